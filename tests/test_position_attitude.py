"""The geometric acceleration map, the position controller and the attitude controller."""

import math

import numpy as np
import pytest

from mavadrc.control import AttitudeController, PositionController, acceleration_to_attitude
from mavadrc.control import geometry as G
from mavadrc.control import rotations as rot
from mavadrc.mission.trajectories import Circle

GRAV = G.GRAVITY


def rotmat(q):
    R = np.empty((3, 3))
    rot.quat_to_rotmat(np.asarray(q, dtype=float), R)
    return R


def euler(q):
    e = np.empty(3)
    rot.quat_to_euler(np.asarray(q, dtype=float), e)
    return e


def thrust_acceleration(q, thrust, tpa):
    """What a rigid body does with this setpoint: thrust along -body z, plus gravity."""
    return -rotmat(q)[:, 2] * thrust / tpa + np.array([0.0, 0.0, GRAV])


# --- the map -------------------------------------------------------------------------------------


def test_the_map_reproduces_the_commanded_acceleration_and_honours_yaw():
    rng = np.random.default_rng(3)
    hover = 0.45
    for _ in range(500):
        acc = rng.uniform([-3, -3, -4], [3, 3, 3])
        yaw = rng.uniform(-math.pi, math.pi)
        q, thrust, applied = acceleration_to_attitude(acc, yaw, hover_thrust=hover,
                                                      tilt_max=math.radians(60))
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
        assert np.allclose(applied, acc, atol=1e-12)  # inside the limits nothing is cut
        assert np.allclose(thrust_acceleration(q, thrust, hover / GRAV), acc, atol=1e-9)
        assert rot.wrap_pi(euler(q)[2] - yaw) == pytest.approx(0.0, abs=1e-9)


def test_mass_and_max_thrust_normalisation():
    q, thrust, _ = acceleration_to_attitude([0, 0, 0], 0.0, mass=2.0, max_thrust=40.0)
    assert thrust == pytest.approx(2.0 * GRAV / 40.0)
    assert np.allclose(q, [1, 0, 0, 0])


def test_tilt_limit_holds_with_altitude_priority():
    tilt = math.radians(30)
    for acc in ([20.0, 0.0, 0.0], [-7.0, 15.0, -2.0], [3.0, 3.0, 1.0]):
        q, thrust, applied = acceleration_to_attitude(acc, 0.3, hover_thrust=0.4, tilt_max=tilt)
        body_z = rotmat(q)[:, 2]
        assert math.acos(body_z[2]) <= tilt + 1e-9
        assert applied[2] == pytest.approx(acc[2])  # vertical kept
        horiz = np.hypot(acc[0], acc[1])
        assert np.allclose(applied[:2] / np.linalg.norm(applied[:2]), np.array(acc[:2]) / horiz)
        assert np.allclose(thrust_acceleration(q, thrust, 0.4 / GRAV), applied, atol=1e-9)


def test_thrust_limits_keep_altitude_first():
    # climbing harder than max thrust allows: all thrust goes up, nothing is left for x/y
    q, thrust, applied = acceleration_to_attitude([2.0, 0.0, -30.0], 0.0, hover_thrust=0.5,
                                                  thrust_max=0.9)
    assert thrust == pytest.approx(0.9)
    assert applied[0] == pytest.approx(0.0, abs=1e-12)
    assert applied[2] == pytest.approx(GRAV - 0.9 / (0.5 / GRAV))
    # diving faster than gravity: minimum thrust, level
    q, thrust, applied = acceleration_to_attitude([0.0, 0.0, 15.0], 0.0, hover_thrust=0.5,
                                                  thrust_min=0.08)
    assert thrust == pytest.approx(0.08)
    # near the thrust limit the horizontal part gets only what is left
    q, thrust, applied = acceleration_to_attitude([10.0, 0.0, -8.0], 0.0, hover_thrust=0.5,
                                                  tilt_max=math.radians(80), thrust_max=1.0)
    assert thrust == pytest.approx(1.0)
    assert applied[2] == pytest.approx(-8.0)
    assert 0.0 < applied[0] < 10.0


def test_bad_mapping_parameters_are_refused():
    with pytest.raises(ValueError, match="hover_thrust"):
        acceleration_to_attitude([0, 0, 0], 0.0, hover_thrust=1.5)
    with pytest.raises(ValueError, match="tilt_max"):
        acceleration_to_attitude([0, 0, 0], 0.0, hover_thrust=0.5, tilt_max=2.0)
    with pytest.raises(ValueError, match="max_thrust"):
        acceleration_to_attitude([0, 0, 0], 0.0, mass=2.0, max_thrust=10.0)


