"""Independent serial copies of a scene stepped side by side: the control behind `bench perf --what
contention` and `bench sweep --ceiling` (bench/studies/perf_contention.py gives the definitions).

Each copy is a spawned process with its own SerialMode on its own copy of the scene: no shared
memory, no message. Copies start together at a barrier after their warm-up and, in step, meet at
a spinning barrier after every step, as ranks meet at the step's allreduce."""
import multiprocessing
import os
import queue
import signal
import threading
import time

from bench.run.lifeline import PR_SET_PDEATHSIG, _prctl


def meet(counts, me, k):
    """Spin until every copy has finished step k (counts: shared step counts, slot me is ours)."""
    counts[me] = k
    for c in range(len(counts)):
        while counts[c] < k:
            pass


def as_copy():
    """Set up a copy's process: SIGINT is left to the parent (which stops the copies) and the copy
    dies with its parent (PR_SET_PDEATHSIG, SIGKILL)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL))


def release(counts, me):
    """A copy that fails: nobody waits at meet for it any more."""
    counts[me] = 2 ** 62


def _held_copy(setup, args, conn, counts, me, cpu=None):
    """One held copy (HeldCopies): bound to CPU cpu where given (before it allocates: first touch),
    work, info = setup(*args, meeting) once (meeting(k): meet the other copies at their k-th
    meeting), sends ("ready", info), then answers each command received on conn with ("ok",
    work(command)) until None comes, or ("error", line) once it fails. Dies with its parent;
    SIGINT is the parent's."""
    as_copy()
    try:
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        work, info = setup(*args, lambda k: meet(counts, me, k))
        conn.send(("ready", info))
        while True:
            command = conn.recv()
            if command is None:
                return
            conn.send(("ok", work(command)))
    except Exception as e:
        release(counts, me)
        conn.send(("error", f"{type(e).__name__}: {e}"))


def build_once(scene, particles, shape=None):
    """Build (and cache: bench.run.prepare) the copies' scene here, once, before they start, rather
    than by every copy at once. A scene that cannot be built is left to the copies, which say why
    in one line (HeldCopies)."""
    from bench.run.prepare import load_prepared
    from dem.scene import SceneError
    try:
        load_prepared(scene, particles=particles, shape=shape)
    except SceneError:
        pass


class HeldCopies:
    """`copies` spawned processes sharing nothing, held for a study's rounds and driven by commands:
    each runs setup(*args, meeting) once (a module-level function: it crosses to the spawned
    process) and then work(command) for each command sent to it (_held_copy); meeting(k) spins
    until every copy has reached its k-th meeting (meet), which copies that work in step call
    with the same k. A copy that fails or gives no answer in `timeout` s stops the study with one
    line; none outlives close() or the parent. info: each copy's set-up answer. cpus [copies]: copy c
    runs on CPU cpus[c] alone (a study whose threads are pinned sets its copies on the same CPUs);
    None: where the OS puts it."""

    def __init__(self, copies, setup, args, timeout=600, cpus=None):
        ctx = multiprocessing.get_context("spawn")
        self.timeout = timeout
        self.counts = ctx.RawArray("q", copies)
        self.conns, self.procs = [], []
        try:
            for me in range(copies):
                ours, theirs = ctx.Pipe()
                proc = ctx.Process(target=_held_copy, args=(setup, args, theirs, self.counts, me,
                                                            None if cpus is None else cpus[me]))
                proc.start()
                theirs.close()
                self.conns.append(ours)
                self.procs.append(proc)
            self.info = self._answers(range(copies))
        except BaseException:   # a copy failed or an interrupt came: none of them outlives the set-up
            self.close()
            raise

    def _answers(self, which):
        out = []
        for c in which:
            conn = self.conns[c]
            if not conn.poll(self.timeout):
                raise RuntimeError(f"a ceiling copy gave no answer in {self.timeout} s")
            try:
                status, got = conn.recv()
            except (EOFError, OSError):
                raise RuntimeError("a ceiling copy ended without an answer") from None
            if status == "error":
                raise RuntimeError(f"a ceiling copy failed: {got}")
            out.append(got)
        return out

    def ask(self, command, which=None):
        """Send command to the copies `which` (default all) at once; their answers, in that order."""
        which = range(len(self.conns)) if which is None else which
        for c in which:
            self.conns[c].send(command)
        return self._answers(which)

    def close(self):
        for conn in self.conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in self.procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
                proc.join()


