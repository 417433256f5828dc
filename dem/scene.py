"""Scenes: TOML files of explicit and generated particles -> a State plus run settings.

Format (DESIGN.md): [domain] box, walls, gravity; [materials.NAME]; [time] dt, steps;
[[particles]] explicit particles; [[generate]] generated particles:

    [[generate]]
    count = 500                     # number of particles
    shape = "ellipsoid"             # sphere | ellipsoid | polyellipsoid
    gradation = [[1.0e-3, 0.0], [2.0e-3, 1.0]]  # [largest diameter 2a [m], fraction passing by number]
    aspect_b = [0.6, 0.9]           # b/a drawn uniformly in this range (ellipsoids)
    aspect_c = [0.4, 0.7]           # c/a drawn uniformly in this range (ellipsoids)
    asymmetry = [0.6, 1.0]          # poly-ellipsoids: each a-/a+, b-/b+, c-/c+ drawn uniformly
                                    # in this range; the extents a+ + a-, b+ + b-, c+ + c- follow
                                    # the gradation and aspects (largest extent = the diameter)
    placement = "lattice"           # lattice | random
    spacing = 1.2                   # lattice pitch over the largest bounding diameter
    pitch = [1.6e-3, 1.6e-3, 1.6e-3]  # or the lattice's site spacing along x, y, z [m], instead of
                                    # spacing: below the diameters it builds a touching crystal,
                                    # whose overlaps the load-time checks accept up to the guard's limit
    columns = [9, 9]                # lattice sites along x and y (default: square-ish)
    order = "rows"                  # the particles' order over the lattice sites: rows (x fastest,
                                    # then y, then z) or morton (the Z-order curve over the sites:
                                    # lattice_order); the order of their global ids
    region = [[x0,y0,z0],[x1,y1,z1]]  # placement region; default: the box. With box = "fit" the box
                                    # is fitted around the lattice instead.
    orientation = "random"          # random | aligned
    speed = 0.0                     # random initial velocity magnitude [m/s]
    material = "default"
    seed = 1

Errors in a scene raise SceneError with one line naming the problem and the field (a type
checked before it is used, a number finite and at most NUM_MAX in magnitude; dem/limits.py: the
size ratio the contact solver resolves and the memory a particle count needs).
"""
import math
import os
import tomllib
from dataclasses import dataclass, field

import numpy as np

from dem.limits import LimitError, check_particle_count, check_size_ratio
from dem.materials import Material, MaterialTable
from dem.quaternion import quat_to_matrices, random_quaternions
from dem.shapes import POLY, POLY_LEN
from dem.overlaps import DEFAULT_OVERLAP_LIMIT, worst_pair_overlap
from dem.particle_files import ParticleBlock, ParticleFileError, read_particle_file
from dem.shapes.polyellipsoid import octant_pose
from dem.shapes.registry import BY_NAME, present, smallest_semi_axes
from dem.state import State

WALL_FACES = {"x-": (0, +1), "x+": (0, -1), "y-": (1, +1), "y+": (1, -1), "z-": (2, +1), "z+": (2, -1)}
BUILTIN_DIR = os.path.join(os.path.dirname(__file__), "scenes")


class SceneError(ValueError):
    """A scene that cannot be built; str() is one line naming the problem."""


@dataclass
class Scene:
    name: str
    box: np.ndarray                    # [2, 3] lower and upper corner [m]
    walls: list                        # face names, in file order
    wall_m: np.ndarray                 # [n_walls, 3] unit normals into the domain
    wall_d: np.ndarray                 # [n_walls] plane offsets, m.x = d
    gravity: np.ndarray                # [3] [m/s^2]
    materials: MaterialTable
    dt: object                         # "auto" or seconds
    steps: int
    state: State
    source: str = ""
    extras: dict = field(default_factory=dict)

    @property
    def n(self):
        return self.state.n_owned


def builtin_scenes():
    """Names and one-line descriptions of the built-in scenes."""
    out = {}
    for f in sorted(os.listdir(BUILTIN_DIR)):
        if f.endswith(".toml"):
            with open(os.path.join(BUILTIN_DIR, f), "rb") as fh:
                first = fh.readline().decode().lstrip("# ").strip()
            out[f[:-5]] = first
    return out


NUM_MAX = 1e30  # no SI quantity of a DEM scene comes near it; beyond it products overflow


def _num(v, what, positive=False):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SceneError(f"{what} must be a number, got {_show(v)}")
    v = float(v)
    if not math.isfinite(v):
        raise SceneError(f"{what} must be finite, got {v!r}")
    if abs(v) > NUM_MAX:
        raise SceneError(f"{what} = {v:g} is beyond any physical value (at most {NUM_MAX:g} in SI units)")
    if positive and v <= 0:
        raise SceneError(f"{what} must be positive, got {v!r}")
    return v


