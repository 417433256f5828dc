"""The registered shapes (dem.shapes.shape.Shape), in code order, and the dispatch of their
vectorised functions over the particles of a set that may hold several shapes.

Adding a shape: its module beside these (a Shape), its line in SHAPES, its contact geometry in
dem/contact/ and the kernels' dispatch on its code (docs/ARCHITECTURE.md, "Adding a shape").
"""
import numpy as np

from dem.shapes import ellipsoid, polyellipsoid, sphere

SHAPES = (sphere.SHAPE, ellipsoid.SHAPE, polyellipsoid.SHAPE)
BY_NAME = {s.name: s for s in SHAPES}
BY_CODE = {s.code: s for s in SHAPES}
SHAPE_NAMES = tuple(BY_NAME)
assert all(s.code == k for k, s in enumerate(SHAPES)), "shape codes are the registry's order"


def present(shape):
    """The shapes that codes shape [n] hold, each with the rows that hold it: [(Shape, rows or
    None)], rows None when it is the only one (no selection needed)."""
    if not len(shape):
        return []
    lo, hi = int(shape.min()), int(shape.max())
    if lo == hi:
        return [(SHAPES[lo], None)]
    found = []
    for s in SHAPES[lo:hi + 1]:
        rows = np.flatnonzero(shape == s.code)
        if len(rows):
            found.append((s, rows))
    return found


def _per_particle(name, axes, shape, poly):
    out = np.empty(len(shape))
    for s, rows in present(shape):
        f = getattr(s, name)
        if rows is None:
            return np.asarray(f(axes, poly), dtype=np.float64).copy()
        out[rows] = f(axes[rows], poly[rows])
    return out


def bounding_radii(axes, shape, poly):
    """Radius [n] [m] of a sphere about each particle's centre (its mass centre) that holds it
    (Shape.bounding_radius); axes [n, 3], shape [n] codes, poly [n, POLY_LEN or 0]."""
    return _per_particle("bounding_radius", axes, shape, poly)


def smallest_semi_axes(axes, shape, poly):
    """Smallest semi-axis [n] [m] of each particle (Shape.smallest_semi_axis)."""
    return _per_particle("smallest_semi_axis", axes, shape, poly)


def equivalent_radii(axes, shape, poly):
    """Volume-equivalent radius [n] [m] of each particle (Shape.equivalent_radius)."""
    return _per_particle("equivalent_radius", axes, shape, poly)
