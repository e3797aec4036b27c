"""The samples a control step runs on, taken in order, timed by the vehicle, and counted.

Every LOCAL_POSITION_NED passes the :class:`SampleGate`: one that is not newer than the last
accepted sample (a duplicate, or one that came out of order, behind a newer one) or that carries
a non-finite number is dropped and counted, never handed to the controller.  An accepted sample
carries the interval since the previous one, from the vehicle's ``time_boot_ms``.

Missing samples are counted against the period flown: over the vehicle time the samples span,
so many periods should have brought a sample; those that did not are missing.  Counting over
the span, not interval by interval, keeps an autopilot whose estimator ticks at another rate
honest: PX4 SIH's estimator ticks every 8 ms, so a 100 Hz stream carries samples 8 and 16 ms
apart, 10 ms on average, and none is missing.

A missing sample was lost (on the link, or never sent) or came out of order: a jittery link
delivers some samples behind newer ones, and those are dropped.  The two are told apart in what
is said (:func:`missed_text`): behind PX4 SIH through 20 ms of uniform jitter at 100 Hz, 12 % of
the samples came out of order where the link lost 5.6 %, and "17 % of the samples lost" had
blamed the link for all of it.
"""

import collections
import math
from dataclasses import dataclass

import numpy as np

#: the loss figure the supervisor watches covers this much vehicle time (s)
LOSS_WINDOW_S = 2.0


@dataclass
class Sample:
    t: float  # vehicle time (s): time_boot_ms / 1000
    pos: np.ndarray  # NED (m)
    vel: np.ndarray  # NED (m/s)
    dt: float = None  # s since the previous accepted sample (None: the first)
    age: float = None  # s from the vehicle taking it to our reading it (None: unknown)


