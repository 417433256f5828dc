"""Execution modes (serial now; threads, mpi, hybrid register here as they land)."""
from modes.base import REGISTRY, Mapping, ModeError, parse_mapping, mode_for  # noqa: F401
from modes import serial, threads, mpi  # noqa: F401  (register serial, threads, mpi, hybrid)
