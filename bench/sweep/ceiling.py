"""The machine's efficiency ceiling beside a sweep (`bench sweep --ceiling`, local launcher).

For each core count W > 1 of the sweep's points, W independent serial copies of the sweep's scene
at N/W particles each (bench.run.copies: no shared memory, no message) are stepped alone, W
together, and W together meeting after every step. One round runs after each round of the
sweep's repeats, so that a load that comes and goes falls on the points and on the control alike.
DIR/ceiling.csv holds the medians over the rounds, a row per W (the last sweep into DIR that measured
them; runs.csv, by contrast, keeps the points of every sweep):

    cores, share, rounds, alone_ms, together_ms, in_step_ms, ceiling_free, ceiling_step, pinned

In a pinned sweep (`--pin`) the W copies are pinned too, as W one-thread ranks would be
(bench.run.binding plan_binding over the usable CPUs: copy c on the plan's CPU of rank c, a lone
copy on rank 0's), so that the ceiling stands beside points bound as they are; pinned = 1 there.

ceiling_free = alone / together and ceiling_step = alone / in step are the efficiency W workers
could reach with their work divided exactly and their communication at no cost (the definitions:
bench/studies/perf_contention.py); efficiency.png draws them beside the points. Core counts above
the usable CPUs are left out: W copies on fewer cores measure the sharing of a core, not a ceiling.
"""
import csv
import os
import statistics

from bench.run.copies import ceilings, sample

CEILING_COLUMNS = ("cores", "share", "rounds", "alone_ms", "together_ms", "in_step_ms", "ceiling_free",
                   "ceiling_step", "pinned")
CONFIGS = ("alone", "together", "in_step")


class CeilingError(ValueError):
    """A sweep whose ceiling cannot be measured (str() is one line)."""


class Ceiling:
    """The control of one sweep: scene (name or file), particles (None: the scene's own count),
    shape, steps (None: the scene's own) and warmup of each copy, cores: the core counts of the
    sweep's points, usable: the CPUs this process may use; options: the serial mode's set-up options
    of the sweep (skin, contact_method, neighbor), so that the copies step what the points step (a
    skin-0 sweep's copies build a list every step too); pin: the copies bound as one-thread ranks
    of a pinned run (module docstring)."""

    def __init__(self, scene, particles, shape, steps, warmup, cores, usable, options=None, pin=False):
        from dem.scene import SceneError, load_scene
        self.scene, self.shape, self.warmup, self.pin = scene, shape, warmup, bool(pin)
        self.options = {k: v for k, v in (options or {}).items() if v is not None}
        counts = sorted({int(w) for w in cores if int(w) > 1})
        self.cores = [w for w in counts if w <= usable]
        self.left_out = [w for w in counts if w > usable]
        try:
            whole = load_scene(scene, particles=particles, shape=shape)
            self.particles = whole.n
            self.steps = max(1, int(steps if steps is not None else whole.steps))
            for w in self.cores:  # the scene must take the share's count: a [[generate]] block
                load_scene(scene, particles=self.share(w), shape=shape)
        except SceneError as e:
            raise CeilingError(f"--ceiling needs copies of the scene at N/W particles: {e}") from None
        self.samples = {w: {c: [] for c in CONFIGS} for w in self.cores}

    def share(self, w):
        return max(1, self.particles // w)

    def cpus(self, w):
        """The CPUs of w copies when pinned: those --pin gives w one-thread ranks (plan_binding over
        the CPUs this process may use), copy c on rank c's; None when not pinned."""
        if not self.pin:
            return None
        from bench.run.binding import plan_binding, read_topology
        return [row[0] for row in plan_binding(read_topology(os.sched_getaffinity(0)), w, 1)]

    def round(self):
        """One round of the control at every core count."""
        for w in self.cores:
            for c, t in sample(self.scene, self.particles, w, self.steps, self.warmup, shape=self.shape,
                               configs=CONFIGS, options=self.options, cpus=self.cpus(w)).items():
                self.samples[w][c].append(t)

    def rows(self):
        out = []
        for w in self.cores:
            s = self.samples[w]
            if not s["alone"]:
                continue
            med = {c: statistics.median(v) for c, v in s.items()}
            out.append({"cores": w, "share": self.share(w), "rounds": len(s["alone"]),
                        **{f"{c}_ms": 1e3 * med[c] for c in CONFIGS}, **ceilings(med), "pinned": int(self.pin)})
        return out

    def write(self, directory):
        """DIR/ceiling.csv (written whole, then renamed into place); returns its rows."""
        rows = self.rows()
        path = os.path.join(directory, "ceiling.csv")
        tmp = path + ".tmp"
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=CEILING_COLUMNS)
            w.writeheader()
            w.writerows(rows)
        os.replace(tmp, path)
        return rows


def read_ceiling(directory):
    """DIR/ceiling.csv as a list of dicts of floats ([] where there is none or it cannot be read);
    a file written before the copies could be pinned has no `pinned`: 0."""
    path = os.path.join(directory, "ceiling.csv")
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        return [{k: float(r[k] if k != "pinned" else r.get(k) or 0) for k in CEILING_COLUMNS} for r in rows]
    except (OSError, KeyError, ValueError, TypeError):
        return []
