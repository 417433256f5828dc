"""`bench sweep`: run one scene under many process/thread mappings and record the metrics.

Every point (mapping x scheme) runs as its own process, `python -m bench run ...` (which starts
mpiexec itself for P > 1), in DIR/<point>/rep<r>/ with its command line, stdout, stderr,
run.json, steps.csv and state.npz. The serial point 1-1-1-1-1 is the reference T(1) and the
reference state for the error columns; it is added (and run first) when missing. After every
point DIR/runs.csv is rewritten atomically, so an interrupted sweep leaves a consistent file;
--resume skips the points already done (identified by their parameters). A point that crashes,
hangs past its timeout or goes unstable is recorded with its status and reason, and the sweep
goes on. Module times per point (DESIGN.md): totalT = mean over steps of the max over ranks,
commuT and migraT = mean over steps of the per-rank mean, compuT = totalT - commuT - migraT;
syncT = mean over steps of the per-rank mean of syncT (the step's one allreduce, part of commuT:
waiting for the slowest rank + the collective's latency; NaN without MPI or when steps.csv has no
syncT); wireT = mean over steps of the per-rank mean of wire_s (the modelled wire time of what a
rank sent, modes/wire.py), above_wireT = commuT + migraT - syncT - wireT (the software above the
wire in the exchanges; commuT + migraT - wireT where syncT is NaN, older records; both NaN
without MPI or when steps.csv has no wire_s); with --repeats R the median over the R runs.
"""
import hashlib
import json
import math
import os
import shlex
import subprocess
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np

from bench.sweep_plots import RUN_COLUMNS  # noqa: E402  (one list: the records' contract)
SERIAL = "1-1-1-1-1"


@dataclass(frozen=True)
class Point:
    """One sweep point: a mapping and, with threads, a scheme; the run parameters it shares."""
    mapping: str
    scheme: str
    scene: str
    particles: int
    steps: int
    warmup: int
    neighbor: str
    shape: str
    pin: bool
    halo: str
    contact_method: str = "exact"

    @property
    def key(self):
        """Folder name: readable mapping and scheme plus a hash of every parameter."""
        digest = hashlib.sha1(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:8]
        return f"{self.mapping}{'-' + self.scheme if self.scheme else ''}-{digest}"

    def run_args(self, out, timeout):
        args = ["run", "--scene", self.scene, "--mapping", self.mapping, "--neighbor", self.neighbor,
                "--warmup", str(self.warmup), "--out", out, "--quiet", "--timeout", str(timeout)]
        for flag, v in (("--particles", self.particles), ("--steps", self.steps), ("--shape", self.shape),
                        ("--scheme", self.scheme)):
            if v:
                args += [flag, str(v)]
        if self.pin:
            args.append("--pin")
        if self.contact_method != "exact":
            args += ["--contact-method", self.contact_method]
        if self.mapping.split("-")[0] != "1":
            args += ["--halo", self.halo]
        return args


def make_points(mappings, schemes, scene, particles, steps, warmup, neighbor, shape, pin, halo,
                contact_method="exact"):
    """Points of a sweep: the serial reference first, then each mapping (x each scheme when it has
    more than one thread), without duplicates, in the order given."""
    from modes.base import parse_mapping
    from modes.parallel import SCHEMES
    for s in schemes:
        if s not in SCHEMES:
            from modes.base import ModeError
            raise ModeError(f"unknown scheme {s!r} (schemes: {', '.join(SCHEMES)})")
    parsed = [parse_mapping(m) for m in mappings]  # one clear line for a malformed mapping
    if SERIAL not in [str(m) for m in parsed]:
        parsed.insert(0, parse_mapping(SERIAL))
    points = []
    for m in parsed:
        for s in (schemes if m.threads > 1 else [""]):
            p = Point(str(m), s, scene, particles or 0, steps or 0, warmup, neighbor, shape or "", pin, halo,
                      contact_method)
            if p not in points:
                points.append(p)
    points.sort(key=lambda p: p.mapping != SERIAL)  # the reference runs first
    return points


