"""The PX4-style cascaded PID position channel (kind 'pid').

Plant unless stated: the exact-ZOH double integrator y'' = u + d at h = 10 ms (the position
loop's rate), the measured velocity fed back.  The point-mass helper is the one of
test_position_attitude (attitude reached at once, thrust along -body z).
"""

import math
import os

import numpy as np
import pytest

from mavadrc.control import PD, PID, PositionController
from mavadrc.control import geometry as G
from mavadrc.control import kernels as K
from mavadrc.control.channels import pid_gains, pid_params
from mavadrc.control.rotations import quat_to_rotmat
from mavadrc.design.gains import default_gains, make_controller
from mavadrc.mission.config import load_mission
from sim.yamlio import ConfigError

H = 0.01
#: PX4's multicopter position-loop defaults (mc_pos_control), per axis x, y, z
PX4 = dict(kp_pos=(0.95, 0.95, 1.0), kp_vel=(1.8, 1.8, 4.0), ki_vel=(0.4, 0.4, 2.0),
           kd_vel=(0.2, 0.2, 0.0))


def run(ctrl, ref, T, d=0.0, rate=True, y0=None, v0=None):
    """``ctrl`` on y'' = u + d; ``ref(t) -> (r, rdot, rddot)``.  Starts on the reference unless
    y0/v0 say otherwise.  Returns (t, y, e = r - y, u), t the time after each step."""
    n = int(round(T / H))
    r0 = ref(0.0)
    y = r0[0] if y0 is None else y0
    yd = r0[1] if v0 is None else v0
    ys, es, us = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        r, rd, rdd = ref(k * H)
        u = ctrl.update(y, r, rd, rdd, ydot=yd if rate else None)
        a = u + d
        y, yd = y + H * yd + 0.5 * H * H * a, yd + H * a
        ys[k], es[k], us[k] = y, ref((k + 1) * H)[0] - y, u
    return np.arange(1, n + 1) * H, ys, es, us


def unit_step(t):
    return 1.0, 0.0, 0.0


def settling_time(t, y, target, band):
    outside = np.nonzero(np.abs(y - target) > band)[0]
    return t[outside[-1]] if outside.size else 0.0


# --- the law on one axis -------------------------------------------------------------------------


@pytest.mark.parametrize("rate", [True, False], ids=["measured-rate", "differentiated"])
def test_integral_action_removes_a_constant_disturbance_that_pd_leaves_as_d_over_kp(rate):
    d, wc = 1.5, 2.5
    pid = PID(h=H, wc=wc)
    t, _, e, _ = run(pid, unit_step, 15.0, d=d, rate=rate, y0=0.0, v0=0.0)
    pid_err = np.abs(e[t >= 10.0]).max()
    assert pid_err < 1e-3
    assert pid.z[2] == pytest.approx(d, abs=1e-3)  # the integrator's disturbance estimate
    pd = PD.from_bandwidth(h=H, wc=wc)
    _, _, e_pd, _ = run(pd, unit_step, 15.0, d=d, rate=rate, y0=0.0, v0=0.0)
    assert e_pd[-1] == pytest.approx(-d / pd.kp, abs=1e-3)  # -0.24 m: PD has no integrator
    assert abs(e_pd[-1]) > 200.0 * pid_err


@pytest.mark.parametrize("axis", [0, 2], ids=["x", "z"])
def test_default_gains_step_response_does_not_overshoot_and_settles(axis):
    """Flight's default pid gains through the position controller on a point mass: a 1 m step
    (north, or up) overshoots < 5 % and settles to 2 % within 3.5 s (x, wc = 2.5: predicted
    3.1 s) and 3.0 s (z, wc = 3: 2.6 s)."""
    ctrl = PositionController("pid", h=H, hover_thrust=0.5, **default_gains("pid"))
    start = np.array([0.0, 0.0, -1.0])
    target = start.copy()
    target[axis] += 1.0 if axis == 0 else -1.0
    p = fly_point_mass(ctrl, target, 10.0, start)[0][:, axis]
    t = np.arange(1, len(p) + 1) * H
    moved = (p - start[axis]) / (target[axis] - start[axis])  # 0 -> 1
    assert (moved.max() - 1.0) * 100.0 < 5.0
    assert settling_time(t, moved, 1.0, 0.02) < (3.5 if axis == 0 else 3.0)
    assert abs(moved[-1] - 1.0) < 1e-3


