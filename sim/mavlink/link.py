"""One MAVLink link of the bundled vehicle: its UDP socket and peers, signing, the parsing of each
datagram on its own with a count of everything dropped, and the schedule of its streams.

Each link binds a local port and sends to a remote one (PX4 SITL's layout: see
:mod:`sim.server`); whoever writes to the local port becomes a peer too.  A datagram is parsed
on its own: anything malformed, truncated, unknown or badly signed is dropped and counted in
:class:`Stats`, never acted on.  Streams are scheduled in integer microseconds of vehicle time
(so that lockstep never drifts a step); the frames of one step go out together, several to a
datagram as PX4 sends them, except LOCAL_POSITION_NED, which leaves at once on its own.

A link may have a bandwidth (:mod:`sim.mavlink.bandwidth`): its frames then go through a line of
that many bytes a second, one frame to a datagram (a radio carries a byte stream; its far end
forwards frame by frame), and its streams slow down as the autopilot's do.  What leaves goes
through ``transmit(buf, peer, delay_s)``: at once, or, in real time with a link model, on the
wall clock (:mod:`sim.mavlink.realtime`).
"""

import errno
import math
import socket
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .bandwidth import DEFAULT_FRAME, STREAM_SHARE, Line, rate_mult

#: the sample a companion's control step runs on
LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED

#: PX4's default onboard-link rates (Hz)
ONBOARD_RATES = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: 30.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    # mavlink_main.cpp, MAVLINK_MODE_ONBOARD (a vehicle without a range finder sends none)
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: 10.0,
}
#: a slower ground-station set
GCS_RATES = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 5.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
}

LOOPBACK = "127.0.0.1"

#: with signing on, the messages accepted unsigned (ArduPilot's rule)
UNSIGNED_ALLOWED = (mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS)


@dataclass
class Stats:
    """What the vehicle received and what it refused, by reason."""
    datagrams: int = 0
    messages: int = 0
    bad_prefix: int = 0
    bad_crc: int = 0
    bad_length: int = 0
    truncated: int = 0
    unknown_msgid: int = 0
    unsigned_rejected: int = 0
    bad_signature: int = 0
    other_target: int = 0
    setpoints_rejected: int = 0
    setpoints_ignored: int = 0
    commands: int = 0
    overruns: int = 0
    # what the link model and the bandwidth did (real time): lost at random, cut by a
    # blackout, delayed; down = vehicle -> companion, up = companion -> vehicle
    link_lost_down: int = 0
    link_lost_up: int = 0
    link_dark_down: int = 0
    link_dark_up: int = 0
    link_delayed_down: int = 0
    link_delayed_up: int = 0
    bandwidth_dropped: int = 0  # frames a full transmit buffer could not take
    by_reason: dict = field(default_factory=dict)

    def dropped(self):
        return (self.bad_prefix + self.bad_crc + self.bad_length + self.truncated
                + self.unknown_msgid + self.unsigned_rejected + self.bad_signature)

    def count(self, reason):
        self.by_reason[reason] = self.by_reason.get(reason, 0) + 1

    def link_summary(self):
        """One line on what the link model and the bandwidth did (None: nothing)."""
        parts = []
        for way in ("down", "up"):
            lost, dark, late = (getattr(self, f"link_{k}_{way}")
                                for k in ("lost", "dark", "delayed"))
            if lost or dark or late:
                parts.append(f"{way}: {lost} lost, {dark} in blackouts, {late} delayed")
        if self.bandwidth_dropped:
            parts.append(f"{self.bandwidth_dropped} frames over the bandwidth")
        return "; ".join(parts) or None


def default_ports(instance, offboard_port=None, gcs_port=None, bind_offboard=None, bind_gcs=None):
    """{link name: (remote port it sends to, local port it binds)} for instance N, as PX4 SITL
    numbers them (offboard: 14540+N and 14580+N; ground station: 14550 and 18570+N); a port
    given overrides its default (a local port of 0: any free one)."""
    return {"offboard": (14540 + instance if offboard_port is None else offboard_port,
                         14580 + instance if bind_offboard is None else bind_offboard),
            "gcs": (14550 if gcs_port is None else gcs_port,
                    18570 + instance if bind_gcs is None else bind_gcs)}


class PortInUse(OSError):
    """A link's local UDP port is taken by another socket."""

    def __init__(self, link, host, port):
        super().__init__(f"UDP port {port} on {host}, the local port of the {link} link, "
                         f"is in use")
        self.link = link
        self.port = port


