"""The run's time step policy (dem.timestep.choose_time_step): chosen once, handed to MPI ranks as
JSON (bench.run.launch -> bench.run.rank), so the ranks step with the parent's dt to the bit."""
import json

import pytest

from dem.scene import SceneError, load_scene
from dem.timestep import TimeStep, choose_time_step


def test_time_step_travels_to_the_ranks_bit_exact():
    """TimeStep -> JSON -> TimeStep gives back the same floats (repr round-trips a float64 exactly)."""
    ts = choose_time_step(load_scene("gas"))
    back = TimeStep.from_dict(json.loads(json.dumps(ts.as_dict())))
    assert back == ts and back.dt == ts.dt and back.critical == ts.critical


def test_auto_and_refusals():
    """dt = "auto" is dt_auto (below dt_critical); a dt above dt_critical or not positive is
    refused in one line naming the critical step."""
    sc = load_scene("gas")
    ts = choose_time_step(sc, "auto")
    assert ts.dt == ts.auto and 0 < ts.auto < ts.critical
    assert choose_time_step(sc, 0.5 * ts.critical).dt == 0.5 * ts.critical
    with pytest.raises(SceneError, match="exceeds the critical step") as e:
        choose_time_step(sc, 2.0 * ts.critical)
    assert "\n" not in str(e.value)
    with pytest.raises(SceneError, match="must be positive"):
        choose_time_step(sc, -1.0)
