"""Each point of a sweep against the same point of an earlier sweep (issue 36, part 4): faster,
slower or the same, with the 95 % interval of the ratio (`bench compare OLD NEW`, `bench sweep
--compare OLD`).

Points are matched by their runs.csv `point` key (the mapping, scheme and a hash of every run
parameter, bench.sweep.points: the same key is the same experiment). For a point measured in both,
the ratio of its step times r = T_new / T_old (runs.csv `totalT`, the median over its repeats) has
the 95 % interval

    r exp(-sqrt(log(T_new / T_new,lo)^2 + log(T_old,hi / T_old)^2)),
    r exp(+sqrt(log(T_new,hi / T_new)^2 + log(T_old / T_old,lo)^2))

from each sweep's own interval of the point's mean step time (`totalT_lo`, `totalT_hi`:
bench.sweep.intervals, Student's t over the repeats' means, or over batch means of steps with one
repeat): the two intervals' log half-widths added in quadrature, the two sweeps' errors being
independent (first order in the relative widths; bench.sweep.intervals.speedup_interval, the form
it takes when the two times are not paired). The two sweeps ran in different rounds, at different
times, so nothing is paired: no machine state shared by a round cancels, and the pairing over
rounds the ranking uses (bench.sweep.ranking) does not apply. The point is

- `slower` when the interval lies above 1 (T_new > T_old at 95 %), `faster` when it lies below 1,
- `same` when it holds 1: the data cannot tell the two sweeps apart,
- `no interval` when either sweep has no interval for it (NaN bounds; a bound <= 0 from a Student
  interval of very scattered repeats counts as none),
- `not compared` when it is not done in either sweep, has no time, or was measured beside foreign
  load (runs.csv flag `load`) in either: a loaded time says nothing of the code,
- `only in old` / `only in new` when one sweep did not measure it.

With one repeat a point's interval covers the step-to-step noise of that run only, not what
changes from run to run (placement, clock, the machine itself): a `slower` from two single-repeat
sweeps, or from sweeps on different machines, says the runs differ, not why. Reading only: nothing
is written into either folder.
"""
import math
import os

from bench.sweep.intervals import number as _num
from bench.sweep.intervals import speedup_interval
from bench.sweep.ranking import point_label
from bench.sweep.records import RunsFileError, read_runs_rows

VERDICTS = ("faster", "slower", "same", "no interval", "not compared", "only in old", "only in new")




def read_sweep_rows(folder):
    """The rows of FOLDER/runs.csv (dicts, bench.sweep.records.read_runs_rows), one per point key (a
    key written twice: its last row). RunsFileError (one line) when the folder or its runs.csv is
    missing or cannot be read as a runs table."""
    if not os.path.isdir(folder):
        raise RunsFileError(f"{folder} is not a folder")
    path = os.path.join(folder, "runs.csv")
    if not os.path.isfile(path):
        raise RunsFileError(f"{folder} has no runs.csv (not a sweep folder)")
    _, rows, _ = read_runs_rows(path)
    return {row["point"]: row for row in rows if row.get("point")}


def _not_comparable(row, side):
    """Why a point's row of one sweep cannot be compared, or None."""
    if (row.get("status") or "").strip() != "done":
        return f"not done in the {side} sweep ({(row.get('status') or 'no status').strip()})"
    if not _num(row.get("totalT")) > 0:
        return f"no step time in the {side} sweep"
    if "load" in [f.strip() for f in (row.get("flag") or "").split(",")]:
        return f"measured beside foreign load in the {side} sweep"
    return None


def ratio_interval(old, new):
    """(ratio, lo, hi) of T_new / T_old of one point (rows of runs.csv as dicts) with its 95 %
    interval, independent form (module docstring); NaN bounds without both intervals."""
    t_old, t_new = _num(old.get("totalT")), _num(new.get("totalT"))
    # T_new / T_old is the "speedup" of the old time against the new as the reference; no repeat
    # means given: the two sweeps are not paired
    lo, hi = speedup_interval(t_new, _num(new.get("totalT_lo")), _num(new.get("totalT_hi")),
                              t_old, _num(old.get("totalT_lo")), _num(old.get("totalT_hi")))
    return t_new / t_old, lo, hi


def verdict(lo, hi):
    """faster (hi < 1), slower (lo > 1), same (the interval holds 1) or no interval (NaN bounds)."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "no interval"
    if hi < 1.0:
        return "faster"
    if lo > 1.0:
        return "slower"
    return "same"


def compare_folders(old_dir, new_dir):
    """Every point of two sweep folders' runs.csv: a list of dicts {point (label: mapping and
    scheme), key, old (old_dir), ratio = T_new / T_old, lo, hi (its 95 % interval; NaN where there
    is none), verdict (VERDICTS), reason (why not compared, else '')}, the new sweep's points in its
    order, then those only in the old one. RunsFileError when either folder has no readable
    runs.csv."""
    old_rows, new_rows = read_sweep_rows(old_dir), read_sweep_rows(new_dir)
    entries = []

    def entry(row, key, verdict_, ratio=math.nan, lo=math.nan, hi=math.nan, reason=""):
        entries.append({"point": point_label(row), "key": key, "old": old_dir, "ratio": ratio, "lo": lo,
                        "hi": hi, "verdict": verdict_, "reason": reason})

    for key, new in new_rows.items():
        old = old_rows.get(key)
        if old is None:
            entry(new, key, "only in new")
            continue
        reason = _not_comparable(old, "old") or _not_comparable(new, "new")
        if reason:
            entry(new, key, "not compared", reason=reason)
            continue
        ratio, lo, hi = ratio_interval(old, new)
        entry(new, key, verdict(lo, hi), ratio, lo, hi)
    for key, old in old_rows.items():
        if key not in new_rows:
            entry(old, key, "only in old")
    return entries


def _percents(*ratios):
    """100 (r - 1) of each ratio as text: whole percent, one decimal when all are within 2 %."""
    pct = [100.0 * (r - 1.0) for r in ratios]
    digits = 1 if max(abs(p) for p in pct) < 2.0 else 0
    return [f"{round(p, digits) + 0.0:+.{digits}f}" for p in pct]  # + 0.0: -0.0 reads +0


def comparison_lines(entries):
    """The comparison in words, a line per point, e.g. "2-2-1-1-1: 7 % slower than in DIR (95 %
    interval +3 to +11 %)", "1-1-1-1-1: the same as in DIR (-1 %, 95 % interval -4 to +2 %)",
    "1-1-1-1-2 dynamic: not compared (measured beside foreign load in the new sweep)"."""
    lines = []
    for e in entries:
        where = e["old"]
        if e["verdict"] in ("faster", "slower"):
            pct, lo, hi = _percents(e["ratio"], e["lo"], e["hi"])
            text = f"{pct.lstrip('+-')} % {e['verdict']} than in {where} (95 % interval {lo} to {hi} %)"
        elif e["verdict"] == "same":
            pct, lo, hi = _percents(e["ratio"], e["lo"], e["hi"])
            text = f"the same as in {where} ({pct} %, 95 % interval {lo} to {hi} %)"
        elif e["verdict"] == "no interval":
            (pct,) = _percents(e["ratio"])
            text = f"{pct} % against {where}, no interval (a sweep has none for this point): not told apart"
        elif e["verdict"] == "not compared":
            text = f"not compared ({e['reason']})"
        elif e["verdict"] == "only in old":
            text = f"only in {where} (not measured in the new sweep)"
        else:
            text = f"not in {where} (new point)"
        lines.append(f"{e['point']}: {text}")
    return lines
