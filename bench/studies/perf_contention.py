"""`bench perf --what contention`: the efficiency P workers can reach when they share nothing.

The efficiency of a mapping, E = T(1) / (P T(P)), mixes three things: the parallel machinery
(messages, ghosts, the merging of forces), the waits of workers whose step times jitter and who
meet once a step, and what the machine gives P busy cores at once (a shared L3 cache and memory
bandwidth, a lower clock with more cores active, other tenants of a shared host). The last two
are no fault of a code, and no mapping escapes them. This control measures them with the code's
parallel machinery left out: P independent processes, each stepping its own copy of the scene at
N/P particles (a rank's share, packed the same way, so the same work per particle), sharing no
memory and sending no message.

- serial: one process, N particles: T1 [s/step]
- alone: one process, N/P particles: Ta
- together: P processes at once, each N/P particles, timed over the same steps (they start at a
  barrier): Tc, the mean over the copies of their mean step
- in step: the same, with a barrier after every step, as ranks meet at the step's allreduce and
  threads at the end of a parallel loop: Ts, the mean step including the wait for the slowest copy.
  The barrier spins on a shared array of step counts, one writer a slot (as MPI busy-polls): a
  multiprocessing.Barrier (semaphores, sleeping) added 1.8 ms a step on 2 cores.

Figures: the two ceilings, Ta / Tc (contention: how much slower a worker runs beside P - 1
others) and Ta / Ts (contention and the waits of meeting every step), the efficiency P ranks or
threads could reach if the work divided exactly and their communication cost nothing; a
mapping's measured efficiency is to be read against them. Beside them, size = T1 / (P Ta): what a
share costs against 1/P of the whole; it is not in the ceilings, since a share packed in a box
of its own has walls where a rank's block has a cut (on 12k packed ellipsoids a copy of 6000
took 8 % more than half of the whole, a rank of 2-2-1-1-1 resolves 2.8 % more pairs than half).
The configurations alternate (serial, alone, together, in step; repeats times), medians quoted.
"""
import os
import statistics

from bench.run.copies import CONFIGURATIONS, ceilings, sample


def measure(scene, particles, copies, steps, repeats, log, warmup=5):
    """The figures above for P = copies workers on `particles` particles of the scene; returns the
    report (perf.json): per configuration its samples [s/step], medians, and the ratios."""
    share = max(1, particles // copies)
    samples = {c: [] for c in CONFIGURATIONS}
    load_start = os.getloadavg()
    for r in range(repeats):
        for c, t in sample(scene, particles, copies, steps, warmup).items():
            samples[c].append(t)
        log(f"repeat {r + 1}/{repeats}: " + ", ".join(f"{k} {1e3 * v[-1]:.3f}" for k, v in samples.items())
            + " ms/step")
    med = {k: statistics.median(v) for k, v in samples.items()}
    t1, ta, tc, ts = med["serial"], med["alone"], med["together"], med["in_step"]
    report = {"scene": scene, "particles": particles, "copies": copies, "share": share, "steps": steps,
              "repeats": repeats, "samples_s": samples, "median_ms": {k: 1e3 * v for k, v in med.items()},
              "contention": ta / tc, **ceilings(med), "size": t1 / (copies * ta), "load_start": load_start,
              "load_end": os.getloadavg()}
    log(f"{scene}, {particles} particles, {copies} independent copies of {share} (no messages, no shared memory):")
    log(f"  serial {1e3 * t1:.3f}, one copy alone {1e3 * ta:.3f}, {copies} together {1e3 * tc:.3f}, "
        f"together meeting every step {1e3 * ts:.3f} ms/step (medians of {repeats})")
    log(f"  efficiency ceiling of {copies} workers (alone / together): {report['ceiling_free']:.3f} free, "
        f"{report['ceiling_step']:.3f} meeting every step")
    log(f"  size (serial / {copies} x alone): {report['size']:.3f} (a share in a box of its own; not in the ceilings)")
    log(f"load average {load_start[0]:.2f} at the start, {report['load_end'][0]:.2f} at the end")
    return report
