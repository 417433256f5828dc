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
