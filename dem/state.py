"""Particle state as a structure of arrays, keyed by global id.

Local order: owned particles occupy rows [0, n_owned); ghosts (MPI copies of a neighbour
block's particles) follow. Serial runs have no ghosts. Orientation is a unit quaternion
(w, x, y, z) body -> world; angular momentum L is kept in the world frame (the rotation
integrator is a splitting on L, contact-mechanics.md §4.2); omega is derived from it.

Contact history lives with the particles, keyed by partner global id: every owned particle
holds a row for each of its current contacts (a CSR: hist_start [n_owned+1], hist_partner [nnz]
ascending per particle, hist_val [nnz, HIST_LEN]), so both ends of a pair (possibly on two
ranks) carry identical history and migration moves it with the particle. The CSR is exactly
the adjacency that the force gather builds each step, so it costs nnz x 64 bytes and is
rewritten, never searched for free slots.
"""
import numpy as np
from numba import njit

from dem.integrate import angular_velocity
from dem.shapes import POLY_LEN
from dem.shapes.registry import bounding_radii, present

# contact-history record (per pair, per particle): stored tangential spring [3], contact radius,
# PW lambda and normal [3] (warm start of the ellipsoid solver)
H_FT = 0
H_A = 3
H_LAM = 4
H_N = 5
HIST_LEN = 8


def csr_rows(start, rows):
    """Entries of CSR rows `rows` (in that order): (index array into the CSR data, counts [len(rows)])."""
    return _csr_rows(np.ascontiguousarray(start, dtype=np.int64), np.ascontiguousarray(rows, dtype=np.int64))


@njit(cache=True)
def _csr_rows(start, rows):
    """csr_rows in two passes (numpy's six calls took 20 us at 800 rows)."""
    counts = np.empty(rows.shape[0], dtype=np.int64)
    total = 0
    for u in range(rows.shape[0]):
        counts[u] = start[rows[u] + 1] - start[rows[u]]
        total += counts[u]
    idx = np.empty(total, dtype=np.int64)
    o = 0
    for u in range(rows.shape[0]):
        for e in range(start[rows[u]], start[rows[u] + 1]):
            idx[o] = e
            o += 1
    return idx, counts


GID_LIMIT = 1 << 31   # global ids lie in [0, GID_LIMIT): a pair's two make one int64 key (dem.pairs.pair_key)


