"""The bundled vehicle behind a MAVLink 2 endpoint on UDP, laid out like PX4 SITL.

Two links, as PX4 SITL has them: the offboard/API link sends to 127.0.0.1:14540+N (MAVSDK and
the `mavadrc fly` companion listen there) and the ground-station link sends to 127.0.0.1:14550
(QGroundControl, MAVProxy).  Each link binds its own local port (14580+N and 18570+N, PX4's
numbers) and also answers whoever writes to it.  Every datagram is parsed on its own; anything
malformed, badly signed, unknown or aimed at another system is dropped and counted, never acted
on.

Clocks: in real time the physics advances on the wall clock in ticks of ``tick`` seconds.  In
lockstep the vehicle advances by one ``lockstep_dt`` for each setpoint that arrives, so a
closed loop runs as fast as both sides allow and gives the same flight for the same seed; if
setpoints stop for ``lockstep_timeout`` (10 s) of wall time while armed, the offboard-loss failsafe
engages and the clock falls back to real time so the vehicle can carry it out.

The autopilot around the vehicle is as unkind as the real ones (rules in :mod:`sim.personality`):
HEARTBEAT at 1 Hz of vehicle time (PX4 sends no extra one when the mode or the arming changes,
ArduPilot one at a mode change), motors held at idle for a while after arming, the autopilot's
own land detector behind EXTENDED_SYS_STATE, disarm refusals and automatic disarming, the
offboard-loss failsafe without RC, and TIMESYNC on the vehicle's clock.
"""

import logging
import math
import select
import socket
import struct
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavadrc.control.rotations import rotation_matrix

from . import personality as PP
from . import physics as phys
from . import wind as W
from .firmware import position as PL

log = logging.getLogger("mavadrc.sitl")

EARTH_RADIUS = 6378137.0
FORCE_ARM_MAGIC = 21196
UNSIGNED_ALLOWED = (mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS)

# ignore bits of SET_POSITION_TARGET_LOCAL_NED
PT_POS = 0x7
PT_VEL = 0x38
PT_ACC = 0x1C0
PT_YAW = 0x400
PT_YAW_RATE = 0x800
# ignore bits of SET_ATTITUDE_TARGET
AT_RATES = 0x7
AT_THROTTLE = 64
AT_ATTITUDE = 128

MSG = mavlink  # message ids as MSG.MAVLINK_MSG_ID_*

LPN = MSG.MAVLINK_MSG_ID_LOCAL_POSITION_NED  # the sample a companion's control step runs on

# PX4's default onboard-link rates (Hz) and a slower ground-station set
ONBOARD_RATES = {
    MSG.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    MSG.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    MSG.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    MSG.MAVLINK_MSG_ID_ODOMETRY: 30.0,
    MSG.MAVLINK_MSG_ID_ATTITUDE_TARGET: 10.0,
    MSG.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    MSG.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    MSG.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    MSG.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    MSG.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    MSG.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
}
GCS_RATES = {
    MSG.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    MSG.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    MSG.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 5.0,
    MSG.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    MSG.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    MSG.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    MSG.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    MSG.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    MSG.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
}

SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
           | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
           | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_AHRS
           | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY | mavlink.MAV_SYS_STATUS_GEOFENCE)
PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK


@dataclass
class Stats:
    """What the vehicle received and what it refused, by reason."""
    datagrams: int = 0
    messages: int = 0
    bad_prefix: int = 0
    bad_crc: int = 0
    bad_length: int = 0
    truncated: int = 0
    unknown_msgid: int = 0
    unsigned_rejected: int = 0
    bad_signature: int = 0
    other_target: int = 0
    setpoints_rejected: int = 0
    setpoints_ignored: int = 0
    commands: int = 0
    overruns: int = 0
    by_reason: dict = field(default_factory=dict)

    def dropped(self):
        return (self.bad_prefix + self.bad_crc + self.bad_length + self.truncated
                + self.unknown_msgid + self.unsigned_rejected + self.bad_signature)


class _Sender:
    """File-like target for pymavlink's MAVLink.send: writes each frame to every peer of a link,
    or, between ``Link.begin()`` and ``Link.flush()``, collects the frames of one step so they go
    out together (several frames per datagram, as PX4 sends them)."""

    def __init__(self, link):
        self.link = link

    def write(self, buf):
        if self.link.batch is not None:
            self.link.batch.append(bytes(buf))
        else:
            self.link.sendto(buf)


class Link:
    def __init__(self, name, sock, remote, mav, rates):
        self.name = name
        self.sock = sock
        self.peers = [remote] if remote else []
        self.batch = None
        self.mav = mav
        mav.file = _Sender(self)
        self.default_rates = dict(rates)
        # schedules in integer microseconds of vehicle time, so lockstep never drifts a step
        self.intervals = {}
        self.next_due = {}
        for mid, hz in rates.items():
            self.set_interval(mid, int(round(1e6 / hz)), due=0)
        self.parser = None  # reused across datagrams while they parse cleanly

    def set_interval(self, mid, interval_us, due=None):
        """Schedule message ``mid`` every ``interval_us`` us of vehicle time (None: never),
        next at ``due`` if given.  LOCAL_POSITION_NED stays first in the schedule (it goes out
        in a datagram of its own, so a companion's control step can start while the rest of
        the step's telemetry is still being built)."""
        self.intervals[mid] = interval_us
        if due is not None:
            self.next_due[mid] = due
        if LPN in self.intervals:
            self.intervals = {LPN: self.intervals.pop(LPN), **self.intervals}
        self.next_any = 0  # the earliest next_due (us of vehicle time): look at every entry

    def learn(self, addr):
        if addr not in self.peers:
            self.peers.append(addr)

    MAX_DATAGRAM = 1400

    def sendto(self, buf):
        for peer in self.peers:
            try:
                self.sock.sendto(buf, peer)
            except OSError:
                pass

    def begin(self):
        self.batch = []

    def flush(self):
        frames, self.batch = self.batch, None
        chunk = b""
        for f in frames or ():
            if chunk and len(chunk) + len(f) > self.MAX_DATAGRAM:
                self.sendto(chunk)
                chunk = b""
            chunk += f
        if chunk:
            self.sendto(chunk)


