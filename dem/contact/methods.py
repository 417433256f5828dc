"""Alternative ellipsoid-ellipsoid contact methods (same signature and OUT_* layout as
dem.contact.ellipsoid.ellipsoid_contact, so that a caller can select them by name
``exact | pw | sextic``; see METHODS).

Reference notes: docs/contact-mechanics.md (§1.2, §1.3, §1.5, §1.6).

pw_contact (@njit, allocation free)
    Perram-Wertheim (1985) / Donev et al. (2005) only, no refinement on S^2.  Overlap test
    F = max_lam lam (1 - lam) R^T G(lam)^-1 R < 1 (same safeguarded Newton as ellipsoid.py),
    normal n = G(lam*)^-1 R / |.|, depth the woo formula delta = |R| (1/mu - 1) (R^.n),
    mu = sqrt(F) (woo Cg2_Ellipsoid_Ellipsoid_L6Geom).  Contact points p1 = s1(n), p2 = s2(-n)
    (support points; p1 - p2 is not exactly delta n), x_c their midpoint; R_e and kratio from
    K1 + K2 at +-n as in ellipsoid.py.  Known error (reference §1.3, "Measured"): relative depth
    error <= ~2 delta/a_min, normal error <= ~4 delta/a_min rad, i.e. O(delta/a).

sextic_contact (@njit, callable from other kernels; allocates small temporaries.  The sextic's roots
come from dem.contact.roots.poly_roots, a numba port of NR balanc + hqr: numba's np.linalg would
need SciPy's LAPACK at run time, which the project does not depend on)
    Yan, Regueiro & Sture (2010), Eng. Comput. 27(4):519, as coded in ParaEllip3d (root6.cpp /
    zrhqr).  Each body is the quadric f_i(x) = x^T A_i x + b_i^T x + c_i (10 coefficients,
    x^2 coefficient normalised to 1, f_i < 0 inside).  The point of body 2 "deepest in body 1"
    minimises f_1 on f_2 = 0: x(lam) = -1/2 adj M (b_1 + lam b_2) / det M, M = A_1 + lam A_2, and
    lam is a root of the sextic p(lam) = N^T A_2 N + (b_2^T N) det M + c_2 det M^2,
    N = -1/2 adj M (b_1 + lam b_2).  Roots: eigenvalues of the 6x6 companion matrix by balancing
    + Hessenberg QR (NR balanc/hqr/zrhqr, as ParaEllip3d; dem.contact.roots); a QR failure
    (30 iterations without deflation) counts as no contact.  Selection (root6): real roots
    (|Im lam| < EPS), det M != 0, |f_2(x)| < EPS_F, the most negative f_1(x).  Both directions
    give point2 (of 2, deepest in 1) and point1 (of 1, deepest in 2); delta = |point1 - point2|,
    n = (point1 - point2) / delta (from body 1 to body 2), x_c the midpoint.  Accepted only if
    both solves succeed, each point lies inside the other body (f < 0; the "two-sided" test:
    root6 also returns a point for separated bodies) and delta / (2 max a_i) > MINOVERLAP.
    Contact radius (ParaEllip3d getRadius): r_i = 2 r' r'' / (r' + r'') = 2 / (kappa' + kappa'')
    the mean-curvature radius of body i at its point, R_e = r_1 r_2 / (r_1 + r_2); kratio = 1
    (the paper's contact is circular).  Not reproduced: MAXOVERLAP capping of delta.
    Scale normalisation (the code's EPS = 1e-12 is absolute in metres): the quadrics are built
    in world axes, but in coordinates x' = (x - o) / L with o = (c1 + c2)/2 and L = the largest
    semi-axis of the pair; EPS applies to those dimensionless quantities (see SEXTIC_EPS_*).
    Known error (reference §1.2 table): definitional, independent of delta: median
    |delta/PD - 1| ~ 2-3 % for 1:0.8:0.6, 10-30 % for needles, 30-70 % for disks; normal errors of
    degrees to tens of degrees.  Exact only for spheres.  A negative control, not a production
    method.
"""
import numpy as np
from numba import njit