def _show(v, limit=60):
    """repr of a value, cut to `limit` characters (a message stays one short line)."""
    text = repr(v)
    return text if len(text) <= limit else text[:limit] + "..."


def _name(v, what, choices=None):
    """A string field (a name or a keyword); choices: the allowed ones."""
    if not isinstance(v, str):
        raise SceneError(f"{what} must be a string{' (' + ', '.join(choices) + ')' if choices else ''}, got {_show(v)}")
    if choices is not None and v not in choices:
        raise SceneError(f"{what}: unknown {v!r} ({', '.join(choices)})")
    return v


def _vec(v, n, what):
    if not isinstance(v, list) or len(v) != n:
        raise SceneError(f"{what} must be a list of {n} numbers, got {_show(v)}")
    return np.array([_num(x, f"{what}[{k}]") for k, x in enumerate(v)])


def _table(d, key, what):
    v = d.get(key, {})
    if not isinstance(v, dict):
        raise SceneError(f"{what} must be a table")
    return v


def _check_keys(d, allowed, what):
    for k in d:
        if k not in allowed:
            raise SceneError(f"unknown key {k!r} in {what} (allowed: {', '.join(sorted(allowed))})")


# the fewest particles a compress build (bench/run/prepare.py compress) rests: 1-3 packed ellipsoids
# were pressed into the walls (overlap 0.08-1.69 of the smallest semi-axis at the first step, the
# coordination target out of reach), 4-64 rested with a largest overlap of 0.8-1.8 % (measured with
# `bench run --scene packed --particles N --steps 2`, ellipsoids and spheres)
COMPRESS_MIN = 4


def load_scene(spec, particles=None, shape=None, seed=None, overlap_limit=None):
    """Build a Scene from a built-in name or a TOML path.

    particles: override the count of the (single) [[generate]] block; shape: override the shape
    of generated particles ("sphere" or "ellipsoid"); seed: override the generator seed.
    """
    if os.path.isfile(spec):
        path = spec
    elif spec in builtin_scenes():
        path = os.path.join(BUILTIN_DIR, spec + ".toml")
    elif spec.endswith(".toml"):
        raise SceneError(f"scene file {spec!r} not found")
    else:
        raise SceneError(f"unknown scene {spec!r} (built-ins: {', '.join(builtin_scenes())}; or a .toml file)")
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"malformed TOML in {path}: {e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"scene {path} is not UTF-8 text (byte {e.object[e.start:e.start + 1]!r} at offset "
                         f"{e.start}); TOML files are UTF-8") from None
    except RecursionError:
        raise SceneError(f"malformed TOML in {path}: arrays or tables nested too deep") from None
    except OSError as e:
        raise SceneError(f"cannot read scene {path}: {e.strerror}") from None
    name = os.path.splitext(os.path.basename(path))[0]
    return build_scene(doc, name=name, source=path, particles=particles, shape=shape, seed=seed,
                       overlap_limit=overlap_limit)


