"""Load-time checks of a state (issue 14, item 3): resting contacts with walls and between particles
are accepted up to the stability guard's overlap limit (5 % of the smaller body's smallest
semi-axis, bench.run.guard), larger ones refused at load in one line naming the particles and the
overlap; two coincident bodies are refused as such (before, these were caught only at step 1)."""
import math

import numpy as np
import pytest

from dem.scene import SceneError
from tests.helpers import GOOD, bench, make_scene, one_line_error, write

R = 1e-3


def spheres(gap_ratio, shape="sphere", axes=(R,)):
    """Two bodies on the x axis whose surfaces overlap by gap_ratio x R (negative: apart)."""
    d = 2 * R * (1.0 - 0.5 * gap_ratio)
    return [dict(shape=shape, axes=list(axes), pos=[0.0, 0.0, 0.0]),
            dict(shape=shape, axes=list(axes), pos=[d, 0.0, 0.0])]


def test_resting_pair_overlaps_accepted_up_to_the_guard_limit():
    """Two spheres of radius R overlapping by delta = r_i + r_j - d: 4.9 % of R loads, 5.1 % is
    refused naming both particles, the depth [m] and its percentage."""
    sc = make_scene(spheres(0.049))
    assert sc.n == 2
    with pytest.raises(SceneError) as e:
        make_scene(spheres(0.051))
    msg = str(e.value)
    assert "particle 0 and particle 1 overlap by 5.1e-05 m, 5.1 %" in msg and "\n" not in msg


def test_half_overlap_and_coincident_bodies_refused():
    """A 50 % overlap (the issue's example) and two coincident ellipsoids (no contact normal exists)
    are refused at load, one line each."""
    with pytest.raises(SceneError, match=r"overlap by 0.0005 m, 50 %"):
        make_scene(spheres(0.5))
    coincident = [dict(shape="ellipsoid", axes=[2e-3, 1e-3, 5e-4], pos=[0.0, 0.0, 0.0]),
                  dict(shape="ellipsoid", axes=[2e-3, 1e-3, 5e-4], pos=[0.0, 0.0, 0.0], quat=[0.0, 0.0, 0.0, 1.0])]
    with pytest.raises(SceneError, match="particle 0 and particle 1 coincide"):
        make_scene(coincident)


def test_ellipsoid_pair_overlap_measured_by_the_exact_solver():
    """Two ellipsoids side by side along their c axes (c = 0.5 mm): the overlap is 2c - d exactly
    (the support distances add along the common axis), 3 % of c is accepted and 6 % refused."""
    ax = [2e-3, 1e-3, 5e-4]
    c = ax[2]
    for ratio, ok in ((0.03, True), (0.06, False)):
        parts = [dict(shape="ellipsoid", axes=ax, pos=[0.0, 0.0, 0.0]),
                 dict(shape="ellipsoid", axes=ax, pos=[0.0, 0.0, 2 * c - ratio * c])]
        if ok:
            make_scene(parts)
        else:
            with pytest.raises(SceneError, match=r"overlap by 3e-05 m, 6 %"):
                make_scene(parts)


def test_wall_overlap_accepted_up_to_the_guard_limit():
    """A sphere resting on the floor z = 0 with its centre at z = R (1 - f): overlap f R; f = 4.9 % loads,
    f = 5.1 % is refused in one line naming the particle, the wall and the overlap."""
    box = ((-0.01, -0.01, 0.0), (0.01, 0.01, 0.02))
    make_scene([dict(shape="sphere", axes=[R], pos=[0.0, 0.0, R * (1 - 0.049)])], box=box, walls=["z-"])
    with pytest.raises(SceneError) as e:
        make_scene([dict(shape="sphere", axes=[R], pos=[0.0, 0.0, R * (1 - 0.051)])], box=box, walls=["z-"])
    assert "particle 0 overlaps a wall (z-) by 5.1e-05 m, 5.1 %" in str(e.value)


def test_guard_limit_option_sets_the_load_limit(tmp_path):
    """`bench run --guard-overlap F` is the load limit too: GOOD's two particles pushed 10 % of the
    ellipsoid's c into each other are refused by default and load with F = 0.2."""
    # GOOD: ellipsoid (1, 0.8, 0.6) mm at x = 10 mm and a sphere of 0.8 mm at x = 11.79 mm, overlapping
    # 0.01 mm along x (a + r = 1.8 mm; 1.7 % of c, a resting contact); at x = 11.74 mm the overlap is
    # 0.06 mm, 10 % of c = 0.6 mm
    text = GOOD.replace("pos = [0.01179, 0.01, 0.0011]", "pos = [0.01174, 0.01, 0.0011]")
    scene = write(tmp_path, text)
    one_line_error(bench("run", "--scene", scene, "--steps", "1", "--out", str(tmp_path / "a")),
                   "particle 0 and particle 1 overlap by 6e-05 m, 10 %")
    res = bench("run", "--scene", scene, "--steps", "1", "--guard-overlap", "0.2", "--out", str(tmp_path / "b"),
                "--quiet")
    assert res.returncode == 0, res.stderr


