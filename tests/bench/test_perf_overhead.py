"""`bench perf --what overhead`: the figures of the parallel machinery come from real `bench run`
records (steps.csv, run.json), so they follow their definitions exactly."""

import math

import pytest

from tests.helpers import bench


def test_overhead_report_from_real_runs(tmp_path):
    """One repeat on small scenes: the 48-particle step time is the mean of steps.csv's totalT; for
    2 ranks the exchanges are commuT - syncT + migraT (syncT is part of commuT, so 0 <= syncT <=
    commuT), the bound is 3 wireT + 20 us, and the speedup is T(serial) / T(2 ranks)."""
    from bench.studies.perf_overhead import measure
    lines = []
    rep = measure(1, lines.append, small_steps=50, scenes=(("gas", 300, 40),))
    assert 0 < rep["small"]["us_per_step"] < rep["small"]["wall_us_per_step"]
    (row,) = rep["mpi"]
    assert row["speedup"] == pytest.approx(row["serial_ms"] / row["two_ranks_ms"])
    assert 0 <= row["sync_us"] <= row["commu_migra_us"]
    assert row["exchange_us"] == pytest.approx(row["commu_migra_us"] - row["sync_us"])
    assert row["wire_us"] > 0 and row["overhead_bound_us"] == pytest.approx(3 * row["wire_us"] + 20)
    assert len(lines) == 4 and "target" in lines[1] and "rank skew" in lines[2]
    # one round gives no interval (a Student interval needs two), so no verdict either way
    assert math.isnan(row["speedup_lo"]) and math.isnan(row["speedup_hi"]) and row["verdict"] == "unresolved"


def test_overhead_against_the_in_step_ceiling():
    """--ceiling: each of the 2 rounds also steps two copies at half the particles, alone and in
    step; ceiling_step is the median of the rounds' alone / in step, of_ceiling the median of the
    rounds' 2-rank efficiency T1 / (2 T2) over their ceiling, its interval over the rounds' log ratios
    holds their geometric mean, and the speedup's interval (2 rounds) is finite."""
    from bench.studies.perf_overhead import measure
    lines = []
    rep = measure(2, lines.append, small_steps=50, scenes=(("gas", 300, 40),), ceiling=True)
    (row,) = rep["mpi"]
    one, two = row["samples"]["serial"], row["samples"]["two_ranks"]
    ceil = [c["alone"] / c["in_step"] for c in row["ceiling_samples"]]
    ratio = [a["totalT"] / (2 * b["totalT"]) / c for a, b, c in zip(one, two, ceil)]
    assert len(ceil) == 2 and row["ceiling_step"] == pytest.approx(sum(ceil) / 2)
    assert row["of_ceiling"] == pytest.approx(sum(ratio) / 2)
    geo = math.sqrt(ratio[0] * ratio[1])
    assert row["of_ceiling_lo"] <= geo <= row["of_ceiling_hi"]
    assert math.isfinite(row["speedup_lo"]) and row["speedup_lo"] <= row["speedup_hi"]
    assert any("ceiling of 2 workers" in line for line in lines)
    assert len(row["rank_skew"]) == 2 and min(row["rank_skew"]) >= 1.0


def test_clean_rounds_keep_those_where_both_ranks_ran_alike():
    """The second reading keeps the rounds whose 2-rank run had a rank skew (largest over smallest
    median compuT of the ranks) at most CLEAN_SKEW = 1.10: of skews 1.02, 1.50, 1.05 the first and
    third, with serial 0.30 and 0.29 ms against 2 ranks 0.19 and 0.20 ms: speedup = median 0.295 /
    median 0.195 = 1.513, its paired interval from those two rounds' log ratios (0.4568, 0.3716:
    mean 0.4142, s 0.0602, t(0.975, 1) = 12.706: exp(0.4142 +- 0.5413) = [0.881, 2.600]),
    unresolved against 1.5. One round kept gives no interval."""
    from bench.studies.perf_overhead import _clean_rounds
    one = [{"totalT": 0.30e-3}, {"totalT": 0.25e-3}, {"totalT": 0.29e-3}]
    two = [{"totalT": 0.19e-3, "rank_skew": 1.02}, {"totalT": 0.30e-3, "rank_skew": 1.50},
           {"totalT": 0.20e-3, "rank_skew": 1.05}]
    c = _clean_rounds(one, two, 1.5)
    assert c["rank_skew"] == [1.02, 1.50, 1.05] and c["clean_rounds"] == 2
    assert c["clean_speedup"] == pytest.approx(0.295 / 0.195)
    assert c["clean_speedup_lo"] == pytest.approx(0.881, abs=2e-3)
    assert c["clean_speedup_hi"] == pytest.approx(2.600, abs=2e-3)
    assert c["clean_verdict"] == "unresolved"
    c = _clean_rounds(one[:2], two[:2], 1.5)
    assert c["clean_rounds"] == 1 and math.isnan(c["clean_speedup_lo"]) and c["clean_verdict"] == "unresolved"


