"""Figures of a flight, from a flight record folder or from any .tlog.

    path3d.png       3-D path (north, east, altitude) and its top view, against the reference
                     (and a simulator's true path, when the record has truth.csv)
    error.png        position error per axis (north, east, altitude) and its 3-D norm (and the
                     true position's, with truth.csv), with summary.json's error figures and the
                     windows they leave out
    disturbance.png  the observer's total disturbance estimate z3 per axis, and the truth if known
                     (less the drag the observers model as a known input, which z3 leaves out)
    commands.png     thrust and attitude setpoint (roll, pitch, yaw in degrees); for a record also
                     the acceleration commanded against the one applied after the tilt/thrust limits
                     (not for a ``native`` record: the autopilot's own controller made them)
    link.png         the interval between samples and their age (a record only)

:func:`plot_record` reads a record folder (``controller.csv`` and ``summary.json``, see
:mod:`mavadrc.flight.record`); :func:`plot_tlog` reads any MAVLink telemetry log (ours, PX4's, QGC's)
and draws what it holds.  Figures are drawn with matplotlib's Agg canvas: no display is needed and
no pyplot state is touched.  Positions are NED; figures show altitude = -z, accelerations keep
NED axes and say so ("down").

What a figure prints is what summary.json says (the error figures are read from it, not worked
out again from the table, whose windows differ), and it says which window each number covers.
No axis is narrower than its unit's floor (:data:`UNIT_FLOORS`), no legend lies on the data,
and nothing matplotlib warns of reaches the console (:data:`caught`).
"""

import contextlib
import json
import logging
import math
import os
import struct
import textwrap
import warnings
from pathlib import Path

import numpy as np

from mavadrc.control.rotations import quats_to_euler
from mavadrc.flight import record
from mavadrc.flight.truth import reference_at
from mavadrc.mission.identification import HANDOVER_S

log = logging.getLogger(__name__)

#: resolution of every PNG, dots per inch
DPI = 150
#: figure sizes in inches (width, height); a PNG is round(w * DPI) x round(h * DPI) pixels
SIZES = {
    "path3d": (11.0, 5.0),
    "error": (8.0, 8.0),
    "disturbance": (8.0, 7.0),
    "commands": (12.0, 7.5),           # record: attitude column + acceleration column
    "commands_attitude": (8.0, 7.5),   # tlog: attitude column only
    "link": (8.0, 4.5),
}

NED = ("north", "east", "down")
_REF_STYLE = dict(color="0.25", ls="--", lw=1.2)
_COLORS = ("C0", "C1", "C2")


# ---------------------------------------------------------------------------------- helpers

_TRUTH_COLOR = "0.55"  # a simulator's true track: grey, beside the estimate's colours
#: the gid of the artists that mark a value, a time or a window (the zero line, settle_s, the
#: windows not scored), not data: what a legend or a box may lie over
MARK = "mark"
#: the windows summary.json's error figures leave out: hatched
_UNSCORED_STYLE = dict(facecolor="none", edgecolor="C3", hatch="////", lw=0.0, alpha=0.35,
                       zorder=0.5)
_SETTLE_STYLE = dict(color="C3", ls=":", lw=1.3)

#: the warnings and matplotlib's log messages the last :func:`plot_record` or :func:`plot_tlog`
#: caught, as text: a flight's console is not the place for a plotting library's complaints
#: (the drawings are made to raise none; the tests hold them to it)
caught = []


@contextlib.contextmanager
def _quiet():
    """Warnings and matplotlib's log records kept in :data:`caught` (and logged at debug
    level), not printed."""
    got = []

    class _Keep(logging.Handler):
        def emit(self, rec):
            got.append(f"matplotlib log: {rec.getMessage()}")

    mpl_log = logging.getLogger("matplotlib")
    keep, propagate = _Keep(logging.WARNING), mpl_log.propagate
    mpl_log.addHandler(keep)
    mpl_log.propagate = False
    try:
        with warnings.catch_warnings(record=True) as warned:
            warnings.simplefilter("always")
            try:
                yield
            finally:
                got.extend(f"{w.category.__name__}: {w.message}" for w in warned)
    finally:
        mpl_log.removeHandler(keep)
        mpl_log.propagate = propagate
        caught[:] = got
        for text in got:
            log.debug("while drawing the figures: %s", text)


def _figure(name):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=SIZES[name], dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig, out, name):
    path = Path(out) / f"{name}.png"
    fig.savefig(path, dpi=DPI)
    return path


def _finite(a):
    a = np.asarray(a, dtype=float)
    return a.size > 0 and bool(np.isfinite(a).any())


def _title(summary, what):
    parts = [what]
    if summary:
        head = " / ".join(str(summary[k]) for k in ("controller", "mission") if summary.get(k))
        if head:
            parts.append(head)
    return "  -  ".join(parts)


def _wrap(text, width=115):
    return "\n".join(textwrap.wrap(text, width))


def quat_to_euler_deg(q):
    """(N, 4) quaternions (w, x, y, z) -> (N, 3) ZYX roll, pitch, yaw in degrees.

    :func:`mavadrc.control.rotations.quat_to_euler` of each row; yaw is unwrapped over the
    finite samples so a turn through 180 degrees draws as a line, not a jump.
    """
    q = np.ascontiguousarray(q, dtype=np.float64).reshape(-1, 4)
    eul = np.empty((len(q), 3))
    quats_to_euler(q, eul)
    yaw = eul[:, 2]
    ok = np.isfinite(yaw)
    if ok.any():
        yaw[ok] = np.unwrap(yaw[ok])
    return np.degrees(eul)


def phase_spans(t, phase):
    """Contiguous runs of the ``phase`` column as (t_start, t_end, name)."""
    spans = []
    if not phase or len(t) == 0:
        return spans
    start = 0
    for i in range(1, len(phase) + 1):
        if i == len(phase) or phase[i] != phase[start]:
            end_t = t[i] if i < len(t) else t[-1]
            if phase[start]:
                spans.append((float(t[start]), float(end_t), phase[start]))
            start = i
    return spans


#: the least span of each kind of axis: below it a signal is drawn flat at its value (its size
#: is printed beside it), not as rounding noise blown up to fill the axes (a yaw setpoint of
#: 1e-8 deg drawn on a 1e-8 deg axis)
MIN_SPAN_M = 1e-3      # a position error, m
MIN_SPAN_ACC = 1e-2    # an acceleration, m/s^2
MIN_SPAN_DEG = 1.0     # an angle, deg
MIN_SPAN_MS = 1.0      # a sample interval or age, ms
MIN_SPAN_S = 1.0       # a time axis, s
MIN_PATH_SPAN_M = 0.1  # the path's north and east: a hover's millimetres on 10 cm
MIN_ALT_SPAN_M = 1.0   # the path's altitude
#: every axis's floor by the unit its label ends with
UNIT_FLOORS = {"[m]": MIN_SPAN_M, "[m/s$^2$]": MIN_SPAN_ACC, "[deg]": MIN_SPAN_DEG,
               "[ms]": MIN_SPAN_MS, "[s]": MIN_SPAN_S, "[normalized]": 1.0}
