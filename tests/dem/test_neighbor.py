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
