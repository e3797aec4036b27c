"""Reference trajectories with analytic derivatives.

Every trajectory has one small contract:

* ``duration``: seconds (``math.inf`` for open-ended ones);
* ``sample(t) -> Reference(pos, vel, acc, yaw, yaw_rate)`` for one time;
* ``sample_many(t_array) -> (pos (N,3), vel (N,3), acc (N,3), yaw (N,), yaw_rate (N,))``
  vectorised, for plots and batch experiments.

Positions are world NED in metres (z down, altitude = -z), yaw in radians wrapped to
[-pi, pi], yaw_rate in rad/s. Velocities and accelerations are the exact derivatives of the
position, so a controller can use them as feed-forward. Times before 0 are clamped to 0; after
a finite ``duration`` the final point is held with zero velocity, acceleration and yaw rate.

Trajectories named after the thesis (``by_name``; the thesis states z up, here it is converted
to NED by z = -z_up and its x, y are read as north, east):

``thesis_circle``
    Section 6.2.1 (PD at 2, 4, 6, 8, 10 m/s) and 6.2.3 (PD under wind, 2-6 m/s): a level circle
    of radius 10 m at speed v (default 2 m/s), yaw pi/6. The thesis's text for 6.2.1 prints the
    spiral formula of 6.2.2 while its figures show circles flown at the stated speeds, so this is
    the circle x = 10 cos(v t / 10), y = 10 sin(v t / 10) at a constant altitude of 1 m (the
    offset in the z_d = 1 + 0.1 t of 6.2.3). Override ``speed`` for the other cases.
``thesis_spiral_pd``
    Sections 6.2.1/6.2.2 (PD) and 6.4 (LADRC, as printed): x = 10 cos(0.1 t), y = 10 sin(0.1 t),
    z_up = 0.1 t, yaw pi/6. Its horizontal speed is 1 m/s; the thesis's "speeds" for these runs
    are not derivable from the formula, so vary ``omega`` (speed = 10 * omega).
``thesis_spiral``
    Sections 6.2.3 and 6.3 (classical ADRC under wind): x = 10 cos(0.5 t), y = 10 sin(0.5 t),
    z_up = 1 + 0.1 t, yaw pi/6 (horizontal speed 5 m/s).
``hover``
    Hold 1 m above the origin, yaw 0.
``figure_eight``
    Lemniscate of Gerono, +-5 m north by +-2.5 m east, 20 s per loop, 2 m altitude, yaw 0.
``figure_eight_vertical``
    Neural-Fly's benchmark eight in the north-up plane: north = 1.25 sin t, altitude =
    2 + 0.75 sin 2t (1 rad/s, a loop in 2 pi s), yaw 0.

Missions chain finite pieces with ``Sequence([Takeoff(...), Waypoints(...), Circle(...,
laps=2), Land(...)])``; a Sequence refuses position jumps at its joins.
"""

from __future__ import annotations

import inspect
import math
from typing import NamedTuple

import numpy as np

__all__ = [
    "Reference",
    "Trajectory",
    "Hover",
    "Circle",
    "Spiral",
    "FigureEight",
    "Lissajous",
    "Waypoints",
    "Takeoff",
    "Land",
    "Doublets",
    "Sequence",
    "by_name",
    "list_names",
]


class Reference(NamedTuple):
    """Desired state at one instant (NED, SI, radians)."""

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    yaw: float
    yaw_rate: float


# --------------------------------------------------------------------------- validation


def _number(owner: str, name: str, value, *, positive=False, nonneg=False, allow_inf=False):
    if isinstance(value, (str, bytes, bool)) or value is None:
        raise ValueError(f"{owner}: {name} must be a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be a number, got {value!r}") from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise ValueError(f"{owner}: {name} must be finite, got {value!r}")
    if positive and not x > 0.0:
        raise ValueError(f"{owner}: {name} must be > 0, got {value!r}")
    if nonneg and not x >= 0.0:
        raise ValueError(f"{owner}: {name} must be >= 0, got {value!r}")
    return x


def _vector(owner: str, name: str, value, n: int) -> np.ndarray:
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be {n} numbers, got {value!r}") from None
    if v.shape != (n,):
        raise ValueError(f"{owner}: {name} must have {n} elements, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{owner}: {name} must be finite, got {value!r}")
    return v


def _duration(owner: str, value) -> float:
    return _number(owner, "duration", value, positive=True, allow_inf=True)


def _yaw_mode(owner: str, yaw):
    """None -> constant 0; a number -> constant; 'tangent' -> face the horizontal velocity."""
    if yaw is None:
        return 0.0
    if isinstance(yaw, str):
        if yaw == "tangent":
            return "tangent"
        raise ValueError(f"{owner}: yaw must be a number, None or 'tangent', got {yaw!r}")
    return _number(owner, "yaw", yaw)


