"""`bench sweep --launcher slurm` end to end on a real single-node Slurm (Debian slurm-wlm 22.05,
munge; slurmctld and slurmd started by tests/bench/slurm/cluster.sh, as root, without systemd or
cgroups) that this session starts and stops itself.

Three sweeps of packed 300 ellipsoids share the node (its CPUs, as `slurmd -C` gives them; 2 on
the machines CI runs on, where each 2-CPU point takes the whole node and the jobs queue):
- A: serial, 2 threads (dynamic) and 2 MPI ranks (srun --mpi=pmi2), every one done and
  bit-identical to serial; the states right after submission are pending/running; the collect
  job writes runs.csv, the figures and the compute node's CPU into the manifest; then
  `--repeats 2 --resume` submits only the new repeat of each point.
- B: fails at run time: the serial point runs past its 1-minute Slurm time limit (`timeout`),
  the 2-rank point started with `--mpi none` (each rank alone) fails with its own line; collect
  exits 4 and names both.
- C: cancelled with `bench sweep --cancel` before it starts.
- D: written with --no-submit, one point's script then spoilt (a partition that does not exist):
  submit.sh submits the other point and the collect job, records the refusal, exits 4.
Plus refusals at generation by what sinfo and `sbatch --test-only` say. The test skips, with the
script's one line, only where slurm-wlm and munge cannot be installed (not root, no apt-get).
"""
import json
import os
import re
import socket
import subprocess
import time

import pandas as pd
import pytest

from tests.helpers import ROOT, bench, one_line_error

CLUSTER = os.path.join(ROOT, "tests", "bench", "slurm", "cluster.sh")
SCENE = ["--scene", "packed", "--particles", "300"]
FINAL = ("COMPLETED", "FAILED", "TIMEOUT", "CANCELLED", "NODE_FAIL", "OUT_OF_MEMORY", "BOOT_FAIL", "DEADLINE")


@pytest.fixture(scope="session")
def slurm_cluster(tmp_path_factory):
    """A running single-node Slurm for the session (SLURM_CONF points at it); stopped at the end,
    by the PIDs its start recorded."""
    state = str(tmp_path_factory.mktemp("slurm"))
    t0 = time.time()
    res = subprocess.run(["bash", CLUSTER, "start", state], capture_output=True, text=True, timeout=1200)
    if res.returncode == 3:
        pytest.skip(res.stderr.strip().splitlines()[-1])
    logs = ""
    for f in ("slurmctld.log", "slurmd.log"):
        p = os.path.join(state, "log", f)
        if os.path.exists(p):
            logs += f"\n--- {f}\n" + open(p).read()[-3000:]
    assert res.returncode == 0, res.stdout + res.stderr + logs
    print(f"slurm cluster started in {time.time() - t0:.0f} s: {res.stdout.strip()}")
    old = os.environ.get("SLURM_CONF")
    os.environ["SLURM_CONF"] = os.path.join(state, "slurm.conf")
    yield state
    stop = subprocess.run(["bash", CLUSTER, "stop", state], capture_output=True, text=True, timeout=300)
    print(stop.stdout + stop.stderr)
    if old is None:
        os.environ.pop("SLURM_CONF", None)
    else:
        os.environ["SLURM_CONF"] = old


def job_state(job_id):
    out = subprocess.run(["scontrol", "show", "job", "-o", str(job_id)], capture_output=True, text=True).stdout
    m = re.search(r"JobState=(\S+)", out)
    return m[1] if m else None


def wait_for(job_ids, limit=900):
    """Wait until Slurm reports every job final (or it left the queue)."""
    deadline = time.time() + limit
    while time.time() < deadline:
        states = [job_state(j) for j in job_ids]
        if all(s is None or s in FINAL for s in states):
            return states
        time.sleep(2)
    raise AssertionError(f"jobs {job_ids} not finished after {limit} s: {states}; "
                         + subprocess.run(["squeue"], capture_output=True, text=True).stdout)


def status_rows(text):
    """{(mapping, rep): (state, reason)} from `bench sweep --status` output."""
    rows = {}
    for line in text.splitlines():
        m = re.match(r"(\d+-\d+-\d+-\d+-\d+)(?: (\w+))?\s+(rep\d+)\s+(\S+)\s+(\S+)\s+(\S+)\s*(.*)$", line)
        if m:
            rows[(m[1], m[3])] = (m[5], m[7].strip())
    return rows


