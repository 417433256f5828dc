"""Critical and automatic time step (contact-mechanics.md §4.3).

The stability limit comes from the contacts. Central difference (leapfrog) on a contact of
stiffness k between effective mass m* is stable for dt < 2/omega, omega = sqrt(k/m*); a Hertz contact
stiffens as it loads (k = 1.5 k_H delta^(1/2)), and at its deepest point, delta_max of an impact at
speed v, this gives dt < t_c / 2.015 with t_c the Hertz contact duration (§4.3). For the stiffest
contact the scene can hold:
  t_c   = 2.8683 (m_eff^2 / (R_e E*^2 f_H^2 v))^{1/5}          Hertz contact duration
  m_eff = f m_min / 2, f = 2/7 (spheres, tangential) or 1/6 (any ellipsoid, eccentric contact)
  R_e   = largest principal radius of curvature a_max^2 / c_min (disk face on a wall)
  v     = impact speed estimate max(2 |v0|_max, sqrt(2 |g| H), 0.01 m/s)
  dt_critical = t_c / 2.015            the contact stability limit: a larger dt is refused
  dt_R  = pi c_min sqrt(rho/G) / (0.1631 nu + 0.8766)        Rayleigh time of the smallest semi-axis
The Rayleigh time bounds the transit of a surface wave through a grain, a rule of thumb for
resolving elastic waves through a packing, not the stability limit of this integrator: a user dt
above it but below dt_critical is run, with a one-line warning (the paper runs its quartz deposition
at 1e-6 s, above its grains' Rayleigh time).
  dt = "auto" = AUTO_FRACTION x dt_critical = 0.1 t_c / 2.015 (about t_c / 20)
AUTO_FRACTION = 0.1 comes from the work-precision study `bench accuracy --steps 2000 --dt-factors
9.5,3,2,1,0.5,0.403 --methods exact --ref-factor 0.1` on the extreme scenes (real quartz at up to
6 m/s; reference: exact at 0.01 dt_critical; error = rms over particles of |x - x_ref| / r_mean after
2.5-2.8 us, a few contact durations):
    dt / dt_critical     0.95     0.3      0.2      0.1      0.05     0.04 (the former t_c/50)
    stiff                1.2e-2   7.2e-3   5.8e-3   4.7e-3   3.5e-3   3.0e-3
    needles              2.1e-4   5.4e-5   5.3e-5   2.0e-5   9.5e-6   7.5e-6
    disks                5.0e-5   2.2e-5   1.6e-5   1.6e-5   2.0e-5   2.0e-5
At 0.1 the position error of needles and disks is a tenth of the Perram-Wertheim method's at the
same dt (2.7e-4 and 2.5e-4: the contact geometry, not the step, bounds the accuracy); stiff's error
is dominated by its stick-slip and multi-body impacts and falls only slowly with dt. The binding
measure is the restitution of a central impact (tests/dem/test_extreme_scenes.py, within 2e-3 m/s of
e v): at 0.1 the stiff and needle wall impacts rebound at e = 0.79977 and 0.79979 (e = 0.8; 25-30
steps per contact); at 0.2 they missed by 3.7e-3 and 4.1e-3 m/s. So auto runs 2.5 x fewer steps
than the former min(0.2 dt_Rayleigh, t_c/50), and stays 10 x below the stability limit, which the
extreme scenes kept at 0.95 (stable, error 1.2e-2 for stiff).

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
from dem.shapes.registry import smallest_semi_axes


# dt = "auto" as a fraction of dt_critical (module docstring)
AUTO_FRACTION = 0.1


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
    dt_auto. Refused (SceneError, one line) when not a positive finite number or above dt_critical;
    above the Rayleigh time (but within dt_critical) it carries a warning (TimeStep.warnings)."""
    s = scene.state
    dt_auto, dt_crit, info = time_step_bounds(s.axes, s.shape, s.mass, s.material, scene.materials,
                                              scene.walls, scene.gravity, scene.box, s.vel, s.poly)
    dt = user_dt if user_dt is not None else scene.dt
    auto = dt == "auto"
    if auto:
        dt = dt_auto
    dt = float(dt)
    if not (dt > 0 and np.isfinite(dt)):
        raise SceneError(f"time step must be positive, got {dt}")
    if dt > dt_crit:
        raise SceneError(f"time step {dt:.3g} s exceeds the critical step {dt_crit:.3g} s (the contact stability "
                         f"limit t_c / 2.015, t_c = {info['t_contact']:.3g} s for the stiffest contact at "
                         f"{info['v_impact']:.3g} m/s); use dt = \"auto\" ({dt_auto:.3g} s) or smaller")
    info = dict(info, warnings=[])
    if not auto and dt > info["dt_rayleigh"]:
        info["warnings"].append(
            f"time step {dt:.3g} s is above the Rayleigh time {info['dt_rayleigh']:.3g} s of the smallest semi-axis "
            f"(elastic waves in a grain are not resolved) but within the contact stability limit {dt_crit:.3g} s: "
            f"running it")
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
    dt_crit = t_c / 2.015
    dt_auto = AUTO_FRACTION * dt_crit
    return dt_auto, dt_crit, {"dt_rayleigh": dt_r, "t_contact": t_c, "v_impact": v,
                              "m_eff": m_eff, "r_e_max": r_e, "auto_fraction": AUTO_FRACTION}
