"""Reference trajectories: exact derivatives, geometry, thesis formulas, timing, validation."""

import math
from pathlib import Path

import numpy as np
import pytest

from mavadrc.mission.trajectories import (
    Circle,
    FigureEight,
    Hover,
    Land,
    Lissajous,
    Reference,
    Sequence,
    Spiral,
    Takeoff,
    Waypoints,
    by_name,
    list_names,
)

H = 1e-6  # finite-difference step (s); small so jerk steps at waypoint joins stay < TOL
TOL = 1e-5  # analytic vs central difference


def _file(given):
    """A trajectory file's reference, its table made in memory: positions and yaw of a 3-D
    curve every 0.25 s, or (``given``) random velocities and accelerations beside them."""
    from mavadrc.mission.trajectory_file import FileTrajectory, Table

    t = np.arange(41) * 0.25
    cols = {"t": t, "north": 2.0 * np.sin(0.7 * t), "east": np.cos(0.4 * t) - 1.0,
            "altitude": 2.0 + 0.5 * np.sin(1.1 * t), "yaw_deg": 50.0 * t}
    if given:
        rng = np.random.default_rng(3)
        for name in ("v_north", "v_east", "v_up", "a_north", "a_east", "a_up"):
            cols[name] = rng.normal(0.0, 1.0, t.size)
    return FileTrajectory(Table("<memory>", cols, np.arange(t.size) + 2, 1))


def _mission():
    """Takeoff, a waypoint leg, a finite hover and a landing: C2 everywhere, including joins."""
    return Sequence(
        [
            Takeoff([0.0, 0.0, 0.0], 3.0, speed=1.0, yaw=0.3),
            Waypoints([[0, 0, -3], [4, 3, -3], [4, 3, -5]], speed=1.5, yaw=0.3, dwell=1.0),
            Hover([4, 3, -5], yaw=0.3, duration=2.0),
            Land([4, 3, -5], speed=0.8, yaw=0.3),
        ]
    )


CASES = {
    "hover": lambda: Hover([1.0, -2.0, -3.0], yaw=2.0, duration=5.0),
    "circle_const_yaw_climb": lambda: Circle(
        4.0, 3.0, 2.0, center=(1.0, -1.0), climb_rate=0.4, yaw=0.7, phase=1.0
    ),
    "circle_tangent_ccw": lambda: Circle(10.0, 10.0, 1.0, yaw="tangent"),
    "circle_tangent_cw": lambda: Circle(2.0, 5.0, 3.0, yaw="tangent", clockwise=True, phase=-2.0),
    "circle_laps_tangent": lambda: Circle(3.0, 2.0, 1.0, yaw="tangent", laps=1.5),
    "thesis_spiral": lambda: by_name("thesis_spiral"),
    "thesis_spiral_pd": lambda: by_name("thesis_spiral_pd"),
    "spiral_reverse_tangent": lambda: Spiral(omega=-0.3, yaw="tangent"),
    "figure_eight_tangent": lambda: FigureEight(5.0, 12.0, 2.0, center=(3.0, 4.0), yaw="tangent"),
    "figure_eight_const": lambda: by_name("figure_eight"),
    "figure_eight_heading_tangent": lambda: FigureEight(4.0, 10.0, 2.0, b=1.5, heading=2.5,
                                                        yaw="tangent"),
    "figure_eight_vertical": lambda: by_name("figure_eight_vertical"),
    "figure_eight_vertical_heading": lambda: FigureEight(2.0, 8.0, 3.0, b=1.0, plane="vertical",
                                                         heading=-0.8, yaw=1.0, duration=20.0),
    "lissajous": lambda: Lissajous([2.0, 1.0, 0.5], [0.5, 1.2, 0.9], 2.0, center=(1.0, -2.0),
                                   phase=(0.3, -1.0, 2.0), yaw=-2.0, duration=25.0),
    "file_spline_yaw": lambda: _file(False),
    "file_given": lambda: _file(True),
    "waypoints_speed_yaws": lambda: Waypoints(
        [[0, 0, -1], [5, 0, -2], [5, 6, -2], [-1, 2, -4]],
        speed=2.0,
        yaw=[0.0, 3.0, -3.0, 1.0],
    ),
    "waypoints_tangent_dwell": lambda: Waypoints(
        [[0, 0, -1], [5, 0, -1], [5, 0, -3], [0, 5, -3]], speed=2.5, yaw="tangent", dwell=1.5
    ),
    "waypoints_durations": lambda: Waypoints(
        [[0, 0, -1], [2, 1, -1], [2, 1, -1], [0, 0, -2]], durations=[2.0, 1.0, 3.0]
    ),
    "takeoff": lambda: Takeoff([1.0, 2.0, 0.0], 5.0, duration=4.0, yaw=-1.0),
    "land": lambda: Land([1.0, 2.0, -5.0], speed=0.7),
    "mission_sequence": _mission,
}


