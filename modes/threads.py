"""Threads mode: mapping 1-1-1-1-T, T numba threads under one of the paper's five schemes.

The step is the serial one (modes/serial.py) with each phase's loop run by modes/parallel.py:
contact detection (neighbour scan, contact resolution) under the chosen scheme, and, unless
`threaded = "detection"` (the paper's situation, for the Amdahl ceiling it reports), the force
gather, walls, integration and derived quantities in T contiguous blocks. The adjacency
(counting sort of the touching pairs) stays serial: it is O(contacts) integer work.
"""
import numpy as np
import numba

from dem.forces import POLYS
from dem.neighbor import CellGrid
from modes.base import ModeError, register
from modes import parallel as par
from modes.serial import SerialMode

_CYCLES_PER_S = None


def cycles_per_second():
    global _CYCLES_PER_S
    if _CYCLES_PER_S is None:
        _CYCLES_PER_S = par.cycles_per_second()
    return _CYCLES_PER_S


@register("threads")
class ThreadsMode(SerialMode):
    """options: threads T, scheme (partition | frogleap | headtail | static | dynamic),
    threaded ("step": every phase; "detection": only neighbour estimate + resolution)."""

    def setup(self, scene, dt, threads=2, scheme="dynamic", threaded="step", **kw):
        if scheme not in par.SCHEMES:
            raise ModeError(f"unknown scheme {scheme!r} (schemes: {', '.join(par.SCHEMES)})")
        if threaded not in ("step", "detection"):
            raise ModeError(f"unknown threaded option {threaded!r} (step, detection)")
        if threads < 1:
            raise ModeError(f"threads must be >= 1, got {threads}")
        if threads > numba.config.NUMBA_NUM_THREADS:
            raise ModeError(f"{threads} threads asked but numba started with NUMBA_NUM_THREADS="
                            f"{numba.config.NUMBA_NUM_THREADS}; set it before numba starts (bench run does)")
        super().setup(scene, dt, **kw)
        self.threads = int(threads)
        self.scheme = scheme
        self.code = par.SCHEMES.index(scheme)
        self.threaded = threaded
        numba.set_num_threads(self.threads)
        self.cap = 1024
        self.offsets = np.zeros(self.threads + 1, dtype=np.int64)
        self.busy = np.zeros(self.threads, dtype=np.int64)
        self.scan_busy = np.zeros(self.threads, dtype=np.int64)
        self.tests = np.zeros(self.threads, dtype=np.int64)
        self.counts = np.zeros(self.threads, dtype=np.int64)
        self.work_imbalance = 1.0
        return self

    def warmup(self):
        numba.set_num_threads(self.threads)
        super().warmup()

    # --- contact detection under the scheme ----------------------------------------------------
    def find_pairs(self, radii):
        s = self.state
        grid = CellGrid(self.neighbor, s.pos, radii, s.gid)
        n = s.n
        row_start, rows = par.scheme_rows(self.scheme, n, self.threads)
        # rows are scan-order positions; explicit schemes index them, static/dynamic use identity
        while True:
            pi_t = np.empty((self.threads, self.cap), dtype=np.int64)
            pj_t = np.empty((self.threads, self.cap), dtype=np.int64)
            par.scan_threads(self.code, self.threads, row_start, rows, grid.scell, grid.dims, grid.cell_start,
                             grid.cell_items, grid.spos, grid.srb, grid.sgid, s.n_owned, pi_t, pj_t,
                             self.counts, self.tests, self.scan_busy)
            if self.counts.max() <= self.cap:
                break
            self.cap = int(self.counts.max() * 1.25) + 64
        self.offsets[1:] = np.cumsum(self.counts)
        m = int(self.offsets[-1])
        self.pairs.ensure(m)
        pi, pj = self.pairs.pi[:m], self.pairs.pj[:m]
        par.compact_pairs(self.threads, pi_t, pj_t, self.offsets, pi, pj)
        self.cap = max(1024, int(self.counts.max() * 1.25) + 64)
        self.work_imbalance = float(self.tests.max() / max(self.tests.mean(), 1e-300))
        return pi, pj

    def neighbour_phase(self):
        self.scan_busy[:] = 0
        return super().neighbour_phase()

    def resolve_phase(self, pi, pj):
        s, m = self.state, self.scene.materials
        self.derive()
        self.work.ensure(len(pi))
        w = self.work
        self.busy[:] = 0
        return par.resolve_threads(self.code, self.threads, self.offsets, self.kind, pi, pj, s.pos, s.vel,
                                   self.omega, self.rot, s.axes, s.shape, s.mass, s.material, s.gid, s.n_owned,
                                   s.hist_start, s.hist_partner, s.hist_val, m.estar, m.gstar, m.mu, m.zeta,
                                   self.dt, self.method, w.active, w.res, w.ratio, self.oorg, self.orot, self.ax6,
                                   self.busy)

    # --- the rest of the step --------------------------------------------------------------------
    def derive(self):
        s = self.state
        self.ensure_derived()
        if self.threaded == "step":
            par.derive_threads(self.threads, s.n, s.quat, s.angmom, s.inertia, s.shape, self.rot, self.omega,
                               self.kind == POLYS, s.pos, s.axes, s.poly, self.orot, self.oorg, self.ax6)
        else:
            super().derive()

    def gather(self, pi, pj, start, items, new_val):
        s = self.state
        if self.threaded == "step":
            par.gather_threads(self.threads, s.n_owned, start, items, pi, pj, self.work.res, s.force, s.torque, new_val)
        else:
            super().gather(pi, pj, start, items, new_val)

    def walls(self):
        s, m, sc = self.state, self.scene.materials, self.scene
        if self.threaded == "step":
            return par.wall_threads(self.threads, s.n_owned, sc.wall_m, sc.wall_d, s.pos, s.vel, self.omega,
                                    self.rot, s.axes, s.rbound, s.shape, s.mass, s.material, m.estar_w, m.gstar_w,
                                    m.zeta_w, m.mu_w, s.wall_hist, self.dt, s.force, s.torque, self.oorg, self.orot,
                                    self.ax6)
        return super().walls()

    def integrate(self):
        s, g = self.state, self.g
        if self.threaded == "step":
            par.integrate_threads(self.threads, s.n_owned, s.pos, s.vel, s.quat, s.angmom, s.mass, s.inertia,
                                  s.shape, s.force, s.torque, g[0], g[1], g[2], self.has_gravity, self.dt)
        else:
            super().integrate()

    def step(self):
        row = super().step()
        hz = cycles_per_second()
        busy = (self.busy + (self.scan_busy if self.rebuilt else 0)) / hz
        row["busy_max"] = float(busy.max())
        row["busy_mean"] = float(busy.mean())
        row["imbalance"] = float(busy.max() / busy.mean()) if busy.mean() > 0 else 1.0
        row["work_imbalance"] = self.work_imbalance
        return row
