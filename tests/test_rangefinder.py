"""A downward range finder beside the height estimate (mavadrc.flight.rangefinder): the record says how
far the estimate strayed from it, and the supervisor ends the mission before a drifting
estimate flies the vehicle into the ground."""

import io

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from mavadrc.flight.fly import fly
from mavadrc.mission.config import load_mission
from mavadrc.flight.rangefinder import (CLEARANCE_GAP_M, CLEARANCE_HOLD_S, DOWN, REST_SAMPLES,
                                 RangeTrack, range_height, rangefinder_text)
from mavadrc.flight.record import read_table
from sim.yamlio import ConfigError

HOVER = """name: range hover
vehicle: crazyflie
controller: {type: ladrc, rate_hz: 100, input_lag: [0.13, 0.13, 0.05]}
trajectory:
  - takeoff: {altitude: 1.0, speed: 1.0}
  - hover: {duration: 12}
  - land: {speed: 0.6}
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
"""


def reading(cm, orientation=DOWN, lo=20, hi=4000, quality=0):
    return M.MAVLink_distance_sensor_message(0, lo, hi, cm, M.MAV_DISTANCE_SENSOR_LASER, 0,
                                             orientation, 0, signal_quality=quality)


def mission(tmp_path, sim, name="m.yaml"):
    path = tmp_path / name
    path.write_text(HOVER + f"sim: {sim}\n")
    return load_mission(path)


def test_a_reading_counts_looking_down_inside_its_span_and_is_taken_to_the_vertical():
    assert range_height(reading(150), 1.0) == pytest.approx(1.5)
    assert range_height(reading(150), 0.8) == pytest.approx(1.2)  # slant range, tilted
    assert range_height(reading(150, orientation=M.MAV_SENSOR_ROTATION_NONE), 1.0) is None
    assert range_height(reading(10), 1.0) is None  # under its minimum: the ground too near
    assert range_height(reading(4001), 1.0) is None  # past its maximum: nothing seen
    assert range_height(reading(150, quality=1), 1.0) is None  # marked invalid
    assert range_height(reading(150, quality=100), 1.0) == pytest.approx(1.5)
    assert range_height(reading(150), 0.4) is None  # tilted past 60 deg


def test_the_clearance_check_holds_its_time_and_needs_both_the_ground_near_and_the_gap():
    track = RangeTrack()
    for _ in range(5):
        track.at_rest(0.0, 0.05)  # the sensor mounted 5 cm up
    track.start()
    assert track.offset == pytest.approx(-0.05)
    # estimate (aligned) 0.95 + 0.05 = 1.0 m, the range finder 0.25 (gap 0.75): near and far apart
    assert track.clearance(10.0, 0.75, 0.25, 0.3, True) is None  # not yet held
    assert track.clearance(10.0 + CLEARANCE_HOLD_S - 0.01, 0.75, 0.25, 0.3, True) is None
    why = track.clearance(10.0 + CLEARANCE_HOLD_S, 0.75, 0.25, 0.3, True)
    assert "0.25 m above the ground" in why and "reads 1.00 m" in why
    fresh = RangeTrack()
    fresh.start()
    # low but agreeing (a landing, a low pass): nothing; far apart but high: nothing
    for t in np.arange(0, 2, 0.1):
        assert fresh.clearance(t, CLEARANCE_GAP_M - 0.05, 0.25 - CLEARANCE_GAP_M + 0.05, 0.3,
                               True) is None
        assert fresh.clearance(t, 1.0, 0.5, 0.3, True) is None
        assert fresh.clearance(t, 0.8, 0.2, 0.0, True) is None  # 0: not checked
        assert fresh.clearance(t, 0.8, 0.2, 0.3, False) is None  # not airborne
    # a gap that closes resets the hold
    assert fresh.clearance(5.0, 0.8, 0.2, 0.3, True) is None
    assert fresh.clearance(5.2, 0.1, 0.2, 0.3, True) is None
    assert fresh.clearance(5.4, 0.8, 0.2, 0.3, True) is None


