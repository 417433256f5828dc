"""Roots of a real polynomial as the eigenvalues of its companion matrix (@njit, no LAPACK).

p(x) = sum_{k=0}^{n} p[k] x^k (ascending powers), leading zero coefficients trimmed (exactly
zero p[n] lowers the degree, as np.roots).  The roots are the eigenvalues of the companion
matrix of the monic polynomial, which is upper Hessenberg:

        | -p[n-1]/p[n]  -p[n-2]/p[n]  ...  -p[0]/p[n] |
    C = |      1             0        ...       0     |
        |      0             1        ...       0     |
        |      0            ...        1        0     |

Algorithm (Press, Teukolsky, Vetterling & Flannery, Numerical Recipes in C, 2nd ed. (1992),
§9.5 zrhqr "eigenvalue methods", §11.5 balanc, §11.6 hqr; the same route as LAPACK's geev used
by np.roots, and the one the code ParaEllip3d uses for the sextic of Yan, Regueiro & Sture (2010),
Eng. Comput. 27(4):519, root6.cpp -> zrhqr -> balanc + hqr):

* balanc: Parlett & Reinsch (1969) balancing with radix 2 (exact in binary floating point).
  For each i, with column and row norms c = sum_{j != i} |a_ji|, r = sum_{j != i} |a_ij|, find the
  power of two f with c f^2 ~ r; apply a_i* /= f, a_*i *= f (a diagonal similarity, which keeps
  the Hessenberg form) when it reduces c + r by more than 5 %; sweep until no row changes.
* hqr: Francis double-shift QR on the upper Hessenberg matrix.  Deflation when a subdiagonal
  element is negligible, |a_l,l-1| + s == s with s = |a_l-1,l-1| + |a_ll|; a 1x1 block gives a
  real eigenvalue, a 2x2 block a real pair or a complex-conjugate pair; otherwise one implicit
  double-shift QR sweep (shifts the eigenvalues of the trailing 2x2 block, Householder 3-vectors),
  with the exceptional ad hoc shifts at iterations 10 and 20 and at most 30 iterations per
  eigenvalue.  Beyond that the routine reports failure (NR stops with nrerror).

poly_roots(p)  p [n+1] float64  ->  (re [m], im [m], ok)
    m = the degree after trimming (0 for a constant or zero polynomial: empty arrays, ok = 1);
    complex roots come as conjugate pairs (im of opposite sign, adjacent); the order is that of
    deflation (unsorted).  ok = 1 on success, 0 if the QR iteration did not converge or the
    companion matrix is not finite (the arrays then hold no usable roots).
balanc(a)  a [n, n], in place.
hqr(a, wr, wi)  a [n, n] upper Hessenberg (destroyed), wr [n], wi [n]  ->  ok (1/0).

Real roots of a sextic (the contact kernel's route since issue 33, 6x cheaper than the eigenvalues
and allocation free; poly_roots stays for degenerate sextics and general degrees):
real_roots6_into(w)  w [REAL6_WORK] with the 7 coefficients in w[0:7]  ->  m; the m real roots,
    ascending, at w[REAL6_ROOTS:]; derivative-chain isolation + bisection-safeguarded Halley
    (method, accuracy and near-double roots: its docstring).
real_roots6(p)  p [7]  ->  the real roots, a new array.
"""
import numpy as np
from numba import njit

RADIX = 2.0             # balancing factor: a power of the floating-point radix
HQR_MAXIT = 30          # QR iterations per eigenvalue (NR hqr)


@njit(cache=True)
def balanc(a):
    """Parlett-Reinsch balancing of the square matrix a in place (NR §11.5 balanc, radix 2).

    Diagonal similarity D^-1 a D with D a product of powers of RADIX: the eigenvalues are unchanged
    (exactly: scaling by powers of two is exact), the row and column norms of each off-diagonal
    part become comparable, which bounds the rounding errors of the QR iteration by a smaller norm.
    """
    n = a.shape[0]
    sqrdx = RADIX * RADIX
    done = False
    while not done:
        done = True
        for i in range(n):
            r = 0.0
            c = 0.0
            for j in range(n):
                if j != i:
                    c += abs(a[j, i])
                    r += abs(a[i, j])
            if c != 0.0 and r != 0.0:
                g = r / RADIX
                f = 1.0
                s = c + r
                while c < g:
                    f *= RADIX
                    c *= sqrdx
                g = r * RADIX
                while c > g:
                    f /= RADIX
                    c /= sqrdx
                if (c + r) / f < 0.95 * s:
                    done = False
                    g = 1.0 / f
                    for j in range(n):
                        a[i, j] *= g
                    for j in range(n):
                        a[j, i] *= f


