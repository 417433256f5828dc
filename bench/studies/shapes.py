"""`bench shapes`: per-contact and per-step cost of spheres, ellipsoids and poly-ellipsoids, and the
neighbour search fraction of each shape with all-pairs and link-cell (the paper's §4.1 / Fig. 7 and
§9: a poly-ellipsoid contact costs about 6x an ellipsoid's and about 300x a sphere's; an
ellipsoid's about 50x a sphere's).

(a) Kernel alone (`kernel` in shapes.json, `kernel_*` columns of shapes.csv): constructed
    overlapping pairs, one pair list per shape, all at the same granularity: the ellipsoid has
    semi-axes KERNEL_ASPECT x KERNEL_SCALE (the pair of `bench perf`), the poly-ellipsoid the same
    extents 2a, 2b, 2c split into plus/minus halves with minus/plus ~ U(0.6, 1) per axis and body
    (the packed scene's asymmetry; same volume as the ellipsoid), the sphere the
    volume-equivalent radius r_eq = (abc)^(1/3). Random orientations and normal n; body 2 is put
    at o2 = s1(n) - (s2(-n) - o2) - delta n with the shape's own support map, so every pair
    overlaps by exactly delta = KERNEL_REL_DEPTH x r_eq along n (reference §1.6; as in
    bench/studies/perf_contact.py and tests/dem/test_contact_polyellipsoid.py). Kernels:
    dem.contact.sphere.sphere_contact (closed form, no warm start),
    dem.contact.ellipsoid.ellipsoid_contact, dem.contact.polyellipsoid.polyellipsoid_contact;
    cold = no previous solution (lambda0 = -1, n0 = 0), warm = started from the pair's own
    converged normal (and lambda* for ellipsoids), what the history gives a persistent contact.
    One timed pass = one @njit loop over all pairs (no Python in the loop; JIT compile and a
    cache-warming pass excluded); passes of every (shape, start) are interleaved round-robin and
    the median pass time / pairs is reported in microseconds.
(b) In situ (rows of shapes.csv): the packed scene (bench.run.prepare, cached) at N particles of each
    shape, SerialMode with neighbor = allpairs and linkcell (skin 0: neighbours every step, the
    paper's way), dt = dem.timestep.choose_time_step. Each configuration works on its own copy of the built
    scene, is warmed up (JIT + WARM_STEPS untimed steps), then `repeats` rounds step every
    configuration `steps` times in turn (round-robin); per round each figure is the median over
    its steps of the per-step value (totalT / N, neighborT / totalT, resolveT / candidates, ...),
    and the median over rounds is recorded.
(c) Ratios poly/ellipsoid, poly/sphere, ellipsoid/sphere of the kernel (cold, warm) and in situ
    (resolve time per candidate pair and per touching contact, us per particle-step) against
    the paper's 6x, 300x and 50x (`ratios` in shapes.json, printed).

Noise on a shared 2-core machine was about +-50 % between runs: only ratios measured within one
run (interleaved as above) are meaningful; absolute figures are indicative. shapes.png is drawn
afterwards from shapes.csv and shapes.json only (plotting reads records). Schema:
results/README.md.
"""
import copy
import csv
import math
import os
import sys
import time

import numpy as np
from numba import njit

from dem.contact.ellipsoid import (
    OUT_LAM,
    OUT_NEWTON_ITERS,
    OUT_NX,
    OUT_PW_ITERS,
    ellipsoid_contact,
)
from dem.contact.polyellipsoid import OUT_SWITCHES, POLY_OUT_LEN, polyellipsoid_contact
from dem.contact.sphere import sphere_contact
from dem.quaternion import quat_to_matrices, random_quaternions
from bench.run.figure import plt
from bench.run.prepare import load_prepared
from bench.run.records import environment, write_json
from bench.run.records import prepare_output
from bench.run.records import write_rows_csv
from dem.timestep import choose_time_step
from modes.serial import SerialMode

