"""Trajectories from CSV files (the ``file:`` segment): the spline's derivatives, given columns
used as they are, every refusal naming the file, line, row and column, and flights of the file,
Lissajous and vertical figure-eight segments."""

import io
import math
from pathlib import Path

import numpy as np
import pytest

from mavadrc.mission.config import load_mission
from mavadrc.mission.trajectory_file import (CHECKS_PER_ROW, FileTrajectory, TrajectoryFileError,
                                             read_table)
from sim.yamlio import ConfigError

ROOT = Path(__file__).resolve().parent.parent
HEADER = "t,north,east,altitude"


def write_csv(path, columns, rows, comment=None):
    """A trajectory file: ``columns`` (names) and ``rows`` (tuples of numbers or text)."""
    lines = [] if comment is None else [f"# {comment}"]
    lines.append(",".join(columns))
    lines += [",".join(v if isinstance(v, str) else repr(float(v)) for v in row) for row in rows]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def sine_rows(step=0.05, end=8.0):
    """north = sin t, east = 0.5 cos 2t, altitude = 2 + 0.3 sin t, sampled every ``step``."""
    t = np.linspace(0.0, end, round(end / step) + 1)
    return t, [(ti, math.sin(ti), 0.5 * math.cos(2 * ti), 2.0 + 0.3 * math.sin(ti)) for ti in t]


def sine_truth(t):
    pos = np.stack([np.sin(t), 0.5 * np.cos(2 * t), -(2.0 + 0.3 * np.sin(t))], axis=1)
    vel = np.stack([np.cos(t), -np.sin(2 * t), -0.3 * np.cos(t)], axis=1)
    acc = np.stack([-np.sin(t), -2.0 * np.cos(2 * t), 0.3 * np.sin(t)], axis=1)
    return pos, vel, acc


def test_the_spline_gives_a_sines_velocity_and_acceleration(tmp_path):
    """Positions only, every 0.05 s: between and at the rows, the position is the sine's within
    1e-7 m, the velocity within 1e-5 m/s and the acceleration within 1e-3 m/s^2 (1e-4 away
    from the first and last half second, where the spline has data on one side only)."""
    _, rows = sine_rows()
    traj = FileTrajectory(read_table(write_csv(tmp_path / "s.csv", HEADER.split(","), rows)))
    assert traj.duration == 8.0
    t = np.linspace(0.0, 8.0, 3201)
    pos, vel, acc, yaw, yaw_rate = traj.sample_many(t)
    want = sine_truth(t)
    inner = (t > 0.5) & (t < 7.5)
    assert np.abs(pos - want[0]).max() < 1e-7
    assert np.abs(vel - want[1]).max() < 1e-5
    assert np.abs(acc - want[2]).max() < 1e-3
    assert np.abs(acc - want[2])[inner].max() < 1e-4
    assert np.all(yaw == 0.0) and np.all(yaw_rate == 0.0)


def test_positions_only_fly_scipys_quintic_spline_itself(tmp_path):
    """With no derivative columns, the pieces between rows are the interpolating quintic
    spline, not merely through its values at the rows."""
    from scipy.interpolate import make_interp_spline

    rng = np.random.default_rng(1)
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.3, 30)])
    xyz = np.cumsum(rng.normal(0.0, 0.05, (31, 3)), axis=0) + [0.0, 0.0, 2.0]
    traj = FileTrajectory(read_table(write_csv(tmp_path / "r.csv", HEADER.split(","),
                                               np.column_stack([t, xyz]))))
    spline = make_interp_spline(t, xyz * [1.0, 1.0, -1.0], k=5)
    q = np.linspace(0.0, t[-1], 997)
    pos, vel, acc = traj.sample_many(q)[:3]
    assert np.abs(pos - spline(q)).max() < 1e-9
    assert np.abs(vel - spline.derivative(1)(q)).max() < 1e-7
    assert np.abs(acc - spline.derivative(2)(q)).max() < 1e-5


