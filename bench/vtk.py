"""Snapshots readable by ParaView: legacy-VTK polydata points with per-particle fields.

Fields: id, shape, axes (semi-axes, 3 components), quat (w, x, y, z), orientation given also as
the three body axes in world coordinates (axis_x, axis_y, axis_z: vectors, scaled by the
semi-axes, ready for ParaView's Tensor Glyph or Glyph filters), vel, omega.
"""

from dem.quaternion import quat_to_matrices


def write_vtk(path, snap, step=0, time=0.0):
    """Write snapshot dict (id, pos, quat, vel, omega, axes, shape) as ASCII legacy VTK."""
    n = len(snap["id"])
    rot = quat_to_matrices(snap["quat"])
    lines = ["# vtk DataFile Version 3.0", f"DEM snapshot step {step} time {time:.9g}", "ASCII",
             "DATASET POLYDATA", f"POINTS {n} double"]
    lines += [f"{p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" for p in snap["pos"]]
    lines.append(f"VERTICES {n} {2 * n}")
    lines += [f"1 {k}" for k in range(n)]
    lines.append(f"POINT_DATA {n}")
    lines += ["SCALARS id long 1", "LOOKUP_TABLE default"] + [str(int(v)) for v in snap["id"]]
    lines += ["SCALARS shape int 1", "LOOKUP_TABLE default"] + [str(int(v)) for v in snap["shape"]]
    lines += ["SCALARS quat double 4", "LOOKUP_TABLE default"] + [" ".join(f"{c:.17g}" for c in q) for q in snap["quat"]]
    lines += ["VECTORS axes double"] + [" ".join(f"{c:.17g}" for c in a) for a in snap["axes"]]
    for k, name in enumerate(("axis_x", "axis_y", "axis_z")):
        vec = rot[:, :, k] * snap["axes"][:, k:k + 1]
        lines += [f"VECTORS {name} double"] + [" ".join(f"{c:.17g}" for c in v) for v in vec]
    lines += ["VECTORS vel double"] + [" ".join(f"{c:.17g}" for c in v) for v in snap["vel"]]
    lines += ["VECTORS omega double"] + [" ".join(f"{c:.17g}" for c in v) for v in snap["omega"]]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
