"""What the vehicle reports about itself: the true state, optionally delayed and noisy."""

from __future__ import annotations

import functools
import math

import numpy as np

from mavadrc.control.jit import jit
from sim.physics import IX_POS, IX_Q, IX_VEL, IX_W, NX

__all__ = ["CLOCK_RATES", "Sensors", "TYPICAL_NOISE", "WANDER_CORNER_HZ", "measure_into", "perturb",
           "wander_band_rms"]

_NOISE_KEYS = ("position", "velocity", "attitude", "rates")

#: standard deviations of typical sensor noise (``python -m sim --noise``, ``sim: {noise: true}``)
TYPICAL_NOISE = {"position": 0.01, "velocity": 0.02, "attitude": 0.002, "rates": 0.01}

#: Hz: the corner of the position estimate's wander (``wander``), as PX4 SIH's EKF2 wanders
#: against SIH's truth: the estimate's error there, over the spiral and the landing of six
#: flights (2026-12-03, 50 Hz truth, Welch), is a second-order low-pass of white noise with its
#: corner near 0.15 Hz and 0.05-0.08 m RMS per axis: 40-75 mm between 0.05 and 0.3 Hz, 8-15
#: between 0.3 and 0.6, 3-5 between 0.6 and 1, 3 between 1 and 2 Hz (this model: 49, 11, 3.6,
#: 1.8 at 0.06 m), its velocity the position's rate (16-33 mm/s between 0.3 and 0.6 Hz measured)
WANDER_CORNER_HZ = 0.15

#: the rates (least, most) the vehicle's clock, the clock of every time it reports, may run at
#: against the wall clock in real time (``--clock-rate``, ``sim: {clock_rate}``)
CLOCK_RATES = (0.5, 2.0)

# columns of one physics step's noise in :meth:`Sensors.draws`, in the order measure draws them
N_POS = 0  # 3: position (m)
N_VEL = 3  # 3: velocity (m/s)
N_W = 6  # 3: body rates (rad/s)
N_ATT = 9  # 3: attitude, a body-frame rotation vector (rad)
NNOISE = 12
#: steps of the wander computed at a time (:meth:`Sensors._wander_rows`)
_WANDER_CHUNK = 1024


@functools.lru_cache(maxsize=16)
def _wander_filter(corner_hz, dt):
    """(b, a, gain, rate_gain) of the wander's discrete second-order Butterworth low-pass at
    step ``dt``: gain is the RMS of its output per unit of white input (the impulse response's
    energy), rate_gain that of the output's rate (the velocity it puts in the estimate)."""
    from scipy.signal import butter, lfilter  # here: scipy.signal is slow to import
    b, a = butter(2, corner_hz, fs=1.0 / dt)
    n = int(math.ceil(40.0 / (corner_hz * dt)))  # the response has died out well before
    impulse = lfilter(b, a, np.r_[1.0, np.zeros(n)])
    rate = np.diff(np.r_[0.0, impulse]) / dt
    return b, a, float(np.sqrt(np.sum(impulse * impulse))), float(np.sqrt(np.sum(rate * rate)))


def wander_band_rms(sigma, corner_hz, f_lo, f_hi):
    """m: the RMS of a wander of ``sigma`` (m) and corner ``corner_hz`` between f_lo and f_hi
    (Hz): the share of the second-order Butterworth's power in the band."""
    x = np.linspace(f_lo, f_hi, 4001) / corner_hz
    band = np.trapezoid(1.0 / (1.0 + x ** 4), x)
    return float(sigma * math.sqrt(band / (math.pi / (2.0 * math.sqrt(2.0)))))


