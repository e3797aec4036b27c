"""Autopilot personalities of the bundled vehicle: how PX4 and ArduCopter look on the wire.

The personality is the only place where the two differ; the autopilot (:mod:`sim.autopilot`)
and the MAVLink handlers (:mod:`sim.mavlink`) ask it and never test which one it is (as
ArduPilot's GCS_MAVLINK lets each vehicle override only what differs).  A personality owns the
heartbeat identity, the custom-mode encoding, the mapping from a mode command to one of the
vehicle's behaviours, the parameter set and the offboard rules: which mode takes setpoints and
when, how an attitude setpoint is flown (PX4: as sent; ArduCopter: GUIDED's attitude control,
:class:`GuidedAngleControl`), which parameter times out a silent stream and what follows.  The
vehicle's behaviours (the ``Behaviour`` names) are shared: hold, takeoff, land, rtl, and the one
that accepts external setpoints, offboard (PX4 OFFBOARD, ArduPilot GUIDED / GUIDED_NOGPS).

It also owns what makes each autopilot less kind than a simulator (see the design notes,
MAVLINK.md section 9): when heartbeats go out, how long the motors stay at idle after arming,
the land detector, when the autopilot disarms by itself, the offboard-loss failsafe, which
messages it can stream and the MAV_RESULT of a refusal.  Each rule names the source file of the
real autopilot it follows (PX4-Autopilot and ArduPilot as of 2026).
"""

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavadrc.control.geometry import GRAVITY
from mavadrc.control.rotations import euler_from_quat, level_quat

log = logging.getLogger("mavadrc.sitl")

#: the message each autopilot's simulator sends its true state in, and the earth radius (m) it
#: projects its local frame with (PX4 SIH: CONSTANTS_RADIUS_OF_EARTH; ArduPilot SITL: the radius
#: of its LOCATION_SCALING_FACTOR).  The companion reads them back with its own table,
#: mavadrc.flight.truth.SOURCES; tests/test_truth.py holds the two equal.
TRUTH_RADIUS = {"HIL_STATE_QUATERNION": 6371000.0, "SIM_STATE": 6378137.0}

# behaviours of the simulated autopilot
HOLD = "hold"
TAKEOFF = "takeoff"
LAND = "land"
RTL = "rtl"
OFFBOARD = "offboard"  # PX4 OFFBOARD and ArduPilot GUIDED / GUIDED_NOGPS: external setpoints
# a mode flown on the pilot's sticks (ArduCopter's LOITER, ALT_HOLD, POSHOLD: the throttle stick
# is a climb rate).  The bundled vehicle has no pilot: its throttle sits at minimum, as an
# ArduPilot SITL's does when nothing drives its RC, and the vehicle descends at the pilot's
# full descent rate (here within the bundled firmware's 1.5 m/s descent limit) until it lands (flown on ArduCopter SITL: a companion's hold in LOITER sank
# from 3 m and met the ground at 2.49 m/s, PILOT_SPEED_UP's 2.5)
PILOT = "pilot"

INT = mavlink.MAV_PARAM_TYPE_INT32
REAL = mavlink.MAV_PARAM_TYPE_REAL32


@dataclass(frozen=True)
class Mode:
    name: str
    custom_mode: int
    behaviour: str
    armable: bool = True


def px4_custom_mode(main, sub=0):
    return (main << 16) | (sub << 24)


PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6,
            "STABILIZED": 7}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}


class Hysteresis:
    """PX4's systemlib::Hysteresis as its land detector uses it: the state becomes true once the
    condition has held for ``rise`` seconds, and false at once."""

    def __init__(self, rise, state=True):
        self.rise = float(rise)
        self.state = state
        self._held = 0.0

    def update(self, cond, dt):
        if not cond:
            self.state = False
            self._held = 0.0
        elif not self.state:
            self._held += dt
            if self._held >= self.rise - 1e-9:
                self.state = True
        return self.state

    def set(self, state):
        self.state = state
        self._held = 0.0


@dataclass
class LandInputs:
    """What a land detector reads each step: the collective thrust the vehicle is asked for
    (normalized), the measured velocity (NED, m/s) and roll/pitch rate norm (rad/s), the tilt of
    the attitude target (rad), whether the altitude is under closed-loop climb-rate control and
    the descent rate (m/s, down) the position loop commands (inf when no position loop runs:
    landing, or idle on the ground)."""
    thrust: float
    velocity: tuple
    rates_xy: float
    target_tilt: float
    climb_rate_control: bool
    descent_cmd: float


