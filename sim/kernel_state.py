"""One vehicle's state as the compiled kernels step it (:func:`sim.vehicle.advance` and its kin):
the arrays they take, and the physics step they are at.

:class:`sim.vehicle.SimVehicle` holds one and hands it to its flight modes
(:class:`sim.flight_modes.FlightModes`) and its sensor side (:class:`sim.reporting.Reporting`).
They read the arrays through it at each call and keep none of their own, so a fleet
(:mod:`sim.fleet`) may swap any of them for a row of a fleet-wide array.
"""

import numpy as np

from . import physics as phys
from .firmware import attitude as A
from .wind import WIND_SCRATCH


class KernelState:
    """The true state ``x``, the firmware's state ``fs``, observer states ``S``/``W``, the
    attitude setpoint ``sp``, rotor commands ``omega``, the firmware's scratch ``wk``, the
    packed vehicle ``pv``, the wind's outputs ``v_wind``/``f_ext``/``tau_ext`` and the kernels'
    work arrays (``scratch``, ``ws``); ``tick`` physics steps of ``physics_dt`` taken, and the
    time the caller asked to reach (``target_time``).

    A vehicle at ``position`` (NED; above the ground, z < 0, it starts flying with its rotors at
    hover speed) heading ``yaw`` (rad), for firmware whose parameters are ``fw``
    (:class:`sim.vehicle.Firmware`).
    """

    __slots__ = ("x", "fs", "S", "W", "sp", "omega", "wk", "pv", "v_wind", "f_ext", "tau_ext",
                 "scratch", "ws", "physics_dt", "tick", "target_time")

    def __init__(self, vp, fw, position, yaw, physics_dt):
        self.pv = vp.pack()
        pos = np.asarray(position, dtype=float)
        airborne = pos[2] < 0.0
        self.x = phys.initial_state(pos, yaw, vp.hover_omega if airborne else 0.0)
        self.fs = np.zeros(A.NFS)
        self.fs[A.FS_LANDED] = 0.0 if airborne else 1.0
        self.fs[A.FS_OMEGA:A.FS_OMEGA + 4] = self.x[phys.IX_ROT:phys.IX_ROT + 4]
        self.S = np.zeros((3, fw.P.shape[1]))
        self.W = np.zeros(2)
        self.sp = np.zeros(A.NSP)
        self.sp[A.SP_Q:A.SP_Q + 4] = self.x[phys.IX_Q:phys.IX_Q + 4]
        self.sp[A.SP_ATT_VALID] = 1.0
        self.omega = np.zeros(4)
        self.wk = np.zeros(A.NWK)
        self.scratch = np.empty(WIND_SCRATCH)
        self.ws = np.empty((5, phys.NX))
        self.v_wind = np.zeros(3)
        self.f_ext = np.zeros(3)
        self.tau_ext = np.zeros(3)
        self.physics_dt = physics_dt
        self.tick = 0
        self.target_time = 0.0

    @property
    def time(self):
        """Seconds since boot (simulated)."""
        return self.tick * self.physics_dt

    @property
    def armed(self):
        return self.fs[A.FS_ARMED] != 0.0

    @property
    def landed(self):
        return self.fs[A.FS_LANDED] != 0.0

    def firmware_arrays(self, fw):
        """The arrays :func:`sim.vehicle.advance_wind` steps, in its argument order (x .. pv),
        with the firmware parameters of ``fw``."""
        return (self.x, self.fs, fw.fp, self.S, fw.P, self.W, fw.mx, self.sp, self.omega,
                self.wk, self.pv)

    def set_attitude(self, q, thrust):
        """Fly attitude ``q`` at normalized ``thrust``, no body-rate feed-forward."""
        sp = self.sp
        sp[A.SP_Q:A.SP_Q + 4] = q
        sp[A.SP_THRUST] = thrust
        sp[A.SP_ATT_VALID] = 1.0
        sp[A.SP_RATE_VALID:A.SP_RATE_VALID + 3] = 0.0
