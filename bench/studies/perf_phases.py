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
binning, scan), `carry` (the list put in gid order and its contact history carried over: the serial
mode sorts it and carries in dem.pairs PairList.set, the threads place it in gid order and carry as
they go, modes.parallel place_by_gid, inside their find_pairs; SerialMode.placing_s moves that part
here), `wall_list`,
`cut` (the threads' ranges of the list), `gather_list` (the gather's adjacency), `resolve`
(contact resolution), `finish` (gather, walls, integration, derived quantities, guard sums),
`decide` (the rebuild decision), `other` (the rest of a rebuild step), and `step` (the whole step).
For each: the median over every timed step of every round [s] at 1 and T threads, speedup S =
t1 / tT, and the Karp-Flatt serial fraction e = (1/S - 1/T) / (1 - 1/T) (Karp & Flatt 1990; 0 for
a phase that scales perfectly, 1 for one that does not scale at all, above 1 when threads slow it).

Each speedup comes with its 95 % interval, paired over the rounds (round r's medians at 1 and T
threads, stepped back to back: the Student interval of the rounds' log ratios,
bench.sweep.intervals.ratio_interval), and the serial fraction with the interval that maps to
(e falls as S grows: e_lo = e(S_hi), e_hi = e(S_lo)). Issue 32's target for every phase, e at most
TARGET_KARP_FLATT = 0.02, gets its verdict from that interval: met where e_hi <= 0.02, not met
where e_lo > 0.02, unresolved between (bench.sweep.intervals.verdict). A phase the threads have
and the serial mode lacks (cut, gather_list) has a speedup far below 1 and misses it by design of
the question: it is a serial phase the threads add.

