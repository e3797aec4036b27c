"""A trajectory read from a CSV file (a mission's ``file:`` segment).

The file has a header row naming its columns, then one row per sample::

    # lines starting with # and blank lines are skipped
    t,north,east,altitude
    0.0,0.0,0.0,1.5
    0.1,0.02,0.0,1.5
    ...

Required columns: ``t`` (s from the segment's start: the first row is t = 0, the times increase
strictly), ``north``, ``east``, ``altitude`` (m in the mission's frame: from the takeoff spot,
altitude up, as a ``waypoints`` segment's points).  Optional, each group all or none:
``v_north, v_east, v_up`` (m/s), ``a_north, a_east, a_up`` (m/s^2), and ``yaw_deg``.

Between rows the reference is a quintic Hermite polynomial per interval through each row's
position, velocity and acceleration, so all three are continuous.  Given columns are used as
they are; a missing velocity or acceleration is the derivative, at the row, of an interpolating
quintic spline (``scipy.interpolate.make_interp_spline``, k = 5) through the positions (the
accelerations through the velocities when those are given).  With neither given, the Hermite
pieces are that spline itself.  The yaw is unwrapped the shortest way between rows and its rate
comes from the same spline.

Everything that can be wrong with the file is said with the file, its line, the data row
(counted from 1 after the header) and the column: :class:`TrajectoryFileError`.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mavadrc.mission.trajectories import Trajectory
from sim.yamlio import did_you_mean

REQUIRED = ("t", "north", "east", "altitude")
VELOCITY = ("v_north", "v_east", "v_up")
ACCELERATION = ("a_north", "a_east", "a_up")
YAW = "yaw_deg"
COLUMNS = REQUIRED + VELOCITY + ACCELERATION + (YAW,)
#: the spline that estimates a derivative is a quintic: it needs six rows
SPLINE_ROWS = 6
MAX_ROWS = 1_000_000
MAX_DURATION = 4 * 3600.0  # s, as a segment's duration
G = 9.80665
#: the vertical acceleration a file may ask, up or down (m/s^2): half a g of thrust margin
MAX_ACCEL_UP = 0.5 * G
#: points checked between two rows against the limits
CHECKS_PER_ROW = 8


class TrajectoryFileError(ValueError):
    """A trajectory file that cannot be flown; the message names the file, line, row, column."""


@dataclass
class Table:
    """The columns of a trajectory file, as read (no column is derived yet)."""

    path: str
    columns: dict  # name -> (n,) float array
    lines: np.ndarray  # the file line (1-based) of each data row
    header_line: int

    @property
    def rows(self):
        return int(self.lines.size)

    def where(self, row, column=None):
        """'PATH:LINE: row R, column C' for data row ``row`` (0-based here, 1-based in words)."""
        col = "" if column is None else f", column {column}"
        return f"{self.path}:{int(self.lines[row])}: row {row + 1}{col}"


def _header(path, row, line):
    names = [name.strip() for name in row]
    at = f"{path}:{line}: header"
    for i, name in enumerate(names):
        if name in names[:i]:
            raise TrajectoryFileError(f"{at}: column {name!r} is named twice")
        if name not in COLUMNS:
            raise TrajectoryFileError(
                f"{at}: column {name!r} is not a trajectory column{did_you_mean(name, COLUMNS)} "
                f"(columns: {', '.join(COLUMNS)})")
    for name in REQUIRED:
        if name not in names:
            raise TrajectoryFileError(f"{at}: column {name!r} missing (required: "
                                      f"{', '.join(REQUIRED)})")
    for group in (VELOCITY, ACCELERATION):
        given = [c for c in group if c in names]
        if given and len(given) < len(group):
            missing = next(c for c in group if c not in names)
            raise TrajectoryFileError(f"{at}: column {missing!r} missing: {given[0]} is given, "
                                      f"so give all of {', '.join(group)} (or none)")
    return names


def read_table(path) -> Table:
    """Read and check a trajectory file's header and values (not yet its limits)."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise TrajectoryFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TrajectoryFileError(f"{path}: not a CSV text file (byte {exc.start} is not "
                                  "UTF-8)") from None
    names, header_line, values, lines = None, None, [], []
    for number, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if names is None:
            names, header_line = _header(path, row, number), number
            continue
        r = len(values)
        if r >= MAX_ROWS:
            raise TrajectoryFileError(f"{path}:{number}: more than {MAX_ROWS} data rows")
        if len(row) != len(names):
            raise TrajectoryFileError(f"{path}:{number}: row {r + 1}: {len(row)} values for "
                                      f"{len(names)} columns ({', '.join(names)})")
        out = []
        for name, cell in zip(names, row):
            try:
                x = float(cell)
            except ValueError:
                raise TrajectoryFileError(f"{path}:{number}: row {r + 1}, column {name}: not a "
                                          f"number ({cell.strip()!r})") from None
            if not math.isfinite(x):
                raise TrajectoryFileError(f"{path}:{number}: row {r + 1}, column {name}: must "
                                          f"be finite (got {cell.strip()})")
            out.append(x)
        values.append(out)
        lines.append(number)
    if names is None:
        raise TrajectoryFileError(f"{path}: no header row (the first line that is not a "
                                  f"comment names the columns: {', '.join(REQUIRED)}, ...)")
    if len(values) < 2:
        raise TrajectoryFileError(f"{path}: {len(values)} data row(s); a trajectory needs at "
                                  "least 2")
    data = np.array(values, dtype=float)
    table = Table(str(path), {name: data[:, i] for i, name in enumerate(names)},
                  np.array(lines), header_line)
    t = table.columns["t"]
    if t[0] != 0.0:
        raise TrajectoryFileError(f"{table.where(0, 't')}: the first row must be at t = 0 "
                                  f"(times are from the segment's start; got {t[0]:g})")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        r = int(np.argmax(steps <= 0.0)) + 1
        raise TrajectoryFileError(f"{table.where(r, 't')}: times must increase strictly "
                                  f"(t = {t[r]:g} after {t[r - 1]:g} on row {r})")
    if t[-1] > MAX_DURATION:
        r = int(np.argmax(t > MAX_DURATION))
        raise TrajectoryFileError(f"{table.where(r, 't')}: past {MAX_DURATION:g} s, the longest "
                                  "a segment may last")
    return table


