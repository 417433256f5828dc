"""Block decomposition and halo packing, tested without MPI (no mpiexec): the geometry that decides
who owns a particle and who receives it as a ghost (Yan & Regueiro §3), and the bit-exact
packing of ghost rows and forward messages (modes/halo.py)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from dem.state import State
from tests.helpers import ROOT
from modes.decomposition import (DIRECTIONS, OPPOSITE, BlockGrid, DecompositionError, balanced_grid, blended_grid,
                                 block_counts, border_width, direction_of, extent_grid, face_bits, fit_skin,
                                 load_profiles, border_lists)
from dem.shapes import ELLIPSOID, POLY, SPHERE
from modes.halo import (PER_PARTICLE, WIDTH, Halo, _columns, _split, drop_ghosts, ghost_fields, pack_moving,
                        unpack_moving)

UNIT = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))


def test_directions_and_opposites():
    """The 26 offsets of {-1, 0, 1}^3 without 0, each once; direction k's opposite is 25 - k and
    is its negation."""
    assert DIRECTIONS.shape == (26, 3)
    assert len({tuple(d) for d in DIRECTIONS}) == 26
    assert not np.any(np.all(DIRECTIONS == 0, axis=1))
    assert np.array_equal(OPPOSITE, 25 - np.arange(26))
    assert np.array_equal(DIRECTIONS[OPPOSITE], -DIRECTIONS)


def test_owner_of_a_centre():
    """Owner = floor of the scaled coordinate: a centre exactly on the face x = 0.5 of a 2x1x1 grid
    belongs to the upper block (1); centres outside the box belong to the nearest edge block."""
    g = BlockGrid(UNIT, (2, 1, 1))
    pos = np.array([[0.5, 0.5, 0.5], [0.4999, 0.5, 0.5], [-0.1, 0.5, 0.5], [1.2, 0.5, 0.5], [0.7, -3.0, 9.0]])
    assert g.block_of(pos).tolist() == [[1, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]]
    lo, hi = g.bounds((1, 0, 0))
    assert lo.tolist() == [0.5, 0.0, 0.0] and hi.tolist() == [1.0, 1.0, 1.0]
    assert g.neighbour((1, 0, 0), int(np.flatnonzero((DIRECTIONS == (1, 0, 0)).all(axis=1))[0])) is None


def test_border_lists_cover_every_touching_pair(rng):
    """Completeness of the ghost choice: on a 3x3x3 grid, for every particle i of the centre block
    and every particle j of neighbour block k with |x_i - x_j| < width, i is in direction k's border
    list (else block k would miss a contact). 4000 random centres, width 0.1 of a 1/3 block."""
    g = BlockGrid(UNIT, (3, 3, 3))
    width = 0.1
    pos = rng.random((4000, 3))
    owner = g.block_of(pos)
    centre = np.all(owner == 1, axis=1)
    lo, hi = g.bounds((1, 1, 1))
    start, items = border_lists(pos[centre], lo, hi, width)
    pi = pos[centre]
    masks = np.zeros((len(DIRECTIONS), len(pi)), dtype=bool)
    for k in range(len(DIRECTIONS)):
        lst = items[start[k]:start[k + 1]]
        assert np.all(np.diff(lst) > 0)  # ascending, each once
        masks[k, lst] = True
    checked = 0
    for k, d in enumerate(DIRECTIONS):
        pj = pos[np.all(owner == 1 + d, axis=1)]
        close = np.linalg.norm(pi[:, None, :] - pj[None, :, :], axis=2) < width
        need = close.any(axis=1)
        checked += int(need.sum())
        assert np.all(masks[k][need]), k
    assert checked > 0
    # and the masks are the box-distance test, nothing more: a centre deep inside is sent nowhere
    inner = np.all((pi - lo > width) & (hi - pi > width), axis=1)
    assert inner.any() and not masks[:, inner].any()


def test_direction_of_round_trip():
    """direction_of inverts DIRECTIONS for all 26 neighbours and gives -1 for a jump of two blocks."""
    origin = np.array([1, 1, 1])
    to = origin + np.vstack([DIRECTIONS, [[2, 0, 0], [0, 0, 0]]])
    got = direction_of(origin, to)
    assert np.array_equal(got[:26], np.arange(26))
    assert got[26] == -1 and got[27] == -1


def test_extent_grid_splits_the_particles_not_the_box():
    """A bed resting in the lowest third of a tall box (centres at z = 0.01..0.30 of 1.0): halving
    the box along z leaves the upper block empty (4 + 0), the grid fitted to the centres' extent
    (the paper's updateGrid) cuts at z = 0.155, between the second and third centre (2 + 2).
    Its corners lie 1e-9 of the span outside the extreme centres, so those stay inside."""
    pos = np.array([[0.5, 0.5, z] for z in (0.01, 0.10, 0.20, 0.30)])
    box = BlockGrid(UNIT, (1, 1, 2))
    assert block_counts(box, pos).tolist() == [[[4, 0]]]
    fitted = extent_grid(pos.min(axis=0), pos.max(axis=0), (1, 1, 2))
    assert block_counts(fitted, pos).tolist() == [[[2, 2]]]
    assert fitted.bounds((0, 0, 0))[1][2] == pytest.approx(0.155)
    assert np.all(fitted.lo < pos.min(axis=0)) and np.all(fitted.hi > pos.max(axis=0))
    # blocks 0.145 wide along z hold a border layer of 0.1, not one of 0.2; unsplit x and y (zero
    # span here) are not checked
    assert fitted.fits(0.1) and not fitted.fits(0.2)
    assert block_counts(fitted, np.zeros((0, 3))).tolist() == [[[0, 0]]]


def test_block_of_and_border_lists_are_their_formulas(rng):
    """The numba kernels are the formulas of their docstrings, element for element: block_of =
    clip(floor((x - lo) / h), 0, dims - 1) on a uniform 3x2x4 grid and searchsorted(cuts, x, right)
    on a grid of cut planes, for 5000 centres in and around the box (some on a face); each border
    list = the ascending centres with x - lo < w where the direction's offset is -1 and hi - x < w
    where it is +1, on every axis."""
    pos = rng.uniform(-0.2, 1.2, (5000, 3))
    pos[:50, 0] = 0.5  # on the face between the two x blocks
    g = BlockGrid(UNIT, (3, 2, 4))
    want = np.clip(np.floor((pos - g.lo) / g.h).astype(np.int64), 0, g.dims - 1)
    assert np.array_equal(g.block_of(pos), want)
    cuts = ([0.5, 0.61], [0.2], [0.3, 0.45, 0.9])
    c = BlockGrid(UNIT, (3, 2, 4), cuts=cuts)
    want = np.stack([np.searchsorted(cuts[a], pos[:, a], side="right") for a in range(3)], axis=1)
    assert np.array_equal(c.block_of(pos), want)
    # leavers: block_of, the marks of the centres outside one block and their count, in one call
    for grid in (g, c):
        target, marks, count = grid.leavers(pos, (1, 0, 2))
        assert np.array_equal(target, grid.block_of(pos))
        assert np.array_equal(marks, np.any(target != (1, 0, 2), axis=1).astype(np.int8))
        assert count == np.count_nonzero(marks) and 0 < count < len(pos)
    lo, hi, w = np.array([0.2, 0.1, 0.3]), np.array([0.7, 0.8, 0.6]), 0.12
    start, items = border_lists(pos, lo, hi, w)
    for k, d in enumerate(DIRECTIONS):
        need = np.ones(len(pos), dtype=bool)
        for a in range(3):
            if d[a] < 0:
                need &= pos[:, a] - lo[a] < w
            elif d[a] > 0:
                need &= hi[a] - pos[:, a] < w
        assert np.array_equal(items[start[k]:start[k + 1]], np.flatnonzero(need)), k
    # a block whose low-x and high-z faces alone have neighbours (x -1 and z +1 and the edge
    # between them): only those three directions list particles, the same ones as without the mask
    dirs = [k for k, d in enumerate(DIRECTIONS) if d[1] == 0 and d[0] in (-1, 0) and d[2] in (0, 1)]
    assert len(dirs) == 3
    start_m, items_m = border_lists(pos, lo, hi, w, face_bits(dirs))
    for k in range(len(DIRECTIONS)):
        got = items_m[start_m[k]:start_m[k + 1]]
        assert np.array_equal(got, items[start[k]:start[k + 1]] if k in dirs else np.zeros(0, dtype=np.int64)), k


def test_grid_with_cut_planes():
    """A grid of cut planes x = 0.375 and z = 0.5, 0.75: a centre on a plane belongs to the upper
    block, as on a uniform grid; centres outside belong to the edge blocks; bounds are the planes;
    the narrowest block (0.25 along z) decides the width it holds."""
    g = BlockGrid(UNIT, (2, 1, 3), cuts=([0.375], [], [0.5, 0.75]))
    pos = np.array([[0.375, 0.5, 0.5], [0.3749, 0.5, 0.7499], [-1.0, 0.5, 2.0], [0.9, 0.5, 0.1]])
    assert g.block_of(pos).tolist() == [[1, 0, 1], [0, 0, 1], [0, 0, 2], [1, 0, 0]]
    lo, hi = g.bounds((1, 0, 1))
    assert lo.tolist() == [0.375, 0.0, 0.5] and hi.tolist() == [1.0, 1.0, 0.75]
    assert g.fits(0.25) and not g.fits(0.26)
    assert [c.tolist() for c in g.inner_cuts()] == [[0.375], [], [0.5, 0.75]]
    assert [c.tolist() for c in BlockGrid(UNIT, (4, 1, 1)).inner_cuts()][0] == [0.25, 0.5, 0.75]


def test_balanced_grid_cuts_at_equal_load():
    """10 000 centres evenly spread along x over 0..1, of weight 1 below x = 0.5 and 3 above: the
    load 0.5 + 3 (c - 0.5) left of a cut c equals half of the total 2 at c = 2/3, so two blocks
    split there: 20000/3 = 6666.7 centres on the left, to within one centre (the profile's 1/1024
    bins hold about 10 centres each, and the cut is placed linearly inside its bin). With the count
    as load they split 5000 + 5000; unsplit axes keep no cut."""
    x = (np.arange(10000) + 0.5) / 10000
    pos = np.stack([x, np.full_like(x, 0.5), np.full_like(x, 0.5)], axis=1)
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    w = np.where(x < 0.5, 1.0, 3.0)
    g = balanced_grid(UNIT, lo, hi, (2, 1, 1), load_profiles(pos, w, lo, hi), 0.1)
    assert g.cuts[0][0] == pytest.approx(2.0 / 3.0, abs=1e-4)
    left, right = block_counts(g, pos).ravel().tolist()
    assert abs(left - 20000 / 3) < 1 and left + right == 10000
    assert len(g.cuts[1]) == 0 and len(g.cuts[2]) == 0
    g = balanced_grid(UNIT, lo, hi, (2, 1, 1), load_profiles(pos, 1.0, lo, hi), 0.1)
    assert block_counts(g, pos).ravel().tolist() == [5000, 5000]


def test_balanced_grid_keeps_blocks_a_border_layer_wide():
    """A bed in the lowest 0.1 of a unit box split in two along z: the equal-count cut (z = 0.05)
    is pushed up to the border layer of 0.3 above the box floor, the lower block's least width;
    a layer of 0.6 leaves no room for two blocks in 1.0 (None). An empty load gives None. The
    outer edges are the box's."""
    rng = np.random.default_rng(7)
    pos = rng.random((500, 3)) * [1.0, 1.0, 0.1]
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    prof = load_profiles(pos, 1.0, lo, hi)
    g = balanced_grid(UNIT, lo, hi, (1, 1, 2), prof, 0.3)
    assert g.cuts[2][0] == pytest.approx(0.3 * (1 + 1e-9), rel=1e-12) and g.fits(0.3)
    assert g.lo.tolist() == [0.0, 0.0, 0.0] and g.hi.tolist() == [1.0, 1.0, 1.0]
    assert balanced_grid(UNIT, lo, hi, (1, 1, 2), prof, 0.6) is None
    assert balanced_grid(UNIT, lo, hi, (1, 1, 2), np.zeros_like(prof), 0.1) is None


def test_blended_grid_moves_cuts_part_way():
    """Keeping half of the old planes: cuts at 0.25 (old, uniform 4 blocks: 0.25, 0.5, 0.75) and a
    target at 0.4, 0.6, 0.9 blend to 0.325, 0.55, 0.825."""
    old = BlockGrid(UNIT, (4, 1, 1))
    target = BlockGrid(UNIT, (4, 1, 1), cuts=([0.4, 0.6, 0.9], [], []))
    assert blended_grid(old, target, 0.5).cuts[0].tolist() == pytest.approx([0.325, 0.55, 0.825], rel=1e-15)


def test_block_width_and_skin():
    """Blocks narrower than the border layer are refused in one line naming the axis; the layer is
    the largest bounding diameter widened by 1e-9; a default skin shrinks to the room left
    (h - width), an explicit one that does not fit is refused."""
    assert border_width(0.05) == 2 * 0.05 * (1 + 1e-9)
    g = BlockGrid(UNIT, (4, 1, 1))   # blocks 0.25 wide along x
    g.check_width(0.25)
    with pytest.raises(DecompositionError) as e:
        g.check_width(0.3)
    assert "along x" in str(e.value) and "\n" not in str(e.value)
    assert fit_skin(g, 0.15, 0.05, explicit=True) == 0.05
    assert fit_skin(g, 0.15, 0.2, explicit=False) == pytest.approx(0.1 * (1 - 1e-9), rel=1e-15)
    with pytest.raises(DecompositionError, match="use a skin of at most"):
        fit_skin(g, 0.15, 0.2, explicit=True)
    assert fit_skin(BlockGrid(UNIT, (1, 1, 1)), 0.15, 5.0, explicit=True) == 5.0  # one block: no ghosts


def _state(rng, n, spheres):
    shape = np.zeros(n, dtype=np.int8) if spheres else rng.integers(0, 2, n).astype(np.int8)
    axes = rng.random((n, 3)) + 0.5
    if spheres:
        axes[:] = axes[:, :1]
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1)[:, None]
    inertia = rng.random((n, 3)) if not spheres else np.repeat(rng.random((n, 1)), 3, axis=1)
    state = State(np.arange(n), shape, axes, rng.random(n), inertia, rng.integers(0, 3, n), rng.normal(size=(n, 3)),
                  rng.normal(size=(n, 3)), quat, rng.normal(size=(n, 3)))
    # large ids, set past State's check of their range (below 2^31, dem.pairs.pair_key): the records
    # carry any int64 bit for bit through the float64 matrix, where a float's 53 bits would not
    state.gid[:] = rng.integers(0, 2 ** 62, n) | (1 << 62)
    return state


