"""The mode contract (issue 35): modes.base.Mode states what the harness may ask of a mode, every
registered mode has all of it, mode_for picks the one registered class whose accepts() takes the
mapping (a new kind joins with one registered class), bench.run.options setup_mode is the one
set-up, and run_info() gives the mode's part of run.json: the keys it had before."""
import argparse
import json

import pytest

from bench.run.options import apply_preset, setup_mode
from bench.run.spec import add_run_arguments
from dem.timestep import choose_time_step
from modes.base import REGISTRY, Mapping, Mode, ModeError, mode_for, parse_mapping, register
from modes.serial import SerialMode
from modes.threads import ThreadsMode
from tests.helpers import GOOD, bench, make_scene, write

# run.json of a serial or threads run, in its order, as driver.execute wrote it before the contract
RUN_JSON_KEYS = [
    "command", "argv", "scene", "scene_source", "particles", "steps", "mapping", "mode", "procs", "px", "py", "pz",
    "threads", "scheme", "threading", "affinity", "mpi_transport", "threaded", "pin", "neighbor", "preset",
    "contact_method", "halo", "forward", "update_grid", "preset_overrides", "skin", "skin_m", "skin_requested",
    "halo_skin", "halo_skin_m", "newton",
    "balance", "dt", "dt_auto", "dt_critical", "dt_details", "walls", "gravity", "materials", "environment",
    "warmup_s", "warmup_steps", "threading_layer", "build", "stable", "max_overlap_ratio", "status", "pid", "host",
    "restart", "checkpoint_every", "step_first", "step_last", "snapshot_format", "time_start", "stability_reason",
    "load", "step_time", "wall_s", "neighbor_rebuilds", "grid_updates", "thread_recuts", "block_cuts_final",
    "kinetic_energy_initial", "kinetic_energy_final", "energy_balance", "guard", "load_s", "setup_s",
    "warmup_steps_s", "simulated_time", "time_end", "checkpoint"]
# the keys among them that run_info() gives, at the start and at the end (end=True)
START_KEYS = ["skin", "skin_m", "halo_skin", "halo_skin_m", "newton", "balance"]
END_KEYS = ["neighbor_rebuilds", "grid_updates", "thread_recuts", "block_cuts_final"]
# a mapping no built-in mode accepts (zero threads: parse_mapping refuses it)
NOBODY = Mapping(1, 1, 1, 1, 0)


def members():
    """The Protocol's members: (methods and properties, data attributes)."""
    methods = [k for k, v in vars(Mode).items()
               if not k.startswith("_") and (callable(v) or isinstance(v, (property, classmethod)))]
    return methods, list(Mode.__annotations__)


def tiny_scene():
    """Two spheres resting on the floor of a small box, under gravity."""
    return make_scene([dict(shape="sphere", axes=[1e-3], pos=[0.01, 0.01, 0.001]),
                       dict(shape="sphere", axes=[1e-3], pos=[0.0125, 0.01, 0.001])],
                      box=((0.0, 0.0, 0.0), (0.02, 0.02, 0.02)), walls=("z-",), gravity=(0.0, 0.0, -9.81))


def run_args(*argv):
    """The options of `bench run ARGV` as the run and its ranks hold them (presets applied)."""
    return apply_preset(add_run_arguments(argparse.ArgumentParser()).parse_args(list(argv)))


def set_up(mapping):
    sc = tiny_scene()
    return setup_mode(parse_mapping(mapping), run_args("--mapping", mapping), sc, choose_time_step(sc).dt)


@pytest.fixture
def echo_mode():
    """A new kind of mode: one class, registered, that takes a mapping no other mode takes; removed
    from the registry afterwards."""
    @register("echo")
    class EchoMode(SerialMode):
        """The serial step, under a mapping of its own."""

        @classmethod
        def accepts(cls, mapping):
            return mapping.threads == 0

    yield EchoMode
    del REGISTRY["echo"]


def test_mode_for_keeps_the_names():
    for text, name in (("1-1-1-1-1", "serial"), ("1-1-1-1-3", "threads"), ("4-2-2-1-1", "mpi"),
                       ("6-3-2-1-2", "hybrid")):
        cls = mode_for(parse_mapping(text))
        assert cls.name == name == parse_mapping(text).kind and REGISTRY[name] is cls
    with pytest.raises(ModeError, match="not available yet"):
        mode_for(NOBODY)


def test_a_registered_mode_is_chosen_and_set_up(echo_mode):
    """The one class is all a new mode needs: mode_for picks it, setup_mode sets it up, and it
    keeps the contract; the other mappings still go to their modes."""
    assert mode_for(NOBODY) is echo_mode and echo_mode.name == "echo"
    assert mode_for(parse_mapping("1-1-1-1-1")) is SerialMode
    sc = tiny_scene()
    m = setup_mode(NOBODY, run_args(), sc, choose_time_step(sc).dt)
    assert type(m) is echo_mode and isinstance(m, Mode)
    m.warmup()
    assert m.step()["n_owned"] == 2


def test_registration_needs_accepts_and_one_taker(echo_mode):
    with pytest.raises(TypeError, match="accepts"):
        register("nothing")(type("Nothing", (), {}))
    assert "nothing" not in REGISTRY

    @register("echo2")
    class Echo2(echo_mode):
        pass
    try:
        with pytest.raises(ModeError, match="several modes: echo, echo2"):
            mode_for(NOBODY)
    finally:
        del REGISTRY["echo2"]


def test_every_registered_mode_has_the_contract():
    """Every registered class has each method of the Protocol, and set-up serial and threads modes
    are Modes (every member, the data attributes included, before any step)."""
    methods, data = members()
    assert {"setup", "warmup", "step", "snapshot", "release", "sync_history", "run_info", "accepts",
            "worst_contact"} <= set(methods)
    assert {"name", "scene", "state", "max_overlap_ratio", "guard_overlap", "sums"} <= set(data)
    for name, cls in REGISTRY.items():
        missing = [k for k in methods if not hasattr(cls, k)]
        assert not missing, (name, missing)
    for mapping, cls in (("1-1-1-1-1", SerialMode), ("1-1-1-1-2", ThreadsMode)):
        m = set_up(mapping)
        assert type(m) is cls and isinstance(m, Mode)
        assert not [k for k in methods + data if not hasattr(m, k)]


def test_run_info_has_the_keys_run_json_had():
    for mapping in ("1-1-1-1-1", "1-1-1-1-2"):
        m = set_up(mapping)
        start = m.run_info()
        assert list(start) == START_KEYS
        assert start["skin_m"] == pytest.approx(start["skin"] * 2e-3) and start["newton"] is None
        m.step()
        end = m.run_info(end=True)
        assert list(end) == END_KEYS and end["neighbor_rebuilds"] == 1
        assert end["thread_recuts"] == (0 if mapping == "1-1-1-1-2" else None)
        json.dumps([start, end])


@pytest.mark.parametrize("mapping", ["1-1-1-1-1", "1-1-1-1-2"])
def test_run_json_keys_unchanged(tmp_path, mapping):
    scene = write(tmp_path, GOOD, "two.toml")
    res = bench("run", "--scene", scene, "--steps", "3", "--mapping", mapping, "--out", str(tmp_path / "out"),
                "--quiet")
    assert res.returncode == 0, res.stderr
    with open(tmp_path / "out" / "run.json") as fh:
        assert list(json.load(fh)) == RUN_JSON_KEYS
