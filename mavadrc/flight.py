"""`mavadrc fly`: fly a mission over MAVLink with the chosen position controller.

One loop, paced by the vehicle's own LOCAL_POSITION_NED stream: each new sample is one control
step, timed by the vehicle (the step is the interval between the samples' ``time_boot_ms``, the
reference is taken at the sample's time), and each step sends exactly one SET_ATTITUDE_TARGET.
That is what makes lockstep work: the bundled vehicle advances one period per setpoint.

Phases (the sequence object of :mod:`mavadrc.sequence` holds what differs between PX4 and
ArduPilot):

1. **connect**: the autopilot's heartbeat names the system flown.
2. **setup**: its identity; who owns it (armed, in the air or in OFFBOARD/GUIDED already means
   another controller does: refused unless ``takeover``); its parameters (hover thrust, the
   motors' start-up delay); the streams, each request confirmed.
3. **measure**: idle setpoints stream (PX4 wants them before OFFBOARD) while the achieved rate
   of the samples is measured over a second.
4. **mode**, **arming**: each command confirmed by its answer and by a heartbeat newer than it
   (a lost answer is settled by the heartbeat).
5. **spoolup**: the motors' delay waited out, thrust ramped; the mission clock starts at the end
   of the ramp, or earlier if the vehicle lifts off.
6. **mission**: the controller flies the trajectory from the ground; until the vehicle has
   lifted off the observers hold no disturbance estimate.
7. **touchdown**: the land segment goes on descending slowly until touchdown is seen (the
   autopilot's ON_GROUND, or vertical speed and height settled), then **cut** thrust and
   **disarming**, which follows the autopilot's landing detector.

Every phase runs under the :class:`~mavadrc.supervisor.Supervisor`: stale telemetry, a bad
link, a limit breached, Ctrl-C, ``--timeout``, an error in the companion, a touchdown, disarm or
landing that takes too long.  Each ends in the autopilot's land mode (after a hold where the
table says so), confirmed and watched until disarmed, or, when the vehicle cannot be reached,
in an exit that says its last known state.  ``summary.json`` is always written.
"""

import collections
import math
import sys
import time
import traceback

import numpy as np

from .console import Console
from .control import PositionController
from .link import TIMEOUT, FlightError, LinkError, M, result_name
from .mission import FINAL_SPEED
from .record import Recorder, attitude_oscillation
from .samples import SampleGate
from .sequence import sequence_for
from .supervisor import GIVE_UP, HOLD_THEN_LAND, LAND, WATCH, Supervisor
from .trajectories import Reference

TRUE_DIST = "TRUE_DIST"
#: lockstep: poll the link this long (s) for the vehicle's answer before sleeping in select
#: (the vehicle answers within a few hundred microseconds; a wake-up from select costs ~50 us)
LOCKSTEP_SPIN_S = 0.002
#: vehicle time (s) over which the achieved sample rate is measured before arming
MEASURE_S = 1.0
#: below this share of the requested rate the flight says so and flies at the rate it gets
RATE_OK = 0.9
#: wall time (s) for a mode or arming change to show in the heartbeat once accepted
CONFIRM_S = 3.0
#: lift-off: this high above the takeoff spot (m), or climbing faster than this (m/s)
LIFTOFF_HEIGHT = 0.05
LIFTOFF_CLIMB = 0.2
#: ... until the vertical speed stays under this (m/s) for this long (s), the reference below
SETTLED_SPEED = 0.1
SETTLED_S = 0.3
#: the heading turns from the vehicle's to the mission's at this rate (rad/s): PX4's
#: MPC_YAWRAUTO_MAX default, 45 deg/s
YAW_RATE = math.radians(45.0)
#: roll/pitch oscillation (deg) worth a warning
OSCILLATION_WARN_DEG = 5.0
#: a failsafe mode command is re-sent this often (s) until the heartbeat shows the mode
RESEND_S = 1.0
#: no heartbeat for this long (s) while landing: the vehicle cannot be reached
UNREACHABLE_S = 10.0
#: the reference is sampled on the control grid in chunks of this many periods
GRID_CHUNK = 2048

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
                    vehicle=None, attitude_controller="px4", rate_hz=None):
    """The position controller of a mission's controller spec.  ``vehicle`` (a bundled vehicle
    name or file) resolves ``input_lag: auto`` by measuring that vehicle's response
    (:func:`sim.vehicle.response_time_constants`); ``rate_hz`` overrides the spec's rate."""
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
    return PositionController(kind, h=1.0 / (rate_hz or spec.rate_hz), tilt_max=math.radians(spec.tilt_max_deg),
                              thrust_min=spec.thrust_min, thrust_max=spec.thrust_max, **thrust,
                              **gains)


SPOOL_S = 0.5  # thrust ramp on the ground before the mission clock starts


def spool_thrust(t, start_at, hover):
    """Normalized thrust of the spool-up: 0.8 hover, reached at vehicle time ``start_at`` after a
    ramp of SPOOL_S (0 before it); ``t`` a time or an array of times."""
    return 0.8 * hover * np.clip((t - (start_at - SPOOL_S)) / SPOOL_S, 0.0, 1.0)


def level_quat(yaw):
    return np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])


