"""Checkpoint and restart (issue 14, item 1): `bench run --checkpoint-every K` writes the whole state
of a run atomically, and `bench run --restart FILE` continues it in any mode or mapping. N steps,
a restart and N more steps give the final state of 2N uninterrupted steps bit for bit
(np.array_equal), because the checkpoint holds everything a step carries to the next (positions,
half-step velocities, quaternions, angular momenta, the contact history of every touching pair and
every wall, the time step) and what it leaves out (the neighbour list, memory order, the block grid)
changes no result (DESIGN.md, Determinism; tests/modes/test_neighbour_list.py for the list)."""
import json
import os

import numpy as np
import pandas as pd
import pytest

from tests.helpers import GOOD, assert_same, bench, one_line_error, write

HAS_MPI = bool(os.path.exists(os.path.join(os.path.dirname(os.sys.executable), "mpiexec"))
               or __import__("shutil").which("mpiexec"))


def run(out, *args, timeout=900):
    res = bench("run", "--out", str(out), "--quiet", "--timeout", "600", *args, timeout=timeout)
    assert res.returncode == 0, res.stderr
    return (dict(np.load(out / "state.npz")), pd.read_csv(out / "steps.csv"),
            json.loads((out / "run.json").read_text()))


_FULL = {}


def uninterrupted(tmp_path_factory, scene, steps):
    """The serial run of `steps` steps without a restart (computed once per scene)."""
    if (scene, steps) not in _FULL:
        _FULL[scene, steps] = run(tmp_path_factory.mktemp("full"), "--scene", scene, "--steps", str(steps))
    return _FULL[scene, steps]


def test_serial_restart_bit_identical(tmp_path, tmp_path_factory):
    """patch162 (162 ellipsoids resting in a closed box under gravity, the paper's patch test):
    60 steps with a checkpoint, then 60 more from it, equal 120 steps exactly; the checkpoint holds
    the history that makes this non-trivial (tangential springs of the resting contacts, wall
    contacts), the steps of the second part are numbered 61..120, and the energy balance of
    run.json (initial kinetic energy, gravity work summed step by step) is the uninterrupted
    run's to the bit."""
    ref, _, ref_info = uninterrupted(tmp_path_factory, "patch162", 120)
    _, steps_a, info_a = run(tmp_path / "a", "--scene", "patch162", "--steps", "60", "--checkpoint-every", "60")
    ckpt = tmp_path / "a" / "checkpoint.npz"
    with np.load(ckpt) as z:
        meta = json.loads(str(z["meta"][()]))
        assert meta["step"] == 60 and meta["time"] == 60 * info_a["dt"]
        assert np.count_nonzero(np.abs(z["pair_hist"][:, :3]).max(axis=1)) > 20   # tangential springs
        assert np.count_nonzero(z["wall_hist"][:, :, 3] > 0) > 20               # wall contacts (radius > 0)
    assert info_a["checkpoint"]["last_step"] == 60
    got, steps_b, info_b = run(tmp_path / "b", "--restart", str(ckpt), "--steps", "60")
    assert_same(ref, got)
    assert list(steps_b["step"]) == list(range(61, 121))
    assert info_b["restart"]["step"] == 60 and info_b["dt"] == ref_info["dt"]
    assert info_b["energy_balance"] == ref_info["energy_balance"]


CROSS = [("patch162", "2-2-1-1-1", "1-1-1-1-2"),   # checkpoint under 2 ranks, continue under 2 threads
         ("gas", "1-1-1-1-2", "2-1-2-1-1"),        # threads -> ranks; the gas then migrates across blocks
         ("patch162", "1-1-1-1-1", "2-2-1-1-2"),   # serial -> hybrid 2 ranks x 2 threads
         ("patch162", "2-2-1-1-2", "1-1-1-1-1")]   # hybrid (newton: the resolvers' history sent back) -> serial


@pytest.mark.skipif(not HAS_MPI, reason="no mpiexec")
@pytest.mark.parametrize("scene,first,second", CROSS)
def test_restart_across_modes_bit_identical(tmp_path, tmp_path_factory, scene, first, second):
    """The first half under one mapping, the second from its checkpoint under another: the final
    state equals the uninterrupted serial run bit for bit."""
    n = 60 if scene == "patch162" else 300
    ref, _, _ = uninterrupted(tmp_path_factory, scene, 2 * n)
    run(tmp_path / "a", "--scene", scene, "--steps", str(n), "--checkpoint-every", str(n), "--mapping", first)
    got, steps, info = run(tmp_path / "b", "--restart", str(tmp_path / "a" / "checkpoint.npz"), "--steps", str(n),
                           "--mapping", second)
    assert info["mapping"] == second and info["restart"]["written_by"] == first
    assert steps["step"].min() == n + 1 and steps["step"].max() == 2 * n
    if scene == "gas" and second.startswith("2"):
        assert steps["n_migrated"].sum() > 0   # the continuation does move particles between ranks
    assert_same(ref, got)


