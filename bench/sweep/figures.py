"""Figures of a mapping sweep, drawn from DIR/runs.csv (plotting only reads records).

plot_sweep(DIR) writes, in DIR (a sweep of several particle counts, the granularity study: one
set a count, speedup-2000.png, ..., and bench.sweep.granularity's granularity.png):
- speedup.png: speedup T(1)/T(p) against cores p = procs x threads (log2-log2), one series per
  family (threads: 1 process; MPI: 1 thread; hybrid: both > 1; split by thread scheme and by
  neighbour method when those vary), every point labelled with its mapping P-px-py-pz-T, the
  ideal y = x and, when DIR/summary.json holds one, the Amdahl curve of the fitted serial fraction;
- efficiency.png: speedup / cores against cores, ideal line at 1;
- on both, each point's 95 % interval (runs.csv speedup_lo/hi, efficiency_lo/hi) as a vertical
  bar where the records have one;
- edsf.png: the Karp-Flatt experimentally determined serial fraction against cores (p > 1), a
  line at 0 and the Amdahl fit when present;
- modules.png: per mapping (x axis ordered by cores, then procs; grouped by core count) stacked
  bars of compuT, commuT, migraT in ms/step (top, with totalT's 95 % interval as whiskers where
  runs.csv has totalT_lo/hi) and as % of totalT (bottom), the paper's
  Figs. 19-21 in kind; where runs.csv has wireT (MPI points whose steps.csv has wire_s), a second
  bar beside it stacks compuT, syncT (the step's allreduce: waiting for the slowest rank + the
  collective's latency; only where runs.csv has it), wireT (the modelled wire time of the bytes
  sent, modes/wire.py) and above_wireT = commuT + migraT - syncT - wireT (the software above the
  wire in the exchanges; commuT + migraT - wireT without syncT); modules_figure(DIR) returns that
  Figure unsaved;
- error_vs_time.png: err_max (final-position error against the serial run over the mean
  particle radius) against totalT [ms/step], log-log; zero errors (bit-identical modes) are
  drawn hollow on a dashed floor line a decade below the smallest non-zero error.

Every figure is drawn for a journal's double-column width (WIDTH = 7 in, no text below 7 pt at
100 %) and written as PNG and, beside it, as vector PDF (speedup.pdf, ...; save_figure, both
atomically). The legend sits below the axes in as many columns as fit under the axes' width, the
foot note below it, and the figure grows in height to hold them (layout_figure); point labels are
placed where they touch no marker, no drawn line and no other text (_place_labels, with a leader
line when a label has to stand off); modules.png's mapping ticks stand upright when level ones
would touch, and each bar carries one short number (totalT in ms above the bars, commuT + migraT
in % above the shares).

Points with status != done are not plotted; they are listed in a note at the foot of each
figure (at most two lines, then "and N more"; all of them once on stdout by plot_sweep). Points
whose runs.csv `flag` is set (measured under foreign load, or with a wide spread:
bench.sweep.records) are ringed in red on every figure (speedup, efficiency, EDSF and error: a
Line2D labelled FLAG_LABEL, and their labels end in `[flag]`; modules.png: a small ring above the
point's bars), and the foot note says so in one line: the flagged points with their foreign load
and spreads when that fits on the line, else how many they are (the rest is in runs.csv). No
figure raises on a runs.csv with only the serial point, with every point failed, with NaN
columns or with a single core count.
"""
import math
import os
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.transforms import offset_copy  # noqa: E402
from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter, NullLocator  # noqa: E402

from bench.sweep.records import read_runs  # noqa: E402
from bench.sweep.ceiling import read_ceiling  # noqa: E402

FAMILY_STYLE = {"serial": ("k", "*"), "threads": ("C0", "o"), "MPI": ("C3", "s"), "hybrid": ("C2", "^")}
FAMILY_ORDER = ("serial", "threads", "MPI", "hybrid")
MODULES = (("compuT", "compuT: computation", "C0"), ("commuT", "commuT: communication", "C1"),
           ("migraT", "migraT: migration", "C2"))
# the overhead commuT + migraT split at the wire (issue 11): the second bar of an MPI point, syncT
# (the allreduce inside commuT) only where runs.csv has it
WIRE_SPLIT = (("compuT", "compuT: computation", "C0", None),
              ("syncT", "syncT: allreduce + waiting for the slowest rank", "C4", None),
              ("wireT", "wireT: modelled wire time of the bytes sent", "0.35", None),
              ("wire_internodeT", "wire_internodeT: the part of wireT sent to other nodes", "0.1", None),
              ("above_wireT", "above_wireT = commuT + migraT - syncT - wireT", "C3", "////"))
ABOVE_WIRE_OLD = "above_wireT = commuT + migraT - wireT"  # no syncT recorded
WIRE_WITHIN = "wireT within the node: modelled wire time of the bytes sent"  # its label beside wire_internodeT
# sizes for a journal's double-column width, read at 100 %: no text below FONT points
WIDTH = 7.0  # in
FONT = 7  # pt: legends, notes, point labels, numbers on bars
TICK = 7.5  # pt: tick labels
LABEL = 8  # pt: axis labels
TITLE = 8  # pt: the one-line title (what was run)
DPI = 200
NOTE_LINES = 2  # at most this many lines of "not plotted" points in a foot note, then "and N more"
FLAG_LABEL = "flagged: timing doubtful (runs.csv flag)"
FLAG_HEAD = "Flagged, timing doubtful (red ring; runs.csv flag)"
FLAG_RING = dict(ls="none", marker="o", ms=12, mfc="none", mec="red", mew=1.2, zorder=4)


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


