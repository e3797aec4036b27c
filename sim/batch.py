"""Many independent vehicles stepped at once: attitude setpoints in, states out.

:class:`BatchVehicles` holds N copies of one vehicle (same parameters and firmware settings),
each with its own state, attitude + thrust setpoint, firmware state and wind.  One compiled call
advances all of them in parallel; every vehicle goes through exactly the arithmetic of a
:class:`sim.vehicle.SimVehicle` in attitude mode (:func:`sim.vehicle.advance`), so a batch run
equals N single runs with the same seeds.

Wind models are Python objects sampled once per physics step and vehicle, so a windy batch is
bound by them; a calm batch runs whole position-loop periods in one call.
"""

import math

import numpy as np
from numba import njit, prange

from . import physics as phys
from .firmware import attitude as A
from .flight_modes import (IGNORE_ATTITUDE, IGNORE_PITCH_RATE, IGNORE_ROLL_RATE, IGNORE_THRUST,
                           IGNORE_YAW_RATE)
from .vehicle import Firmware, advance, child_seeds, resolve_vehicle, resolve_wind
from .wind import Wind


@njit(cache=True, parallel=True, nogil=True)
def advance_batch(X, FS, fp, S, P, W, mx, SP, OMEGA, WK, pv, V, F, T, dt, n, tick, att_div,
                  pos_div, pos_dt):
    for i in prange(X.shape[0]):
        advance(X[i], X[i], FS[i], fp, S[i], P, W[i], mx, SP[i], OMEGA[i], WK[i], pv, V[i], F[i],
                T[i], dt, n, tick, att_div, pos_div, pos_dt)