def sine(t, a=1.0, w=0.5):
    return a * math.sin(w * t), a * w * math.cos(w * t), -a * w * w * math.sin(w * t)


def test_feed_forward_tracks_a_slow_sine_and_a_ramp():
    t, _, e, _ = run(PID(h=H, wc=2.5), sine, 30.0)
    assert np.abs(e[t >= 10.0]).max() < 1e-3
    t, _, e_noff, _ = run(PID(h=H, wc=2.5), lambda t: (sine(t)[0], 0.0, 0.0), 30.0)
    assert np.abs(e_noff[t >= 10.0]).max() > 0.1  # the feed-forward is what does it
    _, _, e, _ = run(PID(h=H, wc=2.5), lambda t: (0.5 * t, 0.5, 0.0), 20.0)
    assert np.abs(e).max() < 1e-9
    # without rdot the ramp lags by rdot/kp_pos: the integrator acts on the velocity error
    t, _, e, _ = run(PID(h=H, wc=2.5), lambda t: (0.5 * t, 0.0, 0.0), 20.0)
    assert e[t >= 15.0] == pytest.approx(0.5 / 1.25, abs=1e-3)


def test_d_acts_on_the_measurement_only():
    """A reference step gives no derivative kick; a measured acceleration is fed back through
    the low-pass (20 Hz default)."""
    with_d = PID(h=H, kp_pos=1.0, kp_vel=2.0, kd_vel=0.5)
    without = PID(h=H, kp_pos=1.0, kp_vel=2.0)
    for _ in range(5):
        assert with_d.update(0.0, 0.0, ydot=0.0) == without.update(0.0, 0.0, ydot=0.0)
    assert with_d.update(0.0, 1.0, ydot=0.0) == without.update(0.0, 1.0, ydot=0.0) == 2.0
    pid = PID(h=H, kp_pos=1.0, kp_vel=2.0, kd_vel=0.5)
    acc = 3.0
    for k in range(100):  # 1 s at a constant measured acceleration
        u = pid.update(0.0, 0.0, ydot=acc * k * H)
    assert u == pytest.approx(-2.0 * acc * 99 * H - 0.5 * acc, rel=1e-6)
    pid = PID(h=H, kp_pos=1.0, kp_vel=2.0, kd_vel=0.5, d_cutoff_hz=20.0)
    pid.update(0.0, 0.0, ydot=0.0)
    u = pid.update(0.0, 0.0, ydot=acc * H)  # the first step of it: one low-pass step
    alpha = 1.0 - math.exp(-2.0 * math.pi * 20.0 * H)
    assert u == pytest.approx(-2.0 * acc * H - 0.5 * alpha * acc, rel=1e-9)


def test_integrator_is_held_at_the_channels_own_limits_and_clamped_to_i_limit():
    """A 5 m step with |u| <= 1 m/s^2: the integrator hardly moves while u is cut, and the
    overshoot is the PD kind's (the saturation's own).  Told the unlimited command was applied,
    it runs into i_limit and overshoots further."""
    def step(ctrl, blind=False):
        y = yd = 0.0
        ys, i_abs, cut = np.empty(2000), np.empty(2000), 0
        for k in range(2000):
            u = ctrl.update(y, 5.0, ydot=yd)
            cut += abs(u) == 1.0
            if blind:
                ctrl.set_applied_input(ctrl.u0)
            y, yd = y + H * yd + 0.5 * H * H * u, yd + H * u
            ys[k], i_abs[k] = y, abs(ctrl._s[K.S_I])
        return ys.max() - 5.0, i_abs.max(), cut * H, abs(y - 5.0)

    os_pd = step(PD.from_bandwidth(h=H, wc=2.5, u_min=-1.0, u_max=1.0))[0]
    os_pid, i_max, cut, final = step(PID(h=H, wc=2.5, u_min=-1.0, u_max=1.0))
    assert cut > 3.0 and i_max < 0.5 and final < 1e-3
    assert os_pid < os_pd + 0.1
    os_blind, i_blind, _, _ = step(PID(h=H, wc=2.5, u_min=-1.0, u_max=1.0), blind=True)
    assert i_blind == pytest.approx(3.0) and os_blind > 1.5 * os_pid
    clamped = PID(h=H, wc=2.5, i_limit=0.5)
    run(clamped, unit_step, 20.0, d=2.0, y0=0.0, v0=0.0)  # needs -2 m/s^2, may give 0.5
    assert clamped.integrator == pytest.approx(-0.5)


