"""The in-process fast path: a mission flown on the bundled vehicle's kernels, no sockets.

This is what ``mavadrc compare`` runs by default.  It is the lockstep MAVLink flight of
:mod:`mavadrc.flight.flight` against ``python -m sim --lockstep``, with the wire taken out:

* the same :class:`sim.vehicle.SimVehicle` (same vehicle file, wind, seed and firmware), changed
  as the mission's ``sim:`` section says (:func:`mavadrc.mission.config.vehicle_flown`) while what the
  companion is told (the hover thrust, ``input_lag: auto``) comes from the file;
* the same timeline: on the ground until armed, the thrust spooled up
  (:func:`mavadrc.mission.takeoff.spool_thrust`), the mission clock started at
  :data:`MISSION_START` s of vehicle time (``Flight(start_at=...)`` on the MAVLink side), or
  at the sample that shows the vehicle lifting off, if it does during the spool-up;
* the same ground rules: until the vehicle has lifted off the observers hold no disturbance
  estimate, and the heading turns from the vehicle's to the mission's at
  :data:`mavadrc.mission.takeoff.YAW_RATE`;
* one control step per LOCAL_POSITION_NED sample, the reference read as the flight reads it, and
  every value that crosses the wire rounded to the float32 MAVLink carries (position, velocity,
  the setpoint quaternion and thrust, the millisecond boot time);
* the same position controller (:func:`mavadrc.control.position.position_update`) and the same
  safety checks (geofence, altitude, speed: the run stops there, as the flight hands over to the
  autopilot's land mode);
* the same sensors: with ``sim: {noise: true}`` the server's noise (``--noise``,
  :data:`sim.sensors.TYPICAL_NOISE`) drawn from the vehicle's own stream in the same order, the
  firmware flying on the noisy estimate and the samples taken of it; the sensor latency as whole
  control periods of delay on the samples (``--latency``).

The ground phase and the mission each run in one compiled call:
controller, wind (:func:`sim.wind.pack_wind`), sensor noise, firmware and physics (a period in
one call of the firmware's loop without noise, step by step with it).  ``mavadrc compare --via
mavlink`` flies the same runs over MAVLink, and a test holds the two paths to 1 mm RMS.

The ``oracle`` controller exists only here: the PD law with the simulator's true disturbance
acceleration fed forward, the floor any controller with the same feedback gains could reach.
"""

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from mavadrc.control import geometry as G
from mavadrc.control import kernels as K
from mavadrc.control.jit import jit
from mavadrc.control.position import position_hold_disturbance, position_update
from mavadrc.control.rotations import quat_to_euler, wrap_pi
from mavadrc.design.gains import make_controller
from mavadrc.mission.takeoff import GROUND_RULES, lifted_f32, spool_thrust
from sim import physics as phys
from sim.firmware import attitude as A
from sim.link_model import LINK_FROM, PeriodLink
from sim.params import load_vehicle
from sim.personality import personality
from sim.sensors import TYPICAL_NOISE
from sim.vehicle import SimVehicle, advance_wind_into, advance_wind_measured_into, vehicle_variant
from sim.wind import WIND_SCRATCH

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
L_AGE = 36  # the sample's age when the controller got it (s), compensated or not
L_ROLL = 37  # the vehicle's roll and pitch (its estimate, as ATTITUDE reports it) at the period
L_PITCH = 38
NLOG = 39

STATUS_OK = 0
STATUS_BREACH = 1
STATUS_NONFINITE = 2
STATUS_LINK = 3
STATUS_GROUND = 4  # (native) the autopilot's loop did not lift the vehicle off
STATUS_NAMES = {STATUS_OK: None, STATUS_BREACH: "safety limit breached",
                STATUS_GROUND: "the vehicle did not lift off",
                STATUS_NONFINITE: "the controller produced a non-finite setpoint",
                STATUS_LINK: "link: a gap between samples past the mission's limit"}


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



@jit
def _store(x, k, spos, svel, syaw, e, eul):
    """The float32 sample (position, velocity, heading) the vehicle takes at period ``k``."""
    for i in range(3):
        spos[k, i] = _f32(x[i])
        svel[k, i] = _f32(x[3 + i])
    for i in range(4):
        e[i] = x[phys.IX_Q + i]
    quat_to_euler(e, eul)
    syaw[k] = _f32(eul[2])


