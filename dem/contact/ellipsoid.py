"""Exact ellipsoid-ellipsoid and ellipsoid-wall contact geometry (scalar @njit kernels).

Method (reference notes contact-mechanics.md §1.4-1.6):

* Ellipsoid i: centre c_i, rotation R_i (body -> world), semi-axes (a_i, b_i, c_i);
  shape matrix Q_i = R_i diag(a_i^2, b_i^2, c_i^2) R_i^T, A_i = Q_i^-1.
  Support function h_i(n) = sqrt(n^T Q_i n), support point s_i(n) = c_i + Q_i n / h_i(n).
* Penetration depth (minimum translation distance) of overlapping convex bodies:
  PD = min_{|n|=1} phi(n),  phi(n) = h_1(n) + h_2(n) - n.R,  R = c_2 - c_1.
  At the minimiser n*, s_1(n*) - s_2(-n*) = PD n*: p1, p2 are the common-normal points.
* Overlap certificate and starting normal: Perram-Wertheim contact function
  F(lam) = lam (1 - lam) R^T G(lam)^-1 R,  G = (1 - lam) Q_1 + lam Q_2 (concave on [0, 1]);
  the bodies overlap iff max F < 1.  Any F(lam) > 1 proves separation.  n0 = G(lam*)^-1 R.
  Maximised by bracketed, safeguarded Newton with bisection fallback (stop test on the raw
  Newton step, before safeguarding; iteration cap).
* Newton on the unit sphere for phi from n0 (Riemannian Hessian H_T = W_1 + W_2 - phi 1,
  W_i = K_i^-1 the radius-of-curvature tensors, K_i = h_i T^T A_i T), trust region, SPD check,
  best-phi bookkeeping: the reported depth is phi at the best normal seen, an upper bound of
  PD that equals PD at convergence; the PW normal is the fallback.
* Any phi(n) < 0 proves separation (n is a separating axis).
* Deep overlap (phi above a principal radius of W_1 + W_2, H_T indefinite; outside the DEM
  regime delta << curvature radii): the steps use W_1 + W_2 (a descent direction) with up to
  NEWTON_DEEP_MAXIT evaluations; the result is a local minimum of phi (or the best phi seen),
  always finite, an upper bound of the true PD.
* Warm start (optional n0): Newton from the previous normal is accepted without PW only if it
  converges with an SPD Hessian and 0 < phi* < rho1 + rho2, rho_i = c_i^2 / a_i the smallest
  radius of curvature of body i.  Then by Blaschke's rolling-ball theorem (all curvature radii of
  the Minkowski body E1 + (-E2) are >= rho1 + rho2) the ball of radius phi* around R lies inside
  the Minkowski body and touches its boundary at the stationary point: the bodies overlap and
  phi* is the global PD.  Otherwise the cold PW path runs.  Results are a pure function of the
  inputs (the warm start is an input).
* Hertz radius: K = K_1 + K_2 in a common tangent basis at +-n*, R_e = det(K)^-1/2,
  kratio = kappa''/kappa' >= 1 (reference §3.1).

All kernels are allocation free (scalar locals and tuples), plain float64, no fastmath.
"""
import numpy as np
from numba import njit, types
from numba.extending import overload

# ---- output buffer layout (float64 array of length OUT_LEN) ----
OUT_DEPTH = 0           # penetration depth delta > 0 [m] (minimum translation distance)
OUT_NX = 1              # unit common normal n, from body 1 towards body 2
OUT_NY = 2
OUT_NZ = 3
OUT_P1X = 4             # p1 = s1(n), contact point on body 1's surface
OUT_P1Y = 5
OUT_P1Z = 6
OUT_P2X = 7             # p2 = s2(-n) = p1 - delta n, contact point on body 2's surface
OUT_P2Y = 8
OUT_P2Z = 9
OUT_XCX = 10            # x_c = (p1 + p2) / 2
OUT_XCY = 11
OUT_XCZ = 12
OUT_RE = 13             # equivalent Hertz radius det(K1 + K2)^-1/2 [m]
OUT_KRATIO = 14         # kappa'' / kappa' >= 1 of K1 + K2
OUT_LAM = 15            # PW lambda* (warm-start path: h1/(h1 + h2) at n*, its touching limit)
OUT_PW_ITERS = 16       # PW iterations (0: warm-start path, PW skipped)
OUT_NEWTON_ITERS = 17   # evaluations of phi / Hessian on S^2 (each followed by a step)
OUT_LEN = 18

