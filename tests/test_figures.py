"""Figures from a synthetic flight record and a synthetic .tlog (mavadrc.study.figures)."""

import json
import math
import os
import re

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink loads a dialect: speak MAVLink 2

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.image import imread  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from mavadrc.study import figures

from mavadrc.flight import record  # noqa: E402
from mavadrc.flight.truth import TRUTH_COLUMNS  # noqa: E402

N = 400
DT = 0.02
R, ALT, OMEGA = 5.0, 10.0, 2 * math.pi / 8.0
T_US0 = 1_700_000_000_000_000  # tlog stamps: Unix time in microseconds


def _expected_px(name):
    w, h = figures.SIZES[name]
    return round(h * figures.DPI), round(w * figures.DPI)


def _check_png(path, size_name):
    assert path.is_file(), path
    assert path.stat().st_size > 10_000, (path, path.stat().st_size)
    img = imread(path)
    assert img.shape[:2] == _expected_px(size_name), (path, img.shape)
    assert img.shape[2] in (3, 4)
    assert float(np.std(img[..., :3])) > 0.01  # not a blank canvas


def _circle(t):
    """Reference circle and a vehicle off it by a known error, NED."""
    ref = np.column_stack([R * np.cos(OMEGA * t), R * np.sin(OMEGA * t), np.full_like(t, -ALT)])
    err = np.column_stack([0.1 * np.sin(3 * t), 0.05 * np.cos(2 * t), np.full_like(t, 0.02)])
    return ref, ref + err, err


def _write_record(folder, controller="ADRC"):
    rec = record.FlightRecord(folder, mission_text="name: circle\n")
    t = np.arange(N) * DT
    ref, pos, err = _circle(t)
    for i, ti in enumerate(t):
        yaw = OMEGA * ti + math.pi / 2
        q = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        cmd = [2.0 * math.sin(ti), -2.5 * math.cos(ti), -0.5]
        applied = [min(max(c, -2.0), 2.0) for c in cmd]  # the tilt limit clips the east axis
        dist = [0.3 * math.sin(0.5 * ti), 0.2, -0.1 * math.cos(ti)]
        z3 = [d + 0.01 for d in dist] if controller != "PD" else [math.nan] * 3
        row = {"t": float(ti), "phase": "takeoff" if i < 50 else ("land" if i > 350 else "mission"),
               "ref_yaw": float(yaw), "yaw": float(yaw), "thrust": 0.5 + 0.05 * math.sin(ti),
               "q_w": q[0], "q_x": q[1], "q_y": q[2], "q_z": q[3],
               "dt": DT * (3 if i == 200 else 1), "sample_age": 0.004 + 0.001 * (i % 3),
               "drag_x": 0.5, "drag_y": 0.5}
        for k, a in enumerate(record.AXES):
            row.update({f"ref_{a}": float(ref[i, k]), f"pos_{a}": float(pos[i, k]),
                        f"ref_v{a}": 0.0, f"ref_a{a}": 0.0, f"vel_{a}": 0.0,
                        f"z1_{a}": float(pos[i, k]), f"z2_{a}": 0.0, f"z3_{a}": z3[k],
                        f"v1_{a}": float(ref[i, k]), f"v2_{a}": 0.0,
                        f"acc_cmd_{a}": cmd[k], f"acc_applied_{a}": applied[k],
                        f"true_dist_{a}": dist[k]})
        rec.table.row([row[c] for c in record.COLUMNS])
    summary = {"controller": controller, "mission": "circle", "duration_s": float(t[-1]),
               "landed": True, **record.error_figures(t, ref, pos, settle_s=1.0)}
    rec.write_summary(summary)
    rec.close()
    return err


@pytest.fixture(scope="module")
def record_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("flight")
    _write_record(folder)
    return folder


@pytest.mark.slow
def test_plot_record_writes_four_figures(record_dir, tmp_path):
    paths = figures.plot_record(record_dir, out=tmp_path / "figs")
    names = sorted(p.name for p in paths)
    assert names == ["commands.png", "disturbance.png", "error.png", "link.png", "path3d.png"]
    for p in paths:
        _check_png(p, p.stem)