from dem.contact import CONTACT_METHODS
from dem.contact.ellipsoid import (_basis, _curv, _h, _hertz_radius,
                                   _hq, _shape_matrix, _write_out, ellipsoid_contact, pw_maximise)
from dem.contact.roots import poly_roots

# ---- sextic (Yan 2010 / ParaEllip3d parameter.cpp), scale-normalised ----
MINOVERLAP = 1e-6        # delta / (2 max semi-axis) must exceed this (relative, as in the code)
SEXTIC_EPS_IM = 1e-12    # |Im lam| < EPS: real root (lam is dimensionless here)
SEXTIC_EPS_F = 1e-12     # |f_other(x)| < EPS: x on the other surface (f dimensionless, x'^2 coef 1)
SEXTIC_EPS_DET = 1e-12   # |det M(lam)| > EPS * |det A_1| : M invertible


# ================================================================ Perram-Wertheim only
@njit(cache=True, _nrt=False)
def pw_contact(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out):
    """Perram-Wertheim-only contact; returns 1 and fills out [OUT_LEN] on overlap, else 0.

    Same arguments as ellipsoid_contact (n0 is accepted and ignored; lam0 in (0, 1) warm-starts
    the PW maximisation).  depth = |R| (1/mu - 1) (R^.n) (woo), n = G(lam*)^-1 R / |.|,
    p1 = s1(n), p2 = s2(-n), OUT_NEWTON_ITERS = 0.  Error O(delta/a) (module docstring).
    """
    rx = c2[0] - c1[0]
    ry = c2[1] - c1[1]
    rz = c2[2] - c1[2]
    rn = np.sqrt(rx * rx + ry * ry + rz * rz)
    hh1 = _h(rot1, ax1, rx, ry, rz)
    hh2 = _h(rot2, ax2, rx, ry, rz)
    if rn * rn > hh1 + hh2:
        return 0                    # exact reject along R^ (as ellipsoid.py)
    q1 = _shape_matrix(rot1, ax1)
    q2 = _shape_matrix(rot2, ax2)
    if lam0 > 0.0 and lam0 < 1.0:
        lam = lam0
    elif hh1 + hh2 > 0.0:
        lam = hh1 / (hh1 + hh2)
    else:
        lam = 0.5
    status, lam, f, sx, sy, sz, it = pw_maximise(q1, q2, rx, ry, rz, lam)
    if status == 0:
        return 0
    ss = sx * sx + sy * sy + sz * sz
    if ss > 0.0 and f > 0.0:
        s = 1.0 / np.sqrt(ss)
        nx = sx * s
        ny = sy * s
        nz = sz * s
        mu = np.sqrt(f)
        depth = (1.0 / mu - 1.0) * (rx * nx + ry * ny + rz * nz)    # |R| (1/mu - 1) (R^.n)
    else:
        # concentric: body 1's shortest axis, depth phi(n) (woo's formula is undefined)
        k = 0
        if ax1[1] < ax1[k]:
            k = 1
        if ax1[2] < ax1[k]:
            k = 2
        nx = rot1[0, k]
        ny = rot1[1, k]
        nz = rot1[2, k]
        depth = _h(rot1, ax1, nx, ny, nz) + _h(rot2, ax2, nx, ny, nz)
    if not (depth > 0.0):
        return 0
    h1, u0, u1, u2 = _hq(rot1, ax1, nx, ny, nz)
    h2, w0, w1, w2 = _hq(rot2, ax2, nx, ny, nz)
    t1x, t1y, t1z, t2x, t2y, t2z = _basis(nx, ny, nz)
    k1 = _curv(rot1, ax1, h1, t1x, t1y, t1z, t2x, t2y, t2z)
    k2 = _curv(rot2, ax2, h2, t1x, t1y, t1z, t2x, t2y, t2z)
    re, kr = _hertz_radius(k1[0] + k2[0], k1[1] + k2[1], k1[2] + k2[2])
    _write_out(out, depth, nx, ny, nz,
               c1[0] + u0 / h1, c1[1] + u1 / h1, c1[2] + u2 / h1,
               c2[0] - w0 / h2, c2[1] - w1 / h2, c2[2] - w2 / h2,
               re, kr, lam, it, 0)
    return 1


