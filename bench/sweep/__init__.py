"""Sweeps: one scene under many mappings (`bench sweep`, `bench plot`, `bench collect`).

points (what a point runs, its key), records (the runs.csv contract, summaries, manifest, Amdahl
fit, reading records back), launchers (a registry: local, slurm), figures (speedup, efficiency,
EDSF, modules, error against time, drawn from runs.csv only), collect (a batch sweep's records),
driver (the sweep). Imports: bench.run, modes and dem, never studies.
"""
