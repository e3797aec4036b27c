"""The bundled vehicle on the wire, driven by pymavlink as a real client would.

Each test starts an in-process vehicle whose offboard link sends to a free loopback port and
talks to it over UDP.
"""

import hashlib
import math
import random
import struct
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl_helpers import NAN, Client, px4_mode, start_vehicle, wait_until

M = mavlink
HOLD = px4_mode(4, 3)
OFFBOARD = px4_mode(6)


def connected(autopilot):
    """A running vehicle of this personality and a client that has heard its heartbeat."""
    srv, port = start_vehicle(autopilot)
    c = Client(port)
    c.heartbeat()
    yield srv, c
    c.close()
    srv.stop()


@pytest.fixture
def px4():
    yield from connected("px4")


@pytest.fixture
def ardupilot():
    yield from connected("ardupilot")


@pytest.mark.realtime
def test_heartbeat_identity_px4(px4):
    srv, c = px4
    hb = c.recv("HEARTBEAT")
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == HOLD == 0x03040000
    assert hb.system_status == M.MAV_STATE_STANDBY
    assert hb.get_header().incompat_flags is not None and hb._msgbuf[0] == 0xFD  # MAVLink 2


@pytest.mark.realtime
def test_instance_shifts_system_id():
    srv, port = start_vehicle("px4", instance=2)
    c = Client(port)
    try:
        hb = c.heartbeat()
        assert hb.get_srcSystem() == 3
    finally:
        c.close()
        srv.stop()


@pytest.mark.realtime
def test_heartbeat_identity_ardupilot(ardupilot):
    srv, c = ardupilot
    hb = c.recv("HEARTBEAT")
    assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == 0  # STABILIZE
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 20) == M.MAV_RESULT_ACCEPTED  # GUIDED_NOGPS
    assert c.recv("HEARTBEAT", cond=lambda m: m.custom_mode == 20) is not None


@pytest.mark.realtime
def test_every_command_gets_an_ack_and_unknown_ones_are_unsupported(px4):
    srv, c = px4
    assert c.command(M.MAV_CMD_DO_SET_SERVO, 1, 1500) == M.MAV_RESULT_UNSUPPORTED
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 42) == M.MAV_RESULT_DENIED  # no such mode
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 3) == M.MAV_RESULT_ACCEPTED


@pytest.mark.realtime
def test_commands_for_another_system_are_dropped_and_counted(px4):
    srv, c = px4
    before = srv.stats.other_target
    c.mav.command_long_send(7, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert c.recv("COMMAND_ACK", timeout=1.0) is None
    assert wait_until(lambda: srv.stats.other_target == before + 1, 2.0)
    assert not srv.vehicle.armed


@pytest.mark.realtime
def test_autopilot_version_and_home_on_request(px4):
    srv, c = px4
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
    av = c.recv("AUTOPILOT_VERSION")
    assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == 0
    home = c.recv("HOME_POSITION")
    assert home.latitude == int(round(47.397742 * 1e7))
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, 9999) == M.MAV_RESULT_DENIED  # as PX4


@pytest.mark.realtime
def test_message_interval_changes_the_rate(px4):
    srv, c = px4
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 100_000) == 0
    c.recv("ATTITUDE")
    t0 = time.monotonic()
    n = 0
    while time.monotonic() - t0 < 1.5:
        if c.recv("ATTITUDE", timeout=0.5):
            n += 1
    assert 12 <= n <= 18  # 10 Hz over 1.5 s
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1) == 0
    end = time.monotonic() + 0.3
    while time.monotonic() < end:  # drain what was already on its way
        c.c.recv_match(blocking=True, timeout=0.05)
    assert c.recv("ATTITUDE", timeout=0.5) is None
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000) == M.MAV_RESULT_FAILED  # PX4


@pytest.mark.realtime
def test_default_telemetry_is_there(px4):
    srv, c = px4
    for name in ("ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                 "ODOMETRY", "SYS_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "SYSTEM_TIME",
                 "BATTERY_STATUS", "ATTITUDE_TARGET"):
        assert c.recv(name, timeout=3.0) is not None, name
    s = c.recv("SYS_STATUS")
    assert s.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK
    e = c.recv("EXTENDED_SYS_STATE")
    assert e.landed_state == M.MAV_LANDED_STATE_ON_GROUND
    o = c.recv("ODOMETRY")
    assert (o.frame_id, o.child_frame_id) == (M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD)


