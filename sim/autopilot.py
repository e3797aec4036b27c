"""The autopilot around the bundled vehicle: its mode and arming, the setpoints it takes, and
what it does by itself.

What a MAVLink handler asks of the autopilot (arm, disarm, a mode, a takeoff, a setpoint) is
decided here by the personality's rules (:mod:`sim.personality`) and answered with a MAV_RESULT,
as PX4's commander and ArduCopter's mode logic answer it.  Around each step of the vehicle the
autopilot carries out what waited for the motors' spool-up and runs GUIDED's attitude control
(before), then its land detector (behind EXTENDED_SYS_STATE) and its supervision: the
offboard-loss failsafe, the end of a takeoff, the return to launch, automatic disarming
(after).  It knows no links or messages: it speaks through ``say(severity, text)`` (a
STATUSTEXT) and ``heartbeat_now()`` (an extra HEARTBEAT).
"""

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from . import personality as PP
from .firmware import position as PL

# ignore bits of SET_ATTITUDE_TARGET's type_mask
AT_RATES = 0x7
AT_THROTTLE = 64
AT_ATTITUDE = 128


@dataclass
class AttitudeSetpoint:
    """SET_ATTITUDE_TARGET as the autopilot takes it: attitude q [w, x, y, z], normalized thrust,
    body rates (rad/s) and the type_mask as sent."""
    q: list
    thrust: float
    rates: list
    mask: int

    @property
    def throttle_ignored(self):
        return bool(self.mask & AT_THROTTLE)

    @property
    def attitude_ignored(self):
        return bool(self.mask & AT_ATTITUDE)

    @property
    def rates_ignored(self):
        return (self.mask & AT_RATES) == AT_RATES


