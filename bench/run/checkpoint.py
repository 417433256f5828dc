"""Checkpoints: everything a run carries from one step to the next, to continue it later in any
mode or mapping (`bench run --checkpoint-every K`, `bench run --restart FILE`).

What a step carries (DESIGN.md, Restart) and where it is kept:
- per particle, sorted by global id: gid, shape, axes [n, 3] (semi-axes [m]), mass [kg],
  inertia [n, 3] (principal moments [kg m^2]), material, poly [n, POLY_LEN] (poly-ellipsoid
  records), pos [n, 3] [m], vel [n, 3] [m/s] (the half-step velocity of the leapfrog,
  v_{n+1/2}), quat [n, 4] (w, x, y, z body to world), angmom [n, 3] (world frame [kg m^2/s]);
  mass and inertia are stored, not recomputed, so they are the same bits;
- the contact history of every touching pair once (pair_i < pair_j global ids, pair_hist
  [m, HIST_LEN]: tangential spring [N], contact radius [m], PW lambda and normal: dem.state H_*);
  both ends of a pair hold identical rows, so the per-particle CSR is rebuilt on load;
- the wall history of every particle whose rows are not all zero (wall_rows [k] global ids,
  wall_hist [k, n_walls, HIST_LEN]);
- the scene around them: box [2, 3] [m], walls, gravity [3] [m/s^2], materials, its name;
- the run's clock and policy: step (the step number the records reached), time (simulated time
  [s], warm-up steps included), the TimeStep (dt, dt_auto, dt_critical and details: a restart
  steps with the same dt, to the bit), the contact method;
- the stability guard's running sums (initial kinetic energy, largest kinetic energy, gravity
  work [J]), so that the energy balance of run.json continues across a restart;
- the random generator state: none. Randomness is used only to generate a scene (its seed is
  part of the scene); a step draws nothing.
Not kept, because no result depends on it (tested): the neighbour list (a restart starts with a
rebuild; the list is a superset of the touching pairs, so its rebuild timing changes no bit),
memory order, the MPI block grid.

Format: one .npz (numpy, no pickles) with the arrays above and `meta`, a JSON string (floats by
repr: exact). Written atomically (a temporary file in the same folder, then a rename), so a crash
while writing leaves the previous checkpoint intact. Under MPI every rank sends its owned
particles and history rows to rank 0, which writes.
"""
import json
import os

import numpy as np

from dem.materials import Material, MaterialTable
from dem.particle_files import read_npz
from dem.scene import Scene, SceneError, wall_planes
from dem.state import HIST_LEN, State

FORMAT = "dem-mapping-bench checkpoint"
VERSION = 1
PARTICLE_FIELDS = ("gid", "shape", "axes", "mass", "inertia", "material", "poly", "pos", "vel", "quat", "angmom")
ARRAYS = PARTICLE_FIELDS + ("pair_i", "pair_j", "pair_hist", "wall_rows", "wall_hist", "box", "gravity")


def local_part(mode):
    """This rank's share of a checkpoint: its owned particles, the history rows of the touching
    pairs whose lower-gid end it owns (each pair exactly once over all ranks) and its non-zero
    wall-history rows."""
    mode.sync_history()  # the pair list's history into the state's per-particle rows
    s = mode.state
    k = s.n_owned
    part = {f: np.ascontiguousarray(getattr(s, f)[:k]) for f in PARTICLE_FIELDS}
    counts = np.diff(s.hist_start)
    owner = np.repeat(s.gid[:k], counts)
    lower = owner < s.hist_partner
    part["pair_i"] = owner[lower]
    part["pair_j"] = s.hist_partner[lower]
    part["pair_hist"] = s.hist_val[lower]
    wall = s.wall_hist[:k]
    keep = np.flatnonzero(np.any(wall.reshape(k, -1) != 0.0, axis=1)) if wall.size else np.zeros(0, dtype=np.int64)
    part["wall_rows"] = s.gid[:k][keep]
    part["wall_hist"] = wall[keep]
    return part


def gather(mode, comm=None):
    """The whole checkpoint's particle arrays, sorted by gid (rank 0; None on other ranks)."""
    part = local_part(mode)
    if comm is not None:
        parts = comm.gather(part, root=0)
        if comm.Get_rank() != 0:
            return None
        part = {f: np.concatenate([p[f] for p in parts]) for f in part}
    order = np.argsort(part["gid"], kind="stable")
    for f in PARTICLE_FIELDS:
        part[f] = part[f][order]
    order = np.lexsort((part["pair_j"], part["pair_i"]))
    for f in ("pair_i", "pair_j", "pair_hist"):
        part[f] = part[f][order]
    order = np.argsort(part["wall_rows"], kind="stable")
    part["wall_rows"], part["wall_hist"] = part["wall_rows"][order], part["wall_hist"][order]
    return part


