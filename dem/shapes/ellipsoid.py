"""The ellipsoid: semi-axes (a, b, c) [m] along its body axes, any order.

Contact geometry: pair_geometry and wall_geometry below, which dem.forces calls through the
registry's dispatch (dem.shapes.dispatch): dem.contact.ellipsoid (ellipsoid_contact:
Perram-Wertheim + Newton on S^2; ellipsoid_wall_contact: the support along the wall normal),
dem.contact.methods (pw, sextic). Rotation: turn and derive below (dem.rotation: the symplectic
free-rotor splitting, contact-mechanics.md §4.2), which dem.integrate calls through the dispatch.
"""
import math

import numpy as np
from numba import njit

from dem.contact import EXACT, PW
from dem.contact.ellipsoid import ellipsoid_contact, ellipsoid_wall_contact, solved_geometry
from dem.contact.methods import pw_contact, sextic_contact
from dem.rotation import drift, rotation_and_omega
from dem.shapes import ELLIPSOID
from dem.shapes.shape import Shape


def semi_axes(values):
    """A scene file's [a, b, c] [m] as the block's six semi-axes [a, b, c, 0, 0, 0]."""
    return np.concatenate([values, np.zeros(3)])


def body(axes6, density, pos, quat):
    """Mass m = (4/3) pi rho a b c [kg] and principal moments m/5 (b^2 + c^2, a^2 + c^2, a^2 + b^2)
    [kg m^2] (the body frame is principal: pos and quat stay as given)."""
    axes = np.ascontiguousarray(axes6[:, :3])
    a, b, c = axes[:, 0], axes[:, 1], axes[:, 2]
    mass = 4.0 / 3.0 * math.pi * density * a * b * c
    inertia = np.stack([mass / 5 * (b * b + c * c), mass / 5 * (a * a + c * c), mass / 5 * (a * a + b * b)], axis=1)
    return axes, mass, inertia, pos, quat, None


def bounding_radius(axes, poly):
    """The largest semi-axis [m]."""
    return axes.max(axis=1)


def smallest_semi_axis(axes, poly):
    """The smallest semi-axis [m]."""
    return axes.min(axis=1)


def equivalent_radius(axes, poly):
    """(a b c)^(1/3) [m]."""
    return np.cbrt(np.prod(axes, axis=1))


def snapshot_pose(pos, quat, axes, poly):
    """Pose as held, each semi-axis twice (plus and minus sides alike)."""
    return pos, quat, np.repeat(axes, 2, axis=1)


def generate(a, draw):
    """Semi-axes (a, a b/a, a c/a), the ratios b/a and c/a drawn from the scene's aspect_b and
    aspect_c ranges (default [1, 1]); the mass centre is the centre."""
    k = len(a)
    return np.stack([a, a * draw("aspect_b", [1.0, 1.0], k), a * draw("aspect_c", [1.0, 1.0], k)], axis=1), \
        np.zeros((k, 3))


# cost model (Shape; `bench perf --what split`, 2 cores, in the sphere's units): an overlapping pair
# (the iterative solve) 0.27 us on packed 2000, 0.35 us on the built-in mixed crystal; the
# per-particle pass 0.142 us, a wall on its list adds 0.129 us (its wall contact needs its support)
SHAPE = Shape("ellipsoid", ELLIPSOID, ("a", "b", "c"), semi_axes, body, bounding_radius, smallest_semi_axis,
              equivalent_radius, snapshot_pose, generate, True,
              # spheres and ellipsoids: 23 doubles a ghost (184 bytes), 13 a forward exchange's row
              ghost_fields=("gid", "shape", "material", "mass", "axes", "inertia", "pos", "vel", "angmom", "quat"),
              moving_fields=("pos", "vel", "angmom", "quat"),
              mirrors=True,
              contact_cost=40.0, pass_cost=2.4, wall_cost=2.2)


@njit(cache=True, inline="always")
def pair_geometry(i, j, pos, rot, axes, shape, method, polys, lam0, n0, out):
    """A pair of ellipsoids, or of an ellipsoid and a sphere (its semi-axes (r, r, r)) (dem.forces
    pair_geometry, whose arguments these are): the contact method CONTACT_METHODS[method] (warm
    start lam0, n0 [3]) into out [OUT_LEN]. Returns (hit, smallest semi-axis of i, of j [m], 1: a
    solver ran)."""
    if method == EXACT:
        hit = ellipsoid_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    elif method == PW:
        hit = pw_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    else:
        hit = sextic_contact(pos[i], rot[i], axes[i], pos[j], rot[j], axes[j], lam0, n0, out)
    ai = min(axes[i, 0], min(axes[i, 1], axes[i, 2]))
    aj = min(axes[j, 0], min(axes[j, 1], axes[j, 2]))
    return hit, ai, aj, 1


@njit(cache=True, inline="always")
def wall_geometry(p, w, wall_m, wall_d, pos, rot, axes, shape, polys, out):
    """Ellipsoid p and wall plane w (dem.forces wall_geometry, whose arguments these are): its
    support along -m (out [OUT_LEN] scratch). Returns (hit, contact_law's record, smallest
    semi-axis [m])."""
    amin = min(axes[p, 0], min(axes[p, 1], axes[p, 2]))
    hit = ellipsoid_wall_contact(pos[p], rot[p], axes[p], wall_m[w], wall_d[w], out) == 1
    return hit, solved_geometry(out), amin


@njit(cache=True, inline="always")
def support_bound(k, nx, ny, nz, rot, axes, rbound, shape):
    """The support function of ellipsoid k along the unit world direction n, exactly:
    h(n) = |diag(a, b, c) R^T n| [m] (R = rot[k] body to world; dem.overlaps' screen)."""
    h2 = 0.0
    for c in range(3):
        t = axes[k, c] * (rot[k, 0, c] * nx + rot[k, 1, c] * ny + rot[k, 2, c] * nz)
        h2 += t * t
    return np.sqrt(h2)


@njit(cache=True, inline="always")
def turn(p, quat, angmom, inertia, shape, dt):
    """The ellipsoid's orientation after dt [s] (dem.integrate integrate_particle, after the torque
    kick of angmom): the symplectic free-rotor splitting (dem.rotation drift). Returns (w, x, y, z)."""
    return drift(quat[p, 0], quat[p, 1], quat[p, 2], quat[p, 3], angmom[p, 0], angmom[p, 1], angmom[p, 2],
                 inertia[p, 0], inertia[p, 1], inertia[p, 2], dt)


@njit(cache=True, inline="always")
def derive(p, quat, angmom, inertia, shape, rot, omega, sphere_rot):
    """Rotation matrix rot[p] = R(q) and world angular velocity omega[p] (dem.integrate
    derive_particle; dem.rotation rotation_and_omega)."""
    rotation_and_omega(p, quat, angmom, inertia, rot, omega)


@njit(cache=True, inline="always")
def octant_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """The ellipsoid as a poly-ellipsoid (dem.integrate derive_poly_geometry): its own octant frame
    and origin, a+ = a-, b+ = b-, c+ = c-."""
    for a in range(3):
        for b in range(3):
            orot[p, a, b] = rot[p, a, b]
        oorg[p, a] = pos[p, a]
        ax6[p, 2 * a] = axes[p, a]
        ax6[p, 2 * a + 1] = axes[p, a]
