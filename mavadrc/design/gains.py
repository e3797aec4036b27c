"""The gain policy: the gains a controller flies with, from the mission's spec, the safe defaults,
the vehicle identified and the delay margin they must keep; the controller made from them."""
import math
import time

import numpy as np

from mavadrc.control.learn import TAU_S as DRAG_LEARN_S
from mavadrc.control.native import NativeController
from mavadrc.control.position import THRUST_ESTIMATE_S, PositionController
from mavadrc.design.identify import (
    ORDER,
    failure_text,
    fit_flight,
    observer_dead_time,
    observer_drag,
    observer_lag,
    response_margin,
)
from mavadrc.design.margin import delay_margin, margin_record
from mavadrc.errors import FlightError

#: observer-based controllers with no input model: bandwidths whose linearised loop is stable
#: on every vehicle whose acceleration answers a command with a first-order lag of 0.03-0.30 s
#: plus 0-50 ms of delay, sampled at 50-250 Hz (mavadrc.design.margin; a test sweeps the family).
#: Faster ones limit-cycled on PX4 SIH and ArduCopter SITL (wc 2.5, wo 12.5: +-21-34 deg).
SAFE_WC = 1.0



SAFE_WO = 4.0



def default_gains(kind, input_model=False):
    """Position-loop gains (per axis x, y, z).  LADRC and ADRC: told the vehicle's response
    (``input_model``: the mission gives ``input_lag``), gains that suit the bundled vehicles;
    not told, the slower ones that are safe on any vehicle of the family above."""
    if kind in ("ladrc", "adrc"):
        # both learn the hover thrust in flight (THRUST_ESTIMATE_S)
        g = {"thrust_estimate": THRUST_ESTIMATE_S}
        if kind == "adrc":
            # The mission's trajectory comes with exact derivatives, so the TD (which would add
            # lag to a moving reference) is off unless the mission asks for it (td: true).
            g.update(td=False, r=(8.0, 8.0, 8.0), c=(1.0, 1.0, 1.0), delta=(0.05, 0.05, 0.05))
        if not input_model:
            return {**g, "wc": (SAFE_WC,) * 3, "wo": (SAFE_WO,) * 3}
        told = (12.5, 12.5, 15.0) if kind == "ladrc" else (12.0, 12.0, 15.0)
        return {**g, "wc": (2.5, 2.5, 3.0), "wo": told}
    if kind == "native":
        return {}  # the autopilot's own position controller: its parameters, not ours
    if kind == "pid":
        # the PD default's bandwidth plus an integrator (channels.pid_gains): kp_pos = wc/2,
        # kp_vel = 2 wc, ki_vel = wc^2/2, no D, i.e. kp_pos (1.25, 1.25, 1.5) /s, kp_vel
        # (5, 5, 6) /s, ki_vel (3.125, 3.125, 4.5) /s^2; integrator authority 3 m/s^2
        return {"wc": (2.5, 2.5, 3.0), "i_limit": (3.0, 3.0, 3.0)}
    return {"wc": (2.5, 2.5, 3.0)}



def identification_gains(learn=True):
    """The gains that fly the takeoff and the identification's doublets (and, when the fit
    fails, the rest of the mission): the safe default LADRC; a mission that asks for the
    takeoff's PID (:func:`takeoff_gains`) has them take over from it, and its thrust learnt,
    before the doublets.  ``learn``: it learns the hover thrust in the takeoff,
    paused over the identify segment (the flight pauses it there: the
    fit needs the map from commanded to produced acceleration to hold still over its window;
    learnt through the vertical doublets, on PX4 SITL the vertical fit once came out with gain
    -8 and was rejected).  Kept at the figure told through the takeoff, a vehicle heavier than
    told was identified on a map that turned each horizontal command into 0.69 of it (PX4 SIH
    40 % heavier than its MPC_THR_HOVER: the vertical observer carried the missing weight, so
    the tilt asked for was 1/1.4 of the one meant): the record (its gains, the drag the leg
    reads through them) described a map the mission's controller, learning the thrust from its
    first step, no longer flew."""
    learning = THRUST_ESTIMATE_S if learn else 0.0
    return {**default_gains("ladrc", False), "thrust_estimate": learning}