@pytest.mark.slow
def test_plot_record_pd_has_no_observer(tmp_path):
    _write_record(tmp_path, controller="PD")
    table = record.read_table(tmp_path / "controller.csv")
    assert np.isnan(table["z3_x"]).all()
    paths = figures.plot_record(tmp_path)  # into the record folder itself
    assert {p.parent for p in paths} == {tmp_path}
    _check_png(tmp_path / "disturbance.png", "disturbance")
    assert len(paths) == 5


def test_quat_to_euler_deg():
    r, p, y = np.radians([10.0, -20.0, 170.0])
    q = np.zeros(4)
    from mavadrc.control.rotations import euler_to_quat

    euler_to_quat(r, p, y, q)
    np.testing.assert_allclose(figures.quat_to_euler_deg(q[None, :])[0], [10.0, -20.0, 170.0],
                               atol=1e-9)


# ------------------------------------------------------------------------------------- tlog

def _write_tlog(path, with_position=True, companion=True, target=False, same_stamp=False):
    """Vehicle (1, 1) and companion (255, 190) frames; returns what was written.

    ``target`` adds the vehicle's POSITION_TARGET_LOCAL_NED (the reference circle).
    """
    veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    w = record.TlogWriter(path)
    t = np.arange(200) * DT
    ref, pos, _ = _circle(t)
    written = {"t": [], "pos": [], "ref": [], "thrust": [], "q": [], "z3": [], "truth": []}
    k = 0

    def put(mav, msg, ti):
        nonlocal k
        t_us = T_US0 + (0 if same_stamp else int(round(ti * 1e6)) + k)  # + 1 us per frame
        w.write(msg.pack(mav), t_us=t_us)
        k += 1
        return (t_us - T_US0) * 1e-6

    put(veh, mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3), 0.0)
    for i, ti in enumerate(t):
        ms = int(ti * 1000)
        if with_position:
            written["t"].append(put(
                veh, mavlink.MAVLink_local_position_ned_message(ms, *pos[i], 0.1, 0.2, 0.3), ti))
            written["pos"].append(pos[i])
        if target:
            put(veh, mavlink.MAVLink_position_target_local_ned_message(
                ms, 1, 0b110111111000, *ref[i], 0, 0, 0, 0, 0, 0, 0, 0), ti)
            written["ref"].append(ref[i])
        if not companion:
            continue
        yaw = OMEGA * ti
        q = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        thrust = 0.5 + 0.1 * math.sin(ti)
        put(gcs, mavlink.MAVLink_set_attitude_target_message(ms, 1, 1, 0b00000111, q, 0, 0, 0,
                                                             thrust), ti)
        written["q"].append(q)
        written["thrust"].append(thrust)
        z3 = [0.3 * math.sin(ti), -0.2, 0.1 * math.cos(ti)]
        for a, v in zip(record.AXES, z3):
            put(gcs, mavlink.MAVLink_named_value_float_message(ms, f"z3_{a}".encode(), v), ti)
        written["z3"].append(z3)
        truth = [0.3 * math.sin(ti) - 0.01, -0.19, 0.1 * math.cos(ti)]
        put(veh, mavlink.MAVLink_debug_vect_message(b"TRUE_DIST", ms * 1000, *truth), ti)
        written["truth"].append(truth)
    w.close()
    written["frames"] = w.frames
    return {k: np.asarray(v) if k != "frames" else v for k, v in written.items()}


@pytest.fixture(scope="module")
def tlog(tmp_path_factory):
    path = tmp_path_factory.mktemp("tlog") / "flight.tlog"
    return path, _write_tlog(path)


