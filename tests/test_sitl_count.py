"""`mavadrc sitl --count N`: many vehicles served from one process (sim/fleet.py)."""

import argparse
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl_helpers import Client, free_udp_port, px4_mode, udp_sink
from sim import cli
from sim.fleet import FleetServer, VehicleRows
from sim.server import SitlServer
from sim.vehicle import SimVehicle

M = mavlink
OFFBOARD = px4_mode(6)


def free_port_run(n):
    """A port P with P..P+n-1 all free on loopback (UDP) right now."""
    for _ in range(50):
        base = free_udp_port()
        socks = []
        try:
            for k in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    pytest.skip(f"no run of {n} free UDP ports")


def fleet_args(count, offboard_base, *extra, gcs_port=None):
    """The command's options; the ground-station streams go to ``gcs_port`` (give a held one,
    :func:`udp_sink`, when the fleet is started)."""
    parser = cli.add_arguments(argparse.ArgumentParser())
    gcs_port = free_udp_port() if gcs_port is None else gcs_port
    return parser.parse_args(["--count", str(count), "--offboard-port", str(offboard_base),
                              "--gcs-port", str(gcs_port), "--bind-offboard", "0",
                              "--bind-gcs", "0", *extra])


@pytest.fixture
def fleet3():
    """A running `--count 3` fleet (made from the command's options) and a client on each
    vehicle's offboard port."""
    base = free_port_run(3)
    clients = [Client(base + k) for k in range(3)]
    sink = udp_sink()
    fleet = FleetServer(cli.make_servers(fleet_args(3, base, "--param", "COM_SPOOLUP_TIME=0",
                                                    gcs_port=sink.getsockname()[1])))
    fleet.start()
    yield fleet, clients
    for c in clients:
        c.close()
    fleet.stop()
    sink.close()


@pytest.mark.realtime
def test_count_3_answers_with_three_heartbeats_on_their_own_ports(fleet3):
    fleet, clients = fleet3
    got = []
    for c in clients:
        hb = c.heartbeat()
        assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
        got.append((hb.get_srcSystem(), hb.get_srcComponent()))
        # nothing from another vehicle reaches this port
        assert c.recv("ATTITUDE", cond=lambda m: m.get_srcSystem() != got[-1][0],
                      timeout=0.3) is None
    assert got == [(1, 1), (2, 1), (3, 1)]
    locals_ = [s.local_ports["offboard"] for s in fleet.servers]
    assert len(set(locals_)) == 3


@pytest.mark.realtime
def test_one_vehicle_flown_with_attitude_targets_climbs_while_the_others_stay_down(fleet3):
    fleet, clients = fleet3
    for c in clients:
        c.heartbeat()
    c = clients[1]
    for _ in range(5):
        c.attitude(thrust=0.0)
        time.sleep(0.02)
    assert c.set_mode_px4(6) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + 10.0
    lpn = None
    while time.monotonic() < end:
        c.attitude(thrust=0.8)
        m = c.recv("LOCAL_POSITION_NED", timeout=0.05)
        lpn = m or lpn
        if lpn is not None and lpn.z < -1.0:
            break
    assert lpn is not None and lpn.z < -1.0 and lpn.get_srcSystem() == 2
    hb = c.recv("HEARTBEAT", cond=lambda m: m.get_srcSystem() == 2)
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.custom_mode == OFFBOARD
    for other in (clients[0], clients[2]):
        m = other.recv("LOCAL_POSITION_NED")
        assert m is not None and abs(m.z) < 1e-6 and abs(m.vz) < 1e-6
        hb = other.recv("HEARTBEAT")
        assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert all(s.vehicle.state[2] == 0.0 for s in (fleet.servers[0], fleet.servers[2]))
    assert fleet.servers[1].vehicle.state[2] < -1.0


# --- the batched stepping is exactly the single vehicle's -------------------------------------

def _attitude(t, k):
    """A setpoint that changes with time and vehicle: climb with a slow wobble."""
    a = 0.05 * np.sin(7.0 * t + k)
    q = [np.cos(a / 2), np.sin(a / 2), 0.0, 0.0]
    return M.MAVLink_set_attitude_target_message(0, k + 1, 1, 7, q, 0.0, 0.0, 0.0,
                                                 0.62 + 0.1 * np.cos(3.0 * t))


def _command(k, cmd, *p):
    p = list(p) + [0.0] * (7 - len(p))
    return M.MAVLink_command_long_message(k + 1, 1, cmd, 0, *p)


