"""The paper beside our records: its Tables 4 and 1 overlaid on a sweep's (`bench plot --paper`).

plot_paper(DIR) writes paper_table4.png (module times normalised by each side's pure-MPI
totalT, ours at our largest core count above the paper's pinned Table 4 on 36 cores; for a sweep
of several particle counts, ours at the count nearest the paper's 12k), for a
sweep of several particle counts granularity_paper.png (bench.sweep.granularity with the paper's
Tables 3 and 4 in kind, paper_granularity_points) and,
only when DIR/schemes.csv exists (bench schemes), paper_table1.png (efficiency per thread scheme,
ours vs the paper's Table 1). The paper: Yan & Regueiro, Computational Particle Mechanics 2019
(its tables are package data, bench/studies/paper/).

Every figure is drawn as the sweep figures are (bench.sweep.figures): a journal's double-column
width (WIDTH, 7 in), no text below FONT (7 pt), the legend in columns below the axes and the foot
note below it (layout_figure), tick labels upright where level ones would touch, and written as PNG
with a vector PDF beside it (save_figure). table4_figure and table1_figure return the Figures
unsaved, for inspection.
"""
import math
import os
import sys

import numpy as np
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, NullFormatter
from matplotlib.transforms import offset_copy

from bench.studies.paper import table_path
from bench.sweep.figures import (FLAG_RING, FONT, LABEL, MODULES, TICK, TITLE, WIDTH, _legend_handles, _style,
                                 done_rows, empty_axes, figure_notes, first_value, layout_figure, particle_counts, plt,
                                 relayout, save_figure, skipped_rows, sweep_context)
from bench.sweep.records import read_runs

SCHEME_ORDER = ("partition", "frogleap", "headtail", "static", "dynamic")
PAPER_MAP = {"partitioning": "partition", "frog-leap": "frogleap", "head-tail": "headtail",
             "static": "static", "dynamic": "dynamic"}
PAPER_THREADS = 12
PAPER_CORES = 36


def _read_paper_table4():
    import pandas as pd
    path = table_path("table4_mappings_one_node.csv")
    if not os.path.exists(path):
        print(f"sweep plots: paper table {os.path.normpath(path)} not found; no paper overlay", file=sys.stderr)
        return None
    t = pd.read_csv(path, comment="#")
    t["pinned"] = t["pinned"].astype(str).str.strip().str.lower()
    return t


# Table 3's scales: ellipsoids and 16-core nodes (hybrid: one process of 16 threads a node)
TABLE3_SCALES = {"12k": 12000, "150k": 150000, "1M": 1000000}
TABLE3_CORES_PER_NODE = 16
TABLE4_PARTICLES = 12000


def paper_granularity_points():
    """The paper's points for the granularity figure's bottom axes (bench.sweep.granularity), in
    kind with ours: {g: particles per core, relative: T_fastest / T, family, source}. Table 3:
    pure MPI and hybrid at N = 12k, 150k, 1M on 8, 64, 256 nodes of 16 cores (g = N / (16 nodes));
    Table 4, pinned: each mapping of 12k ellipsoids on one 36-core node (g = 333) against the
    fastest there (36 x 1, pure MPI). No serial times are given, so no efficiency."""
    import pandas as pd
    out = []
    path = table_path("table3_pure_vs_hybrid.csv")
    if not os.path.exists(path):
        print(f"sweep plots: paper table {os.path.normpath(path)} not found; no Table 3 overlay", file=sys.stderr)
        t3 = pd.DataFrame(columns=["scale", "nodes", "mode", "totalT"])
    else:
        t3 = pd.read_csv(path, comment="#")
    for scale, rows in t3.groupby("scale", sort=False):
        g = TABLE3_SCALES[scale] / (int(rows["nodes"].iloc[0]) * TABLE3_CORES_PER_NODE)
        best = rows["totalT"].min()
        for _, r in rows.iterrows():
            out.append({"g": g, "relative": best / r["totalT"], "source": "Table 3",
                        "family": "MPI" if r["mode"] == "pure-mpi" else "hybrid"})
    t4 = _read_paper_table4()
    if t4 is not None:
        t4 = t4[t4["pinned"] == "yes"]
        best = t4["totalT"].min()
        for _, r in t4.iterrows():
            fam = "MPI" if r["threads"] == 1 else ("threads" if r["procs"] == 1 else "hybrid")
            out.append({"g": TABLE4_PARTICLES / PAPER_CORES, "relative": best / r["totalT"], "source": "Table 4",
                        "family": fam})
    return out


