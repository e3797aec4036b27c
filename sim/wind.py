"""Wind: velocity fields (mean, Dryden turbulence, gusts, sinusoids) and the thesis's force model.

Every model follows one contract, called once per physics step with the real step dt::

    wind.reset(seed)
    v_wind, f_ext, tau_ext = wind.step(t, dt, position, velocity)

``v_wind`` is the air velocity at the vehicle (NED, m/s): the physics turns it into drag through
the air-relative velocity, as rotorpy, RotorS and ArduPilot SITL do. ``f_ext`` (world, N) and
``tau_ext`` (body, N m) are direct disturbances; only :class:`ThesisWind` produces them. Outputs
are evaluated at the start of the step and held over it. Parts add up in :class:`CompositeWind`.
Velocity-field models implement ``velocity(t, dt, position, velocity)`` (the same call without
the two zero vectors).
Random parts draw from a numpy Generator seeded by ``reset(seed)``: same seed, same series.

Directions follow ArduPilot's SIM_WIND_DIR: ``direction_from_deg`` is where the wind blows FROM,
0 = from north, 90 = from east; a wind from north moves air south (-x NED).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numba import njit

from sim.yamlio import Section, config_path, load_yaml

__all__ = [
    "Wind", "ConstantWind", "DrydenTurbulence", "OneMinusCosineGust", "SinusoidWind",
    "ThesisWind", "CompositeWind", "load_wind", "wind_vector", "dryden_scales",
    "DRYDEN_W20", "KNOT", "FOOT", "PackedWind", "pack_wind", "wind_step_packed",
]

KNOT = 0.514444          # m/s
FOOT = 0.3048            # m
#: MIL-F-8785C low-altitude wind speed at 20 ft for the three turbulence intensities (m/s).
DRYDEN_W20 = {"light": 15 * KNOT, "moderate": 30 * KNOT, "severe": 45 * KNOT}


def wind_vector(speed: float, direction_from_deg: float, vertical: float = 0.0) -> np.ndarray:
    """NED air velocity of a wind of ``speed`` blowing from ``direction_from_deg``.

    ``vertical`` is an updraft (m/s, positive up), so it enters as -z.
    """
    a = math.radians(direction_from_deg)
    return np.array([-speed * math.cos(a), -speed * math.sin(a), -vertical])


@njit(cache=True, error_model="numpy")
def _profile_scale(profile, ref_height, roughness, altitude):
    """Height-profile factor of a constant wind; ``profile`` is the index in
    ConstantWind.PROFILES (0 none, 1 sqrt60, 2 log)."""
    if profile == 1.0:
        return math.sqrt(min(max(altitude, 0.0), 60.0) / 60.0)
    if profile == 2.0:
        if altitude <= roughness:
            return 0.0
        return math.log(altitude / roughness) / math.log(ref_height / roughness)
    return 1.0


@njit(cache=True, error_model="numpy")
def _gust_factor(s, t_rise, t_hold):
    """1-cosine gust shape in [0, 1] at ``s`` seconds after its start."""
    if s <= 0.0:
        return 0.0
    if s < t_rise:
        return 0.5 * (1.0 - math.cos(math.pi * s / t_rise))
    s -= t_rise
    if s <= t_hold:
        return 1.0
    s -= t_hold
    if s < t_rise:
        return 0.5 * (1.0 + math.cos(math.pi * s / t_rise))
    return 0.0


def _altitude(position) -> float:
    return max(-float(position[2]), 0.0)


class Wind:
    """Base class: no wind.

    A velocity-field model overrides :meth:`velocity`; a model with direct forces overrides
    :meth:`step` and sets ``has_forces``. Random or stateful models override :meth:`reset`.
    """

    has_forces = False
    random = False  # True when the seed changes the series (the model draws random numbers)

    def reset(self, seed: int | None = 0) -> None:
        """Restart the model (time-dependent state and random stream) from ``seed``."""

    def mean(self, position) -> np.ndarray:
        """The mean (non-turbulent) air velocity at ``position``, NED m/s."""
        return np.zeros(3)

    def velocity(self, t: float, dt: float, position, velocity) -> np.ndarray:
        """The air velocity (NED m/s) held over [t, t + dt]; advances any internal state."""
        return np.zeros(3)

    def step(self, t: float, dt: float, position, velocity):
        """(v_wind NED m/s, f_ext world N, tau_ext body N m) held over [t, t + dt]."""
        return self.velocity(t, dt, position, velocity), np.zeros(3), np.zeros(3)


class ConstantWind(Wind):
    """A steady wind, optionally with a height profile.

    ``profile``: 'none' (same everywhere), 'sqrt60' (ArduPilot SITL: scaled by sqrt(h/60 m) below
    60 m, full above), 'log' (log law, ``speed`` at ``ref_height`` over roughness length
    ``roughness``; zero below it). The profile scales the horizontal part only; ``vertical``
    (updraft, m/s positive up) is the same at every height.
    """

    PROFILES = ("none", "sqrt60", "log")

    def __init__(self, speed: float, direction_from_deg: float = 0.0, vertical: float = 0.0,
                 profile: str = "none", ref_height: float = 10.0, roughness: float = 0.03):
        if profile not in self.PROFILES:
            raise ValueError(f"profile must be one of {', '.join(self.PROFILES)}")
        if speed < 0 or ref_height <= roughness or roughness <= 0:
            raise ValueError("need speed >= 0 and ref_height > roughness > 0")
        self.speed = float(speed)
        self.direction_from_deg = float(direction_from_deg)
        self.vertical = float(vertical)
        self.profile = profile
        self.ref_height = float(ref_height)
        self.roughness = float(roughness)
        self._horizontal = wind_vector(speed, direction_from_deg)
        self._horizontal[2] = 0.0

    def scale(self, altitude: float) -> float:
        """Profile factor for the horizontal wind at ``altitude`` (m above ground)."""
        return _profile_scale(float(self.PROFILES.index(self.profile)), self.ref_height,
                              self.roughness, float(altitude))

    def mean(self, position) -> np.ndarray:
        k = self.scale(_altitude(position))
        return np.array([self._horizontal[0] * k, self._horizontal[1] * k, -self.vertical])

    def velocity(self, t, dt, position, velocity):
        return self.mean(position)


# ---------------------------------------------------------------------------------------------
# Dryden turbulence
# ---------------------------------------------------------------------------------------------

def dryden_scales(altitude_m: float, w20: float) -> tuple[float, float, float, float]:
    """MIL-F-8785C low-altitude Dryden scales: (sigma_u = sigma_v, sigma_w, L_u = L_v, L_w).

    Sigmas in the unit of ``w20``, lengths in m. Altitude is clipped to 10..1000 ft, the range of
    the low-altitude model: L_w = h, L_u = h/(0.177 + 0.000823 h)^1.2, sigma_w = 0.1 W20,
    sigma_u = sigma_w/(0.177 + 0.000823 h)^0.4 (h in ft).
    """
    return _dryden_scales(float(altitude_m), float(w20))


@njit(cache=True, error_model="numpy")
def _dryden_scales(altitude_m, w20):
    h = min(max(altitude_m / FOOT, 10.0), 1000.0)
    k = 0.177 + 0.000823 * h
    sigma_w = 0.1 * w20
    return sigma_w / k ** 0.4, sigma_w, h / k ** 1.2 * FOOT, h * FOOT


@njit(cache=True, error_model="numpy")
def _dryden_setup(mx, my, mz, vx, vy, vz, altitude, w20, v_min, dt):
    """One step's filter arguments of :func:`_dryden_run` for mean wind (mx, my, mz), vehicle
    velocity (vx, vy, vz) and altitude: (eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux, uy)."""
    sig_u, sig_w, l_u, l_w = _dryden_scales(altitude, w20)
    rx = mx - vx
    ry = my - vy
    rz = mz - vz
    travel = max(math.sqrt(rx * rx + ry * ry + rz * rz), v_min) * dt
    horizontal = math.hypot(mx, my)
    if horizontal > 1e-9:
        ux = mx / horizontal
        uy = my / horizontal
    else:
        ux = 1.0
        uy = 0.0
    return travel / l_u, travel / l_u, travel / l_w, sig_u, sig_u, sig_w, ux, uy


@njit(cache=True, error_model="numpy")
def _lower_gamma(k, x):
    """Regularised lower incomplete gamma P(k, x) for integer k >= 1, accurate for small x."""
    if x < 2.0:
        term = math.exp(-x)
        for j in range(1, k + 1):
            term *= x / j
        total = 0.0
        j = k
        while term > 1e-18 * total or total == 0.0:
            total += term
            j += 1
            term *= x / j
            if term == 0.0:
                break
        return total
    term = 1.0
    partial = 1.0
    for j in range(1, k):
        term *= x / j
        partial += term
    return 1.0 - math.exp(-x) * partial


@njit(cache=True, error_model="numpy")
def _dryden2_coeffs(eps, out):
    """Exact discretisation over eps = V dt / L of the unit Dryden v/w filter.

    Normalised filter (distance in units of L): x1' = x2, x2' = -x1 - 2 x2 + n (unit white noise),
    output x1 + sqrt(3) x2, whose stationary variance is 1 and transfer (1 + sqrt3 s)/(1 + s)^2.
    out = [phi11, phi12, phi21, phi22, l11, l21, l22]: x+ = Phi x + L eta, L L^T the noise
    covariance int_0^eps e^{As} B B^T e^{A^T s} ds, written with I_n = int_0^eps u^n e^{-2u} du.
    """
    e = math.exp(-eps)
    out[0] = e * (1.0 + eps)
    out[1] = e * eps
    out[2] = -e * eps
    out[3] = e * (1.0 - eps)
    x = 2.0 * eps
    i0 = 0.5 * _lower_gamma(1, x)
    i1 = 0.25 * _lower_gamma(2, x)
    i2 = 0.25 * _lower_gamma(3, x)
    q11 = i2
    q12 = i1 - i2
    q22 = i0 - 2.0 * i1 + i2
    l11 = math.sqrt(q11)
    l21 = q12 / l11 if l11 > 0.0 else 0.0
    out[4] = l11
    out[5] = l21
    out[6] = math.sqrt(max(q22 - l21 * l21, 0.0))


@njit(cache=True, error_model="numpy")
def _dryden_run(state, eta, eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux, uy, out):
    """Advance the normalised Dryden states len(out) steps; write NED turbulence rows to out.

    state = [u, v1, v2, w1, w2] (stationary covariance: u 1, the pairs 1/4 I), eta (n, 5) unit
    normals, eps_* = V dt / L_* per step, (ux, uy) the horizontal unit vector of u; v is 90 deg
    to its right, w is down.
    """
    _dryden_run_into(state, eta, eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux, uy, out,
                     np.empty(7), np.empty(7))


@njit(cache=True, error_model="numpy")
def _dryden_run_into(state, eta, eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux, uy, out, cv, cw):
    """:func:`_dryden_run` with the filters' coefficient arrays (7 each) passed in."""
    a = math.exp(-eps_u)
    b = math.sqrt(-math.expm1(-2.0 * eps_u))
    _dryden2_coeffs(eps_v, cv)
    _dryden2_coeffs(eps_w, cw)
    s3 = math.sqrt(3.0)
    for k in range(out.shape[0]):
        state[0] = a * state[0] + b * eta[k, 0]
        v1 = cv[0] * state[1] + cv[1] * state[2] + cv[4] * eta[k, 1]
        v2 = cv[2] * state[1] + cv[3] * state[2] + cv[5] * eta[k, 1] + cv[6] * eta[k, 2]
        w1 = cw[0] * state[3] + cw[1] * state[4] + cw[4] * eta[k, 3]
        w2 = cw[2] * state[3] + cw[3] * state[4] + cw[5] * eta[k, 3] + cw[6] * eta[k, 4]
        state[1] = v1
        state[2] = v2
        state[3] = w1
        state[4] = w2
        u = sig_u * state[0]
        v = sig_v * (v1 + s3 * v2)
        out[k, 0] = u * ux - v * uy
        out[k, 1] = u * uy + v * ux
        out[k, 2] = sig_w * (w1 + s3 * w2)


