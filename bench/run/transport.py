"""The MPI library's shared-memory transport, sized for the messages of a step.

mpich (the PyPI wheel; ch4, POSIX shared memory) copies a message into a cell of the receiver's
queue when it is started, and the sender is done ("eager"), only up to about 4 KiB by default;
a larger one goes by rendezvous (CMA): its data moves once both ranks are inside MPI calls, and
mpich has no progress thread, so a message started at the end of a step waits, at the next
step's start, for a handshake with a rank that may still be in its own Python. The messages of a
step are larger than 4 KiB: 12k packed ellipsoids on 2 blocks send 82 kB of moving fields
(the forward exchange) and 53 kB of Newton terms each way. MPICH_EAGER makes the cells 128 KiB
and moves the rendezvous threshold there, so that messages up to about 128 KiB leave at their
start, and larger ones go by CMA as before. The cost: the queues' shared memory, 64 cells (the
default) x 128 KiB = 8 MiB a rank.

Measured with mpich 5.0.2 on 2 cores (2 ranks): the sender of an 8-64 KiB message whose receiver
comes 3 ms late waited 3.0 ms before (rendezvous), 4-14 us after; on 12k packed ellipsoids
(300 steps a run, runs alternating, two each; the rendezvous threshold then at 1 MB, which takes
these messages, all below the cell, by the same eager path) the forward exchange's wait at a step's start fell
from 40-90 us to 19-20 us and a step's commuT less its syncT (the ranks' imbalance) from
200-267 us to 177-209 us (the slower rank's steps to within the noise, 11.35 and 11.45 ms
before, 11.35 and 11.31 after).

The same variables go to the peers' runs (bench.studies.peer), which start the same mpich, so
that both sides of a comparison have the same transport, and to `bench perf --what comm`, so
that its ping-pong measures the wire the runs use. They are left alone where the user sets any
of them (their choice stands) or sets DEM_BENCH_MPI_TRANSPORT=library (the library's defaults;
`step`, or unset, is this sizing; any other value is refused in one line by the bench command);
Open MPI ignores them. run.json records them (mpi_transport).

Shared cores. With more ranks x threads than CPUs (a correctness run on a laptop: 8 ranks on 2
cores) the ranks' exchanges crawled. There SHARED_CORES turns on mpich's progress throttle
(MPIR_CVAR_CH4_PROGRESS_THROTTLE): a usleep(1) after 100 progress polls in a row that made none,
which mpich documents as holding back polling that monopolizes its shared-memory queue and keeps
other processes' packets from being enqueued. Measured with mpich 5.0.2 on 2 cores, the gas
(2500 spheres) at --skin 0 --halo-skin 0, 300-600 steps, median step of the slowest rank, runs
alternating: 4 ranks 7.99, 7.97, 10.74, 11.01 ms spinning, 0.92, 0.79, 1.11, 0.87 ms throttled;
8 ranks (2x2x2, 6-message halo) 39.9, 40.5 ms spinning, 7.6 and 7.7 ms throttled (100 or 10
polls; 10.1 ms after 1000). What it does not do: a rank blocked in one Recv, Waitall or
allreduce for a partner still busy computing keeps using its CPU (a 4-rank probe on 2 cores,
two ranks computing and two waiting: each at half a CPU, throttled or not), so the gain is the
queue's, not a yielded core. A user's own value of either variable stands (the throttle is
not part of the step sizing, so DEM_BENCH_MPI_TRANSPORT=library does not turn it off); run.json
records them (mpi_transport).
"""
import os

CELL = 131072
MPICH_EAGER = {
    "MPIR_CVAR_CH4_SHM_POSIX_IQUEUE_CELL_SIZE": str(CELL),
    "MPIR_CVAR_CH4_PACK_BUFFER_SIZE": str(CELL),      # mpich refuses a pack buffer below the cell
    "MPIR_CVAR_CH4_IPC_CMA_P2P_THRESHOLD": str(CELL),
}
SHARED_CORES = {
    "MPIR_CVAR_CH4_PROGRESS_THROTTLE": "1",
    "MPIR_CVAR_CH4_PROGRESS_THROTTLE_NO_PROGRESS_COUNT": "100",
}
OPT_OUT = "DEM_BENCH_MPI_TRANSPORT"
SETTINGS = ("step", "library")   # DEM_BENCH_MPI_TRANSPORT: sized for the step (default), or mpich's own


def transport_setting(environ=None):
    """DEM_BENCH_MPI_TRANSPORT of environ (default os.environ): "step" when unset or empty, else its
    value; ValueError naming the variable and its values for anything else."""
    environ = os.environ if environ is None else environ
    value = environ.get(OPT_OUT, "").strip().lower() or "step"
    if value not in SETTINGS:
        raise ValueError(f"{OPT_OUT}={environ[OPT_OUT]!r}: expected one of {', '.join(SETTINGS)}")
    return value


def transport_env(env):
    """env (a dict, changed in place) with MPICH_EAGER unless the user set any of its variables or
    DEM_BENCH_MPI_TRANSPORT=library; returns env."""
    if transport_setting(env) == "library" or any(k in env for k in MPICH_EAGER):
        return env
    env.update(MPICH_EAGER)
    return env


def shared_cores_env(env):
    """env (a dict, changed in place) with SHARED_CORES where the user set none of them; returns
    env. For more ranks x threads than CPUs only (module docstring)."""
    for k, v in SHARED_CORES.items():
        env.setdefault(k, v)
    return env


def transport_info(environ=None):
    """The transport variables of this process (run.json's mpi_transport): {} where none is set."""
    environ = os.environ if environ is None else environ
    return {k: environ[k] for k in (*MPICH_EAGER, *SHARED_CORES) if k in environ}
