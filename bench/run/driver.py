"""`bench run`: one scene, one mapping -> run.json, steps.csv, state.npz (DESIGN.md contracts).

run(args) validates the inputs, builds (or loads) the scene, chooses the time step once
(dem.timestep.choose_time_step) and either runs the mode here or hands P > 1 to the launcher
(bench.run.launch), whose ranks each run execute() (bench.run.rank).
"""
import os
import sys
import time

from bench.run.checkpoint import load_checkpoint, write_checkpoint
from bench.run.figure import plot_run
from bench.run.guard import StabilityGuard
from bench.run.launch import launch_mpi
from bench.run.options import mode_options
from bench.run.prepare import prepare
from bench.run.records import StepWriter, environment, merge_step_files, prepare_output, write_json, write_state
from bench.run.snapshots import write_snapshot
from dem.scene import SceneError, load_scene
from dem.timestep import TimeStep, choose_time_step
from modes.base import ModeError, mode_for, parse_mapping
from modes.halo import WIDTH, ghost_fields, moving_fields
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
    mapping = parse_mapping(args.mapping)
    mode_cls = mode_for(mapping)
    if args.scheme is not None and mapping.threads == 1:
        raise ModeError(f"--scheme {args.scheme} needs a mapping with more than one thread")
    scheme = args.scheme or ("dynamic" if mapping.threads > 1 else None)
    if scheme is not None:
        if scheme not in SCHEMES:
            raise ModeError(f"unknown scheme {scheme!r} (schemes: {', '.join(SCHEMES)})")
    # progress of a scene build only on a terminal: logs and tests see one line per outcome
    log = None if args.quiet or not sys.stderr.isatty() else (lambda msg: print(msg, file=sys.stderr, flush=True))
    if args.restart:
        scene, ts = load_restart(args)
    else:
        if not args.scene:
            raise SceneError("bench run needs --scene NAME|FILE.toml (or --restart FILE)")
        args.contact_method = args.contact_method or "exact"
        scene = load_scene(args.scene, particles=args.particles, shape=args.shape, seed=args.seed,
                           overlap_limit=args.guard_overlap)
        if scene.extras.get("build") and (args.dt if args.dt is not None else scene.dt) != "auto":
            choose_time_step(scene, args.dt)  # a numeric dt is refused before the (expensive) build
    scene.extras["clock0"] = clock0
    scene.extras["load_s"] = time.perf_counter() - clock0
    out = args.out or os.path.join("results", f"run-{scene.name}")
    prepare_output(out)
    if not args.restart:
        prepare(scene, log=log)
        ts = choose_time_step(scene, args.dt)  # the run's one time step (the ranks receive it)
        for w in ts.warnings:
            print(f"bench: warning: {w}", file=sys.stderr)
    if mapping.procs > 1:
        return launch_mpi(args, mapping, scene, out, ts)
    mode = mode_cls().setup(scene, dt=ts.dt, **mode_options(mapping, args, scheme))
    return execute(args, scene, mapping, scheme, mode, out, ts)


def load_restart(args):
    """The scene and TimeStep of `--restart FILE` (bench.run.checkpoint). The scene, its particles
    and the time step are the checkpoint's: options that would change them are refused in one
    line; the contact method defaults to the checkpoint's."""
    for name in ("scene", "particles", "shape", "seed", "dt"):
        if getattr(args, name, None) is not None:
            raise SceneError(f"--restart continues the checkpoint's scene and time step: --{name} cannot be given "
                             f"with it")
    scene, meta = load_checkpoint(args.restart)
    args.contact_method = args.contact_method or meta.get("contact_method") or "exact"
    return scene, TimeStep.from_dict(meta["time_step"])


