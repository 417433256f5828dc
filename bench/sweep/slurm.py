"""Slurm for `bench sweep --launcher slurm`: the job scripts, their submission, and what the
scheduler says about the jobs.

A sweep in DIR (absolute paths everywhere, so relative `--out` and `--scene` work) becomes:

- `DIR/prepare.sbatch`: one job that builds each scene of the points (the scene cache) and
  compiles numba's cache for every kernel the points will run (each thread count, scheme,
  neighbour and contact method; the MPI pack kernels), `python -m bench.sweep.job prepare DIR`;
- `DIR/<point>/job.sbatch`: each point as a job array over the repeats to run (task r writes
  `DIR/<point>/rep<r>/`), started after the prepare job (`afterany`: a failed prepare job lets
  the points fail with their own reason instead of waiting for ever). The job runs
  `python -m bench.sweep.job point REP -- <command>` (bench.sweep.job: status, node, time limit),
  the command being `srun --ntasks=1 --cpus-per-task=T --cpu-bind=cores python -m bench run ...`
  for one process, and for P > 1 `python -m bench run ... --mpi-starter 'srun --mpi=pmi2
  --ntasks=P --cpus-per-task=T --cpu-bind=cores --distribution=block:block'` (or, with mpi =
  hydra, the Python's mpiexec `-n P -bind-to core:T` inside the allocation, with
  SLURM_MPI_TYPE=none). Ranks placed by node (issue 37): the ranks number the blocks in
  row-major order, x slowest (bench.run.rank: Create_cart without reordering), and block
  distribution puts consecutive ranks on one node, so with `--nodes K` each node holds a
  contiguous run of blocks (whole x slabs when K divides px): neighbouring blocks share a node
  and only the slabs' faces cross the network (run.json `placement`);
- `DIR/collect.sbatch`: `bench collect DIR` after every point (`afterany`), on a compute node;
- `DIR/submit.sh`: submits the three in that order with `sbatch --parsable`, goes on when sbatch
  refuses a job, and records every job id (or the refusal) in `DIR/jobs.json`,
  `DIR/<point>/job.json`, `DIR/<point>/rep<r>/job.json` and `DIR/{prepare,collect}/job.json`.

What the scheduler knows (`Scheduler`): `scontrol show job -o` while it still knows a job
(MinJobAge), else `sacct` where accounting exists; states mapped to pending, running,
completed, timeout, cancelled, failed.
"""
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

from bench.run.transport import SHARED_CORES
from bench.sweep.slurm_options import DEFAULT_MPI
from modes.base import parse_mapping

REP = "@REP@"  # the repeat folder in a command, replaced by "$REP" in the script


def have_slurm(command="sbatch"):
    return shutil.which(command) is not None


def reachable():
    """(True, '') when Slurm's controller answers here (`scontrol ping`), else (False, why)."""
    if not have_slurm("sbatch"):
        return False, "no sbatch here"
    rc, out, err = _run(["scontrol", "ping"], timeout=30)
    if rc == 0 and "UP" in out:
        return True, ""
    lines = [l.strip() for l in (err or out).splitlines() if l.strip()]
    return False, "Slurm is installed but its controller does not answer here" + (f" ({lines[-1]})" if lines else "")


def _run(cmd, timeout=60):
    """(returncode, stdout, stderr) of a Slurm command; (None, '', reason) when it cannot run."""
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, "", str(e)
    return res.returncode, res.stdout, res.stderr


# --- the job scripts ---------------------------------------------------------------------------

def _header(name, output, opts, chdir, point=True):
    """#SBATCH lines shared by every job of the sweep (points add their own)."""
    lines = ["#!/bin/bash", f"#SBATCH --job-name={name}", f"#SBATCH --chdir={chdir}", f"#SBATCH --output={output}"]
    for key, flag in (("partition", "partition"), ("account", "account"), ("qos", "qos"), ("time", "time"),
                      ("mem", "mem"), ("constraint", "constraint")):
        if opts.get(key):
            lines.append(f"#SBATCH --{flag}={opts[key]}")
    if point:
        # a repeat whose node was lost stays failed with its records (Slurm would requeue it into the
        # same folder); --resume runs it again
        lines.append("#SBATCH --no-requeue")
        if opts.get("exclusive"):
            lines.append("#SBATCH --exclusive")
        if opts.get("hint"):
            lines.append(f"#SBATCH --hint={opts['hint']}")
    return lines


