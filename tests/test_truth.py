"""A simulator's true state beside the autopilot's estimate (mavadrc.flight.truth): the summary says how
far the vehicle really was from its reference, and how far the estimate it flew on was off."""

import io
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M
from sitl_helpers import start_vehicle

from mavadrc.flight.fly import fly
from mavadrc.mission.config import load_mission
from mavadrc.flight.record import read_table
from mavadrc.flight.truth import SOURCES, TruthTrack, estimate_steps, true_state, truth_text
from sim.mavlink import streams

HOVER = """name: truth hover
vehicle: crazyflie
controller: {type: ladrc, rate_hz: 100, input_lag: [0.13, 0.13, 0.05]}
trajectory:
  - takeoff: {altitude: 1.0, speed: 1.0}
  - hover: {duration: HOVER}
  - land: {speed: 0.6}
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
"""

MOVING = """name: truth transit
vehicle: crazyflie
controller: {type: ladrc, rate_hz: 100, input_lag: [0.13, 0.13, 0.05]}
trajectory:
  - takeoff: {altitude: 1.0, speed: 1.0}
  - waypoints: {points: [[3, 0, 1], [3, 3, 1]], speed: 1.5}
  - land: {speed: 0.6}
transit_speed: 1.5
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
"""


def steady(text):
    """A mission flown in real time beside the vehicle in this process, whose telemetry
    failsafe waits 3 s, not 0.5: these flights are about the truth, not the link, and beside a
    busy loop per core the test's process stalled past 0.5 s ("telemetry lost (0.54 s without a
    sample)")."""
    out = text.replace("altitude: {max: 5}}", "altitude: {max: 5}, telemetry_timeout_s: 3.0}")
    assert out != text
    return out


def mission(tmp_path, text, name="m.yaml", extra=""):
    path = tmp_path / name
    path.write_text(text + extra)
    return load_mission(path)


def hil(lat, lon, alt_mm, v=(0, 0, 0)):
    return M.MAVLink_hil_state_quaternion_message(0, [1, 0, 0, 0], 0, 0, 0, lat, lon, alt_mm,
                                                  *v, 0, 0, 0, 0, 0)


def simstate(lat, lon, alt, lat_int=0, lon_int=0, v=(0.0, 0.0, 0.0)):
    return M.MAVLink_sim_state_message(1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, lat, lon, alt, 0, 0,
                                       *v, lat_int, lon_int)


# --- the messages -------------------------------------------------------------------------------

def test_each_message_is_read_in_its_own_units():
    lat, lon, alt, vel = true_state(hil(473977432, 85455942, 489399, (120, -30, 5)))
    assert (lat, lon) == pytest.approx((47.3977432, 8.5455942), abs=1e-9)
    assert alt == pytest.approx(489.399) and vel == pytest.approx((1.2, -0.3, 0.05))
    # ArduPilot: the floats in 1e-7 deg (not the deg its definition says), exact in lat_int
    got = true_state(simstate(-353632621.0, 1491652374.0, 584.1, -353632621, 1491652374,
                              (0.5, 0.0, -0.1)))
    assert got[:2] == pytest.approx((-35.3632621, 149.1652374), abs=1e-9)
    assert got[3] == pytest.approx((0.5, 0.0, -0.1))
    got = true_state(simstate(-353632621.0, 1491652374.0, 584.1))
    assert got[:2] == pytest.approx((-35.3632621, 149.1652374), abs=2e-6)  # float32: 0.2 m
    got = true_state(simstate(-35.3632621, 149.1652374, 584.1))  # as the definition says
    assert got[:2] == pytest.approx((-35.3632621, 149.1652374), abs=1e-5)
    # a simulator not yet placed
    assert true_state(hil(0, 0, 0)) is None and true_state(simstate(0.0, 0.0, 0.0)) is None


def test_the_simulator_projects_its_truth_with_the_radii_the_companion_reads_it_with():
    """sim keeps its own table (it imports nothing of mavadrc but mavadrc.control); it must not
    drift from the companion's."""
    from sim.personality import TRUTH_RADIUS
    assert sorted(TRUTH_RADIUS) == sorted(SOURCES)
    for message, radius in SOURCES.items():
        assert TRUTH_RADIUS[message] == radius, message


