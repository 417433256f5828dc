"""One declaration of the options of `bench run` and `bench sweep` (bench/run/spec.py, issue 35): the
parsers, the sweep file, the ranks' argv, the points' keys and the records all follow FIELDS."""
import argparse
import os
from dataclasses import fields as dataclass_fields

import pytest

from bench.cli import SWEEP_FIELDS, UsageError, _sweep_file, build_parser
from bench.run.options import apply_preset, particle_counts
from bench.run.spec import FIELDS, POINT_FIELDS, REQUIRED, add_run_arguments, file_type, recorded
from bench.sweep.points import Point, make_points, point_from_dict


def _parsers():
    return build_parser()._subparsers._group_actions[0].choices


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_every_field_is_a_flag_as_declared(command):
    """Each Field the command takes is its flag, with the declared dest, help, type, default,
    choices and metavar (the sweep's own where it has them); nothing else is declared there but
    --help (and the sweep's Slurm group)."""
    parser = _parsers()[command]
    mine = [f for f in FIELDS if f.taken_by(command)]
    assert mine
    for f in mine:
        action = parser._option_string_actions[f.flag]
        want = f.argument(command)
        assert action.dest == f.name and action.help == want["help"], f.name
        if want.get("action") == "store_true":
            assert isinstance(action, argparse._StoreTrueAction) and action.default is False, f.name
            continue
        got = {"type": action.type, "default": action.default, "choices": action.choices, "metavar": action.metavar}
        assert got == {k: want.get(k) for k in got}, f.name
    declared = {f.flag for f in mine} | {"-h", "--help"}
    others = {o for a in parser._actions for o in a.option_strings} - declared
    slurm = {o for g in parser._action_groups if g.title and g.title.startswith("Slurm")
             for a in g._group_actions for o in a.option_strings}
    assert others == (slurm if command == "sweep" else set())
    # the order of FIELDS is the order of the help
    flags = [a.option_strings[0] for a in parser._actions if a.option_strings and a.option_strings[0] in declared]
    assert flags[1:] == [f.flag for f in mine]


def test_defaults_written_once():
    """The defaults a point and a run share come from where they are declared."""
    from dem.contact import DEFAULT_CONTACT_METHOD
    by_name = {f.name: f for f in POINT_FIELDS}
    assert by_name["contact_method"].neutral == DEFAULT_CONTACT_METHOD
    assert Point(mapping="1-1-1-1-1", scene="s", warmup=0, neighbor="linkcell", halo="26").contact_method == \
        DEFAULT_CONTACT_METHOD


def _valid(f):
    """A valid sweep-file value of field f and what args holds after reading it."""
    kind = file_type(f)
    if f.sweep_type is particle_counts:
        return [100, 200], [100, 200]
    if kind is bool:
        return True, True
    if kind is int:
        return 3, 3
    if kind is float:
        return 0.5, 0.5
    if f.listed:
        return ["a", "b"], "a,b"
    value = f.choices[-1] if f.choices else "x"
    return value, value


def test_sweep_file_takes_exactly_the_sweep_fields(tmp_path):
    """A sweep file's keys are the Fields with `file` in their takes (and the [sweep.slurm] table):
    each with a valid value is taken into args; any other key is refused with the list."""
    file_fields = [f for f in FIELDS if f.taken_by("file")]
    assert list(SWEEP_FIELDS) == [f.name for f in file_fields] + ["slurm"]
    lines, want = ["[sweep]"], {}
    for f in file_fields:
        value, held = _valid(f)
        lines.append(f"{f.name} = {_toml(value)}")
        want[f.name] = held
    path = tmp_path / "sweep.toml"
    path.write_text("\n".join(lines) + "\n")
    args = _parsers()["sweep"].parse_args(["--file", str(path)])
    _sweep_file(args)
    assert {k: getattr(args, k) for k in want} == want
    path.write_text("[sweep]\ncolour = 1\n")
    with pytest.raises(UsageError, match=r"unknown key 'colour'.*\(allowed: " + ", ".join(SWEEP_FIELDS) + r"\)"):
        _sweep_file(_parsers()["sweep"].parse_args(["--file", str(path)]))
    # a field the file does not take (a flag of the sweep alone, or of bench run alone)
    for name in ("dry_run", "checkpoint_every"):
        path.write_text(f"[sweep]\n{name} = 1\n")
        with pytest.raises(UsageError, match="unknown key"):
            _sweep_file(_parsers()["sweep"].parse_args(["--file", str(path)]))


