"""A lossy UDP link for tests: a MAVLink-aware proxy between the vehicle and a companion.

The proxy sits on the offboard link of the bundled vehicle (or of any MAVLink endpoint that
sends to a port of our choice and answers whoever writes to it) and reproduces real-link
faults deterministically::

    down: vehicle --> link.vehicle_port [proxy] companion-side socket --> companion_port
    up:   vehicle <-- link.vehicle_port [proxy] companion-side socket <-- companion

Up, the proxy sends to the address the vehicle's datagrams come from (so the vehicle hears its
configured peer answer); the companion answers the companion-side socket it hears from.

"down" is vehicle -> companion, "up" is companion -> vehicle.  Each direction is a
:class:`Channel` (``link.down``, ``link.up``) with its own faults and statistics.  Without
faults every datagram is forwarded as soon as the proxy thread reads it, byte for byte.

Usage (a flight of the companion over a lossy link)::

    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    from lossy_link import LossyLink, start_lossy_vehicle
    from mavadrc.flight.fly import fly
    from mavadrc.mission.config import load_mission

    mission = load_mission("configs/missions/hover.yaml")

    srv, link = start_lossy_vehicle(seed=0, link_seed=3)   # real-time vehicle behind a proxy
    try:
        link.down.loss = 0.05                       # 5 % of the vehicle's datagrams are lost
        link.up.latency, link.up.jitter = 0.02, 0.005
        link.blackout(0.0, 1.0, after_lpn=300)      # both ways dead for 1 s after 300 samples
        link.inject_nan(nth=100, fields=("x",))     # the 100th LOCAL_POSITION_NED has x = NaN
        link.drop_ack(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)        # the first ARM ack is lost
        summary, folder = fly(mission, connect=link.companion_url, figures=False)
        assert link.down.stats.frames_dropped["blackout"] > 0
    finally:
        link.stop()
        srv.stop()

or, with a vehicle started elsewhere whose offboard link sends to ``port``::

    with LossyLink(companion_port, vehicle_port=port, seed=1) as link:
        ...

Faults (all can be changed while the proxy runs, from any thread):

* ``channel.loss``: probability of losing a whole datagram; ``channel.frame_loss``: probability
  of losing each MAVLink frame of a datagram on its own (the kept frames go out as one
  datagram, byte-exact, in their order).
* ``channel.latency`` and ``channel.jitter`` (s), ``channel.jitter_dist`` ``"uniform"``
  (latency + U(-jitter, +jitter)) or ``"gauss"`` (latency + N(0, jitter)); the total is never
  negative.  Datagrams leave at their due time, so with latency alone the order is kept and
  jitter reorders them as a real network would.
* :meth:`LossyLink.blackout`: windows (start_s, duration_s) after a reference (the proxy's
  start, now, a :meth:`LossyLink.mark`, or the N-th LOCAL_POSITION_NED forwarded down) in
  which nothing passes in one direction or both.  A datagram is lost if it arrives or is due
  to leave during a blackout.
* :meth:`LossyLink.corrupt` / :meth:`LossyLink.inject_nan`: set fields of the k-th message of a
  type forwarded in a direction (re-encoded with pymavlink: valid CRC, same seq, srcSystem,
  srcComponent and compat flags).  ``link.hook = f(msg, direction) -> msg or None`` sees every
  decodable frame and may change it (in place or by returning another message) or drop it.
* :meth:`LossyLink.drop_command`, :meth:`LossyLink.drop_ack`, :meth:`LossyLink.drop_messages`:
  drop the first n COMMAND_LONG / COMMAND_ACK of a command, or a message type (optionally only
  one command) always or with a probability.

Randomness is reproducible: each direction draws from ``random.Random`` streams derived from
``seed``, one stream per kind of fault (datagram loss, frame loss, delay, drop rules), each
drawing only while its fault is on; so the same seed and the same datagrams give the same
decisions whatever the other faults do.  The traffic itself is real time, so a flight through
the proxy is only as deterministic as the arrival order of its datagrams.

From the first byte that does not start a complete MAVLink 1 or 2 frame, the rest of a
datagram is one opaque chunk (type ``"UNPARSED"``), forwarded unchanged (datagram loss,
latency and blackouts still apply to it); frames that parse but do not decode (bad CRC,
unknown id) are forwarded unchanged too.  Signed frames are forwarded unchanged; a modification of one is
refused: the frame goes out as it came, and the error is recorded in ``link.errors`` and
raised by :meth:`LossyLink.stop`.

Limits: IPv4, one companion (the ``companion_port`` given), one vehicle (the last address it
sent from).  The proxy is a Python thread: in the test process it shares the GIL with a
companion flown there, which is what its forwarding time (about 0.2 ms on loopback) depends
on.  Drop-rule and hook decisions decode frames with pymavlink (tens of microseconds each).
"""

