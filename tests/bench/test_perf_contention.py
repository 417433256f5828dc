"""`bench perf --what contention`: the efficiency ceiling of workers that share nothing. Its
figures are ratios of the measured step times by their definitions (bench/studies/
perf_contention.py), and its step barrier holds every copy until all have finished the step."""
import os
import threading
import time

import pytest

from tests.helpers import bench


def test_contention_report_follows_its_definitions():
    """One repeat on a small scene, 2 copies: every configuration has one sample per repeat, the
    medians are those samples, the ceilings are alone / together (the contention) and alone / in
    step, and size = serial / (2 alone)."""
    from bench.studies.perf_contention import measure
    lines = []
    rep = measure("gas", 200, 2, 20, 1, lines.append, warmup=2)
    assert rep["share"] == 100
    med = {k: v[0] for k, v in rep["samples_s"].items()}
    assert all(v > 0 for v in med.values())
    assert rep["median_ms"]["serial"] == pytest.approx(1e3 * med["serial"])
    assert rep["ceiling_free"] == rep["contention"] == pytest.approx(med["alone"] / med["together"])
    assert rep["ceiling_step"] == pytest.approx(med["alone"] / med["in_step"])
    assert rep["size"] == pytest.approx(med["serial"] / (2 * med["alone"]))
    assert len(lines) == 6 and "ceiling of 2 workers" in lines[3]


def test_copies_step_the_requested_steps():
    """run_copies returns one list of step times per copy, `steps` long, in step or not."""
    from bench.run.copies import run_copies
    for in_step in (False, True):
        out = run_copies("gas", 100, 2, 7, warmup=1, in_step=in_step)
        assert [len(t) for t in out] == [7, 7] and min(min(t) for t in out) > 0


def test_copies_are_set_up_with_the_runs_options():
    """The copies take the serial mode's options of the runs they stand beside (a skin-0 sweep's
    copies build a list every step too): an option the mode refuses ends the round with the mode's
    own reason, so the options reach every copy's set-up; the sweep's control keeps only the options
    set (None: the mode's default)."""
    from bench.run.copies import run_copies
    from bench.sweep.ceiling import Ceiling
    with pytest.raises(RuntimeError, match="unknown contact method 'nope'"):
        run_copies("gas", 100, 2, 3, warmup=1, options={"contact_method": "nope"})
    out = run_copies("gas", 100, 2, 3, warmup=1, options={"skin": 0.0})
    assert [len(t) for t in out] == [3, 3]
    c = Ceiling("gas", 200, None, 6, 1, [2], usable=2, options={"skin": 0.0, "contact_method": None})
    assert c.options == {"skin": 0.0}


def test_step_barrier_waits_for_the_slowest_copy():
    """meet(counts, me, k) returns only once every slot holds k: copy 1 finishes step 3 0.2 s
    after copy 0 arrives, so copy 0 waits at least those 0.2 s; a later arrival does not wait."""
    from bench.run.copies import meet
    counts = [2, 2]
    late = threading.Timer(0.2, lambda: counts.__setitem__(1, 3))
    t = time.perf_counter()
    late.start()
    meet(counts, 0, 3)
    waited = time.perf_counter() - t
    late.join()
    assert counts == [3, 3] and waited >= 0.2
    t = time.perf_counter()
    meet(counts, 1, 3)
    assert time.perf_counter() - t < 0.2


def test_contention_command_bad_scene():
    res = bench("perf", "--what", "contention", "--scene", "no-such-scene", "--particles", "100")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "no-such-scene" in res.stderr


def test_sweep_ceiling_rounds_and_csv(tmp_path):
    """bench.sweep.ceiling: the core counts of a sweep's points above 1 and within the usable CPUs
    get a control (4 is left out with 2 usable); one round gives one sample of each configuration
    at N/W = 100 particles, and ceiling.csv holds their ratios, read back unchanged."""
    from bench.sweep.ceiling import Ceiling, read_ceiling
    c = Ceiling("gas", 200, None, 6, 1, [1, 2, 2, 4], usable=2)
    assert c.cores == [2] and c.left_out == [4] and c.share(2) == 100 and c.steps == 6
    c.round()
    rows = c.write(str(tmp_path))
    (r,) = rows
    assert r["rounds"] == 1 and r["share"] == 100
    assert r["ceiling_free"] == pytest.approx(r["alone_ms"] / r["together_ms"])
    assert r["ceiling_step"] == pytest.approx(r["alone_ms"] / r["in_step_ms"])
    assert read_ceiling(str(tmp_path)) == [pytest.approx({k: float(v) for k, v in r.items()})]
    assert r["pinned"] == 0 and c.cpus(2) is None