def test_the_track_is_projected_with_the_simulators_radius_and_aligned_at_rest():
    track = TruthTrack("HIL_STATE_QUATERNION")
    lat0, lon0 = 47.3977432, 8.5455942
    r = SOURCES["HIL_STATE_QUATERNION"]

    def at(n, e, d):
        lat = lat0 + math.degrees(n / r)
        lon = lon0 + math.degrees(e / (r * math.cos(math.radians(lat0))))
        return hil(round(lat * 1e7), round(lon * 1e7), round((488.0 - d) * 1000))

    for _ in range(30):
        track.at_rest(at(0.0, 0.0, 0.0), [1.0, 2.0, -0.5])  # the estimate's origin elsewhere
    track.start()
    assert "at rest" in track.aligned
    for k in range(101):
        t = 0.1 * k
        track.add(t, at(10.0 * t / 10.0, 0.0, -1.0), [t, 2.0, -1.5 - 0.02 * t])
    pos = np.asarray(track.pos)
    assert pos[0] == pytest.approx([1.0, 2.0, -1.5], abs=0.006)  # 1e-7 deg: 1.1 cm steps
    assert pos[-1] == pytest.approx([11.0, 2.0, -1.5], abs=0.006)  # 10 m north: the scale
    ts = np.linspace(0.0, 10.0, 1001)
    ref = np.column_stack([ts + 1.0, np.full_like(ts, 2.0), np.full_like(ts, -1.5)])
    fig = track.figures(ts, ref, settle_s=5.0)
    assert fig["max_error_m"] < 0.01  # the vehicle was where the reference said
    # the estimate ran 1 m ahead north and climbed 2 cm/s: its error, not the flight's
    assert fig["estimate_error"]["max_xyz_m"][0] == pytest.approx(1.0, abs=0.01)
    assert fig["estimate_error"]["max_xyz_m"][2] == pytest.approx(0.2, abs=0.01)
    assert fig["after_settle"]["rms_error_m"] < 0.01


def test_without_samples_at_rest_it_aligns_in_the_air_and_says_so():
    track = TruthTrack("SIM_STATE")
    for k in range(40):
        track.add(0.01 * k, simstate(0.0, 0.0, 500.0, -353632621, 1491652374), [5.0, 5.0, -3.0])
    assert "in the air" in track.aligned
    assert len(track.t) == 40 - 25 + 1  # the first ones align, from then on they count
    assert np.asarray(track.pos) == pytest.approx(np.tile([5.0, 5.0, -3.0], (16, 1)))


def test_no_true_sample_among_the_scored_steps_gives_no_figures():
    track = TruthTrack("SIM_STATE")
    assert track.figures([0.0, 0.01], [[0, 0, 0], [0, 0, 0]]) is None
    with pytest.raises(ValueError, match="no true state"):
        TruthTrack("GLOBAL_POSITION_INT")


def test_the_console_line_says_over_what_it_was_measured():
    track = TruthTrack("HIL_STATE_QUATERNION")
    track.offset, track.aligned = np.zeros(3), "given"
    for k in range(100):
        track.t.append(0.1 * k)
        track.pos.append(np.array([0.2 if k < 50 else 0.05, 0.0, 0.0]))
        track.est.append(np.zeros(3))
    ts = np.arange(0.0, 10.0, 0.01)
    ref = np.zeros((ts.size, 3))
    line = truth_text(track.figures(ts, ref, settle_s=5.0), 5.0)
    assert "max error 0.050 m, rms 0.050 m after settling" in line
    assert "off by up to 0.200 m" in line
    # a flight that ended before settling: the whole mission, said so (not "nan")
    line = truth_text(track.figures(ts, ref, settle_s=20.0), 20.0)
    assert "max error 0.200 m" in line and "over the mission" in line


def test_truth_across_steps_left_out_is_not_scored():
    """The identification's excitation is not scored: the reference is not interpolated across
    it, so the true samples there count neither way."""
    track = TruthTrack("HIL_STATE_QUATERNION")
    track.offset, track.aligned = np.zeros(3), "given"
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(5.0, 6.0, 0.01)]
    ref = np.zeros((t.size, 3))
    for k in range(300):
        tt = 0.02 * k
        track.t.append(tt)
        track.est.append(np.zeros(3))
        # 2 m off while the steps are left out (1-5 s), on the reference otherwise
        track.pos.append(np.array([2.0, 0.0, 0.0]) if 1.0 < tt < 5.0 else np.zeros(3))
    fig = track.figures(t, ref)
    assert fig["max_error_m"] == 0.0
    assert 98 <= fig["samples"] <= 100  # the 50 + 50 on the scored stretches
    assert fig["rate_hz"] == pytest.approx(50.0)  # as they came, the hole not counted


