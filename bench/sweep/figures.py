"""Figures of a mapping sweep, drawn from DIR/runs.csv (plotting only reads records).

plot_sweep(DIR) writes, in DIR:
- speedup.png: speedup T(1)/T(p) against cores p = procs x threads (log2-log2), one series per
  family (threads: 1 process; MPI: 1 thread; hybrid: both > 1; split by thread scheme and by
  neighbour method when those vary), every point labelled with its mapping P-px-py-pz-T, the
  ideal y = x and, when DIR/summary.json holds one, the Amdahl curve of the fitted serial fraction;
- efficiency.png: speedup / cores against cores, ideal line at 1;
- edsf.png: the Karp-Flatt experimentally determined serial fraction against cores (p > 1), a
  line at 0 and the Amdahl fit when present;
- modules.png: per mapping (x axis ordered by cores, then procs; grouped by core count) stacked
  bars of compuT, commuT, migraT in ms/step (top) and as % of totalT (bottom), the paper's
  Figs. 19-21 in kind; where runs.csv has wireT (MPI points whose steps.csv has wire_s), a second
  bar beside it stacks compuT, syncT (the step's allreduce: waiting for the slowest rank + the
  collective's latency; only where runs.csv has it), wireT (the modelled wire time of the bytes
  sent, modes/wire.py) and above_wireT = commuT + migraT - syncT - wireT (the software above the
  wire in the exchanges; commuT + migraT - wireT without syncT); modules_figure(DIR) returns that
  Figure unsaved;
- error_vs_time.png: err_max (final-position error against the serial run over the mean
  particle radius) against totalT [ms/step], log-log; zero errors (bit-identical modes) are
  drawn hollow on a dashed floor line a decade below the smallest non-zero error.

Points with status != done are not plotted; they are listed in a note at the foot of each
figure (and once on stdout by plot_sweep). Points whose runs.csv `flag` is set (measured under
foreign load, or with a wide spread: bench.sweep.records) are ringed in red on the speedup,
efficiency, EDSF and error figures (a Line2D labelled FLAG_LABEL), their labels and the modules
figure's tick labels end in `[flag]`, and each figure's foot note lists them with their foreign
load and spreads. No figure raises on a runs.csv with only the
serial point, with every point failed, with NaN columns or with a single core count.
"""
import math
import os
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter, NullLocator  # noqa: E402

from bench.sweep.records import read_runs  # noqa: E402
from bench.sweep.ceiling import read_ceiling  # noqa: E402

FAMILY_STYLE = {"serial": ("k", "*"), "threads": ("C0", "o"), "MPI": ("C3", "s"), "hybrid": ("C2", "^")}
FAMILY_ORDER = ("serial", "threads", "MPI", "hybrid")
MODULES = (("compuT", "compuT (computation)", "C0"), ("commuT", "commuT (communication)", "C1"),
           ("migraT", "migraT (migration)", "C2"))
# the overhead commuT + migraT split at the wire (issue 11): the second bar of an MPI point, syncT
# (the allreduce inside commuT) only where runs.csv has it
WIRE_SPLIT = (("compuT", "compuT (computation)", "C0", None),
              ("syncT", "syncT: waiting for the slowest rank + the step's allreduce", "C4", None),
              ("wireT", "wireT: wire time of the bytes sent (ping-pong alpha + n / beta)", "0.35", None),
              ("above_wireT", "above_wireT: software above the wire = commuT + migraT - syncT - wireT", "C3", "////"))
ABOVE_WIRE_OLD = "above_wireT: software above the wire = commuT + migraT - wireT"  # no syncT recorded
DPI = 120
FONT = 7
FLAG_LABEL = "flagged: timing doubtful, its own or its T(1) reference's (runs.csv flag)"
FLAG_RING = dict(ls="none", marker="o", ms=14, mfc="none", mec="red", mew=1.3, zorder=4)


def flagged(d):
    """The rows of d whose runs.csv flag is set."""
    return d[d["flag"].astype(str).str.strip() != ""] if "flag" in d else d.iloc[0:0]


def flag_suffix(r):
    f = str(r.get("flag", "") or "").strip()
    return f" [{f}]" if f else ""


