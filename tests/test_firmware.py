"""The vehicle's firmware pieces on their own: mixer, attitude error, gains, position loop."""

import math

import numpy as np
import pytest

from mavadrc.control import geometry as G
from mavadrc.control.rotations import quat_from_euler, quat_to_rotmat
from sim.firmware import attitude as A
from sim.firmware import position as PL
from sim.firmware.mixer import Mixer
from sim.params import load_vehicle


@pytest.fixture(scope="module", params=["crazyflie", "x500"])
def vehicle(request):
    return load_vehicle(request.param)


# --- mixer ---------------------------------------------------------------------------------------


def test_mixer_gives_what_is_asked_when_it_is_feasible(vehicle):
    m = Mixer(vehicle)
    auth = m.torque_authority(vehicle.weight)
    rng = np.random.default_rng(1)
    for _ in range(50):
        thrust = vehicle.weight * rng.uniform(0.7, 1.3)
        tau = auth * rng.uniform(-0.25, 0.25, 3)
        omega, wrench = m.mix(thrust, tau)
        np.testing.assert_allclose(wrench, [thrust, *tau], rtol=1e-9, atol=1e-12 * thrust)
        np.testing.assert_allclose(vehicle.allocation_matrix() @ omega ** 2, wrench, rtol=1e-12)


def test_mixer_keeps_roll_and_pitch_when_thrust_saturates(vehicle):
    m = Mixer(vehicle)
    auth = m.torque_authority(vehicle.weight)
    tau = np.array([0.4 * auth[0], -0.3 * auth[1], 0.0])
    for thrust in (vehicle.max_thrust, 1.5 * vehicle.max_thrust, 0.0):
        omega, wrench = m.mix(thrust, tau)
        np.testing.assert_allclose(wrench[1:3], tau[:2], rtol=1e-9)
    # at full thrust the collective gives way, at zero thrust it is raised (airmode)
    assert m.mix(vehicle.max_thrust, tau)[1][0] < vehicle.max_thrust
    assert m.mix(0.0, tau)[1][0] > 0.0
    # without airmode the thrust is never raised: no authority at zero thrust
    no_air = Mixer(vehicle, airmode=False).mix(0.0, tau)[1]
    assert np.all(np.abs(no_air[1:]) < 1e-3 * np.abs(tau).max())


def test_mixer_reduces_yaw_first_and_scales_roll_pitch_together(vehicle):
    m = Mixer(vehicle)
    auth = m.torque_authority(vehicle.weight)
    tau = np.array([0.5 * auth[0], 0.0, 5.0 * auth[2]])
    wrench = m.mix(vehicle.weight, tau)[1]
    assert wrench[1] == pytest.approx(tau[0], rel=1e-6)
    assert 0.0 < wrench[3] < tau[2]
    # roll/pitch beyond authority: scaled by one factor, direction kept
    big = np.array([3.0 * auth[0], -1.5 * auth[1], 0.0])
    wrench = m.mix(vehicle.weight, big)[1]
    assert wrench[1] / big[0] == pytest.approx(wrench[2] / big[1], rel=1e-4)
    assert 0.0 < wrench[1] / big[0] < 1.0


def test_mixer_never_commands_outside_the_motor_range(vehicle):
    m = Mixer(vehicle)
    rng = np.random.default_rng(2)
    auth = m.torque_authority(vehicle.weight)
    for _ in range(200):
        thrust = vehicle.max_thrust * rng.uniform(-0.5, 2.0)
        tau = auth * rng.uniform(-5.0, 5.0, 3)
        omega = m.mix(thrust, tau)[0]
        assert np.all(omega >= vehicle.omega_min) and np.all(omega <= vehicle.omega_max)


# --- PX4-like attitude loop ----------------------------------------------------------------------


def _error(q, qd, yaw_w=0.4):
    out = np.empty(3)
    A.attitude_error(np.asarray(q, float), np.asarray(qd, float), yaw_w, out, np.empty(8))
    return out


def test_attitude_error_roll_pitch_exact_and_yaw_weighted():
    assert np.allclose(_error([1, 0, 0, 0], [1, 0, 0, 0]), 0.0)
    e = _error(quat_from_euler(0.1, 0.0, 0.3), quat_from_euler(0.3, 0.0, 0.3))
    np.testing.assert_allclose(e, [2 * math.sin(0.1), 0.0, 0.0], atol=1e-12)
    # pure heading error: weighted by yaw_w (the P gain divides it back out)
    e = _error([1, 0, 0, 0], quat_from_euler(0.0, 0.0, 0.2), yaw_w=0.4)
    np.testing.assert_allclose(e, [0.0, 0.0, 2 * math.sin(0.4 * 0.1)], atol=1e-12)
    # the antipodal quaternion is the same attitude
    qd = quat_from_euler(-0.2, 0.15, 1.0)
    np.testing.assert_allclose(_error([1, 0, 0, 0], qd), _error([1, 0, 0, 0], -qd), atol=1e-12)


def test_px4_gains_put_a_triple_pole_at_the_bandwidth(vehicle):
    lam = np.array([25.0, 25.0, 10.0])
    g = A.px4_gains(vehicle, lam, integral=0.0)
    tau = A.motor_time_constant(vehicle)
    for i in range(3):
        t = max(tau, 1.0 / (3.0 * lam[i]))
        roots = np.roots([t, 1.0 + g["rate_d"][i], g["rate_p"][i], g["rate_p"][i] * g["att_p"][i]])
        np.testing.assert_allclose(roots, -lam[i], rtol=1e-3)
        assert g["rate_d"][i] >= 0.0


