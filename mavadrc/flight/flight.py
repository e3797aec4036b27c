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

The phases live in :mod:`mavadrc.flight.preflight` (1-3), :mod:`mavadrc.flight.ground` (4-5, 7) and this
module (6, the control step); the supervisor's actions in :mod:`mavadrc.flight.failsafe`.

Every phase runs under the :class:`~mavadrc.flight.supervisor.Supervisor`: stale telemetry, a bad
link, a limit breached, Ctrl-C, ``--timeout``, an error in the companion, a touchdown, disarm or
landing that takes too long.  Each ends in the autopilot's land mode (after a hold where the
table says so), confirmed and watched until disarmed, or, when the vehicle cannot be reached,
in an exit that says its last known state.  ``summary.json`` is always written.
"""

import collections
import gc
import math
import sys
import time
import traceback

import numpy as np

from mavadrc.flight.console import Console, Terminated, interrupt_reason
from mavadrc.control.geometry import GRAVITY, thrust_for_tilt
from mavadrc.control.rotations import level_quat
from mavadrc.flight.failsafe import Failsafes
from mavadrc.flight.ground import CARRIED_SHARE, CARRIED_THRUST_MARGIN, SETTLED_S, GroundPhases, landing_tilt
from mavadrc.mission.takeoff import LIFTOFF_HEIGHT, TAKEOFF_RAMP_PER_S, TAKEOFF_WAIT_M, TAKEOFF_WAIT_MAX_S, lifted_off
from mavadrc.control.learn import DragLearner
from mavadrc.errors import FlightError
from mavadrc.mavlink.dialect import M
from mavadrc.mavlink.errors import LinkError
from mavadrc.flight.preflight import Preflight
from mavadrc.control import kernels as K
from mavadrc.control.position import (IN_BUF, IN_HEAD, IN_L1, IN_ND, IN_NLAG, IN_STATE, input_model_rest)
from mavadrc.design.identify import MAX_DELAY_S, failure_text, needs_identification, observer_dead_time, observer_drag, observer_lag, partial_text, summary_line
from mavadrc.design.margin import margin_record, margin_text, prediction_text
from mavadrc.flight.rangefinder import RangeTrack, range_height, rangefinder_text
from mavadrc.flight.record import REGULARITY_PERIODS, Recorder, attitude_oscillation, finite
from mavadrc.mavlink.samples import SampleGate
from mavadrc.mavlink.sequence import mode_name
from mavadrc.flight.supervisor import GIVE_UP, LAND, Supervisor
from mavadrc.mission.trajectories import Reference
from mavadrc.flight.truth import truth_text
from mavadrc.design.gains import MARGIN_SHARE, MISSION_MARGIN_FLOOR, TAKEOFF_KIND, TAKEOFF_WC, _run_once, built, fit_and_make, identification_gains, resolve_gains, slower_than, takeoff_gains
from mavadrc.mission.takeoff import YAW_RATE

TRUE_DIST = "TRUE_DIST"
#: in the final descent or after touchdown, a tilt past 45 deg (its cosine) is a vehicle on its
#: side, not landed
TIPPED_COS = math.cos(math.radians(45.0))
#: lockstep: the least telemetry timeout (s); the vehicle waits on us, so a machine busy
#: elsewhere slows the answer without any link being lost
LOCKSTEP_STALE_S = 5.0
#: s within which the vehicle's same words again are counted, not shown (:meth:`Flight.on_text`)
TEXT_QUIET_S = 10.0
#: wall time (s) for a mode or arming change to show in the heartbeat once accepted
CONFIRM_S = 3.0
#: roll/pitch oscillation (deg) worth a warning
OSCILLATION_WARN_DEG = 5.0
#: s the vehicle must stay past the safety's max_tracking_error before the mission stops
TRACKING_LOST_S = 1.0
#: the reference is sampled on the control grid in chunks of this many periods
GRID_CHUNK = 2048



#: ``thrust_tilt: measured`` sizes the thrust for the vehicle's reported tilt while its newest
#: ATTITUDE is at most this much older (s) than the position sample (PX4 and ArduCopter stream
#: it at 50-100 Hz); an older one, or none, leaves the thrust as computed
ATTITUDE_FRESH_S = 0.1


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


#: a sample the controller answers more than this long (s) after it was taken is late: the loop
#: or the link stalled (a radio's 20-60 ms is not late)
LATE_S = 0.1


def late_warning(ages):
    """The warning for a flight's samples answered late (``ages``, s, the mission's), or None."""
    late = [a for a in ages if a > LATE_S]
    if not late:
        return None
    return (f"{len(late)} samples were answered more than {LATE_S:.1f} s after they were taken "
            f"(the oldest {max(late):.2f} s): the loop or the link stalled, and the controller "
            "flew on old samples there")



#: summary.json's vehicle_messages: the vehicle's first and last texts kept (the rest counted)
TEXTS_KEPT = (20, 30)

#: the drag learnt this long (s) before the identify segment is fitted again with it known
REFINE_AFTER_S = 6.0
#: and the lag refitted flown only when it moves by more than this share
REFINE_TOLERANCE = 0.05



class Held:
    """Whether a condition seen at each step has held a while (vehicle time, s)."""

    __slots__ = ("since",)

    def __init__(self):
        self.since = None

    def held(self, condition, now, seconds):
        """``condition`` now, at vehicle time ``now``: whether it has held ``seconds`` (false
        starts the count again)."""
        if not condition:
            self.since = None
            return False
        if self.since is None:
            self.since = now
        return now - self.since >= seconds


class Flight(Preflight, GroundPhases, Failsafes):
    """One flight of a mission over a :class:`~mavadrc.mavlink.link.Link`.

    The flight owns the phases; what differs between autopilots is in its
    :class:`~mavadrc.mavlink.sequence.Sequence`, the safety table in its
    :class:`~mavadrc.flight.supervisor.Supervisor`, the table in its :class:`~mavadrc.flight.record.Recorder`
    and what the user sees in its :class:`~mavadrc.flight.console.Console`.

    ``hover_thrust``: the normalized hover thrust (None: read from the autopilot);
    ``hover_source`` says where a given one came from.  ``takeover``: fly a vehicle another
    controller is flying, from where it is.  ``max_wall_s``: ``--timeout``, over every phase.
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
        self.kind = kind or mission.controller.kind
        self.hover = hover_thrust
        self.sources = {}
        if self.hover is not None:
            self.sources["hover_thrust"] = hover_source or "the mission"
        self.console = Console(out, progress, fallback=record.note)
        self.hung_up_at = None  # mission time of a SIGHUP (the terminal gone): flown on
        self.recorder = Recorder(record, self.kind)
        self.max_wall_s = max_wall_s
        self.heartbeat_timeout = heartbeat_timeout
        self.lockstep = lockstep
        self.takeover = takeover
        self.bundled = bundled  # None: find out from AUTOPILOT_VERSION
        self.watchdog = watchdog  # raises if the vehicle we started died
        # vehicle time (s) at which the mission clock starts, the thrust spooled up over the
        # SPOOL_S before it (experiments: every run starts at the same time); None: as soon as
        # the motors are up
        self.start_at = start_at
        # a lockstep vehicle cannot move on without us, so a slow answer (a machine busy
        # compiling) is not a lost link; give it longer before calling telemetry stale
        sf = mission.safety
        self.supervisor = Supervisor(sf, sf.telemetry_timeout_s if not lockstep
                                     else max(LOCKSTEP_STALE_S, sf.telemetry_timeout_s))
        self.seq = None
        self.texts = []
        self.phase = "connect"
        self.rate = mission.controller.rate_hz  # the rate flown (the achieved one if lower)
        self.h = 1.0 / self.rate
        self.gate = SampleGate(self.h)
        self.last = None  # latest accepted Sample
        self.yaw = 0.0
        self.cos_tilt = 1.0
        # thrust_tilt: measured, read once (each control step asks)
        self._tilt_measured = mission.controller.thrust_tilt == "measured"
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
        self._attitude_ms = None  # the newest ATTITUDE's time_boot_ms
        self.ctrl = None
        self._learner = None  # the drag learnt along the mission (mavadrc.control.learn)
        self._id_samples = None  # the identify segment's samples, fitted again with the drag
        self._refine_job = None
        self._refine_done = False
        self.gains = None  # the controller's gains, resolved (resolve_gains)
        # input_lag: auto: the fit of the identify segment (mavadrc.design.identify); until it is
        # made, the safe default LADRC flies
        self.identification = None
        self.gains_scaled = None  # scale_to_vehicle's factors, when they slowed the gains
        self._id_windows = None
        # an identifying flight's takeoff is flown, when the mission asks (controller: {takeoff:
        # pid}), by a PID (TAKEOFF_KIND) until this mission time (set with the identify
        # segment's windows), then by the safe LADRC made beside it
        self._takeoff_pid = self.m.controller.takeoff == "pid"
        self._handover_t = None
        self._after_takeoff = None
        self.takeoff_controller = None  # what flew the takeoff, for the summary
        self._id_span = None  # (first window's start, last window's end), mission time
        self._id_data = []
        self._id_job = None  # the fit, running in a thread (real time)
        self._fitter = None  # the fits' own process (real time; mavadrc.design.fitworker)
        self.summary = None
        self.truth = None  # a simulator's true state, when it sends one (mavadrc.flight.truth)
        self.rangefinder = RangeTrack()  # a downward range finder, when one reports
        self.context = {}  # what the caller adds to the record (command line, versions, ...)
        self.delay_margin = None  # of the controller flown, on the plant it assumes (s)
        self.traj = None
        self.origin = None
        self.origin_moved_m = None  # how far the estimate moved on the ground before the mission
        self.mission_start = None
        self.phases = []
        self.motor_delay = 0.0
        self.identity = {}
        self.touchdown_speed = None
        self.touchdown_seen = False
        self.touchdown_height = None  # the estimate's height above the takeoff spot there (m)
        self._land_wall = None  # wall clock the final land segment began at
        self.disarm_confirmed = False
        self.warnings = []
        self._t0 = time.monotonic()
        self._deadline = None if max_wall_s is None else self._t0 + max_wall_s
        self._phase_t0 = None  # vehicle time the phase began
        self._phase_wall = self._t0
        self._cmd = None  # the command the phase waits on
        self._cmd_tries = 0
        self._unheard = False  # the phase's command went unanswered after every try
        self._asked_again = 0  # how often the phase's command was sent again for that
        self._confirm_since = None  # judge state only from heartbeats after this wall time
        self._hb_request_wall = 0.0
        self._held = None  # lockstep: the sample whose answer waits on the vehicle
        self._held_wall = 0.0
        self._last_sample_wall = None
        self._last_send_wall = 0.0
        # lockstep: when we were done with the last sample (work after its setpoint, such as
        # the identification's fit, holds the vehicle, which waits for the next setpoint)
        self._handled_wall = 0.0
        self._hb_wall = 0.0
        self._kick_wall = 0.0
        self._last_named = -1.0
        self._setpoint = (level_quat(0.0), 0.0)
        self._in_control_seen = False
        self._lifted = False
        self._air_said = False  # the autopilot said IN_AIR during the mission
        self._yaw_offset = 0.0
        self._grid = None
        self._grid_k0 = 0
        # the lags of the vehicle the mission's own gains were chosen for (its vehicle file's
        # bundled model, identified in process by the caller before the flight:
        # mavadrc.fast.identify.flight_design_lag); None: the mission gives no gains of its own,
        # names no vehicle file, or identifies nothing
        self.design_lag = design_lag
        self._failsafe = None  # the action in force (supervisor constants)
        self._failsafe_step = None  # "hold" or "land": the mode asked for now
        self._failsafe_wall = 0.0
        self._failsafe_sent = 0.0
        self._hold_cmd = None
        self._hold_point = None
        self._interrupts = 0
        self._exceptions = 0
        self._warned = {}
        self._warned_text = {}  # key: the text _warn_once last kept for it
        self._descent = collections.deque()  # (t, z): the land's history (ground.DESCENT_S)
        self._attitudes = []  # (t, roll, pitch) while the controller flies
        self._settled_since = None
        self._last_thrust = None  # the last control step's thrust (landing_tilt)
        self._tipped = False  # the attitude past TIPPED_COS after touchdown
        self._carried = Held()  # the ground carrying the vehicle mid-mission
        self._far = Held()  # the vehicle past max_tracking_error off the reference
        self._settled_at = None  # (reference, vehicle) down when the vehicle came to rest
        self.takeoff_wait = 0.0  # s the takeoff's reference waited for the vehicle to lift off
        self._waiting = False  # this sample's reference waits for the lift-off
        self._waited_capped = 0.0  # s of that waiting with the thrust at its bound
        self.liftoff_hover = None  # the hover thrust taken at lift-off, after a wait
        self.liftoff_s = None  # mission time of the lift-off seen
        self._range_disputed = False  # the range finder said the estimate's lift-off was not
        self._retry_t = None  # vehicle time to ask for the mode again after a refusal
        self._disarm_refused_wall = None  # wall time of the first refused disarm
        #: how the vehicle came to be disarmed after touchdown: "command" (ours), "land mode"
        #: (the autopilot's, handed the landing), None (not by either)
        self.disarm_how = None
        self._texts_shown = {}  # the vehicle's words: [wall time last shown, times unshown since]
        self.disarm_refused_s = None  # s the disarm was refused before the land mode took over
        self.disarm_after_s = None  # s from the thrust cut to the disarm seen
        self._error = None  # why the flight was refused before anything flew
        self._handed_over = False  # the mission ended in the air, as planned
        self.takeover_in_air = False

    # --- reporting -----------------------------------------------------------------------------

    def say(self, text):
        self.console.say(text)

    def hung_up(self):
        """SIGHUP: the terminal the companion was started from is gone (an SSH session lost).
        The flight goes on; the console, if it was that terminal, fails and goes quiet."""
        if self.hung_up_at is None:
            self.hung_up_at = round(float(self.recorder.duration or 0.0), 3)
            self.rec.note(f"SIGHUP at {self.hung_up_at:.1f} s (mission time): the terminal hung "
                          "up; the flight goes on, what the console cannot say is written here")

    def on_text(self, severity, text):
        """The vehicle's words, each on the console; the same words again within
        :data:`TEXT_QUIET_S` of their last showing are counted, not shown, and the count is
        said with them next time (PX4, refusing a disarm asked for every second, said "disarming
        denied: not landed" and its answer 18 times each in 18 s)."""
        self.texts.append(text)
        now = time.monotonic()
        shown = self._texts_shown.get(text)
        if shown is not None and now - shown[0] < TEXT_QUIET_S:
            shown[1] += 1
            return
        more = f" (and {shown[1]} times more since)" if shown is not None and shown[1] else ""
        self._texts_shown[text] = [now, 0]
        self.console.vehicle(text + more)

    def mode_name(self, custom_mode=None):
        if custom_mode is None:
            custom_mode = self.link.custom_mode
        if custom_mode is None:
            return "unknown mode"
        return mode_name(self.link.autopilot, custom_mode)

    def _warn_once(self, key, text, every=5.0, latest=False):
        """Say ``text`` as a warning, at most once every ``every`` s for ``key``, and keep it in
        the summary's warnings once; ``latest``: the summary keeps only the latest said for
        ``key`` (a reading that changes as the flight goes on: a faulty link's loss, said every
        5 s, once left eleven "X % of the samples lost" in one summary)."""
        now = time.monotonic()
        if now - self._warned.get(key, -math.inf) >= every:
            self._warned[key] = now
            self.say(f"warning: {text}")
            if latest and key in self._warned_text:
                old = self._warned_text[key]
                self.warnings[self.warnings.index(old)] = text
            elif text not in self.warnings:
                self.warnings.append(text)
            self._warned_text[key] = text

    # --- the run -------------------------------------------------------------------------------

    def run(self):
        """Fly; returns the summary (also written to summary.json, whatever happens)."""
        link = self.link
        link.on_text = self.on_text
        frozen = False
        try:
            try:
                self._connect()
                self._setup()
                frozen = _freeze_heap()
                self._loop()
            except KeyboardInterrupt as exc:
                self.supervisor.report("interrupted", interrupt_reason(exc))
                if self.link.armed:
                    self._loop()  # the flight goes on under the supervisor: hold, then land
            except (FlightError, LinkError) as exc:
                self.supervisor.report("refused", str(exc))
                self.summary = self._finish()
                raise
        finally:
            if frozen:
                gc.unfreeze()
            if self._fitter is not None:
                self._fitter.close()
        self.summary = self._finish()
        if self._error is not None:
            raise FlightError(self._error)
        return self.summary

    def _release_refused(self):
        """Refused while arming, the vehicle sits disarmed in the mode we put it in: out of it,
        as at a flight's end (:meth:`_end_disarmed`).  Left there, PX4 SIH refused the next
        flight's companion as 'another controller owns it'."""
        if self.phase != "arming" or self.link.armed:
            return
        try:
            self.link.wait(self.seq.release(self.link))
        except (LinkError, OSError):
            pass

    def _identifying(self):
        """Whether the input model is still to be identified (or could not be: then the safe
        defaults fly the whole mission)."""
        if not needs_identification(self.m.controller, self.kind):
            return False
        return self.identification is None or "input_lag" not in self.identification

    def _controller_flown(self):
        """(kind, gains) flown now: the mission's, or, while the input model is identified, the
        safe default LADRC (:data:`SAFE_WC`, no input model), after the takeoff's PID
        (:func:`takeoff_gains`) until its handover (:meth:`_takeoff_handover`)."""
        if self._identifying():
            if self._takeoff_pid:
                return TAKEOFF_KIND, takeoff_gains()
            return "ladrc", identification_gains()
        if self.gains is None:
            self.gains = resolve_gains(
                self.m.controller, self.kind,
                identified=(observer_lag(self.identification, self.m.controller)
                            if self.identification else None),
                drag=observer_drag(self.identification) if self.identification else None,
                designed_for=self.design_lag if self.identification else None,
                dead_time=(observer_dead_time(self.identification, self.m.controller)
                           if self.identification else None),
                margin_floor=MISSION_MARGIN_FLOOR)
        return self.kind, self.gains

    def _make_controller(self, hover):
        kind, gains = self._controller_flown()
        ctrl, self.delay_margin = self._build(hover, kind, gains)
        if self._identifying() and self._takeoff_pid:
            # the safe LADRC that takes over from the takeoff's PID, made now (its margin is a
            # few hundred ms of kernels: not in the loop)
            self._after_takeoff = self._build(hover, "ladrc", identification_gains())
        self._learner = self._drag_learner(ctrl, gains)
        return ctrl

    def _drag_learner(self, ctrl, gains):
        """The :class:`DragLearner` of the controller ``ctrl`` flown with ``gains`` (None: its
        drag stays as it is: ``drag_learn`` 0, the safe gains of the identification, or a
        controller without the drag in its model).  The identification's safe gains do not
        learn: along the doublets the observers' disturbance is mostly the missing input
        model, and the slope on the reference velocity read 0.7-1.0 /s there on PX4 SIH
        (its drag: 1.0), 0.82 on the bundled model of it."""
        tau = float(gains.get("drag_learn") or 0.0)
        if tau <= 0.0 or self._identifying() or not ctrl.models_drag:
            return None
        return DragLearner(ctrl.drag, tau)

    def _build(self, hover, kind, gains):
        """The controller of ``kind`` with ``gains`` at the rate flown, its delay margin
        computed and every kernel of its step run once (compiled now, not mid-flight); at rest,
        waiting for its first sample."""
        ctrl, margin = built(self.m.controller, hover, kind, self.rate, gains)
        _run_once(ctrl)
        return ctrl, margin

    def _in_doublets(self, time_boot_ms, after=1.0):
        """Whether vehicle time ``time_boot_ms`` falls in the identify segment (or ``after`` s
        past it: the tilt there is still the doublets', not a limit cycle)."""
        if self._id_windows is None:
            return False
        t = time_boot_ms / 1000.0 - self._mission_t0
        return self._id_span[0] <= t <= self._id_span[1] + after

    def _id_data_span(self):
        """(start, end) of the identify segment's samples in mission time: its windows' span,
        from as far before the first as a dead time can reach back for its commands."""
        start, end = self._id_span
        return start - MAX_DELAY_S - 0.1, end

    def _pause_learning(self, t, final_land):
        """Pause or resume learning the hover thrust for mission time ``t`` (``final_land``:
        ``t`` is in the closing land segment).  Not learnt over the identify
        segment's samples (the safe controller learns it in the takeoff and holds it there:
        :func:`identification_gains`), and not from the closing land segment on, where the
        ground may carry the vehicle before the contact is seen (PX4 SIH, its estimate
        climbing on the ground: the vertical observer read the ground's push as a lighter
        vehicle, and the thrust learnt fell from 0.47 to 0.26 by the touchdown)."""
        if not self.ctrl.learns_thrust:
            return
        hold = final_land
        if self._id_windows is not None and self._identifying():
            start, end = self._id_data_span()
            hold = hold or start <= t <= end
        self.ctrl.pause_thrust_learning(hold)

    def _takeoff_text(self):
        """What flies the takeoff, for the line that starts the mission ("" when it is the
        controller named there, or the safe LADRC of an identifying flight)."""
        if not (self._identifying() and self._takeoff_pid):
            return ""
        return (f", taking off on a PID on the measured velocity (wc {TAKEOFF_WC[0]:g}) and "
                "identifying the vehicle on the safe LADRC first")

    def _takeoff_handover(self, s, t, ref_vel):
        """At :attr:`_handover_t` (mission time ``t``, sample ``s``), the takeoff's PID hands
        the vehicle to the safe LADRC that flies the doublets, without a jump
        (:func:`carry_over`: its disturbance estimates start at the PID's integrator, the
        thrust learnt is kept; ``ref_vel``: the reference's velocity now)."""
        if not self._takeoff_pid or self._handover_t is None or t < self._handover_t - 1e-9:
            return
        self._takeoff_pid = False
        old = self.ctrl
        self.ctrl, self.delay_margin = self._after_takeoff
        self._after_takeoff = None
        carry_over(self.ctrl, old, s.pos, s.vel, ref_vel)
        up = float(self.origin[2] - s.pos[2])
        self.takeoff_controller = {**controller_record(self.m.controller, TAKEOFF_KIND,
                                                       takeoff_gains()),
                                   "handed_over_at_s": round(t, 3),
                                   "handed_over_at_m": round(up, 3)}
        self.say(f"the takeoff's PID hands over to the safe LADRC for the identification "
                 f"({t:.1f} s into the mission, {up:.2f} m up); "
                 f"{margin_text(self.delay_margin)}")

    def _identify_step(self, s, t, ref_vel):
        """Keep the samples of the identify segment; at its end fit the input model and fly
        the mission's controller with it.  The fit and the new controller's delay margin take
        a good part of a second: in lockstep (the vehicle waits) they are made at once, in real
        time in a thread while the safe controller flies on, and the new controller takes over
        at the first sample after they are ready (``ref_vel``: the reference's velocity the
        controller flies to now, for :func:`carry_over`)."""
        if self._id_job is not None:
            if not self._id_job.done():
                return
            job, self._id_job = self._id_job, None
            return self._identified(s, ref_vel, *job.result())
        if self._id_windows is None or self.identification is not None:
            return
        start, end = self._id_data_span()
        if t >= start:
            self._id_data.append((t, *self.ctrl.accel_applied, *s.vel,
                                  math.nan if s.age is None else s.age))
        if t < end:
            return
        d = np.asarray(self._id_data)
        self._id_data = []
        self._id_samples = d  # fitted again once the drag is learnt (_refine_step)
        if self.lockstep:
            return self._identified(s, ref_vel, *self._identify_fit(d))
        import concurrent.futures
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="identify")
        self._id_job = pool.submit(self._identify_fit, d)
        pool.shutdown(wait=False)

    def _identify_fit(self, d, drag=None):
        """The fit of the identify segment's samples ``d`` (``drag``: known per axis, else
        fitted), and, if it holds, the mission's controller made with it (:func:`fit_and_make`:
        in the fits' own process in real time, :mod:`mavadrc.design.fitworker`), its kernels run once
        here: (record, controller or None, gains, delay margin)."""
        job = (d, self._id_windows, f"in flight, on system {self.link.target_system} "
               f"({self.link.autopilot})", self.m.controller, self.kind, self.rate,
               self.hover, self.design_lag, drag, MISSION_MARGIN_FLOOR)
        if self._fitter is None:
            out = fit_and_make(*job)
        else:
            out = self._fitter.call(fit_and_make, *job)
            out[0]["fit_in"] = self._fitter.where
        if out[1] is not None:
            _run_once(out[1])
        return out

    def _identified(self, s, ref_vel, rec, ctrl, gains, margin):
        """The identification's result, from sample ``s`` on (``ref_vel``: the reference's
        velocity the controller is flying to now)."""
        self.identification = rec
        # mission time of the switch, and how fast the reference moved there
        rec["switched_at_s"] = round(s.t - self._mission_t0, 3)
        rec["switched_at_speed_mps"] = round(float(np.linalg.norm(ref_vel)), 3)
        self.say(f"input model identified: {summary_line(rec)}")
        if ctrl is None:
            self._learner = None  # the safe gains fly on as they are
            self._warn_once("identify", f"{failure_text(rec)}: the safe default LADRC flies the "
                                        "rest of the mission", every=0.0)
            return
        if partial_text(rec) is not None:
            self._warn_once("identify", partial_text(rec), every=0.0)
        old = self.ctrl
        self.ctrl, self.gains, self.delay_margin = ctrl, gains, margin
        carry_over(self.ctrl, old, s.pos, s.vel, ref_vel)
        self._learner = self._drag_learner(ctrl, gains)
        lag = ", ".join(f"{x:.3f}" for x in gains["input_lag"])
        bw = _bandwidths(gains)
        if self._note_scaling(gains) is not None:
            f, design = self.gains_scaled["factor"], self.gains_scaled["design_lag_s"]
            name = getattr(self.m.vehicle, "name", self.m.vehicle)
            kept = self.gains_scaled.get("wo_factor") == 1.0
            which = f"horizontal wc x{f:.2f}" if kept else f"horizontal wc and wo x{f:.2f}"
            why = " (wo as given: the observers model the lag)" if kept else ""
            took = gains["input_lag"][0]
            if self.gains_scaled["because"] == "slower":
                self.say(f"the mission's gains were chosen for a vehicle answering in "
                         f"{design[0]:.3f} s horizontally ({name}); this one takes "
                         f"{took:.3f} s: {which}, to keep {'its' if kept else 'their'} delay "
                         f"margin{why}")
            else:
                self.say(f"the mission's gains keep under {MISSION_MARGIN_FLOOR:.0%} of this "
                         f"vehicle's lag ({took:.3f} s horizontally) as delay margin: {which}, "
                         f"to keep that much{why}")
        drag = ""
        if any(float(c) > 0.0 for c in gains.get("drag", ())) and self.ctrl.drag.any():
            drag = f", drag ({', '.join(f'{float(c):.2f}' for c in gains['drag'])}) /s"
        fitted = rec.get("delay_margin_s")
        fitted = ("" if fitted is None else
                  f"; {1e3 * fitted:.0f} ms on the response identified (its lags and dead time)")
        self.say(f"flying {self.kind} with the observers' input lag ({lag}) s{drag}{bw}"
                 f"{prediction_text(self.ctrl)} from here; "
                 f"{margin_text(self.delay_margin)}{fitted}")
        slow = max(gains["input_lag"][0], gains["input_lag"][1])
        rule = rec.get("delay_margin_one_lag_s", self.delay_margin)
        if rule is not None and rule < MARGIN_SHARE * slow:
            self._warn_once("margin", f"the delay margin ({1e3 * rule:.0f} ms, on one lag of "
                            f"that 63 % time) is under {MARGIN_SHARE:.0%} of the lag identified "
                            f"({1e3 * slow:.0f} ms): the mission's gains are fast for this "
                            "vehicle and a limit cycle is likely (without wc and wo the "
                            "defaults are slowed to keep that margin)", every=0.0)

    def _margin_outcome(self, warnings, osc):
        """The margin warning (a limit cycle predicted from the delay margin, in ``warnings``)
        with what the flight measured, where it swung no more than
        :data:`OSCILLATION_WARN_DEG`: on ArduCopter SITL the shipped missions kept 44 % of the
        lag, under the 75 % warned at, and swung +-0.3-0.6 deg; a warning left saying "likely"
        would say more than was measured.  (A larger swing has its own warning beside it.)"""
        said = self._warned_text.get("margin")
        if said is None or osc is None or said not in warnings or osc["limit_cycle"] is None:
            return
        if osc["amplitude_deg"] > OSCILLATION_WARN_DEG:
            return
        seen = f"{swing_text(osc)}: none past the {OSCILLATION_WARN_DEG:g} deg warned at"
        warnings[warnings.index(said)] = f"{said}; measured: {seen}"
        self.say(f"the delay margin's warning against what was flown: {seen}")

    def _note_scaling(self, gains):
        """``gains_scaled`` for the gains flown: the factor by which :func:`scale_to_vehicle`
        slowed the mission's own horizontal wc (``factor``) and wo (``wo_factor``, when the
        mission gives wo: 1 where the observers kept their bandwidth), the lags they were
        chosen for (``design_lag_s``, None: not known) and which rule slowed them
        (``because``: "slower", the vehicle is slower than those, and the need was the larger
        of the share they kept there and :data:`MISSION_MARGIN_FLOOR` of its lag; "margin", it
        is not, and the floor alone asked it); None: flown as given.  Returns it."""
        design, given = self.design_lag, self.m.controller.gains.get("wc")
        given_wo = self.m.controller.gains.get("wo")
        self.gains_scaled = None
        if self.kind == self.m.controller.kind and given is not None and "wc" in gains:
            f = float(gains["wc"][0]) / float(given[0])
            if f < 1.0:
                # (slowed only with input_lag: auto, resolved by then to the lags identified)
                slower = slower_than(gains["input_lag"], design)
                self.gains_scaled = {
                    "design_lag_s": None if design is None else [round(x, 4) for x in design],
                    "factor": round(f, 3),
                    "because": "slower" if slower else "margin"}
                if given_wo is not None and "wo" in gains:
                    self.gains_scaled["wo_factor"] = round(
                        float(gains["wo"][0]) / float(given_wo[0]), 3)
        return self.gains_scaled

    def _refine_step(self, s, t):
        """Once the drag has been learnt for :data:`REFINE_AFTER_S`, fit the identify segment's
        samples again with it known (the doublets alone trade the drag against the lag) and, if
        the lag moves by more than :data:`REFINE_TOLERANCE`, fly on with the controller made
        with the lag refined (its gains resolved again: a mission's own are scaled to it).
        Made in a thread in real time, at once in lockstep, as the first fit."""
        if self._refine_job is not None:
            if self._refine_job.done():
                job, self._refine_job = self._refine_job, None
                self._refined(s, t, *job.result())
            return
        learner = self._learner
        if (self._id_samples is None or self._refine_done or learner.first_used_s is None
                or t - learner.first_used_s < REFINE_AFTER_S):
            return
        self._refine_done = True
        # north and east as learnt (as flown where not yet told); the vertical fitted again
        drag = [float(c) if c == c else float(m)
                for c, m in zip(learner.estimate[:2], self.ctrl.drag[:2])] + [None]
        if self.lockstep:
            return self._refined(s, t, drag, *self._identify_fit(self._id_samples, drag))
        import concurrent.futures
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="refine")
        self._refine_job = pool.submit(lambda: (drag, *self._identify_fit(self._id_samples,
                                                                           drag)))
        pool.shutdown(wait=False)

    def _refined(self, s, t, drag, rec, ctrl, gains, margin):
        """The refit's result (``drag``: the horizontal drag it took as known), from sample
        ``s`` (mission time ``t``) on."""
        old_lag = self.gains["input_lag"]
        note = {"at_s": round(t, 2), "drag_per_s": [None if x is None else round(x, 4)
                                                      for x in drag[:2]],
                "axes": rec["axes"], "fit_s": rec["fit_s"], "made_in_s": rec["made_in_s"]}
        if ctrl is None:
            note["flown"] = False
            note["why"] = failure_text(rec)
            self.identification["refined"] = note
            return
        new_lag = gains["input_lag"]
        note["input_lag"] = [round(x, 4) for x in rec["input_lag"]]
        change = abs(new_lag[0] - old_lag[0]) / max(old_lag[0], 1e-9)
        note["flown"] = bool(change > REFINE_TOLERANCE)
        self.identification["refined"] = note
        if not note["flown"]:
            self.say(f"input model fitted again with the drag learnt: {new_lag[0]:.3f} s "
                     f"horizontally (flying {old_lag[0]:.3f}): kept")
            return
        old = self.ctrl
        ctrl.set_drag([*old.drag[:2], ctrl.drag[2]])  # the drag learnt so far goes on
        carry_on(ctrl, old)
        self.ctrl, self.gains, self.delay_margin = ctrl, gains, margin
        rec_margin = rec.get("delay_margin_s")  # on the response refitted (_identify_fit)
        note["delay_margin_s"] = rec_margin
        self._note_scaling(gains)
        self.say(f"input model fitted again with the drag learnt "
                 f"({', '.join(f'{x:.2f}' for x in drag[:2])} /s): {new_lag[0]:.3f} s "
                 f"horizontally for the doublets' {old_lag[0]:.3f}; flying it"
                 f"{_bandwidths(gains)}{prediction_text(self.ctrl)} from here; "
                 f"{margin_text(margin)}"
                 + ("" if rec_margin is None else
                    f"; {1e3 * rec_margin:.0f} ms on the response identified"))

    # --- the loop ------------------------------------------------------------------------------

    def _loop(self):
        link = self.link
        while self.phase != "done":
            try:
                msg = link.recv(0.02)
                if msg is not None:
                    self._dispatch(msg)
                self._tick(time.monotonic())
            except KeyboardInterrupt as exc:
                self._interrupts += 1
                if self._interrupts > 1:
                    self._give_up("a second interrupt")
                elif isinstance(exc, Terminated):
                    self.say(f"terminated ({exc.signame}): hold, then land ({exc.signame} again "
                             "to leave the vehicle to its autopilot)")
                    self._escalate("interrupted", interrupt_reason(exc))
                else:
                    self.say("interrupted: hold, then land (Ctrl-C again to leave the vehicle "
                             "to its autopilot)")
                    self._escalate("interrupted", interrupt_reason(exc))
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
            self._release_refused()
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
            elif self._attitude_ms is not None:
                # in lockstep the vehicle's clock stands still, at the period whose messages
                # come, until we answer: its ATTITUDE (every period, right after the position
                # sample, no link model on it) says the last period's time
                now_s = self._attitude_ms / 1000.0 + self.h
                s.age = max(0, round((now_s - s.t) / self.h)) * self.h
            self.last = s
            self.samples_seen += 1
            self._last_sample_wall = now
            t_in = time.perf_counter()
            self._on_sample(s)
            if self.lockstep:
                self._handled_wall = time.monotonic()
            if self.phase in ("mission", "touchdown"):  # telemetry in -> setpoint out
                self.latency.append(time.perf_counter() - t_in)
                if s.age is not None:
                    self.ages.append(s.age)
        elif t == "ATTITUDE":
            self.yaw = msg.yaw
            self._attitude_ms = msg.time_boot_ms
            if self.phase in ("mission", "touchdown") and not self._in_doublets(msg.time_boot_ms):
                self._attitudes.append((msg.time_boot_ms / 1000.0, msg.roll, msg.pitch))
            self.cos_tilt = math.cos(msg.roll) * math.cos(msg.pitch)
            near_ground = self.touchdown_seen or self.phase == "touchdown"
            if near_ground and self.cos_tilt < TIPPED_COS and not self._tipped:
                self._tipped = True
                why = (f"the vehicle tipped over at touchdown: the autopilot reads "
                       f"{math.degrees(msg.roll):.0f} deg of roll, "
                       f"{math.degrees(msg.pitch):.0f} of pitch")
                self.say(f"warning: {why}")
                self.supervisor.report("tipped", why)
            self.recorder.attitude(msg.time_boot_ms, msg.yaw)
        elif t == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
            self.landed_state_wall = time.monotonic()
            if self.phase == "mission" and msg.landed_state == M.MAV_LANDED_STATE_IN_AIR:
                self._air_said = True
        elif t == "DEBUG_VECT" and msg.name == TRUE_DIST:
            self.recorder.truth(int(round(msg.time_usec / 1000.0)),
                                np.array([msg.x, msg.y, msg.z]))
        elif self.truth is not None and t == self.truth.source:
            self._on_truth(msg)
        elif t == "DISTANCE_SENSOR":
            self._on_range(msg)
        if self._held is not None and not self._awaiting():
            s, self._held = self._held, None
            self._on_sample(s)

    def _on_truth(self, msg):
        """A simulator's true state: beside the estimate of the same time.  It carries no usable
        time: it is timed by its arrival after the last position sample on the same link (in
        lockstep, sent in that sample's period), and the estimate carried there on its own
        velocity."""
        s = self.last
        if s is None:
            return
        if self.mission_start is None:
            self.truth.at_rest(msg, s.pos)
            return
        if self._waiting:
            return  # the mission's clock stands still: no time to put it at
        dt = 0.0 if self.lockstep else max(0.0, time.monotonic() - self._last_sample_wall)
        self.truth.add(s.t + dt - self._mission_t0, msg, s.pos + s.vel * dt)

    def _on_range(self, msg):
        """A range finder's reading (:mod:`mavadrc.flight.rangefinder`): beside the height estimate
        of its own time (the newest sample carried there on its vertical speed, at most 0.1 s),
        and, in the mission, the clearance check."""
        h = range_height(msg, self.cos_tilt)
        s = self.last
        if h is None or s is None:
            return
        self.rangefinder.read(msg.time_boot_ms / 1000.0, h)
        if self.mission_start is None:
            if not self._lifted:
                self.rangefinder.at_rest(0.0, h)
            return
        if self._waiting:
            return  # the mission's clock stands still: no time to put it at
        if self.touchdown_seen or self.phase == "done":
            # on the ground after the touchdown seen, or the flight over: nothing flown to set
            # it beside (PX4 SIH's estimate read 0.8 m of climb on the ground after a landing,
            # which the record's figures had counted as the estimate's error in flight)
            return
        dt = min(0.1, max(-0.1, msg.time_boot_ms / 1000.0 - s.t))
        est_h = float(self.origin[2] - (s.pos[2] + s.vel[2] * dt))
        t = s.t + dt - self._mission_t0
        gap = self.rangefinder.add(t, est_h, h, in_air=self.takeover_in_air)
        if self.phase != "mission":
            return
        why = self.rangefinder.clearance(msg.time_boot_ms / 1000.0, gap, h,
                                         self.m.safety.min_clearance, self._airborne(t))
        if why is not None:
            self._escalate("clearance", why)

    def _grounded_in_flight(self, s, t):
        """Why the flight must end, when the autopilot's land detector says ON_GROUND after it
        had said IN_AIR, before the final land segment (None otherwise).  The height estimate
        is then off, or the vehicle hit something: on PX4 SIH the estimate once drifted 0.7 m
        up over 20 s of the thesis spiral at 1.3 m, the vehicle sat on the ground 8 s while its
        estimate read 1.3-1.6 m, and the position loop lifted it off again, blind."""
        if not (self._air_said and self.landed_state == M.MAV_LANDED_STATE_ON_GROUND) \
                or self._in_final_land(t):
            return None
        return (f"the autopilot says the vehicle is on the ground, "
                f"{self.origin[2] - s.pos[2]:.2f} m above the takeoff spot by its height "
                "estimate, mid-mission: the estimate is off or the vehicle hit something")

    def _carried_in_flight(self, s, t, thrust):
        """Why the flight must end when the ground carries the vehicle mid-mission, whatever
        the autopilot's land detector says (None otherwise): for :data:`SETTLED_S` after
        lift-off, before the final land segment, the thrust at its floor and the vertical
        disturbance estimate holding up :data:`CARRIED_SHARE` of g (the vehicle does not fall
        with the thrust cut: something holds it up).  On PX4 SIH, in the thesis spiral's run-up
        at 1 m, the height estimate read level while the vehicle sank 0.23 m/s into the
        ground; at 2 m/s it stopped dead, the estimate then read a climb, PX4's land detector
        said nothing, and 5 s later the loop lifted it off again to chase a reference 19 m
        away."""
        z3 = float(self.ctrl.z[2, 2])
        low = thrust <= self.m.controller.thrust_min + CARRIED_THRUST_MARGIN
        if not self._carried.held(self._airborne(t) and low and z3 < -CARRIED_SHARE * GRAVITY,
                                  s.t, SETTLED_S):
            return None
        return (f"the ground carries the vehicle mid-mission ({self.origin[2] - s.pos[2]:.2f} m "
                f"above the takeoff spot by its height estimate; the thrust at its floor, "
                f"{-z3:.1f} m/s^2 holding it up): the estimate is off or the vehicle hit "
                "something")

    def _airborne(self, t):
        """After lift-off and before the mission's final land segment (mission time ``t``)."""
        return self._lifted and not self._in_final_land(t)

    def _tracking_lost(self, s, r, t):
        """Why the flight must stop chasing its reference (None otherwise): after lift-off,
        before the final land segment, the vehicle held more than the safety's
        ``max_tracking_error`` from the reference ``r`` for :data:`TRACKING_LOST_S`."""
        limit = self.m.safety.max_tracking_error
        err = math.dist(s.pos, r.pos)
        if not self._far.held(bool(limit) and self._airborne(t) and err > limit, s.t,
                              TRACKING_LOST_S):
            return None
        return (f"tracking lost: {err:.1f} m from the reference for {TRACKING_LOST_S:g} s "
                f"(safety.max_tracking_error {limit:g} m): the vehicle is not following it "
                "(caught or pinned, its height estimate off, a wind past its authority)")

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

    def _end_disarmed(self, hb, text):
        """A heartbeat shows the vehicle disarmed: the flight is over.  Still in our mode (PX4
        goes back to OFFBOARD once its own failsafe has landed and disarmed it), it is put in
        its hold mode, as MAVSDK's offboard.stop() does, so the next flight does not find it
        taken."""
        self.disarm_confirmed = True
        self.say(text)
        if self.seq.in_control(hb):
            self.link.wait(self.seq.release(self.link))
        self.phase = "done"

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










    def _reference(self, t):
        """The reference at mission time ``t``: on the control grid (computed a chunk at a time:
        a vehicle whose clock ticks on the period reads it from there), or sampled exactly off
        it (as :func:`mavadrc.fast.inprocess._references` does)."""
        h = self.h
        k = int(round(t / h))
        grid_n = int(self.traj.duration / h) + 2
        if abs(t - k * h) < 1e-7 and 0 <= k < grid_n:
            if self._grid is None or not self._grid_k0 <= k < self._grid_k0 + GRID_CHUNK:
                # from a little before: the reference a lead ahead (_feedforward) and the one
                # for now then share a chunk
                self._grid_k0 = k0 = max(k - GRID_CHUNK // 8, 0)
                self._grid = self.traj.sample_many(np.arange(k0, min(k0 + GRID_CHUNK, grid_n))
                                                   * h)
            pos, vel, acc, yaw, yaw_rate = self._grid
            i = k - self._grid_k0
            return Reference(pos[i], vel[i], acc[i], float(yaw[i]), float(yaw_rate[i]))
        return self.traj.sample(t)

    def _lead(self, s):
        """How far past sample ``s``'s time the controller carries its estimate, to where its
        command acts (the sample's age, as its ``latency`` says; 0: not compensated): the
        reference it flies to is taken there."""
        age = self.ctrl.sample_age(s.age)
        return age if age == age else 0.0

    def _feedforward(self, rc, t):
        """``rc``, the reference for mission time ``t``, with the acceleration fed forward taken
        where the command will act: per axis ``feedforward_lead`` later (the input lag), plus
        the change of the drag along the reference by then (:attr:`PositionController.drag`)."""
        lead = self.ctrl.feedforward_lead
        if not np.any(lead > 0.0):
            return rc
        drag = self.ctrl.drag
        acc = np.array(rc.acc, dtype=float)
        ahead = {}  # one sample per distinct lead (north and east share theirs)
        for i in range(3):
            if lead[i] > 0.0:
                a = ahead.get(lead[i])
                if a is None:
                    a = ahead[lead[i]] = self._reference(t + float(lead[i]))
                acc[i] = a.acc[i] + drag[i] * (a.vel[i] - rc.vel[i])
        return Reference(rc.pos, rc.vel, acc, rc.yaw, rc.yaw_rate)

    def _control_step(self, s, r, hold=False, tilt_cap=None, aref=None):
        """One control step on sample ``s`` towards reference ``r`` (for the time the
        controller's estimate is carried to, :meth:`_lead`; ``hold``: stay where the
        reference was when the hold began); sends the setpoint, returns (q, thrust).
        ``tilt_cap`` (rad; landing): the tilt limit for this step, lowered further as the
        thrust falls towards its floor (:func:`landing_tilt`).  ``aref``: the reference's own
        acceleration then, where ``r.acc`` is the one fed forward (None: ``r.acc``)."""
        told = None
        if tilt_cap is not None:
            told = self.ctrl.tilt_limit
            self.ctrl.tilt_limit = landing_tilt(tilt_cap, self._last_thrust,
                                                self.ctrl.hover_thrust_estimate,
                                                self.m.controller.thrust_min)
        try:
            q, thrust = self._control_update(s, r, hold, aref)
        finally:
            if told is not None:
                self.ctrl.tilt_limit = told
        self._last_thrust = thrust
        thrust = self._thrust_for_tilt(s, q, thrust)
        self._send(s.t, q, thrust * self.seq.thrust_factor(self))
        return q, thrust

    def _thrust_for_tilt(self, s, q, thrust):
        """``thrust`` sized for the tilt the vehicle reports (``thrust_tilt: measured``,
        :func:`~mavadrc.control.geometry.thrust_for_tilt`) when its newest ATTITUDE is at most
        :data:`ATTITUDE_FRESH_S` older than sample ``s``; else as computed."""
        if not self._tilt_measured or self._attitude_ms is None or \
                s.t - self._attitude_ms / 1000.0 > ATTITUDE_FRESH_S:
            return thrust
        return thrust_for_tilt(thrust, float(q[0]), float(q[1]), float(q[2]), float(q[3]),
                               self.cos_tilt, self.m.controller.thrust_max)

    def _control_update(self, s, r, hold, aref=None):
        if hold:
            if self._hold_point is None:
                self._hold_point = s.pos.copy()
                if self.phase in ("measure", "mode"):
                    self.ctrl.reset(s.pos, s.vel)
            z3 = np.zeros(3)
            q, thrust = self.ctrl.update(s.pos, s.vel, self._hold_point, z3, z3, self.yaw,
                                         dt=s.dt, age=s.age)
        else:
            q, thrust = self.ctrl.update(s.pos, s.vel, r.pos, r.vel, r.acc, r.yaw, dt=s.dt,
                                         age=s.age, ref_acc_now=aref)
        return q, thrust

    def _ph_mission(self, s):
        self._mission_step(s)

    def _mission_step(self, s):
        if self._left_control():
            return
        t = s.t - self._mission_t0
        r = self._reference(t)  # the sample's: what its error is scored against
        self._waiting = not self._lifted and self._takeoff_waits(s, r)
        if self._waiting:  # the mission clock stops: this sample flies to the last reference
            step = s.dt if s.dt is not None else self.h
            self._mission_t0 += step
            self.mission_start = self._mission_t0
            self.takeoff_wait += step
            t = s.t - self._mission_t0
            r = self._reference(t)
        lead = self._lead(s)
        rc = r if lead == 0.0 else self._reference(t + lead)
        aref = rc.acc  # the reference's own, for a law that predicts
        rc = self._feedforward(rc, t + lead)
        if self._yaw_offset != 0.0:
            step = YAW_RATE * (s.dt if s.dt is not None else self.h)
            self._yaw_offset -= max(-step, min(step, self._yaw_offset))
            r = Reference(r.pos, r.vel, r.acc, r.yaw + self._yaw_offset, r.yaw_rate)
            rc = Reference(rc.pos, rc.vel, rc.acc, rc.yaw + self._yaw_offset, rc.yaw_rate)
        if self._waiting:
            rc = self._waiting_reference(s, rc)
            aref = (aref[0], aref[1], 0.0)
        final = self._in_final_land(t)
        cap = math.radians(self.m.controller.tilt_max_deg) if final else None
        self._pause_learning(t, final)
        self._takeoff_handover(s, t, rc.vel)
        q, thrust = self._control_step(s, rc, tilt_cap=cap, aref=aref)
        if self._learner is not None and self._lifted:
            self._learner.step(self.ctrl, t, s.dt, rc.vel, rc.acc)
            self._refine_step(s, t)
        self._identify_step(s, t, rc.vel)
        self._descent_history(s, final)
        if not self._lifted:
            if lifted_off(self.origin[2] - s.pos[2], s.vel[2]) and not self._range_grounded(s):
                self._lifted = True
                self.liftoff_s = t
                if self.takeoff_wait > 0.0:
                    self.liftoff_hover = self.ctrl.hover_thrust_estimate
                    self.say(f"lifted off: the takeoff waited {self.takeoff_wait:.1f} s, the "
                             f"hover thrust raised to {self.ctrl.hover_thrust_estimate:.3f} "
                             f"(told {self.hover:.3f})")
            else:
                self.ctrl.hold_disturbance()  # on the ground: the ground's push is no disturbance
        if self._waiting:
            why = self._raise_takeoff_thrust(s)
            if why is not None:
                return self._escalate("ground", why)
            self._check_link()
            return  # the reference waited: nothing of the mission to score, log or count
        self.steps += 1
        # the identification is not the mission: its doublets, flown on the safe gains, are
        # logged but not scored
        self.recorder.step(t, self._segment_name(t), r, s, self.ctrl, q, thrust,
                           scored=not self._in_doublets(s.t * 1000.0, after=0.0))
        self._named_values(s)
        self._check_link()
        why = self.supervisor.breach(s, self.origin)
        if why is not None:
            return self._escalate("breach", why)
        why = self._grounded_in_flight(s, t) or self._carried_in_flight(s, t, thrust)
        if why is not None:
            return self._escalate("ground", why)
        why = self._tracking_lost(s, r, t)
        if why is not None:
            return self._escalate("tracking", why)
        if self._in_final_land(t):
            if self._land_wall is None:
                self._land_wall = time.monotonic()
            how = self._ground_contact(s, r.pos[2], self._land_wall)
            if how is not None:
                # on the ground before the reference: the height estimate has drifted; what
                # follows is the ground's push, not tracking, and is not scored
                self._unscore_from_contact()
                self.say(f"on the ground {self.origin[2] - s.pos[2]:.2f} m above the takeoff "
                         "spot by the height estimate, before the land segment's end")
                return self._touched_down(s, thrust, how)
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

    def _range_grounded(self, s):
        """Whether a range finder read at rest before the mission, and lately
        (:meth:`~mavadrc.flight.rangefinder.RangeTrack.height_up` at the sample ``s``), still reads the
        vehicle on the ground (under :data:`~mavadrc.flight.ground.LIFTOFF_HEIGHT` above its reading at
        rest) when the height estimate reads a lift-off: the lift-off is then the estimate's alone.
        On PX4 SIH at 1.4 kg (told 1.0), its height estimate read a climb of 0.13-0.19 m/s for
        2 s while the vehicle sat on the ground under a rising thrust: taken for a lift-off, the
        reference ran on to 1 m, and the clearance check ended two of four flights 0.0-0.2 m
        up with the estimate reading 0.35-0.52 m.  Without such a reading (no range finder, or
        the ground under its minimum distance at rest) the estimate decides alone."""
        up = self.rangefinder.height_up(s.t)
        if up is None or up >= LIFTOFF_HEIGHT:
            return False
        if not self._range_disputed:
            self._range_disputed = True
            self.say(f"the height estimate reads a lift-off ({self.origin[2] - s.pos[2]:.2f} m "
                     f"up) the range finder does not ({up:.2f} m): on the ground until it does")
        return True

    def _takeoff_waits(self, s, r):
        """Whether the takeoff's reference ``r`` (the sample's) has climbed
        :data:`~mavadrc.flight.ground.TAKEOFF_WAIT_M` above a vehicle still on the ground (sample
        ``s``): it then waits there.  A vehicle heavier than told does not rise on the thrust
        the loop expected to lift it; running on, the reference left PX4 SIH at 1.4 kg (told
        1.0) 1.1 m below it on the ground for 3.4 s, and it leapt after it at 0.4 m/s.  (Taken
        over in the air, the flight starts lifted: never asked.)"""
        return float(s.pos[2] - r.pos[2]) > TAKEOFF_WAIT_M

    @staticmethod
    def _waiting_reference(s, rc):
        """The reference a waiting takeoff flies to: ``rc`` held vertically at rest
        :data:`~mavadrc.flight.ground.TAKEOFF_WAIT_M` above the vehicle's estimate.  Held where the
        wait began instead, an estimate sinking on the ground (PX4 SIH's read 0.3 m of descent
        in a second of waiting) grew the error the vertical observer learns a weight from: it
        learnt 5.9 m/s^2 where 3.9 were missing, and the lift-off overshot 0.42 m."""
        pos = np.array([rc.pos[0], rc.pos[1], float(s.pos[2]) - TAKEOFF_WAIT_M])
        vel = np.array([rc.vel[0], rc.vel[1], 0.0])
        acc = np.array([rc.acc[0], rc.acc[1], 0.0])
        return Reference(pos, vel, acc, rc.yaw, rc.yaw_rate)

    def _raise_takeoff_thrust(self, s):
        """While the takeoff waits: the thrust per acceleration up by TAKEOFF_RAMP_PER_S of
        itself per second, as an autopilot ramps its takeoff thrust until the vehicle lifts
        off.  Why the flight must end, once it has sat at the bound for TAKEOFF_WAIT_MAX_S."""
        step = s.dt if s.dt is not None else self.h
        if self.takeoff_wait <= step + 1e-9:
            self.say(f"still on the ground {TAKEOFF_WAIT_M:g} m below the takeoff's reference: "
                     "the reference waits, the thrust rises until it lifts off")
        self.ctrl.raise_thrust(1.0 + TAKEOFF_RAMP_PER_S * step)
        if self.ctrl.thrust_at_most:
            self._waited_capped += step
            if self._waited_capped >= TAKEOFF_WAIT_MAX_S:
                return (f"the vehicle did not lift off: {self.takeoff_wait:.0f} s on the ground "
                        f"with the hover thrust raised to {self.ctrl.hover_thrust_estimate:.2f} "
                        f"(told {self.hover:.2f})")
        return None

    def _link_line(self):
        loss = self.gate.recent_loss()
        ooo = self.gate.recent_out_of_order()
        rtt = self.link.timesync.rtts[-1] if self.link.timesync.rtts else None
        return (f"{self.gate.achieved_rate():.0f} Hz, lost {100 * (loss - ooo):.1f} %"
                + (f", out of order {100 * ooo:.1f} %" if ooo >= 0.0005 else "")
                + (f", rtt {1e3 * rtt:.1f} ms" if rtt is not None and not self.lockstep else ""))

    def _check_link(self):
        why = self.supervisor.link(self.gate)
        if why is not None:
            return self._escalate("link", why)
        warn = self.supervisor.link_warning(self.gate)
        if warn is not None:
            self._warn_once("link", warn, latest=True)
        if self.link.other_sources and "sources" not in self._warned:
            # heard in flight: only the vehicle flown is answered and read (said once; the
            # summary's link counts the other's messages)
            self._warn_once("sources", f"{self.link.sources_text()}; the flight goes on with "
                            "the one it flies", every=math.inf)

    def _left_control(self):
        """The pilot or a failsafe took the vehicle: stop commanding, watch it land.  Judged only
        from a heartbeat newer than the mode the flight confirmed."""
        hb = self.link.heartbeat
        if not self._in_control_seen or hb is None or self.seq.in_control(hb):
            return False
        self._escalate("left_control",
                       f"the vehicle left {self.seq.control_mode} for {self.mode_name()}")
        return True

    # --- the wall clock ----------------------------------------------------------------------------

    def _tick(self, now):
        """Wall-clock duties: heartbeat and time sync out, commands re-sent, stale telemetry,
        the deadline, the failsafe's progress, and lockstep kicks."""
        link = self.link
        if self.rec.lost is not None and "record" not in self._warned:
            self._warn_once("record", f"the record stopped being written ({self.rec.lost}): the "
                            "flight goes on without it", every=math.inf)
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
            why = self.supervisor.stale(now, self._last_sample_wall,
                                        max(self._last_send_wall, self._handled_wall))
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

    def _truth_figures(self):
        """summary.json's ``truth``: the true track's error and the estimate's, or None (said
        in ``sources``: why)."""
        if self.truth is None:
            return None
        fig = self.truth.figures(self.recorder.t, self.recorder.ref, self.m.settle_s)
        if fig is None:
            self.sources["truth"] = (f"none: {self.truth.source} asked, "
                                     f"{self.streams.get(self.truth.source, '?')}; "
                                     f"{self.truth.received} true samples came (a simulator "
                                     "sends them, a real vehicle does not)")
            return None
        self.sources["truth"] = f"{fig['source']} at {fig['rate_hz'] or 0:.0f} Hz, aligned " \
                                f"{fig['aligned']}"
        self.say(truth_text(fig, self.m.settle_s))
        return fig

    def _rangefinder_figures(self):
        """summary.json's ``rangefinder``: the height estimate against a downward range finder,
        or None (no reading in the mission)."""
        fig = self.rangefinder.figures(self.m.settle_s)
        if fig is None:
            return None
        self.sources["rangefinder"] = f"{fig['source']}, {fig['aligned']}"
        self.say(rangefinder_text(fig, self.m.settle_s))
        return fig

    def controller_record(self):
        """The controller flown as a mission's ``controller:`` section (:func:`controller_record`);
        None if the gains could not be resolved."""
        try:
            kind, gains = self._controller_flown()
        except Exception:
            return None
        return controller_record(self.m.controller, kind, gains)

    def _named_values(self, s):
        """The observers' disturbance estimates at 10 Hz, live, for a ground station."""
        if self.kind != "pd" and s.t - self._last_named >= 0.1:
            self._last_named = s.t
            z3 = self.ctrl.disturbance
            for i, a in enumerate("xyz"):
                self.link.named_float(s.t * 1000.0, f"z3_{a}", float(z3[i]))

    def _in_final_land(self, t):
        """Whether mission time ``t`` is in the mission's closing land segment."""
        return (self.m.ends_landed and bool(self.phases) and self.phases[-1][1] == "land"
                and t >= self.phases[-1][0])

    def _segment_name(self, t):
        name = self.phases[0][1] if self.phases else ""
        for t0, n in self.phases:
            if t >= t0:
                name = n
        return name

    def _finish(self):
        self.recorder.flush()
        truth = self._truth_figures()
        rangefinder = self._rangefinder_figures()
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
            "sample_age_ms_max": float(max(self.ages) * 1e3) if self.ages else None,
            "samples_late": int(sum(a > LATE_S for a in self.ages)),
            # how much faster the vehicle's clock ran than ours (TIMESYNC; a simulator's runs
            # slow when it cannot keep up): None in lockstep, where the ages come from its clock
            "clock_skew": None if self.lockstep or self.link.timesync.offset_ns is None
            else self.link.timesync.skew,
            "frames_received": self.link.frames_received,
            "frames_lost": self.link.frames_lost,
            "frame_loss_fraction": self.link.frame_loss(),
            "bad_frames": self.link.bad_frames,
            "bad_signatures": self.link.bad_signatures,
            "other_system_messages": self.link.other_system,
            # messages of the flown system from another address (a second vehicle with its id)
            "other_source_messages": sum(self.link.other_sources.values()),
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
            "touchdown_height_m": self.touchdown_height,
            "touchdown_soft": soft,
            "disarmed": bool(disarmed),
            # after touchdown: by our command, by the autopilot's land mode (handed the landing,
            # after its detector refused the disarm for refused_s, or ArduPilot's always), or by
            # the autopilot alone (its auto-disarm); after_cut_s from the thrust cut
            "disarm": {"by": self.disarm_how, "refused_s": self.disarm_refused_s,
                       "after_cut_s": self.disarm_after_s},
            "aborted": aborted,
            # the console (stdout) failing or the terminal hanging up ends nothing: the flight
            # went on, and what the console would have said is in companion.log
            "console": {"lost": self.console.lost, "hung_up_at_s": self.hung_up_at},
            # a record file that could not be written (a full disk): given up, flown on
            "record_lost": self.rec.lost,
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
            # the first (the arming's) and the last (the landing's) when there are many
            "vehicle_messages": (self.texts if len(self.texts) <= sum(TEXTS_KEPT)
                                 else self.texts[:TEXTS_KEPT[0]] + self.texts[-TEXTS_KEPT[1]:]),
            "vehicle_messages_left_out": max(0, len(self.texts) - sum(TEXTS_KEPT)),
        }
        if self.ctrl is not None:
            summary["delay_margin_s"] = margin_record(self.delay_margin)
            # the hover thrust learnt in flight (thrust_estimate), against the one told above
            summary["hover_thrust_learnt"] = (self.ctrl.hover_thrust_estimate
                                              if self.ctrl.learns_thrust else None)
            # s the takeoff's reference waited for the vehicle to lift off (0: it never did),
            # and the hover thrust it had been raised to when it did (None: not raised); the
            # mission time the lift-off was seen (None: not in the mission), and whether a
            # range finder had held a lift-off the height estimate read for the estimate's alone
            summary["takeoff_wait_s"] = round(self.takeoff_wait, 3)
            summary["liftoff_s"] = self.liftoff_s
            summary["liftoff_disputed"] = self._range_disputed
            summary["liftoff_hover_thrust"] = self.liftoff_hover
            # the horizontal drag learnt along the mission (drag_learn), against its start
            summary["drag_learnt"] = None if self._learner is None else self._learner.record()
        if self.identification is not None:
            summary["identification"] = self.identification
            if self.gains_scaled is not None:
                # the mission's own gains slowed for a vehicle slower than theirs
                summary["gains_scaled"] = self.gains_scaled
        if self._attitudes:
            a = np.asarray(self._attitudes)
            osc = attitude_oscillation(a[:, 0], a[:, 1], a[:, 2])
            summary["attitude_oscillation"] = osc
            text = swing_warning(osc)
            if text is not None:
                self.say(f"warning: {text}")
                summary["warnings"].append(text)
            self._margin_outcome(summary["warnings"], osc)
        text = late_warning(self.ages)
        if text is not None:
            self.say(f"warning: {text}")
            summary["warnings"].append(text)
        if self.latency:
            lat = np.asarray(self.latency) * 1e3
            summary["latency_p50_ms"] = float(np.percentile(lat, 50))
            summary["latency_p99_ms"] = float(np.percentile(lat, 99))
        summary.update(self.recorder.errors())
        if self.m.settle_s > 0:
            summary["after_settle"] = self.recorder.errors(self.m.settle_s)
        summary["truth"] = truth
        summary["rangefinder"] = rangefinder
        summary["controller_flown"] = self.controller_record()
        summary["takeoff_controller"] = self.takeoff_controller
        summary["takeoff_spot_moved_m"] = self.origin_moved_m
        summary.update(self.context)
        summary = finite(summary)  # a figure that does not exist is None, in the file and here
        try:
            self.rec.write_summary(summary)
        except OSError as exc:
            self.say(f"summary.json could not be written ({exc.strerror or exc}); the summary "
                     "follows here only")
        return summary