def _exports(env):
    return [f"export {k}={shlex.quote(str(v))}" for k, v in env.items()]


def cache_env():
    """The cache folders the jobs must share with the prepare job, when set here (absolute)."""
    return {k: os.path.abspath(os.environ[k]) for k in ("DEM_BENCH_CACHE", "NUMBA_CACHE_DIR") if os.environ.get(k)}


def tasks_per_node(procs, opts):
    """Ranks a node holds for a point of P = procs ranks under the options (nodes, ntasks_per_node)."""
    if procs == 1:
        return 1
    if opts.get("ntasks_per_node"):
        return min(procs, opts["ntasks_per_node"])
    if opts.get("nodes"):
        return math.ceil(procs / opts["nodes"])
    return procs


def point_nodes(procs, opts):
    """--nodes of a point."""
    if procs == 1:
        return 1
    if opts.get("ntasks_per_node"):
        return math.ceil(procs / min(procs, opts["ntasks_per_node"]))
    return opts.get("nodes") or 1


def mpi_starter(mapping, mpi, mpiexec=None):
    """The command that starts a point's P ranks inside its allocation (bench run --mpi-starter)."""
    if mpi == "hydra":
        return [mpiexec or "mpiexec", "-n", str(mapping.procs), "-bind-to", f"core:{mapping.threads}"]
    return ["srun", f"--mpi={mpi}", f"--ntasks={mapping.procs}", f"--cpus-per-task={mapping.threads}",
            "--cpu-bind=cores", "--distribution=block:block"]


def point_command(point, timeout, opts, python, mpiexec=None):
    """The command of one repeat of a point inside its job (REP stands for the repeat folder)."""
    m = parse_mapping(point.mapping)
    run = [python, "-m", "bench"] + point.run_args(REP, timeout)
    if m.procs == 1:
        return ["srun", "--ntasks=1", f"--cpus-per-task={m.threads}", "--cpu-bind=cores"] + run
    return run + ["--mpi-starter", shlex.join(mpi_starter(m, opts.get("mpi", DEFAULT_MPI), mpiexec))]


def job_name(point):
    return f"dem-{point.mapping}{'-' + point.scheme if point.scheme else ''}"


def array_spec(reps):
    """--array value of the repeats `reps` (sorted ints): ranges where they run on."""
    parts, start = [], None
    for i, r in enumerate(reps):
        if start is None:
            start = r
        if i + 1 == len(reps) or reps[i + 1] != r + 1:
            parts.append(f"{start}" if start == r else f"{start}-{r}")
            start = None
    return ",".join(parts)


def point_script(point, out, reps, opts, timeout, python, env, mpiexec=None):
    """Text of DIR/<point>/job.sbatch: a job array over the repeats `reps` of one point."""
    m = parse_mapping(point.mapping)
    pdir = os.path.join(out, point.key)
    per_node = tasks_per_node(m.procs, opts)
    lines = _header(job_name(point), os.path.join(pdir, "slurm-%A_%a.out"), opts, out)
    lines += [f"#SBATCH --array={array_spec(reps)}", f"#SBATCH --nodes={point_nodes(m.procs, opts)}",
              f"#SBATCH --ntasks={m.procs}", f"#SBATCH --cpus-per-task={m.threads}"]
    if m.procs > 1 and opts.get("ntasks_per_node"):
        lines.append(f"#SBATCH --ntasks-per-node={per_node}")
    lines += list(opts.get("extra", []))
    mpi = opts.get("mpi", DEFAULT_MPI)
    lines.append(f"# point {point.mapping}{' ' + point.scheme if point.scheme else ''} of the sweep in {out}: "
                 f"{m.procs} rank(s) x {m.threads} thread(s); array task r = repeat r"
                 + (f"; ranks started by {'Hydra mpiexec' if mpi == 'hydra' else 'srun --mpi=' + mpi}"
                    if m.procs > 1 else ""))
    lines += _exports(dict(env))
    if m.procs > 1 and mpi == "hydra":
        lines.append("export SLURM_MPI_TYPE=none  # Hydra starts its proxies with srun: no PMI plugin for them")
    lines.append("# ranks x threads beyond the CPUs this node gave the job: OpenMP threads wait passively, and each\n"
                 "# rank's empty polls of mpich's queues are throttled (bench.run.transport SHARED_CORES)")
    throttle = "".join(f'; export {k}="${{{k}:-{v}}}"' for k, v in SHARED_CORES.items())
    lines.append(f'if [ $(({per_node} * {m.threads})) -gt "${{SLURM_CPUS_ON_NODE:-{per_node * m.threads}}}" ]; '
                 f"then export OMP_WAIT_POLICY=PASSIVE{throttle}; fi")
    lines.append(f'REP={shlex.quote(pdir)}/rep"${{SLURM_ARRAY_TASK_ID:-0}}"')
    cmd = shlex.join(point_command(point, timeout, opts, python, mpiexec)).replace(REP, '"$REP"')
    runner = shlex.join([python, "-m", "bench.sweep.job", "point", REP, "--timeout", str(timeout), "--"])
    lines.append("exec " + runner.replace(REP, '"$REP"') + " " + cmd)
    return "\n".join(lines) + "\n"


