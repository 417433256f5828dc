"""Particle files (issue 14, item 2): a scene's particles from a file (dem.particle_files) -- our
npz, whitespace or CSV columns, LAMMPS / LIGGGHTS `dump custom` -- read to the bit, in SI units,
with the conventions of DESIGN.md (quat = (w, x, y, z) body to world; semi-axes a, b, c)."""
import math
import os

import numpy as np
import pytest

from dem.scene import SceneError, load_scene
from dem.shapes import ELLIPSOID, SPHERE
from tests.helpers import bench, one_line_error

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")
BED = os.path.join(DATA, "lammps_bed_corner.txt")

HEAD = """
[domain]
box = [[0.0, 0.0, 0.0], [0.052, 0.052, 0.0754]]
walls = ["x-", "x+", "y-", "y+", "z-"]
gravity = [0.0, 0.0, -9.81]

[materials.default]
density = 2650.0
young = 29e9
poisson = 0.25
friction = 0.5
restitution = 0.8

[time]
dt = 2e-7
steps = 200
"""


def scene_file(tmp_path, block, head=HEAD, name="scene.toml"):
    p = tmp_path / name
    p.write_text(head + "\n[[particle_file]]\n" + block + "\n")
    return str(p)


def bed():
    """The file's rows (id x y z r), by numpy's own reader."""
    return np.loadtxt(BED)


def test_lammps_settled_bed_loads_with_its_resting_contacts(tmp_path):
    """The LAMMPS-settled sphere bed (tests/data/lammps_bed_corner.txt, 103 spheres of the peer
    benchmark's 10k bed) loads: positions and radii are the file's to the bit, ids ascending, and its
    resting contacts are accepted: wall overlaps r - z up to 64 nm (7e-5 of r; the file's own
    numbers) and sphere overlaps r_i + r_j - |x_i - x_j| up to 1e-4 of the smaller r, far below the
    stability guard's 5 %."""
    from dem.overlaps import pair_overlaps
    a = bed()
    sc = load_scene(scene_file(tmp_path, f'path = "{BED}"'))
    s = sc.state
    assert s.n == 103 and np.all(s.shape == SPHERE)
    assert np.array_equal(s.pos, a[:, 1:4]) and np.array_equal(s.axes, np.repeat(a[:, 4:5], 3, axis=1))
    wall = a[:, 4] - a[:, 3]   # overlap with the floor z = 0
    assert 6e-8 < wall.max() < 6.4e-8 and (wall > 0).sum() == 28
    i, j, depth, ratio = pair_overlaps(s)
    d = np.linalg.norm(a[i, 1:4] - a[j, 1:4], axis=1)
    np.testing.assert_allclose(depth, a[i, 4] + a[j, 4] - d, rtol=0, atol=1e-15)
    assert len(depth) > 100 and 0 < ratio.max() < 2e-4


