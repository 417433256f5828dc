"""`bench run`: one scene, one mapping -> run.json, steps.csv, state.npz (DESIGN.md contracts).

run(args) validates the inputs, builds (or loads) the scene, chooses the time step once
(dem.timestep.choose_time_step) and either runs the mode here or hands P > 1 to the launcher
(bench.run.launch), whose ranks each run execute() (bench.run.rank).

Faults (issue 15): a run started by a launcher dies with it (bench.run.lifeline); SIGTERM and
SIGHUP stop a run here as Ctrl-C does, with its records kept and run.json `interrupted`; a record
that cannot be written (full disk) ends the run with one line, run.json `failed` (written in the
space of bench.run.records.Reserve), every earlier row kept.
"""
import os
import socket
import sys
import time

import numpy as np

from bench.run.binding import establish, recheck
from bench.run.checkpoint import load_checkpoint, write_checkpoint
from bench.run.guard import StabilityGuard
from bench.run.launch import launch_mpi
from bench.run.lifeline import Interrupted, die_with_parent, raise_on_signals, signal_name
from bench.run.load import LoadMeter, step_spread
from bench.run.options import run_scheme, setup_mode
from bench.run.prepare import prepare
from bench.run.progress import Progress, build_log
from bench.run.records import (RecordError, Reserve, StepWriter, environment, merge_step_files, prepare_output,
                               read_step_rows, write_json, write_state)
from bench.run.snapshots import write_snapshot
from bench.run.spec import recorded
from bench.run.transport import transport_info
from dem.contact import DEFAULT_CONTACT_METHOD
from dem.scene import SceneError, load_scene
from dem.timestep import TimeStep, choose_time_step
from modes.base import ModeError, mode_for, parse_mapping
from modes.parallel import SCHEMES


def _threading_info():
    import numba
    info = {"NUMBA_NUM_THREADS": numba.config.NUMBA_NUM_THREADS, "layer": None}
    for k in ("OMP_PROC_BIND", "OMP_PLACES", "OMP_WAIT_POLICY", "NUMBA_THREADING_LAYER"):
        if k in os.environ:
            info[k] = os.environ[k]
    return info


def run(args):
    clock0 = time.perf_counter()
    die_with_parent()  # started by a launcher: end with it
    raise_on_signals()  # SIGTERM, SIGHUP: stop like Ctrl-C, records kept
    mapping = parse_mapping(args.mapping)
    mode_for(mapping)  # a mapping no registered mode accepts is refused before anything is built
    if args.scheme is not None and mapping.threads == 1:
        raise ModeError(f"--scheme {args.scheme} needs a mapping with more than one thread")
    scheme = run_scheme(mapping, args)
    if scheme is not None:
        if scheme not in SCHEMES:
            raise ModeError(f"unknown scheme {scheme!r} (schemes: {', '.join(SCHEMES)})")
    # progress of a scene build: each of its lines on a terminal, one every 10 s elsewhere (a log)
    log = None if args.quiet else build_log()
    if args.restart:
        scene, ts = load_restart(args)
    else:
        if not args.scene:
            raise SceneError("bench run needs --scene NAME|FILE.toml (or --restart FILE)")
        args.contact_method = args.contact_method or DEFAULT_CONTACT_METHOD
        scene = load_scene(args.scene, particles=args.particles, shape=args.shape, seed=args.seed,
                           overlap_limit=args.guard_overlap)
        if scene.extras.get("build") and (args.dt if args.dt is not None else scene.dt) != "auto":
            time_step(scene, args.dt)  # a numeric dt is refused before the (expensive) build
    scene.extras["clock0"] = clock0
    scene.extras["load_s"] = time.perf_counter() - clock0
    out = args.out if args.out is not None else os.path.join("results", f"run-{scene.name}")
    steps = args.steps if args.steps is not None else (
        max(0, int(scene.extras["restart"]["steps_target"]) - int(scene.extras["restart"]["step"]))
        if args.restart else scene.steps)
    prepare_output(out, need=record_bytes(scene.n, steps, mapping.procs, getattr(args, "checkpoint_every", 0)))
    if not args.restart:
        prepare(scene, log=log)
        ts = time_step(scene, args.dt)  # the run's one time step (the ranks receive it)
        for w in ts.warnings:
            print(f"bench: warning: {w}", file=sys.stderr)
    if mapping.procs > 1:
        return launch_mpi(args, mapping, scene, out, ts)
    # bound (--pin) and recorded before the mode allocates (first touch) and before any timing
    args.affinity = establish(mapping.threads, args.pin)
    mode = setup_mode(mapping, args, scene, ts.dt)
    return execute(args, scene, mapping, scheme, mode, out, ts)


