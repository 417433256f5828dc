"""Load-time check of particle-particle overlaps (issue 14, item 3).

A state read from a file or another code (a settled bed) holds resting contacts: overlaps of a
small fraction of a particle's size, which the run continues. Larger ones, two coincident bodies
or a 50 % overlap, would explode at step 1 (the stability guard stops a run whose contact
overlaps more than 5 % of the smaller body's smallest semi-axis, bench.run.guard), so they are
refused at load instead, in one line naming both particles and the overlap.

The measure is the guard's: depth over the smaller of the two smallest semi-axes (a poly-
ellipsoid's smallest of six), depth from the exact contact geometry of the pair's shapes
(dem.forces.pair_contacts: closed form for spheres, PW + Newton for ellipsoids, the octant active
set for poly-ellipsoids), for every pair whose bounding spheres overlap (link-cell search,
dem.neighbor). Two centres closer than 1e-9 of the smaller bounding radius are coincident (no
contact normal exists): refused as such. The screen: the depth (the shortest translation that
separates two convex bodies) is the minimum over unit directions n of h_i(n) + h_j(-n) - n.(x_j - x_i),
h the support function about the centre (contact-mechanics.md §1), so any one direction bounds it
from above; along the line of centres n = (x_j - x_i)/d that bound is h_i(n) + h_j(-n) - d, with
h(n) = |diag(a, b, c) R^T n| for an ellipsoid (R body to world) and r for a sphere; a
poly-ellipsoid's h is bounded by its bounding radius (a body lies inside its bounding sphere):
each shape's support_bound (dem.shapes.<name>). A pair whose bound is below the limit cannot
exceed it, and only the others go to the solver (for spheres the bound is the exact depth). A
1M-ellipsoid rested pack, whose resting contacts are all screened out, checks in about a second.
"""
import numpy as np
from numba import njit

from dem.forces import EXACT, pair_contacts
from dem.integrate import derive_geometry_range, derive_range
from dem.neighbor import PairBuffer, candidate_pairs
from dem.shapes.dispatch import by_shape
from dem.shapes.registry import smallest_semi_axes

# the stability guard's default overlap limit (bench run --guard-overlap)
DEFAULT_OVERLAP_LIMIT = 0.05

support_bound = by_shape(
    "support_bound", "k, nx, ny, nz, rot, axes, rbound, shape", "shape[k]",
    """An upper bound [m] of particle k's support function h_k(n) about its centre along the unit
    world direction n (rot [n, 3, 3] body to world, axes [n, 3], rbound [n] bounding radii,
    shape [n] codes): each registered shape's support_bound (dem.shapes.dispatch).""")


@njit(cache=True)
def _screen(pi, pj, pos, rbound, amin, shape, rot, axes, limit):
    """Per candidate pair: 2 when coincident (centres closer than 1e-9 of the smaller bounding radius),
    1 when the depth may exceed limit x min(amin_i, amin_j) (its upper bound along the line of
    centres, h_i(n) + h_j(-n) - d with each h bounded by its shape's support_bound, exceeds it:
    module docstring), else 0."""
    out = np.zeros(pi.shape[0], dtype=np.int8)
    for k in range(pi.shape[0]):
        i = pi[k]
        j = pj[k]
        d2 = 0.0
        for c in range(3):
            x = pos[j, c] - pos[i, c]
            d2 += x * x
        rmin = min(rbound[i], rbound[j])
        if d2 <= (1e-9 * rmin) ** 2:
            out[k] = 2
            continue
        d = np.sqrt(d2)
        nx = (pos[j, 0] - pos[i, 0]) / d
        ny = (pos[j, 1] - pos[i, 1]) / d
        nz = (pos[j, 2] - pos[i, 2]) / d
        bound = (support_bound(i, nx, ny, nz, rot, axes, rbound, shape)
                 + support_bound(j, nx, ny, nz, rot, axes, rbound, shape) - d)
        if bound > limit * min(amin[i], amin[j]):
            out[k] = 1
    return out


def pair_overlaps(state, screen=0.0):
    """(i [m], j [m], depth [m] [m], ratio [m]) of the touching pairs of the owned particles (local
    indices, i < j in gid), ratio = depth / min(smallest semi-axis of i, of j); a coincident pair
    has depth = ratio = inf. screen > 0: only the pairs that may overlap by more than screen x the
    smaller smallest semi-axis (their bounding spheres do; module docstring)."""
    s = state
    n = s.n_owned
    if n < 2:
        z = np.zeros(0, dtype=np.int64)
        return z, z, np.zeros(0), np.zeros(0)
    pi, pj = candidate_pairs("linkcell", s.pos, s.rbound, s.gid, n, PairBuffer(max(1024, 8 * n)))  # one scan
    amin = smallest_semi_axes(s.axes, s.shape, s.poly)
    rot = np.zeros((s.n, 3, 3))
    derive_range(0, s.n, s.quat, s.angmom, s.inertia, s.shape, rot, np.zeros((s.n, 3)))
    flag = _screen(pi, pj, s.pos, s.rbound, amin, s.shape, rot, s.axes, float(screen))
    keep = flag > 0 if screen > 0 else np.ones(len(pi), dtype=bool)
    pi, pj, coincident = pi[keep], pj[keep], flag[keep] == 2
    m = len(pi)
    if m == 0:
        z = np.zeros(0, dtype=np.int64)
        return z, z, np.zeros(0), np.zeros(0)
    g = s.n if s.has_poly else 0
    oorg, orot, ax6 = np.zeros((g, 3)), np.zeros((g, 3, 3)), np.zeros((g, 6))
    if s.has_poly:
        derive_geometry_range(0, s.n, s.pos, rot, s.axes, s.shape, s.poly, orot, oorg, ax6)
    rows = np.zeros((m, 8))
    ok = np.flatnonzero(~coincident)
    if len(ok):
        sub = np.zeros((len(ok), 8))
        pair_contacts(pi[ok], pj[ok], s.pos, rot, s.axes, s.shape, EXACT, (s.poly, oorg, orot, ax6), sub)
        rows[ok] = sub
    hit = (rows[:, 0] != 0) | coincident
    depth = np.where(coincident, np.inf, rows[:, 1])[hit]
    i, j = pi[hit], pj[hit]
    return i, j, depth, depth / np.minimum(amin[i], amin[j])


def worst_pair_overlap(state, limit=0.0):
    """The deepest particle-particle overlap above `limit` of the smaller smallest semi-axis: (ratio,
    depth [m], gid a, gid b, a < b), ratio = depth / min(smallest semi-axes); inf for coincident bodies;
    None when no pair can exceed the limit (limit 0: the deepest of all touching pairs)."""
    i, j, depth, ratio = pair_overlaps(state, screen=limit)
    if not len(ratio):
        return None
    k = int(np.argmax(np.where(np.isnan(ratio), np.inf, ratio)))
    a, b = sorted((int(state.gid[i[k]]), int(state.gid[j[k]])))
    return float(ratio[k]), float(depth[k]), a, b
