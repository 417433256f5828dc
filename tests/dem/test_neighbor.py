"""Neighbour estimate: all-pairs and link-cell find exactly the brute-force candidate set."""
import numpy as np
import pytest

from dem.neighbor import PairBuffer, candidate_pairs


def brute_force(pos, rb, gid):
    n = len(pos)
    out = set()
    for a in range(n):
        for b in range(a + 1, n):
            if np.sum((pos[b] - pos[a]) ** 2) < (rb[a] + rb[b]) ** 2:
                out.add((a, b) if gid[a] < gid[b] else (b, a))
    return out


@pytest.mark.parametrize("method", ["allpairs", "linkcell"])
@pytest.mark.parametrize("n,spread", [(1, 1.0), (2, 0.1), (300, 1.0), (500, 0.2), (400, 50.0)])
def test_candidate_set_equals_brute_force(method, n, spread, rng):
    """Same set as the O(n^2) brute force, each pair once, canonical order gid[i] < gid[j];
    polydisperse radii (1:20) and a shuffled gid order, dense and dilute clouds."""
    pos = rng.uniform(0, spread, (n, 3))
    rb = rng.uniform(0.005, 0.1, n)
    gid = rng.permutation(n).astype(np.int64) * 3 + 7
    pi, pj = candidate_pairs(method, pos, rb, gid, n, PairBuffer(4))  # tiny buffer: exercises growth
    got = list(zip(pi.tolist(), pj.tolist()))
    assert len(got) == len(set(got)), "duplicate pairs"
    assert all(gid[a] < gid[b] for a, b in got)
    assert set(got) == brute_force(pos, rb, gid)


def test_linkcell_cells_not_smaller_than_largest_diameter(rng):
    """Cells are no smaller than the largest bounding diameter (so the 27-cell neighbourhood
    holds every partner); a lone far particle does not blow the grid up."""
    from dem.neighbor import bin_particles
    pos = rng.uniform(0, 1, (200, 3))
    pos[0] = [1e4, 1e4, 1e4]
    dims, lo, size, start, items, _ = bin_particles(pos, 0.05)
    assert np.all(size >= 0.05)
    assert dims.prod() <= 8 * 200 + 64
    assert sorted(items.tolist()) == list(range(200))


def test_ghost_ghost_pairs_skipped(rng):
    """Pairs whose two ends are ghosts (index >= n_owned) are never produced."""
    pos = rng.uniform(0, 0.3, (100, 3))
    rb = np.full(100, 0.05)
    gid = np.arange(100, dtype=np.int64)
    for method in ("allpairs", "linkcell"):
        pi, pj = candidate_pairs(method, pos, rb, gid, 60, PairBuffer(16))
        assert np.all((pi < 60) | (pj < 60))
        expect = {p for p in brute_force(pos, rb, gid) if min(p) < 60}
        assert set(zip(pi.tolist(), pj.tolist())) == expect


def test_half_shell_runs_cover_the_stencil_in_order():
    """shell_runs turns the 13 half-shell offsets into runs along x (cells are numbered x
    fastest): the own cell with (1, 0, 0), then (-1..1, 1, 0), (-1..1, -1, 1), (-1..1, 0, 1),
    (-1..1, 1, 1); listing each run's cells gives the own cell followed by HALF_SHELL in its
    order (13 offsets + 1 = 14 cells in 5 runs)."""
    from dem.neighbor import HALF_SHELL, HALF_SHELL_RUNS, shell_runs
    assert HALF_SHELL_RUNS.tolist() == [[0, 0, 0, 1], [1, 0, -1, 1], [-1, 1, -1, 1], [0, 1, -1, 1], [1, 1, -1, 1]]
    cells = [(dx, dy, dz) for dy, dz, x0, x1 in shell_runs(HALF_SHELL).tolist() for dx in range(x0, x1 + 1)]
    assert cells == [(0, 0, 0)] + [tuple(o) for o in HALF_SHELL.tolist()]


def _scan_cell_by_cell(grid, n_owned):
    """The half-shell scan as it was written before the runs (a reference): for each scan row
    the later particles of its own cell, then each HALF_SHELL cell in turn; the pairs in the
    order found, and the tests made."""
    from dem.neighbor import HALF_SHELL
    scell, dims, cell_start, cell_items, spos, srb, sgid = grid
    nx, ny, nz = dims.tolist()
    pairs, tests = [], 0
    for u in range(len(scell)):
        c = int(scell[u])
        cx, cy, cz = c % nx, (c // nx) % ny, c // (nx * ny)
        a = int(cell_items[u])
        ranges = [(u + 1, int(cell_start[c + 1]))]
        for dx, dy, dz in HALF_SHELL.tolist():
            x, y, z = cx + dx, cy + dy, cz + dz
            if 0 <= x < nx and 0 <= y < ny and 0 <= z < nz:
                d = x + nx * (y + ny * z)
                ranges.append((int(cell_start[d]), int(cell_start[d + 1])))
        for v0, v1 in ranges:
            tests += v1 - v0
            for v in range(v0, v1):
                b = int(cell_items[v])
                if a >= n_owned and b >= n_owned:
                    continue
                if np.sum((spos[v] - spos[u]) ** 2) < (srb[u] + srb[v]) ** 2:
                    pairs.append((a, b) if sgid[u] < sgid[v] else (b, a))
    return pairs, tests


@pytest.mark.parametrize("n,spread,n_owned", [(400, 1.0, 400), (300, 0.6, 200), (250, 3.0, 250), (60, 0.05, 60)])
def test_scan_by_runs_finds_the_pairs_cell_by_cell_did(n, spread, n_owned, rng):
    """scan_rows over HALF_SHELL_RUNS gives the same pairs in the same order, and the same count
    of pair tests, as the cell-by-cell half shell (the reference above): a dense cloud, one with
    ghosts, a dilute one (cells on the box's faces and edges clip their runs) and one so small
    that the grid is a single cell."""
    from dem.neighbor import HALF_SHELL_RUNS, CellGrid, scan_rows
    pos = rng.uniform(0, spread, (n, 3))
    rb = rng.uniform(0.02, 0.08, n)
    gid = rng.permutation(n).astype(np.int64)
    grid = CellGrid("linkcell", pos, rb, gid)
    assert grid.dims.prod() > 1 or n == 60
    rows = np.arange(n, dtype=np.int64)
    pi = np.empty(n * n, dtype=np.int64)
    pj = np.empty(n * n, dtype=np.int64)
    count, tests = scan_rows(rows, 0, n, grid.arrays, HALF_SHELL_RUNS, n_owned, pi, pj, 0)
    expect, expect_tests = _scan_cell_by_cell(grid.arrays, n_owned)
    assert list(zip(pi[:count].tolist(), pj[:count].tolist())) == expect
    assert tests == expect_tests
