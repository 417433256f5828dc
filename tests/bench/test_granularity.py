"""The granularity study (issue 36, part 5): `bench sweep --particles N1,N2,...` runs the grid of
counts x mappings with one serial reference a count, and granularity.png draws efficiency against
particles per core with the families' crossings. Synthetic records where the truth is known for
the figure's logic, one short real sweep end to end."""
import json
import math

import pytest

from bench.sweep.granularity import crossing_lines, crossings, family_curves, granularity_figure, plot_granularity
from bench.sweep.points import SERIAL, make_points
from bench.sweep.ranking import rank, ranking_lines
from bench.sweep.records import amdahl, read_runs, reference_key, write_runs
from tests.helpers import bench, one_line_error


def _points(particles):
    return make_points(["1-1-1-1-2", "2-2-1-1-1"], ["dynamic"], "packed", particles, 20, 0, "linkcell", "", False,
                       "26", "exact", 0, "extent", "auto", None, None)


def test_a_list_of_counts_gives_each_count_its_points_and_its_own_reference():
    """Two counts x (serial, threads, MPI): 6 points, both serial references first, each point's
    reference the serial point of its own count; one count in a list keys its points exactly as the
    plain count does (earlier sweeps resume)."""
    pts = _points([500, 2000])
    assert [(p.mapping, p.particles) for p in pts] == [
        (SERIAL, 500), (SERIAL, 2000), ("1-1-1-1-2", 500), ("2-2-1-1-1", 500), ("1-1-1-1-2", 2000),
        ("2-2-1-1-1", 2000)]
    keys = {p.key for p in pts}
    assert len(keys) == 6
    for p in pts:
        ref = [q for q in pts if q.key == reference_key(p)]
        assert len(ref) == 1 and ref[0].mapping == SERIAL and ref[0].particles == p.particles
    assert [p.key for p in _points([500])] == [p.key for p in _points(500)]


@pytest.mark.parametrize("value, words", [("2000,2000", ["distinct"]), ("0,500", ["positive integer"]),
                                          ("500,", ["positive integer"]), ("5e2", ["positive integer"])])
def test_bad_particle_lists_are_one_line(tmp_path, value, words):
    """A repeated, zero, empty or non-integer count: one line naming --particles, exit 2, nothing run."""
    res = bench("sweep", "--mappings", "1-1-1-1-2", "--scene", "packed", "--particles", value, "--out",
                str(tmp_path / "sw"))
    one_line_error(res, "--particles", *words)
    assert not (tmp_path / "sw").exists()


def _row(mapping, procs, threads, n, eff, flag="", lo=None, hi=None):
    cores = procs * threads
    t1 = 1e-3 * n / 500
    t = t1 / (eff * cores)
    return {"point": f"{mapping}-{n}", "mapping": mapping, "procs": procs, "px": procs, "py": 1, "pz": 1,
            "threads": threads, "cores": cores, "scheme": "dynamic" if threads > 1 else "", "scene": "packed",
            "particles": n, "steps": 20, "repeats": 3, "status": "done", "totalT": t, "speedup": eff * cores,
            "efficiency": eff, "efficiency_lo": eff - 0.05 if lo is None else lo,
            "efficiency_hi": eff + 0.05 if hi is None else hi, "flag": flag, "neighbor": "linkcell"}


def _study(tmp_path, extra=()):
    """Threads lose efficiency faster than MPI as the particles per core fall: threads 0.9 at 1000
    particles a core (N 2000, 2 cores) and 0.5 at 100 (N 200), MPI 0.7 at both; so the curves cross
    where 0.9 - 0.4 s = 0.7 on s = log(1000 / g) / log(10), at g = 1000 / 10^0.5 = 316 particles a core."""
    rows = [_row(SERIAL, 1, 1, n, 1.0) for n in (200, 2000)]
    rows += [_row("1-1-1-1-2", 1, 2, 2000, 0.9), _row("1-1-1-1-2", 1, 2, 200, 0.5),
             _row("2-2-1-1-1", 2, 1, 2000, 0.7), _row("2-2-1-1-1", 2, 1, 200, 0.7)] + list(extra)
    d = tmp_path / "study"
    d.mkdir()
    write_runs(str(d / "runs.csv"), rows)
    return d, rows


