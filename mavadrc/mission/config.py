"""Missions: one YAML file says what to fly, with which controller, on what, in what wind.

    name: thesis spiral in wind
    vehicle: crazyflie              # a vehicle file; or {hover_thrust: 0.6} / {mass:, max_thrust:}
    controller:
      type: ladrc                   # adrc | ladrc | pd | pid | native (the autopilot's own)
      rate_hz: 100
      wc: [2.5, 2.5, 3.0]           # per axis (x, y, z) or one number
      wo: [12.5, 12.5, 15.0]
    trajectory:                     # positions are north, east, altitude (m) from the takeoff spot
      - takeoff: {altitude: 1.0, speed: 0.5}
      - spiral: {radius: 10, omega: 0.5, z0: 1.0, climb: 0.1, duration: 40, join: direct}
      - land: {speed: 0.5}
    wind: breeze_1ms                # the bundled vehicle only: a wind file or mapping
    safety: {geofence: {north: [-15, 15], east: [-15, 15]}, altitude: {max: 20}}

A bad file is refused before anything flies, with the file, line and field
(:class:`sim.yamlio.ConfigError`).
"""

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mavadrc.control.kernels import AGE_MAX
from mavadrc.control.learn import TAU_S as DRAG_LEARN_S
from mavadrc.control.position import DRAG_MAX, THRUST_ESTIMATE_S
from mavadrc.mission import trajectories as T
from mavadrc.mission import trajectory_file as TF
from mavadrc.mission.identification import ALTITUDE
from sim.sensors import CLOCK_RATES, WANDER_CORNER_HZ
from sim.yamlio import (ConfigError, Section, closest, config_path, described, did_you_mean,
                        load_yaml)

KINDS = ("adrc", "ladrc", "pd", "pid", "native")
#: what a controller's ``thrust_tilt`` may say (:class:`ControllerSpec`)
THRUST_TILTS = ("commanded", "measured")
#: what flies the takeoff of a flight that identifies its vehicle (``takeoff``): the safe
#: LADRC, or a PID on the measured velocity (mavadrc.design.gains.TAKEOFF_KIND)
TAKEOFFS = ("safe", "pid")
#: a land segment's last FINAL_HEIGHT metres go at most FINAL_SPEED (peak): an altitude
#: estimate a few tenths of a metre off (PX4 SIH's was 0.29-0.38 m) meets the ground slowly
FINAL_HEIGHT = 0.5
FINAL_SPEED = 0.3
SEGMENTS = ("takeoff", "hover", "circle", "spiral", "figure_eight", "lissajous", "waypoints", "file",
            "land", "named", "identify")


@dataclass
class ControllerSpec:
    kind: str = "ladrc"
    name: str = None
    rate_hz: float = 100.0
    gains: dict = field(default_factory=dict)  # keyword -> scalar or (x, y, z)
    tilt_max_deg: float = 35.0
    thrust_min: float = 0.05
    thrust_max: float = 1.0
    #: the tilt the thrust is sized for: the one commanded (its magnitude is the specific force
    #: asked for), or the one the vehicle reports now ("measured": its vertical part is the one
    #: asked for, whatever the attitude loop has reached; geometry.thrust_for_tilt)
    thrust_tilt: str = "commanded"
    #: what flies the takeoff before the identification (``input_lag: auto``): "safe", the safe
    #: default LADRC that flies the doublets, or "pid", a PID on the measured velocity, stiffer
    #: against the wind at the lift-off but misled by a velocity estimate that strays
    #: (docs/controllers.md)
    takeoff: str = "safe"


@dataclass
class Safety:
    geofence_north: tuple = (-50.0, 50.0)  # m from the takeoff spot
    geofence_east: tuple = (-50.0, 50.0)
    altitude_min: float = -1.0  # m above the takeoff spot (below it: breach)
    altitude_max: float = 50.0
    max_speed: float = 15.0  # m/s
    telemetry_timeout_s: float = 0.5
    set_guid_options: bool = False  # ArduPilot: set GUID_OPTIONS bit 3 if it is clear
    max_sample_loss: float = 0.5  # share of samples lost over the last 2 s that ends the flight
    max_gap_s: float = 0.5  # longest interval between samples before the flight ends (s)
    min_rate_hz: float = 20.0  # below this achieved sample rate the flight is refused
    max_touchdown_speed: float = 0.5  # m/s; a harder touchdown is no landing (exit 1)
    #: m from the reference, held TRACKING_LOST_S after lift-off, that ends the mission (the
    #: vehicle is not following: held where it is, then landed); 0: not checked
    max_tracking_error: float = 2.0
    #: m above the ground by a downward range finder, under which (the height estimate reading
    #: the vehicle 0.3 m higher, for 0.3 s) the mission ends in a landing; 0: not checked
    min_clearance: float = 0.5


