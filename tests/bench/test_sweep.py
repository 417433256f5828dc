"""`bench sweep` end to end (local launcher): records, metrics, resume, failures, collect, bad input.
The Slurm launcher: test_slurm_scripts.py (its scripts) and test_slurm_cluster.py (a real Slurm)."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from tests.helpers import ROOT, bench, one_line_error, processes_naming

SMALL = ["--scene", "pluviation", "--particles", "200", "--steps", "15"]


def sweep(tmp_path, *args, name="sw"):
    out = tmp_path / name
    res = bench("sweep", *SMALL, "--out", str(out), *args, timeout=900)
    return res, out


def test_sweep_records_metrics_figures(tmp_path):
    """Serial, threads and MPI points: runs.csv (one row each, the contract's columns), speedup 1
    for the serial reference and S = T1/T elsewhere, err_max 0 for every bit-identical mode,
    manifest.json with versions and load averages, figures, and bench.load."""
    res, out = sweep(tmp_path, "--mappings", "1-1-1-1-2,2-2-1-1-1", "--schemes", "frogleap")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "point 3/3" in res.stdout and "estimate" in res.stdout
    # the warm start (bench.sweep.warm): the scene built with the one-thread kernels, and the
    # 2-thread frogleap kernels compiled at the same time, before the first point
    assert "scene and kernels ready in" in res.stdout.split("point 1/3")[0]
    build = json.loads((out / "warm" / "build" / "prepare.json").read_text())
    assert [b["scene"] for b in build["builds"]] == ["pluviation"]
    threads = json.loads((out / "warm" / "2" / "prepare.json").read_text())
    assert [(c["threads"], c["scheme"]) for c in threads["compiled"]] == [(2, "frogleap")]
    assert json.loads((out / "warm" / "2" / "status.json").read_text())["status"] == "done"
    runs = pd.read_csv(out / "runs.csv")
    assert runs["mapping"].tolist() == ["1-1-1-1-1", "1-1-1-1-2", "2-2-1-1-1"]
    for col in ("mapping", "procs", "px", "py", "pz", "threads", "scheme", "neighbor", "scene", "particles",
                "steps", "totalT", "commuT", "migraT", "compuT", "overhead_pct", "speedup", "efficiency",
                "edsf", "rss_mb", "err_max", "err_rms", "stable", "wall_s"):
        assert col in runs.columns, col
    assert (runs["status"] == "done").all()
    assert runs.loc[0, "speedup"] == 1.0
    t1 = runs.loc[0, "totalT"]
    assert np.allclose(runs["speedup"], t1 / runs["totalT"])
    assert np.allclose(runs["efficiency"], runs["speedup"] / runs["cores"])
    assert (runs["err_max"] == 0).all() and (runs["err_rms"] == 0).all()  # bit-identical modes
    assert (runs["binding"] == "unpinned").all()  # each run's affinity records held (bench.run.binding)
    assert np.allclose(runs["compuT"], runs["totalT"] - runs["commuT"] - runs["migraT"])
    man = json.loads((out / "manifest.json").read_text())
    for key in ("numpy", "numba", "mpi4py", "mpi_library", "cpu_count", "cpu_model", "git_commit", "load"):
        assert key in man
    assert man["numba_threading_layer"] == ["omp"] or man["numba_threading_layer"][0] in ("tbb", "workqueue")
    assert len(man["load"]) == 3
    for fig in ("speedup.png", "efficiency.png", "edsf.png", "modules.png", "error_vs_time.png"):
        assert (out / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    point = out / runs.loc[2, "point"] / "rep0"
    for f in ("cmd.txt", "stdout.txt", "stderr.txt", "run.json", "steps.csv", "state.npz"):
        assert (point / f).exists(), f
    sys.path.insert(0, ROOT)
    import bench as api
    r, s = api.load(str(out))
    assert len(r) == 3 and set(s["point"]) == set(r["point"]) and len(s) == 15 * (1 + 1 + 2)


def test_warm_start_parts(tmp_path):
    """The warm start's parts: the build (with the one-thread kernels), then each thread count above
    one once, ascending; nothing to overlap (only one-thread points, or one core) runs nothing."""
    from types import SimpleNamespace
    from bench.sweep.warm import parts_of, warm_start
    pts = [SimpleNamespace(mapping=m) for m in ("1-1-1-1-1", "2-2-1-1-4", "1-1-1-1-2", "4-2-2-1-1", "1-1-1-1-4")]
    assert parts_of(pts) == ("build", 2, 4)
    assert parts_of(pts[:1] + pts[3:4]) == ()
    assert warm_start(str(tmp_path), pts, 1, dict(os.environ)) == {}
    assert warm_start(str(tmp_path), pts[:1], 2, dict(os.environ)) == {} and not (tmp_path / "warm").exists()


def test_interrupted_warm_start_leaves_nothing_running(tmp_path):
    """SIGTERM while the warm start compiles (numba's cache empty: NUMBA_CACHE_DIR of the test, so
    compiling lasts tens of seconds): the sweep ends with one line, no part outlives it, and each
    part's status says interrupted."""
    out = tmp_path / "int"
    env = dict(os.environ, PYTHONPATH=ROOT, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    proc = subprocess.Popen([sys.executable, "-m", "bench", "sweep", *SMALL, "--mappings", "1-1-1-1-2", "--out",
                             str(out)], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stdout:
        if "compiling the kernels" in line:
            break
    time.sleep(1.0)
    assert len(processes_naming(f"bench.sweep.job warm {out}")) == 2  # the build and the 2-thread part, compiling
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0 and err.strip().splitlines() == [
        "bench: error: interrupted by SIGTERM; the records written so far are kept"]
    time.sleep(0.5)
    assert processes_naming(f"bench.sweep.job warm {out}") == []  # none left
    for part in ("build", "2"):
        assert json.loads((out / "warm" / part / "status.json").read_text())["status"] == "interrupted"


def test_resume_after_killed_sweep(tmp_path):
    """Kill a sweep after its first point; runs.csv stays consistent; --resume runs only the rest
    and the result has every point exactly once."""
    out = tmp_path / "killed"
    args = [sys.executable, "-m", "bench", "sweep", *SMALL, "--steps", "400", "--mappings",
            "1-1-1-1-2,2-2-1-1-1", "--out", str(out)]
    proc = subprocess.Popen(args, cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline:
        if (out / "runs.csv").exists() and len(pd.read_csv(out / "runs.csv")) >= 1:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    partial = pd.read_csv(out / "runs.csv")
    assert 1 <= len(partial) < 3 and (partial["status"] == "done").all()
    first = out / partial.loc[0, "point"] / "rep0" / "cmd.txt"
    stamp = first.stat().st_mtime_ns
    res = bench("sweep", *SMALL, "--steps", "400", "--mappings", "1-1-1-1-2,2-2-1-1-1", "--out", str(out),
                "--resume", timeout=900)
    assert res.returncode == 0, res.stderr
    runs = pd.read_csv(out / "runs.csv")
    assert sorted(runs["mapping"]) == ["1-1-1-1-1", "1-1-1-1-2", "2-2-1-1-1"]
    assert runs["point"].is_unique and (runs["status"] == "done").all()
    assert first.stat().st_mtime_ns == stamp  # the finished point was not run again


def test_failed_point_is_recorded_and_sweep_goes_on(tmp_path):
    """A point that cannot run (blocks narrower than a particle) is recorded as failed with its
    reason; the later points still run; the exit status says some point failed."""
    res, out = sweep(tmp_path, "--mappings", "16-16-1-1-1,2-2-1-1-1")
    assert res.returncode == 4
    runs = pd.read_csv(out / "runs.csv").set_index("mapping")
    assert runs.loc["16-16-1-1-1", "status"] == "failed"
    assert "use fewer blocks along x" in runs.loc["16-16-1-1-1", "reason"]
    assert runs.loc["2-2-1-1-1", "status"] == "done"


def test_timeout_is_recorded(tmp_path):
    res, out = sweep(tmp_path, "--mappings", "1-1-1-1-1", "--steps", "10000000", "--timeout", "3")
    runs = pd.read_csv(out / "runs.csv")
    assert runs.loc[0, "status"] == "timeout"


def test_local_dry_run(tmp_path):
    """--dry-run prints each point's command with its thread variables and runs nothing (the
    Slurm launcher's scripts: tests/bench/test_slurm_scripts.py)."""
    res = bench("sweep", *SMALL, "--mappings", "2-2-1-1-1", "--dry-run", "--out", str(tmp_path / "dry"))
    assert res.returncode == 0 and "NUMBA_NUM_THREADS=1" in res.stdout and "--mapping 2-2-1-1-1" in res.stdout
    assert not any((tmp_path / "dry").rglob("run.json"))


def dry_run_commands(out, *args):
    """The point commands a `bench sweep --dry-run` of the small scene prints (it must succeed)."""
    res = bench("sweep", *SMALL, *args, "--dry-run", "--out", str(out))
    assert res.returncode == 0, res.stderr
    return [line for line in res.stdout.splitlines() if "--mapping " in line]


def test_update_grid_passes_to_the_mpi_points(tmp_path):
    """--update-grid K reaches the MPI points' commands (and a sweep file's update_grid = K), not
    the serial or thread points, which have no blocks; without it a point keeps the key (folder
    name) it had before the option existed, so --resume still finds sweeps made then."""
    from bench.sweep.points import make_points
    from bench.sweep.records import reference_key
    lines = dry_run_commands(tmp_path / "dry", "--mappings", "1-1-1-1-2,2-1-1-2-1", "--update-grid", "25")
    assert len(lines) == 3
    assert ["--update-grid 25" in line for line in lines] == ["--mapping 2-1-1-2-1" in line for line in lines]
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nupdate_grid = 7\n')
    res = bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry2"))
    assert res.returncode == 0 and "--update-grid 7" in res.stdout, res.stderr
    one_line_error(bench("sweep", *SMALL, "--mappings", "2-2-1-1-1", "--update-grid", "-1", "--out",
                         str(tmp_path / "bad")), "--update-grid")
    args = (["2-2-1-1-1"], ["dynamic"], "pluviation", 200, 15, 0, "linkcell", None, False, "26")
    # the key of this point before update_grid existed: sha1 of its fields without it
    assert make_points(*args)[1].key == "2-2-1-1-1-822c84b2"
    assert make_points(*args, "exact", 25)[1].key != make_points(*args)[1].key
    # --balance rides with --update-grid to the MPI points; the paper's extent keeps the keys
    lines = dry_run_commands(tmp_path / "dry3", "--mappings", "1-1-1-1-2,2-1-1-2-1", "--update-grid", "25",
                             "--balance", "time")
    assert len(lines) == 3
    assert ["--balance time" in line for line in lines] == ["--mapping 2-1-1-2-1" in line for line in lines]
    assert make_points(*args, "exact", 25, "extent")[1].key == make_points(*args, "exact", 25)[1].key
    assert make_points(*args, "exact", 25, "count")[1].key != make_points(*args, "exact", 25)[1].key
    assert make_points(*args, "exact", 0, "time")[1].balance == "extent"  # nothing to fit without update_grid
    # an MPI point with a fitted grid measures its speedup and error against the sweep's serial point
    serial, mpi = make_points(*args, "exact", 25, "time")
    assert reference_key(mpi) == serial.key == make_points(*args)[0].key
    sweep_file.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nupdate_grid = 7\n'
                          'balance = "count"\n')
    res = bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry4"))
    assert res.returncode == 0 and "--update-grid 7 --balance count" in res.stdout, res.stderr
    sweep_file.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nbalance = "load"\n')
    one_line_error(bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry5")), "balance")


def test_newton_passes_to_the_mpi_points(tmp_path):
    """--newton on|off reaches the points with more than one process (and a sweep file's newton),
    hybrid ones too, except under the schemes that store every pair's forces (frogleap, headtail:
    they resolve a pair across a border on both ranks) and get nothing, as the serial and thread
    points; auto keeps a point's key (folder name) as it was before the option, and an MPI point's
    reference is the sweep's serial point."""
    from bench.sweep.points import make_points
    from bench.sweep.records import reference_key
    lines = dry_run_commands(tmp_path / "dry", "--mappings", "1-1-1-1-2,2-1-1-2-1,2-2-1-1-2", "--schemes",
                             "dynamic,frogleap", "--newton", "off")
    assert len(lines) == 6
    assert ["--newton off" in line for line in lines] == [
        "--mapping 2-1-1-2-1" in line or ("--mapping 2-2-1-1-2" in line and "--scheme dynamic" in line)
        for line in lines]
    args = (["2-2-1-1-1", "2-2-1-1-2"], ["dynamic", "headtail"], "pluviation", 200, 15, 0, "linkcell", None, False,
            "26")
    assert make_points(*args)[1].key == "2-2-1-1-1-822c84b2"   # the key before newton existed (above)
    assert make_points(*args, "exact", 0, "extent", "auto")[1].key == "2-2-1-1-1-822c84b2"
    serial, mpi, hybrid, storing = make_points(*args, "exact", 0, "extent", "on")
    assert mpi.newton == "on" and mpi.key != "2-2-1-1-1-822c84b2"
    assert (hybrid.scheme, hybrid.newton, storing.scheme, storing.newton) == ("dynamic", "on", "headtail", "auto")
    assert reference_key(mpi) == serial.key
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nnewton = "on"\n')
    res = bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry2"))
    assert res.returncode == 0 and "--newton on" in res.stdout, res.stderr
    sweep_file.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nnewton = "yes"\n')
    one_line_error(bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry3")), "newton")


def test_forward_passes_to_the_mpi_points(tmp_path):
    """--forward shared|auto reaches the points with more than one process (hybrid ones too), not
    the serial and thread points; messages (the default) keeps a point's key (folder name) as it was
    before the option."""
    from bench.sweep.points import make_points
    lines = dry_run_commands(tmp_path / "dry", "--mappings", "1-1-1-1-2,2-2-1-1-1,2-2-1-1-2", "--forward", "shared")
    assert len(lines) == 4
    assert ["--forward shared" in line for line in lines] == ["--mapping 2-2-1-1" in line for line in lines]
    args = (["2-2-1-1-1"], ["dynamic"], "pluviation", 200, 15, 0, "linkcell", None, False, "26")
    assert make_points(*args, forward="messages")[1].key == "2-2-1-1-1-822c84b2"
    assert make_points(*args, forward="shared")[1].key != "2-2-1-1-1-822c84b2"


def test_collect_rebuilds_runs_csv(tmp_path):
    """bench collect gathers the point folders (as Slurm jobs leave them) into the same rows, with
    the speedups of a local sweep: S = T(1)/T(p), so 1.0 exactly for the serial row, and efficiency
    S/p for the 2 ranks."""
    res, out = sweep(tmp_path, "--mappings", "2-2-1-1-1")
    assert res.returncode == 0, res.stderr
    before = pd.read_csv(out / "runs.csv")
    os.remove(out / "runs.csv")
    for st in out.rglob("status.json"):
        os.remove(st)  # batch jobs write no status.json: collect judges by run.json
    res = bench("collect", str(out))
    assert res.returncode == 0, res.stderr
    after = pd.read_csv(out / "runs.csv")
    assert after["status"].tolist() == ["done", "done"]
    assert np.allclose(after["totalT"], before["totalT"]) and (after["err_max"] == 0).all()
    assert after.loc[0, "mapping"] == "1-1-1-1-1" and after.loc[0, "speedup"] == 1.0
    assert after.loc[1, "speedup"] == pytest.approx(after.loc[0, "totalT"] / after.loc[1, "totalT"], rel=1e-12)
    assert after.loc[1, "efficiency"] == pytest.approx(after.loc[1, "speedup"] / 2, rel=1e-12)


def test_sweep_file(tmp_path):
    f = tmp_path / "sweep.toml"
    f.write_text('[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nparticles = 200\nsteps = 10\n'
                 f'out = "{tmp_path / "fromfile"}"\n')
    res = bench("sweep", "--file", str(f))
    assert res.returncode == 0, res.stderr
    assert len(pd.read_csv(tmp_path / "fromfile" / "runs.csv")) == 2


@pytest.mark.parametrize("mappings,words", [("1-1-1-1-1,9-3-3-2-4", "px*py*pz"), ("1-1-1-1-0", "T must be >= 1"),
                                            ("two", "malformed mapping 'two'")])
def test_bad_mapping_one_line_nothing_lost(tmp_path, mappings, words):
    """A malformed mapping: one line, exit 2, and an existing runs.csv is left as it was."""
    out = tmp_path / "keep"
    out.mkdir()
    (out / "runs.csv").write_text("precious\n")
    one_line_error(bench("sweep", *SMALL, "--mappings", mappings, "--out", str(out)), words)
    assert (out / "runs.csv").read_text() == "precious\n"


@pytest.mark.parametrize("args,words", [
    (["--scene", "nosuch", "--mappings", "1-1-1-1-1"], "unknown scene 'nosuch'"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-2", "--schemes", "roundrobin"], "unknown scheme"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--repeats", "0"], "--repeats"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--precision", "1.5"], "--precision"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--budget", "60"], "give --precision too"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--precision", "0.05", "--launcher", "slurm"],
     "needs the local launcher"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--compare", "nowhere"], "no runs.csv there"),
    (["--scene", "pluviation", "--mappings", "1-1-1-1-1", "--particles", "200,400", "--ceiling"],
     "one --particles count"),
])
def test_bad_sweep_options(tmp_path, args, words):
    one_line_error(bench("sweep", *args, "--out", str(tmp_path / "o")), words)


def test_unwritable_sweep_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line_error(bench("sweep", *SMALL, "--mappings", "1-1-1-1-1", "--out", str(blocker / "sub")), "not writable")


def test_skin_reaches_every_point(tmp_path):
    """`bench sweep --skin 0` (the paper's every-step neighbour estimate under every mapping, the
    serial reference included, so that speedups compare like with like): each point's command
    carries it (dry run), from the command line or a sweep file; a skin outside [0, 10] is one
    line, exit 2, and the default keeps the points' keys (no --skin in their commands)."""
    res = bench("sweep", *SMALL, "--mappings", "1-1-1-1-2,2-2-1-1-1", "--skin", "0", "--dry-run",
                "--out", str(tmp_path / "dry"))
    assert res.returncode == 0, res.stderr
    runs = [line for line in res.stdout.splitlines() if "--mapping" in line]
    assert len(runs) == 3 and all("--skin 0.0" in line for line in runs), res.stdout
    default = bench("sweep", *SMALL, "--mappings", "1-1-1-1-2", "--dry-run", "--out", str(tmp_path / "dry2"))
    assert default.returncode == 0 and "--skin" not in default.stdout
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text('[sweep]\nmappings = ["1-1-1-1-2"]\nscene = "packed"\nparticles = 200\nsteps = 2\n'
                          'skin = 0.05\n')
    res = bench("sweep", "--file", str(sweep_file), "--dry-run", "--out", str(tmp_path / "dry3"))
    assert res.returncode == 0 and res.stdout.count("--skin 0.05") == 2, res.stdout
    # the command line wins over the file, --skin 0 included (0.0 is not "unset")
    res = bench("sweep", "--file", str(sweep_file), "--skin", "0", "--dry-run", "--out", str(tmp_path / "dry4"))
    assert res.returncode == 0 and res.stdout.count("--skin 0.0") == 2 and "0.05" not in res.stdout, res.stdout
    one_line_error(bench("sweep", *SMALL, "--mappings", "1-1-1-1-2", "--skin", "11", "--out",
                         str(tmp_path / "bad")), "--skin")
    sweep_file.write_text('[sweep]\nmappings = "1-1-1-1-2"\nskin = true\n')
    one_line_error(bench("sweep", "--file", str(sweep_file), "--out", str(tmp_path / "bad2")), "skin")


def test_contact_method_reaches_every_point(tmp_path):
    """`bench sweep --contact-method sextic` (the paper's method under every mapping): each point's
    command carries it (dry run), and a bad name is one line, exit 2."""
    res = bench("sweep", *SMALL, "--mappings", "1-1-1-1-2,2-2-1-1-1", "--contact-method", "sextic", "--dry-run",
                "--out", str(tmp_path / "dry"))
    assert res.returncode == 0, res.stderr
    runs = [line for line in res.stdout.splitlines() if "--mapping" in line]
    assert len(runs) == 3 and all("--contact-method sextic" in line for line in runs), res.stdout
    one_line_error(bench("sweep", *SMALL, "--mappings", "1-1-1-1-2", "--contact-method", "cubic", "--out",
                         str(tmp_path / "bad")), "contact-method")


def test_runs_csv_keeps_whole_numbers_whole(tmp_path):
    """A row carried from an earlier runs.csv (its fields read back as text) beside a failed point
    (no particle count: NaN) once turned procs 1 into 1.0 and particles 300 into 300.0 (issue 34);
    counts are written as integers, and an unknown count stays empty."""
    from bench.sweep.records import RUN_COLUMNS, write_runs
    carried = {c: "" for c in RUN_COLUMNS}
    carried.update(point="1-1-1-1-1-aaaa", mapping="1-1-1-1-1", procs="1", px="1", py="1", pz="1", threads="1",
                   cores="1", particles="300", steps="15", repeats="1", status="done", totalT="0.001")
    failed = {c: float("nan") for c in RUN_COLUMNS}
    failed.update(point="2-2-1-1-1-bbbb", mapping="2-2-1-1-1", procs=2, px=2, py=1, pz=1, threads=1, cores=2,
                  repeats=1, status="failed", reason="bench: error: x")
    write_runs(tmp_path / "runs.csv", [carried, failed])
    import csv
    rows = list(csv.DictReader(open(tmp_path / "runs.csv")))
    assert [(r["procs"], r["particles"], r["steps"], r["cores"]) for r in rows] == [("1", "300", "15", "1"),
                                                                                  ("2", "", "", "2")]
    assert rows[0]["totalT"] == "0.001"


def test_status_of_an_interrupted_local_sweep(tmp_path):
    """A local sweep stopped during its first repeat: the repeat that started reads failed (no
    result), those whose folders were never made read not_started, not failed (issue 34 saw
    "1 done, 5 failed" where one repeat had started)."""
    from bench.sweep.status import point_outcome, sweep_outcomes
    out = tmp_path / "i"
    points = [{"key": "1-1-1-1-1-aaaa", "mapping": "1-1-1-1-1"}, {"key": "2-2-1-1-1-bbbb", "mapping": "2-2-1-1-1"}]
    out.mkdir()
    (out / "manifest.json").write_text(json.dumps({"launcher": "local", "repeats": 3, "points": points}))
    done = out / "1-1-1-1-1-aaaa" / "rep0"
    done.mkdir(parents=True)
    (done / "status.json").write_text(json.dumps({"status": "done", "reason": ""}))
    started = out / "2-2-1-1-1-bbbb" / "rep0"
    started.mkdir(parents=True)
    (started / "cmd.txt").write_text("bench run ...")
    _, rows = sweep_outcomes(str(out))
    states = {(p["key"], o["rep"]): o["status"] for p, outs in rows for o in outs}
    assert states == {("1-1-1-1-1-aaaa", "rep0"): "done", ("1-1-1-1-1-aaaa", "rep1"): "not_started",
                      ("1-1-1-1-1-aaaa", "rep2"): "not_started", ("2-2-1-1-1-bbbb", "rep0"): "failed",
                      ("2-2-1-1-1-bbbb", "rep1"): "not_started", ("2-2-1-1-1-bbbb", "rep2"): "not_started"}
    assert point_outcome(rows[0][1])["status"] == "not_started"
    res = bench("sweep", "--status", str(out))
    assert "not_started" in res.stdout, res.stdout + res.stderr