class Sensors:
    """Reported state = true state from ``latency_s`` ago, plus seeded Gaussian noise.

    ``noise`` maps any of position (m), velocity (m/s), attitude (rad, a random small rotation
    applied in the body frame) and rates (rad/s) to a standard deviation; missing keys mean no
    noise. With no noise and no latency, :meth:`measure` returns the truth (a copy). With
    latency, states pass through a ring buffer and the newest one at least ``latency_s`` old is
    delivered (the oldest stored one until the buffer covers the latency). Rotor speeds are
    reported without noise.

    ``wander`` (m, RMS per axis; 0: none) adds an estimator's slow error on top: position
    errors that are white noise through a second-order low-pass at ``wander_corner_hz``, the
    velocity their rate, as PX4 SIH's EKF2 output wanders against its truth
    (:data:`WANDER_CORNER_HZ`).  A loop reads that error as motion; where it cannot follow it
    (a vehicle slower than the wander), it amplifies it.  ``dt`` (s): the interval between
    calls of :meth:`measure` (rows of :meth:`draws`), which the wander's filter steps at.  The
    wander draws from a stream of its own: the white noise of a seed is the same with it.
    """

    def __init__(self, noise: dict[str, float] | None = None, latency_s: float = 0.0,
                 seed: int | None = 0, wander: float = 0.0,
                 wander_corner_hz: float = WANDER_CORNER_HZ, dt: float = 0.001):
        noise = dict(noise or {})
        unknown = sorted(set(noise) - set(_NOISE_KEYS))
        if unknown:
            raise ValueError(f"unknown noise key(s) {', '.join(unknown)}; "
                             f"known: {', '.join(_NOISE_KEYS)}")
        for key, sigma in noise.items():
            if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma >= 0):
                raise ValueError(f"noise {key}: must be a number >= 0 (got {sigma!r})")
        if not (math.isfinite(latency_s) and latency_s >= 0):
            raise ValueError(f"latency_s must be >= 0 (got {latency_s!r})")
        if not (isinstance(wander, (int, float)) and math.isfinite(wander)
                and 0.0 <= wander <= 1.0):
            raise ValueError(f"wander must be 0 to 1 m (got {wander!r})")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be > 0 s (got {dt!r})")
        if not (isinstance(wander_corner_hz, (int, float)) and math.isfinite(wander_corner_hz)
                and 0.01 <= wander_corner_hz <= min(5.0, 0.05 / dt)):
            raise ValueError(f"wander_corner_hz must be 0.01 to {min(5.0, 0.05 / dt):g} Hz "
                             f"(got {wander_corner_hz!r})")
        self.noise = {k: float(noise.get(k, 0.0)) for k in _NOISE_KEYS}
        self.wander = float(wander)
        self.wander_corner_hz = float(wander_corner_hz)
        self.dt = float(dt)
        self.latency_s = float(latency_s)
        n = self.noise
        #: the white noise's sigmas in draws' column order, and with the wander's (sigmas())
        self._white = np.array([n["position"], n["velocity"], n["rates"], n["attitude"]])
        self._sigmas = np.array([math.hypot(n["position"], self.wander),
                                 math.hypot(n["velocity"], self.wander_velocity_rms()),
                                 n["rates"], n["attitude"]])
        self._times = np.empty(64)
        self._states = np.empty((64, NX))
        self.reset(seed)

    def reset(self, seed: int | None = 0) -> None:
        """Forget buffered states and restart the noise stream from ``seed`` (the wander's
        too, from a stationary start)."""
        self._rng = np.random.default_rng(seed)
        self._head = 0      # index of the oldest buffered state
        self._count = 0
        if self.wander > 0.0:
            self._wander_rng = np.random.default_rng(
                None if seed is None else [int(seed), 0x57414E44])  # "WAND": its own stream
            b, a, _, _ = _wander_filter(self.wander_corner_hz, self.dt)
            self._wander_zi = np.zeros((3, max(len(a), len(b)) - 1))
            self._wander_last = np.zeros(3)
            # start where it would be after running for long: 20 of its time constants
            self._wander_fill(int(math.ceil(20.0 / (self.wander_corner_hz * self.dt))))
            self._wander_at = self._wander_buf.shape[0]  # the warm-up is not read

    @property
    def active(self) -> bool:
        """Whether readings differ from the (delayed) truth: some noise or a wander."""
        return self.wander > 0.0 or any(v > 0.0 for v in self.noise.values())

    def _wander_rows(self, n: int):
        """The wander's next ``n`` steps: (position (n, 3) m, velocity (n, 3) m/s), taken from
        a buffer filled :data:`_WANDER_CHUNK` steps at a time (the filter steps the same way
        whatever the chunks, so the numbers are those of stepping it one by one)."""
        n = int(n)
        pos = np.empty((n, 3))
        vel = np.empty((n, 3))
        done = 0
        while done < n:
            if self._wander_at >= self._wander_buf.shape[0]:
                self._wander_fill(max(_WANDER_CHUNK, n - done))
            k = min(n - done, self._wander_buf.shape[0] - self._wander_at)
            rows = self._wander_buf[self._wander_at:self._wander_at + k]
            pos[done:done + k] = rows[:, 0:3]
            vel[done:done + k] = rows[:, 3:6]
            self._wander_at += k
            done += k
        return pos, vel

    def _wander_fill(self, n: int):
        """Step the wander's filter ``n`` steps into the buffer (position, velocity columns)."""
        from scipy.signal import lfilter

        b, a, gain, _ = _wander_filter(self.wander_corner_hz, self.dt)
        # step by step, three at a time: drawn ahead or one by one, the same numbers
        w = self._wander_rng.standard_normal((n, 3)).T * (self.wander / gain)
        buf = np.empty((n, 6))
        for i in range(3):
            p, self._wander_zi[i] = lfilter(b, a, w[i], zi=self._wander_zi[i])
            buf[:, i] = p
            buf[0, 3 + i] = (p[0] - self._wander_last[i]) / self.dt
            buf[1:, 3 + i] = np.diff(p) / self.dt
            self._wander_last[i] = p[-1]
        self._wander_buf = buf
        self._wander_at = 0

    def wander_velocity_rms(self) -> float:
        """m/s: the RMS of the wander's velocity error per axis (0 without a wander)."""
        if self.wander <= 0.0:
            return 0.0
        _, _, gain, rate_gain = _wander_filter(self.wander_corner_hz, self.dt)
        return self.wander / gain * rate_gain

    def _push(self, t: float, x: np.ndarray) -> None:
        cap = self._times.shape[0]
        if self._count == cap:
            order = (self._head + np.arange(cap)) % cap
            self._times = np.concatenate([self._times[order], np.empty(cap)])
            self._states = np.concatenate([self._states[order], np.empty((cap, NX))])
            self._head = 0
            cap *= 2
        i = (self._head + self._count) % cap
        self._times[i] = t
        self._states[i] = x
        self._count += 1

    def _delayed(self, t: float) -> np.ndarray:
        cap = self._times.shape[0]
        due = t - self.latency_s + 1e-9      # 1 ns slack for float time stamps
        # drop the oldest while the next one is also old enough
        while self._count > 1 and self._times[(self._head + 1) % cap] <= due:
            self._head = (self._head + 1) % cap
            self._count -= 1
        return self._states[self._head].copy()

    def sigmas(self) -> np.ndarray:
        """[position, velocity, rates, attitude] standard deviations, in the order of the
        columns of :meth:`draws` (for :func:`measure_into`); position and velocity with the
        wander's."""
        return self._sigmas.copy()

    def draws(self, n: int) -> np.ndarray:
        """The noise of the next ``n`` calls of :meth:`measure`, taken from its stream now:
        (n, NNOISE), columns N_POS, N_VEL, N_W, N_ATT, each the sigma times the normal that
        measure would draw (zero where the sigma is 0, which draws nothing).  Drawing these and
        applying them with :func:`measure_into` leaves the stream and the readings as ``n``
        calls of measure would (for compiled loops that step tick by tick)."""
        sig = self._white
        on = np.nonzero(sig > 0.0)[0]
        out = np.zeros((int(n), NNOISE))
        if on.size:
            z = self._rng.standard_normal((int(n), 3 * on.size))
            for j, c in enumerate(on):
                out[:, 3 * c:3 * c + 3] = sig[c] * z[:, 3 * j:3 * j + 3]
        if self.wander > 0.0:
            pos, vel = self._wander_rows(n)
            out[:, N_POS:N_POS + 3] += pos
            out[:, N_VEL:N_VEL + 3] += vel
        return out

    def measure(self, t: float, x: np.ndarray) -> np.ndarray:
        """The reported state at time t given the true state x (float64[17])."""
        if self.latency_s > 0.0:
            self._push(t, x)
            y = self._delayed(t)
        else:
            y = np.array(x, dtype=float)
        n = self.noise
        # each component's noise summed before it is added, as draws sums it for measure_into
        dpos = dvel = None
        if n["position"] > 0:
            dpos = n["position"] * self._rng.standard_normal(3)
        if n["velocity"] > 0:
            dvel = n["velocity"] * self._rng.standard_normal(3)
        if n["rates"] > 0:
            y[IX_W:IX_W + 3] += n["rates"] * self._rng.standard_normal(3)
        if n["attitude"] > 0:
            q = y[IX_Q:IX_Q + 4].copy()
            perturb(q, n["attitude"] * self._rng.standard_normal(3), y[IX_Q:IX_Q + 4])
        if self.wander > 0.0:
            if self._wander_at >= self._wander_buf.shape[0]:
                self._wander_fill(_WANDER_CHUNK)
            row = self._wander_buf[self._wander_at]  # this step's (position, velocity)
            self._wander_at += 1
            dpos = row[0:3] if dpos is None else dpos + row[0:3]
            dvel = row[3:6] if dvel is None else dvel + row[3:6]
        if dpos is not None:
            y[IX_POS:IX_POS + 3] += dpos
        if dvel is not None:
            y[IX_VEL:IX_VEL + 3] += dvel
        return y