def test_euler_quaternion_round_trip():
    rng = np.random.default_rng(5)
    for r, p, y in rng.uniform([-3, -1.5, -3], [3, 1.5, 3], (200, 3)):
        q = np.empty(4)
        rot.euler_to_quat(r, p, y, q)
        assert np.allclose(euler(q), [r, p, y], atol=1e-9)


# --- the position controller on a point mass -----------------------------------------------------


def fly_point_mass(ctrl, ref, T, h=0.01, disturbance=(0.0, 0.0, 0.0), true_hover=None,
                   ctrl_hover=0.5, start=(0.0, 0.0, 0.0), sub=10):
    """Point mass with the attitude reached instantly: p'' = thrust along -body z + g + d.

    The vehicle's real hover thrust may differ from the controller's figure (a 'b' mismatch).
    Integrated at h/sub (exact for the held acceleration).
    """
    true_tpa = (ctrl_hover if true_hover is None else true_hover) / GRAV
    d = np.asarray(disturbance, dtype=float)
    p = np.array(start, dtype=float)
    v = np.zeros(3)
    n = int(round(T / h))
    err = np.empty((n, 3))
    for k in range(n):
        r = ref.sample(k * h)
        q, thrust = ctrl.update(p, v, r.pos, r.vel, r.acc, r.yaw)
        a = thrust_acceleration(q, thrust, true_tpa) + d
        dt = h / sub
        for _ in range(sub):
            p = p + dt * v + 0.5 * dt * dt * a
            v = v + dt * a
        err[k] = p - ref.sample((k + 1) * h).pos
    return err


class Still:
    def __init__(self, pos):
        self.pos = np.asarray(pos, dtype=float)

    def sample(self, t):
        from mavadrc.mission.trajectories import Reference
        return Reference(self.pos, np.zeros(3), np.zeros(3), 0.3, 0.0)


WIND = (0.6, -0.4, 0.3)


@pytest.mark.parametrize("kind, gains", [
    ("ladrc", dict(wc=2.0, wo=10.0)),
    ("adrc", dict(r0=5.0, r=20.0, c=0.5, h1=0.1, beta=(30.0, 300.0, 1000.0), delta=0.05)),
])
def test_adrc_position_hold_rejects_a_constant_disturbance_and_a_thrust_mismatch(kind, gains):
    ctrl = PositionController(kind, h=0.01, hover_thrust=0.5, **gains)
    err = fly_point_mass(ctrl, Still([1.0, -1.0, -2.0]), 20.0, disturbance=WIND, true_hover=0.4)
    assert np.abs(err[-200:]).max() < 1e-3


def test_ladrc_disturbance_estimate_matches_the_true_disturbance():
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=2.0, wo=10.0)
    fly_point_mass(ctrl, Still([0.0, 0.0, -1.0]), 20.0, disturbance=WIND)
    assert np.allclose(ctrl.disturbance, WIND, atol=1e-3)


def test_pd_position_hold_keeps_the_offset_d_over_kp():
    ctrl = PositionController("pd", h=0.01, hover_thrust=0.5, kp=4.0, kd=4.0)
    err = fly_point_mass(ctrl, Still([0.0, 0.0, -1.0]), 20.0, disturbance=WIND)
    assert np.allclose(err[-1], np.array(WIND) / 4.0, atol=2e-3)


def test_ladrc_tracks_a_circle_in_wind_with_millimetre_error():
    ref = Circle(radius=3.0, speed=2.0, altitude=2.0)
    start = ref.sample(0.0).pos
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=3.0, wo=15.0)
    err = fly_point_mass(ctrl, ref, 20.0, disturbance=WIND, true_hover=0.45, start=start)
    assert np.linalg.norm(err[-1000:], axis=1).max() < 5e-3


def test_tilt_saturated_step_settles_because_observers_see_the_limited_command():
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=3.0, wo=15.0,
                              tilt_max=math.radians(10))
    err = fly_point_mass(ctrl, Still([10.0, 0.0, -1.0]), 30.0, start=(0.0, 0.0, -1.0))
    assert np.abs(err[-300:]).max() < 1e-3


def test_tilt_saturated_step_with_observers_fed_the_unlimited_command_does_not_settle():
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=3.0, wo=15.0,
                              tilt_max=math.radians(10))
    unlimited = ctrl.update

    def wrong_feed(*args):
        out = unlimited(*args)
        ctrl._S[:, 3] = ctrl.accel_command  # overwrite the applied-input feed (kernels.S_U)
        return out

    ctrl.update = wrong_feed
    err = fly_point_mass(ctrl, Still([10.0, 0.0, -1.0]), 30.0, start=(0.0, 0.0, -1.0))
    assert np.abs(err[-300:]).max() > 0.1


