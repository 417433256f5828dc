"""Scene generation and the time-step rule."""

import numpy as np
import pytest

from dem.materials import Material, rayleigh_time
from dem.scene import SceneError, build_scene, load_scene

MAT = {"default": dict(density=2650.0, young=1e7, poisson=0.25, friction=0.5, restitution=0.5)}


def gen_doc(**g):
    base = dict(count=200, shape="ellipsoid", gradation=[[1e-3, 0.0], [2e-3, 1.0]], aspect_b=[0.6, 0.9],
                aspect_c=[0.4, 0.6], placement="lattice", spacing=1.2, seed=3)
    base.update(g)
    return {"domain": {"box": "fit", "walls": ["x-", "x+", "y-", "y+", "z-"], "gravity": [0, 0, -9.81]},
            "materials": MAT, "time": {"dt": "auto", "steps": 1}, "generate": [base]}


def test_lattice_order_morton_takes_the_same_sites_in_compact_runs():
    """[[generate]] order = "morton" (dem.scene.lattice_order): the same lattice sites as "rows"
    (x fastest; 2000 particles on 13 x 13 sites a layer, the top layer part-filled), each once,
    visited along the Z-order curve: the first 8 ids the unit cube of sites at the origin (the
    curve's first octant of 2 x 2 x 2), and cut into 16 runs of 125 consecutive ids (the threads'
    ranges), the lattice's neighbour pairs (sites one apart along an axis) that join two runs are
    0.19 of all where rows give 0.37 (slabs about a layer thick; computed here: 0.1916 and
    0.3684). The particles' other attributes stay in id order (the same sizes); a bad order is
    refused in one line."""
    from dem.scene import lattice_order
    rows = lattice_order(2000, 13, 13, "rows")
    z = lattice_order(2000, 13, 13, "morton")
    assert rows.tolist()[:3] == [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    assert sorted(map(tuple, z.tolist())) == sorted(map(tuple, rows.tolist()))
    assert sorted(map(tuple, z[:8].tolist())) == [(x, y, w) for x in (0, 1) for y in (0, 1) for w in (0, 1)]

    def joining(sites, runs=16):
        run = np.arange(len(sites)) * runs // len(sites)
        at = {tuple(p): k for k, p in enumerate(sites.tolist())}
        pairs = [(k, at[q]) for k, p in enumerate(sites.tolist()) for d in range(3)
                 for q in [tuple(p[e] + (e == d) for e in range(3))] if q in at]
        return sum(run[a] != run[b] for a, b in pairs) / len(pairs)
    assert joining(rows) == pytest.approx(0.3684, abs=1e-4)
    assert joining(z) == pytest.approx(0.1916, abs=1e-4)
    a = build_scene(gen_doc(count=500))
    b = build_scene(gen_doc(count=500, order="morton"))
    assert np.array_equal(a.state.axes, b.state.axes)
    assert sorted(map(tuple, a.state.pos.round(12).tolist())) == sorted(map(tuple, b.state.pos.round(12).tolist()))
    assert not np.array_equal(a.state.pos, b.state.pos)
    with pytest.raises(SceneError, match=r"order: unknown 'hilbert' \(rows, morton\)"):
        build_scene(gen_doc(order="hilbert"))


def test_generated_sizes_aspects_and_orientations():
    """Largest diameters within the gradation's range, b/a and c/a within theirs, quaternions
    unit and (for random orientation) spread over the sphere (mean of R e_x near 0)."""
    sc = build_scene(gen_doc(count=2000))
    s = sc.state
    d = 2 * s.axes[:, 0]
    assert d.min() >= 1e-3 and d.max() <= 2e-3
    assert abs(np.median(d) - 1.5e-3) < 0.05e-3  # linear gradation by number: median 1.5 mm
    assert np.all((s.axes[:, 1] / s.axes[:, 0] >= 0.6) & (s.axes[:, 1] / s.axes[:, 0] <= 0.9))
    assert np.all((s.axes[:, 2] / s.axes[:, 0] >= 0.4) & (s.axes[:, 2] / s.axes[:, 0] <= 0.6))
    assert np.allclose(np.linalg.norm(s.quat, axis=1), 1.0)
    w, x, y, z = s.quat.T
    ex = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1)
    assert np.linalg.norm(ex.mean(axis=0)) < 0.1