@njit(cache=True)
def _sign(a, b):
    """|a| with the sign of b (Fortran SIGN; b = 0 counts as positive)."""
    return abs(a) if b >= 0.0 else -abs(a)


@njit(cache=True)
def hqr(a, wr, wi):
    """Eigenvalues wr + i wi of the upper Hessenberg matrix a (destroyed) by Francis double-shift QR
    (NR §11.6 hqr).  Returns 1, or 0 after HQR_MAXIT iterations without deflation."""
    n = a.shape[0]
    anorm = 0.0
    for i in range(n):
        for j in range(max(i - 1, 0), n):
            anorm += abs(a[i, j])
    nn = n - 1
    t = 0.0                                 # accumulated exceptional shifts
    x = 0.0
    y = 0.0
    w = 0.0
    while nn >= 0:
        its = 0
        while True:
            # look for a single small subdiagonal element a[l, l-1]
            l = nn
            while l >= 1:
                s = abs(a[l - 1, l - 1]) + abs(a[l, l])
                if s == 0.0:
                    s = anorm
                if abs(a[l, l - 1]) + s == s:
                    a[l, l - 1] = 0.0
                    break
                l -= 1
            x = a[nn, nn]
            if l == nn:                             # one root found
                wr[nn] = x + t
                wi[nn] = 0.0
                nn -= 1
                break
            y = a[nn - 1, nn - 1]
            w = a[nn, nn - 1] * a[nn - 1, nn]
            if l == nn - 1:                         # two roots found
                p = 0.5 * (y - x)
                q = p * p + w
                z = np.sqrt(abs(q))
                x += t
                if q >= 0.0:                        # real pair
                    z = p + _sign(z, p)
                    wr[nn - 1] = x + z
                    wr[nn] = x + z
                    if z != 0.0:
                        wr[nn] = x - w / z
                    wi[nn - 1] = 0.0
                    wi[nn] = 0.0
                else:                               # complex-conjugate pair
                    wr[nn - 1] = x + p
                    wr[nn] = x + p
                    wi[nn - 1] = -z
                    wi[nn] = z
                nn -= 2
                break
            # no roots yet: one double-shift QR sweep on rows/columns l..nn
            if its == HQR_MAXIT:
                return 0
            if its == 10 or its == 20:              # exceptional shift
                t += x
                for i in range(nn + 1):
                    a[i, i] -= x
                s = abs(a[nn, nn - 1]) + abs(a[nn - 1, nn - 2])
                x = 0.75 * s
                y = x
                w = -0.4375 * s * s
            its += 1
            # two consecutive small subdiagonal elements: start row m of the sweep
            m = nn - 2
            p = 0.0
            q = 0.0
            r = 0.0
            while True:
                z = a[m, m]
                r = x - z
                s = y - z
                p = (r * s - w) / a[m + 1, m] + a[m, m + 1]
                q = a[m + 1, m + 1] - z - r - s
                r = a[m + 2, m + 1]
                s = abs(p) + abs(q) + abs(r)        # scale to prevent over/underflow
                p /= s
                q /= s
                r /= s
                if m == l:
                    break
                u = abs(a[m, m - 1]) * (abs(q) + abs(r))
                v = abs(p) * (abs(a[m - 1, m - 1]) + abs(z) + abs(a[m + 1, m + 1]))
                if u + v == v:
                    break
                m -= 1
            for i in range(m + 2, nn + 1):
                a[i, i - 2] = 0.0
                if i != m + 2:
                    a[i, i - 3] = 0.0
            # double QR step on rows l..nn and columns m..nn (Householder 3-vectors)
            for k in range(m, nn):
                if k != m:
                    p = a[k, k - 1]                 # the Householder vector of this column
                    q = a[k + 1, k - 1]
                    r = 0.0
                    if k != nn - 1:
                        r = a[k + 2, k - 1]
                    x = abs(p) + abs(q) + abs(r)
                    if x != 0.0:
                        p /= x
                        q /= x
                        r /= x
                s = _sign(np.sqrt(p * p + q * q + r * r), p)
                if s != 0.0:
                    if k == m:
                        if l != m:
                            a[k, k - 1] = -a[k, k - 1]
                    else:
                        a[k, k - 1] = -s * x
                    p += s
                    x = p / s
                    y = q / s
                    z = r / s
                    q /= p
                    r /= p
                    for j in range(k, nn + 1):      # row modification
                        p = a[k, j] + q * a[k + 1, j]
                        if k != nn - 1:
                            p += r * a[k + 2, j]
                            a[k + 2, j] -= p * z
                        a[k + 1, j] -= p * y
                        a[k, j] -= p * x
                    mmin = min(k + 3, nn)
                    for i in range(l, mmin + 1):    # column modification
                        p = x * a[i, k] + y * a[i, k + 1]
                        if k != nn - 1:
                            p += z * a[i, k + 2]
                            a[i, k + 2] -= p * r
                        a[i, k + 1] -= p * q
                        a[i, k] -= p
            # (NR's do-while test l < nn - 1 holds here: iterate again on the same block)
    return 1