# --------------------------------------------------------------------------- small helpers


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Wrap to [-pi, pi], leaving angles already inside untouched (so constants stay exact)."""
    if angle.shape[0] == 1 and abs(float(angle[0])) <= math.pi:
        return angle  # one sample, already inside: a flight's every step
    wrapped = np.mod(angle + math.pi, 2.0 * math.pi) - math.pi
    return np.where(np.abs(angle) <= math.pi, angle, wrapped)


def _tangent_yaw(vel: np.ndarray, acc: np.ndarray):
    """Heading of the horizontal velocity and its exact rate d/dt atan2(vy, vx).

    Only used by curves whose horizontal speed never vanishes (validated speed > 0).
    """
    vx, vy, ax, ay = vel[:, 0], vel[:, 1], acc[:, 0], acc[:, 1]
    return np.arctan2(vy, vx), (vx * ay - vy * ax) / (vx * vx + vy * vy)


def _min_jerk(s: np.ndarray):
    """Quintic 10 s^3 - 15 s^4 + 6 s^5 and its first two derivatives in s, for s in [0, 1].

    Zero slope and curvature at both ends; peak slope 1.875 at s = 1/2.
    """
    s2 = s * s
    q = s2 * s * (10.0 + s * (-15.0 + 6.0 * s))
    dq = 30.0 * s2 * (1.0 - s) ** 2
    ddq = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s)
    return q, dq, ddq


MIN_JERK_PEAK = 1.875
"""Peak of d/ds of the minimum-jerk quintic: peak speed = 1.875 * distance / T."""


# --------------------------------------------------------------------------- base class


class Trajectory:
    """Base class: subclasses set ``duration`` and implement ``_eval`` on clamped times."""

    duration: float = math.inf

    def _eval(self, t: np.ndarray):
        """pos (N,3), vel (N,3), acc (N,3), yaw (N,), yaw_rate (N,) for 0 <= t <= duration."""
        raise NotImplementedError

    def sample_many(self, t):
        """Evaluate at many times (1-D array); see the module docstring for clamping and hold."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1:
            raise ValueError(f"{type(self).__name__}: t must be a 1-D array, got shape {t.shape}")
        if t.shape[0] == 1:  # one time (a flight samples one or three each step): in Python,
            x = float(t[0])  # where numpy's checks on a 1-element array cost more than _eval
            if not math.isfinite(x):
                raise ValueError(f"{type(self).__name__}: t must be finite")
            tc = t if 0.0 <= x <= self.duration else np.array([min(max(x, 0.0), self.duration)])
            after = slice(None) if x > self.duration else None
        else:
            if not np.all(np.isfinite(t)):
                raise ValueError(f"{type(self).__name__}: t must be finite")
            tc = np.clip(t, 0.0, self.duration)
            after = t > self.duration
            after = after if np.any(after) else None
        pos, vel, acc, yaw, yaw_rate = self._eval(tc)
        if after is not None:  # held after the end: at rest
            vel[after] = 0.0
            acc[after] = 0.0
            yaw_rate[after] = 0.0
        return pos, vel, acc, _wrap(yaw), yaw_rate

    def sample(self, t: float) -> Reference:
        """The reference at time t (seconds)."""
        pos, vel, acc, yaw, yaw_rate = self.sample_many(np.array([t], dtype=float))
        return Reference(pos[0], vel[0], acc[0], float(yaw[0]), float(yaw_rate[0]))


# --------------------------------------------------------------------------- shapes


class Hover(Trajectory):
    """Hold a fixed NED position and yaw."""

    def __init__(self, position, yaw: float = 0.0, duration: float = math.inf):
        self.position = _vector("Hover", "position", position, 3)
        self.yaw = _number("Hover", "yaw", yaw)
        self.duration = _duration("Hover", duration)

    def _eval(self, t):
        n = t.shape[0]
        return (
            np.tile(self.position, (n, 1)),
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            np.full(n, self.yaw),
            np.zeros(n),
        )


class _Planar(Trajectory):
    """A horizontal curve at an altitude that changes linearly, with constant or tangent yaw."""

    def _init_vertical(self, owner, altitude, climb_rate, yaw, duration):
        self.altitude = _number(owner, "altitude", altitude)
        if self.altitude < 0.0:
            raise ValueError(
                f"{owner}: altitude is metres above ground (positive up), got {altitude!r}"
            )
        self.climb_rate = _number(owner, "climb_rate", climb_rate)
        self.yaw = _yaw_mode(owner, yaw)
        self.duration = _duration(owner, duration)

    def _horizontal(self, t):
        """Return (xy, vxy, axy), each (N, 2)."""
        raise NotImplementedError

    def _eval(self, t):
        n = t.shape[0]
        xy, vxy, axy = self._horizontal(t)
        pos = np.empty((n, 3))
        vel = np.empty((n, 3))
        acc = np.zeros((n, 3))
        pos[:, :2], vel[:, :2], acc[:, :2] = xy, vxy, axy
        pos[:, 2] = -(self.altitude + self.climb_rate * t)
        vel[:, 2] = 0.0 - self.climb_rate  # not -0.0 when level
        if self.yaw == "tangent":
            yaw, yaw_rate = _tangent_yaw(vel, acc)
        else:
            yaw, yaw_rate = np.full(n, self.yaw), np.zeros(n)
        return pos, vel, acc, yaw, yaw_rate


