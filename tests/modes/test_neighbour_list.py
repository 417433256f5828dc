"""The neighbour list with a skin (issue 11): kept between rebuilds with its contact history,
rebuilt when a particle has moved half the skin, bit-identical to the paper's every-step estimate
in every mode, and a step between rebuilds that allocates nothing."""

import numpy as np
import pytest

from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from dem.pairs import (DEFAULT_SKIN, PairList, adjacency_in_order, history_from_csr, history_to_csr,
                       gid_ranks, pair_adjacency, pair_adjacency_of, sort_by_gid, sort_pairs_by_gid, sorted_view)
from modes.parallel import (COUNT_PAD, adjacency_in_order_threads, adjacency_marked_threads, block_shift,
                            place_by_gid)
from modes.serial import SerialMode
from modes.threads import ThreadsMode

FIELDS = ("id", "pos", "quat", "vel", "omega")


def run(scene, steps, mode=SerialMode, **options):
    m = mode().setup(scene, dt=choose_time_step(scene).dt, **options)
    rows = [m.step() for _ in range(steps)]
    return m, m.snapshot(), rows


def same(a, b):
    return all(np.array_equal(a[f], b[f]) for f in FIELDS)


@pytest.mark.parametrize("name,n,steps,shape", [("patch162", None, 300, None), ("pluviation", 200, 6000, None),
                                                ("gas", None, 1500, None), ("packed", 300, 200, "sphere"),
                                                ("packed", 300, 150, "polyellipsoid")])
def test_skin_bit_identical_to_every_step_estimate(name, n, steps, shape):
    """Skins 0.05, 0.1 (the default) and 0.4 of the largest bounding diameter give the trajectory of
    the every-step estimate (skin 0) bit for bit: the list is a superset of the touching pairs
    while no particle has moved half the skin, the narrow phase decides contact exactly, and the
    history crosses each rebuild through the per-particle rows keyed by partner gid."""
    _, ref, rows0 = run(load_prepared(name, particles=n, shape=shape), steps, skin=0.0)
    assert sum(r["n_contacts"] + r["n_wall_contacts"] for r in rows0) > 0
    assert all(r["neighbor_rebuilt"] == 1 for r in rows0)
    for skin in (0.05, DEFAULT_SKIN, 0.4):
        m, got, rows = run(load_prepared(name, particles=n, shape=shape), steps, skin=skin)
        assert [r["n_contacts"] for r in rows] == [r["n_contacts"] for r in rows0], skin
        assert same(ref, got), skin
        assert m.pairs.rebuilds == sum(r["neighbor_rebuilt"] for r in rows) < steps


@pytest.mark.parametrize("mode,options", [(SerialMode, {}), (ThreadsMode, dict(threads=2, scheme="dynamic")),
                                          (ThreadsMode, dict(threads=2, scheme="frogleap"))])
@pytest.mark.parametrize("name,n,steps,shape", [("patch162", None, 300, None), ("packed", 300, 200, "sphere"),
                                                ("packed", 300, 150, "polyellipsoid")])
def test_rebuild_derives_only_what_the_pass_did_not(mode, options, name, n, steps, shape):
    """A rebuild derives the rotation matrices and angular velocities (and a poly-ellipsoid scene's
    octant geometry) only of particles the last step's per-particle pass did not derive: in the
    serial and thread modes, where particles never leave, none after the first step. The pass and
    the rebuild derive each particle with the same function (dem.integrate derive_particle), so the
    trajectory at skin 0 (a rebuild every step) equals, bit for bit, the one in which every
    rebuild derives every particle again (owned_derived cleared before each step)."""
    scene = load_prepared(name, particles=n, shape=shape)
    dt = choose_time_step(scene).dt
    skip = mode().setup(scene, dt=dt, skin=0.0, **options)
    full = mode().setup(load_prepared(name, particles=n, shape=shape), dt=dt, skin=0.0, **options)
    contacts = 0
    for _ in range(steps):
        row = skip.step()
        full.owned_derived = False
        assert full.step()["n_contacts"] == row["n_contacts"]
        contacts += row["n_contacts"]
        assert skip.owned_derived   # so its next rebuild derives none of the owned particles
    assert contacts > 0
    assert same(skip.snapshot(), full.snapshot())


def test_rebuild_exactly_when_half_the_skin_is_used():
    """The list is rebuilt on the step after the largest displacement since the last build reaches
    skin/2 and on no other (the gas: particles fly at 0.5 m/s, so the list is rebuilt many times)."""
    sc = load_prepared("gas")
    m = SerialMode().setup(sc, dt=choose_time_step(sc).dt, skin=0.1)
    half2 = (0.5 * m.skin) ** 2
    due = True
    rebuilds = 0
    for _ in range(1500):
        row = m.step()
        assert row["neighbor_rebuilt"] == int(due)
        rebuilds += row["neighbor_rebuilt"]
        s = m.state
        due = float(np.max(np.sum((s.pos[:s.n_owned] - m.pairs.ref) ** 2, axis=1))) >= half2
    assert rebuilds > 5


_GAS = []


def _gas_reference():
    if not _GAS:
        _GAS.append(run(load_prepared("gas"), 1500, skin=0.0))
    return _GAS[0]


@pytest.mark.parametrize("scheme", ["partition", "frogleap", "headtail", "static", "dynamic"])
@pytest.mark.parametrize("threads", [2, 3])
def test_threads_with_skin_bit_identical(scheme, threads):
    """Every scheme at 2 and 3 threads, with the default skin, across the rebuilds of a granular
    gas, reproduces the serial every-step trajectory."""
    _, ref, _ = _gas_reference()
    m, got, rows = run(load_prepared("gas"), 1500, mode=ThreadsMode, threads=threads, scheme=scheme)
    assert sum(r["neighbor_rebuilt"] for r in rows) > 3
    assert same(ref, got)


