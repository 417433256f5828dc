"""One MPI rank of `bench perf --what overhead --in-job` (started by bench.studies.perf_overhead
through `mpiexec -n 2 python -m mpi4py -m bench.studies.perf_overhead_rank --scene S --particles N
--cycles C --json FILE [--skin F] [--ceiling]`).

2 ranks against serial inside one MPI job, so that the machine's state, which drifts over seconds
to minutes on a shared host, is the same for both sides of each ratio. Each rank is pinned to a CPU
of its own (bench.run.binding, as `--pin`) and holds two set-ups of the same scene: the 2-rank mode
(2-2-1-1-1, its block) and a serial copy of the whole scene. A cycle is three blocks of
BLOCK_STEPS steps, in an order that rotates with the cycle: the 2 ranks stepping together, rank 0
stepping its serial copy while rank 1 sleeps, rank 1 stepping its own while rank 0 sleeps (so the
serial side runs once on each CPU; the sleeping rank polls a non-blocking barrier every 0.2 ms
instead of spinning in MPI's wait). Every set-up advances BLOCK_STEPS steps a cycle, so all three
hold the same physical state at each cycle's end (the trajectory is bit-identical across modes:
checked at the end, the `identical` field). With --ceiling a cycle also holds the in-step
ceiling's three blocks of a serial copy at half the particles (stepped at the whole scene's time
step): alone on rank 0's CPU, alone on rank 1's (the other asleep), and on both at once, meeting
after every step at an MPI barrier (its time is step and meeting, the mean of the two ranks').

A block's time is the mean over its steps, after its first DROP_STEPS, of the step's totalT, for
the 2 ranks the larger of the two ranks' (the runs.csv definition, bench.sweep.records.module_times);
commuT, syncT, migraT and wire_s of the 2-rank blocks are means over both ranks and the same steps.
Rank 0 writes FILE (JSON): the cycles' times, the ranks' CPU sets, the step count and the end
states' comparison. No records, no supervisor: the figures are the modes' own step times.

After a switch of set-up a block's steps run slow for some milliseconds, longer for the 2 ranks:
the caches refill, and a CPU that slept through the other rank's serial block comes back slowly.
Medians over the blocks of each step of 40-step blocks (2-vCPU VM, --skin 0, 30 cycles): 1521
falling ellipsoids, 2 ranks 391-406, 203-210, 190-192, 186 us at steps 0-3, 181-182 at step 8,
179 at step 20, 176-177 from step 30 on; serial 371-423, 299-300, 287-289 us, 283 at step 8,
281 from step 20 on. Packed 500: 2 ranks 803-810, 532, 511 us, 452-456 at step 8, ~450 from
step 20 on; serial 908-1020, 816-834, 776-808 us, 720-745 from step 20 on. With the blocks of
10 steps, 2 dropped, that the study first had, the transient was a fifth of each timed block
and weighed on the 2 ranks: their steady ratio (281.5 / 177 = 1.59 on the falling scene) read
as ~1.54. A long run steps at the steady state, so blocks are now BLOCK_STEPS = 50 steps with
the first DROP_STEPS = 20 left out (9 ms of packed steps, 3.6 ms of falling ones).
"""
import argparse
import sys
import time

import numpy as np

BLOCK_STEPS = 50   # steps a block
DROP_STEPS = 20    # first steps of a block left out of its time (the switch's transient: docstring)
IDLE_POLL_S = 2e-4  # the sleeping rank's poll of the barrier that ends a serial block
COLUMNS = ("totalT", "commuT", "syncT", "migraT", "wire_s")


def _block(mode, steps, columns=COLUMNS):
    """steps of `mode`, returning [steps, len(columns)] of their rows (0 where a row lacks one)."""
    out = np.zeros((steps, len(columns)))
    for k in range(steps):
        row = mode.step()
        out[k] = [row.get(c, 0.0) or 0.0 for c in columns]
    return out


def _in_step_block(mode, steps, meet):
    """steps of `mode`, each followed by meet() (the other copy's end of the same step): [steps]
    times [s] of step and meeting, as bench.run.copies times a copy in step."""
    out = np.empty(steps)
    for k in range(steps):
        t = time.perf_counter()
        mode.step()
        meet()
        out[k] = time.perf_counter() - t
    return out


def _idle(cart):
    """Sleep until the stepping rank reaches the barrier that ends its serial block."""
    req = cart.Ibarrier()
    while not req.Test():
        time.sleep(IDLE_POLL_S)


def _same(a, b):
    """Whether two snapshots (dem.state.State.snapshot) hold the same numbers, bit for bit."""
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def job_arguments(prog):
    """The arguments an in-job rank program takes from its study (the scene, its particles and
    skin, the cycles, the JSON file rank 0 writes); the program adds its own."""
    p = argparse.ArgumentParser(prog=prog)
    p.add_argument("--scene", required=True)
    p.add_argument("--particles", type=int, default=None)
    p.add_argument("--skin", type=float, default=None)
    p.add_argument("--cycles", type=int, required=True)
    p.add_argument("--json", required=True)
    return p