def flag_note(d, width_in):
    """One line on the flagged points of d: each with its foreign load and spreads when they all fit
    on that line, else how many they are (the rest is in runs.csv)."""
    fl = flagged(d)
    if not len(fl):
        return []
    line = f"{FLAG_HEAD}: " + "; ".join(flag_notes(d))
    if len(line) <= _note_chars(width_in):
        return [line]
    many = f"{len(fl)} point{'s' if len(fl) != 1 else ''}"
    return [f"{FLAG_HEAD}: {many}; their foreign load and spreads are in runs.csv"]


def figure_notes(done, skipped, width):
    return note_lines(skipped, width) + flag_note(done, width)


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
def _note_chars(width_in):
    """Characters of FONT-point text on a line of width_in inches (DejaVu Sans: digits are 0.64 em)."""
    return max(40, int((width_in - 0.15) * 72 / (0.6 * FONT)))


def note_lines(lines, width_in, head="Not plotted (status != done): ", max_lines=NOTE_LINES):
    """head + the entries '; '-joined, wrapped to width_in inches in at most max_lines lines: the
    entries that fit, then 'and N more'."""
    if not lines:
        return []
    chars = _note_chars(width_in)
    for k in range(len(lines), 0, -1):
        more = len(lines) - k
        out = textwrap.wrap(head + "; ".join(lines[:k]) + (f"; and {more} more" if more else ""), chars)
        if len(out) <= max_lines:
            return out
    out = textwrap.wrap(head + lines[0], chars)[:max_lines]
    more = len(lines) - 1
    tail = "..." + (f" and {more} more" if more else "")
    out[-1] = out[-1][:chars - len(tail)] + tail
    return out


def finish_figure(fig, note):
    """tight layout leaving room for the foot note (lines of text), and write the note."""
    h_in = fig.get_size_inches()[1]
    bottom = (len(note) * FONT * 1.35 + 6) / (72 * h_in) if note else 0.0
    fig.tight_layout(rect=(0, min(bottom, 0.4), 1, 1))
    if note:
        fig.text(0.01, 0.006, "\n".join(note), fontsize=FONT, va="bottom", ha="left", color="0.25")
    return bottom


def _legend(ax, handles, ncol, title=None):
    """A frameless legend of FONT points in ncol columns, anchored in figure coordinates and left out
    of tight_layout (layout_figure places it below the axes)."""
    leg = ax.legend(handles=handles, fontsize=FONT, ncol=ncol, loc="upper center", bbox_to_anchor=(0.5, 0.0),
                    bbox_transform=ax.figure.transFigure, frameon=False, borderaxespad=0.0, borderpad=0.2,
                    handlelength=1.8, handletextpad=0.5, columnspacing=1.4, labelspacing=0.35,
                    title=title, title_fontsize=FONT, alignment="left" if title else "center")
    leg.set_in_layout(False)
    return leg


def layout_figure(fig, axes, handles=(), note=(), axes_h=3.2, legend_ax=None, legend_title=None):
    """Lay a figure out at WIDTH inches: its axes `axes_h` inches high (tight_layout of the axes,
    titles and labels), below them the legend of `handles` (on legend_ax, default axes[0]) in as
    many columns as fit under the axes' width (handles may be a function ncol -> handles, for an
    order that reads by rows), below it the foot note (lines of FONT points). The figure grows in
    height to hold legend and note, so none of them squeezes the axes. Returns the legend or None."""
    legend_ax = legend_ax or axes[0]
    dpi = fig.dpi
    gap, pad = 0.06, 0.04  # in
    note_t, note_h = None, 0.0
    if note:
        note_t = fig.text(0.01, 0.0, "\n".join(note), fontsize=FONT, va="bottom", ha="left", color="0.25")
        note_h = note_t.get_window_extent(fig.canvas.get_renderer()).height / dpi
    hs = handles if callable(handles) else (lambda ncol, h=tuple(handles): list(h))
    n = len(hs(1))
    leg, leg_h, ncol = None, 0.0, max(n, 1)

    def arrange(leg_h):
        below = pad + (note_h + gap if note else 0.0) + (leg_h + gap if n else 0.0)
        h = axes_h + below
        fig.set_size_inches(WIDTH, h)
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            fig.tight_layout(rect=(0, below / h, 1, 1), pad=0.3, h_pad=0.6)
        return h

    h = arrange(0.3 * n ** 0.5 if n else 0.0)
    for _ in range(3):
        if not n:
            break
        renderer = fig.canvas.get_renderer()
        width = min(a.get_window_extent(renderer).width for a in axes)
        k = ncol
        while True:
            rows = math.ceil(n / k)
            k = math.ceil(n / rows)  # balanced columns
            leg = _legend(legend_ax, hs(k), k, legend_title)
            if leg.get_window_extent(renderer).width <= width or k == 1:
                break
            k -= 1
        new_h = leg.get_window_extent(renderer).height / dpi
        if k == ncol and abs(new_h - leg_h) < 1e-3:
            break
        ncol, leg_h = k, new_h
        h = arrange(leg_h)
    fig._bench_layout = lambda: place(arrange(leg_h))

    def place(h):
        if leg is not None:
            renderer = fig.canvas.get_renderer()
            boxes = [a.get_window_extent(renderer) for a in axes]
            cx = (min(b.x0 for b in boxes) + max(b.x1 for b in boxes)) / 2 / (WIDTH * dpi)
            leg.set_bbox_to_anchor((cx, (pad + (note_h + gap if note else 0.0) + leg_h) / h), fig.transFigure)
        if note_t is not None:
            note_t.set_position((0.01, pad / h))
    place(h)
    return leg


def relayout(fig):
    """Lay the figure out again as its layout_figure did (after a change of limits or ticks)."""
    fig._bench_layout()