@jit
def perturb(q, rotvec, out):
    """out = q (x) exp(rotvec / 2), normalised: q rotated by the small body-frame rotation
    vector rotvec (out = q when rotvec is zero).  ``out`` must not be ``q``."""
    angle = math.sqrt(rotvec[0] * rotvec[0] + rotvec[1] * rotvec[1] + rotvec[2] * rotvec[2])
    if angle == 0.0:
        for i in range(4):
            out[i] = q[i]
        return
    s = math.sin(0.5 * angle)
    dw = math.cos(0.5 * angle)
    dx = rotvec[0] / angle * s
    dy = rotvec[1] / angle * s
    dz = rotvec[2] / angle * s
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0] = w * dw - x * dx - y * dy - z * dz
    out[1] = w * dx + x * dw + y * dz - z * dy
    out[2] = w * dy - x * dz + y * dw + z * dx
    out[3] = w * dz + x * dy - y * dx + z * dw
    norm = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3])
    for i in range(4):
        out[i] /= norm


@jit
def measure_into(x, noise, sig, xm):
    """xm = the reading of the true state x with one step's noise (a row of
    :meth:`Sensors.draws`; ``sig`` from :meth:`Sensors.sigmas`), as :meth:`Sensors.measure`
    reads it without latency: a component whose sigma is 0 is copied untouched."""
    for i in range(x.shape[0]):
        xm[i] = x[i]
    if sig[0] > 0.0:
        for i in range(3):
            xm[IX_POS + i] = x[IX_POS + i] + noise[N_POS + i]
    if sig[1] > 0.0:
        for i in range(3):
            xm[IX_VEL + i] = x[IX_VEL + i] + noise[N_VEL + i]
    if sig[2] > 0.0:
        for i in range(3):
            xm[IX_W + i] = x[IX_W + i] + noise[N_W + i]
    if sig[3] > 0.0:
        perturb(x[IX_Q:IX_Q + 4], noise[N_ATT:N_ATT + 3], xm[IX_Q:IX_Q + 4])
