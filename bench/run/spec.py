"""The options of `bench run` and `bench sweep`, declared once (issue 35): FIELDS, one Field an option.

Everything else is derived from it: the flags of `bench run` (and of each MPI rank, bench.run.rank)
and of `bench sweep` (bench.cli), the sweep file's keys and their checks (bench.cli SWEEP_FIELDS),
the fields of a sweep point and its key (bench.sweep.points), the options the ranks get in their
argv (rank_argv, bench.run.launch) and the options a run records in run.json and its checkpoint
(recorded, bench.run.driver). Adding an option that a run and a sweep both take is one Field here
(docs/ARCHITECTURE.md, Adding an option), plus the code that acts on it.

The sweep's own options (--mappings, --repeats, --precision, ...) are Fields too, so that its parser
and its file keep one order and one list; only the Slurm group (bench.sweep.slurm_options) is
declared elsewhere. FIELDS is in the order of `bench run --help`; `bench sweep --help` and the sweep
file's key list follow the same order.
"""
from dataclasses import dataclass

from bench.run.options import (BALANCE, CONTACT_METHOD_CHOICES, NEIGHBOR_CHOICES, PRESETS, SHAPE_CHOICES, host_list,
                               nonneg_int, overlap_fraction, particle_counts, positive_float, positive_int,
                               precision_fraction, seconds, skin_fraction, time_step_arg)
from dem.contact import DEFAULT_CONTACT_METHOD  # plain names: numba has not started yet

# `bench sweep --precision`: the most rounds it runs (bench.sweep.precision), named in its help
ROUNDS_CAP = 20


class _Marker:
    def __init__(self, text):
        self.text = text

    def __repr__(self):
        return self.text


REQUIRED = _Marker("REQUIRED")   # Field.neutral: every point sets it (always in its command and its key)
AS_DEFAULT = _Marker("AS_DEFAULT")  # Field.neutral: the option's default


@dataclass(frozen=True)
class Field:
    """One option. name: its attribute (argparse dest) and sweep-file key, flag --name with '-' for
    '_'; help: `bench run`'s text (the sweep's for an option of the sweep alone); type: argparse's
    (bool: a flag, store_true); default, choices, metavar: argparse's.

    takes: the commands that take it: run (and its ranks), sweep (a flag of `bench sweep`), file
    (a key of a sweep file). sweep: what `bench sweep`'s flag has of its own (help, type, default,
    metavar). listed: a comma-separated list, which a sweep file may give as a list of strings.
    expects: a number of the sweep file: what it must be (its one-line error), checked by the
    sweep's type.

    point: part of a sweep point's identity (bench.sweep.points): "always" in its key (the options
    of the first sweeps), or "given": in its key and its command only when not neutral, so that
    the points of sweeps from before the option keep their keys (folder names) for --resume.
    neutral: the value of a point that does not set it (AS_DEFAULT: default; REQUIRED: every point
    sets it, and its command always passes it). scope: "procs": only runs with more than one
    process use it (points with one get the neutral value and no flag; run.json records None),
    "threads": only runs with more than one thread (run.json records None).

    rank: `bench run` hands it to its MPI ranks (rank_argv). record: where a run records it, under
    its name: "run.json", "checkpoint" (recorded)."""
    name: str
    help: str
    type: object = None
    default: object = None
    choices: object = None
    metavar: str = None
    takes: str = "run sweep file"
    sweep: dict = None
    listed: bool = False
    expects: str = ""
    point: str = ""
    neutral: object = AS_DEFAULT
    scope: str = ""
    rank: bool = True
    record: str = ""

    def __post_init__(self):
        if self.neutral is AS_DEFAULT:
            object.__setattr__(self, "neutral", self.default)

    @property
    def flag(self):
        return "--" + self.name.replace("_", "-")

    def taken_by(self, command):
        return command in self.takes.split()

    def argument(self, command):
        """The keyword arguments of its add_argument in `command` (run or sweep)."""
        kw = {"help": self.help, "type": self.type, "default": self.default, "choices": self.choices,
              "metavar": self.metavar}
        if command == "sweep":
            kw.update(self.sweep or {})
        if kw.pop("type") is bool:
            return {"action": "store_true", "help": kw["help"]}
        kw["type"] = self.sweep_type if command == "sweep" else self.type
        return {k: v for k, v in kw.items() if v is not None}

    @property
    def sweep_type(self):
        return (self.sweep or {}).get("type", self.type)


