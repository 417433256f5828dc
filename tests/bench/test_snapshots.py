"""Snapshots (bench.run.snapshots, issue 34): binary VTU (float32, zlib) read back by an independent
reader (meshio) against the run's own npz state, its size against the legacy file (issue 34's
target: at most 1/4), the .pvd time series, the legacy --snapshot-format vtk, and the
poly-ellipsoid surfaces. Small scenes, few steps: patch162 (162 ellipsoids with three distinct
semi-axes, dt 1e-5 s from the scene file), a 20-particle poly-ellipsoid gas and a synthetic
2000-ellipsoid snapshot."""
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


def _sym(t6):
    """VTK's 6 symmetric tensor components (XX, YY, ZZ, XY, YZ, XZ) as the 3x3 matrix, float64."""
    xx, yy, zz, xy, yz, xz = np.asarray(t6, dtype=np.float64)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _f32(a):
    """The float64 state as the VTU stores it: rounded to the nearest float32."""
    return np.asarray(a).astype(np.float32)


def _synthetic(n, seed=34, moving=True):
    """A snapshot dict of n ellipsoids: positions uniform in a 1 m box, random unit quaternions,
    semi-axes 0.5-1.5 mm, velocities N(0, 0.1 m/s) and angular velocities N(0, 10 rad/s) (or zero:
    at rest), shape ellipsoid (1)."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scale = 1.0 if moving else 0.0
    return {"id": np.arange(n, dtype=np.int64), "pos": rng.random((n, 3)), "quat": q,
            "vel": scale * rng.normal(scale=0.1, size=(n, 3)), "omega": scale * rng.normal(scale=10.0, size=(n, 3)),
            "axes": 1e-3 * rng.uniform(0.5, 1.5, size=(n, 3)), "shape": np.ones(n, np.int8)}


def _series(path):
    """(time, file) of every DataSet of a .pvd, in file order."""
    return [(float(d.get("timestep")), d.get("file")) for d in ET.parse(path).getroot().iter("DataSet")]


@pytest.fixture(scope="module")
def patch_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("snap") / "run"
    info = _run(out, "--scene", "patch162", "--steps", "4", "--snapshot-every", "2")
    return out, info


def test_vtu_fields_are_the_state(patch_run):
    """step00000004.vtu read by meshio is the state of step 4 as the documented float32: points =
    state.npz pos cast to float32 and quat, vel, omega, axes = its arrays cast to float32
    (np.array_equal: each float64 rounded to the nearest float32, and nothing else: zlib is
    lossless), id and shape exactly in their own dtypes (int64, int8); step00000002.vtu likewise
    equals step00000002.npz. The file is zlib-compressed (vtkZLibDataCompressor). One VTK_VERTEX
    cell per particle (meshio 'vertex', connectivity 0..n-1). Field data: TimeValue = 4 dt
    (dt = 1e-5 s, run.json, kept float64) and STEP = 4."""
    out, info = patch_run
    snaps = out / "snapshots"
    for step, ref in ((4, out / "state.npz"), (2, snaps / "step00000002.npz")):
        path = snaps / f"step{step:08d}.vtu"
        assert b'compressor="vtkZLibDataCompressor"' in path.read_bytes()[:4096]
        m = meshio.read(path)
        z = np.load(ref)
        n = len(z["id"])
        assert n == 162
        assert len(m.cells) == 1 and m.cells[0].type == "vertex"
        assert np.array_equal(m.cells[0].data.ravel(), np.arange(n))
        assert m.points.dtype == np.float32 and np.array_equal(m.points, _f32(z["pos"]))
        for name in ("id", "shape"):
            assert np.array_equal(m.point_data[name], z[name]), name
            assert m.point_data[name].dtype == z[name].dtype, name
        for name in ("quat", "vel", "omega", "axes"):
            assert m.point_data[name].dtype == np.float32, name
            assert np.array_equal(m.point_data[name].reshape(z[name].shape), _f32(z[name])), name
        assert m.field_data["TimeValue"][0] == pytest.approx(step * info["dt"], rel=1e-15)
        assert m.field_data["STEP"][0] == step
    assert info["snapshot_format"] == "vtu"


def test_vtu_orientation_fields(patch_run):
    """The orientation of particle k with semi-axes a_j and rotation R (body to world, from its npz
    quaternion by the textbook formula): `ellipsoid` is VTK's 6-component symmetric tensor (XX, YY,
    ZZ, XY, YZ, XZ); rebuilt as the 3x3 matrix T it is R diag(a) R^T rounded to float32 (to
    2^-24 a_max a component), its eigenvalues are the semi-axes to float32 precision (3e-7 a_max:
    the rounding's norm is at most sqrt(6) 2^-24 a_max, Weyl) and T R e_j = a_j R e_j (3e-7 a_max);
    patch162's semi-axes are distinct, so eigh's unit eigenvectors are the body axes up to sign:
    |v . R e_j| = 1 to (3e-7 a_max / g_j)^2 / 2, g_j the gap from a_j to the nearest other semi-axis
    (the rounding turns an eigenvector by at most ~ its norm / the gap; g_j >= 1.8e-4 a_max in
    patch162, so at most 1.4e-6; measured 1.6e-9). These are what ParaView's Tensor Glyph (Extract Eigenvalues) uses to
    scale and orient a sphere into the particle's ellipsoid. The body axes a_j R e_j (no longer
    written: the module doc's recipe) follow from the file's float32 quat and axes by the same
    formula to 1e-6 a_j."""
    out, _ = patch_run
    m = meshio.read(out / "snapshots" / "step00000004.vtu")
    z = np.load(out / "state.npz")
    tens = m.point_data["ellipsoid"]
    assert tens.shape == (162, 6) and tens.dtype == np.float32
    assert not {"axis_x", "axis_y", "axis_z"} & set(m.point_data)
    for k in range(162):
        a, r = z["axes"][k], _rot(z["quat"][k])
        assert len(set(a)) == 3
        t = _sym(tens[k])
        np.testing.assert_allclose(t, r @ np.diag(a) @ r.T, rtol=0, atol=2.0**-24 * a.max() * 1.01)
        w, v = np.linalg.eigh(t)
        order = np.argsort(a)
        np.testing.assert_allclose(w, a[order], rtol=0, atol=3e-7 * a.max())
        r32 = _rot(m.point_data["quat"][k].astype(np.float64))
        for i, j in enumerate(order):
            np.testing.assert_allclose(t @ r[:, j], a[j] * r[:, j], rtol=0, atol=3e-7 * a.max())
            gap = np.abs(np.delete(a, j) - a[j]).min()
            assert abs(abs(v[:, i] @ r[:, j]) - 1.0) < 0.5 * (3e-7 * a.max() / gap) ** 2
            np.testing.assert_allclose(m.point_data["axes"][k, j] * r32[:, j], a[j] * r[:, j], rtol=0, atol=1e-6 * a[j])


@pytest.mark.parametrize("moving", [True, False], ids=["moving", "at-rest"])
def test_vtu_is_at_most_a_quarter_of_the_legacy_file(tmp_path, moving):
    """Issue 34's target: a VTU snapshot of ellipsoids at most 1/4 of the legacy ASCII file (write_vtk)
    of the same state. Synthetic 2000 ellipsoids (module doc: 1M measured at 0.152), moving and at
    rest (zero vel and omega shorten the legacy file; zlib squeezes them in the VTU too). The VTU is
    read back by meshio: ids exact, positions the float32 state, the tensor 6 components."""
    import bench.run.snapshots as sn
    snap = _synthetic(2000, moving=moving)
    vtu, vtk = str(tmp_path / "s.vtu"), str(tmp_path / "s.vtk")
    assert sn.write_vtu(vtu, snap, 3, 3e-5) == [vtu]
    assert sn.write_vtk(vtk, snap, 3, 3e-5) == [vtk]
    ratio = os.path.getsize(vtu) / os.path.getsize(vtk)
    assert ratio <= 0.25, ratio
    m = meshio.read(vtu)
    assert np.array_equal(m.point_data["id"], snap["id"]) and np.array_equal(m.points, _f32(snap["pos"]))
    assert np.array_equal(m.point_data["vel"], _f32(snap["vel"])) and m.point_data["ellipsoid"].shape == (2000, 6)


def test_tensor_components_are_vtk_symmetric_order(tmp_path):
    """`ellipsoid`'s 6 components in VTK's symmetric order XX, YY, ZZ, XY, YZ, XZ (what
    vtkTensorGlyph and ParaView's Tensor Glyph expect): rebuilt as a 3x3 matrix in that order, every
    one of 2000 random ellipsoids has eigenvalues = its semi-axes to float32 precision (3e-7 a_max)
    and eigenvectors along its body axes (|v . R e_j| = 1 to 1e-6 where the semi-axes are at least
    1e-3 a_max apart, over 95 % of them: an eigenvector's angle error is ~ the rounding / the gap,
    1 - cos its square / 2); another order (XY and XZ swapped) would not."""
    import bench.run.snapshots as sn
    snap = _synthetic(2000, seed=7)
    path = str(tmp_path / "s.vtu")
    sn.write_vtu(path, snap)
    tens = meshio.read(path).point_data["ellipsoid"]
    mats = np.array([_sym(t) for t in tens])
    w, v = np.linalg.eigh(mats)
    a = snap["axes"]
    order = np.argsort(a, axis=1)
    amax = a.max(axis=1, keepdims=True)
    assert np.all(np.abs(w - np.take_along_axis(a, order, axis=1)) <= 3e-7 * amax)
    rot = np.array([_rot(q) for q in snap["quat"]])
    body = np.take_along_axis(rot, order[:, None, :], axis=2)          # R e_j in eigh's order
    gap = np.diff(np.sort(a, axis=1), axis=1).min(axis=1)
    good = gap > 1e-3 * amax[:, 0]
    assert good.sum() > 1900
    assert np.all(np.abs(np.abs(np.einsum("nik,nik->nk", v, body)[good]) - 1) < 1e-6)
    swapped = np.array([_sym(t[[0, 1, 2, 5, 4, 3]]) for t in tens])
    assert np.abs(np.linalg.eigvalsh(swapped) - np.take_along_axis(a, order, axis=1)).max() > 1e-2 * a.min()


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
    assert np.array_equal(m.points, _f32(np.load(out / "state.npz")["pos"]))


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
    """A poly gas of 20, --snapshot-every 2: step00000002.vtu holds axes6 (= the npz axes [n, 6] as
    float32, as every float of that file); step00000002_surface.vtu (listed in
    snapshots_surface.pvd) holds 20 x 168 triangles (the 8 x 12 latitude-longitude sphere) with cell
    data id. Every vertex x of particle k, with
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
    assert np.array_equal(m.point_data["axes6"], _f32(z["axes"])) and np.array_equal(m.points, _f32(z["pos"]))
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