class PX4LandDetector:
    """PX4's multicopter land detector (src/modules/land_detector/MulticopterLandDetector.cpp,
    LandDetector.cpp), without a distance sensor: land detection time 1 s, in three hysteresis
    stages of 1/3 s each (ground contact -> maybe landed -> landed); any stage clears at once.

    - ground contact: thrust <= MPC_THR_MIN + (hover - MPC_THR_MIN) * 0.3 (0.6 with a hover
      thrust estimate, i.e. under climb-rate control), |vz| < LNDMC_Z_VEL_MAX (x 2.5 once landed),
      |vxy| <= LNDMC_XY_VEL_MAX, and under climb-rate control a commanded descent (faster than
      1.1 LNDMC_Z_VEL_MAX) unless already (maybe) landed;
    - maybe landed: ground contact, roll/pitch rate <= LNDMC_ROT_MAX (x 2.5 once landed) and
      "minimum thrust": under climb-rate control thrust <= MPC_THR_MIN + (hover - MPC_THR_MIN) *
      0.1, otherwise (offboard attitude, manual) thrust <= MPC_MANTHR_MIN + 0.01;
    - landed: maybe landed for another 1/3 s.

    So an armed vehicle sitting on the ground with offboard thrust above 0.09 reports IN_AIR, as
    PX4 does, and a vehicle whose thrust is cut reports ON_GROUND about 1 s later.
    """

    STAGE_S = 1.0 / 3.0

    def __init__(self):
        self.ground_contact = Hysteresis(self.STAGE_S)
        self._maybe = Hysteresis(self.STAGE_S)
        self._landed = Hysteresis(self.STAGE_S)

    @property
    def landed(self):
        return self._landed.state

    @property
    def maybe_landed(self):
        return self._maybe.state

    def reset(self):
        for h in (self.ground_contact, self._maybe, self._landed):
            h.set(True)

    def update(self, dt, params, armed, u):
        if not armed:
            self.reset()
            return
        p = lambda name: float(params[name][0])  # noqa: E731
        hover, thr_min = p("MPC_THR_HOVER"), p("MPC_THR_MIN")
        was_landed = self._landed.state
        vz_max = p("LNDMC_Z_VEL_MAX") * (2.5 if was_landed else 1.0)
        vx, vy, vz = u.velocity
        low = u.thrust <= thr_min + (hover - thr_min) * (0.6 if u.climb_rate_control else 0.3)
        contact = low and abs(vz) < vz_max and math.hypot(vx, vy) <= p("LNDMC_XY_VEL_MAX")
        if u.climb_rate_control and not self._maybe.state and not was_landed:
            contact = contact and u.descent_cmd >= 1.1 * p("LNDMC_Z_VEL_MAX")
        self.ground_contact.update(contact, dt)
        if u.climb_rate_control:
            min_thrust = thr_min + (hover - thr_min) * 0.1
        else:
            min_thrust = p("MPC_MANTHR_MIN") + 0.01
        rot_max = math.radians(p("LNDMC_ROT_MAX")) * (2.5 if was_landed else 1.0)
        self._maybe.update(u.thrust <= min_thrust and u.rates_xy <= rot_max
                           and self.ground_contact.state, dt)
        self._landed.update(self._maybe.state, dt)


class ArduCopterLandDetector:
    """ArduCopter's land detector (ArduCopter/land_detector.cpp, constants in config.h).

    Landed (ap.land_complete) once, for LAND_DETECTOR_TRIGGER_SEC (1.0 s) in a row, the motors
    are at their lower throttle limit, the target lean is under 15 deg (LAND_CHECK_LARGE_ANGLE_CD),
    the 1 Hz low-passed earth-frame acceleration is under LAND_DETECTOR_ACCEL_MAX (1 m/s/s) and
    |vz| < LAND_DETECTOR_VEL_Z_MAX (1 m/s); the filter is what makes a 1.7 m/s touchdown read
    as landed ~1.4 s later.  Maybe landed after LAND_DETECTOR_MAYBE_TRIGGER_SEC (0.2 s).  Landing
    is cleared by the flight mode when it is asked for positive thrust or climb (mode_guided.cpp
    angle_control_run: "landed with positive desired climb rate or thrust, takeoff").
    """

    TRIGGER_S = 1.0
    MAYBE_S = 0.2
    ACCEL_MAX = 1.0
    VEL_Z_MAX = 1.0
    LARGE_ANGLE = math.radians(15.0)
    ACCEL_CUTOFF_HZ = 1.0

    def __init__(self):
        self.reset()

    def reset(self):
        self.landed = True
        self._count = 0.0
        self._acc_f = [0.0, 0.0, 0.0]
        self._v_prev = None

    @property
    def maybe_landed(self):
        return self.landed or self._count >= self.MAYBE_S

    def update(self, dt, params, armed, u):
        v = u.velocity
        if self._v_prev is not None and dt > 0.0:
            alpha = dt / (dt + 1.0 / (2.0 * math.pi * self.ACCEL_CUTOFF_HZ))
            for i in range(3):
                self._acc_f[i] += alpha * ((v[i] - self._v_prev[i]) / dt - self._acc_f[i])
        self._v_prev = tuple(v)
        if not armed:
            self.landed = True
            self._count = 0.0
            return
        if self.landed:
            if u.thrust > 0.0:  # the mode asks for lift: take-off
                self.landed = False
                self._count = 0.0
            return
        acc = math.sqrt(sum(a * a for a in self._acc_f))
        if (u.thrust <= 0.0 and u.target_tilt <= self.LARGE_ANGLE and acc <= self.ACCEL_MAX
                and abs(v[2]) < self.VEL_Z_MAX):
            self._count += dt
            if self._count >= self.TRIGGER_S - 1e-9:
                self.landed = True
        else:
            self._count = 0.0


@dataclass
class GuidedTarget:
    """ArduCopter GUIDED's attitude target (mode_guided.cpp guided_angle_state): attitude,
    thrust or climb rate (m/s), which of the two, vehicle time of the update, body rates (None:
    not given) and the type_mask the attitude controller gets."""
    q: np.ndarray
    value: float
    use_thrust: bool
    t: float
    rates: list = None
    mask: int = 7
    timed_out: bool = False