def _bandwidths(gains):
    """", wc (...), wo (...)" of ``gains`` for the console ("" without both)."""
    if "wc" not in gains or "wo" not in gains:
        return ""
    return (f", wc ({', '.join(f'{x:.2f}' for x in gains['wc'])}), wo "
            f"({', '.join(f'{x:.1f}' for x in gains['wo'])})")


def carry_on(ctrl, old):
    """Go on with ``ctrl`` (of ``old``'s kind, its gains or model changed) where ``old`` is:
    every observer state, the input model's state and the thrust learnt, so the loop goes on
    without a jump mid-mission."""
    ctrl._S[:] = old._S
    same = np.array_equal(ctrl._IN[:, [IN_NLAG, IN_ND]], old._IN[:, [IN_NLAG, IN_ND]])
    for i in range(3):
        if same:  # the same stages: their states go on (the new lags' alphas take over)
            for col in (IN_STATE, IN_L1, IN_HEAD):
                ctrl._IN[i, col] = old._IN[i, col]
            ctrl._IN[i, IN_BUF:] = old._IN[i, IN_BUF:]
        else:  # reshaped: held at the acceleration it gave
            input_model_rest(ctrl._IN[i], old._IN[i, IN_STATE])
    if ctrl.learns_thrust and old.learns_thrust:
        ctrl.adopt_thrust(old)


