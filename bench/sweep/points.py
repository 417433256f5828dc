"""The points of a sweep: a mapping (and, with threads, a scheme) with the run parameters it shares.

Every point runs as its own `bench run` in DIR/<key>/rep<r>/; its key names the mapping and
scheme and hashes every parameter, so --resume recognises a point by what it runs. Its fields are
the options of bench.run.spec whose Field has a point (POINT_FIELDS).
"""
import hashlib
import json
from dataclasses import field, fields, make_dataclass

from bench.run.options import forward_refusal, halo_skin_refusal, too_few_ranks
from bench.run.spec import POINT_FIELDS, REQUIRED
from modes.base import ModeError, parse_mapping
from modes.parallel import SCHEMES, SPLIT_SCHEMES

SERIAL = "1-1-1-1-1"


class _PointMethods:
    @property
    def key(self):
        """Folder name: readable mapping and scheme plus a hash of every parameter (the options of
        the first sweeps always; each later one only when it is not neutral, so that the points of
        sweeps from before it keep their keys for --resume: bench.run.spec Field.point)."""
        params = {f.name: getattr(self, f.name) for f in POINT_FIELDS
                  if f.point == "always" or getattr(self, f.name) != f.neutral}
        digest = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:8]
        return f"{self.mapping}{'-' + self.scheme if self.scheme else ''}-{digest}"

    def run_args(self, out, timeout):
        """The `bench run` command line of the point: each field not neutral (REQUIRED ones always),
        those of scope procs only for more than one process."""
        procs = self.mapping.split("-")[0] != "1"
        args = ["run"]
        for f in POINT_FIELDS:
            value = getattr(self, f.name)
            if f.scope == "procs" and not procs or f.neutral is not REQUIRED and value == f.neutral:
                continue
            args += [f.flag] if f.type is bool else [f.flag, str(value)]
        return args + ["--out", out, "--quiet", "--timeout", str(timeout)]


# One sweep point: a mapping and, with threads, a scheme; the run parameters it shares (keywords:
# bench.run.spec POINT_FIELDS; a field that is not REQUIRED defaults to its neutral value).
Point = make_dataclass("Point", [(f.name, object) if f.neutral is REQUIRED else
                                 (f.name, object, field(default=f.neutral)) for f in POINT_FIELDS],
                       bases=(_PointMethods,), frozen=True, kw_only=True)
Point.__module__ = __name__
Point.__doc__ = "One sweep point: a mapping and, with threads, a scheme; the run parameters it shares."


def point_from_dict(d):
    """The Point of a manifest entry (its other keys, such as key and repeats, left out)."""
    names = {f.name for f in fields(Point)}
    return Point(**{k: v for k, v in d.items() if k in names})


def point_options(args):
    """{name: value} of the point options of a sweep's args (bench.cli; None where unset)."""
    return {f.name: getattr(args, f.name, None) for f in POINT_FIELDS if f.taken_by("sweep")}


# make_points' positional parameters after mappings and schemes, in the order of its callers from
# before the options were keywords
POSITIONAL = ("scene", "particles", "steps", "warmup", "neighbor", "shape", "pin", "halo", "contact_method",
              "update_grid", "balance", "newton", "skin", "preset", "hosts")


def make_points(mappings, schemes, *values, **options):
    """Points of a sweep: the serial reference first, then each mapping (x each scheme when it has
    more than one thread), without duplicates, in the order given. values: the options in the order
    of POSITIONAL; options: any point option by name (bench.run.spec POINT_FIELDS, point_options);
    one not given, or None, is the Field's neutral value. particles: one count, None (the scene's
    own) or a list of counts (the granularity study, issue 36: the grid counts x mappings, each
    count with its own serial reference, the references first, then the count's points in the
    order given, count by count); skin (a fraction, or None for bench run's default) goes to every
    point, the serial reference included. The options of scope procs (update_grid, balance, newton,
    hosts) go to the points with more than one process only; balance only with update_grid, and
    newton not to hybrid points under a scheme that stores every pair's forces (frogleap,
    headtail: they resolve a pair across a border on both ranks). A mapping with fewer ranks than
    hosts is refused (one line)."""
    if len(values) > len(POSITIONAL):
        raise TypeError(f"make_points takes at most {len(POSITIONAL)} options by position")
    options.update(zip(POSITIONAL, values))
    shared = {}
    for f in POINT_FIELDS:
        if f.name not in ("mapping", "scheme"):  # each point's own
            value = options.get(f.name)
            shared[f.name] = f.neutral if value is None and f.neutral is not REQUIRED else value
    if shared["skin"] is not None:
        shared["skin"] = float(shared["skin"])
    refusal = halo_skin_refusal(shared["skin"], shared["halo_skin"], shared["preset"]) or \
        forward_refusal(shared["forward"], shared["halo"], shared["hosts"])
    if refusal:
        raise ModeError(refusal)
    for s in schemes:
        if s not in SCHEMES:
            raise ModeError(f"unknown scheme {s!r} (schemes: {', '.join(SCHEMES)})")
    parsed = [parse_mapping(m) for m in mappings]  # one clear line for a malformed mapping
    hosts = shared["hosts"]
    refusal = next(filter(None, (too_few_ranks(hosts.split(",") if hosts else [], m) for m in parsed)), None)
    if refusal:
        raise ModeError(refusal)
    if SERIAL not in [str(m) for m in parsed]:
        parsed.insert(0, parse_mapping(SERIAL))
    points = []
    particles = options.get("particles")
    counts = list(particles) if isinstance(particles, (list, tuple)) else [particles]
    for n in counts:
        for m in parsed:
            for s in (schemes if m.threads > 1 else [""]):
                values = dict(shared, mapping=str(m), scheme=s, particles=n or 0)
                for f in POINT_FIELDS:
                    if f.scope == "procs" and m.procs == 1 and f.neutral is not REQUIRED:
                        values[f.name] = f.neutral
                if not values["update_grid"]:
                    values["balance"] = "extent"  # nothing to fit
                if m.threads > 1 and s not in SPLIT_SCHEMES:
                    values["newton"] = "auto"  # resolved on both ranks
                p = Point(**values)
                if p not in points:
                    points.append(p)
    points.sort(key=lambda p: p.mapping != SERIAL)  # the reference runs first
    return points


def point_env(point):
    """The thread variables of a point's processes (NUMBA_NUM_THREADS, OMP_NUM_THREADS = T). --pin
    sets no OMP binding here: `bench run --pin` binds its ranks and threads itself
    (bench.run.binding)."""
    m = parse_mapping(point.mapping)
    return {"NUMBA_NUM_THREADS": str(m.threads), "OMP_NUM_THREADS": str(m.threads)}
