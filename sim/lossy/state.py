"""What the lossy link has done: its start, the drops and modifications of each direction, the
faults it refused, and a snapshot of its counters."""

import logging
from collections import Counter

from .channel import Drop, Modification
from .frames import msg_name

log = logging.getLogger("mavadrc.lossy")


class LinkState:
    """The record of a link's two channels.  Its writers (the judgement, the transport) and
    its readers hold the link's lock."""

    def __init__(self, down, up):
        self.channels = {"down": down, "up": up}
        self.errors = []  # faults refused, hooks and predicates that raised
        self.start_t = None  # monotonic time of the start: records carry t relative to it

    def drop(self, ch, frames, reason, t, datagram=True):
        """``frames`` of ``ch`` dropped at monotonic time ``t`` for ``reason`` (with their
        datagram unless ``datagram`` is false: frames dropped one by one)."""
        s = ch.stats
        rel = t - self.start_t
        for f in frames:
            s.frames_dropped[reason] += 1
            s.drops.append(Drop(rel, ch.name, msg_name(f.msgid), reason, f.seq))
        if datagram:
            s.datagrams_dropped[reason] += 1

    def modified(self, ch, f, t):
        """The frame ``f`` of ``ch`` goes out changed (``f.new``, for ``f.what``)."""
        ch.stats.frames_modified += 1
        ch.stats.modifications.append(Modification(t - self.start_t, ch.name, f.new.get_type(),
                                                   f.seq, ",".join(f.what)))

    def error(self, text):
        log.warning("lossy link: %s", text)
        self.errors.append(text)

    def drops(self):
        """Every drop of both directions, in time order."""
        return sorted(self.channels["down"].stats.drops + self.channels["up"].stats.drops,
                      key=lambda d: d.t)

    def snapshot(self):
        """{"down": {...}, "up": {...}}: the counters (without the logs)."""
        out = {}
        for d, ch in self.channels.items():
            s = ch.stats
            out[d] = {k: (dict(v) if isinstance(v, Counter) else v)
                      for k, v in vars(s).items() if k not in ("drops", "modifications")}
        return out