def build_scene(doc, name="scene", source="", particles=None, shape=None, seed=None, overlap_limit=None):
    _check_keys(doc, {"domain", "materials", "time", "particles", "generate", "particle_file", "build"}, "scene")
    dom = _table(doc, "domain", "[domain]")
    _check_keys(dom, {"box", "walls", "gravity"}, "[domain]")
    # --- materials
    mats_doc = _table(doc, "materials", "[materials]")
    if not mats_doc:
        raise SceneError("scene has no [materials.NAME] table")
    materials = []
    for mname, md in mats_doc.items():
        if not isinstance(md, dict):
            raise SceneError(f"[materials.{mname}] must be a table")
        _check_keys(md, {"density", "young", "poisson", "friction", "restitution"}, f"[materials.{mname}]")
        for key in ("density", "young", "poisson", "friction", "restitution"):
            if key not in md:
                raise SceneError(f"[materials.{mname}] is missing {key!r}")
        nu = _num(md["poisson"], f"materials.{mname}.poisson")
        if not (-1.0 < nu < 0.5):
            raise SceneError(f"materials.{mname}.poisson must be in (-1, 0.5), got {nu}")
        e = _num(md["restitution"], f"materials.{mname}.restitution")
        if not (0.0 < e <= 1.0):
            raise SceneError(f"materials.{mname}.restitution must be in (0, 1], got {e}")
        mu = _num(md["friction"], f"materials.{mname}.friction")
        if mu < 0:
            raise SceneError(f"materials.{mname}.friction must be >= 0, got {mu}")
        materials.append(Material(mname, _num(md["density"], f"materials.{mname}.density", True),
                                  _num(md["young"], f"materials.{mname}.young", True), nu, mu, e))
    table = MaterialTable(materials)
    # --- time
    tdoc = _table(doc, "time", "[time]")
    _check_keys(tdoc, {"dt", "steps"}, "[time]")
    dt = tdoc.get("dt", "auto")
    if dt != "auto":
        dt = _num(dt, "time.dt", positive=True)
    steps = tdoc.get("steps", 100)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise SceneError(f"time.steps must be a non-negative integer, got {steps!r}")
    # --- build stage (settling before step 0, done and cached by the harness)
    build = _table(doc, "build", "[build]")
    _check_keys(build, {"method", "max_steps", "ke_tol", "rate", "coordination", "rest", "tile"}, "[build]")
    if build:
        if build.get("method") not in ("settle", "compress"):
            raise SceneError(f"build.method must be 'settle' or 'compress', got {build.get('method')!r}")
        ss = build.get("max_steps", 5000)
        if isinstance(ss, bool) or not isinstance(ss, int) or ss <= 0:
            raise SceneError(f"build.max_steps must be a positive integer, got {ss!r}")
        for key, default in (("ke_tol", 1e-4), ("rate", 2e-4), ("coordination", 4.5)):
            _num(build.get(key, default), f"build.{key}", positive=True)
        for key in ("rest", "tile"):
            if not isinstance(build.get(key, True), bool):
                raise SceneError(f"build.{key} must be true or false, got {build.get(key)!r}")
    # --- particles: explicit tables, generated blocks and particle files, in that order
    blocks = []
    plist = doc.get("particles", [])
    if not isinstance(plist, list):
        raise SceneError("[[particles]] must be an array of tables")
    if plist:
        blocks.append(_rows_block([_explicit_particle(p, k, table) for k, p in enumerate(plist)]))
    gens = doc.get("generate", [])
    if isinstance(gens, dict):
        gens = [gens]
    if not isinstance(gens, list):
        raise SceneError(f"[[generate]] must be an array of tables, got {_show(gens)}")
    if (particles is not None or shape is not None) and len(gens) != 1:
        raise SceneError("--particles/--shape need a scene with exactly one [[generate]] block")
    box_doc = dom.get("box")
    fit_box = box_doc == "fit"
    file_box = box_doc == "file"
    box = None
    if not fit_box and not file_box:
        if not isinstance(box_doc, list) or len(box_doc) != 2:
            raise SceneError("domain.box must be [[x0, y0, z0], [x1, y1, z1]], \"fit\" or \"file\"")
        box = np.array([_vec(box_doc[0], 3, "domain.box[0]"), _vec(box_doc[1], 3, "domain.box[1]")])
        if np.any(box[1] <= box[0]):
            raise SceneError("domain.box upper corner must exceed the lower corner on every axis")
    files = doc.get("particle_file", [])
    if isinstance(files, dict):
        files = [files]
    if not isinstance(files, list):
        raise SceneError("[[particle_file]] must be an array of tables")
    file_blocks = [_file_block(f, k, table, base_dir(source)) for k, f in enumerate(files)]
    if file_box:
        boxes = [b.box for b in file_blocks if b.box is not None]
        if not boxes:
            raise SceneError("domain.box = \"file\" needs a [[particle_file]] in LAMMPS dump format (its BOX BOUNDS)")
        box = np.array([np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)])
    first = sum(b.n for b in blocks)
    for g in gens:
        block, gbox = _generate(g, table, box, particles, shape, seed, first)
        blocks.append(block)
        first += block.n
        if fit_box:
            box = gbox if box is None else np.array([np.minimum(box[0], gbox[0]), np.maximum(box[1], gbox[1])])
    blocks.extend(file_blocks)
    if not blocks or sum(b.n for b in blocks) == 0:
        raise SceneError("scene has no particles ([[particles]], [[generate]] or [[particle_file]])")
    try:
        check_size_ratio(np.concatenate([b.axes for b in blocks]))
    except LimitError as e:
        raise SceneError(str(e)) from None
    if box is None:
        raise SceneError("domain.box = \"fit\" needs a lattice [[generate]] block")
    # --- walls, gravity
    walls = dom.get("walls", [])
    if not isinstance(walls, list):
        raise SceneError(f"domain.walls must be a list of faces, got {walls!r}")
    for w in walls:
        if not isinstance(w, str) or w not in WALL_FACES:
            raise SceneError(f"unknown wall {w!r} (faces: {', '.join(WALL_FACES)})")
    if len(set(walls)) != len(walls):
        raise SceneError("domain.walls lists a face twice")
    wall_m, wall_d = wall_planes(walls, box)
    gravity = _vec(dom.get("gravity", [0.0, 0.0, 0.0]), 3, "domain.gravity")
    state = _assemble(blocks, table, len(walls))
    if build.get("method") == "compress" and state.n < COMPRESS_MIN:
        raise SceneError(f"a compress build needs at least {COMPRESS_MIN} particles, got {state.n}: fewer never reach "
                         f"the coordination it compresses to, and its walls press into them")
    limit = DEFAULT_OVERLAP_LIMIT if overlap_limit is None else float(overlap_limit)
    labels = _Labels(blocks)
    _validate_positions(state, box, wall_m, wall_d, walls, limit, labels)
    _check_pair_overlaps(state, limit, labels)
    import hashlib
    import json
    key = json.dumps({"doc": doc, "particles": particles, "shape": shape, "seed": seed,
                      "files": [_file_stamp(f, base_dir(source)) for f in files]}, sort_keys=True, default=str)
    return Scene(name=name, box=box, walls=list(walls), wall_m=wall_m, wall_d=wall_d, gravity=gravity,
                 materials=table, dt=dt, steps=steps, state=state, source=source,
                 extras={"build": dict(build), "key": hashlib.sha256(key.encode()).hexdigest()[:16],
                         "doc": doc, "overrides": {"particles": particles, "shape": shape, "seed": seed}})


