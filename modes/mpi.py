"""Pure MPI (P-px-py-pz-1) and hybrid (P-px-py-pz-T) modes: link-block decomposition.

Each rank owns the particles whose centre lay in its block at the last neighbour rebuild. A
rebuild step (DESIGN.md) migrates the particles that left the block (migraT; only they write
their contact history into per-particle rows, the others keep it in the list), then chooses the
ghosts from the up to 26 neighbour blocks (commuT), inside a border layer as wide as the largest
bounding diameter plus the skin, so that every pair that can touch before the next rebuild is
present; the steps between only forward the ghosts' moving fields (commuT). With skin 0 (the
paper's every-step neighbour estimate) the halo keeps a skin of its own (halo_skin, default
DEFAULT_HALO_SKIN): the list is rebuilt every step on the ghosts forwarded (relist), the halo
(migration, ghost choice) only when a particle has moved half the halo skin. Then the serial (or
threaded, for hybrid) step runs on owned + ghost particles. A pair with a ghost is resolved once,
by one of its two ranks (a hash of the two gids picks which), which sends the other end's terms
to its owner inside the resolution (newton, the default: modes/newton.py; that message is
commuT; hybrid runs take the terms in each thread's range of the list), or, with newton off and
in hybrid runs under the schemes that store every pair's forces, on both ranks
from identical inputs and identical contact history. Gravity and integration touch owned
particles only, and walls are visited only by blocks that touch them. Whether the next step
rebuilds is decided collectively, in the one allreduce a step makes, which also carries the
stability guard's sums. It is part of commuT and recorded alone as syncT: a rank that finishes
its step early waits there for the slowest, so syncT holds the ranks' imbalance, and the
exchanges that follow it start in step (their time is the wire and the software around it).
With update_grid K the block grid is fitted to the particles at the start and every K steps
(refit_grid): the paper's equal blocks over their extent, or cut planes at equal particle count
or at equal measured compute time (balance; the MPI counterpart of dynamic thread scheduling).
Timers use MPI.Wtime. Halo and migration live in halo.py, the reverse exchange of Newton's third
law in newton.py, the geometry of blocks in decomposition.py, the ping-pong wire model in wire.py;
this module only orchestrates.
"""
import os
import socket
from collections import deque

import numpy as np

from dem.forces import SPLIT, STORE
from dem.pairs import DEFAULT_SKIN
from dem.state import HIST_LEN
from modes.base import ModeError, call_entry, register
from modes.decomposition import (BlockGrid, DecompositionError, balanced_grid, blended_grid, block_counts,
                                 border_width, extent_grid, fit_skin, load_profiles)
from modes.halo import Halo, drop_ghosts, ghost_fields
from modes.newton import NDIR, NewtonPlan, cross_plan, ghost_owner_directions
from modes.serial import SerialMode
from modes.threads import ThreadsMode
from modes.wire import WireModel, pingpong
from modes.window import SharedWindow

# ping-pong message sizes [B] of a run's wire model: a count message to the largest ghost messages
WIRE_SIZES = (8, 512, 4096, 32768, 262144)
# how --update-grid K fits the block grid (at the start and every K steps): "extent", the paper's
# updateGrid (equal blocks over the particles' extent); "count", cut planes at equal particle
# counts; "time", cut planes at equal measured compute time (modes.decomposition.balanced_grid)
BALANCE = ("extent", "count", "time")
# balance "time": the share of the old cut planes kept at a refit (each refit moves the planes half
# way to the measured balance: a steady cost difference is taken up geometrically, 1/2, 3/4, ...,
# while the noise of a window of steps moves them only half as far)
TIME_BALANCE_KEEP = 0.5
# balance "time": the steps whose median compute time weighs a refit (at most the last this many)
TIME_WINDOW = 1000
# the history rows of a rebuild where nobody leaves (never written: a migrant's rows are made anew)
_NO_PARTNERS = np.zeros(0, dtype=np.int64)
_NO_ROWS = np.zeros((0, HIST_LEN))
# modes.newton cross_plan's arrays for a list without pairs, shared by every such plan: the empty
# ones hold nothing to write, the two direction counts [26] are only read (NewtonPlan)
_NONE = np.zeros(0, dtype=np.int64)
_NO_CROSS_PAIRS = (_NONE, np.zeros(NDIR, dtype=np.int64), _NONE, np.zeros(NDIR, dtype=np.int64), _NONE, _NONE, _NONE,
                   _NONE, _NONE, _NO_ROWS, np.zeros(0, dtype=np.int8))