def test_the_estimates_wander_is_measured_in_the_band_a_loop_cannot_follow():
    """An estimate that wanders off the truth by 20 mm RMS at 0.5 Hz, beside a slow drift of
    0.2 m over the flight and a 5 Hz ripple of 20 mm RMS (timing noise): the band 0.3-1 Hz
    keeps the wander and drops the rest; the error read by the estimate is measured there too."""
    track = TruthTrack("HIL_STATE_QUATERNION")
    track.offset, track.aligned = np.zeros(3), "given"
    rng = np.random.default_rng(1)
    ts = np.cumsum(rng.uniform(0.015, 0.025, 2000))  # ~50 Hz, arrival-timed
    a = 0.02 * math.sqrt(2.0)
    wander = a * np.sin(2 * math.pi * 0.5 * ts)
    for k, tt in enumerate(ts):
        true = np.array([0.01 * tt, 0.0, -1.0])
        track.t.append(tt)
        track.pos.append(true)
        track.est.append(true + [wander[k] + a * np.sin(2 * math.pi * 5.0 * tt),
                                 0.005 * tt, 0.0])
    t = np.arange(0.0, ts[-1], 0.01)
    ref = np.column_stack([0.01 * t, np.zeros_like(t), -np.ones_like(t)])
    fig = track.figures(t, ref, settle_s=5.0)
    w = fig["estimate_error"]["wander"]
    assert w["band_hz"] == [0.3, 1.0] and w["from_s"] == 5.0
    assert w["rms_xyz_m"][0] == pytest.approx(0.020, rel=0.1)
    assert w["rms_xyz_m"][1] < 0.001 and w["rms_xyz_m"][2] < 1e-9  # the drift is no wander
    # the loop here followed the truth: the error by the estimate is the wander itself
    assert w["error_rms_xyz_m"][0] == pytest.approx(w["rms_xyz_m"][0], rel=0.02)
    line = truth_text(fig, 5.0)
    assert "between 0.3 and 1 Hz after settling it wandered 20 / 0 mm rms" in line
    # a stretch too short to tell (under 10 s) gives no figure, and no words
    short = track.figures(t, ref, settle_s=ts[-1] - 5.0)
    assert short["estimate_error"]["wander"]["rms_xyz_m"] == [None] * 3
    assert "wandered" not in truth_text(short, ts[-1] - 5.0)


def test_a_quick_move_of_the_estimate_is_measured_and_named_at_the_largest_error():
    """The estimate moves 0.1 m against the truth in 0.3 s at 20 s (a correction, as PX4 SIH's
    EKF2 makes), while the vehicle flies a 5 m/s circle whose true samples arrive with 3 ms of
    timing jitter (as ArduCopter SITL's at that speed: 15-35 mm between two samples): the step
    measure finds the move, at its time, within 15 %, and the jitter alone reads under 30 mm
    (the 0.2 s average; unaveraged 0.07); at the largest error read by the estimate (the move
    itself, which the loop then takes out) the move is named."""
    rng = np.random.default_rng(3)
    ts = np.cumsum(rng.uniform(0.018, 0.022, 2000))  # ~50 Hz, 40 s
    t = np.arange(0.0, ts[-1], 0.01)
    circle = lambda tt: np.column_stack([5 * np.sin(tt), 5 * (1 - np.cos(tt)),  # noqa: E731
                                         -np.ones_like(tt)])
    ref = circle(t)
    for move in (0.0, 0.1):
        track = TruthTrack("HIL_STATE_QUATERNION")
        track.offset, track.aligned = np.zeros(3), "given"
        ramp = move * np.clip((ts - 20.0) / 0.3, 0.0, 1.0)
        # the error read by the estimate: the move, which the loop then takes out in ~0.5 s
        read = ramp * np.exp(-np.clip(ts - 20.3, 0.0, None) / 0.5)
        est = circle(ts) + np.outer(read, [0.0, 1.0, 0.0])
        true = est - np.outer(ramp, [0.0, 1.0, 0.0])  # the vehicle ends as far off
        true += circle(ts + rng.normal(0.0, 0.003, ts.size)) - circle(ts)  # arrival-timed
        for k, tt in enumerate(ts):
            track.t.append(tt)
            track.pos.append(true[k])
            track.est.append(est[k])
        fig = track.figures(t, ref, settle_s=5.0)
        step = fig["estimate_error"]["step"]
        assert step["window_s"] == 0.5 and step["from_s"] == 5.0
        if move == 0.0:
            assert step["max_m"] < 0.03
            continue
        assert step["max_m"] == pytest.approx(move, rel=0.15)
        assert 20.0 <= step["at_s"] <= 20.8
        worst = step["at_worst_error"]
        assert 20.0 <= worst["t_s"] <= 20.6
        assert worst["error_m"] == pytest.approx(move, rel=0.15)
        assert worst["moved_m"] == pytest.approx(move, rel=0.15)
        line = truth_text(fig, 5.0)
        assert "within 0.5 s it moved up to 0.1" in line and "it had just moved 0.1" in line
    # a record shorter than the window, or than the average, has no figure, and no words
    for n in (5, 10, 20):
        assert estimate_steps(ts[:n], np.zeros((n, 3)), np.zeros((n, 3)))["max_m"] is None


