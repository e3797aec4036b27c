"""The flight's phases on the ground: mode, arming and spool-up before the mission, touchdown,
thrust cut and disarm after it (:class:`GroundPhases`, a part of :class:`~mavadrc.flight.flight.Flight`).

Mode and arming: each command confirmed by its answer and by a heartbeat newer than it (a lost
answer is settled by the heartbeat).  Spool-up: the motors' delay waited out, thrust ramped; the
mission clock starts at the end of the ramp, or earlier if the vehicle lifts off.  Touchdown: the
land segment's descent goes on slowly until touchdown is seen (the autopilot's ON_GROUND, or
vertical speed and height settled); then the thrust is cut, and the disarm follows the
autopilot's landing detector.
"""

import math

import numpy as np

from mavadrc.control.geometry import GRAVITY
from mavadrc.control.rotations import level_quat, wrap_pi
from mavadrc.errors import FlightError
from mavadrc.mavlink.commands import TIMEOUT, result_name
from mavadrc.mavlink.dialect import M
from mavadrc.mission.identification import HANDOVER_S, TAKEOFF_HANDOVER_S, leg_speed_of, windows_in
from mavadrc.design.margin import margin_text, prediction_text
from mavadrc.mission.config import FINAL_SPEED
from mavadrc.mission.trajectories import Reference
from mavadrc.mission.takeoff import SPOOL_S, lifted_off, spool_thrust

#: touchdown: the vertical speed stays under this (m/s) for this long (s), the reference below
SETTLED_SPEED = 0.1
SETTLED_S = 0.3
#: the speed is the velocity estimate's, or the position estimate's over this window (s): on
#: PX4 SIH the velocity estimate once read a 0.2-0.35 m/s descent for 6 s while the vehicle sat
#: on the ground and its position estimate moved 0.01-0.03 m/s; touchdown went unseen, the flight
#: ended on its bound and PX4's land mode landed it
STILL_WINDOW_S = 0.5
#: and, for the speed alone to say so, the reference has gone on this much further down, both
#: itself and against the vehicle, since the speed fell under SETTLED_SPEED (m): a reference
#: pausing where a land segment's final leg begins, 0.5 m up, with a slow loop 8 cm behind it
#: and slowing, read as settled on PX4 SIH; the thrust was cut and the vehicle fell 0.5 m
#: (2.4 m/s).  A heavier vehicle (PX4 SIH at 1.4 kg) rose 3.5 cm back from that pausing
#: reference, the gap grew without the reference moving, and it fell 0.67 m (2.3-2.8 m/s)
GAP_GROWTH = 0.05
#: touchdown also: the vertical disturbance estimate holds up this share of g (the ground carries
#: the vehicle's weight), the reference below it, for SETTLED_S, whatever the velocity reads
CARRIED_SHARE = 0.6
#: a touchdown seen unscores the steps from the contact: where the vertical disturbance estimate
#: began to hold up more than this share of g (and held it to the last scored step).  PX4 SIH,
#: s31d-1: its height estimate 0.1 m up, the vehicle met the ground before the land segment's
#: end and the estimate sank on with the reference (no lead); the disturbance estimate went from
#: -0.03..-0.08 g in the descent to -0.22 g at the contact and -0.3..-0.5 g after
CONTACT_HELD_SHARE = 0.15
#: mid-mission, the same with the thrust commanded within this of its floor (normalised)
CARRIED_THRUST_MARGIN = 0.05
CUT_S = 0.5  # thrust ramp down after touchdown
#: s after the thrust cut within which the vehicle must be disarmed, else the flight escalates:
#: PX4 SIH's land mode, handed a landing its detector doubted, saw it 3-5 s later three times
#: and once 18 s later (its estimate's vertical speed wavering about its 0.25 m/s threshold)
DISARM_BOUND_S = 40.0
#: s of a refused disarm before the autopilot's land mode is handed the landing: PX4 SIH's
#: estimate read the grounded vehicle climbing 0.35-0.4 m/s for 4 s after the contact (its
#: height 0.6-1.2 m up), and its land detector, with our zero thrust in OFFBOARD, refused the
#: disarm for all of the 15 s then allowed (3 of about 50 flights)
LAND_HANDOVER_S = 2.0
#: s between disarm requests to an autopilot refusing them
DISARM_RETRY_S = 1.0
#: the tilt limit (deg) of the final descent past the mission's end, as PX4 limits its own
#: landing (MPC_TILTMAX_LND's default)
TOUCHDOWN_TILT_DEG = 12.0
#: s of position history kept before the final land segment (the touchdown speed is judged on
#: the history of that segment, bounded at DESCENT_KEEP_S)
DESCENT_S = 2.0
DESCENT_KEEP_S = 60.0
#: the touchdown speed is judged over the CONTACT_S s before the estimate's descent ended: where
#: the height estimate first came within DESCENT_END_Z m of its lowest point
CONTACT_S = 1.0
DESCENT_END_Z = 0.02
#: a touchdown read further than this (m) from the takeoff spot's height is warned of: the
#: height estimate drifted, and the touchdown speed read from it is uncertain
TOUCHDOWN_HEIGHT_WARN = 0.3