# --- records ---------------------------------------------------------------------------------------
def module_times(steps):
    """Per-step module times of one run (DESIGN.md): dict of totalT, commuT, migraT, compuT,
    syncT (mean over steps of the per-rank mean of syncT [s], the allreduce inside commuT; NaN
    without a syncT column or with it empty, as serial and thread runs leave it), wireT (mean
    over steps of the per-rank mean of wire_s [s]; NaN without a wire_s column), above_wireT =
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
    for col, key in (("wire_s", "wireT"), ("syncT", "syncT")):
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


def summarise(point, rep_dirs, ref_state, t1):
    """One runs.csv row from the repeat folders of a point."""
    import pandas as pd
    from modes.base import parse_mapping
    m = parse_mapping(point.mapping)
    row = {c: math.nan for c in RUN_COLUMNS}
    row.update(point=point.key, mapping=point.mapping, procs=m.procs, px=m.px, py=m.py, pz=m.pz, threads=m.threads,
               cores=m.procs * m.threads, scheme=point.scheme, neighbor=point.neighbor, scene=point.scene,
               contact_method=point.contact_method,
               repeats=len(rep_dirs), status="done", reason="")
    times, walls = [], []
    state = None
    for d in rep_dirs:
        status = _read_status(d)
        if status["status"] != "done":
            row.update(status=status["status"], reason=status["reason"])
            return row
        info = json.load(open(os.path.join(d, "run.json")))
        times.append(module_times(pd.read_csv(os.path.join(d, "steps.csv"))))
        walls.append(info.get("wall_s", math.nan))
        row.update(particles=info["particles"], steps=info["steps"], stable=info["stable"])
        state = dict(np.load(os.path.join(d, "state.npz")))
    for k in times[0]:
        row[k] = float(np.median([t[k] for t in times]))
    if m.procs == 1:  # no MPI, no wire, no allreduce (a serial steps.csv may carry wire_s = 0)
        row["syncT"] = row["wireT"] = row["above_wireT"] = math.nan
    row["wall_s"] = float(np.median(walls))
    row["overhead_pct"] = 100.0 * (row["commuT"] + row["migraT"]) / row["totalT"] if row["totalT"] > 0 else math.nan
    if t1:
        s = t1 / row["totalT"]
        p = row["cores"]
        row.update(speedup=s, efficiency=s / p, edsf=(1 / s - 1 / p) / (1 - 1 / p) if p > 1 else math.nan)
    row["err_max"], row["err_rms"] = state_error(ref_state, state)
    return row


def _read_status(d):
    """status and reason of one run folder from its files (written by _run_point)."""
    path = os.path.join(d, "status.json")
    if os.path.exists(path):
        return json.load(open(path))
    # a folder filled by a batch job: judge by run.json
    run = os.path.join(d, "run.json")
    if os.path.exists(run):
        info = json.load(open(run))
        if info.get("status") == "done" and os.path.exists(os.path.join(d, "state.npz")):
            return {"status": "done", "reason": ""}
        if info.get("stable") is False:
            return {"status": "unstable", "reason": info.get("stability_reason") or "unstable"}
    return {"status": "failed", "reason": "no result (not run, interrupted or crashed)"}


def write_runs(path, rows):
    """runs.csv, atomically (tmp file + rename): an interrupted sweep never leaves half a file."""
    import pandas as pd
    tmp = path + ".tmp"
    pd.DataFrame(rows, columns=RUN_COLUMNS).to_csv(tmp, index=False)
    os.replace(tmp, path)


def manifest(out, points):
    """DIR/manifest.json: versions, MPI library, numba threading layer, CPU, git commit."""
    import platform
    info = {"python": sys.version.split()[0], "platform": platform.platform(), "cpu_count": os.cpu_count(),
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "points": [asdict(p) | {"key": p.key} for p in points]}
    try:
        info["usable_cpus"] = len(os.sched_getaffinity(0))
    except AttributeError:
        pass
    for mod in ("numpy", "numba", "mpi4py", "pandas", "matplotlib", "psutil", "llvmlite"):
        try:
            info[mod] = __import__(mod).__version__
        except Exception:  # noqa: BLE001  (a missing optional package is just not listed)
            info[mod] = None
    try:
        with open("/proc/cpuinfo") as fh:
            info["cpu_model"] = next((l.split(":", 1)[1].strip() for l in fh if l.startswith("model name")), None)
    except OSError:
        info["cpu_model"] = None
    try:
        info["mpi_library"] = subprocess.run([sys.executable, "-c", "from mpi4py import MPI; "
                                              "print(MPI.Get_library_version().splitlines()[0])"],
                                             capture_output=True, text=True, timeout=60).stdout.strip()
    except Exception:  # noqa: BLE001
        info["mpi_library"] = None
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        info["git_commit"] = subprocess.run(["git", "-C", root, "rev-parse", "HEAD"], capture_output=True,
                                            text=True, timeout=10).stdout.strip() or None
    except Exception:  # noqa: BLE001
        info["git_commit"] = None
    return info


# --- running -----------------------------------------------------------------------------------------
def _run_point(point, out, timeout, env):
    """Run one repeat of a point in `out`; write cmd.txt, stdout.txt, stderr.txt, status.json."""
    os.makedirs(out, exist_ok=True)
    cmd = [sys.executable, "-m", "bench"] + point.run_args(out, timeout)
    with open(os.path.join(out, "cmd.txt"), "w") as fh:
        fh.write(shlex.join(cmd) + "\n")
    for f in ("status.json",):
        if os.path.exists(os.path.join(out, f)):
            os.remove(os.path.join(out, f))
    with open(os.path.join(out, "stdout.txt"), "w") as so, open(os.path.join(out, "stderr.txt"), "w") as se:
        try:
            # bench run kills its own MPI ranks at `timeout`; this outer limit only catches a stuck start
            rc = subprocess.run(cmd, stdout=so, stderr=se, env=env, timeout=timeout + min(120, timeout)).returncode
        except subprocess.TimeoutExpired:
            rc = None
    err = open(os.path.join(out, "stderr.txt")).read().strip().splitlines()
    last = next((l for l in reversed(err) if l.strip() and "warning" not in l), "")
    if rc is None or rc == 3:
        status = {"status": "timeout", "reason": f"no result within {timeout} s"}
    elif rc == 0:
        status = {"status": "done", "reason": ""}
    elif rc == 1 and os.path.exists(os.path.join(out, "run.json")) and \
            json.load(open(os.path.join(out, "run.json"))).get("stable") is False:
        status = {"status": "unstable", "reason": last}
    else:
        status = {"status": "failed", "reason": last or f"exit status {rc}"}
    with open(os.path.join(out, "status.json"), "w") as fh:
        json.dump(status, fh)
    return status


def sweep(args):
    """The `bench sweep` command (args from bench.cli)."""
    from bench.run import prepare_output
    from bench.records import write_json
    mappings = [m.strip() for m in args.mappings.split(",") if m.strip()]
    schemes = [s.strip() for s in (args.schemes or "dynamic").split(",") if s.strip()]
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
    if getattr(args, "launcher", "local") == "slurm" or args.dry_run:
        from bench.slurm import plan
        return plan(args, points, out)
    info = manifest(out, points)
    info["load"] = {}
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
                st = _run_point(p, r, args.timeout, env)
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
            if r["status"] == "done" and r["totalT"] == r["totalT"]:
                s = t1 / float(r["totalT"])
                p = int(r["cores"])
                r.update(speedup=s, efficiency=s / p, edsf=(1 / s - 1 / p) / (1 - 1 / p) if p > 1 else math.nan)
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
    from bench.sweep_plots import plot_sweep
    figs = plot_sweep(out)
    print(f"records: {runs_path}; figures: {', '.join(os.path.basename(f) for f in figs)}")
    failed = [r for r in rows.values() if r["status"] != "done"]
    return 0 if not failed else 4


def amdahl(rows):
    """Least-squares Amdahl serial fraction f from 1/S = f (1 - 1/p) + 1/p over the done points
    with p > 1 cores (p = processes x threads)."""
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
