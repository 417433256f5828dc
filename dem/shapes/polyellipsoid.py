"""The poly-ellipsoid (Peters et al. 2009): eight octant ellipsoids with semi-axes
[a+, a-, b+, b-, c+, c-] [m] along its octant frame, glued at the octant origin.

Internally a rigid body at its mass centre in its principal frame (State.pos, quat; axes the
largest semi-axis per octant-frame axis), with a record State.poly [POLY_LEN] (dem.shapes P_*)
mapping that frame back to the octant geometry; scene files and snapshots give the octant origin
and octant frame (DESIGN.md). Contact geometry: dem.contact.polyellipsoid (octant active set;
polyellipsoid_wall_contact: the octant facing the wall), on the octant geometry
(octant_geometry below, through dem.integrate.derive_poly_geometry): pair_geometry and
wall_geometry below, which dem.forces calls through the registry's dispatch
(dem.shapes.dispatch); its ghosts carry the record (ghost_fields). Its rotation is the
ellipsoid's (turn, derive).
"""
import numpy as np
from numba import njit

from dem.contact.ellipsoid import solved_geometry
from dem.contact.polyellipsoid import mass_properties_poly, polyellipsoid_contact, polyellipsoid_wall_contact
from dem.shapes import P_AX, P_OFF, P_ROT, POLY, POLY_LEN, ellipsoid
from dem.shapes.shape import Shape


def poly_body(axes6, density):
    """Rigid-body data of a poly-ellipsoid (Peters et al. 2009; contact-mechanics.md §2.2).

    Returns (mass [kg], principal moments [3] [kg m^2], record [POLY_LEN], V [3, 3]) where V's
    columns are the principal axes in the octant frame (dem.contact.polyellipsoid.
    mass_properties_poly), W = V^T and off = -V^T centroid. The principal frame is R = R_oct V.
    """
    m, cen, moments, v = mass_properties_poly(axes6, density)
    rec = np.zeros(POLY_LEN)
    rec[P_AX:P_AX + 6] = axes6
    rec[P_OFF:P_OFF + 3] = -(v.T @ cen)
    rec[P_ROT:P_ROT + 9] = v.T.reshape(9)
    return m, moments, rec, v


def poly_from_octant(axes6, density, origin, quat_oct):
    """Internal state of a poly-ellipsoid given as DESIGN.md's octant origin [3] and octant-frame
    quaternion [4]: (axes [3] = largest semi-axis per octant-frame axis, mass, principal moments [3],
    mass centre [3], principal-frame quaternion [4], record [POLY_LEN])."""
    from dem.quaternion import quat_of_matrix, quat_to_matrices
    a6 = np.asarray(axes6, dtype=np.float64)
    m, moments, rec, v = poly_body(a6, density)
    quat = quat_of_matrix(quat_to_matrices(quat_oct)[0] @ v)
    r = quat_to_matrices(quat)[0]
    pos = np.asarray(origin, dtype=np.float64) - r @ rec[P_OFF:P_OFF + 3]
    axes3 = np.array([max(a6[0], a6[1]), max(a6[2], a6[3]), max(a6[4], a6[5])])
    return axes3, m, moments, pos, quat, rec


def octant_pose(pos, quat, rec):
    """Octant origin [3] and octant-frame quaternion [4] of a poly-ellipsoid at mass centre pos in
    principal frame quat (record rec [POLY_LEN]): o = pos + R off, R_oct = R W."""
    from dem.quaternion import quat_of_matrix, quat_to_matrices
    r = quat_to_matrices(quat)[0]
    o = pos + r @ rec[P_OFF:P_OFF + 3]
    return o, quat_of_matrix(r @ rec[P_ROT:P_ROT + 9].reshape(3, 3))


def semi_axes(values):
    """A scene file's [a+, a-, b+, b-, c+, c-] [m], as given."""
    return np.asarray(values, dtype=np.float64)


def body(axes6, density, pos, quat):
    """The rigid body of each (poly_from_octant: pos, quat given as octant origin and frame)."""
    k = len(axes6)
    axes, mass, inertia = np.zeros((k, 3)), np.zeros(k), np.zeros((k, 3))
    centre, principal, rec = np.zeros((k, 3)), np.zeros((k, 4)), np.zeros((k, POLY_LEN))
    for u in range(k):
        axes[u], mass[u], inertia[u], centre[u], principal[u], rec[u] = poly_from_octant(
            axes6[u], density[u], pos[u], quat[u])
    return axes, mass, inertia, centre, principal, rec


def bounding_radius(axes, poly):
    """The largest of the six semi-axes plus |octant origin - mass centre| [m]."""
    return poly[:, P_AX:P_AX + 6].max(axis=1) + np.linalg.norm(poly[:, P_OFF:P_OFF + 3], axis=1)


def smallest_semi_axis(axes, poly):
    """The smallest of the six semi-axes [m]."""
    return poly[:, P_AX:P_AX + 6].min(axis=1)


def equivalent_radius(axes, poly):
    """The radius of the volume, that of the ellipsoid with semi-axes (a+ + a-)/2, (b+ + b-)/2,
    (c+ + c-)/2 (contact-mechanics.md §2.2) [m]."""
    a6 = poly[:, P_AX:P_AX + 6]
    return np.cbrt(np.prod(0.5 * (a6[:, 0::2] + a6[:, 1::2]), axis=1))


