"""Neighbour estimate: candidate pairs whose bounding spheres overlap.

Both methods return the same set, each pair once, as local indices (i, j) ordered so that
gid[i] < gid[j] (the canonical order of DESIGN.md, Determinism). Pairs whose two ends are
both ghosts (index >= n_owned) are skipped: no rank needs them.

- all-pairs, O(n^2): i against j > i (Yan & Regueiro's n-by-n search);
- link-cell, O(n): cubic cells no smaller than the largest bounding diameter over the
  particles' bounding box; each cell against itself and its 13 forward neighbours (half-shell
  stencil), so no pair is produced twice (Grest, Duenweg & Kremer 1989).
The loop is written once (scan_rows) over a list of outer particle rows, for both methods (all-
pairs is the same loop over a single cell), so a thread scheme only chooses which rows each
thread takes.
Neighbour lists kept between steps with a skin, and their contact history: dem.pairs.
"""
import numpy as np
from numba import njit

# 13 forward neighbour offsets of the half-shell stencil (lexicographically positive)
HALF_SHELL = np.array([(dx, dy, dz) for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                       if (dz, dy, dx) > (0, 0, 0)], dtype=np.int64)


def shell_runs(shell):
    """The offsets [k, 3] of a stencil, in their order, as runs of cells adjacent along x: rows
    (dy, dz, dx_first, dx_last) [r, 4]. Cells are numbered x fastest and the scan-ordered copies
    hold them in that order, so a run's particles are one contiguous range of scan rows, found
    with two reads of cell_start instead of two a cell. The own cell (0, 0, 0) leads the first run
    (scan_rows starts it after the outer particle)."""
    runs = [[0, 0, 0, 0]]
    for dx, dy, dz in shell:
        last = runs[-1]
        if last[0] == dy and last[1] == dz and last[3] + 1 == dx:
            last[3] = dx
        else:
            runs.append([dy, dz, dx, dx])
    return np.array(runs, dtype=np.int64)


# the own cell and the half shell as 5 runs along x, (dy, dz, dx from, dx to): [0, 0, 0, 1],
# [1, 0, -1, 1], then [dy, 1, -1, 1] for dy = -1, 0, 1
HALF_SHELL_RUNS = shell_runs(HALF_SHELL)


