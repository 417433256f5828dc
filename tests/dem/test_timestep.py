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


def test_rayleigh_is_a_warning_inside_the_contact_limit():
    """The paper runs its quartz deposition at 1e-6 s, above its grains' Rayleigh time: a user dt
    above dt_Rayleigh but within the contact stability limit dt_critical = t_c/2.015 runs with one
    warning line; above dt_critical it is refused (issue 14, item 5). Quartz spheres of 0.5 mm at
    rest under gravity in a 5 mm box: dt_Rayleigh = 8.2e-7 s (contact-mechanics.md §4.3 table, R =
    0.5 mm), and the contact limit is larger (t_c at the fall speed sqrt(2 g H))."""
    from tests.helpers import make_scene
    quartz = {"default": dict(density=2650.0, young=29e9, poisson=0.25, friction=0.5, restitution=0.8)}
    sc = make_scene([dict(shape="sphere", axes=[5e-4], pos=[0.0025, 0.0025, 0.001])], materials=quartz,
                    box=((0.0, 0.0, 0.0), (0.005, 0.005, 0.005)), walls=["z-"], gravity=(0.0, 0.0, -9.81))
    ts = choose_time_step(sc, "auto")
    assert ts.details["dt_rayleigh"] == pytest.approx(8.18e-7, rel=1e-3)
    assert ts.critical == ts.details["t_contact"] / 2.015 > 1e-6 > ts.details["dt_rayleigh"]
    assert ts.auto == 0.1 * ts.critical and ts.warnings == []
    paper = choose_time_step(sc, 1e-6)
    assert paper.dt == 1e-6 and len(paper.warnings) == 1
    assert "above the Rayleigh time" in paper.warnings[0] and "\n" not in paper.warnings[0]
    with pytest.raises(SceneError, match="exceeds the critical step"):
        choose_time_step(sc, 1.01 * ts.critical)


def test_rayleigh_warning_is_one_line_and_the_run_goes_on(tmp_path):
    """`bench run --dt` between the Rayleigh time and dt_critical: exit 0, one warning line on stderr."""
    from tests.helpers import bench
    scene = tmp_path / "quartz.toml"
    scene.write_text("""
[domain]
box = [[0.0, 0.0, 0.0], [0.005, 0.005, 0.005]]
walls = ["z-"]
gravity = [0.0, 0.0, -9.81]
[materials.default]
density = 2650.0
young = 29e9
poisson = 0.25
friction = 0.5
restitution = 0.8
[time]
dt = 1e-6
steps = 3
[[particles]]
shape = "sphere"
axes = [5e-4]
pos = [0.0025, 0.0025, 0.001]
""")
    res = bench("run", "--scene", str(scene), "--out", str(tmp_path / "o"), "--quiet")
    assert res.returncode == 0, res.stderr
    lines = [l for l in res.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("bench: warning: time step 1e-06 s is above the Rayleigh time")
