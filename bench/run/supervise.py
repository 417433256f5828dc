"""The supervisor of an MPI run (issue 15): `python -m bench.run.supervise --out DIR --procs P
--timeout S --hang S -- CMD...`, started by bench.run.launch in a session of its own, runs CMD
(mpiexec or the --mpi-starter with the rank program) and owns every process below it.

- It dies with `bench run` (bench.run.lifeline: PR_SET_PDEATHSIG) and is a subreaper, so what its
  children leave behind is re-parented to it; CMD gets SIGTERM when the supervisor dies.
- SIGINT, SIGTERM and SIGHUP are forwarded to CMD (mpiexec and srun forward them to the ranks);
  what is left GRACE_S seconds later is killed (SIGKILL), the supervisor's descendants included.
- Past --timeout seconds the run is stopped the same way (exit 3).
- A rank whose heartbeat (bench.run.heartbeat) is older than --hang seconds while a peer's is
  fresh has stopped: the run is stopped and the rank named (exit 5).
- A rank that dies is named from its witness's record (bench.run.witness: the rank's pid and its
  wait status, written by its parent, so exact even when the starter kills the other ranks at
  once and reports one of those) and the ranks' heartbeats (exit 5); the supervisor stops the
  others as soon as a record appears. Without a record (a starter that does not run the
  witness), from the starter's report (Hydra: `PID n RUNNING AT host`, `EXIT STRING: Killed
  (signal 9)`; srun: `task r: Killed`). Hydra's multi-line banner is not relayed, since the
  supervisor says the same in one line. A rank that said why in its own `bench: error:` line
  before it ended (e.g. a rank started alone under `srun --mpi=none`) keeps that line as the
  reason.
Whenever the run ends other than by itself, the records are kept and marked: the ranks' step rows
merged into steps.csv (bench.run.records.finalize_run) and run.json's status set (`timeout`,
`failed`, `interrupted`) with the one-line reason, which is also printed as `bench: error: ...`.
"""
import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time

from bench.run.heartbeat import read_beats
from bench.run.lifeline import PR_SET_PDEATHSIG, _prctl, become_subreaper, die_with_parent
from bench.run.witness import clear_ends, describe_status, read_ends

GRACE_S = 5.0
POLL_S = 0.2
FRESH_S = 3.0  # a heartbeat younger than this is fresh (ranks beat every second)
# Hydra's banner around a rank's bad end, and the MPI_Abort lines of the ranks it then stops
NOISE = re.compile(r"^(=+|=   .*|YOUR APPLICATION TERMINATED.*|This typically refers to a problem.*|"
                   r"Please see the FAQ page.*|Abort\(\d+\) on node \d+.*|\s*)$")
HYDRA_PID = re.compile(r"PID (\d+) RUNNING AT (\S+)")
HYDRA_EXIT = re.compile(r"EXIT STRING: (.*)|EXIT CODE: (\d+)")
SRUN_TASK = re.compile(r"srun: error: (\S+): tasks? ([\d,-]+): (.*)")


class Relay(threading.Thread):
    """Copies one of CMD's output streams to ours (`to`) line by line, keeping back Hydra's banner
    (it prints it on stdout) and noting what it says about the rank that ended badly, and the last
    `bench: error:` line of a rank."""

    def __init__(self, stream, to):
        super().__init__(name="relay", daemon=True)
        self.stream = stream
        self.to = to
        self.dead_pid = None
        self.dead_host = None
        self.dead_how = None
        self.srun_task = None
        self.bench_error = None

    def run(self):
        for raw in iter(self.stream.readline, b""):
            line = raw.decode("utf-8", "replace").rstrip("\n")
            m = HYDRA_PID.search(line)
            if m and self.dead_pid is None:
                self.dead_pid, self.dead_host = int(m.group(1)), m.group(2)
            m = HYDRA_EXIT.search(line)
            if m and line.startswith(("=", "YOUR")):
                how = m.group(1) or f"exit code {m.group(2)}"
                if self.dead_how is None or m.group(1):
                    self.dead_how = how
            m = SRUN_TASK.search(line)
            if m and self.srun_task is None:
                self.srun_task = (m.group(1), m.group(2), m.group(3))
            if line.startswith("bench: error:"):
                self.bench_error = line
            if NOISE.match(line):
                continue
            self.to.write(line + "\n")
            self.to.flush()