@njit(cache=True)
def grid_shape(n, lo, hi, cutoff):
    """Cells over the bounding box lo, hi [3] of n particles: (dims [3] int64, size [3]), edges
    >= cutoff (one cell per axis when cutoff is inf: all-pairs)."""
    dims = np.ones(3, dtype=np.int64)
    size = np.empty(3)
    for k in range(3):
        ext = hi[k] - lo[k] if n > 0 else 0.0
        m = int(ext / cutoff) if 0 < cutoff < np.inf else 1
        dims[k] = max(1, m)
    # a particle far from the rest must not blow the grid up: keep <= 8 cells per particle
    while dims[0] * dims[1] * dims[2] > 8 * n + 64:
        k = np.argmax(dims)
        dims[k] = max(1, dims[k] // 2)
    for k in range(3):
        ext = hi[k] - lo[k] if n > 0 else 0.0
        size[k] = max(ext / dims[k], cutoff) if cutoff < np.inf else max(ext, 1.0)
    return dims, size


@njit(cache=True, inline="always")
def cell_of_point(pos, p, lo, size, dims):
    """The cell (x fastest) of particle p."""
    c = 0
    for k in (2, 1, 0):
        ck = int((pos[p, k] - lo[k]) / size[k])
        if ck >= dims[k]:
            ck = dims[k] - 1
        c = c * dims[k] + ck
    return c


@njit(cache=True)
def bin_particles(pos, cutoff):
    """Counting sort of particles into cubic cells of edge >= cutoff over their bounding box.

    Returns (dims [3], lo [3], size [3], cell_start [ncell+1], cell_items [n], cell_of [n]); items
    within a cell keep ascending local index.
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
    dims, size = grid_shape(n, lo, hi, cutoff)
    ncell = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(n, dtype=np.int64)
    cell_start = np.zeros(ncell + 1, dtype=np.int64)
    for p in range(n):
        c = cell_of_point(pos, p, lo, size, dims)
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
    return dims, lo, size, cell_start, cell_items, cell_of


@njit(cache=True)
def sorted_copies(cell_items, cell_of, pos, rbound, gid):
    """Positions, bounding radii, gids and cell indices [n] in cell order (scan order), so the
    scans read contiguous memory."""
    n = cell_items.shape[0]
    spos = np.empty((n, 3))
    srb = np.empty(n)
    sgid = np.empty(n, dtype=np.int64)
    scell = np.empty(n, dtype=np.int64)
    for u in range(n):
        p = cell_items[u]
        spos[u, 0] = pos[p, 0]
        spos[u, 1] = pos[p, 1]
        spos[u, 2] = pos[p, 2]
        srb[u] = rbound[p]
        sgid[u] = gid[p]
        scell[u] = cell_of[p]
    return spos, srb, sgid, scell


@njit(cache=True)
def scan_rows(rows, r0, r1, grid, runs, n_owned, pi, pj, count):
    """The one neighbour loop: for each outer particle at scan row u in `rows`, test the later
    particles of its own cell and all particles of its 13 forward (half-shell) cells, visited as
    runs (HALF_SHELL_RUNS [5, 4]: shell_runs) of cells adjacent along x, each one contiguous range
    of scan rows: the same particles in the same order as cell by cell, with 5 lookups and bounds
    checks a particle instead of 14 (the serial scan of 2500 rested packed ellipsoids 0.57 -> 0.19
    ms, of 12k 3.3-3.6 -> 2.4 ms, of the 1521 falling ellipsoids 0.08-0.13 -> 0.056-0.076 ms).

    Link-cell: cells of edge >= the largest bounding diameter, so no pair is missed or produced
    twice (Grest, Duenweg & Kremer 1989). All-pairs is the same loop over a single cell (the
    n-by-n search, i against j > i). Arrays are in scan (cell) order (sorted_copies); pairs are
    written as local indices via cell_items from position `count` of pi, pj on. Only rows[r0:r1]
    are scanned, so a thread scheme hands each thread its rows.
    grid = (scell, dims, cell_start, cell_items, spos, srb, sgid): CellGrid.arrays.
    Returns (pair count, which may exceed len(pi): then the caller enlarges the buffers and
    scans again; number of pair tests made, the work of these rows).
    """
    scell, dims, cell_start, cell_items, spos, srb, sgid = grid
    nx, ny, nz = dims[0], dims[1], dims[2]
    tests = 0
    for r in range(r0, r1):
        u = rows[r]
        c = scell[u]
        cx = c % nx
        cy = (c // nx) % ny
        cz = c // (nx * ny)
        a = cell_items[u]
        # the outer particle lives in registers: numba cannot tell the pair writes do not alias spos
        xa, ya, za, ra, ga = spos[u, 0], spos[u, 1], spos[u, 2], srb[u], sgid[u]
        ghost_a = a >= n_owned
        for o in range(runs.shape[0]):
            y = cy + runs[o, 0]
            z = cz + runs[o, 1]
            if y < 0 or z < 0 or y >= ny or z >= nz:
                continue
            row = nx * (y + ny * z)
            v0 = u + 1 if o == 0 else cell_start[row + max(cx + runs[o, 2], 0)]
            v1 = cell_start[row + min(cx + runs[o, 3], nx - 1) + 1]
            tests += v1 - v0
            for v in range(v0, v1):
                b = cell_items[v]
                if ghost_a and b >= n_owned:
                    continue
                dx = spos[v, 0] - xa
                dy = spos[v, 1] - ya
                dz = spos[v, 2] - za
                rr = ra + srb[v]
                if dx * dx + dy * dy + dz * dz < rr * rr:
                    if count < pi.shape[0]:
                        if ga < sgid[v]:
                            pi[count] = a
                            pj[count] = b
                        else:
                            pi[count] = b
                            pj[count] = a
                    count += 1
    return count, tests


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


@njit(cache=True)
def cell_edge(allpairs, rbound):
    """The smallest cell edge [m] over bounding radii rbound [n]: inf for all-pairs (one cell), the
    largest bounding diameter for link-cell (1 where there is no particle)."""
    if allpairs:
        return np.inf
    if rbound.shape[0] == 0:
        return 1.0
    top = rbound[0]
    for p in range(1, rbound.shape[0]):
        top = max(top, rbound[p])
    return 2.0 * top


@njit(cache=True)
def cell_grid(pos, rbound, gid, cutoff):
    """The grid of the neighbour loop over positions pos [n, 3], cells of edge >= cutoff [m]:
    (dims, cell_start, cell_items, spos, srb, sgid, scell), bin_particles then sorted_copies."""
    dims, _, _, cell_start, cell_items, cell_of = bin_particles(pos, cutoff)
    spos, srb, sgid, scell = sorted_copies(cell_items, cell_of, pos, rbound, gid)
    return dims, cell_start, cell_items, spos, srb, sgid, scell


def grid_cutoff(method, rbound):
    """The smallest cell edge of the neighbour method over bounding radii rbound [n] (cell_edge)."""
    return cell_edge(is_allpairs(method), rbound)


class CellGrid:
    """Particles binned for the neighbour loop: dims [3], cell_start [ncell+1], cell_items [n]
    (scan row -> local index) and the scan-ordered copies spos, srb, sgid, scell (sorted_copies).
    method "allpairs" uses a single cell (the n-by-n search); "linkcell" cells of edge >= the
    largest bounding diameter over the particles' bounding box."""

    def __init__(self, method, pos, rbound, gid):
        (self.dims, self.cell_start, self.cell_items, self.spos, self.srb, self.sgid,
         self.scell) = cell_grid(pos, rbound, gid, grid_cutoff(method, rbound))

    @property
    def arrays(self):
        """The grid group of scan_rows: (scell, dims, cell_start, cell_items, spos, srb, sgid)."""
        return self.scell, self.dims, self.cell_start, self.cell_items, self.spos, self.srb, self.sgid

    def scan(self, rows, n_owned, pi, pj):
        """Serial scan of all rows; returns the pair count."""
        return scan_rows(rows, 0, rows.shape[0], self.arrays, HALF_SHELL_RUNS, n_owned, pi, pj, 0)[0]


@njit(cache=True)
def estimate_pairs(allpairs, pos, radii, gid, n_owned, pi, pj):
    """The serial neighbour estimate in one call: the grid of CellGrid (cells of edge >= the
    largest diameter 2 max(radii) [m], one cell where allpairs) and the scan of every row
    (scan_rows) into pi, pj; returns the pair count, which exceeds len(pi) where the buffers were
    too small (nothing is written past them: call again with larger ones). One call where the
    grid's three and the scan's took four: on 2 ranks of 500 packed ellipsoids with --skin 0 (345
    particles a rank, a list every step) the calls' own cost was ~15 us of a ~75 us estimate."""
    n = pos.shape[0]
    dims, cell_start, cell_items, spos, srb, sgid, scell = cell_grid(pos, radii, gid, cell_edge(allpairs, radii))
    rows = np.arange(n)
    return scan_rows(rows, 0, n, (scell, dims, cell_start, cell_items, spos, srb, sgid), HALF_SHELL_RUNS, n_owned,
                     pi, pj, 0)[0]


def is_allpairs(method):
    """Whether the neighbour method is all-pairs (True) or link-cell (False); ValueError otherwise."""
    if method not in ("allpairs", "linkcell"):
        raise ValueError(f"unknown neighbour method {method!r} (allpairs, linkcell)")
    return method == "allpairs"


def find_pairs(method, pos, radii, gid, n_owned, buffers, call=None):
    """Serial neighbour estimate into buffers(m) (a function returning pi, pj of at least m
    entries, e.g. dem.pairs.PairList.buffers): pairs whose spheres of radii [n] overlap.
    Returns the pair count. method: "allpairs" or "linkcell". call(kernel, args): how the kernel
    is called (default: directly; a mode passes its compiled entry point's caller)."""
    call = call or (lambda kernel, args: kernel(*args))
    allpairs = is_allpairs(method)
    pi, pj = buffers(0)
    count = call(estimate_pairs, (allpairs, pos, radii, gid, n_owned, pi, pj))
    if count > pi.shape[0]:
        pi, pj = buffers(count)
        count = call(estimate_pairs, (allpairs, pos, radii, gid, n_owned, pi, pj))
    return count


def candidate_pairs(method, pos, rbound, gid, n_owned, buf):
    """Serial neighbour estimate: returns (pi, pj) views of the candidate pairs (buf: a PairBuffer).

    method: "allpairs" or "linkcell".
    """
    def buffers(m):
        buf.ensure(m)
        return buf.pi, buf.pj
    count = find_pairs(method, pos, rbound, gid, n_owned, buffers)
    return buf.pi[:count], buf.pj[:count]


@njit(cache=True)
def cell_order(pos, cutoff):
    """Permutation [n] listing the particles cell by cell (x fastest): a spatial sort, so that
    particles close in space are close in memory."""
    return bin_particles(pos, cutoff)[4]
