"""Particle files: a scene's particles read from a file instead of TOML tables.

A scene names them in `[[particle_file]]` tables (dem.scene):

    [[particle_file]]
    path = "bed.txt"          # relative to the scene file's folder
    format = "auto"           # auto | npz | columns | csv | lammps
    columns = ["id", "x", "y", "z", "radius"]   # columns/csv without a header line that names them
    shape = "auto"            # auto | sphere | ellipsoid: what rows without shape information are
    shape_columns = "semi-axes"  # shapex/shapey/shapez are semi-axes (LIGGGHTS superquadrics) or
                              # "diameters" (LAMMPS atom_style ellipsoid, compute property/atom)
    material = "default"      # material of every row; or per LAMMPS type:
    types = { 1 = "default", 2 = "glass" }
    timestep = -1             # lammps: the snapshot to read (its TIMESTEP value; default the last)

Formats (SI units: metres, m/s, rad/s; no unit conversion is made):
- npz: arrays pos [n, 3] (required); axes [n, 3] (semi-axes a, b, c), [n, 6] (poly-ellipsoid
  [a+, a-, b+, b-, c+, c-], pos its octant origin) or radius [n]; optional shape [n] (dem.shapes
  codes: 0 sphere, 1 ellipsoid, 2 poly-ellipsoid), quat [n, 4] (w, x, y, z body to world), vel,
  omega [n, 3] (world frame), id [n], material [n] (index into the scene's materials in file
  order). A run's state.npz and its snapshots (bench run --snapshot-every) are such files.
- columns: whitespace-separated numbers, one particle a line; '#' lines are comments and the
  last comment line before the data names the columns (its first words, one per column), unless
  `columns` is given.
- csv: comma-separated, the first line names the columns.
- lammps: a LAMMPS or LIGGGHTS `dump custom` text file (ITEM: TIMESTEP / NUMBER OF ATOMS /
  BOX BOUNDS / ATOMS <columns>); several snapshots may follow one another (the last is read, or
  the one of `timestep`); `box = "file"` in [domain] takes its BOX BOUNDS (orthogonal boxes only).
Column names (LAMMPS dump custom and compute property/atom keywords, LIGGGHTS superquadric ones):
  id, type; x y z (also xu yu zu; xs ys zs scaled by the dump's box); radius (or r) or diameter
  (a sphere); shapex shapey shapez (an ellipsoid: semi-axes, or diameters with shape_columns =
  "diameters"; a row with three equal values is an ellipsoid all the same, unless shape =
  "sphere"); quatw quati quatj quatk (LAMMPS) or quat1 quat2 quat3 quat4 (LIGGGHTS: quat1 is the
  scalar part), both body to world; blockiness1 blockiness2 (LIGGGHTS superquadric: must be 2,
  an ellipsoid); vx vy vz [m/s]; omegax omegay omegaz [rad/s] (world frame). Other columns
  (mass, density, forces, ...) are ignored: masses come from the material's density.
Rows are taken in ascending id when there is an id column (LAMMPS dumps are not sorted unless
dump_modify sort id), else in file order; the scene numbers them from 0 in that order (the
global ids of the run's records) and error messages also give the file's id.

read_particle_file returns a ParticleBlock of arrays; it never loops over particles in Python,
so a million particles load in seconds (pandas' C reader for text).
"""
import os
import zipfile
import zlib
from dataclasses import dataclass

import numpy as np

from dem.shapes import ELLIPSOID, POLY, SPHERE

FORMATS = ("auto", "npz", "columns", "csv", "lammps")


class ParticleFileError(ValueError):
    """A particle file that cannot be read; str() is one line naming the file and the problem."""