class Circle(_Planar):
    """Circle of ``radius`` flown at ``speed`` (angular rate w = speed / radius).

    Position: north = cn + R cos(th), east = ce + R sin(th), z = -(altitude + climb_rate t),
    th = phase + w t when ``clockwise`` (north towards east, i.e. clockwise seen from above),
    th = phase - w t otherwise. ``phase`` is the angle at t = 0. ``yaw`` is a constant (None: 0)
    or 'tangent' to face the direction of travel. ``laps`` sets duration = laps * 2 pi / w.
    """

    def __init__(
        self,
        radius: float,
        speed: float,
        altitude: float,
        center=(0.0, 0.0),
        climb_rate: float = 0.0,
        yaw=None,
        clockwise: bool = False,
        phase: float = 0.0,
        duration: float = math.inf,
        laps: float | None = None,
    ):
        owner = type(self).__name__
        self.radius = _number(owner, "radius", radius, positive=True)
        self.speed = _number(owner, "speed", speed, positive=True)
        self.center = _vector(owner, "center", center, 2)
        self.clockwise = bool(clockwise)
        self.phase = _number(owner, "phase", phase)
        self.omega = self.speed / self.radius
        if laps is not None:
            laps = _number(owner, "laps", laps, positive=True)
            if math.isfinite(_duration(owner, duration)):
                raise ValueError(f"{owner}: give laps or duration, not both")
            duration = laps * 2.0 * math.pi / self.omega
        self._init_vertical(owner, altitude, climb_rate, yaw, duration)

    def _horizontal(self, t):
        sign = 1.0 if self.clockwise else -1.0
        w, r = self.omega, self.radius
        th = self.phase + sign * w * t
        c, s = np.cos(th), np.sin(th)
        xy = self.center + r * np.stack([c, s], axis=1)
        vxy = sign * r * w * np.stack([-s, c], axis=1)
        axy = -r * w * w * np.stack([c, s], axis=1)
        return xy, vxy, axy


class Spiral(Circle):
    """The thesis's spiral (sections 6.2-6.4), literally:

    x = R cos(omega t), y = R sin(omega t), altitude = z0 + climb t (NED z = -altitude),
    with x, y read as north, east. Defaults are the section 6.3 ADRC case. A negative
    ``omega`` turns the other way.
    """

    def __init__(
        self,
        radius: float = 10.0,
        omega: float = 0.5,
        z0: float = 1.0,
        climb: float = 0.1,
        yaw=math.pi / 6.0,
        duration: float = math.inf,
    ):
        w = _number("Spiral", "omega", omega)
        if w == 0.0:
            raise ValueError(f"Spiral: omega must be nonzero, got {omega!r}")
        r = _number("Spiral", "radius", radius, positive=True)
        super().__init__(
            radius=r,
            speed=r * abs(w),
            altitude=z0,
            climb_rate=climb,
            yaw=yaw,
            clockwise=w > 0.0,
            duration=duration,
        )


