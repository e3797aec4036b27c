"""Carrying out the supervisor's actions (:class:`Failsafes`, a part of
:class:`~mavadrc.flight.flight.Flight`).

The :class:`~mavadrc.flight.supervisor.Supervisor` says what a condition calls for; this carries it
out: the autopilot's land mode (after a hold where the table says so), re-sent until a heartbeat
newer than the command shows it, watched until a heartbeat shows the vehicle disarmed, with the
vehicle held by our controller until then; before lift-off, a disarm; when the vehicle cannot be
reached, an end that says what was last known of it.
"""

import math
import time

from mavadrc.control.rotations import level_quat
from mavadrc.mavlink.dialect import M
from mavadrc.flight.supervisor import GIVE_UP, HOLD_THEN_LAND, LAND, WATCH

#: a failsafe mode command is re-sent this often (s) until the heartbeat shows the mode
RESEND_S = 1.0
#: no heartbeat for this long (s) while landing: the vehicle cannot be reached
UNREACHABLE_S = 10.0
#: the hold a failsafe asks for before landing, not shown this long (s) after it was first
#: asked, or refused (ArduCopter's BRAKE without a position estimate), is skipped: land
HOLD_CONFIRM_S = 3.0


class Failsafes:
    """The supervisor's actions carried out (methods of :class:`~mavadrc.flight.flight.Flight`)."""

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
        self._hold_cmd = None  # the last hold asked for (its answer)
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
        held = step == "hold" and hb is not None and (self.seq.is_hold(hb)
                                                      or self.seq.is_landing(hb))
        refused = self._hold_cmd is not None and self._hold_cmd.result not in (
            None, M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_IN_PROGRESS)
        if step == "hold" and not held and (refused
                                            or now - self._failsafe_wall >= HOLD_CONFIRM_S):
            why = ("the autopilot refused its hold mode" if refused
                   else f"no hold shown in {HOLD_CONFIRM_S:g} s")
            self.say(f"{why}: landing without it")
            self._failsafe_step = "land"
            self._failsafe_sent = 0.0
            return self._failsafe_command(now)
        if held:
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
            self._hold_cmd = self.seq.request_hold(self.link)
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
            self._end_disarmed(hb, "disarmed" + ("" if self._handed_over
                                                  else f"; {self.last_known()}"))

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
