"""One run: a scene under one mapping (`bench run`).

options (the run's options and the mode options they give), driver (validate, build, choose the
time step once, run the timed loop: run(), execute()), launch (mpiexec for P > 1) and rank (one
MPI rank), prepare (scene build stages, cached), guard (stability checks), records (run.json,
steps.csv, state.npz), snapshots (binary VTU + a .pvd series, or legacy VTK; npz), figure
(run.png), threads_env (thread variables set before numba starts), machine (the CPU facts the
records give). Imports: modes and dem only, never sweep or studies.
"""
