"""Pure, explicitly discrete control laws: no I/O, no clocks, no sockets.

Classical ADRC (Han's TD + NLESO + NLSEF), linear ADRC (Gao's bandwidth form with the ZOH current
observer), the PD baseline and a PX4-style cascaded PID, each on one channel; the position
controller (three channels and the geometric map to attitude + thrust) and the attitude controller
(three channels to torques); the rotations (quaternions, Euler angles) that these laws, the
bundled vehicle and the figures share.
The laws are the corrected forms of the thesis's equations; docs/thesis.md lists each
correction.
"""

from .attitude import AttitudeController
from .channels import (
                       PD,
                       PID,
                       HanADRC,
                       HanESO,
                       LinearADRC,
                       LinearESO,
                       TrackingDifferentiator,
                       make_channel,
)
from .geometry import acceleration_to_attitude
from .kernels import fal, fhan
from .position import PositionController

__all__ = [
    "fhan",
    "fal",
    "TrackingDifferentiator",
    "HanESO",
    "LinearESO",
    "HanADRC",
    "LinearADRC",
    "PD",
    "PID",
    "make_channel",
    "PositionController",
    "AttitudeController",
    "acceleration_to_attitude",
]
