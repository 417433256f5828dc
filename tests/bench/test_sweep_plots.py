"""Figures of a mapping sweep (bench.sweep.figures, bench.studies.paper_figures) from synthetic DIR/runs.csv files.

No DEM run is made: the records are written by hand, with the columns bench sweep writes.
"""
import math
import os

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("matplotlib")

from bench.studies.paper_figures import plot_paper  # noqa: E402
from bench.sweep import figures as sweep_plots  # noqa: E402
from bench.sweep.figures import error_figure, metric_figure, modules_figure, plot_sweep  # noqa: E402
from bench.sweep.records import RUN_COLUMNS  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SWEEP_PNGS = ("speedup.png", "efficiency.png", "edsf.png", "modules.png", "error_vs_time.png")
T1 = 0.200  # serial s/step


@pytest.fixture(autouse=True)
def low_dpi(monkeypatch):
    """Figures at a low resolution: the tests check files, not looks, and stay fast."""
    monkeypatch.setattr(sweep_plots, "DPI", 50)


def row(mapping, scheme="", status="done", reason="", totalT=None, commu=0.0, migra=0.0, err=0.0, rms=None,
        scene="gas", particles=4000, steps=50, neighbor="linkcell", t1=T1, wire=None, sync=None):
    """One runs.csv record as bench sweep writes it (derived columns from totalT and T(1); wireT
    and above_wireT = commuT + migraT - syncT - wireT only when `wire` is given, syncT only when
    `sync` is, else above_wireT = commuT + migraT - wireT as for older records)."""
    p, px, py, pz, t = (int(x) for x in mapping.split("-"))
    cores = p * t
    r = {c: math.nan for c in RUN_COLUMNS}
    r.update(point=f"{mapping}{'-' + scheme if scheme else ''}-deadbeef", mapping=mapping, procs=p, px=px, py=py,
             pz=pz, threads=t, cores=cores, scheme=scheme, neighbor=neighbor, scene=scene, particles=particles,
             steps=steps, repeats=1, status=status, reason=reason)
    if status != "done":
        return r
    compu = totalT - commu - migra
    s = t1 / totalT if t1 else math.nan
    r.update(totalT=totalT, commuT=commu, migraT=migra, compuT=compu, neighborT=0.3 * compu, resolveT=0.6 * compu,
             overhead_pct=100 * (commu + migra) / totalT, speedup=s, efficiency=s / cores,
             edsf=(1 / s - 1 / cores) / (1 - 1 / cores) if cores > 1 else math.nan, rss_mb=120.0 * p,
             err_max=err, err_rms=err / 3 if rms is None else rms, stable=True, wall_s=totalT * steps + 2.0,
             load_before=0.5, load_after=1.5)
    if wire is not None:
        r.update(wireT=wire, above_wireT=commu + migra - (sync or 0.0) - wire)
    if sync is not None:
        r.update(syncT=sync)
    return r


def full_sweep():
    """Serial + threads (two schemes) + MPI + hybrid points, one timeout, zeros in err."""
    return [
        row("1-1-1-1-1", totalT=T1),
        row("1-1-1-1-2", "dynamic", totalT=0.110),
        row("1-1-1-1-2", "static", totalT=0.118),
        row("1-1-1-1-4", "dynamic", totalT=0.062),
        row("1-1-1-1-4", "static", totalT=0.071),
        row("1-1-1-1-8", "dynamic", totalT=0.041),
        row("2-2-1-1-1", totalT=0.104, commu=0.004, migra=0.0004, err=2e-13, wire=0.0012),
        row("4-2-2-1-1", totalT=0.056, commu=0.006, migra=0.0006, err=5e-13, wire=0.0015),
        row("8-2-2-2-1", totalT=0.033, commu=0.007, migra=0.0008, err=1.1e-12),
        row("2-2-1-1-2", "dynamic", totalT=0.060, commu=0.003, migra=0.0003, err=3e-13),
        row("2-2-1-1-4", "dynamic", totalT=0.036, commu=0.003, migra=0.0003, err=0.0, rms=0.0),
        row("4-2-2-1-2", "dynamic", totalT=0.034, commu=0.004, migra=0.0005, err=6e-13),
        row("4-4-1-1-2", "static", status="timeout", reason="no result within 600 s"),
    ]


def write_runs(d, rows):
    os.makedirs(d, exist_ok=True)
    pd.DataFrame(rows, columns=RUN_COLUMNS).to_csv(os.path.join(d, "runs.csv"), index=False)
    return str(d)


def write_schemes(d, threads=4):
    """A schemes.csv like bench schemes writes (subset of its columns is enough)."""
    paper = {"partition": 8.53, "frogleap": 10.30, "headtail": 10.38, "static": 10.06, "dynamic": 11.15}
    rows = [dict(family="serial", method="serial", neighbor="allpairs", threads=1, particles=2500,
                 shape="ellipsoid", speedup=1.0, efficiency=1.0, efficiency_own=1.0, paper_method="n-by-n",
                 paper_threads=1,
                 paper_speedup=1.0, paper_efficiency=1.0),
            dict(family="serial", method="serial", neighbor="linkcell", threads=1, particles=2500,
                 shape="ellipsoid", speedup=6.0, efficiency=6.0, efficiency_own=1.0, paper_method="link-cell",
                 paper_threads=1,
                 paper_speedup=1.17, paper_efficiency=1.17)]
    for k, m in enumerate(paper):
        rows.append(dict(family="parallel", method=m, neighbor="allpairs", threads=threads, particles=2500,
                         shape="ellipsoid", speedup=3.0 + 0.1 * k, efficiency=(3.0 + 0.1 * k) / threads,
                         efficiency_own=(3.0 + 0.1 * k) / threads,
                         paper_method=m, paper_threads=12, paper_speedup=paper[m],
                         paper_efficiency=paper[m] / 12))
        rows.append(dict(family="parallel", method=m, neighbor="linkcell", threads=threads, particles=2500,
                         shape="ellipsoid", speedup=15.0 + k, efficiency=(15.0 + k) / threads,
                         efficiency_own=(15.0 + k) / 6.0 / threads, paper_method="",
                         paper_threads="", paper_speedup="", paper_efficiency=""))
    pd.DataFrame(rows).to_csv(os.path.join(d, "schemes.csv"), index=False)


