"""Snapshots (bench.run.snapshots, issue 34): binary VTU read back by an independent reader (meshio)
against the run's own npz state, the .pvd time series, the legacy --snapshot-format vtk, and the
poly-ellipsoid surfaces. Small scenes, few steps: patch162 (162 ellipsoids with three distinct
semi-axes, dt 1e-5 s from the scene file) and a 20-particle poly-ellipsoid gas."""
import json
import os
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from tests.helpers import bench, one_line_error


def _run(out, *args):
    res = bench("run", "--out", str(out), "--quiet", *args)
    assert res.returncode == 0, res.stderr
    with open(out / "run.json") as fh:
        return json.load(fh)


def _rot(q):
    """Body-to-world rotation of unit quaternion (w, x, y, z), written out here (not dem.quaternion)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _series(path):
    """(time, file) of every DataSet of a .pvd, in file order."""
    return [(float(d.get("timestep")), d.get("file")) for d in ET.parse(path).getroot().iter("DataSet")]


@pytest.fixture(scope="module")
def patch_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("snap") / "run"
    info = _run(out, "--scene", "patch162", "--steps", "4", "--snapshot-every", "2")
    return out, info


def test_vtu_fields_are_the_state(patch_run):
    """step00000004.vtu read by meshio is the state of step 4 bit for bit: points = state.npz pos
    and id, shape, quat, vel, omega, axes = its arrays (np.array_equal: the file stores float64 and
    the integers' own dtypes, raw binary, no rounding); step00000002.vtu likewise equals
    step00000002.npz. One VTK_VERTEX cell per particle (meshio 'vertex', connectivity 0..n-1).
    Field data: TimeValue = 4 dt (dt = 1e-5 s, run.json) and STEP = 4."""
    out, info = patch_run
    snaps = out / "snapshots"
    for step, ref in ((4, out / "state.npz"), (2, snaps / "step00000002.npz")):
        m = meshio.read(snaps / f"step{step:08d}.vtu")
        z = np.load(ref)
        n = len(z["id"])
        assert n == 162
        assert len(m.cells) == 1 and m.cells[0].type == "vertex"
        assert np.array_equal(m.cells[0].data.ravel(), np.arange(n))
        assert np.array_equal(m.points, z["pos"])
        for name in ("id", "shape", "quat", "vel", "omega", "axes"):
            assert np.array_equal(m.point_data[name].reshape(z[name].shape), z[name]), name
            assert m.point_data[name].dtype == z[name].dtype, name
        assert m.field_data["TimeValue"][0] == pytest.approx(step * info["dt"], rel=1e-15)
        assert m.field_data["STEP"][0] == step
    assert info["snapshot_format"] == "vtu"


def test_vtu_orientation_fields(patch_run):
    """The orientation fields of particle k with semi-axes a_j and rotation R (body to world, from
    its quaternion by the textbook formula): axis_x/y/z = a_j R e_j (to 1e-15 of a_j: the same
    product, rounding only); `ellipsoid` (9 components) T = R diag(a) R^T is symmetric, its
    eigenvalues are the semi-axes (1e-12 relative) and T R e_j = a_j R e_j (1e-12 a_max); patch162's
    semi-axes are distinct, so eigh's unit eigenvectors are the body axes up to sign
    (|v . R e_j| = 1 to 1e-12). These are what ParaView's Tensor Glyph (Extract Eigenvalues) uses to
    scale and orient a sphere into the particle's ellipsoid."""
    out, _ = patch_run
    m = meshio.read(out / "snapshots" / "step00000004.vtu")
    z = np.load(out / "state.npz")
    tens = m.point_data["ellipsoid"]
    assert tens.shape == (162, 9)
    for k in range(162):
        a, r = z["axes"][k], _rot(z["quat"][k])
        assert len(set(a)) == 3
        for j, name in enumerate(("axis_x", "axis_y", "axis_z")):
            np.testing.assert_allclose(m.point_data[name][k], a[j] * r[:, j], rtol=0, atol=1e-15 * a[j])
        t = tens[k].reshape(3, 3)
        np.testing.assert_allclose(t, t.T, rtol=0, atol=1e-15 * a.max())
        w, v = np.linalg.eigh(t)
        order = np.argsort(a)
        np.testing.assert_allclose(w, a[order], rtol=1e-12)
        for i, j in enumerate(order):
            np.testing.assert_allclose(t @ r[:, j], a[j] * r[:, j], rtol=0, atol=1e-12 * a.max())
            assert abs(abs(v[:, i] @ r[:, j]) - 1.0) < 1e-12


def test_pvd_lists_every_snapshot_with_its_time(patch_run):
    """snapshots.pvd (a ParaView Collection) lists step00000002.vtu at 2 dt and step00000004.vtu
    at 4 dt; the last time is run.json's time_end (the simulated time reached)."""
    out, info = patch_run
    series = _series(out / "snapshots" / "snapshots.pvd")
    assert [f for _, f in series] == ["step00000002.vtu", "step00000004.vtu"]
    np.testing.assert_allclose([t for t, _ in series], [2 * info["dt"], 4 * info["dt"]], rtol=1e-15)
    assert series[-1][0] == pytest.approx(info["time_end"], rel=1e-15)
    assert sorted(os.listdir(out / "snapshots")) == ["snapshots.pvd", "step00000002.npz", "step00000002.vtu",
                                                     "step00000004.npz", "step00000004.vtu"]


def test_restart_into_the_same_folder_continues_the_series(tmp_path):
    """A 4-step run (checkpoint at 4) continued for 4 more steps into the same folder: snapshots
    keep the step numbers (6, 8) and the series lists all four at k dt (the restart's time_end is
    8 dt), so ParaView plays the two runs as one."""
    out = tmp_path / "run"
    _run(out, "--scene", "patch162", "--steps", "4", "--snapshot-every", "2", "--checkpoint-every", "4")
    info = _run(out, "--restart", str(out / "checkpoint.npz"), "--steps", "4", "--snapshot-every", "2")
    series = _series(out / "snapshots" / "snapshots.pvd")
    assert [f for _, f in series] == [f"step{k:08d}.vtu" for k in (2, 4, 6, 8)]
    np.testing.assert_allclose([t for t, _ in series], [k * info["dt"] for k in (2, 4, 6, 8)], rtol=1e-14)
    assert series[-1][0] == pytest.approx(info["time_end"], rel=1e-15)
    m = meshio.read(out / "snapshots" / "step00000008.vtu")
    assert np.array_equal(m.points, np.load(out / "state.npz")["pos"])


def test_vtk_format_keeps_the_legacy_writer(tmp_path):
    """--snapshot-format vtk writes the legacy ASCII POLYDATA step00000002.vtk (header, POINTS,
    SCALARS quat, VECTORS axes as before) and the npz, no .vtu and no series; run.json records vtk."""
    out = tmp_path / "run"
    info = _run(out, "--scene", "patch162", "--steps", "2", "--snapshot-every", "2", "--snapshot-format", "vtk")
    assert sorted(os.listdir(out / "snapshots")) == ["step00000002.npz", "step00000002.vtk"]
    text = (out / "snapshots" / "step00000002.vtk").read_text()
    assert text.startswith("# vtk DataFile Version 3.0\n")
    for line in ("ASCII", "DATASET POLYDATA", "POINTS 162 double", "SCALARS quat double 4", "VECTORS axes double"):
        assert f"\n{line}\n" in text, line
    assert info["snapshot_format"] == "vtk"


@pytest.mark.parametrize("fmt", ["vtu", "vtk"])
def test_mpi_run_writes_the_format_asked(patch_run, tmp_path, fmt):
    """2 ranks (rank 0 gathers and writes): the format asked reaches the ranks (the launcher once
    dropped it, so vtk wrote VTU), and the VTU holds the same particles bit for bit as the serial
    run's (every mode reproduces the serial trajectory)."""
    out = tmp_path / fmt
    info = _run(out, "--scene", "patch162", "--steps", "4", "--snapshot-every", "2", "--mapping", "2-2-1-1-1",
                "--snapshot-format", fmt)
    assert info["snapshot_format"] == fmt
    assert os.path.exists(out / "snapshots" / f"step00000004.{fmt}")
    if fmt == "vtu":
        serial = meshio.read(patch_run[0] / "snapshots" / "step00000004.vtu")
        ranks = meshio.read(out / "snapshots" / "step00000004.vtu")
        order_s, order_r = np.argsort(serial.point_data["id"]), np.argsort(ranks.point_data["id"])
        assert np.array_equal(serial.points[order_s], ranks.points[order_r])
        assert np.array_equal(serial.point_data["quat"][order_s], ranks.point_data["quat"][order_r])


def test_unknown_snapshot_format_is_one_line(tmp_path):
    one_line_error(bench("run", "--scene", "patch162", "--snapshot-every", "1", "--snapshot-format", "vtp",
                         "--out", str(tmp_path / "run")), "--snapshot-format")


def test_polyellipsoid_scene_writes_its_surfaces(tmp_path):
    """A poly gas of 20, --snapshot-every 2: step00000002.vtu holds axes6 (= the npz axes [n, 6]);
    step00000002_surface.vtu (listed in snapshots_surface.pvd) holds 20 x 168 triangles (the
    8 x 12 latitude-longitude sphere) with cell data id. Every vertex x of particle k, with
    x_b = R^T (x - o) (o, R the octant origin and frame, from the npz) lies on its octant's
    ellipsoid: sum_j (x_b,j / alpha_j)^2 = 1, alpha_j = a+ or a- by the sign of x_b,j (Peters et
    al. 2009), to 1e-12 (float64 vertices: the residual is the rounding of o + R (alpha u), a few
    1e-16 |o| / alpha_min ~ 1e-14 with |o| <= 3 cm, alpha_min >= 0.4 mm; measured 7e-15)."""
    out = tmp_path / "run"
    _run(out, "--scene", "gas", "--shape", "polyellipsoid", "--particles", "20", "--steps", "2",
         "--snapshot-every", "2")
    snaps = out / "snapshots"
    z = np.load(snaps / "step00000002.npz")
    m = meshio.read(snaps / "step00000002.vtu")
    assert np.array_equal(m.point_data["axes6"], z["axes"]) and np.array_equal(m.points, z["pos"])
    s = meshio.read(snaps / "step00000002_surface.vtu")
    n = len(z["id"])
    assert len(s.cells) == 1 and s.cells[0].type == "triangle" and len(s.cells[0].data) == n * 168
    assert np.array_equal(s.cell_data["id"][0], np.repeat(z["id"], 168))
    pts = s.points.reshape(n, -1, 3)
    for k in range(n):
        a6 = z["axes"][k]
        xb = (pts[k] - z["pos"][k]) @ _rot(z["quat"][k])
        al = np.where(xb >= 0, a6[[0, 2, 4]], a6[[1, 3, 5]])
        np.testing.assert_allclose(np.sum((xb / al) ** 2, axis=1), 1.0, rtol=0, atol=1e-12)
    assert [f for _, f in _series(snaps / "snapshots_surface.pvd")] == ["step00000002_surface.vtu"]


def test_a_failed_write_leaves_the_previous_file(tmp_path, monkeypatch):
    """A VTU write that fails half-way (a full disk) raises RecordError (the run records `failed`),
    leaves the file as it was and no temporary file behind (temporary file + os.replace)."""
    import bench.run.snapshots as sn
    from bench.run.records import RecordError
    snap = {"id": np.arange(2), "pos": np.zeros((2, 3)), "quat": np.tile([1.0, 0, 0, 0], (2, 1)),
            "vel": np.zeros((2, 3)), "omega": np.zeros((2, 3)), "axes": np.full((2, 3), 1e-3),
            "shape": np.ones(2, np.int8)}
    path = str(tmp_path / "step00000001.vtu")
    sn.write_vtu(path, snap, 1, 1e-5)
    before = open(path, "rb").read()

    def broken(*a, **kw):
        yield b"<?xml"
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(sn, "vtu_bytes", broken)
    with pytest.raises(RecordError, match="No space left"):
        sn.write_vtu(path, snap, 1, 2e-5)
    assert open(path, "rb").read() == before
    assert os.listdir(tmp_path) == ["step00000001.vtu"]
