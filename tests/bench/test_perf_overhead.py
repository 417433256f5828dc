"""`bench perf --what overhead`: the figures of the parallel machinery come from real `bench run`
records (steps.csv, run.json), so they follow their definitions exactly."""

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
    assert len(lines) == 3 and "target" in lines[1]


def test_overhead_command_bad_repeats(tmp_path):
    res = bench("perf", "--what", "overhead", "--repeats", "0")
    assert res.returncode == 2 and "Traceback" not in res.stderr
