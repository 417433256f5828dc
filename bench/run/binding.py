"""Where a run's ranks and threads execute: the binding plan (`--pin`), binding to it, and the proof.

Plan (plan_binding, a pure function of a described topology). Each of the P ranks of a node gets T
distinct CPUs, one for each of its threads:
- one hardware thread per physical core while P x T fits in the cores; beyond that the sibling
  hardware threads too, a core's siblings to the same rank (they share its caches);
- no rank straddles two sockets when that can be avoided: the ranks are spread evenly over the
  sockets (each socket taking at most what fits in it) and placed in rank order, socket by socket,
  so neighbouring ranks of the block grid share a socket (Open MPI's `--map-by package:PE=T`
  places ranks alike; Rabenseifner, Hager & Jost 2009, on hybrid MPI/OpenMP pinning);
- otherwise ranks take T consecutive CPUs of the socket-ordered list.

Binding (bind_process). The rank binds itself, whatever started it (Hydra's mpiexec, srun, Open
MPI's mpirun, or `bench run` itself for one process): the ranks of a node (MPI's shared-memory
communicator) pool the CPUs they were given, each applies the plan over that pool to every thread
of its process, then numba's T worker threads are reached by a parallel probe (each reports its
numba thread id, kernel thread id and CPU) and each is bound to its own CPU with
sched_setaffinity(tid). numba's thread 0 is the calling thread.

Proof (thread_records, check_binding). At start, before anything is timed, every rank records its
CPU set and every worker thread its affinity mask and the CPU it ran on (run.json `affinity`); a
run whose ranks got fewer CPUs than min(T, the CPUs the launcher had), or, when pinned, threads not
alone on their own CPU or ranks of one node sharing CPUs, stops with one line naming the rank and
its CPUs. The same records are taken again after the timed steps (`affinity.after`: did the
binding hold through the run).
"""
import ctypes
import os
import platform
import socket
import threading
from dataclasses import dataclass

import numpy as np

from modes.base import ModeError

NODE_CPUS_ENV = "DEM_BENCH_NODE_CPUS"  # the CPUs the launching process could use (bench.run.launch)
SYS_CPU = "/sys/devices/system/cpu"


class BindingError(ModeError):
    """A binding that cannot be planned or did not hold; str() is one line."""


@dataclass(frozen=True)
class Cpu:
    """One hardware thread: its OS number (what sched_setaffinity takes), its physical core (unique
    over the machine) and its socket (package)."""
    id: int
    core: int
    socket: int


def described(sockets, cores_per_socket, smt=1):
    """A topology of `sockets` x `cores_per_socket` cores with `smt` hardware threads each, numbered
    as Linux numbers x86 CPUs: the first hardware thread of every core, socket by socket, then the
    second (so core c's siblings are c and c + sockets x cores_per_socket)."""
    cores = sockets * cores_per_socket
    return [Cpu(h * cores + s * cores_per_socket + c, s * cores_per_socket + c, s)
            for h in range(smt) for s in range(sockets) for c in range(cores_per_socket)]


def _read_int(path, default):
    try:
        with open(path) as fh:
            return int(fh.read().strip())
    except (OSError, ValueError):
        return default


def read_topology(allowed):
    """The Cpus of `allowed` (OS CPU numbers) from /sys (package and core ids); a CPU whose
    topology files are missing counts as its own core on socket 0."""
    keys, out = {}, []
    for cpu in sorted(allowed):
        base = f"{SYS_CPU}/cpu{cpu}/topology"
        sock = _read_int(f"{base}/physical_package_id", 0)
        core = _read_int(f"{base}/core_id", None)
        key = (sock, core if core is not None else ("cpu", cpu))
        out.append(Cpu(cpu, keys.setdefault(key, len(keys)), sock))
    return out


def topology_text(topology):
    """'16 (1 socket, 16 cores)', with ', 2 threads a core' when SMT."""
    sockets = sorted({c.socket for c in topology})
    cores = len({c.core for c in topology})
    smt = len(topology) // max(1, cores)
    text = f"{len(topology)} ({len(sockets)} socket{'s' if len(sockets) > 1 else ''}, {cores} cores"
    return text + (f", {smt} threads a core)" if smt > 1 else ")")


