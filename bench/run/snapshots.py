"""Snapshots for ParaView and meshio: binary VTU (default) or legacy ASCII VTK, with an npz beside.

`write_vtu` (`bench run --snapshot-format vtu`, the default) writes a VTK XML UnstructuredGrid with
one VTK_VERTEX cell per particle (Int32 connectivity and offsets below 2^31 particles, UInt8
types), its arrays appended as zlib-compressed binary (compressor="vtkZLibDataCompressor", level
ZLIB_LEVEL = 1, 32 KiB blocks, UInt64 block headers, little-endian), numpy and zlib only,
atomically (temporary file + os.replace). Points and every floating-point point array are
float32 (VTU_FLOAT), each value the float64 state rounded to the nearest float32 (bit for bit
state.astype(np.float32)); the exact float64 state is in the step<k:08d>.npz written beside every
snapshot. Point data, particles sorted by id as in the npz:
  id (int64), shape (int8), axes (semi-axes, 3), quat (w, x, y, z; 4), vel, omega, and `ellipsoid`,
  the symmetric tensor R diag(a, b, c) R^T as VTK's 6 symmetric components XX, YY, ZZ, XY, YZ, XZ
  (the active Tensors): its eigenvalues are the semi-axes and its eigenvectors the body axes, so
  ParaView's Tensor Glyph (Glyph Type Sphere, Extract Eigenvalues on, Scale Factor 2: the sphere
  source has radius 0.5) draws each particle as its ellipsoid. Checked with VTK 9.7.2:
  vtkXMLUnstructuredGridReader reads every array bit for bit (the 6-component tensor as the
  active tensors) and vtkTensorGlyph's vertices lie on the particles' surfaces to 3e-9 m in a 3 cm
  box (6e-6 of the smallest semi-axis; 2e-9 m from float64 data: the glyph's own float32 points
  dominate).
The body axes scaled by their semi-axes, axis_k = R[:, k] axes[k] (point arrays axis_x/y/z before;
dropped for size, see below), are the tensor's eigenvectors times its eigenvalues, or from quat
(w, x, y, z) and axes with R's columns (1 - 2(y^2 + z^2), 2(xy + wz), 2(xz - wy)),
(2(xy - wz), 1 - 2(x^2 + z^2), 2(yz + wx)), (2(xz + wy), 2(yz - wx), 1 - 2(x^2 + y^2)); in
ParaView's Python Calculator axis_x is
  axes[:,0:1]*make_vector(1-2*(quat[:,2]**2+quat[:,3]**2), 2*(quat[:,1]*quat[:,2]+quat[:,0]*quat[:,3]), 2*(quat[:,1]*quat[:,3]-quat[:,0]*quat[:,2]))
(checked with VTK's numpy_interface: float32 rounding, 3e-7 of the semi-axis), and in float64 from
the npz quat_to_matrices(quat)[:, :, k] * axes[:, k:k + 1].
Field data TimeValue [s] (Float64) and STEP. A poly-ellipsoid scene (snapshot axes [n, 6]) adds
`axes6` [a+, a-, b+, b-, c+, c-] as point data; its points are the octant origins, quat the octant
frames, `axes` and `ellipsoid` use the plus half-axes (a glyph can only approximate a
poly-ellipsoid), and `*_surface.vtu` holds every particle's exact surface as triangles (unchanged:
float64 vertices, Int64 connectivity, raw, not compressed).
`snapshots.pvd` (and `snapshots_surface.pvd`) list every snapshot with its simulated time, rewritten
atomically after each, so that ParaView opens the run as one time series.

Size (issue 34's target: a VTU of 1M ellipsoids at most 1/4 of the legacy file). Measured with a
synthetic snapshot (not in the repository) of 1 000 000 ellipsoids: positions uniform in a 1 m box,
uniformly random unit quaternions, semi-axes uniform in 0.5-1.5 mm, velocities N(0, 0.1 m/s),
angular velocities N(0, 10 rad/s); bytes a particle, ratio to the legacy file, time to write the
1M snapshot on a shared 2-core machine:
  legacy write_vtk (ASCII, %.17g; 559 MB)                    558.6 B   1          26 s
  before: float64 raw, axis_x/y/z, 9-component tensor       298.0 B   0.533      1.7 s
  float32, Int32 connectivity                                154.0 B   0.276      1.3 s
  + 6-component tensor                                       142.0 B   0.254      1.0 s
  + without axis_x/y/z                                       106.0 B   0.190      0.7 s
  + zlib level 1 (this writer; 85 MB)                         84.7 B   0.152      2.4-2.9 s (0.25-0.28 s at 100k)
  zlib level 6 instead                                        84.5 B   0.151      3.2 s
  zlib level 1 keeping axis_x/y/z                            118.1 B   0.211      3.1 s
  float64, 6-component tensor, no axis_*, zlib level 1       173.0 B   0.310      4.1 s
zlib squeezes id, shape, connectivity, offsets and types to almost nothing and the float32 data
by a few per cent; 32 KiB, 64 KiB and 1 MiB blocks give the same size. Legacy files of run scenes
are smaller (470-500 B a particle measured on 1000-5000 ellipsoids: shorter ids, zero
components), hence the margin below 1/4 (axis_* kept with zlib, 0.21 here, would be 0.24-0.25
of those).
Reading the 1M file: meshio 5.8 s, VTK 0.5 s.

`write_vtk` (`--snapshot-format vtk`) is the earlier legacy ASCII POLYDATA writer, unchanged:
float64 as %.17g, point fields id, shape, quat, axes, axis_x/y/z, vel, omega (no tensor; axes6 as
a field array), `*_surface.vtk`, no series file.

write_snapshot(mode, folder, k, time, rank, fmt) writes step<k:08d>.vtu|.vtk and step<k:08d>.npz
of a run's state.
"""  # noqa: E501
import os
import xml.etree.ElementTree as ET
import zlib

