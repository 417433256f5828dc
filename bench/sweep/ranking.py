"""The sweep's verdict in words (issue 36, part 3): at each core count, the fastest mapping, those
not distinguishable from it, and the others with how much slower and the 95 % interval.

Two points A (the fastest by median step time) and B at one core count are compared by the
ratio T_B / T_A of their mean step times: paired over the interleaved rounds when both have the
same number R >= 2 of repeat means (runs.csv `totalT_reps`), the Student interval of the mean of
log(T_B,r / T_A,r) over the rounds r (a round's shared machine state cancels: the paired t test);
otherwise from the two points' own intervals, their log half-widths in quadrature
(bench.sweep.intervals.speedup_interval, which computes the same ratio). B ties A when the interval
holds 1: the data cannot tell them apart at 95 %; else B is slower by the ratio - 1. A point
measured beside foreign load (runs.csv flag `load`) or not done is left out of the ranking and
named with the reason. Plotting and this module only read records (runs.csv).
"""
import math

from bench.sweep.intervals import number, parse_reps, speedup_interval


def point_label(row):
    """A point as people name it: its mapping, and its thread scheme when it has one."""
    scheme = row.get("scheme")
    scheme = scheme.strip() if isinstance(scheme, str) else ""
    mapping = row.get("mapping")
    mapping = mapping.strip() if isinstance(mapping, str) and mapping.strip() else str(row.get("point"))
    return mapping + (f" {scheme}" if scheme else "")


def compare(fast, slow):
    """(ratio, lo, hi) of T_slow / T_fast (rows of runs.csv as dicts) with its 95 % interval (module
    docstring); NaN bounds where neither pairing nor both intervals are available."""
    t_fast, t_slow = number(fast["totalT"]), number(slow["totalT"])
    ratio = t_slow / t_fast
    # T_slow / T_fast is the "speedup" of the fast point against the slow one as reference
    lo, hi = speedup_interval(t_slow, number(slow.get("totalT_lo")), number(slow.get("totalT_hi")), t_fast,
                              number(fast.get("totalT_lo")), number(fast.get("totalT_hi")),
                              parse_reps(slow.get("totalT_reps")), parse_reps(fast.get("totalT_reps")))
    return ratio, lo, hi


def _count(row):
    n = number(row.get("particles"))
    return int(n) if math.isfinite(n) else None


def rank(rows):
    """The ranking of runs.csv rows (dicts): a list, one entry per particle count and core count
    (ascending; only points of the same scene size are compared), of {"particles", "cores",
    "fastest", "ties": [{point, percent, lo, hi}], "slower": [...], "excluded": [{point, reason}]};
    percent and its bounds: 100 (T / T_fastest - 1) [%] (None where there is no interval: JSON has
    no NaN)."""
    out = []
    groups = sorted({(_count(r), int(number(r["cores"]))) for r in rows if math.isfinite(number(r.get("cores")))},
                    key=lambda g: (-1 if g[0] is None else g[0], g[1]))
    for n, c in groups:
        at = [r for r in rows if math.isfinite(number(r.get("cores"))) and int(number(r["cores"])) == c
              and _count(r) == n]
        excluded, ranked = [], []
        for r in at:
            flags = str(r.get("flag") or "").split(",")
            if r.get("status") != "done" or not math.isfinite(number(r.get("totalT"))):
                excluded.append({"point": point_label(r), "reason": f"not done ({r.get('status')})"})
            elif "load" in flags:
                excluded.append({"point": point_label(r), "reason": "measured beside foreign load"})
            else:
                ranked.append(r)
        entry = {"particles": n, "cores": c, "fastest": None, "ties": [], "slower": [], "excluded": excluded}
        if ranked:
            ranked.sort(key=lambda r: number(r["totalT"]))
            best = ranked[0]
            entry["fastest"] = point_label(best)
            for r in ranked[1:]:
                ratio, lo, hi = compare(best, r)
                item = {"point": point_label(r), "percent": 100.0 * (ratio - 1.0),
                        "lo": 100.0 * (lo - 1.0) if math.isfinite(lo) else None,
                        "hi": 100.0 * (hi - 1.0) if math.isfinite(hi) else None}
                # without an interval nothing can be told apart: a tie, said as such
                (entry["ties"] if not lo > 1.0 else entry["slower"]).append(item)
        out.append(entry)
    return out


def _pct(item):
    if item["lo"] is None:
        return f"{item['percent']:+.0f} %, no interval"
    return f"{item['percent']:+.0f} %, 95 % interval {item['lo']:+.0f} to {item['hi']:+.0f} %"


def ranking_lines(ranking):
    """The ranking in words, one line per core count (and particle count, named when the sweep has
    several), e.g. "2 cores: 2-2-1-1-1 fastest;
    1-1-1-1-2 dynamic ties it (+1 %, 95 % interval -3 to +5 %); 2-1-2-1-1 is slower (+9 %, ...)"."""
    lines = []
    sizes = len({e.get("particles") for e in ranking}) > 1
    for e in ranking:
        if e["fastest"] is None:
            parts = ["nothing to rank"]
        else:
            parts = [f"{e['fastest']} fastest"]
            parts += [f"{t['point']} ties it ({_pct(t)})" for t in e["ties"]]
            parts += [f"{s['point']} is slower ({_pct(s)})" for s in e["slower"]]
        parts += [f"{x['point']} left out: {x['reason']}" for x in e["excluded"]]
        size = f"{e['particles']:,} particles, " if sizes and e.get("particles") is not None else ""
        lines.append(f"{size}{e['cores']} core{'s' if e['cores'] != 1 else ''}: " + "; ".join(parts))
    return lines