@dataclass
class Mission:
    name: str
    source: str
    text: str
    segments: list  # [(kind, Section-read dict, line)]
    controller: ControllerSpec
    safety: Safety
    vehicle: str = None  # a bundled vehicle name or file
    hover_thrust: float = None
    hover_source: str = None  # where hover_thrust came from, for the console and the record
    sim_given: bool = False  # the file has a sim: section (the bundled vehicle's settings)
    mass: float = None
    max_thrust: float = None
    wind: object = None  # name, path or mapping (bundled vehicle only)
    seed: int = 0
    autopilot: str = "px4"  # personality of the bundled vehicle
    attitude_controller: str = "px4"  # the bundled vehicle's own inner loop
    noise: bool = False
    #: m: the bundled vehicle's position estimate wanders this much (RMS per axis, as PX4 SIH's
    #: EKF2 does: :class:`sim.sensors.Sensors`); 0: it does not
    wander: float = 0.0
    wander_corner_hz: float = WANDER_CORNER_HZ
    sensor_latency_s: float = 0.0  # age of the bundled vehicle's reported state (s)
    height_drift_mps: float = 0.0  # the bundled vehicle's height estimate drifts up (m/s)
    rangefinder: bool = False  # the bundled vehicle has a downward range finder (DISTANCE_SENSOR)
    #: m/s: after a flight, at rest on the ground, the bundled vehicle's estimate reads a climb
    #: (:attr:`sim.vehicle.SimVehicle.ground_climb_mps`)
    ground_climb_mps: float = 0.0
    #: in real time the bundled vehicle's clock runs at this share of the wall clock (MAVLink
    #: paths; ``mavadrc sitl --clock-rate``)
    clock_rate: float = 1.0
    link: object = None  # sim.link_model.LinkModel between the bundled vehicle and the companion
    #: the bundled vehicle against its file (``sim: {mass_scale, motor_thrust_curve,
    #: attitude_bandwidth_scale}``, :func:`sim.vehicle.vehicle_variant`): what the companion is
    #: told (hover thrust, ``input_lag: auto``) still comes from the file
    #: the observers' input model times this once identified (a robustness study's model error)
    input_model_scale: float = 1.0
    mass_scale: float = 1.0
    motor_thrust_curve: float = None
    attitude_bandwidth_scale: float = 1.0
    #: the bundled vehicle's initial heading (deg); NaN (``heading_deg: random``): drawn from
    #: the run's seed (:func:`sim.vehicle.initial_heading`), the same on both paths
    heading_deg: float = 0.0
    settle_s: float = 0.0  # errors are also reported after this mission time
    out: str = "runs"
    transit_speed: float = 1.0
    transit_accel: float = 2.0
    #: ``input_lag: auto`` resolved before flying (mavadrc.fast.identify.with_identified): the fit
    identification: dict = None

    def with_identification(self):
        """This mission with an ``identify`` segment (the doublets :mod:`mavadrc.design.identify`
        fits the input model on) right after its takeoff, unless it has one already; the
        settling time moves by the segment's duration."""
        import copy
        if any(kind == "identify" for kind, _, _ in self.segments):
            return self
        from mavadrc.mission.identification import doublets
        m = copy.copy(self)
        at = next((i + 1 for i, (kind, _, _) in enumerate(self.segments) if kind == "takeoff"),
                  0)
        m.segments = self.segments[:at] + [("identify", {}, None)] + self.segments[at:]
        if m.settle_s > 0.0:  # the mission's own timeline begins that much later
            m.settle_s += doublets(np.zeros(3)).duration
        return m

    @property
    def ends_landed(self):
        """Whether the trajectory ends with a land (else the autopilot lands after it)."""
        return bool(self.segments) and self.segments[-1][0] == "land"

    def build_trajectory(self, origin=(0.0, 0.0, 0.0), in_air=False):
        """The mission's reference as one trajectory, offset to ``origin`` (NED of the takeoff
        spot); returns (trajectory, [(start_time, segment name)]).  ``in_air``: start where the
        takeoff segment ends (taking over a vehicle in flight), without it."""
        parts, names = [], []
        here = np.zeros(3)  # mission frame: takeoff spot at the origin, NED
        here_vel = np.zeros(3)
        here_acc = np.zeros(3)
        here_yaw = 0.0
        segments = self.segments
        if in_air:
            here = _ned(0.0, 0.0, segments[0][1]["altitude"])
            segments = segments[1:]
        for kind, spec, section in segments:
            try:
                new = _segment(kind, spec, here, self)
            except ValueError as exc:
                section.error(None, str(exc))
            for p, name in new:
                first = p.sample(0.0)
                jump = np.linalg.norm(first.pos - here) > 1e-6 or \
                    np.linalg.norm(first.vel - here_vel) > 1e-6
                if jump and spec.get("join", "transit") == "transit":
                    parts.append(Transit(here, here_vel, here_yaw, first, self.transit_speed,
                                         self.transit_accel, acc0=here_acc))
                    names.append(f"transit to {name}")
                parts.append(p)
                names.append(name)
                end = p.sample(p.duration) if math.isfinite(p.duration) else first
                here, here_vel, here_acc, here_yaw = end.pos, end.vel, end.acc, end.yaw
        seq = T.Sequence(parts, join_tol=math.inf)
        traj = Shifted(seq, np.asarray(origin, dtype=float))
        return traj, list(zip(seq.start_times, names))


class Shifted(T.Trajectory):
    """A trajectory moved by a constant NED offset (the takeoff spot, a spiral's centre)."""

    def __init__(self, inner, offset):
        self.inner = inner
        self.offset = np.asarray(offset, dtype=float)
        self.duration = inner.duration

    def _eval(self, t):
        pos, vel, acc, yaw, yaw_rate = self.inner.sample_many(t)
        return pos + self.offset, vel, acc, yaw, yaw_rate


def _ned(n, e, alt):
    return np.array([float(n), float(e), -float(alt)])


def _yaw(spec, default=0.0):
    if spec.get("yaw") == "tangent":
        return "tangent"
    return math.radians(spec["yaw_deg"]) if "yaw_deg" in spec else default