#: what flies the takeoff of a flight that identifies its vehicle (``input_lag: auto``) when the
#: mission asks for it (``controller: {takeoff: pid}``; by default the safe LADRC does): PX4's
#: cascade, a PID on the measured velocity (:func:`takeoff_gains`).  Reading the velocity
#: measured, not estimated from the position, it keeps more delay margin than the safe LADRC on
#: every plant of the family above (50 ms at its worst corner, a lag of 0.30 s and 50 ms of
#: delay, where SAFE_WC keeps none; 70 ms on PX4 SIH's response, two lags of 0.074 s after 0.076
#: s of dead time, against 60), and it stands stiffer against the wind that meets the vehicle as
#: it leaves the ground: lifting off into 5 m/s of wind, the bundled ``arducopter_quad`` drifted
#: 0.19 m on the safe LADRC and 0.07 m on it (lockstep), ArduCopter SITL 0.69-0.70 m and
#: 0.24-0.25 m in its own wind.  But it trusts the velocity estimate: on PX4 SIH, whose EKF2
#: velocity ran the wrong way for seconds in the climb, it drifted 0.08-0.78 m by SIH's truth
#: where the safe LADRC, reading the position only, drifted 0.15-0.23, so it is not the
#: default.  The doublets are flown on the safe LADRC (:func:`identification_gains`), which
#: takes over :data:`mavadrc.mission.identification.TAKEOFF_HANDOVER_S` before the fit's first sample: the
#: drag leg's reading is calibrated on it (flown on this PID, the leg read PX4 SIH's drag of
#: 1.0 /s as 0.93 in process, and the slowed defaults flew the spiral 0.15 m off for 0.017).
TAKEOFF_KIND = "pid"



TAKEOFF_WC = (2.0, 2.0, 3.0)



def takeoff_gains():
    """The gains of :data:`TAKEOFF_KIND` that fly the takeoff of a flight that identifies its
    vehicle: the default PID's structure at :data:`TAKEOFF_WC`, learning the hover thrust from
    its vertical integrator as the observers learn it from their z3 (the safe LADRC that takes
    over adopts what it learnt)."""
    return {**default_gains("pid"), "wc": TAKEOFF_WC, "thrust_estimate": THRUST_ESTIMATE_S}



def drag_learn_memory(spec, kind=None):
    """The memory (s) with which a controller spec flown as ``kind`` learns the horizontal drag
    in flight (:mod:`mavadrc.control.learn`): its ``drag_learn``, else :data:`DRAG_LEARN_S` where the
    drag is ``auto`` (the default with ``input_lag: auto``), else 0 (not learnt)."""
    kind = kind or spec.kind
    if kind not in ("ladrc", "adrc"):
        return 0.0
    g = spec.gains
    if "drag_learn" in g:
        return float(g["drag_learn"])
    drag = g.get("drag", "auto" if g.get("input_lag") == "auto" else None)
    return DRAG_LEARN_S if drag == "auto" else 0.0