def landing_tilt(cap, thrust, hover, thrust_min):
    """The tilt limit (rad) of a landing step: ``cap`` while the last step's ``thrust`` is half
    way from its floor ``thrust_min`` to ``hover`` or more, falling to 0 at the floor.  A
    thrust near its floor is the ground taking the weight: the attitude the acceleration map
    would set for the horizontal command (up to the full tilt limit, the thrust vector being
    nearly all horizontal) then buys no horizontal force, and on the ground it tips the
    vehicle over (PX4 SIH: the final descent commanded 33 deg of roll at 0.06 thrust and left
    the vehicle on its side, its summary saying "landed").  None (no step yet): ``cap``."""
    if thrust is None or not hover > thrust_min:
        return cap
    share = (thrust - thrust_min) / (hover - thrust_min)
    return cap * min(1.0, max(0.0, 2.0 * share))



def touchdown_speed(descent, window=0.1):
    """The fastest descent in ``descent`` ((t, z NED) samples), each sample against the newest
    one at least ``window`` s older, m/s (0 if there is none).

    The autopilot's position estimate, not the truth, and not its velocity estimate: flown
    against PX4 SIH's true state, the velocity estimate near the ground was biased (a climb
    read while the vehicle sat still) and its peaks ran up to 0.15 m/s over the true touchdown
    speed, while the position estimate's descent came within about 0.1 m/s of it."""
    best = 0.0
    j = -1  # the newest sample at least `window` older than sample i
    for i, (t, z) in enumerate(descent):
        while j + 1 < i and descent[j + 1][0] <= t - window + 1e-9:
            j += 1
        if j >= 0:
            t0, z0 = descent[j]
            best = max(best, (z - z0) / (t - t0))
    return best


def descent_end(descent):
    """The time (s) the estimate's descent ended in ``descent`` ((t, z NED) samples): the first
    sample within :data:`DESCENT_END_Z` of the lowest point.  None if there are no samples.

    On the ground the height estimate goes on moving: flown on PX4 SIH, it climbed at up to
    0.2 m/s for seconds after the contact, so touchdown was seen 1-4 s after it, and the 2 s
    before that held only the climb: the touchdown speed read 0.00 for true 0.23-0.35 m/s."""
    if not descent:
        return None
    deepest = max(z for _, z in descent)
    return next(t for t, z in descent if z >= deepest - DESCENT_END_Z)


def contact_speed(descent):
    """The touchdown speed (m/s) judged over the :data:`CONTACT_S` before the estimate's descent
    ended (:func:`descent_end`), and that end's time (None without samples)."""
    end = descent_end(descent)
    if end is None:
        return 0.0, None
    window = [(t, z) for t, z in descent if end - CONTACT_S - 1e-9 <= t <= end]
    return touchdown_speed(window), end


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


