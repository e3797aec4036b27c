"""The vehicle's inner loop: attitude + normalized-thrust setpoint -> rotor speed commands.

One kernel, :func:`inner_step`, runs every firmware step (every physics step by default): attitude
control of the selected kind, thrust scaling and the mixer of :mod:`sim.firmware.mixer`.  Kinds:

- ``px4``: PX4's multicopter structure.  Attitude error from quaternions, roll/pitch first
  (reduced attitude: the shortest rotation of the body z axis onto the desired one) and yaw
  mixed in with a weight (PX4's MC_YAW_WEIGHT), times P gains -> body rate setpoint, limited ->
  rate PID (P; I with anti-windup; D on the measured rate, low-pass filtered) -> angular
  acceleration, times the inertia -> torque (N m).
- ``ladrc``, ``adrc``, ``pd``: the thesis's Euler-angle channels of
  :class:`mavadrc.control.AttitudeController` (b0 = 1/I per axis), whose kernel is called here
  directly.  Their observers are fed the torque really applied: the mixer's saturated output
  passed through the firmware's model of the motors (first-order lag, and the reaction torque
  of the rotors' acceleration about z).  Fed the bare command instead (``observer_input=
  'command'``), the LESO of a 30 g Crazyflie, whose motors lag 50 ms, takes that lag for a
  disturbance and the loop oscillates at every bandwidth that meets a 0.3 s step, and on an
  x500 the yaw channel limit-cycles: the rotor reaction is ~10x the drag torque at high
  frequency, far outside the b/b0 range an ESO tolerates.  Classical ADRC also gets its TD's
  acceleration (from the previous step) as feed-forward; without it the NLSEF lags the TD
  profile and overshoots.

A setpoint that ignores the attitude (body rates only) goes to the rate PID whatever the kind:
the Euler channels have no rate-only form.

Thrust: normalized collective thrust t in [0, 1] is applied as ``t * thrust_scale`` newtons, as
PX4 applies SET_ATTITUDE_TARGET thrust raw (1.0 = the configured maximum thrust).  That is the
autopilot's belief: it turns each rotor's share into a motor output by inverting its own thrust
curve (PX4's THR_MDL_FAC, ArduPilot's MOT_THST_EXPO: thrust fraction = k u^2 + (1 - k) u of output
u), and the motors answer with their own curve (the vehicle file's ``motor_thrust_curve``).  When
the two factors differ (FP_CURVE), the rotor speeds the kernel returns are the motors' real ones,
so thrust is no longer linear in the command; when they agree, or the vehicle gives no curve,
the commands pass through untouched.

Gains of the PX4-like loop come from one bandwidth per axis, ``lam``, placed against the motor
time constant tau_m (the plant from torque command to angle is 1/(I s^2 (tau_m s + 1))): with
rate D gain kd, rate P gain kp and attitude P gain ka (all in angular-acceleration units) the
closed loop is ``tau_m s^3 + (1 + kd) s^2 + kp s + kp ka`` and a triple pole at -lam gives
``kd = 3 lam tau_m - 1, kp = 3 lam^2 tau_m, ka = lam / 3``.  When motors are fast (kd would be
negative) tau_m is taken as 1/(3 lam), which gives kd = 0.
"""

import math

import numpy as np

from mavadrc.control import AttitudeController
from mavadrc.control import kernels as K
from mavadrc.control.jit import jit
from mavadrc.control.attitude import attitude_update
from mavadrc.control.rotations import quat_to_euler

from .mixer import MX_A, NWK_MIX, apply_motor_curve, mix

KINDS = ("px4", "ladrc", "adrc", "pd")
KIND_PX4 = 0.0

