"""Run records: run.json (inputs, environment, stability), steps.csv (per step and rank),
state.npz (final state sorted by global id). Schema: results/README.md.

Records survive (issue 15): every file is written atomically (a temporary file in the same
folder, then os.replace), so a reader sees the old or the new content, never half of one; steps.csv
is appended every FLUSH_ROWS rows or FLUSH_S seconds, and cut back to its last whole row when a
write fails; a write that fails (a full disk) raises RecordError, one line naming the file and
the cause, with every earlier file intact; run.json always ends in a final status (`done`,
`unstable`, `failed`, `timeout`, `interrupted`), written by the run, or by the supervisor of its
ranks (finalize_run) when they could not.
"""
import csv
import operator
import json
import os
import platform
import sys
import time

import numpy as np

from bench.run.lifeline import signals_deferred
from bench.run.machine import cpu_facts


FLUSH_ROWS = 100   # steps.csv rows kept in memory at most ...
FLUSH_S = 1.0      # ... and seconds between appends
RESERVE_BYTES = 64 * 1024  # kept free for the final records when the disk fills (Reserve)
FINAL = ("done", "unstable", "failed", "timeout", "interrupted")


class RecordError(OSError):
    """A record that could not be written (full disk, permissions); str() is one line."""

STEP_COLUMNS = ["step", "rank", "totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT",
                "n_owned", "n_ghost", "n_contacts", "n_wall_contacts", "n_candidates", "neighbor_rebuilt",
                "halo_rebuilt", "n_migrated",
                "bytes_sent", "msgs_sent", "wire_s", "bytes_internode", "msgs_internode", "wire_internode_s", "syncT",
                "ellipsoid_calls", "max_overlap_ratio", "busy_max", "busy_mean",
                "imbalance", "work_imbalance", "nsf", "rss_mb"]


def environment():
    """Versions and machine facts recorded with every run."""
    import numba
    cpus = cpu_facts()
    info = {"python": sys.version.split()[0], "platform": platform.platform(),
            "machine": platform.machine(), "cpu_count": cpus["cpu_count"], "numpy": np.__version__,
            "numba": numba.__version__, "numba_threads": numba.config.NUMBA_NUM_THREADS}
    if cpus["usable"] is not None:
        info["cpu_affinity"] = cpus["usable"]
    if cpus["cpu_model"] is not None:
        info["cpu_model"] = cpus["cpu_model"]
    return info


def atomic_write(path, fill, mode="w"):
    """Write path atomically: fill(fh) writes a temporary file beside it, then os.replace. A failure
    (OSError) removes the temporary file, leaves path as it was and raises RecordError."""
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        with open(tmp, mode, **({"newline": ""} if "b" not in mode else {})) as fh:
            fill(fh)
            fh.flush()
        os.replace(tmp, path)
    except OSError as e:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise RecordError(f"cannot write {path}: {e.strerror or e}") from None


def write_json(path, obj):
    atomic_write(path, lambda fh: json.dump(obj, fh, indent=2, default=_jsonable))


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

    def __init__(self, path, flush_rows=FLUSH_ROWS, flush_s=FLUSH_S):
        import psutil
        self.proc = psutil.Process()
        self.path = path
        self.last_step = 0  # the last step whose row is on disk
        self.fd = None
        try:
            self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            self.good = 0  # bytes of whole rows on disk
            self._append(",".join(STEP_COLUMNS) + "\n")
        except OSError as e:
            self._cut()
            raise RecordError(f"cannot write {path}: {e.strerror or e}") from None
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
        """Append the rows in memory; a failed write cuts the file back to its last whole row and
        raises RecordError (the rows not written are dropped)."""
        if self.fd is None:
            return
        self.rss = self.proc.memory_info().rss / 2**20
        lines = []
        for row in self.rows:
            detect = row["neighborT"] + row["resolveT"]
            row["nsf"] = row["neighborT"] / detect if detect > 0 else 0.0
            row["rss_mb"] = self.rss
            if self.line is None:
                self._layout(row)
            lines.append(self.line % self.values(row))
        last = self.rows[-1]["step"] if self.rows else self.last_step
        self.last = time.monotonic()
        if not lines:
            return
        with signals_deferred():  # the rows on disk and last_step agree whenever a signal lands
            self.rows = []
            try:
                self._append("".join(lines))
            except OSError as e:
                self._cut()
                raise RecordError(f"cannot write {self.path}: {e.strerror or e} (rows up to step "
                                  f"{self.last_step} kept)") from None
            self.last_step = last

    def _append(self, text):
        """Write `text` at the end of the whole rows with os.write, no buffer between: a failed
        write leaves nothing queued that a later close could put past the cut."""
        data = memoryview(text.encode())
        size = len(data)
        while data:
            data = data[os.write(self.fd, data):]
        self.good += size

    def _cut(self):
        """Back to the last whole row (a failed write may leave part of one), and stop writing."""
        fd, self.fd = self.fd, None
        if fd is None:
            return
        try:
            os.ftruncate(fd, self.good)
        except OSError:
            pass
        os.close(fd)

    def close(self):
        if self.fd is None:
            return
        try:
            self.flush()
        finally:
            if self.fd is not None:
                fd, self.fd = self.fd, None
                os.close(fd)


