"""The wire under the halo (modes/wire.py, `bench perf --what comm`): the alpha-beta model's
arithmetic and fit without MPI, and the OSU-style ping-pong under a real mpiexec started here
with a timeout (its process group killed on expiry)."""
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from modes.wire import WireError, WireModel, fit_alpha_beta
from tests.helpers import ROOT, bench, one_line_error

MPIEXEC = os.path.join(os.path.dirname(sys.executable), "mpiexec")
MPIEXEC = MPIEXEC if os.path.exists(MPIEXEC) else shutil.which("mpiexec")
needs_mpi = pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")

TABLE = {1: {"latency_s": 2e-6, "bandwidth_Bps": 5e9}, "3": {"latency_s": 1e-6, "bandwidth_Bps": 1e9}}


# --- the model, no MPI -----------------------------------------------------------------------------
def test_cost_of_one_message():
    """cost = alpha + n / beta: to rank 1, 1e6 B take 2 us + 1e6 / 5e9 s = 202 us; a count message
    of 0 B costs alpha alone (2 us); str keys (run.json's form) work like int keys."""
    w = WireModel(TABLE)
    assert w.partners == [1, 3]
    assert w.cost(1, 1_000_000) == pytest.approx(2e-6 + 2e-4, rel=1e-15)
    assert w.cost(1, 0) == 2e-6
    assert w.cost(3, 1000) == pytest.approx(1e-6 + 1e-6, rel=1e-15)


def test_cost_of_a_steps_messages():
    """The sum over a rank's sends: two count messages (0 B) to 1 and 3, then 1e6 B to 1 and 1e3 B
    to 3: (2 + 1 + 202 + 2) us = 207 us; a scalar size applies to every message; no message
    costs 0."""
    w = WireModel(TABLE)
    assert w.cost_messages([1, 3, 1, 3], [0, 0, 1_000_000, 1000]) == pytest.approx(207e-6, rel=1e-12)
    assert w.cost_messages(np.array([1, 1, 3]), 0) == pytest.approx(5e-6, rel=1e-12)
    assert w.cost_messages([], []) == 0.0
    # the run.json form round-trips
    again = WireModel(json.loads(json.dumps(w.as_dict())))
    assert again.cost_messages([1, 3], [10, 20]) == w.cost_messages([1, 3], [10, 20])


@pytest.mark.parametrize("bad", ["partner", "negative", "shape", "table", "bandwidth"])
def test_model_bad_input(bad):
    """Unknown partner, negative size, mismatched arrays, a malformed table, zero bandwidth: one
    WireError each (a ValueError with a one-line message)."""
    with pytest.raises(WireError) as e:
        if bad == "partner":
            WireModel(TABLE).cost(2, 8)
        elif bad == "negative":
            WireModel(TABLE).cost_messages([1], [-1])
        elif bad == "shape":
            WireModel(TABLE).cost_messages([1, 3], [1, 2, 3])
        elif bad == "table":
            WireModel({0: {"latency_s": 1e-6}})
        else:
            WireModel({0: {"latency_s": 1e-6, "bandwidth_Bps": 0.0}})
    assert "\n" not in str(e.value)


def test_fit_recovers_the_model():
    """Times made by t = 2 us + n / 5 GB/s at the default sizes: the fit gives alpha = 2e-6 s and
    beta = 5e9 B/s back (to 1e-9 relative: the data are exact)."""
    n = np.array([8, 64, 512, 4096, 32768, 262144, 1048576], dtype=float)
    a, b = fit_alpha_beta(n, 2e-6 + n / 5e9)
    assert a == pytest.approx(2e-6, rel=1e-9) and b == pytest.approx(5e9, rel=1e-9)


def test_fit_bounds():
    """alpha >= 0: times of n / 1 GB/s minus 0.1 us (a negative intercept) give alpha = 0 exactly;
    times that do not grow with size (all 3 us) give beta = inf and alpha = 3 us."""
    n = np.array([512, 4096, 32768, 262144], dtype=float)
    a, b = fit_alpha_beta(n, n / 1e9 - 1e-7)
    assert a == 0.0 and 0.9e9 < b < 1.1e9
    a, b = fit_alpha_beta(n, np.full(4, 3e-6))
    assert a == pytest.approx(3e-6, rel=1e-12) and b == math.inf