def test_a_flight_taken_over_in_the_air_aligns_on_its_first_readings():
    """Taken over at 2 m, the estimate's origin is the takeover point: it reads 0 where the
    range finder reads 2.  The first readings align the two; until then nothing is recorded
    and no clearance is checked."""
    track = RangeTrack()
    for k in range(REST_SAMPLES - 1):
        gap = track.add(0.1 * k, 0.0, 2.0, in_air=True)
        assert gap is None
        assert track.clearance(0.1 * k, gap, 0.1, 0.3, True) is None
    assert track.add(1.0, 0.0, 2.0, in_air=True) == pytest.approx(0.0)
    assert track.offset == pytest.approx(-2.0) and track.aligned.startswith("in the air")
    assert track.add(1.1, -0.5, 1.4, in_air=True) == pytest.approx(0.1)
    assert track.figures()["samples"] == 2


def test_min_clearance_is_checked_and_named(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(HOVER.replace("altitude: {max: 5}}", "altitude: {max: 5},\n"
                                  "         min_clearance: -0.1}"))
    with pytest.raises(ConfigError) as e:
        load_mission(path)
    assert "min_clearance" in str(e.value) and "bad.yaml:9" in str(e.value)
    path.write_text(HOVER)
    assert load_mission(path).safety.min_clearance == 0.5  # on by default


@pytest.mark.slow
def test_a_true_estimate_agrees_with_the_range_finder(tmp_path):
    """The bundled vehicle's range finder (``sim: {rangefinder: true}``, DISTANCE_SENSOR at PX4's
    10 Hz) beside an estimate that is the truth: aligned at rest, within 2 cm all flight, and
    the flight flies as without it."""
    out = io.StringIO()
    summary, _ = fly(mission(tmp_path, "{rangefinder: true}"), out=tmp_path / "runs",
                     lockstep=True, progress=False, stream=out)
    assert summary["landed"] and not summary["aborted"], summary["aborted"]
    rf = summary["rangefinder"]
    assert rf["source"] == "DISTANCE_SENSOR (downward)" and rf["aligned"].startswith("at rest")
    assert rf["rate_hz"] == pytest.approx(10.0, rel=0.02)
    assert rf["samples"] >= 10 * 14
    assert rf["max_difference_m"] < 0.02
    assert rf["lowest_m"] < 0.05  # it saw the ground at takeoff and touchdown
    assert "against the downward range finder" in out.getvalue()
    assert summary["config"]["rangefinder"] is True


def test_the_ground_after_the_touchdown_is_not_set_beside_the_estimate(tmp_path):
    """From the contact on the bundled estimate reads a climb of 0.3 m/s on the ground
    (``sim: {ground_climb_mps}``, as PX4 SIH's read 0.8 m there): the record's range finder
    figures end with the touchdown seen (0.25 m of that climb is read before it), where
    counting the ground after it, through the cut and the disarm, read 1.7 m."""
    summary, _ = fly(mission(tmp_path, "{rangefinder: true, ground_climb_mps: 0.3}"),
                     out=tmp_path / "runs", lockstep=True, progress=False,
                     stream=io.StringIO())
    assert summary["landed"], summary["aborted"]
    assert summary["rangefinder"]["max_difference_m"] < 0.3


@pytest.mark.slow
def test_a_drifting_estimate_is_caught_by_the_range_finder_before_the_ground(tmp_path):
    """The height estimate climbs 0.1 m/s: the loop holds it at 1 m while the vehicle sinks.
    Without a range finder nothing sees it until the vehicle is on the ground (the truth at 0);
    with one the mission ends in the autopilot's landing while the vehicle is still 0.4-0.5 m
    up (``safety.min_clearance``, 0.5 m), the estimate reading about 1 m."""
    runs = {}
    for rf in (False, True):
        out = io.StringIO()
        runs[rf] = fly(mission(tmp_path, f"{{rangefinder: {str(rf).lower()}, "
                                         "height_drift_mps: 0.1}", name=f"d{rf}.yaml"),
                       out=tmp_path / "runs", lockstep=True, progress=False,
                       stream=out) + (out.getvalue(),)
    summary, folder, text = runs[True]
    assert summary["aborted"] and "range finder reads the vehicle" in summary["aborted"][0]
    assert "landing" in text
    truth = read_table(folder / "truth.csv")
    t_end = summary["duration_s"]
    # where it was when the mission ended: the truth sank by the drift, not into the ground
    ground = truth["down"][0]  # the truth in the estimate's frame: at rest on the ground
    height_at_end = ground - np.interp(t_end, truth["t"], truth["down"])
    assert 0.38 < height_at_end < 0.5, height_at_end
    rf = summary["rangefinder"]
    assert rf["max_difference_m"] > CLEARANCE_GAP_M
    assert rf["aligned"].startswith("at rest")
    # without it: no such ending; the vehicle met the ground while the estimate flew on (the
    # ground check ended it there)
    summary0, folder0, _ = runs[False]
    assert summary0["rangefinder"] is None
    assert not any("range finder" in a for a in summary0["aborted"])
    truth0 = read_table(folder0 / "truth.csv")
    airborne = truth0["t"] <= summary0["duration_s"]  # the mission, before it ended
    assert (truth0["down"][0] - truth0["down"][airborne & (truth0["t"] > 3.0)]).min() < 0.01


@pytest.mark.slow
def test_a_lift_off_the_estimate_alone_reads_waits_for_the_range_finder(tmp_path):
    """A vehicle 1.4x as heavy as told, whose height estimate climbs 0.1 m/s from the start (as
    PX4 SIH's read 0.13-0.19 m/s on the ground at 1.4 kg): the estimate reads a lift-off at
    once.  Without a range finder that is taken for one, 0.6 s or more before the vehicle leaves
    the ground by the truth; with one, the range finder's ground reading holds it back, the
    console says so, and the lift-off is seen within 0.15 s after the true one."""
    seen = {}
    for rf in (False, True):
        out = io.StringIO()
        summary, folder = fly(mission(tmp_path, f"{{rangefinder: {str(rf).lower()}, "
                                                "mass_scale: 1.4, height_drift_mps: 0.1}",
                                      name=f"h{rf}.yaml"),
                              out=tmp_path / "runs", lockstep=True,
                              progress=False, stream=out)
        truth = read_table(folder / "truth.csv")
        up = truth["down"][0] - truth["down"]  # the truth in the estimate's frame
        true_liftoff = float(truth["t"][np.argmax(up > 0.05)])
        seen[rf] = (summary, true_liftoff, out.getvalue())
    summary, true_liftoff, text = seen[False]
    assert summary["liftoff_s"] < 0.1 and true_liftoff > 0.6
    assert summary["liftoff_disputed"] is False
    summary, true_liftoff, text = seen[True]
    assert summary["liftoff_disputed"] is True
    assert "the height estimate reads a lift-off" in text and "the range finder does not" in text
    assert true_liftoff > 0.6
    assert true_liftoff - 0.02 <= summary["liftoff_s"] <= true_liftoff + 0.15


def test_the_console_line_says_what_was_measured():
    track = RangeTrack()
    track.start()
    for k in range(50):
        track.add(k * 0.1, 1.0 + 0.01 * k, 1.0)
    fig = track.figures(settle_s=2.0)
    assert fig["max_difference_m"] == pytest.approx(0.49)
    assert fig["after_settle"]["max_difference_m"] == pytest.approx(0.49)
    assert fig["samples"] == 50 and fig["rate_hz"] == pytest.approx(10.0)
    text = rangefinder_text(fig, 2.0)
    assert "up to 0.490 m" in text and "after settling (2 s)" in text
