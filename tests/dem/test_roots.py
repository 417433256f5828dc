"""dem.contact.roots.poly_roots (companion matrix, NR balanc + hqr) and real_roots6 (real roots of a
sextic by derivative-chain isolation + safeguarded Halley) against numpy's np.roots (companion
matrix eigenvalues by LAPACK geev) and against constructed roots.

poly_roots takes ascending powers, np.roots descending: np.roots(p[::-1]).  Roots are compared as
multisets: each root of poly_roots is matched to the nearest unused expected root.
"""
import numpy as np
import pytest
from numba import njit

from dem.contact.roots import poly_roots, real_roots6


def match_err(re, im, expected):
    """Largest |z - z_expected| / max(1, |z_expected|) over a greedy nearest matching."""
    z = re + 1j * im
    expected = np.asarray(expected, dtype=complex)
    assert z.shape == expected.shape
    used = np.zeros(expected.shape[0], dtype=bool)
    worst = 0.0
    for zk in z[np.argsort(-np.abs(z))]:
        d = np.abs(expected - zk)
        d[used] = np.inf
        j = int(np.argmin(d))
        used[j] = True
        worst = max(worst, d[j] / max(1.0, abs(expected[j])))
    return worst


def test_random_sextics_match_numpy():
    """(a) 200 degree-6 polynomials with N(0, 1) coefficients (seed 0): poly_roots converges
    (ok = 1), returns 6 roots, complex roots in conjugate pairs, and each root agrees with
    np.roots (LAPACK geev, the expected numbers) to 1e-9 relative to max(1, |root|)."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = rng.normal(size=7)
        re, im, ok = poly_roots(p)
        assert ok == 1
        assert re.shape == (6,) and im.shape == (6,)
        z = re + 1j * im
        assert match_err(z.real, -z.imag, z) == 0.0           # closed under conjugation
        assert match_err(re, im, np.roots(p[::-1])) <= 1e-9


CASES = [
    # (roots, leading coefficient); complex roots listed with their conjugates
    ([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 1.0),
    ([-0.5, 0.25, 1 + 2j, 1 - 2j, -3 + 0.5j, -3 - 0.5j], 2.5),
    ([1e-3, -1e-2, 1e-1, 1.0, -1e1, 1e3], -0.7),                  # spread 1e-3 .. 1e3
    ([1e-3 + 1e-3j, 1e-3 - 1e-3j, 5.0, -5.0, 1e3 + 2e2j, 1e3 - 2e2j], 1e-4),
    ([0.0, 0.5, 1.0, -2.0, 3j, -3j], 3.0),                        # a zero root (p[0] = 0)
    ([2j, -2j, 1 + 1j, 1 - 1j, -1 + 1j, -1 - 1j], 1.0),           # no real root
]


@pytest.mark.parametrize("roots, lead", CASES)
def test_constructed_roots(roots, lead):
    """(b) p = lead * prod (x - r_k) built with np.poly from known roots (the expected numbers),
    including complex-conjugate pairs and magnitudes 1e-3 .. 1e3: poly_roots returns the known
    roots to 1e-9 relative to max(1, |r|) (the polynomial's coefficients are exact to rounding;
    these roots are well conditioned at that level) and agrees with np.roots to 1e-9."""
    p = (lead * np.real(np.poly(roots)))[::-1].copy()           # ascending powers
    re, im, ok = poly_roots(p)
    assert ok == 1
    assert match_err(re, im, roots) <= 1e-9
    assert match_err(re, im, np.roots(p[::-1])) <= 1e-9


DROPS = {                           # degree -> roots (conjugate pairs kept whole)
    5: [1.0, -2.0, 0.5, 3 + 1j, 3 - 1j],
    4: [1.0, -2.0, 3 + 1j, 3 - 1j],
    3: [1.0, -2.0, 0.5],
    2: [1e-3, 1e3],
    1: [-0.25],
}


@pytest.mark.parametrize("deg", list(DROPS))
def test_degree_drops(deg):
    """(c) Exactly-zero leading coefficients lower the degree (as np.roots, which strips them): the
    coefficients of prod (x - r_k) over DROPS[deg] (np.poly; the expected numbers) padded with
    6 - deg zeros to length 7 give deg roots, equal to the constructed ones and to np.roots
    (second oracle) to 1e-9 relative to max(1, |r|)."""
    roots = DROPS[deg]
    p = np.zeros(7)
    p[:deg + 1] = np.real(np.poly(roots))[::-1]
    re, im, ok = poly_roots(p)
    assert ok == 1
    assert re.shape == (deg,)
    assert match_err(re, im, roots) <= 1e-9
    assert match_err(re, im, np.roots(p[::-1])) <= 1e-9


def test_double_roots():
    """A double root is ill conditioned: any backward-stable method (geev included) finds it only to
    ~sqrt(eps) ~ 1.5e-8 relative.  (x - 2)^2 (x + 1)^2 x^2 (np.poly; expected numbers 2, 2, -1, -1,
    0, 0; p[0] = p[1] = 0 exactly): the roots agree with the constructed ones to 1e-7 and come out
    (nearly) real, |Im| <= 1e-7."""
    roots = [2.0, 2.0, -1.0, -1.0, 0.0, 0.0]
    p = np.real(np.poly(roots))[::-1].copy()
    re, im, ok = poly_roots(p)
    assert ok == 1
    assert match_err(re, im, roots) <= 1e-7
    assert np.abs(im).max() <= 1e-7


def test_constant_and_nonfinite():
    """A constant / zero polynomial has no roots (empty arrays, ok = 1, as np.roots gives an empty
    array); a non-finite coefficient is reported as a failure (ok = 0), never a hang."""
    for p in (np.array([3.0, 0.0, 0.0]), np.zeros(7), np.array([2.0])):
        re, im, ok = poly_roots(p)
        assert ok == 1 and re.shape == (0,) and im.shape == (0,)
    for bad in (np.inf, np.nan):
        p = np.array([1.0, bad, 2.0, 1.0])
        assert poly_roots(p)[2] == 0


@njit(cache=False)
def _call_from_njit(p):
    re, _, ok = poly_roots(p)
    return re.shape[0], ok


def test_callable_from_njit():
    """poly_roots compiles inside another @njit function (its use in the sextic contact kernel)."""
    assert _call_from_njit(np.array([-6.0, 11.0, -6.0, 1.0])) == (3, 1)


# ---------------------------------------------------------------- real_roots6
U = 2.0 ** -53


def real_of(z, tol_im):
    """The roots of z [complex] with |Im| <= tol_im max(1, |z|), real parts ascending."""
    z = np.asarray(z, dtype=complex)
    return np.sort(z[np.abs(z.imag) <= tol_im * np.maximum(1.0, np.abs(z))].real)


def residual_ok(p, x, k=16.0):
    """|p(x)| within k u sum_j |p_j| |x|^j (Horner's rounding bound is gamma_12 ~ 12 u of it)."""
    e = sum(abs(c) * abs(x) ** j for j, c in enumerate(p))
    return abs(np.polynomial.polynomial.polyval(x, p)) <= k * U * e


def test_real_roots6_random_sextics_match_numpy():
    """2000 sextics with N(0, 1) coefficients (seed 0): real_roots6 returns exactly the real roots
    of np.roots (|Im| <= 1e-7 max(1, |z|); no root of these has 1e-12 < |Im| < 1e-5, so the real set
    is unambiguous), ascending, each to 1e-9 relative to max(1, |r|) (the np.roots tolerance above),
    with |p(x)| at the rounding level (<= 16 u sum |p_j||x|^j)."""
    rng = np.random.default_rng(0)
    for _ in range(2000):
        p = rng.normal(size=7)
        r = real_roots6(p)
        z = np.roots(p[::-1])
        assert not np.any((np.abs(z.imag) > 1e-12) & (np.abs(z.imag) < 1e-5))
        expected = real_of(z, 1e-7)
        assert r.shape == expected.shape
        assert np.all(np.diff(r) >= 0.0)
        assert np.all(np.abs(r - expected) <= 1e-9 * np.maximum(1.0, np.abs(expected)))
        assert all(residual_ok(p, x) for x in r)


@pytest.mark.parametrize("roots, lead", CASES)
def test_real_roots6_constructed(roots, lead):
    """The CASES above (np.poly from known roots, magnitudes 1e-3 .. 1e3, complex pairs, a zero root,
    no real root): real_roots6 returns the known real roots, ascending, to 1e-9 relative to
    max(1, |r|)."""
    p = (lead * np.real(np.poly(roots)))[::-1].copy()
    expected = real_of(roots, 0.0)
    r = real_roots6(p)
    assert r.shape == expected.shape
    assert np.all(np.abs(r - expected) <= 1e-9 * np.maximum(1.0, np.abs(expected)))


@pytest.mark.parametrize("roots", [
    [2.0, 2.0, -1.0, -1.0, 0.0, 0.0],                  # three exact double roots (p[0] = p[1] = 0)
    [1.0, 1.0 + 1e-9, 3.0, 3.0 + 1e-7, -2.0, -5.0],    # two near-double pairs, two simple roots
    [0.3, 0.3, -4.0, 7.0, 1 + 1e-10j, 1 - 1e-10j],     # a double root and a complex pair Im 1e-10
])
def test_real_roots6_near_double_roots(roots):
    """Near-double roots (ill conditioned: any method finds them to ~sqrt(u) ~ 1.5e-8 relative; the
    companion matrix gives them as a real pair or as a pair with Im ~ 1e-8): each comes back, once
    or twice, within 1e-7 relative of the constructed value (np.poly; a complex pair with |Im| =
    1e-10 < sqrt(u) counts as a double real root), every returned root is within 1e-7 of a
    constructed real (or near-real) root, and the simple roots to 1e-9."""
    p = np.real(np.poly(roots))[::-1].copy()
    expected = np.asarray(roots, dtype=complex)
    expected = np.unique(expected.real[np.abs(expected.imag) <= 1e-8])
    r = real_roots6(p)
    assert 1 <= r.shape[0] <= 6 and np.all(np.diff(r) >= 0.0)
    for x in r:
        assert np.min(np.abs(expected - x) / np.maximum(1.0, np.abs(expected))) <= 1e-7
    for e in expected:
        d = np.min(np.abs(r - e)) / max(1.0, abs(e))
        assert d <= 1e-7
        if np.sum(np.abs(np.asarray(roots) - e) < 1e-6) == 1:         # a simple root
            assert d <= 1e-9


def test_real_roots6_callable_from_njit():
    """real_roots6 compiles inside another @njit function."""
    @njit(cache=False)
    def call(p):
        return real_roots6(p).shape[0]
    assert call(np.real(np.poly([1.0, 2.0, 3.0, 1j, -1j, 5.0]))[::-1].copy()) == 4
