"""The takeoff of a flight: the motors' delay waited out and the thrust spooled up, the
mission's frame set where the vehicle is, and, from the ground, a reference that waits for a
vehicle heavier than told to lift off while the thrust rises (the rules shared with the fast
path are in :mod:`mavadrc.mission.takeoff`)."""

import math

import numpy as np

from mavadrc.control.rotations import level_quat, wrap_pi
from mavadrc.design.margin import margin_text, prediction_text
from mavadrc.errors import FlightError
from mavadrc.mavlink.commands import result_name
from mavadrc.mavlink.dialect import M
from mavadrc.mission.identification import HANDOVER_S, TAKEOFF_HANDOVER_S, leg_speed_of, windows_in
from mavadrc.mission.takeoff import (
    LIFTOFF_HEIGHT,
    NATIVE_TAKEOFF_WAIT_S,
    SPOOL_S,
    TAKEOFF_RAMP_PER_S,
    TAKEOFF_WAIT_M,
    TAKEOFF_WAIT_MAX_S,
    lifted_off,
    spool_thrust,
)
from mavadrc.mission.trajectories import Reference


class Takeoff:
    """Spool-up, the mission's start, and the lift-off (``liftoff_s``, ``takeoff_wait``)."""

    def __init__(self, mission, clock, vehicle, progress, notices, setpoints, steering, choice,
                 ident, gate, tracks, start_at):
        self.m = mission
        self.clock = clock
        self.v = vehicle
        self.progress = progress
        self.notices = notices
        self.setpoints = setpoints
        self.steering = steering
        self.choice = choice
        self.ident = ident
        self.gate = gate
        self.tracks = tracks
        # vehicle time (s) at which the mission clock starts, the thrust spooled up over the
        # SPOOL_S before it (experiments: every run starts at the same time); None: as soon as
        # the motors are up
        self.start_at = start_at
        self.wait = 0.0  # s the takeoff's reference waited for the vehicle to lift off
        self.liftoff_hover = None  # the hover thrust taken at lift-off, after a wait
        self.liftoff_s = None  # mission time of the lift-off seen
        self.range_disputed = False  # the range finder said the estimate's lift-off was not
        self.yaw_offset = 0.0  # the heading still to turn from the vehicle's to the mission's
        self._waited_capped = 0.0  # s of that waiting with the thrust at its bound
        self.takeoff_cmd = None  # native on ArduCopter: its MAV_CMD_NAV_TAKEOFF

    def spool_phase(self, s):
        t_arm = self.clock.t0
        motors = t_arm + self.v.motor_delay
        end = self.start_at if self.start_at is not None else motors + SPOOL_S
        if self.start_at is not None and motors > self.start_at - SPOOL_S + 1e-9:
            raise FlightError(f"armed at {t_arm:.3f} s with a {self.v.motor_delay:g} s motor "
                              f"delay: too late to start the mission at {self.start_at:.3f} s")
        # (native: the autopilot spools its motors itself; the target stays under the vehicle)
        self.setpoints.send(s.t, level_quat(self.v.yaw),
                            0.0 if self.setpoints.native
                            else float(spool_thrust(s.t, end, self.choice.hover)))
        if s.t >= end - 1e-9 or lifted_off(self.progress.origin[2] - s.pos[2], s.vel[2]):
            self.start_mission(s)  # the controller flies from the next sample

    def start_reference(self, s):
        """The mission's frame: from the takeoff spot, or, taking over in the air, as if the
        takeoff had just ended here."""
        p = self.progress
        p.origin = s.pos.copy()
        if self.v.takeover_in_air:
            alt = self.m.segments[0][1]["altitude"]
            p.origin[2] += alt
        p.traj, p.phases = self.m.build_trajectory(p.origin, in_air=self.v.takeover_in_air)

    def _anchor_here(self, s):
        """The takeoff starts where the position estimate has the vehicle when the mission
        starts: the mission's frame moved horizontally to it from where it was measured before
        the mode change, the arming and the spool-up (seconds, over which PX4 SIH's estimate of
        a vehicle at rest wandered 0.05-0.10 m: the loop lifted off already that far from its
        reference, tilted towards it on the ground).  The height keeps the spot measured: it
        is what the lift-off is judged against."""
        p = self.progress
        moved = s.pos[:2] - p.origin[:2]
        p.origin_moved_m = round(float(np.hypot(*moved)), 4)
        p.origin[:2] = s.pos[:2]
        p.traj, p.phases = self.m.build_trajectory(p.origin, in_air=False)

    def start_mission(self, s):
        p, c, ident = self.progress, self.choice, self.ident
        if not self.v.takeover_in_air:  # taking over, the controller already holds the vehicle
            self._anchor_here(s)
            c.ctrl.reset(s.pos)
        self.steering.reset_grid()
        if c.identifying():
            ident.windows = windows_in(p.phases, leg_speed=leg_speed_of(self.m))
            # to the segment's end less its hold: the leg's last ramp and rest too; the fit is
            # made while the vehicle holds still, so the mission's controller takes over at
            # rest, as after the doublets alone
            t_id = dict((name, t0) for t0, name in p.phases)["identify"]
            end = min((t0 for t0, _ in p.phases if t0 > t_id), default=p.traj.duration)
            end -= HANDOVER_S
            ident.span = (ident.windows[0][1], max(end, ident.windows[-1][2]))
            ident.handover_t = ident.data_span()[0] - TAKEOFF_HANDOVER_S
        p.t0 = s.t
        p.start = s.t
        if self.v.seq.takeoff_command and not self.v.takeover_in_air:
            self._command_takeoff()
        if self.tracks.truth is not None:
            self.tracks.truth.start()
        p.lifted = self.v.takeover_in_air
        self.yaw_offset = wrap_pi(self.v.yaw - float(p.traj.sample(0.0).yaw))
        self.gate.restart(c.h)
        # the delay margin is said once: here, or beside the identification that sets the gains
        # the mission flies (the takeoff's safe gains have plenty)
        margin = "" if c.identifying() or c.kind == "native" else \
            f"; {margin_text(c.delay_margin)}"
        self.notices.say(f"flying {self.m.name!r} with {c.kind} at {c.rate:g} Hz "
                         f"({p.traj.duration:.1f} s){ident.takeoff_text()}"
                         f"{prediction_text(c.ctrl)}{margin}")
        self.clock.enter("mission", s)

    def _command_takeoff(self):
        """``native`` on ArduCopter: MAV_CMD_NAV_TAKEOFF to the takeoff segment's altitude (the
        position targets follow once the vehicle is off the ground:
        :meth:`~mavadrc.flight.steering.Steering._native_step`)."""
        kind, spec, _ = self.m.segments[0]
        alt = float(spec.get("altitude", 1.0)) if kind == "takeoff" else 1.0
        self.takeoff_cmd = self.setpoints.link.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0,
                                                       math.nan, 0, 0, alt)
        self.notices.say(f"{self.v.seq.title}'s takeoff to {alt:g} m asked: its position "
                         "controller flies from there")

    def waits(self, s, r):
        """Whether the takeoff's reference ``r`` (the sample's) has climbed
        :data:`~mavadrc.mission.takeoff.TAKEOFF_WAIT_M` above a vehicle still on the ground
        (sample ``s``): it then waits there.  A vehicle heavier than told does not rise on the
        thrust the loop expected to lift it; running on, the reference left PX4 SIH at 1.4 kg
        (told 1.0) 1.1 m below it on the ground for 3.4 s, and it leapt after it at 0.4 m/s.
        (Taken over in the air, the flight starts lifted: never asked.)"""
        if self.setpoints.native:
            return False  # the autopilot's own takeoff: see native_grounded
        return float(s.pos[2] - r.pos[2]) > TAKEOFF_WAIT_M

    def native_grounded(self, t):
        """``native``: why the flight must end, still on the ground
        :data:`NATIVE_TAKEOFF_WAIT_S` into the mission (None otherwise, and for every other
        controller).  The autopilot's loop flies the takeoff's reference
        as it runs, not held for the vehicle as the companion's own loops are: PX4 lifts a
        vehicle by a target above it, and on PX4 SIH a target held 0.15 m above the takeoff
        spot never lifted it: the height estimate rose past the target while the vehicle sat
        still (SIH's truth 0.000 m up), and PX4 took its thrust back."""
        if not self.setpoints.native or self.progress.lifted or t < NATIVE_TAKEOFF_WAIT_S:
            return None
        c = self.takeoff_cmd
        refused = "" if c is None or not c.done or c.accepted else \
            f" (its takeoff command answered {result_name(c.result)})"
        return (f"the vehicle did not lift off: {t:.0f} s into the mission on the ground with "
                f"the autopilot's position controller flying{refused}")

    @staticmethod
    def waiting_reference(s, rc):
        """The reference a waiting takeoff flies to: ``rc`` held vertically at rest
        :data:`~mavadrc.mission.takeoff.TAKEOFF_WAIT_M` above the vehicle's estimate.  Held
        where the wait began instead, an estimate sinking on the ground (PX4 SIH's read 0.3 m of
        descent in a second of waiting) grew the error the vertical observer learns a weight
        from: it learnt 5.9 m/s^2 where 3.9 were missing, and the lift-off overshot 0.42 m."""
        pos = np.array([rc.pos[0], rc.pos[1], float(s.pos[2]) - TAKEOFF_WAIT_M])
        vel = np.array([rc.vel[0], rc.vel[1], 0.0])
        acc = np.array([rc.acc[0], rc.acc[1], 0.0])
        return Reference(pos, vel, acc, rc.yaw, rc.yaw_rate)

    def raise_thrust(self, s):
        """While the takeoff waits: the thrust per acceleration up by TAKEOFF_RAMP_PER_S of
        itself per second, as an autopilot ramps its takeoff thrust until the vehicle lifts
        off.  Why the flight must end, once it has sat at the bound for TAKEOFF_WAIT_MAX_S."""
        ctrl = self.choice.ctrl
        step = s.dt if s.dt is not None else self.choice.h
        if self.wait <= step + 1e-9:
            self.notices.say(f"still on the ground {TAKEOFF_WAIT_M:g} m below the takeoff's "
                             "reference: the reference waits, the thrust rises until it lifts "
                             "off")
        ctrl.raise_thrust(1.0 + TAKEOFF_RAMP_PER_S * step)
        if ctrl.thrust_at_most:
            self._waited_capped += step
            if self._waited_capped >= TAKEOFF_WAIT_MAX_S:
                return (f"the vehicle did not lift off: {self.wait:.0f} s on the ground "
                        f"with the hover thrust raised to {ctrl.hover_thrust_estimate:.2f} "
                        f"(told {self.choice.hover:.2f})")
        return None

    def range_grounded(self, s):
        """Whether a range finder read at rest before the mission, and lately
        (:meth:`~mavadrc.flight.rangefinder.RangeTrack.height_up` at the sample ``s``), still
        reads the vehicle on the ground (under :data:`~mavadrc.mission.takeoff.LIFTOFF_HEIGHT`
        above its reading at rest) when the height estimate reads a lift-off: the lift-off is
        then the estimate's alone.  On PX4 SIH at 1.4 kg (told 1.0), its height estimate read a
        climb of 0.13-0.19 m/s for 2 s while the vehicle sat on the ground under a rising
        thrust: taken for a lift-off, the reference ran on to 1 m, and the clearance check ended
        two of four flights 0.0-0.2 m up with the estimate reading 0.35-0.52 m.  Without such a
        reading (no range finder, or the ground under its minimum distance at rest) the estimate
        decides alone."""
        up = self.tracks.rangefinder.height_up(s.t)
        if up is None or up >= LIFTOFF_HEIGHT:
            return False
        if not self.range_disputed:
            self.range_disputed = True
            self.notices.say(f"the height estimate reads a lift-off "
                             f"({self.progress.origin[2] - s.pos[2]:.2f} m up) the range finder "
                             f"does not ({up:.2f} m): on the ground until it does")
        return True

    def check_liftoff(self, s, t):
        """Before lift-off, on sample ``s`` (mission time ``t``): whether the vehicle has lifted
        off now (said if the takeoff waited); on the ground, the ground's push is held out of
        the disturbance estimates."""
        ctrl = self.choice.ctrl
        if lifted_off(self.progress.origin[2] - s.pos[2], s.vel[2]) and not self.range_grounded(s):
            self.progress.lifted = True
            self.liftoff_s = t
            if self.wait > 0.0:
                self.liftoff_hover = ctrl.hover_thrust_estimate
                self.notices.say(f"lifted off: the takeoff waited {self.wait:.1f} s, the "
                                 f"hover thrust raised to {ctrl.hover_thrust_estimate:.3f} "
                                 f"(told {self.choice.hover:.3f})")
        else:
            ctrl.hold_disturbance()  # on the ground: the ground's push is no disturbance
