"""What differs between PX4 and ArduPilot for a companion flying attitude setpoints (or, with
``controller: native``, position targets).

One object per autopilot: the mode that takes our setpoints and how to ask for it, the modes a
failsafe hands the vehicle to, mode names, the parameters that hold the hover thrust and the
motors' start-up delay, and the checks to make before the setpoint stream starts.  Nothing else
in the companion branches on the autopilot's name.
"""

from mavadrc.errors import FlightError
from mavadrc.mavlink.dialect import M, mavutil


def _px4_names():
    """PX4's mode names by (main mode, sub mode) of its custom_mode, as QGroundControl and
    PX4's console write them (POSCTL, AUTO.LOITER), from pymavlink's PX4_CUSTOM_* constants;
    the few PX4 has that pymavlink does not name are added."""
    names = {}
    for key, value in vars(mavutil).items():
        if key.startswith("PX4_CUSTOM_MAIN_MODE_") and key != "PX4_CUSTOM_MAIN_MODE_AUTO":
            names[(value, 0)] = key[len("PX4_CUSTOM_MAIN_MODE_"):]
        elif key.startswith("PX4_CUSTOM_SUB_MODE_AUTO_"):
            names[(mavutil.PX4_CUSTOM_MAIN_MODE_AUTO, value)] = \
                "AUTO." + key[len("PX4_CUSTOM_SUB_MODE_AUTO_"):]
    # px4_custom_mode.h: TERMINATION, AUTO_PRECLAND and AUTO_VTOL_TAKEOFF
    names.update({(9, 0): "TERMINATION", (4, 9): "AUTO.PRECLAND", (4, 10): "AUTO.VTOL_TAKEOFF"})
    return names


PX4_MODES = _px4_names()
PX4_OFFBOARD = (mavutil.PX4_CUSTOM_MAIN_MODE_OFFBOARD, 0)
PX4_HOLD = (mavutil.PX4_CUSTOM_MAIN_MODE_AUTO, mavutil.PX4_CUSTOM_SUB_MODE_AUTO_LOITER)
PX4_LAND = (mavutil.PX4_CUSTOM_MAIN_MODE_AUTO, mavutil.PX4_CUSTOM_SUB_MODE_AUTO_LAND)
PX4_RTL = (mavutil.PX4_CUSTOM_MAIN_MODE_AUTO, mavutil.PX4_CUSTOM_SUB_MODE_AUTO_RTL)


