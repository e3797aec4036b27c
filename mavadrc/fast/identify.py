"""The input model identified on the bundled vehicle in process (the fast path): what
`input_lag: auto` resolves to before a run, and the lags a mission's gains were chosen for."""

import numpy as np

from mavadrc.design.identify import (
    failure_text,
    fit_flight,
    needs_design_lag,
    needs_identification,
    observer_dead_time,
    observer_drag,
    observer_lag,
    summary_line,
    unidentified_axes,
)
from mavadrc.mission.identification import ALTITUDE, windows_in


def identification_mission(mission, calm=True):
    """``mission`` reduced to the identification: take off to :data:`ALTITUDE`, fly the
    doublets, on the safe default LADRC at the mission's rate and limits, in calm air (the rest
    of the vehicle's setting, its sensors, latency, link and seed, as the mission has them).
    The vehicle is its file as given: a mission that varies it (``sim: {mass_scale,
    motor_thrust_curve, attitude_bandwidth_scale}``, a robustness study) flies with the model
    identified before the change, as a vehicle loaded or worn after its identification would."""
    import dataclasses

    from mavadrc.design.gains import identification_gains
    from mavadrc.mission.config import ControllerSpec
    spec = mission.controller
    # told the vehicle's own hover thrust here, and the kernel cannot pause the learning over
    # the identify segment: it keeps the figure told
    ctrl = ControllerSpec(kind="ladrc", name="identification", rate_hz=spec.rate_hz,
                          gains=identification_gains(learn=False),
                          tilt_max_deg=spec.tilt_max_deg,
                          thrust_min=spec.thrust_min, thrust_max=spec.thrust_max,
                          thrust_tilt=spec.thrust_tilt)
    segments = [("takeoff", {"altitude": ALTITUDE, "speed": 0.5}, None),
                ("identify", {}, None)]
    return dataclasses.replace(mission, name=f"identification ({mission.name})",
                               segments=segments, controller=ctrl,
                               wind=None if calm else mission.wind, settle_s=0.0,
                               mass_scale=1.0, motor_thrust_curve=None,
                               attitude_bandwidth_scale=1.0, input_model_scale=1.0)



_CACHE = {}



def identify_inprocess(mission, seed=None):
    """Fly :func:`identification_mission` on the in-process fast path and fit it: the record of
    :func:`fit` for the vehicle ``mission`` flies (cached per vehicle setting)."""
    m = identification_mission(mission)
    seed = m.seed if seed is None else seed
    link = m.link
    key = (repr(m.vehicle), m.autopilot, m.attitude_controller, m.controller.rate_hz,
           m.controller.tilt_max_deg, m.controller.thrust_tilt, m.hover_thrust, m.noise,
           m.wander, m.wander_corner_hz, m.sensor_latency_s, repr(link), m.heading_deg,
           seed if (m.noise or m.wander or link is not None) else None)
    if key not in _CACHE:
        d, windows = samples_inprocess(m, seed)
        rec = fit_flight(d[:, 0], d[:, 1:4], d[:, 4:7], d[:, 7], windows,
                         "in process, on the bundled vehicle")
        _CACHE[key] = rec
    return _CACHE[key]



def samples_inprocess(m, seed=None):
    """The identify segment's samples of identification mission ``m`` flown on the in-process
    fast path, as a flight keeps them (rows: t, the acceleration applied, the velocity, the
    sample's age; :func:`fit_flight`'s columns), and its windows."""
    from mavadrc.fast.inprocess import L_ACC, L_AGE, L_T, L_VEL, fly_resolved
    run = fly_resolved(m, seed=seed)
    L = run.log
    d = np.column_stack([L[:, L_T], L[:, L_ACC:L_ACC + 3], L[:, L_VEL:L_VEL + 3], L[:, L_AGE]])
    return d, windows_in(run.phases)



def design_lag(mission):
    """The observers' lags (s per axis) of the vehicle a mission's gains were chosen for: its
    vehicle file's bundled model, identified in process as a flight identifies (calm air, no
    link, fresh samples; cached per vehicle); None when the mission names no vehicle file or
    the fit fails."""
    import dataclasses
    if mission.vehicle is None:
        return None
    m = dataclasses.replace(mission, link=None, sensor_latency_s=0.0, noise=False, wander=0.0)
    rec = identify_inprocess(m, 0)
    if "input_lag" not in rec or unidentified_axes(rec):
        return None
    return observer_lag(rec, dataclasses.replace(mission.controller,
                                                 gains={**mission.controller.gains,
                                                        "latency": 0.0}))



def with_identified(mission, kind=None, seed=None):
    """``mission`` with ``input_lag: auto`` replaced by the lags identified on its bundled
    vehicle (:func:`identify_inprocess`); the mission itself when it has nothing to identify.
    The record is kept as the mission's ``identification``."""
    import copy
    import dataclasses
    if not needs_identification(mission.controller, kind):
        return mission
    rec = identify_inprocess(mission, seed)
    if "input_lag" not in rec:
        raise RuntimeError(f"{mission.name}: {failure_text(rec)}: {summary_line(rec)}")
    from mavadrc.design.gains import resolve_gains
    spec = mission.controller
    kind = kind or spec.kind
    # the gains the flight resolves once it has identified (the defaults slowed to keep their
    # margin, where the spec gives none), then the model scaled (a robustness study's error)
    gains = resolve_gains(spec, kind, identified=observer_lag(rec, spec),
                          drag=observer_drag(rec), dead_time=observer_dead_time(rec, spec))
    for key in ("input_lag", "input_dead_time"):
        if key in gains:
            gains[key] = tuple(mission.input_model_scale * x for x in gains[key])
    m = copy.copy(mission)
    m.controller = dataclasses.replace(spec, kind=kind, gains=gains)
    m.identification = rec
    return m


def flight_design_lag(mission, kind=None):
    """The design lag a flight of ``mission`` as ``kind`` needs, found before it starts
    (:func:`design_lag`; it flies the vehicle file in process, which compiles the simulation's
    kernels on a first run: made after the doublets it held the fit's thread while the safe gains
    flew the mission, 0.8 m off on PX4 SIH, and in lockstep starved the vehicle past the
    telemetry timeout).  None where the flight identifies nothing or the mission gives no gains
    of its own."""
    if not needs_design_lag(mission.controller, kind):
        return None
    return design_lag(mission)
