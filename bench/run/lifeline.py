"""A run owns its processes (issue 15): signals reach every process it started, and nothing it
started outlives it.

The chain of a sweep is `bench sweep` -> `bench run` (one repeat) -> `bench.run.supervise` (P > 1)
-> mpiexec (or the --mpi-starter) -> the ranks. Each link dies with the one above it:
- a launcher marks its child with BENCH_PARENT_PID; the child then asks Linux for a signal when its
  parent dies (prctl PR_SET_PDEATHSIG, kept across exec) and checks that the parent is still the
  one it was started by (the parent may have died before the request);
- `bench run` and `bench sweep` turn SIGTERM and SIGHUP into `Interrupted` (SIGINT is Python's
  KeyboardInterrupt), so that they stop their children, keep and mark their records, and exit
  128 + the signal number;
- the supervisor is a subreaper (PR_SET_CHILD_SUBREAPER): a process whose parent dies below it is
  re-parented to it rather than to init, so it can still find and kill it at the end.
On systems without prctl (not Linux) the requests are no-ops and the signal handlers remain.
"""
import contextlib
import ctypes
import os
import signal
import threading

PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36
PARENT_ENV = "BENCH_PARENT_PID"
LOCK_ENV = "BENCH_LOCK_FD"


class Interrupted(Exception):
    """A run or sweep stopped by a signal; signum: its number."""

    def __init__(self, signum):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


def _prctl(option, arg):
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(option, ctypes.c_ulong(arg), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent(sig=signal.SIGTERM):
    """When started by a launcher (BENCH_PARENT_PID set): receive `sig` when the parent dies, and exit
    at once (128 + sig) when it already has. Returns True when the request was made."""
    want = os.environ.get(PARENT_ENV)
    if not want:
        return False
    ok = _prctl(PR_SET_PDEATHSIG, int(sig))
    if str(os.getppid()) != want:  # the parent died before the request: nobody would tell us
        os._exit(128 + int(sig))
    return ok


def child_env(env=None, lock_fd=None):
    """The environment of a child that should die with this process (and hold the sweep's lock)."""
    env = dict(os.environ if env is None else env, **{PARENT_ENV: str(os.getpid())})
    if lock_fd is not None:
        env[LOCK_ENV] = str(lock_fd)
    else:
        env.pop(LOCK_ENV, None)
    return env


def inherited_lock():
    """The sweep lock's file descriptor this process inherited (BENCH_LOCK_FD), to pass on to its own
    children so that the lock is held while any of them lives; () when none."""
    fd = os.environ.get(LOCK_ENV)
    if fd and fd.isdigit():
        try:
            os.fstat(int(fd))
            return (int(fd),)
        except OSError:
            pass
    return ()


def become_subreaper():
    """Orphaned descendants are re-parented to this process (Linux); True when granted."""
    return _prctl(PR_SET_CHILD_SUBREAPER, 1)


def raise_on_signals(signals=(signal.SIGTERM, signal.SIGHUP)):
    """Turn these signals into Interrupted in the main thread (SIGINT stays KeyboardInterrupt)."""
    def handler(signum, frame):
        raise Interrupted(signum)
    for s in signals:
        signal.signal(s, handler)


@contextlib.contextmanager
def signals_deferred(signals=(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
    """Hold these signals back for the block, then deliver them, so that a record and its bookkeeping
    (rows appended and the last step counted) are never split by an interrupt. A mask would not do:
    any other thread (numba's workers) may take the signal and CPython then runs the handler in the
    main thread at its next bytecode. Outside the main thread (no handlers there) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = []
    old = {}
    try:
        for s in signals:
            old[s] = signal.signal(s, lambda signum, frame: held.append(signum))
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for s in dict.fromkeys(held):
            signal.raise_signal(s)  # now, to its own handler


def exit_status(exc):
    """The exit status of a process stopped by exc (Interrupted or KeyboardInterrupt): 128 + signal."""
    return 128 + (exc.signum if isinstance(exc, Interrupted) else int(signal.SIGINT))


def signal_name(exc):
    return signal.Signals(exc.signum).name if isinstance(exc, Interrupted) else "SIGINT"
