"""Rotation kernels of a rigid body's orientation, the quaternion q = (w, x, y, z) (body -> world).

drift: the free rotor under constant world angular momentum L, split exactly into rotations about
the body axes 1(dt/2) 2(dt/2) 3(dt) 2(dt/2) 1(dt/2) (Dullweber, Leimkuhler & McLachlan 1997;
NO_SQUISH, Miller et al. 2002): it keeps the gyroscopic terms (ParaEllip3d drops them) and
conserves |L| to round-off; energy error is O(dt^2) (contact-mechanics.md §4.2: 3.3e-6 at T/2000).
spin: a body of isotropic inertia (a sphere) turned by the exact exp map. rotation_and_omega: the
rotation matrix R(q) and the world angular velocity omega = R I^-1 R^T L. The half-angle sines and
cosines of a step's small rotations come from their Taylor series (truncated below 1e-20 relative),
libm only for angles above 0.1 rad. The shapes pick among these (dem.shapes: turn, derive) and
dem.integrate calls them through the registry's dispatch.
"""
import math
from numba import njit


# Taylor coefficients of sin x / x and cos x in x^2 (|x| <= HALF_ANGLE_SERIES: the first term left
# out is below 1e-20 relative, far under one rounding)
S3, S5, S7, S9 = 1.0 / 6.0, 1.0 / 20.0, 1.0 / 42.0, 1.0 / 72.0
C2, C4, C6, C8, C10 = 0.5, 1.0 / 12.0, 1.0 / 30.0, 1.0 / 56.0, 1.0 / 90.0
HALF_ANGLE_SERIES = 0.05


@njit(cache=True, inline="always")
def _sinc_cos(x2):
    """(sin x / x, cos x) from x^2 <= HALF_ANGLE_SERIES^2 by their Taylor series (Horner form)."""
    sinc = 1.0 - x2 * S3 * (1.0 - x2 * S5 * (1.0 - x2 * S7 * (1.0 - x2 * S9)))
    cos = 1.0 - x2 * C2 * (1.0 - x2 * C4 * (1.0 - x2 * C6 * (1.0 - x2 * C8 * (1.0 - x2 * C10))))
    return sinc, cos


@njit(cache=True, inline="always")
def half_angle(t):
    """(sin(t/2), cos(t/2)) of a rotation angle t [rad]: the series for the small angles of a time
    step (a few multiplications instead of two libm calls), libm beyond."""
    x = 0.5 * t
    if abs(x) <= HALF_ANGLE_SERIES:
        sinc, c = _sinc_cos(x * x)
        return x * sinc, c
    return math.sin(x), math.cos(x)


@njit(cache=True, inline="always")
def _turn(axis, h, ii, w, x, y, z, l0, l1, l2):
    """Exact free rotation of duration h [s] about body axis `axis` under T_k = L_k^2/(2 I_k), ii =
    1/I_k: q <- q (x) (cos(t/2), sin(t/2) e_k) with t = h L_k / I_k, and the body-frame angular
    momentum (l0, l1, l2) rotates by -t about e_k (cos t = 1 - 2 s^2, sin t = 2 s c from the half
    angle). Returns the new (w, x, y, z, l0, l1, l2)."""
    if axis == 0:
        s, c = half_angle(h * l0 * ii)
        ct, st = 1.0 - 2.0 * s * s, 2.0 * s * c
        return (w * c - x * s, x * c + w * s, y * c + z * s, z * c - y * s,
                l0, ct * l1 + st * l2, -st * l1 + ct * l2)
    if axis == 1:
        s, c = half_angle(h * l1 * ii)
        ct, st = 1.0 - 2.0 * s * s, 2.0 * s * c
        return (w * c - y * s, x * c - z * s, y * c + w * s, z * c + x * s,
                ct * l0 - st * l2, l1, st * l0 + ct * l2)
    s, c = half_angle(h * l2 * ii)
    ct, st = 1.0 - 2.0 * s * s, 2.0 * s * c
    return (w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s,
            ct * l0 + st * l1, -st * l0 + ct * l1, l2)


@njit(cache=True, inline="always")
def _normalized(w, x, y, z):
    """q / |q| (removes O(eps) drift each step)."""
    s = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return w * s, x * s, y * s, z * s