def prepare_script(out, points, opts, python, env):
    """Text of DIR/prepare.sbatch: the scene builds and numba's cache for every point."""
    threads = max(parse_mapping(p.mapping).threads for p in points)
    lines = _header("dem-prepare", os.path.join(out, "prepare", "slurm-%j.out"), opts, out, point=False)
    lines += ["#SBATCH --ntasks=1", "#SBATCH --cpus-per-task=1"] + list(opts.get("extra", []))
    lines.append(f"# builds the scenes and compiles numba's cache once for the {len(points)} points of {out}, "
                 "so that their jobs and ranks do not all compile at once")
    lines += _exports(dict(env, NUMBA_NUM_THREADS=threads, OMP_WAIT_POLICY="PASSIVE"))
    lines.append("exec " + shlex.join([python, "-m", "bench.sweep.job", "prepare", out]))
    return "\n".join(lines) + "\n"


def collect_script(out, opts, python, env):
    """Text of DIR/collect.sbatch: bench collect on a compute node, after every point."""
    lines = _header("dem-collect", os.path.join(out, "collect", "slurm-%j.out"), opts, out, point=False)
    lines += ["#SBATCH --ntasks=1", "#SBATCH --cpus-per-task=1"] + list(opts.get("extra", []))
    lines.append(f"# runs.csv, summary.json, manifest.json (with this node's CPU) and the figures of {out}")
    lines += _exports(env)
    lines.append(shlex.join([python, "-m", "bench", "collect", out]))
    lines.append("rc=$?")
    lines.append("# 4: collected, and some point is not done (bench sweep --status tells which): the job itself worked")
    lines.append('[ "$rc" = 4 ] && exit 0')
    lines.append('exit "$rc"')
    return "\n".join(lines) + "\n"


