"""`bench sweep`: run one scene under many process/thread mappings and record the metrics.

Every point (mapping x scheme, bench.sweep.points) runs as its own `bench run` in
DIR/<point>/rep<r>/ through the chosen launcher (bench.sweep.launchers). The serial point
1-1-1-1-1 is the reference T(1) and the reference state for the error columns; it is added (and
run first) when missing. After every point DIR/runs.csv is rewritten atomically, so an
interrupted sweep leaves a consistent file; --resume skips the points already done (identified
by their parameters). A point that crashes, hangs past its timeout or goes unstable is recorded
with its status and reason, and the sweep goes on. A batch launcher (slurm) instead writes and
submits jobs and returns; `bench collect DIR` then records them the same way. The columns are bench.sweep.records'; the
figures (bench.sweep.figures) are drawn from runs.csv at the end.
"""
import json
import math
import os
import time

import numpy as np

from bench.run.records import prepare_output, write_json
from bench.sweep.figures import plot_sweep
from bench.sweep.launchers import LAUNCHERS
from bench.sweep.points import SERIAL, make_points
from bench.sweep.records import RUN_COLUMNS, amdahl, manifest, summarise, with_speedup, write_runs


def sweep(args):
    """The `bench sweep` command (args from bench.cli)."""
    mappings = [m.strip() for m in args.mappings.split(",") if m.strip()]
    schemes = [s.strip() for s in (args.schemes or "dynamic").split(",") if s.strip()]
    launcher = LAUNCHERS[getattr(args, "launcher", "local")].from_args(args)
    if launcher.batch and os.path.isfile(args.scene):  # the jobs run elsewhere, from another folder
        args.scene = os.path.abspath(args.scene)
    points = make_points(mappings, schemes, args.scene, args.particles, args.steps, args.warmup,
                         args.neighbor, args.shape, args.pin, args.halo, getattr(args, "contact_method", "exact"))
    out = args.out
    prepare_output(out)
    runs_path = os.path.join(out, "runs.csv")
    done = {}
    if args.resume and os.path.exists(runs_path):
        import pandas as pd
        old = pd.read_csv(runs_path, keep_default_na=False)
        done = {r["point"]: r for r in old.to_dict("records") if r["status"] == "done"}
    if args.dry_run:
        return launcher.dry_run(points, out, args.repeats)
    if launcher.batch:
        return launcher.submit(points, out, args.repeats, args.resume)
    info = manifest(out, points)
    info.update(launcher=launcher.name, repeats=args.repeats, load={})
    write_json(os.path.join(out, "manifest.json"), info)
    env = dict(os.environ)
    rows = {}
    ref_state = None
    t1 = None
    start = time.perf_counter()
    todo = [p for p in points if p.key not in done]
    print(f"sweep: {len(points)} points ({len(points) - len(todo)} already done) of {args.scene} into {out}",
          flush=True)
    for k, p in enumerate(points, 1):
        reps = [os.path.join(out, p.key, f"rep{r}") for r in range(args.repeats)]
        if p.key in done:
            row = {c: done[p.key].get(c, math.nan) for c in RUN_COLUMNS}
        else:
            load0 = os.getloadavg()[0]
            for r in reps:
                st = launcher.run_point(p, r, env)
                if st["status"] != "done":
                    break
            load1 = os.getloadavg()[0]
            info["load"][p.key] = {"before": load0, "after": load1}
            write_json(os.path.join(out, "manifest.json"), info)
            row = None
        if p.mapping == SERIAL and ref_state is None and os.path.exists(os.path.join(reps[0], "state.npz")):
            ref_state = dict(np.load(os.path.join(reps[0], "state.npz")))
        if row is None:
            row = summarise(p, reps, ref_state, t1)
            row.update(load_before=load0, load_after=load1)
        if p.mapping == SERIAL and row["status"] == "done":
            t1 = float(row["totalT"])
        rows[p.key] = row
        write_runs(runs_path, [rows[q.key] for q in points if q.key in rows])
        el = time.perf_counter() - start
        ran = sum(1 for q in points[:k] if q.key not in done)
        eta = el / ran * (len(todo) - ran) if ran else 0.0
        print(f"point {k}/{len(points)} {p.mapping}{' ' + p.scheme if p.scheme else ''}: {row['status']}"
              f"{' (' + str(row['reason']) + ')' if row['status'] != 'done' else ''}, "
              f"totalT {row['totalT'] * 1e3 if row['totalT'] == row['totalT'] else float('nan'):.3f} ms/step, "
              f"elapsed {el:.0f} s, estimate {eta:.0f} s left", flush=True)
    # speedups of resumed rows against this T(1)
    if t1:
        for r in rows.values():
            with_speedup(r, t1)
        write_runs(runs_path, [rows[q.key] for q in points])
    # the threading layer numba used, as the runs recorded it (a parallel region must have run)
    layers = set()
    for p in points:
        f = os.path.join(out, p.key, "rep0", "run.json")
        if os.path.exists(f):
            layers.add(json.load(open(f)).get("threading_layer"))
    info["numba_threading_layer"] = sorted(x for x in layers if x) or None
    write_json(os.path.join(out, "manifest.json"), info)
    summary = amdahl(list(rows.values()))
    write_json(os.path.join(out, "summary.json"), summary)
    if summary.get("serial_fraction") is not None:
        print(f"Amdahl fit over {summary['points']} points: serial fraction {summary['serial_fraction']:.3f}"
              + ("" if summary["valid"] else f" ({summary['note']})"))
    figs = plot_sweep(out)
    print(f"records: {runs_path}; figures: {', '.join(os.path.basename(f) for f in figs)}")
    failed = [r for r in rows.values() if r["status"] != "done"]
    return 0 if not failed else 4
