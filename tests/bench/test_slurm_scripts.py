"""`bench sweep --launcher slurm` without a cluster: the job scripts it writes for given options
(sweep file and flags), the --mpi choice, the job array over repeats, submit.sh's dependencies,
the refusals at generation, and the parsers of what Slurm prints (scontrol output as a real
Slurm 22.05 printed it). The end-to-end run on a real Slurm is tests/bench/test_slurm_cluster.py.

These runs hide Slurm: PATH holds only an empty folder (the commands bench calls here are the
Python itself and Slurm's), so they behave as on a machine without Slurm even where it is
installed: nothing is submitted, sinfo cannot tell the partition's CPUs.
"""
import json
import os
import re
import subprocess
import sys

import pytest

from tests.helpers import ROOT, one_line_error

SMALL = ["--scene", "pluviation", "--particles", "200", "--steps", "10"]


def bench_noslurm(tmp_path, *args, cwd=None):
    """`python -m bench ...` with no Slurm command on PATH."""
    empty = tmp_path / "empty-bin"
    empty.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM")}
    env.update(PATH=str(empty), PYTHONPATH=ROOT)
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=300, env=env)


def scripts(out):
    """{point mapping[-scheme]: job.sbatch text} of a generated sweep."""
    found = {}
    for d in sorted(os.listdir(out)):
        f = out / d / "job.sbatch"
        if f.exists():
            text = f.read_text()
            found[re.search(r"--job-name=dem-(\S+)", text)[1]] = text
    return found


SWEEP_FILE = """
[sweep]
mappings = ["1-1-1-1-2", "2-2-1-1-1"]
schemes = ["frogleap"]
scene = "pluviation"
particles = 200
steps = 10
repeats = 3
launcher = "slurm"
out = "rel/sweep"

[sweep.slurm]
partition = "short"
account = "proj42"
qos = "normal"
time = "0:20:00"
mem = "4G"
ntasks_per_node = 1
exclusive = true
constraint = "avx2"
hint = "nomultithread"
mpi = "pmi2"
extra = ["#SBATCH --mail-type=NONE", "#SBATCH --comment=bench"]
"""