def flag_notes(d):
    """'mapping scheme: flag (foreign load, spreads)' of the flagged rows of d."""
    out = []
    for _, r in flagged(d).iterrows():
        bits = []
        for col, text in (("foreign_cores", "foreign load {:.2f} CPUs"), ("totalT_spread", "repeat spread {:.0%}"),
                          ("step_spread", "step spread {:.0%}")):
            v = r.get(col)
            if v is not None and np.isfinite(v):
                bits.append(text.format(v))
        if "ref" in str(r["flag"]).split(","):
            bits.append("its T(1) reference is flagged")
        out.append(f"{_point_name(r)}: {r['flag']}" + (f" ({', '.join(bits)})" if bits else ""))
    return out


def figure_notes(done, skipped, width):
    return note_lines(skipped, width) + note_lines(flag_notes(done), width,
                                                   head="Flagged, timing doubtful (runs.csv flag): ")


def done_rows(df):
    return df[(df["status"] == "done") & np.isfinite(df["totalT"])].copy()


def first_value(df, col):
    vals = [v for v in df[col] if (v != "" if isinstance(v, str) else np.isfinite(v))]
    return vals[0] if vals else None


def sweep_context(df):
    """'scene X, N particles, S steps, neighbour' from the first record that has them."""
    scene = first_value(df, "scene") or "scene ?"
    n = first_value(df, "particles")
    steps = first_value(df, "steps")
    nb = first_value(df, "neighbor")
    bits = [f"{scene}", f"{int(n):,} particles" if n is not None else "particles ?"]
    if steps is not None:
        bits.append(f"{int(steps)} steps")
    if nb:
        bits.append(nb)
    return ", ".join(bits)


def _point_name(r, with_scheme=True):
    s = r["mapping"] or r["point"] or "?"
    if with_scheme and r["scheme"] and r["threads"] > 1:
        s += f" {r['scheme']}"
    return s


def skipped_rows(df):
    """'mapping scheme: status (reason)' of every point not done."""
    out = []
    for _, r in df[df["status"] != "done"].iterrows():
        reason = (r["reason"] or "").strip().replace("\n", " ")
        if len(reason) > 70:
            reason = reason[:67] + "..."
        out.append(f"{_point_name(r)}: {r['status'] or 'no status'}{' (' + reason + ')' if reason else ''}")
    # done but without a time (cannot be drawn either)
    for _, r in df[(df["status"] == "done") & ~np.isfinite(df["totalT"])].iterrows():
        out.append(f"{_point_name(r)}: done but no totalT")
    return out


def _series(done):
    """{series label: (family, rows)} in a stable order; the family is split by scheme (threaded
    points) and by neighbour method when those take more than one value among the plotted points."""
    threaded = done[done["threads"] > 1]
    split_scheme = len(set(threaded["scheme"])) > 1
    split_nb = len(set(done["neighbor"])) > 1
    keys = {}
    for i, r in done.iterrows():
        fam = r["family"]
        label = fam
        extra = []
        if split_scheme and r["threads"] > 1 and r["scheme"]:
            extra.append(r["scheme"])
        if split_nb and r["neighbor"]:
            extra.append(r["neighbor"])
        if extra:
            label += f" ({', '.join(extra)})"
        keys.setdefault((FAMILY_ORDER.index(fam) if fam in FAMILY_ORDER else 9, label, fam), []).append(i)
    return [(label, fam, done.loc[idx]) for (_, label, fam), idx in sorted(keys.items())]


def _series_colors(series):
    """Color per series: the family's color for the first series of a family, then tab10 leftovers."""
    used, out = set(), {}
    spare = [f"C{k}" for k in (1, 4, 5, 6, 8, 9, 7)]
    for label, fam, _ in series:
        c = FAMILY_STYLE.get(fam, ("C7", "o"))[0]
        if c in used:
            c = next((s for s in spare if s not in used), "0.4")
        used.add(c)
        out[label] = c
    return out


def _amdahl(directory):
    try:
        import json
        with open(os.path.join(directory, "summary.json")) as fh:
            f = json.load(fh).get("serial_fraction")
        # a fit outside [0, 1] is no serial fraction (not Amdahl-limited points): draw no curve
        return float(f) if f is not None and math.isfinite(float(f)) and 0.0 <= float(f) <= 1.0 else None
    except Exception:  # noqa: BLE001  (an absent or odd summary just means no fit line)
        return None