@pytest.fixture(scope="module")
def sweeps(slurm_cluster, tmp_path_factory):
    """Submit sweeps A, B and C (relative --out, from their parent folder), look at A at once,
    cancel C, wait for A's and B's collect jobs."""
    base = tmp_path_factory.mktemp("sweeps")
    t0 = time.time()
    got = {"base": base}
    got["submit_a"] = bench("sweep", *SCENE, "--steps", "10", "--warmup", "2", "--mappings", "1-1-1-1-2,2-2-1-1-1",
                            "--launcher", "slurm", "--time", "10", "--out", "A", cwd=str(base))
    got["status_a_early"] = bench("sweep", "--status", str(base / "A"))
    got["collect_a_early"] = bench("collect", str(base / "A"))
    got["again_a_early"] = bench("sweep", *SCENE, "--steps", "10", "--warmup", "2", "--mappings", "1-1-1-1-2,2-2-1-1-1",
                                 "--launcher", "slurm", "--time", "10", "--out", "A", cwd=str(base))
    got["submit_b"] = bench("sweep", *SCENE, "--steps", "2000000", "--mappings", "2-2-1-1-1", "--launcher", "slurm",
                            "--time", "1", "--mpi", "none", "--out", "B", cwd=str(base))
    got["submit_c"] = bench("sweep", *SCENE, "--steps", "10", "--mappings", "1-1-1-1-1", "--launcher", "slurm",
                            "--time", "5", "--out", "C", cwd=str(base))
    got["cancel_c"] = bench("sweep", "--cancel", str(base / "C"))
    for name in ("A", "B"):
        assert (base / name / "jobs.json").exists(), got[f"submit_{name.lower()}"].stderr
    ids = [json.loads((base / n / "jobs.json").read_text())["collect"]["job_id"] for n in ("A", "B")]
    got["collect_states"] = wait_for(ids)
    got["seconds"] = time.time() - t0
    print(f"sweeps A and B done in {got['seconds']:.0f} s")
    return got


