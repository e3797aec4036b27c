"""The bundled vehicle is as unkind as the real autopilots where companions trip over them.

Each test drives the vehicle over MAVLink with pymavlink, most of them in lockstep (one 10 ms
step per setpoint, so that timings are exact and the tests fast), and checks one rule of PX4 or
ArduCopter; its docstring names the parameter, its default and where the rule lives in the
autopilot's source (PX4-Autopilot and ArduPilot as of 2026).  See also the design notes,
MAVLINK.md section 9, and the rules themselves in sim/personality.py.
"""

import argparse
import math
import struct
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl_helpers import (Client, Lockstep, free_udp_port, px4_mode, start_vehicle, udp_sink,
                          wait_until)

M = mavlink
OFFBOARD = px4_mode(6)
RTL = px4_mode(4, 5)
ARMED = M.MAV_MODE_FLAG_SAFETY_ARMED
ON_GROUND = M.MAV_LANDED_STATE_ON_GROUND
IN_AIR = M.MAV_LANDED_STATE_IN_AIR
GUIDED_NOGPS = 20


def lockstep(autopilot, params=None, **kw):
    srv, port = start_vehicle(autopilot, lockstep=True, params=params, **kw)
    c = Client(port)
    c.heartbeat()
    L = Lockstep(c)
    # the land detector's view at every step
    assert L.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                     10_000) == 0
    return srv, c, L


@pytest.fixture
def px4_lockstep():
    made = []

    def make(params=None, **kw):
        made.append(lockstep("px4", params, **kw))
        return made[-1]
    yield make
    for srv, c, _ in made:
        c.close()
        srv.stop()


@pytest.fixture
def ap_lockstep():
    made = []

    def make(params=None, **kw):
        made.append(lockstep("ardupilot", params, **kw))
        return made[-1]
    yield make
    for srv, c, _ in made:
        c.close()
        srv.stop()


def first_t(log, pred):
    """Vehicle time (ms) of the first logged message that satisfies ``pred``."""
    return next((t for t, m in log if pred(m)), None)


def lpn_t(L, pred, since_ms=-1):
    return first_t([(t, m) for t, m in L.messages("LOCAL_POSITION_NED", since_ms)], pred)


def landed_states(L, since_ms=-1):
    """(vehicle time in ms, landed_state) of every EXTENDED_SYS_STATE since ``since_ms`` (one
    step late: a step's telemetry after its LOCAL_POSITION_NED is read during the next)."""
    return [(t, m.landed_state) for t, m in L.messages("EXTENDED_SYS_STATE", since_ms)]


def start_px4_offboard(L, thrust=0.0):
    """Stream, switch to OFFBOARD, arm; the vehicle time (ms) of arming."""
    L.run(0.05, thrust=thrust)
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    return L.t_ms


def start_ap_guided_nogps(L, thrust=0.0):
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == M.MAV_RESULT_ACCEPTED
    L.run(0.05, thrust=thrust)
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    return L.t_ms


# --- 1. heartbeats -------------------------------------------------------------------------------


def test_px4_heartbeat_keeps_1hz_of_vehicle_time_through_mode_and_arming_changes(px4_lockstep):
    """PX4 sends HEARTBEAT as a constant-rate 1 Hz stream (mavlink_main.cpp: configure_stream(
    "HEARTBEAT", 1.0f), "rate never adjusted"; streams/HEARTBEAT.hpp) and nothing else sends one:
    after a mode change or arming, a companion still reads the old state for up to a second.
    MAV_CMD_REQUEST_MESSAGE(HEARTBEAT) is answered at once."""
    srv, c, L = px4_lockstep()
    L.run(1.3)
    t_mode = L.t_ms
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    L.run(1.0)
    t_arm = L.t_ms
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    L.run(1.0)
    hbs = L.messages("HEARTBEAT")
    times = [t for t, _ in hbs]
    assert len(times) >= 4 and set(np.diff(times)) == {1000}  # strictly 1 s of vehicle time
    after_mode = [(t, m) for t, m in hbs if t > t_mode]
    assert after_mode[0][0] - t_mode >= 500  # nothing sent at the switch (0.7 s to the next)
    assert after_mode[0][1].custom_mode == OFFBOARD
    assert all(m.custom_mode != OFFBOARD for t, m in hbs if t <= t_mode)
    after_arm = [(t, m) for t, m in hbs if t > t_arm]
    assert after_arm[0][0] - t_arm >= 500 and after_arm[0][1].base_mode & ARMED
    # asked for, it comes at once (no step in between) and shows the present state
    n = len(L.messages("HEARTBEAT"))
    assert L.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HEARTBEAT) == 0
    end = time.monotonic() + 2.0
    while len(L.messages("HEARTBEAT")) == n and time.monotonic() < end:
        L._recv(end)
    t, hb = L.messages("HEARTBEAT")[-1]
    assert len(L.messages("HEARTBEAT")) == n + 1 and t == L.t_ms
    assert hb.custom_mode == OFFBOARD and hb.base_mode & ARMED