def wrap_pi(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def lifted_off(height, vz):
    """Whether a vehicle ``height`` m above its takeoff spot, at vertical speed ``vz`` (NED), has
    left the ground."""
    return height >= LIFTOFF_HEIGHT or vz < -LIFTOFF_CLIMB


def touchdown_reference(start, speed, tau):
    """The descent that continues a land segment ending at rest at ``start`` (NED): it speeds up
    to ``speed`` m/s over 0.5 s and goes on down at that speed; ``tau`` s after its start."""
    ramp = 0.5
    if tau < ramp:
        dz, vz, az = speed * tau * tau / (2.0 * ramp), speed * tau / ramp, speed / ramp
    else:
        dz, vz, az = speed * (tau - 0.5 * ramp), speed, 0.0
    pos = start + np.array([0.0, 0.0, dz])
    return pos, np.array([0.0, 0.0, vz]), np.array([0.0, 0.0, az])



class Flight:
    """One flight of a mission over a :class:`~mavadrc.link.Link`.

    The flight owns the phases; what differs between autopilots is in its
    :class:`~mavadrc.sequence.Sequence`, the safety table in its
    :class:`~mavadrc.supervisor.Supervisor`, the table in its :class:`~mavadrc.record.Recorder`
    and what the user sees in its :class:`~mavadrc.console.Console`.

    ``hover_thrust``: the normalized hover thrust (None: read from the autopilot);
    ``hover_source`` says where a given one came from.  ``takeover``: fly a vehicle another
    controller is flying, from where it is.  ``max_wall_s``: ``--timeout``, over every phase.
    """

    CUT_S = 0.5  # thrust ramp down after touchdown

    def __init__(self, mission, link, record, *, kind=None, hover_thrust=None, progress=True,
                 out=sys.stdout, max_wall_s=None, heartbeat_timeout=15.0, lockstep=False,
                 start_at=None, takeover=False, hover_source=None, bundled=None, watchdog=None):
        self.m = mission
        self.link = link
        self.rec = record
        self.kind = kind or mission.controller.kind
        self.hover = hover_thrust
        self.sources = {}
        if self.hover is not None:
            self.sources["hover_thrust"] = hover_source or "the mission"
        self.console = Console(out, progress)
        self.recorder = Recorder(record, self.kind)
        self.max_wall_s = max_wall_s
        self.heartbeat_timeout = heartbeat_timeout
        self.lockstep = lockstep
        self.takeover = takeover
        self.bundled = bundled  # None: find out from AUTOPILOT_VERSION
        self.watchdog = watchdog  # raises if the vehicle we started died
        if lockstep:
            link.spin_s = LOCKSTEP_SPIN_S
        # vehicle time (s) at which the mission clock starts, the thrust spooled up over the
        # SPOOL_S before it (experiments: every run starts at the same time); None: as soon as
        # the motors are up
        self.start_at = start_at
        # a lockstep vehicle cannot move on without us, so a slow answer (a machine busy
        # compiling) is not a lost link; give it longer before calling telemetry stale
        sf = mission.safety
        self.supervisor = Supervisor(sf, sf.telemetry_timeout_s if not lockstep
                                     else max(5.0, sf.telemetry_timeout_s))
        self.seq = None
        self.texts = []
        self.phase = "connect"
        self.rate = mission.controller.rate_hz  # the rate flown (the achieved one if lower)
        self.h = 1.0 / self.rate
        self.gate = SampleGate(self.h)
        self.last = None  # latest accepted Sample
        self.yaw = 0.0
        self.cos_tilt = 1.0
        self.landed_state = None
        self.landed_state_wall = None
        self.steps = 0
        self.setpoints = 0
        self.samples_seen = 0  # accepted samples, every phase
        self.kicks = 0  # setpoints sent without a sample (a lockstep clock kept going)
        self.double_answers = 0  # samples answered by more than one setpoint (must stay 0)
        self._answered_t = None
        self.latency = []
        self.ages = []
        self.ctrl = None
        self.traj = None
        self.origin = None
        self.mission_start = None
        self.phases = []
        self.motor_delay = 0.0
        self.identity = {}
        self.touchdown_speed = None
        self.touchdown_seen = False
        self.disarm_confirmed = False
        self.warnings = []
        self._t0 = time.monotonic()
        self._deadline = None if max_wall_s is None else self._t0 + max_wall_s
        self._phase_t0 = None  # vehicle time the phase began
        self._phase_wall = self._t0
        self._cmd = None  # the command the phase waits on
        self._cmd_tries = 0
        self._confirm_since = None  # judge state only from heartbeats after this wall time
        self._hb_request_wall = 0.0
        self._held = None  # lockstep: the sample whose answer waits on the vehicle
        self._held_wall = 0.0
        self._last_sample_wall = None
        self._last_send_wall = 0.0
        self._hb_wall = 0.0
        self._kick_wall = 0.0
        self._last_named = -1.0
        self._setpoint = (level_quat(0.0), 0.0)
        self._in_control_seen = False
        self._lifted = False
        self._yaw_offset = 0.0
        self._grid = None
        self._grid_k0 = 0
        self._failsafe = None  # the action in force (supervisor constants)
        self._failsafe_step = None  # "hold" or "land": the mode asked for now
        self._failsafe_wall = 0.0
        self._failsafe_sent = 0.0
        self._hold_point = None
        self._interrupts = 0
        self._exceptions = 0
        self._warned = {}
        self._descent = collections.deque()  # (t, vz) of the last 1.5 s of flight
        self._attitudes = []  # (t, roll, pitch) while the controller flies
        self._settled_since = None
        self._retry_t = None  # vehicle time to ask for the mode again after a refusal
        self._disarm_refused = False
        self._error = None  # why the flight was refused before anything flew
        self._handed_over = False  # the mission ended in the air, as planned
        self.takeover_in_air = False

    # --- reporting -----------------------------------------------------------------------------

    def say(self, text):
        self.console.say(text)

    def on_text(self, severity, text):
        self.texts.append(text)
        self.console.vehicle(text)

    def mode_name(self, custom_mode=None):
        if custom_mode is None:
            custom_mode = self.link.custom_mode
        if custom_mode is None:
            return "unknown mode"
        return self.seq.mode_name(custom_mode) if self.seq is not None else f"{custom_mode:#x}"

    def _warn_once(self, key, text, every=5.0):
        now = time.monotonic()
        if now - self._warned.get(key, -math.inf) >= every:
            self._warned[key] = now
            self.say(f"warning: {text}")
            if text not in self.warnings:
                self.warnings.append(text)

    # --- the run -------------------------------------------------------------------------------

    def run(self):
        """Fly; returns the summary (also written to summary.json, whatever happens)."""
        link = self.link
        link.on_text = self.on_text
        try:
            self._connect()
            self._setup()
            self._loop()
        except KeyboardInterrupt:
            self.supervisor.report("interrupted", "interrupted by the user")
            if self.link.armed:
                self._loop()  # the flight goes on under the supervisor: hold, then land
        except (FlightError, LinkError) as exc:
            self.supervisor.report("refused", str(exc))
            self.summary = self._finish()
            raise
        self.summary = self._finish()
        if self._error is not None:
            raise FlightError(self._error)
        return self.summary

    def _connect(self):
        # the controller (and every kernel of the loop: compiled now, not mid-flight) is made
        # while the vehicle comes up; with the hover thrust still to be read, made again after
        self.ctrl = self._make_controller(self.hover if self.hover is not None else 0.5)
        timeout = self.heartbeat_timeout
        if self._deadline is not None:
            timeout = min(timeout, max(0.0, self._deadline - time.monotonic()))
        waited = [0]

        def idle():
            if self.watchdog is not None:
                self.watchdog()
            waited[0] += 1
            if waited[0] in (3, 10, 30):
                self.say(f"waiting for an autopilot's heartbeat on {self.link.url} "
                         f"({waited[0] - 1} s)")

        hb = self.link.wait_heartbeat(timeout, idle=idle)
        self.seq = sequence_for(self.link.autopilot)
        others = sorted(self.link.systems_heard - {self.link.target_system})
        self.say(f"connected to system {self.link.target_system} ({self.link.autopilot}, "
                 f"{self.mode_name(hb.custom_mode)}) on {self.link.url}"
                 + (f"; also heard system {', '.join(map(str, others))} (--sysid picks one)"
                    if others else ""))

    def _setup(self):
        link = self.link
        self.phase = "setup"
        self._identify()
        self._owner_check()
        if self.hover is None:
            name = self.seq.hover_param
            self.hover = float(link.param_read(name))
            self.sources["hover_thrust"] = f"the vehicle's {name}"
            self.ctrl = self._make_controller(self.hover)
        self.say(f"hover thrust {self.hover:.3f} from {self.sources['hover_thrust']}")
        if self.seq.motor_delay_param is None:
            self.motor_delay = self.seq.motor_delay_default
            self.sources["motor_delay"] = f"{self.seq.name}'s arming delay"
        else:
            self.motor_delay = max(0.0, float(self.read_param(self.seq.motor_delay_param,
                                                              self.seq.motor_delay_default)))
            self.sources["motor_delay"] = self.seq.motor_delay_param
        self._request_streams()
        self.seq.preflight(self)  # before the setpoint stream (and a lockstep clock) starts
        for key in ("angle_boost",):
            if key in self.sources:
                self.say(self.sources[key])
        self.gate.restart(self.h)
        self._enter("measure", None)

    def read_param(self, name, default):
        """A parameter of the vehicle, or ``default`` (said so) when it does not answer."""
        try:
            value = float(self.link.param_read(name))
        except LinkError:
            self.say(f"the vehicle did not answer a read of {name}: using {default:g}")
            return default
        return value

    def _identify(self):
        """AUTOPILOT_VERSION: firmware version, and whether this is the bundled vehicle."""
        result = self.link.command_wait(M.MAV_CMD_REQUEST_MESSAGE,
                                        M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, tries=2)
        end = time.monotonic() + (0.5 if result == M.MAV_RESULT_ACCEPTED else 0.0)
        while "AUTOPILOT_VERSION" not in self.link.messages and time.monotonic() < end:
            self.link.recv(0.02)
        av = self.link.messages.get("AUTOPILOT_VERSION")
        self.identity = {"autopilot": self.link.autopilot, "system_id": self.link.target_system}
        if av is not None:
            v = av.flight_sw_version
            kinds = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}
            self.identity["firmware_version"] = (
                f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF} {kinds.get(v & 0xFF, v & 0xFF)}")
            custom = bytes(av.flight_custom_version).rstrip(b"\0")
            if self.bundled is None:
                self.bundled = custom == b"mavadrc"
        if self.bundled is None:
            self.bundled = False
        self.identity["bundled_vehicle"] = self.bundled

    def _owner_check(self):
        """Armed, in the air or already in the mode that takes setpoints: another controller
        owns the vehicle.  Refused (nothing sent that changes mode, arming or thrust) unless
        takeover."""
        link = self.link
        hb = link.heartbeat
        link.command_wait(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, tries=2)
        end = time.monotonic() + 0.3
        while "EXTENDED_SYS_STATE" not in link.messages and time.monotonic() < end:
            link.recv(0.02)
        ess = link.messages.get("EXTENDED_SYS_STATE")
        in_air = ess is not None and ess.landed_state not in (M.MAV_LANDED_STATE_ON_GROUND,
                                                              M.MAV_LANDED_STATE_UNDEFINED)
        owned = []
        if link.armed:
            owned.append("armed")
        if in_air:
            owned.append("in the air")
        if self.seq.in_control(hb):
            owned.append(f"in {self.mode_name(hb.custom_mode)}")
        self.takeover_in_air = False
        if not owned:
            if self.takeover:
                self.say("--takeover: the vehicle is on the ground and disarmed, flying as usual")
                self.takeover = False
            return
        what = ", ".join(owned)
        if not self.takeover:
            raise FlightError(
                f"system {link.target_system} is {what}: another controller owns it, so mavadrc "
                "sent nothing that changes its mode, arming or thrust; land it first, or give "
                "--takeover to fly it from where it is")
        self.takeover_in_air = link.armed and (in_air or ess is None)
        self.say(f"--takeover: system {link.target_system} is {what}; flying it from where it is")

    def _make_controller(self, hover):
        ctrl = make_controller(self.m.controller, hover_thrust=hover, kind=self.kind,
                               vehicle=self.m.vehicle, attitude_controller=self.m.attitude_controller,
                               rate_hz=self.rate)
        ctrl.reset(np.zeros(3))
        ctrl.update(np.zeros(3), np.zeros(3), np.zeros(3))
        ctrl.reset()
        return ctrl

    def _request_streams(self):
        rate = self.m.controller.rate_hz
        wanted = [(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, rate), (M.MAVLINK_MSG_ID_ATTITUDE, rate),
                  (M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 10.0)]
        if self.bundled and self.seq.debug_vect:
            wanted.append((M.MAVLINK_MSG_ID_DEBUG_VECT, rate))  # the simulator's true disturbance
        for mid in self.seq.unused_streams:
            wanted.append((mid, 0))  # not used: spare the link
        self.streams = {}
        for mid, hz in wanted:
            result = self.link.set_rate(mid, hz)
            name = M.mavlink_map[mid].msgname if mid in M.mavlink_map else str(mid)
            self.streams[name] = result_name(result)
            if result != M.MAV_RESULT_ACCEPTED and hz > 0:
                self.say(f"the vehicle answered {result_name(result)} to {name} at {hz:g} Hz")

    # --- the loop ------------------------------------------------------------------------------

    def _loop(self):
        link = self.link
        while self.phase != "done":
            try:
                msg = link.recv(0.02)
                if msg is not None:
                    self._dispatch(msg)
                self._tick(time.monotonic())
            except KeyboardInterrupt:
                self._interrupts += 1
                if self._interrupts > 1:
                    self._give_up("a second interrupt")
                else:
                    self.say("interrupted: hold, then land (Ctrl-C again to leave the vehicle "
                             "to its autopilot)")
                    self._escalate("interrupted", "interrupted by the user")
            except FlightError as exc:
                self._refused(str(exc))
            except Exception as exc:  # an error of ours never leaves the vehicle unattended
                self._exceptions += 1
                self.rec.note(traceback.format_exc())
                why = f"error in the companion: {type(exc).__name__}: {exc}"
                self.say(why)
                if self._exceptions > 5 or self._failsafe == GIVE_UP:
                    self._give_up("repeated errors in the companion")
                else:
                    self._escalate("exception", why)

    def _refused(self, why):
        """The autopilot refused what the flight needs (a mode, arming): end the flight."""
        self.say(why)
        if not self.link.armed:
            self.supervisor.report("refused", why)
            self.phase = "done"
            self._error = why
            return
        self._escalate("refused", why)

    def _dispatch(self, msg):
        t = msg.get_type()
        if t == "LOCAL_POSITION_NED":
            self.recorder.sample_came()  # whatever of the last sample's attitude and truth came
            s = self.gate.accept(msg.time_boot_ms, (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz))
            if s is None:
                return  # late, repeated or non-finite: dropped and counted
            now = time.monotonic()
            if not self.lockstep:
                s.age = self.link.timesync.age(msg.time_boot_ms)
            self.last = s
            self.samples_seen += 1
            self._last_sample_wall = now
            t_in = time.perf_counter()
            self._on_sample(s)
            if self.phase in ("mission", "touchdown"):  # telemetry in -> setpoint out
                self.latency.append(time.perf_counter() - t_in)
                if s.age is not None:
                    self.ages.append(s.age)
        elif t == "ATTITUDE":
            self.yaw = msg.yaw
            if self.phase in ("mission", "touchdown"):
                self._attitudes.append((msg.time_boot_ms / 1000.0, msg.roll, msg.pitch))
            self.cos_tilt = math.cos(msg.roll) * math.cos(msg.pitch)
            self.recorder.attitude(msg.time_boot_ms, msg.yaw)
        elif t == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
            self.landed_state_wall = time.monotonic()
        elif t == "DEBUG_VECT" and msg.name == TRUE_DIST:
            self.recorder.truth(int(round(msg.time_usec / 1000.0)),
                                np.array([msg.x, msg.y, msg.z]))
        if self._held is not None and not self._awaiting():
            s, self._held = self._held, None
            self._on_sample(s)

    def _send(self, t, q, thrust, kick=False):
        """A setpoint for the sample at vehicle time ``t``, or, ``kick``, one sent without a
        sample (a lockstep clock kept going, the level hover when telemetry stopped)."""
        self._setpoint = (q, thrust)
        self.link.attitude_target(t * 1000.0, q, thrust)
        self.setpoints += 1
        self._last_send_wall = time.monotonic()
        if kick:
            self.kicks += 1
        elif t == self._answered_t:
            self.double_answers += 1  # never: see _on_sample
        else:
            self._answered_t = t

    def _idle(self, s):
        """A level setpoint at zero thrust (the motors at idle): the stream PX4 wants before
        OFFBOARD, harmless to a vehicle on the ground."""
        self._send(s.t, level_quat(self.yaw), 0.0)

    # --- waiting on the vehicle ---------------------------------------------------------------

    def _awaiting(self):
        """Whether the flight waits on an answer of the vehicle (a command's, or a heartbeat
        asked for).  In lockstep the vehicle's clock is held meanwhile, so the flight does not
        depend on how fast the answer travels (same seed, same flight)."""
        if self._cmd is not None and not self._cmd.done:
            return True
        return self._hb_request_wall > 0.0 and self.link.heartbeat_since(self._hb_request_wall) is None

    def _ask_heartbeat(self):
        """Ask for a heartbeat now instead of waiting up to a second for the next (PX4 sends
        them at 1 Hz)."""
        self._hb_request_wall = time.monotonic()
        self.link.request_message(M.MAVLINK_MSG_ID_HEARTBEAT)

    def _fresh(self):
        """The latest heartbeat, if it is newer than the last change the flight asked for."""
        return self.link.heartbeat_since(self._confirm_since)

    # --- phases --------------------------------------------------------------------------------

    def _enter(self, phase, s):
        self.phase = phase
        self._phase_t0 = s.t if s is not None else None
        self._phase_wall = time.monotonic()

    def _on_sample(self, s):
        """Exactly one setpoint per sample (a lockstep vehicle advances one period per
        setpoint: a second one would put every later setpoint a period late)."""
        if self.lockstep and self._awaiting() and self.phase in ("measure", "mode", "arming",
                                                                  "disarming"):
            self._held = s
            self._held_wall = time.monotonic()
            return
        if self._failsafe is not None:
            return self._failsafe_sample(s)
        handler = getattr(self, "_ph_" + self.phase, None)
        if handler is not None:
            handler(s)

    def _ph_measure(self, s):
        if self._phase_t0 is None:
            self._phase_t0 = s.t
            self._start_reference(s)
        if self.takeover_in_air:
            self._control_step(s, None, hold=True)
        else:
            self._idle(s)
        if self.gate.span < MEASURE_S or self.gate.received < 5:
            return
        self._judge_rate()
        self._cmd = self.seq.request_control(self.link)
        self._cmd_tries = 1
        self._enter("mode", s)

    def _judge_rate(self):
        """The rate the samples come at, against the one asked for.  Samples lost on the link
        (gaps in the MAVLink sequence) leave the stream's rate as it is: the steps are timed
        by the vehicle across the gaps.  A vehicle that sends slower than asked is flown at the
        rate it sends, and said so.  Below ``safety.min_rate_hz`` the flight is refused."""
        asked = self.m.controller.rate_hz
        got = self.gate.achieved_rate()
        lost = self.link.frame_loss()
        stream = got / (1.0 - lost) if lost < 0.9 else got
        seen = (f"{got:.1f} Hz reach us: the vehicle sends {stream:.1f} Hz and "
                f"{100 * lost:.0f} % of its frames are lost on the link")
        if got < self.m.safety.min_rate_hz:
            raise FlightError(f"{seen}, where {asked:g} Hz was asked: below safety.min_rate_hz "
                              f"{self.m.safety.min_rate_hz:g}, not flying")
        if stream >= RATE_OK * asked:
            self.sources["rate"] = f"{asked:g} Hz asked, {got:.1f} Hz measured"
            if got < RATE_OK * asked:
                self.sources["rate"] = f"{asked:g} Hz asked; {seen}"
                self.say(f"warning: {seen}: flying at {asked:g} Hz, each step timed by the "
                         "vehicle")
                self.warnings.append(self.sources["rate"])
            return
        self.rate = round(stream, 1)
        self.h = 1.0 / self.rate
        self.ctrl = self._make_controller(self.hover)
        self.gate.restart(self.h)
        self.sources["rate"] = (f"{asked:g} Hz asked; {seen}: flying at {self.rate:g} Hz, each "
                                "step timed by the vehicle")
        self.say(f"warning: the samples come at {stream:.1f} Hz, not the {asked:g} Hz asked "
                 f"({100 * lost:.0f} % lost on the link): flying the controller at "
                 f"{self.rate:g} Hz")
        self.warnings.append(self.sources["rate"])

    def _ph_mode(self, s):
        if self.takeover_in_air:
            self._control_step(s, None, hold=True)
        else:
            self._idle(s)
        c = self._cmd
        if c is not None and c.done:
            self._cmd = None
            if c.accepted or c.result == TIMEOUT:
                # accepted: see it in a heartbeat; no answer: the heartbeat settles it
                self._ask_heartbeat()
                self._confirm_since = c.acked_wall if c.accepted else self._hb_request_wall
                if c.result == TIMEOUT:
                    self.say(f"no answer to the mode change after {c.sent} tries: "
                             "asking the vehicle for its mode")
            elif c.result == M.MAV_RESULT_TEMPORARILY_REJECTED and self._cmd_tries < 5:
                self._cmd_tries += 1  # PX4: the setpoint stream is not seen yet
                self._retry_t = s.t + 0.3
            else:
                raise FlightError(f"the vehicle refused {self.seq.control_mode}: "
                                  f"{result_name(c.result)}{self._because()}")
        if self._retry_t is not None and s.t >= self._retry_t - 1e-9:
            self._retry_t = None
            self._cmd = self.seq.request_control(self.link)
            return
        hb = self._fresh()
        if hb is not None and self.seq.in_control(hb):
            self._in_control_seen = True
            self.say(f"in {self.mode_name(hb.custom_mode)}")
            self._confirm_since = None
            if self.takeover_in_air:
                return self._start_mission(s)
            self._cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            self._enter("arming", s)

    def _ph_arming(self, s):
        self._idle(s)
        c = self._cmd
        if c is not None and c.done:
            self._cmd = None
            if c.accepted or c.result == TIMEOUT:
                self._ask_heartbeat()
                self._confirm_since = c.acked_wall if c.accepted else self._hb_request_wall
                if c.result == TIMEOUT:
                    self.say(f"no answer to the arm command after {c.sent} tries: asking the "
                             "vehicle whether it armed")
            else:
                raise FlightError(f"the vehicle refused to arm: {result_name(c.result)}"
                                  f"{self._because()}")
        hb = self._fresh()
        if hb is not None and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self._confirm_since = None
            if self.takeover:  # armed on the ground already: the motors are up
                self.say("armed: flying from the ground, no spool-up")
                return self._start_mission(s)
            self.say(f"armed; motors start in {self.motor_delay:g} s "
                     f"({self.sources.get('motor_delay', 'default')}), then the spool-up")
            self._enter("spoolup", s)  # from the next sample: one setpoint per sample

    def _because(self):
        """The vehicle's latest words, if any came in the last seconds."""
        return f" ({self.texts[-1]})" if self.texts else ""

    def _ph_spoolup(self, s):
        self._spool(s)

    def _spool(self, s):
        t_arm = self._phase_t0
        motors = t_arm + self.motor_delay
        end = self.start_at if self.start_at is not None else motors + SPOOL_S
        if self.start_at is not None and motors > self.start_at - SPOOL_S + 1e-9:
            raise FlightError(f"armed at {t_arm:.3f} s with a {self.motor_delay:g} s motor delay:"
                              f" too late to start the mission at {self.start_at:.3f} s")
        self._send(s.t, level_quat(self.yaw), float(spool_thrust(s.t, end, self.hover)))
        if s.t >= end - 1e-9 or lifted_off(self.origin[2] - s.pos[2], s.vel[2]):
            self._start_mission(s)  # the controller flies from the next sample

    def _start_reference(self, s):
        """The mission's frame: from the takeoff spot, or, taking over in the air, as if the
        takeoff had just ended here."""
        self.origin = s.pos.copy()
        if self.takeover_in_air:
            alt = self.m.segments[0][1]["altitude"]
            self.origin[2] += alt
        self.traj, self.phases = self.m.build_trajectory(self.origin,
                                                         in_air=self.takeover_in_air)

    def _start_mission(self, s):
        if not self.takeover_in_air:  # taking over, the controller already holds the vehicle
            self.ctrl.reset(s.pos)
        self._grid = None
        self._mission_t0 = s.t
        self.mission_start = s.t
        self._lifted = self.takeover_in_air
        self._yaw_offset = wrap_pi(self.yaw - float(self.traj.sample(0.0).yaw))
        self.gate.restart(self.h)
        self.say(f"flying {self.m.name!r} with {self.kind} at {self.rate:g} Hz "
                 f"({self.traj.duration:.1f} s)")
        self._enter("mission", s)

    def _reference(self, t):
        """The reference at mission time ``t``: on the control grid (computed a chunk at a time:
        a vehicle whose clock ticks on the period reads it from there), or sampled exactly off
        it (as :func:`mavadrc.inprocess._references` does)."""
        h = self.h
        k = int(round(t / h))
        grid_n = int(self.traj.duration / h) + 2
        if abs(t - k * h) < 1e-7 and 0 <= k < grid_n:
            if self._grid is None or not self._grid_k0 <= k < self._grid_k0 + GRID_CHUNK:
                self._grid_k0 = k
                self._grid = self.traj.sample_many(np.arange(k, min(k + GRID_CHUNK, grid_n)) * h)
            pos, vel, acc, yaw, yaw_rate = self._grid
            i = k - self._grid_k0
            return Reference(pos[i], vel[i], acc[i], float(yaw[i]), float(yaw_rate[i]))
        return self.traj.sample(t)

    def _control_step(self, s, r, hold=False):
        """One control step on sample ``s`` towards reference ``r`` (``hold``: stay where the
        reference was when the hold began); sends the setpoint, returns (q, thrust)."""
        if hold:
            if self._hold_point is None:
                self._hold_point = s.pos.copy()
                if self.phase in ("measure", "mode"):
                    self.ctrl.reset(s.pos, s.vel)
            z3 = np.zeros(3)
            q, thrust = self.ctrl.update(s.pos, s.vel, self._hold_point, z3, z3, self.yaw,
                                         dt=s.dt)
        else:
            q, thrust = self.ctrl.update(s.pos, s.vel, r.pos, r.vel, r.acc, r.yaw, dt=s.dt)
        self._send(s.t, q, thrust * self.seq.thrust_factor(self))
        return q, thrust

    def _ph_mission(self, s):
        self._mission_step(s)

    def _mission_step(self, s):
        if self._left_control():
            return
        t = s.t - self._mission_t0
        r = self._reference(t)
        if self._yaw_offset != 0.0:
            step = YAW_RATE * (s.dt if s.dt is not None else self.h)
            self._yaw_offset -= max(-step, min(step, self._yaw_offset))
            r = Reference(r.pos, r.vel, r.acc, r.yaw + self._yaw_offset, r.yaw_rate)
        q, thrust = self._control_step(s, r)
        self._descent_history(s)
        if not self._lifted:
            if lifted_off(self.origin[2] - s.pos[2], s.vel[2]):
                self._lifted = True
            else:
                self.ctrl.hold_disturbance()  # on the ground: the ground's push is no disturbance
        self.steps += 1
        self.recorder.step(t, self._segment_name(t), r, s, self.ctrl, q, thrust)
        self._named_values(s)
        self._check_link()
        why = self.supervisor.breach(s, self.origin)
        if why is not None:
            return self._escalate("breach", why)
        if t >= self.traj.duration:
            if not self.m.ends_landed:
                # the mission ends in the air (an experiment run): the autopilot lands it
                self.say("mission complete in the air: handing over to the autopilot's land mode")
                self._handed_over = True
                return self._start_failsafe(LAND)
            self._descent_from = r.pos.copy()
            self._final_yaw = r.yaw
            self._enter("touchdown", s)
            self.say("land segment done: descending until touchdown is seen")
            return
        self.console.progress(self._segment_name(t), t, self.traj.duration,
                              float(np.linalg.norm(s.pos - r.pos)), self._link_line)

    def _link_line(self):
        loss = self.gate.recent_loss()
        rtt = self.link.timesync.rtts[-1] if self.link.timesync.rtts else None
        return (f"{self.gate.achieved_rate():.0f} Hz, lost {100 * loss:.1f} %"
                + (f", rtt {1e3 * rtt:.1f} ms" if rtt is not None and not self.lockstep else ""))

    def _check_link(self):
        why = self.supervisor.link(self.gate)
        if why is not None:
            return self._escalate("link", why)
        warn = self.supervisor.link_warning(self.gate)
        if warn is not None:
            self._warn_once("link", warn)

    def _left_control(self):
        """The pilot or a failsafe took the vehicle: stop commanding, watch it land.  Judged only
        from a heartbeat newer than the mode the flight confirmed."""
        hb = self.link.heartbeat
        if not self._in_control_seen or hb is None or self.seq.in_control(hb):
            return False
        self._escalate("left_control",
                       f"the vehicle left {self.seq.control_mode} for {self.mode_name()}")
        return True

    def _ph_touchdown(self, s):
        if self._left_control():
            return
        tau = s.t - self._phase_t0
        speed = min(FINAL_SPEED, self._land_speed())
        pos, vel, acc = touchdown_reference(self._descent_from, speed, tau)
        r = Reference(pos, vel, acc, self._final_yaw, 0.0)
        t = s.t - self._mission_t0
        q, thrust = self._control_step(s, r)
        self.recorder.step(t, "touchdown", r, s, self.ctrl, q, thrust, scored=False)
        self._descent_history(s)
        # settled: hardly moving vertically while the reference goes on down below it
        settled = abs(s.vel[2]) < SETTLED_SPEED and pos[2] > s.pos[2] + 0.05
        if settled:
            if self._settled_since is None:
                self._settled_since = s.t
        else:
            self._settled_since = None
        ground = self.landed_state == M.MAV_LANDED_STATE_ON_GROUND and \
            self.landed_state_wall is not None and self.landed_state_wall > self._phase_wall
        if ground or (self._settled_since is not None and s.t - self._settled_since >= SETTLED_S):
            # the touchdown speed: the fastest descent in the second before it settled
            t_settled = self._settled_since if self._settled_since is not None else s.t
            self.touchdown_speed = max([0.0] + [vz for tt, vz in self._descent
                                                if t_settled - 1.0 <= tt <= t_settled])
            self.touchdown_seen = True
            self.ctrl.hold_disturbance()
            self._cut_from = thrust
            self.say(f"touchdown at {self.touchdown_speed:.2f} m/s "
                     f"({'the autopilot says on the ground' if ground else 'settled'})")
            if self.touchdown_speed > self.m.safety.max_touchdown_speed:
                text = (f"a hard touchdown: {self.touchdown_speed:.2f} m/s, above "
                        f"safety.max_touchdown_speed {self.m.safety.max_touchdown_speed:g}")
                self.say(f"warning: {text}")
                self.warnings.append(text)
            self._enter("cut", s)
            return
        bound = 5.0 + max(0.0, self.origin[2] - self._descent_from[2] + 1.0) / speed
        if tau > bound:
            self._escalate("touchdown_timeout",
                           f"touchdown not seen {bound:.0f} s into the final descent")

    def _descent_history(self, s):
        self._descent.append((s.t, float(s.vel[2])))
        while self._descent[0][0] < s.t - 1.5:
            self._descent.popleft()

    def _land_speed(self):
        kind, spec, _ = self.m.segments[-1]
        return float(spec.get("speed", 0.5)) if kind == "land" else 0.5

    def _ph_cut(self, s):
        k = max(0.0, 1.0 - (s.t - self._phase_t0) / self.CUT_S)
        self._send(s.t, level_quat(self.yaw), self._cut_from * k)
        if k <= 0.0:
            self._enter("disarming", s)

    def _ph_disarming(self, s):
        self._send(s.t, level_quat(self.yaw), 0.0)

    def _disarm_tick(self, now):
        """After touchdown and the thrust cut, disarm as the autopilot's landing detector
        allows: PX4, once it says ON_GROUND (a refusal waits for it; PX4 also disarms itself
        COM_DISARM_LAND s after landing); ArduPilot, through its land mode
        (:attr:`~mavadrc.sequence.Sequence.land_to_disarm`).  Bounded at 15 s."""
        since = now - self._phase_wall
        if self._confirm_since is None:
            self._confirm_since = self._phase_wall  # ask for heartbeats until one shows it
        hb = self.link.heartbeat_since(self._phase_wall)
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self.disarm_confirmed = True
            self._confirm_since = None
            self.say("disarmed")
            if self.seq.in_control(hb):
                self.link.wait(self.seq.release(self.link))
            self.phase = "done"
            return
        c = self._cmd
        if self.seq.land_to_disarm:
            if c is None or (c.done and not c.accepted and now - c.acked_wall > 1.0):
                if c is None:
                    self.say(f"on the ground: {self.seq.name}'s land mode disarms it")
                self._cmd = self.link.command(M.MAV_CMD_NAV_LAND)
        elif c is None:
            ground = self.landed_state == M.MAV_LANDED_STATE_ON_GROUND
            if ground or since > 3.0 or "EXTENDED_SYS_STATE" not in self.link.messages:
                self._cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif c.done:
            if not c.accepted and c.result != TIMEOUT and not self._disarm_refused:
                self._disarm_refused = True
                self.say(f"disarm refused ({result_name(c.result)}){self._because()}: waiting "
                         "for the autopilot's landing detector")
            if now - c.acked_wall > 1.0:
                self._cmd = None  # ask again
        if since > 15.0:
            self._escalate("disarm_timeout", "the vehicle did not disarm within 15 s of touchdown")

    # --- failsafes -------------------------------------------------------------------------------

    def _escalate(self, condition, why):
        action = self.supervisor.report(condition, why)
        if action is None:
            return
        if action == GIVE_UP:
            return self._give_up(why)
        if self.phase in ("setup", "measure", "mode", "arming") or (
                self.phase == "spoolup" and not self.link.armed):
            # nothing in the air: a vehicle on the ground is disarmed, not landed
            return self._ground_abort(why)
        self.say(f"{why}: {'watching the autopilot land' if action == WATCH else 'landing' if action == LAND else 'hold, then land'}")
        self._start_failsafe(action)

    def _ground_abort(self, why):
        """Before lift-off: disarm if armed (confirmed), and end."""
        self.say(f"{why}: stopping on the ground")
        self._failsafe = LAND
        self._failsafe_step = "disarm"
        self._failsafe_wall = time.monotonic()
        if not self.link.armed:
            self.phase = "done"

    def _start_failsafe(self, action):
        self._failsafe = action
        self._failsafe_wall = time.monotonic()
        self._failsafe_sent = 0.0
        self._hold_point = None
        if self.phase in ("spoolup",) and not self._lifted:
            self._failsafe_step = "disarm"
        elif action == HOLD_THEN_LAND:
            self._failsafe_step = "hold"
        elif action == LAND:
            self._failsafe_step = "land"
        else:
            self._failsafe_step = "watch"
        self.phase = "failsafe"
        self._failsafe_command(time.monotonic())

    def _failsafe_command(self, now):
        """(Re-)send the mode the failsafe asks for until a heartbeat newer than it shows it."""
        step = self._failsafe_step
        if step == "watch":
            return
        if now - self._failsafe_sent < RESEND_S:
            return
        hb = self.link.heartbeat_since(self._failsafe_sent) if self._failsafe_sent else None
        if step == "hold" and hb is not None and (self.seq.is_hold(hb) or self.seq.is_landing(hb)):
            if now - self._failsafe_wall >= 2.0:
                self._failsafe_step = "land"
                self._failsafe_sent = 0.0
                return self._failsafe_command(now)
            return
        if step == "land" and hb is not None and self.seq.is_landing(hb):
            self._failsafe_step = "watch"
            self.say(f"the autopilot is in {self.mode_name(hb.custom_mode)}: watching it land")
            return
        if step == "disarm" and hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self.phase = "done"
            return
        self._failsafe_sent = now
        if step == "hold":
            self.seq.request_hold(self.link)
        elif step == "land":
            self.link.command(M.MAV_CMD_NAV_LAND)
        elif step == "disarm":
            self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        self._ask_heartbeat()

    def _failsafe_sample(self, s):
        """While the failsafe's mode is not yet confirmed, keep the vehicle where it is with our
        own controller (it is still in our mode); once it is, the autopilot flies."""
        hb = self.link.heartbeat
        ours = hb is not None and self.seq.in_control(hb)
        if self._failsafe_step == "disarm":
            self._idle(s)
        elif ours and self._failsafe != WATCH and self.phase == "failsafe" and \
                self.traj is not None and self.mission_start is not None:
            self._control_step(s, None, hold=True)
        elif self.lockstep:
            self._send(s.t, level_quat(self.yaw), self._setpoint[1])  # the clock must go on
        self._failsafe_disarmed()

    def _failsafe_tick(self, now):
        self._failsafe_command(now)
        hb_age = now - self.link.heartbeat_wall if self.link.heartbeat_wall else math.inf
        if hb_age > UNREACHABLE_S:
            return self._escalate("unreachable",
                                  f"no heartbeat for {hb_age:.0f} s: the vehicle cannot be reached")
        if self.phase == "done":
            return
        bound = self._landing_bound()
        if now - self._failsafe_wall > bound:
            self._escalate("landing_timeout",
                           f"the vehicle has not disarmed {bound:.0f} s after the failsafe began")
        if self._deadline is not None and now > self._deadline + bound:
            self._give_up(f"--timeout ({self.max_wall_s:g} s) and the landing bound passed")
        self._failsafe_disarmed()

    def _failsafe_disarmed(self):
        """A heartbeat newer than the failsafe shows the vehicle disarmed: the flight is over."""
        hb = self.link.heartbeat_since(self._failsafe_wall)
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED \
                and self.phase != "done":
            self.disarm_confirmed = True
            self.say("disarmed" + ("" if self._handed_over else f"; {self.last_known()}"))
            self.phase = "done"

    def _landing_bound(self):
        """How long the autopilot may take to land and disarm: from the height, at 0.4 m/s
        (PX4 lands at 0.7, ArduCopter at 0.5), plus 30 s for the detector and the return."""
        height = 0.0
        if self.last is not None and self.origin is not None:
            height = max(0.0, self.origin[2] - self.last.pos[2])
        return 30.0 + height / 0.4

    def _give_up(self, why):
        self.supervisor.report("unreachable" if "reach" in why else "landing_timeout", why)
        self._failsafe = GIVE_UP
        self.say(f"{why}: giving up; last known: {self.last_known()}")
        self.phase = "done"

    def last_known(self):
        """The vehicle's last known state, in a line: "armed, AUTO.LAND, 1.4 m, 3.2 s ago"."""
        now = time.monotonic()
        parts = []
        if self.link.heartbeat is not None:
            parts.append("armed" if self.link.armed else "disarmed")
            parts.append(self.mode_name())
        if self.last is not None and self.origin is not None:
            parts.append(f"{self.origin[2] - self.last.pos[2]:.1f} m up")
        if self._last_sample_wall is not None:
            parts.append(f"{now - self._last_sample_wall:.1f} s ago")
        return ", ".join(parts) if parts else "nothing heard"

    # --- the wall clock ----------------------------------------------------------------------------

    def _tick(self, now):
        """Wall-clock duties: heartbeat and time sync out, commands re-sent, stale telemetry,
        the deadline, the failsafe's progress, and lockstep kicks."""
        link = self.link
        if now - self._hb_wall >= 1.0:
            self._hb_wall = now
            link.send_heartbeat()
        link.timesync_poll(now)
        for c in list(link.commands.values()):
            c.poll(now)
        if self._held is not None and now - self._held_wall > 1.0:
            s, self._held = self._held, None  # no answer within a second: go on regardless
            self._on_sample(s)
        if self._failsafe is not None:
            return self._failsafe_tick(now)
        if self._deadline is not None and now > self._deadline:
            self._escalate("timeout", f"the flight took longer than --timeout "
                                      f"{self.max_wall_s:g} s")
            return
        if self.phase == "disarming":
            self._disarm_tick(now)
        if self._confirm_since is not None and now - self._hb_request_wall > 0.5:
            self._ask_heartbeat()  # the heartbeat asked for still shows the old state
        if self.phase in ("mode", "arming") and now - self._phase_wall > CONFIRM_S + 3.0:
            hb = link.heartbeat
            raise FlightError(f"{'the mode change' if self.phase == 'mode' else 'arming'} was "
                              f"not confirmed within {CONFIRM_S + 3.0:g} s (the vehicle is "
                              f"{'armed' if link.armed else 'disarmed'}, "
                              f"{self.mode_name(hb.custom_mode) if hb else 'unknown mode'})")
        if self._last_sample_wall is None:
            if self.phase == "measure" and now - self._phase_wall > 5.0:
                raise FlightError("no LOCAL_POSITION_NED from the vehicle within 5 s: does it "
                                  "have a position estimate?")
        elif self.phase in ("spoolup", "mission", "touchdown", "cut"):
            why = self.supervisor.stale(now, self._last_sample_wall, self._last_send_wall)
            if why is not None:
                # level hover on the hover thrust, then the autopilot's land mode
                self._send(self.last.t, level_quat(self.yaw), self.hover if self._lifted else 0.0,
                           kick=True)
                self._escalate("stale", why)
                return
        if self.lockstep and self.phase in ("measure", "mode", "arming", "disarming") and \
                self._held is None and (self._last_sample_wall is None
                                        or now - self._last_sample_wall > 2.0):
            # no telemetry while waiting on the vehicle: an idle setpoint now and then keeps a
            # lockstep vehicle's clock going
            if now - self._kick_wall >= 2.0:
                self._kick_wall = now
                self._send(0.0 if self.last is None else self.last.t, level_quat(self.yaw), 0.0,
                           kick=True)

    # --- records -------------------------------------------------------------------------------

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

    def _finish(self):
        self.recorder.flush()
        hb = self.link.heartbeat
        disarmed = hb is not None and not self.link.armed
        soft = self.touchdown_speed is None or \
            self.touchdown_speed <= self.m.safety.max_touchdown_speed
        landed = (self.touchdown_seen or self._handed_over) and self.disarm_confirmed and soft
        aborted = list(self.supervisor.reasons)
        rtts = np.asarray(self.link.timesync.rtts) * 1e3
        link = self.gate.figures()
        link.update({
            "rtt_ms_median": float(np.median(rtts)) if rtts.size else None,
            "rtt_ms_max": float(rtts.max()) if rtts.size else None,
            "sample_age_ms_median": float(np.median(self.ages) * 1e3) if self.ages else None,
            "sample_age_ms_p99": float(np.percentile(self.ages, 99) * 1e3) if self.ages else None,
            "frames_received": self.link.frames_received,
            "frames_lost": self.link.frames_lost,
            "frame_loss_fraction": self.link.frame_loss(),
            "bad_frames": self.link.bad_frames,
            "bad_signatures": self.link.bad_signatures,
            "other_system_messages": self.link.other_system,
        })
        summary = {
            "controller": self.kind,
            "mission": self.m.name,
            "mission_file": self.m.source,
            "autopilot": self.link.autopilot,
            "vehicle": self.identity,
            "duration_s": self.recorder.duration,
            "landed": bool(landed and not aborted),
            "touchdown_seen": self.touchdown_seen,
            "touchdown_speed_mps": self.touchdown_speed,
            "touchdown_soft": soft,
            "disarmed": bool(disarmed),
            "aborted": aborted,
            "last_known_state": self.last_known(),
            "samples": self.gate.received,
            "control_steps": self.steps,
            "setpoints_sent": self.setpoints,
            "samples_seen": self.samples_seen,
            "setpoints_without_sample": self.kicks,
            "samples_answered_twice": self.double_answers,
            "missed_periods": self.gate.missing,
            "link": link,
            "streams": getattr(self, "streams", {}),
            "rate_requested_hz": self.m.controller.rate_hz,
            "rate_hz": self.rate,
            "settle_s": self.m.settle_s,
            "mission_start_s": self.mission_start,
            "hover_thrust": self.hover,
            "motor_delay_s": self.motor_delay,
            "takeover": self.takeover,
            "sources": dict(self.sources),
            "warnings": list(self.warnings),
            "vehicle_messages": self.texts[-50:],
        }
        if self._attitudes:
            a = np.asarray(self._attitudes)
            osc = attitude_oscillation(a[:, 0], a[:, 1], a[:, 2])
            summary["attitude_oscillation"] = osc
            if osc is not None and osc["amplitude_deg"] > OSCILLATION_WARN_DEG:
                text = (f"roll/pitch swung +-{osc['amplitude_deg']:.0f} deg at "
                        f"{osc['frequency_hz']:.2f} Hz: a limit cycle, whatever the error says "
                        "(the controller is too fast for this vehicle's attitude response)")
                self.say(f"warning: {text}")
                summary["warnings"].append(text)
        if self.latency:
            lat = np.asarray(self.latency) * 1e3
            summary["latency_p50_ms"] = float(np.percentile(lat, 50))
            summary["latency_p99_ms"] = float(np.percentile(lat, 99))
        summary.update(self.recorder.errors())
        if self.m.settle_s > 0:
            summary["after_settle"] = self.recorder.errors(self.m.settle_s)
        self.rec.write_summary(summary)
        return summary

def print_table(summary, out=sys.stdout):
    rms, mx = summary["rms_error_xyz_m"], summary["max_error_xyz_m"]
    if summary["rms_error_m"] is None:
        out.write("\n  no control step was flown: no error figures\n")
        out.flush()
        return
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

