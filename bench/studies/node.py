"""`bench node [--cores C] --out DIR`: the many-core check of one node in one command (issue 32).

The question this harness answers lives on nodes of 16-128 cores. This study runs, on the node it
is started on, what decides how a step should be split there:

1. an unpinned sweep of the paper's Table 4 in kind on rested packed ellipsoids (default 12k):
   C/4 threads, C threads, the hybrids 2 x C/2, 4 x C/4, 8 x C/8 (those that divide C), C/4 ranks
   and C ranks (mappings(); at C = 16 exactly 1-1-1-1-4, 1-1-1-1-16, 2-2-1-1-8, 4-2-2-1-4,
   8-2-2-2-2, 4-2-2-1-1, 16-4-2-2-1), into DIR/unpinned;
2. the same scene pinned (`--pin`, bench.run.binding) with the machine's ceiling (`--ceiling`:
   C serial copies sharing nothing, and meeting every step) for C threads, 4 x C/4 and C ranks,
   into DIR/pinned;
3. Table 1 in kind at C threads (`bench schemes --ceiling`, 2.5k packed ellipsoids: beside it C
   serial copies at 2.5k / C detect alone and together, the machine's own ceiling), into
   DIR/schemes;
4. the ghosts' forward exchange at C ranks by messages against the shared-memory window, on the
   same scene, alternating inside MPI jobs (`bench perf --what forward`, bench.studies.perf_forward),
   into DIR/forward: the window's case is a rank with many neighbours on one node, which 2 cores
   cannot show;

(each part within its own time limit, by default 160 + 160 + 50 + 75 s; the first three took 3-5
minutes on a lent 16-core machine), then writes DIR/verdict.md: each comparison the issue sets a
target for, as a ratio measured within one sweep, beside the target and the repeats' spread of the
two times (a ratio closer to 1 than the larger spread is called a tie), the CPUs Table 1's
threads ran on (schemes.csv's record of the binding), and the forward exchange's ranking with
its 95 % interval over the jobs. Every part has its own time limit, so that a part that
runs long leaves the others their time (past it the part gets SIGTERM, on which it stops its own
runs and MPI jobs, and SIGKILL PART_GRACE_S later); what did not finish is named in the verdict.
The figures are each sweep's own (efficiency.png, modules.png, ...) and DIR/schemes/schemes.png.
"""
import math
import os
import statistics
import subprocess
import sys

import pandas as pd

from bench.run.records import environment, read_json_file
from bench.sweep.intervals import format_interval, verdict as interval_verdict

# issue 32's targets on C cores
TARGET_THREADS_VS_RANKS = 1.10   # C/4 and C threads within 10 % of as many ranks' step time
TARGET_RESOLVE = 1.10            # the threads' contact resolution within 10 % of the ranks' at C/4
TARGET_SLOWEST_THREAD = 1.05     # the slowest thread within 5 % of the mean
TARGET_CEILING = 0.90            # C ranks at >= 0.9 of the in-step ceiling
TARGET_PIN = 1.0                 # pinned at least as fast as unpinned
TARGET_DYNAMIC_SPEEDUP = 11.0    # Table 1 dynamic all-pairs at 16 threads (the paper: 11.15x at 12)
TARGET_LINKCELL_EFF = 0.70       # link-cell detection efficiency against its own serial
PART_GRACE_S = 20                # seconds a part past its limit has to stop its processes after SIGTERM


def grid(procs):
    """The block grid of P ranks: P factored into px >= py >= pz as evenly as possible (16: 4x2x2)."""
    best = None
    for px in range(1, procs + 1):
        for py in range(1, px + 1):
            if procs % (px * py):
                continue
            pz = procs // (px * py)
            if pz > py:
                continue
            key = (max(px, py, pz) - min(px, py, pz), -px)
            if best is None or key < best[0]:
                best = (key, (px, py, pz))
    return best[1]


def mapping(procs, threads):
    px, py, pz = grid(procs)
    return f"{procs}-{px}-{py}-{pz}-{threads}"


