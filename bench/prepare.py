"""Scene preparation that needs a simulation: settling a generated assembly under gravity.

A scene with `[build] settle_steps = K` is stepped serially (its own material, dt and
gravity) until its kinetic energy per unit potential scale falls below `settle_ke` or K steps
have passed; the settled state (positions, velocities, orientations, angular momenta, contact
history) is cached by the scene's parameters and the code's version, so later runs start from
the same assembly at once. Cache folder: $DEM_BENCH_CACHE or ~/.cache/dem-mapping-bench.
"""
import os
import time

import numpy as np

from dem.scene import load_scene

CACHE_VERSION = "1"
SAVED = ("pos", "vel", "quat", "angmom", "hist_gid", "hist_val", "hist_cnt", "wall_hist")


def cache_dir():
    return os.environ.get("DEM_BENCH_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "dem-mapping-bench"))


def load_prepared(spec, particles=None, shape=None, seed=None, log=None):
    """load_scene + the build stage (from cache when possible). Returns the Scene."""
    scene = load_scene(spec, particles=particles, shape=shape, seed=seed)
    build = scene.extras.get("build") or {}
    steps = build.get("settle_steps", 0)
    if not steps:
        return scene
    path = os.path.join(cache_dir(), f"{scene.name}-{scene.n}-{scene.extras['key']}-v{CACHE_VERSION}.npz")
    s = scene.state
    if os.path.exists(path):
        try:
            with np.load(path) as z:
                for f in SAVED:
                    setattr(s, f, z[f].copy())
            scene.extras["settled"] = {"cached": path}
            return scene
        except (OSError, KeyError, ValueError):
            pass  # unreadable cache: settle again
    info = settle(scene, steps, float(build.get("settle_ke", 1e-4)), log=log)
    os.makedirs(cache_dir(), exist_ok=True)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **{f: getattr(s, f) for f in SAVED})
    os.replace(tmp, path)
    scene.extras["settled"] = dict(info, cached=path)
    return scene


def settle(scene, max_steps, ke_tol, log=None):
    """Step serially until KE < ke_tol * sum(m) |g| d_mean (checked every 100 steps)."""
    from bench.run import choose_dt, kinetic_energy
    from modes.serial import SerialMode
    dt = choose_dt(scene, None)[0]
    mode = SerialMode().setup(scene, dt=dt)
    s = scene.state
    g = float(np.linalg.norm(scene.gravity)) or 1.0
    scale = float(s.mass.sum()) * g * 2.0 * float(s.rbound.mean())
    t0 = time.perf_counter()
    k = 0
    ke = kinetic_energy(s)
    while k < max_steps:
        mode.step()
        k += 1
        if k % 100 == 0:
            ke = kinetic_energy(s)
            if log and k % 2000 == 0:
                log(f"settling {scene.name}: step {k}, KE/scale {ke / scale:.2e}")
            if k >= 500 and ke < ke_tol * scale:
                break
    return {"settle_steps": k, "settle_ke_ratio": ke / scale, "settle_s": time.perf_counter() - t0}
