"""Repeats until resolved (issue 36, part 2): `bench sweep --precision F [--budget S]`.

The sweep's loop (bench.sweep.driver.local_sweep) runs here with a synthetic launcher that writes
each repeat's records (status.json, run.json, steps.csv, state.npz) from step times of known
truth instead of running the scene: a point's repeat r has mean step time T (1 + e_r), e_r
~ N(0, s) the run-to-run scatter of that point, plus step noise; seeded by (point, repeat), so
an interrupted and resumed sweep sees the same numbers as one that was not interrupted. Nothing
is timed: the budget test's runs sleep a fixed time.
"""
import argparse
import json
import math
import os
import time
import zlib

import numpy as np
import pytest

from bench.sweep import precision as prec
from bench.sweep.driver import local_sweep
from bench.sweep.intervals import step_time_interval
from bench.sweep.points import make_points
from bench.sweep.records import read_runs_rows
from tests.bench.synthetic_steps import ar1

STEPS = 40


class SyntheticLauncher:
    """Writes a repeat's records from synthetic step times; scatter: {mapping: (T [s], s)}."""
    name = "local"
    batch = False

    def __init__(self, scatter, sleep_s=0.0, interrupt_at=None):
        self.scatter, self.sleep_s, self.interrupt_at = scatter, sleep_s, interrupt_at
        self.ran = []

    def run_point(self, point, rep_dir, env, lock_fd=None, tick=None):
        rep = int(os.path.basename(rep_dir)[3:])
        if (point.mapping, rep) == self.interrupt_at:
            self.interrupt_at = None
            raise KeyboardInterrupt
        os.makedirs(rep_dir, exist_ok=True)
        mean, s = self.scatter[point.mapping]
        rng = np.random.default_rng(zlib.crc32(f"{point.mapping}/{rep}".encode()))
        run_mean = mean * (1.0 + rng.normal(0.0, s))
        x = ar1(rng, STEPS, run_mean, 0.02 * mean, 0.5)
        lines = ["step,rank,totalT,commuT,migraT,neighborT,resolveT"]
        lines += [f"{i + 1},0,{float(v)!r},0.0,0.0,0.0,0.0" for i, v in enumerate(x)]
        with open(os.path.join(rep_dir, "steps.csv"), "w") as fh:
            fh.write("\n".join(lines) + "\n")
        run = {"status": "done", "particles": 10, "steps": STEPS, "stable": True, "wall_s": 0.01, "load": {},
               "step_time": {"spread": 0.05}}
        with open(os.path.join(rep_dir, "run.json"), "w") as fh:
            json.dump(run, fh)
        np.savez(os.path.join(rep_dir, "state.npz"), id=np.arange(3), pos=np.zeros((3, 3)), axes=np.ones((3, 3)))
        with open(os.path.join(rep_dir, "status.json"), "w") as fh:
            json.dump({"status": "done", "reason": ""}, fh)
        time.sleep(self.sleep_s)
        self.ran.append((point.mapping, rep))
        return {"status": "done", "reason": ""}


def _sweep(out, launcher, mappings, precision, repeats=2, budget=None, resume=False):
    points = make_points(mappings, ["dynamic"], "packed", 10, STEPS, 0, "linkcell", "", False, "26", "exact", 0,
                         "extent", "auto", None, None)
    args = argparse.Namespace(repeats=repeats, precision=precision, budget=budget, resume=resume, scene="packed")
    os.makedirs(out, exist_ok=True)
    code = local_sweep(args, launcher, points, str(out), None)
    rows = {r["mapping"]: r for r in read_runs_rows(os.path.join(out, "runs.csv"))[1]}
    return code, rows


def _steps(out, key, reps):
    return [np.loadtxt(os.path.join(out, key, f"rep{r}", "steps.csv"), delimiter=",", skiprows=1)[:, 2]
            for r in range(reps)]