def test_history_survives_rebuilds():
    """Contact history (tangential springs) crosses every rebuild: the per-particle rows written
    from the list at a rebuild give every touching pair back its own record."""
    sc = load_prepared("packed", particles=300)
    m = SerialMode().setup(sc, dt=choose_time_step(sc).dt, skin=0.1)
    for _ in range(5):
        m.step()
    p, s = m.pairs, m.state
    m.sync_history()
    hist = np.zeros_like(p.hist)
    on = np.zeros_like(p.on)
    history_from_csr(p.pi, p.pj, s.gid, s.n_owned, s.hist_start, s.hist_partner, s.hist_val, hist, on)
    assert on.sum() > 100 and np.array_equal(on, p.on)
    assert np.array_equal(hist[on == 1], p.hist[p.on == 1])


def test_adjacency_sorted_by_partner_gid(rng):
    """The gather adjacency lists each owned particle's pairs in ascending partner gid, whatever
    the order of the pair list (the summation order of DESIGN.md's determinism rule); an entry is
    2 k + 1 where the particle is pair k's j end, 2 k where it is the i end."""
    n, m = 40, 300
    gid = rng.permutation(1000)[:n].astype(np.int64)
    a = rng.integers(0, n, m)
    b = rng.integers(0, n, m)
    keep = a != b
    pairs = {(min(x, y, key=lambda i: gid[i]), max(x, y, key=lambda i: gid[i])) for x, y in zip(a[keep], b[keep])}
    pi = np.array([p[0] for p in pairs], dtype=np.int64)
    pj = np.array([p[1] for p in pairs], dtype=np.int64)
    start, items = pair_adjacency(pi, pj, gid, n)
    for q in range(n):
        es = items[start[q]:start[q + 1]]
        assert all((pj[e >> 1] if e & 1 else pi[e >> 1]) == q for e in es)
        partners = [gid[pi[e >> 1]] if e & 1 else gid[pj[e >> 1]] for e in es]
        assert partners == sorted(partners)
        assert len(es) == int(np.sum(pi == q) + np.sum(pj == q))



@pytest.mark.parametrize("stored", ["sorted", "ghost tail"])
def test_adjacency_in_order_needs_no_sort(rng, stored):
    """Filled in the list's (gid_i, gid_j) order, each row of the adjacency comes out in ascending
    partner gid with no sort (a particle's pairs as the j end, whose partners have lower gids, come
    before its own run as the i end): dem.pairs.adjacency_in_order and modes.parallel's at 1-3
    threads must equal pair_adjacency (fill in any order, then sort each row) array for array, for
    a sorted list (order None) and for the same pairs shuffled and seen through their sorted view,
    with the particles stored in gid order or not (ghosts after the owned ones, as under MPI)."""
    n, n_owned = 90, 70
    gid = np.sort(rng.permutation(900)[:n]).astype(np.int64)
    if stored == "ghost tail":
        gid[n_owned:] = rng.permutation(gid[n_owned:])
    pi, pj = _random_pairs(rng, n, 600, gid)
    o = np.lexsort((gid[pj], gid[pi]))
    pi, pj = pi[o], pj[o]
    shuffle = rng.permutation(len(pi))
    qi, qj = pi[shuffle], pj[shuffle]
    view = sorted_view(qi, qj, gid)
    for (ai, aj), args in (((pi, pj), (pi, pj, None)), ((qi, qj), view)):
        ref = pair_adjacency(ai, aj, gid, n_owned)
        assert len(ref[1]) > 0
        got = [adjacency_in_order(*args, n_owned)] + [adjacency_in_order_threads(t, *args, n_owned) for t in (1, 2, 3)]
        for start, items in got:
            assert np.array_equal(start, ref[0]) and np.array_equal(items, ref[1])


def _block_counts(threads, pi_t, offsets, rank, shift, n):
    """The scan's counts for modes.parallel.place_by_gid: each thread's pairs per block of 2^shift
    rows (the rank of the first end), rows padded apart, the padding holding junk the placing
    must not read."""
    nb = ((n - 1) >> shift) + 1
    count = np.full((threads, nb + COUNT_PAD), 99, dtype=np.int64)
    for t in range(threads):
        count[t, :nb] = np.bincount(rank[pi_t[t, :offsets[t + 1] - offsets[t]]] >> shift, minlength=nb)
    return count


def _keys(spi, spj, gid):
    """The pairs' keys as dem.pairs.pair_key defines them, gid_i 2^32 + gid_j, by numpy (the merge's
    own keys and the old list's it reads)."""
    return (gid[spi].astype(np.int64) << 32) + gid[spj]


def _random_pairs(rng, n, m, gid):
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    keep = a != b
    pairs = sorted({(x, y) if gid[x] < gid[y] else (y, x) for x, y in zip(a[keep], b[keep])})
    return np.array([q[0] for q in pairs], dtype=np.int64), np.array([q[1] for q in pairs], dtype=np.int64)