# ================================================================ Yan (2010) sextic
@njit(cache=True)
def _quadric(c, rot, ax, o, L):
    """Quadric (A [3,3], b [3], c0) of the ellipsoid in x' = (x - o)/L, x'^2 coefficient 1.

    f(x') = (x' - c')^T A' (x' - c') - 1 expanded into monomials, A' = R diag((L/a)^2) R^T,
    then divided by A'_00 (ParaEllip3d stores the 10 coefficients normalised that way).
    """
    A = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += rot[i, k] * rot[j, k] * (L / ax[k]) ** 2
            A[i, j] = s
    cc = np.empty(3)
    for i in range(3):
        cc[i] = (c[i] - o[i]) / L
    b = np.empty(3)
    c0 = -1.0
    for i in range(3):
        s = 0.0
        for j in range(3):
            s += A[i, j] * cc[j]
        b[i] = -2.0 * s
        c0 += cc[i] * s
    sc = 1.0 / A[0, 0]
    return A * sc, b * sc, c0 * sc


@njit(cache=True)
def _pmul(p, q):
    r = np.zeros(p.shape[0] + q.shape[0] - 1)
    for i in range(p.shape[0]):
        for j in range(q.shape[0]):
            r[i + j] += p[i] * q[j]
    return r


@njit(cache=True)
def _padd(p, q):
    n = max(p.shape[0], q.shape[0])
    r = np.zeros(n)
    r[:p.shape[0]] += p
    r[:q.shape[0]] += q
    return r


@njit(cache=True)
def _sextic_coeffs(A1, b1, A2, b2, c2):
    """Coefficients (ascending powers, length 7) of p(lam) = N^T A2 N + (b2.N) det M + c2 det^2,
    M = A1 + lam A2, N = -1/2 adj M (b1 + lam b2), built by polynomial arithmetic."""
    M = np.empty((3, 3, 2))
    for i in range(3):
        for j in range(3):
            M[i, j, 0] = A1[i, j]
            M[i, j, 1] = A2[i, j]
    adj = np.empty((3, 3, 3))         # adj[i, j] = cofactor C[j, i] (quadratic in lam)
    for i in range(3):
        for j in range(3):
            r0 = (j + 1) % 3
            r1 = (j + 2) % 3
            s0 = (i + 1) % 3
            s1 = (i + 2) % 3
            # cyclic cofactor: C[j, i] = M[r0,s0] M[r1,s1] - M[r0,s1] M[r1,s0]
            adj[i, j] = _pmul(M[r0, s0], M[r1, s1]) - _pmul(M[r0, s1], M[r1, s0])
    det = np.zeros(4)
    for j in range(3):
        det = _padd(det, _pmul(M[0, j], adj[j, 0]))
    v = np.empty((3, 2))
    for i in range(3):
        v[i, 0] = b1[i]
        v[i, 1] = b2[i]
    N = np.zeros((3, 4))
    for i in range(3):
        for j in range(3):
            N[i] += -0.5 * _pmul(adj[i, j], v[j])
    p = c2 * _pmul(det, det)
    bn = np.zeros(4)
    for i in range(3):
        bn += b2[i] * N[i]
    p = p + _pmul(bn, det)
    for i in range(3):
        for j in range(3):
            p = p + A2[i, j] * _pmul(N[i], N[j])
    return p


@njit(cache=True)
def _qeval(A, b, c0, x0, x1, x2):
    return (A[0, 0] * x0 * x0 + A[1, 1] * x1 * x1 + A[2, 2] * x2 * x2
            + 2.0 * (A[0, 1] * x0 * x1 + A[0, 2] * x0 * x2 + A[1, 2] * x1 * x2)
            + b[0] * x0 + b[1] * x1 + b[2] * x2 + c0)


