"""Exact ellipsoid contact geometry (dem.contact.ellipsoid) and elliptical-Hertz factor
(dem.contact.hertz_factor).

Oracles are those of the contact-mechanics reference (docs/contact-mechanics.md):
§1.4 (support-function penetration depth, wall closed form), §1.6 (constructed-depth pairs),
§3.1 (Johnson's curvature sums, f_H table) and the §5 test table (T5-T9, T11, T12).

Depth accuracy target (project issue): |depth error| <= 1e-9 a_max + 1e-6 delta, normal <= 1e-6 rad.
Float floor (reference §1.5 item 6): depth is a difference of O(a_max) numbers, so every "exact"
comparison carries an absolute allowance of a few tens of ulp of a_max (or of |c| for T8).
"""
import os
import subprocess
import sys
import zlib

import numpy as np
import pytest
from scipy.optimize import brentq, minimize
from scipy.spatial.transform import Rotation
from scipy.special import ellipe, ellipkm1

from dem.contact import ellipsoid as E
from dem.contact.ellipsoid import ellipsoid_contact, ellipsoid_wall_contact
from dem.contact.hertz_factor import contact_ellipse_ratio, hertz_factor

EPS = np.finfo(np.float64).eps
A = 1e-3            # length scale [m]: shapes below are in units of A (mm-size grains)

# name: (semi-axes 1, semi-axes 2, normal mode); "face2" = normal along body 2's short axis
SHAPES = {
    "triaxial_1_0.8_0.6": ((1.0, 0.8, 0.6), (1.0, 0.8, 0.6), None),
    "needle_20_1_1": ((1.0, 0.05, 0.05), (1.0, 0.05, 0.05), None),
    "disk_1_1_0.05": ((1.0, 1.0, 0.05), (1.0, 1.0, 0.05), None),
    "needle_vs_disk": ((1.0, 0.05, 0.05), (1.0, 1.0, 0.05), None),
    "sphere_vs_ellipsoid": ((0.5, 0.5, 0.5), (1.0, 0.8, 0.6), None),
    "sphere_vs_disk_face": ((0.3, 0.3, 0.3), (1.0, 1.0, 0.05), "face2"),
}
REL_DEPTHS = (1e-7, 1e-5, 1e-3, 1e-2)      # delta / a_min (a_min over both bodies)


# ---------------------------------------------------------------- helpers (numpy, test side)
def shape_matrix(rot, ax):
    return rot @ np.diag(np.asarray(ax, dtype=float) ** 2) @ rot.T


def support(c, rot, ax, n):
    """s(n) = c + Q n / sqrt(n^T Q n) (reference §1.1)."""
    q = shape_matrix(rot, ax)
    return c + q @ n / np.sqrt(n @ q @ n)


def construct(ax1, ax2, rel, rng, mode=None, scale=A):
    """Reference §1.6: c2 = c1 + Q1 n/h1(n) + Q2 n/h2(n) - delta n; delta = rel * a_min.

    For delta < rho1 + rho2 (rho_i = c_i^2/a_i, the smallest radii of curvature) the Minkowski
    body has rolling-ball radius > delta, so delta IS the penetration depth, n the normal and
    s1(n), s2(-n) the contact points.  rel < 0 builds a gap of |delta| along n.
    """
    ax1 = scale * np.asarray(ax1, dtype=float)
    ax2 = scale * np.asarray(ax2, dtype=float)
    r1 = Rotation.random(random_state=rng).as_matrix()
    r2 = Rotation.random(random_state=rng).as_matrix()
    if mode == "face2":
        n = -r2[:, 2] * rng.choice([-1.0, 1.0])
    else:
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
    delta = rel * min(ax1.min(), ax2.min())
    assert delta < ax1.min() ** 2 / ax1.max() + ax2.min() ** 2 / ax2.max()
    c1 = rng.uniform(0.0, 20 * scale, 3)
    p1 = support(c1, r1, ax1, n)
    q2 = shape_matrix(r2, ax2)
    c2 = p1 + q2 @ n / np.sqrt(n @ q2 @ n) - delta * n
    p2 = support(c2, r2, ax2, -n)
    return dict(c1=c1, rot1=r1, ax1=ax1, c2=c2, rot2=r2, ax2=ax2, n=n, delta=delta, p1=p1, p2=p2)


def solve(p, lam0=-1.0, n0=None, **over):
    """Run ellipsoid_contact on pair dict p (fields overridable); returns (hit, out copy)."""
    q = dict(p, **over)
    out = np.full(E.OUT_LEN, np.nan)
    n0 = np.zeros(3) if n0 is None else np.asarray(n0, dtype=float)
    hit = ellipsoid_contact(q["c1"], q["rot1"], q["ax1"], q["c2"], q["rot2"], q["ax2"],
                            float(lam0), n0, out)
    return hit, out


