"""Heartbeats of MPI ranks (issue 15): each rank rewrites DIR/.ranks/rank<r>.json every BEAT_S
seconds from a thread of its own, with its pid, host and last finished step; the supervisor
(bench.run.supervise) reads them to name a rank that died and to spot one that stopped.

A rank's thread runs while the rank waits in MPI (mpi4py releases the GIL there), but not while
the rank is stopped, spins in its own code or holds the GIL in a kernel: a rank whose heartbeat
is older than the hang limit while a peer's is fresh is taken as hung (its peers wait for it).
A step whose kernels alone take longer than the limit on one rank while the others wait would
read the same: the limit (`bench run --hang-timeout`, default 30 s) is far above a step of the
scenes this harness runs.
"""
import json
import os
import socket
import threading
import time

BEAT_S = 1.0


def ranks_dir(out):
    return os.path.join(out, ".ranks")


def beat_path(out, rank):
    return os.path.join(ranks_dir(out), f"rank{rank}.json")


class Heartbeat:
    """The heartbeat thread of one rank; set `.step` from the run loop, `.stop()` at the end."""

    def __init__(self, out, rank):
        self.path = beat_path(out, rank)
        self.info = {"rank": rank, "pid": os.getpid(), "host": socket.gethostname()}
        self.step = 0
        self.phase = "starting"
        os.makedirs(ranks_dir(out), exist_ok=True)
        self._stop = threading.Event()
        self._write()
        self._thread = threading.Thread(target=self._run, name="heartbeat", daemon=True)
        self._thread.start()

    def _write(self):
        tmp = f"{self.path}.{os.getpid()}.tmp"
        try:
            with open(tmp, "w") as fh:
                json.dump(dict(self.info, step=self.step, phase=self.phase, t=time.time()), fh)
            os.replace(tmp, self.path)
        except OSError:  # a full disk must not kill the rank: its records say so
            pass

    def _run(self):
        while not self._stop.wait(BEAT_S):
            self._write()

    def stop(self, phase="ended"):
        self.phase = phase
        self._stop.set()
        self._write()


def read_beats(out):
    """{rank: (age [s] of its last heartbeat, its record)} of the ranks that have written one."""
    beats = {}
    d = ranks_dir(out)
    try:
        names = os.listdir(d)
    except OSError:
        return beats
    now = time.time()
    for name in names:
        if not (name.startswith("rank") and name.endswith(".json")):
            continue
        path = os.path.join(d, name)
        try:
            age = now - os.stat(path).st_mtime
            with open(path) as fh:
                rec = json.load(fh)
        except (OSError, ValueError):
            continue
        beats[int(rec.get("rank", name[4:-5]))] = (age, rec)
    return beats