def _descendants():
    try:
        import psutil
        return psutil.Process().children(recursive=True)
    except Exception:  # noqa: BLE001  (psutil missing or the process list unreadable)
        return []


def _signal_local_ranks(beats, sig):
    """Send sig to the ranks of this host named in their heartbeats (SIGCONT wakes a stopped one so
    that it can take SIGTERM)."""
    import socket
    host = socket.gethostname()
    for _, rec in beats.values():
        if rec.get("host") == host and rec.get("pid"):
            try:
                os.kill(int(rec["pid"]), sig)
            except OSError:
                pass


def stop(proc, beats):
    """SIGTERM to CMD (forwarded to the ranks), SIGCONT to stopped ranks here, SIGKILL to every
    descendant still alive GRACE_S seconds later."""
    try:
        proc.send_signal(signal.SIGTERM)
    except OSError:
        pass
    _signal_local_ranks(beats, signal.SIGCONT)
    try:
        proc.wait(timeout=GRACE_S)
    except subprocess.TimeoutExpired:
        pass
    reap()
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def reap():
    """Kill (SIGKILL) and collect every descendant still alive (orphans re-parented to us)."""
    left = _descendants()
    for p in left:
        try:
            p.kill()
        except Exception:  # noqa: BLE001  (already gone)
            pass
    for p in left:
        try:
            p.wait(timeout=5)
        except Exception:  # noqa: BLE001
            pass


def hung_ranks(beats, procs, limit):
    """Ranks whose heartbeat is older than `limit` while some peer's is fresh: [(rank, age, record)]."""
    if not beats or limit <= 0:
        return []
    fresh = any(age < FRESH_S for age, _ in beats.values())
    late = [(r, age, rec) for r, (age, rec) in sorted(beats.items()) if age > limit and rec.get("phase") != "ended"]
    return late if fresh else []


# how long a SIGTERM waits for the launcher's end to show before it is taken as a plain SIGTERM
LAUNCHER_END_S = 2.0


def launcher_ended(launcher, wait=LAUNCHER_END_S):
    """Whether `launcher` (the pid that started this process) has ended or is ending, checked after
    a SIGTERM: this process is no longer its child, or its /proc entry is gone or a zombie. The
    parent-death signal (PR_SET_PDEATHSIG) comes when the *thread* that started this process
    exits: under SIGKILL a launcher's threads end one by one, and while some live this process is
    re-parented to one of them, whose pid (getppid) is still the launcher's. So where neither
    shows yet, it looks again every 10 ms for up to `wait` seconds; a launcher that lives on (it
    forwarded the signal) is then alive: False. (CI once read "interrupted by SIGTERM" for a killed
    launcher: the check came before the launcher's last thread had gone.) The supervisor stops the
    ranks first and waits here only for what is left of the 2 s since the signal."""
    end = time.monotonic() + wait
    while True:
        if os.getppid() != launcher:
            return True
        try:
            with open(f"/proc/{launcher}/stat") as fh:
                state = fh.read().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            return True
        if state in ("Z", "X", "x"):
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.01)


def rank_of_pid(beats, pid):
    for r, (_, rec) in beats.items():
        if rec.get("pid") == pid:
            return r, rec
    return None, None


