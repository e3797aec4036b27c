"""Helpers for the MAVLink tests: an in-process vehicle on free loopback ports and a client."""

import math
import os
import struct
import time

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink loads a dialect: speak MAVLink 2

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from mavadrc.flight.embedded import free_tcp_port, free_udp_port, udp_sink  # noqa: F401  (re-exported)
from sim.lossy import LossyLink
from sim.server import SitlServer
from sim.vehicle import SimVehicle


class _Server(SitlServer):
    """A SitlServer whose ground-station streams go to a port held for it (``sink``), released
    when it stops.  Sent to a port that was only free, another test running beside it could be
    handed that port for its client and read this vehicle's LOCAL_POSITION_NED as its own (a
    lockstep test then sees its vehicle's clock jump)."""

    def __init__(self, *args, sink, **kw):
        self.sink = sink
        super().__init__(*args, gcs_port=sink.getsockname()[1], **kw)

    def stop(self):
        try:
            super().stop()
        finally:
            self.sink.close()


def start_vehicle(autopilot="px4", vehicle="crazyflie", lockstep=False, signing_key=None,
                  wind=None, seed=0, instance=0, params=None, clock_rate=1.0, port=None,
                  **vehicle_kw):
    """A SitlServer in a thread whose offboard link sends to a free port; returns (server, port).
    ``params``: initial values of the autopilot's parameters ({NAME: value}); ``clock_rate``: its
    clock's rate against the wall clock in real time; ``port``: where its offboard link sends
    (default: a free port)."""
    port = free_udp_port() if port is None else port
    v = SimVehicle(vehicle, wind=wind, seed=seed, **vehicle_kw)
    srv = _Server(v, autopilot, instance, lockstep=lockstep, signing_key=signing_key,
                  bind_offboard=0, bind_gcs=0, offboard_port=port, sink=udp_sink(),
                  params=params, clock_rate=clock_rate)
    srv.start()
    return srv, port


def start_lossy_vehicle(*, link_seed=0, companion_port=None, **vehicle_kw):
    """A real-time bundled vehicle (:func:`start_vehicle` with ``**vehicle_kw``) behind a
    started :class:`sim.lossy.LossyLink`; returns (server, link).  The companion connects to
    ``link.companion_url``.  Stop both: ``link.stop(); server.stop()``."""
    srv, port = start_vehicle(**vehicle_kw)
    try:
        link = LossyLink(companion_port or free_udp_port(), vehicle_port=port, seed=link_seed)
    except Exception:
        srv.stop()
        raise
    return srv, link.start()


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


