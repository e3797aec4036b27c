"""The setpoints a flight sends: exactly one per sample, counted.  SET_ATTITUDE_TARGET for the
companion's own controllers; SET_POSITION_TARGET_LOCAL_NED when the autopilot's own position
controller flies (``controller: native``), where every attitude the phases would send becomes
a position target (:meth:`Setpoints.send`)."""

import math
import time

import numpy as np

from mavadrc.control.rotations import euler_from_quat, level_quat
from mavadrc.mission.takeoff import GROUND_TARGET_BELOW_M


_Z3 = np.zeros(3)


class Setpoints:
    """Setpoints out on ``link``, with the counts summary.json keeps.  ``native``: the
    autopilot's position controller flies; the targets are placed from the samples of
    ``vehicle`` (:class:`~mavadrc.flight.state.Vehicle`)."""

    def __init__(self, link, vehicle=None, native=False):
        self.link = link
        self.v = vehicle
        self.native = native
        self.last = (level_quat(0.0), 0.0)  # the last (q, thrust) sent
        self.last_target = None  # native: the last (pos, vel, acc, yaw) sent
        self.sent = 0
        self.kicks = 0  # setpoints sent without a sample (a lockstep clock kept going)
        self.double_answers = 0  # samples answered by more than one setpoint (must stay 0)
        self.last_wall = 0.0
        self._answered_t = None

    def _count(self, t, kick):
        self.sent += 1
        self.last_wall = time.monotonic()
        if kick:
            self.kicks += 1
        elif t == self._answered_t:
            self.double_answers += 1  # never: see Flight.on_sample
        else:
            self._answered_t = t

    def send(self, t, q, thrust, kick=False):
        """A setpoint for the sample at vehicle time ``t``, or, ``kick``, one sent without a
        sample (a lockstep clock kept going, the level hover when telemetry stopped).
        ``native``: no attitude is sent; the vehicle is held where its last sample has it at
        the heading of ``q``, or, at zero thrust (the ground phases), held down
        (:data:`GROUND_TARGET_BELOW_M`)."""
        if self.native:
            yaw = float(euler_from_quat(q)[2])
            return self.hold(t, yaw, ground=thrust == 0.0, kick=kick)
        self.last = (q, thrust)
        self.link.attitude_target(t * 1000.0, q, thrust)
        self._count(t, kick)

    def idle(self, t, yaw):
        """A level setpoint at zero thrust (the motors at idle) for the sample at ``t``: the
        stream PX4 wants before OFFBOARD, harmless to a vehicle on the ground (``native``: a
        target under it)."""
        if self.native:
            return self.hold(t, yaw, ground=True)
        self.send(t, level_quat(yaw), 0.0)

    def hold(self, t, yaw, ground=False, kick=False):
        """``native``: a position target where the vehicle's last sample has it, at rest
        (``ground``: :data:`GROUND_TARGET_BELOW_M` under it)."""
        s = self.v.last if self.v is not None else None
        if s is None:
            pos = np.zeros(3) if self.last_target is None else self.last_target[0]
        else:
            pos = np.array(s.pos, dtype=float)
        if ground:
            pos = pos + np.array([0.0, 0.0, GROUND_TARGET_BELOW_M])
        self.position(t, pos, _Z3, _Z3, yaw, kick=kick)

    def position(self, t, pos, vel, acc, yaw, kick=False):
        """A position target (NED position, velocity, acceleration, yaw) for the sample at
        ``t``: what the autopilot's own position controller flies."""
        self.last_target = (np.array(pos, dtype=float), vel, acc, yaw)
        self.last = (level_quat(yaw), math.nan)
        self.link.position_target(t * 1000.0, pos, vel, acc, yaw)
        self._count(t, kick)
