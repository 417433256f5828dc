"""A sweep against an earlier one (bench/sweep/compare.py, `bench compare OLD NEW`) on synthetic
runs.csv folders whose truth is known (no timing here): a point 10 % slower is called slower with
an interval that holds 1.10, equal points are called the same, loaded, failed and one-sided points
are named as such, and a folder without a readable runs.csv ends in one line."""
import math
import os

import numpy as np
import pytest

from bench.sweep.compare import comparison_lines, compare_folders, ratio_interval, verdict
from bench.sweep.intervals import format_reps, speedup_interval, step_time_interval
from bench.sweep.records import RunsFileError, write_runs
from tests.bench.synthetic_steps import ar1
from tests.helpers import bench, one_line_error

SEEDS = 1000
KEYS = {"1-1-1-1-1": "1-1-1-1-1-78225fa4", "2-2-1-1-1": "2-2-1-1-1-dc8ad06b",
        "1-1-1-1-2": "1-1-1-1-2-dynamic-0108c85f"}


def row(mapping, series, scheme="", flag="", status="done"):
    """A runs.csv row of a point from its repeats' step times [R][n], as bench.sweep.records.summarise
    writes it: totalT the median of the repeats' means, its Student interval, the means."""
    means = [float(np.mean(x)) for x in series]
    lo, hi = step_time_interval(series)
    procs, _, _, _, threads = (int(v) for v in mapping.split("-"))
    return {"point": KEYS[mapping], "mapping": mapping, "scheme": scheme, "procs": procs, "threads": threads,
            "cores": procs * threads, "status": status, "flag": flag, "totalT": float(np.median(means)),
            "totalT_lo": lo, "totalT_hi": hi, "totalT_reps": format_reps(means)}


def sweep_of(rng, mean, repeats=5, steps=100):
    """One sweep's measurement of a point of true mean step time `mean` [s]: `repeats` runs of
    `steps` steps, 1 % step noise with lag-1 correlation 0.3, each run off by its own 0.3 %."""
    return [ar1(rng, steps, mean * (1 + rng.normal(0, 0.003)), 0.01 * mean, 0.3) for _ in range(repeats)]


def folder(path, rows):
    os.makedirs(path, exist_ok=True)
    write_runs(os.path.join(path, "runs.csv"), rows)
    return str(path)


def test_ten_percent_slower_is_slower_and_its_interval_holds_the_truth():
    """The new sweep's point has a true mean step time 1.10 x the old one's (the means given to the
    synthetic series; the ratio of the medians of the repeat means estimates it). Tight intervals (1 %
    step noise, 0.3 % run to run, 5 repeats): called slower in every seed and the 95 % interval of the
    ratio holds 1.10 in at least 95 % of 1000 seeds (at least, not about: the quadrature of two
    Student intervals of 4 degrees of freedom is wider than the Welch interval of their difference)."""
    slower = holds = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        old, new = row("2-2-1-1-1", sweep_of(rng, 1e-3)), row("2-2-1-1-1", sweep_of(rng, 1.1e-3))
        ratio, lo, hi = ratio_interval(old, new)
        slower += verdict(lo, hi) == "slower"
        holds += lo <= 1.10 <= hi
    assert slower == SEEDS
    assert holds / SEEDS >= 0.95


def test_equal_points_are_the_same():
    """The same true mean in both sweeps: the interval holds the true ratio 1, so the verdict is
    `same`, in at least 95 % of 1000 seeds (the interval's level; at least, as above)."""
    same = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        old, new = row("2-2-1-1-1", sweep_of(rng, 1e-3)), row("2-2-1-1-1", sweep_of(rng, 1e-3))
        same += verdict(*ratio_interval(old, new)[1:]) == "same"
    assert same / SEEDS >= 0.95


def test_the_two_sweeps_are_not_paired():
    """Both sweeps have 5 repeat means, which the ranking would pair round by round; two sweeps run
    in different rounds, so the interval is the independent one: speedup_interval of T_new / T_old
    from the two intervals alone (log half-widths in quadrature), not the paired form from
    totalT_reps."""
    rng = np.random.default_rng(7)
    old, new = row("2-2-1-1-1", sweep_of(rng, 1e-3)), row("2-2-1-1-1", sweep_of(rng, 1.1e-3))
    ratio, lo, hi = ratio_interval(old, new)
    assert ratio == new["totalT"] / old["totalT"]
    assert (lo, hi) == speedup_interval(new["totalT"], new["totalT_lo"], new["totalT_hi"],
                                        old["totalT"], old["totalT_lo"], old["totalT_hi"])
    paired = speedup_interval(new["totalT"], new["totalT_lo"], new["totalT_hi"], old["totalT"], old["totalT_lo"],
                              old["totalT_hi"], [float(v) for v in new["totalT_reps"].split(";")],
                              [float(v) for v in old["totalT_reps"].split(";")])
    assert (lo, hi) != paired


