"""The companion's MAVLink link: connection strings, one chosen autopilot, commands, parameters,
time sync and telemetry bookkeeping.

Connection strings are accepted as pymavlink and MAVSDK users write them::

    udpin:0.0.0.0:14540   udpin://0.0.0.0:14540   udp://:14540   udp://0.0.0.0:14540
    udpout:HOST:PORT      udpout://HOST:PORT      tcp:HOST:PORT   tcp://HOST:PORT
    /dev/ttyACM0          /dev/ttyUSB0:57600      /dev/ttyUSB0,57600   serial:///dev/ttyUSB0:57600

UDP is served by a socket of our own, bound without SO_REUSEADDR: a port another program already
listens on is an error that names it (two companions on one port would both command the
vehicle).  TCP and serial links go through pymavlink's mavutil.

One autopilot is flown: the first autopilot heartbeat heard names it, or ``sysid`` picks it when
several systems are heard.  Messages of any other system are dropped and counted, and commands
are addressed to the chosen one.  Every frame in both directions goes to an optional tlog writer
as it passes.  With a signing key everything sent is signed and everything received must be.
"""

import collections
import errno
import logging
import math
import os
import re
import select
import socket
import struct
import time

os.environ.setdefault("MAVLINK20", "1")  # speak MAVLink 2; must precede pymavlink's dialect import

from pymavlink import mavutil  # noqa: E402

from mavadrc.mavlink import px4_events  # noqa: E402

M = mavutil.mavlink
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
#: accepted unsigned on a signed link (as PX4 and ArduPilot do: radios cannot sign)
UNSIGNED_ALLOWED = (M.MAVLINK_MSG_ID_RADIO_STATUS,)
#: 1 Jan 2015, the epoch of MAVLink 2 signing timestamps
SIGNING_EPOCH = 1420070400


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


class LinkError(RuntimeError):
    """The link or the vehicle did not do what the flight needs; the message says what."""



def parse_url(url):
    """(pymavlink device string, baud) for a connection string in any of the accepted forms."""
    u = url.strip()
    baud = 57600
    m = re.fullmatch(r"serial://(/[^:,]+)(?:[:,](\d+))?", u)
    if m:
        return m.group(1), int(m.group(2) or baud)
    m = re.fullmatch(r"(/dev/[^:,]+|COM\d+)(?:[:,](\d+))?", u)
    if m:
        return m.group(1), int(m.group(2) or baud)
    m = re.fullmatch(r"(udpin|udpout|udp|tcp|tcpin)(?::(?://)?|://)([^:]*):(\d+)", u)
    if not m:
        raise LinkError(f"cannot read connection string {url!r}: use udpin:HOST:PORT, "
                        "udpin://HOST:PORT, udp://:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a "
                        "serial device with a baud rate (/dev/ttyUSB0:57600)")
    scheme, host, port = m.group(1), m.group(2), m.group(3)
    if not 0 < int(port) < 65536:
        raise LinkError(f"{url!r}: port {port} is not a port number (1 to 65535)")
    if scheme == "udp":  # MAVSDK: udp://[host]:port listens
        scheme = "udpin"
    if scheme in ("udpin", "tcpin") and host == "":
        host = "0.0.0.0"
    if scheme in ("udpout", "tcp") and host == "":
        raise LinkError(f"{url!r}: {scheme} needs a host to connect to")
    return f"{scheme}:{host}:{port}", baud