def record_bytes(n, steps, procs, checkpoint_every=0):
    """Estimated bytes of a run's records: steps.csv (about 250 B a row, one row per step and
    rank, twice under MPI while the rank files are merged), state.npz (about 150 B a particle),
    a checkpoint (about 1 KiB a particle with its contact history, twice while it is replaced),
    run.json and the reserve (1 MiB)."""
    return (250 * steps * procs * (2 if procs > 1 else 1) + 150 * n + (2048 * n if checkpoint_every else 0)
            + 2**20)


def time_step(scene, dt):
    """dem.timestep.choose_time_step, with a time step that cannot be computed (an overflow, or not
    a positive number) explained by the input that makes it so (dem.limits.explain_time_step)."""
    try:
        ts = choose_time_step(scene, dt)
    except (OverflowError, ZeroDivisionError, FloatingPointError, SceneError) as e:
        if isinstance(e, SceneError) and "must be positive" not in str(e):
            raise
        from dem.limits import explain_time_step
        raise SceneError(explain_time_step(scene, dt, e)) from None
    return ts


def load_restart(args):
    """The scene and TimeStep of `--restart FILE` (bench.run.checkpoint). The scene, its particles
    and the time step are the checkpoint's: options that would change them are refused in one
    line; the contact method defaults to the checkpoint's."""
    for name in ("scene", "particles", "shape", "seed", "dt"):
        if getattr(args, name, None) is not None:
            raise SceneError(f"--restart continues the checkpoint's scene and time step: --{name} cannot be given "
                             f"with it")
    scene, meta = load_checkpoint(args.restart)
    args.contact_method = args.contact_method or meta.get("contact_method") or DEFAULT_CONTACT_METHOD
    return scene, TimeStep.from_dict(meta["time_step"])


class RunSpan:
    """Where the timed steps of one process's run lie in the simulation: from a checkpoint's step and
    time (--restart) or from 0, this run's warm-up steps (untimed; they advance the state) and timed
    steps."""

    def __init__(self, args, scene, dt):
        self.resume = scene.extras.get("restart")  # a checkpoint's meta (bench.run.checkpoint), or None
        resume = self.resume
        self.step0 = int(resume["step"]) if resume else 0            # the records' step number reached so far
        self.time0 = float(resume["time"]) if resume else 0.0        # simulated time [s] so far
        self.warm0 = int(resume.get("warmup_total", 0)) if resume else 0  # the runs before's warm-up steps
        if args.steps is not None:
            self.steps = args.steps
        else:
            self.steps = max(0, int(resume["steps_target"]) - self.step0) if resume else scene.steps
        self.warm = getattr(args, "warmup", 0) or 0
        self.dt = dt

    def time(self, k):
        """The simulated time [s] after timed step k of this run (k = 0: after its warm-up)."""
        return self.time0 + (self.warm + k) * self.dt


