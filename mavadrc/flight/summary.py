"""summary.json: what a flight did, as measured, written whatever happened; the warnings its
end earns (a swing, samples answered late) and the table the command prints."""

import sys

import numpy as np

from mavadrc.design.margin import margin_record
from mavadrc.flight.rangefinder import rangefinder_text
from mavadrc.flight.record import REGULARITY_PERIODS, attitude_oscillation, finite
from mavadrc.flight.truth import truth_text

#: summary.json's vehicle_messages: the vehicle's first and last texts kept (the rest counted)
TEXTS_KEPT = (20, 30)
#: roll/pitch oscillation (deg) worth a warning
OSCILLATION_WARN_DEG = 5.0
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


def margin_outcome(notices, warnings, osc):
    """The margin warning (a limit cycle predicted from the delay margin, in ``warnings``)
    with what the flight measured, where it swung no more than
    :data:`OSCILLATION_WARN_DEG`: a warning left saying "expected" would say more than was
    measured.  (A larger swing has its own warning beside it.)"""
    said = notices.warned_text.get("margin")
    if said is None or osc is None or said not in warnings or osc["limit_cycle"] is None:
        return
    if osc["amplitude_deg"] > OSCILLATION_WARN_DEG:
        return
    seen = f"{swing_text(osc)}: none past the {OSCILLATION_WARN_DEG:g} deg warned at"
    warnings[warnings.index(said)] = f"{said}; measured: {seen}"
    notices.say(f"the delay margin's warning against what was flown: {seen}")


