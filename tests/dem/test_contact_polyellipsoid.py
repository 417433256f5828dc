"""Poly-ellipsoid mass properties and contact geometry (dem.contact.polyellipsoid).

Oracles are those of the contact-mechanics reference (docs/contact-mechanics.md):
§2.2 (poly-ellipsoid support function, octant active set, mass properties with the worked example),
§1.4 (support-function penetration depth, wall closed form) and §1.6 (constructed-depth pairs, here
with poly-ellipsoid support maps).

Depth accuracy target (project issue, as for ellipsoids): |depth error| <= 1e-9 a_max + 1e-6 delta,
normal <= 1e-6 rad.  Float floor (reference §1.5 item 6): depth is a difference of O(a_max) numbers.
"""
import numpy as np
import pytest
from scipy.special import roots_legendre
from scipy.spatial.transform import Rotation

from dem.contact import ellipsoid as E
from dem.contact import polyellipsoid as P
from dem.contact.ellipsoid import ellipsoid_contact
from dem.contact.polyellipsoid import (mass_properties_poly, poly_support, polyellipsoid_contact,
                                       polyellipsoid_wall_contact)

A = 1e-3            # length scale [m] (mm-size grains)
REF_AXES = np.array([1.0, 0.6, 0.7, 0.4, 0.5, 0.5])     # reference §2.2 worked example

# name: (axes6 of body 1, axes6 of body 2), in units of A
PAIRS = {
    "asym_vs_asym": ((1.0, 0.6, 0.7, 0.4, 0.5, 0.5), (0.8, 0.5, 0.6, 0.6, 0.3, 0.45)),
    "egg_vs_sphere": ((1.0, 0.3, 0.5, 0.5, 0.2, 0.4), (0.5, 0.5, 0.5, 0.5, 0.5, 0.5)),
    "needle_vs_asym": ((1.0, 0.2, 0.15, 0.15, 0.15, 0.1), (0.5, 0.8, 0.3, 0.1, 0.4, 0.2)),
    "flat_vs_asym": ((1.0, 0.7, 0.9, 0.5, 0.1, 0.08), (0.6, 0.9, 0.5, 0.3, 0.4, 0.2)),
}
REL_DEPTHS = (1e-7, 1e-5, 1e-3)      # delta / a_min (a_min over both bodies)


def _rng(seed):
    return np.random.default_rng(seed)


def _rot(rng, n=None):
    return Rotation.random(n, random_state=rng).as_matrix()


def _support_np(o, rot, a6, n):
    """Vectorised numpy support function/point (independent of the kernel): reference §2.2."""
    n = np.atleast_2d(n)
    nb = n @ rot                                   # rows: R^T n
    al = np.where(nb >= 0.0, np.array(a6)[[0, 2, 4]], np.array(a6)[[1, 3, 5]])
    h = np.sqrt(np.sum((al * nb) ** 2, axis=1))
    s = o + ((al * al * nb) / h[:, None]) @ rot.T
    return h, s


def _constructed(rng, a1, a2, delta):
    """Reference §1.6 with poly support maps: o2 = s1(n) - (s2(-n) - o2) - delta n."""
    r1 = _rot(rng)
    r2 = _rot(rng)
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    o1 = rng.normal(size=3) * A
    _, s1 = _support_np(o1, r1, a1, n)
    _, s2 = _support_np(np.zeros(3), r2, a2, -n)
    o2 = s1[0] - s2[0] - delta * n
    return o1, r1, o2, r2, n


def _surface(o, rot, a6, nu=400, nv=800):
    """Dense surface sample: octant-wise scaled unit sphere (body frame x_k = alpha_k u_k)."""
    th = (np.arange(nu) + 0.5) * np.pi / nu
    ph = np.arange(nv) * 2.0 * np.pi / nv
    th, ph = np.meshgrid(th, ph, indexing="ij")
    u = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    al = np.where(u >= 0.0, np.array(a6)[[0, 2, 4]], np.array(a6)[[1, 3, 5]])
    return o + (al * u) @ rot.T