# --- closed-loop poles ----------------------------------------------------------------------------


def closed_loop_matrix(params):
    """The linear map of one control step + exact-ZOH double-integrator step on the states
    (y, ydot, I, and with a D term its filter and previous rate), built column by column."""
    d_term = params[K.P_KDV] != 0.0
    slots = [K.S_I] + ([K.S_DF, K.S_VPREV] if d_term else [])
    n = 2 + len(slots)
    A = np.empty((n, n))
    for j in range(n):
        x = np.zeros(n)
        x[j] = 1.0
        s = K.new_state()
        s[K.S_INIT] = 2.0  # past the first step
        for k, slot in enumerate(slots):
            s[slot] = x[2 + k]
        y, yd = x[0], x[1]
        u = K.channel_update(s, params, y, yd, 0.0, 0.0, 0.0, params[K.P_H])
        A[:, j] = [y + H * yd + 0.5 * H * H * u, yd + H * u] + [s[slot] for slot in slots]
    return A


def test_shorthand_places_the_documented_poles():
    """pid_gains: s^3 + 2wc s^2 + 1.5wc^2 s + 0.25wc^3, poles (-0.886 +- 0.558j, -0.228) wc."""
    assert pid_gains(2.0) == (1.0, 4.0, 2.0, 0.0)  # PX4's MPC_Z_P, _VEL_P_ACC, _VEL_I_ACC
    for wc in (1.0, 2.5, 3.0):
        s = np.log(np.linalg.eigvals(closed_loop_matrix(pid_params(h=H, wc=wc)))) / H
        want = np.array([-0.886 + 0.558j, -0.886 - 0.558j, -0.228]) * wc
        assert np.sort_complex(s) == pytest.approx(np.sort_complex(want), abs=0.04 * wc)


@pytest.mark.parametrize("axis", [0, 2], ids=["xy", "z"])
@pytest.mark.parametrize("d_cutoff_hz", [5.0, 20.0])
def test_px4_default_gains_are_stable_through_the_kernel(axis, d_cutoff_hz):
    g = {k: v[axis] for k, v in PX4.items()}
    p = pid_params(h=H, d_cutoff_hz=d_cutoff_hz, **g)
    rho = np.abs(np.linalg.eigvals(closed_loop_matrix(p))).max()
    assert rho < 1.0 - 1e-4
    t, y, e, _ = run(PID(h=H, d_cutoff_hz=d_cutoff_hz, **g), unit_step, 60.0, d=0.5, y0=0.0,
                     v0=0.0)
    assert (y.max() - 1.0) < 0.5 and np.abs(e[t >= 50.0]).max() < 1e-3


def test_px4_default_gains_fly_the_point_mass():
    ctrl = PositionController("pid", h=H, hover_thrust=0.5, d_cutoff_hz=5.0, **PX4)
    target = np.array([1.0, -1.0, -2.0])
    p, _, _ = fly_point_mass(ctrl, target, 40.0, (0.0, 0.0, -1.0), d=(0.3, -0.2, 0.4))
    assert np.abs(p[-500:] - target).max() < 1e-3


# --- in the position controller ------------------------------------------------------------------


def thrust_acceleration(q, thrust, tpa):
    R = np.empty((3, 3))
    quat_to_rotmat(np.asarray(q, dtype=float), R)
    return -R[:, 2] * thrust / tpa + np.array([0.0, 0.0, G.GRAVITY])