@pytest.mark.parametrize("by_gid", [True, False])
def test_history_carried_by_gid_across_a_permutation(rng, by_gid):
    """A rebuild carries each surviving touching pair's history row to the new list by the pair's
    global ids, whatever happened to memory order in between: the particles are permuted, a third
    of the old pairs are dropped and new ones appear. The result must equal, bit for bit, the path
    through the per-particle CSR (history_to_csr then history_from_csr) that migration uses; a
    pair new to the list, or one that was not touching, starts without history (on = 0). Each list
    keeps its pairs' keys gid_i 2^32 + gid_j in gid order (dem.pairs.pair_key), which the next
    carry reads in place of the old list's ids."""
    n = 60
    gid = rng.permutation(500)[:n].astype(np.int64)
    pos = np.zeros((n, 3))
    old = PairList(16)
    pi, pj = _random_pairs(rng, n, 400, gid)
    bi, bj = old.buffers(len(pi))
    bi[:len(pi)], bj[:len(pi)] = pi, pj
    empty = (np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 8)))
    old.set(len(pi), gid, n, *empty, pos, by_gid=by_gid)
    assert np.array_equal(old.key, _keys(*old.view[:2], gid))   # the keys the next carry reads
    old.hist[:] = rng.standard_normal(old.hist.shape)
    old.on[:] = rng.integers(0, 2, old.m)
    csr = old.history(gid, n)
    # the particles move in memory; the new list keeps 2/3 of the old pairs (by ids) and adds others
    perm = rng.permutation(n)
    gid2 = gid[perm]
    inv = np.argsort(perm)
    keep = rng.random(old.m) < 2 / 3
    qi, qj = inv[old.pi[keep]], inv[old.pj[keep]]
    ri, rj = _random_pairs(rng, n, 100, gid2)
    both = {(int(x), int(y)) for x, y in zip(qi, qj)} | {(int(x), int(y)) for x, y in zip(ri, rj)}
    new = np.array(sorted(both), dtype=np.int64)
    new = new[rng.permutation(len(new))]
    m = len(new)
    bi, bj = old.buffers(m)
    bi[:m], bj[:m] = new[:, 0], new[:, 1]
    # the CSR path over the permuted particles: rows follow their particle
    counts = np.diff(csr[0])[perm]
    hs = np.zeros(n + 1, dtype=np.int64)
    hs[1:] = np.cumsum(counts)
    rows = np.concatenate([np.arange(csr[0][q], csr[0][q + 1]) for q in perm]).astype(np.int64)
    hp, hv = csr[1][rows], csr[2][rows]
    hist_csr = np.zeros((m, 8))
    on_csr = np.zeros(m, dtype=np.int8)
    old.set(m, gid2, n, *empty, pos, by_gid=by_gid, carry=True)
    history_from_csr(old.pi, old.pj, gid2, n, hs, hp, hv, hist_csr, on_csr)
    assert 0 < on_csr.sum() < m
    assert np.array_equal(old.on, on_csr)
    assert np.array_equal(old.hist[on_csr == 1], hist_csr[on_csr == 1])
    assert np.array_equal(old.key, _keys(*old.view[:2], gid2))


@pytest.mark.parametrize("by_gid", [True, False])
def test_leavers_rows_and_arrivals_override_the_carry(rng, by_gid):
    """Migration (MPI) writes rows only for the particles that leave: leaver_history_csr must give,
    for each marked particle, exactly the rows of the full CSR (history_to_csr: touching pairs,
    ascending partner gid) and empty rows for the others. At the next build, a pair whose owned
    end has rows (it arrived with them) takes them, every other pair the carry from the old list."""
    n = 60
    gid = rng.permutation(500)[:n].astype(np.int64)
    pos = np.zeros((n, 3))
    empty = (np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 8)))
    lst = PairList(16)
    pi, pj = _random_pairs(rng, n, 400, gid)
    bi, bj = lst.buffers(len(pi))
    bi[:len(pi)], bj[:len(pi)] = pi, pj
    lst.set(len(pi), gid, n, *empty, pos, by_gid=by_gid)
    lst.hist[:] = rng.standard_normal(lst.hist.shape)
    lst.on[:] = rng.integers(0, 2, lst.m)
    full = history_to_csr(*pair_adjacency(lst.pi, lst.pj, gid, n), lst.pi, lst.pj, gid, lst.on, lst.hist, n)
    leaving = (rng.random(n) < 0.3).astype(np.int8)
    part = lst.history(gid, n, leaving)
    assert 0 < leaving.sum() < n and len(part[1]) > 0
    for p in range(n):
        got = slice(part[0][p], part[0][p + 1])
        if not leaving[p]:
            assert part[0][p + 1] == part[0][p]
            continue
        ref = slice(full[0][p], full[0][p + 1])
        assert np.array_equal(part[1][got], full[1][ref]) and np.array_equal(part[2][got], full[2][ref])
    # rows for the marked particles (arrived) with values of their own: those pairs take them
    rows_val = part[2] + 1.0
    old_hist, old_on = lst.hist.copy(), lst.on.copy()
    order = (lst.pi.copy(), lst.pj.copy())
    m = lst.m
    bi, bj = lst.buffers(m)
    bi[:m], bj[:m] = order
    lst.set(m, gid, n, part[0], part[1], rows_val, pos, by_gid=by_gid, carry=True, rows=True)
    own = np.where(lst.pi < n, lst.pi, lst.pj)  # every end is owned here: the i end
    key = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(*order))}
    taken = 0
    for k in range(m):
        k0 = key[(int(lst.pi[k]), int(lst.pj[k]))]
        if leaving[own[k]]:
            p, partner = own[k], gid[lst.pj[k]]
            r = [r for r in range(part[0][p], part[0][p + 1]) if part[1][r] == partner]
            assert lst.on[k] == (1 if r else 0)
            if r:
                assert np.array_equal(lst.hist[k], rows_val[r[0]])
                taken += 1
        else:
            assert lst.on[k] == old_on[k0]
            if old_on[k0]:
                assert np.array_equal(lst.hist[k], old_hist[k0])
    assert taken > 0


