"""A simulator's true state beside the autopilot's estimate: how far the vehicle really was from
its reference, and how far the estimate the loop flew on was from the vehicle.

The summary's errors are those of the estimate the autopilot reports (LOCAL_POSITION_NED): the
only position a real vehicle offers.  A simulator knows better, and several say so on the link:

- PX4's SIH (and the bundled vehicle as PX4) streams HIL_STATE_QUATERNION from its ground-truth
  topics when asked (SET_MESSAGE_INTERVAL; a real PX4 has no ground truth and sends nothing);
- ArduPilot's SITL (and the bundled vehicle as ArduPilot) streams SIM_STATE.

Each gives latitude, longitude and altitude; each simulator projects its local frame on its own
sphere (PX4 6371 km, ArduPilot 6378.137 km), and the same radius takes them back here, so the
true track is exact to the centimetre over the ranges flown.  Neither message carries a usable
time (PX4 leaves HIL_STATE_QUATERNION's time_usec 0): a true sample is timed by its arrival
after the last position sample, on the same link (in lockstep, the period of that sample).

The true track is aligned to the estimate's frame once, where both must agree: the mean
difference over the last :data:`REST_SAMPLES` pairs before the mission starts (the vehicle at
rest on the ground); a flight taken over in the air aligns on its first ones instead, and says
so.  A constant offset of the estimate at start (its origin) is thereby not counted; everything
it does after, drift and noise, is.
"""

import math
from collections import deque

import numpy as np

from mavadrc.flight.record import error_figures

#: the message each autopilot's simulator sends its true state in, and the earth radius (m) it
#: projects its local frame with (PX4: CONSTANTS_RADIUS_OF_EARTH; ArduPilot: the radius of its
#: LOCATION_SCALING_FACTOR)
SOURCES = {"HIL_STATE_QUATERNION": 6371000.0, "SIM_STATE": 6378137.0}
#: how often the true state is asked for (Hz; the control rate if lower)
TRUTH_HZ = 50.0
#: the pairs (estimate, truth) the alignment averages
REST_SAMPLES = 25


def true_state(msg):
    """(latitude deg, longitude deg, altitude m AMSL, NED velocity m/s) of a HIL_STATE_QUATERNION
    or SIM_STATE, or None when it holds no position (a simulator not yet initialised)."""
    if msg.get_type() == "HIL_STATE_QUATERNION":
        if msg.lat == 0 and msg.lon == 0:
            return None
        return (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01))
    lat_i, lon_i = getattr(msg, "lat_int", 0), getattr(msg, "lon_int", 0)
    if lat_i or lon_i:
        lat, lon = lat_i * 1e-7, lon_i * 1e-7
    else:
        # ArduPilot sends the floats in 1e-7 deg; the message's definition says deg
        lat, lon = msg.lat, msg.lon
        if abs(lat) > 90.0 or abs(lon) > 180.0:
            lat, lon = lat * 1e-7, lon * 1e-7
        if lat == 0.0 and lon == 0.0:
            return None
    return lat, lon, float(msg.alt), (float(msg.vn), float(msg.ve), float(msg.vd))


def reference_at(ts, t, ref):
    """The reference ``ref`` (N, 3), flown at times ``t``, at the true samples' times ``ts``
    (linear between steps)."""
    return np.column_stack([np.interp(ts, t, ref[:, i]) for i in range(3)])


