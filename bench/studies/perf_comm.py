"""`bench perf --what comm [--procs P] [--mapping P-px-py-pz-T] [--out DIR]`: the wire under the halo.

P ranks on the mapping's block grid (default 2-2-1-1-1; `--procs P` alone takes the most cubic
grid, as MPI_Dims_create does) measure an OSU-style ping-pong with each of their up to 26
neighbour blocks (modes.wire.pingpong; started as
`mpiexec -n P python -m mpi4py -m bench.studies.perf_comm_rank ...`, killed after --timeout seconds).
Printed per pair, as the OSU micro-benchmarks' osu_latency does: size [B], one-way latency
t(n) = round trip / 2 [us] and the ping-pong bandwidth n / t(n) [MB/s, 1 MB = 1e6 B]; then the
fitted t(n) = alpha + n / beta (Hockney). With --out DIR, DIR/perf.json holds the pairs, every
rank's partner table ({"<rank>": {"latency_s", "bandwidth_Bps", ...}}, the form run.json's
"wire" entry takes) and a summary. T of the mapping is ignored (ranks only, no threads).
More ranks than usable CPUs run (correctness), with a one-line warning: the latency then
measures the scheduler, not the wire. `--patterns` also times the forward exchange's candidate
MPI patterns (new Isend/Irecv, persistent requests, Neighbor_alltoallv) on the same grid: the
measurement behind modes.halo's choice.
"""
import json
import os
import signal
import subprocess
import sys
import tempfile

import numpy as np

from bench.run.launch import mpiexec_path
from bench.run.threads_env import usable_cpus
from bench.run.transport import transport_env
from modes.base import ModeError, parse_mapping

DEFAULT_MAPPING = "2-2-1-1-1"


def dims_create(procs):
    """A px >= py >= pz grid with px py pz = procs, as balanced as possible (MPI_Dims_create's rule):
    each prime factor, largest first, multiplies the smallest dimension."""
    f, n, k = [], procs, 2
    while k * k <= n:
        while n % k == 0:
            f.append(k)
            n //= k
        k += 1
    if n > 1:
        f.append(n)
    dims = [1, 1, 1]
    for q in sorted(f, reverse=True):
        dims[dims.index(min(dims))] *= q
    return sorted(dims, reverse=True)


def resolve_mapping(procs, mapping, what="comm"):
    """The Mapping to measure from --procs / --mapping (ModeError, one line, when they disagree,
    are malformed, or give fewer than 2 ranks); what names the study in that line."""
    if mapping:
        m = parse_mapping(mapping)
        if procs is not None and procs != m.procs:
            raise ModeError(f"--procs {procs} but mapping {mapping} has P = {m.procs}")
    elif procs is not None:
        px, py, pz = dims_create(procs)
        m = parse_mapping(f"{procs}-{px}-{py}-{pz}-1")
    else:
        m = parse_mapping(DEFAULT_MAPPING)
    if m.procs < 2:
        why = {"comm": "MPI ping-pong", "forward": "ghosts to forward"}[what]
        raise ModeError(f"--what {what} needs at least 2 ranks ({why}), got P = {m.procs}")
    return m


def _pairs(doc):
    """One record per unordered pair (from the pinging, lower rank), sorted by (a, b)."""
    coords = {r["rank"]: r["coords"] for r in doc["ranks"]}
    out = []
    for r in doc["ranks"]:
        for p, rec in r["partners"].items():
            b = int(p)
            if r["rank"] < b:
                out.append({"a": r["rank"], "b": b, "coords_a": coords[r["rank"]], "coords_b": coords[b],
                            "directions": r["directions"].get(p, [])} | rec)
    return sorted(out, key=lambda q: (q["a"], q["b"]))


def _summary(pairs):
    def stats(vals):
        v = np.asarray(vals, dtype=float)
        v = v[np.isfinite(v)]
        if not len(v):
            return None
        return {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max())}
    return {"pairs": len(pairs), "latency_s": stats([q["latency_s"] for q in pairs]),
            "bandwidth_Bps": stats([q["bandwidth_Bps"] for q in pairs])}


