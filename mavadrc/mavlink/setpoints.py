"""What the companion streams to the autopilot while it flies: attitude setpoints (position
targets for its own position controller), and named
values for the log."""

import math


def attitude_target(mav, target_system, t_boot_ms, q, thrust):
    """SET_ATTITUDE_TARGET with attitude and thrust, body rates ignored; refuses non-finite."""
    if not (all(math.isfinite(v) for v in q) and math.isfinite(thrust)):
        raise ValueError("refusing to send a non-finite setpoint")
    mav.set_attitude_target_send(int(t_boot_ms) & 0xFFFFFFFF, target_system, 1, 7,
                                 [float(v) for v in q], 0.0, 0.0, 0.0, float(thrust))


#: SET_POSITION_TARGET_LOCAL_NED's type_mask: position, velocity, acceleration and yaw given,
#: the yaw rate ignored
POSITION_TARGET_MASK = 0x800


def position_target(mav, target_system, t_boot_ms, pos, vel, acc, yaw):
    """SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED with position, velocity,
    acceleration and yaw (the autopilot's own position controller flies it); refuses
    non-finite."""
    values = [*pos, *vel, *acc, yaw]
    if not all(math.isfinite(v) for v in values):
        raise ValueError("refusing to send a non-finite position target")
    p, v, a = [float(x) for x in pos], [float(x) for x in vel], [float(x) for x in acc]
    mav.set_position_target_local_ned_send(int(t_boot_ms) & 0xFFFFFFFF, target_system, 1, 1,
                                           POSITION_TARGET_MASK, *p, *v, *a, float(yaw), 0.0)


def named_float(mav, t_boot_ms, name, value):
    """NAMED_VALUE_FLOAT ``name`` = ``value`` (the autopilot logs it)."""
    mav.named_value_float_send(int(t_boot_ms) & 0xFFFFFFFF, name.encode(), float(value))
