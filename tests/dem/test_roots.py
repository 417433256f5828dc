"""dem.contact.roots.poly_roots (companion matrix, NR balanc + hqr) against numpy's np.roots
(companion matrix eigenvalues by LAPACK geev) and against constructed roots.

poly_roots takes ascending powers, np.roots descending: np.roots(p[::-1]).  Roots are compared as
multisets: each root of poly_roots is matched to the nearest unused expected root.
"""
import numpy as np
import pytest
from numba import njit

from dem.contact.roots import poly_roots


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
