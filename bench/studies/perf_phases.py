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

`--ceiling` asks what the machine itself lets each phase gain at T: T serial copies of the packed
scene at N / T particles each (spawned processes sharing nothing: bench.run.copies' ceiling, held
for the whole case and stepped in its rounds), meeting after every step as the threads meet at
the end of each phase, step in a third arm of each round. A phase's ceiling time in a step is the
slowest copy's (the threads' phase ends with its slowest thread), its ceiling speedup C = t1 / tC
(paired interval over the rounds) and its Karp-Flatt e(C) the serial fraction the machine alone
imposes: where two cores share memory bandwidth, caches or a host, a loop that streams memory
gains less than T from T independent copies, and no thread scheme can beat that. The threads'
share of it, tC / tT (paired interval), says how far the code is from the machine's ceiling.
The range cut and gather_list, all but empty in the serial mode, have ceilings as meaningless as
their speedups.

`--pin` binds each of numba's T threads to a CPU of its own before the modes are set up
(bench.run.binding, as `bench run --pin`; thread 0, which steps the serial mode too, on the
first), and the ceiling's copy c to thread c's CPU. perf.json's `affinity` records the binding,
pinned or not: each thread's CPU set at the start and after the last case (`after`), and whether
it held (`held`); `ceiling_cpus` each copy's CPU set as the copy read it.
"""
import copy
import os

import numba
import numpy as np

from bench.run.binding import establish, format_cpus, recheck, thread_cpu_sets
from bench.run.copies import HeldCopies, build_once
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


def _phase_copy(particles, skin, force, meeting):
    """One ceiling copy's set-up (PhaseCopies, bench.run.copies HeldCopies): the serial mode on its
    own packed scene of `particles`; its work steps it `steps` times (the command), meeting the
    other copies after every step, and answers [{phase: s}] a step. Its info: (the particles, the
    CPUs it may run on)."""
    scene = load_prepared("packed", particles=particles)
    mode = SerialMode().setup(scene, dt=choose_time_step(scene).dt, skin=skin)
    mode.warmup()
    step_phases(mode, True)   # untimed: the list's buffers reach their size
    done = [0]

    def work(steps):
        out = []
        for _ in range(steps):
            done[0] += 1
            out.append(step_phases(mode, force))
            meeting(done[0])
        return out
    return work, (scene.n, sorted(os.sched_getaffinity(0)))


class PhaseCopies:
    """`copies` serial copies of the packed scene at `particles` each (_phase_copy), held for a
    case's rounds: round(steps) steps them together and returns, a step, {phase: the slowest
    copy's time [s]} over the phases every copy timed in it. cpus [copies]: copy c on CPU cpus[c]
    (the CPU of pinned thread c), or None."""

    def __init__(self, copies, particles, skin, force, timeout=600, cpus=None):
        build_once("packed", particles)
        self.held = HeldCopies(copies, _phase_copy, (particles, skin, force), timeout, cpus=cpus)
        self.particles = self.held.info[0][0]
        self.cpus = [info[1] for info in self.held.info]

    def round(self, steps):
        per_copy = self.held.ask(steps)
        merged = []
        for k in range(steps):
            phases = set.intersection(*(set(c[k]) for c in per_copy))
            merged.append({ph: max(c[k][ph] for c in per_copy) for ph in phases})
        return merged

    def close(self):
        self.held.close()


def _modes(scene, dt, threads, scheme, skin):
    serial = SerialMode().setup(copy.deepcopy(scene), dt=dt, skin=skin)
    par = ThreadsMode().setup(copy.deepcopy(scene), dt=dt, threads=threads, scheme=scheme, skin=skin)
    serial.warmup()
    par.warmup()
    return serial, par


def measure(particles, threads, steps, repeats, scheme=DEFAULT_SCHEME, log=print, work=False, ceiling=False,
            pin=False):
    """The report: per case, per phase, t1 and tT [s] (medians), speedup and Karp-Flatt e; work: the
    T ranges on one thread instead (module docstring): t1, wT [s], the work inflation W and T / W;
    ceiling: also T serial copies at N / T particles each, each phase's ceiling speedup and the
    threads' share of it (module docstring); pin: the threads (and the copies) bound to a CPU each.
    The report's `affinity` records the binding either way."""
    if threads < 2:
        raise ValueError("--what phases needs --threads T >= 2")
    if work and ceiling:
        raise ValueError("--ceiling is for the speedups, not --work")
    scene = load_prepared("packed", particles=particles)
    dt = choose_time_step(scene).dt
    # bound (pin) and recorded before the modes allocate (first touch) and before any timing
    affinity = establish(threads, pin)
    cpus = thread_cpu_sets(affinity)
    log(f"# threads {'pinned to' if pin else 'unpinned, on'} CPUs {' '.join(format_cpus(c) for c in cpus)}")
    report = {"what": "phases", "particles": scene.n, "threads": threads, "scheme": scheme, "steps": steps,
              "repeats": repeats, "work": work, "ceiling": ceiling, "pinned": bool(pin), "cases": {}}
    for name, skin, force in CASES:
        serial, par = _modes(scene, dt, threads, scheme, skin)
        if work:   # after the warm-up at T threads: the T ranges one after another on one thread
            numba.set_num_threads(1)
            for mode in (serial, par):   # untimed: the one thread's scan buffers grow to its pairs
                step_phases(mode, True)
        copies = PhaseCopies(threads, max(1, scene.n // threads), skin, force,
                             cpus=[c[0] for c in cpus] if pin else None) if ceiling else None
        try:
            samples, rounds = _rounds((serial, par), copies, force, steps, repeats)
        finally:
            if copies is not None:
                copies.close()
        rows = {}
        for phase in PHASES:
            if phase not in samples[0] or phase not in samples[1]:
                continue
            t1, tt = float(np.median(samples[0][phase])), float(np.median(samples[1][phase]))
            row = work_row if work else phase_row
            rows[phase] = row(t1, tt, rounds[0][phase], rounds[1][phase], threads)
            if ceiling:
                rows[phase].update(ceiling_row(t1, tt, samples[2].get(phase), rounds[0][phase], rounds[1][phase],
                                               rounds[2].get(phase), threads))
        report["cases"][name] = rows
        if ceiling:
            report["ceiling_particles"] = copies.particles
            report["ceiling_cpus"] = [format_cpus(c) for c in copies.cpus]
        if work:
            _log_work(log, name, scene.n, threads, scheme, repeats, steps, rows)
            continue
        log(f"# {name}: {scene.n} packed ellipsoids, {threads} threads ({scheme}) against serial, "
            f"{repeats} alternating rounds of {steps} steps, medians; 95 % intervals paired over the rounds; "
            f"target: Karp-Flatt <= {TARGET_KARP_FLATT:g} (issue 32)")
        log(f"{'phase':12s} {'1 thread [ms]':>14s} {f'{threads} threads [ms]':>15s} {'speedup':>8s} "
            f"{'95 %':>16s} {'Karp-Flatt':>10s} {'95 %':>16s} {'verdict':10s}"
            + (f" {'ceiling':>8s} {'95 %':>16s} {'its K-F':>8s} {'of it':>6s} {'95 %':>16s}" if ceiling else ""))
        for phase, r in rows.items():
            log(f"{phase:12s} {1e3 * r['t1_s']:14.4f} {1e3 * r['tT_s']:15.4f} {r['speedup']:8.3f} "
                f"{format_interval(r['speedup_lo'], r['speedup_hi']):>16s} {r['karp_flatt']:10.3f} "
                f"{format_interval(r['karp_flatt_lo'], r['karp_flatt_hi']):>16s} {r['verdict']:10s}"
                + (f" {r['ceiling_speedup']:8.3f} {format_interval(r['ceiling_lo'], r['ceiling_hi']):>16s} "
                   f"{r['ceiling_karp_flatt']:8.3f} {r['of_ceiling']:6.3f} "
                   f"{format_interval(r['of_ceiling_lo'], r['of_ceiling_hi']):>16s}" if ceiling else ""))
        if ceiling:
            log(f"# ceiling: {threads} serial copies of {copies.particles} particles meeting every step, "
                f"a phase's time the slowest copy's; 'of it' = ceiling time / {threads}-thread time")
    report["affinity"] = recheck(affinity, threads, pin)
    if not report["affinity"]["held"]:
        log("# the threads' binding did not hold through the cases (perf.json affinity)")
    return report


def _rounds(modes, copies, force, steps, repeats):
    """Alternating rounds (module docstring): each round K steps of the serial mode, K of the
    threads mode, and K of the ceiling's copies where given. Returns (samples, rounds): per arm
    {phase: every step's time [s]} and {phase: [R] each round's median}."""
    arms = len(modes) + (copies is not None)
    samples = tuple({} for _ in range(arms))
    rounds = tuple({} for _ in range(arms))
    for _ in range(repeats):
        for k in range(arms):
            steps_here = (copies.round(steps) if k == len(modes) else
                          [step_phases(modes[k], force) for _ in range(steps)])
            here = {}
            for ph in steps_here:
                for phase, t in ph.items():
                    samples[k].setdefault(phase, []).append(t)
                    here.setdefault(phase, []).append(t)
            for phase, ts in here.items():
                rounds[k].setdefault(phase, []).append(float(np.median(ts)))
    return samples, rounds


def ceiling_row(t1, tt, steps_c, rounds1, roundsT, roundsC, threads):
    """One phase's ceiling (--ceiling): ceiling_s, the median of the copies' slowest time over every
    step (steps_c [s], None where the copies lack the phase), ceiling_speedup C = t1 / ceiling_s
    and its interval paired over the rounds (rounds1, roundsC [R]), its Karp-Flatt e(C), and the
    threads' share of it, of_ceiling = ceiling_s / tT (paired with roundsT); NaN without copies'
    times or where a round lacks the phase."""
    nan = float("nan")
    if not steps_c or not roundsC or len(roundsC) != len(rounds1):
        return {"ceiling_s": nan, "ceiling_speedup": nan, "ceiling_lo": nan, "ceiling_hi": nan,
                "ceiling_karp_flatt": nan, "of_ceiling": nan, "of_ceiling_lo": nan, "of_ceiling_hi": nan}
    tc = float(np.median(steps_c))
    c = t1 / tc if tc > 0 else nan
    lo, hi = ratio_interval(rounds1, roundsC)
    of_lo, of_hi = ratio_interval(roundsC, roundsT)
    return {"ceiling_s": tc, "ceiling_speedup": c, "ceiling_lo": lo, "ceiling_hi": hi,
            "ceiling_karp_flatt": karp_flatt(c, threads), "of_ceiling": tc / tt if tt > 0 else nan,
            "of_ceiling_lo": of_lo, "of_ceiling_hi": of_hi}


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

