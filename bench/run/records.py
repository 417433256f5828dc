"""Run records: run.json (inputs, environment, stability), steps.csv (per step and rank),
state.npz (final state sorted by global id). Schema: results/README.md."""
import csv
import operator
import json
import os
import platform
import sys
import time

import numpy as np

from dem.scene import SceneError

STEP_COLUMNS = ["step", "rank", "totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT",
                "n_owned", "n_ghost", "n_contacts", "n_wall_contacts", "n_candidates", "neighbor_rebuilt", "n_migrated",
                "bytes_sent", "msgs_sent", "wire_s", "syncT", "ellipsoid_calls", "max_overlap_ratio", "busy_max", "busy_mean",
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
    sampled at each flush and carried between, outside the timers. A row is one format
    operation, fixed by the first row: integers in full, floats to 7 significant digits (times
    to 0.1 us in 1 s), empty for a column the mode leaves out."""

    def __init__(self, path, flush_rows=1000, flush_s=5.0):
        import psutil
        self.proc = psutil.Process()
        self.fh = open(path, "w", newline="")
        self.fh.write(",".join(STEP_COLUMNS) + "\n")
        self.fh.flush()
        self.rows = []
        self.flush_rows = flush_rows
        self.flush_s = flush_s
        self.rss = self.proc.memory_info().rss / 2**20
        self.last = time.monotonic()
        self.line = None

    def write(self, step, rank, row):
        row["step"] = step
        row["rank"] = rank
        self.rows.append(row)
        if len(self.rows) >= self.flush_rows or time.monotonic() - self.last > self.flush_s:
            self.flush()

    def _layout(self, row):
        """The row format and the columns it takes, from the columns this mode fills."""
        present = [c for c in STEP_COLUMNS if c in row]
        self.values = operator.itemgetter(*present)
        self.line = ",".join(("%d" if isinstance(row[c], (int, np.integer)) else "%.7g") if c in row else ""
                             for c in STEP_COLUMNS) + "\n"

    def flush(self):
        self.rss = self.proc.memory_info().rss / 2**20
        lines = []
        for row in self.rows:
            detect = row["neighborT"] + row["resolveT"]
            row["nsf"] = row["neighborT"] / detect if detect > 0 else 0.0
            row["rss_mb"] = self.rss
            if self.line is None:
                self._layout(row)
            lines.append(self.line % self.values(row))
        self.fh.write("".join(lines))
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


def prepare_output(out):
    """Create the output folder and check that it is writable (SceneError, one line, if not)."""
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, ".write-test")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError as e:
        raise SceneError(f"output folder {out!r} is not writable: {e.strerror}") from None


def merge_step_files(out, size):
    """Merge the ranks' step rows (steps.rank<r>.csv) into one steps.csv ordered by (step, rank)."""
    import pandas as pd
    parts = [pd.read_csv(os.path.join(out, f"steps.rank{r}.csv")) for r in range(size)]
    merged = pd.concat(parts).sort_values(["step", "rank"], kind="stable")
    merged.to_csv(os.path.join(out, "steps.csv"), index=False)
    for r in range(size):
        os.remove(os.path.join(out, f"steps.rank{r}.csv"))
