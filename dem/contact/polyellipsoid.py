"""Poly-ellipsoid contact geometry and mass properties (scalar @njit kernels).

A poly-ellipsoid (Peters et al. 2009) is eight octant ellipsoids joined on the principal planes of
its body frame: semi-axes axes6 = [a+, a-, b+, b-, c+, c-]; its reference point o is the octant
origin (DESIGN.md: a poly-ellipsoid's `pos` is the octant origin, not the mass centre); rot is
body -> world.  Method (reference notes contact-mechanics.md §1.4-1.6, §2.2):

* Support function: with n_b = R^T n and alpha = alpha(sign n_b) (component >= 0 -> "+"),
  h_P(n) = |alpha o n_b|, s_P(n) = o + R (alpha^2 o n_b) / h_P(n).  The body is convex, C^1.
* Penetration depth PD = min_{|n|=1} phi(n), phi(n) = h_1(n) + h_2(-n) - n.R, R = o2 - o1.
  Any phi(n) < 0 certifies separation (n is a separating axis).
* Octant active set: from a guess n (warm start, else the direction between the centroids),
  body 1 uses the octant of R1^T n, body 2 that of R2^T (-n); the two full octant ellipsoids
  (centred at the octant origins) are solved with ellipsoid.ellipsoid_contact.  If its normal n'
  keeps both sign patterns (components with |n_b,k| <= OCT_PLANE_TOL count as either side: h_P is
  C^1 there and the mismatch is O(tol^2)), n' is a stationary point of phi: done.  Otherwise
  n <- n' (passed as warm start) and the octants switch; at most MAX_SWITCHES switches.
* Fallback (octant ellipsoids reported apart, switch cap reached): a trust-region Newton on S^2
  directly on phi_P (octant axes re-chosen at each evaluation; the same scheme as the
  ellipsoid's sphere-Newton) from the best normal seen.  It certifies separation by phi < 0.
* Overlap certificate for the reported contact (no false contacts at a gap):
  (o) the active-set answer: the octant ellipsoids' overlap is certified by PW (or by the
      ellipsoid's certified warm start) and n' is a local minimum of phi_P with phi_P = phi_E > 0
      (a separated pair has no such point within the rolling-ball radius, (a); beyond it, deep
      overlap, this is the ellipsoid kernel's own acceptance rule);
  (a) a stationary normal with 0 < phi < rho1 + rho2, rho_i = a_min,i^2 / a_max,i over the six
      semi-axes (a lower bound of every octant's smallest curvature radius): Blaschke's rolling
      ball theorem (as in ellipsoid.py) puts R inside the Minkowski body, and phi is the global PD;
  (b) otherwise (fallback answers in deep overlap, outside the DEM regime) a witness point strictly inside both
      bodies: p1 inside body 2, p2 inside body 1 or the midpoint x_c inside both; the depth is then
      phi at the best normal (an upper bound of PD, equal to it at a stationary point).
* Hertz curvature: the active octant ellipsoid's curvature tensor at each support point
  (discontinuous across the octant planes: R_e jumps there, reference §2.2 last bullet).

Output: the OUT_* layout of ellipsoid.py (depth, normal 1 -> 2, p1, p2, x_c, R_e, kratio, lam,
PW and Newton iteration counts summed over the octant solves); if `out` is longer than OUT_LEN,
out[OUT_SWITCHES] receives the number of octant switches (POLY_OUT_LEN = OUT_LEN + 1).
The caller's `out` doubles as the scratch buffer of the inner ellipsoid solves: the kernels are
allocation free (octant semi-axes and warm-start normals are passed as tuples).
Plain float64, no fastmath; results are a pure function of the inputs.
"""
import itertools

import numpy as np
from numba import njit

from dem.contact.ellipsoid import (
    OUT_NX, OUT_NY, OUT_NZ, OUT_LAM, OUT_PW_ITERS, OUT_NEWTON_ITERS,
    OUT_LEN, NEWTON_DEEP_MAXIT,
    ellipsoid_contact, ellipsoid_wall_contact, _basis, _curv, _hertz_radius, _newton_s2, _oct_axes, _write_out,
    _hq)

__all__ = ["mass_properties_poly", "poly_support", "polyellipsoid_contact",
           "polyellipsoid_wall_contact", "new_out", "OUT_SWITCHES", "POLY_OUT_LEN",
           "MAX_SWITCHES", "OCT_PLANE_TOL"]