def assert_pngs(paths, names):
    """Every expected name was returned, exists, is non-empty and starts with the PNG signature."""
    assert sorted(os.path.basename(p) for p in paths) == sorted(names)
    for p in paths:
        assert os.path.getsize(p) > 500, p
        with open(p, "rb") as fh:
            assert fh.read(8) == PNG_MAGIC, p


def test_full_sweep_figures(tmp_path, capsys):
    """A complete sweep (serial, threads with two schemes, MPI, hybrid, one timed-out point, zero and
    non-zero errors): plot_sweep writes the five PNGs in DIR and returns their paths, and lists the
    timed-out point on stdout; runs.csv is left unchanged (plots only read records)."""
    d = write_runs(tmp_path, full_sweep())
    with open(os.path.join(d, "runs.csv")) as fh:
        before = fh.read()
    paths = plot_sweep(d)
    assert_pngs(paths, SWEEP_PNGS)
    assert all(os.path.dirname(p) == d for p in paths)
    out = capsys.readouterr().out
    assert "4-4-1-1-2" in out and "timeout" in out
    with open(os.path.join(d, "runs.csv")) as fh:
        assert fh.read() == before


def markers(ax):
    """{legend label: (x, y)} of the axes' marker-only lines (the plotted points)."""
    return {l.get_label(): (np.asarray(l.get_xdata(), float), np.asarray(l.get_ydata(), float))
            for l in ax.lines if l.get_linestyle() == "None" and not l.get_label().startswith("_")}


@pytest.mark.parametrize("metric", ["speedup", "efficiency", "edsf"])
def test_metric_figures_draw_the_records(tmp_path, metric):
    """What speedup.png, efficiency.png and edsf.png draw, read back from their artists: per series
    (serial, threads per scheme, MPI, hybrid) x = cores and y = the runs.csv column, e.g. threads
    (dynamic) at 2, 4, 8 cores with speedups 0.200/0.110, 0.200/0.062, 0.200/0.041 (full_sweep's
    totalT); edsf drops p = 1; the timed-out point is drawn nowhere; the ideal line is labelled."""
    rows = [r for r in full_sweep() if r["status"] == "done"]
    d = write_runs(tmp_path, full_sweep())
    fig = metric_figure(d, metric)
    try:
        got = markers(fig.axes[0])
        want = {}
        for r in rows:
            fam = ("serial" if r["cores"] == 1 else "threads" if r["procs"] == 1 else
                   "MPI" if r["threads"] == 1 else "hybrid")
            label = fam + (f" ({r['scheme']})" if r["threads"] > 1 else "")
            if metric == "edsf" and r["cores"] == 1:
                continue
            want.setdefault(label, ([], []))
            want[label][0].append(r["cores"])
            want[label][1].append(r[metric])
        assert sorted(got) == sorted(want)
        for label, (x, y) in want.items():
            assert np.array_equal(got[label][0], x), label
            assert np.allclose(got[label][1], y, rtol=1e-12, atol=0), label
        if metric == "speedup":
            assert np.allclose(got["threads (dynamic)"][1], [0.2 / 0.110, 0.2 / 0.062, 0.2 / 0.041], rtol=1e-12)
        legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert any(t.startswith("ideal") or t.startswith("e = 0") for t in legend)
        assert "4-4-1-1-2" in " ".join(t.get_text() for t in fig.texts)  # the foot note names the timeout
    finally:
        sweep_plots.plt.close(fig)


def test_error_figure_draws_errors_and_zeros(tmp_path):
    """error_vs_time.png read back: MPI's non-zero err_max (2e-13, 5e-13, 1.1e-12) at totalT 104,
    56 and 33 ms; the bit-identical points (serial, threads, hybrid 2-2-1-1-4) hollow at the floor,
    one decade below the smallest non-zero error drawn (err_rms 2e-13 / 3 -> floor 1e-15)."""
    d = write_runs(tmp_path, full_sweep())
    fig = error_figure(d)
    try:
        got = markers(fig.axes[0])
        x, y = got["MPI"]
        assert np.allclose(x, [104.0, 56.0, 33.0], rtol=1e-12) and np.allclose(y, [2e-13, 5e-13, 1.1e-12], rtol=1e-12)
        x, y = got["hybrid (dynamic) (err = 0)"]
        assert np.allclose(x, [36.0], rtol=1e-12) and np.array_equal(y, [1e-15])
        x, y = got["serial (all err = 0)"]
        assert np.allclose(x, [200.0], rtol=1e-12) and np.array_equal(y, [1e-15])
        assert np.array_equal(got["threads (dynamic) (all err = 0)"][1], [1e-15] * 3)
        assert np.allclose(got["hybrid (dynamic)"][1], [3e-13, 6e-13], rtol=1e-12)
    finally:
        sweep_plots.plt.close(fig)


def test_paper_figures(tmp_path):
    """plot_paper writes paper_table4.png always (ours at the largest core count beside the paper's
    Table 4) and paper_table1.png only when DIR/schemes.csv exists."""
    d = write_runs(tmp_path, full_sweep())
    assert_pngs(plot_paper(d), ["paper_table4.png"])
    write_schemes(d)
    assert_pngs(plot_paper(d), ["paper_table4.png", "paper_table1.png"])


def test_paper_tables_missing(tmp_path, monkeypatch, capsys):
    """Without the paper's tables the overlay is skipped with a stderr line, and the figures of our
    side are still written (Table 1 efficiencies then come from schemes.csv's paper columns)."""
    d = write_runs(tmp_path / "sweep", full_sweep())
    write_schemes(d)
    import bench.studies.paper_figures as paper_figures
    monkeypatch.setattr(paper_figures, "table_path", lambda name: str(tmp_path / "nowhere" / name))
    assert_pngs(plot_paper(d), ["paper_table4.png", "paper_table1.png"])
    assert "not found" in capsys.readouterr().err


