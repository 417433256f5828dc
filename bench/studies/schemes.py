"""`bench schemes`: Table 1 in kind, the contact-detection speedup of each thread scheme.

Yan & Regueiro (§4.2, Table 1; bench/studies/paper/table1_thread_schemes.csv) time contact
detection alone (neighbour estimate + contact resolution) on 2.5k packed ellipsoids at rest,
with 12 threads, relative to the serial n-by-n search. Here the same is done on the packed
scene (bench.run.prepare, cached) for: serial all-pairs, serial link-cell, and each of the five
schemes of modes/parallel.py at `--threads` T with both all-pairs and link-cell.

Timing: every configuration is set up on the one scene and warmed up (JIT compile, then one
untimed detection so buffers have their final size); then `--repeats` rounds time each
configuration once in turn (round-robin, so slow drift of the machine spreads over all of
them), and the medians over rounds are reported. Contact detection is
`neighbour_phase()` + `resolve_phase()`; neither moves particles, so every round repeats
identical work, and the neighbour phase is a run's rebuild: the particles' rotation matrices and
spins, derived once at set-up, are not derived again (in a run the step's per-particle pass
derives them).

Columns of OUT/schemes.csv:
- family, method, neighbor, threads, particles, shape, repeats: the configuration (family and
  the paper's pragma: serial, parallel, parallel-for);
- detect_s, neighbor_s, resolve_s: median wall times [s] of detection, neighbour estimate and
  contact resolution;
- speedup: T(serial all-pairs) / T(configuration), detection times, the paper's convention
  (so serial link-cell's speedup is the gain of the neighbour method, not of threads);
- efficiency: speedup / threads, i.e. also relative to serial ALL-PAIRS (a link-cell scheme
  may exceed 1 because of the neighbour method); efficiency_own = T(serial, same neighbour
  method) / (threads x T(configuration)), the parallel efficiency against its own serial;
- neighbor_eff_own, resolve_eff_own: the same per phase, neighbor_s(serial, same neighbour
  method) / (threads x neighbor_s) and resolve_s(serial, same neighbour method) / (threads x
  resolve_s) (1 for the serial rows), so that a scheme's loss is seen where it lies;
- efficiency_own_lo, _hi (and neighbor_eff_own_lo, _hi, resolve_eff_own_lo, _hi): the 95 %
  interval of each, paired over the rounds (round r's serial and threaded detections ran in the
  same round: the Student interval of the rounds' log ratios, bench.sweep.intervals.ratio_interval;
  empty for the serial rows, which are their own reference, and under 2 rounds). The interval is
  that of the geometric mean of the rounds' paired ratios; the point estimate beside it is the
  ratio of the medians, which may fall outside it where the rounds drift;
- target_eff_own, verdict: issue 32's target for efficiency_own at this thread count (TARGETS:
  link-cell 0.92 for partition, static and dynamic and 0.85 for frogleap and headtail, all-pairs
  dynamic 0.95, at 2 threads; link-cell 0.70 and all-pairs dynamic 11x, i.e. 11/16, at 16) and
  its verdict from the interval: met, not met or unresolved (bench.sweep.intervals.verdict);
  empty where the issue sets none;
- candidates, tests: candidate pairs found and pair tests made (per detection);
- work_imbalance: max/mean over threads of the pair tests (mode.tests; deterministic; 1 for
  serial); busy_imbalance: median over rounds of max/mean over threads of the busy cycles of
  both phases (scan_busy + busy; 1 for serial);
- paper_method, paper_threads, paper_speedup, paper_efficiency (= paper_speedup /
  paper_threads: 12 for the schemes, 1 for the serial rows): the paper's row matched to ours.
  The paper's threaded schemes loop n-by-n (link-cell is not threaded there), so they match our
  all-pairs scheme rows; its serial n-by-n and link-cell match our serial rows; our link-cell
  scheme rows have no paper row (NaN). The paper measured ellipsoids; the columns are filled
  whatever --shape is.

With --ceiling, the machine's own ceiling for each neighbour method at T, and each row's share of it:
- ceiling, ceiling_lo, _hi (neighbor_ceiling, resolve_ceiling per phase): T serial copies of the
  packed scene at N / T particles each (spawned processes sharing nothing, held for the rounds:
  bench.run.copies HeldCopies) run the serial detection of that neighbour method in a third arm
  of every round, each copy alone in turn and then all T together, meeting before each phase and
  after the last (the threads' phases end with a join); ceiling = median alone / median
  together, a copy's alone time the mean of the T copies', a phase's time together the slowest
  copy's; its interval paired over the rounds. It is the share of its solo speed a worker keeps
  when T work at once on exactly divided work at no cost of coordination: what the machine
  itself lets T workers reach (its cores, caches, memory and, on a VM, its host), which no thread
  scheme can beat but by doing less work;
- of_ceiling, of_ceiling_lo, _hi: efficiency_own / ceiling, paired over the rounds: how far the
  code is from the machine's ceiling;
- target_reachable: the target against the ceiling's interval (yes: the whole interval at or
  above the target; no: all below it, so that the target asks for more than the machine gives;
  unresolved: it straddles it); empty where no target is set.
The serial rows leave them empty (NaN).

With --pin each of numba's T threads is bound to a CPU of its own before anything is set up
(bench.run.binding, as `bench run --pin`: thread 0, which also runs the serial rows, on the
first), and the ceiling's copy c runs on thread c's CPU. Every row records the binding, pinned or
not: pinned (1 or 0), thread_cpus (each thread's CPU set at the start, in thread order),
binding_held (the same sets after the rounds, each pinned thread having run on its CPU:
bench.run.binding.recheck) and ceiling_cpus (each copy's CPU set as the copy read it).

OUT/schemes.png is drawn from the CSV afterwards (plotting only reads records).
"""
import csv
import math
import os
import sys
import time