class Summary:
    """The summary of a flight, from the parts that flew it (:meth:`write`)."""

    def __init__(self, flight):
        f = flight
        self.m, self.link, self.rec, self.recorder = f.m, f.link, f.rec, f.recorder
        self.notices, self.v, self.progress, self.choice = f.notices, f.v, f.progress, f.choice
        self.takeoff, self.landing, self.receive = f.takeoff, f.landing, f.receive
        self.tracks, self.gate, self.setpoints = f.tracks, f.gate, f.setpoints
        self.supervisor, self.failsafe = f.supervisor, f.failsafe
        self.flight = f

    def _truth_figures(self):
        """summary.json's ``truth``: the true track's error and the estimate's, or None (said
        in ``sources``: why)."""
        truth, sources = self.tracks.truth, self.v.sources
        if truth is None:
            return None
        fig = truth.figures(self.recorder.t, self.recorder.ref, self.m.settle_s)
        if fig is None:
            sources["truth"] = (f"none: {truth.source} asked, "
                                f"{self.v.streams.get(truth.source, '?')}; "
                                f"{truth.received} true samples came (a simulator "
                                "sends them, a real vehicle does not)")
            return None
        sources["truth"] = f"{fig['source']} at {fig['rate_hz'] or 0:.0f} Hz, aligned " \
                           f"{fig['aligned']}"
        self.notices.say(truth_text(fig, self.m.settle_s))
        return fig

    def _rangefinder_figures(self):
        """summary.json's ``rangefinder``: the height estimate against a downward range finder,
        or None (no reading in the mission)."""
        fig = self.tracks.rangefinder.figures(self.m.settle_s)
        if fig is None:
            return None
        self.v.sources["rangefinder"] = f"{fig['source']}, {fig['aligned']}"
        self.notices.say(rangefinder_text(fig, self.m.settle_s))
        return fig

    def _link(self):
        ages, link = self.receive.ages, self.link
        rtts = np.asarray(link.timesync.rtts) * 1e3
        out = self.gate.figures()
        out.update({
            "rtt_ms_median": float(np.median(rtts)) if rtts.size else None,
            "rtt_ms_max": float(rtts.max()) if rtts.size else None,
            "sample_age_ms_median": float(np.median(ages) * 1e3) if ages else None,
            "sample_age_ms_p99": float(np.percentile(ages, 99) * 1e3) if ages else None,
            "sample_age_ms_max": float(max(ages) * 1e3) if ages else None,
            "samples_late": int(sum(a > LATE_S for a in ages)),
            # how much faster the vehicle's clock ran than ours (TIMESYNC; a simulator's runs
            # slow when it cannot keep up): None in lockstep, where the ages come from its clock
            "clock_skew": None if self.flight.lockstep or link.timesync.offset_ns is None
            else link.timesync.skew,
            "frames_received": link.frames_received,
            "frames_lost": link.frames_lost,
            "frame_loss_fraction": link.frame_loss(),
            "bad_frames": link.bad_frames,
            "bad_signatures": link.bad_signatures,
            "other_system_messages": link.other_system,
            # messages of the flown system from another address (a second vehicle with its id)
            "other_source_messages": sum(link.other_sources.values()),
        })
        return out

    def write(self):
        """The summary (written to summary.json: said so when it cannot be)."""
        f, p, c, land, v = self.flight, self.progress, self.choice, self.landing, self.v
        texts, say = self.notices.texts, self.notices.say
        self.recorder.flush()
        truth = self._truth_figures()
        rangefinder = self._rangefinder_figures()
        hb = self.link.heartbeat
        disarmed = hb is not None and not self.link.armed
        soft = land.speed is None or land.speed <= self.m.safety.max_touchdown_speed
        landed = (p.touchdown_seen or p.handed_over) and p.disarm_confirmed and soft
        aborted = list(self.supervisor.reasons)
        summary = {
            "controller": c.kind,
            "mission": self.m.name,
            "mission_file": self.m.source,
            "autopilot": self.link.autopilot,
            "vehicle": v.identity,
            "duration_s": self.recorder.duration,
            "landed": bool(landed and not aborted),
            "touchdown_seen": p.touchdown_seen,
            "touchdown_speed_mps": land.speed,
            "touchdown_height_m": land.height,
            "touchdown_soft": soft,
            "disarmed": bool(disarmed),
            # after touchdown: by our command, by the autopilot's land mode (handed the landing,
            # after its detector refused the disarm for refused_s, or ArduPilot's always), or by
            # the autopilot alone (its auto-disarm); after_cut_s from the thrust cut
            "disarm": {"by": land.disarm_how, "refused_s": land.disarm_refused_s,
                       "after_cut_s": land.disarm_after_s},
            "aborted": aborted,
            # the console (stdout) failing or the terminal hanging up ends nothing: the flight
            # went on, and what the console would have said is in companion.log
            "console": {"lost": self.notices.console.lost, "hung_up_at_s": f.hung_up_at},
            # a record file that could not be written (a full disk): given up, flown on
            "record_lost": self.rec.lost,
            "last_known_state": self.failsafe.last_known(),
            "samples": self.gate.received,
            "control_steps": p.steps,
            "setpoints_sent": self.setpoints.sent,
            "samples_seen": v.samples_seen,
            "setpoints_without_sample": self.setpoints.kicks,
            "samples_answered_twice": self.setpoints.double_answers,
            "missed_periods": self.gate.missing,
            "link": self._link(),
            "streams": v.streams,
            "rate_requested_hz": self.m.controller.rate_hz,
            "rate_hz": c.rate,
            "settle_s": self.m.settle_s,
            "mission_start_s": p.start,
            "hover_thrust": c.hover,
            "motor_delay_s": v.motor_delay,
            "takeover": v.takeover,
            "sources": dict(v.sources),
            "warnings": list(self.notices.warnings),
            # the first (the arming's) and the last (the landing's) when there are many
            "vehicle_messages": (texts if len(texts) <= sum(TEXTS_KEPT)
                                 else texts[:TEXTS_KEPT[0]] + texts[-TEXTS_KEPT[1]:]),
            "vehicle_messages_left_out": max(0, len(texts) - sum(TEXTS_KEPT)),
        }
        if c.ctrl is not None:
            t = self.takeoff
            summary["delay_margin_s"] = margin_record(c.delay_margin)
            # the hover thrust learnt in flight (thrust_estimate), against the one told above
            summary["hover_thrust_learnt"] = (c.ctrl.hover_thrust_estimate
                                              if c.ctrl.learns_thrust else None)
            # s the takeoff's reference waited for the vehicle to lift off (0: it never did),
            # and the hover thrust it had been raised to when it did (None: not raised); the
            # mission time the lift-off was seen (None: not in the mission), and whether a
            # range finder had held a lift-off the height estimate read for the estimate's alone
            summary["takeoff_wait_s"] = round(t.wait, 3)
            summary["liftoff_s"] = t.liftoff_s
            summary["liftoff_disputed"] = t.range_disputed
            summary["liftoff_hover_thrust"] = t.liftoff_hover
            # the horizontal drag learnt along the mission (drag_learn), against its start
            summary["drag_learnt"] = None if c.learner is None else c.learner.record()
        if c.identification is not None:
            summary["identification"] = c.identification
            if c.gains_scaled is not None:
                # the mission's own gains slowed for a vehicle slower than theirs
                summary["gains_scaled"] = c.gains_scaled
        if self.receive.attitudes:
            a = np.asarray(self.receive.attitudes)
            osc = attitude_oscillation(a[:, 0], a[:, 1], a[:, 2])
            summary["attitude_oscillation"] = osc
            text = swing_warning(osc)
            if text is not None:
                say(f"warning: {text}")
                summary["warnings"].append(text)
            margin_outcome(self.notices, summary["warnings"], osc)
        text = late_warning(self.receive.ages)
        if text is not None:
            say(f"warning: {text}")
            summary["warnings"].append(text)
        if self.receive.latency:
            lat = np.asarray(self.receive.latency) * 1e3
            summary["latency_p50_ms"] = float(np.percentile(lat, 50))
            summary["latency_p99_ms"] = float(np.percentile(lat, 99))
        summary.update(self.recorder.errors())
        if self.m.settle_s > 0:
            summary["after_settle"] = self.recorder.errors(self.m.settle_s)
        summary["truth"] = truth
        summary["rangefinder"] = rangefinder
        summary["controller_flown"] = c.record()
        summary["takeoff_controller"] = c.takeoff_controller
        summary["takeoff_spot_moved_m"] = p.origin_moved_m
        summary.update(f.context)
        summary = finite(summary)  # a figure that does not exist is None, in the file and here
        try:
            self.rec.write_summary(summary)
        except OSError as exc:
            say(f"summary.json could not be written ({exc.strerror or exc}); the summary "
                "follows here only")
        return summary


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
    by its position estimate's noise: docs/vehicle.md) swings so, and so does an instability broken up
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