SHAPES = ("sphere", "ellipsoid", "polyellipsoid")
NEIGHBORS = ("allpairs", "linkcell")
KERNEL_ASPECT = (1.0, 0.8, 0.6)     # ellipsoid semi-axes / KERNEL_SCALE (the pair of bench perf)
KERNEL_SCALE = 1e-3                 # [m]
KERNEL_ASYMMETRY = (0.6, 1.0)       # poly-ellipsoid minus/plus half-extent ratio range (packed.toml default)
KERNEL_REL_DEPTH = 1e-3             # overlap delta / r_eq
KERNEL_PASSES = 15                  # timed passes per (shape, start); median reported
WARM_STEPS = 2                      # untimed steps after the JIT warm-up
# the paper: contact resolution cost ratios (§1 and §4.1: ellipsoid ~50x sphere, poly ~300x sphere;
# §9: poly ~6x ellipsoid), "in terms of floating-point operation"
PAPER_RATIOS = {"poly_over_ellipsoid": 6.0, "poly_over_sphere": 300.0, "ellipsoid_over_sphere": 50.0}
# the paper's Fig. 7 (2,000 particles, serial): neighbour estimate share of the CPU time
PAPER_NSF = {("sphere", "allpairs"): 0.747, ("sphere", "linkcell"): 0.208,
             ("ellipsoid", "allpairs"): 0.132, ("ellipsoid", "linkcell"): 0.029,
             ("polyellipsoid", "allpairs"): 0.040, ("polyellipsoid", "linkcell"): 0.007}
NOISE_NOTE = ("on a shared machine the noise between runs can reach +-50 %: only ratios measured "
              "within one run (interleaved passes and rounds) are meaningful; absolute times are indicative")
COLUMNS = ["shape", "neighbor", "particles", "steps", "repeats", "dt", "us_per_particle_step",
           "neighbor_us_per_particle", "resolve_us_per_particle", "other_us_per_particle", "candidates",
           "contacts", "solver_calls", "coordination", "resolve_us_per_candidate", "resolve_us_per_contact",
           "nsf", "nsf_detect", "paper_nsf", "kernel_cold_us", "kernel_warm_us", "kernel_pairs"]
TEXT_COLUMNS = ("shape", "neighbor")
LABEL = {"sphere": "sphere", "ellipsoid": "ellipsoid", "polyellipsoid": "poly-ellipsoid"}


# ------------------------------------------------------------------ (a) constructed pairs

def _unit(rng, n):
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def _rotations(rng, n):
    return quat_to_matrices(random_quaternions(n, rng))


def _poly_support(rot, a6, nrm):
    """Support point offsets s(n) - o [n, 3] of poly-ellipsoids (rot [n,3,3], a6 [n,6]) along nrm [n,3]
    (numpy, reference §2.2: alpha by the sign of R^T n, s - o = R (alpha^2 o n_b) / |alpha o n_b|)."""
    nb = np.einsum("nji,nj->ni", rot, nrm)
    al = np.where(nb >= 0.0, a6[:, 0::2], a6[:, 1::2])
    h = np.sqrt(np.sum((al * nb) ** 2, axis=1))
    return np.einsum("nij,nj->ni", rot, al * al * nb / h[:, None])


def _ellipsoid_support(rot, ax, nrm):
    """Support point offsets s(n) - c [n, 3] of ellipsoids: Q n / sqrt(n.Q n), Q = R diag(ax^2) R^T."""
    return _poly_support(rot, np.repeat(ax, 2, axis=1), nrm)


