"""`mavadrc fly`: fly a mission over MAVLink with the chosen position controller.

One loop, paced by the vehicle's own LOCAL_POSITION_NED stream: each new sample is one control
step (the reference is taken at the vehicle's time_boot_ms), and each step sends exactly one
SET_ATTITUDE_TARGET.  That is what makes lockstep work: the bundled vehicle advances one period
per setpoint.

Sequence.  PX4: stream idle setpoints, OFFBOARD, arm.  ArduPilot: GUIDED_NOGPS (thrust must mean
thrust: GUID_OPTIONS bit 3), arm.  Then spool up on the ground, fly the mission from the ground
(takeoff and landing are part of the trajectory), cut thrust on touchdown and disarm.

Safety.  Stale telemetry: level-hover setpoints, then the autopilot's land mode.  Geofence,
altitude or speed breach: land mode.  Ctrl-C: hold, then land mode, and wait for the landing.
Non-finite setpoints are never sent.  Tilt and thrust limits are applied in the position
controller, whose observers are fed the limited commands.
"""

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from .console import Console
from .control import PositionController
from .link import FlightError, M, result_name
from .record import Recorder
from .sequence import sequence_for
from .supervisor import Supervisor
from .trajectories import Reference

TRUE_DIST = "TRUE_DIST"
#: lockstep: poll the link this long (s) for the vehicle's answer before sleeping in select
#: (the vehicle answers within a few hundred microseconds; a wake-up from select costs ~50 us)
LOCKSTEP_SPIN_S = 0.002


@dataclass
class Sample:
    t: float  # vehicle time, s
    pos: np.ndarray
    vel: np.ndarray


def default_gains(kind):
    """Position-loop gains that suit the bundled vehicles (per axis x, y, z)."""
    if kind == "ladrc":
        return {"wc": (2.5, 2.5, 3.0), "wo": (12.5, 12.5, 15.0)}
    if kind == "adrc":
        # The mission's trajectory comes with exact derivatives, so the TD (which would add lag
        # to a moving reference) is off unless the mission asks for it (td: true).
        return {"td": False, "wc": (2.5, 2.5, 3.0), "wo": (12.0, 12.0, 15.0), "r": (8.0, 8.0, 8.0),
                "c": (1.0, 1.0, 1.0), "delta": (0.05, 0.05, 0.05)}
    if kind == "pid":
        # the PD default's bandwidth plus an integrator (channels.pid_gains): kp_pos = wc/2,
        # kp_vel = 2 wc, ki_vel = wc^2/2, no D, i.e. kp_pos (1.25, 1.25, 1.5) /s, kp_vel
        # (5, 5, 6) /s, ki_vel (3.125, 3.125, 4.5) /s^2; integrator authority 3 m/s^2
        return {"wc": (2.5, 2.5, 3.0), "i_limit": (3.0, 3.0, 3.0)}
    return {"wc": (2.5, 2.5, 3.0)}


def make_controller(spec, hover_thrust=None, mass=None, max_thrust=None, kind=None,
                    vehicle=None, attitude_controller="px4"):
    """The position controller of a mission's controller spec.  ``vehicle`` (a bundled vehicle
    name or file) resolves ``input_lag: auto`` by measuring that vehicle's response
    (:func:`sim.vehicle.response_time_constants`)."""
    kind = kind or spec.kind
    gains = default_gains(kind)  # the mission's gains, where given, override these
    if kind == spec.kind:
        gains.update(spec.gains)
    if gains.get("input_lag") == "auto":
        if vehicle is None:
            raise FlightError("input_lag: auto needs the mission's vehicle file (vehicle: NAME); "
                              "otherwise give the lags in seconds")
        from sim.vehicle import response_time_constants
        tau_xy, tau_z = response_time_constants(vehicle, attitude_controller)
        gains["input_lag"] = (tau_xy, tau_xy, tau_z)
    if kind == "pd" and "kp" in gains and "wc" in gains:
        gains.pop("wc")
    # pid: wc gives every gain (channels.pid_gains); kp_pos, kp_vel, ki_vel, kd_vel given by the
    # mission replace those one by one, so PX4-style gains can be given in full or in part
    if kind == "adrc":
        # bandwidth shorthand: NLSEF fhan(e1, c e2, r, h1) is linear near zero with kp = 1/h1^2,
        # kd = 2c/h1, so h1 = 1/wc; the NLESO gains are those of a triple pole at -wo in fal's
        # linear zone (|e| < delta)
        wc = gains.pop("wc", None)
        if wc is not None:
            gains.setdefault("h1", tuple(1.0 / w for w in wc))
        wo = gains.pop("wo", None)
        if wo is not None:
            gains.setdefault("beta", tuple((3.0 * w, 3.0 * w * w, w ** 3) for w in wo))
    accel_max = gains.pop("accel_max", None)
    if accel_max is not None:
        gains["u_min"] = tuple(-a for a in accel_max)
        gains["u_max"] = tuple(accel_max)
    thrust = {"hover_thrust": hover_thrust} if hover_thrust is not None else \
        {"mass": mass, "max_thrust": max_thrust}
    return PositionController(kind, h=1.0 / spec.rate_hz, tilt_max=math.radians(spec.tilt_max_deg),
                              thrust_min=spec.thrust_min, thrust_max=spec.thrust_max, **thrust,
                              **gains)


