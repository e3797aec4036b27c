"""The vehicle's outer loop and flight modes, as a PX4-like autopilot has them.

- :func:`position_step`: PX4's cascade (mc_pos_control).  Position error times a P gain plus the
  velocity feed-forward gives a velocity setpoint (limited: horizontal speed, climb and descent
  rates); a velocity PID (D on the measured velocity low-passed at 5 Hz, as PX4's MPC_VELD_LP;
  I with anti-windup against the limits of the attitude map) plus the acceleration feed-forward gives a desired acceleration, which
  :func:`mavadrc.control.geometry.accel_to_attitude` turns into attitude + normalized thrust
  (tilt limit, altitude first).  Per axis, a NaN setpoint component means "not given", like the
  ignore mask of SET_POSITION_TARGET_LOCAL_NED: no position -> velocity control; no position and
  no velocity -> the acceleration feed-forward alone.
- :func:`land_detect`: PX4's land detector reduced to its core: armed, thrust below a fraction of
  hover and the vehicle still (vertical and horizontal speed small) for a trigger time ->
  landed; thrust above that fraction -> flying.
- :class:`Navigator`: the modes that produce position setpoints: ``position`` (offboard
  position/velocity/acceleration targets), ``takeoff`` (climb to an altitude along a
  speed- and acceleration-limited profile, then hold there), ``hold`` (stay where commanded),
  ``land`` (hold horizontal position, descend at the land speed).
"""

import math

import numpy as np

from mavadrc.control import geometry as G
from mavadrc.control.jit import jit
from mavadrc.control.rotations import wrap_pi

from . import attitude as A

# position loop parameters (defaults: PX4's MPC_* parameters)
PP_KP = 0  # 3: position P (1/s)                       MPC_XY_P 0.95, MPC_Z_P 1.0
PP_KV = 3  # 3: velocity P (1/s)                       MPC_XY_VEL_P_ACC 1.8, MPC_Z_VEL_P_ACC 4
PP_KI = 6  # 3: velocity I (1/s^2)                     MPC_XY_VEL_I_ACC 0.4, MPC_Z_VEL_I_ACC 2
PP_KD = 9  # 3: velocity D (dimensionless)             MPC_XY_VEL_D_ACC 0.2, MPC_Z_VEL_D_ACC 0
PP_ILIM = 12  # 3: velocity integral limits (m/s^2)
PP_VXY_MAX = 15  # horizontal speed limit (m/s)         MPC_XY_VEL_MAX 12
PP_VUP_MAX = 16  # climb rate limit (m/s)               MPC_Z_VEL_MAX_UP 3
PP_VDN_MAX = 17  # descent rate limit (m/s)             MPC_Z_VEL_MAX_DN 1.5
PP_H = 18  # step (s)
PP_D_ALPHA = 19  # low-pass factor per step of the velocity derivative  MPC_VELD_LP 5 Hz
NPP = 20

# position loop state
PS_INT = 0  # 3: velocity integrals (m/s^2)
PS_PREV = 3  # 3: previous measured velocity
PS_INIT = 6
PS_DV = 7  # 3: filtered velocity derivative (m/s^2)
NPS = 10

# position setpoint
PSP_POS = 0  # 3
PSP_VEL = 3  # 3
PSP_ACC = 6  # 3
NPSP = 9

# land detector parameters, at attitude.FP_LD in the firmware parameter vector
LD_THRUST = 0  # normalized thrust below which the vehicle may be landed
LD_VZ = 1  # m/s
LD_VXY = 2  # m/s
LD_TIME = 3  # s the conditions must hold
NLD = 4


