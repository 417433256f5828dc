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

Across a rebuild the history travels through the state's per-particle CSR (dem.state: rows
keyed by partner gid, the form that migrates with a particle and is saved in caches):
history_to_csr writes it from the old list, history_from_csr reads it into the new one (from the
pair's owned end; both ends hold identical rows). This is LAMMPS' fix neigh/history in kind.
"""
import numpy as np
from numba import njit

from dem.forces import PF_LEN
from dem.state import HIST_LEN

# The default skin, as a fraction of the largest bounding diameter d. Candidates grow as
# (1 + F)^3 (the extra ones fail the bounding-sphere test at a few ns each), ghost layers widen
# by F d, and a list lasts F d / (2 v dt) steps for the fastest particle at v [m/s]. F = 0.1
# (LAMMPS granular examples use 0.1-0.3 d) ... (measured: see the README).
DEFAULT_SKIN = 0.1


@njit(cache=True)
def pair_adjacency(pi, pj, gid, n_owned):
    """Each owned particle's pairs sorted by ascending partner gid: (start [n_owned+1], items [nnz]
    = 2 k + 1 where the particle is pair k's j end, 2 k where it is the i end). Rows are filled in
    pair order and then insertion-sorted (rows are short), so the order never depends on how the
    pair list was produced."""
    m = pi.shape[0]
    start = np.zeros(n_owned + 1, dtype=np.int64)
    for k in range(m):
        if pi[k] < n_owned:
            start[pi[k] + 1] += 1
        if pj[k] < n_owned:
            start[pj[k] + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    items = np.empty(start[n_owned], dtype=np.int64)
    keys = np.empty(start[n_owned], dtype=np.int64)
    for k in range(m):
        i = pi[k]
        j = pj[k]
        if i < n_owned:
            items[fill[i]] = 2 * k
            keys[fill[i]] = gid[j]
            fill[i] += 1
        if j < n_owned:
            items[fill[j]] = 2 * k + 1
            keys[fill[j]] = gid[i]
            fill[j] += 1
    for p in range(n_owned):
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
def history_from_csr(pi, pj, gid, n_owned, hist_start, hist_partner, hist_val, hist, on):
    """Give each pair the history row of its owned end (on[k] = 1), or none (on[k] = 0)."""
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        own = i if i < n_owned else j
        partner = gid[j] if own == i else gid[i]
        on[k] = 0
        for r in range(hist_start[own], hist_start[own + 1]):
            g = hist_partner[r]
            if g == partner:
                for h in range(HIST_LEN):
                    hist[k, h] = hist_val[r, h]
                on[k] = 1
                break
            if g > partner:
                break


class PairList:
    """Candidate pairs of the current neighbour list and their records (see the module docstring).

    pi, pj [m] int64, hist [m, HIST_LEN], pf [m, PF_LEN] and on [m] int8 are views of buffers that
    grow by 25 % when a rebuild needs more (steps between rebuilds allocate nothing); adj_start,
    adj_items the adjacency; near [n_owned] int8 the wall list (dem.forces.wall_candidates); ref
    [n_owned, 3] the owned positions at the rebuild [m]; offsets [T+1]
    the pairs each thread found (thread schemes resolve their own pairs); rebuilds counts the
    builds."""

    def __init__(self, capacity=1024):
        self._alloc(capacity)
        self.m = 0
        self._views(0)
        self.offsets = np.zeros(2, dtype=np.int64)
        self.adj_start = np.zeros(1, dtype=np.int64)
        self.adj_items = np.zeros(0, dtype=np.int64)
        self.ref = np.zeros((0, 3))
        self.near = np.zeros(0, dtype=np.int8)
        self.rebuilds = 0

    def _alloc(self, cap):
        self._pi = np.zeros(cap, dtype=np.int64)
        self._pj = np.zeros(cap, dtype=np.int64)
        self._hist = np.zeros((cap, HIST_LEN))
        self._pf = np.zeros((cap, PF_LEN))
        self._on = np.zeros(cap, dtype=np.int8)

    def _views(self, m):
        self.pi, self.pj, self.hist, self.pf, self.on = (self._pi[:m], self._pj[:m], self._hist[:m], self._pf[:m],
                                                         self._on[:m])

    @property
    def capacity(self):
        return self._pi.shape[0]

    def buffers(self, m):
        """pi, pj buffers of at least m entries for a neighbour scan to write into."""
        if m > self.capacity:
            self._alloc(int(m * 1.25) + 64)
        return self._pi, self._pj

    def set(self, m, gid, n_owned, hist_start, hist_partner, hist_val, pos, by_gid=False):
        """Adopt the m pairs written into buffers(): history from the per-particle CSR, the
        adjacency, the reference positions. by_gid: first sort the pairs by (gid_i, gid_j), the
        order in which one thread can sum each particle's forces as it resolves them."""
        self.m = m
        self._views(m)
        if by_gid and m > 1:
            order = np.argsort(gid[self.pi] * (int(gid.max()) + 1) + gid[self.pj], kind="stable")
            self.pi[:] = self.pi[order]
            self.pj[:] = self.pj[order]
        self.adj_start, self.adj_items = pair_adjacency(self.pi, self.pj, gid, n_owned)
        history_from_csr(self.pi, self.pj, gid, n_owned, hist_start, hist_partner, hist_val, self.hist, self.on)
        self.ref = pos[:n_owned].copy()
        self.rebuilds += 1

    def history(self, gid, n_owned):
        """The per-particle CSR (hist_start, hist_partner, hist_val) of the touching pairs."""
        if self.adj_start.shape[0] != n_owned + 1:  # never built for these particles
            return np.zeros(n_owned + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, HIST_LEN))
        return history_to_csr(self.adj_start, self.adj_items, self.pi, self.pj, gid, self.on, self.hist, n_owned)
