"""The companion's MAVLink link: one chosen autopilot, commands, parameters, time sync and
telemetry bookkeeping, over a :class:`~mavadrc.mavlink.transport.Transport` (connection strings,
UDP, signing, the tlog).

One autopilot is flown: the first autopilot heartbeat heard names it, or ``sysid`` picks it when
several systems are heard.  Messages of any other system are dropped and counted, and commands
are addressed to the chosen one.
"""

import logging
import time

from mavadrc.errors import LinkError
from mavadrc.mavlink import px4_events, setpoints
from mavadrc.mavlink.commands import CommandSender
from mavadrc.mavlink.dialect import M
from mavadrc.mavlink.params import Params
from mavadrc.mavlink.sources import Sources
from mavadrc.mavlink.timesync import TimeSync
from mavadrc.mavlink.transport import Transport

log = logging.getLogger("mavadrc.mavlink.link")


def _part(part, name, doc=None):
    """A read-only attribute of Link that is ``name`` of its part ``part``."""
    return property(lambda self: getattr(getattr(self, part), name), doc=doc)


class Link:
    """A MAVLink connection as an onboard computer (component 191) to one autopilot.

    The facade every caller uses, composed of parts each handed what it uses: the
    :class:`~mavadrc.mavlink.transport.Transport` (the wire), the
    :class:`~mavadrc.mavlink.sources.Sources` (which autopilot, and what is dropped or lost),
    the :class:`~mavadrc.mavlink.commands.CommandSender`, the
    :class:`~mavadrc.mavlink.params.Params` and the
    :class:`~mavadrc.mavlink.timesync.TimeSync`.  Link itself routes each message received to
    the part it concerns and keeps the autopilot's heartbeat and latest messages.
    """

    mav = _part("transport", "mav", "the pymavlink sender (replaced after a frame it choked on)")
    conn = _part("transport", "conn")
    tlog = _part("transport", "tlog")
    sent = _part("transport", "sent")
    bad_frames = _part("transport", "bad_frames")
    bad_signatures = _part("transport", "bad_signatures")
    wanted_sysid = _part("sources", "wanted_sysid")
    target_system = _part("sources", "target_system")
    autopilot = _part("sources", "autopilot")
    systems_heard = _part("sources", "systems_heard")
    other_system = _part("sources", "other_system")
    source = _part("sources", "source")
    other_sources = _part("sources", "other_sources")
    frames_received = _part("sources", "frames_received")
    frames_lost = _part("sources", "frames_lost")
    params = _part("parameters", "values", "name -> the latest PARAM_VALUE")
    commands = _part("command_sender", "works", "key -> the latest Command of that key")

    def __init__(self, url, tlog=None, on_text=None, signing_key=None, sysid=None):
        self.transport = Transport(url, tlog=tlog, signing_key=signing_key)
        self.url = url
        self.on_text = on_text or (lambda sev, text: log.info("vehicle: %s", text))
        self.sources = Sources(url, sysid, by_address=self.transport.answers_sender,
                               speak_as=self.transport.speak_as,
                               answer_to=self.transport.answer_to)
        self.command_sender = CommandSender(
            lambda *args: self.mav.command_long_send(*args), lambda: self.mav.srcSystem,
            lambda severity, text: self.on_text(severity, text))
        self.parameters = Params(self.transport, self.sources, self.recv)
        self.timesync = TimeSync()
        self.heartbeat = None
        self.heartbeat_wall = None  # time.monotonic() when self.heartbeat came
        self.heartbeats = 0
        self.messages = {}  # type -> the latest message of the chosen autopilot
        self.on_message = None  # called with every message of the chosen autopilot

    def close(self):
        self.transport.close()

    # --- receiving ---------------------------------------------------------------------------

    def recv(self, timeout=0.05):
        """Next message of the chosen autopilot (or None after ``timeout`` s), with the
        bookkeeping every message gets.

        The transport hands out the messages received (:meth:`Transport.next`).  Frames that do
        not parse or fail the signature check are dropped and counted (``bad_frames``,
        ``bad_signatures``), as are messages of other systems (``other_system``).
        """
        end = time.monotonic() + timeout
        while True:
            msg = self.transport.next(end)
            if msg is None:
                return None
            msg = self._book(msg)
            if msg is not None or time.monotonic() >= end:
                return msg

    def _book(self, msg):
        t = msg.get_type()
        if t.startswith("UNKNOWN"):  # a message pymavlink's dialect lacks: PX4's EVENT
            self._px4_event(msg)
            return None
        if self.transport.bad(msg) or not self.sources.admit(msg, t):
            return None
        if t == "HEARTBEAT":
            if msg.get_srcComponent() != M.MAV_COMP_ID_AUTOPILOT1:
                return msg
            self.heartbeat = msg
            self.heartbeat_wall = time.monotonic()
            self.heartbeats += 1
        elif t == "COMMAND_ACK":
            if self.command_sender.on_ack(msg) is None:
                return msg  # someone else's, a repeated answer, or from elsewhere
        elif t in ("COMMAND_LONG", "COMMAND_INT") and msg.target_component == \
                M.MAV_COMP_ID_ONBOARD_COMPUTER and msg.target_system == self.mav.srcSystem:
            # a command for us (PX4 sends gimbal commands in its land mode): every command gets
            # an answer, and a companion flying attitude setpoints supports none
            self.mav.command_ack_send(msg.command, M.MAV_RESULT_UNSUPPORTED, 0, 0,
                                      msg.get_srcSystem(), msg.get_srcComponent())
        elif t == "STATUSTEXT":
            self.on_text(msg.severity, msg.text)
        elif t == "PARAM_VALUE":
            self.parameters.on_value(msg)
        elif t == "TIMESYNC":
            self.timesync.on_message(msg, self.mav.timesync_send)
        self.messages[t] = msg
        return msg

    def _px4_event(self, msg):
        """PX4's EVENT (a message pymavlink's dialect lacks), told as text when it is one of the
        chosen PX4's that :mod:`px4_events` knows."""
        ev = px4_events.decode(msg.get_msgbuf()) if self.autopilot == "px4" else None
        if ev is not None and ev.system == self.target_system:
            text = px4_events.describe(ev)
            if text is not None:
                self.on_text(ev.log_levels & 0x0F, text)

    def sources_text(self):
        """What ``other_sources`` means, for a refusal or a warning (None when empty)."""
        return self.sources.sources_text()

    def frame_loss(self):
        """The fraction of the autopilot's frames lost on the way."""
        return self.sources.frame_loss()

    # --- the autopilot's heartbeat -----------------------------------------------------------

    def wait_heartbeat(self, timeout=15.0, idle=None):
        """Wait for the autopilot's heartbeat (``sysid``'s, or the first one heard); identifies
        PX4 or ArduPilot.  ``idle()`` is called now and then (a console message, a deadline)."""
        end = time.monotonic() + timeout
        last_hb = 0.0
        while time.monotonic() < end:
            now = time.monotonic()
            if now - last_hb >= 1.0:
                self.send_heartbeat()
                last_hb = now
                if idle is not None:
                    idle()
            self.recv(0.1)
            if self.heartbeat is not None:
                return self.heartbeat
        heard = sorted(self.systems_heard)
        if self.wanted_sysid is not None and heard:
            raise LinkError(f"no heartbeat from system {self.wanted_sysid} on {self.url} within "
                            f"{timeout:.0f} s (heard: system {', '.join(map(str, heard))})")
        raise LinkError(f"no heartbeat from an autopilot on {self.url} within {timeout:.0f} s: is "
                        "the vehicle running, and is this where it sends (PX4 SITL's offboard "
                        "link: udpin:0.0.0.0:14540)?")

    @property
    def armed(self):
        return bool(self.heartbeat and self.heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def custom_mode(self):
        return self.heartbeat.custom_mode if self.heartbeat else None

    def heartbeat_since(self, wall):
        """The latest heartbeat if it came after ``wall`` (time.monotonic()), else None."""
        if self.heartbeat is None or wall is None or self.heartbeat_wall <= wall:
            return None
        return self.heartbeat

    # --- time sync ---------------------------------------------------------------------------

    def timesync_poll(self, now, period=1.0):
        """Send a TIMESYNC request every ``period`` s (:meth:`TimeSync.poll`)."""
        self.timesync.poll(now, self.mav.timesync_send, period)

    # --- sending -----------------------------------------------------------------------------

    def send_heartbeat(self):
        self.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                M.MAV_STATE_ACTIVE)

    def command(self, cmd, *params, timeout=0.5, tries=3):
        """Send a COMMAND_LONG to the autopilot; returns its :class:`Command` (poll it, or read
        its result as the answer comes).  A newer command of the same key replaces an older
        one's wait (:mod:`~mavadrc.mavlink.commands`)."""
        return self.command_sender.send(cmd, params, self.target_system,
                                        M.MAV_COMP_ID_AUTOPILOT1, timeout=timeout, tries=tries)

    def command_wait(self, cmd, *params, timeout=0.5, tries=3, idle=None):
        """Send a command and wait for its answer (re-sending as :class:`Command` does);
        returns the MAV_RESULT or :data:`TIMEOUT`.  ``idle()`` is called while waiting."""
        return self.wait(self.command(cmd, *params, timeout=timeout, tries=tries), idle)

    def wait(self, c, idle=None):
        """Wait for :class:`Command` ``c``'s answer (re-sent as it does); returns its result."""
        while not c.done:
            self.recv(0.01)
            if idle is not None:
                idle()
            c.poll()
        return c.result

    def set_rate(self, msgid, hz, tries=5, idle=None):
        """Ask for message ``msgid`` at ``hz`` (0: stop) and wait for the answer (re-sent when
        lost); returns the MAV_RESULT or :data:`TIMEOUT`."""
        interval = -1 if hz <= 0 else int(1e6 / hz)
        return self.command_wait(M.MAV_CMD_SET_MESSAGE_INTERVAL, msgid, interval, tries=tries,
                                 idle=idle)

    def request_message(self, msgid):
        """Ask for one message now (MAV_CMD_REQUEST_MESSAGE); returns the :class:`Command`."""
        return self.command(M.MAV_CMD_REQUEST_MESSAGE, msgid)

    def param_read(self, name, timeout=3.0, idle=None):
        return self.parameters.read(name, timeout, idle)

    def param_set(self, name, value, ptype, timeout=3.0, idle=None):
        return self.parameters.set(name, value, ptype, timeout, idle)

    def attitude_target(self, t_boot_ms, q, thrust):
        """SET_ATTITUDE_TARGET with attitude and thrust, body rates ignored; refuses non-finite."""
        setpoints.attitude_target(self.mav, self.target_system, t_boot_ms, q, thrust)

    def position_target(self, t_boot_ms, pos, vel, acc, yaw):
        """SET_POSITION_TARGET_LOCAL_NED: position, velocity, acceleration, yaw; refuses
        non-finite."""
        setpoints.position_target(self.mav, self.target_system, t_boot_ms, pos, vel, acc, yaw)

    def named_float(self, t_boot_ms, name, value):
        setpoints.named_float(self.mav, t_boot_ms, name, value)
