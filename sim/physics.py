"""Rigid-body quadrotor physics as numba kernels: derivatives, RK4 steps, batches.

State x (float64[17]): position NED (m, ground at z = 0, altitude = -z), velocity NED (m/s),
quaternion [w, x, y, z] rotating body FRD -> NED, body rates FRD (rad/s), rotor speeds (rad/s).

Model (SIMULATION.md section 1), with v_a = v - v_wind the air-relative velocity:

    p' = v
    v' = g e3 + (R(q) F_body + f_ext) / m
    q' = 0.5 q (x) [0, w]
    J w' = tau - w x (J w + h_r e3) - h_r' e3 + tau_ext
    Omega_i' = (clamp(cmd_i) - Omega_i) / tau_m        (tau_up speeding up, tau_down slowing)

F_body = thrust sum(k_f Omega_i^2) along -z, rotor drag -rotor_drag*Omega_i*(v_a at rotor i in the
rotor plane), body drag -(drag_linear + drag_quadratic*|v_a|)*v_a per body axis. tau = thrust
moments + yaw drag torques s_i*k_m*Omega_i^2 + moments of the rotor drag forces.
h_r = -rotor_inertia * sum(s_i Omega_i) is the rotors' angular momentum along body z (a
counter-clockwise rotor, s_i = +1, spins about -z FRD): it gives the gyroscopic torque
-w x h_r e3 and the reaction torque of rotor acceleration. f_ext is a world force (N), tau_ext a
body torque (N m), both from a disturbance model.

Integration: classic RK4 with every input held over the step (zero-order hold), then the
quaternion is renormalised and rotor speeds are clamped to [omega_min, omega_max].

Ground contact (after each step): if z >= 0 the vehicle is on the ground. It is put at z = 0,
its horizontal velocity and body rates are zeroed, a downward velocity is zeroed, and it sits
level with its heading kept; a vehicle that was already on the ground keeps its horizontal
position and attitude from before the step (a landed quadrotor rests on its legs and does not
slide, tip or turn). It lifts off in the first step whose net force points up, i.e. when thrust
exceeds weight.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from mavadrc.control.geometry import GRAVITY  # defined once, where the control maps use it
from mavadrc.control.rotations import quat_from_euler
from sim.params import (P_DRAG_LIN, P_DRAG_QUAD, P_IXX, P_IYY, P_IZZ, P_KF, P_KM, P_MASS,
                        P_OMEGA_MAX, P_OMEGA_MIN, P_ROTOR_DIR, P_ROTOR_DRAG, P_ROTOR_INERTIA,
                        P_ROTOR_POS, P_SIZE, P_TAU_DOWN, P_TAU_UP)

__all__ = [
    "GRAVITY", "IX_POS", "IX_VEL", "IX_Q", "IX_W", "IX_ROT", "NX",
    "derivatives", "step", "step_n", "step_batch",
    "initial_state",
]

IX_POS = 0
IX_VEL = 3
IX_Q = 6
IX_W = 10
IX_ROT = 13
NX = 17


@njit(cache=True, error_model="numpy")
def derivatives(x, omega_cmd, P, v_wind, f_ext, tau_ext, xdot):
    """Write dx/dt into xdot for state x, rotor commands omega_cmd (rad/s) and disturbances."""
    m = P[P_MASS]
    ixx = P[P_IXX]
    iyy = P[P_IYY]
    izz = P[P_IZZ]
    kf = P[P_KF]
    km = P[P_KM]
    kd = P[P_ROTOR_DRAG]
    jr = P[P_ROTOR_INERTIA]
    omin = P[P_OMEGA_MIN]
    omax = P[P_OMEGA_MAX]

    qw = x[6]
    qx = x[7]
    qy = x[8]
    qz = x[9]
    p = x[10]
    q = x[11]
    r = x[12]

    # R(q), body -> NED
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r01 = 2.0 * (qx * qy - qw * qz)
    r02 = 2.0 * (qx * qz + qw * qy)
    r10 = 2.0 * (qx * qy + qw * qz)
    r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r12 = 2.0 * (qy * qz - qw * qx)
    r20 = 2.0 * (qx * qz - qw * qy)
    r21 = 2.0 * (qy * qz + qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)

    # air-relative velocity in body axes, R^T (v - v_wind)
    ax = x[3] - v_wind[0]
    ay = x[4] - v_wind[1]
    az = x[5] - v_wind[2]
    ub = r00 * ax + r10 * ay + r20 * az
    vb = r01 * ax + r11 * ay + r21 * az
    wb = r02 * ax + r12 * ay + r22 * az

    fx = 0.0
    fy = 0.0
    fz = 0.0
    tx = 0.0
    ty = 0.0
    tz = 0.0
    h_r = 0.0
    h_r_dot = 0.0
    for i in range(4):
        om = x[13 + i]
        rx = P[P_ROTOR_POS + 3 * i]
        ry = P[P_ROTOR_POS + 3 * i + 1]
        rz = P[P_ROTOR_POS + 3 * i + 2]
        s = P[P_ROTOR_DIR + i]
        thrust = kf * om * om
        fz -= thrust
        tx -= ry * thrust
        ty += rx * thrust
        tz += s * km * om * om
        if kd != 0.0:
            # in-plane air velocity at the hub: v_a + w x r_i
            uix = ub + q * rz - r * ry
            uiy = vb + r * rx - p * rz
            dx = -kd * om * uix
            dy = -kd * om * uiy
            fx += dx
            fy += dy
            tx -= rz * dy
            ty += rz * dx
            tz += rx * dy - ry * dx
        cmd = min(max(omega_cmd[i], omin), omax)
        diff = cmd - om
        om_dot = diff / (P[P_TAU_UP] if diff > 0.0 else P[P_TAU_DOWN])
        xdot[13 + i] = om_dot
        h_r -= jr * s * om
        h_r_dot -= jr * s * om_dot

    speed = math.sqrt(ub * ub + vb * vb + wb * wb)
    fx -= (P[P_DRAG_LIN] + P[P_DRAG_QUAD] * speed) * ub
    fy -= (P[P_DRAG_LIN + 1] + P[P_DRAG_QUAD + 1] * speed) * vb
    fz -= (P[P_DRAG_LIN + 2] + P[P_DRAG_QUAD + 2] * speed) * wb

    xdot[0] = x[3]
    xdot[1] = x[4]
    xdot[2] = x[5]
    xdot[3] = (r00 * fx + r01 * fy + r02 * fz + f_ext[0]) / m
    xdot[4] = (r10 * fx + r11 * fy + r12 * fz + f_ext[1]) / m
    xdot[5] = GRAVITY + (r20 * fx + r21 * fy + r22 * fz + f_ext[2]) / m

    xdot[6] = 0.5 * (-qx * p - qy * q - qz * r)
    xdot[7] = 0.5 * (qw * p + qy * r - qz * q)
    xdot[8] = 0.5 * (qw * q - qx * r + qz * p)
    xdot[9] = 0.5 * (qw * r + qx * q - qy * p)

    hx = ixx * p
    hy = iyy * q
    hz = izz * r + h_r
    xdot[10] = (tx + tau_ext[0] - (q * hz - r * hy)) / ixx
    xdot[11] = (ty + tau_ext[1] - (r * hx - p * hz)) / iyy
    xdot[12] = (tz + tau_ext[2] - (p * hy - q * hx) - h_r_dot) / izz


@njit(cache=True, error_model="numpy")
def _rk4(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, ws):
    """One RK4 step of x in place using the (5, NX) scratch ws, then renormalise and contact."""
    on_ground = x[2] >= 0.0
    x0 = x[0]
    y0 = x[1]
    q0w = x[6]
    q0x = x[7]
    q0y = x[8]
    q0z = x[9]
    k1 = ws[0]
    k2 = ws[1]
    k3 = ws[2]
    k4 = ws[3]
    xt = ws[4]
    half = 0.5 * dt
    derivatives(x, omega_cmd, P, v_wind, f_ext, tau_ext, k1)
    for j in range(NX):
        xt[j] = x[j] + half * k1[j]
    derivatives(xt, omega_cmd, P, v_wind, f_ext, tau_ext, k2)
    for j in range(NX):
        xt[j] = x[j] + half * k2[j]
    derivatives(xt, omega_cmd, P, v_wind, f_ext, tau_ext, k3)
    for j in range(NX):
        xt[j] = x[j] + dt * k3[j]
    derivatives(xt, omega_cmd, P, v_wind, f_ext, tau_ext, k4)
    sixth = dt / 6.0
    for j in range(NX):
        x[j] += sixth * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])

    n = math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
    for j in range(6, 10):
        x[j] /= n
    omin = P[P_OMEGA_MIN]
    omax = P[P_OMEGA_MAX]
    for j in range(13, 17):
        x[j] = min(max(x[j], omin), omax)

    if x[2] >= 0.0:
        if on_ground:
            x[0] = x0
            x[1] = y0
        x[2] = 0.0
        x[3] = 0.0
        x[4] = 0.0
        if x[5] > 0.0:
            x[5] = 0.0
        x[10] = 0.0
        x[11] = 0.0
        x[12] = 0.0
        if on_ground and q0x == 0.0 and q0y == 0.0:
            x[6] = q0w
            x[7] = 0.0
            x[8] = 0.0
            x[9] = q0z
        else:
            # level on the legs, heading kept (from before the step if already on the ground)
            if on_ground:
                qw, qx, qy, qz = q0w, q0x, q0y, q0z
            else:
                qw, qx, qy, qz = x[6], x[7], x[8], x[9]
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            x[6] = math.cos(0.5 * yaw)
            x[7] = 0.0
            x[8] = 0.0
            x[9] = math.sin(0.5 * yaw)


@njit(cache=True, error_model="numpy")
def step(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt):
    """Advance x (float64[17]) in place by one RK4 step of dt seconds, inputs held."""
    ws = np.empty((5, NX))
    _rk4(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, ws)


@njit(cache=True, error_model="numpy")
def disturbance_accel(x, omega_cmd, P, v_wind, f_ext, tau_ext, out):
    """Acceleration (NED, m/s^2) the environment adds beyond rotor thrust and gravity: drag on
    the air-relative velocity, rotor drag and direct forces, over the mass, at state x."""
    disturbance_accel_into(x, omega_cmd, P, v_wind, f_ext, tau_ext, out, np.empty(NX))


@njit(cache=True, error_model="numpy")
def disturbance_accel_into(x, omega_cmd, P, v_wind, f_ext, tau_ext, out, xdot):
    """:func:`disturbance_accel` with the (NX,) derivative scratch passed in."""
    derivatives(x, omega_cmd, P, v_wind, f_ext, tau_ext, xdot)
    thrust = 0.0
    for i in range(4):
        w = x[IX_ROT + i]
        thrust += w * w
    thrust *= P[P_KF] / P[P_MASS]
    qw, qx, qy, qz = x[IX_Q], x[IX_Q + 1], x[IX_Q + 2], x[IX_Q + 3]
    # third column of R(q): body z in NED
    out[0] = xdot[3] + 2.0 * (qx * qz + qw * qy) * thrust
    out[1] = xdot[4] + 2.0 * (qy * qz - qw * qx) * thrust
    out[2] = xdot[5] - GRAVITY + (1.0 - 2.0 * (qx * qx + qy * qy)) * thrust


@njit(cache=True, error_model="numpy")
def rk4_step(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, ws):
    """:func:`step` with the (5, NX) scratch passed in (no allocation: for compiled loops)."""
    _rk4(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, ws)


@njit(cache=True, error_model="numpy")
def step_n(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, n):
    """Advance x in place by n RK4 steps of dt with all inputs held."""
    ws = np.empty((5, NX))
    for _ in range(n):
        _rk4(x, omega_cmd, P, v_wind, f_ext, tau_ext, dt, ws)


@njit(cache=True, parallel=True, error_model="numpy")
def _step_batch(X, OMEGA_CMD, P, V_WIND, F_EXT, TAU_EXT, dt, n):
    N = X.shape[0]
    ws = np.empty((N, 5, NX))
    for i in prange(N):
        for _ in range(n):
            _rk4(X[i], OMEGA_CMD[i], P[i], V_WIND[i], F_EXT[i], TAU_EXT[i], dt, ws[i])


def step_batch(X, OMEGA_CMD, P, V_WIND, F_EXT, TAU_EXT, dt, n=1):
    """Advance N independent vehicles X (N, 17) in place by n RK4 steps, in parallel.

    OMEGA_CMD is (N, 4); P is one packed vector (P_SIZE,) shared by all or (N, P_SIZE);
    V_WIND, F_EXT, TAU_EXT are (N, 3) or (3,) shared. Inputs are held over the n steps.
    Each vehicle follows exactly the arithmetic of ``step``.
    """
    N = X.shape[0]
    if X.ndim != 2 or X.shape[1] != NX or X.dtype != np.float64:
        raise ValueError(f"X must be float64 (N, {NX}), got {X.dtype} {X.shape}")
    if not X.flags.writeable:
        raise ValueError("X must be writeable (it is advanced in place)")
    _step_batch(
        X,
        np.broadcast_to(np.asarray(OMEGA_CMD, dtype=np.float64), (N, 4)),
        np.broadcast_to(np.asarray(P, dtype=np.float64), (N, P_SIZE)),
        np.broadcast_to(np.asarray(V_WIND, dtype=np.float64), (N, 3)),
        np.broadcast_to(np.asarray(F_EXT, dtype=np.float64), (N, 3)),
        np.broadcast_to(np.asarray(TAU_EXT, dtype=np.float64), (N, 3)),
        float(dt),
        int(n),
    )


def initial_state(position=(0.0, 0.0, 0.0), yaw: float = 0.0, rotor_speed: float = 0.0,
                  velocity=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A level state at ``position`` (NED) with heading ``yaw`` and all rotors at rotor_speed."""
    x = np.zeros(NX)
    x[IX_POS:IX_POS + 3] = position
    x[IX_VEL:IX_VEL + 3] = velocity
    x[IX_Q:IX_Q + 4] = quat_from_euler(0.0, 0.0, yaw)
    x[IX_ROT:IX_ROT + 4] = rotor_speed
    return x
