"""The flight record: one folder per flight, written as the flight goes.

    flight.tlog      every MAVLink frame both ways (8-byte big-endian Unix time in us + frame)
    controller.csv   one row per controller step (columns: :data:`COLUMNS`)
    summary.json     controller, mission, duration and the error figures; how the flight was
                     made: the controller flown (controller_flown), the settings after every
                     override (config), the command line, the versions, the vehicle's identity
    mission.yaml     the mission file as given
    effective.yaml   the mission as flown: every override applied, the gains resolved
    *.png            figures (see :mod:`mavadrc.study.figures`)

Both the tlog and the table are flushed as they go, so a killed process leaves readable files.
"""

import csv
import json
import math
import os
import struct
import time
from pathlib import Path

import numpy as np

AXES = ("x", "y", "z")

#: controller.csv columns, in order.  NED metres, seconds from the start of the mission.
COLUMNS = (
    ["t", "phase"]
    + [f"ref_{a}" for a in AXES]
    + [f"ref_v{a}" for a in AXES]
    + [f"ref_a{a}" for a in AXES]
    + ["ref_yaw"]
    + [f"pos_{a}" for a in AXES]
    + [f"vel_{a}" for a in AXES]
    + ["yaw"]
    + [f"z{i}_{a}" for a in AXES for i in (1, 2, 3)]
    + [f"v{i}_{a}" for a in AXES for i in (1, 2)]
    + [f"acc_cmd_{a}" for a in AXES]
    + [f"acc_applied_{a}" for a in AXES]
    + ["q_w", "q_x", "q_y", "q_z", "thrust"]
    + [f"true_dist_{a}" for a in AXES]
    + ["dt", "sample_age"]  # s since the previous sample; s from its taking to our reading
    + ["drag_x", "drag_y"]  # 1/s: the horizontal drag the observers model (learnt: drag_learn)
)


def _stopped(f, exc, writer):
    """A record file that could not be written (a full disk, a card pulled out): the writer
    stops writing it (returns None for its file, closed as far as it will) and says why in its
    ``lost``.  The flight goes on: a record is never a reason to drop a vehicle."""
    if writer.lost is None:
        writer.lost = f"{writer.path.name}: {exc.strerror or exc}" + (
            f" (errno {exc.errno})" if exc.errno else "")
    try:
        f.close()
    except OSError:
        pass
    return None


class _Unwritten:
    """A table that could not even be opened: takes rows and writes nothing (``lost`` says
    why)."""

    def __init__(self, path, exc):
        self.path = Path(path)
        self.lost = None
        _stopped(_Closed(), exc, self)

    def row(self, values):
        pass

    def close(self):
        pass


class _Closed:
    def close(self):
        pass


class TlogWriter:
    """Writes a .tlog: each record is the Unix time in microseconds (big-endian u64) + a frame."""

    def __init__(self, path):
        self.path = Path(path)
        self._f = open(self.path, "wb")
        self.frames = 0
        self._flushed = time.monotonic()
        self.lost = None  # why the file stopped being written (a full disk): see _Stops

    def write(self, frame, t_us=None):
        """Append one frame (buffered: :meth:`flush` puts it on disk; the link flushes before
        it waits for data, so a killed flight loses nothing it had acted on)."""
        if self._f is None:
            return
        if t_us is None:
            t_us = int(time.time() * 1e6)
        try:
            self._f.write(struct.pack(">Q", t_us) + bytes(frame))
        except OSError as exc:
            self._f = _stopped(self._f, exc, self)
            return
        self.frames += 1
        now = time.monotonic()
        if now - self._flushed > 0.25:  # and at least every quarter second of a busy link
            self.flush()

    def flush(self):
        if self._f is not None:
            try:
                self._f.flush()
            except OSError as exc:
                self._f = _stopped(self._f, exc, self)
                return
            self._flushed = time.monotonic()

    def close(self):
        if self._f is not None:
            f, self._f = self._f, None
            try:
                f.close()
            except OSError as exc:
                _stopped(f, exc, self)