@pytest.mark.parametrize("case", ["serial_only", "all_failed", "nan_columns", "one_core_count", "header_only"])
def test_degenerate_sweeps(tmp_path, case):
    """Degenerate runs.csv files give every figure without raising: only the serial point; every point
    failed (serial included, so speedups are NaN); all optional columns NaN (only mapping, status and
    totalT filled); a single core count (4 cores: 1x4, 2x2, 4x1); a header with no record."""
    if case == "serial_only":
        rows = [row("1-1-1-1-1", totalT=T1)]
    elif case == "all_failed":
        rows = [row("1-1-1-1-1", status="failed", reason="exit status 1"),
                row("2-2-1-1-1", status="unstable", reason="kinetic energy blew up"),
                row("1-1-1-1-2", "dynamic", status="timeout", reason="no result within 60 s")]
    elif case == "nan_columns":
        rows = []
        for r in full_sweep():
            keep = {"mapping": r["mapping"], "status": r["status"], "totalT": r["totalT"]}
            rows.append({c: keep.get(c, math.nan) for c in RUN_COLUMNS})
    elif case == "one_core_count":
        rows = [row("1-1-1-1-4", "dynamic", totalT=0.06, t1=None), row("2-2-1-1-2", "dynamic", totalT=0.058,
                commu=0.003, err=1e-13, t1=None), row("4-2-2-1-1", totalT=0.055, commu=0.005, err=4e-13, t1=None)]
    else:
        rows = []
    d = write_runs(tmp_path, rows)
    write_schemes(d)
    assert_pngs(plot_sweep(d), SWEEP_PNGS)
    assert_pngs(plot_paper(d), ["paper_table4.png", "paper_table1.png"])


# --- the wire under commuT + migraT (issue 11): runs.csv wireT / above_wireT and modules.png -----------
def steps_frame(procs, commu, migra, wire=None, steps=3, totalT=0.01, sync=None):
    """A steps.csv of `procs` ranks x `steps` steps: commu[r][s], migra[r][s] and (optional)
    wire[r][s] and sync[r][s] (syncT; "" for an empty cell, as serial runs leave it) per rank r and
    step s [s]; the other columns constant. totalT of rank r is totalT + 0.1 ms x r, so a step's
    max over ranks is totalT + 0.1 ms x (procs - 1)."""
    rows = []
    for s in range(steps):
        for r in range(procs):
            d = dict(step=s + 1, rank=r, totalT=totalT + 1e-4 * r, commuT=commu[r][s], migraT=migra[r][s],
                     compuT=totalT - commu[r][s] - migra[r][s], neighborT=1e-3, resolveT=2e-3, rss_mb=100.0)
            if wire is not None:
                d.update(wire_s=wire[r][s], msgs_sent=52)
            if sync is not None:
                d.update(syncT=sync[r][s])
            rows.append(d)
    return pd.DataFrame(rows)


def write_point(d, mapping, steps):
    """A done point folder as bench sweep leaves it (status.json, run.json, steps.csv, state.npz);
    returns its Point."""
    import json
    import numpy as np
    from bench.sweep.points import Point
    p = Point(mapping=mapping, scheme="", scene="gas", particles=4, steps=int(steps["step"].max()), warmup=0,
              neighbor="linkcell", shape="", pin=False, halo="26")
    rep = os.path.join(d, p.key, "rep0")
    os.makedirs(rep)
    steps.to_csv(os.path.join(rep, "steps.csv"), index=False)
    with open(os.path.join(rep, "status.json"), "w") as fh:
        json.dump({"status": "done", "reason": ""}, fh)
    with open(os.path.join(rep, "run.json"), "w") as fh:
        json.dump({"particles": 4, "steps": int(steps["step"].max()), "stable": True, "wall_s": 0.1}, fh)
    np.savez(os.path.join(rep, "state.npz"), id=np.arange(4), pos=np.zeros((4, 3)), axes=np.ones((4, 3)))
    return p


def sweep_folder(d, with_wire=True, with_sync=False):
    """Serial, 2 and 4 ranks, summarised by bench.sweep.records.summarise from steps.csv files written here,
    runs.csv written by bench.sweep.records.write_runs. Numbers (ms): 2 ranks, 3 steps: commuT rank 0 =
    0.5, rank 1 = 0.7 every step (mean 0.6), migraT 0.1, wire_s rank 0 = 0.1, 0.2, 0.3 and rank 1 =
    0.3, 0.4, 0.5 (step means 0.2, 0.3, 0.4: wireT = 0.3), so above_wireT = 0.6 + 0.1 - 0.3 = 0.4;
    4 ranks: commuT 0.8, migraT 0.2, wire_s 0.25 everywhere: wireT 0.25, above_wireT 0.75. The
    serial steps.csv carries wire_s = 0 (a serial mode may write it), which must still give NaN.
    with_sync adds steps.csv's syncT (else the files have no syncT column, as older records): 2
    ranks: rank 0 = 0.2, 0.3, 0.4, rank 1 = 0.0, 0.1, 0.2 (the earlier rank waits longer; step
    means 0.1, 0.2, 0.3: syncT = 0.2), so above_wireT = 0.6 + 0.1 - 0.2 - 0.3 = 0.2; 4 ranks: syncT
    0.15 everywhere, above_wireT = 0.8 + 0.2 - 0.15 - 0.25 = 0.6; serial: syncT empty."""
    import bench.sweep.records as sw
    ms = 1e-3
    serial = steps_frame(1, [[0.0] * 3], [[0.0] * 3], [[0.0] * 3] if with_wire else None, totalT=0.02,
                         sync=[[""] * 3] if with_sync else None)
    two = steps_frame(2, [[0.5 * ms] * 3, [0.7 * ms] * 3], [[0.1 * ms] * 3] * 2,
                      [[0.1 * ms, 0.2 * ms, 0.3 * ms], [0.3 * ms, 0.4 * ms, 0.5 * ms]] if with_wire else None,
                      sync=[[0.2 * ms, 0.3 * ms, 0.4 * ms], [0.0, 0.1 * ms, 0.2 * ms]] if with_sync else None)
    four = steps_frame(4, [[0.8 * ms] * 3] * 4, [[0.2 * ms] * 3] * 4, [[0.25 * ms] * 3] * 4 if with_wire else None,
                       totalT=0.006, sync=[[0.15 * ms] * 3] * 4 if with_sync else None)
    rows = []
    t1 = None
    for mapping, st in (("1-1-1-1-1", serial), ("2-2-1-1-1", two), ("4-2-2-1-1", four)):
        p = write_point(d, mapping, st)
        r = sw.summarise(p, [os.path.join(d, p.key, "rep0")], None, t1)
        t1 = t1 or r["totalT"]
        rows.append(r)
    os.makedirs(d, exist_ok=True)
    sw.write_runs(os.path.join(d, "runs.csv"), rows)
    return str(d)