def make_pairs(n_pairs, seed=0, rel_depth=KERNEL_REL_DEPTH, scale=KERNEL_SCALE, aspect=KERNEL_ASPECT):
    """Constructed overlapping pairs of each shape at the same granularity (module docstring).
    Returns {shape: dict of arrays} and the common figures (r_eq, delta)."""
    rng = np.random.default_rng(seed)
    ax = scale * np.asarray(aspect, dtype=np.float64)
    r_eq = float(np.prod(ax) ** (1.0 / 3.0))
    delta = rel_depth * r_eq
    pairs = {}
    # spheres: c2 = c1 + (2 r - delta) n
    nrm = _unit(rng, n_pairs)
    c1 = rng.uniform(0.0, 0.02, (n_pairs, 3))
    pairs["sphere"] = dict(c1=c1, r1=np.full(n_pairs, r_eq), c2=c1 + (2.0 * r_eq - delta) * nrm,
                           r2=np.full(n_pairs, r_eq), normal=nrm)
    # ellipsoids
    nrm = _unit(rng, n_pairs)
    ax1 = np.tile(ax, (n_pairs, 1))
    rot1, rot2 = _rotations(rng, n_pairs), _rotations(rng, n_pairs)
    c1 = rng.uniform(0.0, 0.02, (n_pairs, 3))
    c2 = c1 + _ellipsoid_support(rot1, ax1, nrm) - _ellipsoid_support(rot2, ax1, -nrm) - delta * nrm
    pairs["ellipsoid"] = dict(c1=c1, rot1=rot1, ax1=ax1, c2=c2, rot2=rot2, ax2=ax1.copy(), normal=nrm)
    # poly-ellipsoids: extents 2 ax split with minus/plus ~ U(asymmetry), per axis and body

    def six():
        ratio = rng.uniform(KERNEL_ASYMMETRY[0], KERNEL_ASYMMETRY[1], (n_pairs, 3))
        plus = 2.0 * ax / (1.0 + ratio)
        a6 = np.empty((n_pairs, 6))
        a6[:, 0::2] = plus
        a6[:, 1::2] = ratio * plus
        return a6
    nrm = _unit(rng, n_pairs)
    a1, a2 = six(), six()
    rot1, rot2 = _rotations(rng, n_pairs), _rotations(rng, n_pairs)
    o1 = rng.uniform(0.0, 0.02, (n_pairs, 3))
    o2 = o1 + _poly_support(rot1, a1, nrm) - _poly_support(rot2, a2, -nrm) - delta * nrm
    pairs["polyellipsoid"] = dict(c1=o1, rot1=rot1, ax1=a1, c2=o2, rot2=rot2, ax2=a2, normal=nrm)
    return pairs, {"r_eq_m": r_eq, "delta_m": delta, "rel_depth": rel_depth, "ellipsoid_axes_m": ax.tolist(),
                   "poly_asymmetry": list(KERNEL_ASYMMETRY)}


# ------------------------------------------------------------------ (a) timed njit loops

@njit(cache=True)
def _sphere_pass(c1, r1, c2, r2, stats):
    """One pass of sphere_contact over all pairs; returns (hits, checksum) so nothing is elided."""
    hits = 0
    acc = 0.0
    for i in range(c1.shape[0]):
        hit, depth, nx, ny, nz, xx, xy, xz, re = sphere_contact(c1[i, 0], c1[i, 1], c1[i, 2], r1[i],
                                                                c2[i, 0], c2[i, 1], c2[i, 2], r2[i])
        if hit:
            hits += 1
            acc += depth + nx + ny + nz + xx + xy + xz + re
        stats[i, 0] = hit
    return hits, acc


@njit(cache=True)
def _ellipsoid_pass(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out, stats):
    """One pass of ellipsoid_contact; stats [n, 4] = (hit, PW iterations, Newton evaluations, 0)."""
    hits = 0
    acc = 0.0
    for i in range(c1.shape[0]):
        hit = ellipsoid_contact(c1[i], rot1[i], ax1[i], c2[i], rot2[i], ax2[i], lam0[i], n0[i], out)
        stats[i, 0] = hit
        if hit:
            hits += 1
            acc += out[0]
            stats[i, 1] = out[OUT_PW_ITERS]
            stats[i, 2] = out[OUT_NEWTON_ITERS]
    return hits, acc


@njit(cache=True)
def _poly_pass(o1, rot1, a1, o2, rot2, a2, n0, out, stats):
    """One pass of polyellipsoid_contact; stats [n, 4] = (hit, PW iterations, Newton evaluations,
    octant switches)."""
    hits = 0
    acc = 0.0
    for i in range(o1.shape[0]):
        hit = polyellipsoid_contact(o1[i], rot1[i], a1[i], o2[i], rot2[i], a2[i], n0[i], out)
        stats[i, 0] = hit
        if hit:
            hits += 1
            acc += out[0]
            stats[i, 1] = out[OUT_PW_ITERS]
            stats[i, 2] = out[OUT_NEWTON_ITERS]
            stats[i, 3] = out[OUT_SWITCHES]
    return hits, acc