class DrydenTurbulence(Wind):
    """MIL-F-8785C low-altitude Dryden turbulence, discretised exactly.

    The turbulence is a frozen field advected past the vehicle at V = max(|mean wind - vehicle
    velocity|, v_min), so each step covers V*dt of it. u: x+ = a x + sqrt(1 - a^2) eta with
    a = exp(-V dt / L_u); v and w: the exact two-state discretisation of the Dryden filter
    (matrix exponential and Cholesky factor of the step's noise covariance, in closed form). The
    realised standard deviation is sigma at any dt, and the states start stationary.

    Components: u along the horizontal mean wind, v crosswind (to its right), w down; with no mean
    wind, u is north. Intensity: ``w20`` (m/s, wind at 20 ft) or ``intensity`` ('light',
    'moderate', 'severe': 15 / 30 / 45 kt); with neither, W20 is the horizontal mean wind 20 ft
    above the origin (a property of the site, read once). ``mean_wind`` is the model giving the
    mean wind (e.g. a ConstantWind), or None.
    """

    random = True

    def __init__(self, w20: float | None = None, intensity: str | None = None,
                 mean_wind: Wind | None = None, v_min: float = 1.5, seed: int | None = 0):
        if intensity is not None:
            if intensity not in DRYDEN_W20:
                raise ValueError(f"intensity must be one of {', '.join(DRYDEN_W20)}")
            if w20 is not None:
                raise ValueError("give either w20 or intensity, not both")
            w20 = DRYDEN_W20[intensity]
        if w20 is None and mean_wind is None:
            raise ValueError("give w20 or intensity (or a mean wind to take W20 from)")
        if w20 is not None and w20 < 0:
            raise ValueError("w20 must be >= 0")
        if v_min <= 0:
            raise ValueError("v_min must be > 0")
        self.w20 = None if w20 is None else float(w20)
        self.mean_wind = mean_wind
        if w20 is None:
            at20 = mean_wind.mean(np.array([0.0, 0.0, -20.0 * FOOT]))
            w20 = math.hypot(at20[0], at20[1])
        self._w20 = float(w20)
        self.v_min = float(v_min)
        self.state = np.zeros(5)
        self.reset(seed)

    def reset(self, seed: int | None = 0) -> None:
        self._rng = np.random.default_rng(seed)
        self.state[:] = self._rng.standard_normal(5) * np.array([1.0, 0.5, 0.5, 0.5, 0.5])

    def mean(self, position) -> np.ndarray:
        return np.zeros(3)

    def _setup(self, dt, position, velocity):
        if self.mean_wind is not None:
            mx, my, mz = self.mean_wind.mean(position).tolist()
        else:
            mx = my = mz = 0.0
        vx, vy, vz = velocity.tolist() if isinstance(velocity, np.ndarray) else velocity
        return _dryden_setup(mx, my, mz, float(vx), float(vy), float(vz), _altitude(position),
                             self._w20, self.v_min, float(dt))

    def sample(self, n: int, dt: float, position, velocity) -> np.ndarray:
        """Advance n steps of dt at a held position and velocity; (n, 3) NED turbulence."""
        args = self._setup(dt, position, velocity)
        out = np.empty((n, 3))
        chunk = 1 << 16
        for start in range(0, n, chunk):
            stop = min(start + chunk, n)
            eta = self._rng.standard_normal((stop - start, 5))
            _dryden_run(self.state, eta, *args, out[start:stop])
        return out

    def velocity(self, t, dt, position, velocity):
        out = np.empty((1, 3))
        _dryden_run(self.state, self._rng.standard_normal((1, 5)),
                    *self._setup(dt, position, velocity), out)
        return out[0]