def test_half_width_and_stop_rules():
    """w = (hi - lo) / 2 / T: [0.95, 1.05] about T = 1 is 0.05; a failed point is never open; the next
    round is refused at ROUNDS_CAP rounds or when it would end past the budget (the longest round so
    far, 3 s, after 8 s of a 10 s budget)."""
    row = {"status": "done", "totalT": 1.0, "totalT_lo": 0.95, "totalT_hi": 1.05, "mapping": "1-1-1-1-2"}
    assert prec.half_width(row) == pytest.approx(0.05)
    failed = {"status": "failed", "totalT": math.nan, "mapping": "2-2-1-1-1"}
    assert prec.unresolved([row, failed], 0.06) == []
    assert prec.unresolved([row, failed], 0.04) == [("1-1-1-1-2", pytest.approx(0.05))]
    assert prec.next_round(prec.ROUNDS_CAP, 0.0, [1.0], None) == prec.STOPPED_CAP
    assert prec.next_round(3, 8.0, [1.0, 3.0], 10.0) == prec.STOPPED_BUDGET
    assert prec.next_round(3, 6.0, [1.0, 3.0], 10.0) is None


def test_sweep_adds_rounds_until_every_point_is_resolved(tmp_path):
    """Points scattering 1 % and 3 % from run to run at +-5 %: rounds are added until both 95 %
    intervals are within 5 % of the median, and not one round more: one round fewer leaves the
    widest above 5 % (recomputed from the repeat folders). With s = 3 % about (2.1 s / F)^2 + 1 = 2.6
    rounds are needed (bench.sweep.precision), so it stops within the cap."""
    out = tmp_path / "sweep"
    launcher = SyntheticLauncher({"1-1-1-1-1": (1e-3, 0.01), "1-1-1-1-2": (0.6e-3, 0.03)})
    code, rows = _sweep(out, launcher, ["1-1-1-1-1", "1-1-1-1-2"], 0.05)
    assert code == 0
    rounds = int(rows["1-1-1-1-1"]["repeats"])
    assert rows["1-1-1-1-2"]["repeats"] == str(rounds)  # whole rounds: every point as often
    assert 2 <= rounds < prec.ROUNDS_CAP
    assert {r["resolved"] for r in rows.values()} == {"yes"}
    for r in rows.values():
        assert prec.half_width(r) <= 0.05
    if rounds > 2:  # the round before the last left a point open
        widths = []
        for r in rows.values():
            lo, hi = step_time_interval(_steps(out, r["point"], rounds - 1))
            widths.append((hi - lo) / 2 / float(r["totalT"]))
        assert max(widths) > 0.05
    summary = json.load(open(out / "summary.json"))
    assert summary["precision"]["rounds"] == rounds and summary["precision"]["unresolved"] == []


def test_a_noisy_point_stops_on_the_round_cap_and_says_so(tmp_path):
    """A point scattering 30 % from run to run cannot reach +-5 % in ROUNDS_CAP = 20 rounds (t(0.975, 19)
    0.30 / sqrt(20) = 14 %): the sweep stops there, runs.csv says `no: 20 rounds` for it and `yes`
    for the quiet serial point."""
    out = tmp_path / "sweep"
    launcher = SyntheticLauncher({"1-1-1-1-1": (1e-3, 0.005), "1-1-1-1-2": (0.6e-3, 0.30)})
    code, rows = _sweep(out, launcher, ["1-1-1-1-1", "1-1-1-1-2"], 0.05)
    assert code == 0
    assert rows["1-1-1-1-2"]["repeats"] == str(prec.ROUNDS_CAP)
    assert rows["1-1-1-1-2"]["resolved"] == prec.STOPPED_CAP
    assert rows["1-1-1-1-1"]["resolved"] == "yes"


def test_the_budget_stops_the_rounds(tmp_path):
    """Runs of 0.15 s, two points a round (0.3 s), a budget of 1.2 s: the next round starts only when it
    ends within the budget, so at most 4 rounds run, and the noisy point is `no: budget spent`."""
    out = tmp_path / "sweep"
    launcher = SyntheticLauncher({"1-1-1-1-1": (1e-3, 0.005), "1-1-1-1-2": (0.6e-3, 0.30)}, sleep_s=0.15)
    t0 = time.perf_counter()
    code, rows = _sweep(out, launcher, ["1-1-1-1-1", "1-1-1-1-2"], 0.05, budget=1.2)
    assert code == 0
    assert 2 <= int(rows["1-1-1-1-2"]["repeats"]) <= 4
    assert rows["1-1-1-1-2"]["resolved"] == prec.STOPPED_BUDGET
    assert len(launcher.ran) == 2 * int(rows["1-1-1-1-2"]["repeats"])
    assert time.perf_counter() - t0 > 0.6  # it did run the rounds it reports