class UdpEndpoint:
    """A UDP socket for one MAVLink peer.  ``udpin`` binds HOST:PORT (no SO_REUSEADDR, so a port
    in use is an error) and answers the peer it hears; ``udpout`` sends to HOST:PORT from a
    port of its own."""

    def __init__(self, device, url):
        scheme, host, port = device.split(":")
        port = int(port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.peer = None
        try:
            if scheme == "udpin":
                self.sock.bind((host, port))
            else:
                self.peer = (socket.gethostbyname(host), port)
                self.sock.bind(("0.0.0.0", 0))
        except OSError as exc:
            self.sock.close()
            if exc.errno == errno.EADDRINUSE:
                raise LinkError(
                    f"UDP port {port} is already in use by another program (another mavadrc "
                    "fly, MAVProxy, QGroundControl?): two programs on one port would both "
                    f"command the vehicle; stop it, or give another port in {url!r}") from None
            raise LinkError(f"cannot open {url}: {exc}") from None
        self.sock.setblocking(False)
        self.last_from = None

    def recv(self):
        """One datagram (b"" when none is waiting)."""
        try:
            data, self.last_from = self.sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            return b""
        return data

    def select(self, timeout):
        try:
            readable, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        except InterruptedError:
            return False
        return bool(readable)

    def write(self, buf):
        peer = self.peer or self.last_from
        if peer is not None:
            try:
                self.sock.sendto(buf, peer)
            except OSError:
                pass  # a full buffer or an unreachable peer: the datagram is lost, as on a radio

    def close(self):
        self.sock.close()


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
        device, baud = parse_url(url)
        self.url = url
        self.tlog = tlog
        self.on_text = on_text or (lambda sev, text: log.info("vehicle: %s", text))
        self.wanted_sysid = sysid
        if device.startswith(("udpin:", "udpout:")):
            self.conn = UdpEndpoint(device, url)
            self.mav = M.MAVLink(self.conn, srcSystem=1, srcComponent=M.MAV_COMP_ID_ONBOARD_COMPUTER)
            self.mav.robust_parsing = True
            self._datagrams = True
            self._answer_sender = device.startswith("udpin:")
        else:
            try:
                self.conn = mavutil.mavlink_connection(
                    device, baud=baud, source_system=1,
                    source_component=M.MAV_COMP_ID_ONBOARD_COMPUTER, autoreconnect=True)
            except (OSError, ImportError) as exc:
                raise LinkError(f"cannot open {url}: {exc}") from exc
            self.mav = self.conn.mav
            self._datagrams = self._answer_sender = False
        if signing_key is not None:
            self._setup_signing(signing_key)
        self.mav.set_send_callback(self._sent)
        self.target_system = 0
        self.autopilot = None
        self.heartbeat = None
        self.heartbeat_wall = None  # time.monotonic() when self.heartbeat came
        self.heartbeats = 0
        self.systems_heard = set()
        self.commands = {}  # command id -> the latest Command sent
        self.params = {}  # name -> PARAM_VALUE
        self.messages = {}  # type -> the latest message of the chosen autopilot
        self.sent = 0
        self.bad_frames = 0
        self.bad_signatures = 0
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
        self._queue = collections.deque()
        self.timesync = TimeSync()
        self._timesync_wall = 0.0
        self.on_message = None  # called with every message of the chosen autopilot

    def _setup_signing(self, key):
        s = self.mav.signing
        s.secret_key = bytes(key)
        s.sign_outgoing = True
        s.link_id = 0
        s.timestamp = int((time.time() - SIGNING_EPOCH) * 1e5)
        s.allow_unsigned_callback = lambda _mav, msgid: msgid in UNSIGNED_ALLOWED

    def _sent(self, msg):
        self.sent += 1
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())

    def close(self):
        self.conn.close()

    # --- receiving ---------------------------------------------------------------------------

    def recv(self, timeout=0.05):
        """Next message of the chosen autopilot (or None after ``timeout`` s), with the
        bookkeeping every message gets.

        Over UDP a datagram is read and parsed whole (pymavlink's parser, CRC and signing
        checks included) and its messages are handed out one by one; other links go through
        mavutil message by message.  Frames that do not parse or fail the signature check are
        dropped and counted (``bad_frames``, ``bad_signatures``), as are messages of other
        systems (``other_system``).  The tlog is flushed before waiting for data.
        """
        end = time.monotonic() + timeout
        while True:
            if self._queue:
                msg = self._queue.popleft()
            elif self._datagrams:
                msg = self._recv_datagram(max(0.0, end - time.monotonic()))
            else:
                if self.tlog is not None:
                    self.tlog.flush()
                msg = self.conn.recv_match(blocking=True, timeout=max(0.0, end - time.monotonic()))
                if msg is not None and msg.get_type() != "BAD_DATA" and self.tlog is not None:
                    self.tlog.write(msg.get_msgbuf())
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
        if t == "BAD_DATA":
            reason = str(getattr(msg, "reason", ""))
            if "ignature" in reason or "unsigned" in reason.lower():
                self.bad_signatures += 1
            else:
                self.bad_frames += 1
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
        if self._answer_sender and not self._one_source(getattr(msg, "_from", None)):
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
            self._on_timesync(msg)
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
            self.conn.peer = frm  # answer the chosen autopilot only
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
        self.mav.srcSystem = self.target_system
        if hb.autopilot == M.MAV_AUTOPILOT_PX4:
            self.autopilot = "px4"
        elif hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.autopilot = "ardupilot"
        else:
            raise LinkError(f"the autopilot of system {self.target_system} on {self.url} is "
                            f"neither PX4 nor ArduPilot (MAV_AUTOPILOT {hb.autopilot}); "
                            "mavadrc flies those two")

    def _recv_datagram(self, timeout):
        conn = self.conn
        data = conn.recv()
        if not data:  # waited for asleep, in lockstep too (see sim.server's loop)
            if self.tlog is not None:
                self.tlog.flush()
            if not conn.select(timeout):
                return None
            data = conn.recv()
            if not data:
                return None
        try:
            msgs = self.mav.parse_buffer(data)
        except Exception:  # whatever the parser chokes on is dropped, never fatal
            self.bad_frames += 1
            self.mav = self._fresh_parser()
            return None
        if self.mav.buf_len() > 0:  # a truncated frame: nothing of it carries over
            self.bad_frames += 1
            self.mav = self._fresh_parser()
        if not msgs:
            return None
        if self.tlog is not None:
            t_us = int(time.time() * 1e6)
            for m in msgs:
                if m.get_type() != "BAD_DATA":
                    self.tlog.write(m.get_msgbuf(), t_us)
        for m in msgs:
            m._from = conn.last_from  # whose datagram (Link._one_source)
        self._queue.extend(msgs[1:])
        return msgs[0]

    def _fresh_parser(self):
        old = self.mav
        mav = M.MAVLink(self.conn, srcSystem=old.srcSystem, srcComponent=old.srcComponent)
        mav.robust_parsing = True
        mav.signing = old.signing
        mav.seq = old.seq
        mav.send_callback = old.send_callback
        mav.send_callback_args = old.send_callback_args
        mav.send_callback_kwargs = old.send_callback_kwargs
        return mav

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
        """Send a TIMESYNC request every ``period`` s (both PX4 and ArduPilot answer); every
        0.25 s until the vehicle's clock is fitted (:class:`TimeSync`), so that a clock that
        runs at another rate is followed within a second or two of the first answer (for 16
        requests at most: a vehicle that does not answer is asked once a second)."""
        if not self.timesync.fitted and self.timesync.asked < 16:
            period = min(period, 0.25)
        if now - self._timesync_wall >= period:
            self._timesync_wall = now
            ts1 = time.monotonic_ns()
            self.timesync.sent(ts1)
            self.mav.timesync_send(0, ts1)

    def _on_timesync(self, msg):
        if msg.tc1 == 0:  # the vehicle asks: answer with our clock
            self.mav.timesync_send(time.monotonic_ns(), msg.ts1)
        else:
            self.timesync.answered(msg.tc1, msg.ts1, time.monotonic_ns())

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


