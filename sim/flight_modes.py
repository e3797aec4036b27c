"""The bundled vehicle's flight modes: arming, offboard setpoints, takeoff, land, hold, idle, and
at each position-loop tick the mode logic and the autopilot's own position loop.

A :class:`FlightModes` writes the attitude setpoint and the armed flag of the vehicle's
:class:`sim.kernel_state.KernelState`, steers its :class:`sim.firmware.position.Navigator`, and
reads where the vehicle is as it reports itself (:class:`sim.reporting.Reporting`), as an
autopilot's modes fly on its estimate.  :class:`sim.vehicle.SimVehicle` describes the commands.
"""

import math

import numpy as np

from mavadrc.control.rotations import level_quat

from .firmware import attitude as A
from .firmware import position as PL

MODES = ("attitude", "position", "takeoff", "hold", "land", "idle")

# SET_ATTITUDE_TARGET type_mask bits
IGNORE_ROLL_RATE = 1
IGNORE_PITCH_RATE = 2
IGNORE_YAW_RATE = 4
IGNORE_THRUST = 64
IGNORE_ATTITUDE = 128


class CommandRejected(RuntimeError):
    """The vehicle refuses a command in its current state (MAVLink: MAV_RESULT_DENIED)."""


class FlightModes:
    """The mode (one of :data:`MODES`) of the vehicle whose state is ``ks``, flying with ``nav``
    and reading itself through ``reporting``; ``home`` (NED) is where it was last armed on the
    ground; ``auto_disarm_s`` as :class:`sim.vehicle.SimVehicle`'s."""

    def __init__(self, ks, nav, reporting, *, home, auto_disarm_s):
        self.ks = ks
        self.nav = nav
        self.reporting = reporting
        self.home = home
        self.auto_disarm_s = auto_disarm_s
        self.mode = "idle"
        self.landed_at = None  # when a land() touched down

    def _reported(self):
        return self.reporting.reported(self.ks)

    def _yaw(self):
        return float(self._reported().euler[2])

    def arm(self):
        ks = self.ks
        if ks.armed:
            return
        ks.fs[A.FS_ARMED] = 1.0
        self.nav.reset()
        if ks.landed:
            self.home = ks.x[0:3].copy()
        if self.mode not in ("attitude", "position"):
            self.set_idle()

    def disarm(self, force=False):
        ks = self.ks
        if not ks.armed:
            return
        if not ks.landed and not force:
            raise CommandRejected("disarm refused: the vehicle is flying (use force=True)")
        ks.fs[A.FS_ARMED] = 0.0
        self.landed_at = None
        self.mode = "idle"

    def set_attitude_target(self, q, thrust, body_rates=None, type_mask=0):
        sp = self.ks.sp
        mask = int(type_mask)
        if not mask & IGNORE_ATTITUDE:
            qa = np.asarray(q, dtype=float).reshape(4).tolist()
            n = math.sqrt(qa[0] * qa[0] + qa[1] * qa[1] + qa[2] * qa[2] + qa[3] * qa[3])
            if not (math.isfinite(n) and n > 1e-6):  # a NaN or inf component makes n so
                raise ValueError(f"attitude quaternion must be finite and non-zero (got {q!r})")
            for i in range(4):
                sp[A.SP_Q + i] = qa[i] / n
        sp[A.SP_ATT_VALID] = 0.0 if mask & IGNORE_ATTITUDE else 1.0
        for i, bit in enumerate((IGNORE_ROLL_RATE, IGNORE_PITCH_RATE, IGNORE_YAW_RATE)):
            given = body_rates is not None and not mask & bit
            sp[A.SP_RATE_VALID + i] = 1.0 if given else 0.0
            sp[A.SP_RATES + i] = float(body_rates[i]) if given else 0.0
            if given and not math.isfinite(sp[A.SP_RATES + i]):
                raise ValueError(f"body rates must be finite (got {body_rates!r})")
        if not mask & IGNORE_THRUST:
            t = float(thrust)
            if not math.isfinite(t):
                raise ValueError(f"thrust must be finite (got {thrust!r})")
            sp[A.SP_THRUST] = min(max(t, 0.0), 1.0)
        self.mode = "attitude"

    def set_position_target(self, pos=None, vel=None, acc=None, yaw=None, yaw_rate=None):
        if pos is None and vel is None and acc is None:
            raise ValueError("a position target needs at least one of pos, vel, acc")
        self.nav.set_target(pos, vel, acc, yaw, yaw_rate, yaw_now=self._yaw())
        self.mode = "position"

    def takeoff(self, altitude):
        if not self.ks.armed:
            raise CommandRejected("takeoff refused: disarmed")
        alt = float(altitude)
        if not (math.isfinite(alt) and alt > 0.0):
            raise ValueError(f"takeoff altitude must be > 0 (got {altitude!r})")
        r = self._reported()
        self.nav.takeoff(r.position, r.euler[2], self.home[2] - alt)
        self.landed_at = None
        self.mode = "takeoff"

    def land(self, speed=None):
        if not self.ks.armed or self.ks.landed:
            self.set_idle()
            return
        r = self._reported()
        self.nav.land(r.position, r.euler[2], speed)
        self.mode = "land"

    def hold(self):
        if not self.ks.armed or self.ks.landed:
            self.set_idle()
            return
        r = self._reported()
        self.nav.hold(r.position, r.euler[2])
        self.mode = "hold"

    def set_idle(self):
        """Level at the heading the vehicle reports, thrust 0."""
        self.ks.set_attitude(level_quat(self._yaw()), 0.0)
        self.mode = "idle"

    def outer(self):
        """Position-loop tick: flight-mode logic and, in the navigator's modes, the cascade."""
        ks = self.ks
        if self.mode == "land" and ks.landed:
            self.set_idle()
            self.landed_at = ks.time
        if (self.mode == "idle" and self.landed_at is not None and ks.armed
                and self.auto_disarm_s is not None
                and ks.time - self.landed_at >= self.auto_disarm_s - 1e-9):
            self.disarm()
        if self.mode in PL.Navigator.MODES:
            r = self._reported()
            q, thrust = self.nav.update(r.position, r.velocity, ks.landed)
            ks.set_attitude(q, thrust)
            self.mode = self.nav.mode
