"""`bench sweep`: run one scene under many process/thread mappings and record the metrics.

Every point (mapping x scheme, bench.sweep.points) runs as its own `bench run` in
DIR/<point>/rep<r>/ through the chosen launcher (bench.sweep.launchers). The serial point
1-1-1-1-1 is the reference T(1) and the reference state for the error columns; it is added (and
run first) when missing. A point that crashes, hangs past its timeout or goes unstable is
recorded with its status and reason, and the sweep goes on. A batch launcher (slurm) instead
writes and submits jobs and returns; `bench collect DIR` then records them the same way. The
columns are bench.sweep.records'; the figures (bench.sweep.figures) are drawn from runs.csv at the
end.

Faults and trust (issue 15):
- the folder is locked for the sweep's life (bench.sweep.lock): a second sweep or collect into it
  gets one line and exit 2;
- repeats are interleaved: round r runs repeat r of every point (serial first), so that a load
  that comes and goes spreads over the points instead of falling on one;
- DIR/runs.csv (rewritten atomically whenever a point completes) keeps every point ever done in
  the folder: the rows of points outside this sweep are carried over (rebuilt from their folders
  when runs.csv cannot be read or a row is cut short), and manifest.json accumulates its points,
  their load and the history of sweeps (`sweeps`);
- --resume skips the repeats whose folders hold a finished, recorded run (status.json done and its
  run.json, steps.csv and state.npz), whatever runs.csv says; a repeat folder whose run.json says
  running with its process still alive here is refused (one line);
- SIGINT, SIGTERM and SIGHUP stop the point running (its bench run stops its ranks), record it,
  write runs.csv and the manifest, and exit 128 + the signal with one line; `--resume` continues.
"""
import math
import os
import sys
import time

import numpy as np

from bench.run.lifeline import Interrupted, exit_status, raise_on_signals, signal_name
from bench.run.records import prepare_output, process_alive, read_json_file, write_json
from bench.run.threads_env import usable_cpus
from bench.sweep.ceiling import Ceiling, CeilingError
from bench.sweep.figures import plot_sweep
from bench.sweep.granularity import plot_granularity
from bench.sweep.launchers import LAUNCHERS
from bench.sweep.lock import SweepLock
from bench.sweep.points import SERIAL, make_points, point_from_dict, point_options
from bench.sweep.precision import MIN_ROUNDS, mark, next_round, unresolved, widest_text
from bench.sweep.ranking import point_label, rank, ranking_lines
from bench.sweep.records import (RUN_COLUMNS, RunsFileError, amdahl, flag_reference, manifest, merge_manifest,
                                 read_runs_rows, reference_key, summarise, with_speedup, write_runs)
from bench.sweep.warm import warm_start
from modes.base import ModeError, parse_mapping
from modes.parallel import DEFAULT_SCHEME


def sweep(args):
    """The `bench sweep` command (args from bench.cli)."""
    mappings = [m.strip() for m in args.mappings.split(",") if m.strip()]
    schemes = [s.strip() for s in (args.schemes or DEFAULT_SCHEME).split(",") if s.strip()]
    launcher = LAUNCHERS[getattr(args, "launcher", "local")].from_args(args)
    if launcher.batch and os.path.isfile(args.scene):  # the jobs run elsewhere, from another folder
        args.scene = os.path.abspath(args.scene)
    points = make_points(mappings, schemes, **point_options(args))
    out = args.out
    ceiling = _ceiling(args, launcher, points) if getattr(args, "ceiling", False) else None
    if args.dry_run:
        return launcher.dry_run(points, out, args.repeats)
    prepare_output(out)
    raise_on_signals()
    with SweepLock(out) as lock:
        if launcher.batch:
            return launcher.submit(points, out, args.repeats, args.resume)
        return local_sweep(args, launcher, points, out, lock.fd, ceiling)