def test_firmware_params_refuse_unknown_kind_and_gain(vehicle):
    m = Mixer(vehicle)
    with pytest.raises(ValueError, match="attitude_controller"):
        A.firmware_params(vehicle, "lqr", h=0.001, thrust_scale=1.0, mixer=m)
    with pytest.raises(ValueError, match="unknown gains"):
        A.firmware_params(vehicle, "px4", h=0.001, thrust_scale=1.0, mixer=m, wc=3.0)


# --- position loop -------------------------------------------------------------------------------


def _pos_step(sp, pos=(0, 0, -1), vel=(0, 0, 0), yaw=0.0, hover=0.5, landed=False, ps=None):
    pp = PL.position_params(h=0.01)
    M = G.mapping_params(hover_thrust=hover)
    ps = np.zeros(PL.NPS) if ps is None else ps
    out = np.zeros(G.NO + 3)
    PL.position_step(ps, pp, M, np.asarray(pos, float), np.asarray(vel, float),
                     np.asarray(sp, float), yaw, landed, out)
    return out, ps, pp


def _sp(pos=None, vel=None, acc=None):
    sp = np.full(PL.NPSP, math.nan)
    for idx, v in ((PL.PSP_POS, pos), (PL.PSP_VEL, vel), (PL.PSP_ACC, acc)):
        if v is not None:
            sp[idx:idx + 3] = v
    return sp


def test_position_loop_holds_hover_at_the_setpoint():
    out, _, _ = _pos_step(_sp(pos=(0, 0, -1)), yaw=0.3)
    assert out[G.O_THRUST] == pytest.approx(0.5)
    np.testing.assert_allclose(out[0:4], quat_from_euler(0.0, 0.0, 0.3), atol=1e-12)


def test_position_loop_ignore_mask_semantics():
    nan = math.nan
    # velocity only: a = kv * (v_sp - v)
    out, _, pp = _pos_step(_sp(vel=(1.0, 0.0, 0.0)))
    assert out[G.NO] == pytest.approx(pp[PL.PP_KV] * 1.0)
    # position + velocity feed-forward: v_sp = kp * e + v_ff
    out, _, pp = _pos_step(_sp(pos=(0.5, 0, -1), vel=(0.2, 0, 0)))
    assert out[G.NO] == pytest.approx(pp[PL.PP_KV] * (pp[PL.PP_KP] * 0.5 + 0.2))
    # acceleration only on x, nothing on y: a = a_ff, y gets nothing
    out, _, _ = _pos_step(_sp(acc=(0.7, nan, nan)))
    np.testing.assert_allclose(out[G.NO:G.NO + 3], [0.7, 0.0, 0.0])
    # speed limits: far away horizontally -> |v_sp| = 12 m/s at most
    out, _, pp = _pos_step(_sp(pos=(1000.0, 1000.0, -1)))
    assert math.hypot(out[G.NO], out[G.NO + 1]) == pytest.approx(pp[PL.PP_KV] * 12.0)


def test_position_loop_integral_resets_on_the_ground_and_respects_the_tilt_limit():
    ps = np.zeros(PL.NPS)
    for _ in range(10):
        _pos_step(_sp(pos=(0.2, 0, -1)), ps=ps)
    assert ps[PL.PS_INT] > 0.0
    _pos_step(_sp(pos=(0.2, 0, -1)), ps=ps, landed=True)
    assert np.all(ps[PL.PS_INT:PL.PS_INT + 3] == 0.0)
    out, _, _ = _pos_step(_sp(acc=(50.0, 0.0, 0.0)))
    R = np.empty((3, 3))
    quat_to_rotmat(out[0:4], R)
    assert math.degrees(math.acos(R[2, 2])) == pytest.approx(35.0, abs=1e-6)  # mapping default


def test_land_detector_needs_low_thrust_and_stillness_for_the_trigger_time():
    fs = np.zeros(A.NFS)
    fp = np.zeros(A.NFP)
    fp[A.FP_LD:A.FP_LD + PL.NLD] = [0.3, 0.25, 1.0, 0.5]
    fs[A.FS_ARMED] = 1.0
    still = np.zeros(3)
    for _ in range(49):
        PL.land_detect(fs, fp, 0.1, still, 0.01)
    assert fs[A.FS_LANDED] == 0.0
    PL.land_detect(fs, fp, 0.1, still, 0.01)
    assert fs[A.FS_LANDED] == 1.0
    PL.land_detect(fs, fp, 0.5, still, 0.01)  # thrust up: flying again
    assert fs[A.FS_LANDED] == 0.0
    for _ in range(100):  # low thrust while moving is not a landing
        PL.land_detect(fs, fp, 0.1, np.array([0.0, 0.0, 1.0]), 0.01)
    assert fs[A.FS_LANDED] == 0.0
    fs[A.FS_ARMED] = 0.0
    PL.land_detect(fs, fp, 0.5, still, 0.01)
    assert fs[A.FS_LANDED] == 1.0


def test_takeoff_profile_respects_limits_and_stops_at_the_target():
    pr = PL.Profile1D(0.0, -2.0, 1.5, 2.0)
    ps, vs = [], []
    for _ in range(1000):
        pr.step(0.01)
        ps.append(pr.p)
        vs.append(pr.v)
        if pr.done:
            break
    assert pr.done and pr.p == -2.0
    assert min(ps) >= -2.0 - 1e-12
    assert max(abs(v) for v in vs) <= 1.5 + 1e-12
    assert np.max(np.abs(np.diff(vs))) <= 2.0 * 0.01 + 1e-12