@dataclass
class ParticleBlock:
    """Particles of one source, as arrays: shape [n] int8 (dem.shapes codes), axes [n, 6] (semi-axes
    a, b, c in the first three columns; a poly-ellipsoid's [a+, a-, b+, b-, c+, c-]) [m], pos [n, 3]
    [m] (a poly-ellipsoid's octant origin), quat [n, 4] (w, x, y, z body to world, unit), vel [n, 3]
    [m/s], omega [n, 3] [rad/s] (world), material [n] int32, ids [n] int64 (the file's ids, or
    None), source (a name for messages), box [2, 3] (a dump's box, or None)."""
    shape: np.ndarray
    axes: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    vel: np.ndarray
    omega: np.ndarray
    material: np.ndarray
    ids: object = None
    source: str = ""
    box: object = None

    @property
    def n(self):
        return len(self.shape)


# what reading a damaged or truncated .npz raises, at its opening or at an array's first read
NPZ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def read_npz(path):
    """{name: array} of every array of the .npz at path, read now (np.load reads lazily, so a
    truncated file fails at the array it cannot read). Raises ValueError with one line: not a zip
    of .npy arrays, or damaged."""
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"PK\x03\x04":
        raise ValueError("is not an .npz file (a zip of .npy arrays)")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except NPZ_ERRORS as e:
        raise ValueError(f"is damaged or truncated ({type(e).__name__}: {e})") from None


def _err(path, msg):
    return ParticleFileError(f"particle file {path}: {msg}")


def detect_format(path):
    """npz by extension or zip magic, lammps when the file starts with 'ITEM: TIMESTEP', csv by
    extension, else whitespace columns."""
    with open(path, "rb") as fh:
        head = fh.read(64)
    if path.endswith(".npz") or head.startswith(b"PK\x03\x04"):
        return "npz"
    if head.lstrip().startswith(b"ITEM: TIMESTEP"):
        return "lammps"
    if path.lower().endswith(".csv"):
        return "csv"
    return "columns"


def read_particle_file(path, fmt="auto", columns=None, shape="auto", shape_columns="semi-axes", material=0,
                       types=None, timestep=None):
    """The particles of a file as a ParticleBlock (see the module docstring). material: the material
    index of every row; types: {LAMMPS type: material index} (rows of other types are refused)."""
    if fmt not in FORMATS:
        raise _err(path, f"unknown format {fmt!r} ({', '.join(FORMATS)})")
    if shape not in ("auto", "sphere", "ellipsoid"):
        raise _err(path, f"shape must be auto, sphere or ellipsoid, got {shape!r}")
    if shape_columns not in ("semi-axes", "diameters"):
        raise _err(path, f"shape_columns must be 'semi-axes' or 'diameters', got {shape_columns!r}")
    if not os.path.isfile(path):
        raise _err(path, "not found")
    if fmt == "auto":
        fmt = detect_format(path)
    box = None
    try:
        if fmt == "npz":
            return _from_npz(path, material)
        if fmt == "lammps":
            table, box = _read_lammps(path, timestep)
        else:
            table = _read_text(path, fmt, columns)
    except (OSError, UnicodeDecodeError) as e:
        raise _err(path, f"cannot be read ({e})") from None
    return _from_table(path, table, box, shape, shape_columns, material, types)


def _read_text(path, fmt, columns):
    """{column name: float array} of a whitespace or comma table."""
    import pandas as pd
    names = list(columns) if columns else None
    skip = 0
    if fmt == "columns":
        header = None
        with open(path) as fh:
            for line in fh:
                s = line.strip()
                if not s or s.startswith("#"):
                    skip += 1
                    if s.startswith("#"):
                        header = s.lstrip("#").split()
                    continue
                ncol = len(s.split())
                break
            else:
                raise _err(path, "holds no particle rows")
        if names is None:
            if header is None or len(header) < ncol:
                raise _err(path, "no header comment names its columns; give columns = [...] in the scene")
            names = [w.strip(",") for w in header[:ncol]]
        elif len(names) != ncol:
            raise _err(path, f"has {ncol} columns but columns names {len(names)}")
        try:
            df = pd.read_csv(path, sep=r"\s+", header=None, names=names, skiprows=skip, comment="#",
                             dtype=np.float64, engine="c")
        except (ValueError, pd.errors.ParserError) as e:
            raise _err(path, f"malformed row ({_short(e)})") from None
    else:
        try:
            df = pd.read_csv(path, header=None if names else 0, names=names, comment="#", skipinitialspace=True,
                             dtype=np.float64, engine="c")
        except (ValueError, pd.errors.ParserError) as e:
            raise _err(path, f"malformed row ({_short(e)})") from None
        df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise _err(path, "holds no particle rows")
    return {c: df[c].to_numpy(dtype=np.float64) for c in df.columns}