@pytest.mark.parametrize("spheres", [True, False])
def test_ghost_rows_round_trip_bit_exact(rng, spheres):
    """_columns then _split gives back the selected rows of every ghost field bit for bit: gid by
    reinterpretation (ids above 2^62, where a float conversion would round), shape and material
    as small integers, a sphere's radius and moment once (axes0, inertia0) repeated to 3."""
    s = _state(rng, 50, spheres)
    fields = ghost_fields(SPHERE if spheres else ELLIPSOID)
    idx = np.array([3, 0, 49, 17, 17])
    got = _split(_columns(s, fields, idx), fields)
    assert np.array_equal(got["gid"], s.gid[idx])
    for f in ("material", "mass", "axes", "inertia", "pos", "vel", "angmom") + (() if spheres else ("shape", "quat")):
        assert np.array_equal(got[f], getattr(s, f)[idx]), f


def test_ghost_record_widths():
    """The records the shapes declare (Shape.ghost_fields, moving_fields) have the widths the halo
    documents (modes.halo docstring): a scene of spheres 14 doubles a ghost (112 bytes) and 9 a
    forward row (72 bytes); with ellipsoids 23 (184 bytes) and 13 (104 bytes); with poly-ellipsoids
    the 18 of the record besides, 41 (328 bytes) and 13. The paper sends 624 bytes an ellipsoid."""
    assert [Halo.record_widths(k) for k in (SPHERE, ELLIPSOID, POLY)] == [(14, 9), (23, 13), (41, 13)]


