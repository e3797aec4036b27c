"""Many bundled vehicles in one process: `mavadrc sitl --count N`.

:class:`FleetServer` serves N :class:`sim.server.SitlServer` instances (each with its own
autopilot and personality state, parameters, streams, links, ports and system id) from one
select loop on the wall clock, and steps their vehicles together.

What :meth:`sim.vehicle.SimVehicle.step` does for one vehicle is, beyond the compiled kernel
(:func:`sim.vehicle.advance`): sample a wind object or a packed wind every physics step, run a
sensor model every physics step, and at each position-loop tick the flight-mode logic (a landing
that ends, automatic disarming) and, in the navigator's modes (position, takeoff, hold, land),
the autopilot's own position controller.  A vehicle flying attitude setpoints (offboard, or
GUIDED's angle control) or idle, in calm air and without a sensor model, does none of that:
its step is the kernel alone.  Those vehicles are stepped together by one compiled call over
their rows (:func:`advance_rows`, the arithmetic of :func:`sim.vehicle.advance` row by row);
every other vehicle steps on its own.  Each vehicle's kernel arrays are rows of the fleet's
arrays (the vehicle keeps views of them), so nothing is copied between the two paths, and
every vehicle's flight is the one a single :class:`~sim.server.SitlServer` gives for the same
seed and inputs, bit for bit.

The batch kernel is serial: the fleet's cost is its Python part (autopilot supervision and
telemetry per vehicle), which holds the interpreter whatever the kernel's threads do.
"""

import math
import selectors
import time

import numpy as np

from mavadrc.control.jit import jit

from .firmware import position as PL
from .vehicle import advance

#: the kernel arrays of a SimVehicle (its :class:`sim.kernel_state.KernelState`) that become
#: rows of the fleet's arrays
ROW_ARRAYS = ("x", "fs", "S", "W", "sp", "omega", "wk", "v_wind", "f_ext", "tau_ext")
#: the arrays every vehicle of a fleet must share (same vehicle, same firmware settings)
SHARED = (("fw", "fp"), ("fw", "P"), ("fw", "mx"), ("kernel", "pv"))


@jit
def advance_rows(rows, X, FS, fp, S, P, W, mx, SP, OMEGA, WK, pv, V, F, T, dt, n, tick, att_div,
                 pos_div, pos_dt):
    """:func:`sim.vehicle.advance` for the vehicles ``rows`` (indices into the arrays), n
    physics steps each from ``tick``."""
    for j in range(rows.shape[0]):
        i = rows[j]
        advance(X[i], X[i], FS[i], fp, S[i], P, W[i], mx, SP[i], OMEGA[i], WK[i], pv, V[i], F[i],
                T[i], dt, n, tick, att_div, pos_div, pos_dt)


def _shared(vehicle, owner, name):
    return getattr(getattr(vehicle, owner), name)


