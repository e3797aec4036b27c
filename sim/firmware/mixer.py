"""Mixer: collective thrust + body torques -> rotor speed commands, keeping attitude authority.

The allocation matrix A maps squared rotor speeds to ``[T, tau_x, tau_y, tau_z]``; the mixer
applies its inverse B and then fits the result into the motors' range [omega_min^2, omega_max^2]
the way PX4's airmode does, in order of priority:

1. roll and pitch torque are kept whole by shifting the collective thrust (all rotors up or down
   together, the thrust column of B); only if their spread alone exceeds the motors' range are
   they scaled down, both by the same factor so the torque direction is kept;
2. among the thrust shifts that fit, the one closest to the requested thrust is taken;
3. yaw torque is added last and is the first to be reduced when it does not fit; it may move the
   thrust by at most 15% of the thrust range (PX4 gives yaw the same 15% headroom).

With ``airmode=False`` the thrust may only be lowered, never raised, to make room (PX4 with
MC_AIRMODE off): at zero thrust the vehicle then has no attitude authority.  The mixer reports
the wrench the commanded rotor speeds really produce in steady state, which is what observers
and anti-windup must be fed.
"""

import math

import numpy as np

from mavadrc.control.jit import jit

# layout of the mixer parameter vector
MX_B = 0  # 16: inverse allocation, row-major, wrench -> squared rotor speeds
MX_A = 16  # 16: allocation, row-major, squared rotor speeds -> wrench
MX_LO = 32  # omega_min^2
MX_HI = 33  # omega_max^2
MX_AIRMODE = 34  # 1.0: the thrust may be raised to keep roll/pitch authority
NMX = 35
NWK_MIX = 20  # scratch floats mix() needs

YAW_SHIFT = 0.15  # fraction of the thrust range yaw may take from (or add to) the thrust
_BISECT = 40  # bisection steps for the reduction factors (2^-40 resolution)


@jit
def _shift_range(u, d, lo, hi, smin, smax):
    """Interval [a, b] of shifts s with lo <= u_i + s*d_i <= hi for all rotors, within [smin, smax].

    Empty when a > b.
    """
    a = smin
    b = smax
    for i in range(4):
        di = d[i]
        if di > 0.0:
            a = max(a, (lo - u[i]) / di)
            b = min(b, (hi - u[i]) / di)
        elif di < 0.0:
            a = max(a, (hi - u[i]) / di)
            b = min(b, (lo - u[i]) / di)
        elif u[i] < lo or u[i] > hi:
            return math.inf, -math.inf
    return a, b


@jit
def _fits(base, extra, k, d, lo, hi, smin, smax, u):
    """Whether base + k*extra can be shifted along d into range (u receives base + k*extra)."""
    for i in range(4):
        u[i] = base[i] + k * extra[i]
    a, b = _shift_range(u, d, lo, hi, smin, smax)
    tol = 1e-12 * (hi - lo)
    return a <= b + tol


@jit
def _largest_fit(base, extra, d, lo, hi, smin, smax, u):
    """Largest k in [0, 1] for which base + k*extra fits (base itself is assumed to fit)."""
    if _fits(base, extra, 1.0, d, lo, hi, smin, smax, u):
        return 1.0
    k_ok = 0.0
    k_bad = 1.0
    for _ in range(_BISECT):
        k = 0.5 * (k_ok + k_bad)
        if _fits(base, extra, k, d, lo, hi, smin, smax, u):
            k_ok = k
        else:
            k_bad = k
    return k_ok


@jit
def mix(mx, thrust, tx, ty, tz, omega, wrench, wk):
    """Rotor speed commands (written to ``omega``) for thrust (N) and body torques (N m).

    ``wrench`` receives the [T, tau_x, tau_y, tau_z] the commanded speeds produce.  Every command
    lies in [omega_min, omega_max].  ``wk``: scratch of NWK_MIX floats.  Returns the roll/pitch
    scale factor (1.0: kept whole).
    """
    lo = mx[MX_LO]
    hi = mx[MX_HI]
    t_min = 0.0
    t_max = 0.0
    for i in range(4):
        t_min += mx[MX_A + i] * lo
        t_max += mx[MX_A + i] * hi
    if thrust < t_min:
        thrust = t_min
    if thrust > t_max:
        thrust = t_max
    d = wk[0:4]
    base = wk[4:8]
    rp = wk[8:12]
    yw = wk[12:16]
    u = wk[16:20]
    for i in range(4):
        r = MX_B + 4 * i
        d[i] = mx[r]
        base[i] = mx[r] * thrust
        rp[i] = mx[r + 1] * tx + mx[r + 2] * ty
        yw[i] = mx[r + 3] * tz
    smax = math.inf if mx[MX_AIRMODE] != 0.0 else 0.0
    k_rp = _largest_fit(base, rp, d, lo, hi, -math.inf, smax, u)
    for i in range(4):
        base[i] += k_rp * rp[i]
    a, b = _shift_range(base, d, lo, hi, -math.inf, smax)
    s = min(max(0.0, a), b)
    for i in range(4):
        base[i] += s * d[i]
    # yaw may move the thrust by a little more, never by more than YAW_SHIFT of its range
    budget = YAW_SHIFT * (t_max - t_min)
    ymax = budget if mx[MX_AIRMODE] != 0.0 else -s
    k_y = _largest_fit(base, yw, d, lo, hi, -budget, min(budget, ymax), u)
    for i in range(4):
        u[i] = base[i] + k_y * yw[i]
    a, b = _shift_range(u, d, lo, hi, -budget, min(budget, ymax))
    s = min(max(0.0, a), b)
    for i in range(4):
        w2 = u[i] + s * d[i]
        if w2 < lo:
            w2 = lo
        if w2 > hi:
            w2 = hi
        u[i] = w2
        omega[i] = math.sqrt(w2)
    for j in range(4):
        acc = 0.0
        for i in range(4):
            acc += mx[MX_A + 4 * j + i] * u[i]
        wrench[j] = acc
    return k_rp


