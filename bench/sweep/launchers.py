"""Launchers: how the points of a sweep are started, as a registry of small named classes.

- `local` runs every repeat of a point here, one after another, as a child process
  `python -m bench run ...` (which starts mpiexec itself for P > 1), with cmd.txt, stdout.txt,
  stderr.txt and status.json in the repeat's folder.
- `slurm` turns the sweep into Slurm jobs (bench.sweep.slurm: a prepare job, each point a job
  array over its repeats, a collect job; srun --mpi=pmi2 or Hydra for the ranks) after checking
  everything that can be checked before a job runs, and submits them when sbatch is on PATH
  (`--no-submit`: only write them; DIR/submit.sh submits them later). `bench sweep --status DIR`,
  `--cancel DIR` and `bench collect DIR` follow the jobs.

Every launcher has `dry_run(points, out, repeats)` (print each command and its environment, run
nothing). A launcher with `batch = False` runs points one at a time (`run_point`); a batch launcher
hands them all to a scheduler (`submit(points, out, repeats, resume)`) and returns. A new one is
a class with those methods and `from_args(args)` (its options from `bench sweep`'s) under
`@launcher("name")`.
"""
import os
import shlex
import signal
import subprocess
import sys
import time

from bench.run.lifeline import Interrupted, child_env
from bench.run.records import finalize_run, read_json_file, write_json
from bench.sweep.points import point_env
from bench.sweep.status import judge

LAUNCHERS = {}
TICK_S = 1.0  # seconds between progress ticks while a point runs


def launcher(name):
    """Class decorator: register a launcher under `name` (the --launcher choice)."""
    def put(cls):
        cls.name = name
        LAUNCHERS[name] = cls
        return cls
    return put


@launcher("local")
class Local:
    """Each repeat of a point as a child process here, one at a time."""
    batch = False

    def __init__(self, timeout):
        self.timeout = timeout

    @classmethod
    def from_args(cls, args):
        return cls(args.timeout)

    def command(self, point, rep_dir):
        return [sys.executable, "-m", "bench"] + point.run_args(rep_dir, self.timeout)

    def dry_run(self, points, out, repeats):
        for p in points:
            env = " ".join(f"{k}={v}" for k, v in point_env(p).items())
            for r in range(repeats):
                print(f"{env} {shlex.join(self.command(p, os.path.join(out, p.key, f'rep{r}')))}")
        return 0

    def run_point(self, point, rep_dir, env, lock_fd=None, tick=None):
        """Run one repeat of a point in rep_dir; write cmd.txt, stdout.txt, stderr.txt, status.json;
        returns the status {"status", "reason"}.

        The child `bench run` runs in a session of its own (a Ctrl-C at the terminal reaches the
        sweep alone, which forwards it once), dies with the sweep (bench.run.lifeline) and holds
        the sweep's lock (lock_fd) while it lives. Interrupted here (SIGINT, SIGTERM, SIGHUP), the
        signal goes to the child, whose end is waited for and recorded before it is raised again.
        A child that ended without a final run.json status (killed) gets one (finalize_run).
        tick(): called about every TICK_S seconds while the child runs (the sweep's progress)."""
        os.makedirs(rep_dir, exist_ok=True)
        cmd = self.command(point, rep_dir)
        timeout = self.timeout
        with open(os.path.join(rep_dir, "cmd.txt"), "w") as fh:
            fh.write(shlex.join(cmd) + "\n")
        for stale in ("status.json", "run.json"):
            if os.path.exists(os.path.join(rep_dir, stale)):
                os.remove(os.path.join(rep_dir, stale))
        stopped = None
        with open(os.path.join(rep_dir, "stdout.txt"), "w") as so, \
                open(os.path.join(rep_dir, "stderr.txt"), "w") as se:
            fds = (lock_fd,) if lock_fd is not None else ()
            proc = subprocess.Popen(cmd, stdout=so, stderr=se, env=child_env(env, lock_fd), start_new_session=True,
                                    pass_fds=fds)
            # bench run stops its own MPI ranks at `timeout`; this outer limit catches a stuck start
            limit = timeout + min(120, timeout)
            rc = None
            deadline = time.monotonic() + limit
            while rc is None:
                try:
                    rc = proc.wait(timeout=min(TICK_S, max(0.0, deadline - time.monotonic())))
                except subprocess.TimeoutExpired:
                    if time.monotonic() < deadline:
                        if tick is not None:
                            tick()
                        continue
                    _end(proc, signal.SIGTERM)
                    rc = None
                    break
                except (KeyboardInterrupt, Interrupted) as e:
                    stopped = e
                    _end(proc, e.signum if isinstance(e, Interrupted) else signal.SIGINT)
                    rc = proc.returncode
        status = judge(rep_dir, rc, timeout)
        run = read_json_file(os.path.join(rep_dir, "run.json")) or {}
        if run.get("status") == "running" or (not run and rc != 0):
            finalize_run(rep_dir, int(point.mapping.split("-")[0]), status["status"], status["reason"])
        write_json(os.path.join(rep_dir, "status.json"), status)
        if stopped is not None:
            raise stopped
        return status


def _end(proc, sig, grace=20.0):
    """Send sig to a child `bench run` (which stops what it started and marks its records), wait
    grace seconds for it, then kill its session (SIGKILL)."""
    try:
        proc.send_signal(sig)
    except OSError:
        pass
    try:
        proc.wait(timeout=grace)
        return
    except subprocess.TimeoutExpired:
        pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except OSError:
        pass
    proc.wait()


@launcher("slurm")
class Slurm:
    """The sweep as Slurm jobs (bench.sweep.slurm); `bench collect` gathers their results."""
    batch = True

    def __init__(self, timeout, options=None, submit=True):
        self.timeout = timeout
        self.options = dict(options or {})
        self.submit_now = submit

    @classmethod
    def from_args(cls, args):
        return cls(args.timeout, getattr(args, "slurm", None), submit=not getattr(args, "no_submit", False))

    def dry_run(self, points, out, repeats):
        from bench.sweep.slurm import generate
        return generate(points, out, repeats, False, self.options, self.timeout, dry_run=True)

    def submit(self, points, out, repeats, resume):
        from bench.sweep.slurm import generate
        return generate(points, out, repeats, resume, self.options, self.timeout, submit=self.submit_now)
