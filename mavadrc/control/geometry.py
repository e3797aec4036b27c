"""The map from a desired acceleration to an attitude + normalized-thrust setpoint.

Conventions (MAVLink end to end): world NED, body FRD, quaternion [w, x, y, z] rotating body
vectors into NED (the rotations themselves are in :mod:`mavadrc.control.rotations`).

The acceleration map replaces the thesis's eqs. 6-8 (small-angle, with sign errors) by the
geometric construction PX4 uses: the thrust must supply the specific force ``f = a_d - g e3``;
the body z axis points along ``-f``; the desired yaw fixes body x in the plane orthogonal to it.
"""

import math

import numpy as np

from .jit import jit
from .rotations import quat_from_rotmat

GRAVITY = 9.80665

# layout of the output vector of accel_to_attitude
O_Q = 0  # 4: attitude quaternion
O_THRUST = 4  # normalized collective thrust
O_ACC = 5  # 3: acceleration the limited setpoint really commands (NED, gravity included)
NO = 8

# layout of the mapping parameter vector
M_G = 0  # gravity (m/s^2)
M_TPA = 1  # normalized thrust per m/s^2 of specific force (hover_thrust/g, or mass/max_thrust)
M_TILT = 2  # tilt limit (rad)
M_THR_MIN = 3  # normalized thrust limits
M_THR_MAX = 4
M_TPA0 = 5  # the thrust per acceleration the controller was told (M_TPA: its estimate in flight)
M_TPA_RATE = 6  # 1/s: how fast the position loop learns M_TPA in flight (0: it does not)
NM = 7


@jit
def body_z_to_quat(bz0, bz1, bz2, yaw, q):
    """Attitude whose body z axis is the unit vector bz and whose heading is ``yaw``.

    Body x is the desired heading direction projected into the plane orthogonal to bz: it is
    built as (heading rotated by +90 deg in the horizontal plane) x bz.
    """
    yc0 = -math.sin(yaw)
    yc1 = math.cos(yaw)
    # body_x = y_c x body_z
    bx0 = yc1 * bz2
    bx1 = -yc0 * bz2
    bx2 = yc0 * bz1 - yc1 * bz0
    if bz2 < 0.0:  # thrust pointing down (inverted): keep the heading rather than flip it
        bx0, bx1, bx2 = -bx0, -bx1, -bx2
    n = math.sqrt(bx0 * bx0 + bx1 * bx1 + bx2 * bx2)
    if n < 1e-9:  # body z horizontal and along the heading: any x orthogonal to it will do
        bx0, bx1, bx2 = -bz2, 0.0, bz0
        n = math.sqrt(bx0 * bx0 + bx2 * bx2)
        if n < 1e-9:
            bx0, bx1, bx2, n = 0.0, 0.0, 1.0, 1.0
    bx0 /= n
    bx1 /= n
    bx2 /= n
    # body_y = body_z x body_x
    by0 = bz1 * bx2 - bz2 * bx1
    by1 = bz2 * bx0 - bz0 * bx2
    by2 = bz0 * bx1 - bz1 * bx0
    quat_from_rotmat(bx0, by0, bz0, bx1, by1, bz1, bx2, by2, bz2, q)


@jit
def accel_to_attitude(a0, a1, a2, yaw, m, out):
    """Map a desired NED acceleration to attitude + normalized thrust, with limits.

    Limits, altitude first: the upward specific force is kept between the minimum and maximum
    thrust; the horizontal part is then cut to the tilt limit and to what thrust is left
    (sqrt(f_max^2 - f_up^2)), keeping its direction.  ``out`` receives the quaternion, the
    normalized thrust and the acceleration the limited setpoint commands (gravity included),
    which is what an observer must be fed.
    """
    g = m[M_G]
    tpa = m[M_TPA]
    f_min = m[M_THR_MIN] / tpa
    f_max = m[M_THR_MAX] / tpa
    up = g - a2  # upward specific force the thrust must supply
    if up < f_min:
        up = f_min
    if up > f_max:
        up = f_max
    fx = a0
    fy = a1
    fxy = math.sqrt(fx * fx + fy * fy)
    lim = up * math.tan(m[M_TILT])
    rest = math.sqrt(max(f_max * f_max - up * up, 0.0))
    if rest < lim:
        lim = rest
    if fxy > lim:
        k = lim / fxy
        fx *= k
        fy *= k
        fxy = lim
    fn = math.sqrt(fxy * fxy + up * up)
    body_z_to_quat(-fx / fn, -fy / fn, up / fn, yaw, out[O_Q:O_Q + 4])
    out[O_THRUST] = fn * tpa
    out[O_ACC] = fx
    out[O_ACC + 1] = fy
    out[O_ACC + 2] = g - up


