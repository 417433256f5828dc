"""`bench node` (bench/studies/node.py): the many-core check's mappings, its verdict read from
records, and its bad input. The check itself runs on a many-core node (README, "Sixteen cores");
its records are those of `bench sweep` and `bench schemes`, tested in their own files."""
import math
import pandas as pd
import pytest

from bench.studies.node import grid, mappings, verdict
from tests.helpers import bench, one_line_error


def test_mappings_at_16_are_issue_32s():
    """At 16 cores the sweeps the issue ran on the lent machine (issue 32, "Why"): unpinned
    1-1-1-1-4,1-1-1-1-16,2-2-1-1-8,4-2-2-1-4,8-2-2-2-2,4-2-2-1-1,16-4-2-2-1; pinned with the ceiling
    1-1-1-1-16, 4-2-2-1-4, 16-4-2-2-1."""
    unpinned, pinned = mappings(16)
    assert unpinned == ["1-1-1-1-4", "1-1-1-1-16", "2-2-1-1-8", "4-2-2-1-4", "8-2-2-2-2", "4-2-2-1-1", "16-4-2-2-1"]
    assert pinned == ["1-1-1-1-16", "4-2-2-1-4", "16-4-2-2-1"]


def test_mappings_elsewhere():
    """2 cores (the rehearsal): 2 threads and 2 ranks; 36 (the paper's Thunder node): 9 threads,
    36 threads, 2 x 18, 4 x 9, 9 ranks, 36 ranks on a 4x3x3 grid."""
    assert mappings(2) == (["1-1-1-1-2", "2-2-1-1-1"], ["1-1-1-1-2", "2-2-1-1-1"])
    unpinned, pinned = mappings(36)
    assert unpinned == ["1-1-1-1-9", "1-1-1-1-36", "2-2-1-1-18", "4-2-2-1-9", "9-3-3-1-1", "36-4-3-3-1"]
    assert pinned == ["1-1-1-1-36", "4-2-2-1-9", "36-4-3-3-1"]
    assert [grid(p) for p in (1, 2, 4, 8, 9, 16, 12)] == [(1, 1, 1), (2, 1, 1), (2, 2, 1), (2, 2, 2), (3, 3, 1),
                                                         (4, 2, 2), (3, 2, 2)]


def _runs(rows):
    cols = ["mapping", "status", "totalT", "resolveT", "efficiency", "totalT_spread", "binding", "flag", "procs",
            "threads", "point"]
    return pd.DataFrame([dict(zip(cols, r)) for r in rows])