def test_tlog_series_reads_back_what_was_written(tlog):
    path, wr = tlog
    s = figures.tlog_series(path)
    f32 = np.float32
    assert int(s["vehicle"]) == 1
    assert float(s["t0"]) == pytest.approx(T_US0 * 1e-6)
    # first message: the heartbeat at T_US0; float64 Unix seconds resolve ~0.24 us
    np.testing.assert_allclose(s["pos_t"], wr["t"], rtol=0, atol=1e-6)
    for k, a in enumerate(record.AXES):
        np.testing.assert_array_equal(s[f"pos_{a}"], wr["pos"][:, k].astype(f32))
        np.testing.assert_array_equal(s[f"z3_{a}"], wr["z3"][:, k].astype(f32))
        np.testing.assert_array_equal(s[f"true_dist_{a}"], wr["truth"][:, k].astype(f32))
        assert s[f"z3_{a}_t"].size == len(wr["t"])
    np.testing.assert_array_equal(s["vel_y"], np.full(len(wr["t"]), f32(0.2)))
    np.testing.assert_array_equal(s["thrust"], wr["thrust"].astype(f32))
    for k, c in enumerate("wxyz"):
        np.testing.assert_array_equal(s[f"q_{c}"], wr["q"][:, k].astype(f32))
    assert s["ref_t"].size == 0  # the companion sent attitude targets only


def test_mavutil_reads_every_frame(tlog):
    """mavlogdump.py's way of reading: every frame written comes back, none as bad data."""
    path, wr = tlog
    conn = mavutil.mavlink_connection(str(path))
    types = {}
    while (m := conn.recv_match(blocking=False)) is not None:
        types[m.get_type()] = types.get(m.get_type(), 0) + 1
    conn.close()
    assert "BAD_DATA" not in types
    assert sum(types.values()) == wr["frames"] == 1 + 200 * 6
    assert types["LOCAL_POSITION_NED"] == types["SET_ATTITUDE_TARGET"] == 200
    assert types["NAMED_VALUE_FLOAT"] == 600


@pytest.mark.slow
def test_plot_tlog_and_main(tlog, tmp_path, capsys):
    path, _ = tlog
    paths = figures.plot_tlog(path, tmp_path)
    # no position target in the log: no error figure, vehicle path only
    assert sorted(p.name for p in paths) == ["commands.png", "disturbance.png", "path3d.png"]
    _check_png(tmp_path / "path3d.png", "path3d")
    _check_png(tmp_path / "disturbance.png", "disturbance")
    _check_png(tmp_path / "commands.png", "commands_attitude")
    out2 = tmp_path / "via_main"
    assert figures.main(path, out2) == 0
    printed = capsys.readouterr().out.split()
    assert sorted(printed) == sorted(str(out2 / p.name) for p in paths)


def test_plot_tlog_with_a_position_target_draws_the_error(tmp_path):
    path = tmp_path / "px4.tlog"
    wr = _write_tlog(path, companion=False, target=True)
    s = figures.tlog_series(path)
    for k, a in enumerate(record.AXES):
        np.testing.assert_array_equal(s[f"ref_{a}"], wr["ref"][:, k].astype(np.float32))
    assert s["att_t"].size == 0 and s["z3_x"].size == 0
    paths = figures.plot_tlog(path)  # beside the tlog
    assert sorted(p.name for p in paths) == ["error.png", "path3d.png"]
    _check_png(tmp_path / "error.png", "error")


def test_plot_tlog_refuses_a_log_without_positions(tmp_path):
    path = tmp_path / "hb.tlog"
    veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    w = record.TlogWriter(path)
    for i in range(5):
        w.write(mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3).pack(veh), T_US0 + i)
    w.close()
    with pytest.raises(ValueError, match=r"no LOCAL_POSITION_NED in .*hb\.tlog"):
        figures.plot_tlog(path, tmp_path)
    assert not list(tmp_path.glob("*.png"))


def test_tlog_time_falls_back_to_time_boot_ms(tmp_path):
    path = tmp_path / "flat.tlog"
    _write_tlog(path, same_stamp=True)
    s = figures.tlog_series(path)
    np.testing.assert_allclose(s["pos_t"], np.floor(np.arange(200) * DT * 1000) / 1000, atol=1e-9)


def test_main_rejects_other_targets(tmp_path):
    with pytest.raises(SystemExit, match="does not exist"):
        figures.main(tmp_path / "nope")
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(SystemExit, match="neither a flight record folder nor a .tlog"):
        figures.main(tmp_path / "notes.txt")
    with pytest.raises(SystemExit, match="not a flight record"):
        figures.main(tmp_path)
    summary = json.dumps({"controller": "ADRC"})
    (tmp_path / "summary.json").write_text(summary)
    with pytest.raises(SystemExit, match="not a flight record"):
        figures.main(tmp_path)


