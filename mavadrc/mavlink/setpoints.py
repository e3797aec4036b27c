"""What the companion streams to the autopilot while it flies: attitude setpoints, and named
values for the log."""

import math


def attitude_target(mav, target_system, t_boot_ms, q, thrust):
    """SET_ATTITUDE_TARGET with attitude and thrust, body rates ignored; refuses non-finite."""
    if not (all(math.isfinite(v) for v in q) and math.isfinite(thrust)):
        raise ValueError("refusing to send a non-finite setpoint")
    mav.set_attitude_target_send(int(t_boot_ms) & 0xFFFFFFFF, target_system, 1, 7,
                                 [float(v) for v in q], 0.0, 0.0, 0.0, float(thrust))


def named_float(mav, t_boot_ms, name, value):
    """NAMED_VALUE_FLOAT ``name`` = ``value`` (the autopilot logs it)."""
    mav.named_value_float_send(int(t_boot_ms) & 0xFFFFFFFF, name.encode(), float(value))