# ---- solver parameters (reference §1.5) ----
PW_TOL = 1e-11          # |raw Newton step in lambda| for PW convergence
PW_MAXIT = 50           # PW iteration cap
NEWTON_MAXIT = 7        # phi evaluations on S^2 (at most 6 Newton steps)
NEWTON_WARM_MAXIT = 4   # phi evaluations on the warm-start path
NEWTON_DEEP_MAXIT = 20  # phi evaluations once H_T was indefinite (deep overlap, cold path)
NEWTON_TOL = 1e-10      # step length [rad] at which the sphere-Newton has converged
TRUST_RADIUS = 0.2      # largest sphere-Newton step [rad]


def new_out():
    """A fresh output buffer [OUT_LEN] (set-up helper; kernels never allocate)."""
    return np.zeros(OUT_LEN)


@njit(cache=True, _nrt=False)
def _shape_matrix(rot, ax):
    """Upper triangle (q00, q01, q02, q11, q12, q22) of Q = R diag(ax^2) R^T."""
    s0 = ax[0] * ax[0]
    s1 = ax[1] * ax[1]
    s2 = ax[2] * ax[2]
    r00 = rot[0, 0]
    r01 = rot[0, 1]
    r02 = rot[0, 2]
    r10 = rot[1, 0]
    r11 = rot[1, 1]
    r12 = rot[1, 2]
    r20 = rot[2, 0]
    r21 = rot[2, 1]
    r22 = rot[2, 2]
    return (r00 * r00 * s0 + r01 * r01 * s1 + r02 * r02 * s2,
            r00 * r10 * s0 + r01 * r11 * s1 + r02 * r12 * s2,
            r00 * r20 * s0 + r01 * r21 * s1 + r02 * r22 * s2,
            r10 * r10 * s0 + r11 * r11 * s1 + r12 * r12 * s2,
            r10 * r20 * s0 + r11 * r21 * s1 + r12 * r22 * s2,
            r20 * r20 * s0 + r21 * r21 * s1 + r22 * r22 * s2)


@njit(cache=True, _nrt=False)
def _hq(rot, ax, nx, ny, nz):
    """Support function h = sqrt(n^T Q n) and Q n, evaluated in the body frame.

    h^2 = sum_k a_k^2 (R^T n)_k^2 is a sum of positive terms: no cancellation (the world-frame
    n^T Q n loses ~ (a_max / h)^2 ulps at the side of a needle).
    """
    m0 = rot[0, 0] * nx + rot[1, 0] * ny + rot[2, 0] * nz
    m1 = rot[0, 1] * nx + rot[1, 1] * ny + rot[2, 1] * nz
    m2 = rot[0, 2] * nx + rot[1, 2] * ny + rot[2, 2] * nz
    p0 = ax[0] * ax[0] * m0
    p1 = ax[1] * ax[1] * m1
    p2 = ax[2] * ax[2] * m2
    h = np.sqrt(m0 * p0 + m1 * p1 + m2 * p2)
    return (h,
            rot[0, 0] * p0 + rot[0, 1] * p1 + rot[0, 2] * p2,
            rot[1, 0] * p0 + rot[1, 1] * p1 + rot[1, 2] * p2,
            rot[2, 0] * p0 + rot[2, 1] * p1 + rot[2, 2] * p2)


@njit(cache=True, _nrt=False)
def _h(rot, ax, nx, ny, nz):
    """Support function h(n) = sqrt(n^T Q n) (n need not be unit), body frame."""
    m0 = (rot[0, 0] * nx + rot[1, 0] * ny + rot[2, 0] * nz) * ax[0]
    m1 = (rot[0, 1] * nx + rot[1, 1] * ny + rot[2, 1] * nz) * ax[1]
    m2 = (rot[0, 2] * nx + rot[1, 2] * ny + rot[2, 2] * nz) * ax[2]
    return np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)