def _segment(kind, s, here, m):
    """Trajectory parts of one segment starting from ``here`` (mission frame)."""
    alt_here = -here[2]
    if kind == "takeoff":
        return [(T.Takeoff(here, s["altitude"], speed=s.get("speed", 0.5), yaw=_yaw(s)),
                 "takeoff")]
    if kind == "land":
        return [(T.Land(here, s.get("speed", 0.5), yaw=_yaw(s), final_speed=FINAL_SPEED,
                        final_height=FINAL_HEIGHT), "land")]
    if kind == "hover":
        pos = _ned(*s["position"]) if "position" in s else here
        return [(T.Hover(pos, yaw=_yaw(s), duration=s["duration"]), "hover")]
    if kind == "circle":
        return [(T.Circle(s["radius"], s["speed"], s.get("altitude", alt_here),
                          center=tuple(s.get("center", (0.0, 0.0))),
                          climb_rate=s.get("climb_rate", 0.0), yaw=_yaw(s, None),
                          clockwise=s.get("clockwise", False),
                          phase=math.radians(s.get("phase_deg", 0.0)),
                          duration=s.get("duration", math.inf) if "laps" not in s else math.inf,
                          laps=s.get("laps")), "circle")]
    if kind == "spiral":
        center = s.get("center", (0.0, 0.0))
        return [(Shifted(T.Spiral(radius=s.get("radius", 10.0), omega=s.get("omega", 0.5),
                                  z0=s.get("z0", 1.0), climb=s.get("climb", 0.1),
                                  yaw=_yaw(s, math.pi / 6), duration=s["duration"]),
                         (center[0], center[1], 0.0)), "spiral")]
    if kind == "figure_eight":
        return [(T.FigureEight(s["a"], s["period"], s.get("altitude", alt_here),
                               center=tuple(s.get("center", (0.0, 0.0))), yaw=_yaw(s, None),
                               duration=s["duration"], b=s.get("b"),
                               plane=s.get("plane", "horizontal"),
                               heading=math.radians(s.get("heading_deg", 0.0))), "figure_eight")]
    if kind == "lissajous":
        return [(T.Lissajous(s["a"], s["omega"], s.get("altitude", alt_here),
                             center=tuple(s.get("center", (0.0, 0.0))),
                             phase=np.radians(s.get("phase_deg", (0.0, 0.0, 0.0))),
                             yaw=_yaw(s, None), duration=s["duration"]), "lissajous")]
    if kind == "file":
        return [(s["trajectory"], "file")]
    if kind == "waypoints":
        pts = [here] + [_ned(*p) for p in s["points"]]
        return [(T.Waypoints(pts, speed=s["speed"], yaw=_yaw(s, None), dwell=s.get("dwell", 0.0)),
                 "waypoints")]
    if kind == "identify":
        from mavadrc.mission.identification import AMPLITUDE, LEG_SPEED, doublets
        return [(doublets(here, yaw=_yaw(s), amplitude=s.get("amplitude", AMPLITUDE),
                          leg_speed=s.get("leg_speed", LEG_SPEED)), "identify")]
    if kind == "named":
        over = dict(s.get("params", {}))
        traj = T.by_name(s["name"], **over)
        if "duration" in s:
            traj = Truncated(traj, s["duration"])
        return [(traj, s["name"])]
    raise ValueError(f"unknown segment {kind!r}")


