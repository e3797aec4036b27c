"""The simulated vehicle in closed loop: attitude steps, disturbance rejection, flight modes,
determinism and the batch form."""

import math

import numpy as np
import pytest

from mavadrc.control.rotations import quat_from_euler
from sim.batch import BatchVehicles
from sim.vehicle import CommandRejected, SimVehicle
from sim.wind import Wind

ROLL10 = quat_from_euler(math.radians(10.0), 0.0, 0.0)
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


class ConstantLoad(Wind):
    """A constant body torque (N m) and world force (N): a stand-in for an unmodelled load."""

    def __init__(self, torque=(0.0, 0.0, 0.0), force=(0.0, 0.0, 0.0)):
        self.torque = np.asarray(torque, dtype=float)
        self.force = np.asarray(force, dtype=float)

    def step(self, t, dt, position, velocity):
        return np.zeros(3), self.force.copy(), self.torque.copy()


def hovering(name, kind="px4", **kw):
    v = SimVehicle(name, attitude_controller=kind, position=(0.0, 0.0, -5.0), **kw)
    v.arm()
    v.set_attitude_target(LEVEL, v.hover_thrust)
    return v


@pytest.mark.parametrize("name", ["crazyflie", "x500"])
@pytest.mark.parametrize("kind", ["px4", "ladrc"])
def test_inner_loop_tracks_a_10_degree_roll_step_within_0_3_s(name, kind):
    v = hovering(name, kind)
    v.step(0.2)
    v.set_attitude_target(ROLL10, v.hover_thrust)
    roll = []
    for _ in range(600):
        v.step(0.001)
        roll.append(math.degrees(v.reported().euler[0]))
    roll = np.array(roll)
    # within 10% of the step from 0.3 s on, and never more than 20% over it
    assert np.all(np.abs(roll[299:] - 10.0) < 1.0), (roll[299], roll[-1])
    assert roll.max() < 12.0
    assert abs(math.degrees(v.reported().euler[1])) < 0.1


@pytest.mark.parametrize("kind", ["px4", "ladrc"])
def test_slower_inner_loop_rate_still_tracks(kind):
    v = hovering("x500", kind, attitude_rate_hz=250.0, position_rate_hz=50.0)
    v.step(0.2)
    v.set_attitude_target(ROLL10, v.hover_thrust)
    v.step(0.4)
    assert math.degrees(v.reported().euler[0]) == pytest.approx(10.0, abs=1.0)
    with pytest.raises(ValueError, match="attitude_rate_hz"):
        SimVehicle("x500", attitude_rate_hz=300.0)


@pytest.mark.parametrize("name,torque", [("crazyflie", (1.5e-3, -1.0e-3, 2.0e-4)),
                                         ("x500", (0.6, -0.4, 0.05))])
def test_adrc_attitude_rejects_a_constant_torque_with_zero_steady_error(name, torque):
    errors = {}
    for kind in ("ladrc", "adrc", "pd"):
        v = hovering(name, kind, wind=ConstantLoad(torque=torque))
        v.step(2.0)
        errors[kind] = np.abs(v.reported().euler)
    assert errors["ladrc"].max() < 1e-3, errors
    assert errors["adrc"].max() < 1e-3, errors
    # the PD baseline has no integral action: offset d / (b kp) on every loaded axis
    assert errors["pd"][0] > 20 * 1e-3 and errors["pd"][1] > 10 * 1e-3, errors


def test_px4_rate_integral_removes_a_torque_offset_that_p_only_leaves():
    load = (1.5e-3, 0.0, 0.0)
    v = hovering("crazyflie", "px4", wind=ConstantLoad(torque=load))
    p_only = hovering("crazyflie", "px4", wind=ConstantLoad(torque=load),
                      attitude_gains={"rate_i": 0.0})
    v.step(6.0)
    p_only.step(6.0)
    assert abs(v.reported().euler[0]) < 2e-4  # the integral converges slowly, like PX4's
    assert abs(p_only.reported().euler[0]) > 10 * abs(v.reported().euler[0])


@pytest.mark.parametrize("name,kind", [("crazyflie", "px4"), ("x500", "ladrc")])
def test_hover_at_hover_thrust_holds_altitude(name, kind):
    v = hovering(name, kind)
    v.step(5.0)
    assert abs(v.state[2] + 5.0) < 1e-3
    assert np.abs(v.state[3:6]).max() < 1e-3