def _short(e):
    return str(e).strip().splitlines()[-1][:160] if str(e).strip() else type(e).__name__


def _read_lammps(path, timestep):
    """(table, box [2, 3]) of one snapshot of a LAMMPS `dump custom` file (the last one, or the
    one whose TIMESTEP is `timestep`)."""
    import pandas as pd
    snaps = []   # (timestep, n, box, column names, byte offset of the first row)
    with open(path, "rb") as fh:
        while True:
            line = fh.readline()
            if not line:
                break
            if not line.startswith(b"ITEM: TIMESTEP"):
                if line.strip():
                    raise _err(path, f"expected 'ITEM: TIMESTEP', got {line.strip()[:40].decode(errors='replace')!r}")
                continue
            try:
                step = int(fh.readline())
                if not fh.readline().startswith(b"ITEM: NUMBER OF ATOMS"):
                    raise ValueError("no NUMBER OF ATOMS")
                n = int(fh.readline())
                bounds = fh.readline().decode()
                if not bounds.startswith("ITEM: BOX BOUNDS"):
                    raise ValueError("no BOX BOUNDS")
                lims = [fh.readline().split() for _ in range(3)]
                if len(bounds.split()) > 6 or any(len(x) != 2 for x in lims):
                    raise ValueError("triclinic boxes are not supported")
                box = np.array([[float(x[0]) for x in lims], [float(x[1]) for x in lims]])
                atoms = fh.readline().decode()
                if not atoms.startswith("ITEM: ATOMS"):
                    raise ValueError("no ATOMS header")
            except ValueError as e:
                raise _err(path, f"malformed dump header near TIMESTEP ({e})") from None
            names = atoms.split()[2:]
            offset = fh.tell()
            snaps.append((step, n, box, names, offset))
            for _ in range(n):
                if not fh.readline():
                    raise _err(path, f"snapshot of TIMESTEP {step} ends after fewer than {n} rows")
    if not snaps:
        raise _err(path, "holds no 'ITEM: TIMESTEP' snapshot")
    if timestep is None:
        step, n, box, names, offset = snaps[-1]
    else:
        pick = [s for s in snaps if s[0] == timestep]
        if not pick:
            raise _err(path, f"has no snapshot of TIMESTEP {timestep} (has {', '.join(str(s[0]) for s in snaps[:8])})")
        step, n, box, names, offset = pick[0]
    if n == 0:
        raise _err(path, f"snapshot of TIMESTEP {step} holds no atoms")
    with open(path, "rb") as fh:
        fh.seek(offset)
        try:
            df = pd.read_csv(fh, sep=r"\s+", header=None, names=names, nrows=n, dtype=np.float64, engine="c")
        except (ValueError, pd.errors.ParserError) as e:
            raise _err(path, f"malformed row in the snapshot of TIMESTEP {step} ({_short(e)})") from None
    if len(df) != n or df.isna().any().any():
        raise _err(path, f"snapshot of TIMESTEP {step}: rows with missing values")
    table = {c: df[c].to_numpy(dtype=np.float64) for c in df.columns}
    for a, s in zip("xyz", range(3)):   # scaled coordinates
        if a + "s" in table and a not in table:
            table[a] = box[0, s] + table[a + "s"] * (box[1, s] - box[0, s])
    return table, box


def _cols(table, names, path, what):
    for group in names:
        if all(c in table for c in group):
            return np.stack([table[c] for c in group], axis=1)
    return None


