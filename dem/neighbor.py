"""Neighbour estimate: candidate pairs whose bounding spheres overlap.

Both methods return the same set, each pair once, as local indices (i, j) ordered so that
gid[i] < gid[j] (the canonical order of DESIGN.md, Determinism). Pairs whose two ends are
both ghosts (index >= n_owned) are skipped: no rank needs them.

- all-pairs, O(n^2): i against j > i (Yan & Regueiro's n-by-n search);
- link-cell, O(n): cubic cells no smaller than the largest bounding diameter over the
  particles' bounding box; each cell against itself and its 13 forward neighbours (half-shell
  stencil), so no pair is produced twice (Grest, Duenweg & Kremer 1989).
Each outer loop is written once over a given range of rows (particles or cells), so a thread
scheme only chooses which rows each thread takes.
"""
import numpy as np
from numba import njit

# 13 forward neighbour offsets of the half-shell stencil (lexicographically positive)
HALF_SHELL = np.array([(dx, dy, dz) for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                       if (dz, dy, dx) > (0, 0, 0)], dtype=np.int64)


@njit(cache=True, inline="always")
def _emit(a, b, ga, gb, pi, pj, count):
    """Append pair (a, b) in canonical order (lower gid first); returns the new count."""
    if count < pi.shape[0]:
        if ga < gb:
            pi[count] = a
            pj[count] = b
        else:
            pi[count] = b
            pj[count] = a
    return count + 1


@njit(cache=True, inline="always")
def _scan(u, v0, v1, items, spos, srb, sgid, n_owned, pi, pj, count):
    """Test the particle at scan row u against scan rows v0..v1-1; the one inner loop of both
    neighbour methods.

    spos [m,3], srb [m], sgid [m] hold positions, bounding radii and gids in scan order and
    items [m] maps a scan row to its local index. The outer particle is read once into
    registers: numba cannot tell that the pair writes do not alias the positions.
    """
    a = items[u]
    xa, ya, za, ra, ga = spos[u, 0], spos[u, 1], spos[u, 2], srb[u], sgid[u]
    ghost_a = a >= n_owned
    for v in range(v0, v1):
        b = items[v]
        if ghost_a and b >= n_owned:
            continue
        dx = spos[v, 0] - xa
        dy = spos[v, 1] - ya
        dz = spos[v, 2] - za
        rr = ra + srb[v]
        if dx * dx + dy * dy + dz * dz < rr * rr:
            count = _emit(a, b, ga, sgid[v], pi, pj, count)
    return count


@njit(cache=True)
def allpairs_rows(rows, pos, rbound, gid, n_owned, pi, pj):
    """n-by-n search over outer rows i in `rows` against all j > i. Returns the pair count
    (which may exceed len(pi): then the caller enlarges the buffers and calls again)."""
    n = pos.shape[0]
    identity = np.arange(n)
    count = 0
    for r in range(rows.shape[0]):
        i = rows[r]
        count = _scan(i, i + 1, n, identity, pos, rbound, gid, n_owned, pi, pj, count)
    return count


