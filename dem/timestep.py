"""Critical and automatic time step (contact-mechanics.md §4.3).

  dt_R  = pi c_min sqrt(rho/G) / (0.1631 nu + 0.8766)        Rayleigh time of the smallest semi-axis
  t_c   = 2.8683 (m_eff^2 / (R_e E*^2 f_H^2 v))^{1/5}          Hertz contact duration, stiffest contact
  m_eff = f m_min / 2, f = 2/7 (spheres, tangential) or 1/6 (any ellipsoid, eccentric contact)
  R_e   = largest principal radius of curvature a_max^2 / c_min (disk face on a wall)
  v     = impact speed estimate max(2 |v0|_max, sqrt(2 |g| H), 0.01 m/s)
Stability of central difference needs dt < t_c/2.015 (isolated Hertz contact); we call
  dt_critical = min(dt_R, t_c / 2.015)
and dt = "auto" takes min(0.2 dt_R, t_c / 50) (50 steps per contact keeps the restitution of
velocity Verlet within 4e-5, §4.3).

The policy of a run is choose_time_step(scene, user_dt): computed once per run, from the built
scene, by the process that starts it (MPI ranks receive it, bench.run.rank).
"""
import math
from dataclasses import asdict, dataclass

import numpy as np

from dem.contact.hertz_factor import hertz_factor
from dem.materials import hertz_contact_time, rayleigh_time
from dem.scene import SceneError
from dem.shapes import SPHERE
from dem.state import smallest_semi_axes


@dataclass(frozen=True)
class TimeStep:
    """The time step of a run [s], its bounds dt_auto and dt_critical [s] (time_step_bounds) and
    their details (Rayleigh time, contact time, impact speed, ...)."""
    dt: float
    auto: float
    critical: float
    details: dict

    @property
    def warnings(self):
        """One-line warnings about the chosen dt (details["warnings"])."""
        return list(self.details.get("warnings", []))

    def as_dict(self):
        return asdict(self)

    @classmethod
    def from_dict(cls, d):
        return cls(float(d["dt"]), float(d["auto"]), float(d["critical"]), dict(d["details"]))


def choose_time_step(scene, user_dt=None):
    """The run's TimeStep: user_dt [s] (or "auto") when given, else the scene's dt; "auto" is
    dt_auto. Refused (SceneError, one line) when not a positive finite number or above
    dt_critical."""
    s = scene.state
    dt_auto, dt_crit, info = time_step_bounds(s.axes, s.shape, s.mass, s.material, scene.materials,
                                              scene.walls, scene.gravity, scene.box, s.vel, s.poly)
    dt = user_dt if user_dt is not None else scene.dt
    if dt == "auto":
        dt = dt_auto
    dt = float(dt)
    if not (dt > 0 and np.isfinite(dt)):
        raise SceneError(f"time step must be positive, got {dt}")
    if dt > dt_crit:
        raise SceneError(f"time step {dt:.3g} s exceeds the critical step {dt_crit:.3g} s "
                         f"(Rayleigh {info['dt_rayleigh']:.3g} s, contact {info['t_contact']:.3g} s / 2.015); "
                         f"use dt = \"auto\" ({dt_auto:.3g} s) or smaller")
    return TimeStep(dt, dt_auto, dt_crit, info)


def time_step_bounds(axes, shape, mass, material, materials, walls, gravity, box, vel, poly=None):
    """Return (dt_auto, dt_critical, details dict) for the given particles and scene
    (poly [n, POLY_LEN]: poly-ellipsoid records, whose smallest of six semi-axes counts)."""
    cmin = smallest_semi_axes(axes, shape, np.zeros((len(axes), 0)) if poly is None else poly)
    dt_r = np.inf
    for k, mat in enumerate(materials.materials):
        sel = material == k
        if np.any(sel):
            dt_r = min(dt_r, rayleigh_time(float(cmin[sel].min()), mat))
    spheres = bool(np.all(shape == SPHERE))
    f = 2.0 / 7.0 if spheres else 1.0 / 6.0
    m_eff = f * float(mass.min()) / 2.0
    amax = axes.max(axis=1)
    r_e = float(np.max(amax * amax / cmin))
    kmax = float(np.max((amax / cmin) ** 2))
    f_h = hertz_factor(kmax) if kmax > 1.0 else 1.0
    estar = float(max(materials.estar.max(), materials.estar_w.max() if len(walls) else 0.0))
    height = float(box[1][2] - box[0][2]) if box is not None else 0.0
    g = float(np.linalg.norm(gravity))
    vmax = float(np.linalg.norm(vel, axis=1).max()) if len(vel) else 0.0
    v = max(2.0 * vmax, math.sqrt(2.0 * g * height), 0.01)
    t_c = hertz_contact_time(m_eff, r_e, estar * f_h, v)
    dt_crit = min(dt_r, t_c / 2.015)
    dt_auto = min(0.2 * dt_r, t_c / 50.0)
    return dt_auto, dt_crit, {"dt_rayleigh": dt_r, "t_contact": t_c, "v_impact": v,
                              "m_eff": m_eff, "r_e_max": r_e}
