"""Threads mode: mapping 1-1-1-1-T, T numba threads under one of the paper's five schemes.

The step is the serial one (modes/serial.py) with each phase's loop run by modes/parallel.py:
contact detection (neighbour scan on rebuilds, contact resolution every step) under the chosen
scheme (resolution over ranges of the gid-sorted list that sum as they go, unless split=False or
the scheme is frogleap or headtail: modes/parallel.py), and, unless `threaded = "detection"` (the
paper's situation, for the Amdahl ceiling it reports), the per-particle pass (gather, walls,
integration, derived quantities) in T contiguous blocks. A rebuild's own loops run on the T
threads too (modes/parallel.py): the grid (bounding box, counting sort into cells, scan-ordered
copies) with the scan in one call, the placing of the threads' pairs into the list in gid order
(or, for the schemes that keep them in thread order, into its sorted view), the pair adjacency,
the history carry, the wall list and the range cut, each with the one result the serial loop
gives.
"""
import numpy as np
import numba

from dem.contact.ellipsoid import OUT_LEN
from dem.forces import SPLIT, SPLIT_TAKEN, STORE
from dem.shapes import SPHERE
from dem.neighbor import grid_cutoff
from dem.pairs import gid_ascending, gid_ranks
from modes.base import ModeError, register
from modes import parallel as par
from modes.serial import SerialMode

_CYCLES_PER_S = None
PAD = 32   # doubles between two threads' rows of scratch: 256 bytes, more than a cache line and its neighbour
# dynamic scheme: the ranges' cut is re-made from measured times (ThreadsMode.rebalance) when the
# median over a window of REBALANCE_WINDOW steps of the threads' busy time in the resolution is
# more than REBALANCE_ABOVE times its mean, each range's weights scaled half way (REBALANCE_KEEP of
# the old kept) towards its measured cost per unit of estimated weight
REBALANCE_WINDOW = 20
REBALANCE_ABOVE = 1.01
REBALANCE_KEEP = 0.5
# and its fresh cuts (a neighbour rebuild) give thread t the share 1/speed[t] of the estimated work,
# speed[t] its resolution time per unit of estimated weight relative to the threads' mean, learnt at
# each rebuild step with REBALANCE_KEEP of the old value kept (ThreadsMode.learn_speed)


def cycles_per_second():
    global _CYCLES_PER_S
    if _CYCLES_PER_S is None:
        _CYCLES_PER_S = par.cycles_per_second()
    return _CYCLES_PER_S


