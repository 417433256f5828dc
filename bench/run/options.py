"""The options of one run (`bench run` and each MPI rank of it) and the mode options they give.

Every bad value ends as one line through the parser's error (bench.cli); the mode refuses an
option it lacks (modes.base.ModeError).
"""
import argparse
import re

from dem.contact import CONTACT_METHODS, DEFAULT_CONTACT_METHOD  # plain names: numba has not started yet

# modes.mpi.BALANCE, named here because importing modes starts numba (tests/bench/test_cli.py
# checks that they agree)
BALANCE = ("extent", "count", "time")

CONTACT_METHOD_CHOICES = list(CONTACT_METHODS)
NEIGHBOR_CHOICES = ["allpairs", "linkcell"]
SHAPE_CHOICES = ["sphere", "ellipsoid", "polyellipsoid"]


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


def add_run_arguments(r):
    """The `bench run` options on parser r."""
    r.add_argument("--scene", help="built-in scene name or a .toml file (required unless --restart)")
    r.add_argument("--restart", metavar="FILE", default=None,
                   help="continue the run saved in checkpoint FILE (--checkpoint-every) in this mapping: its "
                        "scene, state, time step and energy balance; --steps N more steps (default: the rest of "
                        "the run that wrote it)")
    r.add_argument("--checkpoint-every", type=nonneg_int, default=0, metavar="K",
                   help="write DIR/checkpoint.npz (atomically) every K steps and after the last step")
    r.add_argument("--particles", type=positive_int, help="override the generated particle count")
    r.add_argument("--shape", choices=SHAPE_CHOICES, help="override the generated shape")
    r.add_argument("--seed", type=nonneg_int, help="override the generator seed")
    r.add_argument("--steps", type=nonneg_int, help="override the scene's step count")
    r.add_argument("--warmup", type=nonneg_int, default=0, metavar="W",
                   help="untimed steps before the timed ones (after JIT compilation, which is never timed)")
    r.add_argument("--dt", type=time_step_arg, help="time step [s] (default: the scene's, usually auto)")
    r.add_argument("--mapping", default="1-1-1-1-1", help="P-px-py-pz-T (default 1-1-1-1-1)")
    r.add_argument("--scheme", default=None, help="thread scheme: partition, frogleap, headtail, static, "
                                                  "dynamic (default dynamic; mappings with T > 1)")
    r.add_argument("--threaded", choices=["step", "detection"], default="step",
                   help="thread the whole step (default) or only contact detection (the paper's code)")
    r.add_argument("--pin", action="store_true",
                   help="give each rank T cores of its own and each thread one of them (bench.run.binding)")
    r.add_argument("--neighbor", choices=NEIGHBOR_CHOICES, default=None,
                   help="neighbour estimate: linkcell (default) or allpairs (the n-by-n search)")
    r.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="a named configuration: paper = --contact-method sextic --skin 0 --neighbor allpairs "
                        "(Yan & Regueiro's own; options given with it win)")
    r.add_argument("--contact-method", choices=CONTACT_METHOD_CHOICES, default=None,
                   help="ellipsoid contact geometry: exact (PW + Newton, default; a restart: the checkpoint's), "
                        "pw (Perram-Wertheim depth, error O(depth/size)), sextic (the paper's Yan 2010 method, a "
                        "known error)")
    r.add_argument("--skin", type=skin_fraction, default=None, metavar="F",
                   help="neighbour-list skin, fraction of the largest bounding diameter (default 0.1; "
                        "0: estimate neighbours every step, the paper's way)")
    r.add_argument("--snapshot-every", type=nonneg_int, default=0, metavar="K",
                   help="write DIR/snapshots/step<8-digit step>.vtu (or .vtk) + .npz every K steps")
    r.add_argument("--snapshot-format", choices=["vtu", "vtk"], default="vtu",
                   help="snapshot format: vtu (default: binary VTK XML, a snapshots.pvd time series for "
                        "ParaView, read by meshio) or vtk (legacy ASCII polydata)")
    r.add_argument("--plot", action="store_true", help="draw DIR/run.png (timings, contacts, energy)")
    r.add_argument("--out", default=None, help="output folder (default results/run-<scene>)")
    r.add_argument("--guard-overlap", type=overlap_fraction, default=0.05, metavar="F",
                   help="stop when a contact overlaps more than F of the smaller body's smallest semi-axis "
                        "(default 0.05)")
    r.add_argument("--halo", choices=["26", "6"], default="26",
                   help="ghost exchange: 26 direct messages (default, the paper's) or 3 sweeps of 6")
    r.add_argument("--update-grid", type=nonneg_int, default=0, metavar="K",
                   help="fit the block grid to the particles at the start and every K steps (the paper's "
                        "updateGrid; default 0: blocks divide the box)")
    r.add_argument("--balance", choices=BALANCE, default="extent",
                   help="how --update-grid fits the grid: extent (default, the paper's: equal blocks over the "
                        "particles' extent), count (cut planes at equal particle counts) or time (cut planes at "
                        "equal measured compute time, LAMMPS's weight time)")
    r.add_argument("--newton", choices=["auto", "on", "off"], default="auto",
                   help="P > 1: resolve each cross-border pair on one rank and send its other end's terms back "
                        "(on; LAMMPS's newton on) or on both ranks (off); default auto: on, except under the thread "
                        "schemes that store every pair's forces (frogleap, headtail), where on is refused")
    r.add_argument("--timeout", type=positive_int, default=3600, help="seconds before MPI ranks are killed")
    r.add_argument("--hang-timeout", type=seconds, default=30.0, metavar="S",
                   help="P > 1: stop the run when a rank's heartbeat is S seconds old while a peer's is fresh "
                        "(a rank stopped or stuck; default 30, 0: off)")
    r.add_argument("--hosts", type=host_list, default=None, metavar="H1,H2,...|@FILE",
                   help="P > 1: run the ranks on these hosts (mpiexec -hosts, -ppn ceil(P/K) for K hosts: consecutive "
                        "ranks, so neighbouring blocks, share a host); a comma list or @FILE, one host a line; "
                        "mpiexec reaches them by ssh (or HYDRA_LAUNCHER / HYDRA_LAUNCHER_EXEC)")
    r.add_argument("--mpi-starter", default=None, metavar="CMD",
                   help="P > 1: the command that starts the P ranks instead of `mpiexec -n P`, the rank program "
                        "appended (inside a Slurm allocation: 'srun --mpi=pmi2 --ntasks=P --cpus-per-task=T "
                        "--cpu-bind=cores'; `bench sweep --launcher slurm` writes it)")
    r.add_argument("--quiet", action="store_true", help="no summary line at the end (warnings and errors still)")

    return r


def mode_options(mapping, args, scheme):
    """The setup options of the mode that runs `mapping` (each mode refuses options it lacks)."""
    opts = {"neighbor": args.neighbor, "skin": args.skin,
            "contact_method": args.contact_method or DEFAULT_CONTACT_METHOD}
    if mapping.threads > 1:
        opts.update(threads=mapping.threads, scheme=scheme, threaded=args.threaded)
    if mapping.procs > 1:
        opts.update(halo=args.halo, update_grid=args.update_grid, balance=args.balance,
                    newton={"on": True, "off": False}.get(getattr(args, "newton", "auto")))
    return opts
