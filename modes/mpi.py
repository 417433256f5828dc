"""Pure MPI (P-px-py-pz-1) and hybrid (P-px-py-pz-T) modes: link-block decomposition.

Each rank owns the particles whose centre lay in its block at the last neighbour rebuild. A
rebuild step (DESIGN.md) migrates the particles that left the block (migraT), then chooses the
ghosts from the up to 26 neighbour blocks (commuT), inside a border layer as wide as the largest
bounding diameter plus the skin, so that every pair that can touch before the next rebuild is
present; the steps between only forward the ghosts' moving fields (commuT). Then the serial (or
threaded, for hybrid) step runs on owned + ghost particles: pairs with a ghost are computed on
both ranks from identical inputs and identical contact history, gravity and integration touch
owned particles only, and walls are visited only by blocks that touch them. Whether the next
step rebuilds is decided collectively, in the one allreduce a step makes, which also carries the
stability guard's sums. It is part of commuT and recorded alone as syncT: a rank that finishes
its step early waits there for the slowest, so syncT holds the ranks' imbalance, and the
exchanges that follow it start in step (their time is the wire and the software around it).
With update_grid K the block grid is fitted to the particles at the start and every K steps
(refit_grid): the paper's equal blocks over their extent, or cut planes at equal particle count
or at equal measured compute time (balance; the MPI counterpart of dynamic thread scheduling).
Timers use MPI.Wtime. Halo and migration live in halo.py, the geometry of blocks in
decomposition.py, the ping-pong wire model in wire.py; this module only orchestrates.
"""
from collections import deque

import numpy as np

from modes.base import ModeError, register
from modes.decomposition import (BlockGrid, DecompositionError, balanced_grid, blended_grid, block_counts,
                                 border_width, extent_grid, fit_skin, load_profiles)
from modes.halo import Halo
from modes.serial import SerialMode
from modes.threads import ThreadsMode
from modes.wire import WireModel, pingpong

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


class _Blocks:
    """Mixin: decomposition + halo around a step driver's step()."""

    collective = True
    migrates = True

    def setup(self, scene, dt, cart=None, skin=None, halo="26", update_grid=0, balance="extent", wire=True, **kw):
        if balance not in BALANCE:
            raise ModeError(f"unknown balance {balance!r} ({', '.join(BALANCE)})")
        from mpi4py import MPI
        self.clock = MPI.Wtime
        self.mpi = MPI
        super().setup(scene, dt, skin=skin, **kw)
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
        self.width = base + self.skin
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
        self.halo = Halo(cart, self.grid, self.coords, halo=halo)
        # the wire under this halo: a ping-pong with the same neighbour ranks, in this run (collective)
        self.wire = WireModel(pingpong(cart, self.halo.neighbour_ranks(), sizes=WIRE_SIZES, time_per_size=1e-3)) \
            if wire else None
        self.halo.wire = self.wire
        self.steps_done = 0
        self.grid_updates = 0
        self.decision = np.zeros(4)
        # walls only where the block touches the box face (others are farther than any radius)
        touch = []
        for w in scene.walls:
            axis = "xyz".index(w[0])
            touch.append(self.coords[axis] == (0 if w[1] == "-" else dims[axis] - 1))
        self.touches_walls = any(touch)
        return self

    def _fresh(self):
        super()._fresh()
        if hasattr(self, "halo"):  # a warm-up twin exchanges through a halo of its own
            self.halo = self.halo.clone()

    def warmup(self):
        super().warmup()  # collective: every rank steps its twin (a rebuild and a forward step)
        self.halo.reset_counters()
        self.compute_times.clear()  # the twin's steps (compilation) are no measure of this block's load

    def release(self):
        self.halo.free()

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
        if self._refit_due(self.steps_done + 1):
            return self.refit_grid()
        return self.halo.migrate(self.state)[0]

    def ghosts(self, rebuild):
        if rebuild:
            self.halo.build(self.state, self.width, self.all_spheres)
        else:
            self.halo.forward(self.state)

    def start_forward(self):
        if self.skin > 0:  # with a skin the next step may be a forward step: its messages leave now
            self.halo.forward_start(self.state)

    def decide(self, max_disp2, flag, ke, wg):
        d = self.decision
        d[0] = 1.0 if self.skin <= 0 or max_disp2 >= (0.5 * self.skin) ** 2 else 0.0
        d[1] = flag
        d[2] = ke
        d[3] = wg
        t = self.clock()
        self.cart.Allreduce(self.mpi.IN_PLACE, d, op=self.mpi.SUM)
        self.sync_time = self.clock() - t
        self.sums = (d[1], d[2], d[3])
        return bool(d[0] > 0.0) or self._refit_due(self.steps_done + 2)

    def step(self):
        row = super().step()
        self.steps_done += 1
        h = self.halo
        row["bytes_sent"] = h.bytes_sent
        row["msgs_sent"] = h.msgs_sent
        row["wire_s"] = h.wire_s
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


@register("mpi")
class MpiMode(_Blocks, SerialMode):
    """P processes, one thread each."""


@register("hybrid")
class HybridMode(_Blocks, ThreadsMode):
    """P processes x T threads (any scheme) each."""