def test_sweep_file_options_reach_every_job(tmp_path):
    """A sweep file's [sweep.slurm] table with every option, a flag overriding one (--time 15), a
    relative --out: absolute --chdir/--output and REP paths; partition, account, qos, time, mem,
    constraint and the 2 extra lines on all 5 jobs (prepare, 3 points, collect); exclusive and
    hint on the 3 points only; the MPI point on 2 nodes of 1 rank (ntasks_per_node = 1), the others
    on 1; repeats 3 as --array=0-2; job names with the scheme; nothing submitted without sbatch."""
    (tmp_path / "sweep.toml").write_text(SWEEP_FILE)
    res = bench_noslurm(tmp_path, "sweep", "--file", "sweep.toml", "--time", "15", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "no sbatch here" in res.stdout and "sinfo cannot tell" in res.stdout
    out = tmp_path / "rel" / "sweep"
    jobs = scripts(out)
    assert sorted(jobs) == ["1-1-1-1-1", "1-1-1-1-2-frogleap", "2-2-1-1-1"]
    every = [(out / "prepare.sbatch").read_text(), (out / "collect.sbatch").read_text(), *jobs.values()]
    for text in every:
        for line in ("#SBATCH --partition=short", "#SBATCH --account=proj42", "#SBATCH --qos=normal",
                     "#SBATCH --time=15", "#SBATCH --mem=4G", "#SBATCH --constraint=avx2",
                     "#SBATCH --mail-type=NONE", "#SBATCH --comment=bench", f"#SBATCH --chdir={out}"):
            assert line in text.splitlines(), (line, text)
        assert re.search(rf"#SBATCH --output={re.escape(str(out))}/\S+/slurm-%[jA]", text), text
    for name, text in jobs.items():
        assert "#SBATCH --exclusive" in text and "#SBATCH --hint=nomultithread" in text
        assert "#SBATCH --array=0-2" in text
        assert f'REP={out}/{text.split(str(out) + "/")[1].split("/")[0]}/rep"${{SLURM_ARRAY_TASK_ID:-0}}"' in text
        assert '--out "$REP"' in text
    for text in every[:2]:
        assert "--exclusive" not in text and "--hint" not in text and "--array" not in text
    mpi, threads, serial = jobs["2-2-1-1-1"], jobs["1-1-1-1-2-frogleap"], jobs["1-1-1-1-1"]
    assert "#SBATCH --nodes=2" in mpi and "#SBATCH --ntasks=2" in mpi and "#SBATCH --ntasks-per-node=1" in mpi
    assert "#SBATCH --nodes=1" in threads and "#SBATCH --cpus-per-task=2" in threads
    assert "export NUMBA_NUM_THREADS=2" in threads and "export OMP_NUM_THREADS=2" in threads
    assert "srun --ntasks=1 --cpus-per-task=2 --cpu-bind=cores" in threads and "--scheme frogleap" in threads
    assert "srun --ntasks=1 --cpus-per-task=1 --cpu-bind=cores" in serial
    assert ("--mpi-starter 'srun --mpi=pmi2 --ntasks=2 --cpus-per-task=1 --cpu-bind=cores "
            "--distribution=block:block'" in mpi)
    assert "-m bench.sweep.job point \"$REP\" --timeout 1800 --" in mpi
    # the prepare job compiles for the largest thread count, passively waiting
    prep = (out / "prepare.sbatch").read_text()
    assert "export NUMBA_NUM_THREADS=2" in prep and "export OMP_WAIT_POLICY=PASSIVE" in prep
    assert f"-m bench.sweep.job prepare {out}" in prep
    man = json.loads((out / "manifest.json").read_text())
    assert man["launcher"] == "slurm" and man["repeats"] == 3 and man["slurm"]["time"] == "15"
    assert man["slurm"]["partition"] == "short" and man["cpu_model"] is None and "cpu_model" in man["submit_host"]
    assert not (out / "jobs.json").exists() and not list(out.rglob("job.json"))


def test_relative_scene_file_becomes_absolute(tmp_path):
    """A scene given as a relative .toml path (run from its folder) reaches every job as an
    absolute path (the jobs run in DIR, not where bench sweep ran)."""
    import shutil
    from dem.scene import BUILTIN_DIR
    shutil.copy(os.path.join(BUILTIN_DIR, "pluviation.toml"), tmp_path / "my.toml")
    res = bench_noslurm(tmp_path, "sweep", "--scene", "my.toml", "--particles", "200", "--steps", "10",
                        "--mappings", "2-2-1-1-1", "--launcher", "slurm", "--out", "o", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    jobs = scripts(tmp_path / "o")
    assert len(jobs) == 2 and all(f"--scene {tmp_path / 'my.toml'} " in t for t in jobs.values())
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert {p["scene"] for p in man["points"]} == {str(tmp_path / "my.toml")}


def test_submit_script_dependencies_and_records(tmp_path):
    """submit.sh: the prepare job first, each point after it (afterany), the collect job after all
    point jobs (afterany); no `set -e` (a refused job does not stop the rest); job ids go to
    jobs.json, each point's job.json and each repeat's job.json (array task ids)."""
    res = bench_noslurm(tmp_path, "sweep", *SMALL, "--mappings", "2-2-1-1-1", "--launcher", "slurm",
                        "--repeats", "2", "--out", str(tmp_path / "s"))
    assert res.returncode == 0, res.stderr
    sh = (tmp_path / "s" / "submit.sh").read_text()
    assert "set -e" not in sh and "sbatch --parsable ${2:+--dependency=$2}" in sh
    assert sh.index("submit prepare.sbatch") < sh.index("/job.sbatch \"$dep\"") < sh.index("submit collect.sbatch")
    assert 'dep=${id:+afterany:$id}' in sh and 'submit collect.sbatch "afterany:$(IFS=:; echo "${points[*]}")"' in sh
    assert sh.count('/job.sbatch "$dep"') == 2 and "'\"tasks\": [0, 1], '" in sh
    assert ">jobs.json.tmp && mv jobs.json.tmp jobs.json" in sh and '"$key/rep$t/job.json"' in sh
    assert subprocess.run(["bash", "-n", str(tmp_path / "s" / "submit.sh")]).returncode == 0  # valid bash


def test_hybrid_point_job(tmp_path):
    """A hybrid point 4-2-2-1-3 with --pin: 4 tasks of 3 CPUs, its ranks started by srun with the
    same counts and core binding, and on a node that gives it fewer than 12 CPUs the OpenMP threads
    wait passively and mpich's progress throttle is on (bench.run.transport SHARED_CORES; a user's
    own value stands); the 3 threads are bound by each rank itself (bench run --pin,
    bench.run.binding), so the job exports no OMP_PROC_BIND, which would pin its launching
    process to one CPU and every rank with it."""
    res = bench_noslurm(tmp_path, "sweep", *SMALL, "--mappings", "1-1-1-1-2,4-2-2-1-3", "--launcher", "slurm",
                        "--pin", "--out", str(tmp_path / "s"))
    assert res.returncode == 0, res.stderr
    jobs = scripts(tmp_path / "s")
    assert sorted(jobs) == ["1-1-1-1-1", "1-1-1-1-2-dynamic", "4-2-2-1-3-dynamic"]
    hybrid = jobs["4-2-2-1-3-dynamic"]
    assert "#SBATCH --ntasks=4" in hybrid and "#SBATCH --cpus-per-task=3" in hybrid and "#SBATCH --nodes=1" in hybrid
    assert ("--mpi-starter 'srun --mpi=pmi2 --ntasks=4 --cpus-per-task=3 --cpu-bind=cores "
            "--distribution=block:block'" in hybrid)
    for line in ("export NUMBA_NUM_THREADS=3", "export OMP_NUM_THREADS=3"):
        assert line in hybrid.splitlines()
    assert "OMP_PROC_BIND" not in hybrid and "OMP_PLACES" not in hybrid
    assert ('if [ $((4 * 3)) -gt "${SLURM_CPUS_ON_NODE:-12}" ]; then export OMP_WAIT_POLICY=PASSIVE; '
            'export MPIR_CVAR_CH4_PROGRESS_THROTTLE="${MPIR_CVAR_CH4_PROGRESS_THROTTLE:-1}"; '
            'export MPIR_CVAR_CH4_PROGRESS_THROTTLE_NO_PROGRESS_COUNT='
            '"${MPIR_CVAR_CH4_PROGRESS_THROTTLE_NO_PROGRESS_COUNT:-100}"; fi') in hybrid
    assert "--pin" in hybrid and "--mapping 4-2-2-1-3" in hybrid and "--scheme dynamic" in hybrid
    assert not (tmp_path / "s" / "runs.csv").exists()


@pytest.mark.parametrize("mpi,starter", [
    ("hydra", "--mpi-starter '{bin}/mpiexec -n 2 -bind-to core:1'"),
    ("pmix", "--mpi-starter 'srun --mpi=pmix --ntasks=2 --cpus-per-task=1 --cpu-bind=cores "
             "--distribution=block:block'"),
])
def test_mpi_choice(tmp_path, mpi, starter):
    """--mpi hydra: the Python's own mpiexec inside the allocation, with SLURM_MPI_TYPE=none
    exported; any other value: srun --mpi=<value>."""
    res = bench_noslurm(tmp_path, "sweep", *SMALL, "--mappings", "2-2-1-1-1", "--launcher", "slurm",
                        "--mpi", mpi, "--out", str(tmp_path / "s"))
    assert res.returncode == 0, res.stderr
    text = scripts(tmp_path / "s")["2-2-1-1-1"]
    assert starter.format(bin=os.path.dirname(sys.executable)) in text
    assert ("export SLURM_MPI_TYPE=none" in text) == (mpi == "hydra")
    assert "SLURM_MPI_TYPE" not in scripts(tmp_path / "s")["1-1-1-1-1"]


def test_dry_run_prints_every_script_and_writes_none(tmp_path):
    res = bench_noslurm(tmp_path, "sweep", *SMALL, "--mappings", "1-1-1-1-2", "--launcher", "slurm", "--dry-run",
                        "--out", str(tmp_path / "d"))
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("# ---- ") == 5  # prepare, collect, 2 points, submit.sh
    assert not (tmp_path / "d" / "submit.sh").exists() and not list((tmp_path / "d").rglob("*.sbatch"))


@pytest.mark.parametrize("args,words", [
    (["--mappings", "16-16-1-1-1"], "mapping 16-16-1-1-1: blocks are"),
    (["--mappings", "2-2-1-1-1", "--nodes", "4"], "slurm.nodes = 4 but mapping 2-2-1-1-1 has only 2 ranks"),
    (["--mappings", "2-2-1-1-1", "--time", "soon"], "slurm.time in --time must be minutes"),
    (["--mappings", "2-2-1-1-1", "--partition", "a b"], "slurm.partition in --partition must be one word"),
    (["--mappings", "2-2-1-1-1", "--mpi", "PMI 2"], "slurm.mpi in --mpi must be an srun --mpi type"),
    (["--mappings", "2-2-1-1-1", "--launcher", "pbs"], "unknown launcher 'pbs' (launchers: local, slurm)"),
    (["--mappings", "2-2-1-1-1", "--launcher", "local", "--partition", "x"],
     "Slurm options (partition) need --launcher slurm"),
])
def test_refused_at_generation_one_line_nothing_lost(tmp_path, args, words):
    """Refused before anything is written (one line, exit 2): blocks too narrow for the border
    layer (16 blocks along x of the 200-particle pluviation), nodes beyond the ranks, bad option
    values, an unknown launcher, Slurm options without the slurm launcher. An existing runs.csv
    stays as it was."""
    out = tmp_path / "keep"
    out.mkdir()
    (out / "runs.csv").write_text("precious\n")
    launcher = [] if "--launcher" in args else ["--launcher", "slurm"]
    one_line_error(bench_noslurm(tmp_path, "sweep", *SMALL, *launcher, *args, "--out", str(out)), words)
    assert (out / "runs.csv").read_text() == "precious\n" and sorted(os.listdir(out)) == ["runs.csv"]


@pytest.mark.parametrize("table,words", [
    ("exclusive = \"yes\"", "slurm.exclusive in {f} must be true or false, got 'yes'"),
    ("nodes = 0", "slurm.nodes in {f} must be a positive integer, got 0"),
    ("extra = [\"--mem=1G\"]", "slurm.extra in {f}: '--mem=1G' is not one '#SBATCH --option' line"),
    ("extra = \"#SBATCH --mem=1G\"", "slurm.extra in {f} must be a list"),
    ("time = 0", "slurm.time in {f} must be minutes"),
    ("partitions = \"x\"", "unknown Slurm option 'partitions' in {f}"),
    ("mpi = 2", "slurm.mpi in {f} must be a non-empty string, got 2"),
])
def test_bad_slurm_table_one_line(tmp_path, table, words):
    """Each bad [sweep.slurm] value: one line naming the field (and the file), exit 2."""
    f = tmp_path / "sweep.toml"
    f.write_text(f'[sweep]\nmappings = ["2-2-1-1-1"]\nscene = "pluviation"\nlauncher = "slurm"\n'
                 f'out = "{tmp_path / "o"}"\n\n[sweep.slurm]\n{table}\n')
    one_line_error(bench_noslurm(tmp_path, "sweep", "--file", str(f)), words.format(f=f))


def test_status_and_collect_without_slurm(tmp_path):
    """A Slurm sweep written but never submitted (no sbatch): --status says `unsubmitted` for each
    of its 2 points, collect records them so and exits 4; --cancel needs scancel (one line)."""
    out = tmp_path / "s"
    assert bench_noslurm(tmp_path, "sweep", *SMALL, "--mappings", "2-2-1-1-1", "--launcher", "slurm", "--out",
                         str(out)).returncode == 0
    res = bench_noslurm(tmp_path, "sweep", "--status", str(out))
    assert res.returncode == 0, res.stderr
    assert len(re.findall(r"rep0\s+-\s+unsubmitted", res.stdout)) == 2 and "2 unsubmitted" in res.stdout
    assert "prepare job -: unsubmitted" in res.stdout
    res = bench_noslurm(tmp_path, "collect", str(out))
    assert res.returncode == 4, res.stderr
    assert "collected 0 of 2 points" in res.stdout and "point 2-2-1-1-1: unsubmitted" in res.stdout
    one_line_error(bench_noslurm(tmp_path, "sweep", "--cancel", str(out)), "needs Slurm's scancel")
    one_line_error(bench_noslurm(tmp_path, "sweep", "--status", str(tmp_path / "nothing")), "not a sweep folder")


# --- what Slurm prints, parsed (lines as a Slurm 22.05 printed them) -----------------------------------

SCONTROL = (
    "JobId=7 ArrayJobId=6 ArrayTaskId=0 JobName=a.sh UserId=root(0) JobState=COMPLETED Reason=None "
    "Dependency=(null) ExitCode=0:0 RunTime=00:00:03 TimeLimit=UNLIMITED NodeList=vm BatchHost=vm\n"
    "JobId=6 ArrayJobId=6 ArrayTaskId=2-4 JobName=a.sh UserId=root(0) JobState=PENDING Reason=Dependency "
    "Dependency=afterany:5(unfulfilled) ExitCode=0:0 TimeLimit=00:01:00 NodeList=\n"
    "JobId=9 JobName=t.sh UserId=root(0) JobState=TIMEOUT Reason=TimeLimit ExitCode=0:15 "
    "TimeLimit=00:01:00 NodeList=vm\n")


def test_scontrol_records_and_array_tasks():
    """Task 0 of array 6 is COMPLETED (our `completed`), tasks 2-4 pending behind a dependency,
    task 1 unknown; job 9 timed out at its 1-minute limit; array specs are compressed ranges."""
    from bench.sweep.slurm import Record, Scheduler, array_spec, parse_scontrol, task_ids
    recs = parse_scontrol(SCONTROL)
    assert [r["JobId"] for r in recs] == ["7", "6", "9"]
    assert task_ids("2-4") == {2, 3, 4} and task_ids("0-8:4%2") == {0, 4, 8} and task_ids("1,3") == {1, 3}
    assert array_spec([0, 1, 2, 5, 7, 8]) == "0-2,5,7-8" and array_spec([3]) == "3"
    sched = Scheduler()
    sched._seen = {"6": recs[:2], "9": recs[2:]}
    assert sched.lookup("6_0").state == "completed" and sched.lookup("6_3").state == "pending"
    assert sched.lookup("6_3").reason == "Dependency" and sched.lookup("6_1") is None
    t = sched.lookup("9")
    assert (t.state == "timeout"
            and t.text() == "Slurm JobState=TIMEOUT Reason=TimeLimit ExitCode=0:15 TimeLimit=00:01:00")
    assert (Record({"JobState": "NODE_FAIL"}).state == "failed"
            and Record({"JobState": "CANCELLED"}).state == "cancelled")


def test_outcome_rules(tmp_path):
    """How a repeat's files and Slurm's word combine (bench.sweep.status.rep_outcome): a final
    status.json wins (done stays done even if Slurm says CANCELLED); Slurm's TIMEOUT wins over a
    `failed` the job wrote while being killed; `running` in the files with Slurm saying COMPLETED
    is a failure naming the job; a pending job shows Slurm's reason; sbatch's refusal is the reason."""
    from bench.sweep.slurm import Scheduler, parse_scontrol
    from bench.sweep.status import rep_outcome
    sched = Scheduler()
    sched._seen = {"6": parse_scontrol(SCONTROL)[:2], "9": parse_scontrol(SCONTROL)[2:]}

    def rep(name, status=None, job=None):
        d = tmp_path / name
        d.mkdir()
        if status:
            (d / "status.json").write_text(json.dumps(status))
        if job:
            (d / "job.json").write_text(json.dumps(job))
        return str(d)

    got = rep_outcome(rep("a", {"status": "done", "reason": ""}, {"job_id": "9"}), sched, True)
    assert (got["status"], got["job"]) == ("done", "9")
    got = rep_outcome(rep("b", {"status": "failed", "reason": "exit status -15"}, {"job_id": "9"}), sched, True)
    assert got["status"] == "timeout" and "TimeLimit=00:01:00" in got["reason"]
    got = rep_outcome(rep("c", {"status": "running", "reason": ""}, {"job_id": "6_0"}), sched, True)
    assert got["status"] == "failed" and got["reason"].startswith("job 6_0 ended without writing its outcome")
    got = rep_outcome(rep("d", None, {"job_id": "6_2"}), sched, True)
    assert (got["status"], got["reason"]) == ("pending", "Dependency")
    got = rep_outcome(rep("e", None, {"job_id": None, "error": "sbatch: error: invalid partition"}), sched, True)
    assert (got["status"], got["reason"]) == ("failed", "sbatch refused the job: sbatch: error: invalid partition")
    assert rep_outcome(rep("f"), sched, True)["status"] == "unsubmitted"
    assert rep_outcome(rep("g", None, {"job_id": "77_0"}), None, True)["status"] == "unknown"


def test_mpi_starter_of_bench_run(tmp_path):
    """`bench run --mpi-starter CMD` (what a Slurm job passes) starts the 2 ranks with CMD: here the
    Python's own mpiexec, named explicitly; the run's 2 ranks write 10 steps each. A starter that
    does not exist is one line, exit 2."""
    mpiexec = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    if not os.path.exists(mpiexec):
        import shutil
        mpiexec = shutil.which("mpiexec")
    out = tmp_path / "run"
    res = bench_noslurm(tmp_path, "run", *SMALL, "--mapping", "2-2-1-1-1", "--quiet", "--timeout", "600",
                        "--mpi-starter", f"{mpiexec} -n 2", "--out", str(out))
    assert res.returncode == 0, res.stderr
    run = json.loads((out / "run.json").read_text())
    assert run["procs"] == 2 and run["status"] == "done"
    assert (out / "steps.csv").read_text().count("\n") == 1 + 2 * 10
    one_line_error(bench_noslurm(tmp_path, "run", *SMALL, "--mapping", "2-2-1-1-1", "--mpi-starter",
                                 "no-such-starter -n 2", "--out", str(tmp_path / "bad")),
                   "--mpi-starter 'no-such-starter -n 2': no-such-starter not found")