@jit
def position_step(ps, pp, M, pos, vel, sp, yaw, landed, out):
    """One step of the position/velocity cascade; writes accel_to_attitude's output to out.

    ``out`` also receives, after the map's layout (geometry.NO entries), the three commanded
    accelerations before the map's limits.
    """
    h = pp[PP_H]
    vsp = np.empty(3)
    for i in range(3):
        v = math.nan
        if math.isfinite(sp[PSP_POS + i]):
            v = pp[PP_KP + i] * (sp[PSP_POS + i] - pos[i])
        if math.isfinite(sp[PSP_VEL + i]):
            v = (v if math.isfinite(v) else 0.0) + sp[PSP_VEL + i]
        vsp[i] = v
    vmax = pp[PP_VXY_MAX]
    if math.isfinite(vsp[0]) and math.isfinite(vsp[1]):
        n = math.sqrt(vsp[0] * vsp[0] + vsp[1] * vsp[1])
        if n > vmax:
            vsp[0] *= vmax / n
            vsp[1] *= vmax / n
    else:
        for i in range(2):
            if math.isfinite(vsp[i]):
                vsp[i] = min(max(vsp[i], -vmax), vmax)
    if math.isfinite(vsp[2]):
        vsp[2] = min(max(vsp[2], -pp[PP_VUP_MAX]), pp[PP_VDN_MAX])
    if ps[PS_INIT] == 0.0:
        for i in range(3):
            ps[PS_PREV + i] = vel[i]
            ps[PS_DV + i] = 0.0
        ps[PS_INIT] = 1.0
    for i in range(3):
        dv = (vel[i] - ps[PS_PREV + i]) / h
        ps[PS_DV + i] += pp[PP_D_ALPHA] * (dv - ps[PS_DV + i])
        ps[PS_PREV + i] = vel[i]
    acc = np.empty(3)
    for i in range(3):
        a = sp[PSP_ACC + i] if math.isfinite(sp[PSP_ACC + i]) else 0.0
        if math.isfinite(vsp[i]):
            a += (pp[PP_KV + i] * (vsp[i] - vel[i]) + ps[PS_INT + i]
                  - pp[PP_KD + i] * ps[PS_DV + i])
        acc[i] = a
    G.accel_to_attitude(acc[0], acc[1], acc[2], yaw, M, out)
    for i in range(3):
        out[G.NO + i] = acc[i]
        if landed or not math.isfinite(vsp[i]):
            ps[PS_INT + i] = 0.0
            continue
        e = vsp[i] - vel[i]
        applied = out[G.O_ACC + i]
        tol = 1e-9 * (1.0 + abs(acc[i]))
        if (applied < acc[i] - tol and e > 0.0) or (applied > acc[i] + tol and e < 0.0):
            continue  # the map cut this axis: integrating further would only wind up
        lim = pp[PP_ILIM + i]
        ps[PS_INT + i] = min(max(ps[PS_INT + i] + pp[PP_KI + i] * e * h, -lim), lim)


@jit
def land_detect(fs, fp, thrust, vel, dt):
    """Update the landed flag fs[FS_LANDED] from the thrust setpoint and the measured velocity."""
    if fs[A.FS_ARMED] == 0.0:
        fs[A.FS_LANDED] = 1.0
        fs[A.FS_LD_TIMER] = 0.0
        return
    ld = fp[A.FP_LD:A.FP_LD + NLD]
    low = thrust < ld[LD_THRUST]
    if fs[A.FS_LANDED] != 0.0:
        if not low:
            fs[A.FS_LANDED] = 0.0
            fs[A.FS_LD_TIMER] = 0.0
        return
    still = (abs(vel[2]) < ld[LD_VZ]
             and math.sqrt(vel[0] * vel[0] + vel[1] * vel[1]) < ld[LD_VXY])
    if low and still:
        fs[A.FS_LD_TIMER] += dt
        if fs[A.FS_LD_TIMER] >= ld[LD_TIME]:
            fs[A.FS_LANDED] = 1.0
            fs[A.FS_LD_TIMER] = 0.0
    else:
        fs[A.FS_LD_TIMER] = 0.0