class Transit(T.Trajectory):
    """A quintic leg from a point at rest (or moving) to the start of the next segment, matching
    its position, velocity and acceleration, so a segment that starts at speed (a circle, the
    thesis spiral) is joined without a velocity step.  It starts with the acceleration the
    segment before it ended with (``acc0``), so leaving a turn (the spiral's 2.5 m/s^2 toward
    its centre) asks no step of the feed-forward.  The heading turns along a smoothstep.

    Duration: long enough for the distance at ``speed`` (peak speed of a rest-to-rest quintic is
    1.875 distance/T) and for the change of velocity at about ``accel`` m/s^2 (a mission's
    ``transit_accel``).
    """

    ACCEL = 2.0

    def __init__(self, p0, v0, yaw0, ref, speed, accel=ACCEL, acc0=(0.0, 0.0, 0.0)):
        p0, v0 = np.asarray(p0, dtype=float), np.asarray(v0, dtype=float)
        a0 = np.asarray(acc0, dtype=float)
        p1, v1, a1 = ref.pos, ref.vel, ref.acc
        dist = float(np.linalg.norm(p1 - p0))
        dv = float(np.linalg.norm(v1 - v0))
        self.duration = max(1.0, 1.875 * dist / speed, 2.5 * dv / accel)
        Tn = self.duration
        # coefficients per axis of p(s) = sum c_k s^k, s = t/T, from the six boundary values
        A = np.array([[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
                      [1, 1, 1, 1, 1, 1], [0, 1, 2, 3, 4, 5], [0, 0, 2, 6, 12, 20]], dtype=float)
        b = np.vstack([p0, v0 * Tn, a0 * Tn * Tn, p1, v1 * Tn, a1 * Tn * Tn])
        self.c = np.linalg.solve(A, b)  # (6, 3)
        self.yaw0 = float(yaw0)
        self.dyaw = float((ref.yaw - yaw0 + math.pi) % (2 * math.pi) - math.pi)

    def _eval(self, t):
        Tn = self.duration
        s = (t / Tn)[:, None]
        k = np.arange(6)
        pos = (s ** k) @ self.c
        vel = (k[1:] * s ** (k[1:] - 1)) @ self.c[1:] / Tn
        acc = (k[2:] * (k[2:] - 1) * s ** (k[2:] - 2)) @ self.c[2:] / Tn**2
        u = s[:, 0]
        smooth = u * u * (3 - 2 * u)
        yaw = self.yaw0 + self.dyaw * smooth
        yaw_rate = self.dyaw * 6 * u * (1 - u) / Tn
        return pos, vel, acc, yaw, yaw_rate


class Truncated(T.Trajectory):
    """An open-ended trajectory cut after ``duration`` seconds."""

    def __init__(self, inner, duration):
        self.inner = inner
        self.duration = float(duration)

    def _eval(self, t):
        return self.inner.sample_many(t)


# --- reading the file ----------------------------------------------------------------------------

_SEG_KEYS = {
    "takeoff": {"altitude": "pos", "speed": "pos", "yaw_deg": "num"},
    "land": {"speed": "pos", "yaw_deg": "num"},
    "hover": {"duration": "pos", "position": "vec3", "yaw_deg": "num"},
    "circle": {"radius": "pos", "speed": "pos", "altitude": "nonneg", "center": "vec2",
               "climb_rate": "num", "yaw_deg": "num", "yaw": "tangent", "clockwise": "bool",
               "phase_deg": "num", "duration": "pos", "laps": "pos"},
    "spiral": {"radius": "pos", "omega": "num", "z0": "nonneg", "climb": "num", "yaw_deg": "num",
               "duration": "pos", "center": "vec2"},
    "figure_eight": {"a": "pos", "period": "pos", "altitude": "nonneg", "center": "vec2",
                     "yaw_deg": "num", "yaw": "tangent", "duration": "pos", "b": "pos",
                     "plane": "plane", "heading_deg": "num"},
    "lissajous": {"a": "vec3+", "omega": "vec3+", "phase_deg": "vec3", "altitude": "nonneg",
                  "center": "vec2", "yaw_deg": "num", "duration": "pos"},
    "file": {"path": "file", "yaw_deg": "num"},
    "waypoints": {"points": "points", "speed": "pos", "dwell": "nonneg", "yaw_deg": "num",
                  "yaw": "tangent"},
    "named": {"name": "str", "params": "map", "duration": "pos"},
    "identify": {"amplitude": "pos", "yaw_deg": "num", "leg_speed": "nonneg"},
}
#: the largest value a segment key may take: sizes, speeds and durations a multirotor mission
#: can mean (a typo such as a 1e9 s hover is refused before anything is computed)
_MAX = {"amplitude": 3.0, "leg_speed": 3.0, "altitude": 1000.0, "speed": 40.0, "radius": 2000.0, "duration": 4 * 3600.0, "a": 2000.0,
        "period": 3600.0, "dwell": 3600.0, "laps": 1000.0, "z0": 1000.0, "omega": 10.0,
        "climb": 10.0, "climb_rate": 10.0, "b": 2000.0, "heading_deg": 360.0,
        "phase_deg": 360.0}
_REQUIRED = {
    "takeoff": ("altitude",), "hover": ("duration",), "circle": ("radius", "speed"),
    "spiral": ("duration",), "figure_eight": ("a", "period", "duration"),
    "lissajous": ("a", "omega", "duration"), "file": ("path",),
    "waypoints": ("points", "speed"), "named": ("name",),
}


def _read_segment(sec):
    keys = [k for k in sec.data]
    if len(keys) != 1 or keys[0] not in SEGMENTS:
        hint = did_you_mean(keys[0], SEGMENTS) if len(keys) == 1 else ""
        sec.error(keys[0] if keys else None,
                  f"each trajectory item is one of {', '.join(SEGMENTS)} (got {keys!r}{hint})")
    kind = keys[0]
    body = sec.raw(kind)
    if body is None:
        body = {}
    inner = Section(body, sec.source, sec.field_name(kind), line=sec.line(kind))
    spec = {}
    for key in _REQUIRED.get(kind, ()):
        inner.raw(key)  # raises 'required field missing' with the line
    for key, what in _SEG_KEYS[kind].items():
        if not inner.has(key):
            continue
        top = _MAX.get(key)
        if what == "pos":
            spec[key] = inner.number(key, gt=0.0, le=top)
        elif what == "nonneg":
            spec[key] = inner.number(key, ge=0.0, le=top)
        elif what == "num":
            spec[key] = inner.number(key, ge=None if top is None else -top, le=top)
        elif what == "bool":
            spec[key] = inner.boolean(key)
        elif what == "str":
            spec[key] = inner.string(key)
        elif what == "tangent":
            spec[key] = inner.string(key, choices=("tangent",))
        elif what == "vec2":
            spec[key] = tuple(inner.vector(key, 2))
        elif what == "vec3":
            spec[key] = tuple(inner.vector(key, 3))
            if top is not None:
                inner.check(key, max(abs(x) for x in spec[key]) <= top,
                            f"each item must be within +-{top:g} (got {list(spec[key])})")
        elif what == "vec3+":
            spec[key] = tuple(inner.vector(key, 3, ge=0.0))
            inner.check(key, max(spec[key]) <= top,
                        f"each item must be <= {top:g} (got {list(spec[key])})")
        elif what == "plane":
            spec[key] = inner.string(key, choices=T.FigureEight.PLANES)
        elif what == "file":
            spec[key], spec["trajectory"] = _read_file(inner, key)
        elif what == "map":
            spec[key] = dict(inner.raw(key))
        elif what == "points":
            pts = inner.raw(key)
            if not isinstance(pts, list) or len(pts) < 1:
                inner.error(key, "must be a list of [north, east, altitude] points")
            for i, p in enumerate(pts):
                if not (isinstance(p, list) and len(p) == 3
                        and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                and math.isfinite(v) for v in p)):
                    inner.error(key, f"point {i} must be [north, east, altitude] (got {p!r})")
            spec[key] = [tuple(map(float, p)) for p in pts]
    if inner.has("join"):
        spec["join"] = inner.string("join", choices=("transit", "direct"))
    if kind == "file":
        inner.check("yaw_deg", "yaw_deg" not in spec or not spec["trajectory"].given["yaw"],
                    "the file has a yaw_deg column, which sets the heading")
        if "yaw_deg" in spec:
            spec["trajectory"] = TF.FileTrajectory(spec["trajectory"].table,
                                                   yaw=math.radians(spec["yaw_deg"]))
    inner.finish()
    return kind, spec, inner