@njit(cache=True, _nrt=False)
def _basis(nx, ny, nz):
    """Orthonormal tangent basis t1, t2 of unit n (t1 = n x e_k / |.|, k = smallest |n_k|)."""
    ax = abs(nx)
    ay = abs(ny)
    az = abs(nz)
    if ax <= ay and ax <= az:
        tx, ty, tz = 0.0, nz, -ny
    elif ay <= az:
        tx, ty, tz = -nz, 0.0, nx
    else:
        tx, ty, tz = ny, -nx, 0.0
    s = 1.0 / np.sqrt(tx * tx + ty * ty + tz * tz)
    tx *= s
    ty *= s
    tz *= s
    return tx, ty, tz, ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx


@njit(cache=True, _nrt=False)
def _curv(rot, ax, h, t1x, t1y, t1z, t2x, t2y, t2z):
    """Curvature tensor K = h T^T A T (A = Q^-1) at the support point of normal n = t1 x t2.

    Returns (k11, k12, k22); evaluated in the body frame as sums over the semi-axes.
    """
    u0 = (rot[0, 0] * t1x + rot[1, 0] * t1y + rot[2, 0] * t1z) / ax[0]
    u1 = (rot[0, 1] * t1x + rot[1, 1] * t1y + rot[2, 1] * t1z) / ax[1]
    u2 = (rot[0, 2] * t1x + rot[1, 2] * t1y + rot[2, 2] * t1z) / ax[2]
    v0 = (rot[0, 0] * t2x + rot[1, 0] * t2y + rot[2, 0] * t2z) / ax[0]
    v1 = (rot[0, 1] * t2x + rot[1, 1] * t2y + rot[2, 1] * t2z) / ax[1]
    v2 = (rot[0, 2] * t2x + rot[1, 2] * t2y + rot[2, 2] * t2z) / ax[2]
    return (h * (u0 * u0 + u1 * u1 + u2 * u2),
            h * (u0 * v0 + u1 * v1 + u2 * v2),
            h * (v0 * v0 + v1 * v1 + v2 * v2))


@njit(cache=True, _nrt=False)
def _hertz_radius(k11, k12, k22):
    """R_e = det(K)^-1/2 and kappa''/kappa' of a 2x2 SPD curvature tensor."""
    det = k11 * k22 - k12 * k12
    half_tr = 0.5 * (k11 + k22)
    dd = 0.5 * (k11 - k22)
    big = half_tr + np.sqrt(dd * dd + k12 * k12)
    small = det / big
    return 1.0 / np.sqrt(det), big / small


@njit(cache=True, inline="always")
def _oct_axes(rot, a6, nx, ny, nz):
    """Octant semi-axes (tuple) selected by the sign pattern of R^T n (0 counts as +)."""
    m0 = rot[0, 0] * nx + rot[1, 0] * ny + rot[2, 0] * nz
    m1 = rot[0, 1] * nx + rot[1, 1] * ny + rot[2, 1] * nz
    m2 = rot[0, 2] * nx + rot[1, 2] * ny + rot[2, 2] * nz
    return (a6[0] if m0 >= 0.0 else a6[1],
            a6[2] if m1 >= 0.0 else a6[3],
            a6[4] if m2 >= 0.0 else a6[5])


def _facing_axes(rot, a, octants, nx, ny, nz):
    """The three semi-axes of the body that face direction n: a itself for an ellipsoid (a [3], or
    a 3-tuple: an octant the active set chose), the octant ellipsoid of a poly-ellipsoid (a [6],
    octants True). Compiled by its overload below, per type of a: the 3-tuple form (called from
    the poly-ellipsoid solver) never types the octant choice."""
    raise NotImplementedError("numba only")


@overload(_facing_axes)
def _facing_axes_numba(rot, a, octants, nx, ny, nz):
    if isinstance(a, types.BaseTuple):
        return lambda rot, a, octants, nx, ny, nz: a

    def axes_of(rot, a, octants, nx, ny, nz):
        if octants:
            return _oct_axes(rot, a, nx, ny, nz)
        return (a[0], a[1], a[2])
    return axes_of