def test_takeoff_hold_land_disarm():
    v = SimVehicle("x500")
    assert v.landed and not v.armed and v.mode == "idle"
    with pytest.raises(CommandRejected):
        v.takeoff(2.0)
    v.arm()
    v.takeoff(2.0)
    v.step(6.0)
    assert v.mode == "hold" and not v.landed
    assert abs(-v.reported().position[2] - 2.0) < 0.05
    assert np.abs(v.reported().position[:2]).max() < 0.05
    with pytest.raises(CommandRejected):
        v.disarm()
    v.land()
    assert v.mode == "land"
    v.step(1.5)
    assert v.reported().velocity[2] == pytest.approx(0.7, abs=0.1)  # land speed
    v.step(6.0)
    assert v.landed and v.mode == "idle"
    assert v.state[2] == 0.0
    v.step(2.5)
    assert not v.armed and np.all(v.rotor_commands == 0.0)


def test_position_setpoint_reached_without_steady_error():
    v = SimVehicle("crazyflie", position=(0.0, 0.0, -1.0))
    v.arm()
    target = np.array([1.0, -0.5, -2.0])
    v.set_position_target(pos=target, yaw=0.5)
    v.step(15.0)
    r = v.reported()
    assert v.mode == "position"
    assert np.abs(r.position - target).max() < 5e-3
    assert r.euler[2] == pytest.approx(0.5, abs=1e-3)
    # velocity only: the vehicle flies at that velocity
    v.set_position_target(vel=(0.5, 0.0, 0.0))
    v.step(5.0)
    np.testing.assert_allclose(v.reported().velocity, [0.5, 0.0, 0.0], atol=0.02)


def test_body_rate_setpoints_and_ignore_bits():
    v = hovering("x500")
    v.set_attitude_target(None, v.hover_thrust, body_rates=(0.0, 0.0, 0.5), type_mask=128)
    v.step(1.0)
    assert v.reported().rates[2] == pytest.approx(0.5, abs=0.02)
    v.set_attitude_target(LEVEL, 0.0, type_mask=64)  # thrust ignored: the last one stays
    assert v.attitude_setpoint[1] == pytest.approx(v.hover_thrust)
    with pytest.raises(ValueError):
        v.set_attitude_target([0.0, 0.0, 0.0, 0.0], 0.5)


def test_true_disturbance_is_the_external_acceleration():
    force = np.array([0.06, -0.03, 0.0])
    v = hovering("crazyflie", wind=ConstantLoad(force=force))
    v.step(0.001)
    np.testing.assert_allclose(v.true_disturbance(), force / v.params.mass, rtol=0.02, atol=1e-9)


def test_sensor_latency_delays_the_reports_not_the_firmware():
    noise = {"position": 0.005, "velocity": 0.01, "attitude": 0.001, "rates": 0.005}
    v = SimVehicle("x500", sensors={"noise": noise, "latency_s": 0.1})
    v.arm()
    v.takeoff(2.0)
    v.step(1.0)
    truth_before = v.state[2]
    v.step(0.1)
    assert v.reported().position[2] == pytest.approx(truth_before, abs=0.03)
    assert v.state[2] < truth_before - 0.05  # still climbing
    v.step(6.0)
    assert v.mode == "hold"
    assert np.abs(v.state[0:3] - [0.0, 0.0, -2.0]).max() < 0.05


def test_a_drifting_height_estimate_reads_high_and_the_vehicle_holds_on_it():
    """height_drift_mps: the reported height climbs that fast; the vehicle's own hold flies on
    its estimate, so the true vehicle sinks as the estimate rises (a barometer's drift)."""
    v = SimVehicle("x500", height_drift_mps=0.05)
    assert v.reported().position[2] == pytest.approx(0.0)
    v.arm()
    v.takeoff(2.0)
    v.step(8.0)
    assert v.mode == "hold"
    t = v.time
    rep, true = v.reported().position[2], v.state[2]
    assert rep - true == pytest.approx(-0.05 * t, abs=1e-9)
    v.step(4.0)  # holding its estimate at 2 m: the truth sinks 5 cm a second
    assert v.reported().position[2] == pytest.approx(rep, abs=0.03)
    assert v.state[2] - true == pytest.approx(0.2, abs=0.03)
    with pytest.raises(ValueError, match="height_drift_mps"):
        SimVehicle("x500", height_drift_mps=math.nan)


