"""`bench perf --what forward [--procs P | --mapping P-px-py-pz-T] [--scene S] [--particles N]
[--skin F] [--repeats R] [--in-job C] [--timeout S] [--out DIR]`: which way the ghosts' moving
fields should travel between rebuilds on one node, by messages (`--forward messages`, the paper's
way) or through an MPI-3 shared-memory window (`--forward shared`, modes/window.py).

Each of R MPI jobs (default 3) of P ranks (the mapping's block grid, default 2-2-1-1-1; `--procs P`
alone takes the most cubic grid, as MPI_Dims_create does; T is ignored) holds both set-ups of the
scene (default packed, `--particles` of it) and alternates blocks of them for C cycles (default 40;
bench.studies.perf_forward_rank, started as `mpiexec -n P python -m mpi4py -m
bench.studies.perf_forward_rank ...`, killed with its ranks after --timeout seconds). With no more
ranks than usable CPUs each rank is pinned to a CPU of its own; with more (correctness only) they are
not, and a warning says the times measure the scheduler.

Per job: each cycle's ratio messages / shared of the two blocks' times (above 1: the window is
faster), their geometric mean with the Student interval of the cycles' log ratios (the noise
within the job). Over the jobs: the geometric mean of the jobs' ratios with the Student interval of
their logs (R - 1 degrees of freedom), the verdict's interval: on a shared host the state that
decides a ratio changes between jobs more than within one (bench.studies.perf_overhead, --in-job),
so one job's interval is too narrow for a verdict. The verdict: `shared` where the whole interval
is above 1, `messages` where it is below 1, `tie` where it holds 1 (or there is one job). Every job
must end with both set-ups' states identical bit for bit (else exit 1). `bench node` runs this at
C ranks on the node it checks (issue 32: the window's case is a rank with up to 26 neighbours on a
many-core node; at 2 ranks of the 2-core VM 23 jobs tied, 0.992 [0.978, 1.007]).
"""
import math
import os
import statistics
import sys
import tempfile

from bench.run.launch import mpiexec_path
from bench.run.threads_env import check_size, usable_cpus
from bench.studies.perf_comm import resolve_mapping
from bench.studies.perf_overhead import run_job
from modes.base import ModeError
from bench.sweep.intervals import mean_interval

DEFAULT_CYCLES = 40


def job_row(doc):
    """A job's row from perf_forward_rank's JSON: the medians of the blocks' times [ms], the
    geometric mean of the cycles' ratios messages / shared with its interval over the cycles, and
    each set-up's means a step (parts_us: the phases [us], neighbor_rebuilt a share of the steps,
    msgs_sent the messages of all ranks)."""
    a, b = doc["messages_s"], doc["shared_s"]
    logs = [math.log(x / y) for x, y in zip(a, b)]
    lo, hi = mean_interval(logs)
    parts = {fw: {k: (v if k in ("msgs_sent", "neighbor_rebuilt") else 1e6 * v) for k, v in p.items()}
             for fw, p in doc["parts"].items()}
    return {"cycles": doc["cycles"], "identical": doc["identical"], "pinned": doc["pinned"],
            "messages_ms": 1e3 * statistics.median(a), "shared_ms": 1e3 * statistics.median(b),
            "ratio": math.exp(statistics.mean(logs)), "ratio_lo": math.exp(lo), "ratio_hi": math.exp(hi),
            "transport": doc["transport"], "forward_windows": doc["forward_windows"], "parts_us": parts,
            "samples": {"messages_s": a, "shared_s": b}}


def faster(lo, hi):
    """The verdict of an interval (lo, hi) of messages / shared: "shared" (lo > 1), "messages"
    (hi < 1) or "tie" (it holds 1, or there is none: NaN)."""
    if lo > 1.0:
        return "shared"
    if hi < 1.0:
        return "messages"
    return "tie"


def summarize(rows):
    """The report of R jobs' rows (job_row): the jobs' geometric mean ratio and its Student interval
    over the jobs (NaN under 2 jobs), the verdict, the medians of the jobs' block times and whether
    every job ended identical."""
    logs = [math.log(r["ratio"]) for r in rows]
    lo, hi = mean_interval(logs)
    lo, hi = math.exp(lo), math.exp(hi)
    return {"jobs": len(rows), "ratio": math.exp(statistics.mean(logs)), "ratio_lo": lo, "ratio_hi": hi,
            "faster": faster(lo, hi), "identical": all(r["identical"] for r in rows),
            "messages_ms": statistics.median(r["messages_ms"] for r in rows),
            "shared_ms": statistics.median(r["shared_ms"] for r in rows)}


