"""The wire as the lossy link sees it: MAVLink frames cut out of a datagram byte-exact, decoded
only when a fault needs their fields, and packed again as their sender packed them."""

import os
import struct

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink loads a dialect: speak MAVLink 2

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

LPN = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
DIRECTIONS = ("down", "up")
_V2, _V1 = 0xFD, 0xFE
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN = 13


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


def named_directions(direction):
    """The directions ``direction`` names (``"both"``: down and up)."""
    if direction == "both":
        return DIRECTIONS
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be 'down', 'up' or 'both', not {direction!r}")
    return (direction,)


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


def snapshot(msg):
    """What a hook could change in ``msg``: its class and its fields' values."""
    return type(msg), repr([getattr(msg, f, None) for f in msg.get_fieldnames()])
