"""Snapshots readable by ParaView: legacy-VTK polydata.

`write_vtk` writes points with per-particle fields: id, shape, axes (semi-axes, 3 components),
quat (w, x, y, z), orientation given also as the three body axes in world coordinates (axis_x,
axis_y, axis_z: vectors, scaled by the semi-axes, ready for ParaView's Tensor Glyph or Glyph
filters), vel, omega. In a scene with poly-ellipsoids (snapshot axes [n, 6]) the points are the
octant origins, quat the octant frames, `axes` the plus half-axes (a+, b+, c+), a field array
`axes6` [a+, a-, b+, b-, c+, c-], and a second file (`*_surface.vtk`) holds every particle's
surface as triangles, since no glyph draws a poly-ellipsoid.

write_snapshot(mode, folder, k, dt, rank) writes step<k>.vtk and step<k>.npz of a run's state.
"""
import os

import numpy as np

from dem.quaternion import quat_to_matrices


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
    lines += ["SCALARS quat double 4", "LOOKUP_TABLE default"] + [" ".join(f"{c:.17g}" for c in q) for q in snap["quat"]]
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
        surface = path[:-4] + "_surface.vtk" if path.endswith(".vtk") else path + "_surface.vtk"
        write_surfaces(surface, snap, step, time)
        written.append(surface)
    return written


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


def write_surfaces(path, snap, step=0, time=0.0):
    """Every particle's surface as triangles: unit-sphere points u map to o + R (alpha o u), alpha the
    semi-axes of u's octant (a+ or a- by the sign of each component; Peters et al. 2009), so each
    octant is an exact ellipsoid piece. Cell data: id."""
    u, tris = _unit_sphere()
    n = len(snap["id"])
    rot = quat_to_matrices(snap["quat"])
    a6 = snap["axes"] if snap["axes"].shape[1] == 6 else np.repeat(snap["axes"], 2, axis=1)
    plus, minus = a6[:, 0::2], a6[:, 1::2]
    alpha = np.where(u[None, :, :] >= 0, plus[:, None, :], minus[:, None, :])          # [n, v, 3]
    pts = snap["pos"][:, None, :] + np.einsum("nab,nvb->nva", rot, alpha * u[None, :, :])
    nv, nt = len(u), len(tris)
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


def write_snapshot(mode, folder, k, dt, rank=0):
    """Snapshot of step k (time k dt [s]) as folder/step<k>.vtk and .npz; collective in MPI modes:
    every rank calls it, rank 0 gets the data and writes."""
    snap = mode.snapshot()
    if rank != 0:
        return
    write_vtk(os.path.join(folder, f"step{k:08d}.vtk"), snap, step=k, time=k * dt)
    np.savez(os.path.join(folder, f"step{k:08d}.npz"), **snap)
