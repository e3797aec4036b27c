"""Pure, explicitly discrete control laws: no I/O, no clocks, no sockets.

Classical ADRC (Han's TD + NLESO + NLSEF), linear ADRC (Gao's bandwidth form with the ZOH current
observer) and the PD baseline, each on one channel; the position controller (three channels and
the geometric map to attitude + thrust) and the attitude controller (three channels to torques).
The laws are the corrected forms of the thesis's equations; see the README.
"""

from .attitude import AttitudeController
from .channels import (PD, HanADRC, HanESO, LinearADRC, LinearESO, TrackingDifferentiator,
                       make_channel)
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
    "make_channel",
    "PositionController",
    "AttitudeController",
    "acceleration_to_attitude",
]
