"""A downward range finder beside the height estimate: a height the loop does not fly on.

The loop holds the autopilot's height estimate on its reference; when that estimate drifts, the
vehicle follows the drift and no error shows it.  A vehicle with a downward range finder says
on the link how high it really is above the ground under it (DISTANCE_SENSOR, orientation
MAV_SENSOR_ROTATION_PITCH_270; PX4 streams it on its onboard link at 10 Hz, PX4 SIH simulates
one).  Over flat ground that is the height above the takeoff spot, to be set beside the
estimate's:

- the flight's record says how far the estimate strayed from it (``summary.json``'s
  ``rangefinder``, and a console line), as :mod:`mavadrc.flight.truth` does with a simulator's truth;
- the supervisor ends the mission when the range finder reads the vehicle under
  ``safety.min_clearance`` while the estimate reads it :data:`CLEARANCE_GAP_M` higher, for
  :data:`CLEARANCE_HOLD_S`: the estimate is off and the ground is near (on PX4 SIH, with its
  GNSS height reference, the estimate read level while the vehicle sank 0.9 m in the thesis
  spiral's run-up at 1 m, into the ground at 2.5 m/s).

A reading counts only inside the sensor's own span (``min_distance`` to ``max_distance``), with
a signal not marked invalid (``signal_quality`` 1), tilted less than 60 deg; it is taken to the
vertical with the tilt of the newest ATTITUDE.  The two heights are aligned once, at rest
before the mission (the sensor's mounting height and the estimate's origin), as the truth is;
a range finder that reads nothing at rest (the ground under its ``min_distance``) is not
aligned, and says so.  Over anything but flat ground (a slope, a table, tall grass) the range
finder measures the ground under the vehicle, not the takeoff spot: the record says what it
measured, and the clearance check is a check of the ground below, as it should be.
"""

import math
from collections import deque

import numpy as np

#: MAV_SENSOR_ROTATION_PITCH_270: a range finder looking down
DOWN = 25
#: the rate a flight asks for DISTANCE_SENSOR at (Hz; PX4's own on its onboard link)
RANGE_HZ = 10.0
#: readings at rest the alignment averages (1 s at PX4's 10 Hz)
REST_SAMPLES = 10
#: the estimate must read the vehicle at least this much higher than the range finder (m) ...
CLEARANCE_GAP_M = 0.3
#: ... for this long (s of the vehicle's clock) under ``safety.min_clearance`` to end the mission
CLEARANCE_HOLD_S = 0.3
#: a reading tilted past this (cos of the tilt, 60 deg) is not taken to the vertical
MIN_COS_TILT = 0.5
#: a reading younger than this (s of the vehicle's clock, three of PX4's 10 Hz) has a say in
#: whether the vehicle has lifted off
RANGE_FRESH_S = 0.3


def range_height(msg, cos_tilt):
    """The height above the ground (m, vertical) a DISTANCE_SENSOR reads, or None: not looking
    down, outside its own span, its signal marked invalid, or tilted past 60 deg."""
    if msg.orientation != DOWN:
        return None
    d = msg.current_distance
    if d < msg.min_distance or d > msg.max_distance or d == 0xFFFF:
        return None
    if getattr(msg, "signal_quality", 0) == 1:
        return None
    if not cos_tilt >= MIN_COS_TILT:
        return None
    return d * 0.01 * cos_tilt


