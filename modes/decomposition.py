"""Link-block space decomposition (Yan & Regueiro §3): px x py x pz blocks over the domain box.

A particle is owned by the block that holds its centre (floor of its scaled coordinate, so a
centre exactly on a face belongs to the upper block; centres outside the box belong to the
nearest edge block). Each block needs as ghosts every particle that can touch one of its own:
a pair touches only if the centres are closer than r_i + r_j <= 2 r_max (bounding radii), so
the border layer is the largest bounding diameter wide (slightly widened against round-off),
and a block must be at least that wide, or a ghost would have to come from beyond the 26
neighbours. numpy and small numba kernels (block_of, border_lists, direction_of): no MPI, no physics.
"""
import itertools

import numpy as np
from numba import njit

# the 26 neighbour offsets, in a fixed order; direction k's opposite is 25 - k
DIRECTIONS = np.array([d for d in itertools.product((-1, 0, 1), repeat=3) if d != (0, 0, 0)], dtype=np.int64)
OPPOSITE = np.array([int(np.flatnonzero((DIRECTIONS == -d).all(axis=1))[0]) for d in DIRECTIONS])


class DecompositionError(ValueError):
    """A decomposition that cannot work; str() is one line."""


class BlockGrid:
    """Blocks of the box [2, 3] split dims = (px, py, pz) ways. Uniform by default (block edges
    lo + i h); with cuts, a tuple of three arrays [dims[a] - 1] of ascending inner cut planes per
    axis (the planes of LAMMPS's `balance shift`: a tensor-product grid whose slabs may differ in
    width), the edges lo, cuts..., hi."""

    def __init__(self, box, dims, cuts=None):
        self.lo = np.asarray(box[0], dtype=np.float64)
        self.hi = np.asarray(box[1], dtype=np.float64)
        self.dims = np.asarray(dims, dtype=np.int64)
        self.h = (self.hi - self.lo) / self.dims
        self.cuts = None if cuts is None else tuple(np.asarray(c, dtype=np.float64) for c in cuts)
        if self.cuts is not None:
            self.edges = tuple(np.concatenate(([self.lo[a]], self.cuts[a], [self.hi[a]])) for a in range(3))
            # the narrowest block along each axis [m]
            self.h = np.array([float(np.diff(e).min()) for e in self.edges])

    def block_of(self, pos):
        """Block coordinates [n, 3] of centres pos [n, 3] (a centre on a cut belongs to the upper block)."""
        pos = np.ascontiguousarray(pos, dtype=np.float64).reshape(-1, 3)
        if self.cuts is None:
            return _uniform_blocks(pos, self.lo, self.h, self.dims)
        return _cut_blocks(pos, self.edges[0], self.edges[1], self.edges[2])

    def leavers(self, pos, coords):
        """The block of each centre pos [n, 3] (block_of), marks of those not in block coords [3]
        (int8 [n]: numpy's (target != coords).any(axis=1) took 180 us at 6000 particles) and their
        number, in one numba call (block_of, the marks and a count took ~8 us a step at 900
        particles, every step with --skin 0)."""
        pos = np.ascontiguousarray(pos, dtype=np.float64).reshape(-1, 3)
        coords = np.asarray(coords, dtype=np.int64).reshape(3)
        if self.cuts is None:
            return _leavers(pos, True, self.lo, self.h, self.dims, _NO_EDGES, _NO_EDGES, _NO_EDGES, coords)
        return _leavers(pos, False, self.lo, self.h, self.dims, self.edges[0], self.edges[1], self.edges[2], coords)

    def bounds(self, coords):
        """Lower and upper corner [3] of block `coords`."""
        coords = np.asarray(coords)
        if self.cuts is None:
            return self.lo + coords * self.h, self.lo + (coords + 1) * self.h
        return (np.array([self.edges[a][coords[a]] for a in range(3)]),
                np.array([self.edges[a][coords[a] + 1] for a in range(3)]))

    def inner_cuts(self):
        """The inner cut planes [m] along x, y, z: a tuple of three arrays [dims[a] - 1]."""
        if self.cuts is not None:
            return self.cuts
        return tuple(self.lo[a] + self.h[a] * np.arange(1, self.dims[a]) for a in range(3))

    def neighbour(self, coords, k):
        """Coordinates of the neighbour in direction k, or None beyond the grid (not periodic)."""
        c = np.asarray(coords) + DIRECTIONS[k]
        if np.any(c < 0) or np.any(c >= self.dims):
            return None
        return c

    def fits(self, width):
        """Whether every split axis has blocks at least `width` [m] wide."""
        return not np.any((self.dims > 1) & (self.h < width))

    def check_width(self, width):
        """Refuse blocks narrower than the border layer (a particle larger than a block)."""
        for k, name in enumerate("xyz"):
            if self.dims[k] > 1 and self.h[k] < width:
                raise DecompositionError(
                    f"blocks are {self.h[k]:.3g} m wide along {name} ({self.dims[k]} blocks) but the largest "
                    f"particle needs a border layer of {width:.3g} m (its bounding diameter): use fewer "
                    f"blocks along {name}")