#: rows the phase names may take above a time axis before one is left out
LABEL_ROWS = 3


def _shade_phases(axes, spans, label_top=True):
    """Every other phase shaded; the phases' names above the first axes, centred on their spans
    and staggered over up to :data:`LABEL_ROWS` rows so that no two overlap."""
    if len(spans) < 2:
        return
    for k, (t0, t1, name) in enumerate(spans):
        for ax in axes:
            if k % 2:
                ax.axvspan(t0, t1, color="0.92", lw=0, zorder=0, gid=MARK)
    if label_top:
        _phase_labels(axes[0], spans)


def _layout(fig):
    """Lays ``fig`` out as it will be saved (its axes where they will be), returns a renderer."""
    fig.get_layout_engine().execute(fig)
    return fig.canvas.get_renderer()


def _phase_labels(ax, spans):
    renderer = _layout(ax.figure)
    x0, x1 = ax.get_xlim()
    scale = ax.bbox.width / (x1 - x0) if x1 > x0 else 0.0
    pad = 4.0  # pixels between neighbours in a row
    row_ends = [-math.inf] * LABEL_ROWS  # right edge (pixels from the axes' left) of each row
    for t0, t1, name in spans:
        mid = 0.5 * (t0 + t1)
        text = ax.annotate(name, xy=(mid, 1.0), xycoords=ax.get_xaxis_transform(),
                           xytext=(0.0, 3.0), textcoords="offset points", ha="center",
                           va="bottom", fontsize=8, color="0.35")
        half = 0.5 * text.get_window_extent(renderer).width
        centre = (mid - x0) * scale
        row = next((r for r, end in enumerate(row_ends) if centre - half >= end + pad), None)
        if row is None:
            text.remove()  # no room in any row: the shading still shows the phase
            continue
        row_ends[row] = centre + half
        text.xyann = (0.0, 3.0 + 10.0 * row)


def _rms_max_text(rms, mx):
    """'RMS .., max ..' in one unit, the one the max reads best in: m from 1 cm, mm from 1 um,
    below that m in powers of ten (rounding noise, e.g. an axis the vehicle never left)."""
    rms, mx = float(rms), float(mx)
    if abs(mx) >= 1e-2:
        return f"RMS {rms:#.3g} m, max {mx:#.3g} m"
    if abs(mx) >= 1e-6:
        return f"RMS {1e3 * rms:#.3g} mm, max {1e3 * mx:#.3g} mm"
    return f"RMS {rms:.2e} m, max {mx:.2e} m"


def _seconds(x):
    """A time as summary.json has it, without its float noise: 37.800000000000004 -> '37.8'."""
    return f"{float(x):.2f}".rstrip("0").rstrip(".")


def min_span(ax, span, which="y"):
    """Widen each axis in ``which`` ('x', 'y', 'z') to at least ``span`` around its data:
    values that differ only by floating-point rounding (an estimate of 1e-13 where the truth is
    0) draw as a flat line at their value, not blown up to fill the axes on a 1e-13 scale."""
    for name in which:
        lo, hi = getattr(ax, f"get_{name}lim")()
        if hi - lo < span:
            mid = 0.5 * (lo + hi)
            getattr(ax, f"set_{name}lim")(mid - 0.5 * span, mid + 0.5 * span)


def label_3d(ax, xlabel, ylabel, zlabel):
    """Label 3-D axes with few, small ticks and the labels set off from them (on a flat box
    the altitude label otherwise lands on the north one, and ticks run into each other)."""
    from matplotlib.ticker import MaxNLocator

    for axis, n in ((ax.xaxis, 5), (ax.yaxis, 5), (ax.zaxis, 4)):
        axis.set_major_locator(MaxNLocator(n))
    ax.tick_params(labelsize=7, pad=0)
    ax.set_xlabel(xlabel, labelpad=2)
    ax.set_ylabel(ylabel, labelpad=2)
    ax.set_zlabel(zlabel, labelpad=6)


def _data_lines(ax):
    """The lines of ``ax`` that draw data (not a zero line or a marked time)."""
    return [ln for ln in ax.get_lines() if ln.get_gid() != MARK]


def _room_above(ax, texts, pad=0.04):
    """Raise the top of ``ax``'s y axis until its data lines stay below ``texts`` (anchored to
    the axes' top): a box of figures is never written over the curves it describes."""
    renderer = _layout(ax.figure)
    bottom = min(t.get_window_extent(renderer).y0 for t in texts)
    frac = (bottom - ax.bbox.y0) / ax.bbox.height - pad  # the data's share of the height
    tops = [np.nanmax(np.asarray(ln.get_ydata(), dtype=float)) for ln in _data_lines(ax)
            if _finite(ln.get_ydata())]
    if not tops or frac <= 0.2:
        return
    lo, hi = ax.get_ylim()
    top = max(tops)
    if top > lo + frac * (hi - lo):
        ax.set_ylim(lo, lo + (top - lo) / frac)


def _figure_legend(fig, handles, ncols=None):
    """One legend for the figure, outside every axes (below them): on no data."""
    if not handles:
        return None
    return fig.legend(handles=handles, loc="outside lower center", fontsize=8,
                      ncols=ncols or len(handles), frameon=False)


# ------------------------------------------------------------------------ what summary.json scored

def scoring(t, spans, summary):
    """What summary.json's error figures cover, on a record's time axis: None when it has none
    (no summary, or a tlog); else a dict of

    ``settle_s``  the after-settle figures (``after_settle``) count from here (None: none);
    ``end``       the last scored step (summary.json's ``duration_s``);
    ``unscored``  [(t0, t1, why)]: the rows logged but left out of every figure: the
                  identification's doublets (its segment but for the hold before the hand-over,
                  :data:`~mavadrc.mission.identification.HANDOVER_S`) and what follows the last
                  scored step (the touchdown, and the ground's push before contact was seen).
    """
    if not summary or "rms_error_m" not in summary:
        return None
    t = np.asarray(t, dtype=float)
    unscored = []
    for t0, t1, name in spans:
        if name == "identify":
            unscored.append((t0, max(t0, t1 - HANDOVER_S), "identification"))
    end = summary.get("duration_s")
    if end is not None and t.size and t[-1] > end:
        unscored.append((float(end), float(t[-1]), "touchdown"))
    settle = summary.get("settle_s") or 0.0
    return {"settle_s": float(settle) if settle > 0 else None, "end": end, "unscored": unscored}