class FigureEight(_Planar):
    """Lemniscate of Gerono: along = a sin(th), across = b sin(2 th), th = w t, w = 2 pi / period.

    ``plane='horizontal'`` (the default): ``along`` points to ``heading`` (radians from north,
    default 0) and ``across`` 90 deg to its right, so with heading 0 north = cn + a sin(th),
    east = ce + b sin(2 th). It starts at the centre crossing, spans +-a along by +-b across
    (b defaults to a/2), and its horizontal speed w sqrt(a^2 cos^2 th + 4 b^2 cos^2 2th)
    never vanishes, so 'tangent' yaw is smooth everywhere.

    ``plane='vertical'``: ``along`` is horizontal, towards ``heading``, and ``across`` is up:
    altitude = altitude + b sin(2 th), the eight of Neural-Fly's benchmark (a = 1.25 m,
    b = 0.75 m, w = 1 rad/s: :func:`by_name` ``figure_eight_vertical``). Its horizontal speed
    stops at each end, so yaw is a constant there; its lowest point is b below ``altitude``.
    """

    PLANES = ("horizontal", "vertical")

    def __init__(
        self,
        a: float,
        period: float,
        altitude: float,
        center=(0.0, 0.0),
        yaw=None,
        duration: float = math.inf,
        b: float | None = None,
        plane: str = "horizontal",
        heading: float = 0.0,
    ):
        owner = "FigureEight"
        self.a = _number(owner, "a", a, positive=True)
        self.b = 0.5 * self.a if b is None else _number(owner, "b", b, positive=True)
        self.period = _number(owner, "period", period, positive=True)
        self.center = _vector(owner, "center", center, 2)
        self.heading = _number(owner, "heading", heading)
        if plane not in self.PLANES:
            raise ValueError(f"{owner}: plane must be one of {', '.join(self.PLANES)}, "
                             f"got {plane!r}")
        self.plane = plane
        self.omega = 2.0 * math.pi / self.period
        self._init_vertical(owner, altitude, 0.0, yaw, duration)
        if plane == "vertical":
            if self.yaw == "tangent":
                raise ValueError(f"{owner}: yaw 'tangent' needs the horizontal plane (a "
                                 "vertical eight's horizontal speed stops at each end)")
            if self.altitude < self.b:
                raise ValueError(f"{owner}: a vertical eight reaches b = {self.b:g} m below its "
                                 f"altitude {self.altitude:g} m, under the ground")
        self._cs = (math.cos(self.heading), math.sin(self.heading))

    def _shape(self, t):
        """(along, across) and their first two derivatives, each (N, 2)."""
        a, b, w = self.a, self.b, self.omega
        th = w * t
        s1, c1, s2, c2 = np.sin(th), np.cos(th), np.sin(2.0 * th), np.cos(2.0 * th)
        # each factor grouped as the horizontal eight has always computed it (b = a/2 there):
        # the same bits, so its flights' records stay byte for byte what they were
        return (np.stack([a * s1, b * s2], axis=1),
                np.stack([(a * w) * c1, (2.0 * b * w) * c2], axis=1),
                np.stack([(-a * w * w) * s1, (-2.0 * b * w * w) * (2.0 * s2)], axis=1))

    def _horizontal(self, t):
        shape = self._shape(t)
        if self.plane == "vertical":  # along only; across is added to the altitude in _eval
            c, s = self._cs
            # (+ 0.0: no -0.0 on an axis the eight does not move along)
            out = [np.stack([q[:, 0] * c + 0.0, q[:, 0] * s + 0.0], axis=1) for q in shape]
        elif self.heading == 0.0:  # along is north, across is east
            out = list(shape)
        else:
            c, s = self._cs  # (along, across) -> (north, east), element by element: a
            # matrix product rounds one row differently from many
            out = [np.stack([q[:, 0] * c - q[:, 1] * s, q[:, 0] * s + q[:, 1] * c], axis=1)
                   for q in shape]
        out[0] = self.center + out[0]
        return tuple(out)

    def _eval(self, t):
        out = super()._eval(t)
        if self.plane == "vertical":
            up, vup, aup = (q[:, 1] for q in self._shape(t))
            pos, vel, acc = out[:3]
            pos[:, 2] -= up
            vel[:, 2] = 0.0 - vup
            acc[:, 2] = 0.0 - aup
        return out


class Lissajous(Trajectory):
    """A Lissajous figure in three axes: with (an, ae, au) = ``a``, (wn, we, wu) = ``omega``
    (rad/s) and (pn, pe, pu) = ``phase`` (rad),

        north = cn + an sin(wn t + pn), east = ce + ae sin(we t + pe),
        altitude = altitude + au sin(wu t + pu).

    An amplitude or a rate of 0 keeps that axis still (at its offset a sin(p)). The yaw is a
    constant (None: 0): the horizontal speed of such a figure may stop, where a heading along
    the path is not defined. Its lowest point is ``au`` below ``altitude``, which may not be
    under the ground.
    """

    def __init__(self, a, omega, altitude: float, center=(0.0, 0.0), phase=(0.0, 0.0, 0.0),
                 yaw=None, duration: float = math.inf):
        owner = "Lissajous"
        self.a = _vector(owner, "a", a, 3)
        self.omega = _vector(owner, "omega", omega, 3)
        self.phase = _vector(owner, "phase", phase, 3)
        if np.any(self.a < 0.0) or np.any(self.omega < 0.0):
            raise ValueError(f"{owner}: a and omega must be >= 0 (a sign is a phase of pi)")
        self.center = _vector(owner, "center", center, 2)
        self.altitude = _number(owner, "altitude", altitude)
        if self.altitude < self.a[2]:
            raise ValueError(f"{owner}: the figure reaches a_up = {self.a[2]:g} m below its "
                             f"altitude {self.altitude:g} m, under the ground")
        if yaw == "tangent":
            raise ValueError(f"{owner}: yaw must be a number (a Lissajous figure's horizontal "
                             "speed may stop, where 'tangent' is not defined)")
        self.yaw = _yaw_mode(owner, yaw)
        self.duration = _duration(owner, duration)
        # NED offset and amplitude: altitude up is -z
        self._offset = np.array([self.center[0], self.center[1], -self.altitude])
        self._amp = self.a * np.array([1.0, 1.0, -1.0])

    def _eval(self, t):
        n = t.shape[0]
        th = t[:, None] * self.omega + self.phase
        s, c = np.sin(th), np.cos(th)
        pos = self._offset + self._amp * s
        vel = self._amp * self.omega * c + 0.0  # (+ 0.0: no -0.0 on a still axis)
        acc = 0.0 - self._amp * self.omega * self.omega * s
        return pos, vel, acc, np.full(n, self.yaw), np.zeros(n)


