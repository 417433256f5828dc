"""One MPI rank of `bench run` (started by bench.run.launch as `python -m mpi4py -m bench.run.rank`,
or by srun in a batch job): the same options as `bench run`, and the TimeStep the launcher chose
(--time-step, JSON; computed here only when a batch job starts the ranks without it).

A rank dies with its parent (the starter's proxy: PR_SET_PDEATHSIG, SIGKILL) and keeps the
default SIGTERM (an immediate end: a rank waiting in MPI could not run a handler); it beats a
heartbeat (bench.run.heartbeat) for its supervisor, which keeps and marks the records of a run
whose ranks it had to stop (issue 15)."""
import argparse
import json
import os
import signal
import sys
import time

from mpi4py import MPI

from bench.run.binding import BindingError, establish
from bench.run.checkpoint import load_checkpoint
from bench.run.driver import execute
from bench.run.heartbeat import Heartbeat, ranks_dir
from bench.run.lifeline import PR_SET_PDEATHSIG, _prctl
from bench.run.options import apply_preset, run_scheme, setup_mode
from bench.run.prepare import load_prepared
from bench.run.records import RecordError
from bench.run.spec import add_run_arguments
from dem.contact import DEFAULT_CONTACT_METHOD
from dem.timestep import TimeStep, choose_time_step
from modes.base import ModeError, parse_mapping


def _first_to_say(out):
    """True for the first rank of the run to call it (an empty marker file created exclusively; on a
    disk too full for even that, every rank is first)."""
    try:
        os.close(os.open(os.path.join(ranks_dir(out), "said"), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        return True
    except FileExistsError:
        return False
    except OSError:
        return True


def main(argv):
    clock0 = time.perf_counter()
    parser = add_run_arguments(argparse.ArgumentParser(prog="bench.run.rank"))
    parser.add_argument("--time-step", default=None, help="the launcher's TimeStep as JSON (dem.timestep)")
    args = apply_preset(parser.parse_args(argv))
    mapping = parse_mapping(args.mapping)
    comm = MPI.COMM_WORLD
    _prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL))
    if comm.Get_size() != mapping.procs:
        raise SystemExit(f"bench: error: started with {comm.Get_size()} ranks for mapping {mapping}")
    beat = Heartbeat(args.out, comm.Get_rank())
    cart = comm.Create_cart([mapping.px, mapping.py, mapping.pz], periods=[False] * 3, reorder=False)
    try:  # bound (--pin) and recorded before the scene is loaded (first touch) and anything timed
        args.affinity = establish(mapping.threads, args.pin, cart)
    except BindingError as e:  # the same on every rank: rank 0 says it, all end
        if cart.Get_rank() == 0:
            print(f"bench: error: {e}", file=sys.stderr, flush=True)
        beat.stop()
        return 1
    if args.restart:  # every rank reads the checkpoint; the mode keeps the particles of its block
        scene, meta = load_checkpoint(args.restart)
        ts = TimeStep.from_dict(meta["time_step"])
        args.contact_method = args.contact_method or meta.get("contact_method") or DEFAULT_CONTACT_METHOD
    else:
        scene = load_prepared(args.scene, particles=args.particles, shape=args.shape, seed=args.seed,
                              overlap_limit=args.guard_overlap)  # cached
        ts = TimeStep.from_dict(json.loads(args.time_step)) if args.time_step else choose_time_step(scene, args.dt)
    scene.extras["clock0"] = clock0
    scene.extras["load_s"] = time.perf_counter() - clock0
    scheme = run_scheme(mapping, args)
    try:
        mode = setup_mode(mapping, args, scene, ts.dt, comm=cart)
    except ModeError as e:  # the set-up decides collectively, so every rank refuses alike: rank 0 says it
        if cart.Get_rank() == 0:
            print(f"bench: error: {e}", file=sys.stderr, flush=True)
        beat.stop()
        return 1
    beat.phase = "running"
    try:
        execute(args, scene, mapping, scheme, mode, args.out, ts, comm=cart, beat=beat)
    except RecordError as e:  # a full disk: the first rank to fail says it, in one line (the others
        if _first_to_say(args.out):  # are stopped when this one ends); its supervisor keeps the rows
            print(f"bench: error: rank {cart.Get_rank()}: {e}", file=sys.stderr, flush=True)
        beat.stop()
        return 1
    # an unstable run has written its records and its one line (rank 0): end normally, since a
    # non-zero exit makes `python -m mpi4py` abort every rank; the launcher reads run.json
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
