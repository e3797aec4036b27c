"""A link of limited bandwidth: the autopilot's telemetry port feeding a radio (a 57600-baud
SiK radio carries about 5.7 kB/s), modelled as a line that sends ``bytes_per_s`` behind a
transmit buffer of ``buffer_bytes``.

A frame put on the line leaves once the bytes ahead of it and its own have been sent; a frame
that does not fit in what the buffer has free is dropped (PX4's Mavlink::send_start counts a
transmit-buffer overrun).  The autopilots keep their streams from getting there, each its own
way (:attr:`sim.personality.Personality.bandwidth_throttle`):

Streams get half the line (:data:`STREAM_SHARE`), the rest is for commands' answers,
parameters and text:

- PX4 (Mavlink::update_rate_mult, mavlink_main.cpp): its data rate on a serial port is, unless
  MAV_x_RATE says otherwise, half the port's theoretical maximum (baudrate/20 bytes/s,
  module.yaml); every stream that is not of constant rate runs at its rate times one
  multiplier, (data rate - the constant-rate streams' bytes/s) /
  (the other streams' bytes/s at their configured rates), at most 1 (no flow control) and at
  least 0.05 (so that something is always sent); each stream's bytes are its frames' average
  size.  The rest of the link stays free for commands, acks and parameters.
- ArduPilot (GCS_MAVLINK, CHECK_PAYLOAD_SIZE): a message for which the port has no room is not
  sent now and is tried again on a later pass (update_send stops at the first that does not
  fit); streams slow down to what the line carries, the most overdue going first.  Here the
  streams may fill half the port's buffer: on a real radio the radio's flow control
  (RADIO_STATUS txbuf -> stream_slowdown_ms) keeps the port from filling, and without it every
  COMMAND_ACK would find the port full.

The line's clock is the vehicle's (s): in real time it runs with the wall clock; in lockstep
the line still throttles and drops, but nothing is delayed on the wall clock.
"""

#: a stream's frame size before one has been measured (bytes)
DEFAULT_FRAME = 40
#: the share of a line (and of its buffer) the streams may take
STREAM_SHARE = 0.5
#: PX4: the floor of the rate multiplier
MIN_RATE_MULT = 0.05


class Line:
    """``bytes_per_s`` through a transmit buffer of ``buffer_bytes``."""

    def __init__(self, bytes_per_s, buffer_bytes):
        if not bytes_per_s > 0:
            raise ValueError(f"bandwidth must be > 0 bytes/s (got {bytes_per_s!r})")
        self.rate = float(bytes_per_s)
        self.buffer = int(buffer_bytes)
        self._free_at = 0.0  # when the line has sent everything it holds (s)
        self.sent_bytes = 0
        self.dropped = 0

    def backlog(self, now):
        """Bytes waiting in the buffer at time ``now``."""
        return max(0.0, self._free_at - now) * self.rate

    def room(self, now, n):
        """Whether ``n`` more bytes fit in the buffer now."""
        return self.backlog(now) + n <= self.buffer + 1e-9

    def put(self, now, n):
        """Queue ``n`` bytes at ``now``; the time (s from now) their last byte leaves, or None
        when the buffer cannot take them (dropped)."""
        if not self.room(now, n):
            self.dropped += 1
            return None
        self._free_at = max(now, self._free_at) + n / self.rate
        self.sent_bytes += n
        return self._free_at - now


def rate_mult(bytes_per_s, streams, const_bytes_per_s=0.0):
    """PX4's rate multiplier for a link of ``bytes_per_s``: ``streams`` is [(average frame size
    in bytes, configured interval in us)], ``const_bytes_per_s`` what the constant-rate streams
    (HEARTBEAT) take."""
    load = sum(size * 1e6 / us for size, us in streams if us)
    if load <= 0.0:
        return 1.0
    return min(1.0, max(MIN_RATE_MULT, (bytes_per_s - const_bytes_per_s) / load))