def test_ardupilot_heartbeat_at_once_on_a_mode_change_but_not_on_arming(ap_lockstep):
    """ArduCopter: Copter::set_mode (ArduCopter/mode.cpp) ends with
    gcs().send_message(MSG_HEARTBEAT), so a mode change is on the wire at once (only when the
    mode really changes); arming and disarming (AP_Arming_Copter::arm/disarm) send none: the
    1 Hz heartbeat (GCS_MAVLINK, interval 1000 ms) shows them."""
    srv, c, L = ap_lockstep({"SIM_ARMING_DELAY": 0.0})
    L.run(1.3)
    t_mode = L.t_ms
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == M.MAV_RESULT_ACCEPTED
    L.run(0.01)
    at_switch = [m for t, m in L.messages("HEARTBEAT") if t == t_mode]
    assert len(at_switch) == 1 and at_switch[0].custom_mode == GUIDED_NOGPS
    n = len(L.messages("HEARTBEAT"))
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == M.MAV_RESULT_ACCEPTED  # same
    L.run(0.01)
    assert len(L.messages("HEARTBEAT")) == n
    L.run(0.3)
    t_arm = L.t_ms
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    L.run(1.0)
    after_arm = [(t, m) for t, m in L.messages("HEARTBEAT") if t >= t_arm]
    assert after_arm[0][0] - t_arm >= 300 and after_arm[0][1].base_mode & ARMED
    regular = [t for t, _ in L.messages("HEARTBEAT") if t != t_mode]
    assert set(np.diff(regular)) == {1000}


# --- 2. motors held at idle after arming ---------------------------------------------------------


@pytest.mark.parametrize("spoolup", [None, 0.3])
def test_px4_position_control_waits_com_spoolup_time_after_arming(px4_lockstep, spoolup):
    """PX4 COM_SPOOLUP_TIME (default 1.0 s, commander_params.c): mc_pos_control's takeoff state
    machine (mc_pos_control/Takeoff/Takeoff.cpp: disarmed -> spoolup -> ready_for_takeoff) holds
    the motors at idle that long after arming, whatever position setpoints ask.  Readable and
    settable over the parameter protocol."""
    srv, c, L = px4_lockstep()
    assert L.param("COM_SPOOLUP_TIME") == pytest.approx(1.0)
    if spoolup is not None:
        assert L.param("COM_SPOOLUP_TIME", spoolup) == pytest.approx(spoolup)
    wait = 1.0 if spoolup is None else spoolup
    L.run(0.05, position=(0.0, 0.0, -1.0))
    assert L.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    t_arm = L.t_ms
    L.run(wait + 0.6, position=(0.0, 0.0, -1.0))
    lift = lpn_t(L, lambda m: m.z < -0.005, since_ms=t_arm)
    assert lift is not None
    assert wait * 1000 <= lift - t_arm <= wait * 1000 + 400
    assert all(m.z == 0.0 for t, m in L.messages("LOCAL_POSITION_NED", t_arm)
               if t <= t_arm + wait * 1000)