def test_given_columns_are_used_as_they_are(tmp_path):
    """Velocity, acceleration and yaw columns (which need not agree with the positions) are
    the reference's at each row; between rows all three stay continuous (C2 pieces)."""
    rng = np.random.default_rng(2)
    n = 12
    t = np.arange(n) * 0.2
    cols = ["t", "north", "east", "altitude", "v_north", "v_east", "v_up", "a_north", "a_east",
            "a_up", "yaw_deg"]
    data = np.column_stack([t, rng.normal(0, 1, (n, 2)), 2 + rng.uniform(0, 1, n),
                            rng.normal(0, 1, (n, 3)), rng.normal(0, 2, (n, 3)),
                            np.linspace(0.0, 90.0, n)])
    traj = FileTrajectory(read_table(write_csv(tmp_path / "g.csv", cols, data)))
    pos, vel, acc, yaw, _ = traj.sample_many(t)
    up = np.array([1.0, 1.0, -1.0])
    np.testing.assert_allclose(pos, data[:, 1:4] * up, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vel, data[:, 4:7] * up, rtol=0, atol=1e-12)
    np.testing.assert_allclose(acc, data[:, 7:10] * up, rtol=0, atol=1e-10)
    np.testing.assert_allclose(yaw, np.radians(data[:, 10]), rtol=0, atol=1e-12)
    h = 1e-8  # across each interior row: no step in position, velocity or acceleration
    for i in range(1, n - 1):
        before, after = traj.sample(t[i] - h), traj.sample(t[i] + h)
        assert np.abs(after.pos - before.pos).max() < 1e-6
        assert np.abs(after.vel - before.vel).max() < 1e-5
        assert np.abs(after.acc - before.acc).max() < 1e-3


def test_given_velocities_set_the_acceleration_through_their_own_spline(tmp_path):
    """Positions and velocities of the sine (no acceleration column): the acceleration is the
    derivative of the velocities' spline, the sine's within 1e-3 m/s^2."""
    t, rows = sine_rows(step=0.1)
    _, vel, acc = sine_truth(t)
    cols = HEADER.split(",") + ["v_north", "v_east", "v_up"]
    data = np.column_stack([np.array(rows), vel * [1.0, 1.0, -1.0]])
    traj = FileTrajectory(read_table(write_csv(tmp_path / "v.csv", cols, data)))
    got = traj.sample_many(t)
    np.testing.assert_allclose(got[1], vel, rtol=0, atol=1e-12)
    assert np.abs(got[2] - acc).max() < 1e-3


def test_the_yaw_turns_the_short_way_between_rows(tmp_path):
    t = np.arange(8) * 0.5
    yaw = [150.0, 170.0, -170.0, -150.0, -130.0, -110.0, -90.0, -70.0]
    rows = [(ti, 0.0, 0.0, 1.0, y) for ti, y in zip(t, yaw)]
    traj = FileTrajectory(read_table(write_csv(tmp_path / "y.csv", HEADER.split(",") + ["yaw_deg"],
                                               rows)))
    _, _, _, psi, rate = traj.sample_many(np.linspace(0.0, t[-1], 200))
    assert np.all(rate > 0.0)  # 40 deg/s, never the long way round
    assert rate.mean() == pytest.approx(math.radians(40.0), rel=0.02)
    assert np.all(np.abs(psi) <= math.pi)