def _warm_inputs(shape, p):
    """(lam0, n0) of a warm start: each pair's own converged lambda* / normal from one cold solve."""
    n = p["c1"].shape[0]
    lam0 = -np.ones(n)
    n0 = np.zeros((n, 3))
    out = np.zeros(POLY_OUT_LEN)
    for i in range(n):
        if shape == "ellipsoid":
            hit = ellipsoid_contact(p["c1"][i], p["rot1"][i], p["ax1"][i], p["c2"][i], p["rot2"][i], p["ax2"][i],
                                    -1.0, n0[i], out)
        else:
            hit = polyellipsoid_contact(p["c1"][i], p["rot1"][i], p["ax1"][i], p["c2"][i], p["rot2"][i],
                                        p["ax2"][i], n0[i], out)
        if hit:
            lam0[i] = out[OUT_LAM]
            n0[i] = out[OUT_NX:OUT_NX + 3]
    return lam0, n0


def _kernel_runs(pairs):
    """{(shape, start): zero-argument callable running one pass, its stats array}."""
    runs = {}
    p = pairs["sphere"]
    st = np.zeros((p["c1"].shape[0], 4))
    runs[("sphere", "cold")] = (lambda p=p, st=st: _sphere_pass(p["c1"], p["r1"], p["c2"], p["r2"], st), st)
    for shape in ("ellipsoid", "polyellipsoid"):
        p = pairs[shape]
        n = p["c1"].shape[0]
        starts = {"cold": (-np.ones(n), np.zeros((n, 3)))}
        starts["warm"] = _warm_inputs(shape, p)
        for start, (lam0, n0) in starts.items():
            st = np.zeros((n, 4))
            out = np.zeros(POLY_OUT_LEN)
            if shape == "ellipsoid":
                fn = (lambda p=p, lam0=lam0, n0=n0, out=out, st=st:
                      _ellipsoid_pass(p["c1"], p["rot1"], p["ax1"], p["c2"], p["rot2"], p["ax2"], lam0, n0, out, st))
            else:
                fn = (lambda p=p, n0=n0, out=out, st=st:
                      _poly_pass(p["c1"], p["rot1"], p["ax1"], p["c2"], p["rot2"], p["ax2"], n0, out, st))
            runs[(shape, start)] = (fn, st)
    return runs


def time_kernels(n_pairs=20000, passes=KERNEL_PASSES, seed=0, log=None):
    """(a): {shape: {"cold": {...}, "warm": {...} or None}} plus the construction figures.
    Each entry: us_per_contact (median over passes of pass time / pairs), pairs, hits, passes,
    pw_iters_mean, newton_iters_mean, switches_mean (poly), spread (max/min pass time)."""
    pairs, info = make_pairs(n_pairs, seed)
    runs = _kernel_runs(pairs)
    for fn, _ in runs.values():       # JIT compile (or cache load) and a cache-warming pass
        fn()
    times = {key: [] for key in runs}
    for _ in range(passes):           # round-robin: drift spreads over every kernel alike
        for key, (fn, _) in runs.items():
            t0 = time.perf_counter()
            fn()
            times[key].append(time.perf_counter() - t0)
    res = {shape: {"cold": None, "warm": None} for shape in SHAPES}
    for (shape, start), (fn, st) in runs.items():
        hit = st[:, 0] > 0
        t = np.asarray(times[(shape, start)])
        res[shape][start] = {
            "us_per_contact": 1e6 * float(np.median(t)) / n_pairs, "pairs": n_pairs, "hits": int(hit.sum()),
            "passes": passes, "spread": float(t.max() / t.min()),
            "pw_iters_mean": float(st[hit, 1].mean()) if hit.any() and shape != "sphere" else 0.0,
            "newton_iters_mean": float(st[hit, 2].mean()) if hit.any() and shape != "sphere" else 0.0,
            "switches_mean": float(st[hit, 3].mean()) if hit.any() and shape == "polyellipsoid" else 0.0}
    res["sphere"]["warm_note"] = "closed form: no warm start (the cold figure is the only one)"
    res["construction"] = info
    return res


# ------------------------------------------------------------------ (b) in situ

