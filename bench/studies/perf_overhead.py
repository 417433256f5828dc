"""`bench perf --what overhead`: what the parallel machinery and the per-step bookkeeping cost.

Two figures of issue 11, measured by running `bench run` itself (the harness's own path, records
and all), alternating the configurations (A B A B ...), medians over the repeats:

- small: the fixed cost of a step on a 48-particle scene (pluviation, the paper's deposition),
  serial: mean totalT over the timed steps and wall time per step [us]. Target <= 20 us.
- mpi: 2 ranks (2-2-1-1-1) against serial on the 1521-particle free fall (pluviation) and on
  packed 500: speedup T(1)/T(2) from the module times of runs.csv's definition
  (bench.sweep.records.module_times: totalT = mean over steps of the max over ranks), and the parallel
  overhead against the wire: wireT, the ping-pong model of the bytes and messages each rank sent
  (modes/wire.py), against the exchanges (commuT - syncT + migraT: the data movement) and against
  all of commuT + migraT (with syncT, the step's allreduce, where a rank waits for the slowest:
  load imbalance, not software). Targets: speedup > 1; overhead <= 3 wireT + 20 us.

Two ranks on two cores busy-poll: run it on an otherwise idle machine (the load average at the
start and the end is printed and written).

With --skin 0 (issue 33: the paper's every-step neighbour estimate; the MPI halo, its migration and
ghost choice, by its own skin, bench run's --halo-skin default) the MPI comparison runs both sides
at that skin, against that issue's targets: 2 ranks at least 1.5x faster than serial, the
exchanges at most 3 wireT + 50 us.

Each speedup comes with its 95 % interval, paired over the alternating rounds (round r's serial
and 2-rank runs; bench.sweep.intervals speedup_interval: the Student interval of the rounds' log
ratios, so that a round's machine state cancels), and a verdict against the target: "met" where
the whole interval is at or above it, "not met" where it is below, "unresolved" where it straddles
the target (more --repeats narrow it as 1/sqrt(R); one repeat gives no interval).

With --ceiling each round also steps two serial copies of the scene at half its particles, at the
same skin, alone and meeting after every step (bench.run.copies; the in-step ceiling of `bench
perf --what contention`): ceiling_step = alone / in step, the efficiency two workers reach on the
machine in that round with no parallel machinery at all. of_ceiling = the 2 ranks' efficiency
(speedup / 2) over it, median over the rounds, with its Student interval over the rounds' log
ratios: what the code reaches of what the machine allows, where the speedup alone also carries
the machine's hour (on a 2-vCPU VM the in-step ceiling moved 0.86-0.99 within a day).

Each 2-rank run also gives its rank skew: the largest over the smallest of the ranks' median
compute time per step (compuT). The two ranks hold blocks of nearly equal work, so a skew well
above the work's own (packed 500: 680 and 723 contacts, ~1.05) says that one CPU ran slower for
that whole run (on the 2-vCPU VM, runs where one rank's neighbour estimate took 1.7-1.9x the
other's, with equal particles, alternated with runs at 1.00-1.02). Beside the verdict over every
round, the speedup over the rounds whose skew is at most CLEAN_SKEW is reported, with its interval
and verdict, and the number of such rounds: a second reading, never the verdict itself.

With --in-job C the MPI comparison is made inside one MPI job instead of alternating runs
(bench.studies.perf_overhead_rank): C cycles, each of three blocks of 50 steps (the first 20 left
out: the switch's transient, perf_overhead_rank) in a rotating order, the 2 ranks together, then
each rank alone stepping a serial copy of the whole scene on its own CPU (pinned) while the other
sleeps. A cycle's serial time is the mean of its two CPUs' blocks, so
a CPU that runs slower counts on both sides; the speedup is the geometric mean of the cycles'
serial / 2-rank ratios with its interval (paired over the cycles, which lie seconds apart instead
of a run's minutes: the interval's own centre, where the ratio of medians of the alternating runs
may fall outside its interval); serial_ms and two_ranks_ms are the cycles' medians. cpu_skew
(the median over the cycles of the slower CPU's serial block over the faster's) says how unlike
the two CPUs ran. The job checks that the 2 ranks and both serial copies end in the same state,
bit for bit (identical). With --ceiling each cycle also holds three blocks of a serial copy at half
the particles (the --ceiling copies', stepped at the whole scene's time step): alone on each CPU
while the other sleeps, and on both at once meeting after every step (an MPI barrier); the
cycle's in-step ceiling is the mean of the two alone over the in-step time, and the 2 ranks'
efficiency is read against it cycle by cycle (of_ceiling: their geometric mean, with its
interval).

With --in-job and --repeats R the comparison runs in R jobs a scene, the scenes' jobs alternating
(A B A B ...). The cycles of one job share its state: which CPU runs slower, where the host puts
the two vCPUs, the neighbours' load, for the whole job; the jobs do not. On a 2-vCPU VM two jobs
of the same code minutes apart gave intervals that did not overlap (1521 falling ellipsoids at
--skin 0: [1.23, 1.33] and [1.48, 1.53]): a job's interval over its cycles covers the noise
within a job only. Over R >= 2 jobs the verdict's interval is therefore over the jobs' paired
speedups, each job one batch (the batch means of bench.sweep.intervals, Law, "Simulation Modeling
and Analysis", 5th ed., 9.5.3): the geometric mean of the jobs' speedups with the Student interval
of their logs (R - 1 degrees of freedom; of_ceiling the same way), the jobs' own rows kept beside
it (jobs). One job (--repeats 1) gives its cycles' interval, as before.
"""
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
from bench.run.copies import sample
from bench.run.launch import mpiexec_path
from bench.run.transport import transport_env
from bench.sweep.intervals import mean_interval, speedup_interval, verdict
from bench.sweep.records import module_times