def test_the_rows_frame_is_the_waypoints_frame(tmp_path):
    """north, east, altitude from the takeoff spot, as a waypoints segment's points: the
    reference of a file segment goes through the same NED points, offset by the takeoff spot
    the mission is placed at."""
    rows = [(0.0, 1.0, 2.0, 3.0), (1.0, 1.5, 2.0, 3.0), (2.0, 2.0, 2.5, 3.5)]
    cols = HEADER.split(",") + ["v_north", "v_east", "v_up", "a_north", "a_east", "a_up"]
    csv = write_csv(tmp_path / "w.csv", cols, [r + (0.0,) * 6 for r in rows])
    text = ("name: m\nvehicle: crazyflie\ntrajectory:\n  - takeoff: {altitude: 3}\n"
            "  - SEGMENT\n  - land: {}\n")
    origin = np.array([10.0, -5.0, 0.0])
    got = {}
    for kind, seg, after in (
            ("file", f"file: {{path: {csv.name}}}", 0.0),
            # the waypoints leg starts where the takeoff ends, 3 m above the spot: sampled
            # where it reaches its first point (sqrt 5 m at a peak 1 m/s)
            ("waypoints", "waypoints: {points: [[1, 2, 3], [1.5, 2, 3], [2, 2.5, 3.5]], "
                          "speed: 1}", 1.875 * math.sqrt(5.0))):
        (tmp_path / "m.yaml").write_text(text.replace("SEGMENT", seg))
        traj, phases = load_mission(tmp_path / "m.yaml").build_trajectory(origin)
        start = {name: t0 for t0, name in phases}[kind]
        got[kind] = traj.sample(start + after).pos
    np.testing.assert_allclose(got["file"], origin + [1.0, 2.0, -3.0], atol=1e-12)
    np.testing.assert_allclose(got["waypoints"], origin + [1.0, 2.0, -3.0], atol=1e-12)


# --- in a mission ------------------------------------------------------------------------------

EIGHT = ("name: {kind}\nvehicle: crazyflie\ncontroller: {{type: ladrc}}\ntrajectory:\n"
         "  - takeoff: {{altitude: 2.0, speed: 0.5}}\n  - {segment}\n  - land: {{speed: 0.5}}\n"
         "wind: calm\n")

MISSION = """name: m
vehicle: crazyflie
trajectory:
  - takeoff: {altitude: 1.0}
  - file: {path: PATH}
  - land: {}
safety: {geofence: {north: [-3, 3], east: [-3, 3]}, altitude: {max: 4}, max_speed: 2}
"""


def mission_with(tmp_path, rows, columns=HEADER, path="tr.csv", extra=""):
    """Load a mission (m.yaml, its file segment on line 5) flying ``rows`` written to ``path``
    under tmp_path; returns the Mission or raises."""
    csv = tmp_path / path
    csv.parent.mkdir(parents=True, exist_ok=True)
    csv.write_text(columns + "\n" + "\n".join(rows) + "\n")
    (tmp_path / "m.yaml").write_text(MISSION.replace("PATH", path).replace("{path", "{" + extra
                                                                           + "path"))
    return load_mission(tmp_path / "m.yaml")


def line_rows(step=0.1, speed=0.5, n=10):
    return [f"{step * i:.2f},{speed * step * i:.4f},0,1" for i in range(n)]


def refused(tmp_path, rows, **kw):
    with pytest.raises(ConfigError) as e:
        mission_with(tmp_path, rows, **kw)
    text = str(e.value)
    assert "m.yaml:5: trajectory[1].file.path: " in text, text
    return text


def test_a_file_segment_flies_from_the_mission_folder(tmp_path):
    """The path is read from the mission's folder, wherever the process runs; a transit joins
    the file's first row as it joins any segment, or a jump with join: direct."""
    rows = [r.replace(",0,1", ",0.5,1") for r in line_rows()]  # 0.5 m east of the climb's top
    (tmp_path / "elsewhere").mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp_path / "elsewhere")
        m = mission_with(tmp_path, rows, path="sub/tr.csv")
    assert Path(m.segments[1][1]["path"]) == tmp_path / "sub" / "tr.csv"
    traj, phases = m.build_trajectory()
    names = [name for _, name in phases]
    assert names == ["takeoff", "transit to file", "file", "transit to land", "land"]
    start = {name: t0 for t0, name in phases}["file"]
    assert traj.sample(start).pos == pytest.approx([0.0, 0.5, -1.0], abs=1e-12)
    traj, phases = mission_with(tmp_path, rows, extra="join: direct, ").build_trajectory()
    assert [name for _, name in phases][:2] == ["takeoff", "file"]