def _read_file(inner, key):
    """A file segment's path, resolved against the folder of the file it is written in (the
    mission's), and the trajectory it holds; a ConfigError naming the mission's line and the
    file's line, row and column when the file cannot be flown."""
    given = inner.string(key)
    source = Path(inner.source)
    base = source.parent if source.is_file() else Path(".")
    path = Path(given).expanduser()
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        here = path.parent
        names = [p.name for p in here.iterdir() if p.is_file()] if here.is_dir() else []
        near = closest(path.name, names)
        hint = f"; did you mean {str(Path(given).with_name(near))!r}?" if near else ""
        inner.error(key, f"no such file {str(path)!r} (a relative path is read from the folder "
                         f"of {source.name}){hint}")
    try:
        return str(path), TF.FileTrajectory(TF.read_table(path))
    except TF.TrajectoryFileError as exc:
        inner.error(key, str(exc))


def _check_files(m):
    """Each file segment against the mission's geofence, altitude and speed limits and the
    acceleration its tilt limit allows, naming the file's row and column."""
    sf = m.safety
    for kind, spec, inner in m.segments:
        if kind != "file":
            continue
        try:
            spec["trajectory"].check_limits(
                sf.geofence_north, sf.geofence_east, (sf.altitude_min, sf.altitude_max),
                sf.max_speed, TF.G * math.tan(math.radians(m.controller.tilt_max_deg)))
        except TF.TrajectoryFileError as exc:
            inner.error("path", str(exc))


