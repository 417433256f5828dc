"""The pair list: candidate pairs kept between neighbour rebuilds, with their records and history.

A rebuild (dem.neighbor finds the pairs whose bounding spheres, widened by half the skin each,
overlap) gives pi, pj [m] (local indices, gid[pi] < gid[pj]). Between rebuilds the list is a
superset of the touching pairs as long as no particle has moved more than half the skin
(Verlet 1967; LAMMPS' neighbor skin), so each step resolves the same list. Per pair the list
keeps hist [m, HIST_LEN] (the contact history) and on [m] (touching at the last resolution: the
history is valid) and pf [m, PF_LEN] (its forces, written by each resolution); per owned particle
the adjacency adj_start [n_owned+1], adj_items: its pairs in ascending partner gid, the
summation order of DESIGN.md's determinism rule, each entry 2 k + (1 if the particle is pair
k's j end), so the gather needs no other lookup.

Across a rebuild the history is carried from the old list to the new one by the pair's global
ids (carry_history_sorted merges the two lists in (gid_i, gid_j) order: a list kept in another
order, the pairs each thread found, is seen in it through a sorted view), so memory order may
change in between. A particle that migrates (MPI) takes its history along in the state's
per-particle CSR (dem.state: rows keyed by partner gid, the form that moves with a particle and
is saved in caches): leaver_history_csr writes the leaving particles' rows from the old list,
and at the next build the pairs whose owned end came with rows take them
(history_from_rows_where_present), every other pair the carry (both ends hold identical rows);
history_to_csr writes every particle's rows (caches, checkpoints) and history_from_csr reads
them into a first list. This is LAMMPS' fix neigh/history in kind, which packs the history of
the atoms exchange() sends.
"""
import numpy as np
from numba import njit

from dem.forces import PF_LEN, SPLIT, SUM
from dem.state import HIST_LEN

# The default skin, as a fraction F of the largest bounding diameter d. Candidates grow about as
# (1 + F)^3 (the extra ones fail the bounding-sphere test at a few ns each), MPI ghost layers widen
# by F d, and a list lasts F d / (2 v dt) steps for the fastest particle at v [m/s]. F = 0.1 (LAMMPS
# granular examples use 0.1-0.3 d) is the skin whose worst cost over three regimes is smallest:
# `bench perf --what skin` (serial, 3 rounds of 1000 steps, medians) on packed 2000 ellipsoids,
# packed 2000 spheres and the 1521-ellipsoid deposition 20 ms into its fall gave per skin
# 0 / 0.02 / 0.05 / 0.1 / 0.2 / 0.3 a worst cost over each scene's best of 2.74 / 1.08 / 1.16 /
# 1.04 / 1.19 / 1.11 (F = 0.1: 2.09, 0.28 and 0.20 us per particle-step, lists lasting 430, 190
# and 250 steps, 1.6, 1.5 and 9.6 candidates per contact). The cost is flat within noise from
# 0.02 to 0.3; skin 0 (the paper's every-step estimate) costs 1.4-2.7x.
DEFAULT_SKIN = 0.1


@njit(cache=True)
def pair_adjacency(pi, pj, gid, n_owned):
    """Each owned particle's pairs sorted by ascending partner gid: (start [n_owned+1], items [nnz]
    = 2 k + 1 where the particle is pair k's j end, 2 k where it is the i end). Rows are filled in
    pair order and then insertion-sorted (rows are short), so the order never depends on how the
    pair list was produced: the reference for the lists' own adjacency, whose rows are filled in
    the list's gid order and need no sort (adjacency_in_order)."""
    return _adjacency(pi, pj, gid, n_owned, np.zeros(0, dtype=np.int8), True)


@njit(cache=True)
def pair_adjacency_of(pi, pj, gid, n_owned, mark):
    """pair_adjacency's rows for the owned particles with mark[p] != 0 only (mark [n_owned] int8),
    the others empty: the rows a gather reads when only some particles gather (SPLIT: those whose
    pairs fall in two threads' ranges); the reference for adjacency_in_order given a mark."""
    return _adjacency(pi, pj, gid, n_owned, mark, False)