@jit
def _period(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, noise, sig, v_wind,
            f_ext, tau_ext, dt, r, per, tick, att_div, pos_div, pos_dt, scratch, ws):
    """One control period: ``per`` physics steps from ``tick``, with rows ``r`` on of ``eta``
    (the wind's normals) and ``noise`` (:meth:`sim.sensors.Sensors.draws`).  Without noise (no
    rows; ``xm`` is ``x``) the firmware flies on the truth and the period runs in one call; with
    noise it runs step by step, the firmware flying on the estimate ``xm``, which each step's
    end state is read into (:func:`sim.sensors.measure_into`), as the vehicle does it."""
    if noise.shape[0] == 0:
        advance_wind_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate,
                          eta[r:r + per], v_wind, f_ext, tau_ext, dt, per, tick, att_div, pos_div,
                          pos_dt, scratch, ws)
        return
    advance_wind_measured_into(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate,
                               eta[r:r + per], noise[r:r + per], sig, v_wind, f_ext, tau_ext, dt,
                               per, tick, att_div, pos_div, pos_dt, scratch, ws)


@jit
def closed_loop(x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind, f_ext,
                tau_ext, dt, tick0, att_div, pos_div, pos_dt, per, xm, noise, sig, k0, k_end,
                delivered, applied, lag, stimes, t0, spos, svel, syaw, spq, spt, refs, crefs, Sc,
                Pc, Mc, INc, latency, oracle, limits, max_gap, origin, rules, lifted, yaw_offset,
                log, tilt_measured):
    """Fly the mission from period ``k0`` (periods count from the arming) to at most ``k_end``.

    Each period ``k``: the vehicle takes its sample of its estimate ``xm`` (the truth ``x``
    itself without noise; ``noise`` and ``sig`` as :func:`_period` takes them) into
    ``spos``/``svel``/``syaw`` at row ``k + lag`` (rows before ``lag``: the samples of the
    periods before the arming); if the companion gets one now (``delivered[k]`` = the period
    ``s`` it was taken, -1: none) it runs a control step on row ``s`` (data of period
    ``s - lag``: the sensor latency, at the sample's time ``stimes[s]``, mission time from
    ``t0``; the interval since the last sample it got; its age, ``k - s`` periods, as the
    controller's ``latency`` says: NaN not compensated, < 0 the age measured, else that many
    seconds), the
    reference of ``crefs`` row by row (N, 13: pos, vel, the acceleration fed forward, yaw,
    the reference's own acceleration; for the sample's time, or
    with the age compensated for now; ``refs``: for the sample's time, the one logged and
    scored), and makes a setpoint (float32,
    into ``spq``/``spt`` at ``k``); the vehicle applies setpoint ``applied[k]`` if one arrives
    (-1: keeps the last) and runs ``per`` physics steps.  ``limits`` = [north lo, hi, east lo,
    hi, altitude lo, hi, max speed] relative to ``origin``; ``max_gap``: the longest interval
    between mission samples before the flight ends.  Until ``lifted`` the observers hold no
    disturbance; the reference's heading is offset by ``yaw_offset``, turned to 0 at
    ``rules[2]`` (:data:`GROUND_RULES`).  The run ends after the row whose time reaches the
    last reference.  Fills ``log`` row by row; returns (rows written, status, periods flown).
    ``tilt_measured``: the thrust is sized for the vehicle's tilt by its estimate of the period
    before (:func:`mavadrc.control.geometry.thrust_for_tilt`; the flight's newest ATTITUDE when
    a sample comes: it follows the position sample in a period's messages).
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
    j = 0
    nrows = refs.shape[0]
    prev = -1.0
    cos_tilt = 1.0
    if tilt_measured:  # (the first sample: its own period's)
        cos_tilt = 1.0 - 2.0 * (xm[phys.IX_Q + 1] ** 2 + xm[phys.IX_Q + 2] ** 2)
    for k in range(k0, k_end):
        _store(xm, k + lag, spos, svel, syaw, e, eul)
        s = delivered[k]
        if s >= 0:
            d = s  # the sample of period s - lag
            for i in range(3):
                pos[i] = spos[d, i]
                vel[i] = svel[d, i]
                rpos[i] = crefs[j, i]
                rvel[i] = crefs[j, 3 + i]
                racc[i] = crefs[j, 6 + i]
                Sc[i, K.S_AREF] = crefs[j, 10 + i]  # the reference's own (a law that predicts)
            phys.disturbance_accel_into(x, omega, pv, v_wind, f_ext, tau_ext, dist, xdot)
            if oracle:
                for i in range(3):
                    racc[i] -= dist[i]
            t = stimes[s] - t0
            hc = t - (prev if j > 0 else 0.0)
            gap = j > 0 and hc > max_gap
            prev = t
            if yaw_offset != 0.0:
                yaw_offset -= max(-rules[2] * hc, min(rules[2] * hc, yaw_offset))
            yaw_ref = crefs[j, 9] + yaw_offset
            age = latency
            if latency < 0.0:
                age = (k - s) * Pc[0, K.P_H]
            ok = position_update(Sc, Pc, Mc, INc, pos, vel, rpos, rvel, racc, yaw_ref, out, hc,
                                 age)
            if not lifted:
                if lifted_f32(pos, vel, origin, rules):
                    lifted = True
                else:
                    position_hold_disturbance(Sc)
            row = log[j]
            row[L_T] = t
            for i in range(3):
                row[L_REF + i] = refs[j, i]
                row[L_POS + i] = pos[i]
                row[L_VEL + i] = vel[i]
                row[L_ACC_CMD + i] = out[G.NO + i]
                row[L_ACC + i] = out[G.O_ACC + i]
                row[L_Z3 + i] = Sc[i, K.S_Z3]
                row[L_DIST + i] = dist[i]
            for i in range(4):
                row[L_WRENCH + i] = fs[A.FS_WRENCH + i]
            row[L_YAW] = syaw[d]
            row[L_REF_YAW] = refs[j, 9] + yaw_offset
            row[L_AGE] = (k - s) * Pc[0, K.P_H]
            row[L_ROLL] = eul[0]  # of this period (_store above)
            row[L_PITCH] = eul[1]
            for i in range(3):
                row[L_REF_ACC + i] = refs[j, 6 + i]
            j += 1
            if not ok:
                return j, STATUS_NONFINITE, k - k0
            for i in range(4):
                spq[k, i] = _f32(out[G.O_Q + i])
                row[L_Q + i] = spq[k, i]
            thrust = out[G.O_THRUST]
            if tilt_measured:
                thrust = G.thrust_for_tilt(thrust, out[G.O_Q], out[G.O_Q + 1], out[G.O_Q + 2],
                                           out[G.O_Q + 3], cos_tilt, Mc[G.M_THR_MAX])
            spt[k] = _f32(thrust)
            row[L_THRUST] = spt[k]
            # the flight's safety checks, on the sample, after logging it
            if gap:
                return j, STATUS_LINK, k - k0
            north = pos[0] - origin[0]
            east = pos[1] - origin[1]
            alt = -(pos[2] - origin[2])
            speed = math.sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2])
            if not (limits[0] <= north <= limits[1] and limits[2] <= east <= limits[3]) or \
                    alt > limits[5] or alt < limits[4] or speed > limits[6]:
                return j, STATUS_BREACH, k - k0
        a = applied[k]
        if a >= 0:
            _attitude_setpoint(sp, spq[a, 0], spq[a, 1], spq[a, 2], spq[a, 3], spt[a])
        _period(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, noise, sig, v_wind,
                f_ext, tau_ext, dt, tick - tick0, per, tick, att_div, pos_div, pos_dt, scratch,
                ws)
        tick += per
        if tilt_measured:  # this period's, for the next sample
            cos_tilt = math.cos(eul[0]) * math.cos(eul[1])
        if j == nrows:
            return j, STATUS_OK, k - k0 + 1
    return j, STATUS_LINK, k_end - k0


@jit
def spool(x, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, v_wind, f_ext, tau_ext,
          dt, tick0, att_div, pos_div, pos_dt, per, xm, noise, sig, n, delivered, applied, lag,
          yaw_before, stimes, thrusts, last_k, spos, svel, syaw, spq, spt, origin, rules, start):
    """The flight's ground phase from the arming (period 0), one setpoint per sample the
    companion gets (``delivered``, the samples and the estimate as in :func:`closed_loop`):
    level at the heading the flight knows then, that of the ATTITUDE of the period before
    (float32, as ATTITUDE and SET_ATTITUDE_TARGET carry it; LOCAL_POSITION_NED comes first in
    a period's messages, and ATTITUDE is not subject to the link: ``syaw`` at row ``k - 1``,
    ``yaw_before`` at period 0), with the spool-up thrust of
    the sample's time (``thrusts``, by the period the sample was taken), applied as
    ``applied`` says, then ``per`` physics steps.

    Ends after the sample that shows the vehicle lifting off (relative to ``origin``) or the
    one taken at ``last_k`` or later (the mission's start time); ``start`` gets that sample's
    float32 position, the heading then (where the mission starts) and the period it was
    taken.  Returns the number of periods flown (0: no such sample within ``n``)."""
    e = np.empty(4)
    eul = np.empty(3)
    pos = np.empty(3)
    vel = np.empty(3)
    scratch = np.empty(WIND_SCRATCH)
    ws = np.empty((5, phys.NX))
    tick = tick0
    for k in range(n):
        _store(xm, k + lag, spos, svel, syaw, e, eul)
        s = delivered[k]
        last = False
        if s >= 0:
            d = s  # the sample of period s - lag
            for i in range(3):
                pos[i] = spos[d, i]
                vel[i] = svel[d, i]
            yaw = syaw[k - 1] if k >= 1 else yaw_before
            last = s >= last_k or lifted_f32(pos, vel, origin, rules)
            if last:
                for i in range(3):
                    start[i] = pos[i]
                start[3] = yaw
                start[4] = s
            spq[k, 0] = _f32(math.cos(0.5 * yaw))
            spq[k, 1] = 0.0
            spq[k, 2] = 0.0
            spq[k, 3] = _f32(math.sin(0.5 * yaw))
            spt[k] = thrusts[s]
        a = applied[k]
        if a >= 0:
            _attitude_setpoint(sp, spq[a, 0], spq[a, 1], spq[a, 2], spq[a, 3], spt[a])
        _period(x, xm, fs, fp, S, P, W, mx, sp, omega, wk, pv, wp, dstate, eta, noise, sig, v_wind,
                f_ext, tau_ext, dt, tick - tick0, per, tick, att_div, pos_div, pos_dt, scratch,
                ws)
        tick += per
        if last:
            return k + 1
    return 0


@dataclass
class InProcessRun:
    """The per-step log of one run (columns L_*), its phases and how it ended."""

    log: np.ndarray
    phases: list  # [(mission time, segment name)]
    duration: float  # the trajectory's duration (s)
    status: int
    mission_start: float  # vehicle time of the mission's t = 0
    hover_thrust: float  # the normalized hover thrust the controller was given
    hover_thrust_learnt: float = None  # what it had learnt by the end (None: it does not learn)

    @property
    def aborted(self):
        return STATUS_NAMES[self.status]


def boot_seconds(tick, physics_dt):
    """The vehicle time a LOCAL_POSITION_NED sample at ``tick`` carries (ms resolution)."""
    ms = np.round(np.asarray(tick, dtype=np.int64) * physics_dt * 1000.0).astype(np.int64)
    return (ms & 0xFFFFFFFF) / 1000.0


def vehicle_of(mission, seed=None, wind=None, vehicle_options=None):
    """The bundled vehicle ``mission`` flies in process (its file changed as its ``sim:``
    section says; ``seed``/``wind`` override the mission's), at rest before its boot: returns
    (vehicle, control period h, physics steps per period, sensor latency in periods, the hover
    thrust the companion is told).  Refuses what the in-process path does not model."""
    seed = mission.seed if seed is None else seed
    spec = mission.controller
    wind = mission.wind if wind is None else wind
    options = {"yaw": math.radians(mission.heading_deg),
               # the thrust curve the mission's autopilot linearises with, as the server's
               "thrust_model_factor":
                   personality(mission.autopilot).default_thrust_model_factor(),
               **dict(vehicle_options or {})}
    if mission.noise or mission.wander:  # the server's --noise and --wander (latency: below)
        options.setdefault("sensors", {"noise": TYPICAL_NOISE if mission.noise else {},
                                       "wander": mission.wander,
                                       "wander_corner_hz": mission.wander_corner_hz})
    told = _vehicle_params(mission.vehicle or "crazyflie")  # the file: what the companion knows
    flown = vehicle_variant(told, mass_scale=mission.mass_scale,
                            motor_thrust_curve=mission.motor_thrust_curve,
                            attitude_bandwidth_scale=mission.attitude_bandwidth_scale)
    v = SimVehicle(flown, wind=wind, seed=seed, attitude_controller=mission.attitude_controller,
                   **options)
    h = 1.0 / spec.rate_hz
    dt = v.physics_dt
    per = int(round(h / dt))
    if abs(per * dt - h) > 1e-9 * h:
        raise ValueError(f"controller rate {spec.rate_hz:g} Hz must divide the physics rate "
                         f"{1.0 / dt:g} Hz for the in-process path")
    if mission.height_drift_mps:
        raise ValueError("sim.height_drift_mps: the in-process path does not model a drifting "
                         "height estimate (it never lands); fly it over MAVLink")
    if mission.ground_climb_mps:
        raise ValueError("sim.ground_climb_mps: the in-process path has no autopilot to land "
                         "on; fly it over MAVLink")
    if mission.clock_rate != 1.0:
        raise ValueError("sim.clock_rate: the in-process path has one clock (the vehicle's); "
                         "fly it over MAVLink in real time")
    lag = int(round(mission.sensor_latency_s / h))
    if abs(lag * h - mission.sensor_latency_s) > 1e-9:
        raise ValueError(f"sensor latency {mission.sensor_latency_s:g} s must be a whole number "
                         f"of control periods ({h:g} s) for the in-process path")
    hover = mission.hover_thrust if mission.hover_thrust is not None else v.hover_thrust
    return v, h, per, lag, hover


def fly_resolved(mission, kind=None, seed=None, wind=None, vehicle_options=None):
    """Fly ``mission`` in process, its input model resolved already (no ``input_lag: auto``:
    :func:`mavadrc.fast.fly.fly_inprocess` resolves it first); returns an :class:`InProcessRun`.

    ``kind``: the position controller ('pd', 'ladrc', 'adrc', 'pid', or 'oracle': PD with the
    true disturbance fed forward); ``seed``/``wind`` override the mission's (as ``mavadrc fly``'s
    options do).  ``vehicle_options``: extra :class:`SimVehicle` keywords.
    """
    kind = kind or mission.controller.kind
    oracle = kind == "oracle"
    seed = mission.seed if seed is None else seed
    spec = mission.controller
    v, h, per, lag, hover = vehicle_of(mission, seed, wind, vehicle_options)
    dt = v.physics_dt
    if oracle:  # the PD law with the oracle's own gains (a spec of another kind flies defaults)
        spec = dataclasses.replace(spec, kind="pd")
    ctrl = make_controller(spec, hover_thrust=hover, kind="pd" if oracle else kind)
    # on the ground, disarmed, then armed at idle; thrust spooled up to MISSION_START.  The
    # samples of the last ``lag`` periods before the arming are what the companion gets in the
    # first ``lag`` periods after it (the sensor latency); the mission's origin is the first
    # sample the flight gets, at the end of the first period (that of period 1 - lag, or of
    # the vehicle's boot while the latency reaches back before it)
    n_arm = round(ARM_AT / h)
    k_origin = max(1 - lag, 0)
    v.step(k_origin * h)
    origin = f32(v.reported().position)
    v.step((n_arm - lag - 1 - k_origin) * h)
    before = []  # periods -lag-1 .. -1
    for _ in range(lag + 1):
        before.append(v.reported())
        v.step(h)
    # the heading the ATTITUDE of period -1 carries (what the flight's first spool-up setpoint
    # levels at)
    yaw_before = float(f32(before[0].euler[2]))
    traj, phases = mission.build_trajectory(origin)
    v.arm()
    # periods from the arming on: the samples the companion gets and the setpoints the vehicle
    # applies, as the link decides them (every one, at once, on a perfect link)
    state = v.kernel_state()
    packed, wind_out = v.kernel_wind()
    fw = v.fw
    timing = (fw.att_div, fw.pos_div, fw.pos_dt, per)
    tick0 = v.tick
    link = mission.link
    slack = 0 if link is None else \
        int(math.ceil((max(link.down.latency_s + link.down.jitter_s,
                           link.up.latency_s + link.up.jitter_s)
                       + sum(d for _, d in link.blackouts)) / h)) + 200
    n_pre = int(math.ceil((MISSION_START - ARM_AT) / h)) + 3 + slack
    n = n_pre + int(math.ceil((traj.duration + 2 * h) / h)) + 2 + slack
    stimes = boot_seconds(tick0 + per * np.arange(n), dt)
    delivered = np.arange(n, dtype=np.int64)
    applied = np.arange(n, dtype=np.int64)
    if link is not None:  # from LINK_FROM on, as the lockstep vehicle applies it
        k_link = int(np.argmax(stimes >= LINK_FROM - 1e-9))
        d, a = PeriodLink(link, seed, h, float(stimes[k_link])).arrays(n - k_link)
        delivered[k_link:] = np.where(d >= 0, d + k_link, -1)
        applied[k_link:] = np.where(a >= 0, a + k_link, -1)
    last_k = int(np.argmax(stimes >= MISSION_START - 1e-9))
    thrusts = f32(spool_thrust(stimes, MISSION_START, hover))
    spos = np.zeros((n + lag, 3))  # row k + lag: the sample of period k
    svel = np.zeros((n + lag, 3))
    syaw = np.zeros(n + lag)
    for i, b in enumerate(before[1:]):
        spos[i] = f32(b.position)
        svel[i] = f32(b.velocity)
        syaw[i] = f32(b.euler[2])
    spq = np.zeros((n, 4))
    spt = np.zeros(n)
    eta = packed.normals(n * per)  # the wind's draws, in the order the vehicle makes them
    sensing = v.kernel_sensors(n * per)  # and the sensors' (none without noise)
    start = np.zeros(5)
    sent = spool(*state, packed.params, packed.state, eta, *wind_out, dt, tick0, *timing,
                 *sensing, n_pre, delivered, applied, lag, yaw_before, stimes, thrusts, last_k,
                 spos, svel, syaw, spq, spt, origin, GROUND_RULES, start)
    if sent == 0:
        raise RuntimeError("the link delivered no sample to start the mission on")
    ctrl.reset(start[:3])
    # the mission's frame moved horizontally to where the estimate has the vehicle at the
    # start, as a flight moves it (GroundPhases._anchor_here)
    origin = np.array(origin, dtype=np.float64)
    origin[:2] = start[:2]
    traj, phases = mission.build_trajectory(origin)
    t0 = float(stimes[int(start[4])])
    v.ran(sent * per)
    # the mission steps: one per sample the companion gets, at the sample's time as the wire
    # carries it, the reference as the flight reads it (the grid of control periods, or an
    # exact sample off the grid)
    got = delivered[sent:]
    at = np.nonzero(got >= 0)[0] + sent  # the periods they come in
    got = got[got >= 0]
    times = stimes[got] - t0
    done = np.nonzero(times >= traj.duration)[0]
    rows_max = int(done[0]) + 1 if done.size else times.size
    ref = _references(traj, times[:rows_max], h)
    # the controller's reference: for now when it compensates the samples' age
    latency = math.nan if ctrl.latency is None else (-1.0 if ctrl.latency == "auto"
                                                     else ctrl.latency)
    if latency != latency:
        cref = ref
    else:
        now = times[:rows_max] + ((at[:rows_max] - got[:rows_max]) * h if latency < 0.0
                                  else latency)
        cref = _references(traj, now, h)
    # then the reference's own acceleration (a law that predicts compares its estimate's with
    # it), where columns 6-8 become the acceleration fed forward
    cref = np.column_stack([cref, cref[:, 6:9]])
    lead = ctrl.feedforward_lead
    if np.any(lead > 0.0):
        # the acceleration fed forward: the reference's where the command will act (as the
        # flight's Flight._feedforward computes it), sampled once per distinct lead
        base = times[:rows_max] if latency != latency else now
        drag = ctrl.drag
        ahead = {}
        for i in range(3):
            if lead[i] > 0.0:
                if lead[i] not in ahead:
                    ahead[lead[i]] = _references(traj, base + lead[i], h)
                a = ahead[lead[i]]
                cref[:, 6 + i] = a[:, 6 + i] + drag[i] * (a[:, 3 + i] - cref[:, 3 + i])
    log = np.full((rows_max, NLOG), math.nan)
    sf = mission.safety
    limits = np.array([*sf.geofence_north, *sf.geofence_east, sf.altitude_min, sf.altitude_max,
                       sf.max_speed], dtype=float)
    Pc, Mc = ctrl.params
    yaw_offset = wrap_pi(start[3] - float(traj.sample(0.0).yaw))
    xm, noise, sig = sensing
    rows, status, flown = closed_loop(
        *state, packed.params, packed.state, eta[sent * per:], *wind_out, dt, v.tick, *timing,
        xm, noise[sent * per:], sig, sent, n, delivered, applied, lag, stimes, t0, spos, svel,
        syaw, spq, spt, ref, cref, ctrl._S, Pc, Mc, ctrl._IN, latency, oracle, limits,
        sf.max_gap_s, origin, GROUND_RULES, False, yaw_offset, log,
        spec.thrust_tilt == "measured")
    v.ran(flown * per)
    ctrl.adopt_thrust_of(Mc)  # what the run learnt, read as the flight reads it
    learnt = ctrl.hover_thrust_estimate if ctrl.learns_thrust else None
    return InProcessRun(log[:rows], phases, traj.duration, int(status), t0, hover, learnt)


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