def base_dir(source):
    """The folder that relative particle-file paths start from: the scene file's."""
    return os.path.dirname(os.path.abspath(source)) if source else os.getcwd()


def _file_stamp(f, folder):
    """What identifies a particle file's content for the build cache: path, size, modification time."""
    if not isinstance(f, dict) or not isinstance(f.get("path"), str):
        return None
    path = os.path.join(folder, f["path"])
    try:
        st = os.stat(path)
        return [os.path.abspath(path), st.st_size, st.st_mtime_ns]
    except OSError:
        return None


def _file_block(f, k, table, folder):
    """A [[particle_file]] table -> ParticleBlock (dem.particle_files); errors as one line."""
    what = f"particle_file[{k}]"
    if not isinstance(f, dict):
        raise SceneError(f"[[particle_file]] entry {k} must be a table")
    _check_keys(f, {"path", "format", "columns", "shape", "shape_columns", "material", "types", "timestep"}, what)
    path = f.get("path")
    if not isinstance(path, str) or not path:
        raise SceneError(f"{what} needs path = \"FILE\"")
    cols = f.get("columns")
    if cols is not None and (not isinstance(cols, list) or not all(isinstance(c, str) for c in cols)):
        raise SceneError(f"{what}.columns must be a list of column names")
    mname = f.get("material", "default" if "default" in table.index else table.materials[0].name)
    if mname not in table.index:
        raise SceneError(f"{what}: unknown material {mname!r} (defined: {', '.join(table.index)})")
    types = f.get("types")
    if types is not None:
        if not isinstance(types, dict):
            raise SceneError(f"{what}.types must be a table {{type = \"material\"}}")
        tmap = {}
        for t, m in types.items():
            if not str(t).lstrip("-").isdigit():
                raise SceneError(f"{what}.types: keys must be LAMMPS type numbers, got {t!r}")
            if m not in table.index:
                raise SceneError(f"{what}.types: unknown material {m!r} (defined: {', '.join(table.index)})")
            tmap[int(t)] = table.index[m]
        types = tmap
    step = f.get("timestep")
    if step is not None and (isinstance(step, bool) or not isinstance(step, int)):
        raise SceneError(f"{what}.timestep must be an integer, got {step!r}")
    try:
        block = read_particle_file(os.path.join(folder, path), f.get("format", "auto"), cols, f.get("shape", "auto"),
                                   f.get("shape_columns", "semi-axes"), table.index[mname], types, step)
    except ParticleFileError as e:
        raise SceneError(str(e)) from None
    if block.n and (block.material.min() < 0 or block.material.max() >= len(table.materials)):
        raise SceneError(f"{what}: material indices outside 0..{len(table.materials) - 1}")
    block.source = path
    return block


def _rows_block(rows):
    """Explicit particle rows (dicts) -> ParticleBlock."""
    n = len(rows)
    axes = np.zeros((n, 6))
    for k, r in enumerate(rows):
        axes[k, :len(r["axes"])] = r["axes"]
    return ParticleBlock(np.array([r["shape"] for r in rows], dtype=np.int8), axes,
                         np.array([r["pos"] for r in rows], dtype=np.float64).reshape(n, 3),
                         np.array([r["quat"] for r in rows], dtype=np.float64).reshape(n, 4),
                         np.array([r["vel"] for r in rows], dtype=np.float64).reshape(n, 3),
                         np.array([r["omega"] for r in rows], dtype=np.float64).reshape(n, 3),
                         np.array([r["material"] for r in rows], dtype=np.int32))