class SampleGate:
    """Takes samples in order and counts what the link did to them.

    ``period`` is the interval the stream should have (s); samples missing between two accepted
    ones are counted against it (``missing``), and the longest interval is kept.  Counting
    starts again at :meth:`restart` (for instance once the requested rate is confirmed).
    """

    def __init__(self, period):
        self.period = float(period)
        self.last_ms = None
        self.late = 0  # older than the last accepted sample
        self.duplicate = 0  # the same time as the last accepted sample
        self.nonfinite = 0
        self.restart()

    def restart(self, period=None):
        """Count from the next sample on (at ``period`` if given)."""
        if period is not None:
            self.period = float(period)
        self.received = 0  # accepted since the restart
        self.longest_gap = 0.0
        self.first_t = None
        self.last_t = None
        self._recent = collections.deque()  # sample times over LOSS_WINDOW_S
        self.intervals = []
        self.out_of_order = 0  # came behind a newer sample since the restart (dropped)
        self._recent_out_of_order = collections.deque()  # their times, over LOSS_WINDOW_S

    def accept(self, time_boot_ms, pos, vel):
        """A :class:`Sample`, or None when the sample is dropped (counted by reason)."""
        ms = int(time_boot_ms)
        if self.last_ms is not None and ms <= self.last_ms:
            if ms == self.last_ms:
                self.duplicate += 1
            else:
                self.late += 1
                if self.first_t is not None and ms / 1000.0 >= self.first_t:
                    self.out_of_order += 1
                    self._recent_out_of_order.append(ms / 1000.0)
            return None
        if not all(math.isfinite(v) for v in (*pos, *vel)):
            self.nonfinite += 1
            return None
        dt = None if self.last_ms is None else (ms - self.last_ms) / 1000.0
        self.last_ms = ms
        t = ms / 1000.0
        if dt is not None and self.first_t is not None:
            self.longest_gap = max(self.longest_gap, dt)
            self.intervals.append(dt)
        if self.first_t is None:
            self.first_t = t
        self.last_t = t
        self.received += 1
        self._recent.append(t)
        while self._recent[0] < t - LOSS_WINDOW_S:
            self._recent.popleft()
        ooo = self._recent_out_of_order
        while ooo and ooo[0] < t - LOSS_WINDOW_S:
            ooo.popleft()
        return Sample(t, np.array(pos, dtype=float), np.array(vel, dtype=float), dt)

    def _expected(self, span):
        return int(round(span / self.period)) + 1

    @property
    def missing(self):
        """Periods since the restart that brought no sample."""
        return max(0, self._expected(self.span) - self.received) if self.received else 0

    @property
    def dropped(self):
        return self.late + self.duplicate + self.nonfinite

    @property
    def span(self):
        """Vehicle time covered by the samples since the restart (s)."""
        return 0.0 if self.first_t is None else self.last_t - self.first_t

    def loss(self):
        """Share of the expected samples that did not come, since the restart."""
        expected = self.received + self.missing
        return self.missing / expected if expected else 0.0

    def out_of_order_share(self):
        """Share of the expected samples, since the restart, that came out of order (behind a
        newer one) and were dropped: part of :meth:`loss`, never more."""
        expected = self.received + self.missing
        return min(self.out_of_order / expected, self.loss()) if expected else 0.0

    def recent_loss(self):
        """The same as :meth:`loss` over the last :data:`LOSS_WINDOW_S` of vehicle time (0
        until half a window has passed)."""
        if len(self._recent) < 2 or self.span < 0.5 * LOSS_WINDOW_S:
            return 0.0
        expected = self._expected(self._recent[-1] - self._recent[0])
        return max(0.0, 1.0 - len(self._recent) / expected)

    def recent_out_of_order(self):
        """The same as :meth:`out_of_order_share` over the last :data:`LOSS_WINDOW_S` of
        vehicle time: part of :meth:`recent_loss`, never more."""
        loss = self.recent_loss()
        if loss <= 0.0:
            return 0.0
        first = self._recent[0]
        n = sum(1 for t in self._recent_out_of_order if t >= first)
        return min(n / self._expected(self._recent[-1] - first), loss)

    def arrival_rate(self):
        """Samples per second of vehicle time that reached us since the restart, in order or
        not (:meth:`achieved_rate` counts those flown on)."""
        if self.span <= 0:
            return 0.0
        return (self.received + self.out_of_order - 1) / self.span

    def achieved_rate(self):
        """Samples per second of vehicle time flown on (reached us in order) since the
        restart."""
        return (self.received - 1) / self.span if self.span > 0 else 0.0

    def stream_period(self):
        """The interval the vehicle sends at: the median interval between samples."""
        return float(np.median(self.intervals)) if self.intervals else None

    def figures(self):
        """The link's figures for summary.json."""
        return {
            "samples_received": self.received,
            "samples_expected": self.received + self.missing,
            "missing": self.missing,
            "loss_fraction": self.loss(),
            "longest_gap_s": self.longest_gap,
            "achieved_rate_hz": self.achieved_rate(),
            "out_of_order_fraction": self.out_of_order_share(),
            "dropped_late": self.late,
            "dropped_duplicate": self.duplicate,
            "dropped_nonfinite": self.nonfinite,
        }


def missed_text(missed, out_of_order):
    """What a share ``missed`` of the samples not flown on was, ``out_of_order`` of them having
    come behind a newer one: "4.0 % of the samples lost", or "16.9 % of the samples missed:
    4.9 % lost, 12.0 % out of order (behind a newer one, dropped)"."""
    out_of_order = min(max(out_of_order, 0.0), missed)
    lost = missed - out_of_order
    if out_of_order < 0.0005:
        return f"{100 * missed:.1f} % of the samples lost"
    if lost < 0.0005:
        return (f"{100 * missed:.1f} % of the samples out of order (behind a newer one, "
                "dropped)")
    return (f"{100 * missed:.1f} % of the samples missed: {100 * lost:.1f} % lost, "
            f"{100 * out_of_order:.1f} % out of order (behind a newer one, dropped)")