def _figures(rows, n):
    """Per-round figures: medians over the round's steps of each per-step quantity (so an
    inequality that holds at every step, e.g. nsf <= nsf_detect, holds for the medians; the parts
    neighbour / resolve / other are medians of their own and need not add up to the total exactly)."""
    def med(f):
        return float(np.median([f(r) for r in rows]))

    def per(a, b):
        return med(lambda r: r[a] / r[b] if r[b] else math.nan)
    return {"us_per_particle_step": 1e6 * med(lambda r: r["totalT"]) / n,
            "neighbor_us_per_particle": 1e6 * med(lambda r: r["neighborT"]) / n,
            "resolve_us_per_particle": 1e6 * med(lambda r: r["resolveT"]) / n,
            "other_us_per_particle": 1e6 * med(lambda r: r["totalT"] - r["neighborT"] - r["resolveT"]) / n,
            "candidates": med(lambda r: r["n_candidates"]), "contacts": med(lambda r: r["n_contacts"]),
            "solver_calls": med(lambda r: r["ellipsoid_calls"]),
            "coordination": 2.0 * med(lambda r: r["n_contacts"]) / n,
            "resolve_us_per_candidate": 1e6 * per("resolveT", "n_candidates"),
            "resolve_us_per_contact": 1e6 * per("resolveT", "n_contacts"),
            "nsf": per("neighborT", "totalT"),
            "nsf_detect": med(lambda r: r["neighborT"] / (r["neighborT"] + r["resolveT"]))}


def measure_insitu(particles, steps, repeats, log=None):
    """(b): rows (dicts of COLUMNS without the kernel columns), one per shape x neighbour method, and
    the build record of each shape's scene."""
    confs, builds = [], {}
    for shape in SHAPES:
        scene = load_prepared("packed", particles=particles, shape=shape, log=log)
        builds[shape] = scene.extras.get("built")
        dt = choose_time_step(scene).dt
        for nb in NEIGHBORS:
            if log:
                log(f"warming up {shape} {nb}")
            mode = SerialMode().setup(copy.deepcopy(scene), dt=dt, neighbor=nb, skin=0.0)
            mode.warmup()
            for _ in range(WARM_STEPS):
                mode.step()
            confs.append((shape, nb, dt, mode))
    samples = [[] for _ in confs]
    for r in range(repeats):          # round-robin rounds, as bench schemes
        for k, (shape, nb, dt, mode) in enumerate(confs):
            samples[k].append(_figures([mode.step() for _ in range(steps)], mode.state.n_owned))
    rows = []
    for (shape, nb, dt, mode), smp in zip(confs, samples):
        row = {"shape": shape, "neighbor": nb, "particles": mode.state.n_owned, "steps": steps,
               "repeats": repeats, "dt": dt, "paper_nsf": PAPER_NSF[(shape, nb)]}
        for key in smp[0]:
            row[key] = float(np.median([s[key] for s in smp]))
        rows.append(row)
    return rows, builds


# ------------------------------------------------------------------ (c) ratios

def _ratio(a, b):
    return a / b if (b and b > 0 and not math.isnan(a) and not math.isnan(b)) else math.nan


def ratios(kernel, rows):
    """{"paper": PAPER_RATIOS, "kernel": {"cold": {...}, "warm": {...}}, "insitu": {nb: {figure: {...}}}}:
    each {...} maps poly_over_ellipsoid, poly_over_sphere, ellipsoid_over_sphere to our ratio and
    <name>_vs_paper to ours / the paper's. Warm kernel ratios divide by the sphere's cold figure
    (a sphere has no warm start)."""
    def block(sph, ell, poly):
        d = {"poly_over_ellipsoid": _ratio(poly, ell), "poly_over_sphere": _ratio(poly, sph),
             "ellipsoid_over_sphere": _ratio(ell, sph)}
        d.update({f"{k}_vs_paper": _ratio(d[k], v) for k, v in PAPER_RATIOS.items()})
        return d
    sph = kernel["sphere"]["cold"]["us_per_contact"]
    out = {"paper": dict(PAPER_RATIOS), "kernel": {}, "insitu": {}}
    for start in ("cold", "warm"):
        out["kernel"][start] = block(sph, kernel["ellipsoid"][start]["us_per_contact"],
                                     kernel["polyellipsoid"][start]["us_per_contact"])
    get = {(r["shape"], r["neighbor"]): r for r in rows}
    for nb in NEIGHBORS:
        out["insitu"][nb] = {fig: block(*(get[(s, nb)][fig] for s in SHAPES))
                             for fig in ("resolve_us_per_candidate", "resolve_us_per_contact", "us_per_particle_step")}
    return out


# ------------------------------------------------------------------ records

def write_csv(path, rows):
    write_rows_csv(path, rows, COLUMNS)


def read_csv(path):
    """shapes.csv rows with numbers parsed (empty -> NaN)."""
    with open(path, newline="") as fh:
        return [{k: v if k in TEXT_COLUMNS else (float(v) if v not in ("", None) else math.nan)
                 for k, v in r.items()} for r in csv.DictReader(fh)]