class State:
    """Arrays of n particles (owned first, then ghosts).

    gid [n] int64; shape [n] int8; axes [n, 3] semi-axes [m] (a sphere repeats r); rbound [n]
    bounding radius [m]; mass [n] [kg]; inertia [n, 3] principal moments [kg m^2];
    material [n] int32; pos [n, 3] [m]; vel [n, 3] [m/s]; quat [n, 4]; angmom [n, 3] world
    [kg m^2/s]; force, torque [n, 3] of the last step; contact history hist_start [n_owned+1],
    hist_partner [nnz] (partner gid), hist_val [nnz, HIST_LEN]; wall_hist [n, n_walls, HIST_LEN];
    poly [n, POLY_LEN] poly-ellipsoid records ([n, 0] in a scene without poly-ellipsoids).
    A poly-ellipsoid's pos / quat / axes here are its mass centre, principal frame and largest
    semi-axis per octant-frame axis; snapshot() reports its octant origin and frame (DESIGN.md).
    """

    def __init__(self, gid, shape, axes, mass, inertia, material, pos, vel, quat, angmom,
                 n_walls=0, poly=None):
        n = len(gid)
        self.gid = np.ascontiguousarray(gid, dtype=np.int64)
        if n and (self.gid.min() < 0 or self.gid.max() >= GID_LIMIT):
            raise ValueError(f"global ids must lie in [0, {GID_LIMIT}), got {self.gid.min()} to {self.gid.max()}")
        self.shape = np.ascontiguousarray(shape, dtype=np.int8)
        self.axes = np.ascontiguousarray(axes, dtype=np.float64).reshape(n, 3)
        self.poly = (np.zeros((n, 0)) if poly is None else
                     np.ascontiguousarray(poly, dtype=np.float64).reshape(n, POLY_LEN).copy())
        self.rbound = bounding_radii(self.axes, self.shape, self.poly)
        self.mass = np.ascontiguousarray(mass, dtype=np.float64)
        self.inertia = np.ascontiguousarray(inertia, dtype=np.float64).reshape(n, 3)
        self.material = np.ascontiguousarray(material, dtype=np.int32)
        self.pos = np.ascontiguousarray(pos, dtype=np.float64).reshape(n, 3).copy()
        self.vel = np.ascontiguousarray(vel, dtype=np.float64).reshape(n, 3).copy()
        self.quat = np.ascontiguousarray(quat, dtype=np.float64).reshape(n, 4).copy()
        self.angmom = np.ascontiguousarray(angmom, dtype=np.float64).reshape(n, 3).copy()
        self.force = np.zeros((n, 3))
        self.torque = np.zeros((n, 3))
        self.n_owned = n
        self.hist_start = np.zeros(n + 1, dtype=np.int64)
        self.hist_partner = np.zeros(0, dtype=np.int64)
        self.hist_val = np.zeros((0, HIST_LEN))
        self.wall_hist = np.zeros((n, n_walls, HIST_LEN))

    @property
    def n(self):
        return len(self.gid)

    @property
    def has_poly(self):
        """Whether the scene has poly-ellipsoids (fixed at construction: the record's width)."""
        return self.poly.shape[1] == POLY_LEN

    PER_PARTICLE = ("gid", "shape", "axes", "rbound", "mass", "inertia", "material", "pos", "vel",
                    "quat", "angmom", "force", "torque", "wall_hist", "poly")

    def permute_keep(self, rows):
        """Keep only the owned particles `rows` (in that order), with their history rows. take, not
        fancy indexing: a row gather of a [n, 3] array takes a quarter of the time."""
        rows = np.asarray(rows, dtype=np.int64)
        hrows, counts = csr_rows(self.hist_start, rows)
        for f in self.PER_PARTICLE:
            setattr(self, f, getattr(self, f).take(rows, axis=0))
        self.hist_start = np.zeros(len(rows) + 1, dtype=np.int64)
        np.cumsum(counts, out=self.hist_start[1:])
        self.hist_partner = self.hist_partner.take(hrows)
        self.hist_val = self.hist_val.take(hrows, axis=0)
        self.n_owned = len(rows)

    def permute(self, perm):
        """Store the owned particles in the order perm [n_owned] (a permutation of 0..n_owned-1),
        carrying every per-particle array and each particle's contact-history rows. Only the
        memory order changes: results never depend on it (DESIGN.md, Determinism)."""
        if self.n != self.n_owned:
            raise ValueError("permute() needs a state without ghosts")
        self.permute_keep(perm)

    def omega(self):
        """Angular velocity in the world frame [n, 3]: omega = R diag(1/I) R^T L."""
        out = np.empty((self.n, 3))
        angular_velocity(self.quat, self.angmom, self.inertia, self.shape, out)
        return out

    def kinetic_energy(self):
        """Translational + rotational kinetic energy of the owned particles [J]:
        sum m |v|^2 / 2 + omega . L / 2."""
        k = self.n_owned
        om = self.omega()[:k]
        return float(0.5 * np.sum(self.mass[:k, None] * self.vel[:k] ** 2) + 0.5 * np.sum(om * self.angmom[:k]))

    def snapshot(self):
        """Owned particles sorted by global id: dict of id [n], pos [n,3], quat [n,4], vel, omega [n,3],
        axes, shape. In a scene with poly-ellipsoids axes is [n, 6] ([a+, a-, b+, b-, c+, c-]; an
        ellipsoid repeats each semi-axis) and a poly-ellipsoid's pos and quat are its octant origin
        and octant frame (DESIGN.md); vel is always the mass centre's."""
        k = self.n_owned
        order = np.argsort(self.gid[:k], kind="stable")
        om = self.omega()[:k]
        snap = {"id": self.gid[:k][order].copy(), "pos": self.pos[:k][order].copy(),
                "quat": self.quat[:k][order].copy(), "vel": self.vel[:k][order].copy(),
                "omega": om[order].copy(), "axes": self.axes[:k][order].copy(),
                "shape": self.shape[:k][order].copy()}
        if self.has_poly:  # each shape's snapshot pose and six semi-axes (Shape.snapshot_pose)
            poly = self.poly[:k][order]
            axes6 = np.empty((k, 6))
            for shape, rows in present(snap["shape"]):
                rows = np.arange(k) if rows is None else rows
                snap["pos"][rows], snap["quat"][rows], axes6[rows] = shape.snapshot_pose(
                    snap["pos"][rows], snap["quat"][rows], snap["axes"][rows], poly[rows])
            snap["axes"] = axes6
        return snap