# firmware parameter vector
FP_KIND = 0  # index into KINDS
FP_H = 1  # inner loop step (s)
FP_THRUST_SCALE = 2  # N of collective thrust per unit of normalized thrust
FP_ATT_P = 3  # 3: attitude P gains (1/s); yaw already divided by the yaw weight
FP_YAW_W = 6  # yaw weight of the attitude error (0..1)
FP_RATE_MAX = 7  # 3: body rate setpoint limits (rad/s)
FP_KP = 10  # 3: rate P (1/s)
FP_KI = 13  # 3: rate I (1/s^2)
FP_KD = 16  # 3: rate D (dimensionless: angular acceleration per angular acceleration)
FP_ILIM = 19  # 3: rate integral limits (rad/s^2)
FP_D_ALPHA = 22  # D-term low-pass filter factor per step (1: no filter)
FP_INERTIA = 23  # 3: Ixx, Iyy, Izz
FP_LD = 26  # 4: land detector parameters (sim.firmware.position.LD_*)
FP_MOTOR_UP = 30  # motor model: fraction of the gap closed per step when speeding up
FP_MOTOR_DOWN = 31  # ... when slowing down
FP_OBS_MODEL = 32  # 1.0: Euler-channel observers get the motor model's torque, 0.0: the command
FP_JR = 33  # 4: rotor inertia times spin direction (kg m^2): reaction torque of rotor acceleration
FP_CURVE = 37  # 1.0: the motors' thrust curve differs from the one the autopilot linearises with
FP_CURVE_ASSUMED = 38  # the autopilot's thrust curve factor (THR_MDL_FAC / MOT_THST_EXPO)
FP_CURVE_TRUE = 39  # the vehicle's motors' real factor (the vehicle file's motor_thrust_curve)
NFP = 40

# firmware state vector
FS_ARMED = 0
FS_LANDED = 1
FS_INT = 2  # 3: rate integrals (rad/s^2)
FS_PREV = 5  # 3: previous measured rates
FS_DF = 8  # 3: filtered angular acceleration
FS_INIT = 11  # 1.0 once FS_PREV holds a measurement
FS_SAT = 12  # 3: +1 / -1 when the mixer could not give the requested torque up / down
FS_WRENCH = 15  # 4: achieved [T, tau_x, tau_y, tau_z]
FS_REQ = 19  # 4: requested [T, tau_x, tau_y, tau_z]
FS_RATE_SP = 23  # 3: body rate setpoint of the last step (px4 kind and rate-only setpoints)
FS_LD_TIMER = 26  # land detector: time the landed conditions have held
FS_OMEGA = 27  # 4: motor model: rotor speeds the commands have produced so far (rad/s)
NFS = 31

# setpoint vector
SP_Q = 0  # 4: attitude [w, x, y, z]
SP_THRUST = 4  # normalized collective thrust
SP_RATES = 5  # 3: body rates (rad/s): feed-forward with an attitude, setpoint without
SP_RATE_VALID = 8  # 3: 1.0 where SP_RATES is given
SP_ATT_VALID = 11  # 1.0: attitude given; 0.0: body rates only
NSP = 12

# scratch vector of inner_step (one per vehicle, so that no step allocates)
WK_ACC = 0  # 3
WK_TAU = 3  # 3
WK_RSP = 6  # 3
WK_EUL = 9  # 3
WK_REF = 12  # 3
WK_ZERO = 15  # 3
WK_RACC = 18  # 3
WK_MODEL = 21  # 4: motor-model wrench
WK_W2 = 25  # 4
WK_QERR = 29  # 8: attitude_error
WK_MIX = 37  # NWK_MIX: mixer
NWK = WK_MIX + NWK_MIX

_RATE_I_FADE = math.radians(400.0)  # rate error at which the integral stops growing (PX4)


@jit
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3, out):
    out[0] = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    out[1] = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    out[2] = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    out[3] = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0


