"""The in-process fast path: a mission flown on the bundled vehicle's kernels, no sockets.

This is what ``mavadrc compare`` runs by default.  It is the lockstep MAVLink flight of
:mod:`mavadrc.flight` against ``python -m sim --lockstep``, with the wire taken out:

* the same :class:`sim.vehicle.SimVehicle` (same vehicle file, wind, seed and firmware);
* the same timeline: on the ground until armed, the thrust spooled up
  (:func:`mavadrc.flight.spool_thrust`), the mission clock started at
  :data:`MISSION_START` s of vehicle time (``Flight(start_at=...)`` on the MAVLink side), or
  at the sample that shows the vehicle lifting off, if it does during the spool-up;
* the same ground rules: until the vehicle has lifted off the observers hold no disturbance
  estimate, and the heading turns from the vehicle's to the mission's at
  :data:`mavadrc.flight.YAW_RATE`;
* one control step per LOCAL_POSITION_NED sample, the reference read as the flight reads it, and
  every value that crosses the wire rounded to the float32 MAVLink carries (position, velocity,
  the setpoint quaternion and thrust, the millisecond boot time);
* the same position controller (:func:`mavadrc.control.position.position_update`) and the same
  safety checks (geofence, altitude, speed: the run stops there, as the flight hands over to the
  autopilot's land mode).

The ground phase and the mission each run in one compiled call:
controller, wind (:func:`sim.wind.pack_wind`), firmware and physics.  ``mavadrc compare --via
mavlink`` flies the same runs over MAVLink, and a test holds the two paths to 1 mm RMS.

The ``oracle`` controller exists only here: the PD law with the simulator's true disturbance
acceleration fed forward, the floor any controller with the same feedback gains could reach.
"""

import functools
import math
from dataclasses import dataclass

import numpy as np

from sim import physics as phys
from sim.firmware import attitude as A
from sim.params import load_vehicle
from sim.vehicle import SimVehicle, advance_wind_into
from sim.wind import WIND_SCRATCH

from .control import geometry as G
from .control import kernels as K
from .control._jit import jit
from .control.position import position_hold_disturbance, position_update
from .control.rotations import quat_to_euler, wrap_pi
from .flight import YAW_RATE, make_controller
from .ground import LIFTOFF_CLIMB, LIFTOFF_HEIGHT, spool_thrust

#: s of vehicle time at which every run's mission clock starts: after the MAVLink flight has
#: measured the sample rate (1 s), armed, and waited out PX4's COM_SPOOLUP_TIME (1 s)
MISSION_START = 3.0
ARM_AT = 1.01  # s: where the lockstep MAVLink flight arms (after measuring the rate for 1 s)
# on the ground, disarmed or idle, nothing differs by the time the spool-up starts)

# columns of the per-step log
L_T = 0
L_REF = 1  # 3
L_POS = 4  # 3
L_VEL = 7  # 3
L_Q = 10  # 4
L_THRUST = 14
L_ACC_CMD = 15  # 3
L_ACC = 18  # 3
L_Z3 = 21  # 3: observer disturbance estimates
L_DIST = 24  # 3: the simulator's true disturbance acceleration
L_WRENCH = 27  # 4: achieved [T, tau_x, tau_y, tau_z] (the thesis's U1..U4)
L_YAW = 31
L_REF_YAW = 32
L_REF_ACC = 33  # 3
NLOG = 36

STATUS_OK = 0
STATUS_BREACH = 1
STATUS_NONFINITE = 2
STATUS_NAMES = {STATUS_OK: None, STATUS_BREACH: "safety limit breached",
                STATUS_NONFINITE: "the controller produced a non-finite setpoint"}