# ---------------------------------------------------------------------------------------------
# Deterministic time profiles
# ---------------------------------------------------------------------------------------------

class OneMinusCosineGust(Wind):
    """Discrete gust: (A/2)(1 - cos(pi (t - t_start)/t_rise)) rise, hold A for t_hold, then the
    mirror-image fall over t_rise. ``amplitude`` is the peak NED air velocity (3,)."""

    def __init__(self, amplitude: Sequence[float], t_start: float, t_rise: float,
                 t_hold: float = 0.0):
        if t_rise <= 0 or t_hold < 0:
            raise ValueError("need t_rise > 0 and t_hold >= 0")
        self.amplitude = np.array(amplitude, dtype=float).reshape(3)
        self.t_start = float(t_start)
        self.t_rise = float(t_rise)
        self.t_hold = float(t_hold)

    def factor(self, t: float) -> float:
        """Gust shape in [0, 1] at time t."""
        return _gust_factor(float(t) - self.t_start, self.t_rise, self.t_hold)

    def velocity(self, t, dt, position, velocity):
        return self.amplitude * self.factor(t)


class SinusoidWind(Wind):
    """v = amplitude * sin(2 pi freq t + phase); ``amplitude`` is the NED peak vector (3,)."""

    def __init__(self, amplitude: Sequence[float], freq: float, phase: float = 0.0):
        if freq < 0:
            raise ValueError("freq must be >= 0")
        self.amplitude = np.array(amplitude, dtype=float).reshape(3)
        self.freq = float(freq)
        self.phase = float(phase)

    def velocity(self, t, dt, position, velocity):
        return self.amplitude * math.sin(2.0 * math.pi * self.freq * t + self.phase)


