"""The sweep's ranking in words (bench/sweep/ranking.py) on synthetic step times whose truth is
known (no timing here): a point 5 % slower than another is told apart, two equal points are called
tied at the interval's 95 %, and loaded or failed points are left out with their reason."""
import numpy as np

from bench.sweep.intervals import format_reps, step_time_interval
from bench.sweep.ranking import rank, ranking_lines
from tests.bench.synthetic_steps import ar1

SEEDS = 1000


def row(mapping, series, cores=2, flag="", status="done"):
    """A runs.csv row of a point from its repeats' step times, as bench.sweep.records writes it."""
    means = [float(np.mean(x)) for x in series]
    lo, hi = step_time_interval(series)
    return {"mapping": mapping, "scheme": "", "cores": cores, "status": status, "flag": flag,
            "totalT": float(np.median(means)), "totalT_lo": lo, "totalT_hi": hi, "totalT_reps": format_reps(means)}


def two_points(rng, slower, rounds=5, steps=200):
    """A and B over `rounds` interleaved rounds of `steps` steps (10 % step noise, lag-1 correlation
    0.3), each round's machine state slowing both by a shared 5 %, each run by its own 1 %; B's
    true mean is (1 + slower) times A's."""
    shared = 1 + rng.normal(0, 0.05, rounds)
    a = [ar1(rng, steps, 1e-3 * f * (1 + rng.normal(0, 0.01)), 1e-4, 0.3) for f in shared]
    b = [ar1(rng, steps, 1e-3 * (1 + slower) * f * (1 + rng.normal(0, 0.01)), 1e-4, 0.3) for f in shared]
    return [row("2-2-1-1-1", a), row("1-1-1-1-2", b)]


def test_five_percent_apart_are_told_apart():
    """B 5 % slower than A, 5 rounds of 200 steps: A is named fastest and B slower (not tied) in at
    least 95 % of seeds."""
    right = 0
    for seed in range(SEEDS):
        e = rank(two_points(np.random.default_rng(seed), 0.05))[0]
        right += e["fastest"] == "2-2-1-1-1" and [s["point"] for s in e["slower"]] == ["1-1-1-1-2"]
    assert right / SEEDS >= 0.95


def test_equal_points_tie():
    """A and B equal, 5 rounds: tied in 93-97 % of seeds (the paired 95 % interval holds the true
    ratio 1 in 95 % of seeds; 1000 seeds, Monte-Carlo error 0.7 %)."""
    ties = sum(len(rank(two_points(np.random.default_rng(seed), 0.0))[0]["ties"]) == 1 for seed in range(SEEDS))
    assert 0.93 <= ties / SEEDS <= 0.97


def test_loaded_and_failed_points_are_left_out_and_named():
    """A loaded point (flag load) and a failed one do not rank, whatever their times, and the line
    names them with the reason; each core count has its own line."""
    rng = np.random.default_rng(1)
    rows = two_points(rng, 0.05) + [
        dict(row("2-1-2-1-1", [np.full(10, 1e-4)] * 5), flag="load,spread"),
        dict(row("2-2-1-1-1x", [np.full(10, 1e-4)] * 5), status="failed"),
        row("1-1-1-1-1", [np.full(10, 2e-3)] * 5, cores=1)]
    r = rank(rows)
    assert [e["cores"] for e in r] == [1, 2]
    assert r[1]["fastest"] == "2-2-1-1-1"
    assert {x["point"]: x["reason"] for x in r[1]["excluded"]} == {
        "2-1-2-1-1": "measured beside foreign load", "2-2-1-1-1x": "not done (failed)"}
    lines = ranking_lines(r)
    assert lines[0] == "1 core: 1-1-1-1-1 fastest"
    assert lines[1].startswith("2 cores: 2-2-1-1-1 fastest; 1-1-1-1-2 is slower (+")
    assert "2-1-2-1-1 left out: measured beside foreign load" in lines[1]
