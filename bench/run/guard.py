"""Stability guard: cheap checks after every step, taken collectively in MPI runs.

A step fails when (1) a position or velocity is not finite, (2) a contact overlaps more than
`overlap` (default 5 %) of the smaller body's smallest semi-axis, or (3) the kinetic energy
exceeds `energy_factor` times what the run can explain: the largest of its initial kinetic
energy, the work gravity has done, the largest kinetic energy seen so far, and a floor
M (0.01 m/s)^2. Explicit integration fails suddenly once dt passes 2/omega of the stiffest
contact (contact-mechanics.md §4.3): overlaps and energy grow by orders of magnitude within a
few steps, so these thresholds are crossed long before anything else is written.
The run then stops with one line naming the step, the particles and the likely cause; every
record up to that step is kept and run.json says stable: false.

A restarted run (bench.run.checkpoint) continues the running sums of the run it continues (initial
kinetic energy, largest kinetic energy, gravity work), so its energy balance and its energy test
are those of the uninterrupted run.
"""
import numpy as np


class StabilityGuard:
    def __init__(self, mode, dt, dt_critical, gravity, comm=None, overlap=0.05, energy_factor=1e4, v_floor=0.01,
                 resume=None):
        self.mode = mode
        self.dt = dt
        self.dt_critical = dt_critical
        self.g = np.asarray(gravity, dtype=np.float64)
        self.comm = comm
        self.overlap = overlap
        self.energy_factor = energy_factor
        s = mode.state
        self.mass_total = self._sum(float(s.mass[:s.n_owned].sum()))
        self.v_floor = v_floor
        self.ke0 = self._sum(self.mode.state.kinetic_energy())
        self.ke_max = self.ke0
        self.ke_last = self.ke0
        self.gravity_work = 0.0
        if resume:  # the sums of the run this one continues (sums())
            self.ke0 = float(resume["ke0"])
            self.ke_max = float(resume["ke_max"])
            self.ke_last = float(resume["ke_last"])
            self.gravity_work = float(resume["gravity_work"])
        mode.guard_overlap = overlap  # the mode flags the step with the same limit

    def sums(self):
        """The running sums a checkpoint keeps [J]: initial, largest and last kinetic energy, gravity work."""
        return {"ke0": self.ke0, "ke_max": self.ke_max, "ke_last": self.ke_last, "gravity_work": self.gravity_work}

    def _sum(self, x):
        return self.comm.allreduce(x) if self.comm is not None else x

    def check(self, step, row):
        """None when the step is sound, else the one-line reason (the same on every rank). Reads
        the step's own sums (modes: kinetic_energy, gravity_work, n_bad, first_bad,
        max_overlap_ratio, all computed by the kernels as they pass over the particles), so a
        check costs a few comparisons and, under MPI, one allreduce."""
        reason = None
        if row["n_bad"]:
            reason = (f"non-finite position or velocity of particle {row['first_bad']}; likely cause: "
                      f"time step {self.dt:.3g} s too large (critical {self.dt_critical:.3g} s)")
        elif row["max_overlap_ratio"] > self.overlap:
            who = self.mode.worst_contact
            where = (f"particle {who[0]} and a wall" if who and who[1] == "wall" else
                     f"particles {who[0]} and {who[1]}" if who else "a contact")
            reason = (f"overlap {row['max_overlap_ratio']:.3g} of the smallest semi-axis between {where} "
                      f"(limit {self.overlap:g}); likely cause: time step {self.dt:.3g} s too large for the stiffest "
                      f"contact (critical {self.dt_critical:.3g} s) or a material too soft for its loads")
        # the mode's step ended with the run's sums (one allreduce under MPI, with its rebuild
        # decision): flagged ranks, kinetic energy, gravity work
        flagged, ke, wg = self.mode.sums
        if ke != ke:
            ke = np.inf  # NaN (a non-finite state) counts as infinite
        self.gravity_work += wg
        if flagged:
            if self.comm is not None:
                reasons = [r for r in self.comm.allgather(reason) if r]
                reason = reasons[0]
            return f"run unstable at step {step}: {reason}"
        ref = max(self.ke0, self.ke_max, self.gravity_work, self.mass_total * self.v_floor ** 2)
        if not ke <= self.energy_factor * ref:
            return (f"run unstable at step {step}: kinetic energy {ke:.3g} J is {ke / ref:.3g} times what the run "
                    f"can explain ({ref:.3g} J); likely cause: time step {self.dt:.3g} s too large "
                    f"(critical {self.dt_critical:.3g} s) or contacts too stiff for it")
        self.ke_max = max(self.ke_max, ke)
        self.ke_last = ke
        return None

    def balance(self):
        """Energy balance for run.json [J]: what came in (initial KE + gravity work) and went out."""
        ke_final = self._sum(self.mode.state.kinetic_energy())
        return {"kinetic_initial": self.ke0, "gravity_work": self.gravity_work, "kinetic_final": ke_final,
                "dissipated_or_stored": self.ke0 + self.gravity_work - ke_final}
