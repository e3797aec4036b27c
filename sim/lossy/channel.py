"""One direction of the lossy link: its faults (loss, latency, jitter), the random streams they
draw from, and what it saw."""

import random
from collections import Counter, namedtuple
from dataclasses import dataclass, field

#: one dropped frame: t (s since the proxy started), direction, message type, reason, seq
#: (None for an unparsed chunk)
Drop = namedtuple("Drop", "t direction type reason seq")
#: one modified frame: t, direction, type, seq, what ("fields x,y", "hook")
Modification = namedtuple("Modification", "t direction type seq what")


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