def bind_udp(host, port, link):
    """A non-blocking UDP socket bound to (host, port) for link ``link``; PortInUse if another
    socket has that port."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        if e.errno == errno.EADDRINUSE:
            raise PortInUse(link, host, port) from None
        raise
    sock.setblocking(False)
    return sock


def read_signing_key(path):
    """The 32-byte secret from a file holding it as 64 hex characters."""
    with open(path, encoding="ascii") as f:
        text = f.read().strip()
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise ValueError(f"{path}: signing key must be 64 hex characters") from None
    if len(key) != 32:
        raise ValueError(f"{path}: signing key must be 32 bytes (64 hex characters), got {len(key)}")
    return key


class _Sender:
    """File-like target for pymavlink's MAVLink.send: writes each frame to every peer of a link,
    or, between ``Link.begin()`` and ``Link.flush()``, collects the frames of one step so they go
    out together (several frames per datagram, as PX4 sends them)."""

    def __init__(self, link):
        self.link = link

    def write(self, buf):
        if self.link.batch is not None:
            self.link.batch.append(bytes(buf))
        else:
            self.link.sendto(buf)


class Link:
    """One link: ``name`` ("offboard" or "gcs"), its bound socket, the address it sends to, the
    vehicle's system id, its default stream rates {msgid: Hz} and the signing secret (None: no
    signing)."""

    MAX_DATAGRAM = 1400

    def __init__(self, name, sock, remote, sysid, rates, signing_key=None):
        self.name = name
        self.sock = sock
        self.peers = [remote] if remote else []
        self.batch = None
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.mav.file = _Sender(self)
        if signing_key is not None:
            _setup_signing(self.mav, signing_key)
        self.default_rates = dict(rates)
        self.intervals = {}  # {msgid: us} the stream runs at
        self.requested = {}  # {msgid: us} GET_MESSAGE_INTERVAL reports
        self.next_due = {}
        self.transmit = self._transmit
        self.inbound = None  # takes each received datagram instead (sim.mavlink.realtime)
        self.clock = lambda: 0.0  # vehicle time (s): the line's clock
        self.stats = None
        self.line = None  # a bandwidth-limited line (sim.mavlink.bandwidth.Line)
        self.throttle = "rate_mult"
        self.rate_mult = 1.0
        self._mult_due = 0
        self.sizes = {}  # {msgid: average frame size (bytes)}
        for mid, hz in rates.items():
            self.set_interval(mid, int(round(1e6 / hz)), due=0)
        self.parser = None  # reused across datagrams while they parse cleanly

    # --- receiving -------------------------------------------------------------------------------

    def learn(self, addr):
        if addr not in self.peers:
            self.peers.append(addr)

    def parse(self, data, stats):
        """Decode one datagram on its own; count and drop everything that is not a good frame.

        The parser is reused only while every datagram leaves it empty; one that leaves a
        partial frame behind (or makes it raise) gets a fresh parser for the next datagram, so
        nothing of a bad datagram carries over."""
        parser = self.parser
        if parser is None:
            parser = self.parser = mavlink.MAVLink(None, srcSystem=self.mav.srcSystem,
                                                   srcComponent=1)
            parser.robust_parsing = True
            parser.signing = self.mav.signing
        out = []
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:
            stats.bad_length += 1
            self.parser = None
            return out
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                reason = str(getattr(m, "reason", ""))
                if "prefix" in reason:
                    stats.bad_prefix += 1
                elif "CRC" in reason:
                    stats.bad_crc += 1
                elif "signature" in reason:
                    if m.data and len(m.data) > 2 and (m.data[2] & mavlink.MAVLINK_IFLAG_SIGNED):
                        stats.bad_signature += 1
                    else:
                        stats.unsigned_rejected += 1
                else:
                    stats.bad_length += 1
                continue
            if t == "UNKNOWN" or m.get_msgId() < 0:
                stats.unknown_msgid += 1
                continue
            out.append(m)
        if parser.buf_len() > 0:
            stats.truncated += 1
            self.parser = None
        stats.messages += len(out)
        return out

    # --- sending ---------------------------------------------------------------------------------

    def set_bandwidth(self, bytes_per_s, buffer_bytes, throttle):
        """Carry this link's frames over a line of ``bytes_per_s`` behind a transmit buffer of
        ``buffer_bytes``, its streams throttled the ``throttle`` way ("rate_mult" or
        "payload_space", :mod:`sim.mavlink.bandwidth`)."""
        self.line = Line(bytes_per_s, buffer_bytes)
        self.throttle = throttle
        self._mult_due = 0

    def sendto(self, buf):
        delay = 0.0
        if self.line is not None:
            delay = self.line.put(self.clock(), len(buf))
            if delay is None:
                if self.stats is not None:
                    self.stats.bandwidth_dropped += 1
                return
        for peer in self.peers:
            self.transmit(buf, peer, delay)

    def _transmit(self, buf, peer, delay=0.0):
        try:
            self.sock.sendto(buf, peer)
        except OSError:
            pass

    def begin(self):
        self.batch = []

    def flush(self):
        frames, self.batch = self.batch, None
        if self.line is not None:  # a byte stream: each frame on its own
            for f in frames or ():
                self.sendto(f)
            return
        chunk = b""
        for f in frames or ():
            if chunk and len(chunk) + len(f) > self.MAX_DATAGRAM:
                self.sendto(chunk)
                chunk = b""
            chunk += f
        if chunk:
            self.sendto(chunk)

    def set_interval(self, mid, interval_us, due=None, requested=None):
        """Schedule message ``mid`` every ``interval_us`` us of vehicle time (None: never),
        next at ``due`` if given; ``requested`` is the interval reported for it (default
        ``interval_us``).  LOCAL_POSITION_NED stays first in the schedule (it goes out in a
        datagram of its own, so a companion's control step can start while the rest of the
        step's telemetry is still being built)."""
        self.intervals[mid] = interval_us
        self.requested[mid] = interval_us if requested is None else requested
        self._mult_due = 0
        if due is not None:
            self.next_due[mid] = due
        if LPN in self.intervals:
            self.intervals = {LPN: self.intervals.pop(LPN), **self.intervals}
        self.next_any = 0  # the earliest next_due (us of vehicle time): look at every entry

    def send_due(self, t, build):
        """Send what the schedule has due at vehicle time ``t`` (us), each message made by
        ``build(msgid)`` (None: not produced), as one batch."""
        if t < self.next_any:
            return  # nothing of this link's schedule is due
        line = self.line
        mult = 1.0
        if line is not None and self.throttle == "rate_mult":
            if t >= self._mult_due:
                self._update_rate_mult()
                self._mult_due = t + 100_000
            mult = self.rate_mult
        waits = line is not None and self.throttle == "payload_space"
        self.begin()
        next_any = math.inf
        schedule = self.intervals.items()
        if waits:  # the most overdue first, as ArduPilot's buckets take turns
            schedule = sorted(schedule, key=lambda item: self.next_due.get(item[0], 0))
        for mid, interval in schedule:
            if not interval:
                continue
            if mult < 1.0:
                interval = max(interval, int(self.requested.get(mid, interval) / mult))
            due = self.next_due.get(mid, 0)
            if t >= due:
                if waits and (line.backlog(t * 1e-6) + sum(map(len, self.batch))
                              + self.sizes.get(mid, DEFAULT_FRAME) > STREAM_SHARE * line.buffer):
                    # no room in the port: this pass ends here, and the message and the rest
                    # wait for the next (GCS_MAVLINK::update_send stops at the first one that
                    # does not fit)
                    next_any = min(next_any, due)
                    break
                msg = build(mid)
                if msg is not None:
                    self.mav.send(msg)
                    if self.batch:
                        n = len(self.batch[-1])
                        self.sizes[mid] = 0.9 * self.sizes.get(mid, n) + 0.1 * n
                    if mid == LPN:  # the sample leaves at once, on its own
                        self.flush()
                        self.begin()
                nxt = due + interval
                due = self.next_due[mid] = nxt if nxt > t else t + interval
            if due < next_any:
                next_any = due
        self.next_any = next_any
        self.flush()

    def _update_rate_mult(self):
        """PX4's Mavlink::update_rate_mult over this link's streams for a data rate of half the
        line (HEARTBEAT, 1 Hz, is the constant-rate stream)."""
        hb = 21 + (13 if self.mav.signing.sign_outgoing else 0)
        streams = [(self.sizes.get(mid, DEFAULT_FRAME), self.requested.get(mid, us))
                   for mid, us in self.intervals.items() if us]
        self.rate_mult = rate_mult(STREAM_SHARE * self.line.rate, streams, hb)


def _setup_signing(mav, key):
    s = mav.signing
    s.secret_key = bytes(key)
    s.sign_outgoing = True
    s.link_id = 0
    s.timestamp = int((time.time() - 1420070400) * 1e5)
    s.allow_unsigned_callback = lambda _mav, msgid: msgid in UNSIGNED_ALLOWED