import numpy as np

from bench.run.records import atomic_write
from dem.quaternion import quat_to_matrices

SNAPSHOT_FORMATS = ("vtu", "vtk")
SERIES = "snapshots.pvd"                  # the particles' time series
SURFACE_SERIES = "snapshots_surface.pvd"  # the poly-ellipsoid surfaces' time series
VTK_VERTEX, VTK_TRIANGLE = 1, 5
ZLIB_LEVEL = 1        # write_vtu's zlib level (module doc: level 1 is ~as small as 6 and faster)
ZLIB_BLOCK = 1 << 15  # bytes of raw data a compressed block (VTK's own default)
VTU_FLOAT = np.float32  # write_vtu's float arrays (module doc: the npz beside holds the float64 state)
_VTK_TYPES = {"i1": "Int8", "u1": "UInt8", "i2": "Int16", "u2": "UInt16", "i4": "Int32", "u4": "UInt32",
              "i8": "Int64", "u8": "UInt64", "f4": "Float32", "f8": "Float64"}


def write_vtk(path, snap, step=0, time=0.0):
    """Write snapshot dict (id, pos, quat, vel, omega, axes, shape) as ASCII legacy VTK; returns
    the files written."""
    n = len(snap["id"])
    rot = quat_to_matrices(snap["quat"])
    six = snap["axes"].shape[1] == 6
    axes3 = snap["axes"][:, 0::2] if six else snap["axes"]
    lines = ["# vtk DataFile Version 3.0", f"DEM snapshot step {step} time {time:.9g}", "ASCII",
             "DATASET POLYDATA", f"POINTS {n} double"]
    lines += [f"{p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" for p in snap["pos"]]
    lines.append(f"VERTICES {n} {2 * n}")
    lines += [f"1 {k}" for k in range(n)]
    lines.append(f"POINT_DATA {n}")
    lines += ["SCALARS id long 1", "LOOKUP_TABLE default"] + [str(int(v)) for v in snap["id"]]
    lines += ["SCALARS shape int 1", "LOOKUP_TABLE default"] + [str(int(v)) for v in snap["shape"]]
    lines += ["SCALARS quat double 4", "LOOKUP_TABLE default"] + [" ".join(f"{c:.17g}" for c in q)
                                                                  for q in snap["quat"]]
    lines += ["VECTORS axes double"] + [" ".join(f"{c:.17g}" for c in a) for a in axes3]
    for k, name in enumerate(("axis_x", "axis_y", "axis_z")):
        vec = rot[:, :, k] * axes3[:, k:k + 1]
        lines += [f"VECTORS {name} double"] + [" ".join(f"{c:.17g}" for c in v) for v in vec]
    lines += ["VECTORS vel double"] + [" ".join(f"{c:.17g}" for c in v) for v in snap["vel"]]
    lines += ["VECTORS omega double"] + [" ".join(f"{c:.17g}" for c in v) for v in snap["omega"]]
    if six:
        lines += ["FIELD FieldData 1", f"axes6 6 {n} double"]
        lines += [" ".join(f"{c:.17g}" for c in a) for a in snap["axes"]]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    written = [path]
    if six:
        surface = _surface_path(path, ".vtk")
        write_surfaces(surface, snap, step, time)
        written.append(surface)
    return written


