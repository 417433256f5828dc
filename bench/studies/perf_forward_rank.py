"""One MPI rank of `bench perf --what forward` (started by bench.studies.perf_forward through
`mpiexec -n P python -m mpi4py -m bench.studies.perf_forward_rank --dims PX PY PZ --scene S
--particles N --cycles C --json FILE [--skin F] [--pin]`).

The ghosts' forward exchange by messages against the same exchange through an MPI-3 shared-memory
window (modes/window.py; Hoefler et al., "MPI+MPI", Computing 95 (2013) 1121-1136), inside one MPI
job, so that the machine's state, which drifts over seconds to minutes on a shared host, is the same
for both sides of each ratio. Every rank holds two set-ups of its block of the same scene on the
PX x PY x PZ grid (bench.run.rank's Cartesian communicator): the MPI mode with `--forward messages`
and with `--forward shared`. A cycle is one block of BLOCK_STEPS steps of each, the order turning
with the cycle (messages first in even cycles), so that neither always follows the other. Both
advance the same steps, so they hold the same physical state at every cycle's end (the forward
transport never changes results: checked bit for bit at the end, the `identical` field).

A block's time is the mean over its steps, after its first DROP_STEPS (the switch's transient:
bench.studies.perf_overhead_rank), of the step's totalT of the slowest rank (the runs.csv
definition, bench.sweep.records.module_times). commuT, syncT, neighborT and compuT are each
set-up's means over the ranks and the same steps, neighbor_rebuilt the share of those steps that
built the list anew, msgs_sent the messages all ranks sent a step (the halo's Traffic counter: the
window sends no forward message between rebuilds). With --pin each rank is bound to
a CPU of its own (bench.run.binding, as `--pin`). Rank 0 writes FILE (JSON). No records, no
supervisor: the figures are the modes' own step times.
"""
import sys

import numpy as np

from bench.studies.perf_overhead_rank import BLOCK_STEPS, DROP_STEPS, _block, _same, job_arguments

COLUMNS = ("totalT", "commuT", "syncT", "neighborT", "compuT", "neighbor_rebuilt", "msgs_sent")
FORWARDS = ("messages", "shared")


def main(argv):
    p = job_arguments("bench.studies.perf_forward_rank")
    p.add_argument("--dims", type=int, nargs=3, required=True)
    p.add_argument("--pin", action="store_true", help="bind each rank to a CPU of its own")
    args = p.parse_args(argv)
    from mpi4py import MPI
    from bench.run.binding import BindingError, establish
    from bench.run.prepare import load_prepared
    from bench.run.records import write_json
    from dem.timestep import choose_time_step
    from modes.base import ModeError, mode_for, parse_mapping
    comm = MPI.COMM_WORLD
    px, py, pz = args.dims
    procs = px * py * pz
    if comm.Get_size() != procs:
        raise SystemExit(f"bench: error: started with {comm.Get_size()} ranks for a {px}x{py}x{pz} grid")
    cart = comm.Create_cart([px, py, pz], periods=[False] * 3, reorder=False)
    rank = cart.Get_rank()
    try:
        affinity = establish(1, args.pin, cart)
    except BindingError as e:
        if rank == 0:
            print(f"bench: error: {e}", file=sys.stderr, flush=True)
        return 1
    mapping = parse_mapping(f"{procs}-{px}-{py}-{pz}-1")
    opts = {} if args.skin is None else {"skin": args.skin}
    modes = {}
    try:
        for fw in FORWARDS:
            scene = load_prepared(args.scene, particles=args.particles)
            modes[fw] = mode_for(mapping)().setup(scene, dt=choose_time_step(scene).dt, cart=cart, forward=fw, **opts)
    except ModeError as e:   # the same on every rank (the set-up is collective): rank 0 says it
        if rank == 0:
            print(f"bench: error: {e}", file=sys.stderr, flush=True)
        return 2
    for m in modes.values():
        m.warmup()
    times = {fw: [] for fw in FORWARDS}
    parts = {fw: [] for fw in FORWARDS}
    for cycle in range(args.cycles + 1):   # cycle 0 untimed: every path run once
        order = FORWARDS if cycle % 2 == 0 else FORWARDS[::-1]
        for fw in order:
            cart.Barrier()
            rows = _block(modes[fw], BLOCK_STEPS, COLUMNS)[DROP_STEPS:]
            total = np.empty(rows.shape[0])
            cart.Allreduce(np.ascontiguousarray(rows[:, 0]), total, op=MPI.MAX)
            sums = np.empty(len(COLUMNS) - 1)
            cart.Allreduce(np.ascontiguousarray(rows[:, 1:].mean(axis=0)), sums, op=MPI.SUM)
            if cycle:
                times[fw].append(float(total.mean()))
                parts[fw].append(sums)
    snaps = {fw: m.snapshot() for fw, m in modes.items()}   # gathered on rank 0
    transport = {fw: m.forward_transport for fw, m in modes.items()}
    for m in modes.values():
        m.release()
    windows = modes["shared"].forward_windows
    if rank == 0:
        summed = {}
        for fw in FORWARDS:
            mean = np.mean(parts[fw], axis=0) if parts[fw] else np.zeros(len(COLUMNS) - 1)
            summed[fw] = {c: float(v) / (procs if c != "msgs_sent" else 1)
                          for c, v in zip(COLUMNS[1:], mean)}
        doc = {"dims": [px, py, pz], "procs": procs, "scene": args.scene,
               "particles": int(snaps["messages"]["pos"].shape[0]), "skin": args.skin, "cycles": args.cycles,
               "block_steps": BLOCK_STEPS, "drop_steps": DROP_STEPS, "steps": (args.cycles + 1) * 2 * BLOCK_STEPS,
               "identical": bool(_same(snaps["messages"], snaps["shared"])), "affinity": affinity, "pinned": args.pin,
               "transport": transport, "forward_windows": windows,
               "messages_s": times["messages"], "shared_s": times["shared"], "parts": summed,
               "mpi_library": MPI.Get_library_version().splitlines()[0].strip()}
        write_json(args.json, doc)
    cart.Free()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