class TruthTrack:
    """The true samples of one flight, in the estimate's frame once aligned."""

    def __init__(self, source, table=None):
        """``table``: None, or a callable giving the TableWriter of :data:`TRUTH_COLUMNS` the
        mission's true samples are written to (called with the first)."""
        if source not in SOURCES:
            raise ValueError(f"no true state in {source!r}; known: {', '.join(SOURCES)}")
        self.source = source
        self.radius = SOURCES[source]
        self._table = table
        self.table = None
        self._origin = None  # (lat, lon, alt) of the first true sample
        self._rest = deque(maxlen=REST_SAMPLES)
        self.offset = None  # estimate minus truth, once aligned
        self.aligned = None  # how
        self.received = 0
        self.t, self.pos, self.est = [], [], []

    def local(self, msg):
        """(NED position about the first true sample, NED velocity) of ``msg``; None if it
        holds no position."""
        st = true_state(msg)
        if st is None:
            return None
        lat, lon, alt, vel = st
        if self._origin is None:
            self._origin = (lat, lon, alt)
        lat0, lon0, alt0 = self._origin
        r = self.radius
        north = math.radians(lat - lat0) * r
        east = math.radians(lon - lon0) * r * math.cos(math.radians(lat0))
        return np.array([north, east, alt0 - alt]), np.array(vel, dtype=float)

    def at_rest(self, msg, estimate):
        """A true sample before the mission, beside the position ``estimate`` of that time."""
        got = self.local(msg)
        if got is None:
            return
        self.received += 1
        self._rest.append(np.asarray(estimate, dtype=float) - got[0])

    def start(self):
        """The mission starts: align on the pairs at rest (if any came)."""
        if self._rest and self.offset is None:
            self.offset = np.mean(self._rest, axis=0)
            self.aligned = (f"to the position estimate at rest before the mission "
                            f"(mean of {len(self._rest)} samples)")

    def add(self, t, msg, estimate):
        """A true sample at mission time ``t``, beside the position ``estimate`` then."""
        got = self.local(msg)
        if got is None:
            return
        self.received += 1
        pos, vel = got
        if self.offset is None:
            self._rest.append(np.asarray(estimate, dtype=float) - pos)
            if len(self._rest) < REST_SAMPLES:
                return
            self.offset = np.mean(self._rest, axis=0)
            self.aligned = (f"to the position estimate on the first {len(self._rest)} samples "
                            "of the mission (no samples at rest: taken over in the air)")
        pos = pos + self.offset
        self.t.append(float(t))
        self.pos.append(pos)
        self.est.append(np.asarray(estimate, dtype=float))
        if self._table is not None:
            if self.table is None:
                self.table = self._table(TRUTH_COLUMNS)
            self.table.row([float(t), *pos.tolist(), *vel.tolist()])

    def figures(self, t, ref, settle_s=0.0):
        """The true track's error against the reference ``ref`` (N, 3) flown at mission times
        ``t`` (the scored steps), over those steps' span, and the estimate's error against the
        truth; None without true samples in that span."""
        t = np.asarray(t, dtype=float)
        ts = np.asarray(self.t, dtype=float)
        if t.size < 2 or ts.size == 0:
            return None
        # only between two scored steps next to each other: not across the steps left out (the
        # identification's excitation, flown on another reference, is not scored)
        k = np.clip(np.searchsorted(t, ts), 1, t.size - 1)
        step = float(np.median(np.diff(t)))
        keep = (ts >= t[0]) & (ts <= t[-1]) & (t[k] - t[k - 1] <= 2.5 * step)
        if keep.sum() < 2:
            return None
        ts = ts[keep]
        pos = np.asarray(self.pos).reshape(-1, 3)[keep]
        est = np.asarray(self.est).reshape(-1, 3)[keep]
        ref = np.asarray(ref, dtype=float).reshape(-1, 3)
        r = reference_at(ts, t, ref)
        gaps = np.diff(ts)
        gaps = gaps[gaps > 0]
        out = {"source": self.source, "aligned": self.aligned, "samples": int(ts.size),
               # the rate they came at (not their count over the span: the steps left out
               # leave a hole in it)
               "rate_hz": float(1.0 / np.median(gaps)) if gaps.size else None}
        out.update(error_figures(ts, r, pos))
        if settle_s > 0:
            out["after_settle"] = error_figures(ts, r, pos, settle_s)
        miss = est - pos
        norm = np.linalg.norm(miss, axis=1)
        out["estimate_error"] = {
            "rms_m": float(np.sqrt(np.mean(norm ** 2))), "max_m": float(norm.max()),
            "rms_xyz_m": [float(v) for v in np.sqrt(np.mean(miss ** 2, axis=0))],
            "max_xyz_m": [float(v) for v in np.abs(miss).max(axis=0)]}
        after = ts >= settle_s
        out["estimate_error"]["wander"] = {
            "band_hz": list(WANDER_BAND_HZ), "from_s": float(settle_s),
            "rms_xyz_m": band_rms(ts[after], miss[after]),
            "error_rms_xyz_m": band_rms(ts[after], est[after] - r[after])}
        out["estimate_error"]["step"] = estimate_steps(ts[after], miss[after],
                                                       est[after] - r[after], settle_s)
        return out