def submit_script(out, plan, active=()):
    """Text of DIR/submit.sh. plan: [(point key, [repeats])]; active: job ids of the sweep still
    pending or running (--resume), which the collect job waits for as well."""
    q = shlex.quote
    s = f"""#!/bin/bash
# Submits the sweep in {out} to Slurm and records every job id: the prepare job (scene builds,
# numba's cache), each point as a job array over its repeats after it (afterany), then the collect
# job after every point (afterany: it runs whatever their outcome). A job that sbatch refuses is
# recorded with sbatch's message (jobs.json, the point's job.json) and does not stop the others;
# the exit status is then 4. `bench sweep --launcher slurm` writes this file and runs it when
# sbatch is on PATH. Then: bench sweep --status DIR, bench sweep --cancel DIR, bench collect DIR.
set -u
cd {q(out)} || exit 1
refused=0
now=$(date +%Y-%m-%dT%H:%M:%S%z)
errfile=$(mktemp)
# submit SCRIPT [DEPENDENCY]: sets id (empty when sbatch refuses) and err (sbatch's message)
submit() {{
  local got
  if got=$(sbatch --parsable ${{2:+--dependency=$2}} "$1" 2>"$errfile"); then
    id=${{got##*$'\\n'}}; id=${{id%%;*}}; err=""
  else
    id=""; err=$(tr -d '"\\\\' <"$errfile" | tr '\\n\\t' '  ' | sed 's/ *$//')
    [ -n "$err" ] || err="sbatch failed"
    refused=$((refused + 1)); echo "sbatch refused $1: $err" >&2
  fi
}}
# record FILE [FIELDS]: this submission as JSON
record() {{
  if [ -n "$id" ]; then printf '{{"job_id": "%s", %s"submitted": "%s"}}\\n' "$id" "${{2:-}}" "$now" >"$1"
  else printf '{{"job_id": null, %s"error": "%s", "submitted": "%s"}}\\n' "${{2:-}}" "$err" "$now" >"$1"; fi
}}
# record_reps KEY TASKS...: each array task's job id in its repeat folder
record_reps() {{
  local key=$1 t; shift
  for t in "$@"; do
    if [ -n "$id" ]; then
      printf '{{"job_id": "%s_%s", "array_job_id": "%s", "task": %s, "submitted": "%s"}}\\n' "$id" "$t" "$id" "$t" "$now" >"$key/rep$t/job.json"
    else
      printf '{{"job_id": null, "task": %s, "error": "%s", "submitted": "%s"}}\\n' "$t" "$err" "$now" >"$key/rep$t/job.json"
    fi
  done
}}
points=({" ".join(q(a) for a in active)})
entries=()

submit prepare.sbatch
record prepare/job.json
prepare=$(cat prepare/job.json)
dep=${{id:+afterany:$id}}
"""  # noqa: E501
    for key, reps in plan:
        tasks = ", ".join(str(r) for r in reps)
        s += (f"\nsubmit {q(key + '/job.sbatch')} \"$dep\"\n"
              f"record {q(key + '/job.json')} '\"tasks\": [{tasks}], '\n"
              f"record_reps {q(key)} {' '.join(str(r) for r in reps)}\n"
              f"[ -n \"$id\" ] && points+=(\"$id\")\n"
              f"entries+=(\"\\\"{key}\\\": $(cat {q(key + '/job.json')})\")\n")
    s += """
if [ ${#points[@]} -gt 0 ]; then
  submit collect.sbatch "afterany:$(IFS=:; echo "${points[*]}")"
  record collect/job.json
else
  id=""; err="no point job to wait for"; record collect/job.json
fi
collect=$(cat collect/job.json)
{
  printf '{"submitted": "%s",\\n "prepare": %s,\\n "collect": %s,\\n "points": {' "$now" "$prepare" "$collect"
  sep=""
  for e in "${entries[@]}"; do printf '%s\\n  %s' "$sep" "$e"; sep=","; done
  printf '}}\\n'
} >jobs.json.tmp && mv jobs.json.tmp jobs.json
rm -f "$errfile"
echo "submitted the prepare job, ${#points[@]} point job(s) and the collect job of $PWD ($refused refused); ids in $PWD/jobs.json"
[ "$refused" = 0 ] || exit 4
"""  # noqa: E501
    return s


# --- what the cluster offers ---------------------------------------------------------------------

def partition_cpus(partition=None):
    """(largest CPUs of a node, nodes) of the partition (default: the default partition) from sinfo,
    or None where sinfo cannot tell."""
    if not have_slurm("sinfo"):
        return None
    cmd = ["sinfo", "-h", "-o", "%c %D %P"] + (["-p", partition] if partition else [])
    rc, out, _ = _run(cmd)
    if rc != 0 or not out.strip():
        return None
    cpus, nodes = 0, 0
    for line in out.split("\n"):
        parts = line.split()
        if len(parts) < 3 or (not partition and not parts[2].endswith("*")):
            continue
        try:
            c = int(parts[0].rstrip("+"))
            n = int(parts[1])
        except ValueError:
            continue
        cpus, nodes = max(cpus, c), nodes + n
    return (cpus, nodes) if cpus else None


def test_only(script_text):
    """sbatch --test-only on a script's text: None when Slurm would take it, else its one-line refusal."""
    try:
        res = subprocess.run(["sbatch", "--test-only"], input=script_text, capture_output=True, text=True,
                             timeout=60)
    except (OSError, subprocess.TimeoutExpired) as e:
        return str(e)
    if res.returncode == 0:
        return None
    lines = [l.strip() for l in res.stderr.splitlines() if l.strip() and "warning" not in l.lower()]
    return "; ".join(lines) or f"sbatch --test-only exit status {res.returncode}"