# ---------------------------------------------------------------------------------------------
# The thesis's model
# ---------------------------------------------------------------------------------------------

class ThesisWind(Wind):
    """The thesis's wind disturbance, eqs. 9-13, exactly as printed (sec. 4.2).

    Per rotor i: f_mi = kF w^2 (w in rpm, kF in N/rpm^2), f_wi = 2 rho A Vp^2 sqrt(1 + Vw^2/Vp^2)
    - f_mi. Eq. 13 adds sum(f_wi)/m to x'', y'' and z'' (z up), so here f_ext = (S, S, -S) with
    S = sum(f_wi), in N (the physics divides by the vehicle's mass). Torques go to the same-named
    axes: tau_x = (f_w4 - f_w2) l, tau_y = (f_w3 - f_w1) l, tau_z = sum_i k_drag Vw^2 (eq. 12).
    No air velocity is produced (v_wind = 0).

    With the published numbers f_wi = -0.248 N per rotor: -0.99 N on each axis, 33 m/s^2 on a
    30 g vehicle for a 1 m/s wind, and k_drag = rho/2 (as eq. 12's text defines it) gives a yaw
    torque of 2.59 N m. docs/vehicle.md explains why this is not a wind model.
    """

    has_forces = True

    def __init__(self, rho: float, area: float, v_p: float, v_w: float, k_f_rpm2: float,
                 rotor_rpm: float | Sequence[float], arm_length: float, k_drag: float):
        if v_p <= 0:
            raise ValueError("v_p must be > 0")
        self.rho = float(rho)
        self.area = float(area)
        self.v_p = float(v_p)
        self.v_w = float(v_w)
        self.k_f_rpm2 = float(k_f_rpm2)
        self.rotor_rpm = np.broadcast_to(np.asarray(rotor_rpm, dtype=float), 4).copy()
        self.arm_length = float(arm_length)
        self.k_drag = float(k_drag)

    def rotor_forces(self) -> np.ndarray:
        """f_wi (N) for the four rotors, eq. 11."""
        f_m = self.k_f_rpm2 * self.rotor_rpm ** 2
        lift = 2.0 * self.rho * self.area * self.v_p ** 2 * math.sqrt(
            1.0 + self.v_w ** 2 / self.v_p ** 2)
        return lift - f_m

    def step(self, t, dt, position, velocity):
        f = self.rotor_forces()
        s = float(f.sum())
        l = self.arm_length
        tau = np.array([(f[3] - f[1]) * l, (f[2] - f[0]) * l, 4.0 * self.k_drag * self.v_w ** 2])
        return np.zeros(3), np.array([s, s, -s]), tau


