"""Motor thrust curves against the autopilot's linearisation, and a random initial heading.

The autopilot turns each rotor's share of the normalized thrust into a motor output u by
inverting the curve it assumes, rotor thrust fraction = f u^2 + (1 - f) u: PX4's THR_MDL_FAC
(src/lib/mixer_module/motor_params.c, default 0: thrust linear in the output) and ArduPilot's
MOT_THST_EXPO (AP_MotorsMulticopter, default 0.65 for ArduCopter).  The motors answer with the
vehicle file's ``motor_thrust_curve`` k.  f = k: thrust linear in the command; f != k: thrust
fraction = k u^2 + (1 - k) u with u the inverse of f's curve at the command; no key: the motors
have the autopilot's curve, as every bundled vehicle (bit for bit as before).  The hover
parameter the autopilot reports (MPC_THR_HOVER, PX4 default 0.5; MOT_THST_HOVER, ArduCopter
default 0.35) is the command that hovers under that map.
"""

import argparse
import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from mavadrc.study.experiment import experiment_from_text  # noqa: E402
from mavadrc.fast.inprocess import L_POS, L_YAW  # noqa: E402
from mavadrc.mission.config import load_mission  # noqa: E402
from sim import cli  # noqa: E402
from sim import physics as phys  # noqa: E402
from sim.firmware.mixer import thrust_curve, thrust_curve_inverse  # noqa: E402
from sim.params import load_vehicle  # noqa: E402
from sim.vehicle import SimVehicle, child_seeds, initial_heading  # noqa: E402
from sim.yamlio import ConfigError  # noqa: E402
from sitl_helpers import Client, Lockstep, both_paths, start_vehicle  # noqa: E402

X500 = load_vehicle("x500")
GUIDED_NOGPS = 20


def curved(k, base=X500):
    return dataclasses.replace(base, motor_thrust_curve=k)


def vehicle_file(tmp_path, k, name="x500_curve"):
    """configs/vehicles/x500.yaml with the motors' real curve k."""
    text = (Path(__file__).resolve().parent.parent / "configs" / "vehicles" / "x500.yaml") \
        .read_text()
    path = tmp_path / f"{name}.yaml"
    path.write_text(text.replace("name: x500", f"name: {name}")
                    + f"motor_thrust_curve: {k}\n")
    return path


def rotor_thrust(v, command, settle=0.3):
    """Collective rotor thrust (N) a level command asks of the motors (the rotor speeds they
    settle at), and the vertical acceleration (m/s^2, up) after ``settle`` s."""
    v.arm()
    v.set_attitude_target([1.0, 0.0, 0.0, 0.0], command)
    v.step(settle)
    omega = v.rotor_commands
    thrust = float(np.sum(v.params.k_f * omega ** 2))
    reached = v.state[phys.IX_ROT:phys.IX_ROT + 4]
    assert np.allclose(reached, omega, rtol=1e-4)  # the motors are there
    vz0 = v.state[5]
    v.step(0.01)
    vz = 0.5 * (vz0 + v.state[5])
    drag = v.params.drag_quadratic[2] * vz * abs(vz) + v.params.drag_linear[2] * vz  # N, up
    # the acceleration rotor thrust alone gives: measured, less the body drag's part
    return thrust, -(v.state[5] - vz0) / 0.01 - drag / v.params.mass


COMMANDS = (0.2, 0.4, 0.6, 0.8, 0.95)


# --- the curve itself ----------------------------------------------------------------------------

@pytest.mark.parametrize("k", [-1.0, -0.4, 0.0, 1e-9, 0.3, 0.65, 1.0])
def test_the_curve_and_its_inverse(k):
    u = np.linspace(0.0, 1.0, 101)
    f = np.array([thrust_curve(k, x) for x in u])
    assert f[0] == 0.0 and f[-1] == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.diff(f) >= 0.0)
    back = np.array([thrust_curve_inverse(k, x) for x in f])
    assert np.max(np.abs(back - u)) < 1e-12