@njit(cache=True)
def _select(re, im, A1, b1, c1, A2, b2, c2):
    """root6 selection: among real roots with det M != 0 and |f2(x)| < EPS_F, the x with the most
    negative f1(x).  Returns (ok, x0, x1, x2, f1, lam)."""
    ok = 0
    best = np.inf
    bx0 = 0.0
    bx1 = 0.0
    bx2 = 0.0
    blam = 0.0
    d1 = (A1[0, 0] * (A1[1, 1] * A1[2, 2] - A1[1, 2] * A1[2, 1])
          - A1[0, 1] * (A1[1, 0] * A1[2, 2] - A1[1, 2] * A1[2, 0])
          + A1[0, 2] * (A1[1, 0] * A1[2, 1] - A1[1, 1] * A1[2, 0]))
    for k in range(re.shape[0]):
        if not (abs(im[k]) < SEXTIC_EPS_IM):
            continue
        lam = re[k]
        m = A1 + lam * A2
        v0 = b1[0] + lam * b2[0]
        v1 = b1[1] + lam * b2[1]
        v2 = b1[2] + lam * b2[2]
        a00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
        a01 = m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]
        a02 = m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]
        a11 = m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]
        a12 = m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]
        a22 = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
        det = m[0, 0] * a00 + m[1, 0] * a01 + m[2, 0] * a02
        if not (abs(det) > SEXTIC_EPS_DET * abs(d1)):
            continue
        s = -0.5 / det
        x0 = s * (a00 * v0 + a01 * v1 + a02 * v2)
        x1 = s * (a01 * v0 + a11 * v1 + a12 * v2)
        x2 = s * (a02 * v0 + a12 * v1 + a22 * v2)
        if not (abs(_qeval(A2, b2, c2, x0, x1, x2)) < SEXTIC_EPS_F):
            continue
        f1 = _qeval(A1, b1, c1, x0, x1, x2)
        if f1 < best:
            best = f1
            bx0 = x0
            bx1 = x1
            bx2 = x2
            blam = lam
            ok = 1
    return ok, bx0, bx1, bx2, best, blam


@njit(cache=True)
def _deepest(Aa, ba, ca, Ab, bb, cb):
    """Point of body b deepest in body a: min f_a on f_b = 0.  (ok, x [3], f_a(x), lam).

    Roots of the sextic by dem.contact.roots.poly_roots (companion matrix, NR balanc + hqr as in
    ParaEllip3d zrhqr); a QR failure counts as no root (ok = 0)."""
    re, im, rok = poly_roots(_sextic_coeffs(Aa, ba, Ab, bb, cb))
    if rok == 0:
        return 0, np.zeros(3), np.inf, 0.0
    ok, x0, x1, x2, fa, lam = _select(re, im, Aa, ba, ca, Ab, bb, cb)
    x = np.empty(3)
    x[0] = x0
    x[1] = x1
    x[2] = x2
    return ok, x, fa, lam


@njit(cache=True)
def _mean_curv_radius(c, rot, ax, p):
    """ParaEllip3d getRadius: 2 / (kappa' + kappa'') at the surface point p (world)."""
    # outward normal A (p - c) (body frame: divide by a_k^2)
    d0 = p[0] - c[0]
    d1 = p[1] - c[1]
    d2 = p[2] - c[2]
    m0 = (rot[0, 0] * d0 + rot[1, 0] * d1 + rot[2, 0] * d2) / (ax[0] * ax[0])
    m1 = (rot[0, 1] * d0 + rot[1, 1] * d1 + rot[2, 1] * d2) / (ax[1] * ax[1])
    m2 = (rot[0, 2] * d0 + rot[1, 2] * d1 + rot[2, 2] * d2) / (ax[2] * ax[2])
    nx = rot[0, 0] * m0 + rot[0, 1] * m1 + rot[0, 2] * m2
    ny = rot[1, 0] * m0 + rot[1, 1] * m1 + rot[1, 2] * m2
    nz = rot[2, 0] * m0 + rot[2, 1] * m1 + rot[2, 2] * m2
    s = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
    nx *= s
    ny *= s
    nz *= s
    h = _h(rot, ax, nx, ny, nz)
    t1x, t1y, t1z, t2x, t2y, t2z = _basis(nx, ny, nz)
    k = _curv(rot, ax, h, t1x, t1y, t1z, t2x, t2y, t2z)
    return 2.0 / (k[0] + k[2])


