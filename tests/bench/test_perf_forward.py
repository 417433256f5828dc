"""`bench perf --what forward` (bench/studies/perf_forward.py): the ghosts' forward exchange by
messages against the shared-memory window inside MPI jobs. The transport never changes results
(DESIGN.md, Determinism), so both set-ups of a job end bit-identical; the window sends no forward
message; the statistics follow their definitions (worked by hand below)."""
import json
import math
import os
import signal
import subprocess
import sys
import time

import pytest

from bench.studies.perf_forward import faster, job_row, summarize
from tests.helpers import ROOT, bench, one_line_error


def test_forward_jobs_end_identical_and_the_window_sends_no_forward_message(tmp_path):
    """Two jobs of 2 ranks (2-2-1-1-1) on 500 packed ellipsoids at rest, 2 cycles each. Between
    rebuilds each rank sends one forward message and one reverse (Newton) message a step to its one
    neighbour by messages, and only the reverse one through the window: with no rebuild in the timed
    steps (a bed at rest moves less than half the skin) all ranks send 4 messages a step against 2.
    Both set-ups end in the same state, bit for bit. Each job made two windows (modes/window.py: an
    empty one at set-up, then the one the first rows ask for) and none grew after."""
    res = bench("perf", "--what", "forward", "--particles", "500", "--repeats", "2", "--in-job", "2",
                "--out", str(tmp_path), timeout=600)
    assert res.returncode == 0, res.stderr
    rep = json.loads((tmp_path / "perf.json").read_text())
    assert rep["what"] == "forward" and rep["mapping"] == "2-2-1-1-1" and rep["jobs"] == 2 and rep["identical"]
    for row in rep["jobs_rows"]:
        assert row["identical"] and row["transport"] == {"messages": "messages", "shared": "shared"}
        assert row["forward_windows"] == 2
        msg, win = row["parts_us"]["messages"], row["parts_us"]["shared"]
        assert msg["neighbor_rebuilt"] == 0 and win["neighbor_rebuilt"] == 0
        assert msg["msgs_sent"] == 4 and win["msgs_sent"] == 2
        assert len(row["samples"]["messages_s"]) == len(row["samples"]["shared_s"]) == 2
    assert "no ranking" in res.stdout or "faster" in res.stdout


def test_job_row_and_summary_follow_their_definitions():
    """A job of 3 cycles, messages 2.0, 2.2, 2.1 ms against shared 1.9, 2.0, 2.1 ms: ratios 1.0526,
    1.1, 1.0, geometric mean 1.05008; the Student interval of the logs (t(2) = 4.3027, sd 0.047702)
    is [0.93274, 1.18219]; medians 2.1 and 2.0 ms. Three jobs of ratio 1.10, 1.20, 1.15: geometric
    mean 1.14927, interval [1.03154, 1.28045] (sd of the logs 0.043508): the window is faster."""
    doc = {"messages_s": [2.0e-3, 2.2e-3, 2.1e-3], "shared_s": [1.9e-3, 2.0e-3, 2.1e-3], "cycles": 3,
           "identical": True, "pinned": True, "transport": {}, "forward_windows": 1,
           "parts": {"messages": {"commuT": 1e-5, "msgs_sent": 4.0, "neighbor_rebuilt": 0.0}}}
    row = job_row(doc)
    assert row["ratio"] == pytest.approx(1.050082, abs=1e-5)
    assert (row["ratio_lo"], row["ratio_hi"]) == pytest.approx((0.932740, 1.182185), abs=1e-5)
    assert (row["messages_ms"], row["shared_ms"]) == pytest.approx((2.1, 2.0))
    assert row["parts_us"]["messages"] == pytest.approx({"commuT": 10.0, "msgs_sent": 4.0, "neighbor_rebuilt": 0.0})
    rows = [dict(row, ratio=r) for r in (1.10, 1.20, 1.15)]
    s = summarize(rows)
    assert s["ratio"] == pytest.approx(1.149275, abs=1e-5)
    assert (s["ratio_lo"], s["ratio_hi"]) == pytest.approx((1.031536, 1.280453), abs=1e-5)
    assert s["faster"] == "shared" and s["jobs"] == 3 and s["identical"]
    one = summarize(rows[:1])
    assert math.isnan(one["ratio_lo"]) and one["faster"] == "tie"   # one job: no interval, no ranking


def test_faster_reads_the_whole_interval():
    """Above 1 throughout: the window; below 1 throughout: the messages; holding 1: neither."""
    assert faster(1.01, 1.2) == "shared"
    assert faster(0.9, 0.99) == "messages"
    assert faster(0.98, 1.02) == "tie"
    assert faster(math.nan, math.nan) == "tie"


@pytest.mark.parametrize("args,words", [
    (["--procs", "1"], ["--what forward needs at least 2 ranks"]),
    (["--mapping", "2-2-2-1-1"], ["malformed mapping"]),
    (["--scene", "nosuch"], ["unknown scene 'nosuch'"]),
    (["--procs", "100000"], ["100000 ranks x 1 threads started here is more than"]),
])
def test_bad_input(args, words):
    one_line_error(bench("perf", "--what", "forward", *args), *words)


def test_in_job_is_for_overhead_and_forward_only():
    one_line_error(bench("perf", "--what", "comm", "--in-job", "3"), "--in-job is for --what overhead and forward")


def _forward_ranks():
    """The processes of a forward comparison's MPI job (its ranks name their program)."""
    import psutil
    left = []
    for p in psutil.process_iter(["pid", "cmdline"]):
        try:
            if any("perf_forward_rank" in a for a in (p.info["cmdline"] or [])):
                left.append(p.info["pid"])
        except psutil.Error:
            pass
    return left


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_interrupted_comparison_leaves_no_rank(sig, code):
    """SIGTERM (as `bench node` sends a part past its time) or Ctrl-C of `bench perf --what forward`
    while its ranks step: one line, exit 128 + the signal, and no rank of its MPI job left."""
    proc = subprocess.Popen([sys.executable, "-m", "bench", "perf", "--what", "forward", "--particles", "300",
                             "--repeats", "1", "--in-job", "100000"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    end = time.time() + 240
    while len(_forward_ranks()) < 2 and time.time() < end:
        time.sleep(0.2)
    assert len(_forward_ranks()) >= 2, "the ranks never started"
    time.sleep(3.0)   # past their set-up: stepping
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "interrupted by " + signal.Signals(sig).name in lines[0], err
    time.sleep(1.0)
    assert _forward_ranks() == [], "orphan ranks"