def cancel(job_ids):
    """scancel the jobs; returns (ok, message)."""
    rc, out, err = _run(["scancel"] + list(job_ids))
    return rc == 0, (err or out).strip()


# --- what the scheduler says ---------------------------------------------------------------------

STATES = {  # Slurm job state -> our word
    "PENDING": "pending", "REQUEUED": "pending", "REQUEUE_HOLD": "pending", "REQUEUE_FED": "pending",
    "RESV_DEL_HOLD": "pending", "CONFIGURING": "pending", "SUSPENDED": "running",
    "RUNNING": "running", "COMPLETING": "running", "STAGE_OUT": "running", "SIGNALING": "running",
    "RESIZING": "running", "COMPLETED": "completed", "TIMEOUT": "timeout", "DEADLINE": "timeout",
    "CANCELLED": "cancelled", "PREEMPTED": "cancelled", "FAILED": "failed", "NODE_FAIL": "failed",
    "BOOT_FAIL": "failed", "OUT_OF_MEMORY": "failed", "SPECIAL_EXIT": "failed", "REVOKED": "failed",
}


def task_ids(spec):
    """The array task ids of scontrol's ArrayTaskId ('0-2', '1,3', '0-9%2', '0-8:2')."""
    ids = set()
    for part in spec.split("%")[0].split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+)(?::(\d+))?)?", part.strip())
        if m:
            a, b, step = int(m[1]), int(m[2] or m[1]), int(m[3] or 1)
            ids.update(range(a, b + 1, step))
    return ids


def parse_scontrol(text):
    """Records of `scontrol show job -o` (one line a job or pending array range): dicts of its fields."""
    recs = []
    for line in text.splitlines():
        if "JobId=" in line:
            recs.append(dict(re.findall(r"(?:^|\s)([A-Za-z][\w/:]*)=(\S*)", line)))
    return recs


def parse_sacct(text):
    """Records of `sacct -n -P -X -o JobID,State,ExitCode,NodeList,Reason,Timelimit`."""
    recs = []
    for line in text.splitlines():
        f = line.split("|")
        if len(f) < 6:
            continue
        jid = f[0]
        rec = {"JobState": f[1].split()[0] if f[1] else "", "ExitCode": f[2], "NodeList": f[3], "Reason": f[4],
               "TimeLimit": f[5], "JobId": jid}
        m = re.fullmatch(r"(\d+)_\[?([^\]]*)\]?", jid)
        if m:
            rec.update(ArrayJobId=m[1], ArrayTaskId=m[2])
        recs.append(rec)
    return recs


class Record:
    """One job (or array task) as the scheduler reports it."""

    def __init__(self, fields):
        self.fields = fields
        self.slurm_state = fields.get("JobState", "")
        self.state = STATES.get(self.slurm_state, "failed" if self.slurm_state else "unknown")
        self.reason = fields.get("Reason", "")
        self.node = fields.get("NodeList", "") or fields.get("BatchHost", "")

    def text(self):
        """One line: what Slurm says about the job."""
        parts = [f"Slurm JobState={self.slurm_state}"]
        if self.reason and self.reason not in ("None", "(null)"):
            parts.append(f"Reason={self.reason}")
        if self.fields.get("ExitCode") not in (None, "", "0:0"):
            parts.append(f"ExitCode={self.fields['ExitCode']}")
        if self.state == "timeout" and self.fields.get("TimeLimit"):
            parts.append(f"TimeLimit={self.fields['TimeLimit']}")
        return " ".join(parts)