# --- layout helpers -------------------------------------------------------------------------------------
def note_lines(lines, width_in, head="Not plotted (status != done): "):
    if not lines:
        return []
    chars = max(40, int(width_in * 72 / (0.52 * FONT)))
    return textwrap.wrap(head + "; ".join(lines), chars)


def finish_figure(fig, note):
    """tight layout leaving room for the foot note (lines of text), and write the note."""
    h_in = fig.get_size_inches()[1]
    bottom = (len(note) * FONT * 1.35 + 6) / (72 * h_in) if note else 0.0
    fig.tight_layout(rect=(0, min(bottom, 0.4), 1, 1))
    if note:
        fig.text(0.01, 0.006, "\n".join(note), fontsize=FONT, va="bottom", ha="left", color="0.25")
    return bottom


def save_figure(fig, path):
    """Write the figure atomically (a full disk leaves the old file and raises RecordError)."""
    from bench.run.records import atomic_write
    try:
        atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=DPI, bbox_inches="tight", pad_inches=0.08),
                     mode="wb")
    finally:
        plt.close(fig)
    return path


def _place_labels(ax, pts, fontsize=FONT - 0.5):
    """Annotate points (x, y, text, color) right of the marker (left when near the right edge),
    nudged vertically in display space so that labels do not overlap; call once limits and the
    layout are final."""
    if not pts:
        return
    fig = ax.figure
    k = 72.0 / fig.dpi  # pixels -> points
    bbox = ax.get_window_extent()
    right = bbox.x1 * k
    h = fontsize * 1.2
    disp = []
    for x, y, text, color in pts:
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        X, Y = ax.transData.transform((x, y))
        disp.append((X * k, Y * k, text, color, x, y))
    disp.sort(key=lambda d: (round(d[0], 1), d[1]))
    boxes = [(X - 3, Y - 3, X + 3, Y + 3) for X, Y, *_ in disp]  # the markers themselves

    def free(b):
        return all(b[2] <= o[0] or b[0] >= o[2] or b[3] <= o[1] or b[1] >= o[3] for o in boxes)

    for X, Y, text, color, x, y in disp:
        w = 0.56 * fontsize * len(text)
        side = 1 if X + 6 + w < right + 40 else -1
        chosen = None
        for step in [0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6, -6, 8, -8]:
            dy = step * h
            x0 = X + 5 if side > 0 else X - 5 - w
            b = (x0, Y + dy - h / 2, x0 + w, Y + dy + h / 2)
            if free(b):
                chosen = (dy, b)
                break
        if chosen is None:
            dy = 0.0
            x0 = X + 5 if side > 0 else X - 5 - w
            chosen = (dy, (x0, Y - h / 2, x0 + w, Y + h / 2))
        dy, b = chosen
        boxes.append(b)
        arrow = dict(arrowstyle="-", lw=0.4, color="0.55", shrinkA=0, shrinkB=2) if abs(dy) > h * 0.6 else None
        ax.annotate(text, (x, y), xytext=(5 * side, dy), textcoords="offset points", fontsize=fontsize,
                    ha="left" if side > 0 else "right", va="center", color=color, arrowprops=arrow,
                    annotation_clip=False, zorder=4,
                    bbox=dict(boxstyle="square,pad=0.05", fc="white", ec="none", alpha=0.75))


def _log2_cores_axis(ax, cores, label_room=1.8):
    cores = sorted({int(c) for c in cores if np.isfinite(c) and c > 0}) or [1]
    ax.set_xscale("log", base=2)
    ax.set_xlim(min(cores) / 1.35, max(cores) * label_room)
    ax.xaxis.set_major_locator(FixedLocator(cores))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xticklabels([str(c) for c in cores])
    ax.set_xlabel("cores = processes x threads")
    return cores


def empty_axes(ax, text):
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9, color="0.35")