def _drive(server, k, step):
    """Vehicle 0 flies attitude setpoints in OFFBOARD, vehicle 1 stays on the ground disarmed,
    vehicle 2 takes off (the autopilot's own position loop) and then flies attitude setpoints
    too: all three paths of the fleet, switching between them."""
    link = server.links[0]
    t = step * 0.002
    if k == 0:
        server.receiver.handle(link, _attitude(t, k))
        if step == 5:
            server.receiver.handle(link, _command(k, M.MAV_CMD_DO_SET_MODE, 1, 6))
            server.receiver.handle(link, _command(k, M.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    elif k == 2:
        if step == 5:
            server.receiver.handle(link, _command(k, M.MAV_CMD_COMPONENT_ARM_DISARM, 1))
            server.receiver.handle(link, _command(k, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0,
                                                  489.0))
        if step >= 400:
            server.receiver.handle(link, _attitude(t, k))
        if step == 405:
            server.receiver.handle(link, _command(k, M.MAV_CMD_DO_SET_MODE, 1, 6))


def _servers(n, sink):
    port = sink.getsockname()[1]
    return [SitlServer(SimVehicle("crazyflie", seed=k), "px4", k, bind_offboard=0, bind_gcs=0,
                       offboard_port=port, gcs_port=port, params={"COM_SPOOLUP_TIME": 0})
            for k in range(n)]


def test_the_fleet_steps_each_vehicle_exactly_as_a_server_of_its_own():
    sink = udp_sink()
    alone = _servers(3, sink)
    fleet = FleetServer(_servers(3, sink))
    try:
        modes = set()
        for step in range(800):
            for k in range(3):
                _drive(alone[k], k, step)
                _drive(fleet.servers[k], k, step)
            for s in alone:
                s.advance(0.002)
            fleet.advance(0.002)
            modes.update((k, s.vehicle.mode) for k, s in enumerate(fleet.servers))
        for a, b in zip(alone, fleet.servers):
            assert b.vehicle.tick == a.vehicle.tick == 1600
            assert np.array_equal(a.vehicle.state, b.vehicle.state)
            assert np.array_equal(a.vehicle.kernel.fs, b.vehicle.kernel.fs)
            assert np.array_equal(a.vehicle.kernel.S, b.vehicle.kernel.S)
            assert a.mode == b.mode and a.vehicle.armed == b.vehicle.armed
        # every path was taken: attitude flight and idle batched, the takeoff on its own
        assert {(0, "attitude"), (1, "idle"), (2, "takeoff"), (2, "attitude")} <= modes
        assert fleet.rows.batched >= 1600 * 2
        assert fleet.servers[0].vehicle.state[2] < -0.2  # vehicle 0 flew
        assert fleet.servers[2].vehicle.state[2] < -0.2  # so did vehicle 2
    finally:
        for s in alone + fleet.servers:
            s._close()
        sink.close()


def test_vehicle_rows_match_single_vehicles_in_every_mode():
    """VehicleRows.step against SimVehicle.step, vehicle by vehicle, bit for bit."""
    def make():
        return [SimVehicle("crazyflie", seed=k, position=(0.0, 0.0, -1.0 if k else 0.0))
                for k in range(4)]
    alone, rows_of = make(), make()
    rows = VehicleRows(rows_of)
    for k, (a, b) in enumerate(zip(alone, rows_of)):
        for v in (a, b):
            v.arm()
            if k == 3:
                v.set_position_target(pos=(0.3, 0.0, -1.2))
            else:
                v.set_attitude_target([1.0, 0.0, 0.02 * k, 0.0], 0.5 + 0.05 * k)
    for step in range(300):
        dt = 0.001 * (1 + step % 3)  # uneven steps, not aligned to the position loop
        for v in alone:
            v.step(dt)
        rows.step(dt)
    for a, b in zip(alone, rows_of):
        assert a.tick == b.tick
        assert np.array_equal(a.state, b.state)
    assert rows.batched > 0


def test_count_with_lockstep_is_one_line_error():
    p = subprocess.run([sys.executable, "-m", "sim", "--count", "2", "--lockstep"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode != 0
    assert "--count" in p.stderr and "real time" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr


def test_fleet_ports_move_by_instance():
    args = fleet_args(3, 15000, "--instance", "4")
    assert [cli.fleet_ports(args, k)["offboard_port"] for k in range(3)] == [15000, 15001, 15002]
    assert [cli.fleet_ports(args, k)["bind_offboard"] for k in range(3)] == [0, 0, 0]
    assert len({cli.fleet_ports(args, k)["gcs_port"] for k in range(3)}) == 1


def test_a_fleet_whose_offboard_ports_reach_the_ground_station_port_is_refused():
    """Instance 10 on the default ports would send its offboard link to 14540 + 10 = 14550, the
    ground-station port: refused at once with the options that fix it, before anything binds."""
    p = subprocess.run([sys.executable, "-m", "sim", "--count", "12", "--duration", "1"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode != 0 and "Traceback" not in p.stderr
    assert "instance 10" in p.stderr and "14550" in p.stderr and "--offboard-port" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