class Autopilot:
    """The autopilot of personality ``ap`` flying ``vehicle`` (a :class:`sim.vehicle.SimVehicle`)
    with parameters ``params`` ({name: (value, MAV_PARAM_TYPE)}) from ``home`` (lat, lon, alt
    AMSL); ``stream_stalled()`` says whether the setpoint stream stopped on the wall clock (in
    lockstep, where the vehicle's clock stops with it)."""

    def __init__(self, vehicle, ap, params, home, say, heartbeat_now, stream_stalled):
        self.vehicle = vehicle
        self.ap = ap
        self.params = params
        self.home = home
        self._say = say
        self._heartbeat_now = heartbeat_now
        self._stream_stalled = stream_stalled
        self.mode = ap.mode(ap.initial_mode)
        self.failsafe = False
        self.failsafe_t = None  # vehicle time the last offboard-loss failsafe fired
        self._mode_before_failsafe = None  # what a failsafe switched away from
        self.last_setpoint_t = -math.inf  # vehicle time of the last proof-of-life setpoint
        #: what ATTITUDE_TARGET echoes: (q, thrust, body rates, type_mask)
        self.att_target = (np.array([1.0, 0.0, 0.0, 0.0]), 0.0, np.zeros(3), 0)
        self.guided = PP.GuidedAngleControl()
        self.rtl_phase = None  # "return", then "land"
        self.ld = ap.land_detector()
        self._taken_off = False  # the land detector saw a take-off since arming
        self._armed_t = 0.0
        self._landed_since = None  # vehicle time the land detector last declared landing
        self._spool_until = -math.inf  # motors held at idle after arming until then
        self._deferred = None  # what the last setpoint or takeoff asked for while held at idle
        self._rep = None
        vehicle.auto_disarm_s = None  # the autopilot disarms by itself (after_step)
        self._apply_mode_behaviour()

    def reported(self):
        """The vehicle's reported state, read once per step for everything built from it."""
        if self._rep is None:
            self._rep = self.vehicle.reported()
        return self._rep

    # --- each step -------------------------------------------------------------------------------

    def before_step(self, dt):
        """What waited for the spool-up, now that the motors are free; GUIDED's attitude
        control."""
        if self._deferred is not None and not self.spooling():
            apply, self._deferred = self._deferred, None
            apply()
        if self.guided.target is not None and self.vehicle.armed and not self.spooling():
            timeout = float(self.params[self.ap.offboard_timeout_param][0])
            self.guided.output(dt, self.vehicle, self.params, timeout, self.ld.landed,
                               self.reported)

    def after_step(self, dt):
        """The land detector on the new state, then the autopilot's supervision: offboard
        loss, takeoff complete, return to launch, auto-disarm."""
        self._rep = None
        self._detect_landing(dt)
        v = self.vehicle
        t = v.time
        if (self.ap.offboard_loss_failsafe and self.mode.behaviour == PP.OFFBOARD and v.armed
                and not self.failsafe):
            timeout = float(self.params[self.ap.offboard_timeout_param][0])
            if self._stream_stalled() or t - self.last_setpoint_t > timeout:
                self._offboard_lost()
        if (self.ap.mode_after_takeoff and self.mode.behaviour == PP.TAKEOFF
                and v.mode == "hold"):
            self.set_mode(self.ap.mode(self.ap.mode_after_takeoff))
        # return to launch: go home, then land
        if self.mode.behaviour == PP.RTL and self.rtl_phase == "return" and v.armed:
            p = self.reported().position
            if math.hypot(p[0], p[1]) < 0.5:
                self.rtl_phase = "land"
                v.land(self.ap.land_speed(self.params))
        # auto-disarm: the personality's rules (landed for a while, or no takeoff after arming)
        if v.armed:
            why = self.ap.auto_disarm(self.params, t, self._armed_t, self._taken_off,
                                      self._landed_since)
            if why is not None:
                self.disarm(why)

    def _detect_landing(self, dt):
        """Run the personality's land detector on this step; announce and time its changes."""
        v = self.vehicle
        r = self.reported()
        q_sp, thrust = v.attitude_setpoint
        climb_rate_control = v.mode != "attitude"
        descent = math.inf  # landing, or idle on the ground
        if v.mode in ("position", "hold", "takeoff"):
            sp = v.nav.sp
            descent = sp[PL.PSP_VEL + 2] if math.isfinite(sp[PL.PSP_VEL + 2]) else 0.0
            if math.isfinite(sp[PL.PSP_POS + 2]):
                descent += v.nav.pp[PL.PP_KP + 2] * (sp[PL.PSP_POS + 2] - r.position[2])
        tilt = math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (q_sp[1] ** 2 + q_sp[2] ** 2))))
        u = PP.LandInputs(thrust, (float(r.velocity[0]), float(r.velocity[1]),
                                   float(r.velocity[2])),
                          math.hypot(r.rates[0], r.rates[1]), tilt, climb_rate_control, descent)
        was = self.ld.landed
        self.ld.update(dt, self.params, v.armed, u)
        if not v.armed or was == self.ld.landed:
            return
        if self.ld.landed:
            self._landed_since = v.time
            if self.ap.landing_text:
                self._say(mavlink.MAV_SEVERITY_INFO, self.ap.landing_text)
        else:
            self._landed_since = None
            self._taken_off = True
            if self.ap.takeoff_text:
                self._say(mavlink.MAV_SEVERITY_INFO, self.ap.takeoff_text)

    def landed_state(self):
        """EXTENDED_SYS_STATE.landed_state from the autopilot's land detector, not from the
        vehicle's contact with the ground."""
        if self.ld.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.mode.behaviour == PP.TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.mode.behaviour == PP.LAND or (self.mode.behaviour == PP.RTL
                                              and self.rtl_phase == "land"):
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _offboard_lost(self):
        """The offboard-loss failsafe (the personality's offboard_loss_action), announced as PX4
        does: the event text, then the STATUSTEXT "Failsafe activated"."""
        self.failsafe = True
        self.failsafe_t = self.vehicle.time
        if self._mode_before_failsafe is None:
            self._mode_before_failsafe = self.mode
        target, action = self.ap.offboard_loss_action(self.params)
        self._say(mavlink.MAV_SEVERITY_CRITICAL, f"Failsafe activated: switching to {action}")
        self._say(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated")
        if target in ("DISARM", "TERMINATE"):
            self.disarm("failsafe")
        else:
            self.set_mode(self.ap.mode(target))

    # --- the motors' spool-up --------------------------------------------------------------------

    def spooling(self):
        """The motors are still held at idle after arming (the personality's spoolup_param)."""
        return self.vehicle.armed and self.vehicle.time < self._spool_until - 1e-9

    def when_spooled(self, apply):
        """Carry out a setpoint or takeoff now, or once the motors are free if they are still held
        at idle after arming (the last request wins)."""
        if self.spooling():
            self._deferred = apply
        else:
            self._deferred = None
            apply()

    # --- setpoints -------------------------------------------------------------------------------

    def _takes_setpoints(self):
        return not self.ap.setpoints_only_in_offboard or self.mode.behaviour == PP.OFFBOARD

    def stream_alive(self):
        """A setpoint came within the offboard timeout."""
        timeout = float(self.params[self.ap.offboard_timeout_param][0])
        return self.vehicle.time - self.last_setpoint_t <= timeout

    def take_attitude_setpoint(self, sp):
        """An attitude setpoint (:class:`AttitudeSetpoint`), as the personality takes it;
        whether it is proof of life of the setpoint stream (False: ignored)."""
        if not self._takes_setpoints():
            return False
        alive = self.ap.attitude_setpoint(self, sp)
        if alive:
            self.last_setpoint_t = self.vehicle.time
        return alive

    def fly_attitude(self, sp):
        """Give the vehicle's attitude controller setpoint ``sp`` now (what waited for the
        spool-up lapses)."""
        self._deferred = None
        self.vehicle.set_attitude_target(sp.q, sp.thrust,
                                         body_rates=None if sp.rates_ignored else sp.rates,
                                         type_mask=sp.mask)

    def take_position_setpoint(self, pos, vel, acc, yaw, yaw_rate):
        """A local NED position target (None: a part ignored); whether it was taken (False:
        ignored).  Flown in the offboard mode when armed, once the motors are free (PX4
        Takeoff.cpp, ArduCopter's interlock); not on the ground where the personality flies
        none there (:attr:`~sim.personality.Personality.position_targets_on_ground`)."""
        if not self._takes_setpoints():
            return False
        self.last_setpoint_t = self.vehicle.time
        if not self.ap.position_targets_on_ground and self.vehicle.landed:
            # (proof of life all the same; a takeoff under way goes on: ArduCopter's would
            # be replaced by the target, and stay on the ground)
            return True
        self.guided.target = None
        if self.mode.behaviour == PP.OFFBOARD and self.vehicle.armed:
            self.when_spooled(lambda: self.vehicle.set_position_target(
                pos=pos, vel=vel, acc=acc, yaw=yaw, yaw_rate=yaw_rate))
        return True

    # --- arming ----------------------------------------------------------------------------------

    def arm(self, force):
        M = mavlink
        v = self.vehicle
        if v.armed:
            return M.MAV_RESULT_ACCEPTED
        if not force:
            if not self.mode.armable:
                self._say(M.MAV_SEVERITY_CRITICAL, f"Arming denied: not armable in {self.mode.name}")
                return self.ap.arming_refused
            if (self.mode.behaviour == PP.OFFBOARD and self.ap.offboard_needs_stream
                    and not self.stream_alive()):
                self._say(M.MAV_SEVERITY_CRITICAL, "Arming denied: no offboard signal")
                return self.ap.arming_refused
            if not v.landed:
                return self.ap.arming_refused
        v.arm()
        self._taken_off = False
        self._armed_t = v.time
        self._landed_since = v.time if self.ld.landed else None
        self._spool_until = v.time + max(0.0, float(self.params[self.ap.spoolup_param][0]))
        self._deferred = None
        self.guided.climb_i = 0.0
        self.failsafe = False
        self._mode_before_failsafe = None
        self._say(M.MAV_SEVERITY_INFO, self.ap.armed_text())
        return M.MAV_RESULT_ACCEPTED  # no heartbeat now: the next 1 Hz one shows it

    def disarm_command(self, force):
        M = mavlink
        if not self.vehicle.armed:
            return M.MAV_RESULT_ACCEPTED
        if not force and not self.ap.disarm_allowed(self.ld):
            if self.ap.disarm_denied_text:
                self._say(M.MAV_SEVERITY_CRITICAL, self.ap.disarm_denied_text)
            return self.ap.arming_refused
        self.disarm("external")
        return M.MAV_RESULT_ACCEPTED

    def disarm(self, why):
        """Disarm (the autopilot's decision: the vehicle's own landed flag is not asked)."""
        self.vehicle.disarm(force=True)
        self.guided.target = None
        self._deferred = None
        self._taken_off = False
        self._landed_since = None
        self.failsafe = False
        self._say(mavlink.MAV_SEVERITY_INFO, self.ap.disarmed_text(why))
        before, self._mode_before_failsafe = self._mode_before_failsafe, None
        if before is not None and self.ap.restores_mode_after_failsafe:
            self.mode = before
            self._mode_changed()
        elif self.mode.behaviour in (PP.LAND, PP.RTL, PP.TAKEOFF):
            self.mode = self.ap.mode(self.ap.initial_mode)
            self._apply_mode_behaviour()
            self._mode_changed()

    # --- modes -----------------------------------------------------------------------------------

    def _mode_changed(self):
        """The mode has just changed: ArduPilot sends a heartbeat at once, PX4 waits for the next
        one of its 1 Hz stream."""
        if self.ap.heartbeat_on_mode_change:
            self._heartbeat_now()

    def set_mode(self, mode):
        M = mavlink
        if (mode.behaviour == PP.OFFBOARD and self.ap.offboard_needs_stream
                and not self.stream_alive()):
            self._say(M.MAV_SEVERITY_CRITICAL, "Offboard denied: no setpoint stream")
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode.behaviour == PP.TAKEOFF and not self.vehicle.armed:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        changed = mode is not self.mode
        self.mode = mode
        if changed:
            self._deferred = None  # a takeoff or setpoint held back for the spool-up lapses
        if changed or mode.behaviour != PP.OFFBOARD:
            self._apply_mode_behaviour()
        if mode.behaviour != PP.OFFBOARD:
            self.guided.target = None
        self.failsafe = self.failsafe and mode.behaviour != PP.OFFBOARD
        if changed:
            self._mode_changed()
        return M.MAV_RESULT_ACCEPTED

    def _apply_mode_behaviour(self):
        v = self.vehicle
        b = self.mode.behaviour
        self.rtl_phase = None
        if b == PP.HOLD:
            if v.armed:
                v.hold()  # on the ground: idle, whatever offboard thrust was last asked for
        elif b == PP.LAND:
            if v.armed:
                v.land(self.ap.land_speed(self.params))
        elif b == PP.PILOT:
            if v.armed:
                v.land(self.ap.pilot_descent(self.params))  # no pilot: the throttle at minimum
        elif b == PP.RTL:
            if v.armed and not v.landed:
                p = v.reported().position
                alt = max(-p[2], self.ap.rtl_altitude(self.params))
                v.set_position_target(pos=np.array([0.0, 0.0, -alt]))
                self.rtl_phase = "return"
            elif v.armed:
                v.hold()
        elif b == PP.TAKEOFF:
            alt = self.ap.takeoff_altitude(self.params, math.nan, self.home[2])
            self.when_spooled(lambda: v.takeoff(alt))
        elif b == PP.OFFBOARD:
            if v.armed and not v.landed and self.ap.offboard_entry_holds:
                v.hold()

    def takeoff(self, p7):
        """MAV_CMD_NAV_TAKEOFF with param7 ``p7``: in the personality's takeoff mode, or in the
        offboard mode if it has none."""
        M = mavlink
        v = self.vehicle
        if not v.armed:
            self._say(M.MAV_SEVERITY_CRITICAL, "Takeoff denied: disarmed")
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if self.ap.takeoff_mode is None and self.mode.behaviour != PP.OFFBOARD:
            return M.MAV_RESULT_FAILED
        alt = self.ap.takeoff_altitude(self.params, p7, self.home[2])
        if alt is None:
            return M.MAV_RESULT_DENIED
        self.guided.target = None
        changed = False
        if self.ap.takeoff_mode is not None:
            mode = self.ap.mode(self.ap.takeoff_mode)
            changed = mode is not self.mode
            self.mode = mode
        self.when_spooled(lambda: v.takeoff(alt))
        if changed:
            self._mode_changed()
        return M.MAV_RESULT_ACCEPTED
