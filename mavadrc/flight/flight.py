"""`mavadrc fly`: fly a mission over MAVLink with the chosen position controller.

One loop, paced by the vehicle's own LOCAL_POSITION_NED stream: each new sample is one control
step, timed by the vehicle (the step is the interval between the samples' ``time_boot_ms``, the
reference is taken at the sample's time), and each step sends exactly one SET_ATTITUDE_TARGET.
That is what makes lockstep work: the bundled vehicle advances one period per setpoint.

Phases (the sequence object of :mod:`mavadrc.mavlink.sequence` holds what differs between PX4 and
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
   lifted off the vertical observer holds no disturbance estimate.
7. **touchdown**: the land segment goes on descending slowly until touchdown is seen (the
   autopilot's ON_GROUND, or vertical speed and height settled), then **cut** thrust and
   **disarming**, which follows the autopilot's landing detector.

Each phase is an object of its own, handed what it uses: :mod:`~mavadrc.flight.preflight` (1-3),
:mod:`~mavadrc.flight.arming` (4), :mod:`~mavadrc.flight.takeoff` (5),
:mod:`~mavadrc.flight.mission_step` (6, with :mod:`~mavadrc.flight.steering`, the control step, and
:mod:`~mavadrc.flight.identification`), :mod:`~mavadrc.flight.landing` (7); the supervisor's
actions in :mod:`~mavadrc.flight.failsafe`.  What they share is in :mod:`~mavadrc.flight.state`;
this module holds the loop and the wall clock's duties.

Every phase runs under the :class:`~mavadrc.flight.supervisor.Supervisor`: stale telemetry, a bad
link, a limit breached, Ctrl-C, ``--timeout``, an error in the companion, a touchdown, disarm or
landing that takes too long.  Each ends in the autopilot's land mode (after a hold where the
table says so), confirmed and watched until disarmed, or, when the vehicle cannot be reached,
in an exit that says its last known state.  ``summary.json`` is always written.
"""
import gc
import sys
import time
import traceback

from mavadrc.control.rotations import level_quat
from mavadrc.design.identify import needs_identification
from mavadrc.errors import FlightError, LinkError
from mavadrc.flight.arming import Arming
from mavadrc.flight.choice import ControllerChoice
from mavadrc.flight.confirm import Confirm
from mavadrc.flight.console import Console, Terminated, interrupt_reason
from mavadrc.flight.failsafe import Failsafe
from mavadrc.flight.identification import Identification
from mavadrc.flight.landing import Landing
from mavadrc.flight.mission_step import MissionStep
from mavadrc.flight.notices import Notices
from mavadrc.flight.preflight import Preflight
from mavadrc.flight.receive import Receive
from mavadrc.flight.record import Recorder
from mavadrc.flight.setpoints import Setpoints
from mavadrc.flight.state import PhaseClock, Progress, Tracks, Vehicle, vehicle_mode
from mavadrc.flight.steering import Steering
from mavadrc.flight.summary import Summary
from mavadrc.flight.supervisor import GIVE_UP, Supervisor
from mavadrc.flight.takeoff import Takeoff
from mavadrc.mavlink.samples import SampleGate

#: lockstep: the least telemetry timeout (s); the vehicle waits on us, so a machine busy
#: elsewhere slows the answer without any link being lost
LOCKSTEP_STALE_S = 5.0
#: wall time (s) for a mode or arming change to show in the heartbeat once accepted
CONFIRM_S = 3.0
#: wall time (s) from connecting to the first LOCAL_POSITION_NED before the flight gives up on
#: the vehicle's estimate; in lockstep the bundled vehicle (on the ground, disarmed) first loads
#: its compiled kernels, which took past 5 s on a machine busy elsewhere
FIRST_SAMPLE_S = 5.0
FIRST_SAMPLE_LOCKSTEP_S = 30.0


def _freeze_heap():
    """Collect the heap once and move what survives (the modules, numba's and scipy's state,
    the mission: several hundred thousand objects) out of the collector's sight, before the
    flight's loop begins.  A full collection walks every object the collector tracks; over
    that heap it stopped the loop for 99-141 ms on the shared 2-core machine, once or twice a
    flight (on PX4 SIH the samples' age rose to 0.1 s each time).  Frozen, a collection walks only
    what the flight made since.  Returns whether it froze it (not where the caller's heap was
    frozen already: that is the caller's to undo); :meth:`Flight.run` then unfreezes it when
    the flight ends."""
    if gc.get_freeze_count():
        return False
    gc.collect()
    gc.freeze()
    return True


