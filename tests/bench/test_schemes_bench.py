"""`bench schemes` end to end (Table 1 in kind): one row per configuration, the paper's columns,
and the per-thread work split of the explicit schemes; no timing assertions."""
import csv
import math
import os
import subprocess
import sys

import pytest

from tests.helpers import ROOT

PAPER = os.path.join(ROOT, "bench", "studies", "paper",
                     "table1_thread_schemes.csv")  # the paper's Table 1, package data
SCHEMES = ("partition", "frogleap", "headtail", "static", "dynamic")
N, T = 300, 2


def _rows_tests(n, rows):
    """All-pairs pair tests of outer rows u (i against j > i): n - 1 - u each."""
    return sum(n - 1 - u for u in rows)


def test_schemes_command(tmp_path):
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=ROOT, DEM_BENCH_CACHE=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "-m", "bench", "schemes", "--particles", str(N), "--threads", str(T),
                          "--repeats", "2", "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
                         timeout=600, env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == "--- Table 1 in kind"

    with open(out / "schemes.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for col in ("family", "method", "neighbor", "threads", "particles", "detect_s", "neighbor_s", "resolve_s",
                "speedup", "efficiency", "efficiency_own", "neighbor_eff_own", "resolve_eff_own", "work_imbalance",
                "busy_imbalance", "paper_speedup", "paper_efficiency"):
        assert col in rows[0], col
    got = {(r["method"], r["neighbor"]): r for r in rows}
    want = [("serial", nb) for nb in ("allpairs", "linkcell")] + \
           [(s, nb) for s in SCHEMES for nb in ("allpairs", "linkcell")]
    assert len(rows) == 12 and sorted(got) == sorted(want)
    for r in rows:
        assert int(r["threads"]) == (1 if r["method"] == "serial" else T)
        assert float(r["detect_s"]) > 0 and float(r["speedup"]) > 0
    assert float(got[("serial", "allpairs")]["speedup"]) == 1.0
    # parallel efficiency against the serial row of the same neighbour method, whole and per phase
    for r in rows:
        own = got[("serial", r["neighbor"])]
        for col, t in (("efficiency_own", "detect_s"), ("neighbor_eff_own", "neighbor_s"),
                       ("resolve_eff_own", "resolve_s")):
            want_eff = float(own[t]) / (int(r["threads"]) * float(r[t]))
            assert math.isclose(float(r[col]), want_eff, rel_tol=1e-4), (r["method"], r["neighbor"], col)
        if r["method"] == "serial":
            assert float(r["neighbor_eff_own"]) == 1.0 and float(r["resolve_eff_own"]) == 1.0
    # each threaded efficiency's 95 % interval, paired over the 2 rounds (the serial rows are their own
    # reference: none), and issue 32's 2-core targets with their verdicts where it sets one
    targets = {("partition", "linkcell"): 0.92, ("static", "linkcell"): 0.92, ("dynamic", "linkcell"): 0.92,
               ("frogleap", "linkcell"): 0.85, ("headtail", "linkcell"): 0.85, ("dynamic", "allpairs"): 0.95}
    for (method, nb), r in got.items():
        for col in ("efficiency_own", "neighbor_eff_own", "resolve_eff_own"):
            lo, hi = float(r[f"{col}_lo"]), float(r[f"{col}_hi"])
            if method == "serial":
                assert math.isnan(lo) and math.isnan(hi)
            else:
                assert 0 < lo <= hi, (method, nb, col)
        if (method, nb) in targets:
            assert float(r["target_eff_own"]) == targets[(method, nb)]
            assert r["verdict"] in ("met", "not met", "unresolved")
        else:
            assert math.isnan(float(r["target_eff_own"])) and r["verdict"] == ""
    assert float(got[("serial", "linkcell")]["work_imbalance"]) == 1.0

    # work split (pair tests per thread) of all-pairs, i against j > i over n rows
    n = int(got[("serial", "allpairs")]["particles"])
    assert int(got[("serial", "allpairs")]["tests"]) == n * (n - 1) // 2
    # partition: thread t takes rows [t n/T, (t+1) n/T); at n = 300, T = 2 thread 0 makes
    # 33675 of the 44850 tests, so max/mean = 33675 / 22425 = 1.50167 (-> 3/2 as n grows)
    bounds = [(t * n) // T for t in range(T + 1)]
    per = [_rows_tests(n, range(bounds[t], bounds[t + 1])) for t in range(T)]
    expected = max(per) / (sum(per) / T)
    assert abs(expected - 1.5) < 0.05
    assert math.isclose(float(got[("partition", "allpairs")]["work_imbalance"]), expected, rel_tol=1e-4)
    assert abs(float(got[("partition", "allpairs")]["work_imbalance"]) - 1.5) <= 0.05
    # head-tail: row pairs (k, n-1-k) cost n-1 each, 1.0; frog-leap: rows t, t+T, ... 22500 / 22425
    for scheme in ("headtail", "frogleap"):
        assert abs(float(got[(scheme, "allpairs")]["work_imbalance"]) - 1.0) <= 0.02, scheme

    # the paper's Table 1 maps onto our all-pairs scheme rows and the two serial rows
    ours = {"n-by-n": ("serial", "allpairs"), "link-cell": ("serial", "linkcell"),
            "partitioning": ("partition", "allpairs"), "frog-leap": ("frogleap", "allpairs"),
            "head-tail": ("headtail", "allpairs"), "static": ("static", "allpairs"),
            "dynamic": ("dynamic", "allpairs")}
    with open(PAPER, newline="") as fh:
        paper = list(csv.DictReader(l for l in fh if l.strip() and not l.startswith("#")))
    assert len(paper) == 7
    for p in paper:
        r = got[ours[p["method"]]]
        assert math.isclose(float(r["paper_speedup"]), float(p["speedup"]), rel_tol=1e-9), p
        threads = 1 if p["family"] == "serial" else 12
        assert math.isclose(float(r["paper_efficiency"]), float(p["speedup"]) / threads, rel_tol=1e-5), p
    assert float(got[("dynamic", "allpairs")]["paper_speedup"]) == 11.15
    for s in SCHEMES:
        assert math.isnan(float(got[(s, "linkcell")]["paper_speedup"]))
        assert math.isnan(float(got[(s, "linkcell")]["paper_efficiency"]))

    # unpinned, the binding is recorded all the same: each thread may run on every usable CPU
    usable = _cpus(sorted(os.sched_getaffinity(0)))
    for r in rows:
        assert (r["pinned"], r["binding_held"]) == ("0", "1")
        assert r["thread_cpus"] == " ".join([usable] * T)
    assert f"threads unpinned, on CPUs {' '.join([usable] * T)}" in res.stdout

    png = out / "schemes.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _cpus(cpus):
    """bench.run.binding.format_cpus of a sorted CPU list, written out: '{0-1}', '{3}'."""
    return "{" + (f"{cpus[0]}-{cpus[-1]}" if len(cpus) > 1 and cpus[-1] - cpus[0] == len(cpus) - 1
                  else ",".join(map(str, cpus))) + "}"


def test_efficiency_intervals_are_paired_over_rounds():
    """efficiency_own's interval from the rounds' times: serial detections 2.0, 2.2, 1.8 ms against
    2 threads' 1.25, 1.3, 1.2 ms give [0.68666, 0.92681] (worked by hand in
    tests/bench/test_intervals.py, test_ratio_interval_is_paired_over_rounds); with the neighbour
    estimate 1.0, 1.1, 0.9 against 0.8 in every round, that phase's ratios 1.25, 1.375, 1.125 halve to
    the interval of their log mean (0.2198, s 0.1004: [0.4854, 0.7993]). Against 0.92 the detection's
    interval straddles the target (unresolved); against 0.95 (all-pairs dynamic) it lies below it
    (not met)."""
    import numpy as np
    from bench.studies.schemes import efficiency_intervals
    from bench.sweep.intervals import verdict
    own = {"detect": np.array([2.0, 2.2, 1.8]) * 1e-3, "neighbor": np.array([1.0, 1.1, 0.9]) * 1e-3,
           "resolve": np.array([1.0, 1.1, 0.9]) * 1e-3}
    mine = {"detect": np.array([1.25, 1.3, 1.2]) * 1e-3, "neighbor": np.array([0.8, 0.8, 0.8]) * 1e-3,
            "resolve": np.array([0.45, 0.5, 0.4]) * 1e-3}
    out = efficiency_intervals(own, mine, 2)
    assert out["efficiency_own_lo"] == pytest.approx(0.68666, abs=1e-5)
    assert out["efficiency_own_hi"] == pytest.approx(0.92681, abs=1e-5)
    assert out["neighbor_eff_own_lo"] == pytest.approx(0.4854, abs=1e-3)
    assert out["neighbor_eff_own_hi"] == pytest.approx(0.7993, abs=1e-3)
    assert verdict(out["efficiency_own_lo"], out["efficiency_own_hi"], 0.92) == "unresolved"
    assert verdict(out["efficiency_own_lo"], out["efficiency_own_hi"], 0.95) == "not met"


def test_ceiling_columns_by_hand():
    """--ceiling's columns from three rounds worked by hand: the copies' neighbour estimates take
    1.0, 1.1, 0.9 ms alone and 1.25, 1.375, 1.125 together (0.8 of their solo speed kept), their
    detections 3.0, 3.3, 2.7 ms alone and 3.0 / 0.9 ... together (0.9 kept), so that the
    resolutions take 2.0, 2.2, 1.8 alone and 2.0833, 2.2917, 1.875 together (0.96). Every round
    has the same ratio, so each interval is the point itself. A 2-thread row whose own serial
    detects in 2.0, 2.2, 1.8 ms and which takes 1.25, 1.375, 1.125 has efficiency_own 1.6 / 2 =
    0.8, and 0.8 / 0.9 = 0.888889 of the ceiling; a target of 0.92 lies above the ceiling's
    interval [0.9, 0.9] (not reachable: "no"), one of 0.85 below it ("yes"); a serial row and a
    run without copies have none (NaN)."""
    import numpy as np
    from bench.studies.schemes import ceiling_columns
    alone_nb, alone_det = np.array([1.0, 1.1, 0.9]), np.array([3.0, 3.3, 2.7])
    tog_nb, tog_det = alone_nb / 0.8, alone_det / 0.9
    rounds = [{"linkcell": ([a * 1e-3, (d - a) * 1e-3], [b * 1e-3, (e - b) * 1e-3]), "allpairs": ([1, 1], [1, 1])}
              for a, d, b, e in zip(alone_nb, alone_det, tog_nb, tog_det)]
    own = {"detect": np.array([2.0, 2.2, 1.8]) * 1e-3}
    mine = {"detect": np.array([1.25, 1.375, 1.125]) * 1e-3}
    row = {"method": "static", "neighbor": "linkcell", "threads": 2, "efficiency_own": 0.8, "target_eff_own": 0.92}
    out = ceiling_columns(row, own, mine, rounds)
    assert out["ceiling"] == pytest.approx(0.9, abs=1e-12)
    assert (out["ceiling_lo"], out["ceiling_hi"]) == pytest.approx((0.9, 0.9), abs=1e-12)
    assert out["neighbor_ceiling"] == pytest.approx(0.8, abs=1e-12)
    assert out["resolve_ceiling"] == pytest.approx(0.96, abs=1e-12)
    assert out["of_ceiling"] == pytest.approx(0.888889, abs=1e-6)
    assert (out["of_ceiling_lo"], out["of_ceiling_hi"]) == pytest.approx((0.888889, 0.888889), abs=1e-6)
    assert out["target_reachable"] == "no"
    assert ceiling_columns(dict(row, target_eff_own=0.85), own, mine, rounds)["target_reachable"] == "yes"
    assert ceiling_columns(dict(row, target_eff_own=math.nan), own, mine, rounds)["target_reachable"] == ""
    for args in ((dict(row, method="serial", threads=1), own, own, rounds), (row, own, mine, [])):
        empty = ceiling_columns(*args)
        assert empty.pop("target_reachable") == "" and all(math.isnan(v) for v in empty.values())


def test_schemes_ceiling_runs_copies_beside_the_schemes(tmp_path):
    """`bench schemes --ceiling` end to end at 2 threads on 300 packed ellipsoids: 2 serial copies
    of 150 detect alone and together in each of 2 rounds; every threaded row has the ceiling of its
    neighbour method (the same for every scheme), positive with an interval, and its share of it
    is efficiency_own / ceiling; issue 32's targeted rows say whether the target is within the
    ceiling; the serial rows have none; the table follows Table 1 on stdout."""
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=ROOT, DEM_BENCH_CACHE=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "-m", "bench", "schemes", "--particles", str(N), "--threads", str(T),
                          "--repeats", "2", "--ceiling", "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
                         timeout=600, env=env)
    assert res.returncode == 0, res.stderr
    with open(out / "schemes.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    by_nb = {}
    for r in rows:
        if r["method"] == "serial":
            assert math.isnan(float(r["ceiling"])) and math.isnan(float(r["of_ceiling"]))
            assert r["target_reachable"] == ""
            continue
        assert int(r["ceiling_particles"]) == N // T
        c, lo, hi = float(r["ceiling"]), float(r["ceiling_lo"]), float(r["ceiling_hi"])
        assert c > 0 and 0 < lo <= hi
        assert float(r["neighbor_ceiling"]) > 0 and float(r["resolve_ceiling"]) > 0
        assert by_nb.setdefault(r["neighbor"], (c, lo, hi)) == (c, lo, hi)
        assert math.isclose(float(r["of_ceiling"]), float(r["efficiency_own"]) / c, rel_tol=1e-4)
        assert 0 < float(r["of_ceiling_lo"]) <= float(r["of_ceiling_hi"])
        targeted = not math.isnan(float(r["target_eff_own"]))
        assert r["target_reachable"] in (("yes", "no", "unresolved") if targeted else ("",))
    assert sorted(by_nb) == ["allpairs", "linkcell"]
    assert f"{T} serial copies of {N // T} particles" in res.stdout
    table = res.stdout.split("--- against the machine's ceiling")[1].splitlines()
    assert table[1].split()[:4] == ["method", "neighbor", "eff_own", "ceiling"] and len(table) >= 12


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < T, reason="--pin needs a CPU for each of the 2 threads")
def test_schemes_pin_binds_each_thread_and_its_ceiling_copy_to_a_cpu(tmp_path):
    """`bench schemes --pin --ceiling` at 2 threads (issue 32: pinning that holds, and proves it):
    numba's 2 threads are bound to one CPU each, distinct (on 2 CPUs {0} and {1}, as bench.run.binding
    plans `1-1-1-1-2 --pin`), every row records that set and that it held through the rounds, and the
    ceiling's copy c reports the CPU of thread c as the only one it may run on."""
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=ROOT, DEM_BENCH_CACHE=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "-m", "bench", "schemes", "--particles", str(N), "--threads", str(T),
                          "--repeats", "2", "--pin", "--ceiling", "--out", str(out)], capture_output=True, text=True,
                         cwd=ROOT, timeout=600, env=env)
    assert res.returncode == 0, res.stderr
    with open(out / "schemes.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    sets = rows[0]["thread_cpus"].split()
    assert len(sets) == T and len(set(sets)) == T and all("-" not in c and "," not in c for c in sets)
    assert {int(c.strip("{}")) for c in sets} <= os.sched_getaffinity(0)
    if os.sched_getaffinity(0) == {0, 1}:
        assert sets == ["{0}", "{1}"]
    for r in rows:
        assert (r["pinned"], r["binding_held"], r["thread_cpus"]) == ("1", "1", rows[0]["thread_cpus"])
        assert r["ceiling_cpus"] == rows[0]["thread_cpus"]
    assert f"threads pinned to CPUs {rows[0]['thread_cpus']}" in res.stdout


def test_schemes_pin_with_more_threads_than_cpus_is_one_line(tmp_path):
    """--pin of more threads than usable CPUs: one line naming the problem, exit 2, nothing measured."""
    too_many = len(os.sched_getaffinity(0)) + 1
    env = dict(os.environ, PYTHONPATH=ROOT, DEM_BENCH_CACHE=str(tmp_path / "cache"), OMP_WAIT_POLICY="PASSIVE")
    res = subprocess.run([sys.executable, "-m", "bench", "schemes", "--particles", "60", "--threads", str(too_many),
                          "--repeats", "1", "--pin", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                         cwd=ROOT, timeout=600, env=env)
    assert res.returncode == 2, res.stderr
    errors = [line for line in res.stderr.splitlines() if line.startswith("bench: error:")]
    assert len(errors) == 1 and f"--pin: 1 rank x {too_many} threads need {too_many} CPUs" in errors[0], res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out" / "schemes.csv").exists()