# ---------------------------------------------------------------------------------------------
# Sums and configuration
# ---------------------------------------------------------------------------------------------

class CompositeWind(Wind):
    """The sum of several wind models; each random part gets its own stream from one seed."""

    def __init__(self, parts: Sequence[Wind] = (), seed: int | None = 0):
        self.parts = list(parts)
        self.reset(seed)

    def reset(self, seed: int | None = 0) -> None:
        children = np.random.SeedSequence(seed).spawn(len(self.parts))
        for part, child in zip(self.parts, children):
            part.reset(child)

    def mean(self, position) -> np.ndarray:
        total = np.zeros(3)
        for part in self.parts:
            total += part.mean(position)
        return total

    @property
    def has_forces(self) -> bool:
        return any(part.has_forces for part in self.parts)

    @property
    def random(self) -> bool:
        return any(part.random for part in self.parts)

    def velocity(self, t, dt, position, velocity):
        v = np.zeros(3)
        for part in self.parts:
            v += part.velocity(t, dt, position, velocity)
        return v

    def step(self, t, dt, position, velocity):
        v = np.zeros(3)
        f = np.zeros(3)
        tau = np.zeros(3)
        for part in self.parts:
            if part.has_forces:
                pv, pf, pt = part.step(t, dt, position, velocity)
                f += pf
                tau += pt
            else:
                pv = part.velocity(t, dt, position, velocity)
            v += pv
        return v, f, tau