# --------------------------------------------------------------------------- waypoints


class Waypoints(Trajectory):
    """Straight segments through ``points`` (K x 3, NED) with minimum-jerk timing.

    Along each segment the path parameter follows 10 s^3 - 15 s^4 + 6 s^5 of normalised time,
    so velocity and acceleration are zero at every waypoint and continuous everywhere.
    Give either ``speed`` (each segment lasts T = 1.875 * length / speed, so its peak speed is
    exactly ``speed``) or ``durations`` (K-1 segment times). ``dwell`` seconds are spent at
    each interior waypoint.

    ``yaw``: a constant (None: 0); K per-waypoint yaws, blended along each segment with the
    same quintic the shortest way round; or 'tangent' to face along each segment (turning
    during the dwell at interior waypoints, or stepping there if dwell = 0).
    """

    def __init__(self, points, speed=None, durations=None, yaw=None, dwell: float = 0.0):
        owner = type(self).__name__
        try:
            p = np.array(points, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{owner}: points must be a K x 3 array of numbers") from None
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
            raise ValueError(f"{owner}: points must be K x 3 with K >= 2, got shape {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{owner}: points must be finite")
        k = p.shape[0]
        lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)

        if (speed is None) == (durations is None):
            raise ValueError(f"{owner}: give exactly one of speed or durations")
        if speed is not None:
            self.speed = _number(owner, "speed", speed, positive=True)
            if np.any(lengths == 0.0):
                i = int(np.argmax(lengths == 0.0))
                raise ValueError(
                    f"{owner}: points {i} and {i + 1} coincide; with speed every segment "
                    "needs a length (use dwell or durations to hold)"
                )
            seg_t = MIN_JERK_PEAK * lengths / self.speed
        else:
            self.speed = None
            try:
                seg_t = np.array(durations, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise ValueError(f"{owner}: durations must be {k - 1} numbers") from None
            if seg_t.shape != (k - 1,):
                raise ValueError(f"{owner}: durations must have {k - 1} elements, got {seg_t.size}")
            if not np.all(np.isfinite(seg_t) & (seg_t > 0.0)):
                raise ValueError(f"{owner}: durations must be finite and > 0, got {durations!r}")
        self.dwell = _number(owner, "dwell", dwell, nonneg=True)
        self.points = p
        self.segment_durations = seg_t

        seg_yaw0, seg_yaw1, dwell_yaw = self._yaw_plan(owner, yaw, p)

        # Phases: move along segment i, then (at interior waypoints) dwell.
        t0, p0, p1, y0, y1, arrivals = [], [], [], [], [], [0.0]
        clock = 0.0
        for i in range(k - 1):
            t0.append(seg_t[i])
            p0.append(p[i])
            p1.append(p[i + 1])
            y0.append(seg_yaw0[i])
            y1.append(seg_yaw1[i])
            clock += seg_t[i]
            arrivals.append(clock)
            if self.dwell > 0.0 and i + 1 < k - 1:
                t0.append(self.dwell)
                p0.append(p[i + 1])
                p1.append(p[i + 1])
                y0.append(dwell_yaw[i][0])
                y1.append(dwell_yaw[i][1])
                clock += self.dwell
        self._T = np.array(t0)
        self._start = np.concatenate([[0.0], np.cumsum(self._T)[:-1]])
        self._end = self._start + self._T
        self._p0 = np.array(p0)
        self._p1 = np.array(p1)
        self._y0 = np.array(y0)
        self._dy = np.array(y1) - self._y0
        self.arrival_times = np.array(arrivals)  # when each waypoint is reached (before dwell)
        self.duration = float(self._end[-1])

    @staticmethod
    def _yaw_plan(owner, yaw, p):
        """Yaw at the start/end of each segment and of each interior dwell (unwrapped)."""
        k = p.shape[0]
        if isinstance(yaw, str) and yaw == "tangent":
            d = np.diff(p[:, :2], axis=0)
            flat = np.hypot(d[:, 0], d[:, 1]) > 1e-9
            head = np.where(flat, np.arctan2(d[:, 1], d[:, 0]), np.nan)
            if not np.any(flat):
                head[:] = 0.0
            else:
                # Vertical legs keep the neighbouring heading (the next one before the first leg).
                first = int(np.argmax(flat))
                head[:first] = head[first]
                for i in range(first + 1, k - 1):
                    if not flat[i]:
                        head[i] = head[i - 1]
            head = head[0] + np.concatenate([[0.0], np.cumsum(_wrap(np.diff(head)))])
            dwell = [(head[i], head[i + 1]) for i in range(k - 2)]
            return head, head, dwell
        if yaw is None or np.ndim(yaw) == 0:
            c = _yaw_mode(owner, yaw)
            return np.full(k - 1, c), np.full(k - 1, c), [(c, c)] * (k - 2)
        wy = _vector(owner, "yaw", yaw, k)
        wy = wy[0] + np.concatenate([[0.0], np.cumsum(_wrap(np.diff(wy)))])
        dwell = [(wy[i + 1], wy[i + 1]) for i in range(k - 2)]
        return wy[:-1], wy[1:], dwell

    def _eval(self, t):
        i = np.clip(np.searchsorted(self._start, t, side="right") - 1, 0, self._T.size - 1)
        T = self._T[i]
        done = t >= self._end[i]
        s = np.where(done, 1.0, (t - self._start[i]) / T)
        q, dq, ddq = _min_jerk(s)
        p0, p1 = self._p0[i], self._p1[i]
        dp = p1 - p0
        pos = np.where(done[:, None], p1, p0 + dp * q[:, None])
        vel = dp * (dq / T)[:, None]
        acc = dp * (ddq / (T * T))[:, None]
        yaw = self._y0[i] + self._dy[i] * q
        yaw_rate = self._dy[i] * dq / T
        return pos, vel, acc, yaw, yaw_rate


class Takeoff(Waypoints):
    """Vertical minimum-jerk climb from ``from_pos`` to ``altitude`` metres above ground.

    Give ``duration`` or ``speed`` (peak climb speed).
    """

    def __init__(self, from_pos, altitude: float, duration=None, speed=None, yaw: float = 0.0):
        start = _vector("Takeoff", "from_pos", from_pos, 3)
        alt = _number("Takeoff", "altitude", altitude, nonneg=True)
        if -start[2] == alt:
            raise ValueError(f"Takeoff: altitude {alt} equals the starting altitude")
        if (duration is None) == (speed is None):
            raise ValueError("Takeoff: give exactly one of duration or speed")
        if duration is not None:
            duration = [_number("Takeoff", "duration", duration, positive=True)]
        else:
            speed = _number("Takeoff", "speed", speed, positive=True)
        end = np.array([start[0], start[1], -alt])
        super().__init__(
            [start, end], speed=speed, durations=duration, yaw=_number("Takeoff", "yaw", yaw)
        )


class Land(Waypoints):
    """Vertical minimum-jerk descent from ``from_pos`` to the ground (z = 0) at peak ``speed``.

    With ``final_speed``, the last ``final_height`` metres are a second leg at that peak speed:
    an altitude estimate off by a few tenths of a metre then meets the ground slowly, whichever
    way it is off.  The reference ends on the ground with zero velocity; detecting touchdown
    and disarming belong to the mission, not to the reference.
    """

    def __init__(self, from_pos, speed: float, yaw: float = 0.0, final_speed=None,
                 final_height: float = 0.5):
        start = _vector("Land", "from_pos", from_pos, 3)
        if not start[2] < 0.0:
            raise ValueError(f"Land: from_pos must be above the ground (z < 0), got z = {start[2]}")
        speed = _number("Land", "speed", speed, positive=True)
        end = np.array([start[0], start[1], 0.0])
        yaw = _number("Land", "yaw", yaw)
        if final_speed is None or _number("Land", "final_speed", final_speed,
                                          positive=True) >= speed:
            super().__init__([start, end], speed=speed, yaw=yaw)
            return
        final_height = _number("Land", "final_height", final_height, positive=True)
        if -start[2] <= final_height:
            super().__init__([start, end], speed=final_speed, yaw=yaw)
            return
        mid = np.array([start[0], start[1], -final_height])
        durations = [MIN_JERK_PEAK * (mid[2] - start[2]) / speed,
                     MIN_JERK_PEAK * final_height / final_speed]
        super().__init__([start, mid, end], durations=durations, yaw=yaw)


class Doublets(Trajectory):
    """Acceleration doublets about a fixed point, one axis after the other, then optionally a
    drag leg: the excitation an input model is identified from (:mod:`mavadrc.design.identify`).

    On each axis in ``axes`` (0 north, 1 east, 2 down) the acceleration is ``repeats`` times the
    pattern +A, -A, -A, +A, each held ``half_period`` s, then ``rest`` s of nothing before the
    next axis.  Velocity and position are its exact integrals, so the reference comes back to
    ``position`` after every doublet: the peak excursion is A half_period^2 and the peak
    speed A half_period (1 m/s^2, 0.4 s: 0.16 m, 0.4 m/s).  A controller tracking it commands
    the doublets as feed-forward, and its feedback has little to add.

    ``leg``: (north, east) speed (m/s; None or zeros: no leg) of a horizontal leg out and back
    after the doublets: up to speed in ``leg_ramp`` s at constant acceleration, ``leg_cruise``
    s at that speed, through the reverse speed in twice the ramp, ``leg_cruise`` s back, to
    rest in a ramp, then ``rest`` s still; it ends where it began.  At constant speed the
    vehicle's commanded acceleration is its drag plus the wind, whatever its response's lag:
    :attr:`leg_windows` (start, end) are the last ``leg_window`` s of each cruise, where it is
    read.

    ``hold``: s of stillness at the very end, after what is read (:attr:`fit_end`): the
    vehicle waits there, at rest, while the fit is made.
    """

    PATTERN = (1.0, -1.0, -1.0, 1.0)

    def __init__(self, position, amplitude=(1.0, 1.0, 1.0), half_period: float = 0.4,
                 repeats: int = 2, rest: float = 1.0, axes=(0, 1, 2), yaw: float = 0.0,
                 leg=None, leg_ramp: float = 0.8, leg_cruise: float = 2.0,
                 leg_window: float = 1.2, hold: float = 0.0):
        self.position = _vector("Doublets", "position", position, 3)
        amp = np.broadcast_to(np.asarray(amplitude, dtype=float), 3)
        if not np.all(np.isfinite(amp)) or np.any(amp <= 0.0):
            raise ValueError(f"Doublets: amplitude must be > 0 m/s^2, got {amplitude!r}")
        hp = _number("Doublets", "half_period", half_period, positive=True)
        rest = _number("Doublets", "rest", rest, nonneg=True)
        self.yaw = _number("Doublets", "yaw", yaw)
        if int(repeats) < 1:
            raise ValueError(f"Doublets: repeats must be >= 1, got {repeats!r}")
        # piecewise-constant acceleration: (start time, axis, value); velocity and position
        # are zero at every piece that starts a doublet, so each piece starts from its own
        # integrals, kept below
        t, pieces = 0.0, []
        self.windows = []  # (axis, t_start, t_end) of each axis's excitation and rest
        for ax in axes:
            t_ax = t
            for _ in range(int(repeats)):
                for sign in self.PATTERN:
                    pieces.append((t, int(ax), sign * float(amp[int(ax)])))
                    t += hp
            pieces.append((t, int(ax), 0.0))
            t += rest
            self.windows.append((int(ax), t_ax, t))
        self.doublets_end = t
        self._t = np.array([p[0] for p in pieces])
        self._ax = np.array([p[1] for p in pieces])
        self._a = np.array([p[2] for p in pieces])
        self._v0 = np.zeros(len(pieces))
        self._p0 = np.zeros(len(pieces))
        for i in range(1, len(pieces)):
            if self._ax[i] == self._ax[i - 1]:
                d = self._t[i] - self._t[i - 1]
                self._v0[i] = self._v0[i - 1] + self._a[i - 1] * d
                self._p0[i] = self._p0[i - 1] + self._v0[i - 1] * d + 0.5 * self._a[i - 1] * d * d
        # rounding aside, every axis ends back at rest at its start
        self._v0[np.abs(self._v0) < 1e-12] = 0.0
        self.leg = np.zeros(2) if leg is None else np.array(
            _vector("Doublets", "leg", leg, 2), dtype=float)
        self.leg_windows = []
        if np.any(self.leg != 0.0):
            r = _number("Doublets", "leg_ramp", leg_ramp, positive=True)
            cruise = _number("Doublets", "leg_cruise", leg_cruise, positive=True)
            w = min(_number("Doublets", "leg_window", leg_window, positive=True), cruise)
            # the leg's acceleration (in units of leg / leg_ramp) from each time on
            self._leg_t = t + np.cumsum([0.0, r, cruise, 2.0 * r, cruise, r])
            self._leg_a = np.array([1.0, 0.0, -1.0, 0.0, 1.0, 0.0]) / r
            v, p, v0, p0 = 0.0, 0.0, [], []
            for k in range(len(self._leg_t)):
                v0.append(v)
                p0.append(p)
                if k + 1 < len(self._leg_t):
                    d = self._leg_t[k + 1] - self._leg_t[k]
                    p += v * d + 0.5 * self._leg_a[k] * d * d
                    v += self._leg_a[k] * d
            self._leg_v0, self._leg_p0 = np.array(v0), np.array(p0)
            self.leg_windows = [(self._leg_t[2] - w, self._leg_t[2]),
                                (self._leg_t[4] - w, self._leg_t[4])]
            t = self._leg_t[-1] + rest
        self.fit_end = t
        self.duration = t + _number("Doublets", "hold", hold, nonneg=True)

    def _eval(self, t):
        n = t.shape[0]
        i = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, len(self._t) - 1)
        d = t - self._t[i]
        pos = np.tile(self.position, (n, 1))
        vel = np.zeros((n, 3))
        acc = np.zeros((n, 3))
        rows = np.arange(n)
        ax = self._ax[i]
        acc[rows, ax] = self._a[i]
        vel[rows, ax] = self._v0[i] + self._a[i] * d
        pos[rows, ax] += self._p0[i] + self._v0[i] * d + 0.5 * self._a[i] * d * d
        if self.leg_windows:
            on = t >= self.doublets_end
            if on.any():
                tl = np.minimum(t[on], self._leg_t[-1])
                k = np.clip(np.searchsorted(self._leg_t, tl, side="right") - 1, 0,
                            len(self._leg_t) - 1)
                d = tl - self._leg_t[k]
                a = self._leg_a[k] * (t[on] <= self._leg_t[-1])
                s_v = self._leg_v0[k] + self._leg_a[k] * d
                s_p = self._leg_p0[k] + self._leg_v0[k] * d + 0.5 * self._leg_a[k] * d * d
                acc[on] = 0.0
                vel[on] = 0.0
                pos[on] = self.position
                acc[on, :2] = np.outer(a, self.leg)
                vel[on, :2] = np.outer(s_v, self.leg)
                pos[on, :2] += np.outer(s_p, self.leg)
        return pos, vel, acc, np.full(n, self.yaw), np.zeros(n)