# --- plot_sweep -----------------------------------------------------------------------------------------
def plot_sweep(directory):
    """Read DIR/runs.csv and write speedup.png, efficiency.png, edsf.png, modules.png and
    error_vs_time.png in DIR; return their paths. Points not done are listed in a foot note
    of each figure and on stdout."""
    df = read_runs(directory)
    done = done_rows(df)
    skipped = skipped_rows(df)
    if skipped:
        print(f"sweep plots: not plotted (status != done): {'; '.join(skipped)}")
    ctx = sweep_context(df)
    fit = _amdahl(directory)
    paths = [
        _plot_metric(done, skipped, ctx, fit, "speedup", os.path.join(directory, "speedup.png")),
        _plot_metric(done, skipped, ctx, fit, "efficiency", os.path.join(directory, "efficiency.png"),
                     read_ceiling(directory)),
        _plot_metric(done, skipped, ctx, fit, "edsf", os.path.join(directory, "edsf.png")),
        _plot_modules(done, skipped, ctx, os.path.join(directory, "modules.png")),
        _plot_error(done, skipped, ctx, os.path.join(directory, "error_vs_time.png")),
    ]
    return paths


def metric_figure(directory, metric):
    """The speedup.png, efficiency.png or edsf.png Figure (metric = its runs.csv column) of
    DIR/runs.csv, not saved (for inspection: one Line2D of markers per series, labelled as in the
    legend, x = cores, y = the metric). The caller closes it."""
    df = read_runs(directory)
    return _metric_figure(done_rows(df), skipped_rows(df), sweep_context(df), _amdahl(directory), metric,
                          read_ceiling(directory) if metric == "efficiency" else ())


def _plot_metric(done, skipped, ctx, fit, metric, path, ceiling=()):
    return save_figure(_metric_figure(done, skipped, ctx, fit, metric, ceiling), path)