def test_sweep_a_runs_every_point_under_slurm(sweeps):
    """A: 3 points (serial, 1-1-1-1-2 dynamic, 2-2-1-1-1 through srun --mpi=pmi2) pending or
    running right after submission (collect then exits 4, the same sweep again is refused);
    afterwards all 3 done on this node, the
    collect job's runs.csv has speedup 1.0 for serial, S = T1/T for the others and err_max 0 for
    all (bit-identical under Slurm too), and the manifest names this node's CPU model and count."""
    base = sweeps["base"]
    a = base / "A"
    sub = sweeps["submit_a"]
    assert sub.returncode == 0, sub.stderr
    assert "submitted the prepare job, 3 point job(s) and the collect job" in sub.stdout
    early = status_rows(sweeps["status_a_early"].stdout)
    assert len(early) == 3 and {s for s, _ in early.values()} <= {"pending", "running"}, sweeps["status_a_early"].stdout
    assert sweeps["collect_a_early"].returncode == 4
    # the same sweep again while its jobs are queued: refused (nothing submitted twice)
    one_line_error(sweeps["again_a_early"], "repeat(s) still pending or running", "--cancel", "--resume")
    assert sweeps["collect_states"][0] == "COMPLETED"
    res = bench("sweep", "--status", str(a))
    assert res.returncode == 0, res.stderr
    rows = status_rows(res.stdout)
    host = socket.gethostname().split(".")[0]
    assert rows == {("1-1-1-1-1", "rep0"): ("done", ""), ("1-1-1-1-2", "rep0"): ("done", ""),
                    ("2-2-1-1-1", "rep0"): ("done", "")}, res.stdout
    assert "prepare job" in res.stdout and re.search(r"prepare job \d+: done", res.stdout)
    assert re.search(r"collect job \d+: done", res.stdout) and "3 done" in res.stdout
    runs = pd.read_csv(a / "runs.csv", keep_default_na=False)  # written by the collect job
    assert runs["mapping"].tolist() == ["1-1-1-1-1", "1-1-1-1-2", "2-2-1-1-1"]
    assert (runs["status"] == "done").all() and runs.loc[1, "scheme"] == "dynamic"
    assert runs.loc[0, "speedup"] == 1.0
    assert runs["speedup"].tolist() == pytest.approx((runs.loc[0, "totalT"] / runs["totalT"]).tolist(), rel=1e-12)
    assert (runs["err_max"] == 0).all() and (runs["particles"] == 300).all() and (runs["steps"] == 10).all()
    assert (runs["load_before"] >= 0).all()
    for fig in ("speedup.png", "efficiency.png", "edsf.png", "modules.png", "error_vs_time.png"):
        assert (a / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    man = json.loads((a / "manifest.json").read_text())
    model = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    assert man["launcher"] == "slurm" and man["cpu_model"] == model and man["cpu_count"] == os.cpu_count()
    assert list(man["nodes"]) == [host] and man["mpi_library"].startswith("MPICH")
    assert man["numba_threading_layer"] and "collected" in man
    # the job ids: jobs.json, each point's job.json and each repeat's (the job itself wrote status.json)
    jobs = json.loads((a / "jobs.json").read_text())
    assert len(jobs["points"]) == 3 and jobs["prepare"]["job_id"] and jobs["collect"]["job_id"]
    for key, job in jobs["points"].items():
        assert json.loads((a / key / "job.json").read_text())["job_id"] == job["job_id"]
        st = json.loads((a / key / "rep0" / "status.json").read_text())
        assert st["job_id"] == f"{job['job_id']}_0" == json.loads((a / key / "rep0" / "job.json").read_text())["job_id"]
        assert st["node"] == host and st["status"] == "done"
    mpi = runs.loc[2, "point"]
    run = json.loads((a / mpi / "rep0" / "run.json").read_text())
    assert run["procs"] == 2 and "srun --mpi=pmi2 --ntasks=2" in (a / mpi / "rep0" / "cmd.txt").read_text()
    steps = pd.read_csv(a / mpi / "rep0" / "steps.csv")
    assert sorted(steps["rank"].unique()) == [0, 1] and len(steps) == 20
    # the prepare job compiled the kernels of both thread counts before the points ran
    prep = json.loads((a / "prepare" / "prepare.json").read_text())
    assert {(c["threads"], c["scheme"]) for c in prep["compiled"]} == {(1, ""), (2, "dynamic")}
    # collecting again from here gives the same rows and exit 0
    res = bench("collect", str(a))
    assert res.returncode == 0, res.stdout + res.stderr
    again = pd.read_csv(a / "runs.csv", keep_default_na=False)
    assert again["totalT"].tolist() == runs["totalT"].tolist()


def test_sweep_b_failures_are_named(sweeps):
    """B: the serial point killed at its 1-minute Slurm time limit is `timeout`; the 2-rank point
    under --mpi none (two 1-rank runs) is `failed` with the rank's own line; collect exits 4 and
    prints both; the collect job itself completed."""
    b = sweeps["base"] / "B"
    assert sweeps["submit_b"].returncode == 0, sweeps["submit_b"].stderr
    assert sweeps["collect_states"][1] == "COMPLETED"
    rows = status_rows(bench("sweep", "--status", str(b)).stdout)
    assert rows[("1-1-1-1-1", "rep0")] == ("timeout", "killed at Slurm's time limit (00:01:00)")
    assert rows[("2-2-1-1-1", "rep0")] == ("failed", "bench: error: started with 1 ranks for mapping 2-2-1-1-1")
    res = bench("collect", str(b))
    assert res.returncode == 4
    assert "point 1-1-1-1-1: timeout (killed at Slurm's time limit (00:01:00))" in res.stdout
    assert "point 2-2-1-1-1: failed (bench: error: started with 1 ranks for mapping 2-2-1-1-1)" in res.stdout
    runs = pd.read_csv(b / "runs.csv", keep_default_na=False)
    assert runs["status"].tolist() == ["timeout", "failed"]


def test_sweep_c_cancelled(sweeps):
    """C: `bench sweep --cancel` right after submission scancels its 3 jobs; every repeat, the
    prepare and the collect job read `cancelled`; collect exits 4."""
    c = sweeps["base"] / "C"
    assert sweeps["submit_c"].returncode == 0, sweeps["submit_c"].stderr
    assert re.search(r"cancelled 3 job\(s\)", sweeps["cancel_c"].stdout), sweeps["cancel_c"].stdout
    res = bench("sweep", "--status", str(c))
    assert status_rows(res.stdout)[("1-1-1-1-1", "rep0")][0] == "cancelled"
    assert re.search(r"prepare job \d+: cancelled", res.stdout) and re.search(r"collect job \d+: cancelled", res.stdout)
    res = bench("collect", str(c))
    assert res.returncode == 4 and "point 1-1-1-1-1: cancelled" in res.stdout


def test_resume_submits_only_the_new_repeats(sweeps):
    """A again with --repeats 2 --resume: only repeat 1 of each of the 3 points is submitted (array
    task 1), repeat 0 keeps its files; after its collect job every point has 2 repeats done; a
    second --resume submits nothing."""
    a = sweeps["base"] / "A"
    before = {k: (a / k / "rep0" / "status.json").read_text()
              for k in json.loads((a / "jobs.json").read_text())["points"]}
    args = [*SCENE, "--steps", "10", "--warmup", "2", "--mappings", "1-1-1-1-2,2-2-1-1-1", "--launcher", "slurm",
            "--time", "10", "--repeats", "2", "--resume", "--out", str(a)]
    res = bench("sweep", *args)
    assert res.returncode == 0, res.stderr
    assert "wrote 3 point job script(s) (3 repeat(s))" in res.stdout
    jobs = json.loads((a / "jobs.json").read_text())
    assert all(j["tasks"] == [1] for j in jobs["points"].values())
    for key in before:
        assert "#SBATCH --array=1\n" in (a / key / "job.sbatch").read_text()
    wait_for([jobs["collect"]["job_id"]])
    for key, text in before.items():
        assert (a / key / "rep0" / "status.json").read_text() == text  # never run again
    runs = pd.read_csv(a / "runs.csv", keep_default_na=False)
    assert (runs["status"] == "done").all() and (runs["repeats"] == 2).all() and (runs["err_max"] == 0).all()
    res = bench("sweep", *args)
    assert res.returncode == 0 and "nothing to submit" in res.stdout


def test_refused_by_the_cluster_at_generation(slurm_cluster, tmp_path):
    """Checked with the cluster before anything is submitted: 2 ranks x 2 threads need 4 CPUs on a
    node that has fewer (sinfo); an unknown partition (sbatch --test-only). One line, exit 2, no
    job script written."""
    cpus = int(subprocess.run(["sinfo", "-h", "-o", "%c"], capture_output=True, text=True).stdout.split()[0])
    t = cpus  # 2 ranks x cpus threads never fit on one node of `cpus` CPUs
    one_line_error(bench("sweep", *SCENE, "--steps", "10", "--mappings", f"2-2-1-1-{t}", "--launcher", "slurm",
                         "--out", str(tmp_path / "big")),
                   f"mapping 2-2-1-1-{t} needs {2 * t} CPUs on a node", f"at most {cpus} (sinfo)")
    one_line_error(bench("sweep", *SCENE, "--steps", "10", "--mappings", "1-1-1-1-1", "--launcher", "slurm",
                         "--partition", "nosuch", "--out", str(tmp_path / "part")),
                   "sbatch --test-only refuses prepare.sbatch", "invalid partition")
    assert not list(tmp_path.rglob("*.sbatch"))


def test_submit_goes_on_past_a_refused_job(slurm_cluster, tmp_path):
    """D: `--no-submit` writes the scripts; the serial point's job.sbatch then names a partition
    that does not exist. bash submit.sh: sbatch refuses that one job, submits the prepare, the
    2-thread point and the collect job, records the refusal in jobs.json and the point's job.json,
    and exits 4; --status shows the refused point failed with sbatch's message. Then --cancel."""
    d = tmp_path / "D"
    res = bench("sweep", *SCENE, "--steps", "10", "--mappings", "1-1-1-1-2", "--launcher", "slurm", "--time", "5",
                "--no-submit", "--out", str(d))
    assert res.returncode == 0 and "submit them with: bash" in res.stdout, res.stdout + res.stderr
    assert not (d / "jobs.json").exists()
    serial = next(p for p in os.listdir(d) if p.startswith("1-1-1-1-1-"))
    script = d / serial / "job.sbatch"
    script.write_text(script.read_text().replace("#SBATCH --time=5\n",
                                                 "#SBATCH --time=5\n#SBATCH --partition=nosuch\n"))
    sub = subprocess.run(["bash", str(d / "submit.sh")], capture_output=True, text=True, timeout=120)
    assert sub.returncode == 4, sub.stdout + sub.stderr
    assert f"sbatch refused {serial}/job.sbatch" in sub.stderr and "(1 refused)" in sub.stdout
    jobs = json.loads((d / "jobs.json").read_text())
    assert jobs["prepare"]["job_id"] and jobs["collect"]["job_id"]
    assert jobs["points"][serial]["job_id"] is None and "invalid partition" in jobs["points"][serial]["error"]
    threads = next(k for k in jobs["points"] if k != serial)
    assert jobs["points"][threads]["job_id"] and jobs["points"][threads]["tasks"] == [0]
    assert json.loads((d / serial / "job.json").read_text())["job_id"] is None
    rows = status_rows(bench("sweep", "--status", str(d)).stdout)
    state, reason = rows[("1-1-1-1-1", "rep0")]
    assert state == "failed" and reason.startswith("sbatch refused the job:") and "invalid partition" in reason
    assert rows[("1-1-1-1-2", "rep0")][0] in ("pending", "running", "done")
    res = bench("sweep", "--cancel", str(d))
    assert res.returncode == 0, res.stderr