def px4_mode_name(custom_mode):
    """PX4's name of a heartbeat's custom_mode ('OFFBOARD', 'AUTO.LAND'), or its hex."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    if main != mavutil.PX4_CUSTOM_MAIN_MODE_AUTO:
        sub = 0  # only AUTO has sub modes (PX4 leaves the byte 0 otherwise)
    return PX4_MODES.get((main, sub), f"custom_mode {custom_mode:#x}")


def ardupilot_mode_name(custom_mode):
    """ArduCopter's name of a heartbeat's custom_mode ('GUIDED', 'LAND'; pymavlink's table),
    or its number."""
    return mavutil.mode_mapping_acm.get(custom_mode, f"custom_mode {custom_mode}")


def mode_name(autopilot, custom_mode):
    """The name of ``custom_mode`` on ``autopilot`` ('px4', 'ardupilot' or None: unknown)."""
    if autopilot == "px4":
        return px4_mode_name(custom_mode)
    if autopilot == "ardupilot":
        return ardupilot_mode_name(custom_mode)
    return f"custom_mode {custom_mode:#x}"


_AP_NUMBER = {name: number for number, name in mavutil.mode_mapping_acm.items()}
AP_GUIDED_NOGPS = _AP_NUMBER["GUIDED_NOGPS"]
AP_GUIDED = _AP_NUMBER["GUIDED"]
AP_LOITER = _AP_NUMBER["LOITER"]
AP_BRAKE = _AP_NUMBER["BRAKE"]
AP_LAND = _AP_NUMBER["LAND"]
AP_RTL = _AP_NUMBER["RTL"]
AP_SMART_RTL = _AP_NUMBER["SMART_RTL"]


class Sequence:
    name = "?"
    title = "?"  # as the console names it
    control_mode = "?"  # the mode that takes our setpoints
    hover_param = None
    motor_delay_param = None  # the parameter holding how long the motors need after arming
    motor_delay_default = 0.0  # s; the autopilot's default, or its constant
    #: streams a companion does not use that the autopilot sends on its link by default
    unused_streams = ()
    #: after touchdown, disarm by the autopilot's land mode (its landing detector cannot see
    #: the ground while it takes our thrust)
    land_to_disarm = False
    #: whether the autopilot has DEBUG_VECT (the bundled vehicle's truth rides on it)
    debug_vect = True
    #: the message its simulator sends the vehicle's true state in (mavadrc.flight.truth), if asked
    truth_message = None
    #: the vehicle leaves the ground by MAV_CMD_NAV_TAKEOFF before it flies position targets
    #: (``controller: native``; False: the targets lift it off)
    takeoff_command = False

    def request_control(self, link):
        """Ask for the mode that takes our setpoints; returns the :class:`~mavadrc.mavlink.commands.Command`."""
        raise NotImplementedError

    def request_hold(self, link):
        raise NotImplementedError

    def in_control(self, heartbeat):
        """Whether ``heartbeat`` shows the mode that takes our setpoints."""
        raise NotImplementedError

    def is_hold(self, heartbeat):
        raise NotImplementedError

    def is_landing(self, heartbeat):
        """Whether the autopilot is bringing the vehicle down (land, or return and land)."""
        raise NotImplementedError

    def mode_name(self, custom_mode):
        return mode_name(self.name, custom_mode)

    def preflight(self, link, safety, say, read_param, sources):
        """Checks and settings before the setpoint stream (and a lockstep clock) starts, on
        ``link``, as the mission's ``safety`` allows; ``say`` tells the user, ``read_param``
        reads a parameter with a default, ``sources`` keeps where a setting came from."""

    def release(self, link):
        """After the flight, disarmed: out of the setpoint mode (into the hold mode, as
        MAVSDK's offboard.stop() does), so the next companion does not find it taken."""
        return self.request_hold(link)

    def thrust_factor(self, cos_tilt):
        """What the autopilot multiplies the thrust we send by, to be divided out (1: none),
        the vehicle tilted by the angle of cosine ``cos_tilt``."""
        return 1.0


class PX4Sequence(Sequence):
    """PX4: OFFBOARD (setpoints must already stream), Hold (AUTO.LOITER), AUTO.LAND."""

    name = "px4"
    title = "PX4"
    control_mode = "OFFBOARD"
    hover_param = "MPC_THR_HOVER"
    # the ESCs' spool-up time PX4 gives its own takeoff (mc_pos_control); in OFFBOARD attitude
    # control PX4 applies our thrust at once, so the flight waits it out itself
    motor_delay_param = "COM_SPOOLUP_TIME"
    motor_delay_default = 1.0
    unused_streams = (M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                      M.MAVLINK_MSG_ID_ODOMETRY)
    truth_message = "HIL_STATE_QUATERNION"  # SIH's ground truth (a real PX4 has none to send)

    def request_control(self, link):
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, *PX4_OFFBOARD)

    def request_hold(self, link):
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, *PX4_HOLD)

    @staticmethod
    def _modes(heartbeat):
        c = heartbeat.custom_mode
        return (c >> 16) & 0xFF, (c >> 24) & 0xFF

    def in_control(self, heartbeat):
        return self._modes(heartbeat)[0] == PX4_OFFBOARD[0]

    def is_hold(self, heartbeat):
        return self._modes(heartbeat) == PX4_HOLD

    def is_landing(self, heartbeat):
        return self._modes(heartbeat) in (PX4_LAND, PX4_RTL)


