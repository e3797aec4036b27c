"""A mission flown in process on the vehicle's compiled kernels, its input model identified
first where it asks for one (``input_lag: auto``)."""

from mavadrc.fast.identify import with_identified
from mavadrc.fast.inprocess import fly_resolved
from mavadrc.fast.native import fly_native


def fly_inprocess(mission, kind=None, seed=None, wind=None, vehicle_options=None):
    """Fly ``mission`` in process; returns an :class:`~mavadrc.fast.inprocess.InProcessRun`.

    ``kind``: the position controller ('pd', 'ladrc', 'adrc', 'pid', 'native': the vehicle's
    own position controller, :func:`~mavadrc.fast.native.fly_native`, or 'oracle': PD with the
    true disturbance fed forward); ``seed``/``wind`` override the mission's (as ``mavadrc fly``'s
    options do).  ``vehicle_options``: extra :class:`SimVehicle` keywords.  ``input_lag: auto``
    is measured first, on the same vehicle (:func:`~mavadrc.fast.identify.with_identified`).
    """
    kind = kind or mission.controller.kind
    if kind == "native":
        return fly_native(mission, seed, wind, vehicle_options)
    if kind != "oracle":
        mission = with_identified(mission, kind, mission.seed if seed is None else seed)
    return fly_resolved(mission, kind, seed, wind, vehicle_options)