def _interior_times(traj, n=400):
    end = min(traj.duration, 60.0)
    return np.linspace(2 * H, end - 2 * H, n)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


@pytest.mark.parametrize("name", sorted(CASES))
def test_derivatives_match_central_differences(name):
    traj = CASES[name]()
    t = _interior_times(traj)
    pos, vel, acc, yaw, yaw_rate = traj.sample_many(t)
    pos_p, vel_p, _, yaw_p, _ = traj.sample_many(t + H)
    pos_m, vel_m, _, yaw_m, _ = traj.sample_many(t - H)
    assert np.max(np.abs((pos_p - pos_m) / (2 * H) - vel)) < TOL
    assert np.max(np.abs((vel_p - vel_m) / (2 * H) - acc)) < TOL
    assert np.max(np.abs(_wrap(yaw_p - yaw_m) / (2 * H) - yaw_rate)) < TOL
    assert np.all(np.abs(yaw) <= np.pi)


@pytest.mark.parametrize("name", sorted(CASES))
def test_sample_many_agrees_with_sample(name):
    traj = CASES[name]()
    end = traj.duration if math.isfinite(traj.duration) else 30.0
    t = np.concatenate([[-3.0, 0.0], np.linspace(0.0, end + 2.0, 37), [end, end + 100.0]])
    many = traj.sample_many(t)
    for i, ti in enumerate(t):
        ref = traj.sample(float(ti))
        assert isinstance(ref, Reference)
        assert ref.pos.shape == ref.vel.shape == ref.acc.shape == (3,)
        assert ref.pos.dtype == np.float64
        np.testing.assert_array_equal(ref.pos, many[0][i])
        np.testing.assert_array_equal(ref.vel, many[1][i])
        np.testing.assert_array_equal(ref.acc, many[2][i])
        assert ref.yaw == many[3][i] and ref.yaw_rate == many[4][i]


SHIPPED = sorted(p.stem for p in (Path(__file__).resolve().parent.parent / "configs"
                                   / "missions").glob("*.yaml"))


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_missions_reference_is_the_same_one_time_at_a_time(name):
    """A flight samples its reference one time at a time (a fast path of its own); every
    shipped mission's reference, joins and the hold after its end included, is the one
    sampled many times at once (to 1e-12: a transit's polynomial, a matrix product, rounds an
    ulp differently for one row than for many)."""
    from mavadrc.mission.config import load_mission
    traj, phases = load_mission(Path(__file__).resolve().parent.parent / "configs" / "missions"
                                / f"{name}.yaml").build_trajectory(np.array([1.0, -2.0, 0.0]))
    joins = [t0 for t0, _ in phases]
    t = np.concatenate([[-1.0], joins, np.nextafter(joins, -np.inf),
                        np.random.default_rng(0).uniform(0.0, traj.duration, 300),
                        [traj.duration, traj.duration + 3.0]])
    many = traj.sample_many(t)
    for i, ti in enumerate(t):
        ref = traj.sample(float(ti))
        for got, want in zip((ref.pos, ref.vel, ref.acc, ref.yaw, ref.yaw_rate), many):
            np.testing.assert_allclose(got, want[i], rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(CASES))
def test_clamps_before_start_and_holds_after_end(name):
    traj = CASES[name]()
    before, at0 = traj.sample(-5.0), traj.sample(0.0)
    np.testing.assert_array_equal(before.pos, at0.pos)
    np.testing.assert_array_equal(before.vel, at0.vel)
    assert before.yaw == at0.yaw
    if math.isfinite(traj.duration):
        final = traj.sample(traj.duration)
        for late in (traj.duration + 1e-9, traj.duration + 50.0):
            ref = traj.sample(late)
            np.testing.assert_array_equal(ref.pos, final.pos)
            assert ref.yaw == final.yaw
            assert not np.any(ref.vel) and not np.any(ref.acc) and ref.yaw_rate == 0.0


