"""The companion's MAVLink link: connection strings, heartbeat, commands, parameters, telemetry.

Connection strings are accepted as pymavlink and MAVSDK users write them::

    udpin:0.0.0.0:14540   udpin://0.0.0.0:14540   udp://:14540   udp://0.0.0.0:14540
    udpout:HOST:PORT      udpout://HOST:PORT      tcp:HOST:PORT   tcp://HOST:PORT
    /dev/ttyACM0          /dev/ttyUSB0:57600      /dev/ttyUSB0,57600   serial:///dev/ttyUSB0:57600

Every frame in both directions goes to an optional tlog writer as it passes.
"""

import collections
import logging
import math
import os
import re
import struct
import time

os.environ.setdefault("MAVLINK20", "1")  # speak MAVLink 2; must precede pymavlink's dialect import

from pymavlink import mavutil  # noqa: E402

M = mavutil.mavlink
log = logging.getLogger("mavadrc.link")

RESULT_NAMES = {v: k for k, v in vars(M).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}


#: commands whose every answer the user sees (all others are shown when not ACCEPTED)
ANNOUNCED = (M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_LAND,
             M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_RETURN_TO_LAUNCH)


class LinkError(RuntimeError):
    """The link or the vehicle did not do what the flight needs; the message says what."""


class FlightError(RuntimeError):
    """The flight could not start or go on; the message says why, in the vehicle's words."""


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
    if scheme == "udp":  # MAVSDK: udp://[host]:port listens
        scheme = "udpin"
    if scheme in ("udpin", "tcpin") and host == "":
        host = "0.0.0.0"
    if scheme in ("udpout", "tcp") and host == "":
        raise LinkError(f"{url!r}: {scheme} needs a host to connect to")
    return f"{scheme}:{host}:{port}", baud