@njit(cache=True, _nrt=False)
def _newton_s2(rot1, a1, rot2, a2, octants, rx, ry, rz, rn, nx, ny, nz, maxit, deep_maxit):
    """Minimise phi(n) = h1(n) + h2(n) - n.R on S^2 from the unit normal (nx, ny, nz).

    Ellipsoids (octants False): a1, a2 [3] semi-axes. Poly-ellipsoids (octants True): a1, a2 [6]
    = [a+, a-, b+, b-, c+, c-], and each evaluation re-chooses the octant ellipsoid that faces n
    (body 2 faces -n), phi then being phi_P of the octant active set (polyellipsoid.py).

    rn = |R| sets the round-off scale of phi.  At most maxit evaluations of phi (each followed
    by a step unless stopped), raised to deep_maxit once the Riemannian Hessian is found
    indefinite (deep overlap; steps then use its SPD part W1 + W2, a descent direction).
    Steps are clipped to a trust region; a step that raises phi beyond round-off is undone and
    the region shrunk.  Returns (nx, ny, nz, phi, evaluations, status) at the best normal:
    status 1: converged (step < NEWTON_TOL, Hessian SPD and phi non-increasing throughout),
    0: not converged / Hessian indefinite / a step was undone (best normal kept),
    -1: phi(n) < 0, i.e. n is a separating axis (bodies certainly apart).
    """
    bx, by, bz = nx, ny, nz
    best = np.inf
    radius = TRUST_RADIUS
    status = 1
    deep = False
    it = 0
    while True:
        it += 1
        ax1 = _facing_axes(rot1, a1, octants, nx, ny, nz)
        ax2 = _facing_axes(rot2, a2, octants, -nx, -ny, -nz)
        h1, u0, u1, u2 = _hq(rot1, ax1, nx, ny, nz)
        h2, w0, w1, w2 = _hq(rot2, ax2, nx, ny, nz)
        phi = h1 + h2 - (nx * rx + ny * ry + nz * rz)
        if phi < 0.0:
            return nx, ny, nz, phi, it, -1
        if phi > best + 1e-14 * (h1 + h2 + rn):
            # phi went up beyond round-off: back to the best normal, smaller trust region
            status = 0
            nx, ny, nz = bx, by, bz
            radius *= 0.25
            if it >= maxit:
                break
            continue
        best = phi
        bx, by, bz = nx, ny, nz
        if it >= maxit:
            status = 0
            break
        t1x, t1y, t1z, t2x, t2y, t2z = _basis(nx, ny, nz)
        # tangential gradient T^T g, g = Q1 n / h1 + Q2 n / h2 - R
        gx = u0 / h1 + w0 / h2 - rx
        gy = u1 / h1 + w1 / h2 - ry
        gz = u2 / h1 + w2 / h2 - rz
        g1 = t1x * gx + t1y * gy + t1z * gz
        g2 = t2x * gx + t2y * gy + t2z * gz
        # Riemannian Hessian H = W1 + W2 - phi 1, W_i = K_i^-1 radius-of-curvature tensors
        k1 = _curv(rot1, ax1, h1, t1x, t1y, t1z, t2x, t2y, t2z)
        k2 = _curv(rot2, ax2, h2, t1x, t1y, t1z, t2x, t2y, t2z)
        e1 = 1.0 / (k1[0] * k1[2] - k1[1] * k1[1])
        e2 = 1.0 / (k2[0] * k2[2] - k2[1] * k2[1])
        h11 = k1[2] * e1 + k2[2] * e2 - phi
        h12 = -(k1[1] * e1 + k2[1] * e2)
        h22 = k1[0] * e1 + k2[0] * e2 - phi
        det = h11 * h22 - h12 * h12
        if not (h11 > 0.0 and det > 0.0):
            # deep overlap (phi above a radius of curvature of the Minkowski body): H is
            # indefinite; descend with the SPD part W1 + W2 instead (uncertified, best phi kept)
            if not deep:
                deep = True
                maxit = max(maxit, deep_maxit)
            status = 0
            h11 += phi
            h22 += phi
            det = h11 * h22 - h12 * h12
        v1 = (h12 * g2 - h22 * g1) / det
        v2 = (h12 * g1 - h11 * g2) / det
        vn = np.sqrt(v1 * v1 + v2 * v2)
        converged = vn < NEWTON_TOL
        if vn > radius:
            sc = radius / vn
            v1 *= sc
            v2 *= sc
        # retraction n <- (n + T v) / |n + T v|
        nx = nx + v1 * t1x + v2 * t2x
        ny = ny + v1 * t1y + v2 * t2y
        nz = nz + v1 * t1z + v2 * t2z
        sc = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
        nx *= sc
        ny *= sc
        nz *= sc
        if converged:
            # the last step is below tolerance: take it (phi changes by O(|v|^2) < round-off)
            return nx, ny, nz, best, it, status
    return bx, by, bz, best, it, status


