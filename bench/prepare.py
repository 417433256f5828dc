"""Scene preparation that needs a simulation, done once and cached.

`[build] method = "settle"`: step the generated assembly serially under its own gravity until
its kinetic energy falls below ke_tol x (sum m |g| d_mean) or max_steps pass (the paper's
gravitational deposition, used by patch162).

`[build] method = "compress"`: affine compression of the lattice in its closed box (no gravity,
positions and walls scaled towards the box centre by (1 - rate) per step, particle sizes kept, a
Lubachevsky-Stillinger-like protocol) until the mean particle-particle coordination number
reaches `coordination`, then relaxation with the walls fixed until KE < ke_tol x (sum m v_ref^2)
with v_ref the compression speed of the box faces. Used by packed: a dense static assembly built
in a few thousand steps, where gravitational settling would need the fall time of the column.

The built state (positions, velocities, orientations, angular momenta, contact history, box)
is cached by the scene's parameters and this module's version: $DEM_BENCH_CACHE or
~/.cache/dem-mapping-bench.
"""
import os
import time

import numpy as np

from dem.scene import load_scene, wall_planes

CACHE_VERSION = "3"
SAVED = ("pos", "vel", "quat", "angmom", "hist_start", "hist_partner", "hist_val", "wall_hist")


def cache_dir():
    return os.environ.get("DEM_BENCH_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "dem-mapping-bench"))


def load_prepared(spec, particles=None, shape=None, seed=None, log=None):
    """load_scene + its build stage (from the cache when possible). Returns the Scene."""
    return prepare(load_scene(spec, particles=particles, shape=shape, seed=seed), log=log)


def prepare(scene, log=None):
    """Run (or load from the cache) the scene's [build] stage in place; returns the scene."""
    build = scene.extras.get("build") or {}
    if not build:
        return scene
    path = os.path.join(cache_dir(), f"{scene.name}-{scene.n}-{scene.extras['key']}-v{CACHE_VERSION}.npz")
    s = scene.state
    if os.path.exists(path):
        try:
            with np.load(path) as z:
                for f in SAVED:
                    setattr(s, f, z[f].copy())
                _set_box(scene, z["box"].copy())
                info = {k[5:]: z[k].item() for k in z.files if k.startswith("info_")}
            scene.extras["built"] = dict(info, cached=path, from_cache=True)
            return scene
        except (OSError, KeyError, ValueError):
            pass  # unreadable cache: build again
    if build["method"] == "settle":
        info = settle(scene, build.get("max_steps", 5000), float(build.get("ke_tol", 1e-4)), log=log)
    else:
        info = compress(scene, build.get("max_steps", 5000), float(build.get("rate", 2e-4)),
                        float(build.get("coordination", 4.5)), float(build.get("ke_tol", 1e-4)), log=log)
    os.makedirs(cache_dir(), exist_ok=True)
    tmp = path + f".{os.getpid()}.tmp.npz"
    np.savez(tmp, box=scene.box, **{f: getattr(s, f) for f in SAVED}, **{f"info_{k}": v for k, v in info.items()})
    os.replace(tmp, path)
    scene.extras["built"] = dict(info, cached=path, from_cache=False)
    return scene


def _set_box(scene, box):
    scene.box = np.asarray(box, dtype=np.float64)
    scene.wall_m, scene.wall_d = wall_planes(scene.walls, scene.box)


def _serial(scene):
    from bench.run import choose_dt
    from modes.serial import SerialMode
    dt = choose_dt(scene, None)[0]
    return SerialMode().setup(scene, dt=dt), dt


def settle(scene, max_steps, ke_tol, log=None):
    """Step serially until KE < ke_tol * sum(m) |g| d_mean (checked every 100 steps)."""
    mode, dt = _serial(scene)
    s = scene.state
    g = float(np.linalg.norm(scene.gravity)) or 1.0
    scale = float(s.mass.sum()) * g * 2.0 * float(s.rbound.mean())
    t0 = time.perf_counter()
    k = 0
    ke = s.kinetic_energy()
    while k < max_steps:
        mode.step()
        k += 1
        if k % 100 == 0:
            ke = s.kinetic_energy()
            if log and k % 2000 == 0:
                log(f"settling {scene.name}: step {k}, KE/scale {ke / scale:.2e}")
            if k >= 500 and ke < ke_tol * scale:
                break
    return {"method": "settle", "steps": k, "ke_ratio": ke / scale, "seconds": time.perf_counter() - t0}


def compress(scene, max_steps, rate, coordination, ke_tol, log=None, relax_steps=200):
    """Staged affine compression towards the box centre, gravity off during the build:
    compress at `rate` per step (twice that while Z < 1, a dilute gas) until the mean
    particle-particle coordination Z overshoots `coordination` + 0.5, hold the walls for
    `relax_steps`, and resume (at half the rate) if the relaxed Z fell below `coordination`; finish with a relaxation until KE < ke_tol * sum(m) v_ref^2 (v_ref the
    first compression speed of the box faces). Returns build statistics."""
    g_saved = scene.gravity.copy()
    scene.gravity = np.zeros(3)
    mode, dt = _serial(scene)
    s = scene.state
    n = s.n_owned
    centre = 0.5 * (scene.box[0] + scene.box[1])
    v_ref = rate * float(np.max(scene.box[1] - scene.box[0])) / dt
    scale = float(s.mass.sum()) * v_ref ** 2
    t0 = time.perf_counter()
    compressing = True
    z = 0.0
    ke = np.inf
    held = 0
    jammed = False
    for k in range(1, max_steps + 1):
        if compressing:
            f = 1.0 - (2.0 * rate if z < 1.0 else rate)
            s.pos[:n] = centre + (s.pos[:n] - centre) * f
            _set_box(scene, centre + (scene.box - centre) * f)
        row = mode.step()
        z = 2.0 * row["n_contacts"] / n
        if compressing:
            if z >= coordination + 0.5:
                compressing = False
                held = 0
        else:
            held += 1
            if held == relax_steps:
                if z < coordination:
                    compressing = True
                    rate *= 0.5
                else:
                    jammed = True
        if k % 100 == 0 or (jammed and held >= relax_steps):
            ke = s.kinetic_energy()
            if log and k % int(os.environ.get("DEM_BUILD_LOG_EVERY", 1000)) == 0:
                log(f"building {scene.name}: step {k}, coordination {z:.2f}, KE ratio {ke / scale:.1e}")
            if jammed and ke < ke_tol * scale:
                break
    scene.gravity = g_saved
    return {"method": "compress", "steps": k, "coordination": z, "jammed": jammed,
            "ke_ratio": ke / scale, "seconds": time.perf_counter() - t0}
