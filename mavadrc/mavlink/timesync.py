"""The vehicle's clock as the companion reads it: TIMESYNC requests sent, answers fitted, and the
vehicle's requests answered."""

import collections
import time


class TimeSync:
    """Round trip, clock offset and the vehicle clock's rate from TIMESYNC exchanges.

    A request carries our clock ``ts1`` (ns); the answer adds the vehicle's clock ``tc1`` (ns
    since its boot, the clock of ``time_boot_ms``).  The round trip is ``now - ts1``; the
    vehicle's clock read ``tc1`` about half a round trip before ``now``, so ``offset = tc1 -
    (ts1 + now)/2`` maps our clock onto the vehicle's at our time ``(ts1 + now)/2``, to within
    half the round trip.

    The vehicle's clock need not run at the rate of ours: a simulator's runs slow when its
    loop cannot keep up (PX4 SITL's, SIH, ran 1.35 % slow on 2 cores, 2026-12-03), and two
    crystals differ by tens of ppm.  So the offset is a line in our time: fitted through the
    exchanges of the last :attr:`WINDOW_S` whose round trip is near the shortest among them
    (within :attr:`RTT_SLACK` times it plus :attr:`RTT_SLACK_NS`: the least queued), and read
    where it is asked.  With fewer than :attr:`MIN_FIT` of them, or spanning under
    :attr:`MIN_SPAN_S`: the newest one's offset, at the rate last fitted (none before the
    first fit).  On a loaded machine one exchange with a short round trip can leave too few of
    the others near it; forgetting the rate then read a clock running 5 % slow as running at
    ours (a test's real-time flight on the 2 shared cores).  An exchange with a short round trip that
    lands more than :attr:`JUMP_NS` off the line says the vehicle's clock jumped (a reboot, a
    time reset): the exchanges before it are forgotten.
    """

    WINDOW_S = 6.0
    RTT_SLACK = 2.0
    RTT_SLACK_NS = 1_000_000
    MIN_FIT = 3
    MIN_SPAN_S = 1.0
    JUMP_NS = 50_000_000

    def __init__(self):
        self._pending = collections.deque(maxlen=16)
        self.rtts = []  # every round trip measured (s)
        self._recent = collections.deque()  # (our time at the exchange (ns), rtt_ns, offset_ns)
        self._line = None  # (t0_ns, offset at t0 (ns), skew): offset(t) = o0 + skew (t - t0)
        self.fitted = False  # whether the line is fitted (else: the newest exchange's offset)
        self._fitted_skew = 0.0  # the rate of the last line fitted, kept while none can be
        self.asked = 0  # requests sent
        self._asked_wall = 0.0  # time.monotonic() of the latest request (poll)

    def poll(self, now, send, period=1.0):
        """Send a TIMESYNC request through ``send(tc1, ts1)`` every ``period`` s (both PX4 and
        ArduPilot answer); every 0.25 s until the vehicle's clock is fitted, so that a clock
        that runs at another rate is followed within a second or two of the first answer (for
        16 requests at most: a vehicle that does not answer is asked once a second)."""
        if not self.fitted and self.asked < 16:
            period = min(period, 0.25)
        if now - self._asked_wall >= period:
            self._asked_wall = now
            ts1 = time.monotonic_ns()
            self.sent(ts1)
            send(0, ts1)

    def on_message(self, msg, send):
        """A TIMESYNC of the vehicle: its request is answered with our clock through
        ``send(tc1, ts1)``; its answer to ours is fitted."""
        if msg.tc1 == 0:  # the vehicle asks: answer with our clock
            send(time.monotonic_ns(), msg.ts1)
        else:
            self.answered(msg.tc1, msg.ts1, time.monotonic_ns())

    def sent(self, ts1):
        self._pending.append(ts1)
        self.asked += 1

    def answered(self, tc1, ts1, now):
        if ts1 not in self._pending:
            return  # not ours, or a late duplicate
        self._pending.remove(ts1)
        rtt = now - ts1
        if rtt < 0:
            return
        self.rtts.append(rtt * 1e-9)
        mid = (ts1 + now) // 2
        offset = tc1 - mid
        if self._line is not None and rtt <= self._good_rtt() \
                and abs(offset - self.offset_at(mid)) > self.JUMP_NS + rtt:
            self._recent.clear()  # the vehicle's clock jumped
        self._recent.append((mid, rtt, offset))
        while self._recent and mid - self._recent[0][0] > self.WINDOW_S * 1e9:
            self._recent.popleft()
        self._fit()

    def _good_rtt(self):
        return self.RTT_SLACK * min(r for _, r, _ in self._recent) + self.RTT_SLACK_NS

    def _fit(self):
        good = self._good_rtt()
        pts = [(t, o) for t, r, o in self._recent if r <= good]
        t_new, o_new = pts[-1]
        self.fitted = len(pts) >= self.MIN_FIT and t_new - pts[0][0] >= self.MIN_SPAN_S * 1e9
        if not self.fitted:
            self._line = (t_new, o_new, self._fitted_skew)
            return
        # least squares in seconds from the newest exchange (offsets in ns from its offset)
        t = [(ti - t_new) * 1e-9 for ti, _ in pts]
        o = [float(oi - o_new) for _, oi in pts]
        tm, om = sum(t) / len(t), sum(o) / len(o)
        skew_ns = sum((a - tm) * (b - om) for a, b in zip(t, o)) / \
            sum((a - tm) ** 2 for a in t)  # ns per s
        self._line = (t_new, o_new + int(round(om - skew_ns * tm)), skew_ns * 1e-9)
        self._fitted_skew = skew_ns * 1e-9

    @property
    def offset_ns(self):
        """The offset (ns) at the newest exchange (None before the first)."""
        return None if self._line is None else self._line[1]

    @property
    def skew(self):
        """How much faster the vehicle's clock runs than ours (-0.0135: 1.35 % slower; 0 until
        the exchanges span :attr:`MIN_SPAN_S`, then the last fitted while no line can be)."""
        return 0.0 if self._line is None else self._line[2]

    def offset_at(self, now_ns):
        t0, o0, skew = self._line
        return o0 + int(round(skew * (now_ns - t0)))

    def age(self, time_boot_ms, now_ns=None):
        """Seconds since the vehicle took a sample stamped ``time_boot_ms`` (None before the
        first exchange)."""
        if self._line is None:
            return None
        now_ns = time.monotonic_ns() if now_ns is None else now_ns
        return (now_ns + self.offset_at(now_ns) - time_boot_ms * 1_000_000) * 1e-9
