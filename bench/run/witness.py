"""The witness of one MPI rank (issue 15): `python -m bench.run.witness --out DIR -- CMD...` is what
the starter (mpiexec, srun) starts for each rank; it runs the rank (CMD) as its child, waits for
it, and when the rank ends badly (a signal, or a non-zero exit status) writes how, with the
rank's pid, to DIR/.ranks/end.<pid>.json before it ends the same way itself.

Why: when a rank dies, the starter kills the others at once (Hydra's proxy, Slurm's
--kill-on-bad-exit), all by SIGKILL, and its report cannot be trusted to name the first: Hydra's
banner names the first process of its proxy with a bad status, and that is rank 0 whenever the
proxy has reaped it (killed by the clean-up) before reporting, a race seen in CI. A witness
killed by the starter's clean-up writes nothing (SIGKILL), and its rank follows it
(PR_SET_PDEATHSIG): only the rank that died first of its own leaves a record, which
bench.run.supervise reads to name it (the earliest by its time, should ranks on several hosts
leave one each).

The witness forwards SIGINT, SIGTERM, SIGHUP, SIGUSR1 and SIGUSR2 to the rank (the starter sends
them to the process it started), so that an interrupted rank still keeps its records. It dies
with its own parent (PR_SET_PDEATHSIG SIGKILL), and the rank with it (the same request, made for
the rank between fork and exec). It imports nothing heavy: it waits, idle, beside the rank.
"""
import json
import os
import signal
import sys
import time

from bench.run.heartbeat import ranks_dir
from bench.run.lifeline import PR_SET_PDEATHSIG, _prctl

FORWARDED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2)
# where each starter says which rank a process is (a rank that died before its first heartbeat)
RANK_ENV = ("PMI_RANK", "SLURM_PROCID", "OMPI_COMM_WORLD_RANK", "PMIX_RANK")


def end_path(out, pid):
    return os.path.join(ranks_dir(out), f"end.{pid}.json")


def clear_ends(out):
    """Remove the records of an earlier run in the same folder (a resumed or repeated point)."""
    d = ranks_dir(out)
    try:
        names = os.listdir(d)
    except OSError:
        return
    for name in names:
        if name.startswith("end."):
            try:
                os.unlink(os.path.join(d, name))
            except OSError:
                pass


def read_ends(out):
    """The witnesses' records of ranks that ended badly: [{pid, rank (from the starter's
    environment, or None), status (raw wait status, waitpid(2)), t [s since the epoch]}], earliest
    first."""
    d = ranks_dir(out)
    try:
        names = [n for n in os.listdir(d) if n.startswith("end.") and n.endswith(".json")]
    except OSError:
        return []
    ends = []
    for name in names:
        try:
            with open(os.path.join(d, name)) as fh:
                ends.append(json.load(fh))
        except (OSError, ValueError):
            continue
    return sorted(ends, key=lambda e: (e.get("t", 0.0), e.get("rank") if e.get("rank") is not None else 1 << 30))


def describe_status(raw):
    """A raw wait status in words: 9 -> 'Killed (signal 9)', 139 -> 'Segmentation fault (signal
    11, core dumped)', 768 -> 'exit code 3'."""
    if os.WIFSIGNALED(raw):
        sig = os.WTERMSIG(raw)
        try:
            name = signal.strsignal(sig) or "signal"
        except ValueError:
            name = "signal"
        return f"{name} (signal {sig}{', core dumped' if os.WCOREDUMP(raw) else ''})"
    if os.WIFEXITED(raw):
        return f"exit code {os.WEXITSTATUS(raw)}"
    return f"wait status {raw}"


def _rank_from_env():
    for name in RANK_ENV:
        v = os.environ.get(name, "")
        if v.isdigit():
            return int(v)
    return None


def _record(out, pid, raw):
    os.makedirs(ranks_dir(out), exist_ok=True)
    path = end_path(out, pid)
    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w") as fh:
            json.dump({"pid": pid, "rank": _rank_from_env(), "status": raw, "t": time.time()}, fh)
        os.replace(tmp, path)
    except OSError:  # a full disk: the supervisor falls back on the starter's report
        pass


def _end_like(raw):
    """End this process as the rank ended (the starter then reports the same status)."""
    sys.stdout.flush()
    sys.stderr.flush()
    if os.WIFSIGNALED(raw):
        sig = os.WTERMSIG(raw)
        if sig not in (signal.SIGKILL, signal.SIGSTOP):  # those two cannot be caught, hence not reset
            signal.signal(sig, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [sig])
        os.kill(os.getpid(), sig)
        os._exit(128 + sig)  # not reached unless the signal is ignored by default
    os._exit(os.WEXITSTATUS(raw) if os.WIFEXITED(raw) else 1)


def main(argv):
    if len(argv) < 4 or argv[0] != "--out" or argv[2] != "--":
        print("bench: error: usage: python -m bench.run.witness --out DIR -- CMD...", file=sys.stderr)
        return 2
    out, cmd = argv[1], argv[3:]
    _prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL))
    got = []
    for s in FORWARDED:  # until the child exists, a signal is kept and sent on once it does
        signal.signal(s, lambda signum, frame: got.append(signum))
    pid = os.fork()
    if pid == 0:
        for s in FORWARDED:
            signal.signal(s, signal.SIG_DFL)
        _prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL))  # kept across exec: the rank dies with its witness
        try:
            os.execvp(cmd[0], cmd)
        except OSError as e:
            print(f"bench: error: cannot start {cmd[0]}: {e.strerror}", file=sys.stderr, flush=True)
            os._exit(127)

    def forward(signum, frame):
        try:
            os.kill(pid, signum)
        except OSError:
            pass
    for s in FORWARDED:
        signal.signal(s, forward)
    for s in got:
        forward(s, None)
    _, raw = os.waitpid(pid, 0)  # retried after each forwarded signal (PEP 475)
    if raw != 0:
        _record(out, pid, raw)
    _end_like(raw)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
