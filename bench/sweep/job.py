"""What a Slurm job of a sweep runs on its node (bench.sweep.slurm writes the scripts that call it).

`python -m bench.sweep.job prepare DIR`: the prepare job. Builds (or loads from the cache) each
scene the points of DIR/manifest.json use, and compiles numba's cache for every kernel they will
run: each distinct (threads, scheme, neighbour method, contact method) through the mode's own
warm-up on a copy of the scene (bench.run.launch.warm_cache, what `bench run` does before it
starts ranks), and the MPI pack kernels. NUMBA_NUM_THREADS is the largest T of the points (the
script sets it). Writes DIR/prepare/prepare.json (node, builds, what was compiled and how long it
took) and DIR/prepare/status.json; it also checks the block widths of the MPI points against the
built box, which a scene's build can shrink (a point too narrow fails in its own job, in one line).

`python -m bench.sweep.job point REP --timeout S -- CMD...`: one repeat of a point. Writes
REP/status.json `running` with the job id, node, its CPU and the load average, runs CMD with
REP/stdout.txt and REP/stderr.txt (REP/cmd.txt: the command), and then its outcome (judged as the
local launcher judges it: bench.sweep.status.judge). Past `--timeout` seconds it is stopped
(`timeout`). When Slurm signals the job (SIGTERM: its time limit, or scancel), the outcome is
`timeout` or `cancelled` as `scontrol` gives the job's reason (TimeLimit or not), or `failed`
naming the node and its ranks when Slurm reports one of the job's nodes down or not responding (a
node lost mid-run), written once the run has ended (its own records kept: steps.csv merged) or,
at the latest, 1.5 s before Slurm's KillWait ends. A node lost while Slurm still waits for
it (SlurmdTimeout) is found first by the run's own heartbeat watchdog (bench.run.supervise), whose
line names the rank and its host.
"""
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time

from bench.run.machine import cpu_facts


def _write(path, obj):
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1)
    os.replace(tmp, path)


def node_info():
    """The node this job runs on: host, CPU model, CPUs, the CPUs the job may use, Slurm's ids."""
    cpus = cpu_facts()
    info = {"node": os.environ.get("SLURMD_NODENAME") or socket.gethostname(), "cpu_count": cpus["cpu_count"]}
    if cpus["usable"] is not None:
        info["usable_cpus"] = cpus["usable"]
    info["cpu_model"] = cpus["cpu_model"]
    for key, var in (("job_id", "SLURM_JOB_ID"), ("array_job_id", "SLURM_ARRAY_JOB_ID"),
                     ("array_task_id", "SLURM_ARRAY_TASK_ID"), ("nodelist", "SLURM_JOB_NODELIST"),
                     ("cpus_on_node", "SLURM_CPUS_ON_NODE")):
        if os.environ.get(var):
            info[key] = os.environ[var]
    if info.get("array_job_id"):  # the id the sweep records (jobs.json, job.json)
        info["job_id"] = f"{info['array_job_id']}_{info['array_task_id']}"
        info["slurm_job_id"] = os.environ.get("SLURM_JOB_ID")
    return info


def _scontrol(*args):
    """The key=value fields of each line of `scontrol show ... -o` (empty where it cannot tell)."""
    try:
        out = subprocess.run(["scontrol", "show", *args, "-o"], capture_output=True, text=True, timeout=5).stdout
    except (OSError, subprocess.TimeoutExpired):
        return []
    return [dict(kv.split("=", 1) for kv in line.split() if "=" in kv) for line in out.splitlines() if line.strip()]


# what is left of Slurm's KillWait when the final status is written [s]
KILL_WAIT_MARGIN_S = 1.5


def kill_wait(default=30.0):
    """Slurm's KillWait [s]: how long after its SIGTERM Slurm kills (SIGKILL) what is left of a job
    (`scontrol show config`; Slurm's default, 30, where it cannot tell)."""
    try:
        out = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, timeout=5).stdout
    except (OSError, subprocess.TimeoutExpired):
        return default
    m = re.search(r"^KillWait\s*=\s*(\d+)", out, re.M)
    return float(m.group(1)) if m else default


def lost_nodes(nodelist):
    """[(node, state)] of the nodes of a Slurm node list that Slurm reports down or not responding
    (State DOWN..., or a trailing '*' / NOT_RESPONDING): a node lost under a running job."""
    lost = []
    for node in _scontrol("node", nodelist) if nodelist else []:
        state = node.get("State", "")
        if state.startswith("DOWN") or "NOT_RESPONDING" in state or state.endswith("*"):
            lost.append((node.get("NodeName", "?"), state))
    return lost