# how the ghosts' moving fields travel between rebuilds: messages (the default, the paper's way),
# shared (a shared-memory window of the node: modes.window; refused where it cannot be), auto (the
# window where every rank runs on one node with --halo 26, else messages). At 2 ranks on a 2-vCPU
# VM the two tied one day (23 jobs alternating 50-step blocks of each, falling ellipsoids: messages
# / shared 0.992 [0.978, 1.007]) and the window led by 3 % another (16 jobs, 1.032 and 1.035; packed
# scenes tied: `bench perf --what forward`); the default stays the paper's, which needs no room in
# the node's shared-memory file system (MPI_Win_allocate_shared: /dev/shm)
FORWARD = ("auto", "shared", "messages")
# the halo skin of a run with --skin 0, a fraction of the largest bounding diameter (bench run's
# default list skin, dem.pairs.DEFAULT_SKIN): the ghosts and owners are re-chosen only when a
# particle has moved half of it (LAMMPS's comm cutoff: force cutoff + skin)
DEFAULT_HALO_SKIN = DEFAULT_SKIN


class _Blocks:
    """Mixin: decomposition + halo around a step driver's step()."""

    collective = True
    migrates = True

    def setup(self, scene, dt, cart=None, skin=None, halo="26", update_grid=0, balance="extent", wire=True,
              newton=None, halo_skin=None, forward="messages", **kw):
        if balance not in BALANCE:
            raise ModeError(f"unknown balance {balance!r} ({', '.join(BALANCE)})")
        if forward not in FORWARD:
            raise ModeError(f"unknown forward {forward!r} ({', '.join(FORWARD)})")
        if forward == "shared" and halo != "26":
            raise ModeError("--forward shared needs --halo 26 (the three sweeps forward what earlier sweeps brought)")
        if newton is not None and not isinstance(newton, (bool, np.bool_)):
            raise ModeError(f"newton must be true or false, got {newton!r}")
        from mpi4py import MPI
        self.clock = MPI.Wtime
        self.mpi = MPI
        super().setup(scene, dt, skin=skin, **kw)
        # the threads' schemes that store every pair's forces (frogleap, headtail, split=False) cannot
        # take a cross pair's terms in its place: they resolve cross pairs on both ranks
        takes = self.deliver != STORE
        if newton and not takes:
            raise ModeError(f"newton needs a scheme that sums over ranges of the pair list (partition, static, "
                            f"dynamic): the {self.scheme} scheme with split={self.deliver == SPLIT} stores every "
                            "pair's forces (use newton off)")
        self.newton = takes if newton is None else bool(newton)
        self.reverse_time = 0.0
        self.rebuild_comm = 0.0
        s = self.state
        self.cart = cart
        dims = cart.Get_topo()[0]
        self.grid = BlockGrid(scene.box, dims)
        self.coords = np.array(cart.Get_coords(cart.Get_rank()))
        base = border_width(float(s.rbound.max()))
        try:
            self.grid.check_width(base)
            self.skin = fit_skin(self.grid, base, self.skin, explicit=skin is not None)
        except DecompositionError as e:
            raise ModeError(str(e)) from None
        self.skin_fraction = self.skin / (2.0 * float(s.rbound.max()))
        # the halo's own skin [m] (ghost layer, migration): the list's where it has one; with skin 0
        # (neighbours every step) a halo skin lets the ghosts and owners stay over several steps
        # (halo_skin, a fraction of the largest bounding diameter; default DEFAULT_HALO_SKIN)
        if self.skin > 0:
            if halo_skin is not None and float(halo_skin) != self.skin_fraction:
                raise ModeError("a halo skin of its own needs --skin 0 (with a list skin the halo takes the list's)")
            self.halo_skin = self.skin
        else:
            hs = (DEFAULT_HALO_SKIN if halo_skin is None else float(halo_skin)) * 2.0 * float(s.rbound.max())
            try:
                self.halo_skin = fit_skin(self.grid, base, hs, explicit=halo_skin is not None)
            except DecompositionError as e:
                raise ModeError(str(e).replace("a skin", "a halo skin")) from None
        self.halo_skin_fraction = self.halo_skin / (2.0 * float(s.rbound.max()))
        # skin 0 with a halo skin: the list is rebuilt every step, the halo only when some particle
        # moved half the halo skin (SerialMode.step `relist`)
        self.relist_every_step = self.skin <= 0 < self.halo_skin
        self.width = base + self.halo_skin
        self.update_grid = int(update_grid)
        self.balance = balance
        self.compute_times = deque(maxlen=TIME_WINDOW)  # compuT of the steps since the last refit ("time")
        if self.update_grid and s.n:
            # every rank holds the whole scene here, so each fits the same grid without a message; as
            # at a refit, a grid too tight for the border layer leaves the box's. No time has been
            # measured yet: "time" starts from equal counts
            lo, hi = s.pos.min(axis=0), s.pos.max(axis=0)
            fitted = extent_grid(lo, hi, dims) if balance == "extent" else \
                balanced_grid(scene.box, lo, hi, dims, load_profiles(s.pos, 1.0, lo, hi), self.width)
            if fitted is not None and fitted.fits(self.width):
                self.grid = fitted
        # the particles of each block at the start (the driver warns of empty ones)
        self.block_counts = block_counts(self.grid, s.pos)
        mine = np.flatnonzero(np.all(self.grid.block_of(s.pos) == self.coords, axis=1))
        s.permute_keep(mine)
        self.shared_window = self._window(cart, forward, halo)
        self.shared_owner = self   # a warm-up twin (a copy) shares the window and does not free it
        self.forward_windows = None  # the windows made (modes.window allocations), kept when it is freed
        self.forward_transport = "shared" if self.shared_window is not None else "messages"
        self.halo = Halo(cart, self.grid, self.coords, halo=halo, window=self.shared_window)
        # where each rank runs (collective): the neighbours on another node are counted apart
        self.hosts = cart.allgather(socket.gethostname())
        me = cart.Get_rank()
        self.remote = frozenset(r for r in self.halo.neighbour_ranks() if self.hosts[r] != self.hosts[me])
        # the wire under this halo: a ping-pong with the same neighbour ranks, in this run (collective)
        self.wire = WireModel(pingpong(cart, self.halo.neighbour_ranks(), sizes=WIRE_SIZES, time_per_size=1e-3)) \
            if wire else None
        self.halo.set_links(self.wire, self.remote)
        self.steps_done = 0
        self.grid_updates = 0
        self.decision = np.zeros(7)
        self.counts_check = 0.0  # this rank's term of the cross pairs' counts checksum (modes.newton)
        self.leaving = None  # the owned particles' blocks, outside marks and count (BlockGrid.leavers)
        self.found_next = None  # the same, found at the end of the step before a rebuild (decide)
        self.migration_due = True  # some rank has particles to send at the next rebuild (or cannot tell)
        # walls only where the block touches the box face (others are farther than any radius)
        touch = []
        for w in scene.walls:
            axis = "xyz".index(w[0])
            touch.append(self.coords[axis] == (0 if w[1] == "-" else dims[axis] - 1))
        self.touches_walls = any(touch)
        return self

    def _window(self, cart, forward, halo):
        """The node's shared window of the forward exchange (modes.window; collective), or None: by
        messages. auto: where every rank runs on one node, with --halo 26, and a forward exchange
        runs at all (a skin or a halo skin); shared: refused in one line where the ranks span nodes."""
        if forward == "messages" or halo != "26" or (forward == "auto" and self.halo_skin <= 0):
            return None
        window = SharedWindow(cart, Halo.record_widths(self.kind)[1])
        if window.whole:
            return window
        if forward == "shared":
            raise ModeError("--forward shared needs every rank on one node (these ranks span nodes: use auto or "
                            "messages)")
        return None

    def _fresh(self):
        super()._fresh()
        self.plan = None   # the reverse exchange of the current list (newton)
        self.ghost_dir = None  # the ghosts' owners' directions at the halo's last build (three sweeps)
        self.no_cross_plan = None  # the reverse exchange of every list without pairs (split)
        self.found_next = None
        self.migration_due = True
        if hasattr(self, "halo"):  # a warm-up twin exchanges through a halo of its own
            self.halo = self.halo.clone()

    def warmup(self):
        super().warmup()  # collective: every rank steps its twin (a rebuild and a forward step)
        self.halo.reset_counters()
        self.compute_times.clear()  # the twin's steps (compilation) are no measure of this block's load

    def release(self):
        """Complete the forward exchange the last step started and free every persistent request.
        Call it before MPI_Finalize: a started exchange still reads from and writes into this
        rank's buffers (a script that skipped it once died in malloc at exit)."""
        self.halo.free()
        self._free_plan()
        if self.shared_window is not None and self.shared_owner is self:   # collective over the node
            self.forward_windows = self.shared_window.allocations
            self.shared_window.free()
            self.shared_window = None

    def _free_plan(self):
        if self.plan is not None:
            self.plan.free()
            self.plan = None

    def refit_grid(self):
        """The paper's updateGrid: re-fit the block grid to the particle centres (balance "extent":
        equal blocks over their extent, which all ranks agree on through two allreduces; "count" and
        "time": cut planes at equal load, placed by rank 0 from the summed load profiles and
        broadcast, so that every rank holds the same planes) when the blocks stay wide enough, and
        hand particles to their new owners. The "time" load spreads each rank's median compute
        time per step since the last refit (its last TIME_WINDOW steps) over its particles.
        Returns the number of particles this rank sent."""
        MPI = self.mpi
        from modes.halo import redistribute
        s = self.state
        n = s.n_owned
        lo = s.pos[:n].min(axis=0) if n else np.full(3, np.inf)
        hi = s.pos[:n].max(axis=0) if n else np.full(3, -np.inf)
        self.cart.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        self.cart.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        if self.balance == "extent":
            grid = extent_grid(lo, hi, self.grid.dims)
        else:
            weight = 1.0
            if self.balance == "time":
                weight = float(np.median(self.compute_times)) / n if n and self.compute_times else 0.0
            local = load_profiles(s.pos[:n], weight, lo, hi)
            total = np.zeros_like(local)
            self.cart.Reduce(local, total, op=MPI.SUM, root=0)
            grid = None
            if self.cart.Get_rank() == 0:
                grid = balanced_grid(self.scene.box, lo, hi, self.grid.dims, total, self.width)
                if grid is not None and self.balance == "time":
                    damped = blended_grid(self.grid, grid, TIME_BALANCE_KEEP)
                    grid = damped if damped.fits(self.width) else grid
            grid = self.cart.bcast(grid, root=0)
        self.compute_times.clear()
        if grid is None or not grid.fits(self.width):
            return 0  # too tight for the border layer: keep the current grid
        self.grid = grid
        self.halo.set_grid(grid)
        self.grid_updates += 1
        return redistribute(self.cart, grid, s, self.coords)

    def _refit_due(self, step):
        return self.update_grid and step % self.update_grid == 0

    def migrate(self):
        self.halo.free()  # a rebuild: the exchange started at the end of the last step is not needed
        self._free_plan()
        if self._refit_due(self.steps_done + 1):
            self.owned_derived = False
            return self.refit_grid()
        found, self.leaving = self.leaving, None
        if not self.migration_due:  # no rank has a particle to send (decide): no message round either
            drop_ghosts(self.state)
            return 0
        sent, received = self.halo.migrate(self.state, found)
        if sent or received:  # the owned rows moved: their derived quantities are derived anew (build_list)
            self.owned_derived = False
        return sent

    def ghosts(self, rebuild):
        if rebuild:
            self.halo.build(self.state, self.width, self.kind)
            self.ghost_dir = None
            s = self.state
            dirs = self.halo.ghost_dirs  # the direct exchange's, from its messages
            if self.newton and (dirs is None or len(dirs) != s.n - s.n_owned):
                # the three sweeps': from the ghosts' places now, at the build (a relist's ghosts move
                # on, some out of their owner's block, before the list has a pair to need them)
                self.ghost_dir = ghost_owner_directions(self.grid, self.coords, s.pos[s.n_owned:s.n])
        else:
            self.halo.forward(self.state)

    def _history_back(self):
        """With newton the received pairs' history comes back from their resolvers (modes.newton),
        so that the list holds that of both-sided resolution."""
        if self.plan is not None:
            self.plan.put_back(self.pairs)
            t0 = self.clock()
            self.plan.send_history(self.pairs.hist, self.halo.account)
            self.rebuild_comm += self.clock() - t0

    def sync_history(self):
        self._history_back()
        super().sync_history()

    def relist(self):
        """The list alone rebuilt on the ghosts just forwarded (skin 0 with a halo skin: the halo
        and the owners stay): the received pairs' history back from their resolvers first, then
        the list carries it by gid with no per-particle rows (nobody came), and its reference
        positions stay those of the halo's rebuild, against which decide measures the moves."""
        self._history_back()
        self.build_list(rows=False, ref=self.pairs.ref)

    def leaver_history(self):
        """Before migration: the rows of the particles leaving this block only (as LAMMPS's fix
        neigh/history packs only the atoms that exchange() sends); the others keep their history
        in the list, which the next build carries (dem.pairs.PairList.set, rows=True). Rows for
        every particle at a refit of the grid, whose moves are not known here. Against rows for
        every particle (and numpy's any(axis=1) for the leavers), on 12k packed ellipsoids on 2
        ranks with --skin 0 (a rebuild every step; three alternating 100-step runs, slowest rank's
        medians): step 16.6 -> 15.0 ms, migraT 0.44 -> 0.12 ms, neighborT 5.3 -> 4.2 ms. When nobody
        leaves, constant empty rows and the leavers found in one numba call (BlockGrid.leavers):
        6 -> 3 us a rebuild on 2 ranks of 1521 falling ellipsoids with --skin 0."""
        self._history_back()
        s = self.state
        self.leaving = None
        if self._refit_due(self.steps_done + 1):
            super().sync_history()
            return
        n = s.n_owned
        found, self.found_next = self.found_next, None
        if found is None or len(found[0]) != n:
            found = self.grid.leavers(s.pos[:n], self.coords)
        self.leaving = found
        if found[2]:
            s.hist_start, s.hist_partner, s.hist_val = self.pairs.history(s.gid, n, found[1])
        else:  # nobody leaves (most rebuilds): no rows to write (the list's walk took 10 us at 900 particles)
            s.hist_start = np.zeros(n + 1, dtype=np.int64)
            s.hist_partner = _NO_PARTNERS
            s.hist_val = _NO_ROWS

    def split(self):
        """With newton: pick out the cross-border pairs this rank resolves and those it receives, and
        fix the reverse exchange (modes.newton); its counts' checksum goes into this step's
        allreduce (decide); then the base mode's split, with the cross pairs' terms taken in their place.
        Else the base mode's split."""
        if not self.newton:
            return super().split()
        s = self.state
        p = self.pairs
        if p.m:
            ghost_dir = self.halo.ghost_dirs  # from the messages of the last build (direct exchange)
            if ghost_dir is None or len(ghost_dir) != s.n - s.n_owned:  # else from the ghosts' places at that build
                ghost_dir = self.ghost_dir
            layout = call_entry(self.halo.entries, cross_plan, (p.pi, p.pj, p.hist, p.on, s.gid, s.n_owned,
                                                                ghost_dir), True)
            # a relist (the halo, and so the neighbour ranks, kept) whose cross pairs' counts per
            # direction are the last list's keeps that plan's requests (NewtonPlan.adopt); a halo's
            # rebuild has freed it (migrate)
            kept = self.plan
            if kept is None or kept is self.no_cross_plan or not kept.adopt(layout):
                self._free_plan()
                # with --skin 0 every list lives one step: its history rides on the step's terms (NewtonPlan)
                self.plan = NewtonPlan(self.cart, self.halo.ranks, layout, (self.halo.wire, self.halo.remote),
                                       entries=self.halo.entries, carry_history=self.skin <= 0)
        else:  # no pair (a falling scene): no cross pair, no kernel's call (~7 us a rebuild), and one plan
            self._free_plan()
            if self.no_cross_plan is None:  # for every such list (it holds no requests: ~6 us a rebuild)
                self.no_cross_plan = NewtonPlan(self.cart, self.halo.ranks, _NO_CROSS_PAIRS,
                                                (self.halo.wire, self.halo.remote), entries=self.halo.entries,
                                                carry_history=self.skin <= 0)
            self.plan = self.no_cross_plan
        # summed in this step's allreduce (decide); 0 without cross pairs
        self.counts_check = self.plan.count_checksum() if p.m else 0.0
        super().split(self.plan.cross, self.plan.terms)

    def resolve(self):
        """With newton: the sent pairs (their own list, STORE), their terms to the neighbours and the
        neighbours' back (commuT), then the whole list as the base mode resolves it, the cross
        pairs' terms taken in their place (dem.forces, TAKEN and SPLIT_TAKEN); the received pairs
        are resolved by the ghost's owner."""
        if not self.newton:
            return super().resolve()
        plan, s, h = self.plan, self.state, self.halo
        if not plan.m_sent and not plan.m_recv:  # no cross pair (a falling scene): no messages either
            return super().resolve()
        a = self.resolve_stored("resolve_sent", plan.list, plan.m_sent)
        t0 = self.clock()
        plan.exchange(s.n_owned, h.startall, h.waitall)
        self.reverse_time = self.clock() - t0
        h.traffic.add(plan.traffic)
        b = super().resolve()
        worst, worst_k = (a[2], int(plan.sent_idx[a[3]])) if a[2] > b[2] else (b[2], b[3])
        return a[0] + b[0], a[1] + b[1], worst, worst_k, a[4] + b[4]

    def start_forward(self):
        self.halo.forward_start(self.state)  # the next step is a forward step: its messages leave now

    def decide(self, max_disp2, flag, ke, wg):
        """The step's one allreduce: whether the next step rebuilds (any rank's particles moved half
        the skin), the guard's flag and sums, the cross pairs' counts checksum, and how many
        particles the ranks will send at that rebuild. A rank that asks for the rebuild finds its
        leavers here (leaver_history takes them); one that does not cannot tell and counts 1, so
        the migration's message round is skipped only when every rank knows it sends nobody (with
        --skin 0 most rebuilds: the round cost ~20 us of a 2-rank rebuild of 1521 falling
        ellipsoids)."""
        d = self.decision
        d[0] = 1.0 if self.halo_skin <= 0 or max_disp2 >= (0.5 * self.halo_skin) ** 2 else 0.0
        d[1] = flag
        d[2] = ke
        d[3] = wg
        d[4] = self.counts_check
        self.counts_check = 0.0
        self.found_next = None
        d[5] = 1.0
        if d[0] and not self._refit_due(self.steps_done + 2):
            self.found_next = self.grid.leavers(self.state.pos[:self.state.n_owned], self.coords)
            d[5] = float(self.found_next[2])
        # through a shared window the ghosts' rows are written before the allreduce, which orders
        # them before the neighbours' reads (modes.window); a rank whose rows do not fit asks for more
        d[6] = 0.0 if self.halo.publish(self.state) else 1.0
        t = self.clock()
        self.cart.Allreduce(self.mpi.IN_PLACE, d, op=self.mpi.SUM)
        self.sync_time = self.clock() - t
        if d[6] > 0.0:
            self.halo.grow(self.state)
        self.migration_due = d[5] > 0.0
        if d[4] != 0.0:
            raise RuntimeError(f"cross-border pair lists disagree between neighbour ranks at step "
                               f"{self.steps_done + 1} "
                               f"(the counts' checksum is {d[4]:g}, not 0: modes.newton count_checksum)")
        self.sums = (d[1], d[2], d[3])
        return bool(d[0] > 0.0) or self._refit_due(self.steps_done + 2)

    def step(self):
        self.reverse_time = 0.0
        self.rebuild_comm = 0.0
        row = super().step()
        self.steps_done += 1
        h = self.halo
        # the messages inside the resolution (the reverse exchange) and inside the rebuild (the
        # received pairs' history back, the check of the cross pairs' counts) are communication
        rt, bt = self.reverse_time, self.rebuild_comm
        row["commuT"] += rt + bt
        row["compuT"] -= rt + bt
        row["resolveT"] -= rt
        row["neighborT"] -= bt
        row.update(h.traffic.row())
        row["syncT"] = self.sync_time
        h.reset_counters()
        if self.balance == "time":
            self.compute_times.append(row["compuT"])
        return row

    def snapshot(self):
        """Owned particles of every rank, gathered on rank 0 and sorted by gid (None elsewhere)."""
        parts = self.cart.gather(self.state.snapshot(), root=0)
        if self.cart.Get_rank() != 0:
            return None
        snap = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        order = np.argsort(snap["id"], kind="stable")
        return {k: v[order] for k, v in snap.items()}

    def run_info(self, end=False):
        """The base mode's part of run.json, with the decomposition's (collective: every rank calls
        it; the gathered values are rank 0's, None elsewhere). At the start: newton, balance (with
        update_grid), the MPI library, the ghosts' fields and bytes, each rank's wire model and place
        (host, CPUs, block, neighbours, those on another node), the nodes, the particles of each
        block [px][py][pz] and the grid's box and inner cuts [m], how the forward exchange travels
        (forward_transport: shared or messages). At the end: grid updates and cuts, the shared
        windows made (forward_windows; None by messages)."""
        info = super().run_info(end)
        cuts = [c.tolist() for c in self.grid.inner_cuts()]
        if end:
            windows = self.shared_window.allocations if self.shared_window is not None else self.forward_windows
            info.update(grid_updates=self.grid_updates, block_cuts_final=cuts, forward_windows=windows)
            return info
        cart, root = self.cart, self.cart.Get_rank() == 0
        info.update(newton=self.newton, balance=self.balance if self.update_grid else None,
                    halo_skin=self.halo_skin_fraction, halo_skin_m=self.halo_skin,
                    forward_transport=self.forward_transport)
        info["mpi_library"] = self.mpi.Get_library_version().strip().splitlines()[0]
        info["ghost_fields"] = list(ghost_fields(self.kind))
        record, moving = Halo.record_widths(self.kind)
        info["ghost_bytes_per_particle"] = 8 * record  # the paper: 624 per ellipsoid
        info["forward_bytes_per_ghost"] = 8 * moving
        wires = cart.gather(self.wire.as_dict() if self.wire is not None else None, root=0)
        info["wire"] = {str(r): w for r, w in enumerate(wires)} if root else None
        places = cart.gather({"host": socket.gethostname(), "cpus": sorted(os.sched_getaffinity(0)),
                              "block": [int(c) for c in self.coords], "neighbours": self.halo.neighbour_ranks(),
                              "neighbours_internode": sorted(self.remote)}, root=0)
        info["placement"] = {str(r): p for r, p in enumerate(places)} if root else None
        info["nodes"] = sorted({p["host"] for p in places}) if root else None
        info["block_particles"] = self.block_counts.tolist()  # [px][py][pz], at the start
        info["block_box"] = [self.grid.lo.tolist(), self.grid.hi.tolist()]
        info["block_cuts"] = cuts
        return info


@register("mpi")
class MpiMode(_Blocks, SerialMode):
    """P processes, one thread each."""

    @classmethod
    def accepts(cls, mapping):
        """More than one process, one thread each (P-px-py-pz-1)."""
        return mapping.procs > 1 and mapping.threads == 1


@register("hybrid")
class HybridMode(_Blocks, ThreadsMode):
    """P processes x T threads (any scheme) each."""

    @classmethod
    def accepts(cls, mapping):
        """More than one process, more than one thread each (P-px-py-pz-T)."""
        return mapping.procs > 1 and mapping.threads > 1