def _normalise(rows, procs, threads, cores):
    """(reference totalT, what it is): pure MPI (procs = cores, 1 thread) when present, else the best."""
    pure = rows[(rows[procs] == cores) & (rows[threads] == 1)]
    if len(pure) and pure["totalT"].min() > 0:
        return float(pure["totalT"].min()), f"pure MPI {int(cores)}x1"
    return float(rows["totalT"].min()), "best totalT"


BAR_W = 0.2  # a group's four bars (totalT and its modules), in units of the group spacing
BAR_COLS = (("totalT", "totalT", "0.55"),) + tuple(MODULES)


def _grouped_log_bars(ax, labels, table, ref, hatch=None):
    """Grouped bars (totalT, compuT, commuT, migraT)/ref on a log axis; zeros marked '0', values not
    recorded '-' (FONT points, at the foot of the bar's place)."""
    x = np.arange(len(labels))
    for k, (key, lab, color) in enumerate(BAR_COLS):
        v = np.asarray(table[key], dtype=float) / ref
        xs = x + (k - 1.5) * BAR_W
        good = np.isfinite(v) & (v > 0)
        ax.bar(xs[good], v[good], BAR_W, color=color, label=lab, hatch=hatch, edgecolor="white" if hatch else None,
               lw=0.3)
        for xi, vi in zip(xs[~good], v[~good]):
            ax.text(xi, 0.01, "0" if np.isfinite(vi) else "-", transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=FONT, color=color)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, fontsize=TICK)
    # groups at most about 1.4 in apart, however few (the axes about WIDTH - 0.6 in wide)
    half = max(len(labels) + 0.2, (WIDTH - 0.6) / 1.4) / 2
    ax.set_xlim((len(labels) - 1) / 2 - half, (len(labels) - 1) / 2 + half)


def _upright_when_crowded(axes):
    """Stand the x tick labels of each axes upright where level ones would touch their neighbours
    (as modules.png's mapping ticks); True when any did (the caller lays the figure out again)."""
    changed = False
    for ax in axes:
        renderer = ax.figure.canvas.get_renderer()
        ticks = [t for t in ax.get_xticklabels() if t.get_text()]
        if len(ticks) < 2:
            continue
        step = abs(ax.transData.transform((1.0, 1.0))[0] - ax.transData.transform((0.0, 1.0))[0])
        if max(t.get_window_extent(renderer).width for t in ticks) + 4 * ax.figure.dpi / 72.0 > step:
            for t in ticks:
                t.set_rotation(90)
                t.set_ha("center")
                t.set_va("top")
            changed = True
    return changed


def plot_paper(directory):
    """Overlay the paper's tables on ours: paper_table4.png (module times per procs x threads,
    normalised by each side's pure-MPI totalT, ours at our largest core count above the paper's
    pinned Table 4, 36 cores), for a sweep of several particle counts granularity_paper.png, and,
    when DIR/schemes.csv exists, paper_table1.png (efficiency per thread scheme, ours vs the
    paper's Table 1). Each is drawn at the sweep figures' journal width (bench.sweep.figures: WIDTH,
    no text below FONT points, legend below the axes) and written as PNG with a PDF beside it.
    Returns the written PNG paths."""
    paths = []
    p = _plot_paper_table4(directory)
    if p:
        paths.append(p)
    from bench.sweep.granularity import plot_granularity
    runs = os.path.join(directory, "runs.csv")
    if os.path.exists(runs) and len(particle_counts(done_rows(read_runs(directory)))) > 1:
        paths += plot_granularity(directory, paper_granularity_points(), name="granularity_paper.png")
    if os.path.exists(os.path.join(directory, "schemes.csv")):
        paths.append(_plot_paper_table1(directory))
    return paths


def _plot_paper_table4(directory):
    if not os.path.exists(os.path.join(directory, "runs.csv")):
        print(f"sweep plots: {os.path.join(directory, 'runs.csv')} not found; no paper_table4.png", file=sys.stderr)
        return None
    return save_figure(table4_figure(directory), os.path.join(directory, "paper_table4.png"))