def _rms_max(fig, k):
    """'RMS .., max ..' of panel ``k`` (0-2 per axis, 3 the 3-D norm) of a summary's error
    figures ``fig``; 'not reached' where it has none (a flight ended before settle_s)."""
    try:
        if k == 3:
            rms, mx = fig["rms_error_m"], fig["max_error_m"]
        else:
            rms, mx = fig["rms_error_xyz_m"][k], fig["max_error_xyz_m"][k]
    except (TypeError, KeyError, IndexError):
        return "not reached"
    if rms is None or mx is None:
        return "not reached"
    return _rms_max_text(rms, mx)


def score_lines(summary, k):
    """The lines of figures printed on error panel ``k``: summary.json's, each saying its
    window."""
    lines = []
    settle = summary.get("settle_s") or 0.0
    if settle > 0:
        lines.append(f"after {_seconds(settle)} s (settle_s): "
                     + _rms_max(summary.get("after_settle"), k))
    lines.append("whole mission (scored steps): " + _rms_max(summary, k))
    return lines


def _drawn_line(err, what):
    err = np.asarray(err, dtype=float)
    ok = np.isfinite(err)
    if not ok.any():
        return None
    rms = math.sqrt(float(np.mean(err[ok] ** 2)))
    mx = float(np.max(np.abs(err[ok])))
    return f"{what}: " + _rms_max_text(rms, mx)


def _stat_box(ax, lines):
    if not lines:
        return None
    return ax.text(0.01, 0.96, "\n".join(lines), transform=ax.transAxes, ha="left", va="top",
                   fontsize=7.5, zorder=5, linespacing=1.3,
                   bbox=dict(boxstyle="round,pad=0.25", fc="white", ec="0.8", alpha=0.95))


