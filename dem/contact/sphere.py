"""Sphere-sphere and sphere-wall contact geometry, closed form (no iteration, no solver)."""
import math
from numba import njit


@njit(cache=True, inline="always")
def sphere_contact(x1, y1, z1, r1, x2, y2, z2, r2):
    """Overlap of spheres (centre (x1, y1, z1), radius r1) and ((x2, y2, z2), r2) [m].

    depth = r1 + r2 - |c2 - c1|, n = (c2 - c1)/|c2 - c1| (from 1 towards 2), contact point at the
    middle of the overlap c1 + (r1 - depth/2) n, R_e = r1 r2/(r1 + r2).
    Coincident centres (|c2 - c1| = 0) are a contact too, of depth r1 + r2, with the fixed normal
    n = +z: every caller passes the pair in canonical order (body 1 = the lower global id,
    DESIGN.md Determinism), so the normal points from the lower id to the higher one in every mode
    and memory order, and the stability guard then stops the run naming the overlap (a contact
    that is never missed, issue 15).
    Returns (hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e); hit is False only for no overlap.
    """
    dx = x2 - x1
    dy = y2 - y1
    dz = z2 - z1
    d2 = dx * dx + dy * dy + dz * dz
    rs = r1 + r2
    if d2 >= rs * rs:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if d2 == 0.0:  # coincident centres: the fixed normal +z, from body 1 (lower gid) to body 2
        t = r1 - 0.5 * rs
        return True, rs, 0.0, 0.0, 1.0, x1, y1, z1 + t, r1 * r2 / rs
    d = math.sqrt(d2)
    depth = rs - d
    nx, ny, nz = dx / d, dy / d, dz / d
    t = r1 - 0.5 * depth
    return True, depth, nx, ny, nz, x1 + t * nx, y1 + t * ny, z1 + t * nz, r1 * r2 / rs


@njit(cache=True, inline="always")
def sphere_wall_contact(x, y, z, r, mx, my, mz, d):
    """Overlap of sphere (centre (x, y, z), radius r) with the plane m.x = d (m into the domain).

    depth = r - (m.c - d); normal from the sphere into the wall is -m; contact point midway
    between the sphere's deepest point and the plane; R_e = r.
    Returns (hit, depth, xcx, xcy, xcz, r_e).
    """
    dist = mx * x + my * y + mz * z - d
    depth = r - dist
    if depth <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    t = r - 0.5 * depth
    return True, depth, x - t * mx, y - t * my, z - t * mz, r