class ArduPilotSequence(Sequence):
    """ArduCopter: GUIDED_NOGPS with GUID_OPTIONS bit 3 (thrust means thrust), BRAKE to hold,
    LAND; LOITER once disarmed.

    The hold is BRAKE, never LOITER: LOITER (like ALT_HOLD and POSHOLD) flies the pilot's
    throttle stick as a climb rate, so with the stick at minimum, or no pilot at all, it sinks
    at the pilot's full descent rate. Flown on ArduCopter SITL, a companion's hold in LOITER
    met the ground from 3 m at 2.49 m/s. BRAKE stops the vehicle and holds its position and
    height with no pilot input (it needs a position estimate: refused without one, and the
    failsafe then lands at once)."""

    name = "ardupilot"
    title = "ArduPilot"
    control_mode = "GUIDED_NOGPS"
    hover_param = "MOT_THST_HOVER"
    # ArduCopter holds the motors at minimum for ARMING_DELAY_SEC after arming: a build
    # constant (ArduCopter/config.h), not a parameter
    motor_delay_param = None
    motor_delay_default = 2.0
    # in GUIDED_NOGPS with thrust setpoints ArduCopter keeps the throttle mix high (no descent
    # is demanded of its position controller, Copter::update_throttle_mix), so its landing
    # detector never fires and a disarm is refused: its LAND mode lands and disarms instead
    land_to_disarm = True
    debug_vect = False  # SET_MESSAGE_INTERVAL for it is DENIED (GCS_Common.cpp)
    truth_message = "SIM_STATE"  # SITL's (SIM::sim_state_send); DENIED on a real vehicle

    def __init__(self):
        self.angle_boost = True  # ATC_ANGLE_BOOST, read in preflight

    def request_control(self, link):
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED_NOGPS)

    def request_hold(self, link):
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_BRAKE)

    def release(self, link):
        """Disarmed on the ground: LOITER, a mode a pilot can arm in (BRAKE is not armable),
        so the next companion does not find the vehicle in ours."""
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_LOITER)

    def in_control(self, heartbeat):
        return heartbeat.custom_mode in (AP_GUIDED_NOGPS, AP_GUIDED)

    def is_hold(self, heartbeat):
        return heartbeat.custom_mode == AP_BRAKE

    def is_landing(self, heartbeat):
        return heartbeat.custom_mode in (AP_LAND, AP_RTL, AP_SMART_RTL)

    def preflight(self, link, safety, say, read_param, sources):
        opts = int(link.param_read("GUID_OPTIONS"))
        if not opts & 8:
            if not safety.set_guid_options:
                raise FlightError(
                    "ArduPilot's GUID_OPTIONS bit 3 is clear, so SET_ATTITUDE_TARGET thrust "
                    "would be read as a climb rate, not thrust; set GUID_OPTIONS |= 8 on the "
                    "vehicle, or put 'set_guid_options: true' under safety: in the mission to "
                    "let mavadrc set it")
            got = int(link.param_set("GUID_OPTIONS", opts | 8, M.MAV_PARAM_TYPE_INT32))
            if not got & 8:
                raise FlightError("the vehicle did not accept GUID_OPTIONS bit 3")
            say(f"set GUID_OPTIONS to {got} (thrust means thrust)")
        # GUIDED multiplies the thrust it is sent by 1/cos(lean angle) when ATC_ANGLE_BOOST is
        # on (AC_AttitudeControl_Multi::get_throttle_boosted)
        boost = read_param("ATC_ANGLE_BOOST", 1.0)
        self.angle_boost = bool(boost)
        sources["angle_boost"] = (
            f"ATC_ANGLE_BOOST {int(boost)}: thrust sent x cos(lean angle)" if self.angle_boost
            else "ATC_ANGLE_BOOST 0: thrust sent as computed")

    def thrust_factor(self, cos_tilt):
        if not self.angle_boost:
            return 1.0
        # ArduCopter divides by cos of the current lean angle, clamped at 0.1
        return max(0.1, cos_tilt)


class ArduPilotNativeSequence(ArduPilotSequence):
    """ArduCopter flying its own position controller (``controller: native``): GUIDED, which
    takes SET_POSITION_TARGET_LOCAL_NED (GUIDED_NOGPS does not).  GUIDED flies no position
    target while the vehicle is on the ground (ModeGuided: disarmed or landed, nothing runs,
    and the target replaces a takeoff under way): the vehicle leaves the ground by
    MAV_CMD_NAV_TAKEOFF and takes the targets once it is off (:attr:`takeoff_command`).
    Thrust is never sent, so GUID_OPTIONS is not read."""

    control_mode = "GUIDED"
    #: the vehicle leaves the ground on MAV_CMD_NAV_TAKEOFF, not on position targets
    takeoff_command = True

    def request_control(self, link):
        return link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED)

    def preflight(self, link, safety, say, read_param, sources):
        self.angle_boost = False  # no thrust is sent


def sequence_for(autopilot, kind=None):
    """The :class:`Sequence` of ``autopilot`` for a flight of controller ``kind``."""
    if autopilot == "px4":
        return PX4Sequence()
    return ArduPilotNativeSequence() if kind == "native" else ArduPilotSequence()