def carry_over(ctrl, old, pos, vel, ref_vel=None):
    """Start ``ctrl`` where ``old`` left off: at the measured ``pos``/``vel``, with ``old``'s
    disturbance estimates, the thrust it had learnt (both learning) and the acceleration it
    last commanded as the input model's state (a controller made anew mid-flight then takes
    over without a jump).  ``ref_vel``: the reference's velocity now; the drag along it that
    ``ctrl`` models and ``old`` did not is moved out of the disturbance estimates (left in, it
    was fed forward twice: on PX4 SIH, taking over 1.5 s into the run-up at 0.75 m/s, the
    command went from -1.2 to -3 m/s^2 and the vehicle fell 0.17 m off)."""
    ctrl.reset(pos, vel)
    ctrl._S[:, K.S_Z3] = old._S[:, K.S_Z3]
    if ref_vel is not None:
        ctrl._S[:, K.S_Z3] += (ctrl.drag - old.drag) * np.asarray(ref_vel, dtype=float)
    for i, a in enumerate(old.accel_applied):
        input_model_rest(ctrl._IN[i], a)
    if ctrl.learns_thrust and old.learns_thrust:
        ctrl.adopt_thrust(old)
    elif old.learns_thrust:  # the new one keeps the thrust told: its z3 is the whole disturbance
        ctrl._S[2, K.S_Z3] = old.disturbance[2]