@njit(cache=True, inline="always")
def drift(w, x, y, z, lx, ly, lz, i0, i1, i2, dt):
    """Quaternion (w, x, y, z) advanced by dt [s] under constant world angular momentum
    (lx, ly, lz) [kg m^2/s], principal moments (i0, i1, i2) [kg m^2]: the symmetric splitting
    1(dt/2) 2(dt/2) 3(dt) 2(dt/2) 1(dt/2) of the free rotor, normalised. Scalars only: no array
    views, whose reference counts cost atomic operations in numba."""
    # body-frame angular momentum R^T L
    l0 = ((1.0 - 2.0 * (y * y + z * z)) * lx + 2.0 * (x * y + w * z) * ly + 2.0 * (x * z - w * y) * lz)
    l1 = (2.0 * (x * y - w * z) * lx + (1.0 - 2.0 * (x * x + z * z)) * ly + 2.0 * (y * z + w * x) * lz)
    l2 = (2.0 * (x * z + w * y) * lx + 2.0 * (y * z - w * x) * ly + (1.0 - 2.0 * (x * x + y * y)) * lz)
    i0, i1, i2 = 1.0 / i0, 1.0 / i1, 1.0 / i2
    h = 0.5 * dt
    w, x, y, z, l0, l1, l2 = _turn(0, h, i0, w, x, y, z, l0, l1, l2)
    w, x, y, z, l0, l1, l2 = _turn(1, h, i1, w, x, y, z, l0, l1, l2)
    w, x, y, z, l0, l1, l2 = _turn(2, dt, i2, w, x, y, z, l0, l1, l2)
    w, x, y, z, l0, l1, l2 = _turn(1, h, i1, w, x, y, z, l0, l1, l2)
    w, x, y, z, l0, l1, l2 = _turn(0, h, i0, w, x, y, z, l0, l1, l2)
    return _normalized(w, x, y, z)


@njit(cache=True)
def free_rotor_drift(q, angmom, inertia, dt, rot, lb):
    """drift() on arrays: advance quaternion q [4] in place by dt under constant world angular
    momentum angmom [3] (rot [3,3], lb [3]: unused, kept for callers that pass scratch)."""
    q[0], q[1], q[2], q[3] = drift(q[0], q[1], q[2], q[3], angmom[0], angmom[1], angmom[2],
                                   inertia[0], inertia[1], inertia[2], dt)


@njit(cache=True, inline="always")
def spin(w, x, y, z, ox, oy, oz, dt):
    """Quaternion (w, x, y, z) of a sphere turned at world angular velocity (ox, oy, oz) [rad/s] for
    dt [s]: the exact exp map (cos h, sin(h)/|omega| omega) (x) q, h = |omega| dt/2, by the series
    in h^2 (no root, no libm) for the small angles of a step; normalised."""
    h2 = 0.25 * dt * dt * (ox * ox + oy * oy + oz * oz)
    if h2 == 0.0:
        return w, x, y, z
    if h2 <= HALF_ANGLE_SERIES * HALF_ANGLE_SERIES:
        sinc, c = _sinc_cos(h2)
        s = 0.5 * dt * sinc
    else:
        wn = math.sqrt(ox * ox + oy * oy + oz * oz)
        c = math.cos(0.5 * wn * dt)
        s = math.sin(0.5 * wn * dt) / wn
    ax, ay, az = s * ox, s * oy, s * oz
    return _normalized(c * w - ax * x - ay * y - az * z, c * x + ax * w + ay * z - az * y,
                       c * y - ax * z + ay * w + az * x, c * z + ax * y - ay * x + az * w)


@njit(cache=True, inline="always")
def rotation_and_omega(p, quat, angmom, inertia, rot, omega):
    """Rotation matrix rot[p] [3,3] = R(q_p) and world angular velocity omega[p] [3] =
    R diag(1/I) R^T L [rad/s] of particle p (principal moments inertia[p] [kg m^2], world angular
    momentum angmom[p] [kg m^2/s])."""
    w, x, y, z = quat[p, 0], quat[p, 1], quat[p, 2], quat[p, 3]
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r01 = 2.0 * (x * y - w * z)
    r02 = 2.0 * (x * z + w * y)
    r10 = 2.0 * (x * y + w * z)
    r11 = 1.0 - 2.0 * (x * x + z * z)
    r12 = 2.0 * (y * z - w * x)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    rot[p, 0, 0] = r00
    rot[p, 0, 1] = r01
    rot[p, 0, 2] = r02
    rot[p, 1, 0] = r10
    rot[p, 1, 1] = r11
    rot[p, 1, 2] = r12
    rot[p, 2, 0] = r20
    rot[p, 2, 1] = r21
    rot[p, 2, 2] = r22
    lx, ly, lz = angmom[p, 0], angmom[p, 1], angmom[p, 2]
    b0 = (r00 * lx + r10 * ly + r20 * lz) / inertia[p, 0]
    b1 = (r01 * lx + r11 * ly + r21 * lz) / inertia[p, 1]
    b2 = (r02 * lx + r12 * ly + r22 * lz) / inertia[p, 2]
    omega[p, 0] = r00 * b0 + r01 * b1 + r02 * b2
    omega[p, 1] = r10 * b0 + r11 * b1 + r12 * b2
    omega[p, 2] = r20 * b0 + r21 * b1 + r22 * b2
