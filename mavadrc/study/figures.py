"""Figures of a flight, from a flight record folder or from any .tlog.

    path3d.png       3-D path (north, east, altitude) and its top view, against the reference
                     (and a simulator's true path, when the record has truth.csv)
    error.png        position error per axis (north, east, altitude) and its 3-D norm (and the
                     true position's, with truth.csv)
    disturbance.png  the observer's total disturbance estimate z3 per axis, and the truth if known
    commands.png     thrust and attitude setpoint (roll, pitch, yaw in degrees); for a record also
                     the acceleration commanded against the one applied after the tilt/thrust limits

:func:`plot_record` reads a record folder (``controller.csv`` and ``summary.json``, see
:mod:`mavadrc.flight.record`); :func:`plot_tlog` reads any MAVLink telemetry log (ours, PX4's, QGC's)
and draws what it holds.  Figures are drawn with matplotlib's Agg canvas: no display is needed and
no pyplot state is touched.  Positions are NED; figures show altitude = -z, accelerations keep
NED axes and say so ("down").
"""

import json
import math
import os
import struct
from pathlib import Path

import numpy as np

from mavadrc.control.rotations import quats_to_euler
from mavadrc.flight import record
from mavadrc.flight.truth import reference_at

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


#: the least y span of an error (m) and of an acceleration (m/s^2) axes: below these a signal is
#: drawn flat (its size is in the box or the legend), not as rounding noise blown up to fill
MIN_SPAN_M = 1e-3
MIN_SPAN_ACC = 1e-2
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
                ax.axvspan(t0, t1, color="0.92", lw=0, zorder=0)
    if label_top:
        _phase_labels(axes[0], spans)


def _phase_labels(ax, spans):
    fig = ax.figure
    fig.get_layout_engine().execute(fig)  # the axes where they will be saved
    renderer = fig.canvas.get_renderer()
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


def _metres(x):
    """A length to three significant digits, in mm below 1 mm: '0.0340 m', '0.120 mm'."""
    x = float(x)
    if x != 0.0 and abs(x) < 1e-3:
        return f"{1e3 * x:#.3g} mm"
    return f"{x:#.3g} m"


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


def _stat_box(ax, err, label="RMS"):
    err = np.asarray(err, dtype=float)
    ok = np.isfinite(err)
    if not ok.any():
        return
    rms = math.sqrt(float(np.mean(err[ok] ** 2)))
    mx = float(np.max(np.abs(err[ok])))
    ax.text(0.99, 0.95, f"{label} {_metres(rms)}, max {_metres(mx)}", transform=ax.transAxes,
            ha="right", va="top", fontsize=8,
            bbox=dict(boxstyle="round,pad=0.25", fc="white", ec="0.8", alpha=0.9))


# ---------------------------------------------------------------------------------- drawings

def draw_path(out, pos, ref=None, title="Flight path", truth=None):
    """path3d.png: ``pos`` and ``ref`` are (N, 3) NED; ``ref`` may be None (vehicle path only);
    ``truth``: a simulator's true path (M, 3), drawn beside the estimate's, or None."""
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
    if truth is not None and len(truth):
        tr = np.asarray(truth, dtype=float)
        ax.plot(tr[:, 1], tr[:, 0], -tr[:, 2], color=_TRUTH_COLOR, lw=1.0,
                label="true (simulator)", zorder=1)
        top.plot(tr[:, 1], tr[:, 0], color=_TRUTH_COLOR, lw=1.0, label="true (simulator)",
                 zorder=1)
    if has_ref:
        ref = np.asarray(ref, dtype=float)
        ax.plot(ref[:, 1], ref[:, 0], -ref[:, 2], label="reference", zorder=3, **_REF_STYLE)
        top.plot(ref[:, 1], ref[:, 0], label="reference", zorder=3, **_REF_STYLE)
    ok = np.flatnonzero(np.isfinite(pos).all(axis=1))
    if ok.size:
        i0, i1 = ok[0], ok[-1]
        ax.scatter([east[i0]], [north[i0]], [alt[i0]], color="C2", marker="o", s=25, label="start")
        ax.scatter([east[i1]], [north[i1]], [alt[i1]], color="C3", marker="s", s=25, label="end")
        top.plot(east[i0], north[i0], "o", color="C2", ms=5, label="start")
        top.plot(east[i1], north[i1], "s", color="C3", ms=5, label="end")
        # north and east to the same scale, altitude stretched to stay readable
        pts = [pos[ok]] + ([ref[np.isfinite(ref).all(axis=1)]] if has_ref else [])
        allp = np.vstack(pts)
        span = np.ptp(allp, axis=0)
        horiz = max(span[0], span[1], 1e-3)
        # a level flight has a tiny altitude span: show at least 1 m (or a fifth of the width)
        zmin = max(1.0, 0.2 * horiz)
        if span[2] < zmin:
            mid = -0.5 * (allp[:, 2].max() + allp[:, 2].min())
            ax.set_zlim(mid - zmin / 2, mid + zmin / 2)
            span[2] = zmin
        ax.set_box_aspect((max(span[1], 1e-3) / horiz, max(span[0], 1e-3) / horiz,
                           float(np.clip(span[2] / horiz, 0.35, 1.0))))
    min_span(ax, MIN_SPAN_M, "xy")
    label_3d(ax, "east [m]", "north [m]", "altitude [m]")
    ax.set_title("3-D path")
    ax.legend(loc="upper left", fontsize=8)
    top.set_xlabel("east [m]")
    top.set_ylabel("north [m]")
    top.set_title("top view")
    min_span(top, MIN_SPAN_M, "xy")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(True, alpha=0.3)
    top.legend(fontsize=8)
    path = _save(fig, out, "path3d")
    return path


