"""Threads mode: the paper's five schemes reproduce the serial trajectory bit for bit, and their
row assignment and work balance are what the schemes promise."""
import itertools
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from dem.forces import SPLIT, STORE
from dem.shapes import ELLIPSOID
from modes.parallel import (CONTACT_COST, DYNAMIC, PARTITION, SCHEMES, STATIC, WEIGHT_BLOCK, _offsets_by_row,
                            cut_at_equal_weight, cut_ranges, offsets_by_row_threads, scheme_rows,
                            split_pairs, wall_threads)
from modes.serial import SerialMode
from modes.threads import ThreadsMode
from tests.helpers import ROOT, bench, one_line_error

FIELDS = ("id", "pos", "quat", "vel", "omega")


def run(name, steps, n=None, threads=1, **kw):
    sc = load_prepared(name, particles=n)
    dt = choose_time_step(sc).dt
    mode = (ThreadsMode().setup(sc, dt=dt, threads=threads, **kw) if threads > 1 else
            SerialMode().setup(sc, dt=dt, **{k: v for k, v in kw.items() if k in ("neighbor", "skin")}))
    rows = [mode.step() for _ in range(steps)]
    return mode.snapshot(), rows


_REF = {}


def reference(name, steps, n, neighbor):
    key = (name, steps, n, neighbor)
    if key not in _REF:
        _REF[key] = run(name, steps, n, neighbor=neighbor)
    return _REF[key]


def assert_same(a, b):
    for f in FIELDS:
        assert np.array_equal(a[f], b[f]), f


@pytest.mark.parametrize("neighbor", ["allpairs", "linkcell"])
@pytest.mark.parametrize("threads", [2, 3])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_patch162_bit_identical(scheme, threads, neighbor):
    """patch162 (deposited ellipsoids, wall and particle contacts): every scheme, 2 and 3
    threads, both neighbour methods: the final state equals the serial one exactly."""
    ref, rows = reference("patch162", 150, None, neighbor)
    got, trows = run("patch162", 150, threads=threads, scheme=scheme, neighbor=neighbor)
    assert sum(r["n_contacts"] for r in rows) > 0
    assert [r["n_contacts"] for r in trows] == [r["n_contacts"] for r in rows]
    assert_same(ref, got)