def save_figure(fig, path):
    """Write the figure atomically as PNG at path and as PDF (vector, fonts embedded as TrueType)
    beside it, path with .pdf for .png (a full disk leaves the old files and raises RecordError)."""
    from bench.run.records import atomic_write
    try:
        # the legends stand out of tight_layout (layout_figure): named here, or a figure without a
        # foot note below them would be cropped above its legend; the figure's own texts (the foot
        # note) named too, as extra artists replace the default ones that held them
        legends = [a.get_legend() for a in fig.axes if a.get_legend() is not None] + list(fig.legends)
        kw = dict(bbox_inches="tight", pad_inches=0.03, bbox_extra_artists=legends + list(fig.texts))
        atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=DPI, **kw), mode="wb")
        with matplotlib.rc_context({"pdf.fonttype": 42}):
            atomic_write(os.path.splitext(path)[0] + ".pdf", lambda fh: fig.savefig(fh, format="pdf", **kw),
                         mode="wb")
    finally:
        plt.close(fig)
    return path


def _line_points(line, step=2.0):
    """Display points along a drawn line (segments resampled every `step` pixels), NaN gaps kept."""
    xy = line.get_transform().transform(np.asarray(line.get_xydata(), dtype=float))
    out = []
    for (x0, y0), (x1, y1) in zip(xy[:-1], xy[1:]):
        if not (np.isfinite(x0) and np.isfinite(y0) and np.isfinite(x1) and np.isfinite(y1)):
            continue
        k = int(min(2000, max(1, math.hypot(x1 - x0, y1 - y0) / step)))
        t = np.linspace(0.0, 1.0, k + 1)
        out.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _place_labels(ax, pts, fontsize=FONT):
    """Annotate points (x, y, text, color) with labels placed in display space, the first free of
    several spots around the point (right, left, above, below, the diagonals, then right and left
    nudged up and down) where a label touches no marker, no drawn line (ideal, fit, ceiling and
    series lines), no other text and stays inside the axes; where no spot is free, the one that
    hides least. Call once limits and the layout are final."""
    pts = [p for p in pts if np.isfinite(p[0]) and np.isfinite(p[1])]
    if not pts:
        return
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    px = fig.dpi / 72.0  # pixels per point
    abox = ax.get_window_extent(renderer)
    marks, lines = [], []
    for ln in ax.get_lines():
        if not ln.get_visible():
            continue
        if ln.get_marker() not in (None, "None", "none", "", " ") and ln.get_markersize() > 0:
            r = ln.get_markersize() * px / 2 + 0.5 * px
            for X, Y in ln.get_transform().transform(np.asarray(ln.get_xydata(), dtype=float)):
                if np.isfinite(X) and np.isfinite(Y):
                    marks.append((X - r, Y - r, X + r, Y + r))
        if ln.get_linestyle() not in ("None", "none", "", " "):
            lines.append(_line_points(ln))
    line_xy = np.concatenate(lines) if lines else np.zeros((0, 2))
    inside = ((line_xy[:, 0] >= abox.x0) & (line_xy[:, 0] <= abox.x1) & (line_xy[:, 1] >= abox.y0)
              & (line_xy[:, 1] <= abox.y1)) if len(line_xy) else np.zeros(0, bool)
    line_xy = line_xy[inside]
    texts = []
    for t in ax.texts:
        if t.get_visible() and t.get_text():
            b = t.get_window_extent(renderer)
            texts.append((b.x0, b.y0, b.x1, b.y1))
    m = 1.2 * px  # clearance

    def hits(boxes, pts_xy):
        if not len(pts_xy) or not boxes:
            return 0
        bx = np.asarray(boxes)[None, :, :]
        px_, py_ = pts_xy[:, None, 0], pts_xy[:, None, 1]
        return int(np.count_nonzero((px_ > bx[..., 0] - m) & (px_ < bx[..., 2] + m)
                                    & (py_ > bx[..., 1] - m) & (py_ < bx[..., 3] + m)))

    def cost(b, leader, texts, line_xy, leaders):
        x0, y0, x1, y1 = b
        c = 0.0
        if x0 < abox.x0 + m or x1 > abox.x1 - m or y0 < abox.y0 + m or y1 > abox.y1 - m:
            c += 1e5
        for o in texts:
            if x0 < o[2] + m and x1 > o[0] - m and y0 < o[3] + m and y1 > o[1] - m:
                c += 1e4
        for o in marks:
            if x0 < o[2] + m and x1 > o[0] - m and y0 < o[3] + m and y1 > o[1] - m:
                c += 1e2
        if len(line_xy):
            c += float(np.count_nonzero((line_xy[:, 0] > x0 - m) & (line_xy[:, 0] < x1 + m)
                                        & (line_xy[:, 1] > y0 - m) & (line_xy[:, 1] < y1 + m)))
        if leader is not None:
            c += 1e3 * min(1, hits(texts, leader)) + 10 * min(3, hits(marks, leader))
            (p0, p1) = leader[0], leader[-1]
            c += 500 * sum(_crosses(p0, p1, q0, q1) for q0, q1 in leaders)
        return c

    probe = ax.text(0, 0, "", fontsize=fontsize)
    disp = []
    for x, y, text, color in pts:
        X, Y = ax.transData.transform((x, y))
        probe.set_text(text)
        bb = probe.get_window_extent(renderer)
        disp.append((X, Y, x, y, text, color, bb.width, bb.height))
    probe.remove()
    r = 8.0 * px  # clears the marker and a red ring around it (ms 12: radius 6 + edge)

    def spots_of(X, Y, w, h):
        d = r * 0.75
        spots = [(X + r, Y - h / 2), (X - r - w, Y - h / 2), (X - w / 2, Y + r), (X - w / 2, Y - r - h),
                 (X + d, Y + d), (X + d, Y - d - h), (X - d - w, Y + d), (X - d - w, Y - d - h)]
        for k in range(1, 25):
            dy = r * 0.5 + k * h * 0.5
            dx = r + 4 * px if k > 2 else r
            for sgn in (1, -1):
                spots += [(X + dx, Y - h / 2 + sgn * dy), (X - dx - w, Y - h / 2 + sgn * dy)]
            if k <= 8:
                spots += [(X - w / 2, Y + r + k * h * 0.5), (X - w / 2, Y - r - h - k * h * 0.5)]
        for k in range(1, 6):  # further aside, level with the point and a little above and below
            for dy in (0.0, h, -h):
                spots += [(X + r + k * h, Y - h / 2 + dy), (X - r - w - k * h, Y - h / 2 + dy)]
        return spots

    def run(order):
        """Greedy placement in this order: (total cost, [(index, box, leader)])."""
        placed_texts, lxy, leaders, out, total = list(texts), line_xy, [], [], 0.0
        for i in order:
            X, Y, *_, w, h = disp[i]
            best = None
            for x0, y0 in spots_of(X, Y, w, h):
                b = (x0, y0, x0 + w, y0 + h)
                leader = _leader(X, Y, b, r)
                c = cost(b, leader, placed_texts, lxy, leaders) + (0.5 if leader is not None else 0.0)
                if best is None or c < best[0]:
                    best = (c, b, leader)
                if c <= 0.5:
                    break
            c, b, leader = best
            total += c
            placed_texts.append(b)
            if leader is not None:
                lxy = np.concatenate([lxy, leader])
                leaders.append((leader[0], leader[-1]))
            out.append((i, b, leader))
        return total, out

    idx = range(len(disp))
    crowd = [sum(math.hypot(disp[i][0] - disp[j][0], disp[i][1] - disp[j][1]) < 40 * px for j in idx) for i in idx]
    orders = [sorted(idx, key=lambda i: (round(disp[i][0], 1), -disp[i][1])),
              sorted(idx, key=lambda i: (-crowd[i], round(disp[i][0], 1), -disp[i][1])),
              sorted(idx, key=lambda i: (-round(disp[i][0], 1), disp[i][1]))]
    best = None
    for order in orders:
        total, out = run(order)
        if best is None or total < best[0]:
            best = (total, out)
        if total < 1:
            break
    for i, b, leader in best[1]:
        X, Y, x, y, text, color, w, h = disp[i]
        ax.annotate(text, (x, y), xytext=((b[0] - X) / px, (b[1] - Y) / px), textcoords="offset points",
                    fontsize=fontsize, ha="left", va="bottom", color=color, annotation_clip=False, zorder=5)
        if leader is not None:
            (lx0, ly0), (lx1, ly1) = ax.transData.inverted().transform(leader[[0, -1]])
            ax.plot([lx0, lx1], [ly0, ly1], color=color, lw=0.5, alpha=0.7, zorder=2, label="_leader")


