"""One MAVLink link of the bundled vehicle: its UDP socket and peers, signing, the parsing of each
datagram on its own with a count of everything dropped, and the schedule of its streams.

Each link binds a local port and sends to a remote one (PX4 SITL's layout: see
:mod:`sim.server`); whoever writes to the local port becomes a peer too.  A datagram is parsed
on its own: anything malformed, truncated, unknown or badly signed is dropped and counted in
:class:`Stats`, never acted on.  Streams are scheduled in integer microseconds of vehicle time
(so that lockstep never drifts a step); the frames of one step go out together, several to a
datagram as PX4 sends them, except LOCAL_POSITION_NED, which leaves at once on its own.
"""

import errno
import math
import socket
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

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
    by_reason: dict = field(default_factory=dict)

    def dropped(self):
        return (self.bad_prefix + self.bad_crc + self.bad_length + self.truncated
                + self.unknown_msgid + self.unsigned_rejected + self.bad_signature)

    def count(self, reason):
        self.by_reason[reason] = self.by_reason.get(reason, 0) + 1


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
        self.intervals = {}
        self.next_due = {}
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

    def sendto(self, buf):
        for peer in self.peers:
            try:
                self.sock.sendto(buf, peer)
            except OSError:
                pass

    def begin(self):
        self.batch = []

    def flush(self):
        frames, self.batch = self.batch, None
        chunk = b""
        for f in frames or ():
            if chunk and len(chunk) + len(f) > self.MAX_DATAGRAM:
                self.sendto(chunk)
                chunk = b""
            chunk += f
        if chunk:
            self.sendto(chunk)

    def set_interval(self, mid, interval_us, due=None):
        """Schedule message ``mid`` every ``interval_us`` us of vehicle time (None: never),
        next at ``due`` if given.  LOCAL_POSITION_NED stays first in the schedule (it goes out
        in a datagram of its own, so a companion's control step can start while the rest of
        the step's telemetry is still being built)."""
        self.intervals[mid] = interval_us
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
        self.begin()
        next_any = math.inf
        for mid, interval in self.intervals.items():
            if not interval:
                continue
            due = self.next_due.get(mid, 0)
            if t >= due:
                msg = build(mid)
                if msg is not None:
                    self.mav.send(msg)
                    if mid == LPN:  # the sample leaves at once, on its own
                        self.flush()
                        self.begin()
                nxt = due + interval
                due = self.next_due[mid] = nxt if nxt > t else t + interval
            if due < next_any:
                next_any = due
        self.next_any = next_any
        self.flush()


def _setup_signing(mav, key):
    s = mav.signing
    s.secret_key = bytes(key)
    s.sign_outgoing = True
    s.link_id = 0
    s.timestamp = int((time.time() - 1420070400) * 1e5)
    s.allow_unsigned_callback = lambda _mav, msgid: msgid in UNSIGNED_ALLOWED
