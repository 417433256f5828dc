"""Scene preparation that needs a simulation, done once and cached.

`[build] method = "settle"`: step the generated assembly serially under its own gravity until
its kinetic energy falls below ke_tol x (sum m |g| d_mean) or max_steps pass (the paper's
gravitational deposition, used by patch162).

`[build] method = "compress"`: pressure-servoed affine compression of the lattice in its closed box
(no gravity, positions and walls scaled towards the box centre, particle sizes kept, friction
capped at BUILD_FRICTION = 0.1 while compressing). The scaling itself drives neighbours together
at rate x spacing / dt (0.1-0.2 m/s at rate 5e-4: 1.5-2.5 % overlap per collision), so the rate is
servoed on a pressure proxy p = Z x (mean depth ratio of the touching pairs), target
p_t = coordination x OVERLAP_TARGET (4e-3): 2 x rate in the dilute gas (Z < 1), then
rate x clip(2 (1 - p / p_t), 0.2, 1); the walls hold once p >= p_t and compression resumes if p
falls 20 % (gas collisions, creep). After 100 held steps the full friction is restored; jammed
once 100 held steps (50 with full friction) end with KE < ke_tol x (sum m v_ref^2), v_ref the first
compression speed of the box faces. The stop rule is pressure-based: frictional spheres jam at a
lower particle-particle Z than ellipsoids. Used by packed: a dense static assembly built in a few
thousand steps, where gravitational settling would need the fall time of the column. Measured
(CACHE_VERSION 4, 2-core machine; max overlap ratio and Z = 2 contacts / N over the first 50 run
steps; the previous protocol, Z-triggered at rate 5e-4, in brackets):

    shape          N      steps   build [s]   Z      max overlap
    sphere         300    2321    0.6         3.35   1.6 %  (27 %)
    sphere         500    1818    0.4         3.51   1.9 %  (19 %)
    sphere         400    2296    0.5         3.58   2.4 %
    sphere         2000   1897    2.1         4.00   1.9 %  (9.5 %)
    ellipsoid      300    2336    1.6         5.49   1.1 %  (9.6 %)
    ellipsoid      400    2536    2.2         5.67   1.5 %
    ellipsoid      500    2054    2.2         5.62   0.9 %  (3.3 %)
    ellipsoid      2000   2241    11.4        6.04   0.8 %  (0.37 %)
    ellipsoid      10000  2588    69.6        6.78   1.8 %  (1.6 %; 2079 steps, 49.1 s)
    polyellipsoid  300    3075    2.8         5.55   1.1 %  (5.5 %)
    polyellipsoid  500    2792    4.2         6.11   1.0 %  (2.4 %)
    polyellipsoid  2000   2874    19.8        6.44   1.0 %

Rest (compress builds; `[build] rest = false` skips it, `rest = true` adds it to a settle build):
the built assembly is brought to rest before use. Criterion (kinetic energy): started from zero
velocities, CHECK_STEPS = 50 free steps end with KE = sum m |v|^2/2 + omega.L/2 below KE_rest =
M v_rest^2 / 2, i.e. an rms point speed below v_rest = REST_DISP x d_min / (REST_STEPS x dt), the
speed at which a point moves 1e-4 of the smallest bounding diameter in 1000 steps (1.6e-5 m/s for
packed, about a sixth of its mean contact overlap in a 1000-step benchmark). Reached by rounds of
300 damped steps (Cundall's local non-viscous damping, Cundall 1987, alpha = 0.7 as PFC: after each
step v -= dt alpha |F| sign(v) / m and L -= dt alpha |T| sign(omega) per component, F, T the
unbalanced force with gravity and the torque; plus a viscous 0.2 % per step, which stops the steady
sliding that local damping leaves alone; a particle without any force is stopped when there is no
gravity; the walls frictionless meanwhile for a cell to be mirror-tiled, so that at rest they
carry no tangential force, which the tiling below relies on), each followed by zero velocities and
the 50 free steps; at most 30 rounds (build.rest_reached says whether the criterion was met). The cached state has zero
velocities and angular momenta; a check of 50 plain steps on a copy then measures what a run sees:
max |v|, max |omega|, median |v|, the particles whose point speed |v| + |omega| r_b exceeds v_rest,
KE / KE_rest, the contacts at its first and last step (cache metadata and run.json build.rest_*).
Before (the issue's measurement): packed 500 had median |v| 1.2 mm/s, max 5.6 cm/s, max |omega|
143 rad/s; after: median 1.1e-7 m/s, max 8.8e-5 m/s, max |omega| 0.19 rad/s (3 rounds). Sphere packs
roll and rest slowly: 500 spheres reach the criterion in 21 rounds, 300 do not in 30 (KE / KE_rest
9.8, median |v| 1.3e-6 m/s, max 3.6e-4 m/s; build.rest_reached = false).

Measured rested builds of packed ellipsoids (serial, 2 shared cores under other load; wall time of
`load_prepared`, the cell's build included; the 50-step check from the cached state):

    N        build          wall    rest rounds  KE/KE_rest  max |v|    max |omega|  median |v|  contacts
    12 000   direct         8.1 min  5           0.92        8.1e-4     1.37         4.2e-8      40 726 = 40 726
    150 000  2x2x4 x 9375   4.3 min  10 (cell)   0.95        3.6e-4     2.99         2.3e-7      524 840 -> 524 856
    1 000 000 4x5x5 x 10000 6.7 min  6 (cell)    0.70        8.3e-4     1.21         1.6e-7      3 507 335 = 3 507 335
    ([m/s], [rad/s]; peak memory of the 1M build 3.6 GB, its cache 0.69 GB.)

Large packs (compress, N > CELL_MAX, spheres and ellipsoids): a cell of n = N / T particles (T =
tx ty tz tiles, the smallest near-cubic T that divides N with n <= CELL_MAX) is built, brought to
rest with frictionless walls and mirror-tiled: copy (ix, iy, iz) is the cell reflected across each
axis whose index is odd, so neighbouring copies meet face to face as mirror images. Across such a
face a particle that pressed on the wall by delta presses on its image by 2 delta, and the
Hertz-Mindlin-Tsuji law of the pair (E* and R_e halved, the relative approach doubled) gives the
wall's normal force exactly; the walls were frictionless, so no tangential force is lost: the tiled
assembly is at rest as the cell was. Orientations R' = M R D (M the reflection, D = diag(-1, 1, 1)
when det M = -1: an ellipsoid is symmetric in its principal planes), velocities M v, angular
momenta det(M) M L, pair and wall histories mirrored (tangential springs and normals M x). If N has
no such divisor, the cell holds ceil(N / T) and the surplus particles nearest the top wall are
removed, and the whole assembly goes through the rest phase again. The tiled pack repeats its cell
(period 2 L): a benchmark geometry, not a new random packing. Poly-ellipsoids are built directly.

The built state (positions, velocities, orientations, angular momenta, contact and wall history,
sizes, masses, box) is cached by the scene's parameters and this module's version:
$DEM_BENCH_CACHE or ~/.cache/dem-mapping-bench.
"""
import copy
import os
import time