def test_generated_poly_ellipsoids_and_range_errors():
    """Each shape generates its own (dem.shapes, Shape.generate): a poly-ellipsoid's minus/plus
    ratios lie in the scene's asymmetry range [0.7, 0.9] and its plus and minus halves sum to the
    ellipsoid's extents, whose b/a, c/a lie in aspect_b, aspect_c; spheres draw no aspects and do
    not turn (identity quaternions). A range outside (0, 1] is one SceneError naming the key and
    its values as given."""
    s = build_scene(gen_doc(count=300, shape="polyellipsoid", asymmetry=[0.7, 0.9])).state
    a6 = s.poly[:, :6]
    ratio = a6[:, 1::2] / a6[:, 0::2]
    assert np.all((ratio >= 0.7 - 1e-12) & (ratio <= 0.9 + 1e-12))
    ext = a6[:, 0::2] + a6[:, 1::2]  # 2a, 2b, 2c
    assert np.all((ext[:, 1] / ext[:, 0] >= 0.6 - 1e-12) & (ext[:, 1] / ext[:, 0] <= 0.9 + 1e-12))
    assert np.all((ext[:, 2] / ext[:, 0] >= 0.4 - 1e-12) & (ext[:, 2] / ext[:, 0] <= 0.6 + 1e-12))
    sph = build_scene(gen_doc(count=50, shape="sphere", aspect_b=[0.1, 0.2])).state
    assert np.all(sph.axes == sph.axes[:, :1]) and np.all(sph.quat == [1.0, 0.0, 0.0, 0.0])
    for key in ("asymmetry", "aspect_c"):
        with pytest.raises(SceneError, match=rf"\[\[generate\]\]\.{key} must satisfy 0 < lo <= hi <= 1, got "
                                             r"\[0\.0, 1\.0\]"):
            build_scene(gen_doc(count=20, shape="polyellipsoid", **{key: [0.0, 1.0]}))


def test_lattice_fits_box_and_particles_do_not_overlap():
    sc = build_scene(gen_doc(count=300))
    s = sc.state
    assert np.all(s.pos >= sc.box[0]) and np.all(s.pos <= sc.box[1])
    dist = np.linalg.norm(s.pos[:, None] - s.pos[None], axis=2) + np.eye(s.n)
    assert np.all(dist >= (s.rbound[:, None] + s.rbound[None]) * (1 - 1e-12))


def test_random_placement_and_overrides():
    doc = gen_doc(count=100, placement="random")
    doc["domain"]["box"] = [[0, 0, 0], [0.03, 0.03, 0.03]]
    sc = build_scene(doc, particles=150, shape="sphere", seed=9)
    s = sc.state
    assert s.n == 150 and np.all(s.shape == 0) and np.all(s.axes[:, 0] == s.axes[:, 2])
    dist = np.linalg.norm(s.pos[:, None] - s.pos[None], axis=2) + np.eye(s.n)
    assert np.all(dist >= s.rbound[:, None] + s.rbound[None])
    assert np.all(s.pos - s.rbound[:, None] >= 0) and np.all(s.pos + s.rbound[:, None] <= 0.03)


def test_random_placement_that_cannot_fit_is_refused():
    doc = gen_doc(count=500, placement="random")
    doc["domain"]["box"] = [[0, 0, 0], [0.005, 0.005, 0.005]]
    with pytest.raises(SceneError, match="could not place"):
        build_scene(doc)


def test_pluviation_particles_override():
    sc = load_scene("pluviation", particles=300)
    assert sc.n == 300 and sc.walls == ["x-", "x+", "y-", "y+", "z-"]


def test_rayleigh_time_quartz():
    """§4.3 table: quartz (E = 29 GPa, nu = 0.25, rho = 2650), R = 0.05 mm: dt_R = 8.18e-8 s."""
    q = Material("q", 2650.0, 29e9, 0.25, 0.5, 0.5)
    assert rayleigh_time(0.05e-3, q) == pytest.approx(8.18e-8, rel=1e-3)


def test_auto_time_step_rule():
    """dt = auto is 0.1 dt_critical, dt_critical = t_c/2.015 the central-difference stability limit of
    the stiffest conceivable Hertz contact (contact-mechanics.md §4.3; dem/timestep.py: the fraction
    from the work-precision study); the Rayleigh time of the smallest semi-axis is reported."""
    from dem.timestep import choose_time_step
    sc = build_scene(gen_doc(count=50))
    ts = choose_time_step(sc)
    dt, dt_auto, dt_crit, info = ts.dt, ts.auto, ts.critical, ts.details
    assert dt == dt_auto == pytest.approx(0.1 * info["t_contact"] / 2.015, rel=1e-15)
    assert dt_crit == pytest.approx(info["t_contact"] / 2.015, rel=1e-15)
    assert dt < dt_crit
    c_min = sc.state.axes.min()
    assert info["dt_rayleigh"] == pytest.approx(rayleigh_time(c_min, sc.materials.materials[0]))


