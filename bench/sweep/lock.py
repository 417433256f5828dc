"""One writer a sweep folder (issue 15): `bench sweep` and `bench collect` hold an exclusive
flock on DIR/.lock for as long as they write there; a second writer gets one line and exit 2.

The lock's file descriptor is inherited by the sweep's `bench run` children and their supervisors
(bench.run.lifeline: BENCH_LOCK_FD and pass_fds), and an flock belongs to the open file, so the
folder stays locked while any process of the sweep lives: a `--resume` started while a killed
sweep's runs are still ending is refused rather than mixing its files with theirs. The file holds
the holder's pid, host, start time and command, for the message. When that holder is gone but
the lock is still held (the processes of a killed sweep are ending: they stop within seconds,
bench.run.lifeline), the new writer waits for them up to WAIT_DEAD_S seconds before it gives up.
"""
import fcntl
import json
import os
import socket
import sys
import time

from modes.base import ModeError

WAIT_DEAD_S = 60.0


class SweepLock:
    """with SweepLock(DIR) as lock: ... (lock.fd: the descriptor children inherit)."""

    def __init__(self, directory):
        self.path = os.path.join(directory, ".lock")
        self.fd = None

    def __enter__(self):
        self.created = not os.path.exists(self.path)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = None
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError:
                info = _holder(fd)
                if not _gone(info):
                    os.close(fd)
                    raise ModeError(f"{os.path.dirname(self.path) or '.'} is in use by another sweep or collect "
                                    f"({_describe(info)}); wait for it to end, or write to another --out") from None
                if deadline is None:
                    deadline = time.monotonic() + WAIT_DEAD_S
                    print(f"bench: note: waiting for the processes of a stopped sweep ({_describe(info)}) to end",
                          file=sys.stderr, flush=True)
                elif time.monotonic() > deadline:
                    os.close(fd)
                    raise ModeError(f"{os.path.dirname(self.path) or '.'} is still locked {WAIT_DEAD_S:.0f} s after "
                                    f"its sweep ({_describe(info)}) ended: some of its processes still run") from None
                time.sleep(0.2)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                 "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                                 "command": " ".join(sys.argv)}).encode())
        os.set_inheritable(fd, True)
        self.fd = fd
        return self

    def __exit__(self, kind, value, tb):
        # close only: an explicit LOCK_UN would also free it for the children still holding it
        if self.fd is not None and self.created and kind is not None and issubclass(kind, ValueError):
            try:  # refused input (ModeError, SceneError): leave the folder as it was
                os.remove(self.path)
            except OSError:
                pass
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        return False


def _holder(fd):
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        info = json.loads(os.read(fd, 4096).decode() or "{}")
        return info if isinstance(info, dict) else {}
    except (OSError, ValueError):
        return {}


def _describe(info):
    if not info:
        return "holder unknown"
    return f"pid {info.get('pid')} on {info.get('host')} since {info.get('since')}"


def _gone(info):
    """Whether the recorded holder, on this host, no longer runs (its children may still)."""
    if not info.get("pid") or info.get("host") != socket.gethostname():
        return False
    from bench.run.records import process_alive
    return not process_alive(info["pid"])