def bars(ax):
    """{container label: [bar heights]} of an axes."""
    return {c.get_label(): [p.get_height() for p in c.patches] for c in ax.containers}


def test_runs_csv_wire_columns(tmp_path):
    """wireT = mean over steps of the per-rank mean of wire_s (like commuT): 0.3 ms for 2 ranks,
    0.25 ms for 4; above_wireT = commuT + migraT - wireT = 0.4 ms and 0.75 ms; empty (NaN) for the
    serial point even though its steps.csv has wire_s = 0. These steps.csv files have no syncT
    column (older records): syncT is empty everywhere and above_wireT keeps that old definition."""
    d = sweep_folder(tmp_path / "sw")
    runs = pd.read_csv(os.path.join(d, "runs.csv"))
    assert runs["mapping"].tolist() == ["1-1-1-1-1", "2-2-1-1-1", "4-2-2-1-1"]
    assert runs["syncT"].isna().all()
    assert math.isnan(runs.loc[0, "wireT"]) and math.isnan(runs.loc[0, "above_wireT"])
    assert runs.loc[1, "commuT"] == pytest.approx(0.6e-3, rel=1e-12)
    assert runs.loc[1, "wireT"] == pytest.approx(0.3e-3, rel=1e-12)
    assert runs.loc[1, "above_wireT"] == pytest.approx(0.4e-3, rel=1e-9)
    assert runs.loc[2, "wireT"] == pytest.approx(0.25e-3, rel=1e-12)
    assert runs.loc[2, "above_wireT"] == pytest.approx(0.75e-3, rel=1e-9)


def test_modules_figure_draws_the_wire(tmp_path):
    """modules.png from that sweep: every point has its compuT / commuT / migraT bar (heights in ms
    equal runs.csv's, x 1e3); the two MPI points have a second bar stacking compuT, wireT and
    above_wireT at exactly runs.csv's values (0.3 and 0.25 ms of wire; 0.4 and 0.75 ms above it),
    with bottoms compuT and compuT + wireT; the lower panel draws the same in % of totalT; the
    serial point has no split. plot_sweep writes the PNGs from the same figure code."""
    d = sweep_folder(tmp_path / "sw")
    runs = pd.read_csv(os.path.join(d, "runs.csv"))
    fig = modules_figure(d)
    try:
        ax, ax2 = fig.axes[:2]
        h = bars(ax)
        assert "syncT" not in h  # no syncT recorded: the old split, compuT + wireT + above_wireT
        for col in ("compuT", "commuT", "migraT"):
            assert h[col] == pytest.approx((1e3 * runs[col].clip(lower=0)).tolist(), rel=1e-12), col
        mpi = runs.iloc[1:]
        assert h["wireT"] == pytest.approx((1e3 * mpi["wireT"]).tolist(), rel=1e-12)
        assert h["above_wireT"] == pytest.approx((1e3 * mpi["above_wireT"]).tolist(), rel=1e-12)
        assert h["split compuT"] == pytest.approx((1e3 * mpi["compuT"]).tolist(), rel=1e-12)
        assert h["wireT"] == pytest.approx([0.3, 0.25], rel=1e-9)
        wire_c = next(c for c in ax.containers if c.get_label() == "wireT")
        above_c = next(c for c in ax.containers if c.get_label() == "above_wireT")
        assert [p.get_y() for p in wire_c.patches] == pytest.approx((1e3 * mpi["compuT"]).tolist(), rel=1e-12)
        assert [p.get_y() for p in above_c.patches] == pytest.approx((1e3 * (mpi["compuT"] + mpi["wireT"])).tolist(),
                                                                      rel=1e-12)
        h2 = bars(ax2)
        assert h2["wireT"] == pytest.approx((100 * mpi["wireT"] / mpi["totalT"]).tolist(), rel=1e-12)
        assert h2["above_wireT"] == pytest.approx((100 * mpi["above_wireT"] / mpi["totalT"]).tolist(), rel=1e-12)
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert any(t.startswith("wireT") for t in legend) and any(t.startswith("above_wireT") for t in legend)
    finally:
        sweep_plots.plt.close(fig)
    assert_pngs(plot_sweep(d), SWEEP_PNGS)


@pytest.mark.parametrize("old", ["steps_without_wire", "runs_without_columns"])
def test_modules_figure_without_wire(tmp_path, old):
    """Older records still load and plot, as before the wire: a sweep whose steps.csv files lack
    wire_s (runs.csv wireT and above_wireT empty), and a runs.csv written before those columns
    existed. One bar per point (compuT, commuT, migraT, at runs.csv's values), no wire bar."""
    d = sweep_folder(tmp_path / "sw", with_wire=False)
    runs = pd.read_csv(os.path.join(d, "runs.csv"))
    assert runs["wireT"].isna().all() and runs["above_wireT"].isna().all()
    if old == "runs_without_columns":
        runs.drop(columns=["syncT", "wireT", "above_wireT"]).to_csv(os.path.join(d, "runs.csv"), index=False)
    fig = modules_figure(d)
    try:
        h = bars(fig.axes[0])
        assert set(h) == {"compuT", "commuT", "migraT"}
        assert h["commuT"] == pytest.approx((1e3 * runs["commuT"]).tolist(), rel=1e-12)
    finally:
        sweep_plots.plt.close(fig)
    assert_pngs(plot_sweep(d), SWEEP_PNGS)


def test_modules_figure_wire_above_overhead(tmp_path):
    """A modelled wire above the measured overhead (messages overlapped better than one after
    another): above_wireT < 0 is drawn as a 0-high bar marked '<0', the wire bar at its value."""
    d = write_runs(tmp_path, [row("1-1-1-1-1", totalT=T1),
                              row("2-2-1-1-1", totalT=0.104, commu=0.001, migra=0.0001, wire=0.0015)])
    fig = modules_figure(d)
    try:
        h = bars(fig.axes[0])
        assert h["wireT"] == pytest.approx([1.5], rel=1e-12) and h["above_wireT"] == [0.0]
        assert "<0" in [t.get_text() for t in fig.axes[0].texts]
    finally:
        sweep_plots.plt.close(fig)


