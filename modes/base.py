"""Execution modes: a registry of step drivers behind one contract.

A mode owns how a step is executed (loops, threads, ranks) and its per-step timers; the
physics it runs is dem/'s. Mode (below) states everything the harness (bench/) may ask of one:
``setup(scene, dt, **options)``, ``step() -> dict`` of phase times and counters, ``snapshot() ->
dict`` of the final state sorted by global id, ``warmup()`` which compiles every kernel on a
throw-away copy so no JIT time is ever timed, ``run_info()`` (its part of run.json), and the few
attributes the stability guard and the records read. A mode joins the registry with
``@register(name)`` and says which mappings it runs with ``accepts(mapping)``; mode_for asks each.
"""
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:  # annotations only
    from dem.scene import Scene
    from dem.state import State

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


def fingerprint(args):
    """The type fingerprint numba's dispatcher computes (in C, ~1 us for a step kernel's arguments)
    of the tuple args, or None where it has none."""
    if compute_fingerprint is None:
        return None
    try:
        return compute_fingerprint(args)
    except (TypeError, ValueError, NotImplementedError):
        return None


def call_entry(entries, kernel, args, check=False):
    """kernel(*args): the first call through its dispatcher (which compiles where needed), later
    ones through the compiled entry point it leaves in entries (a dict per owner of a fixed set
    of arrays: their types cannot change until the owner is replaced). check: the arrays may have
    been replaced since (a rebuild): the entry is used when the arguments' fingerprint is the one
    it was found for (fingerprint, 1 us), else the dispatcher finds another."""
    hit = entries.get(kernel)
    if hit is not None:
        if not check:
            return hit[1](*args)
        fp = fingerprint(args)
        if fp is not None and fp == hit[0]:
            return hit[1](*args)
    result = kernel(*args)
    entries[kernel] = (fingerprint(args), compiled_entry(kernel, args))
    return result


def register(name):
    """Class decorator: put the mode class in REGISTRY under `name` (its `name`); mode_for then offers
    it every mapping, and it runs those its accepts(mapping) takes."""
    def deco(cls):
        if not callable(getattr(cls, "accepts", None)):
            raise TypeError(f"mode {name!r}: {cls.__name__} has no accepts(mapping) classmethod")
        REGISTRY[name] = cls
        cls.name = name
        return cls
    return deco


@runtime_checkable
class Mode(Protocol):
    """Everything the harness (bench/run: the driver, the ranks, guard, checkpoints, snapshots, the
    cache warm-up; the studies that step a mode) may ask of a set-up mode. SerialMode implements it;
    the other modes subclass it (docs/ARCHITECTURE.md, Adding a mode). A study of one mode's
    internals (bench/studies: schemes, perf_phases) sets up that class itself and reads more."""

    name: str
    """The mode's registry name (set by register): serial, threads, mpi, hybrid."""
    scene: "Scene"
    """The scene it runs: walls [planes], materials, gravity [m/s^2] (the guard reads them)."""
    state: "State"
    """The particles: arrays [n, ...], the first n_owned this process's own, then its ghosts."""
    max_overlap_ratio: float
    """The largest overlap of the run so far, over the smallest semi-axis of the bodies in contact."""
    guard_overlap: float
    """The overlap ratio above which a step flags itself for the guard (the guard sets it)."""
    sums: tuple
    """(flagged, kinetic energy [J], gravity work [J]) of the last step, over every rank."""

    @classmethod
    def accepts(cls, mapping: "Mapping") -> bool:
        """Whether this mode runs `mapping` (P-px-py-pz-T); mode_for asks every registered mode."""

    def setup(self, scene: "Scene", dt: float, **options) -> "Mode":
        """Take the scene (its state, which the mode now owns) and time step [s]; returns self.
        options: those of bench.run.options mode_options (ModeError for one it lacks), cart under MPI."""

    def warmup(self) -> None:
        """Compile every kernel on a throw-away twin of the state (collective under MPI)."""

    def step(self) -> dict:
        """One time step; returns its row of steps.csv: phase times [s] and counters (DESIGN.md)."""

    def snapshot(self) -> "dict | None":
        """The owned particles' fields [n, ...] sorted by global id (every rank's on rank 0; None on others)."""

    def sync_history(self) -> None:
        """Write the contact history of the pair list into the state's per-particle rows (checkpoints)."""

    def release(self) -> None:
        """Free what the mode holds outside Python (MPI requests); before a snapshot and MPI_Finalize."""

    @property
    def worst_contact(self) -> "tuple | None":
        """The deepest contact of the last step by global ids: (i, j), (i, "wall") or None."""

    def run_info(self, end: bool = False) -> dict:
        """The mode's part of run.json (JSON values): its set-up at the start (collective under MPI:
        every rank calls it, the gathered values are rank 0's), what the run did at the end (end=True)."""


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
    """The registered mode class that runs `mapping`: the one whose accepts(mapping) is true, or
    ModeError if none is (or, a registration mistake, several are)."""
    found = [cls for cls in REGISTRY.values() if cls.accepts(mapping)]
    if not found:
        raise ModeError(f"mapping {mapping} needs the {mapping.kind} mode, which is not available yet "
                        f"(available: {', '.join(sorted(REGISTRY))})")
    if len(found) > 1:
        raise ModeError(f"mapping {mapping} is accepted by several modes: {', '.join(c.name for c in found)}")
    return found[0]
