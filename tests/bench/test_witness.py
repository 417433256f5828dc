"""The witness of a rank (bench.run.witness) and how the supervisor names a rank that died from it.

Regression: CI once saw `bench run` name rank 0 when rank 1 had been killed (SIGKILL). Hydra's
proxy kills the other ranks at once and its banner names the first process of the proxy with a
bad status, rank 0 whenever the proxy has reaped it before reporting. The supervisor now names the
rank its witness saw die first; here a fake starter plays the race on purpose.
"""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from bench.run.witness import describe_status, read_ends

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))


def test_describe_status_reads_wait_statuses():
    """waitpid(2) encodes a death by signal s as s (+128 when it dumped core) and exit(n) as n << 8:
    9 -> Killed, 139 -> SIGSEGV with core, 768 -> exit code 3, 256 -> exit code 1 (MPI_Abort's)."""
    assert describe_status(9) == "Killed (signal 9)"
    assert describe_status(139) == "Segmentation fault (signal 11, core dumped)"
    assert describe_status(768) == "exit code 3"
    assert describe_status(256) == "exit code 1"


def _witness(out, code, **kw):
    return subprocess.Popen([sys.executable, "-m", "bench.run.witness", "--out", str(out), "--",
                             sys.executable, "-c", code], env=dict(ENV, PMI_RANK="3"), **kw)


@pytest.mark.parametrize("code, status, rc", [
    ("import os, signal; os.kill(os.getpid(), signal.SIGKILL)", 9, -9),
    ("import sys; sys.exit(3)", 768, 3),
    ("pass", None, 0),
])
def test_witness_records_a_bad_end_and_ends_alike(tmp_path, code, status, rc):
    """A rank killed (SIGKILL) or ending with exit status 3 leaves one record with its wait status
    (9, 768) and the rank of the starter's environment (PMI_RANK=3), and its witness ends the same
    way (-9: killed by signal 9; 3), as the starter must see; a clean end (0) leaves no record."""
    p = _witness(tmp_path, code)
    assert p.wait(timeout=60) == rc
    ends = read_ends(str(tmp_path))
    if status is None:
        assert ends == []
    else:
        assert len(ends) == 1 and ends[0]["status"] == status and ends[0]["rank"] == 3 and ends[0]["pid"] != p.pid


def test_witness_forwards_sigterm(tmp_path):
    """SIGTERM sent to the witness (as Hydra and srun send it to the process they started) reaches
    the rank, whose handler writes a file and ends cleanly: exit 0 and no record."""
    flag = tmp_path / "got"
    code = textwrap.dedent(f"""
        import signal, sys, time
        signal.signal(signal.SIGTERM, lambda s, f: (open({str(flag)!r}, "w").write(str(s)), sys.exit(0)))
        open({str(flag)!r} + ".ready", "w").close()
        time.sleep(60)
    """)
    p = _witness(tmp_path, code)
    t0 = time.time()
    while not (tmp_path / "got.ready").exists():
        assert time.time() - t0 < 60 and p.poll() is None
        time.sleep(0.05)
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=30) == 0
    assert flag.read_text() == str(int(signal.SIGTERM)) and read_ends(str(tmp_path)) == []


def test_witness_killed_takes_its_rank_and_writes_nothing(tmp_path):
    """A witness killed by SIGKILL (the starter's clean-up) writes no record, and its rank ends
    within seconds (PR_SET_PDEATHSIG), so no process is left."""
    code = "import os, time; open('pid', 'w').write(str(os.getpid())); time.sleep(60)"
    p = _witness(tmp_path, code, cwd=str(tmp_path))
    t0 = time.time()
    while not (tmp_path / "pid").exists() or not (tmp_path / "pid").read_text():
        assert time.time() - t0 < 60
        time.sleep(0.05)
    child = int((tmp_path / "pid").read_text())
    p.kill()
    p.wait(timeout=30)
    t0 = time.time()
    while os.path.exists(f"/proc/{child}") and open(f"/proc/{child}/stat").read().split()[2] != "Z":
        assert time.time() - t0 < 10, "the rank outlived its witness"
        time.sleep(0.05)
    assert read_ends(str(tmp_path)) == []