import heapq
import logging
import math
import os
import random
import select
import socket
import struct
import threading
import time
from collections import Counter, namedtuple
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink loads a dialect: speak MAVLink 2

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

log = logging.getLogger("mavadrc.tests.lossy_link")

LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
DIRECTIONS = ("down", "up")
_V2, _V1 = 0xFD, 0xFE
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN = 13

#: one dropped frame: t (s since the proxy started), direction, message type, reason, seq
#: (None for an unparsed chunk)
Drop = namedtuple("Drop", "t direction type reason seq")
#: one modified frame: t, direction, type, seq, what ("fields x,y", "hook")
Modification = namedtuple("Modification", "t direction type seq what")


class LossyLinkError(RuntimeError):
    """A fault the proxy was asked for but refused (a signed frame, an undecodable frame, a
    hook that raised), raised by :meth:`LossyLink.stop`."""


def msg_id(msg_type):
    """The message id of ``msg_type`` (an id or a name such as ``"LOCAL_POSITION_NED"``)."""
    if isinstance(msg_type, int):
        return msg_type
    mid = getattr(mavlink, f"MAVLINK_MSG_ID_{str(msg_type).upper()}", None)
    if mid is None:
        raise ValueError(f"unknown MAVLink message type {msg_type!r}")
    return mid


def msg_name(mid):
    if mid is None:
        return "UNPARSED"
    cls = mavlink.mavlink_map.get(mid)
    return cls.msgname if cls is not None else f"UNKNOWN_{mid}"


def _directions(direction):
    if direction == "both":
        return DIRECTIONS
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be 'down', 'up' or 'both', not {direction!r}")
    return (direction,)


# --- frames ------------------------------------------------------------------------------------

class Frame:
    """One MAVLink frame of a datagram (``msgid`` None: an unparsed rest, forwarded as is)."""

    __slots__ = ("raw", "msgid", "msg", "decoded", "new", "what")

    def __init__(self, raw, msgid):
        self.raw = raw
        self.msgid = msgid
        self.msg = None  # the decoded message (only decoded when a fault needs its fields)
        self.decoded = False
        self.new = None  # the message to re-encode in place of raw, if modified
        self.what = []  # what changed it: "hook" and field names

    @property
    def v1(self):
        return self.raw[0] == _V1

    @property
    def signed(self):
        return self.raw[0] == _V2 and bool(self.raw[2] & _SIGNED)

    @property
    def seq(self):
        if self.msgid is None:
            return None
        return self.raw[4] if self.raw[0] == _V2 else self.raw[2]

    @property
    def src(self):
        """(srcSystem, srcComponent)."""
        return (self.raw[5], self.raw[6]) if self.raw[0] == _V2 else (self.raw[3], self.raw[4])

    def decode(self, decoder):
        """The pymavlink message, or None if the frame does not decode (bad CRC, unknown id)."""
        if not self.decoded:
            self.decoded = True
            if self.msgid is not None:
                try:
                    m = decoder.decode(bytearray(self.raw))
                except Exception:  # noqa: BLE001 (pymavlink raises MAVError and struct errors)
                    m = None
                if m is not None and not isinstance(m, mavlink.MAVLink_unknown):
                    self.msg = m
        return self.msg


def split_frames(data):
    """The frames of a datagram, in order: each MAVLink 1 or 2 frame on its own (by its length
    field, signature included), and anything from the first byte that does not start a
    complete frame to the end as one unparsed chunk.  ``b"".join(f.raw ...)`` gives ``data``."""
    frames = []
    i, n = 0, len(data)
    while i < n:
        b = data[i]
        if b == _V2 and i + 10 <= n:
            end = i + 12 + data[i + 1] + (_SIGNATURE_LEN if data[i + 2] & _SIGNED else 0)
            if end <= n:
                mid = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
                frames.append(Frame(data[i:end], mid))
                i = end
                continue
        elif b == _V1 and i + 6 <= n:
            end = i + 8 + data[i + 1]
            if end <= n:
                frames.append(Frame(data[i:end], data[i + 5]))
                i = end
                continue
        frames.append(Frame(data[i:], None))
        break
    return frames