def _ceiling(args, launcher, points):
    """The machine-ceiling control of `--ceiling` (bench.sweep.ceiling), checked before anything is
    written: a ModeError (one line) for the Slurm launcher or a scene that cannot be resized."""
    if launcher.batch:
        raise ModeError("--ceiling needs the local launcher: its copies run where the sweep runs, beside the points")
    usable = len(os.sched_getaffinity(0))
    cores = [parse_mapping(p.mapping).procs * parse_mapping(p.mapping).threads for p in points]
    try:
        options = {k: getattr(args, k, None) for k in ("skin", "contact_method", "neighbor")}
        ceiling = Ceiling(args.scene, args.particles, args.shape, args.steps, args.warmup, cores, usable, options,
                          pin=bool(getattr(args, "pin", False)))
    except CeilingError as e:
        raise ModeError(str(e)) from None
    if ceiling.left_out:
        print(f"ceiling: left out at {', '.join(map(str, ceiling.left_out))} cores (more than the {usable} usable "
              f"CPUs)", flush=True)
    return ceiling


def repeat_done(rep):
    """A finished, recorded repeat: status.json done and its run.json, steps.csv and state.npz."""
    st = read_json_file(os.path.join(rep, "status.json")) or {}
    return st.get("status") == "done" and all(os.path.exists(os.path.join(rep, f))
                                              for f in ("run.json", "steps.csv", "state.npz"))


def earlier_rows(out, points):
    """{point key: row} of DIR/runs.csv for the given points, each a whole row (bench.sweep.records.
    read_runs_rows) whose `done` is borne out by its folders; and a warning line or None."""
    path = os.path.join(out, "runs.csv")
    if not os.path.exists(path):
        return {}, None
    try:
        header, rows, cut = read_runs_rows(path)
    except RunsFileError as e:
        return {}, f"{e}: its rows are rebuilt from the point folders"
    keep = {}
    for r in rows:
        p = points.get(r.get("point"))
        if p is None:
            continue
        if r.get("status") == "done" and not all(repeat_done(d) for d in p["dirs"]):
            continue  # a row that says done without the records to back it
        keep[r["point"]] = {c: _typed(r.get(c, "")) for c in RUN_COLUMNS}
    note = f"{path}: {cut} row(s) cut short, rebuilt from the point folders" if cut else None
    return keep, note


def _typed(text):
    if text == "":
        return math.nan
    try:
        return float(text) if text.strip().lower() not in ("true", "false") else text
    except ValueError:
        return text


