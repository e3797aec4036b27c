"""The flight's supervisor: checks turned into actions, apart from the phases that fly.

Modelled on PX4's commander failsafe framework: each check raises a condition; a fixed table says
which action the condition calls for; the actions are ordered by severity and a flight only
ever escalates (a landing is never turned back into a hold).  Every condition is kept, in order,
as a reason the flight ended early (``summary.json``'s ``aborted``).

===================  ================  =============================================
condition            action            why
===================  ================  =============================================
left_control         watch             the pilot or a failsafe took the vehicle: do not
                                       fight it, watch it land
interrupted          hold, then land   Ctrl-C: stop where it is, then come down
link                 hold, then land   loss or a gap past ``safety`` limits
stale                land              no telemetry: we cannot fly what we cannot see
breach               land              geofence, altitude or speed limit
ground               land              on the ground mid-mission (the autopilot says so,
                                       or the ground carries the vehicle's weight): the
                                       height estimate is off (or a collision)
clearance            land              a downward range finder reads the vehicle under
                                       ``min_clearance`` where its height estimate
                                       reads it 0.3 m higher: the estimate is off and
                                       the ground is near
tracking             hold, then land   the vehicle held ``max_tracking_error`` from the
                                       reference: it is not following (caught, pinned,
                                       a wind past its authority): stop chasing it
timeout              land              ``--timeout`` passed
exception            land              an error in the companion itself
touchdown_timeout    land              touchdown not seen in its bound
disarm_timeout       land              the autopilot would not disarm in its bound
refused              land              the autopilot refused what the flight needs
tipped               continue          at touchdown the autopilot's attitude tilted past
                                       45 deg: on its side, not landed (the thrust is
                                       being cut already; recorded, the flight ends as it
                                       does)
landing_timeout      give up           the autopilot has not landed in its bound
unreachable          give up           no heartbeat: nothing more can be done
===================  ================  =============================================
"""

import math

from mavadrc.mavlink.samples import missed_text

CONTINUE, WATCH, HOLD_THEN_LAND, LAND, GIVE_UP = range(5)
ACTION_NAMES = {CONTINUE: "continue", WATCH: "watch", HOLD_THEN_LAND: "hold, then land",
                LAND: "land", GIVE_UP: "give up"}

RULES = {
    "left_control": WATCH,
    "interrupted": HOLD_THEN_LAND,
    "link": HOLD_THEN_LAND,
    "stale": LAND,
    "breach": LAND,
    "ground": LAND,
    "clearance": LAND,
    "tracking": HOLD_THEN_LAND,
    "timeout": LAND,
    "exception": LAND,
    "touchdown_timeout": LAND,
    "disarm_timeout": LAND,
    "refused": LAND,
    "tipped": CONTINUE,
    "landing_timeout": GIVE_UP,
    "unreachable": GIVE_UP,
}


class Supervisor:
    """Keeps the reasons and the action in force; the checks are pure functions of what the
    flight sees."""

    def __init__(self, safety, telemetry_timeout):
        self.sf = safety
        self.telemetry_timeout = telemetry_timeout
        self.reasons = []  # every condition's message, in order
        self.conditions = []
        self.action = CONTINUE

    def report(self, condition, message):
        """Record a condition; returns the action to take now if it escalates, else None."""
        action = RULES[condition]
        if message not in self.reasons:
            self.reasons.append(message)
            self.conditions.append(condition)
        if action > self.action:
            self.action = action
            return action
        return None

    # --- checks: what is wrong (None when nothing is) ---------------------------------------------

    def breach(self, s, origin):
        """The geofence, altitude or speed limit ``s`` breaks (relative to ``origin``)."""
        sf = self.sf
        north, east, down = (s.pos - origin).tolist()
        alt = -down
        vn, ve, vd = s.vel.tolist()
        speed = math.sqrt(vn * vn + ve * ve + vd * vd)
        if not sf.geofence_north[0] <= north <= sf.geofence_north[1] or \
                not sf.geofence_east[0] <= east <= sf.geofence_east[1]:
            return f"geofence breach at north {north:.1f} m, east {east:.1f} m"
        if alt > sf.altitude_max or alt < sf.altitude_min:
            return f"altitude limit breach at {alt:.1f} m"
        if speed > sf.max_speed:
            return f"speed limit breach at {speed:.1f} m/s"
        return None

    def stale(self, now, last_sample_wall, answered_wall):
        """Telemetry stale past the timeout: counted from the last sample, or from when we were
        done answering it if that took long (a lockstep vehicle cannot move on before our
        answer, nor, in our loop, be heard while we still work on the last one)."""
        quiet = now - max(last_sample_wall, answered_wall)
        if quiet > self.telemetry_timeout:
            return f"telemetry lost ({quiet:.2f} s without a sample)"
        return None

    def link(self, gate):
        """Sample loss over the last seconds, or a gap, past the mission's limits."""
        loss = gate.recent_loss()
        if loss > self.sf.max_sample_loss:
            return (f"link: {missed_text(loss, gate.recent_out_of_order())} over the last "
                    f"seconds (limit {100 * self.sf.max_sample_loss:.0f} % missed)")
        if gate.longest_gap > self.sf.max_gap_s:
            return (f"link: a {gate.longest_gap:.2f} s gap between samples "
                    f"(limit {self.sf.max_gap_s:.2f} s)")
        return None

    @staticmethod
    def link_warning(gate):
        """Worth a warning, not an ending: loss past 2 %, or a gap past 3 periods."""
        loss = gate.recent_loss()
        if loss > 0.02:
            return missed_text(loss, gate.recent_out_of_order())
        if gate.intervals and gate.intervals[-1] > 3.0 * gate.period:
            return f"a {gate.intervals[-1]:.3f} s gap between samples"
        return None
