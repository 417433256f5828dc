"""The sphere: one radius r [m], held as the ellipsoid (r, r, r), whose orientation shapes nothing.

Contact geometry: dem.contact.sphere (closed form, pair and wall), dispatched by dem.forces
pair_geometry and wall_geometry; a scene of spheres only has a loop of its own
(dem.forces _resolve_spheres, finish_range with spheres=True: no rotation of the shape), its
ghosts a shorter record (modes.halo GHOST_SPHERE). Mass properties, radii and snapshot are the
ellipsoid's with a = b = c.
"""
import numpy as np

from dem.shapes import SPHERE
from dem.shapes import ellipsoid
from dem.shapes.shape import Shape


def semi_axes(values):
    """A scene file's [r] [m] as the block's six semi-axes [r, r, r, 0, 0, 0]."""
    r = values[0]
    return np.array([r, r, r, 0.0, 0.0, 0.0])


def generate(a, draw):
    """Radius a (nothing drawn); the mass centre is the centre."""
    return np.repeat(a[:, None], 3, axis=1), np.zeros((len(a), 3))


# cost model (Shape; `bench perf --what split`, 2 cores): a pair apart 0.0066-0.0117 us, an overlapping
# sphere pair (closed form) 0.063 us; the per-particle pass 0.059 us, a wall on its list adds 0.009 us
SHAPE = Shape("sphere", SPHERE, ("r",), semi_axes, ellipsoid.body, ellipsoid.bounding_radius,
              ellipsoid.smallest_semi_axis, ellipsoid.equivalent_radius, ellipsoid.snapshot_pose, generate, False,
              contact_cost=10.0, pass_cost=1.0, wall_cost=0.15)
