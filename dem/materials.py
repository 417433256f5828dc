"""Materials, pair mixing rules, and the damping that yields a requested restitution.

Mixing rule (stated once, used everywhere):
  1/E* = (1-nu1^2)/E1 + (1-nu2^2)/E2          (Hertz; rigid wall: E* = E/(1-nu^2))
  1/G* = (2-nu1)/G1 + (2-nu2)/G2, G = E/(2(1+nu)) (Mindlin; rigid wall: G* = G/(2-nu))
  mu   = min(mu1, mu2)                           (the weaker surface slides first)
  e    = min(e1, e2)                             (the more dissipative body governs)
Reference: contact-mechanics.md §3.1-3.3; Johnson, Contact Mechanics (1985) §4.2, §7.
"""
from dataclasses import dataclass
from functools import lru_cache
import math
import numpy as np
from numba import njit


@dataclass(frozen=True)
class Material:
    name: str
    density: float      # [kg/m^3]
    young: float        # [Pa]
    poisson: float      # [-]
    friction: float     # Coulomb coefficient [-]
    restitution: float  # of a head-on central collision [-], 0 < e <= 1

    @property
    def shear(self):
        return self.young / (2.0 * (1.0 + self.poisson))


@njit(cache=True)
def _clamped_restitution(zeta, nsub):
    """Restitution of the dimensionless clamped Hertz-Tsuji impact.

    x'' = -max(0, x^{3/2} + zeta x^{1/4} x'),  x(0) = 0, x'(0) = 1 (approach speed 1):
    integrate (RK4 in time, nsub steps per unit time) until x returns to 0 and
    return e = -x'. The result depends on zeta only (scale invariance of Hertz + Tsuji
    damping, contact-mechanics.md §3.3), so one calibration serves every impact speed.
    """
    h = 1.0 / nsub
    x = 0.0
    v = 1.0
    for _ in range(200 * nsub):
        # RK4 on (x, v); the force is clamped at zero (no attraction)
        k1x = v
        xx = max(x, 0.0)
        k1v = -max(0.0, xx ** 1.5 + zeta * xx ** 0.25 * v)
        x2 = x + 0.5 * h * k1x
        v2 = v + 0.5 * h * k1v
        xx = max(x2, 0.0)
        k2x = v2
        k2v = -max(0.0, xx ** 1.5 + zeta * xx ** 0.25 * v2)
        x3 = x + 0.5 * h * k2x
        v3 = v + 0.5 * h * k2v
        xx = max(x3, 0.0)
        k3x = v3
        k3v = -max(0.0, xx ** 1.5 + zeta * xx ** 0.25 * v3)
        x4 = x + h * k3x
        v4 = v + h * k3v
        xx = max(x4, 0.0)
        k4x = v4
        k4v = -max(0.0, xx ** 1.5 + zeta * xx ** 0.25 * v4)
        xn = x + h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
        vn = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if xn < 0.0 and vn < 0.0:
            return -vn
        x = xn
        v = vn
    return 0.0  # never separated: the particles stick


@lru_cache(maxsize=256)
def damping_ratio_for_restitution(e, nsub=4000):
    """zeta such that a clamped Hertz contact with Tsuji damping returns restitution e.

    Normal force F = k_H d^{3/2} - zeta sqrt(m* k_H) d^{1/4} v_n, clamped at F >= 0, with
    k_H = (4/3) E* sqrt(R_e) f_H. Unclamped, zeta = sqrt(5)|ln e|/sqrt(ln^2 e + pi^2) gives e
    exactly (Tsuji et al. 1992); the clamp raises e (contact-mechanics.md §3.3 table:
    e = 0.5 needs zeta = 0.5708), so we invert the clamped map by bisection. Kept per (e, nsub)
    for the process: the bisection integrates about 34 impacts (60 ms), which every scene
    build of the same restitution would otherwise repeat.
    """
    if not (0.0 < e <= 1.0):
        raise ValueError(f"restitution must be in (0, 1], got {e}")
    if e >= 1.0:
        return 0.0
    lo, hi = 0.0, 10.0  # e(zeta) decreases monotonically from 1
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _clamped_restitution(mid, nsub) > e:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9:
            break
    return 0.5 * (lo + hi)


class MaterialTable:
    """Per-pair constants [n_mat, n_mat] and per-material wall constants [n_mat].

    Arrays: estar, gstar, mu, zeta for particle pairs; estar_w, gstar_w, mu_w, zeta_w for a
    particle on a rigid wall.
    """

    def __init__(self, materials):
        self.materials = list(materials)
        self.index = {m.name: k for k, m in enumerate(self.materials)}
        nm = len(self.materials)
        self.estar = np.zeros((nm, nm))
        self.gstar = np.zeros((nm, nm))
        self.mu = np.zeros((nm, nm))
        self.zeta = np.zeros((nm, nm))
        z = damping_ratio_for_restitution   # kept per restitution (lru_cache)
        for a, ma in enumerate(self.materials):
            for b, mb in enumerate(self.materials):
                self.estar[a, b] = 1.0 / ((1 - ma.poisson**2) / ma.young + (1 - mb.poisson**2) / mb.young)
                self.gstar[a, b] = 1.0 / ((2 - ma.poisson) / ma.shear + (2 - mb.poisson) / mb.shear)
                self.mu[a, b] = min(ma.friction, mb.friction)
                self.zeta[a, b] = z(min(ma.restitution, mb.restitution))
        self.estar_w = np.array([m.young / (1 - m.poisson**2) for m in self.materials])
        self.gstar_w = np.array([m.shear / (2 - m.poisson) for m in self.materials])
        self.mu_w = np.array([m.friction for m in self.materials])
        self.zeta_w = np.array([z(m.restitution) for m in self.materials])


def rayleigh_time(radius, material):
    """Rayleigh wave time pi R sqrt(rho/G) / (0.1631 nu + 0.8766) [s] (contact-mechanics.md §4.3)."""
    return math.pi * radius * math.sqrt(material.density / material.shear) / (0.1631 * material.poisson + 0.8766)


def hertz_contact_time(mstar, r_e, estar, v):
    """Duration of an elastic Hertz impact t_c = 2.8683 (m*^2/(R_e E*^2 v))^{1/5} [s] (§4.3)."""
    return 2.8683 * (mstar**2 / (r_e * estar**2 * v)) ** 0.2