def test_px4_offboard_attitude_thrust_is_not_held_by_the_spoolup(px4_lockstep):
    """PX4 applies COM_SPOOLUP_TIME in position control and to manual throttle only
    (mc_att_control_main.cpp _spooled_up -> _manual_throttle_maximum); an offboard
    SET_ATTITUDE_TARGET goes straight to the attitude controller
    (mavlink_receiver.cpp handle_message_set_attitude_target), so its thrust acts at once."""
    srv, c, L = px4_lockstep()
    t_arm = start_px4_offboard(L, thrust=0.9)
    L.run(0.4, thrust=0.9)
    lift = lpn_t(L, lambda m: m.z < -0.005, since_ms=t_arm)
    assert lift is not None and lift - t_arm <= 300


@pytest.mark.parametrize("delay", [None, 0.5])
def test_ardupilot_motors_stay_at_minimum_for_the_arming_delay(ap_lockstep, delay):
    """ArduCopter ARMING_DELAY_SEC (2.0 s, ArduCopter/config.h; a compile-time constant, offered
    here as the simulator parameter SIM_ARMING_DELAY): motors.cpp keeps the motor interlock off
    (AP_MotorsMulticopter::output_logic: SHUT_DOWN) while ap.in_arming_delay, so thrust sent
    meanwhile does nothing and the land detector keeps saying landed."""
    srv, c, L = ap_lockstep({"GUID_OPTIONS": 8})
    assert L.param("SIM_ARMING_DELAY") == pytest.approx(2.0)
    if delay is not None:
        assert L.param("SIM_ARMING_DELAY", delay) == pytest.approx(delay)
    wait = 2.0 if delay is None else delay
    t_arm = start_ap_guided_nogps(L, thrust=0.9)
    L.run(wait + 0.5, thrust=0.9)
    lift = lpn_t(L, lambda m: m.z < -0.005, since_ms=t_arm)
    assert lift is not None and wait * 1000 <= lift - t_arm <= wait * 1000 + 300
    held = [s for t, s in landed_states(L, t_arm) if t < t_arm + wait * 1000 - 20]
    assert held and set(held) == {ON_GROUND}


# --- 3. PX4's land detector and automatic disarming ----------------------------------------------


def test_px4_land_detector_in_air_above_minimum_thrust_and_disarm_after_landing(px4_lockstep):
    """PX4's multicopter land detector (land_detector/MulticopterLandDetector.cpp) without
    climb-rate control: "maybe landed" needs thrust <= MPC_MANTHR_MIN + 0.01 (0.08 + 0.01), so
    a vehicle sitting on the ground at thrust 0.2 reports IN_AIR and a disarm is refused
    (Commander::disarm: "Disarming denied: not landed", TEMPORARILY_REJECTED).  Thrust cut:
    ON_GROUND ~1 s later (three 1/3 s hysteresis stages, less the ground contact already seen),
    then Commander::handleAutoDisarm disarms after COM_DISARM_LAND (default 2.0 s)."""
    srv, c, L = px4_lockstep()
    t_arm = start_px4_offboard(L, thrust=0.05)
    L.run(1.5, thrust=0.05)
    assert set(s for t, s in landed_states(L, t_arm)) == {ON_GROUND}  # idle thrust: landed
    t_up = L.t_ms
    L.run(0.5, thrust=0.2)  # below hover: the vehicle stays on the ground
    assert srv.vehicle.state[2] == 0.0
    assert L.landed_state() == IN_AIR
    assert ("Takeoff detected" in [x for t, x in L.texts(t_up)])
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert "Disarming denied: not landed" in [x for t, x in L.texts(t_up)]
    t_cut = L.t_ms
    L.run(4.0, thrust=0.0, until=lambda m: not srv.vehicle.armed)
    landed = first_t([(t, s) for t, s in landed_states(L, t_cut)], lambda s: s == ON_GROUND)
    assert 600 <= landed - t_cut <= 1100
    texts = L.texts(t_cut)
    assert [x for t, x in texts][:2] == ["Landing detected", "Disarmed by landing"]
    t_disarm = texts[1][0]
    assert t_disarm - landed == pytest.approx(2000, abs=30)
    assert not srv.vehicle.armed


