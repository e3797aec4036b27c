"""The companion's MAVLink link: one chosen autopilot, commands, parameters, time sync and
telemetry bookkeeping, over a :class:`~mavadrc.mavlink.transport.Transport` (connection strings,
UDP, signing, the tlog).

One autopilot is flown: the first autopilot heartbeat heard names it, or ``sysid`` picks it when
several systems are heard.  Messages of any other system are dropped and counted, and commands
are addressed to the chosen one.
"""

import collections
import logging
import math
import struct
import time

from mavadrc.mavlink import px4_events
from mavadrc.mavlink.dialect import M, mavutil  # noqa: F401 (mavutil: as importers had it)
from mavadrc.mavlink.errors import LinkError
from mavadrc.mavlink.timesync import TimeSync
from mavadrc.mavlink.transport import Transport, parse_url  # noqa: F401 (parse_url: importers)

log = logging.getLogger("mavadrc.mavlink.link")

RESULT_NAMES = {v: k for k, v in vars(M).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}
COMMAND_NAMES = {v: k for k, v in vars(M).items() if k.startswith("MAV_CMD_")
                 and isinstance(v, int)}
#: a command that got no answer after all its tries (not a MAV_RESULT)
TIMEOUT = -1

#: commands whose every answer the user sees (all others are shown when not ACCEPTED)
ANNOUNCED = (M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_LAND,
             M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_RETURN_TO_LAUNCH)


#: sequence numbers jumped over that a late frame may still fill in (a reordering link)
SKIPPED_KEPT = 64


def count_sequence(last, seq, skipped):
    """(the newest sequence number, frames to count lost) after a frame numbered ``seq`` where
    ``last`` was the newest (None: the first).  A jump ahead counts the numbers jumped over as
    lost and keeps them in ``skipped`` (a bounded deque); a frame behind the newest one that
    fills one of them in was late, not lost, and is taken back (-1); any other frame behind is
    a repeat (0).  A jittery link reorders frames: counted as gaps alone, 5 % of the samples
    lost read as 23 % of the frames."""
    if last is None:
        return seq, 0
    gap = (seq - last - 1) & 0xFF
    if gap >= 128:  # behind the newest
        if seq in skipped:
            skipped.remove(seq)
            return last, -1
        return last, 0
    for k in range(1, gap + 1):
        skipped.append((last + k) & 0xFF)
    # what is now half the sequence behind could only be matched by a later lap's number
    while skipped and (seq - skipped[0]) & 0xFF >= 128:
        skipped.popleft()
    return seq, gap


class Command:
    """One COMMAND_LONG until the vehicle answers it, as MAVSDK's command sender does: re-sent
    after ``timeout`` s without an answer, ``tries`` times in all; an IN_PROGRESS answer
    gives it longer.  ``result`` is the vehicle's MAV_RESULT, :data:`TIMEOUT`, or None while
    it waits."""

    IN_PROGRESS_S = 3.0

    def __init__(self, link, cmd, params, timeout=0.5, tries=3):
        self.link = link
        self.cmd = cmd
        self.params = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.timeout = timeout
        self.tries = tries
        self.sent = 0
        self.result = None
        self.ack = None
        self.acked_wall = None  # time.monotonic() of the final answer
        self._due = 0.0
        self._send()

    def _send(self):
        self.sent += 1
        self._due = time.monotonic() + self.timeout
        self.link.mav.command_long_send(self.link.target_system, 1, self.cmd, self.sent - 1,
                                        *self.params)

    @property
    def done(self):
        return self.result is not None

    @property
    def accepted(self):
        return self.result == M.MAV_RESULT_ACCEPTED

    def answered(self, ack):
        self.ack = ack
        if ack.result == M.MAV_RESULT_IN_PROGRESS:
            self._due = time.monotonic() + self.IN_PROGRESS_S
            return
        self.result = ack.result
        self.acked_wall = time.monotonic()

    def poll(self, now=None):
        """Re-send when an answer is overdue; give up (TIMEOUT) after the last try."""
        if self.result is not None:
            return
        now = time.monotonic() if now is None else now
        if now < self._due:
            return
        if self.sent >= self.tries:
            self.result = TIMEOUT
            self.acked_wall = now
            return
        self._send()

    def __repr__(self):
        return f"<{command_name(self.cmd)} {result_name(self.result)}>"


