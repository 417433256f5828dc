"""Kernel dispatch built from the registered shapes: one numba function per concern that calls the
kernel of the shape a code names, as an if-chain over the codes in registry order.

by_shape("pair_geometry", "i, j, ...", "max(shape[i], shape[j])") returns an njit function of
those parameters whose body is

    code = max(shape[i], shape[j])
    if code == 0:
        return _kernel0(i, j, ...)     # dem.shapes.sphere.pair_geometry
    if code == 1:
        return _kernel1(i, j, ...)     # dem.shapes.ellipsoid.pair_geometry
    return _kernel2(i, j, ...)         # the last registered shape's

from generated source with the kernels as its globals, so that numba compiles the chain a
programmer would write (each call inlined, the kernels being inline="always"). It is not cached
itself: the cached kernels that call it compile it in (their cache folder is keyed by every
source file of dem/ and modes/: dem/__init__.py, so adding a shape rebuilds them). Two other ways
were measured on three trivial kernels over 2 million random codes: a loop `for f in
literal_unroll(kernels)` ran within 4 % of the hand-written chain but numba types a tuple of
functions as first-class functions (an experimental feature, with a warning), and a chain of
closures ran 4x slower (its calls were not inlined); this generated chain ran as fast as the
hand-written one (11.3-11.6 ms both).
"""
import importlib

from numba import njit

from dem.shapes.registry import shapes


def by_shape(concern, params, code, doc=""):
    """An njit(inline="always") function of params (a comma-separated parameter list) calling the
    registered shapes' `concern` kernel (each shape module's function of that name, taking the same
    parameters) of the shape whose code is the expression `code` over the parameters."""
    kernels = [getattr(importlib.import_module(f"dem.shapes.{s.name}"), concern) for s in shapes()]
    names = {f"_kernel{k}": f for k, f in enumerate(kernels)}
    lines = [f"def {concern}({params}):", f"    code = {code}"]
    for k in range(len(kernels) - 1):
        lines += [f"    if code == {k}:", f"        return _kernel{k}({params})"]
    lines.append(f"    return _kernel{len(kernels) - 1}({params})")
    namespace = dict(names)
    exec(compile("\n".join(lines) + "\n", f"<dem.shapes.dispatch {concern}>", "exec"), namespace)
    f = namespace[concern]
    f.__doc__ = doc
    f.__module__ = __name__
    return njit(inline="always")(f)