def controller_record(spec, kind, gains):
    """A mission's ``controller:`` section that flies the controller flown: its kind, rate,
    limits and every gain resolved (plain lists and numbers, for YAML and JSON)."""
    rec = {"type": kind, "rate_hz": spec.rate_hz, "tilt_max_deg": spec.tilt_max_deg,
           "thrust_min": spec.thrust_min, "thrust_max": spec.thrust_max}
    if spec.thrust_tilt != "commanded":
        rec["thrust_tilt"] = spec.thrust_tilt
    if spec.takeoff != "safe" and kind in ("ladrc", "adrc"):
        rec["takeoff"] = spec.takeoff
    for k, v in (gains or {}).items():
        rec[k] = [float(x) for x in v] if isinstance(v, (tuple, list, np.ndarray)) else v
    return rec


def swing_text(osc):
    """How an :func:`~mavadrc.flight.record.attitude_oscillation` reads: "+-A deg at F Hz, ..."."""
    where = "" if osc["frequency_hz"] is None else f" at {osc['frequency_hz']:.2f} Hz"
    kind = {True: "regular (a limit cycle)", False: "irregular",
            None: "too short a record to tell its kind"}[osc["limit_cycle"]]
    like = "" if osc["regularity"] is None else \
        f", {osc['regularity']:.2f} alike {REGULARITY_PERIODS} periods later"
    return f"+-{osc['amplitude_deg']:.1f} deg{where}, {kind}{like}"