def main(argv):
    p = job_arguments("bench.studies.perf_overhead_rank")
    p.add_argument("--ceiling", action="store_true", help="also the in-step ceiling of 2 workers")
    p.add_argument("--forward", default="messages", help="the 2 ranks' forward transport (modes/window.py)")
    args = p.parse_args(argv)
    from mpi4py import MPI
    from bench.run.binding import BindingError, establish
    from bench.run.prepare import load_prepared
    from bench.run.records import write_json
    from dem.timestep import choose_time_step
    from modes.base import mode_for, parse_mapping
    from modes.serial import SerialMode
    comm = MPI.COMM_WORLD
    if comm.Get_size() != 2:
        raise SystemExit(f"bench: error: started with {comm.Get_size()} ranks, not 2")
    cart = comm.Create_cart([2, 1, 1], periods=[False] * 3, reorder=False)
    rank = cart.Get_rank()
    try:
        affinity = establish(1, True, cart)
    except BindingError as e:
        if rank == 0:
            print(f"bench: error: {e}", file=sys.stderr, flush=True)
        return 1
    # a scene each: the serial mode steps its scene's state in place
    scene, own = (load_prepared(args.scene, particles=args.particles) for _ in range(2))
    dt = choose_time_step(scene).dt
    particles = int(own.n)   # the 2-rank mode keeps its block of `scene`
    opts = {} if args.skin is None else {"skin": args.skin}
    two = mode_for(parse_mapping("2-2-1-1-1"))().setup(scene, dt=dt, cart=cart, forward=args.forward, **opts)
    one = SerialMode().setup(own, dt=dt, **opts)
    two.warmup()
    one.warmup()
    kinds = ["two", ("serial", 0), ("serial", 1)]
    half = None
    if args.ceiling:   # the in-step ceiling's copies, at half the particles
        half = SerialMode().setup(load_prepared(args.scene, particles=max(1, particles // 2)), dt=dt, **opts)
        half.warmup()
        kinds += [("alone", 0), ("alone", 1), "in_step"]
    times = {k: [] for k in kinds}
    parts = {c: [] for c in COLUMNS[1:]}
    for cycle in range(args.cycles + 1):   # cycle 0 untimed: every path run once
        for j in range(len(kinds)):
            kind = kinds[(j + cycle) % len(kinds)]
            cart.Barrier()
            if kind == "two":
                rows = _block(two, BLOCK_STEPS)[DROP_STEPS:]
                both = np.empty((2,) + rows.shape)
                cart.Allgather(np.ascontiguousarray(rows), both)
                if cycle:
                    times["two"].append(float(both[:, :, 0].max(axis=0).mean()))
                    for c, col in enumerate(COLUMNS[1:], start=1):
                        parts[col].append(float(both[:, :, c].mean()))
            elif kind == "in_step":   # both halves at once, meeting after every step as the ranks do
                mine = _in_step_block(half, BLOCK_STEPS, cart.Barrier)[DROP_STEPS:].mean()
                if cycle:
                    times["in_step"].append(float(np.mean(cart.allgather(mine))))
            elif kind[1] == rank:
                rows = _block(one if kind[0] == "serial" else half, BLOCK_STEPS)[DROP_STEPS:]
                cart.Ibarrier().Wait()
                if cycle:
                    times[kind].append(float(rows[:, 0].mean()))
            else:
                _idle(cart)
    # the blocks of each CPU were timed on that rank only
    for k in kinds[1:]:
        if k != "in_step" and k[1] == 1:
            times[k] = cart.bcast(times[k], root=1)
    snap_two = two.snapshot()                     # gathered on rank 0
    snap_one = cart.gather(one.snapshot(), root=0)
    two.release()
    if rank == 0:
        identical = bool(_same(snap_two, snap_one[0]) and _same(snap_two, snap_one[1]))
        doc = {"scene": args.scene, "particles": particles, "skin": args.skin, "cycles": args.cycles,
               "block_steps": BLOCK_STEPS, "drop_steps": DROP_STEPS,
               "steps": (args.cycles + 1) * BLOCK_STEPS, "identical": identical, "affinity": affinity,
               "forward_transport": two.forward_transport,
               "two_ranks_s": times["two"], "serial_cpu0_s": times[("serial", 0)],
               "serial_cpu1_s": times[("serial", 1)], "two_ranks_parts_s": parts}
        if half is not None:
            doc.update(ceiling_particles=int(half.state.n), alone_cpu0_s=times[("alone", 0)],
                       alone_cpu1_s=times[("alone", 1)], in_step_s=times["in_step"])
        write_json(args.json, doc)
    cart.Free()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
