"""SET_ATTITUDE_TARGET and SET_POSITION_TARGET_LOCAL_NED, the offboard setpoints: checked as
the autopilots check them, then handed to the autopilot (:mod:`sim.autopilot`), whose
personality decides what it does with them.

A malformed setpoint (non-finite values, a quaternion not of unit length, thrust outside 0..1,
nothing to act on, an unsupported frame) is rejected, counted and announced (one STATUSTEXT a
second per reason); a well-formed one the autopilot does not take is counted as ignored.  Every
well-formed setpoint, taken or not, is a tick of the lockstep clock (``on_setpoint``): the
companion's stream is the clock.
"""

import math
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ..autopilot import AttitudeSetpoint

# ignore bits of SET_POSITION_TARGET_LOCAL_NED's type_mask
PT_POS = 0x7
PT_VEL = 0x38
PT_ACC = 0x1C0
PT_YAW = 0x400
PT_YAW_RATE = 0x800

FRAMES = (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
          mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)


class Offboard:
    """The setpoint handlers of ``autopilot``; ``stats`` counts, ``statustext_limited(key,
    severity, text)`` announces a rejection."""

    def __init__(self, autopilot, stats, statustext_limited, on_setpoint):
        self.autopilot = autopilot
        self.stats = stats
        self._announce = statustext_limited
        self._on_setpoint = on_setpoint
        self.last_setpoint_wall = -math.inf  # wall time of the last proof-of-life setpoint

    def _reject(self, reason):
        self.stats.setpoints_rejected += 1
        self.stats.count(reason)
        self._announce(reason, mavlink.MAV_SEVERITY_WARNING, f"Setpoint rejected: {reason}")

    def _taken(self, alive):
        if alive:
            self.last_setpoint_wall = time.monotonic()
        else:
            self.stats.setpoints_ignored += 1
        self._on_setpoint()

    def on_attitude_target(self, link, msg):
        sp = AttitudeSetpoint([float(c) for c in msg.q], float(msg.thrust),
                              [float(msg.body_roll_rate), float(msg.body_pitch_rate),
                               float(msg.body_yaw_rate)], msg.type_mask)
        if not sp.attitude_ignored:
            if not all(math.isfinite(c) for c in sp.q):
                return self._reject("non-finite quaternion")
            if abs(math.sqrt(sum(c * c for c in sp.q)) - 1.0) > 1e-3:
                return self._reject("quaternion not unit length")
        if not sp.throttle_ignored:
            if not math.isfinite(sp.thrust):
                return self._reject("non-finite thrust")
            if not 0.0 <= sp.thrust <= 1.0:
                return self._reject("thrust out of range")
        if not sp.rates_ignored and not all(math.isfinite(c) for c in sp.rates):
            return self._reject("non-finite body rates")
        if sp.attitude_ignored and sp.rates_ignored:
            return self._reject("attitude and rates both ignored")
        self._taken(self.autopilot.take_attitude_setpoint(sp))

    def on_position_target(self, link, msg):
        mask = msg.type_mask
        if msg.coordinate_frame not in FRAMES:
            return self._reject("unsupported frame")
        pos = None if mask & PT_POS else np.array([msg.x, msg.y, msg.z], dtype=float)
        vel = None if mask & PT_VEL else np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        acc = None if mask & PT_ACC else np.array([msg.afx, msg.afy, msg.afz], dtype=float)
        yaw = None if mask & PT_YAW else float(msg.yaw)
        yaw_rate = None if mask & PT_YAW_RATE else float(msg.yaw_rate)
        for name, val in (("position", pos), ("velocity", vel), ("acceleration", acc),
                          ("yaw", yaw), ("yaw rate", yaw_rate)):
            if val is not None and not np.all(np.isfinite(val)):
                return self._reject(f"non-finite {name}")
        if pos is None and vel is None and acc is None:
            return self._reject("position target ignores everything")
        if pos is not None and np.abs(pos).max() > 1e5:
            return self._reject("position out of range")
        r = self.autopilot.reported()
        if msg.coordinate_frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
            c, s = math.cos(r.euler[2]), math.sin(r.euler[2])
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            vel = None if vel is None else rot @ vel
            acc = None if acc is None else rot @ acc
            if pos is not None:
                pos = r.position + rot @ pos
        elif msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED and pos is not None:
            pos = r.position + pos
        self._taken(self.autopilot.take_position_setpoint(pos, vel, acc, yaw, yaw_rate))