def read_controller(sec, kinds=None):
    c = ControllerSpec()
    c.name = sec.string("name", None)  # a label (experiments' tables; mavadrc tune writes one)
    c.kind = sec.string("type", "ladrc", choices=kinds or KINDS)
    c.rate_hz = sec.number("rate_hz", 100.0, ge=5.0, le=500.0)
    c.tilt_max_deg = sec.number("tilt_max_deg", 35.0, gt=0.0, lt=90.0)
    c.thrust_min = sec.number("thrust_min", 0.05, ge=0.0, lt=1.0)
    c.thrust_max = sec.number("thrust_max", 1.0, gt=0.0, le=1.0)
    c.thrust_tilt = sec.string("thrust_tilt", "commanded", choices=THRUST_TILTS)
    c.takeoff = sec.string("takeoff", "safe", choices=TAKEOFFS)
    per_axis = ("wc", "wo", "b0", "kp", "kd", "r0", "h0", "r", "c", "h1", "delta", "accel_max")
    for key in per_axis:
        if sec.has(key):
            c.gains[key] = tuple(sec.vector(key, 3, scalar_ok=True, gt=0.0))
    for key, zero_ok in (("kp_pos", False), ("kp_vel", False), ("ki_vel", True), ("kd_vel", True),
                         ("i_limit", True), ("d_cutoff_hz", True)):  # the pid kind's gains
        if sec.has(key):
            bound = {"ge": 0.0} if zero_ok else {"gt": 0.0}
            c.gains[key] = tuple(sec.vector(key, 3, scalar_ok=True, **bound))
    if sec.has("input_lag"):
        if sec.data["input_lag"] == "auto":
            c.gains["input_lag"] = sec.string("input_lag")
        else:
            c.gains["input_lag"] = tuple(sec.vector("input_lag", 3, scalar_ok=True, ge=0.0))
            sec.check("input_lag", c.kind in ("ladrc", "adrc"),
                      "the input model is part of the observers' model: ladrc and adrc only")
    if sec.has("input_dead_time") or sec.has("input_lags"):
        # the input model shaped as identified: a dead time, then input_lags equal lags
        # sharing the rest of input_lag (its 63 % time)
        key = "input_dead_time" if sec.has("input_dead_time") else "input_lags"
        sec.check(key, isinstance(c.gains.get("input_lag"), tuple),
                  "shapes the input model: give input_lag in seconds too")
        if sec.has("input_dead_time"):
            c.gains["input_dead_time"] = tuple(float(x) for x in sec.vector(
                "input_dead_time", 3, scalar_ok=True, ge=0.0))
            sec.check("input_dead_time", all(d <= t for d, t in zip(
                c.gains["input_dead_time"], c.gains["input_lag"])),
                "the dead time is part of input_lag (its 63 % time): at most input_lag")
        if sec.has("input_lags"):
            n = sec.number("input_lags")
            sec.check("input_lags", n in (1, 2), f"must be 1 or 2 (got {n!r})")
            c.gains["input_lags"] = int(n)
    sec.check("takeoff", c.takeoff == "safe" or c.gains.get("input_lag") == "auto",
              "chooses what flies the takeoff before the vehicle is identified: give "
              "input_lag: auto too")
    if sec.has("predict"):
        # the law acts on its errors carried over the input model's delay (PositionController)
        c.gains["predict"] = sec.boolean("predict")
        sec.check("predict", not c.gains["predict"] or c.kind in ("ladrc", "adrc"),
                  "the law's errors are carried on the observers' estimate: ladrc and adrc only")
        sec.check("predict", not c.gains["predict"] or "input_lag" in c.gains,
                  "the law's errors are carried over the input model's delay: give input_lag "
                  "too")
    if sec.has("drag"):
        # the vehicle's linear drag (1/s per axis) in the observers' model: auto (identified
        # with input_lag: auto, the default then), numbers, or 0 (none)
        if sec.data["drag"] == "auto":
            c.gains["drag"] = sec.string("drag")
            sec.check("drag", c.gains.get("input_lag") == "auto",
                      "drag: auto is identified with the input model: give input_lag: auto, "
                      "or the drag in 1/s")
        else:
            c.gains["drag"] = tuple(float(x) for x in
                                    sec.vector("drag", 3, scalar_ok=True, ge=0.0))
            sec.check("drag", max(c.gains["drag"]) <= DRAG_MAX,
                      f"must be at most {DRAG_MAX:g} /s (got {max(c.gains['drag']):g})")
        sec.check("drag", c.kind in ("ladrc", "adrc"),
                  "the drag is part of the observers' model: ladrc and adrc only")
    if sec.has("drag_learn"):
        # the memory (s) with which the horizontal drag is learnt in flight from the observers
        # (mavadrc.control.learn; true: the default, on with drag: auto; 0 or false: the drag stays)
        if isinstance(sec.data["drag_learn"], bool):
            c.gains["drag_learn"] = DRAG_LEARN_S if sec.boolean("drag_learn") else 0.0
        else:
            c.gains["drag_learn"] = sec.number("drag_learn", ge=0.0, le=120.0)
        sec.check("drag_learn", c.gains["drag_learn"] == 0.0 or c.kind in ("ladrc", "adrc"),
                  "the drag is learnt from the observers: ladrc and adrc only")
    if sec.has("latency"):
        # how old the samples are, for the observers to compensate: auto (measured), seconds,
        # or 0 (not compensated)
        if sec.data["latency"] == "auto":
            c.gains["latency"] = sec.string("latency")
        else:
            c.gains["latency"] = sec.number("latency", ge=0.0, le=AGE_MAX)
        sec.check("latency", c.gains["latency"] == 0.0 or c.kind in ("ladrc", "adrc"),
                  "the observers compensate the samples' age: ladrc and adrc only")
    if sec.has("thrust_estimate"):
        # the time constant (s) with which the thrust per acceleration is learnt in flight from
        # the vertical disturbance estimate (an observer's z3, a PID's integrator; 0 or false:
        # the figure told is kept; true: the default 2 s)
        if isinstance(sec.data["thrust_estimate"], bool):
            c.gains["thrust_estimate"] = THRUST_ESTIMATE_S if sec.boolean("thrust_estimate") \
                else 0.0
        else:
            c.gains["thrust_estimate"] = sec.number("thrust_estimate", ge=0.0, le=60.0)
        sec.check("thrust_estimate", c.gains["thrust_estimate"] == 0.0
                  or c.kind in ("ladrc", "adrc", "pid"),
                  "the thrust is learnt from the vertical disturbance estimate (an observer's "
                  "or a PID's integrator): ladrc, adrc and pid only")
    if sec.has("beta"):
        c.gains["beta"] = tuple(sec.vector("beta", 3, gt=0.0))
    if sec.has("td"):
        c.gains["td"] = sec.boolean("td")
    if sec.has("eso_gains"):
        c.gains["eso_gains"] = sec.string("eso_gains", choices=("han", "thesis"))
    if c.kind == "native":
        # the autopilot's own position controller: its gains are its parameters (PX4 MPC_*,
        # ArduCopter PSC_*), not the mission's; nor does the companion size any thrust
        for key in [*c.gains, "thrust_tilt", "takeoff"]:
            if sec.has(key):
                sec.error(key, "the autopilot's own position controller flies native: set its "
                               "gains as its parameters (PX4 MPC_*, ArduCopter PSC_*)")
    sec.finish()
    return c


def _read_safety(sec, s):
    if sec.has("geofence"):
        g = sec.section("geofence")
        s.geofence_north = tuple(g.vector("north", 2, s.geofence_north))
        s.geofence_east = tuple(g.vector("east", 2, s.geofence_east))
        for key in ("north", "east"):
            lo, hi = getattr(s, f"geofence_{key}")
            g.check(key, lo < 0.0 < hi, "the box must contain the takeoff spot (min < 0 < max)")
        g.finish()
    if sec.has("altitude"):
        a = sec.section("altitude")
        s.altitude_min = a.number("min", s.altitude_min)
        s.altitude_max = a.number("max", s.altitude_max, gt=0.0)
        a.check("max", s.altitude_max > s.altitude_min, "must exceed altitude.min")
        a.finish()
    s.max_speed = sec.number("max_speed", s.max_speed, gt=0.0)
    s.telemetry_timeout_s = sec.number("telemetry_timeout_s", s.telemetry_timeout_s, ge=0.05,
                                       le=10.0)
    s.set_guid_options = sec.boolean("set_guid_options", s.set_guid_options)
    s.max_sample_loss = sec.number("max_sample_loss", s.max_sample_loss, gt=0.0, le=1.0)
    s.max_gap_s = sec.number("max_gap_s", s.max_gap_s, gt=0.0, le=10.0)
    s.min_rate_hz = sec.number("min_rate_hz", s.min_rate_hz, gt=0.0, le=500.0)
    s.max_touchdown_speed = sec.number("max_touchdown_speed", s.max_touchdown_speed, gt=0.0,
                                       le=5.0)
    s.max_tracking_error = sec.number("max_tracking_error", s.max_tracking_error, ge=0.0,
                                      le=1000.0)
    s.min_clearance = sec.number("min_clearance", s.min_clearance, ge=0.0, le=100.0)
    sec.finish()
    return s


