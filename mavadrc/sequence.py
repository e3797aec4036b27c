"""What differs between PX4 and ArduPilot for a companion flying attitude setpoints.

One object per autopilot: the mode that takes our setpoints and how to ask for it, the modes a
failsafe hands the vehicle to, the parameter that holds the hover thrust, how to read a mode
number, and the checks to make before the setpoint stream starts.  Nothing else in the companion
branches on the autopilot's name.
"""

from .link import FlightError, M

PX4_OFFBOARD = (6, 0)
PX4_HOLD = (4, 3)
AP_GUIDED_NOGPS = 20
AP_GUIDED = 4
AP_LOITER = 5


class Sequence:
    name = "?"
    control_mode = "?"  # the mode that takes our setpoints
    hover_param = None

    def request_control(self, link):
        """Ask for the mode that takes our setpoints."""
        raise NotImplementedError

    def request_hold(self, link):
        raise NotImplementedError

    def in_control(self, heartbeat):
        """Whether ``heartbeat`` shows the mode that takes our setpoints."""
        raise NotImplementedError

    def preflight(self, flight):
        """Checks and settings before the setpoint stream (and a lockstep clock) starts."""


class PX4Sequence(Sequence):
    """PX4: OFFBOARD (setpoints must already stream), Hold (AUTO.LOITER)."""

    name = "px4"
    control_mode = "OFFBOARD"
    hover_param = "MPC_THR_HOVER"

    def request_control(self, link):
        link.command(M.MAV_CMD_DO_SET_MODE, 1, *PX4_OFFBOARD)

    def request_hold(self, link):
        link.command(M.MAV_CMD_DO_SET_MODE, 1, *PX4_HOLD)

    def in_control(self, heartbeat):
        return (heartbeat.custom_mode >> 16) & 0xFF == PX4_OFFBOARD[0]


class ArduPilotSequence(Sequence):
    """ArduCopter: GUIDED_NOGPS with GUID_OPTIONS bit 3 (thrust means thrust), LOITER."""

    name = "ardupilot"
    control_mode = "GUIDED_NOGPS"
    hover_param = "MOT_THST_HOVER"

    def request_control(self, link):
        link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED_NOGPS)

    def request_hold(self, link):
        link.command(M.MAV_CMD_DO_SET_MODE, 1, AP_LOITER)

    def in_control(self, heartbeat):
        return heartbeat.custom_mode in (AP_GUIDED_NOGPS, AP_GUIDED)

    def preflight(self, flight):
        link = flight.link
        opts = int(link.param_read("GUID_OPTIONS"))
        if opts & 8:
            return
        if not flight.m.safety.set_guid_options:
            raise FlightError(
                "ArduPilot's GUID_OPTIONS bit 3 is clear, so SET_ATTITUDE_TARGET thrust would be "
                "read as a climb rate, not thrust; set GUID_OPTIONS |= 8 on the vehicle, or put "
                "'set_guid_options: true' under safety: in the mission to let mavadrc set it")
        got = int(link.param_set("GUID_OPTIONS", opts | 8, M.MAV_PARAM_TYPE_INT32))
        if not got & 8:
            raise FlightError("the vehicle did not accept GUID_OPTIONS bit 3")
        flight.console.say(f"set GUID_OPTIONS to {got} (thrust means thrust)")


def sequence_for(autopilot):
    return PX4Sequence() if autopilot == "px4" else ArduPilotSequence()