def test_px4_preflight_auto_disarm_applies_in_offboard(px4_lockstep):
    """Commander::handleAutoDisarm: a vehicle that never took off since arming is disarmed
    COM_SPOOLUP_TIME + COM_DISARM_PRFLT (1.0 + 10.0 s) after arming, "Disarmed by auto preflight
    disarming", in every mode, OFFBOARD included (no mode condition in that rule)."""
    srv, c, L = px4_lockstep()
    t_arm = start_px4_offboard(L, thrust=0.05)
    L.run(11.5, thrust=0.05, until=lambda m: not srv.vehicle.armed)
    t_disarm = first_t(L.messages("STATUSTEXT", t_arm),
                       lambda m: m.text == "Disarmed by auto preflight disarming")
    assert t_disarm is not None and t_disarm - t_arm == pytest.approx(11000, abs=30)
    assert set(s for t, s in landed_states(L, t_arm)) == {ON_GROUND}


# --- 4. PX4 offboard loss without RC -------------------------------------------------------------


@pytest.mark.realtime
def test_px4_offboard_loss_without_rc_returns_lands_and_disarms():
    """PX4 failsafe.cpp checkModeFallback: COM_OF_LOSS_T (default 1.0 s) without setpoints ->
    COM_OBL_RC_ACT (default 0, Position mode); Position needs manual control, which the vehicle
    has not, so the RC-loss action NAV_RCL_ACT follows (default 2, Return; Return needs a home,
    which arming set).  Announced as PX4 does ("Failsafe activated: switching to RTL" is its
    event, "Failsafe activated" its STATUSTEXT, framework.cpp notifyUser); once landed,
    COM_DISARM_LAND disarms.  The vehicle never hovers armed for ever."""
    srv, port = start_vehicle("px4", params={"RTL_RETURN_ALT": 1.5})
    c = Client(port)
    try:
        c.heartbeat()
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                         20_000) == 0
        for _ in range(5):
            c.position(1.5, 0.0, -1.0)
            time.sleep(0.02)
        assert c.set_mode_px4(6) == M.MAV_RESULT_ACCEPTED
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        end = time.monotonic() + 15
        while time.monotonic() < end:
            c.position(1.5, 0.0, -1.0)
            p = srv.vehicle.reported().position
            if abs(p[0] - 1.5) < 0.1 and abs(p[2] + 1.0) < 0.1:
                break
            time.sleep(0.02)
        else:
            raise AssertionError("did not get there")
        t_stop = time.monotonic()
        texts = []
        while len(texts) < 2:
            m = c.recv("STATUSTEXT", timeout=3.0, cond=lambda m: m.text.startswith("Failsafe"))
            assert m is not None
            texts.append(m.text)
        assert time.monotonic() - t_stop <= 1.0 + 0.3
        assert texts == ["Failsafe activated: switching to RTL", "Failsafe activated"]
        hb = c.recv("HEARTBEAT", cond=lambda m: m.custom_mode == RTL)
        assert hb is not None and hb.system_status == M.MAV_STATE_CRITICAL
        assert c.recv("EXTENDED_SYS_STATE", timeout=20.0,
                      cond=lambda m: m.landed_state == ON_GROUND) is not None
        assert math.hypot(*srv.vehicle.reported().position[:2]) < 0.6  # it came home
        assert c.recv("STATUSTEXT", timeout=5.0,
                      cond=lambda m: m.text == "Disarmed by landing") is not None
        hb = c.recv("HEARTBEAT", timeout=3.0, cond=lambda m: not m.base_mode & ARMED)
        # and, disarmed, back in the mode the failsafe took it from (PX4's user intention; seen
        # on PX4 SITL: RTL, landed, "Disarmed by landing", then heartbeats in OFFBOARD)
        assert hb is not None and hb.custom_mode == px4_mode(6)
    finally:
        c.close()
        srv.stop()


# --- 5. ArduCopter -------------------------------------------------------------------------------