def test_an_interrupted_precision_sweep_resumes_to_the_same_records(tmp_path):
    """Interrupted in its fourth round (an added one) and resumed with --resume, the sweep ends with
    the same rounds and the same repeat means as one that ran through (the synthetic runs are seeded by
    point and repeat), and reruns only the repeat that was interrupted."""
    scatter = {"1-1-1-1-1": (1e-3, 0.01), "1-1-1-1-2": (0.6e-3, 0.06)}
    whole = SyntheticLauncher(scatter)
    _, ref = _sweep(tmp_path / "whole", whole, ["1-1-1-1-1", "1-1-1-1-2"], 0.05)
    assert int(ref["1-1-1-1-2"]["repeats"]) >= 5, "the scatter should need more than four rounds"
    out = tmp_path / "cut"
    first = SyntheticLauncher(scatter, interrupt_at=("1-1-1-1-2", 3))
    code, _ = _sweep(out, first, ["1-1-1-1-1", "1-1-1-1-2"], 0.05)
    assert code != 0
    second = SyntheticLauncher(scatter)
    code, rows = _sweep(out, second, ["1-1-1-1-1", "1-1-1-1-2"], 0.05, resume=True)
    assert code == 0
    assert second.ran[0] == ("1-1-1-1-2", 3)
    for m in scatter:
        assert rows[m]["repeats"] == ref[m]["repeats"]
        assert rows[m]["totalT_reps"] == ref[m]["totalT_reps"]
        assert rows[m]["resolved"] == "yes"


def test_foreign_load_for_part_of_a_real_sweep(tmp_path):
    """A real `bench sweep --precision 0.05 --budget 40` while the test keeps one CPU busy during its
    first round (a spinning process, stopped when the second round starts; 2000 steps a run, so that the
    timed steps last long enough for the foreign CPU to be told from the measurement's resolution): the
    repeats it overlapped
    carry the `load` flag (bench.run.load sees the foreign CPU), the sweep ends (exit 0) saying either
    that every point is resolved or which are not, runs.csv `resolved` is set for every point, and the
    ranking leaves out each loaded point with that reason (summary.json and the printed lines)."""
    import subprocess
    import sys
    from tests.helpers import ROOT
    out = tmp_path / "sw"
    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        cmd = [sys.executable, "-m", "bench", "sweep", "--scene", "pluviation", "--particles", "200", "--steps",
               "2000", "--mappings", "1-1-1-1-1,1-1-1-1-2", "--precision", "0.05", "--budget", "40", "--out", str(out)]
        sweep = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        serial_rep1 = None
        while sweep.poll() is None and spin.poll() is None:
            found = [d for d in out.glob("*/rep1")] if out.exists() else []
            if found:  # the second round has started: the load stops
                serial_rep1 = found[0]
                spin.kill()
                break
            time.sleep(0.2)
        stdout, stderr = sweep.communicate(timeout=600)
    finally:
        spin.kill()
        spin.wait()
    assert sweep.returncode == 0, stderr + stdout
    assert serial_rep1 is not None, "the sweep never reached its second round"
    rows = read_runs_rows(os.path.join(out, "runs.csv"))[1]
    loaded = [r for r in rows if "load" in r["flag"].split(",")]
    assert loaded, "no point saw the foreign load: " + str([(r["mapping"], r["foreign_cores"]) for r in rows])
    assert all(r["resolved"] in ("yes", prec.STOPPED_BUDGET, prec.STOPPED_CAP) for r in rows)
    assert "precision +-5 %: " in stdout
    ranking = json.load(open(out / "summary.json"))["ranking"]
    excluded = {(x["point"], x["reason"]) for e in ranking for x in e["excluded"]}
    for r in loaded:
        name = r["mapping"] + (f" {r['scheme']}" if r["scheme"] else "")
        assert (name, "measured beside foreign load") in excluded
        assert f"{name} left out: measured beside foreign load" in stdout