# ------------------------------------------------------------------------------------- legibility

@pytest.fixture
def drawn(monkeypatch, tmp_path):
    """The matplotlib Figure each drawing saves, by PNG name, laid out as saved."""
    figs = {}
    save = figures._save

    def keep(fig, out, name):
        figs[name] = fig
        return save(fig, out, name)

    monkeypatch.setattr(figures, "_save", keep)
    return figs


def _boxes(artists):
    renderer = artists[0].figure.canvas.get_renderer()
    return [a.get_window_extent(renderer) for a in artists]


def _overlap(a, b):
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_phase_names_are_all_written_and_none_overlaps(drawn, tmp_path):
    # a short takeoff beside a long name, then two more short phases: side by side they collide
    t = np.arange(0.0, 53.0, 0.05)
    spans = [(0.0, 3.8, "takeoff"), (3.8, 13.1, "transit to thesis_spiral"),
             (13.1, 32.2, "thesis_spiral"), (32.2, 38.4, "transit to hover"),
             (38.4, 40.4, "hover"), (40.4, 50.4, "land"), (50.4, 53.0, "touchdown")]
    figures.draw_error(tmp_path, t, np.zeros((t.size, 3)) + 0.01, spans)
    fig = drawn["error"]
    fig.canvas.draw()
    top = fig.axes[0]
    labels = [a for a in top.texts if a.get_text() in {name for _, _, name in spans}]
    assert sorted(a.get_text() for a in labels) == sorted(name for _, _, name in spans)
    boxes = _boxes(labels)
    for i in range(len(boxes)):
        for j in range(i):
            assert not _overlap(boxes[i], boxes[j]), (labels[i].get_text(), labels[j].get_text())
        assert boxes[i].y0 >= top.bbox.y1  # above the axes, not on the data


def test_small_errors_keep_their_digits_and_rounding_noise_draws_flat(drawn, tmp_path):
    t = np.arange(0.0, 10.0, 0.02)
    err = np.column_stack([0.0347 * np.sin(t), 1e-13 * t, np.full_like(t, -2e-4)])
    figures.draw_error(tmp_path, t, err)
    axes = drawn["error"].axes
    boxes = [next(a.get_text() for a in ax.texts if "RMS" in a.get_text()) for ax in axes[:3]]
    # no summary.json: the figures are the drawn samples', and say so
    assert boxes[0] == "every sample drawn: RMS 0.0240 m, max 0.0347 m"
    assert boxes[2] == "every sample drawn: RMS 0.200 mm, max 0.200 mm"  # not "RMS 0.000 m"
    lo, hi = axes[1].get_ylim()  # 1e-12 m of drift: a flat line, not a 1e-12 scale
    assert hi - lo >= figures.MIN_SPAN_M
    est = [(t, 3e-11 * t / 10.0)] * 3  # an estimate that is zero but for rounding
    figures.draw_disturbance(tmp_path, est, [(t, np.zeros_like(t))] * 3)
    for ax in drawn["disturbance"].axes:
        lo, hi = ax.get_ylim()
        assert hi - lo >= figures.MIN_SPAN_ACC


def test_the_path_figure_shows_the_reference_over_the_vehicle_and_its_labels_apart(drawn,
                                                                                    tmp_path):
    t = np.arange(0.0, 40.0, 0.02)
    ref, pos, _ = _circle(t)
    ref[:, 2] -= 0.1 * t  # a spiral: climbing 4 m
    pos[:, 2] -= 0.1 * t
    figures.draw_path(tmp_path, pos, ref)
    fig = drawn["path3d"]
    ax3, top = fig.axes
    assert not ax3.computed_zorder
    for ax in (ax3, top):
        z = {ln.get_label(): ln.get_zorder() for ln in ax.get_lines()}
        assert z["reference"] > z["vehicle"]
    fig.canvas.draw()
    zlabel, north = _boxes([ax3.zaxis.label, top.yaxis.label])
    assert not _overlap(zlabel, north)
    for ticks, (lo, hi) in ((ax3.get_xticks(), ax3.get_xlim()), (ax3.get_yticks(), ax3.get_ylim())):
        assert np.count_nonzero((ticks >= lo) & (ticks <= hi)) <= 6  # not crowded


