"""`bench accuracy`: a work-precision study of the ellipsoid contact methods and the time step.

Every (method, dt factor) runs the same scene for the same simulated time T = steps x dt_base
(dt_base = the scene's time step, usually "auto") with dt = factor x dt_base, serially, and is
compared at T with a fine reference: the exact method at the smallest time step,
ref_factor x dt_base (default half the smallest listed factor, so that every listed point has a
measurable error). Errors of the final state, particles matched by global id:

  err_max, err_rms      max / rms over particles of |x - x_ref| / r_mean   [-]
                        r_mean = mean volume-equivalent radius (dem.shapes.registry.equivalent_radii)
  err_vel_max, _rms     max / rms of |v - v_ref| / v_ref,rms               [-]
  err_energy            |KE - KE_ref| / max(KE_ref, KE_0, M (0.01 m/s)^2)   [-]

and their cost: wall_s (the step loop, compilation excluded), resolve_s (contact resolution),
cost_per_contact_us = resolve_s / ellipsoid-solver calls, us_per_step. A dense granular flow is
chaotic, so trajectory errors grow with T: keep T short (a few contact durations) to see the
O(dt^2) convergence of the integrator, and the dt-independent error floor of an inexact
contact method (the paper's sextic: reference §1.2).
"""
import copy
import json
import math
import os
import time

import numpy as np

from dem.contact import CONTACT_METHODS
from dem.scene import SceneError
from bench.run.guard import StabilityGuard
from bench.run.prepare import prepare
from bench.run.records import prepare_output
from dem.scene import load_scene
from dem.shapes.registry import equivalent_radii
from dem.timestep import choose_time_step
from modes.serial import SerialMode

COLUMNS = ["method", "dt_factor", "dt", "steps", "err_max", "err_rms", "err_vel_max", "err_vel_rms",
           "err_energy", "wall_s", "resolve_s", "solver_calls", "contacts", "wall_contacts", "cost_per_contact_us",
           "us_per_step", "stable", "max_overlap_ratio", "reason"]


def parse_factors(text):
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SceneError(f"--dt-factors must be comma-separated numbers, got {text!r}") from None
    if not vals or any(not (v > 0 and math.isfinite(v)) for v in vals):
        raise SceneError(f"--dt-factors must be positive numbers, got {text!r}")
    return sorted(set(vals), reverse=True)


def parse_methods(text):
    vals = [x.strip() for x in text.split(",") if x.strip()]
    for v in vals:
        if v not in CONTACT_METHODS:
            raise SceneError(f"unknown contact method {v!r} in --methods ({', '.join(CONTACT_METHODS)})")
    if not vals:
        raise SceneError("--methods is empty")
    return list(dict.fromkeys(vals))


def simulate(scene, dt, steps, method, dt_crit):
    """Run a copy of the (prepared) scene serially; returns (snapshot, record dict)."""
    mode = SerialMode().setup(copy.deepcopy(scene), dt=dt, contact_method=method)
    mode.warmup()
    guard = StabilityGuard(mode, dt, dt_crit, scene.gravity)
    resolve = 0.0
    calls = contacts = wall_contacts = 0
    reason = None
    t0 = time.perf_counter()
    for k in range(1, steps + 1):
        row = mode.step()
        resolve += row["resolveT"]
        calls += row["ellipsoid_calls"]
        contacts += row["n_contacts"]
        wall_contacts += row["n_wall_contacts"]
        reason = guard.check(k, row)
        if reason:
            break
    wall = time.perf_counter() - t0
    rec = {"method": method, "dt": dt, "steps": steps, "wall_s": wall, "resolve_s": resolve,
           "solver_calls": calls, "contacts": contacts, "wall_contacts": wall_contacts,
           "cost_per_contact_us": 1e6 * resolve / calls if calls else float("nan"),
           "us_per_step": 1e6 * wall / max(steps, 1), "stable": reason is None,
           "max_overlap_ratio": mode.max_overlap_ratio, "reason": reason or ""}
    return mode.state.snapshot(), mode.state.kinetic_energy(), rec


def errors(snap, ke, ref, ke_ref, r_mean, ke_floor):
    """Final-state errors of snap against the reference snapshot (both sorted by id)."""
    if not np.array_equal(snap["id"], ref["id"]):
        raise SceneError("accuracy: a run lost or gained particles; cannot compare it with the reference")
    dx = np.linalg.norm(snap["pos"] - ref["pos"], axis=1) / r_mean
    v_scale = float(np.sqrt(np.mean(np.sum(ref["vel"] ** 2, axis=1))))
    dv = np.linalg.norm(snap["vel"] - ref["vel"], axis=1) / max(v_scale, 1e-300)
    return {"err_max": float(dx.max()), "err_rms": float(np.sqrt(np.mean(dx ** 2))),
            "err_vel_max": float(dv.max()), "err_vel_rms": float(np.sqrt(np.mean(dv ** 2))),
            "err_energy": abs(ke - ke_ref) / max(ke_ref, ke_floor)}