@pytest.mark.parametrize("rec", [SPHERE, ELLIPSOID, POLY])
def test_ghost_records_in_place_equal_the_fields(rng, rec):
    """pack_ghost_rows writes the records _columns writes (the same fields, order and bits), and a
    halo's _append of them after rows 0..n-1 gives every per-particle array the selected rows bit
    for bit, with a second _append into the same capacity arrays (no copy of the owned rows)
    after the first ghosts are dropped; a poly-ellipsoid's bounding radius holds its offset."""
    s = _state(rng, 50, rec == SPHERE)
    if rec == POLY:
        from dem.shapes import POLY_LEN
        from dem.shapes.registry import bounding_radii
        s.shape[::3] = POLY
        s.poly = rng.random((50, POLY_LEN))
        s.rbound = bounding_radii(s.axes, s.shape, s.poly)
    fields = ghost_fields(rec)
    idx = np.array([3, 0, 39, 17, 17, 21])
    halo = Halo.__new__(Halo)
    halo.store, halo.entries, halo.held = {}, {}, None
    records = halo._records(s, rec, idx, sum(WIDTH[f] for f in fields))
    assert np.array_equal(records.view(np.int64), _columns(s, fields, idx).view(np.int64))
    owned = {f: getattr(s, f).copy() for f in PER_PARTICLE}
    s.n_owned = 40
    for pick in (idx[:4], idx):
        drop_ghosts(s)
        halo._append(s, [None, (halo._records(s, rec, pick, records.shape[1]),)], rec)
        assert s.n == 40 + len(pick) and s.gid.base is halo.store["gid"]
        for f in PER_PARTICLE:
            want = owned[f][np.concatenate([np.arange(40), pick])]
            if f in ("force", "torque"):
                want[40:] = 0.0
            if rec == SPHERE and f == "quat":
                want[40:] = (1.0, 0.0, 0.0, 0.0)
            assert np.array_equal(getattr(s, f), want), f