@pytest.mark.parametrize(
    "speed, clockwise, yaw", [(2.0, False, None), (6.0, True, "tangent"), (10.0, False, "tangent")]
)
def test_circle_speed_radius_direction_and_tangent_yaw(speed, clockwise, yaw):
    r, center = 10.0, np.array([3.0, -4.0])
    c = Circle(r, speed, 7.0, center=center, yaw=yaw, clockwise=clockwise)
    pos, vel, acc, yaw_v, yaw_rate = c.sample_many(np.linspace(0.0, 40.0, 501))
    np.testing.assert_allclose(np.linalg.norm(pos[:, :2] - center, axis=1), r, rtol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(vel, axis=1), speed, rtol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), speed**2 / r, rtol=1e-13)
    np.testing.assert_array_equal(pos[:, 2], -7.0)
    # NED: a positive turn about z (down) goes north -> east, i.e. clockwise seen from above.
    rel = pos[:, :2] - center
    turn = rel[:, 0] * vel[:, 1] - rel[:, 1] * vel[:, 0]
    assert np.all(np.sign(turn) == (1.0 if clockwise else -1.0))
    if yaw == "tangent":
        heading = np.stack([np.cos(yaw_v), np.sin(yaw_v)], axis=1)
        np.testing.assert_allclose(heading * speed, vel[:, :2], atol=1e-12)
        np.testing.assert_allclose(yaw_rate, (1 if clockwise else -1) * speed / r, rtol=1e-12)
    else:
        assert np.all(yaw_v == 0.0) and np.all(yaw_rate == 0.0)


def test_circle_laps_climb_and_altitude_convention():
    c = Circle(5.0, 2.0, 3.0, climb_rate=0.5, laps=2, phase=0.4)
    assert c.duration == pytest.approx(2 * 2 * math.pi * 5.0 / 2.0, rel=1e-15)
    start, end = c.sample(0.0), c.sample(c.duration)
    np.testing.assert_allclose(end.pos[:2], start.pos[:2], atol=1e-12)
    np.testing.assert_allclose(start.pos[:2], 5.0 * np.array([math.cos(0.4), math.sin(0.4)]))
    assert start.pos[2] == -3.0  # altitude above ground is -z
    assert end.pos[2] == pytest.approx(-(3.0 + 0.5 * c.duration), rel=1e-14)
    assert start.vel[2] == -0.5  # climbing is negative z velocity


@pytest.mark.parametrize(
    "name, omega, z0", [("thesis_spiral", 0.5, 1.0), ("thesis_spiral_pd", 0.1, 0.0)]
)
def test_spiral_matches_thesis_formulas(name, omega, z0):
    """Sections 6.2-6.4: x = 10 cos(w t), y = 10 sin(w t), z_up = z0 + 0.1 t, psi = pi/6."""
    traj = by_name(name)
    for t in (0.0, 0.7, 3.0, 12.5, 47.0, 100.0):
        ref = traj.sample(t)
        w = omega
        np.testing.assert_allclose(
            ref.pos, [10 * math.cos(w * t), 10 * math.sin(w * t), -(z0 + 0.1 * t)], atol=1e-12
        )
        np.testing.assert_allclose(
            ref.vel, [-10 * w * math.sin(w * t), 10 * w * math.cos(w * t), -0.1], atol=1e-12
        )
        np.testing.assert_allclose(
            ref.acc, [-10 * w * w * math.cos(w * t), -10 * w * w * math.sin(w * t), 0.0], atol=1e-12
        )
        assert ref.yaw == pytest.approx(math.pi / 6, abs=1e-15)
        assert ref.yaw_rate == 0.0


@pytest.mark.parametrize("speed", [2.0, 4.0, 6.0, 8.0, 10.0])
def test_thesis_circle_at_the_pd_study_speeds(speed):
    traj = by_name("thesis_circle", speed=speed)
    w = speed / 10.0
    for t in (0.0, 1.0, 5.5, 20.0):
        ref = traj.sample(t)
        np.testing.assert_allclose(
            ref.pos, [10 * math.cos(w * t), 10 * math.sin(w * t), -1.0], atol=1e-12
        )
        assert np.linalg.norm(ref.vel) == pytest.approx(speed, rel=1e-13)
        assert ref.yaw == pytest.approx(math.pi / 6, abs=1e-15)


def test_figure_eight_is_a_closed_gerono_lemniscate():
    a, period, center = 6.0, 15.0, np.array([2.0, -1.0])
    f = FigureEight(a, period, 4.0, center=center)
    pos, vel, _, _, _ = f.sample_many(np.linspace(0.0, period, 2001))
    x, y = (pos[:, :2] - center).T
    np.testing.assert_allclose(x**4, a * a * (x * x - y * y), atol=1e-10)
    np.testing.assert_allclose(pos[-1], pos[0], atol=1e-12)
    np.testing.assert_allclose(pos[0, :2], center, atol=1e-15)
    assert np.max(x) == pytest.approx(a, rel=1e-6) and np.max(y) == pytest.approx(a / 2, rel=1e-6)
    speed = np.linalg.norm(vel, axis=1)
    assert np.min(speed) > 0.5 * a * 2 * math.pi / period  # never stops: tangent yaw is defined
    assert np.max(speed) == pytest.approx(math.sqrt(2) * a * 2 * math.pi / period, rel=1e-12)
    np.testing.assert_array_equal(pos[:, 2], -4.0)