@jit
def attitude_error(q, qd, yaw_w, out, wk):
    """PX4-style attitude error (rad, body axes) from attitude q to setpoint qd, written to out.

    The setpoint is first replaced by the attitude reached by tilting the body z axis the
    shortest way onto the desired one (roll/pitch only), then the remaining rotation about z is
    mixed back in scaled by yaw_w.  The error is 2 * imag(q^-1 qd) of that, for the short way.
    """
    # body z axes in NED (third column of R(q))
    z0 = 2.0 * (q[1] * q[3] + q[0] * q[2])
    z1 = 2.0 * (q[2] * q[3] - q[0] * q[1])
    z2 = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
    d0 = 2.0 * (qd[1] * qd[3] + qd[0] * qd[2])
    d1 = 2.0 * (qd[2] * qd[3] - qd[0] * qd[1])
    d2 = 1.0 - 2.0 * (qd[1] * qd[1] + qd[2] * qd[2])
    red = wk[0:4]
    tmp = wk[4:8]
    c = z0 * d0 + z1 * d1 + z2 * d2
    if c < -1.0 + 1e-9:
        # thrust axis to be flipped: the tilt alone is undefined, use the full setpoint
        for i in range(4):
            red[i] = qd[i]
    else:
        # shortest rotation z -> d (world frame): [1 + c, z x d], normalised; then applied to q
        w = 1.0 + c
        x = z1 * d2 - z2 * d1
        y = z2 * d0 - z0 * d2
        zz = z0 * d1 - z1 * d0
        n = math.sqrt(w * w + x * x + y * y + zz * zz)
        _qmul(w / n, x / n, y / n, zz / n, q[0], q[1], q[2], q[3], red)
    # remaining rotation red^-1 qd is about body z; keep a fraction yaw_w of it
    _qmul(red[0], -red[1], -red[2], -red[3], qd[0], qd[1], qd[2], qd[3], tmp)
    if tmp[0] < 0.0:
        for i in range(4):
            tmp[i] = -tmp[i]
    cw = min(max(tmp[0], -1.0), 1.0)
    sz = min(max(tmp[3], -1.0), 1.0)
    half_c = yaw_w * math.acos(cw)
    half_s = yaw_w * math.asin(sz)
    _qmul(red[0], red[1], red[2], red[3], math.cos(half_c), 0.0, 0.0, math.sin(half_s), tmp)
    # error rotation q^-1 tmp
    _qmul(q[0], -q[1], -q[2], -q[3], tmp[0], tmp[1], tmp[2], tmp[3], red)
    sgn = 2.0 if red[0] >= 0.0 else -2.0
    out[0] = sgn * red[1]
    out[1] = sgn * red[2]
    out[2] = sgn * red[3]


@jit
def rate_pid(fs, fp, rates, rate_sp, landed, acc):
    """Rate PID to angular acceleration (rad/s^2, written to acc); D acts on the measurement."""
    h = fp[FP_H]
    if fs[FS_INIT] == 0.0:
        for i in range(3):
            fs[FS_PREV + i] = rates[i]
            fs[FS_DF + i] = 0.0
        fs[FS_INIT] = 1.0
    alpha = fp[FP_D_ALPHA]
    for i in range(3):
        e = rate_sp[i] - rates[i]
        dw = (rates[i] - fs[FS_PREV + i]) / h
        fs[FS_PREV + i] = rates[i]
        fs[FS_DF + i] += alpha * (dw - fs[FS_DF + i])
        acc[i] = fp[FP_KP + i] * e + fs[FS_INT + i] - fp[FP_KD + i] * fs[FS_DF + i]
        if landed:
            fs[FS_INT + i] = 0.0
            continue
        # no integration further into a saturation the mixer reported; fade for large errors
        sat = fs[FS_SAT + i]
        if (sat > 0.0 and e > 0.0) or (sat < 0.0 and e < 0.0):
            continue
        fade = 1.0 - (e / _RATE_I_FADE) ** 2
        if fade < 0.0:
            fade = 0.0
        v = fs[FS_INT + i] + fp[FP_KI + i] * e * h * fade
        lim = fp[FP_ILIM + i]
        fs[FS_INT + i] = min(max(v, -lim), lim)


@jit
def _reset(fs, S, W):
    for i in range(3):
        fs[FS_INT + i] = 0.0
        fs[FS_SAT + i] = 0.0
        fs[FS_RATE_SP + i] = 0.0
    fs[FS_INIT] = 0.0
    S[:, :] = 0.0
    W[:] = 0.0


@jit
def motor_model(fs, fp, mx, omega, out, w2):
    """Advance the firmware's first-order model of the rotors over one step of commands omega.

    Writes to ``out`` the wrench [T, tau_x, tau_y, tau_z] averaged over the step: thrust and
    drag torques (trapezoid in Omega^2) plus, about z, the reaction to the rotors' angular
    acceleration.  On
    a large quadrotor that reaction is several times the drag torque while the rotors change
    speed; an observer not told about it sees a yaw "disturbance" made by its own input.
    ``w2``: scratch of 4 floats.
    """
    react = 0.0
    for i in range(4):
        o = fs[FS_OMEGA + i]
        a = fp[FP_MOTOR_UP] if omega[i] > o else fp[FP_MOTOR_DOWN]
        n = o + a * (omega[i] - o)
        fs[FS_OMEGA + i] = n
        w2[i] = 0.5 * (o * o + n * n)
        react += fp[FP_JR + i] * (n - o)
    for j in range(4):
        acc = 0.0
        for i in range(4):
            acc += mx[MX_A + 4 * j + i] * w2[i]
        out[j] = acc
    out[3] += react / fp[FP_H]