@pytest.mark.parametrize("case, rows, columns, expect", [
    ("t not increasing", ["0,0,0,1", "0.1,0,0,1", "0.1,0,0,1"] + line_rows()[3:], HEADER,
     "tr.csv:4: row 3, column t: times must increase strictly (t = 0.1 after 0.1 on row 2)"),
    ("t going back", line_rows()[:5] + ["0.3,0.2,0,1"] + line_rows()[6:], HEADER,
     "tr.csv:7: row 6, column t: times must increase strictly"),
    ("first t", ["0.5,0,0,1"] + line_rows()[6:], HEADER,
     "tr.csv:2: row 1, column t: the first row must be at t = 0"),
    ("NaN", line_rows()[:4] + ["0.40,nan,0,1"] + line_rows()[5:], HEADER,
     "tr.csv:6: row 5, column north: must be finite (got nan)"),
    ("infinite", line_rows()[:4] + ["0.40,0.2,0,inf"] + line_rows()[5:], HEADER,
     "tr.csv:6: row 5, column altitude: must be finite (got inf)"),
    ("not a number", line_rows()[:2] + ["0.20,0.1,x,1"] + line_rows()[3:], HEADER,
     "tr.csv:4: row 3, column east: not a number ('x')"),
    ("missing column", [r.rsplit(",", 1)[0] for r in line_rows()], "t,north,east",
     "tr.csv:1: header: column 'altitude' missing (required: t, north, east, altitude)"),
    ("misspelt column", line_rows(), "t,north,esat,altitude",
     "tr.csv:1: header: column 'esat' is not a trajectory column; did you mean 'east'?"),
    ("half a group", [r + ",0.5" for r in line_rows()], HEADER + ",v_north",
     "tr.csv:1: header: column 'v_east' missing: v_north is given, so give all of v_north, "
     "v_east, v_up (or none)"),
    ("short row", line_rows()[:3] + ["0.30,0.15,0"] + line_rows()[4:], HEADER,
     "tr.csv:5: row 4: 3 values for 4 columns"),
    ("too few rows", line_rows()[:4], HEADER,
     "tr.csv: 4 data rows; the spline that estimates the derivatives the file does not give "
     "needs at least 6"),
])
def test_a_bad_file_is_refused_naming_its_line_row_and_column(tmp_path, case, rows, columns,
                                                             expect):
    assert expect in refused(tmp_path, rows, columns=columns)


def test_a_file_outside_the_missions_limits_is_refused_at_the_row(tmp_path):
    # too fast: 2.5 m/s in rows of positions (the spline's velocity) and in given velocities
    text = refused(tmp_path, line_rows(speed=2.5))
    assert "tr.csv:2: row 1, column north, east, altitude (their spline's velocity): speed " \
           "2.50 m/s exceeds safety.max_speed 2 m/s" in text
    rows = [r + ",2.5,0,0" for r in line_rows(speed=2.5)]
    text = refused(tmp_path, rows, columns=HEADER + ",v_north,v_east,v_up")
    assert "tr.csv:2: row 1, column v_north, v_east, v_up: speed 2.50 m/s exceeds " \
           "safety.max_speed 2 m/s" in text
    # outside the geofence (north 3 m): the row where it leaves
    rows = line_rows(speed=1.0, n=40)
    text = refused(tmp_path, rows)
    assert "tr.csv:32: row 31, column north: north 3.00 m" not in text  # 3.00 is inside
    assert "tr.csv:32: between rows 31 and 32 (t = 3.0" in text and "column north: north 3.0" \
        in text and "outside the geofence [-3, 3] m" in text
    rows = [f"{0.1 * i:.2f},0,{-0.15 * i:.2f},1" for i in range(30)]  # west, 1.5 m/s
    text = refused(tmp_path, rows)
    assert "tr.csv:22: between rows 21 and 22 (t = 2.0" in text
    assert "column east: east -3.0" in text and "outside the geofence [-3, 3] m" in text
    text = refused(tmp_path, [f"{i:.1f},0,0,{1 + 0.4 * i:.2f}" for i in range(10)])
    assert "tr.csv:9: between rows 8 and 9 (t = 7.6" in text  # 1 + 0.4 t reaches 4 m at 7.5 s
    assert "column altitude: altitude 4.0" in text and "outside the limits [-1, 4] m" in text
    # a horizontal acceleration the 35 deg tilt limit cannot give (6.9 m/s^2)
    rows = [f"{0.1 * i:.2f},{0.5 * (0.1 * i) ** 2 * 8:.4f},0,1" for i in range(6)]
    text = refused(tmp_path, rows)
    assert "tr.csv:2: row 1, column north, east (their spline's acceleration): horizontal " \
           "acceleration 8.00 m/s^2 exceeds 6.87 m/s^2 (g tan(tilt_max_deg)" in text


