"""What a flight knows, kept in small objects its phases are handed: the vehicle as its
telemetry shows it (:class:`Vehicle`), the phase and when it began (:class:`PhaseClock`), the
mission's frame and progress (:class:`Progress`), and a condition's duration (:class:`Held`)."""

import time
from dataclasses import dataclass, field

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


@dataclass
class PhaseClock:
    """The flight's phase ("connect", "setup", "measure", "mode", "arming", "spoolup",
    "mission", "touchdown", "cut", "disarming", "failsafe", "done"), the vehicle time it began
    at (``t0``, None before a sample) and the wall time (``wall``)."""

    phase: str = "connect"
    t0: float | None = None
    wall: float = field(default_factory=time.monotonic)

    def enter(self, phase, s):
        self.phase = phase
        self.t0 = s.t if s is not None else None
        self.wall = time.monotonic()


@dataclass
class Vehicle:
    """The vehicle flown, as its telemetry and its answers show it: the latest sample and
    attitude, its land detector, who it is (``identity``, ``seq``: the autopilot's
    :class:`~mavadrc.mavlink.sequence.Sequence`, known once connected), where each figure the
    flight uses came from (``sources``), the streams asked, and whether it is taken over."""

    takeover: bool = False
    bundled: bool | None = None  # None: find out from AUTOPILOT_VERSION
    seq: object = None
    identity: dict = field(default_factory=dict)
    sources: dict = field(default_factory=dict)
    streams: dict = field(default_factory=dict)
    takeover_in_air: bool = False
    motor_delay: float = 0.0
    last: object = None  # latest accepted Sample
    yaw: float = 0.0
    cos_tilt: float = 1.0
    attitude_ms: int | None = None  # the newest ATTITUDE's time_boot_ms
    landed_state: int | None = None
    landed_state_wall: float | None = None
    air_said: bool = False  # the autopilot said IN_AIR during the mission
    samples_seen: int = 0  # accepted samples, every phase
    last_sample_wall: float | None = None
    # lockstep: when we were done with the last sample (work after its setpoint, such as the
    # identification's fit, holds the vehicle, which waits for the next setpoint)
    handled_wall: float = 0.0
    in_control_seen: bool = False  # the mode that takes setpoints confirmed once


@dataclass
class Progress:
    """The mission's frame and how far it has got: the takeoff spot (``origin``), the
    trajectory and its segments (``phases``: (start s, name)), the vehicle time the mission
    clock started at (``t0``; it moves on while a takeoff waits), the lift-off, and how it
    ended."""

    m: object  # the mission flown
    origin: object = None  # the takeoff spot (NED), set in the measure phase
    origin_moved_m: float | None = None  # how far the estimate moved on the ground before
    traj: object = None
    phases: list = field(default_factory=list)
    t0: float | None = None  # vehicle time of mission time 0
    start: float | None = None  # the mission's start as summary.json says it
    lifted: bool = False
    waiting: bool = False  # this sample's reference waits for the lift-off
    steps: int = 0
    descent_from: object = None  # where the final descent past the mission's end starts
    final_yaw: float = 0.0
    land_wall: float | None = None  # wall clock the final land segment began at
    handed_over: bool = False  # the mission ended in the air, as planned
    touchdown_seen: bool = False
    disarm_confirmed: bool = False

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


@dataclass
class Tracks:
    """Measures set beside the flight's estimate: a simulator's true state (``truth``, a
    :class:`~mavadrc.flight.truth.TruthTrack` once asked for) and a downward range finder."""

    truth: object = None
    rangefinder: RangeTrack = field(default_factory=RangeTrack)


def vehicle_mode(link, custom_mode=None):
    """The name of the vehicle's mode (``custom_mode``, or its latest heartbeat's)."""
    if custom_mode is None:
        custom_mode = link.custom_mode
    if custom_mode is None:
        return "unknown mode"
    return mode_name(link.autopilot, custom_mode)