@jit
def inner_step(fs, fp, S, P, W, mx, x, sp, omega, wk):
    """One firmware inner-loop step for measured state x (17); rotor commands written to omega.

    fs/fp: firmware state/parameters; S, P, W: Euler-channel state (3, NS), parameters (3, NP)
    and yaw-unwrap state of the ladrc/adrc/pd kinds (unused for px4); mx: mixer parameters;
    sp: setpoint vector; wk: scratch of NWK floats.  Disarmed: rotors stopped and every
    controller state cleared.
    """
    model = wk[WK_MODEL:WK_MODEL + 4]
    if fs[FS_ARMED] == 0.0:
        for i in range(4):
            omega[i] = 0.0
            fs[FS_WRENCH + i] = 0.0
            fs[FS_REQ + i] = 0.0
        _reset(fs, S, W)
        motor_model(fs, fp, mx, omega, model, wk[WK_W2:WK_W2 + 4])
        return
    landed = fs[FS_LANDED] != 0.0
    q = x[6:10]
    rates = x[10:13]
    acc = wk[WK_ACC:WK_ACC + 3]
    tau = wk[WK_TAU:WK_TAU + 3]
    rsp = wk[WK_RSP:WK_RSP + 3]
    if sp[SP_ATT_VALID] != 0.0 and fp[FP_KIND] != KIND_PX4:
        eul = wk[WK_EUL:WK_EUL + 3]
        ref = wk[WK_REF:WK_REF + 3]
        zero = wk[WK_ZERO:WK_ZERO + 3]
        racc = wk[WK_RACC:WK_RACC + 3]
        if landed:
            S[:, :] = 0.0  # the ground holds the vehicle: restart the observers at lift-off
            W[:] = 0.0
        quat_to_euler(q, eul)
        quat_to_euler(sp[SP_Q:SP_Q + 4], ref)
        for i in range(3):
            zero[i] = 0.0
            racc[i] = S[i, K.S_FH]
        attitude_update(S, P, eul, rates, ref, zero, racc, W, tau)
        fs[FS_INIT] = 0.0
        for i in range(3):
            fs[FS_INT + i] = 0.0
    else:
        if sp[SP_ATT_VALID] != 0.0:
            attitude_error(q, sp[SP_Q:SP_Q + 4], fp[FP_YAW_W], rsp, wk[WK_QERR:WK_QERR + 8])
            for i in range(3):
                rsp[i] *= fp[FP_ATT_P + i]
                if sp[SP_RATE_VALID + i] != 0.0:
                    rsp[i] += sp[SP_RATES + i]
        else:
            S[:, :] = 0.0
            W[:] = 0.0
            for i in range(3):
                rsp[i] = sp[SP_RATES + i] if sp[SP_RATE_VALID + i] != 0.0 else 0.0
        for i in range(3):
            lim = fp[FP_RATE_MAX + i]
            rsp[i] = min(max(rsp[i], -lim), lim)
            fs[FS_RATE_SP + i] = rsp[i]
        rate_pid(fs, fp, rates, rsp, landed, acc)
        for i in range(3):
            tau[i] = fp[FP_INERTIA + i] * acc[i]
    t = min(max(sp[SP_THRUST], 0.0), 1.0) * fp[FP_THRUST_SCALE]
    w = fs[FS_WRENCH:FS_WRENCH + 4]
    mix(mx, t, tau[0], tau[1], tau[2], omega, w, wk[WK_MIX:WK_MIX + NWK_MIX])
    fs[FS_REQ] = t
    motor_model(fs, fp, mx, omega, model, wk[WK_W2:WK_W2 + 4])
    if fp[FP_CURVE] != 0.0:
        # the autopilot's outputs through motors whose curve it does not know: the firmware's
        # own model (and so the observers and the reported wrench) keeps its belief
        apply_motor_curve(mx, fp[FP_CURVE_ASSUMED], fp[FP_CURVE_TRUE], omega)
    for i in range(3):
        fs[FS_REQ + 1 + i] = tau[i]
        # observers see the torque really applied: the mixer's output, through the motor model
        S[i, K.S_U] = model[1 + i] if fp[FP_OBS_MODEL] != 0.0 else w[1 + i]
        tol = 1e-9 * (abs(tau[i]) + 1e-12)
        if w[1 + i] < tau[i] - tol:
            fs[FS_SAT + i] = 1.0
        elif w[1 + i] > tau[i] + tol:
            fs[FS_SAT + i] = -1.0
        else:
            fs[FS_SAT + i] = 0.0