def test_ardupilot_refuses_disarm_in_air_and_detects_landing_after_touchdown(ap_lockstep):
    """ArduCopter: AP_Arming_Copter::disarm refuses a MAVLink disarm while !ap.land_complete
    ("do not allow disarm via mavlink if we think we are flying"), which
    GCS_MAVLINK::handle_command_component_arm_disarm answers MAV_RESULT_FAILED, with no text.
    Any positive GUIDED thrust clears land_complete (mode_guided.cpp angle_control_run).  The
    land detector (land_detector.cpp) declares landing after LAND_DETECTOR_TRIGGER_SEC (1.0 s)
    of motors at their lower limit, |vz| < 1 m/s and the 1 Hz filtered acceleration < 1 m/s/s;
    the filter holds the touchdown's jolt: ~1.4 s after a hard touchdown (as measured on
    ArduCopter SITL).  Reported in EXTENDED_SYS_STATE."""
    srv, c, L = ap_lockstep({"GUID_OPTIONS": 8, "SIM_ARMING_DELAY": 0.0})
    hover = srv.vehicle.hover_thrust
    start_ap_guided_nogps(L, thrust=0.0)
    L.run(0.5, thrust=0.0)
    assert L.landed_state() == ON_GROUND
    L.run(0.3, thrust=0.2 * hover)  # positive thrust, still on the ground
    assert srv.vehicle.state[2] == 0.0 and L.landed_state() == IN_AIR
    n_texts = len(L.texts())
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_FAILED
    assert srv.vehicle.armed and len(L.texts()) == n_texts
    t_cut = L.t_ms
    L.run(1.5, thrust=0.0)  # at rest on the ground: 1.0 s of lower limit
    landed = first_t(landed_states(L, t_cut), lambda s: s == ON_GROUND)
    assert 1000 <= landed - t_cut <= 1100
    # a hop: up 0.6 m, thrust cut, a hard touchdown
    L.run(5.0, thrust=min(1.0, 1.4 * hover), until=lambda m: m.z < -0.6)
    t_fall = L.t_ms
    L.run(1.5, thrust=0.0, until=lambda m: m.z >= 0.0)
    touchdown = L.t_ms
    fall_speed = L.messages("LOCAL_POSITION_NED")[-2][1].vz
    assert fall_speed > 2.0
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_FAILED  # not yet
    L.run(2.5, thrust=0.0)
    landed = first_t(landed_states(L, touchdown), lambda s: s == ON_GROUND)
    assert landed is not None and 1200 <= landed - touchdown <= 2000
    assert all(s == IN_AIR for t, s in landed_states(L, t_fall) if t < landed)
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
    assert "Disarming motors" in [x for t, x in L.texts(touchdown)]


def test_ardupilot_disarms_itself_disarm_delay_after_landing(ap_lockstep):
    """Copter::auto_disarm_check (ArduCopter/motors.cpp): landed with the motors at ground idle
    for DISARM_DELAY s (default 10, Parameters.cpp), in any mode -> disarm."""
    srv, c, L = ap_lockstep({"GUID_OPTIONS": 8, "SIM_ARMING_DELAY": 0.0, "DISARM_DELAY": 3})
    assert L.param("DISARM_DELAY", 3, M.MAV_PARAM_TYPE_INT32) == 3
    t_arm = start_ap_guided_nogps(L, thrust=0.0)
    L.run(4.0, thrust=0.0, until=lambda m: not srv.vehicle.armed)
    t_disarm = first_t(L.messages("STATUSTEXT", t_arm), lambda m: m.text == "Disarming motors")
    assert t_disarm is not None and t_disarm - t_arm == pytest.approx(3000, abs=30)