# --- the ping-pong under mpiexec -------------------------------------------------------------------
SCRIPT = """
import json, sys, time
from mpi4py import MPI
from modes.wire import WireError, pingpong
comm = MPI.COMM_WORLD
me, size = comm.Get_rank(), comm.Get_size()
mode = sys.argv[2]
partners = {"all": [r for r in range(size) if r != me],
            "asymmetric": [1] if me == 0 else []}[mode]
t0 = time.perf_counter()
try:
    res = {str(k): v for k, v in pingpong(comm, partners).items()}
    err = None
except WireError as e:
    res, err = {}, str(e)
rec = {"rank": me, "seconds": time.perf_counter() - t0, "partners": res, "error": err}
with open(f"{sys.argv[1]}/rank{me}.json", "w") as fh:
    json.dump(rec, fh)
"""


def run_ranks(tmp_path, n, mode, timeout=120):
    """Start `mpiexec -n n python script` in its own session; kill the group after `timeout` s.
    Returns {rank: record}."""
    script = tmp_path / "pp.py"
    script.write_text(textwrap.dedent(SCRIPT))
    env = dict(os.environ, PYTHONPATH=ROOT)
    proc = subprocess.Popen([MPIEXEC, "-n", str(n), sys.executable, str(script), str(tmp_path), mode], cwd=ROOT,
                            env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"{n} ranks ({mode}) did not finish within {timeout} s: deadlock?")
    assert proc.returncode == 0, err
    return {r: json.loads((tmp_path / f"rank{r}.json").read_text()) for r in range(n)}


def spearman(x, y):
    rx, ry = np.argsort(np.argsort(x)), np.argsort(np.argsort(y))
    return float(np.corrcoef(rx, ry)[0, 1])


def check_pair(recs, a, b):
    """Both ends of {a, b} hold the same numbers; alpha > 0 finite, beta > 0 finite; the one-way
    time grows with size overall (rank correlation >= 0.6 over the 7 sizes, 1 MiB above 8 B)."""
    ra, rb = recs[a]["partners"][str(b)], recs[b]["partners"][str(a)]
    assert ra == rb
    assert ra["pinger"] == min(a, b)
    assert 0.0 < ra["latency_s"] < 1e-2 and math.isfinite(ra["latency_s"])
    assert 0.0 < ra["bandwidth_Bps"] < math.inf
    t = np.array(ra["one_way_s"])
    assert ra["sizes"] == [8, 64, 512, 4096, 32768, 262144, 1048576] and len(t) == 7 and (t > 0).all()
    assert t[-1] > t[0]
    assert spearman(ra["sizes"], t) >= 0.6, t


@needs_mpi
def test_pingpong_two_ranks(tmp_path):
    """2 ranks pinging each other: one pair, the same alpha / beta on both ends, and the whole
    measurement under 1.5 s (about 30 ms when the 2 cores are free: 7 sizes x 2 ms + warm-up)."""
    recs = run_ranks(tmp_path, 2, "all")
    assert all(r["error"] is None for r in recs.values())
    assert list(recs[0]["partners"]) == ["1"] and list(recs[1]["partners"]) == ["0"]
    check_pair(recs, 0, 1)
    assert max(r["seconds"] for r in recs.values()) < 1.5


@needs_mpi
def test_pingpong_three_ranks_every_pair(tmp_path):
    """3 ranks (oversubscribed on 2 cores), each pinging both others: the three pairs (0,1), (0,2),
    (1,2) in the global order finish (no deadlock) and each pair's two ends agree."""
    recs = run_ranks(tmp_path, 3, "all")
    for r in range(3):
        assert sorted(recs[r]["partners"]) == [str(q) for q in range(3) if q != r]
    for a, b in ((0, 1), (0, 2), (1, 2)):
        ra, rb = recs[a]["partners"][str(b)], recs[b]["partners"][str(a)]
        assert ra == rb and ra["latency_s"] > 0 and ra["bandwidth_Bps"] > 0


@needs_mpi
def test_pingpong_asymmetric_partners_refused(tmp_path):
    """Rank 0 lists rank 1 but rank 1 lists nobody: both ranks raise the same WireError before any
    message (so nobody waits for a partner that never comes)."""
    recs = run_ranks(tmp_path, 2, "asymmetric", timeout=60)
    assert recs[0]["error"] == recs[1]["error"]
    assert "rank 0 lists rank 1 but rank 1 does not list rank 0" in recs[0]["error"]


# --- bench perf --what comm ------------------------------------------------------------------------
def test_dims_create():
    """The most cubic px >= py >= pz grid (MPI_Dims_create's rule): 2 -> 2x1x1, 12 -> 3x2x2,
    16 -> 4x2x2, 27 -> 3x3x3, 7 (prime) -> 7x1x1."""
    from bench.studies.perf_comm import dims_create
    assert [dims_create(p) for p in (2, 12, 16, 27, 7)] == [[2, 1, 1], [3, 2, 2], [4, 2, 2], [3, 3, 3], [7, 1, 1]]


