"""The outcome of each repeat of a sweep's points: from its files and, for a Slurm sweep, from
what the scheduler says (`bench sweep --status`, `bench collect`).

States: `done`; `failed` (with the run's own last error line, or what Slurm says); `unstable`
(the stability guard stopped it); `timeout` (past `--timeout`, or killed at Slurm's time limit);
`cancelled` (scancel, `bench sweep --cancel`); `pending` (queued, with Slurm's reason);
`running`; `unsubmitted` (written but never submitted); `not_started` (a local sweep's repeat whose
folder the sweep never made: it was interrupted before; `--resume` runs it); `unknown` (submitted,
no result yet, and no Slurm here to ask). The first five are final.

A repeat folder holds `status.json` (written by the local launcher, and in a Slurm job by
bench.sweep.job: `running` when it starts, its outcome when it ends) and, for a Slurm sweep,
`job.json` (its submission: the array task's job id, or sbatch's refusal). A final status in the
files is the answer, except that Slurm's TIMEOUT or CANCELLED wins over a non-done one (the job
was killed before it could say why). Otherwise Slurm's state is (pending, running, or a job
that ended without writing its outcome: failed with Slurm's JobState, Reason and ExitCode).
"""
import json
import os

FINAL = ("done", "failed", "unstable", "timeout", "cancelled")
ACTIVE = ("pending", "running")
# the state a point takes from its repeats: the first of these that any repeat has
PRIORITY = ("failed", "unstable", "timeout", "cancelled", "unknown", "unsubmitted", "not_started", "running",
            "pending", "done")


def read_json(path):
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def judge(rep_dir, rc, timeout):
    """status.json content of a finished run in rep_dir: rc is the exit status of `bench run`
    (None: killed at the outer time limit; 3: its MPI ranks killed at --timeout). The reason of a
    failure is the run's last `bench: error:` line in stderr.txt, else its last line."""
    try:
        with open(os.path.join(rep_dir, "stderr.txt")) as fh:
            err = fh.read().strip().splitlines()
    except OSError:
        err = []
    # the run's own one line when it wrote one (launchers such as srun and MPI_Abort add theirs after it)
    last = next((l.strip() for l in reversed(err) if l.startswith("bench: error:")), "") or \
        next((l for l in reversed(err) if l.strip() and "warning" not in l), "")
    run = read_json(os.path.join(rep_dir, "run.json")) or {}
    if rc is None or rc == 3:
        return {"status": "timeout", "reason": f"no result within {timeout} s"}
    if rc == 0:
        return {"status": "done", "reason": ""}
    if rc == 1 and run.get("stable") is False:
        return {"status": "unstable", "reason": last}
    return {"status": "failed", "reason": last or exit_text(rc)}


def exit_text(rc):
    """What an exit status says: a signal that killed the process (rc < 0), or 128 + a signal."""
    import signal
    for sig, how in ((-rc, "killed by"), (rc - 128, "ended by")):
        if sig > 0:
            try:
                name = signal.Signals(sig).name
            except ValueError:
                continue
            if how == "killed by" or rc > 128:
                return f"{how} {name} (exit status {rc})"
    return f"exit status {rc}"


def from_files(rep_dir):
    """The outcome the files of a repeat folder give without any job record: status.json, else
    judged by run.json (a folder filled by hand or by an older batch job)."""
    st = read_json(os.path.join(rep_dir, "status.json"))
    if st and st.get("status"):
        return st
    run = read_json(os.path.join(rep_dir, "run.json"))
    if run:
        if run.get("status") == "done" and os.path.exists(os.path.join(rep_dir, "state.npz")):
            return {"status": "done", "reason": ""}
        if run.get("stable") is False:
            return {"status": "unstable", "reason": run.get("stability_reason") or "unstable"}
        if run.get("status") in ("failed", "timeout", "interrupted"):
            status = "timeout" if run["status"] == "timeout" else "failed"
            return {"status": status, "reason": run.get("reason") or run["status"]}
        if run.get("status") == "running" and run.get("pid"):
            from bench.run.records import process_alive
            if not process_alive(run["pid"], run.get("host")):
                return {"status": "failed", "reason": f"run.json says running, but its process {run['pid']} on "
                                                      f"{run.get('host')} is gone (killed)"}
    return None