@pytest.mark.skipif(not HAS_MPI, reason="no mpiexec")
@pytest.mark.parametrize("mapping", ["2-2-1-1-1", "2-2-1-1-2"])
def test_every_step_estimate_checkpoints_the_resolvers_history(tmp_path, tmp_path_factory, mapping):
    """With --skin 0 under Newton's third law the received pairs' history comes back with each
    step's terms (modes.newton, carry_history), not in a message of the checkpoint's own: a
    checkpoint of patch162 (resting contacts across the border, their tangential springs set)
    written by 2 ranks (pure MPI and hybrid) and continued in serial gives the uninterrupted
    serial run bit for bit; a history row left stale on the rank that does not resolve the pair
    would change the continuation."""
    ref, _, _ = uninterrupted(tmp_path_factory, "patch162", 120)
    run(tmp_path / "a", "--scene", "patch162", "--steps", "60", "--checkpoint-every", "60", "--mapping", mapping,
        "--skin", "0", "--newton", "on")
    got, _, info = run(tmp_path / "b", "--restart", str(tmp_path / "a" / "checkpoint.npz"), "--steps", "60")
    assert info["restart"]["written_by"] == mapping
    assert_same(ref, got)


def test_checkpoint_and_snapshot_cadence_follow_the_step_number(tmp_path):
    """Checkpoints every K steps and after the last one; a continued run keeps counting steps, so
    its snapshots are numbered as the uninterrupted run's would be."""
    scene = write(tmp_path, GOOD)
    _, _, info = run(tmp_path / "a", "--scene", scene, "--steps", "7", "--checkpoint-every", "3")
    assert info["checkpoint"]["written"] == 3 and info["checkpoint"]["last_step"] == 7   # steps 3, 6, 7
    run(tmp_path / "b", "--restart", str(tmp_path / "a" / "checkpoint.npz"), "--steps", "8", "--snapshot-every", "5",
        "--snapshot-format", "vtk")
    assert sorted(os.listdir(tmp_path / "b" / "snapshots")) == ["step00000010.npz", "step00000010.vtk",
                                                                 "step00000015.npz", "step00000015.vtk"]


def test_restart_runs_the_rest_of_the_interrupted_run(tmp_path):
    """Without --steps a restart runs the steps its writer had still to do (meta steps_target minus
    step): a 20-step run whose checkpoint was last written at step 8 (as when it is killed after
    step 8) continues for 12 steps."""
    scene = write(tmp_path, GOOD)
    run(tmp_path / "a", "--scene", scene, "--steps", "8", "--checkpoint-every", "8")
    ckpt = tmp_path / "a" / "checkpoint.npz"
    with np.load(ckpt) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"][()]))
    meta["steps_target"] = 20   # what the interrupted run had asked for
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(ckpt, **arrays)
    _, steps, _ = run(tmp_path / "b", "--restart", str(ckpt))
    assert list(steps["step"]) == list(range(9, 21))


def test_checkpoint_written_atomically(tmp_path, monkeypatch):
    """A write that fails half-way (disk full, a kill) leaves the previous checkpoint whole and no
    temporary file behind."""
    import bench.run.checkpoint as ck
    from dem.timestep import choose_time_step
    from tests.helpers import make_scene, serial
    sc = make_scene([{"shape": "sphere", "axes": [1e-3], "pos": [0.0, 0.0, 0.0], "vel": [1.0, 0.0, 0.0]}])
    mode = serial(sc, choose_time_step(sc).dt)
    meta = {"step": 0, "time": 0.0, "steps_target": 1, "time_step": choose_time_step(sc).as_dict(), "guard": {}}
    path = str(tmp_path / "checkpoint.npz")
    ck.write_checkpoint(path, mode, sc, meta)
    before = open(path, "rb").read()
    mode.step()

    def broken(file, **arrays):
        with open(file, "wb") as fh:
            fh.write(b"PK\x03\x04 half a file")
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(ck.np, "savez", broken)
    with pytest.raises(OSError):
        ck.write_checkpoint(path, mode, sc, dict(meta, step=1))
    assert open(path, "rb").read() == before
    assert os.listdir(tmp_path) == ["checkpoint.npz"]
    monkeypatch.undo()
    scene, meta = ck.load_checkpoint(path)
    assert meta["step"] == 0 and np.array_equal(scene.state.pos, [[0.0, 0.0, 0.0]])


