"""The stored tangential spring rotated into the new tangent plane (contact-mechanics.md §3.2,
step 1: subtract (F_t.n) n and rescale to the old magnitude), through dem.forces.contact_force,
which writes it on the unnormalised normal u (n = u/|u|, iu2 = 1/|u|^2)."""
import numpy as np
import pytest

from dem.forces import contact_force

# A contact with no relative motion (vr = 0), so the returned spring is the rotated one: no
# increment k_t v_t dt, no damping; mu = 1e6 keeps the Coulomb cap (mu F_n) far above it.
DEPTH, R_E, MSTAR, ESTAR, GSTAR, ZETA, MU, DT = 1e-6, 1e-3, 1e-5, 1e9, 4e8, 0.3, 1e6, 1e-7
SPRING = (2e-3, -1e-3, 5e-4)  # stored spring o [N], not tangent to any of the normals below


def _spring(n, u, iu2, o=SPRING, a_old=3e-5):
    f = contact_force(DEPTH, *n, *u, iu2, R_E, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                      MSTAR, ESTAR, GSTAR, ZETA, MU, *o, a_old, True, DT)
    return np.array(f[9:12])


@pytest.mark.parametrize("u", [(0.3e-3, -0.2e-3, 1.9e-3), (1.9e-3, 0.0, 0.0), (-1e-3, 1e-3, 1e-3)])
def test_spring_rotated_into_the_tangent_plane_at_its_old_magnitude(u):
    """Centre line u [m] of two spheres (n = u/|u|): the rotated spring is perpendicular to n, has
    the stored spring's magnitude |o| (a_old above the new contact radius sqrt(R_e d) = 3.2e-5 m
    would also rescale it by a/a_old: a_old = 3e-5 m is below, so it does not), and equals
    |o| (o - (o.n) n)/|o - (o.n) n|, computed here with numpy on n; all to 1e-14 relative."""
    u = np.array(u)
    n = u / np.linalg.norm(u)
    o = np.array(SPRING)
    got = _spring(n, u, 1.0 / (u @ u))
    proj = o - (o @ n) * n
    want = proj * (np.linalg.norm(o) / np.linalg.norm(proj))
    assert abs(got @ n) <= 1e-14 * np.linalg.norm(o)
    assert np.linalg.norm(got) == pytest.approx(np.linalg.norm(o), rel=1e-14)
    assert np.allclose(got, want, rtol=0.0, atol=1e-14 * np.linalg.norm(o))
    # the same rotation on n itself (u = n, iu2 = 1: what ellipsoid and wall contacts pass)
    assert np.allclose(_spring(n, n, 1.0), want, rtol=0.0, atol=1e-14 * np.linalg.norm(o))


def test_spring_already_tangent_is_unchanged():
    """A spring already in the new tangent plane (o.u = 0) comes back bit for bit: the projection
    subtracts 0 u and the rescale is sqrt(|o|^2/|o|^2) = 1."""
    tangent = (2e-3, -1e-3, 0.0)
    for n, u in (((0.0, 0.0, 1.0), (0.0, 0.0, 2e-3)), ((0.0, 0.0, 1.0), (0.0, 0.0, 1.0))):
        assert np.array_equal(_spring(n, u, 1.0 / (u[2] * u[2]), o=tangent), np.array(tangent))