# --- gains and parameters (plain Python, run once) -----------------------------------------------


def motor_time_constant(vehicle):
    """One motor time constant for gain design: the mean of the up and down constants."""
    return 0.5 * (vehicle.tau_up + vehicle.tau_down)


def px4_gains(vehicle, bandwidth=(25.0, 25.0, 10.0), integral=0.05):
    """Rate and attitude gains of the PX4-like loop from a closed-loop bandwidth per axis (rad/s).

    Triple pole at -bandwidth against the motor lag (see the module notes).  The rate integral
    gain is ``integral * bandwidth * kp``, a slow integrator that leaves the poles nearly in place.
    Returns a dict of per-axis arrays: att_p, rate_p, rate_i, rate_d.
    """
    lam = np.broadcast_to(np.asarray(bandwidth, dtype=float), 3).copy()
    if not np.all(np.isfinite(lam) & (lam > 0.0)):
        raise ValueError(f"bandwidth must be > 0 (got {bandwidth!r})")
    tau = np.maximum(motor_time_constant(vehicle), 1.0 / (3.0 * lam))
    kp = 3.0 * lam ** 2 * tau
    return {
        "att_p": lam / 3.0,
        "rate_p": kp,
        "rate_i": float(integral) * lam * kp,
        "rate_d": 3.0 * lam * tau - 1.0,
    }


def default_bandwidths(vehicle, kind):
    """Closed-loop bandwidths (rad/s) per axis chosen for the vehicle's motor lag.

    px4: triple pole (the vehicle file's ``attitude_bandwidth`` where it gives one);
    ladrc/adrc/pd: controller bandwidth wc (the observer runs at 4 wc).
    """
    tau = motor_time_constant(vehicle)
    if kind == "px4":
        if getattr(vehicle, "attitude_bandwidth", None) is not None:
            return np.array(vehicle.attitude_bandwidth, dtype=float)  # the vehicle file's
        return np.array([25.0, 25.0, 10.0])
    # the control law itself does not know the motor lag: keep wc below 1/tau_m on slow motors
    # (Crazyflie: 12 rad/s settles a 10 deg step in 0.24 s; 16 rad/s already overshoots)
    wc = min(25.0, 0.6 / tau)
    return np.array([wc, wc, 0.5 * wc])