# --- thrust against the command ------------------------------------------------------------------

@pytest.mark.parametrize("k", [0.3, 0.65])
def test_matched_curves_give_thrust_linear_in_the_command(k):
    """Motors with curve k, an autopilot that assumes k: thrust = command x maximum thrust."""
    vp = curved(k)
    for c in COMMANDS:
        v = SimVehicle(vp, position=(0.0, 0.0, -100.0), thrust_model_factor=k)
        thrust, _ = rotor_thrust(v, c)
        assert thrust == pytest.approx(c * vp.max_thrust, rel=1e-9)


@pytest.mark.parametrize("k, f", [(0.65, 0.0), (0.0, 0.65), (1.0, 0.3), (-0.3, 0.5)])
def test_a_mismatch_follows_the_predicted_nonlinear_map(k, f):
    """Motors with curve k, autopilot assuming f: rotor thrust fraction = curve_k(curve_f^-1(c)),
    measured as rotor thrust and as vertical acceleration at five commands."""
    vp = curved(k)
    measured = []
    for c in COMMANDS:
        v = SimVehicle(vp, position=(0.0, 0.0, -100.0), thrust_model_factor=f)
        thrust, acc = rotor_thrust(v, c)
        predicted = thrust_curve(k, thrust_curve_inverse(f, c)) * vp.max_thrust
        assert thrust == pytest.approx(predicted, rel=1e-9)
        # the vehicle feels it: (thrust - weight) / mass
        assert acc == pytest.approx((predicted - vp.weight) / vp.mass, abs=0.01)
        measured.append(thrust / vp.max_thrust)
    # and it is not linear: at least 3 % of maximum thrust off the line somewhere
    assert max(abs(m - c) for m, c in zip(measured, COMMANDS)) > 0.03


def test_without_a_curve_the_factor_changes_nothing():
    """A vehicle file without motor_thrust_curve has the autopilot's curve: any factor flies
    the same flight, bit for bit."""
    runs = []
    for f in (0.0, 0.65, -0.5):
        v = SimVehicle("x500", wind="moderate_gusts", seed=4, position=(0.0, 0.0, -10.0),
                       thrust_model_factor=f)
        v.arm()
        v.set_attitude_target([0.99, 0.05, 0.0, 0.0], 0.62)
        v.step(1.0)
        runs.append(v.state)
        assert v.hover_thrust == X500.weight / X500.max_thrust
    assert np.array_equal(runs[0], runs[1]) and np.array_equal(runs[0], runs[2])


def test_the_hover_thrust_hovers_and_the_position_loop_knows_it():
    """hover_thrust under a mismatch holds the vehicle; the linear figure would not; the
    vehicle's own position loop (takeoff, hold) uses the real one."""
    vp = curved(0.65)
    v = SimVehicle(vp, position=(0.0, 0.0, -20.0))
    assert v.hover_thrust == pytest.approx(0.7080, abs=1e-4)  # linear: 0.5736
    _, acc = rotor_thrust(v, v.hover_thrust, settle=0.5)
    assert abs(acc) < 1e-6
    _, acc = rotor_thrust(SimVehicle(vp, position=(0.0, 0.0, -20.0)), vp.hover_thrust_norm)
    assert acc < -1.0  # the linear hover thrust sinks it
    v = SimVehicle(vp)
    v.arm()
    v.takeoff(2.0)
    v.step(8.0)
    assert v.state[2] == pytest.approx(-2.0, abs=0.05) and abs(v.state[5]) < 0.05


def test_a_vehicle_file_gives_the_curve_and_refuses_one_out_of_range(tmp_path):
    assert load_vehicle(vehicle_file(tmp_path, 0.65)).motor_thrust_curve == 0.65
    assert X500.motor_thrust_curve is None
    with pytest.raises(ConfigError, match="motor_thrust_curve"):
        load_vehicle(vehicle_file(tmp_path, 1.5, "bad"))