OUT_SWITCHES = OUT_LEN      # octant switches (written only when len(out) > OUT_LEN)
POLY_OUT_LEN = OUT_LEN + 1
MAX_SWITCHES = 8            # octant switches before the direct phi_P Newton fallback
OCT_PLANE_TOL = 1e-9        # |n_b,k| below which a normal counts as on an octant plane
POLY_NEWTON_MAXIT = 12      # phi_P evaluations of the fallback Newton (raised when deep)


def new_out():
    """A fresh output buffer [POLY_OUT_LEN] (set-up helper; kernels never allocate)."""
    return np.zeros(POLY_OUT_LEN)


# ------------------------------------------------------------------ mass properties (numpy)

def mass_properties_poly(axes6, density):
    """Mass, centroid (shape frame, relative to the octant origin), principal moments and axes.

    axes6 = [a+, a-, b+, b-, c+, c-]; reference §2.2:
      V = (pi/6)(a+ + a-)(b+ + b-)(c+ + c-),  centroid = (3/8)(a+ - a-, b+ - b-, c+ - c-),
      S_xx = int x^2 dV = (pi/30)(a+^3 + a-^3)(b+ + b-)(c+ + c-)  (cyclic),
      S_xy = int xy dV = (1/15)(a+^2 - a-^2)(b+^2 - b-^2)(c+ + c-)  (cyclic),
      I_c = rho[(tr S) 1 - S] - m(|c|^2 1 - c c^T)  (about the centroid, shape frame).
    Returns (mass, centroid [3], inertia_principal [3], principal_rot [3, 3]) with
    I_c = principal_rot diag(inertia_principal) principal_rot^T; the columns of principal_rot are
    the principal axes in the shape frame, ordered to match the shape axes as closely as possible
    (the column permutation maximising |prod diag|; ties: first in lexicographic order), signs with
    a non-negative diagonal, right-handed (det = +1; if needed the column with the smallest
    |diagonal| is flipped).  For an ordinary ellipsoid/sphere principal_rot = identity.
    """
    ap, am, bp, bm, cp, cm = (float(v) for v in axes6)
    rho = float(density)
    sa, sb, sc = ap + am, bp + bm, cp + cm
    vol = np.pi / 6.0 * sa * sb * sc
    mass = rho * vol
    cen = 0.375 * np.array([ap - am, bp - bm, cp - cm])
    s = np.empty((3, 3))
    s[0, 0] = np.pi / 30.0 * (ap ** 3 + am ** 3) * sb * sc
    s[1, 1] = np.pi / 30.0 * (bp ** 3 + bm ** 3) * sa * sc
    s[2, 2] = np.pi / 30.0 * (cp ** 3 + cm ** 3) * sa * sb
    s[0, 1] = s[1, 0] = (ap * ap - am * am) * (bp * bp - bm * bm) * sc / 15.0
    s[0, 2] = s[2, 0] = (ap * ap - am * am) * (cp * cp - cm * cm) * sb / 15.0
    s[1, 2] = s[2, 1] = (bp * bp - bm * bm) * (cp * cp - cm * cm) * sa / 15.0
    inertia = rho * (np.trace(s) * np.eye(3) - s) - mass * (cen @ cen * np.eye(3) - np.outer(cen, cen))
    inertia = 0.5 * (inertia + inertia.T)
    off = abs(inertia[0, 1]) + abs(inertia[0, 2]) + abs(inertia[1, 2])
    if off == 0.0:
        return mass, cen, np.diag(inertia).copy(), np.eye(3)
    w, v = np.linalg.eigh(inertia)
    best = None
    for perm in itertools.permutations(range(3)):
        score = abs(v[0, perm[0]] * v[1, perm[1]] * v[2, perm[2]])
        if best is None or score > best[0] * (1.0 + 1e-12):
            best = (score, perm)
    perm = list(best[1])
    w = w[perm]
    v = v[:, perm].copy()
    for k in range(3):
        if v[k, k] < 0.0:
            v[:, k] = -v[:, k]
    if np.linalg.det(v) < 0.0:
        k = int(np.argmin(np.abs(np.diag(v))))
        v[:, k] = -v[:, k]
    return mass, cen, w, v + 0.0          # + 0.0: no signed zeros