def test_a_scenario_figure_names_each_controller_once_outside_the_panels(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    from mavadrc.study import report
    from mavadrc.fast.inprocess import L_DIST, L_POS, L_REF, L_REF_ACC, L_T, L_WRENCH, L_Z3

    t = np.arange(0.0, 12.0, 0.01)
    runs = []
    for k, (name, kind) in enumerate((("PD", "pd"), ("ADRC", "adrc"), ("LADRC", "ladrc"),
                                      ("PID", "pid"))):
        L = np.zeros((t.size, L_REF_ACC + 3))
        L[:, L_T] = t
        L[:, L_REF + 2] = L[:, L_POS + 2] = -1.0
        L[:, L_POS] = 1e-13 * k * t  # hovering, but for rounding
        L[:, L_Z3] = 3e-11 * k * t / 12.0
        L[:, L_WRENCH] = 0.3
        runs.append((name, kind, L))
    assert not runs[0][2][:, L_DIST].any()
    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    report._scenario_figure((str(tmp_path / "s.png"), "attitude step", 3.0, runs))
    (fig,) = kept
    fig.canvas.draw()
    (legend,) = fig.legends
    assert [x.get_text() for x in legend.get_texts()] == ["PD", "ADRC", "LADRC", "PID",
                                                          "reference"]
    box = legend.get_window_extent()
    assert not any(_overlap(box, ax.get_window_extent()) for ax in fig.axes)
    ax3, _, dist, inputs = fig.axes
    assert len(inputs.get_legend().get_texts()) == 4  # U1..U4 by line style, not 12 entries
    lo, hi = dist.get_ylim()
    assert hi - lo >= figures.MIN_SPAN_ACC
    lo, hi = ax3.get_xlim()
    assert hi - lo >= figures.MIN_SPAN_M
    plt.close(fig)


@pytest.mark.slow
def test_a_record_with_truth_draws_the_true_path_and_error_beside_the_estimates(drawn, tmp_path):
    """truth.csv (a simulator's true state): path3d.png and error.png draw it beside the
    estimate's, its error taken against the reference at the true samples' times."""
    _write_record(tmp_path)
    table = record.read_table(tmp_path / "controller.csv")
    t = table["t"][::4]
    ref = np.column_stack([table[f"ref_{a}"][::4] for a in record.AXES])
    off = np.array([0.3, -0.2, 0.1])  # the vehicle really 0.3 m north, 0.2 west, 0.1 lower
    w = record.TableWriter(tmp_path / "truth.csv", columns=TRUTH_COLUMNS, text=())
    for k in range(t.size):
        w.row([float(t[k]), *(ref[k] + off).tolist(), 0.0, 0.0, 0.0])
    w.close()
    figures.plot_record(tmp_path)
    top = drawn["path3d"].axes[1]
    true_line = next(ln for ln in top.get_lines() if ln.get_label() == "true (simulator)")
    assert np.allclose(true_line.get_xdata(), ref[:, 1] - 0.2)
    assert "vehicle (estimate)" in {ln.get_label() for ln in top.get_lines()}
    axes = drawn["error"].axes
    north = next(ln for ln in axes[0].get_lines() if ln.get_label() == "true (simulator)")
    assert np.allclose(north.get_ydata(), 0.3, atol=1e-6)
    alt = [ln for ln in axes[2].get_lines() if ln.get_color() == figures._TRUTH_COLOR][0]
    assert np.allclose(alt.get_ydata(), -0.1, atol=1e-6)  # altitude error: 0.1 m low
    norm = [ln for ln in axes[3].get_lines() if ln.get_color() == figures._TRUTH_COLOR][0]
    assert np.allclose(norm.get_ydata(), np.linalg.norm(off), atol=1e-6)


# ------------------------------------------------------------------------- a flight's own record

#: a short flight (lockstep, ~6 s of wall time): a takeoff, a lap of a 1 m circle in a breeze
#: with a drag model told, the landing; the error figures after 4 s and over the whole mission
SHORT_MISSION = """\
name: short circle
vehicle: crazyflie
controller:
  type: ladrc
  rate_hz: 100
  drag: [0.3, 0.3, 0.2]
trajectory:
  - takeoff: {altitude: 1.0, speed: 0.5}
  - circle: {radius: 1.0, speed: 1.5, laps: 1}
  - land: {speed: 0.5}
transit_speed: 2.0
wind: breeze_1ms
sim: {seed: 1}
logging: {settle_s: 4}
"""

_UNITS = {"m": 1.0, "mm": 1e-3}


def _rms_max(line):
    """(rms, max) in metres of a line 'window: RMS x u, max y u'."""
    m = re.search(r"RMS (\S+) (mm|m), max (\S+) (mm|m)$", line)
    assert m, line
    return float(m[1]) * _UNITS[m[2]], float(m[3]) * _UNITS[m[4]]


def _span_floor(label):
    return next((f for unit, f in figures.UNIT_FLOORS.items() if label.endswith(unit)), None)


def _check_floors(fig):
    """Every labelled axis of ``fig`` spans at least its unit's floor."""
    for ax in fig.axes:
        pairs = [(ax.get_ylabel(), ax.get_ylim()), (ax.get_xlabel(), ax.get_xlim())]
        if hasattr(ax, "get_zlim"):
            pairs.append((ax.get_zlabel(), ax.get_zlim()))
        for label, (lo, hi) in pairs:
            floor = _span_floor(label)
            if floor is not None:
                assert hi - lo >= floor * (1 - 1e-9), (label, lo, hi)


def _visible(line, renderer):
    """The part of ``line``'s bounding box inside its axes (None: none of it)."""
    from matplotlib.transforms import Bbox

    if not np.asarray(line.get_xdata()).size:
        return None
    return Bbox.intersection(line.get_window_extent(renderer), line.axes.bbox)


def _check_legends_off_the_data(fig):
    """No legend in any axes; the figure's legends clear of every axes (and so of its lines)."""
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        assert ax.get_legend() is None, ax.get_ylabel()
    for legend in fig.legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            assert not _overlap(box, ax.bbox), (ax.get_ylabel(), box, ax.bbox)
            for ln in figures._data_lines(ax) if ax.name != "3d" else []:
                seen = _visible(ln, renderer)
                assert seen is None or not _overlap(box, seen)


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    from mavadrc.cli.main import main as cli

    folder = tmp_path_factory.mktemp("lockstep")
    (folder / "short.yaml").write_text(SHORT_MISSION)
    assert cli(["fly", str(folder / "short.yaml"), "--lockstep", "--no-figures", "-q", "--out",
                str(folder / "runs")]) == 0
    (rec,) = (folder / "runs").iterdir()
    return rec


@pytest.mark.slow
def test_a_lockstep_flight_s_figures_print_its_summary_and_keep_off_the_data(
        flown, drawn, tmp_path, recwarn, caplog):
    import logging

    caplog.set_level(logging.WARNING, logger="matplotlib")
    summary = json.loads((flown / "summary.json").read_text())
    table = record.read_table(flown / "controller.csv")
    assert summary["settle_s"] == 4.0 and summary["after_settle"]["rms_error_m"] is not None
    paths = figures.plot_record(flown, out=tmp_path)
    assert sorted(p.name for p in paths) == ["commands.png", "disturbance.png", "error.png",
                                             "link.png", "path3d.png"]
    # nothing warned, nothing logged by matplotlib: none of it would have reached the console
    assert figures.caught == []
    assert not [str(w.message) for w in recwarn.list]
    assert not [r.getMessage() for r in caplog.records if r.name.startswith("matplotlib")]
    for fig in drawn.values():
        fig.canvas.draw()
        _check_floors(fig)
        _check_legends_off_the_data(fig)

    # error.png: summary.json's figures, each saying its window, on every panel
    axes = drawn["error"].axes
    for k, ax in enumerate(axes):
        (box,) = [x for x in ax.texts if "RMS" in x.get_text()]
        after, whole = box.get_text().split("\n")
        assert after.startswith("after 4 s (settle_s): ")
        assert whole.startswith("whole mission (scored steps): ")
        for line, fig in ((after, summary["after_settle"]), (whole, summary)):
            want = ((fig["rms_error_m"], fig["max_error_m"]) if k == 3 else
                    (fig["rms_error_xyz_m"][k], fig["max_error_xyz_m"][k]))
            assert _rms_max(line) == pytest.approx(want, rel=5e-3), (k, line)
        # the box over no curve
        renderer = drawn["error"].canvas.get_renderer()
        for ln in figures._data_lines(ax):
            seen = _visible(ln, renderer)
            assert seen is None or not _overlap(box.get_window_extent(renderer), seen)
        # settle_s marked; the touchdown, past the last scored step, hatched as not scored
        marks = [ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_gid() == figures.MARK
                 and ln.get_linestyle() == ":"]
        assert marks == [4.0]
        hatched = [p for p in ax.patches if p.get_hatch()]
        assert len(hatched) == 1
        assert hatched[0].get_x() == pytest.approx(summary["duration_s"])
    assert any("not scored in summary.json (touchdown)" in x.get_text()
               for x in drawn["error"].legends[0].get_texts())

    # disturbance.png: the truth less the drag the observers model, which z3 leaves out
    t = table["t"]
    axes = drawn["disturbance"].axes
    for k, a in enumerate(record.AXES):
        (truth,) = [ln for ln in axes[k].get_lines() if "less the drag" in ln.get_label()]
        c = table[f"drag_{a}"] if k < 2 else np.full(t.size, 0.2)
        np.testing.assert_allclose(truth.get_ydata(),
                                   table[f"true_dist_{a}"] + c * table[f"ref_v{a}"], atol=1e-9)
    assert "linear drag along the reference" in axes[0].get_title(loc="left")
    # the y axes from the flight in the air: the touchdown's push clipped, and said so
    air = (t >= summary["liftoff_s"]) & (t <= summary["duration_s"])
    for k, a in enumerate(record.AXES):
        lo, hi = axes[k].get_ylim()
        z3 = table[f"z3_{a}"]
        assert lo <= z3[air].min() and z3[air].max() <= hi
        if z3.min() < lo or z3.max() > hi:
            assert "clipped: z3" in (axes[k].get_title(loc="right")
                                     + axes[0].get_title(loc="left"))
    assert table["z3_z"].min() < axes[2].get_ylim()[0]  # the ground's push at the touchdown

    # path3d.png: the start a ring and the end a square, both drawn; the legend below
    top = drawn["path3d"].axes[1]
    start, end = (next(ln for ln in top.get_lines() if ln.get_label() == name)
                  for name in ("start", "end"))
    assert start.get_markersize() > end.get_markersize() and start.get_markerfacecolor() == "none"
    # link.png: lockstep ages are said to be periods
    assert "Lockstep" in drawn["link"].axes[1].get_title(loc="left")
    # commands.png: the accelerations' axes span the flight in the air too, the rest named
    right = [ax for ax in drawn["commands"].axes if "acc [m/s" in ax.get_ylabel()]
    assert len(right) == 3
    for k, a in enumerate(record.AXES):
        lo, hi = right[k].get_ylim()
        cmd = table[f"acc_cmd_{a}"]
        assert lo <= cmd[air].min() and cmd[air].max() <= hi
        if cmd.min() < lo or cmd.max() > hi:
            assert right[k].get_title(loc="right").startswith("clipped: commanded to ")


def test_a_hover_s_path_is_drawn_at_10_cm_with_its_start_and_end_both_seen(drawn, tmp_path,
                                                                         recwarn, caplog):
    import logging

    caplog.set_level(logging.WARNING, logger="matplotlib")
    t = np.arange(0.0, 10.0, 0.02)
    pos = np.column_stack([4e-4 * np.sin(t), 3e-4 * np.cos(t), -np.clip(t, 0, 1)]) + [2.0, -1.0,
                                                                                     0.0]
    pos[-1] = pos[0]  # landed where it took off
    figures.draw_path(tmp_path, pos, pos + 1e-4)
    fig = drawn["path3d"]
    fig.canvas.draw()
    assert not recwarn.list and not caplog.records  # "Ignoring fixed y limits ..." was logged
    ax3, top = fig.axes
    (x0, x1), (y0, y1) = top.get_xlim(), top.get_ylim()
    assert x1 - x0 >= figures.MIN_PATH_SPAN_M and y1 - y0 >= figures.MIN_PATH_SPAN_M
    assert 0.5 * (x0 + x1) == pytest.approx(-1.0, abs=1e-3)  # centred on the path (east)
    assert 0.5 * (y0 + y1) == pytest.approx(2.0, abs=1e-3)
    assert x1 - x0 == pytest.approx(y1 - y0)  # one scale
    lo, hi = ax3.get_xlim()
    assert hi - lo >= figures.MIN_PATH_SPAN_M
    for ax in (ax3, top):
        start, end = (next(ln for ln in ax.get_lines() if ln.get_label() == name)
                      for name in ("start", "end"))
        # on the same spot, the end's square inside the start's ring: both show
        assert start.get_markersize() >= 2 * end.get_markersize()
        assert start.get_markerfacecolor() == "none"
    _check_legends_off_the_data(fig)
    _check_floors(fig)


def test_no_axis_is_drawn_on_floating_point_noise(drawn, tmp_path):
    t = np.arange(0.0, 20.0, 0.01)
    yaw = 1e-8 * np.sin(3 * t)  # an x500's yaw setpoint: 0 but for rounding
    q = np.column_stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)])
    tiny = np.full((t.size, 3), 1e-12)
    figures.draw_commands(tmp_path, t, q, np.full(t.size, 0.5), (t, tiny, tiny))
    figures.draw_link(tmp_path, t, np.full(t.size, 0.01), np.full(t.size, 2e-9))
    for name in ("commands", "link"):
        drawn[name].canvas.draw()
        _check_floors(drawn[name])
    (yaw_ax,) = [ax for ax in drawn["commands"].axes if ax.get_ylabel() == "yaw [deg]"]
    lo, hi = yaw_ax.get_ylim()
    assert hi - lo >= figures.MIN_SPAN_DEG