class Scheduler:
    """Job states from scontrol (jobs Slurm still holds) and sacct (accounting, where it exists),
    one query per array job, cached. `Scheduler.here()` is None without Slurm's commands."""

    def __init__(self):
        self._seen = {}

    @classmethod
    def here(cls):
        return cls() if have_slurm("scontrol") or have_slurm("sacct") else None

    def _load(self, base):
        recs = []
        if have_slurm("scontrol"):
            rc, out, _ = _run(["scontrol", "show", "job", "-o", base])
            if rc == 0:
                recs = parse_scontrol(out)
        if not recs and have_slurm("sacct"):
            rc, out, _ = _run(["sacct", "-n", "-P", "-X", "-j", base, "-o",
                               "JobID,State,ExitCode,NodeList,Reason,Timelimit"])
            if rc == 0:
                recs = parse_sacct(out)
        self._seen[base] = recs
        return recs

    def lookup(self, job_id):
        """The Record of a job id ('123') or array task ('123_4'), or None when Slurm does not know it."""
        if not job_id:
            return None
        base, _, task = str(job_id).partition("_")
        recs = self._seen[base] if base in self._seen else self._load(base)
        for f in recs:
            if task:
                if f.get("ArrayJobId") == base and int(task) in task_ids(f.get("ArrayTaskId", "")):
                    return Record(f)
            elif f.get("JobId") == base:
                return Record(f)
        return None


# --- generation: checks, scripts, submission -------------------------------------------------------

def check_points(points, opts, mpiexec):
    """Everything about the points that can be checked before a job runs; ModeError (one line)
    for the first problem. Returns notes to print (what could not be checked)."""
    from bench.run.prepare import prepare
    from dem.scene import load_scene
    from modes.base import ModeError
    from modes.decomposition import BlockGrid, DecompositionError, border_width
    notes = []
    mappings = {p.mapping: parse_mapping(p.mapping) for p in points}
    mpi_points = [m for m in mappings.values() if m.procs > 1]
    if opts.get("nodes"):
        small = [m for m in mpi_points if m.procs < opts["nodes"]]
        if small:
            raise ModeError(f"slurm.nodes = {opts['nodes']} but mapping {small[0]} has only {small[0].procs} "
                            f"ranks (at least one a node)")
    if mpi_points and opts.get("mpi", DEFAULT_MPI) == "hydra" and mpiexec is None:
        raise ModeError("slurm.mpi = hydra needs mpiexec beside this Python or on PATH (pip install mpich)")
    # block widths against the border layer (against the built box when the build is cached)
    scenes = {}
    for p in points:
        m = mappings[p.mapping]
        if m.procs == 1:
            continue
        key = (p.scene, p.particles or None, p.shape or None)
        if key not in scenes:
            scene = load_scene(p.scene, particles=key[1], shape=key[2])
            if prepare(scene, build_missing=False) is None:
                notes.append(f"scene {p.scene} ({scene.n} particles) is not built yet: block widths checked "
                             f"against its unbuilt box, and again by the prepare job after the build")
            scenes[key] = (scene.box, border_width(float(scene.state.rbound.max())))
        box, width = scenes[key]
        try:
            BlockGrid(box, (m.px, m.py, m.pz)).check_width(width)
        except DecompositionError as e:
            raise ModeError(f"mapping {m}: {e}") from None
    # cores against the partition, where sinfo can tell
    part = partition_cpus(opts.get("partition"))
    if part is None:
        notes.append("sinfo cannot tell the partition's CPUs here: requested cores not checked")
    else:
        cpus, nodes = part
        where = f"partition {opts['partition']}" if opts.get("partition") else "the default partition"
        for m in mappings.values():
            need = tasks_per_node(m.procs, opts) * m.threads
            if need > cpus:
                raise ModeError(f"mapping {m} needs {need} CPUs on a node ({tasks_per_node(m.procs, opts)} rank(s) "
                                f"x {m.threads} thread(s)) but the nodes of {where} have at most {cpus} (sinfo)")
            if point_nodes(m.procs, opts) > nodes:
                raise ModeError(f"mapping {m} needs {point_nodes(m.procs, opts)} nodes but {where} has {nodes} (sinfo)")
    return notes


def plan_repeats(points, out, repeats, resume, scheduler):
    """([(point, [repeats to submit])], [job ids still active]) for a generation in `out`: with
    --resume the repeats done are skipped; repeats pending or running are never submitted again
    (without --resume they refuse the generation: ModeError)."""
    from bench.sweep.status import ACTIVE, rep_outcome
    from modes.base import ModeError
    plan, active, busy = [], set(), []
    for p in points:
        reps = []
        for r in range(repeats):
            o = rep_outcome(os.path.join(out, p.key, f"rep{r}"), scheduler, True)
            if o["status"] in ACTIVE:
                busy.append(o["job"])
                active.add(o["job"].split("_")[0])
                continue
            if resume and o["status"] == "done":
                continue
            reps.append(r)
        if reps:
            plan.append((p, reps))
    if busy and not resume:
        raise ModeError(f"{out} has {len(busy)} repeat(s) still pending or running (job {busy[0]}): "
                        f"bench sweep --cancel {out} first, or --resume")
    return plan, sorted(active)


