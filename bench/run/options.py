"""The values of the options of a run (`bench run` and each MPI rank of it; declared in
bench.run.spec): their checks, the presets, the mode options they give and the mode's one set-up
(setup_mode).

Every bad value ends as one line through the parser's error (bench.cli); the mode refuses an
option it lacks (modes.base.ModeError).
"""
import argparse
import re

from dem.contact import CONTACT_METHODS, DEFAULT_CONTACT_METHOD  # plain names: numba has not started yet
from dem.shapes.registry import SHAPE_NAMES  # the same

# modes.mpi.BALANCE, named here because importing modes starts numba (tests/bench/test_cli.py
# checks that they agree)
BALANCE = ("extent", "count", "time")

CONTACT_METHOD_CHOICES = list(CONTACT_METHODS)
NEIGHBOR_CHOICES = ["allpairs", "linkcell"]
SHAPE_CHOICES = list(SHAPE_NAMES)  # the registered shapes (dem.shapes.registry)


def _integer_at_least(text, lo, what):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if v < lo:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return v


def positive_int(text):
    return _integer_at_least(text, 1, "a positive integer")


def nonneg_int(text):
    return _integer_at_least(text, 0, "a non-negative integer")


def _number_in(text, ok, expected):
    """float(text) when ok(value) (nan fails every comparison, so it never passes); else one
    argparse line 'expected <expected>, got <text>'."""
    try:
        v = float(text)
    except ValueError:
        v = None
    if v is None or not ok(v):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return v


def skin_fraction(text):
    return _number_in(text, lambda v: 0.0 <= v <= 10.0, "a fraction in [0, 10]")


def particle_counts(text):
    """bench sweep --particles: one count or a comma-separated list of distinct positive counts
    (the granularity study); an int for one count, a list for several."""
    parts = [t.strip() for t in str(text).split(",")]
    if not parts or any(not t for t in parts):
        raise argparse.ArgumentTypeError(f"expected a positive integer or a comma-separated list of them, got {text!r}")
    counts = [_integer_at_least(t, 1, "a positive integer or a comma-separated list of them") for t in parts]
    if len(set(counts)) != len(counts):
        raise argparse.ArgumentTypeError(f"expected distinct particle counts, got {text!r}")
    return counts[0] if len(counts) == 1 else counts


def precision_fraction(text):
    """bench sweep --precision: the relative half-width sought, in (0, 1)."""
    return _number_in(text, lambda v: 0.0 < v < 1.0, "a fraction in (0, 1), e.g. 0.05")


def positive_float(text):
    """A finite number > 0 (e.g. --budget seconds)."""
    return _number_in(text, lambda v: 0.0 < v < 1e12, "a finite number > 0")


def overlap_fraction(text):
    """--guard-overlap: a finite fraction in (0, 1] (nan would turn the guard off)."""
    return _number_in(text, lambda v: 0.0 < v <= 1.0, "a fraction in (0, 1]")


def seconds(text):
    """A finite number of seconds >= 0."""
    return _number_in(text, lambda v: 0.0 <= v < 1e9, "seconds >= 0")


HOST_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")  # a host name or address, as mpiexec -hosts takes it


def host_list(text):
    """--hosts: host names, comma-separated, or @FILE with one a line ('#' comments; a Hydra or Open
    MPI host file's `host:slots` / `host slots=N` keep their host). Returns them joined by commas."""
    if text.startswith("@"):
        try:
            with open(text[1:]) as fh:
                names = [line.split("#", 1)[0].split()[0].split(":")[0] for line in fh if line.split("#", 1)[0].strip()]
        except (OSError, UnicodeDecodeError) as e:
            raise argparse.ArgumentTypeError(f"cannot read the host file {text[1:]!r}: "
                                             f"{getattr(e, 'strerror', None) or e}") from None
    else:
        names = [h.strip() for h in text.split(",")]
    bad = next((h for h in names if not HOST_NAME.fullmatch(h)), None)
    if not names or bad is not None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of host names (bad: {bad!r})")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r} names a host twice")
    return ",".join(names)


def too_few_ranks(hosts, mapping):
    """The one-line refusal of a mapping (modes.base.Mapping) with fewer ranks than the hosts [K]
    of --hosts (at least one a host), or None when it fits or runs on one process."""
    if 1 < mapping.procs < len(hosts):
        return (f"--hosts names {len(hosts)} hosts but mapping {mapping} has only {mapping.procs} ranks "
                f"(at least one a host)")
    return None