class SitlServer:
    """Runs a :class:`sim.vehicle.SimVehicle` behind MAVLink.

    ``SitlServer(vehicle, autopilot="px4", instance=0).run()`` blocks; ``start()`` runs it in a
    thread (tests) and ``stop()`` ends it.
    """

    def __init__(self, vehicle, autopilot="px4", instance=0, *, lockstep=False, lockstep_dt=0.01,
                 lockstep_timeout=10.0, tick=0.002, signing_key=None, home=(47.397742, 8.545594, 488.0),
                 host="127.0.0.1", offboard_port=None, gcs_port=None, bind_offboard=None,
                 bind_gcs=None, params=None):
        self.vehicle = vehicle
        self.ap = PP.personality(autopilot)
        self.instance = int(instance)
        self.sysid = self.instance + 1
        self.lockstep = bool(lockstep)
        self.lockstep_dt = float(lockstep_dt)
        self.lockstep_timeout = float(lockstep_timeout)
        self.tick = float(tick)
        self.home = tuple(float(v) for v in home)
        self.stats = Stats()
        self.params = {name: (default, ptype) for name, default, ptype in self.ap.params}
        self.params[self.ap.sysid_param] = (self.sysid, PP.INT)
        self.params[self.ap.hover_param] = (float(vehicle.hover_thrust), PP.REAL)
        self._param_names = [name for name, _, _ in self.ap.params]
        for name, value in (params or {}).items():
            self.params[name] = (parse_param(self.ap, name, value), self.params[name][1])
        self._signing_key = signing_key
        self._boot_wall = time.time()
        self.mode = self.ap.mode(self.ap.initial_mode)
        self.failsafe = False
        self._mode_before_failsafe = None  # what a failsafe switched away from
        self._last_setpoint_t = -math.inf  # vehicle time of the last proof-of-life setpoint
        self._last_setpoint_wall = -math.inf
        self._taken_off = False  # the land detector saw a take-off since arming
        self._armed_t = 0.0
        self._landed_since = None  # vehicle time the land detector last declared landing
        self._ld = self.ap.land_detector()
        self._spool_until = -math.inf  # motors held at idle after arming until then
        self._deferred = None  # what the last setpoint or takeoff asked for while held at idle
        self._rtl_phase = None
        self._guided = None  # ArduPilot GUIDED attitude target (see _guided_output)
        self._climb_i = 0.0  # ArduPilot GUIDED climb-rate loop integrator (m/s^2)
        self._att_target = (np.array([1.0, 0.0, 0.0, 0.0]), 0.0, np.zeros(3), 0)
        self._statustext_last = {}
        self._pending_steps = 0
        self._rep = None
        self._running = False
        self._thread = None
        self._last_hb_wall = 0.0
        self._last_step_wall = 0.0  # lockstep: wall time the clock last advanced
        self._last_hb_t = -10**9
        self._base_wind = vehicle.wind
        if any(name.startswith("SIM_WIND_") for name in (params or {})):
            self._update_gcs_wind(announce=False)
        vehicle.auto_disarm_s = None  # the autopilot disarms by itself (auto_disarm)
        self.links = []
        off_remote = (host, 14540 + self.instance if offboard_port is None else offboard_port)
        gcs_remote = (host, 14550 if gcs_port is None else gcs_port)
        off_bind = 14580 + self.instance if bind_offboard is None else bind_offboard
        gcs_bind = 18570 + self.instance if bind_gcs is None else bind_gcs
        for name, remote, port, rates in (("offboard", off_remote, off_bind, ONBOARD_RATES),
                                          ("gcs", gcs_remote, gcs_bind, GCS_RATES)):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((host, port))
            sock.setblocking(False)
            mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
            if signing_key is not None:
                self._setup_signing(mav)
            rates = {mid: hz for mid, hz in rates.items() if self.ap.sends(mid)}
            self.links.append(Link(name, sock, remote, mav, rates))
        self._apply_mode_behaviour()

    # --- setup -----------------------------------------------------------------------------------

    def _setup_signing(self, mav):
        s = mav.signing
        s.secret_key = bytes(self._signing_key)
        s.sign_outgoing = True
        s.link_id = 0
        s.timestamp = int((time.time() - 1420070400) * 1e5)
        s.allow_unsigned_callback = lambda _mav, msgid: msgid in UNSIGNED_ALLOWED

    @property
    def local_ports(self):
        return {link.name: link.sock.getsockname()[1] for link in self.links}

    # --- main loop -------------------------------------------------------------------------------

    def start(self):
        import threading
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="mavadrc-sitl", daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for link in self.links:
            link.sock.close()

    def stop_soon(self):
        """Ask a running loop to end (from a signal handler or a timer)."""
        self._running = False

    def run(self):
        self._running = True
        try:
            self._loop()
        finally:
            for link in self.links:
                link.sock.close()

    #: lockstep: poll this long (wall s) for the next setpoint before sleeping in select.  The
    #: companion answers within a few hundred microseconds, and waking from select costs about
    #: 50 us on each side of the loop.
    LOCKSTEP_SPIN_S = 0.002

    def _loop(self):
        socks = [link.sock for link in self.links]
        next_tick = time.monotonic()
        while self._running:
            now = time.monotonic()
            readable = ()
            if self.lockstep and not self._lockstep_stalled():
                timeout = 0.1
                end = time.perf_counter() + self.LOCKSTEP_SPIN_S
                while not readable and time.perf_counter() < end:
                    readable, _, _ = select.select(socks, [], [], 0.0)
            else:
                timeout = max(0.0, next_tick - now)
            if not readable:
                readable, _, _ = select.select(socks, [], [], timeout)
            for sock in readable:
                self._drain(sock)
            if self.lockstep and not self._lockstep_stalled():
                if self._pending_steps > 0:
                    self._last_step_wall = time.monotonic()
                while self._pending_steps > 0:
                    self._pending_steps -= 1
                    self.advance(self.lockstep_dt)
                self._wall_heartbeat()
                next_tick = time.monotonic()
                continue
            now = time.monotonic()
            if now >= next_tick:
                self.advance(self.tick)
                next_tick += self.tick
                if now - next_tick > 0.25:  # fell far behind (machine busy): resynchronise
                    self.stats.overruns += 1
                    next_tick = now

    def _lockstep_stalled(self):
        """In lockstep, setpoints stopped for ``lockstep_timeout`` wall seconds while flying."""
        if not (self.vehicle.armed and self._last_setpoint_wall > -math.inf):
            return False
        return time.monotonic() - self._last_setpoint_wall > self.lockstep_timeout

    def _wall_heartbeat(self):
        """Lockstep with the clock stopped (no setpoints yet, or a pause): a heartbeat each second
        of wall time, so that a client can connect before it streams.  While the clock runs,
        heartbeats keep to 1 Hz of vehicle time."""
        now = time.monotonic()
        if now - max(self._last_hb_wall, self._last_step_wall) >= 1.0:
            self._send_all(self._heartbeat())
            self._last_hb_wall = now

    def _drain(self, sock):
        link = next(lk for lk in self.links if lk.sock is sock)
        while True:
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self.stats.datagrams += 1
            link.learn(addr)
            for msg in self._parse(link, data):
                try:
                    self._handle(link, msg)
                except Exception:  # a message we cannot act on never stops the vehicle
                    log.exception("error handling %s", msg.get_type())
                    self._count("handler_error")

    def _parse(self, link, data):
        """Decode one datagram on its own; count and drop everything that is not a good frame.

        The link's parser is reused only while every datagram leaves it empty; one that leaves
        a partial frame behind (or makes it raise) gets a fresh parser for the next datagram,
        so nothing of a bad datagram carries over."""
        parser = link.parser
        if parser is None:
            parser = link.parser = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
            parser.robust_parsing = True
            parser.signing = link.mav.signing
        out = []
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:
            self.stats.bad_length += 1
            link.parser = None
            return out
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                reason = str(getattr(m, "reason", ""))
                if "prefix" in reason:
                    self.stats.bad_prefix += 1
                elif "CRC" in reason:
                    self.stats.bad_crc += 1
                elif "signature" in reason:
                    if m.data and len(m.data) > 2 and (m.data[2] & mavlink.MAVLINK_IFLAG_SIGNED):
                        self.stats.bad_signature += 1
                    else:
                        self.stats.unsigned_rejected += 1
                else:
                    self.stats.bad_length += 1
                continue
            if t == "UNKNOWN" or m.get_msgId() < 0:
                self.stats.unknown_msgid += 1
                continue
            out.append(m)
        if parser.buf_len() > 0:
            self.stats.truncated += 1
            link.parser = None
        self.stats.messages += len(out)
        return out

    # --- time and physics ------------------------------------------------------------------------

    @property
    def time(self):
        return self.vehicle.time

    def _boot_ms(self):
        return int(round(self.vehicle.time * 1000.0)) & 0xFFFFFFFF

    def advance(self, dt):
        """Advance the vehicle by dt and do everything the autopilot does per step."""
        if self._deferred is not None and not self._spooling():
            apply, self._deferred = self._deferred, None
            apply()
        self._guided_output(dt)
        self.vehicle.step(dt)
        self._rep = None
        self._detect_landing(dt)
        self._supervise()
        self._send_due()

    def _loss_timeout(self):
        if self.ap.name == "px4":
            return float(self.params["COM_OF_LOSS_T"][0])
        return float(self.params["GUID_TIMEOUT"][0])

    # --- what the autopilot does by itself -------------------------------------------------------

    def _spooling(self):
        """The motors are still held at idle after arming (the personality's spoolup_param)."""
        return self.vehicle.armed and self.vehicle.time < self._spool_until - 1e-9

    def _when_spooled(self, apply):
        """Carry out a setpoint or takeoff now, or once the motors are free if they are still held
        at idle after arming (the last request wins)."""
        if self._spooling():
            self._deferred = apply
        else:
            self._deferred = None
            apply()

    def _detect_landing(self, dt):
        """Run the personality's land detector on this step; announce and time its changes."""
        v = self.vehicle
        r = self._reported()
        q_sp, thrust = v.attitude_setpoint
        climb_rate_control = v.mode != "attitude"
        in_descend = True  # landing, or idle on the ground
        if v.mode in ("position", "hold", "takeoff"):
            sp = v.nav.sp
            vz = sp[PL.PSP_VEL + 2] if math.isfinite(sp[PL.PSP_VEL + 2]) else 0.0
            if math.isfinite(sp[PL.PSP_POS + 2]):
                vz += v.nav.pp[PL.PP_KP + 2] * (sp[PL.PSP_POS + 2] - r.position[2])
            in_descend = vz >= 1.1 * float(self.params.get("LNDMC_Z_VEL_MAX", (0.25,))[0])
        tilt = math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (q_sp[1] ** 2 + q_sp[2] ** 2))))
        u = PP.LandInputs(thrust, (float(r.velocity[0]), float(r.velocity[1]),
                                   float(r.velocity[2])),
                          math.hypot(r.rates[0], r.rates[1]), tilt, climb_rate_control, in_descend)
        was = self._ld.landed
        self._ld.update(dt, self.params, v.armed, u)
        if not v.armed or was == self._ld.landed:
            return
        if self._ld.landed:
            self._landed_since = v.time
            if self.ap.landing_text:
                self.statustext(mavlink.MAV_SEVERITY_INFO, self.ap.landing_text)
        else:
            self._landed_since = None
            self._taken_off = True
            if self.ap.takeoff_text:
                self.statustext(mavlink.MAV_SEVERITY_INFO, self.ap.takeoff_text)

    def _supervise(self):
        v = self.vehicle
        t = v.time
        # offboard loss
        if (self.ap.offboard_loss_param and self.mode.behaviour == PP.OFFBOARD and v.armed
                and not self.failsafe):
            stalled = self.lockstep and self._lockstep_stalled()
            timeout = float(self.params[self.ap.offboard_loss_param][0])
            if stalled or t - self._last_setpoint_t > timeout:
                self._offboard_lost()
        # takeoff complete
        if self.mode.behaviour == PP.TAKEOFF and v.mode == "hold" and self.ap.name == "px4":
            self._set_mode(self.ap.mode("AUTO.LOITER"))
        # return to launch: go home, then land
        if self.mode.behaviour == PP.RTL and self._rtl_phase == "return" and v.armed:
            p = self._reported().position
            if math.hypot(p[0], p[1]) < 0.5:
                self._rtl_phase = "land"
                v.land()
        # auto-disarm: the personality's rules (landed for a while, or no takeoff after arming)
        if v.armed:
            why = self.ap.auto_disarm(self.params, t, self._armed_t, self._taken_off,
                                      self._landed_since)
            if why is not None:
                self._disarm(why)

    def _offboard_lost(self):
        """PX4: the offboard-loss failsafe (the personality's offboard_loss_action), announced
        as PX4 does: the event text, then the STATUSTEXT "Failsafe activated"."""
        self.failsafe = True
        if self._mode_before_failsafe is None:
            self._mode_before_failsafe = self.mode
        target, action = self.ap.offboard_loss_action(self.params)
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Failsafe activated: switching to {action}")
        self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated")
        if target in ("DISARM", "TERMINATE"):
            self._disarm("failsafe")
        else:
            self._set_mode(self.ap.mode(target))

    def _guided_output(self, dt):
        """ArduCopter's GUIDED attitude control (mode_guided.cpp angle_control_run), each step.

        No new target for GUID_TIMEOUT s: level at the target's heading and hold the climb rate
        at zero (the thrust, if it was thrust, becomes a climb rate).  On the ground (land
        detector) without positive thrust or climb: motors at idle.  Otherwise thrust
        (GUID_OPTIONS bit 3) through the angle boost, or the climb-rate loop."""
        g = self._guided
        v = self.vehicle
        if g is None or not v.armed or self._spooling():
            return
        if not g.timed_out and v.time - g.t > float(self.params["GUID_TIMEOUT"][0]) + 1e-9:
            w, x, y, z = g.q
            yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            g.q = np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])
            g.rates, g.mask = None, 7
            g.value, g.use_thrust, g.timed_out = 0.0, False, True
            self._climb_i = 0.0
            log.info("GUIDED: no attitude target for GUID_TIMEOUT: level, climb rate zero")
        if self._ld.landed and not g.value > 0.0:
            r = self._reported()
            yaw = float(r.euler[2])
            v.set_attitude_target([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)], 0.0)
            self._climb_i = 0.0
            return
        thrust = self._angle_boost(g.value) if g.use_thrust else self._climb_thrust(g, dt)
        v.set_attitude_target(g.q, thrust, body_rates=g.rates, type_mask=g.mask)

    def _angle_boost(self, thrust):
        """AC_AttitudeControl_Multi::get_throttle_boosted, as GUIDED's set_throttle_out(thrust,
        true, ...) applies it: thrust x inverted_factor / cos(tilt), where cos(tilt) is the
        measured cos(roll) cos(pitch), the boost factor clamped to cos >= 0.1 and
        inverted_factor = clamp(10 cos(tilt), 0, 1); off with ATC_ANGLE_BOOST 0.  The motors clip
        the result to 0..1."""
        if int(self.params["ATC_ANGLE_BOOST"][0]):
            q = self._reported().quaternion
            c = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])
            thrust = thrust * min(max(10.0 * c, 0.0), 1.0) / min(max(c, 0.1), 1.0)
        return min(max(thrust, 0.0), 1.0)

    def _climb_thrust(self, g, dt):
        """GUIDED without GUID_OPTIONS bit 3: thrust is a climb rate; a PI climb-rate loop
        (its integrator winds the throttle down to its lower limit on the ground, as
        ArduCopter's, so that the land detector can see a landing)."""
        r = self._reported()
        err = g.value + r.velocity[2]  # climb rate asked minus climb rate measured (m/s)
        self._climb_i = min(max(self._climb_i + 2.0 * err * dt, -phys.GRAVITY), phys.GRAVITY)
        hover = float(self.params["MOT_THST_HOVER"][0])
        q = g.q
        tilt = max(0.3, 1.0 - 2.0 * (q[1] ** 2 + q[2] ** 2))
        thrust = hover * (1.0 + (3.0 * err + self._climb_i) / phys.GRAVITY) / tilt
        return min(max(thrust, 0.0), 1.0)

    # --- sending ---------------------------------------------------------------------------------

    def _send_all(self, msg):
        if msg is None:
            return
        for link in self.links:
            link.mav.send(msg)

    def _send_due(self):
        t = int(round(self.vehicle.time * 1e6))
        if t - self._last_hb_t >= 1_000_000:
            self._send_all(self._heartbeat())
            self._last_hb_t = t
            self._last_hb_wall = time.monotonic()
        for link in self.links:
            if t < link.next_any:
                continue  # nothing of this link's schedule is due
            link.begin()
            next_any = math.inf
            for mid, interval in link.intervals.items():
                if not interval:
                    continue
                due = link.next_due.get(mid, 0)
                if t >= due:
                    msg = self._build(mid)
                    if msg is not None:
                        link.mav.send(msg)
                        if mid == LPN:  # the sample leaves at once, on its own
                            link.flush()
                            link.begin()
                    nxt = due + interval
                    due = link.next_due[mid] = nxt if nxt > t else t + interval
                if due < next_any:
                    next_any = due
            link.next_any = next_any
            link.flush()

    def statustext(self, severity, text):
        self._send_all(mavlink.MAVLink_statustext_message(severity, text[:50].encode()))
        log.info("STATUSTEXT %s", text)

    def _statustext_limited(self, key, severity, text):
        now = time.monotonic()
        if now - self._statustext_last.get(key, -10.0) >= 1.0:
            self._statustext_last[key] = now
            self.statustext(severity, text)

    def _heartbeat(self):
        v = self.vehicle
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if v.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if self.ap.name == "ardupilot":
            base |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
            if self.mode.behaviour == PP.OFFBOARD:
                base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.failsafe:
            status = mavlink.MAV_STATE_CRITICAL
        elif v.armed:
            status = mavlink.MAV_STATE_ACTIVE
        else:
            status = mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, self.ap.autopilot,
                                                 base, self.mode.custom_mode, status, 3)

    def _landed_state(self):
        """EXTENDED_SYS_STATE.landed_state from the autopilot's land detector, not from the
        vehicle's contact with the ground."""
        if self._ld.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.mode.behaviour == PP.TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.mode.behaviour == PP.LAND or (self.mode.behaviour == PP.RTL
                                              and self._rtl_phase == "land"):
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _global(self, p):
        lat0, lon0, alt0 = self.home
        lat = lat0 + math.degrees(p[0] / EARTH_RADIUS)
        lon = lon0 + math.degrees(p[1] / (EARTH_RADIUS * math.cos(math.radians(lat0))))
        return int(round(lat * 1e7)), int(round(lon * 1e7)), alt0 - p[2]

    def _reported(self):
        """The vehicle's reported state, read once per step for all the messages built from it."""
        if self._rep is None:
            self._rep = self.vehicle.reported()
        return self._rep

    def _build(self, mid):
        """Build message ``mid`` from the vehicle's reported state; None if not produced."""
        v = self.vehicle
        r = self._reported()
        ms = self._boot_ms()
        p, vel, q, e, w = r.position, r.velocity, r.quaternion, r.euler, r.rates
        M = mavlink
        if mid == M.MAVLINK_MSG_ID_ATTITUDE:
            return M.MAVLink_attitude_message(ms, e[0], e[1], e[2], w[0], w[1], w[2])
        if mid == M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            return M.MAVLink_attitude_quaternion_message(ms, q[0], q[1], q[2], q[3], w[0], w[1],
                                                         w[2], [0.0, 0.0, 0.0, 0.0])
        if mid == M.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return M.MAVLink_local_position_ned_message(ms, p[0], p[1], p[2], vel[0], vel[1],
                                                        vel[2])
        if mid == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            lat, lon, alt = self._global(p)
            hdg = int(round(math.degrees(e[2]) * 100.0)) % 36000
            return M.MAVLink_global_position_int_message(
                ms, lat, lon, int(round(alt * 1000)), int(round(-p[2] * 1000)),
                int(round(vel[0] * 100)), int(round(vel[1] * 100)), int(round(vel[2] * 100)), hdg)
        if mid == M.MAVLINK_MSG_ID_ODOMETRY:
            R = rotation_matrix(q)
            vb = R.T @ vel
            nan21 = [math.nan] * 21
            return M.MAVLink_odometry_message(
                int(round(v.time * 1e6)), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD, p[0], p[1], p[2],
                list(map(float, q)), vb[0], vb[1], vb[2], w[0], w[1], w[2], nan21, nan21, 0,
                M.MAV_ESTIMATOR_TYPE_NAIVE, 100)
        if mid == M.MAVLINK_MSG_ID_ATTITUDE_TARGET:
            qt, thrust, rates, mask = self._att_target
            return M.MAVLink_attitude_target_message(ms, mask, list(map(float, qt)), rates[0],
                                                     rates[1], rates[2], abs(thrust))
        if mid == M.MAVLINK_MSG_ID_SYS_STATUS:
            health = SENSORS | (0 if self.failsafe else PREARM)
            pct = self._battery_remaining()
            return M.MAVLink_sys_status_message(SENSORS | PREARM, SENSORS | PREARM, health, 200,
                                                self._battery_mv(), -1, pct, 0, 0, 0, 0, 0, 0)
        if mid == M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED,
                                                        self._landed_state())
        if mid == M.MAVLINK_MSG_ID_HOME_POSITION:
            lat0, lon0, alt0 = self.home
            return M.MAVLink_home_position_message(
                int(round(lat0 * 1e7)), int(round(lon0 * 1e7)), int(round(alt0 * 1000)), 0.0, 0.0,
                0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(round(v.time * 1e6)))
        if mid == M.MAVLINK_MSG_ID_BATTERY_STATUS:
            cells = [self._battery_mv() // 4] * 4 + [65535] * 6
            return M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL,
                                                    M.MAV_BATTERY_TYPE_LIPO, 2500, cells, -1, -1,
                                                    -1, self._battery_remaining())
        if mid == M.MAVLINK_MSG_ID_SYSTEM_TIME:
            return M.MAVLink_system_time_message(int(time.time() * 1e6), ms)
        if mid == M.MAVLINK_MSG_ID_GPS_RAW_INT:
            lat, lon, alt = self._global(p)
            cog = int(round(math.degrees(math.atan2(vel[1], vel[0])) * 100)) % 36000
            return M.MAVLink_gps_raw_int_message(int(round(v.time * 1e6)), M.GPS_FIX_TYPE_3D_FIX, lat,
                                                 lon, int(round(alt * 1000)), 80, 120,
                                                 int(round(math.hypot(vel[0], vel[1]) * 100)),
                                                 cog, 12)
        if mid == M.MAVLINK_MSG_ID_DEBUG_VECT:
            # the simulator's truth, for comparing observer estimates: the acceleration (NED,
            # m/s^2) the environment adds beyond thrust and gravity
            d = v.true_disturbance()
            return M.MAVLink_debug_vect_message(b"TRUE_DIST", int(round(v.time * 1e6)),
                                                float(d[0]), float(d[1]), float(d[2]))
        if mid == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return M.MAVLink_autopilot_version_message(
                self.ap.capabilities, self.ap.flight_sw_version, 0, 0, 1, b"mavadrc\0",
                b"\0" * 8, b"\0" * 8, 0, 0, 0x4D41564144524300 + self.sysid)
        return None

    def _battery_remaining(self):
        return int(max(5.0, 100.0 - 0.05 * self.vehicle.time))

    def _battery_mv(self):
        return int(16800 - 20 * (100 - self._battery_remaining()))

    # --- receiving -------------------------------------------------------------------------------

    def _count(self, reason):
        self.stats.by_reason[reason] = self.stats.by_reason.get(reason, 0) + 1

    def _for_us(self, msg):
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        if ts not in (0, self.sysid) or tc not in (0, 1):
            self.stats.other_target += 1
            return False
        return True

    def _handle(self, link, msg):
        t = msg.get_type()
        h = self._handlers.get(t)
        if h is None:
            return
        if t != "HEARTBEAT" and hasattr(msg, "target_system") and not self._for_us(msg):
            return
        h(self, link, msg)

    def _ack(self, link, msg, command, result):
        link.mav.send(mavlink.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_command(self, link, msg):
        self.stats.commands += 1
        params = [msg.param1, msg.param2, msg.param3, msg.param4]
        if msg.get_type() == "COMMAND_INT":
            params += [msg.x / 1e7, msg.y / 1e7, msg.z]
        else:
            params += [msg.param5, msg.param6, msg.param7]
        try:
            result, after = self._command(link, msg.command, params)
        except Exception:  # never silence: a command that breaks is answered FAILED
            log.exception("command %s failed", msg.command)
            self._count("command_error")
            result, after = mavlink.MAV_RESULT_FAILED, None
        self._ack(link, msg, msg.command, result)
        if after is not None:
            after()

    def _command(self, link, cmd, p):
        """Carry out a command; returns (MAV_RESULT, optional follow-up sending after the ACK)."""
        M = mavlink
        R = M.MAV_RESULT_ACCEPTED
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = _near(p[1], FORCE_ARM_MAGIC)
            if _near(p[0], 1.0):
                return self._arm(force), None
            if _near(p[0], 0.0):
                return self._disarm_cmd(force), None
            return M.MAV_RESULT_DENIED, None
        if cmd == M.MAV_CMD_DO_SET_MODE:
            return self._set_mode_cmd(p), None
        if cmd == M.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff_cmd(p[6]), None
        if cmd == M.MAV_CMD_NAV_LAND:
            return self._set_mode(self.ap.mode("AUTO.LAND" if self.ap.name == "px4" else "LAND")), None
        if cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode(self.ap.mode("AUTO.RTL" if self.ap.name == "px4" else "RTL")), None
        if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(link, p[0], p[1]), None
        if cmd == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            mid = int(p[0])
            us = link.intervals.get(mid) or -1
            return R, lambda: link.mav.send(M.MAVLink_message_interval_message(mid, us))
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            mid = int(p[0]) if math.isfinite(p[0]) else -1
            if mid in (M.MAVLINK_MSG_ID_HEARTBEAT,):
                return R, lambda: link.mav.send(self._heartbeat())  # at once, either autopilot
            if not self.ap.sends(mid) or self._build(mid) is None:
                return self.ap.request_refused, None
            return R, lambda: link.mav.send(self._build(mid))
        if cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return R, lambda: link.mav.send(self._build(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
        if cmd == M.MAV_CMD_GET_HOME_POSITION:
            return R, lambda: link.mav.send(self._build(M.MAVLINK_MSG_ID_HOME_POSITION))
        if cmd == M.MAV_CMD_NAV_LOITER_UNLIM:
            return self._set_mode(self.ap.mode("AUTO.LOITER" if self.ap.name == "px4"
                                               else "LOITER")), None
        return M.MAV_RESULT_UNSUPPORTED, None

    def _arm(self, force):
        M = mavlink
        v = self.vehicle
        if v.armed:
            return M.MAV_RESULT_ACCEPTED
        if not force:
            if not self.mode.armable:
                self.statustext(M.MAV_SEVERITY_CRITICAL, f"Arming denied: not armable in {self.mode.name}")
                return self.ap.arming_refused
            if self.mode.behaviour == PP.OFFBOARD and self.ap.name == "px4" and not self._stream_alive():
                self.statustext(M.MAV_SEVERITY_CRITICAL, "Arming denied: no offboard signal")
                return self.ap.arming_refused
            if not v.landed:
                return self.ap.arming_refused
        v.arm()
        self._taken_off = False
        self._armed_t = v.time
        self._landed_since = v.time if self._ld.landed else None
        self._spool_until = v.time + max(0.0, float(self.params[self.ap.spoolup_param][0]))
        self._deferred = None
        self._climb_i = 0.0
        self.failsafe = False
        self._mode_before_failsafe = None
        self.statustext(M.MAV_SEVERITY_INFO, self.ap.armed_text())
        return M.MAV_RESULT_ACCEPTED  # no heartbeat now: the next 1 Hz one shows it

    def _disarm_cmd(self, force):
        M = mavlink
        if not self.vehicle.armed:
            return M.MAV_RESULT_ACCEPTED
        if not force and not self.ap.disarm_allowed(self._ld):
            if self.ap.disarm_denied_text:
                self.statustext(M.MAV_SEVERITY_CRITICAL, self.ap.disarm_denied_text)
            return self.ap.arming_refused
        self._disarm("external")
        return M.MAV_RESULT_ACCEPTED

    def _disarm(self, why):
        """Disarm (the autopilot's decision: the vehicle's own landed flag is not asked)."""
        self.vehicle.disarm(force=True)
        self._guided = None
        self._deferred = None
        self._taken_off = False
        self._landed_since = None
        self.failsafe = False
        self.statustext(mavlink.MAV_SEVERITY_INFO, self.ap.disarmed_text(why))
        before, self._mode_before_failsafe = self._mode_before_failsafe, None
        if before is not None and self.ap.restores_mode_after_failsafe:
            self.mode = before
            self._mode_changed()
        elif self.mode.behaviour in (PP.LAND, PP.RTL, PP.TAKEOFF):
            self.mode = self.ap.mode(self.ap.initial_mode)
            self._apply_mode_behaviour()
            self._mode_changed()

    def _mode_changed(self):
        """The mode has just changed: ArduPilot sends a heartbeat at once, PX4 waits for the next
        one of its 1 Hz stream."""
        if self.ap.heartbeat_on_mode_change:
            self._send_all(self._heartbeat())

    def _set_mode_cmd(self, p):
        M = mavlink
        base = int(p[0]) if math.isfinite(p[0]) else 0
        if not base & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return M.MAV_RESULT_DENIED
        if self.ap.name == "px4":
            main = int(p[1]) if math.isfinite(p[1]) else 0
            sub = int(p[2]) if math.isfinite(p[2]) else 0
            custom = PP.px4_custom_mode(main, sub if main == 4 else 0)
        else:
            custom = int(p[1]) if math.isfinite(p[1]) else -1
        mode = self.ap.mode_from_custom(custom)
        if mode is None:
            return M.MAV_RESULT_DENIED
        return self._set_mode(mode)

    def _stream_alive(self):
        return self.vehicle.time - self._last_setpoint_t <= self._loss_timeout()

    def _set_mode(self, mode):
        M = mavlink
        if mode.behaviour == PP.OFFBOARD and self.ap.name == "px4" and not self._stream_alive():
            self.statustext(M.MAV_SEVERITY_CRITICAL, "Offboard denied: no setpoint stream")
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode.behaviour == PP.TAKEOFF and not self.vehicle.armed:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        changed = mode is not self.mode
        self.mode = mode
        if changed:
            self._deferred = None  # a takeoff or setpoint held back for the spool-up lapses
        if changed or mode.behaviour != PP.OFFBOARD:
            self._apply_mode_behaviour()
        if mode.behaviour != PP.OFFBOARD:
            self._guided = None
        self.failsafe = self.failsafe and mode.behaviour != PP.OFFBOARD
        if changed:
            self._mode_changed()
        return M.MAV_RESULT_ACCEPTED

    def _apply_mode_behaviour(self):
        v = self.vehicle
        b = self.mode.behaviour
        self._rtl_phase = None
        if b == PP.HOLD:
            if v.armed:
                v.hold()  # on the ground: idle, whatever offboard thrust was last asked for
        elif b == PP.LAND:
            if v.armed:
                v.land()
        elif b == PP.RTL:
            if v.armed and not v.landed:
                p = v.reported().position
                alt = max(-p[2], self._rtl_alt())
                v.set_position_target(pos=np.array([0.0, 0.0, -alt]))
                self._rtl_phase = "return"
            elif v.armed:
                v.hold()
        elif b == PP.TAKEOFF:
            alt = float(self.params["MIS_TAKEOFF_ALT"][0])
            self._when_spooled(lambda: v.takeoff(alt))
        elif b == PP.OFFBOARD:
            if v.armed and not v.landed and self.ap.name == "ardupilot":
                v.hold()

    def _rtl_alt(self):
        if self.ap.name == "px4":
            return float(self.params["RTL_RETURN_ALT"][0])
        return float(self.params["RTL_ALT"][0]) / 100.0

    def _takeoff_cmd(self, p7):
        M = mavlink
        v = self.vehicle
        if not v.armed:
            self.statustext(M.MAV_SEVERITY_CRITICAL, "Takeoff denied: disarmed")
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.ap.name == "px4":
            alt = float(self.params["MIS_TAKEOFF_ALT"][0])
            if math.isfinite(p7) and p7 - self.home[2] >= 1.0:
                alt = p7 - self.home[2]
            changed = self.mode is not self.ap.mode("AUTO.TAKEOFF")
            self.mode = self.ap.mode("AUTO.TAKEOFF")
            self._when_spooled(lambda: v.takeoff(alt))
            if changed:
                self._mode_changed()
            return M.MAV_RESULT_ACCEPTED
        if self.mode.behaviour != PP.OFFBOARD:
            return M.MAV_RESULT_FAILED
        if not (math.isfinite(p7) and p7 > 0.0):
            return M.MAV_RESULT_DENIED
        self._guided = None
        self._when_spooled(lambda: v.takeoff(p7))
        return M.MAV_RESULT_ACCEPTED

    def _set_interval(self, link, msgid, interval_us):
        M = mavlink
        if not (math.isfinite(msgid) and math.isfinite(interval_us)):
            return M.MAV_RESULT_DENIED
        mid = int(msgid)
        hb = mid == M.MAVLINK_MSG_ID_HEARTBEAT
        if (not self.ap.sends(mid) or (hb and not self.ap.heartbeat_interval_settable)
                or (not hb and self._build(mid) is None)):
            text = self.ap.interval_refused_text(mid)
            if text:
                self.statustext(M.MAV_SEVERITY_INFO, text)
            return self.ap.interval_refused
        if hb:
            return M.MAV_RESULT_ACCEPTED  # always 1 Hz
        if interval_us < 0:
            link.set_interval(mid, None)
        elif interval_us == 0:
            hz = link.default_rates.get(mid)
            link.set_interval(mid, None if hz is None else int(round(1e6 / hz)))
        else:
            link.set_interval(mid, max(1, int(round(interval_us))),
                              due=int(round(self.vehicle.time * 1e6)))
        return M.MAV_RESULT_ACCEPTED

    # setpoints

    def _reject_setpoint(self, reason):
        self.stats.setpoints_rejected += 1
        self._count(reason)
        self._statustext_limited(reason, mavlink.MAV_SEVERITY_WARNING, f"Setpoint rejected: {reason}")

    def _proof_of_life(self):
        self._last_setpoint_t = self.vehicle.time
        self._last_setpoint_wall = time.monotonic()
        self._lockstep_tick()

    def _lockstep_tick(self):
        """In lockstep every well-formed setpoint advances the clock one period, whether or not
        the current mode acts on it: the companion's stream is the clock."""
        if self.lockstep:
            self._pending_steps += 1

    def _on_attitude_target(self, link, msg):
        mask = msg.type_mask
        q = [float(c) for c in msg.q]
        rates = [float(msg.body_roll_rate), float(msg.body_pitch_rate), float(msg.body_yaw_rate)]
        thrust = float(msg.thrust)
        if not mask & AT_ATTITUDE:
            if not all(math.isfinite(c) for c in q):
                return self._reject_setpoint("non-finite quaternion")
            if abs(math.sqrt(sum(c * c for c in q)) - 1.0) > 1e-3:
                return self._reject_setpoint("quaternion not unit length")
        if not mask & AT_THROTTLE:
            if not math.isfinite(thrust):
                return self._reject_setpoint("non-finite thrust")
            if not 0.0 <= thrust <= 1.0:
                return self._reject_setpoint("thrust out of range")
        if (mask & AT_RATES) != AT_RATES and not all(math.isfinite(c) for c in rates):
            return self._reject_setpoint("non-finite body rates")
        if mask & AT_ATTITUDE and (mask & AT_RATES) == AT_RATES:
            return self._reject_setpoint("attitude and rates both ignored")
        if self.ap.name == "ardupilot":
            if self.mode.behaviour != PP.OFFBOARD:
                self.stats.setpoints_ignored += 1
                self._lockstep_tick()
                return None
            self._proof_of_life()
            if not self.vehicle.armed:
                return None
            use_thrust = bool(int(self.params["GUID_OPTIONS"][0]) & 8) and not mask & AT_THROTTLE
            th = 0.5 if mask & AT_THROTTLE else thrust
            if use_thrust:
                value = thrust
            else:
                up = float(self.params["PILOT_SPEED_UP"][0]) / 100.0
                dn = float(self.params["PILOT_SPEED_DN"][0]) / 100.0
                value = (th - 0.5) * 2.0 * (up if th >= 0.5 else dn)
            qa = np.array([1.0, 0.0, 0.0, 0.0] if mask & AT_ATTITUDE else q, dtype=float)
            given = (mask & AT_RATES) != AT_RATES
            self._guided = _GuidedTarget(qa, value, use_thrust, self.vehicle.time,
                                         rates if given else None, mask & ~AT_THROTTLE)
            self._att_target = (qa, th, rates, mask)
            return None
        elif not mask & AT_THROTTLE:
            self._proof_of_life()  # a throttle-ignoring setpoint is not proof of life
        else:
            self.stats.setpoints_ignored += 1
            self._lockstep_tick()
        self._att_target = (q, thrust, rates, mask)
        if self.mode.behaviour == PP.OFFBOARD and self.vehicle.armed:
            def apply():
                self.vehicle.set_attitude_target(
                    q, thrust, body_rates=None if (mask & AT_RATES) == AT_RATES else rates,
                    type_mask=mask)
            if self.ap.spoolup_holds_attitude_thrust:
                self._when_spooled(apply)
            else:
                self._deferred = None
                apply()
        return None

    def _on_position_target(self, link, msg):
        mask = msg.type_mask
        frames = (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
                  mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)
        if msg.coordinate_frame not in frames:
            return self._reject_setpoint("unsupported frame")
        pos = None if mask & PT_POS else np.array([msg.x, msg.y, msg.z], dtype=float)
        vel = None if mask & PT_VEL else np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        acc = None if mask & PT_ACC else np.array([msg.afx, msg.afy, msg.afz], dtype=float)
        yaw = None if mask & PT_YAW else float(msg.yaw)
        yaw_rate = None if mask & PT_YAW_RATE else float(msg.yaw_rate)
        for name, val in (("position", pos), ("velocity", vel), ("acceleration", acc),
                          ("yaw", yaw), ("yaw rate", yaw_rate)):
            if val is not None and not np.all(np.isfinite(val)):
                return self._reject_setpoint(f"non-finite {name}")
        if pos is None and vel is None and acc is None:
            return self._reject_setpoint("position target ignores everything")
        if pos is not None and np.abs(pos).max() > 1e5:
            return self._reject_setpoint("position out of range")
        r = self._reported()
        if msg.coordinate_frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
            c, s = math.cos(r.euler[2]), math.sin(r.euler[2])
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            vel = None if vel is None else rot @ vel
            acc = None if acc is None else rot @ acc
            if pos is not None:
                pos = r.position + rot @ pos
        elif msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED and pos is not None:
            pos = r.position + pos
        if self.ap.name == "ardupilot" and self.mode.behaviour != PP.OFFBOARD:
            self.stats.setpoints_ignored += 1
            self._lockstep_tick()
            return None
        self._proof_of_life()
        self._guided = None
        if self.mode.behaviour == PP.OFFBOARD and self.vehicle.armed:
            # position control waits for the spool-up (PX4 Takeoff.cpp, ArduCopter's interlock)
            self._when_spooled(lambda: self.vehicle.set_position_target(
                pos=pos, vel=vel, acc=acc, yaw=yaw, yaw_rate=yaw_rate))
        return None

    def _on_set_mode(self, link, msg):
        if msg.target_system not in (0, self.sysid):
            self.stats.other_target += 1
            return
        if self.ap.name == "px4":
            main = (msg.custom_mode >> 16) & 0xFF
            sub = (msg.custom_mode >> 24) & 0xFF
            p = [msg.base_mode, main, sub]
        else:
            p = [msg.base_mode, msg.custom_mode, 0]
        self._set_mode_cmd(p)

    def _on_timesync(self, link, msg):
        """Answer a request (tc1 == 0) with tc1 = the vehicle's own clock in ns since boot, the
        clock of every time_boot_ms it sends (PX4 mavlink_timesync.cpp: hrt_absolute_time();
        ArduPilot GCS_MAVLINK::handle_timesync: micros64 at reception)."""
        if msg.tc1 == 0:
            tc1 = max(1, int(round(self.vehicle.time * 1e9)))  # 0 would read as a request
            link.mav.send(mavlink.MAVLink_timesync_message(tc1, msg.ts1))

    # parameters

    def _encode_param(self, name):
        value, ptype = self.params[name]
        if ptype == PP.INT and self.ap.bytewise_params:
            return struct.unpack("<f", struct.pack("<i", int(value)))[0], ptype
        return float(value), ptype

    def _param_value(self, link, name):
        value, ptype = self._encode_param(name)
        idx = self._param_names.index(name)
        link.mav.send(mavlink.MAVLink_param_value_message(name.encode(), value, ptype,
                                                          len(self._param_names), idx))

    def _on_param_request_list(self, link, msg):
        for name in self._param_names:
            self._param_value(link, name)

    def _on_param_request_read(self, link, msg):
        name = msg.param_id.decode(errors="replace") if isinstance(msg.param_id, bytes) else msg.param_id
        if msg.param_index >= 0:
            if msg.param_index < len(self._param_names):
                self._param_value(link, self._param_names[msg.param_index])
            return
        if name in self.params:
            self._param_value(link, name)

    def _on_param_set(self, link, msg):
        name = msg.param_id.decode(errors="replace") if isinstance(msg.param_id, bytes) else msg.param_id
        if name not in self.params:
            self._statustext_limited("param:" + name, mavlink.MAV_SEVERITY_WARNING,
                                     f"Unknown parameter {name}")
            return
        _, ptype = self.params[name]
        raw = msg.param_value
        if ptype == PP.INT:
            if self.ap.bytewise_params and msg.param_type == PP.INT:
                value = struct.unpack("<i", struct.pack("<f", raw))[0]
            elif math.isfinite(raw):
                value = int(round(raw))
            else:
                value = None
        else:
            value = float(raw) if math.isfinite(raw) else None
        if value is None:
            self._statustext_limited("param:" + name, mavlink.MAV_SEVERITY_WARNING,
                                     f"Parameter {name}: value refused")
        else:
            self.params[name] = (value, ptype)
            if name.startswith("SIM_WIND_"):
                self._update_gcs_wind()
        self._param_value(link, name)

    def _update_gcs_wind(self, announce=True):
        spd = float(self.params["SIM_WIND_SPD"][0])
        direction = float(self.params["SIM_WIND_DIR"][0])
        turb = float(self.params["SIM_WIND_TURB"][0])
        vert = float(self.params["SIM_WIND_DIR_Z"][0])
        parts = []
        if spd > 0.0 or vert != 0.0:
            parts.append(W.ConstantWind(max(spd, 0.0), direction, vertical=vert))
        if turb > 0.0:
            parts.append(W.DrydenTurbulence(w20=turb, seed=self.vehicle.seed))
        extra = W.CompositeWind(parts, seed=self.vehicle.seed) if parts else None
        self.vehicle.wind = W.LayeredWind.over(self._base_wind, extra)
        if announce:
            self.statustext(mavlink.MAV_SEVERITY_INFO,
                            f"Wind {spd:.1f} m/s from {direction:.0f} deg, turbulence {turb:.1f}")

    # missions: an empty list of every type, so ground stations connect cleanly

    def _on_mission_request_list(self, link, msg):
        link.mav.send(mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), 0, getattr(msg, "mission_type", 0)))

    def _on_mission_clear_all(self, link, msg):
        link.mav.send(mavlink.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED,
            getattr(msg, "mission_type", 0)))

    def _on_mission_count(self, link, msg):
        result = mavlink.MAV_MISSION_ACCEPTED if msg.count == 0 else mavlink.MAV_MISSION_UNSUPPORTED
        link.mav.send(mavlink.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), result, getattr(msg, "mission_type", 0)))

    def _on_mission_request(self, link, msg):
        link.mav.send(mavlink.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_INVALID_SEQUENCE,
            getattr(msg, "mission_type", 0)))

    def _on_heartbeat(self, link, msg):
        return None

    def _on_named_value(self, link, msg):
        """Forward a companion's named values to the other links (as PX4's forwarding does), so
        a ground station can plot, e.g., the observers' disturbance estimates live."""
        for other in self.links:
            if other is not link:
                other.mav.send(msg)

    def _on_ftp(self, link, msg):
        """MAVLink FTP is not offered: answer every request with a NAK (file not found), so
        clients that try it first (MAVProxy's parameter download) fall back at once."""
        req = bytes(msg.payload)
        if len(req) < 12:
            return
        seq = (req[0] | (req[1] << 8)) + 1
        nak = bytearray(251)
        nak[0], nak[1] = seq & 0xFF, (seq >> 8) & 0xFF
        nak[2] = req[2]  # session
        nak[3] = 129  # NAK
        nak[4] = 1  # size of the error data
        nak[5] = req[3]  # the request's opcode
        nak[12] = 10  # FileNotFound
        link.mav.send(mavlink.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(),
                                                                     msg.get_srcComponent(),
                                                                     list(nak)))

    _handlers = {
        "COMMAND_LONG": _on_command,
        "COMMAND_INT": _on_command,
        "SET_ATTITUDE_TARGET": _on_attitude_target,
        "SET_POSITION_TARGET_LOCAL_NED": _on_position_target,
        "SET_MODE": _on_set_mode,
        "TIMESYNC": _on_timesync,
        "PARAM_REQUEST_LIST": _on_param_request_list,
        "PARAM_REQUEST_READ": _on_param_request_read,
        "PARAM_SET": _on_param_set,
        "MISSION_REQUEST_LIST": _on_mission_request_list,
        "MISSION_CLEAR_ALL": _on_mission_clear_all,
        "MISSION_COUNT": _on_mission_count,
        "MISSION_REQUEST_INT": _on_mission_request,
        "MISSION_REQUEST": _on_mission_request,
        "HEARTBEAT": _on_heartbeat,
        "FILE_TRANSFER_PROTOCOL": _on_ftp,
        "NAMED_VALUE_FLOAT": _on_named_value,
    }