def test_verdict_reads_the_targets():
    """Issue 32's 16-core figures as records: 4 threads 6.67 ms against 4 ranks 4.88 ms is 1.367
    (37 % slower, target <= 1.1); 16 threads 2.15 against 16 ranks 2.06 is 1.044 (met); 16 ranks at
    efficiency 0.553 over an in-step ceiling 0.635 is 0.871 (target >= 0.9)."""
    unpinned = _runs([
        ("1-1-1-1-1", "done", 18.97e-3, 13.5e-3, 1.0, 0.34, "unpinned", "spread", 1, 1, "a"),
        ("1-1-1-1-4", "done", 6.67e-3, 5.2e-3, 0.71, 0.05, "unpinned", "", 1, 4, "b"),
        ("4-2-2-1-1", "done", 4.88e-3, 3.65e-3, 0.97, 0.02, "unpinned", "", 4, 1, "c"),
        ("1-1-1-1-16", "done", 2.15e-3, 1.5e-3, 0.55, 0.02, "unpinned", "", 1, 16, "d"),
        ("16-4-2-2-1", "done", 2.06e-3, 1.0e-3, 0.58, 0.03, "unpinned", "", 16, 1, "e"),
        ("4-2-2-1-4", "done", 2.16e-3, 1.2e-3, 0.55, 0.02, "unpinned", "", 4, 4, "f"),
    ])
    pinned = _runs([
        ("1-1-1-1-16", "done", 2.0e-3, 1.4e-3, 0.59, 0.01, "pinned", "", 1, 16, "g"),
        ("16-4-2-2-1", "done", 2.14e-3, 1.0e-3, 0.553, 0.01, "pinned", "", 16, 1, "h"),
        ("4-2-2-1-4", "done", 2.3e-3, 1.2e-3, 0.52, 0.01, "pinned", "", 4, 4, "i"),
    ])
    ceiling = pd.DataFrame([{"cores": 16, "ceiling_free": 0.957, "ceiling_step": 0.635}])
    # Table 1's rows with their 95 % intervals (bench schemes, paired over its rounds); one without
    schemes = pd.DataFrame([
        {"method": "dynamic", "neighbor": "allpairs", "threads": 16, "speedup": 5.4, "efficiency_own": 0.3375,
         "efficiency_own_lo": 0.30, "efficiency_own_hi": 0.35},
        {"method": "dynamic", "neighbor": "linkcell", "threads": 16, "speedup": 3.0, "efficiency_own": 0.2,
         "efficiency_own_lo": 0.18, "efficiency_own_hi": 0.22},
        {"method": "static", "neighbor": "linkcell", "threads": 16, "speedup": 9.0, "efficiency_own": 0.71,
         "efficiency_own_lo": 0.66, "efficiency_own_hi": 0.75, "ceiling": 0.8, "ceiling_lo": 0.72,
         "ceiling_hi": 0.85, "of_ceiling": 0.8875},
        {"method": "frogleap", "neighbor": "linkcell", "threads": 16, "speedup": 9.0, "efficiency_own": 0.71,
         "efficiency_own_lo": math.nan, "efficiency_own_hi": math.nan},
    ])
    # the binding Table 1 recorded, the same on every row (bench.studies.schemes)
    schemes["pinned"], schemes["thread_cpus"], schemes["binding_held"] = 0, " ".join(["{0-15}"] * 16), 1
    text = "\n".join(verdict(16, unpinned, pinned, ceiling, schemes, steps={"1-1-1-1-4": 1.2}))
    assert f"- Table 1's threads unpinned, on CPUs {' '.join(['{0-15}'] * 16)}\n" in text + "\n"
    held = schemes.assign(pinned=1, thread_cpus=" ".join(f"{{{c}}}" for c in range(16)), binding_held=0)
    said = "\n".join(verdict(16, unpinned, pinned, ceiling, held))
    assert ("- Table 1's threads pinned to CPUs {0} {1} {2} {3} {4} {5} {6} {7} {8} {9} {10} {11} {12} {13} {14} "
            "{15} (the binding did not hold through the rounds)") in said
    assert "- 1-1-1-1-4 / 4-2-2-1-1, step time: 1.367 (target <= 1.1: NOT met; repeats' spread up to 5 %)" in text
    assert "- 1-1-1-1-16 / 16-4-2-2-1, step time: 1.044 (target <= 1.1: met; repeats' spread up to 3 %)" in text
    assert "- 1-1-1-1-4, slowest thread over the mean: 1.200 (target <= 1.05: NOT met)" in text
    assert ("- 16-4-2-2-1 (pinned, the ceiling's sweep) efficiency over the in-step ceiling: 0.553 / 0.635 = 0.871 "
            "(target >= 0.9: NOT met; free ceiling 0.957)") in text
    # 2.0 / 2.15 = 0.930: pinned faster; 2.3 / 2.16 = 1.065: pinned slower
    assert "- 1-1-1-1-16 pinned / unpinned, step time (two sweeps): 0.930 (target <= 1: met;" in text
    assert "- 4-2-2-1-4 pinned / unpinned, step time (two sweeps): 1.065 (target <= 1: NOT met;" in text
    assert "- binding of the pinned points: pinned, pinned, pinned" in text
    # 16 x [0.30, 0.35] = [4.80, 5.60], all below 11; link-cell verdicts from the whole interval
    assert ("dynamic all-pairs detection speedup at 16 threads: 5.40x [4.80, 5.60] (target >= 11 at 16: NOT met)"
            in text)
    assert "- Table 1 link-cell dynamic: eff_own 0.20 [0.18, 0.22] (target >= 0.7: NOT met)" in text
    # with --ceiling: 0.71 / 0.8 = 0.8875 of the machine's ceiling, whose interval [0.72, 0.85] lies
    # above the target: the target is within what the machine gives
    assert ("- Table 1 link-cell static: eff_own 0.71 [0.66, 0.75] (target >= 0.7: unresolved); the machine's "
            "ceiling 0.80 [0.72, 0.85], of it 0.89, the target within it") in text
    assert "- Table 1 link-cell frogleap: eff_own 0.71 (target >= 0.7: met (one round: no interval))" in text