class Link:
    """A MAVLink connection as an onboard computer (component 191) to one autopilot."""

    def __init__(self, url, tlog=None, on_text=None, signing_key=None, sysid=None):
        self.transport = Transport(url, tlog=tlog, signing_key=signing_key)
        self.url = url
        self.on_text = on_text or (lambda sev, text: log.info("vehicle: %s", text))
        self.wanted_sysid = sysid
        self.target_system = 0
        self.autopilot = None
        self.heartbeat = None
        self.heartbeat_wall = None  # time.monotonic() when self.heartbeat came
        self.heartbeats = 0
        self.systems_heard = set()
        self.commands = {}  # command id -> the latest Command sent
        self.params = {}  # name -> PARAM_VALUE
        self.messages = {}  # type -> the latest message of the chosen autopilot
        self.other_system = 0
        # udpin: the address the chosen autopilot speaks from, and any other address that
        # speaks as the same system (another vehicle with its id: _one_source)
        self.source = None
        self.other_sources = {}  # address -> messages dropped
        self.frames_received = 0
        self.frames_lost = 0
        self._last_seq = None
        # sequence numbers jumped over and not yet seen (count_sequence)
        self._skipped = collections.deque(maxlen=SKIPPED_KEPT)
        self.timesync = TimeSync()
        self.on_message = None  # called with every message of the chosen autopilot

    @property
    def mav(self):
        """The pymavlink sender (the transport's: it replaces it after a frame it choked on)."""
        return self.transport.mav

    @property
    def conn(self):
        return self.transport.conn

    @property
    def sent(self):
        return self.transport.sent

    @property
    def bad_frames(self):
        return self.transport.bad_frames

    @property
    def bad_signatures(self):
        return self.transport.bad_signatures

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
            ev = px4_events.decode(msg.get_msgbuf()) if self.autopilot == "px4" else None
            if ev is not None and ev.system == self.target_system:
                text = px4_events.describe(ev)
                if text is not None:
                    self.on_text(ev.log_levels & 0x0F, text)
            return None
        if self.transport.bad(msg):
            return None
        src = msg.get_srcSystem()
        if t == "HEARTBEAT" and msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 \
                and msg.autopilot != M.MAV_AUTOPILOT_INVALID:
            self.systems_heard.add(src)
            if self.target_system == 0 and self.wanted_sysid in (None, src):
                self._choose(msg)
        if self.target_system == 0 or src != self.target_system:
            if self.target_system != 0:
                self.other_system += 1
            return None
        if self.transport.answers_sender and not self._one_source(getattr(msg, "_from", None)):
            return None
        if msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1:
            self._count_seq(msg.get_seq())
        if t == "HEARTBEAT":
            if msg.get_srcComponent() != M.MAV_COMP_ID_AUTOPILOT1:
                return msg
            self.heartbeat = msg
            self.heartbeat_wall = time.monotonic()
            self.heartbeats += 1
        elif t == "COMMAND_ACK":
            if msg.target_system not in (0, self.mav.srcSystem) or \
                    msg.target_component not in (0, M.MAV_COMP_ID_ONBOARD_COMPUTER):
                return msg  # an answer to someone else's command
            c = self.commands.get(msg.command)
            if c is None or c.done:
                return msg  # a repeated answer (PX4 may answer twice), or not ours
            c.answered(msg)
            if msg.result not in (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_IN_PROGRESS) or \
                    msg.command in ANNOUNCED and msg.result == M.MAV_RESULT_ACCEPTED:
                self.on_text(M.MAV_SEVERITY_INFO if msg.result == M.MAV_RESULT_ACCEPTED
                             else M.MAV_SEVERITY_WARNING,
                             f"{command_name(msg.command)}: {result_name(msg.result)}")
        elif t in ("COMMAND_LONG", "COMMAND_INT") and msg.target_component == \
                M.MAV_COMP_ID_ONBOARD_COMPUTER and msg.target_system == self.mav.srcSystem:
            # a command for us (PX4 sends gimbal commands in its land mode): every command gets
            # an answer, and a companion flying attitude setpoints supports none
            self.mav.command_ack_send(msg.command, M.MAV_RESULT_UNSUPPORTED, 0, 0,
                                      msg.get_srcSystem(), msg.get_srcComponent())
        elif t == "STATUSTEXT":
            self.on_text(msg.severity, msg.text)

        elif t == "PARAM_VALUE":
            self.params[msg.param_id] = msg
        elif t == "TIMESYNC":
            self.timesync.on_message(msg, self.mav.timesync_send)
        self.messages[t] = msg
        return msg

    def _one_source(self, frm):
        """Over udpin, whether a message of the chosen system comes from the address it was
        first heard from (and answered there).  Another address speaking as the same system is
        a second vehicle with its id (two SITLs on one port, two radios): MAVLink cannot tell
        them apart, and answering whoever spoke last sent the setpoints to both in turn and
        flew the loop on both vehicles' positions mixed.  Its messages are dropped and counted
        (``other_sources``); a flight refuses to arm while one is heard."""
        if frm is None or frm == self.source:
            return True
        if self.source is None:
            self.source = frm
            self.transport.answer_to(frm)  # answer the chosen autopilot only
            return True
        self.other_sources[frm] = self.other_sources.get(frm, 0) + 1
        return False

    def sources_text(self):
        """What ``other_sources`` means, for a refusal or a warning (None when empty)."""
        if not self.other_sources:
            return None
        others = ", ".join(f"{a}:{p}" for a, p in self.other_sources)
        return (f"two vehicles speak as system {self.target_system} on {self.url}: "
                f"{self.source[0]}:{self.source[1]} (flown) and {others} "
                f"({sum(self.other_sources.values())} messages of the other dropped); MAVLink "
                "cannot tell them apart, so setpoints could reach either; stop one, or give "
                "them different system ids")

    def _count_seq(self, seq):
        """Frames lost on the way: gaps in the autopilot's MAVLink sequence numbers
        (:func:`count_sequence`)."""
        self.frames_received += 1
        self._last_seq, lost = count_sequence(self._last_seq, seq, self._skipped)
        self.frames_lost += lost

    def frame_loss(self):
        n = self.frames_received + self.frames_lost
        return self.frames_lost / n if n else 0.0

    def _choose(self, hb):
        self.target_system = hb.get_srcSystem()
        self.transport.speak_as(self.target_system)
        if hb.autopilot == M.MAV_AUTOPILOT_PX4:
            self.autopilot = "px4"
        elif hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.autopilot = "ardupilot"
        else:
            raise LinkError(f"the autopilot of system {self.target_system} on {self.url} is "
                            f"neither PX4 nor ArduPilot (MAV_AUTOPILOT {hb.autopilot}); "
                            "mavadrc flies those two")

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
        """Send a COMMAND_LONG; returns its :class:`Command` (poll it, or read its result as
        the answer comes).  A newer command of the same id replaces an older one's wait: a
        COMMAND_ACK names the command, not the request."""
        c = Command(self, cmd, params, timeout=timeout, tries=tries)
        self.commands[cmd] = c
        return c

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

    def _param_exchange(self, name, send, timeout, idle, what):
        """Send a parameter request until the PARAM_VALUE for ``name`` comes back (3 tries)."""
        for _ in range(3):
            self.params.pop(name, None)
            send()
            end = time.monotonic() + timeout / 3
            while time.monotonic() < end:
                self.recv(0.02)
                if idle is not None:
                    idle()
                if name in self.params:
                    return self._decode(self.params[name])
        raise LinkError(f"the vehicle did not {what} parameter {name}")

    def param_read(self, name, timeout=3.0, idle=None):
        return self._param_exchange(
            name, lambda: self.mav.param_request_read_send(self.target_system, 1, name.encode(), -1),
            timeout, idle, "answer a read of")

    def param_set(self, name, value, ptype, timeout=3.0, idle=None):
        raw = float(value)
        if ptype == M.MAV_PARAM_TYPE_INT32 and self.autopilot == "px4":
            raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        return self._param_exchange(
            name, lambda: self.mav.param_set_send(self.target_system, 1, name.encode(), raw, ptype),
            timeout, idle, "confirm setting")

    def _decode(self, pv):
        if pv.param_type == M.MAV_PARAM_TYPE_INT32 and self.autopilot == "px4":
            return struct.unpack("<i", struct.pack("<f", pv.param_value))[0]
        return pv.param_value

    def attitude_target(self, t_boot_ms, q, thrust):
        """SET_ATTITUDE_TARGET with attitude and thrust, body rates ignored; refuses non-finite."""
        if not (all(math.isfinite(v) for v in q) and math.isfinite(thrust)):
            raise ValueError("refusing to send a non-finite setpoint")
        self.mav.set_attitude_target_send(int(t_boot_ms) & 0xFFFFFFFF, self.target_system, 1, 7,
                                          [float(v) for v in q], 0.0, 0.0, 0.0, float(thrust))

    def named_float(self, t_boot_ms, name, value):
        self.mav.named_value_float_send(int(t_boot_ms) & 0xFFFFFFFF, name.encode(), float(value))


def result_name(result):
    if result == TIMEOUT:
        return "no answer"
    if result is None:
        return "waiting"
    return RESULT_NAMES.get(result, str(result)).replace("MAV_RESULT_", "")


def command_name(cmd):
    return COMMAND_NAMES.get(cmd, str(cmd))
