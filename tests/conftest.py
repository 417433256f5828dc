import os
import sys

# before numba starts: room for 3 threads (more than a 2-core machine has: correctness only),
# and passive waiting so oversubscribed OpenMP threads do not spin
os.environ.setdefault("NUMBA_NUM_THREADS", "3")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def make_scene(particles, materials=None, box=((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)), walls=(),
               gravity=(0.0, 0.0, 0.0), dt="auto", steps=10):
    """Scene from explicit particle dicts (DESIGN.md format), through the real scene reader."""
    from dem.scene import build_scene
    materials = materials or {"default": dict(density=2650.0, young=29e9, poisson=0.25, friction=0.5,
                                              restitution=0.8)}
    doc = {"domain": {"box": [list(box[0]), list(box[1])], "walls": list(walls), "gravity": list(gravity)},
           "materials": materials, "time": {"dt": dt, "steps": steps}, "particles": particles}
    return build_scene(doc, name="test")


def serial(scene, dt, neighbor="linkcell"):
    from modes.serial import SerialMode
    return SerialMode().setup(scene, dt=dt, neighbor=neighbor)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
