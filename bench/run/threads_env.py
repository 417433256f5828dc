"""Thread environment of a run, set before numba starts (numba reads it at import).

NUMBA_NUM_THREADS = T of the mapping. --pin sets nothing here: the run binds its ranks and threads
itself (bench.run.binding), because OMP_PROC_BIND in a launching process binds that process's main
thread to one CPU as soon as it runs a parallel region, and every rank it starts inherits that one
CPU (a pinned 4-2-2-1-4 ran all four ranks on CPU 0). More threads than the CPUs this process may use get a
one-line warning and OMP_WAIT_POLICY=PASSIVE: spinning GNU OpenMP threads on shared cores were
seen to make steps 100x slower.
"""
import os
import re
import sys

# threads (or local ranks x threads) per CPU of the node beyond which a run is refused: numba starts
# every thread at once (10^5 of them crashed the process) and correctness runs need only a few
MAX_PER_CPU = 8


def size_limit():
    """The most threads a process, or ranks x threads started here, may ask for: MAX_PER_CPU x the
    node's CPUs."""
    return MAX_PER_CPU * (os.cpu_count() or 1)


def check_size(mapping_text, local_ranks=True):
    """None, or the one-line reason a mapping 'P-px-py-pz-T' asks for more threads (T, and P x T when
    the ranks start here) than size_limit(); a malformed mapping passes (the run refuses it)."""
    m = re.fullmatch(r"\s*(\d+)-(\d+)-(\d+)-(\d+)-(\d+)\s*", mapping_text or "", re.ASCII)
    if not m:
        return None
    procs, px, py, pz, threads = (int(g) for g in m.groups())
    if min(procs, px, py, pz, threads) < 1 or procs != px * py * pz:
        return None  # malformed: the mapping parser says why
    limit = size_limit()
    if threads > limit:
        return (f"mapping {mapping_text.strip()}: {threads} threads a process is more than {MAX_PER_CPU} per CPU "
                f"({os.cpu_count()} CPUs: at most {limit})")
    if local_ranks and procs * threads > limit:
        return (f"mapping {mapping_text.strip()}: {procs} ranks x {threads} threads started here is more than "
                f"{MAX_PER_CPU} per CPU ({os.cpu_count()} CPUs: at most {limit}); under Slurm they spread over nodes")
    return None


def usable_cpus():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def configure_threads(mapping_text, pin=False, procs_per_node=1):
    """Set the thread variables for mapping 'P-px-py-pz-T' (ignored if malformed: the run
    reports that). Returns a dict of what was set, for run.json."""
    m = re.fullmatch(r"\s*(\d+)-(\d+)-(\d+)-(\d+)-(\d+)\s*", mapping_text or "", re.ASCII)
    if not m:
        return {}
    procs, px, py, pz, threads = (int(g) for g in m.groups())
    if min(procs, px, py, pz, threads) < 1 or procs != px * py * pz:
        return {}  # malformed: the run refuses it with one line
    if "numba" in sys.modules:
        import numba
        if numba.config.NUMBA_NUM_THREADS < threads:
            return {}  # too late: the mode refuses with one line
    os.environ["NUMBA_NUM_THREADS"] = str(threads)
    info = {"NUMBA_NUM_THREADS": threads}
    if pin:
        info["pin"] = "bench.run.binding"
    cpus = usable_cpus()
    if threads * procs_per_node > cpus:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        info["OMP_WAIT_POLICY"] = os.environ["OMP_WAIT_POLICY"]
        print(f"bench: warning: {threads * procs_per_node} threads on {cpus} usable CPUs oversubscribes them; "
              f"fine for correctness, not for timings", file=sys.stderr)
    info["usable_cpus"] = cpus
    return info
