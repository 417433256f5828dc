"""Serial mode: one process, one thread; the reference trajectory every mode reproduces.

The step follows DESIGN.md: (migrate, exchange: no-ops here) -> neighbour estimate (neighborT)
-> contact resolution + pair forces (resolveT) -> gather, walls, gravity, integration.
Timers wrap these phases here, never inside kernels.
"""
import copy
import time

import numpy as np

from dem.forces import (CONTACT_METHODS, PR_LEN, POLYS, SPHERES, build_adjacency, gather_range,
                        resolve_pairs_range, resolve_poly_pairs_range, resolve_sphere_pairs_range,
                        scene_kind, wall_range)
from dem.integrate import derive_geometry_range, derive_range, integrate_range
from dem.state import HIST_LEN
from dem.neighbor import PairBuffer, VerletList, candidate_pairs, cell_order
from modes.base import ModeError, register


class PairArrays:
    """Per-pair work arrays reused across steps, grown on demand."""

    def __init__(self):
        self.active = np.zeros(0, dtype=np.int8)
        self.res = np.zeros((0, PR_LEN))
        self.ratio = np.zeros(0)

    def ensure(self, m):
        if m > self.active.shape[0]:
            cap = int(m * 1.25) + 64
            self.active = np.zeros(cap, dtype=np.int8)
            self.res = np.zeros((cap, PR_LEN))
            self.ratio = np.zeros(cap)