# ------------------------------------------------------------------ support function

@njit(cache=True, _nrt=False)
def poly_support(o, rot, axes6, nx, ny, nz):
    """Support function and support point of a poly-ellipsoid in direction n (world frame).

    Returns (h, sx, sy, sz): h = |alpha o R^T n| (h(n) = max_{x in P} n.(x - o)), s = o + R
    (alpha^2 o R^T n) / h (reference §2.2).  n need not be unit (h is 1-homogeneous).
    """
    ax = _oct_axes(rot, axes6, nx, ny, nz)
    h, u0, u1, u2 = _hq(rot, ax, nx, ny, nz)
    return h, o[0] + u0 / h, o[1] + u1 / h, o[2] + u2 / h


@njit(cache=True, _nrt=False)
def _phi(rot1, a1, rot2, a2, rx, ry, rz, nx, ny, nz):
    """phi_P(n) = h1(n) + h2(-n) - n.R."""
    ax1 = _oct_axes(rot1, a1, nx, ny, nz)
    ax2 = _oct_axes(rot2, a2, -nx, -ny, -nz)
    h1, u0, u1, u2 = _hq(rot1, ax1, nx, ny, nz)
    h2, w0, w1, w2 = _hq(rot2, ax2, nx, ny, nz)
    return h1 + h2 - (nx * rx + ny * ry + nz * rz)


@njit(cache=True, _nrt=False)
def _consistent(rot, ax, a6, nx, ny, nz):
    """Does the octant with semi-axes ax contain the normal n (within OCT_PLANE_TOL)?"""
    m0 = rot[0, 0] * nx + rot[1, 0] * ny + rot[2, 0] * nz
    m1 = rot[0, 1] * nx + rot[1, 1] * ny + rot[2, 1] * nz
    m2 = rot[0, 2] * nx + rot[1, 2] * ny + rot[2, 2] * nz
    ok = True
    if abs(m0) > OCT_PLANE_TOL and (a6[0] if m0 > 0.0 else a6[1]) != ax[0]:
        ok = False
    if abs(m1) > OCT_PLANE_TOL and (a6[2] if m1 > 0.0 else a6[3]) != ax[1]:
        ok = False
    if abs(m2) > OCT_PLANE_TOL and (a6[4] if m2 > 0.0 else a6[5]) != ax[2]:
        ok = False
    return ok


@njit(cache=True, _nrt=False)
def _inside(o, rot, a6, x, y, z):
    """Implicit function sum_k (x_b,k / alpha_k)^2 of the poly-ellipsoid at world point (x, y, z)."""
    dx = x - o[0]
    dy = y - o[1]
    dz = z - o[2]
    m0 = rot[0, 0] * dx + rot[1, 0] * dy + rot[2, 0] * dz
    m1 = rot[0, 1] * dx + rot[1, 1] * dy + rot[2, 1] * dz
    m2 = rot[0, 2] * dx + rot[1, 2] * dy + rot[2, 2] * dz
    m0 /= a6[0] if m0 >= 0.0 else a6[1]
    m1 /= a6[2] if m1 >= 0.0 else a6[3]
    m2 /= a6[4] if m2 >= 0.0 else a6[5]
    return m0 * m0 + m1 * m1 + m2 * m2


@njit(cache=True, _nrt=False)
def _min_curv_radius6(a6):
    """Lower bound a_min^2 / a_max of every octant ellipsoid's smallest curvature radius."""
    amin = a6[0]
    amax = a6[0]
    for k in range(1, 6):
        amin = min(amin, a6[k])
        amax = max(amax, a6[k])
    return amin * amin / amax


# ------------------------------------------------------------------ direct Newton on phi_P

# ------------------------------------------------------------------ pair contact