def firmware_params(vehicle, kind="px4", *, h, thrust_scale, mixer, bandwidth=None,
                    yaw_weight=0.4, rate_max=(math.radians(220.0), math.radians(220.0),
                                              math.radians(200.0)),
                    d_cutoff_hz=30.0, integral_limit=0.3, observer_input="motor_model", **gains):
    """Firmware parameter vector and the Euler-channel parameters (3, NP) for ``kind``.

    ``gains`` override the PX4-like gains (att_p, rate_p, rate_i, rate_d: per-axis triples) or,
    for the Euler kinds, are passed to :class:`mavadrc.control.AttitudeController` (wc, wo, ...).
    ``bandwidth``: per-axis rad/s from which the defaults are designed (px4: the triple pole;
    Euler kinds: wc, with wo = 4 wc).  ``yaw_weight``, ``rate_max`` (rad/s): as PX4's
    MC_YAW_WEIGHT and MC_*RATE_MAX.  ``d_cutoff_hz``: low-pass of the rate D term (PX4's
    IMU_DGYRO_CUTOFF; 0 = none).  ``integral_limit``: rate integral limit as a fraction of the
    torque authority at hover.  ``observer_input``: what the Euler channels' observers are fed,
    'motor_model' (default) or 'command' (the mixer's output as is).
    """
    if kind not in KINDS:
        raise ValueError(f"attitude_controller must be one of {', '.join(KINDS)} (got {kind!r})")
    inertia = np.asarray(vehicle.inertia, dtype=float)
    hover = vehicle.weight
    authority = mixer.torque_authority(hover)
    px4_keys = ("att_p", "rate_p", "rate_i", "rate_d")
    lam = default_bandwidths(vehicle, "px4") if (kind != "px4" or bandwidth is None) else bandwidth
    g = px4_gains(vehicle, lam)
    if kind == "px4":
        for k in px4_keys:
            if k in gains:
                g[k] = np.broadcast_to(np.asarray(gains.pop(k), dtype=float), 3).copy()
    fp = np.zeros(NFP)
    fp[FP_KIND] = KINDS.index(kind)
    fp[FP_H] = h
    fp[FP_THRUST_SCALE] = thrust_scale
    yw = float(yaw_weight)
    if not 0.0 < yw <= 1.0:
        raise ValueError(f"yaw_weight must be in (0, 1] (got {yaw_weight!r})")
    fp[FP_YAW_W] = yw
    fp[FP_ATT_P:FP_ATT_P + 3] = g["att_p"]
    fp[FP_ATT_P + 2] /= yw  # the yaw error is scaled by yw: small yaw errors keep gain att_p
    fp[FP_RATE_MAX:FP_RATE_MAX + 3] = rate_max
    fp[FP_KP:FP_KP + 3] = g["rate_p"]
    fp[FP_KI:FP_KI + 3] = g["rate_i"]
    fp[FP_KD:FP_KD + 3] = g["rate_d"]
    fp[FP_ILIM:FP_ILIM + 3] = integral_limit * authority / inertia
    fp[FP_D_ALPHA] = 1.0 if d_cutoff_hz <= 0.0 else 1.0 - math.exp(-2.0 * math.pi * d_cutoff_hz * h)
    fp[FP_INERTIA:FP_INERTIA + 3] = inertia
    fp[FP_MOTOR_UP] = -math.expm1(-h / vehicle.tau_up)
    fp[FP_MOTOR_DOWN] = -math.expm1(-h / vehicle.tau_down)
    fp[FP_JR:FP_JR + 4] = vehicle.rotor_inertia * np.asarray(vehicle.rotor_directions, dtype=float)
    if observer_input not in ("motor_model", "command"):
        raise ValueError("observer_input must be 'motor_model' or 'command' "
                         f"(got {observer_input!r})")
    fp[FP_OBS_MODEL] = 1.0 if observer_input == "motor_model" else 0.0
    if kind == "px4":
        if gains:
            raise ValueError(f"unknown gains for the px4 attitude loop: {', '.join(gains)}")
        P = AttitudeController("pd", h=h, inertia=inertia, kp=1.0, kd=1.0).params
    else:
        for k in px4_keys:
            gains.pop(k, None)
        P = AttitudeController(kind, h=h, inertia=inertia, torque_max=authority,
                               **euler_gains(vehicle, kind, h, bandwidth, authority, gains)).params
    return fp, P


def euler_gains(vehicle, kind, h, bandwidth, authority, gains):
    """Gain keywords of the Euler-angle channels, defaults from the bandwidth, user keys win.

    For 'adrc', ``wc`` and ``wo`` may be given too: they set the defaults of h1, c and the NLESO
    gains as described below.
    """
    out = dict(gains)
    wc = default_bandwidths(vehicle, kind) if bandwidth is None else bandwidth
    wc = np.broadcast_to(np.asarray(out.pop("wc", wc) if kind == "adrc" else out.get("wc", wc),
                                    dtype=float), 3).copy()
    if kind == "ladrc":
        out.setdefault("wc", tuple(wc))
        out.setdefault("wo", tuple(4.0 * wc))
    elif kind == "pd":
        out.setdefault("wc", tuple(wc))
    else:
        # Han's ADRC, linear-equivalent near the origin: fhan(e1, c e2, r, h1) acts as
        # kp = 1/h1^2, kd = 2c/h1 inside its linear zone, so h1 = 1/wc, c = 1; the NLESO's fal
        # terms have slopes delta^(alpha-1) there, so beta is scaled to put its poles at -wo.
        wo = np.broadcast_to(np.asarray(out.pop("wo", 4.0 * wc), dtype=float), 3)
        delta = out.setdefault("delta", 0.01)
        acc_max = authority / np.asarray(vehicle.inertia, dtype=float)
        out.setdefault("h1", tuple(1.0 / wc))
        out.setdefault("c", 1.0)
        out.setdefault("r", tuple(acc_max))
        out.setdefault("r0", tuple(0.05 * acc_max))
        # TD filter factor on the loop's time scale: a setpoint stream with noise (a position
        # loop on noisy estimates) is smoothed rather than chased step by step
        out.setdefault("h0", tuple(np.maximum(0.6 / wc, h)))
        out.setdefault("beta", [(3.0 * wo[i], 3.0 * wo[i] ** 2 * delta ** 0.5,
                                 wo[i] ** 3 * delta ** 0.75) for i in range(3)])
    return out