def resolve_gains(spec, kind=None, vehicle=None, attitude_controller="px4", identified=None,
                  drag=None, designed_for=None, dead_time=None, margin_floor=0.0):
    """The gains a controller spec flies as ``kind``, in the mission's own terms (``wc``,
    ``wo``, ``input_lag``, ...): the defaults, overridden by the spec's gains where it is of
    that kind (another kind, ``--controller``, flies the defaults, keeping only the vehicle's
    ``input_lag``), the observer's bandwidth derived from the controller's where only that is
    given, and ``input_lag: auto`` replaced by the lags ``identified`` on the vehicle
    (:mod:`mavadrc.design.identify`), ``drag: auto`` (its default with ``input_lag: auto``) by the
    ``drag`` identified with them (None: none).  The mission's own ``wc`` and ``wo`` with
    ``input_lag: auto`` are slowed by :func:`scale_to_vehicle` when the vehicle identified is
    slower than the one they were chosen for (``designed_for``: its lags; None: not known),
    and, whatever they were chosen for, until they keep ``margin_floor`` of the horizontal lag
    as delay margin (a flight passes :data:`MISSION_MARGIN_FLOOR`; the fast path, which
    studies the gains as given, 0).
    ``dead_time`` (s per axis, with ``identified``): the observers' input model is shaped as
    identified, that dead time and :data:`mavadrc.design.identify.ORDER` equal lags sharing the rest
    of the 63 % time (``input_dead_time``, ``input_lags``); the rules that slow the gains judge
    them on the one-lag model they were calibrated on.  Given as a mission's controller, they
    fly the same controller again.  ``vehicle`` and ``attitude_controller`` are not read (kept for callers)."""
    kind = kind or spec.kind
    # an axis the identification could not fit (None): flown on the safe gains with no model
    safe = [] if identified is None else [i for i, x in enumerate(identified) if x is None]
    if safe:
        identified = tuple(0.0 if x is None else x for x in identified)
    given = dict(spec.gains) if kind == spec.kind else {}
    if kind in ("ladrc", "adrc"):
        # the vehicle's response and the samples' age, not gains: they hold for any observer
        # flown on it
        for key in ("input_lag", "latency", "drag", "drag_learn", "predict"):
            if key in spec.gains:
                given.setdefault(key, spec.gains[key])
        if given.get("input_lag") == "auto":
            given.setdefault("drag", "auto")
        tau = drag_learn_memory(spec, kind)
        if tau > 0.0:  # the doublets' drag is a start: learnt along the mission (mavadrc.control.learn)
            given.setdefault("drag_learn", tau)
    lag = given.get("input_lag")
    told = lag == "auto" or (lag is not None and any(float(v) > 0.0 for v in lag))
    gains = default_gains(kind, told)  # the mission's gains, where given, override these
    gains.update(given)
    if kind in ("ladrc", "adrc") and "wc" in given and "wo" not in given:
        # the observer at the defaults' ratio to the controller given
        ratio = 5.0 if told else SAFE_WO / SAFE_WC
        gains["wo"] = tuple(ratio * float(w) for w in given["wc"])
    if identified is not None and gains.get("drag") == "auto":
        # None: the identification gave lags only (a caller's), no drag to model
        gains["drag"] = (0.0,) * 3 if drag is None else tuple(float(x) for x in drag)
    if gains.get("input_lag") == "auto" and identified is not None \
            and kind in ("ladrc", "adrc") and ("wc" in given or "wo" in given):
        gains, _ = scale_to_vehicle(
            spec, kind, gains, tuple(float(x) for x in identified),
            None if designed_for is None else tuple(float(x) for x in designed_for), dead_time,
            floor=margin_floor)
    shaped = gains.get("input_lag") == "auto" and identified is not None and \
        dead_time is not None
    if gains.get("input_lag") == "auto" and identified is not None and kind in ("ladrc", "adrc") \
            and "wc" not in given and "wo" not in given:
        # the fast defaults were chosen for the bundled vehicles (63 % in 0.125 s); on a slower
        # vehicle they are slowed until the loop keeps its margin
        gains = fit_to_margin(spec, kind, gains, tuple(float(x) for x in identified),
                              dead_time)
    if gains.get("input_lag") == "auto":
        if identified is None:
            raise FlightError("input_lag: auto is measured on the vehicle flown: in flight (the "
                              "mission flies an identify segment after its takeoff), by "
                              "mavadrc.fast.identify.with_identified on the fast path, or by "
                              "`mavadrc identify`; otherwise give the lags in seconds")
        gains["input_lag"] = tuple(float(x) for x in identified)
    if shaped and kind in ("ladrc", "adrc"):
        # (after the rules above, which judge the gains on the one-lag model)
        gains["input_dead_time"] = tuple(min(float(d), float(x))
                                         for d, x in zip(dead_time, identified))
        gains["input_lags"] = ORDER
    if safe and kind in ("ladrc", "adrc"):
        gains = _safe_axes(gains, safe)
    return gains



