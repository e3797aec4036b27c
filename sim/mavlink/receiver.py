"""The receiving side of the bundled vehicle's links: each datagram read and parsed on its own
(:meth:`sim.mavlink.link.Link.parse`), each message for this vehicle handed to the one handler
of its type (PX4's mavlink_receiver, ArduPilot's GCS_MAVLINK::handle_message).

A message aimed at another system or component is counted and dropped; one without a handler
is dropped; an error in a handler is logged and counted, and never stops the vehicle.
"""

import logging

log = logging.getLogger("mavadrc.sitl")

#: messages passed on to the other links, as PX4's forwarding does: a companion's named values
#: reach a ground station, which can plot, e.g., the observers' disturbance estimates live
FORWARDED = ("NAMED_VALUE_FLOAT",)


class Receiver:
    """Receives on ``links`` for system ``sysid``; ``handlers`` is {message type: handler(link,
    msg)}; ``stats`` counts."""

    def __init__(self, links, sysid, stats, handlers):
        self.links = links
        self.sysid = sysid
        self.stats = stats
        self.handlers = dict(handlers)
        for t in FORWARDED:
            self.handlers[t] = self._forward

    def drain(self, link):
        """Read and handle every datagram waiting on ``link``."""
        while True:
            try:
                data, addr = link.sock.recvfrom(65535)
            except OSError:  # nothing more to read (or the socket is gone)
                return
            if link.inbound is not None:  # a link model decides when (and if) it arrives
                link.inbound(data, addr)
            else:
                self.datagram(link, data, addr)

    def datagram(self, link, data, addr):
        """Handle one datagram received on ``link`` from ``addr``."""
        self.stats.datagrams += 1
        link.learn(addr)
        for msg in link.parse(data, self.stats):
            try:
                self.handle(link, msg)
            except Exception:  # a message we cannot act on never stops the vehicle
                log.exception("error handling %s", msg.get_type())
                self.stats.count("handler_error")

    def handle(self, link, msg):
        handler = self.handlers.get(msg.get_type())
        if handler is None:
            return
        if hasattr(msg, "target_system") and not self._for_us(msg):
            return
        handler(link, msg)

    def _for_us(self, msg):
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        if ts not in (0, self.sysid) or tc not in (0, 1):
            self.stats.other_target += 1
            return False
        return True

    def _forward(self, link, msg):
        for other in self.links:
            if other is not link:
                other.mav.send(msg)