def _mark_scoring(axes, score):
    """The windows summary.json left out, hatched, and settle_s, a dotted line, on ``axes``;
    returns the legend's handles for them."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = []
    if score is None:
        return handles
    if score["unscored"]:
        for ax in axes:
            for t0, t1, _ in score["unscored"]:
                ax.axvspan(t0, t1, gid=MARK, **_UNSCORED_STYLE)
        whys = " and ".join(dict.fromkeys(why for _, _, why in score["unscored"]))
        handles.append(Patch(label=f"not scored in summary.json ({whys})",
                             **{k: v for k, v in _UNSCORED_STYLE.items() if k != "zorder"}))
    if score["settle_s"] is not None:
        for ax in axes:
            ax.axvline(score["settle_s"], gid=MARK, zorder=1, **_SETTLE_STYLE)
        handles.append(Line2D([], [], label=f"settle_s {_seconds(score['settle_s'])} s: "
                              "the after-settle figures from here", **_SETTLE_STYLE))
    return handles


# ---------------------------------------------------------------------------------- drawings

def _path_limits(pts):
    """(centre, span) per axis (east, north, altitude) of the points ``pts`` (N, 3) NED, each
    span at least its floor: north and east :data:`MIN_PATH_SPAN_M`, altitude
    :data:`MIN_ALT_SPAN_M` or a fifth of the width (a level flight still reads as one)."""
    enu = np.column_stack([pts[:, 1], pts[:, 0], -pts[:, 2]])
    lo, hi = enu.min(axis=0), enu.max(axis=0)
    centre, span = 0.5 * (lo + hi), hi - lo
    span[:2] = np.maximum(span[:2], MIN_PATH_SPAN_M)
    span[2] = max(span[2], MIN_ALT_SPAN_M, 0.2 * max(span[0], span[1]))
    return centre, span


def draw_path(out, pos, ref=None, title="Flight path", truth=None):
    """path3d.png: ``pos`` and ``ref`` are (N, 3) NED; ``ref`` may be None (vehicle path only);
    ``truth``: a simulator's true path (M, 3), drawn beside the estimate's, or None.

    Both views span at least :data:`MIN_PATH_SPAN_M` north and east, centred on the path (a
    hover's few millimetres draw as a dot in a 10 cm box, not as a box of millimetres); the
    start is a ring, the end a smaller square inside it where the flight ends where it began;
    the legend is below the views, on no line."""
    pos = np.asarray(pos, dtype=float)
    has_ref = ref is not None and _finite(ref)
    fig = _figure("path3d")
    fig.suptitle(title)
    # the 3-D axes' altitude label reaches past its box, which the layout does not see: room
    # between the panels keeps it off the top view's north label
    fig.get_layout_engine().set(wspace=0.12)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)
    north, east, alt = pos[:, 0], pos[:, 1], -pos[:, 2]
    # the vehicle under the reference: a few centimetres off, the reference still shows
    ax.computed_zorder = False  # draw in the order given, not by depth
    what = "vehicle" if truth is None else "vehicle (estimate)"
    ax.plot(east, north, alt, color="C0", lw=2.0, alpha=0.8, label=what, zorder=2)
    top.plot(east, north, color="C0", lw=2.0, alpha=0.8, label=what, zorder=2)
    pts = [pos]
    if truth is not None and len(truth):
        tr = np.asarray(truth, dtype=float)
        ax.plot(tr[:, 1], tr[:, 0], -tr[:, 2], color=_TRUTH_COLOR, lw=1.0,
                label="true (simulator)", zorder=1)
        top.plot(tr[:, 1], tr[:, 0], color=_TRUTH_COLOR, lw=1.0, label="true (simulator)",
                 zorder=1)
        pts.append(tr)
    if has_ref:
        ref = np.asarray(ref, dtype=float)
        ax.plot(ref[:, 1], ref[:, 0], -ref[:, 2], label="reference", zorder=3, **_REF_STYLE)
        top.plot(ref[:, 1], ref[:, 0], label="reference", zorder=3, **_REF_STYLE)
        pts.append(ref)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1))
    if ok.size:
        i0, i1 = ok[0], ok[-1]
        # the start a ring, the end a smaller filled square: a flight that lands where it took
        # off shows both
        start = dict(color="C2", marker="o", mfc="none", mew=2.0, ms=11, ls="none",
                     label="start", zorder=6)
        end = dict(color="C3", marker="s", ms=5, ls="none", label="end", zorder=7)
        top.plot([east[i0]], [north[i0]], **start)
        top.plot([east[i1]], [north[i1]], **end)
        ax.plot([east[i0]], [north[i0]], [alt[i0]], **start)
        ax.plot([east[i1]], [north[i1]], [alt[i1]], **end)
    allp = np.vstack([p[np.isfinite(p).all(axis=1)] for p in pts])
    if allp.size:
        centre, span = _path_limits(allp)
        margin = 1.06
        for k, setter in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            half = 0.5 * margin * span[k]
            setter(centre[k] - half, centre[k] + half)
        # north and east to the same scale, altitude stretched to stay readable
        horiz = max(span[0], span[1])
        ax.set_box_aspect((span[0] / horiz, span[1] / horiz,
                           float(np.clip(span[2] / horiz, 0.35, 1.0))))
        # the top view square, at one scale: its limits hold, the box takes the aspect
        half = 0.5 * margin * horiz
        top.set_xlim(centre[0] - half, centre[0] + half)
        top.set_ylim(centre[1] - half, centre[1] + half)
    else:
        min_span(ax, MIN_PATH_SPAN_M, "xy")
        min_span(top, MIN_PATH_SPAN_M, "xy")
    top.set_aspect("equal", adjustable="box")
    label_3d(ax, "east [m]", "north [m]", "altitude [m]")
    ax.set_title("3-D path")
    top.set_xlabel("east [m]")
    top.set_ylabel("north [m]")
    top.set_title("top view")
    top.grid(True, alpha=0.3)
    _figure_legend(fig, top.get_legend_handles_labels()[0])
    return _save(fig, out, "path3d")


def draw_error(out, t, err, spans=(), stats=None, title="Position error", xlabel="time [s]",
               truth=None):
    """error.png: ``err`` = position - reference, (N, 3) NED; drawn as north, east, altitude.
    ``truth``: (t, err) of a simulator's true position against the reference, drawn thin
    beside the estimate's (the figures stay the estimate's), or None.

    ``stats``: summary.json.  Its error figures are the ones printed, each with its window
    (after settle_s, the whole mission's scored steps), and the windows they leave out are
    marked (:func:`scoring`).  Without them (a tlog) the figures printed are worked out over
    every sample drawn, and say so.
    """
    t = np.asarray(t, dtype=float)
    err = np.asarray(err, dtype=float)
    shown = np.column_stack([err[:, 0], err[:, 1], -err[:, 2]])  # altitude error = -(z error)
    norm = np.linalg.norm(err, axis=1)
    fig = _figure("error")
    fig.suptitle(title)
    axes = fig.subplots(4, 1, sharex=True)
    names = ("north", "east", "altitude")
    score = scoring(t, spans, stats)
    handles = []
    if truth is not None:
        tt, et = (np.asarray(a, dtype=float) for a in truth)
        et = np.column_stack([et[:, 0], et[:, 1], -et[:, 2]])
        for k in range(3):
            axes[k].plot(tt, et[:, k], color=_TRUTH_COLOR, lw=0.8, alpha=0.8,
                         label="true (simulator)")
        axes[3].plot(tt, np.linalg.norm(et, axis=1), color=_TRUTH_COLOR, lw=0.8, alpha=0.8)
        handles.append(axes[0].get_lines()[-1])
    for k in range(3):
        ax = axes[k]
        ax.plot(t, shown[:, k], color=_COLORS[k], lw=1.0, label="estimate")
        ax.axhline(0.0, color="0.5", lw=0.6, gid=MARK)
        ax.set_ylabel(f"{names[k]} error [m]")
    if truth is not None:
        handles.insert(0, axes[0].get_lines()[-2])
    axes[3].plot(t, norm, color="k", lw=1.0)
    axes[3].set_ylabel("3-D error [m]")
    axes[3].set_ylim(bottom=0.0)
    axes[-1].set_xlabel(xlabel)
    min_span(axes[-1], MIN_SPAN_S, "x")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    _shade_phases(list(axes), list(spans))
    handles += _mark_scoring(axes, score)
    _figure_legend(fig, handles, ncols=min(len(handles), 2))
    boxes = []
    for k, ax in enumerate(axes):
        if score is not None:
            lines = score_lines(stats, k)
        else:
            lines = [_drawn_line(shown[:, k] if k < 3 else norm, "every sample drawn")]
        boxes.append(_stat_box(ax, [ln for ln in lines if ln]))
    for ax, box in zip(axes, boxes):
        min_span(ax, MIN_SPAN_M)
        if box is not None:
            _room_above(ax, [box])
    return _save(fig, out, "error")


def _limits(series, window):
    """y limits for the (t, v) ``series`` of one axes: the extremes of their samples in
    ``window`` (t0, t1), or without one their 0.5-99.5 percentiles, 5 % apart from the data."""
    vals = []
    for tt, vv in series:
        tt, vv = np.asarray(tt, dtype=float), np.asarray(vv, dtype=float)
        m = np.isfinite(vv)
        if window is not None:
            m &= (tt >= window[0]) & (tt <= window[1])
        vals.append(vv[m])
    v = np.concatenate(vals) if vals else np.empty(0)
    if v.size == 0:
        return None
    lo, hi = (float(v.min()), float(v.max())) if window is not None else \
        (float(np.percentile(v, 0.5)), float(np.percentile(v, 99.5)))
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def _clipped(series, names, lo, hi, window=None, unit="m/s$^2$"):
    """What the y limits (lo, hi) leave out of ``series``: '<name> to <v> <unit> at <t> s', the
    sample furthest out of each series with any out, and where it was against ``window`` (the
    span in the air: before it the vehicle stood on the ground, after it the ground met it)."""
    parts = []
    for (tt, vv), name in zip(series, names):
        tt, vv = np.asarray(tt, dtype=float), np.asarray(vv, dtype=float)
        out = np.isfinite(vv) & ((vv < lo) | (vv > hi))
        if out.any():
            i = np.flatnonzero(out)[np.argmax(np.abs(vv[out] - 0.5 * (lo + hi)))]
            where = ""
            if window is not None and tt[i] < window[0]:
                where = ", before lift-off"
            elif window is not None and tt[i] > window[1]:
                where = ", after the last scored step"
            parts.append(f"{name} to {vv[i]:.2g} {unit} at {tt[i]:.1f} s{where}")
    return parts


def draw_disturbance(out, est=None, truth=None, note=None, title="Total disturbance",
                     xlabel="time [s]", drag=None, window=None, explain=None):
    """disturbance.png: ``est`` and ``truth`` are 3 per-axis (t, value) pairs (NED) or None.

    With no estimate, ``note`` (e.g. "PD has no observer") is written in each axes.

    ``drag``: 3 per-axis arrays, at the truth's times, of the drag acceleration the observers
    take as a known input (-c v_ref, NED; NaN where none is modelled), or None.  Their z3 is the
    rest, so the truth is drawn less it.  ``window``: (t0, t1, words) whose samples set the y
    axes (the flight in the air), or None: each axes' 0.5-99.5 percentiles; what falls outside
    is clipped, and said so over the axes.  ``explain``: a sentence under the axes.
    """
    fig = _figure("disturbance")
    fig.suptitle(title)
    axes = fig.subplots(3, 1, sharex=True)
    has_est = est is not None and any(_finite(v) for _, v in est)
    has_truth = truth is not None and any(_finite(v) for _, v in truth)
    less_drag = has_truth and drag is not None and any(_finite(d) for d in drag)
    handles = []
    for k in range(3):
        ax = axes[k]
        series, names = [], []
        if has_truth:
            tt, vv = (np.asarray(a, dtype=float) for a in truth[k])
            what = "true disturbance (simulator)"
            if less_drag:
                vv = vv - np.nan_to_num(np.asarray(drag[k], dtype=float), nan=0.0)
                what = (r"true disturbance less the drag modelled (simulator's truth + "
                        r"$c\,v_\mathrm{ref}$)")
            ax.plot(tt, vv, color="k", ls="--", lw=1.1, label=what)
            series.append((tt, vv))
            names.append("truth" + (" less drag" if less_drag else ""))
        if has_est:
            te, ve = (np.asarray(a, dtype=float) for a in est[k])
            ax.plot(te, ve, color=_COLORS[k], lw=1.2, label="observer's estimate z3")
            series.append((te, ve))
            names.append("z3")
        else:
            ax.text(0.5, 0.5, note or "no disturbance estimate", transform=ax.transAxes,
                    ha="center", va="center", fontsize=12, color="0.3",
                    bbox=dict(boxstyle="round,pad=0.4", fc="white", ec="0.7"))
        ax.axhline(0.0, color="0.5", lw=0.6, gid=MARK)
        ax.set_ylabel(f"{NED[k]} [m/s$^2$]")
        lim = _limits(series, None if window is None else window[:2]) if series else None
        if lim is not None and lim[1] > lim[0]:
            ax.set_ylim(*lim)
            gone = _clipped(series, names, *lim, window=None if window is None else window[:2])
            if gone:
                ax.set_title("clipped: " + "; ".join(gone), loc="right", fontsize=7.5,
                             color="0.3")
        min_span(ax, MIN_SPAN_ACC)
        ax.grid(True, alpha=0.3)
        if k == 0:
            handles = ax.get_legend_handles_labels()[0]
    axes[-1].set_xlabel(xlabel)
    min_span(axes[-1], MIN_SPAN_S, "x")
    words = [explain] if explain else []
    if window is not None:
        words.append(f"y axes: {window[2]}; beyond it clipped.")
    elif has_est or has_truth:
        words.append("y axes: each axis's 0.5-99.5 percentiles; beyond them clipped.")
    if words:
        axes[0].set_title(_wrap(" ".join(words), 125), loc="left", fontsize=7.5, color="0.2")
        if axes[0].get_title(loc="right"):  # the clip note under the explanation, not beside
            axes[0].set_title(axes[0].get_title(loc="left") + "\n"
                              + axes[0].get_title(loc="right"), loc="left", fontsize=7.5,
                              color="0.2")
            axes[0].set_title("", loc="right")
    _figure_legend(fig, handles)
    return _save(fig, out, "disturbance")


def draw_commands(out, t, q, thrust, acc=None, spans=(), title="Commands", xlabel="time [s]",
                  window=None):
    """commands.png: thrust (0..1) and the attitude setpoint ``q`` (N, 4) as roll/pitch/yaw.

    ``acc`` = (t, acc_cmd (N, 3), acc_applied (N, 3)) adds a column per NED axis, with the
    samples where the limits changed the command shaded.  Angles span at least
    :data:`MIN_SPAN_DEG`, accelerations :data:`MIN_SPAN_ACC`; the legend is below the axes.
    ``window`` = (t0, t1, words): the accelerations' y axes span that window (the flight in the
    air), what lies beyond is clipped and named over the axes (a touchdown's spike once
    squashed the flight into a line).
    """
    t = np.asarray(t, dtype=float)
    eul = quat_to_euler_deg(q)
    fig = _figure("commands" if acc is not None else "commands_attitude")
    fig.suptitle(title + "\n" + ("attitude setpoint (left), controller acceleration, NED (right)"
                                 if acc is not None else "attitude setpoint (SET_ATTITUDE_TARGET)"),
                 linespacing=1.5)
    if acc is not None:
        grid = fig.subplots(3, 2, sharex=True)
        left, right = grid[:, 0], grid[:, 1]
    else:
        left, right = fig.subplots(3, 1, sharex=True), []
    ax = left[0]
    ax.plot(t, thrust, color="C3", lw=1.0)
    ax.set_ylabel("thrust [normalized]")
    ax.set_ylim(-0.02, 1.02)
    ax = left[1]
    ax.plot(t, eul[:, 0], color="C0", lw=1.0, label="roll")
    ax.plot(t, eul[:, 1], color="C1", lw=1.0, label="pitch")
    ax.axhline(0.0, color="0.5", lw=0.6, gid=MARK)
    ax.set_ylabel("roll, pitch [deg]")
    min_span(ax, MIN_SPAN_DEG)
    handles = ax.get_legend_handles_labels()[0]
    ax = left[2]
    ax.plot(t, eul[:, 2], color="C2", lw=1.0)
    ax.set_ylabel("yaw [deg]")
    min_span(ax, MIN_SPAN_DEG)
    left[-1].set_xlabel(xlabel)
    min_span(left[-1], MIN_SPAN_S, "x")
    if acc is not None:
        from matplotlib.patches import Patch

        ta, cmd, app = (np.asarray(a, dtype=float) for a in acc)
        limited = False
        for k in range(3):
            ax = right[k]
            ax.plot(ta, cmd[:, k], color="0.2", ls="--", lw=1.0, label="acceleration commanded")
            ax.plot(ta, app[:, k], color=_COLORS[k], lw=1.1,
                    label="applied (after the limits)")
            lim = np.abs(cmd[:, k] - app[:, k]) > 1e-6
            if lim.any():
                limited = True
                ax.fill_between(ta, cmd[:, k], app[:, k], where=lim, color="C3", alpha=0.25,
                                lw=0)
            ax.set_ylabel(f"{NED[k]} acc [m/s$^2$]")
            ax.axhline(0.0, color="0.5", lw=0.6, gid=MARK)
            series = [(ta, cmd[:, k]), (ta, app[:, k])]
            lim_y = None if window is None else _limits(series, window[:2])
            if lim_y is not None:
                ax.set_ylim(*lim_y)
                gone = _clipped(series[:1], ["commanded"], *lim_y, window=window[:2])
                if gone:
                    ax.set_title("clipped: " + "; ".join(gone), loc="right", fontsize=7.5,
                                 color="0.35")
            min_span(ax, MIN_SPAN_ACC)
        handles += right[0].get_legend_handles_labels()[0]
        if limited:
            handles.append(Patch(color="C3", alpha=0.25, label="limited (tilt/thrust)"))
        right[-1].set_xlabel(xlabel)
    axes = list(left) + list(right)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    _figure_legend(fig, handles)
    _shade_phases(list(left), list(spans))
    if len(right):
        _shade_phases(list(right), list(spans))
    return _save(fig, out, "commands")


# ---------------------------------------------------------------------------------- records

def draw_link(out, t, dt, age=None, spans=(), title="Link", xlabel="time [s]", age_note=None):
    """link.png: the interval between the samples the controller stepped on and, where the
    clocks were synchronised (TIMESYNC), each sample's age: gaps, a slow stream and latency show
    here.

    An age is our clock, mapped onto the vehicle's by TIMESYNC's offset, less the sample's
    time_boot_ms: the offset is an estimate (good to about half a round trip, and to the step
    of the vehicle's clock), so a fresh sample can read a little below 0.  ``age_note`` says how
    the ages were had; the ages below 0 are counted and called what they are over the panel."""
    t = np.asarray(t, dtype=float)
    have_age = age is not None and _finite(age)
    fig = _figure("link")
    fig.suptitle(title)
    axes = fig.subplots(2 if have_age else 1, 1, sharex=True, squeeze=False)[:, 0]
    axes[0].plot(t, 1e3 * np.asarray(dt, dtype=float), ".", ms=2, color="C0")
    axes[0].set_ylabel("sample interval [ms]")
    axes[0].set_ylim(bottom=0.0)
    min_span(axes[0], MIN_SPAN_MS)
    if have_age:
        ms = 1e3 * np.asarray(age, dtype=float)
        ax = axes[1]
        ax.plot(t, ms, ".", ms=2, color="C1")
        ax.axhline(0.0, color="0.5", lw=0.6, gid=MARK)
        ax.set_ylabel("sample age [ms]")
        min_span(ax, MIN_SPAN_MS)
        words = [age_note] if age_note else []
        ok = np.isfinite(ms)
        below = ok & (ms < 0.0)
        if below.any():
            words.append(f"{int(below.sum())} of {int(ok.sum())} below 0 (down to "
                         f"{float(ms[below].min()):.2f} ms): the clock offset's error, not "
                         "samples from the future.")
        if words:
            ax.set_title(_wrap(" ".join(words), 120), loc="left", fontsize=7.5, color="0.2")
    axes[-1].set_xlabel(xlabel)
    min_span(axes[-1], MIN_SPAN_S, "x")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    _shade_phases(list(axes), list(spans))
    return _save(fig, out, "link")


def _cols(table, names, n):
    return np.column_stack([table.get(c, np.full(n, math.nan)) for c in names])


def modelled_drag(table, summary, n):
    """(n, 3) the drag acceleration the observers took as a known input at each row, -c v_ref
    (NED, m/s^2), and (3,) the largest c (1/s) per axis; (None, None) where no row models one.

    North and east from the row's own drag (``drag_x``, ``drag_y``: as flown, learnt or not);
    the vertical drag is not in the table: the flown controller's (summary.json's
    ``controller_flown``), from the identification's hand-over on (before it the safe gains
    model none), at the rows whose controller models drag at all."""
    cx = np.asarray(table.get("drag_x", np.full(n, math.nan)), dtype=float)
    cy = np.asarray(table.get("drag_y", np.full(n, math.nan)), dtype=float)
    models = np.isfinite(cx) & np.isfinite(cy)
    if not models.any():
        return None, None
    flown = (summary or {}).get("controller_flown") or {}
    try:
        cz_flown = float((flown.get("drag") or [0.0, 0.0, 0.0])[2])
    except (TypeError, ValueError, IndexError):
        cz_flown = 0.0
    cz = np.where(models, cz_flown, math.nan)
    ident = (summary or {}).get("identification") or {}
    if ident.get("switched_at_s") is not None:
        cz[np.asarray(table["t"]) < float(ident["switched_at_s"])] = 0.0
    c = np.column_stack([cx, cy, cz])
    vref = _cols(table, [f"ref_v{a}" for a in record.AXES], n)
    top = np.array([float(np.nanmax(c[:, k])) if _finite(c[:, k]) else 0.0 for k in range(3)])
    return -c * vref, top


def _drag_words(acc, c):
    """The sentence that says what the observers model and where it went."""
    peak = [float(np.nanmax(np.abs(acc[:, k]))) if _finite(acc[:, k]) else 0.0 for k in range(3)]
    return (r"The observers model the linear drag along the reference, $-c\,v_\mathrm{ref}$ "
            f"(c up to {c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f} /s north, east, down; here up to "
            f"{peak[0]:.2f}, {peak[1]:.2f}, {peak[2]:.2f} m/s$^2$), as a known input: their z3 "
            "estimates the "
            "rest, and the truth is drawn less that drag.")


def _in_air(t, spans, summary):
    """(t0, t1, words): the record's time in the air, from summary.json's lift-off to its last
    scored step (else to the touchdown phase), or None when neither is known."""
    t = np.asarray(t, dtype=float)
    s = summary or {}
    t0 = s.get("liftoff_s")
    t1 = s.get("duration_s")
    if t1 is None:
        t1 = next((a for a, _, name in spans if name == "touchdown"), None)
    if t0 is None and t1 is None:
        return None
    start = f"lift-off {_seconds(t0)} s" if t0 is not None else "the record's start"
    end = f"the last scored step {_seconds(t1)} s" if t1 is not None else "the record's end"
    return (float(t[0]) if t0 is None else float(t0), float(t[-1]) if t1 is None else float(t1),
            f"the flight in the air, {start} to {end}")


def _age_note(summary):
    """How a record's sample ages were had: in lockstep counted in the vehicle's periods, else
    through TIMESYNC's estimate of its clock, which has an error of its own."""
    s = summary or {}
    if (s.get("config") or {}).get("lockstep"):
        return "Lockstep: each age counts the vehicle's control periods since the sample."
    rtt = (s.get("link") or {}).get("rtt_ms_median")
    half = f" ({rtt / 2:.2f} ms here)" if rtt else ""
    bundled = not any(str(a).startswith("--connect") for a in s.get("command_line") or [])
    step = (" and the step of that clock (the bundled vehicle's moves in 2 ms ticks and answers "
            "TIMESYNC with the last tick's time: ages read up to 2 ms short)") if bundled else (
            " and the step of that clock")
    return ("Ages by TIMESYNC's estimate of the vehicle's clock, good to about half a round "
            f"trip{half}{step}.")


