"""`bench collect DIR`: runs.csv, summary.json and the figures of a sweep from its point folders
(a Slurm sweep's results, gathered exactly as a local sweep records them).

Each point's row takes the real outcome of its repeats (bench.sweep.status: each repeat's
status.json and, for a Slurm sweep, what the scheduler says): done, failed with the point's own
one-line reason, unstable, timeout, cancelled, pending, running. Speedups are against this
collection's serial T(1) (1.0 for the serial row). For a Slurm sweep the manifest gets the
compute nodes (each node's CPU model and core count, from the jobs; `cpu_model` and `cpu_count`
the nodes' own when they are alike), the MPI library and numba's threading layer the runs
recorded. Exit status 0 when every point is done, 4 otherwise (the points not done are listed).
"""
import os
import time

import numpy as np

from bench.run.records import write_json
from bench.sweep.figures import plot_sweep
from bench.sweep.granularity import plot_granularity
from bench.sweep.points import SERIAL, point_from_dict
from bench.sweep.ranking import rank, ranking_lines
from bench.sweep.records import amdahl, flag_reference, reference_key, summarise, with_speedup, write_runs
from bench.sweep.status import PRIORITY, read_json, sweep_outcomes
from dem.scene import SceneError


def compute_nodes(directory, rows):
    """{node: {cpu_model, cpu_count}} from the repeats' status.json (written on the node by the job)
    and run.json's environment, and this process's node when it runs in a Slurm job."""
    from bench.sweep.job import node_info
    nodes = {}
    for _, outcomes in rows:
        for o in outcomes:
            st = read_json(os.path.join(o["dir"], "status.json")) or {}
            env = (read_json(os.path.join(o["dir"], "run.json")) or {}).get("environment") or {}
            node = st.get("node")
            if node:
                nodes.setdefault(node, {"cpu_model": st.get("cpu_model") or env.get("cpu_model"),
                                        "cpu_count": st.get("cpu_count") or env.get("cpu_count")})
    if os.environ.get("SLURM_JOB_ID"):
        me = node_info()
        nodes.setdefault(me["node"], {"cpu_model": me.get("cpu_model"), "cpu_count": me.get("cpu_count")})
    return nodes


def collect(args):
    """The `bench collect` command (args from bench.cli)."""
    from bench.sweep.slurm import Scheduler
    if not os.path.exists(os.path.join(args.dir, "manifest.json")):
        raise SceneError(f"{args.dir} has no manifest.json (not a sweep folder)")
    info = read_json(os.path.join(args.dir, "manifest.json"))
    if not isinstance(info, dict) or not isinstance(info.get("points"), list):
        raise SceneError(f"{os.path.join(args.dir, 'manifest.json')} cannot be read as a sweep manifest (not JSON, "
                         f"or no points list); it can be rebuilt by running the sweep again with --resume")
    batch = info.get("launcher") == "slurm"
    info, outcomes = sweep_outcomes(args.dir, Scheduler.here() if batch else None)
    rows = []
    ref_state, t1 = {}, {}  # per serial point: its state and totalT (each group's reference)
    for p, reps in outcomes:
        point = point_from_dict(p)
        dirs = [o["dir"] for o in reps]
        if point.mapping == SERIAL and os.path.exists(os.path.join(dirs[0], "state.npz")) and \
                all(o["status"] == "done" for o in reps):
            ref_state[point.key] = dict(np.load(os.path.join(dirs[0], "state.npz")))
    keys = []
    by_key = {}
    for p, reps in outcomes:
        point = point_from_dict(p)
        dirs = [o["dir"] for o in reps]
        ordered = sorted(reps, key=lambda o: PRIORITY.index(o["status"]) if o["status"] in PRIORITY else 0)
        row = summarise(point, dirs, ref_state.get(reference_key(point)), None, statuses=ordered)
        loads = [read_json(os.path.join(d, "status.json")) or {} for d in dirs]
        if any("load_before" in s for s in loads):
            row["load_before"] = float(np.median([s["load_before"] for s in loads if "load_before" in s]))
            row["load_after"] = float(np.median([s["load_after"] for s in loads if "load_after" in s] or [np.nan]))
        if point.mapping == SERIAL and row["status"] == "done":
            t1[point.key] = row["totalT"]
        rows.append(row)
        by_key[point.key] = row
        keys.append(reference_key(point))
    for row, ref in zip(rows, keys):  # the serial row too (speedup 1.0), against its group's T(1)
        with_speedup(row, t1.get(ref), by_key.get(ref))
        flag_reference(row, by_key.get(ref))
    runs_path = os.path.join(args.dir, "runs.csv")
    write_runs(runs_path, rows)
    summary = amdahl(rows)
    summary["ranking"] = rank(rows)
    write_json(os.path.join(args.dir, "summary.json"), summary)
    for line in ranking_lines(summary["ranking"]):
        print(f"ranking, {line}")
    if batch:
        nodes = compute_nodes(args.dir, outcomes)
        info["nodes"] = nodes
        for key in ("cpu_model", "cpu_count"):
            values = sorted({str(n[key]) for n in nodes.values() if n.get(key) is not None})
            if len(values) == 1:
                info[key] = next(n[key] for n in nodes.values() if n.get(key) is not None)
            else:
                info[key] = values or None  # several kinds of node (or none known yet)
        layers, libs = set(), set()
        for _, reps in outcomes:
            for o in reps:
                run = read_json(os.path.join(o["dir"], "run.json")) or {}
                if run.get("threading_layer"):
                    layers.add(run["threading_layer"])
                if run.get("mpi_library"):
                    libs.add(run["mpi_library"])
        info["numba_threading_layer"] = sorted(layers) or None
        if libs:
            info["mpi_library"] = sorted(libs)[0] if len(libs) == 1 else sorted(libs)
        info["collected"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        write_json(os.path.join(args.dir, "manifest.json"), info)
    figs = plot_sweep(args.dir) + plot_granularity(args.dir)
    done = sum(r["status"] == "done" for r in rows)
    for r in rows:
        if r["status"] != "done":
            print(f"point {r['mapping']}{' ' + r['scheme'] if r['scheme'] else ''}: {r['status']}"
                  + (f" ({r['reason']})" if r["reason"] else ""))
    print(f"collected {done} of {len(rows)} points into {runs_path}; figures: "
          f"{', '.join(os.path.basename(f) for f in figs)}")
    return 0 if done == len(rows) else 4