# --------------------------------------------------------------------------- sequence


class Sequence(Trajectory):
    """Trajectories played one after the other, each in its own time starting at 0.

    All parts but the last must be finite; the last may be open-ended. By default a position
    jump larger than ``join_tol`` metres between one part's end and the next part's start is
    refused (set ``join_tol=math.inf`` to allow it). At a join time the later part is used.
    """

    def __init__(self, parts, join_tol: float = 1e-6):
        parts = list(parts)
        if not parts:
            raise ValueError("Sequence: parts must not be empty")
        for i, part in enumerate(parts):
            if not isinstance(part, Trajectory):
                raise ValueError(f"Sequence: parts[{i}] is not a Trajectory: {part!r}")
            if i < len(parts) - 1 and not math.isfinite(part.duration):
                raise ValueError(f"Sequence: parts[{i}] is open-ended; only the last part may be")
        self.join_tol = _number("Sequence", "join_tol", join_tol, nonneg=True, allow_inf=True)
        for i in range(len(parts) - 1):
            end = parts[i].sample(parts[i].duration).pos
            start = parts[i + 1].sample(0.0).pos
            jump = float(np.linalg.norm(start - end))
            if jump > self.join_tol:
                raise ValueError(
                    f"Sequence: parts[{i}] ends at {end.tolist()} but parts[{i + 1}] starts at "
                    f"{start.tolist()} ({jump:.3g} m jump > join_tol)"
                )
        self.parts = tuple(parts)
        durations = np.array([p.duration for p in parts])
        self.start_times = np.concatenate([[0.0], np.cumsum(durations)[:-1]])  # part k begins
        self.duration = float(np.sum(durations))

    def _eval(self, t):
        n = t.shape[0]
        last = len(self.parts) - 1
        idx = np.clip(np.searchsorted(self.start_times, t, side="right") - 1, 0, last)
        if n == 1:  # one time: its part alone
            k = int(idx[0])
            return self.parts[k].sample_many(t - self.start_times[k])
        pos, vel, acc = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        yaw, yaw_rate = np.empty(n), np.empty(n)
        for k in np.unique(idx):
            m = idx == k
            out = self.parts[k].sample_many(t[m] - self.start_times[k])
            pos[m], vel[m], acc[m], yaw[m], yaw_rate[m] = out
        return pos, vel, acc, yaw, yaw_rate