def test_the_earliest_breach_is_the_one_named(tmp_path):
    """A file that goes too fast and then leaves the geofence is refused for its speed, one
    that leaves the geofence and then goes too fast for the geofence."""
    def speeding_up(at):  # north at 1 m/s, then from ``at`` s up to 2.5 m/s at 1 m/s^2
        t = np.arange(60) * 0.1
        ramp = np.clip(t - at, 0.0, 1.5)
        north = t + 0.5 * ramp ** 2 + 1.5 * np.maximum(t - at - 1.5, 0.0)
        return [f"{ti:.1f},{x:.6f},0,1" for ti, x in zip(t, north)]

    text = refused(tmp_path, speeding_up(1.0))  # over 2 m/s at 2 s, 2.5 m north
    assert "exceeds safety.max_speed" in text and "geofence" not in text
    assert "between rows 20 and 21" in text or "row 21," in text
    text = refused(tmp_path, speeding_up(3.0))  # at 3 m north at 3 s, over 2 m/s at 4 s
    assert "outside the geofence" in text and "max_speed" not in text


def test_a_missing_file_and_a_yaw_given_twice_are_refused(tmp_path):
    (tmp_path / "track.csv").write_text(HEADER + "\n" + "\n".join(line_rows()) + "\n")
    (tmp_path / "m.yaml").write_text(MISSION.replace("PATH", "trak.csv"))
    with pytest.raises(ConfigError) as e:
        load_mission(tmp_path / "m.yaml")
    assert "m.yaml:5: trajectory[1].file.path: no such file" in str(e.value)
    assert "did you mean 'track.csv'?" in str(e.value)
    rows = [r + ",10" for r in line_rows()]
    with pytest.raises(ConfigError) as e:
        mission_with(tmp_path, rows, columns=HEADER + ",yaw_deg", extra="yaw_deg: 20, ")
    assert "file.yaw_deg: the file has a yaw_deg column" in str(e.value)
    traj, phases = mission_with(tmp_path, line_rows(), extra="yaw_deg: 90, ").build_trajectory()
    start = {name: t0 for t0, name in phases}["file"]
    assert traj.sample(start + 0.5).yaw == pytest.approx(math.pi / 2)


def test_comments_blank_lines_and_a_byte_order_mark_are_read(tmp_path):
    path = tmp_path / "c.csv"
    path.write_bytes(("\ufeff# made by hand\n\n" + HEADER + "\n# the first row\n"
                      + "\n".join(line_rows()) + "\n\n").encode("utf-8"))
    table = read_table(path)
    assert table.rows == 10 and table.lines[0] == 5 and table.lines[1] == 6
    assert table.where(1, "east") == f"{path}:6: row 2, column east"