class GuidedAngleControl:
    """ArduCopter GUIDED's attitude control (mode_guided.cpp angle_control_run), run by the
    autopilot each step while armed and past the arming delay, on the target of the last
    SET_ATTITUDE_TARGET (:meth:`ArduCopter.attitude_setpoint`; a PX4 vehicle never sets one).

    No new target for GUID_TIMEOUT s: level at the target's heading and hold the climb rate at
    zero (the thrust, if it was thrust, becomes a climb rate).  On the ground (land detector)
    without positive thrust or climb: motors at idle.  Otherwise thrust (GUID_OPTIONS bit 3)
    through the angle boost, or the climb-rate loop.
    """

    def __init__(self):
        self.target = None
        self.climb_i = 0.0  # climb-rate loop integrator (m/s^2)

    def take(self, sp, params, t):
        """Make attitude setpoint ``sp`` (:class:`sim.autopilot.AttitudeSetpoint`), received at
        vehicle time ``t``, the target; returns what ATTITUDE_TARGET then echoes (q, thrust,
        rates, type_mask).  Thrust is a climb rate (0.5: hold, PILOT_SPEED_UP / _DN at the
        ends) unless GUID_OPTIONS bit 3 makes it thrust; a setpoint that ignores the throttle
        asks for a climb rate of zero."""
        use_thrust = bool(int(params["GUID_OPTIONS"][0]) & 8) and not sp.throttle_ignored
        th = 0.5 if sp.throttle_ignored else sp.thrust
        if use_thrust:
            value = sp.thrust
        else:
            up = float(params["PILOT_SPEED_UP"][0]) / 100.0
            dn = float(params["PILOT_SPEED_DN"][0]) / 100.0
            value = (th - 0.5) * 2.0 * (up if th >= 0.5 else dn)
        q = np.array([1.0, 0.0, 0.0, 0.0] if sp.attitude_ignored else sp.q, dtype=float)
        self.target = GuidedTarget(q, value, use_thrust, t,
                                   None if sp.rates_ignored else sp.rates,
                                   sp.mask & ~mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE)
        return q, th, sp.rates, sp.mask

    def output(self, dt, vehicle, params, timeout, landed, reported):
        """Set the vehicle's attitude target for this step: ``timeout`` is GUID_TIMEOUT (s),
        ``landed`` the land detector's state, ``reported()`` the vehicle's reported state."""
        g = self.target
        if not g.timed_out and vehicle.time - g.t > timeout + 1e-9:
            g.q = level_quat(euler_from_quat(g.q)[2])
            g.rates, g.mask = None, 7
            g.value, g.use_thrust, g.timed_out = 0.0, False, True
            self.climb_i = 0.0
            log.info("GUIDED: no attitude target for GUID_TIMEOUT: level, climb rate zero")
        if landed and not g.value > 0.0:
            vehicle.set_attitude_target(level_quat(float(reported().euler[2])), 0.0)
            self.climb_i = 0.0
            return
        if g.use_thrust:
            thrust = self._angle_boost(g.value, params, reported().quaternion)
        else:
            thrust = self._climb_thrust(g, dt, params, reported().velocity)
        vehicle.set_attitude_target(g.q, thrust, body_rates=g.rates, type_mask=g.mask)

    @staticmethod
    def _angle_boost(thrust, params, q):
        """AC_AttitudeControl_Multi::get_throttle_boosted, as GUIDED's set_throttle_out(thrust,
        true, ...) applies it: thrust x inverted_factor / cos(tilt), where cos(tilt) is the
        measured cos(roll) cos(pitch), the boost factor clamped to cos >= 0.1 and
        inverted_factor = clamp(10 cos(tilt), 0, 1); off with ATC_ANGLE_BOOST 0.  The motors
        clip the result to 0..1."""
        if int(params["ATC_ANGLE_BOOST"][0]):
            c = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
            thrust = thrust * min(max(10.0 * c, 0.0), 1.0) / min(max(c, 0.1), 1.0)
        return min(max(thrust, 0.0), 1.0)

    def _climb_thrust(self, g, dt, params, velocity):
        """GUIDED without GUID_OPTIONS bit 3: thrust is a climb rate; a PI climb-rate loop
        (its integrator winds the throttle down to its lower limit on the ground, as
        ArduCopter's, so that the land detector can see a landing)."""
        err = g.value + velocity[2]  # climb rate asked minus climb rate measured (m/s)
        self.climb_i = min(max(self.climb_i + 2.0 * err * dt, -GRAVITY), GRAVITY)
        hover = float(params["MOT_THST_HOVER"][0])
        q = g.q
        tilt = max(0.3, 1.0 - 2.0 * (q[1] ** 2 + q[2] ** 2))
        thrust = hover * (1.0 + (3.0 * err + self.climb_i) / GRAVITY) / tilt
        return min(max(thrust, 0.0), 1.0)