@pytest.mark.parametrize("boost", [1, 0])
def test_ardupilot_guided_thrust_gets_the_angle_boost(ap_lockstep, boost):
    """ArduCopter GUIDED with GUID_OPTIONS bit 3: thrust is thrust, and angle_control_run
    calls attitude_control->set_throttle_out(thrust, true, ...), i.e. with the angle boost of
    AC_AttitudeControl_Multi::get_throttle_boosted: thrust x inverted_factor /
    clamp(cos(tilt), 0.1, 1), tilt the measured lean (_thrust_angle_rad), inverted_factor =
    clamp(10 cos(tilt), 0, 1); ATC_ANGLE_BOOST (default 1) turns it off.  With it, hover thrust
    at a 30 deg lean still holds the height."""
    srv, c, L = ap_lockstep({"GUID_OPTIONS": 8, "SIM_ARMING_DELAY": 0.0,
                             "ATC_ANGLE_BOOST": boost})
    hover = srv.vehicle.hover_thrust
    start_ap_guided_nogps(L, thrust=0.0)
    L.run(5.0, thrust=1.3 * hover, until=lambda m: m.z < -1.5)
    L.run(3.0, thrust=0.7 * hover, until=lambda m: m.vz >= -0.02)  # stop climbing
    roll = math.radians(30.0)
    q = (math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0)
    L.run(0.4, q=q, thrust=hover)  # lean over
    vz0 = L.step(q=q, thrust=hover).vz
    sent, cos_tilt = [], []
    for _ in range(60):
        w, x, y, z = srv.vehicle.reported().quaternion  # what the boost of this step reads
        m = L.step(q=q, thrust=hover)
        cos_tilt.append(1.0 - 2.0 * (x * x + y * y))
        sent.append(srv.vehicle.attitude_setpoint[1] / hover)
    assert np.allclose(cos_tilt, math.cos(roll), atol=0.02)
    dvz = m.vz - vz0  # over 0.6 s
    if boost:
        assert np.allclose(np.array(sent) * cos_tilt, 1.0, atol=1e-6)  # hover / cos(tilt)
        assert abs(dvz) < 0.25
    else:
        assert np.allclose(sent, 1.0, atol=1e-9)  # thrust as sent
        assert dvz > 0.5  # sinks: g (1 - cos 30 deg) = 1.3 m/s/s


@pytest.mark.realtime
def test_ardupilot_denies_intervals_of_messages_it_does_not_send():
    """ArduPilot GCS_MAVLINK::set_message_interval: a MAVLink id without an ap_message
    (GCS_Common.cpp map[]: no DEBUG_VECT, no ODOMETRY, which ArduPilot only receives) ->
    MAV_RESULT_DENIED and, in SITL builds, "No ap_message for mavlink id (N)";
    handle_command_request_message -> FAILED.  The PX4 personality keeps streaming DEBUG_VECT
    (PX4 has that stream; the bundled vehicle's TRUE_DIST is a simulator extension)."""
    srv, port = start_vehicle("ardupilot")
    c = Client(port)
    try:
        c.heartbeat()
        c.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                M.MAVLINK_MSG_ID_DEBUG_VECT, 10_000, 0, 0, 0, 0, 0)
        got = []
        while not got or got[-1].get_type() != "COMMAND_ACK":
            m = c.recv(["STATUSTEXT", "COMMAND_ACK"])
            assert m is not None
            got.append(m)
        assert got[-1].result == M.MAV_RESULT_DENIED
        assert [m.text for m in got[:-1]] == ["No ap_message for mavlink id (250)"]
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ODOMETRY,
                         10_000) == M.MAV_RESULT_DENIED
        assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_DEBUG_VECT) == \
            M.MAV_RESULT_FAILED
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                         20_000) == M.MAV_RESULT_ACCEPTED
        assert c.recv("ODOMETRY", timeout=1.0) is None and c.recv("DEBUG_VECT", 0.5) is None
    finally:
        c.close()
        srv.stop()
    srv, port = start_vehicle("px4")
    c = Client(port)
    try:
        c.heartbeat()
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_DEBUG_VECT,
                         20_000) == M.MAV_RESULT_ACCEPTED
        assert c.recv("DEBUG_VECT", cond=lambda m: m.name == "TRUE_DIST") is not None
    finally:
        c.close()
        srv.stop()


