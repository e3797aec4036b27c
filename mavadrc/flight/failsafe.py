"""Carrying out the supervisor's actions.

The :class:`~mavadrc.flight.supervisor.Supervisor` says what a condition calls for; this carries it
out: the autopilot's land mode (after a hold where the table says so), re-sent until a heartbeat
newer than the command shows it, watched until a heartbeat shows the vehicle disarmed, with the
vehicle held by our controller until then; before lift-off, a disarm; when the vehicle cannot be
reached, an end that says what was last known of it.
"""

import math
import time

from mavadrc.control.rotations import level_quat
from mavadrc.flight.state import vehicle_mode
from mavadrc.flight.supervisor import GIVE_UP, HOLD_THEN_LAND, LAND, WATCH
from mavadrc.mavlink.dialect import M

#: a failsafe mode command is re-sent this often (s) until the heartbeat shows the mode
RESEND_S = 1.0
#: no heartbeat for this long (s) while landing: the vehicle cannot be reached
UNREACHABLE_S = 10.0
#: the hold a failsafe asks for before landing, not shown this long (s) after it was first
#: asked, or refused (ArduCopter's BRAKE without a position estimate), is skipped: land
HOLD_CONFIRM_S = 3.0


def _doing(action):
    """What a failsafe action does, as the console says it."""
    return ("watching the autopilot land" if action == WATCH else "landing" if action == LAND
            else "hold, then land")


