"""What the vehicle sends, read: a position sample (one control step, timed and aged), its
attitude, its land detector, and the measures set beside the estimate (a simulator's true
state and disturbance, a range finder)."""

import math
import time

import numpy as np

from mavadrc.flight.rangefinder import range_height
from mavadrc.mavlink.dialect import M

TRUE_DIST = "TRUE_DIST"
#: in the final descent or after touchdown, a tilt past 45 deg (its cosine) is a vehicle on its
#: side, not landed
TIPPED_COS = math.cos(math.radians(45.0))


class Receive:
    """The vehicle's messages into the flight's state; each accepted position sample handed to
    ``on_sample`` (the flight's phase)."""

    def __init__(self, mission, link, clock, vehicle, progress, notices, choice, ident, tracks,
                 recorder, gate, supervisor, failsafe, on_sample, lockstep):
        self.m = mission
        self.link = link
        self.clock = clock
        self.v = vehicle
        self.progress = progress
        self.notices = notices
        self.choice = choice
        self.ident = ident
        self.tracks = tracks
        self.recorder = recorder
        self.gate = gate
        self.supervisor = supervisor
        self.failsafe = failsafe
        self.on_sample = on_sample
        self.lockstep = lockstep
        self.latency = []  # s from a sample's arrival to its setpoint, in the mission
        self.ages = []  # the samples' ages, in the mission
        self.attitudes = []  # (t, roll, pitch) while the controller flies
        self.tipped = False  # the attitude past TIPPED_COS after touchdown

    def message(self, msg):
        t = msg.get_type()
        v, phase = self.v, self.clock.phase
        if t == "LOCAL_POSITION_NED":
            self.recorder.sample_came()  # whatever of the last sample's attitude and truth came
            s = self.gate.accept(msg.time_boot_ms, (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz))
            if s is None:
                return  # late, repeated or non-finite: dropped and counted
            now = time.monotonic()
            if not self.lockstep:
                s.age = self.link.timesync.age(msg.time_boot_ms)
            elif v.attitude_ms is not None:
                # in lockstep the vehicle's clock stands still, at the period whose messages
                # come, until we answer: its ATTITUDE (every period, right after the position
                # sample, no link model on it) says the last period's time
                h = self.choice.h
                now_s = v.attitude_ms / 1000.0 + h
                s.age = max(0, round((now_s - s.t) / h)) * h
            v.last = s
            v.samples_seen += 1
            v.last_sample_wall = now
            t_in = time.perf_counter()
            self.on_sample(s)
            if self.lockstep:
                v.handled_wall = time.monotonic()
            if self.clock.phase in ("mission", "touchdown"):  # telemetry in -> setpoint out
                self.latency.append(time.perf_counter() - t_in)
                if s.age is not None:
                    self.ages.append(s.age)
        elif t == "ATTITUDE":
            v.yaw = msg.yaw
            v.attitude_ms = msg.time_boot_ms
            if phase in ("mission", "touchdown") and not self.ident.in_doublets(msg.time_boot_ms):
                self.attitudes.append((msg.time_boot_ms / 1000.0, msg.roll, msg.pitch))
            v.cos_tilt = math.cos(msg.roll) * math.cos(msg.pitch)
            near_ground = self.progress.touchdown_seen or phase == "touchdown"
            if near_ground and v.cos_tilt < TIPPED_COS and not self.tipped:
                self.tipped = True
                why = (f"the vehicle tipped over at touchdown: the autopilot reads "
                       f"{math.degrees(msg.roll):.0f} deg of roll, "
                       f"{math.degrees(msg.pitch):.0f} of pitch")
                self.notices.say(f"warning: {why}")
                self.supervisor.report("tipped", why)
            self.recorder.attitude(msg.time_boot_ms, msg.yaw)
        elif t == "EXTENDED_SYS_STATE":
            v.landed_state = msg.landed_state
            v.landed_state_wall = time.monotonic()
            if phase == "mission" and msg.landed_state == M.MAV_LANDED_STATE_IN_AIR:
                v.air_said = True
        elif t == "DEBUG_VECT" and msg.name == TRUE_DIST:
            self.recorder.truth(int(round(msg.time_usec / 1000.0)),
                                np.array([msg.x, msg.y, msg.z]))
        elif self.tracks.truth is not None and t == self.tracks.truth.source:
            self._on_truth(msg)
        elif t == "DISTANCE_SENSOR":
            self._on_range(msg)

    def _on_truth(self, msg):
        """A simulator's true state: beside the estimate of the same time.  It carries no usable
        time: it is timed by its arrival after the last position sample on the same link (in
        lockstep, sent in that sample's period), and the estimate carried there on its own
        velocity."""
        s, p, truth = self.v.last, self.progress, self.tracks.truth
        if s is None:
            return
        if p.start is None:
            truth.at_rest(msg, s.pos)
            return
        if p.waiting:
            return  # the mission's clock stands still: no time to put it at
        dt = 0.0 if self.lockstep else max(0.0, time.monotonic() - self.v.last_sample_wall)
        truth.add(s.t + dt - p.t0, msg, s.pos + s.vel * dt)

    def _on_range(self, msg):
        """A range finder's reading (:mod:`mavadrc.flight.rangefinder`): beside the height
        estimate of its own time (the newest sample carried there on its vertical speed, at most
        0.1 s), and, in the mission, the clearance check."""
        h = range_height(msg, self.v.cos_tilt)
        s, p, rf = self.v.last, self.progress, self.tracks.rangefinder
        if h is None or s is None:
            return
        rf.read(msg.time_boot_ms / 1000.0, h)
        if p.start is None:
            if not p.lifted:
                rf.at_rest(0.0, h)
            return
        if p.waiting:
            return  # the mission's clock stands still: no time to put it at
        if p.touchdown_seen or self.clock.phase == "done":
            # on the ground after the touchdown seen, or the flight over: nothing flown to set
            # it beside (PX4 SIH's estimate read 0.8 m of climb on the ground after a landing,
            # which the record's figures had counted as the estimate's error in flight)
            return
        dt = min(0.1, max(-0.1, msg.time_boot_ms / 1000.0 - s.t))
        est_h = float(p.origin[2] - (s.pos[2] + s.vel[2] * dt))
        t = s.t + dt - p.t0
        gap = rf.add(t, est_h, h, in_air=self.v.takeover_in_air)
        if self.clock.phase != "mission":
            return
        why = rf.clearance(msg.time_boot_ms / 1000.0, gap, h, self.m.safety.min_clearance,
                           p.airborne(t))
        if why is not None:
            self.failsafe.escalate("clearance", why)
