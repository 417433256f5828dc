"""A local sweep's warm start (issue 34): the scenes are built and numba's cache compiled for every
kernel the points run before the first point starts, in processes that run at once, instead of
inside the points' runs one after another.

Each point is its own `bench run`. From a cold cache the first point with one thread built its
scene (the packed pack's relaxation compiles the serial kernels: about 47 of its 55 s on 2 cores)
and the first with two threads then compiled the threads' kernels (about 31 s), while the other
core idled. Here one process builds the scenes and compiles the one-thread kernels (`python -m
bench.sweep.job warm DIR build`), and one process per thread count T > 1 compiles that count's
kernels on the scenes as generated, which have the arrays and types of the built ones (part T;
bench.sweep.job prepare), at most as many at once as the sweep has usable cores. The points start
when every part has ended, so nothing compiles beside a timed step. A part that fails is only
reported (DIR/warm/<part>/: log.txt, prepare.json, status.json): its points compile what they need
themselves, as before.
"""
import os
import signal
import subprocess
import sys
import time

from bench.run.lifeline import Interrupted, child_env
from bench.run.records import read_json_file, write_json

WARM_FOLDER = "warm"


def parts_of(points):
    """The parts of the warm start of points (bench.sweep.points Point): "build", then each thread
    count above one, ascending; () when there is nothing to run beside the build."""
    threads = sorted({int(p.mapping.split("-")[4]) for p in points} - {1})
    return ("build", *threads) if threads else ()


def warm_start(out, points, cores, env, lock_fd=None):
    """Run the warm start's parts of points (parts_of) for the sweep in out, at most `cores` at once
    (environment env; each child holds the sweep's lock, lock_fd, and dies with the sweep). Returns
    {part: exit status} (empty when there is nothing to overlap: one part, or one core). Interrupted
    (SIGINT, SIGTERM, SIGHUP), it stops the running parts and raises again."""
    parts = list(parts_of(points))
    if len(parts) < 2 or cores < 2:
        return {}
    folder = os.path.join(out, WARM_FOLDER)
    os.makedirs(folder, exist_ok=True)
    t0 = time.perf_counter()
    print(f"sweep: building the scene and compiling the kernels of {len(parts)} kinds of point at once "
        f"({', '.join(str(p) if p == 'build' else f'{p} threads' for p in parts)})", flush=True)
    pending, running, status = list(parts), {}, {}
    fds = (lock_fd,) if lock_fd is not None else ()
    try:
        while pending or running:
            while pending and len(running) < cores:
                part = pending.pop(0)
                threads = "1" if part == "build" else str(part)
                penv = dict(env, NUMBA_NUM_THREADS=threads, OMP_NUM_THREADS=threads)
                where = os.path.join(WARM_FOLDER, str(part))  # its records: prepare.json, status.json, log.txt
                os.makedirs(os.path.join(out, where), exist_ok=True)
                fh = open(os.path.join(out, where, "log.txt"), "w")
                cmd = [sys.executable, "-m", "bench.sweep.job", "warm", out, str(part), where]
                running[part] = (subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, pass_fds=fds,
                                                  env=child_env(penv, lock_fd), start_new_session=True), fh)
            for part, (proc, fh) in list(running.items()):
                if proc.poll() is not None:
                    fh.close()
                    status[part] = proc.returncode
                    del running[part]
            time.sleep(0.2)
    except (KeyboardInterrupt, Interrupted):
        for part, (proc, fh) in running.items():
            try:
                os.killpg(proc.pid, signal.SIGKILL)  # compiling only: nothing to keep
            except OSError:
                pass
            proc.wait()
            fh.close()
            path = os.path.join(out, WARM_FOLDER, str(part), "status.json")
            write_json(path, dict(read_json_file(path) or {}, status="interrupted", reason="the sweep was interrupted"))
        raise
    failed = [str(p) for p, rc in status.items() if rc != 0]
    print(f"sweep: scene and kernels ready in {time.perf_counter() - t0:.0f} s"
        + (f" (part {', '.join(failed)} failed: its points compile themselves; {folder})" if failed else ""),
        flush=True)
    return status
