"""Sweeps beyond one machine: Slurm batch scripts, dry runs, and `bench collect`.

`bench sweep --launcher slurm` writes DIR/<point>/job.sbatch per point (srun with --ntasks,
--cpus-per-task, --cpu-bind and the thread variables; P > 1 points run the MPI rank program
`python -m mpi4py -m bench.mpi_run` directly under srun) and DIR/submit.sh that submits them
all. Each job first makes a zero-step serial run, which builds the scene's cache and compiles
numba's cache once, so the ranks do not all compile at once. `bench collect DIR` then gathers
the finished points into DIR/runs.csv exactly as a local sweep does. `--dry-run` prints every
command and its environment without running anything.
"""
import os
import shlex
import sys

from modes.base import parse_mapping


def point_env(point):
    m = parse_mapping(point.mapping)
    env = {"NUMBA_NUM_THREADS": str(m.threads), "OMP_NUM_THREADS": str(m.threads)}
    if point.pin:
        env.update(OMP_PROC_BIND="close", OMP_PLACES="cores")
    return env


def job_script(point, out, timeout, python=None):
    """Text of the sbatch script of one point (its records go to out/rep0)."""
    python = python or sys.executable
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
        cmd = srun + [python, "-m", "mpi4py", "-m", "bench.mpi_run"] + run_args[1:]
    else:
        cmd = srun + [python, "-m", "bench"] + run_args
    lines.append(shlex.join(cmd) + f" > {shlex.quote(os.path.join(rep, 'stdout.txt'))}"
                 f" 2> {shlex.quote(os.path.join(rep, 'stderr.txt'))}")
    return "\n".join(lines) + "\n"


def plan(args, points, out):
    """--launcher slurm: write the scripts; --dry-run: print commands and environments."""
    if args.dry_run:
        for p in points:
            env = " ".join(f"{k}={v}" for k, v in point_env(p).items())
            if args.launcher == "slurm":
                print(f"# {p.key}: sbatch {os.path.join(out, p.key, 'job.sbatch')}")
                print(job_script(p, out, args.timeout))
            else:
                for r in range(args.repeats):
                    cmd = [sys.executable, "-m", "bench"] + p.run_args(os.path.join(out, p.key, f"rep{r}"), args.timeout)
                    print(f"{env} {shlex.join(cmd)}")
        return 0
    scripts = []
    for p in points:
        os.makedirs(os.path.join(out, p.key), exist_ok=True)
        path = os.path.join(out, p.key, "job.sbatch")
        with open(path, "w") as fh:
            fh.write(job_script(p, out, args.timeout))
        scripts.append(path)
    from bench.records import write_json
    from bench.sweep import manifest
    write_json(os.path.join(out, "manifest.json"), manifest(out, points))
    submit = os.path.join(out, "submit.sh")
    with open(submit, "w") as fh:
        fh.write("#!/bin/bash\n# submit every point of the sweep; then: bench collect " + shlex.quote(out) + "\nset -e\n")
        fh.writelines(f"sbatch {shlex.quote(s)}\n" for s in scripts)
    os.chmod(submit, 0o755)
    print(f"wrote {len(scripts)} job scripts and {submit}; after the jobs: bench collect {out}")
    return 0


def collect(args):
    """`bench collect DIR`: runs.csv from the point folders listed in DIR/manifest.json."""
    import json
    from bench.sweep import Point, SERIAL, amdahl, summarise, write_runs
    from bench.records import write_json
    from dem.scene import SceneError
    path = os.path.join(args.dir, "manifest.json")
    if not os.path.exists(path):
        raise SceneError(f"{args.dir} has no manifest.json (not a sweep folder)")
    info = json.load(open(path))
    points = [Point(**{k: v for k, v in p.items() if k != "key"}) for p in info["points"]]
    rows = []
    ref_state, t1 = None, None
    import numpy as np
    for p in points:
        pdir = os.path.join(args.dir, p.key)
        reps = sorted(os.path.join(pdir, d) for d in os.listdir(pdir) if d.startswith("rep")) \
            if os.path.isdir(pdir) else []
        reps = reps or [os.path.join(pdir, "rep0")]
        if p.mapping == SERIAL and os.path.exists(os.path.join(reps[0], "state.npz")):
            ref_state = dict(np.load(os.path.join(reps[0], "state.npz")))
        row = summarise(p, reps, ref_state, t1)
        if p.mapping == SERIAL and row["status"] == "done":
            t1 = row["totalT"]
        rows.append(row)
    write_runs(os.path.join(args.dir, "runs.csv"), rows)
    write_json(os.path.join(args.dir, "summary.json"), amdahl(rows))
    done = sum(r["status"] == "done" for r in rows)
    print(f"collected {done} of {len(rows)} points into {os.path.join(args.dir, 'runs.csv')}")
    return 0
