"""The records of a sweep: the runs.csv contract, one row per point from its run folders, the
manifest, the Amdahl fit, and reading them back (`read_runs`, `load`).

Module times per point (DESIGN.md): totalT = mean over steps of the max over ranks, commuT and
migraT = mean over steps of the per-rank mean, compuT = totalT - commuT - migraT; syncT = mean
over steps of the per-rank mean of syncT (the step's one allreduce, part of commuT: waiting for
the slowest rank + the collective's latency; NaN without MPI or when steps.csv has no syncT);
wireT = mean over steps of the per-rank mean of wire_s (the modelled wire time of what a rank
sent, modes/wire.py), above_wireT = commuT + migraT - syncT - wireT (the software above the wire
in the exchanges; commuT + migraT - wireT where syncT is NaN, older records; both NaN without
MPI or when steps.csv has no wire_s); with --repeats R the median over the R runs.

Whether a point's times can be trusted (issue 15; results/README.md): foreign_cores (the most CPUs
other processes kept busy during any repeat's timed steps, bench.run.load), foreign_cpu_s (their
CPU seconds over all repeats), step_spread (the median over repeats of (p90 - p10) / p50 of the
step times), totalT_spread ((max - min) / median of totalT over the repeats; NaN with one) and
`flag`: `load` when a repeat ran beside more than LOAD_FLAG_CORES of foreign CPU (above the
measurement's resolution), `spread` when totalT_spread > SPREAD_FLAG_REPEATS or step_spread >
SPREAD_FLAG_STEPS, `ref` when the point's T(1) reference (its group's serial point) is flagged,
since its speedup, efficiency and EDSF are then as doubtful as that time; comma-separated, empty
for a clean point.

runs.csv keeps every point ever done in its folder (rows of earlier sweeps are carried over,
read_runs_rows), and a row cut short (a last line without its newline, or with fewer fields than
the header) is never taken as a point's result.
"""
import csv
import io
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict

import numpy as np

from bench.run.machine import cpu_facts
from bench.sweep.intervals import format_reps, parse_reps, speedup_interval, step_time_interval
from bench.sweep.intervals import number as _num
from modes.base import parse_mapping

RUN_COLUMNS = ["point", "mapping", "procs", "px", "py", "pz", "threads", "cores", "scheme", "neighbor", "scene",
               "particles", "steps", "repeats", "status", "reason", "totalT", "commuT", "migraT", "compuT",
               "syncT", "wireT", "above_wireT", "neighborT", "resolveT", "overhead_pct", "speedup", "efficiency",
               "edsf", "rss_mb", "err_max",
               "err_rms", "stable", "wall_s", "load_before", "load_after", "contact_method",
               "skin", "halo_skin", "preset", "binding",
               "foreign_cores", "foreign_cpu_s", "step_spread", "totalT_spread", "flag",
               "totalT_lo", "totalT_hi", "speedup_lo", "speedup_hi", "efficiency_lo", "efficiency_hi", "totalT_reps",
               "resolved", "nodes", "wire_internodeT", "forward"]


TEXT_COLUMNS = ("point", "mapping", "scheme", "neighbor", "scene", "status", "reason", "stable", "contact_method",
                "preset", "binding", "flag", "totalT_reps", "resolved", "forward")

LOAD_FLAG_CORES = 0.25      # foreign CPUs busy on average during a repeat's timed steps
SPREAD_FLAG_REPEATS = 0.10  # (max - min) / median of totalT over the repeats
SPREAD_FLAG_STEPS = 0.5     # (p90 - p10) / p50 of the step times (median over repeats)


class RunsFileError(ValueError):
    """A runs.csv that cannot be read as a table; str() is one line."""