def param_value(m, bytewise):
    if m.param_type == M.MAV_PARAM_TYPE_INT32 and bytewise:
        return struct.unpack("<i", struct.pack("<f", m.param_value))[0]
    return m.param_value


def read_all_params(c):
    c.mav.param_request_list_send(c.c.target_system, 1)
    got = {}
    while True:
        m = c.recv("PARAM_VALUE", timeout=1.0)
        if m is None:
            return got
        got[m.param_id] = m


@pytest.mark.realtime
def test_parameter_protocol_px4(px4):
    srv, c = px4
    got = read_all_params(c)
    names = {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "MPC_THR_HOVER", "MIS_TAKEOFF_ALT",
             "SIM_WIND_SPD", "SIM_WIND_DIR"}
    assert names <= set(got)
    count = {m.param_count for m in got.values()}
    assert count == {len(got)}
    assert sorted(m.param_index for m in got.values()) == list(range(len(got)))
    assert got["MPC_THR_HOVER"].param_value == pytest.approx(srv.vehicle.hover_thrust, rel=1e-6)
    # int parameters travel bytewise on PX4
    c.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 4))[0],
                         M.MAV_PARAM_TYPE_INT32)
    m = c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "COM_OBL_RC_ACT")
    assert param_value(m, True) == 4
    c.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 2.5, M.MAV_PARAM_TYPE_REAL32)
    assert c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "COM_OF_LOSS_T").param_value == 2.5
    c.mav.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    assert c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "COM_OF_LOSS_T").param_value == 2.5
    c.mav.param_request_read_send(1, 1, b"", 0)
    assert c.recv("PARAM_VALUE", cond=lambda m: m.param_index == 0) is not None


@pytest.mark.realtime
def test_parameter_protocol_ardupilot_uses_c_cast(ardupilot):
    srv, c = ardupilot
    got = read_all_params(c)
    assert {"GUID_OPTIONS", "GUID_TIMEOUT", "SIM_WIND_SPD"} <= set(got)
    c.mav.param_set_send(1, 1, b"GUID_OPTIONS", 8.0, M.MAV_PARAM_TYPE_INT32)
    assert c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "GUID_OPTIONS").param_value == 8.0


@pytest.mark.realtime
def test_wind_can_be_changed_from_the_ground_station(px4):
    srv, c = px4
    c.mav.param_set_send(1, 1, b"SIM_WIND_SPD", 3.0, M.MAV_PARAM_TYPE_REAL32)
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "SIM_WIND_SPD")
    c.mav.param_set_send(1, 1, b"SIM_WIND_DIR", 90.0, M.MAV_PARAM_TYPE_REAL32)
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "SIM_WIND_DIR")
    mean = srv.vehicle.wind.mean(np.array([0.0, 0.0, -10.0]))
    assert mean == pytest.approx([0.0, -3.0, 0.0], abs=1e-9)  # from the east blows west


@pytest.mark.realtime
def test_empty_mission_fence_and_rally_lists(px4):
    srv, c = px4
    for kind in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY):
        c.mav.mission_request_list_send(1, 1, kind)
        m = c.recv("MISSION_COUNT", cond=lambda m: m.mission_type == kind)
        assert m is not None and m.count == 0


