"""When the lossy link's held faults apply: the drop rules, the blackouts and the corruptions it
was given, the marks they count from, and which of them are still waiting for their mark."""

import time
from collections import Counter

from .faults import Blackout, Corruption, Ref, Rule
from .frames import DIRECTIONS, LPN, mavlink, msg_id, msg_name, named_directions


class FaultSchedule:
    """The rules, blackouts and corruptions of a link, anchored to the references they name.

    Handed the link's two channels (whose forwarded counts the references and the blackouts
    after N samples read) and the link's lock, which its changes take and which the callers of
    :meth:`blacked` hold."""

    def __init__(self, down, up, lock):
        self.channels = {"down": down, "up": up}
        self.rules = []
        self.blackouts = []
        self.corruptions = []
        self.marks = {}
        self._pending = []  # blackouts and corruptions waiting for a mark of their ref_name
        self._lock = lock
        self._start_t = None

    # --- references ------------------------------------------------------------------------------

    def started(self, t):
        """The link started at monotonic time ``t``: anchor what counts from ``"start"``."""
        self._start_t = t
        self._resolve("start", Ref(t, {d: Counter() for d in DIRECTIONS}))

    def _counts(self):
        return {d: Counter(self.channels[d]._fwd) for d in DIRECTIONS}

    def mark(self, name):
        """Record the reference ``name``; returns its time since the start (s)."""
        if name in ("start", "now"):
            raise ValueError(f"{name!r} is a reserved reference")
        with self._lock:
            ref = Ref(time.monotonic(), self._counts())
            self.marks[name] = ref
            self._resolve(name, ref)
            return ref.t - (self._start_t if self._start_t is not None else ref.t)

    def _ref(self, after):
        """The reference ``after`` names if it has happened (None otherwise)."""
        if after == "now":
            return Ref(time.monotonic(), self._counts())
        if after == "start":
            return (Ref(self._start_t, {d: Counter() for d in DIRECTIONS})
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
        times = self.channels["down"]._lpn_times
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

    def blackout(self, start_s, duration_s, direction, after, after_lpn):
        """A new :class:`Blackout` (see :meth:`LossyLink.blackout`)."""
        if start_s < 0 or not duration_s >= 0:
            raise ValueError("a blackout starts at >= 0 s and lasts >= 0 s")
        b = Blackout(start_s, duration_s, named_directions(direction), after, int(after_lpn))
        with self._lock:
            self.blackouts.append(b)
            self._attach(b, after)
        return b

    def corrupt(self, msg_type, nth, fields, direction, after, count):
        """A new :class:`Corruption` (see :meth:`LossyLink.corrupt`)."""
        if nth < 1 or count < 1:
            raise ValueError("nth and count start at 1")
        (d,) = named_directions(direction)
        c = Corruption(d, msg_id(msg_type), nth, count, fields, after)
        cls = mavlink.mavlink_map.get(c.msgid)
        unknown = [f for f in c.fields if cls is None or f not in cls.fieldnames]
        if unknown:
            raise ValueError(f"{msg_name(c.msgid)} has no field {', '.join(unknown)}")
        with self._lock:
            self.corruptions.append(c)
            self._attach(c, after)
        return c

    def drop_messages(self, msg_type, p, direction, command, n, where, reason):
        """A new :class:`Rule` (see :meth:`LossyLink.drop_messages`)."""
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"p is a probability, not {p}")
        cls = mavlink.mavlink_map.get(msg_id(msg_type))
        if command is not None and (cls is None or "command" not in cls.fieldnames):
            raise ValueError(f"{msg_name(msg_id(msg_type))} has no command field")
        rule = Rule(named_directions(direction), msg_id(msg_type), command, p, n, where, reason)
        with self._lock:
            self.rules.append(rule)
        return rule

    def remove(self, item):
        """Lift a rule, blackout or corruption."""
        with self._lock:
            for lst in (self.rules, self.blackouts, self.corruptions, self._pending):
                if item in lst:
                    lst.remove(item)
            if isinstance(item, Rule):
                item.active = False

    def clear(self):
        """No rules, blackouts or corruptions."""
        with self._lock:
            for r in self.rules:
                r.active = False
            self.rules.clear()
            self.blackouts.clear()
            self.corruptions.clear()
            self._pending.clear()

    # --- the judgement's question ----------------------------------------------------------------

    def blacked(self, direction, t):
        """Whether a blackout holds ``direction`` at monotonic time ``t`` (the caller holds the
        lock)."""
        for b in self.blackouts:
            if direction not in b.directions:
                continue
            if b.anchor is None and b.lpn and b.ref is not None:
                self._lpn_anchor(b)
            w = b.window()
            if w is not None and w[0] <= t < w[1]:
                return True
        return False