TARGETS = {"small_us_per_step": 20.0, "mpi_speedup": 1.0, "overhead_over_wire_factor": 3.0,
           "overhead_over_wire_add_us": 20.0}
MPI_SCENES = (("pluviation", 1521, 400), ("packed", 500, 300))
# the rank skew (largest / smallest median compuT of the 2 ranks) up to which a round counts as one
# where both CPUs ran alike (module docstring)
CLEAN_SKEW = 1.10
# issue 33's targets of the comparison with --skin 0 (the list rebuilt every step)
REBUILD_TARGETS = {"mpi_speedup": 1.5, "overhead_over_wire_factor": 3.0, "overhead_over_wire_add_us": 50.0}


def _run(scene, particles, steps, mapping, out, warmup=20, skin=None):
    cmd = [sys.executable, "-m", "bench", "run", "--scene", scene, "--particles", str(particles), "--steps",
           str(steps), "--warmup", str(warmup), "--mapping", mapping, "--out", out, "--quiet", "--timeout", "900"]
    if skin is not None:
        cmd += ["--skin", repr(float(skin))]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    if res.returncode != 0:
        lines = (res.stderr.strip() or res.stdout.strip() or "no output").splitlines()
        raise RuntimeError(f"{' '.join(cmd[2:])} failed: {lines[-1]}")
    import pandas as pd
    steps = pd.read_csv(os.path.join(out, "steps.csv"))
    times = module_times(steps)
    compute = steps.groupby("rank")["compuT"].median()
    times["rank_skew"] = float(compute.max() / compute.min()) if compute.min() > 0 else math.nan
    with open(os.path.join(out, "run.json")) as fh:
        info = json.load(fh)
    times["wall_per_step"] = info["wall_s"] / max(info["steps"], 1)
    return times


def overhead_bound(targets, wire):
    """The exchanges' bound [s] for a step whose messages take wire [s] on the wire: factor x wire +
    the added microseconds of targets (TARGETS, REBUILD_TARGETS)."""
    return targets["overhead_over_wire_factor"] * wire + 1e-6 * targets["overhead_over_wire_add_us"]


def _in_job(scene, particles, skin, cycles, tmp, ceiling=False, timeout=900, forward="messages"):
    """The comparison of one scene inside one MPI job (module docstring; bench.studies.
    perf_overhead_rank): its JSON document. RuntimeError (one line) where the job cannot run or
    fails."""
    exe = mpiexec_path()
    if exe is None:
        raise RuntimeError("--in-job needs mpiexec (pip install mpich, or a system MPI)")
    raw = os.path.join(tmp, f"{scene}-in-job.json")
    cmd = [exe, "-n", "2", sys.executable, "-m", "mpi4py", "-m", "bench.studies.perf_overhead_rank",
           "--scene", scene, "--particles", str(particles), "--cycles", str(cycles), "--json", raw]
    if skin is not None:
        cmd += ["--skin", repr(float(skin))]
    if ceiling:
        cmd.append("--ceiling")
    cmd += ["--forward", forward]
    return run_job(cmd, raw, timeout, f"the in-job comparison of {scene}")