def _copy(scene, particles, shape, steps, warmup, barrier, in_step, results, counts, me, options=None, cpu=None):
    """One worker (copy me): step a serial copy of the scene; put its step times [s] on results
    (or a line saying why it could not). It dies with its parent and leaves SIGINT to it (the
    parent stops the copies); a copy that fails frees the others from waiting for it. options: the
    serial mode's set-up options (skin, contact_method, neighbor: those of the runs it stands beside);
    cpu: the one CPU it runs on (bound before it allocates), or None."""
    as_copy()
    from bench.run.prepare import load_prepared
    from dem.timestep import choose_time_step
    from modes.serial import SerialMode
    times = []
    clock = time.perf_counter
    try:
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        sc = load_prepared(scene, particles=particles, shape=shape)
        mode = SerialMode().setup(sc, dt=choose_time_step(sc).dt, **(options or {}))
        mode.warmup()
        for _ in range(warmup):
            mode.step()
        barrier.wait()
        for k in range(1, steps + 1):
            t = clock()
            mode.step()
            if in_step:
                meet(counts, me, k)
            times.append(clock() - t)
    except Exception as e:
        results.put(("error", f"{type(e).__name__}: {e}"))
        release(counts, me)
        barrier.abort()
        return
    try:
        barrier.wait()  # report once every copy has stepped
    except threading.BrokenBarrierError:
        pass
    results.put(("ok", times))


def run_copies(scene, particles, copies, steps, warmup=5, in_step=False, shape=None, timeout=1800, options=None,
               cpus=None):
    """Step `copies` independent serial copies of the scene (each `particles` particles) at once;
    returns each copy's step times [s] (a list per copy). They start together (a barrier after
    their warm-up); in_step: they also meet at a barrier after every step. options: the serial
    mode's set-up options (None: its defaults); cpus [>= copies]: copy c on CPU cpus[c] alone
    (None: where the OS puts it)."""
    ctx = multiprocessing.get_context("spawn")
    barrier = ctx.Barrier(copies, timeout=timeout)
    results = ctx.Queue()
    counts = ctx.RawArray("q", copies)
    procs = [ctx.Process(target=_copy, args=(scene, particles, shape, steps, warmup, barrier, in_step, results,
                                             counts, me, options, None if cpus is None else cpus[me]))
             for me in range(copies)]
    for p in procs:
        p.start()
    try:
        out = [results.get(timeout=timeout) for _ in procs]
    except BaseException as e:  # no result in time, or an interrupt: the copies stop now
        for p in procs:
            p.kill()
        for p in procs:
            p.join()
        if isinstance(e, queue.Empty):
            raise RuntimeError(f"copies of {scene} at {particles} particles gave no result in {timeout} s") from None
        raise
    for p in procs:
        p.join(timeout=10)
        if p.is_alive():
            p.kill()
    bad = [msg for status, msg in out if status != "ok"]
    if bad:
        raise RuntimeError(f"a copy of {scene} at {particles} particles failed: {bad[0]}")
    return [times for _, times in out]


def _mean(xs):
    return sum(xs) / len(xs)


CONFIGURATIONS = ("serial", "alone", "together", "in_step")


def sample(scene, particles, copies, steps, warmup=5, shape=None, configs=CONFIGURATIONS, options=None, cpus=None):
    """One round of the configurations (in the order given): {configuration: mean step [s]}, every
    copy set up with the serial mode's options (None: its defaults); cpus [copies]: copy c on CPU
    cpus[c] (a lone copy on cpus[0]), or None."""
    share = max(1, particles // copies)
    plan = {"serial": (particles, 1, False), "alone": (share, 1, False), "together": (share, copies, False),
            "in_step": (share, copies, True)}
    out = {}
    for c in configs:
        n, k, in_step = plan[c]
        out[c] = _mean([_mean(t) for t in run_copies(scene, n, k, steps, warmup, in_step=in_step, shape=shape,
                                                              options=options, cpus=cpus)])
    return out


def ceilings(med):
    """The ratios of the module docstring from the configurations' step times med [s]."""
    return {"ceiling_free": med["alone"] / med["together"], "ceiling_step": med["alone"] / med["in_step"]}
