"""A link model (:class:`sim.link_model.LinkModel`) applied on the wall clock to the datagrams of
one link of the real-time server.

Each datagram the vehicle sends (down) and each one it receives (up) is lost with the
direction's probability or delayed by its latency plus a uniform draw in [0, jitter]; a
datagram held back waits in a queue with its due wall time and is delivered from the server's
select loop (:meth:`RealtimeLink.next_due` bounds the select timeout).  Blackouts are in vehicle
time: a datagram is cut when it would leave, or arrive, inside one, both ways.  Outgoing
datagrams also wait for their bytes to leave a bandwidth-limited line (the ``delay`` the link
passes on, :mod:`sim.mavlink.bandwidth`).

The draws come from generators of their own, one per link and direction, seeded from the
server's seed: enabling a link model changes no wind or sensor-noise draw, and the same
sequence of datagrams meets the same decisions.  Two uniforms are drawn per datagram (loss,
then jitter) whether or not they matter.  In lockstep nothing here runs: the lockstep path
consults the model in vehicle time.
"""

import heapq
import itertools
import time

import numpy as np

from ..link_model import LinkModel

#: tags the link model's generators apart from the vehicle's (wind, noise) ones
RNG_TAG = 0x4C494E4B  # "LINK"


class RealtimeLink:
    """Applies ``model`` to :class:`sim.mavlink.link.Link` ``link`` (the ``index``-th of its
    server) for ``seed``; ``vehicle_time()`` is the vehicle's clock (s), ``deliver(link, data,
    addr)`` hands a received datagram on, ``stats`` counts (:class:`sim.mavlink.link.Stats`)."""

    def __init__(self, link, model, seed, index, stats, vehicle_time, deliver,
                 wall=time.monotonic):
        self.link = link
        self.model = model if model is not None else LinkModel()
        self.stats = stats
        self.vehicle_time = vehicle_time
        self.deliver = deliver
        self.wall = wall
        base = [int(seed) & 0xFFFFFFFF, RNG_TAG, int(index)]
        self._rng = {"down": np.random.default_rng(base + [0]),
                     "up": np.random.default_rng(base + [1])}
        self._out = []  # (due wall time, n, datagram, peer)
        self._in = []  # (due wall time, n, datagram, sender)
        self._n = itertools.count()
        link.transmit = self.send
        link.inbound = self.receive

    def _decide(self, way, extra=0.0):
        """'dark', 'lost' or the delay (s) for one datagram going ``way``."""
        u_loss, u_jitter = self._rng[way].random(2)
        if self.model.dark(self.vehicle_time()):
            return "dark"
        w = getattr(self.model, way)
        if u_loss < w.loss:
            return "lost"
        return extra + w.latency_s + u_jitter * w.jitter_s

    def _count(self, what, way):
        key = f"link_{what}_{way}"
        setattr(self.stats, key, getattr(self.stats, key) + 1)

    def send(self, buf, peer, delay=0.0):
        """The link's transmit: ``buf`` to ``peer`` after ``delay`` s (the line's), and the
        model's."""
        d = self._decide("down", delay)
        if isinstance(d, str):
            return self._count(d, "down")
        if d <= 0.0:
            return self._sendto(buf, peer)
        self._count("delayed", "down")
        heapq.heappush(self._out, (self.wall() + d, next(self._n), bytes(buf), peer))

    def receive(self, data, addr):
        """A datagram just read from the link's socket: delivered now, queued or dropped."""
        d = self._decide("up")
        if isinstance(d, str):
            return self._count(d, "up")
        if d <= 0.0:
            return self.deliver(self.link, data, addr)
        self._count("delayed", "up")
        heapq.heappush(self._in, (self.wall() + d, next(self._n), data, addr))

    def next_due(self):
        """Wall time of the next queued datagram (inf: none)."""
        return min(self._out[0][0] if self._out else float("inf"),
                   self._in[0][0] if self._in else float("inf"))

    def release(self, now=None):
        """Deliver every queued datagram due by ``now``; one that would arrive in a blackout is
        cut."""
        now = self.wall() if now is None else now
        while self._out and self._out[0][0] <= now:
            _, _, buf, peer = heapq.heappop(self._out)
            if self.model.dark(self.vehicle_time()):
                self._count("dark", "down")
            else:
                self._sendto(buf, peer)
        while self._in and self._in[0][0] <= now:
            _, _, data, addr = heapq.heappop(self._in)
            if self.model.dark(self.vehicle_time()):
                self._count("dark", "up")
            else:
                self.deliver(self.link, data, addr)

    def _sendto(self, buf, peer):
        try:
            self.link.sock.sendto(buf, peer)
        except OSError:
            pass
