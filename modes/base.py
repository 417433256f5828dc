"""Execution modes: a registry of step drivers behind one small interface.

A mode owns how a step is executed (loops, threads, ranks) and its per-step timers; the
physics it runs is dem/'s. Interface: ``setup(scene, options)``, ``step() -> dict`` of phase
times and counters, ``snapshot() -> dict`` of the final state sorted by global id, and
``warmup()`` which compiles every kernel on a throw-away copy so no JIT time is ever timed.
"""
import re
from dataclasses import dataclass

REGISTRY = {}


class ModeError(ValueError):
    """Bad mode request (mapping, scheme, unavailable mode); str() is one line."""


try:  # the type fingerprint numba's dispatcher computes in C to find an overload (dtype, ndim, layout, writeable)
    from numba._dispatcher import compute_fingerprint
except ImportError:  # pragma: no cover - an older or newer numba without it: typeof every time
    compute_fingerprint = None

# (kernel, fingerprint of its arguments) -> compiled entry point (compiled_entry)
_ENTRIES = {}


def compiled_entry(kernel, args):
    """The compiled entry point of the numba kernel for the types of args, or the kernel itself
    (its dispatcher) where it has none. A dispatcher finds the overload from the arguments' types
    at every call: for the two dozen arrays of a step's kernels that took 3.9 us against 1.6 us
    through the entry point (an empty resolve_range), a quarter of a 48-particle step. The
    overload is found once per kernel and argument types: typing the arguments in Python
    (typeof_pyval, recursing through the tuples of arrays) took 0.59 ms for resolve_range, at
    every neighbour rebuild and for every kernel, 2 of the 3.8 ms of a 2-rank rebuild of an
    800-particle gas; the fingerprint that keys the cache takes 1 us."""
    key = None
    if compute_fingerprint is not None:
        try:
            key = (kernel, compute_fingerprint(args))
        except (TypeError, ValueError, NotImplementedError):
            key = None   # an argument without a fingerprint: type it in Python
        hit = _ENTRIES.get(key) if key is not None else None
        if hit is not None:
            return hit
    try:
        entry = kernel.overloads[tuple(kernel.typeof_pyval(a) for a in args)].entry_point
    except (AttributeError, KeyError):
        return kernel
    if key is not None:
        _ENTRIES[key] = entry
    return entry


def call_entry(entries, kernel, args):
    """kernel(*args): the first call through its dispatcher (which compiles where needed), later
    ones through the compiled entry point it leaves in entries (a dict per owner of a fixed set
    of arrays: their types cannot change until the owner is replaced)."""
    entry = entries.get(kernel)
    if entry is None:
        result = kernel(*args)
        entries[kernel] = compiled_entry(kernel, args)
        return result
    return entry(*args)


def register(name):
    def deco(cls):
        REGISTRY[name] = cls
        cls.name = name
        return cls
    return deco


@dataclass(frozen=True)
class Mapping:
    """Process/thread mapping P-px-py-pz-T: P processes on a px*py*pz block grid, T threads each."""
    procs: int
    px: int
    py: int
    pz: int
    threads: int

    def __str__(self):
        return f"{self.procs}-{self.px}-{self.py}-{self.pz}-{self.threads}"

    @property
    def kind(self):
        """serial, threads, mpi or hybrid (DESIGN.md, MPI)."""
        if self.procs == 1:
            return "serial" if self.threads == 1 else "threads"
        return "mpi" if self.threads == 1 else "hybrid"


def parse_mapping(text):
    """Parse 'P-px-py-pz-T'; raise ModeError with one line naming the problem."""
    if not isinstance(text, str) or not re.fullmatch(r"\s*\d+(-\d+){4}\s*", text, re.ASCII):
        raise ModeError(f"malformed mapping {text!r}: expected P-px-py-pz-T, e.g. 9-3-3-1-4")
    p, px, py, pz, t = (int(x) for x in text.strip().split("-"))
    for name, v in (("P", p), ("px", px), ("py", py), ("pz", pz), ("T", t)):
        if v < 1:
            raise ModeError(f"malformed mapping {text!r}: {name} must be >= 1")
    if p != px * py * pz:
        raise ModeError(f"malformed mapping {text!r}: P = {p} but px*py*pz = {px}*{py}*{pz} = {px * py * pz}")
    return Mapping(p, px, py, pz, t)


def mode_for(mapping):
    """The registered mode class that runs `mapping`, or ModeError if none does yet."""
    kind = mapping.kind
    if kind not in REGISTRY:
        raise ModeError(f"mapping {mapping} needs the {kind} mode, which is not available yet "
                        f"(available: {', '.join(sorted(REGISTRY))})")
    return REGISTRY[kind]
