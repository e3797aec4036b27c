"""The takeoff's rules, shared by a flight over MAVLink and the in-process fast path: the thrust
spooled up on the ground, when the vehicle has lifted off, how fast the heading turns."""
import math

import numpy as np

from mavadrc.control.jit import jit

SPOOL_S = 0.5  # thrust ramp on the ground before the mission clock starts



#: the takeoff waits for the vehicle: while it is still on the ground and the reference has
#: climbed this far above it (m), the mission clock stops (the reference waits) and the thrust
#: per acceleration rises by TAKEOFF_RAMP_PER_S of itself per second, until it lifts off
TAKEOFF_WAIT_M = 0.15



TAKEOFF_RAMP_PER_S = 0.15



#: s of waiting with the thrust at its bound (twice the hover thrust told) before giving up
TAKEOFF_WAIT_MAX_S = 5.0



#: lift-off: this high above the takeoff spot (m), or climbing faster than this (m/s)
LIFTOFF_HEIGHT = 0.05



LIFTOFF_CLIMB = 0.2



def spool_thrust(t, start_at, hover):
    """Normalized thrust of the spool-up: 0.8 hover, reached at vehicle time ``start_at`` after a
    ramp of SPOOL_S (0 before it); ``t`` a time or an array of times."""
    return 0.8 * hover * np.clip((t - (start_at - SPOOL_S)) / SPOOL_S, 0.0, 1.0)



def lifted_off(height, vz):
    """Whether a vehicle ``height`` m above its takeoff spot, at vertical speed ``vz`` (NED), has
    left the ground."""
    return height >= LIFTOFF_HEIGHT or vz < -LIFTOFF_CLIMB


#: the heading turns from the vehicle's to the mission's at this rate (rad/s): PX4's
#: MPC_YAWRAUTO_MAX default, 45 deg/s
YAW_RATE = math.radians(45.0)


#: the takeoff's rules as the fast path's compiled loops take them (passed in: a constant read
#: from another module would be frozen into numba's cache of the loop's)
GROUND_RULES = np.array([LIFTOFF_HEIGHT, LIFTOFF_CLIMB, YAW_RATE])


@jit
def lifted_f32(pos, vel, origin, rules):
    """:func:`lifted_off` on a float32 sample, for the compiled fast path (``rules``:
    :data:`GROUND_RULES`)."""
    return origin[2] - pos[2] >= rules[0] or vel[2] < -rules[1]


#: ``controller: native``, on the ground (idle, the thrust cut): the position target this far (m)
#: below the vehicle, so the autopilot's position loop holds it down instead of starting a
#: takeoff (PX4 mc_pos_control takes off in OFFBOARD once a target is above the vehicle)
GROUND_TARGET_BELOW_M = 0.5
#: ``controller: native``: s into the mission a vehicle still on the ground ends the flight (the
#: autopilot's own takeoff: PX4 ramps it over MPC_TKO_RAMP_T, ArduCopter spools up and climbs on
#: its takeoff command; its takeoff's reference is not held for it)
NATIVE_TAKEOFF_WAIT_S = 10.0