def execute(args, scene, mapping, scheme, mode, out, ts, comm=None, beat=None):
    """The timed run loop of one process, or of every rank (comm given): warm-up, steps, records.

    Rank 0 writes run.json, state.npz and (merged) steps.csv; each rank writes its own rows.
    Decisions that end the loop are taken collectively so that no rank waits for a dead one.
    beat: the rank's bench.run.heartbeat.Heartbeat (its step is set as the loop goes)."""
    rank = comm.Get_rank() if comm is not None else 0
    span = RunSpan(args, scene, ts.dt)
    t_compile = time.perf_counter()
    mode.warmup()
    t_ready = time.perf_counter()
    t_compile = t_ready - t_compile
    # the guard watches the warm-up steps too (untimed, unrecorded: the state advances), so that the
    # first step it checks resolves the starting positions (an overlap there was in the scene)
    guard = StabilityGuard(mode, ts.dt, ts.critical, scene.gravity, comm=comm,
                           overlap=getattr(args, "guard_overlap", 0.05),
                           resume=span.resume["guard"] if span.resume else None)
    reason = None
    for w in range(1, span.warm + 1):
        reason = guard.check(f"{w} of the warm-up", mode.step())
        if reason:
            break
    t_warm_steps = time.perf_counter() - t_ready
    info = run_record(args, scene, mapping, scheme, mode, ts, span, t_compile, comm)
    if rank == 0 and "block_particles" in info:  # the mode's blocks (MPI)
        for w in empty_block_warnings(np.asarray(info["block_particles"]), args.update_grid):
            print(f"bench: warning: {w}", file=sys.stderr, flush=True)
    reserve = Reserve(out) if rank == 0 else None
    run_json = os.path.join(out, "run.json")
    if rank == 0:
        write_json(run_json, info)
    writer = StepWriter(os.path.join(out, "steps.csv" if comm is None else f"steps.rank{rank}.csv"))
    snap_dir = os.path.join(out, "snapshots")
    if args.snapshot_every and rank == 0:
        os.makedirs(snap_dir, exist_ok=True)
    checkpoints = Checkpoints(os.path.join(out, "checkpoint.npz"), args, scene, mapping, scheme, mode, ts, guard,
                              span, comm)
    meter = LoadMeter().start()
    t_wall = time.perf_counter()
    # setup: from the start of the run (this process) to its first step: scene load or checkpoint, build
    # (or its cache), time step, mode set-up, JIT warm-up (the --warmup steps apart: warmup_steps_s)
    clock0 = scene.extras.get("clock0")
    setup = {"load_s": scene.extras.get("load_s"), "setup_s": (t_ready - clock0) if clock0 is not None else None,
             "warmup_steps_s": t_warm_steps}
    # between the timed steps: a bar on a terminal, a line every 10 s elsewhere (rank 0, not --quiet)
    progress = Progress(span.steps, f"{scene.name} {mapping}", enabled=rank == 0 and not args.quiet)
    loop = StepLoop(args, mode, guard, span, writer, progress, checkpoints, snap_dir, rank, comm, beat)
    try:
        if reason is None:
            reason = loop.run()
        writer.close()
    except (KeyboardInterrupt, Interrupted, RecordError) as e:
        # one process (a rank's own SIGTERM ends it at once: its supervisor keeps the records)
        progress.close()
        record_stop(e, loop.k, info, run_json, writer, reserve, t_wall)
        raise
    stable = reason is None
    wall = time.perf_counter() - t_wall
    progress.close()
    meter.stop()
    if hasattr(args, "affinity"):  # did the binding hold through the run (collective)
        info["affinity"] = recheck(args.affinity, mapping.threads, args.pin, comm)
    mode.release()  # MPI: complete the exchange the last step started, free its requests
    snap = mode.snapshot()
    worst = mode.max_overlap_ratio if comm is None else comm.allreduce(mode.max_overlap_ratio, op=_max_op())
    energy = guard.balance()
    host = socket.gethostname()
    own = meter.own
    if comm is not None:  # the CPU of every rank on rank 0's host is the run's own
        root_host = comm.bcast(host, root=0)
        own = sum(cpu for h, cpu in comm.allgather((host, meter.own)) if h == root_host)
        comm.Barrier()
    if beat is not None:
        beat.stop()
    if rank != 0:
        return 0
    try:
        if comm is not None:
            merge_step_files(out, comm.Get_size())
        write_state(os.path.join(out, "state.npz"), snap)
    except RecordError as e:
        reserve.release()
        info.update(status="failed", reason=str(e))
        try:
            write_json(run_json, info)
        except RecordError:
            pass
        raise
    rows = read_step_rows(os.path.join(out, "steps.csv"))
    spread = step_spread(rows.groupby("step")["totalT"].max().to_numpy() if len(rows) else [])
    info.update(outcome_record(mode, guard, span, loop.k, reason, energy, worst, wall, meter, own, spread, setup,
                               checkpoints))
    reserve.release()
    write_json(run_json, info)
    n_total, dt, steps = info["particles"], ts.dt, span.steps
    if args.plot:
        from bench.run.figure import plot_run   # here: matplotlib costs every rank 0.4 s to import
        plot_run(loop.series, os.path.join(out, "run.png"), title=f"{scene.name}, {n_total} particles, {mapping}")
    if not args.quiet:
        print(f"{scene.name}: {n_total} particles, {steps} steps of {dt:.3g} s, mapping {mapping}: "
              f"{wall:.2f} s ({1e6 * wall / max(steps, 1) / max(n_total, 1):.3f} us/particle-step), "
              f"max overlap {worst:.2e}; records in {out}")
    if not stable:
        print(f"bench: error: {reason}", file=sys.stderr)
        return 1
    return 0


def _take(part, *keys):
    """The items of `keys` taken out of the dict part (None for a key it lacks), in that order."""
    return {key: part.pop(key, None) for key in keys}


