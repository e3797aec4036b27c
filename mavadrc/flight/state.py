"""What a flight knows, kept in small objects its phases are handed: the vehicle as its
telemetry shows it (:class:`Vehicle`), the phase and when it began (:class:`PhaseClock`), the
mission's frame and progress (:class:`Progress`), and a condition's duration (:class:`Held`)."""

import time

from mavadrc.flight.rangefinder import RangeTrack
from mavadrc.mavlink.sequence import mode_name


class Held:
    """Whether a condition seen at each step has held a while (vehicle time, s)."""

    __slots__ = ("since",)

    def __init__(self):
        self.since = None

    def held(self, condition, now, seconds):
        """``condition`` now, at vehicle time ``now``: whether it has held ``seconds`` (false
        starts the count again)."""
        if not condition:
            self.since = None
            return False
        if self.since is None:
            self.since = now
        return now - self.since >= seconds


class PhaseClock:
    """The flight's phase ("connect", "setup", "measure", "mode", "arming", "spoolup",
    "mission", "touchdown", "cut", "disarming", "failsafe", "done"), the vehicle time it began
    at (``t0``, None before a sample) and the wall time (``wall``)."""

    def __init__(self):
        self.phase = "connect"
        self.t0 = None
        self.wall = time.monotonic()

    def enter(self, phase, s):
        self.phase = phase
        self.t0 = s.t if s is not None else None
        self.wall = time.monotonic()


class Vehicle:
    """The vehicle flown, as its telemetry and its answers show it: the latest sample and
    attitude, its land detector, who it is (``identity``, ``seq``: the autopilot's
    :class:`~mavadrc.mavlink.sequence.Sequence`, known once connected), where each figure the
    flight uses came from (``sources``), the streams asked, and whether it is taken over."""

    def __init__(self, takeover, bundled):
        self.seq = None
        self.identity = {}
        self.sources = {}
        self.streams = {}
        self.takeover = takeover
        self.takeover_in_air = False
        self.bundled = bundled  # None: find out from AUTOPILOT_VERSION
        self.motor_delay = 0.0
        self.last = None  # latest accepted Sample
        self.yaw = 0.0
        self.cos_tilt = 1.0
        self.attitude_ms = None  # the newest ATTITUDE's time_boot_ms
        self.landed_state = None
        self.landed_state_wall = None
        self.air_said = False  # the autopilot said IN_AIR during the mission
        self.samples_seen = 0  # accepted samples, every phase
        self.last_sample_wall = None
        # lockstep: when we were done with the last sample (work after its setpoint, such as
        # the identification's fit, holds the vehicle, which waits for the next setpoint)
        self.handled_wall = 0.0
        self.in_control_seen = False  # the mode that takes setpoints confirmed once


class Progress:
    """The mission's frame and how far it has got: the takeoff spot (``origin``), the
    trajectory and its segments (``phases``: (start s, name)), the vehicle time the mission
    clock started at (``t0``; it moves on while a takeoff waits), the lift-off, and how it
    ended."""

    def __init__(self, mission):
        self.m = mission
        self.origin = None
        self.origin_moved_m = None  # how far the estimate moved on the ground before the mission
        self.traj = None
        self.phases = []
        self.t0 = None  # vehicle time of mission time 0
        self.start = None  # the mission's start as summary.json says it (the same, once set)
        self.lifted = False
        self.waiting = False  # this sample's reference waits for the lift-off
        self.steps = 0
        self.descent_from = None  # where the final descent past the mission's end starts
        self.final_yaw = 0.0
        self.land_wall = None  # wall clock the final land segment began at
        self.handed_over = False  # the mission ended in the air, as planned
        self.touchdown_seen = False
        self.disarm_confirmed = False

    def in_final_land(self, t):
        """Whether mission time ``t`` is in the mission's closing land segment."""
        return (self.m.ends_landed and bool(self.phases) and self.phases[-1][1] == "land"
                and t >= self.phases[-1][0])

    def airborne(self, t):
        """After lift-off and before the mission's final land segment (mission time ``t``)."""
        return self.lifted and not self.in_final_land(t)

    def segment_name(self, t):
        name = self.phases[0][1] if self.phases else ""
        for t0, n in self.phases:
            if t >= t0:
                name = n
        return name

    def height(self, s):
        """Sample ``s``'s height above the takeoff spot (m)."""
        return float(self.origin[2] - s.pos[2])


def vehicle_mode(link, custom_mode=None):
    """The name of the vehicle's mode (``custom_mode``, or its latest heartbeat's)."""
    if custom_mode is None:
        custom_mode = link.custom_mode
    if custom_mode is None:
        return "unknown mode"
    return mode_name(link.autopilot, custom_mode)


class Tracks:
    """Measures set beside the flight's estimate: a simulator's true state (``truth``, a
    :class:`~mavadrc.flight.truth.TruthTrack` once asked for) and a downward range finder."""

    def __init__(self):
        self.truth = None
        self.rangefinder = RangeTrack()