import numpy as np
from bench.run.binding import establish, format_cpus, recheck, thread_cpu_sets
from bench.run.copies import HeldCopies, build_once
from bench.run.figure import plt
from bench.run.prepare import load_prepared
from bench.run.records import prepare_output
from bench.run.records import write_rows_csv
from bench.studies.paper import table_path
from bench.sweep.intervals import format_interval, ratio_interval, verdict
from dem.neighbor import HALF_SHELL_RUNS, CellGrid, scan_rows
from dem.timestep import choose_time_step
from modes.parallel import SCHEMES
from modes.serial import SerialMode
from modes.threads import ThreadsMode

PAPER_THREADS = 12
# paper Table 1 method -> (our method, our neighbour method)
PAPER_MAP = {"n-by-n": ("serial", "allpairs"), "link-cell": ("serial", "linkcell"),
             "partitioning": ("partition", "allpairs"), "frog-leap": ("frogleap", "allpairs"),
             "head-tail": ("headtail", "allpairs"), "static": ("static", "allpairs"),
             "dynamic": ("dynamic", "allpairs")}
FAMILY = {"serial": "serial", "partition": "parallel", "frogleap": "parallel", "headtail": "parallel",
          "static": "parallel-for", "dynamic": "parallel-for"}
COLUMNS = ["family", "method", "neighbor", "threads", "particles", "shape", "repeats", "detect_s", "neighbor_s",
           "resolve_s", "speedup", "efficiency", "efficiency_own", "efficiency_own_lo", "efficiency_own_hi",
           "neighbor_eff_own", "neighbor_eff_own_lo", "neighbor_eff_own_hi", "resolve_eff_own", "resolve_eff_own_lo",
           "resolve_eff_own_hi", "target_eff_own", "verdict", "candidates", "tests", "work_imbalance",
           "busy_imbalance", "paper_method", "paper_threads", "paper_speedup", "paper_efficiency", "ceiling",
           "ceiling_lo", "ceiling_hi", "neighbor_ceiling", "resolve_ceiling", "of_ceiling", "of_ceiling_lo",
           "of_ceiling_hi", "target_reachable", "ceiling_particles", "ceiling_cpus", "pinned", "thread_cpus",
           "binding_held"]
