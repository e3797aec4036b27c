"""A radio link between the bundled vehicle and a companion: latency, jitter, loss and blackouts,
per direction, deterministic under the seed.

``sim: {link: {...}}`` in a mission or an experiment, or ``mavadrc sitl --link-*``::

    link:
      down: {latency_s: 0.02, jitter_s: 0.01, loss: 0.05}   # vehicle -> companion (samples)
      up: {latency_s: 0.02, loss: 0.01}                      # companion -> vehicle (setpoints)
      blackouts: [[12.0, 2.0]]                               # [start, duration] s of vehicle time

Each datagram on its way is delayed by ``latency_s`` plus a uniform draw in [0, ``jitter_s``],
lost with probability ``loss``, and lost during a blackout (both directions).

The same decisions serve every path.  In real time the vehicle's server delays and drops
datagrams on the wall clock.  In lockstep and on the in-process fast path, time moves in control
periods: the sample of period k reaches the companion ``down(k)`` periods later (or never), the
setpoint of period k reaches the vehicle ``up(k)`` periods later (or never), and at each period
the companion gets the newest sample that has arrived and is newer than the last it got (at most
one: what a companion stepping once per sample does), and the vehicle applies the newest
setpoint that has arrived.  The draws are made period by period in a fixed order (loss then
delay, down then up), whether or not a draw matters, so both paths meet the same link for the
same seed.
"""

import math
from dataclasses import dataclass, field

import numpy as np

#: a period whose sample (or setpoint) never arrives
LOST = -1

#: s of vehicle time from which, in lockstep and on the in-process fast path, the control
#: samples and setpoints pass through the link model: after the arming handshake (whose
#: commands a lossy link would make depend on wall-clock retries), before the motors start
LINK_FROM = 2.0


@dataclass
class Way:
    """One direction of the link."""

    latency_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0

    def __post_init__(self):
        for name in ("latency_s", "jitter_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 5.0):
                raise ValueError(f"{name} must be in [0, 5] s (got {v!r})")
        if not (math.isfinite(self.loss) and 0.0 <= self.loss <= 1.0):
            raise ValueError(f"loss must be in [0, 1] (got {self.loss!r})")

    @property
    def perfect(self):
        return self.latency_s == 0.0 and self.jitter_s == 0.0 and self.loss == 0.0


@dataclass
class LinkModel:
    down: Way = field(default_factory=Way)  # vehicle -> companion
    up: Way = field(default_factory=Way)  # companion -> vehicle
    blackouts: tuple = ()  # ((start_s, duration_s), ...) of vehicle time, both directions

    def __post_init__(self):
        spans = []
        for b in self.blackouts:
            start, duration = (float(v) for v in b)
            if not (math.isfinite(start) and start >= 0.0 and math.isfinite(duration)
                    and duration > 0.0):
                raise ValueError(f"a blackout is [start >= 0, duration > 0] s (got {b!r})")
            spans.append((start, duration))
        self.blackouts = tuple(spans)

    @property
    def perfect(self):
        return self.down.perfect and self.up.perfect and not self.blackouts

    def dark(self, t):
        """Whether vehicle time ``t`` falls in a blackout."""
        return any(s <= t < s + d for s, d in self.blackouts)

    def schedule(self, seed, period, t0=0.0):
        """The link's decisions, period by period, for ``seed`` and a control ``period`` (s),
        period 0 at vehicle time ``t0``."""
        return LinkSchedule(self, seed, period, t0)

    def as_dict(self):
        return {"down": vars(self.down).copy(), "up": vars(self.up).copy(),
                "blackouts": [list(b) for b in self.blackouts]}


def link_from_section(sec):
    """A :class:`LinkModel` from a ``link:`` YAML section (:class:`sim.yamlio.Section`)."""
    ways = {}
    for name in ("down", "up"):
        if sec.has(name):
            w = sec.section(name)
            ways[name] = Way(latency_s=w.number("latency_s", 0.0, ge=0.0, le=5.0),
                             jitter_s=w.number("jitter_s", 0.0, ge=0.0, le=5.0),
                             loss=w.number("loss", 0.0, ge=0.0, le=1.0))
            w.finish()
    blackouts = []
    if sec.has("blackouts"):
        raw = sec.raw("blackouts")
        if not isinstance(raw, list):
            sec.error("blackouts", "must be a list of [start_s, duration_s]")
        for i, b in enumerate(raw):
            ok = (isinstance(b, list) and len(b) == 2
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in b)
                  and b[0] >= 0 and b[1] > 0)
            if not ok:
                sec.error("blackouts", f"item {i} must be [start_s >= 0, duration_s > 0] "
                                       f"(got {b!r})")
            blackouts.append((float(b[0]), float(b[1])))
    sec.finish()
    return LinkModel(ways.get("down", Way()), ways.get("up", Way()), tuple(blackouts))