def snapshot_pose(pos, quat, axes, poly):
    """The octant origin and octant frame (octant_pose) and the six semi-axes."""
    pos, quat = pos.copy(), quat.copy()
    for u in range(len(pos)):
        pos[u], quat[u] = octant_pose(pos[u], quat[u], poly[u])
    return pos, quat, poly[:, P_AX:P_AX + 6].copy()


def generate(a, draw):
    """The ellipsoid's extents 2a, 2b, 2c (ellipsoid.generate), each split into a plus and a minus
    half with minus/plus drawn from the scene's asymmetry range (default [0.6, 1.0]); the mass
    centre from the octant origin is 3/8 (a+ - a-, b+ - b-, c+ - c-) (contact-mechanics.md §2.2)."""
    axes, _ = ellipsoid.generate(a, draw)
    ratio = draw("asymmetry", [0.6, 1.0], (len(a), 3))
    plus = 2.0 * axes / (1.0 + ratio)
    axes = np.stack([plus[:, 0], ratio[:, 0] * plus[:, 0], plus[:, 1], ratio[:, 1] * plus[:, 1],
                     plus[:, 2], ratio[:, 2] * plus[:, 2]], axis=1)
    return axes, 0.375 * (axes[:, 0::2] - axes[:, 1::2])


# cost model (Shape; `bench perf --what split`, 2 cores): an overlapping pair (the octant active set)
# 0.29 us on packed 2000, as an ellipsoid pair's; its per-particle pass and walls taken as the ellipsoid's
SHAPE = Shape("polyellipsoid", POLY, ("a+", "a-", "b+", "b-", "c+", "c-"), semi_axes, body, bounding_radius,
              smallest_semi_axis, equivalent_radius, snapshot_pose, generate, True,
              # the ellipsoid's and the record (41 doubles, 328 bytes); the record never changes
              ghost_fields=ellipsoid.SHAPE.ghost_fields + ("poly",), moving_fields=ellipsoid.SHAPE.moving_fields,
              # its mirror swaps a+ and a- (another poly-ellipsoid unless its record is mirrored too)
              mirrors=False,
              contact_cost=40.0, pass_cost=2.4, wall_cost=2.2)


@njit(cache=True, inline="always")
def pair_geometry(i, j, pos, rot, axes, shape, method, polys, lam0, n0, out):
    """A pair with a poly-ellipsoid on either side (dem.forces pair_geometry, whose arguments these
    are): the octant active set on the octant geometry of polys (dem.integrate
    derive_poly_geometry), warm normal n0 [3], into out [OUT_LEN]. Returns (hit, smallest
    semi-axis of i, of j [m], 1: a solver ran)."""
    _, oorg, orot, ax6 = polys
    hit = polyellipsoid_contact(oorg[i], orot[i], ax6[i], oorg[j], orot[j], ax6[j], n0, out)
    ai = ax6[i, 0]
    aj = ax6[j, 0]
    for c in range(1, 6):
        ai = min(ai, ax6[i, c])
        aj = min(aj, ax6[j, c])
    return hit, ai, aj, 1


@njit(cache=True, inline="always")
def wall_geometry(p, w, wall_m, wall_d, pos, rot, axes, shape, polys, out):
    """Poly-ellipsoid p and wall plane w (dem.forces wall_geometry, whose arguments these are): the
    ellipsoid wall contact of its octant facing the wall (out [OUT_LEN] scratch). Returns (hit,
    contact_law's record, smallest semi-axis [m])."""
    _, oorg, orot, ax6 = polys
    amin = min(axes[p, 0], min(axes[p, 1], axes[p, 2]))
    hit = polyellipsoid_wall_contact(oorg[p], orot[p], ax6[p], wall_m[w], wall_d[w], out) == 1
    for c in range(6):
        amin = min(amin, ax6[p, c])
    return hit, solved_geometry(out), amin


@njit(cache=True, inline="always")
def support_bound(k, nx, ny, nz, rot, axes, rbound, shape):
    """A bound of poly-ellipsoid k's support along any direction (dem.overlaps' screen): its bounding
    radius rbound[k] [m] (the body lies inside its bounding sphere)."""
    return rbound[k]


# its rotation is the rigid body's in its principal frame, the ellipsoid's
turn = ellipsoid.turn
derive = ellipsoid.derive


@njit(cache=True, inline="always")
def octant_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """Octant frame orot[p] = R W [3,3], octant origin oorg[p] = x + R off [3] [m] and six semi-axes
    ax6[p] [6] [m] from its record poly[p] (dem.integrate derive_poly_geometry; rot[p] derived
    first)."""
    for a in range(3):
        for b in range(3):
            orot[p, a, b] = (rot[p, a, 0] * poly[p, P_ROT + b] + rot[p, a, 1] * poly[p, P_ROT + 3 + b]
                             + rot[p, a, 2] * poly[p, P_ROT + 6 + b])
        oorg[p, a] = pos[p, a] + (rot[p, a, 0] * poly[p, P_OFF] + rot[p, a, 1] * poly[p, P_OFF + 1]
                                  + rot[p, a, 2] * poly[p, P_OFF + 2])
    for k in range(6):
        ax6[p, k] = poly[p, P_AX + k]
