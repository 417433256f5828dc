"""Run records: run.json (inputs, environment, stability), steps.csv (per step and rank),
state.npz (final state sorted by global id). Schema: results/README.md."""
import csv
import json
import os
import platform
import sys
import time

import numpy as np

STEP_COLUMNS = ["step", "rank", "totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT",
                "n_owned", "n_ghost", "n_contacts", "n_wall_contacts", "n_candidates", "neighbor_rebuilt", "n_migrated",
                "bytes_sent", "msgs_sent", "wire_s", "ellipsoid_calls", "max_overlap_ratio", "busy_max", "busy_mean",
                "imbalance", "work_imbalance", "nsf", "rss_mb"]


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
    """steps.csv rows (one per step and rank), kept in memory and appended to the file every
    `flush_rows` rows or `flush_s` seconds and at close, so that writing costs a step nothing
    and a crash keeps all but the last few rows. rss_mb (resident memory [MiB], from psutil) is
    sampled at each flush and carried between, outside the timers."""

    def __init__(self, path, flush_rows=1000, flush_s=5.0):
        import psutil
        self.proc = psutil.Process()
        self.fh = open(path, "w", newline="")
        self.w = csv.writer(self.fh)
        self.w.writerow(STEP_COLUMNS)
        self.fh.flush()
        self.rows = []
        self.flush_rows = flush_rows
        self.flush_s = flush_s
        self.rss = self.proc.memory_info().rss / 2**20
        self.last = time.monotonic()

    def write(self, step, rank, row):
        row["step"] = step
        row["rank"] = rank
        self.rows.append(row)
        if len(self.rows) >= self.flush_rows or time.monotonic() - self.last > self.flush_s:
            self.flush()

    def flush(self):
        self.rss = self.proc.memory_info().rss / 2**20
        out = []
        for row in self.rows:
            detect = row.get("neighborT", 0.0) + row.get("resolveT", 0.0)
            row["nsf"] = row.get("neighborT", 0.0) / detect if detect > 0 else 0.0
            row["rss_mb"] = self.rss
            out.append([row.get(c, "") for c in STEP_COLUMNS])
        self.w.writerows(out)
        self.fh.flush()
        self.rows = []
        self.last = time.monotonic()

    def close(self):
        self.flush()
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