def fly_point_mass(ctrl, target, T, start, d=(0.0, 0.0, 0.0), blind=False):
    """Point mass at hover thrust 0.5, attitude reached at once; returns (positions, x-axis
    integrator, saturated?) per step.  ``blind``: tell the channels the unlimited command was
    applied (conditional integration defeated)."""
    tpa = 0.5 / G.GRAVITY
    p = np.array(start, dtype=float)
    v = np.zeros(3)
    n = int(round(T / H))
    P, I, sat = np.empty((n, 3)), np.empty(n), np.zeros(n, dtype=bool)
    for k in range(n):
        q, thrust = ctrl.update(p, v, target)
        if blind:
            ctrl._S[:, K.S_U] = ctrl.accel_command
        sat[k] = np.abs(ctrl.accel_command - ctrl.accel_applied).max() > 1e-6
        a = thrust_acceleration(q, thrust, tpa) + np.asarray(d)
        for _ in range(10):
            dt = H / 10
            p = p + dt * v + 0.5 * dt * dt * a
            v = v + dt * a
        P[k], I[k] = p, ctrl._S[0, K.S_I]
    return P, I, sat


def test_tilt_saturation_does_not_wind_the_integrator_up():
    """A 5 m step with a 10 deg tilt limit: the command is cut for over 3 s.  Conditional
    integration keeps the integrator far inside i_limit and the overshoot at the PD kind's
    (which has no integrator; the overshoot is the saturation's own).  Told the unlimited
    command was applied, the integrator runs into the clamp and overshoots 2.5x as far; without
    the clamp, it never settles."""
    tilt = math.radians(10.0)
    start, target = (0.0, 0.0, -1.0), np.array([5.0, 0.0, -1.0])

    def step(kind, blind=False, **gains):
        ctrl = PositionController(kind, h=H, hover_thrust=0.5, wc=2.5, tilt_max=tilt, **gains)
        P, I, sat = fly_point_mass(ctrl, target, 30.0, start, blind=blind)
        return P[:, 0].max() - 5.0, np.abs(I).max(), sat.sum() * H, np.abs(P[-1] - target).max()

    os_pd, _, _, _ = step("pd")
    os_pid, i_max, saturated, final = step("pid")
    assert saturated > 3.0
    assert i_max < 0.5  # i_limit is 3
    assert os_pid < os_pd + 0.1 and os_pid < 0.5
    assert final < 1e-3
    os_blind, i_blind, _, final_blind = step("pid", blind=True)
    assert i_blind == pytest.approx(3.0)  # the clamp is all that held it
    assert os_blind > 2.0 * os_pid and final_blind < 1e-3
    _, _, _, final_unclamped = step("pid", blind=True, i_limit=1e3)
    assert final_unclamped > 1.0