def _load():
    try:
        return os.getloadavg()[0]
    except OSError:
        return math.nan


def format_report(kernel, rows, rat):
    """The printed summary: kernel table, in-situ table, ratios against the paper, the noise note."""
    L = ["--- per-contact cost by shape (kernel alone, median of njit passes)",
         f"{'shape':14s} {'cold us':>9s} {'warm us':>9s} {'hits':>11s} {'PW it':>6s} {'Newton':>6s} {'switch':>6s}"]
    for s in SHAPES:
        c, w = kernel[s]["cold"], kernel[s]["warm"]
        warm = f"{w['us_per_contact']:9.4f}" if w else f"{'-':>9s}"
        L.append(f"{LABEL[s]:14s} {c['us_per_contact']:9.4f} {warm} {c['hits']:5d}/{c['pairs']:<5d} "
                 f"{c['pw_iters_mean']:6.2f} {c['newton_iters_mean']:6.2f} {c['switches_mean']:6.2f}")
    n = int(rows[0]["particles"])
    L += [f"--- in situ: packed scene, N = {n}, serial, median over {int(rows[0]['repeats'])} round(s) of the "
          f"median of {int(rows[0]['steps'])} steps",
          f"{'shape':14s} {'neighbor':8s} {'us/p-step':>9s} {'nbr us/p':>8s} {'res us/p':>8s} {'us/cand':>8s} "
          f"{'us/cont':>8s} {'cand':>7s} {'cont':>7s} {'NSF':>6s} {'paper':>6s} {'NSFdet':>6s}"]
    for r in rows:
        L.append(f"{LABEL[r['shape']]:14s} {r['neighbor']:8s} {r['us_per_particle_step']:9.3f} "
                 f"{r['neighbor_us_per_particle']:8.3f} {r['resolve_us_per_particle']:8.3f} "
                 f"{r['resolve_us_per_candidate']:8.4f} {r['resolve_us_per_contact']:8.4f} {r['candidates']:7.0f} "
                 f"{r['contacts']:7.0f} {r['nsf']:6.3f} {r['paper_nsf']:6.3f} {r['nsf_detect']:6.3f}")
    L.append("--- cost ratios (ours vs the paper's ~6x poly/ellipsoid, ~300x poly/sphere, ~50x ellipsoid/sphere)")
    names = (("poly_over_ellipsoid", "poly/ellipsoid"), ("poly_over_sphere", "poly/sphere"),
             ("ellipsoid_over_sphere", "ellipsoid/sphere"))

    def line(label, d, paper=True):
        return f"{label:38s} " + "  ".join(
            f"{nm} {d[k]:7.2f}x" + (f" (paper {PAPER_RATIOS[k]:g}x)" if paper else "") for k, nm in names)
    L.append(line("kernel, cold start", rat["kernel"]["cold"]))
    L.append(line("kernel, warm start (sphere: cold)", rat["kernel"]["warm"]))
    for nb in NEIGHBORS:
        L.append(line(f"in situ {nb}, resolve / candidate", rat["insitu"][nb]["resolve_us_per_candidate"]))
        L.append(line(f"in situ {nb}, resolve / contact", rat["insitu"][nb]["resolve_us_per_contact"]))
    L.append("whole step (the paper's ratios are per contact, not per step):")
    for nb in NEIGHBORS:
        L.append(line(f"in situ {nb}, per particle-step", rat["insitu"][nb]["us_per_particle_step"], False))
    L.append("note: " + NOISE_NOTE)
    return L


