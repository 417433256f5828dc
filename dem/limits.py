"""What a scene may ask of the solver, checked at load with one line naming the cause (issue 15).

Size ratio. The exact ellipsoid solver (dem/contact/ellipsoid.py: Perram-Wertheim + Newton on
S^2) resolves a contact between bodies of very different size only down to the round-off of
its support functions. The probe: a big ellipsoid of semi-axes (1, 0.8, 0.6) m and a small body
(an ellipsoid (1, 0.8, 0.6), a sphere, a needle (1, 0.05, 0.05), a disk (1, 1, 0.05)) scaled down,
both randomly oriented, the small one on a random surface point of the big one with its centre
at a depth of 30 % of its smallest semi-axis; the ratio is the pair's largest semi-axis over its
smallest. 150 trials per shape and ratio find every contact, with its depth to 1e-3, at 1e7,
2e7, 3e7 and 5e7 (0 of 600 missed at each); at 1e8 16 of 150 trials of the (1, 0.8, 0.6) body and
2 of 150 needles find no contact at all (the small body passes through), at 2e8 27 of 150 of a
mixed set, from 3e8 on all. So a scene whose largest semi-axis over its smallest (over every
particle, a particle's own axes included, so a needle's or a disk's aspect counts too) exceeds
SIZE_RATIO_MAX = 1e7, a factor 5 below the largest ratio measured clean, is refused at load.
tests/dem/test_contact_faults.py repeats the probe at the limit. The limit is the exact
solver's; `--contact-method pw` loses accuracy from about 1e7 and the sextic is approximate at
any ratio (contact-mechanics.md §1.2).

Particle count. Loading costs about 1.4 KiB a generated particle (the rows, the state arrays;
measured at 1e5 particles) before a run allocates its neighbour lists, so a count whose
LOAD_BYTES_PER_PARTICLE = 2 KiB estimate exceeds the physical memory is refused before anything
is allocated (instead of a MemoryError deep inside numpy).
"""
import os

import numpy as np

SIZE_RATIO_MAX = 1e7
LOAD_BYTES_PER_PARTICLE = 2048


class LimitError(ValueError):
    """A scene beyond what the solver resolves or the memory holds; str() is one line."""


def check_size_ratio(axes_rows):
    """Refuse (LimitError) a scene whose largest semi-axis over its smallest exceeds SIZE_RATIO_MAX.

    axes_rows: per particle, its semi-axes [m] (a sphere [r] or (r, r, r), an ellipsoid (a, b, c),
    a poly-ellipsoid [a+, a-, b+, b-, c+, c-]), in particle order: a list of rows, or an array
    [n, k] whose zero entries are absent axes (the scene's particle blocks pad to 6). Returns the
    ratio."""
    if isinstance(axes_rows, np.ndarray):
        table = np.asarray(axes_rows, dtype=np.float64).reshape(len(axes_rows), -1)
    else:
        rows = [np.ravel(np.asarray(ax, dtype=np.float64)) for ax in axes_rows]
        table = np.zeros((len(rows), max((len(r) for r in rows), default=0)))
        for k, r in enumerate(rows):
            table[k, :len(r)] = r
    if table.size == 0:
        return 1.0
    smallest = np.where(table > 0, table, np.inf).min(axis=1)
    largest = table.max(axis=1)
    lo_k, hi_k = int(np.argmin(smallest)), int(np.argmax(largest))
    lo, hi = float(smallest[lo_k]), float(largest[hi_k])
    ratio = hi / lo
    if not ratio <= SIZE_RATIO_MAX:
        raise LimitError(f"semi-axes from {lo:.3g} m (particle {lo_k}) to {hi:.3g} m (particle {hi_k}): "
                         f"a size ratio of {ratio:.3g}, above the {SIZE_RATIO_MAX:.0e} up to which the contact "
                         f"solver was measured to resolve contacts (dem/limits.py); rescale the smallest or "
                         f"the largest bodies")
    return ratio


def physical_memory():
    """Bytes of physical memory [B], or None where the system does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_particle_count(count, what="particle count"):
    """Refuse (LimitError) a count whose load alone (LOAD_BYTES_PER_PARTICLE a particle) exceeds the
    physical memory, before anything is allocated."""
    mem = physical_memory()
    need = count * LOAD_BYTES_PER_PARTICLE
    if mem is not None and need > mem:
        raise LimitError(f"{what} {count} needs about {_size(need)} to load ({LOAD_BYTES_PER_PARTICLE // 1024} KiB "
                         f"a particle), more than the {_size(mem)} of memory")


def _size(b):
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if b < 1024 or unit == "PiB":
            return f"{b:.3g} {unit}"
        b /= 1024.0
    return f"{b:.3g} PiB"


# the ranges beyond which an input, not the time step, is the likely cause of a time step that
# cannot be computed (SI units): stiffest solids ~1e12 Pa, densest ~2.3e4 kg/m^3
PLAUSIBLE = {"young": (1e3, 1e13, "Pa"), "density": (1.0, 1e5, "kg/m^3"), "gravity": (0.0, 1e6, "m/s^2"),
             "speed": (0.0, 1e4, "m/s"), "size": (1e-9, 1e3, "m")}


def explain_time_step(scene, dt, err):
    """One line: why no time step can be computed for `scene` (user dt `dt` or None), naming the
    inputs outside PLAUSIBLE; err: what the computation raised."""
    import numpy as np
    causes = []

    def out_of(what, v, key):
        lo, hi, unit = PLAUSIBLE[key]
        if not (lo <= v <= hi):
            causes.append(f"{what} = {v:.3g} {unit} (a plausible range is {lo:g} to {hi:g})")
    for m in scene.materials.materials:
        out_of(f"materials.{m.name}.young", m.young, "young")
        out_of(f"materials.{m.name}.density", m.density, "density")
    out_of("|domain.gravity|", float(np.linalg.norm(scene.gravity)), "gravity")
    s = scene.state
    if s.n_owned:
        out_of("the largest initial speed", float(np.linalg.norm(s.vel[:s.n_owned], axis=1).max()), "speed")
        out_of("the smallest semi-axis", float(s.axes[:s.n_owned].min()), "size")
        out_of("the largest semi-axis", float(s.axes[:s.n_owned].max()), "size")
    what = str(err) if str(err) else type(err).__name__
    if causes:
        return f"no time step can be computed ({what}): " + "; ".join(causes)
    return f"no time step can be computed from this scene ({what})"
