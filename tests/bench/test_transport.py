"""bench.run.transport: mpich's shared-memory cells sized for the messages of a step."""
import os
import subprocess
import sys

import pytest

from bench.run.launch import mpiexec_path
from bench.run.threads_env import usable_cpus
from bench.run.transport import MPICH_EAGER, OPT_OUT, SHARED_CORES, shared_cores_env, transport_env, transport_info
from tests.helpers import ROOT, bench, mpi_run, one_line_error


def test_transport_env_set_unless_the_user_chose():
    """The three variables are set on a plain environment, all left alone where the user set any of
    them or asked for the library's defaults, and read back for run.json."""
    env = transport_env({"PATH": "/bin"})
    assert {k: env[k] for k in MPICH_EAGER} == MPICH_EAGER and transport_info(env) == MPICH_EAGER
    mine = {"MPIR_CVAR_CH4_IPC_CMA_P2P_THRESHOLD": "1000000"}
    assert transport_env(dict(mine)) == mine
    assert transport_env({OPT_OUT: "library"}) == {OPT_OUT: "library"} and transport_info({OPT_OUT: "library"}) == {}
    assert {k: v for k, v in transport_env({OPT_OUT: "step"}).items() if k != OPT_OUT} == MPICH_EAGER


def test_shared_cores_env_set_unless_the_user_chose():
    """mpich's progress throttle (a usleep after 100 polls that made no progress) is added to an
    environment, a user's own value of either variable stands, and both are read back for run.json."""
    env = shared_cores_env({"PATH": "/bin"})
    assert {k: env[k] for k in SHARED_CORES} == SHARED_CORES == transport_info(env)
    assert SHARED_CORES["MPIR_CVAR_CH4_PROGRESS_THROTTLE_NO_PROGRESS_COUNT"] == "100"
    mine = {"MPIR_CVAR_CH4_PROGRESS_THROTTLE": "0"}
    assert shared_cores_env(dict(mine))["MPIR_CVAR_CH4_PROGRESS_THROTTLE"] == "0"


@pytest.mark.skipif(mpiexec_path() is None, reason="no mpiexec")
def test_ranks_on_shared_cores_get_the_progress_throttle(tmp_path):
    """4 ranks: where they outnumber the usable CPUs (2 in CI) run.json's mpi_transport holds the
    step-sized cells and the progress throttle (bench.run.transport SHARED_CORES); where each rank
    has a CPU, the cells only (timed runs keep mpich's own polling)."""
    _, steps, info = mpi_run(tmp_path, "gas", 5, "4-2-2-1-1")
    want = dict(MPICH_EAGER, **(SHARED_CORES if 4 > usable_cpus() else {}))
    assert info["mpi_transport"] == want and len(steps) == 4 * 5


def test_unknown_transport_setting_refused_in_one_line():
    """A misspelt DEM_BENCH_MPI_TRANSPORT is refused in one line naming it and its values (exit 2),
    before any work, never applied as if it were the default."""
    res = bench("scenes", env={OPT_OUT: "libary"})
    one_line_error(res, OPT_OUT, "libary", "step, library")


# rank 0 starts a message of NBYTES and sees whether it completes before rank 1 posts the receive:
# rank 1 posts it only after rank 0's verdict (an 8-byte message, eager in any setting), so a send
# that completes alone went eagerly, one that needs the receiver (rendezvous) cannot within the wait
EAGER_PROBE = """
import sys, time
import numpy as np
from mpi4py import MPI
c = MPI.COMM_WORLD
n = int(sys.argv[1]) // 8
big = np.ones(n)
if c.rank == 0:
    req = c.Isend(big, dest=1, tag=1)
    t = time.monotonic()
    done = False
    while not done and time.monotonic() - t < 2.0:
        done = req.Test()
    c.Send(np.array([1.0 if done else 0.0]), dest=1, tag=2)
    req.Wait()
    print("eager" if done else "rendezvous", flush=True)
else:
    verdict = np.zeros(1)
    c.Recv(verdict, source=0, tag=2)
    c.Recv(np.empty(n), source=0, tag=1)
"""


@pytest.mark.skipif(mpiexec_path() is None, reason="no mpiexec")
@pytest.mark.parametrize("nbytes", [82_000, 120_000])
def test_step_sized_message_leaves_at_its_start(nbytes):
    """Under the launcher's variables a message of a step's size (82 kB: the moving fields of the
    791 ghosts of 12k packed ellipsoids on 2 blocks; 120 kB, near the 128 KiB cell) is complete at
    the sender before the receiver has posted its receive (eager); with the library's defaults
    (mpich 5: eager only up to about 4 KiB) the same message waits for the receiver."""
    def probe(env):
        res = subprocess.run([mpiexec_path(), "-n", "2", sys.executable, "-c", EAGER_PROBE, str(nbytes)],
                             capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
        assert res.returncode == 0, res.stderr
        return res.stdout.strip()
    base = {k: v for k, v in os.environ.items() if k not in MPICH_EAGER and k != OPT_OUT}
    assert probe(transport_env(dict(base))) == "eager"
    assert probe(dict(base, **{OPT_OUT: "library"})) == "rendezvous"