@pytest.mark.parametrize("case", ["missing", "not-npz", "state-npz", "with-scene", "with-dt", "half",
                                  "tail-cut"])
def test_bad_restart_one_line(tmp_path, case):
    """A checkpoint that is not there, not an npz, another npz (a run's state.npz), half a checkpoint
    or one with its last 200 bytes cut (a copy that stopped; issue 34 saw a BadZipFile traceback),
    or options that would change the checkpoint's scene or time step: one line, exit 2, nothing
    written."""
    scene = write(tmp_path, GOOD)
    run(tmp_path / "a", "--scene", scene, "--steps", "2", "--checkpoint-every", "2")
    ckpt = str(tmp_path / "a" / "checkpoint.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    whole = open(ckpt, "rb").read()
    (tmp_path / "half.npz").write_bytes(whole[:len(whole) // 2])
    (tmp_path / "cut.npz").write_bytes(whole[:-200])
    args, words = {"missing": (["--restart", str(tmp_path / "nope.npz")], ["not found"]),
                   "not-npz": (["--restart", str(tmp_path / "junk.npz")], ["is not an .npz file"]),
                   "half": (["--restart", str(tmp_path / "half.npz")], ["is damaged or truncated"]),
                   "tail-cut": (["--restart", str(tmp_path / "cut.npz")], ["is damaged or truncated"]),
                   "state-npz": (["--restart", str(tmp_path / "a" / "state.npz")], ["not a checkpoint"]),
                   "with-scene": (["--restart", ckpt, "--scene", "gas"], ["--scene cannot be given"]),
                   "with-dt": (["--restart", ckpt, "--dt", "1e-6"], ["--dt cannot be given"])}[case]
    out = tmp_path / "b"
    one_line_error(bench("run", *args, "--out", str(out)), "bench: error:", *words)
    assert not out.exists()


def test_checkpoint_fields_round_trip(tmp_path):
    """The checkpoint reader rebuilds each particle's history rows (ascending partner gid, both ends
    of a pair) and wall rows exactly as the run held them."""
    from bench.run.checkpoint import load_checkpoint
    from bench.run.prepare import load_prepared
    from dem.timestep import choose_time_step
    from modes.serial import SerialMode
    import bench.run.checkpoint as ck
    sc = load_prepared("patch162")
    mode = SerialMode().setup(sc, dt=choose_time_step(sc).dt)
    for _ in range(30):
        mode.step()
    path = str(tmp_path / "c.npz")
    ck.write_checkpoint(path, mode, sc, {"step": 30, "time": 0.0, "time_step": choose_time_step(sc).as_dict()})
    s = mode.state   # write_checkpoint synced the list's history into the state's rows
    order = np.argsort(s.gid)
    back, _ = load_checkpoint(path)
    b = back.state
    assert np.array_equal(b.gid, s.gid[order])
    for f in ("pos", "vel", "quat", "angmom", "mass", "inertia", "axes", "wall_hist"):
        assert np.array_equal(getattr(b, f), getattr(s, f)[order]), f
    for r, p in enumerate(order):
        rows = slice(s.hist_start[p], s.hist_start[p + 1])
        rows_b = slice(b.hist_start[r], b.hist_start[r + 1])
        assert np.array_equal(b.hist_partner[rows_b], s.hist_partner[rows])
        assert np.array_equal(b.hist_val[rows_b], s.hist_val[rows])
    assert len(b.hist_partner) > 100


def test_restart_polyellipsoids_bit_identical(tmp_path):
    """Poly-ellipsoids (the gas scene with --shape polyellipsoid: flying, colliding, their octant
    records in the checkpoint): 150 + restart + 150 steps equal 300 steps."""
    ref, _, _ = run(tmp_path / "full", "--scene", "gas", "--shape", "polyellipsoid", "--steps", "300")
    run(tmp_path / "a", "--scene", "gas", "--shape", "polyellipsoid", "--steps", "150", "--checkpoint-every", "150")
    got, _, _ = run(tmp_path / "b", "--restart", str(tmp_path / "a" / "checkpoint.npz"), "--steps", "150")
    assert_same(ref, got)