def _metric_figure(done, skipped, ctx, fit, metric, ceiling=()):
    """speedup / efficiency / edsf against cores, one series per family (and scheme); on the
    efficiency figure also the machine's ceiling of DIR/ceiling.csv where a sweep measured it
    (bench.sweep.ceiling: W independent copies, alone over together and over meeting every step)."""
    fig, ax = plt.subplots(figsize=(8.6, 5.0))
    d = done[np.isfinite(done[metric]) & np.isfinite(done["cores"])]
    if metric == "edsf":
        d = d[d["cores"] > 1]
    series = _series(d)
    colors = _series_colors(series)
    serial = done[done["family"] == "serial"]
    s_ref = (1.0, float(serial[metric].iloc[0]) if metric != "edsf" and len(serial) and
             np.isfinite(serial[metric].iloc[0]) else None)
    labels = []
    for label, fam, rows in series:
        color, marker = colors[label], FAMILY_STYLE.get(fam, ("C7", "o"))[1]
        ax.plot(rows["cores"], rows[metric], ls="none", marker=marker, ms=8 if marker == "*" else 6,
                color=color, label=label, zorder=3)
        # a thin line through the best point per core count, from the serial reference
        best = rows.sort_values("totalT").groupby("cores", sort=True)[metric].first()
        xs, ys = list(best.index), list(best.values)
        if fam != "serial" and s_ref[1] is not None and (not xs or xs[0] > 1):
            xs, ys = [1.0] + xs, [s_ref[1]] + ys
        if len(xs) > 1:
            ax.plot(xs, ys, color=color, lw=1.0, alpha=0.6, zorder=2)
        for _, r in rows.iterrows():
            labels.append((r["cores"], r[metric], (r["mapping"] or r["point"]) + flag_suffix(r), color))
    fl = flagged(d)
    if len(fl):
        ax.plot(fl["cores"], fl[metric], label=FLAG_LABEL, **FLAG_RING)
    cores = _log2_cores_axis(ax, list(d["cores"]) + ([] if metric == "edsf" and len(d) else [1]))
    xlo, xhi = ax.get_xlim()
    pp = np.geomspace(max(xlo, 1.0), xhi, 100)
    if metric == "speedup":
        ax.set_yscale("log", base=2)
        ax.plot([xlo, xhi], [xlo, xhi], "k--", lw=0.8, label="ideal: speedup = cores", zorder=1)
        if fit is not None:
            ax.plot(pp, 1 / (fit + (1 - fit) / pp), color="0.5", ls=":", lw=1.0,
                    label=f"Amdahl fit, serial fraction f = {fit:.3f}")
        vals = [v for v in d[metric] if v > 0] + [1.0, max(cores)]
        lo, hi = min(vals) / 1.5, max(vals) * 1.5
        ax.set_ylim(lo, hi)
        ticks = [2.0 ** k for k in range(int(math.floor(math.log2(lo))), int(math.ceil(math.log2(hi))) + 1)]
        ax.yaxis.set_major_locator(FixedLocator(ticks))
        ax.yaxis.set_minor_locator(NullLocator())
        ax.set_yticklabels([f"{t:g}" for t in ticks])
        ax.set_ylabel("speedup T(1) / T(p)  [totalT of serial 1-1-1-1-1 / totalT]")
        ax.set_title(f"Speedup against cores\n{ctx}", fontsize=9)
    elif metric == "efficiency":
        ax.axhline(1.0, color="k", ls="--", lw=0.8, label="ideal: efficiency = 1", zorder=1)
        if fit is not None:
            ax.plot(pp, 1 / (fit * pp + (1 - fit)), color="0.5", ls=":", lw=1.0,
                    label=f"Amdahl fit, serial fraction f = {fit:.3f}")
        if len(ceiling):
            cx = [1.0] + [c["cores"] for c in ceiling]
            ax.plot(cx, [1.0] + [c["ceiling_free"] for c in ceiling], color="k", ls=":", lw=0.9, marker="^",
                    mfc="none", ms=6, zorder=2, label="machine ceiling: W copies sharing nothing (alone / together)")
            ax.plot(cx, [1.0] + [c["ceiling_step"] for c in ceiling], color="k", ls="-.", lw=0.9, marker="v",
                    ms=6, zorder=2, label="machine ceiling: W copies meeting every step (ceiling.csv)")
        top = max([1.0] + [v for v in d[metric] if np.isfinite(v)] + [c["ceiling_free"] for c in ceiling])
        ax.set_ylim(0, 1.15 * top)
        ax.set_ylabel("parallel efficiency = speedup / cores")
        ax.set_title(f"Parallel efficiency against cores\n{ctx}", fontsize=9)
    else:
        ax.axhline(0.0, color="k", ls="--", lw=0.8, label="e = 0 (ideal; < 0 is superlinear)", zorder=1)
        if fit is not None:
            ax.axhline(fit, color="0.5", ls=":", lw=1.0, label=f"Amdahl fit, serial fraction f = {fit:.3f}")
        vals = [v for v in d[metric] if np.isfinite(v)] + [0.0] + ([fit] if fit is not None else [])
        lo, hi = min(vals), max(vals)
        span = max(hi - lo, 0.05)
        ax.set_ylim(lo - 0.12 * span, hi + 0.18 * span)
        ax.set_ylabel("Karp-Flatt serial fraction e = (1/S - 1/p) / (1 - 1/p)\n(S = speedup, p = cores; "
                      "undefined at p = 1)")
        ax.set_title(f"Experimentally determined serial fraction (Karp-Flatt) against cores\n{ctx}", fontsize=9)
    if len(d) == 0:
        if len(done) == 0:
            msg = "no completed point"
        elif metric == "edsf" and not (done["cores"] > 1).any():
            msg = "no completed point with more than one core"
        else:
            msg = f"no completed point has a {metric} value\n(it needs the serial reference 1-1-1-1-1 done)"
        empty_axes(ax, msg)
    ax.grid(True, which="major", lw=0.4, alpha=0.5)
    ax.legend(fontsize=FONT, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    finish_figure(fig, figure_notes(d, skipped, 8.6))
    _place_labels(ax, labels)
    return fig


def modules_figure(directory):
    """The modules.png Figure of DIR/runs.csv, not saved (for inspection: its bar containers are
    labelled by column, see _modules_figure). The caller closes it."""
    df = read_runs(directory)
    return _modules_figure(done_rows(df), skipped_rows(df), sweep_context(df))


def _plot_modules(done, skipped, ctx, path):
    """modules.png: stacked module times per mapping (paper Figs. 19-21 in kind)."""
    return save_figure(_modules_figure(done, skipped, ctx), path)


def _modules_figure(done, skipped, ctx):
    """Stacked module times per mapping, grouped by core count (paper Figs. 19-21 in kind).
    Each point has one bar compuT + commuT + migraT; a point with a finite wireT has a second one
    beside it, compuT + syncT + wireT + above_wireT with above_wireT = commuT + migraT - syncT -
    wireT (the same overhead split into the allreduce, waiting for the slowest rank included, the
    wire, and the software above it; a point without syncT, older records, stacks compuT + wireT +
    above_wireT = commuT + migraT - wireT), so both bars sum to compuT + commuT + migraT = totalT.
    above_wireT is recomputed from the row's commuT, migraT, syncT and wireT by that rule (runs.csv's
    above_wireT for one repeat; with --repeats, the medians combined, so the bar sums to what the
    first one draws); above_wireT < 0, better than the one-after-another model or a
    syncT above the rest, is drawn as 0 and marked '<0'. Bar containers are labelled by the runs.csv
    column they draw: 'compuT', 'commuT', 'migraT' (first bars), 'split compuT', 'syncT' (only the
    points with a finite syncT; no container when none has), 'wireT', 'above_wireT' (second bars),
    in ms on the top axes and % of totalT below."""
    d = done[np.isfinite(done["cores"])].sort_values(["cores", "procs", "threads", "scheme", "neighbor"])
    n = len(d)
    wire = d["wireT"].to_numpy(dtype=float)
    sync_all = d["syncT"].to_numpy(dtype=float)
    has = np.isfinite(wire)
    hs = np.isfinite(sync_all[has])  # the split points with a syncT (not older records)
    ns = int(hs.sum())
    nw = int(has.sum())
    width = max(6.4, 0.62 * n + 0.3 * nw + 2.0)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(width, 6.4), sharex=True, gridspec_kw=dict(height_ratios=(3, 2)))
    split_scheme = len(set(d.loc[d["threads"] > 1, "scheme"])) > 1
    split_nb = len(set(d["neighbor"])) > 1
    x = np.arange(n)
    commu = np.nan_to_num(d["commuT"].to_numpy(), nan=0.0)
    migra = np.nan_to_num(d["migraT"].to_numpy(), nan=0.0)
    total = d["totalT"].to_numpy()
    compu = d["compuT"].to_numpy()
    compu = np.where(np.isfinite(compu), compu, total - commu - migra)
    vals = {"compuT": np.clip(compu, 0, None), "commuT": np.clip(commu, 0, None), "migraT": np.clip(migra, 0, None)}
    half = 0.36
    xs = np.where(has, x - half / 2 - 0.01, x)  # a point with a wire split: first bar left of centre
    ws = np.where(has, half, 0.7)
    pct = lambda v: np.where(total > 0, 100.0 * v / total, 0.0)  # noqa: E731
    bottom = np.zeros(n)
    bottom2 = np.zeros(n)
    for key, label, color in MODULES:
        v = vals[key]
        ax.bar(xs, 1e3 * v, ws, bottom=1e3 * bottom, color=color, label=key)
        ax2.bar(xs, pct(v), ws, bottom=bottom2, color=color, label=key)
        bottom += v
        bottom2 += pct(v)
    if nw:
        sync = np.where(hs, sync_all[has], 0.0)
        above = (commu + migra)[has] - sync - wire[has]
        split = {"compuT": vals["compuT"][has], "syncT": np.clip(sync, 0, None), "wireT": np.clip(wire[has], 0, None),
                 "above_wireT": np.clip(above, 0, None)}
        xw = x[has] + half / 2 + 0.01
        tot = np.where(np.isfinite(total[has]), total[has], 0.0)
        pw = lambda v: np.where(tot > 0, 100.0 * v / np.where(tot > 0, tot, 1.0), 0.0)  # noqa: E731
        bottom = np.zeros(nw)
        bottom2 = np.zeros(nw)
        for key, _, color, hatch in WIRE_SPLIT:
            v = split[key]
            on = hs if key == "syncT" else np.ones(nw, dtype=bool)  # syncT only where recorded (0 elsewhere)
            name = "split compuT" if key == "compuT" else key
            kw = dict(color=color, hatch=hatch, edgecolor="white" if hatch else None, lw=0.0)
            if on.any():
                ax.bar(xw[on], 1e3 * v[on], half, bottom=1e3 * bottom[on], label=name, **kw)
                ax2.bar(xw[on], pw(v)[on], half, bottom=bottom2[on], label=name, **kw)
            bottom += v
            bottom2 += pw(v)
        for xi, a, b in zip(xw, above, 1e3 * bottom):
            if a < 0:
                ax.text(xi, b, "<0", ha="center", va="bottom", fontsize=FONT - 1.5, color="C3")
    top = max([1e3 * t for t in total if np.isfinite(t)] + [1e-9])
    if nw:
        top = max(top, 1e3 * float(np.nanmax(split["compuT"] + split["syncT"] + split["wireT"])))
    for xi, t in zip(x, total):
        ax.text(xi, 1e3 * t + 0.01 * top, f"{1e3 * t:.3g}" if t < 1 else f"{1e3 * t:.0f}", ha="center", va="bottom", fontsize=FONT - 1)
    # communication + migration share printed on the lower panel (and the allreduce's and the wire's part of it)
    recorded = np.isfinite(d["commuT"].to_numpy()) | np.isfinite(d["migraT"].to_numpy())
    for xi, c, m, t, rec, w, sy in zip(x, commu, migra, total, recorded, wire, sync_all):
        if t > 0:
            text = f"{100 * (c + m) / t:.1f}%" if rec else "n/a"
            if np.isfinite(w) and np.isfinite(sy):
                text += f"\nsync {100 * sy / t:.1f}%"
            if np.isfinite(w):
                text += f"\nwire {100 * w / t:.1f}%"
            ax2.text(xi, 101, text, ha="center", va="bottom", fontsize=FONT - 1, color="C1")
    ax.set_ylim(0, 1.14 * top)
    ax2.set_ylim(0, 134 if ns else 124 if nw else 112)
    # core-count groups: separators and labels
    cores = d["cores"].to_numpy()
    starts = ([0] if n else []) + [i for i in range(1, n) if cores[i] != cores[i - 1]]
    for k, s in enumerate(starts):
        e = starts[k + 1] if k + 1 < len(starts) else n
        if s > 0:
            for a in (ax, ax2):
                a.axvline(s - 0.5, color="0.5", lw=0.8, ls="--")
        c = int(cores[s])
        ax.text((s + e - 1) / 2, 1.12 * top, f"{c} core{'s' if c != 1 else ''}", ha="center", va="top",
                fontsize=FONT + 1, fontweight="bold", color="0.3")
    ticks = []
    for _, r in d.iterrows():
        t = (r["mapping"] or r["point"]) + flag_suffix(r)
        extra = [s for s, on in ((r["scheme"], split_scheme and r["threads"] > 1), (r["neighbor"], split_nb))
                 if on and s]
        ticks.append(t + ("\n" + ", ".join(extra) if extra else ""))
    ax2.set_xticks(x)
    ax2.set_xticklabels(ticks, rotation=45 if n > 6 else 0, ha="right" if n > 6 else "center", fontsize=FONT)
    ax2.set_xlabel("mapping P-px-py-pz-T (ordered by cores, then processes)")
    ax.set_ylabel("time per step [ms]\n(totalT printed on top)")
    ax2.set_ylabel("share of totalT [%]\n(commuT + migraT" + (", syncT, wireT printed)" if ns else " and wireT printed)"
                                                             if nw else " printed)"))
    ax.set_title(f"Module times per mapping (paper Figs. 19-21 in kind)\n{ctx}", fontsize=9)
    handles = [Patch(color=c, label=lab) for _, lab, c in MODULES]
    if nw:
        handles.append(Patch(color="none", label="second bar of an MPI point: the same commuT + migraT split into"))
        labels = {"above_wireT": ABOVE_WIRE_OLD if not ns else
                  WIRE_SPLIT[-1][1] + ("\n(points without syncT: commuT + migraT - wireT)" if ns < nw else "")}
        handles += [Patch(facecolor=c, hatch=h, edgecolor="white" if h else None, label=labels.get(key, lab))
                    for key, lab, c, h in WIRE_SPLIT if key != "compuT" and (key != "syncT" or ns)]
    ax.legend(handles=handles, fontsize=FONT, loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0.0)
    if n == 0:
        ax.set_xlim(-0.5, 0.5)
        ax.set_ylim(0, 1)
        empty_axes(ax, "no completed point")
    else:
        ax.set_xlim(-0.6, n - 0.4)
    for a in (ax, ax2):
        a.grid(True, axis="y", lw=0.4, alpha=0.5)
    finish_figure(fig, figure_notes(d, skipped, width))
    return fig


