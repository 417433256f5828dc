"""Repeats until resolved (issue 36, part 2): when `bench sweep --precision F` may stop adding rounds.

After the requested rounds (at least MIN_ROUNDS: one run's interval covers its steps' noise only,
not what changes from run to run, bench.sweep.intervals), the sweep adds whole interleaved rounds
(every point of the sweep once, the serial reference first, so that speedups and the ranking stay
paired over the same rounds) while some point is unresolved: its 95 % interval of the mean step
time [lo, hi] (runs.csv totalT_lo/hi) has a relative half-width

    w = (hi - lo) / 2 / T,    T = the point's median step time (runs.csv totalT)

above F. With R repeats w shrinks about as t(0.975, R - 1) / sqrt(R) (4.3 / 1.7 = 2.5 at R = 3,
2.3 / 3.0 = 0.77 at R = 9): a point whose repeats scatter by s (relative) is resolved near
R = (2.1 s / F)^2 + 1 rounds. It stops when every done point is resolved, when the next round
would not fit the budget (`--budget`: seconds of the whole sweep; the next round is expected to
last as long as the longest round so far), or after ROUNDS_CAP rounds. runs.csv `resolved` then
says for each point: `yes`, `no: budget spent` or `no: ROUNDS_CAP rounds`.
"""
import math

from bench.run.spec import ROUNDS_CAP  # declared with --precision, whose help states it
from bench.sweep.intervals import number as _num
from bench.sweep.ranking import point_label as label

MIN_ROUNDS = 2

RESOLVED = "yes"
STOPPED_BUDGET = "no: budget spent"
STOPPED_CAP = f"no: {ROUNDS_CAP} rounds"


def half_width(row):
    """The relative half-width w = (totalT_hi - totalT_lo) / 2 / totalT of a runs.csv row (NaN
    without an interval: a failed point, or fewer than two repeats or batches)."""
    t, lo, hi = _num(row.get("totalT")), _num(row.get("totalT_lo")), _num(row.get("totalT_hi"))
    if not (math.isfinite(t) and math.isfinite(lo) and math.isfinite(hi)) or t <= 0:
        return math.nan
    return (hi - lo) / 2.0 / t


def unresolved(rows, precision):
    """The done rows whose half-width is above `precision` or unknown (a failed point can never be
    resolved by more rounds: it is left out), widest first, as (label, w)."""
    out = [(label(r), half_width(r)) for r in rows if r.get("status") == "done"]
    out = [(n, w) for n, w in out if not w <= precision]
    return sorted(out, key=lambda item: -item[1] if math.isfinite(item[1]) else -math.inf)


def widest(rows):
    """(label, w) of the done row with the widest relative interval; None when none has one."""
    known = [(label(r), half_width(r)) for r in rows if r.get("status") == "done"]
    known = [(n, w) for n, w in known if math.isfinite(w)]
    return max(known, key=lambda item: item[1]) if known else None


def widest_text(rows):
    """The progress line's ", widest interval +-7.3 % (2-2-1-1-1)" ('' before any interval)."""
    w = widest(rows)
    return f", widest interval +-{100 * w[1]:.1f} % ({w[0]})" if w else ""


def next_round(rounds_done, elapsed, round_seconds, budget):
    """Why no further round starts (STOPPED_CAP, STOPPED_BUDGET), or None when one may: at most
    ROUNDS_CAP rounds, and with a budget [s] the next round (as long as the longest so far,
    round_seconds [s]) must end within it."""
    if rounds_done >= ROUNDS_CAP:
        return STOPPED_CAP
    if budget is not None and elapsed + max(round_seconds or [0.0]) > budget:
        return STOPPED_BUDGET
    return None


def mark(rows, precision, stop):
    """Set runs.csv `resolved` of each done row: yes when its half-width is within `precision`,
    else why the sweep stopped short (`stop`, or STOPPED_CAP when it did not say)."""
    for r in rows:
        if r.get("status") != "done":
            r["resolved"] = ""
        else:
            r["resolved"] = RESOLVED if half_width(r) <= precision else (stop or STOPPED_CAP)
    return rows