def position_params(*, h, kp=(0.95, 0.95, 1.0), kv=(1.8, 1.8, 4.0), ki=(0.4, 0.4, 2.0),
                    kd=(0.2, 0.2, 0.0), int_limit=(5.0, 5.0, 0.8 * G.GRAVITY), vel_max_xy=12.0,
                    vel_max_up=3.0, vel_max_down=1.5, d_cutoff_hz=5.0):
    """Parameter vector of :func:`position_step` (defaults: PX4's)."""
    pp = np.empty(NPP)
    for idx, name, val in ((PP_KP, "kp", kp), (PP_KV, "kv", kv), (PP_KI, "ki", ki),
                           (PP_KD, "kd", kd), (PP_ILIM, "int_limit", int_limit)):
        arr = np.broadcast_to(np.asarray(val, dtype=float), 3)
        if not np.all(np.isfinite(arr) & (arr >= 0.0)):
            raise ValueError(f"{name} must be >= 0 (got {val!r})")
        pp[idx:idx + 3] = arr
    for idx, name, val in ((PP_VXY_MAX, "vel_max_xy", vel_max_xy),
                           (PP_VUP_MAX, "vel_max_up", vel_max_up),
                           (PP_VDN_MAX, "vel_max_down", vel_max_down), (PP_H, "h", h)):
        if not (math.isfinite(val) and val > 0.0):
            raise ValueError(f"{name} must be > 0 (got {val!r})")
        pp[idx] = val
    if not (math.isfinite(d_cutoff_hz) and d_cutoff_hz >= 0.0):
        raise ValueError(f"d_cutoff_hz must be >= 0 (got {d_cutoff_hz!r})")
    pp[PP_D_ALPHA] = 1.0 if d_cutoff_hz == 0.0 else -math.expm1(-2.0 * math.pi * d_cutoff_hz * h)
    return pp


class Profile1D:
    """A reference moving to a target at limited speed and acceleration, without overshoot."""

    def __init__(self, start, target, v_max, a_max):
        self.p = float(start)
        self.v = 0.0
        self.a = 0.0
        self.target = float(target)
        self.v_max = float(v_max)
        self.a_max = float(a_max)

    @property
    def done(self):
        return self.p == self.target and self.v == 0.0

    def step(self, h):
        e = self.target - self.p
        if abs(e) <= 0.5 * self.a_max * h * h and abs(self.v) <= self.a_max * h:
            self.a = -self.v / h
            self.p, self.v = self.target, 0.0
            return
        # fastest speed after this step from which braking at a_max still stops at the target:
        # v'^2 / (2 a) <= |e| - (v + v') h / 2 along the direction of e
        s = 1.0 if e > 0.0 else -1.0
        ah = self.a_max * h
        disc = ah * ah + 8.0 * self.a_max * abs(e) - 4.0 * ah * s * self.v
        v_stop = 0.5 * (-ah + math.sqrt(disc)) if disc > 0.0 else 0.0
        v_want = s * min(self.v_max, max(v_stop, 0.0))
        dv = min(max(v_want - self.v, -self.a_max * h), self.a_max * h)
        v_new = self.v + dv
        self.a = dv / h
        self.p += 0.5 * (self.v + v_new) * h
        self.v = v_new


