"""The setpoints a flight sends: exactly one SET_ATTITUDE_TARGET per sample, counted."""

import time

from mavadrc.control.rotations import level_quat


class Setpoints:
    """SET_ATTITUDE_TARGET out on ``link``, with the counts summary.json keeps."""

    def __init__(self, link):
        self.link = link
        self.last = (level_quat(0.0), 0.0)  # the last (q, thrust) sent
        self.sent = 0
        self.kicks = 0  # setpoints sent without a sample (a lockstep clock kept going)
        self.double_answers = 0  # samples answered by more than one setpoint (must stay 0)
        self.last_wall = 0.0
        self._answered_t = None

    def send(self, t, q, thrust, kick=False):
        """A setpoint for the sample at vehicle time ``t``, or, ``kick``, one sent without a
        sample (a lockstep clock kept going, the level hover when telemetry stopped)."""
        self.last = (q, thrust)
        self.link.attitude_target(t * 1000.0, q, thrust)
        self.sent += 1
        self.last_wall = time.monotonic()
        if kick:
            self.kicks += 1
        elif t == self._answered_t:
            self.double_answers += 1  # never: see Flight.on_sample
        else:
            self._answered_t = t

    def idle(self, t, yaw):
        """A level setpoint at zero thrust (the motors at idle) for the sample at ``t``: the
        stream PX4 wants before OFFBOARD, harmless to a vehicle on the ground."""
        self.send(t, level_quat(yaw), 0.0)
