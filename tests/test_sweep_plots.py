"""Figures of a mapping sweep (bench.sweep_plots) from synthetic DIR/runs.csv files.

No DEM run is made: the records are written by hand, with the columns bench sweep writes.
"""
import math
import os

import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("matplotlib")

from bench import sweep_plots  # noqa: E402
from bench.sweep_plots import RUN_COLUMNS, plot_paper, plot_sweep  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SWEEP_PNGS = ("speedup.png", "efficiency.png", "edsf.png", "modules.png", "error_vs_time.png")
T1 = 0.200  # serial s/step


@pytest.fixture(autouse=True)
def low_dpi(monkeypatch):
    """Figures at a low resolution: the tests check files, not looks, and stay fast."""
    monkeypatch.setattr(sweep_plots, "DPI", 50)


def row(mapping, scheme="", status="done", reason="", totalT=None, commu=0.0, migra=0.0, err=0.0, rms=None,
        scene="gas", particles=4000, steps=50, neighbor="linkcell", t1=T1):
    """One runs.csv record as bench sweep writes it (derived columns from totalT and T(1))."""
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
        row("2-2-1-1-1", totalT=0.104, commu=0.004, migra=0.0004, err=2e-13),
        row("4-2-2-1-1", totalT=0.056, commu=0.006, migra=0.0006, err=5e-13),
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
    monkeypatch.setattr(sweep_plots, "paper_path", lambda name: str(tmp_path / "nowhere" / name))
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
