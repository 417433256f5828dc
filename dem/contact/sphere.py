"""Sphere-sphere and sphere-wall contact geometry, closed form (no iteration, no solver)."""
import math
from numba import njit


@njit(cache=True, inline="always")
def sphere_contact(c1, r1, c2, r2):
    """Overlap of spheres (c1 [3], r1) and (c2 [3], r2) [m].

    depth = r1 + r2 - |c2 - c1|, n = (c2 - c1)/|c2 - c1| (from 1 towards 2), contact point at the
    middle of the overlap c1 + (r1 - depth/2) n, R_e = r1 r2/(r1 + r2).
    Returns (hit, depth, nx, ny, nz, xcx, xcy, xcz, r_e); hit is False for no overlap or
    coincident centres (no defined normal).
    """
    dx = c2[0] - c1[0]
    dy = c2[1] - c1[1]
    dz = c2[2] - c1[2]
    d2 = dx * dx + dy * dy + dz * dz
    rs = r1 + r2
    if d2 >= rs * rs or d2 == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    d = math.sqrt(d2)
    depth = rs - d
    nx, ny, nz = dx / d, dy / d, dz / d
    t = r1 - 0.5 * depth
    return True, depth, nx, ny, nz, c1[0] + t * nx, c1[1] + t * ny, c1[2] + t * nz, r1 * r2 / rs


@njit(cache=True, inline="always")
def sphere_wall_contact(c, r, mx, my, mz, d):
    """Overlap of sphere (c, r) with the plane m.x = d (m into the domain).

    depth = r - (m.c - d); normal from the sphere into the wall is -m; contact point midway
    between the sphere's deepest point and the plane; R_e = r.
    Returns (hit, depth, xcx, xcy, xcz, r_e).
    """
    dist = mx * c[0] + my * c[1] + mz * c[2] - d
    depth = r - dist
    if depth <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    t = r - 0.5 * depth
    return True, depth, c[0] - t * mx, c[1] - t * my, c[2] - t * mz, r
