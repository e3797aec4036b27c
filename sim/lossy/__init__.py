"""A lossy UDP link: a MAVLink-aware proxy between a vehicle and a companion.

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
    from sim.lossy import LossyLink
    from sitl_helpers import start_lossy_vehicle  # the tests' helper
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

from .channel import Channel, ChannelStats, Drop, Modification
from .faults import Blackout, Corruption, Rule
from .frames import DIRECTIONS, LPN, Frame, encode_like, msg_id, msg_name, split_frames
from .link import LossyLink, LossyLinkError

__all__ = ["DIRECTIONS", "LPN", "Blackout", "Channel", "ChannelStats", "Corruption", "Drop",
           "Frame", "LossyLink", "LossyLinkError", "Modification", "Rule", "encode_like",
           "msg_id", "msg_name", "split_frames"]