class TimeSync:
    """Round trip, clock offset and the vehicle clock's rate from TIMESYNC exchanges.

    A request carries our clock ``ts1`` (ns); the answer adds the vehicle's clock ``tc1`` (ns
    since its boot, the clock of ``time_boot_ms``).  The round trip is ``now - ts1``; the
    vehicle's clock read ``tc1`` about half a round trip before ``now``, so ``offset = tc1 -
    (ts1 + now)/2`` maps our clock onto the vehicle's at our time ``(ts1 + now)/2``, to within
    half the round trip.

    The vehicle's clock need not run at the rate of ours: a simulator's runs slow when its
    loop cannot keep up (PX4 SITL's, SIH, ran 1.35 % slow on 2 cores, 2026-12-03), and two
    crystals differ by tens of ppm.  So the offset is a line in our time: fitted through the
    exchanges of the last :attr:`WINDOW_S` whose round trip is near the shortest among them
    (within :attr:`RTT_SLACK` times it plus :attr:`RTT_SLACK_NS`: the least queued), and read
    where it is asked.  With fewer than :attr:`MIN_FIT` of them, or spanning under
    :attr:`MIN_SPAN_S`: the newest one's offset, at the rate last fitted (none before the
    first fit).  On a loaded machine one exchange with a short round trip can leave too few of
    the others near it; forgetting the rate then read a clock running 5 % slow as running at
    ours (a test's real-time flight on the 2 shared cores).  An exchange with a short round trip that
    lands more than :attr:`JUMP_NS` off the line says the vehicle's clock jumped (a reboot, a
    time reset): the exchanges before it are forgotten.
    """

    WINDOW_S = 6.0
    RTT_SLACK = 2.0
    RTT_SLACK_NS = 1_000_000
    MIN_FIT = 3
    MIN_SPAN_S = 1.0
    JUMP_NS = 50_000_000

    def __init__(self):
        self._pending = collections.deque(maxlen=16)
        self.rtts = []  # every round trip measured (s)
        self._recent = collections.deque()  # (our time at the exchange (ns), rtt_ns, offset_ns)
        self._line = None  # (t0_ns, offset at t0 (ns), skew): offset(t) = o0 + skew (t - t0)
        self.fitted = False  # whether the line is fitted (else: the newest exchange's offset)
        self._fitted_skew = 0.0  # the rate of the last line fitted, kept while none can be
        self.asked = 0  # requests sent

    def sent(self, ts1):
        self._pending.append(ts1)
        self.asked += 1

    def answered(self, tc1, ts1, now):
        if ts1 not in self._pending:
            return  # not ours, or a late duplicate
        self._pending.remove(ts1)
        rtt = now - ts1
        if rtt < 0:
            return
        self.rtts.append(rtt * 1e-9)
        mid = (ts1 + now) // 2
        offset = tc1 - mid
        if self._line is not None and rtt <= self._good_rtt() \
                and abs(offset - self.offset_at(mid)) > self.JUMP_NS + rtt:
            self._recent.clear()  # the vehicle's clock jumped
        self._recent.append((mid, rtt, offset))
        while self._recent and mid - self._recent[0][0] > self.WINDOW_S * 1e9:
            self._recent.popleft()
        self._fit()

    def _good_rtt(self):
        return self.RTT_SLACK * min(r for _, r, _ in self._recent) + self.RTT_SLACK_NS

    def _fit(self):
        good = self._good_rtt()
        pts = [(t, o) for t, r, o in self._recent if r <= good]
        t_new, o_new = pts[-1]
        self.fitted = len(pts) >= self.MIN_FIT and t_new - pts[0][0] >= self.MIN_SPAN_S * 1e9
        if not self.fitted:
            self._line = (t_new, o_new, self._fitted_skew)
            return
        # least squares in seconds from the newest exchange (offsets in ns from its offset)
        t = [(ti - t_new) * 1e-9 for ti, _ in pts]
        o = [float(oi - o_new) for _, oi in pts]
        tm, om = sum(t) / len(t), sum(o) / len(o)
        skew_ns = sum((a - tm) * (b - om) for a, b in zip(t, o)) / \
            sum((a - tm) ** 2 for a in t)  # ns per s
        self._line = (t_new, o_new + int(round(om - skew_ns * tm)), skew_ns * 1e-9)
        self._fitted_skew = skew_ns * 1e-9

    @property
    def offset_ns(self):
        """The offset (ns) at the newest exchange (None before the first)."""
        return None if self._line is None else self._line[1]

    @property
    def skew(self):
        """How much faster the vehicle's clock runs than ours (-0.0135: 1.35 % slower; 0 until
        the exchanges span :attr:`MIN_SPAN_S`, then the last fitted while no line can be)."""
        return 0.0 if self._line is None else self._line[2]

    def offset_at(self, now_ns):
        t0, o0, skew = self._line
        return o0 + int(round(skew * (now_ns - t0)))

    def age(self, time_boot_ms, now_ns=None):
        """Seconds since the vehicle took a sample stamped ``time_boot_ms`` (None before the
        first exchange)."""
        if self._line is None:
            return None
        now_ns = time.monotonic_ns() if now_ns is None else now_ns
        return (now_ns + self.offset_at(now_ns) - time_boot_ms * 1_000_000) * 1e-9


def result_name(result):
    if result == TIMEOUT:
        return "no answer"
    if result is None:
        return "waiting"
    return RESULT_NAMES.get(result, str(result)).replace("MAV_RESULT_", "")


def command_name(cmd):
    return COMMAND_NAMES.get(cmd, str(cmd))