class Failsafe:
    """The supervisor's action in force (``action``, None: none) and its progress (``step``:
    "hold", "land", "watch" or "disarm", the mode asked for now)."""

    def __init__(self, supervisor, link, clock, vehicle, progress, notices, setpoints, steering,
                 confirm, *, lockstep, deadline, max_wall_s):
        self.supervisor = supervisor
        self.link = link
        self.clock = clock
        self.v = vehicle
        self.progress = progress
        self.notices = notices
        self.setpoints = setpoints
        self.steering = steering
        self.confirm = confirm
        self.lockstep = lockstep
        self.deadline = deadline
        self.max_wall_s = max_wall_s
        self.action = None  # the action in force (supervisor constants)
        self.step = None  # "hold" or "land": the mode asked for now
        self.wall = 0.0
        self._sent = 0.0
        self._hold_cmd = None

    def escalate(self, condition, why, hint=None):
        """``condition`` (a supervisor's rule) for the reason ``why``: start the failsafe it
        asks for, said in one line (``hint``, in brackets after it: what the user can do next).
        A condition that asks no more than the failsafe already under way is said only when it
        has a ``hint`` (the user's own interrupt always gets an answer)."""
        action = self.supervisor.report(condition, why)
        more = f" ({hint})" if hint else ""
        if action is None:
            if hint and self.action is not None:
                self.notices.say(f"{why}: already {_doing(self.action)}{more}")
            return
        if action == GIVE_UP:
            return self.give_up(why)
        phase = self.clock.phase
        if phase in ("setup", "measure", "mode", "arming") or (
                phase == "spoolup" and not self.link.armed):
            # nothing in the air: a vehicle on the ground is disarmed, not landed
            return self._ground_abort(why)
        self.notices.say(f"{why}: {_doing(action)}{more}")
        self.start(action)

    def left_control(self):
        """The pilot or a failsafe took the vehicle: stop commanding, watch it land.  Judged only
        from a heartbeat newer than the mode the flight confirmed."""
        hb = self.link.heartbeat
        if not self.v.in_control_seen or hb is None or self.v.seq.in_control(hb):
            return False
        self.escalate("left_control", f"the vehicle left {self.v.seq.control_mode} for "
                      f"{vehicle_mode(self.link)}")
        return True

    def _ground_abort(self, why):
        """Before lift-off: disarm if armed (confirmed), and end."""
        self.notices.say(f"{why}: stopping on the ground")
        self.action = LAND
        self.step = "disarm"
        self.wall = time.monotonic()
        if not self.link.armed:
            self.clock.phase = "done"

    def start(self, action):
        self.action = action
        self.wall = time.monotonic()
        self._sent = 0.0
        self.steering.hold_point = None
        self._hold_cmd = None  # the last hold asked for (its answer)
        if self.clock.phase in ("spoolup",) and not self.progress.lifted:
            self.step = "disarm"
        elif action == HOLD_THEN_LAND:
            self.step = "hold"
        elif action == LAND:
            self.step = "land"
        else:
            self.step = "watch"
        self.clock.phase = "failsafe"
        self._command(time.monotonic())

    def _command(self, now):
        """(Re-)send the mode the failsafe asks for until a heartbeat newer than it shows it."""
        step, seq, say = self.step, self.v.seq, self.notices.say
        if step == "watch":
            return
        if now - self._sent < RESEND_S:
            return
        hb = self.link.heartbeat_since(self._sent) if self._sent else None
        held = step == "hold" and hb is not None and (seq.is_hold(hb) or seq.is_landing(hb))
        refused = self._hold_cmd is not None and self._hold_cmd.result not in (
            None, M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_IN_PROGRESS)
        if step == "hold" and not held and (refused or now - self.wall >= HOLD_CONFIRM_S):
            why = ("the autopilot refused its hold mode" if refused
                   else f"no hold shown in {HOLD_CONFIRM_S:g} s")
            say(f"{why}: landing without it")
            self.step = "land"
            self._sent = 0.0
            return self._command(now)
        if held:
            if now - self.wall >= 2.0:
                self.step = "land"
                self._sent = 0.0
                return self._command(now)
            return
        if step == "land" and hb is not None and seq.is_landing(hb):
            self.step = "watch"
            say(f"the autopilot is in {vehicle_mode(self.link, hb.custom_mode)}: watching it land")
            return
        if step == "disarm" and hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self.clock.phase = "done"
            return
        self._sent = now
        if step == "hold":
            self._hold_cmd = seq.request_hold(self.link)
        elif step == "land":
            self.link.command(M.MAV_CMD_NAV_LAND)
        elif step == "disarm":
            self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        self.confirm.ask_heartbeat()

    def sample(self, s):
        """While the failsafe's mode is not yet confirmed, keep the vehicle where it is with our
        own controller (it is still in our mode); once it is, the autopilot flies."""
        hb = self.link.heartbeat
        ours = hb is not None and self.v.seq.in_control(hb)
        if self.step == "disarm":
            self.setpoints.idle(s.t, self.v.yaw)
        elif ours and self.action != WATCH and self.clock.phase == "failsafe" and \
                self.progress.traj is not None and self.progress.start is not None:
            self.steering.step(s, None, hold=True)
        elif self.lockstep:  # the clock must go on
            self.setpoints.send(s.t, level_quat(self.v.yaw), self.setpoints.last[1])
        self._disarmed()

    def tick(self, now):
        self._command(now)
        hb_age = now - self.link.heartbeat_wall if self.link.heartbeat_wall else math.inf
        if hb_age > UNREACHABLE_S:
            return self.escalate("unreachable",
                                 f"no heartbeat for {hb_age:.0f} s: the vehicle cannot be reached")
        if self.clock.phase == "done":
            return
        bound = self._landing_bound()
        if now - self.wall > bound:
            self.escalate("landing_timeout",
                          f"the vehicle has not disarmed {bound:.0f} s after the failsafe began")
        if self.deadline is not None and now > self.deadline + bound:
            self.give_up(f"--timeout ({self.max_wall_s:g} s) and the landing bound passed")
        self._disarmed()

    def _disarmed(self):
        """A heartbeat newer than the failsafe shows the vehicle disarmed: the flight is over."""
        hb = self.link.heartbeat_since(self.wall)
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED \
                and self.clock.phase != "done":
            where = self.last_known(armed=False, age=False)
            self.end_disarmed(hb, "disarmed" + ("" if self.progress.handed_over
                                                else f" ({where})"))

    def end_disarmed(self, hb, text):
        """A heartbeat shows the vehicle disarmed: the flight is over.  Still in our mode (PX4
        goes back to OFFBOARD once its own failsafe has landed and disarmed it), it is put in
        its hold mode, as MAVSDK's offboard.stop() does, so the next flight does not find it
        taken."""
        self.progress.disarm_confirmed = True
        self.notices.say(text)
        if self.v.seq.in_control(hb):
            self.link.wait(self.v.seq.release(self.link))
        self.clock.phase = "done"

    def _landing_bound(self):
        """How long the autopilot may take to land and disarm: from the height, at 0.4 m/s
        (PX4 lands at 0.7, ArduCopter at 0.5), plus 30 s for the detector and the return."""
        height = 0.0
        last, origin = self.v.last, self.progress.origin
        if last is not None and origin is not None:
            height = max(0.0, origin[2] - last.pos[2])
        return 30.0 + height / 0.4

    def give_up(self, why):
        self.supervisor.report("unreachable" if "reach" in why else "landing_timeout", why)
        self.action = GIVE_UP
        self.notices.say(f"{why}: giving up; last known: {self.last_known()}")
        self.clock.phase = "done"

    def last_known(self, armed=True, age=True):
        """The vehicle's last known state, in a line: "armed, AUTO.LAND, 1.4 m up, 3.2 s ago"
        (without the first word when not ``armed``, without the last two when not ``age``)."""
        now = time.monotonic()
        parts = []
        if self.link.heartbeat is not None:
            if armed:
                parts.append("armed" if self.link.armed else "disarmed")
            parts.append(vehicle_mode(self.link))
        last, origin = self.v.last, self.progress.origin
        if last is not None and origin is not None:
            parts.append(f"{origin[2] - last.pos[2]:.1f} m up")
        if age and self.v.last_sample_wall is not None:
            parts.append(f"{now - self.v.last_sample_wall:.1f} s ago")
        return ", ".join(parts) if parts else "nothing heard"
