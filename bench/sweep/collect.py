"""`bench collect DIR`: runs.csv from the point folders listed in DIR/manifest.json (a batch
sweep's results, gathered exactly as a local sweep records them)."""
import json
import os

import numpy as np

from bench.run.records import write_json
from bench.sweep.points import SERIAL, Point
from bench.sweep.records import amdahl, summarise, with_speedup, write_runs
from dem.scene import SceneError


def collect(args):
    """The `bench collect` command (args from bench.cli)."""
    path = os.path.join(args.dir, "manifest.json")
    if not os.path.exists(path):
        raise SceneError(f"{args.dir} has no manifest.json (not a sweep folder)")
    info = json.load(open(path))
    points = [Point(**{k: v for k, v in p.items() if k != "key"}) for p in info["points"]]
    rows = []
    ref_state, t1 = None, None
    for p in points:
        pdir = os.path.join(args.dir, p.key)
        reps = sorted(os.path.join(pdir, d) for d in os.listdir(pdir) if d.startswith("rep")) \
            if os.path.isdir(pdir) else []
        reps = reps or [os.path.join(pdir, "rep0")]
        if p.mapping == SERIAL and os.path.exists(os.path.join(reps[0], "state.npz")):
            ref_state = dict(np.load(os.path.join(reps[0], "state.npz")))
        row = summarise(p, reps, ref_state, t1)
        if p.mapping == SERIAL and row["status"] == "done":
            t1 = row["totalT"]
        rows.append(row)
    for row in rows:  # the serial row too (speedup 1.0), against the T(1) of this collection
        with_speedup(row, t1)
    write_runs(os.path.join(args.dir, "runs.csv"), rows)
    write_json(os.path.join(args.dir, "summary.json"), amdahl(rows))
    done = sum(r["status"] == "done" for r in rows)
    print(f"collected {done} of {len(rows)} points into {os.path.join(args.dir, 'runs.csv')}")
    return 0