def _prepare(scene, particles, skin):
    """Before any rank starts: the scene loaded (a bad one: its one line), its build stage run and
    cached (the rested pack), and the kernels the ranks run compiled into numba's cache by a serial
    twin and the halo's and Newton's compile calls, so that 2 P processes neither build the pack nor
    compile at once (bench.run.launch warm_cache)."""
    import copy
    from bench.run.prepare import load_prepared
    from dem.timestep import choose_time_step
    from modes.halo import compile_kernels
    from modes.newton import compile_kernels as compile_newton_kernels
    from modes.serial import SerialMode
    built = load_prepared(scene, particles=particles)
    opts = {} if skin is None else {"skin": skin}
    SerialMode().setup(copy.copy(built), dt=choose_time_step(built).dt, **opts).warmup()
    compile_kernels()
    compile_newton_kernels()


def measure(mapping=None, procs=None, scene="packed", particles=None, skin=None, repeats=3, cycles=None,
            timeout=600, log=print):
    """The `bench perf --what forward` report (module docstring). ModeError (one line) for a bad
    mapping or more ranks than bench run starts on this node's CPUs; RuntimeError (one line) where
    a job fails or ends with the two states apart."""
    m = resolve_mapping(procs, mapping, what="forward")
    too_big = check_size(f"{m.procs}-{m.px}-{m.py}-{m.pz}-1")   # bench run's limit of ranks started here
    if too_big:
        raise ModeError(too_big)
    _prepare(scene, particles, skin)
    exe = mpiexec_path()
    if exe is None:
        raise RuntimeError("--what forward needs mpiexec (pip install mpich, or a system MPI)")
    cycles = cycles or DEFAULT_CYCLES
    cpus = usable_cpus()
    pin = m.procs <= cpus
    if not pin:
        print(f"bench: warning: {m.procs} ranks on {cpus} usable CPUs oversubscribes them: the comparison runs "
              f"(correctness) but its times measure the scheduler", file=sys.stderr)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-forward-") as tmp:
        for r in range(repeats):
            raw = os.path.join(tmp, f"job{r}.json")
            cmd = [exe, "-n", str(m.procs), sys.executable, "-m", "mpi4py", "-m", "bench.studies.perf_forward_rank",
                   "--dims", str(m.px), str(m.py), str(m.pz), "--scene", scene, "--cycles", str(cycles),
                   "--json", raw]
            if particles is not None:
                cmd += ["--particles", str(particles)]
            if skin is not None:
                cmd += ["--skin", repr(float(skin))]
            if pin:
                cmd.append("--pin")
            doc = run_job(cmd, raw, timeout, "the forward comparison")
            row = job_row(doc)
            rows.append(row)
            log(f"job {r + 1}/{repeats}: {m} {scene} {doc['particles']}: messages {row['messages_ms']:.3f}, "
                f"shared {row['shared_ms']:.3f} ms/step, messages / shared {row['ratio']:.3f} "
                f"[{row['ratio_lo']:.3f}, {row['ratio_hi']:.3f}] over {row['cycles']} cycles; messages a step "
                f"{row['parts_us']['messages']['msgs_sent']:.1f} against {row['parts_us']['shared']['msgs_sent']:.1f}"
                f"; end states {'identical' if row['identical'] else 'DIFFER'}")
            if not row["identical"]:
                raise RuntimeError(f"job {r + 1}: the two forward transports ended in different states")
    report = {"what": "forward", "mapping": str(m), "procs": m.procs, "dims": [m.px, m.py, m.pz], "scene": scene,
              "particles": doc["particles"], "skin": skin, "cycles": cycles, "block_steps": doc["block_steps"],
              "drop_steps": doc["drop_steps"], "pinned": pin, "usable_cpus": cpus,
              "mpi_library": doc["mpi_library"], **summarize(rows), "jobs_rows": rows}
    interval = ("" if math.isnan(report["ratio_lo"]) else
                f" [{report['ratio_lo']:.3f}, {report['ratio_hi']:.3f}] over {len(rows)} jobs")
    log(f"forward exchange at {m.procs} ranks ({m}): messages / shared {report['ratio']:.3f}{interval}: "
        + {"shared": "the shared window is faster", "messages": "the messages are faster",
           "tie": "no ranking at 95 %"}[report["faster"]])
    return report
