"""The warm-up twin (issue 14): for more than WARMUP_PARTICLES owned particles the mode compiles its
kernels on a compact piece of the state instead of a copy of all of it (a 1M-particle warm-up took
17-27 s of the set-up). Warming up changes nothing of the state, and the trajectory after it is the
one after a full-size warm-up, bit for bit."""
import copy

import numpy as np
import pytest

import modes.serial as ser
from bench.run.prepare import load_prepared
from dem.timestep import choose_time_step


@pytest.mark.parametrize("mode_name", ["serial", "threads"])
def test_small_twin_warmup_changes_nothing(monkeypatch, mode_name):
    from modes.base import REGISTRY
    sc = load_prepared("gas")
    dt = choose_time_step(sc).dt
    opts = {"threads": 2} if mode_name == "threads" else {}
    runs = []
    for limit in (10 ** 9, 50):   # a full-size twin, then the 50 particles nearest the first one
        monkeypatch.setattr(ser, "WARMUP_PARTICLES", limit)
        scene = copy.deepcopy(sc)
        m = REGISTRY[mode_name]().setup(scene, dt=dt, **opts)
        before = {f: getattr(scene.state, f).copy() for f in ("pos", "vel", "quat", "angmom", "gid")}
        twin = m._twin_state()
        assert twin.n_owned == min(limit, scene.state.n_owned)
        m.warmup()
        for f, a in before.items():
            assert np.array_equal(getattr(scene.state, f), a), f
        for _ in range(300):
            m.step()
        runs.append(scene.state.snapshot())
    for f in ("id", "pos", "quat", "vel", "omega"):
        assert np.array_equal(runs[0][f], runs[1][f]), f


def test_warmup_runs_the_dynamic_recut(monkeypatch):
    """The dynamic scheme re-cuts its ranges after a window of steps between rebuilds (rebalance),
    whose kernel (modes.parallel rescale_weights) ran first in a timed step: a 10 ms step from
    numba's cache in 30-step runs whose other steps took 1.05 ms. The warm-up now runs that re-cut
    once on its twin (warm_between), and the mode itself keeps no re-cut (0 re-cuts, none due)."""
    import modes.threads as thr
    calls = []
    original = thr.ThreadsMode._recut
    monkeypatch.setattr(thr.ThreadsMode, "_recut", lambda self: (calls.append(self), original(self))[1])
    sc = load_prepared("gas")
    m = thr.ThreadsMode().setup(copy.deepcopy(sc), dt=choose_time_step(sc).dt, threads=2, scheme="dynamic")
    m.warmup()
    assert len(calls) == 1 and calls[0] is not m
    assert m.recuts == 0 and m.recut is None