def plot_record(folder, out=None):
    """Draws the figures of a flight record folder into ``out`` (default: the folder); what
    matplotlib warns of is kept in :data:`caught`, not printed."""
    with _quiet():
        return _plot_record(folder, out)


def _plot_record(folder, out):
    folder = Path(folder)
    csv_path = folder / "controller.csv"
    if not csv_path.is_file():
        raise FileNotFoundError(f"no controller.csv in {folder}")
    table = record.read_table(csv_path)
    t = table.get("t")
    if t is None or len(t) == 0:
        raise ValueError(f"{csv_path} has no rows")
    n = len(t)
    summary = {}
    if (folder / "summary.json").is_file():
        summary = json.loads((folder / "summary.json").read_text())
    out = Path(out) if out is not None else folder
    out.mkdir(parents=True, exist_ok=True)
    spans = phase_spans(t, table.get("phase", []))
    xlabel = "time since mission start [s]"
    ax3 = record.AXES

    pos = _cols(table, [f"pos_{a}" for a in ax3], n)
    ref = _cols(table, [f"ref_{a}" for a in ax3], n)
    true_path = true_err = None
    if (folder / "truth.csv").is_file():  # a simulator's true state (mavadrc.flight.truth)
        tr = record.read_table(folder / "truth.csv")
        if len(tr.get("t", ())) > 1:
            true_path = np.column_stack([tr["north"], tr["east"], tr["down"]])
            on = (tr["t"] >= t[0]) & (tr["t"] <= t[-1])
            true_err = (tr["t"][on], true_path[on] - reference_at(tr["t"][on], t, ref))
    paths = [draw_path(out, pos, ref, title=_title(summary, "Flight path"), truth=true_path)]
    paths.append(draw_error(out, t, pos - ref, spans, stats=summary,
                            title=_title(summary, "Position error"), xlabel=xlabel,
                            truth=true_err))

    z3 = _cols(table, [f"z3_{a}" for a in ax3], n)
    truth = _cols(table, [f"true_dist_{a}" for a in ax3], n)
    controller = str(summary.get("controller") or "")
    if _finite(z3):
        note = None
    elif controller == "native":
        note = "native: the autopilot's own controller, no observer of mavadrc's"
    elif controller and controller.upper() != "PD":
        note = f"no observer estimate (z3) in the record ({controller})"
    else:
        note = "PD has no observer"
    drag, c_max = modelled_drag(table, summary, n)
    explain = None
    if drag is not None and _finite(truth):
        explain = _drag_words(drag, c_max)
    paths.append(draw_disturbance(
        out, est=[(t, z3[:, k]) for k in range(3)] if _finite(z3) else None,
        truth=[(t, truth[:, k]) for k in range(3)] if _finite(truth) else None, note=note,
        title=_title(summary, "Total disturbance acceleration"), xlabel=xlabel,
        drag=None if drag is None else [drag[:, k] for k in range(3)],
        window=_in_air(t, spans, summary), explain=explain))

    q = _cols(table, ["q_w", "q_x", "q_y", "q_z"], n)
    acc = (t, _cols(table, [f"acc_cmd_{a}" for a in ax3], n),
           _cols(table, [f"acc_applied_{a}" for a in ax3], n))
    if controller != "native":  # (native: the attitude and thrust are the autopilot's, unsent)
        paths.append(draw_commands(out, t, q, table.get("thrust", np.full(n, math.nan)), acc,
                                   spans, title=_title(summary, "Commands"), xlabel=xlabel,
                                   window=_in_air(t, spans, summary)))
    if "dt" in table and _finite(table["dt"]):
        paths.append(draw_link(out, t, table["dt"], table.get("sample_age"), spans,
                               title=_title(summary, "Samples"), xlabel=xlabel,
                               age_note=_age_note(summary)))
    return paths