def test_the_vertical_eight_is_neural_flys_and_a_lissajous():
    """figure_eight_vertical: north = 1.25 sin t, altitude = 2 + 0.75 sin 2t; any vertical eight
    is the Lissajous figure with rates w and 2w along its heading and up."""
    t = np.linspace(0.0, 2 * math.pi, 501)
    pos, vel, acc, yaw, _ = by_name("figure_eight_vertical").sample_many(t)
    np.testing.assert_allclose(pos[:, 0], 1.25 * np.sin(t), atol=1e-12)
    np.testing.assert_array_equal(pos[:, 1], 0.0)
    np.testing.assert_allclose(-pos[:, 2], 2.0 + 0.75 * np.sin(2 * t), atol=1e-12)
    np.testing.assert_allclose(-vel[:, 2], 1.5 * np.cos(2 * t), atol=1e-12)
    np.testing.assert_allclose(-acc[:, 2], -3.0 * np.sin(2 * t), atol=1e-12)
    assert not np.signbit(np.r_[pos[:, 1], vel[:, 1], acc[:, 1]]).any()  # no -0.0 east
    np.testing.assert_array_equal(yaw, 0.0)
    h, w = 0.6, 2 * math.pi / 9.0
    eight = FigureEight(3.0, 9.0, 2.5, center=(1.0, 2.0), b=0.9, plane="vertical", heading=h)
    phase = [0.0 if math.cos(h) > 0 else math.pi, 0.0 if math.sin(h) > 0 else math.pi, 0.0]
    liss = Lissajous([3.0 * abs(math.cos(h)), 3.0 * abs(math.sin(h)), 0.9], [w, w, 2 * w], 2.5,
                     center=(1.0, 2.0), phase=phase)
    for got, want in zip(eight.sample_many(t), liss.sample_many(t)):
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_the_heading_turns_the_horizontal_eight():
    """With heading h the eight's long axis points to h: the same eight as heading 0, turned."""
    t = np.linspace(0.0, 10.0, 301)
    plain = FigureEight(4.0, 10.0, 2.0, b=1.5).sample_many(t)[0]
    turned = FigureEight(4.0, 10.0, 2.0, b=1.5, heading=math.pi / 2).sample_many(t)[0]
    np.testing.assert_allclose(turned[:, 0], -plain[:, 1], atol=1e-12)  # across: to the south
    np.testing.assert_allclose(turned[:, 1], plain[:, 0], atol=1e-12)  # along: to the east
    assert np.abs(plain[:, 1]).max() == pytest.approx(1.5, rel=1e-3)


POINTS = np.array([[0, 0, -2], [10, 0, -2], [10, 4, -5], [0, 0, -1], [3, 3, -3]], dtype=float)


@pytest.mark.parametrize("dwell", [0.0, 2.0])
def test_waypoints_pass_through_each_point_at_rest(dwell):
    wp = Waypoints(POINTS, speed=3.0, dwell=dwell)
    lengths = np.linalg.norm(np.diff(POINTS, axis=0), axis=1)
    np.testing.assert_allclose(wp.segment_durations, 1.875 * lengths / 3.0, rtol=1e-15)
    assert wp.duration == pytest.approx(np.sum(wp.segment_durations) + 3 * dwell, rel=1e-15)
    pos, vel, acc, _, _ = wp.sample_many(wp.arrival_times)
    np.testing.assert_allclose(pos, POINTS, atol=1e-12)
    np.testing.assert_allclose(vel, 0.0, atol=1e-12)
    np.testing.assert_allclose(acc, 0.0, atol=1e-12)
    if dwell:
        held = wp.sample_many(wp.arrival_times[1:-1] + 0.5 * dwell)
        np.testing.assert_allclose(held[0], POINTS[1:-1], atol=1e-12)
        assert not np.any(held[1])


def test_waypoints_are_hit_bit_exactly():
    """Arrival positions equal the given points exactly, not up to rounding (Land ends at z = 0)."""
    pts = np.random.default_rng(7).uniform(-50.0, 50.0, size=(40, 3))
    wp = Waypoints(pts, speed=4.0, dwell=0.5)
    np.testing.assert_array_equal(wp.sample_many(wp.arrival_times)[0], pts)
    np.testing.assert_array_equal(wp.sample(wp.duration + 1.0).pos, pts[-1])
    for a, b in zip(pts[:-1], pts[1:]):  # the end of a leg, where s = 1
        leg = Waypoints([a, b], speed=4.0)
        np.testing.assert_array_equal(leg.sample(leg.duration).pos, b)