def test_the_limits_are_checked_between_rows(tmp_path):
    """The spline can swing past the rows; the check looks between them too."""
    t = np.arange(10) * 1.0
    north = [0, 0, 0, 0, 2.9, 2.9, 0, 0, 0, 0]
    traj = FileTrajectory(read_table(write_csv(tmp_path / "o.csv", HEADER.split(","),
                                               [(ti, n, 0.0, 1.0) for ti, n in zip(t, north)])))
    q = np.linspace(0, 9, 9 * CHECKS_PER_ROW + 1)
    assert traj.sample_many(q)[0][:, 0].max() > 3.0  # the swing the rows do not show
    with pytest.raises(TrajectoryFileError, match=r"o\.csv:\d+: between rows \d and \d "
                                                  r".* column north: north 3\.\d\d m is outside"):
        traj.check_limits((-3, 3), (-3, 3), (-1, 4), 15.0, 100.0, max_accel_up=100.0)


@pytest.mark.parametrize("segment, expect", [
    ("figure_eight: {a: 1, period: 6, duration: 6, plane: vertcal}",
     "figure_eight.plane: must be one of horizontal, vertical (got 'vertcal'; did you mean "
     "'vertical'?)"),
    ("figure_eight: {a: 1, b: 1.5, period: 6, duration: 6, plane: vertical, altitude: 1}",
     "figure_eight: FigureEight: a vertical eight reaches b = 1.5 m below its altitude 1 m"),
    ("figure_eight: {a: 1, period: 6, duration: 6, heading_deg: 400}",
     "figure_eight.heading_deg: must be <= 360"),
    ("lissajous: {a: [1, -1, 0], omega: [1, 1, 1], duration: 6}",
     "lissajous.a: item 1 must be >= 0"),
    ("lissajous: {a: [1, 1, 0], omega: [1, 11, 1], duration: 6}",
     "lissajous.omega: each item must be <= 10"),
    ("lissajous: {a: [1, 1, 0], omega: [1, 1, 1], duration: 6, phase_deg: [0, 0, 500]}",
     "lissajous.phase_deg: each item must be within +-360"),
    ("lissajous: {a: [1, 1, 0], duration: 6}", "lissajous.omega: required field missing"),
    ("lissajous: {a: [1, 1, 0], omega: [1, 1, 1], duration: 6, yaw: tangent}",
     "lissajous.yaw: unknown key"),
])
def test_the_new_segments_keys_are_checked_in_the_mission(tmp_path, segment, expect):
    (tmp_path / "m.yaml").write_text(EIGHT.format(kind="m", segment=segment))
    with pytest.raises(ConfigError) as e:
        load_mission(tmp_path / "m.yaml")
    assert "m.yaml:6: trajectory[1]." in str(e.value) and expect in str(e.value), str(e.value)


def test_a_lissajous_segment_defaults_to_where_the_last_one_ended(tmp_path):
    (tmp_path / "m.yaml").write_text(EIGHT.format(kind="m", segment=(
        "lissajous: {a: [1, 0.5, 0.2], omega: [0.5, 1, 1.5], phase_deg: [0, 90, 0], "
        "center: [1, 0], duration: 10, yaw_deg: 45}")))
    traj, phases = load_mission(tmp_path / "m.yaml").build_trajectory()
    start = {name: t0 for t0, name in phases}["lissajous"]
    ref = traj.sample(start)
    assert ref.pos == pytest.approx([1.0, 0.5, -2.0], abs=1e-12)  # altitude: the takeoff's
    assert ref.yaw == pytest.approx(math.pi / 4)


# --- flights -----------------------------------------------------------------------------------


def _flown(mission_path):
    from mavadrc.fast.fly import fly_inprocess
    from mavadrc.fast.inprocess import L_POS, L_REF, L_T

    run = fly_inprocess(load_mission(mission_path))
    assert run.aborted is None
    t = run.log[:, L_T]
    err = np.linalg.norm(run.log[:, L_REF:L_REF + 3] - run.log[:, L_POS:L_POS + 3], axis=1)
    return run, t, err


