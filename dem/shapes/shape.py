"""Shape: what the scene build, the state and the records need of one shape, in one place.

Each shape's module (dem.shapes.sphere, ellipsoid, polyellipsoid) makes one Shape and holds the
kernels of its contact geometry, pair_geometry and wall_geometry (the same arguments in every
module), which dem.forces calls through a dispatch built from the registry (dem.shapes.dispatch).
Its rotation (turn, derive, octant_geometry) is called likewise by dem.integrate; modes.halo builds
the ghost records from its ghost_fields (docs/ARCHITECTURE.md, "Adding a shape").
"""
from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Shape:
    """One shape. All functions are vectorised over k particles of this shape.

    name: as scene files and --shape write it; code: State.shape (dem.shapes); file_axes: how a
    scene file's `axes` gives it, e.g. "[r]", its length the number of values;
    semi_axes(values [len]): the scene block's semi-axes [6] (unused ones 0) [m];
    body(axes6 [k, 6], density [k], pos [k, 3], quat [k, 4]) -> (axes [k, 3], mass [k] [kg],
    principal moments [k, 3] [kg m^2], mass centre [k, 3] [m], principal-frame quaternion
    [k, 4], poly record [k, POLY_LEN] or None): the rigid body of particles given as a scene
    gives them; bounding_radius, smallest_semi_axis, equivalent_radius (axes [k, 3],
    poly [k, POLY_LEN]) -> [k] [m]: the radius about the mass centre that holds the particle,
    its smallest semi-axis (the depth scale of the stability guard and of the time step) and
    its volume-equivalent radius; snapshot_pose(pos [k, 3], quat [k, 4], axes [k, 3],
    poly [k, POLY_LEN]) -> (pos, quat, six semi-axes [k, 6]): the pose and semi-axes a snapshot
    of a scene with poly-ellipsoids reports (DESIGN.md), from which its surface is drawn;
    generate(a [k], draw) -> (semi-axes [k, 3] or [k, 6] as a scene block holds them, mass centre
    from the octant origin in the octant frame [k, 3] [m]): the shape of k generated particles of
    largest semi-axis a [m] ([[generate]]), draw(key, default, size) giving the scene's [lo, hi]
    range `key` (default if absent) drawn uniformly (in the order the shape draws them: the scene's
    seed fixes them); oriented: whether its orientation shapes it (generated ones turn at random);
    ghost_fields: the per-particle fields (State's names; axes0, inertia0: the first semi-axis and
    moment only) a ghost carries in a scene whose most general shape this is, enough for the
    kernels of every shape up to it (modes.halo generates the records' pack and write from them);
    moving_fields: those of them that change in a step (a forward exchange's); mirrors: whether its
    mirror image through a plane of its body frame is itself, turned (the build stage mirror-tiles
    a rested cell of such shapes: bench.run.prepare).

    The thread schemes' cost model (modes.parallel: the dynamic cut of the pair list and the
    blocks of the per-particle pass), measured by `bench perf --what split` on the machine at hand:
    contact_cost, a candidate pair's resolution where this is the pair's most general shape and
    the bounding spheres overlap, in units of a pair whose bounding spheres are apart; pass_cost,
    its per-particle pass (gather, integration) in units of a sphere's; wall_cost, what a wall on
    its wall list adds to that pass, in the same units."""
    name: str
    code: int
    file_axes: tuple
    semi_axes: Callable
    body: Callable
    bounding_radius: Callable
    smallest_semi_axis: Callable
    equivalent_radius: Callable
    snapshot_pose: Callable
    generate: Callable
    oriented: bool
    ghost_fields: tuple
    moving_fields: tuple
    mirrors: bool
    contact_cost: float
    pass_cost: float
    wall_cost: float