def write_checkpoint(path, mode, scene, meta, comm=None):
    """Write the checkpoint of `mode` (collective under MPI: every rank calls it). meta: the run's
    clock, time step, guard sums and options (bench.run.driver). Returns the bytes written (rank 0)
    or 0."""
    part = gather(mode, comm)
    if part is None:
        return 0
    doc = dict(meta, format=FORMAT, version=VERSION, particles=int(len(part["gid"])),
               scene={"name": scene.name, "source": scene.source, "walls": list(scene.walls),
                      "materials": [m.__dict__ for m in scene.materials.materials], "dt": scene.dt,
                      "steps": scene.steps, "built": scene.extras.get("built"), "key": scene.extras.get("key")},
               rng=None)
    folder = os.path.dirname(os.path.abspath(path))
    tmp = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.tmp.npz")
    try:
        np.savez(tmp, meta=np.array(json.dumps(doc, default=_jsonable)), box=np.asarray(scene.box, dtype=np.float64),
                 gravity=np.asarray(scene.gravity, dtype=np.float64), **part)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return os.path.getsize(path)


def _jsonable(o):
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def read_meta(path):
    """The checkpoint's meta dict (SceneError, one line, when the file is not a checkpoint)."""
    return _meta(_open(path), path)


def _open(path):
    """{name: array} of the checkpoint at path, every array read (a truncated file, half written by
    a run that died without the atomic rename, fails here); SceneError with one line."""
    if not os.path.isfile(path):
        raise SceneError(f"checkpoint {path!r} not found")
    try:
        return read_npz(path)
    except OSError as e:
        raise SceneError(f"checkpoint {path!r} cannot be read ({e.strerror})") from None
    except ValueError as e:
        raise SceneError(f"checkpoint {path!r} {e}") from None


def _meta(z, path):
    try:
        meta = json.loads(str(z["meta"][()]))
    except (KeyError, ValueError, TypeError):
        raise SceneError(f"{path!r} is not a checkpoint of this program (no meta record)") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise SceneError(f"{path!r} is not a checkpoint of this program")
    if meta.get("version") != VERSION:
        raise SceneError(f"checkpoint {path!r} has format version {meta.get('version')}, this program reads {VERSION}")
    return meta


def history_csr(gid, pair_i, pair_j, pair_hist):
    """The per-particle history CSR (hist_start [n+1], hist_partner [nnz], hist_val [nnz, HIST_LEN])
    of particles gid [n] (ascending) from each touching pair once: both ends get the pair's row,
    each particle's rows in ascending partner gid (dem.state)."""
    n = len(gid)
    owner = np.concatenate([pair_i, pair_j])
    partner = np.concatenate([pair_j, pair_i])
    vals = np.concatenate([pair_hist, pair_hist]).reshape(-1, HIST_LEN)
    order = np.lexsort((partner, owner))
    rows = np.searchsorted(gid, owner[order])
    start = np.zeros(n + 1, dtype=np.int64)
    start[1:] = np.cumsum(np.bincount(rows, minlength=n))
    return start, np.ascontiguousarray(partner[order], dtype=np.int64), np.ascontiguousarray(vals[order])


def load_checkpoint(path):
    """(Scene, meta) of a checkpoint: the scene with its state as written (no build stage, no
    load-time checks: it is the continuation of a run that passed them). Bad files end as
    SceneError with one line."""
    z = _open(path)
    meta = _meta(z, path)
    missing = [f for f in ARRAYS if f not in z]
    if missing:
        raise SceneError(f"checkpoint {path!r} lacks {', '.join(missing)}")
    a = {f: z[f] for f in ARRAYS}
    sc = meta.get("scene") or {}
    try:
        gid = a["gid"].astype(np.int64)
        n = len(gid)
        walls = list(sc["walls"])
        box = np.asarray(a["box"], dtype=np.float64).reshape(2, 3)
        materials = MaterialTable([Material(**m) for m in sc["materials"]])
        state = State(gid, a["shape"], a["axes"], a["mass"], a["inertia"], a["material"], a["pos"], a["vel"],
                      a["quat"], a["angmom"], n_walls=len(walls), poly=a["poly"] if a["poly"].size else None)
        if np.any(gid[1:] <= gid[:-1]):
            raise ValueError("global ids not strictly ascending")
        state.hist_start, state.hist_partner, state.hist_val = history_csr(gid, a["pair_i"].astype(np.int64),
                                                                           a["pair_j"].astype(np.int64),
                                                                           a["pair_hist"])
        if len(a["wall_rows"]):
            state.wall_hist[np.searchsorted(gid, a["wall_rows"])] = a["wall_hist"]
        wall_m, wall_d = wall_planes(walls, box)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise SceneError(f"checkpoint {path!r} is damaged ({e})") from None
    ts = meta["time_step"]
    scene = Scene(name=sc.get("name", "restart"), box=box, walls=walls, wall_m=wall_m, wall_d=wall_d,
                  gravity=np.asarray(a["gravity"], dtype=np.float64), materials=materials, dt=float(ts["dt"]),
                  steps=int(sc.get("steps", 0)), state=state, source=os.path.abspath(path),
                  extras={"build": {}, "key": sc.get("key"), "built": sc.get("built"),
                          "restart": dict(meta, path=os.path.abspath(path))})
    if n != meta.get("particles"):
        raise SceneError(f"checkpoint {path!r} is damaged (holds {n} particles, its record says "
                         f"{meta.get('particles')})")
    return scene, meta