def f32(x):
    """What a float32 MAVLink field carries of x (as float64)."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


@jit
def _f32(v):
    return float(np.float32(v))


@jit
def _attitude_setpoint(sp, q0, q1, q2, q3, thrust):
    """What the vehicle does with SET_ATTITUDE_TARGET (attitude + thrust, rates ignored)."""
    nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    sp[A.SP_Q] = q0 / nq
    sp[A.SP_Q + 1] = q1 / nq
    sp[A.SP_Q + 2] = q2 / nq
    sp[A.SP_Q + 3] = q3 / nq
    sp[A.SP_ATT_VALID] = 1.0
    for i in range(3):
        sp[A.SP_RATE_VALID + i] = 0.0
        sp[A.SP_RATES + i] = 0.0
    sp[A.SP_THRUST] = min(max(thrust, 0.0), 1.0)


#: the flight's ground rules, passed to the compiled loops (a constant read from another
#: module would be frozen into numba's cache of this one)
GROUND_RULES = np.array([LIFTOFF_HEIGHT, LIFTOFF_CLIMB, YAW_RATE])


@jit
def _lifted(pos, vel, origin, rules):
    """:func:`mavadrc.flight.lifted_off` on a float32 sample."""
    return origin[2] - pos[2] >= rules[0] or vel[2] < -rules[1]


@jit
def closed_loop(x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind, f_ext,
                tau_ext, dt, tick0, att_div, pos_div, pos_dt, per, times, Sc, Pc, Mc, INc, refs,
                oracle, limits, origin, rules, lifted, yaw_offset, log):
    """Fly the mission steps of ``refs`` (N, 10: pos, vel, acc, yaw) from tick ``tick0``.

    Each step: sample (float32), control over the interval since the last sample (``times``:
    sample times from the controller's start at t = 0), setpoint (float32), ``per`` physics
    steps.  ``limits`` = [north lo, hi, east lo, hi, altitude lo, hi, max speed] relative to
    ``origin``.  Until ``lifted`` the observers hold no disturbance; the reference's heading is
    offset by ``yaw_offset``, turned to 0 at ``rules[2]`` (:data:`GROUND_RULES`).  Fills ``log`` row by row; returns (rows
    written, status).
    """
    pos = np.empty(3)
    vel = np.empty(3)
    rpos = np.empty(3)
    rvel = np.empty(3)
    racc = np.empty(3)
    dist = np.empty(3)
    out = np.zeros(G.NO + 3)
    e = np.empty(4)
    eul = np.empty(3)
    scratch = np.empty(WIND_SCRATCH)
    ws = np.empty((5, phys.NX))
    xdot = np.empty(phys.NX)
    tick = tick0
    for j in range(refs.shape[0]):
        for i in range(3):
            pos[i] = _f32(x[i])
            vel[i] = _f32(x[3 + i])
            rpos[i] = refs[j, i]
            rvel[i] = refs[j, 3 + i]
            racc[i] = refs[j, 6 + i]
        phys.disturbance_accel_into(x, omega, pv, v_wind, f_ext, tau_ext, dist, xdot)
        if oracle:
            for i in range(3):
                racc[i] -= dist[i]
        hc = times[j] - (times[j - 1] if j > 0 else 0.0)
        if yaw_offset != 0.0:
            yaw_offset -= max(-rules[2] * hc, min(rules[2] * hc, yaw_offset))
        yaw_ref = refs[j, 9] + yaw_offset
        ok = position_update(Sc, Pc, Mc, INc, pos, vel, rpos, rvel, racc, yaw_ref, out, hc)
        if not lifted:
            if _lifted(pos, vel, origin, rules):
                lifted = True
            else:
                position_hold_disturbance(Sc)
        row = log[j]
        row[L_T] = times[j]
        for i in range(3):
            row[L_REF + i] = rpos[i]
            row[L_POS + i] = pos[i]
            row[L_VEL + i] = vel[i]
            row[L_ACC_CMD + i] = out[G.NO + i]
            row[L_ACC + i] = out[G.O_ACC + i]
            row[L_Z3 + i] = Sc[i, K.S_Z3]
            row[L_DIST + i] = dist[i]
        for i in range(4):
            e[i] = x[phys.IX_Q + i]
            row[L_WRENCH + i] = fs[A.FS_WRENCH + i]
        quat_to_euler(e, eul)
        row[L_YAW] = eul[2]
        row[L_REF_YAW] = yaw_ref
        for i in range(3):
            row[L_REF_ACC + i] = refs[j, 6 + i]
        if not ok:
            return j + 1, STATUS_NONFINITE
        for i in range(4):
            e[i] = _f32(out[G.O_Q + i])
            row[L_Q + i] = e[i]
        thrust = _f32(out[G.O_THRUST])
        row[L_THRUST] = thrust
        # the flight's safety checks, on the sample, after logging it
        north = pos[0] - origin[0]
        east = pos[1] - origin[1]
        alt = -(pos[2] - origin[2])
        speed = math.sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2])
        if not (limits[0] <= north <= limits[1] and limits[2] <= east <= limits[3]) or \
                alt > limits[5] or alt < limits[4] or speed > limits[6]:
            return j + 1, STATUS_BREACH
        _attitude_setpoint(sp, e[0], e[1], e[2], e[3], thrust)
        advance_wind_into(x, x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate,
                          eta[(tick - tick0):(tick - tick0) + per], v_wind, f_ext, tau_ext, dt,
                          per, tick, att_div, pos_div, pos_dt, scratch, ws)
        tick += per
    return refs.shape[0], STATUS_OK


@jit
def spool(x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind, f_ext, tau_ext,
          dt, tick0, att_div, pos_div, pos_dt, per, thrusts, origin, rules, start):
    """The flight's ground phase, one setpoint per control period: level at the measured
    heading (float32, as ATTITUDE and SET_ATTITUDE_TARGET carry it) with thrust ``thrusts[j]``
    (idle, then the spool-up ramp), then ``per`` physics steps.

    Ends after the sample that shows the vehicle lifting off (relative to ``origin``), or after
    the last thrust; ``start`` gets that sample's float32 position and heading (where the
    mission starts).  Returns the number of setpoints sent."""
    e = np.empty(4)
    eul = np.empty(3)
    pos = np.empty(3)
    vel = np.empty(3)
    scratch = np.empty(WIND_SCRATCH)
    ws = np.empty((5, phys.NX))
    tick = tick0
    n = thrusts.shape[0]
    for j in range(n):
        for i in range(3):
            pos[i] = _f32(x[i])
            vel[i] = _f32(x[3 + i])
        for i in range(4):
            e[i] = x[phys.IX_Q + i]
        quat_to_euler(e, eul)
        yaw = _f32(eul[2])
        last = j == n - 1 or _lifted(pos, vel, origin, rules)
        if last:
            for i in range(3):
                start[i] = pos[i]
            start[3] = yaw
        _attitude_setpoint(sp, _f32(math.cos(0.5 * yaw)), 0.0, 0.0, _f32(math.sin(0.5 * yaw)),
                           thrusts[j])
        advance_wind_into(x, x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate,
                          eta[(tick - tick0):(tick - tick0) + per], v_wind, f_ext, tau_ext, dt,
                          per, tick, att_div, pos_div, pos_dt, scratch, ws)
        tick += per
        if last:
            return j + 1
    return n


@dataclass
class InProcessRun:
    """The per-step log of one run (columns L_*), its phases and how it ended."""

    log: np.ndarray
    phases: list  # [(mission time, segment name)]
    duration: float  # the trajectory's duration (s)
    status: int
    mission_start: float  # vehicle time of the mission's t = 0
    hover_thrust: float  # the normalized hover thrust the controller was given

    @property
    def aborted(self):
        return STATUS_NAMES[self.status]


def boot_seconds(tick, physics_dt):
    """The vehicle time a LOCAL_POSITION_NED sample at ``tick`` carries (ms resolution)."""
    ms = np.round(np.asarray(tick, dtype=np.int64) * physics_dt * 1000.0).astype(np.int64)
    return (ms & 0xFFFFFFFF) / 1000.0


def fly_inprocess(mission, kind=None, seed=None, wind=None, vehicle_options=None):
    """Fly ``mission`` in process; returns an :class:`InProcessRun`.

    ``kind``: the position controller ('pd', 'ladrc', 'adrc', 'pid', or 'oracle': PD with the
    true disturbance fed forward); ``seed``/``wind`` override the mission's (as ``mavadrc fly``'s
    options do).  ``vehicle_options``: extra :class:`SimVehicle` keywords.
    """
    if mission.noise:
        raise ValueError("sensor noise is modelled by the bundled vehicle's server only: fly "
                         "this mission over MAVLink")
    kind = kind or mission.controller.kind
    oracle = kind == "oracle"
    spec = mission.controller
    seed = mission.seed if seed is None else seed
    wind = mission.wind if wind is None else wind
    v = SimVehicle(_vehicle_params(mission.vehicle or "crazyflie"), wind=wind, seed=seed,
                   attitude_controller=mission.attitude_controller,
                   **dict(vehicle_options or {}))
    h = 1.0 / spec.rate_hz
    dt = v.physics_dt
    per = int(round(h / dt))
    if abs(per * dt - h) > 1e-9 * h:
        raise ValueError(f"controller rate {spec.rate_hz:g} Hz must divide the physics rate "
                         f"{1.0 / dt:g} Hz for the in-process path")
    hover = mission.hover_thrust if mission.hover_thrust is not None else v.hover_thrust
    ctrl = make_controller(spec, hover_thrust=hover, kind="pd" if oracle else kind,
                           vehicle=v.params, attitude_controller=mission.attitude_controller)
    # on the ground, disarmed, then armed at idle; thrust spooled up to MISSION_START
    v.step(round(ARM_AT / h) * h)
    r = v.reported()
    origin = f32(r.position)
    traj, phases = mission.build_trajectory(origin)
    v.arm()
    # idle and spool-up setpoints, one per control period, up to and including the sample at
    # MISSION_START (the flight resets its controller there and sends the last spool setpoint)
    state = v.kernel_state()
    packed, wind_out = v.kernel_wind()
    fw = v.fw
    timing = (fw.att_div, fw.pos_div, fw.pos_dt, per)
    tick0 = v.tick
    n_max = int(math.ceil((MISSION_START - ARM_AT) / h)) + 3
    ts_pre = boot_seconds(tick0 + per * np.arange(n_max), dt)
    n_pre = int(np.argmax(ts_pre >= MISSION_START - 1e-9))
    t0 = float(ts_pre[n_pre])
    thrusts = f32(spool_thrust(ts_pre[:n_pre + 1], MISSION_START, hover))
    eta = packed.normals((n_pre + 1) * per)
    start = np.zeros(4)
    sent = spool(*state, packed.params, packed.state, eta, *wind_out, dt, tick0, *timing, thrusts,
                 origin, GROUND_RULES, start)
    ctrl.reset(start[:3])
    t0 = float(ts_pre[sent - 1])
    v.ran(sent * per)
    # the mission steps: sample times as the wire carries them, the reference as the flight
    # reads it (the grid of control periods, or an exact sample off the grid)
    n_max = int(math.ceil((traj.duration + 2 * h) / h)) + 2
    times = boot_seconds(v.tick + per * np.arange(n_max), dt) - t0
    done = np.nonzero(times >= traj.duration)[0]
    n = int(done[0]) + 1 if done.size else n_max
    times = times[:n]
    ref = _references(traj, times, h)
    eta = packed.normals(n * per)
    log = np.full((n, NLOG), math.nan)
    sf = mission.safety
    limits = np.array([*sf.geofence_north, *sf.geofence_east, sf.altitude_min, sf.altitude_max,
                       sf.max_speed], dtype=float)
    Pc, Mc = ctrl.params
    yaw_offset = wrap_pi(start[3] - float(traj.sample(0.0).yaw))
    rows, status = closed_loop(*state, packed.params, packed.state, eta, *wind_out, dt, v.tick,
                               *timing, times, ctrl._S, Pc, Mc, ctrl._IN, ref, oracle, limits,
                               origin, GROUND_RULES, False, yaw_offset, log)
    v.ran((rows if status == STATUS_OK else rows - 1) * per)
    return InProcessRun(log[:rows], phases, traj.duration, int(status), t0, hover)


@functools.lru_cache(maxsize=16)
def _vehicle_params(name):
    """A vehicle file read once per process (runs of an experiment share a few vehicles)."""
    return load_vehicle(name)


def _references(traj, times, h):
    """(N, 10) reference rows [pos, vel, acc, yaw] the flight would use at mission times."""
    k = np.round(times / h).astype(np.int64)
    grid_n = int(traj.duration / h) + 2
    on_grid = (np.abs(times - k * h) < 1e-7) & (k < grid_n) & (k >= 0)
    pos, vel, acc, yaw, _ = traj.sample_many(np.where(on_grid, k * h, times))
    return np.column_stack([pos, vel, acc, yaw])