@njit(cache=True)
def poly_roots(p):
    """Roots of sum_k p[k] x^k (p [n+1] float64, ascending powers): (re [m], im [m], ok).

    Eigenvalues of the companion matrix (module docstring) by balanc + hqr (NR §9.5 zrhqr,
    unsorted).  Exactly-zero leading coefficients are trimmed (degree m <= n).  ok = 0 when the
    companion matrix is not finite or hqr does not converge (re, im then unusable).
    """
    n = p.shape[0] - 1
    while n > 0 and p[n] == 0.0:
        n -= 1
    if n < 1:
        return np.zeros(0), np.zeros(0), 1
    comp = np.zeros((n, n))
    for k in range(n):
        comp[0, k] = -p[n - 1 - k] / p[n]
        if k + 1 < n:
            comp[k + 1, k] = 1.0
    wr = np.zeros(n)
    wi = np.zeros(n)
    for k in range(n):
        if not np.isfinite(comp[0, k]):
            return wr, wi, 0
    balanc(comp)
    ok = hqr(comp, wr, wi)
    return wr, wi, ok


# ================================================================ real roots of a sextic
# Work-array layout of real_roots6_into (float64, REAL6_WORK entries): the coefficients of
# p^(k), the k-th derivative of p (degree d = 6 - k, ascending powers), in a block of 7 at
# REAL6_LEVEL[d] = 7 k, zero above degree d (so every level is evaluated as a sextic by the same
# straight-line code, and its derivatives are the next two blocks); two root buffers of 6 entries
# each (ping-pong between levels); the real roots of p end up at REAL6_ROOTS.
REAL6_LEVEL = (42, 35, 28, 21, 14, 7, 0)    # offset of the degree-d polynomial, d = 0..6
REAL6_BUF = (49, 55)                        # root buffers: degree d writes to REAL6_BUF[d % 2]
REAL6_ROOTS = 49                            # = REAL6_BUF[0]: the roots of the sextic (d = 6)
REAL6_WORK = 61
REAL6_MAXIT = 128                           # iterations per root (bisection alone halves a
#                                             bracket of 2 B to 1e-15 |x| in < 100)
REAL6_TOL_ROOT = 1e-6                       # last Halley step |dx| / |x| of the sextic's roots
#                                             and critical points: error ~ dx^3, rounding level
REAL6_TOL_CRIT = 1e-3                       # ... of the lower derivatives' roots (interval ends
#                                             only): error ~ 1e-9
UNIT_ROUNDOFF = 2.0 ** -53
REAL6_GAMMA = 12.0 * UNIT_ROUNDOFF / (1.0 - 12.0 * UNIT_ROUNDOFF)  # gamma_12 >= gamma_7 (_eval_bound)


@njit(cache=True, _nrt=False)
def _estrin(w, o, x, x2, x4):
    """sum_{j<=6} w[o + j] x^j by Estrin's scheme (a0 + a1 x) + x^2 (a2 + a3 x) + x^4 (a4 + a5 x
    + a6 x^2): three levels of dependent operations instead of Horner's six."""
    return ((w[o] + w[o + 1] * x) + x2 * (w[o + 2] + w[o + 3] * x)
            + x4 * ((w[o + 4] + w[o + 5] * x) + x2 * w[o + 6]))