def test_carry_by_ranges_equals_one_merge(rng):
    """Threads carry a rebuild's history over T ranges of the new list, each merge starting at a
    binary search in the old one (dem.pairs.carry_history_sorted_range over each range, as
    modes.parallel.place_by_gid runs it over each thread's rows): the rows and flags must equal one
    thread's merge (dem.pairs.carry_history_sorted) bit for bit, for T = 1..5, including ranges
    that start on a pair absent from the old list. Lists kept in another order (STORE schemes)
    carry through their sorted views (dem.pairs.sorted_view): both lists shuffled, each pair must
    get the row it gets in the sorted carry."""
    from dem.pairs import carry_history_sorted, carry_history_sorted_range

    def carry_threads(threads, spi, *rest):   # T contiguous ranges of the new list's sorted order
        m = spi.shape[0]
        for t in range(threads):
            carry_history_sorted_range(t * m // threads, (t + 1) * m // threads, spi, *rest)
    n = 90
    gid = rng.permutation(700)[:n].astype(np.int64)
    def sorted_pairs(m):
        pi, pj = _random_pairs(rng, n, m, gid)
        o = np.lexsort((gid[pj], gid[pi]))
        return pi[o], pj[o]
    opi, opj = sorted_pairs(700)
    ohist = rng.standard_normal((len(opi), 8))
    oon = rng.integers(0, 2, len(opi)).astype(np.int8)
    keep = rng.random(len(opi)) < 0.7
    qi, qj = sorted_pairs(200)
    both = sorted({(int(a), int(b)) for a, b in zip(opi[keep], opj[keep])} | {(int(a), int(b)) for a, b in zip(qi, qj)},
                  key=lambda q: (gid[q[0]], gid[q[1]]))
    pi = np.array([q[0] for q in both], dtype=np.int64)
    pj = np.array([q[1] for q in both], dtype=np.int64)
    ref_hist, ref_on, key = np.zeros((len(pi), 8)), np.zeros(len(pi), dtype=np.int8), np.zeros(len(pi), np.int64)
    carry_history_sorted(pi, pj, gid, None, key, _keys(opi, opj, gid), None, oon, ohist, ref_hist, ref_on)
    assert 0 < ref_on.sum() < len(pi)
    assert np.array_equal(key, _keys(pi, pj, gid))
    for threads in range(1, 6):
        hist, on = np.full((len(pi), 8), np.nan), np.full(len(pi), 7, dtype=np.int8)
        key = np.full(len(pi), -1, dtype=np.int64)
        carry_threads(threads, pi, pj, gid, None, key, _keys(opi, opj, gid), None, oon, ohist, hist, on)
        assert np.array_equal(on, ref_on)
        assert np.array_equal(hist[on == 1], ref_hist[ref_on == 1])
        assert np.array_equal(key, _keys(pi, pj, gid))
    # both lists in shuffled order, seen sorted through their views
    new_perm, old_perm = rng.permutation(len(pi)), rng.permutation(len(opi))
    qi, qj = pi[new_perm], pj[new_perm]
    oview = sorted_view(opi[old_perm], opj[old_perm], gid)
    view = sorted_view(qi, qj, gid)
    assert np.array_equal(view[0], pi) and np.array_equal(oview[0], opi)
    for threads in range(0, 4):
        hist, on = np.full((len(pi), 8), np.nan), np.full(len(pi), 7, dtype=np.int8)
        args = (*view[:2], gid, view[2], np.empty(len(pi), dtype=np.int64), _keys(*oview[:2], gid), oview[2],
                oon[old_perm], ohist[old_perm], hist, on)
        carry_threads(threads, *args) if threads else carry_history_sorted(*args)
        assert np.array_equal(on, ref_on[new_perm])
        assert np.array_equal(hist[on == 1], ref_hist[new_perm][on == 1])


def test_gid_ranks_are_the_places_in_gid_order(rng):
    """gid_ranks gives each particle its place in ascending gid, as numpy's double argsort does:
    stored in gid order (the indices), owned ones in gid order and ghosts after them in any order
    (the prefix merged with the rest sorted), all shuffled, one particle, none."""
    gid = np.sort(rng.permutation(5000)[:700]).astype(np.int64)
    tail = gid.copy()
    tail[600:] = rng.permutation(tail[600:])
    cases = [gid, tail, rng.permutation(gid), gid[:1], gid[:0], gid[::-1].copy()]
    for g in cases:
        assert np.array_equal(gid_ranks(g), np.argsort(np.argsort(g)))


def test_marked_adjacency_rows_and_gid_sort(rng):
    """The gather of SPLIT reads the rows of the particles that gather only: pair_adjacency_of gives
    each marked particle exactly its pair_adjacency row (its pairs in ascending partner gid) and
    the others none, and the same arrays come from filling them in the list's gid order
    (dem.pairs.adjacency_in_order given the mark; modes.parallel.adjacency_marked_threads at 1-64
    ranges, more than the 60 owned particles), for the sorted list and through the sorted view of
    the same pairs shuffled.
    sort_by_gid (and in place, sort_pairs_by_gid) orders the pairs by (gid_i, gid_j) as numpy's
    lexsort does, with the particles stored in gid order (ranks taken as indices) or not (owned
    ones sorted, ghosts after them in any order, as under MPI), and modes.parallel.place_by_gid
    the same order at 1-7 threads from the pairs split among the threads' buffers, with the
    sorted view of the pairs' concatenation in thread order (stored in gid order, with the ranks
    given and with none: the indices)."""
    n = 80
    for stored in ("sorted", "ghost tail"):
        gid = np.sort(rng.permutation(900)[:n]).astype(np.int64)
        if stored == "ghost tail":
            gid[50:] = rng.permutation(gid[50:])
        pi, pj = _random_pairs(rng, n, 500, gid)
        # and a hub: the particle of the smallest gid paired with 30 others, a row of the list six
        # times as long as packed ellipsoids' (place_by_gid orders each row as it gathers it)
        hub = int(np.argmin(gid))
        spokes = {(hub, int(x)) for x in rng.permutation(np.delete(np.arange(n), hub))[:30]}
        both = sorted(spokes | set(zip(pi.tolist(), pj.tolist())))
        pi, pj = np.array([q[0] for q in both], dtype=np.int64), np.array([q[1] for q in both], dtype=np.int64)
        assert np.count_nonzero(pi == hub) >= 30
        order = rng.permutation(len(pi))
        pi, pj = pi[order], pj[order]
        si, sj = np.empty_like(pi), np.empty_like(pj)
        sort_by_gid(pi.copy(), pj.copy(), gid, si, sj)
        ref = np.lexsort((gid[pj], gid[pi]))
        assert np.array_equal(si, pi[ref]) and np.array_equal(sj, pj[ref])
        ii, jj = pi.copy(), pj.copy()   # the list's own sort, in place in one call
        sort_pairs_by_gid(ii, jj, gid)
        assert np.array_equal(ii, si) and np.array_equal(jj, sj)
        rank = gid_ranks(gid)
        for threads in (1, 2, 3, 7):  # the threads' pairs, thread t holding the t-th of T uneven parts
            cuts = np.sort(rng.integers(0, len(pi) + 1, threads - 1))
            offsets = np.concatenate([[0], cuts, [len(pi)]]).astype(np.int64)
            cap = int(np.diff(offsets).max()) + 3
            pi_t, pj_t = np.full((threads, cap), -1), np.full((threads, cap), -1)
            for t in range(threads):
                pi_t[t, :offsets[t + 1] - offsets[t]] = pi[offsets[t]:offsets[t + 1]]
                pj_t[t, :offsets[t + 1] - offsets[t]] = pj[offsets[t]:offsets[t + 1]]
            # blocks of one row (the mode's own up to 8 threads: block_shift), of 8 and of 32 rows (80
            # rows in 3 blocks: fewer than the threads)
            for shift in (0, 3, 5):
                blocks = _block_counts(threads, pi_t, offsets, rank, shift, n)
                # stored in gid order, the ranks are the indices: the placing reads none (rank None)
                for ranks in ((rank, None) if stored == "sorted" else (rank,)):
                    ti, tj = np.empty_like(pi), np.empty_like(pj)
                    place_by_gid(threads, pi_t, pj_t, offsets, ranks, n, blocks.copy(), shift, ti, tj,
                                 np.zeros(0, dtype=np.int64))
                    assert np.array_equal(ti, si) and np.array_equal(tj, sj)
                    # the sorted view of their concatenation: the pairs' indices moved with them
                    view = (np.empty_like(pi), np.empty_like(pj), np.empty_like(pi))
                    place_by_gid(threads, pi_t, pj_t, offsets, ranks, n, blocks.copy(), shift, *view)
                    assert all(np.array_equal(a, b) for a, b in zip(view, (si, sj, ref)))
        assert all(np.array_equal(a, b) for a, b in zip(sorted_view(pi, pj, gid), (si, sj, ref)))
        full = pair_adjacency(si, sj, gid, 60)
        mark = (rng.random(60) < 0.2).astype(np.int8)
        part = pair_adjacency_of(si, sj, gid, 60, mark)
        assert 0 < mark.sum() < 60
        for p in range(60):
            got = part[1][part[0][p]:part[0][p + 1]]
            want = full[1][full[0][p]:full[0][p + 1]] if mark[p] else full[1][:0]
            assert np.array_equal(got, want)
        # filled in the list's gid order (dem.pairs.adjacency_in_order given the mark, and the
        # threads' one-pass version, modes.parallel): the same arrays, for the sorted list and for the
        # same pairs shuffled and seen through their sorted view
        shuffle = rng.permutation(len(si))
        view = sorted_view(si[shuffle], sj[shuffle], gid)
        inv = np.argsort(shuffle)   # pair k of the sorted list is pair inv[k] of the shuffled one
        want_view = (part[0], 2 * inv[part[1] >> 1] + (part[1] & 1))
        for args, want in (((si, sj, None), part), (view, want_view)):
            got = [adjacency_in_order(*args, 60, mark)] + [adjacency_marked_threads(t, *args, 60, mark)
                                                           for t in (1, 2, 3, 7, 16, 64)]
            for start, items in got:
                assert np.array_equal(start, want[0]) and np.array_equal(items, want[1])


ALLOCATION_PROBE = """
import json
from numba.core import types
from numba.core.runtime import rtsys
from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step
from dem.forces import finish_range, resolve_range
from modes import parallel as par
from modes.serial import SerialMode
from modes.threads import ThreadsMode
def leaf_arrays(t):  # the arrays of an argument type, inside the argument groups (tuples) too
    return 1 if isinstance(t, types.Array) else sum(leaf_arrays(e) for e in t) if isinstance(t, types.BaseTuple) else 0
def wrappers(*kernels):  # numba wraps each array argument of a kernel that uses its runtime in one meminfo per call
    return sum(leaf_arrays(t) for k in kernels if k.targetoptions.get("_nrt", True) for t in k.signatures[0])
sc = load_prepared("packed", particles=300)
out = []
for mode, opts, kernels in ((SerialMode, {}, (resolve_range, finish_range)),
                            (ThreadsMode, {"threads": 2, "scheme": "dynamic"},
                             (par.resolve_threads, par.finish_threads)),
                            (ThreadsMode, {"threads": 2, "scheme": "static"},
                             (par.resolve_threads, par.finish_threads))):
    m = mode().setup(sc, dt=choose_time_step(sc).dt, skin=0.1, **opts)
    m.warmup()
    m.step()  # the first build
    s, p = m.state, m.pairs
    keep = lambda: [s.pos, s.vel, s.quat, s.angmom, s.force, s.wall_hist, p.pi, p.hist, p.on, p.pf, p.adj_items,
                    m.rot, m.omega]
    arrays = keep()
    before = rtsys.get_allocation_stats().alloc
    rebuilt = sum(m.step()["neighbor_rebuilt"] for _ in range(20))
    out.append({"mode": mode.__name__, "allocs": rtsys.get_allocation_stats().alloc - before, "rebuilt": rebuilt,
                "wrappers": 20 * wrappers(*kernels), "same": all(a is b for a, b in zip(arrays, keep()))})
print(json.dumps(out))
"""


def test_steps_between_rebuilds_allocate_nothing():
    """Between rebuilds a step allocates no array: numba's allocator (NRT statistics,
    NUMBA_NRT_STATS=1 in a process of its own) counts nothing for the serial kernels (compiled
    without the runtime) and exactly one meminfo per array argument of the two threaded kernels
    (prange needs the runtime), and the state, pair list and derived arrays stay the same objects
    (serial, 2 threads dynamic and static)."""
    import json
    import os
    import subprocess
    import sys
    from tests.helpers import ROOT
    env = dict(os.environ, NUMBA_NRT_STATS="1", NUMBA_NUM_THREADS="2", PYTHONPATH=ROOT)
    res = subprocess.run([sys.executable, "-c", ALLOCATION_PROBE], capture_output=True, text=True, env=env,
                         timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    rows = json.loads(res.stdout.strip().splitlines()[-1])
    for r in rows:
        assert r["rebuilt"] == 0, r  # a packed assembly keeps its list for 20 steps
        assert r["allocs"] == r["wrappers"] and r["same"], r
    assert [r["wrappers"] > 0 for r in rows] == [False, True, True]


def test_unknown_mode_option_refused():
    """A misspelt option is refused in one line instead of being dropped silently."""
    from modes.base import ModeError
    sc = load_prepared("patch162")
    with pytest.raises(ModeError, match="unknown option"):
        SerialMode().setup(sc, dt=choose_time_step(sc).dt, skn=0.1)


@pytest.mark.parametrize("threads", [8, 11, 16])
def test_marked_rows_placed_by_the_threads(rng, threads):
    """Where the marked rows hold many entries (PLACE_THREADS_FROM or more, at PLACE_THREADS_MIN or
    more ranges: at 16 ranges two thirds of 12k packed ellipsoids gather), the threads place them
    bucketed by blocks of particles (modes.parallel._place_entries_threads) instead of one thread:
    the rows are those of dem.pairs.adjacency_in_order given the mark, entry for entry, for the
    sorted list and through the sorted view of the same pairs shuffled; and the bucketed placement
    of made-up entries (particles in any order, some with none) equals one thread's in thread order."""
    from modes.parallel import PLACE_THREADS_FROM, PLACE_THREADS_MIN, _place_entries_threads
    assert threads >= PLACE_THREADS_MIN
    n, n_owned = 3000, 2600
    gid = np.sort(rng.permutation(10 * n)[:n]).astype(np.int64)
    pi, pj = _random_pairs(rng, n, 9000, gid)
    si, sj = np.empty_like(pi), np.empty_like(pj)
    sort_by_gid(pi, pj, gid, si, sj)
    mark = (rng.random(n_owned) < 0.9).astype(np.int8)
    want = adjacency_in_order(si, sj, None, n_owned, mark)
    assert len(want[1]) >= PLACE_THREADS_FROM
    shuffle = rng.permutation(len(si))
    view = sorted_view(si[shuffle], sj[shuffle], gid)
    for args in ((si, sj, None), view):
        ref = adjacency_in_order(*args, n_owned, mark)
        got = adjacency_marked_threads(threads, *args, n_owned, mark)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    got_n = np.array([5, 0, 9, 3] + [4] * (threads - 4), dtype=np.int64)
    ent_p = rng.integers(0, 50, (threads, 10)).astype(np.int64)
    ent_item = rng.integers(0, 10**6, (threads, 10)).astype(np.int64)
    start, items = _place_entries_threads(threads, ent_p, ent_item, got_n, 50)
    flat_p = np.concatenate([ent_p[t, :got_n[t]] for t in range(threads)])
    flat_i = np.concatenate([ent_item[t, :got_n[t]] for t in range(threads)])
    order = np.argsort(flat_p, kind="stable")   # one thread's placement: by particle, in thread order
    assert np.array_equal(start, np.concatenate([[0], np.cumsum(np.bincount(flat_p, minlength=50))]))
    assert np.array_equal(items, flat_i[order])


def test_placing_threads_carry_and_cut_as_the_separate_passes(rng):
    """modes.parallel.place_by_gid may carry the history (carry=...) and cut the list (cut=...) as
    the threads place it, in place of passes of their own: the rows and flags must equal one
    thread's merge (dem.pairs.carry_history_sorted; the rows where the flag is set), and the cut,
    finished by mark_and_home, the ranges, marks, home lists and count of cut_ranges at equal
    pairs (cut_at_equal_pairs' bounds, for equal and for unequal shares), with the marked rows of
    the adjacency those of adjacency_marked_threads, bit for bit. Random lists among 80 particles
    (60 owned; stored in gid order, or with ghosts out of order and owned ones too, cut_ranges'
    other branch, or with the owned ones in gid order and the ghosts out of it: pairs with a ghost
    end among rows of owned ones), of 500 candidate pairs (few empty rows), 25 (many: a cut steps
    past them) and none, at 1-7 threads."""
    from dem.pairs import carry_history_sorted, gid_ranks, sort_by_gid
    from dem.state import HIST_LEN
    from modes.parallel import cut_ranges, mark_and_home
    n, n_owned = 80, 60
    for stored in ("sorted", "shuffled", "ghosts"):
        gid = np.sort(rng.permutation(900)[:n]).astype(np.int64)
        if stored == "shuffled":
            gid[40:] = rng.permutation(gid[40:])
        elif stored == "ghosts":   # the ghosts' gids among the owned ones'
            gid = rng.permutation(900)[:n].astype(np.int64)
            gid[:n_owned] = np.sort(gid[:n_owned])
        rank = gid_ranks(gid)
        for size in (500, 25, 0):
            pi, pj = _random_pairs(rng, n, size, gid) if size else (np.zeros(0, np.int64), np.zeros(0, np.int64))
            m = len(pi)
            si, sj = np.empty_like(pi), np.empty_like(pj)
            sort_by_gid(pi.copy(), pj.copy(), gid, si, sj)
            # an old list: a random half of these pairs and some others, sorted, half touching
            opi, opj = _random_pairs(rng, n, 300, gid)
            keep = rng.random(m) < 0.5
            opi, opj = np.concatenate([opi, pi[keep]]), np.concatenate([opj, pj[keep]])
            key = {(a, b) for a, b in zip(opi.tolist(), opj.tolist())}
            opi = np.array([a for a, _ in sorted(key)], dtype=np.int64)
            opj = np.array([b for _, b in sorted(key)], dtype=np.int64)
            osi, osj = np.empty_like(opi), np.empty_like(opj)
            sort_by_gid(opi, opj, gid, osi, osj)
            oon = (rng.random(len(osi)) < 0.5).astype(np.int8)
            ohist = rng.random((len(osi), HIST_LEN))
            want_hist, want_on = np.zeros((m, HIST_LEN)), np.zeros(m, dtype=np.int8)
            carry_history_sorted(si, sj, gid, None, np.empty(m, dtype=np.int64), _keys(osi, osj, gid), None, oon, ohist,
                                 want_hist, want_on)
            for threads in (1, 2, 3, 7):
                cuts = np.sort(rng.integers(0, m + 1, threads - 1))
                offsets = np.concatenate([[0], cuts, [m]]).astype(np.int64)
                cap = int(np.diff(offsets).max()) + 3
                order = rng.permutation(m)
                pi_t, pj_t = np.full((threads, cap), -1), np.full((threads, cap), -1)
                for t in range(threads):
                    pi_t[t, :offsets[t + 1] - offsets[t]] = pi[order][offsets[t]:offsets[t + 1]]
                    pj_t[t, :offsets[t + 1] - offsets[t]] = pj[order][offsets[t]:offsets[t + 1]]
                shift = (0, 2, 4)[threads % 3]   # blocks of 1, 4 and 16 rows
                blocks = _block_counts(threads, pi_t, offsets, rank, shift, n)
                for v, shares in enumerate((np.ones(threads), rng.uniform(0.3, 3.0, threads))):
                    # stored in gid order, the second time with no ranks given (the indices are the ranks)
                    ranks = None if stored == "sorted" and v == 1 else rank
                    # the list's buffers, longer than the list (PairList.buffers)
                    ti, tj = np.full(m + 5, -1, dtype=np.int64), np.full(m + 5, -1, dtype=np.int64)
                    hist, on = np.full((m, HIST_LEN), -1.0), np.full(m, 7, dtype=np.int8)
                    key = np.full(m, -1, dtype=np.int64)
                    bounds, gat = np.zeros(threads + 1, dtype=np.int64), np.full(n_owned, 5, dtype=np.int8)
                    later, later_at, got = place_by_gid(
                        threads, pi_t, pj_t, offsets, ranks, n, blocks.copy(), shift, ti, tj,
                        np.zeros(0, dtype=np.int64), (gid, None, key, _keys(osi, osj, gid), None, oon, ohist, hist, on),
                        (shares, n_owned, gid, bounds, gat))
                    ti, tj = ti[:m], tj[:m]
                    assert np.array_equal(ti, si) and np.array_equal(tj, sj)
                    # the rows of the pairs that carry one (a pair without history has no row to read)
                    assert np.array_equal(on, want_on) and np.array_equal(hist[on == 1], want_hist[want_on == 1])
                    assert np.array_equal(key, _keys(ti, tj, gid))
                    home_start, home_items = np.empty(threads + 1, dtype=np.int64), np.empty(n_owned, dtype=np.int64)
                    count, adj_start, adj_items = mark_and_home(threads, bounds, ti, tj, gid, n_owned, gat, later,
                                                                later_at, got, home_start, home_items, True)
                    want = [np.zeros(threads + 1, dtype=np.int64), np.zeros(n_owned, dtype=np.int8),
                            np.empty(threads + 1, dtype=np.int64), np.empty(n_owned, dtype=np.int64)]
                    want_count = cut_ranges(None, threads, shares, si, sj, gid, n_owned, *want)
                    assert count == want_count
                    assert np.array_equal(bounds, want[0]) and np.array_equal(gat, want[1])
                    assert np.array_equal(home_start, want[2])
                    assert np.array_equal(home_items[:count], want[3][:count])
                    want_adj = adjacency_marked_threads(threads, si, sj, None, n_owned, gat)
                    assert np.array_equal(adj_start, want_adj[0]) and np.array_equal(adj_items, want_adj[1])
                    if size == 500 and threads > 1:
                        assert 0 < bounds[1] < m and gat.sum() > 0



@pytest.mark.parametrize("ranks", [False, True])
def test_placing_cut_of_many_later_ends_by_the_threads(rng, ranks):
    """The placing's cut at 16 ranges where most pairs cross a range's end (40k pairs among 6000
    particles stored in gid order, partners up to 400 indices apart; with 500 ghosts, their gids
    among the owned ones' and out of order, in some of them): the later ends, at least
    modes.parallel PLACE_THREADS_FROM of them, are marked by the threads (_mark_later_threads),
    which also find each range's last marked particle, up to whose row a range reads its pairs
    for the marked rows of the adjacency (_marked_entries_cut).
    The marks, home lists and count must equal cut_ranges' on the same list and the marked rows
    adjacency_marked_threads' full pass, bit for bit; ranks: the gid ranks given, or none (the
    indices are the ranks, as where no ghost is)."""
    from dem.pairs import gid_ranks, sort_by_gid
    from modes.parallel import PLACE_THREADS_FROM, cut_ranges, mark_and_home
    n_owned, n, threads = 6000, 6500 if ranks else 6000, 16
    gid = 3 * np.arange(n, dtype=np.int64) + 5
    if ranks:   # the ghosts' gids among the owned ones' (each a gid between two owned ones, out of order)
        gid[n_owned:] = rng.permutation(3 * rng.choice(n_owned, n - n_owned, replace=False) + 6)
    i = rng.integers(0, n - 30, 40000)
    j = np.minimum(i + rng.integers(1, 400, 40000), n - 1)
    keys = np.unique(np.stack([i, j], axis=1), axis=0)
    keys = keys[keys[:, 0] != keys[:, 1]]
    a, b = keys[:, 0], keys[:, 1]
    swap = gid[a] > gid[b]
    pi, pj = np.where(swap, b, a), np.where(swap, a, b)
    m = len(pi)
    si, sj = np.empty_like(pi), np.empty_like(pj)
    sort_by_gid(pi.copy(), pj.copy(), gid, si, sj)
    rank = gid_ranks(gid)
    offsets = (np.arange(threads + 1) * m) // threads
    cap = int(np.diff(offsets).max())
    order = rng.permutation(m)
    pi_t, pj_t = np.zeros((threads, cap), dtype=np.int64), np.zeros((threads, cap), dtype=np.int64)
    for t in range(threads):
        pi_t[t, :offsets[t + 1] - offsets[t]] = pi[order][offsets[t]:offsets[t + 1]]
        pj_t[t, :offsets[t + 1] - offsets[t]] = pj[order][offsets[t]:offsets[t + 1]]
    ti, tj = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    bounds, gat = np.zeros(threads + 1, dtype=np.int64), np.full(n_owned, 5, dtype=np.int8)
    later, later_at, got = place_by_gid(threads, pi_t, pj_t, offsets.astype(np.int64), rank if ranks else None, n,
                                        _block_counts(threads, pi_t, offsets, rank, 0, n), 0, ti, tj,
                                        np.zeros(0, dtype=np.int64), None,
                                        (np.ones(threads), n_owned, gid, bounds, gat))
    assert np.array_equal(ti, si) and np.array_equal(tj, sj)
    assert got[:, 0].sum() >= PLACE_THREADS_FROM and not got[:, 1].any()
    home_start, home_items = np.empty(threads + 1, dtype=np.int64), np.empty(n_owned, dtype=np.int64)
    count, adj_start, adj_items = mark_and_home(threads, bounds, ti, tj, gid, n_owned, gat, later, later_at, got,
                                                home_start, home_items, True)
    want = [np.zeros(threads + 1, dtype=np.int64), np.zeros(n_owned, dtype=np.int8),
            np.empty(threads + 1, dtype=np.int64), np.empty(n_owned, dtype=np.int64)]
    assert count == cut_ranges(None, threads, np.ones(threads), si, sj, gid, n_owned, *want)
    assert np.array_equal(bounds, want[0]) and np.array_equal(gat, want[1])
    assert np.array_equal(home_start, want[2]) and np.array_equal(home_items[:count], want[3][:count])
    want_adj = adjacency_marked_threads(threads, si, sj, None, n_owned, gat)
    assert np.array_equal(adj_start, want_adj[0]) and np.array_equal(adj_items, want_adj[1])
    assert len(adj_items) > PLACE_THREADS_FROM

def test_sorting_network_of_eight_sorts_every_input(rng):
    """modes.parallel._sort8, the placing's 19-comparator network (Knuth, TAOCP vol. 3, 5.3.4):
    a comparator network sorts every input if it sorts every input of 0s and 1s (the 0-1
    principle, ibid. exercise 5.3.4-36), so all 256 such inputs are checked, then 200 random
    permutations of distinct keys and inputs with repeats and the largest int64 (the padding of
    a short row) must come out as numpy's sort."""
    from modes.parallel import _sort8
    for bits in range(256):
        v = np.array([(bits >> k) & 1 for k in range(8)], dtype=np.int64)
        want = np.sort(v)
        _sort8(v)
        assert np.array_equal(v, want)
    top = np.iinfo(np.int64).max
    for _ in range(200):
        v = rng.permutation(np.concatenate([rng.integers(0, 1 << 40, 5), [top, top, 3]])).astype(np.int64)
        want = np.sort(v)
        _sort8(v)
        assert np.array_equal(v, want)


@pytest.mark.parametrize("n, threads", [(1, 1), (80, 1), (80, 7), (12000, 2), (12000, 8), (12000, 9), (12000, 16),
                                        (1_000_000, 64)])
def test_placing_blocks_are_few_and_whole(n, threads):
    """modes.parallel.block_shift: single rows up to PLACE_ROWS_THREADS (8) threads; beyond,
    blocks of 2^shift rows, at most PLACE_BLOCKS (16) per thread, and no larger than that needs
    (halving them would pass 16 T): 12k rows at 2 and 8 threads in 12000 blocks of one, at 9 in
    94 of 128, at 16 in 188 of 64."""
    from modes.parallel import PLACE_BLOCKS, PLACE_ROWS_THREADS
    shift = block_shift(n, threads)
    blocks = ((n - 1) >> shift) + 1
    if threads <= PLACE_ROWS_THREADS:
        assert shift == 0
    else:
        assert blocks <= PLACE_BLOCKS * threads
        if shift:
            assert ((n - 1) >> (shift - 1)) + 1 > PLACE_BLOCKS * threads
    want = {(12000, 2): (0, 12000), (12000, 8): (0, 12000), (12000, 9): (7, 94), (12000, 16): (6, 188)}
    if (n, threads) in want:
        assert (shift, blocks) == want[(n, threads)]


@pytest.mark.parametrize("mode_name", ["serial", "threads"])
@pytest.mark.parametrize("skin", [0.0, 0.4])
def test_wall_list_closes_the_histories_of_particles_it_drops(mode_name, skin):
    """A rebuild's wall list closes the wall histories (H_A = 0) of the particles it leaves out,
    which cannot touch a wall before the next rebuild (dem.forces.wall_candidates). Where the
    particles are stored as at the last list, only those on that list can hold an open history,
    so only they are closed: 64 spheres (radius 0.05) bouncing in a box of 6 walls (restitution
    0.8, gravity 9.81 down, random velocities up to 2 m/s, 0.05 m from the walls), 400 steps, the serial mode and 2
    static threads, at skin 0 (a list every step) and 0.4. Every step's state, wall histories
    included, must equal bit for bit a twin whose lists close every unlisted particle's history
    (np.array_equal), and at skin 0 some particle must leave the list with its history open (the
    case the closing is for) and some must touch a wall."""
    from dem.state import H_A
    from tests.helpers import make_scene
    rng = np.random.default_rng(3)
    grid = np.stack(np.meshgrid(*[np.linspace(-0.9, 0.9, 4)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    parts = [dict(shape="sphere", axes=[0.05], pos=list(p), vel=list(rng.uniform(-2.0, 2.0, 3))) for p in grid]

    def make():
        sc = make_scene(parts, walls=["x-", "x+", "y-", "y+", "z-", "z+"], gravity=(0.0, 0.0, -9.81))
        if mode_name == "serial":
            return sc, SerialMode().setup(sc, dt=2e-4, skin=skin)
        return sc, ThreadsMode().setup(sc, dt=2e-4, threads=2, scheme="static", skin=skin)

    sa, a = make()
    sb, b = make()
    full = np.zeros(0, dtype=np.int8)
    lister = b.wall_list
    b.wall_list = lambda *args: lister(*args[:-1], full)   # every unlisted particle's history closed
    dropped_open = touched = 0
    for _ in range(400):
        was = a.pairs.near.copy()
        open_before = np.any(sa.state.wall_hist[:, :, H_A] != 0.0, axis=1)
        a.step()
        b.step()
        for f in ("pos", "vel", "quat", "angmom", "wall_hist"):
            assert np.array_equal(getattr(sa.state, f), getattr(sb.state, f)), f
        if was.shape == a.pairs.near.shape:
            dropped_open += int(np.sum((was == 1) & (a.pairs.near == 0) & open_before))
        touched += int(np.sum(sa.state.wall_hist[:, :, H_A] != 0.0))
    assert touched > 0
    if skin == 0.0:
        assert dropped_open > 0