def load_mission(path):
    """Read and check a mission file; returns a :class:`Mission` or raises ConfigError."""
    path = config_path(path, "missions") if not Path(str(path)).exists() else Path(path)
    text = read_text(path)
    data = load_yaml(path, text=text)
    return mission_from_section(Section(data, str(path)), str(path), text, Path(path).stem)


def read_text(path):
    """A configuration file's text; a file that is not UTF-8 text is a ConfigError naming it."""
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a YAML text file (byte {exc.start} is not UTF-8)") from None
    if "\0" in text:
        raise ConfigError(f"{path}: not a YAML text file (it holds NUL bytes)")
    return text


def check_limits(m, top, segs):
    """Refuse a trajectory that leaves its own geofence, altitude or speed limits."""
    traj, phases = m.build_trajectory()
    sf = m.safety
    t = np.arange(0.0, traj.duration + 0.025, 0.025)
    pos, vel, _, _, _ = traj.sample_many(np.minimum(t, traj.duration))
    north, east, alt = pos[:, 0], pos[:, 1], -pos[:, 2]
    speed = np.linalg.norm(vel, axis=1)
    bad = [(north < sf.geofence_north[0]) | (north > sf.geofence_north[1])
           | (east < sf.geofence_east[0]) | (east > sf.geofence_east[1]),
           (alt > sf.altitude_max) | (alt < sf.altitude_min),
           speed > sf.max_speed]
    what = ["leaves the geofence", "leaves the altitude limits", "exceeds safety.max_speed"]
    for mask, text in zip(bad, what):
        if mask.any():
            k = int(np.argmax(mask))
            tk = float(t[k])
            name = phases[0][1]
            for t0, n in phases:
                if tk >= t0:
                    name = n
            at = (f"north {north[k]:.1f} m, east {east[k]:.1f} m, altitude {alt[k]:.1f} m, "
                  f"{speed[k]:.1f} m/s")
            seg = next((s for (kind, spec, s) in m.segments if name.endswith(kind)
                        or spec.get("name") == name), None)
            where = seg if seg is not None else top
            where.error(None, f"the reference {text} at {tk:.1f} s ({name}: {at})")


def _bundled_hover(vp, autopilot):
    """The hover thrust of a bundled vehicle whose motors have their own thrust curve, as its
    autopilot (linearising with its default THR_MDL_FAC / MOT_THST_EXPO) reports it."""
    from sim.firmware.mixer import hover_command
    from sim.personality import personality

    ap = personality(autopilot)
    default = next(d for name, d, _ in ap.params if name == ap.thrust_model_param)
    return hover_command(vp, vp.max_thrust, ap.thrust_model_factor(default))


def _read_variant(s, m):
    """The ``sim:`` keys that make the bundled vehicle differ from its file (``s``: the section,
    after ``attitude_controller``; ``m.vehicle`` read)."""
    m.mass_scale = s.number("mass_scale", 1.0, gt=0.0, le=10.0)
    m.motor_thrust_curve = s.number("motor_thrust_curve", None, ge=-1.0, le=1.0)
    m.attitude_bandwidth_scale = s.number("attitude_bandwidth_scale", 1.0, gt=0.0, le=10.0)
    varied = [k for k, v in (("mass_scale", m.mass_scale != 1.0),
                             ("motor_thrust_curve", m.motor_thrust_curve is not None),
                             ("attitude_bandwidth_scale", m.attitude_bandwidth_scale != 1.0))
              if v]
    if not varied:
        return
    if m.vehicle is None:
        s.error(varied[0], "changes the bundled vehicle against its file: give the file "
                           "(vehicle: NAME), whose figures the companion is told")
    if m.attitude_bandwidth_scale != 1.0 and m.attitude_controller != "px4":
        s.error("attitude_bandwidth_scale", "scales the PX4-like attitude loop "
                                            "(attitude_controller: px4)")
    from sim.vehicle import vehicle_variant
    try:
        vehicle_variant(m.vehicle, mass_scale=m.mass_scale,
                        motor_thrust_curve=m.motor_thrust_curve,
                        attitude_bandwidth_scale=m.attitude_bandwidth_scale)
    except ConfigError as exc:
        s.error(varied[0], str(exc))


def vehicle_flown(m):
    """The bundled vehicle a mission flies: its file, changed as its ``sim:`` section says
    (:func:`sim.vehicle.vehicle_variant`)."""
    from sim.vehicle import vehicle_variant
    return vehicle_variant(m.vehicle or "crazyflie", mass_scale=m.mass_scale,
                           motor_thrust_curve=m.motor_thrust_curve,
                           attitude_bandwidth_scale=m.attitude_bandwidth_scale)