def accuracy(args, log=print):
    import pandas as pd
    factors = parse_factors(args.dt_factors)
    methods = parse_methods(args.methods)
    ref_factor = args.ref_factor if args.ref_factor is not None else 0.5 * min(factors)
    if not (ref_factor > 0 and ref_factor <= min(factors)):
        raise SceneError(f"--ref-factor must be in (0, smallest dt factor {min(factors):g}], got {ref_factor:g}")
    scene = load_scene(args.scene, particles=args.particles, shape=args.shape, seed=args.seed)
    ts = choose_time_step(scene, args.dt)
    dt_base, dt_auto, dt_crit = ts.dt, ts.auto, ts.critical
    if max(factors) * dt_base > dt_crit:
        raise SceneError(f"dt factor {max(factors):g} gives {max(factors) * dt_base:.3g} s, above the critical step "
                         f"{dt_crit:.3g} s")
    prepare_output(args.out)
    prepare(scene)
    steps = args.steps if args.steps is not None else scene.steps
    t_end = steps * dt_base
    s = scene.state
    k = s.n_owned
    r_mean = float(np.mean(equivalent_radii(s.axes[:k], s.shape[:k], s.poly[:k])))
    ke_floor = max(s.kinetic_energy(), float(s.mass.sum()) * 0.01 ** 2)
    n_ref = int(round(t_end / (ref_factor * dt_base)))
    log(f"accuracy: {scene.name}, {s.n} particles, T = {t_end:.3g} s; reference: exact, dt = {ref_factor:g} x "
        f"{dt_base:.3g} s ({n_ref} steps)")
    ref, ke_ref, ref_rec = simulate(scene, t_end / n_ref, n_ref, "exact", dt_crit)
    if not ref_rec["stable"]:
        raise SceneError(f"accuracy: the reference run is unstable: {ref_rec['reason']}")
    rows = []
    for method in methods:
        for f in factors:
            n = int(round(t_end / (f * dt_base)))
            snap, ke, rec = simulate(scene, t_end / n, n, method, dt_crit)
            rec["dt_factor"] = f
            nan = {k: float("nan") for k in ("err_max", "err_rms", "err_vel_max", "err_vel_rms", "err_energy")}
            rec.update(errors(snap, ke, ref, ke_ref, r_mean, ke_floor) if rec["stable"] else nan)
            rows.append(rec)
            log(f"  {method:6s} dt x {f:<6g} {n:6d} steps  err_max {rec['err_max']:.3g}  err_rms {rec['err_rms']:.3g}  "
                f"energy {rec['err_energy']:.3g}  {rec['wall_s']:.2f} s  {rec['cost_per_contact_us']:.3g} us/contact"
                + ("" if rec["stable"] else "  UNSTABLE"))
    table = pd.DataFrame(rows)[COLUMNS]
    table.to_csv(os.path.join(args.out, "accuracy.csv"), index=False)
    with open(os.path.join(args.out, "accuracy.json"), "w") as fh:
        json.dump({"scene": scene.name, "scene_source": scene.source, "particles": int(s.n), "dt_base": dt_base,
                   "dt_auto": dt_auto, "dt_critical": dt_crit, "simulated_time": t_end, "r_mean": r_mean,
                   "reference": {"method": "exact", "dt_factor": ref_factor, **ref_rec},
                   "dt_factors": factors, "methods": methods}, fh, indent=1, default=float)
    fig = plot_accuracy(args.out)
    log(f"records in {args.out}: accuracy.csv, accuracy.json, {os.path.basename(fig)}")
    return 0


def plot_accuracy(out):
    """Log-log error against run time, one curve per method, points labelled by dt factor
    (reads only DIR/accuracy.csv and accuracy.json). Returns the figure path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd
    t = pd.read_csv(os.path.join(out, "accuracy.csv"))
    with open(os.path.join(out, "accuracy.json")) as fh:
        meta = json.load(fh)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    panels = [("err_rms", "position error, rms / r_mean"), ("err_vel_rms", "velocity error, rms / v_rms"),
              ("err_energy", "kinetic energy error, relative")]
    for ax, (col, label) in zip(axes, panels):
        for method, g in t.groupby("method", sort=False):
            g = g[g["stable"].astype(bool)].sort_values("wall_s")
            y = np.maximum(g[col].to_numpy(dtype=float), 1e-16)   # an exact match is drawn at the floor
            ax.loglog(g["wall_s"], y, "o-", label=method)
            for x, yy, f in zip(g["wall_s"], y, g["dt_factor"]):
                ax.annotate(f"{f:g}", (x, yy), textcoords="offset points", xytext=(3, 3), fontsize=7)
        ax.set_xlabel("run time [s]")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(title="contact method")
    fig.suptitle(f"{meta['scene']}, {meta['particles']} particles, T = {meta['simulated_time']:.3g} s: error against "
                 f"run time (labels: dt / dt_base, dt_base = {meta['dt_base']:.3g} s; reference exact at "
                 f"{meta['reference']['dt_factor']:g})", fontsize=9)
    fig.tight_layout()
    path = os.path.join(out, "accuracy.png")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
