"""Hertz-Mindlin contact law with Tsuji damping, written once as a scalar function.

Every contact (sphere, ellipsoid, wall) and every execution mode calls `hertz_mindlin`;
a new mode never touches the law (contact-mechanics.md §3).
"""
import math
from numba import njit


@njit(cache=True, inline="always")
def hertz_mindlin(depth, r_e, f_h, estar, gstar, mstar, zeta, mu,
                  vn, vtx, vty, vtz, ftx, fty, ftz, a_old, dt):
    """Normal and tangential force of one contact for one step.

    Normal (Hertz with elliptical factor f_H, Tsuji damping, no tension):
        k_H = (4/3) E* sqrt(R_e) f_H                          [N/m^{3/2}]
        F_n = max(0, k_H d^{3/2} - zeta sqrt(m* k_H) d^{1/4} v_n)   [N]
    Tangential (incremental Mindlin no-slip, Thornton et al. 2011 unloading, Coulomb cap):
        a = sqrt(R_e d),  k_t = 8 G* a                         [m], [N/m]
        F_s <- F_s (a/a_old) when unloading;  F_s <- F_s - k_t v_t dt
        F_t = F_s - c_t v_t, c_t = zeta sqrt(m* k_t (2/3)), capped |F_t| <= mu F_n; on sliding the
        spring is reset to the capped force (so it never stores more than mu F_n).
    Inputs: d = depth [m] > 0; v_n = (v2 - v1).n at the contact [m/s] (negative approaching);
    v_t [3] the tangential relative velocity of body 2 with respect to body 1; F_s = (ftx, fty,
    ftz), the stored spring force on body 2 already rotated into the current tangent plane [N];
    a_old the previous contact radius (0 for a new contact) [m]; dt [s].
    Returns (F_n, F_t [3] on body 2, F_s [3] to store, a).
    The tangential damping uses S_t = 8 G* a in place of S_n (contact-mechanics.md §3.2 step 6),
    i.e. sqrt(m* S_t) * 2 sqrt(5/6)|beta| = zeta sqrt(m* 8 G* a * 2/3).
    """
    sqrt_r = math.sqrt(r_e)
    sqrt_d = math.sqrt(depth)
    a = sqrt_r * sqrt_d
    k_h = (4.0 / 3.0) * estar * sqrt_r * f_h
    # zeta sqrt(m* k_H) d^{1/4} = zeta sqrt(m* k_H sqrt(d)): one root instead of two
    fn = k_h * depth * sqrt_d - zeta * math.sqrt(mstar * k_h * sqrt_d) * vn
    if fn < 0.0:
        fn = 0.0
    if a_old > a and a_old > 0.0:
        s = a / a_old
        ftx *= s
        fty *= s
        ftz *= s
    kt = 8.0 * gstar * a
    ftx -= kt * vtx * dt
    fty -= kt * vty * dt
    ftz -= kt * vtz * dt
    ct = zeta * math.sqrt(mstar * kt * (2.0 / 3.0))
    tx = ftx - ct * vtx
    ty = fty - ct * vty
    tz = ftz - ct * vtz
    tmag2 = tx * tx + ty * ty + tz * tz
    cap = mu * fn
    if tmag2 > cap * cap:
        s = cap / math.sqrt(tmag2)
        tx *= s
        ty *= s
        tz *= s
        ftx, fty, ftz = tx, ty, tz
    return fn, tx, ty, tz, ftx, fty, ftz, a
