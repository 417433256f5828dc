"""Sweeps: one scene under many mappings (`bench sweep`, `bench plot`, `bench collect`).

points (what a point runs, its key), records (the runs.csv contract, summaries, manifest, Amdahl
fit, reading records back), launchers (a registry: local, slurm), slurm (the Slurm jobs of a
sweep: checks, scripts, submission, what the scheduler says, --status, --cancel), slurm_options
(their names and checks), job (what a Slurm job runs on its node: the prepare job, one repeat),
status (each repeat's outcome from its files and the scheduler), figures (speedup, efficiency,
EDSF, modules, error against time, drawn from runs.csv only), collect (runs.csv and figures from
the point folders), driver (the sweep). Imports: bench.run, modes and dem, never studies.
"""