def draw_error(out, t, err, spans=(), stats=None, title="Position error", xlabel="time [s]",
               truth=None):
    """error.png: ``err`` = position - reference, (N, 3) NED; drawn as north, east, altitude.
    ``truth``: (t, err) of a simulator's true position against the reference, drawn thin
    beside the estimate's (the boxes stay the estimate's), or None.

    ``stats`` (optional) holds summary.json's rms/max figures; they are shown in the titles as
    the flight's official numbers, the boxes show the whole drawn span.
    """
    t = np.asarray(t, dtype=float)
    err = np.asarray(err, dtype=float)
    shown = np.column_stack([err[:, 0], err[:, 1], -err[:, 2]])  # altitude error = -(z error)
    norm = np.linalg.norm(err, axis=1)
    fig = _figure("error")
    fig.suptitle(title)
    axes = fig.subplots(4, 1, sharex=True)
    names = ("north", "east", "altitude")
    if truth is not None:
        tt, et = (np.asarray(a, dtype=float) for a in truth)
        et = np.column_stack([et[:, 0], et[:, 1], -et[:, 2]])
        for k in range(3):
            axes[k].plot(tt, et[:, k], color=_TRUTH_COLOR, lw=0.8, alpha=0.8,
                         label="true (simulator)" if k == 0 else None)
        axes[3].plot(tt, np.linalg.norm(et, axis=1), color=_TRUTH_COLOR, lw=0.8, alpha=0.8)
    for k in range(3):
        ax = axes[k]
        ax.plot(t, shown[:, k], color=_COLORS[k], lw=1.0,
                label="estimate" if k == 0 and truth is not None else None)
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel(f"{names[k]} error [m]")
        min_span(ax, MIN_SPAN_M)
        _stat_box(ax, shown[:, k])
    axes[3].plot(t, norm, color="k", lw=1.0)
    axes[3].set_ylabel("3-D error [m]")
    axes[3].set_ylim(bottom=0.0)
    _stat_box(axes[3], norm)
    axes[-1].set_xlabel(xlabel)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    if truth is not None:
        axes[0].legend(fontsize=8, loc="upper left")
    _shade_phases(list(axes), list(spans))
    if stats and stats.get("rms_error_m") is not None:
        try:
            axes[3].set_title(f"summary.json: RMS {_metres(stats['rms_error_m'])}, "
                              f"max {_metres(stats['max_error_m'])}", fontsize=9, loc="left")
        except (TypeError, ValueError, KeyError):
            pass
    return _save(fig, out, "error")


def draw_disturbance(out, est=None, truth=None, note=None, title="Total disturbance",
                     xlabel="time [s]"):
    """disturbance.png: ``est`` and ``truth`` are 3 per-axis (t, value) pairs (NED) or None.

    With no estimate, ``note`` (e.g. "PD has no observer") is written in each axes.
    """
    fig = _figure("disturbance")
    fig.suptitle(title)
    axes = fig.subplots(3, 1, sharex=True)
    has_est = est is not None and any(_finite(v) for _, v in est)
    has_truth = truth is not None and any(_finite(v) for _, v in truth)
    for k in range(3):
        ax = axes[k]
        if has_truth:
            tt, vv = truth[k]
            ax.plot(tt, vv, color="k", ls="--", lw=1.1, label="true disturbance (simulator)")
        if has_est:
            te, ve = est[k]
            ax.plot(te, ve, color=_COLORS[k], lw=1.2, label="estimate z3 (observer)")
        else:
            ax.text(0.5, 0.5, note or "no disturbance estimate", transform=ax.transAxes,
                    ha="center", va="center", fontsize=12, color="0.3",
                    bbox=dict(boxstyle="round,pad=0.4", fc="white", ec="0.7"))
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel(f"{NED[k]} [m/s$^2$]")
        min_span(ax, MIN_SPAN_ACC)
        ax.grid(True, alpha=0.3)
    if has_est or has_truth:
        axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel(xlabel)
    return _save(fig, out, "disturbance")