def test_folders_loaded_failed_and_one_sided_points(tmp_path):
    """Through runs.csv files (bench.sweep.records.write_runs): 2-2-1-1-1 10 % slower (slower, the
    interval holds 1.10, the line says "10 % slower than in OLD"), 1-1-1-1-1 equal (the same), the
    loaded 1-1-1-1-2 (flag load in the new sweep) not compared with the reason whatever its time, a
    failed point not compared, and points only in one folder listed as such."""
    rng = np.random.default_rng(3)
    old = folder(tmp_path / "old", [row("1-1-1-1-1", sweep_of(rng, 2e-3)), row("2-2-1-1-1", sweep_of(rng, 1e-3)),
                                    row("1-1-1-1-2", sweep_of(rng, 1.2e-3), scheme="dynamic")])
    new = folder(tmp_path / "new", [row("1-1-1-1-1", sweep_of(rng, 2e-3)), row("2-2-1-1-1", sweep_of(rng, 1.1e-3)),
                                    row("1-1-1-1-2", sweep_of(rng, 5e-3), scheme="dynamic", flag="load,spread")])
    got = {e["point"]: e for e in compare_folders(old, new)}
    assert [e["verdict"] for e in got.values()] == ["same", "slower", "not compared"]
    slow = got["2-2-1-1-1"]
    assert slow["lo"] <= 1.10 <= slow["hi"] and slow["ratio"] == pytest.approx(1.10, rel=0.01)
    assert got["1-1-1-1-2 dynamic"]["reason"] == "measured beside foreign load in the new sweep"
    lines = comparison_lines(list(got.values()))
    assert lines[1].startswith(f"2-2-1-1-1: 10 % slower than in {old} (95 % interval +")
    assert lines[0].startswith(f"1-1-1-1-1: the same as in {old} (")
    assert lines[2] == "1-1-1-1-2 dynamic: not compared (measured beside foreign load in the new sweep)"

    failed = dict(row("2-2-1-1-1", sweep_of(rng, 1e-3)), status="failed", totalT=math.nan)
    folder(tmp_path / "new2", [failed, row("1-1-1-1-2", sweep_of(rng, 1e-3), scheme="dynamic")])
    folder(tmp_path / "old2", [row("2-2-1-1-1", sweep_of(rng, 1e-3)), row("1-1-1-1-1", sweep_of(rng, 2e-3))])
    got = compare_folders(str(tmp_path / "old2"), str(tmp_path / "new2"))
    assert [(e["point"], e["verdict"]) for e in got] == [("2-2-1-1-1", "not compared"),
                                                         ("1-1-1-1-2 dynamic", "only in new"),
                                                         ("1-1-1-1-1", "only in old")]
    assert got[0]["reason"] == "not done in the new sweep (failed)"
    assert comparison_lines(got)[1:] == [f"1-1-1-1-2 dynamic: not in {tmp_path / 'old2'} (new point)",
                                         f"1-1-1-1-1: only in {tmp_path / 'old2'} (not measured in the new sweep)"]


def test_no_interval_is_said():
    """A point whose old sweep has no interval (NaN bounds, as an old runs.csv without the
    columns reads) gets the ratio and `no interval`, never a verdict."""
    rng = np.random.default_rng(5)
    old = dict(row("2-2-1-1-1", sweep_of(rng, 1e-3)), totalT_lo=math.nan, totalT_hi=math.nan)
    ratio, lo, hi = ratio_interval(old, row("2-2-1-1-1", sweep_of(rng, 1.1e-3)))
    assert math.isnan(lo) and math.isnan(hi) and verdict(lo, hi) == "no interval"
    line = comparison_lines([{"point": "2-2-1-1-1", "old": "A", "ratio": ratio, "lo": lo, "hi": hi,
                              "verdict": "no interval", "reason": ""}])[0]
    assert line.startswith("2-2-1-1-1: +10 % against A, no interval")


def test_bad_folders_raise_one_line(tmp_path):
    """A missing folder, a folder without runs.csv and a runs.csv that is not a runs table each
    raise RunsFileError (a ValueError) with a one-line message naming the folder or file."""
    good = folder(tmp_path / "good", [row("1-1-1-1-1", [np.full(10, 1e-3)] * 2)])
    (tmp_path / "empty").mkdir()
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "runs.csv").write_text("a,b\n1,2\n")
    for bad, words in ((tmp_path / "nope", "is not a folder"), (tmp_path / "empty", "has no runs.csv"),
                       (tmp_path / "junk", "is not a runs table")):
        with pytest.raises(RunsFileError) as e:
            compare_folders(good, str(bad))
        assert words in str(e.value) and "\n" not in str(e.value)
        with pytest.raises(ValueError):
            compare_folders(str(bad), good)


def test_cli_prints_lines_writes_nothing_and_fails_in_one_line(tmp_path):
    """`python -m bench compare OLD NEW`: the lines on stdout and exit 0 with a point 10 % slower (a
    regression is reported, not a failure), OLD's files untouched (names, sizes, times); a missing
    folder, an empty runs.csv and a runs.csv of binary junk end in one line on stderr, no traceback,
    exit 2."""
    rng = np.random.default_rng(11)
    old = folder(tmp_path / "old", [row("2-2-1-1-1", sweep_of(rng, 1e-3))])
    new = folder(tmp_path / "new", [row("2-2-1-1-1", sweep_of(rng, 1.1e-3))])
    before = {f: os.stat(os.path.join(old, f)) for f in os.listdir(old)}
    res = bench("compare", old, new)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [comparison_lines(compare_folders(old, new))[0]]
    assert res.stdout.startswith(f"2-2-1-1-1: 10 % slower than in {old}")
    after = {f: os.stat(os.path.join(old, f)) for f in os.listdir(old)}
    assert {f: (s.st_size, s.st_mtime_ns) for f, s in after.items()} == \
        {f: (s.st_size, s.st_mtime_ns) for f, s in before.items()}

    one_line_error(bench("compare", str(tmp_path / "missing"), new), "bench compare", "is not a folder")
    (tmp_path / "blank").mkdir()
    (tmp_path / "blank" / "runs.csv").write_text("")
    one_line_error(bench("compare", old, str(tmp_path / "blank")), "runs.csv is empty")
    (tmp_path / "binary").mkdir()
    (tmp_path / "binary" / "runs.csv").write_bytes(bytes(range(256)) * 4)
    one_line_error(bench("compare", str(tmp_path / "binary"), new), "bench compare")