def test_the_families_cross_where_the_interpolation_says(tmp_path):
    """The crossing of the synthetic curves (_study) at g = 316 particles per core (linear in log g), MPI
    ahead below it, threads above; said in words."""
    d, _ = _study(tmp_path)
    curves = family_curves(read_runs(str(d)).query("status == 'done'"))
    assert set(curves) == {"threads", "MPI"}
    assert list(curves["threads"]["g"]) == [100.0, 1000.0]
    c = crossings(curves)
    assert len(c) == 1
    assert c[0]["g"] == pytest.approx(1000 / math.sqrt(10))
    assert (c[0]["ahead_below"], c[0]["ahead_above"]) == ("MPI", "threads")
    assert crossing_lines(curves) == ["MPI overtakes threads below about 316 particles per core"]


def test_the_figure_draws_each_family_and_leaves_out_loaded_points(tmp_path):
    """granularity.png: one curve a family through its points at g = N / p with the efficiencies of the
    records, intervals as bars, the loaded hybrid point left out and named in the foot note; the
    bottom axes' T_fastest / T is 1 for the fastest family at each (N, p): at 2000 particles threads
    (0.9 > 0.7) and MPI at 0.7 / 0.9."""
    d, _ = _study(tmp_path, [_row("2-1-1-1-2", 2, 2, 2000, 0.95, flag="load")])
    fig = granularity_figure(str(d))
    top, bottom = fig.axes[:2]
    lines = {l.get_label(): l for l in top.get_lines() if not l.get_label().startswith("_")}
    assert set(lines) == {"threads", "MPI", "ideal (E = 1)"}
    assert list(lines["threads"].get_xdata()) == [100.0, 1000.0]
    assert list(lines["threads"].get_ydata()) == pytest.approx([0.5, 0.9])
    rel = {tuple(l.get_xdata()): list(l.get_ydata()) for l in bottom.get_lines() if len(l.get_xdata()) == 2}
    assert rel[(100.0, 1000.0)] in ([pytest.approx(1.0), pytest.approx(0.7 / 0.9)],
                                    [pytest.approx(0.5 / 0.7), pytest.approx(1.0)])
    notes = " ".join(t.get_text() for t in fig.texts)
    assert "2-1-1-1-2 at 2,000" in notes and "foreign load" in notes
    import matplotlib.pyplot as plt
    plt.close(fig)
    assert plot_granularity(str(d)) == [str(d / "granularity.png")]


def test_one_count_draws_no_granularity_figure_and_ranking_keeps_sizes_apart(tmp_path):
    """A sweep of one size writes no granularity.png; the ranking compares only points of one size
    (the 200-particle MPI point is faster in ms than every 2000-particle point, yet ranks only at
    200), and each size gets its own Amdahl fit."""
    d, rows = _study(tmp_path)
    one = tmp_path / "one"
    one.mkdir()
    write_runs(str(one / "runs.csv"), [r for r in rows if r["particles"] == 2000])
    assert plot_granularity(str(one)) == []
    r = rank(rows)
    assert [(e["particles"], e["cores"]) for e in r] == [(200, 1), (200, 2), (2000, 1), (2000, 2)]
    assert r[3]["fastest"] == "1-1-1-1-2 dynamic"
    assert ranking_lines(r)[1].startswith("200 particles, 2 cores: 2-2-1-1-1 fastest")
    fit = amdahl(rows)
    assert fit["serial_fraction"] is None and set(fit["by_particles"]) == {"200", "2000"}