@njit(cache=True, inline="always")
def _write_out(out, depth, nx, ny, nz, p1x, p1y, p1z, p2x, p2y, p2z, re, kr, lam, pw_it, nw_it):
    """Fill the OUT_* layout; the contact point is the midpoint of p1 and p2."""
    out[OUT_DEPTH] = depth
    out[OUT_NX] = nx
    out[OUT_NY] = ny
    out[OUT_NZ] = nz
    out[OUT_P1X] = p1x
    out[OUT_P1Y] = p1y
    out[OUT_P1Z] = p1z
    out[OUT_P2X] = p2x
    out[OUT_P2Y] = p2y
    out[OUT_P2Z] = p2z
    out[OUT_XCX] = 0.5 * (p1x + p2x)
    out[OUT_XCY] = 0.5 * (p1y + p2y)
    out[OUT_XCZ] = 0.5 * (p1z + p2z)
    out[OUT_RE] = re
    out[OUT_KRATIO] = kr
    out[OUT_LAM] = lam
    out[OUT_PW_ITERS] = pw_it
    out[OUT_NEWTON_ITERS] = nw_it


@njit(cache=True, _nrt=False)
def _fill(c1, rot1, ax1, c2, rot2, ax2, nx, ny, nz, rx, ry, rz, lam, pw_it, nw_it, out):
    """Write depth, normal, contact points, R_e, kratio at the normal n; returns the depth."""
    h1, u0, u1, u2 = _hq(rot1, ax1, nx, ny, nz)
    h2, w0, w1, w2 = _hq(rot2, ax2, nx, ny, nz)
    depth = h1 + h2 - (nx * rx + ny * ry + nz * rz)
    if not (depth > 0.0):
        return 0.0
    t1x, t1y, t1z, t2x, t2y, t2z = _basis(nx, ny, nz)
    k1 = _curv(rot1, ax1, h1, t1x, t1y, t1z, t2x, t2y, t2z)
    k2 = _curv(rot2, ax2, h2, t1x, t1y, t1z, t2x, t2y, t2z)
    re, kr = _hertz_radius(k1[0] + k2[0], k1[1] + k2[1], k1[2] + k2[2])
    p1x = c1[0] + u0 / h1
    p1y = c1[1] + u1 / h1
    p1z = c1[2] + u2 / h1
    p2x = c2[0] - w0 / h2
    p2y = c2[1] - w1 / h2
    p2z = c2[2] - w2 / h2
    _write_out(out, depth, nx, ny, nz, p1x, p1y, p1z, p2x, p2y, p2z, re, kr, lam, pw_it, nw_it)
    return depth


@njit(cache=True, _nrt=False)
def _min_curv_radius(ax):
    """Smallest radius of curvature c^2 / a of an ellipsoid with semi-axes ax [3]."""
    amax = max(ax[0], max(ax[1], ax[2]))
    amin = min(ax[0], min(ax[1], ax[2]))
    return amin * amin / amax


