"""The sensor side of the bundled vehicle: the estimate its firmware flies on, and the state it
reports to the companion (:meth:`sim.vehicle.SimVehicle.reported`).

A :class:`Reporting` holds the sensor model and its reading; its methods are handed the
vehicle's :class:`sim.kernel_state.KernelState` to read the truth and the clock from.
"""

import dataclasses
import math

import numpy as np

from mavadrc.control.rotations import quat_to_euler

from . import physics as phys
from .sensors import NNOISE, Sensors

#: ``ground_climb_mps``: the shape of the climb the estimate reads after the vehicle comes to
#: rest on the ground, as PX4 SIH's EKF2 read it (0.35-0.4 m/s for 4 s, then dying away with a
#: 4 s time constant, 1.2 m in all, while SIH's truth sat still): held this long (s) ...
GROUND_CLIMB_HOLD_S = 4.0
#: ... then decaying with this time constant (s)
GROUND_CLIMB_DECAY_S = 4.0
#: the vehicle has flown once it was this high (m), and is at rest within this of the ground
GROUND_CLIMB_FLOWN_M = 0.5
GROUND_CLIMB_REST_M = 0.005


@dataclasses.dataclass(frozen=True)
class Reported:
    """The vehicle's state as its sensors report it (NED, body FRD, SI units, radians)."""

    time: float
    position: np.ndarray
    velocity: np.ndarray
    quaternion: np.ndarray
    euler: np.ndarray
    rates: np.ndarray


class Reporting:
    """``sensors``: None (truth) or a :class:`sim.sensors.Sensors`, seeded ``seed``, read every
    ``physics_dt``: its noise and wander make the estimate ``xm`` the firmware flies on, its
    latency delays only what is reported (``xr``).  ``height_drift_mps`` and
    ``ground_climb_mps`` (validated by the caller) bend the reported position and velocity as
    :class:`sim.vehicle.SimVehicle` describes."""

    def __init__(self, sensors, seed, physics_dt, height_drift_mps, ground_climb_mps):
        self.height_drift_mps = height_drift_mps
        self.ground_climb_mps = ground_climb_mps
        self._flown = False
        self._rest_t = None  # when the vehicle, having flown, first came to rest on the ground
        self.sensors = sensors
        self.estimate = self.report = None
        if sensors is not None:
            # the firmware flies on the noisy estimate at once; the latency is the report path's
            self.estimate = Sensors(noise=sensors.noise, seed=seed, wander=sensors.wander,
                                    wander_corner_hz=sensors.wander_corner_hz, dt=physics_dt)
            if sensors.latency_s > 0.0:
                self.report = Sensors(latency_s=sensors.latency_s)
        self.xm = self.xr = None  # the estimate and the report, once measured
        #: the tick the estimate was last read at (a compiled loop that reads it sets this)
        self.measured_tick = None
        self._estimate_outside = False

    def firmware_input(self, ks):
        """The state the firmware flies on: the estimate, or the truth without sensors."""
        return self.xm if self.sensors is not None else ks.x

    def measure(self, ks):
        """The sensor model's reading of the state of this tick (once per tick)."""
        if self.sensors is not None and self.measured_tick != ks.tick:
            self.measured_tick = ks.tick
            self.xm = self.estimate.measure(ks.time, ks.x)
            self.xr = self.xm if self.report is None else self.report.measure(ks.time, self.xm)

    def kernel_sensors(self, ks, ticks):
        """(xm, noise, sigmas): :meth:`sim.vehicle.SimVehicle.kernel_sensors`."""
        if self.estimate is None or not self.estimate.active:
            return ks.x, np.zeros((0, NNOISE)), np.zeros(4)
        self.measure(ks)
        self._estimate_outside = True  # ran() takes the estimate as of its tick
        return self.xm, self.estimate.draws(ticks), self.estimate.sigmas()

    def ran(self, ks):
        """A caller ran the kernels up to ``ks.tick`` itself (:meth:`kernel_sensors`)."""
        if self._estimate_outside:  # kernel_sensors' estimate was read of every step
            self.measured_tick = ks.tick
            self.xr = self.xm if self.report is None else self.report.measure(ks.time, self.xm)

    def reported(self, ks):
        """:meth:`sim.vehicle.SimVehicle.reported` of the vehicle whose state is ``ks``."""
        y = self.xr if self.sensors is not None else ks.x
        q = y[phys.IX_Q:phys.IX_Q + 4].copy()
        e = np.empty(3)
        quat_to_euler(q, e)
        pos = y[0:3].copy()
        if self.height_drift_mps:
            # a height estimate that drifts (a barometer's): it reads higher by this much each
            # second; the vehicle's own controllers fly on the truth or their estimate as before
            pos[2] -= self.height_drift_mps * ks.time
        vel = y[3:6].copy()
        if self.ground_climb_mps:
            self._ground_climb(ks, pos, vel)
        return Reported(ks.time, pos, vel, q, e,
                        y[phys.IX_W:phys.IX_W + 3].copy())

    def _ground_climb(self, ks, pos, vel):
        """``ground_climb_mps``: from the first rest on the ground after a flight the estimate
        reads a climb (up: NED z falling) of that speed, held GROUND_CLIMB_HOLD_S, then dying
        away in GROUND_CLIMB_DECAY_S; the height it gained stays.  The truth, and the vehicle's
        own controllers, are untouched.  Judged on the true state each time the state is read."""
        z = float(ks.x[2])
        if z < -GROUND_CLIMB_FLOWN_M:
            self._flown = True
        if self._flown and self._rest_t is None and z >= -GROUND_CLIMB_REST_M:
            self._rest_t = ks.time
        if self._rest_t is None:
            return
        a, hold, tau = ks.time - self._rest_t, GROUND_CLIMB_HOLD_S, GROUND_CLIMB_DECAY_S
        v = self.ground_climb_mps
        if a <= hold:
            rise, speed = v * a, v
        else:
            e = math.exp(-(a - hold) / tau)
            rise, speed = v * (hold + tau * (1.0 - e)), v * e
        pos[2] -= rise
        vel[2] -= speed