def _surface_path(path, ext):
    """The surfaces' file beside a snapshot path: stem + "_surface" + ext (ext: ".vtk" or ".vtu")."""
    return (path[:-len(ext)] if path.endswith(ext) else path) + "_surface" + ext


def _unit_sphere(nlat=8, nlon=12):
    """Vertices [v, 3] and triangles [t, 3] of a latitude-longitude unit sphere."""
    verts = [[0.0, 0.0, 1.0]]
    for i in range(1, nlat):
        th = np.pi * i / nlat
        for j in range(nlon):
            ph = 2 * np.pi * j / nlon
            verts.append([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    verts.append([0.0, 0.0, -1.0])
    tris = []
    last = len(verts) - 1
    for j in range(nlon):
        tris.append([0, 1 + j, 1 + (j + 1) % nlon])
    for i in range(nlat - 2):
        a, b = 1 + i * nlon, 1 + (i + 1) * nlon
        for j in range(nlon):
            j1 = (j + 1) % nlon
            tris += [[a + j, b + j, b + j1], [a + j, b + j1, a + j1]]
    base = 1 + (nlat - 2) * nlon
    for j in range(nlon):
        tris.append([base + j, last, base + (j + 1) % nlon])
    return np.array(verts), np.array(tris)


def _surface_points(snap):
    """Surface vertices [n, v, 3] of every particle and the triangles [t, 3] of one (write_surfaces)."""
    u, tris = _unit_sphere()
    rot = quat_to_matrices(snap["quat"])
    a6 = snap["axes"] if snap["axes"].shape[1] == 6 else np.repeat(snap["axes"], 2, axis=1)
    plus, minus = a6[:, 0::2], a6[:, 1::2]
    alpha = np.where(u[None, :, :] >= 0, plus[:, None, :], minus[:, None, :])          # [n, v, 3]
    pts = snap["pos"][:, None, :] + np.einsum("nab,nvb->nva", rot, alpha * u[None, :, :])
    return pts, tris


def write_surfaces(path, snap, step=0, time=0.0):
    """Every particle's surface as triangles: unit-sphere points u map to o + R (alpha o u), alpha the
    semi-axes of u's octant (a+ or a- by the sign of each component; Peters et al. 2009), so each
    octant is an exact ellipsoid piece. Cell data: id."""
    pts, tris = _surface_points(snap)
    n = len(snap["id"])
    nv, nt = pts.shape[1], len(tris)
    lines = ["# vtk DataFile Version 3.0", f"DEM particle surfaces step {step} time {time:.9g}", "ASCII",
             "DATASET POLYDATA", f"POINTS {n * nv} double"]
    lines += [f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in pts.reshape(-1, 3)]
    lines.append(f"POLYGONS {n * nt} {4 * n * nt}")
    for k in range(n):
        off = k * nv
        lines += [f"3 {t[0] + off} {t[1] + off} {t[2] + off}" for t in tris]
    lines += [f"CELL_DATA {n * nt}", "SCALARS id long 1", "LOOKUP_TABLE default"]
    lines += [str(int(v)) for v in np.repeat(snap["id"], nt)]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def _vtk_array(arr):
    """Little-endian contiguous copy of arr and its VTK type name."""
    arr = np.ascontiguousarray(arr)
    le = arr.dtype.newbyteorder("<")
    return arr.astype(le, copy=False), _VTK_TYPES[le.str[1:]]


def _array_tag(name, arr, offset, indent, tuples=False):
    """A DataArray element for arr ([n] or [n, c]) at offset of the appended data."""
    arr, vtk_type = _vtk_array(arr)
    label = f' Name="{name}"' if name else ""
    comps = f' NumberOfComponents="{arr.shape[1]}"' if arr.ndim == 2 else ""
    count = f' NumberOfTuples="{len(arr)}"' if tuples else ""
    return f'{indent}<DataArray type="{vtk_type}"{label}{comps}{count} format="appended" offset="{offset}"/>'


def _zlib_block(raw, level, block=ZLIB_BLOCK):
    """raw as a VTK zlib-compressed block: UInt64 header [number of blocks, block size, size of the
    partial last block (0 when it is full), compressed size of each block], then the blocks, each
    `block` bytes of raw compressed on its own (vtkZLibDataCompressor)."""
    parts = [zlib.compress(raw[i:i + block], level) for i in range(0, len(raw), block)]
    head = np.array([len(parts), block, len(raw) % block, *(len(c) for c in parts)], dtype="<u8")
    return head.tobytes() + b"".join(parts)


def vtu_bytes(points, cells, offsets, types, point_data=(), cell_data=(), field_data=(), active=None,
              zlib_level=None):
    """One VTK XML UnstructuredGrid piece, every array appended as little-endian binary, each block a
    UInt64 byte count then the bytes (zlib_level None), or zlib-compressed at that level
    (compressor="vtkZLibDataCompressor", _zlib_block). points [n, 3]; cells the connectivity,
    offsets the end of each cell in it, types the VTK cell types; *_data: (name, array) pairs;
    active: attributes of <PointData> (e.g. {"Tensors": "ellipsoid"})."""
    blocks, tags, offset = [], [], 0

    def add(name, arr, indent, tuples=False):
        nonlocal offset
        data, _ = _vtk_array(arr)
        raw = data.tobytes()
        tags.append(_array_tag(name, arr, offset, indent, tuples))
        block = (np.uint64(len(raw)).astype("<u8").tobytes() + raw if zlib_level is None
                 else _zlib_block(raw, zlib_level))
        blocks.append(block)
        offset += len(block)

    n_points, n_cells = len(points), len(types)
    tags.append("  <UnstructuredGrid>")
    if field_data:
        tags.append("    <FieldData>")
        for name, arr in field_data:
            add(name, np.atleast_1d(arr), "      ", tuples=True)
        tags.append("    </FieldData>")
    tags.append(f'    <Piece NumberOfPoints="{n_points}" NumberOfCells="{n_cells}">')
    attrs = "".join(f' {k}="{v}"' for k, v in (active or {}).items())
    tags.append(f"      <PointData{attrs}>")
    for name, arr in point_data:
        add(name, arr, "        ")
    tags.append("      </PointData>")
    tags.append("      <CellData>")
    for name, arr in cell_data:
        add(name, arr, "        ")
    tags.append("      </CellData>")
    tags.append("      <Points>")
    add(None, points, "        ")
    tags.append("      </Points>")
    tags.append("      <Cells>")
    add("connectivity", cells, "        ")
    add("offsets", offsets, "        ")
    add("types", types, "        ")
    tags.append("      </Cells>")
    tags.append("    </Piece>")
    tags.append("  </UnstructuredGrid>")
    compressor = ' compressor="vtkZLibDataCompressor"' if zlib_level is not None else ""
    head = ('<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
            f'header_type="UInt64"{compressor}>\n' + "\n".join(tags) + '\n  <AppendedData encoding="raw">\n   _')
    return [head.encode("ascii"), *blocks, b"\n  </AppendedData>\n</VTKFile>\n"]


def ellipsoid_tensor(rot, axes3):
    """R diag(a, b, c) R^T [n, 3, 3]: symmetric, eigenvalues the semi-axes, eigenvectors the body
    axes (the columns of R); the surface is x^T T^-2 x = 1."""
    return np.einsum("nik,nk,njk->nij", rot, axes3, rot)


def _write_parts(path, parts):
    def fill(fh):
        for p in parts:
            fh.write(p)
    atomic_write(path, fill, mode="wb")


def symmetric6(t):
    """Symmetric tensors [n, 3, 3] as VTK's 6 components [n, 6]: XX, YY, ZZ, XY, YZ, XZ."""
    return t[:, [0, 1, 2, 0, 1, 0], [0, 1, 2, 1, 2, 2]]


def write_vtu(path, snap, step=0, time=0.0):
    """Write snapshot dict (id, pos, quat, vel, omega, axes, shape) as binary VTU (module doc: floats
    VTU_FLOAT, zlib level ZLIB_LEVEL); returns the files written (with a poly-ellipsoid scene's
    `*_surface.vtu`)."""
    n = len(snap["id"])
    rot = quat_to_matrices(snap["quat"]).reshape(n, 3, 3)
    six = snap["axes"].shape[1] == 6
    axes3 = snap["axes"][:, 0::2] if six else snap["axes"]

    def real(a):
        return np.asarray(a, dtype=VTU_FLOAT)
    point_data = [("id", snap["id"]), ("shape", snap["shape"]), ("axes", real(axes3)), ("quat", real(snap["quat"]))]
    if six:
        point_data.append(("axes6", real(snap["axes"])))
    point_data += [("vel", real(snap["vel"])), ("omega", real(snap["omega"])),
                   ("ellipsoid", real(symmetric6(ellipsoid_tensor(rot, axes3))))]
    fields = [("TimeValue", np.float64(time)), ("STEP", np.int64(step))]
    ids = np.arange(n, dtype=np.int32 if n < 2**31 else np.int64)
    _write_parts(path, vtu_bytes(real(snap["pos"]), ids, ids + 1, np.full(n, VTK_VERTEX, np.uint8), point_data,
                                 field_data=fields, active={"Scalars": "id", "Vectors": "vel", "Tensors": "ellipsoid"},
                                 zlib_level=ZLIB_LEVEL))
    written = [path]
    if six:
        surface = _surface_path(path, ".vtu")
        write_surfaces_vtu(surface, snap, step, time)
        written.append(surface)
    return written


def write_surfaces_vtu(path, snap, step=0, time=0.0):
    """write_surfaces as binary VTU: every particle's surface as triangles (vertices Float64), cell
    data id."""
    pts, tris = _surface_points(snap)
    n, nv = pts.shape[:2]
    nt = len(tris)
    conn = (tris[None, :, :].astype(np.int64) + (nv * np.arange(n, dtype=np.int64))[:, None, None]).reshape(-1)
    fields = [("TimeValue", np.float64(time)), ("STEP", np.int64(step))]
    _write_parts(path, vtu_bytes(pts.reshape(-1, 3), conn, 3 * np.arange(1, n * nt + 1, dtype=np.int64),
                                 np.full(n * nt, VTK_TRIANGLE, np.uint8), cell_data=[("id", np.repeat(snap["id"], nt))],
                                 field_data=fields))


def read_series(path):
    """The (time, file) entries of a .pvd series file; [] when there is none or it cannot be read."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return []
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")
            if d.get("timestep") is not None and d.get("file")]


def update_series(folder, name, time, file):
    """Add (or replace) file at time in folder/name, a ParaView .pvd collection, and rewrite it
    atomically. Entries are kept by file name, so a restart into the same folder continues (or
    rewrites) the series; entries whose file is gone are dropped. Sorted by time."""
    path = os.path.join(folder, name)
    entries = {f: t for t, f in read_series(path) if os.path.exists(os.path.join(folder, f))}
    entries[file] = time
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">', "  <Collection>"]
    lines += [f'    <DataSet timestep="{t!r}" group="" part="0" file="{f}"/>'
              for f, t in sorted(entries.items(), key=lambda e: (e[1], e[0]))]
    lines += ["  </Collection>", "</VTKFile>", ""]
    atomic_write(path, lambda fh: fh.write("\n".join(lines)))


def write_snapshot(mode, folder, k, time, rank=0, fmt="vtu"):
    """Snapshot of step k at simulated time `time` [s] as folder/step<k:08d>.vtu (fmt vtu; the
    series files updated) or .vtk (fmt vtk), and step<k:08d>.npz; collective in MPI modes: every
    rank calls it, rank 0 gets the data and writes. Returns the files written (rank 0)."""
    snap = mode.snapshot()
    if rank != 0:
        return []
    base = os.path.join(folder, f"step{k:08d}")
    if fmt == "vtk":
        written = write_vtk(base + ".vtk", snap, step=k, time=time)
    elif fmt == "vtu":
        written = write_vtu(base + ".vtu", snap, step=k, time=time)
        update_series(folder, SERIES, float(time), os.path.basename(written[0]))
        if len(written) > 1:
            update_series(folder, SURFACE_SERIES, float(time), os.path.basename(written[1]))
    else:
        raise ValueError(f"unknown snapshot format {fmt!r} (formats: {', '.join(SNAPSHOT_FORMATS)})")
    atomic_write(base + ".npz", lambda fh: np.savez(fh, **snap), mode="wb")
    return written + [base + ".npz"]