def _from_table(path, table, box, shape, shape_columns, material, types):
    pos = _cols(table, [("x", "y", "z"), ("xu", "yu", "zu")], path, "position")
    if pos is None:
        raise _err(path, f"has no position columns x y z (columns: {', '.join(table)})")
    n = len(pos)
    ids = table["id"].astype(np.int64) if "id" in table else None
    if ids is not None and np.any(ids != table["id"]):
        raise _err(path, "has non-integer ids")
    sem = _cols(table, [("shapex", "shapey", "shapez")], path, "shape")
    axes = np.zeros((n, 6))
    if sem is not None:
        if shape_columns == "diameters":
            sem = 0.5 * sem
        axes[:, :3] = sem
        code = np.full(n, ELLIPSOID, dtype=np.int8)
        for b in ("blockiness1", "blockiness2"):
            if b in table and np.any(table[b] != 2.0):
                k = int(np.flatnonzero(table[b] != 2.0)[0])
                raise _err(path, f"row {k} has {b} = {table[b][k]:g}: only blockiness 2 (an ellipsoid) is supported")
        if shape == "sphere":
            if np.any((sem[:, 0] != sem[:, 1]) | (sem[:, 0] != sem[:, 2])):
                raise _err(path, "shape = \"sphere\" but shapex, shapey, shapez differ")
            code[:] = SPHERE
    elif "radius" in table or "r" in table or "diameter" in table:
        r = table["radius"] if "radius" in table else table["r"] if "r" in table else 0.5 * table["diameter"]
        if shape == "ellipsoid":
            code = np.full(n, ELLIPSOID, dtype=np.int8)
        else:
            code = np.full(n, SPHERE, dtype=np.int8)
        axes[:, 0] = axes[:, 1] = axes[:, 2] = r
    else:
        raise _err(path, "has no size columns (radius, diameter, or shapex shapey shapez)")
    quat = _cols(table, [("quatw", "quati", "quatj", "quatk"), ("quat1", "quat2", "quat3", "quat4")], path, "quat")
    vel = _cols(table, [("vx", "vy", "vz")], path, "velocity")
    omega = _cols(table, [("omegax", "omegay", "omegaz")], path, "omega")
    mat = np.full(n, material, dtype=np.int32)
    if types is not None and "type" in table:
        t = table["type"].astype(np.int64)
        mat = np.empty(n, dtype=np.int32)
        for tv in np.unique(t):
            if int(tv) not in types:
                raise _err(path, f"has atoms of type {int(tv)}, which `types` does not map to a material")
            mat[t == tv] = types[int(tv)]
    return _finish(path, code, axes, pos, quat, vel, omega, mat, ids, box)


def _finish(path, code, axes, pos, quat, vel, omega, mat, ids, box):
    """Validate and order the rows (ascending id where ids are given)."""
    n = len(code)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if quat is None else np.array(quat, dtype=np.float64)
    vel = np.zeros((n, 3)) if vel is None else np.asarray(vel, dtype=np.float64)
    omega = np.zeros((n, 3)) if omega is None else np.asarray(omega, dtype=np.float64)
    for what, a in (("position", pos), ("size", axes), ("quaternion", quat), ("velocity", vel), ("omega", omega)):
        bad = ~np.isfinite(a).all(axis=1)
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise _err(path, f"row {k}{_id(ids, k)} has a non-finite {what}")
    width = np.where(code == POLY, 6, 3)
    small = (axes <= 0.0) & (np.arange(6)[None, :] < width[:, None])
    if np.any(small):
        k = int(np.flatnonzero(small.any(axis=1))[0])
        raise _err(path, f"row {k}{_id(ids, k)} has a size <= 0")
    qn = np.linalg.norm(quat, axis=1)
    if np.any(qn == 0.0):
        k = int(np.flatnonzero(qn == 0.0)[0])
        raise _err(path, f"row {k}{_id(ids, k)} has a zero quaternion")
    off = np.abs(qn - 1.0) > 1e-12   # unit to round-off (a file written at full precision) stays as written
    quat[off] = quat[off] / qn[off, None]
    if ids is not None:
        order = np.argsort(ids, kind="stable")
        sid = ids[order]
        twice = np.flatnonzero(sid[1:] == sid[:-1])
        if len(twice):
            raise _err(path, f"id {int(sid[twice[0]])} appears twice")
        if np.any(order != np.arange(n)):
            code, axes, pos, quat, vel, omega, mat, ids = (a[order] for a in (code, axes, pos, quat, vel, omega, mat,
                                                                                ids))
    return ParticleBlock(np.ascontiguousarray(code, dtype=np.int8), np.ascontiguousarray(axes, dtype=np.float64),
                         np.ascontiguousarray(pos, dtype=np.float64), np.ascontiguousarray(quat),
                         np.ascontiguousarray(vel), np.ascontiguousarray(omega), np.ascontiguousarray(mat), ids,
                         os.path.basename(path), box)