def stream_for(c, seconds, **att):
    """Stream attitude setpoints at 50 Hz for ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        c.attitude(**att)
        time.sleep(0.02)


@pytest.mark.realtime
def test_offboard_needs_a_setpoint_stream_first(px4):
    srv, c = px4
    assert c.set_mode_px4(6) == M.MAV_RESULT_TEMPORARILY_REJECTED
    # a stream that ignores throttle is not proof of life
    for _ in range(10):
        c.attitude(thrust=0.0, mask=7 | 64)
        time.sleep(0.02)
    assert c.set_mode_px4(6) == M.MAV_RESULT_TEMPORARILY_REJECTED
    for _ in range(5):
        c.attitude(thrust=0.0)
        time.sleep(0.02)
    assert c.set_mode_px4(6) == M.MAV_RESULT_ACCEPTED
    assert c.recv("HEARTBEAT", cond=lambda m: m.custom_mode == OFFBOARD) is not None


def fly_offboard_hover(srv, c, alt=1.0):
    """Offboard with position setpoints, arm, climb to ``alt``; returns when there."""
    for _ in range(5):
        c.position(0, 0, -alt)
        time.sleep(0.02)
    assert c.set_mode_px4(6) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + 10
    while time.monotonic() < end:
        c.position(0, 0, -alt)
        if srv.vehicle.reported().position[2] < -0.9 * alt:
            return
        time.sleep(0.02)
    raise AssertionError("did not climb")


# COM_OBL_RC_ACT 0 (Position) needs RC, which the vehicle has not: NAV_RCL_ACT (Return) follows,
# and a vehicle already over home lands at once
@pytest.mark.realtime
@pytest.mark.parametrize("action, mode, behaviour", [(0, px4_mode(4, 5), "land"),
                                                       (4, px4_mode(4, 6), "land")])
def test_offboard_loss_triggers_the_configured_failsafe_in_time(px4, action, mode, behaviour):
    srv, c = px4
    c.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT",
                         struct.unpack("<f", struct.pack("<i", action))[0], M.MAV_PARAM_TYPE_INT32)
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "COM_OBL_RC_ACT")
    fly_offboard_hover(srv, c)
    c.position(0, 0, -1.0)
    t_stop = time.monotonic()
    text = c.recv("STATUSTEXT", timeout=3.0, cond=lambda m: m.text == "Failsafe activated")
    t_failsafe = time.monotonic()
    assert text is not None
    # COM_OF_LOSS_T (1 s) after the last setpoint on the vehicle's clock, one 500 Hz step
    # late at most; on the wall clock never early (the test's own wake-ups, 0.6 s late beside a
    # busy loop per core, are not the vehicle's)
    fw = srv.autopilot
    assert 1.0 < fw.failsafe_t - fw.last_setpoint_t <= 1.0 + 0.0021
    assert t_failsafe - t_stop > 1.0 - 0.05
    assert c.recv("HEARTBEAT", cond=lambda m: m.custom_mode == mode) is not None
    assert srv.vehicle.mode == behaviour
    assert srv.vehicle.armed and not srv.vehicle.landed
    if behaviour == "land":
        assert wait_until(lambda: srv.vehicle.landed, 10.0)
        assert wait_until(lambda: not srv.vehicle.armed, 5.0)  # COM_DISARM_LAND


@pytest.mark.realtime
def test_arming_rules(px4):
    srv, c = px4
    assert c.set_mode_px4(4, 6) == M.MAV_RESULT_ACCEPTED  # Land: not armable
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert c.set_mode_px4(4, 3) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert c.recv("HEARTBEAT", cond=lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
    assert not srv.vehicle.armed


@pytest.mark.realtime
def test_takeoff_hold_land_and_disarm_by_command(px4):
    srv, c = px4
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, NAN) == \
        M.MAV_RESULT_TEMPORARILY_REJECTED  # disarmed
    c.mav.param_set_send(1, 1, b"MIS_TAKEOFF_ALT", 1.5, M.MAV_PARAM_TYPE_REAL32)
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, NAN) == M.MAV_RESULT_ACCEPTED
    assert c.recv("HEARTBEAT", timeout=8.0, cond=lambda m: m.custom_mode == HOLD) is not None
    assert srv.vehicle.reported().position[2] == pytest.approx(-1.5, abs=0.1)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == \
        M.MAV_RESULT_TEMPORARILY_REJECTED  # flying
    assert c.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
    assert c.recv("EXTENDED_SYS_STATE", timeout=8.0,
                  cond=lambda m: m.landed_state == M.MAV_LANDED_STATE_ON_GROUND) is not None
    assert c.recv("HEARTBEAT", timeout=5.0,
                  cond=lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED) is not None


@pytest.mark.realtime
def test_bad_setpoints_are_rejected_counted_and_announced(px4):
    srv, c = px4
    for _ in range(5):
        c.attitude(thrust=0.0)
        time.sleep(0.02)
    assert c.set_mode_px4(6) == M.MAV_RESULT_ACCEPTED
    before = srv.stats.setpoints_rejected
    c.attitude(q=(NAN, 0, 0, 0), thrust=0.5)
    c.attitude(q=(0.9, 0.1, 0.0, 0.0), thrust=0.5)  # not unit length
    c.attitude(thrust=1.7)
    c.attitude(thrust=math.inf)
    c.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111111000,
                                             NAN, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0)
    assert wait_until(lambda: srv.stats.setpoints_rejected == before + 5, 2.0)
    assert c.recv("STATUSTEXT", cond=lambda m: "rejected" in m.text) is not None
    q, thrust = srv.vehicle.attitude_setpoint
    assert np.all(np.isfinite(q)) and 0.0 <= thrust <= 1.0
    assert srv.vehicle.state[2] == 0.0  # still on the ground, never acted on


@pytest.mark.realtime
def test_ardupilot_attitude_targets_only_in_guided_and_thrust_as_climb_rate(ardupilot):
    srv, c = ardupilot
    c.attitude(thrust=0.9, mask=7)
    assert wait_until(lambda: srv.stats.setpoints_ignored >= 1, 2.0)  # STABILIZE: ignored
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 4) == M.MAV_RESULT_ACCEPTED  # GUIDED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 1.5) == M.MAV_RESULT_ACCEPTED
    assert wait_until(lambda: srv.vehicle.reported().position[2] < -1.4, 8.0)
    # thrust 0.5 = hold altitude (climb rate zero), not half thrust
    stream_for(c, 1.5, thrust=0.5)
    assert abs(srv.vehicle.reported().velocity[2]) < 0.1
    stream_for(c, 1.0, thrust=0.8)  # climb at 0.6 * PILOT_SPEED_UP = 1.5 m/s
    assert srv.vehicle.reported().velocity[2] == pytest.approx(-1.5, abs=0.3)


@pytest.mark.realtime
def test_ardupilot_guid_options_bit_3_makes_thrust_thrust(ardupilot):
    srv, c = ardupilot
    c.mav.param_set_send(1, 1, b"GUID_OPTIONS", 8.0, M.MAV_PARAM_TYPE_INT32)
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "GUID_OPTIONS")
    c.mav.param_set_send(1, 1, b"SIM_ARMING_DELAY", 0.0, M.MAV_PARAM_TYPE_REAL32)  # no 2 s wait
    c.recv("PARAM_VALUE", cond=lambda m: m.param_id == "SIM_ARMING_DELAY")
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 20) == M.MAV_RESULT_ACCEPTED  # GUIDED_NOGPS
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    # thrust 0.5 on a vehicle hovering at hover_thrust < 0.5 climbs away
    stream_for(c, 1.0, thrust=min(1.0, srv.vehicle.hover_thrust * 1.3))
    assert srv.vehicle.reported().velocity[2] < -0.5


@pytest.mark.realtime
def test_ardupilot_guided_timeout_levels_and_holds(ardupilot):
    srv, c = ardupilot
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 4) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 1.0) == M.MAV_RESULT_ACCEPTED
    assert wait_until(lambda: srv.vehicle.reported().position[2] < -0.9, 8.0)
    q = (math.cos(0.05), math.sin(0.05), 0.0, 0.0)  # 5.7 deg roll
    stream_for(c, 0.5, q=q, thrust=0.5)
    t0 = time.monotonic()
    # ArduCopter says nothing when GUID_TIMEOUT runs out: it levels and holds the climb rate
    assert wait_until(lambda: srv.vehicle.attitude_setpoint[0][1] == 0.0, 5.0)
    assert 3.0 - 0.3 <= time.monotonic() - t0 <= 3.0 + 0.3
    assert wait_until(lambda: abs(srv.vehicle.reported().euler[0]) < 0.01, 2.0)
    assert srv.vehicle.mode == "attitude" and abs(srv.vehicle.reported().velocity[2]) < 0.2


def make_signed_client(port, key, link_id=1):
    c = Client(port)
    c.heartbeat()  # learn the vehicle's address before talking
    c.c.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return c


@pytest.mark.realtime
def test_signing_drops_unsigned_and_badly_signed_messages():
    key = hashlib.sha256(b"mavadrc test key").digest()
    srv, port = start_vehicle("px4", signing_key=key)
    plain = Client(port)
    try:
        hb = plain.heartbeat()  # heartbeats come signed but pymavlink reads them anyway
        assert hb is not None
        plain.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        assert wait_until(lambda: srv.stats.unsigned_rejected >= 1, 2.0)
        assert not srv.vehicle.armed
        plain.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        time.sleep(0.2)
        assert srv.stats.unsigned_rejected == 1  # heartbeats may come unsigned
        plain.close()
        wrong = make_signed_client(port, hashlib.sha256(b"another key").digest())
        wrong.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        assert wait_until(lambda: srv.stats.bad_signature >= 1, 2.0)
        assert not srv.vehicle.armed
        wrong.close()
        good = make_signed_client(port, key, link_id=2)
        assert good.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, target_system=1) == 0
        ack_frame = good.recv("HEARTBEAT")
        assert ack_frame._signed
        assert srv.vehicle.armed
        good.close()
    finally:
        srv.stop()


@pytest.mark.realtime
def test_other_component_commands_are_not_answered(px4):
    srv, c = px4
    c.mav.command_long_send(1, 100, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert c.recv("COMMAND_ACK", timeout=0.5) is None
    assert not srv.vehicle.armed


# --- lockstep ------------------------------------------------------------------------------------


class LockstepPilot:
    """Drives a lockstep vehicle: one setpoint per step, waits for the telemetry of the new time."""

    def __init__(self, c, srv):
        self.c = c
        self.srv = srv
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                         10_000) == 0
        self.t_ms = 0

    def step(self, x=0.0, y=0.0, z=-1.0, junk=()):
        for d in junk:
            self.c.c.port.sendto(d, ("127.0.0.1", self.srv.local_ports["offboard"]))
        self.c.position(x, y, z)
        self.t_ms += 10
        m = self.c.recv("LOCAL_POSITION_NED", timeout=5.0,
                        cond=lambda m: m.time_boot_ms >= self.t_ms)
        assert m is not None and m.time_boot_ms == self.t_ms
        return m

    def start(self):
        self.step()
        assert self.c.set_mode_px4(6) == 0
        assert self.c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0


def lockstep_flight(n_steps, junk_per_step=0, seed=0, wind=None):
    srv, port = start_vehicle("px4", lockstep=True, wind=wind, seed=seed)
    c = Client(port)
    rng = random.Random(1234)
    try:
        c.heartbeat()
        pilot = LockstepPilot(c, srv)
        pilot.start()
        frames = sample_frames(c)
        for k in range(n_steps):
            junk = [fuzz_datagram(rng, frames, c) for _ in range(junk_per_step)]
            pilot.step(0.5, -0.5, -1.0, junk)
        return srv.vehicle.state, srv.stats
    finally:
        c.close()
        srv.stop()


def sample_frames(c):
    """Valid frames of the kinds a companion sends, to be mutated."""
    mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
    msgs = [
        M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [1.0, 0, 0, 0], 0, 0, 0, 0.9),
        M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, 0, 5, 5, -5, 0, 0, 0, 0, 0,
                                                        0, 0, 0),
        M.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0),
        M.MAVLink_command_long_message(1, 1, 176, 0, 1, 4, 6, 0, 0, 0, 0),
        M.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", 0.0, M.MAV_PARAM_TYPE_REAL32),
        M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3),
    ]
    return [bytes(m.pack(mav)) for m in msgs]


def fuzz_datagram(rng, frames, c):
    """A random or mutated datagram that pymavlink itself cannot decode as a valid message."""
    check = M.MAVLink(None)
    check.robust_parsing = True
    while True:
        kind = rng.random()
        if kind < 0.3:
            d = rng.randbytes(rng.randint(1, 300))
        elif kind < 0.6:
            f = bytearray(rng.choice(frames))
            for _ in range(rng.randint(1, 4)):
                f[rng.randrange(len(f))] = rng.getrandbits(8)
            d = bytes(f)
        elif kind < 0.8:
            f = rng.choice(frames)
            d = f[: rng.randint(1, len(f) - 1)]  # truncated
        else:
            f = bytearray(rng.choice(frames))
            f[7:10] = rng.getrandbits(24).to_bytes(3, "little")  # unknown message id
            d = bytes(f)
        parsed = check.parse_buffer(d) or []
        check = M.MAVLink(None)
        check.robust_parsing = True
        if not any(m.get_type() not in ("BAD_DATA", "UNKNOWN") for m in parsed):
            return d


def test_lockstep_is_deterministic_and_advances_one_step_per_setpoint():
    a, _ = lockstep_flight(150, wind="moderate_gusts", seed=4)
    b, _ = lockstep_flight(150, wind="moderate_gusts", seed=4)
    assert np.array_equal(a, b)
    assert a[2] < -0.05  # it did fly: the position target lifted it


@pytest.mark.slow
def test_fuzzed_datagrams_are_dropped_and_change_nothing():
    """100 000 random, mutated, truncated and unknown datagrams between the setpoints."""
    ref, _ = lockstep_flight(1000)
    fuzzed, stats = lockstep_flight(1000, junk_per_step=100)
    assert np.array_equal(ref, fuzzed)
    assert stats.dropped() >= 100_000
