"""The simulated vehicle's own autopilot loops, as a PX4-like flight controller has them.

- :mod:`.attitude`: the inner loop (every physics step by default): attitude + normalized thrust
  setpoint -> torques (PX4-like quaternion/rate PID, or the thesis's ADRC/LADRC/PD channels)
  -> mixer -> rotor speed commands;
- :mod:`.mixer`: collective thrust + torques -> rotor speeds with airmode-like saturation;
- :mod:`.position`: the position/velocity cascade, the land detector and the takeoff / hold /
  land modes.

Kernels are numba functions over flat float arrays (one row per vehicle in a batch); the classes
are thin holders.  :class:`sim.vehicle.SimVehicle` wires them to the physics.
"""

from .attitude import KINDS, firmware_params, px4_gains
from .mixer import Mixer, mixer_params
from .position import Navigator, position_params

__all__ = ["KINDS", "firmware_params", "px4_gains", "Mixer", "mixer_params", "Navigator",
           "position_params"]