# ------------------------------------------------------------------ mass properties

def test_mass_properties_reference_example():
    """Reference §2.2 worked example a+- = (1, 0.6), b+- = (0.7, 0.4), c+- = (0.5, 0.5), rho = 1:
    V = 0.92153, centroid (0.15, 0.1125, 0), I_c/rho = [[0.10261, 0.00147, 0], [0.00147, 0.16542, 0],
    [0, 0, 0.17587]] (5 printed decimals: tolerance 6e-6 absolute)."""
    m, cen, ip, pr = mass_properties_poly(REF_AXES, 1.0)
    assert m == pytest.approx(0.92153, abs=6e-6)
    assert m == pytest.approx(np.pi / 6 * 1.6 * 1.1 * 1.0, rel=1e-14)
    np.testing.assert_allclose(cen, [0.15, 0.1125, 0.0], atol=1e-15)
    tensor = pr @ np.diag(ip) @ pr.T
    ref = np.array([[0.10261, 0.00147, 0.0], [0.00147, 0.16542, 0.0], [0.0, 0.0, 0.17587]])
    np.testing.assert_allclose(tensor, ref, atol=6e-6)
    # principal frame: orthonormal, right-handed, close to the shape frame (small xy tilt)
    np.testing.assert_allclose(pr.T @ pr, np.eye(3), atol=1e-14)
    assert np.linalg.det(pr) == pytest.approx(1.0, abs=1e-14)
    assert np.all(np.diag(pr) > 0.99)
    # density scales mass and inertia linearly
    m2, cen2, ip2, pr2 = mass_properties_poly(REF_AXES, 2650.0)
    assert m2 == pytest.approx(2650.0 * m, rel=1e-14)
    np.testing.assert_allclose(ip2, 2650.0 * ip, rtol=1e-13)
    np.testing.assert_allclose(pr2, pr, atol=1e-14)


def _quadrature_moments(a6, nq=24):
    """Independent check: Gauss-Legendre quadrature (scipy roots_legendre) in spherical coordinates
    over each octant (x_k = alpha_k r u_k, dV = alpha beta gamma r^2 sin(theta) dr dtheta dphi).
    Returns V, first moments int x dV [3], second moments int x x^T dV [3, 3] about the octant origin."""
    xg, wg = roots_legendre(nq)
    r, wr = 0.5 * (xg + 1.0), 0.5 * wg
    t, wt = np.pi / 4 * (xg + 1.0), np.pi / 4 * wg
    p, wp = np.pi / 4 * (xg + 1.0), np.pi / 4 * wg
    R, T, PH = np.meshgrid(r, t, p, indexing="ij")
    W = np.einsum("i,j,k->ijk", wr, wt, wp) * R ** 2 * np.sin(T)
    u = np.stack([np.sin(T) * np.cos(PH), np.sin(T) * np.sin(PH), np.cos(T)], -1) * R[..., None]
    vol = 0.0
    first = np.zeros(3)
    second = np.zeros((3, 3))
    for sx in (1, -1):
        for sy in (1, -1):
            for sz in (1, -1):
                sg = np.array([sx, sy, sz])
                al = np.array([a6[0] if sx > 0 else a6[1], a6[2] if sy > 0 else a6[3],
                               a6[4] if sz > 0 else a6[5]])
                x = u * (sg * al)
                w = W * np.prod(al)
                vol += w.sum()
                first += np.einsum("ijk,ijkl->l", w, x)
                second += np.einsum("ijk,ijkl,ijkm->lm", w, x, x)
    return vol, first, second


