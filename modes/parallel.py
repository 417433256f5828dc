"""Thread schemes as numba loops: who takes which outer particle rows of contact detection.

The paper's five OpenMP schemes (Yan & Regueiro §4.2, Table 1), over the outer particle loop
of contact detection (neighbour estimate + contact resolution) for all-pairs and link-cell:
- partition: thread t takes the contiguous rows [t n/T, (t+1) n/T);
- frogleap:  thread t takes rows t, t+T, t+2T, ...;
- headtail:  thread t takes the row pairs (k, n-1-k) for k = t, t+T, ... (balances a triangle);
- static:    numba prange, default (static) chunking, over blocks of STATIC_BLOCK rows (and then
             of pairs): numba hands each thread one contiguous run of blocks, so static is the
             partition distributed by the runtime instead of by hand;
- dynamic:   rows (and then candidate pairs) handed out at run time in small chunks from a
             shared atomic counter, so it is really dynamic on the default omp layer too
             (numba's prange chunk size only balances on tbb).
Contact resolution: under frogleap and headtail a thread resolves the contacts it found at the
last neighbour rebuild (the paper's loop: for each i, find and resolve its pairs), stores each
pair's forces, and every particle gathers its own (dem.forces, STORE). Under partition, static
and dynamic the list is sorted by global id and cut, at each rebuild, into T contiguous ranges
of whole rows (split_pairs): equal rows (partition), equal pairs (static), or equal estimated
work (dynamic, which re-balances at every rebuild instead of handing out chunks, and between
rebuilds re-cuts from the threads' measured busy times: modes.threads, rebalance): a pair whose
bounding spheres are apart counts 1, one whose bounding spheres overlap the larger contact cost
of its two shapes (CONTACT_COST, from the registered shapes: 10 for two spheres' closed form, 40
where an ellipsoid or poly-ellipsoid needs the iterative solve), so that a scene of spheres
beside ellipsoids splits by cost, not by count.
Thread t resolves range t and sums the forces of the particles whose pairs all lie in it as it
goes, as one thread does (SPLIT); only the particles with pairs in two ranges gather. Where the
ranges hold many particles this spares the gather and the per-pair stores: on 12k packed
ellipsoids the gather alone cost as much as the rest of the per-particle pass. The per-particle
pass (gather, walls, integration, derived quantities) is split in T contiguous blocks of equal
estimated cost (wall_threads, with the wall list). Results never depend on the scheme or the split (DESIGN.md,
Determinism): each particle receives its pair terms in ascending partner id.

Busy time per thread is read from the CPU cycle counter around each thread's share of a phase
(the scheduling level, not inside the physics) and converted to seconds by `cycles_per_second`.
"""
import math
import time

import numpy as np
from llvmlite import ir
from numba import get_thread_id, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from dem.forces import SPLIT, SPLIT_TAKEN, finish_range, resolve_range, wall_candidates_range
from dem.integrate import derive_all
from dem.neighbor import HALF_SHELL_RUNS, cell_of_point, grid_shape, scan_rows
from dem.pairs import NO_KEY, _at, carry_history_sorted_range
from dem.shapes.registry import SHAPES

SCHEMES = ("partition", "frogleap", "headtail", "static", "dynamic")
DEFAULT_SCHEME = "dynamic"   # the scheme of a run with T > 1 threads when none is given
# the schemes whose resolution runs over ranges of the gid-sorted list (SPLIT); the others store
# every pair's forces for the gather
SPLIT_SCHEMES = ("partition", "static", "dynamic")
PARTITION = 0
STATIC = 3
DYNAMIC = 4
STATIC_BLOCK = 64     # rows or pairs per prange iteration of the static scheme
DYNAMIC_ROWS = 16     # rows per dynamic hand-out
DYNAMIC_PAIRS = 64    # candidate pairs per dynamic hand-out (the dynamic scheme with split=False)
WEIGHT_BLOCK = 1024   # pairs per prange iteration of the range cut's per-pair loops (pair_weights)
COUNT_PAD = 8         # int64 counters between two threads' rows of counts (a cache line)
PLACE_BLOCKS = 16     # the placing's blocks of rows per thread, at most (block_shift): a thread's run of
# whole blocks is within half a block, 1/32 of its share, of equal pairs
# threads up to which the placing's blocks are single rows (block_shift): the staging pass that blocks of
# several rows need costs about 42 ns of work a particle (12k packed, one core, with the carry and the
# cut: 1.89 against 1.38 ms), shared by the T threads; single rows need instead one thread's walk over
# the T x n counts, about 0.45 ns an entry (75-92 us at 16 x 12k), so they are faster while
# 0.45 T < 42 / T, up to about 9 threads (8 keeps a margin)
PLACE_ROWS_THREADS = 8
OFFSETS_THREADS_FROM = 65536   # counts [T x rows] from which their write offsets are made by the threads
# entries from which, and ranges from which, the threads place the marked rows' entries and mark the later
# ends (adjacency_marked_threads, cut_ranges): their bucketed placement does 4.5x one thread's work (77.6k
# entries in 16 buckets, one pinned CPU: 0.59 against 0.13 ms), so it gains from 8 cores on
PLACE_THREADS_FROM = 8192
PLACE_THREADS_MIN = 8
# The cost model, from the registered shapes (dem.shapes.shape.Shape, measured by `bench perf --what
# split`), indexed by shape code: a candidate pair whose bounding spheres overlap, in units of one
# whose bounding spheres are apart, costs the larger CONTACT_COST of its two shapes (the dynamic cut);
# a particle's per-particle pass PASS_COST, plus WALL_COST when a wall is on its list, in units of
# a sphere's (the pass's blocks).
CONTACT_COST = np.array([s.contact_cost for s in SHAPES])
PASS_COST = np.array([s.pass_cost for s in SHAPES])
WALL_COST = np.array([s.wall_cost for s in SHAPES])


