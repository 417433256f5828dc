"""Execution modes: how a step of the shared DEM core (dem/) is executed.

A small registry (modes.base: REGISTRY, register, mode_for, parse_mapping of P-px-py-pz-T) of
modes behind one contract (modes.base.Mode: setup, warmup, step, snapshot, release, run_info, ...;
each class's accepts(mapping) says which mappings it runs): serial (the reference trajectory),
threads (1-1-1-1-T, the paper's five schemes, modes/parallel.py), mpi (P-px-py-pz-1, block
decomposition in modes/decomposition.py, ghosts and migration in modes/halo.py, the wire model in
modes/wire.py) and hybrid (P-px-py-pz-T).
"""
from modes.base import REGISTRY, Mapping, ModeError, parse_mapping, mode_for  # noqa: F401
from modes import serial, threads, mpi  # noqa: F401  (register serial, threads, mpi, hybrid)