@register("threads")
class ThreadsMode(SerialMode):
    """options: threads T, scheme (partition | frogleap | headtail | static | dynamic),
    threaded ("step": every phase; "detection": only neighbour estimate + resolution), split
    (partition, static, dynamic: resolve T ranges of the gid-sorted list, each summing its own
    particles' forces (True, the default), or hand the pairs out as the scheme does, every pair's
    forces stored and gathered (False))."""

    deliver = STORE   # how the resolution hands on the pair forces (dem.forces; set by setup)
    newton = False    # whether split takes cross-border terms (hybrid with Newton's third law: modes.mpi)

    def setup(self, scene, dt, threads=2, scheme=par.DEFAULT_SCHEME, threaded="step", split=True, **kw):
        if scheme not in par.SCHEMES:
            raise ModeError(f"unknown scheme {scheme!r} (schemes: {', '.join(par.SCHEMES)})")
        if threaded not in ("step", "detection"):
            raise ModeError(f"unknown threaded option {threaded!r} (step, detection)")
        if threads < 1:
            raise ModeError(f"threads must be >= 1, got {threads}")
        if threads > numba.config.NUMBA_NUM_THREADS:
            raise ModeError(f"{threads} threads asked but numba started with NUMBA_NUM_THREADS="
                            f"{numba.config.NUMBA_NUM_THREADS}; set it before numba starts (bench run does)")
        self.threads = int(threads)
        self.scheme = scheme
        self.code = par.SCHEMES.index(scheme)
        self.threaded = threaded
        if not isinstance(split, (bool, np.bool_)):
            raise ModeError(f"split must be true or false, got {split!r}")
        self.deliver = SPLIT if split and scheme in par.SPLIT_SCHEMES else STORE
        numba.set_num_threads(self.threads)
        self.cap = 1024
        self.scan_busy = np.zeros(self.threads, dtype=np.int64)
        self.tests = np.zeros(self.threads, dtype=np.int64)
        self.counts = np.zeros(self.threads, dtype=np.int64)
        self.work_imbalance = 1.0
        self.row_plan = None       # (n, row_start, rows) of the scheme (scheme_rows), kept while n holds
        self.pair_t = None     # the threads' pair buffers pi_t, pj_t [T, >= cap], kept between rebuilds
        self.block_count = None  # the threads' counts per block of rows of the list's placing [T, >= nb + COUNT_PAD]
        self.placed = None     # (m, None | view) of the last scan: its pair count, the list's sorted view
        self.carried = None    # the pair count of the last scan where it carried the history as it placed
        self.ref_fill = None   # the list's reference positions of this rebuild, for the wall list to fill
        self.cut_made = None   # (m, weight, bounds, later, later_at, got) of the cut the last scan made as it placed
        self.marked_adj = None   # (gat, adj_start, adj_items): the marked rows made with that cut
        self.no_order = np.zeros(0, dtype=np.int64)
        super().setup(scene, dt, **kw)
        return self

    def _fresh(self):
        super()._fresh()
        t = self.threads
        # the pair list's own loops by the T threads: its order by gid is made as the threads'
        # pairs are placed into it (find_pairs: the list itself, or its sorted view), its adjacency
        # here
        p = self.pairs
        p.sort_pairs = self._placed_sorted
        p.sort_view = self._placed_view

        def build_adjacency(spi, spj, order, n_owned, mark=None):
            if mark is None:
                return par.adjacency_in_order_threads(t, spi, spj, order, n_owned)
            made, self.marked_adj = self.marked_adj, None
            if made is not None and made[0] is mark:   # made with the cut (_finish_cut)
                return made[1], made[2]
            return par.adjacency_marked_threads(t, spi, spj, order, n_owned, mark)
        p.build_adjacency = build_adjacency
        # per-thread scratch and results, each row PAD doubles apart: rows closer than a cache line
        # would be written by two threads at once (false sharing on every pair: measured 14 %)
        self.outs = np.zeros((t, max(OUT_LEN, PAD)))
        self.n0s = np.zeros((t, PAD))
        self.red = np.zeros((t, PAD))
        self.fin = np.zeros((t, PAD))
        self.busy_rows = np.zeros((t, PAD), dtype=np.int64)
        self.busy_stored = np.zeros((t, PAD), dtype=np.int64)   # resolve_stored's (hybrid with newton)
        self.stored = None
        self.window = np.zeros((REBALANCE_WINDOW, t))   # busy cycles of the last steps (rebalance)
        self.window_n = 0
        self.recut = None      # the ranges' weight factors [T] of a re-cut due at the next resolution
        self.recuts = 0        # re-cuts from measured times in this run
        self.speed = np.ones(t)   # each thread's relative resolution time per unit of weight (learn_speed)
        self.equal = np.ones(t)   # the shares of a cut by weight alone
        self.counter = np.zeros(1, dtype=np.int64)
        self.scratch = (self.outs, self.n0s, self.counter, self.red, self.busy_rows)

    @property
    def busy(self):
        """Busy cycles [T] of each thread in the last contact resolution."""
        return self.busy_rows[:, 0] + self.busy_stored[:, 0]

    def warmup(self):
        numba.set_num_threads(self.threads)
        super().warmup()

    # --- contact detection under the scheme ----------------------------------------------------
    def find_pairs(self, radii):
        """The neighbour estimate by the T threads in one call (modes.parallel.find_pairs_threads):
        the grid (binning and scan-ordered copies), the scan under the scheme counting each thread's
        pairs per block of rows (modes.parallel.block_shift); then the threads place them into the
        list in gid order (SPLIT), or into the list in thread order and its sorted view
        (modes.parallel.place_by_gid)."""
        s = self.state
        n = s.n
        if self.row_plan is None or self.row_plan[0] != n:
            self.row_plan = (n,) + par.scheme_rows(self.scheme, n, self.threads)
        _, row_start, rows = self.row_plan
        # rows are scan-order positions; explicit schemes index them, static/dynamic use identity
        cutoff = grid_cutoff(self.neighbor, radii)
        offsets = np.empty(self.threads + 1, dtype=np.int64)
        shift = par.block_shift(n, self.threads)
        nb = par.n_blocks(n, shift)
        if self.block_count is None or self.block_count.shape[1] < nb + par.COUNT_PAD:
            self.block_count = np.empty((self.threads, nb + par.COUNT_PAD), dtype=np.int64)
        rank = None if gid_ascending(s.gid) else gid_ranks(s.gid)   # None: the indices are the ranks
        while True:
            if self.pair_t is None or self.pair_t[0].shape[1] < self.cap:
                self.pair_t = (np.empty((self.threads, self.cap), dtype=np.int64),
                               np.empty((self.threads, self.cap), dtype=np.int64))
            pi_t, pj_t = self.pair_t
            m, top = par.find_pairs_threads(self.code, self.threads, cutoff, s.pos, radii, s.gid, s.n_owned, row_start,
                                            rows, pi_t, pj_t, self.counts, self.tests, self.scan_busy, offsets, rank,
                                            shift, self.block_count)
            if m >= 0:
                break
            self.cap = int(top * 1.25) + 64
        p = self.pairs
        pi, pj = p.buffers(m)
        # a rebuild after the first carries the history as the rows are placed (PairList.set then
        # takes it: carry_sorted)
        carries = bool(p.rebuilds)
        t0 = self.clock()
        if self.deliver == SPLIT:   # the list itself in gid order
            cut = self._placing_cut()
            later, later_at, got = par.place_by_gid(self.threads, pi_t, pj_t, offsets, rank, n, self.block_count,
                                                    shift, pi, pj, self.no_order,
                                                    p.carry_args(m, s.gid) if carries else None, cut and cut[1:])
            self.placed = (m, None)
            self.cut_made = cut and (m, cut[0], cut[4], later, later_at, got)
        else:                       # the list in thread order, seen in gid order through its view
            par.compact_pairs(self.threads, pi_t, pj_t, offsets, pi, pj)
            view = (np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64))
            par.place_by_gid(self.threads, pi_t, pj_t, offsets, rank, n, self.block_count, shift, *view,
                             p.carry_args(m, s.gid, view[2]) if carries else None)
            self.placed = (m, view)
        self.carried = m if carries else None
        self.placing_s = self.clock() - t0
        self.pairs.offsets = offsets
        self.cap = max(self.cap, int(top * 1.25) + 64)
        # plain floats: numpy's reductions of T numbers read 20 us a rebuild under line_profiler (2500 particles)
        tests = self.tests.tolist()
        self.work_imbalance = max(tests) / max(sum(tests) / len(tests), 1e-300)
        return m

    def _placing_cut(self):
        """(weight, shares, n_owned, gid, bounds, gat) of the cut that find_pairs makes as it places
        the list (modes.parallel.place_by_gid, cut_ranges' ranges at equal pairs): under SPLIT where
        every pair of the fresh list weighs the same (uniform_weight) and no cross-border terms
        are taken (newton); else None, and split cuts the list."""
        if self.newton:
            return None
        weight = self.uniform_weight(False)
        if weight is None:
            return None
        s = self.state
        self.gat = np.empty(s.n_owned, dtype=np.int8)
        return weight, self._shares(), s.n_owned, s.gid, np.zeros(self.threads + 1, dtype=np.int64), self.gat

    def _shares(self):
        """Each thread's share [T] of a fresh cut: the dynamic scheme's by the learnt speeds
        (learn_speed), else equal."""
        return 1.0 / self.speed if self.scheme == "dynamic" else self.equal

    def _placed_sorted(self, pi, pj, gid):
        """The pair list's sort by gid (PairList.sort_pairs): find_pairs placed the pairs in that
        order (modes.parallel.place_by_gid)."""
        if self.placed is None or self.placed[0] != pi.shape[0] or self.placed[1] is not None:
            raise ModeError("the threads' pair list was not placed in gid order by their neighbour scan")
        self.placed = None

    def _placed_view(self, pi, pj, gid):
        """The pair list's sorted view (PairList.sort_view: spi, spj, order), placed with the list by
        find_pairs (modes.parallel.place_by_gid)."""
        if self.placed is None or self.placed[0] != pi.shape[0] or self.placed[1] is None:
            raise ModeError("the threads' pair list has no sorted view from their neighbour scan")
        view = self.placed[1]
        self.placed = None
        return view

    def rebuild_ref(self):
        """The owned positions at this rebuild (PairList.ref) are copied by the threads with the wall
        list (wall_list), as they read them: here the array they fill."""
        self.ref_fill = np.empty((self.state.n_owned, 3))
        return self.ref_fill

    def wall_list(self, n_owned, pos, reach, wall_m, wall_d, wall_hist, near, was):
        """The rebuild's wall list (dem.forces.wall_candidates) by the T threads, and with it the
        blocks of the per-particle pass (made from the list in the same parallel region) and the
        copy of the owned positions at this rebuild into the list's ref (rebuild_ref):
        modes.parallel.wall_threads."""
        self.finish_blocks = np.zeros(self.threads + 1, dtype=np.int64)
        ref, self.ref_fill = self.ref_fill, None
        if ref is None or ref.shape[0] != n_owned:
            raise ModeError("the threads' wall list has no reference positions to fill (rebuild_ref)")
        return par.wall_threads(self.threads, n_owned, pos, reach, wall_m, wall_d, wall_hist, near, was,
                                self.state.shape, self.finish_blocks, ref)

    def carry_sorted(self, *arrays):
        """The rebuild's history carry (PairList.set's carry_sorted): find_pairs made it as the
        threads placed the list, each over the rows it placed (modes.parallel.place_by_gid), so
        nothing is left to do here."""
        if self.carried is None or self.carried != arrays[0].shape[0]:
            raise ModeError("the threads' history carry was not made as their neighbour scan placed the list")
        self.carried = None

    def split(self, cross=None, terms=None):
        """Under SPLIT the T ranges of the new (gid-sorted) list, the particles that gather, and
        those each range's thread zeroes and sums (modes.parallel.split_pairs; the blocks of the
        per-particle pass come with the wall list: wall_list). Given cross [c] (the ascending indices
        of the pairs with a ghost end: hybrid with Newton's third law, modes.newton) the ranges take
        their terms [c, TERMS] in their place (SPLIT_TAKEN), range t from row terms_start[t] on."""
        s = self.state
        t1 = self.threads + 1
        self.stored = None
        if self.deliver != SPLIT:
            if cross is not None:
                raise ModeError(f"the {self.scheme} scheme stores every pair's forces: it cannot take cross-border "
                                "terms (newton)")
            self.ranges = (STORE, s.n_owned, self.gat, np.zeros(t1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                           self.no_terms, np.zeros(t1, dtype=np.int64))
            return
        self.taken = (cross, terms)
        self.weights = None
        self.recut = None  # one due was measured on the old list's ranges: the fresh cut has the speeds
        made, self.cut_made = self.cut_made, None
        if made is not None and cross is None:
            self._finish_cut(*made)
        else:
            self._cut()

    def _finish_cut(self, m, weight, bounds, later, later_at, got):
        """The cut that find_pairs made as it placed the list (_placing_cut) finished: the marks, the
        home lists and the marked rows of the adjacency (modes.parallel.mark_and_home, in one
        parallel region), which gather_arrays then takes (build_adjacency)."""
        s = self.state
        p = self.pairs
        if m != p.m:
            raise ModeError("the threads' cut was made for another pair list")
        t1 = self.threads + 1
        home_start = np.empty(t1, dtype=np.int64)
        home_items = np.empty(s.n_owned, dtype=np.int64)
        _, adj_start, adj_items = par.mark_and_home(self.threads, bounds, p.pi, p.pj, s.gid, s.n_owned, self.gat,
                                                    later, later_at, got, home_start, home_items, True)
        self.marked_adj = (self.gat, adj_start, adj_items)
        self.weights = weight
        p.offsets = bounds
        self.ranges = (SPLIT, s.n_owned, self.gat, home_start, home_items, self.no_terms, np.zeros(t1, dtype=np.int64))
        self.window_n = 0

    def _cut(self):
        """The ranges of the list (the weights of split_pairs' estimate, or self.weights as measured
        times rescaled them: cut_ranges), the particles that gather and those each range zeroes.
        Where every pair of a fresh list weighs the same (uniform_weight) the cut is made at equal
        pairs with no pass over them, and self.weights is that one weight [float]."""
        s = self.state
        p = self.pairs
        t1 = self.threads + 1
        cross, terms = self.taken
        bounds = np.zeros(t1, dtype=np.int64)
        self.gat = np.empty(s.n_owned, dtype=np.int8)
        home_start = np.empty(t1, dtype=np.int64)
        home_items = np.empty(s.n_owned, dtype=np.int64)
        if self.weights is None:  # a fresh cut: the dynamic scheme's shares by the learnt speeds
            shares = self._shares()
            self.weights = self.uniform_weight(cross is not None)
            if self.weights is not None:
                par.cut_ranges(None, self.threads, shares, p.pi, p.pj, s.gid, s.n_owned, bounds, self.gat, home_start,
                               home_items)
            else:
                self.weights = par.split_pairs(self.code, self.threads, shares, p.pi, p.pj, s.gid, s.n_owned, s.pos,
                                               s.rbound, s.shape, cross is not None, bounds, self.gat, home_start,
                                               home_items)
        else:
            par.cut_ranges(self.weights, self.threads, self.equal, p.pi, p.pj, s.gid, s.n_owned, bounds, self.gat,
                           home_start, home_items)
        p.offsets = bounds
        if cross is None:
            self.ranges = (SPLIT, s.n_owned, self.gat, home_start, home_items, self.no_terms,
                           np.zeros(t1, dtype=np.int64))
        else:
            self.ranges = (SPLIT_TAKEN, s.n_owned, self.gat, home_start, home_items, terms,
                           np.searchsorted(cross, bounds).astype(np.int64))
        self.window_n = 0

    def uniform_weight(self, taken):
        """The one weight [float] every pair of a fresh list has in the cut where they all weigh the
        same (modes.parallel.pair_weights), else None: 1 for the static scheme; under the dynamic
        one, with skin 0 (each candidate's bounding spheres overlap: the list's reach is the bounding
        radius), no terms taken (SPLIT_TAKEN weighs the pairs with a ghost end 1) and one shape among
        the local particles, that shape's CONTACT_COST; the partition scheme weighs rows."""
        if self.code == par.STATIC:
            return 1.0
        if self.code != par.DYNAMIC or taken or self.skin > 0:
            return None
        cost = par.uniform_contact_cost(self.state.shape)
        return cost if cost > 0 else None

    def range_work(self):
        """The estimated weight of each range of the current cut [T]."""
        b = self.pairs.offsets
        if isinstance(self.weights, float):
            return self.weights * np.diff(b).astype(np.float64)
        return np.array([self.weights[b[t]:b[t + 1]].sum() for t in range(self.threads)])

    def rebalance(self):
        """The dynamic scheme's feedback: after each window of REBALANCE_WINDOW steps with one cut
        (no rebuild), when the threads' median busy times in the resolution differ by more than
        REBALANCE_ABOVE, schedule a re-cut at the next resolution with each range's weights
        scaled towards its measured cost per unit of estimated weight (two cores of one machine
        need not run alike: on the 2-core VM the second thread took 5 % longer over the same
        estimated work; the estimate alone left the threads' busy times 1.035 apart on 12k packed).
        The cut never changes a result (DESIGN.md, Determinism)."""
        if self.scheme != "dynamic" or self.deliver != SPLIT or self.window_n < REBALANCE_WINDOW:
            return
        self.window_n = 0
        med = np.median(self.window, axis=0)
        if med.min() <= 0 or med.max() <= REBALANCE_ABOVE * med.mean():
            return
        work = self.range_work()
        if work.min() <= 0:
            return
        rate = med / work
        self.recut = 1.0 + (1.0 - REBALANCE_KEEP) * (rate / np.mean(rate) - 1.0)

    def learn_speed(self):
        """The dynamic scheme at a rebuild step (a fresh cut, the weights as estimated): each
        thread's resolution time per unit of its range's estimated weight, relative to the
        threads' mean, into speed [T] (REBALANCE_KEEP of the old value kept), so that the next fresh
        cut gives thread t the share 1/speed[t]. Two cores of one machine need not run alike, and
        with --skin 0 every step is a rebuild, where the re-cut between rebuilds (rebalance) never
        comes: on 12k packed ellipsoids at 2 threads the slower thread's busy time stayed 4.9 %
        above the mean (bench run, 60 steps, median)."""
        if self.scheme != "dynamic" or self.deliver != SPLIT or self.weights is None:
            return
        work = self.range_work()
        busy = self.busy_rows[:, 0].astype(np.float64)
        if work.min() <= 0 or busy.min() <= 0:
            return
        rate = busy / work
        self.speed = REBALANCE_KEEP * self.speed + (1.0 - REBALANCE_KEEP) * rate / rate.mean()

    def warm_between(self):
        """The dynamic scheme's re-cut (rebalance) runs in the warm-up's step between rebuilds, by
        factors 1 (the same ranges): its kernels compiled there, not in the first timed step after a
        window of REBALANCE_WINDOW steps (a 10 ms step from numba's cache, ~75 ms compiling, in 30-step
        runs of 2000 packed ellipsoids at 2 threads whose other steps took 1.05 ms)."""
        if self.scheme == "dynamic" and self.deliver == SPLIT:
            self.recut = np.ones(self.threads)

    def _recut(self):
        """Re-make the ranges from the weights rescaled by self.recut (within the resolution's time)."""
        if isinstance(self.weights, float):   # one weight for all: each pair's own from now on
            self.weights = np.full(self.pairs.m, self.weights)
        par.rescale_weights(self.weights, self.pairs.offsets, self.recut)
        self.recut = None
        self._cut()
        self.adj = self.pairs.gather_arrays(self.deliver, self.gat)
        self.recuts += 1

    def resolve(self):
        if self.recut is not None:
            self._recut()
        self.busy_rows[:, 0] = 0
        return par.resolve_threads(self.code, self.threads, self.pairs.offsets, self.kind, self.method, self.plist,
                                   self.bodies, self.polys, self.law, self.dt, self.scratch, self.ranges)

    def resolve_stored(self, name, plist, m):
        """SerialMode.resolve_stored by the T threads, in chunks handed out at run time (STORE: the
        order does not matter); its busy cycles count with the step's resolution (busy)."""
        if self.stored is None or self.stored[0][-1] != m:  # fixed until the next rebuild: nothing allocated
            offsets = np.zeros(self.threads + 1, dtype=np.int64)
            offsets[-1] = m
            self.stored = (offsets, (STORE, self.state.n_owned, self.gat, offsets, np.zeros(0, dtype=np.int64),
                                     self.no_terms, offsets))
        self.busy_stored[:, 0] = 0
        outs, n0s, counter, red, _ = self.scratch
        return par.resolve_threads(par.DYNAMIC, self.threads, self.stored[0], self.kind, self.method, plist,
                                   self.bodies, self.polys, self.law, self.dt,
                                   (outs, n0s, counter, red, self.busy_stored), self.stored[1])

    # --- the rest of the step --------------------------------------------------------------------
    def derive(self, lo, hi):
        if self.threaded == "step" and hi > lo:
            self.kernel_call("derive_threads", par.derive_threads,
                             (self.threads, lo, hi, self.bodies, self.polys, self.octants))
        else:
            super().derive(lo, hi)

    def finish(self):
        if self.threaded != "step":
            return super().finish()
        return par.finish_threads(self.threads, self.finish_blocks, self.kind == SPHERE, self.deliver, self.adj,
                                  self.bodies, self.walls(), self.polys, self.gravity, self.dt, self.octants,
                                  self.pairs.ref, self.outs, self.fin)

    def step(self):
        row = super().step()
        hz = cycles_per_second()
        # plain floats over the T threads: numpy's reductions of so few numbers read 30-50 us a step
        # under line_profiler (which inflates small calls), 3 % of a 2-thread step of 2500 packed ellipsoids
        busy = (self.busy + self.scan_busy if row["neighbor_rebuilt"] else self.busy).tolist()
        top = max(busy) / hz
        mean = sum(busy) / len(busy) / hz
        row["busy_max"] = top
        row["busy_mean"] = mean
        row["imbalance"] = top / mean if mean > 0 else 1.0
        row["work_imbalance"] = self.work_imbalance
        if row["neighbor_rebuilt"]:
            self.window_n = 0   # a new cut (and cold caches): its window starts with the next step
            self.learn_speed()
        else:
            self.window[self.window_n % REBALANCE_WINDOW] = self.busy_rows[:, 0]
            self.window_n += 1
            self.rebalance()
        return row

    @classmethod
    def accepts(cls, mapping):
        """One process, more than one thread (1-1-1-1-T)."""
        return mapping.procs == 1 and mapping.threads > 1

    def run_info(self, end=False):
        """SerialMode's, with the re-cuts of the dynamic scheme's ranges at the end (thread_recuts)."""
        info = super().run_info(end)
        if end:
            info["thread_recuts"] = self.recuts
        return info