@intrinsic
def cycle_counter(typingctx):
    """CPU cycle counter (llvm.readcyclecounter): int64 cycles."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.readcyclecounter")
        return builder.call(fn, [])
    return sig, codegen


@intrinsic
def fetch_add(typingctx, arr, idx, val):
    """Atomic arr[idx] += val returning the old value (int64 arrays), sequentially consistent."""
    sig = types.int64(arr, idx, val)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        return builder.atomic_rmw("add", ptr, args[2], "seq_cst")
    return sig, codegen


@njit(cache=True)
def _read_cycles():
    return cycle_counter()


def cycles_per_second(duration=0.02):
    """Calibrate the cycle counter against perf_counter (once per process)."""
    _read_cycles()
    t0, c0 = time.perf_counter(), _read_cycles()
    while time.perf_counter() - t0 < duration:
        pass
    return (_read_cycles() - c0) / (time.perf_counter() - t0)


def scheme_rows(scheme, n, threads):
    """Rows of each thread for the explicit schemes: (row_start [T+1], rows [n]).

    Thread t scans rows[row_start[t]:row_start[t+1]]; static and dynamic need no list
    (identity order, assigned by prange or the atomic counter)."""
    t_count = threads
    if scheme in ("static", "dynamic"):
        per = [np.arange(n)] + [np.zeros(0, dtype=np.int64)] * (t_count - 1)
    elif scheme == "partition":
        bounds = [(t * n) // t_count for t in range(t_count + 1)]
        per = [np.arange(bounds[t], bounds[t + 1]) for t in range(t_count)]
    elif scheme == "frogleap":
        per = [np.arange(t, n, t_count) for t in range(t_count)]
    elif scheme == "headtail":
        half = (n + 1) // 2
        per = []
        for t in range(t_count):
            k = np.arange(t, half, t_count)
            tail = n - 1 - k
            both = np.stack([k, tail], axis=1).ravel()
            per.append(both[np.concatenate([[True], both[1:] != both[:-1]])] if len(both) else both)
    else:
        raise ValueError(f"unknown scheme {scheme!r} ({', '.join(SCHEMES)})")
    row_start = np.zeros(t_count + 1, dtype=np.int64)
    row_start[1:] = np.cumsum([len(p) for p in per])
    return row_start, np.concatenate(per).astype(np.int64)


@njit(parallel=True, cache=True)
def grid_threads(threads, pos, rbound, gid, cutoff):
    """dem.neighbor.bin_particles and sorted_copies by T threads, each over a contiguous range of
    the particles: the bounding box from per-thread minima and maxima; a per-thread counting sort,
    each thread counting its range per cell, the write offsets a prefix sum over (cell, thread),
    so that items within a cell keep ascending local index as one thread's sort gives; each thread
    then writes its particles and their scan-ordered copies. Returns (dims, cell_start,
    cell_items, spos, srb, sgid, scell) of dem.neighbor.CellGrid, identical to one thread's."""
    n = pos.shape[0]
    box = np.empty((threads, 6))
    for t in prange(threads):
        for k in range(3):
            box[t, k] = np.inf
            box[t, 3 + k] = -np.inf
        for p in range(t * n // threads, (t + 1) * n // threads):
            for k in range(3):
                box[t, k] = min(box[t, k], pos[p, k])
                box[t, 3 + k] = max(box[t, 3 + k], pos[p, k])
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        lo[k] = np.inf
        hi[k] = -np.inf
        for t in range(threads):
            lo[k] = min(lo[k], box[t, k])
            hi[k] = max(hi[k], box[t, 3 + k])
    dims, size = grid_shape(n, lo, hi, cutoff)
    ncell = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(n, dtype=np.int64)
    fill = np.zeros((threads, ncell), dtype=np.int64)
    for t in prange(threads):
        for p in range(t * n // threads, (t + 1) * n // threads):
            c = cell_of_point(pos, p, lo, size, dims)
            cell_of[p] = c
            fill[t, c] += 1
    cell_start = np.empty(ncell + 1, dtype=np.int64)
    offsets_by_row_threads(fill, ncell, cell_start)  # each thread's first slot in each cell, in thread order
    cell_items = np.empty(n, dtype=np.int64)
    spos = np.empty((n, 3))
    srb = np.empty(n)
    sgid = np.empty(n, dtype=np.int64)
    scell = np.empty(n, dtype=np.int64)
    for t in prange(threads):
        for p in range(t * n // threads, (t + 1) * n // threads):
            c = cell_of[p]
            u = fill[t, c]
            fill[t, c] = u + 1
            cell_items[u] = p
            spos[u, 0] = pos[p, 0]
            spos[u, 1] = pos[p, 1]
            spos[u, 2] = pos[p, 2]
            srb[u] = rbound[p]
            sgid[u] = gid[p]
            scell[u] = c
    return dims, cell_start, cell_items, spos, srb, sgid, scell


@njit(cache=True)
def n_blocks(n, shift):
    """The number of blocks of 2^shift rows that hold n rows: ceil(n / 2^shift)."""
    return ((n - 1) >> shift) + 1 if n > 0 else 0


def block_shift(n, threads):
    """The placing's blocks of rows (place_by_gid): 2^shift consecutive rows of the list; single
    rows (shift 0) up to PLACE_ROWS_THREADS threads, else the fewest rows a block for which n rows
    make at most PLACE_BLOCKS T blocks; returns shift."""
    if threads <= PLACE_ROWS_THREADS:
        return 0
    shift = 0
    while n_blocks(n, shift) > PLACE_BLOCKS * threads:
        shift += 1
    return shift


@njit(inline="always")
def _rk(rank, p):
    """The place of local particle p in ascending gid order: rank[p] (dem.pairs.gid_ranks), or p
    itself where rank is None, the particles being stored in gid order (numba compiles that case
    apart, with no load: the placing of 2500 and 12k packed ellipsoids' lists, with the carry and
    the cut, at 1 and 2 threads, took 0.87-0.92 of its time with the identity ranks read from an
    array)."""
    if rank is None:
        return p
    return rank[p]


@njit(inline="always")
def _count_blocks(pi, k0, k1, rank, shift, block_count, t):
    """block_count[t, rank of pi[k] >> shift] += 1 for the pairs k0..k1-1 a thread has just written."""
    for k in range(k0, k1):
        block_count[t, _rk(rank, pi[k]) >> shift] += 1


@njit(parallel=True, cache=True)
def scan_threads(code, threads, row_start, rows, grid, n_owned, pi_t, pj_t, counts, tests, busy, rank, shift,
                 block_count):
    """Neighbour scan (dem.neighbor.scan_rows over the grid group) under a scheme into per-thread
    buffers pi_t, pj_t [T, cap]; counts [T], tests [T] (pair tests made) and busy [T] (cycles) per
    thread; block_count [T, >= nb] each thread's pairs per block of 2^shift rows of the list in gid
    order (nb blocks of the rank of their first end, rank [n] or None: place_by_gid), counted as
    they are written (while in cache). A thread's pairs past its buffer are counted but not
    written (counts[t] > cap: the caller scans again)."""
    n = grid[0].shape[0]
    cap = pi_t.shape[1]
    counts[:] = 0
    tests[:] = 0
    busy[:] = 0
    nb = n_blocks(n, shift)
    for t in prange(threads):
        for b in range(nb):
            block_count[t, b] = 0
    if code == STATIC:
        for b in prange((n + STATIC_BLOCK - 1) // STATIC_BLOCK):
            t = get_thread_id()
            c0 = cycle_counter()
            k0 = counts[t]
            c, w = scan_rows(rows, b * STATIC_BLOCK, min(n, (b + 1) * STATIC_BLOCK), grid, HALF_SHELL_RUNS, n_owned,
                             pi_t[t], pj_t[t], k0)
            _count_blocks(pi_t[t], k0, min(c, cap), rank, shift, block_count, t)
            counts[t] = c
            tests[t] += w
            busy[t] += cycle_counter() - c0
    elif code == DYNAMIC:
        counter = np.zeros(1, dtype=np.int64)
        for t in prange(threads):
            c0 = cycle_counter()
            c = 0
            w = 0
            while True:
                s = fetch_add(counter, 0, DYNAMIC_ROWS)
                if s >= n:
                    break
                k0 = c
                c, dw = scan_rows(rows, s, min(n, s + DYNAMIC_ROWS), grid, HALF_SHELL_RUNS, n_owned, pi_t[t], pj_t[t],
                                  c)
                _count_blocks(pi_t[t], k0, min(c, cap), rank, shift, block_count, t)
                w += dw
            counts[t] = c
            tests[t] = w
            busy[t] = cycle_counter() - c0
    else:
        for t in prange(threads):
            c0 = cycle_counter()
            c, w = scan_rows(rows, row_start[t], row_start[t + 1], grid, HALF_SHELL_RUNS, n_owned, pi_t[t], pj_t[t], 0)
            _count_blocks(pi_t[t], 0, min(c, cap), rank, shift, block_count, t)
            counts[t] = c
            tests[t] = w
            busy[t] = cycle_counter() - c0


@njit(cache=True)
def find_pairs_threads(code, threads, cutoff, pos, rbound, gid, n_owned, row_start, rows, pi_t, pj_t, counts, tests,
                       busy, offsets, rank, shift, block_count):
    """The neighbour estimate by T threads in one call: the grid (grid_threads, cells of edge >=
    cutoff) and the scan under the scheme into pi_t, pj_t [T, cap] (scan_threads), offsets [T+1] of
    the threads' pairs in thread order and block_count [T, >= nb] their counts per block of 2^shift
    rows by the rank of their first end (rank [n] or None: place_by_gid). Returns (m, the largest
    thread count): m = -1 when a thread's buffer was too small (grow cap to the count and call
    again). The pairs are then placed into one list in ascending (gid_i, gid_j) (place_by_gid), or
    in thread order (compact_pairs) and into its sorted view (place_by_gid)."""
    grid = grid_threads(threads, pos, rbound, gid, cutoff)
    dims, cell_start, cell_items, spos, srb, sgid, scell = grid
    scan_threads(code, threads, row_start, rows, (scell, dims, cell_start, cell_items, spos, srb, sgid), n_owned,
                 pi_t, pj_t, counts, tests, busy, rank, shift, block_count)
    top = 0
    for t in range(threads):
        top = max(top, counts[t])
    if top > pi_t.shape[1]:
        return -1, top
    offsets[0] = 0
    for t in range(threads):
        offsets[t + 1] = offsets[t] + counts[t]
    return offsets[threads], top


@njit(parallel=True, cache=True)
def compact_pairs(threads, pi_t, pj_t, offsets, pi, pj):
    """Concatenate the per-thread pair buffers in thread order into pi, pj [sum counts]."""
    for t in prange(threads):
        o = offsets[t]
        for k in range(offsets[t + 1] - o):
            pi[o + k] = pi_t[t, k]
            pj[o + k] = pj_t[t, k]


@njit(parallel=True, cache=True)
def place_by_gid(threads, pi_t, pj_t, offsets, rank, n, block_count, shift, spi, spj, order, carry=None, cut=None):
    """The threads' pairs (pi_t, pj_t [T, cap], thread t's offsets[t+1] - offsets[t] of them:
    gid[pi] < gid[pj]) placed in ascending (gid_i, gid_j) into spi, spj [m], with no sort of the
    whole list: a bucket sort by blocks of 2^shift rows (the rank of the first end among the n
    local particles, rank [n]: gid_ranks, or None where they are stored in gid order: _rk; nb =
    ceil(n / 2^shift) blocks: block_shift), from each thread's pairs per block,
    counted by the scan (block_count [T, >= nb], rows COUNT_PAD or more apart: scan_threads;
    overwritten), whose T x nb counts one thread turns into write offsets.

    Blocks of single rows (shift 0, up to PLACE_ROWS_THREADS threads): each thread moves its own
    pairs' second ends straight to their places, row by row and within a row in thread order;
    then each thread takes a run of rows of about equal pairs and orders each row by the rank of
    the second end. Blocks of several rows (at most PLACE_BLOCKS T, so that the offsets' walk does
    not grow with T times the particles): each thread moves its own pairs (first end's rank,
    second end, index: int32, local indices and pair counts being below 2^31) into the blocks'
    part of a staging list, block by block and within a block in thread order; then each thread
    takes a run of whole blocks of about equal pairs, sorts them by row within the block (a
    counting sort over its 2^shift rows, in cache) straight into their places in the list, and
    orders each row. On 12k packed ellipsoids' 57k pairs, one core, with the carry and the cut:
    single rows 1.38 ms at 2 ranges and 1.63 at 16, blocks 1.89 and 2.06 (2500: 0.271 against
    0.364 ms at 2 ranges). The placing before blocks counted each thread's pairs per row too, but
    had every thread read the whole T x n table (a pass over every particle per thread, which more
    threads do not shorten).

    A row is ordered by _order_short_row where it holds up to 8 pairs, as nearly all do (packed
    ellipsoids hold 3-7 a row): a sorting network, where an insertion sort mispredicted a branch
    at about every pair (0.44 against 0.14 ms for the same 57k pairs already in order). Where
    order [m] is not empty, order[a] = the index of spi[a]'s pair in the threads' list
    concatenated in thread order (compact_pairs): the sorted view of a list kept in thread order
    (dem.pairs.sorted_view). The keys are distinct, so the order is the one dem.pairs.sort_by_gid
    gives. Three parallel regions with a cut, two without.

    carry = (gid, corder, key, okey, oorder, oon, ohist, hist, on), or None: each thread then
    also carries the history of the rows it has just placed from the old list
    (dem.pairs.carry_history_sorted_range over its run of the sorted order, corder None where the
    list itself is sorted, else order; the other arguments as there), while they are in its cache
    and in the same parallel region, in place of a pass of its own over the new list.

    cut = (shares [T], n_owned, gid [n], bounds [T+1], gat [n_owned]), or None: the list (sorted
    itself: order empty) is then also cut into the T ranges of cut_ranges at equal pairs (the
    bounds of cut_at_equal_pairs, read from the placed list), and in a third region each thread
    collects its range's later ends and clears its block of gat (cut_ranges' first region);
    mark_and_home then finishes the cut. Returns (later [T, >= 1], later_at [T, >= 1], got [T,
    COUNT_PAD]) for mark_and_home (empty where cut is None)."""
    m = offsets[threads]
    viewed = order.shape[0] > 0
    nb = n_blocks(n, shift)
    # the write offsets: block-major, then thread, each thread's pairs of a block in its own order
    # (one thread's walk over the T x nb counts: T x n for single rows, else at most 16 T^2)
    base = np.empty(nb + 1, dtype=np.int64)
    _offsets_by_row(block_count, nb, base)
    # thread g places blocks run[g] .. run[g+1]-1: the block boundary nearest to g m / T pairs
    run = np.empty(threads + 1, dtype=np.int64)
    run[0] = 0
    b = 0
    for g in range(1, threads):
        target = (g * m) // threads
        while b < nb and base[b + 1] <= target:
            b += 1
        if b < nb and base[b + 1] - target < target - base[b]:
            run[g] = b + 1
        else:
            run[g] = b
        run[g] = max(run[g], run[g - 1])
    run[threads] = nb
    # blocks of one row (shift 0) are rows: the staging list is the placed list, rows not yet ordered
    staged = shift > 0
    st_row = np.empty(m if staged else 0, dtype=np.int32)
    st_j = np.empty(m if staged else 0, dtype=np.int32)
    st_x = np.empty(m if staged and viewed else 0, dtype=np.int32)
    first = np.empty(n, dtype=np.int64)   # the particle of each rank: the first end of every pair of its row
    for t in prange(threads):
        for p in range(t * n // threads, (t + 1) * n // threads):
            first[_rk(rank, p)] = p
        o = offsets[t]
        for k in range(offsets[t + 1] - o):
            r = _rk(rank, pi_t[t, k])
            b = r >> shift
            u = block_count[t, b]
            block_count[t, b] = u + 1
            if staged:
                st_row[u] = r
                st_j[u] = pj_t[t, k]
                if viewed:
                    st_x[u] = o + k
            else:
                spj[u] = pj_t[t, k]
                if viewed:
                    order[u] = o + k
    for g in prange(threads):
        r0 = min(run[g] << shift, n)
        r1 = min(run[g + 1] << shift, n)
        p0 = base[run[g]]
        p1 = base[run[g + 1]]
        end = np.zeros(r1 - r0 + 1, dtype=np.int64)   # row r0 + x: pairs p0 + end[x - 1] .. p0 + end[x] - 1
        if staged:
            for q in range(p0, p1):
                end[st_row[q] - r0 + 1] += 1
            for x in range(r1 - r0):
                end[x + 1] += end[x]
            for q in range(p0, p1):
                x = st_row[q] - r0
                u = p0 + end[x]
                end[x] += 1
                spj[u] = st_j[q]
                if viewed:
                    order[u] = st_x[q]
        else:
            for x in range(r1 - r0):
                end[x] = base[r0 + x + 1] - p0
        lo = p0
        keys = np.empty(8, dtype=np.int64)
        held = np.empty(16, dtype=np.int64)
        for x in range(r1 - r0):
            hi = p0 + end[x]
            a = first[r0 + x]
            if hi - lo <= 8 and lo + 8 <= p1:
                _order_short_row(lo, hi, spi, spj, order, viewed, rank, a, keys, held)
            else:
                for u in range(lo, hi):
                    spi[u] = a
                _order_row(lo, hi, spj, order, viewed, rank)
            lo = hi
        if carry is not None:
            gid, corder, key, okey, oorder, oon, ohist, hist, on = carry
            carry_history_sorted_range(p0, p1, spi, spj, gid, corder, key, okey, oorder, oon, ohist, hist, on)
    if cut is None:
        none = np.empty((threads, 0), dtype=np.int64)
        return none, none, np.zeros((threads, COUNT_PAD), dtype=np.int64)
    shares, n_owned, gid, bounds, gat = cut
    cut_at_equal_pairs(spi[:m], threads, shares, bounds)   # spi may be longer than the list (a buffer)
    later = np.empty((threads, _widest(threads, bounds)), dtype=np.int64)
    later_at = np.empty_like(later)
    got = np.zeros((threads, COUNT_PAD), dtype=np.int64)
    for t in prange(threads):
        last = _rk(rank, spi[bounds[t + 1]]) if bounds[t + 1] < m else n   # the next range's first row
        got[t, 0] = _later_ends(bounds[t], bounds[t + 1], spj, rank, last, n_owned, later[t], later_at[t])
        got[t, 1] = _clear_marks(t, threads, n_owned, gid, gat)
    return later, later_at, got


@njit(inline="always")
def _order_short_row(lo, hi, spi, spj, order, viewed, rank, a, keys, held):
    """A row of at most 8 pairs, spi, spj[lo:hi] (and order[lo:hi] where viewed), its first end a
    written and its pairs put into ascending rank of the second end, with no branch on the data
    and loops of fixed length: the 8 entries from lo on are read (the row's and the next rows',
    lo + 8 within the thread's own run of the list), each of the row's a key (rank << 3 | its
    place in the row; the others the largest int64) through a sorting network of 19 comparators
    (Knuth, TAOCP vol. 3, 5.3.4: the best known for 8 inputs), and written back, the next rows'
    entries as they were (their spi is written again with their own row). On 12k packed
    ellipsoids' rows (57k pairs, 3-7 a row) 0.22 ms where the same network over the row's own
    entries took 0.30 and an insertion sort 0.34 (its branch mispredicted at about every pair).
    keys [8], held [16] scratch."""
    k = hi - lo
    for y in range(8):
        v = spj[lo + y]
        held[y] = v
        if viewed:
            held[8 + y] = order[lo + y]
        keys[y] = ((_rk(rank, v) << 3) | y) if y < k else NO_KEY
        spi[lo + y] = a
    _sort8(keys)
    for y in range(8):
        z = (keys[y] & 7) if y < k else y
        spj[lo + y] = held[z]
        if viewed:
            order[lo + y] = held[8 + z]


@njit(inline="always")
def _order_row(lo, hi, spj, order, viewed, rank):
    """A row of the placed list, spj[lo:hi] (and order[lo:hi] where viewed), into ascending rank of
    the second end by insertion: the rows _order_short_row does not take (longer than 8, or at
    the end of a thread's run)."""
    for w0 in range(lo + 1, hi):
        v = spj[w0]
        x = order[w0] if viewed else 0
        key = _rk(rank, v)
        w = w0 - 1
        while w >= lo and _rk(rank, spj[w]) > key:
            spj[w + 1] = spj[w]
            if viewed:
                order[w + 1] = order[w]
            w -= 1
        spj[w + 1] = v
        if viewed:
            order[w + 1] = x


@njit(inline="always")
def _cx(a, b):
    """A comparator: (min, max)."""
    return min(a, b), max(a, b)


@njit(inline="always")
def _sort8(v):
    """v [8] ascending by the 19-comparator network for 8 inputs (Knuth, TAOCP vol. 3, 5.3.4)."""
    a0, a1, a2, a3, a4, a5, a6, a7 = v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]
    a0, a2 = _cx(a0, a2)
    a1, a3 = _cx(a1, a3)
    a4, a6 = _cx(a4, a6)
    a5, a7 = _cx(a5, a7)
    a0, a4 = _cx(a0, a4)
    a1, a5 = _cx(a1, a5)
    a2, a6 = _cx(a2, a6)
    a3, a7 = _cx(a3, a7)
    a0, a1 = _cx(a0, a1)
    a2, a3 = _cx(a2, a3)
    a4, a5 = _cx(a4, a5)
    a6, a7 = _cx(a6, a7)
    a2, a4 = _cx(a2, a4)
    a3, a5 = _cx(a3, a5)
    a1, a4 = _cx(a1, a4)
    a3, a6 = _cx(a3, a6)
    a1, a2 = _cx(a1, a2)
    a3, a4 = _cx(a3, a4)
    a5, a6 = _cx(a5, a6)
    v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7] = a0, a1, a2, a3, a4, a5, a6, a7


@njit(cache=True, parallel=True)
def wall_threads(threads, n_owned, pos, reach, wall_m, wall_d, wall_hist, near, was, shape, cuts, ref):
    """dem.forces.wall_candidates by T threads over contiguous blocks of the owned particles (each
    particle's entry is its own), and in the same region the weights of the per-particle pass
    from the list just made, so that its blocks cuts [T+1] cost no region of their own: T
    contiguous blocks of the owned particles of equal estimated cost, a particle weighing its
    shape's (shape [n] codes) PASS_COST (a sphere 1, an ellipsoid or poly-ellipsoid 2.4) plus its
    WALL_COST when near [n_owned] puts it on the wall list (0.15, 2.2), equal to within one where
    every particle weighs the same (_finish_weights, _finish_blocks). And ref [n_owned, 3] =
    pos[:n_owned], the owned positions at this rebuild (the pair list's reference, against which
    the next rebuild is decided), copied as they are read. Returns the count of the wall list."""
    count = np.zeros(threads, dtype=np.int64)
    w = np.empty(n_owned)
    sums = np.zeros(threads)
    for t in prange(threads):
        a = t * n_owned // threads
        b = (t + 1) * n_owned // threads
        count[t] = wall_candidates_range(a, b, pos, reach, wall_m, wall_d, wall_hist, near, was)
        sums[t] = _finish_weights(a, b, shape, near, w)
        for p in range(a, b):
            ref[p, 0] = pos[p, 0]
            ref[p, 1] = pos[p, 1]
            ref[p, 2] = pos[p, 2]
    _finish_blocks(threads, n_owned, w, sums, cuts)
    return count.sum()


@njit(cache=True)
def _offsets_by_row(count, nrow, start):
    """Counts count [T, nrow] of each thread per row -> start [nrow+1] (row-major prefix sum) and,
    in count, each thread's first write position in each row (thread t after threads < t)."""
    threads = count.shape[0]
    acc = 0
    for r in range(nrow):
        start[r] = acc
        for t in range(threads):
            c = count[t, r]
            count[t, r] = acc
            acc += c
    start[nrow] = acc


@njit(cache=True, parallel=True)
def offsets_by_row_threads(count, nrow, start):
    """_offsets_by_row by the T threads of count [T, nrow], each over a contiguous block of rows: the
    blocks' totals, their prefix on one thread (T numbers), then each block's offsets from its
    base; the same offsets. One thread's walk over the T x nrow counts is a serial phase of the
    rebuild's counting sorts that grows with T (the grid's cells, the adjacency's particles);
    below OFFSETS_THREADS_FROM counts one thread walks them (two more parallel regions gained
    nothing at 2 threads: the grid of 2500 and 12k packed ellipsoids took 0.027 and 0.075 ms
    either way)."""
    threads = count.shape[0]
    if threads * nrow < OFFSETS_THREADS_FROM:
        _offsets_by_row(count, nrow, start)
        return
    base = np.zeros(threads + 1, dtype=np.int64)
    for b in prange(threads):
        acc = 0
        for r in range(b * nrow // threads, (b + 1) * nrow // threads):
            for t in range(threads):
                acc += count[t, r]
        base[b + 1] = acc
    for b in range(threads):
        base[b + 1] += base[b]
    for b in prange(threads):
        acc = base[b]
        for r in range(b * nrow // threads, (b + 1) * nrow // threads):
            start[r] = acc
            for t in range(threads):
                c = count[t, r]
                count[t, r] = acc
                acc += c
    start[nrow] = base[threads]


@njit(cache=True, parallel=True)
def adjacency_in_order_threads(threads, spi, spj, order, n_owned):
    """dem.pairs.adjacency_in_order by T threads: each counts the ends of a contiguous range of the
    sorted order per particle, a prefix over (particle, thread) gives its write offsets, and each
    fills its range's entries in that order, so every row comes out as one thread's, in ascending
    partner gid, with no sort (the marked rows only: adjacency_marked_threads)."""
    m = spi.shape[0]
    count = np.zeros((threads, n_owned), dtype=np.int64)
    for t in prange(threads):
        for a in range(t * m // threads, (t + 1) * m // threads):
            i = spi[a]
            j = spj[a]
            if i < n_owned:
                count[t, i] += 1
            if j < n_owned:
                count[t, j] += 1
    start = np.empty(n_owned + 1, dtype=np.int64)
    offsets_by_row_threads(count, n_owned, start)
    items = np.empty(start[n_owned], dtype=np.int64)
    for t in prange(threads):
        for a in range(t * m // threads, (t + 1) * m // threads):
            k = _at(order, a)
            i = spi[a]
            j = spj[a]
            if i < n_owned:
                items[count[t, i]] = 2 * k
                count[t, i] += 1
            if j < n_owned:
                items[count[t, j]] = 2 * k + 1
                count[t, j] += 1
    return start, items


@njit(cache=True, inline="always")
def _block_of(p, starts, scale):
    """The block b of item p, starts[b] <= p < starts[b+1] (starts [T+1] ascending, blocks of about
    n / T items; scale = T / n): the float estimate p x scale corrected against the starts, with no
    integer division (an entry's block is looked up twice)."""
    b = min(int(p * scale), starts.shape[0] - 2)
    while p >= starts[b + 1]:
        b += 1
    while p < starts[b]:
        b -= 1
    return b


@njit(cache=True, parallel=True)
def adjacency_marked_threads(threads, spi, spj, order, n_owned, mark):
    """dem.pairs.adjacency_in_order's rows of the owned particles with mark[p] != 0 only (mark
    [n_owned] int8; the list seen in (gid_i, gid_j) order: spi, spj [m], order or None) by T
    threads in one pass over the pairs: each collects the marked ends of a contiguous range of the
    pairs (their particle and 2 k + end); the entries are then placed, in that order, into the
    rows, which puts each in ascending partner gid with no sort. Where few particles are marked
    (SPLIT: those whose pairs fall in two ranges, 535 of 12k packed ellipsoids at 2 threads) the
    full adjacency's two passes over every pair took 0.165 ms; placing the entries in pair order
    and then sorting each row by partner gid took 0.103 ms against 0.075 (12k) and 0.042 against
    0.030 ms (2500).

    Few entries (under PLACE_THREADS_FROM), or few ranges (under PLACE_THREADS_MIN), are placed by
    one thread. More are placed by the T threads with no serial pass (_place_entries_threads): the
    share of particles that gather grows with the ranges (12k packed ellipsoids: 4 % at 2 threads,
    13 % at 4, 31 % at 8, 67 % at 16 with 77.6k entries, 94 % at 32), and one thread's placement grew
    with them into a serial phase of the rebuild (issue 32). The threads' placement does more work
    (a count, a move and a fill over the entries, and every particle's row start): 0.59 ms against
    one thread's 0.13 ms for 77.6k entries in 16 buckets on one pinned CPU, a gain from 8 cores on
    (PLACE_THREADS_MIN), none at 2 (12k, 5205 entries: 0.14 against 0.09 ms)."""
    m = spi.shape[0]
    cap = 2 * ((m + threads - 1) // threads) + 2
    ent_p = np.empty((threads, cap), dtype=np.int64)
    ent_item = np.empty((threads, cap), dtype=np.int64)
    got = np.zeros(threads, dtype=np.int64)
    for t in prange(threads):
        got[t] = _marked_entries(t * m // threads, (t + 1) * m // threads, spi, spj, order, n_owned, mark, ent_p[t],
                                 ent_item[t])
    return place_marked_entries(threads, ent_p, ent_item, got, n_owned)


@njit(cache=True, inline="always")
def _marked_entries(a0, a1, spi, spj, order, n_owned, mark, ent_p, ent_item):
    """The marked ends of the pairs a0..a1-1 of the list seen in (gid_i, gid_j) order
    (adjacency_marked_threads), in that order: ent_p [>= 2 (a1 - a0)] their particles, ent_item
    the pairs' 2 k + end; returns their count."""
    c = 0
    for a in range(a0, a1):
        i = spi[a]
        j = spj[a]
        k = _at(order, a)
        if i < n_owned and mark[i] != 0:
            ent_p[c] = i
            ent_item[c] = 2 * k
            c += 1
        if j < n_owned and mark[j] != 0:
            ent_p[c] = j
            ent_item[c] = 2 * k + 1
            c += 1
    return c


@njit(cache=True)
def place_marked_entries(threads, ent_p, ent_item, got, n_owned):
    """The rows (start [n_owned+1], items) of the marked ends thread t collected, ent_p[t, :got[t]]
    and ent_item[t, :got[t]] (_marked_entries over the T consecutive parts of the list), each row
    in the order of the list (adjacency_marked_threads): by one thread, or by the T threads where
    they are many (_place_entries_threads)."""
    total = 0
    for t in range(threads):
        total += got[t]
    if threads >= PLACE_THREADS_MIN and total >= PLACE_THREADS_FROM:
        return _place_entries_threads(threads, ent_p, ent_item, got, n_owned)
    start = np.zeros(n_owned + 1, dtype=np.int64)
    for t in range(threads):
        for c in range(got[t]):
            start[ent_p[t, c] + 1] += 1
    for p in range(n_owned):
        start[p + 1] += start[p]
    fill = start[:n_owned].copy()
    items = np.empty(start[n_owned], dtype=np.int64)
    for t in range(threads):
        for c in range(got[t]):
            p = ent_p[t, c]
            items[fill[p]] = ent_item[t, c]
            fill[p] += 1
    return start, items


@njit(cache=True, parallel=True)
def _bucket_by_block(threads, keys, payload, got, starts):
    """The entries of T threads, thread t's keys[t, :got[t]] with payload[t, :got[t]], moved into
    one bucket per block of keys (block b: starts[b] <= key < starts[b+1], starts [T+1] ascending
    from 0): each thread counts its entries per block (_block_of), a prefix over (block, thread)
    gives each (thread, block) its place, and each thread moves its entries there, so that bucket
    b holds thread 0's entries of the block, then thread 1's, ..., each in its thread's order.
    Returns (base [T+1]: bucket b at base[b]..base[b+1], keys [sum got], payloads [sum got])."""
    scale = threads / max(starts[threads], 1)
    count = np.zeros((threads, threads + COUNT_PAD), dtype=np.int64)   # [thread, block]: entries
    for t in prange(threads):
        for c in range(got[t]):
            count[t, _block_of(keys[t, c], starts, scale)] += 1
    base = np.empty(threads + 1, dtype=np.int64)
    _offsets_by_row(count, threads, base)
    acc = base[threads]
    stage_k = np.empty(acc, dtype=np.int64)
    stage_p = np.empty(acc, dtype=np.int64)
    for t in prange(threads):
        for c in range(got[t]):
            k = keys[t, c]
            b = _block_of(k, starts, scale)
            u = count[t, b]
            count[t, b] = u + 1
            stage_k[u] = k
            stage_p[u] = payload[t, c]
    return base, stage_k, stage_p


@njit(cache=True, parallel=True)
def _place_entries_threads(threads, ent_p, ent_item, got, n_owned):
    """The rows (start [n_owned+1], items) of the entries that thread t collected, ent_p[t, :got[t]]
    (particles) and ent_item[t, :got[t]] (2 k + end), in thread order and each thread's own order,
    by the T threads: the entries are moved into one bucket per block of particles (T contiguous
    blocks: _bucket_by_block), and each thread then fills the rows of its block from its bucket
    (the entries of thread t after those of threads < t: the order one thread's placement gives)."""
    starts = np.empty(threads + 1, dtype=np.int64)
    for b in range(threads + 1):
        starts[b] = (b * n_owned) // threads
    base, stage_p, stage_item = _bucket_by_block(threads, ent_p, ent_item, got, starts)
    acc = base[threads]
    # block b's entries lie at base[b]..base[b+1] of items, as they do in the bucket
    start = np.empty(n_owned + 1, dtype=np.int64)
    fill = np.empty(n_owned, dtype=np.int64)
    items = np.empty(acc, dtype=np.int64)
    for b in prange(threads):
        for p in range(starts[b], starts[b + 1]):
            fill[p] = 0
        for u in range(base[b], base[b + 1]):
            fill[stage_p[u]] += 1
        here = base[b]
        for p in range(starts[b], starts[b + 1]):
            c = fill[p]
            start[p] = here
            fill[p] = here
            here += c
        for u in range(base[b], base[b + 1]):
            p = stage_p[u]
            items[fill[p]] = stage_item[u]
            fill[p] += 1
    start[n_owned] = acc
    return start, items


@njit(cache=True, parallel=True)
def cut_at_equal_weight(w, pi, every, threads, shares, bounds):
    """Cut the sequence of weights w [m] into T contiguous ranges of weight in proportion to shares
    [T] (all 1: equal): bounds [T+1] = 0, the T-1 cuts, m; cut t at the first allowed index k whose
    preceding weight reaches (shares[0] + ... + shares[t-1]) / sum(shares) of the total, t/T for
    equal shares (a range may be empty). Allowed: every index when every, else the row starts of the
    gid-sorted list pi [m] (k = 0 or pi[k] != pi[k-1]: ranges of whole rows). The threads sum
    blocks of WEIGHT_BLOCK weights; one thread then walks the blocks' sums and looks inside only
    the blocks a cut falls in (_cut_in_blocks). One walk over every weight, a chain of dependent
    additions, took 0.145 of a 0.28 ms range cut on 57k pairs of 12k packed ellipsoids at 2
    threads. (A cut may fall one row apart from that walk's where rounding differs; no result
    depends on the cut: DESIGN.md, Determinism.)"""
    m = w.shape[0]
    nb = (m + WEIGHT_BLOCK - 1) // WEIGHT_BLOCK
    sums = np.zeros(nb)
    starts = np.empty(nb + 1, dtype=np.int64)
    for b in prange(nb):
        acc = 0.0
        for k in range(b * WEIGHT_BLOCK, min(m, (b + 1) * WEIGHT_BLOCK)):
            acc += w[k]
        sums[b] = acc
        starts[b] = b * WEIGHT_BLOCK
    starts[nb] = m
    _cut_in_blocks(w, pi, every, threads, shares, bounds, sums, starts)


@njit(cache=True)
def _cut_in_blocks(w, pi, every, threads, shares, bounds, sums, starts):
    """cut_at_equal_weight's cuts (same arguments) from the weights' sums [nb] over the blocks
    starts[b]..starts[b+1]-1 (starts [nb+1] ascending, from 0 to m): one walk over the blocks'
    sums, and inside only the blocks a cut falls in."""
    m = w.shape[0]
    nb = sums.shape[0]
    total = 0.0
    for b in range(nb):
        total += sums[b]
    target = np.empty(threads + 1)  # target[t]: the weight before cut t
    whole = 0.0
    for t in range(threads):
        whole += shares[t]
    before = 0.0
    for t in range(threads + 1):
        target[t] = total * before / whole  # equal shares: t * total / T
        if t < threads:
            before += shares[t]
    bounds[0] = 0
    t = 1
    acc = 0.0  # the weight before the block (or, inside a block walked, before index k)
    for b in range(nb):
        if t < threads and acc + sums[b] >= target[t]:  # a cut falls here or is still open
            for k in range(starts[b], starts[b + 1]):
                if every or k == 0 or pi[k] != pi[k - 1]:
                    while t < threads and acc >= target[t]:
                        bounds[t] = k
                        t += 1
                acc += w[k]
        else:
            acc += sums[b]
    while t <= threads:
        bounds[t] = m
        t += 1


@njit(cache=True, inline="always")
def _equal_pairs_target(m, before, whole, prev):
    """The pair a cut at equal pairs aims at: the first at or past before / whole of the m pairs,
    not before the previous cut prev (cut_at_equal_pairs)."""
    return max(prev, min(m, int(math.ceil(m * before / whole))))


@njit(cache=True)
def cut_at_equal_pairs(pi, threads, shares, bounds):
    """cut_at_equal_weight over pairs that all weigh the same, without their weights: cut t at the
    first row start of the gid-sorted list pi [m] at or after (shares[0] + ... + shares[t-1]) /
    sum(shares) of the m pairs, bounds [T+1]. O(T + the rows' lengths) where the weights' pass
    and block sums cost O(m) (0.035 ms a rebuild of 2500 packed ellipsoids' 11k pairs at 2
    threads)."""
    m = pi.shape[0]
    whole = 0.0
    for t in range(threads):
        whole += shares[t]
    bounds[0] = 0
    before = 0.0
    for t in range(1, threads):
        before += shares[t - 1]
        k = _equal_pairs_target(m, before, whole, bounds[t - 1])
        while 0 < k < m and pi[k] == pi[k - 1]:
            k += 1
        bounds[t] = k
    bounds[threads] = m


@njit(cache=True)
def split_pairs(code, threads, shares, pi, pj, gid, n_owned, pos, rbound, shape, taken, bounds, gat, home_start,
                home_items):
    """Cut the gid-sorted pair list (pi, pj [m]: rows of equal pi contiguous; gid [n]) into T ranges
    of whole rows, bounds [T+1] (pair indices), by the scheme `code`: equal rows (PARTITION), equal estimated
    work (DYNAMIC: for a pair whose bounding spheres of radii rbound [n] [m] overlap at pos [n,3] [m],
    the larger CONTACT_COST of its two shape [n] codes (both spheres 10, else 40); 1 for the others
    and, when taken, for the pairs with a ghost end, whose terms are taken, not resolved: dem.forces,
    SPLIT_TAKEN), equal pairs (otherwise): pair_weights, then cut_ranges, range t taking shares[t] of
    the weight (cut_at_equal_weight). Returns the pairs' weights w [m] (cut_ranges cuts them again
    when measured times rescale them)."""
    w = pair_weights(code, pi, pj, n_owned, pos, rbound, shape, taken)
    cut_ranges(w, threads, shares, pi, pj, gid, n_owned, bounds, gat, home_start, home_items)
    return w


@njit(cache=True)
def uniform_contact_cost(shape):
    """CONTACT_COST of the one shape code of shape [n] (float), or -1 where the codes differ: the
    weight of every pair whose bounding spheres overlap (pair_weights) where all are alike."""
    for p in range(1, shape.shape[0]):
        if shape[p] != shape[0]:
            return -1.0
    return float(CONTACT_COST[shape[0]]) if shape.shape[0] else -1.0


@njit(cache=True, parallel=True)
def pair_weights(code, pi, pj, n_owned, pos, rbound, shape, taken):
    """The estimated cost w [m] of each pair of the list under the scheme `code` (split_pairs), by
    the threads over blocks of the list (each pair's weight is its own)."""
    m = pi.shape[0]
    w = np.empty(m)
    nb = (m + WEIGHT_BLOCK - 1) // WEIGHT_BLOCK
    for b in prange(nb):
        for k in range(b * WEIGHT_BLOCK, min(m, (b + 1) * WEIGHT_BLOCK)):
            w[k] = _pair_weight(code, k, pi, pj, n_owned, pos, rbound, shape, taken)
    return w


@njit(cache=True, inline="always")
def _pair_weight(code, k, pi, pj, n_owned, pos, rbound, shape, taken):
    if code == PARTITION:
        return 1.0 if k == 0 or pi[k] != pi[k - 1] else 0.0
    if code != DYNAMIC:
        return 1.0
    i = pi[k]
    j = pj[k]
    if taken and (i >= n_owned or j >= n_owned):
        return 1.0
    d2 = (pos[j, 0] - pos[i, 0]) ** 2 + (pos[j, 1] - pos[i, 1]) ** 2 + (pos[j, 2] - pos[i, 2]) ** 2
    if d2 >= (rbound[i] + rbound[j]) ** 2:
        return 1.0
    return max(CONTACT_COST[shape[i]], CONTACT_COST[shape[j]])


@njit(cache=True, parallel=True)
def cut_ranges(w, threads, shares, pi, pj, gid, n_owned, bounds, gat, home_start, home_items):
    """Cut the gid-sorted list (pi, pj [m]: gid[pi] < gid[pj], rows of equal pi contiguous, in
    ascending gid) into T ranges of whole rows, range t with shares[t] of the weight w [m]
    (cut_at_equal_weight), or of the pairs where w is None (every pair weighs the same:
    cut_at_equal_pairs), bounds [T+1]. Range t's rows are those of the particles with gid in
    [first[t], first[t+1]), first[t] the gid of its first row. Then gat [n_owned] int8 = 1 for the
    owned particles that a range before their own holds as a pair's later end (gid[pj] at or past
    the next range's first row: they gather their forces), and each range's other particles, those it
    alone sums: home_items [n_owned - gathered] grouped by range, home_start [T+1]; their force and
    torque are zeroed by the thread of their range before it resolves (dem.forces.resolve_range,
    SPLIT). Returns the number of particles the ranges sum themselves.

    Why that is every particle with pairs in two ranges: a range holds a particle's own row and the
    pairs (i, p) whose earlier end i has a row in it, so a particle's pairs lie in its own range
    unless an earlier range holds a pair (i, p). Such a particle gathers even when its own range
    holds none of its pairs (its sum is the same either way: DESIGN.md, Determinism).

    Two parallel regions. In the first each thread reads pj and gid[pj] of its range's pairs once
    and keeps the later ends past its range in a list of its own (a pair's end is marked by one
    thread after every thread has read: marking in place needs gat zeroed in a region before),
    zeroes its block of gat and checks that the block is stored in ascending gid. One thread then
    sets the marks (a few hundred). Where the owned particles are stored in gid order (the
    threads mode's are, as scenes are built and after SerialMode.reorder) range t's particles are
    those of one index interval, and each thread writes its range's home list from it in the second
    region; otherwise a counting sort over T blocks of particles writes them (two more regions).
    Both give ascending index within each range, as one thread's loop gives. The cut of 57k pairs
    of 12k packed ellipsoids at 2 threads took 0.137 ms in four regions with the ranges' counters
    on one cache line (false sharing), 0.109 with them padded apart, 0.040 this way."""
    if w is None:
        cut_at_equal_pairs(pi, threads, shares, bounds)
    else:
        cut_at_equal_weight(w, pi, False, threads, shares, bounds)
    first = _first_gids(threads, bounds, pi, gid)
    later = np.empty((threads, _widest(threads, bounds)), dtype=np.int64)
    later_at = np.empty_like(later)
    got = np.zeros((threads, COUNT_PAD), dtype=np.int64)   # [range, (later ends, block out of gid order)]
    for t in prange(threads):
        got[t, 0] = _later_ends(bounds[t], bounds[t + 1], pj, gid, first[t + 1], n_owned, later[t], later_at[t])
        got[t, 1] = _clear_marks(t, threads, n_owned, gid, gat)
    return mark_and_home(threads, bounds, pi, pj, gid, n_owned, gat, later, later_at, got, home_start, home_items,
                         False)[0]


@njit(cache=True, inline="always")
def _first_gids(threads, bounds, pi, gid):
    """first [T+1]: the gid of the first row of each range of the list (bounds [T+1]; the largest
    int64 for an empty range at the end)."""
    m = pi.shape[0]
    first = np.empty(threads + 1, dtype=np.int64)
    top = np.iinfo(np.int64).max
    for t in range(threads + 1):
        first[t] = gid[pi[bounds[t]]] if bounds[t] < m else top
    return first


@njit(cache=True, inline="always")
def _widest(threads, bounds):
    """The most pairs in one range (bounds [T+1]), at least 1."""
    cap = 1
    for t in range(threads):
        cap = max(cap, bounds[t + 1] - bounds[t])
    return cap


@njit(cache=True, inline="always")
def _later_ends(k0, k1, pj, key, last, n_owned, later, later_at):
    """A range's later ends (cut_ranges): the owned second ends j = pj[k] of its pairs k0..k1-1 with
    key[j] >= last (their gid at or past the next range's first row: key the gids and last that
    row's gid, or key the gid ranks, or None for ranks that are the indices (_rk), and last that
    row), into later, in ascending k, and their pairs k into later_at; returns their count."""
    c = 0
    for k in range(k0, k1):
        j = pj[k]
        if j < n_owned and _rk(key, j) >= last:
            later[c] = j
            later_at[c] = k
            c += 1
    return c


@njit(cache=True, inline="always")
def _clear_marks(t, threads, n_owned, gid, gat):
    """gat = 0 over block t of the T blocks of the owned particles; returns 1 where the block is not
    stored in ascending gid (cut_ranges)."""
    out = 0
    for p in range(t * n_owned // threads, (t + 1) * n_owned // threads):
        gat[p] = 0
        if p > 0 and gid[p] < gid[p - 1]:
            out = 1
    return out


@njit(cache=True, parallel=True)
def mark_and_home(threads, bounds, pi, pj, gid, n_owned, gat, later, later_at, got, home_start, home_items, adjacency):
    """The rest of cut_ranges once each range t has collected its later ends later[t, :got[t, 0]]
    (their pairs later_at[t, :got[t, 0]]) and cleared its block of gat (got[t, 1] = 1 where that
    block is out of gid order): the marks gat, the home lists (home_start, home_items) and, where
    adjacency, the marked rows of the adjacency (adjacency_marked_threads) collected in the home
    lists' region, each range's thread over its own pairs. Returns (the number of particles the
    ranges sum themselves, adj_start, adj_items; both empty unless adjacency).

    Where the owned particles are stored in gid order, range t reads only the pairs that can hold
    a marked end (_marked_entries_cut): its rows up to that of its last marked particle, then its
    recorded later pairs past them. At 2 ranges the first has no marked particle of its own and
    reads none of its pairs, the second its rows up to its last gatherer's; a pass over every pair
    of the list was most of the cut's time (12k packed ellipsoids, 57k pairs: 0.095 of 0.15 ms)."""
    first = _first_gids(threads, bounds, pi, gid)
    ordered = True
    for t in range(threads):
        ordered = ordered and got[t, 1] == 0
    cap = 2 * _widest(threads, bounds) + 2 if adjacency else 0
    ent_p = np.empty((threads, cap), dtype=np.int64)
    ent_item = np.empty((threads, cap), dtype=np.int64)
    agot = np.zeros(threads, dtype=np.int64)
    if ordered:
        # range t's particles: indices lo[t] .. lo[t+1]-1 (range 0 from the first, the last to the end);
        # each range's count of those that gather as they are marked, and its last one (top, -1: none)
        lo = np.empty(threads + 1, dtype=np.int64)
        lo[0] = 0
        for t in range(1, threads):
            lo[t] = np.searchsorted(gid[:n_owned], first[t])
        lo[threads] = n_owned
        gathered = np.zeros(threads, dtype=np.int64)
        top = np.full(threads, -1, dtype=np.int64)
        total = 0
        for t in range(threads):
            total += got[t, 0]
        if threads >= PLACE_THREADS_MIN and total >= PLACE_THREADS_FROM:
            _mark_later_threads(threads, later, got, lo, gat, gathered, top)
        else:
            for t in range(threads):
                for c in range(got[t, 0]):
                    j = later[t, c]
                    if gat[j] == 0:
                        gat[j] = 1
                        h = np.searchsorted(lo, j, side="right") - 1
                        gathered[h] += 1
                        top[h] = max(top[h], j)
        home_start[0] = 0
        for t in range(threads):
            home_start[t + 1] = home_start[t] + (lo[t + 1] - lo[t]) - gathered[t]
        for t in prange(threads):
            u = home_start[t]
            for p in range(lo[t], lo[t + 1]):
                if gat[p] == 0:
                    home_items[u] = p
                    u += 1
            if adjacency:
                gtop = gid[top[t]] if top[t] >= 0 else -1
                agot[t] = _marked_entries_cut(bounds[t], bounds[t + 1], pi, pj, gid, n_owned, gat, gtop, later_at[t],
                                              got[t, 0], ent_p[t], ent_item[t])
    else:
        for t in range(threads):
            for c in range(got[t, 0]):
                gat[later[t, c]] = 1
        count = np.zeros((threads, threads + COUNT_PAD), dtype=np.int64)   # [particle block, range]
        home = np.empty(n_owned, dtype=np.int64)
        for b in prange(threads):
            for p in range(b * n_owned // threads, (b + 1) * n_owned // threads):
                if gat[p] == 0:
                    g = gid[p]
                    h = 0
                    while h + 1 < threads and first[h + 1] <= g:
                        h += 1
                    home[p] = h
                    count[b, h] += 1
        # write offsets: range-major, then particle block (ascending index within a range)
        _offsets_by_row(count[:, :threads], threads, home_start)
        for b in prange(threads):
            for p in range(b * n_owned // threads, (b + 1) * n_owned // threads):
                if gat[p] == 0:
                    t = home[p]
                    home_items[count[b, t]] = p
                    count[b, t] += 1
            if adjacency:
                agot[b] = _marked_entries(bounds[b], bounds[b + 1], pi, pj, None, n_owned, gat, ent_p[b], ent_item[b])
    if not adjacency:
        return home_start[threads], np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    start, items = place_marked_entries(threads, ent_p, ent_item, agot, n_owned)
    return home_start[threads], start, items


@njit(cache=True, inline="always")
def _marked_entries_cut(a0, a1, spi, spj, gid, n_owned, mark, gtop, later_at, n_later, ent_p, ent_item):
    """_marked_entries of a range's pairs a0..a1-1 (mark_and_home, particles stored in gid order),
    reading only the pairs that can hold a marked end. A marked particle is a later end of some
    range; both ends of the range's pairs have gid at or past its first row's. So a marked end has
    its gid in the range's own particles, at most gtop (the gid of the range's last marked particle,
    -1 for none), and then so has the pair's first end (gid_i < gid_j): the pair lies in the rows
    up to gtop's, all read; or it is a later end of this range, recorded with its pair in
    later_at[:n_later] (ascending), of which those past those rows are added. The same entries in
    the same order as _marked_entries over all the pairs."""
    e = a0
    while e < a1 and gid[spi[e]] <= gtop:
        e += 1
    c = _marked_entries(a0, e, spi, spj, None, n_owned, mark, ent_p, ent_item)
    for u in range(n_later):
        k = later_at[u]
        if k >= e:
            ent_p[c] = spj[k]
            ent_item[c] = 2 * k + 1
            c += 1
    return c


@njit(cache=True, parallel=True)
def _mark_later_threads(threads, later, got, lo, gat, gathered, top):
    """cut_ranges' marks by the T threads: range t's later ends later[t, :got[t, 0]] (owned
    particles that an earlier range holds as a pair's later end) set gat[j] = 1, gathered [T]
    counts the particles so marked in each range (range h: indices lo[h]..lo[h+1]-1, lo [T+1]
    ascending) and top [T] holds the last of them (-1: none). The later ends are moved into one
    bucket per range (_bucket_by_block), and each thread then marks the particles of its own
    range from its bucket: no two threads write one mark, and the marks and counts are one
    thread's. One thread's loop over every later end grew with the ranges (at 16 ranges most of
    12k packed ellipsoids gather: issue 32)."""
    base, stage, _ = _bucket_by_block(threads, later, later, got[:, 0], lo)
    for h in prange(threads):
        marked = 0
        last = -1
        for u in range(base[h], base[h + 1]):
            j = stage[u]
            last = max(last, j)
            if gat[j] == 0:
                gat[j] = 1
                marked += 1
        gathered[h] = marked
        top[h] = last


@njit(cache=True)
def rescale_weights(w, bounds, factor):
    """w[k] *= factor[t] for the pairs k of range t (bounds [T+1]): the measured cost per unit of
    estimated weight of each range, relative to their mean."""
    for t in range(factor.shape[0]):
        for k in range(bounds[t], bounds[t + 1]):
            w[k] *= factor[t]


RED_LEN = 5      # per-thread row of dem.forces.RESOLVED
FIN_LEN = 8      # per-thread row of dem.forces.FINISHED


@njit(cache=True, inline="always")
def _fold_resolved(red, t, r):
    """Accumulate one chunk's dem.forces.RESOLVED tuple r into thread t's row red[t]."""
    red[t, 0] += r[0]
    red[t, 1] += r[1]
    if r[2] > red[t, 2]:
        red[t, 2] = r[2]
        red[t, 3] = r[3]
    red[t, 4] += r[4]


@njit(parallel=True, cache=True)
def resolve_threads(code, threads, offsets, kind, method, plist, bodies, polys, law, dt, scratch, split):
    """Contact resolution of the pair list under a scheme (dem.forces.resolve_range, argument
    groups as there). split = (deliver, n_owned, gat, home_start, home_items, terms, terms_start):
    with deliver SPLIT or SPLIT_TAKEN (a gid-sorted list cut by split_pairs into the ranges offsets
    [T+1]) thread t zeroes the force and torque of its range's particles
    home_items[home_start[t]:home_start[t+1]], then resolves the pairs offsets[t]..offsets[t+1]
    summing theirs (SPLIT_TAKEN, hybrid with Newton: the cross pairs' terms [c, 7] taken from row
    terms_start[t] on); else (STORE) every pair's forces are stored
    for the gather, under frogleap and headtail thread t resolving the pairs it found,
    offsets[t]..offsets[t+1]; static: prange over blocks of STATIC_BLOCK pairs; dynamic: chunks of
    DYNAMIC_PAIRS from the atomic counter [1]. scratch = (outs [T, >= OUT_LEN], n0s [T, >= 3]
    per-thread scratch, counter [1], red [T, >= RED_LEN] per-thread reductions, busy [T, >= 1]
    cycles (column 0)); rows padded apart so that no two threads write one cache line.
    Returns dem.forces.RESOLVED over all threads."""
    outs, n0s, counter, red, busy = scratch
    deliver, n_owned, gat, home_start, home_items, terms, terms_start = split
    m = offsets[threads]
    red[:, :] = 0.0
    red[:, 3] = -1.0
    if deliver == SPLIT or deliver == SPLIT_TAKEN:
        force, torque = bodies[10], bodies[11]
        for t in prange(threads):
            c0 = cycle_counter()
            for u in range(home_start[t], home_start[t + 1]):
                p = home_items[u]
                for c in range(3):
                    force[p, c] = 0.0
                    torque[p, c] = 0.0
            r = resolve_range(kind, method, offsets[t], offsets[t + 1], plist, bodies, polys, law, dt, deliver, n_owned,
                              gat, terms[terms_start[t]:], outs[t], n0s[t])
            _fold_resolved(red, t, r)
            busy[t, 0] += cycle_counter() - c0
    elif code == STATIC:
        for b in prange((m + STATIC_BLOCK - 1) // STATIC_BLOCK):
            t = get_thread_id()
            c0 = cycle_counter()
            k = b * STATIC_BLOCK
            r = resolve_range(kind, method, k, min(m, k + STATIC_BLOCK), plist, bodies, polys, law, dt, deliver,
                              n_owned, gat, terms, outs[t], n0s[t])
            _fold_resolved(red, t, r)
            busy[t, 0] += cycle_counter() - c0
    else:
        counter[0] = 0
        for t in prange(threads):
            c0 = cycle_counter()
            k0 = offsets[t]
            k1 = offsets[t + 1]
            while True:
                if code == DYNAMIC:
                    k0 = fetch_add(counter, 0, DYNAMIC_PAIRS)
                    if k0 >= m:
                        break
                    k1 = min(m, k0 + DYNAMIC_PAIRS)
                r = resolve_range(kind, method, k0, k1, plist, bodies, polys, law, dt, deliver, n_owned, gat, terms,
                                  outs[t], n0s[t])
                _fold_resolved(red, t, r)
                if code != DYNAMIC:
                    break
            busy[t, 0] += cycle_counter() - c0
    nc = 0
    calls = 0
    worst = 0.0
    worst_k = -1
    rsum = 0.0
    for t in range(threads):
        nc += int(red[t, 0])
        calls += int(red[t, 1])
        if red[t, 2] > worst:
            worst = red[t, 2]
            worst_k = int(red[t, 3])
        rsum += red[t, 4]
    return nc, calls, worst, worst_k, rsum


@njit(parallel=True, cache=True)
def derive_threads(threads, lo, hi, bodies, polys, poly_scene):
    """dem.integrate.derive_all of particles lo..hi-1 in T contiguous blocks."""
    for t in prange(threads):
        derive_all(lo + (t * (hi - lo)) // threads, lo + ((t + 1) * (hi - lo)) // threads, bodies, polys, poly_scene)


@njit(cache=True, inline="always")
def _finish_weights(a, b, shape, near, w):
    """w[p] = the per-particle pass's weight of the particles p = a..b-1 (wall_threads); returns
    their sum."""
    acc = 0.0
    for p in range(a, b):
        x = PASS_COST[shape[p]] + WALL_COST[shape[p]] * near[p]
        w[p] = x
        acc += x
    return acc


@njit(cache=True)
def _finish_blocks(threads, n_owned, w, sums, cuts):
    """The per-particle pass's blocks cuts [T+1] (wall_threads) from the weights w [n_owned] and
    their sums [T] over the T blocks t n_owned / T .. (t+1) n_owned / T - 1."""
    starts = np.empty(threads + 1, dtype=np.int64)
    for t in range(threads + 1):
        starts[t] = t * n_owned // threads
    _cut_in_blocks(w, np.zeros(0, dtype=np.int64), True, threads, np.ones(threads), cuts, sums, starts)


@njit(parallel=True, cache=True)
def finish_threads(threads, cuts, spheres, gathered, adj, bodies, walls, polys, gravity, dt, poly_scene, ref, outs,
                   fin):
    """dem.forces.finish_range (argument groups as there) of the owned particles in T contiguous
    blocks cuts[t]..cuts[t+1] (wall_threads; particles are independent in this pass: each reads only
    its own pairs' results). outs [T, >= OUT_LEN] is per-thread scratch; fin [T, >= FIN_LEN] holds
    the per-thread results, combined here in thread order. Returns dem.forces.FINISHED."""
    for t in prange(threads):
        r = finish_range(cuts[t], cuts[t + 1], spheres, gathered, adj, bodies, walls, polys,
                         gravity, dt, poly_scene, ref, outs[t])
        fin[t, 0] = r[0]
        fin[t, 1] = r[1]
        fin[t, 2] = r[2]
        fin[t, 3] = r[3]
        fin[t, 4] = r[4]
        fin[t, 5] = r[5]
        fin[t, 6] = r[6]
        fin[t, 7] = r[7]
    n_wall = 0
    wall_worst = 0.0
    wall_p = -1
    ke = 0.0
    wg = 0.0
    n_bad = 0
    first_bad = -1
    disp2 = 0.0
    for t in range(threads):
        n_wall += int(fin[t, 0])
        if fin[t, 1] > wall_worst:
            wall_worst = fin[t, 1]
            wall_p = int(fin[t, 2])
        ke += fin[t, 3]
        wg += fin[t, 4]
        n_bad += int(fin[t, 5])
        if first_bad < 0 and fin[t, 6] >= 0:
            first_bad = int(fin[t, 6])
        disp2 = max(disp2, fin[t, 7])
    return n_wall, wall_worst, wall_p, ke, wg, n_bad, first_bad, disp2
