"""Launchers: how the points of a sweep are started, as a registry of small named classes.

- `local` runs every repeat of a point here, one after another, as a child process
  `python -m bench run ...` (which starts mpiexec itself for P > 1), with cmd.txt, stdout.txt,
  stderr.txt and status.json in the repeat's folder.
- `slurm` writes DIR/<point>/job.sbatch per point (srun with --ntasks, --cpus-per-task,
  --cpu-bind and the thread variables; P > 1 points run the MPI rank program
  `python -m mpi4py -m bench.run.rank` directly under srun) and DIR/submit.sh that submits them
  all. Each job first makes a zero-step serial run, which builds the scene's cache and compiles
  numba's cache once, so the ranks do not all compile at once. `bench collect DIR` then gathers
  the finished points into DIR/runs.csv exactly as a local sweep does.

Every launcher has `dry_run(points, out, repeats)` (print each command and its environment,
run nothing). A launcher with `batch = False` runs points one at a time (`run_point`); a batch
launcher hands them all to a scheduler (`submit`) and returns.
"""
import json
import os
import shlex
import subprocess
import sys

from bench.run.records import write_json
from bench.sweep.records import manifest
from modes.base import parse_mapping

LAUNCHERS = {}


def launcher(name):
    """Class decorator: register a launcher under `name` (the --launcher choice)."""
    def put(cls):
        cls.name = name
        LAUNCHERS[name] = cls
        return cls
    return put


def point_env(point):
    """The thread variables of a point's processes."""
    m = parse_mapping(point.mapping)
    env = {"NUMBA_NUM_THREADS": str(m.threads), "OMP_NUM_THREADS": str(m.threads)}
    if point.pin:
        env.update(OMP_PROC_BIND="close", OMP_PLACES="cores")
    return env


@launcher("local")
class Local:
    """Each repeat of a point as a child process here, one at a time."""
    batch = False

    def __init__(self, timeout):
        self.timeout = timeout

    def command(self, point, rep_dir):
        return [sys.executable, "-m", "bench"] + point.run_args(rep_dir, self.timeout)

    def dry_run(self, points, out, repeats):
        for p in points:
            env = " ".join(f"{k}={v}" for k, v in point_env(p).items())
            for r in range(repeats):
                print(f"{env} {shlex.join(self.command(p, os.path.join(out, p.key, f'rep{r}')))}")
        return 0

    def run_point(self, point, rep_dir, env):
        """Run one repeat of a point in rep_dir; write cmd.txt, stdout.txt, stderr.txt, status.json;
        returns the status {"status", "reason"}."""
        os.makedirs(rep_dir, exist_ok=True)
        cmd = self.command(point, rep_dir)
        timeout = self.timeout
        with open(os.path.join(rep_dir, "cmd.txt"), "w") as fh:
            fh.write(shlex.join(cmd) + "\n")
        if os.path.exists(os.path.join(rep_dir, "status.json")):
            os.remove(os.path.join(rep_dir, "status.json"))
        with open(os.path.join(rep_dir, "stdout.txt"), "w") as so, \
                open(os.path.join(rep_dir, "stderr.txt"), "w") as se:
            try:
                # bench run kills its own MPI ranks at `timeout`; this outer limit only catches a stuck start
                rc = subprocess.run(cmd, stdout=so, stderr=se, env=env,
                                    timeout=timeout + min(120, timeout)).returncode
            except subprocess.TimeoutExpired:
                rc = None
        err = open(os.path.join(rep_dir, "stderr.txt")).read().strip().splitlines()
        last = next((l for l in reversed(err) if l.strip() and "warning" not in l), "")
        if rc is None or rc == 3:
            status = {"status": "timeout", "reason": f"no result within {timeout} s"}
        elif rc == 0:
            status = {"status": "done", "reason": ""}
        elif rc == 1 and os.path.exists(os.path.join(rep_dir, "run.json")) and \
                json.load(open(os.path.join(rep_dir, "run.json"))).get("stable") is False:
            status = {"status": "unstable", "reason": last}
        else:
            status = {"status": "failed", "reason": last or f"exit status {rc}"}
        with open(os.path.join(rep_dir, "status.json"), "w") as fh:
            json.dump(status, fh)
        return status


@launcher("slurm")
class Slurm:
    """One sbatch script per point and a submit.sh; `bench collect` reads the results."""
    batch = True

    def __init__(self, timeout, python=None):
        self.timeout = timeout
        self.python = python or sys.executable

    def job_script(self, point, out):
        """Text of the sbatch script of one point (its records go to out/<key>/rep0)."""
        python, timeout = self.python, self.timeout
        m = parse_mapping(point.mapping)
        rep = os.path.join(out, point.key, "rep0")
        run_args = point.run_args(rep, timeout)
        lines = ["#!/bin/bash", f"#SBATCH --job-name=dem-{point.mapping}", f"#SBATCH --ntasks={m.procs}",
                 f"#SBATCH --cpus-per-task={m.threads}", f"#SBATCH --time={max(1, timeout // 60 + 5)}",
                 f"#SBATCH --output={os.path.join(out, point.key, 'slurm-%j.out')}", "set -e"]
        lines += [f"export {k}={v}" for k, v in point_env(point).items()]
        lines.append(f"mkdir -p {shlex.quote(rep)}")
        prep = [python, "-m", "bench", "run", "--scene", point.scene, "--steps", "0", "--quiet",
                "--out", os.path.join(out, point.key, "prepare")]
        if point.particles:
            prep += ["--particles", str(point.particles)]
        if point.shape:
            prep += ["--shape", point.shape]
        lines.append(shlex.join(prep) + "  # builds the scene cache and compiles numba's cache once")
        srun = ["srun", f"--ntasks={m.procs}", f"--cpus-per-task={m.threads}", "--cpu-bind=cores"]
        if m.procs > 1:
            cmd = srun + [python, "-m", "mpi4py", "-m", "bench.run.rank"] + run_args[1:]
        else:
            cmd = srun + [python, "-m", "bench"] + run_args
        lines.append(shlex.join(cmd) + f" > {shlex.quote(os.path.join(rep, 'stdout.txt'))}"
                     f" 2> {shlex.quote(os.path.join(rep, 'stderr.txt'))}")
        return "\n".join(lines) + "\n"

    def dry_run(self, points, out, repeats):
        for p in points:
            print(f"# {p.key}: sbatch {os.path.join(out, p.key, 'job.sbatch')}")
            print(self.job_script(p, out))
        return 0

    def submit(self, points, out):
        """Write every point's job script, the manifest and DIR/submit.sh."""
        scripts = []
        for p in points:
            os.makedirs(os.path.join(out, p.key), exist_ok=True)
            path = os.path.join(out, p.key, "job.sbatch")
            with open(path, "w") as fh:
                fh.write(self.job_script(p, out))
            scripts.append(path)
        write_json(os.path.join(out, "manifest.json"), manifest(out, points))
        submit = os.path.join(out, "submit.sh")
        with open(submit, "w") as fh:
            fh.write("#!/bin/bash\n# submit every point of the sweep; then: bench collect " + shlex.quote(out)
                     + "\nset -e\n")
            fh.writelines(f"sbatch {shlex.quote(s)}\n" for s in scripts)
        os.chmod(submit, 0o755)
        print(f"wrote {len(scripts)} job scripts and {submit}; after the jobs: bench collect {out}")
        return 0