@register("serial")
class SerialMode:
    """Reference step driver. options: neighbor ('allpairs' | 'linkcell'); skin: Verlet skin as a
    fraction of the largest bounding diameter (0: estimate neighbours every step, the paper's way);
    contact_method: ellipsoid contact geometry, one of dem.forces.CONTACT_METHODS."""

    def setup(self, scene, dt, neighbor="linkcell", skin=0.0, contact_method="exact", **_):
        if contact_method not in CONTACT_METHODS:
            raise ModeError(f"unknown contact method {contact_method!r} ({', '.join(CONTACT_METHODS)})")
        self.contact_method = contact_method
        self.method = CONTACT_METHODS.index(contact_method)
        self.scene = scene
        self.state = scene.state
        self.dt = float(dt)
        self.neighbor = neighbor
        self.g = np.asarray(scene.gravity, dtype=np.float64)
        self.has_gravity = bool(np.any(self.g != 0.0))
        self.has_walls = len(scene.walls) > 0
        self.all_spheres = self.state.all_spheres
        self.kind = scene_kind(self.state.shape, self.state.has_poly)
        self.pairs = PairBuffer(max(1024, 8 * self.state.n))
        self.skin = float(skin)
        self.verlet = VerletList(self.skin * 2.0 * float(self.state.rbound.max())) if skin > 0 else None
        self.rebuilt = True
        self.work = PairArrays()
        self.rot = None
        self.ensure_derived()
        self.max_overlap_ratio = 0.0
        self.worst_contact = None
        return self

    def warmup(self):
        """Compile every kernel by stepping a deep copy once (nothing of it is kept)."""
        twin = copy.copy(self)
        twin.state = copy.deepcopy(self.state)
        twin.pairs = PairBuffer(self.pairs.pi.shape[0])
        if self.verlet is not None:
            twin.verlet = VerletList(self.verlet.skin)
        twin.work = PairArrays()
        twin.rot = None
        twin.ensure_derived()
        twin.step()

    # --- phases -------------------------------------------------------------------------------
    def find_pairs(self, radii):
        """Candidate pairs whose spheres of radii [n] overlap (the mode's loop strategy)."""
        s = self.state
        return candidate_pairs(self.neighbor, s.pos, radii, s.gid, s.n_owned, self.pairs)

    def neighbour_phase(self):
        s = self.state
        if self.verlet is None:
            self.rebuilt = True
            return self.find_pairs(s.rbound)
        v = self.verlet
        self.rebuilt = v.needs_rebuild(s.pos, s.n_owned)
        if self.rebuilt:
            # re-sort particles in space first: memory order never changes results (Determinism)
            s.permute(cell_order(s.pos, 2.0 * float(s.rbound.max())))
            v.keep(s.pos, *self.find_pairs(s.rbound + 0.5 * v.skin))
        return v.pi, v.pj

    def ensure_derived(self):
        """Per-step rotation matrices [n,3,3] and angular velocities [n,3] sized to the current n
        (MPI changes n every step: ghosts and migrants); in a scene with poly-ellipsoids also the
        octant geometry oorg [n,3], orot [n,3,3], ax6 [n,6] (empty otherwise)."""
        n = self.state.n
        if self.rot is None or self.rot.shape[0] != n:
            self.rot = np.zeros((n, 3, 3))
            self.omega = np.zeros((n, 3))
            g = n if self.kind == POLYS else 0
            self.oorg = np.zeros((g, 3))
            self.orot = np.zeros((g, 3, 3))
            self.ax6 = np.zeros((g, 6))

    def derive(self):
        s = self.state
        self.ensure_derived()
        derive_range(0, s.n, s.quat, s.angmom, s.inertia, s.shape, self.rot, self.omega)
        if self.kind == POLYS:
            derive_geometry_range(0, s.n, s.pos, self.rot, s.axes, s.shape, s.poly, self.orot, self.oorg, self.ax6)

    def resolve_phase(self, pi, pj):
        s, m = self.state, self.scene.materials
        self.derive()
        self.work.ensure(len(pi))
        w = self.work
        if self.kind == POLYS:
            return resolve_poly_pairs_range(0, len(pi), pi, pj, s.pos, s.vel, self.omega, self.rot, s.axes,
                                            s.shape, s.mass, s.material, s.gid, s.n_owned, s.hist_start,
                                            s.hist_partner, s.hist_val, m.estar, m.gstar, m.mu, m.zeta, self.dt,
                                            self.method, w.active, w.res, w.ratio, self.oorg, self.orot, self.ax6)
        if self.kind == SPHERES:
            return resolve_sphere_pairs_range(0, len(pi), pi, pj, s.pos, s.vel, self.omega, s.axes, s.mass,
                                              s.material, s.gid, s.n_owned, s.hist_start, s.hist_partner,
                                              s.hist_val, m.estar, m.gstar, m.mu, m.zeta, self.dt,
                                              w.active, w.res, w.ratio)
        return resolve_pairs_range(0, len(pi), pi, pj, s.pos, s.vel, self.omega, self.rot, s.axes,
                                   s.shape, s.mass, s.material, s.gid, s.n_owned, s.hist_start,
                                   s.hist_partner, s.hist_val, m.estar, m.gstar, m.mu, m.zeta, self.dt,
                                   self.method, w.active, w.res, w.ratio)

    def gather(self, pi, pj, start, items, new_val):
        s = self.state
        gather_range(0, s.n_owned, start, items, pi, pj, self.work.res, s.force, s.torque, new_val)

    def walls(self):
        s, m, sc = self.state, self.scene.materials, self.scene
        return wall_range(0, s.n_owned, sc.wall_m, sc.wall_d, s.pos, s.vel, self.omega, self.rot, s.axes,
                          s.rbound, s.shape, s.mass, s.material, m.estar_w, m.gstar_w, m.zeta_w, m.mu_w,
                          s.wall_hist, self.dt, s.force, s.torque, self.oorg, self.orot, self.ax6)

    def integrate(self):
        s, g = self.state, self.g
        integrate_range(0, s.n_owned, s.pos, s.vel, s.quat, s.angmom, s.mass, s.inertia, s.shape,
                        s.force, s.torque, g[0], g[1], g[2], self.has_gravity, self.dt)

    def gather_phase(self, pi, pj):
        """Gather (ascending partner gid), walls, gravity and integration of the owned particles."""
        s = self.state
        w = self.work
        active = w.active[:len(pi)]
        start, items, keys = build_adjacency(pi, pj, active, s.gid, s.n_owned)
        new_val = np.empty((len(items), HIST_LEN))
        self.gather(pi, pj, start, items, new_val)
        s.hist_start, s.hist_partner, s.hist_val = start, keys, new_val
        n_wall, wall_worst, wall_p = self.walls() if self.has_walls else (0, 0.0, -1)
        n_contacts = int(active.sum())
        # the deepest contact of the step, named by global ids for the stability guard
        pair_worst = 0.0
        self.worst_contact = None
        if n_contacts:
            ratios = np.where(active == 1, w.ratio[:len(pi)], -1.0)
            k = int(np.argmax(ratios))
            pair_worst = float(ratios[k])
            self.worst_contact = (int(s.gid[pi[k]]), int(s.gid[pj[k]]))
        if wall_worst > pair_worst:
            self.worst_contact = (int(s.gid[wall_p]), "wall")
        self.integrate()
        return n_contacts, n_wall, max(pair_worst, wall_worst)

    def step(self):
        """One time step; returns the phase times [s] and counters of DESIGN.md's steps.csv."""
        t0 = time.perf_counter()
        pi, pj = self.neighbour_phase()
        t1 = time.perf_counter()
        ecalls = self.resolve_phase(pi, pj)
        t2 = time.perf_counter()
        n_contacts, n_wall, worst = self.gather_phase(pi, pj)
        t3 = time.perf_counter()
        self.max_overlap_ratio = max(self.max_overlap_ratio, worst)
        total = t3 - t0
        return {"totalT": total, "commuT": 0.0, "migraT": 0.0, "compuT": total,
                "neighborT": t1 - t0, "resolveT": t2 - t1, "n_owned": self.state.n_owned,
                "n_ghost": self.state.n - self.state.n_owned, "n_contacts": n_contacts,
                "n_wall_contacts": n_wall,
                "n_candidates": len(pi), "neighbor_rebuilt": int(self.rebuilt), "n_migrated": 0, "bytes_sent": 0,
                "ellipsoid_calls": ecalls, "max_overlap_ratio": worst}

    def snapshot(self):
        return self.state.snapshot()
