"""Run records: run.json (inputs, environment, stability), steps.csv (per step and rank),
state.npz (final state sorted by global id). Schema: results/README.md."""
import csv
import json
import os
import platform
import sys

import numpy as np

STEP_COLUMNS = ["step", "rank", "totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT",
                "n_owned", "n_ghost", "n_contacts", "n_wall_contacts", "n_candidates", "neighbor_rebuilt", "n_migrated", "bytes_sent",
                "ellipsoid_calls", "max_overlap_ratio", "busy_max", "busy_mean", "imbalance", "work_imbalance", "nsf", "rss_mb"]


def environment():
    """Versions and machine facts recorded with every run."""
    import numba
    info = {"python": sys.version.split()[0], "platform": platform.platform(),
            "machine": platform.machine(), "cpu_count": os.cpu_count(), "numpy": np.__version__,
            "numba": numba.__version__, "numba_threads": numba.config.NUMBA_NUM_THREADS}
    try:
        info["cpu_affinity"] = len(os.sched_getaffinity(0))
    except AttributeError:
        pass
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu_model"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def write_json(path, obj):
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=2, default=_jsonable)
    os.replace(tmp, path)


def _jsonable(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


class StepWriter:
    """Appends one steps.csv row per step and rank, flushed as it goes (a crash keeps its rows)."""

    def __init__(self, path):
        import psutil
        self.proc = psutil.Process()
        self.fh = open(path, "w", newline="")
        self.w = csv.DictWriter(self.fh, fieldnames=STEP_COLUMNS, extrasaction="ignore")
        self.w.writeheader()

    def write(self, step, rank, row):
        detect = row.get("neighborT", 0.0) + row.get("resolveT", 0.0)
        nsf = row.get("neighborT", 0.0) / detect if detect > 0 else 0.0
        rss = self.proc.memory_info().rss / 2**20  # resident memory of this rank [MiB], outside the timers
        self.w.writerow({"step": step, "rank": rank, "nsf": nsf, "rss_mb": rss, **row})

    def close(self):
        self.fh.close()


def write_state(path, snap):
    """state.npz: id [n], pos [n,3], quat [n,4], vel [n,3], omega [n,3] (+ axes, shape)."""
    tmp = path + ".tmp.npz"
    np.savez(tmp, **snap)
    os.replace(tmp, path)


def write_rows_csv(path, rows, columns):
    """Write dict rows as CSV with the given columns (floats to 6 significant digits), atomically."""
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, path)