def error_figure(directory):
    """The error_vs_time.png Figure of DIR/runs.csv, not saved (for inspection: per series one
    Line2D of its non-zero err_max and one, labelled "(err = 0)", of its zeros at the floor, x =
    totalT [ms]). The caller closes it."""
    df = read_runs(directory)
    return _error_figure(done_rows(df), skipped_rows(df), sweep_context(df))


def _plot_error(done, skipped, ctx, path):
    return save_figure(_error_figure(done, skipped, ctx), path)


def _error_figure(done, skipped, ctx):
    """err_max against totalT, log-log, zeros at a floor marked bit-identical."""
    fig, ax = plt.subplots(figsize=(8.6, 5.0))
    d = done[np.isfinite(done["totalT"]) & (done["totalT"] > 0)]
    noerr = [f"{_point_name(r)}" for _, r in d.iterrows() if not np.isfinite(r["err_max"])]
    d = d[np.isfinite(d["err_max"])]
    errs = np.concatenate([d["err_max"].to_numpy(), d["err_rms"].to_numpy()])
    pos = errs[np.isfinite(errs) & (errs > 0)]
    floor = 10.0 ** (math.floor(math.log10(pos.min())) - 1) if len(pos) else 1e-16
    series = _series(d)
    colors = _series_colors(series)
    labels = []
    any_zero = False
    for label, fam, rows in series:
        color, marker = colors[label], FAMILY_STYLE.get(fam, ("C7", "o"))[1]
        y = rows["err_max"].to_numpy()
        zero = y <= 0
        any_zero |= bool(zero.any())
        ms = 8 if marker == "*" else 6
        if (~zero).any():
            ax.plot(1e3 * rows["totalT"].to_numpy()[~zero], y[~zero], ls="none", marker=marker, ms=ms, color=color,
                    label=label, zorder=3)
        if zero.any():
            ax.plot(1e3 * rows["totalT"].to_numpy()[zero], np.full(zero.sum(), floor), ls="none", marker=marker, ms=ms,
                    mfc="white", mec=color, mew=1.3,
                    label=label + (" (err = 0)" if (~zero).any() else " (all err = 0)"),
                    zorder=3)
        rms = rows["err_rms"].to_numpy()
        ok = np.isfinite(rms)
        if ok.any():
            ax.plot(1e3 * rows["totalT"].to_numpy()[ok], np.where(rms[ok] > 0, rms[ok], floor), ls="none", marker=".",
                    ms=4, color=color, alpha=0.6, zorder=2)
        for (_, r), yy in zip(rows.iterrows(), np.where(zero, floor, y)):
            name = r["mapping"] or r["point"]
            if fam == "serial":
                name += " (reference)"
            labels.append((1e3 * r["totalT"], yy, name + flag_suffix(r), color))
    fl = flagged(d)
    if len(fl):
        ax.plot(1e3 * fl["totalT"].to_numpy(), np.where(fl["err_max"] > 0, fl["err_max"], floor), label=FLAG_LABEL,
                **FLAG_RING)
    ax.set_xscale("log")
    ax.set_yscale("log")
    if len(d):
        t = 1e3 * d["totalT"].to_numpy()
        ax.set_xlim(t.min() / 1.6, t.max() * 2.8)
        hi = max(pos.max() if len(pos) else floor * 100, floor * 100)
        ax.set_ylim(floor / 4, hi * 4)
    else:
        empty_axes(ax, "no completed point with an error recorded")
    if any_zero or len(d):
        ax.axhline(floor, color="0.4", ls="--", lw=0.8, zorder=1,
                   label=f"bit-identical (err = 0), drawn at floor {floor:.0e}")
    ax.plot([], [], ls="none", marker=".", color="0.4", label="err_rms (small dots)")
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_major_locator(LogLocator(base=10, numticks=12))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("totalT: wall time per step [ms] (mean over steps of the max over ranks)")
    ax.set_ylabel("err_max: final-position error vs serial\n[in mean particle radii]")
    ax.set_title(f"Final-position error against time per step\n{ctx}", fontsize=9)
    ax.grid(True, which="major", lw=0.4, alpha=0.5)
    ax.legend(fontsize=FONT, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    note = figure_notes(d, skipped, 8.6)
    if noerr:
        note += note_lines(noerr, 8.6, head="Done, no error recorded (not plotted): ")
    finish_figure(fig, note)
    _place_labels(ax, labels)
    return fig
