"""The messages the bundled vehicle sends, one builder each: registered under its MAVLink id,
it fills its message from the vehicle's state as the autopilot reports it (PX4's
``src/modules/mavlink/streams/``).

A link's schedule (:mod:`sim.mavlink.link`) and the commands that request a message ask
:meth:`Streams.build` for a message by id; an id without a builder is a message the vehicle
does not produce.
"""

import math
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavadrc.control.rotations import euler_from_quat, rotation_matrix

from ..personality import TRUTH_RADIUS  # each simulator's sphere, as it projects

M = mavlink
EARTH_RADIUS = 6378137.0

SENSORS = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | M.MAV_SYS_STATUS_SENSOR_3D_MAG | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
           | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
           | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
           | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
           | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
           | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | M.MAV_SYS_STATUS_AHRS
           | M.MAV_SYS_STATUS_SENSOR_BATTERY | M.MAV_SYS_STATUS_GEOFENCE)
PREARM = M.MAV_SYS_STATUS_PREARM_CHECK

#: {MAVLink id: builder(streams) -> message}
BUILDERS = {}


def builds(msgid):
    """Register the decorated function as the builder of message ``msgid``."""
    def register(builder):
        BUILDERS[msgid] = builder
        return builder
    return register


class Streams:
    """Builds the messages of the vehicle that ``autopilot`` flies, as system ``sysid``."""

    def __init__(self, autopilot, sysid):
        self.autopilot = autopilot
        self.vehicle = autopilot.vehicle
        self.ap = autopilot.ap
        self.sysid = sysid

    def build(self, msgid):
        """Message ``msgid`` as of now; None if the vehicle does not produce it."""
        builder = BUILDERS.get(msgid)
        return None if builder is None else builder(self)

    # --- what several messages share -------------------------------------------------------------

    def boot_ms(self):
        return int(round(self.vehicle.time * 1000.0)) & 0xFFFFFFFF

    def time_us(self):
        return int(round(self.vehicle.time * 1e6))

    def global_position(self, p, radius=EARTH_RADIUS):
        """(lat, lon in 1e-7 deg, altitude AMSL in m) of local NED position ``p``, on a sphere
        of ``radius`` (m) about home."""
        lat0, lon0, alt0 = self.autopilot.home
        lat = lat0 + math.degrees(p[0] / radius)
        lon = lon0 + math.degrees(p[1] / (radius * math.cos(math.radians(lat0))))
        return int(round(lat * 1e7)), int(round(lon * 1e7)), alt0 - float(p[2])

    def battery_remaining(self):
        return int(max(5.0, 100.0 - 0.05 * self.vehicle.time))

    def battery_mv(self):
        return int(16800 - 20 * (100 - self.battery_remaining()))


@builds(M.MAVLINK_MSG_ID_HEARTBEAT)
def heartbeat(s):
    a = s.autopilot
    armed = s.vehicle.armed
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | s.ap.base_mode_flags(a.mode)
    if armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    if a.failsafe:
        status = M.MAV_STATE_CRITICAL
    elif armed:
        status = M.MAV_STATE_ACTIVE
    else:
        status = M.MAV_STATE_STANDBY
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, s.ap.autopilot, base,
                                       a.mode.custom_mode, status, 3)


@builds(M.MAVLINK_MSG_ID_ATTITUDE)
def attitude(s):
    r = s.autopilot.reported()
    e, w = r.euler, r.rates
    return M.MAVLink_attitude_message(s.boot_ms(), e[0], e[1], e[2], w[0], w[1], w[2])


@builds(M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION)
def attitude_quaternion(s):
    r = s.autopilot.reported()
    q, w = r.quaternion, r.rates
    return M.MAVLink_attitude_quaternion_message(s.boot_ms(), q[0], q[1], q[2], q[3], w[0], w[1],
                                                 w[2], [0.0, 0.0, 0.0, 0.0])


