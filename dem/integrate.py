"""Time integration: leapfrog (central difference) translation, symplectic splitting rotation.

Translation (central difference, velocities at half steps):
    v_{n+1/2} = v_{n-1/2} + dt (F_n/m + g),   x_{n+1} = x_n + dt v_{n+1/2}.
Rotation (Dullweber, Leimkuhler & McLachlan 1997; NO_SQUISH, Miller et al. 2002): the world-frame
angular momentum takes the torque kick L += dt T, then the free-rotor drift is split exactly into
rotations about the body axes 1(dt/2) 2(dt/2) 3(dt) 2(dt/2) 1(dt/2). It keeps the gyroscopic terms
(ParaEllip3d drops them) and conserves |L| to round-off; energy error is O(dt^2)
(contact-mechanics.md §4.2: 3.3e-6 at T/2000). Spheres (isotropic I) rotate by the exact exp map.
"""
import math
import numpy as np
from numba import njit

from dem.quaternion import quat_to_matrix, quat_normalize
from dem.state import SPHERE, POLY, P_AX, P_OFF, P_ROT


@njit(cache=True, inline="always")
def _rotate_body_axis(q, lb, inertia, axis, h):
    """Exact free rotation of duration h [s] about body axis `axis` under T_k = L_k^2/(2 I_k).

    q <- q (x) (cos(t/2), sin(t/2) e_k) with t = h L_k/I_k; the body-frame angular momentum
    lb [3] rotates by -t about e_k. Both arrays are updated in place.
    """
    t = h * lb[axis] / inertia[axis]
    s = math.sin(0.5 * t)
    # one sine and one root instead of four trigonometric calls: cos(t/2) >= 0 while |t| <= pi (a
    # sub-step turns far less), cos t = 1 - 2 s^2, sin t = 2 s c
    c = math.sqrt(1.0 - s * s) if abs(t) <= math.pi else math.cos(0.5 * t)
    ct = 1.0 - 2.0 * s * s
    st = 2.0 * s * c
    w, x, y, z = q[0], q[1], q[2], q[3]
    if axis == 0:
        q[0] = w * c - x * s
        q[1] = x * c + w * s
        q[2] = y * c + z * s
        q[3] = z * c - y * s
        l1, l2 = lb[1], lb[2]
        lb[1] = ct * l1 + st * l2
        lb[2] = -st * l1 + ct * l2
    elif axis == 1:
        q[0] = w * c - y * s
        q[1] = x * c - z * s
        q[2] = y * c + w * s
        q[3] = z * c + x * s
        l0, l2 = lb[0], lb[2]
        lb[0] = ct * l0 - st * l2
        lb[2] = st * l0 + ct * l2
    else:
        q[0] = w * c - z * s
        q[1] = x * c + y * s
        q[2] = y * c - x * s
        q[3] = z * c + w * s
        l0, l1 = lb[0], lb[1]
        lb[0] = ct * l0 + st * l1
        lb[1] = -st * l0 + ct * l1


@njit(cache=True)
def free_rotor_drift(q, angmom, inertia, dt, rot, lb):
    """Advance quaternion q [4] by dt under constant world angular momentum angmom [3].

    Symmetric splitting 1(dt/2) 2(dt/2) 3(dt) 2(dt/2) 1(dt/2); rot [3,3] and lb [3] are scratch.
    """
    quat_to_matrix(q, rot)
    for k in range(3):
        lb[k] = rot[0, k] * angmom[0] + rot[1, k] * angmom[1] + rot[2, k] * angmom[2]
    _rotate_body_axis(q, lb, inertia, 0, 0.5 * dt)
    _rotate_body_axis(q, lb, inertia, 1, 0.5 * dt)
    _rotate_body_axis(q, lb, inertia, 2, dt)
    _rotate_body_axis(q, lb, inertia, 1, 0.5 * dt)
    _rotate_body_axis(q, lb, inertia, 0, 0.5 * dt)
    quat_normalize(q)


@njit(cache=True, inline="always")
def _spin_sphere(q, angmom, i0, dt):
    """q <- (cos(|w|dt/2), sin(|w|dt/2) w_hat) (x) q with w = L/I (world frame), exact for spheres."""
    wx = angmom[0] / i0
    wy = angmom[1] / i0
    wz = angmom[2] / i0
    wn = math.sqrt(wx * wx + wy * wy + wz * wz)
    if wn == 0.0:
        return
    h = 0.5 * wn * dt
    sh = math.sin(h)
    c = math.sqrt(1.0 - sh * sh) if h <= 0.5 * math.pi else math.cos(h)  # one sine, as above
    s = sh / wn
    ax, ay, az = s * wx, s * wy, s * wz
    w, x, y, z = q[0], q[1], q[2], q[3]
    q[0] = c * w - ax * x - ay * y - az * z
    q[1] = c * x + ax * w + ay * z - az * y
    q[2] = c * y - ax * z + ay * w + az * x
    q[3] = c * z + ax * y - ay * x + az * w
    quat_normalize(q)


