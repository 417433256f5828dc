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

sextic_contact (@njit, callable from other kernels; allocates one work array of 61 floats a call.
The sextic's real roots come from dem.contact.roots.real_roots6_into, allocation free; numba's
np.linalg would need SciPy's LAPACK at run time, which the project does not depend on)
    Yan, Regueiro & Sture (2010), Eng. Comput. 27(4):519, as coded in ParaEllip3d (root6.cpp /
    zrhqr).  Each body is the quadric f_i(x) = x^T A_i x + b_i^T x + c_i (10 coefficients,
    x^2 coefficient normalised to 1, f_i < 0 inside).  The point of body 2 "deepest in body 1"
    minimises f_1 on f_2 = 0: x(lam) = -1/2 adj M (b_1 + lam b_2) / det M, M = A_1 + lam A_2, and
    lam is a root of the sextic p(lam) = N^T A_2 N + (b_2^T N) det M + c_2 det M^2,
    N = -1/2 adj M (b_1 + lam b_2); its 7 coefficients by explicit scalar arithmetic
    (_sextic_coeffs_into).  Roots: ParaEllip3d takes the eigenvalues of the 6x6 companion matrix
    (balancing + Hessenberg QR, NR balanc/hqr/zrhqr) and keeps the real ones (|Im lam| < EPS);
    here all real roots directly (real_roots6_into: derivative-chain isolation + safeguarded
    Halley, rounding-level accuracy, near-double roots kept as real), the same set to rounding
    at a third of the cost; a degenerate sextic (leading coefficient 0, or not finite; never for
    an ellipsoid pair) keeps the eigenvalue route (dem.contact.roots.poly_roots), where a QR
    failure counts as no contact.  Selection (root6): real roots, det M != 0, |f_2(x)| < EPS_F,
    the most negative f_1(x).  Both directions
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
from dem.contact.roots import REAL6_ROOTS, REAL6_WORK, poly_roots, real_roots6_into

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
# A quadric is the tuple (a00, a01, a02, a11, a12, a22, b0, b1, b2, c0) of
# f(x) = x^T A x + b^T x + c0 (A symmetric): scalars, no arrays (nothing to allocate).
@njit(cache=True, _nrt=False)
def _quadric(c, rot, ax, ox, oy, oz, L):
    """Quadric of the ellipsoid in x' = (x - o)/L, x'^2 coefficient 1 (the tuple above).

    f(x') = (x' - c')^T A' (x' - c') - 1 expanded into monomials, A' = R diag((L/a)^2) R^T,
    then divided by A'_00 (ParaEllip3d stores the 10 coefficients normalised that way).  The
    same operations in the same order as the former array version (bit-identical quadrics).
    """
    w0 = (L / ax[0]) ** 2
    w1 = (L / ax[1]) ** 2
    w2 = (L / ax[2]) ** 2
    a00 = rot[0, 0] * rot[0, 0] * w0 + rot[0, 1] * rot[0, 1] * w1 + rot[0, 2] * rot[0, 2] * w2
    a01 = rot[0, 0] * rot[1, 0] * w0 + rot[0, 1] * rot[1, 1] * w1 + rot[0, 2] * rot[1, 2] * w2
    a02 = rot[0, 0] * rot[2, 0] * w0 + rot[0, 1] * rot[2, 1] * w1 + rot[0, 2] * rot[2, 2] * w2
    a11 = rot[1, 0] * rot[1, 0] * w0 + rot[1, 1] * rot[1, 1] * w1 + rot[1, 2] * rot[1, 2] * w2
    a12 = rot[1, 0] * rot[2, 0] * w0 + rot[1, 1] * rot[2, 1] * w1 + rot[1, 2] * rot[2, 2] * w2
    a22 = rot[2, 0] * rot[2, 0] * w0 + rot[2, 1] * rot[2, 1] * w1 + rot[2, 2] * rot[2, 2] * w2
    c0 = (c[0] - ox) / L
    c1 = (c[1] - oy) / L
    c2 = (c[2] - oz) / L
    s0 = a00 * c0 + a01 * c1 + a02 * c2
    s1 = a01 * c0 + a11 * c1 + a12 * c2
    s2 = a02 * c0 + a12 * c1 + a22 * c2
    f0 = -1.0 + c0 * s0 + c1 * s1 + c2 * s2
    sc = 1.0 / a00
    return (a00 * sc, a01 * sc, a02 * sc, a11 * sc, a12 * sc, a22 * sc,
            -2.0 * s0 * sc, -2.0 * s1 * sc, -2.0 * s2 * sc, f0 * sc)


@njit(cache=True, _nrt=False)
def _lin2(p0, p1, q0, q1, r0, r1, s0, s1):
    """(p0 + l p1)(q0 + l q1) - (r0 + l r1)(s0 + l s1): 3 coefficients, ascending."""
    return (p0 * q0 - r0 * s0, (p0 * q1 + p1 * q0) - (r0 * s1 + r1 * s0), p1 * q1 - r1 * s1)


@njit(cache=True, _nrt=False)
def _lq(p0, p1, q0, q1, q2):
    """(p0 + l p1)(q0 + l q1 + l^2 q2): 4 coefficients, ascending."""
    return (p0 * q0, p0 * q1 + p1 * q0, p0 * q2 + p1 * q1, p1 * q2)


@njit(cache=True, _nrt=False)
def _half_adj_row(ba0, bb0, ba1, bb1, ba2, bb2, c0, c1, c2):
    """-1/2 (c0 v0 + c1 v1 + c2 v2) with v_k = ba_k + l bb_k and c_k a row of adj M (quadratics):
    one component of N, 4 coefficients ascending."""
    u0 = _lq(ba0, bb0, c0[0], c0[1], c0[2])
    u1 = _lq(ba1, bb1, c1[0], c1[1], c1[2])
    u2 = _lq(ba2, bb2, c2[0], c2[1], c2[2])
    return (-0.5 * (u0[0] + u1[0] + u2[0]), -0.5 * (u0[1] + u1[1] + u2[1]), -0.5 * (u0[2] + u1[2] + u2[2]),
            -0.5 * (u0[3] + u1[3] + u2[3]))


@njit(cache=True, _nrt=False)
def _sextic_coeffs_into(qa, qb, w):
    """The 7 coefficients (ascending) of p(lam) = N^T B N + (bb^T N) det M + cb det M^2 into
    w[0:7], M = A + lam B (quadrics qa = (A, ba, ca), qb = (B, bb, cb)), N = -1/2 adj M (ba + lam bb).

    Explicit scalar arithmetic, no arrays (it was polynomial arithmetic on ~100 small heap arrays:
    4.7 us a sextic on the packed scene's pairs, now 0.04 us): M symmetric, so adj M is
    symmetric, 6 quadratic cofactors
    adj_00 = m11 m22 - m12^2, adj_11 = m00 m22 - m02^2, adj_22 = m00 m11 - m01^2,
    adj_01 = m02 m12 - m01 m22, adj_02 = m01 m12 - m02 m11, adj_12 = m01 m02 - m00 m12;
    det M = m00 adj_00 + m01 adj_01 + m02 adj_02 (cubic); N_i = -1/2 sum_j adj_ij v_j (cubic),
    v = ba + lam bb; then p = det (cb det + bb.N) + sum_i N_i (B N)_i, four cubic x cubic products.
    The same polynomial as before, the sums in another order: the coefficients agree to rounding
    (tests/dem/test_contact_methods.py: to 1e-12 of the sum of |terms| of each coefficient, against
    polynomial arithmetic on numpy; measured <= 3 u).
    """
    A00, A01, A02, A11, A12, A22, ba0, ba1, ba2, _ = qa
    B00, B01, B02, B11, B12, B22, bb0, bb1, bb2, cb = qb
    d00 = _lin2(A11, B11, A22, B22, A12, B12, A12, B12)
    d11 = _lin2(A00, B00, A22, B22, A02, B02, A02, B02)
    d22 = _lin2(A00, B00, A11, B11, A01, B01, A01, B01)
    d01 = _lin2(A02, B02, A12, B12, A01, B01, A22, B22)
    d02 = _lin2(A01, B01, A12, B12, A02, B02, A11, B11)
    d12 = _lin2(A01, B01, A02, B02, A00, B00, A12, B12)
    t0 = _lq(A00, B00, d00[0], d00[1], d00[2])
    t1 = _lq(A01, B01, d01[0], d01[1], d01[2])
    t2 = _lq(A02, B02, d02[0], d02[1], d02[2])
    e0 = t0[0] + t1[0] + t2[0]                          # det M
    e1 = t0[1] + t1[1] + t2[1]
    e2 = t0[2] + t1[2] + t2[2]
    e3 = t0[3] + t1[3] + t2[3]
    # N_i = -1/2 (adj_i0 v0 + adj_i1 v1 + adj_i2 v2)
    n00, n01, n02, n03 = _half_adj_row(ba0, bb0, ba1, bb1, ba2, bb2, d00, d01, d02)
    n10, n11, n12, n13 = _half_adj_row(ba0, bb0, ba1, bb1, ba2, bb2, d01, d11, d12)
    n20, n21, n22, n23 = _half_adj_row(ba0, bb0, ba1, bb1, ba2, bb2, d02, d12, d22)
    # g = cb det + bb.N, h_i = (B N)_i (cubics)
    g0 = cb * e0 + bb0 * n00 + bb1 * n10 + bb2 * n20
    g1 = cb * e1 + bb0 * n01 + bb1 * n11 + bb2 * n21
    g2 = cb * e2 + bb0 * n02 + bb1 * n12 + bb2 * n22
    g3 = cb * e3 + bb0 * n03 + bb1 * n13 + bb2 * n23
    h00 = B00 * n00 + B01 * n10 + B02 * n20
    h01 = B00 * n01 + B01 * n11 + B02 * n21
    h02 = B00 * n02 + B01 * n12 + B02 * n22
    h03 = B00 * n03 + B01 * n13 + B02 * n23
    h10 = B01 * n00 + B11 * n10 + B12 * n20
    h11 = B01 * n01 + B11 * n11 + B12 * n21
    h12 = B01 * n02 + B11 * n12 + B12 * n22
    h13 = B01 * n03 + B11 * n13 + B12 * n23
    h20 = B02 * n00 + B12 * n10 + B22 * n20
    h21 = B02 * n01 + B12 * n11 + B22 * n21
    h22 = B02 * n02 + B12 * n12 + B22 * n22
    h23 = B02 * n03 + B12 * n13 + B22 * n23
    # p = det g + N_0 h_0 + N_1 h_1 + N_2 h_2 (cubic x cubic, coefficient k = sum_{i+j=k})
    w[0] = e0 * g0 + n00 * h00 + n10 * h10 + n20 * h20
    w[1] = (e0 * g1 + e1 * g0) + (n00 * h01 + n01 * h00) + (n10 * h11 + n11 * h10) + (n20 * h21 + n21 * h20)
    w[2] = ((e0 * g2 + e1 * g1 + e2 * g0) + (n00 * h02 + n01 * h01 + n02 * h00)
            + (n10 * h12 + n11 * h11 + n12 * h10) + (n20 * h22 + n21 * h21 + n22 * h20))
    w[3] = ((e0 * g3 + e1 * g2 + e2 * g1 + e3 * g0) + (n00 * h03 + n01 * h02 + n02 * h01 + n03 * h00)
            + (n10 * h13 + n11 * h12 + n12 * h11 + n13 * h10)
            + (n20 * h23 + n21 * h22 + n22 * h21 + n23 * h20))
    w[4] = ((e1 * g3 + e2 * g2 + e3 * g1) + (n01 * h03 + n02 * h02 + n03 * h01)
            + (n11 * h13 + n12 * h12 + n13 * h11) + (n21 * h23 + n22 * h22 + n23 * h21))
    w[5] = (e2 * g3 + e3 * g2) + (n02 * h03 + n03 * h02) + (n12 * h13 + n13 * h12) + (n22 * h23 + n23 * h22)
    w[6] = e3 * g3 + n03 * h03 + n13 * h13 + n23 * h23


@njit(cache=True)
def _sextic_coeffs(qa, qb):
    """The coefficients of _sextic_coeffs_into as a new array [7] (tests, callers outside)."""
    w = np.empty(7)
    _sextic_coeffs_into(qa, qb, w)
    return w


@njit(cache=True, _nrt=False)
def _qeval(q, x0, x1, x2):
    return (q[0] * x0 * x0 + q[3] * x1 * x1 + q[5] * x2 * x2
            + 2.0 * (q[1] * x0 * x1 + q[2] * x0 * x2 + q[4] * x1 * x2)
            + q[6] * x0 + q[7] * x1 + q[8] * x2 + q[9])


@njit(cache=True, _nrt=False)
def _candidate(lam, qa, qb, da):
    """One root lam of the root6 selection: (ok, x0, x1, x2, f_a(x)); ok = 0 when
    |det M(lam)| <= EPS_DET |det A_a| (da) or |f_b(x)| >= EPS_F.  x = -1/2 adj M v / det M,
    M = A_a + lam A_b, v = b_a + lam b_b (the operations of the former _select)."""
    m00 = qa[0] + lam * qb[0]
    m01 = qa[1] + lam * qb[1]
    m02 = qa[2] + lam * qb[2]
    m11 = qa[3] + lam * qb[3]
    m12 = qa[4] + lam * qb[4]
    m22 = qa[5] + lam * qb[5]
    v0 = qa[6] + lam * qb[6]
    v1 = qa[7] + lam * qb[7]
    v2 = qa[8] + lam * qb[8]
    a00 = m11 * m22 - m12 * m12
    a01 = m02 * m12 - m01 * m22
    a02 = m01 * m12 - m02 * m11
    a11 = m00 * m22 - m02 * m02
    a12 = m02 * m01 - m00 * m12
    a22 = m00 * m11 - m01 * m01
    det = m00 * a00 + m01 * a01 + m02 * a02
    if not (abs(det) > SEXTIC_EPS_DET * abs(da)):
        return 0, 0.0, 0.0, 0.0, 0.0
    s = -0.5 / det
    x0 = s * (a00 * v0 + a01 * v1 + a02 * v2)
    x1 = s * (a01 * v0 + a11 * v1 + a12 * v2)
    x2 = s * (a02 * v0 + a12 * v1 + a22 * v2)
    if not (abs(_qeval(qb, x0, x1, x2)) < SEXTIC_EPS_F):
        return 0, 0.0, 0.0, 0.0, 0.0
    return 1, x0, x1, x2, _qeval(qa, x0, x1, x2)


@njit(cache=True, _nrt=False)
def _det3(q):
    return (q[0] * (q[3] * q[5] - q[4] * q[4])
            - q[1] * (q[1] * q[5] - q[4] * q[2])
            + q[2] * (q[1] * q[4] - q[3] * q[2]))


@njit(cache=True, _nrt=False)
def _select(re, im, n, qa, qb):
    """root6 selection: among the n roots re[k] (candidates when |im[k]| < EPS_IM; im = None:
    all real) with det M != 0 and |f_b(x)| < EPS_F, the x with the most negative f_a(x).
    Returns (ok, x0, x1, x2, f_a, lam)."""
    ok = 0
    best = np.inf
    bx0 = 0.0
    bx1 = 0.0
    bx2 = 0.0
    blam = 0.0
    da = _det3(qa)
    for k in range(n):
        if im is not None and not (abs(im[k]) < SEXTIC_EPS_IM):
            continue
        lam = re[k]
        cok, x0, x1, x2, fa = _candidate(lam, qa, qb, da)
        if cok == 1 and fa < best:
            best = fa
            bx0 = x0
            bx1 = x1
            bx2 = x2
            blam = lam
            ok = 1
    return ok, bx0, bx1, bx2, best, blam


@njit(cache=True)
def _select_companion(w, qa, qb):
    """The former route, for a degenerate sextic (leading coefficient exactly 0, or a coefficient
    not finite; never for an ellipsoid pair, whose leading coefficient is -det(A_b)^2 up to the
    normalisation): poly_roots (companion matrix; trims exactly-zero leading coefficients, ok = 0
    on a non-finite matrix or a QR failure, then no root), real within EPS_IM, then _select."""
    re, im, rok = poly_roots(w[:7].copy())
    if rok == 0:
        return 0, 0.0, 0.0, 0.0, np.inf, 0.0
    return _select(re, im, re.shape[0], qa, qb)


@njit(cache=True)
def _deepest(qa, qb, w):
    """Point of body b deepest in body a: min f_a on f_b = 0.  (ok, x0, x1, x2, f_a(x), lam).

    Coefficients by _sextic_coeffs_into into w [REAL6_WORK] (the caller's work array, reused);
    all real roots by dem.contact.roots.real_roots6_into (derivative-chain isolation + safeguarded
    Halley, allocation free, 0.66 us a sextic on the packed scene's pairs; formerly the eigenvalues
    of the companion matrix, NR balanc + hqr, 2.0 us, of which the roots with |Im| < EPS_IM were
    kept: the real roots, near-double ones included, are the same set to rounding, see
    real_roots6_into); a degenerate sextic keeps the former route (_select_companion).
    Where det M(lam) is small at a root, the filter |f_b(x)| = |p(lam)| / det M^2 < EPS_F is
    decided at the rounding level of the root: the rounding-level roots here keep candidates
    that the eigenvalues (|p| ~ 1e-13 worse) lost, and the point found is then the deeper one
    that root6 asks for.  Measured: no difference on the packed scene's 2002 pairs (shallow
    contacts) nor in the tests; 71 of 4115 contacts differ on random deep overlaps (centres
    0.05-1 x the sum of the long semi-axes apart; a probe outside the repository), 47 of the 48 differing
    solves examined being such a recovered candidate (the other: a sextic whose leading
    coefficient is 1e-11 of the largest, both routes at rounding level)."""
    _sextic_coeffs_into(qa, qb, w)
    good = w[6] != 0.0
    for k in range(7):
        good = good and np.isfinite(w[k])
    if not good:
        return _select_companion(w, qa, qb)
    m = real_roots6_into(w)
    return _select(w[REAL6_ROOTS:], None, m, qa, qb)


@njit(cache=True, _nrt=False)
def _mean_curv_radius(c, rot, ax, px, py, pz):
    """ParaEllip3d getRadius: 2 / (kappa' + kappa'') at the surface point p (world)."""
    # outward normal A (p - c) (body frame: divide by a_k^2)
    d0 = px - c[0]
    d1 = py - c[1]
    d2 = pz - c[2]
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


@njit(cache=True, _nrt=True)  # it allocates one work array: not inherit the callers' _nrt=False (dem.forces)
def sextic_contact(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out, minoverlap=MINOVERLAP):
    """Yan (2010) sextic contact; returns 1 and fills out [OUT_LEN] on a valid contact, else 0.

    Same arguments as ellipsoid_contact (float64 arrays c [3], rot [3, 3], ax [3], n0 [3],
    out [OUT_LEN]; lam0, n0 ignored: the method has no warm start).  @njit, callable from other
    kernels (9 positional arguments: minoverlap = MINOVERLAP); allocates one work array
    [REAL6_WORK] (the quadrics are scalar tuples, the two sextics and their roots share it).
    OUT_LAM holds the lambda of the point-2 solve; OUT_PW_ITERS = OUT_NEWTON_ITERS = 0;
    OUT_RE = r1 r2 / (r1 + r2) with mean-curvature radii; OUT_KRATIO = 1.
    minoverlap (default MINOVERLAP = 1e-6 as in ParaEllip3d): a contact needs
    delta / (2 max semi-axis) > minoverlap; 0 keeps every geometric overlap (for measuring
    the method's geometry below the paper's cut-off).
    """
    ox = 0.5 * (c1[0] + c2[0])
    oy = 0.5 * (c1[1] + c2[1])
    oz = 0.5 * (c1[2] + c2[2])
    L = max(ax1.max(), ax2.max())
    q1 = _quadric(c1, rot1, ax1, ox, oy, oz, L)
    q2 = _quadric(c2, rot2, ax2, ox, oy, oz, L)
    w = np.empty(REAL6_WORK)
    ok2, y0, y1, y2, f1_at_2, lam2 = _deepest(q1, q2, w)     # of body 2, deepest in 1
    if ok2 == 0 or not (f1_at_2 < 0.0):
        return _sextic_missed(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out)
    ok1, z0, z1, z2, f2_at_1, _ = _deepest(q2, q1, w)         # of body 1, deepest in 2
    if ok1 == 0 or not (f2_at_1 < 0.0):
        return _sextic_missed(c1, rot1, ax1, c2, rot2, ax2, lam0, n0, out)
    p1x = ox + L * z0
    p1y = oy + L * z1
    p1z = oz + L * z2
    p2x = ox + L * y0
    p2y = oy + L * y1
    p2z = oz + L * y2
    d0 = p1x - p2x
    d1 = p1y - p2y
    d2 = p1z - p2z
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
    r1 = _mean_curv_radius(c1, rot1, ax1, p1x, p1y, p1z)
    r2 = _mean_curv_radius(c2, rot2, ax2, p2x, p2y, p2z)
    re = r1 * r2 / (r1 + r2)
    _write_out(out, depth, nx, ny, nz, p1x, p1y, p1z, p2x, p2y, p2z,
               re, 1.0, lam2, 0.0, 0.0)
    return 1


METHODS = dict(zip(CONTACT_METHODS, (ellipsoid_contact, pw_contact, sextic_contact)))  # in their code order
