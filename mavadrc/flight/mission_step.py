"""The mission phase: each sample one control step towards the trajectory, the identification
and the drag learnt along the way, the step recorded, and the checks that end a mission early
(the supervisor's limits, the ground under a vehicle in flight, tracking lost)."""

import math
import time

import numpy as np

from mavadrc.control.geometry import GRAVITY
from mavadrc.flight.landing import CARRIED_SHARE, CARRIED_THRUST_MARGIN, SETTLED_S
from mavadrc.flight.state import Held
from mavadrc.flight.supervisor import LAND
from mavadrc.mavlink.dialect import M
from mavadrc.mission.takeoff import YAW_RATE
from mavadrc.mission.trajectories import Reference

#: s the vehicle must stay past the safety's max_tracking_error before the mission stops
TRACKING_LOST_S = 1.0


class MissionStep:
    """The mission's control step and its checks."""

    def __init__(self, mission, link, clock, vehicle, progress, notices, steering, choice, ident,
                 takeoff, landing, failsafe, recorder, supervisor, gate, lockstep):
        self.m = mission
        self.link = link
        self.clock = clock
        self.v = vehicle
        self.progress = progress
        self.notices = notices
        self.steering = steering
        self.choice = choice
        self.ident = ident
        self.takeoff = takeoff
        self.landing = landing
        self.failsafe = failsafe
        self.recorder = recorder
        self.supervisor = supervisor
        self.gate = gate
        self.lockstep = lockstep
        self._carried = Held()  # the ground carrying the vehicle mid-mission
        self._far = Held()  # the vehicle past max_tracking_error off the reference
        self._last_named = -1.0

    def step(self, s):
        p, c, steer, escalate = self.progress, self.choice, self.steering, self.failsafe.escalate
        if self.failsafe.left_control():
            return
        t = s.t - p.t0
        r = steer.reference(t)  # the sample's: what its error is scored against
        p.waiting = not p.lifted and self.takeoff.waits(s, r)
        if p.waiting:  # the mission clock stops: this sample flies to the last reference
            step = s.dt if s.dt is not None else c.h
            p.t0 += step
            p.start = p.t0
            self.takeoff.wait += step
            t = s.t - p.t0
            r = steer.reference(t)
        lead = steer.lead(s)
        rc = r if lead == 0.0 else steer.reference(t + lead)
        aref = rc.acc  # the reference's own, for a law that predicts
        rc = steer.feedforward(rc, t + lead)
        if self.takeoff.yaw_offset != 0.0:
            step = YAW_RATE * (s.dt if s.dt is not None else c.h)
            self.takeoff.yaw_offset -= max(-step, min(step, self.takeoff.yaw_offset))
            off = self.takeoff.yaw_offset
            r = Reference(r.pos, r.vel, r.acc, r.yaw + off, r.yaw_rate)
            rc = Reference(rc.pos, rc.vel, rc.acc, rc.yaw + off, rc.yaw_rate)
        if p.waiting:
            rc = self.takeoff.waiting_reference(s, rc)
            aref = (aref[0], aref[1], 0.0)
        final = p.in_final_land(t)
        cap = math.radians(self.m.controller.tilt_max_deg) if final else None
        self.ident.pause_learning(t, final)
        self.ident.takeoff_handover(s, t, rc.vel)
        q, thrust = steer.step(s, rc, tilt_cap=cap, aref=aref)
        if c.learner is not None and p.lifted:
            c.learner.step(c.ctrl, t, s.dt, rc.vel, rc.acc)
            self.ident.refine_step(s, t)
        self.ident.step(s, t, rc.vel)
        self.landing.history(s, final)
        if not p.lifted:
            self.takeoff.check_liftoff(s, t)
            why = self.takeoff.native_grounded(t)
            if why is not None:
                return escalate("ground", why)
        if p.waiting:
            why = self.takeoff.raise_thrust(s)
            if why is not None:
                return escalate("ground", why)
            self.check_link()
            return  # the reference waited: nothing of the mission to score, log or count
        p.steps += 1
        # the identification is not the mission: its doublets, flown on the safe gains, are
        # logged but not scored
        self.recorder.step(t, p.segment_name(t), r, s, c.ctrl, q, thrust,
                           scored=not self.ident.in_doublets(s.t * 1000.0, after=0.0))
        self._named_values(s)
        self.check_link()
        why = self.supervisor.breach(s, p.origin)
        if why is not None:
            return escalate("breach", why)
        why = self._grounded_in_flight(s, t) or self._carried_in_flight(s, t, thrust)
        if why is not None:
            return escalate("ground", why)
        why = self._tracking_lost(s, r, t)
        if why is not None:
            return escalate("tracking", why)
        if p.in_final_land(t):
            if p.land_wall is None:
                p.land_wall = time.monotonic()
            how = self.landing.ground_contact(s, r.pos[2], p.land_wall)
            if how is not None:
                # on the ground before the reference: the height estimate has drifted; what
                # follows is the ground's push, not tracking, and is not scored
                self.landing.unscore_from_contact()
                self.notices.say(f"on the ground {p.origin[2] - s.pos[2]:.2f} m above the "
                                 "takeoff spot by the height estimate, before the land "
                                 "segment's end")
                return self.landing.touched_down(s, thrust, how)
        if t >= p.traj.duration:
            if not self.m.ends_landed:
                # the mission ends in the air (an experiment run): the autopilot lands it
                self.notices.say("mission complete in the air: handing over to the autopilot's "
                                 "land mode")
                p.handed_over = True
                return self.failsafe.start(LAND)
            p.descent_from = r.pos.copy()
            p.final_yaw = r.yaw
            self.clock.enter("touchdown", s)
            self.notices.say("land segment done: descending until touchdown is seen")
            return
        self.notices.console.progress(p.segment_name(t), t, p.traj.duration,
                                      float(np.linalg.norm(s.pos - r.pos)), self.link_line)

    def _grounded_in_flight(self, s, t):
        """Why the flight must end, when the autopilot's land detector says ON_GROUND after it
        had said IN_AIR, before the final land segment (None otherwise).  The height estimate
        is then off, or the vehicle hit something: on PX4 SIH the estimate once drifted 0.7 m
        up over 20 s of the thesis spiral at 1.3 m, the vehicle sat on the ground 8 s while its
        estimate read 1.3-1.6 m, and the position loop lifted it off again, blind."""
        if not (self.v.air_said and self.v.landed_state == M.MAV_LANDED_STATE_ON_GROUND) \
                or self.progress.in_final_land(t):
            return None
        return (f"the autopilot says the vehicle is on the ground, "
                f"{self.progress.origin[2] - s.pos[2]:.2f} m above the takeoff spot by its "
                "height estimate, mid-mission: the estimate is off or the vehicle hit something")

    def _carried_in_flight(self, s, t, thrust):
        """Why the flight must end when the ground carries the vehicle mid-mission, whatever
        the autopilot's land detector says (None otherwise): for
        :data:`~mavadrc.flight.landing.SETTLED_S` after lift-off, before the final land segment,
        the thrust at its floor and the vertical disturbance estimate holding up
        :data:`~mavadrc.flight.landing.CARRIED_SHARE` of g (the vehicle does not fall with the
        thrust cut: something holds it up).  On PX4 SIH, in the thesis spiral's run-up at 1 m,
        the height estimate read level while the vehicle sank 0.23 m/s into the ground; at 2
        m/s it stopped dead, the estimate then read a climb, PX4's land detector said nothing,
        and 5 s later the loop lifted it off again to chase a reference 19 m away."""
        z3 = float(self.choice.ctrl.z[2, 2])
        low = thrust <= self.m.controller.thrust_min + CARRIED_THRUST_MARGIN
        if not self._carried.held(self.progress.airborne(t) and low
                                  and z3 < -CARRIED_SHARE * GRAVITY, s.t, SETTLED_S):
            return None
        return (f"the ground carries the vehicle mid-mission "
                f"({self.progress.origin[2] - s.pos[2]:.2f} m above the takeoff spot by its "
                f"height estimate; the thrust at its floor, {-z3:.1f} m/s^2 holding it up): the "
                "estimate is off or the vehicle hit something")

    def _tracking_lost(self, s, r, t):
        """Why the flight must stop chasing its reference (None otherwise): after lift-off,
        before the final land segment, the vehicle held more than the safety's
        ``max_tracking_error`` from the reference ``r`` for :data:`TRACKING_LOST_S`."""
        limit = self.m.safety.max_tracking_error
        err = math.dist(s.pos, r.pos)
        if not self._far.held(bool(limit) and self.progress.airborne(t) and err > limit, s.t,
                              TRACKING_LOST_S):
            return None
        return (f"tracking lost: {err:.1f} m from the reference for {TRACKING_LOST_S:g} s "
                f"(safety.max_tracking_error {limit:g} m): the vehicle is not following it "
                "(caught or pinned, its height estimate off, a wind past its authority)")

    def _named_values(self, s):
        """The observers' disturbance estimates at 10 Hz, live, for a ground station."""
        if self.choice.kind not in ("pd", "native") and s.t - self._last_named >= 0.1:
            self._last_named = s.t
            z3 = self.choice.ctrl.disturbance
            for i, a in enumerate("xyz"):
                self.link.named_float(s.t * 1000.0, f"z3_{a}", float(z3[i]))

    def link_line(self):
        loss = self.gate.recent_loss()
        ooo = self.gate.recent_out_of_order()
        rtt = self.link.timesync.rtts[-1] if self.link.timesync.rtts else None
        return (f"{self.gate.achieved_rate():.0f} Hz, lost {100 * (loss - ooo):.1f} %"
                + (f", out of order {100 * ooo:.1f} %" if ooo >= 0.0005 else "")
                + (f", rtt {1e3 * rtt:.1f} ms" if rtt is not None and not self.lockstep else ""))

    def check_link(self):
        why = self.supervisor.link(self.gate)
        if why is not None:
            return self.failsafe.escalate("link", why)
        warn = self.supervisor.link_warning(self.gate)
        if warn is not None:
            self.notices.warn_once("link", warn, latest=True)
        if self.link.other_sources and "sources" not in self.notices.warned:
            # heard in flight: only the vehicle flown is answered and read (said once; the
            # summary's link counts the other's messages)
            self.notices.warn_once("sources", f"{self.link.sources_text()}; the flight goes on "
                                   "with the one it flies", every=math.inf)
