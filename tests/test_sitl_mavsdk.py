"""Unmodified MAVSDK-Python (classic API, mavsdk<4, which ships mavsdk_server) flies the vehicle."""

import asyncio

import pytest

# mavsdk_server, started by MAVSDK, flies a vehicle in real time
pytestmark = [pytest.mark.clients, pytest.mark.realtime]

mavsdk = pytest.importorskip("mavsdk")

from mavsdk import System  # noqa: E402
from mavsdk.offboard import Attitude, PositionNedYaw  # noqa: E402
from mavsdk.telemetry import FlightMode, LandedState  # noqa: E402

from sitl_helpers import free_tcp_port, start_vehicle  # noqa: E402


async def first(stream, pred=lambda v: True, timeout=15.0):
    async def get():
        async for v in stream:
            if pred(v):
                return v
    return await asyncio.wait_for(get(), timeout)


async def mavsdk_flight(port, grpc_port):
    drone = System(port=grpc_port)
    await drone.connect(system_address=f"udpin://0.0.0.0:{port}")
    await first(drone.core.connection_state(), lambda s: s.is_connected)
    health = await first(drone.telemetry.health())
    assert health.is_armable and health.is_local_position_ok and health.is_global_position_ok
    assert await first(drone.telemetry.flight_mode()) == FlightMode.HOLD
    home = await first(drone.telemetry.home())
    assert home.latitude_deg == pytest.approx(47.397742, abs=1e-6)
    assert await first(drone.telemetry.landed_state()) == LandedState.ON_GROUND
    await drone.action.arm()
    assert await first(drone.telemetry.armed(), lambda a: a)
    await drone.action.set_takeoff_altitude(2.0)
    await drone.action.takeoff()
    await first(drone.telemetry.landed_state(), lambda s: s == LandedState.IN_AIR)
    pv = await first(drone.telemetry.position_velocity_ned(),
                     lambda p: p.position.down_m < -1.9)
    assert pv.position.down_m == pytest.approx(-2.0, abs=0.15)

    # offboard with position setpoints
    await drone.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -2.0, 0.0))
    await drone.offboard.start()
    assert await first(drone.telemetry.flight_mode(), lambda m: m == FlightMode.OFFBOARD)
    await drone.offboard.set_position_ned(PositionNedYaw(2.0, 1.0, -2.5, 30.0))
    pv = await first(drone.telemetry.position_velocity_ned(),
                     lambda p: abs(p.position.north_m - 2.0) < 0.05
                     and abs(p.position.east_m - 1.0) < 0.05, timeout=20.0)
    att = await first(drone.telemetry.attitude_euler())
    assert att.yaw_deg == pytest.approx(30.0, abs=3.0)

    # offboard with attitude setpoints: a 5 degree roll at hover thrust
    hover = await drone.param.get_param_float("MPC_THR_HOVER")
    await drone.offboard.set_attitude(Attitude(5.0, 0.0, 30.0, hover))
    att = await first(drone.telemetry.attitude_euler(), lambda a: abs(a.roll_deg - 5.0) < 0.5,
                      timeout=5.0)
    assert att.pitch_deg == pytest.approx(0.0, abs=1.0)
    await drone.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -2.0, 0.0))
    await asyncio.sleep(1.0)
    await drone.offboard.stop()
    assert await first(drone.telemetry.flight_mode(), lambda m: m != FlightMode.OFFBOARD) in (
        FlightMode.HOLD, FlightMode.POSCTL)

    await drone.action.land()
    await first(drone.telemetry.landed_state(), lambda s: s == LandedState.ON_GROUND,
                timeout=30.0)
    assert not await first(drone.telemetry.armed(), lambda a: not a, timeout=10.0)


def test_mavsdk_connects_flies_offboard_and_lands():
    srv, port = start_vehicle("px4")
    try:
        asyncio.run(asyncio.wait_for(mavsdk_flight(port, free_tcp_port()), 120))
        assert srv.stats.dropped() == 0
    finally:
        srv.stop()