def slurm_manifest(out, points, repeats, opts, timeout):
    """manifest.json of a Slurm sweep: the plan and the submit host; the compute nodes' CPU comes
    from the jobs (bench collect fills cpu_model, cpu_count and nodes)."""
    import socket
    from bench.sweep.records import manifest
    info = manifest(out, points)
    host = {k: info.pop(k, None) for k in ("platform", "cpu_count", "usable_cpus", "cpu_model")}
    host["host"] = socket.gethostname()
    info.update(launcher="slurm", repeats=repeats, timeout=timeout, slurm=dict(opts), submit_host=host,
                cpu_model=None, cpu_count=None, nodes={},
                compute_nodes="cpu_model, cpu_count and nodes are the compute nodes', filled in by bench collect")
    return info


def generate(points, out, repeats, resume, opts, timeout, submit=True, dry_run=False):
    """`bench sweep --launcher slurm`: check, write the job scripts and submit.sh, and submit them
    when sbatch is on PATH (and submit); returns the exit status."""
    from bench.run.launch import mpiexec_path
    from bench.run.records import write_json
    from bench.sweep.points import point_env
    from bench.sweep.records import merge_manifest
    from modes.base import ModeError
    out = os.path.abspath(out)
    opts = dict(opts)
    opts.setdefault("mpi", DEFAULT_MPI)
    python = sys.executable
    mpiexec = mpiexec_path()
    notes = check_points(points, opts, mpiexec)
    scheduler = Scheduler.here()
    if dry_run:
        plan, active = [(p, list(range(repeats))) for p in points], []
    else:
        plan, active = plan_repeats(points, out, repeats, resume, scheduler)
    env = cache_env()
    texts = {"prepare.sbatch": prepare_script(out, points, opts, python, env),
             "collect.sbatch": collect_script(out, opts, python, env)}
    for p, reps in plan:
        texts[os.path.join(p.key, "job.sbatch")] = point_script(p, out, reps, opts, timeout, python,
                                                                dict(env, **point_env(p)), mpiexec)
    texts["submit.sh"] = submit_script(out, [(p.key, reps) for p, reps in plan], active)
    for n in notes:
        print(f"bench: note: {n}")
    if dry_run:
        for name, text in texts.items():
            print(f"# ---- {os.path.join(out, name)}")
            print(text)
        return 0
    can_submit, why = reachable()
    if can_submit:  # what Slurm would refuse, before anything is written or submitted
        for name, text in texts.items():
            if name.endswith(".sbatch"):
                refusal = test_only(text)
                if refusal:
                    raise ModeError(f"sbatch --test-only refuses {name}: {refusal}")
    elif have_slurm("sbatch"):
        print(f"bench: note: {why}: the job scripts are not checked by sbatch --test-only")
    info = slurm_manifest(out, points, repeats, opts, timeout)
    for p in info["points"]:
        p["repeats"] = repeats
    entry = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": " ".join(sys.argv),
             "points": [p.key for p in points], "repeats": repeats, "resume": bool(resume), "launcher": "slurm"}
    write_json(os.path.join(out, "manifest.json"), merge_manifest(out, info, entry))
    if not plan:
        print(f"nothing to submit: every repeat of the {len(points)} points is done"
              f"{' or still queued' if active else ''}; bench sweep --status {out}")
        return 0
    for role in ("prepare", "collect"):
        os.makedirs(os.path.join(out, role), exist_ok=True)
    for p, reps in plan:
        for r in reps:
            rep = os.path.join(out, p.key, f"rep{r}")
            os.makedirs(rep, exist_ok=True)
            for stale in ("status.json", "job.json"):
                if os.path.exists(os.path.join(rep, stale)):
                    os.remove(os.path.join(rep, stale))
    for name, text in texts.items():
        path = os.path.join(out, name)
        with open(path, "w") as fh:
            fh.write(text)
        os.chmod(path, 0o755 if name.endswith(".sh") else 0o644)
    n_reps = sum(len(r) for _, r in plan)
    print(f"wrote {len(plan)} point job script(s) ({n_reps} repeat(s)), prepare.sbatch, collect.sbatch and "
          f"submit.sh in {out}")
    if not (submit and can_submit):
        print(f"submit them with: bash {os.path.join(out, 'submit.sh')}{'' if can_submit else f' ({why})'}; "
              f"then bench sweep --status {out}; bench collect {out}")
        return 0
    res = subprocess.run(["bash", os.path.join(out, "submit.sh")], capture_output=True, text=True)
    sys.stdout.write(res.stdout)
    sys.stderr.write(res.stderr)
    print(f"follow them with: bench sweep --status {out}; cancel: bench sweep --cancel {out}; "
          f"the collect job writes runs.csv and the figures")
    return 0 if res.returncode == 0 else 4