class VehicleRows:
    """The kernel arrays of ``vehicles`` (:class:`sim.vehicle.SimVehicle`, all of one vehicle
    and firmware) as rows of fleet-wide arrays; :meth:`step` advances them all by dt, the
    batchable ones in one compiled call."""

    def __init__(self, vehicles):
        self.vehicles = list(vehicles)
        first = self.vehicles[0]
        for v in self.vehicles[1:]:
            for owner, name in SHARED:
                if not np.array_equal(_shared(v, owner, name), _shared(first, owner, name)):
                    raise ValueError("a fleet's vehicles must share one vehicle model and "
                                     "firmware settings")
            if (v.physics_dt, v.fw.att_div, v.fw.pos_div) != (first.physics_dt, first.fw.att_div,
                                                              first.fw.pos_div):
                raise ValueError("a fleet's vehicles must share their loop rates")
        n = len(self.vehicles)
        self.arrays = []
        for name in ROW_ARRAYS:
            a = getattr(first.kernel, name)
            big = np.empty((n,) + a.shape)
            for i, v in enumerate(self.vehicles):
                big[i] = getattr(v.kernel, name)
                setattr(v.kernel, name, big[i])
            self.arrays.append(big)
        self._fw = first.fw
        self._pv = first.kernel.pv
        self.batched = 0  # vehicle-steps taken by the batch path (for tests and benchmarks)

    @staticmethod
    def batchable(v):
        """The vehicle's next step is the kernel alone: attitude setpoints or idle, no wind,
        no sensor model, and no landing or automatic disarm that the mode logic could end."""
        return (v.sensors is None and v.wind is None and v.mode not in PL.Navigator.MODES
                and (v.modes.landed_at is None or v.auto_disarm_s is None or not v.armed))

    def step(self, dt):
        """Advance every vehicle by dt (as :meth:`sim.vehicle.SimVehicle.step` does)."""
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be >= 0 (got {dt!r})")
        groups = {}
        fw = self._fw
        for i, v in enumerate(self.vehicles):
            # a vehicle whose THR_MDL_FAC / MOT_THST_EXPO was set apart from the first's has
            # firmware parameters of its own: it steps on them, alone
            if not self.batchable(v) or v.fw.thrust_model_factor != fw.thrust_model_factor:
                v.step(dt)
                continue
            ks = v.kernel
            ks.target_time += float(dt)
            end = int(math.floor(ks.target_time / v.physics_dt + 1e-6))
            if end > ks.tick:
                groups.setdefault((ks.tick, end), []).append(i)
        X, FS, S, W, SP, OMEGA, WK, V, F, T = self.arrays
        for (tick, end), rows in groups.items():
            advance_rows(np.array(rows, dtype=np.int64), X, FS, fw.fp, S, fw.P, W, fw.mx, SP,
                         OMEGA, WK, self._pv, V, F, T, self.vehicles[rows[0]].physics_dt,
                         end - tick, tick, fw.att_div, fw.pos_div, fw.pos_dt)
            for i in rows:
                self.vehicles[i].kernel.tick = end
            self.batched += len(rows) * (end - tick)


class FleetServer:
    """Serves ``servers`` (:class:`sim.server.SitlServer`, not started, real time, one vehicle
    model) from one loop, advancing every vehicle by ``tick`` seconds of wall time."""

    def __init__(self, servers, tick=0.002):
        self.servers = list(servers)
        if not self.servers:
            raise ValueError("a fleet needs at least one vehicle")
        if any(s.lockstep for s in self.servers):
            raise ValueError("a fleet runs in real time only")
        self.tick = float(tick)
        self.rows = VehicleRows(s.vehicle for s in self.servers)
        self._running = False
        self.overruns = 0

    @property
    def time(self):
        return self.servers[0].time

    def start(self):
        """Run the loop in a thread (tests); :meth:`stop` ends it."""
        import threading

        self._running = True
        self._thread = threading.Thread(target=self._loop, name="mavadrc-sitl-fleet",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._running = False
        if getattr(self, "_thread", None) is not None:
            self._thread.join(timeout=5.0)
        self.close()

    def stop_soon(self):
        self._running = False

    def close(self):
        for s in self.servers:
            s._close()

    def run(self):
        self._running = True
        try:
            self._loop()
        finally:
            self.close()

    def _loop(self):
        sel = selectors.DefaultSelector()  # epoll on Linux: no limit of 1024 descriptors
        for s in self.servers:
            for link in s.links:
                sel.register(link.sock, selectors.EVENT_READ, (s, link))
        try:
            self._serve(sel)
        finally:
            sel.close()

    def _serve(self, sel):
        wall_tick = self.tick / self.servers[0].clock_rate  # the vehicles share the options
        next_tick = time.monotonic()
        while self._running:
            timeout = max(0.0, next_tick - time.monotonic())
            for key, _ in sel.select(timeout):
                s, link = key.data
                s.receiver.drain(link)
            now = time.monotonic()
            if now >= next_tick:
                self.advance(self.tick)
                next_tick += wall_tick
                if now - next_tick > 0.25:  # fell far behind (machine busy): resynchronise
                    self.overruns += 1
                    for s in self.servers:
                        s.stats.overruns += 1
                    next_tick = now

    def advance(self, dt):
        """What :meth:`sim.server.SitlServer.advance` does, for every vehicle, the vehicles
        stepped together."""
        for s in self.servers:
            s.autopilot.before_step(dt)
        self.rows.step(dt)
        for s in self.servers:
            s.autopilot.after_step(dt)
            s._send_due()