@njit(inline="always")
def _adjacency(pi, pj, gid, n_owned, mark, every):
    m = pi.shape[0]
    start = np.zeros(n_owned + 1, dtype=np.int64)
    for k in range(m):
        if pi[k] < n_owned and (every or mark[pi[k]] != 0):
            start[pi[k] + 1] += 1
        if pj[k] < n_owned and (every or mark[pj[k]] != 0):
            start[pj[k] + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    items = np.empty(start[n_owned], dtype=np.int64)
    keys = np.empty(start[n_owned], dtype=np.int64)
    for k in range(m):
        i = pi[k]
        j = pj[k]
        if i < n_owned and (every or mark[i] != 0):
            items[fill[i]] = 2 * k
            keys[fill[i]] = gid[j]
            fill[i] += 1
        if j < n_owned and (every or mark[j] != 0):
            items[fill[j]] = 2 * k + 1
            keys[fill[j]] = gid[i]
            fill[j] += 1
    for p in range(n_owned):
        if start[p + 1] - start[p] < 2:
            continue
        for u in range(start[p] + 1, start[p + 1]):
            kk = keys[u]
            it = items[u]
            v = u - 1
            while v >= start[p] and keys[v] > kk:
                keys[v + 1] = keys[v]
                items[v + 1] = items[v]
                v -= 1
            keys[v + 1] = kk
            items[v + 1] = it
    return start, items


@njit(cache=True)
def _counting_sort(key, n, a, b, a_out, b_out, c=None, c_out=None):
    """(a, b) [m], and c [m] where given, stably sorted by key [m] (integers in 0..n-1) into a_out,
    b_out (c_out): O(m + n)."""
    count = np.zeros(n + 1, dtype=np.int64)
    for k in range(key.shape[0]):
        count[key[k] + 1] += 1
    for r in range(n):
        count[r + 1] += count[r]
    for k in range(key.shape[0]):
        r = key[k]
        a_out[count[r]] = a[k]
        b_out[count[r]] = b[k]
        if c is not None:
            c_out[count[r]] = c[k]
        count[r] += 1


@njit(cache=True)
def gid_ranks(gid):
    """rank [n]: the place of each of the n local particles in ascending gid order (gids distinct):
    the indices themselves when the particles are stored in gid order (owned ones are, after
    reorder; the argsort took 0.18 ms of 12k sorted gids), else the stored-in-order prefix merged
    with the rest argsorted, O(n + g log g) for the g particles from the first out of order on (the
    ghosts after the owned ones under MPI: 7000 local particles of which 1000 ghosts took 0.109 ms
    in one argsort of them all)."""
    n = gid.shape[0]
    rank = np.empty(n, dtype=np.int64)
    k = _first_descent(gid)   # gid[:k] ascending
    if k == n:
        for p in range(n):
            rank[p] = p
        return rank
    rest = np.argsort(gid[k:]) + k
    a = 0
    b = 0
    for r in range(n):
        if b == n - k or (a < k and gid[a] < gid[rest[b]]):
            rank[a] = r
            a += 1
        else:
            rank[rest[b]] = r
            b += 1
    return rank


@njit(cache=True)
def sort_by_gid(pi, pj, gid, pi_out, pj_out, idx=None, idx_out=None):
    """The pairs (pi, pj) [m] in ascending (gid[pi], gid[pj]) order, into pi_out, pj_out, and idx
    [m] where given moved with them into idx_out: two stable counting sorts over the gid ranks of
    the n local particles (gid_ranks), by j then by i, O(m + n), plus O(g log g) where the g
    particles from the first stored out of gid order on are not in gid order (gid_ranks)."""
    n = gid.shape[0]
    rank = gid_ranks(gid)
    tmp_i = np.empty_like(pi)
    tmp_j = np.empty_like(pj)
    if idx is None:
        tmp_x = None
    else:
        tmp_x = np.empty_like(idx)
    _counting_sort(rank[pj], n, pi, pj, tmp_i, tmp_j, idx, tmp_x)
    _counting_sort(rank[tmp_i], n, tmp_i, tmp_j, pi_out, pj_out, tmp_x, idx_out)


@njit(cache=True)
def sort_pairs_by_gid(pi, pj, gid):
    """sort_by_gid in place: pi, pj [m] in ascending (gid[pi], gid[pj]) order, the two counting
    sorts in one call (sort_by_gid's ten numpy and numba calls took ~15 us of a 1080-pair list's
    sort on 2 ranks of 500 packed ellipsoids, a list every step with --skin 0). Where the particles
    are stored in gid order (serial and threads always; an MPI rank's ghosts are not) each index
    is its own rank, and the sorts key on the indices themselves with no gather of ranks (12k
    packed ellipsoids' 57k pairs 0.65 -> 0.55 ms, 2500's 11k 0.101 -> 0.084 ms)."""
    n = gid.shape[0]
    m = pi.shape[0]
    tmp_i = np.empty(m, dtype=np.int64)
    tmp_j = np.empty(m, dtype=np.int64)
    if gid_ascending(gid):
        _counting_sort(pj, n, pi, pj, tmp_i, tmp_j)
        _counting_sort(tmp_i, n, tmp_i, tmp_j, pi, pj)
        return
    rank = gid_ranks(gid)
    key = np.empty(m, dtype=np.int64)
    for k in range(m):
        key[k] = rank[pj[k]]
    _counting_sort(key, n, pi, pj, tmp_i, tmp_j)
    for k in range(m):
        key[k] = rank[tmp_i[k]]
    _counting_sort(key, n, tmp_i, tmp_j, pi, pj)


@njit(cache=True, inline="always")
def _first_descent(gid):
    """The first p with gid[p] < gid[p - 1], or n: gid[:p] is ascending."""
    for p in range(1, gid.shape[0]):
        if gid[p] < gid[p - 1]:
            return p
    return gid.shape[0]


@njit(cache=True)
def gid_ascending(gid):
    """Whether the particles are stored in ascending gid [n] (then gid_ranks is the identity)."""
    return _first_descent(gid) == gid.shape[0]


NO_KEY = np.iinfo(np.int64).max   # above every pair's key


@njit(inline="always")
def pair_key(gid, i, j):
    """The pair (i, j)'s place in ascending (gid_i, gid_j) as one integer: gid_i 2^32 + gid_j
    (gids in [0, 2^31): dem.state GID_LIMIT), so that two pairs compare in one comparison."""
    return (gid[i] << 32) + gid[j]


@njit(inline="always")
def _at(order, a):
    """The index of the list's a-th pair in ascending (gid_i, gid_j): a itself where the list is
    stored in that order (order None: numba prunes the branch, so a sorted list pays nothing),
    else order[a]."""
    if order is None:
        return a
    return order[a]


def sorted_view(pi, pj, gid):
    """A list kept in another order (the pairs each thread found: STORE schemes) seen in ascending
    (gid[pi], gid[pj]): (spi, spj, order) [m], spi[a] = pi[order[a]] (sort_by_gid moving the
    indices), the order in which the history is carried and the adjacency filled (the threads
    make theirs as they place their pairs: modes.parallel place_by_gid)."""
    spi, spj, order = np.empty_like(pi), np.empty_like(pj), np.empty_like(pi)
    sort_by_gid(pi, pj, gid, spi, spj, np.arange(pi.shape[0]), order)
    return spi, spj, order


@njit(cache=True)
def adjacency_in_order(spi, spj, order, n_owned, mark=None):
    """pair_adjacency of a list seen in ascending (gid_i, gid_j) (spi, spj [m], pair order[a] of
    the list at a; order None: the list itself): the entries are filled in that order, so each row
    comes out in ascending partner gid with no sort (a particle's pairs as a j end, partner gid
    below its own, precede its own run as the i end, in which the partners ascend). O(m + n_owned).
    Given mark [n_owned] int8, the rows of the particles with mark[p] != 0 only (pair_adjacency_of's),
    the others empty."""
    m = spi.shape[0]
    start = np.zeros(n_owned + 1, dtype=np.int64)
    for a in range(m):
        if spi[a] < n_owned and (mark is None or mark[spi[a]] != 0):
            start[spi[a] + 1] += 1
        if spj[a] < n_owned and (mark is None or mark[spj[a]] != 0):
            start[spj[a] + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    items = np.empty(start[n_owned], dtype=np.int64)
    for a in range(m):
        k = _at(order, a)
        i = spi[a]
        j = spj[a]
        if i < n_owned and (mark is None or mark[i] != 0):
            items[fill[i]] = 2 * k
            fill[i] += 1
        if j < n_owned and (mark is None or mark[j] != 0):
            items[fill[j]] = 2 * k + 1
            fill[j] += 1
    return start, items


@njit(cache=True)
def history_to_csr(adj_start, adj_items, pi, pj, gid, on, hist, n_owned):
    """The per-particle contact history of the touching pairs: (hist_start [n_owned+1],
    hist_partner [nnz] partner gid, ascending per particle, hist_val [nnz, HIST_LEN])."""
    start = np.zeros(n_owned + 1, dtype=np.int64)
    for p in range(n_owned):
        c = 0
        for u in range(adj_start[p], adj_start[p + 1]):
            c += on[adj_items[u] >> 1]
        start[p + 1] = start[p] + c
    partner = np.empty(start[n_owned], dtype=np.int64)
    val = np.empty((start[n_owned], HIST_LEN))
    for p in range(n_owned):
        r = start[p]
        for u in range(adj_start[p], adj_start[p + 1]):
            k = adj_items[u] >> 1
            if on[k]:
                partner[r] = gid[pi[k]] if adj_items[u] & 1 else gid[pj[k]]
                for h in range(HIST_LEN):
                    val[r, h] = hist[k, h]
                r += 1
    return start, partner, val


@njit(cache=True)
def leaver_history_csr(leaving, pi, pj, gid, on, hist, n_owned):
    """history_to_csr for the owned particles with leaving[p] != 0 only (leaving [n_owned] int8; the
    others get empty rows), from one pass over the pairs, without the adjacency: (hist_start
    [n_owned+1], hist_partner [nnz] partner gid, ascending per particle, hist_val [nnz, HIST_LEN]).
    The rows a migrating particle takes to its new owner: the particles that stay keep their
    history in the list (PairList.set, rows=True)."""
    start = np.zeros(n_owned + 1, dtype=np.int64)
    m = pi.shape[0]
    for k in range(m):
        if on[k]:
            i = pi[k]
            j = pj[k]
            if i < n_owned and leaving[i]:
                start[i + 1] += 1
            if j < n_owned and leaving[j]:
                start[j + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    nnz = start[n_owned]
    partner = np.empty(nnz, dtype=np.int64)
    val = np.empty((nnz, HIST_LEN))
    if nnz == 0:
        return start, partner, val
    fill = start[:-1].copy()
    for k in range(m):
        if on[k]:
            i = pi[k]
            j = pj[k]
            if i < n_owned and leaving[i]:
                _insert_row(start[i], fill, i, gid[j], hist, k, partner, val)
            if j < n_owned and leaving[j]:
                _insert_row(start[j], fill, j, gid[i], hist, k, partner, val)
    return start, partner, val


@njit(inline="always")
def _insert_row(first, fill, own, g, hist, k, partner, val):
    """Put pair k's history row into own's rows (from first, filled up to fill[own]) in ascending
    partner gid g, by insertion (rows are short): the order history_to_csr gives."""
    r = fill[own]
    fill[own] += 1
    while r > first and partner[r - 1] > g:
        partner[r] = partner[r - 1]
        for h in range(HIST_LEN):
            val[r, h] = val[r - 1, h]
        r -= 1
    partner[r] = g
    for h in range(HIST_LEN):
        val[r, h] = hist[k, h]


@njit(inline="always")
def _owned_end(i, j, gid, n_owned):
    """(the pair's owned end, the other end's gid): the end whose rows hold the pair's history."""
    own = i if i < n_owned else j
    return own, (gid[j] if own == i else gid[i])


@njit(inline="always")
def _take_row(hist, on, k, src, r):
    """Pair k takes history row r of src (and is marked as having one)."""
    for h in range(HIST_LEN):
        hist[k, h] = src[r, h]
    on[k] = 1


@njit(inline="always")
def _take_from_rows(k, own, partner, hist_start, hist_partner, hist_val, hist, on):
    """Pair k takes the row of partner gid `partner` among own's rows (ascending partner gid) of
    the per-particle CSR, or none (on[k] = 0)."""
    on[k] = 0
    for r in range(hist_start[own], hist_start[own + 1]):
        g = hist_partner[r]
        if g == partner:
            _take_row(hist, on, k, hist_val, r)
            break
        if g > partner:
            break


@njit(cache=True)
def history_from_csr(pi, pj, gid, n_owned, hist_start, hist_partner, hist_val, hist, on):
    """Give each pair the history row of its owned end (on[k] = 1), or none (on[k] = 0)."""
    for k in range(pi.shape[0]):
        own, partner = _owned_end(pi[k], pj[k], gid, n_owned)
        _take_from_rows(k, own, partner, hist_start, hist_partner, hist_val, hist, on)


@njit(cache=True, _nrt=False)
def history_from_rows_where_present(pi, pj, gid, n_owned, hist_start, hist_partner, hist_val, hist, on):
    """After a carry: each pair whose owned end (history_from_csr's) has rows in the per-particle
    CSR takes its history from them instead (a particle that migrated in brings every contact it
    had; the pairs of the others keep what the carry gave)."""
    for k in range(pi.shape[0]):
        own, partner = _owned_end(pi[k], pj[k], gid, n_owned)
        if hist_start[own + 1] > hist_start[own]:
            _take_from_rows(k, own, partner, hist_start, hist_partner, hist_val, hist, on)


@njit(inline="always")
def _keys_range(a0, a1, spi, spj, gid, key):
    """key[a] = pair_key(gid, spi[a], spj[a]) for a = a0..a1-1."""
    for a in range(a0, a1):
        key[a] = pair_key(gid, spi[a], spj[a])


@njit(cache=True, _nrt=False)
def pair_keys(spi, spj, gid, key):
    """key[a] = pair_key(gid, spi[a], spj[a]) [m]: the keys of a list seen in ascending (gid_i,
    gid_j), kept with it (PairList.key) for the merge of the next rebuild's carry."""
    _keys_range(0, spi.shape[0], spi, spj, gid, key)


@njit(cache=True, _nrt=False)
def carry_history_sorted(spi, spj, gid, order, key, okey, oorder, oon, ohist, hist, on):
    """History of the new pairs from the old list: one merge of the two lists' key sequences in
    ascending (gid_i, gid_j), O(m + m_old). The new list in that order is (spi, spj [m]) over the
    ids gid, its a-th pair being pair order[a] of the list (order None: the list itself, sorted),
    whose row of hist [m, HIST_LEN] and flag of on [m] are written, and its keys key [m] (pair_key,
    in that order: the next carry's okey); the old list is seen by its keys okey [m_old] in the
    same order (pair_keys), oorder, its flags oon and rows ohist. A pair new to the list starts
    without history."""
    carry_history_sorted_range(0, spi.shape[0], spi, spj, gid, order, key, okey, oorder, oon, ohist, hist, on)


@njit(cache=True, _nrt=False)
def carry_history_sorted_range(a0, a1, spi, spj, gid, order, key, okey, oorder, oon, ohist, hist, on):
    """carry_history_sorted for the new pairs a0..a1-1 of the sorted order: their keys first, in a
    pass of their own (a loop with no branch, its gathers independent of each other), then the
    merge from the first old pair whose key is not below pair a0's (a binary search), so that
    threads can carry ranges of the list (modes.parallel.place_by_gid, each thread over the rows it
    places). The merge compares one integer key a pair, read in sequence from both lists (the old
    list's kept from its own rebuild: no gathers of ids, past its end NO_KEY), and a pair found in
    the old list takes the old row and flag whatever the flag (a row is read only where on[k] = 1):
    a copy with no branch on the data. On the arguments of a packed ellipsoids' rebuild at --skin
    0, one thread, against the merge that made both lists' keys from their ids and copied a row
    only where the old flag was set (interleaved, medians): 12k (57k pairs, 41k with history)
    0.48 -> 0.28 and 0.73 -> 0.45 ms in two runs, 2500 (11k pairs) 0.075 -> 0.056 and 0.119 ->
    0.083 ms; the keys' own pass is about a third of the new time."""
    mo = okey.shape[0]
    if a0 >= a1:
        return
    _keys_range(a0, a1, spi, spj, gid, key)
    key0 = key[a0]
    lo, hi = 0, mo
    while lo < hi:
        mid = (lo + hi) >> 1
        if okey[mid] < key0:
            lo = mid + 1
        else:
            hi = mid
    u = lo
    old = okey[u] if u < mo else NO_KEY
    for a in range(a0, a1):
        k = _at(order, a)
        while old < key[a]:
            u += 1
            old = okey[u] if u < mo else NO_KEY
        if old == key[a]:
            ku = _at(oorder, u)
            for h in range(HIST_LEN):
                hist[k, h] = ohist[ku, h]
            on[k] = oon[ku]
        else:
            on[k] = 0


class PairList:
    """Candidate pairs of the current neighbour list and their records (see the module docstring).

    pi, pj [m] int64, hist [m, HIST_LEN], on [m] int8 and pf [m, PF_LEN] are views of buffers that
    grow by 25 % when a rebuild needs more (steps between rebuilds allocate nothing). pi, pj, hist
    and on are double-buffered: a scan writes the next list into the spare set (buffers()) while
    the current one still holds the history to carry over. adj_start, adj_items the adjacency
    (built on demand where nothing gathers: sorted lists sum as they resolve); near [n_owned] int8
    the wall list (dem.forces.wall_candidates); ref [n_owned, 3] the owned positions at the
    rebuild [m]; gid the local particles' global ids at the rebuild [n]; offsets [T+1] the pairs
    each thread found (thread schemes resolve their own pairs); rebuilds counts the builds;
    view = (spi, spj, order) the list in ascending (gid_i, gid_j) (sorted_view; order None where
    the list itself is sorted), in which the next rebuild carries its history; key [m] int64 the
    pairs' keys in that order (pair_key; double-buffered with pi), which the next carry's merge
    reads in place of the ids.
    build_adjacency, sort_pairs and sort_view are the list's loops (adjacency_in_order,
    sort_pairs_by_gid, sorted_view, same arguments; build_adjacency given a mark builds the marked
    rows only); a thread mode sets its own on the instance (modes.threads: modes.parallel's, with
    identical results)."""

    build_adjacency = staticmethod(adjacency_in_order)
    sort_pairs = staticmethod(sort_pairs_by_gid)
    sort_view = staticmethod(sorted_view)

    def __init__(self, capacity=1024):
        self._cur = self._alloc(capacity)
        self._spare = self._alloc(capacity)
        self._pf = np.zeros((capacity, PF_LEN))
        self.m = 0
        self._views(0)
        self.view = (self.pi, self.pj, None)
        self.offsets = np.zeros(2, dtype=np.int64)
        self._adj = (np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64))
        self.gid = np.zeros(0, dtype=np.int64)
        self.n_owned = 0
        self.ref = np.zeros((0, 3))
        self.near = np.zeros(0, dtype=np.int8)
        self.rebuilds = 0

    @staticmethod
    def _alloc(cap):
        return (np.zeros(cap, dtype=np.int64), np.zeros(cap, dtype=np.int64), np.zeros((cap, HIST_LEN)),
                np.zeros(cap, dtype=np.int8), np.zeros(cap, dtype=np.int64))

    def _views(self, m):
        pi, pj, hist, on, key = self._cur
        self.pi, self.pj, self.hist, self.on, self.pf = pi[:m], pj[:m], hist[:m], on[:m], self._pf[:m]
        self.key = key[:m]

    @property
    def capacity(self):
        return self._spare[0].shape[0]

    def buffers(self, m):
        """pi, pj buffers (the spare set) of at least m entries for a neighbour scan to write into."""
        if m > self.capacity:
            self._spare = self._alloc(int(m * 1.25) + 64)
        return self._spare[0], self._spare[1]

    def carry_args(self, m, gid, order=None):
        """The arguments (gid, order, key, okey, oorder, oon, ohist, hist, on) of
        carry_history_sorted that carry the current list's history into the next one, m pairs over
        the ids gid in the spare buffers (buffers()), seen in gid order directly (order None) or
        through order: for a thread mode that carries as it places the new list (modes.parallel
        place_by_gid), after which set() is told not to carry again."""
        _, _, hist, on, key = self._spare
        return gid, order, key[:m], self.key, self.view[2], self.on, self.hist, hist[:m], on[:m]

    @property
    def adj_start(self):
        return self.adjacency()[0]

    @property
    def adj_items(self):
        return self.adjacency()[1]

    @property
    def arrays(self):
        """The resolution kernels' plist group (pi, pj, hist, on, pf) (dem.forces)."""
        return self.pi, self.pj, self.hist, self.on, self.pf

    def gather_arrays(self, deliver, gat):
        """The finish kernels' adj group (adj_start, adj_items, on, pf, near, gat) (dem.forces) for a
        resolution that delivers its forces by `deliver` (dem.forces STORE, SUM, SPLIT; gat [n_owned]
        int8 the particles that gather under SPLIT, else empty); where every sum is made as the
        pairs are resolved (SUM) nothing gathers, and the adjacency is left unbuilt (empty arrays
        of its types take its place); where only the particles with gat == 1 gather (SPLIT), only
        their rows are built (on 12k packed ellipsoids, 2 threads, every row took 0.95 ms a
        rebuild)."""
        if deliver == SUM:
            adj_start, adj_items = np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
        elif deliver == SPLIT and self._adj is None:
            adj_start, adj_items = self.build_adjacency(*self.view, self.n_owned, gat)
        else:
            adj_start, adj_items = self.adjacency()
        return adj_start, adj_items, self.on, self.pf, self.near, gat

    def adjacency(self):
        """(adj_start [n_owned+1], adj_items): each owned particle's pairs in ascending partner gid."""
        if self._adj is None:
            self._adj = self.build_adjacency(*self.view, self.n_owned)
        return self._adj

    def set(self, m, gid, n_owned, hist_start, hist_partner, hist_val, pos, by_gid=False, carry=False,
            rows=False, carry_sorted=None, ref=None):
        """Adopt the m pairs written into buffers(), with their history: carry=True takes it from
        the current list (the same particles, in any memory order: gid identifies them), else from
        the per-particle CSR (hist_start, hist_partner, hist_val: a first build). With carry and
        rows=True (particles migrated: MPI), a pair whose owned end has rows in the CSR (it came
        from another rank, which wrote them: leaver_history_csr) takes them instead of the carry;
        the others were in the old list (a pair that can touch has both ends there, one of them
        owned, the other owned or a ghost). by_gid: first sort the pairs by (gid_i, gid_j),
        the order in which one thread can sum each particle's forces as it resolves them; the
        adjacency is then built only on demand. Else the list keeps the order it was found in
        (the pairs each thread found), is seen sorted through its view (sort_view) and its
        adjacency is built at once. carry_sorted: the merge of two lists seen in gid order
        (carry_history_sorted's arguments; default carry_history_sorted, threads: their own). ref
        [n_owned, 3]: the array that holds the owned positions at this rebuild where the caller
        fills it (the threads, with the wall list); default a copy of pos[:n_owned]."""
        old, old_m, old_view = self._cur, self.m, self.view
        self._cur, self._spare = self._spare, old
        if self._pf.shape[0] < self._cur[0].shape[0]:
            self._pf = np.zeros((self._cur[0].shape[0], PF_LEN))
        self.m = m
        self._views(m)
        if by_gid and m > 1:
            self.sort_pairs(self.pi, self.pj, gid)
        self.gid = gid.copy()
        self.n_owned = n_owned
        self.view = (self.pi, self.pj, None) if by_gid else self.sort_view(self.pi, self.pj, gid)
        self._adj = None if by_gid else self.build_adjacency(*self.view, n_owned)
        if not carry:
            history_from_csr(self.pi, self.pj, gid, n_owned, hist_start, hist_partner, hist_val, self.hist, self.on)
            pair_keys(*self.view[:2], gid, self.key)
        else:   # the merge writes the new list's keys (self.key) as it reads the old one's
            ohist, oon, okey = old[2][:old_m], old[3][:old_m], old[4][:old_m]
            (carry_sorted or carry_history_sorted)(*self.view[:2], gid, self.view[2], self.key, okey, old_view[2], oon,
                                                   ohist, self.hist, self.on)
        if carry and rows and len(hist_partner):
            history_from_rows_where_present(self.pi, self.pj, gid, n_owned, hist_start, hist_partner, hist_val,
                                            self.hist, self.on)
        self.ref = pos[:n_owned].copy() if ref is None else ref
        self.rebuilds += 1

    def history(self, gid, n_owned, leaving=None):
        """The per-particle CSR (hist_start, hist_partner, hist_val) of the touching pairs; given
        leaving [n_owned] int8, only the rows of the particles marked (leaver_history_csr)."""
        if self.rebuilds == 0:
            return np.zeros(n_owned + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, HIST_LEN))
        if self.n_owned != n_owned or not np.array_equal(self.gid[:n_owned], gid[:n_owned]):
            raise ValueError("pair list history read for particles other than those it was built for")
        if leaving is not None:
            return leaver_history_csr(leaving, self.pi, self.pj, gid, self.on, self.hist, n_owned)
        adj_start, adj_items = self.adjacency()
        return history_to_csr(adj_start, adj_items, self.pi, self.pj, gid, self.on, self.hist, n_owned)