CEILING = ("ceiling", "ceiling_lo", "ceiling_hi", "neighbor_ceiling", "resolve_ceiling", "of_ceiling", "of_ceiling_lo",
           "of_ceiling_hi")
REACHABLE = {"met": "yes", "not met": "no", "unresolved": "unresolved"}
NEIGHBORS = ("allpairs", "linkcell")
# issue 32's targets for efficiency_own, {threads: {(method, neighbour): target}}: on 2 cores the
# link-cell detection of the schemes that split the gid-sorted list (partition, static, dynamic)
# 0.92 and of those that store every pair's forces (frogleap, headtail) 0.85, all-pairs dynamic
# 0.95; on 16 cores link-cell 0.70 and all-pairs dynamic 11x serial all-pairs (the paper's 11.15x
# at 12 threads: Yan & Regueiro, Table 1), i.e. 11/16 of its own serial
TARGETS = {2: {("partition", "linkcell"): 0.92, ("static", "linkcell"): 0.92, ("dynamic", "linkcell"): 0.92,
               ("frogleap", "linkcell"): 0.85, ("headtail", "linkcell"): 0.85, ("dynamic", "allpairs"): 0.95},
           16: {**{(s, "linkcell"): 0.70 for s in SCHEMES}, ("dynamic", "allpairs"): 11.0 / 16.0}}


def paper_table_path():
    """The paper's Table 1 as CSV (package data: bench/studies/paper/table1_thread_schemes.csv)."""
    return table_path("table1_thread_schemes.csv")


def read_paper_table(path=None):
    """{(our method, neighbour): (paper method, paper threads, paper speedup)} from the paper's
    Table 1 CSV (columns family, method, speedup; '#' lines are comments), or None if missing."""
    path = path or paper_table_path()
    if not os.path.exists(path):
        return None
    out = {}
    with open(path, newline="") as fh:
        for row in csv.DictReader(line for line in fh if line.strip() and not line.lstrip().startswith("#")):
            method = row["method"].strip()
            if method in PAPER_MAP:
                threads = 1 if row["family"].strip() == "serial" else PAPER_THREADS
                out[PAPER_MAP[method]] = (method, threads, float(row["speedup"]))
    return out


def _ratio(a):
    a = np.asarray(a, dtype=np.float64)
    return float(a.max() / a.mean()) if a.size and a.mean() > 0 else 1.0


def configurations():
    """(method, neighbour) in table order: the two serial rows, then each scheme x neighbour."""
    return [("serial", nb) for nb in NEIGHBORS] + [(s, nb) for s in SCHEMES for nb in NEIGHBORS]


def _setup(scene, dt, method, neighbor, threads):
    if method == "serial":
        mode = SerialMode().setup(scene, dt=dt, neighbor=neighbor, skin=0.0)
    else:
        mode = ThreadsMode().setup(scene, dt=dt, neighbor=neighbor, threads=threads, scheme=method, skin=0.0)
    mode.warmup()
    pi, pj = mode.neighbour_phase()  # untimed: buffers reach their final size
    mode.resolve_phase(pi, pj)
    # the particles do not move, so the rotations and spins that detection derived stay current: a
    # timed neighbour phase derives none, as a run's rebuild does not (the step's pass derived them:
    # SerialMode.build_list); timed, they were ~5 % of the phase (52 us of 2500 ellipsoids' ~1 ms)
    mode.owned_derived = True
    return mode


def _detect(mode):
    """One timed contact detection: (neighbour s, resolution s, candidates, busy imbalance)."""
    threaded = hasattr(mode, "scan_busy")
    if threaded:
        import numba
        numba.set_num_threads(mode.threads)
    t0 = time.perf_counter()
    pi, pj = mode.neighbour_phase()
    t1 = time.perf_counter()
    mode.resolve_phase(pi, pj)
    t2 = time.perf_counter()
    busy = _ratio(mode.scan_busy + mode.busy) if threaded else 1.0
    return t1 - t0, t2 - t1, len(pi), busy


