"""COMMAND_LONG / COMMAND_INT and SET_MODE: every command answered with one COMMAND_ACK.

Arming, disarming, mode changes, takeoff, land, return and loiter go to the autopilot
(:mod:`sim.autopilot`), which decides the result; message intervals and message requests are
answered here from the link's schedule and the streams (:mod:`sim.mavlink.streams`).  A command
the vehicle does not know is UNSUPPORTED and one that breaks is FAILED: never silence.
"""

import logging
import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

log = logging.getLogger("mavadrc.sitl")

FORCE_ARM_MAGIC = 21196


def _near(x, value):
    return math.isfinite(x) and abs(x - value) < 0.5


class Commands:
    """The command handlers of ``autopilot``, its messages made by ``streams``."""

    def __init__(self, autopilot, streams, stats, statustext, stream_limits=True):
        self.autopilot = autopilot
        #: the autopilot's estimator and scheduler bound a requested interval (real time; in
        #: lockstep the vehicle's loop runs once per setpoint, at whatever rate that is)
        self.stream_limits = stream_limits
        self.ap = autopilot.ap
        self.streams = streams
        self.stats = stats
        self._say = statustext

    def on_command(self, link, msg):
        """COMMAND_LONG or COMMAND_INT (x and y in 1e-7 deg)."""
        self.stats.commands += 1
        params = [msg.param1, msg.param2, msg.param3, msg.param4]
        if msg.get_type() == "COMMAND_INT":
            params += [msg.x / 1e7, msg.y / 1e7, msg.z]
        else:
            params += [msg.param5, msg.param6, msg.param7]
        try:
            result, after = self._command(link, msg.command, params)
        except Exception:  # never silence: a command that breaks is answered FAILED
            log.exception("command %s failed", msg.command)
            self.stats.count("command_error")
            result, after = mavlink.MAV_RESULT_FAILED, None
        link.mav.send(mavlink.MAVLink_command_ack_message(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
        if after is not None:
            after()

    def on_set_mode(self, link, msg):
        """SET_MODE (superseded by MAV_CMD_DO_SET_MODE, still sent by some ground stations):
        carried out, not answered."""
        self._set_mode(msg.base_mode, self.ap.message_mode(msg.custom_mode))

    def _set_mode(self, base_mode, mode):
        if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or mode is None:
            return mavlink.MAV_RESULT_DENIED
        return self.autopilot.set_mode(mode)

    def _command(self, link, cmd, p):
        """Carry out a command; returns (MAV_RESULT, optional follow-up sending after the ACK)."""
        M = mavlink
        R = M.MAV_RESULT_ACCEPTED
        a = self.autopilot
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = _near(p[1], FORCE_ARM_MAGIC)
            if _near(p[0], 1.0):
                return a.arm(force), None
            if _near(p[0], 0.0):
                return a.disarm_command(force), None
            return M.MAV_RESULT_DENIED, None
        if cmd == M.MAV_CMD_DO_SET_MODE:
            base = int(p[0]) if math.isfinite(p[0]) else 0
            return self._set_mode(base, self.ap.command_mode(p[1], p[2])), None
        if cmd == M.MAV_CMD_NAV_TAKEOFF:
            return a.takeoff(p[6]), None
        if cmd == M.MAV_CMD_NAV_LAND:
            return a.set_mode(self.ap.mode("LAND")), None
        if cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return a.set_mode(self.ap.mode("RTL")), None
        if cmd == M.MAV_CMD_NAV_LOITER_UNLIM:
            return a.set_mode(self.ap.mode("LOITER")), None
        if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(link, p[0], p[1]), None
        if cmd == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            mid = int(p[0])
            us = link.requested.get(mid) or -1
            return R, lambda: link.mav.send(M.MAVLink_message_interval_message(mid, us))
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            mid = int(p[0]) if math.isfinite(p[0]) else -1
            if not self.ap.sends(mid) or self.streams.build(mid) is None:
                return self.ap.request_refused, None
            return R, lambda: link.mav.send(self.streams.build(mid))
        if cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return R, lambda: link.mav.send(self.streams.build(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
        if cmd == M.MAV_CMD_GET_HOME_POSITION:
            return R, lambda: link.mav.send(self.streams.build(M.MAVLINK_MSG_ID_HOME_POSITION))
        return M.MAV_RESULT_UNSUPPORTED, None

    def _set_interval(self, link, msgid, interval_us):
        """MAV_CMD_SET_MESSAGE_INTERVAL: every ``interval_us`` us (-1: stop, 0: the link's
        default); HEARTBEAT stays at 1 Hz.  An interval shorter than the autopilot can serve
        is answered as it answers it (:meth:`sim.personality.Personality.stream_interval`:
        PX4 ACCEPTED and the stream at the estimator's rate, ArduCopter DENIED)."""
        M = mavlink
        if not (math.isfinite(msgid) and math.isfinite(interval_us)):
            return M.MAV_RESULT_DENIED
        mid = int(msgid)
        hb = mid == M.MAVLINK_MSG_ID_HEARTBEAT
        if (not self.ap.sends(mid) or (hb and not self.ap.heartbeat_interval_settable)
                or self.streams.build(mid) is None):
            text = self.ap.interval_refused_text(mid)
            if text:
                self._say(M.MAV_SEVERITY_INFO, text)
            return self.ap.interval_refused
        if hb:
            return M.MAV_RESULT_ACCEPTED
        if interval_us < 0:
            link.set_interval(mid, None)
        elif interval_us == 0:
            hz = link.default_rates.get(mid)
            link.set_interval(mid, None if hz is None else int(round(1e6 / hz)))
        else:
            asked = max(1, int(round(interval_us)))
            result, runs, reported, text = M.MAV_RESULT_ACCEPTED, asked, asked, None
            if self.stream_limits:
                result, runs, reported, text = self.ap.stream_interval(mid, asked)
            if text:
                self._say(M.MAV_SEVERITY_INFO, text)
            if runs is not None:
                link.set_interval(mid, runs, due=self.streams.time_us(), requested=reported)
            return result
        return M.MAV_RESULT_ACCEPTED
