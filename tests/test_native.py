"""``controller: native``: the autopilot's own position controller flies the mission's reference,
sent as SET_POSITION_TARGET_LOCAL_NED, with the same takeoff, landing, supervisor and records
as every other controller; on the fast path too; a column of every compare report."""

import io
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from mavadrc.control.native import NativeController
from mavadrc.fast import inprocess as I
from mavadrc.fast.fly import fly_inprocess
from mavadrc.flight.fly import fly
from mavadrc.flight.record import read_table
from mavadrc.flight.setpoints import Setpoints
from mavadrc.mavlink.sequence import (
    AP_GUIDED,
    ArduPilotNativeSequence,
    ArduPilotSequence,
    PX4Sequence,
    sequence_for,
)
from mavadrc.mission.config import load_mission
from mavadrc.mission.takeoff import GROUND_TARGET_BELOW_M
from sim.firmware.position import Navigator
from sitl_helpers import start_vehicle, tlog_messages

MISSIONS = Path(__file__).resolve().parent.parent / "configs" / "missions"
M = mavutil.mavlink


def fly_native(name, tmp_path, **kw):
    kw.setdefault("lockstep", True)
    return fly(load_mission(MISSIONS / f"{name}.yaml"), kind="native", out=tmp_path,
               progress=False, stream=kw.pop("stream", io.StringIO()), **kw)


# --- the parts ------------------------------------------------------------------------------------


def test_the_stand_in_forwards_the_reference_and_estimates_nothing():
    c = NativeController(hover_thrust=0.4)
    q, thrust = c.update(np.zeros(3), np.zeros(3), [1.0, 2.0, -3.0], [0.5, 0.0, 0.0],
                         [0.0, 0.1, 0.0], 0.3)
    pos, vel, acc, yaw = c.target
    assert pos.tolist() == [1.0, 2.0, -3.0] and vel.tolist() == [0.5, 0.0, 0.0]
    assert acc.tolist() == [0.0, 0.1, 0.0] and yaw == 0.3
    assert math.isnan(thrust) and np.isnan(q).all()
    assert np.isnan(c.disturbance).all() and not c.models_drag and not c.learns_thrust
    assert math.isnan(c.sample_age(0.02))  # no lead: the autopilot flies on its own estimate


class _Link:
    def __init__(self):
        self.targets, self.attitudes = [], []

    def position_target(self, t_ms, pos, vel, acc, yaw):
        self.targets.append((t_ms, np.array(pos), np.array(vel), np.array(acc), yaw))

    def attitude_target(self, t_ms, q, thrust):
        self.attitudes.append((t_ms, q, thrust))


class _Vehicle:
    def __init__(self, pos):
        self.last = type("S", (), {"pos": np.array(pos)})()


def test_native_setpoints_turn_every_attitude_into_a_position_target():
    link = _Link()
    sp = Setpoints(link, _Vehicle([1.0, 2.0, -0.1]), native=True)
    sp.idle(1.0, 0.5)  # on the ground: held down, not a takeoff
    sp.send(1.01, np.array([math.cos(0.25), 0.0, 0.0, math.sin(0.25)]), 0.45)  # held where it is
    assert not link.attitudes and sp.sent == 2
    (_, p0, v0, a0, y0), (_, p1, _, _, y1) = link.targets
    assert p0.tolist() == pytest.approx([1.0, 2.0, -0.1 + GROUND_TARGET_BELOW_M])
    assert v0.tolist() == [0.0, 0.0, 0.0] and a0.tolist() == [0.0, 0.0, 0.0]
    assert y0 == pytest.approx(0.5) and y1 == pytest.approx(0.5)
    assert p1.tolist() == pytest.approx([1.0, 2.0, -0.1])
    plain = Setpoints(_Link())
    plain.idle(1.0, 0.0)
    assert plain.link.attitudes and not plain.link.targets


def test_arducopter_is_flown_native_in_guided_and_takes_off_by_command():
    seq = sequence_for("ardupilot", "native")
    assert isinstance(seq, ArduPilotNativeSequence) and seq.control_mode == "GUIDED"
    assert seq.takeoff_command and not ArduPilotSequence.takeoff_command
    assert isinstance(sequence_for("ardupilot", "ladrc"), ArduPilotSequence)
    assert not isinstance(sequence_for("ardupilot", "ladrc"), ArduPilotNativeSequence)
    assert isinstance(sequence_for("px4", "native"), PX4Sequence)

    class L:
        def command(self, *args):
            return args

    assert seq.request_control(L()) == (M.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED)


