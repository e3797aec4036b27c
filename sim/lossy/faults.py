"""The faults the lossy link holds for a while: drop rules, blackout windows, field corruptions,
and the reference points (the start, a mark) they count from."""

from .frames import msg_name


class Ref:
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