def _detection_copy(particles, shape, meeting):
    """One ceiling copy's set-up (DetectionCeiling, bench.run.copies HeldCopies): the serial
    detection of each neighbour method on its own packed scene of `particles` (_setup). Its work
    (the command: in_step) runs one detection of each, meeting the other copies before each phase
    and after the last where in_step, and answers {neighbour: (neighbour estimate s, resolution s)}.
    Its info: (the particles, the CPUs it may run on)."""
    scene = load_prepared("packed", particles=particles, shape=shape)
    dt = choose_time_step(scene).dt
    modes = {nb: _setup(scene, dt, "serial", nb, 1) for nb in NEIGHBORS}
    met = [0]

    def meet(in_step):
        if in_step:
            met[0] += 1
            meeting(met[0])

    def work(in_step):
        out = {}
        for nb, mode in modes.items():
            meet(in_step)
            t0 = time.perf_counter()
            pi, pj = mode.neighbour_phase()
            t1 = time.perf_counter()
            meet(in_step)
            t2 = time.perf_counter()
            mode.resolve_phase(pi, pj)
            out[nb] = (t1 - t0, time.perf_counter() - t2)
        meet(in_step)
        return out
    return work, (scene.n, sorted(os.sched_getaffinity(0)))


class DetectionCeiling:
    """--ceiling's arm: `threads` serial copies of the packed scene at particles / threads each
    (_detection_copy), held for the rounds. round() runs one detection of each neighbour method on
    each copy alone, in turn, then on all of them together, and returns {neighbour: (alone, together)},
    each [neighbour estimate s, resolution s]: alone the mean over the copies (their CPUs may differ),
    together the slowest copy's per phase. cpus [threads]: copy c on CPU cpus[c] (the CPU of pinned
    thread c), or None."""

    def __init__(self, threads, particles, shape, cpus=None):
        share = max(1, particles // threads)
        build_once("packed", share, shape)
        self.held = HeldCopies(threads, _detection_copy, (share, shape), cpus=cpus)
        self.copies = threads
        self.particles = self.held.info[0][0]
        self.cpus = [info[1] for info in self.held.info]   # each copy's CPUs (the proof of --pin)

    def round(self):
        alone = [self.held.ask(False, [c])[0] for c in range(self.copies)]
        together = self.held.ask(True)
        return {nb: ([sum(a[nb][k] for a in alone) / self.copies for k in (0, 1)],
                     [max(t[nb][k] for t in together) for k in (0, 1)]) for nb in NEIGHBORS}

    def close(self):
        self.held.close()


def measure(scene, dt, threads, repeats, shape, log=None, ceiling=False, cpus=None):
    """Rows (dicts, COLUMNS without the paper columns and the binding's) of every configuration;
    ceiling: with the machine's ceiling at T (module docstring), its copies on cpus [T] where given
    (the pinned threads' CPUs)."""
    confs = configurations()
    modes = []
    for method, nb in confs:
        if log:
            log(f"warming up {method} {nb}")
        modes.append(_setup(scene, dt, method, nb, threads))
    samples = [[] for _ in confs]
    copies = None
    if ceiling:
        if log:
            log(f"starting {threads} ceiling copies at {max(1, scene.n // threads)} particles")
        copies = DetectionCeiling(threads, scene.n, shape, cpus)
    ceiling_rounds = []
    try:
        for r in range(repeats):
            for k, mode in enumerate(modes):
                samples[k].append(_detect(mode))
            if copies is not None:
                ceiling_rounds.append(copies.round())
    finally:
        if copies is not None:
            copies.close()
    rows = []
    for (method, nb), mode, smp in zip(confs, modes, samples):
        t_nb = np.array([s[0] for s in smp])
        t_res = np.array([s[1] for s in smp])
        threaded = method != "serial"
        tests = mode.tests if threaded else None
        rows.append({"family": FAMILY[method], "method": method, "neighbor": nb,
                     "threads": threads if threaded else 1, "particles": scene.n, "shape": shape,
                     "repeats": repeats,
                     "detect_s": float(np.median(t_nb + t_res)), "neighbor_s": float(np.median(t_nb)),
                     "resolve_s": float(np.median(t_res)), "candidates": int(smp[-1][2]),
                     "tests": int(tests.sum()) if threaded else _serial_tests(mode),
                     "work_imbalance": _ratio(tests) if threaded else 1.0,
                     "busy_imbalance": float(np.median([s[3] for s in smp]))})
    serial = {nb: next(r for r in rows if r["method"] == "serial" and r["neighbor"] == nb) for nb in NEIGHBORS}
    rounds = {conf: _round_times(smp) for conf, smp in zip(confs, samples)}
    for r in rows:
        own = serial[r["neighbor"]]
        r["speedup"] = serial["allpairs"]["detect_s"] / r["detect_s"]
        r["efficiency"] = r["speedup"] / r["threads"]
        r["efficiency_own"] = own["detect_s"] / (r["threads"] * r["detect_s"])
        r["neighbor_eff_own"] = own["neighbor_s"] / (r["threads"] * r["neighbor_s"])
        r["resolve_eff_own"] = own["resolve_s"] / (r["threads"] * r["resolve_s"])
        r.update(efficiency_intervals(rounds[("serial", r["neighbor"])], rounds[(r["method"], r["neighbor"])],
                                      r["threads"]) if r["method"] != "serial" else
                 {f"{k}_{e}": math.nan for k in ("efficiency_own", "neighbor_eff_own", "resolve_eff_own")
                  for e in ("lo", "hi")})
        target = TARGETS.get(r["threads"], {}).get((r["method"], r["neighbor"]), math.nan)
        r["target_eff_own"] = target
        r["verdict"] = "" if math.isnan(target) else verdict(r["efficiency_own_lo"], r["efficiency_own_hi"], target)
        r.update(ceiling_columns(r, rounds[("serial", r["neighbor"])], rounds[(r["method"], r["neighbor"])],
                                 ceiling_rounds))
        r["ceiling_particles"] = copies.particles if copies is not None else ""
        r["ceiling_cpus"] = " ".join(format_cpus(c) for c in copies.cpus) if copies is not None else ""
    return rows


def ceiling_columns(row, own, mine, ceiling_rounds):
    """A row's --ceiling columns (module docstring) from the rounds: own, mine (_round_times of the
    serial row of its neighbour method and of this row) and ceiling_rounds (DetectionCeiling.round
    of each round; empty without --ceiling). NaN for the serial rows and without copies;
    target_reachable empty where no target is set."""
    out = {k: math.nan for k in CEILING}
    out["target_reachable"] = ""
    if not ceiling_rounds or row["method"] == "serial":
        return out
    nb, threads = row["neighbor"], row["threads"]
    alone = np.array([c[nb][0] for c in ceiling_rounds])      # [R, phase]
    together = np.array([c[nb][1] for c in ceiling_rounds])
    a_det, t_det = alone.sum(axis=1), together.sum(axis=1)
    out["ceiling"] = float(np.median(a_det) / np.median(t_det))
    out["ceiling_lo"], out["ceiling_hi"] = ratio_interval(a_det, t_det)
    out["neighbor_ceiling"] = float(np.median(alone[:, 0]) / np.median(together[:, 0]))
    out["resolve_ceiling"] = float(np.median(alone[:, 1]) / np.median(together[:, 1]))
    out["of_ceiling"] = row["efficiency_own"] / out["ceiling"]
    # round r's efficiency over its ceiling: t_serial t_together / (T t_threads t_alone)
    out["of_ceiling_lo"], out["of_ceiling_hi"] = ratio_interval(own["detect"] * t_det, mine["detect"] * a_det,
                                                                1.0 / threads)
    if not math.isnan(row["target_eff_own"]):
        out["target_reachable"] = REACHABLE[verdict(out["ceiling_lo"], out["ceiling_hi"], row["target_eff_own"])]
    return out


def binding_columns(affinity):
    """The binding's columns of every row: pinned (1: --pin bound each thread to a CPU of its own,
    0: where the OS put them), thread_cpus (each thread's CPU set at the start, in thread order:
    the proof), binding_held (1: the same sets after the rounds, each pinned thread having run on
    its CPU: bench.run.binding.recheck)."""
    cpus = " ".join(format_cpus(c) for c in thread_cpu_sets(affinity))
    return {"pinned": int(affinity["pinned"]), "thread_cpus": cpus, "binding_held": int(affinity["held"])}


def _round_times(samples):
    """{detect, neighbor, resolve: [R] times [s]} of one configuration's rounds (_detect samples)."""
    nb = np.array([s[0] for s in samples])
    res = np.array([s[1] for s in samples])
    return {"detect": nb + res, "neighbor": nb, "resolve": res}


def efficiency_intervals(own, mine, threads):
    """The 95 % intervals of a threaded row's efficiency against its own serial, of detection and of
    each phase, paired over the rounds (own, mine: _round_times of the serial row of the same
    neighbour method and of this row; bench.sweep.intervals.ratio_interval): efficiency_own_lo, _hi,
    neighbor_eff_own_lo, _hi, resolve_eff_own_lo, _hi."""
    out = {}
    for key, phase in (("efficiency_own", "detect"), ("neighbor_eff_own", "neighbor"), ("resolve_eff_own", "resolve")):
        out[f"{key}_lo"], out[f"{key}_hi"] = ratio_interval(own[phase], mine[phase], 1.0 / threads)
    return out


def _serial_tests(mode):
    """Pair tests of a serial neighbour estimate: n(n-1)/2 for all-pairs, counted for link-cell."""
    s = mode.state
    grid = CellGrid(mode.neighbor, s.pos, s.rbound, s.gid)
    rows = np.arange(s.n, dtype=np.int64)
    empty = np.empty(0, dtype=np.int64)
    return int(scan_rows(rows, 0, s.n, grid.arrays, HALF_SHELL_RUNS, s.n_owned, empty, empty, 0)[1])


def add_paper(rows, paper):
    for r in rows:
        m = (paper or {}).get((r["method"], r["neighbor"]))
        r["paper_method"] = m[0] if m else ""
        r["paper_threads"] = m[1] if m else ""
        r["paper_speedup"] = m[2] if m else math.nan
        r["paper_efficiency"] = m[2] / m[1] if m else math.nan
    return rows


def write_csv(path, rows):
    write_rows_csv(path, rows, COLUMNS)


def read_csv(path):
    """schemes.csv rows with numbers parsed (empty -> NaN)."""
    num = {"threads", "particles", "repeats", "detect_s", "neighbor_s", "resolve_s", "speedup", "efficiency",
           "efficiency_own", "efficiency_own_lo", "efficiency_own_hi", "neighbor_eff_own", "neighbor_eff_own_lo",
           "neighbor_eff_own_hi", "resolve_eff_own", "resolve_eff_own_lo", "resolve_eff_own_hi", "target_eff_own",
           "candidates", "tests", "work_imbalance", "busy_imbalance", "paper_threads", "paper_speedup",
           "paper_efficiency", "ceiling_particles", "pinned", "binding_held", *CEILING}
    with open(path, newline="") as fh:
        return [{k: (float(v) if v not in ("", None) else math.nan) if k in num else v for k, v in r.items()}
                for r in csv.DictReader(fh)]


def format_table(rows):
    head = (f"{'method':10s} {'neighbor':8s} {'T':>2s} {'detect ms':>10s} {'nbr ms':>9s} {'res ms':>9s} "
            f"{'speedup':>8s} {'eff':>6s} {'eff_own':>7s} {'nbr_own':>7s} {'res_own':>7s} {'work_imb':>8s} "
            f"{'busy_imb':>8s} "
            f"{'paper':>6s} {'paper_eff':>9s}  {'eff_own 95 %':>14s} {'target':>6s} verdict")
    lines = [head]
    for r in rows:
        ps = "" if math.isnan(r["paper_speedup"]) else f"{r['paper_speedup']:.2f}"
        pe = "" if math.isnan(r["paper_efficiency"]) else f"{r['paper_efficiency']:.3f}"
        ci = format_interval(r.get("efficiency_own_lo", math.nan), r.get("efficiency_own_hi", math.nan))
        tg = r.get("target_eff_own", math.nan)
        tg = "" if math.isnan(tg) else f"{tg:.3g}"
        vd = r.get("verdict", "")
        vd = "" if not isinstance(vd, str) else vd
        lines.append(f"{r['method']:10s} {r['neighbor']:8s} {int(r['threads']):2d} {1e3 * r['detect_s']:10.2f} "
                     f"{1e3 * r['neighbor_s']:9.2f} {1e3 * r['resolve_s']:9.2f} {r['speedup']:8.2f} "
                     f"{r['efficiency']:6.3f} {r['efficiency_own']:7.3f} {r['neighbor_eff_own']:7.3f} "
                     f"{r['resolve_eff_own']:7.3f} {r['work_imbalance']:8.3f} "
                     f"{r['busy_imbalance']:8.3f} {ps:>6s} {pe:>9s}  {ci:>14s} {tg:>6s} {vd}")
    return lines


def format_ceiling(rows):
    """--ceiling's table: each threaded row's efficiency against its own serial, the machine's
    ceiling for its neighbour method (and per phase), its share of it, and whether its target is
    within the ceiling."""
    lines = [f"{'method':10s} {'neighbor':8s} {'eff_own':>7s} {'ceiling':>7s} {'95 %':>16s} {'nbr':>6s} {'res':>6s} "
             f"{'of_ceil':>7s} {'95 %':>16s} {'target':>6s} reachable"]
    for r in rows:
        if r["method"] == "serial":
            continue
        tg = "" if math.isnan(r["target_eff_own"]) else f"{r['target_eff_own']:.3g}"
        lines.append(f"{r['method']:10s} {r['neighbor']:8s} {r['efficiency_own']:7.3f} {r['ceiling']:7.3f} "
                     f"{format_interval(r['ceiling_lo'], r['ceiling_hi']):>16s} {r['neighbor_ceiling']:6.3f} "
                     f"{r['resolve_ceiling']:6.3f} {r['of_ceiling']:7.3f} "
                     f"{format_interval(r['of_ceiling_lo'], r['of_ceiling_hi']):>16s} {tg:>6s} "
                     f"{r['target_reachable'] if isinstance(r['target_reachable'], str) else ''}")
    return lines


def plot_schemes(csv_path, png_path):
    """Grouped bars of parallel efficiency (speedup / threads, vs serial all-pairs) per scheme:
    ours with all-pairs and link-cell beside the paper's (12 threads, n-by-n); read from the CSV."""
    rows = read_csv(csv_path)
    get = {(r["method"], r["neighbor"]): r for r in rows}
    n, shape = int(rows[0]["particles"]), rows[0]["shape"]
    threads = int(next(r["threads"] for r in rows if r["method"] != "serial"))
    x = np.arange(len(SCHEMES))
    w = 0.27
    fig, ax = plt.subplots(figsize=(7.6, 4.4))
    series = [(f"ours, all-pairs, {threads} threads", [get[(s, "allpairs")]["efficiency"] for s in SCHEMES], "C0"),
              (f"ours, link-cell, {threads} threads", [get[(s, "linkcell")]["efficiency"] for s in SCHEMES], "C1"),
              (f"paper, n-by-n, {PAPER_THREADS} threads",
               [get[(s, "allpairs")]["paper_efficiency"] for s in SCHEMES], "0.55")]
    top = 1.0
    for k, (label, vals, color) in enumerate(series):
        vals = np.asarray(vals, dtype=float)
        if np.all(np.isnan(vals)):
            label += " (table missing)"
        bars = ax.bar(x + (k - 1) * w, np.nan_to_num(vals), w, label=label, color=color)
        for b, v in zip(bars, vals):
            if not math.isnan(v):
                ax.text(b.get_x() + b.get_width() / 2, v, f"{v:.2f}", ha="center", va="bottom", fontsize=7)
        top = max(top, np.nanmax(vals) if not np.all(np.isnan(vals)) else 0.0)
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="all-pairs ideal (speedup = threads)")
    lc = get.get(("serial", "linkcell"))
    if lc is not None:
        ax.axhline(lc["speedup"], color="C1", lw=0.8, ls="--",
                   label=f"link-cell ideal: ours, serial link-cell speedup ({lc['speedup']:.2f})")
        top = max(top, lc["speedup"])
    ax.set_xticks(x)
    ax.set_xticklabels(SCHEMES)
    ax.set_ylim(0, 1.25 * top)
    ax.set_ylabel("efficiency = speedup / threads\n(speedup vs serial all-pairs)")
    ax.set_title(f"Contact detection (Table 1 in kind): {n} packed {shape}s, ours {threads} threads, "
                 f"paper {PAPER_THREADS}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", ncol=2)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