class Navigator:
    """Flight modes that drive the position loop: position, takeoff, hold, land.

    ``update(pos, vel, landed)`` runs one position-loop step and returns (q, normalized thrust).
    ``mode`` becomes 'hold' by itself when a takeoff reaches its altitude.
    """

    MODES = ("position", "takeoff", "hold", "land")

    def __init__(self, *, h, hover_thrust, tilt_max=math.radians(45.0), thrust_min=0.05,
                 thrust_max=1.0, takeoff_speed=1.5, takeoff_accel=2.0, land_speed=0.7, **gains):
        self.h = float(h)
        self.pp = position_params(h=self.h, **gains)
        self.M = G.mapping_params(hover_thrust=hover_thrust, tilt_max=tilt_max,
                                  thrust_min=thrust_min, thrust_max=thrust_max)
        self.ps = np.zeros(NPS)
        self.sp = np.full(NPSP, math.nan)
        self.out = np.zeros(G.NO + 3)
        self.takeoff_speed = float(takeoff_speed)
        self.takeoff_accel = float(takeoff_accel)
        self.land_speed = float(land_speed)
        self.mode = None
        self.yaw = 0.0
        self.yaw_rate = math.nan
        self._profile = None

    def reset(self):
        self.ps[:] = 0.0

    def _set(self, pos=None, vel=None, acc=None):
        for idx, v in ((PSP_POS, pos), (PSP_VEL, vel), (PSP_ACC, acc)):
            self.sp[idx:idx + 3] = math.nan if v is None else np.asarray(v, dtype=float)

    def set_target(self, pos=None, vel=None, acc=None, yaw=None, yaw_rate=None, yaw_now=0.0):
        """Offboard target; None (or NaN components) = not given.  No yaw: keep the heading."""
        if self.mode != "position":
            self.yaw = yaw_now
        self._set(pos, vel, acc)
        if yaw is not None and math.isfinite(yaw):
            self.yaw = float(yaw)
        self.yaw_rate = math.nan if yaw_rate is None else float(yaw_rate)
        self.mode = "position"

    def takeoff(self, pos, yaw, altitude_z):
        """Climb from ``pos`` to NED height ``altitude_z`` above the current horizontal position."""
        self._set(pos=pos, vel=(math.nan, math.nan, 0.0), acc=(math.nan, math.nan, 0.0))
        self._profile = Profile1D(pos[2], altitude_z, self.takeoff_speed, self.takeoff_accel)
        self.yaw = yaw
        self.yaw_rate = math.nan
        self.mode = "takeoff"

    def hold(self, pos, yaw):
        self._set(pos=pos)
        self.yaw = yaw
        self.yaw_rate = math.nan
        self.mode = "hold"

    def land(self, pos, yaw, speed=None):
        """Descend at ``speed`` m/s (the land speed if None) above ``pos``."""
        speed = self.land_speed if speed is None else float(speed)
        self._set(pos=(pos[0], pos[1], math.nan), vel=(math.nan, math.nan, speed))
        self.yaw = yaw
        self.yaw_rate = math.nan
        self.mode = "land"

    def wants_takeoff(self, pos):
        """Whether the offboard target asks a vehicle on the ground to take off: its position
        above the vehicle, or a climb asked by velocity or acceleration (PX4
        MulticopterPositionControl's want_takeoff in OFFBOARD; ArduCopter's GUIDED takes none
        from the ground, its companion takes off by MAV_CMD_NAV_TAKEOFF first)."""
        sp = self.sp
        return ((math.isfinite(sp[PSP_POS + 2]) and sp[PSP_POS + 2] < pos[2])
                or (math.isfinite(sp[PSP_VEL + 2]) and sp[PSP_VEL + 2] < 0.0)
                or (math.isfinite(sp[PSP_ACC + 2]) and sp[PSP_ACC + 2] < 0.0))

    def update(self, pos, vel, landed):
        if self.mode == "position" and landed and not self.wants_takeoff(pos):
            # on the ground, no takeoff asked: the motors at idle, the loop at rest (PX4's
            # takeoff state machine before its ramp; ArduCopter's landed GUIDED)
            self.ps[:] = 0.0
            self.out[G.O_Q:G.O_Q + 4] = (math.cos(0.5 * self.yaw), 0.0, 0.0,
                                         math.sin(0.5 * self.yaw))
            self.out[G.O_THRUST] = 0.0
            return self.out[G.O_Q:G.O_Q + 4], 0.0
        if self.mode == "takeoff":
            pr = self._profile
            pr.step(self.h)
            self.sp[PSP_POS + 2] = pr.p
            self.sp[PSP_VEL + 2] = pr.v
            self.sp[PSP_ACC + 2] = pr.a
            if pr.done:
                self._set(pos=self.sp[PSP_POS:PSP_POS + 3].copy())
                self.mode = "hold"
        elif math.isfinite(self.yaw_rate):
            self.yaw = wrap_pi(self.yaw + self.yaw_rate * self.h)
        position_step(self.ps, self.pp, self.M, np.asarray(pos, dtype=float),
                      np.asarray(vel, dtype=float), self.sp, self.yaw, landed, self.out)
        return self.out[G.O_Q:G.O_Q + 4], float(self.out[G.O_THRUST])