def mappings(cores):
    """(unpinned, pinned) mapping lists for a node of `cores` cores (module docstring)."""
    quarter = max(1, cores // 4)
    unpinned = []
    for m in [mapping(1, quarter), mapping(1, cores)] + \
             [mapping(p, cores // p) for p in (2, 4, 8) if p < cores and cores % p == 0] + \
             [mapping(quarter, 1), mapping(cores, 1)]:
        if m not in unpinned and m != "1-1-1-1-1":
            unpinned.append(m)
    pinned = [m for m in (mapping(1, cores), mapping(4, cores // 4) if cores >= 8 else None, mapping(cores, 1))
              if m and m != "1-1-1-1-1"]
    return unpinned, list(dict.fromkeys(pinned))


def _row(runs, m):
    if runs is None or "mapping" not in runs:
        return None
    rows = runs[(runs["mapping"] == m) & (runs["status"] == "done")]
    return None if rows.empty else rows.iloc[0]


def _spread(row):
    v = row.get("totalT_spread") if row is not None else None
    return 0.0 if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _text(v):
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)


def _compare(label, a, b, target, what="totalT", lower_is_better=True):
    """One verdict line: a[what] / b[what] against target (a ratio <= target meets it)."""
    if a is None or b is None:
        return f"- {label}: not measured (a point missing or failed)"
    ratio = float(a[what]) / float(b[what]) if float(b[what]) > 0 else math.nan
    noise = max(_spread(a), _spread(b))
    met = ratio <= target if lower_is_better else ratio >= target
    tie = abs(ratio - 1.0) <= noise
    conf = (f"repeats' spread up to {100 * noise:.0f} %" + (", a tie within it" if tie else "")) if noise else \
        "one repeat: no spread known"
    return f"- {label}: {ratio:.3f} (target {'<=' if lower_is_better else '>='} {target:g}: " \
           f"{'met' if met else 'NOT met'}; {conf})"


def verdict(cores, unpinned, pinned, ceiling, schemes, steps=None, missing=(), forward=None):
    """The lines of DIR/verdict.md from the records (DataFrames or None): runs.csv of each sweep,
    ceiling.csv, schemes.csv, the mean busy imbalance of each point (steps: {mapping: max/mean
    of the threads' busy time, median over steps}) and the forward exchange's report (forward: the
    perf.json of `bench perf --what forward`, or None)."""
    quarter = max(1, cores // 4)
    t_q, r_q = mapping(1, quarter), mapping(quarter, 1)
    t_c, r_c = mapping(1, cores), mapping(cores, 1)
    lines = [f"# The {cores}-core check", ""]
    for name in missing:
        lines.append(f"- {name}: did not finish in its time (see log)")
    if unpinned is not None and len(unpinned):
        lines.append("")
        lines.append("| mapping | ms/step | efficiency | spread | binding | flag |")
        lines.append("|---|---|---|---|---|---|")
        for _, r in unpinned.iterrows():
            lines.append(f"| {r['mapping']} | {1e3 * r['totalT']:.2f} | {r['efficiency']:.2f} | "
                         f"{_spread(r):.2f} | {_text(r.get('binding'))} | {_text(r.get('flag'))} |")
        lines.append("")
    if quarter > 1:
        lines.append(_compare(f"{t_q} / {r_q}, step time", _row(unpinned, t_q), _row(unpinned, r_q),
                              TARGET_THREADS_VS_RANKS))
        lines.append(_compare(f"{t_q} / {r_q}, contact resolution (resolveT)", _row(unpinned, t_q),
                              _row(unpinned, r_q), TARGET_RESOLVE, what="resolveT"))
        if steps and t_q in steps:
            imb = steps[t_q]
            lines.append(f"- {t_q}, slowest thread over the mean: {imb:.3f} (target <= {TARGET_SLOWEST_THREAD:g}: "
                         f"{'met' if imb <= TARGET_SLOWEST_THREAD else 'NOT met'})")
    lines.append(_compare(f"{t_c} / {r_c}, step time", _row(unpinned, t_c), _row(unpinned, r_c),
                          TARGET_THREADS_VS_RANKS))
    if ceiling is not None and len(ceiling) and "cores" in ceiling:
        c = ceiling[ceiling["cores"] == cores]
        ranks, which = _row(pinned, r_c), "pinned, the ceiling's sweep"
        if ranks is None:
            ranks, which = _row(unpinned, r_c), "unpinned"
        if len(c) and ranks is not None:
            step = float(c.iloc[0]["ceiling_step"])
            share = float(ranks["efficiency"]) / step if step > 0 else math.nan
            lines.append(f"- {r_c} ({which}) efficiency over the in-step ceiling: {float(ranks['efficiency']):.3f} / "
                         f"{step:.3f}"
                         f" = {share:.3f} (target >= {TARGET_CEILING:g}: "
                         f"{'met' if share >= TARGET_CEILING else 'NOT met'};"
                         f" free ceiling {float(c.iloc[0]['ceiling_free']):.3f})")
    for m in (t_c, mapping(4, cores // 4) if cores >= 8 else None):
        if m:
            lines.append(_compare(f"{m} pinned / unpinned, step time (two sweeps)", _row(pinned, m),
                                  _row(unpinned, m), TARGET_PIN))
    if pinned is not None and "binding" in pinned:
        held = pinned[pinned["status"] == "done"]["binding"].tolist()
        lines.append(f"- binding of the pinned points: {', '.join(map(str, held)) or 'none done'}")
    if schemes is not None and len(schemes):
        if "thread_cpus" in schemes:   # the binding Table 1 recorded (bench.studies.schemes)
            r = schemes.iloc[0]
            how = "pinned to" if int(r["pinned"]) else "unpinned, on"
            lines.append(f"- Table 1's threads {how} CPUs {r['thread_cpus']}"
                         f"{'' if int(r['binding_held']) else ' (the binding did not hold through the rounds)'}")
        dyn = schemes[(schemes["method"] == "dynamic") & (schemes["neighbor"] == "allpairs")]
        if len(dyn):
            r = dyn.iloc[0]
            s = float(r["speedup"])
            # dynamic all-pairs' speedup is its efficiency_own x T (its own serial is serial all-pairs)
            threads = float(r.get("threads", cores))
            lo, hi = (float(r.get(f"efficiency_own_{e}", math.nan)) * threads for e in ("lo", "hi"))
            lines.append(f"- Table 1 dynamic all-pairs detection speedup at {cores} threads: {s:.2f}x{_ci(lo, hi)} "
                         f"(target >= {TARGET_DYNAMIC_SPEEDUP:g} at 16: {_verdict(s, lo, hi, TARGET_DYNAMIC_SPEEDUP)})")
        lc = schemes[(schemes["method"] != "serial") & (schemes["neighbor"] == "linkcell")]
        for _, r in lc.iterrows():
            extra = "".join(f", {k} {float(r[k]):.2f}" for k in ("neighbor_eff_own", "resolve_eff_own") if k in r)
            eff = float(r["efficiency_own"])
            lo, hi = (float(r.get(f"efficiency_own_{e}", math.nan)) for e in ("lo", "hi"))
            lines.append(f"- Table 1 link-cell {r['method']}: eff_own {eff:.2f}{_ci(lo, hi)}{extra} "
                         f"(target >= {TARGET_LINKCELL_EFF:g}: {_verdict(eff, lo, hi, TARGET_LINKCELL_EFF)})"
                         f"{_table1_ceiling(r)}")
    if forward:
        lines.append(_forward_line(forward))
    return lines


def _forward_line(rep):
    """The verdict's line of `bench perf --what forward`'s report (bench.studies.perf_forward)."""
    said = {"shared": "the shared window is faster", "messages": "the messages are faster",
            "tie": "no ranking at 95 %"}[rep["faster"]]
    msgs = [statistics.mean(r["parts_us"][fw]["msgs_sent"] for r in rep["jobs_rows"]) for fw in ("messages", "shared")]
    return (f"- forward exchange at {rep['procs']} ranks ({rep['mapping']}), messages / shared window, step time: "
            f"{rep['ratio']:.3f}{_ci(rep['ratio_lo'], rep['ratio_hi'])} over {rep['jobs']} jobs of {rep['cycles']} "
            f"cycles ({1e3 * rep['messages_ms']:.0f} against {1e3 * rep['shared_ms']:.0f} us a step; messages a "
            f"step, all ranks: {msgs[0]:.0f} against {msgs[1]:.0f}): {said}"
            + ("" if rep["identical"] else "; END STATES DIFFER"))


def _table1_ceiling(row):
    """'; the machine's ceiling ...' of a Table 1 row run with --ceiling (bench.studies.schemes: the
    share of its solo speed each of C serial copies keeps when all C detect at once), its share of
    it, and whether the target is within it at 95 %; '' without."""
    c = float(row.get("ceiling", math.nan))
    if math.isnan(c):
        return ""
    lo, hi = float(row.get("ceiling_lo", math.nan)), float(row.get("ceiling_hi", math.nan))
    reach = interval_verdict(lo, hi, TARGET_LINKCELL_EFF) if not (math.isnan(lo) or math.isnan(hi)) else "unresolved"
    said = {"met": "within it", "not met": "above it", "unresolved": "unresolved"}[reach]
    return (f"; the machine's ceiling {c:.2f}{_ci(lo, hi)}, of it {float(row['of_ceiling']):.2f}, "
            f"the target {said}")


def _ci(lo, hi):
    """' [lo, hi]' of a 95 % interval to 2 decimals, '' where there is none."""
    text = format_interval(lo, hi, 2)
    return f" {text}" if text else ""


def _verdict(value, lo, hi, target):
    """The verdict from the 95 % interval (bench.sweep.intervals.verdict: met, not met, unresolved);
    where there is none (one round), the point estimate's, marked so."""
    if math.isnan(lo) or math.isnan(hi):
        return ("met" if value >= target else "NOT met") + " (one round: no interval)"
    v = interval_verdict(lo, hi, target)
    return "NOT met" if v == "not met" else v


def _read(path):
    try:
        return pd.read_csv(path)
    except (OSError, ValueError):
        return None


def _busy_imbalance(sweep_dir, runs):
    """{mapping: median over steps of steps.csv `imbalance`} of the thread points of a sweep."""
    out = {}
    if runs is None:
        return out
    for _, r in runs.iterrows():
        if r.get("threads", 1) > 1 and r.get("procs", 1) == 1 and r["status"] == "done":
            steps = _read(os.path.join(sweep_dir, str(r["point"]), "rep0", "steps.csv"))
            if steps is not None and "imbalance" in steps:
                out[r["mapping"]] = float(steps["imbalance"].median())
    return out


def _part(cmd, limit, grace=PART_GRACE_S):
    """Run one part (a `bench` command) for at most `limit` seconds: its exit status, or None past
    the limit, when it is sent SIGTERM, which each part turns into a stop of its own processes (a
    sweep's runs, a study's MPI job: bench.run.lifeline), and SIGKILL `grace` seconds later if it
    has not ended."""
    proc = subprocess.Popen(cmd)
    try:
        return proc.wait(timeout=limit)
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        return None
    except BaseException:   # the check interrupted: the part stops its own processes as above
        proc.terminate()
        proc.wait()
        raise


def node_check(args, log=print):
    """The `bench node` command: the three parts (module docstring), then the verdict. Exit 0 when
    every part finished, 4 when one did not (the verdict names it)."""
    cores = args.cores or len(os.sched_getaffinity(0))
    unpinned_maps, pinned_maps = mappings(cores)
    out = args.out
    os.makedirs(out, exist_ok=True)
    common = ["--scene", "packed", "--particles", str(args.particles), "--steps", str(args.steps),
              "--warmup", str(args.warmup), "--repeats", str(args.repeats), "--timeout", str(args.point_timeout)]
    parts = [("unpinned sweep", ["sweep", "--mappings", ",".join(unpinned_maps), *common,
                                 "--out", os.path.join(out, "unpinned")], args.sweep_time),
             ("pinned sweep with the ceiling", ["sweep", "--mappings", ",".join(pinned_maps), *common, "--pin",
                                                "--ceiling", "--out", os.path.join(out, "pinned")], args.sweep_time),
             (f"Table 1 at {cores} threads", ["schemes", "--particles", str(args.schemes_particles), "--threads",
                                              str(cores), "--repeats", str(args.schemes_repeats), "--ceiling",
                                              "--out", os.path.join(out, "schemes")], args.schemes_time)]
    if cores >= 2:
        parts.append((f"the forward exchange at {cores} ranks",
                      ["perf", "--what", "forward", "--procs", str(cores), "--particles", str(args.particles),
                       "--repeats", str(args.forward_jobs), "--in-job", str(args.forward_cycles),
                       "--out", os.path.join(out, "forward")], args.forward_time))
    missing = []
    for name, argv, limit in parts:
        log(f"== {name}: bench {' '.join(argv)}")
        rc = _part([sys.executable, "-m", "bench", *argv], limit)
        if rc is None:
            missing.append(f"{name} (past {limit} s)")
        elif rc not in (0, 4):
            missing.append(f"{name} (exit {rc})")
    unpinned = _read(os.path.join(out, "unpinned", "runs.csv"))
    pinned = _read(os.path.join(out, "pinned", "runs.csv"))
    lines = verdict(cores, unpinned, pinned, _read(os.path.join(out, "pinned", "ceiling.csv")),
                    _read(os.path.join(out, "schemes", "schemes.csv")),
                    steps=_busy_imbalance(os.path.join(out, "unpinned"), unpinned), missing=missing,
                    forward=read_json_file(os.path.join(out, "forward", "perf.json")))
    cpu = environment().get("cpu_model", "CPU model unknown")
    lines[1:1] = ["", f"{cpu}, {cores} cores used of {os.cpu_count()}; {args.particles} packed ellipsoids, "
                      f"{args.steps} steps, {args.repeats} repeats. Commands: see log; records in the folders "
                      f"beside this file."]
    with open(os.path.join(out, "verdict.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    log("\n".join(lines))
    return 4 if missing else 0