def _derivatives(t, y, order):
    """The ``order``-th derivative at the rows of the interpolating quintic spline through y."""
    from scipy.interpolate import make_interp_spline

    return make_interp_spline(t, y, k=5, axis=0).derivative(order)(t)


def _hermite(t, p, v, a):
    """Quintic Hermite coefficients (6, m, C) in s = (t - t_i) / h_i on each of the m
    intervals, through position, velocity and acceleration (n, C) at both ends."""
    h = np.diff(t)[:, None]
    p0, p1, v0, v1, a0, a1 = p[:-1], p[1:], v[:-1] * h, v[1:] * h, a[:-1] * h * h, a[1:] * h * h
    d = p1 - p0
    return np.stack([p0, v0, 0.5 * a0,
                     10.0 * d - 6.0 * v0 - 4.0 * v1 - 1.5 * a0 + 0.5 * a1,
                     -15.0 * d + 8.0 * v0 + 7.0 * v1 + 1.5 * a0 - a1,
                     6.0 * d - 3.0 * (v0 + v1) - 0.5 * (a0 - a1)])


class FileTrajectory(Trajectory):
    """The reference a trajectory file describes (module docstring), in the mission's frame
    (NED from the takeoff spot).  ``yaw`` (rad) is the heading when the file has no yaw_deg
    column."""

    def __init__(self, table: Table, yaw: float = 0.0):
        cols, t = table.columns, table.columns["t"]
        self.table = table
        self.given = {"velocity": VELOCITY[0] in cols, "acceleration": ACCELERATION[0] in cols,
                      "yaw": YAW in cols}
        estimated = not (self.given["velocity"] and self.given["acceleration"]) \
            or self.given["yaw"]
        if estimated and table.rows < SPLINE_ROWS:
            raise TrajectoryFileError(
                f"{table.path}: {table.rows} data rows; the spline that estimates the "
                f"derivatives the file does not give needs at least {SPLINE_ROWS} (give "
                f"{', '.join(VELOCITY + ACCELERATION)}, or more rows)")
        up = np.array([1.0, 1.0, -1.0])  # north, east, up -> NED
        pos = np.stack([cols["north"], cols["east"], cols["altitude"]], axis=1) * up
        vel = np.stack([cols[c] for c in VELOCITY], axis=1) * up if self.given["velocity"] \
            else _derivatives(t, pos, 1)
        if self.given["acceleration"]:
            acc = np.stack([cols[c] for c in ACCELERATION], axis=1) * up
        else:
            acc = _derivatives(t, vel, 1) if self.given["velocity"] else _derivatives(t, pos, 2)
        n = t.size
        if self.given["yaw"]:
            psi = np.unwrap(np.radians(cols[YAW]))
            dpsi, ddpsi = _derivatives(t, psi, 1), _derivatives(t, psi, 2)
        else:
            psi, dpsi, ddpsi = np.full(n, float(yaw)), np.zeros(n), np.zeros(n)
        # channels: north, east, down, yaw (unwrapped)
        self._t = t
        self._h = np.diff(t)
        self._c = _hermite(t, np.column_stack([pos, psi]), np.column_stack([vel, dpsi]),
                           np.column_stack([acc, ddpsi]))
        k = np.arange(6.0)[:, None, None]
        self._dc = (k * self._c)[1:]  # d/ds
        self._ddc = (k[:5] * self._dc)[1:]  # d2/ds2
        self.duration = float(t[-1])

    def _eval(self, t):
        i = np.clip(np.searchsorted(self._t, t, side="right") - 1, 0, self._h.size - 1)
        h = self._h[i][:, None]
        s = ((t - self._t[i]) / self._h[i])[:, None]
        c, dc, ddc = self._c[:, i], self._dc[:, i], self._ddc[:, i]  # (k, N, channels)
        p, v, a = c[5], dc[4], ddc[3]
        for k in range(4, -1, -1):  # Horner's rule
            p = c[k] + s * p
            if k > 0:
                v = dc[k - 1] + s * v
            if k > 1:
                a = ddc[k - 2] + s * a
        v = v / h
        a = a / (h * h)
        return p[:, :3], v[:, :3], a[:, :3], p[:, 3], v[:, 3]

    # -- limits ---------------------------------------------------------------------------------

    def _source(self, order, axes):
        """The columns a velocity (order 1) or acceleration (2) on ``axes`` comes from."""
        if order == 1 and self.given["velocity"]:
            return ", ".join(VELOCITY[k] for k in axes)
        if order == 2 and self.given["acceleration"]:
            return ", ".join(ACCELERATION[k] for k in axes)
        if order == 2 and self.given["velocity"]:
            return f"{', '.join(VELOCITY[k] for k in axes)} (their spline's derivative)"
        return f"{', '.join(REQUIRED[1 + k] for k in axes)} (their spline's " \
               f"{'velocity' if order == 1 else 'acceleration'})"

    def check_limits(self, geofence_north, geofence_east, altitude_range, max_speed,
                     max_accel_horizontal, max_accel_up=MAX_ACCEL_UP):
        """Refuse a file whose reference leaves the geofence or the altitude limits, or goes
        faster or accelerates harder than the limits, at a row or between two (checked at
        :data:`CHECKS_PER_ROW` points per interval); the error names the row and column of the
        earliest breach."""
        frac = np.arange(CHECKS_PER_ROW) / CHECKS_PER_ROW
        t = np.append((self._t[:-1, None] + self._h[:, None] * frac).ravel(), self._t[-1])
        pos, vel, acc = self._eval(t)[:3]
        north, east, alt = pos[:, 0], pos[:, 1], -pos[:, 2]
        speed = np.linalg.norm(vel, axis=1)
        acc_h, acc_up = np.hypot(acc[:, 0], acc[:, 1]), -acc[:, 2]
        v_cols = self._source(1, (0, 1, 2))
        tests = [
            (north, lambda x: (x < geofence_north[0]) | (x > geofence_north[1]), "north",
             "north {:.2f} m is outside the geofence [{:g}, {:g}] m",
             tuple(geofence_north)),
            (east, lambda x: (x < geofence_east[0]) | (x > geofence_east[1]), "east",
             "east {:.2f} m is outside the geofence [{:g}, {:g}] m", tuple(geofence_east)),
            (alt, lambda x: (x < altitude_range[0]) | (x > altitude_range[1]), "altitude",
             "altitude {:.2f} m is outside the limits [{:g}, {:g}] m", tuple(altitude_range)),
            (speed, lambda x: x > max_speed, v_cols,
             "speed {:.2f} m/s exceeds safety.max_speed {:g} m/s", (max_speed,)),
            (acc_h, lambda x: x > max_accel_horizontal, self._source(2, (0, 1)),
             "horizontal acceleration {:.2f} m/s^2 exceeds {:.2f} m/s^2 (g tan(tilt_max_deg): "
             "what the tilt limit allows)", (max_accel_horizontal,)),
            (acc_up, lambda x: np.abs(x) > max_accel_up, self._source(2, (2,)),
             "vertical acceleration {:.2f} m/s^2 exceeds {:.2f} m/s^2 (half a g, up or down)",
             (max_accel_up,)),
        ]
        found = []  # (first sample breaking it, the test): the earliest is said
        for k, (values, bad, column, text, bounds) in enumerate(tests):
            mask = bad(values)
            if mask.any():
                found.append((int(np.argmax(mask)), k))
        if not found:
            return
        j, k = min(found)
        values, _, column, text, bounds = tests[k]
        row, part = divmod(j, CHECKS_PER_ROW)
        reason = text.format(values[j], *bounds)
        if part == 0:
            where = self.table.where(row, column)
        else:
            where = (f"{self.table.path}:{int(self.table.lines[row])}: between rows "
                     f"{row + 1} and {row + 2} (t = {t[j]:.3f} s), column {column}")
        raise TrajectoryFileError(f"{where}: {reason}")