# --- the autopilot's parameters ------------------------------------------------------------------

def _hover_flight(L, autopilot, value):
    """Armed in the air at ``value`` thrust for 1 s after the spin-up: the vertical speed change."""
    if autopilot == "px4":
        L.run(0.03, thrust=value)
        assert L.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == 0
    else:
        assert L.command(M.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS) == 0
    assert L.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196) == 0
    L.run(0.5, thrust=value)
    vz0 = L.step(thrust=value).vz
    return L.run(1.0, thrust=value).vz - vz0


AP_PARAMS = {"SIM_ARMING_DELAY": 0.0, "GUID_OPTIONS": 8}


@pytest.mark.parametrize("autopilot, hover_name, curve_name, k, expected", [
    # linear figure 0.5736; PX4 assumes 0 of motors at 0.65: each command gives less thrust
    ("px4", "MPC_THR_HOVER", "THR_MDL_FAC", 0.65, 0.7080),
    # ArduCopter assumes 0.65 of motors linear in their output: each command gives more
    ("ardupilot", "MOT_THST_HOVER", "MOT_THST_EXPO", 0.0, 0.4146),
])
def test_the_reported_hover_parameter_is_the_command_that_hovers(tmp_path, autopilot, hover_name,
                                                                 curve_name, k, expected):
    """Over MAVLink: the hover parameter is the real command at hover under the autopilot's
    default factor (THR_MDL_FAC 0 / MOT_THST_EXPO 0.65) and a vehicle whose motors differ;
    streamed level at that thrust the vehicle keeps its vertical speed."""
    params = AP_PARAMS if autopilot == "ardupilot" else None
    srv, port = start_vehicle(autopilot, vehicle=str(vehicle_file(tmp_path, k)), lockstep=True,
                              params=params, position=(0.0, 0.0, -30.0))
    c = Client(port)
    try:
        c.heartbeat()
        L = Lockstep(c)
        assert L.param(curve_name) == pytest.approx(0.0 if autopilot == "px4" else 0.65)
        value = L.param(hover_name)
        assert value == pytest.approx(expected, abs=1e-4)
        assert value == pytest.approx(srv.vehicle.hover_thrust, rel=1e-6)
        assert abs(_hover_flight(L, autopilot, value)) < 0.15
    finally:
        c.close()
        srv.stop()


@pytest.mark.parametrize("autopilot, hover_name, curve_name", [
    ("px4", "MPC_THR_HOVER", "THR_MDL_FAC"), ("ardupilot", "MOT_THST_HOVER", "MOT_THST_EXPO")])
def test_param_set_of_the_thrust_model_moves_the_hover_point(tmp_path, autopilot, hover_name,
                                                             curve_name):
    """PARAM_SET of THR_MDL_FAC / MOT_THST_EXPO to the motors' real curve makes thrust linear
    again: the hover parameter becomes weight / maximum thrust, and that hovers; a value the
    autopilot would not apply as given is taken as it applies it (PX4: outside (0, 1] is
    linear; ArduPilot: clamped to [-1, 1])."""
    params = AP_PARAMS if autopilot == "ardupilot" else None
    srv, port = start_vehicle(autopilot, vehicle=str(vehicle_file(tmp_path, 0.3)), lockstep=True,
                              params=params, position=(0.0, 0.0, -30.0))
    c = Client(port)
    try:
        c.heartbeat()
        L = Lockstep(c)
        before = L.param(hover_name)
        assert L.param(curve_name, 0.3) == pytest.approx(0.3)
        linear = X500.weight / X500.max_thrust
        after = L.param(hover_name)
        assert after == pytest.approx(linear, rel=1e-6) and abs(after - before) > 0.01
        assert srv.vehicle.thrust_model_factor == pytest.approx(0.3, rel=1e-7)
        L.param(curve_name, 1.5)
        assert srv.vehicle.thrust_model_factor == (0.0 if autopilot == "px4" else 1.0)
        assert L.param(hover_name) == pytest.approx(srv.vehicle.hover_thrust, rel=1e-6)
        L.param(curve_name, 0.3)
        assert abs(_hover_flight(L, autopilot, L.param(hover_name))) < 0.15
    finally:
        c.close()
        srv.stop()