def _safe_axes(gains, axes):
    """``gains`` with the axes ``axes`` (indices) flown as the safe default LADRC flies them
    (:data:`SAFE_WC`, :data:`SAFE_WO`, no input model, no drag): stable on any response of
    0.03-0.3 s with no model (docs/controllers.md)."""
    out = dict(gains)
    for key, value in (("wc", SAFE_WC), ("wo", SAFE_WO), ("input_lag", 0.0),
                       ("input_dead_time", 0.0), ("drag", 0.0)):
        if key in out and not isinstance(out[key], str):
            row = [float(x) for x in np.broadcast_to(np.asarray(out[key], dtype=float), 3)]
            for i in axes:
                row[i] = value
            out[key] = tuple(row)
    return out



#: the share of the identified horizontal lag the default gains keep as delay margin (on the
#: single-lag model the observers fly).  Calibrated on PX4 SIH (63 % in 0.25-0.27 s, a response
#: of two lags and a dead time, slower at 1 Hz than one lag): wc 2.5 / wo 12.5, a margin of 23 %
#: of the lag, swung +-13 deg; wc 1.5 (50 %) 4-5 deg; wc 1.24 (64 %) about 4 deg; this share
#: gives it wc 1.09 / wo 5.45.  The bundled vehicles (0.125 s) get wc 2.0-2.2.
MARGIN_SHARE = 0.75



def built(spec, hover, kind, rate, gains):
    """The controller of ``kind`` with ``gains`` at ``rate`` (Hz) and its delay margin (None
    for ``native``: the autopilot's loop, whose margin the companion does not know)."""
    ctrl = make_controller(spec, hover_thrust=hover, kind=kind, rate_hz=rate, gains=gains)
    return ctrl, delay_margin(ctrl)



def run_once(ctrl):
    """Every kernel of ``ctrl``'s step, and of what the record reads of it each step (its
    estimates; ADRC's TD outputs), run once: compiled or loaded now, not mid-flight.  (The TD's
    read was not: on PX4 SIH a first ADRC flight compiled it at the mission's first sample and
    answered the next 28 samples up to 0.32 s late.)  It is left at rest, waiting for its first
    sample."""
    ctrl.reset(np.zeros(3))
    ctrl.update(np.zeros(3), np.zeros(3), np.zeros(3))
    ctrl.z
    if ctrl.kind == "adrc":
        ctrl.td
    ctrl.reset()



def fit_and_make(d, windows, flown, spec, kind, rate, hover, designed_for, drag=None,
                 margin_floor=0.0):
    """The fit of an identify segment's samples ``d`` (rows: t, the acceleration applied, the
    velocity, the sample's age; ``windows`` and ``flown`` as :func:`fit_flight` takes them;
    ``drag``: known per axis, else fitted) and, if it holds, the controller of ``kind`` that
    ``spec`` makes with it at ``rate`` (``designed_for``: the lags the spec's own gains were
    chosen for, :func:`design_lag`; ``margin_floor`` as :func:`resolve_gains` takes it):
    (record, controller or None, gains, delay margin).  The
    record says how long the fit took (``fit_s``) and the whole of it, the controller and its
    margins made (``made_in_s``).  Whole in the fits' own process in real time: the margins
    are a few hundred ms of kernels that would hold the loop's interpreter too."""
    t0 = time.perf_counter()
    rec = fit_flight(d[:, 0], d[:, 1:4], d[:, 4:7], d[:, 7], windows, flown, drag=drag)
    rec["fit_s"] = rec["made_in_s"] = round(time.perf_counter() - t0, 3)
    if failure_text(rec) is not None:
        return rec, None, None, None
    gains = resolve_gains(spec, kind, identified=observer_lag(rec, spec),
                          drag=observer_drag(rec), designed_for=designed_for,
                          dead_time=observer_dead_time(rec, spec), margin_floor=margin_floor)
    ctrl, margin = built(spec, hover, kind, rate, gains)
    rec["delay_margin_s"] = margin_record(response_margin(ctrl, rec, spec))
    # what the rules that slow the gains (and Flight._identified's warning) judge: the same
    # gains with one lag of the 63 % time, as they were calibrated
    one = {k: v for k, v in gains.items() if k not in ("input_dead_time", "input_lags")}
    rec["delay_margin_one_lag_s"] = margin_record(delay_margin(make_controller(
        spec, hover_thrust=0.5, kind=kind, rate_hz=rate, gains=one)))
    rec["made_in_s"] = round(time.perf_counter() - t0, 3)
    return rec, ctrl, gains, margin



