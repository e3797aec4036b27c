"""Helpers for the MAVLink tests: an in-process vehicle on free loopback ports and a client."""

import math
import os
import time

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink loads a dialect: speak MAVLink 2

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from mavadrc.embedded import free_tcp_port, free_udp_port  # noqa: F401  (re-exported for tests)
from sim.server import SitlServer
from sim.vehicle import SimVehicle


def start_vehicle(autopilot="px4", vehicle="crazyflie", lockstep=False, signing_key=None,
                  wind=None, seed=0, instance=0, **vehicle_kw):
    """A SitlServer in a thread whose offboard link sends to a free port; returns (server, port)."""
    port = free_udp_port()
    v = SimVehicle(vehicle, wind=wind, seed=seed, **vehicle_kw)
    srv = SitlServer(v, autopilot, instance, lockstep=lockstep, signing_key=signing_key,
                     bind_offboard=0, bind_gcs=0, offboard_port=port, gcs_port=free_udp_port())
    srv.start()
    return srv, port


class Client:
    """A pymavlink ground-side connection to a test vehicle's offboard link."""

    def __init__(self, port, sysid=255, compid=190):
        self.c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=sysid,
                                            source_component=compid, dialect="ardupilotmega")
        self.mav = self.c.mav

    def heartbeat(self, timeout=10.0):
        hb = self.c.wait_heartbeat(timeout=timeout)
        assert hb is not None, "no heartbeat from the vehicle"
        return hb

    def recv(self, type, timeout=3.0, cond=None):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.c.recv_match(type=type, blocking=True, timeout=max(0.01, end - time.monotonic()))
            if m is not None and (cond is None or cond(m)):
                return m
        return None

    def command(self, cmd, *params, target_system=None, target_component=1, timeout=3.0):
        p = list(params) + [0.0] * (7 - len(params))
        ts = self.c.target_system if target_system is None else target_system
        self.mav.command_long_send(ts, target_component, cmd, 0, *p)
        ack = self.recv("COMMAND_ACK", timeout, cond=lambda m: m.command == cmd)
        assert ack is not None, f"no COMMAND_ACK for command {cmd}"
        return ack.result

    def set_mode_px4(self, main, sub=0):
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, 1, main, sub)

    def attitude(self, q=(1.0, 0.0, 0.0, 0.0), thrust=0.5, mask=7, target_system=None):
        ts = self.c.target_system if target_system is None else target_system
        self.mav.set_attitude_target_send(0, ts, 1, mask, list(q), 0.0, 0.0, 0.0, thrust)

    def position(self, x, y, z, yaw=0.0, mask=0b0000_1111_1111_1000):
        self.mav.set_position_target_local_ned_send(0, self.c.target_system, 1,
                                                    mavlink.MAV_FRAME_LOCAL_NED, mask, x, y, z,
                                                    0, 0, 0, 0, 0, 0, yaw, 0)

    def mode_of(self, hb):
        return hb.custom_mode

    def close(self):
        self.c.close()


def px4_mode(main, sub=0):
    return (main << 16) | (sub << 24)


def wait_until(pred, timeout, step=0.02):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


NAN = math.nan
