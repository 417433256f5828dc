"""The points of a sweep: a mapping (and, with threads, a scheme) with the run parameters it shares.

Every point runs as its own `bench run` in DIR/<key>/rep<r>/; its key names the mapping and
scheme and hashes every parameter, so --resume recognises a point by what it runs.
"""
import hashlib
import json
from dataclasses import asdict, dataclass, fields

from bench.run.options import too_few_ranks
from dem.contact import DEFAULT_CONTACT_METHOD
from modes.base import ModeError, parse_mapping
from modes.parallel import SCHEMES, SPLIT_SCHEMES

SERIAL = "1-1-1-1-1"


@dataclass(frozen=True)
class Point:
    """One sweep point: a mapping and, with threads, a scheme; the run parameters it shares."""
    mapping: str
    scheme: str
    scene: str
    particles: int
    steps: int
    warmup: int
    neighbor: str
    shape: str
    pin: bool
    halo: str
    contact_method: str = DEFAULT_CONTACT_METHOD
    update_grid: int = 0
    balance: str = "extent"
    newton: str = "auto"
    skin: float = None   # the neighbour-list skin fraction of every point (None: bench run's default)
    preset: str = ""     # bench run --preset of every point ("" none); its options are the fields above
    hosts: str = ""      # bench run --hosts of the MPI and hybrid points ("" this host)

    @property
    def key(self):
        """Folder name: readable mapping and scheme plus a hash of every parameter (update_grid only
        when set, balance only when not the paper's extent, newton only when not auto and skin only
        when given, so the points of sweeps from before them keep their keys for --resume)."""
        params = asdict(self)
        if not params["update_grid"]:
            del params["update_grid"]
        if params["balance"] == "extent":
            del params["balance"]
        if params["newton"] == "auto":
            del params["newton"]
        if params["skin"] is None:
            del params["skin"]
        if not params["preset"]:
            del params["preset"]
        if not params["hosts"]:
            del params["hosts"]
        digest = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:8]
        return f"{self.mapping}{'-' + self.scheme if self.scheme else ''}-{digest}"

    def run_args(self, out, timeout):
        args = ["run", "--scene", self.scene, "--mapping", self.mapping, "--neighbor", self.neighbor,
                "--warmup", str(self.warmup), "--out", out, "--quiet", "--timeout", str(timeout)]
        for flag, v in (("--particles", self.particles), ("--steps", self.steps), ("--shape", self.shape),
                        ("--scheme", self.scheme)):
            if v:
                args += [flag, str(v)]
        if self.pin:
            args.append("--pin")
        if self.contact_method != DEFAULT_CONTACT_METHOD:
            args += ["--contact-method", self.contact_method]
        if self.skin is not None:
            args += ["--skin", repr(float(self.skin))]
        if self.preset:
            args += ["--preset", self.preset]
        if self.mapping.split("-")[0] != "1":
            args += ["--halo", self.halo]
            if self.update_grid:
                args += ["--update-grid", str(self.update_grid)]
                if self.balance != "extent":
                    args += ["--balance", self.balance]
            if self.newton != "auto":
                args += ["--newton", self.newton]
            if self.hosts:
                args += ["--hosts", self.hosts]
        return args


def point_from_dict(d):
    """The Point of a manifest entry (its other keys, such as key and repeats, left out)."""
    names = {f.name for f in fields(Point)}
    return Point(**{k: v for k, v in d.items() if k in names})


def make_points(mappings, schemes, scene, particles, steps, warmup, neighbor, shape, pin, halo,
                contact_method=DEFAULT_CONTACT_METHOD, update_grid=0, balance="extent", newton="auto", skin=None,
                preset=None, hosts=None):
    """Points of a sweep: the serial reference first, then each mapping (x each scheme when it has
    more than one thread), without duplicates, in the order given; particles: one count, None (the
    scene's own) or a list of counts (the granularity study, issue 36: the grid counts x mappings,
    each count with its own serial reference, the references first, then the count's points in
    the order given, count by count); skin (a fraction, or None for
    bench run's default) goes to every point, the serial reference included. newton (auto, on, off) goes to
    the points with more than one process, except hybrid points under a scheme that stores every
    pair's forces (frogleap, headtail: they resolve a pair across a border on both ranks). hosts
    (bench run --hosts) goes to the points with more than one process; a mapping with fewer
    ranks than hosts is refused (one line)."""
    for s in schemes:
        if s not in SCHEMES:
            raise ModeError(f"unknown scheme {s!r} (schemes: {', '.join(SCHEMES)})")
    parsed = [parse_mapping(m) for m in mappings]  # one clear line for a malformed mapping
    refusal = next(filter(None, (too_few_ranks(hosts.split(",") if hosts else [], m) for m in parsed)), None)
    if refusal:
        raise ModeError(refusal)
    if SERIAL not in [str(m) for m in parsed]:
        parsed.insert(0, parse_mapping(SERIAL))
    points = []
    counts = list(particles) if isinstance(particles, (list, tuple)) else [particles]
    for n in counts:
        for m in parsed:
            for s in (schemes if m.threads > 1 else [""]):
                p = Point(str(m), s, scene, n or 0, steps or 0, warmup, neighbor, shape or "", pin, halo,
                          contact_method, update_grid if m.procs > 1 else 0,
                          balance if m.procs > 1 and update_grid else "extent",
                          newton if m.procs > 1 and (m.threads == 1 or s in SPLIT_SCHEMES) else "auto",
                          None if skin is None else float(skin), preset or "",
                          hosts if m.procs > 1 and hosts else "")
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