#: a vehicle identified slower than the one a mission's gains were chosen for by more than the
#: identification's accuracy (tested within 15 %) may fly them slowed (scale_to_vehicle)
SCALE_TOLERANCE = 1.15



#: the share of the identified horizontal lag a mission's own gains keep as delay margin on a
#: vehicle slower than theirs, when they kept at least that on their own.  Chosen on PX4 SIH
#: (0.24-0.27 s): the spiral's wc 4 (32 % on the Crazyflie) kept 11 % there and flew 0.37-0.50 m
#: at the tilt limit; x500_gusts' wc 2 kept 36-38 % (with its wo 10 of then).  At that share
#: both swung +-6-10 deg at 1 Hz there (the flights' own attitude_oscillation; an earlier
#: reading by hand had said 2.3-2.4): the loop answering the estimate's noise, and slowing them further (wc 1.6) traded
#: the swing for a slow error twice as large (docs/results.md).
MISSION_MARGIN_SHARE = 0.35



#: the share of the identified horizontal lag a mission's own gains keep as delay margin in a
#: flight, whatever they were chosen for: a mission that names the vehicle flown as its own (or
#: none) is never "slower than its design", and without this floor flew any gains it gave.  On
#: real PX4 SIH (0.25-0.27 s) thesis_spiral_wind's wc 4 named for its quad kept 30 ms (11 %) and
#: swung +-38.8 deg at 1.16 Hz, a limit cycle (0.30 m); held to 20 % (wc 2.87) it still swung
#: +-17.9 deg (0.29 m), where the bundled model had flown that 20 % at +-1.5 deg.  At 30 % (wc
#: 2.28) it keeps about what the shipped spiral keeps there by the rule above (32 %: wc 2.28,
#: 0.075 m, +-8.4 deg).  Under the 32.7 % the spiral keeps on its own Crazyflie: the shipped
#: missions on their own vehicles fly as given.  A rule of flight, as the slowing for a slower
#: vehicle is: the fast path (compare, tune, the robustness study) flies the gains as given, to
#: show where they break.
MISSION_MARGIN_FLOOR = 0.3



def _judged(gains, lag, dead_time):
    """``gains`` with the input model ``lag`` (s per axis) that the rules below judge them on:
    the single lag they were calibrated on, or for a law that predicts (``predict``) the shape
    identified (``dead_time`` s per axis, None: not known; :data:`mavadrc.design.identify.ORDER` lags),
    which it flies: its prediction, exact for the one lag, leaves a dead time and two lags less
    margin (PX4 SIH, the spiral's wc 4: 90 ms on the one lag, 50 on the shape)."""
    out = {**gains, "input_lag": tuple(lag)}
    if gains.get("predict") and dead_time is not None:
        out["input_dead_time"] = tuple(min(float(d), float(x)) for d, x in zip(dead_time, lag))
        out["input_lags"] = ORDER
    return out



def slower_than(lag, design):
    """Whether a vehicle answering with the lags ``lag`` (s per axis) is slower horizontally than
    the one whose lags are ``design`` (None: not known, never) by more than the identification's
    accuracy (:data:`SCALE_TOLERANCE`)."""
    if design is None:
        return False
    quick = max(design[0], design[1])
    return quick > 0.0 and max(lag[0], lag[1]) > SCALE_TOLERANCE * quick