def run_record(args, scene, mapping, scheme, mode, ts, span, t_compile, comm=None):
    """run.json as it is written before the first timed step (collective under MPI: the particles'
    total and the mode's part, mode.run_info(), whose set-up keys sit with the run's options and
    the rest, the decomposition's, at the end). t_compile: the JIT warm-up's seconds."""
    try:
        import numba
        layer = numba.threading_layer()
    except ValueError:  # no parallel region has run (serial mode)
        layer = None
    n_total = comm.allreduce(mode.state.n_owned) if comm is not None else mode.state.n_owned
    part = mode.run_info()  # the mode's part of run.json (collective under MPI)
    resume, step0, steps, dt = span.resume, span.step0, span.steps, ts.dt
    every = getattr(args, "checkpoint_every", 0) or 0
    info = {"command": "bench " + " ".join(sys.argv[1:]) if sys.argv and sys.argv[0].endswith("bench") else None,
            "argv": sys.argv, "scene": scene.name, "scene_source": scene.source,
            "particles": n_total, "steps": steps, "mapping": str(mapping), "mode": mapping.kind,
            "procs": mapping.procs, "px": mapping.px, "py": mapping.py, "pz": mapping.pz,
            "threads": mapping.threads, "scheme": scheme,
            "threading": _threading_info(), "affinity": getattr(args, "affinity", None),
            "mpi_transport": transport_info(),
            **recorded(args, mapping, "run.json"),  # threaded, pin, neighbor, preset, contact_method, halo, ...
            "preset_overrides": getattr(args, "preset_overrides", None) or None,
            **_take(part, "skin", "skin_m"), "skin_requested": args.skin,
            **_take(part, "halo_skin", "halo_skin_m", "newton", "balance"),
            "dt": dt, "dt_auto": ts.auto,
            "dt_critical": ts.critical, "dt_details": ts.details, "walls": scene.walls,
            "gravity": scene.gravity.tolist(),
            "materials": [m.__dict__ for m in scene.materials.materials],
            "environment": environment(), "warmup_s": t_compile, "warmup_steps": getattr(args, "warmup", 0),
            "threading_layer": layer,
            "build": scene.extras.get("built"), "stable": None, "max_overlap_ratio": 0.0, "status": "running",
            "pid": os.getpid(), "host": socket.gethostname(),
            "restart": ({"from": resume["path"], "step": step0, "time": span.time0,
                         "written_by": resume.get("mapping")} if resume else None),
            "checkpoint_every": every or None, "step_first": step0 + 1, "step_last": step0 + steps,
            "snapshot_format": (getattr(args, "snapshot_format", None) or "vtu") if args.snapshot_every else None,
            "time_start": span.time(0)}
    info.update(part)  # the mode's own keys (MPI: library, ghosts, wire, placement, blocks)
    return info


def outcome_record(mode, guard, span, k, reason, energy, worst, wall, meter, own, spread, setup, checkpoints):
    """What run.json adds at the end of a run that was not interrupted (rank 0): the outcome (k: the
    last timed step taken, reason: why the run stopped unstable, or None), the load, the step times'
    spread, the mode's part (mode.run_info(end=True)), the energy balance, the set-up times and the
    checkpoints."""
    stable = reason is None
    return {"stable": stable, "stability_reason": reason, "status": "done" if stable else "unstable",
            "load": dict(meter.foreign(own), wall_s=meter.wall), "step_time": spread,
            "max_overlap_ratio": worst, "wall_s": wall,
            **mode.run_info(end=True),  # neighbor_rebuilds, grid_updates, thread_recuts, block_cuts_final
            "kinetic_energy_initial": guard.ke0, "kinetic_energy_final": energy["kinetic_final"],
            "energy_balance": energy,
            "guard": {"overlap_limit": guard.overlap, "energy_factor": guard.energy_factor},
            **setup, "simulated_time": span.steps * span.dt, "time_end": span.time(k if span.steps else 0),
            "checkpoint": checkpoints.record()}


def record_stop(e, k, info, run_json, writer, reserve, t_wall):
    """run.json of a run stopped at timed step k by a signal or a record it could not write (e): the
    rows written so far are kept, and run.json says why (room made for it by the reserve)."""
    try:
        writer.close()
    except RecordError:
        pass
    if reserve is not None:
        reserve.release()  # room for run.json on a full disk
    if isinstance(e, RecordError):
        info.update(status="failed", reason=f"{e} at step {k}")
    else:
        info.update(status="interrupted", reason=f"interrupted by {signal_name(e)} at step {k}; the records "
                                                 f"up to step {writer.last_step} are kept")
    info.update(steps_done=writer.last_step, wall_s=time.perf_counter() - t_wall)
    try:
        write_json(run_json, info)
    except RecordError:
        pass