@njit(cache=True, _nrt=False)
def _eval3(w, o, x):
    """p(x), p'(x), p''(x) of the level at w[o ..] (its derivatives are the blocks at o + 7 and
    o + 14), by Estrin: the three evaluations are independent, so one costs the latency of one."""
    x2 = x * x
    x4 = x2 * x2
    return _estrin(w, o, x, x2, x4), _estrin(w, o + 7, x, x2, x4), _estrin(w, o + 14, x, x2, x4)


@njit(cache=True, _nrt=False)
def _eval_bound(w, o, x):
    """p(x), p''(x) and e = sum_j |a_j| |x|^j of the level at w[o ..], by Estrin (_estrin).  Every
    term a_j x^j of Estrin's expression passes at most 7 roundings (x^2: 1, x^4: 2, then the
    products and sums), so |fl(p(x)) - p(x)| <= gamma_7 e (Higham (2002), Accuracy and Stability
    of Numerical Algorithms, 2nd ed., §3.1, gamma_k = k u / (1 - k u)); e itself is exact to
    gamma_7 (all terms positive)."""
    x2 = x * x
    x4 = x2 * x2
    ax = abs(x)
    e = ((abs(w[o]) + abs(w[o + 1]) * ax) + x2 * (abs(w[o + 2]) + abs(w[o + 3]) * ax)
         + x4 * ((abs(w[o + 4]) + abs(w[o + 5]) * ax) + x2 * abs(w[o + 6])))
    return _estrin(w, o, x, x2, x4), _estrin(w, o + 14, x, x2, x4), e


@njit(cache=True, _nrt=False)
def _root_in(w, o, xl, xh, x, tol):
    """The root of the level at w[o ..] (degree <= 6) in the bracket with p(xl) < 0 < p(xh)
    (either order), on which p is monotonic, from the start x inside it: Halley's method
    x <- x - 2 p p' / (2 p'^2 - p p'') (cubic convergence; p', p'' come with p, _eval3)
    safeguarded by bisection as NR §9.4 rtsafe: a step that would leave the bracket, or that is
    not below half the step before last, is replaced by bisection; each evaluation shrinks the
    bracket.  Returns after a Halley step |dx| <= tol |x| or <= 2 u |x| (the error after it is then
    ~ K dx^3, K = (p''/2p')^2 - p'''/6p' ~ 1/(distance to the next root)^2: tol = 1e-6 leaves
    ~ 1e-18 |x| for a root apart from the others by > 3 % of |x|), when p(x) == 0, when x no
    longer moves, or after REAL6_MAXIT steps."""
    lo = min(xl, xh)
    hi = max(xl, xh)
    if not (lo < x < hi):
        x = 0.5 * (xl + xh)
    dxold = abs(xh - xl)
    dx = dxold
    for _ in range(REAL6_MAXIT):
        f, df, d2 = _eval3(w, o, x)
        if f == 0.0:
            return x
        if f < 0.0:
            xl = x
        else:
            xh = x
        den = 2.0 * df * df - f * d2
        step = 2.0 * f * df / den if den != 0.0 else np.inf
        xn = x - step
        ax = abs(x)
        if abs(step) <= 2.0 * UNIT_ROUNDOFF * ax:
            return xn                       # converged to rounding (xn may equal x, a bracket end)
        if not (min(xl, xh) < xn < max(xl, xh)) or abs(2.0 * step) > abs(dxold):
            dxold = dx                      # bisection
            dx = 0.5 * (xh - xl)
            x = xl + dx
            if x == xl or x == xh:
                return x
        else:
            dxold = dx                      # Halley
            dx = step
            x = xn
            if abs(dx) <= tol * ax:
                return x
    return x


@njit(cache=True, _nrt=False)
def _smoothstep_inv(r):
    """t in [0, 1] with 3 t^2 - 2 t^3 ~ r (r in (0, 1)), a start point: t0 = sqrt(r / 3) (the
    small-t branch; r > 1/2 by the symmetry t(1 - r) = 1 - t(r)) and one Newton step, to < 0.01
    (the exact inverse, 1/2 - sin(asin(1 - 2 r) / 3), costs two transcendental calls)."""
    rr = r if r <= 0.5 else 1.0 - r
    t = np.sqrt(rr / 3.0)
    d = 6.0 * t * (1.0 - t)
    if d > 0.0:
        t -= (t * t * (3.0 - 2.0 * t) - rr) / d
    return t if r <= 0.5 else 1.0 - t


