"""`--preset paper` (bench/run/options.py PRESETS): the paper's own configuration (Yan & Regueiro
2019: the sextic contact method, the neighbour estimate every step, the n-by-n search) as one
option of `bench run` and `bench sweep`, recorded in run.json and runs.csv, every mode still
bit-identical to serial under it (DESIGN.md, Determinism)."""
import argparse
import json

import numpy as np
import pandas as pd

from bench.run.options import PRESETS, apply_preset
from bench.run.spec import add_run_arguments
from tests.helpers import bench, one_line_error


def _parse(*argv):
    return apply_preset(add_run_arguments(argparse.ArgumentParser()).parse_args(list(argv)))


def test_paper_sets_the_three_options():
    a = _parse("--scene", "packed", "--preset", "paper")
    assert (a.contact_method, a.skin, a.neighbor) == ("sextic", 0.0, "allpairs")
    assert a.preset_overrides == []
    assert PRESETS["paper"] == {"contact_method": "sextic", "skin": 0.0, "neighbor": "allpairs"}


def test_explicit_options_win_and_are_named():
    """--preset paper --neighbor linkcell: the link-cell search, the rest of the preset, the override
    recorded; an explicit option equal to the preset's is no override."""
    a = _parse("--scene", "packed", "--preset", "paper", "--neighbor", "linkcell", "--skin", "0")
    assert (a.contact_method, a.skin, a.neighbor) == ("sextic", 0.0, "linkcell")
    assert a.preset_overrides == ["neighbor"]


def test_without_a_preset_nothing_changes():
    a = _parse("--scene", "packed")
    assert (a.contact_method, a.skin, a.neighbor, a.preset) == (None, None, "linkcell", None)


def test_unknown_preset_is_one_line(tmp_path):
    one_line_error(bench("run", "--scene", "packed", "--preset", "fast", "--out", str(tmp_path / "r")), "--preset")
    one_line_error(bench("sweep", "--scene", "packed", "--mappings", "1-1-1-1-2", "--preset", "fast",
                         "--out", str(tmp_path / "s")), "--preset")


def test_paper_preset_sweep_bit_identical(tmp_path):
    """A sweep under --preset paper: serial, 2 threads and 2 ranks ran with sextic contacts, skin 0 and
    all-pairs (run.json, runs.csv), and the threads and ranks reproduce the serial state bit for
    bit (runs.csv err_max 0, state.npz compared with np.array_equal)."""
    out = tmp_path / "p"
    res = bench("sweep", "--scene", "packed", "--particles", "300", "--steps", "8", "--mappings",
                "1-1-1-1-2,2-2-1-1-1", "--preset", "paper", "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr + res.stdout
    runs = pd.read_csv(out / "runs.csv", keep_default_na=False)
    assert runs["mapping"].tolist() == ["1-1-1-1-1", "1-1-1-1-2", "2-2-1-1-1"]
    assert (runs["preset"] == "paper").all() and (runs["contact_method"] == "sextic").all()
    assert (runs["skin"].astype(float) == 0.0).all() and (runs["neighbor"] == "allpairs").all()
    assert (runs["err_max"].astype(float) == 0.0).all()
    states = []
    for point in runs["point"]:
        info = json.loads((out / point / "rep0" / "run.json").read_text())
        assert (info["preset"], info["contact_method"], info["skin"], info["neighbor"]) == \
            ("paper", "sextic", 0.0, "allpairs")
        assert info["neighbor_rebuilds"] == 8  # skin 0: the neighbour estimate at every one of the 8 steps
        states.append(np.load(out / point / "rep0" / "state.npz"))
    for s in states[1:]:
        for k in ("id", "pos", "vel", "quat", "omega"):
            assert np.array_equal(s[k], states[0][k]), k