import numpy as np

from dem.quaternion import quat_to_matrices
from dem.scene import build_scene, load_scene, wall_planes, WALL_FACES
from dem.shapes.registry import present, shapes
from dem.state import H_FT, H_N, HIST_LEN, State
from dem.timestep import choose_time_step
from modes.serial import SerialMode

CACHE_VERSION = "7"
# rest: a point may move REST_DISP of the smallest bounding diameter in REST_STEPS steps; local damping
REST_DISP = 1e-4
REST_STEPS = 1000
LOCAL_DAMPING = 0.7
VISCOUS_DAMPING = 0.002
CHECK_STEPS = 50
# compress builds above CELL_MAX particles mirror-tile a cell (module docstring)
CELL_MAX = 12000
# compress: target mean overlap ratio of the touching pairs at the [build] coordination, and the
# friction cap while compressing (see compress)
OVERLAP_TARGET = 4e-3
BUILD_FRICTION = 0.1
SAVED = ("gid", "shape", "axes", "mass", "inertia", "material", "poly", "pos", "vel", "quat", "angmom",
         "hist_start", "hist_partner", "hist_val")


def cache_dir():
    return os.environ.get("DEM_BENCH_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "dem-mapping-bench"))


def load_prepared(spec, particles=None, shape=None, seed=None, log=None, overlap_limit=None):
    """load_scene + its build stage (from the cache when possible). Returns the Scene."""
    return prepare(load_scene(spec, particles=particles, shape=shape, seed=seed, overlap_limit=overlap_limit), log=log)


def prepare(scene, log=None, build_missing=True):
    """Run (or load from the cache) the scene's [build] stage in place; returns the scene.
    build_missing=False only loads a cached build: returns None when the scene has a build stage
    that is not cached yet (the scene is left unbuilt)."""
    build = scene.extras.get("build") or {}
    if not build:
        return scene
    kind = "-cell" if scene.extras.get("tile_cell") else ""
    path = os.path.join(cache_dir(), f"{scene.name}{kind}-{scene.n}-{scene.extras['key']}-v{CACHE_VERSION}.npz")
    if os.path.exists(path):
        try:
            _load_cache(scene, path)
            return scene
        except (OSError, KeyError, ValueError):
            pass  # unreadable cache: build again
    if not build_missing:
        return None
    t0 = time.perf_counter()
    tiles = _tiles_for(scene, build)
    if build["method"] == "settle":
        info = settle(scene, build.get("max_steps", 5000), float(build.get("ke_tol", 1e-4)), log=log)
        if build.get("rest", False):
            info.update(rest(scene, log=log))
    elif tiles is not None:
        info = tile_build(scene, tiles, log=log)
    else:
        info = compress(scene, build.get("max_steps", 5000), float(build.get("rate", 2e-4)),
                        float(build.get("coordination", 4.5)), float(build.get("ke_tol", 1e-4)), log=log)
        if build.get("rest", True):
            info.update(rest(scene, frictionless_walls=bool(scene.extras.get("tile_cell")), log=log))
    s = scene.state
    s.permute(np.argsort(s.gid, kind="stable"))  # the build may re-sort in space: back to file order
    if build["method"] == "compress" and build.get("rest", True) or build.get("rest", False):
        info.update(rest_check(scene))
    info["build_s"] = time.perf_counter() - t0
    _save_cache(scene, path, info)
    scene.extras["built"] = dict(info, cached=path, from_cache=False)
    return scene


def _save_cache(scene, path, info):
    """The built state as an .npz (wall history sparse: its non-zero rows), atomically."""
    s = scene.state
    os.makedirs(cache_dir(), exist_ok=True)
    tmp = path + f".{os.getpid()}.tmp.npz"
    rows = np.flatnonzero(np.any(s.wall_hist.reshape(s.n, -1) != 0.0, axis=1)) if s.wall_hist.size else \
        np.zeros(0, dtype=np.int64)
    np.savez(tmp, box=scene.box, wall_rows=rows, wall_vals=s.wall_hist[rows], **{f: getattr(s, f) for f in SAVED},
             **{f"info_{k}": v for k, v in info.items() if v is not None})
    os.replace(tmp, path)


def _load_cache(scene, path):
    with np.load(path) as z:
        a = {f: z[f] for f in SAVED}
        n_walls = len(scene.walls)
        state = State(a["gid"], a["shape"], a["axes"], a["mass"], a["inertia"], a["material"], a["pos"], a["vel"],
                      a["quat"], a["angmom"], n_walls=n_walls, poly=a["poly"] if a["poly"].size else None)
        state.hist_start, state.hist_partner, state.hist_val = a["hist_start"], a["hist_partner"], a["hist_val"]
        state.wall_hist[z["wall_rows"]] = z["wall_vals"]
        box = z["box"]
        info = {k[5:]: z[k].item() for k in z.files if k.startswith("info_")}
    scene.state = state
    _set_box(scene, box)
    scene.extras["built"] = dict(info, cached=path, from_cache=True)


def _set_box(scene, box):
    scene.box = np.asarray(box, dtype=np.float64)
    scene.wall_m, scene.wall_d = wall_planes(scene.walls, scene.box)


def _serial(scene, skin=None):
    dt = choose_time_step(scene).dt  # the build's own step (the scene's dt policy)
    return SerialMode().setup(scene, dt=dt, skin=skin), dt


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
    mode.sync_history()  # the contact history the cache saves
    return {"method": "settle", "steps": k, "ke_ratio": ke / scale, "seconds": time.perf_counter() - t0}


def compress(scene, max_steps, rate, coordination, ke_tol, log=None, overlap=OVERLAP_TARGET,
             friction=BUILD_FRICTION, hold_steps=100, rough_steps=50, hysteresis=0.2, min_rate=0.2, gain=2.0,
             smoothing=0.1):
    """Pressure-servoed affine compression towards the box centre, gravity off during the build.

    Pressure proxy p = Z * (mean depth ratio of the touching particle-particle pairs), smoothed
    over ~1/`smoothing` steps; target p_t = `coordination` * `overlap`. Friction is capped at
    `friction` while compressing. Each step: compress by 2 * rate while Z < 1 and p < p_t / 2 (a
    dilute gas), then by rate * clip(gain * (1 - p / p_t), min_rate, 1) (the neighbours' approach
    speed falls near jamming); hold the walls once p >= p_t, and resume if p falls below
    (1 - hysteresis) * p_t (collisions of a gas, or creep). After `hold_steps` held steps the
    material friction is restored; jammed once `hold_steps` held steps (`rough_steps` of them with
    full friction) end with KE < ke_tol * sum(m) v_ref^2 (v_ref the first compression speed of the
    box faces). Returns build statistics."""
    g_saved = scene.gravity.copy()
    scene.gravity = np.zeros(3)
    mat = scene.materials
    mu_saved = mat.mu.copy(), mat.mu_w.copy()
    mat.mu[:] = np.minimum(mu_saved[0], friction)
    mat.mu_w[:] = np.minimum(mu_saved[1], friction)
    try:
        mode, dt = _serial(scene, skin=0.0)  # positions are scaled between steps: neighbours every step
        s = scene.state
        n = s.n_owned
        centre = 0.5 * (scene.box[0] + scene.box[1])
        v_ref = rate * float(np.max(scene.box[1] - scene.box[0])) / dt
        scale = float(s.mass.sum()) * v_ref ** 2
        p_t = coordination * overlap
        t0 = time.perf_counter()
        z = p = mo = 0.0
        ke = np.inf
        held = 0
        rough = 0  # step at which the full friction was restored (0: not yet)
        jammed = False
        for k in range(1, max_steps + 1):
            if held and p < (1.0 - hysteresis) * p_t:
                held = 0
            f = 0.0
            if not held:
                if z < 1.0 and p < 0.5 * p_t:
                    f = 2.0 * rate
                elif p < p_t:
                    f = rate * min(1.0, max(min_rate, gain * (1.0 - p / p_t)))
            if f > 0.0:
                s.pos[:n] = centre + (s.pos[:n] - centre) * (1.0 - f)
                _set_box(scene, centre + (scene.box - centre) * (1.0 - f))
            else:
                held += 1
            row = mode.step()
            z = 2.0 * row["n_contacts"] / n
            mo = row["pair_overlap_ratio_sum"] / row["n_contacts"] if row["n_contacts"] else 0.0
            p = z * mo if k == 1 else (1.0 - smoothing) * p + smoothing * z * mo
            if held >= hold_steps and not rough:
                rough = k
                mat.mu[:], mat.mu_w[:] = mu_saved
            if held >= hold_steps and k - rough >= rough_steps:
                ke = s.kinetic_energy()
                if ke < ke_tol * scale:
                    jammed = True
            if log and k % int(os.environ.get("DEM_BUILD_LOG_EVERY", 1000)) == 0:
                log(f"building {scene.name}: step {k}, coordination {z:.2f}, mean overlap {mo:.2%}, "
                    f"pressure/target {p / p_t:.2f}, KE ratio {s.kinetic_energy() / scale:.1e}")
            if jammed:
                break
        ke = s.kinetic_energy()
        mode.sync_history()  # the contact history the cache saves
    finally:
        mat.mu[:], mat.mu_w[:] = mu_saved
        scene.gravity = g_saved
    return {"method": "compress", "steps": k, "coordination": z, "mean_overlap": mo, "jammed": jammed,
            "ke_ratio": ke / scale, "seconds": time.perf_counter() - t0}


# --- rest ---------------------------------------------------------------------------------------
def rest_speed(state, dt):
    """v_rest = REST_DISP x (smallest bounding diameter) / (REST_STEPS x dt) [m/s]."""
    return REST_DISP * 2.0 * float(state.rbound[:state.n_owned].min()) / (REST_STEPS * dt)


def _speeds(mode):
    """(|v| [n], |omega| [n], point speed |v| + |omega| r_b [n]) of the owned particles, with omega the
    mode's derived angular velocity."""
    s = mode.state
    k = s.n_owned
    v = np.linalg.norm(s.vel[:k], axis=1)
    w = np.linalg.norm(mode.omega[:k], axis=1)
    return v, w, v + w * s.rbound[:k]


def rest(scene, rounds=30, damped=300, frictionless_walls=False, log=None):
    """Bring the scene's state to rest in place (module docstring). Each round: `damped` steps of local
    non-viscous damping (alpha = LOCAL_DAMPING) plus a viscous VISCOUS_DAMPING per step (which stops
    the steady sliding that local damping leaves alone), rattlers stopped (without gravity), walls
    frictionless where frictionless_walls (a cell to be mirror-tiled); then every velocity and angular
    momentum set to zero and CHECK_STEPS plain steps:
    at rest when the kinetic energy they end with is below KE_rest = M v_rest^2 / 2 (the rms point
    speed below v_rest); then zeroed again.
    Returns rest_* statistics."""
    mat = scene.materials
    mu_w = mat.mu_w.copy()
    if frictionless_walls:
        mat.mu_w[:] = 0.0
    t0 = time.perf_counter()
    try:
        mode, dt = _serial(scene)
        s = scene.state
        g = np.asarray(scene.gravity, dtype=np.float64)
        v_rest = rest_speed(s, dt)
        ke_rest = 0.5 * float(s.mass[:s.n_owned].sum()) * v_rest ** 2
        steps = 0
        reached = False
        for r in range(1, rounds + 1):
            for _ in range(damped):
                mode.step()
                n = s.n_owned
                f = s.force[:n] + s.mass[:n, None] * g
                t = s.torque[:n]
                v, lm = s.vel[:n], s.angmom[:n]
                v -= (dt * LOCAL_DAMPING / s.mass[:n])[:, None] * np.abs(f) * np.sign(v)
                lm -= dt * LOCAL_DAMPING * np.abs(t) * np.sign(mode.omega[:n])
                v *= 1.0 - VISCOUS_DAMPING
                lm *= 1.0 - VISCOUS_DAMPING
                if not np.any(g):  # without gravity a particle without any force is a rattler: stop it
                    free = ~(np.any(s.force[:n] != 0.0, axis=1) | np.any(t != 0.0, axis=1))
                    v[free] = 0.0
                    lm[free] = 0.0
                mode.derive(0, s.n)
            s.vel[:] = 0.0
            s.angmom[:] = 0.0
            mode.derive(0, s.n)
            for _ in range(CHECK_STEPS):
                mode.step()
            ke = s.kinetic_energy()
            steps += damped + CHECK_STEPS
            if log:
                log(f"resting {scene.name}: round {r}, KE / KE_rest after {CHECK_STEPS} free steps {ke / ke_rest:.2e}")
            if ke < ke_rest:
                reached = True
                break
        s.vel[:] = 0.0
        s.angmom[:] = 0.0
        mode.sync_history()
    finally:
        mat.mu_w[:] = mu_w
    return {"rest_steps": steps, "rest_rounds": r, "rest_reached": reached, "rest_ke_ratio_last_round": ke / ke_rest,
            "rest_s": time.perf_counter() - t0}


def rest_check(scene, steps=CHECK_STEPS):
    """What a run of the built scene sees: CHECK_STEPS plain steps on a copy; rest_* statistics of
    the last one (max |v| [m/s], max |omega| [rad/s], median |v|, particles whose point speed exceeds
    v_rest, KE / KE_rest) and the contacts at the first and last step."""
    twin = copy.deepcopy(scene)
    mode, dt = _serial(twin)
    s = twin.state
    rows = [mode.step() for _ in range(steps)]
    v, w, point = _speeds(mode)
    v_rest = rest_speed(s, dt)
    ke_rest = 0.5 * float(s.mass[:s.n_owned].sum()) * v_rest ** 2
    return {"rest_criterion": "KE after 50 free steps < M v_rest^2 / 2, v_rest = 1e-4 d_min / (1000 dt)",
            "rest_v_rest": v_rest,
            "rest_check_steps": steps, "rest_max_v": float(v.max()), "rest_max_omega": float(w.max()),
            "rest_median_v": float(np.median(v)), "rest_n_faster_than_v_rest": int((point > v_rest).sum()),
            "rest_ke_ratio": s.kinetic_energy() / ke_rest, "rest_contacts_first": int(rows[0]["n_contacts"]),
            "rest_contacts_last": int(rows[-1]["n_contacts"]),
            "rest_max_overlap_ratio": float(max(r["max_overlap_ratio"] for r in rows))}


# --- mirror tiling ------------------------------------------------------------------------------
def _near_cubic(t):
    """Tile counts (tx, ty, tz) with tx ty tz = t, the most cubic (smallest max/min), else None."""
    best = None
    for tx in range(1, t + 1):
        if t % tx:
            continue
        for ty in range(1, t // tx + 1):
            if (t // tx) % ty:
                continue
            tz = t // tx // ty
            key = (max(tx, ty, tz) / min(tx, ty, tz), -tz)
            if best is None or key < best[0]:
                best = (key, (tx, ty, tz))
    return best[1] if best and best[0][0] <= 2.0 else None


def tiling(n, cell_max=None):
    """(tiles (tx, ty, tz), cell size) for n particles: the smallest near-cubic T = tx ty tz (max/min
    <= 2) dividing n with n / T <= cell_max; else the smallest near-cubic T with ceil(n / T) <= cell_max
    (the surplus is removed after tiling). cell_max: default CELL_MAX."""
    cell_max = CELL_MAX if cell_max is None else cell_max
    lo = -(-n // cell_max)
    for t in range(max(2, lo), 64 * lo + 8):
        tiles = _near_cubic(t)
        if tiles and n % t == 0:
            return tiles, n // t
    for t in range(max(2, lo), 64 * lo + 8):
        tiles = _near_cubic(t)
        if tiles:
            return tiles, -(-n // t)
    raise ValueError(f"no tiling for {n} particles")


def _tiles_for(scene, build):
    """The tiling of a compress build too large for one cell (None: build directly)."""
    if build.get("method") != "compress" or not build.get("tile", True) or scene.n <= CELL_MAX:
        return None
    if not all(s.mirrors for s, _ in present(scene.state.shape)) or "doc" not in scene.extras:
        return None
    return tiling(scene.n)


def quats_of_matrices(r):
    """Unit quaternions [n, 4] (w >= 0) of rotation matrices r [n, 3, 3]: Shepperd's method row by row
    as dem.quaternion.quat_of_matrix, vectorised (the largest of 1 + t, 1 + 2 r_kk - t picks the branch)."""
    r = np.asarray(r, dtype=np.float64)
    t = np.trace(r, axis1=1, axis2=2)
    cand = np.stack([t, r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((len(r), 4))
    for b in range(4):
        m = r[k == b]
        if not len(m):
            continue
        if b == 0:
            s = 2.0 * np.sqrt(1.0 + t[k == b])
            qb = [0.25 * s, (m[:, 2, 1] - m[:, 1, 2]) / s, (m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 1, 0] - m[:, 0, 1]) / s]
        elif b == 1:
            s = 2.0 * np.sqrt(1.0 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2])
            qb = [(m[:, 2, 1] - m[:, 1, 2]) / s, 0.25 * s, (m[:, 0, 1] + m[:, 1, 0]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s]
        elif b == 2:
            s = 2.0 * np.sqrt(1.0 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2])
            qb = [(m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 0, 1] + m[:, 1, 0]) / s, 0.25 * s, (m[:, 1, 2] + m[:, 2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2])
            qb = [(m[:, 1, 0] - m[:, 0, 1]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s, (m[:, 1, 2] + m[:, 2, 1]) / s, 0.25 * s]
        q[k == b] = np.stack(qb, axis=1)
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[q[:, 0] < 0] *= -1.0
    return q


def mirror_tile(cell, tiles):
    """The State and box of the cell scene's state mirror-tiled tx x ty x tz (module docstring); gid
    of particle i in copy c is c n_cell + i (copies x fastest)."""
    s = cell.state
    n = s.n_owned
    tx, ty, tz = tiles
    lo, hi = cell.box[0], cell.box[1]
    size = hi - lo
    walls = list(cell.walls)
    copies = [(ix, iy, iz) for iz in range(tz) for iy in range(ty) for ix in range(tx)]
    rot = quat_to_matrices(s.quat[:n])
    parts = {f: [] for f in ("pos", "vel", "quat", "angmom", "wall")}
    counts = np.diff(s.hist_start)
    hp, hv, hs = [], [], [np.zeros(1, dtype=np.int64)]
    # a shape whose orientation shapes nothing (a sphere) keeps its quaternion in every copy
    unturned = ~np.array([shape.oriented for shape in shapes()])[s.shape[:n]]
    for c, idx in enumerate(copies):
        mirror = np.array([-1.0 if i % 2 else 1.0 for i in idx])
        det = float(np.prod(mirror))
        pos = s.pos[:n].copy()
        for a in range(3):
            if mirror[a] < 0:
                pos[:, a] = lo[a] + (idx[a] + 1) * size[a] - (pos[:, a] - lo[a])
            else:
                pos[:, a] = pos[:, a] + idx[a] * size[a]
        parts["pos"].append(pos)
        parts["vel"].append(s.vel[:n] * mirror)
        parts["angmom"].append(det * s.angmom[:n] * mirror)
        if det > 0 and np.all(mirror > 0):
            q = s.quat[:n].copy()
        else:
            d = np.array([-1.0, 1.0, 1.0]) if det < 0 else np.ones(3)
            q = quats_of_matrices(mirror[None, :, None] * rot * d[None, None, :])
            q[unturned] = s.quat[:n][unturned]
        parts["quat"].append(q)
        # wall history: a face of the cell maps to the copy's face on the mirrored side, kept where that
        # face is on the outside of the tiled box
        wh = np.zeros_like(s.wall_hist[:n])
        for w, face in enumerate(walls):
            axis, sign = WALL_FACES[face]
            side = sign * (-1 if mirror[axis] < 0 else 1)   # +1: the lower face of the copy
            i, t = idx[axis], tiles[axis]
            if (side > 0 and i == 0) or (side < 0 and i == t - 1):
                target = ("xyz"[axis] + ("-" if side > 0 else "+"))
                if target in walls:
                    row = s.wall_hist[:n, w].copy()
                    row[:, H_FT:H_FT + 3] *= mirror
                    wh[:, walls.index(target)] = row
        parts["wall"].append(wh)
        val = s.hist_val.copy()
        val[:, H_FT:H_FT + 3] *= mirror
        val[:, H_N:H_N + 3] *= mirror
        hp.append(s.hist_partner + c * n)
        hv.append(val)
        hs.append(s.hist_start[1:] + c * len(s.hist_partner))
    t = len(copies)
    state = State(np.arange(t * n, dtype=np.int64), np.tile(s.shape[:n], t), np.tile(s.axes[:n], (t, 1)),
                  np.tile(s.mass[:n], t), np.tile(s.inertia[:n], (t, 1)), np.tile(s.material[:n], t),
                  np.concatenate(parts["pos"]), np.concatenate(parts["vel"]), np.concatenate(parts["quat"]),
                  np.concatenate(parts["angmom"]), n_walls=len(walls),
                  poly=np.tile(s.poly[:n], (t, 1)) if s.has_poly else None)
    state.hist_start = np.concatenate(hs).astype(np.int64)
    state.hist_partner = np.concatenate(hp).astype(np.int64)
    state.hist_val = np.concatenate(hv).reshape(-1, HIST_LEN)
    state.wall_hist = np.concatenate(parts["wall"])
    assert len(state.hist_start) == t * n + 1 and counts.sum() * t == len(state.hist_partner)
    box = np.array([lo, lo + size * np.array(tiles)])
    return state, box


def drop_top(state, count, axis=2):
    """Remove the `count` particles with the largest coordinate along axis (the top layer at the z+
    wall) and renumber the rest 0..n-1 in gid order, with their history rows (pairs with a removed
    partner dropped)."""
    n = state.n_owned
    gone = np.argsort(state.pos[:n, axis], kind="stable")[n - count:]
    keep = np.ones(n, dtype=bool)
    keep[gone] = False
    new_id = np.cumsum(keep) - 1
    counts = np.diff(state.hist_start)
    owner = np.repeat(np.arange(n), counts)
    ok = keep[owner] & keep[state.hist_partner]
    partner = new_id[state.hist_partner[ok]]
    vals = state.hist_val[ok]
    rows = np.flatnonzero(keep)
    out = State(np.arange(len(rows), dtype=np.int64), state.shape[rows], state.axes[rows], state.mass[rows],
                state.inertia[rows], state.material[rows], state.pos[rows], state.vel[rows], state.quat[rows],
                state.angmom[rows], n_walls=state.wall_hist.shape[1],
                poly=state.poly[rows] if state.has_poly else None)
    out.hist_start = np.concatenate([[0], np.cumsum(np.bincount(new_id[owner[ok]], minlength=len(rows)))]).astype(
        np.int64)
    out.hist_partner = partner.astype(np.int64)
    out.hist_val = vals
    out.wall_hist = state.wall_hist[rows].copy()
    return out


def tile_build(scene, tiles_and_cell, log=None):
    """Build the scene's compress assembly by mirror tiling (module docstring), in place."""
    tiles, n_cell = tiles_and_cell
    ov = scene.extras["overrides"]
    cell = build_scene(scene.extras["doc"], name=scene.name, source=scene.source, particles=n_cell,
                       shape=ov["shape"], seed=ov["seed"])
    cell.extras["tile_cell"] = True   # rests with frictionless walls (module docstring)
    prepare(cell, log=log)   # cached by its own parameters
    t0 = time.perf_counter()
    state, box = mirror_tile(cell, tiles)
    surplus = state.n - scene.n
    info = {f"cell_{k}": v for k, v in cell.extras["built"].items() if k not in ("cached", "from_cache")}
    info.update(method="compress", tiles=f"{tiles[0]}x{tiles[1]}x{tiles[2]}", cell_particles=n_cell,
                surplus_removed=surplus)
    if surplus:
        state = drop_top(state, surplus)
    scene.state = state
    _set_box(scene, box)
    info["tile_s"] = time.perf_counter() - t0
    if surplus:
        info.update(rest(scene, log=log))
    return info