def table4_figure(directory):
    """The paper_table4.png Figure of DIR/runs.csv, not saved: ours (top axes: the largest core
    count, one bar group per procs x threads, the fastest point when several; a flagged point
    ringed in red above its group) above the paper's pinned Table 4 (bottom axes, its unpinned
    totals as crosses), the same log y axis, each side normalised by its own pure-MPI totalT.
    The caller closes it."""
    df = read_runs(directory)
    done = done_rows(df)
    done = done[np.isfinite(done["cores"]) & (done["totalT"] > 0)]
    skipped = skipped_rows(df)
    ctx = sweep_context(df)
    counts = particle_counts(done)
    if len(counts) > 1:  # a granularity study: the particle count nearest the paper's 12k, not a mix
        n = min(counts, key=lambda c: abs(math.log(c / TABLE4_PARTICLES)))
        done = done[done["particles"] == n]
        ctx = sweep_context(df[df["particles"] == n])
    paper = _read_paper_table4()
    fig, axes = plt.subplots(2, 1, figsize=(WIDTH, 5.6), sharey=True)
    ax, axp = axes
    for a in axes:
        _style(a)
    ymin, ymax = [], []
    ours = done.iloc[0:0]
    rings = []
    # ours: the largest core count, one bar group per procs x threads (the fastest when several)
    if len(done):
        cmax = done["cores"].max()
        ours = done[done["cores"] == cmax].sort_values("totalT").drop_duplicates(["procs", "threads"])
        ours = ours.sort_values(["procs", "threads"])
        ref, what = _normalise(ours, "procs", "threads", cmax)
        labels = [f"{int(r['procs'])} x {int(r['threads'])}\n{r['mapping']}" for _, r in ours.iterrows()]
        tab = {k: ours[k].to_numpy(dtype=float) for k in ("totalT", "compuT", "commuT", "migraT")}
        tab["compuT"] = np.where(np.isfinite(tab["compuT"]), tab["compuT"],
                                 tab["totalT"] - np.nan_to_num(tab["commuT"]) - np.nan_to_num(tab["migraT"]))
        _grouped_log_bars(ax, labels, tab, ref)
        v = np.concatenate([t / ref for t in tab.values()])
        v = v[np.isfinite(v) & (v > 0)]
        ymin.append(v.min())
        ymax.append(v.max())
        flag = np.array([bool(str(f).strip()) for f in ours["flag"]]) if "flag" in ours else np.zeros(len(ours), bool)
        rings = [(i - 1.5 * BAR_W, t / ref) for i, (t, f) in enumerate(zip(tab["totalT"], flag)) if f]
        several = len(done[done["cores"] == cmax]) > len(ours)
        ax.set_title(f"ours: {int(cmax)} core{'s' if cmax != 1 else ''}, {ctx}\nnormalised by our {what} "
                     f"= {1e3 * ref:.3g} ms/step" + ("; the fastest point per procs x threads" if several else ""),
                     fontsize=TITLE)
    else:
        empty_axes(ax, "ours: no completed point")
        ax.set_xticks([])
        ax.set_title(f"ours: {ctx}", fontsize=TITLE)
    # the paper: pinned Table 4, 36 cores
    if paper is not None:
        pin = paper[paper["pinned"] == "yes"].sort_values("procs")
        unpin = paper[paper["pinned"] == "no"].set_index("procs")
        pref, pwhat = _normalise(pin, "procs", "threads", PAPER_CORES)
        strings = {}
        mpath = table_path("table4_mapping_strings.csv")
        if os.path.exists(mpath):
            import pandas as pd
            for m in pd.read_csv(mpath, comment="#")["mapping"]:
                strings[int(str(m).split("-")[0])] = str(m)
        labels = [f"{int(r['procs'])} x {int(r['threads'])}" + (f"\n{strings[int(r['procs'])]}"
                                                                if int(r["procs"]) in strings else "")
                  for _, r in pin.iterrows()]
        tab = {k: pin[k].to_numpy(dtype=float) for k in ("totalT", "compuT", "commuT", "migraT")}
        _grouped_log_bars(axp, labels, tab, pref)
        # unpinned totals as markers, same normalisation (pinned pure MPI)
        un = np.array([unpin["totalT"].get(int(p), np.nan) for p in pin["procs"]], dtype=float) / pref
        axp.plot(np.arange(len(pin)) - 1.5 * BAR_W, un, ls="none", marker="x", color="k", ms=5, mew=1.0,
                 label="paper: totalT not pinned")
        v = np.concatenate([t / pref for t in tab.values()] + [un])
        v = v[np.isfinite(v) & (v > 0)]
        ymin.append(v.min())
        ymax.append(v.max())
        axp.set_title(f"paper (Yan & Regueiro, Table 4): 12k ellipsoids, one {PAPER_CORES}-core node, pinned\n"
                      f"normalised by its {pwhat} = {1e3 * pref:.3g} ms/step", fontsize=TITLE)
    else:
        empty_axes(axp, "paper table 4 not found\n(bench/studies/paper/table4_mappings_one_node.csv)")
        axp.set_xticks([])
        axp.set_title("paper (Yan & Regueiro, Table 4)", fontsize=TITLE)
    for a in axes:
        a.set_xlabel("procs x threads (mapping)", fontsize=LABEL)
        a.set_ylabel("time / reference totalT", fontsize=LABEL)
    if ymin:
        axp.set_yscale("log")
        axp.set_ylim(min(ymin) / 3, max(ymax) * 3)
        for a in axes:
            a.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            a.yaxis.set_minor_formatter(NullFormatter())
    for a in axes:
        a.grid(True, axis="y", which="major", lw=0.4, alpha=0.5)
        a.set_axisbelow(True)
        a.axhline(1.0, color="k", lw=0.7, ls=":")
    for xr, yr in rings:  # a small red ring above a flagged point's totalT bar (the foot note says why)
        ax.plot([xr], [yr], transform=offset_copy(ax.transData, fig, y=6, units="points"), label="_flag",
                **dict(FLAG_RING, ms=6, mew=1.0))
    handles = [Patch(color=c, label=lab) for _, lab, c in BAR_COLS] if len(ours) or paper is not None else []
    if paper is not None:
        handles += [h for h in axp.get_lines() if h.get_label() == "paper: totalT not pinned"]
    title = ("each panel normalised by its own pure-MPI totalT (its best totalT without one; dotted line: 1);\n"
             "'0': a zero time, '-': a time not recorded")
    layout_figure(fig, list(axes), handles, figure_notes(ours, skipped, WIDTH), axes_h=5.6, legend_title=title)
    if _upright_when_crowded(axes):
        relayout(fig)
    return fig