class LayeredWind(Wind):
    """Two winds summed without reseeding either (CompositeWind reseeds its parts): how the
    vehicle's server lays a ground station's SIM_WIND_* wind over the configured one in flight."""

    def __init__(self, base, extra):
        self.base = base
        self.extra = extra

    @classmethod
    def over(cls, base, extra):
        if extra is None:
            return base
        if base is None:
            return extra
        return cls(base, extra)

    @property
    def random(self) -> bool:
        return self.base.random or self.extra.random

    def mean(self, position):
        return self.base.mean(position) + self.extra.mean(position)

    def step(self, t, dt, position, velocity):
        v1, f1, m1 = self.base.step(t, dt, position, velocity)
        v2, f2, m2 = self.extra.step(t, dt, position, velocity)
        return v1 + v2, f1 + f2, m1 + m2


def _vector_or_heading(sec: Section, key: str) -> np.ndarray:
    """``key`` as an NED vector [n, e, d], or a number with direction_from_deg (and vertical)."""
    if sec.has(key) and isinstance(sec.data[key], list):
        return sec.vector(key, 3)
    speed = sec.number(key)
    return wind_vector(speed, sec.number("direction_from_deg", 0.0), sec.number("vertical", 0.0))


def _constant(sec: Section) -> ConstantWind:
    speed = sec.number("speed", ge=0)
    direction = sec.number("direction_from_deg", 0.0)
    vertical = sec.number("vertical", 0.0)
    profile = sec.string("profile", "none", choices=ConstantWind.PROFILES)
    roughness = sec.number("roughness", 0.03, gt=0)
    ref_height = sec.number("ref_height", 10.0, gt=roughness)
    return ConstantWind(speed, direction, vertical, profile, ref_height, roughness)


def _dryden(sec: Section, mean_wind: Wind | None) -> DrydenTurbulence:
    intensity = sec.string("intensity", None, choices=tuple(DRYDEN_W20))
    w20 = sec.number("w20", None, ge=0)
    if intensity is not None and w20 is not None:
        sec.error("w20", "give either w20 or intensity, not both")
    if intensity is None and w20 is None and mean_wind is None:
        sec.error(None, "give intensity or w20, or add a constant component to take W20 from")
    return DrydenTurbulence(w20=w20, intensity=intensity, mean_wind=mean_wind,
                            v_min=sec.number("v_min", 1.5, gt=0))


def _gust(sec: Section) -> OneMinusCosineGust:
    amplitude = _vector_or_heading(sec, "amplitude")
    return OneMinusCosineGust(amplitude, sec.number("t_start", ge=0), sec.number("t_rise", gt=0),
                              sec.number("t_hold", 0.0, ge=0))


def _sinusoid(sec: Section) -> SinusoidWind:
    amplitude = _vector_or_heading(sec, "amplitude")
    return SinusoidWind(amplitude, sec.number("freq_hz", ge=0),
                        math.radians(sec.number("phase_deg", 0.0)))


def _thesis(sec: Section) -> ThesisWind:
    return ThesisWind(
        rho=sec.number("rho", gt=0), area=sec.number("area", gt=0), v_p=sec.number("v_p", gt=0),
        v_w=sec.number("v_w", ge=0), k_f_rpm2=sec.number("k_f_rpm2", ge=0),
        rotor_rpm=sec.number("rotor_rpm", ge=0), arm_length=sec.number("arm_length", gt=0),
        k_drag=sec.number("k_drag", ge=0))