def test_waypoints_straight_segments_and_exact_peak_speed():
    speed = 2.5
    wp = Waypoints(POINTS, speed=speed)
    starts = wp.arrival_times[:-1]
    mids = starts + 0.5 * wp.segment_durations
    _, vel_mid, _, _, _ = wp.sample_many(mids)
    np.testing.assert_allclose(np.linalg.norm(vel_mid, axis=1), speed, rtol=1e-12)
    t = np.linspace(0.0, wp.duration, 20001)
    pos, vel, _, _, _ = wp.sample_many(t)
    assert np.max(np.linalg.norm(vel, axis=1)) <= speed * (1 + 1e-12)
    assert np.max(np.linalg.norm(vel, axis=1)) == pytest.approx(speed, abs=1e-6)
    seg = np.clip(np.searchsorted(wp.arrival_times, t, side="right") - 1, 0, len(POINTS) - 2)
    d = POINTS[seg + 1] - POINTS[seg]
    off_line = np.linalg.norm(np.cross(pos - POINTS[seg], d), axis=1) / np.linalg.norm(d, axis=1)
    assert np.max(off_line) < 1e-12
    along = np.einsum("ij,ij->i", vel, d)
    assert np.all(along >= -1e-12)  # never backs up along a segment


def test_waypoints_acceleration_is_continuous():
    """No jumps at joins: consecutive samples differ by at most peak jerk * dt."""
    wp = Waypoints(POINTS, speed=3.0)
    dt = 1e-3
    _, _, acc, _, _ = wp.sample_many(np.arange(0.0, wp.duration, dt))
    lengths = np.linalg.norm(np.diff(POINTS, axis=0), axis=1)
    peak_jerk = np.max(60.0 * lengths / wp.segment_durations**3)  # |q'''| <= 60 on [0, 1]
    assert np.max(np.linalg.norm(np.diff(acc, axis=0), axis=1)) <= peak_jerk * dt * 1.0001
    for t_join in wp.arrival_times[1:-1]:
        left, right = wp.sample(t_join - 1e-9).acc, wp.sample(t_join + 1e-9).acc
        assert np.linalg.norm(left - right) < 1e-6
        assert np.linalg.norm(left) < 1e-6


def test_waypoints_given_durations():
    wp = Waypoints(POINTS[:3], durations=[4.0, 2.0])
    np.testing.assert_array_equal(wp.arrival_times, [0.0, 4.0, 6.0])
    assert wp.duration == 6.0
    assert wp.speed is None


def test_waypoint_yaws_blend_the_short_way_round():
    yaws = [math.radians(170), math.radians(-170), 0.0]
    wp = Waypoints(POINTS[:3], speed=2.0, yaw=yaws)
    _, _, _, yaw_at, _ = wp.sample_many(wp.arrival_times)
    np.testing.assert_allclose(_wrap(yaw_at - yaws), 0.0, atol=1e-12)
    t = np.linspace(0.0, wp.arrival_times[1], 101)[1:-1]
    _, _, _, yaw, rate = wp.sample_many(t)
    assert np.all(rate > 0)  # 170 deg -> 190 deg: 20 deg through north-south, not 340 back
    assert np.all(np.abs(yaw) >= math.radians(170) - 1e-12)


def test_waypoint_tangent_yaw_faces_each_leg_and_turns_in_the_dwell():
    pts = [[0, 0, -1], [5, 0, -1], [5, 0, -3], [5, 5, -3]]  # north, straight down, east
    wp = Waypoints(pts, speed=2.0, yaw="tangent", dwell=1.0)
    leg_start = wp.arrival_times[:-1] + np.array([0.0, 1.0, 1.0])  # after each interior dwell
    _, _, _, yaw, rate = wp.sample_many(leg_start + 0.5 * wp.segment_durations)
    np.testing.assert_allclose(yaw, [0.0, 0.0, math.pi / 2], atol=1e-12)  # vertical leg keeps 0
    np.testing.assert_array_equal(rate, 0.0)
    mid_turn = wp.sample(wp.arrival_times[2] + 0.5)  # halfway through the dwell at point 2
    assert mid_turn.yaw == pytest.approx(math.pi / 4, abs=1e-12)
    assert mid_turn.yaw_rate == pytest.approx(1.875 * (math.pi / 2) / 1.0, rel=1e-12)
    np.testing.assert_allclose(mid_turn.pos, pts[2], atol=1e-12)


