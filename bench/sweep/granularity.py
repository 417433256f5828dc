"""The granularity study (issue 36, part 5): parallel efficiency against particles per core.

Yan & Regueiro (2019) argue from granularity, the work a core holds against what it must
communicate: pure MPI wins at fine granularity (few particles per core) where hybrid ranks pay
for their threads' fork-join and shared neighbour lists, and the two draw level as each core
holds more (their Tables 3 and 4 at 94-333 particles a core). `bench sweep --particles
2000,12000,50000` runs every mapping at each N (each N with its own serial reference, so that a
point's efficiency E = T(1, N) / (p T(p, N)) is against its own size); this module reads the
sweep's runs.csv and draws granularity.png:

- top: E against particles per core g = N / p (log x), one curve per family (threads: 1 process;
  MPI: 1 thread; hybrid: both > 1): at each (N, p) the family's most efficient point, its 95 %
  interval as a bar (runs.csv efficiency_lo/hi, bench.sweep.intervals), the curve through them
  in order of g; where two families' curves cross (their difference changes sign between two
  neighbouring g, linear in log g; `crossings`), a dotted vertical line and its g: below it one
  family is ahead, above it the other;
- bottom: each family's speed against the fastest family at the same N and p, T_fastest / T
  (1: the fastest), the quantity the paper's tables give (they have no serial time, so no
  efficiency); `bench plot DIR --paper` overlays the paper's points in kind (hollow markers:
  Table 3, hybrid (one process of 16 threads a node) against pure MPI at 12k, 150k and 1M
  ellipsoids on 8-256 nodes; Table 4, the pinned mappings of 12k ellipsoids on one 36-core node
  against its pure-MPI mapping 36-1).

Plotting only reads records; points not done or flagged `load` are left out (named in the foot
note), as the ranking leaves them out.
"""
import math
import os

import numpy as np

from bench.sweep.figures import (FAMILY_STYLE, FONT, LABEL, TICK, TITLE, WIDTH, _style, done_rows, interval_bars,
                                 layout_figure, note_lines, particle_counts, plt, save_figure, skipped_rows)
from bench.sweep.records import read_runs

FAMILIES = ("threads", "MPI", "hybrid")
PAPER_LABELS = {"Table 3": "paper Table 3: 12k-1M on 8-256 nodes (hollow diamonds)",
                "Table 4": "paper Table 4: 12k on one 36-core node, pinned (hollow, the family's marker)"}


def _usable(done):
    """(done points of more than one core with an efficiency, not measured beside foreign load;
    the done points that were measured beside foreign load)."""
    loaded = done["flag"].map(lambda f: "load" in str(f).split(",")).astype(bool)
    clean = done[~loaded]
    d = clean[np.isfinite(clean["efficiency"]) & (clean["cores"] > 1) & np.isfinite(clean["particles"])].copy()
    return d, done[loaded]


def family_curves(done):
    """{family: frame of its best point (least totalT) at each (N, p), sorted by g = N / p, with
    columns g, efficiency, efficiency_lo, efficiency_hi, relative (T_fastest / T over the families at
    that N and p), mapping, particles, cores}."""
    d, _ = _usable(done)
    if not len(d):
        return {}
    d["g"] = d["particles"] / d["cores"]
    best = d.sort_values("totalT").groupby(["particles", "cores"], sort=False)["totalT"].first()
    out = {}
    for fam in FAMILIES:
        f = d[d["family"] == fam].sort_values("totalT").drop_duplicates(["particles", "cores"])
        if not len(f):
            continue
        f = f.assign(relative=[best[(n, c)] / t for n, c, t in zip(f["particles"], f["cores"], f["totalT"])])
        out[fam] = f.sort_values("g")
    return out


def crossings(curves):
    """Where two families' efficiency curves cross: a list of {"g": particles per core, "ahead_below":
    family ahead at smaller g, "ahead_above": family ahead at larger g}, from the sign changes of the
    difference at the g both curves span (each interpolated linearly in log g between its points)."""
    out = []
    fams = [f for f in FAMILIES if f in curves and len(curves[f]) >= 2]
    for i, a in enumerate(fams):
        for b in fams[i + 1:]:
            ga, ea = np.log(curves[a]["g"].to_numpy(float)), curves[a]["efficiency"].to_numpy(float)
            gb, eb = np.log(curves[b]["g"].to_numpy(float)), curves[b]["efficiency"].to_numpy(float)
            lo, hi = max(ga.min(), gb.min()), min(ga.max(), gb.max())
            xs = np.unique(np.concatenate([ga, gb]))
            xs = xs[(xs >= lo) & (xs <= hi)]
            if len(xs) < 2:
                continue
            diff = np.interp(xs, ga, ea) - np.interp(xs, gb, eb)
            for k in range(len(xs) - 1):
                d0, d1 = diff[k], diff[k + 1]
                if d0 == 0 or d0 * d1 >= 0:
                    continue
                x = xs[k] + (xs[k + 1] - xs[k]) * d0 / (d0 - d1)
                below, above = (a, b) if d0 > 0 else (b, a)
                out.append({"g": float(math.exp(x)), "ahead_below": below, "ahead_above": above})
    return sorted(out, key=lambda c: c["g"])