class GroundPhases:
    """Mode, arming, spool-up; touchdown, cut, disarm (methods of
    :class:`~mavadrc.flight.flight.Flight`)."""

    def _ph_mode(self, s):
        if self.takeover_in_air:
            self._control_step(s, None, hold=True)
        else:
            self._idle(s)
        c = self._cmd
        if c is not None and c.done:
            self._unheard = c.result == TIMEOUT
            if self._refused_answer(c, "the mode change", "its mode"):
                if c.result == M.MAV_RESULT_TEMPORARILY_REJECTED and self._cmd_tries < 5:
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
            self._unheard, self._asked_again = False, 0
            self._enter("arming", s)
        elif self._ask_again(hb, f"not in {self.seq.control_mode}"):
            self._cmd = self.seq.request_control(self.link)

    def _ph_arming(self, s):
        self._idle(s)
        c = self._cmd
        if c is not None and c.done:
            self._unheard = c.result == TIMEOUT
            if self._refused_answer(c, "the arm command", "whether it armed"):
                raise FlightError(f"the vehicle refused to arm: {result_name(c.result)}"
                                  f"{self._because()}")
        hb = self._fresh()
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and \
                self._ask_again(hb, "not armed"):
            self._cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if hb is not None and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self._confirm_since = None
            if self.takeover:  # armed on the ground already: the motors are up
                self.say("armed: flying from the ground, no spool-up")
                return self._start_mission(s)
            self.say(f"armed; motors start in {self.motor_delay:g} s "
                     f"({self.sources.get('motor_delay', 'default')}), then the spool-up")
            self._enter("spoolup", s)  # from the next sample: one setpoint per sample

    #: how often a command that went unanswered after every try is sent again in one phase
    ASK_AGAIN = 3

    def _ask_again(self, hb, state):
        """Whether to send the phase's command again: it went unanswered after every try, and
        the heartbeat asked for since shows the vehicle ``state`` (the command was lost on the
        way: on a link that loses a fifth of the datagrams each way, three tries are all lost
        once in 125 flights).  At most :attr:`ASK_AGAIN` times a phase."""
        if hb is None or not self._unheard or self._cmd is not None or \
                self._asked_again >= self.ASK_AGAIN:
            return False
        self._unheard = False
        self._asked_again += 1
        self.say(f"{state} by its heartbeat after an unanswered command: sending it again "
                 f"({self._asked_again} of {self.ASK_AGAIN})")
        return True

    def _refused_answer(self, c, what, question):
        """The answer to a command that changes the vehicle's state: accepted, it is to be seen
        in a heartbeat newer than the answer; unanswered, such a heartbeat settles it (both
        asked for now).  Returns whether the vehicle refused."""
        self._cmd = None
        if c.accepted or c.result == TIMEOUT:
            self._ask_heartbeat()
            self._confirm_since = c.acked_wall if c.accepted else self._hb_request_wall
            if c.result == TIMEOUT:
                self.say(f"no answer to {what} after {c.sent} tries: asking the vehicle "
                         f"{question}")
            return False
        return True

    def _because(self):
        """The vehicle's latest words of its own (its reason, as "Disarming denied: not
        landed"), not a command's answer, which the caller names already; "" if none among the
        last three."""
        for text in reversed(self.texts[-3:]):
            if not text.startswith("MAV_CMD_"):
                return f" ({text})"
        return ""

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

    def _anchor_here(self, s):
        """The takeoff starts where the position estimate has the vehicle when the mission
        starts: the mission's frame moved horizontally to it from where it was measured before
        the mode change, the arming and the spool-up (seconds, over which PX4 SIH's estimate of
        a vehicle at rest wandered 0.05-0.10 m: the loop lifted off already that far from its
        reference, tilted towards it on the ground).  The height keeps the spot measured: it
        is what the lift-off is judged against."""
        moved = s.pos[:2] - self.origin[:2]
        self.origin_moved_m = round(float(np.hypot(*moved)), 4)
        self.origin[:2] = s.pos[:2]
        self.traj, self.phases = self.m.build_trajectory(self.origin, in_air=False)

    def _start_mission(self, s):
        if not self.takeover_in_air:  # taking over, the controller already holds the vehicle
            self._anchor_here(s)
            self.ctrl.reset(s.pos)
        self._grid = None
        if self._identifying():
            self._id_windows = windows_in(self.phases, leg_speed=leg_speed_of(self.m))
            # to the segment's end less its hold: the leg's last ramp and rest too; the fit is
            # made while the vehicle holds still, so the mission's controller takes over at
            # rest, as after the doublets alone
            t_id = dict((name, t0) for t0, name in self.phases)["identify"]
            end = min((t0 for t0, _ in self.phases if t0 > t_id), default=self.traj.duration)
            end -= HANDOVER_S
            self._id_span = (self._id_windows[0][1], max(end, self._id_windows[-1][2]))
            self._handover_t = self._id_data_span()[0] - TAKEOFF_HANDOVER_S
        self._mission_t0 = s.t
        self.mission_start = s.t
        if self.truth is not None:
            self.truth.start()
        self._lifted = self.takeover_in_air
        self._yaw_offset = wrap_pi(self.yaw - float(self.traj.sample(0.0).yaw))
        self.gate.restart(self.h)
        self.say(f"flying {self.m.name!r} with {self.kind} at {self.rate:g} Hz "
                 f"({self.traj.duration:.1f} s){self._takeoff_text()}"
                 f"{prediction_text(self.ctrl)}; "
                 f"{margin_text(self.delay_margin)}")
        self._enter("mission", s)

    def _ph_touchdown(self, s):
        if self._left_control():
            return
        tau = s.t - self._phase_t0
        speed = min(FINAL_SPEED, self._land_speed())
        pos, vel, acc = touchdown_reference(self._descent_from, speed, tau)
        r = Reference(pos, vel, acc, self._final_yaw, 0.0)
        t = s.t - self._mission_t0
        lead = self._lead(s)
        rc = r if lead == 0.0 else Reference(
            *touchdown_reference(self._descent_from, speed, tau + lead), self._final_yaw, 0.0)
        q, thrust = self._control_step(s, rc, tilt_cap=math.radians(TOUCHDOWN_TILT_DEG))
        self.recorder.step(t, "touchdown", r, s, self.ctrl, q, thrust, scored=False)
        self._descent_history(s, final=True)
        how = self._ground_contact(s, pos[2], self._phase_wall)
        if how is not None:
            # on the ground before the land segment ended, where the height estimate had
            # drifted up (PX4 SIH: 0.09 m at the contact, then climbing 0.2 m/s): its last
            # scored second was the ground's push, 0.24 m of "error", not tracking
            self._unscore_from_contact(min_growth=GAP_GROWTH)
            return self._touched_down(s, thrust, how)
        bound = 5.0 + max(0.0, self.origin[2] - self._descent_from[2] + 1.0) / speed
        if tau > bound:
            self._escalate("touchdown_timeout",
                           f"touchdown not seen {bound:.0f} s into the final descent")

    def _ground_contact(self, s, ref_z, since_wall):
        """Whether the vehicle is on the ground while the reference (down ``ref_z``) goes on
        below it: None if not, else how it was seen: the autopilot says so (ON_GROUND, told after
        ``since_wall``), or the samples: for SETTLED_S the reference more than 5 cm under the
        vehicle, and the ground carrying it (the vertical disturbance estimate holding up
        :data:`CARRIED_SHARE` of g: the thrust is down and the vehicle does not fall) or it
        hardly moving vertically (by its velocity estimate or its position estimate's motion
        over :data:`STILL_WINDOW_S`) while the reference goes on :data:`GAP_GROWTH` further
        down, itself and against the vehicle.  The estimates fail each in turn: PX4 SIH's
        velocity read a 0.25-0.5 m/s descent while the vehicle sat on the ground, and its own
        land detector, fooled alike, said ON_GROUND only after the flight's 8 s bound."""
        below = ref_z > s.pos[2] + 0.05
        still = abs(s.vel[2]) < SETTLED_SPEED or self._height_still(s)
        carried = float(self.ctrl.z[2, 2]) < -CARRIED_SHARE * GRAVITY
        if below and (still or carried):
            if self._settled_since is None:
                self._settled_since = s.t
                self._settled_at = (ref_z, float(s.pos[2]))
        else:
            self._settled_since = None
        if self.landed_state == M.MAV_LANDED_STATE_ON_GROUND and \
                self.landed_state_wall is not None and self.landed_state_wall > since_wall:
            return "the autopilot says on the ground"
        if self._settled_since is not None and s.t - self._settled_since >= SETTLED_S:
            if carried:
                return "the ground carries its weight"
            # slow, and the reference going on below without it: not paused ahead (the gap
            # then grows only if the vehicle rises back from it)
            ref0, z0 = self._settled_at
            went_on = ref_z - ref0
            grew = (ref_z - float(s.pos[2])) - (ref0 - z0)
            if went_on >= GAP_GROWTH and grew >= GAP_GROWTH:
                return "settled"
        return None

    def _height_still(self, s):
        """Whether the height estimate moved under SETTLED_SPEED over the last STILL_WINDOW_S
        of the descent history (False before it holds that much)."""
        for t, z in reversed(self._descent):
            if t <= s.t - STILL_WINDOW_S:
                return abs(float(s.pos[2]) - z) < SETTLED_SPEED * (s.t - t)
        return False

    def _touched_down(self, s, thrust, how):
        """Touchdown seen on sample ``s`` (``how``: :meth:`_ground_contact`'s answer): judge its
        speed, cut the thrust."""
        self.touchdown_speed, end = contact_speed(self._descent)
        self.touchdown_seen = True
        self.touchdown_height = float(self.origin[2] - s.pos[2])
        self.ctrl.hold_disturbance()
        self._cut_from = thrust
        late = s.t - end if end is not None else 0.0
        where = (f"; the estimate's descent ended {late:.1f} s before, where it is judged"
                 if late >= 0.5 else "")
        self.say(f"touchdown at {self.touchdown_speed:.2f} m/s ({how}{where})")
        if abs(self.touchdown_height) > TOUCHDOWN_HEIGHT_WARN:
            self._warn_once("touchdown_height", (
                f"touchdown read {abs(self.touchdown_height):.2f} m "
                f"{'above' if self.touchdown_height > 0 else 'below'} the takeoff spot: the "
                "height estimate drifted, and the touchdown speed read from it is uncertain"),
                every=0.0)
        if self.touchdown_speed > self.m.safety.max_touchdown_speed:
            self._warn_once("hard_touchdown", (
                f"a hard touchdown: {self.touchdown_speed:.2f} m/s, above "
                f"safety.max_touchdown_speed {self.m.safety.max_touchdown_speed:g}"), every=0.0)
        self._enter("cut", s)

    def _descent_history(self, s, final):
        """Keep the position history the touchdown speed is judged on: the last
        :data:`DESCENT_S` before the final land segment, all of it (to :data:`DESCENT_KEEP_S`)
        from there on (``final``)."""
        self._descent.append((s.t, float(s.pos[2])))
        keep = DESCENT_KEEP_S if final else DESCENT_S
        while self._descent[0][0] < s.t - keep:
            self._descent.popleft()

    def _land_speed(self):
        kind, spec, _ = self.m.segments[-1]
        return float(spec.get("speed", 0.5)) if kind == "land" else 0.5

    def _ph_cut(self, s):
        k = max(0.0, 1.0 - (s.t - self._phase_t0) / CUT_S)
        self._send(s.t, level_quat(self.yaw), self._cut_from * k)
        if k <= 0.0:
            self._enter("disarming", s)

    def _ph_disarming(self, s):
        self._send(s.t, level_quat(self.yaw), 0.0)

    def _disarm_tick(self, now):
        """After touchdown and the thrust cut, disarm as the autopilot's landing detector
        allows: PX4, once it says ON_GROUND (PX4 also disarms itself COM_DISARM_LAND s after
        landing); a refusal for :data:`LAND_HANDOVER_S` hands the landing to its land mode, which
        disarms the vehicle once its detector agrees (disarms are still asked meanwhile);
        ArduPilot, through its land mode from the start
        (:attr:`~mavadrc.mavlink.sequence.Sequence.land_to_disarm`).  Bounded at
        :data:`DISARM_BOUND_S`."""
        since = now - self._phase_wall
        if self._confirm_since is None:
            self._confirm_since = self._phase_wall  # ask for heartbeats until one shows it
        hb = self.link.heartbeat_since(self._phase_wall)
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            self._confirm_since = None
            self.disarm_after_s = since
            if self.disarm_how is None:
                c = self._cmd
                ours = c is not None and c.cmd == M.MAV_CMD_COMPONENT_ARM_DISARM and c.accepted
                self.disarm_how = "command" if ours else "autopilot"
            return self._end_disarmed(hb, "disarmed" + (
                f" (by {self.seq.title}'s land mode)" if self.disarm_how == "land mode" else ""))
        c = self._cmd
        if not self._land_mode_disarms() and self._disarm_refused_wall is not None and \
                now - self._disarm_refused_wall >= LAND_HANDOVER_S and (c is None or c.done):
            self.disarm_how = "land mode"
            self.disarm_refused_s = now - self._disarm_refused_wall
            self.say(f"{self.seq.title}'s landing detector still reads the vehicle in the air"
                     f"{self._estimate_now()}: its land mode takes the landing over, to disarm "
                     "it once the detector agrees")
            c = self._cmd = None
        if self._land_mode_disarms():
            if c is None or (c.done and c.cmd == M.MAV_CMD_NAV_LAND and not c.accepted
                             and now - c.acked_wall > 1.0):
                if c is None and self.disarm_how is None:  # ArduPilot: from the start
                    self.disarm_how = "land mode"
                    self.say(f"on the ground: {self.seq.title}'s land mode disarms it")
                self._cmd = self.link.command(M.MAV_CMD_NAV_LAND)
            elif not self.seq.land_to_disarm and c.done and (
                    c.cmd != M.MAV_CMD_NAV_LAND or c.accepted) and \
                    now - c.acked_wall > DISARM_RETRY_S:
                # PX4's land mode disarms by itself unless COM_DISARM_LAND is off: ask as well
                self._cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif c is None:
            ground = self.landed_state == M.MAV_LANDED_STATE_ON_GROUND
            if ground or since > 3.0 or "EXTENDED_SYS_STATE" not in self.link.messages:
                self._cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif c.done:
            if not c.accepted and c.result != TIMEOUT and self._disarm_refused_wall is None:
                self._disarm_refused_wall = now
                self.say(f"disarm refused ({result_name(c.result)}){self._because()}: waiting "
                         "for the autopilot's landing detector")
            if now - c.acked_wall > DISARM_RETRY_S:
                self._cmd = None  # ask again
        if since > DISARM_BOUND_S:
            self._escalate("disarm_timeout", f"the vehicle did not disarm within "
                                             f"{DISARM_BOUND_S:g} s of touchdown")

    def _unscore_from_contact(self, min_growth=0.0):
        """The steps since the ground met the vehicle leave the error figures
        (:meth:`~mavadrc.flight.record.Recorder.unscore_from_contact`: where the reference went on
        below it, or where the ground began to hold it up, :data:`CONTACT_HELD_SHARE`)."""
        self.recorder.unscore_from_contact(min_growth=min_growth,
                                           held=CONTACT_HELD_SHARE * GRAVITY)

    def _land_mode_disarms(self):
        """Whether the autopilot's land mode is to disarm the vehicle: ArduPilot's always
        (:attr:`~mavadrc.mavlink.sequence.Sequence.land_to_disarm`), PX4's once handed the landing."""
        return self.seq.land_to_disarm or self.disarm_how == "land mode"

    def _estimate_now(self):
        """' (its estimate: 0.62 m above the takeoff spot, climbing 0.35 m/s)', from the last
        sample, or '' without one."""
        s = self.last
        if s is None:
            return ""
        vz = float(s.vel[2])
        motion = (f"climbing {-vz:.2f} m/s" if vz < -0.05 else
                  f"sinking {vz:.2f} m/s" if vz > 0.05 else "still")
        return (f" (its estimate: {float(self.origin[2] - s.pos[2]):.2f} m above the takeoff "
                f"spot, {motion})")
