"""`bench perf --what skin`: the cost of a step against the Verlet skin, the measurement behind
dem.pairs.DEFAULT_SKIN.

A skin F (a fraction of the largest bounding diameter d) trades two costs (Verlet 1967; LAMMPS
`neighbor`): the candidate pairs grow about as (1 + F)^3 and each extra one is resolved every
step (it fails the bounding-sphere test), while the list is rebuilt only when a particle has
moved F d / 2, so the rebuild (neighbour scan, history carry, adjacency) is paid once per
F d / (2 v_max dt) steps. A dense static pack favours a small F, a fast free fall a large one.

Each scene runs serially once per skin from the same state (the trajectories are bit-identical:
DESIGN.md, Determinism), in round-robin rounds of `steps` steps; the figures are medians over
rounds of the mean cost per particle-step (rebuilds amortised), and each skin's cost relative to
the best skin of its scene measured in the same rounds. The default skin is the one whose worst
relative cost over the scenes is smallest.
"""
import copy
import os
import statistics
import sys
from bench.run.prepare import load_prepared
from bench.run.records import write_json
from dem.timestep import choose_time_step
from modes.serial import SerialMode

SKINS = (0.0, 0.02, 0.05, 0.1, 0.2, 0.3)
# (scene, particles, shape, steps run before the copies are made): a dense pack of each contact
# kind, and the paper's deposition 20 ms into the fall (10 000 steps of 2 us: the lowest layers are
# landing, the rest falls at about 0.2 m/s), where a list lasts the fewest steps
SCENES = (("packed", 2000, "ellipsoid", 0), ("packed", 2000, "sphere", 0), ("pluviation", 1521, None, 10000))


def measure(steps, repeats, log, skins=SKINS, scenes=SCENES):
    """Rows (one per scene x skin): us_per_particle_step, relative (to the best skin of the scene),
    steps_per_rebuild, candidates_per_contact (NaN without contacts); and the skin with the
    smallest worst relative cost."""
    confs = []
    for spec, n, shape, advance in scenes:
        scene = load_prepared(spec, particles=n, shape=shape, log=log)
        dt = choose_time_step(scene).dt
        if advance:
            log(f"advancing {scene.name} by {advance} steps")
            lead = SerialMode().setup(scene, dt=dt)
            for _ in range(advance):
                lead.step()
            lead.sync_history()  # the copies start from the state's own rows
        for f in skins:
            log(f"warming up {scene.name} at skin {f:g}")
            mode = SerialMode().setup(copy.deepcopy(scene), dt=dt, skin=f)
            mode.warmup()
            confs.append({"scene": scene.name, "shape": shape or "", "particles": scene.n, "skin": f, "mode": mode,
                          "cost": [], "rebuilds": 0, "steps": 0, "cand": 0.0, "cont": 0.0})
    for _ in range(repeats):  # round robin: every configuration once per round
        for c in confs:
            rows = [c["mode"].step() for _ in range(steps)]
            c["cost"].append(1e6 * sum(r["totalT"] for r in rows) / (steps * c["particles"]))
            c["rebuilds"] += sum(r["neighbor_rebuilt"] for r in rows)
            c["steps"] += steps
            c["cand"] += sum(r["n_candidates"] for r in rows)
            c["cont"] += sum(r["n_contacts"] + r["n_wall_contacts"] for r in rows)
    rows = []
    for c in confs:
        best = [min(o["cost"][r] for o in confs if o["scene"] == c["scene"] and o["shape"] == c["shape"])
                for r in range(repeats)]
        rows.append({"scene": c["scene"], "shape": c["shape"], "particles": c["particles"], "skin": c["skin"],
                     "us_per_particle_step": statistics.median(c["cost"]),
                     "relative": statistics.median(x / b for x, b in zip(c["cost"], best)),
                     "steps_per_rebuild": c["steps"] / max(c["rebuilds"], 1),
                     "candidates_per_contact": c["cand"] / c["cont"] if c["cont"] else float("nan")})
    worst = {f: max(r["relative"] for r in rows if r["skin"] == f) for f in skins}
    choice = min(skins, key=lambda f: (worst[f], f))
    return {"steps": steps, "repeats": repeats, "rows": rows, "worst_relative": worst, "best_skin": choice,
            "load": [round(x, 2) for x in os.getloadavg()]}


def perf_skin(args):
    """The study's table on stdout (and perf.json with --out)."""
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    steps = args.steps if args.steps is not None else 1000
    report = measure(steps, args.repeats, log)
    print(f"{'scene':<24} {'skin':>5} {'us/p-step':>10} {'relative':>9} {'steps/rebuild':>14} {'cand/contact':>13}")
    for r in report["rows"]:
        name = f"{r['scene']} {r['shape']}".strip()
        print(f"{name:<24} {r['skin']:>5g} {r['us_per_particle_step']:>10.3f} {r['relative']:>9.3f} "
              f"{r['steps_per_rebuild']:>14.1f} {r['candidates_per_contact']:>13.2f}")
    print("worst relative cost per skin: " + ", ".join(f"{f:g}: {w:.3f}" for f, w in report["worst_relative"].items())
          + f"; smallest worst: skin {report['best_skin']:g} (medians of {args.repeats} rounds of {steps} steps)")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        write_json(os.path.join(args.out, "perf.json"), report)
    return 0