def encode_like(msg, frame, encoder):
    """``msg`` packed as ``frame`` was: same seq, srcSystem, srcComponent, protocol version and
    compat flags, with a fresh CRC (pymavlink's packer, trailing zeros trimmed in MAVLink 2)."""
    encoder.srcSystem, encoder.srcComponent = frame.src
    encoder.seq = frame.seq
    buf = bytearray(msg.pack(encoder, force_mavlink1=frame.v1))
    if not frame.v1 and frame.raw[3] != buf[3]:  # keep the sender's compat flags
        buf[3] = frame.raw[3]
        crc = mavlink.x25crc(buf[1:-2])
        crc.accumulate(struct.pack("B", msg.crc_extra))
        buf[-2:] = struct.pack("<H", crc.crc)
    return bytes(buf)


def _snapshot(msg):
    return type(msg), repr([getattr(msg, f, None) for f in msg.get_fieldnames()])


# --- configuration objects ---------------------------------------------------------------------

@dataclass
class ChannelStats:
    """What one direction saw.  Frames count MAVLink frames and unparsed chunks; once nothing
    is in flight, ``frames_in == frames_out + sum(frames_dropped.values())`` and the same for
    datagrams."""
    datagrams_in: int = 0
    datagrams_out: int = 0
    datagrams_dropped: Counter = field(default_factory=Counter)  # by reason
    frames_in: int = 0
    frames_out: int = 0
    frames_dropped: Counter = field(default_factory=Counter)  # by reason
    frames_modified: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    unparsed: int = 0  # unparsed chunks seen (forwarded unchanged)
    undecodable: int = 0  # frames a fault had to decode but could not (forwarded unchanged)
    refused: int = 0  # modifications refused (signed or undecodable frames)
    drops: list = field(default_factory=list)  # Drop records, in order
    modifications: list = field(default_factory=list)  # Modification records, in order
    in_flight: int = 0  # datagrams waiting out their latency

    def dropped_types(self, reason=None):
        """Counter of the dropped message types (for one reason, or all)."""
        return Counter(d.type for d in self.drops if reason is None or d.reason == reason)


class Channel:
    """The faults and statistics of one direction (``"down"``: vehicle -> companion, ``"up"``:
    companion -> vehicle).  Set the attributes at any time; they are validated."""

    _FAULTS = ("loss", "frame_loss", "latency", "jitter", "jitter_dist")

    def __init__(self, name, seed):
        self.name = name
        self.loss = 0.0
        self.frame_loss = 0.0
        self.latency = 0.0
        self.jitter = 0.0
        self.jitter_dist = "uniform"
        self.stats = ChannelStats()
        self.reseed(seed)
        self._fwd = Counter()  # frames forwarded, by message id (after drops and the hook)
        self._lpn_times = []  # monotonic time of each LOCAL_POSITION_NED forwarded

    def reseed(self, seed):
        """Restart this direction's random streams (one per kind of fault) from ``seed``."""
        self.rng_loss = random.Random(f"{seed}:{self.name}:loss")
        self.rng_frame = random.Random(f"{seed}:{self.name}:frame")
        self.rng_delay = random.Random(f"{seed}:{self.name}:delay")
        self.rng_rules = random.Random(f"{seed}:{self.name}:rules")

    def __setattr__(self, key, value):
        if key in ("loss", "frame_loss"):
            value = float(value)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{key} is a probability, not {value}")
        elif key in ("latency", "jitter"):
            value = float(value)
            if not value >= 0.0:
                raise ValueError(f"{key} must be >= 0 s, not {value}")
        elif key == "jitter_dist" and value not in ("uniform", "gauss"):
            raise ValueError(f"jitter_dist is 'uniform' or 'gauss', not {value!r}")
        object.__setattr__(self, key, value)

    def set(self, **faults):
        """Set several faults at once: ``link.down.set(loss=0.1, latency=0.02)``."""
        for key, value in faults.items():
            if key not in self._FAULTS:
                raise TypeError(f"unknown fault {key!r} (one of {', '.join(self._FAULTS)})")
            setattr(self, key, value)
        return self

    def clear(self):
        """No loss, no latency."""
        return self.set(loss=0.0, frame_loss=0.0, latency=0.0, jitter=0.0)

    def delay(self):
        d = self.latency
        if self.jitter > 0.0:
            if self.jitter_dist == "gauss":
                d += self.rng_delay.gauss(0.0, self.jitter)
            else:
                d += self.rng_delay.uniform(-self.jitter, self.jitter)
        return d if d > 0.0 else 0.0

    def __repr__(self):
        return (f"Channel({self.name}: loss={self.loss}, frame_loss={self.frame_loss}, "
                f"latency={self.latency}, jitter={self.jitter} {self.jitter_dist})")


class _Ref:
    """A reference point: a time and the per-direction counts of forwarded messages then."""

    def __init__(self, t, counts):
        self.t = t
        self.counts = counts  # {"down": Counter, "up": Counter}