@dataclass
class Personality:
    name: str
    autopilot: int
    modes: dict
    initial_mode: str
    params: list  # (name, default, MAV_PARAM_TYPE)
    capabilities: int
    bytewise_params: bool
    flight_sw_version: int
    mode_aliases: dict = field(default_factory=dict)
    sysid_param: str = "MAV_SYS_ID"
    hover_param: str = "MPC_THR_HOVER"
    #: parameter holding the thrust curve factor the autopilot linearises its motor outputs with
    thrust_model_param: str = "THR_MDL_FAC"
    #: a heartbeat goes out at once when the mode changes (besides the 1 Hz one)
    heartbeat_on_mode_change: bool = False
    #: parameter (s) holding the motors at idle after arming; setpoints meanwhile do nothing
    spoolup_param: str = "COM_SPOOLUP_TIME"
    #: parameter (s) after which a silent setpoint stream counts as lost
    offboard_timeout_param: str = "COM_OF_LOSS_T"
    #: a lost setpoint stream triggers the failsafe of offboard_loss_action (otherwise the
    #: offboard mode copes with it itself)
    offboard_loss_failsafe: bool = False
    #: arming in the offboard mode and switching to it need a live setpoint stream
    offboard_needs_stream: bool = False
    #: setpoints outside the offboard mode are ignored (not stored, not proof of life)
    setpoints_only_in_offboard: bool = False
    #: switching to the offboard mode in the air holds the position until a setpoint comes
    offboard_entry_holds: bool = False
    #: position targets are flown from the ground (PX4: a target above the vehicle takes it
    #: off); False: ignored while the vehicle is landed, a takeoff command lifts it first
    #: (ArduCopter's GUIDED: pos_control_run does nothing disarmed or landed)
    position_targets_on_ground: bool = True
    #: the mode MAV_CMD_NAV_TAKEOFF switches to (None: a takeoff only in the offboard mode)
    takeoff_mode: str = None
    #: the mode the takeoff mode hands over to once the takeoff altitude is reached
    mode_after_takeoff: str = None
    #: MAV_RESULTs of refusals
    arming_refused: int = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    interval_refused: int = mavlink.MAV_RESULT_FAILED
    request_refused: int = mavlink.MAV_RESULT_DENIED
    #: SET_MESSAGE_INTERVAL(HEARTBEAT) is accepted (and ignored: always 1 Hz)
    heartbeat_interval_settable: bool = False
    #: MAVLink ids it can stream or send on request (None: every one the vehicle builds)
    messages: frozenset = None
    #: after a failsafe has landed and disarmed the vehicle, it goes back to the mode it was in
    #: before the failsafe (PX4's user intention: measured on PX4 SITL, an offboard-loss
    #: failsafe, then a land command, then "Disarmed by landing", and the heartbeat shows
    #: OFFBOARD again)
    restores_mode_after_failsafe: bool = False
    #: STATUSTEXTs (None: the autopilot says nothing)
    disarm_denied_text: str = None
    landing_text: str = None
    takeoff_text: str = None
    #: how a link short of bandwidth slows its streams: "rate_mult" (PX4: every stream's
    #: interval stretched by one multiplier sized to the link's data rate) or "payload_space"
    #: (ArduPilot: a message that does not fit in the link's transmit buffer waits for room)
    bandwidth_throttle: str = "rate_mult"
    #: bytes the port of a bandwidth-limited link holds before a message has to wait (or is
    #: dropped): the transmit buffer of the autopilot's telemetry port
    tx_buffer_bytes: int = 3000

    def mode(self, name):
        """The mode called ``name`` or one of its aliases."""
        return self.modes[self.mode_aliases.get(name, name)]

    def mode_from_custom(self, custom_mode):
        for m in self.modes.values():
            if m.custom_mode == custom_mode:
                return m
        return None

    def sends(self, msgid):
        return self.messages is None or msgid in self.messages

    # the rules below are overridden per autopilot

    def base_mode_flags(self, mode):
        """HEARTBEAT base_mode flags in ``mode`` besides CUSTOM_MODE_ENABLED and SAFETY_ARMED."""
        return 0

    def command_mode(self, p2, p3):
        """The mode MAV_CMD_DO_SET_MODE asks for with param2 and param3 (None: no such mode)."""
        raise NotImplementedError

    def message_mode(self, custom_mode):
        """The mode SET_MODE asks for with ``custom_mode`` (None: no such mode)."""
        raise NotImplementedError

    def rtl_altitude(self, params):
        """Minimum altitude (m above home) of the return to launch."""
        raise NotImplementedError

    def land_speed(self, params):
        """m/s: the final descent of the land mode (and of a return's landing)."""
        raise NotImplementedError

    def takeoff_altitude(self, params, p7, home_alt):
        """Takeoff altitude (m above home) of MAV_CMD_NAV_TAKEOFF with param7 ``p7`` (NaN: none
        given) for a home at ``home_alt`` m AMSL; None: the command is denied."""
        raise NotImplementedError

    def attitude_setpoint(self, autopilot, sp):
        """Take SET_ATTITUDE_TARGET ``sp`` (:class:`sim.autopilot.AttitudeSetpoint`) as this
        autopilot does, on ``autopilot`` (:class:`sim.autopilot.Autopilot`); whether it is
        proof of life of the setpoint stream."""
        raise NotImplementedError

    def land_detector(self):
        raise NotImplementedError

    def disarm_allowed(self, ld):
        """A disarm command without force is accepted in this land-detector state."""
        raise NotImplementedError

    def auto_disarm(self, params, t, armed_t, taken_off, landed_since):
        """Reason key for disarming by itself now (None: stay armed)."""
        raise NotImplementedError

    def armed_text(self):
        raise NotImplementedError

    def disarmed_text(self, reason):
        raise NotImplementedError

    def interval_refused_text(self, msgid):
        return None

    def stream_interval(self, msgid, interval_us):
        """A SET_MESSAGE_INTERVAL of ``interval_us`` (> 0) for a message this autopilot sends,
        as its estimator and scheduler can serve it: (MAV_RESULT, the interval the stream then
        runs at in us (None: unchanged), the interval GET_MESSAGE_INTERVAL reports, optional
        STATUSTEXT)."""
        return mavlink.MAV_RESULT_ACCEPTED, interval_us, interval_us, None

    def offboard_loss_action(self, params):
        """(mode name, or 'DISARM' / 'TERMINATE', the failsafe action's name)."""
        return None

    def thrust_model_factor(self, value):
        """The thrust curve factor (rotor thrust fraction = f u^2 + (1 - f) u of motor output u)
        the autopilot really applies for a value of :attr:`thrust_model_param`."""
        raise NotImplementedError

    def default_thrust_model_factor(self):
        """:meth:`thrust_model_factor` of the parameter's default (what a fresh autopilot flies
        with; the in-process fast path uses it as the server does)."""
        default = next(v for name, v, _ in self.params if name == self.thrust_model_param)
        return self.thrust_model_factor(default)