def test_speedup_verdict_reads_the_whole_interval():
    """A target is met only where the whole 95 % interval lies at or above it, missed only where it
    lies below; an interval straddling it (or none) leaves the verdict open. Rounds of serial 0.75,
    0.74, 0.76 ms against 2 ranks 0.50, 0.49, 0.51 ms: log ratios 0.4055, 0.4122, 0.3989 (mean
    0.4055, s 0.00667, t(0.975, 2) = 4.303): the interval exp(0.4055 +- 0.0166) = [1.475, 1.525] straddles
    1.5."""
    from bench.studies.perf_overhead import speedup_verdict
    from bench.sweep.intervals import speedup_interval
    assert speedup_verdict(1.52, 1.60, 1.5) == "met"
    assert speedup_verdict(1.40, 1.49, 1.5) == "not met"
    assert speedup_verdict(1.45, 1.55, 1.5) == "unresolved"
    assert speedup_verdict(math.nan, math.nan, 1.5) == "unresolved"
    # the default skin's target is strict (speedup > 1): an interval starting at 1 does not meet it
    assert speedup_verdict(1.0, 1.2, 1.0) == "met" and speedup_verdict(1.0, 1.2, 1.0, strict=True) == "unresolved"
    assert speedup_verdict(0.8, 1.0, 1.0, strict=True) == "not met"
    nan = math.nan
    lo, hi = speedup_interval(0.75, nan, nan, 0.50, nan, nan, [0.75, 0.74, 0.76], [0.50, 0.49, 0.51])
    assert lo == pytest.approx(1.4755, abs=1e-3) and hi == pytest.approx(1.5252, abs=1e-3)
    assert speedup_verdict(lo, hi, 1.5) == "unresolved" and speedup_verdict(lo, hi, 1.45) == "met"


def test_overhead_command_bad_repeats(tmp_path):
    res = bench("perf", "--what", "overhead", "--repeats", "0")
    assert res.returncode == 2 and "Traceback" not in res.stderr


def test_ceiling_is_refused_outside_overhead():
    """--ceiling reads 2 ranks against 2 workers: with any other --what it is one line naming both,
    exit 2, no traceback."""
    res = bench("perf", "--what", "pairs", "--ceiling")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "--ceiling" in res.stderr and "pairs" in res.stderr


def test_in_job_row_from_its_cycles():
    """--in-job: a cycle's serial time is the mean of its two CPUs' serial blocks (0.30 and 0.34,
    0.32 and 0.30, 0.31 and 0.33 ms: 0.32, 0.31, 0.32), against the 2 ranks' 0.20, 0.21, 0.20 ms
    the cycles' log ratios 0.4700, 0.3895, 0.4700: the speedup their geometric mean exp(0.4432) =
    1.5576 with its interval (s 0.0465, t(0.975, 2) = 4.303: [1.388, 1.748]), unresolved against
    1.5; serial_ms and two_ranks_ms the cycles' medians; the CPUs' skew the median of 1.133, 1.067, 1.065; the
    exchanges commuT - syncT + migraT from the means over the cycles (45 - 25 + 0 = 20 us) against
    3 wireT + 50 us = 59 us."""
    from bench.studies.perf_overhead import REBUILD_TARGETS, TARGETS, in_job_row
    doc = {"scene": "pluviation", "particles": 1521, "cycles": 3, "block_steps": 10, "steps": 40, "identical": True,
           "affinity": None, "forward_transport": "messages",
           "serial_cpu0_s": [0.30e-3, 0.32e-3, 0.31e-3], "serial_cpu1_s": [0.34e-3, 0.30e-3, 0.33e-3],
           "two_ranks_s": [0.20e-3, 0.21e-3, 0.20e-3],
           "two_ranks_parts_s": {"commuT": [40e-6, 50e-6, 45e-6], "syncT": [20e-6, 30e-6, 25e-6], "migraT": [0.0] * 3,
                                 "wire_s": [3e-6] * 3}}
    row = in_job_row(doc, dict(TARGETS, **REBUILD_TARGETS), strict=False)
    assert row["serial_ms"] == pytest.approx(0.32) and row["two_ranks_ms"] == pytest.approx(0.20)
    assert row["speedup"] == pytest.approx(1.5576, abs=1e-4)
    assert row["speedup_lo"] == pytest.approx(1.3877, abs=1e-3) and row["speedup_hi"] == pytest.approx(1.7483, abs=1e-3)
    assert row["verdict"] == "unresolved"
    assert row["cpu_skew"] == pytest.approx(0.32 / 0.30)
    assert row["exchange_us"] == pytest.approx(20.0) and row["overhead_bound_us"] == pytest.approx(59.0)
    assert "of_ceiling" not in row   # run without --ceiling