@njit(cache=True, _nrt=False)
def pw_maximise(q1, q2, rx, ry, rz, lam):
    """Maximise F(lam) = lam (1 - lam) R^T G^-1 R, G = (1 - lam) Q1 + lam Q2, on [0, 1].

    Safeguarded Newton with a bisection bracket from the sign of F' (the stop test is on the raw
    Newton step, before safeguarding; reference §1.5), early exit when some F(lam) > 1. Shared by
    ellipsoid_contact and the PW-only method (dem/contact/methods.py). Returns (status, lam*, F,
    nu_x, nu_y, nu_z, iterations); status 0: separated (some F(lam) > 1 or F >= 1), 1: overlap;
    nu = G(lam*)^-1 R.
    """
    d00 = q2[0] - q1[0]
    d01 = q2[1] - q1[1]
    d02 = q2[2] - q1[2]
    d11 = q2[3] - q1[3]
    d12 = q2[4] - q1[4]
    d22 = q2[5] - q1[5]
    lo = 0.0
    hi = 1.0
    it = 0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    f = 0.0
    lam_out = lam
    while True:
        it += 1
        g00 = q1[0] + lam * d00
        g01 = q1[1] + lam * d01
        g02 = q1[2] + lam * d02
        g11 = q1[3] + lam * d11
        g12 = q1[4] + lam * d12
        g22 = q1[5] + lam * d22
        # G = L diag(e0, e1, e2) L^T (LDL^T; G is SPD): q = R^T G^-1 R = sum y_i^2 / e_i
        # is a sum of positive terms, far more accurate than the adjugate for 50:1 shapes
        i0 = 1.0 / g00
        l10 = g01 * i0
        l20 = g02 * i0
        i1 = 1.0 / (g11 - l10 * g01)
        l21 = (g12 - l20 * g01) * i1
        i2 = 1.0 / (g22 - l20 * g02 - l21 * (g12 - l20 * g01))
        y0 = rx
        y1 = ry - l10 * y0
        y2 = rz - l20 * y0 - l21 * y1
        q = y0 * y0 * i0 + y1 * y1 * i1 + y2 * y2 * i2
        sz = y2 * i2
        sy = y1 * i1 - l21 * sz
        sx = y0 * i0 - l10 * sy - l20 * sz
        wx = d00 * sx + d01 * sy + d02 * sz
        wy = d01 * sx + d11 * sy + d12 * sz
        wz = d02 * sx + d12 * sy + d22 * sz
        qp = -(sx * wx + sy * wy + sz * wz)
        y0 = wx
        y1 = wy - l10 * y0
        y2 = wz - l20 * y0 - l21 * y1
        qpp = 2.0 * (y0 * y0 * i0 + y1 * y1 * i1 + y2 * y2 * i2)
        l1 = lam * (1.0 - lam)
        l2 = 1.0 - 2.0 * lam
        f = l1 * q
        if f > 1.0:
            return 0, lam, f, sx, sy, sz, it
        fp = l2 * q + l1 * qp
        fpp = -2.0 * q + 2.0 * l2 * qp + l1 * qpp
        if fp > 0.0:
            lo = lam
        else:
            hi = lam
        lam_out = lam
        if fpp < 0.0:
            step = -fp / fpp
            if abs(step) < PW_TOL:
                lam_out = lam + step
                break
            lnew = lam + step
            if lnew <= lo or lnew >= hi:
                lnew = 0.5 * (lo + hi)
        else:
            lnew = 0.5 * (lo + hi)
        if it >= PW_MAXIT or hi - lo < PW_TOL:
            break
        lam = lnew
    if not (f < 1.0):
        return 0, lam_out, f, sx, sy, sz, it
    return 1, lam_out, f, sx, sy, sz, it


