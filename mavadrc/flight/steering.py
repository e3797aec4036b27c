"""One control step: the reference where the command will act (the sample's age led, the
acceleration fed forward a lag ahead), the controller's update, the thrust sized for the tilt
where asked, and the setpoint sent."""

import numpy as np

from mavadrc.control.geometry import thrust_for_tilt
from mavadrc.mission.trajectories import Reference

#: the reference is sampled on the control grid in chunks of this many periods
GRID_CHUNK = 2048
#: ``thrust_tilt: measured`` sizes the thrust for the vehicle's reported tilt while its newest
#: ATTITUDE is at most this much older (s) than the position sample (PX4 and ArduCopter stream
#: it at 50-100 Hz); an older one, or none, leaves the thrust as computed
ATTITUDE_FRESH_S = 0.1


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


class Steering:
    """The control step of every phase that flies: handed the controller choice (``ctrl``, the
    period), the mission's progress (its trajectory), the vehicle's telemetry and the
    setpoints out."""

    def __init__(self, mission, choice, progress, vehicle, setpoints, clock, lockstep=False):
        self.m = mission
        self.choice = choice
        self.progress = progress
        self.v = vehicle
        self.setpoints = setpoints
        self.clock = clock
        self.tilt_measured = mission.controller.thrust_tilt == "measured"
        self.lockstep = lockstep  # the vehicle's clock is the setpoint stream
        self.hold_point = None  # where a hold keeps the vehicle (None: where the next step is)
        self.last_thrust = None  # the last control step's thrust (landing_tilt)
        self._grid = None
        self._grid_k0 = 0

    def reset_grid(self):
        self._grid = None

    def reference(self, t):
        """The reference at mission time ``t``: on the control grid (computed a chunk at a time:
        a vehicle whose clock ticks on the period reads it from there), or sampled exactly off
        it (as :func:`mavadrc.fast.inprocess._references` does)."""
        h = self.choice.h
        traj = self.progress.traj
        k = int(round(t / h))
        grid_n = int(traj.duration / h) + 2
        if abs(t - k * h) < 1e-7 and 0 <= k < grid_n:
            if self._grid is None or not self._grid_k0 <= k < self._grid_k0 + GRID_CHUNK:
                # from a little before: the reference a lead ahead (feedforward) and the one
                # for now then share a chunk
                self._grid_k0 = k0 = max(k - GRID_CHUNK // 8, 0)
                self._grid = traj.sample_many(np.arange(k0, min(k0 + GRID_CHUNK, grid_n)) * h)
            pos, vel, acc, yaw, yaw_rate = self._grid
            i = k - self._grid_k0
            return Reference(pos[i], vel[i], acc[i], float(yaw[i]), float(yaw_rate[i]))
        return traj.sample(t)

    def lead(self, s):
        """How far past sample ``s``'s time the controller carries its estimate, to where its
        command acts (the sample's age, as its ``latency`` says; 0: not compensated): the
        reference it flies to is taken there."""
        age = self.choice.ctrl.sample_age(s.age)
        return age if age == age else 0.0

    def feedforward(self, rc, t):
        """``rc``, the reference for mission time ``t``, with the acceleration fed forward taken
        where the command will act: per axis ``feedforward_lead`` later (the input lag), plus
        the change of the drag along the reference by then (:attr:`PositionController.drag`)."""
        ctrl = self.choice.ctrl
        lead = ctrl.feedforward_lead
        if not np.any(lead > 0.0):
            return rc
        drag = ctrl.drag
        acc = np.array(rc.acc, dtype=float)
        ahead = {}  # one sample per distinct lead (north and east share theirs)
        for i in range(3):
            if lead[i] > 0.0:
                a = ahead.get(lead[i])
                if a is None:
                    a = ahead[lead[i]] = self.reference(t + float(lead[i]))
                acc[i] = a.acc[i] + drag[i] * (a.vel[i] - rc.vel[i])
        return Reference(rc.pos, rc.vel, acc, rc.yaw, rc.yaw_rate)

    def step(self, s, r, hold=False, tilt_cap=None, aref=None):
        """One control step on sample ``s`` towards reference ``r`` (for the time the
        controller's estimate is carried to, :meth:`lead`; ``hold``: stay where the
        reference was when the hold began); sends the setpoint, returns (q, thrust).
        ``tilt_cap`` (rad; landing): the tilt limit for this step, lowered further as the
        thrust falls towards its floor (:func:`landing_tilt`).  ``aref``: the reference's own
        acceleration then, where ``r.acc`` is the one fed forward (None: ``r.acc``)."""
        ctrl = self.choice.ctrl
        if self.setpoints.native:
            return self._native_step(s, r, hold, aref)
        told = None
        if tilt_cap is not None:
            told = ctrl.tilt_limit
            ctrl.tilt_limit = landing_tilt(tilt_cap, self.last_thrust,
                                           ctrl.hover_thrust_estimate,
                                           self.m.controller.thrust_min)
        try:
            q, thrust = self._update(s, r, hold, aref)
        finally:
            if told is not None:
                ctrl.tilt_limit = told
        self.last_thrust = thrust
        thrust = self._thrust_for_tilt(s, q, thrust)
        self.setpoints.send(s.t, q, thrust * self.v.seq.thrust_factor(self.v.cos_tilt))
        return q, thrust

    def _native_step(self, s, r, hold, aref):
        """``native``: the reference (or the hold point) sent as the autopilot's position
        target.  ArduCopter's GUIDED is not sent one before the vehicle has left the ground on
        its MAV_CMD_NAV_TAKEOFF (:attr:`~mavadrc.mavlink.sequence.Sequence.takeoff_command`: a
        target would replace the takeoff and GUIDED flies none on the ground); a lockstep
        vehicle (the bundled one, which takes them from the ground) gets them all the same, its
        clock being the stream."""
        q, thrust = self._update(s, r, hold, aref)
        if self.v.seq.takeoff_command and not self.progress.lifted and not self.lockstep \
                and not hold:
            return q, thrust
        pos, vel, acc, yaw = self.choice.ctrl.target
        self.setpoints.position(s.t, pos, vel, acc, yaw)
        return q, thrust

    def _thrust_for_tilt(self, s, q, thrust):
        """``thrust`` sized for the tilt the vehicle reports (``thrust_tilt: measured``,
        :func:`~mavadrc.control.geometry.thrust_for_tilt`) when its newest ATTITUDE is at most
        :data:`ATTITUDE_FRESH_S` older than sample ``s``; else as computed."""
        att = self.v.attitude_ms
        if not self.tilt_measured or att is None or s.t - att / 1000.0 > ATTITUDE_FRESH_S:
            return thrust
        return thrust_for_tilt(thrust, float(q[0]), float(q[1]), float(q[2]), float(q[3]),
                               self.v.cos_tilt, self.m.controller.thrust_max)

    def _update(self, s, r, hold, aref=None):
        ctrl = self.choice.ctrl
        if hold:
            if self.hold_point is None:
                self.hold_point = s.pos.copy()
                if self.clock.phase in ("measure", "mode"):
                    ctrl.reset(s.pos, s.vel)
            z3 = np.zeros(3)
            return ctrl.update(s.pos, s.vel, self.hold_point, z3, z3, self.v.yaw, dt=s.dt,
                               age=s.age)
        return ctrl.update(s.pos, s.vel, r.pos, r.vel, r.acc, r.yaw, dt=s.dt, age=s.age,
                           ref_acc_now=aref)