@njit(cache=True, _nrt=False)
def _centre_inside(c, rot, ax, p):
    """True when point p [3] lies inside the ellipsoid (centre c [3], rotation rot [3, 3] body ->
    world, semi-axes ax [3]): sum_k ((R^T (p - c))_k / a_k)^2 < 1."""
    s = 0.0
    for k in range(3):
        u = (rot[0, k] * (p[0] - c[0]) + rot[1, k] * (p[1] - c[1]) + rot[2, k] * (p[2] - c[2])) / ax[k]
        s += u * u
    return s < 1.0


@njit(cache=True, _nrt=False)
def _sextic_missed(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out):
    """Where the sextic finds no contact: 0, unless a centre lies inside the other body. That deep
    overlap is outside the method's regime (its deepest-point solve fails there, concentric
    bodies included), and it is handed to the exact solver, so that it is never missed and the
    stability guard names it (issue 15). Every contact the sextic finds is left as it was."""
    if _centre_inside(c1, rot1, ax1, c2) or _centre_inside(c2, rot2, ax2, c1):
        return ellipsoid_contact(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out)
    return 0


@njit(cache=True, _nrt=True)  # it allocates: not inherit the callers' _nrt=False (dem.forces)
def sextic_contact(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out, minoverlap=MINOVERLAP):
    """Yan (2010) sextic contact; returns 1 and fills out [OUT_LEN] on a valid contact, else 0.

    Same arguments as ellipsoid_contact (float64 arrays c [3], rot [3, 3], ax [3], n0 [3],
    out [OUT_LEN]; lam0, n0 ignored: the method has no warm start).  @njit, callable from other
    kernels (9 positional arguments: minoverlap = MINOVERLAP); allocates small temporaries.
    OUT_LAM holds the lambda of the point-2 solve; OUT_PW_ITERS = OUT_NEWTON_ITERS = 0;
    OUT_RE = r1 r2 / (r1 + r2) with mean-curvature radii; OUT_KRATIO = 1.
    minoverlap (default MINOVERLAP = 1e-6 as in ParaEllip3d): a contact needs
    delta / (2 max semi-axis) > minoverlap; 0 keeps every geometric overlap (for measuring
    the method's geometry below the paper's cut-off).
    """
    o = np.empty(3)
    for i in range(3):
        o[i] = 0.5 * (c1[i] + c2[i])
    L = max(ax1.max(), ax2.max())
    A1, b1, f1c = _quadric(c1, rot1, ax1, o, L)
    A2, b2, f2c = _quadric(c2, rot2, ax2, o, L)
    ok2, x2, f1_at_2, lam2 = _deepest(A1, b1, f1c, A2, b2, f2c)     # of body 2, deepest in 1
    if ok2 == 0 or not (f1_at_2 < 0.0):
        return _sextic_missed(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out)
    ok1, x1, f2_at_1, _ = _deepest(A2, b2, f2c, A1, b1, f1c)         # of body 1, deepest in 2
    if ok1 == 0 or not (f2_at_1 < 0.0):
        return _sextic_missed(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out)
    p1 = o + L * x1
    p2 = o + L * x2
    d0 = p1[0] - p2[0]
    d1 = p1[1] - p2[1]
    d2 = p1[2] - p2[2]
    depth = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if not (depth / (2.0 * L) > minoverlap):
        return 0
    nx = d0 / depth
    ny = d1 / depth
    nz = d2 / depth
    if nx * (c2[0] - c1[0]) + ny * (c2[1] - c1[1]) + nz * (c2[2] - c1[2]) < 0.0:
        nx = -nx                # orient from body 1 to body 2 (never triggered for shallow overlaps)
        ny = -ny
        nz = -nz
    r1 = _mean_curv_radius(c1, rot1, ax1, p1)
    r2 = _mean_curv_radius(c2, rot2, ax2, p2)
    re = r1 * r2 / (r1 + r2)
    _write_out(out, depth, nx, ny, nz, p1[0], p1[1], p1[2], p2[0], p2[1], p2[2],
               re, 1.0, lam2, 0.0, 0.0)
    return 1


METHODS = dict(zip(CONTACT_METHODS, (ellipsoid_contact, pw_contact, sextic_contact)))  # in their code order
