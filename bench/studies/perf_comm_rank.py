"""One MPI rank of `bench perf --what comm` (started by bench.studies.perf_comm through
`mpiexec -n P python -m mpi4py -m bench.perf_comm_rank --dims PX PY PZ --json FILE ...`).

The ranks sit on the non-periodic Cartesian grid PX x PY x PZ (rank order as bench.run.rank's
`Create_cart(..., reorder=False)`), each pings its up to 26 neighbour blocks (the directions of
modes.decomposition, as the halo exchange sends to them) with modes.wire.pingpong, and rank 0
writes every rank's record to FILE as JSON; with --patterns the ranks then time the forward
exchange's MPI patterns with all their neighbours at once (modes.wire.exchange_patterns). No
physics, no numba.
"""
import argparse
import json
import sys
from modes.decomposition import BlockGrid
from modes.decomposition import DIRECTIONS
from modes.wire import DEFAULT_SIZES, exchange_patterns, pingpong


def neighbour_ranks(cart, grid, coords):
    """{neighbour rank: [direction indices k of modes.decomposition.DIRECTIONS]} of block `coords`."""
    out = {}
    for k in range(len(DIRECTIONS)):
        c = grid.neighbour(coords, k)
        if c is not None:
            out.setdefault(int(cart.Get_cart_rank([int(x) for x in c])), []).append(k)
    return out


def main(argv):
    p = argparse.ArgumentParser(prog="bench.studies.perf_comm_rank")
    p.add_argument("--dims", type=int, nargs=3, required=True)
    p.add_argument("--sizes", default=None, help="comma-separated message sizes [B]")
    p.add_argument("--time-per-size", type=float, default=2e-3)
    p.add_argument("--json", required=True)
    p.add_argument("--patterns", action="store_true", help="also time the forward exchange's MPI patterns")
    args = p.parse_args(argv)
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    px, py, pz = args.dims
    if comm.Get_size() != px * py * pz:
        raise SystemExit(f"bench: error: started with {comm.Get_size()} ranks for a {px}x{py}x{pz} grid")
    cart = comm.Create_cart([px, py, pz], periods=[False] * 3, reorder=False)
    grid = BlockGrid(((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)), (px, py, pz))  # only the topology is used
    coords = [int(c) for c in cart.Get_coords(cart.Get_rank())]
    neigh = neighbour_ranks(cart, grid, coords)
    sizes = [int(s) for s in args.sizes.split(",")] if args.sizes else list(DEFAULT_SIZES)
    cart.Barrier()
    t0 = MPI.Wtime()
    res = pingpong(cart, sorted(neigh), sizes=sizes, time_per_size=args.time_per_size)
    patterns = exchange_patterns(cart, sorted(neigh)) if args.patterns else None
    wall = cart.allreduce(MPI.Wtime() - t0, op=MPI.MAX)
    rec = {"rank": cart.Get_rank(), "coords": coords, "host": MPI.Get_processor_name(),
           "directions": {str(r): ks for r, ks in sorted(neigh.items())},
           "partners": {str(r): v for r, v in sorted(res.items())}}
    recs = cart.gather(rec, root=0)
    if cart.Get_rank() == 0:
        doc = {"dims": [px, py, pz], "procs": cart.Get_size(), "sizes": sizes,
               "time_per_size_s": args.time_per_size, "wall_s": wall,
               "mpi_library": MPI.Get_library_version().splitlines()[0].strip(),
               "mpi_wtick_s": MPI.Wtick(), "ranks": recs}
        if patterns is not None:
            doc["patterns"] = {name: {str(n): t for n, t in v.items()} for name, v in patterns.items()}
        with open(args.json, "w") as fh:
            json.dump(doc, fh, indent=1)
    cart.Free()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