def plan_binding(topology, ranks, threads):
    """[ranks][threads] OS CPU numbers: thread k of local rank r runs on plan[r][k] (module
    docstring for the rules). Raises BindingError when ranks x threads exceed the CPUs."""
    if ranks < 1 or threads < 1:
        raise BindingError(f"a binding needs at least one rank and one thread, got {ranks} x {threads}")
    need = ranks * threads
    if need > len(topology):
        raise BindingError(f"--pin: {ranks} rank{'s' if ranks > 1 else ''} x {threads} thread"
                           f"{'s' if threads > 1 else ''} need {need} CPUs; usable: {topology_text(topology)}")
    siblings = {}
    for c in topology:
        siblings.setdefault((c.socket, c.core), []).append(c.id)
    cores = sorted(siblings, key=lambda k: (k[0], min(siblings[k])))
    one_per_core = need <= len(cores)
    slots = {}  # socket -> CPUs in placement order
    for key in cores:
        ids = sorted(siblings[key])
        slots.setdefault(key[0], []).extend(ids[:1] if one_per_core else ids)
    sockets = sorted(slots)
    fit = [len(slots[s]) // threads for s in sockets]
    if sum(fit) >= ranks:
        counts = [0] * len(sockets)
        for _ in range(ranks):  # evenly over the sockets, within what each holds
            s = min((k for k in range(len(sockets)) if counts[k] < fit[k]), key=lambda k: (counts[k], k))
            counts[s] += 1
        plan = []
        for s, count in zip(sockets, counts):
            plan += [slots[s][j * threads:(j + 1) * threads] for j in range(count)]
        return plan
    flat = [cpu for s in sockets for cpu in slots[s]]
    return [flat[r * threads:(r + 1) * threads] for r in range(ranks)]


# --- numba's worker threads -------------------------------------------------------------------------

_PROBE = None
_SYS_GETTID = {"x86_64": 186, "aarch64": 178, "ppc64le": 207}


def _native():
    """ctypes handles of gettid() and sched_getcpu() (glibc), callable from numba."""
    libc = ctypes.CDLL(None, use_errno=True)
    if hasattr(libc, "gettid"):
        gettid = libc.gettid
        gettid.restype, gettid.argtypes = ctypes.c_int, []
    else:  # glibc < 2.30
        number = _SYS_GETTID.get(platform.machine())
        if number is None:
            raise BindingError(f"no gettid on {platform.machine()}: threads cannot be bound")
        raw = libc.syscall
        raw.restype, raw.argtypes = ctypes.c_long, [ctypes.c_long]
        gettid = raw
        return gettid, libc.sched_getcpu, number
    getcpu = libc.sched_getcpu
    getcpu.restype, getcpu.argtypes = ctypes.c_int, []
    return gettid, getcpu, None


def _probe():
    """A parallel kernel: row k of out [T, 3] <- (numba thread id, kernel thread id, CPU) of the
    thread that ran iteration k. Compiled on first use (not cached: it calls C through ctypes)."""
    global _PROBE
    if _PROBE is None:
        from numba import get_thread_id, njit, prange
        gettid, getcpu, number = _native()
        if number is None:
            @njit(parallel=True)
            def probe(out):
                for k in prange(out.shape[0]):
                    out[k, 0] = get_thread_id()
                    out[k, 1] = gettid()
                    out[k, 2] = getcpu()
        else:
            @njit(parallel=True)
            def probe(out):
                for k in prange(out.shape[0]):
                    out[k, 0] = get_thread_id()
                    out[k, 1] = gettid(number)
                    out[k, 2] = getcpu()
        _PROBE = probe
    return _PROBE


def numba_threads(threads, tries=200):
    """{numba thread id: (kernel thread id, CPU it ran on)} of the `threads` threads of numba's pool.
    With the omp layer's static schedule the first call reaches them all; other layers may take
    several calls. Raises BindingError when some thread never shows."""
    if threads == 1:  # this thread alone: no parallel region (a serial run starts no thread pool)
        gettid, getcpu, number = _native()
        return {0: (threading.get_native_id(), int(getcpu()))}
    import numba
    if numba.config.NUMBA_NUM_THREADS < threads:
        raise BindingError(f"numba has {numba.config.NUMBA_NUM_THREADS} threads, the run needs {threads}")
    numba.set_num_threads(threads)
    probe = _probe()
    out = np.full((threads, 3), -1, dtype=np.int64)
    seen = {}
    for _ in range(tries):
        probe(out)
        for t, tid, cpu in out:
            seen[int(t)] = (int(tid), int(cpu))
        if len(seen) >= threads:
            break
    if len(seen) < threads:
        raise BindingError(f"only {len(seen)} of numba's {threads} threads could be reached to bind them")
    return seen


def _tasks():
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [os.getpid()]


def process_cpus():
    """The union of the affinity masks of every thread of this process (its CPU set)."""
    cpus = set()
    for tid in _tasks():
        try:
            cpus |= os.sched_getaffinity(tid)
        except OSError:  # a thread that ended meanwhile
            pass
    return sorted(cpus)


def bind_process(cpus, threads):
    """Bind this process to `cpus` (its plan row, [threads] OS CPU numbers): every thread of the
    process to the set, then numba's thread k alone to cpus[k]."""
    whole = set(cpus)
    for tid in _tasks():
        try:
            os.sched_setaffinity(tid, whole)
        except OSError as e:
            if tid == os.getpid():
                raise BindingError(f"cannot bind to CPUs {format_cpus(cpus)}: {e.strerror}") from None
    for k, (tid, _) in sorted(numba_threads(threads).items()):
        try:
            os.sched_setaffinity(tid, {cpus[k]})
        except OSError as e:
            raise BindingError(f"cannot bind thread {k} to CPU {cpus[k]}: {e.strerror}") from None


def thread_records(threads):
    """This process's record: host, pid, CPU set, and each numba thread's kernel id, mask and the
    CPU it ran on (a probe, now)."""
    rows = []
    for k, (tid, ran) in sorted(numba_threads(threads).items()):
        try:
            mask = sorted(os.sched_getaffinity(tid))
        except OSError:
            mask = []
        rows.append({"thread": k, "tid": tid, "cpus": mask, "ran_on": ran})
    return {"host": socket.gethostname(), "pid": os.getpid(), "cpus": process_cpus(), "threads": rows}


def format_cpus(cpus):
    """'{0-3,8}': a CPU list as ranges."""
    cpus = sorted(cpus)
    parts, k = [], 0
    while k < len(cpus):
        j = k
        while j + 1 < len(cpus) and cpus[j + 1] == cpus[j] + 1:
            j += 1
        parts.append(str(cpus[k]) if j == k else f"{cpus[k]}-{cpus[j]}")
        k = j + 1
    return "{" + ",".join(parts) + "}"


def check_binding(records, threads, pinned, launcher_cpus=None):
    """None, or the one line saying how the binding failed. records: one thread_records() dict per
    rank, in rank order. Every rank must hold at least min(T, launcher_cpus) CPUs (launcher_cpus:
    what the launching process could use; T when unknown). Pinned: each thread alone on one CPU of
    its own, the threads of a rank on distinct CPUs, each having run there, the ranks of a host on
    disjoint sets."""
    want = threads if launcher_cpus is None else min(threads, launcher_cpus)
    for r, rec in enumerate(records):
        if len(rec["cpus"]) < want:
            seen = f" (the launcher had {launcher_cpus})" if launcher_cpus is not None else ""
            return (f"rank {r} on {rec['host']} got CPUs {format_cpus(rec['cpus'])} for {threads} thread"
                    f"{'s' if threads > 1 else ''}{seen}: CPUs were lost between the launcher and the rank")
    if not pinned:
        return None
    owner = {}
    for r, rec in enumerate(records):
        mine = set()
        for row in rec["threads"]:
            if len(row["cpus"]) != 1:
                return (f"rank {r} on {rec['host']}: thread {row['thread']} is bound to CPUs "
                        f"{format_cpus(row['cpus'])}, not to one CPU of its own (--pin)")
            cpu = row["cpus"][0]
            if cpu in mine:
                return f"rank {r} on {rec['host']}: two threads bound to CPU {cpu} (--pin)"
            if row["ran_on"] != cpu:
                return (f"rank {r} on {rec['host']}: thread {row['thread']} bound to CPU {cpu} ran on CPU "
                        f"{row['ran_on']} (--pin)")
            mine.add(cpu)
        for cpu in mine:
            other = owner.get((rec["host"], cpu))
            if other is not None:
                return (f"ranks {other} and {r} on {rec['host']} share CPU {cpu} (rank {r}: CPUs "
                        f"{format_cpus(mine)}; --pin gives each rank CPUs of its own)")
            owner[(rec["host"], cpu)] = r
    return None


def launcher_cpus():
    """The CPUs the launching process could use (NODE_CPUS_ENV), or None."""
    value = os.environ.get(NODE_CPUS_ENV)
    try:
        return int(value) if value else None
    except ValueError:
        return None


def establish(threads, pin, comm=None):
    """Bind (when pin) and record this process's ranks and threads, collectively under MPI (comm:
    the run's communicator, or None for one process). Returns the run.json `affinity` dict on
    rank 0 (None on the others); raises BindingError (the same line on every rank) when the binding
    cannot be planned or did not hold."""
    problem, plan_row = None, None
    # what the CPUs given are checked against: the launcher's count (MPI under bench run), this
    # process's own for one process (it is its own launcher: a run of more threads than CPUs, for
    # correctness, has all of them), else T (a starter such as srun placed the ranks)
    given = launcher_cpus()
    if given is None and comm is None:
        given = len(os.sched_getaffinity(0))
    if pin:
        mine = os.sched_getaffinity(0) | set(process_cpus())
        if comm is not None:
            from mpi4py import MPI
            node = comm.Split_type(MPI.COMM_TYPE_SHARED)
            pool = set().union(*node.allgather(mine))
            local, local_size = node.Get_rank(), node.Get_size()
            node.Free()
        else:
            pool, local, local_size = mine, 0, 1
        try:
            plan_row = plan_binding(read_topology(pool), local_size, threads)[local]
            bind_process(plan_row, threads)
        except BindingError as e:
            problem = str(e)
    record = None
    if problem is None:
        try:
            record = thread_records(threads)
        except BindingError as e:
            problem = str(e)
    problems = comm.allgather(problem) if comm is not None else [problem]
    first = next((p for p in problems if p), None)
    if first:
        rank = problems.index(first)
        raise BindingError(first if comm is None else f"rank {rank}: {first}")
    records = comm.gather(record, root=0) if comm is not None else [record]
    rank = comm.Get_rank() if comm is not None else 0
    verdict = check_binding(records, threads, pin, given) if rank == 0 else None
    if comm is not None:
        verdict = comm.bcast(verdict, root=0)
    if verdict:
        raise BindingError(verdict)
    if rank != 0:
        return None
    return {"pinned": bool(pin), "held": True, "threads": threads, "launcher_cpus": given, "ranks": records}


def thread_cpu_sets(affinity):
    """Each numba thread's CPU set [T] (sorted lists, thread order) at the start, from establish's
    record of one process (the studies that time threads in one process: bench schemes, bench perf
    --what phases)."""
    return [t["cpus"] for t in affinity["ranks"][0]["threads"]]


def recheck(affinity, threads, pin, comm=None):
    """After the timed steps: the records again (affinity['after']) and whether the binding still
    held (affinity['held']). Collective under MPI; returns the updated dict on rank 0."""
    try:
        record = thread_records(threads)
    except BindingError:
        record = None
    records = comm.gather(record, root=0) if comm is not None else [record]
    if affinity is None:
        return None
    if any(r is None for r in records):
        affinity["held"] = False
        affinity["after_problem"] = "a thread could not be reached after the run"
    else:
        verdict = check_binding(records, threads, pin, affinity.get("launcher_cpus"))
        moved = pin and any([t["cpus"] for t in a["threads"]] != [t["cpus"] for t in b["threads"]]
                            for a, b in zip(affinity["ranks"], records))
        affinity["held"] = verdict is None and not moved
        if verdict:
            affinity["after_problem"] = verdict
    affinity["after"] = records
    return affinity