#: the band (Hz) in which an estimate's own wander is measured: faster than a loop on a vehicle
#: that answers in 0.2-0.3 s can follow, slower than the true samples' arrival jitter reaches
#: (PX4 SIH's EKF2 output wandered 11-35 mm RMS per axis there in every phase of a flight, at
#: rest as at 5 m/s; the bundled vehicle's noisy estimate 1-2 mm)
WANDER_BAND_HZ = (0.3, 1.0)
#: the grid (Hz) the true samples are put on to be filtered, and the shortest stretch (s) of them
#: without a gap over :data:`WANDER_GAP_S` that is measured
WANDER_GRID_HZ = 20.0
WANDER_MIN_S = 10.0
WANDER_GAP_S = 0.25


def band_rms(ts, x, band=WANDER_BAND_HZ, grid_hz=WANDER_GRID_HZ, min_s=WANDER_MIN_S,
             gap_s=WANDER_GAP_S):
    """Per axis, the RMS (m) of ``x`` ((N, 3) at times ``ts``, s) in the frequency band
    ``band`` (Hz): each stretch of samples without a gap over ``gap_s`` and at least ``min_s``
    long, put on a ``grid_hz`` grid and band-passed forwards and backwards (a 2nd-order
    Butterworth on each edge), its power summed over the stretches; None per axis when no
    stretch is long enough."""
    from scipy.signal import butter, sosfiltfilt
    ts = np.asarray(ts, dtype=float)
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    if ts.size < 2:
        return [None] * 3
    cuts = np.flatnonzero(np.diff(ts) > gap_s) + 1
    sos = butter(2, band, btype="bandpass", fs=grid_hz, output="sos")
    power, count = np.zeros(3), 0
    for seg in np.split(np.arange(ts.size), cuts):
        if seg.size < 2 or ts[seg[-1]] - ts[seg[0]] < min_s:
            continue
        grid = np.arange(ts[seg[0]], ts[seg[-1]], 1.0 / grid_hz)
        for i in range(3):
            y = np.interp(grid, ts[seg], x[seg, i])
            power[i] += float(np.sum(sosfiltfilt(sos, y - y.mean()) ** 2))
        count += grid.size
    if count == 0:
        return [None] * 3
    return [float(v) for v in np.sqrt(power / count)]


#: the time (s) within which the estimate's own moves against the truth are counted as one step:
#: about what a loop on a vehicle answering in 0.2-0.3 s needs to follow a move of its estimate
#: (PX4 SIH's EKF2 once moved 0.085 m against its truth in 0.36 s, and the error read by it rose
#: 0.11 m while the vehicle had moved 0.03)
STEP_WINDOW_S = 0.5
#: the miss is first averaged over this many seconds, centred: the true samples are timed by
#: their arrival, which at 5 m/s puts 20-30 mm of jitter between two of them (ArduCopter SITL)
STEP_SMOOTH_S = 0.2