def margin_need(spec, kind, gains, lag, design, floor):
    """The delay margin (s) a mission's own ``gains`` must keep on a vehicle whose lags are
    ``lag``: ``floor`` (a share) of its horizontal lag, whatever the ``design`` (None: not
    known), and on a vehicle slower than their design (:func:`slower_than`) the share of the
    lag they kept on their own vehicle, up to :data:`MISSION_MARGIN_SHARE`, where that is more."""
    slow = max(lag[0], lag[1])
    need = floor * slow
    if slower_than(lag, design):
        quick = max(design[0], design[1])
        own = delay_margin(make_controller(spec, hover_thrust=0.5, kind=kind,
                                           gains={**gains, "input_lag": tuple(design)}))
        need = max(need, min(own / quick, MISSION_MARGIN_SHARE) * slow)
    return need



def scale_to_vehicle(spec, kind, gains, lag, design, dead_time=None, keep_observers=True,
                     floor=0.0):
    """The mission's ``wc`` and ``wo`` (chosen for a vehicle whose lags are ``design``, s per
    axis) for one whose lags are ``lag``.  Where the horizontal lag exceeds the design's by more
    than :data:`SCALE_TOLERANCE`, the gains must keep, as a share of the lag, the delay margin
    they had on their own vehicle, up to :data:`MISSION_MARGIN_SHARE`; on any vehicle (``design``
    None: not known) at least ``floor`` of it (:func:`margin_need`); if they do not, the
    horizontal ``wc`` and ``wo`` are scaled down by one factor until they do (the loop designed,
    in slower time: a loop whose gains and plant lag scale together is the same loop, time
    stretched, with the same margin as a share of the lag).  Then the observers get their own
    bandwidth back: they model the lag (``input_lag``), so what the lag limits is the
    feedback's bandwidth, not theirs, and a faster observer lags the loop less, so ``wo``
    is flown as given wherever that keeps at least the stretched loop's margin (on PX4 SIH's
    response the spiral's wc 2.1 keeps 100 ms on one lag with its own wo 23.9, 90 with wo
    slowed to 12.6, and it answers the estimate's wander less; ``keep_observers`` False scales
    ``wo`` with ``wc`` as before).  Never faster
    than given; the vertical loop, which answers through the thrust in 0.01-0.1 s on every
    vehicle flown, is left as given.  Returns (gains, the horizontal factor of ``wc``: 1 when
    left as given)."""
    def scaled(f, keys=("wc", "wo")):  # the horizontal wc (and wo) times f
        return {**gains, **{key: tuple(round(f * float(w), 3) if i < 2 else float(w)
                                       for i, w in enumerate(gains[key]))
                            for key in keys}}

    def margin(f, plant, dead=None, keys=("wc", "wo")):
        g = _judged(scaled(f, keys), plant, dead)
        return delay_margin(make_controller(spec, hover_thrust=0.5, kind=kind, gains=g))

    need = margin_need(spec, kind, gains, lag, design, floor)
    if need <= 0.0 or margin(1.0, lag, dead_time) >= need:
        # (no need, as on the fast path on the vehicle named: no margin computed)
        return gains, 1.0
    lo, hi = 0.05, 1.0
    while hi - lo > 0.02:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if margin(mid, lag, dead_time) >= need else (lo, mid)
    f = round(lo, 3)
    if keep_observers and margin(f, lag, dead_time, ("wc",)) >= margin(f, lag, dead_time):
        return scaled(f, ("wc",)), f
    return scaled(f), f



def fit_to_margin(spec, kind, gains, lag, dead_time=None):
    """``gains`` (with ``wc`` and ``wo``) as they are if the controller's delay margin on the
    plant ``lag`` (s per axis, the observers' input model) is at least :data:`MARGIN_SHARE` of
    the horizontal lag; else both bandwidths scaled down by one factor until it is (bisection,
    to 2 %).  Returns the gains flown, with ``input_lag`` set to ``lag``.  A law that predicts
    is judged on the shape identified (``dead_time``; :func:`_judged`)."""
    base = {**gains, "input_lag": tuple(lag)}
    need = MARGIN_SHARE * max(lag[0], lag[1])

    def scaled(f):
        return {**base, "wc": tuple(round(f * float(w), 3) for w in gains["wc"]),
                "wo": tuple(round(f * float(w), 3) for w in gains["wo"])}

    def holds(f):
        c = make_controller(spec, hover_thrust=0.5, kind=kind,
                            gains=_judged(scaled(f), lag, dead_time))
        return delay_margin(c) >= need

    if holds(1.0):
        return base
    lo, hi = 0.05, 1.0
    while hi - lo > 0.02:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return scaled(round(lo, 3))