def draw_commands(out, t, q, thrust, acc=None, spans=(), title="Commands", xlabel="time [s]"):
    """commands.png: thrust (0..1) and the attitude setpoint ``q`` (N, 4) as roll/pitch/yaw.

    ``acc`` = (t, acc_cmd (N, 3), acc_applied (N, 3)) adds a column per NED axis, with the
    samples where the limits changed the command shaded.
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
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_ylabel("roll, pitch [deg]")
    ax.legend(loc="upper right", fontsize=8)
    ax = left[2]
    ax.plot(t, eul[:, 2], color="C2", lw=1.0)
    ax.set_ylabel("yaw [deg]")
    left[-1].set_xlabel(xlabel)
    if acc is not None:
        ta, cmd, app = (np.asarray(a, dtype=float) for a in acc)
        limited = False
        for k in range(3):
            ax = right[k]
            ax.plot(ta, cmd[:, k], color="0.2", ls="--", lw=1.0, label="commanded")
            ax.plot(ta, app[:, k], color=_COLORS[k], lw=1.1, label="applied (after limits)")
            lim = np.abs(cmd[:, k] - app[:, k]) > 1e-6
            if lim.any():
                limited = True
                ax.fill_between(ta, cmd[:, k], app[:, k], where=lim, color="C3", alpha=0.25,
                                lw=0)
            ax.set_ylabel(f"{NED[k]} acc [m/s$^2$]")
            ax.axhline(0.0, color="0.5", lw=0.6)
        from matplotlib.patches import Patch

        handles = right[0].get_legend_handles_labels()[0]
        if limited:
            handles.append(Patch(color="C3", alpha=0.25, label="limited (tilt/thrust)"))
        right[0].legend(handles=handles, loc="upper right", fontsize=8)
        right[-1].set_xlabel(xlabel)
    axes = list(left) + list(right)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    _shade_phases(list(left), list(spans))
    if len(right):
        _shade_phases(list(right), list(spans))
    return _save(fig, out, "commands")


# ---------------------------------------------------------------------------------- records

def draw_link(out, t, dt, age=None, spans=(), title="Link", xlabel="time [s]"):
    """link.png: the interval between the samples the controller stepped on and, where the
    clocks were synchronised (TIMESYNC), each sample's age: gaps, a slow stream and latency show
    here."""
    t = np.asarray(t, dtype=float)
    have_age = age is not None and _finite(age)
    fig = _figure("link")
    fig.suptitle(title)
    axes = fig.subplots(2 if have_age else 1, 1, sharex=True, squeeze=False)[:, 0]
    axes[0].plot(t, 1e3 * np.asarray(dt, dtype=float), ".", ms=2, color="C0")
    axes[0].set_ylabel("sample interval [ms]")
    axes[0].set_ylim(bottom=0.0)
    if have_age:
        axes[1].plot(t, 1e3 * np.asarray(age, dtype=float), ".", ms=2, color="C1")
        axes[1].set_ylabel("sample age [ms]")
    axes[-1].set_xlabel(xlabel)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    _shade_phases(list(axes), list(spans))
    return _save(fig, out, "link")


def _cols(table, names, n):
    return np.column_stack([table.get(c, np.full(n, math.nan)) for c in names])


def plot_record(folder, out=None):
    """Draws the four figures of a flight record folder into ``out`` (default: the folder)."""
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
    elif controller and controller.upper() != "PD":
        note = f"no observer estimate (z3) in the record ({controller})"
    else:
        note = "PD has no observer"
    paths.append(draw_disturbance(
        out, est=[(t, z3[:, k]) for k in range(3)] if _finite(z3) else None,
        truth=[(t, truth[:, k]) for k in range(3)] if _finite(truth) else None, note=note,
        title=_title(summary, "Total disturbance acceleration"), xlabel=xlabel))

    q = _cols(table, ["q_w", "q_x", "q_y", "q_z"], n)
    acc = (t, _cols(table, [f"acc_cmd_{a}" for a in ax3], n),
           _cols(table, [f"acc_applied_{a}" for a in ax3], n))
    paths.append(draw_commands(out, t, q, table.get("thrust", np.full(n, math.nan)), acc, spans,
                               title=_title(summary, "Commands"), xlabel=xlabel))
    if "dt" in table and _finite(table["dt"]):
        paths.append(draw_link(out, t, table["dt"], table.get("sample_age"), spans,
                               title=_title(summary, "Samples"), xlabel=xlabel))
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
    """
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
        paths.append(draw_disturbance(out, est, truth, title=f"Total disturbance  -  {name}",
                                      xlabel=xlabel))
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