#: PX4's publication rates of the topics behind its streams (Hz): vehicle_local_position,
#: vehicle_global_position and vehicle_odometry come from an EKF2 update, one each
#: EKF2_PREDICT_US (default 10000 us: 100 Hz, src/modules/ekf2/module.yaml); vehicle_attitude
#: from the output predictor on every IMU sample, IMU_INTEG_RATE (default 200 Hz,
#: vehicle_imu/imu_parameters.c).  A stream sends only a sample it has not sent (the
#: streams' ``_sub.update()``), so it runs no faster than its topic, whatever was asked.
PX4_ESTIMATOR_HZ = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 100.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 100.0,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: 100.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 200.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 200.0,
}

#: ArduCopter's main loop, SCHED_LOOP_RATE (default 400 Hz, AP_Scheduler.cpp); GCS_MAVLINK
#: streams no message faster than 0.8 of it (cap_message_interval, GCS_Common.cpp)
ARDUCOPTER_LOOP_HZ = 400.0


class PX4(Personality):
    def stream_interval(self, msgid, interval_us):
        """MavlinkReceiver::set_message_interval configures the stream at the rate asked and
        answers ACCEPTED; the stream then sends each new sample of its topic at most once, so
        faster than the estimator publishes it comes out at the estimator's rate, silently.
        GET_MESSAGE_INTERVAL reports the interval asked (stream->get_interval())."""
        hz = PX4_ESTIMATOR_HZ.get(msgid)
        floor = 0 if hz is None else int(round(1e6 / hz))
        return mavlink.MAV_RESULT_ACCEPTED, max(interval_us, floor), interval_us, None

    def command_mode(self, p2, p3):
        """param2 the main mode, param3 the sub mode (AUTO's only) (commander:
        handle_command DO_SET_MODE)."""
        main = int(p2) if math.isfinite(p2) else 0
        sub = int(p3) if math.isfinite(p3) else 0
        return self.mode_from_custom(px4_custom_mode(main, sub if main == 4 else 0))

    def message_mode(self, custom_mode):
        return self.command_mode((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)

    def rtl_altitude(self, params):
        return float(params["RTL_RETURN_ALT"][0])

    def land_speed(self, params):
        return float(params["MPC_LAND_SPEED"][0])

    def takeoff_altitude(self, params, p7, home_alt):
        """MIS_TAKEOFF_ALT, or param7 (AMSL) if it is at least 1 m above home."""
        if math.isfinite(p7) and p7 - home_alt >= 1.0:
            return p7 - home_alt
        return float(params["MIS_TAKEOFF_ALT"][0])

    def attitude_setpoint(self, autopilot, sp):
        """mavlink_receiver.cpp handle_message_set_attitude_target: in OFFBOARD the attitude
        and the raw thrust go straight to the attitude controller, not held by the spool-up
        (COM_SPOOLUP_TIME gates mc_pos_control's takeoff and manual throttle only); a
        setpoint that ignores the throttle keeps nothing alive (PX4 #27622)."""
        autopilot.att_target = (sp.q, sp.thrust, sp.rates, sp.mask)
        if autopilot.mode.behaviour == OFFBOARD and autopilot.vehicle.armed:
            autopilot.fly_attitude(sp)
        return not sp.throttle_ignored

    def land_detector(self):
        return PX4LandDetector()

    def disarm_allowed(self, ld):
        # Commander::disarm: landed or maybe_landed, else "Disarming denied: not landed"
        return ld.landed or ld.maybe_landed

    def auto_disarm(self, params, t, armed_t, taken_off, landed_since):
        """Commander::handleAutoDisarm: COM_DISARM_LAND s after landing was detected if the
        vehicle took off since arming; otherwise COM_SPOOLUP_TIME + COM_DISARM_PRFLT s after
        arming, in every mode (OFFBOARD included).  A value <= 0 disables the rule."""
        land = float(params["COM_DISARM_LAND"][0])
        prflt = float(params["COM_DISARM_PRFLT"][0])
        if taken_off:
            if land > 0.0 and landed_since is not None and t - landed_since >= land - 1e-9:
                return "landing"
        elif prflt > 0.0:
            if t - armed_t >= float(params["COM_SPOOLUP_TIME"][0]) + prflt - 1e-9:
                return "preflight_inaction"
        return None

    def armed_text(self):
        return "Armed by external command"

    _DISARM_REASONS = {"external": "external command", "landing": "landing",
                       "preflight_inaction": "auto preflight disarming", "failsafe": "failsafe"}

    def disarmed_text(self, reason):
        return f"Disarmed by {self._DISARM_REASONS.get(reason, reason)}"

    # COM_OBL_RC_ACT: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold,
    # 6 Terminate, 7 Disarm (commander_params.c)
    _OBL = {3: ("AUTO.RTL", "RTL"), 4: ("AUTO.LAND", "Land"), 5: ("AUTO.LOITER", "Hold"),
            6: ("TERMINATE", "terminate"), 7: ("DISARM", "disarm")}
    # NAV_RCL_ACT: 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Disarm
    _RCL = {1: ("AUTO.LOITER", "Hold"), 2: ("AUTO.RTL", "RTL"), 3: ("AUTO.LAND", "Land"),
            5: ("TERMINATE", "terminate"), 6: ("DISARM", "disarm")}

    def offboard_loss_action(self, params):
        """failsafe.cpp checkModeFallback: COM_OBL_RC_ACT; its stick-flown modes (Position,
        Altitude, Stabilized) cannot run without manual control, and the bundled vehicle has no
        RC, so the RC-loss action NAV_RCL_ACT follows (default 2, Return).  Return needs a home
        position, which the vehicle has from arming."""
        action = int(params["COM_OBL_RC_ACT"][0])
        if action in self._OBL:
            return self._OBL[action]
        return self._RCL.get(int(params["NAV_RCL_ACT"][0]), ("AUTO.RTL", "RTL"))

    def thrust_model_factor(self, value):
        """THR_MDL_FAC (src/lib/mixer_module/motor_params.c, default 0, range 0..1):
        FunctionMotors::updateValues inverts the curve only for 0 < factor <= 1 and leaves the
        outputs linear in thrust otherwise."""
        v = float(value)
        return v if 1.2e-7 < v <= 1.0 else 0.0


class ArduCopter(Personality):
    def command_mode(self, p2, p3):
        """param2 the mode number (GCS_MAVLINK::handle_command_do_set_mode)."""
        return self.mode_from_custom(int(p2) if math.isfinite(p2) else -1)

    def message_mode(self, custom_mode):
        return self.command_mode(custom_mode, 0)

    def base_mode_flags(self, mode):
        """GCS_MAVLINK_Copter::base_mode: STABILIZE_ENABLED in every mode, GUIDED_ENABLED in
        the guided modes."""
        flags = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if mode.behaviour == OFFBOARD:
            flags |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return flags

    def rtl_altitude(self, params):
        return float(params["RTL_ALT"][0]) / 100.0

    def land_speed(self, params):
        return float(params["LAND_SPEED"][0]) / 100.0

    def takeoff_altitude(self, params, p7, home_alt):
        """param7, the altitude above home, in GUIDED (Mode::do_user_takeoff); denied unless
        it is above home."""
        return p7 if math.isfinite(p7) and p7 > 0.0 else None

    def attitude_setpoint(self, autopilot, sp):
        """GCS_MAVLINK_Copter::handle_message_set_attitude_target, in GUIDED / GUIDED_NOGPS
        only (setpoints_only_in_offboard): every setpoint is proof of life; armed, it becomes
        the target of GUIDED's attitude control (:class:`GuidedAngleControl`), which waits out
        the arming delay."""
        if autopilot.vehicle.armed:
            autopilot.att_target = autopilot.guided.take(sp, autopilot.params,
                                                         autopilot.vehicle.time)
        return True

    def land_detector(self):
        return ArduCopterLandDetector()

    def disarm_allowed(self, ld):
        # AP_Arming_Copter::disarm: "do not allow disarm via mavlink if we think we are flying"
        return ld.landed

    def pilot_descent(self, params):
        """m/s: the descent of a mode flown on the pilot's sticks with the throttle at minimum
        (:data:`PILOT`): PILOT_SPEED_DN, or PILOT_SPEED_UP where that is 0."""
        dn = float(params["PILOT_SPEED_DN"][0])
        return (dn if dn > 0.0 else float(params["PILOT_SPEED_UP"][0])) / 100.0

    def auto_disarm(self, params, t, armed_t, taken_off, landed_since):
        """Copter::auto_disarm_check (motors.cpp): landed, motors at ground idle and throttle
        low for DISARM_DELAY s (0 disables), whatever the mode."""
        delay = float(params["DISARM_DELAY"][0])
        if delay > 0.0 and landed_since is not None and t - landed_since >= delay - 1e-9:
            return "disarm_delay"
        return None

    def armed_text(self):
        return "Arming motors"  # AP_Arming_Copter::arm (sent by SITL builds)

    def disarmed_text(self, reason):
        return "Disarming motors"

    def thrust_model_factor(self, value):
        """MOT_THST_EXPO (AP_MotorsMulticopter, default 0.65 for ArduCopter, range -1..1):
        Thrust_Linearization::apply_thrust_curve_and_volt_scaling constrains it to -1..1.  The
        outputs it makes span MOT_SPIN_MIN..MOT_SPIN_MAX, which the bundled vehicle takes as
        set up to its motors' thrust range (omega_min..omega_max)."""
        return min(max(float(value), -1.0), 1.0)

    def interval_refused_text(self, msgid):
        # GCS_MAVLINK::set_message_interval, SITL builds
        return f"No ap_message for mavlink id ({msgid})"

    def stream_interval(self, msgid, interval_us):
        """GCS_MAVLINK::set_message_interval: the interval in whole milliseconds (truncated;
        under 1 ms: 1 ms); one the main loop cannot serve (interval_ms * 800 < the loop period
        in us, i.e. faster than 0.8 x SCHED_LOOP_RATE) is DENIED with a STATUSTEXT."""
        ms = max(1, int(interval_us) // 1000)
        if ms * 800 < 1e6 / ARDUCOPTER_LOOP_HZ:
            return (mavlink.MAV_RESULT_DENIED, None, None,
                    f"Requested rate for message ID {msgid} too fast. Increase SCHED_LOOP_RATE")
        return mavlink.MAV_RESULT_ACCEPTED, ms * 1000, ms * 1000, None


_CAPS = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
         | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
         | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
         | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
         | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
         | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT)

_WIND_PARAMS = [
    ("SIM_WIND_SPD", 0.0, REAL),  # mean wind speed (m/s) added by the ground station
    ("SIM_WIND_DIR", 0.0, REAL),  # direction it blows from (deg)
    ("SIM_WIND_TURB", 0.0, REAL),  # Dryden turbulence: wind speed at 6 m (m/s) setting its intensity
    ("SIM_WIND_DIR_Z", 0.0, REAL),  # vertical wind (m/s, positive up)
]


def px4():
    P = px4_custom_mode
    modes = {
        "MANUAL": Mode("MANUAL", P(1), HOLD),
        "ALTCTL": Mode("ALTCTL", P(2), HOLD),
        "POSCTL": Mode("POSCTL", P(3), HOLD),
        "OFFBOARD": Mode("OFFBOARD", P(6), OFFBOARD),
        "STABILIZED": Mode("STABILIZED", P(7), HOLD),
        "AUTO.READY": Mode("AUTO.READY", P(4, 1), HOLD),
        "AUTO.TAKEOFF": Mode("AUTO.TAKEOFF", P(4, 2), TAKEOFF),
        "AUTO.LOITER": Mode("AUTO.LOITER", P(4, 3), HOLD),
        "AUTO.RTL": Mode("AUTO.RTL", P(4, 5), RTL, armable=False),
        "AUTO.LAND": Mode("AUTO.LAND", P(4, 6), LAND, armable=False),
    }
    params = [
        ("MAV_SYS_ID", 1, INT),
        ("COM_OF_LOSS_T", 1.0, REAL),
        # 0 Position, 1 Altitude, 2 Stabilized (these three need RC: NAV_RCL_ACT follows),
        # 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm
        ("COM_OBL_RC_ACT", 0, INT),
        ("NAV_RCL_ACT", 2, INT),  # 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Disarm
        ("COM_DISARM_LAND", 2.0, REAL),
        ("COM_DISARM_PRFLT", 10.0, REAL),
        ("COM_SPOOLUP_TIME", 1.0, REAL),  # motors at idle after arming (position control)
        ("MPC_THR_HOVER", 0.5, REAL),
        # thrust model: rel_thrust = f out^2 + (1 - f) out, inverted on the motor outputs
        # (mixer_module/motor_params.c; gz x500 airframes leave the default 0)
        ("THR_MDL_FAC", 0.0, REAL),
        ("MPC_THR_MIN", 0.12, REAL),  # land detector thresholds
        ("MPC_MANTHR_MIN", 0.08, REAL),
        ("LNDMC_Z_VEL_MAX", 0.25, REAL),
        ("LNDMC_XY_VEL_MAX", 1.5, REAL),
        ("LNDMC_ROT_MAX", 20.0, REAL),
        ("MPC_TKO_SPEED", 1.5, REAL),
        ("MPC_LAND_SPEED", 0.7, REAL),
        ("MPC_XY_VEL_MAX", 12.0, REAL),
        ("MIS_TAKEOFF_ALT", 2.5, REAL),
        ("RTL_RETURN_ALT", 30.0, REAL),
        ("SYS_AUTOSTART", 4001, INT),
    ] + _WIND_PARAMS
    return PX4("px4", mavlink.MAV_AUTOPILOT_PX4, modes, "AUTO.LOITER", params,
               _CAPS | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, True,
               (1 << 24) | (15 << 16) | (0 << 8) | 255,
               mode_aliases={"HOLD": "AUTO.LOITER", "LOITER": "AUTO.LOITER", "POSITION": "POSCTL",
                             "LAND": "AUTO.LAND", "TAKEOFF": "AUTO.TAKEOFF",
                             "RTL": "AUTO.RTL", "RETURN": "AUTO.RTL"},
               # HEARTBEAT is a constant-rate 1 Hz stream and nothing else sends one
               # (mavlink_main.cpp, streams/HEARTBEAT.hpp)
               heartbeat_on_mode_change=False,
               # COM_SPOOLUP_TIME gates mc_pos_control's takeoff (Takeoff.cpp) and manual
               # throttle (mc_att_control); offboard attitude setpoints go straight to the
               # attitude controller (PX4.attitude_setpoint)
               spoolup_param="COM_SPOOLUP_TIME",
               # failsafe.cpp: offboard loss after COM_OF_LOSS_T; Commander: OFFBOARD (and
               # arming in it) refused without a setpoint stream; setpoints stored in any mode
               offboard_timeout_param="COM_OF_LOSS_T", offboard_loss_failsafe=True,
               offboard_needs_stream=True,
               # Takeoff.cpp / Navigator: AUTO.TAKEOFF, then Hold at the takeoff altitude
               takeoff_mode="AUTO.TAKEOFF", mode_after_takeoff="AUTO.LOITER",
               restores_mode_after_failsafe=True,
               # Commander: arming/disarming denied -> TEMPORARILY_REJECTED; mavlink_receiver:
               # SET_MESSAGE_INTERVAL without such a stream -> FAILED, REQUEST_MESSAGE -> DENIED
               arming_refused=mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
               interval_refused=mavlink.MAV_RESULT_FAILED,
               request_refused=mavlink.MAV_RESULT_DENIED,
               heartbeat_interval_settable=False,  # set_message_interval: PX4_ERROR
               disarm_denied_text="Disarming denied: not landed",
               landing_text="Landing detected", takeoff_text="Takeoff detected",
               # Mavlink::update_rate_mult: non-constant streams scaled to the data rate
               bandwidth_throttle="rate_mult",
               # TELEM1 (UART7) of fmu-v6x: CONFIG_UART7_TXBUFSIZE=3000 (nuttx defconfig)
               tx_buffer_bytes=3000)


# MAVLink ids with an ap_message (GCS_Common.cpp, map[] in mavlink_id_to_ap_message_id) among
# those the bundled vehicle builds: no ODOMETRY (ArduPilot only receives it) and no DEBUG_VECT
_ARDUPILOT_MESSAGES = frozenset((
    mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, mavlink.MAVLINK_MSG_ID_ATTITUDE,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, mavlink.MAVLINK_MSG_ID_SIM_STATE,
))


def ardupilot():
    modes = {
        "STABILIZE": Mode("STABILIZE", 0, HOLD),
        "ALT_HOLD": Mode("ALT_HOLD", 2, PILOT),
        "AUTO": Mode("AUTO", 3, HOLD),
        "GUIDED": Mode("GUIDED", 4, OFFBOARD),
        "LOITER": Mode("LOITER", 5, PILOT),
        "RTL": Mode("RTL", 6, RTL, armable=False),
        "LAND": Mode("LAND", 9, LAND, armable=False),
        "POSHOLD": Mode("POSHOLD", 16, PILOT),
        # mode_brake.cpp: stops and holds the position and the height, no pilot input; not
        # armable (Mode::allows_arming)
        "BRAKE": Mode("BRAKE", 17, HOLD, armable=False),
        "GUIDED_NOGPS": Mode("GUIDED_NOGPS", 20, OFFBOARD),
    }
    params = [
        ("SYSID_THISMAV", 1, INT),
        ("GUID_OPTIONS", 0, INT),  # bit 3 (8): SET_ATTITUDE_TARGET thrust is thrust, not climb rate
        ("GUID_TIMEOUT", 3.0, REAL),
        ("MOT_THST_HOVER", 0.5, REAL),
        # thrust curve the motor outputs are linearised with (AP_MOTORS_THST_EXPO_DEFAULT)
        ("MOT_THST_EXPO", 0.65, REAL),
        ("PILOT_SPEED_UP", 250, INT),  # cm/s
        ("PILOT_SPEED_DN", 0, INT),  # cm/s; 0: PILOT_SPEED_UP (Copter::get_pilot_speed_dn)
        ("LAND_SPEED", 50, INT),  # cm/s
        ("WPNAV_SPEED_UP", 250, REAL),  # cm/s
        ("DISARM_DELAY", 10, INT),  # s landed before disarming by itself (0: never)
        ("RTL_ALT", 1500, INT),  # cm
        ("ATC_ANGLE_BOOST", 1, INT),  # GUIDED thrust (GUID_OPTIONS bit 3) x 1/cos(tilt)
        # ArduCopter's ARMING_DELAY_SEC is a compile-time constant (ArduCopter/config.h, 2 s),
        # not a parameter; the bundled vehicle offers it as a simulator parameter
        ("SIM_ARMING_DELAY", 2.0, REAL),
    ] + _WIND_PARAMS
    return ArduCopter("ardupilot", mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, modes, "STABILIZE",
                      params, _CAPS | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST, False,
                      (4 << 24) | (6 << 16) | (0 << 8) | 255,
                      sysid_param="SYSID_THISMAV", hover_param="MOT_THST_HOVER",
                      thrust_model_param="MOT_THST_EXPO",
                      # Copter::set_mode ends with gcs().send_message(MSG_HEARTBEAT); arming
                      # and disarming send none
                      heartbeat_on_mode_change=True,
                      # motors.cpp: no motor interlock during the arming delay (motors shut
                      # down, whatever is asked)
                      spoolup_param="SIM_ARMING_DELAY",
                      # mode_guided.cpp: GUID_TIMEOUT levels and holds (GuidedAngleControl),
                      # no failsafe; set_mode(GUIDED) needs no stream and, in the air, holds
                      # the position; attitude and position targets only in the guided modes
                      offboard_timeout_param="GUID_TIMEOUT", offboard_loss_failsafe=False,
                      offboard_needs_stream=False, setpoints_only_in_offboard=True,
                      offboard_entry_holds=True, position_targets_on_ground=False,
                      # GCS_MAVLINK::handle_command_component_arm_disarm: FAILED;
                      # set_message_interval without an ap_message: DENIED;
                      # handle_command_request_message without one: FAILED
                      arming_refused=mavlink.MAV_RESULT_FAILED,
                      interval_refused=mavlink.MAV_RESULT_DENIED,
                      request_refused=mavlink.MAV_RESULT_FAILED,
                      heartbeat_interval_settable=True, messages=_ARDUPILOT_MESSAGES,
                      # GCS_MAVLINK: CHECK_PAYLOAD_SIZE defers a message the port's txspace
                      # cannot take; it goes out on a later pass (update_send)
                      bandwidth_throttle="payload_space",
                      # AP_SERIALMANAGER_MAVLINK_BUFSIZE_TX (AP_SerialManager_config.h)
                      tx_buffer_bytes=256)


def personality(name):
    if name == "px4":
        return px4()
    if name == "ardupilot":
        return ardupilot()
    raise ValueError(f"autopilot must be 'px4' or 'ardupilot' (got {name!r})")
