"""The 95 % intervals of runs.csv (bench/sweep/intervals.py) on synthetic step times whose true mean
is known (no timing here): each interval must cover the truth in 93-97 % of seeds, the band issue
36 sets (at 1000 seeds the Monte-Carlo error of a 95 % coverage is 0.7 %)."""
import math

import numpy as np
import pytest

from bench.sweep.intervals import (batch_means, format_reps, mean_interval, parse_reps, speedup_interval,
                                   step_time_interval)
from tests.bench.synthetic_steps import ar1

SEEDS = 1000


def coverage(draw, truth):
    hits = 0
    for seed in range(SEEDS):
        lo, hi = draw(np.random.default_rng(seed))
        hits += lo <= truth <= hi
    return hits / SEEDS


def test_repeats_interval_covers_the_mean_with_run_to_run_offsets():
    """3 repeats of 100 correlated steps (10 % noise, lag-1 correlation 0.5), each run offset from
    the true 1.0 ms by its own 5 % (placement, clock): the Student interval over the repeat means
    covers 1.0 ms in 93-97 % of seeds (exact for normal repeat means: Law §9.5.3)."""
    def draw(rng):
        return step_time_interval([ar1(rng, 100, 1e-3 * (1 + rng.normal(0, 0.05)), 1e-4, 0.5) for _ in range(3)])
    assert 0.93 <= coverage(draw, 1e-3) <= 0.97


def test_one_repeat_interval_from_batches_of_correlated_steps():
    """One run of 400 steps (10 % noise, lag-1 correlation 0.3): 10 batch means of 40 steps are
    nearly independent, and their Student interval covers the true mean in 93-97 % of seeds; the
    naive interval over the steps themselves (as if independent) covers it less often."""
    def draw(rng):
        return step_time_interval([ar1(rng, 400, 1e-3, 1e-4, 0.3)])

    def naive(rng):
        return mean_interval(ar1(rng, 400, 1e-3, 1e-4, 0.3))
    assert 0.93 <= coverage(draw, 1e-3) <= 0.97
    assert coverage(naive, 1e-3) < 0.90


def test_paired_speedup_interval_covers_the_true_ratio():
    """A point twice as fast as its reference, 3 interleaved rounds, each round's machine state
    slowing both by a shared factor (10 %) and each run by its own 2 %: the interval paired over
    the rounds covers the true speedup 2 in 93-97 % of seeds, and is narrower than the unpaired
    one (which carries the shared factor twice)."""
    widths = []

    def draw(rng):
        shared = 1 + rng.normal(0, 0.10, 3)
        t1 = [ar1(rng, 100, 1e-3 * f * (1 + rng.normal(0, 0.02)), 1e-4, 0.3) for f in shared]
        t = [ar1(rng, 100, 0.5e-3 * f * (1 + rng.normal(0, 0.02)), 0.5e-4, 0.3) for f in shared]
        r1, r = [x.mean() for x in t1], [x.mean() for x in t]
        (a, b), (c, d) = step_time_interval(t1), step_time_interval(t)
        paired = speedup_interval(np.median(r1), a, b, np.median(r), c, d, r1, r)
        unpaired = speedup_interval(np.median(r1), a, b, np.median(r), c, d)
        widths.append((paired[1] - paired[0], unpaired[1] - unpaired[0]))
        return paired
    assert 0.93 <= coverage(draw, 2.0) <= 0.97
    w = np.array([x for x in widths if np.all(np.isfinite(x))])
    assert np.median(w[:, 0]) < np.median(w[:, 1])


def test_batches_reps_and_missing_intervals():
    """Batch means of 23 steps in 10 batches of 2 leave the first 3 out; fewer than 4 steps give
    none (no interval); a repeat list survives runs.csv's text; a speedup without both intervals
    has none."""
    x = np.arange(23.0)
    assert np.array_equal(batch_means(x), x[3:].reshape(10, 2).mean(axis=1))
    assert len(batch_means(x[:3])) == 0 and all(math.isnan(v) for v in step_time_interval([x[:3]]))
    assert parse_reps(format_reps([1e-3, 2.5e-3])) == [1e-3, 2.5e-3] and parse_reps("") == []
    assert all(math.isnan(v) for v in speedup_interval(1.0, math.nan, 1.1, 0.5, 0.4, 0.6))


@pytest.mark.parametrize("r", [2, 3])
def test_repeats_interval_is_student(r):
    """The interval of R repeat means is mean +- t(0.975, R - 1) s / sqrt(R) (t = 12.7062 at R = 2,
    4.30265 at R = 3: Abramowitz & Stegun, Table 26.10)."""
    m = np.array([1.0, 1.2, 0.9][:r])
    t = {2: 12.7062, 3: 4.30265}[r]
    half = t * m.std(ddof=1) / math.sqrt(r)
    lo, hi = step_time_interval([np.full(5, v) for v in m])
    assert lo == pytest.approx(m.mean() - half, abs=1e-5) and hi == pytest.approx(m.mean() + half, abs=1e-5)


def test_ratio_interval_is_paired_over_rounds():
    """A 2-thread efficiency against its own serial from three rounds (serial 2.0, 2.2, 1.8 ms;
    2 threads 1.25, 1.3, 1.2 ms): log ratios 0.470004, 0.526093, 0.405465 (mean 0.467187, s 0.060363,
    t(0.975, 2) = 4.302653, half-width 0.149951); efficiency = ratio / 2 in
    [exp(0.317236), exp(0.617138)] / 2 = [0.68666, 0.92681], worked by hand. One round gives none."""
    from bench.sweep.intervals import ratio_interval
    lo, hi = ratio_interval([2.0e-3, 2.2e-3, 1.8e-3], [1.25e-3, 1.3e-3, 1.2e-3], 0.5)
    assert lo == pytest.approx(0.68666, abs=1e-5) and hi == pytest.approx(0.92681, abs=1e-5)
    assert all(math.isnan(v) for v in ratio_interval([2.0e-3], [1.0e-3]))
    assert all(math.isnan(v) for v in ratio_interval([2.0e-3, 0.0], [1.0e-3, 1.0e-3]))


def test_verdict_lower_is_better():
    """A serial fraction's target (at most 0.02) is met only where the whole interval is at or
    below it, missed only where the whole interval is above it."""
    from bench.sweep.intervals import verdict
    assert verdict(0.005, 0.019, 0.02, higher_is_better=False) == "met"
    assert verdict(0.021, 0.05, 0.02, higher_is_better=False) == "not met"
    assert verdict(0.019, 0.021, 0.02, higher_is_better=False) == "unresolved"
    assert verdict(math.nan, math.nan, 0.02, higher_is_better=False) == "unresolved"
    assert verdict(0.93, 0.95, 0.92) == "met" and verdict(0.80, 0.91, 0.92) == "not met"