def _toml(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return f'"{value}"' if isinstance(value, str) else repr(value)


RUN_CASES = [
    ["--scene", "packed"],
    ["--scene", "packed", "--particles", "300", "--shape", "sphere", "--seed", "4", "--steps", "9", "--warmup", "2",
     "--dt", "1e-5", "--mapping", "2-2-1-1-2", "--scheme", "static", "--threaded", "detection", "--pin", "--neighbor",
     "allpairs", "--contact-method", "pw", "--skin", "0.3", "--snapshot-every", "3", "--snapshot-format", "vtk",
     "--plot", "--guard-overlap", "0.1", "--halo", "6", "--update-grid", "5", "--balance", "time", "--newton", "off",
     "--timeout", "9", "--hang-timeout", "4", "--hosts", "a,b", "--quiet", "--checkpoint-every", "2"],
    ["--restart", "ck.npz", "--mapping", "2-1-1-2-1", "--preset", "paper", "--neighbor", "linkcell", "--out", "x"],
]


@pytest.mark.parametrize("argv", RUN_CASES)
def test_rank_argv_round_trips(argv):
    """The ranks' argv (bench.run.launch._run_argv), parsed by the rank's parser, gives every option
    the ranks take the parent's value (the output folder resolved, the checkpoint's path made
    absolute); the launcher's own options keep their defaults there."""
    from bench.run.launch import _run_argv
    parent = apply_preset(add_run_arguments(argparse.ArgumentParser()).parse_args(argv))
    parent.contact_method = parent.contact_method or "exact"  # as bench.run.driver sets it before launching
    rank_parser = add_run_arguments(argparse.ArgumentParser(prog="bench.run.rank"))
    rank_parser.add_argument("--time-step", default=None)
    got = apply_preset(rank_parser.parse_args(_run_argv(parent, "/tmp/out")))
    for f in FIELDS:
        if not f.taken_by("run"):
            continue
        if f.name == "out":
            assert got.out == "/tmp/out"
        elif f.name == "restart":
            assert got.restart == (os.path.abspath(parent.restart) if parent.restart else None)
        elif f.rank:
            assert getattr(got, f.name) == getattr(parent, f.name), f.name
        else:
            assert getattr(got, f.name) == f.default, f.name
    assert got.preset_overrides == parent.preset_overrides
    assert "--time-step" not in _run_argv(parent, "/tmp/out")


# keys (folder names) and commands the code before bench.run.spec made: make_points(*BASE, *extra)
BASE = (["2-2-1-1-1", "1-1-1-1-2", "2-2-1-1-2"], ["dynamic", "headtail"], "pluviation", 200, 15, 0, "linkcell", None,
        False, "26")
OLD_KEYS = [
    ((), ["1-1-1-1-1-1ae7f5a2", "2-2-1-1-1-822c84b2", "1-1-1-1-2-dynamic-d51d986b", "1-1-1-1-2-headtail-0156a558",
          "2-2-1-1-2-dynamic-44b72b39", "2-2-1-1-2-headtail-bf33e51b"]),
    (("exact", 25), ["1-1-1-1-1-1ae7f5a2", "2-2-1-1-1-574f9dc2", "1-1-1-1-2-dynamic-d51d986b",
                     "1-1-1-1-2-headtail-0156a558", "2-2-1-1-2-dynamic-4970eb3f", "2-2-1-1-2-headtail-f2836781"]),
    (("exact", 25, "count"), ["1-1-1-1-1-1ae7f5a2", "2-2-1-1-1-fb473eb2", "1-1-1-1-2-dynamic-d51d986b",
                              "1-1-1-1-2-headtail-0156a558", "2-2-1-1-2-dynamic-3e37e203",
                              "2-2-1-1-2-headtail-b9151909"]),
    (("exact", 0, "extent", "on"), ["1-1-1-1-1-1ae7f5a2", "2-2-1-1-1-85b29a3b", "1-1-1-1-2-dynamic-d51d986b",
                                    "1-1-1-1-2-headtail-0156a558", "2-2-1-1-2-dynamic-21caa94d",
                                    "2-2-1-1-2-headtail-bf33e51b"]),
    (("sextic", 0, "extent", "auto", 0.0), ["1-1-1-1-1-be71ef15", "2-2-1-1-1-381bfd8e", "1-1-1-1-2-dynamic-1e0f7df5",
                                            "1-1-1-1-2-headtail-469ce86b", "2-2-1-1-2-dynamic-08b7bcaf",
                                            "2-2-1-1-2-headtail-c9c56bef"]),
    (("exact", 0, "extent", "auto", None, "paper"), ["1-1-1-1-1-08258bfb", "2-2-1-1-1-4ef51a62",
                                                     "1-1-1-1-2-dynamic-673332c3", "1-1-1-1-2-headtail-7211b98f",
                                                     "2-2-1-1-2-dynamic-d1194323", "2-2-1-1-2-headtail-04ee60b2"]),
    (("pw", 3, "time", "off", 0.2, "paper", "h1,h2"), ["1-1-1-1-1-ae59c0d8", "2-2-1-1-1-6b6fe819",
                                                       "1-1-1-1-2-dynamic-a2648cd8", "1-1-1-1-2-headtail-1a44b501",
                                                       "2-2-1-1-2-dynamic-6933258e", "2-2-1-1-2-headtail-d52c0d77"]),
]


@pytest.mark.parametrize("extra,keys", OLD_KEYS)
def test_point_keys_are_the_old_ones(extra, keys):
    """Old sweep folders still resume: the same options give the same keys as before the spec."""
    assert [p.key for p in make_points(*BASE, *extra)] == keys


def test_point_keys_by_name_and_granularity():
    """Options given by name (as bench sweep gives them) make the same points; a list of particle
    counts, hybrid-free mappings, --pin and --halo 6 keep their old keys too."""
    by_name = make_points(BASE[0], BASE[1], scene="pluviation", particles=200, steps=15, warmup=0,
                          neighbor="linkcell", pin=False, halo="26", contact_method="pw", update_grid=3,
                          balance="time", newton="off", skin=0.2, preset="paper", hosts="h1,h2")
    assert by_name == make_points(*BASE, "pw", 3, "time", "off", 0.2, "paper", "h1,h2")
    points = make_points(["1-1-1-1-1", "2-2-1-1-1"], ["dynamic"], "packed", [100, 300], None, 2, "allpairs",
                         "ellipsoid", True, "6")
    assert [p.key for p in points] == ["1-1-1-1-1-50cafd85", "1-1-1-1-1-2774f90d", "2-2-1-1-1-87b9d966",
                                       "2-2-1-1-1-73671f52"]
    mpi = points[2]
    assert sorted(mpi.run_args("OUT", 77)) == sorted(
        "run --scene packed --mapping 2-2-1-1-1 --neighbor allpairs --warmup 2 --out OUT --quiet --timeout 77 "
        "--particles 100 --shape ellipsoid --pin --halo 6".split())


def test_point_fields_and_old_manifests():
    """Point has a field for each point Field; a manifest entry from before the later options (no
    preset, hosts, skin, ...) reads back with their neutral values and its old key."""
    assert [f.name for f in dataclass_fields(Point)] == [f.name for f in POINT_FIELDS]
    old = {"mapping": "2-2-1-1-1", "scheme": "", "scene": "pluviation", "particles": 200, "steps": 15, "warmup": 0,
           "neighbor": "linkcell", "shape": "", "pin": False, "halo": "26", "contact_method": "exact",
           "key": "2-2-1-1-1-822c84b2", "repeats": 1}
    p = point_from_dict(old)
    assert p.key == "2-2-1-1-1-822c84b2" and p.hosts == "" and p.skin is None and p.newton == "auto"
    assert all(f.neutral is not REQUIRED or f.name in old for f in POINT_FIELDS)


def test_recorded_options():
    """run.json and the checkpoint record the Fields that say so, None outside their scope."""
    from modes.base import parse_mapping
    args = apply_preset(add_run_arguments(argparse.ArgumentParser()).parse_args(
        ["--scene", "packed", "--halo", "6", "--update-grid", "4", "--threaded", "detection", "--pin"]))
    args.contact_method = "exact"
    assert recorded(args, parse_mapping("1-1-1-1-1"), "run.json") == {
        "threaded": None, "pin": True, "neighbor": "linkcell", "preset": None, "contact_method": "exact",
        "halo": None, "forward": None, "update_grid": None}
    assert recorded(args, parse_mapping("2-2-1-1-2"), "run.json") == {
        "threaded": "detection", "pin": True, "neighbor": "linkcell", "preset": None, "contact_method": "exact",
        "halo": "6", "forward": "messages", "update_grid": 4}
    assert recorded(args, parse_mapping("2-2-1-1-2"), "checkpoint") == {"neighbor": "linkcell",
                                                                        "contact_method": "exact"}