def run_job(cmd, raw, timeout, what):
    """Run one MPI job (cmd: mpiexec and its program) in a session of its own and read the JSON it
    writes to raw; on a timeout or an interruption the session is killed (mpiexec's proxies and
    ranks with it: no rank outlives the study). RuntimeError (one line naming `what`) where it
    times out, fails or writes nothing."""
    proc = subprocess.Popen(cmd, start_new_session=True, env=transport_env(dict(os.environ)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException as e:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        if isinstance(e, subprocess.TimeoutExpired):
            raise RuntimeError(f"{what} did not end within {timeout} s; killed") from None
        raise
    if proc.returncode != 0 or not os.path.exists(raw):
        last = (err.strip() or out.strip() or "no output").splitlines()[-1].removeprefix("bench: error: ")
        raise RuntimeError(f"{what} failed (exit status {proc.returncode}): {last}")
    with open(raw) as fh:
        return json.load(fh)


def in_job_row(doc, targets, strict):
    """The report row of an in-job comparison (doc: perf_overhead_rank's JSON; module docstring;
    strict: the speedup target is to be exceeded, speedup_verdict)."""
    two = doc["two_ranks_s"]
    serial = [0.5 * (a + b) for a, b in zip(doc["serial_cpu0_s"], doc["serial_cpu1_s"])]
    t1, t2 = statistics.median(serial), statistics.median(two)
    lo, hi = speedup_interval(t1, math.nan, math.nan, t2, math.nan, math.nan, serial, two)
    paired = math.exp(statistics.mean(math.log(a / b) for a, b in zip(serial, two)))
    parts = {k: statistics.mean(v) for k, v in doc["two_ranks_parts_s"].items()}
    exchange = parts["commuT"] - parts["syncT"] + parts["migraT"]
    bound = overhead_bound(targets, parts["wire_s"])
    skew = [max(a, b) / min(a, b) for a, b in zip(doc["serial_cpu0_s"], doc["serial_cpu1_s"])]
    return {"scene": doc["scene"], "particles": doc["particles"], "method": "in_job", "cycles": doc["cycles"],
            "block_steps": doc["block_steps"], "steps": doc["steps"], "identical": doc["identical"],
            "serial_ms": 1e3 * t1, "two_ranks_ms": 1e3 * t2, "speedup": paired, "speedup_lo": lo, "speedup_hi": hi,
            "verdict": speedup_verdict(lo, hi, targets["mpi_speedup"], strict),
            "cpu_skew": statistics.median(skew), "sync_us": 1e6 * parts["syncT"], "exchange_us": 1e6 * exchange,
            "wire_us": 1e6 * parts["wire_s"], "overhead_bound_us": 1e6 * bound, "exchange_over_bound": exchange / bound,
            "samples": {"serial_cpu0": doc["serial_cpu0_s"], "serial_cpu1": doc["serial_cpu1_s"], "two_ranks": two},
            "affinity": doc["affinity"], "forward_transport": doc["forward_transport"],
            **_in_job_ceiling(doc, serial, two)}


def in_job_jobs(rows, targets, strict):
    """The report row of R in-job comparisons of one scene (rows: in_job_row of each job; module
    docstring): one job's row as it is (jobs 1); over R >= 2 jobs the geometric mean of their
    speedups with the Student interval of their logs and its verdict, serial_ms, two_ranks_ms and
    cpu_skew the jobs' medians, the exchanges, syncT and wire the jobs' means, identical where
    every job ended bit-identical, of_ceiling (where measured) as the speedup, and the jobs' rows
    under `jobs_rows`."""
    if len(rows) == 1:
        return dict(rows[0], jobs=1)
    logs = [math.log(r["speedup"]) for r in rows]
    lo, hi = mean_interval(logs)
    row = {"scene": rows[0]["scene"], "particles": rows[0]["particles"], "method": "in_job", "jobs": len(rows),
           "cycles": rows[0]["cycles"], "block_steps": rows[0]["block_steps"], "steps": rows[0]["steps"],
           "identical": all(r["identical"] for r in rows),
           "forward_transport": rows[0]["forward_transport"],
           "serial_ms": statistics.median(r["serial_ms"] for r in rows),
           "two_ranks_ms": statistics.median(r["two_ranks_ms"] for r in rows),
           "speedup": math.exp(statistics.mean(logs)), "speedup_lo": math.exp(lo), "speedup_hi": math.exp(hi),
           "verdict": speedup_verdict(math.exp(lo), math.exp(hi), targets["mpi_speedup"], strict),
           "cpu_skew": statistics.median(r["cpu_skew"] for r in rows)}
    for k in ("sync_us", "exchange_us", "wire_us", "overhead_bound_us", "exchange_over_bound"):
        row[k] = statistics.mean(r[k] for r in rows)
    if all("of_ceiling" in r for r in rows):
        shares = [math.log(r["of_ceiling"]) for r in rows]
        clo, chi = mean_interval(shares)
        row.update(ceiling_step=statistics.median(r["ceiling_step"] for r in rows),
                   of_ceiling=math.exp(statistics.mean(shares)), of_ceiling_lo=math.exp(clo),
                   of_ceiling_hi=math.exp(chi))
    row["jobs_rows"] = rows
    return row


def _in_job_ceiling(doc, serial, two):
    """The in-step ceiling of an in-job comparison run with --ceiling (module docstring), else {}:
    per cycle, ceiling = the mean of the two CPUs' half copies alone / the halves in step, and the
    2 ranks' efficiency serial / (2 two) over it; ceiling_step the median of the cycles' ceilings,
    of_ceiling the geometric mean of the cycles' shares with its 95 % interval."""
    if "in_step_s" not in doc:
        return {}
    ceil = [0.5 * (a + b) / c for a, b, c in zip(doc["alone_cpu0_s"], doc["alone_cpu1_s"], doc["in_step_s"])]
    share = [math.log(s / (2.0 * t) / c) for s, t, c in zip(serial, two, ceil)]
    lo, hi = mean_interval(share)
    return {"ceiling_particles": doc["ceiling_particles"], "ceiling_step": statistics.median(ceil),
            "of_ceiling": math.exp(statistics.mean(share)), "of_ceiling_lo": math.exp(lo),
            "of_ceiling_hi": math.exp(hi),
            "ceiling_samples": {"alone_cpu0": doc["alone_cpu0_s"], "alone_cpu1": doc["alone_cpu1_s"],
                                "in_step": doc["in_step_s"]}}


def _median(rows, key):
    return statistics.median(r[key] for r in rows)


def _against_ceiling(one, two, copies):
    """The rounds' in-step ceilings (copies: {alone, in_step} [s] per round) and the 2 ranks'
    efficiency over them (module docstring): ceiling_step, of_ceiling (medians over the rounds),
    of_ceiling_lo, of_ceiling_hi (95 % Student interval of the log ratios; NaN under 2 rounds) and
    the samples."""
    ceil = [c["alone"] / c["in_step"] for c in copies]
    ratio = [a["totalT"] / (2.0 * b["totalT"]) / c for a, b, c in zip(one, two, ceil)]
    lo, hi = mean_interval([math.log(x) for x in ratio])
    return {"ceiling_step": statistics.median(ceil), "of_ceiling": statistics.median(ratio),
            "of_ceiling_lo": math.exp(lo), "of_ceiling_hi": math.exp(hi), "ceiling_samples": copies}


def _clean_rounds(one, two, target, strict=False):
    """The rank skew of every round's 2-rank run, and the speedup over the rounds whose skew is at
    most CLEAN_SKEW (module docstring): rank_skew [per round], clean_rounds, clean_speedup (the
    ratio of those rounds' medians), clean_speedup_lo, _hi (paired interval; NaN under 2 such
    rounds) and clean_verdict (strict: the target is to be exceeded, speedup_verdict)."""
    skew = [r["rank_skew"] for r in two]
    keep = [k for k, x in enumerate(skew) if x <= CLEAN_SKEW]
    t1 = [one[k]["totalT"] for k in keep]
    t2 = [two[k]["totalT"] for k in keep]
    s = statistics.median(t1) / statistics.median(t2) if keep else math.nan
    lo, hi = speedup_interval(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, t1, t2)
    return {"rank_skew": skew, "clean_rounds": len(keep), "clean_speedup": s, "clean_speedup_lo": lo,
            "clean_speedup_hi": hi, "clean_verdict": speedup_verdict(lo, hi, target, strict)}


def speedup_verdict(lo, hi, target, strict=False):
    """The speedup target's verdict from its interval (lo, hi) (bench.sweep.intervals.verdict):
    "met" (lo >= target; lo > target where strict, as the default skin's "speedup > 1"), "not met"
    (hi < target; hi <= target where strict) or "unresolved" (the interval straddles it, or there
    is none: NaN)."""
    return verdict(lo, hi, target, strict=strict)


def measure(repeats, log, small_steps=2000, scenes=MPI_SCENES, skin=None, ceiling=False, in_job=None,
            forward="messages"):
    """Run the figures above (scenes: (scene, particles, steps) of the MPI comparison, at the
    neighbour-list skin fraction `skin`, None: the default; ceiling: each round also measures the
    in-step ceiling of 2 workers; in_job: the MPI comparison inside MPI jobs of that many cycles
    instead, `repeats` jobs a scene, its 2-rank side's ghosts forwarded by `forward`: messages,
    shared or auto, modes/window.py); returns the report (perf.json): targets, skin, forward, small,
    mpi [one row per scene], load averages."""
    targets = dict(TARGETS, **REBUILD_TARGETS) if skin == 0 else TARGETS
    report = {"targets": targets, "skin": skin, "load_start": os.getloadavg(), "in_job": in_job, "forward": forward}
    with tempfile.TemporaryDirectory(prefix="bench-overhead-") as tmp:
        # the fixed cost of a step
        small = [_run("pluviation", 48, small_steps, "1-1-1-1-1", os.path.join(tmp, f"small{r}"))
                 for r in range(repeats)]
        report["small"] = {"particles": 48, "steps": small_steps, "us_per_step": 1e6 * _median(small, "totalT"),
                           "wall_us_per_step": 1e6 * _median(small, "wall_per_step")}
        log(f"48 particles (pluviation), serial: {report['small']['us_per_step']:.1f} us/step "
            f"(wall {report['small']['wall_us_per_step']:.1f} us/step); target <= {TARGETS['small_us_per_step']:g}")
        report["mpi"] = []
        jobs = {scene: [] for scene, _, _ in scenes}
        for r in range(repeats if in_job else 0):   # the scenes' jobs alternating (module docstring)
            for scene, n, steps in scenes:
                row = in_job_row(_in_job(scene, n, skin, in_job, tmp, ceiling, forward=forward), targets,
                                 strict=skin != 0)
                if not row["identical"]:   # the modes' trajectories must agree bit for bit (DESIGN.md)
                    raise RuntimeError(f"the in-job comparison of {scene}: the 2 ranks and the serial copies ended "
                                       f"in different states")
                jobs[scene].append(row)
        for scene, n, steps in (scenes if in_job else ()):
            row = in_job_jobs(jobs[scene], targets, strict=skin != 0)
            report["mpi"].append(row)
            each = "" if row["jobs"] == 1 else (
                f" over {row['jobs']} jobs (their interval; each job's "
                + ", ".join(f"{j['speedup']:.2f} [{j['speedup_lo']:.2f}, {j['speedup_hi']:.2f}]"
                            for j in row["jobs_rows"]) + ")")
            where = "one MPI job" if row["jobs"] == 1 else "MPI jobs"
            if row["forward_transport"] == "shared":
                where += ", the 2 ranks' ghosts forwarded through the shared window"
            log(f"{scene} {n}, 2 ranks against serial in {where} ({row['cycles']} cycles of "
                f"{row['block_steps']}-step blocks a job): {row['two_ranks_ms']:.3f} against {row['serial_ms']:.3f} "
                f"ms/step, speedup {row['speedup']:.2f} [{row['speedup_lo']:.2f}, {row['speedup_hi']:.2f}]{each} "
                f"(target "
                f"{'>= ' if skin == 0 else '> '}{targets['mpi_speedup']:g}: {row['verdict']}); the CPUs' serial "
                f"skew {row['cpu_skew']:.2f}; exchanges {row['exchange_us']:.1f} us, wire {row['wire_us']:.1f} us: "
                f"{row['exchange_over_bound']:.2f} of {targets['overhead_over_wire_factor']:g} wire + "
                f"{targets['overhead_over_wire_add_us']:g} us; syncT {row['sync_us']:.1f} us; end states identical")
            if ceiling:
                log(f"  the in-step ceiling of 2 workers in the same cycles: efficiency {row['ceiling_step']:.3f}; the "
                    f"2 ranks' {row['speedup'] / 2:.3f} is {row['of_ceiling']:.2f} [{row['of_ceiling_lo']:.2f}, "
                    f"{row['of_ceiling_hi']:.2f}] of it")
        for scene, n, steps in (() if in_job else scenes):
            one, two, copies = [], [], []
            for r in range(repeats):  # alternating: serial, 2 ranks, (the copies,) serial, 2 ranks, ...
                one.append(_run(scene, n, steps, "1-1-1-1-1", os.path.join(tmp, f"{scene}-1-{r}"), skin=skin))
                two.append(_run(scene, n, steps, "2-2-1-1-1", os.path.join(tmp, f"{scene}-2-{r}"), skin=skin))
                if ceiling:
                    copies.append(sample(scene, n, 2, steps, warmup=20, configs=("alone", "in_step"),
                                         options=None if skin is None else {"skin": skin}))
            t1, t2 = _median(one, "totalT"), _median(two, "totalT")
            lo, hi = speedup_interval(t1, float("nan"), float("nan"), t2, float("nan"), float("nan"),
                                      [r["totalT"] for r in one], [r["totalT"] for r in two])
            over = _median(two, "commuT") + _median(two, "migraT")
            sync = _median(two, "syncT")
            wire = _median(two, "wireT")
            bound = overhead_bound(targets, wire)
            row = {"scene": scene, "particles": n, "steps": steps, "serial_ms": 1e3 * t1, "two_ranks_ms": 1e3 * t2,
                   "speedup": t1 / t2, "speedup_lo": lo, "speedup_hi": hi,
                   "verdict": speedup_verdict(lo, hi, targets["mpi_speedup"], strict=skin != 0),
                   "commu_migra_us": 1e6 * over, "sync_us": 1e6 * sync,
                   "exchange_us": 1e6 * (over - sync), "wire_us": 1e6 * wire, "overhead_bound_us": 1e6 * bound,
                   "exchange_over_bound": (over - sync) / bound, "overhead_over_bound": over / bound,
                   "samples": {"serial": one, "two_ranks": two}}
            if ceiling:
                row.update(_against_ceiling(one, two, copies))
            row.update(_clean_rounds(one, two, targets["mpi_speedup"], strict=skin != 0))
            report["mpi"].append(row)
            log(f"{scene} {n}, 2 ranks against serial: {row['two_ranks_ms']:.3f} against "
                f"{row['serial_ms']:.3f} ms/step, "
                f"speedup {row['speedup']:.2f} [{lo:.2f}, {hi:.2f}] (target {'>= ' if skin == 0 else '> '}"
                f"{targets['mpi_speedup']:g}: {row['verdict']}); "
                f"per step: exchanges (commuT - syncT + migraT) {row['exchange_us']:.1f} us, wire "
                f"{row['wire_us']:.1f} us: {row['exchange_over_bound']:.2f} of "
                f"{targets['overhead_over_wire_factor']:g} "
                f"wire + {targets['overhead_over_wire_add_us']:g} us (target <= 1); with syncT {row['sync_us']:.1f} us "
                f"(the allreduce, waiting for the "
                f"slowest rank): {row['overhead_over_bound']:.2f}")
            log(f"  rank skew per round: {', '.join(f'{k:.2f}' for k in row['rank_skew'])}; over the "
                f"{row['clean_rounds']} rounds at most {CLEAN_SKEW:g}: speedup {row['clean_speedup']:.2f} "
                f"[{row['clean_speedup_lo']:.2f}, {row['clean_speedup_hi']:.2f}] ({row['clean_verdict']})")
            if ceiling:
                log(f"  the in-step ceiling of 2 workers in the same rounds: efficiency {row['ceiling_step']:.3f}; "
                    f"the 2 ranks' {row['speedup'] / 2:.3f} is {row['of_ceiling']:.2f} "
                    f"[{row['of_ceiling_lo']:.2f}, {row['of_ceiling_hi']:.2f}] of it")
    report["load_end"] = os.getloadavg()
    log(f"load average {report['load_start'][0]:.2f} at the start, {report['load_end'][0]:.2f} at the end")
    return report
