"""Shape codes (State.shape) and the poly-ellipsoid record layout (State.poly): the plain
constants every kernel indexes with, in a module of their own so that state, integration and
contact modules can all import them (no import circle).

Shapes: SPHERE (one radius, axes [r, r, r]), ELLIPSOID (semi-axes a >= b >= c or any order
[m]), POLY (poly-ellipsoid, Peters et al. 2009: eight octant ellipsoids).
"""
SPHERE = 0
ELLIPSOID = 1
POLY = 2
SHAPE_CODES = {"sphere": SPHERE, "ellipsoid": ELLIPSOID, "polyellipsoid": POLY}

# poly-ellipsoid record, State.poly [n, POLY_LEN] (POLY_LEN columns only in a scene that has
# poly-ellipsoids, else 0). Internally a poly-ellipsoid is a rigid body at its mass centre (pos)
# in its principal frame (quat), so the integrator sees diagonal inertia; the record maps that
# frame back to the octant geometry: octant frame R_oct = R W, octant origin o = pos + R off.
P_AX = 0        # six semi-axes [a+, a-, b+, b-, c+, c-] [m]
P_OFF = 6       # octant origin minus mass centre, principal frame [3] [m]
P_ROT = 9       # W = principal -> octant frame rotation [3, 3], row-major
POLY_LEN = 18