`--work` asks what each phase costs at T ranges, whatever the cores: the threads mode keeps its T
ranges (every loop split T ways, every table and pass the T threads have) but numba runs them on
one thread (numba.set_num_threads(1): a prange over the T ranges then runs them one after another),
so each phase's time is the whole work of the T-range algorithm. Its ratio to the serial mode's
time, the work inflation W = w_T / t1 (paired interval over the rounds, as the speedups'), bounds
what T cores can give: a speedup of at most T / W, and a phase whose work grows with T (a table of
T x n entries, each thread passing over every particle) shows it here on 2 cores as it would on T.
Rounds alternate the serial mode and the T-range mode on one thread, as above, after one untimed
rebuild of both (under the dynamic scheme the one thread takes every chunk of the scan, and its
buffer grows to hold them); no verdict (issue 32 sets its targets on speedups).
"""
import copy

import numba
import numpy as np

from bench.run.prepare import load_prepared
from bench.sweep.intervals import format_interval, ratio_interval, verdict
from dem.timestep import choose_time_step
from modes.parallel import DEFAULT_SCHEME
from modes.serial import SerialMode
from modes.threads import ThreadsMode

PHASES = ("reorder", "derive", "find_pairs", "carry", "wall_list", "cut", "gather_list", "resolve", "finish",
          "decide", "other", "step")
CASES = (("skin 0.1", 0.1, False), ("skin 0.1, rebuild", 0.1, True), ("skin 0", 0.0, False))
# issue 32: every phase's Karp-Flatt serial fraction at most 0.02 (on 2 cores, 12k packed, skin 0.1 and 0)
TARGET_KARP_FLATT = 0.02


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


def measure(particles, threads, steps, repeats, scheme=DEFAULT_SCHEME, log=print, work=False):
    """The report: per case, per phase, t1 and tT [s] (medians), speedup and Karp-Flatt e; work: the
    T ranges on one thread instead (module docstring): t1, wT [s], the work inflation W and T / W."""
    if threads < 2:
        raise ValueError("--what phases needs --threads T >= 2")
    scene = load_prepared("packed", particles=particles)
    dt = choose_time_step(scene).dt
    report = {"what": "phases", "particles": scene.n, "threads": threads, "scheme": scheme, "steps": steps,
              "repeats": repeats, "work": work, "cases": {}}
    for name, skin, force in CASES:
        serial, par = _modes(scene, dt, threads, scheme, skin)
        if work:   # after the warm-up at T threads: the T ranges one after another on one thread
            numba.set_num_threads(1)
            for mode in (serial, par):   # untimed: the one thread's scan buffers grow to its pairs
                step_phases(mode, True)
        samples = ({}, {})
        rounds = ({}, {})   # {phase: [R] the round's median} at 1 and T threads
        for _ in range(repeats):  # alternating rounds: serial K steps, threads K steps
            for k, mode in enumerate((serial, par)):
                here = {}
                for _ in range(steps):
                    for phase, t in step_phases(mode, force).items():
                        samples[k].setdefault(phase, []).append(t)
                        here.setdefault(phase, []).append(t)
                for phase, ts in here.items():
                    rounds[k].setdefault(phase, []).append(float(np.median(ts)))
        rows = {}
        for phase in PHASES:
            if phase not in samples[0] or phase not in samples[1]:
                continue
            t1, tt = float(np.median(samples[0][phase])), float(np.median(samples[1][phase]))
            row = work_row if work else phase_row
            rows[phase] = row(t1, tt, rounds[0][phase], rounds[1][phase], threads)
        report["cases"][name] = rows
        if work:
            _log_work(log, name, scene.n, threads, scheme, repeats, steps, rows)
            continue
        log(f"# {name}: {scene.n} packed ellipsoids, {threads} threads ({scheme}) against serial, "
            f"{repeats} alternating rounds of {steps} steps, medians; 95 % intervals paired over the rounds; "
            f"target: Karp-Flatt <= {TARGET_KARP_FLATT:g} (issue 32)")
        log(f"{'phase':12s} {'1 thread [ms]':>14s} {f'{threads} threads [ms]':>15s} {'speedup':>8s} "
            f"{'95 %':>16s} {'Karp-Flatt':>10s} {'95 %':>16s} verdict")
        for phase, r in rows.items():
            log(f"{phase:12s} {1e3 * r['t1_s']:14.4f} {1e3 * r['tT_s']:15.4f} {r['speedup']:8.3f} "
                f"{format_interval(r['speedup_lo'], r['speedup_hi']):>16s} {r['karp_flatt']:10.3f} "
                f"{format_interval(r['karp_flatt_lo'], r['karp_flatt_hi']):>16s} {r['verdict']}")
    return report


def _log_work(log, name, n, threads, scheme, repeats, steps, rows):
    log(f"# {name}: {n} packed ellipsoids, the work of {threads} ranges ({scheme}) on one thread against serial, "
        f"{repeats} alternating rounds of {steps} steps, medians; 95 % intervals paired over the rounds")
    log(f"{'phase':12s} {'serial [ms]':>12s} {f'{threads} ranges [ms]':>15s} {'work x':>8s} {'95 %':>16s} "
        f"{'speedup at most':>16s}")
    for phase, r in rows.items():
        log(f"{phase:12s} {1e3 * r['t1_s']:12.4f} {1e3 * r['wT_s']:15.4f} {r['inflation']:8.3f} "
            f"{format_interval(r['inflation_lo'], r['inflation_hi']):>16s} {r['speedup_bound']:16.2f}")


def work_row(t1, wt, rounds1, roundsW, threads):
    """One phase's work report (--work): t1_s, wT_s (medians over every step [s]: serial, and the T
    ranges on one thread), the work inflation wT / t1 with its 95 % interval paired over the rounds,
    and the speedup T cores can give it at most, T / inflation."""
    w = wt / t1 if t1 > 0 else float("nan")
    lo, hi = ratio_interval(roundsW, rounds1)
    return {"t1_s": t1, "wT_s": wt, "inflation": w, "inflation_lo": lo, "inflation_hi": hi,
            "speedup_bound": threads / w if w > 0 else float("nan")}


def phase_row(t1, tt, rounds1, roundsT, threads):
    """One phase's report: t1_s, tT_s (medians over every step [s]), speedup t1 / tT and its 95 %
    interval paired over the rounds (rounds1, roundsT [R]: each round's median at 1 and T threads),
    karp_flatt and its interval (e falls as S grows: e(S_hi), e(S_lo)), and the verdict against
    TARGET_KARP_FLATT (lower is better)."""
    s = t1 / tt if tt > 0 else float("nan")
    lo, hi = ratio_interval(rounds1, roundsT)
    e_lo, e_hi = karp_flatt(hi, threads), karp_flatt(lo, threads)
    return {"t1_s": t1, "tT_s": tt, "speedup": s, "speedup_lo": lo, "speedup_hi": hi,
            "karp_flatt": karp_flatt(s, threads), "karp_flatt_lo": e_lo, "karp_flatt_hi": e_hi,
            "target_karp_flatt": TARGET_KARP_FLATT,
            "verdict": verdict(e_lo, e_hi, TARGET_KARP_FLATT, higher_is_better=False)}