class Reserve:
    """RESERVE_BYTES of disk held in DIR/.reserve from the start of a run, and given back when a
    write fails for lack of space, so that run.json can still say how the run ended."""

    def __init__(self, out):
        self.path = os.path.join(out, ".reserve")
        try:
            with open(self.path, "wb") as fh:
                fh.write(b"\0" * RESERVE_BYTES)
        except OSError:
            self.release()

    def release(self):
        try:
            os.remove(self.path)
        except OSError:
            pass


def write_state(path, snap):
    """state.npz: id [n], pos [n,3], quat [n,4], vel [n,3], omega [n,3] (+ axes, shape)."""
    atomic_write(path, lambda fh: np.savez(fh, **snap), mode="wb")


def write_rows_csv(path, rows, columns):
    """Write dict rows as CSV with the given columns (floats to 6 significant digits), atomically."""
    def fill(fh):
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write(path, fill)


PROBE_BYTES = 64 * 1024


def prepare_output(out, need=0):
    """Create the output folder and check that it takes a write: a PROBE_BYTES probe written and
    flushed to disk (an empty one passes on a full disk), and `need` bytes more free (the
    estimated records). SceneError, one line, if not."""
    from dem.scene import SceneError  # here: numba starts with dem.scene, after the thread variables are set
    if not isinstance(out, str) or not out.strip():
        raise SceneError(f"output folder must be a non-empty path, got {out!r}")
    probe = os.path.join(out, f".write-test.{os.getpid()}")
    try:
        os.makedirs(out, exist_ok=True)
        with open(probe, "wb") as fh:
            fh.write(b"\0" * PROBE_BYTES)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as e:
        raise SceneError(f"output folder {out!r} is not writable: {e.strerror or e}") from None
    finally:
        try:
            os.remove(probe)
        except OSError:
            pass
    try:
        st = os.statvfs(out)
        free = st.f_bavail * st.f_frsize
    except (OSError, AttributeError):
        return
    if need and free < need:
        raise SceneError(f"output folder {out!r} has {free / 2**20:.3g} MiB free, the records need about "
                         f"{need / 2**20:.3g} MiB")


def read_step_rows(path):
    """The whole rows of a steps.csv being written or cut short (a last line without its newline, or
    with fewer fields, is left out), in (step, rank) order: a DataFrame, empty when the file has none."""
    import io
    import pandas as pd
    try:
        with open(path, newline="") as fh:
            text = fh.read()
    except OSError:
        return pd.DataFrame(columns=STEP_COLUMNS)
    if not text.endswith("\n"):
        text = text[:text.rfind("\n") + 1]
    lines = text.splitlines(keepends=True)
    if not lines:
        return pd.DataFrame(columns=STEP_COLUMNS)
    width = lines[0].count(",")
    body = [l for l in lines[1:] if l.count(",") == width]
    try:
        rows = pd.read_csv(io.StringIO(lines[0] + "".join(body)))
    except Exception:  # noqa: BLE001  (a damaged header: no rows to keep)
        return pd.DataFrame(columns=STEP_COLUMNS)
    if {"step", "rank"} <= set(rows.columns):  # a merge in place on a full disk leaves them out of order
        rows = rows.sort_values(["step", "rank"], kind="stable", ignore_index=True)
    return rows