class Checkpoints:
    """--checkpoint-every K: DIR/checkpoint.npz after every K-th step of the records and after the
    run's last (collective under MPI); its time is outside the step timers (run.json `checkpoint`)."""

    def __init__(self, path, args, scene, mapping, scheme, mode, ts, guard, span, comm=None):
        self.path = path
        self.every = getattr(args, "checkpoint_every", 0) or 0
        self.args, self.scene, self.mapping, self.scheme = args, scene, mapping, scheme
        self.mode, self.ts, self.guard, self.span, self.comm = mode, ts, guard, span, comm
        self.written = 0
        self.seconds = 0.0
        self.bytes = 0
        self.step = None   # the records' step of the last one written

    def due(self, k):
        """Whether a checkpoint follows timed step k of this run."""
        return self.every and ((self.span.step0 + k) % self.every == 0 or k == self.span.steps)

    def write(self, k):
        """Write the checkpoint after timed step k (collective under MPI)."""
        span = self.span
        t = time.perf_counter()
        meta = {"step": span.step0 + k, "time": span.time(k), "warmup_total": span.warm0 + span.warm,
                "steps_target": span.step0 + span.steps, "time_step": self.ts.as_dict(), "guard": self.guard.sums(),
                **recorded(self.args, self.mapping, "checkpoint"), "mapping": str(self.mapping),
                "scheme": self.scheme}
        self.bytes = write_checkpoint(self.path, self.mode, self.scene, meta, comm=self.comm)
        self.seconds += time.perf_counter() - t
        self.written += 1
        self.step = span.step0 + k

    def record(self):
        """run.json `checkpoint` (None without --checkpoint-every)."""
        if not self.every:
            return None
        return {"path": self.path, "written": self.written, "last_step": self.step, "bytes": self.bytes,
                "seconds": self.seconds}


class StepLoop:
    """The timed steps of a run: each step's row to the step file, the guard's check (collective:
    every rank stops at the same step), the --plot series, snapshots and checkpoints."""

    def __init__(self, args, mode, guard, span, writer, progress, checkpoints, snap_dir, rank=0, comm=None,
                 beat=None):
        self.args, self.mode, self.guard, self.span = args, mode, guard, span
        self.writer, self.progress, self.checkpoints = writer, progress, checkpoints
        self.snap_dir = snap_dir
        self.snapshot_format = getattr(args, "snapshot_format", None) or "vtu"
        self.rank, self.comm, self.beat = rank, comm, beat
        self.k = 0   # the timed step being taken (or the last one taken)
        self.series = {"step": [], "totalT": [], "n_contacts": [], "ke": []}   # --plot

    def run(self):
        """Take the timed steps; returns None, or the guard's reason for the step that ended them."""
        args, mode, guard, span, rank, comm = self.args, self.mode, self.guard, self.span, self.rank, self.comm
        step0, series = span.step0, self.series
        for k in range(1, span.steps + 1):
            self.k = k
            row = mode.step()
            self.progress.update(k)
            self.writer.write(step0 + k, rank, row)
            if self.beat is not None:
                self.beat.step = step0 + k
            reason = guard.check(step0 + k, row)  # collective: every rank stops at the same step
            if args.plot:
                series["step"].append(step0 + k)
                series["totalT"].append(row["totalT"])
                series["n_contacts"].append(comm.allreduce(row["n_contacts"]) if comm is not None
                                            else row["n_contacts"])
                series["ke"].append(getattr(guard, "ke_last", 0.0))
            if reason:
                return reason
            if args.snapshot_every and (step0 + k) % args.snapshot_every == 0:
                write_snapshot(mode, self.snap_dir, step0 + k, span.time(k), rank, self.snapshot_format)
            if self.checkpoints.due(k):
                self.checkpoints.write(k)
        return None


def empty_block_warnings(counts, update_grid):
    """A line for a block grid some of whose blocks (counts [px, py, pz]: particles per block at the
    start) hold no particle: their ranks would only wait, so the point measures fewer workers than
    its mapping names."""
    empty = int((counts == 0).sum())
    if not empty:
        return []
    grid = "x".join(str(d) for d in counts.shape)
    hint = ("" if update_grid else
            "; --update-grid K fits the grid to the particles (at the start and every K steps)")
    return [f"{empty} of {counts.size} blocks of the {grid} grid hold no particle at the start, so their ranks "
            f"only wait{hint}"]


def _max_op():
    from mpi4py import MPI
    return MPI.MAX