@pytest.mark.skipif(os.sched_getaffinity(0) != {0, 1}, reason="the expected CPUs are those of 2 CPUs")
def test_pinned_sweep_ceiling_pins_its_copies(tmp_path):
    """In a pinned sweep the ceiling's copies are bound as --pin binds W one-thread ranks
    (bench.run.binding plan_binding: on 2 CPUs copy 0 on {0} and copy 1 on {1}, as 2-2-1-1-1 --pin
    gives its ranks); its round runs on them and ceiling.csv says pinned = 1. A ceiling.csv written
    before the column existed reads as pinned 0."""
    from bench.run.copies import run_copies
    from bench.sweep.ceiling import CEILING_COLUMNS, Ceiling, read_ceiling
    c = Ceiling("gas", 200, None, 6, 1, [2], usable=2, pin=True)
    assert c.cpus(2) == [0, 1] and c.cpus(1) == [0]
    c.round()
    (r,) = c.write(str(tmp_path))
    assert r["pinned"] == 1 and read_ceiling(str(tmp_path))[0]["pinned"] == 1.0
    with pytest.raises(RuntimeError, match="Invalid argument"):   # a CPU that is not there: the copy says so
        run_copies("gas", 100, 1, 2, warmup=1, cpus=[4096])
    old = tmp_path / "old"
    old.mkdir()
    cols = [k for k in CEILING_COLUMNS if k != "pinned"]
    (old / "ceiling.csv").write_text(",".join(cols) + "\n" + ",".join(str(r[k]) for k in cols) + "\n")
    assert read_ceiling(str(old))[0]["pinned"] == 0.0


def test_sweep_ceiling_bad_requests(tmp_path):
    """--ceiling on a scene whose count cannot be set (explicit particles), or with the Slurm
    launcher: one line each, exit 2, no traceback, and nothing written."""
    from tests.helpers import GOOD
    scene = tmp_path / "two.toml"
    scene.write_text(GOOD)
    res = bench("sweep", "--mappings", "1-1-1-1-1,1-1-1-1-2", "--scene", str(scene), "--steps", "2", "--ceiling",
                "--out", str(tmp_path / "a"))
    assert res.returncode == 2 and "Traceback" not in res.stderr and "--ceiling" in res.stderr
    assert not (tmp_path / "a").exists()
    res = bench("sweep", "--mappings", "1-1-1-1-2", "--scene", "gas", "--particles", "100", "--steps", "2",
                "--ceiling", "--launcher", "slurm", "--out", str(tmp_path / "b"))
    assert res.returncode == 2 and "Traceback" not in res.stderr and "local launcher" in res.stderr


def test_failing_copy_ends_the_round_with_its_reason():
    """A copy that cannot run (an unknown scene) frees the others and the round ends at once with
    a RuntimeError naming the reason, instead of waiting out the barrier's timeout (1800 s)."""
    from bench.run.copies import run_copies
    t = time.perf_counter()
    with pytest.raises(RuntimeError, match="no-such-scene"):
        run_copies("no-such-scene", 100, 2, 5, in_step=True)
    assert time.perf_counter() - t < 120


def test_contention_command_writes_perf_json(tmp_path):
    """The command end to end: its report lines and DIR/perf.json with both ceilings."""
    import json
    res = bench("perf", "--what", "contention", "--scene", "gas", "--particles", "100", "--steps", "3",
                "--repeats", "1", "--out", str(tmp_path))
    assert res.returncode == 0, res.stderr
    assert "efficiency ceiling of 2 workers" in res.stdout
    rep = json.loads((tmp_path / "perf.json").read_text())
    assert rep["copies"] == 2 and rep["share"] == 50 and rep["ceiling_free"] > 0 and rep["ceiling_step"] > 0