def execute(args, scene, mapping, scheme, mode, out, ts, comm=None):
    """The timed run loop of one process, or of every rank (comm given): warm-up, steps, records.

    Rank 0 writes run.json, state.npz and (merged) steps.csv; each rank writes its own rows.
    Decisions that end the loop are taken collectively so that no rank waits for a dead one."""
    dt = ts.dt
    rank = comm.Get_rank() if comm is not None else 0
    resume = scene.extras.get("restart")  # a checkpoint's meta (bench.run.checkpoint), or None
    step0 = int(resume["step"]) if resume else 0            # the records' step number reached so far
    time0 = float(resume["time"]) if resume else 0.0        # simulated time [s] so far
    warm0 = int(resume.get("warmup_total", 0)) if resume else 0
    if args.steps is not None:
        steps = args.steps
    else:
        steps = max(0, int(resume["steps_target"]) - step0) if resume else scene.steps
    every = getattr(args, "checkpoint_every", 0) or 0
    t_compile = time.perf_counter()
    mode.warmup()
    t_ready = time.perf_counter()
    t_compile = t_ready - t_compile
    warm = getattr(args, "warmup", 0) or 0
    for _ in range(warm):  # untimed, unrecorded: the state advances
        mode.step()
    t_warm_steps = time.perf_counter() - t_ready
    clock0 = scene.extras.get("clock0")
    try:
        import numba
        layer = numba.threading_layer()
    except ValueError:  # no parallel region has run (serial mode)
        layer = None

    def total(x):
        return comm.allreduce(x) if comm is not None else x

    n_total = total(mode.state.n_owned)
    info = {"command": "bench " + " ".join(sys.argv[1:]) if sys.argv and sys.argv[0].endswith("bench") else None,
            "argv": sys.argv, "scene": scene.name, "scene_source": scene.source,
            "particles": n_total, "steps": steps, "mapping": str(mapping), "mode": mapping.kind,
            "procs": mapping.procs, "px": mapping.px, "py": mapping.py, "pz": mapping.pz,
            "threads": mapping.threads, "scheme": scheme,
            "threaded": args.threaded if mapping.threads > 1 else None, "pin": args.pin,
            "threading": _threading_info(),
            "neighbor": args.neighbor, "contact_method": getattr(args, "contact_method", "exact"),
            "skin": mode.skin_fraction, "skin_m": mode.skin, "skin_requested": args.skin,
            "halo": args.halo if mapping.procs > 1 else None,
            "update_grid": args.update_grid if mapping.procs > 1 else None, "dt": dt, "dt_auto": ts.auto,
            "dt_critical": ts.critical, "dt_details": ts.details, "walls": scene.walls, "gravity": scene.gravity.tolist(),
            "materials": [m.__dict__ for m in scene.materials.materials],
            "environment": environment(), "warmup_s": t_compile, "warmup_steps": getattr(args, "warmup", 0), "threading_layer": layer,
            "build": scene.extras.get("built"), "stable": None, "max_overlap_ratio": 0.0, "status": "running",
            "restart": ({"from": resume["path"], "step": step0, "time": time0, "written_by": resume.get("mapping")}
                        if resume else None),
            "checkpoint_every": every or None, "step_first": step0 + 1, "step_last": step0 + steps,
            "time_start": time0 + warm * dt}
    if comm is not None:
        from mpi4py import MPI  # here, not at the top: importing it starts MPI
        info["mpi_library"] = MPI.Get_library_version().strip().splitlines()[0]
        fields = ghost_fields(mode.all_spheres, mode.state.has_poly)
        info["ghost_fields"] = list(fields)
        info["ghost_bytes_per_particle"] = 8 * sum(WIDTH[f] for f in fields)  # the paper: 624 per ellipsoid
        info["forward_bytes_per_ghost"] = 8 * sum(WIDTH[f] for f in moving_fields(mode.all_spheres))
        wires = comm.gather(mode.wire.as_dict() if mode.wire is not None else None, root=0)
        info["wire"] = {str(r): w for r, w in enumerate(wires)} if rank == 0 else None
    if rank == 0:
        write_json(os.path.join(out, "run.json"), info)
    step_file = os.path.join(out, "steps.csv" if comm is None else f"steps.rank{rank}.csv")
    writer = StepWriter(step_file)
    snap_dir = os.path.join(out, "snapshots")
    if args.snapshot_every and rank == 0:
        os.makedirs(snap_dir, exist_ok=True)
    guard = StabilityGuard(mode, dt, ts.critical, scene.gravity, comm=comm,
                           overlap=getattr(args, "guard_overlap", 0.05), resume=resume["guard"] if resume else None)
    ke0 = guard.ke0
    ckpt_path = os.path.join(out, "checkpoint.npz")
    ckpt = {"written": 0, "seconds": 0.0, "bytes": 0, "step": None}

    def checkpoint(k):
        """Write DIR/checkpoint.npz after timed step k (collective under MPI); its time is outside the
        step timers (it is recorded in run.json)."""
        t = time.perf_counter()
        meta = {"step": step0 + k, "time": time0 + (warm + k) * dt, "warmup_total": warm0 + warm,
                "steps_target": step0 + steps, "time_step": ts.as_dict(), "guard": guard.sums(),
                "contact_method": args.contact_method or "exact", "neighbor": args.neighbor,
                "mapping": str(mapping), "scheme": scheme}
        ckpt["bytes"] = write_checkpoint(ckpt_path, mode, scene, meta, comm=comm)
        ckpt["seconds"] += time.perf_counter() - t
        ckpt["written"] += 1
        ckpt["step"] = step0 + k
    series = {"step": [], "totalT": [], "n_contacts": [], "ke": []}
    t_wall = time.perf_counter()
    # setup: from the start of the run (this process) to its first step: scene load or checkpoint, build
    # (or its cache), time step, mode set-up, JIT warm-up (the --warmup steps apart: warmup_steps_s)
    setup = {"load_s": scene.extras.get("load_s"), "setup_s": (t_ready - clock0) if clock0 is not None else None,
             "warmup_steps_s": t_warm_steps}
    stable = True
    reason = None
    try:
        for k in range(1, steps + 1):
            row = mode.step()
            writer.write(step0 + k, rank, row)
            reason = guard.check(step0 + k, row)  # collective: every rank stops at the same step
            if args.plot:
                series["step"].append(step0 + k)
                series["totalT"].append(row["totalT"])
                series["n_contacts"].append(total(row["n_contacts"]))
                series["ke"].append(getattr(guard, "ke_last", 0.0))
            if reason:
                stable = False
                break
            if args.snapshot_every and (step0 + k) % args.snapshot_every == 0:
                write_snapshot(mode, snap_dir, step0 + k, dt, rank)
            if every and ((step0 + k) % every == 0 or k == steps):
                checkpoint(k)
    finally:
        writer.close()
    wall = time.perf_counter() - t_wall
    mode.release()  # MPI: complete the exchange the last step started, free its requests
    snap = mode.snapshot()
    worst = mode.max_overlap_ratio if comm is None else comm.allreduce(mode.max_overlap_ratio, op=_max_op())
    energy = guard.balance()
    ke1 = energy["kinetic_final"]
    if comm is not None:
        comm.Barrier()
    if rank != 0:
        return 0
    if comm is not None:
        merge_step_files(out, comm.Get_size())
    write_state(os.path.join(out, "state.npz"), snap)
    info.update({"stable": stable, "stability_reason": reason, "status": "done" if stable else "unstable",
                 "max_overlap_ratio": worst, "wall_s": wall,
                 "neighbor_rebuilds": mode.pairs.rebuilds,
                 "grid_updates": getattr(mode, "grid_updates", None),
                 "kinetic_energy_initial": ke0, "kinetic_energy_final": ke1, "energy_balance": energy,
                 "guard": {"overlap_limit": guard.overlap, "energy_factor": guard.energy_factor},
                 **setup, "simulated_time": steps * dt, "time_end": time0 + (warm + (k if steps else 0)) * dt,
                 "checkpoint": ({"path": ckpt_path, "written": ckpt["written"], "last_step": ckpt["step"],
                                 "bytes": ckpt["bytes"], "seconds": ckpt["seconds"]} if every else None)})
    write_json(os.path.join(out, "run.json"), info)
    if args.plot:
        plot_run(series, os.path.join(out, "run.png"), title=f"{scene.name}, {n_total} particles, {mapping}")
    if not args.quiet:
        print(f"{scene.name}: {n_total} particles, {steps} steps of {dt:.3g} s, mapping {mapping}: "
              f"{wall:.2f} s ({1e6 * wall / max(steps, 1) / max(n_total, 1):.3f} us/particle-step), "
              f"max overlap {worst:.2e}; records in {out}")
    if not stable:
        print(f"bench: error: {reason}", file=sys.stderr)
        return 1
    return 0


def _max_op():
    from mpi4py import MPI
    return MPI.MAX