@builds(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
def local_position_ned(s):
    r = s.autopilot.reported()
    p, v = r.position, r.velocity
    return M.MAVLink_local_position_ned_message(s.boot_ms(), p[0], p[1], p[2], v[0], v[1], v[2])


@builds(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
def global_position_int(s):
    r = s.autopilot.reported()
    p, v = r.position, r.velocity
    lat, lon, alt = s.global_position(p)
    hdg = int(round(math.degrees(r.euler[2]) * 100.0)) % 36000
    return M.MAVLink_global_position_int_message(
        s.boot_ms(), lat, lon, int(round(alt * 1000)), int(round(-p[2] * 1000)),
        int(round(v[0] * 100)), int(round(v[1] * 100)), int(round(v[2] * 100)), hdg)


@builds(M.MAVLINK_MSG_ID_ODOMETRY)
def odometry(s):
    """Frame LOCAL_NED, child frame BODY_FRD: the velocity in body axes."""
    r = s.autopilot.reported()
    p, q, w = r.position, r.quaternion, r.rates
    vb = rotation_matrix(q).T @ r.velocity
    nan21 = [math.nan] * 21
    return M.MAVLink_odometry_message(
        s.time_us(), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD, p[0], p[1], p[2],
        list(map(float, q)), vb[0], vb[1], vb[2], w[0], w[1], w[2], nan21, nan21, 0,
        M.MAV_ESTIMATOR_TYPE_NAIVE, 100)


@builds(M.MAVLINK_MSG_ID_ATTITUDE_TARGET)
def attitude_target(s):
    """The last attitude setpoint taken, thrust as its magnitude (PX4's echo)."""
    qt, thrust, rates, mask = s.autopilot.att_target
    return M.MAVLink_attitude_target_message(s.boot_ms(), mask, list(map(float, qt)), rates[0],
                                             rates[1], rates[2], abs(thrust))


@builds(M.MAVLINK_MSG_ID_SYS_STATUS)
def sys_status(s):
    """Every sensor present and healthy; the prearm check passes except in a failsafe."""
    health = SENSORS | (0 if s.autopilot.failsafe else PREARM)
    return M.MAVLink_sys_status_message(SENSORS | PREARM, SENSORS | PREARM, health, 200,
                                        s.battery_mv(), -1, s.battery_remaining(), 0, 0, 0, 0,
                                        0, 0)


@builds(M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE)
def extended_sys_state(s):
    return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED,
                                                s.autopilot.landed_state())


@builds(M.MAVLINK_MSG_ID_HOME_POSITION)
def home_position(s):
    lat0, lon0, alt0 = s.autopilot.home
    return M.MAVLink_home_position_message(
        int(round(lat0 * 1e7)), int(round(lon0 * 1e7)), int(round(alt0 * 1000)), 0.0, 0.0, 0.0,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, s.time_us())


@builds(M.MAVLINK_MSG_ID_BATTERY_STATUS)
def battery_status(s):
    cells = [s.battery_mv() // 4] * 4 + [65535] * 6
    return M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO,
                                            2500, cells, -1, -1, -1, s.battery_remaining())


@builds(M.MAVLINK_MSG_ID_SYSTEM_TIME)
def system_time(s):
    return M.MAVLink_system_time_message(int(time.time() * 1e6), s.boot_ms())


@builds(M.MAVLINK_MSG_ID_GPS_RAW_INT)
def gps_raw_int(s):
    r = s.autopilot.reported()
    v = r.velocity
    lat, lon, alt = s.global_position(r.position)
    cog = int(round(math.degrees(math.atan2(v[1], v[0])) * 100)) % 36000
    return M.MAVLink_gps_raw_int_message(s.time_us(), M.GPS_FIX_TYPE_3D_FIX, lat, lon,
                                         int(round(alt * 1000)), 80, 120,
                                         int(round(math.hypot(v[0], v[1]) * 100)), cog, 12)


#: the bundled range finder's span (cm): PX4 SIH's (SIH_DISTSNSR_MIN 0, SIH_DISTSNSR_MAX 100 m)
RANGE_MIN_CM, RANGE_MAX_CM = 0, 10000


@builds(M.MAVLINK_MSG_ID_DISTANCE_SENSOR)
def distance_sensor(s):
    """A downward range finder (``SimVehicle(rangefinder=True)``; None without one): the true
    height above the flat ground along the body's down axis, -z / cos(tilt), as PX4 SIH's
    (simulator_sih ``send_dist_snsr``), in whole cm.  Past its span it reads one more than its
    maximum (out of range, as a receiver must take it)."""
    if not s.vehicle.rangefinder:
        return None
    x = s.vehicle.state
    q = x[6:10]
    cos_tilt = 1.0 - 2.0 * (float(q[1]) ** 2 + float(q[2]) ** 2)  # R[2, 2]: body down vs down
    height = max(0.0, -float(x[2]))
    if cos_tilt <= 0.1:
        cm = RANGE_MAX_CM + 1
    else:
        cm = min(RANGE_MAX_CM + 1, int(round(100.0 * height / cos_tilt)))
    return M.MAVLink_distance_sensor_message(
        s.boot_ms(), RANGE_MIN_CM, RANGE_MAX_CM, cm, M.MAV_DISTANCE_SENSOR_LASER, 0,
        M.MAV_SENSOR_ROTATION_PITCH_270, 0)


@builds(M.MAVLINK_MSG_ID_DEBUG_VECT)
def debug_vect(s):
    """The simulator's truth, for comparing observer estimates: the acceleration (NED, m/s^2)
    the environment adds beyond thrust and gravity."""
    d = s.vehicle.true_disturbance()
    return M.MAVLink_debug_vect_message(b"TRUE_DIST", s.time_us(), float(d[0]), float(d[1]),
                                        float(d[2]))


@builds(M.MAVLINK_MSG_ID_HIL_STATE_QUATERNION)
def hil_state_quaternion(s):
    """The true state, as PX4's SIH sends it (streams/HIL_STATE_QUATERNION.hpp, from the
    ground-truth topics; its global position projected with PX4's earth radius, 6371 km): what
    a companion measures its tracking against, beside the autopilot's estimate.  PX4 leaves
    time_usec 0; so does this."""
    x = s.vehicle.state
    lat, lon, alt = s.global_position(x[0:3], TRUTH_RADIUS["HIL_STATE_QUATERNION"])
    q, v, w = x[6:10], x[3:6], x[10:13]
    return M.MAVLink_hil_state_quaternion_message(
        0, list(map(float, q)), float(w[0]), float(w[1]), float(w[2]), lat, lon,
        int(round(alt * 1000)), int(round(v[0] * 100)), int(round(v[1] * 100)),
        int(round(v[2] * 100)), 0, 0, 0, 0, 0)


@builds(M.MAVLINK_MSG_ID_SIM_STATE)
def sim_state(s):
    """The true state, as ArduPilot's SITL sends it (SIM::sim_state_send): lat and lon as
    floats in 1e-7 deg (not deg, as the message's definition says) and again exact in lat_int
    and lon_int; ArduPilot's earth radius, 6378137 m."""
    x = s.vehicle.state
    lat, lon, alt = s.global_position(x[0:3], TRUTH_RADIUS["SIM_STATE"])
    q, v, w = x[6:10], x[3:6], x[10:13]
    e = euler_from_quat(q)
    return M.MAVLink_sim_state_message(
        float(q[0]), float(q[1]), float(q[2]), float(q[3]), *map(float, e), 0.0, 0.0, 0.0,
        float(w[0]), float(w[1]), float(w[2]), float(lat), float(lon), alt, 0.0, 0.0,
        float(v[0]), float(v[1]), float(v[2]), lat, lon)


@builds(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
def autopilot_version(s):
    return M.MAVLink_autopilot_version_message(
        s.ap.capabilities, s.ap.flight_sw_version, 0, 0, 1, b"mavadrc\0", b"\0" * 8, b"\0" * 8,
        0, 0, 0x4D41564144524300 + s.sysid)
