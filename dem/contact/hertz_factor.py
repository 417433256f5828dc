"""Exact elliptical-Hertz force factor f_H(B/A) (Johnson, Contact Mechanics, 1985, §4.2).

Two bodies with relative curvature tensor K = K1 + K2 (eigenvalues kappa' <= kappa'', Johnson's
A = kappa'/2, B = kappa''/2) pressed together by delta form an elliptical contact with semi-axes
a >= b, eccentricity e^2 = 1 - (b/a)^2, where (K, E complete elliptic integrals of modulus e)

    B/A   = [E/(1 - e^2) - K] / (K - E)
    a^2   = delta (K - E) / (A K e^2)
    P     = (2 pi / 3) E* delta a / K.

The force of the equivalent sphere with R_e = sqrt(R'R'') = 1/(2 sqrt(AB)) is
P_e = (4/3) E* sqrt(R_e) delta^(3/2); the factor is their ratio

    f_H(k) = P / P_e = (pi / (2 K)) sqrt(2 (K - E) sqrt(k) / (K e^2)),   k = B/A,

so that F_n = (4/3) E* sqrt(R_e) delta^(3/2) f_H(kratio) is exact for the elliptical contact
(f_H(1) = 1; 1.0100 at k = 2, 1.1090 at 10, 1.4351 at 100: contact-mechanics reference §3.1).

K and E come from the arithmetic-geometric mean (Abramowitz & Stegun 17.6), written in terms
of r = b/a: a0 = 1, b0 = r, c0 = e; K = pi / (2 a_N), K - E = K sum_n 2^(n-1) c_n^2 (no
cancellation near e = 0).  At import a table of f_H and ln(b/a) on a uniform grid in ln k,
0 <= ln k <= LNK_MAX, is built once (k -> r by bisection) and the @njit functions interpolate it
with 4-point Lagrange cubics; k beyond the ends is clamped (f_H(k <= 1) = 1).
Interpolation error < 1e-7 relative over 1 <= k <= 1e6.
"""
import numpy as np
from numba import njit

LNK_MAX = np.log(1e6)     # table end: kratio up to 1e6 (clamped beyond)
N_TABLE = 1025            # grid points in ln(kratio)


@njit(cache=True)
def elliptic_ke(r):
    """Complete elliptic integrals (K(e), K(e) - E(e)) for complementary modulus r = sqrt(1 - e^2).

    AGM with c_n tracked explicitly, so K - E is accurate even for e -> 0.  0 < r <= 1.
    """
    a = 1.0
    b = r
    c2 = (1.0 - r) * (1.0 + r)          # c0^2 = e^2
    s = 0.5 * c2
    w = 0.5
    for _ in range(64):
        c = 0.5 * (a - b)
        if c == 0.0:
            break
        an = 0.5 * (a + b)
        b = np.sqrt(a * b)
        a = an
        w *= 2.0
        s += w * c * c
        if c < 1e-17 * a:
            break
    k = np.pi / (2.0 * a)
    return k, k * s


@njit(cache=True)
def ratio_and_factor(r):
    """(B/A, f_H) of the elliptical Hertz contact whose contact ellipse has b/a = r (0 < r <= 1)."""
    if r >= 1.0:
        return 1.0, 1.0
    e2 = (1.0 - r) * (1.0 + r)
    kk, kme = elliptic_ke(r)            # K, K - E
    s = kme / kk                        # (K - E) / K = sum 2^(n-1) c_n^2
    # B/A = [E/r^2 - K] / (K - E) = [(1 - s)/r^2 - 1] / s = (e^2 - s) / (r^2 s)
    k = (e2 - s) / (r * r * s)
    f = np.pi / (2.0 * kk) * np.sqrt(2.0 * s * np.sqrt(k) / e2)
    return k, f


@njit(cache=True)
def _build_table(n, lnk_max):
    """f_H and ln(b/a) on the uniform grid ln k_i = i lnk_max / (n - 1) (k -> r by bisection)."""
    fh = np.empty(n)
    lnr = np.empty(n)
    fh[0] = 1.0
    lnr[0] = 0.0
    for i in range(1, n):
        target = i * lnk_max / (n - 1)
        lo = -60.0                       # ln r: k(r) decreases from inf (r -> 0) to 1 (r = 1)
        hi = 0.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            k, f = ratio_and_factor(np.exp(mid))
            if np.log(k) > target:
                lo = mid
            else:
                hi = mid
            if hi - lo < 1e-15:
                break
        mid = 0.5 * (lo + hi)
        k, f = ratio_and_factor(np.exp(mid))
        fh[i] = f
        lnr[i] = mid
    return fh, lnr


_FH_TABLE, _LNR_TABLE = _build_table(N_TABLE, LNK_MAX)
_H = LNK_MAX / (N_TABLE - 1)


@njit(cache=True, _nrt=False)
def _interp(table, kratio):
    """4-point Lagrange interpolation of a table on the uniform ln-k grid, clamped at the ends."""
    if not (kratio > 1.0):
        return table[0]
    x = np.log(kratio) / _H
    n = table.shape[0]
    if x >= n - 1:
        return table[n - 1]
    i = int(x)
    # stencil i-1 .. i+2, shifted inside the table at the ends
    j = min(max(i - 1, 0), n - 4)
    t = x - j                            # position relative to node j, in [0, 3]
    t1 = t - 1.0
    t2 = t - 2.0
    t3 = t - 3.0
    return (-table[j] * t1 * t2 * t3 / 6.0 + table[j + 1] * t * t2 * t3 / 2.0
            - table[j + 2] * t * t1 * t3 / 2.0 + table[j + 3] * t * t1 * t2 / 6.0)


@njit(cache=True, _nrt=False)
def hertz_factor(kratio):
    """Exact elliptical-Hertz force factor f_H = P_exact / P(R_e = sqrt(R'R'')) for B/A = kratio.

    kratio = kappa''/kappa' >= 1 (ellipsoid.OUT_KRATIO); f_H(1) = 1, clamped beyond 1e6.
    """
    return _interp(_FH_TABLE, kratio)


@njit(cache=True, _nrt=False)
def contact_ellipse_ratio(kratio):
    """Axis ratio b/a <= 1 of the elliptical Hertz contact area for B/A = kratio (1 at kratio 1)."""
    return np.exp(_interp(_LNR_TABLE, kratio))
