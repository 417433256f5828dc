"""Studies of the paper and of our own machinery, each a `bench` command: schemes (Table 1),
shapes (Fig. 7), accuracy (work-precision), perf (per pair and per particle-step), perf_overhead,
perf_comm (+ perf_comm_rank, the MPI ping-pong), perf_skin, perf_contact, contacts (a scene's
contacts as JSON), paper (the paper's tables as package data) and paper_figures (`bench plot
--paper`). Imports: sweep, run, modes and dem.
"""