FIELDS = (
    # bench sweep's own, first in its help
    Field("mappings", "comma-separated P-px-py-pz-T list (1-1-1-1-1 is added when missing)", takes="sweep file",
          listed=True),
    Field("file", "sweep file (TOML, a [sweep] table with the same fields) instead of options", takes="sweep"),
    Field("schemes", "comma-separated thread schemes for mappings with T > 1 (default dynamic)", takes="sweep file",
          listed=True),
    Field("scene", "built-in scene name or a .toml file (required unless --restart)", point="always",
          neutral=REQUIRED,
          sweep={"help": "built-in scene name (bench scenes) or a .toml file, the same for every point"}),
    Field("restart", "continue the run saved in checkpoint FILE (--checkpoint-every) in this mapping: its scene, "
          "state, time step and energy balance; --steps N more steps (default: the rest of the run that wrote it)",
          metavar="FILE", takes="run"),
    Field("checkpoint_every", "write DIR/checkpoint.npz (atomically) every K steps and after the last step",
          type=nonneg_int, default=0, metavar="K", takes="run"),
    Field("particles", "override the generated particle count", type=positive_int, point="always", neutral=0,
          sweep={"type": particle_counts,
                 "help": "particles of a generated scene (default the scene's); a list (2000,12000,50000) runs "
                         "every mapping at each count, each with its own serial reference, and draws "
                         "granularity.png (efficiency against particles per core)"}),
    Field("shape", "override the generated shape", choices=SHAPE_CHOICES, point="always", neutral="",
          sweep={"help": "shape of a generated scene's particles (default the scene's)"}),
    Field("seed", "override the generator seed", type=nonneg_int, takes="run"),
    Field("steps", "override the scene's step count", type=nonneg_int, point="always", neutral=0,
          sweep={"type": positive_int, "help": "timed steps of every point (default the scene's)"}),
    Field("warmup", "untimed steps before the timed ones (after JIT compilation, which is never timed)",
          type=nonneg_int, default=0, metavar="W", point="always", neutral=REQUIRED,
          sweep={"metavar": None, "help": "untimed steps before the timed ones"}),
    Field("repeats", "runs per point (medians recorded)", type=positive_int, default=1, takes="sweep file"),
    Field("dt", "time step [s] (default: the scene's, usually auto)", type=time_step_arg, takes="run"),
    Field("mapping", "P-px-py-pz-T (default 1-1-1-1-1)", default="1-1-1-1-1", takes="run", point="always",
          neutral=REQUIRED),
    Field("scheme", "thread scheme: partition, frogleap, headtail, static, dynamic (default dynamic; mappings "
          "with T > 1)", takes="run", point="always", neutral=""),
    Field("threaded", "thread the whole step (default) or only contact detection (the paper's code)",
          choices=["step", "detection"], default="step", takes="run", scope="threads", record="run.json"),
    Field("pin", "give each rank T cores of its own and each thread one of them (bench.run.binding)", type=bool,
          default=False, point="always", record="run.json",
          sweep={"help": "every point's ranks get T cores of their own and each thread one of them (bench run "
                         "--pin; runs.csv binding says whether it held)"}),
    Field("neighbor", "neighbour estimate: linkcell (default) or allpairs (the n-by-n search)",
          choices=NEIGHBOR_CHOICES, point="always", neutral=REQUIRED, record="run.json checkpoint",
          sweep={"help": "linkcell (default) or allpairs"}),
    Field("preset", "a named configuration: paper = --contact-method sextic --skin 0 --neighbor allpairs "
          "(Yan & Regueiro's own; options given with it win)", choices=sorted(PRESETS), point="given", neutral="",
          record="run.json",
          sweep={"help": "a named configuration for every point: paper = --contact-method sextic --skin 0 "
                         "--neighbor allpairs (options given with it win)"}),
    Field("contact_method", "ellipsoid contact geometry: exact (PW + Newton, default; a restart: the checkpoint's), "
          "pw (Perram-Wertheim depth, error O(depth/size)), sextic (the paper's Yan 2010 method, a known error)",
          choices=CONTACT_METHOD_CHOICES, point="always", neutral=DEFAULT_CONTACT_METHOD,
          record="run.json checkpoint",
          sweep={"help": "ellipsoid contact geometry of every point (default exact)"}),
    Field("skin", "neighbour-list skin, fraction of the largest bounding diameter (default 0.1; 0: estimate "
          "neighbours every step, the paper's way)", type=skin_fraction, metavar="F", point="given",
          expects="a fraction in [0, 10]",
          sweep={"help": "neighbour-list skin of every point, fraction of the largest bounding diameter (default "
                         "bench run's, 0.1; 0: neighbours estimated every step, the paper's way)"}),
    Field("halo_skin", "with --skin 0, the MPI halo's own skin, fraction of the largest bounding diameter: the "
          "ghosts and the particles' owners are chosen anew only when a particle has moved half of it, the "
          "neighbours still every step (default 0.1; 0: the halo every step too, as the paper's code)",
          type=skin_fraction, metavar="F", point="given", scope="procs", expects="a fraction in [0, 10]",
          sweep={"help": "MPI points with --skin 0: the halo's own skin, fraction of the largest bounding "
                         "diameter (default bench run's, 0.1; 0: ghosts and migration every step)"}),
    Field("snapshot_every", "write DIR/snapshots/step<8-digit step>.vtu (or .vtk) + .npz every K steps",
          type=nonneg_int, default=0, metavar="K", takes="run"),
    Field("snapshot_format", "snapshot format: vtu (default: binary VTK XML, a snapshots.pvd time series for "
          "ParaView, read by meshio) or vtk (legacy ASCII polydata)", choices=["vtu", "vtk"], default="vtu",
          takes="run"),
    Field("plot", "draw DIR/run.png (timings, contacts, energy)", type=bool, default=False, takes="run"),
    Field("out", "output folder (default results/run-<scene>)", takes="run"),
    Field("guard_overlap", "stop when a contact overlaps more than F of the smaller body's smallest semi-axis "
          "(default 0.05)", type=overlap_fraction, default=0.05, metavar="F", takes="run"),
    Field("halo", "ghost exchange: 26 direct messages (default, the paper's) or 3 sweeps of 6", choices=["26", "6"],
          default="26", point="always", neutral=REQUIRED, scope="procs", record="run.json",
          sweep={"help": "MPI points: ghosts in 26 direct messages (default, the paper's) or 3 sweeps of 6"}),
    Field("forward", "P > 1: how the ghosts' moving fields travel between neighbour rebuilds: messages (default, "
          "the paper's way); shared: through a shared-memory window (MPI-3) of the node (refused where the ranks "
          "span nodes or with --halo 6); auto: the window where every rank runs on one node with --halo 26, else "
          "messages", choices=["auto", "shared", "messages"], default="messages", point="given", scope="procs",
          record="run.json",
          sweep={"help": "MPI and hybrid points: the ghosts' moving fields between rebuilds by messages (default) or "
                         "through a shared-memory window on one node (shared; auto: where it can be)"}),
    Field("update_grid", "fit the block grid to the particles at the start and every K steps (the paper's "
          "updateGrid; default 0: blocks divide the box)", type=nonneg_int, default=0, metavar="K", point="given",
          scope="procs", record="run.json",
          sweep={"help": "MPI points fit their block grid to the particles at the start and every K steps (the "
                         "paper's updateGrid; default 0: blocks divide the box)"}),
    Field("balance", "how --update-grid fits the grid: extent (default, the paper's: equal blocks over the "
          "particles' extent), count (cut planes at equal particle counts) or time (cut planes at equal measured "
          "compute time, LAMMPS's weight time)", choices=BALANCE, default="extent", point="given", scope="procs",
          sweep={"help": "how --update-grid fits the grid: extent (default, the paper's), count (equal particle "
                         "counts) or time (equal measured compute time)"}),
    Field("newton", "P > 1: resolve each cross-border pair on one rank and send its other end's terms back (on; "
          "LAMMPS's newton on) or on both ranks (off); default auto: on, except under the thread schemes that store "
          "every pair's forces (frogleap, headtail), where on is refused", choices=["auto", "on", "off"],
          default="auto", point="given", scope="procs",
          sweep={"help": "MPI and hybrid points: resolve each pair across a border on one rank (on) or on both "
                         "(off); default auto (on); hybrid points under frogleap or headtail always resolve it on "
                         "both"}),
    Field("timeout", "seconds before MPI ranks are killed", type=positive_int, default=3600, takes="run", rank=False),
    Field("hang_timeout", "P > 1: stop the run when a rank's heartbeat is S seconds old while a peer's is fresh "
          "(a rank stopped or stuck; default 30, 0: off)", type=seconds, default=30.0, metavar="S", takes="run",
          rank=False),
    Field("hosts", "P > 1: run the ranks on these hosts (mpiexec -hosts, -ppn ceil(P/K) for K hosts: consecutive "
          "ranks, so neighbouring blocks, share a host); a comma list or @FILE, one host a line; mpiexec reaches "
          "them by ssh (or HYDRA_LAUNCHER / HYDRA_LAUNCHER_EXEC)", type=host_list, metavar="H1,H2,...|@FILE",
          listed=True, point="given", neutral="", scope="procs", rank=False,
          sweep={"help": "local launcher: run every MPI and hybrid point's ranks on these hosts (bench run --hosts: "
                         "mpiexec -hosts, consecutive ranks a host); a comma list or @FILE, one host a line"}),
    Field("mpi_starter", "P > 1: the command that starts the P ranks instead of `mpiexec -n P`, the rank program "
          "appended (inside a Slurm allocation: 'srun --mpi=pmi2 --ntasks=P --cpus-per-task=T --cpu-bind=cores'; "
          "`bench sweep --launcher slurm` writes it)", metavar="CMD", takes="run", rank=False),
    Field("quiet", "no summary line at the end (warnings and errors still)", type=bool, default=False, takes="run"),
    # bench sweep's own, last in its help
    Field("ceiling", "also measure the machine's efficiency ceiling at each core count W of the sweep (W "
          "independent serial copies of the scene at N/W particles, alone, together and meeting every step, a "
          "round after each round of repeats): OUT/ceiling.csv, drawn on efficiency.png (local launcher)",
          type=bool, default=False, takes="sweep file"),
    Field("precision", "after --repeats rounds (at least 2), more interleaved rounds of every point until each "
          "point's 95 %% interval of its step time is within F of its median (e.g. 0.05), the --budget is spent "
          f"or {ROUNDS_CAP} rounds are run; runs.csv `resolved` says which", type=precision_fraction, metavar="F",
          takes="sweep file", expects="a fraction in (0, 1)"),
    Field("budget", "with --precision: start no further round once the sweep has run this long or the next round "
          "would not fit", type=positive_float, metavar="SECONDS", takes="sweep file",
          expects="a number of seconds > 0"),
    Field("compare", "after the sweep, each point against the same point of the earlier sweep in DIR: faster, "
          "slower or the same, with the 95 %% interval of the ratio (bench compare DIR OUT)", metavar="DIR",
          takes="sweep file"),
    Field("timeout", "seconds per point run", type=positive_int, default=1800, takes="sweep file"),
    Field("launcher", "local (default: each point here, one after another) or slurm (a prepare job, a job array a "
          "point, a collect job)", default="local", takes="sweep file"),
    Field("dry_run", "print every command and environment, run nothing", type=bool, default=False, takes="sweep"),
    Field("resume", "skip the points already done in OUT/runs.csv (slurm: the repeats done, pending or running)",
          type=bool, default=False, takes="sweep"),
    Field("out", "sweep folder: runs.csv, manifest.json, figures and one folder a point", takes="sweep file"),
    Field("status", "the state of each point of the sweep in DIR (its files, and Slurm's scontrol/sacct where Slurm "
          "runs)", metavar="DIR", takes="sweep"),
    Field("cancel", "scancel the jobs of the Slurm sweep in DIR still pending or running", metavar="DIR",
          takes="sweep"),
)