def test_position_controller_pid_gives_a_unit_quaternion_and_thrust():
    ctrl = PositionController("pid", h=H, hover_thrust=0.5, wc=2.5)
    q, thrust = ctrl.update([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    assert np.allclose(q, [1.0, 0.0, 0.0, 0.0]) and thrust == pytest.approx(0.5)
    rng = np.random.default_rng(1)
    for _ in range(50):
        q, thrust = ctrl.update(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3),
                                rng.normal(size=3), rng.normal(size=3), yaw=rng.uniform(-3, 3))
        assert q.shape == (4,) and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
        assert 0.05 <= thrust <= 1.0
    assert ctrl.z.shape == (3, 3) and np.all(np.isfinite(ctrl.disturbance))
    with pytest.raises(ValueError, match="pos"):
        ctrl.update([0.0, math.nan, 0.0], None, [0.0, 0.0, 0.0])


def test_non_finite_input_never_poisons_the_state():
    clean, hit = PID(h=H, wc=2.0, kd_vel=0.3), PID(h=H, wc=2.0, kd_vel=0.3)
    for k in range(25):
        clean.update(0.01 * k, 1.0)
        hit.update(0.01 * k, 1.0)
    with pytest.raises(ValueError, match="y"):
        hit.update(math.nan, 1.0)
    with pytest.raises(ValueError, match="ydot"):
        hit.update(0.3, 1.0, ydot=math.inf)
    for k in range(25, 50):
        assert hit.update(0.01 * k, 1.0) == clean.update(0.01 * k, 1.0)
    assert np.all(np.isfinite(hit._s))


@pytest.mark.parametrize("kwargs, name", [
    (dict(), "wc"),
    (dict(kp_pos=1.0), "kp_vel"),
    (dict(wc=-1.0), "wc"),
    (dict(wc=2.0, kp_pos=0.0), "kp_pos"),
    (dict(wc=2.0, ki_vel=-1.0), "ki_vel"),
    (dict(wc=2.0, kd_vel=math.nan), "kd_vel"),
    (dict(wc=2.0, i_limit=-1.0), "i_limit"),
    (dict(wc=2.0, d_cutoff_hz=-5.0), "d_cutoff_hz"),
    (dict(wc=2.0, u_min=1.0, u_max=0.0), "u_min"),
])
def test_bad_pid_parameters_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        PID(h=H, **kwargs)


def test_explicit_gains_override_the_shorthand():
    assert PID(h=H, wc=2.0).gains == (1.0, 4.0, 2.0, 0.0)
    assert PID(h=H, wc=2.0, ki_vel=0.0, kd_vel=0.2).gains == (1.0, 4.0, 0.0, 0.2)
    assert PID(h=H, kp_pos=0.95, kp_vel=1.8).gains == (0.95, 1.8, 0.0, 0.0)


# --- missions ------------------------------------------------------------------------------------

MISSION = """name: t
vehicle: crazyflie
controller: {CONTROLLER}
trajectory:
  - takeoff: {altitude: 1.0}
  - hover: {duration: 1}
  - land: {speed: 0.5}
"""


def write_mission(tmp_path, controller):
    path = tmp_path / "pid.yaml"
    path.write_text(MISSION.replace("{CONTROLLER}", controller))
    return path


def test_a_pid_mission_loads_and_builds_the_default_controller(tmp_path):
    m = load_mission(write_mission(tmp_path, "{type: pid}"))
    assert m.controller.kind == "pid"
    ctrl = make_controller(m.controller, hover_thrust=m.hover_thrust)
    P, _ = ctrl.params
    for i, wc in enumerate((2.5, 2.5, 3.0)):
        assert np.array_equal(P[i], pid_params(h=0.01, wc=wc, i_limit=3.0))
    q, thrust = ctrl.update([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.5, 0.0, -1.0])
    assert np.linalg.norm(q) == pytest.approx(1.0) and 0.0 < thrust <= 1.0


def test_a_pid_mission_takes_px4_style_gains(tmp_path):
    m = load_mission(write_mission(
        tmp_path, "{type: pid, kp_pos: [0.95, 0.95, 1], kp_vel: [1.8, 1.8, 4], "
                  "ki_vel: [0.4, 0.4, 2], kd_vel: [0.2, 0.2, 0], d_cutoff_hz: 5, i_limit: 4}"))
    P, _ = make_controller(m.controller, hover_thrust=m.hover_thrust).params
    for i in range(3):
        want = pid_params(h=0.01, d_cutoff_hz=5.0, i_limit=4.0,
                          **{k: v[i] for k, v in PX4.items()})
        assert np.array_equal(P[i], want)


@pytest.mark.parametrize("controller, field", [
    ("{type: pid, kp_pos: 0}", "controller.kp_pos"),
    ("{type: pid, ki_vel: -1}", "controller.ki_vel"),
    ("{type: pid, kd_vel: [0.1, 0.2]}", "controller.kd_vel"),
])
def test_bad_pid_gains_in_a_mission_are_refused(tmp_path, controller, field):
    path = write_mission(tmp_path, controller)
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    assert f"{path}:3" in str(err.value) and field in str(err.value)


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1",
                    reason="a whole simulated flight is too slow without the compiled kernels")
def test_pid_flies_the_gusty_x500_mission_in_process():
    """The bundled x500 in moderate gusts, default gains: the integrator takes most of the
    PD kind's error away (measured: max 0.08 m vs PD's 0.21 m)."""
    from pathlib import Path

    from mavadrc.fast.inprocess import L_POS, L_REF
    from mavadrc.fast.fly import fly_inprocess

    mission = load_mission(Path(__file__).resolve().parent.parent / "configs" / "missions"
                           / "x500_gusts.yaml")
    err = {}
    for kind in ("pid", "pd"):
        run_ = fly_inprocess(mission, kind=kind)
        assert run_.aborted is None
        log = run_.log
        err[kind] = np.linalg.norm(log[:, L_POS:L_POS + 3] - log[:, L_REF:L_REF + 3], axis=1)
    assert err["pid"].max() < 0.12
    assert np.sqrt(np.mean(err["pid"] ** 2)) < 0.5 * np.sqrt(np.mean(err["pd"] ** 2))