class Rule:
    """A drop rule (from :meth:`LossyLink.drop_messages` and friends).  ``dropped`` counts the
    frames it dropped; ``remaining`` (None: no limit) how many more it may drop; set
    ``active = False`` (or :meth:`LossyLink.remove`) to lift it."""

    def __init__(self, directions, msgid, command, p, n, where, reason):
        self.directions = directions
        self.msgid = msgid
        self.command = command
        self.p = float(p)
        self.remaining = n
        self.where = where
        self.reason = reason
        self.dropped = 0
        self.active = True

    def __repr__(self):
        cmd = "" if self.command is None else f" command={self.command}"
        return (f"Rule({msg_name(self.msgid)}{cmd} {'/'.join(self.directions)} p={self.p} "
                f"remaining={self.remaining} dropped={self.dropped})")


class Blackout:
    """A window in which nothing passes: ``start_s`` .. ``start_s + duration_s`` after its
    anchor (``anchor`` is the monotonic time, None until the reference has happened)."""

    def __init__(self, start_s, duration_s, directions, ref_name, lpn):
        self.start_s = float(start_s)
        self.duration_s = float(duration_s)
        self.directions = directions
        self.ref_name = ref_name
        self.lpn = lpn
        self.ref = None
        self.anchor = None

    def window(self):
        """(begin, end) in monotonic time, or None while the anchor is unknown."""
        if self.anchor is None:
            return None
        return self.anchor + self.start_s, self.anchor + self.start_s + self.duration_s

    def __repr__(self):
        after = self.ref_name + (f" + {self.lpn} LOCAL_POSITION_NED" if self.lpn else "")
        return (f"Blackout({self.start_s}+{self.duration_s} s after {after}, "
                f"{'/'.join(self.directions)})")


class Corruption:
    """Field changes for the ``nth`` .. ``nth + count - 1``-th message of a type forwarded in
    a direction after a reference.  ``applied`` counts the frames changed."""

    def __init__(self, direction, msgid, nth, count, fields, ref_name):
        self.direction = direction
        self.msgid = msgid
        self.nth = int(nth)
        self.count = int(count)
        self.fields = dict(fields)
        self.ref_name = ref_name
        self.first = None  # absolute forwarded count of the first message to change
        self.applied = 0

    def __repr__(self):
        return (f"Corruption({msg_name(self.msgid)} #{self.nth}x{self.count} {self.direction} "
                f"after {self.ref_name}: {self.fields}, applied={self.applied})")


# --- the proxy ---------------------------------------------------------------------------------