@njit(cache=True, _nrt=False)
def _level_roots(w, d, co, m, oo, bound, tol):
    """Real roots of the degree-d polynomial p_d = w[REAL6_LEVEL[d] ..] (d >= 3), ascending into
    w[oo ..], given the m real roots crit = w[co .. co + m] (ascending) of its derivative and the
    root bound; returns their number.  Between consecutive points of
    -bound < crit_0 < ... < crit_m-1 < bound, p_d is monotonic, so each interval whose ends have
    opposite signs holds exactly one root (_root_in) and no other does.  Starts: on the two
    unbounded sides, Laguerre's step from the critical point c (p'(c) = 0),
    h = sqrt(d / (d - 1) |p(c) / p''(c)|) (exact when the other d - 1 roots coincide); between two
    critical points, the root of the cubic Hermite model with zero end slopes (the smoothstep
    3 t^2 - 2 t^3, inverted approximately: _smoothstep_inv).  A critical point where |p_d| is within Horner's
    rounding bound (_eval_bound) counts as a (double) root itself, and its sign as zero
    (no root on either side of it then): near-double roots, whose computed eigenvalues the
    companion-matrix route gives as real or as a pair with Im ~ sqrt(u), are kept as real.
    (The bound used is REAL6_GAMMA e = gamma_12 e, above Estrin's gamma_7 e: generous, so that a
    double root is not lost to a rounding-level sign; a spurious one costs a candidate that the
    contact's selection tests like any other.)"""
    o = REAL6_LEVEL[d]
    lead = w[o + d]
    gam = REAL6_GAMMA
    lag = d / (d - 1.0)
    sr = 1.0 if lead > 0.0 else -1.0        # sign of p_d at +bound
    sl = sr if d % 2 == 0 else -sr          # ... at -bound
    n = 0
    px = -bound
    ps = sl
    pf = 0.0
    pg = 0.0
    for i in range(m + 1):
        if i < m:
            x = w[co + i]
            f, g, e = _eval_bound(w, o, x)
            s = 0.0
            if f > gam * e:
                s = 1.0
            elif f < -gam * e:
                s = -1.0
        else:
            x = bound
            s = sr
            f = 0.0
            g = 0.0
        if ps * s < 0.0:                    # one root in (px, x)
            if m == 0:
                x0 = 0.0
            elif i == 0:                    # (-bound, crit_0): Laguerre from crit_0
                x0 = x - np.sqrt(lag * abs(f / g)) if g != 0.0 else 0.5 * (px + x)
            elif i == m:                    # (crit_m-1, bound): Laguerre from crit_m-1
                x0 = px + np.sqrt(lag * abs(pf / pg)) if pg != 0.0 else 0.5 * (px + x)
            else:                           # smoothstep model: 3 t^2 - 2 t^3 = pf / (pf - f)
                x0 = px + _smoothstep_inv(pf / (pf - f)) * (x - px)
            if ps < 0.0:
                w[oo + n] = _root_in(w, o, px, x, x0, tol)
            else:
                w[oo + n] = _root_in(w, o, x, px, x0, tol)
            n += 1
        if s == 0.0:
            w[oo + n] = x
            n += 1
        px = x
        ps = s
        pf = f
        pg = g
    return n


