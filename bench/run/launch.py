"""Launching a P > 1 mapping: `mpiexec -n P python -m bench.run.witness --out DIR -- python -m mpi4py
-m bench.run.rank ...` (the witness records how its rank ended, if badly).

The parent process has already validated the inputs, built the scene's cache, chosen the time
step (handed to the ranks, which do not choose it again) and created the output folder; here it
refuses a decomposition that cannot work (one line), compiles numba's
cache once so that P ranks do not compile at the same time, and runs mpiexec under its supervisor
(bench.run.supervise, in a session of its own; `python -m mpi4py` aborts every rank when one
raises): the supervisor forwards signals, stops the ranks at the timeout, names a rank that died
or stopped responding (heartbeats), keeps and marks the records, and dies with this process, which
forwards SIGINT, SIGTERM and SIGHUP to it and waits for it (issue 15). Environment:
NUMBA_NUM_THREADS = T; more ranks x threads than usable CPUs get a one-line warning and
OMP_WAIT_POLICY=PASSIVE, and mpich's progress throttle (bench.run.transport
SHARED_CORES); mpich's shared-memory cells sized for a step's messages
(bench.run.transport). --pin: each rank binds itself and its threads to the plan of
bench.run.binding over the CPUs its node's ranks were given, whatever the starter; Hydra (MPICH)
is asked for `-bind-to core:T` as well (Open MPI's equivalent is `--map-by slot:PE=T --bind-to
core`, Slurm's `srun --cpus-per-task=T --cpu-bind=cores`). This process runs a parallel warm-up
before it starts the ranks, which an OMP_PROC_BIND in the environment would pin to one CPU, and
the ranks would inherit it: its CPU set is restored after the warm-up, and the ranks get the count
it had (DEM_BENCH_NODE_CPUS), against which they check their own. `--mpi-starter CMD` replaces
`mpiexec -n P` (a Slurm job starts its ranks with
`srun --mpi=pmi2 ...`, bench.sweep.slurm); the starter then places the ranks, possibly over
several nodes, so the CPUs of this process are not compared with P x T. `--hosts H1,...,HK`
(issue 37) runs `mpiexec -n P -hosts H1,...,HK -ppn ceil(P/K)`: Hydra places consecutive ranks on
a host, and the ranks number the blocks in row-major order, so each host holds a contiguous run of
blocks (run.json `placement`); Hydra reaches the hosts by ssh, or by the launcher its
HYDRA_LAUNCHER and HYDRA_LAUNCHER_EXEC name.
"""
import copy
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys

from bench.run.binding import NODE_CPUS_ENV, plan_binding, read_topology
from bench.run.lifeline import Interrupted, child_env, inherited_lock
from bench.run.options import forward_refusal, halo_skin_refusal, setup_mode, too_few_ranks
from bench.run.spec import rank_argv
from bench.run.threads_env import check_size, usable_cpus
from bench.run.transport import shared_cores_env, transport_env
from modes.base import ModeError, parse_mapping
from modes.decomposition import BlockGrid, DecompositionError, border_width, fit_skin
from modes.halo import compile_kernels
from modes.newton import compile_kernels as compile_newton_kernels
from modes.parallel import DEFAULT_SCHEME, SPLIT_SCHEMES


def mpiexec_path():
    here = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    return here if os.path.exists(here) else shutil.which("mpiexec")


def warm_cache(scene, mapping, args, dt):
    """Compile (and cache on disk) every kernel the ranks will run. The mode's warm-up steps a twin
    of the state (a compact piece of a large one), never the state itself (tests/modes/test_warmup.py),
    so the scene is not copied (a 1M-particle scene: 2 GB). The twin runs in one process with the
    mapping's threads and the run's mode options (bench.run.options setup_mode)."""
    twin = copy.copy(scene)
    alone = parse_mapping(f"1-1-1-1-{mapping.threads}")
    setup_mode(alone, args, twin, dt).warmup()
    compile_kernels()
    compile_newton_kernels()