SPOOL_S = 0.5  # thrust ramp on the ground before the mission clock starts


def spool_thrust(t, start_at, hover):
    """Normalized thrust of the spool-up: 0.8 hover, reached at vehicle time ``start_at`` after a
    ramp of SPOOL_S (0 before it); ``t`` a time or an array of times."""
    return 0.8 * hover * np.clip((t - (start_at - SPOOL_S)) / SPOOL_S, 0.0, 1.0)


def level_quat(yaw):
    return np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])


class Flight:
    """One flight of a mission over a :class:`~mavadrc.link.Link`.

    The flight owns the phases; what differs between autopilots is in its
    :class:`~mavadrc.sequence.Sequence`, the safety checks in its
    :class:`~mavadrc.supervisor.Supervisor`, the table in its :class:`~mavadrc.record.Recorder`
    and what the user sees in its :class:`~mavadrc.console.Console`.
    """

    CUT_S = 0.5  # thrust ramp down after touchdown

    def __init__(self, mission, link, record, *, kind=None, hover_thrust=None, progress=True,
                 out=sys.stdout, max_wall_s=None, heartbeat_timeout=15.0, lockstep=False,
                 start_at=None):
        self.m = mission
        self.link = link
        self.kind = kind or mission.controller.kind
        self.hover = hover_thrust if hover_thrust is not None else mission.hover_thrust
        self.console = Console(out, progress)
        self.recorder = Recorder(record, self.kind)
        self.max_wall_s = max_wall_s
        self.heartbeat_timeout = heartbeat_timeout
        self.lockstep = lockstep
        if lockstep:
            link.spin_s = LOCKSTEP_SPIN_S
        # vehicle time (s) at which the mission clock starts, the thrust spooled up over the
        # SPOOL_S before it (experiments: every run starts at the same time); None: at once
        self.start_at = start_at
        self._held = False
        # a lockstep vehicle cannot move on without us, so a slow answer (a machine busy
        # compiling) is not a lost link; give it longer before calling telemetry stale
        self.supervisor = Supervisor(mission.safety, mission.safety.telemetry_timeout_s
                                     if not lockstep else max(5.0, mission.safety.telemetry_timeout_s))
        self.seq = None
        self.texts = []
        self.phase = "connect"
        self.last = None  # latest Sample
        self.yaw = 0.0
        self.landed_state = None
        self.reason = None
        self.samples = 0
        self.missed = 0
        self.steps = 0
        self.setpoints = 0
        self.latency = []
        self.ctrl = None
        self.traj = None
        self.mission_start = None
        self.phases = []
        self._phase_t0 = None
        self._last_named = -1.0
        self._last_sample_wall = None
        self._setpoint = (level_quat(0.0), 0.0)
        # wall-clock marks (time.monotonic) of the periodic sends
        self._hb_wall = self._kick_wall = self._last_send_wall = 0.0
        self._hover_wall = 0.0
        self._land_cmd_wall = self._cmd_sent_wall = 0.0
        self._tries = 0

    # --- reporting -----------------------------------------------------------------------------

    def say(self, text):
        self.console.say(text)

    def on_text(self, severity, text):
        self.texts.append(text)
        self.console.vehicle(text)

    # --- the loop ------------------------------------------------------------------------------

    def run(self):
        link = self.link
        link.on_text = self.on_text
        # the controller (and every kernel of the loop: compiled now, not mid-flight) is made
        # while the vehicle comes up; with the hover thrust still to be read, made again after
        hover_known = self.hover is not None
        self.ctrl = self._make_controller(self.hover if hover_known else 0.5)
        hb = link.wait_heartbeat(self.heartbeat_timeout)
        self.seq = sequence_for(link.autopilot)
        self.say(f"connected to system {link.target_system} ({link.autopilot}, "
                 f"mode {hb.custom_mode:#x}) on {link.url}")
        if not hover_known:
            name = self.seq.hover_param
            self.hover = float(link.param_read(name))
            self.say(f"hover thrust {self.hover:.3f} from the vehicle's {name}")
            self.ctrl = self._make_controller(self.hover)
        self.h = 1.0 / self.m.controller.rate_hz
        self._request_streams()
        self.seq.preflight(self)  # before the setpoint stream (and a lockstep clock) starts
        wall0 = time.monotonic()
        self.phase = "prearm"
        try:
            while self.phase != "done":
                msg = link.recv(0.02)
                if msg is not None:
                    self._dispatch(msg)
                self._watch(time.monotonic())
                if self.max_wall_s is not None and time.monotonic() - wall0 > self.max_wall_s \
                        and self.phase != "landing":
                    self._abort_land(f"the flight took longer than {self.max_wall_s:.0f} s")
        except FlightError as exc:
            # the record is still completed; the vehicle is left in (or sent to) a safe mode
            self.reason = str(exc)
            if self.link.armed:
                self._abort_land(str(exc))
            self.summary = self._finish()
            raise
        except KeyboardInterrupt:
            self.say("interrupted: hold, then land")
            self._abort_land("interrupted by the user", hold_first=True)
            try:
                self._wait_landed()
            except KeyboardInterrupt:
                self.say("second interrupt: leaving the vehicle in its land mode")
        return self._finish()

    def _make_controller(self, hover):
        ctrl = make_controller(self.m.controller, hover_thrust=hover, kind=self.kind,
                               vehicle=self.m.vehicle, attitude_controller=self.m.attitude_controller)
        ctrl.reset(np.zeros(3))
        ctrl.update(np.zeros(3), np.zeros(3), np.zeros(3))
        ctrl.reset()
        return ctrl

    def _request_streams(self):
        rate = self.m.controller.rate_hz
        L = self.link
        L.set_rate(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, rate)
        L.set_rate(M.MAVLINK_MSG_ID_ATTITUDE, rate)
        L.set_rate(M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 5)
        L.set_rate(M.MAVLINK_MSG_ID_DEBUG_VECT, rate)  # the bundled vehicle's true disturbance
        for mid in (M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                    M.MAVLINK_MSG_ID_ODOMETRY):
            L.set_rate(mid, 0)  # not used: spare the link

    def _dispatch(self, msg):
        t = msg.get_type()
        if t == "LOCAL_POSITION_NED":
            self.recorder.sample_came()  # whatever of the last sample's attitude and truth came
            s = Sample(msg.time_boot_ms / 1000.0, np.array([msg.x, msg.y, msg.z]),
                       np.array([msg.vx, msg.vy, msg.vz]))
            if self.last is not None and s.t <= self.last.t:
                return  # a repeat or an old sample
            if self.last is not None and s.t - self.last.t > 2.5 * self.h \
                    and self.phase in ("mission", "touchdown"):
                self.missed += int(round((s.t - self.last.t) / self.h)) - 1
            self.last = s
            self.samples += 1
            self._last_sample_wall = time.monotonic()
            t_in = time.perf_counter()
            self._step(s)
            if self.phase in ("mission", "touchdown"):  # telemetry in -> setpoint out
                self.latency.append(time.perf_counter() - t_in)
        elif t == "ATTITUDE":
            self.yaw = msg.yaw
            self.recorder.attitude(msg.time_boot_ms, msg.yaw)
        elif t == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
        elif t == "COMMAND_ACK" and self._held and self.last is not None:
            self._held = False
            self._step(self.last)
        elif t == "DEBUG_VECT" and msg.name == TRUE_DIST:
            self.recorder.truth(int(round(msg.time_usec / 1000.0)),
                                np.array([msg.x, msg.y, msg.z]))

    def _send(self, t, q, thrust):
        self._setpoint = (q, thrust)
        self.link.attitude_target(t * 1000.0, q, thrust)
        self.setpoints += 1
        self._last_send_wall = time.monotonic()

    # --- phases --------------------------------------------------------------------------------

    AWAITED = {"mode": M.MAV_CMD_DO_SET_MODE, "arming": M.MAV_CMD_COMPONENT_ARM_DISARM,
               "disarming": M.MAV_CMD_COMPONENT_ARM_DISARM}

    def _step(self, s):
        ph = self.phase
        if self.lockstep and ph in self.AWAITED and self.AWAITED[ph] not in self.link.acks:
            # lockstep: the vehicle's clock stands still until the command is answered, so the
            # flight does not depend on how fast the answer travels (same seed, same flight)
            self._held = True
            return
        if ph in ("prearm", "mode", "arming", "disarming", "landing"):
            self._send(s.t, level_quat(self.yaw), 0.0 if ph != "landing" else self._setpoint[1])
            if ph == "prearm":
                self._prearm(s)
            elif ph == "mode":
                self._mode(s)
            elif ph == "arming":
                self._arming(s)
            elif ph == "disarming":
                self._disarming(s)
            elif ph == "landing":
                self._landing(s)
        elif ph == "spoolup":
            # the ramp ends at start_at, or SPOOL_S after arming when no start time is set
            start_at = self.start_at if self.start_at is not None else self._phase_t0 + SPOOL_S
            if self._phase_t0 > start_at - SPOOL_S + 1e-9:
                raise FlightError(f"armed at {self._phase_t0:.3f} s, too late to start the "
                                  f"mission at {self.start_at:.3f} s")
            self._send(s.t, level_quat(self.yaw), float(spool_thrust(s.t, start_at, self.hover)))
            if s.t >= start_at - 1e-9:
                self._start_mission(s)
        elif ph == "mission":
            self._mission_step(s)
        elif ph == "touchdown":
            k = max(0.0, 1.0 - (s.t - self._phase_t0) / self.CUT_S)
            self._send(s.t, level_quat(self.yaw), self._cut_from * k)
            on_ground = self.landed_state == M.MAV_LANDED_STATE_ON_GROUND
            if k <= 0.0 and (on_ground or s.t - self._phase_t0 > self.CUT_S + 3.0):
                self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
                self._enter("disarming", s)

    def _enter(self, phase, s):
        self.phase = phase
        self._phase_t0 = s.t if s is not None else None
        self._cmd_sent_wall = time.monotonic()
        self._tries = 0

    def _prearm(self, s):
        if self._phase_t0 is None:
            self._phase_t0 = s.t
            self.origin = s.pos.copy()
            self.traj, self.phases = self.m.build_trajectory(self.origin)
            return
        if s.t - self._phase_t0 < 0.3:  # setpoints must be streaming before OFFBOARD
            return
        self.seq.request_control(self.link)
        self._enter("mode", s)

    def _retry(self, resend, what):
        ack_wait = 1.0
        if time.monotonic() - self._cmd_sent_wall > ack_wait:
            self._tries += 1
            if self._tries >= 3:
                raise FlightError(f"{what}: no answer from the vehicle after 3 tries")
            self._cmd_sent_wall = time.monotonic()
            resend()

    def _mode(self, s):
        ack = self.link.acks.get(M.MAV_CMD_DO_SET_MODE)
        if ack is None:
            return self._retry(lambda: self.seq.request_control(self.link), "mode change")
        if ack.result == M.MAV_RESULT_ACCEPTED:
            self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            return self._enter("arming", s)
        if ack.result == M.MAV_RESULT_TEMPORARILY_REJECTED and self._tries < 3:
            self._tries += 1
            self.link.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
            self._cmd_sent_wall = time.monotonic()
            return self.seq.request_control(self.link)
        raise FlightError(f"the vehicle refused {self.seq.control_mode}: {result_name(ack.result)}")

    def _arming(self, s):
        ack = self.link.acks.get(M.MAV_CMD_COMPONENT_ARM_DISARM)
        if ack is None:
            return self._retry(lambda: self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1), "arming")
        if ack.result != M.MAV_RESULT_ACCEPTED:
            raise FlightError(f"the vehicle refused to arm: {result_name(ack.result)}"
                              + (f" ({self.texts[-1]})" if self.texts else ""))
        self.say("armed; spooling up")
        self._enter("spoolup", s)

    def _start_mission(self, s):
        # the reference at every control period, computed once: a vehicle whose clock ticks on
        # the period (the bundled one) reads it from here; other times are sampled exactly
        n = int(self.traj.duration / self.h) + 2
        self._grid = self.traj.sample_many(np.arange(n) * self.h)
        self.ctrl.reset(s.pos)
        self._mission_t0 = s.t
        self.mission_start = s.t
        self.say(f"flying {self.m.name!r} with {self.kind} ({self.traj.duration:.1f} s)")
        self._enter("mission", s)

    def _reference(self, t):
        k = int(round(t / self.h))
        pos, vel, acc, yaw, yaw_rate = self._grid
        if abs(t - k * self.h) < 1e-7 and k < len(yaw):
            return Reference(pos[k], vel[k], acc[k], float(yaw[k]), float(yaw_rate[k]))
        return self.traj.sample(t)

    def _in_control(self):
        """Whether the autopilot is still in the mode that takes our setpoints."""
        hb = self.link.heartbeat
        return hb is None or self.seq.in_control(hb)

    def _mission_step(self, s):
        if not self._in_control():
            # the pilot or a failsafe took the vehicle: stop commanding, let the autopilot land
            self.reason = f"the vehicle left offboard control (mode {self.link.custom_mode:#x})"
            self.say(self.reason + "; waiting for it to land")
            self._land_cmd_wall = time.monotonic()
            self.phase = "landing"
            return
        t = s.t - self._mission_t0
        r = self._reference(t)
        q, thrust = self.ctrl.update(s.pos, s.vel, r.pos, r.vel, r.acc, r.yaw)
        self._send(s.t, q, thrust)
        self.steps += 1
        self.recorder.step(t, self._segment_name(t), r, s, self.ctrl, q, thrust)
        self._named_values(s)
        if self._breach(s):
            return
        if t >= self.traj.duration:
            if not self.m.ends_landed:
                # the mission ends in the air (an experiment run): the autopilot lands it
                self.say("mission complete in the air: handing over to the autopilot's land mode")
                self._land_mode()
                return
            self._cut_from = thrust
            self._enter("touchdown", s)
        self.console.progress(self._segment_name(t), t, self.traj.duration,
                              float(np.linalg.norm(s.pos - r.pos)))

    def _named_values(self, s):
        """The observers' disturbance estimates at 10 Hz, live, for a ground station."""
        if self.kind != "pd" and s.t - self._last_named >= 0.1:
            self._last_named = s.t
            z3 = self.ctrl.disturbance
            for i, a in enumerate("xyz"):
                self.link.named_float(s.t * 1000.0, f"z3_{a}", float(z3[i]))

    def _segment_name(self, t):
        name = self.phases[0][1] if self.phases else ""
        for t0, n in self.phases:
            if t >= t0:
                name = n
        return name

    def _breach(self, s):
        why = self.supervisor.breach(s, self.origin)
        if why is None:
            return False
        self._abort_land(why)
        return True

    def _abort_land(self, why, hold_first=False):
        """Hand the vehicle to the autopilot's land mode (after a hold, if asked)."""
        self.reason = why
        self.say(f"{why}: landing")
        if hold_first:
            self.seq.request_hold(self.link)
        self._land_mode()

    def _land_mode(self):
        self.link.command(M.MAV_CMD_NAV_LAND)
        self._land_cmd_wall = time.monotonic()
        self.phase = "landing"

    def _landing(self, s):
        if not self.link.armed and self.link.heartbeat is not None:
            self.phase = "done"

    def _disarming(self, s):
        ack = self.link.acks.get(M.MAV_CMD_COMPONENT_ARM_DISARM)
        if not self.link.armed:
            self.phase = "done"
        elif ack is not None and ack.result != M.MAV_RESULT_ACCEPTED:
            self._abort_land(f"disarm refused ({result_name(ack.result)})")
        elif ack is None:
            self._retry(lambda: self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0), "disarm")

    def _wait_landed(self, timeout=120.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end and self.phase != "done":
            msg = self.link.recv(0.05)
            if msg is not None:
                self._dispatch(msg)
            self._watch(time.monotonic())

    def _watch(self, now):
        """Wall-clock checks: heartbeat out, stale telemetry."""
        if now - self._hb_wall >= 1.0:
            self._hb_wall = now
            self.link.send_heartbeat()
        waiting = self.phase in ("prearm", "mode", "arming", "disarming")
        quiet = 0.2 if not self.lockstep else (2.0 if self._last_sample_wall is not None else 0.0)
        if self._held and now - self._cmd_sent_wall > 1.0:  # unanswered: ask again
            self._tries += 1
            if self._tries >= 3:
                raise FlightError(f"{self.phase}: no answer from the vehicle after 3 tries")
            self._cmd_sent_wall = now
            if self.phase == "mode":
                self.seq.request_control(self.link)
            else:
                self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM,
                                  1 if self.phase == "arming" else 0)
        if waiting and not self._held and (self._last_sample_wall is None
                                           or now - self._last_sample_wall > quiet):
            # no fresh telemetry while waiting on the vehicle: an idle setpoint now and then
            # keeps a lockstep vehicle's clock going (a real autopilot ignores it outside
            # offboard, and streams telemetry regardless)
            if now - self._kick_wall >= (0.1 if not self.lockstep else 2.0):
                self._kick_wall = now
                self._send(0.0 if self.last is None else self.last.t, level_quat(self.yaw), 0.0)
            if self.phase == "prearm":
                return
        if self.phase == "done" or self._last_sample_wall is None:
            return
        stale = self.supervisor.stale_for(now, self._last_sample_wall, self._last_send_wall)
        if stale <= 0.0:
            return
        if self.phase in ("mission", "spoolup", "touchdown"):
            # level hover on the last known thrust, then the autopilot's land mode
            self.say(f"telemetry stale for {stale + self.supervisor.telemetry_timeout:.2f} s: "
                     "level hover, then land")
            self._send(self.last.t, level_quat(self.yaw), self.hover)
            self._abort_land("telemetry lost")
        elif self.phase == "landing" and now - self._last_sample_wall > max(
                5.0, 10.0 * self.supervisor.telemetry_timeout):
            self.say("no telemetry since the land command: the vehicle is in its own land mode")
            self.reason = self.reason or "telemetry lost"
            self.phase = "done"
            return
        if self.phase == "landing" and now - self._land_cmd_wall > 120.0:
            self.say("the vehicle has not disarmed 120 s after the land command; leaving it landing")
            self.phase = "done"
            return
        if self.phase == "landing":
            if now - self._hover_wall >= self.h:
                self._hover_wall = now
                self._send(self.last.t, level_quat(self.yaw), self.hover)

    def _finish(self):
        self.recorder.flush()
        summary = {
            "controller": self.kind,
            "mission": self.m.name,
            "mission_file": self.m.source,
            "autopilot": self.link.autopilot,
            "duration_s": self.recorder.duration,
            "landed": (not self.link.armed) and self.reason is None,
            "disarmed": not self.link.armed,
            "aborted": self.reason,
            "samples": self.samples,
            "control_steps": self.steps,
            "setpoints_sent": self.setpoints,
            "missed_periods": self.missed,
            "rate_hz": self.m.controller.rate_hz,
            "settle_s": self.m.settle_s,
            "mission_start_s": self.mission_start,
            "hover_thrust": self.hover,
            "vehicle_messages": self.texts[-50:],
        }
        if self.latency:
            lat = np.asarray(self.latency) * 1e3
            summary["latency_p50_ms"] = float(np.percentile(lat, 50))
            summary["latency_p99_ms"] = float(np.percentile(lat, 99))
        summary.update(self.recorder.errors())
        if self.m.settle_s > 0:
            summary["after_settle"] = self.recorder.errors(self.m.settle_s)
        self.recorder.rec.write_summary(summary)
        return summary


def print_table(summary, out=sys.stdout):
    rms, mx = summary["rms_error_xyz_m"], summary["max_error_xyz_m"]
    out.write("\n  position error (m)      x        y        z       3-D\n")
    out.write(f"  RMS               {rms[0]:8.4f} {rms[1]:8.4f} {rms[2]:8.4f} "
              f"{summary['rms_error_m']:9.4f}\n")
    out.write(f"  max               {mx[0]:8.4f} {mx[1]:8.4f} {mx[2]:8.4f} "
              f"{summary['max_error_m']:9.4f}\n")
    if "after_settle" in summary:
        a = summary["after_settle"]
        out.write(f"  after {summary['settle_s']:.0f} s: RMS {a['rms_error_m']:.4f}, "
                  f"max {a['max_error_m']:.4f}\n")
    out.flush()