def test_the_bundled_position_loop_idles_on_the_ground_until_a_target_is_above():
    """PX4's takeoff rule in OFFBOARD: on the ground, a target under the vehicle keeps the
    motors at idle (the loop at rest); one above it takes it off."""
    nav = Navigator(h=0.01, hover_thrust=0.5)
    ground = np.array([0.0, 0.0, 0.0])
    nav.set_target(pos=[0.0, 0.0, 0.5], vel=[0.0, 0.0, 0.0], acc=[0.0, 0.0, 0.0])
    for _ in range(100):
        _, thrust = nav.update(ground, np.zeros(3), landed=True)
    assert thrust == 0.0 and not nav.ps.any()
    nav.set_target(pos=[0.0, 0.0, -0.2], vel=[0.0, 0.0, 0.0], acc=[0.0, 0.0, 0.0])
    _, thrust = nav.update(ground, np.zeros(3), landed=True)
    assert thrust > 0.5  # climbing: above the hover thrust


# --- flights on the bundled vehicle --------------------------------------------------------------


def test_native_flies_the_hover_on_position_targets_alone(tmp_path):
    out = io.StringIO()
    summary, folder = fly_native("hover", tmp_path, stream=out)
    assert summary["landed"] and summary["aborted"] == [], summary["aborted"]
    assert summary["controller"] == "native" and summary["disarm"]["by"] == "command"
    assert summary["touchdown_speed_mps"] < 0.5
    assert summary["max_error_m"] < 0.03  # measured 0.011 m: PX4's default gains, no wind
    assert summary["delay_margin_s"] is None  # the autopilot's loop: not ours to know
    msgs = tlog_messages(folder, ["SET_POSITION_TARGET_LOCAL_NED", "SET_ATTITUDE_TARGET"])
    assert msgs and all(m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" for m in msgs)
    assert {m.type_mask for m in msgs} == {0x800} and {m.coordinate_frame for m in msgs} == {1}
    # the controller record has the reference and the estimate, no commanded attitude or thrust
    tab = read_table(folder / "controller.csv")
    assert np.isnan(tab["thrust"]).all() and np.isfinite(tab["pos_z"]).all()
    assert "delay margin" not in out.getvalue()


@pytest.mark.slow
def test_native_on_ardupilot_takes_off_by_command_then_flies_the_targets(tmp_path):
    out = io.StringIO()
    summary, folder = fly_native("ardupilot_hover", tmp_path, stream=out)
    assert summary["landed"] and summary["aborted"] == [], summary["aborted"]
    assert summary["max_error_m"] < 0.2  # measured 0.143 m (the takeoff outruns the reference)
    assert "takeoff to 1.5 m asked" in out.getvalue()
    commands = tlog_messages(folder, ["COMMAND_LONG"])
    cmds = [m for m in commands if m.command == M.MAV_CMD_NAV_TAKEOFF]
    assert cmds and cmds[0].param7 == pytest.approx(1.5)
    modes = [m.param2 for m in commands if m.command == M.MAV_CMD_DO_SET_MODE]
    assert modes[0] == AP_GUIDED  # not GUIDED_NOGPS: GUIDED takes position targets
    assert not tlog_messages(folder, ["SET_ATTITUDE_TARGET"])


SHORT_AP = """name: short ardupilot hover
vehicle: crazyflie
controller: {type: native, rate_hz: 100}
trajectory:
  - takeoff: {altitude: 1.0, speed: 0.5}
  - hover: {duration: 2}
  - land: {speed: 0.5}
sim: {autopilot: ardupilot}
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
"""


@pytest.mark.slow
@pytest.mark.realtime
def test_in_real_time_arducopter_gets_no_target_before_it_has_left_the_ground(tmp_path):
    """GUIDED flies no target on the ground and a target there replaces its takeoff: the
    targets start only once the vehicle is off the ground on its takeoff command (the bundled
    ArduPilot flies none on the ground either: without the command it would stay there)."""
    path = tmp_path / "short.yaml"
    path.write_text(SHORT_AP)
    srv, port = start_vehicle("ardupilot", params={"SIM_ARMING_DELAY": 0.0})
    try:
        summary, folder = fly(load_mission(path), out=tmp_path,
                              connect=f"udpout:127.0.0.1:{srv.local_ports['offboard']}",
                              progress=False, stream=io.StringIO(), timeout=60.0)
    finally:
        srv.stop()
    assert summary["landed"] and summary["aborted"] == [], summary["aborted"]
    assert summary["controller"] == "native" and summary["max_error_m"] < 0.25
    msgs = tlog_messages(folder, ["COMMAND_LONG", "SET_POSITION_TARGET_LOCAL_NED",
                                  "LOCAL_POSITION_NED"])
    k = next(i for i, m in enumerate(msgs) if m.get_type() == "COMMAND_LONG"
             and m.command == M.MAV_CMD_NAV_TAKEOFF)
    first = next(i for i, m in enumerate(msgs) if i > k
                 and m.get_type() == "SET_POSITION_TARGET_LOCAL_NED")
    between = [m for m in msgs[k:first] if m.get_type() == "LOCAL_POSITION_NED"]
    ground = next(m.z for m in reversed(msgs[:k]) if m.get_type() == "LOCAL_POSITION_NED")
    # off the ground (mission.takeoff.lifted_off: 5 cm up, or climbing 0.2 m/s) before the
    # first target, and the targets from there on, within a few samples of the lift-off
    lifted = [i for i, m in enumerate(between) if ground - m.z >= 0.05 or m.vz < -0.2]
    assert lifted and len(between) - lifted[0] <= 3


@pytest.mark.slow
def test_the_fast_path_flies_native_as_the_mavlink_flight_does(tmp_path):
    """x500_gusts (turbulence, a figure eight): the in-process run and the lockstep MAVLink
    flight of the bundled vehicle's own position loop agree (0.2123 / 0.2099 m RMS measured
    over the mission)."""
    m = load_mission(MISSIONS / "x500_gusts.yaml")
    run = fly_inprocess(m, "native")
    summary, _ = fly(m, kind="native", out=tmp_path, lockstep=True, progress=False,
                     stream=io.StringIO(), start_at=I.MISSION_START)
    assert run.status == I.STATUS_OK and summary["landed"]
    L = run.log
    scored = L[:, I.L_T] <= run.duration
    e = np.linalg.norm(L[scored, I.L_POS:I.L_POS + 3] - L[scored, I.L_REF:I.L_REF + 3], axis=1)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms == pytest.approx(summary["rms_error_m"], rel=0.05)
    assert float(e.max()) == pytest.approx(summary["max_error_m"], rel=0.1)
    assert 0.1 < rms < 0.4  # the autopilot's loop in gusts: PX4's default gains

def test_a_compare_report_has_the_native_column(tmp_path):
    """An experiment with the autopilot's own controller beside the companion's: it runs on
    the fast path, its record has no delay margin, and the report's tables have its column."""
    from mavadrc.study.compare import compare

    path = tmp_path / "tiny_native.yaml"
    path.write_text((Path(__file__).parent / "data" / "tiny_experiment.yaml").read_text().replace(
        "  - {name: oracle, type: oracle, wc: [2.5, 2.5, 3.0]}\n",
        "  - {name: native, type: native}\n"))
    folder, exp, records = compare(path, out=tmp_path / "out", seeds=1, workers=1,
                                   progress=False, figures=False, stream=io.StringIO())
    native = {r["scenario"]: r for r in records if r["controller"] == "native"}
    assert all(r["delay_margin_s"] is None for r in native.values())
    hover = native["gusty hover"]
    assert hover["feasible"]
    # the thesis's wind asks more than the Crazyflie's thrust (every controller's runs are
    # infeasible there): reported, not hidden
    stuck = native["thesis wind hover"]
    assert not stuck["feasible"] and stuck["infeasible_reason"]
    pd = next(r for r in records if r["controller"] == "PD" and r["scenario"] == "gusty hover")
    # PX4's default gains against the PD at wc 2.5 in 3 m/s of wind and light turbulence
    assert hover["after_settle"]["rms_error_m"] > pd["after_settle"]["rms_error_m"]
    report = (Path(folder) / "report.md").read_text()
    rows = [line for line in report.splitlines() if line.startswith("| native |")]
    assert len(rows) == 2 and "| ok |" in rows[0] and "infeasible" in rows[1]


def test_a_native_record_draws_no_commands_of_its_own(tmp_path):
    """The attitude and thrust of a native flight are the autopilot's, never sent: no
    commands.png (it would be empty axes), and the disturbance figure says why it has no
    estimate."""
    from mavadrc.study.figures import plot_record

    summary, folder = fly_native("hover", tmp_path / "rec")
    paths = [Path(p).name for p in plot_record(folder, tmp_path / "fig")]
    assert "commands.png" not in paths
    assert {"path3d.png", "error.png", "disturbance.png"} <= set(paths)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.stem for p in MISSIONS.glob("*.yaml")))
def test_native_flies_every_shipped_mission_in_lockstep(name, tmp_path):
    """Every shipped mission, flown by the bundled vehicle's own position loop: landed and
    disarmed, nothing aborted, the error bounded (the loop trails a moving reference by about
    the attitude lag: 0.01-1 m measured, the thesis spiral's 5 m/s run-up the most)."""
    summary, _ = fly_native(name, tmp_path)
    assert summary["landed"] and summary["aborted"] == [], summary["aborted"]
    assert summary["controller"] == "native"
    assert summary["max_error_m"] < 2.0, summary["max_error_m"]


def test_tune_refuses_the_native_controller_with_the_reason():
    """Nothing of mavadrc's to search: its gains are the autopilot's parameters."""
    from mavadrc.study.tune import tune

    with pytest.raises(ValueError, match="no gains of mavadrc's to search"):
        tune(MISSIONS.parent / "experiments" / "thesis.yaml", "native", maxiter=1,
             stream=io.StringIO())
