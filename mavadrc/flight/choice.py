"""Which controller flies, with which gains: the mission's, or, while its vehicle is identified,
the safe default LADRC (after the takeoff's PID where the mission asks for one); made at the
rate flown and the hover thrust known, its kernels run once before it flies."""

import numpy as np

from mavadrc.control.learn import DragLearner
from mavadrc.design.gains import (
    MISSION_MARGIN_FLOOR,
    TAKEOFF_KIND,
    built,
    identification_gains,
    resolve_gains,
    run_once,
    slower_than,
    takeoff_gains,
)
from mavadrc.design.identify import (
    needs_identification,
    observer_dead_time,
    observer_drag,
    observer_lag,
)


class ControllerChoice:
    """The controller flown (``ctrl``), its gains and delay margin, the identification's
    record once made, and the rate and hover thrust it is made for."""

    def __init__(self, mission, kind, rate, hover, design_lag):
        self.m = mission
        self.kind = kind
        self.rate = rate  # the rate flown (the achieved one if lower)
        self.h = 1.0 / rate
        self.hover = hover
        # the lags of the vehicle the mission's own gains were chosen for (its vehicle file's
        # bundled model, identified in process by the caller before the flight:
        # mavadrc.fast.identify.flight_design_lag); None: the mission gives no gains of its own,
        # names no vehicle file, or identifies nothing
        self.design_lag = design_lag
        self.ctrl = None
        self.gains = None  # the controller's gains, resolved (resolve_gains)
        self.delay_margin = None  # of the controller flown, on the plant it assumes (s)
        # input_lag: auto: the fit of the identify segment (mavadrc.design.identify); until it is
        # made, the safe default LADRC flies
        self.identification = None
        self.gains_scaled = None  # scale_to_vehicle's factors, when they slowed the gains
        self.learner = None  # the drag learnt along the mission (mavadrc.control.learn)
        # an identifying flight's takeoff is flown, when the mission asks (controller: {takeoff:
        # pid}), by a PID (TAKEOFF_KIND) until the handover, then by the safe LADRC made beside it
        self.takeoff_pid = mission.controller.takeoff == "pid"
        self.after_takeoff = None
        self.takeoff_controller = None  # what flew the takeoff, for the summary

    def set_rate(self, rate):
        self.rate = rate
        self.h = 1.0 / rate

    def identifying(self):
        """Whether the input model is still to be identified (or could not be: then the safe
        defaults fly the whole mission)."""
        if not needs_identification(self.m.controller, self.kind):
            return False
        return self.identification is None or "input_lag" not in self.identification

    def flown(self):
        """(kind, gains) flown now: the mission's, or, while the input model is identified, the
        safe default LADRC (:data:`~mavadrc.design.gains.SAFE_WC`, no input model), after the
        takeoff's PID (:func:`~mavadrc.design.gains.takeoff_gains`) until its handover."""
        if self.identifying():
            if self.takeoff_pid:
                return TAKEOFF_KIND, takeoff_gains()
            return "ladrc", identification_gains()
        if self.gains is None:
            rec = self.identification
            self.gains = resolve_gains(
                self.m.controller, self.kind,
                identified=observer_lag(rec, self.m.controller) if rec else None,
                drag=observer_drag(rec) if rec else None,
                designed_for=self.design_lag if rec else None,
                dead_time=observer_dead_time(rec, self.m.controller) if rec else None,
                margin_floor=MISSION_MARGIN_FLOOR)
        return self.kind, self.gains

    def make(self, hover):
        """The controller flown now (:meth:`flown`) for ``hover`` thrust, made the one flown."""
        kind, gains = self.flown()
        self.ctrl, self.delay_margin = self.build(hover, kind, gains)
        if self.identifying() and self.takeoff_pid:
            # the safe LADRC that takes over from the takeoff's PID, made now (its margin is a
            # few hundred ms of kernels: not in the loop)
            self.after_takeoff = self.build(hover, "ladrc", identification_gains())
        self.learner = self.drag_learner(self.ctrl, gains)
        return self.ctrl

    def drag_learner(self, ctrl, gains):
        """The :class:`DragLearner` of the controller ``ctrl`` flown with ``gains`` (None: its
        drag stays as it is: ``drag_learn`` 0, the safe gains of the identification, or a
        controller without the drag in its model).  The identification's safe gains do not
        learn: along the doublets the observers' disturbance is mostly the missing input
        model, and the slope on the reference velocity read 0.7-1.0 /s there on PX4 SIH
        (its drag: 1.0), 0.82 on the bundled model of it."""
        tau = float(gains.get("drag_learn") or 0.0)
        if tau <= 0.0 or self.identifying() or not ctrl.models_drag:
            return None
        return DragLearner(ctrl.drag, tau)

    def build(self, hover, kind, gains):
        """The controller of ``kind`` with ``gains`` at the rate flown, its delay margin
        computed and every kernel of its step run once (compiled now, not mid-flight); at rest,
        waiting for its first sample."""
        ctrl, margin = built(self.m.controller, hover, kind, self.rate, gains)
        run_once(ctrl)
        return ctrl, margin

    def record(self):
        """The controller flown as a mission's ``controller:`` section (:func:`controller_record`);
        None if the gains could not be resolved."""
        try:
            kind, gains = self.flown()
        except Exception:
            return None
        return controller_record(self.m.controller, kind, gains)

    def note_scaling(self, gains):
        """``gains_scaled`` for the gains flown: the factor by which
        :func:`~mavadrc.design.gains.scale_to_vehicle` slowed the mission's own horizontal wc
        (``factor``) and wo (``wo_factor``, when the mission gives wo: 1 where the observers
        kept their bandwidth), the lags they were chosen for (``design_lag_s``, None: not
        known) and which rule slowed them (``because``: "slower", the vehicle is slower than
        those, and the need was the larger of the share they kept there and
        :data:`~mavadrc.design.gains.MISSION_MARGIN_FLOOR` of its lag; "margin", it is not, and
        the floor alone asked it); None: flown as given.  Returns it."""
        design, given = self.design_lag, self.m.controller.gains.get("wc")
        given_wo = self.m.controller.gains.get("wo")
        self.gains_scaled = None
        if self.kind == self.m.controller.kind and given is not None and "wc" in gains:
            f = float(gains["wc"][0]) / float(given[0])
            if f < 1.0:
                # (slowed only with input_lag: auto, resolved by then to the lags identified)
                slower = slower_than(gains["input_lag"], design)
                self.gains_scaled = {
                    "design_lag_s": None if design is None else [round(x, 4) for x in design],
                    "factor": round(f, 3),
                    "because": "slower" if slower else "margin"}
                if given_wo is not None and "wo" in gains:
                    self.gains_scaled["wo_factor"] = round(
                        float(gains["wo"][0]) / float(given_wo[0]), 3)
        return self.gains_scaled


def bandwidths(gains):
    """", wc (...), wo (...)" of ``gains`` for the console ("" without both)."""
    if "wc" not in gains or "wo" not in gains:
        return ""
    return (f", wc ({', '.join(f'{x:.2f}' for x in gains['wc'])}), wo "
            f"({', '.join(f'{x:.1f}' for x in gains['wo'])})")


def controller_record(spec, kind, gains):
    """A mission's ``controller:`` section that flies the controller flown: its kind, rate,
    limits and every gain resolved (plain lists and numbers, for YAML and JSON)."""
    rec = {"type": kind, "rate_hz": spec.rate_hz, "tilt_max_deg": spec.tilt_max_deg,
           "thrust_min": spec.thrust_min, "thrust_max": spec.thrust_max}
    if spec.thrust_tilt != "commanded":
        rec["thrust_tilt"] = spec.thrust_tilt
    if spec.takeoff != "safe" and kind in ("ladrc", "adrc"):
        rec["takeoff"] = spec.takeoff
    for k, v in (gains or {}).items():
        rec[k] = [float(x) for x in v] if isinstance(v, (tuple, list, np.ndarray)) else v
    return rec
