"""Helpers the tests share: the `bench` command as a user runs it, the one-line error contract,
scenes built through the real scene reader, and serial / MPI runs of a scene to compare."""
import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the repository


GOOD = """
[domain]
box = [[0.0, 0.0, 0.0], [0.02, 0.02, 0.04]]
walls = ["x-", "x+", "y-", "y+", "z-"]
gravity = [0.0, 0.0, -9.81]

[materials.default]
density = 2650.0
young = 1e7
poisson = 0.25
friction = 0.5
restitution = 0.8

[time]
dt = "auto"
steps = 20

[[particles]]
shape = "ellipsoid"
axes = [1e-3, 8e-4, 6e-4]
pos = [0.01, 0.01, 0.0011]
quat = [1.0, 0.0, 0.0, 0.0]

[[particles]]
shape = "sphere"
axes = [8e-4]
pos = [0.01179, 0.01, 0.0011]
"""


def bench(*args, cwd=None, timeout=300, env=None):
    env = dict(os.environ, PYTHONPATH=ROOT, **(env or {}))  # env: variables added for this command
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=timeout, env=env)


def one_line_error(res, *words):
    assert res.returncode == 2, res.stderr
    lines = [l for l in res.stderr.strip().splitlines() if l.strip()]
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    for w in words:
        assert w in lines[0], lines[0]


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def make_scene(particles, materials=None, box=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)), walls=(),
               gravity=(0.0, 0.0, 0.0), dt="auto", steps=10, overlap_limit=None):
    """Scene from explicit particle dicts (DESIGN.md format), through the real scene reader
    (overlap_limit: its load-time overlap check, default the guard's; inf lets a test start a mode
    on overlaps a scene file may not have, such as coincident bodies)."""
    from dem.scene import build_scene
    materials = materials or {"default": dict(density=2650.0, young=29e9, poisson=0.25, friction=0.5,
                                              restitution=0.8)}
    doc = {"domain": {"box": [list(box[0]), list(box[1])], "walls": list(walls), "gravity": list(gravity)},
           "materials": materials, "time": {"dt": dt, "steps": steps}, "particles": particles}
    return build_scene(doc, name="test", overlap_limit=overlap_limit)


def serial(scene, dt, neighbor="linkcell"):
    from modes.serial import SerialMode
    return SerialMode().setup(scene, dt=dt, neighbor=neighbor)


FIELDS = ("id", "pos", "quat", "vel", "omega")


_SERIAL = {}


def serial_state(tmp_path_factory, scene, steps, extra=()):
    key = (scene, steps, tuple(extra))
    if key not in _SERIAL:
        out = tmp_path_factory.mktemp("serial")
        res = bench("run", "--scene", scene, "--steps", str(steps), "--out", str(out), "--quiet", *extra)
        assert res.returncode == 0, res.stderr
        _SERIAL[key] = dict(np.load(out / "state.npz"))
    return _SERIAL[key]


def mpi_run(tmp_path, scene, steps, mapping, *extra):
    out = tmp_path / mapping
    res = bench("run", "--scene", scene, "--steps", str(steps), "--mapping", mapping, "--out", str(out),
                "--quiet", "--timeout", "600", *extra, timeout=900)
    assert res.returncode == 0, res.stderr
    return dict(np.load(out / "state.npz")), pd.read_csv(out / "steps.csv"), json.loads((out / "run.json").read_text())


def assert_same(a, b):
    for f in FIELDS:
        assert np.array_equal(a[f], b[f]), f


def processes_naming(text):
    """PIDs of live processes whose command line (its arguments joined by spaces) contains text
    (/proc; zombies have none)."""
    pids = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                cmd = fh.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmd:
            pids.append(int(pid))
    return pids