def _ranks_on(rep, node):
    """The ranks run.json's placement puts on node (empty when not written yet)."""
    try:
        with open(os.path.join(rep, "run.json")) as fh:
            place = json.load(fh).get("placement") or {}
    except (OSError, ValueError):
        return []
    return sorted(int(r) for r, p in place.items() if p.get("host") == node)


def slurm_verdict(rep=None):
    """(status, reason) of this job being stopped by Slurm: failed when one of its nodes was lost
    (Slurm says it is down or not responding: the reason names it and the ranks run.json placed
    there), timeout at its time limit, else cancelled."""
    job = os.environ.get("SLURM_JOB_ID")
    fields = (_scontrol("job", job) or [{}])[0] if job else {}
    # the allocation this script runs in (a requeued or ending job's NodeList may be gone already)
    nodes = ",".join(x for x in (os.environ.get("SLURM_JOB_NODELIST"), fields.get("NodeList")) if x and x != "(null)")
    lost = lost_nodes(nodes)
    if lost or fields.get("JobState") == "NODE_FAIL":
        node, state = lost[0] if lost else ("?", "NODE_FAIL")
        ranks = _ranks_on(rep, node) if rep else []
        on = f" with rank{'s' if len(ranks) > 1 else ''} {', '.join(map(str, ranks))}" if ranks else ""
        return "failed", f"node {node}{on} lost mid-run (Slurm: {state}); the job was ended"
    if fields.get("Reason") == "TimeLimit" or fields.get("JobState") in ("TIMEOUT", "DEADLINE"):
        return "timeout", f"killed at Slurm's time limit ({fields.get('TimeLimit', '?')})"
    return "cancelled", f"cancelled (Slurm JobState={fields.get('JobState', '?')})"


def run_point(rep, timeout, cmd):
    """One repeat in a Slurm job (see the module docstring); returns the exit status."""
    from bench.sweep.status import judge
    os.makedirs(rep, exist_ok=True)
    base = dict(node_info(), started=time.strftime("%Y-%m-%dT%H:%M:%S%z"), load_before=os.getloadavg()[0])
    status_path = os.path.join(rep, "status.json")
    _write(status_path, dict(base, status="running", reason=""))
    with open(os.path.join(rep, "cmd.txt"), "w") as fh:
        fh.write(shlex.join(cmd) + "\n")
    proc = None

    def stopped(signum, frame):
        t0 = time.monotonic()
        status, reason = slurm_verdict(rep)
        if proc is not None:  # Slurm signalled the run too: it keeps its records (steps.csv) as it ends,
            try:  # which the final status must follow, written before KillWait ends
                proc.wait(timeout=max(0.5, kill_wait() - KILL_WAIT_MARGIN_S - (time.monotonic() - t0)))
            except subprocess.TimeoutExpired:
                pass
        _write(status_path, dict(base, status=status, reason=reason, load_after=os.getloadavg()[0],
                                 ended=time.strftime("%Y-%m-%dT%H:%M:%S%z")))
        if proc is not None and proc.poll() is None:
            proc.kill()
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, stopped)
    with open(os.path.join(rep, "stdout.txt"), "w") as so, open(os.path.join(rep, "stderr.txt"), "w") as se:
        proc = subprocess.Popen(cmd, stdout=so, stderr=se)
        try:
            # bench run kills its own MPI ranks at --timeout; this outer limit catches a stuck start
            rc = proc.wait(timeout=timeout + min(120, timeout))
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            rc = None
    status = judge(rep, rc, timeout)
    if rc is not None and rc < 0 and status["status"] == "failed":  # killed by a signal: Slurm's doing?
        status = dict(zip(("status", "reason"), slurm_verdict(rep)))
    _write(status_path, dict(base, **status, load_after=os.getloadavg()[0],
                             ended=time.strftime("%Y-%m-%dT%H:%M:%S%z")))
    return 0 if status["status"] == "done" else 1


