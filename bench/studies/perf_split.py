"""`bench perf --what split`: the measurement behind the thread schemes' cost model (each registered
shape's contact_cost, pass_cost and wall_cost: dem.shapes.shape.Shape, read by modes.parallel),
taken on the machine at hand.

On the built-in `mixed` crystal (2000 spheres, then 2000 aligned ellipsoids by global id, every
particle on the floor) a serial mode is built at two Verlet skins, 0.1 and 0.6. Its gid-sorted
pair list falls in two row ranges, the spheres' rows and the ellipsoids' rows; in each,
dem.forces.resolve_range is timed (median of `repeats` rounds of `calls` calls) and the two
skins' timings t = n_near c_near + n_apart c_apart are solved for the cost of a pair whose
bounding spheres overlap (c_near) and of one whose bounding spheres are apart (c_apart). The
per-particle pass, dem.forces.finish_range, is timed over the spheres and over the ellipsoids
with the scene's walls and with none: the particle's cost without a wall, and what its floor
contact adds. The calls repeat one step's work on a throwaway copy (its history and positions
drift by the repeats, which does not change what the kernels do).

Weights are in the units of the cost model: a pair apart (pairs), a sphere without a wall (the
per-particle pass). The poly-ellipsoid is not in the crystal; its costs are the ellipsoid's.
"""
import statistics
import time

import numpy as np

from bench.run.prepare import load_prepared
from dem.forces import finish_range, resolve_range
from dem.shapes import SPHERE
from dem.shapes.registry import BY_NAME
from dem.timestep import choose_time_step
from modes.serial import SerialMode

SKINS = (0.1, 0.6)


def _median_time(fn, calls, repeats):
    """Median over `repeats` rounds of the mean time of `calls` calls of fn() [s] (one call first)."""
    fn()
    rounds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        rounds.append((time.perf_counter() - t0) / calls)
    return statistics.median(rounds)


def _pair_timings(mode, calls, repeats):
    """Per row range (spheres' rows, ellipsoids' rows): (pairs whose bounding spheres overlap,
    pairs apart, resolve_range time [s])."""
    m = mode
    s = m.state
    pi, pj = m.pairs.pi[:m.pairs.m], m.pairs.pj[:m.pairs.m]
    first_solid = int(np.searchsorted(pi, int(np.argmax(s.shape != SPHERE))))
    d2 = np.sum((s.pos[pj] - s.pos[pi]) ** 2, axis=1)
    near = d2 < (s.rbound[pi] + s.rbound[pj]) ** 2
    out = []
    for k0, k1 in ((0, first_solid), (first_solid, m.pairs.m)):
        t = _median_time(lambda: resolve_range(m.kind, m.method, k0, k1, m.plist, m.bodies, m.polys, m.law, m.dt,
                                               m.deliver, s.n_owned, m.gat, m.no_terms, m.out, m.n0), calls, repeats)
        out.append((int(near[k0:k1].sum()), int((~near[k0:k1]).sum()), t))
    return out


def _finish_timings(mode, calls, repeats):
    """Per particle kind (spheres, ellipsoids): (particles, time with the scene's walls [s], time
    without walls [s]) of finish_range."""
    m = mode
    s = m.state
    walls = m.walls()
    bare = (walls[0][:0], walls[1][:0]) + tuple(walls[2:])  # no planes: the pass without wall contacts
    spheres = np.flatnonzero(s.shape[:s.n_owned] == SPHERE)
    cut = int(spheres[-1]) + 1  # the spheres come first in the mixed crystal
    out = []
    for p0, p1 in ((0, cut), (cut, s.n_owned)):
        times = []
        for w in (walls, bare):
            times.append(_median_time(lambda: finish_range(p0, p1, m.kind == SPHERE, m.deliver, m.adj, m.bodies, w,
                                                           m.polys, m.gravity, m.dt, False, m.pairs.ref, m.out),
                                      calls, repeats))
        out.append((p1 - p0, times[0], times[1]))
    return out


def measure(repeats, log, calls=100, scene_name="mixed"):
    """The per-kind costs [us] and the weights they imply beside modes.parallel's constants."""
    scene = load_prepared(scene_name, log=log)
    dt = choose_time_step(scene).dt
    pairs = []
    finish = None
    for skin in SKINS:
        log(f"timing {scene.name} at skin {skin:g}")
        mode = SerialMode().setup(scene, dt=dt, skin=skin)
        mode.warmup()
        for _ in range(3):
            mode.step()
        pairs.append(_pair_timings(mode, calls, repeats))
        if finish is None:
            finish = _finish_timings(mode, calls, repeats)
    costs = {}
    for side, kind in enumerate(("sphere", "ellipsoid")):
        a = np.array([[pairs[k][side][0], pairs[k][side][1]] for k in range(len(SKINS))], dtype=float)
        y = np.array([pairs[k][side][2] for k in range(len(SKINS))])
        near, apart = np.linalg.solve(a, y) * 1e6
        costs[kind] = {"near_us": float(near), "apart_us": float(apart),
                       "rows": [{"skin": f, "near": pairs[k][side][0], "apart": pairs[k][side][1],
                                 "seconds": pairs[k][side][2]} for k, f in enumerate(SKINS)]}
    apart = max(statistics.mean([costs["sphere"]["apart_us"], costs["ellipsoid"]["apart_us"]]), 1e-12)
    (ns, s_walls, s_bare), (ne, e_walls, e_bare) = finish
    base = 1e6 * s_bare / ns
    fin = {"sphere_us": base, "ellipsoid_us": 1e6 * e_bare / ne,
           "sphere_wall_us": 1e6 * (s_walls - s_bare) / ns, "ellipsoid_wall_us": 1e6 * (e_walls - e_bare) / ne}
    measured = {"sphere.contact_cost": costs["sphere"]["near_us"] / apart,
                "ellipsoid.contact_cost": costs["ellipsoid"]["near_us"] / apart,
                "ellipsoid.pass_cost": fin["ellipsoid_us"] / base,
                "sphere.wall_cost": fin["sphere_wall_us"] / base,
                "ellipsoid.wall_cost": fin["ellipsoid_wall_us"] / base}
    constants = {}
    for k in measured:
        shape, cost = k.split(".")
        constants[k] = float(getattr(BY_NAME[shape], cost))
    return {"scene": scene.name, "particles": scene.n, "skins": list(SKINS), "repeats": repeats, "calls": calls,
            "pairs": costs, "finish": fin, "measured_weights": measured, "constants": constants}


def report_lines(rep):
    """The report as lines for the terminal."""
    p, f = rep["pairs"], rep["finish"]
    lines = [f"pairs ({rep['scene']}, {rep['particles']} particles): sphere pair {p['sphere']['near_us']:.4f} us, "
             f"ellipsoid pair {p['ellipsoid']['near_us']:.4f} us (bounding spheres overlapping); apart "
             f"{p['sphere']['apart_us']:.4f} and {p['ellipsoid']['apart_us']:.4f} us",
             f"per-particle pass: sphere {f['sphere_us']:.4f} us, ellipsoid {f['ellipsoid_us']:.4f} us; a wall "
             f"contact adds {f['sphere_wall_us']:.4f} and {f['ellipsoid_wall_us']:.4f} us"]
    for k, v in rep["measured_weights"].items():
        lines.append(f"{k}: measured {v:.3g}, registered {rep['constants'][k]:g}")
    return lines