@pytest.mark.parametrize("rec", [SPHERE, ELLIPSOID, POLY])
def test_border_messages_are_the_border_lists_records(rng, rec):
    """The direct exchange's fused ghost choice: pack_border_messages' message to each neighbour
    that exists is [count, the records pack_ghost_rows writes of border_lists' particles in that
    direction] and its send_idx those particles in neighbour order, bit for bit; the messages
    written back by write_border_messages after 40 owned rows give every per-particle array the
    rows write_ghost_rows gives, and each ghost its message's direction."""
    from dem.shapes import POLY_LEN
    from dem.shapes.registry import bounding_radii
    from modes.decomposition import NEEDS
    from modes.halo import pack_border_messages, pack_ghost_rows, write_border_messages, write_ghost_rows
    s = _state(rng, 60, rec == SPHERE)
    s.pos = rng.uniform(0.0, 1.0, (60, 3))
    if rec == POLY:
        s.shape[::3] = POLY
        s.poly = rng.random((60, POLY_LEN))
        s.rbound = bounding_radii(s.axes, s.shape, s.poly)
    ncol = sum(WIDTH[f] for f in ghost_fields(rec))
    lo, hi, w = np.zeros(3), np.ones(3), 0.3
    dirs = np.array([k for k, d in enumerate(DIRECTIONS) if d[2] == 0 and d[1] >= 0], dtype=np.int64)
    faces = face_bits(dirs)
    fields = (s.gid.view(np.float64), s.shape, s.material, s.mass, s.axes, s.inertia, s.pos, s.vel, s.angmom, s.quat,
              s.poly)
    buf, offs, send_idx, counts = pack_border_messages(40, lo, hi, w, NEEDS, faces, dirs, rec, ncol, *fields)
    start, items = border_lists(s.pos[:40], lo, hi, w, faces)
    want_idx = []
    for i, k in enumerate(dirs):
        idx = items[start[k]:start[k + 1]]
        want_idx.append(idx)
        rows = np.empty((len(idx), ncol))
        pack_ghost_rows(idx, rec, *fields[:10], s.poly, rows)
        assert counts[i] == len(idx) and buf[offs[i]] == len(idx)
        assert np.array_equal(buf[offs[i] + 1:offs[i + 1]].view(np.int64), rows.reshape(-1).view(np.int64)), k
    assert np.array_equal(send_idx, np.concatenate(want_idx)) and counts.sum() > 10
    m = int(counts.sum())
    # the first 20 rows of every per-particle array, then room for the m ghosts
    a, b = ([np.concatenate([getattr(s, f)[:20], np.zeros((m,) + getattr(s, f).shape[1:], getattr(s, f).dtype)])
             for f in PER_PARTICLE] for _ in range(2))
    ghost_dirs, got_counts = np.empty(m, dtype=np.int64), np.empty(len(dirs), dtype=np.int64)
    write_border_messages(20, buf, buf.view(np.int64), offs, dirs, ncol, rec, ghost_dirs, got_counts, *a)
    every = np.concatenate([buf[offs[i] + 1:offs[i + 1]].reshape(-1, ncol) for i in range(len(dirs))])
    write_ghost_rows(20, every, np.ascontiguousarray(every[:, 0]).view(np.int64), rec, *b)
    for f, x, y in zip(PER_PARTICLE, a, b):
        assert np.array_equal(x, y), f
    assert np.array_equal(got_counts, counts) and np.array_equal(ghost_dirs, np.repeat(dirs, counts))