class Flight:
    """One flight of a mission over a :class:`~mavadrc.mavlink.link.Link`.

    The flight runs the loop and hands each sample to its phase; what differs between
    autopilots is in its :class:`~mavadrc.mavlink.sequence.Sequence`, the safety table in its
    :class:`~mavadrc.flight.supervisor.Supervisor`, the table in its
    :class:`~mavadrc.flight.record.Recorder` and what the user sees in its
    :class:`~mavadrc.flight.console.Console`.

    ``hover_thrust``: the normalized hover thrust (None: read from the autopilot);
    ``hover_source`` says where a given one came from.  ``takeover``: fly a vehicle another
    controller is flying, from where it is.  ``max_wall_s``: ``--timeout``, over every phase.
    ``design_lag``: the lags the mission's own gains were chosen for
    (:func:`mavadrc.fast.identify.flight_design_lag`, found by the caller before the flight).
    """

    def __init__(self, mission, link, record, *, kind=None, hover_thrust=None, progress=True,
                 out=sys.stdout, max_wall_s=None, heartbeat_timeout=15.0, lockstep=False,
                 start_at=None, takeover=False, hover_source=None, bundled=None, watchdog=None,
                 design_lag=None):
        kind = kind or mission.controller.kind
        if needs_identification(mission.controller, kind):
            mission = mission.with_identification()
        self.m = mission
        self.link = link
        self.rec = record
        self.kind = kind
        self.lockstep = lockstep
        self.max_wall_s = max_wall_s
        self.hung_up_at = None  # mission time of a SIGHUP (the terminal gone): flown on
        self.context = {}  # what the caller adds to the record (command line, versions, ...)
        self.summary = None
        self._t0 = time.monotonic()
        self._deadline = None if max_wall_s is None else self._t0 + max_wall_s
        # a lockstep vehicle cannot move on without us, so a slow answer (a machine busy
        # compiling) is not a lost link; give it longer before calling telemetry stale
        sf = mission.safety
        self.supervisor = Supervisor(sf, sf.telemetry_timeout_s if not lockstep
                                     else max(LOCKSTEP_STALE_S, sf.telemetry_timeout_s))
        self.recorder = Recorder(record, kind)
        self.notices = Notices(Console(out, progress, fallback=record.note))
        self.clock = PhaseClock()
        self.v = Vehicle(takeover, bundled)
        if hover_thrust is not None:
            self.v.sources["hover_thrust"] = hover_source or "the mission"
        self.progress = Progress(mission)
        self.tracks = Tracks()
        self.choice = ControllerChoice(mission, kind, mission.controller.rate_hz, hover_thrust,
                                       design_lag)
        self.gate = SampleGate(self.choice.h)
        self.setpoints = Setpoints(link, self.v, native=kind == "native")
        self.confirm = Confirm(link, self.notices)
        self.steering = Steering(mission, self.choice, self.progress, self.v, self.setpoints,
                                 self.clock, lockstep)
        self.ident = Identification(self.choice, self.notices, link, self.progress, lockstep)
        self.failsafe = Failsafe(self.supervisor, link, self.clock, self.v, self.progress,
                                 self.notices, self.setpoints, self.steering, self.confirm,
                                 lockstep=lockstep, deadline=self._deadline,
                                 max_wall_s=max_wall_s)
        self.takeoff = Takeoff(mission, self.clock, self.v, self.progress, self.notices,
                               self.setpoints, self.steering, self.choice, self.ident, self.gate,
                               self.tracks, start_at)
        self.landing = Landing(mission, link, self.clock, self.v, self.progress, self.notices,
                               self.setpoints, self.steering, self.recorder, self.choice,
                               self.confirm, self.failsafe)
        self.mission = MissionStep(mission, link, self.clock, self.v, self.progress,
                                   self.notices, self.steering, self.choice, self.ident,
                                   self.takeoff, self.landing, self.failsafe, self.recorder,
                                   self.supervisor, self.gate, lockstep)
        self.preflight = Preflight(mission, link, record, self.clock, self.v, self.notices,
                                   self.choice, self.ident, self.confirm, self.setpoints,
                                   self.steering, self.takeoff, self.gate, self.tracks,
                                   lockstep=lockstep, heartbeat_timeout=heartbeat_timeout,
                                   deadline=self._deadline, watchdog=watchdog)
        self.arming = Arming(link, self.clock, self.v, self.notices, self.confirm,
                             self.setpoints, self.steering, self.takeoff)
        self.receive = Receive(mission, link, self.clock, self.v, self.progress, self.notices,
                               self.choice, self.ident, self.tracks, self.recorder, self.gate,
                               self.supervisor, self.failsafe, self.on_sample, lockstep)
        #: each phase's handler of a sample (the phases without one wait on the wall clock)
        self.phase_table = {
            "measure": self.preflight.measure_phase,
            "mode": self.arming.mode_phase,
            "arming": self.arming.arming_phase,
            "spoolup": self.takeoff.spool_phase,
            "mission": self.mission.step,
            "touchdown": self.landing.touchdown_phase,
            "cut": self.landing.cut_phase,
            "disarming": self.landing.disarming_phase,
        }
        self._held = None  # lockstep: the sample whose answer waits on the vehicle
        self._held_wall = 0.0
        self._hb_wall = 0.0
        self._kick_wall = 0.0
        self._interrupts = 0
        self._exceptions = 0
        self._error = None  # why the flight was refused before anything flew

    @property
    def phase(self):
        return self.clock.phase

    @property
    def ctrl(self):
        """The controller flown now."""
        return self.choice.ctrl

    def say(self, text):
        self.notices.say(text)

    def hung_up(self):
        """SIGHUP: the terminal the companion was started from is gone (an SSH session lost).
        The flight goes on; the console, if it was that terminal, fails and goes quiet."""
        if self.hung_up_at is None:
            self.hung_up_at = round(float(self.recorder.duration or 0.0), 3)
            self.rec.note(f"SIGHUP at {self.hung_up_at:.1f} s (mission time): the terminal hung "
                          "up; the flight goes on, what the console cannot say is written here")

    # --- the run -------------------------------------------------------------------------------

    def run(self):
        """Fly; returns the summary (also written to summary.json, whatever happens)."""
        self.link.on_text = self.notices.on_text
        frozen = False
        try:
            try:
                self.preflight.connect()
                self.preflight.setup()
                frozen = _freeze_heap()
                self._loop()
            except KeyboardInterrupt as exc:
                self.supervisor.report("interrupted", interrupt_reason(exc))
                if self.link.armed:
                    self._loop()  # the flight goes on under the supervisor: hold, then land
            except (FlightError, LinkError) as exc:
                self.supervisor.report("refused", str(exc))
                self.summary = Summary(self).write()
                raise
        finally:
            if frozen:
                gc.unfreeze()
            if self.ident.fitter is not None:
                self.ident.fitter.close()
            self.notices.console.close()  # the live line off the terminal
        self.summary = Summary(self).write()
        if self._error is not None:
            raise FlightError(self._error)
        return self.summary

    def _release_refused(self):
        """Refused while arming, the vehicle sits disarmed in the mode we put it in: out of it,
        as at a flight's end (:meth:`Failsafe.end_disarmed`).  Left there, PX4 SIH refused the
        next flight's companion as 'another controller owns it'."""
        if self.clock.phase != "arming" or self.link.armed:
            return
        try:
            self.link.wait(self.v.seq.release(self.link))
        except (LinkError, OSError):
            pass

    def _loop(self):
        link, failsafe = self.link, self.failsafe
        while self.clock.phase != "done":
            try:
                msg = link.recv(0.02)
                if msg is not None:
                    self._dispatch(msg)
                self._tick(time.monotonic())
            except KeyboardInterrupt as exc:
                self._interrupts += 1
                if self._interrupts > 1:
                    failsafe.give_up("a second interrupt")
                else:
                    again = exc.signame if isinstance(exc, Terminated) else "Ctrl-C"
                    failsafe.escalate("interrupted", interrupt_reason(exc),
                                      hint=f"{again} again to leave the vehicle to its autopilot")
            except FlightError as exc:
                self._refused(str(exc))
            except Exception as exc:  # an error of ours never leaves the vehicle unattended
                self._exceptions += 1
                self.rec.note(traceback.format_exc())
                why = f"error in the companion: {type(exc).__name__}: {exc}"
                self.say(why)
                if self._exceptions > 5 or failsafe.action == GIVE_UP:
                    failsafe.give_up("repeated errors in the companion")
                else:
                    failsafe.escalate("exception", why)

    def _refused(self, why):
        """The autopilot refused what the flight needs (a mode, arming): end the flight."""
        self.say(why)
        if not self.link.armed:
            self.supervisor.report("refused", why)
            self._release_refused()
            self.clock.phase = "done"
            self._error = why
            return
        self.failsafe.escalate("refused", why)

    def _dispatch(self, msg):
        self.receive.message(msg)
        if self._held is not None and not self.confirm.awaiting():
            s, self._held = self._held, None
            self.on_sample(s)

    def on_sample(self, s):
        """Exactly one setpoint per sample (a lockstep vehicle advances one period per
        setpoint: a second one would put every later setpoint a period late)."""
        phase = self.clock.phase
        if self.lockstep and self.confirm.awaiting() and phase in ("measure", "mode", "arming",
                                                                   "disarming"):
            self._held = s
            self._held_wall = time.monotonic()
            return
        if self.failsafe.action is not None:
            return self.failsafe.sample(s)
        handler = self.phase_table.get(phase)
        if handler is not None:
            handler(s)

    # --- the wall clock ----------------------------------------------------------------------------

    def _tick(self, now):
        """Wall-clock duties: heartbeat and time sync out, commands re-sent, stale telemetry,
        the deadline, the failsafe's progress, and lockstep kicks."""
        link, v, clock, confirm = self.link, self.v, self.clock, self.confirm
        if self.rec.lost is not None and "record" not in self.notices.warned:
            self.notices.warn_once("record", f"the record stopped being written ({self.rec.lost}):"
                                   " the flight goes on without it", every=float("inf"))
        if now - self._hb_wall >= 1.0:
            self._hb_wall = now
            link.send_heartbeat()
        link.timesync_poll(now)
        for c in list(link.commands.values()):
            c.poll(now)
        if self._held is not None and now - self._held_wall > 1.0:
            s, self._held = self._held, None  # no answer within a second: go on regardless
            self.on_sample(s)
        if self.failsafe.action is not None:
            return self.failsafe.tick(now)
        if self._deadline is not None and now > self._deadline:
            self.failsafe.escalate("timeout", f"the flight took longer than --timeout "
                                              f"{self.max_wall_s:g} s")
            return
        if clock.phase == "disarming":
            self.landing.disarm_tick(now)
        if confirm.since is not None and now - confirm.hb_request_wall > 0.5:
            confirm.ask_heartbeat()  # the heartbeat asked for still shows the old state
        if clock.phase in ("mode", "arming") and now - clock.wall > CONFIRM_S + 3.0:
            hb = link.heartbeat
            raise FlightError(f"{'the mode change' if clock.phase == 'mode' else 'arming'} was "
                              f"not confirmed within {CONFIRM_S + 3.0:g} s (the vehicle is "
                              f"{'armed' if link.armed else 'disarmed'}, "
                              f"{vehicle_mode(link, hb.custom_mode) if hb else 'unknown mode'})")
        if v.last_sample_wall is None:
            limit = FIRST_SAMPLE_LOCKSTEP_S if self.lockstep else FIRST_SAMPLE_S
            if clock.phase == "measure" and now - clock.wall > limit:
                raise FlightError(f"no LOCAL_POSITION_NED from the vehicle within {limit:g} s: "
                                  "does it have a position estimate?")
        elif clock.phase in ("spoolup", "mission", "touchdown", "cut"):
            why = self.supervisor.stale(now, v.last_sample_wall,
                                        max(self.setpoints.last_wall, v.handled_wall))
            if why is not None:
                # level hover on the hover thrust, then the autopilot's land mode
                self.setpoints.send(v.last.t, level_quat(v.yaw),
                                    self.choice.hover if self.progress.lifted else 0.0, kick=True)
                self.failsafe.escalate("stale", why)
                return
        if self.lockstep and clock.phase in ("measure", "mode", "arming", "disarming") and \
                self._held is None and (v.last_sample_wall is None
                                        or now - v.last_sample_wall > 2.0):
            # no telemetry while waiting on the vehicle: an idle setpoint now and then keeps a
            # lockstep vehicle's clock going
            if now - self._kick_wall >= 2.0:
                self._kick_wall = now
                self.setpoints.send(0.0 if v.last is None else v.last.t, level_quat(v.yaw), 0.0,
                                    kick=True)