def read_runs_rows(path):
    """(header, rows as dicts of str, cut) of a runs.csv read as CSV: rows with as many fields as
    the header, a last line without its newline left out (cut counts those left out).
    RunsFileError when the file is empty or has no header with a `point` column."""
    try:
        with open(path, newline="", encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError as e:
        raise RunsFileError(f"{path} cannot be read: {e.strerror}") from None
    if not text.strip():
        raise RunsFileError(f"{path} is empty (0 rows, no header)")
    complete = text.endswith("\n")
    try:
        lines = list(csv.reader(io.StringIO(text)))
    except csv.Error as e:
        raise RunsFileError(f"{path} is not a CSV table: {e}") from None
    header = lines[0] if lines else []
    if "point" not in header or "status" not in header:
        raise RunsFileError(f"{path} is not a runs table (its header has no point and status columns)")
    rows, cut = [], 0
    body = lines[1:]
    for k, fields in enumerate(body):
        last = k == len(body) - 1
        if len(fields) != len(header) or (last and not complete):
            cut += 1
            continue
        rows.append(dict(zip(header, fields)))
    return header, rows, cut


NUMERIC_COLUMNS = [c for c in RUN_COLUMNS if c not in TEXT_COLUMNS]
INTEGER_COLUMNS = ("procs", "px", "py", "pz", "threads", "cores", "particles", "steps", "repeats", "nodes")


def read_runs(directory):
    """DIR/runs.csv as a DataFrame with every column of RUN_COLUMNS (NaN where absent), numbers
    parsed, text columns as str ('' for empty), procs/threads/cores filled from the mapping string
    when empty, and a `family` column (serial, threads, MPI, hybrid)."""
    import pandas as pd
    path = os.path.join(directory, "runs.csv")
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: no runs.csv (run `bench sweep` first)")
    header, rows, cut = read_runs_rows(path)
    if cut:
        print(f"bench: warning: {path}: {cut} row(s) cut short (fewer fields than the header, or no final "
              f"newline) left out", file=sys.stderr)
    df = pd.DataFrame(rows, columns=header).replace("", math.nan)
    for c in RUN_COLUMNS:
        if c not in df:
            df[c] = math.nan
    for c in NUMERIC_COLUMNS:
        df[c] = pd.to_numeric(df[c], errors="coerce").astype(float)
    for c in TEXT_COLUMNS:
        df[c] = df[c].map(lambda v: "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v).strip())
    for i, m in df["mapping"].items():
        parts = m.strip().split("-")
        if len(parts) == 5 and all(p.isdigit() for p in parts):
            p, px, py, pz, t = (float(x) for x in parts)
            for col, v in (("procs", p), ("px", px), ("py", py), ("pz", pz), ("threads", t)):
                if math.isnan(df.at[i, col]):
                    df.at[i, col] = v
    miss = df["cores"].isna()
    df.loc[miss, "cores"] = df.loc[miss, "procs"] * df.loc[miss, "threads"]
    # a row without a status counts as done when it has a time
    nostat = df["status"] == ""
    df.loc[nostat, "status"] = np.where(np.isfinite(df.loc[nostat, "totalT"]), "done", "unknown")
    df["family"] = [family(p, t) for p, t in zip(df["procs"], df["threads"])]
    return df


def family(procs, threads):
    """serial, threads (1 process), MPI (1 thread) or hybrid."""
    if not (np.isfinite(procs) and np.isfinite(threads)):
        return "hybrid" if np.isfinite(procs) and procs > 1 else "threads"
    if procs == 1 and threads == 1:
        return "serial"
    if procs == 1:
        return "threads"
    return "MPI" if threads == 1 else "hybrid"


def module_times(steps):
    """Per-step module times of one run (DESIGN.md): dict of totalT, commuT, migraT, compuT,
    syncT (mean over steps of the per-rank mean of syncT [s], the allreduce inside commuT; NaN
    without a syncT column or with it empty, as serial and thread runs leave it), wireT (mean
    over steps of the per-rank mean of wire_s [s]; NaN without a wire_s column), wire_internodeT
    (the same of wire_internode_s, the part of wireT sent to other nodes), above_wireT =
    commuT + migraT - syncT - wireT [s] (the software above the wire in the exchanges; commuT +
    migraT - wireT when syncT is NaN; NaN when wireT is), neighborT, resolveT, rss_mb."""
    g = steps.groupby("step")
    total = g["totalT"].max()
    commu = g["commuT"].mean()
    migra = g["migraT"].mean()
    out = {"totalT": float(total.mean()), "commuT": float(commu.mean()), "migraT": float(migra.mean())}
    out["compuT"] = out["totalT"] - out["commuT"] - out["migraT"]
    # the wire under commuT + migraT (issue 11): absent from older steps.csv files
    import pandas as pd
    # and the allreduce inside commuT (syncT): absent from older ones, empty without MPI
    for col, key in (("wire_s", "wireT"), ("syncT", "syncT"), ("wire_internode_s", "wire_internodeT")):
        v = pd.to_numeric(steps[col], errors="coerce") if col in steps else None
        if v is not None and v.notna().any():
            out[key] = float(v.groupby(steps["step"]).mean().mean())
        else:
            out[key] = math.nan
    sync = out["syncT"] if math.isfinite(out["syncT"]) else 0.0  # older records: the old definition
    out["above_wireT"] = out["commuT"] + out["migraT"] - sync - out["wireT"]
    out["neighborT"] = float(g["neighborT"].max().mean())
    out["resolveT"] = float(g["resolveT"].max().mean())
    out["rss_mb"] = float(steps["rss_mb"].max()) if "rss_mb" in steps else math.nan
    return out


def state_error(ref, got):
    """err_max, err_rms of final positions over the mean bounding radius (0 when bit-identical)."""
    if ref is None or got is None or not np.array_equal(ref["id"], got["id"]):
        return math.nan, math.nan
    d = np.linalg.norm(got["pos"] - ref["pos"], axis=1) / float(ref["axes"].max(axis=1).mean())
    return float(d.max()), float(np.sqrt(np.mean(d ** 2)))


def summarise(point, rep_dirs, ref_state, t1, statuses=None):
    """One runs.csv row from the repeat folders of a point; statuses: their outcomes when known
    (bench collect: files and Slurm, bench.sweep.status), else read from each folder."""
    import pandas as pd
    m = parse_mapping(point.mapping)
    row = {c: math.nan for c in RUN_COLUMNS}
    row.update(point=point.key, mapping=point.mapping, procs=m.procs, px=m.px, py=m.py, pz=m.pz, threads=m.threads,
               cores=m.procs * m.threads, scheme=point.scheme, neighbor=point.neighbor, scene=point.scene,
               contact_method=point.contact_method,
               repeats=len(rep_dirs), status="done", reason="")
    times, walls, loads, spreads, bindings, series = [], [], [], [], [], []
    state = None
    statuses = statuses or [read_status(d) for d in rep_dirs]
    for status in statuses:
        if status["status"] != "done":
            row.update(status=status["status"], reason=status["reason"])
            return row
    for d in rep_dirs:
        info = json.load(open(os.path.join(d, "run.json")))
        steps = pd.read_csv(os.path.join(d, "steps.csv"))
        times.append(module_times(steps))
        series.append(steps.groupby("step")["totalT"].max().to_numpy())  # a step's time: its slowest rank's
        walls.append(info.get("wall_s", math.nan))
        loads.append(info.get("load") or {})
        spreads.append((info.get("step_time") or {}).get("spread"))
        bindings.append(binding_word(info.get("affinity")))
        row.update(particles=info["particles"], steps=info["steps"], stable=info["stable"], skin=info.get("skin"),
                   halo_skin=info.get("halo_skin"), preset=info.get("preset") or "",
                   forward=info.get("forward_transport") or "",
                   nodes=len(info.get("nodes") or [info.get("host")]))
        state = dict(np.load(os.path.join(d, "state.npz")))
    for k in times[0]:
        row[k] = float(np.median([t[k] for t in times]))
    if m.procs == 1:  # no MPI, no wire, no allreduce (a serial steps.csv may carry wire_s = 0)
        row["syncT"] = row["wireT"] = row["above_wireT"] = row["wire_internodeT"] = math.nan
    row["totalT_lo"], row["totalT_hi"] = step_time_interval(series)
    row["totalT_reps"] = format_reps(t["totalT"] for t in times)
    row["wall_s"] = float(np.median(walls))
    row["binding"] = next((b for b in bindings if b == "lost"), bindings[0] if bindings else "")
    trust(row, [t["totalT"] for t in times], loads, spreads)
    row["overhead_pct"] = 100.0 * (row["commuT"] + row["migraT"]) / row["totalT"] if row["totalT"] > 0 else math.nan
    with_speedup(row, t1)
    row["err_max"], row["err_rms"] = state_error(ref_state, state)
    return row


def binding_word(affinity):
    """runs.csv `binding` of one repeat from run.json `affinity` (bench.run.binding): `pinned` or
    `unpinned` when the binding held from the first step to the last, `lost` when it did not, ''
    for records without it."""
    if not affinity:
        return ""
    if not affinity.get("held", False):
        return "lost"
    return "pinned" if affinity.get("pinned") else "unpinned"


def trust(row, totals, loads, spreads):
    """Set foreign_cores, foreign_cpu_s, step_spread, totalT_spread and flag of a row from its
    repeats' totalT [s], run.json `load` dicts and step spreads (module docstring)."""
    cores = [_num(l.get("foreign_cores")) for l in loads]
    cpu = [_num(l.get("foreign_cpu_s")) for l in loads]
    res = [_num(l.get("resolution_s")) for l in loads]
    fc = [c for c in cores if math.isfinite(c)]
    row["foreign_cores"] = max(fc) if fc else math.nan
    fs = [c for c in cpu if math.isfinite(c)]
    row["foreign_cpu_s"] = float(sum(fs)) if fs else math.nan
    sp = [_num(s) for s in spreads if math.isfinite(_num(s))]
    row["step_spread"] = float(np.median(sp)) if sp else math.nan
    t = [x for x in totals if math.isfinite(x)]
    med = float(np.median(t)) if t else math.nan
    row["totalT_spread"] = (max(t) - min(t)) / med if len(t) > 1 and med > 0 else math.nan
    flags = []
    if any(c > LOAD_FLAG_CORES and u > (r if math.isfinite(r) else 0.0) for c, u, r in zip(cores, cpu, res)
           if math.isfinite(c) and math.isfinite(u)):
        flags.append("load")
    if row["totalT_spread"] > SPREAD_FLAG_REPEATS or row["step_spread"] > SPREAD_FLAG_STEPS:
        flags.append("spread")
    row["flag"] = ",".join(flags)
    return row


def _own_flags(row):
    f = row.get("flag")
    return [x for x in (f.split(",") if isinstance(f, str) else []) if x.strip() and x.strip() != "ref"]


def flag_reference(row, ref):
    """Set or clear `ref` in the flag of a row by whether its T(1) reference row ref (another row)
    carries a flag of its own (module docstring)."""
    own = _own_flags(row)
    if ref is not None and ref is not row and _own_flags(ref):
        own.append("ref")
    row["flag"] = ",".join(own)
    return row


def with_speedup(row, t1, ref=None):
    """Set speedup T(1)/T(p), efficiency = speedup / p and the Karp-Flatt EDSF
    (1/S - 1/p) / (1 - 1/p) of a done row against the serial totalT t1 (p = cores); no-op without
    t1 or a time. Given the reference row ref (t1's), also the 95 % intervals speedup_lo/hi and
    efficiency_lo/hi (bench.sweep.intervals; none for the reference itself)."""
    if not t1 or row["status"] != "done" or not row["totalT"] == row["totalT"]:
        return row
    s = t1 / float(row["totalT"])
    p = int(row["cores"])
    row.update(speedup=s, efficiency=s / p, edsf=(1 / s - 1 / p) / (1 - 1 / p) if p > 1 else math.nan)
    lo = hi = math.nan
    if ref is not None and ref is not row and ref.get("point") != row.get("point"):
        lo, hi = speedup_interval(t1, _num(ref.get("totalT_lo")), _num(ref.get("totalT_hi")), float(row["totalT"]),
                                  _num(row.get("totalT_lo")), _num(row.get("totalT_hi")),
                                  parse_reps(ref.get("totalT_reps")), parse_reps(row.get("totalT_reps")))
    row.update(speedup_lo=lo, speedup_hi=hi, efficiency_lo=lo / p, efficiency_hi=hi / p)
    return row


def read_status(d):
    """status and reason of one run folder from its files (status.json, written by the local
    launcher and by a Slurm job; else judged by run.json)."""
    from bench.sweep.status import from_files
    return from_files(d) or {"status": "failed", "reason": "no result (not run, interrupted or crashed)"}


def write_runs(path, rows):
    """runs.csv, atomically (tmp file + rename): an interrupted sweep never leaves half a file, and a
    full disk leaves the old one (bench.run.records.RecordError)."""
    import pandas as pd
    from bench.run.records import atomic_write
    frame = pd.DataFrame(rows, columns=RUN_COLUMNS)
    for c in INTEGER_COLUMNS:  # whole numbers stay whole beside a row's NaN or a carried row's text
        values = pd.to_numeric(frame[c], errors="coerce")
        if (values.dropna() % 1 == 0).all():
            frame[c] = values.astype("Int64")
    atomic_write(path, lambda fh: frame.to_csv(fh, index=False))


def manifest(out, points):
    """DIR/manifest.json: versions, MPI library, numba threading layer, CPU, git commit."""
    import platform
    cpus = cpu_facts()
    info = {"python": sys.version.split()[0], "platform": platform.platform(), "cpu_count": cpus["cpu_count"],
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "points": [asdict(p) | {"key": p.key} for p in points]}
    if cpus["usable"] is not None:
        info["usable_cpus"] = cpus["usable"]
    for mod in ("numpy", "numba", "mpi4py", "pandas", "matplotlib", "psutil", "llvmlite"):
        try:
            info[mod] = __import__(mod).__version__
        except Exception:  # noqa: BLE001  (a missing optional package is just not listed)
            info[mod] = None
    info["cpu_model"] = cpus["cpu_model"]
    try:
        info["mpi_library"] = subprocess.run([sys.executable, "-c", "from mpi4py import MPI; "
                                              "print(MPI.Get_library_version().splitlines()[0])"],
                                             capture_output=True, text=True, timeout=60).stdout.strip()
    except Exception:  # noqa: BLE001
        info["mpi_library"] = None
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        info["git_commit"] = subprocess.run(["git", "-C", root, "rev-parse", "HEAD"], capture_output=True,
                                            text=True, timeout=10).stdout.strip() or None
    except Exception:  # noqa: BLE001
        info["git_commit"] = None
    return info


def reference_key(point):
    """The key of the serial point with the same run parameters (the reference T(1) and state of its
    speedup and error columns); the block grid's options (update_grid, balance) and newton are the
    MPI points' alone, so the serial point has them unset."""
    from dataclasses import replace
    from bench.sweep.points import SERIAL
    return replace(point, mapping=SERIAL, scheme="", update_grid=0, balance="extent", newton="auto").key


def merge_manifest(out, info, entry):
    """This sweep's manifest `info` with the folder's earlier one folded in (issue 15: the manifest
    accumulates): the earlier points kept in their order, then this sweep's new ones (a point's
    entry is this sweep's when it runs it again), `load` per point merged, `created` the first
    sweep's, and `sweeps` the history, one entry per sweep (`entry`: its start, command, points
    and repeats) appended. An unreadable earlier manifest is kept as manifest.json.broken."""
    path = os.path.join(out, "manifest.json")
    old = {}
    if os.path.exists(path):
        try:
            with open(path) as fh:
                old = json.load(fh)
            if not isinstance(old, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError):
            try:
                os.replace(path, path + ".broken")
            except OSError:
                pass
            old = {}
    points = {p["key"]: p for p in old.get("points", []) if isinstance(p, dict) and "key" in p}
    order = list(points)
    for p in info["points"]:
        if p["key"] not in points:
            order.append(p["key"])
        points[p["key"]] = p
    info["points"] = [points[k] for k in order]
    info["load"] = dict(old.get("load") or {}, **(info.get("load") or {}))
    info["created"] = old.get("created", info.get("created"))
    info["sweeps"] = list(old.get("sweeps") or []) + [entry]
    return info


def amdahl(rows):
    """Least-squares Amdahl serial fraction f from 1/S = f (1 - 1/p) + 1/p over the done points
    with p > 1 cores (p = processes x threads). Points of several particle counts (the granularity
    study) are not pooled: serial_fraction is None and `by_particles` holds one fit a count."""
    counts = sorted({int(_num(r.get("particles"))) for r in rows if math.isfinite(_num(r.get("particles")))})
    if len(counts) > 1:
        return {"serial_fraction": None, "points": 0, "by_particles": {
            str(n): _amdahl_fit([r for r in rows if _num(r.get("particles")) == n]) for n in counts}}
    return _amdahl_fit(rows)


def _amdahl_fit(rows):
    pts = [(float(r["speedup"]), int(r["cores"])) for r in rows
           if r["status"] == "done" and int(r["cores"]) > 1 and r["speedup"] == r["speedup"]]
    if not pts:
        return {"serial_fraction": None, "points": 0}
    x = np.array([1 - 1 / p for _, p in pts])
    y = np.array([1 / s - 1 / p for s, p in pts])
    f = float(np.dot(x, y) / np.dot(x, x))
    out = {"serial_fraction": f, "points": len(pts), "valid": 0.0 <= f <= 1.0,
           "model": "1/S = f (1 - 1/p) + 1/p, least squares over points with p > 1"}
    if not out["valid"]:
        out["note"] = ("f outside [0, 1]: the points are not Amdahl-limited (slower than serial, e.g. a "
                       "loaded or oversubscribed machine, or superlinear); do not read f as a serial fraction")
    return out


def load(path):
    """(runs, steps) DataFrames of a sweep folder; steps gathers every point's steps.csv with
    `point` and `rep` columns."""
    import pandas as pd
    runs = pd.read_csv(os.path.join(path, "runs.csv"))
    frames = []
    for key in runs["point"]:
        pdir = os.path.join(path, key)
        if not os.path.isdir(pdir):
            continue
        for rep in sorted(os.listdir(pdir)):
            f = os.path.join(pdir, rep, "steps.csv")
            if os.path.exists(f):
                frames.append(pd.read_csv(f).assign(point=key, rep=rep))
    steps = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return runs, steps
