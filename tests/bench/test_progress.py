"""Progress of long work (bench/run/progress.py, bench.sweep.driver.SweepClock): what a user sees
while a run or a sweep goes on, and how good its estimate of the time left is (issue 34: after
`sweep: 4 points x 1 repeats ...` nothing was printed for 160 s, and the first estimate said
481 s left where 71 s remained)."""
import io
import json

import pytest

from bench.run.progress import Progress, format_seconds
from bench.sweep.driver import SweepClock, current_step


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_a_line_every_period_off_a_terminal():
    """Off a terminal: one line every 10 s of the work, with the count, the share done and the time
    left at the rate so far (1200 of 2000 steps in 30 s: 20 s left)."""
    clock, out = FakeClock(), io.StringIO()
    p = Progress(2000, "packed 1-1-1-1-2", terminal=False, stream=out, clock=clock)
    for step in range(1, 2001):
        clock.t = 0.025 * step
        p.update(step)
    lines = out.getvalue().splitlines()
    assert len(lines) == 5  # at 10, 20, 30, 40 and 50 s of a 50 s run
    assert lines[2] == "packed 1-1-1-1-2: 1200/2000 steps (60 %), 30 s elapsed, about 20 s left"
    quiet = Progress(2000, "x", enabled=False, terminal=False, stream=out, clock=clock)
    quiet.update(2000)
    assert len(out.getvalue().splitlines()) == 5


def test_format_seconds():
    assert [format_seconds(s) for s in (4.2, 59.6, 65, 3725)] == ["4 s", "60 s", "1 min 05 s", "1 h 02 min"]


def _rep(tmp_path, name, steps_written, total, build=None):
    d = tmp_path / name
    d.mkdir()
    (d / "run.json").write_text(json.dumps({"steps": total, "step_first": 1, "build": build or {}}))
    rows = "".join(f"{k},0,0.001\n" for k in range(1, steps_written + 1))
    (d / "steps.csv").write_text("step,rank,totalT\n" + rows + "17,0,0.0")  # a row being written
    return str(d)


def test_current_step_reads_the_last_whole_row(tmp_path):
    rep = _rep(tmp_path, "a", 16, 100)
    assert current_step(rep) == (16, 100)
    assert current_step(str(tmp_path / "none")) == (None, None)


def test_estimate_leaves_out_the_build_and_uses_the_running_rate(tmp_path, monkeypatch):
    """Three runs of 100 steps: the first built its scene (40 s of its 50 s), so it stands for
    10 s; the second is a quarter through after 5 s, so 15 s remain of it: 15 s + one run of
    10 s left. The old estimate (elapsed / runs done x runs left) said 100 s."""
    import bench.sweep.driver as driver
    now = {"t": 0.0}
    monkeypatch.setattr(driver.time, "monotonic", lambda: now["t"])
    clock = SweepClock(3)
    first = _rep(tmp_path, "r0", 100, 100, build={"from_cache": False, "build_s": 40.0})
    clock.begin("point 1/3", first)
    now["t"] = 50.0
    clock.end(first)
    second = _rep(tmp_path, "r1", 25, 100)
    clock.begin("point 2/3", second)
    now["t"] = 55.0
    assert clock.left() == pytest.approx(15.0 + 10.0)
    clock.close()


def test_build_log_off_a_terminal_is_throttled():
    """A scene build logs every 1000 steps; off a terminal one line every 10 s reaches the log."""
    from bench.run.progress import build_log
    clock, out = FakeClock(), io.StringIO()
    log = build_log(terminal=False, stream=out, clock=clock)
    for k in range(1, 101):  # a message every 0.5 s for 50 s
        clock.t = 0.5 * k
        log(f"building: step {1000 * k}")
    assert out.getvalue().splitlines() == [f"building: step {1000 * k}" for k in (20, 40, 60, 80, 100)]