# --- the step's allreduce inside commuT: runs.csv syncT and its segment in the split bar ---------------
def container(ax, label):
    return next(c for c in ax.containers if c.get_label() == label)


def test_runs_csv_sync_column(tmp_path):
    """syncT = mean over steps of the per-rank mean of steps.csv's syncT (like commuT): 0.2 ms for 2
    ranks (step means 0.1, 0.2, 0.3), 0.15 ms for 4; above_wireT = commuT + migraT - syncT - wireT
    = 0.6 + 0.1 - 0.2 - 0.3 = 0.2 ms and 0.8 + 0.2 - 0.15 - 0.25 = 0.6 ms; wireT unchanged (0.3,
    0.25 ms); the serial point (syncT cells empty, as serial runs leave them) has syncT,
    wireT and above_wireT empty."""
    d = sweep_folder(tmp_path / "sw", with_sync=True)
    runs = pd.read_csv(os.path.join(d, "runs.csv"))
    assert list(runs.columns) == RUN_COLUMNS
    assert math.isnan(runs.loc[0, "syncT"]) and math.isnan(runs.loc[0, "above_wireT"])
    assert runs.loc[1:, "syncT"].tolist() == pytest.approx([0.2e-3, 0.15e-3], rel=1e-9)
    assert runs.loc[1:, "wireT"].tolist() == pytest.approx([0.3e-3, 0.25e-3], rel=1e-12)
    assert runs.loc[1:, "above_wireT"].tolist() == pytest.approx([0.2e-3, 0.6e-3], rel=1e-9)


def test_modules_figure_draws_sync(tmp_path):
    """modules.png of that sweep: the second bar of each MPI point stacks compuT, syncT, wireT,
    above_wireT at runs.csv's values. 2 ranks: totalT = 10 + 0.1 ms (max over ranks), compuT =
    10.1 - 0.6 - 0.1 = 9.4 ms, then 0.2, 0.3, 0.2 ms; 4 ranks: totalT 6.3 ms, compuT 5.3 ms, then
    0.15, 0.25, 0.6 ms. Each segment sits on the sum of those below it and the bar's top is
    totalT (10.1 and 6.3 ms; 100 % on the lower panel): the split bar still sums to totalT. The
    first bar (compuT, commuT, migraT) is unchanged; the legend names syncT."""
    d = sweep_folder(tmp_path / "sw", with_sync=True)
    runs = pd.read_csv(os.path.join(d, "runs.csv"))
    mpi = runs.iloc[1:]
    fig = modules_figure(d)
    try:
        ax, ax2 = fig.axes[:2]
        h = bars(ax)
        for col in ("compuT", "commuT", "migraT"):
            assert h[col] == pytest.approx((1e3 * runs[col]).tolist(), rel=1e-12), col
        order = ("split compuT", "syncT", "wireT", "above_wireT")
        for name, col in zip(order, ("compuT", "syncT", "wireT", "above_wireT")):
            assert h[name] == pytest.approx((1e3 * mpi[col]).tolist(), rel=1e-12), name
        assert h["split compuT"] == pytest.approx([9.4, 5.3], rel=1e-9)
        assert h["syncT"] == pytest.approx([0.2, 0.15], rel=1e-9)
        assert h["wireT"] == pytest.approx([0.3, 0.25], rel=1e-9)
        assert h["above_wireT"] == pytest.approx([0.2, 0.6], rel=1e-9)
        below = [0.0, 0.0]
        for name in order:
            assert [p.get_y() for p in container(ax, name).patches] == pytest.approx(below, rel=1e-9, abs=1e-12), name
            below = [b + v for b, v in zip(below, h[name])]
        assert below == pytest.approx([10.1, 6.3], rel=1e-9)
        assert below == pytest.approx((1e3 * mpi["totalT"]).tolist(), rel=1e-12)
        h2 = bars(ax2)
        assert [sum(h2[name][i] for name in order) for i in range(2)] == pytest.approx([100.0, 100.0], rel=1e-9)
        assert h2["syncT"] == pytest.approx((100 * mpi["syncT"] / mpi["totalT"]).tolist(), rel=1e-12)
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert any(t.startswith("syncT") for t in legend)
        assert any("commuT + migraT - syncT - wireT" in t for t in legend)
        assert "<0" not in [t.get_text() for t in ax.texts]
    finally:
        sweep_plots.plt.close(fig)
    assert_pngs(plot_sweep(d), SWEEP_PNGS)


def test_modules_figure_sync_beside_older_point(tmp_path):
    """A runs.csv mixing a point with syncT and an older one without (e.g. a resumed sweep): 2-2-1-1-1
    totalT 104 ms, commuT 4, migraT 0.4, syncT 1.5, wireT 1.2 ms -> split compuT 99.6, syncT 1.5,
    wireT 1.2, above_wireT 4.4 - 1.5 - 1.2 = 1.7 ms; 4-2-2-1-1 (no syncT) totalT 56, commuT 6,
    migraT 0.6, wireT 1.5 -> compuT 49.4, wireT 1.5, above_wireT 6.6 - 1.5 = 5.1 ms, the old split
    with wireT right on compuT. The syncT container holds the first point's bar only; both split
    bars top out at totalT; the legend gives the older points' definition too."""
    d = write_runs(tmp_path, [row("1-1-1-1-1", totalT=T1),
                              row("2-2-1-1-1", totalT=0.104, commu=0.004, migra=0.0004, wire=0.0012, sync=0.0015),
                              row("4-2-2-1-1", totalT=0.056, commu=0.006, migra=0.0006, wire=0.0015)])
    fig = modules_figure(d)
    try:
        ax = fig.axes[0]
        h = bars(ax)
        assert h["split compuT"] == pytest.approx([99.6, 49.4], rel=1e-9)
        assert h["syncT"] == pytest.approx([1.5], rel=1e-9)
        assert h["wireT"] == pytest.approx([1.2, 1.5], rel=1e-9)
        assert h["above_wireT"] == pytest.approx([1.7, 5.1], rel=1e-9)
        assert [p.get_y() for p in container(ax, "syncT").patches] == pytest.approx([99.6], rel=1e-9)
        assert [p.get_y() for p in container(ax, "wireT").patches] == pytest.approx([101.1, 49.4], rel=1e-9)
        tops = [p.get_y() + p.get_height() for p in container(ax, "above_wireT").patches]
        assert tops == pytest.approx([104.0, 56.0], rel=1e-9)
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert any("without syncT: commuT + migraT - wireT" in t for t in legend)
    finally:
        sweep_plots.plt.close(fig)


