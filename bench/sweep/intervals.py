"""95 % confidence intervals of a point's step time, speedup and efficiency (issue 36, part 1).

A point's step time is measured by R repeats (interleaved rounds: round r runs repeat r of every
point), each a series of per-step times x_r [n] (steps.csv; the step's time is the slowest rank's).
Steps within a run are correlated (a rebuild, the cache, the machine's clock drift), and runs
differ from each other by more than their steps say (placement, frequency, foreign load), so
neither the steps nor the repeats alone give an honest interval:

- R >= 2: the repeat means m_r (each the mean of its steps: correlated steps only make m_r
  noisier, which its spread over the repeats then shows) are R independent estimates of the
  point's mean step time; the interval is mean(m) +- t(0.975, R - 1) s(m) / sqrt(R), Student's t
  (the batch means of a simulation's output analysis with each run one batch: Law, "Simulation
  Modeling and Analysis", 5th ed., §9.5.3). It is wide with few repeats (t(0.975, 1) = 12.7,
  t(0.975, 2) = 4.30): the honest price of two or three runs; more rounds narrow it as 1/sqrt(R).
- R = 1: the same over B_STEPS batch means of consecutive steps within the run (Law §9.5.3,
  nonoverlapping batch means: batches long against the steps' correlation are nearly
  independent). It covers the step-to-step noise only, not what changes from run to run.

Speedup S = T1 / T and efficiency S / p take the intervals of both times: with per-repeat means of
both (runs.csv `totalT_reps`) and the same R >= 2 (the reference ran in the same rounds), paired
over the rounds, the log ratios d_r = log(T1_r / T_r) with their Student interval (a round's
shared machine state cancels); otherwise the two log-intervals' half-widths added in quadrature
(independent errors, first order in the relative widths). The serial row is its own reference:
its speedup is 1 by definition, with no interval.
"""
import math

import numpy as np

LEVEL = 0.95
# the batches of one repeat's steps (R = 1); fewer when the run has fewer than 2 steps a batch
B_STEPS = 10


def number(v):
    """float(v), NaN for what is not a number (a runs.csv field: text, empty or NaN)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def t_quantile(df, level=LEVEL):
    """The two-sided Student t quantile t((1 + level) / 2, df)."""
    from scipy.stats import t
    return float(t.ppf(0.5 + level / 2.0, df))


def batch_means(x, batches=B_STEPS):
    """Means of `batches` consecutive equal batches of the series x [n] (the first n mod batches
    steps left out); fewer batches when n < 2 batches (at least 2 steps each), [] under 4 steps."""
    x = np.asarray(x, dtype=float)
    b = min(batches, len(x) // 2)
    if b < 2:
        return np.zeros(0)
    size = len(x) // b
    return x[len(x) - b * size:].reshape(b, size).mean(axis=1)


def mean_interval(samples, level=LEVEL):
    """(lo, hi) of the Student interval of the mean of independent samples [k] (NaN for k < 2)."""
    s = np.asarray(samples, dtype=float)
    s = s[np.isfinite(s)]
    if len(s) < 2:
        return math.nan, math.nan
    half = t_quantile(len(s) - 1, level) * float(np.std(s, ddof=1)) / math.sqrt(len(s))
    m = float(np.mean(s))
    return m - half, m + half


def step_time_interval(series, level=LEVEL):
    """(lo, hi) [s] of a point's mean step time from its repeats' per-step times series [R][n]:
    over the repeat means when R >= 2, else over the one run's batch means (module docstring)."""
    series = [np.asarray(x, dtype=float) for x in series if len(x)]
    if len(series) >= 2:
        return mean_interval([x.mean() for x in series], level)
    if len(series) == 1:
        return mean_interval(batch_means(series[0]), level)
    return math.nan, math.nan


def format_reps(values):
    """runs.csv `totalT_reps`: the repeats' mean step times [s], ';'-separated."""
    return ";".join(repr(float(v)) for v in values)


def parse_reps(text):
    """The repeat means of a `totalT_reps` field ([] when empty or unreadable)."""
    if not isinstance(text, str) or not text.strip():
        return []
    try:
        return [float(v) for v in text.split(";")]
    except ValueError:
        return []


def speedup_interval(t1, t1_lo, t1_hi, t, t_lo, t_hi, reps1=(), reps=(), level=LEVEL):
    """(lo, hi) of the speedup T1 / T (module docstring): paired over the rounds when both have
    the same number >= 2 of repeat means, else the log-intervals' half-widths in quadrature, each
    side of the point estimate t1 / t. NaN where an interval is missing."""
    reps1, reps = list(reps1), list(reps)
    if len(reps1) == len(reps) >= 2 and all(v > 0 for v in reps1 + reps):
        return ratio_interval(reps1, reps, level=level)
    vals = (t1, t1_lo, t1_hi, t, t_lo, t_hi)
    if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in vals):
        return math.nan, math.nan
    s = t1 / t
    down = math.hypot(math.log(t1 / t1_lo), math.log(t_hi / t))
    up = math.hypot(math.log(t1_hi / t1), math.log(t / t_lo))
    return s * math.exp(-down), s * math.exp(up)


def ratio_interval(num, den, scale=1.0, level=LEVEL):
    """(lo, hi) of a ratio scale x num / den measured in rounds, paired over them: num, den [R] the
    two sides' times of each round (round r's num and den ran back to back, so the machine's state
    of that round cancels); the Student interval of the rounds' log ratios, mapped back (the
    geometric mean's interval, as speedup_interval). NaN under 2 rounds or where a time is not
    positive. A parallel efficiency against its own serial is ratio_interval(t_serial, t_T, 1 / T)."""
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    if num.shape != den.shape or len(num) < 2 or not (np.all(num > 0) and np.all(den > 0)):
        return math.nan, math.nan
    lo, hi = mean_interval(np.log(num) - np.log(den), level)
    return scale * math.exp(lo), scale * math.exp(hi)


def verdict(lo, hi, target, higher_is_better=True, strict=False):
    """A target's verdict from a figure's interval (lo, hi): "met" where the whole interval is on
    the target's good side (at or above it; strict: above, as "speedup > 1"; at or below it where
    lower is better, as a serial fraction), "not met" where the whole interval is on the other
    side, "unresolved" where it straddles the target or there is none (NaN): more rounds narrow it
    as 1 / sqrt(R)."""
    if not higher_is_better:
        return verdict(-hi, -lo, -target, True, strict)
    if lo > target or (lo == target and not strict):
        return "met"
    if hi < target or (hi == target and strict):
        return "not met"
    return "unresolved"


def format_interval(lo, hi, digits=3):
    """'[lo, hi]' of an interval to `digits` decimals, '' where there is none (NaN)."""
    if math.isnan(lo) or math.isnan(hi):
        return ""
    return f"[{lo:.{digits}f}, {hi:.{digits}f}]"