def test_packed_is_dense_and_static(tmp_path, monkeypatch):
    """packed: mean particle-particle coordination >= 4 after its build, and it stays static
    (contacts persist, kinetic energy stays tiny) over the following steps, with every overlap
    under half the guard's 5 % (measured at N = 400: Z 5.67, max overlap ratio 1.5 %)."""
    monkeypatch.setenv("DEM_BENCH_CACHE", str(tmp_path))
    from bench.run.prepare import load_prepared
    from dem.timestep import choose_time_step
    from modes.serial import SerialMode
    sc = load_prepared("packed", particles=400)
    assert sc.extras["built"]["jammed"]
    m = SerialMode().setup(sc, dt=choose_time_step(sc).dt)
    rows = [m.step() for _ in range(50)]
    z = [2 * r["n_contacts"] / sc.n for r in rows]
    assert min(z) >= 4.0
    assert max(r["max_overlap_ratio"] for r in rows) < 0.025
    again = load_prepared("packed", particles=400)  # from the cache: same assembly at once
    assert again.extras["built"]["from_cache"]
    assert np.array_equal(again.state.pos, load_prepared("packed", particles=400).state.pos)


@pytest.mark.parametrize("name", ["patch162", "pluviation", "packed"])
@pytest.mark.parametrize("shape", [None, "sphere"])
def test_builtin_scene_time_steps_are_accepted(name, shape):
    """Each built-in scene's own dt is below its critical step at its default size."""
    from dem.timestep import choose_time_step
    sc = load_scene(name, shape=shape)
    ts = choose_time_step(sc)
    dt, dt_crit = ts.dt, ts.critical
    assert dt <= dt_crit


def test_lattice_pitch_per_axis_builds_a_touching_crystal():
    """`pitch = [px, py, pz]` [m] places sites at region[0] + (i + 1/2) p per axis; a pitch below the
    diameters gives a touching crystal, accepted while the overlap stays under the guard's 5 % of
    the smallest semi-axis and refused above it. Spheres of r = 1 mm at pitch 1.99 mm overlap by
    2 - 1.99 = 0.01 mm (1 %); at 1.8 mm by 0.2 mm (20 %)."""
    doc = gen_doc(count=12, shape="sphere", gradation=[[2e-3, 1.0]], pitch=[1.99e-3, 2.5e-3, 3e-3], columns=[3, 2])
    del doc["generate"][0]["spacing"]
    doc["domain"].update(box=[[0, 0, 0], [0.01, 0.01, 0.01]], walls=[])
    s = build_scene(doc).state
    assert np.array_equal(s.pos[:4], [[0.995e-3, 1.25e-3, 1.5e-3], [2.985e-3, 1.25e-3, 1.5e-3],
                                      [4.975e-3, 1.25e-3, 1.5e-3], [0.995e-3, 3.75e-3, 1.5e-3]])
    assert np.isclose(s.pos[6, 2], 4.5e-3)
    doc["generate"][0]["pitch"] = [1.8e-3, 2.5e-3, 3e-3]
    with pytest.raises(SceneError, match="overlap by 0.0002 m, 20 %"):
        build_scene(doc)
    doc["generate"][0]["spacing"] = 1.2
    with pytest.raises(SceneError, match="give spacing or pitch, not both"):
        build_scene(doc)
    del doc["generate"][0]["spacing"]
    doc["generate"][0]["pitch"] = [1e-3, 0.0, 1e-3]
    with pytest.raises(SceneError, match="pitch must be three positive lengths"):
        build_scene(doc)


def test_mixed_scene_is_spheres_then_ellipsoids_touching():
    """The built-in `mixed` (its header): 2000 spheres (r = 0.8 mm) in x < 64 mm, then 2000 aligned
    ellipsoids (1.0, 0.8, 0.6 mm); neighbours 1.599 mm apart in y overlap by 1.6 - 1.599 = 1 um, so
    each interior particle touches 4 others and the largest overlap is 1 um / 0.6 mm = 0.17 % of
    the smallest semi-axis (dem.overlaps)."""
    from dem.overlaps import worst_pair_overlap
    from dem.shapes import ELLIPSOID, SPHERE
    s = load_scene("mixed").state
    sph, ell = s.shape == SPHERE, s.shape == ELLIPSOID
    assert sph.sum() == 2000 and ell.sum() == 2000
    assert s.pos[sph, 0].max() < 0.064 < s.pos[ell, 0].min()
    assert np.all(s.axes[sph, :3] == 0.8e-3) and np.all(s.axes[ell, :3] == [1e-3, 0.8e-3, 0.6e-3])
    ratio, depth, a, b = worst_pair_overlap(s, 0.0)
    assert abs(depth - 1e-6) < 1e-9 and abs(ratio - 1e-6 / 0.6e-3) < 1e-5