def time_step_arg(text):
    """--dt: a positive finite number of seconds."""
    return _number_in(text, lambda v: 0.0 < v < 1e30, "a finite time step [s] > 0")


# --preset NAME: the options a named configuration sets (explicit options given with it win).
# paper: Yan & Regueiro (2019)'s own configuration, as ParaEllip3d runs it: the sextic contact
# method of Yan, Regueiro & Sture (2010) (§2; dem.contact.methods), the neighbour estimate every
# step (no Verlet list: skin 0), and the n-by-n search within each process's block and thread
# (its threaded schemes loop n-by-n, §4.2, Table 1; and O(n^2) "outperforms O(n) in large-scale
# parallel 3D DEM simulations generally", §5.4).
PRESETS = {"paper": {"contact_method": "sextic", "skin": 0.0, "neighbor": "allpairs"}}
# what each option is when neither the preset nor the user sets it (bench run; bench sweep also
# fills the contact method, which bench run leaves unset for a restart to take the checkpoint's)
PRESET_FALLBACK = {"neighbor": "linkcell"}
SWEEP_FALLBACK = dict(PRESET_FALLBACK, contact_method=DEFAULT_CONTACT_METHOD)


def apply_preset(args, fallback=PRESET_FALLBACK):
    """Fill the options of args.preset (PRESETS) that were not given explicitly (None), then the
    fallbacks of those still unset. Returns args; args.preset_overrides names the options given
    against the preset (recorded with the run)."""
    preset = getattr(args, "preset", None)
    overrides = []
    for key, value in (PRESETS.get(preset) or {}).items():
        given = getattr(args, key, None)
        if given is None:
            setattr(args, key, value)
        elif given != value:
            overrides.append(key)
    for key, value in fallback.items():
        if getattr(args, key, None) is None:
            setattr(args, key, value)
    args.preset_overrides = overrides
    return args


def halo_skin_refusal(skin, halo_skin, preset=None):
    """The one line refusing --halo-skin where the list has a skin (skin None: the preset's, else
    bench run's default 0.1), or None: the halo has a skin of its own only with --skin 0."""
    if halo_skin is None:
        return None
    if skin is None:
        skin = PRESETS.get(preset or "", {}).get("skin")
    return None if skin == 0 else "--halo-skin needs --skin 0 (with a list skin the halo takes the list's)"


def forward_refusal(forward, halo, hosts=""):
    """The one line refusing --forward shared where no window can be (--halo 6, whose sweeps forward
    what earlier sweeps brought; ranks on more than one host), or None."""
    if forward != "shared":
        return None
    if halo == "6":
        return "--forward shared needs --halo 26 (the three sweeps forward what earlier sweeps brought)"
    if len({h for h in (hosts or "").split(",") if h}) > 1:
        return "--forward shared needs every rank on one node (--hosts names several: use auto or messages)"
    return None


def mode_options(mapping, args, scheme):
    """The setup options of the mode that runs `mapping` (each mode refuses options it lacks)."""
    opts = {"neighbor": args.neighbor, "skin": getattr(args, "skin", None),
            "contact_method": args.contact_method or DEFAULT_CONTACT_METHOD}
    if mapping.threads > 1:
        opts.update(threads=mapping.threads, scheme=scheme, threaded=args.threaded)
    if mapping.procs > 1:
        opts.update(halo=args.halo, update_grid=args.update_grid, balance=args.balance,
                    newton={"on": True, "off": False}.get(getattr(args, "newton", "auto")),
                    halo_skin=getattr(args, "halo_skin", None), forward=getattr(args, "forward", "messages"))
    return opts


def run_scheme(mapping, args):
    """The threads' scheme of a run: --scheme, else modes.parallel's default for a mapping with more
    than one thread (None for one thread)."""
    from modes.parallel import DEFAULT_SCHEME  # here, not at the top: importing modes starts numba
    return args.scheme or (DEFAULT_SCHEME if mapping.threads > 1 else None)


def setup_mode(mapping, args, scene, dt, comm=None):
    """The one set-up of a run's mode (bench run's process, each MPI rank, the launcher's cache
    warm-up): the registered mode that accepts `mapping` (modes.base mode_for), set up on the scene
    with time step dt [s] and the run's options (mode_options; comm: the rank's Cartesian
    communicator, for P > 1). Returns the mode (modes.base.Mode)."""
    from modes.base import mode_for  # here, not at the top: importing modes starts numba
    opts = mode_options(mapping, args, run_scheme(mapping, args))
    if comm is not None:
        opts["cart"] = comm
    return mode_for(mapping)().setup(scene, dt=dt, **opts)