def test_modules_figure_sync_above_overhead(tmp_path):
    """syncT + wireT above the measured overhead: commuT 1, migraT 0.1, syncT 0.8, wireT 0.5 ms ->
    above_wireT = 1.1 - 0.8 - 0.5 = -0.2 ms, drawn as a 0-high bar marked '<0'; syncT and wireT
    at their values (0.8, 0.5 ms)."""
    d = write_runs(tmp_path, [row("1-1-1-1-1", totalT=T1),
                              row("2-2-1-1-1", totalT=0.104, commu=0.001, migra=0.0001, wire=0.0005, sync=0.0008)])
    fig = modules_figure(d)
    try:
        h = bars(fig.axes[0])
        assert h["syncT"] == pytest.approx([0.8], rel=1e-12) and h["wireT"] == pytest.approx([0.5], rel=1e-12)
        assert h["above_wireT"] == [0.0]
        assert "<0" in [t.get_text() for t in fig.axes[0].texts]
    finally:
        sweep_plots.plt.close(fig)


def test_efficiency_figure_draws_the_machine_ceiling(tmp_path):
    """With DIR/ceiling.csv (bench sweep --ceiling) efficiency.png draws the two ceilings from
    efficiency 1 at one core to the csv's values at each core count: here alone 10.0 ms, together
    10.5 ms, in step 11.0 ms at 2 cores, so 10/10.5 and 10/11; without the file, nothing."""
    from bench.sweep.ceiling import CEILING_COLUMNS
    d = write_runs(tmp_path, full_sweep())
    fig = metric_figure(d, "efficiency")
    try:
        assert not any("ceiling" in l.get_label() for l in fig.axes[0].lines)
    finally:
        sweep_plots.plt.close(fig)
    pd.DataFrame([[2, 100, 3, 10.0, 10.5, 11.0, 10.0 / 10.5, 10.0 / 11.0, 0]], columns=CEILING_COLUMNS).to_csv(
        os.path.join(d, "ceiling.csv"), index=False)
    fig = metric_figure(d, "efficiency")
    try:
        lines = {l.get_label(): l for l in fig.axes[0].lines if "ceiling" in l.get_label()}
        free = next(l for k, l in lines.items() if "sharing nothing" in k)
        step = next(l for k, l in lines.items() if "every step" in k)
        assert np.array_equal(free.get_xdata(), [1.0, 2]) and np.allclose(free.get_ydata(), [1.0, 10 / 10.5])
        assert np.allclose(step.get_ydata(), [1.0, 10 / 11.0])
    finally:
        sweep_plots.plt.close(fig)


# --- figures fit for a paper (issue 34): no text on text, legends under the axes, PDFs beside PNGs -----
def flag_all(rows):
    """Every done point flagged (the worst case for labels and notes): load, spread or both, with
    the foreign load and spreads bench sweep records."""
    kinds = ("load", "spread", "load,spread", "load,ref")
    for k, r in enumerate(x for x in rows if x["status"] == "done"):
        r.update(flag=kinds[k % len(kinds)], foreign_cores=0.4 + 0.1 * k, step_spread=0.12 + 0.01 * k,
                 totalT_spread=0.3)
    return rows


def sweep_4_points():
    """4 points on 2 cores, all flagged, one more not done: serial, 2 threads (two schemes) and 2 MPI
    ranks with syncT and wireT (the example that showed the overlaps)."""
    t1 = 0.00052
    return flag_all([
        row("1-1-1-1-1", totalT=t1, t1=t1),
        row("1-1-1-1-2", "dynamic", totalT=0.0261, t1=t1),
        row("1-1-1-1-2", "static", totalT=0.0244, t1=t1),
        row("2-2-1-1-1", totalT=0.00243, commu=0.0012, migra=0.0001, err=2e-13, wire=0.000005, sync=0.00026, t1=t1),
        row("2-2-1-1-1", "", status="failed", reason="exit status 1: mpirun was unable to launch the specified "
                                                         "application as it could not access or execute"),
    ])


def sweep_16_points():
    """16 points on up to 16 cores: the paper's Table 4 mappings on 16 cores (1-1-1-1-1, 1-1-1-1-4,
    1-1-1-1-16, 2-2-1-1-8, 4-2-2-1-4, 8-2-2-2-2, 4-2-2-1-1, 16-4-2-2-1) with the 2- and 8-core ones,
    every MPI point with syncT and wireT, every point flagged, three points not done."""
    rows = [row("1-1-1-1-1", totalT=T1)]
    spec = [("1-1-1-1-2", "dynamic", 0.108), ("2-2-1-1-1", "", 0.104), ("1-1-1-1-4", "dynamic", 0.058),
            ("1-1-1-1-4", "static", 0.066), ("2-2-1-1-2", "dynamic", 0.056), ("4-2-2-1-1", "", 0.054),
            ("1-1-1-1-8", "dynamic", 0.033), ("2-2-1-1-4", "dynamic", 0.031), ("4-2-2-1-2", "dynamic", 0.030),
            ("8-2-2-2-1", "", 0.029), ("1-1-1-1-16", "dynamic", 0.021), ("2-2-1-1-8", "dynamic", 0.0185),
            ("4-2-2-1-4", "dynamic", 0.0172), ("8-2-2-2-2", "dynamic", 0.0168), ("16-4-2-2-1", "", 0.0175)]
    for k, (m, scheme, t) in enumerate(spec):
        procs = int(m.split("-")[0])
        if procs > 1:
            c = t * (0.05 + 0.02 * math.log2(procs))
            rows.append(row(m, scheme, totalT=t, commu=c, migra=0.1 * c, err=1e-13 * procs, wire=0.2 * c,
                            sync=0.3 * c))
        else:
            rows.append(row(m, scheme, totalT=t))
    rows += [row("16-4-2-2-1", "static", status="timeout", reason="no result within 600 s"),
             row("8-2-2-2-2", "static", status="failed", reason="exit status 137: killed (out of memory?)"),
             row("4-4-1-1-4", "dynamic", status="unstable", reason="kinetic energy blew up at step 12")]
    return flag_all(rows)