def _near(x, value):
    return math.isfinite(x) and abs(x - value) < 0.5


@dataclass
class _GuidedTarget:
    """ArduCopter GUIDED's attitude target (mode_guided.cpp guided_angle_state): attitude,
    thrust or climb rate (m/s), which of the two, vehicle time of the update, body rates."""
    q: np.ndarray
    value: float
    use_thrust: bool
    t: float
    rates: list = None
    mask: int = 7
    timed_out: bool = False


def parse_param(ap, name, value):
    """The initial value of parameter ``name`` of personality ``ap`` from a number or its text;
    ValueError for a name the personality does not have or a value its type cannot hold."""
    types = {n: t for n, _, t in ap.params}
    if name not in types:
        raise ValueError(f"unknown parameter {name!r} for the {ap.name} personality "
                         f"(known: {', '.join(sorted(types))})")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"parameter {name}: {value!r} is not a finite number")
    if types[name] == PP.INT:
        if x != int(x):
            raise ValueError(f"parameter {name} is an integer (got {value!r})")
        return int(x)
    return x


def read_signing_key(path):
    """The 32-byte secret from a file holding it as 64 hex characters."""
    with open(path, encoding="ascii") as f:
        text = f.read().strip()
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise ValueError(f"{path}: signing key must be 64 hex characters") from None
    if len(key) != 32:
        raise ValueError(f"{path}: signing key must be 32 bytes (64 hex characters), got {len(key)}")
    return key