def shapes(args):
    """Measure (a) and (b), write OUT/shapes.csv and OUT/shapes.json, draw OUT/shapes.png from them,
    print the summary."""
    prepare_output(args.out)

    def log(msg):
        print(f"bench shapes: {msg}", file=sys.stderr, flush=True)

    load_before = _load()
    t0 = time.perf_counter()
    log(f"kernel timing: {args.pairs} constructed pairs per shape, {KERNEL_PASSES} passes")
    kernel = time_kernels(args.pairs, KERNEL_PASSES, log=log)
    rows, builds = measure_insitu(args.particles, args.steps, args.repeats, log=log)
    for r in rows:
        k = kernel[r["shape"]]
        r["kernel_cold_us"] = k["cold"]["us_per_contact"]
        r["kernel_warm_us"] = k["warm"]["us_per_contact"] if k["warm"] else math.nan
        r["kernel_pairs"] = k["cold"]["pairs"]
    rat = ratios(kernel, rows)
    csv_path = os.path.join(args.out, "shapes.csv")
    json_path = os.path.join(args.out, "shapes.json")
    write_csv(csv_path, rows)
    report = {"command": "bench shapes", "argv": sys.argv[1:], "particles": args.particles, "steps": args.steps,
              "repeats": args.repeats, "pairs": args.pairs, "kernel_passes": KERNEL_PASSES,
              "warm_steps": WARM_STEPS, "kernel": kernel, "insitu": rows, "ratios": rat,
              "paper": {"ratios": PAPER_RATIOS, "nsf_fig7": {f"{s}/{nb}": v for (s, nb), v in PAPER_NSF.items()},
                        "particles": 2000},
              "builds": builds, "noise_note": NOISE_NOTE,
              "notes": [f"kernel: same granularity (volume-equivalent radius r_eq) for every shape, depth "
                        f"{KERNEL_REL_DEPTH:g} x r_eq; warm ratios divide by the sphere's cold figure",
                        "in situ: resolve_us_per_candidate = resolveT / candidate pairs (every candidate "
                        "goes through one contact kernel: sphere closed form or the ellipsoid/poly solver; "
                        "equals resolveT / solver calls for ellipsoids and poly-ellipsoids); "
                        "resolve_us_per_contact = resolveT / touching contacts; both include the force law "
                        "and history look-up",
                        "in situ: the packed scene sizes particles by their largest diameter, so its "
                        "spheres are larger in volume than its ellipsoids / poly-ellipsoids (per-particle "
                        "figures compare; box sizes differ)",
                        "nsf = neighborT / totalT (share of the whole step, the paper's Fig. 7 pies); "
                        "nsf_detect = neighborT / (neighborT + resolveT) (the NSF formula, steps.csv's nsf)"],
              "load_before": load_before, "load_after": _load(), "wall_s": time.perf_counter() - t0,
              "environment": environment()}
    write_json(json_path, report)
    png = plot_shapes(args.out)
    for line in format_report(kernel, read_csv(csv_path), rat):
        print(line)
    print(f"wrote {csv_path}, {json_path} and {png}")
    return 0


# ------------------------------------------------------------------ figure (reads the records only)