def test_granularity_sweep_end_to_end(tmp_path):
    """A real sweep of 200 and 400 falling ellipsoids, serial and 2 MPI ranks: four points done, each
    count's serial point its own reference (speedup 1), one figure set a count and granularity.png,
    the MPI points bit-identical to their own serial run, the summary's Amdahl fit per count."""
    out = tmp_path / "sw"
    res = bench("sweep", "--scene", "pluviation", "--particles", "200,400", "--steps", "10", "--mappings",
                "2-2-1-1-1", "--out", str(out), timeout=900)
    assert res.returncode == 0, res.stderr + res.stdout
    runs = read_runs(str(out))
    assert sorted(zip(runs["particles"], runs["mapping"])) == [(200, SERIAL), (200, "2-2-1-1-1"), (400, SERIAL),
                                                               (400, "2-2-1-1-1")]
    assert (runs["status"] == "done").all() and (runs["err_max"] == 0).all()
    assert (runs.loc[runs["mapping"] == SERIAL, "speedup"] == 1.0).all()
    for n in (200, 400):
        t1 = float(runs.loc[(runs["mapping"] == SERIAL) & (runs["particles"] == n), "totalT"].iloc[0])
        mpi = runs[(runs["mapping"] != SERIAL) & (runs["particles"] == n)].iloc[0]
        assert mpi["speedup"] == pytest.approx(t1 / mpi["totalT"])
        for fig in ("speedup", "efficiency", "modules"):
            assert (out / f"{fig}-{n}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "granularity.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "at 400 particles" in res.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["by_particles"]) == {"200", "400"}


def test_paper_overlay_in_kind(tmp_path):
    """`bench plot --paper` on a granularity study: granularity_paper.png with the paper's points on the
    bottom axes. Their values come from the package's copy of the paper's tables: Table 3 at 12k on 8
    nodes of 16 cores, g = 12000 / 128 = 93.75, hybrid T_pure / T_hybrid = 2.42e-2 / 4.47e-2 = 0.541;
    Table 4 pinned at g = 12000 / 36 = 333.3, the fastest mapping 36 x 1 (3.86e-2 s) at 1."""
    from bench.studies.paper_figures import paper_granularity_points, plot_paper
    pts = paper_granularity_points()
    t3 = [p for p in pts if p["source"] == "Table 3" and p["g"] == pytest.approx(93.75)]
    assert {p["family"]: p["relative"] for p in t3} == {"MPI": 1.0, "hybrid": pytest.approx(2.42e-2 / 4.47e-2)}
    t4 = [p for p in pts if p["source"] == "Table 4"]
    assert len(t4) == 8 and all(p["g"] == pytest.approx(12000 / 36) for p in t4)
    assert max(p["relative"] for p in t4) == 1.0
    d, _ = _study(tmp_path)
    assert str(d / "granularity_paper.png") in plot_paper(str(d))


def test_paper_overlay_readable_at_journal_width(tmp_path):
    """granularity_paper.png of the synthetic study (a crossing at g = 316, the paper's Tables 3 and 4 on
    the bottom axes, one loaded point in the foot note) as the sweep figures are drawn: 7 in wide, no
    text below 7 pt, no two texts overlapping (the crossing's words stand inside the axes, under the
    title), none leaving the figure (bench.sweep.figures' check, tests/bench/test_sweep_plots.py)."""
    from bench.studies.paper_figures import paper_granularity_points
    from tests.bench.test_sweep_plots import assert_readable
    d, _ = _study(tmp_path, [_row("2-1-1-1-2", 2, 2, 2000, 0.95, flag="load")])
    fig = granularity_figure(str(d), paper_granularity_points())
    try:
        assert fig.get_size_inches()[0] == pytest.approx(7.0)
        assert_readable(fig, "granularity_paper.png")
        words = [t for t in fig.axes[0].texts if "ahead below" in t.get_text()]
        assert len(words) == 1
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)