def with_fit_and_ceiling(d, cores=(2, 4, 8, 16)):
    """summary.json with an Amdahl fit and a ceiling.csv, so every reference line is drawn."""
    import json
    from bench.sweep.ceiling import CEILING_COLUMNS
    with open(os.path.join(d, "summary.json"), "w") as fh:
        json.dump({"serial_fraction": 0.04}, fh)
    pd.DataFrame([[c, 100, 3, 10.0, 10.0 * (1 + 0.03 * c), 10.0 * (1 + 0.06 * c), 1 / (1 + 0.03 * c),
                   1 / (1 + 0.06 * c), 0] for c in cores], columns=CEILING_COLUMNS).to_csv(
        os.path.join(d, "ceiling.csv"), index=False)
    return d


def drawn_texts(fig):
    """The figure's visible, non-empty Text artists (fig.findobj) that a draw actually renders (a
    tick whose label is set but which lies outside the view is kept by the axis and not drawn),
    with their window extents."""
    import matplotlib.text
    drawn = set()
    orig = matplotlib.text.Text.draw

    def spy(self, renderer):
        drawn.add(id(self))
        return orig(self, renderer)

    matplotlib.text.Text.draw = spy
    try:
        fig.canvas.draw()
    finally:
        matplotlib.text.Text.draw = orig
    renderer = fig.canvas.get_renderer()
    return [(t, t.get_window_extent(renderer)) for t in fig.findobj(matplotlib.text.Text)
            if t.get_visible() and t.get_text().strip() and id(t) in drawn]


def assert_readable(fig, name):
    """No two drawn texts overlap (touching within 0.5 px is allowed), none leaves the figure, no
    text is below 7 pt, and every legend is at most as wide as its axes."""
    texts = drawn_texts(fig)
    assert texts, name
    W, H = fig.bbox.width, fig.bbox.height
    tol = 0.5
    for t, b in texts:
        assert t.get_fontsize() >= 7, (name, t.get_text(), t.get_fontsize())
        assert b.x0 >= -tol and b.y0 >= -tol and b.x1 <= W + tol and b.y1 <= H + tol, \
            (name, "outside the figure", t.get_text(), b.bounds, (W, H))
    for i, (t, b) in enumerate(texts):
        for u, c in texts[i + 1:]:
            ov_x = min(b.x1, c.x1) - max(b.x0, c.x0)
            ov_y = min(b.y1, c.y1) - max(b.y0, c.y0)
            assert ov_x <= tol or ov_y <= tol, (name, "texts overlap", t.get_text(), u.get_text(), b.bounds, c.bounds)
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None:
            assert leg.get_window_extent(renderer).width <= ax.get_window_extent(renderer).width + tol, name


def figures_of(d):
    return {"speedup.png": metric_figure(d, "speedup"), "efficiency.png": metric_figure(d, "efficiency"),
            "edsf.png": metric_figure(d, "edsf"), "modules.png": modules_figure(d),
            "error_vs_time.png": error_figure(d)}


@pytest.mark.parametrize("sweep", ["4_points", "16_points"])
def test_figures_readable_at_journal_width(tmp_path, sweep):
    """Every sweep figure at a double-column width (7 in), fonts of 7 pt and more, for a sweep of 4
    points on 2 cores and one of 16 points on 16 cores, every point flagged, points not done, an
    Amdahl fit and a machine ceiling drawn: no two texts overlap (point labels, tick labels, the
    numbers on the bars, legend, notes), no text leaves the figure, legends are no wider than their
    axes; the foot note gives the flags in one line and the points not done in at most two. plot_sweep
    writes a PDF beside each PNG."""
    rows = sweep_4_points() if sweep == "4_points" else sweep_16_points()
    d = with_fit_and_ceiling(write_runs(tmp_path, rows), (2,) if sweep == "4_points" else (2, 4, 8, 16))
    figs = figures_of(d)
    try:
        for name, fig in figs.items():
            assert fig.get_size_inches()[0] == pytest.approx(7.0), name
            assert_readable(fig, name)
            notes = [t.get_text() for t in fig.texts]
            lines = "\n".join(notes).split("\n")
            assert sum("Flagged" in s for s in lines) == 1, (name, lines)
            assert len([s for s in lines if s.strip()]) <= 3, (name, lines)
            assert any("Not plotted" in s for s in lines), name
    finally:
        for fig in figs.values():
            sweep_plots.plt.close(fig)
    paths = plot_sweep(d)
    assert_pngs(paths, SWEEP_PNGS)
    assert_pdfs(paths)
    assert_saved_whole(paths[0], metric_figure(d, "speedup"))


def assert_pdfs(paths):
    """A vector PDF beside every PNG."""
    for p in paths:
        pdf = os.path.splitext(p)[0] + ".pdf"
        with open(pdf, "rb") as fh:
            assert fh.read(5) == b"%PDF-", pdf


def assert_saved_whole(path, fig):
    """The PNG at path (save_figure) is as tall as the figure it was drawn from, fig (the same one
    drawn again; closed here) less the crop's slack: its foot note below the legend was kept (extra
    bbox artists once replaced the default ones and cropped it)."""
    import matplotlib.image as mpimg
    h_in = fig.get_size_inches()[1]
    sweep_plots.plt.close(fig)
    assert fig.texts, path  # a foot note to keep
    assert mpimg.imread(path).shape[0] >= (h_in - 0.15) * sweep_plots.DPI, path


def test_modules_figure_16_points_ticks_and_notes(tmp_path):
    """modules.png of 16 points: the mapping ticks stand upright (level they would run into each other),
    one share note per point, a single short line each, and a red ring over each flagged point."""
    d = write_runs(tmp_path, sweep_16_points())
    fig = modules_figure(d)
    try:
        ax, ax2 = fig.axes[:2]
        assert all(t.get_rotation() == 90 for t in ax2.get_xticklabels())
        notes = [t.get_text() for t in ax2.texts]
        assert len(notes) == 16 and all("\n" not in s and s.endswith("%") for s in notes)
        rings = [ln for ln in ax.lines if ln.get_markeredgecolor() == "red"]
        assert len(rings) == 16
    finally:
        sweep_plots.plt.close(fig)