def swing_warning(osc):
    """The warning a flight's roll/pitch swing earns (None under :data:`OSCILLATION_WARN_DEG`),
    its kind said as measured.  A regular swing (alike period after period) is a limit cycle:
    the controller too fast for the vehicle's attitude response.  An irregular one is no steady
    cycle: a loop's resonance driven by noise or wind (PX4 SIH's swing on `x500_gusts`, driven
    by its position estimate's noise: README) swings so, and so does an instability broken up
    by lost or late samples and the tilt limit (fast path: 20-59 deg read 0.17-0.59).  Either
    way the flight is no good one, whatever its error says.  On a record too short to tell the
    kind (``limit_cycle`` None), no kind is named."""
    if osc is None or osc["amplitude_deg"] <= OSCILLATION_WARN_DEG:
        return None
    if osc["limit_cycle"] is None:
        return (f"roll/pitch swung {swing_text(osc)}: a limit cycle or a resonance, the record "
                "cannot say; a swing this large is no good flight, whatever the error says")
    if osc["limit_cycle"] is False:
        return (f"roll/pitch swung {swing_text(osc)}: no steady limit cycle (a loop's "
                "resonance driven by noise in the position estimate or by the wind swings so, "
                "and so does an instability broken up by lost or late samples and the tilt "
                "limit); a swing this large is no good flight, whatever the error says")
    return (f"roll/pitch swung {swing_text(osc)}: a limit cycle, whatever the error says (the "
            "controller is too fast for this vehicle's attitude response)")


