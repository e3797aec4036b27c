"""The input model identified in flight (``input_lag: auto``): the identify segment's samples
kept, fitted at its end (in lockstep at once; in real time in the fits' own process while the
safe controller flies on), the mission's controller made with the fit taking over without a
jump, and the fit made again once the drag has been learnt."""

import concurrent.futures
import math

import numpy as np

from mavadrc.design.gains import (
    MARGIN_SHARE,
    MISSION_MARGIN_FLOOR,
    TAKEOFF_KIND,
    TAKEOFF_WC,
    fit_and_make,
    run_once,
    takeoff_gains,
)
from mavadrc.design.identify import MAX_DELAY_S, failure_text, partial_text, summary_line
from mavadrc.design.margin import identified_margin_text, prediction_text
from mavadrc.flight.choice import bandwidths, controller_record

#: the drag learnt this long (s) before the identify segment is fitted again with it known
REFINE_AFTER_S = 6.0
#: and the lag refitted flown only when it moves by more than this share
REFINE_TOLERANCE = 0.05


class Identification:
    """The identify segment of a flight: its windows (``windows``, None: the flight identifies
    nothing), its samples and fits."""

    def __init__(self, choice, notices, link, progress, lockstep):
        self.choice = choice
        self.notices = notices
        self.link = link
        self.progress = progress
        self.lockstep = lockstep
        self.windows = None
        self.span = None  # (first window's start, last window's end), mission time
        self.handover_t = None  # mission time the takeoff's PID hands over (takeoff: pid)
        self.fitter = None  # the fits' own process (real time; mavadrc.design.fitworker)
        self._data = []
        self._job = None  # the fit, running in a thread (real time)
        self._samples = None  # the identify segment's samples, fitted again with the drag
        self._refine_job = None
        self._refine_done = False

    def in_doublets(self, time_boot_ms, after=1.0):
        """Whether vehicle time ``time_boot_ms`` falls in the identify segment (or ``after`` s
        past it: the tilt there is still the doublets', not a limit cycle)."""
        if self.windows is None:
            return False
        t = time_boot_ms / 1000.0 - self.progress.t0
        return self.span[0] <= t <= self.span[1] + after

    def data_span(self):
        """(start, end) of the identify segment's samples in mission time: its windows' span,
        from as far before the first as a dead time can reach back for its commands."""
        start, end = self.span
        return start - MAX_DELAY_S - 0.1, end

    def pause_learning(self, t, final_land):
        """Pause or resume learning the hover thrust for mission time ``t`` (``final_land``:
        ``t`` is in the closing land segment).  Not learnt over the identify
        segment's samples (the safe controller learns it in the takeoff and holds it there:
        :func:`~mavadrc.design.gains.identification_gains`), and not from the closing land
        segment on, where the ground may carry the vehicle before the contact is seen (PX4 SIH,
        its estimate climbing on the ground: the vertical observer read the ground's push as a
        lighter vehicle, and the thrust learnt fell from 0.47 to 0.26 by the touchdown)."""
        ctrl = self.choice.ctrl
        if not ctrl.learns_thrust:
            return
        hold = final_land
        if self.windows is not None and self.choice.identifying():
            start, end = self.data_span()
            hold = hold or start <= t <= end
        ctrl.pause_thrust_learning(hold)

    def takeoff_text(self):
        """What flies the takeoff, for the line that starts the mission ("" when it is the
        controller named there, or the safe LADRC of an identifying flight)."""
        if not (self.choice.identifying() and self.choice.takeoff_pid):
            return ""
        return (f", taking off on a PID on the measured velocity (wc {TAKEOFF_WC[0]:g}) and "
                "identifying the vehicle on the safe LADRC first")

    def takeoff_handover(self, s, t, ref_vel):
        """At :attr:`handover_t` (mission time ``t``, sample ``s``), the takeoff's PID hands
        the vehicle to the safe LADRC that flies the doublets, without a jump
        (:meth:`~mavadrc.control.position.PositionController.take_over_from`: its disturbance estimates start at the
        PID's integrator, the thrust learnt is kept; ``ref_vel``: the reference's velocity)."""
        c = self.choice
        if not c.takeoff_pid or self.handover_t is None or t < self.handover_t - 1e-9:
            return
        c.takeoff_pid = False
        old = c.ctrl
        c.ctrl, c.delay_margin = c.after_takeoff
        c.after_takeoff = None
        c.ctrl.take_over_from(old, s.pos, s.vel, ref_vel)
        up = float(self.progress.origin[2] - s.pos[2])
        c.takeoff_controller = {**controller_record(c.m.controller, TAKEOFF_KIND,
                                                    takeoff_gains()),
                                "handed_over_at_s": round(t, 3),
                                "handed_over_at_m": round(up, 3)}
        self.notices.say(f"the takeoff's PID hands over to the safe LADRC for the identification "
                         f"({t:.1f} s into the mission, {up:.2f} m up)")

    def step(self, s, t, ref_vel):
        """Keep the samples of the identify segment; at its end fit the input model and fly
        the mission's controller with it.  The fit and the new controller's delay margin take
        a good part of a second: in lockstep (the vehicle waits) they are made at once, in real
        time in a thread while the safe controller flies on, and the new controller takes over
        at the first sample after they are ready (``ref_vel``: the reference's velocity the
        controller flies to now, for
        :meth:`~mavadrc.control.position.PositionController.take_over_from`)."""
        if self._job is not None:
            if not self._job.done():
                return
            job, self._job = self._job, None
            return self._identified(s, ref_vel, *job.result())
        if self.windows is None or self.choice.identification is not None:
            return
        start, end = self.data_span()
        if t >= start:
            self._data.append((t, *self.choice.ctrl.accel_applied, *s.vel,
                               math.nan if s.age is None else s.age))
        if t < end:
            return
        d = np.asarray(self._data)
        self._data = []
        self._samples = d  # fitted again once the drag is learnt (refine_step)
        if self.lockstep:
            return self._identified(s, ref_vel, *self._fit(d))
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="identify")
        self._job = pool.submit(self._fit, d)
        pool.shutdown(wait=False)

    def _fit(self, d, drag=None):
        """The fit of the identify segment's samples ``d`` (``drag``: known per axis, else
        fitted), and, if it holds, the mission's controller made with it
        (:func:`~mavadrc.design.gains.fit_and_make`: in the fits' own process in real time,
        :mod:`mavadrc.design.fitworker`), its kernels run once here: (record, controller or
        None, gains, delay margin)."""
        c = self.choice
        job = (d, self.windows, f"in flight, on system {self.link.target_system} "
               f"({self.link.autopilot})", c.m.controller, c.kind, c.rate,
               c.hover, c.design_lag, drag, MISSION_MARGIN_FLOOR)
        if self.fitter is None:
            out = fit_and_make(*job)
        else:
            out = self.fitter.call(fit_and_make, *job)
            out[0]["fit_in"] = self.fitter.where
        if out[1] is not None:
            run_once(out[1])
        return out

    def _identified(self, s, ref_vel, rec, ctrl, gains, margin):
        """The identification's result, from sample ``s`` on (``ref_vel``: the reference's
        velocity the controller is flying to now)."""
        c, say = self.choice, self.notices.say
        c.identification = rec
        # mission time of the switch, and how fast the reference moved there
        rec["switched_at_s"] = round(s.t - self.progress.t0, 3)
        rec["switched_at_speed_mps"] = round(float(np.linalg.norm(ref_vel)), 3)
        say(f"input model identified: {summary_line(rec)}")
        if ctrl is None:
            c.learner = None  # the safe gains fly on as they are
            self.notices.warn_once("identify", f"{failure_text(rec)}: the safe default LADRC "
                                   "flies the rest of the mission", every=0.0)
            return
        if partial_text(rec) is not None:
            self.notices.warn_once("identify", partial_text(rec), every=0.0)
        old = c.ctrl
        c.ctrl, c.gains, c.delay_margin = ctrl, gains, margin
        c.ctrl.take_over_from(old, s.pos, s.vel, ref_vel)
        c.learner = c.drag_learner(ctrl, gains)
        lag = ", ".join(f"{x:.3f}" for x in gains["input_lag"])
        bw = bandwidths(gains)
        if c.note_scaling(gains) is not None:
            f, design = c.gains_scaled["factor"], c.gains_scaled["design_lag_s"]
            name = getattr(c.m.vehicle, "name", c.m.vehicle)
            kept = c.gains_scaled.get("wo_factor") == 1.0
            which = f"horizontal wc x{f:.2f}" if kept else f"horizontal wc and wo x{f:.2f}"
            why = " (wo as given: the observers model the lag)" if kept else ""
            took = gains["input_lag"][0]
            if c.gains_scaled["because"] == "slower":
                say(f"the mission's gains were chosen for a vehicle answering in "
                    f"{design[0]:.3f} s horizontally ({name}); this one takes "
                    f"{took:.3f} s: {which}, to keep {'its' if kept else 'their'} delay "
                    f"margin{why}")
            else:
                say(f"the mission's gains keep under {MISSION_MARGIN_FLOOR:.0%} of this "
                    f"vehicle's lag ({took:.3f} s horizontally) as delay margin: {which}, "
                    f"to keep that much{why}")
        drag = ""
        if any(float(x) > 0.0 for x in gains.get("drag", ())) and c.ctrl.drag.any():
            drag = f", drag ({', '.join(f'{float(x):.2f}' for x in gains['drag'])}) /s"
        fitted = rec.get("delay_margin_s")  # on the response identified (lags, dead time)
        margin = c.delay_margin if fitted is None else fitted
        say(f"flying {c.kind} with the observers' input lag ({lag}) s{drag}{bw}"
            f"{prediction_text(c.ctrl)} from here; "
            f"{identified_margin_text(margin, gains, MARGIN_SHARE)}")
        self._warn_unstable(margin)

    def _warn_unstable(self, margin):
        """A limit cycle is predicted only where the loop has no delay margin on the response
        identified (its lags and dead time): a small margin is said with the margin, and the
        end of the flight says what swung (a gains rule once warned "likely" under 75 % of the
        lag; ArduCopter SITL flew 44 % at +-0.5 deg and the bundled spiral 16 % at +-1.2)."""
        if margin is not None and margin <= 0.0:
            self.notices.warn_once(
                "margin", "no delay margin on the response identified: the loop is unstable on "
                "this vehicle's model and a limit cycle is expected (without wc and wo the "
                "defaults are slowed to keep a margin)", every=0.0)

    def refine_step(self, s, t):
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
        learner = self.choice.learner
        if (self._samples is None or self._refine_done or learner.first_used_s is None
                or t - learner.first_used_s < REFINE_AFTER_S):
            return
        self._refine_done = True
        # north and east as learnt (as flown where not yet told); the vertical fitted again
        drag = [float(x) if x == x else float(m)
                for x, m in zip(learner.estimate[:2], self.choice.ctrl.drag[:2])] + [None]
        if self.lockstep:
            return self._refined(s, t, drag, *self._fit(self._samples, drag))
        pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="refine")
        self._refine_job = pool.submit(lambda: (drag, *self._fit(self._samples, drag)))
        pool.shutdown(wait=False)

    def _refined(self, s, t, drag, rec, ctrl, gains, margin):
        """The refit's result (``drag``: the horizontal drag it took as known), from sample
        ``s`` (mission time ``t``) on."""
        c = self.choice
        old_lag = c.gains["input_lag"]
        note = {"at_s": round(t, 2), "drag_per_s": [None if x is None else round(x, 4)
                                                      for x in drag[:2]],
                "axes": rec["axes"], "fit_s": rec["fit_s"], "made_in_s": rec["made_in_s"]}
        if ctrl is None:
            note["flown"] = False
            note["why"] = failure_text(rec)
            c.identification["refined"] = note
            return
        new_lag = gains["input_lag"]
        note["input_lag"] = [round(x, 4) for x in rec["input_lag"]]
        change = abs(new_lag[0] - old_lag[0]) / max(old_lag[0], 1e-9)
        note["flown"] = bool(change > REFINE_TOLERANCE)
        c.identification["refined"] = note
        if not note["flown"]:
            self.notices.say(f"input model fitted again with the drag learnt: {new_lag[0]:.3f} "
                             f"s horizontally (flying {old_lag[0]:.3f}): kept")
            return
        old = c.ctrl
        ctrl.set_drag([*old.drag[:2], ctrl.drag[2]])  # the drag learnt so far goes on
        ctrl.continue_from(old)
        c.ctrl, c.gains, c.delay_margin = ctrl, gains, margin
        rec_margin = rec.get("delay_margin_s")  # on the response refitted (_fit)
        note["delay_margin_s"] = rec_margin
        said = margin if rec_margin is None else rec_margin
        c.note_scaling(gains)
        self.notices.say(f"input model fitted again with the drag learnt "
                         f"({', '.join(f'{x:.2f}' for x in drag[:2])} /s): {new_lag[0]:.3f} s "
                         f"horizontally for the doublets' {old_lag[0]:.3f}; flying it"
                         f"{bandwidths(gains)}{prediction_text(c.ctrl)} from here; "
                         + identified_margin_text(said, gains, MARGIN_SHARE))
        self._warn_unstable(said)