def test_the_vertical_eight_flies_the_same_as_a_lissajous_and_as_a_file(tmp_path):
    """Neural-Fly's eight (two loops) as a vertical figure_eight, as the lissajous with its
    amplitudes and rates, and as a CSV of its positions every 0.05 s: the three flights agree
    (the lissajous exactly; the file within 0.1 mm: its spline's derivatives feed the law
    forward as the formula's do), and the LADRC safe defaults keep within 0.15 m of it
    (measured 0.113 m)."""
    t = np.linspace(0.0, 4 * math.pi, 252)
    write_csv(tmp_path / "eight.csv", HEADER.split(","),
              [(ti, 1.25 * math.sin(ti), 0.0, 2.0 + 0.75 * math.sin(2 * ti)) for ti in t])
    segments = {
        "figure_eight": "figure_eight: {a: 1.25, b: 0.75, period: 6.283185307179586, "
                        "plane: vertical, altitude: 2, duration: 12.566370614359172}",
        "lissajous": "lissajous: {a: [1.25, 0, 0.75], omega: [1, 0, 2], altitude: 2, "
                     "duration: 12.566370614359172}",
        "file": "file: {path: eight.csv}",
    }
    runs = {}
    for kind, segment in segments.items():
        path = tmp_path / f"{kind}.yaml"
        path.write_text(EIGHT.format(kind=kind, segment=segment))
        runs[kind] = _flown(path)
    from mavadrc.fast.inprocess import L_POS

    eight, t_log, err = runs["figure_eight"]
    start = {name: t0 for t0, name in eight.phases}["figure_eight"]
    on = (t_log >= start) & (t_log <= start + 4 * math.pi)
    assert err[on].max() < 0.15, err[on].max()
    np.testing.assert_array_equal(runs["lissajous"][0].log, eight.log)
    flown = runs["file"][0].log
    assert flown.shape == eight.log.shape
    assert np.abs(flown[:, L_POS:L_POS + 3] - eight.log[:, L_POS:L_POS + 3]).max() < 1e-4


def test_the_shipped_missions_of_the_new_segments_fly_within_bounds():
    """The trefoil read from its CSV (positions only, at 10 Hz) and Neural-Fly's vertical eight
    in a 1 m/s breeze, on the LADRC safe defaults: within 0.2 m and 0.15 m of the reference in
    the segment (measured 0.156 and 0.117 m), 0.12 and 0.09 m RMS (0.095, 0.072)."""
    for name, segment, worst, rms in (("trefoil_file", "file", 0.2, 0.12),
                                      ("vertical_figure_eight", "figure_eight", 0.15, 0.09)):
        run, t, err = _flown(ROOT / "configs" / "missions" / f"{name}.yaml")
        starts = [t0 for t0, _ in run.phases] + [run.duration]
        k = [n for _, n in run.phases].index(segment)
        on = (t >= starts[k]) & (t < starts[k + 1])
        assert err[on].max() < worst, (name, err[on].max())
        assert np.sqrt(np.mean(err[on] ** 2)) < rms, name


@pytest.mark.slow
def test_the_trefoil_file_flies_over_mavlink_and_its_record_flies_again(tmp_path):
    """``mavadrc fly trefoil_file --lockstep``: landed, within the fast path's bound, and the
    record's effective.yaml names the CSV by its full path, so it loads from the record's
    folder."""
    from mavadrc.fast.identify import flight_design_lag
    from mavadrc.flight.fly import fly

    mission = load_mission(ROOT / "configs" / "missions" / "trefoil_file.yaml")
    summary, folder = fly(mission, out=tmp_path, lockstep=True, progress=False,
                          stream=io.StringIO(), design_lag=flight_design_lag(mission, None))
    assert summary["landed"] and summary["aborted"] == []
    assert summary["missed_periods"] == 0
    assert summary["after_settle"]["max_error_m"] < 0.2
    again = load_mission(folder / "effective.yaml")
    kind, spec, _ = again.segments[1]
    assert kind == "file" and Path(spec["path"]).is_absolute()
    assert Path(spec["path"]).samefile(ROOT / "configs" / "trajectories" / "trefoil.csv")