def merge_step_files(out, size):
    """Merge the ranks' step rows (steps.rank<r>.csv) into one steps.csv ordered by (step, rank),
    atomically; a rank's file that is missing or cut short gives the whole rows it has. Returns
    {rank: rows} of the merged files; the rank files are removed once steps.csv is written."""
    import pandas as pd
    counts, parts = {}, []
    for r in range(size):
        path = os.path.join(out, f"steps.rank{r}.csv")
        if os.path.exists(path):
            part = read_step_rows(path)
            counts[r] = len(part)
            parts.append(part)
    if not parts:
        return counts
    merged = pd.concat(parts).sort_values(["step", "rank"], kind="stable")
    try:
        atomic_write(os.path.join(out, "steps.csv"), lambda fh: merged.to_csv(fh, index=False))
    except RecordError:  # a full disk has no room for a second copy: merge in place, rank by rank
        _merge_in_place(out, sorted(counts))
        return counts
    for r in counts:
        os.remove(os.path.join(out, f"steps.rank{r}.csv"))
    return counts


def _merge_in_place(out, ranks, chunk=16384):
    """steps.csv from the ranks' files on a disk without room for a copy: the first rank's file
    renamed to it; each other rank's rows moved over from the end of its file, a chunk of whole rows
    at a time (appended, then cut off the rank's file), so the disk needs room for one chunk only.
    The rows are then not in (step, rank) order: readers group by step (read_step_rows sorts)."""
    target = os.path.join(out, "steps.csv")
    os.replace(os.path.join(out, f"steps.rank{ranks[0]}.csv"), target)
    with open(target, "rb") as fh:
        whole = fh.read().rfind(b"\n") + 1
    os.truncate(target, whole)  # a row cut short at the end goes (it frees room, needs none)
    for r in ranks[1:]:
        path = os.path.join(out, f"steps.rank{r}.csv")
        with open(path, "rb") as fh:
            data = fh.read()
        head = data.find(b"\n") + 1            # the header stays behind
        end = data.rfind(b"\n") + 1            # whole rows only
        while end > head:
            # the whole rows within the last chunk (all that is left when no row ends before it)
            start = max(head, data.rfind(b"\n", head, max(head, end - chunk)) + 1)
            try:
                with open(target, "ab") as fh:
                    fh.write(data[start:end])
            except OSError as e:
                raise RecordError(f"cannot merge {path} into {target}: {e.strerror or e}") from None
            os.truncate(path, start)
            end = start
        os.remove(path)


def steps_done(out, size, info):
    """The last step whose row every rank wrote, from OUT/steps.csv (the step before the run's first
    when none; None when the file cannot be read)."""
    first = int(info.get("step_first") or 1)
    try:
        rows = read_step_rows(os.path.join(out, "steps.csv"))
    except (OSError, ValueError):
        return first - 1 if not os.path.exists(os.path.join(out, "steps.csv")) else None
    if not len(rows) or "rank" not in rows or "step" not in rows:
        return first - 1
    last = rows.groupby("rank")["step"].max()
    if len(last) < size:
        return first - 1
    return int(last.min())


def read_json_file(path):
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def finalize_run(out, size, status, reason):
    """Keep and mark the records of a run that did not end by itself (the supervisor of its ranks, or
    a launcher whose run was killed): the ranks' step rows merged into steps.csv, and run.json's
    status set to `status` with `reason` unless the run wrote a final one. Never raises: a record
    that cannot be written is named in run.json where possible."""
    notes = []
    try:
        os.remove(os.path.join(out, ".reserve"))  # the run's reserve, if it could not give it back
    except OSError:
        pass
    try:
        counts = merge_step_files(out, size) if size > 1 else {}
    except (OSError, ValueError) as e:
        counts, notes = {}, [f"steps.rank<r>.csv not merged: {e}"]
    path = os.path.join(out, "run.json")
    info = read_json_file(path) or {}
    if info.get("status") in FINAL:
        return info
    info.update(status=status, stable=info.get("stable"), reason=reason, ended=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    if info.get("steps_done") is None:
        info["steps_done"] = steps_done(out, size, info)
    if counts:
        info["rank_step_rows"] = {str(r): n for r, n in counts.items()}
    if notes:
        info["record_notes"] = notes
    try:
        write_json(path, info)
    except RecordError:
        pass
    return info


def process_alive(pid, host=None):
    """Whether process pid still runs (on this host: another host's pid cannot be asked)."""
    import socket
    if host is not None and host != socket.gethostname():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, TypeError):
        return True
    try:
        with open(f"/proc/{int(pid)}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True
