"""The registered shapes (dem.shapes.shape.Shape), in code order, and the dispatch of their
vectorised functions over the particles of a set that may hold several shapes.

Adding a shape: its module beside these (dem.shapes.<name>: its Shape and its kernels) and its
name in SHAPE_NAMES (docs/ARCHITECTURE.md, "Adding a shape").

SHAPE_NAMES is plain data: the command line reads it before numba starts (the thread variables
are set first: bench.run.threads_env), while the shapes' modules hold numba kernels. SHAPES,
BY_NAME and BY_CODE therefore import the modules when first asked for.
"""
import importlib

import numpy as np

# one line a shape, in code order (its module is dem.shapes.<name>)
SHAPE_NAMES = ("sphere", "ellipsoid", "polyellipsoid")

_LOADED = {}


def shapes():
    """The registered Shapes in code order (their modules imported on the first call)."""
    if "SHAPES" not in _LOADED:
        found = tuple(importlib.import_module(f"dem.shapes.{name}").SHAPE for name in SHAPE_NAMES)
        assert all(s.code == k and s.name == SHAPE_NAMES[k] for k, s in enumerate(found)), \
            "shape codes are the registry's order"
        _LOADED["SHAPES"] = found
        _LOADED["BY_NAME"] = {s.name: s for s in found}
        _LOADED["BY_CODE"] = {s.code: s for s in found}
    return _LOADED["SHAPES"]


def __getattr__(name):
    """SHAPES, BY_NAME ({name: Shape}), BY_CODE ({code: Shape}), loaded on first use."""
    if name in ("SHAPES", "BY_NAME", "BY_CODE"):
        shapes()
        return _LOADED[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def present(shape):
    """The shapes that codes shape [n] hold, each with the rows that hold it: [(Shape, rows or
    None)], rows None when it is the only one (no selection needed)."""
    if not len(shape):
        return []
    registered = shapes()
    lo, hi = int(shape.min()), int(shape.max())
    if lo == hi:
        return [(registered[lo], None)]
    found = []
    for s in registered[lo:hi + 1]:
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