def test_an_estimate_climbing_on_the_ground_after_the_landing_reads_as_told():
    """ground_climb_mps: once the vehicle has flown and rests on the ground, the reported
    height climbs that fast for GROUND_CLIMB_HOLD_S, then ever slower (time constant
    GROUND_CLIMB_DECAY_S), as PX4 SIH's did; the truth stays on the ground, and nothing of it
    shows before the landing."""
    from sim.vehicle import GROUND_CLIMB_DECAY_S as TAU, GROUND_CLIMB_HOLD_S as HOLD
    v = SimVehicle("x500", ground_climb_mps=0.4, auto_disarm_s=None)
    v.step(1.0)  # on the ground, never flown: no climb
    assert v.reported().velocity[2] == pytest.approx(0.0, abs=1e-9)
    v.arm()
    v.takeoff(2.0)
    v.step(8.0)
    assert v.reported().position[2] == pytest.approx(v.state[2], abs=1e-9)  # in flight: truth
    v.land()
    while v.state[2] < -1e-3:
        v.step(0.01)
        v.reported()  # read every step, as the server does
    t0 = v.time
    v.step(HOLD / 2)
    r = v.reported()
    assert r.velocity[2] == pytest.approx(-0.4, abs=0.02)
    assert r.position[2] == pytest.approx(-0.4 * (v.time - t0), abs=0.03)
    v.step(HOLD / 2 + TAU)  # one time constant into the decay
    r = v.reported()
    assert r.velocity[2] == pytest.approx(-0.4 / math.e, abs=0.02)
    assert r.position[2] == pytest.approx(-0.4 * (HOLD + TAU * (1 - 1 / math.e)), abs=0.04)
    assert v.state[2] == pytest.approx(0.0, abs=1e-6)  # the truth sits on the ground
    assert v.state[5] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="ground_climb_mps"):
        SimVehicle("x500", ground_climb_mps=-0.1)


TURBULENT = {"components": [{"type": "constant", "speed": 3.0, "direction_from_deg": 45.0},
                            {"type": "dryden", "intensity": "light"}]}


def test_same_seed_same_flight_different_seed_differs():
    def fly(seed, chunks):
        v = SimVehicle("crazyflie", wind=TURBULENT, seed=seed, position=(0.0, 0.0, -2.0))
        v.arm()
        v.set_position_target(pos=(0.0, 0.0, -2.0))
        for dt in chunks:
            v.step(dt)
        return v.state

    a = fly(1, [1.0])
    assert np.array_equal(a, fly(1, [0.25, 0.5, 0.003, 0.247]))
    assert not np.allclose(a, fly(2, [1.0]), atol=1e-6)


def test_sensor_noise_flies_the_same_however_the_steps_are_cut():
    """With noise and no report latency the vehicle reads its sensors in the compiled loop,
    the noise drawn ahead up to each position-loop tick; with report latency it reads them in
    Python step by step.  Either way, and however the time is cut into steps, the firmware
    flies on the same draws: the same flight, to the bit (on attitude setpoints: the vehicle's
    own position loop flies on the delayed reports)."""
    from sim.cli import NOISE

    def fly(latency, chunks, seed=3):
        v = SimVehicle("crazyflie", wind=TURBULENT, seed=seed, position=(0.0, 0.0, -2.0),
                       sensors={"noise": NOISE, "latency_s": latency})
        v.arm()
        v.set_attitude_target([0.999, 0.02, -0.01, 0.0], v.hover_thrust)
        for dt in chunks:
            v.step(dt)
        return v.state, v.reported().position

    a, ra = fly(0.0, [1.0])
    for latency, chunks in ((0.0, [0.25, 0.5, 0.003, 0.247]), (0.02, [1.0]),
                            (0.0, [0.001] * 1000)):
        b, rb = fly(latency, chunks)
        assert np.array_equal(a, b)
        assert np.array_equal(ra, rb) == (latency == 0.0)
    assert not np.allclose(a, fly(0.0, [1.0], seed=4)[0], atol=1e-6)
    # the reading is noisy: the estimate is not the truth
    assert 1e-4 < np.abs(ra - a[0:3]).max() < 0.05


@pytest.mark.parametrize("kind,wind", [("px4", None), ("ladrc", TURBULENT)])
def test_batch_equals_single_vehicles(kind, wind):
    n = 3
    q = np.array([quat_from_euler(math.radians(4.0 * i), math.radians(-3.0 * i), 0.3 * i)
                  for i in range(n)])
    thrust = np.array([0.45, 0.5, 0.55])
    b = BatchVehicles(n, "crazyflie", wind=wind, seeds=[7, 8, 9], attitude_controller=kind,
                      positions=(0.0, 0.0, -3.0))
    b.arm()
    b.set_attitude_targets(q, thrust)
    b.step(0.5)
    for i in range(n):
        v = SimVehicle("crazyflie", wind=wind, seed=7 + i, attitude_controller=kind,
                       position=(0.0, 0.0, -3.0))
        v.arm()
        v.set_attitude_target(q[i], thrust[i])
        v.step(0.5)
        np.testing.assert_allclose(b.states[i], v.state, rtol=0, atol=1e-9)