@pytest.mark.parametrize("a6", [REF_AXES, (1.0, 0.3, 0.5, 0.5, 0.2, 0.4), (0.9, 0.5, 0.3, 0.7, 0.6, 0.2)])
def test_mass_properties_vs_quadrature(a6):
    """Closed forms (reference §2.2) against octant-wise Gauss quadrature: V, centroid and the full
    centroidal inertia tensor (including the non-zero products) agree to 1e-12 relative (quadrature
    is exact up to round-off for these polynomial-times-trig integrands with 24 nodes)."""
    rho = 3.0
    m, cen, ip, pr = mass_properties_poly(a6, rho)
    vol, first, second = _quadrature_moments(a6)
    c = first / vol
    i_ref = rho * (np.trace(second) * np.eye(3) - second) - rho * vol * (c @ c * np.eye(3) - np.outer(c, c))
    assert m == pytest.approx(rho * vol, rel=1e-12)
    np.testing.assert_allclose(cen, c, atol=1e-12)
    np.testing.assert_allclose(pr @ np.diag(ip) @ pr.T, i_ref, atol=1e-12 * np.abs(i_ref).max())


def test_mass_properties_monte_carlo():
    """Reference example against plain Monte Carlo (2e6 points in the bounding box, seed 7): volume and
    centroid within 5 standard errors (V: ~1.3e-3 relative; centroid: ~1e-3 absolute)."""
    rng = _rng(7)
    npts = 2_000_000
    lo = -REF_AXES[[1, 3, 5]]
    hi = REF_AXES[[0, 2, 4]]
    x = lo + (hi - lo) * rng.random((npts, 3))
    al = np.where(x >= 0.0, hi, -lo)
    inside = np.sum((x / al) ** 2, axis=1) <= 1.0
    box = np.prod(hi - lo)
    frac = inside.mean()
    vol_mc = box * frac
    m, cen, _, _ = mass_properties_poly(REF_AXES, 1.0)
    se_v = box * np.sqrt(frac * (1 - frac) / npts)
    assert abs(vol_mc - m) < 5 * se_v
    xin = x[inside]
    se_c = xin.std(axis=0) / np.sqrt(len(xin))
    assert np.all(np.abs(xin.mean(axis=0) - cen) < 5 * se_c + 1e-12)


def test_mass_properties_sphere_and_ellipsoid_limits():
    """Sphere (all six = a): m = (4/3) pi a^3 rho, centroid 0, I = (2/5) m a^2, principal_rot = 1.
    Ellipsoid (a+ = a-, ...): I_x = m (b^2 + c^2) / 5 etc. (textbook), principal_rot = 1."""
    a, rho = 0.7 * A, 2650.0
    m, cen, ip, pr = mass_properties_poly([a] * 6, rho)
    assert m == pytest.approx(4.0 / 3.0 * np.pi * a ** 3 * rho, rel=1e-14)
    np.testing.assert_array_equal(cen, 0.0)
    np.testing.assert_allclose(ip, 0.4 * m * a * a, rtol=1e-14)
    np.testing.assert_array_equal(pr, np.eye(3))
    ax = np.array([1.0, 0.8, 0.6]) * A
    m, cen, ip, pr = mass_properties_poly(np.repeat(ax, 2), rho)
    assert m == pytest.approx(4.0 / 3.0 * np.pi * ax.prod() * rho, rel=1e-14)
    np.testing.assert_allclose(ip, m / 5 * np.array([ax[1] ** 2 + ax[2] ** 2, ax[0] ** 2 + ax[2] ** 2,
                                                     ax[0] ** 2 + ax[1] ** 2]), rtol=1e-13)
    np.testing.assert_array_equal(pr, np.eye(3))


# ------------------------------------------------------------------ support function

def test_poly_support_matches_surface_sampling():
    """h(n) = max over the surface of n.(x - o) (definition): the kernel's h is >= the dense-sample
    maximum and exceeds it by at most the sampling error (grid pi/400: < 1e-4 a); the support point
    lies on the surface (implicit function = 1 to 1e-14) and agrees with the numpy reference map."""
    rng = _rng(11)
    a6 = np.array(PAIRS["needle_vs_asym"][1]) * A
    rot = _rot(rng)
    o = rng.normal(size=3) * A
    pts = _surface(o, rot, a6, 200, 400)
    for _ in range(20):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        h, sx, sy, sz = poly_support(o, rot, a6, n[0], n[1], n[2])
        hs = np.max((pts - o) @ n)
        assert 0.0 <= h - hs < 2e-4 * A
        s = np.array([sx, sy, sz])
        hr, sr = _support_np(o, rot, a6, n)
        assert h == pytest.approx(hr[0], rel=1e-14)
        np.testing.assert_allclose(s, sr[0], atol=1e-15 * A)
        assert P._inside(o, rot, a6, sx, sy, sz) == pytest.approx(1.0, abs=1e-14)
        assert (s - o) @ n == pytest.approx(h, rel=1e-13)


