"""Shapes: the codes (State.shape) and record layouts every kernel indexes with, and one module
per shape.

The plain constants live here, in the package's root, so that state, integration and contact
modules can all import them (no import circle). Each shape's own facts (the scene file's
semi-axes, mass properties, bounding radius, smallest and volume-equivalent semi-axis, the pose
and semi-axes a snapshot reports, how a generated scene makes it, its costs in the thread
schemes' cost model, its ghost record, whether a build may mirror it) and its kernels (pair and
wall geometry, support bound, rotation step, derived rotation, octant geometry) live in its module:
dem.shapes.sphere, dem.shapes.ellipsoid, dem.shapes.polyellipsoid, each a dem.shapes.shape.Shape;
dem.shapes.registry lists them and dispatches over the shapes a set of particles holds, and
dem.shapes.dispatch builds the kernels' dispatch from it.

Shapes: SPHERE (one radius, axes [r, r, r]), ELLIPSOID (semi-axes a >= b >= c or any order
[m]), POLY (poly-ellipsoid, Peters et al. 2009: eight octant ellipsoids). A scene's kind, which
picks its pair loop, is the most general code it holds (dem.forces.scene_kind): the codes are
ordered so, each shape's kernels handling the ones before it.
"""
SPHERE = 0
ELLIPSOID = 1
POLY = 2

# poly-ellipsoid record, State.poly [n, POLY_LEN] (POLY_LEN columns only in a scene that has
# poly-ellipsoids, else 0). Internally a poly-ellipsoid is a rigid body at its mass centre (pos)
# in its principal frame (quat), so the integrator sees diagonal inertia; the record maps that
# frame back to the octant geometry: octant frame R_oct = R W, octant origin o = pos + R off.
P_AX = 0        # six semi-axes [a+, a-, b+, b-, c+, c-] [m]
P_OFF = 6       # octant origin minus mass centre, principal frame [3] [m]
P_ROT = 9       # W = principal -> octant frame rotation [3, 3], row-major
POLY_LEN = 18