def test_position_controller_refuses_non_finite_measurements():
    ctrl = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=2.0, wo=10.0)
    ctrl.update([0, 0, -1], None, [0, 0, -1])
    z = ctrl.z
    with pytest.raises(ValueError, match="pos"):
        ctrl.update([0, math.nan, -1], None, [0, 0, -1])
    assert np.array_equal(ctrl.z, z)


def test_position_controller_reports_internals():
    ctrl = PositionController("adrc", h=0.01, hover_thrust=0.5, r0=5.0, r=5.0)
    ctrl.update([0, 0, 0], None, [1, 0, -1])
    assert ctrl.td.shape == (3, 2) and ctrl.z.shape == (3, 3)
    assert ctrl.accel_command.shape == (3,) and ctrl.accel_applied.shape == (3,)


# --- the attitude controller on a rigid body -----------------------------------------------------


def fly_rigid_body(ctrl, ref_euler, T, inertia, h=0.001, tau_ext=(0.0, 0.0, 0.0), q0=None):
    """Rotational dynamics J w' = tau - w x Jw + tau_ext, RK-free small-step integration."""
    J = np.asarray(inertia)
    q = np.array([1.0, 0, 0, 0]) if q0 is None else np.asarray(q0, dtype=float)
    w = np.zeros(3)
    e = np.empty(3)
    n = int(round(T / h))
    hist = np.empty((n, 3))
    for k in range(n):
        rot.quat_to_euler(q, e)
        tau = ctrl.update(e, w, ref_euler)
        sub = 10
        dt = h / sub
        for _ in range(sub):
            wdot = (tau + np.asarray(tau_ext) - np.cross(w, J * w)) / J
            w = w + dt * wdot
            qw = np.array([0.0, *w])
            q = q + dt * 0.5 * np.array([
                q[0] * qw[0] - q[1] * qw[1] - q[2] * qw[2] - q[3] * qw[3],
                q[0] * qw[1] + q[1] * qw[0] + q[2] * qw[3] - q[3] * qw[2],
                q[0] * qw[2] - q[1] * qw[3] + q[2] * qw[0] + q[3] * qw[1],
                q[0] * qw[3] + q[1] * qw[2] - q[2] * qw[1] + q[3] * qw[0]])
            q /= np.linalg.norm(q)
        rot.quat_to_euler(q, e)
        hist[k] = e
    return hist


CF = (1.43e-5, 1.43e-5, 2.89e-5)


def test_ladrc_attitude_rejects_a_constant_torque_with_zero_steady_error():
    ctrl = AttitudeController("ladrc", h=0.001, inertia=CF, wc=(25, 25, 10), wo=(120, 120, 50))
    ref = (math.radians(10), math.radians(-5), 0.5)
    hist = fly_rigid_body(ctrl, ref, 3.0, CF, tau_ext=(2e-5, -1e-5, 5e-6))
    assert np.abs(hist[-500:] - ref).max() < 1e-5
    within = np.abs(hist[:, 0] - ref[0]) < 0.1 * ref[0]
    first = np.argmax(within)
    assert within[first:].all() and first * 0.001 < 0.3


@pytest.mark.slow
def test_pd_attitude_leaves_the_torque_offset():
    kp, kd = 625.0, 50.0
    ctrl = AttitudeController("pd", h=0.001, inertia=CF, kp=kp, kd=kd)
    tau = 2e-5
    hist = fly_rigid_body(ctrl, (0.0, 0.0, 0.0), 3.0, CF, tau_ext=(tau, 0.0, 0.0))
    # torque = I*(kp*e + kd*edot) with b0 = 1/I: equilibrium at phi = tau/(I*kp)
    assert hist[-1, 0] == pytest.approx(tau / (CF[0] * kp), rel=1e-3)


def test_yaw_crossing_pi_takes_the_short_way():
    ctrl = AttitudeController("ladrc", h=0.001, inertia=CF, wc=(25, 25, 10), wo=(120, 120, 50))
    q0 = np.empty(4)
    rot.euler_to_quat(0.0, 0.0, math.radians(170), q0)
    hist = fly_rigid_body(ctrl, (0.0, 0.0, math.radians(-170)), 2.0, CF, q0=q0)
    unwrapped = np.unwrap(hist[:, 2])
    assert unwrapped.max() < math.radians(192)  # went through 180, not back through 0
    assert abs(rot.wrap_pi(hist[-1, 2] - math.radians(-170))) < 1e-4