def test_the_thrust_model_from_the_command_line(tmp_path):
    """--param THR_MDL_FAC=... is applied before the hover parameter is filled in; a hover
    value given with --param is kept."""
    path = str(vehicle_file(tmp_path, 0.65))
    srv, _ = start_vehicle("px4", vehicle=path, params={"THR_MDL_FAC": 0.65})
    try:
        assert srv.vehicle.hover_thrust == pytest.approx(X500.weight / X500.max_thrust, rel=1e-12)
        assert srv.parameters.values["MPC_THR_HOVER"][0] == srv.vehicle.hover_thrust
    finally:
        srv.stop()
    srv, _ = start_vehicle("px4", vehicle=path, params={"MPC_THR_HOVER": 0.45})
    try:
        assert srv.parameters.values["MPC_THR_HOVER"][0] == 0.45
    finally:
        srv.stop()


# --- random initial heading ----------------------------------------------------------------------

def test_a_random_heading_is_deterministic_per_seed_and_differs_across_seeds():
    headings = [initial_heading(math.nan, s) for s in range(8)]
    assert headings == [initial_heading(math.nan, s) for s in range(8)]
    assert len(set(headings)) == 8
    assert all(-math.pi <= h < math.pi for h in headings)
    assert initial_heading(0.3, 5) == 0.3
    for s in (0, 7):
        v = SimVehicle("crazyflie", seed=s, yaw=math.nan)
        assert v.initial_yaw == headings[s]
        q = v.state[phys.IX_Q:phys.IX_Q + 4]
        assert 2.0 * math.atan2(q[3], q[0]) == pytest.approx(headings[s], abs=1e-12)


def test_a_random_heading_leaves_the_wind_and_sensor_draws_alone():
    """The heading's stream is the seed's third child: the wind's and the sensors' are the
    first two, the same as before; a vehicle with a drawn heading flies as one given it."""
    assert child_seeds(11, 3)[:2] == child_seeds(11)
    yaw = initial_heading(math.nan, 11)
    runs = []
    for given in (math.nan, yaw):
        v = SimVehicle("crazyflie", wind="moderate_gusts", seed=11, yaw=given,
                       sensors={"noise": cli.NOISE}, position=(0.0, 0.0, -5.0))
        v.arm()
        v.set_attitude_target(v.state[phys.IX_Q:phys.IX_Q + 4], v.hover_thrust)
        v.step(0.5)
        runs.append((v.state, v.wind_velocity, v.reported().position))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def _mission(tmp_path, heading):
    path = tmp_path / "m.yaml"
    path.write_text(MISSION.format(heading=heading))
    return load_mission(path)


def _cli(*argv):
    p = argparse.ArgumentParser()
    cli.add_arguments(p)
    return p.parse_args(list(argv))


def test_random_heading_in_missions_and_on_the_command_line(tmp_path):
    assert math.isnan(_mission(tmp_path, "random").heading_deg)
    assert _mission(tmp_path, 30).heading_deg == 30.0
    with pytest.raises(ConfigError, match="heading_deg"):
        _mission(tmp_path, "north")
    assert math.isnan(_cli("--heading", "random").heading)
    assert _cli("--heading", "-45").heading == -45.0
    with pytest.raises(SystemExit):
        _cli("--heading", "nan")


MISSION = """
name: heading
vehicle: crazyflie
trajectory:
  - takeoff: {{altitude: 1.0, speed: 0.5}}
  - land: {{speed: 0.5}}
sim: {{heading_deg: {heading}}}
"""

