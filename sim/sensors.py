"""What the vehicle reports about itself: the true state, optionally delayed and noisy."""

from __future__ import annotations

import math

import numpy as np

from sim.physics import IX_POS, IX_Q, IX_VEL, IX_W, NX

__all__ = ["Sensors"]

_NOISE_KEYS = ("position", "velocity", "attitude", "rates")


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
            y[IX_Q:IX_Q + 4] = _perturb(y[IX_Q:IX_Q + 4],
                                        n["attitude"] * self._rng.standard_normal(3))
        return y


def _perturb(q: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """q (x) exp(rotvec / 2): q rotated by the small body-frame rotation vector rotvec."""
    angle = float(np.linalg.norm(rotvec))
    if angle == 0.0:
        return q
    axis = rotvec / angle
    s = math.sin(0.5 * angle)
    dw, dx, dy, dz = math.cos(0.5 * angle), axis[0] * s, axis[1] * s, axis[2] * s
    w, x, y, z = q
    out = np.array([
        w * dw - x * dx - y * dy - z * dz,
        w * dx + x * dw + y * dz - z * dy,
        w * dy - x * dz + y * dw + z * dx,
        w * dz + x * dy - y * dx + z * dw,
    ])
    return out / np.linalg.norm(out)