class RangeTrack:
    """The range finder's heights of one flight beside the estimate's (both above the takeoff
    spot), once aligned."""

    def __init__(self):
        self._rest = deque(maxlen=REST_SAMPLES)  # estimate - range finder, at rest
        self.offset = None
        self.aligned = None
        self.t, self.estimate, self.range = [], [], []
        self._low_since = None
        self._latest = None  # (vehicle s, m) the newest valid reading

    def at_rest(self, est_h, rng_h):
        """A reading before the mission, the vehicle at rest on the ground."""
        self._rest.append(est_h - rng_h)

    def read(self, t_vehicle, rng_h):
        """The newest valid reading (``t_vehicle``: the vehicle's clock, s), in any phase."""
        self._latest = (t_vehicle, rng_h)

    def height_up(self, t_vehicle):
        """How far (m) the newest reading is above the readings at rest before the mission
        (the takeoff spot's ground), or None: no reading at rest, or none within
        :data:`RANGE_FRESH_S` before ``t_vehicle``."""
        if self._latest is None or not self._rest:
            return None
        t_r, h = self._latest
        if t_vehicle - t_r > RANGE_FRESH_S:
            return None
        return h + float(np.mean(self._rest))  # the rest holds estimate 0 minus each reading

    def start(self, in_air=False):
        """The alignment fixed from the readings kept: at rest before the mission, or, for a
        flight taken over in the air (``in_air``), its first ones in the mission."""
        if not self._rest:
            self.offset = 0.0
            self.aligned = ("not aligned: no reading at rest (the ground under the sensor's "
                            "minimum distance, or no sensor yet); the takeoff spot's ground "
                            "taken as the range finder's zero")
            return
        self.offset = float(np.mean(self._rest))
        where = ("in the air, on the first {} readings (the flight taken over there)" if in_air
                 else "at rest before the mission ({} readings)").format(len(self._rest))
        self.aligned = (f"{where}: the estimate read {self.offset:+.3f} m from the range finder "
                        "there")

    def add(self, t, est_h, rng_h, in_air=False):
        """A reading at mission time ``t``; returns the estimate's height above it (m), or None
        while a flight taken over in the air (``in_air``, no reading at rest) is still aligning
        on its first :data:`REST_SAMPLES` readings."""
        if self.offset is None:
            if in_air:
                self._rest.append(est_h - rng_h)
                if len(self._rest) < REST_SAMPLES:
                    return None
            self.start(in_air)
        self.t.append(t)
        self.estimate.append(est_h - self.offset)
        self.range.append(rng_h)
        return est_h - self.offset - rng_h

    def clearance(self, t_vehicle, gap, rng_h, min_clearance, airborne):
        """Why the mission must end (None otherwise): airborne, the range finder under
        ``min_clearance`` (m) while the estimate reads :data:`CLEARANCE_GAP_M` more (``gap``,
        what :meth:`add` returned; None while not aligned: nothing checked), for
        :data:`CLEARANCE_HOLD_S` of the vehicle's clock ``t_vehicle``."""
        low = gap is not None and bool(min_clearance) and airborne and rng_h < min_clearance \
            and gap > CLEARANCE_GAP_M
        if not low:
            self._low_since = None
            return None
        if self._low_since is None:
            self._low_since = t_vehicle
        if t_vehicle - self._low_since < CLEARANCE_HOLD_S:
            return None
        return (f"the range finder reads the vehicle {rng_h:.2f} m above the ground where its "
                f"height estimate reads {rng_h + gap:.2f} m (safety.min_clearance "
                f"{min_clearance:g} m): "
                "the estimate is off and the ground is near")

    def figures(self, settle_s=0.0):
        """summary.json's ``rangefinder``: how far the estimate's height was from the range
        finder's (estimate minus range finder), over the mission and after settling."""
        if not self.t:
            return None
        t = np.asarray(self.t)
        diff = np.asarray(self.estimate) - np.asarray(self.range)
        out = {"source": "DISTANCE_SENSOR (downward)", "samples": int(t.size),
               "rate_hz": (float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 and t[-1] > t[0]
                           else None),
               "aligned": self.aligned,
               "max_difference_m": float(np.max(np.abs(diff))),
               "rms_difference_m": float(math.sqrt(np.mean(diff ** 2))),
               "mean_difference_m": float(np.mean(diff)),
               "lowest_m": float(np.min(self.range))}
        after = t >= settle_s
        if settle_s > 0 and after.any():
            d = diff[after]
            out["after_settle"] = {"max_difference_m": float(np.max(np.abs(d))),
                                   "rms_difference_m": float(math.sqrt(np.mean(d ** 2)))}
        return out


def rangefinder_text(fig, settle_s=0.0):
    """The console's line for :meth:`RangeTrack.figures`."""
    part = fig.get("after_settle") if settle_s > 0 else None
    when = f" after settling ({settle_s:g} s)" if part else ""
    fig_ = part or fig
    return (f"against the downward range finder ({fig['samples']} readings): the height "
            f"estimate was off by up to {fig_['max_difference_m']:.3f} m (rms "
            f"{fig_['rms_difference_m']:.3f} m){when}, {fig['mean_difference_m']:+.3f} m on "
            f"average over the mission; lowest reading {fig['lowest_m']:.2f} m (flat ground "
            "assumed)")