@njit(cache=True)
def bin_particles(pos, cutoff):
    """Counting sort of particles into cubic cells of edge >= cutoff over their bounding box.

    Returns (dims [3], lo [3], size [3], cell_start [ncell+1], cell_items [n]); items within a
    cell keep ascending local index.
    """
    n = pos.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        lo[k] = np.inf
        hi[k] = -np.inf
    for p in range(n):
        for k in range(3):
            lo[k] = min(lo[k], pos[p, k])
            hi[k] = max(hi[k], pos[p, k])
    dims = np.ones(3, dtype=np.int64)
    size = np.empty(3)
    for k in range(3):
        ext = hi[k] - lo[k] if n > 0 else 0.0
        m = int(ext / cutoff) if cutoff > 0 else 1
        dims[k] = max(1, m)
    # a particle far from the rest must not blow the grid up: keep <= 8 cells per particle
    while dims[0] * dims[1] * dims[2] > 8 * n + 64:
        k = np.argmax(dims)
        dims[k] = max(1, dims[k] // 2)
    for k in range(3):
        ext = hi[k] - lo[k] if n > 0 else 0.0
        size[k] = max(ext / dims[k], cutoff)
    ncell = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(n, dtype=np.int64)
    cell_start = np.zeros(ncell + 1, dtype=np.int64)
    for p in range(n):
        c = 0
        for k in (2, 1, 0):
            ck = int((pos[p, k] - lo[k]) / size[k])
            if ck >= dims[k]:
                ck = dims[k] - 1
            c = c * dims[k] + ck
        cell_of[p] = c
        cell_start[c + 1] += 1
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    cell_items = np.empty(n, dtype=np.int64)
    for p in range(n):
        c = cell_of[p]
        cell_items[fill[c]] = p
        fill[c] += 1
    return dims, lo, size, cell_start, cell_items


@njit(cache=True)
def sorted_copies(cell_items, pos, rbound, gid):
    """Positions, bounding radii and gids [n] in cell order, so cell scans read contiguous memory."""
    n = cell_items.shape[0]
    spos = np.empty((n, 3))
    srb = np.empty(n)
    sgid = np.empty(n, dtype=np.int64)
    for u in range(n):
        p = cell_items[u]
        spos[u, 0] = pos[p, 0]
        spos[u, 1] = pos[p, 1]
        spos[u, 2] = pos[p, 2]
        srb[u] = rbound[p]
        sgid[u] = gid[p]
    return spos, srb, sgid


@njit(cache=True)
def linkcell_rows(cells, dims, cell_start, cell_items, half_shell, spos, srb, sgid, n_owned, pi, pj):
    """Half-shell link-cell search over the cells listed in `cells` (flat indices, x fastest),
    on the cell-ordered copies spos [n,3], srb [n], sgid [n] of sorted_copies. Pairs are written
    as local indices (cell_items maps back). Returns the pair count (see allpairs_rows)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    count = 0
    for r in range(cells.shape[0]):
        c = cells[r]
        cx = c % nx
        cy = (c // nx) % ny
        cz = c // (nx * ny)
        s0, s1 = cell_start[c], cell_start[c + 1]
        for u in range(s0, s1):
            count = _scan(u, u + 1, s1, cell_items, spos, srb, sgid, n_owned, pi, pj, count)
            for o in range(half_shell.shape[0]):
                x = cx + half_shell[o, 0]
                y = cy + half_shell[o, 1]
                z = cz + half_shell[o, 2]
                if x < 0 or y < 0 or z < 0 or x >= nx or y >= ny or z >= nz:
                    continue
                d = x + nx * (y + ny * z)
                count = _scan(u, cell_start[d], cell_start[d + 1], cell_items, spos, srb, sgid, n_owned,
                              pi, pj, count)
    return count


class PairBuffer:
    """Growable candidate-pair buffers pi, pj [capacity] int64 reused across steps."""

    def __init__(self, capacity=1024):
        self.pi = np.empty(capacity, dtype=np.int64)
        self.pj = np.empty(capacity, dtype=np.int64)

    def ensure(self, count):
        if count > self.pi.shape[0]:
            cap = int(count * 1.25) + 64
            self.pi = np.empty(cap, dtype=np.int64)
            self.pj = np.empty(cap, dtype=np.int64)
            return False
        return True


def candidate_pairs(method, pos, rbound, gid, n_owned, buf):
    """Serial neighbour estimate: returns (pi, pj) views of the candidate pairs.

    method: "allpairs" or "linkcell".
    """
    n = pos.shape[0]
    if method == "allpairs":
        rows = np.arange(n, dtype=np.int64)
        while True:
            count = allpairs_rows(rows, pos, rbound, gid, n_owned, buf.pi, buf.pj)
            if buf.ensure(count):
                break
    elif method == "linkcell":
        cutoff = 2.0 * rbound.max() if n else 1.0
        dims, lo, size, cell_start, cell_items = bin_particles(pos, cutoff)
        spos, srb, sgid = sorted_copies(cell_items, pos, rbound, gid)
        cells = np.arange(dims[0] * dims[1] * dims[2], dtype=np.int64)
        while True:
            count = linkcell_rows(cells, dims, cell_start, cell_items, HALF_SHELL, spos, srb, sgid,
                                  n_owned, buf.pi, buf.pj)
            if buf.ensure(count):
                break
    else:
        raise ValueError(f"unknown neighbour method {method!r} (allpairs, linkcell)")
    return buf.pi[:count], buf.pj[:count]


@njit(cache=True)
def max_displacement2(pos, ref, n):
    """Largest squared displacement [m^2] of particles 0..n-1 since the reference positions."""
    worst = 0.0
    for p in range(n):
        dx = pos[p, 0] - ref[p, 0]
        dy = pos[p, 1] - ref[p, 1]
        dz = pos[p, 2] - ref[p, 2]
        worst = max(worst, dx * dx + dy * dy + dz * dz)
    return worst


@njit(cache=True)
def cell_order(pos, cutoff):
    """Permutation [n] listing the particles cell by cell (x fastest): a spatial sort, so that
    particles close in space are close in memory."""
    return bin_particles(pos, cutoff)[4]


class VerletList:
    """Candidate pairs within r_i + r_j + skin, reused until some particle moved skin/2.

    Bounding spheres do not change under rotation, so the list stays a superset of the touching
    pairs until a particle has translated by half the skin (Verlet 1967; LAMMPS' neighbor skin).
    The narrow phase then decides contact exactly, so the contact set, and the trajectory, are
    those of a per-step estimate.
    """

    def __init__(self, method, skin):
        self.method = method
        self.skin = float(skin)     # [m]
        self.ref = None
        self.pi = self.pj = None
        self.buf = PairBuffer(1024)
        self.rebuilds = 0

    def needs_rebuild(self, pos, n_owned):
        if self.ref is None or self.ref.shape != pos.shape:
            return True
        return max_displacement2(pos, self.ref, pos.shape[0]) >= (0.5 * self.skin) ** 2

    def rebuild(self, pos, rbound, gid, n_owned):
        pi, pj = candidate_pairs(self.method, pos, rbound + 0.5 * self.skin, gid, n_owned, self.buf)
        self.pi, self.pj = pi, pj
        self.ref = pos.copy()
        self.rebuilds += 1
        return pi, pj