def test_a_figure_without_a_foot_note_keeps_its_legend(tmp_path):
    """The legend stands below the axes, out of tight_layout (layout_figure); a clean sweep has no foot
    note below it, and the saved PNG must still hold it: the same figure saved with its legend is
    taller than saved without (a crop above the legend lost it before issue 36)."""
    import matplotlib.image as mpimg
    d = write_runs(tmp_path / "sweep", [row("1-1-1-1-1", totalT=T1), row("2-2-1-1-1", totalT=T1 / 1.8)])
    with_legend = sweep_plots.save_figure(metric_figure(d, "speedup"), str(tmp_path / "with.png"))
    fig = metric_figure(d, "speedup")
    fig.axes[0].get_legend().remove()
    without = sweep_plots.save_figure(fig, str(tmp_path / "without.png"))
    assert mpimg.imread(with_legend).shape[0] > mpimg.imread(without).shape[0]


def test_modules_figure_draws_the_totalT_interval(tmp_path):
    """modules.png draws each point's totalT 95 % interval (runs.csv totalT_lo/hi) as whiskers from lo to
    hi in ms at its first bar, for the points that have one (here 2-2-1-1-1: [0.9, 1.3] x T1 / 1.8;
    the serial point has none), and says so above its legend."""
    t = T1 / 1.8
    mpi = dict(row("2-2-1-1-1", totalT=t, commu=0.1 * t), totalT_lo=0.9 * t, totalT_hi=1.3 * t)
    d = write_runs(tmp_path / "sweep", [row("1-1-1-1-1", totalT=T1), mpi])
    fig = modules_figure(d)
    whiskers = [c for c in fig.axes[0].collections if c.get_label() == "totalT: 95 % interval"]
    assert len(whiskers) == 1
    ys = sorted({round(y, 9) for seg in whiskers[0].get_segments() for y in seg[:, 1]})
    assert ys == pytest.approx([1e3 * 0.9 * t, 1e3 * 1.3 * t])
    assert "95 % interval" in fig.axes[0].get_legend().get_title().get_text()
    import matplotlib.pyplot as plt
    plt.close(fig)


# --- the paper's figures (`bench plot --paper`) at the sweep figures' standard (issue 34) ---------------
def two_counts(rows, n2=12000):
    """The rows again at a second particle count n2 (a granularity study: granularity_paper.png), the
    copies 2.5 times slower."""
    more = []
    for r in rows:
        c = dict(r, particles=n2, point=f"{r['point']}-{n2}")
        for k in ("totalT", "commuT", "migraT", "compuT", "neighborT", "resolveT"):
            c[k] = 2.5 * r[k]
        more.append(c)
    return rows + more


def paper_figures_of(d):
    from bench.studies.paper_figures import paper_granularity_points, table1_figure, table4_figure
    from bench.sweep.granularity import granularity_figure
    return {"paper_table4.png": table4_figure(d), "paper_table1.png": table1_figure(d),
            "granularity_paper.png": granularity_figure(d, paper_granularity_points())}


@pytest.mark.parametrize("sweep", ["4_points", "16_points"])
def test_paper_figures_readable_at_journal_width(tmp_path, sweep):
    """Every figure of `bench plot --paper` (paper_table4.png, paper_table1.png, granularity_paper.png)
    drawn as the sweep figures are, for the 4- and the 16-point sweep (every point flagged, points
    not done) at two particle counts with a schemes.csv: 7 in wide, no text below 7 pt, no two texts
    overlapping, none leaving the figure, legends no wider than their axes; paper_table4.png draws
    ours at the count nearest the paper's 12k and its foot note gives the flags in one line and the
    points not done in at most two. plot_paper writes the three PNGs with a PDF beside each, the foot
    note kept in the PNG."""
    rows = two_counts(sweep_4_points() if sweep == "4_points" else sweep_16_points())
    d = write_runs(tmp_path, rows)
    write_schemes(d)
    figs = paper_figures_of(d)
    try:
        for name, fig in figs.items():
            assert fig.get_size_inches()[0] == pytest.approx(7.0), name
            assert_readable(fig, name)
        ours = figs["paper_table4.png"].axes[0]
        assert "12,000 particles" in ours.get_title()
        assert len(ours.get_xticklabels()) == (2 if sweep == "4_points" else 5)
        lines = "\n".join(t.get_text() for t in figs["paper_table4.png"].texts).split("\n")
        assert sum("Flagged" in s for s in lines) == 1, lines
        assert any("Not plotted" in s for s in lines) and len([s for s in lines if s.strip()]) <= 3, lines
    finally:
        for fig in figs.values():
            sweep_plots.plt.close(fig)
    paths = plot_paper(d)
    assert_pngs(paths, ["paper_table4.png", "granularity_paper.png", "paper_table1.png"])
    assert_pdfs(paths)
    from bench.studies.paper_figures import table4_figure
    assert_saved_whole(paths[0], table4_figure(d))


def test_paper_figures_crowded_ticks_stand_upright(tmp_path):
    """paper_table4.png of ten mappings on 48 cores and paper_table1.png of six thread counts per
    scheme: the mapping ticks and the numbers above the bars stand upright where level ones would
    touch, and still no text overlaps."""
    from bench.studies.paper_figures import table1_figure, table4_figure
    rows = [row("1-1-1-1-1", totalT=T1)]
    for p in (1, 2, 3, 4, 6, 8, 12, 16, 24, 48):
        rows.append(row(f"{p}-{p}-1-1-{48 // p}", "dynamic" if p < 48 else "", totalT=0.005 + 0.0001 * p,
                        commu=0.0003 * (p > 1), migra=0.00003 * (p > 1)))
    d = write_runs(tmp_path, rows)
    write_schemes(d)
    s = pd.read_csv(os.path.join(d, "schemes.csv"))
    extra = s[s["family"] == "parallel"].assign(threads=8)
    pd.concat([s, extra, extra.assign(threads=16)]).to_csv(os.path.join(d, "schemes.csv"), index=False)
    fig4, fig1 = table4_figure(d), table1_figure(d)
    try:
        assert_readable(fig4, "paper_table4.png")
        assert_readable(fig1, "paper_table1.png")
        assert all(t.get_rotation() == 90 for t in fig4.axes[0].get_xticklabels())
        assert all(t.get_rotation() == 90 for t in fig1.axes[0].texts)
    finally:
        sweep_plots.plt.close(fig4)
        sweep_plots.plt.close(fig1)