@pytest.mark.realtime
def test_ardupilot_guid_timeout_levels_and_holds_the_climb_rate_at_zero():
    """ArduCopter mode_guided.cpp angle_control_run: no SET_ATTITUDE_TARGET for GUID_TIMEOUT
    (default 3.0 s, Parameters.cpp) -> attitude level at the target's heading, body rates zero,
    climb rate zero (a thrust target becomes a climb-rate target: use_thrust = false).  Nothing
    is said on the wire."""
    srv, port = start_vehicle("ardupilot", params={"GUID_OPTIONS": 8, "SIM_ARMING_DELAY": 0.0})
    c = Client(port)
    try:
        c.heartbeat()
        hover = srv.vehicle.hover_thrust
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == M.MAV_RESULT_ACCEPTED
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        end = time.monotonic() + 10
        while srv.vehicle.reported().position[2] > -1.5 and time.monotonic() < end:
            c.attitude(thrust=1.3 * hover)
            time.sleep(0.02)
        yaw = 0.4
        q = (math.cos(0.05) * math.cos(yaw / 2), math.sin(0.05) * math.cos(yaw / 2),
             math.sin(0.05) * math.sin(yaw / 2), math.cos(0.05) * math.sin(yaw / 2))
        for _ in range(25):  # 5.7 deg of roll at hover thrust for 0.5 s
            c.attitude(q=q, thrust=hover)
            time.sleep(0.02)
        t_last = srv.vehicle.time
        assert wait_until(lambda: srv.vehicle.attitude_setpoint[0][1] == 0.0, 5.0)
        assert srv.vehicle.time - t_last == pytest.approx(3.0, abs=0.06)
        qs = srv.vehicle.attitude_setpoint[0]
        assert qs[2] == 0.0 and 2.0 * math.atan2(qs[3], qs[0]) == pytest.approx(yaw, abs=1e-6)
        time.sleep(1.0)
        z0 = srv.vehicle.reported().position[2]
        time.sleep(1.0)
        r = srv.vehicle.reported()
        assert abs(r.euler[0]) < 0.01 and abs(r.velocity[2]) < 0.15
        assert abs(r.position[2] - z0) < 0.15
        assert srv.vehicle.armed and c.recv("STATUSTEXT", timeout=0.2) is None
    finally:
        c.close()
        srv.stop()


# --- 6. hover parameters -------------------------------------------------------------------------


@pytest.mark.parametrize("autopilot, name", [("px4", "MPC_THR_HOVER"),
                                             ("ardupilot", "MOT_THST_HOVER")])
@pytest.mark.parametrize("vehicle", ["crazyflie", "x500"])
def test_hover_parameter_is_the_vehicles_real_hover_point(autopilot, name, vehicle):
    """MPC_THR_HOVER (PX4, default 0.5) / MOT_THST_HOVER (ArduCopter, default 0.35, learnt in
    flight) report the thrust that really holds the bundled vehicle: streamed level at that
    thrust, a (force-armed, airborne) vehicle keeps its vertical speed."""
    params = {"SIM_ARMING_DELAY": 0.0, "GUID_OPTIONS": 8} if autopilot == "ardupilot" else None
    srv, c, L = lockstep(autopilot, params, vehicle=vehicle, position=(0.0, 0.0, -20.0))
    try:
        value = L.param(name)
        assert value == pytest.approx(srv.vehicle.hover_thrust, rel=1e-6)
        if autopilot == "px4":
            L.run(0.03, thrust=value)
            assert L.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == 0
        else:
            assert L.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == 0
        assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196) == 0
        L.run(0.5, thrust=value)  # rotors spin up
        vz0 = L.step(thrust=value).vz
        m = L.run(1.0, thrust=value)
        # only drag on the fall of the spin-up (~0.5 m/s) changes it; a hover thrust 5 % off
        # would change it by 0.5 m/s
        assert abs(m.vz - vz0) < 0.15
    finally:
        c.close()
        srv.stop()


# --- 7. TIMESYNC ---------------------------------------------------------------------------------


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_timesync_answers_with_the_vehicle_clock(autopilot):
    """TIMESYNC with tc1 = 0 is answered with tc1 = the autopilot's time since boot in ns, the
    clock of time_boot_ms (PX4 mavlink_timesync.cpp: hrt_absolute_time() * 1000; ArduPilot
    GCS_MAVLINK::handle_timesync: micros64() * 1000 at reception), and ts1 echoed: a companion
    can tell the age of a sample."""
    srv, c, L = lockstep(autopilot)
    try:
        L.run(1.23)
        c.mav.timesync_send(0, 987_654_321)
        end = time.monotonic() + 3.0
        while not L.messages("TIMESYNC") and time.monotonic() < end:
            L._recv(end)
        (t, ts), = L.messages("TIMESYNC")
        assert ts.ts1 == 987_654_321
        assert ts.tc1 == 1_230_000_000 == L.messages("LOCAL_POSITION_NED")[-1][1].time_boot_ms \
            * 1_000_000
    finally:
        c.close()
        srv.stop()