def main(argv):
    p = argparse.ArgumentParser(prog="bench.run.supervise")
    p.add_argument("--out", required=True)
    p.add_argument("--procs", type=int, required=True)
    p.add_argument("--timeout", type=float, required=True)
    p.add_argument("--hang", type=float, default=30.0)
    p.add_argument("cmd", nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    cmd = args.cmd[1:] if args.cmd and args.cmd[0] == "--" else args.cmd
    launcher = os.getppid()  # bench run: when it dies, the SIGTERM below is its death signal
    die_with_parent(signal.SIGTERM)
    become_subreaper()
    got = []  # (signal, when it came [monotonic s])

    def on_signal(signum, frame):
        got.append((signum, time.monotonic()))
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, on_signal)

    def child_setup():  # single-threaded here: CMD gets SIGTERM when the supervisor dies
        _prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
    clear_ends(args.out)  # an earlier run's ranks in this folder (a resumed point) are not these
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=child_setup)
    relays = [Relay(proc.stdout, sys.stdout), Relay(proc.stderr, sys.stderr)]
    for r in relays:
        r.start()
    start = time.monotonic()
    verdict = None  # (status, reason, exit status)
    ends = []  # witnesses' records of ranks that ended badly, before the supervisor stopped any
    while True:
        try:
            rc = proc.wait(timeout=POLL_S)
            break
        except subprocess.TimeoutExpired:
            pass
        beats = read_beats(args.out)
        if got:
            # the ranks first: a Slurm job has KillWait seconds (5 in the tests' cluster) before every
            # process of it is killed, and the records are kept only after the ranks stopped
            sig, when = got[0]
            stop(proc, beats)
            name = signal.Signals(sig).name
            if sig == signal.SIGTERM and launcher_ended(launcher, max(0.0, LAUNCHER_END_S - (time.monotonic()
                                                                                               - when))):
                name = f"the end of its launcher (bench run, pid {launcher}, killed)"
            step = max((rec.get("step", 0) for _, rec in beats.values()), default=0)
            verdict = ("interrupted", f"interrupted by {name} near step {step}: stopped the {args.procs} ranks; "
                                      f"the records written are kept in {args.out}", 128 + sig)
            rc = proc.returncode
            break
        elif time.monotonic() - start > args.timeout:
            verdict = ("timeout", f"{args.procs} MPI ranks did not finish within {args.timeout:g} s; killed", 3)
        else:
            ends = read_ends(args.out)  # named below, with the rest of what the starter said
            late = [] if ends else hung_ranks(beats, args.procs, args.hang)
            if late:
                r, age, rec = late[0]
                verdict = ("failed", f"rank {r} (pid {rec.get('pid')} on {rec.get('host')}) stopped responding at "
                                     f"step {rec.get('step', 0)}: no heartbeat for {age:.0f} s while its peers wait "
                                     f"for it; stopped the {args.procs} ranks, records kept in {args.out}", 5)
        if verdict is not None or ends:
            stop(proc, beats)
            rc = proc.returncode
            break
    reap()
    for r in relays:
        r.join(timeout=2)
    relay = Relay(None, None)  # what the two streams said, together
    for r in relays:
        for key in ("dead_pid", "dead_host", "dead_how", "srun_task", "bench_error"):
            if getattr(r, key) is not None:
                setattr(relay, key, getattr(r, key))
    beats = read_beats(args.out)
    if verdict is None and not ends and rc != 0:  # ended by itself: the witnesses wrote before the end
        ends = read_ends(args.out)
    if verdict is None and (rc != 0 or ends) and relay.bench_error is None:  # a rank's own line wins
        if ends:
            first = ends[0]
            r, rec = rank_of_pid(beats, first["pid"])
            r = first.get("rank") if r is None else r
            who = f"rank {r}" if r is not None else "a rank"
            where = f" on {rec['host']}" if rec and rec.get("host") else ""
            at = f" at step {rec.get('step', 0)}" if rec else " while starting"
            verdict = ("failed", f"{who} (pid {first['pid']}{where}) died{at}: {describe_status(first['status'])}; "
                                 f"the other ranks were stopped, records kept in {args.out}", 5)
        elif relay.dead_pid is not None:
            r, rec = rank_of_pid(beats, relay.dead_pid)
            who = f"rank {r} (pid {relay.dead_pid} on {relay.dead_host})" if r is not None else \
                f"a rank (pid {relay.dead_pid} on {relay.dead_host})"
            at = f" at step {rec.get('step', 0)}" if rec else ""
            how = relay.dead_how or f"exit status {rc}"
            verdict = ("failed", f"{who} died{at}: {how}; the other ranks were stopped, records kept in {args.out}", 5)
        elif relay.srun_task is not None:
            node, tasks, how = relay.srun_task
            verdict = ("failed", f"rank {tasks} on {node} died: {how}; the other ranks were stopped, records kept in "
                                 f"{args.out}", 5)
        else:
            verdict = ("failed", f"the ranks ended with exit status {rc} without a word; records kept in {args.out}",
                       rc if rc > 0 else 5)
    from bench.run.records import finalize_run
    if verdict is not None:
        status, reason, code = verdict
        finalize_run(args.out, args.procs, status, reason)
        print(f"bench: error: {reason}", file=sys.stderr, flush=True)
        return code
    if rc != 0 or ends:  # a rank said why in its own line: keep its records and its reason
        finalize_run(args.out, args.procs, "failed", relay.bench_error[len("bench: error: "):])
    return rc if rc or not ends else 5


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