def print_table(summary, out=None):
    out = out if out is not None else sys.stdout
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
        if a["rms_error_m"] is None:
            out.write(f"  after {summary['settle_s']:.0f} s: not reached\n")
        else:
            out.write(f"  after {summary['settle_s']:.0f} s: RMS {a['rms_error_m']:.4f}, "
                      f"max {a['max_error_m']:.4f}\n")
    osc = summary.get("attitude_oscillation")
    if osc is not None:
        out.write(f"  roll/pitch swing {swing_text(osc)}\n")
    learnt, told = summary.get("hover_thrust_learnt"), summary.get("hover_thrust")
    if learnt is not None and told is not None:
        out.write(f"  hover thrust learnt in flight {learnt:.3f} (told {told:.3f})\n")
    drag = summary.get("drag_learnt")
    if drag is not None:
        if drag["first_used_s"] is None:
            out.write("  drag not learnt: the reference did not move enough "
                      f"(kept {_pair(drag['start_per_s'])} /s)\n")
        else:
            out.write(f"  drag learnt in flight {_pair(drag['per_s'])} /s north, east (from "
                      f"{_pair(drag['start_per_s'])}, {drag['first_used_s']:.0f} s into the "
                      "mission)\n")
    out.flush()


def _pair(v):
    return ", ".join("-" if x is None else f"{x:.2f}" for x in v)

