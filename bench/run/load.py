"""Whether a measurement can be trusted (issue 15): the CPU time other processes took during a
run's timed steps, and the spread of its step times.

Foreign CPU. Linux's /proc/stat counts, since boot, the time all CPUs spent busy: user + nice +
system + irq + softirq + steal, in clock ticks (guest time is inside user; steal is time a
hypervisor gave another guest while this one wanted the CPU, so it counts as foreign). Over the
timed steps

    foreign_cpu_s = busy ticks / CLK_TCK  -  own CPU time of the run

where the run's own CPU time is the user + system time of its processes (resource.getrusage of
each process, all its threads; under MPI the sum over the ranks on the same host). A run alone on
its machine reads about 0; foreign_cores = foreign_cpu_s / wall_s is the mean number of CPUs other
processes kept busy. The tick (10 ms) makes resolution_s = 2 ticks x CPUs the uncertainty of
foreign_cpu_s, so a run of a fraction of a second cannot tell its load (bench.sweep.records
flags a load only above that uncertainty).

Step spread. (p90 - p10) / p50 of the per-step totalT (the max over ranks of each step): a run
whose steps are alike reads a few hundredths; neighbour rebuild steps, about one step in tens
with the default skin, sit above p90 and do not move it.
"""
import os
import resource
import time

import numpy as np

BUSY_FIELDS = (0, 1, 2, 5, 6, 7)  # user nice system [idle iowait] irq softirq steal


def busy_seconds():
    """CPU seconds all CPUs have been busy since boot (/proc/stat), or None where it cannot be read."""
    try:
        with open("/proc/stat") as fh:
            first = fh.readline().split()
        ticks = [int(first[1 + k]) for k in BUSY_FIELDS if 1 + k < len(first)]
        return sum(ticks) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def resolution_s():
    """The uncertainty [s] of a difference of two /proc/stat readings: a tick at each end on each CPU."""
    try:
        return 2.0 * (os.cpu_count() or 1) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        return 0.02 * (os.cpu_count() or 1)


def own_seconds():
    """User + system CPU seconds of this process (every thread)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class LoadMeter:
    """Foreign CPU over an interval: start() before the timed steps, stop() after; then
    foreign(own_total) with own_total the CPU seconds of every process of the run on this host."""

    def start(self):
        self.busy0 = busy_seconds()
        self.own0 = own_seconds()
        self.t0 = time.perf_counter()
        return self

    def stop(self):
        self.busy1 = busy_seconds()
        self.own = own_seconds() - self.own0
        self.wall = time.perf_counter() - self.t0
        return self

    def foreign(self, own_total=None):
        """{foreign_cpu_s, own_cpu_s, foreign_cores} (None where /proc/stat cannot be read)."""
        own = self.own if own_total is None else own_total
        if self.busy0 is None or self.busy1 is None:
            return {"foreign_cpu_s": None, "own_cpu_s": own, "foreign_cores": None}
        foreign = max(0.0, (self.busy1 - self.busy0) - own)
        return {"foreign_cpu_s": foreign, "own_cpu_s": own,
                "foreign_cores": foreign / self.wall if self.wall > 0 else None,
                "resolution_s": resolution_s()}


def step_spread(step_times):
    """{p10, p50, p90 [s], spread = (p90 - p10) / p50} of per-step times [s] (an array [steps])."""
    t = np.asarray(step_times, dtype=float)
    t = t[np.isfinite(t)]
    if not len(t):
        return {"p10": None, "p50": None, "p90": None, "spread": None}
    p10, p50, p90 = (float(x) for x in np.percentile(t, [10, 50, 90]))
    return {"p10": p10, "p50": p50, "p90": p90, "spread": (p90 - p10) / p50 if p50 > 0 else None}