class TableWriter:
    """CSV of the controller internals; flushed every ``flush_every`` rows and on close.

    Numbers are written with 9 significant digits, NaN as an empty field; ``text`` columns as
    strings.  The numbers of a row are formatted in one pass (a step's 48 values cost a few
    microseconds, which matters in a lockstep loop)."""

    def __init__(self, path, flush_every=25, columns=COLUMNS, text=("phase",)):
        self.path = Path(path)
        self._f = open(self.path, "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(columns)
        self._f.flush()
        self._n = 0
        self.flush_every = flush_every
        self._text = [i for i, c in enumerate(columns) if c in text]
        self._fmt = ",".join(["%.9g"] * len(columns))
        self.lost = None  # why the file stopped being written (a full disk): see _stopped

    def row(self, values):
        if self._f is None:
            return
        nums = list(values)
        for i in self._text:
            nums[i] = 0.0
        cells = (self._fmt % tuple(nums)).replace("nan", "").split(",")
        for i in self._text:
            cells[i] = values[i]
        try:
            self._w.writerow(cells)
            self._n += 1
            if self._n % self.flush_every == 0:
                self._f.flush()
        except OSError as exc:
            self._f = _stopped(self._f, exc, self)

    def close(self):
        if self._f is not None:
            f, self._f = self._f, None
            try:
                f.flush()
                f.close()
            except OSError as exc:
                _stopped(f, exc, self)


def finite(x):
    """``x`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(x, dict):
        return {k: finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def read_table(path):
    """controller.csv as a dict of numpy arrays (``phase`` stays a list of strings)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    out = {}
    for j, name in enumerate(header):
        col = [r[j] if j < len(r) else "" for r in body]
        if name == "phase":
            out[name] = col
        else:
            out[name] = np.array([float(v) if v != "" else math.nan for v in col])
    return out


def error_figures(t, ref, pos, settle_s=0.0):
    """RMS and max position error, 3-D and per axis, over t >= settle_s.

    ``ref`` and ``pos`` are (N, 3).  Returns the keys of ``summary.json``.
    """
    t = np.asarray(t, dtype=float)
    keep = t >= settle_s
    err = np.asarray(pos, dtype=float)[keep] - np.asarray(ref, dtype=float)[keep]
    if err.shape[0] == 0:
        nan3 = [math.nan] * 3
        return {"rms_error_m": math.nan, "max_error_m": math.nan, "rms_error_xyz_m": nan3,
                "max_error_xyz_m": nan3}
    norm = np.linalg.norm(err, axis=1)
    return {
        "rms_error_m": float(np.sqrt(np.mean(norm**2))),
        "max_error_m": float(norm.max()),
        "rms_error_xyz_m": [float(v) for v in np.sqrt(np.mean(err**2, axis=0))],
        "max_error_xyz_m": [float(v) for v in np.abs(err).max(axis=0)],
    }


#: a swing is a limit cycle when it is this like itself :data:`REGULARITY_PERIODS` of its
#: periods later (its autocorrelation there, 1 for a sustained periodic swing, clipped or not;
#: exp(-2 pi zeta n) for a resonance of damping zeta driven by noise, 0.06 at zeta 0.15 over 3
#: periods; 0.6 is zeta 0.027)
LIMIT_CYCLE_REGULARITY = 0.6
REGULARITY_PERIODS = 3
#: judged in windows this many periods long (the lag must fit in half of one)
REGULARITY_WINDOW_PERIODS = 8
#: a shorter record (s) is not called either way (None), nor one shorter than a window
LIMIT_CYCLE_MIN_S = 20.0


def regularity(x, dt, f, periods=REGULARITY_PERIODS):
    """How alike the swing ``x`` (sampled every ``dt`` s) is to itself ``periods`` of its
    periods (1/``f`` s) later: its autocorrelation at that lag (unbiased for the overlap, the
    best within a tenth of a period of it), in windows of :data:`REGULARITY_WINDOW_PERIODS`
    periods half overlapping, averaged with each window's power as its weight.  Windowed, a
    limit cycle that grows or changes its period along the flight (on ArduCopter SITL one in
    roll was joined by one in pitch and read 0.55 over the whole record) reads as the cycle it
    is in each stretch.  None if no window fits in ``x``."""
    x = np.asarray(x, dtype=float)
    period = 1.0 / f / dt  # samples
    width = int(math.ceil(REGULARITY_WINDOW_PERIODS * period))
    lo = int(math.floor((periods - 0.1) * period))
    hi = int(math.ceil((periods + 0.1) * period))
    if lo < 1 or hi >= width // 2 or width > x.size:
        return None
    overlap = width - np.arange(width)  # the pairs each lag has: the estimate unbiased by it
    total = weight = 0.0
    for start in range(0, x.size - width + 1, max(1, width // 2)):
        seg = x[start:start + width]
        seg = seg - float(np.mean(seg))
        spec = np.fft.rfft(seg, 2 * width)
        ac = np.fft.irfft(spec * np.conj(spec), 2 * width)[:width] / overlap
        if ac[0] > 0.0:
            total += float(np.max(ac[lo:hi + 1]))  # = power x the window's regularity
            weight += float(ac[0])
    return total / weight if weight > 0.0 else None


def attitude_oscillation(t, roll, pitch, window_s=1.0):
    """Roll/pitch oscillation of a flight: the 99th percentile of |angle - its 1 s running mean|
    (deg, the worse axis) and the strongest frequency of that axis (Hz, 0.2-10 Hz), or None with
    less than 3 s of attitude.  A limit cycle shows here however good the position error looks.

    And what kind of swing it is: ``regularity`` (:func:`regularity` of that axis's swing at its
    strongest frequency) and ``limit_cycle``, whether that is at least
    :data:`LIMIT_CYCLE_REGULARITY` (None on a record shorter than :data:`LIMIT_CYCLE_MIN_S`).
    A limit cycle repeats itself, period after period; a loop's resonance driven by noise or
    wind swings as far but forgets itself within a few periods, and so does a manoeuvre.
    """
    t = np.asarray(t, dtype=float)
    if t.size < 10 or t[-1] - t[0] < 3.0:
        return None
    dt = float(np.median(np.diff(t)))
    k = max(3, int(round(window_s / dt)))
    best = None
    for a in (np.degrees(np.asarray(roll, dtype=float)), np.degrees(np.asarray(pitch, dtype=float))):
        resid = (a - np.convolve(a, np.ones(k) / k, mode="same"))[k:-k]
        if resid.size < 2 * k:
            return None
        amp = float(np.percentile(np.abs(resid), 99))
        if best is None or amp > best[0]:
            best = (amp, resid)
    amp, resid = best
    spectrum = np.abs(np.fft.rfft(resid * np.hanning(resid.size)))
    freq = np.fft.rfftfreq(resid.size, dt)
    band = (freq >= 0.2) & (freq <= 10.0)
    if not band.any():
        return {"amplitude_deg": amp, "frequency_hz": None, "regularity": None,
                "limit_cycle": None}
    f_peak = float(freq[band][np.argmax(spectrum[band])])
    like = regularity(resid, dt, f_peak)
    long_enough = resid.size * dt >= LIMIT_CYCLE_MIN_S
    verdict = bool(like >= LIMIT_CYCLE_REGULARITY) if like is not None and long_enough else None
    return {"amplitude_deg": amp, "frequency_hz": f_peak, "regularity": like,
            "limit_cycle": verdict}


class FlightRecord:
    """Creates the folder and its writers; ``finish(summary)`` writes summary.json."""

    def __init__(self, folder, mission_text=None):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.tlog = TlogWriter(self.folder / "flight.tlog")
        self.table = TableWriter(self.folder / "controller.csv")
        self.truth = None  # truth.csv, opened with the first true sample of the mission
        self._log_lost = None  # companion.log's, as the writers' ``lost``
        if mission_text is not None:
            (self.folder / "mission.yaml").write_text(mission_text)

    @property
    def lost(self):
        """None while every file of the record is written; else why the first stopped (the
        flight goes on without it)."""
        for w in (self.tlog, self.table, self.truth):
            if w is not None and w.lost is not None:
                return w.lost
        return self._log_lost

    def write_summary(self, summary):
        """summary.json, strict JSON: a NaN or an infinity is written as null."""
        tmp = self.folder / "summary.json.tmp"
        tmp.write_text(json.dumps(finite(summary), indent=2, sort_keys=True, allow_nan=False)
                       + "\n")
        os.replace(tmp, self.folder / "summary.json")

    def note(self, text):
        """Append to companion.log (tracebacks of errors the flight survived); a log that
        cannot be written is given up, never raised (:attr:`lost`)."""
        if self._log_lost is not None:
            return
        try:
            with open(self.folder / "companion.log", "a") as f:
                f.write(time.strftime("%H:%M:%S ") + text.rstrip() + "\n")
        except OSError as exc:
            self._log_lost = f"companion.log: {exc.strerror or exc}"

    def truth_table(self, columns):
        """truth.csv (a simulator's true state, :mod:`mavadrc.flight.truth`), opened on first use (a
        file that cannot be opened is given up as one that stops: :attr:`lost`)."""
        if self.truth is None:
            try:
                self.truth = TableWriter(self.folder / "truth.csv", columns=columns, text=())
            except OSError as exc:
                self.truth = _Unwritten(self.folder / "truth.csv", exc)
        return self.truth

    def close(self):
        self.tlog.close()
        self.table.close()
        if self.truth is not None:
            self.truth.close()


YAW_COLUMN = COLUMNS.index("yaw")  # where the vehicle's yaw sits in a controller.csv row
TRUTH_COLUMN = COLUMNS.index("true_dist_x")
#: the parts of a row that come after its position sample: the vehicle's attitude, the truth
ATTITUDE_PART, TRUTH_PART = 1, 2


class Recorder:
    """What a flight writes as it goes: one controller.csv row per control step, and the
    reference and position history the error figures are computed from.

    A row's vehicle attitude and true disturbance are those of the same sample: the bundled
    vehicle sends the position sample first, on its own, and ATTITUDE and the simulator's
    TRUE_DIST right after, so the row is written when both have come (or, from an autopilot
    that sends no TRUE_DIST, when the next sample comes)."""

    def __init__(self, record, kind):
        self.rec = record
        self.kind = kind
        self.yaw = 0.0
        self.true_dist = np.full(3, math.nan)
        self.t, self.ref, self.pos = [], [], []
        self.carried = []  # per scored step: the vertical disturbance estimate (m/s^2, NED)
        self._row = None  # the last control step's row, waiting for its attitude and truth
        self._row_ms = None
        self._row_have = 0

    def step(self, t, segment, r, s, ctrl, q, thrust, scored=True):
        """The row of one control step at mission time ``t`` (reference ``r``, sample ``s``);
        ``scored``: whether it counts in the error figures (the final descent into the ground,
        past the mission's end, does not)."""
        if self._row is not None:
            self._write_row()
        z = ctrl.z
        row = [float(t), segment, *r.pos.tolist(), *r.vel.tolist(), *r.acc.tolist(),
               float(r.yaw), *s.pos.tolist(), *s.vel.tolist(), math.nan]
        row += z.ravel().tolist() if self.kind != "pd" else [math.nan] * 9
        row += ctrl.td.ravel().tolist() if self.kind == "adrc" else [math.nan] * 6
        row += [*ctrl.accel_command.tolist(), *ctrl.accel_applied.tolist(), *map(float, q),
                float(thrust), math.nan, math.nan, math.nan,
                math.nan if s.dt is None else s.dt, math.nan if s.age is None else s.age]
        row += ctrl.drag[:2].tolist() if ctrl.models_drag else [math.nan, math.nan]
        self._row = row
        self._row_ms = int(round(s.t * 1000.0))
        self._row_have = 0
        if not scored:
            return
        self.t.append(t)
        self.ref.append(r.pos)
        self.pos.append(s.pos)
        self.carried.append(float(z[2, 2]) if self.kind != "pd" else math.nan)

    def unscore_from_contact(self, window_s=3.0, min_growth=0.0, held=None):
        """A vehicle resting on the ground stopped following the reference down where, within
        the last ``window_s`` of scored steps, the reference was least below it (down:
        reference minus position, smallest); the steps from there on no longer count in the
        error figures (they stay in the table).  Left as they are when the reference's lead
        grew by less than ``min_growth`` (m) from there to the last scored step (it was still
        followed).  ``held`` (m/s^2): also from where the ground began to hold the vehicle up,
        when it still did at the last scored step: the start of the run of steps, ending
        there, whose vertical disturbance estimate pushed up by more than that (an estimate
        sinking with the reference on the ground shows no lead at all)."""
        if not self.t:
            return
        t = np.asarray(self.t)
        first = int(np.searchsorted(t, t[-1] - window_s, side="left"))
        lead = [r[2] - p[2] for r, p in zip(self.ref[first:], self.pos[first:])]
        cuts = []
        if lead[-1] - min(lead) >= min_growth:
            cuts.append(first + int(np.argmin(lead)))
        if held is not None:
            up = np.asarray(self.carried[first:]) < -held
            if up[-1]:
                run = len(up) - 1
                while run > 0 and up[run - 1]:
                    run -= 1
                cuts.append(first + run)
        if cuts:
            keep = min(cuts)
            del self.t[keep:], self.ref[keep:], self.pos[keep:], self.carried[keep:]

    def sample_came(self):
        """A new position sample: the pending row gets whatever of its parts came."""
        if self._row is not None:
            self._write_row()

    def attitude(self, time_boot_ms, yaw):
        self.yaw = yaw
        self._part(time_boot_ms, ATTITUDE_PART)

    def truth(self, time_boot_ms, dist):
        self.true_dist = dist
        self._part(time_boot_ms, TRUTH_PART)

    def _part(self, ms, part):
        if self._row is not None and ms == self._row_ms:
            self._row_have |= part
            if self._row_have == ATTITUDE_PART | TRUTH_PART:
                self._write_row()

    def _write_row(self):
        row = self._row
        self._row = None
        row[YAW_COLUMN] = float(self.yaw)
        row[TRUTH_COLUMN:TRUTH_COLUMN + 3] = self.true_dist.tolist()
        self.rec.table.row(row)

    def flush(self):
        if self._row is not None:
            self._write_row()

    def errors(self, settle_s=0.0):
        """The error figures of the steps logged so far (:func:`error_figures`)."""
        t = np.asarray(self.t)
        ref = np.asarray(self.ref).reshape(-1, 3)
        pos = np.asarray(self.pos).reshape(-1, 3)
        return error_figures(t, ref, pos, settle_s)

    @property
    def duration(self):
        return float(self.t[-1]) if self.t else 0.0
