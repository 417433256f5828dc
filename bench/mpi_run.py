"""One MPI rank of `bench run` (started by bench.launch through `python -m mpi4py -m bench.mpi_run`)."""
import sys


def main(argv):
    from mpi4py import MPI
    from bench.cli import build_parser
    from bench.prepare import load_prepared
    from bench.run import choose_dt, execute, mode_options
    from modes.base import mode_for, parse_mapping

    args = build_parser().parse_args(["run"] + argv)
    mapping = parse_mapping(args.mapping)
    comm = MPI.COMM_WORLD
    if comm.Get_size() != mapping.procs:
        raise SystemExit(f"bench: error: started with {comm.Get_size()} ranks for mapping {mapping}")
    cart = comm.Create_cart([mapping.px, mapping.py, mapping.pz], periods=[False] * 3, reorder=False)
    scene = load_prepared(args.scene, particles=args.particles, shape=args.shape, seed=args.seed)  # cached
    dts = choose_dt(scene, args.dt)
    scheme = args.scheme or ("dynamic" if mapping.threads > 1 else None)
    mode = mode_for(mapping)().setup(scene, dt=dts[0], cart=cart, **mode_options(mapping, args, scheme))
    execute(args, scene, mapping, scheme, mode, args.out, dts, comm=cart)
    # an unstable run has written its records and its one line (rank 0): end normally, since a
    # non-zero exit makes `python -m mpi4py` abort every rank; the launcher reads run.json
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