EXPERIMENT = """
name: curve and heading
seeds: 1
defaults:
  vehicle: {vehicle}
  settle_s: 1
controllers:
  - {{name: LADRC, type: ladrc, wc: [2.0, 2.0, 2.5], wo: [10.0, 10.0, 12.5]}}
scenarios:
  - name: hover
    trajectory:
      - takeoff: {{altitude: 1.0, speed: 0.5}}
      - hover: {{duration: 2}}
    wind: {{components: [{{type: constant, speed: 2.0, direction_from_deg: 270}}]}}
    sim: {{heading_deg: random, autopilot: {autopilot}}}
"""


def test_the_fast_path_and_the_wire_fly_a_curved_vehicle_from_the_same_random_heading(tmp_path):
    """An x500 whose motors' curve (0.65) is not PX4's THR_MDL_FAC (0), from a heading drawn
    from seed 3: the in-process run and the lockstep MAVLink flight are the same flight."""
    exp = experiment_from_text("curve.yaml", EXPERIMENT.format(
        vehicle=vehicle_file(tmp_path, 0.65), autopilot="px4"))
    assert exp.scenarios[0].random
    seed = 3
    rec_fast, log, rec_wire, tab, pos = both_paths(exp, 0, 0, seed, tmp_path)
    rms = float(np.sqrt(np.mean(np.sum((pos - log[:, L_POS:L_POS + 3]) ** 2, axis=1))))
    assert rms < 1e-3, rms
    assert np.max(np.abs(tab["yaw"] - log[:, L_YAW])) < 1e-6
    # both started at the seed's heading (the first sample, on the ground)
    assert log[0, L_YAW] == pytest.approx(initial_heading(math.nan, seed), abs=1e-6)
    assert rec_fast["rms_error_m"] < 0.2  # it flew: the controller had the real hover thrust


def test_a_fleet_vehicle_with_its_own_thrust_model_steps_on_it():
    """mavadrc sitl --count: a PARAM_SET of THR_MDL_FAC reaches one vehicle of the fleet; the
    fleet's batch step (which shares the first vehicle's firmware parameters) leaves that one
    to step alone, so each flies as a lone vehicle with its factor, bit for bit."""
    from sim.fleet import VehicleRows

    vp = curved(0.65)

    def make():
        return [SimVehicle(vp, seed=k, position=(0.0, 0.0, -10.0)) for k in range(3)]

    alone, rows_of = make(), make()
    rows = VehicleRows(rows_of)
    for group in (alone, rows_of):
        group[1].set_thrust_model_factor(0.65)
        for v in group:
            v.arm()
            v.set_attitude_target([1.0, 0.0, 0.0, 0.0], 0.6)
    for _ in range(200):
        for v in alone:
            v.step(0.002)
        rows.step(0.002)
    for a, b in zip(alone, rows_of):
        assert np.array_equal(a.state, b.state)
    assert rows.batched > 0
    assert rows_of[1].state[5] < rows_of[0].state[5] - 0.5  # 0.6 climbs with the right model


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_the_fast_path_linearises_with_the_missions_autopilot(tmp_path, autopilot):
    """The in-process path gives its vehicle the thrust curve the mission's autopilot assumes
    by default (THR_MDL_FAC 0, MOT_THST_EXPO 0.65), as the server does, so the hover command
    the mission gives the controller (0.574 and 0.415 for an x500 on linear motors) really
    hovers: PD, which has no integrator to hide a wrong one, holds its altitude."""
    from mavadrc.fast.inprocess import L_POS, L_REF
    from mavadrc.fast.fly import fly_inprocess

    exp = experiment_from_text("curve.yaml", EXPERIMENT.format(
        vehicle=vehicle_file(tmp_path, 0.0), autopilot=autopilot))
    m = exp.mission(0, 0)
    m.wind = None
    run = fly_inprocess(m, kind="pd")
    tail = run.log[-50:]
    assert np.max(np.abs(tail[:, L_POS + 2] - tail[:, L_REF + 2])) < 0.01
