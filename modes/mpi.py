"""Pure MPI (P-px-py-pz-1) and hybrid (P-px-py-pz-T) modes: link-block decomposition.

Each rank owns the particles whose centre lies in its block of the Cartesian grid. A step is
(DESIGN.md): migrate the particles that left the block (migraT), exchange ghosts with the up to
26 neighbour blocks (commuT), then the serial (or threaded, for hybrid) step on owned + ghost
particles: pairs with a ghost are computed on both ranks from identical inputs and identical
contact history, gravity and integration touch owned particles only, and walls are visited
only by blocks that touch them. Timers use MPI.Wtime. Halo and migration live in halo.py,
the geometry of blocks in decomposition.py; this module only orchestrates.
"""
import numpy as np

from modes.base import register
from modes.decomposition import BlockGrid, border_width
from modes.halo import Halo
from modes.serial import SerialMode
from modes.threads import ThreadsMode


class _Blocks:
    """Mixin: decomposition + halo around a step driver's step()."""

    def setup(self, scene, dt, cart=None, skin=0.0, halo="26", update_grid=0, **kw):
        from mpi4py import MPI
        self.wtime = MPI.Wtime
        super().setup(scene, dt, skin=0.0, **kw)
        s = self.state
        self.cart = cart
        dims = cart.Get_topo()[0]
        self.grid = BlockGrid(scene.box, dims)
        self.coords = np.array(cart.Get_coords(cart.Get_rank()))
        self.width = border_width(float(s.rbound.max()))
        self.grid.check_width(self.width)
        mine = np.flatnonzero(np.all(self.grid.block_of(s.pos) == self.coords, axis=1))
        s.permute_keep(mine)
        self.halo = Halo(cart, self.grid, self.coords, halo=halo)
        self.update_grid = int(update_grid)
        self.steps_done = 0
        self.grid_updates = 0
        # walls only where the block touches the box face (others are farther than any radius)
        touch = []
        for w in scene.walls:
            axis = "xyz".index(w[0])
            touch.append(self.coords[axis] == (0 if w[1] == "-" else dims[axis] - 1))
        self.has_walls = bool(any(touch))
        return self

    def warmup(self):
        super().warmup()  # collective: every rank steps its twin once
        self.halo.bytes_sent = 0

    def refit_grid(self):
        """The paper's updateGrid: re-fit the block grid to the extent of the particle centres
        (all ranks agree through two allreduces) when the blocks stay wide enough, and hand
        particles to their new owners. Returns the number of particles this rank sent."""
        from mpi4py import MPI
        from modes.halo import redistribute
        s = self.state
        n = s.n_owned
        lo = s.pos[:n].min(axis=0) if n else np.full(3, np.inf)
        hi = s.pos[:n].max(axis=0) if n else np.full(3, -np.inf)
        self.cart.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        self.cart.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        span = np.maximum(hi - lo, 1e-300)
        grid = BlockGrid(np.array([lo - 1e-9 * span, hi + 1e-9 * span]), self.grid.dims)
        if np.any((grid.dims > 1) & (grid.h < self.width)):
            return 0  # too tight for the border layer: keep the current grid
        self.grid = grid
        self.halo.grid = grid
        self.halo.lo, self.halo.hi = grid.bounds(self.coords)
        self.grid_updates += 1
        return redistribute(self.cart, grid, s, self.coords)

    def step(self):
        t0 = self.wtime()
        self.steps_done += 1
        moved = 0
        if self.update_grid and self.steps_done % self.update_grid == 0:
            moved = self.refit_grid()
        sent, received = self.halo.migrate(self.state)
        sent += moved
        t1 = self.wtime()
        n_ghost = self.halo.exchange_ghosts(self.state, self.width, self.all_spheres)
        t2 = self.wtime()
        row = super().step()
        migra, commu = t1 - t0, t2 - t1
        row["migraT"] = migra
        row["commuT"] = commu
        row["totalT"] = row["totalT"] + migra + commu
        row["compuT"] = row["totalT"] - migra - commu
        row["n_migrated"] = sent
        row["n_ghost"] = n_ghost
        row["bytes_sent"] = self.halo.bytes_sent
        self.halo.bytes_sent = 0
        return row

    def snapshot(self):
        """Owned particles of every rank, gathered on rank 0 and sorted by gid (None elsewhere)."""
        from modes.halo import drop_ghosts
        drop_ghosts(self.state)
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