def _crosses(p0, p1, q0, q1):
    """Whether segments p0-p1 and q0-q1 cross."""
    def side(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return (side(p0, p1, q0) * side(p0, p1, q1) < 0) and (side(q0, q1, p0) * side(q0, q1, p1) < 0)


def _leader(X, Y, b, r):
    """Points along a leader line from a marker (X, Y) (from its edge, radius r) to the nearest point
    of label box b, or None when the label sits next to the marker."""
    cx, cy = min(max(X, b[0]), b[2]), min(max(Y, b[1]), b[3])
    dist = math.hypot(cx - X, cy - Y)
    if dist <= 1.6 * r:
        return None
    t = np.linspace(r / dist, 1.0, max(2, int(dist / 2)))
    return np.column_stack([X + t * (cx - X), Y + t * (cy - Y)])


def _log2_cores_axis(ax, cores, label_room=1.6):
    cores = sorted({int(c) for c in cores if np.isfinite(c) and c > 0}) or [1]
    ax.set_xscale("log", base=2)
    ax.set_xlim(min(cores) / 1.4, max(cores) * label_room)
    ax.xaxis.set_major_locator(FixedLocator(cores))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xticklabels([str(c) for c in cores])
    ax.set_xlabel("cores p = processes \u00d7 threads", fontsize=LABEL)
    return cores


def _style(ax):
    ax.tick_params(labelsize=TICK, length=3, width=0.6)
    for s in ax.spines.values():
        s.set_linewidth(0.7)


def empty_axes(ax, text):
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=LABEL, color="0.35")


# --- plot_sweep -----------------------------------------------------------------------------------------
def plot_sweep(directory):
    """Read DIR/runs.csv and write speedup.png, efficiency.png, edsf.png, modules.png and
    error_vs_time.png in DIR; return their paths. Points not done are listed in a foot note
    of each figure and on stdout."""
    df = read_runs(directory)
    skipped = skipped_rows(df)
    if skipped:
        print(f"sweep plots: not plotted (status != done): {'; '.join(skipped)}")
    counts = particle_counts(df)
    if len(counts) < 2:
        return _figure_set(df, directory, "", _amdahl(directory), read_ceiling(directory))
    # the granularity study (several N): one set a particle count, speedup-2000.png, ...; the
    # Amdahl fit of summary.json pools the sizes, so none is drawn
    paths = []
    for n in counts:
        paths += _figure_set(df[df["particles"] == n], directory, f"-{n}", None, ())
    return paths


def _figure_set(df, directory, suffix, fit, ceiling):
    done = done_rows(df)
    skipped = skipped_rows(df)
    ctx = sweep_context(df)
    path = lambda name: os.path.join(directory, f"{name}{suffix}.png")  # noqa: E731
    return [
        _plot_metric(done, skipped, ctx, fit, "speedup", path("speedup")),
        _plot_metric(done, skipped, ctx, fit, "efficiency", path("efficiency"), ceiling),
        _plot_metric(done, skipped, ctx, fit, "edsf", path("edsf")),
        _plot_modules(done, skipped, ctx, path("modules")),
        _plot_error(done, skipped, ctx, path("error_vs_time")),
    ]