@njit(cache=True)
def _uniform_blocks(pos, lo, h, dims):
    """floor((x - lo) / h) per axis, clipped to the grid (numpy's five passes took 30 us at 800)."""
    out = np.empty((pos.shape[0], 3), dtype=np.int64)
    for p in range(pos.shape[0]):
        for a in range(3):
            c = int(np.floor((pos[p, a] - lo[a]) / h[a]))
            out[p, a] = min(max(c, 0), dims[a] - 1)
    return out


@njit(cache=True)
def _cut_blocks(pos, ex, ey, ez):
    """The slab of each axis's edges (lo, cuts..., hi) holding the centre: the number of inner cuts
    at or below it (a centre on a cut belongs to the upper block)."""
    out = np.empty((pos.shape[0], 3), dtype=np.int64)
    for p in range(pos.shape[0]):
        out[p, 0] = np.searchsorted(ex[1:-1], pos[p, 0], side="right")
        out[p, 1] = np.searchsorted(ey[1:-1], pos[p, 1], side="right")
        out[p, 2] = np.searchsorted(ez[1:-1], pos[p, 2], side="right")
    return out


def extent_grid(lo, hi, dims):
    """The paper's updateGrid (Yan & Regueiro §3.3, flowchart step 9, for load balance): the dims
    grid of blocks over the extent lo..hi [3] of the particle centres [m], widened by 1e-9 of the
    span so that the extreme centres lie inside, rather than over the whole domain box. An axis
    along which every centre is the same (a monolayer) is widened by 1e-9 of the largest span or
    coordinate instead, so that its blocks keep a width (too thin for a split axis: fits says so)."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    span = hi - lo
    scale = max(float(span.max()), float(np.abs(lo).max()), float(np.abs(hi).max()), 1e-300)
    pad = 1e-9 * np.where(span > 0.0, span, scale)
    return BlockGrid(np.array([lo - pad, hi + pad]), dims)


# bins per axis of the load profiles that place balanced cuts: a cut lands within 1/BALANCE_BINS of
# the centres' extent of its quantile before the linear interpolation inside the bin
BALANCE_BINS = 1024


def load_profiles(pos, weight, lo, hi, bins=BALANCE_BINS):
    """The load of particles (centres pos [n, 3], each of weight `weight`: [n] or one number) along
    each axis: histograms [3, bins] over the extent lo..hi [3] of the centres [m] (a centre outside
    it counts in the end bin)."""
    prof = np.zeros((3, bins))
    if len(pos) == 0:
        return prof
    lo = np.asarray(lo, dtype=np.float64)
    span = np.asarray(hi, dtype=np.float64) - lo
    span = np.where(span > 0.0, span, 1.0)
    w = np.broadcast_to(np.asarray(weight, dtype=np.float64), (len(pos),))
    for a in range(3):
        b = np.clip(np.floor((pos[:, a] - lo[a]) / span[a] * bins), 0, bins - 1).astype(np.int64)
        prof[a] = np.bincount(b, weights=w, minlength=bins)
    return prof


def balanced_grid(box, lo, hi, dims, profiles, width):
    """The dims grid whose cut planes split the load profiles [3, bins] (over the centres' extent
    lo..hi [3], load_profiles) into equal parts: along an axis of P blocks, cut k sits where the
    cumulative load reaches k/P of the total (linearly inside its bin). As in LAMMPS's `balance
    shift` (Plimpton et al., "Load balancing", LAMMPS manual), the cuts are planes through the
    whole grid, so along each axis the load balances between slabs. With the particle count as
    load this splits the particles equally; with each rank's measured compute time spread over
    its particles (LAMMPS's `weight time`) it equalises time, whatever makes a particle dear (its
    contacts, its shape, a slower core). The outer edges are the box's (widened to the extent where
    centres lie outside it). Blocks narrower than width [m] (the border layer) are widened by
    pushing cuts apart; returns None where an axis cannot hold P such blocks or its load is empty."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    outer_lo = np.minimum(np.asarray(box[0], dtype=np.float64), lo)
    outer_hi = np.maximum(np.asarray(box[1], dtype=np.float64), hi)
    wide = width * (1.0 + 1e-9)
    cuts = []
    for a in range(3):
        parts = int(dims[a])
        if parts == 1:
            cuts.append(np.zeros(0))
            continue
        prof = np.asarray(profiles[a], dtype=np.float64)
        cum = np.concatenate(([0.0], np.cumsum(prof)))
        total = cum[-1]
        if not total > 0.0:
            return None
        bins = len(prof)
        edges = lo[a] + (hi[a] - lo[a]) * np.arange(bins + 1) / bins
        target = total * np.arange(1, parts) / parts
        k = np.clip(np.searchsorted(cum, target, side="left"), 1, bins)  # cum[k-1] < target <= cum[k]
        frac = (target - cum[k - 1]) / np.maximum(cum[k] - cum[k - 1], 1e-300)
        c = edges[k - 1] + frac * (edges[k] - edges[k - 1])
        for i in range(parts - 1):  # at least a border layer from the block below ...
            c[i] = max(c[i], (c[i - 1] if i else outer_lo[a]) + wide)
        for i in range(parts - 2, -1, -1):  # ... and from the block above
            c[i] = min(c[i], (c[i + 1] if i < parts - 2 else outer_hi[a]) - wide)
        if np.any(np.diff(np.concatenate(([outer_lo[a]], c, [outer_hi[a]]))) < width):
            return None
        cuts.append(c)
    return BlockGrid(np.array([outer_lo, outer_hi]), dims, cuts)


def blended_grid(current, target, keep):
    """target's grid (its outer edges) with each inner cut plane moved only (1 - keep) of the way
    from current's (same dims): a damped step towards a balance measured under noise. Between two
    inner cuts a block is at least as wide as the narrower of the two grids' blocks there; an
    outer block may not be (the outer edges move too), so the caller checks fits()."""
    cuts = tuple(keep * c + (1.0 - keep) * t for c, t in zip(current.inner_cuts(), target.inner_cuts()))
    return BlockGrid(np.array([target.lo, target.hi]), target.dims, cuts)


def block_counts(grid, pos):
    """Particles [px, py, pz] whose centre (pos [n, 3]) each block of grid holds."""
    counts = np.zeros(tuple(int(d) for d in grid.dims), dtype=np.int64)
    if len(pos):
        np.add.at(counts, tuple(grid.block_of(pos).T), 1)
    return counts


def border_width(rbound_max):
    """Border (ghost) layer width [m]: the largest bounding diameter, widened by 1e-9 relative."""
    return 2.0 * rbound_max * (1.0 + 1e-9)


# border_lists' faces: all six (axis a low side bit 2a, high side 2a + 1)
ALL_FACES = 63


def border_lists(pos, lo, hi, width, faces=ALL_FACES):
    """For each of the 26 directions, the particles (centres pos [n, 3]) within `width` of the
    block faces on that side, ascending: direction k's are items[start[k]:start[k + 1]] (start
    [27], items int64). Per axis, offset -1 needs x - lo < width, +1 needs hi - x < width, 0
    nothing (a box-distance test, a superset of the sphere test). faces: the faces that count, as
    bits (axis a low side 2a, high side 2a + 1; face_bits): a direction that needs another lists
    nothing (a block's faces on the box have no neighbour, and its particles there none to send)."""
    return border_lists_kernel(np.ascontiguousarray(pos, dtype=np.float64), np.asarray(lo, dtype=np.float64),
                               np.asarray(hi, dtype=np.float64), float(width), NEEDS, int(faces))


def face_bits(directions):
    """The faces (border_lists' bits) that the directions [k] need."""
    bits = 0
    for k in directions:
        bits |= int(NEEDS[k])
    return bits


def _needs():
    """The faces each direction needs, as bits (axis a low side 2a, high side 2a + 1) [26]."""
    out = np.zeros(len(DIRECTIONS), dtype=np.int64)
    for k, d in enumerate(DIRECTIONS):
        for a in range(3):
            if d[a]:
                out[k] |= 1 << (2 * a + (d[a] > 0))
    return out


# the faces each direction needs, as bits (border_lists' test; modes.halo pack_border_messages)
NEEDS = _needs()


@njit(cache=True)
def border_lists_kernel(pos, lo, hi, width, needs, faces):
    """border_lists in two passes (count, fill) over a face code per particle, so that the many
    particles near no face cost six comparisons (a [26, n] mask of every test took 0.1 ms at 800
    particles)."""
    n = pos.shape[0]
    nd = needs.shape[0]
    code = np.zeros(n, dtype=np.int64)
    start = np.zeros(nd + 1, dtype=np.int64)
    for p in range(n):
        c = 0
        for a in range(3):
            if pos[p, a] - lo[a] < width:
                c |= 1 << (2 * a)
            if hi[a] - pos[p, a] < width:
                c |= 1 << (2 * a + 1)
        c &= faces
        code[p] = c
        if c:
            for k in range(nd):
                if c & needs[k] == needs[k]:
                    start[k + 1] += 1
    for k in range(nd):
        start[k + 1] += start[k]
    items = np.empty(start[nd], dtype=np.int64)
    fill = start[:nd].copy()
    for p in range(n):
        c = code[p]
        if c:
            for k in range(nd):
                if c & needs[k] == needs[k]:
                    items[fill[k]] = p
                    fill[k] += 1
    return start, items


_NO_EDGES = np.zeros(2)


@njit(cache=True)
def _leavers(pos, uniform, lo, h, dims, ex, ey, ez, coords):
    """BlockGrid.leavers: _uniform_blocks or _cut_blocks, the marks and their count in one pass."""
    n = pos.shape[0]
    target = np.empty((n, 3), dtype=np.int64)
    out = np.zeros(n, dtype=np.int8)
    count = 0
    for p in range(n):
        if uniform:
            for a in range(3):
                c = int(np.floor((pos[p, a] - lo[a]) / h[a]))
                target[p, a] = min(max(c, 0), dims[a] - 1)
        else:
            target[p, 0] = np.searchsorted(ex[1:-1], pos[p, 0], side="right")
            target[p, 1] = np.searchsorted(ey[1:-1], pos[p, 1], side="right")
            target[p, 2] = np.searchsorted(ez[1:-1], pos[p, 2], side="right")
        if target[p, 0] != coords[0] or target[p, 1] != coords[1] or target[p, 2] != coords[2]:
            out[p] = 1
            count += 1
    return target, out, count


def direction_of(coords_from, coords_to):
    """Direction index k with coords_to = coords_from + DIRECTIONS[k] (coords_to [n, 3]);
    -1 where the target is not a neighbour (a particle that jumped more than a block)."""
    return _direction_of(np.asarray(coords_from, dtype=np.int64).reshape(3),
                         np.ascontiguousarray(coords_to, dtype=np.int64).reshape(-1, 3), DIRECTIONS)


@njit(cache=True)
def _direction_of(origin, to, directions):
    table = np.full(27, -1, dtype=np.int64)
    for k in range(directions.shape[0]):
        table[(directions[k, 0] + 1) * 9 + (directions[k, 1] + 1) * 3 + (directions[k, 2] + 1)] = k
    out = np.full(to.shape[0], -1, dtype=np.int64)
    for p in range(to.shape[0]):
        d0 = to[p, 0] - origin[0]
        d1 = to[p, 1] - origin[1]
        d2 = to[p, 2] - origin[2]
        if abs(d0) <= 1 and abs(d1) <= 1 and abs(d2) <= 1:
            out[p] = table[(d0 + 1) * 9 + (d1 + 1) * 3 + (d2 + 1)]
    return out


def fit_skin(grid, width, skin, explicit):
    """The neighbour-list skin [m] the blocks allow. Ghosts must cover every pair that can touch
    before the next rebuild, so the border layer is width + skin wide and a block at least that.
    A default skin (explicit False) shrinks to fit (to 0 at worst: neighbours every step); an
    explicit one that does not fit is refused."""
    split = grid.dims > 1
    if not split.any() or skin <= 0:
        return skin
    room = float(grid.h[split].min()) - width
    if skin <= room:
        return skin
    if explicit:
        raise DecompositionError(
            f"a skin of {skin:.3g} m widens the border layer to {width + skin:.3g} m, wider than the "
            f"{width + room:.3g} m blocks: use a skin of at most {max(room, 0.0):.3g} m or fewer blocks")
    return max(room, 0.0) * (1.0 - 1e-9)