def plot_shapes(directory):
    """DIR/shapes.png from DIR/shapes.csv and DIR/shapes.json: (1) per-contact cost per shape, log
    scale: kernel cold/warm and in-situ resolve time per candidate and per contact, with the paper's
    ratios drawn from our sphere kernel figure; (2) us per particle-step per shape, all-pairs vs
    link-cell, with the neighbour estimate part marked; (3) NSF per shape, all-pairs vs link-cell, ours
    beside the paper's Fig. 7."""
    import json

    rows = read_csv(os.path.join(directory, "shapes.csv"))
    with open(os.path.join(directory, "shapes.json")) as fh:
        rep = json.load(fh)
    get = {(r["shape"], r["neighbor"]): r for r in rows}
    n = int(rows[0]["particles"])
    x = np.arange(len(SHAPES))
    fig, axes = plt.subplots(1, 3, figsize=(14.5, 4.9))

    ax = axes[0]
    kern = rep["kernel"]
    series = [("kernel, cold start", [kern[s]["cold"]["us_per_contact"] for s in SHAPES], "C0", None),
              ("kernel, warm start", [kern[s]["warm"]["us_per_contact"] if kern[s]["warm"] else math.nan
                                      for s in SHAPES], "C9", None),
              ("in situ link-cell, resolve / candidate",
               [get[(s, "linkcell")]["resolve_us_per_candidate"] for s in SHAPES], "C1", None),
              ("in situ link-cell, resolve / contact",
               [get[(s, "linkcell")]["resolve_us_per_contact"] for s in SHAPES], "C3", None)]
    w = 0.2
    for k, (label, vals, color, hatch) in enumerate(series):
        vals = np.asarray(vals, dtype=float)
        bars = ax.bar(x + (k - 1.5) * w, np.where(np.isnan(vals), 0.0, vals), w, label=label, color=color)
        for b, v in zip(bars, vals):
            if not math.isnan(v):
                ax.text(b.get_x() + b.get_width() / 2, v * 1.08, f"{v:.3g}", ha="center", va="bottom",
                        fontsize=6, rotation=90)
    sph = kern["sphere"]["cold"]["us_per_contact"]
    paper = [sph, sph * PAPER_RATIOS["ellipsoid_over_sphere"], sph * PAPER_RATIOS["poly_over_sphere"]]
    ax.plot(x, paper, "k_", ms=28, mew=1.6, label="paper: 1x, 50x, 300x our sphere kernel (cold)")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([LABEL[s] for s in SHAPES])
    ax.set_ylabel("time per contact [us]")
    rk = rep["ratios"]["kernel"]["cold"]
    ax.set_title(f"Per-contact cost (kernel cold: poly/ell {rk['poly_over_ellipsoid']:.1f}x, "
                 f"poly/sph {rk['poly_over_sphere']:.0f}x;\npaper 6x, 300x)", fontsize=8.5)
    top = np.nanmax([np.nanmax(np.asarray(v, dtype=float)) for _, v, _, _ in series] + [max(paper)])
    ax.set_ylim(top=top * 12)
    ax.legend(fontsize=6.5, loc="upper left")

    ax = axes[1]
    w = 0.36
    for k, (nb, color, label) in enumerate((("allpairs", "C0", "all-pairs"), ("linkcell", "C1", "link-cell"))):
        tot = np.array([get[(s, nb)]["us_per_particle_step"] for s in SHAPES])
        nbr = np.array([get[(s, nb)]["neighbor_us_per_particle"] for s in SHAPES])
        bars = ax.bar(x + (k - 0.5) * w, tot, w, color=color, label=f"{label}: whole step")
        ax.plot(x + (k - 0.5) * w, nbr, "k_", ms=14, mew=1.4, label="its neighbour estimate part" if k else None)
        for b, v, v2 in zip(bars, tot, nbr):
            ax.text(b.get_x() + b.get_width() / 2, v * 1.08, f"{v:.3g}\n(nbr {v2:.2g})", ha="center",
                    va="bottom", fontsize=6)
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([LABEL[s] for s in SHAPES])
    ax.set_ylabel("time per particle-step [us]")
    ax.set_title(f"Per-step cost, N = {n} packed, serial\n(bars: whole step; dash: neighbour estimate)",
                 fontsize=8.5)
    ax.legend(fontsize=6.5, loc="upper left")
    lo = min(get[(s, nb)]["neighbor_us_per_particle"] for s in SHAPES for nb in NEIGHBORS)
    hi = max(get[(s, nb)]["us_per_particle_step"] for s in SHAPES for nb in NEIGHBORS)
    ax.set_ylim(max(lo, 1e-4) * 0.5, hi * 8)

    ax = axes[2]
    w = 0.2
    series = [("ours, all-pairs", "allpairs", "nsf", "C0", None),
              ("paper, O(n^2)", "allpairs", "paper_nsf", "0.55", "//"),
              ("ours, link-cell", "linkcell", "nsf", "C1", None), ("paper, O(n) link-cell", "linkcell", "paper_nsf",
                                                                  "0.8", "//")]
    for k, (label, nb, key, color, hatch) in enumerate(series):
        vals = np.array([get[(s, nb)][key] for s in SHAPES])
        bars = ax.bar(x + (k - 1.5) * w, vals, w, label=label, color=color, hatch=hatch, edgecolor="k", lw=0.4)
        for b, v in zip(bars, vals):
            ax.text(b.get_x() + b.get_width() / 2, v * 1.08, f"{100 * v:.1f}%", ha="center", va="bottom",
                    fontsize=6, rotation=90)
    ax.set_yscale("log")
    ax.set_ylim(1e-3, 3.0)
    ax.set_xticks(x)
    ax.set_xticklabels([LABEL[s] for s in SHAPES])
    ax.set_ylabel("NSF = neighborT / totalT")
    ax.set_title(f"Neighbour search fraction (Fig. 7 in kind;\nours N = {n}, paper N = 2000)", fontsize=8.5)
    ax.legend(fontsize=6.5, loc="upper right", ncol=2)
    fig.text(0.01, 0.005, "Note: " + NOISE_NOTE + ".", fontsize=7, color="0.3", ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    path = os.path.join(directory, "shapes.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