# --------------------------------------------------------------------------- named


_NAMED = {
    "hover": (Hover, dict(position=(0.0, 0.0, -1.0), yaw=0.0)),
    "thesis_circle": (
        Circle,
        dict(radius=10.0, speed=2.0, altitude=1.0, yaw=math.pi / 6.0, clockwise=True),
    ),
    "thesis_spiral_pd": (
        Spiral,
        dict(radius=10.0, omega=0.1, z0=0.0, climb=0.1, yaw=math.pi / 6.0),
    ),
    "thesis_spiral": (
        Spiral,
        dict(radius=10.0, omega=0.5, z0=1.0, climb=0.1, yaw=math.pi / 6.0),
    ),
    "figure_eight": (FigureEight, dict(a=5.0, period=20.0, altitude=2.0, yaw=0.0)),
    "figure_eight_vertical": (
        FigureEight,
        dict(a=1.25, b=0.75, period=2.0 * math.pi, altitude=2.0, yaw=0.0, plane="vertical"),
    ),
}


def list_names() -> list[str]:
    """Names accepted by ``by_name``."""
    return sorted(_NAMED)


def by_name(name: str, **overrides) -> Trajectory:
    """A named trajectory (see the module docstring), with constructor arguments overridden.

    Example: ``by_name("thesis_circle", speed=8.0)``.
    """
    if name not in _NAMED:
        raise ValueError(f"name: unknown trajectory {name!r}; known: {', '.join(list_names())}")
    cls, defaults = _NAMED[name]
    accepted = inspect.signature(cls).parameters
    unknown = sorted(set(overrides) - set(accepted))
    if unknown:
        raise ValueError(
            f"{name}: unknown parameter(s) {', '.join(unknown)}; "
            f"accepted: {', '.join(accepted)}"
        )
    return cls(**{**defaults, **overrides})