def schemes(args):
    """Measure, write OUT/schemes.csv, draw OUT/schemes.png from it, print the table."""
    prepare_output(args.out)

    def log(msg):
        print(f"bench schemes: {msg}", file=sys.stderr, flush=True)

    paper = read_paper_table()
    if paper is None:
        print(f"bench schemes: paper table {os.path.normpath(paper_table_path())} not found; "
              f"paper columns left NaN", file=sys.stderr)
    scene = load_prepared("packed", particles=args.particles, shape=args.shape, log=log)
    dt = choose_time_step(scene).dt
    ceiling = getattr(args, "ceiling", False)
    pin = getattr(args, "pin", False)
    # bound (--pin) and recorded before the modes allocate (first touch) and before any timing
    affinity = establish(args.threads, pin)
    cpus = thread_cpu_sets(affinity)
    log(f"threads {'pinned to' if pin else 'on'} CPUs {' '.join(format_cpus(c) for c in cpus)}")
    rows = measure(scene, dt, args.threads, args.repeats, args.shape, log=log, ceiling=ceiling,
                   cpus=[c[0] for c in cpus] if pin else None)
    affinity = recheck(affinity, args.threads, pin)
    for r in rows:
        r.update(binding_columns(affinity))
    add_paper(rows, paper)
    csv_path = os.path.join(args.out, "schemes.csv")
    write_csv(csv_path, rows)
    plot_schemes(csv_path, os.path.join(args.out, "schemes.png"))
    print("--- Table 1 in kind")
    print(f"contact detection (neighbour estimate + resolution), {scene.n} packed {args.shape}s, "
          f"median of {args.repeats}; speedup vs serial all-pairs; eff = speedup/T; eff_own vs serial of the "
          f"same neighbour method (nbr_own, res_own: per phase), its 95 % interval paired over the rounds and "
          f"its verdict against issue 32's target; paper: {PAPER_THREADS} threads, n-by-n; threads "
          f"{'pinned to' if pin else 'unpinned, on'} CPUs {rows[0]['thread_cpus']}"
          f"{'' if rows[0]['binding_held'] else ' (the binding did not hold through the rounds)'}")
    table = read_csv(csv_path)
    for line in format_table(table):
        print(line)
    if ceiling:
        print(f"--- against the machine's ceiling: {args.threads} serial copies of {int(rows[0]['ceiling_particles'])} "
              f"particles, alone and together (ceiling = alone / together; of_ceil = eff_own / ceiling; both "
              f"paired over the {args.repeats} rounds)")
        for line in format_ceiling(table):
            print(line)
    print(f"wrote {csv_path} and schemes.png")
    return 0