# ---------------------------------------------------------------------------------- tlogs

_TLOG_TYPES = ["LOCAL_POSITION_NED", "POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_LOCAL_NED",
               "SET_ATTITUDE_TARGET", "NAMED_VALUE_FLOAT", "DEBUG_VECT"]
_Z3_NAMES = {f"z3_{a}": a for a in record.AXES}
_MAV_FRAME_LOCAL_NED = 1
_POS_IGNORE = 0b111          # POSITION_TARGET_TYPEMASK x, y, z ignore bits
_ATT_IGNORE_THRUST = 1 << 6  # ATTITUDE_TARGET_TYPEMASK
_ATT_IGNORE_ATTITUDE = 1 << 7


def _mavutil():
    os.environ["MAVLINK20"] = "1"  # before pymavlink picks a dialect: read MAVLink 2 frames
    from pymavlink import mavutil

    if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported earlier without MAVLINK20
        mavutil.set_dialect(mavutil.current_dialect)
    return mavutil


def _first_stamp(path):
    with open(path, "rb") as f:
        head = f.read(8)
    return struct.unpack(">Q", head)[0] * 1e-6 if len(head) == 8 else None


def tlog_series(path):
    """The time series :func:`plot_tlog` draws, read from a .tlog with pymavlink.

    Times are seconds from the tlog's first message (its tlog timestamp; ``time_boot_ms`` if
    the log has no usable timestamps).  Every key is present, empty when the log lacks it:

    ``t0`` (0-d, Unix seconds of the first message), ``vehicle`` (0-d, the system id sending
    LOCAL_POSITION_NED, -1 if none); ``pos_t``, ``pos_x/y/z``, ``vel_x/y/z`` (LOCAL_POSITION_NED
    of the vehicle); ``ref_t``, ``ref_x/y/z`` (the vehicle's POSITION_TARGET_LOCAL_NED, else the
    SET_POSITION_TARGET_LOCAL_NED sent to it, local NED frame, position not ignored);
    ``att_t``, ``q_w/x/y/z``, ``thrust`` (SET_ATTITUDE_TARGET sent to the vehicle; NaN where the
    type_mask ignores the field); ``z3_x_t``, ``z3_x`` ... (NAMED_VALUE_FLOAT "z3_x" ...);
    ``true_dist_t``, ``true_dist_x/y/z`` (DEBUG_VECT "TRUE_DIST").
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such tlog: {path}")
    mavutil = _mavutil()
    conn = mavutil.mavlink_connection(str(path))
    rows = {k: [] for k in _TLOG_TYPES}
    try:
        while True:
            # asking for the wanted types lets pymavlink's mmap reader skip the rest unparsed
            m = conn.recv_match(type=_TLOG_TYPES, blocking=False)
            if m is None:
                break
            typ = m.get_type()
            if typ in rows:
                rows[typ].append(m)
    finally:
        conn.close()

    # time base: tlog stamps, or time_boot_ms when the stamps do not move
    stamps = [m._timestamp for ms in rows.values() for m in ms]
    use_boot = len(stamps) > 1 and max(stamps) == min(stamps)
    if use_boot:
        boots = [m.time_boot_ms * 1e-3 for ms in rows.values() for m in ms
                 if hasattr(m, "time_boot_ms")]
        t0 = min(boots) if boots else 0.0

        def when(m):
            return m.time_boot_ms * 1e-3 - t0 if hasattr(m, "time_boot_ms") else math.nan
    else:
        # the first message of the file (whatever its type) is the tlog's first record
        t0 = _first_stamp(path)
        if stamps and (t0 is None or abs(min(stamps) - t0) > 3 * 24 * 3600):
            t0 = min(stamps)  # not a plausible first stamp (damaged head)
        t0 = t0 or 0.0

        def when(m):
            return m._timestamp - t0

    def arr(v):
        return np.asarray(v, dtype=float)

    out = {"t0": arr(t0)}
    lpn = rows["LOCAL_POSITION_NED"]
    senders = {}
    for m in lpn:
        senders[m.get_srcSystem()] = senders.get(m.get_srcSystem(), 0) + 1
    vehicle = max(senders, key=senders.get) if senders else -1
    out["vehicle"] = arr(vehicle)
    lpn = [m for m in lpn if m.get_srcSystem() == vehicle]
    out["pos_t"] = arr([when(m) for m in lpn])
    for a in record.AXES:
        out[f"pos_{a}"] = arr([getattr(m, a) for m in lpn])
        out[f"vel_{a}"] = arr([getattr(m, "v" + a) for m in lpn])

    def for_vehicle(m):
        return m.target_system in (vehicle, 0) or vehicle == -1

    def pos_target(m):
        return (m.coordinate_frame == _MAV_FRAME_LOCAL_NED and not (m.type_mask & _POS_IGNORE))

    refs = [m for m in rows["POSITION_TARGET_LOCAL_NED"]
            if m.get_srcSystem() == vehicle and pos_target(m)]
    if not refs:
        refs = [m for m in rows["SET_POSITION_TARGET_LOCAL_NED"]
                if for_vehicle(m) and pos_target(m)]
    out["ref_t"] = arr([when(m) for m in refs])
    for a in record.AXES:
        out[f"ref_{a}"] = arr([getattr(m, a) for m in refs])

    att = [m for m in rows["SET_ATTITUDE_TARGET"] if for_vehicle(m)]
    out["att_t"] = arr([when(m) for m in att])
    qs = arr([m.q if not (m.type_mask & _ATT_IGNORE_ATTITUDE) else [math.nan] * 4
              for m in att]).reshape(-1, 4)
    for k, c in enumerate("wxyz"):
        out[f"q_{c}"] = qs[:, k].copy()
    out["thrust"] = arr([m.thrust if not (m.type_mask & _ATT_IGNORE_THRUST) else math.nan
                         for m in att])

    z3 = {a: [] for a in record.AXES}
    for m in rows["NAMED_VALUE_FLOAT"]:
        a = _Z3_NAMES.get(m.name)
        if a is not None:
            z3[a].append(m)
    for a in record.AXES:
        out[f"z3_{a}_t"] = arr([when(m) for m in z3[a]])
        out[f"z3_{a}"] = arr([m.value for m in z3[a]])

    truth = [m for m in rows["DEBUG_VECT"] if m.name == "TRUE_DIST"]
    out["true_dist_t"] = arr([when(m) for m in truth])
    for a in record.AXES:
        out[f"true_dist_{a}"] = arr([getattr(m, a) for m in truth])
    return out


def _interp_nan(t_new, t, v):
    """Linear interpolation of v(t) at t_new, NaN outside [t[0], t[-1]]."""
    res = np.interp(t_new, t, v)
    res[(t_new < t[0]) | (t_new > t[-1])] = math.nan
    return res


def plot_tlog(tlog_path, out=None):
    """Draws what a .tlog holds into ``out`` (default: the tlog's folder).

    path3d.png from LOCAL_POSITION_NED (with the position target if the log has one, then also
    error.png); commands.png from SET_ATTITUDE_TARGET; disturbance.png from NAMED_VALUE_FLOAT
    z3_x/y/z (with DEBUG_VECT TRUE_DIST when present).  ValueError if none of these is there.
    What matplotlib warns of is kept in :data:`caught`, not printed.
    """
    with _quiet():
        return _plot_tlog(tlog_path, out)


def _plot_tlog(tlog_path, out):
    tlog_path = Path(tlog_path)
    s = tlog_series(tlog_path)
    has_pos = s["pos_t"].size > 0
    has_att = s["att_t"].size > 0
    has_z3 = any(s[f"z3_{a}"].size for a in record.AXES)
    if not (has_pos or has_att or has_z3):
        raise ValueError(f"no LOCAL_POSITION_NED in {tlog_path} (nor SET_ATTITUDE_TARGET or "
                         "NAMED_VALUE_FLOAT z3_x/y/z): nothing to plot")
    out = Path(out) if out is not None else tlog_path.parent
    out.mkdir(parents=True, exist_ok=True)
    xlabel = "time since first message [s]"
    name = tlog_path.name
    paths = []
    if has_pos:
        pos = np.column_stack([s[f"pos_{a}"] for a in record.AXES])
        ref = None
        if s["ref_t"].size > 1:
            order = np.argsort(s["ref_t"], kind="stable")
            ref = np.column_stack([_interp_nan(s["pos_t"], s["ref_t"][order], s[f"ref_{a}"][order])
                                   for a in record.AXES])
        title = f"Flight path  -  {name}" + ("" if ref is not None else " (no reference in log)")
        paths.append(draw_path(out, pos, ref, title=title))
        if ref is not None:
            paths.append(draw_error(out, s["pos_t"], pos - ref,
                                    title=f"Position error  -  {name}", xlabel=xlabel))
    if has_z3:
        est = [(s[f"z3_{a}_t"], s[f"z3_{a}"]) for a in record.AXES]
        truth = None
        if s["true_dist_t"].size:
            truth = [(s["true_dist_t"], s[f"true_dist_{a}"]) for a in record.AXES]
        # the log holds no drag model: the truth is drawn whole, and said to be
        explain = None if truth is None else (
            "The truth is TRUE_DIST as the simulator sends it, drag included; an observer that "
            "models the drag along the reference (ladrc, adrc without its TD) leaves that out "
            "of z3, and the log does not say how much it modelled.")
        paths.append(draw_disturbance(out, est, truth, title=f"Total disturbance  -  {name}",
                                      xlabel=xlabel, explain=explain))
    if has_att:
        q = np.column_stack([s[f"q_{c}"] for c in "wxyz"])
        paths.append(draw_commands(out, s["att_t"], q, s["thrust"],
                                   title=f"Commands  -  {name}", xlabel=xlabel))
    return paths


# ---------------------------------------------------------------------------------- CLI

def main(target, out=None):
    """``mavadrc plot TARGET [--out DIR]``: a record folder or a .tlog; prints the PNG paths.

    A folder without controller.csv but with flight.tlog is drawn from the tlog.  Returns 0;
    raises SystemExit with a message for a target that is neither.
    """
    target = Path(target)
    try:
        if target.is_dir():
            if (target / "controller.csv").is_file():
                paths = plot_record(target, out)
            elif (target / "flight.tlog").is_file():
                paths = plot_tlog(target / "flight.tlog", out if out is not None else target)
            else:
                raise ValueError(f"{target} is not a flight record (no controller.csv or "
                                 "flight.tlog)")
        elif target.is_file() and target.suffix.lower() == ".tlog":
            paths = plot_tlog(target, out)
        elif not target.exists():
            raise FileNotFoundError(f"{target} does not exist")
        else:
            raise ValueError(f"{target} is neither a flight record folder nor a .tlog file")
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"mavadrc plot: {e}") from None
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(prog="python -m mavadrc.study.figures", description=main.__doc__)
    ap.add_argument("target", help="flight record folder or .tlog file")
    ap.add_argument("--out", help="folder for the PNGs (default: beside the input)")
    a = ap.parse_args()
    raise SystemExit(main(a.target, a.out))