# --- flown on the bundled vehicle ---------------------------------------------------------------

def test_a_drifting_height_estimate_is_flown_as_it_says_and_measured_by_the_truth(tmp_path):
    """The bundled vehicle's height estimate climbs 3 cm/s: the loop holds the estimate on its
    reference, so the summary's own error stays small, while the truth shows the vehicle sinking
    below the reference by as much as the estimate drifted since the mission began."""
    m = mission(tmp_path, HOVER.replace("HOVER", "8"), extra="sim: {height_drift_mps: 0.03}\n")
    out = io.StringIO()
    summary, folder = fly(m, out=tmp_path / "runs", lockstep=True,
                          progress=False, stream=out)
    assert summary["landed"], summary["aborted"]
    truth = summary["truth"]
    assert truth["source"] == "HIL_STATE_QUATERNION" and "at rest" in truth["aligned"]
    assert truth["rate_hz"] == pytest.approx(50.0, rel=0.02)
    drifted = 0.03 * summary["duration_s"]
    est_z = truth["estimate_error"]["max_xyz_m"][2]
    assert est_z == pytest.approx(drifted, rel=0.15)
    assert summary["max_error_xyz_m"][2] < 0.1  # on the estimate: the drift unseen
    assert truth["max_error_xyz_m"][2] > 0.8 * drifted  # by the truth: the vehicle sank
    assert truth["max_error_xyz_m"][2] > 3 * summary["max_error_xyz_m"][2]
    assert "against the simulator's true position" in out.getvalue()
    tab = read_table(folder / "truth.csv")
    assert tab["t"].size >= truth["samples"]  # every one written, scored or not
    assert np.all(np.diff(tab["t"]) > 0)


WANDERING = """name: wandering hover
vehicle: px4_sih_quad
controller: {type: ladrc, rate_hz: 100, wc: [2, 2, 2.5], wo: [10, 10, 12.5],
             input_lag: [0.2, 0.2, 0.06], input_lags: 2}
trajectory:
  - takeoff: {altitude: 1.5, speed: 1.0}
  - hover: {duration: 20}
  - land: {speed: 0.5}
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
logging: {settle_s: 4}
"""


@pytest.mark.slow
def test_a_wandering_estimate_is_flown_and_the_truth_measures_its_wander(tmp_path):
    """``sim: {wander: 0.06}`` over MAVLink (the server's --wander): the estimate the vehicle
    reports wanders off its true state (HIL_STATE_QUATERNION) by the model's 11 mm RMS between
    0.3 and 1 Hz (measured 8-11), and the loop, which cannot follow that on a vehicle answering
    in 0.26 s, shows it amplified in its own error (12-18 mm); without it both are ~0."""
    from sim.sensors import WANDER_CORNER_HZ, wander_band_rms

    band = wander_band_rms(0.06, WANDER_CORNER_HZ, 0.3, 1.0)
    flown = {}
    for wander in (0.0, 0.06):
        m = mission(tmp_path, WANDERING, name=f"w{wander}.yaml",
                    extra=f"sim: {{wander: {wander}, seed: 1}}\n")
        summary, _ = fly(m, out=tmp_path / "runs", lockstep=True,
                         progress=False, stream=io.StringIO())
        assert summary["landed"], summary["aborted"]
        assert summary["config"]["wander"] == wander
        flown[wander] = summary
    still = flown[0.0]["truth"]["estimate_error"]["wander"]
    assert max(still["rms_xyz_m"]) < 0.001 and max(still["error_rms_xyz_m"]) < 0.004
    w = flown[0.06]["truth"]["estimate_error"]["wander"]
    for axis in range(3):
        assert 0.6 * band < w["rms_xyz_m"][axis] < 1.5 * band
    assert np.mean(w["error_rms_xyz_m"][:2]) > np.mean(w["rms_xyz_m"][:2])
    assert flown[0.06]["after_settle"]["max_error_m"] > 2 * flown[0.0]["after_settle"]["max_error_m"]