def launch_mpi(args, mapping, scene, out, ts):
    """Run the ranks of `mapping` on the built scene with the run's TimeStep ts; returns the exit
    status (3: killed at the timeout)."""
    try:
        grid = BlockGrid(scene.box, (mapping.px, mapping.py, mapping.pz))
        width = border_width(float(scene.state.rbound.max()))
        grid.check_width(width)
        if args.skin is not None:
            fit_skin(grid, width, args.skin * 2.0 * float(scene.state.rbound.max()), explicit=True)
        halo_skin = getattr(args, "halo_skin", None)
        refusal = halo_skin_refusal(args.skin, halo_skin, getattr(args, "preset", None)) or \
            forward_refusal(getattr(args, "forward", "messages"), args.halo, getattr(args, "hosts", None))
        if refusal:
            raise ModeError(refusal)
        if halo_skin is not None:
            try:
                fit_skin(grid, width, halo_skin * 2.0 * float(scene.state.rbound.max()), explicit=True)
            except DecompositionError as e:
                raise ModeError(f"--halo-skin: {e}".replace("a skin", "a halo skin")) from None
    except DecompositionError as e:
        raise ModeError(str(e)) from None
    scheme = args.scheme or DEFAULT_SCHEME
    if mapping.threads > 1 and getattr(args, "newton", "auto") == "on" and scheme not in SPLIT_SCHEMES:
        raise ModeError(f"--newton on needs a scheme that sums over ranges of the pair list (partition, static, "
                        f"dynamic): {scheme} stores every pair's forces and resolves each cross-border pair on "
                        f"both of its ranks")
    starter = getattr(args, "mpi_starter", None)
    hosts = getattr(args, "hosts", None)
    if hosts and starter:
        raise ModeError("--hosts and --mpi-starter cannot be given together (the starter places the ranks)")
    hosts = hosts.split(",") if hosts else []
    if too_few_ranks(hosts, mapping):
        raise ModeError(too_few_ranks(hosts, mapping))
    elsewhere = bool(starter or hosts)  # the ranks may run on other nodes: this one's CPUs do not bound them
    too_big = None if elsewhere else check_size(str(mapping))
    if too_big:
        raise ModeError(too_big)
    if starter:
        cmd = shlex.split(starter)
        if not cmd or shutil.which(cmd[0]) is None:
            raise ModeError(f"--mpi-starter {starter!r}: {cmd[0] if cmd else 'an empty command'} not found")
    else:
        exe = mpiexec_path()
        if exe is None:
            raise ModeError("mapping with P > 1 needs mpiexec (pip install mpich, or a system MPI)")
        cmd = [exe, "-n", str(mapping.procs)]
        if hosts:  # consecutive ranks on a host: contiguous blocks (row-major) share it
            cmd += ["-hosts", ",".join(hosts), "-ppn", str(-(-mapping.procs // len(hosts)))]
        if args.pin:
            if not hosts:  # the other hosts' CPUs are not known here: each rank binds itself there
                plan_binding(read_topology(os.sched_getaffinity(0)), mapping.procs, mapping.threads)  # or one line
            cmd += ["-bind-to", f"core:{mapping.threads}"]
    mine = os.sched_getaffinity(0)
    try:
        warm_cache(scene, mapping, args, ts.dt)
    finally:
        os.sched_setaffinity(0, mine)  # what the ranks inherit (module docstring)
    env = transport_env(dict(os.environ, NUMBA_NUM_THREADS=str(mapping.threads)))
    cpus = usable_cpus()
    if not elsewhere:  # a starter or --hosts may place the ranks on other nodes
        env[NODE_CPUS_ENV] = str(len(mine))
    if not elsewhere and mapping.procs * mapping.threads > cpus:
        env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        shared_cores_env(env)
        print(f"bench: warning: {mapping.procs} ranks x {mapping.threads} threads on {cpus} usable CPUs "
              f"oversubscribes them (MPI busy-polls): fine for correctness, not for timings", file=sys.stderr)
    # each rank under its witness, which records how it ended if it ended badly (bench.run.witness)
    cmd += [sys.executable, "-m", "bench.run.witness", "--out", out, "--"]
    cmd += [sys.executable, "-m", "mpi4py", "-m", "bench.run.rank"] + _run_argv(args, out)
    cmd += ["--time-step", json.dumps(ts.as_dict())]
    sup = [sys.executable, "-m", "bench.run.supervise", "--out", out, "--procs", str(mapping.procs),
           "--timeout", str(args.timeout), "--hang", str(getattr(args, "hang_timeout", 30)), "--"] + cmd
    locks = inherited_lock()
    proc = subprocess.Popen(sup, env=child_env(env, locks[0] if locks else None), start_new_session=True,
                            pass_fds=locks)
    rc = None
    while rc is None:
        try:
            rc = proc.wait()
        except (KeyboardInterrupt, Interrupted) as e:  # to the supervisor, which stops the ranks
            try:
                proc.send_signal(e.signum if isinstance(e, Interrupted) else signal.SIGINT)
            except OSError:
                pass
    if rc == 0:
        try:
            with open(os.path.join(out, "run.json")) as fh:
                if json.load(fh).get("stable") is False:
                    return 1  # rank 0 printed the reason
        except (OSError, ValueError):
            pass
    return rc


def _run_argv(args, out):
    """The bench-run options the ranks need (bench.run.spec rank_argv: the same run, with the resolved
    output folder and the checkpoint's absolute path)."""
    return rank_argv(args, out=out, restart=os.path.abspath(args.restart) if args.restart else None)