def test_in_job_ceiling_from_its_cycles():
    """--in-job with --ceiling: a cycle's in-step ceiling is the mean of the half copies alone on
    each CPU over the halves in step ((0.17 + 0.19) / 2 / 0.20 = 0.90, (0.18 + 0.18) / 2 / 0.20 =
    0.90, (0.17 + 0.17) / 2 / 0.19 = 0.8947: median 0.90); the 2 ranks' efficiency serial / (2 x 2
    ranks) over it, 0.32 / 0.40 / 0.90 = 0.8889, 0.31 / 0.42 / 0.90 = 0.8201, 0.32 / 0.40 / 0.8947 =
    0.8941: geometric mean 0.8670, interval [0.7690, 0.9775] (Student, 2 degrees of freedom)."""
    from bench.studies.perf_overhead import REBUILD_TARGETS, TARGETS, in_job_row
    doc = {"scene": "pluviation", "particles": 1521, "cycles": 3, "block_steps": 10, "steps": 40, "identical": True,
           "affinity": None, "forward_transport": "messages",
           "serial_cpu0_s": [0.30e-3, 0.32e-3, 0.31e-3], "serial_cpu1_s": [0.34e-3, 0.30e-3, 0.33e-3],
           "two_ranks_s": [0.20e-3, 0.21e-3, 0.20e-3],
           "two_ranks_parts_s": {"commuT": [40e-6] * 3, "syncT": [20e-6] * 3, "migraT": [0.0] * 3,
                                 "wire_s": [3e-6] * 3},
           "ceiling_particles": 760, "alone_cpu0_s": [0.17e-3, 0.18e-3, 0.17e-3],
           "alone_cpu1_s": [0.19e-3, 0.18e-3, 0.17e-3], "in_step_s": [0.20e-3, 0.20e-3, 0.19e-3]}
    row = in_job_row(doc, dict(TARGETS, **REBUILD_TARGETS), strict=False)
    assert row["ceiling_particles"] == 760 and row["ceiling_step"] == pytest.approx(0.90)
    assert row["of_ceiling"] == pytest.approx(0.8670, abs=1e-4)
    assert row["of_ceiling_lo"] == pytest.approx(0.7690, abs=1e-4)
    assert row["of_ceiling_hi"] == pytest.approx(0.9775, abs=1e-4)


def test_in_job_jobs_interval_over_the_jobs():
    """--in-job with --repeats 3: the jobs' speedups 1.30, 1.50, 1.45 (each with a narrow interval
    of its own cycles) give the geometric mean exp(mean(log)) = 1.4141 with the Student interval of
    their logs (t(0.975, 2) = 4.303): [1.1743, 1.7027], unresolved against 1.5, where every job's own
    interval alone would have said "not met" or "met"; of_ceiling 0.76, 0.80, 0.78 the same way:
    0.7798 [0.7317, 0.8311]; the step times the jobs' medians; one job is its own row."""
    from bench.studies.perf_overhead import REBUILD_TARGETS, TARGETS, in_job_jobs

    def job(s, share, two_ms):
        return {"scene": "pluviation", "particles": 1521, "method": "in_job", "cycles": 100, "block_steps": 10,
                "steps": 1010, "identical": True, "serial_ms": 0.29, "two_ranks_ms": two_ms, "speedup": s,
                "speedup_lo": s - 0.02, "speedup_hi": s + 0.02, "verdict": "met" if s > 1.52 else "not met",
                "cpu_skew": 1.05, "sync_us": 20.0, "exchange_us": 15.0, "wire_us": 4.0, "overhead_bound_us": 62.0,
                "exchange_over_bound": 15.0 / 62.0, "ceiling_step": 0.9, "of_ceiling": share,
                "forward_transport": "messages"}

    targets = dict(TARGETS, **REBUILD_TARGETS)
    rows = [job(1.30, 0.76, 0.22), job(1.50, 0.80, 0.19), job(1.45, 0.78, 0.20)]
    row = in_job_jobs(rows, targets, strict=False)
    assert row["jobs"] == 3 and row["jobs_rows"] == rows and row["identical"]
    assert row["speedup"] == pytest.approx(1.41406, abs=1e-4)
    assert row["speedup_lo"] == pytest.approx(1.17434, abs=1e-4)
    assert row["speedup_hi"] == pytest.approx(1.70272, abs=1e-4)
    assert row["verdict"] == "unresolved"
    assert row["two_ranks_ms"] == pytest.approx(0.20) and row["serial_ms"] == pytest.approx(0.29)
    assert row["of_ceiling"] == pytest.approx(0.77983, abs=1e-4)
    assert row["of_ceiling_lo"] == pytest.approx(0.73169, abs=1e-4)
    assert row["of_ceiling_hi"] == pytest.approx(0.83113, abs=1e-4)
    assert in_job_jobs(rows[:1], targets, strict=False) == dict(rows[0], jobs=1)