def estimate_steps(ts, miss, err, from_s=0.0, window=STEP_WINDOW_S, gap_s=WANDER_GAP_S,
                   smooth_s=STEP_SMOOTH_S):
    """How far the estimate moved against the truth within ``window`` s: its miss ``miss``
    ((N, 3) estimate minus truth, at times ``ts``; averaged over ``smooth_s``, centred) against
    the miss ``window`` s before, on each stretch without a gap over ``gap_s`` (3-D, m).  A loop
    follows its estimate, so a move this quick is read as the vehicle's error before any loop
    could answer it: a floor under the error the estimate reports.  Also, at the largest error
    read by the estimate ``err`` ((N, 3) estimate minus reference), how much of it the estimate
    had just moved.  None where no stretch is longer than ``window``."""
    ts = np.asarray(ts, dtype=float)
    miss = np.asarray(miss, dtype=float).reshape(-1, 3)
    err = np.asarray(err, dtype=float).reshape(-1, 3)
    moved = np.full(ts.size, np.nan)
    for seg in np.split(np.arange(ts.size), np.flatnonzero(np.diff(ts) > gap_s) + 1):
        if seg.size < 2:
            continue
        k = int(round(smooth_s / float(np.median(np.diff(ts[seg])))))
        if k >= 2:  # centred running mean; the half-windows at the ends are dropped
            if seg.size <= k:
                continue
            m = np.column_stack([np.convolve(miss[seg, i], np.ones(k) / k, mode="valid")
                                 for i in range(3)])
            seg = seg[k // 2:k // 2 + m.shape[0]]
        else:
            m = miss[seg]
        st = ts[seg]
        late = st - window >= st[0]
        if not late.any():
            continue
        before = np.column_stack([np.interp(st[late] - window, st, m[:, i])
                                  for i in range(3)])
        moved[seg[late]] = np.linalg.norm(m[late] - before, axis=1)
    out = {"window_s": float(window), "from_s": float(from_s), "max_m": None, "at_s": None,
           "at_worst_error": None}
    if not np.isfinite(moved).any():
        return out
    top = int(np.nanargmax(moved))
    out["max_m"], out["at_s"] = float(moved[top]), float(ts[top])
    norm = np.linalg.norm(err, axis=1)
    w = int(np.argmax(norm))
    if np.isfinite(moved[w]):
        out["at_worst_error"] = {"t_s": float(ts[w]), "error_m": float(norm[w]),
                                 "moved_m": float(moved[w])}
    return out


#: truth.csv's columns: mission time, the true position in the estimate's frame, true velocity
TRUTH_COLUMNS = ["t", "north", "east", "down", "vn", "ve", "vd"]


def truth_text(fig, settle_s=0.0):
    """The console's line on a flight's true track (``fig`` from :meth:`TruthTrack.figures`)."""
    settled = fig.get("after_settle") if settle_s > 0 else None
    if settled is not None and not math.isfinite(settled["max_error_m"] or math.nan):
        settled = None  # the flight ended before it settled
    e = fig if settled is None else settled
    when = "over the mission" if settled is None else "after settling"
    est = fig["estimate_error"]
    text = (f"against the simulator's true position ({fig['source']}): max error "
            f"{e['max_error_m']:.3f} m, rms {e['rms_error_m']:.3f} m {when}; the autopilot's "
            f"estimate was off by up to {est['max_m']:.3f} m (rms {est['rms_m']:.3f} m)")
    w = est.get("wander")
    if w and None not in w["rms_xyz_m"][:2] and None not in w["error_rms_xyz_m"][:2]:
        lo, hi = w["band_hz"]
        mm = lambda v: f"{1e3 * v[0]:.0f} / {1e3 * v[1]:.0f}"  # noqa: E731
        where = " after settling" if settle_s > 0 else ""
        text += (f"; between {lo:g} and {hi:g} Hz{where} it wandered {mm(w['rms_xyz_m'])} mm rms (north / east), which the loop "
                 f"reads as motion, and the error by it was {mm(w['error_rms_xyz_m'])} mm there")
    st = est.get("step")
    if st and st["max_m"] is not None:
        text += (f"; within {st['window_s']:g} s it moved up to {st['max_m']:.3f} m against the "
                 f"truth (at {st['at_s']:.1f} s), a move no loop follows in time")
        worst = st["at_worst_error"]
        if worst is not None:
            text += (f", and at the largest error read by it ({worst['error_m']:.3f} m, "
                     f"{worst['t_s']:.1f} s) it had just moved {worst['moved_m']:.3f} m")
    return text