def test_ages_below_zero_are_called_the_clock_offset_s_error(drawn, tmp_path):
    t = np.arange(0.0, 10.0, 0.01)
    age = np.where(np.arange(t.size) % 4 == 0, 0.0012, -0.0009)
    summary = {"config": {"lockstep": False}, "link": {"rtt_ms_median": 0.4},
               "command_line": ["fly", "hover.yaml"]}
    figures.draw_link(tmp_path, t, np.full(t.size, 0.01), age,
                      age_note=figures._age_note(summary))
    note = drawn["link"].axes[1].get_title(loc="left").replace("\n", " ")
    assert "half a round trip (0.20 ms here)" in note
    assert "750 of 1000 below 0 (down to -0.90 ms): the clock offset's error" in note


def test_the_windows_summary_json_leaves_out(tmp_path):
    """The identification's doublets (its segment but the hold before the hand-over) and what
    follows the last scored step are not scored; the after-settle figures start at settle_s."""
    t = np.arange(0.0, 60.0, 0.01)
    spans = [(0.0, 4.0, "takeoff"), (4.0, 28.0, "identify"), (28.0, 55.0, "figure_eight"),
             (55.0, 59.0, "land"), (59.0, 59.99, "touchdown")]
    summary = {"rms_error_m": 0.1, "duration_s": 58.7, "settle_s": 30.0}
    score = figures.scoring(t, spans, summary)
    assert score["settle_s"] == 30.0
    assert score["unscored"] == [(4.0, 25.0, "identification"),
                                 (58.7, pytest.approx(59.99), "touchdown")]
    assert figures.scoring(t, spans, {"controller": "pd"}) is None  # no figures to print
    lines = figures.score_lines({**summary, "after_settle": None, "rms_error_xyz_m": [0.05] * 3,
                                 "max_error_xyz_m": [0.2] * 3, "max_error_m": 0.3}, 0)
    assert lines == ["after 30 s (settle_s): not reached",
                     "whole mission (scored steps): RMS 0.0500 m, max 0.200 m"]
