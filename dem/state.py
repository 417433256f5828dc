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
import math

import numpy as np
from numba import njit

from dem.contact.polyellipsoid import mass_properties_poly
from dem.integrate import angular_velocity
from dem.quaternion import quat_to_matrices
from dem.shapes import P_AX, P_OFF, P_ROT, POLY, POLY_LEN, SPHERE

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


def mass_properties(shape, axes, density):
    """Mass [kg] and principal moments [kg m^2] [3] of a sphere (axes [r]) or ellipsoid (a, b, c).

    Ellipsoid: m = (4/3) pi rho a b c, I = m/5 (b^2+c^2, a^2+c^2, a^2+b^2).
    """
    a, b, c = axes
    m = 4.0 / 3.0 * math.pi * density * a * b * c
    return m, np.array([m / 5 * (b * b + c * c), m / 5 * (a * a + c * c), m / 5 * (a * a + b * b)])


def poly_body(axes6, density):
    """Rigid-body data of a poly-ellipsoid (Peters et al. 2009; contact-mechanics.md §2.2).

    Returns (mass [kg], principal moments [3] [kg m^2], record [POLY_LEN], V [3, 3]) where V's
    columns are the principal axes in the octant frame (dem.contact.polyellipsoid.
    mass_properties_poly), W = V^T and off = -V^T centroid. The principal frame is R = R_oct V.
    """
    m, cen, moments, v = mass_properties_poly(axes6, density)
    rec = np.zeros(POLY_LEN)
    rec[P_AX:P_AX + 6] = axes6
    rec[P_OFF:P_OFF + 3] = -(v.T @ cen)
    rec[P_ROT:P_ROT + 9] = v.T.reshape(9)
    return m, moments, rec, v


def poly_from_octant(axes6, density, origin, quat_oct):
    """Internal state of a poly-ellipsoid given as DESIGN.md's octant origin [3] and octant-frame
    quaternion [4]: (axes [3] = largest semi-axis per octant-frame axis, mass, principal moments [3],
    mass centre [3], principal-frame quaternion [4], record [POLY_LEN])."""
    a6 = np.asarray(axes6, dtype=np.float64)
    m, moments, rec, v = poly_body(a6, density)
    quat = quat_of_matrix(quat_to_matrices(quat_oct)[0] @ v)
    r = quat_to_matrices(quat)[0]
    pos = np.asarray(origin, dtype=np.float64) - r @ rec[P_OFF:P_OFF + 3]
    axes3 = np.array([max(a6[0], a6[1]), max(a6[2], a6[3]), max(a6[4], a6[5])])
    return axes3, m, moments, pos, quat, rec


def bounding_radii(axes, shape, poly):
    """Radius [n] of a sphere about each particle's centre (its mass centre) that holds it:
    the largest semi-axis, for a poly-ellipsoid the largest of six plus |octant origin offset|."""
    rb = axes.max(axis=1).copy()
    if poly.shape[1]:
        sel = shape == POLY
        rb[sel] = poly[sel, P_AX:P_AX + 6].max(axis=1) + np.linalg.norm(poly[sel, P_OFF:P_OFF + 3], axis=1)
    return rb


def equivalent_radii(axes, shape, poly):
    """Volume-equivalent radius [n] [m]: (a b c)^(1/3); a poly-ellipsoid's volume is that of the
    ellipsoid with semi-axes (a+ + a-)/2, (b+ + b-)/2, (c+ + c-)/2 (contact-mechanics.md §2.2)."""
    r = np.cbrt(np.prod(axes, axis=1))
    if poly.shape[1]:
        sel = shape == POLY
        a6 = poly[sel, P_AX:P_AX + 6]
        r[sel] = np.cbrt(np.prod(0.5 * (a6[:, 0::2] + a6[:, 1::2]), axis=1))
    return r


def smallest_semi_axes(axes, shape, poly):
    """Smallest semi-axis [n] of each particle (of six for a poly-ellipsoid) [m]."""
    amin = axes.min(axis=1).copy()
    if poly.shape[1]:
        sel = shape == POLY
        amin[sel] = poly[sel, P_AX:P_AX + 6].min(axis=1)
    return amin


def quat_of_matrix(r):
    """Unit quaternion (w, x, y, z), w >= 0, of rotation matrix r [3, 3] (Shepperd's method)."""
    t = np.trace(r)
    k = int(np.argmax([t, r[0, 0], r[1, 1], r[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = np.array([(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        q = np.array([(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        q = np.array([(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


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
    def all_spheres(self):
        return bool(np.all(self.shape == SPHERE))

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
        if self.has_poly:
            poly = self.poly[:k][order]
            snap["axes"] = np.repeat(snap["axes"], 2, axis=1)
            for r in np.flatnonzero(snap["shape"] == POLY):
                snap["axes"][r] = poly[r, P_AX:P_AX + 6]
                snap["pos"][r], snap["quat"][r] = octant_pose(snap["pos"][r], snap["quat"][r], poly[r])
        return snap


def octant_pose(pos, quat, rec):
    """Octant origin [3] and octant-frame quaternion [4] of a poly-ellipsoid at mass centre pos in
    principal frame quat (record rec [POLY_LEN]): o = pos + R off, R_oct = R W."""
    r = quat_to_matrices(quat)[0]
    o = pos + r @ rec[P_OFF:P_OFF + 3]
    return o, quat_of_matrix(r @ rec[P_ROT:P_ROT + 9].reshape(3, 3))