def local_sweep(args, launcher, points, out, lock_fd, ceiling=None):
    runs_path = os.path.join(out, "runs.csv")
    precision = getattr(args, "precision", None)
    budget = getattr(args, "budget", None)
    repeats = max(args.repeats, MIN_ROUNDS) if precision else args.repeats
    if precision and args.repeats < MIN_ROUNDS:
        print(f"sweep: --precision judges after at least {MIN_ROUNDS} rounds (one run's interval does not see "
              f"what changes from run to run)", flush=True)
    if args.resume and precision:  # the rounds an earlier --precision sweep added are this sweep's too
        started = {p.get("key"): p.get("repeats") for p in
                   (read_json_file(os.path.join(out, "manifest.json")) or {}).get("points", []) if isinstance(p, dict)}
        repeats = max([repeats] + [int(started[p.key]) for p in points
                                   if isinstance(started.get(p.key), int) and started[p.key] > 0])
    info = manifest(out, points)
    for p in info["points"]:
        p["repeats"] = repeats
    entry = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": " ".join(sys.argv),
             "points": [p.key for p in points], "repeats": repeats, "resume": bool(args.resume),
             "launcher": launcher.name}
    info = merge_manifest(out, info, entry)
    info.update(launcher=launcher.name, repeats=repeats)
    everything = {}
    for d in info["points"]:
        n = int(d.get("repeats") or repeats)
        everything[d["key"]] = {"point": point_from_dict(d), "dirs": [os.path.join(out, d["key"], f"rep{r}")
                                                                        for r in range(n)]}
    old, note = earlier_rows(out, everything)
    if note:
        print(f"bench: warning: {note}", flush=True)
    # the repeats to run: all of this sweep's, or with --resume those without a finished record
    todo = {}
    for p in points:
        reps = everything[p.key]["dirs"]
        todo[p.key] = [r for r, d in enumerate(reps) if not (args.resume and repeat_done(d))]
        for r in todo[p.key]:
            run = read_json_file(os.path.join(reps[r], "run.json")) or {}
            if run.get("status") == "running" and run.get("pid") and process_alive(run["pid"], run.get("host")):
                raise ModeError(f"{reps[r]} is still being run by process {run['pid']} on {run.get('host')} (left "
                                f"by an earlier sweep?): stop it before running this point again")
    write_json(os.path.join(out, "manifest.json"), info)
    rows = {}
    for key, e in everything.items():  # every earlier point keeps its row
        if key not in todo:
            rows[key] = old.get(key) or summarise(e["point"], e["dirs"], None, None)
    for p in points:
        if not todo[p.key]:
            rows[p.key] = old.get(p.key) or summarise(p, everything[p.key]["dirs"], None, None)
    env = dict(os.environ)
    n_runs = sum(len(v) for v in todo.values())
    print(f"sweep: {len(points)} points x {repeats} repeats ({sum(repeats - len(v) for v in todo.values())} "
          f"repeats already done) of {args.scene} into {out}", flush=True)
    if n_runs:  # build and compile at once, before any point (bench.sweep.warm)
        warm_start(out, [p for p in points if todo[p.key]], usable_cpus(), env, lock_fd)
    start = time.perf_counter()
    failed = {}
    ran = 0
    ref_state, t1 = {}, {}

    def record(p):
        """Summarise a point whose repeats are all run (or one failed) into its runs.csv row."""
        reps = everything[p.key]["dirs"]
        if p.mapping == SERIAL and os.path.exists(os.path.join(reps[0], "state.npz")):
            ref_state[p.key] = dict(np.load(os.path.join(reps[0], "state.npz")))
        ref = reference_key(p)
        row = summarise(p, reps, ref_state.get(ref), t1.get(ref))
        if p.mapping == SERIAL and row["status"] == "done":
            t1[p.key] = float(row["totalT"])
        load = info["load"].get(p.key) or {}
        row.update(load_before=load.get("before", math.nan), load_after=load.get("after", math.nan))
        rows[p.key] = row
        write_runs(runs_path, [rows[k] for k in everything if k in rows])
        return row

    for key, e in everything.items():  # serial references done before this sweep
        row = rows.get(key)
        if e["point"].mapping == SERIAL and row is not None and row.get("status") == "done":
            t1[key] = float(row["totalT"])
            if os.path.exists(os.path.join(e["dirs"][0], "state.npz")):
                ref_state[key] = dict(np.load(os.path.join(e["dirs"][0], "state.npz")))
    stopped = current = None
    clock = SweepClock(n_runs)
    round_seconds, short = [], None   # each round's wall time; why --precision stopped short
    this_sweep = [p.key for p in points]
    sizes = len({p.particles for p in points}) > 1   # the granularity study: points named with their N
    try:
        r = -1
        while True:
            r += 1
            if r >= repeats:  # the requested rounds are run: --precision may add one
                if not precision:
                    break
                open_points = unresolved([rows[k] for k in this_sweep if k in rows], precision)
                if not open_points:
                    break
                short = next_round(r, time.perf_counter() - start, round_seconds, budget)
                if short is not None:
                    break
                widest_point, width = open_points[0]
                print(f"round {r + 1}: {len(open_points)} point(s) not yet within +-{100 * precision:g} %, the widest "
                      f"{widest_point} " + (f"+-{100 * width:.1f} %" if math.isfinite(width)
                                            else "without an interval"),
                      flush=True)
                _add_round(info, everything, todo, points, r, out)
                clock.add(len(points))
            round_start = time.perf_counter()
            for k, p in enumerate(points, 1):
                if r not in todo[p.key] or p.key in failed:
                    continue
                rep = everything[p.key]["dirs"][r]
                load0 = os.getloadavg()[0]
                current = p
                name = f"point {k}/{len(points)} {_label(p, sizes)}" + \
                    (f" rep {r + 1}/{max(repeats, r + 1)}" if repeats > 1 else "")
                clock.begin(name, rep)
                st = launcher.run_point(p, rep, env, lock_fd, tick=clock.tick)
                clock.end(rep)
                current = None
                ran += 1
                load = info["load"].setdefault(p.key, {})
                load.setdefault("before", load0)
                load["after"] = os.getloadavg()[0]
                write_json(os.path.join(out, "manifest.json"), info)
                if st["status"] != "done":
                    failed[p.key] = st
                # --precision judges after every repeat from the last requested round on
                last = st["status"] != "done" or r == max(todo[p.key]) or bool(precision and r >= repeats - 1)
                row = record(p) if last else None
                el = time.perf_counter() - start
                line = _progress(k, len(points), p, r, max(repeats, r + 1), st, row, rep, el, clock.left(), sizes)
                if precision:
                    line += widest_text([rows[q] for q in this_sweep if q in rows])
                print(line, flush=True)
            round_seconds.append(time.perf_counter() - round_start)
            if ceiling is not None and ceiling.cores:  # the control's round after the points' round
                try:
                    ceiling.round()
                except RuntimeError as e:  # a copy failed: the points go on without the control
                    print(f"bench: warning: ceiling not measured further: {e}", flush=True)
                    ceiling = None
                    continue
                for c in ceiling.write(out):
                    print(f"ceiling at {c['cores']} cores ({c['rounds']} round(s)"
                          f"{', copies pinned' if c['pinned'] else ''}): efficiency {c['ceiling_free']:.3f} "
                          f"sharing nothing, {c['ceiling_step']:.3f} meeting every step", flush=True)
    except (KeyboardInterrupt, Interrupted) as e:
        stopped = e
        clock.close()
        if current is not None:  # the point that was running: its repeat is recorded (interrupted)
            failed[current.key] = True
            record(current)
    clock.close()
    # speedups against each group's T(1) (this sweep's serial point, or the row carried over)
    for key, row in rows.items():
        ref = rows.get(reference_key(everything[key]["point"]))
        if ref is not None and ref.get("status") == "done":
            with_speedup(row, float(ref["totalT"]), ref)
        flag_reference(row, ref)
    if precision and stopped is None:
        mark([rows[k] for k in this_sweep if k in rows], precision, short)
    write_runs(runs_path, [rows[k] for k in everything if k in rows])
    layers = set()
    for p in points:
        f = os.path.join(out, p.key, "rep0", "run.json")
        run = read_json_file(f) or {}
        if run.get("threading_layer"):
            layers.add(run["threading_layer"])
    info["numba_threading_layer"] = sorted(layers) or None
    info["sweeps"][-1]["ended"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    info["sweeps"][-1]["outcome"] = "interrupted" if stopped is not None else "ended"
    write_json(os.path.join(out, "manifest.json"), info)
    if stopped is not None:
        print(f"bench: error: sweep interrupted by {signal_name(stopped)}: the point running was stopped and "
              f"recorded; runs.csv has every point done; `bench sweep ... --resume` continues", file=sys.stderr,
              flush=True)
        return exit_status(stopped)
    summary = amdahl(list(rows.values()))
    summary["ranking"] = rank(list(rows.values()))
    left = [rows[k] for k in this_sweep if k in rows and str(rows[k].get("resolved")).startswith("no")]
    if precision:
        summary["precision"] = {"target": precision, "budget_s": budget, "rounds": r,
                                "unresolved": [point_label(rw) for rw in left], "stopped": short}
    write_json(os.path.join(out, "summary.json"), summary)
    for n, fit in ((summary.get("by_particles") or {}) | {"": summary}).items():
        if fit.get("serial_fraction") is not None:
            print(f"Amdahl fit over {fit['points']} points{f' of {int(n):,} particles' if n else ''}: serial "
                  f"fraction {fit['serial_fraction']:.3f}" + ("" if fit["valid"] else f" ({fit['note']})"))
    for line in ranking_lines(summary["ranking"]):
        print(f"ranking, {line}")
    if precision:
        print(f"precision +-{100 * precision:g} %: " + (
            f"every point resolved in {r} rounds" if not left else
            f"{len(left)} point(s) not resolved ({left[0]['resolved']}): " + ", ".join(point_label(rw) for rw in left)),
            flush=True)
    if getattr(args, "compare", None):  # against an earlier sweep (bench.sweep.compare): reported, never failed on
        from bench.sweep.compare import compare_folders, comparison_lines
        entries = compare_folders(args.compare, out)
        summary["compare"] = {"against": os.path.abspath(args.compare),  # JSON has no NaN: null
                              "points": [{k: None if isinstance(v, float) and not math.isfinite(v) else v
                                          for k, v in e.items()} for e in entries]}
        write_json(os.path.join(out, "summary.json"), summary)
        for line in comparison_lines(entries):
            print(f"compared, {line}")
    figs = plot_sweep(out) + plot_granularity(out)
    print(f"records: {runs_path}; figures: {', '.join(os.path.basename(f) for f in figs)}")
    flagged = [r for r in rows.values() if isinstance(r.get("flag"), str) and r["flag"]]
    if flagged:
        print(f"flagged: {len(flagged)} point(s) measured under foreign load or with a wide spread (runs.csv "
              f"flag): " + ", ".join(f"{r['mapping']}"
                                      f"{' ' + r['scheme'] if isinstance(r['scheme'], str) and r['scheme'] else ''}"
                                      f" [{r['flag']}]" for r in flagged))
    failed_rows = [r for r in rows.values() if r["status"] != "done"]
    return 0 if not failed_rows else 4


def _add_round(info, everything, todo, points, r, out):
    """Round r (0-based) of --precision: repeat folder rep<r> for every point of this sweep, written
    to manifest.json before it runs (a --resume then runs what is left of it)."""
    keys = {p.key for p in points}
    for d in info["points"]:
        if d["key"] in keys:
            d["repeats"] = r + 1
    for p in points:
        everything[p.key]["dirs"].append(os.path.join(out, p.key, f"rep{r}"))
        todo[p.key].append(r)
    write_json(os.path.join(out, "manifest.json"), info)


def current_step(rep_dir):
    """(step, steps) of the run in rep_dir: the last whole row of its steps.csv (or rank 0's
    steps.rank0.csv under MPI) and run.json's step count; None where not known yet."""
    run = read_json_file(os.path.join(rep_dir, "run.json")) or {}
    total = run.get("steps")
    for name in ("steps.csv", "steps.rank0.csv"):
        try:
            with open(os.path.join(rep_dir, name), "rb") as fh:
                fh.seek(0, os.SEEK_END)
                size = fh.tell()
                fh.seek(max(0, size - 4096))
                tail = fh.read().rsplit(b"\n", 2)
        except OSError:
            continue
        line = tail[-2] if len(tail) >= 2 else b""
        try:
            return int(line.split(b",", 1)[0]) - int(run.get("step_first") or 1) + 1, total
        except ValueError:
            return 0, total
    return None, total


class SweepClock:
    """The sweep's progress between its progress lines: while a repeat runs, a bar on a terminal
    (tqdm: repeats done, the point and its step) or a line every PERIOD_S seconds elsewhere; and the
    estimate of the time left: the running repeat's own rate over its remaining steps, plus the
    repeats still to run at the median time of those done, each without its scene build (a build
    is cached: it happens once)."""

    def __init__(self, runs):
        from bench.run.progress import PERIOD_S, on_terminal
        self.runs = runs
        self.done = []        # seconds of each repeat done, its scene build left out
        self.period = PERIOD_S
        self.name = self.rep = None
        self.t0 = self.last = time.monotonic()
        self.bar = None
        if on_terminal() and runs > 0:
            from tqdm import tqdm
            self.bar = tqdm(total=runs, desc="sweep", unit="run", leave=False, dynamic_ncols=True, file=sys.stderr)

    def add(self, runs):
        """`runs` more repeats to run (a round --precision adds)."""
        self.runs += runs
        if self.bar is not None:
            self.bar.total = self.runs
            self.bar.refresh()

    def begin(self, name, rep):
        self.name, self.rep, self.t0 = name, rep, time.monotonic()

    def end(self, rep):
        took = time.monotonic() - self.t0
        run = read_json_file(os.path.join(rep, "run.json")) or {}
        build = run.get("build") or {}
        if not build.get("from_cache", True):
            took -= float(build.get("build_s") or build.get("seconds") or 0.0)
        self.done.append(max(0.0, took))
        if self.bar is not None:
            self.bar.update(1)
        self.name = None

    def left(self, now=None):
        """Seconds left (None before the first repeat is done and without a running rate)."""
        now = time.monotonic() if now is None else now
        per = float(np.median(self.done)) if self.done else None
        after = self.runs - len(self.done) - (1 if self.name else 0)
        current = 0.0
        if self.name:
            step, total = current_step(self.rep)
            el = now - self.t0
            if step and total and (step >= 0.1 * total or per is None):  # its own rate, once it has one
                current = el / step * (total - step)
            elif per is not None:
                current = max(0.0, per - el)
            else:
                return None
        if per is None:
            return current if after == 0 else None
        return current + after * per

    def tick(self):
        now = time.monotonic()
        if self.name is None:
            return
        step, total = current_step(self.rep)
        where = f"step {step}/{total}" if step is not None and total else "starting"
        left = self.left(now)
        eta = f"estimate {left:.0f} s left" if left is not None else "estimate after the first run"
        if self.bar is not None:
            self.bar.set_postfix_str(f"{self.name}: {where}, {eta}", refresh=True)
        elif now - self.last >= self.period:
            print(f"  {self.name}: {where}, {now - self.t0:.0f} s in this run, {eta}", flush=True)
            self.last = now

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _label(p, sizes=False):
    """A point's name in the progress lines: mapping, scheme and, in a granularity study, N."""
    return f"{p.mapping}{' ' + p.scheme if p.scheme else ''}" + (f" at {p.particles:,} particles" if sizes else "")


def _progress(k, n, p, r, repeats, st, row, rep, elapsed, eta, sizes=False):
    """The progress line of one repeat: the point, its outcome, its time and what makes it doubtful."""
    name = f"point {k}/{n} {_label(p, sizes)}"
    if repeats > 1:
        name += f" rep {r + 1}/{repeats}"
    text = f"{name}: {st['status']}" + (f" ({st['reason']})" if st["status"] != "done" else "")
    run = read_json_file(os.path.join(rep, "run.json")) or {}
    if st["status"] == "done":
        if row is not None and math.isfinite(row["totalT"]):
            text += f", totalT {row['totalT'] * 1e3:.3f} ms/step"
        load = run.get("load") or {}
        fc = load.get("foreign_cores")
        if fc is not None:
            text += f", foreign load {fc:.2f} CPUs"
        if row is not None and row.get("flag"):
            text += f" [FLAG {row['flag']}]"
    return text + f", elapsed {elapsed:.0f} s" + (f", estimate {eta:.0f} s left" if eta is not None else "")