@needs_mpi
def test_perf_comm_two_ranks(tmp_path):
    """`bench perf --what comm --procs 2 --out DIR`: exit 0, the OSU-style table (7 size rows and a
    fit line for the single pair 0 <-> 1) on stdout, and DIR/perf.json with that pair and both
    ranks' partner tables (the same alpha, beta seen from each end)."""
    res = bench("perf", "--what", "comm", "--procs", "2", "--out", str(tmp_path), timeout=180)
    assert res.returncode == 0, res.stderr
    assert "# pair 0 <-> 1" in res.stdout and "Latency [us]" in res.stdout and "Bandwidth [MB/s]" in res.stdout
    rows = [l for l in res.stdout.splitlines() if l.strip() and not l.startswith("#")]
    assert [int(l.split()[0]) for l in rows] == [8, 64, 512, 4096, 32768, 262144, 1048576]
    assert res.stdout.count("# fit t(n) = alpha + n / beta") == 1
    rep = json.loads((tmp_path / "perf.json").read_text())
    assert rep["mapping"] == "2-2-1-1-1" and rep["dims"] == [2, 1, 1] and len(rep["pairs"]) == 1
    p0, p1 = rep["ranks"]["0"]["partners"]["1"], rep["ranks"]["1"]["partners"]["0"]
    assert p0["latency_s"] == p1["latency_s"] > 0 and p0["bandwidth_Bps"] == p1["bandwidth_Bps"] > 0
    assert WireModel(rep["ranks"]["0"]).cost(1, 0) == p0["latency_s"]


@needs_mpi
def test_perf_comm_default_grid(tmp_path):
    """--mapping 4-2-2-1-1 puts 4 ranks on 2x2x1 blocks, where every block neighbours every other
    (two faces and the diagonal edge of the 26 directions): C(4, 2) = 6 pairs, each rank with 3
    partners; 4 ranks on fewer than 4 usable CPUs print the one-line oversubscription warning."""
    res = bench("perf", "--what", "comm", "--mapping", "4-2-2-1-1", "--out", str(tmp_path), timeout=240)
    assert res.returncode == 0, res.stderr
    rep = json.loads((tmp_path / "perf.json").read_text())
    assert [(q["a"], q["b"]) for q in rep["pairs"]] == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert all(len(r["partners"]) == 3 for r in rep["ranks"].values())
    from bench.run.threads_env import usable_cpus
    if usable_cpus() < 4:
        assert rep["oversubscribed"]
        assert [l for l in res.stderr.splitlines() if "oversubscribes" in l][0].startswith("bench: warning:")


@needs_mpi
def test_perf_comm_patterns(tmp_path):
    """--patterns times the forward exchange's three MPI patterns (modes.halo's choice) at the
    three message sizes of modes.wire.PATTERN_SIZES (a ghost's 104-byte forward record, and 120 and
    500 of them): every pattern and size present in perf.json with a positive finite time, and one
    table row per pattern on stdout."""
    from modes.wire import PATTERN_SIZES, PATTERNS
    res = bench("perf", "--what", "comm", "--procs", "2", "--patterns", "--out", str(tmp_path), timeout=180)
    assert res.returncode == 0, res.stderr
    pat = json.loads((tmp_path / "perf.json").read_text())["patterns"]
    assert sorted(pat) == sorted(PATTERNS) and PATTERN_SIZES == (104, 12480, 52000)
    for name in PATTERNS:
        assert sorted(int(n) for n in pat[name]) == list(PATTERN_SIZES)
        assert all(0 < t < 1e-2 and math.isfinite(t) for t in pat[name].values())
        assert sum(1 for l in res.stdout.splitlines() if l.split()[:1] == [name]) == 1

@pytest.mark.parametrize("argv,words", [
    (["--procs", "0"], ["--procs"]),
    (["--mapping", "2-2-1"], ["malformed mapping"]),
    (["--mapping", "3-2-1-1-1"], ["P = 3"]),
    (["--procs", "1"], ["at least 2 ranks"]),
    (["--procs", "3", "--mapping", "2-2-1-1-1"], ["--procs 3"]),
])
def test_perf_comm_bad_input(argv, words):
    """Bad --procs / --mapping: one line, exit 2, no traceback, no mpiexec started."""
    one_line_error(bench("perf", "--what", "comm", *argv, timeout=120), *words)