def metric_figure(directory, metric):
    """The speedup.png, efficiency.png or edsf.png Figure (metric = its runs.csv column) of
    DIR/runs.csv, not saved (for inspection: one Line2D of markers per series, labelled as in the
    legend, x = cores, y = the metric). The caller closes it."""
    df = read_runs(directory)
    return _metric_figure(done_rows(df), skipped_rows(df), sweep_context(df), _amdahl(directory), metric,
                          read_ceiling(directory) if metric == "efficiency" else ())


def _plot_metric(done, skipped, ctx, fit, metric, path, ceiling=()):
    return save_figure(_metric_figure(done, skipped, ctx, fit, metric, ceiling), path)


def particle_counts(df):
    """The distinct particle counts of a runs.csv frame, ascending (several: the granularity study)."""
    return sorted({int(n) for n in df["particles"] if np.isfinite(n)})


def interval_bars(ax, rows, x, metric, color):
    """The 95 % intervals of runs.csv (metric_lo, metric_hi: bench.sweep.intervals) as vertical bars
    at rows[x] through the points that have them (older records have none)."""
    lo, hi = f"{metric}_lo", f"{metric}_hi"
    if lo not in rows or hi not in rows:
        return
    r = rows[np.isfinite(rows[lo]) & np.isfinite(rows[hi]) & (rows[lo] > 0)]
    if len(r):  # not part of the axes' data limits: an interval of two discordant repeats can span decades
        from matplotlib.collections import LineCollection
        segs = [[(v, a), (v, b)] for v, a, b in zip(r[x], r[lo], r[hi])]
        ax.add_collection(LineCollection(segs, colors=color, linewidths=1.1, alpha=0.7, zorder=2.5), autolim=False)


def _metric_figure(done, skipped, ctx, fit, metric, ceiling=()):
    """speedup / efficiency / edsf against cores, one series per family (and scheme); on the
    efficiency figure also the machine's ceiling of DIR/ceiling.csv where a sweep measured it
    (bench.sweep.ceiling: W independent copies, alone over together and over meeting every step)."""
    fig, ax = plt.subplots(figsize=(WIDTH, 4.0))
    _style(ax)
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
        ax.plot(rows["cores"], rows[metric], ls="none", marker=marker, ms=8 if marker == "*" else 5.5,
                color=color, label=label, zorder=3)
        interval_bars(ax, rows, "cores", metric, color)
        # a thin line through the best point per core count, from the serial reference
        best = rows.sort_values("totalT").groupby("cores", sort=True)[metric].first()
        xs, ys = list(best.index), list(best.values)
        if fam != "serial" and s_ref[1] is not None and (not xs or xs[0] > 1):
            xs, ys = [1.0] + xs, [s_ref[1]] + ys
        if len(xs) > 1:
            ax.plot(xs, ys, color=color, lw=0.9, alpha=0.55, zorder=2)
        for _, r in rows.iterrows():
            labels.append((r["cores"], r[metric], (r["mapping"] or r["point"]) + flag_suffix(r), color))
    fl = flagged(d)
    if len(fl):
        ax.plot(fl["cores"], fl[metric], label=FLAG_LABEL, **FLAG_RING)
    cores = _log2_cores_axis(ax, list(d["cores"]) + ([] if metric == "edsf" and len(d) else [1]))
    _label_room(ax, [lab for lab in labels if lab[0] == max(cores)])
    xlo, xhi = ax.get_xlim()
    pp = np.geomspace(max(xlo, 1.0), xhi, 100)
    if metric == "speedup":
        ax.set_yscale("log", base=2)
        ax.plot([xlo, xhi], [xlo, xhi], "k--", lw=0.8, label="ideal (S = p)", zorder=1)
        if fit is not None:
            ax.plot(pp, 1 / (fit + (1 - fit) / pp), color="0.5", ls=":", lw=1.0,
                    label=f"Amdahl fit (serial fraction f = {fit:.3f})")
        vals = [v for v in d[metric] if v > 0] + [1.0, max(cores)]
        lo, hi = min(vals) / 1.5, max(vals) * 1.5
        ax.set_ylim(lo, hi)
        ticks = [2.0 ** k for k in range(int(math.floor(math.log2(lo))), int(math.ceil(math.log2(hi))) + 1)]
        ax.yaxis.set_major_locator(FixedLocator(ticks))
        ax.yaxis.set_minor_locator(NullLocator())
        ax.set_yticklabels([f"{t:g}" for t in ticks])
        ax.set_ylabel("speedup S = T(1) / T(p)", fontsize=LABEL)
        ax.set_title(f"Speedup: {ctx}", fontsize=TITLE)
    elif metric == "efficiency":
        ax.axhline(1.0, color="k", ls="--", lw=0.8, label="ideal (E = 1)", zorder=1)
        if fit is not None:
            ax.plot(pp, 1 / (fit * pp + (1 - fit)), color="0.5", ls=":", lw=1.0,
                    label=f"Amdahl fit (serial fraction f = {fit:.3f})")
        if len(ceiling):
            cx = [1.0] + [c["cores"] for c in ceiling]
            ax.plot(cx, [1.0] + [c["ceiling_free"] for c in ceiling], color="k", ls=":", lw=0.9, marker="^",
                    mfc="none", ms=5, zorder=2, label="machine ceiling: copies sharing nothing")
            ax.plot(cx, [1.0] + [c["ceiling_step"] for c in ceiling], color="k", ls="-.", lw=0.9, marker="v",
                    ms=5, zorder=2, label="machine ceiling: copies meeting every step")
        top = max([1.0] + [v for v in d[metric] if np.isfinite(v)] + [c["ceiling_free"] for c in ceiling])
        ax.set_ylim(0, 1.18 * top)
        ax.set_ylabel("efficiency E = S / p", fontsize=LABEL)
        ax.set_title(f"Parallel efficiency: {ctx}", fontsize=TITLE)
    else:
        ax.axhline(0.0, color="k", ls="--", lw=0.8, label="e = 0 (ideal; < 0 superlinear)", zorder=1)
        if fit is not None:
            ax.axhline(fit, color="0.5", ls=":", lw=1.0, label=f"Amdahl fit (serial fraction f = {fit:.3f})")
        vals = [v for v in d[metric] if np.isfinite(v)] + [0.0] + ([fit] if fit is not None else [])
        lo, hi = min(vals), max(vals)
        span = max(hi - lo, 0.05)
        ax.set_ylim(lo - 0.15 * span, hi + 0.2 * span)
        ax.set_ylabel("serial fraction e (Karp-Flatt)", fontsize=LABEL)
        ax.set_title(f"Karp-Flatt serial fraction e = (1/S - 1/p) / (1 - 1/p): {ctx}", fontsize=TITLE)
    if len(d) == 0:
        if len(done) == 0:
            msg = "no completed point"
        elif metric == "edsf" and not (done["cores"] > 1).any():
            msg = "no completed point with more than one core"
        else:
            msg = f"no completed point has a {metric} value\n(it needs the serial reference 1-1-1-1-1 done)"
        empty_axes(ax, msg)
    ax.grid(True, which="major", lw=0.4, alpha=0.5)
    layout_figure(fig, [ax], _legend_handles(ax), figure_notes(d, skipped, WIDTH))
    _place_labels(ax, labels)
    return fig