def test_waypoint_tangent_yaw_with_a_vertical_first_leg_faces_the_first_horizontal_leg():
    wp = Waypoints([[0, 0, 0], [0, 0, -3], [0, 4, -3]], speed=1.0, yaw="tangent")
    _, _, _, yaw, rate = wp.sample_many(np.linspace(0.0, wp.duration, 50))
    np.testing.assert_allclose(yaw, math.pi / 2, atol=1e-15)
    np.testing.assert_array_equal(rate, 0.0)
    straight_up = Waypoints([[1, 1, 0], [1, 1, -3]], speed=1.0, yaw="tangent")
    assert straight_up.sample(1.0).yaw == 0.0  # no horizontal leg at all: north


def test_waypoint_tangent_turn_across_south_takes_the_short_way():
    a, b = math.radians(170), math.radians(-170)
    p1 = 5.0 * np.array([math.cos(a), math.sin(a), 0.0])
    p2 = p1 + 5.0 * np.array([math.cos(b), math.sin(b), 0.0])
    wp = Waypoints([[0, 0, 0], p1, p2], speed=1.0, yaw="tangent", dwell=2.0)
    t = np.linspace(wp.arrival_times[1], wp.arrival_times[1] + 2.0, 51)[1:-1]
    _, _, _, yaw, rate = wp.sample_many(t)
    assert np.all(rate > 0.0)  # 170 -> 190 deg, not 340 deg back through north
    assert np.all(np.abs(yaw) >= a - 1e-12)


def test_takeoff_and_land_are_vertical_and_reach_their_ends():
    to = Takeoff([2.0, -3.0, -0.1], 4.0, speed=1.2)
    end = to.sample(to.duration)
    np.testing.assert_allclose(end.pos, [2.0, -3.0, -4.0], atol=1e-15)
    _, vel, _, _, _ = to.sample_many(np.linspace(0, to.duration, 4001))
    assert np.all(vel[:, :2] == 0.0) and np.all(vel[:, 2] <= 0.0)
    assert np.max(-vel[:, 2]) == pytest.approx(1.2, rel=1e-6)
    land = Land([2.0, -3.0, -4.0], speed=0.5)
    assert land.duration == pytest.approx(1.875 * 4.0 / 0.5, rel=1e-15)
    down = land.sample(land.duration)
    assert down.pos[2] == 0.0 and not np.any(down.vel)
    assert Takeoff([0, 0, 0], 2.0, duration=3.0).duration == 3.0


def test_sequence_is_continuous_at_joins_and_chains_time():
    seq = _mission()
    assert seq.duration == pytest.approx(sum(p.duration for p in seq.parts), rel=1e-15)
    np.testing.assert_allclose(seq.start_times[1:], np.cumsum([p.duration for p in seq.parts])[:-1])
    for k, t_join in enumerate(seq.start_times[1:]):
        left, right = seq.sample(t_join - 1e-9), seq.sample(t_join)
        assert np.linalg.norm(left.pos - right.pos) < 1e-8
        np.testing.assert_array_equal(right.pos, seq.parts[k + 1].sample(0.0).pos)
    np.testing.assert_array_equal(seq.sample(seq.duration + 10).pos, [4.0, 3.0, 0.0])


def test_sequence_with_circle_laps_and_open_ended_tail():
    start = [10.0, 0.0, -5.0]
    seq = Sequence(
        [
            Takeoff([10.0, 0.0, 0.0], 5.0, speed=1.0),
            Circle(10.0, 4.0, 5.0, laps=3, clockwise=True),
            Hover(start),
        ]
    )
    assert math.isinf(seq.duration)
    t_circle = seq.start_times[1] + 0.25 * seq.parts[1].duration
    ref = seq.sample(t_circle)
    assert np.linalg.norm(ref.vel) == pytest.approx(4.0, rel=1e-12)
    np.testing.assert_allclose(seq.sample(1e6).pos, start, atol=1e-12)


def test_sequence_refuses_jumps_and_open_ended_middles():
    with pytest.raises(ValueError, match="jump"):
        Sequence([Hover([0, 0, -1], duration=1.0), Hover([0, 0, -2], duration=1.0)])
    jumpy = Sequence(
        [Hover([0, 0, -1], duration=1.0), Hover([0, 0, -2], duration=1.0)], join_tol=math.inf
    )
    assert jumpy.sample(1.5).pos[2] == -2.0
    with pytest.raises(ValueError, match=r"parts\[0\]"):
        Sequence([Hover([0, 0, -1]), Hover([0, 0, -1], duration=1.0)])
    with pytest.raises(ValueError, match="parts"):
        Sequence([])


