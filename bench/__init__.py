"""The harness: `bench` CLI, runs, sweeps, records, metrics and plots.

Python API: ``runs, steps = bench.load(DIR)`` reads a sweep folder into pandas DataFrames.
"""


def load(path):
    """(runs, steps) DataFrames of a sweep folder (see bench.sweep.records.load)."""
    from bench.sweep.records import load as _load
    return _load(path)
