"""The autopilot's parameters: read and set, one at a time, and their values decoded."""

import struct
import time

from mavadrc.errors import LinkError
from mavadrc.mavlink.dialect import M


class Params:
    """Parameter reads and writes over ``transport`` (its ``mav`` sends) to the autopilot
    ``sources`` chose (its ``target_system`` and ``autopilot``), waiting on ``recv(timeout)``,
    which reads the link (and hands every PARAM_VALUE to :meth:`on_value`).

    PX4 sends an INT32 parameter's bits in the float field; ArduPilot sends its value."""

    def __init__(self, transport, sources, recv):
        self._transport = transport
        self._sources = sources
        self._recv = recv
        self.values = {}  # name -> the latest PARAM_VALUE

    def on_value(self, msg):
        self.values[msg.param_id] = msg

    def read(self, name, timeout=3.0, idle=None):
        target = self._sources.target_system
        return self._exchange(
            name, lambda: self._transport.mav.param_request_read_send(target, 1, name.encode(), -1),
            timeout, idle, "answer a read of")

    def set(self, name, value, ptype, timeout=3.0, idle=None):
        raw = float(value)
        if ptype == M.MAV_PARAM_TYPE_INT32 and self._px4:
            raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        target = self._sources.target_system
        return self._exchange(
            name, lambda: self._transport.mav.param_set_send(target, 1, name.encode(), raw, ptype),
            timeout, idle, "confirm setting")

    @property
    def _px4(self):
        return self._sources.autopilot == "px4"

    def _exchange(self, name, send, timeout, idle, what):
        """Send a parameter request until the PARAM_VALUE for ``name`` comes back (3 tries)."""
        for _ in range(3):
            self.values.pop(name, None)
            send()
            end = time.monotonic() + timeout / 3
            while time.monotonic() < end:
                self._recv(0.02)
                if idle is not None:
                    idle()
                if name in self.values:
                    return self.decode(self.values[name])
        raise LinkError(f"the vehicle did not {what} parameter {name}")

    def decode(self, pv):
        """A PARAM_VALUE's value (an int for PX4's INT32 parameters)."""
        if pv.param_type == M.MAV_PARAM_TYPE_INT32 and self._px4:
            return struct.unpack("<i", struct.pack("<f", pv.param_value))[0]
        return pv.param_value