class _Labels:
    """Names of particles for messages: the scene index (file order, the run's global id) and, for a
    particle from a particle file, its id there."""

    def __init__(self, blocks):
        self.starts = np.cumsum([0] + [b.n for b in blocks])
        self.blocks = blocks

    def __call__(self, k):
        b = int(np.searchsorted(self.starts, k, side="right") - 1)
        block = self.blocks[b]
        if block.source:
            r = k - int(self.starts[b])
            where = f"id {int(block.ids[r])}" if block.ids is not None else f"row {r}"
            return f"particle {k} ({where} of {block.source})"
        return f"particle {k}"


def _assemble(blocks, table, n_walls):
    """The State of the particle blocks, vectorised (no loop over particles but the poly-ellipsoids'
    rigid-body set-up): each shape's rigid body (dem.shapes.shape.Shape.body: mass [kg], principal
    moments [kg m^2], mass centre and principal frame), angular momentum L = R diag(I) R^T omega
    (world)."""
    shape_arr = np.concatenate([b.shape for b in blocks]).astype(np.int8)
    n = len(shape_arr)
    axes6 = np.concatenate([b.axes for b in blocks])
    pos = np.concatenate([b.pos for b in blocks])
    quat = np.concatenate([b.quat for b in blocks])
    vel = np.concatenate([b.vel for b in blocks])
    omega = np.concatenate([b.omega for b in blocks])
    mat = np.concatenate([b.material for b in blocks]).astype(np.int32)
    rho = np.array([m.density for m in table.materials])[mat]
    axes, mass, inertia, poly = np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3)), None
    for shape, rows in present(shape_arr):  # each shape's rigid body (Shape.body)
        rows = np.arange(n) if rows is None else rows
        body = shape.body(axes6[rows], rho[rows], pos[rows], quat[rows])
        axes[rows], mass[rows], inertia[rows], pos[rows], quat[rows], rec = body
        if rec is not None:
            poly = np.zeros((n, POLY_LEN)) if poly is None else poly
            poly[rows] = rec
    gid = np.arange(n, dtype=np.int64)
    state = State(gid, shape_arr, axes, mass, inertia, mat, pos, vel, quat, np.zeros((n, 3)), n_walls=n_walls,
                  poly=poly)
    spin = np.flatnonzero(np.any(omega != 0.0, axis=1))
    if len(spin):  # L = R I R^T omega (world frame), all spinning particles at once
        rots = quat_to_matrices(state.quat[spin])
        body = np.einsum("kji,kj->ki", rots, omega[spin])
        state.angmom[spin] = np.einsum("kij,kj->ki", rots, state.inertia[spin] * body)
    return state


def wall_planes(walls, box):
    """Planes m.x = d of the named box faces: m [n_walls, 3] unit normals into the box, d [n_walls]."""
    wall_m = np.zeros((len(walls), 3))
    wall_d = np.zeros(len(walls))
    for k, w in enumerate(walls):
        axis, sign = WALL_FACES[w]
        wall_m[k, axis] = sign
        wall_d[k] = sign * (box[0][axis] if sign > 0 else box[1][axis])
    return wall_m, wall_d


def _explicit_particle(p, k, table):
    what = f"particles[{k}]"
    if not isinstance(p, dict):
        raise SceneError(f"{what} must be a table")
    _check_keys(p, {"shape", "axes", "pos", "quat", "vel", "omega", "material"}, what)
    name = p.get("shape", "sphere")
    if not isinstance(name, str) or name not in BY_NAME:
        raise SceneError(f"{what}: unknown shape {_show(name)} ({', '.join(BY_NAME)})")
    shape = BY_NAME[name]
    if "axes" not in p or "pos" not in p:
        raise SceneError(f"{what} needs 'axes' and 'pos'")
    ax = p["axes"]
    if not isinstance(ax, list) or len(ax) != len(shape.file_axes):
        raise SceneError(f"{what}: {name} axes must be [{', '.join(shape.file_axes)}], got {ax!r}")
    values = _vec(ax, len(ax), f"{what}.axes")
    if np.any(values <= 0):
        raise SceneError(f"{what}: axes must be positive, got {ax!r}")
    axes = shape.semi_axes(values)
    quat = _vec(p.get("quat", [1.0, 0.0, 0.0, 0.0]), 4, f"{what}.quat")
    qn = np.linalg.norm(quat)
    if qn == 0:
        raise SceneError(f"{what}: quat must be non-zero")
    mname = p.get("material", "default" if "default" in table.index else table.materials[0].name)
    if not isinstance(mname, str) or mname not in table.index:
        raise SceneError(f"{what}: unknown material {mname!r} (defined: {', '.join(table.index)})")
    return {"shape": shape.code, "axes": axes, "pos": _vec(p["pos"], 3, f"{what}.pos"), "quat": quat / qn,
            "vel": _vec(p.get("vel", [0.0, 0.0, 0.0]), 3, f"{what}.vel"),
            "omega": _vec(p.get("omega", [0.0, 0.0, 0.0]), 3, f"{what}.omega"), "material": table.index[mname]}