def mission_from_section(top, source, text, default_name="mission", require_land=True,
                         controller=True):
    """A :class:`Mission` from a YAML section (a mission file, or an experiment's scenario).

    ``require_land``: the last segment must be a land (experiment runs may end in the air);
    ``controller``: whether a ``controller:`` key is read here.
    """
    m = Mission(name=top.string("name", default_name), source=source, text=text,
                segments=[], controller=ControllerSpec(), safety=Safety())
    if top.has("vehicle"):
        v = top.raw("vehicle")
        if isinstance(v, str):
            m.vehicle = v
            try:
                from sim.params import load_vehicle
                vp = load_vehicle(v)
            except ConfigError as exc:
                top.error("vehicle", str(exc))
            m.hover_thrust = vp.hover_thrust_norm
            m.hover_source = f"the bundled vehicle {v}"
        else:
            vs = top.section("vehicle")
            m.hover_thrust = vs.number("hover_thrust", None, gt=0.0, lt=1.0)
            m.mass = vs.number("mass", None, gt=0.0)
            m.max_thrust = vs.number("max_thrust", None, gt=0.0)
            if m.hover_thrust is None and (m.mass is None) != (m.max_thrust is None):
                vs.error(None, "give hover_thrust, or both mass and max_thrust")
            if m.mass is not None and m.max_thrust is not None and m.max_thrust <= m.mass * 9.80665:
                vs.error("max_thrust", f"must exceed the weight ({m.mass * 9.80665:.3g} N)")
            vs.finish()
            if m.hover_thrust is not None:
                m.hover_source = "the mission's vehicle.hover_thrust"
            elif m.mass is not None:
                # thrust linear in the command: hovering takes weight / maximum thrust
                m.hover_thrust = m.mass * 9.80665 / m.max_thrust
                m.hover_source = "the mission's vehicle.mass and max_thrust"
    if controller:
        m.controller = read_controller(top.section("controller")) if top.has("controller") \
            else ControllerSpec()
    segs = top.sections("trajectory")
    if not segs:
        top.error("trajectory", "must list at least one segment")
    m.segments = []
    for s in segs:
        kind, spec, inner = _read_segment(s)
        m.segments.append((kind, spec, inner))
    if m.segments[0][0] != "takeoff":
        segs[0].error(None, "the first segment must be a takeoff (missions start on the ground)")
    if require_land and m.segments[-1][0] != "land":
        segs[-1].error(None, "the last segment must be a land")
    if top.has("wind"):
        m.wind = top.raw("wind")
        top.check("wind", isinstance(m.wind, (str, dict)),
                  f"must be a wind name, a file or a mapping (got {described(m.wind)})")
        try:
            from sim.wind import load_wind
            load_wind(m.wind)  # checked now, before anything flies
        except ConfigError as exc:
            top.error("wind", str(exc))
    if top.has("sim"):
        m.sim_given = True
        s = top.section("sim")
        m.seed = int(s.number("seed", 0, ge=0))
        m.autopilot = s.string("autopilot", "px4", choices=("px4", "ardupilot"))
        m.attitude_controller = s.string("attitude_controller", "px4",
                                         choices=("px4", "ladrc", "adrc", "pd"))
        m.noise = s.boolean("noise", False)
        m.wander = s.number("wander", 0.0, ge=0.0, le=1.0)
        m.wander_corner_hz = s.number("wander_corner_hz", WANDER_CORNER_HZ, ge=0.01, le=5.0)
        m.sensor_latency_s = s.number("sensor_latency_s", 0.0, ge=0.0, le=1.0)
        m.height_drift_mps = s.number("height_drift_mps", 0.0, ge=-0.5, le=0.5)
        m.ground_climb_mps = s.number("ground_climb_mps", 0.0, ge=0.0, le=2.0)
        m.rangefinder = s.boolean("rangefinder", False)
        m.clock_rate = s.number("clock_rate", 1.0, ge=CLOCK_RATES[0], le=CLOCK_RATES[1])
        if s.has("link"):
            from sim.link_model import link_from_section
            link = link_from_section(s.section("link"))
            m.link = None if link.perfect else link
        _read_variant(s, m)
        if isinstance(s.raw("heading_deg", None), str):
            if s.string("heading_deg").strip().lower() != "random":
                s.error("heading_deg", "must be degrees or 'random' (drawn from the seed)")
            m.heading_deg = math.nan
        else:
            m.heading_deg = s.number("heading_deg", 0.0, ge=-360.0, le=360.0)
        s.finish()
    if m.vehicle is not None and m.motor_thrust_curve is not None:
        # the motors' curve as if the file gave it: the autopilot reports its hover thrust
        from sim.vehicle import vehicle_variant
        vp = vehicle_variant(vp, motor_thrust_curve=m.motor_thrust_curve)
    if m.vehicle is not None and vp.motor_thrust_curve is not None:
        m.hover_thrust = _bundled_hover(vp, m.autopilot)
    m.safety = _read_safety(top.section("safety"), Safety()) if top.has("safety") else Safety()
    _check_files(m)
    if top.has("logging"):
        lg = top.section("logging")
        m.out = lg.string("out", "runs")
        m.settle_s = lg.number("settle_s", 0.0, ge=0.0)
        lg.finish()
    m.transit_speed = top.number("transit_speed", 1.0, gt=0.0)
    m.transit_accel = top.number("transit_accel", Transit.ACCEL, gt=0.0, le=20.0)
    top.finish()
    try:
        check_limits(m, top, segs)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        top.error("trajectory", str(exc))
    return m


def flight_mission(mission, altitude=ALTITUDE):
    """``mission`` reduced to take off, identify and land, flown by the safe default LADRC (the
    mission's rate and limits; its vehicle, wind and sim settings kept, as ``fly`` would fly
    them): what ``mavadrc identify`` flies."""
    import dataclasses

    spec = mission.controller
    ctrl = ControllerSpec(kind="ladrc", name="identification", rate_hz=spec.rate_hz,
                          gains={"input_lag": "auto"}, tilt_max_deg=spec.tilt_max_deg,
                          thrust_min=spec.thrust_min, thrust_max=spec.thrust_max,
                          thrust_tilt=spec.thrust_tilt)
    segments = [("takeoff", {"altitude": altitude, "speed": 0.5}, None),
                ("identify", {}, None), ("land", {"speed": 0.5}, None)]
    return dataclasses.replace(mission, name=f"identification ({mission.name})",
                               segments=segments, controller=ctrl, settle_s=0.0)