class Link:
    """A MAVLink connection as an onboard computer (component 191) to one autopilot."""

    def __init__(self, url, tlog=None, on_text=None):
        device, baud = parse_url(url)
        self.url = url
        self.tlog = tlog
        self.on_text = on_text or (lambda sev, text: log.info("vehicle: %s", text))
        try:
            self.conn = mavutil.mavlink_connection(device, baud=baud, source_system=1,
                                                   source_component=M.MAV_COMP_ID_ONBOARD_COMPUTER,
                                                   autoreconnect=True)
        except OSError as exc:
            raise LinkError(f"cannot open {url}: {exc}") from exc
        self.mav = self.conn.mav
        self.mav.set_send_callback(self._sent)
        self.target_system = 0
        self.autopilot = None
        self.heartbeat = None
        self.acks = {}  # command -> last COMMAND_ACK
        self.params = {}  # name -> PARAM_VALUE
        self.sent = 0
        self.bad_frames = 0
        self.spin_s = 0.0  # UDP: poll this long (s) for data before sleeping (lockstep sets it)
        self._queue = collections.deque()
        self._datagrams = isinstance(self.conn, mavutil.mavudp)

    def _sent(self, msg):
        self.sent += 1
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())

    def close(self):
        self.conn.close()

    # --- receiving ---------------------------------------------------------------------------

    def recv(self, timeout=0.05):
        """Next message (or None after ``timeout`` s), with the bookkeeping every message gets.

        Over UDP a datagram is read and parsed whole (pymavlink's parser, CRC and signing
        checks included) and its messages are handed out one by one; other links go through
        mavutil message by message.  Frames that do not parse are dropped and counted
        (``bad_frames``).  The tlog is flushed before waiting for data.
        """
        if self._queue:
            msg = self._queue.popleft()
        elif self._datagrams:
            msg = self._recv_datagram(timeout)
        else:
            if self.tlog is not None:
                self.tlog.flush()
            msg = self.conn.recv_match(blocking=True, timeout=timeout)
            if msg is not None and msg.get_type() != "BAD_DATA" and self.tlog is not None:
                self.tlog.write(msg.get_msgbuf())
        if msg is None:
            return None
        t = msg.get_type()
        if t == "BAD_DATA":
            self.bad_frames += 1
            return None
        if t == "HEARTBEAT" and msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 \
                and msg.autopilot != M.MAV_AUTOPILOT_INVALID:
            self.heartbeat = msg
        elif t == "COMMAND_ACK":
            self.acks[msg.command] = msg
            if msg.result != M.MAV_RESULT_ACCEPTED or msg.command in ANNOUNCED:
                self.on_text(M.MAV_SEVERITY_INFO if msg.result == M.MAV_RESULT_ACCEPTED
                             else M.MAV_SEVERITY_WARNING,
                             f"{command_name(msg.command)}: {result_name(msg.result)}")
        elif t == "STATUSTEXT":
            self.on_text(msg.severity, msg.text)
        elif t == "PARAM_VALUE":
            self.params[msg.param_id] = msg
        return msg

    def _recv_datagram(self, timeout):
        conn = self.conn
        data = conn.recv()
        if not data:
            if self.tlog is not None:
                self.tlog.flush()
            if self.spin_s > 0.0:
                end = time.perf_counter() + min(self.spin_s, timeout)
                while not data and time.perf_counter() < end:
                    data = conn.recv()
        if not data:
            if not conn.select(timeout):
                return None
            data = conn.recv()
            if not data:
                return None
        try:
            msgs = self.mav.parse_buffer(data)
        except Exception:  # whatever the parser chokes on is dropped, never fatal
            self.bad_frames += 1
            return None
        if not msgs:
            return None
        if self.tlog is not None:
            t_us = int(time.time() * 1e6)
            for m in msgs:
                if m.get_type() != "BAD_DATA":
                    self.tlog.write(m.get_msgbuf(), t_us)
        self._queue.extend(msgs[1:])
        return msgs[0]

    def wait_heartbeat(self, timeout=15.0):
        """Wait for an autopilot's heartbeat; identifies PX4 or ArduPilot."""
        end = time.monotonic() + timeout
        last_hb = 0.0
        while time.monotonic() < end:
            now = time.monotonic()
            if now - last_hb >= 1.0:
                self.send_heartbeat()
                last_hb = now
            self.recv(0.1)
            if self.heartbeat is not None:
                hb = self.heartbeat
                self.target_system = hb.get_srcSystem()
                self.mav.srcSystem = self.target_system
                if hb.autopilot == M.MAV_AUTOPILOT_PX4:
                    self.autopilot = "px4"
                elif hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
                    self.autopilot = "ardupilot"
                else:
                    raise LinkError(f"the autopilot on {self.url} is neither PX4 nor ArduPilot "
                                    f"(MAV_AUTOPILOT {hb.autopilot}); mavadrc flies those two")
                return hb
        raise LinkError(f"no heartbeat from an autopilot on {self.url} within {timeout:.0f} s: is "
                        "the vehicle running, and is this where it sends (PX4 SITL's offboard "
                        "link: udpin:0.0.0.0:14540)?")

    @property
    def armed(self):
        return bool(self.heartbeat and self.heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def custom_mode(self):
        return self.heartbeat.custom_mode if self.heartbeat else None

    # --- sending -----------------------------------------------------------------------------

    def send_heartbeat(self):
        self.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                M.MAV_STATE_ACTIVE)

    def command(self, cmd, *params):
        """Send a COMMAND_LONG (not waiting); its ACK lands in ``acks[cmd]``."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.acks.pop(cmd, None)
        self.mav.command_long_send(self.target_system, 1, cmd, 0, *p)

    def command_wait(self, cmd, *params, timeout=1.0, retries=3, idle=None):
        """Send a command, retrying, until acknowledged; returns the MAV_RESULT.

        ``idle()`` is called while waiting (to keep a setpoint stream alive)."""
        for _ in range(retries):
            self.command(cmd, *params)
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                self.recv(0.02)
                if idle is not None:
                    idle()
                if cmd in self.acks:
                    return self.acks[cmd].result
        raise LinkError(f"no COMMAND_ACK for {command_name(cmd)} after {retries} tries")

    def set_rate(self, msgid, hz):
        """Ask for message ``msgid`` at ``hz`` (0: stop)."""
        interval = -1 if hz <= 0 else int(1e6 / hz)
        self.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msgid, interval)

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
    return RESULT_NAMES.get(result, str(result)).replace("MAV_RESULT_", "")


def command_name(cmd):
    for k, v in vars(M).items():
        if k.startswith("MAV_CMD_") and v == cmd:
            return k
    return str(cmd)