@njit(cache=True, _nrt=False)
def polyellipsoid_contact(o1, rot1, ax6_1, o2, rot2, ax6_2, n0, out):
    """Exact contact of poly-ellipsoids 1 and 2; returns 1 and fills out on overlap, else 0.

    o1, o2 [3] octant origins; rot1, rot2 [3, 3] body -> world; ax6_i [6] = [a+, a-, b+, b-,
    c+, c-]; n0 [3] previous normal (zeros for none).  out [>= OUT_LEN] (OUT_* layout of
    ellipsoid.py; out[OUT_SWITCHES] too when long enough).  Normal points from body 1 to body 2;
    depth = minimum translation distance.  out is also used as scratch (its content on return 0
    is unspecified).
    """
    rx = o2[0] - o1[0]
    ry = o2[1] - o1[1]
    rz = o2[2] - o1[2]
    rn = np.sqrt(rx * rx + ry * ry + rz * rz)
    # direction between the centroids: R + rot2 cb2 - rot1 cb1, cb = (3/8)(a+ - a-, ...)
    b0 = 0.375 * (ax6_2[0] - ax6_2[1])
    b1 = 0.375 * (ax6_2[2] - ax6_2[3])
    b2 = 0.375 * (ax6_2[4] - ax6_2[5])
    e0 = 0.375 * (ax6_1[0] - ax6_1[1])
    e1 = 0.375 * (ax6_1[2] - ax6_1[3])
    e2 = 0.375 * (ax6_1[4] - ax6_1[5])
    dx = rx + rot2[0, 0] * b0 + rot2[0, 1] * b1 + rot2[0, 2] * b2 \
        - (rot1[0, 0] * e0 + rot1[0, 1] * e1 + rot1[0, 2] * e2)
    dy = ry + rot2[1, 0] * b0 + rot2[1, 1] * b1 + rot2[1, 2] * b2 \
        - (rot1[1, 0] * e0 + rot1[1, 1] * e1 + rot1[1, 2] * e2)
    dz = rz + rot2[2, 0] * b0 + rot2[2, 1] * b1 + rot2[2, 2] * b2 \
        - (rot1[2, 0] * e0 + rot1[2, 1] * e1 + rot1[2, 2] * e2)
    dn = np.sqrt(dx * dx + dy * dy + dz * dz)
    # 1. cheap exact rejects: phi_P < 0 along the centroid direction or along R
    if dn > 0.0:
        dx /= dn
        dy /= dn
        dz /= dn
        if _phi(rot1, ax6_1, rot2, ax6_2, rx, ry, rz, dx, dy, dz) < 0.0:
            return 0
    if rn > 0.0:
        if _phi(rot1, ax6_1, rot2, ax6_2, rx, ry, rz, rx / rn, ry / rn, rz / rn) < 0.0:
            return 0
    # 2. starting normal
    nn = n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]
    warm = nn > 0.0
    if warm:
        sc = 1.0 / np.sqrt(nn)
        nx = n0[0] * sc
        ny = n0[1] * sc
        nz = n0[2] * sc
    elif dn > 0.0:
        nx, ny, nz = dx, dy, dz
    elif rn > 0.0:
        nx, ny, nz = rx / rn, ry / rn, rz / rn
    else:
        nx, ny, nz = rot1[0, 0], rot1[1, 0], rot1[2, 0]
    # 3. octant active set with the ellipsoid solver
    best = np.inf
    bx, by, bz = nx, ny, nz
    lam = -1.0
    pw_tot = 0.0
    nw_tot = 0.0
    switches = 0
    stationary = False
    from_pw = False
    while True:
        ax1 = _oct_axes(rot1, ax6_1, nx, ny, nz)
        ax2 = _oct_axes(rot2, ax6_2, -nx, -ny, -nz)
        if warm:
            wn = (nx, ny, nz)
        else:
            wn = (0.0, 0.0, 0.0)
        r = ellipsoid_contact(o1, rot1, ax1, o2, rot2, ax2, lam, wn, out)
        if r == 0:
            break                       # octant ellipsoids apart: no information, fall back
        pw_tot += out[OUT_PW_ITERS]
        nw_tot += out[OUT_NEWTON_ITERS]
        lam = out[OUT_LAM]
        mx = out[OUT_NX]
        my = out[OUT_NY]
        mz = out[OUT_NZ]
        phi = _phi(rot1, ax6_1, rot2, ax6_2, rx, ry, rz, mx, my, mz)
        if phi < 0.0:
            return 0                    # separating axis of the poly-ellipsoids
        if phi < best:
            best = phi
            bx, by, bz = mx, my, mz
        if (_consistent(rot1, ax1, ax6_1, mx, my, mz)
                and _consistent(rot2, ax2, ax6_2, -mx, -my, -mz)):
            stationary = True
            from_pw = True
            bx, by, bz = mx, my, mz
            best = phi
            break
        if switches >= MAX_SWITCHES:
            break
        switches += 1
        nx, ny, nz = mx, my, mz
        warm = True
    if not stationary:
        # 4. fallback: Newton directly on phi_P from the best normal seen
        if best < np.inf:
            nx, ny, nz = bx, by, bz
        nx, ny, nz, phi, nit, status = _newton_s2(
            rot1, ax6_1, rot2, ax6_2, True, rx, ry, rz, rn, nx, ny, nz,
            POLY_NEWTON_MAXIT, max(POLY_NEWTON_MAXIT, NEWTON_DEEP_MAXIT))
        nw_tot += nit
        if status < 0:
            return 0
        if phi < best:
            best = phi
            bx, by, bz = nx, ny, nz
            stationary = status == 1
        if not (best < np.inf):
            return 0
    # 5. outputs at the best normal, with the overlap certificate
    nx, ny, nz = bx, by, bz
    ax1 = _oct_axes(rot1, ax6_1, nx, ny, nz)
    ax2 = _oct_axes(rot2, ax6_2, -nx, -ny, -nz)
    h1, u0, u1, u2 = _hq(rot1, ax1, nx, ny, nz)
    h2, w0, w1, w2 = _hq(rot2, ax2, nx, ny, nz)
    depth = h1 + h2 - (nx * rx + ny * ry + nz * rz)
    if not (depth > 0.0):
        return 0
    p1x = o1[0] + u0 / h1
    p1y = o1[1] + u1 / h1
    p1z = o1[2] + u2 / h1
    p2x = o2[0] - w0 / h2
    p2y = o2[1] - w1 / h2
    p2z = o2[2] - w2 / h2
    certified = from_pw or (stationary and
                            depth < _min_curv_radius6(ax6_1) + _min_curv_radius6(ax6_2))
    if not certified:
        xx = 0.5 * (p1x + p2x)
        xy = 0.5 * (p1y + p2y)
        xz = 0.5 * (p1z + p2z)
        if not ((_inside(o1, rot1, ax6_1, xx, xy, xz) < 1.0
                 and _inside(o2, rot2, ax6_2, xx, xy, xz) < 1.0)
                or _inside(o2, rot2, ax6_2, p1x, p1y, p1z) < 1.0
                or _inside(o1, rot1, ax6_1, p2x, p2y, p2z) < 1.0):
            return 0
    t1x, t1y, t1z, t2x, t2y, t2z = _basis(nx, ny, nz)
    k1 = _curv(rot1, ax1, h1, t1x, t1y, t1z, t2x, t2y, t2z)
    k2 = _curv(rot2, ax2, h2, t1x, t1y, t1z, t2x, t2y, t2z)
    re, kr = _hertz_radius(k1[0] + k2[0], k1[1] + k2[1], k1[2] + k2[2])
    _write_out(out, depth, nx, ny, nz, p1x, p1y, p1z, p2x, p2y, p2z, re, kr, lam, pw_tot, nw_tot)
    if out.shape[0] > OUT_SWITCHES:
        out[OUT_SWITCHES] = switches
    return 1


# ------------------------------------------------------------------ wall contact

@njit(cache=True, _nrt=False)
def polyellipsoid_wall_contact(o, rot, axes6, m, d, out):
    """Contact of a poly-ellipsoid with the wall m.x = d (unit m points into the particle region).

    delta = h_P(-m) - (m.o - d) (reference §2.2): the ellipsoid's wall contact
    (dem.contact.ellipsoid.ellipsoid_wall_contact) of the octant ellipsoid that faces the wall,
    the octant of R^T(-m), about the octant origin o. On contact returns 1 and fills out as that
    does (n = -m, p1 = s_P(-m), p2 on the plane, R_e and kratio from the octant ellipsoid's
    curvature at p1, lam = 0, iterations 0), and switches 0 when out is long enough. Returns 0
    otherwise.
    """
    hit = ellipsoid_wall_contact(o, rot, _oct_axes(rot, axes6, -m[0], -m[1], -m[2]), m, d, out)
    if hit and out.shape[0] > OUT_SWITCHES:
        out[OUT_SWITCHES] = 0.0
    return hit