# ------------------------------------------------------------------ pair contact

@pytest.mark.parametrize("name", sorted(PAIRS))
def test_constructed_depth_pairs(name):
    """Reference §1.6 with poly-ellipsoid support maps: o2 = s1(n) - (s2(-n) - o2) - delta n gives a
    common normal n with depth delta (the penetration depth for delta below the curvature radii).
    Random orientations, delta / a_min in {1e-7, 1e-5, 1e-3}, 60 pairs each: depth within
    1e-9 a_max + 1e-6 delta, normal within 1e-6 rad, p1 = s1(n), p2 = p1 - delta n within
    1e-9 a_max; octant switches <= MAX_SWITCHES (cap) and a mean < 1 (reference §2.2 prototype:
    mean 0.3-0.7, max 3); no contact when the same pair is moved apart to a gap of 1e-4 a_min.
    Repeated with a warm start (true normal perturbed by 1e-3 rad): same tolerances."""
    a1 = np.array(PAIRS[name][0]) * A
    a2 = np.array(PAIRS[name][1]) * A
    amin = min(a1.min(), a2.min())
    amax = max(a1.max(), a2.max())
    rng = _rng(sum(map(ord, name)))
    out = P.new_out()
    zero = np.zeros(3)
    switches = []
    worst_depth = 0.0
    worst_normal = 0.0
    for rel in REL_DEPTHS:
        delta = rel * amin
        for _ in range(60):
            o1, r1, o2, r2, n = _constructed(rng, a1, a2, delta)
            _, s1 = _support_np(o1, r1, a1, n)
            for n0 in (zero, n + 1e-3 * rng.normal(size=3)):
                assert polyellipsoid_contact(o1, r1, a1, o2, r2, a2, n0, out) == 1
                tol = 1e-9 * amax + 1e-6 * delta
                err = abs(out[E.OUT_DEPTH] - delta)
                ang = np.arccos(min(1.0, out[E.OUT_NX:E.OUT_NZ + 1] @ n))
                worst_depth = max(worst_depth, err / tol)
                worst_normal = max(worst_normal, ang)
                assert err <= tol
                assert ang <= 1e-6
                np.testing.assert_allclose(out[E.OUT_P1X:E.OUT_P1Z + 1], s1[0], atol=1e-9 * amax)
                np.testing.assert_allclose(out[E.OUT_P2X:E.OUT_P2Z + 1], s1[0] - delta * n, atol=1e-9 * amax)
                assert np.isfinite(out[:P.POLY_OUT_LEN]).all()
                assert out[E.OUT_RE] > 0.0 and out[E.OUT_KRATIO] >= 1.0
                switches.append(out[P.OUT_SWITCHES])
            # moved apart to a gap of 1e-4 a_min: no contact (cold and warm)
            og = o2 + (delta + 1e-4 * amin) * n
            assert polyellipsoid_contact(o1, r1, a1, og, r2, a2, zero, out) == 0
            assert polyellipsoid_contact(o1, r1, a1, og, r2, a2, n, out) == 0
    switches = np.array(switches)
    print(f"{name}: worst depth err / tol = {worst_depth:.2e}, worst normal = {worst_normal:.1e} rad, "
          f"switches mean {switches.mean():.2f} max {switches.max():.0f}")
    assert switches.max() <= P.MAX_SWITCHES
    assert switches.mean() < 1.0