def _id(ids, k):
    return "" if ids is None else f" (id {int(ids[k])})"


def _from_npz(path, material):
    try:
        z = read_npz(path)
    except OSError as e:
        raise _err(path, f"cannot be read ({e.strerror})") from None
    except ValueError as e:
        raise _err(path, str(e)) from None
    files = set(z)
    if "meta" in files and "angmom" in files:
        raise _err(path, "is a checkpoint: continue it with `bench run --restart FILE`")
    if "pos" not in files:
        raise _err(path, f"has no 'pos' array (arrays: {', '.join(sorted(files))})")
    pos = np.asarray(z["pos"], dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise _err(path, f"pos must be [n, 3], got {list(pos.shape)}")
    n = len(pos)

    def get(name, width):
        if name not in files:
            return None
        a = np.asarray(z[name], dtype=np.float64)
        if a.shape != (n, width):
            raise _err(path, f"{name} must be [{n}, {width}], got {list(a.shape)}")
        return a
    axes = np.zeros((n, 6))
    if "axes" in files:
        ax = np.asarray(z["axes"], dtype=np.float64)
        if ax.ndim != 2 or ax.shape[0] != n or ax.shape[1] not in (1, 3, 6):
            raise _err(path, f"axes must be [{n}, 3] or [{n}, 6], got {list(ax.shape)}")
        if ax.shape[1] == 1:
            ax = np.repeat(ax, 3, axis=1)
        axes[:, :ax.shape[1]] = ax
        default = np.full(n, POLY if ax.shape[1] == 6 else ELLIPSOID, dtype=np.int8)
    elif "radius" in files:
        r = np.asarray(z["radius"], dtype=np.float64).reshape(-1)
        if len(r) != n:
            raise _err(path, f"radius must be [{n}], got {len(r)} values")
        axes[:, 0] = axes[:, 1] = axes[:, 2] = r
        default = np.full(n, SPHERE, dtype=np.int8)
    else:
        raise _err(path, "has neither 'axes' nor 'radius'")
    code = np.asarray(z["shape"]).astype(np.int8) if "shape" in files else default
    if code.shape != (n,) or np.any((code < SPHERE) | (code > POLY)):
        raise _err(path, "shape must hold n codes 0 (sphere), 1 (ellipsoid) or 2 (poly-ellipsoid)")
    if "axes" in files and z["axes"].shape[1] == 6:
        # a run's state.npz of a poly scene repeats each semi-axis of its ellipsoids and spheres
        nonpoly = code != POLY
        axes[nonpoly, :3] = axes[nonpoly][:, 0::2]
        axes[nonpoly, 3:] = 0.0
    elif np.any(code == POLY):
        raise _err(path, "poly-ellipsoids (shape 2) need axes [n, 6]")
    mat = np.full(n, material, dtype=np.int32)
    if "material" in files:
        mat = np.asarray(z["material"]).astype(np.int32).reshape(-1)
    ids = np.asarray(z["id"]).astype(np.int64) if "id" in files else None
    return _finish(path, code, axes, pos, get("quat", 4), get("vel", 3), get("omega", 3), mat, ids, None)