# A fake starter for 2 ranks, each under its witness with a heartbeat at step 7. It kills rank 1
# (SIGKILL); with `race` it then kills rank 0's witness at once, as Hydra's clean-up does, prints
# Hydra's banner naming rank 0's pid (what CI saw) and exits 9; without it, it waits for the
# supervisor to stop it (a starter that does not clean up).
STARTER = textwrap.dedent("""
    import json, os, signal, subprocess, sys, time
    out, race = sys.argv[1], sys.argv[2] == "race"
    rank = ("import sys, time; from bench.run.heartbeat import Heartbeat; "
            "b = Heartbeat(sys.argv[1], int(sys.argv[2])); b.phase = 'running'; b.step = 7; b._write(); "
            "time.sleep(120)")
    ws = [subprocess.Popen([sys.executable, "-m", "bench.run.witness", "--out", out, "--", sys.executable, "-c",
                            rank, out, str(r)], env=dict(os.environ, PMI_RANK=str(r))) for r in range(2)]
    pids = {}
    while len(pids) < 2:
        for r in range(2):
            try:
                beat = json.load(open(os.path.join(out, ".ranks", f"rank{r}.json")))
                if beat["step"] == 7:
                    pids[r] = beat["pid"]
            except (OSError, ValueError):
                pass
        time.sleep(0.05)
    os.kill(pids[1], signal.SIGKILL)
    if not race:
        time.sleep(120)
    ws[1].wait()
    ws[0].kill()
    ws[0].wait()
    print("=" * 83)
    print("=   BAD TERMINATION OF ONE OF YOUR APPLICATION PROCESSES")
    print(f"=   PID {pids[0]} RUNNING AT {os.uname().nodename}")
    print("=   EXIT CODE: 9")
    print("=" * 83)
    print("YOUR APPLICATION TERMINATED WITH THE EXIT STRING: Killed (signal 9)", flush=True)
    sys.exit(9)
""")


@pytest.mark.parametrize("race", ["race", "wait"])
def test_supervisor_names_the_rank_that_died_first(tmp_path, race):
    """Rank 1 is killed (SIGKILL) at step 7. race: the starter then kills rank 0 too and its banner
    names rank 0; wait: the starter does nothing more. Either way the supervisor's one line names
    rank 1 with its pid and `Killed (signal 9)`, exit 5, within 30 s, and run.json says `failed`."""
    starter = tmp_path / "starter.py"
    starter.write_text(STARTER)
    out = tmp_path / "d"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"status": "running"}))
    t0 = time.time()
    p = subprocess.run([sys.executable, "-m", "bench.run.supervise", "--out", str(out), "--procs", "2",
                        "--timeout", "100", "--", sys.executable, str(starter), str(out), race],
                       capture_output=True, text=True, env=ENV, timeout=120)
    took = time.time() - t0
    assert p.returncode == 5, p.stderr
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    assert len(lines) == 1, p.stderr
    pid1 = json.loads((out / ".ranks" / "rank1.json").read_text())["pid"]
    assert (lines[0].startswith(f"bench: error: rank 1 (pid {pid1} on ")
            and "died at step 7: Killed (signal 9)" in lines[0])
    assert took < 30, f"took {took:.1f} s"
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "failed" and f"rank 1 (pid {pid1}" in run["reason"]


def test_supervisor_ignores_an_earlier_runs_records(tmp_path):
    """A resumed point reuses its folder: a record left by the interrupted run before it (rank 1,
    SIGKILL) must not end the new run, which exits 0 with nothing on stderr (CI caught a resumed
    sweep stopped at once this way)."""
    out = tmp_path / "d"
    (out / ".ranks").mkdir(parents=True)
    (out / ".ranks" / "end.12345.json").write_text(json.dumps({"pid": 12345, "rank": 1, "status": 9, "t": time.time()}))
    p = subprocess.run([sys.executable, "-m", "bench.run.supervise", "--out", str(out), "--procs", "2",
                        "--timeout", "100", "--", sys.executable, "-c", "import time; time.sleep(1.0)"],
                       capture_output=True, text=True, env=ENV, timeout=120)
    assert p.returncode == 0 and p.stderr == "", p.stderr
    assert read_ends(str(out)) == []