# --- status and cancel ---------------------------------------------------------------------------

def show_status(directory):
    """`bench sweep --status DIR`: each repeat's state (files + Slurm) and the sweep's jobs."""
    from bench.sweep.status import job_outcome, sweep_outcomes
    scheduler = Scheduler.here()
    info, rows = sweep_outcomes(directory, scheduler)
    counts = {}
    lines = []
    for p, outcomes in rows:
        name = p["mapping"] + (" " + p["scheme"] if p.get("scheme") else "")
        for o in outcomes:
            counts[o["status"]] = counts.get(o["status"], 0) + 1
            lines.append((name, o["rep"], o["job"] or "-", o["status"], o["node"] or "-", o["reason"]))
    print(f"sweep {directory}: {len(rows)} points x {info.get('repeats', '?')} repeat(s), launcher "
          f"{info.get('launcher', 'local')}" + ("" if scheduler is not None else " (no Slurm here: files only)"))
    if info.get("launcher") == "slurm":
        for role in ("prepare", "collect"):
            state, jid, reason = job_outcome(directory, role, scheduler)
            print(f"{role} job {jid or '-'}: {state}" + (f" ({reason})" if reason else ""))
    widths = [max([len(h)] + [len(str(l[i])) for l in lines]) for i, h in enumerate(("point", "rep", "job", "state",
                                                                                          "node"))]
    head = ("point", "rep", "job", "state", "node")
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  reason")
    for l in lines:
        print("  ".join(str(v).ljust(w) for v, w in zip(l[:5], widths)) + "  " + l[5])
    print(", ".join(f"{n} {s}" for s, n in sorted(counts.items())))
    return 0


def cancel_sweep(directory):
    """`bench sweep --cancel DIR`: scancel the sweep's jobs still pending or running; repeats that
    had not started are recorded as cancelled."""
    from bench.run.records import write_json
    from bench.sweep.status import ACTIVE, job_outcome, read_json, sweep_outcomes
    from modes.base import ModeError
    if not have_slurm("scancel"):
        raise ModeError("bench sweep --cancel needs Slurm's scancel, which is not on PATH here")
    scheduler = Scheduler()
    info, rows = sweep_outcomes(directory, scheduler)
    ids, waiting = set(), []
    for role in ("prepare", "collect"):
        state, jid, _ = job_outcome(directory, role, scheduler)
        if state in ACTIVE and jid:
            ids.add(jid)
    for _, outcomes in rows:
        for o in outcomes:
            if o["status"] in ACTIVE:
                ids.add(o["job"])
                if o["status"] == "pending":
                    waiting.append(o)
    if not ids:
        print(f"nothing to cancel: no job of {directory} is pending or running")
        return 0
    ok, msg = cancel(sorted(ids))
    if not ok:
        raise ModeError(f"scancel failed: {msg}")
    for o in waiting:  # never started: no job of theirs will write an outcome
        job = read_json(os.path.join(o["dir"], "job.json")) or {}
        write_json(os.path.join(o["dir"], "status.json"),
                   {"status": "cancelled", "reason": "cancelled before it started (bench sweep --cancel)",
                    "job_id": job.get("job_id")})
    print(f"cancelled {len(ids)} job(s) of {directory}: {' '.join(sorted(ids))}")
    return 0