class Lockstep:
    """Drives a lockstep vehicle (``start_vehicle(lockstep=True)``: each setpoint advances it one
    ``dt_ms``).  ``step`` sends one setpoint and returns that step's LOCAL_POSITION_NED; every
    message received is kept in ``log`` as (vehicle time in ms, message), HEARTBEATs with the
    exact step they were sent in (they leave before the step's telemetry)."""

    def __init__(self, client, dt_ms=10):
        self.c = client
        self.dt_ms = dt_ms
        self.t_ms = 0
        self.log = []
        assert self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, dt_ms * 1000) == 0

    def _recv(self, end):
        m = self.c.c.recv_match(blocking=True, timeout=max(0.01, end - time.monotonic()))
        if m is not None:
            self.log.append((self.t_ms, m))
        return m

    def command(self, cmd, *params, timeout=3.0):
        """COMMAND_LONG; its result (the messages that come meanwhile are logged)."""
        p = list(params) + [0.0] * (7 - len(params))
        self.c.mav.command_long_send(self.c.c.target_system, 1, cmd, 0, *p)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self._recv(end)
            if m is not None and m.get_type() == "COMMAND_ACK" and m.command == cmd:
                return m.result
        raise AssertionError(f"no COMMAND_ACK for command {cmd}")

    def param(self, name, value=None, ptype=mavlink.MAV_PARAM_TYPE_REAL32, timeout=3.0):
        """Read (or set, then read back) a parameter; its value (INT32 of a PX4 vehicle decoded)."""
        if value is None:
            self.c.mav.param_request_read_send(self.c.c.target_system, 1, name.encode(), -1)
        else:
            raw = float(value)
            if ptype == mavlink.MAV_PARAM_TYPE_INT32 and self.bytewise:
                raw = struct.unpack("<f", struct.pack("<i", int(value)))[0]
            self.c.mav.param_set_send(self.c.c.target_system, 1, name.encode(), raw, ptype)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self._recv(end)
            if m is not None and m.get_type() == "PARAM_VALUE" and m.param_id == name:
                if m.param_type == mavlink.MAV_PARAM_TYPE_INT32 and self.bytewise:
                    return struct.unpack("<i", struct.pack("<f", m.param_value))[0]
                return m.param_value
        raise AssertionError(f"no PARAM_VALUE for {name}")

    @property
    def bytewise(self):
        return self.c.c.messages.get("HEARTBEAT") is not None and \
            self.c.c.messages["HEARTBEAT"].autopilot == mavlink.MAV_AUTOPILOT_PX4

    def step(self, q=(1.0, 0.0, 0.0, 0.0), thrust=0.0, mask=7, position=None):
        """One setpoint (attitude, or a position target if ``position`` is given), one step."""
        if position is not None:
            self.c.position(*position)
        else:
            self.c.attitude(q=q, thrust=thrust, mask=mask)
        self.t_ms += self.dt_ms
        end = time.monotonic() + 5.0
        while True:
            m = self._recv(end)
            assert m is not None, f"no telemetry for t = {self.t_ms} ms"
            if m.get_type() == "LOCAL_POSITION_NED" and m.time_boot_ms >= self.t_ms:
                assert m.time_boot_ms == self.t_ms
                return m

    def run(self, seconds, until=None, **setpoint):
        """Step for ``seconds`` (or until ``until(lpn)`` holds); the last LOCAL_POSITION_NED."""
        m = None
        for _ in range(int(round(seconds * 1000 / self.dt_ms))):
            m = self.step(**setpoint)
            if until is not None and until(m):
                break
        return m

    def messages(self, type, since_ms=-1):
        return [(t, m) for t, m in self.log if t > since_ms and m.get_type() == type]

    def texts(self, since_ms=-1):
        return [(t, m.text) for t, m in self.messages("STATUSTEXT", since_ms)]

    def landed_state(self):
        """The last EXTENDED_SYS_STATE.landed_state received (None before one)."""
        got = self.messages("EXTENDED_SYS_STATE")
        return got[-1][1].landed_state if got else None


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


def both_paths(exp, i, j, seed, tmp_path):
    """Run (scenario i, controller j, seed) of ``exp`` on the fast path and over MAVLink against
    the bundled vehicle in lockstep, checking that both flew the same steps at the same times;
    returns (fast record, its log, MAVLink record, its controller.csv table, its positions)."""
    from pathlib import Path

    import numpy as np

    from mavadrc.study.experiment import run_inprocess, run_mavlink
    from mavadrc.fast.inprocess import L_T
    from mavadrc.flight.record import read_table

    rec_fast, log = run_inprocess(exp, i, j, seed, keep_log=True)
    rec_wire, _ = run_mavlink(exp, i, j, seed, tmp_path)
    tab = read_table(Path(rec_wire["record_folder"]) / "controller.csv")
    pos = np.column_stack([tab["pos_x"], tab["pos_y"], tab["pos_z"]])
    assert len(pos) == len(log)
    assert np.allclose(tab["t"], log[:, L_T], atol=1e-9)
    return rec_fast, log, rec_wire, tab, pos


def wait_rows(folder_glob, n, timeout=60.0):
    """The folder of the first file ``folder_glob()`` yields that has more than ``n`` lines (a
    flight's controller.csv: the mission has started), within ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for p in folder_glob():
            try:
                if sum(1 for _ in open(p)) > n:
                    return p.parent
            except OSError:
                pass
        time.sleep(0.05)
    raise AssertionError("the mission did not start")


def tlog_messages(folder, types=None):
    """The messages of a flight record's ``flight.tlog``, in order (what the companion sent and
    what it heard); ``types``: only those MAVLink message names."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(folder / "flight.tlog"))
    out = []
    while True:
        m = log.recv_match(type=types, blocking=False)
        if m is None:
            return out
        out.append(m)