# --- 8. initial heading and parameters from the command line -------------------------------------


@pytest.mark.realtime
def test_initial_heading_and_parameters_from_the_command_line():
    """`mavadrc sitl --heading DEG --param NAME=VALUE` (sim.cli.add_arguments): the vehicle starts
    with that yaw and the autopilot with that parameter value; an unknown parameter name or a
    value its type cannot hold is refused with a clear error before anything starts."""
    from sim import cli

    parser = cli.add_arguments(argparse.ArgumentParser())
    gcs = udp_sink()
    base = ["--offboard-port", str(free_udp_port()), "--gcs-port", str(gcs.getsockname()[1]),
            "--bind-offboard", "0", "--bind-gcs", "0"]
    with pytest.raises(SystemExit, match="unknown parameter 'NOPE_PARAM' for the px4"):
        cli.make_server(parser.parse_args(base + ["--param", "NOPE_PARAM=1"]))
    with pytest.raises(SystemExit, match="NAV_RCL_ACT is an integer"):
        cli.make_server(parser.parse_args(base + ["--param", "NAV_RCL_ACT=2.5"]))
    with pytest.raises(SystemExit, match="NAME=VALUE"):
        cli.make_server(parser.parse_args(base + ["--param", "COM_SPOOLUP_TIME"]))
    with pytest.raises(SystemExit, match="SIM_ARMING_DELAY"):  # an ArduPilot one on PX4
        cli.make_server(parser.parse_args(base + ["--param", "SIM_ARMING_DELAY=0"]))
    args = parser.parse_args(base + ["--heading", "90", "--param", "COM_SPOOLUP_TIME=0",
                                     "--param", "NAV_RCL_ACT=3"])
    srv = cli.make_server(args)
    port = args.offboard_port
    srv.start()
    c = Client(port)
    try:
        c.heartbeat()
        att = c.recv("ATTITUDE")
        assert math.degrees(att.yaw) == pytest.approx(90.0, abs=0.01)
        assert srv.params["COM_SPOOLUP_TIME"][0] == 0.0 and srv.params["NAV_RCL_ACT"][0] == 3
        c.mav.param_request_read_send(1, 1, b"NAV_RCL_ACT", -1)
        pv = c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "NAV_RCL_ACT")
        assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == 3
        # armed on the ground the heading stays
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        time.sleep(0.5)
        assert math.degrees(srv.vehicle.reported().euler[2]) == pytest.approx(90.0, abs=0.5)
    finally:
        c.close()
        srv.stop()
        gcs.close()


# --- 9. lockstep stays deterministic -------------------------------------------------------------


def ardupilot_hop(seed):
    """Arming delay, a thrust hop with the angle boost, a hard touchdown, the land detector."""
    srv, c, L = lockstep("ardupilot", {"GUID_OPTIONS": 8, "SIM_ARMING_DELAY": 0.5},
                         wind="moderate_gusts", seed=seed)
    try:
        hover = srv.vehicle.hover_thrust
        q = (math.cos(0.1), math.sin(0.1), 0.0, 0.0)
        start_ap_guided_nogps(L, thrust=0.0)
        L.run(1.5, q=q, thrust=1.4 * hover)
        L.run(2.5, thrust=0.0)
        return srv.vehicle.state, landed_states(L), [x for t, x in L.texts()]
    finally:
        c.close()
        srv.stop()


def test_lockstep_flights_with_the_autopilot_rules_are_identical():
    """Same seed, same flight: the autopilot's rules run on vehicle time only."""
    a, b = ardupilot_hop(7), ardupilot_hop(7)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1] and a[2] == b[2]
    assert ON_GROUND in [s for t, s in a[1]] and IN_AIR in [s for t, s in a[1]]