@pytest.mark.parametrize("neighbor", ["allpairs", "linkcell"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_pluviation_bit_identical(scheme, neighbor):
    """A falling pluviation (200 ellipsoids) past the first particle-particle contacts (step ~8040):
    2 threads, every scheme, both neighbour methods, bit-identical to serial."""
    ref, rows = reference("pluviation", 9000, 200, neighbor)
    got, _ = run("pluviation", 9000, 200, threads=2, scheme=scheme, neighbor=neighbor)
    assert sum(r["n_contacts"] for r in rows) > 0
    assert_same(ref, got)


@pytest.mark.parametrize("shape", ["ellipsoid", "sphere"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_packed_bit_identical(scheme, shape, monkeypatch):
    """A packed assembly (coordination >= 4) of ellipsoids and of spheres (the sphere-only pair
    loop): 3 threads, every scheme, bit-identical to serial."""
    def go(threads):
        sc = load_prepared("packed", particles=400, shape=shape)
        dt = choose_time_step(sc).dt
        mode = ThreadsMode().setup(sc, dt=dt, threads=3, scheme=scheme) if threads > 1 else \
            SerialMode().setup(sc, dt=dt)
        for _ in range(30):
            mode.step()
        return mode.snapshot()
    assert_same(go(1), go(3))


def test_skin_and_detection_only_bit_identical():
    """Threads with a Verlet skin (list rebuilt and particles re-sorted during the fall), and with
    only contact detection threaded (the paper's situation), still match serial exactly."""
    ref, _ = reference("pluviation", 9000, 200, "linkcell")
    got, rows = run("pluviation", 9000, 200, threads=2, scheme="dynamic", skin=0.2)
    assert sum(r["neighbor_rebuilt"] for r in rows) > 3
    assert_same(ref, got)
    got, _ = run("pluviation", 9000, 200, threads=3, scheme="headtail", threaded="detection")
    assert_same(ref, got)


@pytest.mark.parametrize("split", [True, False])
@pytest.mark.parametrize("scheme", ["partition", "static", "dynamic"])
def test_split_ranges_sum_and_gather_bit_identical(scheme, split):
    """Threads over ranges of the gid-sorted pair list (split, the default): the particles whose
    pairs all lie in one range are summed by its thread as it resolves, the others gather; with
    split=False every pair's forces are stored and gathered. Both: the force and torque of every
    particle and the final state after 40 steps (packed 400 ellipsoids, 3 threads, the list built
    at step 1 with the pack's contact history) equal serial's exactly, and under split both kinds of particle
    occur (a test of the two paths, not of one)."""
    def go(threads):
        sc = load_prepared("packed", particles=400)
        dt = choose_time_step(sc).dt
        mode = ThreadsMode().setup(sc, dt=dt, threads=threads, scheme=scheme, split=split) if threads > 1 else \
            SerialMode().setup(sc, dt=dt)
        for _ in range(40):
            mode.step()
        s = mode.state
        order = np.argsort(s.gid[:s.n_owned])
        return mode, mode.snapshot(), s.force[order].copy(), s.torque[order].copy()
    ref, ref_snap, ref_f, ref_t = go(1)
    mode, snap, f, t = go(3)
    assert_same(ref_snap, snap)
    assert np.array_equal(ref_f, f) and np.array_equal(ref_t, t)
    if split:
        assert mode.deliver == SPLIT and 0 < int(mode.gat.sum()) < mode.state.n_owned
    else:
        assert mode.deliver == STORE


def test_dynamic_recuts_from_measured_times_bit_identical():
    """The dynamic scheme re-cuts its ranges when the threads' measured busy times differ
    (ThreadsMode.rebalance). The cut never changes a result: packed 400 ellipsoids, 3 threads, a
    re-cut forced every 7 steps with range weights scaled by (1.6, 0.7, 1.0), alternately reversed,
    so the cuts move both ways; after 40 steps force, torque and state equal serial's exactly."""
    def go(threads):
        sc = load_prepared("packed", particles=400)
        dt = choose_time_step(sc).dt
        mode = ThreadsMode().setup(sc, dt=dt, threads=threads, scheme="dynamic") if threads > 1 else \
            SerialMode().setup(sc, dt=dt)
        cuts = []
        for k in range(40):
            if threads > 1 and k and k % 7 == 0:
                mode.recut = np.array([1.6, 0.7, 1.0])[::1 if k % 14 else -1]
                cuts.append(mode.pairs.offsets.tolist())
            mode.step()
        s = mode.state
        order = np.argsort(s.gid[:s.n_owned])
        return mode, mode.snapshot(), s.force[order].copy(), s.torque[order].copy(), cuts
    _, ref_snap, ref_f, ref_t, _ = go(1)
    mode, snap, f, t, cuts = go(3)
    assert mode.recuts == 5 and len({tuple(c) for c in cuts}) == 5
    assert_same(ref_snap, snap)
    assert np.array_equal(ref_f, f) and np.array_equal(ref_t, t)


def test_rebalance_scales_weights_towards_measured_cost():
    """rebalance: a window of REBALANCE_WINDOW steps in which thread 0 was busy 2 units and thread 1
    one, over ranges of equal estimated weight, gives costs per weight 2:1, i.e. 4/3 and 2/3 of
    their mean, and weight factors half way there (REBALANCE_KEEP = 0.5): 7/6 and 5/6. Busy times
    within REBALANCE_ABOVE = 1.01 of each other (1.0 and 1.005, max/mean 1.0025) give none."""
    from modes import threads as th
    sc = load_prepared("packed", particles=400)
    mode = ThreadsMode().setup(sc, dt=choose_time_step(sc).dt, threads=2, scheme="dynamic")
    mode.step()
    mode.weights[:] = 1.0
    mode.pairs.offsets[:] = [0, 100, 200]
    for busy, want in (([2.0, 1.0], [7 / 6, 5 / 6]), ([1.0, 1.005], None)):
        mode.recut = None
        mode.window[:] = busy
        mode.window_n = th.REBALANCE_WINDOW
        mode.rebalance()
        assert (mode.recut is None) if want is None else np.allclose(mode.recut, want, rtol=1e-12, atol=0)
        assert mode.window_n == 0


@pytest.mark.parametrize("scheme", ["static", "dynamic"])
def test_every_step_lists_cut_at_equal_pairs(scheme):
    """With skin 0 (every step a rebuild) in a scene of one shape, every candidate pair's bounding
    spheres overlap (the list's reach is the bounding radius), so every pair weighs the same in the
    cut (static: 1; dynamic: the ellipsoid's CONTACT_COST) and the fresh cut is made at equal pairs
    with no pass over the pairs (ThreadsMode.weights holds the one weight). The ranges, the
    particles that gather and the home lists equal those of split_pairs' per-pair weights (equal
    shares: the same cut), and 40 steps of packed 400 ellipsoids at 3 threads, with re-cuts from
    unequal factors forced at two steps (the one weight becomes each pair's), equal serial's bit
    for bit."""
    sc = load_prepared("packed", particles=400)
    dt = choose_time_step(sc).dt
    ref = SerialMode().setup(sc, dt=dt, skin=0.0)
    mode = ThreadsMode().setup(sc, dt=dt, threads=3, scheme=scheme, skin=0.0)
    fresh_cut = mode.split
    due = []

    def split_then_recut(*args):   # a re-cut due at this step's resolution, after its fresh cut
        fresh_cut(*args)
        mode.recut = due.pop() if due else None

    mode.split = split_then_recut
    for k in range(40):
        ref.step()
        if k in (10, 25):
            due.append(np.array([1.2, 0.9, 0.9]))
        mode.step()
        if k == 0:
            code = SCHEMES.index(scheme)
            assert mode.weights == (1.0 if scheme == "static" else float(CONTACT_COST[ELLIPSOID]))
            s, p = mode.state, mode.pairs
            got = [np.zeros(4, dtype=np.int64), np.zeros(s.n_owned, dtype=np.int8), np.zeros(4, dtype=np.int64),
                   np.zeros(s.n_owned, dtype=np.int64)]
            want = [a.copy() for a in got]
            cut_ranges(None, 3, np.ones(3), p.pi, p.pj, s.gid, s.n_owned, *got)
            split_pairs(code, 3, np.ones(3), p.pi, p.pj, s.gid, s.n_owned, s.pos, s.rbound, s.shape, False, *want)
            assert 0 < got[0][1] < got[0][2] < p.m and got[1].sum() > 0
            assert all(np.array_equal(a, b) for a, b in zip(got, want))
    assert mode.recuts == 2 and isinstance(mode.weights, float)
    assert_same(ref.snapshot(), mode.snapshot())


def test_learn_speed_gives_the_next_fresh_cut_shares():
    """learn_speed, at a rebuild step: thread 0 busy 2 units and thread 1 one over ranges of equal
    estimated weight are costs per weight 2:1, 4/3 and 2/3 of their mean; from speeds (1, 1) half
    way there (REBALANCE_KEEP = 0.5): 7/6 and 5/6. The next fresh cut (a rebuild's split) gives
    thread t the share 1/speed[t] of the estimated weight: range 0 holds (6/7) / (6/7 + 6/5) =
    5/12 of it, to within the heaviest row (the cut falls at a row start). Packed 400 ellipsoids,
    2 threads, dynamic."""
    sc = load_prepared("packed", particles=400)
    mode = ThreadsMode().setup(sc, dt=choose_time_step(sc).dt, threads=2, scheme="dynamic")
    mode.step()
    m = mode.pairs.m
    mode.weights[:] = 1.0
    mode.pairs.offsets[:] = [0, m // 2, m]
    mode.busy_rows[:, 0] = [2_000_000 * (m // 2), 1_000_000 * (m - m // 2)]
    mode.speed[:] = 1.0  # the step above (a rebuild) learnt from its own times
    mode.learn_speed()
    assert np.allclose(mode.speed, [1.0 + 0.5 * (4 / 3 - 1), 1.0 + 0.5 * (2 / 3 - 1)], rtol=1e-9, atol=0)
    mode.split()  # a rebuild's fresh cut, by the learnt shares
    w, b, pi = mode.weights, mode.pairs.offsets, mode.pairs.pi
    heaviest = max(w[pi == r].sum() for r in np.unique(pi))
    assert abs(w[:b[1]].sum() - 5 / 12 * w.sum()) <= heaviest
    assert mode.recut is None


@pytest.mark.parametrize("code", [PARTITION, STATIC, DYNAMIC])
@pytest.mark.parametrize("threads", [1, 2, 3, 5])
@pytest.mark.parametrize("stored", ["reverse", "gid"])
def test_split_pairs_cuts_whole_rows_and_marks_shared_particles(code, threads, stored):
    """split_pairs on a random gid-sorted list of up to 600 pairs among particles 0..119 of 150 (30
    without pairs), stored in reverse gid order (the home lists by a counting sort) or in gid order
    (each range's home list from its interval of indices): the T ranges start at row starts and
    cover the list in order; gat[p] = 1 exactly for the particles that a range before their own
    (the range whose rows span gid[p]) holds as a pair's later end (by brute force), which takes in
    every particle with pairs in two ranges; every other particle is zeroed by exactly one range,
    its own, which holds all its pairs; static ranges hold m/T pairs to within one row."""
    _check_split(code, threads, stored, 150, 600, 30)


@pytest.mark.parametrize("stored", ["reverse", "gid"])
def test_split_marks_many_later_ends_by_the_threads(stored):
    """The same checks on 40000 pairs among 6000 particles, partners up to 400 gids apart, cut into
    16 ranges: most pairs cross a range's end, so the later ends (modes.parallel PLACE_THREADS_FROM
    and more) are marked by the threads (_mark_later_threads, bucketed by the range they lie in)
    where the particles are stored in gid order, and by the counting sort's path where they are not;
    both give the brute force's marks."""
    _check_split(STATIC, 16, stored, 6000, 40000, 400)


def _check_split(code, threads, stored, n, count, reach):
    rng = np.random.default_rng(7)
    top = n - 31
    i = rng.integers(0, top, count)
    j = np.minimum(i + rng.integers(1, reach, count), top)
    keys = np.unique(np.stack([i, j], axis=1), axis=0)
    keys = keys[keys[:, 0] < keys[:, 1]]
    if stored == "reverse":
        gid = np.arange(n)[::-1].copy()   # particle p has gid n-1-p: rows by gid, not by index
        pi, pj = n - 1 - keys[:, 0], n - 1 - keys[:, 1]
    else:
        gid = 3 * np.arange(n) + 5        # ascending, not the indices themselves
        pi, pj = keys[:, 0], keys[:, 1]
    assert np.all(gid[pi] < gid[pj])
    m = len(pi)
    if n > 150:   # enough later ends for the threads' marking
        from modes.parallel import PLACE_THREADS_FROM
        first = gid[pi[(np.arange(1, threads) * m) // threads]]
        assert np.sum(gid[pj] >= np.min(first)) >= PLACE_THREADS_FROM
    pos = rng.random((n, 3))
    rbound = np.full(n, 0.1)
    bounds = np.zeros(threads + 1, dtype=np.int64)
    gat = np.zeros(n, dtype=np.int8)
    home_start = np.zeros(threads + 1, dtype=np.int64)
    home_items = np.zeros(n, dtype=np.int64)
    split_pairs(code, threads, np.ones(threads), pi, pj, gid, n, pos, rbound, np.zeros(n, dtype=np.int8), False,
                bounds, gat, home_start, home_items)
    assert bounds[0] == 0 and bounds[-1] == m and np.all(np.diff(bounds) >= 0)
    assert all(b in (0, m) or pi[b] != pi[b - 1] for b in bounds)
    rng_of = np.searchsorted(bounds, np.arange(m), side="right") - 1
    first = [gid[pi[b]] if b < m else np.inf for b in bounds]
    own = [max([0] + [t for t in range(1, threads) if first[t] <= gid[p]]) for p in range(n)]
    ranges = [set() for _ in range(n)]
    later_end_before_own = np.zeros(n, dtype=np.int8)
    for k in range(m):
        ranges[pi[k]].add(rng_of[k])
        ranges[pj[k]].add(rng_of[k])
        if rng_of[k] < own[pj[k]]:
            later_end_before_own[pj[k]] = 1
    assert gat.tolist() == later_end_before_own.tolist()
    assert all(gat[p] == 1 for p in range(n) if len(ranges[p]) > 1)
    assert (gat.sum() > 0) == (threads > 1)
    assert home_start[threads] == n - gat.sum()
    zeroed = {}
    for t in range(threads):
        for p in home_items[home_start[t]:home_start[t + 1]]:
            assert p not in zeroed
            zeroed[int(p)] = t
    assert sorted(zeroed) == [p for p in range(n) if gat[p] == 0]
    assert all(zeroed[p] == own[p] and ranges[p] <= {own[p]} for p in zeroed)
    assert all(list(home_items[home_start[t]:home_start[t + 1]]) == sorted(home_items[home_start[t]:home_start[t + 1]])
               for t in range(threads))
    if code == STATIC:
        longest = np.max(np.unique(pi, return_counts=True)[1])
        assert np.all(np.abs(np.diff(bounds) - m / threads) <= longest)


@pytest.mark.parametrize("threads, nrow", [(1, 5), (2, 1000), (3, 7), (7, 2), (16, 300), (2, 40000), (16, 5000),
                                           (7, 10000)])
def test_offsets_by_row_threads_is_the_one_thread_prefix(threads, nrow):
    """The counting sorts' write offsets by T threads over blocks of rows (one thread below
    OFFSETS_THREADS_FROM = 65536 counts, the last three cases above it) equal one thread's walk:
    start[r] = the counts of rows before r, and each thread's first slot in row r after the
    threads before it (np.cumsum of the row-major counts)."""
    count = np.random.default_rng(threads).integers(0, 6, (threads, nrow))
    flat = np.concatenate([[0], np.cumsum(count.T.ravel())])
    want_slots = flat[:-1].reshape(nrow, threads).T
    one, many = count.copy(), count.copy()
    s1 = np.empty(nrow + 1, dtype=np.int64)
    s2 = np.full(nrow + 1, -1, dtype=np.int64)
    _offsets_by_row(one, nrow, s1)
    offsets_by_row_threads(many, nrow, s2)
    assert np.array_equal(s2, s1) and np.array_equal(s2, flat[::threads])
    assert np.array_equal(many, one) and np.array_equal(many, want_slots)


@pytest.mark.parametrize("threads", [2, 3, 7])
def test_cut_at_equal_weight_over_many_blocks(threads):
    """The cut over a list of ~10 WEIGHT_BLOCKs (the threads sum blocks, one walks the sums and looks
    inside the blocks a cut falls in) is the first row start whose preceding weight reaches t/T of
    the total, as one walk over every weight finds it. Weights are small integers, so every sum
    is exact and the two walks must agree to the index; rows of 1-12 pairs, some of weight 0."""
    rng = np.random.default_rng(3)
    rows = rng.integers(1, 13, 1500)
    pi = np.repeat(np.arange(len(rows)), rows).astype(np.int64)
    m = len(pi)
    assert m > 8 * WEIGHT_BLOCK
    w = rng.integers(0, 20, m).astype(np.float64)
    bounds = np.zeros(threads + 1, dtype=np.int64)
    cut_at_equal_weight(w, pi, False, threads, np.ones(threads), bounds)
    before = np.concatenate([[0.0], np.cumsum(w)[:-1]])
    starts = np.flatnonzero(np.concatenate([[True], pi[1:] != pi[:-1]]))
    want = [0] + [int(next((k for k in starts if before[k] >= t * w.sum() / threads), m))
                  for t in range(1, threads)] + [m]
    assert bounds.tolist() == want
    every = np.zeros(threads + 1, dtype=np.int64)
    cut_at_equal_weight(w, pi[:0], True, threads, np.ones(threads), every)
    assert every.tolist() == [0] + [int(np.argmax(before >= t * w.sum() / threads)) for t in range(1, threads)] + [m]


def _cut_spheres_then_ellipsoids(code, n_owned, taken):
    """split_pairs on 2 threads over 100 sphere pairs (rows 0..99) then 100 ellipsoid pairs (rows
    100..199), all touching, one pair a row (pi = 0, 2, ..., 398, pj = pi + 1), particles
    n_owned.. ghosts: the cut [0, c, 200]."""
    n = 400
    pi = np.arange(0, 400, 2)
    pj = pi + 1
    pos = np.zeros((n, 3))
    pos[:, 0] = np.arange(n) * 1e-3
    rbound = np.full(n, 1e-3)
    shape = np.where(np.arange(n) < 200, 0, 1).astype(np.int8)
    bounds = np.zeros(3, dtype=np.int64)
    split_pairs(code, 2, np.ones(2), pi, pj, np.arange(n), n_owned, pos, rbound, shape, taken, bounds,
                np.zeros(n_owned, dtype=np.int8), np.zeros(3, dtype=np.int64), np.zeros(n_owned, dtype=np.int64))
    return bounds.tolist()


def test_dynamic_split_weighs_ellipsoid_pairs_above_sphere_pairs():
    """The dynamic scheme cuts by estimated cost (modes.parallel CONTACT_COST, the registered shapes'
    contact_cost: an overlapping sphere pair weighs 10, one with an ellipsoid 40, from resolve_range
    timings):
    100 sphere pairs (rows 0..99) then 100 ellipsoid pairs (rows 100..199), all touching, one pair
    a row, on 2 threads: half the cost is 2500 = 100 x 10 + 37.5 x 40, so thread 0 takes the 100
    sphere pairs and 38 ellipsoid pairs (the row where the cost first reaches 2500), thread 1 the
    other 62, where equal pairs (static) would cut at 100."""
    assert _cut_spheres_then_ellipsoids(DYNAMIC, 400, False) == [0, 138, 200]
    assert _cut_spheres_then_ellipsoids(STATIC, 400, False) == [0, 100, 200]


def test_dynamic_split_weighs_taken_cross_pairs_one():
    """Under hybrid with Newton's third law a pair with a ghost end is not resolved but its terms
    taken (dem.forces, SPLIT_TAKEN), so the dynamic cut weighs it 1 (modes.parallel.split_pairs,
    taken). The list of the test above with particles 301.. ghosts: pairs 150..199 (pi = 300..398)
    cross. Cost 100 x 10 + 50 x 40 + 50 x 1 = 3050, half 1525, first reached after 14 ellipsoid
    pairs (1000 + 14 x 40 = 1560): cut at pair 114. Without taken, the cut of the test above, 138."""
    assert _cut_spheres_then_ellipsoids(DYNAMIC, 301, True) == [0, 114, 200]
    assert _cut_spheres_then_ellipsoids(DYNAMIC, 301, False) == [0, 138, 200]


def test_finish_blocks_are_cut_at_equal_estimated_cost():
    """The per-particle pass is cut by estimated cost, with the wall list (modes.parallel
    wall_threads, which also copies the owned positions into the list's reference: a sphere 1, an
    ellipsoid 2.4, on the wall list + 0.15 and + 2.2, from finish_range timings). 100 spheres then
    100 ellipsoids, none near a wall, 2 threads: half the cost is (100 + 240) / 2 = 170, first reached
    after the 100 spheres and 30 ellipsoids (172), so the cut is at 130. All near a wall: half of
    100 x 1.15 + 100 x 4.6 is 287.5, first reached after 100 spheres and 38 ellipsoids (289.8): 138.
    Equal weights give blocks equal to within one particle."""
    from dem.state import HIST_LEN

    def finish_cuts(t, n, shape, near_wall, cuts):
        # one wall plane x = +-10 (normal +x), particles on a line at x < 1 with reach 1: every
        # particle on the wall list (plane beyond them: distance below 0) or none (distance 9 up)
        pos = np.zeros((n, 3))
        pos[:, 0] = np.linspace(0.0, 0.9, n)
        near, ref = np.full(n, 5, dtype=np.int8), np.full((n, 3), np.nan)
        count = wall_threads(t, n, pos, np.ones(n), np.array([[1.0, 0.0, 0.0]]),
                             np.array([10.0 if near_wall else -10.0]), np.zeros((n, 1, HIST_LEN)), near,
                             np.zeros(0, dtype=np.int8), shape, cuts, ref)
        assert count == (n if near_wall else 0) and np.all(near == int(near_wall)) and np.array_equal(ref, pos)

    shape = np.where(np.arange(200) < 100, 0, 1).astype(np.int8)
    cuts = np.zeros(3, dtype=np.int64)
    finish_cuts(2, 200, shape, False, cuts)
    assert cuts.tolist() == [0, 130, 200]
    finish_cuts(2, 200, shape, True, cuts)
    assert cuts.tolist() == [0, 138, 200]
    for n, t in ((7, 3), (100, 2), (101, 4)):
        cuts = np.zeros(t + 1, dtype=np.int64)
        finish_cuts(t, n, np.ones(n, dtype=np.int8), False, cuts)
        assert cuts[0] == 0 and cuts[-1] == n and np.all(np.abs(np.diff(cuts) - n / t) <= 1)


@pytest.mark.parametrize("scheme", ["dynamic", "partition", "frogleap"])
def test_mixed_crystal_bit_identical(scheme):
    """The built-in mixed crystal (2000 spheres beside 2000 ellipsoids, all touching, walls), where
    the dynamic split and the per-particle blocks fall away from the middle: 20 steps on 2
    threads equal the serial ones exactly, contacts step by step too."""
    ref, rows = reference("mixed", 20, None, "linkcell")
    got, trows = run("mixed", 20, threads=2, scheme=scheme, neighbor="linkcell")
    assert min(r["n_contacts"] for r in rows) > 7000
    assert [r["n_contacts"] for r in trows] == [r["n_contacts"] for r in rows]
    assert_same(ref, got)


@pytest.mark.parametrize("scheme", ["partition", "frogleap", "headtail"])
@pytest.mark.parametrize("n", [0, 1, 7, 100, 101])
@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_scheme_rows_cover_each_row_once(scheme, n, threads):
    """Each explicit scheme hands every outer row to exactly one thread."""
    start, rows = scheme_rows(scheme, n, threads)
    assert len(start) == threads + 1 and start[0] == 0 and start[-1] == n
    assert sorted(rows.tolist()) == list(range(n))


def test_scheme_row_patterns():
    """The patterns of the paper (§4.2): partition = contiguous blocks, frogleap = stride T,
    headtail = pairs (k, n-1-k) for k = t, t+T, ..."""
    s, r = scheme_rows("partition", 10, 2)
    assert r[s[0]:s[1]].tolist() == [0, 1, 2, 3, 4] and r[s[1]:s[2]].tolist() == [5, 6, 7, 8, 9]
    s, r = scheme_rows("frogleap", 10, 3)
    assert r[s[1]:s[2]].tolist() == [1, 4, 7]
    s, r = scheme_rows("headtail", 10, 2)
    assert r[s[0]:s[1]].tolist() == [0, 9, 2, 7, 4, 5] and r[s[1]:s[2]].tolist() == [1, 8, 3, 6]


def test_allpairs_work_imbalance():
    """On the triangular all-pairs loop (row u tests n-1-u partners), partition at 2 threads makes
    thread 0 do sum_{u < n/2} (n-1-u) tests: max/mean -> 1.5 for large n (3/4 of the work against
    a mean of 1/2); frogleap and headtail balance it to ~1.0. Work = pair tests actually made."""
    sc = load_prepared("packed", particles=400)
    n = sc.n
    dt = choose_time_step(sc).dt
    expect = {"partition": sum(n - 1 - u for u in range(n // 2)) / (n * (n - 1) / 4)}
    for scheme, lo, hi in (("partition", expect["partition"] - 1e-9, expect["partition"] + 1e-9),
                           ("frogleap", 1.0, 1.01), ("headtail", 1.0, 1.01)):
        m = ThreadsMode().setup(sc, dt=dt, threads=2, scheme=scheme, neighbor="allpairs")
        m.neighbour_phase()
        assert m.tests.sum() == n * (n - 1) // 2
        assert lo <= m.work_imbalance <= hi, (scheme, m.work_imbalance)
    assert 1.49 < expect["partition"] < 1.51


def test_dynamic_hands_out_all_rows():
    """dynamic: the atomic counter hands out every row exactly once (the pair tests sum to the
    serial count) whichever thread takes them."""
    sc = load_prepared("packed", particles=400)
    m = ThreadsMode().setup(sc, dt=choose_time_step(sc).dt, threads=3, scheme="dynamic", neighbor="allpairs")
    m.neighbour_phase()
    assert m.tests.sum() == sc.n * (sc.n - 1) // 2


def test_run_records_threads(tmp_path):
    """bench run with 1-1-1-1-2: run.json records threads, scheme, layer and pinning; steps.csv
    carries the load-imbalance and NSF columns."""
    out = tmp_path / "t"
    res = bench("run", "--scene", "patch162", "--mapping", "1-1-1-1-2", "--scheme", "headtail", "--steps", "20",
                "--pin", "--out", str(out))
    assert res.returncode == 0, res.stderr
    info = json.loads((out / "run.json").read_text())
    assert info["threads"] == 2 and info["scheme"] == "headtail" and info["pin"] is True
    assert info["threading_layer"] in ("omp", "tbb", "workqueue")
    assert info["threading"]["NUMBA_NUM_THREADS"] == 2
    # --pin binds through bench.run.binding (no OMP_PROC_BIND, which pinned launchers to one CPU):
    # on the 2-CPU machines of CI thread 0 alone on CPU 0 and thread 1 on CPU 1 (plan_binding)
    if os.sched_getaffinity(0) == {0, 1}:
        threads = info["affinity"]["ranks"][0]["threads"]
        assert [(t["cpus"], t["ran_on"]) for t in threads] == [([0], 0), ([1], 1)]
    assert info["affinity"]["pinned"] is True and info["affinity"]["held"] is True
    import pandas as pd
    steps = pd.read_csv(out / "steps.csv")
    assert {"imbalance", "work_imbalance", "busy_max", "nsf"} <= set(steps.columns)
    assert (steps["imbalance"] >= 1.0).all()


@pytest.mark.parametrize("args,words", [
    (["--mapping", "1-1-1-1-2", "--scheme", "roundrobin"], "unknown scheme 'roundrobin'"),
    (["--scheme", "dynamic"], "needs a mapping with more than one thread"),
    (["--mapping", "1-1-1-1-0"], "T must be >= 1"),
    (["--mapping", "1-1-1-1--2"], "malformed mapping"),
])
def test_bad_thread_options(tmp_path, args, words):
    one_line_error(bench("run", "--scene", "patch162", "--steps", "1", "--out", str(tmp_path / "o"), *args), words)


@pytest.mark.skipif(len(os.sched_getaffinity(0)) >= 4, reason="needs fewer than 4 usable CPUs")
def test_oversubscription_warns_in_one_line(tmp_path):
    res = bench("run", "--scene", "patch162", "--steps", "2", "--mapping", "1-1-1-1-4", "--out", str(tmp_path / "o"))
    assert res.returncode == 0, res.stderr
    lines = [l for l in res.stderr.splitlines() if "oversubscribes" in l]
    assert len(lines) == 1


def test_threads_placing_counts_as_carry():
    """bench perf --what phases compares the serial and the threads' rebuild phase by phase: the
    list put in gid order and its history carry count as `carry` wherever they run. The serial
    mode sorts and carries in PairList.set (between build_list's clock reads t2 and t3); the
    threads place the list and carry as they go inside find_pairs (t1..t2), which times that part
    (placing_s) and moves it to carry. With a clock that ticks 1 per read (the rebuild reads it
    at t0..t6, the threads twice more around the placing) the threads' phases are derive 1,
    find_pairs 3 - 1 = 2, carry 1 + 1 = 2 and 1 each for the wall list, cut and gather; the
    serial mode's 1 each, with nothing moved."""
    sc = load_prepared("packed", particles=400)
    dt = choose_time_step(sc).dt
    for mode, want, placing in ((ThreadsMode().setup(sc, dt=dt, threads=2, scheme="dynamic", skin=0.0),
                                 {"derive": 1, "find_pairs": 2, "carry": 2, "wall_list": 1, "cut": 1,
                                  "gather_list": 1}, 1),
                                (SerialMode().setup(sc, dt=dt, skin=0.0),
                                 {"derive": 1, "find_pairs": 1, "carry": 1, "wall_list": 1, "cut": 1,
                                  "gather_list": 1}, 0)):
        mode.step()
        ticks = itertools.count()
        mode.clock = lambda: float(next(ticks))
        mode.build_list()
        assert mode.build_phases == want
        assert mode.placing_s == placing


_MANY_THREADS = """
import sys
import numpy as np
from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from modes.parallel import block_shift
from modes.serial import SerialMode
from modes.threads import ThreadsMode
dt = choose_time_step(load_prepared("packed", particles=400)).dt
ref = SerialMode().setup(load_prepared("packed", particles=400), dt=dt, skin=0.0)
for _ in range(15):
    ref.step()
want = ref.snapshot()
print("shift", block_shift(400, 9))
for scheme in ("dynamic", "frogleap"):
    mode = ThreadsMode().setup(load_prepared("packed", particles=400), dt=dt, threads=9, scheme=scheme, skin=0.0)
    for _ in range(15):
        mode.step()
    got = mode.snapshot()
    print(scheme, all(np.array_equal(got[f], want[f]) for f in ("id", "pos", "quat", "vel", "omega")))
"""


def test_nine_threads_place_by_blocks_of_rows():
    """Beyond PLACE_ROWS_THREADS (8) threads the list is placed by blocks of several rows
    (modes.parallel.block_shift: 400 rows at 9 threads in 100 blocks of 4, at most 16 T = 144):
    packed 400 at 9 threads, skin 0 (a rebuild every step, each after the first carrying the
    history), the dynamic and the frogleap scheme, equals the serial trajectory bit for bit.
    Its own process: numba's pool is sized before it starts (NUMBA_NUM_THREADS). Each mode loads
    the scene afresh: a mode steps the scene's arrays in place."""
    res = subprocess.run([sys.executable, "-c", _MANY_THREADS], capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, PYTHONPATH=ROOT, NUMBA_NUM_THREADS="9", OMP_WAIT_POLICY="PASSIVE"))
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["shift", "2", "dynamic", "True", "frogleap", "True"]