def normal(out):
    return out[E.OUT_NX:E.OUT_NZ + 1]


def p1_of(out):
    return out[E.OUT_P1X:E.OUT_P1Z + 1]


def p2_of(out):
    return out[E.OUT_P2X:E.OUT_P2Z + 1]


def angle(u, v):
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))


# ---------------------------------------------------------------- T5: sphere limit
@pytest.mark.parametrize("rel", [1e-3, 1e-2, 1e-1])
def test_T5_sphere_limit(rel):
    """Spheres passed as ellipsoids (a = b = c): delta = r1 + r2 - |R|, n = R-hat, and PW
    converges in one iteration because lambda0 = h1/(h1 + h2) = r1/(r1 + r2) is its exact
    maximiser.  Tolerance (reference §5 T5): 1e-13 relative or 20 ulp(r) absolute."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        r1, r2 = A * rng.uniform(0.3, 1.0, 2)
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
        c1 = rng.uniform(0.0, 20 * A, 3)
        c2 = c1 + (r1 + r2 - rel * min(r1, r2)) * n
        p = dict(c1=c1, rot1=Rotation.random(random_state=rng).as_matrix(), ax1=np.full(3, r1),
                 c2=c2, rot2=Rotation.random(random_state=rng).as_matrix(), ax2=np.full(3, r2))
        hit, out = solve(p)
        R = c2 - c1
        expected = r1 + r2 - np.linalg.norm(R)
        assert hit == 1
        tol = max(1e-13 * expected, 20 * np.spacing(max(r1, r2)))
        assert abs(out[E.OUT_DEPTH] - expected) <= tol
        assert angle(normal(out), R / np.linalg.norm(R)) <= 1e-14
        assert out[E.OUT_PW_ITERS] == 1
        assert out[E.OUT_RE] == pytest.approx(r1 * r2 / (r1 + r2), rel=1e-13)
        assert out[E.OUT_KRATIO] == pytest.approx(1.0, abs=1e-12)


# ---------------------------------------------------------------- T6: constructed depths
@pytest.mark.parametrize("shape", list(SHAPES))
def test_T6_constructed_depth(shape):
    """Reference §1.6 construction (T6): depth, normal and common-normal points are known
    exactly.  Required: |depth error| <= 1e-9 a_max + 1e-6 delta, normal within 1e-6 rad,
    p1, p2 within 1e-9 a_max of s1(n), s2(-n); iteration budgets of T6 (PW <= 25, sphere-Newton
    <= 4 evaluations) for aspect ratios up to 20:1."""
    ax1, ax2, mode = SHAPES[shape]
    rng = np.random.default_rng(zlib.crc32(shape.encode()))
    for rel in REL_DEPTHS:
        for _ in range(60):
            p = construct(ax1, ax2, rel, rng, mode)
            amax = max(p["ax1"].max(), p["ax2"].max())
            hit, out = solve(p)
            assert hit == 1, (shape, rel)
            assert np.all(np.isfinite(out))
            assert abs(out[E.OUT_DEPTH] - p["delta"]) <= 1e-9 * amax + 1e-6 * p["delta"]
            assert angle(normal(out), p["n"]) <= 1e-6
            assert np.linalg.norm(p1_of(out) - p["p1"]) <= 1e-9 * amax
            assert np.linalg.norm(p2_of(out) - p["p2"]) <= 1e-9 * amax
            xc = out[E.OUT_XCX:E.OUT_XCZ + 1]
            assert np.allclose(xc, 0.5 * (p["p1"] + p["p2"]), rtol=0, atol=1e-9 * amax)
            assert 0.0 < out[E.OUT_LAM] < 1.0
            assert 1 <= out[E.OUT_PW_ITERS] <= 25
            assert 1 <= out[E.OUT_NEWTON_ITERS] <= 4
            assert out[E.OUT_RE] > 0.0 and out[E.OUT_KRATIO] >= 1.0


def test_T6_depth_accuracy_at_float_floor():
    """Reference §1.5/§5 T6: the depth error sits at the float64 floor, |error| <= 20 eps a_max
    (plus the round-off of the construction itself, ~eps |c|), over all shapes and depths."""
    rng = np.random.default_rng(66)
    worst = 0.0
    for ax1, ax2, mode in SHAPES.values():
        for rel in REL_DEPTHS:
            for _ in range(20):
                p = construct(ax1, ax2, rel, rng, mode)
                amax = max(p["ax1"].max(), p["ax2"].max())
                hit, out = solve(p)
                assert hit == 1
                err = abs(out[E.OUT_DEPTH] - p["delta"]) / (EPS * (amax + np.abs(p["c2"]).max()))
                worst = max(worst, err)
    assert worst <= 20.0


@pytest.mark.parametrize("shape", list(SHAPES))
def test_no_false_contact_at_gap(shape):
    """Same construction with delta = -1e-4 a_min (a gap along n): the PW certificate
    F(lambda) > 1 (or a separating axis phi(n) < 0) must report no contact, cold and warm."""
    ax1, ax2, mode = SHAPES[shape]
    rng = np.random.default_rng(7)
    for _ in range(60):
        p = construct(ax1, ax2, -1e-4, rng, mode)
        assert solve(p)[0] == 0
        assert solve(p, lam0=0.5, n0=p["n"])[0] == 0


# ---------------------------------------------------------------- T7: aligned prolate cases
PA, PB = 5.0, 1.0          # prolate (a, b, b), reference §5 T7


def _prolate_pair(c2, rot2=np.eye(3)):
    return dict(c1=np.zeros(3), rot1=np.eye(3), ax1=np.array([PA, PB, PB]),
                c2=np.asarray(c2, dtype=float), rot2=np.asarray(rot2, dtype=float),
                ax2=np.array([PA, PB, PB]))


CROSSED = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])   # body x -> world z


@pytest.mark.parametrize("case", ["tip", "side", "crossed"])
def test_T7_aligned_prolate(case):
    """Reference §5 T7, a = 5, b = 1, delta = 1e-3:
    tip-to-tip along x: delta = 2a - |R|, R_e = b^2/(2a) = 0.1, circular (kratio 1);
    side-by-side parallel: delta = 2b - |R|, R_e = a/2 = 2.5, kratio = a^2/b^2 = 25;
    crossed at 90 deg: delta = 2b - |R|, R_e = a^2 b/(a^2 + b^2) = 0.96154, kratio 1.
    All to 1e-12 relative: the aligned geometry has no cancellation (curvatures are sums of
    positive body-frame terms), so R_e and kratio are as tight as the depth."""
    d = 1e-3
    if case == "tip":
        p = _prolate_pair([2 * PA - d, 0.0, 0.0])
        n_exp, re_exp, kr_exp, dist = [1.0, 0.0, 0.0], PB ** 2 / (2 * PA), 1.0, 2 * PA
    elif case == "side":
        p = _prolate_pair([0.0, 2 * PB - d, 0.0])
        n_exp, re_exp, kr_exp, dist = [0.0, 1.0, 0.0], PA / 2, PA ** 2 / PB ** 2, 2 * PB
    else:
        p = _prolate_pair([0.0, 2 * PB - d, 0.0], CROSSED)
        n_exp, re_exp, kr_exp, dist = [0.0, 1.0, 0.0], PA ** 2 * PB / (PA ** 2 + PB ** 2), 1.0, 2 * PB
    hit, out = solve(p)
    assert hit == 1
    expected = dist - np.linalg.norm(p["c2"] - p["c1"])
    assert out[E.OUT_DEPTH] == pytest.approx(expected, rel=1e-12)
    assert np.allclose(normal(out), n_exp, rtol=0, atol=1e-15)
    assert out[E.OUT_RE] == pytest.approx(re_exp, rel=1e-12)
    assert out[E.OUT_KRATIO] == pytest.approx(kr_exp, rel=1e-12)


@pytest.mark.parametrize("alpha_deg", [0.0, 15.0, 30.0, 45.0, 60.0, 89.0])
def test_T7_crossed_prolate_johnson(alpha_deg):
    """Side-by-side prolates (a = 5, b = 1) whose axes make an angle alpha: Johnson §4.2
    (reference §3.1): A + B = (1/2) sum of principal curvatures, B - A = (1/2) sqrt(d1^2 + d2^2
    + 2 d1 d2 cos 2 alpha), d_i = 1/R_i'' - 1/R_i' with 1/R' = b/a^2, 1/R'' = 1/b;
    R_e = 1/(2 sqrt(AB)), kratio = B/A.  Endpoints 0 and 90 deg are the T7 values."""
    al = np.radians(alpha_deg)
    rot2 = Rotation.from_rotvec([0.0, al, 0.0]).as_matrix()     # about the common normal y
    p = _prolate_pair([0.0, 2 * PB - 1e-3, 0.0], rot2)
    hit, out = solve(p)
    assert hit == 1
    k_small, k_big = PB / PA ** 2, 1.0 / PB
    apb = 0.5 * 2 * (k_small + k_big)
    dk = k_big - k_small
    bma = 0.5 * np.sqrt(2 * dk ** 2 + 2 * dk * dk * np.cos(2 * al))
    a_, b_ = 0.5 * (apb - bma), 0.5 * (apb + bma)
    assert out[E.OUT_RE] == pytest.approx(1.0 / (2 * np.sqrt(a_ * b_)), rel=1e-12)
    assert out[E.OUT_KRATIO] == pytest.approx(b_ / a_, rel=1e-10)
    assert out[E.OUT_DEPTH] == pytest.approx(2 * PB - np.linalg.norm(p["c2"]), rel=1e-12)


# ---------------------------------------------------------------- T8: invariances
INV_SHAPES = ["triaxial_1_0.8_0.6", "needle_20_1_1", "needle_vs_disk", "sphere_vs_disk_face"]


@pytest.mark.parametrize("shape", INV_SHAPES)
def test_T8_invariances(shape):
    """Reference §5 T8 at delta = 1e-2 a_min: translation by 1e3 a_max changes delta by at
    most ~eps |c| (the round-off of R = c2 - c1); a rigid rotation of both bodies leaves delta
    invariant and rotates n; swapping the bodies keeps delta, flips n, swaps p1 <-> p2 and maps
    lambda -> 1 - lambda.  'Invariant' = 1e-12 relative plus the float floor 20 eps a_max."""
    ax1, ax2, mode = SHAPES[shape]
    rng = np.random.default_rng(8)
    for _ in range(30):
        p = construct(ax1, ax2, 1e-2, rng, mode)
        amax = max(p["ax1"].max(), p["ax2"].max())
        floor = 1e-12 * p["delta"] + 20 * EPS * amax
        hit, out = solve(p)
        assert hit == 1
        d0, n0 = out[E.OUT_DEPTH], normal(out).copy()
        # translation
        t = rng.standard_normal(3)
        t *= 1e3 * amax / np.linalg.norm(t)
        hit, o = solve(p, c1=p["c1"] + t, c2=p["c2"] + t)
        assert hit == 1
        assert abs(o[E.OUT_DEPTH] - d0) <= floor + 10 * EPS * np.abs(p["c2"] + t).max()
        assert angle(normal(o), n0) <= 1e-9
        # rigid rotation about the origin
        m = Rotation.random(random_state=rng).as_matrix()
        hit, o = solve(p, c1=m @ p["c1"], c2=m @ p["c2"], rot1=m @ p["rot1"], rot2=m @ p["rot2"])
        assert hit == 1
        assert abs(o[E.OUT_DEPTH] - d0) <= floor
        assert angle(normal(o), m @ n0) <= 1e-10
        # swap bodies
        hit, o = solve(p, c1=p["c2"], rot1=p["rot2"], ax1=p["ax2"],
                       c2=p["c1"], rot2=p["rot1"], ax2=p["ax1"])
        assert hit == 1
        assert abs(o[E.OUT_DEPTH] - d0) <= floor
        assert angle(normal(o), -n0) <= 1e-10
        assert np.linalg.norm(p1_of(o) - p2_of(out)) <= 1e-10 * amax
        assert np.linalg.norm(p2_of(o) - p1_of(out)) <= 1e-10 * amax
        assert o[E.OUT_LAM] == pytest.approx(1.0 - out[E.OUT_LAM], abs=1e-12)
        assert o[E.OUT_RE] == pytest.approx(out[E.OUT_RE], rel=1e-10)


# ---------------------------------------------------------------- T9: separation certificate
@pytest.mark.parametrize("shape", list(SHAPES))
def test_T9_separation_certificate(shape):
    """Reference §5 T9: from a constructed overlap delta = 1e-3 a_min, moving body 2 by
    (1 + 1e-6) delta n opens a gap of 1e-6 delta -> no contact; (1 - 1e-6) delta n leaves an
    overlap of 1e-6 delta -> contact with that depth (to the float floor 20 eps a_max).
    Exact decisions since delta >> 1e6 eps a_max.  Checked cold and warm-started."""
    ax1, ax2, mode = SHAPES[shape]
    rng = np.random.default_rng(9)
    for _ in range(40):
        p = construct(ax1, ax2, 1e-3, rng, mode)
        amax = max(p["ax1"].max(), p["ax2"].max())
        for n0 in (None, p["n"]):
            c2 = p["c2"] + (1 + 1e-6) * p["delta"] * p["n"]
            assert solve(p, n0=n0, c2=c2)[0] == 0
            c2 = p["c2"] + (1 - 1e-6) * p["delta"] * p["n"]
            hit, out = solve(p, n0=n0, c2=c2)
            assert hit == 1
            assert abs(out[E.OUT_DEPTH] - 1e-6 * p["delta"]) <= 20 * EPS * amax


# ---------------------------------------------------------------- robustness (extreme shapes)
def test_extreme_shapes_robust():
    """Reference §1.5 stress set: needle 50:1:1, disk 1:1:0.02, needle vs disk, r = 0.01 sphere
    vs disk, near-parallel needles, delta/a_min random in [1e-9, 1e-3]: always finite, always
    found, accurate to 1e-9 a_max + 1e-6 delta (normal 1e-6 rad); plus degenerate inputs
    (concentric bodies, far apart, exact touching) never give NaN."""
    rng = np.random.default_rng(11)
    cases = [((1.0, 0.02, 0.02), (1.0, 0.02, 0.02)), ((1.0, 1.0, 0.02), (1.0, 1.0, 0.02)),
             ((1.0, 0.02, 0.02), (1.0, 1.0, 0.02)), ((0.01, 0.01, 0.01), (1.0, 1.0, 0.02))]
    for ax1, ax2 in cases:
        for _ in range(100):
            p = construct(ax1, ax2, 10 ** rng.uniform(-9, -3), rng)
            amax = max(p["ax1"].max(), p["ax2"].max())
            hit, out = solve(p)
            assert hit == 1 and np.all(np.isfinite(out))
            assert abs(out[E.OUT_DEPTH] - p["delta"]) <= 1e-9 * amax + 1e-6 * p["delta"]
            assert angle(normal(out), p["n"]) <= 1e-6
            assert out[E.OUT_PW_ITERS] <= 25 and out[E.OUT_NEWTON_ITERS] <= 6
    # near-parallel needles, side by side (normal perpendicular to both axes)
    for _ in range(100):
        ax = A * np.array([1.0, 0.02, 0.02])
        r1 = Rotation.random(random_state=rng).as_matrix()
        tilt = Rotation.from_rotvec(r1[:, 1] * 10 ** rng.uniform(-8, -2)).as_matrix()
        r2 = tilt @ r1
        n = r1[:, 1]
        delta = 10 ** rng.uniform(-9, -3) * ax.min()
        c1 = np.zeros(3)
        c2 = support(c1, r1, ax, n) + shape_matrix(r2, ax) @ n / np.sqrt(
            n @ shape_matrix(r2, ax) @ n) - delta * n
        p = dict(c1=c1, rot1=r1, ax1=ax, c2=c2, rot2=r2, ax2=ax)
        hit, out = solve(p)
        assert hit == 1 and np.all(np.isfinite(out))
        assert abs(out[E.OUT_DEPTH] - delta) <= 1e-9 * A + 1e-6 * delta
        assert angle(normal(out), n) <= 1e-6
    # degenerate inputs
    ax1, ax2 = A * np.array([1.0, 0.5, 0.2]), A * np.array([0.7, 0.7, 0.1])
    r1 = Rotation.random(random_state=rng).as_matrix()
    r2 = Rotation.random(random_state=rng).as_matrix()
    p = dict(c1=np.ones(3) * A, rot1=r1, ax1=ax1, c2=np.ones(3) * A, rot2=r2, ax2=ax2)
    hit, out = solve(p)                                   # concentric
    assert hit == 1 and np.all(np.isfinite(out)) and out[E.OUT_DEPTH] > 0
    assert solve(p, c2=p["c1"] + 5 * A)[0] == 0           # far apart
    p = dict(c1=np.zeros(3), rot1=np.eye(3), ax1=np.full(3, A), c2=np.array([2 * A, 0, 0]),
             rot2=np.eye(3), ax2=np.full(3, A))
    assert solve(p)[0] == 0                               # exactly touching: depth 0


# ---------------------------------------------------------------- warm start
@pytest.mark.parametrize("shape", list(SHAPES))
def test_warm_start_matches_cold(shape):
    """Warm start (previous lambda*, n*) after a small relative motion gives the cold-start
    answer to float tolerance (delta to 1e-12 rel + 20 eps a_max, n to 1e-9 rad) and normally
    skips PW (OUT_PW_ITERS = 0, certified by the rolling-ball bound).  Bad warm starts
    (reversed or random n0, stale lambda0) fall back to the cold path and agree too.
    Results are pure functions of the inputs (bitwise repeatable)."""
    ax1, ax2, mode = SHAPES[shape]
    rng = np.random.default_rng(12)
    skipped = hits = 0
    for _ in range(40):
        p = construct(ax1, ax2, 10 ** rng.uniform(-6, -2), rng, mode)
        amax = max(p["ax1"].max(), p["ax2"].max())
        hit, prev = solve(p)
        assert hit == 1
        # next step: body 2 moved by ~1e-2 delta and turned by ~1e-2 delta / a_max
        c2 = p["c2"] + 1e-2 * p["delta"] * rng.standard_normal(3) / np.sqrt(3)
        turn = 1e-2 * p["delta"] / amax * rng.standard_normal(3) / np.sqrt(3)
        rot2 = Rotation.from_rotvec(turn).as_matrix() @ p["rot2"]
        hit_c, cold = solve(p, c2=c2, rot2=rot2)
        hit_w, warm = solve(p, lam0=prev[E.OUT_LAM], n0=normal(prev), c2=c2, rot2=rot2)
        assert hit_c == hit_w
        if not hit_c:
            continue
        hits += 1
        tol = 1e-12 * cold[E.OUT_DEPTH] + 20 * EPS * amax
        assert abs(warm[E.OUT_DEPTH] - cold[E.OUT_DEPTH]) <= tol
        assert angle(normal(warm), normal(cold)) <= 1e-9
        assert np.linalg.norm(p1_of(warm) - p1_of(cold)) <= 1e-10 * amax
        assert warm[E.OUT_RE] == pytest.approx(cold[E.OUT_RE], rel=1e-8)
        skipped += warm[E.OUT_PW_ITERS] == 0
        for lam0, n0 in ((0.9, -normal(prev)), (0.1, rng.standard_normal(3)), (0.99, None)):
            hit_b, bad = solve(p, lam0=lam0, n0=n0, c2=c2, rot2=rot2)
            assert hit_b == 1
            assert abs(bad[E.OUT_DEPTH] - cold[E.OUT_DEPTH]) <= tol
            assert angle(normal(bad), normal(cold)) <= 1e-9
        again = solve(p, lam0=prev[E.OUT_LAM], n0=normal(prev), c2=c2, rot2=rot2)[1]
        assert np.array_equal(again, warm)
    assert hits >= 30 and skipped >= 0.9 * hits


# ---------------------------------------------------------------- walls
def _wall(c, rot, ax, m, d):
    out = np.full(E.OUT_LEN, np.nan)
    hit = ellipsoid_wall_contact(np.asarray(c, float), np.asarray(rot, float),
                                 np.asarray(ax, float), np.asarray(m, float), float(d), out)
    return hit, out


def test_wall_resting_ellipsoid_T12():
    """Reference §5 T12: quartz ellipsoid a, b, c = 0.5, 0.3, 0.2 mm resting on the floor
    z = 0 with its shortest axis vertical: delta = c - z_c, n = -m, p1 = (x, y, z - c),
    p2 = (x, y, 0), R_e = ab/c = 7.5e-4 m, kratio = (a/b)^2 = 2.7778, f_H(kratio) = 1.0217,
    static depth [3mg/(4E* sqrt(R_e) f_H)]^(2/3) = 2.001e-10 m (E* = E/(1 - nu^2), E = 29 GPa,
    nu = 0.25, m = 3.330e-7 kg).  Needle 0.5 x 0.05 x 0.05 mm lying flat: R_e = 5e-4 m,
    kratio = 100, f_H = 1.435, delta = 2.195e-11 m (2.793e-11 m without f_H)."""
    estar = 29e9 / (1 - 0.25 ** 2)
    for (a, b, c), mass, re_exp, kr_exp, fh_exp, d_exp, d_nofh in [
            ((0.5e-3, 0.3e-3, 0.2e-3), 3.330e-7, 7.5e-4, (0.5 / 0.3) ** 2, 1.0217, 2.001e-10, None),
            ((0.5e-3, 0.05e-3, 0.05e-3), None, 5e-4, 100.0, 1.435, 2.195e-11, 2.793e-11)]:
        delta = 1e-6 * c
        cen = np.array([3e-3, -2e-3, c - delta])
        hit, out = _wall(cen, np.eye(3), [a, b, c], [0.0, 0.0, 1.0], 0.0)
        assert hit == 1
        assert out[E.OUT_DEPTH] == pytest.approx(c - cen[2], abs=2 * np.spacing(c))
        assert np.array_equal(normal(out), [-0.0, -0.0, -1.0])
        assert np.allclose(p1_of(out), [3e-3, -2e-3, cen[2] - c], rtol=0, atol=1e-19)
        assert np.allclose(p2_of(out), [3e-3, -2e-3, 0.0], rtol=0, atol=1e-19)
        assert out[E.OUT_RE] == pytest.approx(re_exp, rel=1e-13)
        assert out[E.OUT_KRATIO] == pytest.approx(kr_exp, rel=1e-13)
        fh = hertz_factor(out[E.OUT_KRATIO])
        assert fh == pytest.approx(fh_exp, abs=1e-4)
        m = mass if mass is not None else 2650 * 4 / 3 * np.pi * a * b * c
        d_static = (3 * m * 9.81 / (4 * estar * np.sqrt(out[E.OUT_RE]) * fh)) ** (2 / 3)
        assert d_static == pytest.approx(d_exp, rel=1e-3)
        if d_nofh is not None:
            d0 = (3 * m * 9.81 / (4 * estar * np.sqrt(out[E.OUT_RE]))) ** (2 / 3)
            assert d0 == pytest.approx(d_nofh, rel=1e-3)


def test_wall_tilted_matches_brute_force():
    """Tilted ellipsoid vs an arbitrary plane m.x = d: the closed form delta = h(m) - (m.c - d)
    (reference §1.4) against brute force over the surface: a dense (theta, phi) sampling gives
    0 <= delta - delta_sampled <= sampling error (~(pi a / N)^2 / rho_min), and refining the best
    sample with BFGS recovers delta to 1e-12 a and the deepest point p1 to 1e-6 a."""
    rng = np.random.default_rng(13)
    th, ph = np.meshgrid(np.linspace(0, np.pi, 401), np.linspace(0, 2 * np.pi, 801),
                         indexing="ij")
    for ax in ([1.0, 0.6, 0.4], [1.0, 0.2, 0.2], [1.0, 1.0, 0.1]):
        ax = A * np.array(ax)
        for _ in range(4):
            rot = Rotation.random(random_state=rng).as_matrix()
            m = rng.standard_normal(3)
            m /= np.linalg.norm(m)
            c = rng.uniform(0, 10 * A, 3)
            d = m @ c - np.sqrt(m @ shape_matrix(rot, ax) @ m) + 1e-3 * ax.min()
            hit, out = _wall(c, rot, ax, m, d)
            assert hit == 1

            def height(t):
                body = np.array([ax[0] * np.sin(t[0]) * np.cos(t[1]),
                                 ax[1] * np.sin(t[0]) * np.sin(t[1]), ax[2] * np.cos(t[0])])
                return m @ (c + rot @ body) - d

            pts = np.stack([ax[0] * np.sin(th) * np.cos(ph), ax[1] * np.sin(th) * np.sin(ph),
                            ax[2] * np.cos(th)], axis=-1) @ rot.T + c
            hts = pts @ m - d
            k = np.unravel_index(np.argmin(hts), hts.shape)
            d_sampled = -hts[k]
            rho = ax.min() ** 2 / ax.max()
            assert 0.0 <= out[E.OUT_DEPTH] - d_sampled <= (np.pi * ax.max() / 400) ** 2 / rho
            res = minimize(height, [th[k], ph[k]], method="BFGS", options={"gtol": 1e-14})
            assert out[E.OUT_DEPTH] == pytest.approx(-res.fun, abs=1e-12 * ax.max())
            body = np.array([ax[0] * np.sin(res.x[0]) * np.cos(res.x[1]),
                             ax[1] * np.sin(res.x[0]) * np.sin(res.x[1]), ax[2] * np.cos(res.x[0])])
            assert np.linalg.norm(p1_of(out) - (c + rot @ body)) <= 1e-6 * ax.max()
            assert np.allclose(normal(out), -m, rtol=0, atol=0)
            assert abs(m @ p2_of(out) - d) <= 4 * EPS * np.abs(c).max()
            # no contact when lifted by 2 delta
            assert _wall(c + 2 * out[E.OUT_DEPTH] * m, rot, ax, m, d)[0] == 0


def test_wall_sphere_exact():
    """Sphere (r, r, r) on a wall: delta = r - (m.c - d), p1 = c - r m, R_e = r, kratio 1
    (a sphere's curvature tensor is 1/r), to a few ulp."""
    rng = np.random.default_rng(14)
    for _ in range(50):
        r = A * rng.uniform(0.2, 1.0)
        m = rng.standard_normal(3)
        m /= np.linalg.norm(m)
        c = rng.uniform(0, 10 * A, 3)
        d = m @ c - r + rng.uniform(1e-9, 1e-2) * r
        hit, out = _wall(c, Rotation.random(random_state=rng).as_matrix(), [r, r, r], m, d)
        assert hit == 1
        assert abs(out[E.OUT_DEPTH] - (r - (m @ c - d))) <= 4 * np.spacing(np.abs(c).max())
        assert np.linalg.norm(p1_of(out) - (c - r * m)) <= 4 * np.spacing(np.abs(c).max())
        assert out[E.OUT_RE] == pytest.approx(r, rel=1e-14)
        assert out[E.OUT_KRATIO] == pytest.approx(1.0, abs=1e-14)
        assert out[E.OUT_LAM] == 0.0 and out[E.OUT_PW_ITERS] == 0
    assert _wall([0, 0, 2 * A], np.eye(3), [A, A, A], [0, 0, 1.0], 0.0)[0] == 0


# ---------------------------------------------------------------- T11: elliptical Hertz factor
def _exact_hertz(k):
    """f_H and b/a from scipy's elliptic integrals (Johnson §4.2; reference §3.1)."""
    if k == 1.0:
        return 1.0, 1.0

    def ke(lr):                                   # lr = ln(b/a), m = e^2 = 1 - (b/a)^2
        p = np.exp(2 * lr)
        return ellipkm1(p), ellipe(1 - p), 1 - p

    def g(lr):
        kk, ee, m = ke(lr)
        return np.log((ee / (1 - m) - kk) / (kk - ee)) - np.log(k)

    with np.errstate(divide="ignore", invalid="ignore"):
        lr = brentq(g, -20, -1e-9, xtol=1e-15, rtol=1e-15)
    kk, ee, m = ke(lr)
    return np.pi / (2 * kk) * np.sqrt(2 * (kk - ee) * np.sqrt(k) / (kk * m)), np.exp(lr)


def test_T11_hertz_factor_table():
    """Reference §3.1 / §5 T11: f_H(B/A) = 1.0034, 1.0100, 1.0250, 1.0536, 1.1090, 1.1838,
    1.3130, 1.4351, 2.0205 at B/A = 1.5, 2, 3, 5, 10, 20, 50, 100, 1000 (to 1e-4), contact
    ellipse b/a = 0.763 ... 0.015 (to 1e-3); f_H(1) = 1 and clamping below 1."""
    table = [(1.5, 1.0034, 0.763), (2, 1.0100, 0.631), (3, 1.0250, 0.483), (5, 1.0536, 0.346),
             (10, 1.1090, 0.222), (20, 1.1838, 0.144), (50, 1.3130, 0.083),
             (100, 1.4351, 0.055), (1000, 2.0205, 0.015)]
    for k, fh, ratio in table:
        assert hertz_factor(float(k)) == pytest.approx(fh, abs=1e-4)
        assert contact_ellipse_ratio(float(k)) == pytest.approx(ratio, abs=1e-3)
    assert hertz_factor(1.0) == 1.0 and contact_ellipse_ratio(1.0) == 1.0
    assert hertz_factor(0.5) == 1.0
    # Johnson's F2 = f_H^(-2/3) = 0.933 at B/A = 10 (reference §3.1)
    assert hertz_factor(10.0) ** (-2 / 3) == pytest.approx(0.933, abs=1e-3)


def test_hertz_factor_vs_scipy():
    """The interpolated table against the exact relation evaluated with scipy's ellipk/ellipe
    (independent implementation): <= 1e-6 relative over 1 <= B/A <= 1e4 (required 1e-4)."""
    rng = np.random.default_rng(15)
    ks = np.concatenate([np.exp(rng.uniform(0, np.log(1e4), 300)), 1 + np.logspace(-6, -1, 11)])
    for k in ks:
        fh, ratio = _exact_hertz(k)
        assert hertz_factor(k) == pytest.approx(fh, rel=1e-6)
        assert contact_ellipse_ratio(k) == pytest.approx(ratio, rel=1e-6)


# ---------------------------------------------------------------- allocation-free hot path
def test_hot_path_allocation_free():
    """The kernels must not allocate per call: numba's NRT allocation counter (enabled by
    NUMBA_NRT_STATS=1 in a child process) is the same for a loop over 10 and over 1000 pairs
    (only the per-call boxing of the argument arrays counts)."""
    code = (
        "import numpy as np\n"
        "from numba.core.runtime import rtsys\n"
        "from bench.studies.perf_contact import make_pairs, _run\n"
        "from dem.contact.ellipsoid import OUT_LEN\n"
        "counts = []\n"
        "for n in (10, 1000, 1000):\n"
        "    p = make_pairs(n)\n"
        "    a = (p['c1'], p['rot1'], p['ax1'], p['c2'], p['rot2'], p['ax2'], -np.ones(n),\n"
        "         np.zeros((n, 3)), np.zeros(OUT_LEN), np.zeros((n, 3)))\n"
        "    _run(*a)\n"
        "    s0 = rtsys.get_allocation_stats().alloc\n"
        "    _run(*a)\n"
        "    counts.append(rtsys.get_allocation_stats().alloc - s0)\n"
        "print(counts[0], counts[1], counts[2])\n")
    from tests.helpers import ROOT as root
    env = dict(os.environ, NUMBA_NRT_STATS="1", PYTHONPATH=root)
    res = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    c10, c1000, again = map(int, res.stdout.split())
    assert c10 == c1000 == again
