"""The companion's end of the wire: connection strings, the connection, signing, the tlog and the
frames that arrive.

Connection strings are accepted as pymavlink and MAVSDK users write them::

    udpin:0.0.0.0:14540   udpin://0.0.0.0:14540   udp://:14540   udp://0.0.0.0:14540
    udpout:HOST:PORT      udpout://HOST:PORT      tcp:HOST:PORT   tcp://HOST:PORT
    /dev/ttyACM0          /dev/ttyUSB0:57600      /dev/ttyUSB0,57600   serial:///dev/ttyUSB0:57600

UDP is served by a socket of our own, bound without SO_REUSEADDR: a port another program already
listens on is an error that names it (two companions on one port would both command the
vehicle).  TCP and serial links go through pymavlink's mavutil.  Every frame in both directions
goes to an optional tlog writer as it passes.  With a signing key everything sent is signed and
everything received must be.
"""

import collections
import contextlib
import errno
import io
import re
import select
import socket
import time

from mavadrc.errors import LinkError
from mavadrc.mavlink.dialect import M, mavutil

#: a TCP link (tcp:HOST:PORT) is tried this many times, this many seconds apart, before the
#: flight gives up on it (an autopilot's SITL may still be starting)
TCP_TRIES = 3
TCP_RETRY_S = 1.0

#: accepted unsigned on a signed link (as PX4 and ArduPilot do: radios cannot sign)
UNSIGNED_ALLOWED = (M.MAVLINK_MSG_ID_RADIO_STATUS,)
#: 1 Jan 2015, the epoch of MAVLink 2 signing timestamps
SIGNING_EPOCH = 1420070400


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


def setup_signing(mav, key):
    """Sign everything ``mav`` sends with ``key`` and accept only signed frames (but
    :data:`UNSIGNED_ALLOWED`)."""
    s = mav.signing
    s.secret_key = bytes(key)
    s.sign_outgoing = True
    s.link_id = 0
    s.timestamp = int((time.time() - SIGNING_EPOCH) * 1e5)
    s.allow_unsigned_callback = lambda _mav, msgid: msgid in UNSIGNED_ALLOWED


class Transport:
    """The connection to the vehicle as an onboard computer (component 191), and the frames
    that pass it.

    ``mav`` is the pymavlink sender and parser (replaced by a fresh one after a frame it choked
    on: use it through this object).  :meth:`next` hands out the messages received one by one,
    ``BAD_DATA`` and messages the dialect lacks included; :meth:`bad` counts the bad ones
    (``bad_frames``, ``bad_signatures``).  ``sent`` counts the messages sent.  Over udpin
    (``answers_sender``) it answers whoever sent last until it is told an address
    (:meth:`answer_to`).
    """

    def __init__(self, url, tlog=None, signing_key=None):
        device, baud = parse_url(url)
        self.url = url
        self.tlog = tlog
        if device.startswith(("udpin:", "udpout:")):
            self.conn = UdpEndpoint(device, url)
            self.mav = M.MAVLink(self.conn, srcSystem=1, srcComponent=M.MAV_COMP_ID_ONBOARD_COMPUTER)
            self.mav.robust_parsing = True
            self.datagrams = True
            self.answers_sender = device.startswith("udpin:")
        else:
            tries = "" if not device.startswith("tcp:") else \
                f" ({TCP_TRIES} tries, {TCP_RETRY_S:g} s apart)"
            try:
                # pymavlink prints "<error> sleeping" on each refused try: said once, below
                with contextlib.redirect_stdout(io.StringIO()):
                    self.conn = mavutil.mavlink_connection(
                        device, baud=baud, source_system=1,
                        source_component=M.MAV_COMP_ID_ONBOARD_COMPUTER, autoreconnect=True,
                        retries=TCP_TRIES, reconnect_delay=TCP_RETRY_S)
            except (OSError, ImportError) as exc:
                raise LinkError(f"cannot open {url}: {exc}{tries}") from exc
            self.mav = self.conn.mav
            self.datagrams = self.answers_sender = False
        if signing_key is not None:
            setup_signing(self.mav, signing_key)
        self.mav.set_send_callback(self._sent)
        self.sent = 0
        self.bad_frames = 0
        self.bad_signatures = 0
        self._queue = collections.deque()  # the rest of a datagram's messages

    def _sent(self, msg):
        self.sent += 1
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())

    def close(self):
        self.conn.close()

    def speak_as(self, sysid):
        """Send as system ``sysid`` (the companion speaks as the autopilot's system)."""
        self.mav.srcSystem = sysid

    def answer_to(self, addr):
        """Send to ``addr`` only (udpin: the chosen autopilot's address)."""
        self.conn.peer = addr

    def next(self, end):
        """The next message received (None when none came by ``end``, time.monotonic()).

        Over UDP a datagram is read and parsed whole (pymavlink's parser, CRC and signing checks
        included) and its messages are handed out one by one, each with ``_from``, the address
        it came from; other links go through mavutil message by message.  The tlog is flushed
        before waiting for data."""
        if self._queue:
            return self._queue.popleft()
        if self.datagrams:
            return self._recv_datagram(max(0.0, end - time.monotonic()))
        if self.tlog is not None:
            self.tlog.flush()
        msg = self.conn.recv_match(blocking=True, timeout=max(0.0, end - time.monotonic()))
        if msg is not None and msg.get_type() != "BAD_DATA" and self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())
        return msg

    def bad(self, msg):
        """Whether ``msg`` is a frame that did not parse or failed the signature check
        (counted)."""
        if msg.get_type() != "BAD_DATA":
            return False
        reason = str(getattr(msg, "reason", ""))
        if "ignature" in reason or "unsigned" in reason.lower():
            self.bad_signatures += 1
        else:
            self.bad_frames += 1
        return True

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
            m._from = conn.last_from  # whose datagram (sources.Sources.admit)
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