@pytest.mark.slow
def test_an_ardupilot_sitl_sends_sim_state_and_a_clean_estimate_agrees_with_it(tmp_path):
    text = HOVER.replace("HOVER", "3").replace("safety: {", "safety: {set_guid_options: true, ")
    m = mission(tmp_path, text, extra="sim: {autopilot: ardupilot}\n")
    summary, folder = fly(m, out=tmp_path / "runs", lockstep=True,
                          progress=False, stream=io.StringIO())
    assert summary["landed"], summary["aborted"]
    truth = summary["truth"]
    assert truth["source"] == "SIM_STATE"
    # the estimate is the truth here: what is left is SIM_STATE's 1e-7 deg (1.1 cm) steps
    assert truth["estimate_error"]["max_m"] < 0.01
    assert truth["rms_error_m"] == pytest.approx(summary["rms_error_m"], abs=0.004)


@pytest.mark.realtime
def test_in_real_time_a_true_sample_is_timed_by_its_arrival(tmp_path):
    """Not in lockstep a true sample is timed by its arrival after the last position sample,
    on the vehicle's clock: moving at 1.5 m/s the true track's error against the reference is
    the estimate's own (the clean vehicle's estimate is the truth), within 5 mm; timed 20 ms
    late, it reads twice that."""
    srv, port = start_vehicle(params={"COM_SPOOLUP_TIME": 0.0})
    try:
        m = mission(tmp_path, steady(MOVING))
        summary, folder = fly(m, connect=f"udpout:127.0.0.1:{srv.local_ports['offboard']}",
                              out=tmp_path / "runs", progress=False,
                              stream=io.StringIO(), timeout=90.0)
    finally:
        srv.stop()
    assert summary["landed"], summary["aborted"]
    truth = summary["truth"]
    tab = read_table(folder / "truth.csv")
    speed = np.hypot(tab["vn"], tab["ve"])
    assert speed.max() > 1.3  # it did move
    assert truth["estimate_error"]["rms_m"] < 0.006
    assert truth["rms_error_m"] == pytest.approx(summary["rms_error_m"], abs=0.005)


@pytest.mark.realtime
def test_a_vehicle_without_truth_says_so_and_flies_as_before(tmp_path, monkeypatch):
    """A real PX4 has no ground truth: the stream is refused (or nothing comes), the summary's
    truth is None and its sources say why."""
    monkeypatch.delitem(streams.BUILDERS, M.MAVLINK_MSG_ID_HIL_STATE_QUATERNION)
    srv, port = start_vehicle(params={"COM_SPOOLUP_TIME": 0.0})
    try:
        m = mission(tmp_path, steady(HOVER.replace("HOVER", "2")))
        out = io.StringIO()
        summary, folder = fly(m, connect=f"udpout:127.0.0.1:{srv.local_ports['offboard']}",
                              out=tmp_path / "runs", progress=False, stream=out,
                              timeout=60.0)
    finally:
        srv.stop()
    assert summary["landed"], summary["aborted"]
    assert summary["truth"] is None
    assert summary["streams"]["HIL_STATE_QUATERNION"] == "FAILED"
    assert summary["sources"]["truth"].startswith("none: HIL_STATE_QUATERNION asked, FAILED")
    # not a warning (expected of a vehicle): only the vehicle's own answer names it
    said = [line for line in out.getvalue().splitlines() if "HIL_STATE_QUATERNION" in line]
    assert said == ["  vehicle: MAV_CMD_SET_MESSAGE_INTERVAL (HIL_STATE_QUATERNION): FAILED"], said
    assert not (folder / "truth.csv").exists()