_BUILDERS = {"constant": _constant, "gust": _gust, "sinusoid": _sinusoid, "thesis": _thesis}
_TYPES = ("constant", "dryden", "gust", "sinusoid", "thesis")


def load_wind(path_or_mapping: str | Path | dict[str, Any], seed: int | None = 0) -> Wind:
    """Build a wind model from YAML (a file, a bare name meaning configs/wind/NAME.yaml, or an
    already-loaded mapping), reset with ``seed``.

    Forms: ``{type: constant, ...}`` for one part, ``{components: [{type: ...}, ...]}`` for a
    sum, ``{components: []}`` for calm. A Dryden part takes its mean wind (axes, advection, and
    W20 if it has no intensity/w20) from the constant parts of the same file.
    """
    if isinstance(path_or_mapping, dict):
        sec = Section(path_or_mapping, "<wind mapping>")
    else:
        path = config_path(path_or_mapping, "wind")
        sec = Section(load_yaml(path), str(path))
    sec.string("name", "")
    sec.string("description", "")
    single = not sec.has("components")
    sections = [sec] if single else sec.sections("components")
    kinds = [s.string("type", choices=_TYPES) for s in sections]
    parts: list[Wind | None] = [None if kind == "dryden" else _BUILDERS[kind](s)
                                for s, kind in zip(sections, kinds)]
    means = [p for p in parts if isinstance(p, ConstantWind)]
    mean_wind = means[0] if len(means) == 1 else (CompositeWind(means) if means else None)
    for i, kind in enumerate(kinds):
        if kind == "dryden":
            parts[i] = _dryden(sections[i], mean_wind)
    for s in sections:
        s.finish()
    if not single:
        sec.finish()
    wind = parts[0] if single else CompositeWind(parts)
    wind.reset(seed)
    return wind


# ---------------------------------------------------------------------------------------------
# Compiled form
# ---------------------------------------------------------------------------------------------
# The common winds (at most one constant part, at most one Dryden part taking its mean from it,
# any number of gusts and sinusoids, the thesis's constant forces) pack into one float vector that
# a compiled loop evaluates per physics step with exactly the formulas above.  The Dryden part's
# unit normals still come from its numpy Generator, drawn ahead in blocks by the caller: the
# stream is the same whether it is drawn one row or a thousand rows at a time.

WP_MEAN = 0        # horizontal mean wind x, y (m/s)
WP_MEAN_Z = 2      # vertical air velocity, NED (-updraft)
WP_PROFILE = 3     # 0 none, 1 sqrt60, 2 log
WP_REF_H = 4
WP_ROUGH = 5
WP_DRYDEN = 6      # 1.0 if a Dryden part is present
WP_W20 = 7
WP_VMIN = 8
WP_FORCE = 9       # f_ext (3, world N) and tau_ext (3, body N m), constant
WP_NGUST = 15
WP_NSINE = 16
WP_ITEMS = 17      # gusts: [ax, ay, az, t_start, t_rise, t_hold]; then sines: [ax, ay, az, f, phase]
GUST_SIZE = 6
SINE_SIZE = 5
WIND_SCRATCH = 17


class PackedWind:
    """A wind model in compiled form: ``params`` for :func:`wind_step_packed`, and the Dryden
    part (its ``state`` is advanced in place, its generator supplies the normals) or None."""

    def __init__(self, params, dryden):
        self.params = params
        self.dryden = dryden

    def normals(self, n):
        """The next n rows of unit normals the Dryden part would draw ((n, 5); empty if none)."""
        if self.dryden is None:
            return np.zeros((n, 5))
        return self.dryden._rng.standard_normal((n, 5))

    @property
    def state(self):
        return self.dryden.state if self.dryden is not None else np.zeros(5)