@njit(cache=True, inline="always")
def integrate_particle(p, pos, vel, quat, angmom, mass, inertia, shape, force, torque,
                       gx, gy, gz, has_gravity, dt, rot, lb):
    """One leapfrog step of particle p (see module docstring). rot [3,3], lb [3] are scratch."""
    im = 1.0 / mass[p]
    if has_gravity:
        vel[p, 0] += dt * (force[p, 0] * im + gx)
        vel[p, 1] += dt * (force[p, 1] * im + gy)
        vel[p, 2] += dt * (force[p, 2] * im + gz)
    else:
        vel[p, 0] += dt * (force[p, 0] * im)
        vel[p, 1] += dt * (force[p, 1] * im)
        vel[p, 2] += dt * (force[p, 2] * im)
    pos[p, 0] += dt * vel[p, 0]
    pos[p, 1] += dt * vel[p, 1]
    pos[p, 2] += dt * vel[p, 2]
    angmom[p, 0] += dt * torque[p, 0]
    angmom[p, 1] += dt * torque[p, 1]
    angmom[p, 2] += dt * torque[p, 2]
    if shape[p] == SPHERE:
        _spin_sphere(quat[p], angmom[p], inertia[p, 0], dt)
    else:
        free_rotor_drift(quat[p], angmom[p], inertia[p], dt, rot, lb)


@njit(cache=True)
def integrate_range(lo, hi, pos, vel, quat, angmom, mass, inertia, shape, force, torque,
                    gx, gy, gz, has_gravity, dt):
    """Integrate particles lo..hi-1 (a loop strategy's share of the owned particles)."""
    rot = np.empty((3, 3))
    lb = np.empty(3)
    for p in range(lo, hi):
        integrate_particle(p, pos, vel, quat, angmom, mass, inertia, shape, force, torque,
                           gx, gy, gz, has_gravity, dt, rot, lb)


@njit(cache=True, inline="always")
def derive_particle(p, quat, angmom, inertia, shape, rot, omega):
    """Rotation matrix rot[p] [3,3] and world angular velocity omega[p] [3]. A sphere's rot is the
    identity (its orientation does not shape it; a sphere-ellipsoid pair reads it, and a fixed value
    keeps that pair's rounding the same in every mode)."""
    if shape[p] == SPHERE:
        for a in range(3):
            for b in range(3):
                rot[p, a, b] = 1.0 if a == b else 0.0
        i0 = inertia[p, 0]
        omega[p, 0] = angmom[p, 0] / i0
        omega[p, 1] = angmom[p, 1] / i0
        omega[p, 2] = angmom[p, 2] / i0
        return
    r = rot[p]
    quat_to_matrix(quat[p], r)
    b0 = (r[0, 0] * angmom[p, 0] + r[1, 0] * angmom[p, 1] + r[2, 0] * angmom[p, 2]) / inertia[p, 0]
    b1 = (r[0, 1] * angmom[p, 0] + r[1, 1] * angmom[p, 1] + r[2, 1] * angmom[p, 2]) / inertia[p, 1]
    b2 = (r[0, 2] * angmom[p, 0] + r[1, 2] * angmom[p, 1] + r[2, 2] * angmom[p, 2]) / inertia[p, 2]
    omega[p, 0] = r[0, 0] * b0 + r[0, 1] * b1 + r[0, 2] * b2
    omega[p, 1] = r[1, 0] * b0 + r[1, 1] * b1 + r[1, 2] * b2
    omega[p, 2] = r[2, 0] * b0 + r[2, 1] * b1 + r[2, 2] * b2


@njit(cache=True)
def derive_range(lo, hi, quat, angmom, inertia, shape, rot, omega):
    for p in range(lo, hi):
        derive_particle(p, quat, angmom, inertia, shape, rot, omega)


@njit(cache=True)
def angular_velocity(quat, angmom, inertia, shape, out):
    """World-frame angular velocity out [n, 3] of all particles."""
    rot = np.empty((quat.shape[0], 3, 3))
    derive_range(0, quat.shape[0], quat, angmom, inertia, shape, rot, out)


@njit(cache=True, inline="always")
def derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """Contact geometry of particle p in a scene with poly-ellipsoids: every particle as a
    poly-ellipsoid (Peters et al. 2009): octant frame orot[p] [3,3], octant origin oorg[p] [3] [m],
    six semi-axes ax6[p] [6] [m]. A poly-ellipsoid's come from its record (R_oct = R W,
    o = x + R off); an ellipsoid is its own octant frame with a+ = a-, ...; a sphere has the
    identity frame and six equal radii. rot[p] must be derived first (derive_particle)."""
    if shape[p] == POLY:
        for a in range(3):
            for b in range(3):
                orot[p, a, b] = (rot[p, a, 0] * poly[p, P_ROT + b] + rot[p, a, 1] * poly[p, P_ROT + 3 + b]
                                 + rot[p, a, 2] * poly[p, P_ROT + 6 + b])
            oorg[p, a] = pos[p, a] + (rot[p, a, 0] * poly[p, P_OFF] + rot[p, a, 1] * poly[p, P_OFF + 1]
                                      + rot[p, a, 2] * poly[p, P_OFF + 2])
        for k in range(6):
            ax6[p, k] = poly[p, P_AX + k]
        return
    for a in range(3):
        for b in range(3):
            orot[p, a, b] = (1.0 if a == b else 0.0) if shape[p] == SPHERE else rot[p, a, b]
        oorg[p, a] = pos[p, a]
        ax6[p, 2 * a] = axes[p, a]
        ax6[p, 2 * a + 1] = axes[p, a]


@njit(cache=True)
def derive_geometry_range(lo, hi, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """derive_poly_geometry of particles lo..hi-1."""
    for p in range(lo, hi):
        derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)


@njit(cache=True)
def derive_all(lo, hi, pos, quat, angmom, inertia, axes, shape, poly, rot, omega, poly_scene, orot, oorg, ax6):
    """Derived quantities of particles lo..hi-1: rot, omega (derive_particle) and, when poly_scene,
    the octant geometry (derive_poly_geometry)."""
    for p in range(lo, hi):
        derive_particle(p, quat, angmom, inertia, shape, rot, omega)
        if poly_scene:
            derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)
