"""`bench perf --what phases --threads T [--particles N] [--steps K] [--repeats R]`: every phase of a
step at one thread and at T, its speedup and its Karp-Flatt serial fraction (issue 32).

A thread mode gains only what each phase gains: one phase left on one thread caps the whole step
(Amdahl). Here the serial mode (the one-thread reference, no thread machinery) and the threads mode
(`--scheme`, default dynamic) step twins of the same rested packed ellipsoids side by side, in
rounds that alternate (serial K steps, threads K steps, ...), so both do the same work on the same
trajectory (bit-identical modes) and slow drift of the machine falls on both. Three cases:

- `skin 0.1`: the default neighbour list, the steps between its rebuilds (resolution, the
  per-particle pass, the decision);
- `skin 0.1, rebuild`: the same list rebuilt every step (a rebuild is forced; the list is a superset
  of the touching pairs, so the trajectory does not change): the rebuild's phases;
- `skin 0`: the paper's every-step neighbour estimate (no re-sort, no skin).

Phases (modes/serial.py step and build_list, timed at the orchestration level): `reorder` (the
rebuild's re-sort), `derive` (rotations of the rebuild), `find_pairs` (the neighbour estimate:
binning, scan, compaction), `carry` (the list's contact history carried over), `wall_list`,
`cut` (the threads' ranges of the list), `gather_list` (the gather's adjacency), `resolve`
(contact resolution), `finish` (gather, walls, integration, derived quantities, guard sums),
`decide` (the rebuild decision), `other` (the rest of a rebuild step), and `step` (the whole step).
For each: the median over every timed step of every round [s] at 1 and T threads, speedup S =
t1 / tT, and the Karp-Flatt serial fraction e = (1/S - 1/T) / (1 - 1/T) (Karp & Flatt 1990; 0 for
a phase that scales perfectly, 1 for one that does not scale at all, above 1 when threads slow it).
"""
import copy

import numpy as np

from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from modes.parallel import DEFAULT_SCHEME
from modes.serial import SerialMode
from modes.threads import ThreadsMode

PHASES = ("reorder", "derive", "find_pairs", "carry", "wall_list", "cut", "gather_list", "resolve", "finish",
          "decide", "other", "step")
CASES = (("skin 0.1", 0.1, False), ("skin 0.1, rebuild", 0.1, True), ("skin 0", 0.0, False))


def karp_flatt(speedup, p):
    """(1/S - 1/p) / (1 - 1/p), the experimentally determined serial fraction; NaN for p = 1."""
    if p <= 1 or not speedup > 0:
        return float("nan")
    return (1.0 / speedup - 1.0 / p) / (1.0 - 1.0 / p)


def step_phases(mode, force):
    """One step of mode, returning {phase: seconds}; force: rebuild the list this step."""
    if force:
        mode.rebuild_next = True
    row = mode.step()
    out = {"step": row["totalT"], "resolve": row["resolveT"], "finish": mode.finish_s}
    if row["neighbor_rebuilt"]:
        out["reorder"] = mode.reorder_s
        out.update(mode.build_phases)
        out["other"] = row["neighborT"] - mode.reorder_s - sum(mode.build_phases.values())
    out["decide"] = row["totalT"] - row["neighborT"] - row["resolveT"] - mode.finish_s
    return out


def _modes(scene, dt, threads, scheme, skin):
    serial = SerialMode().setup(copy.deepcopy(scene), dt=dt, skin=skin)
    par = ThreadsMode().setup(copy.deepcopy(scene), dt=dt, threads=threads, scheme=scheme, skin=skin)
    serial.warmup()
    par.warmup()
    return serial, par


def measure(particles, threads, steps, repeats, scheme=DEFAULT_SCHEME, log=print):
    """The report: per case, per phase, t1 and tT [s] (medians), speedup and Karp-Flatt e."""
    if threads < 2:
        raise ValueError("--what phases needs --threads T >= 2")
    scene = load_prepared("packed", particles=particles)
    dt = choose_time_step(scene).dt
    report = {"what": "phases", "particles": scene.n, "threads": threads, "scheme": scheme, "steps": steps,
              "repeats": repeats, "cases": {}}
    for name, skin, force in CASES:
        serial, par = _modes(scene, dt, threads, scheme, skin)
        samples = ({}, {})
        for _ in range(repeats):  # alternating rounds: serial K steps, threads K steps
            for k, mode in enumerate((serial, par)):
                for _ in range(steps):
                    for phase, t in step_phases(mode, force).items():
                        samples[k].setdefault(phase, []).append(t)
        rows = {}
        for phase in PHASES:
            if phase not in samples[0] or phase not in samples[1]:
                continue
            t1, tt = float(np.median(samples[0][phase])), float(np.median(samples[1][phase]))
            s = t1 / tt if tt > 0 else float("nan")
            rows[phase] = {"t1_s": t1, "tT_s": tt, "speedup": s, "karp_flatt": karp_flatt(s, threads)}
        report["cases"][name] = rows
        log(f"# {name}: {scene.n} packed ellipsoids, {threads} threads ({scheme}) against serial, "
            f"{repeats} alternating rounds of {steps} steps, medians")
        log(f"{'phase':12s} {'1 thread [ms]':>14s} {f'{threads} threads [ms]':>15s} {'speedup':>8s} "
            f"{'Karp-Flatt':>10s}")
        for phase, r in rows.items():
            log(f"{phase:12s} {1e3 * r['t1_s']:14.4f} {1e3 * r['tT_s']:15.4f} {r['speedup']:8.3f} "
                f"{r['karp_flatt']:10.3f}")
    return report