def _align(v, w):
    """Rotation matrix taking unit v onto unit w (Rodrigues; v != -w)."""
    ax = np.cross(v, w)
    c = v @ w
    k = np.array([[0.0, -ax[2], ax[1]], [ax[2], 0.0, -ax[0]], [-ax[1], ax[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def test_constructed_depth_normal_on_octant_planes():
    """Constructed pairs (reference §1.6) whose common normal lies on octant planes of both bodies
    (one or two body-frame components of n exactly 0 for body 1, one for body 2): the worst case of the
    active set (either octant is valid there, reference §2.2).  Same tolerances as above (depth
    1e-9 a_max + 1e-6 delta, normal 1e-6 rad), cold and warm; the switch cap is never reached."""
    rng = _rng(21)
    out = P.new_out()
    for name in sorted(PAIRS):
        a1 = np.array(PAIRS[name][0]) * A
        a2 = np.array(PAIRS[name][1]) * A
        amin = min(a1.min(), a2.min())
        amax = max(a1.max(), a2.max())
        for rel in REL_DEPTHS:
            delta = rel * amin
            for k in range(12):
                r1 = _rot(rng)
                nb = rng.normal(size=3)
                nb[k % 3] = 0.0
                if k % 2:
                    nb[(k + 1) % 3] = 0.0
                nb /= np.linalg.norm(nb)
                n = r1 @ nb
                mb = rng.normal(size=3)
                mb[(k + 2) % 3] = 0.0
                mb /= np.linalg.norm(mb)
                q = _rot(rng)
                r2 = _align(q @ mb, -n) @ q          # R2 mb = -n: -n on an octant plane of body 2
                o1 = rng.normal(size=3) * A
                _, s1 = _support_np(o1, r1, a1, n)
                _, s2 = _support_np(np.zeros(3), r2, a2, -n)
                o2 = s1[0] - s2[0] - delta * n
                for n0 in (np.zeros(3), n + 1e-3 * rng.normal(size=3)):
                    assert polyellipsoid_contact(o1, r1, a1, o2, r2, a2, n0, out) == 1
                    assert abs(out[E.OUT_DEPTH] - delta) <= 1e-9 * amax + 1e-6 * delta
                    assert np.arccos(min(1.0, out[1:4] @ n)) <= 1e-6
                    assert out[P.OUT_SWITCHES] < P.MAX_SWITCHES


def test_ellipsoid_limit_matches_ellipsoid_contact():
    """a+ = a-, b+ = b-, c+ = c- (and spheres): every octant is the same ellipsoid, so the output
    equals ellipsoid_contact's (same formulas) to round-off (1e-12 relative), including R_e, kratio,
    lam and iteration counts; both agree on separated pairs."""
    rng = _rng(3)
    out = P.new_out()
    oe = E.new_out()
    zero = np.zeros(3)
    hits = 0
    for k in range(200):
        ax1 = rng.uniform(0.2, 1.0, 3) * A
        ax2 = rng.uniform(0.2, 1.0, 3) * A
        if k % 10 == 0:
            ax2[:] = ax2[0]             # sphere
        r1 = _rot(rng)
        r2 = _rot(rng)
        c1 = rng.normal(size=3) * A
        c2 = c1 + rng.normal(size=3) * 0.6 * A
        re = ellipsoid_contact(c1, r1, ax1, c2, r2, ax2, -1.0, zero, oe)
        rp = polyellipsoid_contact(c1, r1, np.repeat(ax1, 2), c2, r2, np.repeat(ax2, 2), zero, out)
        assert re == rp
        if re:
            hits += 1
            np.testing.assert_allclose(out[:E.OUT_LEN], oe, rtol=1e-12, atol=1e-15 * A)
            assert out[P.OUT_SWITCHES] == 0
    assert hits > 50


def test_rigid_motion_invariance_and_swap():
    """Rigid rotation Q and translation t of both bodies: depth unchanged (1e-12 a_max relative to
    round-off), normal and contact points transformed (1e-9 rad / 1e-12 a).  Swapping the bodies:
    same depth, normal flipped, p1 and p2 exchanged (reference §1.4: phi_21(-n) = phi_12(n))."""
    rng = _rng(5)
    out = P.new_out()
    out2 = P.new_out()
    zero = np.zeros(3)
    for name in sorted(PAIRS):
        a1 = np.array(PAIRS[name][0]) * A
        a2 = np.array(PAIRS[name][1]) * A
        for rel in (1e-5, 1e-2):
            o1, r1, o2, r2, n = _constructed(rng, a1, a2, rel * min(a1.min(), a2.min()))
            assert polyellipsoid_contact(o1, r1, a1, o2, r2, a2, zero, out) == 1
            q = _rot(rng)
            t = rng.normal(size=3) * 3 * A
            assert polyellipsoid_contact(q @ o1 + t, q @ r1, a1, q @ o2 + t, q @ r2, a2, zero, out2) == 1
            assert out2[E.OUT_DEPTH] == pytest.approx(out[E.OUT_DEPTH], abs=1e-12 * A)
            np.testing.assert_allclose(out2[1:4], q @ out[1:4], atol=1e-9)
            np.testing.assert_allclose(out2[4:7], q @ out[4:7] + t, atol=1e-12 * A)
            np.testing.assert_allclose(out2[7:10], q @ out[7:10] + t, atol=1e-12 * A)
            assert out2[E.OUT_RE] == pytest.approx(out[E.OUT_RE], rel=1e-8)
            # swap
            assert polyellipsoid_contact(o2, r2, a2, o1, r1, a1, zero, out2) == 1
            assert out2[E.OUT_DEPTH] == pytest.approx(out[E.OUT_DEPTH], abs=1e-12 * A)
            np.testing.assert_allclose(out2[1:4], -out[1:4], atol=1e-9)
            np.testing.assert_allclose(out2[4:7], out[7:10], atol=1e-12 * A)
            np.testing.assert_allclose(out2[7:10], out[4:7], atol=1e-12 * A)


def test_random_pairs_against_sampled_phi():
    """Global check on random pairs at random distances (moderate and separated): with phi_s the
    minimum of phi(n) = h1(n) + h2(-n) - n.R over 20 000 sampled directions (an upper bound of the
    true minimum, reference §1.4):
    * a reported contact never has phi_s < 0 (no false contact: a sampled separating axis exists);
    * for depths < 0.05 a_min (DEM regime) the depth is <= phi_s + 1e-12 a (global minimum) and is
      a stationary point (p1 - p2 = depth n to 1e-10 a);
    * a rejected pair has phi_s < 1e-3 a (missed contacts only within sampling error of touching);
    all outputs finite."""
    rng = _rng(9)
    g = rng.normal(size=(20000, 3))
    g /= np.linalg.norm(g, axis=1)[:, None]
    out = P.new_out()
    zero = np.zeros(3)
    shapes = [np.array(s) * A for pair in PAIRS.values() for s in pair]
    nc = 0
    for k in range(500):
        a1 = shapes[rng.integers(len(shapes))]
        a2 = shapes[rng.integers(len(shapes))]
        r1 = _rot(rng)
        r2 = _rot(rng)
        o1 = rng.normal(size=3) * A
        d = rng.normal(size=3)
        # distance around contact: bounding-sphere sum scaled by [0.3, 1.0]
        o2 = o1 + d / np.linalg.norm(d) * (a1.max() + a2.max()) * rng.uniform(0.3, 1.0)
        r = polyellipsoid_contact(o1, r1, a1, o2, r2, a2, zero, out)
        h1, _ = _support_np(o1, r1, a1, g)
        h2, _ = _support_np(o2, r2, a2, -g)
        phi_s = (h1 + h2 - g @ (o2 - o1)).min()
        if r:
            nc += 1
            assert np.isfinite(out[:P.POLY_OUT_LEN]).all()
            assert phi_s > 0.0
            if out[E.OUT_DEPTH] < 0.05 * min(a1.min(), a2.min()):
                assert out[E.OUT_DEPTH] <= phi_s + 1e-12 * A
                dp = out[4:7] - out[7:10]
                np.testing.assert_allclose(dp, out[E.OUT_DEPTH] * out[1:4], atol=1e-10 * A)
        else:
            assert phi_s < 1e-3 * A
    assert nc > 50


def test_concentric_and_identical_bodies_finite():
    """Degenerate inputs (o1 = o2, identical bodies; deep overlap outside the DEM regime): a contact
    with finite outputs and depth <= h1(n) + h2(-n) at the reported normal (never NaN, reference §2.2)."""
    rng = _rng(13)
    out = P.new_out()
    for name in sorted(PAIRS):
        a1 = np.array(PAIRS[name][0]) * A
        r1 = _rot(rng)
        o = rng.normal(size=3) * A
        assert polyellipsoid_contact(o, r1, a1, o, r1, a1, np.zeros(3), out) == 1
        assert np.isfinite(out[:P.POLY_OUT_LEN]).all()
        assert out[E.OUT_DEPTH] > 0.0
        assert abs(np.linalg.norm(out[1:4]) - 1.0) < 1e-14


# ------------------------------------------------------------------ wall contact

def test_wall_contact_vs_surface_sampling():
    """Tilted asymmetric body vs plane m.x = d (m into the particle region): depth = d - min_x m.x
    over the surface (reference §1.4/§2.2 closed form h_P(-m) - (m.o - d)).  Brute force over a dense
    surface sample (400 x 800 octant-wise grid) underestimates it by at most ~a (pi/400)^2 / 2: the
    kernel depth lies in [brute, brute + 1e-4 a].  p1 on the surface, p2 = p1 + depth m on the plane,
    n = -m; no contact when the wall is moved 1e-6 a beyond the deepest point."""
    rng = _rng(17)
    out = P.new_out()
    for name in ("asym_vs_asym", "needle_vs_asym", "flat_vs_asym"):
        a6 = np.array(PAIRS[name][0]) * A
        rot = _rot(rng)
        o = rng.normal(size=3) * A
        pts = _surface(o, rot, a6)
        for _ in range(4):
            m = rng.normal(size=3)
            m /= np.linalg.norm(m)
            lowest = (pts @ m).min()
            d = lowest + 0.01 * A
            assert polyellipsoid_wall_contact(o, rot, a6, m, d, out) == 1
            brute = d - lowest
            assert brute - 1e-15 * A <= out[E.OUT_DEPTH] <= brute + 1e-4 * A
            np.testing.assert_allclose(out[1:4], -m, atol=0)
            p1 = out[4:7]
            p2 = out[7:10]
            assert P._inside(o, rot, a6, *p1) == pytest.approx(1.0, abs=1e-12)
            assert p2 @ m == pytest.approx(d, abs=1e-15 * A)
            np.testing.assert_allclose(p2 - p1, out[E.OUT_DEPTH] * m, atol=1e-15 * A)
            assert out[E.OUT_RE] > 0.0 and out[E.OUT_KRATIO] >= 1.0
            h, *_ = poly_support(o, rot, a6, -m[0], -m[1], -m[2])
            dgap = m @ o - h - 1e-6 * A
            assert polyellipsoid_wall_contact(o, rot, a6, m, dgap, out) == 0


def test_wall_ellipsoid_limit():
    """a+ = a- etc.: polyellipsoid_wall_contact equals ellipsoid_wall_contact (same closed form)."""
    rng = _rng(19)
    out = P.new_out()
    oe = E.new_out()
    for _ in range(20):
        ax = rng.uniform(0.2, 1.0, 3) * A
        rot = _rot(rng)
        c = rng.normal(size=3) * A
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        d = m @ c - 0.9 * ax.max()
        r1 = E.ellipsoid_wall_contact(c, rot, ax, m, d, oe)
        r2 = polyellipsoid_wall_contact(c, rot, np.repeat(ax, 2), m, d, out)
        assert r1 == r2
        if r1:
            np.testing.assert_allclose(out[:E.OUT_LEN], oe, rtol=1e-13, atol=1e-16 * A)
