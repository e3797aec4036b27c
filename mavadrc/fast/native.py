"""The in-process fast path of ``controller: native``: the bundled vehicle's own position
controller (:mod:`sim.firmware.position`) flies the mission's reference, sent it as position
targets, no sockets.

It is the lockstep MAVLink flight of ``mavadrc fly --controller native`` with the wire taken
out, on the timeline of :func:`mavadrc.fast.inprocess.fly_resolved`: on the ground until armed
at :data:`~mavadrc.fast.inprocess.ARM_AT`, a target under the vehicle until the mission starts
at :data:`~mavadrc.fast.inprocess.MISSION_START` (or at the sample that shows it lifting off),
then one target per period, the reference of the sample's time (float32, as
SET_POSITION_TARGET_LOCAL_NED carries it), the heading turned from the vehicle's to the
mission's at :data:`~mavadrc.mission.takeoff.YAW_RATE`, the takeoff's reference running as it
does in the flight (the autopilot's loop lifts the vehicle; a run still on the ground
:data:`~mavadrc.mission.takeoff.NATIVE_TAKEOFF_WAIT_S` into the mission ends there), and the
flight's safety checks.  The autopilot's loop runs in Python here (its modes
are Python in the bundled vehicle too), one period at a time: slower than the compiled loop of
the companion's controllers, still several hundred times real time.

A link model (``link:``) is not flown here: the MAVLink path flies it.
"""

import collections
import math

import numpy as np

from mavadrc.control import geometry as G
from mavadrc.control.rotations import wrap_pi
from mavadrc.mission.takeoff import (
    GROUND_TARGET_BELOW_M,
    NATIVE_TAKEOFF_WAIT_S,
    YAW_RATE,
    lifted_off,
)

from . import inprocess as I


def fly_native(mission, seed=None, wind=None, vehicle_options=None):
    """Fly ``mission`` with the bundled vehicle's own position controller; returns an
    :class:`~mavadrc.fast.inprocess.InProcessRun` (columns ``L_*``; the observers' columns NaN:
    there are none)."""
    if mission.link is not None:
        raise ValueError("controller native with a link model: the in-process path does not "
                         "fly one for the autopilot's own controller; fly it over MAVLink "
                         "(compare --via mavlink)")
    v, h, per, lag, hover = I.vehicle_of(mission, seed, wind, vehicle_options)
    dt = v.physics_dt
    samples = collections.deque(maxlen=lag + 1)  # what the companion gets: lag periods old

    def sample():
        r = v.reported()
        samples.append((I.f32(r.position), I.f32(r.velocity), float(I.f32(r.euler[2])),
                        float(r.euler[0]), float(r.euler[1])))
        return samples[0]

    n_arm = round(I.ARM_AT / h)
    k_origin = max(1 - lag, 0)
    v.step(k_origin * h)
    origin = np.array(I.f32(v.reported().position), dtype=float)
    v.step((n_arm - lag - 1 - k_origin) * h)
    for _ in range(lag + 1):
        sample()
        v.step(h)
    v.arm()
    tick0 = v.tick
    n_pre = int(math.ceil((I.MISSION_START - I.ARM_AT) / h)) + 3
    k = 0
    while True:  # the ground phase: a target under the vehicle until the mission starts
        t_s = float(I.boot_seconds(tick0 + per * k, dt))
        pos, vel, yaw, _, _ = sample()
        start = t_s >= I.MISSION_START - 1e-9 or lifted_off(origin[2] - pos[2], vel[2])
        if start:
            break
        v.set_position_target(pos=pos + np.array([0.0, 0.0, GROUND_TARGET_BELOW_M]),
                              vel=np.zeros(3), acc=np.zeros(3), yaw=yaw)
        v.step(h)
        k += 1
        if k > n_pre:
            raise RuntimeError("the mission did not start on the ground phase's timeline")
    # the mission's frame moved horizontally to where the estimate has the vehicle at the
    # start, as a flight moves it
    origin[:2] = pos[:2]
    traj, phases = mission.build_trajectory(origin)
    t0 = t_s
    yaw_offset = wrap_pi(yaw - float(traj.sample(0.0).yaw))
    sf = mission.safety
    # one row per period until the mission time reaches its end (the samples' millisecond
    # times put that at most a period or two past duration / h)
    log = np.full((int(math.ceil(traj.duration / h)) + 3, I.NLOG), math.nan)
    j = 0
    status = I.STATUS_OK
    lifted = False
    while j < len(log):
        t_s = float(I.boot_seconds(tick0 + per * k, dt))
        pos, vel, yaw, roll, pitch = sample()
        t = t_s - t0
        r = traj.sample(min(t, traj.duration))
        if not lifted and lifted_off(origin[2] - pos[2], vel[2]):
            lifted = True
        if not lifted and t >= NATIVE_TAKEOFF_WAIT_S:  # as the flight ends it (Takeoff)
            status = I.STATUS_GROUND
            break
        if yaw_offset != 0.0:
            yaw_offset -= max(-YAW_RATE * h, min(YAW_RATE * h, yaw_offset))
        dist = v.true_disturbance()
        v.set_position_target(pos=I.f32(r.pos), vel=I.f32(r.vel), acc=I.f32(r.acc),
                              yaw=float(I.f32(r.yaw + yaw_offset)))
        row = log[j]
        row[I.L_T] = t
        row[I.L_REF:I.L_REF + 3] = r.pos
        row[I.L_POS:I.L_POS + 3] = pos
        row[I.L_VEL:I.L_VEL + 3] = vel
        row[I.L_DIST:I.L_DIST + 3] = dist
        row[I.L_YAW] = yaw
        row[I.L_REF_YAW] = r.yaw + yaw_offset
        row[I.L_REF_ACC:I.L_REF_ACC + 3] = r.acc
        row[I.L_AGE] = lag * h
        row[I.L_ROLL] = roll
        row[I.L_PITCH] = pitch
        v.step(h)
        # what the autopilot's loop made of it (its newest step, within this period)
        out = v.nav.out
        row[I.L_Q:I.L_Q + 4] = out[G.O_Q:G.O_Q + 4]
        row[I.L_THRUST] = out[G.O_THRUST]
        row[I.L_ACC_CMD:I.L_ACC_CMD + 3] = out[G.NO:G.NO + 3]
        row[I.L_ACC:I.L_ACC + 3] = out[G.O_ACC:G.O_ACC + 3]
        row[I.L_WRENCH:I.L_WRENCH + 4] = v.wrench
        j += 1
        k += 1
        north, east = pos[0] - origin[0], pos[1] - origin[1]
        alt = -(pos[2] - origin[2])
        if not (sf.geofence_north[0] <= north <= sf.geofence_north[1]
                and sf.geofence_east[0] <= east <= sf.geofence_east[1]) \
                or not sf.altitude_min <= alt <= sf.altitude_max \
                or float(np.linalg.norm(vel)) > sf.max_speed:
            status = I.STATUS_BREACH
            break
        if t >= traj.duration:
            break
    return I.InProcessRun(log[:j], phases, traj.duration, status, t0, hover, None)