def test_in_job_comparison_runs_one_mpi_job():
    """--in-job 2 --ceiling on the 300-particle gas at --skin 0: one MPI job of 2 pinned ranks, 3
    cycles (the first untimed) of 50-step blocks; each timed cycle gives a 2-rank block, one serial
    block on each CPU and the ceiling's three blocks of a 150-particle copy; the 2 ranks and both
    serial copies end bit-identical (the job compares their snapshots with np.array_equal), and
    the speedup is the geometric mean of the cycles' serial / 2-rank ratios, inside its
    interval."""
    from bench.studies.perf_overhead import measure
    lines = []
    rep = measure(1, lines.append, small_steps=50, scenes=(("gas", 300, 40),), skin=0, in_job=2, ceiling=True)
    (row,) = rep["mpi"]
    assert row["identical"] and row["cycles"] == 2 and row["steps"] == 150 and row["particles"] == 300
    assert row["jobs"] == 1   # one repeat: one job, its cycles' interval
    s = row["samples"]
    assert len(s["two_ranks"]) == len(s["serial_cpu0"]) == len(s["serial_cpu1"]) == 2
    serial = [0.5 * (a + b) for a, b in zip(s["serial_cpu0"], s["serial_cpu1"])]
    ratios = [a / b for a, b in zip(serial, s["two_ranks"])]
    assert row["speedup"] == pytest.approx(math.sqrt(ratios[0] * ratios[1]))
    assert row["speedup_lo"] <= row["speedup"] <= row["speedup_hi"]
    assert [len(r["cpus"]) for r in row["affinity"]["ranks"]] == [1, 1]   # pinned, one CPU each
    c = row["ceiling_samples"]
    assert row["ceiling_particles"] == 150 and len(c["alone_cpu0"]) == len(c["in_step"]) == 2
    assert row["of_ceiling_lo"] <= row["of_ceiling"] <= row["of_ceiling_hi"]
    assert len(lines) == 4 and "in one MPI job" in lines[1] and "identical" in lines[1]
    assert "ceiling of 2 workers" in lines[2]


def test_in_job_two_ranks_through_the_shared_window():
    """--in-job --forward shared: the 2 ranks' ghosts travel through the node's shared-memory window
    (run.json's forward_transport, here the job's), and the 2 ranks still end bit-identical to both
    serial copies (the transport never changes results: DESIGN.md, Determinism)."""
    from bench.studies.perf_overhead import measure
    lines = []
    rep = measure(1, lines.append, small_steps=50, scenes=(("gas", 300, 40),), skin=0, in_job=1, forward="shared")
    (row,) = rep["mpi"]
    assert rep["forward"] == "shared" and row["forward_transport"] == "shared" and row["identical"]
    assert "through the shared window" in lines[1]


def test_forward_is_for_the_in_job_comparison():
    """--forward picks the in-job 2 ranks' transport; elsewhere it is one line naming the option."""
    res = bench("perf", "--what", "overhead", "--forward", "shared")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "--forward is for --what overhead --in-job" in res.stderr


def test_in_job_is_refused_elsewhere():
    """--in-job is a way of --what overhead's and forward's comparisons: with another --what it is
    one line naming the option, exit 2, no traceback."""
    res = bench("perf", "--what", "pairs", "--in-job")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "--in-job" in res.stderr