def _read_paper_table1():
    """{our scheme: paper efficiency (speedup / 12)} from the paper's Table 1, or {} if absent."""
    import pandas as pd
    path = table_path("table1_thread_schemes.csv")
    if not os.path.exists(path):
        print(f"sweep plots: paper table {os.path.normpath(path)} not found; no paper overlay", file=sys.stderr)
        return {}
    t = pd.read_csv(path, comment="#")
    return {PAPER_MAP[m]: float(s) / PAPER_THREADS for m, s in zip(t["method"], t["speedup"]) if m in PAPER_MAP}


def _plot_paper_table1(directory):
    return save_figure(table1_figure(directory), os.path.join(directory, "paper_table1.png"))


def table1_figure(directory):
    """The paper_table1.png Figure of DIR/schemes.csv, not saved: grouped bars of parallel
    efficiency per thread scheme, ours per (neighbour method, threads) against its own serial
    (efficiency_own = T(serial, same neighbour method) / (threads x T)), the paper's Table 1 (12
    threads, n-by-n loops, so against serial n-by-n) beside them; each bar's value above it (upright
    where a level one would be wider than its bar). The caller closes it."""
    import pandas as pd
    s = pd.read_csv(os.path.join(directory, "schemes.csv"))
    for c in ("method", "neighbor", "shape"):
        s[c] = s[c].fillna("").astype(str) if c in s else ""
    for c in ("threads", "particles", "speedup", "efficiency", "efficiency_own", "paper_speedup",
              "paper_efficiency"):
        s[c] = pd.to_numeric(s[c], errors="coerce") if c in s else math.nan
    # efficiency against the serial run of the same neighbour method where recorded, else vs all-pairs
    own = bool(np.isfinite(s["efficiency_own"]).any())
    metric = "efficiency_own" if own else "efficiency"
    thr = s[(s["method"] != "serial") & (s["method"] != "")]
    methods = [m for m in SCHEME_ORDER if m in set(thr["method"])] + sorted(set(thr["method"]) - set(SCHEME_ORDER))
    paper = {m: v for m, v in thr.groupby("method")["paper_efficiency"].max().items() if np.isfinite(v)}
    if not paper:
        paper = _read_paper_table1()
    groups = sorted({(nb, t) for nb, t in zip(thr["neighbor"], thr["threads"])}, key=lambda g: (g[0], g[1]))
    nser = len(groups) + 1
    w = 0.8 / nser
    x = np.arange(len(methods))
    fig, ax = plt.subplots(figsize=(WIDTH, 3.6))
    _style(ax)
    top = 1.0
    nbname = {"allpairs": "all-pairs", "linkcell": "link-cell"}
    values = []  # (x, value) of every bar with a value, for the numbers above them
    for k, (nb, t) in enumerate(groups):
        sub = thr[(thr["neighbor"] == nb) & (thr["threads"] == t)].drop_duplicates("method").set_index("method")
        vals = np.array([float(sub[metric].get(m, np.nan)) for m in methods])
        against = f"vs serial {nbname.get(nb, nb)}" if own else "vs serial all-pairs"
        xs = x + (k - (nser - 1) / 2) * w
        ax.bar(xs, np.nan_to_num(vals), w, color=f"C{k}",
               label=f"ours, {nbname.get(nb, nb or '?')}, {int(t) if np.isfinite(t) else '?'} threads ({against})")
        values += [(xi, v) for xi, v in zip(xs, vals) if np.isfinite(v)]
    pv = np.array([paper.get(m, np.nan) for m in methods])
    xs = x + (nser - 1 - (nser - 1) / 2) * w
    ax.bar(xs, np.nan_to_num(pv), w, color="0.55",
           label=f"paper Table 1, n-by-n, {PAPER_THREADS} threads (vs serial n-by-n)" + ("" if paper else
                                                                                          " (table missing)"))
    values += [(xi, v) for xi, v in zip(xs, pv) if np.isfinite(v)]
    top = max([top] + [v for _, v in values])
    ax.axhline(1.0, color="k", ls="--", lw=0.8, label="ideal: speedup = threads")
    ax.set_xticks(x)
    ax.set_xticklabels(methods, fontsize=TICK)
    ax.set_xlim(-0.6, max(len(methods), 1) - 0.4)
    ax.set_ylim(0, 1.1 * top)
    ax.set_xlabel("thread scheme of contact detection (neighbour estimate + contact resolution)", fontsize=LABEL)
    ax.set_ylabel("efficiency = speedup / threads\n" + ("(vs serial, same neighbour method)" if own else
                                                        "(vs serial all-pairs detection)"), fontsize=LABEL)
    n = first_value(s, "particles") if len(s) else None
    shape = first_value(s, "shape") if len(s) else None
    ax.set_title(f"Contact-detection efficiency per thread scheme, ours vs paper Table 1\n"
                 f"ours: {int(n) if n is not None else '?'} packed {shape or 'particle'}s; paper: 2.5k packed "
                 f"ellipsoids, dual Xeon X5690", fontsize=TITLE)
    if not methods:
        empty_axes(ax, "no threaded scheme in schemes.csv")
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    ax.set_axisbelow(True)
    layout_figure(fig, [ax], _legend_handles(ax), [], axes_h=3.6)
    _upright_when_crowded([ax])
    # the numbers above the bars: level where they fit on their bar, else upright; room above for them
    renderer = fig.canvas.get_renderer()
    px = fig.dpi / 72.0
    bar_pt = abs(ax.transData.transform((w, 0))[0] - ax.transData.transform((0, 0))[0]) / px
    texts = [f"{v:.2f}" for _, v in values]
    probe = ax.text(0, 0, max(texts, key=len) if texts else "", fontsize=FONT)
    text_w = probe.get_window_extent(renderer).width / px
    probe.remove()
    up = text_w + 1 > bar_pt
    for (xi, v), txt in zip(values, texts):
        ax.annotate(txt, (xi, v), xytext=(0, 1.0), textcoords="offset points", ha="center", va="bottom",
                    fontsize=FONT, rotation=90 if up else 0)
    head = (text_w if up else FONT * 1.25) + 3
    h_pt = ax.get_window_extent(renderer).height / px
    ax.set_ylim(0, max(1.1 * top, top / max(0.3, 1 - head / h_pt)))
    relayout(fig)
    return fig
