"""`bench` command line: contracts (files, columns) and error paths (one line, exit 2)."""
import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from tests.helpers import GOOD, ROOT, bench, one_line_error, write


def test_cli_imports_leave_numba_unstarted():
    """numba reads NUMBA_NUM_THREADS when it starts; `bench` sets it from the mapping
    (bench.run.threads_env) after loading the CLI and the modules its error handling needs, so
    none of them may start numba (a record module that did made a 2-thread run launch 2 threads
    and then fail at its next compile: 'Cannot set NUMBA_NUM_THREADS ... trying to set 3')."""
    code = ("import sys; import bench.cli, bench.run.records, bench.run.lifeline, bench.run.threads_env; "
            "print('numba' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "False", res.stderr


def test_run_draws_run_png_only_when_asked(tmp_path):
    """`bench run --plot` draws run.png (a PNG: time per step, contacts, kinetic energy); without
    it there is none, and a rank's modules leave matplotlib unloaded (it cost every rank 0.4 s of
    start-up: bench.run.driver imports the figure module where it draws)."""
    scene = write(tmp_path, GOOD)
    for plot in (True, False):
        out = tmp_path / f"run{plot}"
        res = bench("run", "--scene", scene, "--steps", "5", "--out", str(out), "--quiet",
                    *(["--plot"] if plot else []))
        assert res.returncode == 0, res.stderr
        assert (out / "run.png").exists() == plot
    assert (tmp_path / "runTrue" / "run.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code = "import sys; import bench.run.rank; print('matplotlib' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "False", res.stderr


def test_balance_choices_are_the_modes():
    """The CLI names the ways to fit the block grid without importing modes (numba must not start
    there): they are modes.mpi.BALANCE, in the same order."""
    from bench.run.options import BALANCE
    from modes.mpi import BALANCE as MODES_BALANCE
    assert BALANCE == MODES_BALANCE == ("extent", "count", "time")


def test_run_writes_contract_files(tmp_path):
    """run.json (dt, dt_critical, stable, max_overlap_ratio), steps.csv (DESIGN.md columns, one row
    per step and rank), state.npz (id, pos [n,3], quat [n,4], vel, omega sorted by id)."""
    scene = write(tmp_path, GOOD)
    out = tmp_path / "run"
    res = bench("run", "--scene", scene, "--steps", "15", "--out", str(out), "--snapshot-every", "5",
                "--snapshot-format", "vtk")
    assert res.returncode == 0, res.stderr
    info = json.loads((out / "run.json").read_text())
    for key in ("dt", "dt_critical", "stable", "max_overlap_ratio"):
        assert key in info
    assert info["stable"] is True and info["dt"] <= info["dt_critical"]
    steps = pd.read_csv(out / "steps.csv")
    for col in ("step", "rank", "totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT",
                "n_owned", "n_ghost", "n_contacts", "n_migrated", "bytes_sent"):
        assert col in steps.columns
    assert list(steps["step"]) == list(range(1, 16))
    st = np.load(out / "state.npz")
    assert st["pos"].shape == (2, 3) and st["quat"].shape == (2, 4)
    assert st["vel"].shape == (2, 3) and st["omega"].shape == (2, 3)
    assert list(st["id"]) == [0, 1]
    snaps = sorted(os.listdir(out / "snapshots"))
    assert snaps == ["step00000005.npz", "step00000005.vtk", "step00000010.npz", "step00000010.vtk",
                     "step00000015.npz", "step00000015.vtk"]
    vtk = (out / "snapshots" / "step00000005.vtk").read_text()
    assert "POINTS 2 double" in vtk and "SCALARS quat double 4" in vtk and "VECTORS axes double" in vtk


def test_contacts_json(tmp_path):
    """`bench contacts`: i < j file-order ids, unit normal from i to j, positive depth.
    Two spheres r = 1 mm, centres 1.9 mm apart on x: depth 0.1 mm, normal +x."""
    text = GOOD.split("[[particles]]")[0] + """
[[particles]]
shape = "sphere"
axes = [1e-3]
pos = [0.01, 0.01, 0.01]
[[particles]]
shape = "sphere"
axes = [1e-3]
pos = [0.0119, 0.01, 0.01]
[[particles]]
shape = "sphere"
axes = [1e-3]
pos = [0.005, 0.005, 0.03]
"""
    res = bench("contacts", write(tmp_path, text))
    assert res.returncode == 0, res.stderr
    rows = json.loads(res.stdout)
    assert len(rows) == 1
    c = rows[0]
    assert (c["i"], c["j"]) == (0, 1)
    assert c["depth"] == pytest.approx(1e-4, rel=1e-9)
    assert c["normal"] == pytest.approx([1.0, 0.0, 0.0])
    assert c["point"] == pytest.approx([0.01095, 0.01, 0.01])


def test_scenes_lists_builtins():
    res = bench("scenes")
    assert res.returncode == 0
    for name in ("patch162", "pluviation", "packed"):
        assert name in res.stdout


BAD_SCENES = [
    ("[domain\nbox=1", "malformed TOML"),
    (GOOD.replace('shape = "sphere"', 'shape = "cube"'), "unknown shape 'cube'"),
    (GOOD.replace('pos = [0.01179, 0.01, 0.0011]', 'pos = [0.01179, 0.01, 0.0011]\nmaterial = "steel"'),
     "unknown material 'steel'"),
    (GOOD.replace("axes = [8e-4]", "axes = [-8e-4]"), "axes must be positive"),
    (GOOD.replace("axes = [1e-3, 8e-4, 6e-4]", "axes = [1e-3, 0.0, 6e-4]"), "axes must be positive"),
    (GOOD.replace("axes = [8e-4]", "axes = [8e-4, 1e-4]"), "sphere axes must be [r]"),
    (GOOD.replace("axes = [1e-3, 8e-4, 6e-4]", "axes = [1e-3, 8e-4]"), "ellipsoid axes must be [a, b, c]"),
    (GOOD.replace("density = 2650.0", "density = -1.0"), "density must be positive"),
    (GOOD.replace("pos = [0.01, 0.01, 0.0011]", "pos = [0.05, 0.01, 0.0011]"), "outside the box"),
    (GOOD.replace("pos = [0.01, 0.01, 0.0011]", "pos = [0.01, 0.01, 0.0005]"), "overlaps a wall"),
    (GOOD.replace('walls = ["x-"', 'walls = ["w-"'), "unknown wall 'w-'"),
    (GOOD.replace("friction = 0.5", "friction = 0.5\ncolour = 1"), "unknown key 'colour'"),
    (GOOD.replace("steps = 20", "steps = -3"), "time.steps"),
]


@pytest.mark.parametrize("text,words", BAD_SCENES, ids=[w for _, w in BAD_SCENES])
def test_bad_scene_one_line_exit_2(tmp_path, text, words):
    """Bad scenes: one line naming the problem, exit 2, no traceback (issue 2, item 11)."""
    one_line_error(bench("run", "--scene", write(tmp_path, text), "--out", str(tmp_path / "o")), words)


@pytest.mark.parametrize("args,words", [
    (["run", "--scene", "nosuch"], "unknown scene 'nosuch'"),
    (["run", "--scene", "patch162", "--frobnicate"], "unrecognized arguments: --frobnicate"),
    (["run", "--scene", "patch162", "--mapping", "9-3-3-2-4"], "px*py*pz"),
    (["run", "--scene", "patch162", "--mapping", "two"], "malformed mapping"),
    # a packed build of 1 particle pressed it into the walls, then told the user to move it (issue 34)
    (["run", "--scene", "packed", "--particles", "1"], "a compress build needs at least 4 particles, got 1"),
    # a full-width digit (U+FF12) is a digit to Python's \d and int(), not to a mapping (issue 34)
    (["run", "--scene", "patch162", "--mapping", "\uff12-2-1-1-1"], "malformed mapping"),
    (["sweep", "--scene", "patch162", "--mappings", "\uff12-2-1-1-1", "--out", "x"], "malformed mapping"),
    (["run", "--scene", "patch162", "--mapping", "1-1-1-1-0"], "T must be >= 1"),
    (["run", "--scene", "patch162", "--mapping", "18-18-1-1-1"], "use fewer blocks along x"),
    (["run", "--scene", "patch162", "--steps", "x"], "--steps"),
    (["run", "--scene", "patch162", "--neighbor", "octree"], "--neighbor"),
    (["run", "--scene", "patch162", "--shape", "cube"], "--shape"),
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--balance", "load"], "--balance"),
    (["run", "--scene", "patch162", "--dt", "1.0", "--steps", "1"], "exceeds the critical step"),
    (["bogus"], "invalid choice"),
    # --hosts (issue 37): names, a readable file, no more hosts than ranks, not with a starter or Slurm
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--hosts", "a,,b"], "not a list of host names"),
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--hosts", "a,a"], "names a host twice"),
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--hosts", "@/nonexistent/hosts"],
     "cannot read the host file"),
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--hosts", "a,b,c"], "has only 2 ranks"),
    (["run", "--scene", "patch162", "--mapping", "2-2-1-1-1", "--hosts", "a", "--mpi-starter", "srun"],
     "cannot be given together"),
    (["sweep", "--scene", "patch162", "--mappings", "2-2-1-1-1", "--hosts", "a,b,c", "--out", "x"],
     "has only 2 ranks"),
    (["sweep", "--scene", "patch162", "--mappings", "2-2-1-1-1", "--hosts", "a,b", "--launcher", "slurm",
      "--out", "x"], "--nodes K"),
])
def test_bad_options_one_line_exit_2(tmp_path, args, words):
    """Bad options, mappings and time steps: one clear line, exit 2 (items 6, 10, 11)."""
    one_line_error(bench(*args, "--out", str(tmp_path / "o")) if args[0] == "run" else bench(*args), words)


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line_error(bench("run", "--scene", write(tmp_path, GOOD), "--out", str(blocker / "sub")), "not writable")


def test_every_option_has_help():
    """`bench CMD --help` describes every option of every command (issue 34: `bench sweep --help` had
    none for --scene, --particles, --shape, --steps, --neighbor, --halo, --pin)."""
    from bench.cli import build_parser
    missing = []
    for name, sub in build_parser()._subparsers._group_actions[0].choices.items():
        for action in sub._actions:
            if action.option_strings and not action.help and "--help" not in action.option_strings:
                missing.append(f"{name} {action.option_strings[0]}")
    assert missing == []
    res = bench("sweep", "--help")
    assert res.returncode == 0 and "--pin" in res.stdout and "binding" in res.stdout