def pack_wind(wind):
    """:class:`PackedWind` for ``wind``, or None when its structure has no compiled form (the
    per-step Python path then runs it, with the same physics)."""
    if wind is None:
        return None
    parts = wind.parts if type(wind) is CompositeWind else [wind]
    consts, dry, gusts, sines, forces = [], [], [], [], []
    for part in parts:
        kind = type(part)
        if kind is ConstantWind:
            consts.append(part)
        elif kind is DrydenTurbulence:
            dry.append(part)
        elif kind is OneMinusCosineGust:
            gusts.append(part)
        elif kind is SinusoidWind:
            sines.append(part)
        elif kind is ThesisWind:
            forces.append(part)
        elif kind is Wind:
            continue
        else:
            return None
    if len(consts) > 1 or len(dry) > 1:
        return None
    if dry and dry[0].mean_wind is not None and (not consts or dry[0].mean_wind is not consts[0]):
        return None
    wp = np.zeros(WP_ITEMS + GUST_SIZE * len(gusts) + SINE_SIZE * len(sines))
    if consts:
        c = consts[0]
        wp[WP_MEAN:WP_MEAN + 2] = c._horizontal[0:2]
        wp[WP_MEAN_Z] = -c.vertical
        wp[WP_PROFILE] = ConstantWind.PROFILES.index(c.profile)
        wp[WP_REF_H] = c.ref_height
        wp[WP_ROUGH] = c.roughness
    if dry:
        d = dry[0]
        wp[WP_DRYDEN] = 1.0
        wp[WP_W20] = d._w20
        wp[WP_VMIN] = d.v_min
        if d.mean_wind is None:  # the Dryden's axes and advection then ignore the constant part
            if consts:
                return None
    for f in forces:
        _, fe, te = f.step(0.0, 0.0, np.zeros(3), np.zeros(3))
        wp[WP_FORCE:WP_FORCE + 3] += fe
        wp[WP_FORCE + 3:WP_FORCE + 6] += te
    wp[WP_NGUST] = len(gusts)
    wp[WP_NSINE] = len(sines)
    k = WP_ITEMS
    for g in gusts:
        wp[k:k + 3] = g.amplitude
        wp[k + 3:k + 6] = (g.t_start, g.t_rise, g.t_hold)
        k += GUST_SIZE
    for s in sines:
        wp[k:k + 3] = s.amplitude
        wp[k + 3:k + 5] = (s.freq, s.phase)
        k += SINE_SIZE
    return PackedWind(wp, dry[0] if dry else None)


@njit(cache=True, error_model="numpy")
def wind_step_packed(wp, dstate, eta, k, t, dt, x, v_out, f_out, tau_out, scratch):
    """The packed wind over [t, t + dt] for state x (position x[0:3], velocity x[3:6]):
    writes v_out, f_out, tau_out as :meth:`Wind.step` returns them; ``eta[k]`` is the Dryden
    part's row of normals for this step; ``scratch``: (WIND_SCRATCH,) work space."""
    alt = max(-x[2], 0.0)
    sc = _profile_scale(wp[WP_PROFILE], wp[WP_REF_H], wp[WP_ROUGH], alt)
    mx = wp[WP_MEAN] * sc
    my = wp[WP_MEAN + 1] * sc
    mz = wp[WP_MEAN_Z]
    v_out[0] = mx
    v_out[1] = my
    v_out[2] = mz
    if wp[WP_DRYDEN] != 0.0:
        eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux, uy = _dryden_setup(
            mx, my, mz, x[3], x[4], x[5], alt, wp[WP_W20], wp[WP_VMIN], dt)
        out = scratch[0:3].reshape((1, 3))
        _dryden_run_into(dstate, eta[k:k + 1], eps_u, eps_v, eps_w, sig_u, sig_v, sig_w, ux,
                         uy, out, scratch[3:10], scratch[10:17])
        v_out[0] += out[0, 0]
        v_out[1] += out[0, 1]
        v_out[2] += out[0, 2]
    j = WP_ITEMS
    for _ in range(int(wp[WP_NGUST])):
        fac = _gust_factor(t - wp[j + 3], wp[j + 4], wp[j + 5])
        v_out[0] += wp[j] * fac
        v_out[1] += wp[j + 1] * fac
        v_out[2] += wp[j + 2] * fac
        j += GUST_SIZE
    for _ in range(int(wp[WP_NSINE])):
        s = math.sin(2.0 * math.pi * wp[j + 3] * t + wp[j + 4])
        v_out[0] += wp[j] * s
        v_out[1] += wp[j + 1] * s
        v_out[2] += wp[j + 2] * s
        j += SINE_SIZE
    for i in range(3):
        f_out[i] = wp[WP_FORCE + i]
        tau_out[i] = wp[WP_FORCE + 3 + i]