def prepare(directory, part=None, folder="prepare"):
    """The prepare job (see the module docstring); returns the exit status. part: None, all of it;
    "build": the scenes and the kernels of the points with one thread; T (an int > 1): the kernels
    of the points with T threads alone, on the scenes as generated, before their build stage (the
    same arrays and types, so the same compiled kernels; no wait for the build): the parts of a
    local sweep's warm start (bench.sweep.warm), which run at once. folder: DIR/<folder>/ takes
    the records (prepare.json, status.json)."""
    import types
    pdir = os.path.join(directory, folder)
    os.makedirs(pdir, exist_ok=True)
    base = dict(node_info(), started=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    status_path = os.path.join(pdir, "status.json")
    _write(status_path, dict(base, status="running", reason=""))
    record = dict(base, builds=[], compiled=[], width_problems=[])
    try:
        from bench.run.launch import warm_cache
        from bench.run.prepare import prepare as build
        from dem.scene import load_scene
        from dem.timestep import choose_time_step
        from modes.base import parse_mapping
        from modes.decomposition import BlockGrid, DecompositionError, border_width
        from modes.parallel import DEFAULT_SCHEME
        with open(os.path.join(directory, "manifest.json")) as fh:
            points = json.load(fh)["points"]
        if part is not None:
            want = 1 if part == "build" else int(part)
            points = [p for p in points if parse_mapping(p["mapping"]).threads == want]
            record["part"] = part
        scenes = {}
        for p in points:
            skey = (p["scene"], p["particles"] or None, p["shape"] or None)
            if skey not in scenes:
                t = time.perf_counter()
                scene = load_scene(p["scene"], particles=skey[1], shape=skey[2])
                if part is None or part == "build":
                    scene = build(scene)
                    built = scene.extras.get("built") or {}
                    record["builds"].append({"scene": p["scene"], "particles": scene.n, "shape": skey[2],
                                             "from_cache": bool(built.get("from_cache")),
                                             "seconds": time.perf_counter() - t})
                    print(f"prepare: scene {p['scene']} ({scene.n} particles) "
                          f"{'loaded from the cache' if built.get('from_cache') else 'built'} "
                          f"in {time.perf_counter() - t:.1f} s", flush=True)
                dt = choose_time_step(scene, None).dt
                scenes[skey] = (scene, dt, set())
            scene, dt, done = scenes[skey]
            m = parse_mapping(p["mapping"])
            if m.procs > 1 and (part is None or part == "build"):
                try:
                    BlockGrid(scene.box, (m.px, m.py, m.pz)).check_width(border_width(float(scene.state.rbound.max())))
                except DecompositionError as e:
                    record["width_problems"].append({"point": p["key"], "reason": str(e)})
                    print(f"prepare: point {p['mapping']}: {e}", flush=True)
            scheme = (p["scheme"] or DEFAULT_SCHEME) if m.threads > 1 else ""
            ckey = (m.threads, scheme, p["neighbor"], p["contact_method"], p.get("skin"))
            if ckey in done:
                continue
            done.add(ckey)
            args = types.SimpleNamespace(neighbor=p["neighbor"], scheme=scheme or None, threaded="step",
                                         contact_method=p["contact_method"], skin=p.get("skin"))
            t = time.perf_counter()
            warm_cache(scene, parse_mapping(f"1-1-1-1-{m.threads}"), args, dt)  # on a copy of the scene
            took = time.perf_counter() - t
            record["compiled"].append({"scene": p["scene"], "threads": m.threads, "scheme": scheme,
                                       "neighbor": p["neighbor"], "contact_method": p["contact_method"],
                                       "seconds": took})
            print(f"prepare: kernels of {m.threads} thread(s){' ' + scheme if scheme else ''}, {p['neighbor']}, "
                  f"{p['contact_method']} ready in {took:.1f} s", flush=True)
    except Exception as e:  # noqa: BLE001  (recorded as the job's one-line reason; the points still run)
        reason = f"{type(e).__name__}: {e}".splitlines()[0]
        _write(os.path.join(pdir, "prepare.json"), record)
        _write(status_path, dict(base, status="failed", reason=reason, ended=time.strftime("%Y-%m-%dT%H:%M:%S%z")))
        print(f"bench: error: {reason}", file=sys.stderr)
        return 1
    _write(os.path.join(pdir, "prepare.json"), record)
    _write(status_path, dict(base, status="done", reason="", ended=time.strftime("%Y-%m-%dT%H:%M:%S%z")))
    return 0


def main(argv):
    if len(argv) == 2 and argv[0] == "prepare":
        return prepare(argv[1])
    if len(argv) == 4 and argv[0] == "warm":  # a part of a local sweep's warm start (bench.sweep.warm)
        from bench.run.lifeline import die_with_parent
        die_with_parent()
        return prepare(argv[1], part=argv[2], folder=argv[3])
    if len(argv) >= 5 and argv[0] == "point" and argv[2] == "--timeout" and "--" in argv:
        cut = argv.index("--")
        return run_point(argv[1], int(argv[3]), argv[cut + 1:])
    print("usage: python -m bench.sweep.job prepare DIR | point REP --timeout S -- CMD...", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
