"""Attitude controller: roll, pitch and yaw channels of one kind, outputs body torques.

The thesis's inner loop: each Euler angle is a second-order channel ``angle'' = tau/I + f`` with
``b0 = 1/I`` per axis (the thesis used one b0 = 0.83 for every channel, off by orders of
magnitude for its own plant).  PD channels use the measured body rates converted to Euler rates;
the yaw measurement is unwrapped so a heading crossing +-pi never looks like a 2*pi step.
"""

import math

import numpy as np

from . import kernels as K
from .channels import nonfinite_arrays
from .jit import jit
from .position import axis_params
from .rotations import wrap_pi

# unwrap state layout
W_YAW = 0  # last unwrapped yaw
W_INIT = 1


@jit
def attitude_update(S, P, euler, rates, ref, ref_rate, ref_acc, W, tau):
    """One step of the three attitude channels; writes torques to ``tau``; False on bad input.

    The attitude loop runs at its fixed rate: every step is the nominal step of ``P``.
    """
    for i in range(3):
        if not (math.isfinite(euler[i]) and math.isfinite(rates[i]) and math.isfinite(ref[i])
                and math.isfinite(ref_rate[i]) and math.isfinite(ref_acc[i])):
            return False
    phi = euler[0]
    th = euler[1]
    sphi = math.sin(phi)
    cphi = math.cos(phi)
    cth = math.cos(th)
    if abs(cth) < 1e-6:
        cth = 1e-6
    p, q, r = rates[0], rates[1], rates[2]
    phidot = p + (q * sphi + r * cphi) * math.sin(th) / cth
    thdot = q * cphi - r * sphi
    psidot = (q * sphi + r * cphi) / cth
    if W[W_INIT] == 0.0:
        yaw = euler[2]
        W[W_INIT] = 1.0
    else:
        yaw = W[W_YAW] + wrap_pi(euler[2] - W[W_YAW])
    W[W_YAW] = yaw
    yaw_ref = yaw + wrap_pi(ref[2] - yaw)
    tau[0] = K.channel_update(S[0], P[0], phi, phidot, ref[0], ref_rate[0], ref_acc[0],
                              P[0, K.P_H])
    tau[1] = K.channel_update(S[1], P[1], th, thdot, ref[1], ref_rate[1], ref_acc[1],
                              P[1, K.P_H])
    tau[2] = K.channel_update(S[2], P[2], yaw, psidot, yaw_ref, ref_rate[2], ref_acc[2],
                              P[2, K.P_H])
    return True


class AttitudeController:
    """Roll, pitch, yaw channels -> body torques (N m).

    ``AttitudeController(kind="ladrc", h=0.001, inertia=(1.43e-5, 1.43e-5, 2.89e-5),
    wc=(30, 30, 10), wo=(150, 150, 50), torque_max=(...))``.  ``b0`` defaults to 1/I per axis.
    Gain keywords as for :class:`~mavadrc.control.position.PositionController`.
    """

    def __init__(self, kind="ladrc", *, h, inertia, torque_max=None, **gains):
        inertia = [float(v) for v in inertia]
        if len(inertia) != 3 or not all(math.isfinite(v) and v > 0.0 for v in inertia):
            raise ValueError(f"inertia must be three finite numbers > 0 (got {inertia!r})")
        self.kind = kind
        gains = dict(gains)
        gains.setdefault("b0", tuple(1.0 / v for v in inertia))
        if torque_max is not None:
            tm = [float(torque_max[i] if np.ndim(torque_max) else torque_max) for i in range(3)]
            if not all(math.isfinite(v) and v > 0.0 for v in tm):
                raise ValueError(f"torque_max must be > 0 (got {torque_max!r})")
            gains["u_min"] = tuple(-v for v in tm)
            gains["u_max"] = tuple(tm)
        self._P = np.stack([axis_params(kind, i, h, gains) for i in range(3)])
        self._S = np.zeros((3, K.NS))
        self._W = np.zeros(2)
        self._tau = np.zeros(3)
        self._zero3 = np.zeros(3)

    def reset(self):
        self._S[:] = 0.0
        self._W[:] = 0.0

    def update(self, euler, rates, ref, ref_rate=None, ref_acc=None):
        """One step: measured (roll, pitch, yaw) and body rates, reference angles -> torques."""
        euler = np.asarray(euler, dtype=np.float64)
        rates = np.asarray(rates, dtype=np.float64)
        ref = np.asarray(ref, dtype=np.float64)
        rr = self._zero3 if ref_rate is None else np.asarray(ref_rate, dtype=np.float64)
        ra = self._zero3 if ref_acc is None else np.asarray(ref_acc, dtype=np.float64)
        if not attitude_update(self._S, self._P, euler, rates, ref, rr, ra, self._W, self._tau):
            raise nonfinite_arrays(euler=euler, rates=rates, ref=ref, ref_rate=rr, ref_acc=ra)
        return self._tau.copy()

    def set_applied_torque(self, tau):
        """Feed the observers the torques really applied (after a mixer's saturation)."""
        for i in range(3):
            self._S[i, K.S_U] = float(tau[i])

    @property
    def z(self):
        """(3, 3) observer estimates per axis: angle, rate, total disturbance (rad/s^2)."""
        return self._S[:, K.S_Z1:K.S_Z3 + 1].copy()

    @property
    def params(self):
        return self._P.copy()