def test_by_name_lists_and_overrides():
    assert set(list_names()) == {
        "hover",
        "thesis_circle",
        "thesis_spiral_pd",
        "thesis_spiral",
        "figure_eight",
        "figure_eight_vertical",
    }
    for name in list_names():
        ref = by_name(name).sample(1.0)
        assert np.all(np.isfinite(ref.pos))
    assert by_name("thesis_circle", speed=8.0).speed == 8.0
    assert by_name("thesis_spiral", omega=0.2).omega == pytest.approx(0.2)
    with pytest.raises(ValueError, match="name"):
        by_name("thesis_square")
    with pytest.raises(ValueError, match="colour"):
        by_name("hover", colour="red")


NAN = float("nan")
BAD = [
    (lambda: Circle(0.0, 2.0, 1.0), "radius"),
    (lambda: Circle(-1.0, 2.0, 1.0), "radius"),
    (lambda: Circle(NAN, 2.0, 1.0), "radius"),
    (lambda: Circle(5.0, 0.0, 1.0), "speed"),
    (lambda: Circle(5.0, -2.0, 1.0), "speed"),
    (lambda: Circle(5.0, math.inf, 1.0), "speed"),
    (lambda: Circle(5.0, 2.0, -3.0), "altitude"),
    (lambda: Circle(5.0, 2.0, NAN), "altitude"),
    (lambda: Circle(5.0, 2.0, 1.0, center=(0, 0, 0)), "center"),
    (lambda: Circle(5.0, 2.0, 1.0, yaw="north"), "yaw"),
    (lambda: Circle(5.0, 2.0, 1.0, yaw=NAN), "yaw"),
    (lambda: Circle(5.0, 2.0, 1.0, duration=0.0), "duration"),
    (lambda: Circle(5.0, 2.0, 1.0, laps=-1), "laps"),
    (lambda: Circle(5.0, 2.0, 1.0, laps=1, duration=3.0), "laps"),
    (lambda: Circle(5.0, 2.0, 1.0, climb_rate=math.inf), "climb_rate"),
    (lambda: Circle(5.0, "2", 1.0), "speed"),
    (lambda: Spiral(omega=0.0), "omega"),
    (lambda: Spiral(radius=-10.0), "radius"),
    (lambda: Spiral(z0=NAN), "altitude"),
    (lambda: FigureEight(0.0, 10.0, 1.0), "a"),
    (lambda: FigureEight(5.0, -10.0, 1.0), "period"),
    (lambda: FigureEight(5.0, 10.0, 1.0, b=0.0), "b"),
    (lambda: FigureEight(5.0, 10.0, 1.0, plane="sideways"), "plane"),
    (lambda: FigureEight(5.0, 10.0, 1.0, plane="vertical", yaw="tangent"), "tangent"),
    (lambda: FigureEight(5.0, 10.0, 1.0, plane="vertical", b=1.5), "altitude"),
    (lambda: FigureEight(5.0, 10.0, 1.0, heading=NAN), "heading"),
    (lambda: Lissajous([1.0, -1.0, 0.0], [1.0, 1.0, 1.0], 2.0), "a"),
    (lambda: Lissajous([1.0, 1.0, 0.0], [1.0, 1.0], 2.0), "omega"),
    (lambda: Lissajous([1.0, 1.0, 0.0], [1.0, -1.0, 1.0], 2.0), "omega"),
    (lambda: Lissajous([1.0, 1.0, 3.0], [1.0, 1.0, 1.0], 2.0), "altitude"),
    (lambda: Lissajous([1.0, 1.0, 0.0], [1.0, 1.0, 1.0], 2.0, yaw="tangent"), "yaw"),
    (lambda: Lissajous([1.0, 1.0, 0.0], [1.0, 1.0, 1.0], 2.0, phase=[0, NAN, 0]), "phase"),
    (lambda: Hover([0, 0, NAN]), "position"),
    (lambda: Hover([0, 0]), "position"),
    (lambda: Hover([0, 0, -1], duration=-1.0), "duration"),
    (lambda: Waypoints([[0, 0, -1]], speed=1.0), "points"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, NAN]], speed=1.0), "points"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], speed=0.0), "speed"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], speed=-1.0), "speed"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]]), "speed"),
    (lambda: Waypoints([[0, 0, -1], [0, 0, -1]], speed=1.0), "points"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], durations=[0.0]), "durations"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], durations=[1.0, 2.0]), "durations"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], speed=1.0, dwell=-1.0), "dwell"),
    (lambda: Waypoints([[0, 0, -1], [1, 0, -1]], speed=1.0, yaw=[0.0, 1.0, 2.0]), "yaw"),
    (lambda: Takeoff([0, 0, 0], -2.0, speed=1.0), "altitude"),
    (lambda: Takeoff([0, 0, 0], 2.0), "duration"),
    (lambda: Takeoff([0, 0, 0], 2.0, speed=NAN), "speed"),
    (lambda: Land([0, 0, 0], speed=1.0), "from_pos"),
    (lambda: Land([0, 0, -3], speed=0.0), "speed"),
]