def fields(command):
    """The Fields `command` takes (run, sweep or file), in FIELDS' order."""
    return tuple(f for f in FIELDS if f.taken_by(command))


def add_arguments(parser, command):
    """The flags of `command` (run or sweep) on parser; returns it."""
    for f in fields(command):
        parser.add_argument(f.flag, **f.argument(command))
    return parser


def add_run_arguments(r):
    """The `bench run` options on parser r (also each MPI rank's, bench.run.rank)."""
    return add_arguments(r, "run")


def file_type(f):
    """What a sweep file's value of f is: bool, int, float (its `expects`) or str."""
    t = f.sweep_type
    if t is bool:
        return bool
    if t in (positive_int, nonneg_int, particle_counts):
        return int
    return float if f.expects else str


# the fields of a sweep point (bench.sweep.points Point), in FIELDS' order
POINT_FIELDS = tuple(f for f in fields("run") if f.point)


def applies(f, mapping):
    """Whether a run of mapping (modes.base.Mapping) uses option f (its scope)."""
    return {"procs": mapping.procs > 1, "threads": mapping.threads > 1}.get(f.scope, True)


def rank_argv(args, **given):
    """The argv that gives each MPI rank the options of this run (args; given: values that replace
    its own, such as the resolved output folder): every option of `bench run` the ranks take that is
    set (flags: given), in FIELDS' order."""
    argv = []
    for f in fields("run"):
        if not f.rank:
            continue
        value = given[f.name] if f.name in given else getattr(args, f.name, f.default)
        if f.type is bool:
            argv += [f.flag] if value else []
        elif value is not None:
            argv += [f.flag, str(value)]
    return argv


def recorded(args, mapping, where):
    """{name: value} of the options a run of mapping records in `where` ("run.json" or "checkpoint"),
    None for one the mapping does not use (its scope)."""
    return {f.name: getattr(args, f.name, f.default) if applies(f, mapping) else None
            for f in fields("run") if where in f.record.split()}