def rep_outcome(rep_dir, scheduler, batch):
    """{"status", "reason", "job", "node"} of one repeat folder. scheduler: a
    bench.sweep.slurm.Scheduler, or None where Slurm cannot be asked; batch: a Slurm sweep (a
    folder without any record is then `unsubmitted`, else `failed`)."""
    st = from_files(rep_dir)
    job = read_json(os.path.join(rep_dir, "job.json")) or {}
    jid = job.get("job_id") or (st or {}).get("job_id")
    out = {"job": jid or "", "node": (st or {}).get("node", "")}
    state = (st or {}).get("status")
    rec = scheduler.lookup(jid) if scheduler is not None and jid else None
    if rec is not None:
        out["node"] = out["node"] or rec.node
    if rec is not None and rec.state in ("timeout", "cancelled") and state != "done":
        reason = st.get("reason") if state == rec.state and st.get("reason") else rec.text()
        return dict(out, status=rec.state, reason=reason)
    if state in FINAL:
        return dict(out, status=state, reason=st.get("reason", ""))
    if job.get("error"):
        return dict(out, status="failed", reason=f"sbatch refused the job: {job['error']}")
    if rec is not None:
        if rec.state in ACTIVE:
            reason = rec.reason if rec.reason not in ("None", "(null)") else ""
            return dict(out, status=rec.state, reason=reason)
        if rec.state == "completed":
            return dict(out, status="failed", reason=f"job {jid} ended without writing its outcome ({rec.text()})")
        return dict(out, status="failed", reason=rec.text())
    if state == "running":
        if scheduler is None:
            return dict(out, status="running", reason="as its status.json says (no Slurm here to ask)")
        return dict(out, status="failed", reason=f"job {jid} ended without writing its outcome and Slurm no "
                                                 f"longer knows it")
    if jid:
        if scheduler is None:
            return dict(out, status="unknown", reason=f"submitted as job {jid}, no result yet (no Slurm here to ask)")
        return dict(out, status="failed", reason=f"job {jid} left no result and Slurm no longer knows it")
    if batch:
        return dict(out, status="unsubmitted", reason="not submitted (run DIR/submit.sh)")
    if not os.path.isdir(rep_dir) or not os.listdir(rep_dir):
        return dict(out, status="not_started", reason="never started: the sweep ended before it (--resume runs it)")
    return dict(out, status="failed", reason="no result (interrupted or crashed)")


def point_outcome(outcomes):
    """The state of a point from its repeats' outcomes (PRIORITY) and that repeat's outcome."""
    for s in PRIORITY:
        for o in outcomes:
            if o["status"] == s:
                return o
    return outcomes[0]


def sweep_outcomes(directory, scheduler=None):
    """(manifest, [(point dict, [rep outcome, ...])]) of the sweep in `directory`, from its
    manifest.json (its points and repeats) and the repeat folders."""
    info = read_json(os.path.join(directory, "manifest.json"))
    if info is None or "points" not in info:
        raise FileNotFoundError(f"{directory} has no manifest.json (not a sweep folder)")
    batch = info.get("launcher") == "slurm"
    rows = []
    for p in info["points"]:
        pdir = os.path.join(directory, p["key"])
        repeats = p.get("repeats") or info.get("repeats")
        if repeats:
            reps = [os.path.join(pdir, f"rep{r}") for r in range(int(repeats))]
        else:  # older manifests: the folders there are
            reps = sorted(os.path.join(pdir, d) for d in os.listdir(pdir) if d.startswith("rep")) \
                if os.path.isdir(pdir) else []
            reps = reps or [os.path.join(pdir, "rep0")]
        rows.append((p, [dict(rep_outcome(r, scheduler, batch), rep=os.path.basename(r), dir=r) for r in reps]))
    return info, rows


def job_outcome(directory, role, scheduler):
    """State of the sweep's prepare or collect job: (state, job id, reason)."""
    job = read_json(os.path.join(directory, role, "job.json")) or {}
    jid = job.get("job_id")
    if job.get("error"):
        return "failed", "", f"sbatch refused it: {job['error']}"
    st = read_json(os.path.join(directory, role, "status.json")) or {}
    rec = scheduler.lookup(jid) if scheduler is not None and jid else None
    if st.get("status") in FINAL and not (rec is not None and rec.state in ("timeout", "cancelled")):
        return st["status"], jid or "", st.get("reason", "")
    if rec is not None:
        state = "done" if rec.state == "completed" else rec.state
        if state in ACTIVE:
            return state, jid, rec.reason if rec.reason not in ("None", "(null)") else ""
        return state, jid, "" if state == "done" else rec.text()
    if not jid:
        return "unsubmitted", "", ""
    return "unknown", jid, "Slurm does not know it (any more)" if scheduler is not None else "no Slurm here to ask"