def crossing_lines(curves):
    """The crossings in words, e.g. "MPI overtakes threads below about 270 particles per core"."""
    return [f"{c['ahead_below']} overtakes {c['ahead_above']} below about {c['g']:.0f} particles per core"
            for c in crossings(curves)]


def granularity_figure(directory, paper=()):
    """The granularity Figure of DIR/runs.csv (module docstring), not saved; paper: points to
    overlay on the bottom axes, dicts {g, relative, family, source} (bench.studies.paper_figures)."""
    df = read_runs(directory)
    done = done_rows(df)
    curves = family_curves(done)
    _, loaded = _usable(done)
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(WIDTH, 6.0), sharex=True, gridspec_kw=dict(height_ratios=(3, 2)))
    for a in (ax, axr):
        _style(a)
        a.set_xscale("log")
    for fam, f in curves.items():
        color, marker = FAMILY_STYLE[fam]
        ax.plot(f["g"], f["efficiency"], color=color, marker=marker, ms=5.5, lw=1.0, label=fam, zorder=3)
        interval_bars(ax, f, "g", "efficiency", color)
        axr.plot(f["g"], f["relative"], color=color, marker=marker, ms=5.5, lw=1.0, zorder=3)
    sources = {}
    for p in paper:
        color, marker = FAMILY_STYLE.get(p["family"], ("C7", "o"))
        src_marker = "D" if p["source"] == "Table 3" else marker
        axr.plot([p["g"]], [p["relative"]], ls="none", marker=src_marker, mfc="none", mec=color, mew=1.1, ms=6,
                 zorder=4)
        sources.setdefault(p["source"], src_marker)
    for c in crossings(curves):
        for a in (ax, axr):
            a.axvline(c["g"], color="0.4", ls=":", lw=0.9, zorder=1)
        # inside the axes, in the room above the curves (ylim 1.18 x the top), not on the title
        ax.annotate(f"{c['ahead_below']} ahead below,\n{c['ahead_above']} above {c['g']:.0f}", (c["g"], 0.98),
                    xycoords=("data", "axes fraction"), ha="center", va="top", fontsize=FONT, color="0.3",
                    bbox=dict(boxstyle="square,pad=0.1", fc="white", ec="none"), zorder=5)
    ax.axhline(1.0, color="k", ls="--", lw=0.8, label="ideal (E = 1)", zorder=1)
    axr.axhline(1.0, color="k", ls="--", lw=0.8, zorder=1)
    top = max([1.0] + [float(v) for f in curves.values() for v in f["efficiency"]])
    ax.set_ylim(0, 1.18 * top)
    axr.set_ylim(0, 1.1)
    ns = particle_counts(done)
    ax.set_title(f"Efficiency against granularity: {', '.join(f'{n:,}' for n in ns)} particles "
                 f"({first_scene(df)})", fontsize=TITLE)
    ax.set_ylabel("efficiency E = T(1) / (p T(p))", fontsize=LABEL)
    axr.set_ylabel("T(fastest family) / T", fontsize=LABEL)
    axr.set_xlabel("particles per core N / p", fontsize=LABEL)
    from matplotlib.ticker import FuncFormatter
    for a in (ax, axr):
        a.grid(True, which="major", lw=0.4, alpha=0.5)
        a.tick_params(which="both", labelsize=TICK)
        a.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        a.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}"[0] in "25" else ""))
    if not curves:
        ax.text(0.5, 0.5, "no done point of more than one core with an efficiency", transform=ax.transAxes,
                ha="center", va="center", fontsize=8, color="0.4")
    handles = list(ax.get_legend_handles_labels()[0])
    from matplotlib.lines import Line2D
    for src, marker in sources.items():
        handles.append(Line2D([], [], ls="none", marker=marker, mfc="none", mec="0.3", label=PAPER_LABELS[src]))
    skipped = skipped_rows(df)
    note = note_lines(skipped, WIDTH) if skipped else []
    if len(loaded):  # at most two lines, then "and N more" (note_lines)
        note = list(note) + note_lines([f"{r['mapping']} at {int(r['particles']):,}" for _, r in loaded.iterrows()],
                                       WIDTH, head="Left out, measured beside foreign load: ")
    layout_figure(fig, [ax, axr], handles, note, axes_h=5.0)
    return fig


def first_scene(df):
    vals = [v for v in df["scene"] if isinstance(v, str) and v]
    return vals[0] if vals else "scene ?"


def plot_granularity(directory, paper=(), name="granularity.png"):
    """Write DIR/granularity.png (and .pdf) when the sweep has more than one particle count and
    print its crossings in words; [its path], or [] for a sweep of one size."""
    df = read_runs(directory)
    if len(particle_counts(done_rows(df))) < 2:
        return []
    for line in crossing_lines(family_curves(done_rows(df))):
        print(f"granularity: {line}")
    return [save_figure(granularity_figure(directory, paper), os.path.join(directory, name))]