def make_controller(spec, hover_thrust=None, mass=None, max_thrust=None, kind=None,
                    vehicle=None, attitude_controller="px4", rate_hz=None, gains=None):
    """The position controller of a mission's controller spec (``input_lag: auto`` resolved
    before: :func:`mavadrc.fast.identify.with_identified`); ``rate_hz`` overrides the spec's rate;
    ``gains``: those of :func:`resolve_gains`, already resolved."""
    kind = kind or spec.kind
    if kind == "native":
        return NativeController(hover_thrust if hover_thrust is not None else 0.5,
                                math.radians(spec.tilt_max_deg), 1.0 / (rate_hz or spec.rate_hz))
    gains = dict(gains if gains is not None else
                 resolve_gains(spec, kind, vehicle, attitude_controller))
    if kind == "pd" and "kp" in gains and "wc" in gains:
        gains.pop("wc")
    # pid: wc gives every gain (channels.pid_gains); kp_pos, kp_vel, ki_vel, kd_vel given by the
    # mission replace those one by one, so PX4-style gains can be given in full or in part
    if kind == "adrc":
        # bandwidth shorthand: NLSEF fhan(e1, c e2, r, h1) is linear near zero with kp = 1/h1^2,
        # kd = 2c/h1, so h1 = 1/wc.  The NLESO corrects with beta01 e, beta02 fal(e, 1/2, delta)
        # and beta03 fal(e, 1/4, delta); inside fal's linear zone (|e| < delta) fal(e, a, delta)
        # = e delta^(a - 1), so the gains of a triple pole at -wo there are (3 wo,
        # 3 wo^2 delta^(1/2), wo^3 delta^(3/4))
        wc = gains.pop("wc", None)
        if wc is not None:
            gains.setdefault("h1", tuple(1.0 / w for w in wc))
        wo = gains.pop("wo", None)
        if wo is not None:
            delta = gains.get("delta")
            if delta is None:  # the NLESO's default zone: one sample period
                delta = 1.0 / (rate_hz or spec.rate_hz)
            delta = np.broadcast_to(np.asarray(delta, dtype=float), 3)
            gains.setdefault("beta", tuple((3.0 * w, 3.0 * w * w * d ** 0.5, w ** 3 * d ** 0.75)
                                           for w, d in zip(wo, delta)))
    gains.pop("drag_learn", None)  # the flight's (mavadrc.control.learn), not the controller's
    learn = gains.pop("thrust_estimate", 0.0)
    if learn:
        gains["thrust_estimate_tau"] = float(learn)
    accel_max = gains.pop("accel_max", None)
    if accel_max is not None:
        gains["u_min"] = tuple(-a for a in accel_max)
        gains["u_max"] = tuple(accel_max)
    thrust = {"hover_thrust": hover_thrust} if hover_thrust is not None else \
        {"mass": mass, "max_thrust": max_thrust}
    return PositionController(kind, h=1.0 / (rate_hz or spec.rate_hz),
                              tilt_max=math.radians(spec.tilt_max_deg),
                              thrust_min=spec.thrust_min, thrust_max=spec.thrust_max, **thrust,
                              **gains)


_SPEC_MARGINS = {}



def spec_margin(spec, kind=None, vehicle=None, attitude_controller="px4"):
    """:func:`delay_margin` of a mission's controller spec (cached: an experiment asks for the
    same few controllers in every run)."""

    key = (repr(spec), kind, repr(vehicle), attitude_controller)
    if key not in _SPEC_MARGINS:
        ctrl = make_controller(spec, hover_thrust=0.5, kind=kind, vehicle=vehicle,
                               attitude_controller=attitude_controller)
        _SPEC_MARGINS[key] = margin_record(delay_margin(ctrl))
    return _SPEC_MARGINS[key]