@pytest.mark.parametrize("with_quat", [True, False])
def test_forward_message_round_trip(rng, with_quat):
    """pack_moving then unpack_moving writes rows idx of (pos, vel, angmom[, quat]) into rows g0..
    of another state bit for bit, and without quat leaves the orientation untouched."""
    n, g0 = 40, 30
    src = [rng.normal(size=(n, w)) for w in (3, 3, 3, 4)]
    idx = np.array([5, 1, 39, 8])
    buf = np.empty((len(idx), 13 if with_quat else 9))
    pack_moving(idx, *src, with_quat, buf)
    dst = [np.zeros((g0 + len(idx), w)) for w in (3, 3, 3, 4)]
    unpack_moving(buf, g0, *dst, with_quat)
    for a, b in zip(src[:3], dst[:3]):
        assert np.array_equal(b[g0:], a[idx]) and not b[:g0].any()
    if with_quat:
        assert np.array_equal(dst[3][g0:], src[3][idx])
    else:
        assert not dst[3].any()


def test_warm_up_kernels_stay_inside_their_arrays(tmp_path):
    """The MPI kernels' warm-up (modes.halo and modes.newton compile_kernels, which `bench run` calls
    in the launcher before it starts the ranks) compiled afresh with numba's bounds checks
    (NUMBA_BOUNDSCHECK=1): no index past an array. A ghost record written past a scene's narrower
    poly array once corrupted the launcher's heap ("corrupted double-linked list", or a silent
    SIGSEGV: 3 of 80 launches) while every result stayed right."""
    code = ("from modes.halo import compile_kernels; from modes.newton import compile_kernels as newton; "
            "compile_kernels(); newton()")
    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
