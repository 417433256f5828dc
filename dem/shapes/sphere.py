"""The sphere: one radius r [m], held as the ellipsoid (r, r, r), whose orientation shapes nothing.

Contact geometry: pair_geometry and wall_geometry below (dem.contact.sphere, closed form), which
dem.forces calls through the registry's dispatch (dem.shapes.dispatch); rotation: turn and derive
below (the exact exp map), which dem.integrate calls likewise. A scene of spheres only has a loop
of its own (dem.forces _resolve_spheres, finish_range with spheres=True: no rotation of the
shape) and a shorter ghost record (ghost_fields). Mass properties, radii and snapshot are the
ellipsoid's with a = b = c.
"""
import numpy as np
from numba import njit

from dem.contact.ellipsoid import _write_out
from dem.contact.sphere import sphere_contact, sphere_wall_contact
from dem.rotation import spin
from dem.shapes import SPHERE
from dem.shapes import ellipsoid
from dem.shapes.shape import Shape


def semi_axes(values):
    """A scene file's [r] [m] as the block's six semi-axes [r, r, r, 0, 0, 0]."""
    r = values[0]
    return np.array([r, r, r, 0.0, 0.0, 0.0])


def generate(a, draw):
    """Radius a (nothing drawn); the mass centre is the centre."""
    return np.repeat(a[:, None], 3, axis=1), np.zeros((len(a), 3))


# cost model (Shape; `bench perf --what split`, 2 cores): a pair apart 0.0066-0.0117 us, an overlapping
# sphere pair (closed form) 0.063 us; the per-particle pass 0.059 us, a wall on its list adds 0.009 us
SHAPE = Shape("sphere", SPHERE, ("r",), semi_axes, ellipsoid.body, ellipsoid.bounding_radius,
              ellipsoid.smallest_semi_axis, ellipsoid.equivalent_radius, ellipsoid.snapshot_pose, generate, False,
              # a scene of spheres: 14 doubles a ghost (112 bytes), 9 a forward exchange's row
              ghost_fields=("gid", "material", "mass", "axes0", "inertia0", "pos", "vel", "angmom"),
              moving_fields=("pos", "vel", "angmom"),
              mirrors=True,
              contact_cost=10.0, pass_cost=1.0, wall_cost=0.15)


@njit(cache=True, inline="always")
def pair_geometry(i, j, pos, rot, axes, shape, method, polys, lam0, n0, out):
    """Two spheres (dem.forces pair_geometry, whose arguments these are): closed form, the surface
    points p1 = x_c + depth/2 n on i, p2 = x_c - depth/2 n on j into out [OUT_LEN]. Returns (hit,
    radius of i, of j [m], 0: no solver)."""
    hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e = sphere_contact(
        pos[i, 0], pos[i, 1], pos[i, 2], axes[i, 0], pos[j, 0], pos[j, 1], pos[j, 2], axes[j, 0])
    if hit:
        h = 0.5 * depth
        _write_out(out, depth, nx, ny, nz, xcx + h * nx, xcy + h * ny, xcz + h * nz,
                   xcx - h * nx, xcy - h * ny, xcz - h * nz, r_e, 1.0, 0.0, 0, 0)
    return 1 if hit else 0, axes[i, 0], axes[j, 0], 0


@njit(cache=True, inline="always")
def wall_geometry(p, w, wall_m, wall_d, pos, rot, axes, shape, polys, out):
    """Sphere p and wall plane w (dem.forces wall_geometry, whose arguments these are): closed form,
    the normal from particle into wall -m. Returns (hit, contact_law's record, radius [m])."""
    mx, my, mz = wall_m[w, 0], wall_m[w, 1], wall_m[w, 2]
    hit, depth, xcx, xcy, xcz, r_e = sphere_wall_contact(pos[p, 0], pos[p, 1], pos[p, 2], axes[p, 0],
                                                         mx, my, mz, wall_d[w])
    return hit, (depth, -mx, -my, -mz, -mx, -my, -mz, 1.0, xcx, xcy, xcz, r_e, 1.0, 0.0), axes[p, 0]


@njit(cache=True, inline="always")
def support_bound(k, nx, ny, nz, rot, axes, rbound, shape):
    """The sphere's support along n (dem.overlaps' screen): the ellipsoid's formula with a = b = c = r,
    r to rounding."""
    return ellipsoid.support_bound(k, nx, ny, nz, rot, axes, rbound, shape)


@njit(cache=True, inline="always")
def turn(p, quat, angmom, inertia, shape, dt):
    """The sphere's orientation after dt [s] (dem.integrate integrate_particle, after the torque
    kick of angmom): the exact exp map at omega = L/I (dem.rotation spin). Returns (w, x, y, z)."""
    ii = 1.0 / inertia[p, 0]
    return spin(quat[p, 0], quat[p, 1], quat[p, 2], quat[p, 3], angmom[p, 0] * ii, angmom[p, 1] * ii,
                angmom[p, 2] * ii, dt)


@njit(cache=True, inline="always")
def derive(p, quat, angmom, inertia, shape, rot, omega, sphere_rot):
    """The sphere's rotation matrix rot[p] [3,3] and world angular velocity omega[p] = L/I [rad/s]
    (dem.integrate derive_particle). Its rot is the identity (its orientation does not shape it; a
    sphere-ellipsoid pair reads it, and a fixed value keeps that pair's rounding the same in every
    mode), written only when sphere_rot (it never changes, so the per-step pass leaves it)."""
    if sphere_rot:
        for a in range(3):
            for b in range(3):
                rot[p, a, b] = 1.0 if a == b else 0.0
    ii = 1.0 / inertia[p, 0]
    omega[p, 0] = angmom[p, 0] * ii
    omega[p, 1] = angmom[p, 1] * ii
    omega[p, 2] = angmom[p, 2] * ii


@njit(cache=True, inline="always")
def octant_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """The sphere as a poly-ellipsoid (dem.integrate derive_poly_geometry): the identity frame, its
    centre, six equal radii."""
    for a in range(3):
        for b in range(3):
            orot[p, a, b] = 1.0 if a == b else 0.0
        oorg[p, a] = pos[p, a]
        ax6[p, 2 * a] = axes[p, a]
        ax6[p, 2 * a + 1] = axes[p, a]