def mapping_params(*, hover_thrust=None, mass=None, max_thrust=None, tilt_max=math.radians(35.0),
                   thrust_min=0.05, thrust_max=1.0, g=GRAVITY, thrust_estimate_tau=None):
    """Parameter vector of :func:`accel_to_attitude`.

    Thrust is normalised either from a hover-thrust figure (normalized thrust that holds a hover,
    like PX4's MPC_THR_HOVER) or from the mass and the maximum collective thrust (N).
    ``thrust_estimate_tau`` (s): the time constant with which a position loop with a vertical
    observer learns the thrust per acceleration in flight (None: it keeps the figure told).
    """
    if hover_thrust is not None:
        if mass is not None or max_thrust is not None:
            raise ValueError("give either hover_thrust or mass and max_thrust, not both")
        ht = float(hover_thrust)
        if not (math.isfinite(ht) and 0.0 < ht < 1.0):
            raise ValueError(f"hover_thrust must be in (0, 1) (got {hover_thrust!r})")
        tpa = ht / g
    elif mass is not None and max_thrust is not None:
        m, t = float(mass), float(max_thrust)
        if not (math.isfinite(m) and m > 0.0):
            raise ValueError(f"mass must be a finite number > 0 (got {mass!r})")
        if not (math.isfinite(t) and t > m * g):
            raise ValueError(f"max_thrust must exceed the weight mass*g = {m * g:.4g} N (got {max_thrust!r})")
        tpa = m / t
    else:
        raise ValueError("the thrust scale needs hover_thrust, or both mass and max_thrust")
    tilt = float(tilt_max)
    if not (math.isfinite(tilt) and 0.0 < tilt < 0.5 * math.pi):
        raise ValueError(f"tilt_max must be in (0, pi/2) rad (got {tilt_max!r})")
    lo, hi = float(thrust_min), float(thrust_max)
    if not (0.0 <= lo < hi <= 1.0):
        raise ValueError(f"need 0 <= thrust_min < thrust_max <= 1 (got {thrust_min!r}, {thrust_max!r})")
    if hi / tpa <= g:
        raise ValueError(f"thrust_max={hi} cannot hold a hover (hover needs {g * tpa:.3f})")
    rate = 0.0
    if thrust_estimate_tau is not None:
        tau = float(thrust_estimate_tau)
        if not (math.isfinite(tau) and tau > 0.0):
            raise ValueError(f"thrust_estimate_tau must be a number of seconds > 0 (got {thrust_estimate_tau!r})")
        rate = 1.0 / tau
    m = np.empty(NM)
    m[M_G], m[M_TPA], m[M_TILT], m[M_THR_MIN], m[M_THR_MAX] = g, tpa, tilt, lo, hi
    m[M_TPA0], m[M_TPA_RATE] = tpa, rate
    return m


def acceleration_to_attitude(acc, yaw, **mapping):
    """Convenience form of :func:`accel_to_attitude`: returns (q, thrust, applied_acc).

    ``mapping`` takes the keywords of :func:`mapping_params`.
    """
    m = mapping_params(**mapping)
    out = np.empty(NO)
    accel_to_attitude(float(acc[0]), float(acc[1]), float(acc[2]), float(yaw), m, out)
    return out[O_Q:O_Q + 4].copy(), float(out[O_THRUST]), out[O_ACC:O_ACC + 3].copy()


#: ``thrust_tilt: measured`` scales the thrust by cos(tilt commanded) / cos(tilt measured)
#: within this range: a measured tilt far from the one commanded (a vehicle tipping on the
#: ground, an attitude estimate gone wrong) does not take the thrust with it
TILT_RATIO_RANGE = (0.75, 1.33)


@jit
def thrust_for_tilt(thrust, q0, q1, q2, q3, cos_now, thrust_max):
    """The thrust of a setpoint (``thrust`` for the attitude ``q``) sized for the tilt the
    vehicle has now (``cos_now``: the cosine of its measured tilt) instead of the one commanded,
    so that its vertical part is the one the loop commanded: thrust * cos(tilt commanded) /
    cos(tilt now), the ratio within :data:`TILT_RATIO_RANGE`, at most ``thrust_max``.

    The attitude loop reaches a new tilt a lag later (0.16-0.26 s on the autopilots flown) while
    the thrust acts at once: sized for the tilt commanded, a thrust that rises with a larger
    horizontal command lifts the vehicle before it leans, and the vertical loop fights that
    (ArduCopter's angle boost does the same on its own attitude)."""
    cos_cmd = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
    if not (cos_now > 0.0 and cos_cmd > 0.0):
        return thrust
    ratio = cos_cmd / cos_now
    if ratio < TILT_RATIO_RANGE[0]:
        ratio = TILT_RATIO_RANGE[0]
    elif ratio > TILT_RATIO_RANGE[1]:
        ratio = TILT_RATIO_RANGE[1]
    return min(thrust * ratio, thrust_max)