def test_verdict_names_what_is_missing():
    """A part that ran out of time and a failed point: named, not guessed."""
    unpinned = _runs([("1-1-1-1-1", "done", 1e-3, 1e-3, 1.0, 0.0, "unpinned", "", 1, 1, "a"),
                      ("1-1-1-1-2", "failed", float("nan"), float("nan"), float("nan"), 0.0, "", "", 1, 2, "b")])
    lines = verdict(2, unpinned, None, None, None, missing=["pinned sweep with the ceiling (past 200 s)"])
    assert "- pinned sweep with the ceiling (past 200 s): did not finish in its time (see log)" in lines
    assert "- 1-1-1-1-2 / 2-2-1-1-1, step time: not measured (a point missing or failed)" in lines


@pytest.mark.parametrize("args,words", [
    (["--cores", "0"], ["--cores"]),
    (["--cores", "100000"], ["--cores 100000 is more than the"]),
    (["--out", " "], ["--out must be a folder"]),
])
def test_bad_input(tmp_path, args, words):
    one_line_error(bench("node", *(["--out", str(tmp_path / "n")] if "--out" not in args else []), *args), *words)


def test_verdict_reads_the_forward_exchange():
    """The fourth part's report (bench perf --what forward at C ranks): its ratio messages / shared
    with the interval over its jobs, the two step times and the messages of all ranks a step (the
    jobs' mean: 120 and 116 by messages, 40 through the window), and the ranking it allows."""
    rows = [{"parts_us": {"messages": {"msgs_sent": m}, "shared": {"msgs_sent": 40.0}}} for m in (120.0, 116.0)]
    forward = {"procs": 16, "mapping": "16-4-2-2-1", "ratio": 1.08, "ratio_lo": 1.02, "ratio_hi": 1.14, "jobs": 2,
               "cycles": 10, "messages_ms": 2.10, "shared_ms": 1.95, "faster": "shared", "identical": True,
               "jobs_rows": rows}
    lines = verdict(16, None, None, None, None, forward=forward)
    assert ("- forward exchange at 16 ranks (16-4-2-2-1), messages / shared window, step time: 1.080 [1.02, 1.14] "
            "over 2 jobs of 10 cycles (2100 against 1950 us a step; messages a step, all ranks: 118 against 40): "
            "the shared window is faster") in lines
    tie = verdict(16, None, None, None, None, forward=dict(forward, ratio_lo=0.97, faster="tie", identical=False))
    assert tie[-1].endswith("no ranking at 95 %; END STATES DIFFER")


def test_a_part_past_its_time_gets_sigterm_then_sigkill(tmp_path):
    """A part past its limit is sent SIGTERM, which a `bench` command turns into a stop of its own
    processes (bench.run.lifeline); one that ignores it is killed after the grace. Both return None
    (named missing in the verdict); a part that ends in time returns its exit status."""
    import sys
    import time
    from bench.studies.node import _part
    mark = tmp_path / "term"
    polite = ("import signal, sys, time\n"
              f"signal.signal(signal.SIGTERM, lambda s, f: (open({str(mark)!r}, 'w').write('term'), sys.exit(0)))\n"
              "time.sleep(60)\n")
    assert _part([sys.executable, "-c", polite], 2) is None
    assert mark.read_text() == "term"
    deaf = "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\ntime.sleep(60)\n"
    t0 = time.time()
    assert _part([sys.executable, "-c", deaf], 1, grace=1) is None
    assert time.time() - t0 < 20
    assert _part([sys.executable, "-c", "raise SystemExit(4)"], 30) == 4