@njit(cache=True, _nrt=False)
def real_roots6_into(w):
    """All real roots of the sextic p(x) = sum_k w[k] x^k (w[6] != 0, all finite: the caller
    checks), ascending, at w[REAL6_ROOTS .. REAL6_ROOTS + m]; returns m (0..6).  w [REAL6_WORK]
    is the whole work space (no allocation).

    Method (isolation by the derivative chain; Collins & Loos (1976) "Polynomial real root
    isolation by differentiation", as in C. Yuksel (2022), "High-performance polynomial root
    finding for graphics", Proc. ACM Comput. Graph. Interact. Tech. 5(3)): the derivatives
    p^(k) (degree 6 - k, exact integer multiples of the coefficients up to one rounding) are
    solved from the quadratic one upward (its roots in closed form, the stable formula); the real
    roots of p^(k+1) split the real line into intervals on which p^(k) is monotonic
    (_level_roots), each sign change holds one root, found by bisection-safeguarded Halley
    iteration (_root_in).  All roots lie within the Fujiwara (1916) bound
    B = 2 max_k |a_6-k / a_6|^(1/k) (a_0 / 2 for k = 6; the odd roots bounded above by square
    roots), which by the Gauss-Lucas theorem also
    bounds the roots of every derivative, so the two unbounded intervals are closed at -B, B.

    Accuracy: the roots of p'' and below (interval ends only) to ~1e-9 relative (last Halley step
    <= REAL6_TOL_CRIT = 1e-3, cubic convergence); those of p' (the sextic's critical points, which
    decide near-double roots) and of p to the rounding level (last step <= REAL6_TOL_ROOT = 1e-6):
    |x - x*| <~ u |x*| cond(x*), cond = sum|a_j||x*|^j / |x* p'(x*)| the condition number with
    respect to the coefficients; |p(x)| <~ 16 u sum|a_j||x|^j (tests/dem/test_roots.py;
    measured <= 3.4 u).  As good as or better than the companion-matrix eigenvalues (backward
    stable for the balanced matrix, not the coefficients; on the packed scene's sextics the two
    agree to 1e-13 relative).  An interval end off by delta changes p at it by ~ p'' delta^2,
    far below the rounding bound used to sign it.
    A near-double root (a close real pair, or a complex pair with Im below ~ sqrt(u)) comes back
    as the critical point between them (or as the pair), to ~ sqrt(u), the inherent limit, the
    same as the eigenvalue route's.  A root of multiplicity >= 3 (spheres give a quadruple root
    at det M = 0, which the contact's selection rejects) may come back as several points within
    ~ u^(1/4) of it, as the eigenvalues do.
    No failure mode: every bracket converges (bisection) within REAL6_MAXIT steps.
    """
    a6 = w[6]
    # Fujiwara with t^(1/k) bounded above by square roots only: t^(1/3) <= max(t^(1/2), t^(1/4)),
    # t^(1/5) and t^(1/6) <= max(t^(1/4), t^(1/8))
    B = abs(w[5] / a6)
    B = max(B, np.sqrt(abs(w[4] / a6)))
    t = np.sqrt(abs(w[3] / a6))
    B = max(B, t, np.sqrt(t))
    B = max(B, np.sqrt(np.sqrt(abs(w[2] / a6))))
    t = np.sqrt(np.sqrt(abs(w[1] / a6)))
    B = max(B, t, np.sqrt(t))
    t = np.sqrt(np.sqrt(abs(0.5 * w[0] / a6)))
    B = max(B, t, np.sqrt(t))
    B = 2.0 * B * (1.0 + 1e-6) + 1e-300
    # derivative chain: p^(k) at REAL6_LEVEL[6 - k], down to the linear one, zero-padded
    for d in range(5, 0, -1):
        o = REAL6_LEVEL[d]
        oh = REAL6_LEVEL[d + 1]
        for j in range(d + 1):
            w[o + j] = (j + 1) * w[oh + j + 1]
        for j in range(d + 1, 7):
            w[o + j] = 0.0
    # quadratic level c0 + c1 x + c2 x^2: stable closed form (a double root, disc == 0, once)
    o2 = REAL6_LEVEL[2]
    c0 = w[o2]
    c1 = w[o2 + 1]
    c2 = w[o2 + 2]
    b = REAL6_BUF[0]
    disc = c1 * c1 - 4.0 * c2 * c0
    m = 0
    if disc > 0.0:
        q = -0.5 * (c1 + (np.sqrt(disc) if c1 >= 0.0 else -np.sqrt(disc)))
        r0 = q / c2
        r1 = c0 / q if q != 0.0 else r0
        w[b] = min(r0, r1)
        w[b + 1] = max(r0, r1)
        m = 2
    elif disc == 0.0:
        w[b] = -0.5 * c1 / c2
        m = 1
    for d in range(3, 7):
        m = _level_roots(w, d, REAL6_BUF[(d + 1) % 2], m, REAL6_BUF[d % 2], B,
                         REAL6_TOL_ROOT if d >= 5 else REAL6_TOL_CRIT)
    return m


@njit(cache=True)
def real_roots6(p):
    """Real roots of the sextic sum_k p[k] x^k (p [7], p[6] != 0, finite), ascending: a new array
    (real_roots6_into on a fresh work array; for tests and callers outside the kernels)."""
    w = np.zeros(REAL6_WORK)
    for k in range(7):
        w[k] = p[k]
    m = real_roots6_into(w)
    return w[REAL6_ROOTS:REAL6_ROOTS + m].copy()