def test_settled_bed_runs_at_rest(tmp_path):
    """`bench run` on the imported bed (quartz, dt 2e-7 s as the peer benchmark): 200 steps stable;
    resting contacts stay resting (overlap ratios ~1e-4, the guard's limit is 5e-2)."""
    out = tmp_path / "run"
    res = bench("run", "--scene", scene_file(tmp_path, f'path = "{BED}"'), "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    import json
    info = json.loads((out / "run.json").read_text())
    assert info["stable"] is True and info["particles"] == 103
    assert info["max_overlap_ratio"] < 1e-3


def dump(rows, names, step=0, box=((0.0, 0.052), (0.0, 0.052), (0.0, 0.0754))):
    """A LAMMPS `dump custom` snapshot (text) of rows [n, len(names)]."""
    lines = ["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", str(len(rows)), "ITEM: BOX BOUNDS ff ff ff"]
    lines += [f"{lo!r} {hi!r}" for lo, hi in box]
    lines.append("ITEM: ATOMS " + " ".join(names))
    lines += [" ".join(repr(float(v)) if not float(v).is_integer() or k > 1 else str(int(v))
                       for k, v in enumerate(r)) for r in rows]
    return "\n".join(lines) + "\n"


def test_lammps_dump_custom_matches_the_columns_file(tmp_path):
    """The same bed as a LAMMPS dump (ITEM: ATOMS id type x y z radius vx vy vz, rows shuffled as
    an unsorted parallel dump writes them, two snapshots): the last snapshot is read by default,
    `timestep` picks another, rows are taken in ascending id, and the state is the columns
    file's to the bit; box = "file" takes the dump's BOX BOUNDS."""
    a = bed()
    rng = np.random.default_rng(3)
    perm = rng.permutation(len(a))
    vel = np.zeros((len(a), 3))
    vel[:, 2] = -0.01
    rows = np.column_stack([a[:, 0], np.ones(len(a)), a[:, 1:4], a[:, 4], vel])[perm]
    names = ["id", "type", "x", "y", "z", "radius", "vx", "vy", "vz"]
    early = rows.copy()
    early[:, 4] += 1e-3   # an earlier snapshot, 1 mm higher
    path = tmp_path / "bed.dump"
    path.write_text(dump(early, names, step=1000) + dump(rows, names, step=2000))
    head = HEAD.replace('box = [[0.0, 0.0, 0.0], [0.052, 0.052, 0.0754]]', 'box = "file"')
    s = load_scene(scene_file(tmp_path, f'path = "{path}"', head=head)).state
    ref = load_scene(scene_file(tmp_path, f'path = "{BED}"', name="ref.toml")).state
    for f in ("pos", "axes", "mass", "inertia", "shape"):
        assert np.array_equal(getattr(s, f), getattr(ref, f)), f
    assert np.array_equal(s.vel, vel)
    sc = load_scene(scene_file(tmp_path, f'path = "{path}"\ntimestep = 1000', head=head, name="early.toml"))
    assert np.array_equal(sc.state.pos[:, 2], a[:, 3] + 1e-3)
    assert np.array_equal(sc.box, [[0.0, 0.0, 0.0], [0.052, 0.052, 0.0754]])


def test_liggghts_superquadric_dump_gives_ellipsoids(tmp_path):
    """LIGGGHTS superquadric columns: shapex shapey shapez are the semi-axes a, b, c and quat1 is
    the quaternion's scalar part (LIGGGHTS-PUBLIC atom_vec_superquadric: shape = semi-axes,
    identity quaternion (1, 0, 0, 0)); blockiness 2 is an ellipsoid. A rotation of 90 degrees about
    z, q = (cos 45, 0, 0, sin 45), maps the body x axis to the world y axis. shape_columns =
    "diameters" reads LAMMPS ellipsoid dumps (compute property/atom: diameters)."""
    c = math.cos(math.pi / 4)
    rows = [[1, 1, 0.01, 0.01, 0.01, 2e-3, 1e-3, 5e-4, c, 0.0, 0.0, c, 2.0, 2.0],
            [2, 1, 0.02, 0.01, 0.01, 1e-3, 1e-3, 1e-3, 1.0, 0.0, 0.0, 0.0, 2.0, 2.0]]
    names = ["id", "type", "x", "y", "z", "shapex", "shapey", "shapez", "quat1", "quat2", "quat3", "quat4",
             "blockiness1", "blockiness2"]
    path = tmp_path / "sq.dump"
    path.write_text(dump(rows, names))
    s = load_scene(scene_file(tmp_path, f'path = "{path}"')).state
    assert list(s.shape) == [ELLIPSOID, ELLIPSOID]
    assert np.array_equal(s.axes, [[2e-3, 1e-3, 5e-4], [1e-3, 1e-3, 1e-3]])
    from dem.quaternion import quat_to_matrices
    np.testing.assert_allclose(quat_to_matrices(s.quat[:1])[0] @ [1.0, 0, 0], [0.0, 1.0, 0.0], atol=1e-15)
    m = 2650.0 * 4.0 / 3.0 * math.pi * 2e-3 * 1e-3 * 5e-4
    assert s.mass[0] == pytest.approx(m, rel=1e-15)
    d = load_scene(scene_file(tmp_path, f'path = "{path}"\nshape_columns = "diameters"', name="d.toml")).state
    assert np.array_equal(d.axes, 0.5 * s.axes)
    rows[1][12] = 3.0
    path.write_text(dump(rows, names))
    with pytest.raises(SceneError, match="blockiness1 = 3: only blockiness 2"):
        load_scene(scene_file(tmp_path, f'path = "{path}"', name="b.toml"))


def test_csv_and_npz_of_a_run(tmp_path):
    """A CSV with a header (x,y,z,radius,vx,vy,vz), and a run's own state.npz read back as the
    particles of a new scene: the same positions, orientations, sizes and velocities, to the bit
    (ellipsoids from the packed scene's generator)."""
    a = bed()
    csv = tmp_path / "bed.csv"
    rows = [",".join(repr(float(v)) for v in r[1:5]) + ",0.0,0.0,0.5\n" for r in a]
    csv.write_text("x,y,z,radius,vx,vy,vz\n" + "".join(rows))
    s = load_scene(scene_file(tmp_path, f'path = "{csv}"')).state
    assert np.array_equal(s.pos, a[:, 1:4]) and np.all(s.vel[:, 2] == 0.5)
    from dem.scene import load_scene as ls
    gen = ls("gas")
    snap = gen.state.snapshot()
    np.savez(tmp_path / "state.npz", **snap)
    head = HEAD.replace("[[0.0, 0.0, 0.0], [0.052, 0.052, 0.0754]]", "[[0.0, 0.0, 0.0], [0.03, 0.03, 0.03]]")
    t = load_scene(scene_file(tmp_path, f'path = "{tmp_path / "state.npz"}"', head=head, name="npz.toml")).state
    for f in ("pos", "quat", "vel", "axes", "shape"):
        assert np.array_equal(getattr(t, f), getattr(gen.state, f)), f


BAD = {
    "missing": ('path = "nope.txt"', "not found"),
    "no-columns": ('path = "{tmp}/plain.txt"', "no header comment names its columns"),
    "malformed": ('path = "{tmp}/bad.txt"', "malformed row"),
    "duplicate-id": ('path = "{tmp}/dup.txt"', "id 7 appears twice"),
    "no-size": ('path = "{tmp}/nosize.csv"', "no size columns"),
    "unknown-key": ('path = "{tmp}/plain.txt"\nscale = 2', "unknown key 'scale'"),
    "checkpoint": ('path = "{tmp}/ck.npz"', "is a checkpoint"),
    "not-a-zip": ('path = "{tmp}/text.npz"', "is not an .npz file"),
    "truncated-npz": ('path = "{tmp}/half.npz"', "is damaged or truncated"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_particle_file_one_line(tmp_path, case):
    """A particle file that is missing, unreadable or incomplete: one line `bench: error: ...`, exit 2."""
    (tmp_path / "plain.txt").write_text("0.01 0.01 0.01 0.001\n")
    (tmp_path / "bad.txt").write_text("# x y z radius\n0.01 0.01 0.01 0.001\n0.02 0.01 oops 0.001\n")
    (tmp_path / "dup.txt").write_text("# id x y z radius\n7 0.01 0.01 0.01 0.001\n7 0.02 0.01 0.01 0.001\n")
    (tmp_path / "nosize.csv").write_text("x,y,z\n0.01,0.01,0.01\n")
    np.savez(tmp_path / "ck.npz", meta=np.array("{}"), angmom=np.zeros((1, 3)), pos=np.zeros((1, 3)))
    (tmp_path / "text.npz").write_text("not a zip")
    np.savez(tmp_path / "whole.npz", pos=np.full((400, 3), 0.01), axes=np.full((400, 3), 1e-3))
    whole = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "half.npz").write_bytes(whole[:len(whole) // 2])  # issue 34: a BadZipFile traceback
    block, words = BAD[case]
    scene = scene_file(tmp_path, block.format(tmp=tmp_path))
    one_line_error(bench("run", "--scene", scene, "--steps", "1", "--out", str(tmp_path / "o")), "bench: error:",
                   words)


def test_the_readmes_example_scene_loads_and_runs(tmp_path):
    """docs/examples/bed.toml with bed.csv (the README's complete particle-file example): four
    ellipsoids in id order, semi-axes and velocities as written, row 2 turned 90 degrees about z
    (quaternion (cos 45, 0, 0, sin 45)), and the scene runs."""
    from tests.helpers import ROOT, bench
    path = os.path.join(ROOT, "docs", "examples", "bed.toml")
    st = load_scene(path).state
    assert st.n == 4
    assert np.array_equal(st.axes[0], [0.001, 0.0008, 0.0006]) and np.array_equal(st.axes[2], [0.0008] * 3)
    assert np.array_equal(st.quat[1], [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
    assert np.array_equal(st.vel[[0, 2]], [[0.0, 0.0, -0.1], [0.05, 0.0, 0.0]])
    res = bench("run", "--scene", path, "--steps", "20", "--out", str(tmp_path / "bed"))
    assert res.returncode == 0, res.stderr
