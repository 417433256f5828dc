"""`bench perf --what skin`: the study behind the default Verlet skin (dem.pairs.DEFAULT_SKIN)."""
import pytest

from tests.helpers import bench


def test_skin_study_figures():
    """At skin 0 the list is rebuilt every step (1 step per rebuild, by definition of the paper's
    every-step estimate); a skin keeps it for several steps and can only add candidates per
    contact (the reach grows by half the skin on each side); each cost is relative to the best skin
    of its round, so no figure is below 1, and the chosen skin has the smallest worst figure."""
    from bench.studies.perf_skin import measure
    rep = measure(30, 2, lambda msg: None, skins=(0.0, 0.1), scenes=(("gas", 300, None, 5),))
    zero, tenth = rep["rows"]
    assert (zero["skin"], tenth["skin"]) == (0.0, 0.1)
    assert zero["steps_per_rebuild"] == 1.0 and tenth["steps_per_rebuild"] > 1.0
    assert tenth["candidates_per_contact"] >= zero["candidates_per_contact"]
    assert all(r["relative"] >= 1.0 and r["us_per_particle_step"] > 0 for r in rep["rows"])
    assert rep["best_skin"] == min(rep["worst_relative"], key=rep["worst_relative"].get)


@pytest.mark.parametrize("flag", [["--steps", "0"], ["--repeats", "-1"]])
def test_skin_study_bad_options(flag):
    """A bad --steps or --repeats: one line naming the option, exit 2."""
    res = bench("perf", "--what", "skin", *flag)
    assert res.returncode == 2 and res.stderr.strip().splitlines() == [res.stderr.strip()] and flag[0] in res.stderr
