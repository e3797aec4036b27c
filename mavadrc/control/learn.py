"""The vehicle's horizontal drag, learnt in flight from what the observers are left to carry.

The observers take the drag along the reference velocity as a known input (``drag``), so their
disturbance estimate z3 keeps the rest: the wind, the drag of the tracking error, and whatever
part of the drag the model misjudged.  The doublets of ``input_lag: auto`` fit the drag together
with the lag; in closed loop the two trade against each other and the drag comes out scattered
(PX4 SIH, SIH_KDV 1 /s: 0.41-1.32 over 20 flights, following the lag fitted).  Along a mission
the reference moves for tens of seconds, and the observers' total disturbance

    D = z3 - c_model * v_ref  ~  b - c * v_ref + k * a_ref + noise

(``b`` the mean wind's push, ``k`` what is left of the acceleration's gain and lag) gives the
drag ``c`` itself as the slope on the reference velocity.  The regressors are the reference's
(noise-free, and not driven by the gusts), so the wind's turbulence is noise, not bias.  Replayed
on 19 logged PX4 SIH figure eights the slope read 0.95-1.05 /s after 10 s on north and east,
whatever the doublets had fitted.

:class:`DragLearner` keeps per axis the exponentially forgotten normal equations of that
regression (its memory ``tau_s``) and, once the reference velocity has moved enough apart from
the acceleration and the mean to tell the slope (:data:`MIN_INFORMATION`, over at least
:data:`MIN_SECONDS`), moves the controller's drag towards it at most :data:`RATE_PER_S2` per
second, so the feed-forward changes smoothly.  Only north and east: the vertical observer's
disturbance is the thrust estimate's (``thrust_estimate``), and a mission's vertical velocity
seldom moves enough.
"""

import math

import numpy as np

from mavadrc.control.position import DRAG_MAX

#: the default memory of the regression (s): a figure eight's half period and more
TAU_S = 10.0
#: the information on the slope before it is used: the reference velocity's spread (weighted
#: mean square apart from the mean and the acceleration, m^2/s^2) times the samples' weight (s):
#: as much as 0.3 m/s of spread over 5 s
MIN_INFORMATION = 0.45
#: and at least this many seconds of samples.  Sooner (1.5 s, 0.5 /s per s) the first
#: estimates of a figure eight's run-up scattered 0.6-1.6 /s (replayed on PX4 SIH flights) and
#: the bundled PX4 SIH model's figure eight flew 0.079 m against 0.062
MIN_SECONDS = 3.0
#: the most the controller's drag changes per second (1/s per s)
RATE_PER_S2 = 0.25
#: the axes learnt: north and east
AXES = (0, 1)


class DragLearner:
    """Learn the horizontal drag (1/s) from the observers' disturbance estimate.

    ``start``: (3,) the drag the controller flies now (the doublets', or the mission's);
    ``tau_s``: the regression's memory.  Call :meth:`step` once per control step with the
    controller; it sets the controller's drag (:meth:`PositionController.set_drag`) as it
    learns."""

    def __init__(self, start, tau_s=TAU_S):
        if not tau_s > 0.0:
            raise ValueError(f"the drag's memory must be positive (got {tau_s!r})")
        self.tau_s = float(tau_s)
        self.start = np.array(start, dtype=float).reshape(3)
        self.flown = self.start.copy()
        self._A = np.zeros((3, 3, 3))  # per axis: forgotten sum of x x^T, x = [1, v_ref, a_ref]
        self._b = np.zeros((3, 3))  # per axis: forgotten sum of x D
        self._w = 0.0  # forgotten sum of the samples' durations (s)
        self.estimate = np.full(3, math.nan)
        self.first_used_s = None  # mission time the slope was first used

    def _slope(self, i):
        """The drag on axis ``i`` from the normal equations (nan: not yet told)."""
        A = self._A[i]
        if self._w < MIN_SECONDS or A[0, 0] <= 0.0:
            return math.nan
        # the reference velocity's weighted spread apart from what the mean and the
        # acceleration explain: the slope's information per unit weight
        try:
            other = np.linalg.solve(A[np.ix_((0, 2), (0, 2))], A[(0, 2), 1])
        except np.linalg.LinAlgError:
            return math.nan
        spread2 = (A[1, 1] - A[1, (0, 2)] @ other) / A[0, 0]
        if not spread2 * self._w >= MIN_INFORMATION:
            return math.nan
        theta = np.linalg.solve(A, self._b[i])
        return float(min(max(-theta[1], 0.0), DRAG_MAX))

    def _observe(self, ctrl, dt, ref_vel, ref_acc):
        z3 = ctrl.z[:, 2]
        model = ctrl.drag
        lam = math.exp(-dt / self.tau_s)
        self._A *= lam
        self._b *= lam
        self._w = self._w * lam + dt
        for i in AXES:
            x = np.array([1.0, float(ref_vel[i]), float(ref_acc[i])])
            y = float(z3[i]) - float(model[i]) * x[1]
            if not (math.isfinite(y) and math.isfinite(x[1]) and math.isfinite(x[2])):
                continue
            self._A[i] += dt * np.outer(x, x)
            self._b[i] += dt * x * y
        for i in AXES:
            c = self._slope(i)
            if c == c:
                self.estimate[i] = c
        return model

    def step(self, ctrl, t, dt, ref_vel, ref_acc):
        """One control step of mission time ``t`` (s), ``dt`` after the last, at the reference
        velocity and acceleration the controller was given; updates ``ctrl``'s drag."""
        if not (dt is not None and 0.0 < dt < 1.0):
            return
        model = self._observe(ctrl, dt, ref_vel, ref_acc)
        changed = False
        for i in AXES:
            c = self.estimate[i]
            if c != c:
                continue
            step = RATE_PER_S2 * dt
            new = model[i] + max(-step, min(step, c - model[i]))
            if new != model[i]:
                model[i] = new
                changed = True
            if self.first_used_s is None:
                self.first_used_s = float(t)
        if changed:
            ctrl.set_drag(model)
            self.flown = model.copy()

    def record(self):
        """The summary's record: the drag flown at the end, the estimate, where it started."""
        def axes(v):
            return [None if not math.isfinite(x) else round(float(x), 4) for x in v[:2]]
        return {"per_s": axes(self.flown), "estimate_per_s": axes(self.estimate),
                "start_per_s": axes(self.start), "memory_s": self.tau_s,
                "first_used_s": None if self.first_used_s is None
                else round(self.first_used_s, 2)}
