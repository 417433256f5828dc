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

The cause of an overlap (issue 15) is named from what can be known:
- present at the start: the first checked step resolves the contacts of the starting positions
  (leapfrog: forces at x_0, then the move), so an overlap above the limit there was in the scene;
- an impact too fast for the material: the pair's present approach speed v along the line of
  centres (a lower bound of its impact speed, the contact slows it) gives a Hertz peak overlap
  delta_max = (15 m* v^2 / (16 E* sqrt(R*)))^(2/5) (Johnson 1985, §11.4; m* = m_i m_j / (m_i + m_j),
  E* the pair's mixed modulus, R* from the largest radii of curvature a^2/c, a lower bound of
  the peak) above the limit: the time step cannot help, and the message gives the speed at which
  the peak stays under it, sqrt(16 E* sqrt(R*) (limit a_min)^(5/2) / (15 m*));
- else the time step when it is above a quarter of the critical one (explicit integration fails
  near it), else a material too soft for its loads (gravity, confinement).

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
        self.checked = 0  # steps checked so far (the first resolves the starting positions)
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
        self.checked += 1
        if row["n_bad"]:
            reason = (f"non-finite position or velocity of particle {row['first_bad']}; likely cause: "
                      f"time step {self.dt:.3g} s too large (critical {self.dt_critical:.3g} s)")
        elif row["max_overlap_ratio"] > self.overlap:
            who = self.mode.worst_contact
            where = (f"particle {who[0]} and a wall" if who and who[1] == "wall" else
                     f"particles {who[0]} and {who[1]}" if who else "a contact")
            reason = (f"overlap {row['max_overlap_ratio']:.3g} of the smallest semi-axis between {where} "
                      f"(limit {self.overlap:g}); {self._overlap_cause(who)}")
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

    def _overlap_cause(self, who):
        """The likely cause of an overlap above the limit between who = (i, j) or (i, "wall") (global
        ids), as the module docstring sets out."""
        if self.checked == 1:
            return ("it was there at the start of the run (the first step resolves the starting positions): the "
                    "scene places these bodies overlapping; move them apart")
        impact = self._impact(who) if who else None
        if impact is not None and impact[1] > self.overlap:
            v, peak, v_ok = impact
            return (f"likely cause: an impact too fast for the material: they approach at {v:.3g} m/s, at which Hertz "
                    f"theory puts the peak overlap at {peak:.3g} of the smallest semi-axis (under the limit up to "
                    f"about {v_ok:.3g} m/s); a stiffer material or slower particles, not a smaller time step")
        if self.dt > 0.25 * self.dt_critical:
            return (f"likely cause: time step {self.dt:.3g} s too large for the stiffest contact (critical "
                    f"{self.dt_critical:.3g} s)")
        return (f"likely cause: a material too soft for its loads (gravity, confinement): the time step "
                f"{self.dt:.3g} s is {self.dt_critical / self.dt:.3g} times below the critical one")

    def _impact(self, who):
        """(approach speed v [m/s], Hertz peak overlap over the smaller smallest semi-axis, the speed
        [m/s] whose peak is the limit) of the contact who, from this process's rows of the two bodies
        (owned or ghost), or None when they do not approach or are not here."""
        s = self.mode.state
        scene = getattr(self.mode, "scene", None)
        if scene is None:
            return None
        gid = s.gid[:s.n]
        rows = np.flatnonzero(gid == who[0])
        if not len(rows):
            return None
        i = int(rows[0])
        amin_i = float(s.axes[i].min())
        r_i = float(s.axes[i].max()) ** 2 / amin_i  # largest radius of curvature a^2 / c
        mats = scene.materials
        if who[1] == "wall":
            if not len(scene.wall_m):
                return None
            gap = scene.wall_m @ s.pos[i] - scene.wall_d
            w = int(np.argmin(gap))
            v = -float(s.vel[i] @ scene.wall_m[w])
            mstar, estar, rstar, amin = float(s.mass[i]), float(mats.estar_w[s.material[i]]), r_i, amin_i
        else:
            rows = np.flatnonzero(gid == who[1])
            if not len(rows):
                return None
            j = int(rows[0])
            d = s.pos[j] - s.pos[i]
            dn = float(np.linalg.norm(d))
            if dn == 0.0:
                return None
            v = float((s.vel[i] - s.vel[j]) @ d) / dn
            amin_j = float(s.axes[j].min())
            r_j = float(s.axes[j].max()) ** 2 / amin_j
            mi, mj = float(s.mass[i]), float(s.mass[j])
            mstar, estar = mi * mj / (mi + mj), float(mats.estar[s.material[i], s.material[j]])
            rstar, amin = r_i * r_j / (r_i + r_j), min(amin_i, amin_j)
        if not v > 0.0:
            return None
        peak = (15.0 * mstar * v * v / (16.0 * estar * np.sqrt(rstar))) ** 0.4 / amin
        v_ok = float(np.sqrt(16.0 * estar * np.sqrt(rstar) * (self.overlap * amin) ** 2.5 / (15.0 * mstar)))
        return v, float(peak), v_ok

    def balance(self):
        """Energy balance for run.json [J]: what came in (initial KE + gravity work) and went out."""
        ke_final = self._sum(self.mode.state.kinetic_energy())
        return {"kinetic_initial": self.ke0, "gravity_work": self.gravity_work, "kinetic_final": ke_final,
                "dissipated_or_stored": self.ke0 + self.gravity_work - ke_final}