class LossyLink:
    """A UDP proxy between a vehicle's offboard link and a companion, with faults.

    ``LossyLink(companion_port, vehicle_port=0, host="127.0.0.1", seed=0, vehicle_addr=None)``:
    the companion listens on ``companion_port`` (``udpin:HOST:PORT``, see ``companion_url``);
    the vehicle must send to ``vehicle_port`` (bound now; 0 picks a free port, read it back from
    the attribute).  Datagrams from the companion go to the address the vehicle last sent from
    (or ``vehicle_addr`` until it has sent), from the vehicle-side socket, so the vehicle sees
    its configured peer answering.  ``start()`` runs the proxy in a thread, ``stop()`` ends it;
    it is also a context manager.
    """

    def __init__(self, companion_port, *, vehicle_port=0, host="127.0.0.1", seed=0,
                 vehicle_addr=None):
        self.host = host
        self.companion_port = int(companion_port)
        self.companion_addr = (host, self.companion_port)
        self.vehicle_addr = tuple(vehicle_addr) if vehicle_addr is not None else None
        self.seed = seed
        self.down = Channel("down", seed)
        self.up = Channel("up", seed)
        self.hook = None  # f(msg, direction) -> msg (the same, changed, or another) or None
        self.errors = []
        self.rules = []
        self.blackouts = []
        self.corruptions = []
        self.marks = {}
        self._pending = []  # blackouts and corruptions waiting for a mark of their ref_name
        self._lock = threading.RLock()
        self._heap = []
        self._order = 0
        self._decoder = {d: mavlink.MAVLink(None) for d in DIRECTIONS}
        self._encoder = mavlink.MAVLink(None)
        self._start_t = None  # monotonic time of start() (see start_time)
        self._running = False
        self._thread = None
        self._vsock = self._socket(vehicle_port)
        self._csock = self._socket(0)
        self.vehicle_port = self._vsock.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)

    def _socket(self, port):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                s.setsockopt(socket.SOL_SOCKET, opt, 1 << 20)
            except OSError:
                pass
        s.bind((self.host, port))
        s.setblocking(False)
        return s

    # --- endpoints and life cycle ----------------------------------------------------------------

    @property
    def companion_url(self):
        """The connection string the companion listens with, e.g. ``udpin:127.0.0.1:14540``."""
        return f"udpin:{self.host}:{self.companion_port}"

    @property
    def companion_side_port(self):
        """The port the proxy sends to the companion from (the companion answers there)."""
        return self._csock.getsockname()[1]

    @property
    def start_time(self):
        """``time.monotonic()`` at :meth:`start` (None before): drop and modification records
        carry ``t`` relative to it, blackout windows are in monotonic time."""
        return self._start_t

    @property
    def channels(self):
        return {"down": self.down, "up": self.up}

    def start(self):
        with self._lock:
            if self._thread is not None:
                raise RuntimeError("the proxy is already started")
            self._start_t = time.monotonic()
            self._resolve("start", _Ref(self._start_t, {d: Counter() for d in DIRECTIONS}))
            self._running = True
        self._thread = threading.Thread(target=self._run, name="lossy-link", daemon=True)
        self._thread.start()
        return self

    def stop(self, check=True):
        """End the proxy and close its sockets (datagrams still waiting out their latency are
        dropped, reason ``"stopped"``); with ``check``, raise :class:`LossyLinkError` if a fault
        was refused or the hook raised."""
        self._running = False
        if self._thread is not None:
            try:
                self._wake_w.send(b"x")
            except OSError:
                pass
            self._thread.join(timeout=5.0)
        for s in (self._vsock, self._csock, self._wake_r, self._wake_w):
            s.close()
        with self._lock:
            t = time.monotonic()
            for _, _, ch, _, frames in self._heap:  # still in flight: lost with the link
                self._drop(ch, frames, "stopped", t)
                ch.stats.in_flight -= 1
            self._heap.clear()
        if check and self.errors:
            raise LossyLinkError("; ".join(self.errors))

    def __enter__(self):
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, exc_type, exc, tb):
        self.stop(check=exc_type is None)
        return False

    def now(self):
        """Seconds since the proxy started."""
        return time.monotonic() - self._start_t if self._start_t is not None else 0.0

    # --- references ------------------------------------------------------------------------------

    def _counts(self):
        return {d: Counter(self.channels[d]._fwd) for d in DIRECTIONS}

    def mark(self, name="mark"):
        """Record a reference point ``name`` (now, and the messages forwarded so far) for
        :meth:`blackout` and :meth:`corrupt` (``after=name``); returns the proxy time (s).
        Faults already anchored keep their anchor; marking again only moves later ones."""
        if name in ("start", "now"):
            raise ValueError(f"{name!r} is a reserved reference")
        with self._lock:
            ref = _Ref(time.monotonic(), self._counts())
            self.marks[name] = ref
            self._resolve(name, ref)
            return ref.t - (self._start_t if self._start_t is not None else ref.t)

    def _ref(self, after):
        """The reference ``after`` names if it has happened (None otherwise)."""
        if after == "now":
            return _Ref(time.monotonic(), self._counts())
        if after == "start":
            return (_Ref(self._start_t, {d: Counter() for d in DIRECTIONS})
                    if self._start_t is not None else None)
        return self.marks.get(after)

    def _resolve(self, name, ref):
        keep = []
        for item in self._pending:
            if item.ref_name == name:
                self._anchor(item, ref)
            else:
                keep.append(item)
        self._pending = keep

    def _anchor(self, item, ref):
        if isinstance(item, Blackout):
            item.ref = ref
            if not item.lpn:
                item.anchor = ref.t
            else:
                self._lpn_anchor(item)
        else:
            item.first = ref.counts[item.direction][item.msgid] + item.nth

    def _lpn_anchor(self, b):
        target = b.ref.counts["down"][LPN] + b.lpn
        times = self.down._lpn_times
        if len(times) >= target:
            b.anchor = times[target - 1]

    def _attach(self, item, after):
        with self._lock:
            ref = self._ref(after)
            if ref is None:
                self._pending.append(item)
            else:
                self._anchor(item, ref)

    # --- faults ----------------------------------------------------------------------------------

    def set(self, direction="both", **faults):
        """Set channel faults in one direction or both: ``link.set("both", loss=0.1)``."""
        for d in _directions(direction):
            self.channels[d].set(**faults)
        return self

    def reseed(self, seed):
        """Restart the random streams of both directions from ``seed``."""
        with self._lock:
            self.seed = seed
            self.down.reseed(seed)
            self.up.reseed(seed)

    def blackout(self, start_s, duration_s, *, direction="both", after="start", after_lpn=0):
        """Nothing passes in ``direction`` from ``start_s`` to ``start_s + duration_s`` seconds
        after the reference: ``after`` is ``"start"`` (the proxy's start), ``"now"``, or the name
        of a :meth:`mark` (pending until it is made); with ``after_lpn=N`` the reference is the
        moment the N-th LOCAL_POSITION_NED after that point is forwarded down (it passes; the
        window can begin right after it).  Returns the :class:`Blackout`."""
        if start_s < 0 or not duration_s >= 0:
            raise ValueError("a blackout starts at >= 0 s and lasts >= 0 s")
        b = Blackout(start_s, duration_s, _directions(direction), after, int(after_lpn))
        with self._lock:
            self.blackouts.append(b)
            self._attach(b, after)
        return b

    def corrupt(self, msg_type, nth, fields, *, direction="down", after="start", count=1):
        """Give the ``nth`` (1 = the first) message of ``msg_type`` forwarded in ``direction``
        after the reference (``"start"``, ``"now"`` or a mark name, as for :meth:`blackout`)
        the ``fields`` values (a dict), and the ``count - 1`` next ones too.  Messages dropped
        by other faults are not counted.  Returns the :class:`Corruption`."""
        if nth < 1 or count < 1:
            raise ValueError("nth and count start at 1")
        (d,) = _directions(direction)
        c = Corruption(d, msg_id(msg_type), nth, count, fields, after)
        cls = mavlink.mavlink_map.get(c.msgid)
        unknown = [f for f in c.fields if cls is None or f not in cls.fieldnames]
        if unknown:
            raise ValueError(f"{msg_name(c.msgid)} has no field {', '.join(unknown)}")
        with self._lock:
            self.corruptions.append(c)
            self._attach(c, after)
        return c

    def inject_nan(self, nth=1, fields=("x",), *, after="start", count=1):
        """NaN in ``fields`` of the ``nth`` LOCAL_POSITION_NED forwarded down (see
        :meth:`corrupt`)."""
        return self.corrupt(LPN, nth, {f: math.nan for f in fields}, direction="down",
                            after=after, count=count)

    def drop_messages(self, msg_type, p=1.0, *, direction="both", command=None, n=None,
                      where=None, reason="rule"):
        """Drop frames of ``msg_type`` in ``direction`` with probability ``p``; only those whose
        ``command`` field is ``command`` if given (COMMAND_LONG, COMMAND_INT, COMMAND_ACK), and
        for which ``where(msg)`` is true if given; at most ``n`` of them (None: no limit).
        Returns the :class:`Rule`."""
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"p is a probability, not {p}")
        cls = mavlink.mavlink_map.get(msg_id(msg_type))
        if command is not None and (cls is None or "command" not in cls.fieldnames):
            raise ValueError(f"{msg_name(msg_id(msg_type))} has no command field")
        rule = Rule(_directions(direction), msg_id(msg_type), command, p, n, where, reason)
        with self._lock:
            self.rules.append(rule)
        return rule

    def drop_command(self, command, n=1):
        """Drop the next ``n`` COMMAND_LONG of ``command`` going up (to the vehicle)."""
        return self.drop_messages("COMMAND_LONG", direction="up", command=command, n=n,
                                  reason="command")

    def drop_ack(self, command, n=1):
        """Drop the next ``n`` COMMAND_ACK of ``command`` going down (to the companion)."""
        return self.drop_messages("COMMAND_ACK", direction="down", command=command, n=n,
                                  reason="ack")

    def remove(self, item):
        """Lift a rule, blackout or corruption."""
        with self._lock:
            for lst in (self.rules, self.blackouts, self.corruptions, self._pending):
                if item in lst:
                    lst.remove(item)
            if isinstance(item, Rule):
                item.active = False

    def clear(self):
        """No faults at all (channels, rules, blackouts, corruptions, hook); stats are kept."""
        with self._lock:
            self.down.clear()
            self.up.clear()
            for r in self.rules:
                r.active = False
            self.rules.clear()
            self.blackouts.clear()
            self.corruptions.clear()
            self._pending.clear()
            self.hook = None

    # --- queries ---------------------------------------------------------------------------------

    def forwarded(self, msg_type="LOCAL_POSITION_NED", direction="down"):
        """How many frames of ``msg_type`` have been forwarded in ``direction`` (decided, not
        necessarily delivered yet if there is latency)."""
        (d,) = _directions(direction)
        with self._lock:
            return self.channels[d]._fwd[msg_id(msg_type)]

    def in_blackout(self, direction, t=None):
        """Whether a blackout holds ``direction`` at monotonic time ``t`` (now)."""
        t = time.monotonic() if t is None else t
        with self._lock:
            return self._blacked(direction, t)

    @property
    def drops(self):
        """Every drop of both directions, in time order."""
        with self._lock:
            return sorted(self.down.stats.drops + self.up.stats.drops, key=lambda d: d.t)

    def stats(self):
        """A snapshot: {"down": {...}, "up": {...}} of the counters (without the logs)."""
        with self._lock:
            out = {}
            for d, ch in self.channels.items():
                s = ch.stats
                out[d] = {k: (dict(v) if isinstance(v, Counter) else v)
                          for k, v in vars(s).items() if k not in ("drops", "modifications")}
            return out

    # --- the loop --------------------------------------------------------------------------------

    def _run(self):
        socks = [self._vsock, self._csock, self._wake_r]
        while self._running:
            with self._lock:
                timeout = max(0.0, self._heap[0][0] - time.monotonic()) if self._heap else None
            try:
                readable, _, _ = select.select(socks, [], [], timeout)
            except (OSError, ValueError):
                break
            if not self._running:
                break
            if self._heap:
                self._deliver_due()
            if self._wake_r in readable:
                try:
                    self._wake_r.recv(64)
                except OSError:
                    pass
            if self._vsock in readable:
                self._drain(self._vsock, self.down)
            if self._csock in readable:
                self._drain(self._csock, self.up)

    def _drain(self, sock, ch):
        while True:
            try:
                data, addr = sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:  # an ICMP error for an earlier send: ignore it
                continue
            except OSError:
                return
            with self._lock:
                if ch is self.down:
                    self.vehicle_addr = addr
                try:
                    self._forward(ch, data, time.monotonic())
                except Exception as e:  # noqa: BLE001 (a bug or a test's callable: keep going)
                    log.exception("lossy link: forwarding a datagram %s", ch.name)
                    self._error(f"forwarding a datagram {ch.name} failed: {e!r}")

    def _blacked(self, direction, t):
        for b in self.blackouts:
            if direction not in b.directions:
                continue
            if b.anchor is None and b.lpn and b.ref is not None:
                self._lpn_anchor(b)
            w = b.window()
            if w is not None and w[0] <= t < w[1]:
                return True
        return False

    def _drop(self, ch, frames, reason, t, datagram=True):
        s = ch.stats
        rel = t - self._start_t
        for f in frames:
            s.frames_dropped[reason] += 1
            s.drops.append(Drop(rel, ch.name, msg_name(f.msgid), reason, f.seq))
        if datagram:
            s.datagrams_dropped[reason] += 1

    def _error(self, text):
        log.warning("lossy link: %s", text)
        self.errors.append(text)

    def _forward(self, ch, data, now):
        s = ch.stats
        s.datagrams_in += 1
        s.bytes_in += len(data)
        frames = split_frames(data)
        s.frames_in += len(frames)
        if frames and frames[-1].msgid is None:
            s.unparsed += 1
        if self._blacked(ch.name, now):
            return self._drop(ch, frames, "blackout", now)
        if ch.loss > 0.0 and ch.rng_loss.random() < ch.loss:
            return self._drop(ch, frames, "loss", now)
        kept = []
        changed = False
        for f in frames:
            if f.msgid is not None:
                reason = self._frame_fate(ch, f, now)
                if reason is not None:
                    self._drop(ch, [f], reason, now, datagram=False)
                    changed = True
                    continue
                if f.new is not None:
                    raw = self._reencode(ch, f, now)
                    if raw is not f.raw:
                        f.raw = raw
                        changed = True
            kept.append(f)
        if frames and not kept:  # every frame dropped on its own: nothing left to send
            s.datagrams_dropped["emptied"] += 1
            return
        out = b"".join(f.raw for f in kept) if changed else data
        delay = ch.delay()
        if delay <= 0.0:  # due now: after whatever is overdue, before what is still in flight
            if self._heap:
                self._deliver_due()
            self._send(ch, out, kept, now)
        else:
            self._order += 1
            heapq.heappush(self._heap, (now + delay, self._order, ch, out, kept))
            s.in_flight += 1

    def _frame_fate(self, ch, f, now):
        """None if the frame goes on (maybe with ``f.new`` set), else the drop reason."""
        if ch.frame_loss > 0.0 and ch.rng_frame.random() < ch.frame_loss:
            return "frame_loss"
        decoder = self._decoder[ch.name]
        for rule in self.rules:
            if not rule.active or ch.name not in rule.directions or rule.msgid != f.msgid:
                continue
            if rule.remaining is not None and rule.remaining <= 0:
                continue
            if rule.command is not None or rule.where is not None:
                msg = f.decode(decoder)
                if msg is None:
                    ch.stats.undecodable += 1
                    continue
                if rule.command is not None and getattr(msg, "command", None) != rule.command:
                    continue
                if rule.where is not None:
                    try:
                        if not rule.where(msg):
                            continue
                    except Exception as e:  # noqa: BLE001 (a test's predicate)
                        self._error(f"the where= of {rule!r} raised {e!r}: frame kept")
                        continue
            if rule.p < 1.0 and ch.rng_rules.random() >= rule.p:
                continue
            rule.dropped += 1
            if rule.remaining is not None:
                rule.remaining -= 1
            return rule.reason
        hook = self.hook
        if hook is not None:
            msg = f.decode(decoder)
            if msg is not None:
                before = _snapshot(msg)
                try:
                    res = hook(msg, ch.name)
                except Exception as e:  # noqa: BLE001 (a test's hook: report, forward as is)
                    self._error(f"the hook raised {e!r} on {msg_name(f.msgid)} {ch.name}: "
                                f"forwarded unchanged")
                    f.msg, f.decoded = None, False  # it may have changed the message half-way
                else:
                    if res is None:
                        return "hook"
                    if res is not msg or _snapshot(res) != before:
                        f.new = res
                        f.what.append("hook")
        # forwarded: count it, and change it if a corruption is due
        n = ch._fwd[f.msgid] = ch._fwd[f.msgid] + 1
        if f.msgid == LPN and ch is self.down:
            ch._lpn_times.append(now)
        for c in self.corruptions:
            if (c.direction == ch.name and c.msgid == f.msgid and c.first is not None
                    and c.first <= n < c.first + c.count):
                msg = f.new if f.new is not None else f.decode(decoder)
                if msg is None:
                    ch.stats.undecodable += 1
                    ch.stats.refused += 1
                    self._error(f"cannot decode {msg_name(f.msgid)} seq {f.seq} {ch.name} "
                                f"to change {sorted(c.fields)}")
                    continue
                for k, v in c.fields.items():
                    setattr(msg, k, v)
                f.new = msg
                f.what.extend(c.fields)
                c.applied += 1
        return None

    def _reencode(self, ch, f, now):
        name = msg_name(f.msgid)
        if f.signed:
            ch.stats.refused += 1
            self._error(f"refused to modify the signed frame {name} seq {f.seq} {ch.name} "
                        f"(it would need the signing key): forwarded unchanged")
            return f.raw
        try:
            raw = encode_like(f.new, f, self._encoder)
        except Exception as e:  # noqa: BLE001 (a hook may return a message that does not pack)
            ch.stats.refused += 1
            self._error(f"cannot re-encode {name} seq {f.seq} {ch.name}: {e!r}")
            return f.raw
        if raw == f.raw:
            return f.raw
        ch.stats.frames_modified += 1
        ch.stats.modifications.append(Modification(now - self._start_t, ch.name, f.new.get_type(),
                                                   f.seq, ",".join(f.what)))
        return raw

    def _deliver_due(self):
        with self._lock:
            now = time.monotonic()
            while self._heap and self._heap[0][0] <= now:
                due, _, ch, out, frames = heapq.heappop(self._heap)
                ch.stats.in_flight -= 1
                if self._blacked(ch.name, due):
                    self._drop(ch, frames, "blackout", due)
                else:
                    self._send(ch, out, frames, due)

    def _send(self, ch, out, frames, t):
        if ch is self.down:
            sock, addr = self._csock, self.companion_addr
        else:
            sock, addr = self._vsock, self.vehicle_addr
            if addr is None:
                return self._drop(ch, frames, "no_vehicle", t)
        try:
            sock.sendto(out, addr)
        except OSError:
            return self._drop(ch, frames, "send_error", t)
        s = ch.stats
        s.datagrams_out += 1
        s.frames_out += len(frames)
        s.bytes_out += len(out)


def start_lossy_vehicle(*, link_seed=0, companion_port=None, **vehicle_kw):
    """A real-time bundled vehicle (``sitl_helpers.start_vehicle(**vehicle_kw)``) behind a
    started :class:`LossyLink`; returns (server, link).  The companion connects to
    ``link.companion_url``.  Stop both: ``link.stop(); server.stop()``."""
    from sitl_helpers import free_udp_port, start_vehicle

    srv, port = start_vehicle(**vehicle_kw)
    try:
        link = LossyLink(companion_port or free_udp_port(), vehicle_port=port, seed=link_seed)
    except Exception:
        srv.stop()
        raise
    return srv, link.start()
