"""`bench perf --what phases` (bench/studies/perf_phases.py): the Karp-Flatt serial fraction and
the decomposition of a step into its phases. Its figures are benchmarks, not asserted here."""
import math

import pytest

from bench.run.prepare import load_prepared
from bench.studies.perf_phases import PHASES, _modes, karp_flatt, step_phases
from dem.timestep import choose_time_step
from tests.helpers import bench, one_line_error


@pytest.mark.parametrize("f,p", [(0.0, 2), (0.02, 2), (0.057, 16), (0.5, 4), (1.0, 8)])
def test_karp_flatt_recovers_amdahls_fraction(f, p):
    """Karp & Flatt (1990): for a code that follows Amdahl's law, S = 1 / (f + (1 - f)/p), the
    measure e = (1/S - 1/p) / (1 - 1/p) gives back f (issue 32: the sweep's f = 0.057 caps 16
    threads near efficiency 0.55)."""
    s = 1.0 / (f + (1.0 - f) / p)
    assert karp_flatt(s, p) == pytest.approx(f, abs=1e-12)
    assert math.isnan(karp_flatt(s, 1))


def test_phases_add_up_to_the_step():
    """Every phase of a rebuild step and of a step between rebuilds, serial and 2 threads: the
    parts are the whole step's time (the same clock reads, up to rounding)."""
    scene = load_prepared("packed", particles=300)
    dt = choose_time_step(scene).dt
    for mode in _modes(scene, dt, 2, "dynamic", 0.1):
        for force in (True, False, True):
            ph = step_phases(mode, force)
            parts = sum(v for k, v in ph.items() if k != "step")
            assert parts == pytest.approx(ph["step"], rel=1e-9, abs=1e-12)
            if force:
                assert set(ph) == set(PHASES)
            else:
                assert set(ph) == {"step", "resolve", "finish", "decide"}


def test_phases_needs_threads():
    one_line_error(bench("perf", "--what", "phases", "--threads", "1"), "--threads T >= 2")