@jit
def thrust_curve(k, u):
    """Rotor thrust as a fraction of its range at normalized motor output ``u`` in [0, 1]:
    ``k u^2 + (1 - k) u``, the form of PX4's THR_MDL_FAC and ArduPilot's MOT_THST_EXPO
    (k = 0: thrust linear in the output; k = 1: rotor speed linear in it, thrust quadratic).
    Monotonic on [0, 1] for k in [-1, 1]."""
    return u * (k * u + (1.0 - k))


@jit
def thrust_curve_inverse(k, f):
    """The motor output u in [0, 1] whose thrust fraction under :func:`thrust_curve` is ``f``:
    the root of ``k u^2 + (1 - k) u = f``, written so that it holds at k = 0 and near it."""
    if f <= 0.0:
        return 0.0
    if f >= 1.0:
        return 1.0
    b = 1.0 - k
    return 2.0 * f / (b + math.sqrt(b * b + 4.0 * k * f))


@jit
def apply_motor_curve(mx, assumed, true_k, omega):
    """Rotor speeds (rad/s, in place) that motors with thrust curve factor ``true_k`` reach for
    the commands ``omega`` of an autopilot that linearises with factor ``assumed``.

    Each command's thrust fraction f = (omega^2 - omega_min^2) / (omega_max^2 - omega_min^2) is
    turned into the motor output u the autopilot believes gives it (inverse of its curve), and
    the motor makes thrust fraction thrust_curve(true_k, u) of that output.  Equal factors give
    back the commands (to rounding)."""
    lo = mx[MX_LO]
    span = mx[MX_HI] - lo
    for i in range(4):
        f = (omega[i] * omega[i] - lo) / span
        u = thrust_curve_inverse(assumed, f)
        omega[i] = math.sqrt(lo + span * thrust_curve(true_k, u))


def curve_mismatch(vehicle, assumed):
    """Whether the vehicle's motors' thrust curve differs from the autopilot's assumption."""
    k = vehicle.motor_thrust_curve
    return k is not None and float(k) != float(assumed)


def hover_command(vehicle, thrust_scale, assumed):
    """Normalized collective thrust that holds a level hover: ``thrust_scale`` N per unit as
    the autopilot believes, linearised with its factor ``assumed``, through the vehicle's real
    motor curve (``motor_thrust_curve``; None or equal: weight / thrust_scale)."""
    if not curve_mismatch(vehicle, assumed):
        return vehicle.weight / thrust_scale
    lo = vehicle.omega_min ** 2
    span = vehicle.omega_max ** 2 - lo
    real = (vehicle.weight / (4.0 * vehicle.k_f) - lo) / span  # each rotor's share, as it is
    believed = thrust_curve(float(assumed), thrust_curve_inverse(vehicle.motor_thrust_curve, real))
    return 4.0 * vehicle.k_f * (lo + span * believed) / thrust_scale


def mixer_params(allocation, omega_min, omega_max, airmode=True):
    """Mixer parameter vector from the (4, 4) allocation matrix and the rotor speed range."""
    A = np.asarray(allocation, dtype=np.float64)
    if A.shape != (4, 4):
        raise ValueError(f"allocation must be a 4x4 matrix (got shape {A.shape})")
    if not (0.0 <= omega_min < omega_max and math.isfinite(omega_max)):
        raise ValueError(f"need 0 <= omega_min < omega_max (got {omega_min!r}, {omega_max!r})")
    B = np.linalg.inv(A)
    if not np.all(B[:, 0] > 0.0):
        raise ValueError("every rotor must contribute to the collective thrust (B[:, 0] > 0)")
    mx = np.empty(NMX)
    mx[MX_B:MX_B + 16] = B.reshape(16)
    mx[MX_A:MX_A + 16] = A.reshape(16)
    mx[MX_LO] = float(omega_min) ** 2
    mx[MX_HI] = float(omega_max) ** 2
    mx[MX_AIRMODE] = 1.0 if airmode else 0.0
    return mx


class Mixer:
    """Thin holder of the mixer parameters of one vehicle.

    ``Mixer(vehicle)`` with a :class:`sim.params.VehicleParams`; ``mix(thrust, torque)`` returns
    (rotor speed commands rad/s, achieved [T, tau_x, tau_y, tau_z]).
    """

    def __init__(self, vehicle, airmode=True):
        self.params = mixer_params(vehicle.allocation_matrix(), vehicle.omega_min,
                                   vehicle.omega_max, airmode)
        self._omega = np.zeros(4)
        self._wrench = np.zeros(4)
        self._wk = np.zeros(NWK_MIX)

    def mix(self, thrust, torque):
        mix(self.params, float(thrust), float(torque[0]), float(torque[1]), float(torque[2]),
            self._omega, self._wrench, self._wk)
        return self._omega.copy(), self._wrench.copy()

    def torque_authority(self, thrust):
        """Largest torque (N m) about each body axis alone at collective thrust ``thrust``."""
        big = 1e3 * float(np.max(np.abs(self.params[MX_A:MX_A + 16]))) * self.params[MX_HI]
        out = np.empty(3)
        for axis in range(3):
            tau = np.zeros(3)
            tau[axis] = big
            out[axis] = self.mix(thrust, tau)[1][1 + axis]
        return out