class BatchVehicles:
    """N vehicles in attitude mode.

    ``BatchVehicles(1000, "crazyflie", positions=(0, 0, -5))`` starts 1000 hovering Crazyflies.
    ``seeds``: one per vehicle (default 0..N-1), used as ``SimVehicle(seed=...)`` uses its seed.
    ``wind``: None, one wind spec for all (each vehicle gets its own instance and seed) or a list
    of N specs / Wind objects.  ``positions``: (3,) or (N, 3) start positions.  Other keywords as
    :class:`sim.vehicle.SimVehicle`.
    """

    def __init__(self, n, vehicle="crazyflie", wind=None, seeds=None, attitude_controller="px4",
                 physics_dt=0.001, attitude_rate_hz=None, position_rate_hz=100.0,
                 max_thrust=None, hover_thrust=None, airmode=True, attitude_gains=None,
                 positions=(0.0, 0.0, 0.0), yaw=0.0):
        n = int(n)
        if n < 1:
            raise ValueError(f"need at least one vehicle (got {n})")
        self.params = resolve_vehicle(vehicle)
        vp = self.params
        self.physics_dt = float(physics_dt)
        self.seeds = list(range(n)) if seeds is None else [int(s) for s in seeds]
        if len(self.seeds) != n:
            raise ValueError(f"need {n} seeds (got {len(self.seeds)})")
        if isinstance(wind, (list, tuple)):
            specs = list(wind)
        elif isinstance(wind, Wind) and n > 1:
            raise ValueError("one Wind object cannot drive several vehicles: pass a list of N "
                             "Wind objects, or a config name/path/mapping")
        else:
            specs = [wind] * n
        if len(specs) != n:
            raise ValueError(f"need {n} wind models (got {len(specs)})")
        self.winds = [resolve_wind(spec, child_seeds(seed)[0])
                      for spec, seed in zip(specs, self.seeds)]
        self._windy = any(w is not None for w in self.winds)
        self.fw = Firmware(vp, attitude_controller=attitude_controller,
                           physics_dt=self.physics_dt, attitude_rate_hz=attitude_rate_hz,
                           position_rate_hz=position_rate_hz, max_thrust=max_thrust,
                           hover_thrust=hover_thrust, airmode=airmode,
                           attitude_gains=attitude_gains)
        self.n = n
        self._pv = vp.pack()
        pos = np.broadcast_to(np.asarray(positions, dtype=float), (n, 3))
        yaws = np.broadcast_to(np.asarray(yaw, dtype=float), (n,))
        self._X = np.empty((n, phys.NX))
        self._FS = np.zeros((n, A.NFS))
        for i in range(n):
            airborne = pos[i, 2] < 0.0
            self._X[i] = phys.initial_state(pos[i], float(yaws[i]),
                                            vp.hover_omega if airborne else 0.0)
            self._FS[i, A.FS_LANDED] = 0.0 if airborne else 1.0
        self._FS[:, A.FS_OMEGA:A.FS_OMEGA + 4] = self._X[:, phys.IX_ROT:phys.IX_ROT + 4]
        self._S = np.zeros((n, 3, self.fw.P.shape[1]))
        self._W = np.zeros((n, 2))
        self._SP = np.zeros((n, A.NSP))
        self._SP[:, A.SP_Q:A.SP_Q + 4] = self._X[:, phys.IX_Q:phys.IX_Q + 4]
        self._SP[:, A.SP_ATT_VALID] = 1.0
        self._OMEGA = np.zeros((n, 4))
        self._WK = np.zeros((n, A.NWK))
        self._V = np.zeros((n, 3))
        self._F = np.zeros((n, 3))
        self._T = np.zeros((n, 3))
        self._tick = 0
        self._target_time = 0.0

    # -- read-outs -------------------------------------------------------------------------------
    @property
    def time(self):
        return self._tick * self.physics_dt

    @property
    def states(self):
        """(N, 17) copy of the true states."""
        return self._X.copy()

    @property
    def armed(self):
        return self._FS[:, A.FS_ARMED] != 0.0

    @property
    def landed(self):
        return self._FS[:, A.FS_LANDED] != 0.0

    @property
    def hover_thrust(self):
        return self.fw.hover_thrust

    @property
    def wrench(self):
        """(N, 4) [T, tau_x, tau_y, tau_z] the mixers achieved in the last firmware step."""
        return self._FS[:, A.FS_WRENCH:A.FS_WRENCH + 4].copy()

    # -- commands --------------------------------------------------------------------------------
    def arm(self, which=None):
        """Arm all vehicles, or those selected by ``which`` (index array or boolean mask)."""
        sel = slice(None) if which is None else which
        self._FS[sel, A.FS_ARMED] = 1.0

    def disarm(self, which=None):
        sel = slice(None) if which is None else which
        self._FS[sel, A.FS_ARMED] = 0.0

    def set_attitude_targets(self, q, thrust, body_rates=None, type_mask=0):
        """Per-vehicle setpoints: q (N, 4) or (4,), thrust (N,) or scalar, body_rates (N, 3).

        ``type_mask`` as :meth:`sim.vehicle.SimVehicle.set_attitude_target`, one for all.
        """
        n = self.n
        sp = self._SP
        mask = int(type_mask)
        if not mask & IGNORE_ATTITUDE:
            Q = np.broadcast_to(np.asarray(q, dtype=float), (n, 4))
            norm = np.linalg.norm(Q, axis=1)
            if not (np.all(np.isfinite(Q)) and np.all(norm > 1e-6)):
                raise ValueError("attitude quaternions must be finite and non-zero")
            sp[:, A.SP_Q:A.SP_Q + 4] = Q / norm[:, None]
        sp[:, A.SP_ATT_VALID] = 0.0 if mask & IGNORE_ATTITUDE else 1.0
        rates = None if body_rates is None else np.broadcast_to(
            np.asarray(body_rates, dtype=float), (n, 3))
        if rates is not None and not np.all(np.isfinite(rates)):
            raise ValueError("body rates must be finite")
        for i, bit in enumerate((IGNORE_ROLL_RATE, IGNORE_PITCH_RATE, IGNORE_YAW_RATE)):
            given = rates is not None and not mask & bit
            sp[:, A.SP_RATE_VALID + i] = 1.0 if given else 0.0
            sp[:, A.SP_RATES + i] = rates[:, i] if given else 0.0
        if not mask & IGNORE_THRUST:
            t = np.broadcast_to(np.asarray(thrust, dtype=float), (n,))
            if not np.all(np.isfinite(t)):
                raise ValueError("thrust must be finite")
            sp[:, A.SP_THRUST] = np.clip(t, 0.0, 1.0)

    # -- simulation ------------------------------------------------------------------------------
    def step(self, dt):
        """Advance every vehicle by dt seconds (a whole number of physics steps, rounded)."""
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be >= 0 (got {dt!r})")
        self._target_time += float(dt)
        end = int(math.floor(self._target_time / self.physics_dt + 1e-6))
        fw = self.fw
        while self._tick < end:
            tick = self._tick
            if self._windy:
                t = tick * self.physics_dt
                for i, w in enumerate(self.winds):
                    if w is not None:
                        v, f, tau = w.step(t, self.physics_dt, self._X[i, 0:3], self._X[i, 3:6])
                        self._V[i] = v
                        self._F[i] = f
                        self._T[i] = tau
                n = 1
            else:
                n = end - tick
            advance_batch(self._X, self._FS, fw.fp, self._S, fw.P, self._W, fw.mx, self._SP,
                          self._OMEGA, self._WK, self._pv, self._V, self._F, self._T,
                          self.physics_dt, n, tick, fw.att_div, fw.pos_div, fw.pos_dt)
            self._tick += n