@pytest.mark.parametrize("make, param", BAD, ids=[f"{i}-{p}" for i, (_, p) in enumerate(BAD)])
def test_bad_parameters_raise_value_error_naming_the_parameter(make, param):
    with pytest.raises(ValueError, match=rf"\b{param}\b"):
        make()


def test_bad_times_raise():
    with pytest.raises(ValueError, match=r"\bt\b"):
        Hover([0, 0, -1]).sample(NAN)
    with pytest.raises(ValueError, match=r"\bt\b"):
        Hover([0, 0, -1]).sample_many(np.zeros((2, 2)))


def test_transit_accel_times_the_run_up_into_a_segment_that_starts_at_speed(tmp_path):
    """x500_gusts' figure eight starts at 1.9 m/s at the hover point: the transit into it is
    timed for the change of velocity at ``transit_accel`` (1 m/s^2 there: twice as long as at
    the default 2, half the peak acceleration); a bad value names the file, line and field."""
    from mavadrc.mission.config import load_mission
    from sim.yamlio import ConfigError

    def transit(accel):
        text = ("name: m\nvehicle: x500\ncontroller: {type: pd}\ntrajectory:\n"
                "  - takeoff: {altitude: 3}\n"
                "  - figure_eight: {a: 6, period: 20, altitude: 3, duration: 20}\n"
                "  - land: {}\ntransit_speed: 2.0\n"
                + ("" if accel is None else f"transit_accel: {accel}\n"))
        path = tmp_path / "m.yaml"
        path.write_text(text)
        traj, phases = load_mission(path).build_trajectory(np.zeros(3))
        i = [name for _, name in phases].index("transit to figure_eight")
        t0, t1 = phases[i][0], phases[i + 1][0]
        acc = traj.sample_many(np.linspace(t0, t1, 400))[2]
        return t1 - t0, np.linalg.norm(acc, axis=1).max()

    (slow, a_default), (long, a_gentle) = transit(None), transit(1.0)
    assert slow == pytest.approx(2.5 * 6 * 2 * math.pi / 20 * math.sqrt(2) / 2.0, rel=0.02)
    assert long == pytest.approx(2 * slow)
    assert a_gentle == pytest.approx(a_default / 2, rel=0.05)
    with pytest.raises(ConfigError) as e:
        transit(0)
    assert "transit_accel" in str(e.value) and "m.yaml:9" in str(e.value)


@pytest.mark.parametrize("path", sorted((Path(__file__).parent.parent / "configs" / "missions")
                                        .glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_mission_asks_no_step_of_the_feed_forward(path):
    """The reference a mission builds is continuous in position, velocity and acceleration
    across every phase boundary: a step in the acceleration is a step in the feed-forward,
    which a vehicle whose tilt follows late answers off its track (leaving the spiral of
    ``thesis_spiral_wind``, 2.5 m/s^2 toward its centre, the transit to the hover used to
    drop it to 0 at once)."""
    from mavadrc.mission.config import load_mission

    traj, phases = load_mission(path).build_trajectory(np.zeros(3))
    for start, name in phases[1:]:
        pos, vel, acc = traj.sample_many(np.array([start - 1e-7, start + 1e-7]))[:3]
        assert np.linalg.norm(pos[1] - pos[0]) < 1e-5, (name, pos)
        assert np.linalg.norm(vel[1] - vel[0]) < 1e-4, (name, vel)
        assert np.linalg.norm(acc[1] - acc[0]) < 1e-3, (name, acc)


def test_a_transit_leaving_a_turn_starts_with_the_turns_acceleration():
    """The transit out of a segment that ends turning begins with that segment's acceleration
    and still reaches the next one's start at its position, velocity and acceleration."""
    from mavadrc.mission.config import Transit

    target = Hover([4.0, 1.0, -2.0]).sample(0.0)
    leg = Transit([0.0, 0.0, -2.0], [0.0, 5.0, 0.0], 0.0, target, 2.0, acc0=[2.5, 0.0, 0.0])
    pos, vel, acc = leg.sample_many(np.array([0.0, leg.duration]))[:3]
    assert acc[0] == pytest.approx([2.5, 0.0, 0.0], abs=1e-9)
    assert vel[0] == pytest.approx([0.0, 5.0, 0.0], abs=1e-9)
    assert pos[1] == pytest.approx(target.pos, abs=1e-9)
    assert vel[1] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert acc[1] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    # the default still starts from no acceleration
    rest = Transit([0.0, 0.0, -2.0], [0.0, 5.0, 0.0], 0.0, target, 2.0)
    assert rest.sample(0.0).acc == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