def print_table(report, file=sys.stdout):
    """OSU-style table per pair and the fitted alpha / beta."""
    pr = lambda *a: print(*a, file=file)  # noqa: E731
    pr(f"# bench perf --what comm: MPI ping-pong, {report['procs']} ranks on a "
       f"{'x'.join(str(d) for d in report['dims'])} grid (mapping {report['mapping']}), "
       f"{len(report['pairs'])} neighbour pair{'s' if len(report['pairs']) != 1 else ''}, "
       f"{' '.join(report['mpi_library'].split())}, {report['wall_s']:.2f} s")
    pr("# one-way t(n) = round trip / 2 (OSU osu_latency); bandwidth = n / t(n), 1 MB = 1e6 B")
    for q in report["pairs"]:
        pr(f"# pair {q['a']} <-> {q['b']}: blocks {tuple(q['coords_a'])} <-> {tuple(q['coords_b'])}")
        pr(f"# {'Size [B]':<10s}{'Latency [us]':>16s}{'Bandwidth [MB/s]':>20s}{'iterations':>12s}")
        for n, t, k in zip(q["sizes"], q["one_way_s"], q["iterations"]):
            pr(f"  {n:<10d}{1e6 * t:>16.2f}{(n / t / 1e6 if t > 0 else float('nan')):>20.2f}{k:>12d}")
        pr(f"# fit t(n) = alpha + n / beta: alpha = {1e6 * q['latency_s']:.3f} us, "
           f"beta = {q['bandwidth_Bps'] / 1e6:.1f} MB/s")
    if "patterns" in report:
        sizes = list(next(iter(report["patterns"].values())))
        pr("# forward exchange, every rank with all its neighbours at once (modes.wire.exchange_patterns): "
           "time per exchange, slowest rank, best of 2")
        pr(f"# {'pattern':<20s}" + "".join(f"{n + ' B':>12s}" for n in sizes))
        for name, v in report["patterns"].items():
            pr(f"  {name:<20s}" + "".join(f"{1e6 * v[n]:>10.2f}us" for n in sizes))
    s = report["summary"]
    if s["latency_s"]:
        pr(f"# over {s['pairs']} pairs: alpha {1e6 * s['latency_s']['min']:.3f} / "
           f"{1e6 * s['latency_s']['median']:.3f} / {1e6 * s['latency_s']['max']:.3f} us (min / median / max), "
           f"beta {s['bandwidth_Bps']['min'] / 1e6:.1f} / {s['bandwidth_Bps']['median'] / 1e6:.1f} / "
           f"{s['bandwidth_Bps']['max'] / 1e6:.1f} MB/s")


def perf_comm(args):
    """The `bench perf --what comm` command (args from bench.cli). Exit 0, 3 on timeout, 1 when
    the ranks fail."""
    m = resolve_mapping(getattr(args, "procs", None), getattr(args, "mapping", None))
    timeout = getattr(args, "timeout", None) or 120
    exe = mpiexec_path()
    if exe is None:
        raise ModeError("bench perf --what comm needs mpiexec (pip install mpich, or a system MPI)")
    out = getattr(args, "out", None)
    if out:
        try:
            os.makedirs(out, exist_ok=True)
        except OSError as e:
            raise ModeError(f"cannot create output folder {out}: {e.strerror}") from None
        if not os.access(out, os.W_OK):
            raise ModeError(f"output folder {out} is not writable")
    cpus = usable_cpus()
    oversubscribed = m.procs > cpus
    if oversubscribed:
        print(f"bench: warning: {m.procs} ranks on {cpus} usable CPUs oversubscribes them: the ping-pong "
              f"runs (correctness) but its latency measures the scheduler, not the wire", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="bench-comm-") as tmp:
        raw = os.path.join(tmp, "ranks.json")
        cmd = [exe, "-n", str(m.procs), sys.executable, "-m", "mpi4py", "-m", "bench.studies.perf_comm_rank",
               "--dims", str(m.px), str(m.py), str(m.pz), "--json", raw]
        if getattr(args, "patterns", False):
            cmd.append("--patterns")
        try:
            proc = subprocess.Popen(cmd, start_new_session=True, env=transport_env(dict(os.environ)))
            rc = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            print(f"bench: error: {m.procs} ping-pong ranks did not finish within {timeout} s; killed",
                  file=sys.stderr)
            return 3
        if rc != 0 or not os.path.exists(raw):
            print(f"bench: error: the ping-pong ranks failed (exit status {rc})", file=sys.stderr)
            return 1
        with open(raw) as fh:
            doc = json.load(fh)
    pairs = _pairs(doc)
    report = {"what": "comm", "mapping": str(m), "procs": m.procs, "dims": doc["dims"], "sizes": doc["sizes"],
              "time_per_size_s": doc["time_per_size_s"], "wall_s": doc["wall_s"],
              "mpi_library": doc["mpi_library"], "mpi_wtick_s": doc["mpi_wtick_s"], "usable_cpus": cpus,
              "oversubscribed": oversubscribed,
              "model": "t(n) = alpha + n / beta, least squares on relative residuals (modes/wire.py)",
              "pairs": pairs, "summary": _summary(pairs),
              "ranks": {str(r["rank"]): {"coords": r["coords"], "host": r["host"], "directions": r["directions"],
                                         "partners": r["partners"]} for r in doc["ranks"]}}
    if "patterns" in doc:
        report["patterns"] = doc["patterns"]
    print_table(report)
    if out:
        with open(os.path.join(out, "perf.json"), "w") as fh:
            json.dump(report, fh, indent=1)
        print(f"# wrote {os.path.join(out, 'perf.json')}")
    return 0