def _label_room(ax, last, fontsize=FONT):
    """Widen the log2 cores axis to the right so that the labels of the points at the largest core
    count fit beside them (at most a third of the axes, taken WIDTH - 1 in wide: call before the
    layout and the lines that span the axes)."""
    if not last:
        return
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    t = ax.text(0, 0, "", fontsize=fontsize)
    need = 0.0
    for *_, text, _c in last:
        t.set_text(text)
        need = max(need, t.get_window_extent(renderer).width)
    t.remove()
    need += 10 * fig.dpi / 72.0
    lo, hi = ax.get_xlim()
    cmax = max(x for x, *_ in last)
    width = (WIDTH - 1.0) * fig.dpi
    # pixels per octave with hi' = cmax * 2**e: width / (log2(cmax / lo) + e); room = e * that
    span = math.log2(cmax / lo)
    e = min(need * span / max(1.0, width - need), span / 2)
    if cmax * 2.0 ** e > hi:
        ax.set_xlim(lo, cmax * 2.0 ** e)


def _legend_handles(ax):
    """The axes' labelled artists but the red rings (the foot note names them)."""
    hs, ls = ax.get_legend_handles_labels()
    return [h for h, lab in zip(hs, ls) if lab != FLAG_LABEL]


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
    points with a finite syncT; no container when none has), 'wireT' (within the node when
    runs.csv has wire_internodeT), 'wire_internodeT' (only the points that sent to other nodes:
    issue 37), 'above_wireT' (second bars),
    in ms on the top axes and % of totalT below."""
    d = done[np.isfinite(done["cores"])].sort_values(["cores", "procs", "threads", "scheme", "neighbor"])
    n = len(d)
    wire = d["wireT"].to_numpy(dtype=float)
    sync_all = d["syncT"].to_numpy(dtype=float)
    has = np.isfinite(wire)
    hs = np.isfinite(sync_all[has])  # the split points with a syncT (not older records)
    ns = int(hs.sum())
    nw = int(has.sum())
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(WIDTH, 4.4), sharex=True, gridspec_kw=dict(height_ratios=(3, 2)))
    for a in (ax, ax2):
        _style(a)
    split_scheme = len(set(d.loc[d["threads"] > 1, "scheme"])) > 1
    split_nb = len(set(d["neighbor"])) > 1
    x = np.arange(n)
    commu = np.nan_to_num(d["commuT"].to_numpy(), nan=0.0)
    migra = np.nan_to_num(d["migraT"].to_numpy(), nan=0.0)
    total = d["totalT"].to_numpy()
    compu = d["compuT"].to_numpy()
    compu = np.where(np.isfinite(compu), compu, total - commu - migra)
    vals = {"compuT": np.clip(compu, 0, None), "commuT": np.clip(commu, 0, None), "migraT": np.clip(migra, 0, None)}
    # bars at most 0.45 in wide (a pair 0.6 in), however few the mappings (the axes about WIDTH - 0.8 in)
    unit = (WIDTH - 0.8) / max(n, 1)  # inches per mapping
    half = min(0.38, 0.3 / unit)
    xs = np.where(has, x - half / 2 - 0.01, x)  # a point with a wire split: first bar left of centre
    ws = np.where(has, half, min(0.66, 0.45 / unit))
    pct = lambda v: np.where(total > 0, 100.0 * v / total, 0.0)  # noqa: E731
    bottom = np.zeros(n)
    bottom2 = np.zeros(n)
    for key, label, color in MODULES:
        v = vals[key]
        ax.bar(xs, 1e3 * v, ws, bottom=1e3 * bottom, color=color, label=key, lw=0)
        ax2.bar(xs, pct(v), ws, bottom=bottom2, color=color, label=key, lw=0)
        bottom += v
        bottom2 += pct(v)
    tops = 1e3 * np.where(np.isfinite(total), total, 0.0)  # where the numbers above a point start
    if "totalT_lo" in d and "totalT_hi" in d:  # the 95 % interval of totalT through the first bar's top
        lo, hi = d["totalT_lo"].to_numpy(dtype=float), d["totalT_hi"].to_numpy(dtype=float)
        ok = np.isfinite(lo) & np.isfinite(hi) & (hi > 0)
        if ok.any():
            from matplotlib.collections import LineCollection
            cap = 0.25 * ws
            segs = [seg for xi, c, a, b in zip(xs[ok], cap[ok], 1e3 * np.clip(lo[ok], 0, None), 1e3 * hi[ok])
                    for seg in ([(xi, a), (xi, b)], [(xi - c, a), (xi + c, a)], [(xi - c, b), (xi + c, b)])]
            ax.add_collection(LineCollection(segs, colors="k", linewidths=0.8, zorder=3,
                                             label="totalT: 95 % interval"))
            tops[ok] = np.maximum(tops[ok], 1e3 * hi[ok])
    lt0 = np.zeros(n, dtype=bool)
    if nw:
        sync = np.where(hs, sync_all[has], 0.0)
        above = (commu + migra)[has] - sync - wire[has]
        inter = np.nan_to_num(d["wire_internodeT"].to_numpy(dtype=float)[has], nan=0.0) \
            if "wire_internodeT" in d else np.zeros(nw)
        split = {"compuT": vals["compuT"][has], "syncT": np.clip(sync, 0, None),
                 "wireT": np.clip(wire[has] - inter, 0, None), "wire_internodeT": np.clip(inter, 0, None),
                 "above_wireT": np.clip(above, 0, None)}
        xw = x[has] + half / 2 + 0.01
        tot = np.where(np.isfinite(total[has]), total[has], 0.0)
        pw = lambda v: np.where(tot > 0, 100.0 * v / np.where(tot > 0, tot, 1.0), 0.0)  # noqa: E731
        bottom = np.zeros(nw)
        bottom2 = np.zeros(nw)
        for key, _, color, hatch in WIRE_SPLIT:
            v = split[key]
            # syncT only where recorded (0 elsewhere); the wire across nodes only where some was sent
            on = hs if key == "syncT" else inter > 0 if key == "wire_internodeT" else np.ones(nw, dtype=bool)
            name = "split compuT" if key == "compuT" else key
            kw = dict(color=color, hatch=hatch, edgecolor="white" if hatch else None, lw=0.0)
            if on.any():
                ax.bar(xw[on], 1e3 * v[on], half, bottom=1e3 * bottom[on], label=name, **kw)
                ax2.bar(xw[on], pw(v)[on], half, bottom=bottom2[on], label=name, **kw)
            bottom += v
            bottom2 += pw(v)
        tops[has] = np.maximum(tops[has], 1e3 * bottom)
        lt0[has] = above < 0
    top = max(list(tops) + [1e-9])
    flag = np.array([bool(str(f).strip()) for f in d["flag"]]) if "flag" in d else np.zeros(n, dtype=bool)
    # core-count groups: separators, and their core counts on a top axis
    cores = d["cores"].to_numpy()
    starts = ([0] if n else []) + [i for i in range(1, n) if cores[i] != cores[i - 1]]
    groups = [(s, starts[k + 1] if k + 1 < len(starts) else n) for k, s in enumerate(starts)]
    for s, _ in groups[1:]:
        for a in (ax, ax2):
            a.axvline(s - 0.5, color="0.55", lw=0.7, ls="--", zorder=0)
    ticks = []
    for _, r in d.iterrows():
        extra = [s for s, on in ((r["scheme"], split_scheme and r["threads"] > 1), (r["neighbor"], split_nb))
                 if on and s]
        ticks.append((r["mapping"] or r["point"]) + ("\n" + ", ".join(extra) if extra else ""))
    ax2.set_xticks(x)
    ax2.set_xticklabels(ticks, fontsize=TICK)
    ax2.set_xlabel("mapping P-px-py-pz-T", fontsize=LABEL)
    ax.set_ylabel("time per step [ms]", fontsize=LABEL)
    ax2.set_ylabel("share of totalT [%]", fontsize=LABEL)
    ax.set_title(f"Module times per mapping: {ctx}", fontsize=TITLE)
    top_axis = ax.secondary_xaxis("top")
    top_axis.tick_params(length=0, labelsize=TICK, labelcolor="0.3", pad=2)
    if n == 0:
        ax.set_xlim(-0.5, 0.5)
        ax.set_ylim(0, 1)
        ax2.set_ylim(0, 100)
        top_axis.set_xticks([])
        empty_axes(ax, "no completed point")
    else:
        ax.set_xlim(-0.6, n - 0.4)
        ax.set_ylim(0, 1.25 * top)
        ax2.set_ylim(0, 115)
    for a in (ax, ax2):
        a.grid(True, axis="y", lw=0.4, alpha=0.5)
        a.set_axisbelow(True)

    def handles(ncol):
        first = [Patch(color=c, label=lab) for _, lab, c in MODULES]
        if not nw:
            return first
        above = ABOVE_WIRE_OLD if not ns else WIRE_SPLIT[-1][1] + (
            "\n(without syncT: commuT + migraT - wireT)" if ns < nw else "")
        internode = nw and "wire_internodeT" in d and bool((d["wire_internodeT"].fillna(0) > 0).any())
        labels = {"above_wireT": above, "wireT": WIRE_WITHIN if internode else WIRE_SPLIT[2][1]}
        second = [Patch(facecolor=c, hatch=h, edgecolor="white" if h else None, lw=0, label=labels.get(key, lab))
                  for key, lab, c, h in WIRE_SPLIT
                  if key != "compuT" and (key != "syncT" or ns) and (key != "wire_internodeT" or internode)]
        if ncol != len(first):
            return first + second  # (by columns: the first bar's modules, then the second bar's)
        # read by rows: the first bar's modules on the first row, the second bar's on the second
        return [h for j in range(ncol) for h in (first[j:j + 1] + second[j:j + 1])]
    interval = ax.findobj(lambda a: getattr(a, "get_label", lambda: "")() == "totalT: 95 % interval")
    title = ("left bar: totalT split into modules (totalT [ms] above it, commuT + migraT [%] below); right bar "
             "of an MPI point:\nthe same commuT + migraT split at the wire" if nw else
             "totalT [ms] above each bar; commuT + migraT [% of totalT] above each share")
    if interval:
        title += "; whiskers: totalT's 95 % interval"
    renderer = fig.canvas.get_renderer()
    px = fig.dpi / 72.0
    # the x ticks: level while they fit between their neighbours (the axes about WIDTH - 0.8 in
    # wide), else upright
    if n and max(t.get_window_extent(renderer).width / px for t in ax2.get_xticklabels()) + 4 > \
            (WIDTH - 0.8) * 72 / n:
        ax2.set_xticklabels(ticks, fontsize=TICK, rotation=90, ha="center", va="top")
    layout_figure(fig, [ax, ax2], handles, figure_notes(d, skipped, WIDTH), axes_h=4.2, legend_title=title)
    if n == 0:
        return fig
    renderer = fig.canvas.get_renderer()
    step = ax.get_window_extent(renderer).width / n / px  # points between two mappings
    top_axis.set_xticks([(s + e - 1) / 2 for s, e in groups])
    names = []
    probe = ax.text(0, 0, "", fontsize=TICK)
    for s, e in groups:
        c = int(cores[s])
        probe.set_text(f"{c} core{'s' if c != 1 else ''}")
        fits = probe.get_window_extent(renderer).width / px + 4 <= (e - s) * step
        names.append(probe.get_text() if fits else str(c))
    probe.remove()
    top_axis.set_xticklabels(names)
    # numbers on the bars, one short line each; upright where they would touch their neighbours
    t_txt = [f"{v:.3g}" if v < 100 else f"{v:.0f}" for v in 1e3 * total]
    recorded = np.isfinite(d["commuT"].to_numpy()) | np.isfinite(d["migraT"].to_numpy())
    p_txt = [(f"{v:.1f}%" if v < 9.95 else f"{v:.0f}%") if rec else "n/a"
             for v, rec in zip(100 * (commu + migra) / np.where(total > 0, total, np.nan), recorded)]
    char = 0.62 * FONT
    t_up = max(len(s) for s in t_txt) * char + 2 > step
    p_up = max(len(s) for s in p_txt) * char + 2 > step
    line = FONT * 1.25
    heads = []
    for i in range(n):
        off = 1.0
        if lt0[i]:
            ax.annotate("<0", (xw[np.flatnonzero(has).tolist().index(i)], tops[i]), xytext=(0, off),
                        textcoords="offset points", ha="center", va="bottom", fontsize=FONT, color="C3")
            off += line
        if flag[i]:
            ax.plot([x[i]], [tops[i]], transform=offset_copy(ax.transData, fig, y=off + 4, units="points"),
                    label="_flag", **dict(FLAG_RING, ms=6, mew=1.0))
            off += 9
        ax.annotate(t_txt[i], (x[i], tops[i]), xytext=(0, off), textcoords="offset points", ha="center",
                    va="bottom", fontsize=FONT, rotation=90 if t_up else 0)
        heads.append(off + (len(t_txt[i]) * char if t_up else line) + 2)
        if total[i] > 0:
            ax2.annotate(p_txt[i], (x[i], 100.0), xytext=(0, 1.0), textcoords="offset points", ha="center",
                         va="bottom", fontsize=FONT, color="C1" if recorded[i] else "0.4",
                         rotation=90 if p_up else 0)
    # room above the bars for their numbers
    h_pt = ax.get_window_extent(renderer).height / px
    need = max(t / max(1e-9, 1 - hd / h_pt) for t, hd in zip(tops, heads))
    ax.set_ylim(0, max(need, 1.02 * top))
    h2_pt = ax2.get_window_extent(renderer).height / px
    p_head = (max(len(s) for s in p_txt) * char if p_up else line) + 3
    ax2.set_ylim(0, 100 / max(0.3, 1 - p_head / h2_pt))
    relayout(fig)
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
    fig, ax = plt.subplots(figsize=(WIDTH, 4.0))
    _style(ax)
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
        ms = 8 if marker == "*" else 5.5
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
        ax.set_xlim(t.min() / 1.8, t.max() * 2.5)
        hi = max(pos.max() if len(pos) else floor * 100, floor * 100)
        ax.set_ylim(floor / 4, hi * 4)
    else:
        empty_axes(ax, "no completed point with an error recorded")
    if any_zero or len(d):
        ax.axhline(floor, color="0.4", ls="--", lw=0.8, zorder=1,
                   label=f"err = 0 (bit-identical), drawn at {floor:.0e}")
    ax.plot([], [], ls="none", marker=".", color="0.4", label="err_rms (small dots)")
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_major_locator(LogLocator(base=10, numticks=12))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("time per step totalT [ms]", fontsize=LABEL)
    ax.set_ylabel("err_max [mean particle radii]", fontsize=LABEL)
    ax.set_title(f"Final-position error against the serial run: {ctx}", fontsize=TITLE)
    ax.grid(True, which="major", lw=0.4, alpha=0.5)
    note = figure_notes(d, skipped, WIDTH)
    if noerr:
        note += note_lines(noerr, WIDTH, head="Done, no error recorded (not plotted): ")
    layout_figure(fig, [ax], _legend_handles(ax), note)
    _place_labels(ax, labels)
    return fig