class LinkSchedule:
    """Per control period k: how many periods the sample of period k takes to reach the
    companion, and the setpoint of period k to reach the vehicle (:data:`LOST`: never).

    ``t0`` is the vehicle time of period 0 and ``period`` its length; blackouts are judged at
    the period's time.  Draws are made lazily but in period order, four uniforms a period."""

    def __init__(self, model, seed, period, t0=0.0):
        self.model = model
        self.period = float(period)
        self.t0 = float(t0)
        self._rng = np.random.default_rng(seed)
        self._down = []
        self._up = []

    def _draw(self, k):
        m = self.model
        while len(self._down) <= k:
            j = len(self._down)
            t = self.t0 + j * self.period
            u = self._rng.random(4)
            dark = m.dark(t)
            self._down.append(self._delay(m.down, u[0], u[1], dark))
            self._up.append(self._delay(m.up, u[2], u[3], dark))

    def _delay(self, way, u_loss, u_jitter, dark):
        if dark or u_loss < way.loss:
            return LOST
        seconds = way.latency_s + u_jitter * way.jitter_s
        return int(math.ceil(seconds / self.period - 1e-9))

    def down(self, k):
        self._draw(k)
        return self._down[k]

    def up(self, k):
        self._draw(k)
        return self._up[k]

    def arrays(self, n):
        """(down, up) delays of periods 0..n-1 as int64 arrays (for compiled loops)."""
        if n > 0:
            self._draw(n - 1)
        return (np.asarray(self._down[:n], dtype=np.int64),
                np.asarray(self._up[:n], dtype=np.int64))


class Delivery:
    """The companion's side of the discrete link: which sample it gets at each period.

    ``arrive(k, delay)`` files the sample of period k; ``take(k)`` returns the newest period
    whose sample has arrived by period k and is newer than the last one taken, or None."""

    def __init__(self):
        self._pending = []  # (arrival period, sample period)
        self._last = -1

    def arrive(self, k, delay):
        if delay != LOST:
            self._pending.append((k + delay, k))

    def take(self, k):
        due = [s for a, s in self._pending if a <= k and s > self._last]
        self._pending = [(a, s) for a, s in self._pending if a > k and s > self._last]
        if not due:
            return None
        self._last = max(due)
        self._pending = [(a, s) for a, s in self._pending if s > self._last]
        return self._last


class PeriodLink:
    """The link between a companion that answers each sample with one setpoint and a vehicle
    whose clock moves in control periods (lockstep, the in-process fast path), period by period.

    Period 0 is at vehicle time ``t0`` (:data:`LINK_FROM`); its sample goes out before the link
    model applies, and the setpoints made before it have all arrived.  At each period ``k``, in this order:

    * :meth:`sample` files the sample taken at period k and returns the period of the sample the
      companion gets now (the newest arrived one newer than the last it got), or None;
    * :meth:`answered` files the setpoint the companion made at period k (only when it got a
      sample then);
    * :meth:`applied` returns the period of the setpoint the vehicle applies from now on (the
      newest arrived one newer than the last it applied), or None to keep the last.

    Both paths call exactly these, so they meet the same link for the same seed."""

    def __init__(self, model, seed, period, t0=0.0):
        self.schedule = model.schedule(seed, period, t0)
        self._samples = Delivery()
        self._setpoints = Delivery()
        self._samples._last = 0  # the arming sample was delivered on a perfect link
        self.k = 0
        self.samples_lost = 0
        self.setpoints_lost = 0

    def sample(self, k):
        self.k = k
        if k == 0:
            return 0
        delay = self.schedule.down(k)
        if delay == LOST:
            self.samples_lost += 1
        self._samples.arrive(k, delay)
        return self._samples.take(k)

    def answered(self, k):
        delay = self.schedule.up(k)
        if delay == LOST:
            self.setpoints_lost += 1
        self._setpoints.arrive(k, delay)

    def applied(self, k):
        return self._setpoints.take(k)

    def arrays(self, n, answers=None):
        """(delivered, applied): per period 0..n-1, the sample period the companion gets and
        the setpoint period the vehicle applies (-1: none), for a companion that answers every
        sample it gets (or, ``answers(k, sample_period)`` False, stops answering)."""
        delivered = np.full(n, -1, dtype=np.int64)
        applied = np.full(n, -1, dtype=np.int64)
        for k in range(n):
            s = self.sample(k)
            if s is not None:
                delivered[k] = s
                if answers is None or answers(k, s):
                    self.answered(k)
            a = self.applied(k)
            if a is not None:
                applied[k] = a
        return delivered, applied