def _sample_gradation(grad, n, rng, what):
    """Largest diameters [n] by inverse-CDF sampling of a piecewise-linear gradation curve."""
    if not isinstance(grad, list) or len(grad) < 1:
        raise SceneError(f"{what}.gradation must be a list of [diameter, fraction passing]")
    pts = np.array([_vec(g, 2, f"{what}.gradation point") for g in grad])
    if np.any(pts[:, 0] <= 0):
        raise SceneError(f"{what}.gradation diameters must be positive")
    if len(pts) == 1:
        return np.full(n, pts[0, 0])
    if np.any(np.diff(pts[:, 0]) <= 0) or np.any(np.diff(pts[:, 1]) < 0):
        raise SceneError(f"{what}.gradation must have increasing diameters and non-decreasing fractions")
    if pts[0, 1] != 0.0 or pts[-1, 1] != 1.0:
        raise SceneError(f"{what}.gradation fractions must run from 0 to 1")
    u = rng.random(n)
    return np.interp(u, pts[:, 1], pts[:, 0])


def _generate(g, table, box, particles, shape_override, seed_override, first_index):
    what = "[[generate]]"
    if not isinstance(g, dict):
        raise SceneError(f"{what} must be a table")
    _check_keys(g, {"count", "shape", "gradation", "aspect_b", "aspect_c", "asymmetry", "placement", "spacing",
                    "pitch", "columns", "order", "region", "orientation", "speed", "material", "seed"}, what)
    count = particles if particles is not None else g.get("count")
    if isinstance(count, bool) or not isinstance(count, int) or count <= 0:
        raise SceneError(f"particle count must be a positive integer, got {_show(count)}")
    try:
        check_particle_count(count, "particle count" if particles is not None else f"{what}.count")
    except LimitError as e:
        raise SceneError(str(e)) from None
    shape = shape_override or g.get("shape", "sphere")
    if not isinstance(shape, str) or shape not in BY_NAME:
        raise SceneError(f"unknown shape {_show(shape)} ({', '.join(BY_NAME)})")
    kind = BY_NAME[shape]
    code = kind.code
    seed = seed_override if seed_override is not None else g.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SceneError(f"{what}.seed must be a non-negative integer, got {_show(seed)}")
    rng = np.random.default_rng(seed)
    diam = _sample_gradation(g.get("gradation"), count, rng, what)

    def draw(key, default, size):  # a [lo, hi] range of the [[generate]] table, drawn (Shape.generate)
        lo, hi = _vec(g.get(key, default), 2, f"{what}.{key}")
        if not (0 < lo <= hi <= 1):
            raise SceneError(f"{what}.{key} must satisfy 0 < lo <= hi <= 1, got {[float(lo), float(hi)]}")
        return rng.uniform(lo, hi, size)
    axes, cen = kind.generate(diam / 2.0, draw)  # cen: the mass centre from the octant origin
    rb = axes.max(axis=1) + np.linalg.norm(cen, axis=1)
    orient = g.get("orientation", "random")
    if orient == "random":
        quat = random_quaternions(count, rng) if kind.oriented else np.tile([1.0, 0, 0, 0], (count, 1))
    elif orient == "aligned":
        quat = np.tile([1.0, 0, 0, 0], (count, 1))
    else:
        raise SceneError(f"{what}.orientation must be 'random' or 'aligned', got {orient!r}")
    mname = g.get("material", "default" if "default" in table.index else table.materials[0].name)
    if not isinstance(mname, str) or mname not in table.index:
        raise SceneError(f"{what}: unknown material {mname!r} (defined: {', '.join(table.index)})")
    placement = g.get("placement", "lattice")
    dmax = 2.0 * float(rb.max())
    region = None
    if "region" in g:
        rg = g["region"]
        if not isinstance(rg, list) or len(rg) != 2:
            raise SceneError(f"{what}.region must be [[x0,y0,z0],[x1,y1,z1]]")
        region = np.array([_vec(rg[0], 3, f"{what}.region[0]"), _vec(rg[1], 3, f"{what}.region[1]")])
    elif box is not None:
        region = box.copy()
    if placement == "lattice":
        if "pitch" in g:
            if "spacing" in g:
                raise SceneError(f"{what}: give spacing or pitch, not both")
            pitch = _vec(g["pitch"], 3, f"{what}.pitch")
            if np.any(pitch <= 0):
                raise SceneError(f"{what}.pitch must be three positive lengths [m], got {pitch.tolist()}")
        else:
            pitch = dmax * _num(g.get("spacing", 1.2), f"{what}.spacing")
            if pitch < dmax:
                raise SceneError(f"{what}.spacing must be >= 1 (pitch below the largest diameter)")
            pitch = np.full(3, pitch)
        if "columns" in g:
            cols = g["columns"]
            if (not isinstance(cols, list) or len(cols) != 2 or
                    any(isinstance(c, bool) or not isinstance(c, int) or c <= 0 for c in cols)):
                raise SceneError(f"{what}.columns must be two positive integers")
            nx, ny = cols
        elif region is not None:
            nx = max(1, int((region[1, 0] - region[0, 0]) // pitch[0]))
            ny = max(1, int((region[1, 1] - region[0, 1]) // pitch[1]))
        else:
            nx = ny = max(1, int(round(count ** (1 / 3))))
        nz = -(-count // (nx * ny))
        if region is None:
            region = np.array([[0.0, 0.0, 0.0], [nx, ny, nz]]) * pitch
            gbox = region.copy()
        else:
            gbox = None
            if np.any(region[0] + np.array([nx, ny, nz]) * pitch > region[1] + 1e-12 * pitch):
                raise SceneError(f"{count} particles at pitch {_show(pitch.tolist())} m do not fit the region "
                                 f"({nx}x{ny}x{nz} lattice sites needed)")
        sites = lattice_order(count, nx, ny, _name(g.get("order", "rows"), f"{what}.order", ("rows", "morton")))
        pos = region[0] + (sites + 0.5) * pitch
    elif placement == "random":
        if region is None:
            raise SceneError(f"{what}: random placement needs a box or region")
        gbox = None
        pos = _random_placement(region, rb, rng, what)
    else:
        raise SceneError(f"{what}.placement must be 'lattice' or 'random', got {placement!r}")
    speed = _num(g.get("speed", 0.0), f"{what}.speed")
    if speed < 0:
        raise SceneError(f"{what}.speed must be >= 0 (a magnitude [m/s]), got {speed:g}")
    vel = np.zeros((count, 3))
    if speed > 0:
        d = rng.standard_normal((count, 3))
        vel = speed * d / np.linalg.norm(d, axis=1)[:, None]
    if np.any(cen != 0.0):  # the mass centre sits on the site; a row gives the octant origin (DESIGN.md)
        pos = pos - np.einsum("kab,kb->ka", quat_to_matrices(quat), cen)
    ax6 = np.zeros((count, 6))
    ax6[:, :axes.shape[1]] = axes
    block = ParticleBlock(np.full(count, code, dtype=np.int8), ax6, np.ascontiguousarray(pos),
                          np.ascontiguousarray(quat, dtype=np.float64), vel, np.zeros((count, 3)),
                          np.full(count, table.index[mname], dtype=np.int32))
    return block, gbox


def lattice_order(count, nx, ny, order):
    """The lattice sites [count, 3] (integer x, y, z; nx x ny sites a layer, layers filled from
    z = 0) of particles 0..count-1: order "rows" fills them x fastest, then y, then z; "morton"
    takes the same sites along the Z-order curve (Morton 1966: the sites sorted by their
    coordinates' bits interleaved), so that particles of nearby global ids lie near each other in
    all three directions, not only along x. The threads mode cuts its gid-sorted pair list into T
    ranges of consecutive ids (modes.parallel): rows make them slabs, of which at 16 ranges of 12k
    packed ellipsoids 67 % of the particles have pairs in two (they store and gather their
    forces), the Z-order compact blocks, 26 % (the rested pack, its neighbour list at skin 0); the
    16 ranges' work of a step fell by 0.26 ms of 22 (`bench perf --what phases --threads 16
    --work`), while the serial resolution of one pack stored and numbered along the curve took
    4.6 % more than in rows (15.96 -> 16.69 ms, 12k packed ellipsoids, twice each, alternating):
    along x the rows keep every neighbour within a layer's reach in memory, the curve's jumps do
    not. So the built-in scenes keep rows."""
    k = np.arange(count)
    sites = np.stack([k % nx, (k // nx) % ny, k // (nx * ny)], axis=1)
    if order == "rows":
        return sites
    code = np.zeros(count, dtype=np.int64)
    # the sites' bits, 21 at most a direction (63 in a code); beyond 2^21 sites along one
    # direction the order is still a permutation of the sites, no longer the curve's
    for bit in range(min(int(sites.max()).bit_length(), 21)):
        for d in range(3):
            code |= ((sites[:, d] >> bit) & 1) << (3 * bit + d)
    return sites[np.argsort(code, kind="stable")]


def _random_placement(region, rb, rng, what, attempts=200):
    """Random sequential addition of non-overlapping bounding spheres inside region [2, 3]."""
    order = np.argsort(-rb, kind="stable")
    pos = np.zeros((len(rb), 3))
    placed = []
    cell = 2.0 * rb.max()
    grid = {}
    for k in order:
        lo = region[0] + rb[k]
        hi = region[1] - rb[k]
        if np.any(hi < lo):
            raise SceneError(f"{what}: region smaller than a particle")
        for _ in range(attempts):
            p = rng.uniform(lo, hi)
            key = tuple((p // cell).astype(int))
            ok = True
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for dz in (-1, 0, 1):
                        for q in grid.get((key[0] + dx, key[1] + dy, key[2] + dz), ()):
                            if np.sum((pos[q] - p) ** 2) < (rb[q] + rb[k]) ** 2:
                                ok = False
                                break
                        if not ok:
                            break
                    if not ok:
                        break
                if not ok:
                    break
            if ok:
                pos[k] = p
                grid.setdefault(key, []).append(k)
                placed.append(k)
                break
        else:
            raise SceneError(f"{what}: could not place {len(rb)} particles at random in the region "
                             f"(placed {len(placed)}); enlarge the region or use lattice placement")
    return pos


def _check_pair_overlaps(state, limit, label):
    """Refuse (SceneError, one line) the deepest particle-particle overlap above `limit` of the smaller
    body's smallest semi-axis (dem.overlaps); resting contacts below it are accepted."""
    worst = worst_pair_overlap(state, limit)
    if worst is None:
        return
    ratio, depth, a, b = worst
    if ratio <= limit * (1.0 + 1e-9):
        return
    if not math.isfinite(depth):
        raise SceneError(f"{label(a)} and {label(b)} coincide (centres {state.pos[a].tolist()}): two bodies "
                         f"cannot share a place")
    raise SceneError(f"{label(a)} and {label(b)} overlap by {depth:.3g} m, {100 * ratio:.3g} % of the smaller "
                     f"smallest semi-axis (resting contacts up to {100 * limit:g} %, the stability guard's limit, "
                     f"are accepted)")


def _validate_positions(state, box, wall_m, wall_d, walls, limit, label=lambda k: f"particle {k}"):
    """Refuse (SceneError, one line) a particle whose centre is outside the box, or that overlaps a
    wall by more than `limit` of its smallest semi-axis (the stability guard's overlap limit: a
    resting contact with a wall, as a settled bed from another code has, is accepted). A wall's
    overlap is the support distance h = |diag(a) R^T m| (m the wall normal into the box; a
    poly-ellipsoid's support from its octant origin, contact-mechanics.md §2.2) minus the centre's
    distance m.x - d to the plane [m]."""
    n = state.n
    pos = state.pos
    out = np.any(pos < box[0], axis=1) | np.any(pos > box[1], axis=1)
    if np.any(out):
        k = int(np.flatnonzero(out)[0])
        raise SceneError(f"{label(k)} centre {pos[k].tolist()} is outside the box")
    if not len(wall_m) or n == 0:
        return
    rots = quat_to_matrices(state.quat)
    amin = smallest_semi_axes(state.axes, state.shape, state.poly)
    polys = np.flatnonzero(state.shape == POLY)
    worst = (0.0, -1, -1, 0.0)
    for w in range(len(wall_m)):
        m = wall_m[w]
        u = np.einsum("kji,j->ki", rots, m) * state.axes      # diag(a) R^T m
        h = np.sqrt(np.sum(u * u, axis=1))
        for k in polys:  # poly support along -m from the octant origin
            o, qo = octant_pose(pos[k], state.quat[k], state.poly[k])
            nb = quat_to_matrices(qo)[0].T @ (-m)
            a6 = state.poly[k, :6]
            alpha = np.where(nb >= 0, a6[0::2], a6[1::2])
            h[k] = float(np.linalg.norm(alpha * nb)) + m @ (pos[k] - o)
        depth = h - (pos @ m - wall_d[w])
        ratio = depth / amin
        k = int(np.argmax(ratio))
        if ratio[k] > worst[0]:
            worst = (float(ratio[k]), k, w, float(depth[k]))
    ratio, k, w, depth = worst
    if ratio > limit * (1.0 + 1e-9):
        raise SceneError(f"{label(k)} overlaps a wall ({walls[w]}) by {depth:.3g} m, {100 * ratio:.3g} % of its "
                         f"smallest semi-axis (resting contacts up to {100 * limit:g} %, the stability guard's limit, "
                         f"are accepted)")