@njit(cache=True, _nrt=False)
def ellipsoid_contact(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out):
    """Exact contact of ellipsoids 1 and 2; returns 1 and fills out [OUT_LEN] on overlap, else 0.

    c1, c2 [3] centres; rot1, rot2 [3, 3] rotation matrices body -> world; ax1, ax2 [3]
    semi-axes along body x, y, z (a sphere is (r, r, r)).  lam0: previous PW lambda
    (outside (0, 1) for none); n0 [3]: previous normal (zeros for none).
    Output normal points from body 1 towards body 2; depth = minimum translation distance.
    """
    rx = c2[0] - c1[0]
    ry = c2[1] - c1[1]
    rz = c2[2] - c1[2]
    rn = np.sqrt(rx * rx + ry * ry + rz * rz)
    # 1. cheap exact reject along R-hat: |R| > h1(R^) + h2(R^)  <=>  |R|^2 > H1 + H2,
    #    with H_i = h_i(R) = |R| h_i(R^)  (R = 0, concentric, is never rejected)
    hh1 = _h(rot1, ax1, rx, ry, rz)
    hh2 = _h(rot2, ax2, rx, ry, rz)
    if rn * rn > hh1 + hh2:
        return 0

    # 2. warm start from the previous normal (certified, else fall through to PW)
    nn = n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]
    if nn > 0.0:
        sc = 1.0 / np.sqrt(nn)
        nx, ny, nz, phi, nit, status = _newton_s2(
            rot1, ax1, rot2, ax2, False, rx, ry, rz, rn, n0[0] * sc, n0[1] * sc, n0[2] * sc,
            NEWTON_WARM_MAXIT, NEWTON_WARM_MAXIT)
        if status < 0:
            return 0
        if status == 1 and phi > 0.0 and phi < _min_curv_radius(ax1) + _min_curv_radius(ax2):
            h1 = _h(rot1, ax1, nx, ny, nz)
            h2 = _h(rot2, ax2, nx, ny, nz)
            lam = h1 / (h1 + h2)
            if _fill(c1, rot1, ax1, c2, rot2, ax2, nx, ny, nz, rx, ry, rz,
                     lam, 0, nit, out) > 0.0:
                return 1
            return 0

    q1 = _shape_matrix(rot1, ax1)
    q2 = _shape_matrix(rot2, ax2)
    # 3. Perram-Wertheim: maximise F(lam) on [0, 1]
    if lam0 > 0.0 and lam0 < 1.0:
        lam = lam0
    elif hh1 + hh2 > 0.0:
        lam = hh1 / (hh1 + hh2)
    else:
        lam = 0.5
    status, lam_out, f, sx, sy, sz, pw_it = pw_maximise(q1, q2, rx, ry, rz, lam)
    if status == 0:
        return 0

    # 4. PW normal n0 = G^-1 R, then Newton on S^2 for phi
    ss = sx * sx + sy * sy + sz * sz
    if ss > 0.0:
        s = 1.0 / np.sqrt(ss)
        nx = sx * s
        ny = sy * s
        nz = sz * s
    else:
        # concentric bodies: start along body 1's shortest axis
        k = 0
        if ax1[1] < ax1[k]:
            k = 1
        if ax1[2] < ax1[k]:
            k = 2
        nx = rot1[0, k]
        ny = rot1[1, k]
        nz = rot1[2, k]
    nx, ny, nz, phi, nit, status = _newton_s2(
        rot1, ax1, rot2, ax2, False, rx, ry, rz, rn, nx, ny, nz, NEWTON_MAXIT, NEWTON_DEEP_MAXIT)
    if status < 0 or not (phi > 0.0):
        return 0
    if _fill(c1, rot1, ax1, c2, rot2, ax2, nx, ny, nz, rx, ry, rz,
             lam_out, pw_it, nit, out) > 0.0:
        return 1
    return 0


@njit(cache=True, _nrt=False)
def ellipsoid_wall_contact(c, rot, ax, m, d, out):
    """Contact of an ellipsoid with the planar wall m.x = d (unit m points into the particle region).

    delta = h(m) - (m.c - d) (reference §1.4); on contact (delta > 0) returns 1 and fills out:
    n = -m (particle -> wall), p1 = s(-m) deepest particle point, p2 = p1 + delta m (its
    projection onto the plane), R_e and kratio from the particle's curvature tensor at p1
    (the wall is flat), lam = 0, iterations 0.  Returns 0 otherwise.
    """
    mx = m[0]
    my = m[1]
    mz = m[2]
    h, u0, u1, u2 = _hq(rot, ax, mx, my, mz)
    depth = h - (mx * c[0] + my * c[1] + mz * c[2] - d)
    if not (depth > 0.0):
        return 0
    t1x, t1y, t1z, t2x, t2y, t2z = _basis(mx, my, mz)
    k = _curv(rot, ax, h, t1x, t1y, t1z, t2x, t2y, t2z)
    re, kr = _hertz_radius(k[0], k[1], k[2])
    p1x = c[0] - u0 / h
    p1y = c[1] - u1 / h
    p1z = c[2] - u2 / h
    p2x = p1x + depth * mx
    p2y = p1y + depth * my
    p2z = p1z + depth * mz
    _write_out(out, depth, -mx, -my, -mz, p1x, p1y, p1z, p2x, p2y, p2z, re, kr, 0.0, 0.0, 0.0)
    return 1


@njit(cache=True, inline="always")
def solved_geometry(out):
    """The contact record dem.forces contact_law takes, of a contact a solver wrote to out [OUT_LEN]
    (the normal is a unit vector: u = n, iu2 = 1): (depth [m], n [3], u [3], iu2, x_c [3] [m],
    R_e [m], kappa ratio, PW lambda)."""
    nx, ny, nz = out[OUT_NX], out[OUT_NY], out[OUT_NZ]
    return (out[OUT_DEPTH], nx, ny, nz, nx, ny, nz, 1.0, out[OUT_XCX], out[OUT_XCY], out[OUT_XCZ], out[OUT_RE],
            out[OUT_KRATIO], out[OUT_LAM])