def test_contacts_command_shows_any_overlap(tmp_path):
    """`bench contacts` prints the contacts of any configuration, a 50 % overlap included (no load
    limit there): depth r_i + r_j - d = 0.5 mm."""
    import json
    text = GOOD.split("[[particles]]")[0] + """
[[particles]]
shape = "sphere"
axes = [1e-3]
pos = [0.009, 0.01, 0.01]
[[particles]]
shape = "sphere"
axes = [1e-3]
pos = [0.0105, 0.01, 0.01]
"""
    res = bench("contacts", write(tmp_path, text))
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout)
    assert len(got) == 1 and math.isclose(got[0]["depth"], 5e-4, rel_tol=1e-12)


def test_screen_bound_is_never_below_the_depth():
    """The load check's screen (dem/overlaps.py) drops a pair when h_i(n) + h_j(-n) - d along the line
    of centres is below the limit; that is an upper bound of the depth (the shortest separating
    translation is the minimum of h_i(n) + h_j(-n) - n.(x_j - x_i) over all n), h bounded by each
    shape's support_bound (the ellipsoid's and sphere's exact, a poly-ellipsoid's its bounding
    radius). 300 random pairs of an ellipsoid (semi-axes U[0.2, 1]) with an ellipsoid, a sphere (20 %)
    or a poly-ellipsoid (20 %, six semi-axes U[0.2, 1]), random orientations and offsets: every
    touching pair's exact depth is at most the bound, up to round-off (1e-12 of the sizes)."""
    from dem.integrate import derive_range
    from dem.overlaps import pair_overlaps, support_bound
    from dem.quaternion import random_quaternions
    from tests.helpers import make_scene
    rng = np.random.default_rng(7)
    touching = {"ellipsoid": 0, "sphere": 0, "polyellipsoid": 0}
    for _ in range(300):
        u = rng.random()
        partner = "sphere" if u < 0.2 else "polyellipsoid" if u < 0.4 else "ellipsoid"
        parts = []
        for k in range(2):
            kind = partner if k == 1 else "ellipsoid"
            axes = [float(x) for x in rng.uniform(0.2, 1.0, {"sphere": 1, "ellipsoid": 3, "polyellipsoid": 6}[kind])]
            pos = [0.0, 0.0, 0.0] if k == 0 else [float(x) for x in rng.normal(size=3) * rng.uniform(0.1, 1.2)]
            parts.append(dict(shape=kind, axes=axes, pos=pos, quat=[float(q) for q in random_quaternions(1, rng)[0]]))
        s = make_scene(parts, box=((-5.0,) * 3, (5.0,) * 3), overlap_limit=float("inf")).state
        i, _, depth, _ = pair_overlaps(s, screen=0.0)
        if not len(i):
            continue
        touching[partner] += 1
        rot = np.zeros((2, 3, 3))
        derive_range(0, 2, s.quat, s.angmom, s.inertia, s.shape, rot, np.zeros((2, 3)))
        d = s.pos[1] - s.pos[0]
        n = d / np.linalg.norm(d)
        bound = sum(support_bound(k, n[0], n[1], n[2], rot, s.axes, s.rbound, s.shape) for k in (0, 1)) \
            - np.linalg.norm(d)
        assert depth[0] <= bound + 1e-12, (parts, depth[0], bound)
    # the offsets make most pairs touch: 113 ellipsoid, 46 sphere and 40 poly-ellipsoid partners of 300
    assert min(touching.values()) > 20 and sum(touching.values()) > 100, touching


def test_global_ids_beyond_the_pair_key_refused():
    """dem.pairs.pair_key packs a pair's two global ids into one int64 (gid_i 2^32 + gid_j), exact
    and ordered as the pairs for ids in [0, 2^31): a state with an id outside it is refused with a
    message naming the range, and the largest id allowed, 2^31 - 1, is kept."""
    from dem.state import GID_LIMIT, State
    assert GID_LIMIT == 2 ** 31

    def state(gid):
        n = len(gid)
        return State(np.array(gid), np.zeros(n), np.full((n, 3), 0.01), np.ones(n), np.ones((n, 3)), np.zeros(n),
                     np.zeros((n, 3)), np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros((n, 3)))
    assert state([0, 2 ** 31 - 1]).gid[1] == 2 ** 31 - 1
    for bad in ([0, 2 ** 31], [-1, 3]):
        with pytest.raises(ValueError, match=r"global ids must lie in \[0, 2147483648\)"):
            state(bad)
