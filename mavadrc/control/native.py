"""``native``: the autopilot's own position controller flies the mission.

No law runs here.  Each control step the companion hands the autopilot the mission's reference
(position, velocity, acceleration and yaw, by SET_POSITION_TARGET_LOCAL_NED) and the autopilot's
position loop (PX4's mc_pos_control in OFFBOARD, ArduCopter's GUIDED position controller, the
bundled vehicle's :mod:`sim.firmware.position`) makes the attitude and thrust.  This is the
baseline every other controller is measured against: what a user of the autopilot gets without
the companion's loop.

:class:`NativeController` stands where a
:class:`~mavadrc.control.position.PositionController` stands in a flight, with the parts of
its interface a flight reads: it has no disturbance estimate (NaN), no drag model, no thrust to
learn, compensates no sample age and feeds nothing forward; :meth:`update` returns the
reference it is given as the target the autopilot is sent.
"""

import math

import numpy as np

NAN3 = (math.nan, math.nan, math.nan)


class NativeController:
    """The stand-in for the autopilot's own position controller (see the module)."""

    kind = "native"
    models_drag = False
    learns_thrust = False
    thrust_at_most = False
    latency = None

    def __init__(self, hover_thrust=0.5, tilt_max=math.radians(35.0), h=0.01):
        self.hover_thrust_estimate = float(hover_thrust)
        self.tilt_limit = float(tilt_max)
        self.h = float(h)
        self.z = np.full((3, 3), math.nan)
        self.td = np.full((3, 2), math.nan)
        self.drag = np.zeros(3)
        self.feedforward_lead = np.zeros(3)
        self.prediction = np.zeros(3)
        self.accel_command = np.full(3, math.nan)
        self.accel_applied = np.full(3, math.nan)
        self.target = None  # the last target: (pos, vel, acc, yaw)

    @property
    def disturbance(self):
        return self.z[:, 2]

    def sample_age(self, age):
        """The age the reference is led by: none (the autopilot flies on its own estimate)."""
        return math.nan

    def update(self, pos, vel, ref_pos=None, ref_vel=None, ref_acc=None, ref_yaw=0.0, dt=None,
               age=None, ref_acc_now=None):
        """The target for the autopilot: the reference given (zeros where not given)."""
        z3 = np.zeros(3)
        self.target = (np.array(ref_pos if ref_pos is not None else pos, dtype=float),
                       np.array(ref_vel if ref_vel is not None else z3, dtype=float),
                       np.array(ref_acc if ref_acc is not None else z3, dtype=float),
                       float(ref_yaw))
        return np.full(4, math.nan), math.nan

    # what a flight asks of a position controller, with nothing to do here
    def reset(self, pos=None, vel=None):
        self.target = None

    def hold_disturbance(self):
        pass

    def raise_thrust(self, factor):
        pass

    def pause_thrust_learning(self, paused=True):
        pass

    def set_drag(self, drag):
        pass
