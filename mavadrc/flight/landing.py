"""The flight's end on the ground: the final descent past the mission's end until touchdown is
seen (the autopilot's ON_GROUND, or vertical speed and height settled), the touchdown speed judged
on the height estimate's history, the thrust cut, and the disarm, which follows the autopilot's
landing detector."""

import collections
import math

import numpy as np

from mavadrc.control.geometry import GRAVITY
from mavadrc.control.rotations import level_quat
from mavadrc.mavlink.commands import TIMEOUT, result_name
from mavadrc.mavlink.dialect import M
from mavadrc.mission.config import FINAL_SPEED
from mavadrc.mission.trajectories import Reference

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


class Landing:
    """Touchdown, cut and disarm: the final descent flown past the mission's end, the contact
    judged, the disarm asked as the autopilot's landing detector allows."""

    def __init__(self, mission, link, clock, vehicle, progress, notices, setpoints, steering,
                 recorder, choice, confirm, failsafe):
        self.m = mission
        self.link = link
        self.clock = clock
        self.v = vehicle
        self.progress = progress
        self.notices = notices
        self.setpoints = setpoints
        self.steering = steering
        self.recorder = recorder
        self.choice = choice
        self.confirm = confirm
        self.failsafe = failsafe
        self.descent = collections.deque()  # (t, z): the land's history (DESCENT_S)
        self.speed = None  # the touchdown speed judged (m/s)
        self.height = None  # the estimate's height above the takeoff spot there (m)
        #: how the vehicle came to be disarmed after touchdown: "command" (ours), "land mode"
        #: (the autopilot's, handed the landing), None (not by either)
        self.disarm_how = None
        self.disarm_refused_s = None  # s the disarm was refused before the land mode took over
        self.disarm_after_s = None  # s from the thrust cut to the disarm seen
        self._settled_since = None
        self._settled_at = None  # (reference, vehicle) down when the vehicle came to rest
        self._cut_from = None
        self._disarm_refused_wall = None  # wall time of the first refused disarm

    def touchdown_phase(self, s):
        if self.failsafe.left_control():
            return
        p = self.progress
        tau = s.t - self.clock.t0
        speed = min(FINAL_SPEED, self._land_speed())
        pos, vel, acc = touchdown_reference(p.descent_from, speed, tau)
        r = Reference(pos, vel, acc, p.final_yaw, 0.0)
        t = s.t - p.t0
        lead = self.steering.lead(s)
        rc = r if lead == 0.0 else Reference(
            *touchdown_reference(p.descent_from, speed, tau + lead), p.final_yaw, 0.0)
        q, thrust = self.steering.step(s, rc, tilt_cap=math.radians(TOUCHDOWN_TILT_DEG))
        self.recorder.step(t, "touchdown", r, s, self.choice.ctrl, q, thrust, scored=False)
        self.history(s, final=True)
        how = self.ground_contact(s, pos[2], self.clock.wall)
        if how is not None:
            # on the ground before the land segment ended, where the height estimate had
            # drifted up (PX4 SIH: 0.09 m at the contact, then climbing 0.2 m/s): its last
            # scored second was the ground's push, 0.24 m of "error", not tracking
            self.unscore_from_contact(min_growth=GAP_GROWTH)
            return self.touched_down(s, thrust, how)
        bound = 5.0 + max(0.0, p.origin[2] - p.descent_from[2] + 1.0) / speed
        if tau > bound:
            self.failsafe.escalate("touchdown_timeout",
                                   f"touchdown not seen {bound:.0f} s into the final descent")

    def ground_contact(self, s, ref_z, since_wall):
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
        carried = float(self.choice.ctrl.z[2, 2]) < -CARRIED_SHARE * GRAVITY
        if below and (still or carried):
            if self._settled_since is None:
                self._settled_since = s.t
                self._settled_at = (ref_z, float(s.pos[2]))
        else:
            self._settled_since = None
        if self.v.landed_state == M.MAV_LANDED_STATE_ON_GROUND and \
                self.v.landed_state_wall is not None and self.v.landed_state_wall > since_wall:
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
        for t, z in reversed(self.descent):
            if t <= s.t - STILL_WINDOW_S:
                return abs(float(s.pos[2]) - z) < SETTLED_SPEED * (s.t - t)
        return False

    def touched_down(self, s, thrust, how):
        """Touchdown seen on sample ``s`` (``how``: :meth:`ground_contact`'s answer): judge its
        speed, cut the thrust."""
        self.speed, end = contact_speed(self.descent)
        self.progress.touchdown_seen = True
        self.height = float(self.progress.origin[2] - s.pos[2])
        self.choice.ctrl.hold_disturbance()
        self._cut_from = thrust
        late = s.t - end if end is not None else 0.0
        where = (f"; the estimate's descent ended {late:.1f} s before, where it is judged"
                 if late >= 0.5 else "")
        self.notices.say(f"touchdown at {self.speed:.2f} m/s ({how}{where})")
        if abs(self.height) > TOUCHDOWN_HEIGHT_WARN:
            self.notices.warn_once("touchdown_height", (
                f"touchdown read {abs(self.height):.2f} m "
                f"{'above' if self.height > 0 else 'below'} the takeoff spot: the "
                "height estimate drifted, and the touchdown speed read from it is uncertain"),
                every=0.0)
        limit = self.m.safety.max_touchdown_speed
        if self.speed > limit:
            self.notices.warn_once("hard_touchdown", (
                f"a hard touchdown: {self.speed:.2f} m/s, above "
                f"safety.max_touchdown_speed {limit:g}"), every=0.0)
        self.clock.enter("cut", s)

    def history(self, s, final):
        """Keep the position history the touchdown speed is judged on: the last
        :data:`DESCENT_S` before the final land segment, all of it (to :data:`DESCENT_KEEP_S`)
        from there on (``final``)."""
        self.descent.append((s.t, float(s.pos[2])))
        keep = DESCENT_KEEP_S if final else DESCENT_S
        while self.descent[0][0] < s.t - keep:
            self.descent.popleft()

    def _land_speed(self):
        kind, spec, _ = self.m.segments[-1]
        return float(spec.get("speed", 0.5)) if kind == "land" else 0.5

    def cut_phase(self, s):
        k = max(0.0, 1.0 - (s.t - self.clock.t0) / CUT_S)
        # (native: no thrust of ours to cut; the target held under the vehicle)
        self.setpoints.send(s.t, level_quat(self.v.yaw),
                            0.0 if self.setpoints.native else self._cut_from * k)
        if k <= 0.0:
            self.clock.enter("disarming", s)

    def disarming_phase(self, s):
        self.setpoints.send(s.t, level_quat(self.v.yaw), 0.0)

    def disarm_tick(self, now):
        """After touchdown and the thrust cut, disarm as the autopilot's landing detector
        allows: PX4, once it says ON_GROUND (PX4 also disarms itself COM_DISARM_LAND s after
        landing); a refusal for :data:`LAND_HANDOVER_S` hands the landing to its land mode, which
        disarms the vehicle once its detector agrees (disarms are still asked meanwhile);
        ArduPilot, through its land mode from the start
        (:attr:`~mavadrc.mavlink.sequence.Sequence.land_to_disarm`).  Bounded at
        :data:`DISARM_BOUND_S`."""
        confirm, seq, say = self.confirm, self.v.seq, self.notices.say
        since = now - self.clock.wall
        if confirm.since is None:
            confirm.since = self.clock.wall  # ask for heartbeats until one shows it
        hb = self.link.heartbeat_since(self.clock.wall)
        if hb is not None and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            confirm.since = None
            self.disarm_after_s = since
            if self.disarm_how is None:
                c = confirm.cmd
                ours = c is not None and c.cmd == M.MAV_CMD_COMPONENT_ARM_DISARM and c.accepted
                self.disarm_how = "command" if ours else "autopilot"
            return self.failsafe.end_disarmed(hb, "disarmed" + (
                f" (by {seq.title}'s land mode)" if self.disarm_how == "land mode" else ""))
        c = confirm.cmd
        if not self._land_mode_disarms() and self._disarm_refused_wall is not None and \
                now - self._disarm_refused_wall >= LAND_HANDOVER_S and (c is None or c.done):
            self.disarm_how = "land mode"
            self.disarm_refused_s = now - self._disarm_refused_wall
            say(f"{seq.title}'s landing detector still reads the vehicle in the air"
                f"{self._estimate_now()}: its land mode takes the landing over, to disarm "
                "it once the detector agrees")
            c = confirm.cmd = None
        if self._land_mode_disarms():
            if c is None or (c.done and c.cmd == M.MAV_CMD_NAV_LAND and not c.accepted
                             and now - c.acked_wall > 1.0):
                if c is None and self.disarm_how is None:  # ArduPilot: from the start
                    self.disarm_how = "land mode"
                    say(f"on the ground: {seq.title}'s land mode disarms it")
                confirm.cmd = self.link.command(M.MAV_CMD_NAV_LAND)
            elif not seq.land_to_disarm and c.done and (
                    c.cmd != M.MAV_CMD_NAV_LAND or c.accepted) and \
                    now - c.acked_wall > DISARM_RETRY_S:
                # PX4's land mode disarms by itself unless COM_DISARM_LAND is off: ask as well
                confirm.cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif c is None:
            ground = self.v.landed_state == M.MAV_LANDED_STATE_ON_GROUND
            if ground or since > 3.0 or "EXTENDED_SYS_STATE" not in self.link.messages:
                confirm.cmd = self.link.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        elif c.done:
            if not c.accepted and c.result != TIMEOUT and self._disarm_refused_wall is None:
                self._disarm_refused_wall = now
                say(f"disarm refused ({result_name(c.result)}){self.notices.because()}: waiting "
                    "for the autopilot's landing detector")
            if now - c.acked_wall > DISARM_RETRY_S:
                confirm.cmd = None  # ask again
        if since > DISARM_BOUND_S:
            self.failsafe.escalate("disarm_timeout", f"the vehicle did not disarm within "
                                                     f"{DISARM_BOUND_S:g} s of touchdown")

    def unscore_from_contact(self, min_growth=0.0):
        """The steps since the ground met the vehicle leave the error figures
        (:meth:`~mavadrc.flight.record.Recorder.unscore_from_contact`: where the reference went on
        below it, or where the ground began to hold it up, :data:`CONTACT_HELD_SHARE`)."""
        self.recorder.unscore_from_contact(min_growth=min_growth,
                                           held=CONTACT_HELD_SHARE * GRAVITY)

    def _land_mode_disarms(self):
        """Whether the autopilot's land mode is to disarm the vehicle: ArduPilot's always
        (:attr:`~mavadrc.mavlink.sequence.Sequence.land_to_disarm`), PX4's once handed the landing."""
        return self.v.seq.land_to_disarm or self.disarm_how == "land mode"

    def _estimate_now(self):
        """' (its estimate: 0.62 m above the takeoff spot, climbing 0.35 m/s)', from the last
        sample, or '' without one."""
        s = self.v.last
        if s is None:
            return ""
        vz = float(s.vel[2])
        motion = (f"climbing {-vz:.2f} m/s" if vz < -0.05 else
                  f"sinking {vz:.2f} m/s" if vz > 0.05 else "still")
        return (f" (its estimate: {float(self.progress.origin[2] - s.pos[2]):.2f} m above the "
                f"takeoff spot, {motion})")
