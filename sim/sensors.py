"""What the vehicle reports about itself: the true state, optionally delayed and noisy."""

from __future__ import annotations

import math

import numpy as np

from mavadrc.control._jit import jit
from sim.physics import IX_POS, IX_Q, IX_VEL, IX_W, NX

__all__ = ["Sensors", "TYPICAL_NOISE", "measure_into", "perturb"]

_NOISE_KEYS = ("position", "velocity", "attitude", "rates")

#: standard deviations of typical sensor noise (``python -m sim --noise``, ``sim: {noise: true}``)
TYPICAL_NOISE = {"position": 0.01, "velocity": 0.02, "attitude": 0.002, "rates": 0.01}

# columns of one physics step's noise in :meth:`Sensors.draws`, in the order measure draws them
N_POS = 0  # 3: position (m)
N_VEL = 3  # 3: velocity (m/s)
N_W = 6  # 3: body rates (rad/s)
N_ATT = 9  # 3: attitude, a body-frame rotation vector (rad)
NNOISE = 12


class Sensors:
    """Reported state = true state from ``latency_s`` ago, plus seeded Gaussian noise.

    ``noise`` maps any of position (m), velocity (m/s), attitude (rad, a random small rotation
    applied in the body frame) and rates (rad/s) to a standard deviation; missing keys mean no
    noise. With no noise and no latency, :meth:`measure` returns the truth (a copy). With
    latency, states pass through a ring buffer and the newest one at least ``latency_s`` old is
    delivered (the oldest stored one until the buffer covers the latency). Rotor speeds are
    reported without noise.
    """

    def __init__(self, noise: dict[str, float] | None = None, latency_s: float = 0.0,
                 seed: int | None = 0):
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
        self.noise = {k: float(noise.get(k, 0.0)) for k in _NOISE_KEYS}
        self.latency_s = float(latency_s)
        self._times = np.empty(64)
        self._states = np.empty((64, NX))
        self.reset(seed)

    def reset(self, seed: int | None = 0) -> None:
        """Forget buffered states and restart the noise stream from ``seed``."""
        self._rng = np.random.default_rng(seed)
        self._head = 0      # index of the oldest buffered state
        self._count = 0

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
        columns of :meth:`draws` (for :func:`measure_into`)."""
        n = self.noise
        return np.array([n["position"], n["velocity"], n["rates"], n["attitude"]])

    def draws(self, n: int) -> np.ndarray:
        """The noise of the next ``n`` calls of :meth:`measure`, taken from its stream now:
        (n, NNOISE), columns N_POS, N_VEL, N_W, N_ATT, each the sigma times the normal that
        measure would draw (zero where the sigma is 0, which draws nothing).  Drawing these and
        applying them with :func:`measure_into` leaves the stream and the readings as ``n``
        calls of measure would (for compiled loops that step tick by tick)."""
        sig = self.sigmas()
        on = np.nonzero(sig > 0.0)[0]
        out = np.zeros((int(n), NNOISE))
        if on.size:
            z = self._rng.standard_normal((int(n), 3 * on.size))
            for j, c in enumerate(on):
                out[:, 3 * c:3 * c + 3] = sig[c] * z[:, 3 * j:3 * j + 3]
        return out

    def measure(self, t: float, x: np.ndarray) -> np.ndarray:
        """The reported state at time t given the true state x (float64[17])."""
        if self.latency_s > 0.0:
            self._push(t, x)
            y = self._delayed(t)
        else:
            y = np.array(x, dtype=float)
        n = self.noise
        if n["position"] > 0:
            y[IX_POS:IX_POS + 3] += n["position"] * self._rng.standard_normal(3)
        if n["velocity"] > 0:
            y[IX_VEL:IX_VEL + 3] += n["velocity"] * self._rng.standard_normal(3)
        if n["rates"] > 0:
            y[IX_W:IX_W + 3] += n["rates"] * self._rng.standard_normal(3)
        if n["attitude"] > 0:
            q = y[IX_Q:IX_Q + 4].copy()
            perturb(q, n["attitude"] * self._rng.standard_normal(3), y[IX_Q:IX_Q + 4])
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
