"""The vehicle's input model, identified from flight data (``input_lag: auto``).

The observers of LADRC and ADRC predict with the acceleration they command; a real vehicle
produces it late (its attitude loop, its motors, the age of the samples).  How late is measured
on the vehicle being flown, never read from a model of it:

1. the vehicle takes off and hovers on the safe default gains (:data:`mavadrc.design.gains.SAFE_WC`,
   no input model; or, when the mission asks, takes off on a PID on the measured velocity,
   :data:`mavadrc.design.gains.TAKEOFF_KIND`, which hands it over to them before the doublets); both
   hold on any vehicle of the family docs/vehicle.md describes;
2. it flies acceleration doublets about the hover point, one axis after the other
   (:class:`mavadrc.mission.trajectories.Doublets`: +-2 m/s^2 horizontally, about 11 deg of tilt, and
   +-1 m/s^2 vertically, 0.4 s each way, 0.32 m and 0.16 m of excursion; 12.6 s), then a drag
   leg out and back diagonally at :data:`LEG_SPEED` (8.2 s), tracked as a reference, so the
   commands are mostly the doublets; then it holds still :data:`HANDOVER_S` while the fit is
   made (23.8 s in all);
3. per axis a model of how the commanded acceleration ``u`` (the limited command, held between
   samples) becomes the vehicle's, ``a(t) = k L(u(t - d)) - c v + b(t)``, is fitted to the
   measured velocity ``v``: ``L`` two equal first-order lags ``tau`` (the attitude loop and the
   motors; one lag fits the bundled vehicles' higher-order response worse), ``d`` a dead time,
   ``k`` a gain, ``c`` a linear drag and ``b(t)`` a disturbance drifting as a polynomial of
   degree :data:`POLY` over the axis's window (wind; gusts slower than the doublets).  The
   model's acceleration is integrated and compared with the velocity samples, every linear
   term solved by least squares for each (tau, d), which are searched on a grid and refined.
   Working on velocity, not a differentiated acceleration, keeps sensor noise from being
   amplified.  Without the drag term the fit mistakes the drag's growing push for a faster
   response (on the bundled Crazyflie: a lag of 0.10 s against a true 63 % time of 0.128 s);
   with a constant disturbance only, turbulence spoils it (x500 in moderate gusts: 0.03-0.15
   s scattered; with the drifting one, 0.124-0.130 s).  The drag ``c`` trades against the lag
   along the doublets (PX4 SIH: 0.46-1.35 /s for its 1.0 from flight to flight); at constant
   speed on the leg it does not, and the fit ties it to the gain as the leg reads it
   (:func:`leg_reading`).

The observers' input model is then the single lag with the fitted response's 63 % time,
``d + 2.146 tau`` (the first-order lag it has always been).  How that time splits into lag and
dead time is not unique for a response that is neither, so the record keeps every figure of the
fit.  ``mavadrc identify`` flies only this and writes the result as a controller section.
"""

import math

import numpy as np

from mavadrc.control.jit import jit
from mavadrc.control.position import LAG63

#: the legs' speeds must differ by this much (m/s) on an axis for its drag to be read there
LEG_MIN_DV = 0.5
#: how long before a cruise window the commands are run through the model (s), from rest
LEG_SETTLE_S = 1.0
#: the fit: dead times searched (s), lags searched (s), the integration grid (s)
MAX_DELAY_S = 0.3
TAU_RANGE_S = (0.005, 1.0)
FINE_S = 0.001
#: below this share of the velocity's variance explained the fit is not trusted
MIN_R2 = 0.9
#: a gain outside this range says the commands are not what the vehicle does (a wrong hover
#: thrust, a saturated axis): the fit is not trusted either
GAIN_RANGE = (0.5, 2.0)
#: the lag's order: 1 (tau + d is the 63 % time) or 2 (two equal lags: d + 2.146 tau)
ORDER = 2
#: the disturbance's polynomial degree over an axis's window (0: constant)
POLY = 4

AXES = ("x", "y", "z")



def _shifted_hold(t, u, grid, d):
    """The commands ``u`` (held from each sample time ``t`` to the next), seen ``d`` s late, on
    ``grid``."""
    i = np.searchsorted(t, grid - d, side="right") - 1
    return u[np.clip(i, 0, len(u) - 1)]


class _AxisFit:
    """Least squares of one axis for given (tau, d)."""

    def __init__(self, t, u, v, t0, t1, drag=None, leg=None):
        self.t, self.u = t, u
        self.window = (t0, t1)
        self.drag = None if drag is None else float(drag)  # fixed (1/s), or fitted (None)
        # the drag leg's cruises [(t0, t1, mean speed, acceleration)] (leg_reading), when the
        # drag is not fixed: c = k s1 - s0 with s1 from the commands as the model sees them
        self.leg = None
        if leg is not None and self.drag is None:
            # per cruise: the model's grid from LEG_SETTLE_S before it, and where it begins
            grids = [np.arange(a - MAX_DELAY_S - LEG_SETTLE_S, b + FINE_S, FINE_S)
                     for a, b, _, _ in leg]
            self.leg = [(g, int(np.searchsorted(g, a))) for g, (a, _, _, _) in zip(grids, leg)]
            (_, _, v1, a1), (_, _, v2, a2) = leg
            self.leg_dv, self.leg_s0 = v1 - v2, (a1 - a2) / (v1 - v2)
            self._leg_d, self._leg_held = None, None
        lead = t0 - MAX_DELAY_S - 0.05
        self.grid = np.arange(max(lead, t[0]), t1 + FINE_S, FINE_S)
        keep = (t >= t0) & (t <= t1)
        self.ts, self.vs = t[keep], v[keep]
        if self.ts.size < 20:
            raise ValueError("too few samples in the identification window")
        self.i0 = int(np.searchsorted(self.grid, t0))
        self.at = np.interp(self.ts, self.grid, np.arange(self.grid.size)).round().astype(int)
        self.rel = self.ts - t0
        self._held_d, self._held = None, None
        # a disturbance that drifts over the window (gusts slower than the doublets): its
        # integral, a polynomial in time (the first column is the initial velocity)
        x = self.rel / max(self.rel[-1], 1e-9)
        self.poly = [x ** p for p in range(POLY + 2)]
        # the measured velocity's integral: the drag term's regressor
        self.iv = np.concatenate([[0.0], np.cumsum(0.5 * (self.vs[1:] + self.vs[:-1])
                                                    * np.diff(self.ts))])
        # for the search: every column but the lagged commands' is the same at every (tau, d),
        # so they are projected out once (an orthonormal basis of them) and each (tau, d)
        # solves for one column instead of a least squares of all
        if self.leg is not None:
            target, fixed = self.vs - self.leg_s0 * self.iv, self.poly
        elif self.drag is not None:
            target, fixed = self.vs + self.drag * self.iv, self.poly
        else:
            target, fixed = self.vs, [-self.iv, *self.poly]
        self._basis, _ = np.linalg.qr(np.column_stack(fixed))
        self._rest_target = self._rest(target)
        self._rest_iv = self._rest(self.iv)

    def _held_for(self, d):
        """The commands seen ``d`` s late on the grid, kept for the next call (the search runs
        every lag at one dead time before the next)."""
        if d != self._held_d:
            self._held_d, self._held = d, _shifted_hold(self.t, self.u, self.grid, d)
        return self._held

    def _rest(self, x):
        """What of ``x`` the columns fixed over the search do not explain."""
        return x - self._basis @ (self._basis.T @ x)

    def sse(self, tau, d):
        """The squared velocity residual :meth:`solve` gives for (tau, d), as the search needs
        it (the same least squares, solved by projection: a tenth of the time)."""
        col = self._rest(lagged_change(self._held_for(d), _alpha(tau), ORDER, self.at, self.i0,
                                       FINE_S))
        if self.leg is not None:
            col = col - self.leg_ratio(tau, d) * self._rest_iv
        norm = float(col @ col)
        r = self._rest_target - (float(col @ self._rest_target) / norm) * col if norm > 0.0 \
            else self._rest_target
        return float(r @ r)

    def solve(self, tau, d):
        """(sse, k, v0, b, c) of the velocity fit for lag ``tau`` and dead time ``d``."""
        # the modelled velocity change since the window began
        w = lagged_change(self._held_for(d), _alpha(tau), ORDER, self.at, self.i0, FINE_S)
        if self.leg is not None:  # c = k s1 - s0: k's column carries the drag's share
            s1, s0 = self.leg_ratio(tau, d), self.leg_s0
            target = self.vs - s0 * self.iv
            A = np.column_stack([w - s1 * self.iv, *self.poly])
            coef, *_ = np.linalg.lstsq(A, target, rcond=None)
            r = target - A @ coef
            b = coef[2] / max(self.rel[-1], 1e-9)
            return (float(r @ r), float(coef[0]), float(coef[1]), float(b),
                    float(coef[0] * s1 - s0))
        if self.drag is not None:  # the drag known: its push moves to the measured side
            target = self.vs + self.drag * self.iv
            A = np.column_stack([w, *self.poly])
            coef, *_ = np.linalg.lstsq(A, target, rcond=None)
            r = target - A @ coef
            b = coef[2] / max(self.rel[-1], 1e-9)
            return float(r @ r), float(coef[0]), float(coef[1]), float(b), self.drag
        A = np.column_stack([w, -self.iv, *self.poly])
        coef, *_ = np.linalg.lstsq(A, self.vs, rcond=None)
        r = self.vs - A @ coef
        b = coef[3] / max(self.rel[-1], 1e-9)  # the disturbance's mean over the window
        return float(r @ r), float(coef[0]), float(coef[2]), float(b), float(coef[1])

    def leg_ratio(self, tau, d):
        """s1: the change between the leg's cruises of the commands as the model for (tau,
        d) produces them, per m/s of the speeds' change."""
        if d != self._leg_d:
            self._leg_d = d
            self._leg_held = [_shifted_hold(self.t, self.u, g, d) for g, _ in self.leg]
        alpha = _alpha(tau)
        means = [float(lagged(y, alpha, ORDER)[i0:].mean())
                 for (_, i0), y in zip(self.leg, self._leg_held)]
        return (means[0] - means[1]) / self.leg_dv


def _alpha(tau):
    """The gain of a first-order lag ``tau`` discretised at :data:`FINE_S` (1: no lag)."""
    return 1.0 - math.exp(-FINE_S / tau) if tau > 0.0 else 1.0


@jit
def lagged(x, alpha, order):
    """``x`` through ``order`` first-order lags ``y += alpha (x - y)``, each started at rest
    on ``x[0]``.  The operations and their order are scipy.signal.lfilter's for ``b = [alpha],
    a = [1, alpha - 1], zi = [x[0] (1 - alpha)]`` (what the fit called before: the same bits),
    without its per-call cost, which was half of a fit's time."""
    y = x.copy()
    a1 = alpha - 1.0
    for _ in range(order):
        z = y[0] * (1.0 - alpha)
        for k in range(y.size):
            xk = y[k]
            yk = z + alpha * xk
            z = xk * 0.0 - yk * a1
            y[k] = yk
    return y


@jit
def lagged_change(x, alpha, order, at, i0, dt):
    """The integral (rectangles of ``dt``, as ``np.cumsum(y) * dt``) of ``x`` through
    :func:`lagged`, at the indices ``at`` less its value at ``i0``."""
    y = lagged(x, alpha, order)
    total = 0.0
    for k in range(y.size):
        total += y[k]
        y[k] = total
    base = y[i0] * dt
    out = np.empty(at.size)
    for j in range(at.size):
        out[j] = y[at[j]] * dt - base
    return out


def load_fitting():
    """Import what a fit uses (scipy.optimize, about half a second) and load its kernels from
    numba's cache (compiled there on a first run: a few seconds) now.  A flight that will
    identify calls this before it flies: the fit runs in a thread beside the control loop, and
    an import or a compile there would hold the interpreter for the loop's steps."""
    import importlib

    importlib.import_module("scipy.optimize")
    lagged(np.zeros(4), 0.5, ORDER)  # the leg's reading calls it as the fit's integral does
    lagged_change(np.zeros(4), 0.5, ORDER, np.arange(4), 0, FINE_S)


def _search(fits):
    """(tau, d) minimising the summed squared velocity residual of ``fits`` (each an
    :class:`_AxisFit`): a grid, then Nelder-Mead from its best point."""
    def total(tau, d):
        return sum(f.sse(tau, d) for f in fits)

    best = (math.inf, None, None)
    for d in np.arange(0.0, MAX_DELAY_S + 1e-9, 0.01):
        for tau in np.geomspace(*TAU_RANGE_S, 20):
            sse = total(tau, d)
            if sse < best[0]:
                best = (sse, tau, d)

    def cost(p):
        tau, d = p
        if not (TAU_RANGE_S[0] * 0.5 <= tau <= TAU_RANGE_S[1] * 1.5 and 0.0 <= d <= MAX_DELAY_S):
            return math.inf
        return total(tau, d)

    from scipy.optimize import minimize
    res = minimize(cost, [best[1], best[2]], method="Nelder-Mead",
                   options={"xatol": 2e-4, "fatol": 1e-12, "maxiter": 400})
    return tuple(float(x) for x in res.x) if res.fun <= best[0] else (best[1], best[2])


def _record(f, tau, d):
    sse, k, v0, b, c = f.solve(tau, d)
    var = float(np.sum((f.vs - f.vs.mean()) ** 2))
    r2 = 1.0 - sse / var if var > 0.0 else 0.0
    ok = bool(r2 >= MIN_R2 and GAIN_RANGE[0] <= k <= GAIN_RANGE[1])
    return {"tau_s": tau, "delay_s": d, "lag_s": LAG63[ORDER] * tau + d, "gain": k,
            "bias_mps2": b, "drag_per_s": c,
            "drag_from": "told" if f.drag is not None else "leg" if f.leg is not None
            else "fitted", "r2": r2, "rms_mps": math.sqrt(sse / f.ts.size),
            "samples": int(f.ts.size), "ok": ok}


def fit_axis(t, u, v, t0, t1):
    """Fit ``a = k L(u(t - d)) - c v + b(t)`` on one axis over [t0, t1].

    ``t``: sample times (s, increasing), ``u``: the acceleration commanded at each (held until
    the next), ``v``: the measured velocity at each.  Returns a dict: ``tau_s``, ``delay_s``,
    ``lag_s`` (the 63 % time, what the observers use), ``gain``, ``bias_mps2``,
    ``drag_per_s``, ``r2`` (share of the velocity's variance explained), ``rms_mps`` (velocity
    residual), ``samples``, ``ok``.
    """
    t, u, v = (np.asarray(a, dtype=float) for a in (t, u, v))
    f = _AxisFit(t, u, v, t0, t1)
    return _record(f, *_search([f]))


def leg_reading(t, u, v, legs):
    """What the drag leg says per horizontal axis: ``legs`` its two cruise windows [(t0, t1)]
    in the samples' time (``u`` commands, ``v`` velocities at times ``t``).

    At constant speed the model ``a = k L(u) - c v + b`` gives, averaged over each window
    (``a`` the velocity's slope there), ``k L(u) = a + c v - b``; the wind's mean ``b`` is
    common to both, so ``c = k s1 - s0`` with ``s1 = d L(u) / dv`` and ``s0 = da / dv`` between
    the windows.  The commands hardly move there, so ``s1`` hardly depends on the response's
    lag, but the fit takes it from its own ``L(u)`` (:class:`_AxisFit`).  Returns per axis (0,
    1) a dict (the windows' mean speeds, accelerations and commands, and the ratio ``du / dv``
    of the raw commands), or None where the speeds differ by less than :data:`LEG_MIN_DV` or a
    window has too few samples."""
    t, u, v = (np.asarray(a, dtype=float) for a in (t, u, v))
    out = {}
    for ax in (0, 1):
        means = []
        for t0, t1 in legs:
            keep = (t >= t0) & (t <= t1) & np.isfinite(u[:, ax]) & np.isfinite(v[:, ax])
            if keep.sum() < 10:
                break
            tk = t[keep] - t[keep].mean()
            vk = v[keep, ax]
            slope = float(tk @ (vk - vk.mean()) / (tk @ tk)) if tk @ tk > 0.0 else 0.0
            means.append((float(u[keep, ax].mean()), float(vk.mean()), slope))
        if len(means) != 2 or abs(means[0][1] - means[1][1]) < LEG_MIN_DV:
            out[ax] = None
            continue
        (u1, v1, a1), (u2, v2, a2) = means
        out[ax] = {"speed_mps": [v1, v2], "accel_mps2": [a1, a2], "command_mps2": [u1, u2],
                   "ratio_per_s": (u1 - u2) / (v1 - v2)}
    return out


def fit(t, u, v, windows, shared_xy=True, drag=None):
    """Each axis of ``windows`` ([(axis, t0, t1)], as :class:`Doublets` gives them, in the
    samples' time) fitted as :func:`fit_axis` does; returns the identification record: per axis
    the fit, and ``input_lag`` (x, y, z: the lag for the observers) when every axis fitted well.

    ``shared_xy``: north and east share one lag and dead time, each keeping its own gain, drag
    and disturbance (a multirotor's roll and pitch answer alike).  Fitted alone, the second
    horizontal axis on PX4 SIH came out 0.21-0.35 s over five flights where the first gave
    0.24-0.27: in closed loop the gain, the drag and the lag trade against each other, and two
    axes' doublets pin them down where one does not.

    ``drag``: (3,) the drag per axis when it is known (None entries, or None: fitted).  The
    doublets tell the drag poorly: it trades against the lag (on PX4 SIH the free fit gave
    0.22-0.29 s with 0.46-1.35 /s for SIH's 1 /s; with the drag learnt along the mission,
    :mod:`mavadrc.control.learn`, the same samples gave 0.244-0.271 s).  Windows of axis ``"leg"`` are
    the drag leg's cruises (:func:`leg_reading`): where it reads an axis and ``drag`` does not
    give it, the drag there is tied to the gain as the leg says (``drag_from: leg``); with
    ``shared_xy`` and the leg read on both, north and east are fitted again with the mean of
    their two readings as their drag (each axis's own kept as ``leg_drag_own_per_s``)."""
    t, u, v = (np.asarray(a, dtype=float) for a in (t, u, v))
    legs = [(t0, t1) for ax, t0, t1 in windows if ax == "leg"]
    windows = [w for w in windows if w[0] != "leg"]
    reading = leg_reading(t, u, v, legs) if len(legs) == 2 else {}
    fits = {}
    axes = {}
    for ax, t0, t1 in windows:
        leg = reading.get(ax)
        if leg is not None:
            leg = [(a, b, sp, ac) for (a, b), sp, ac in zip(legs, leg["speed_mps"],
                                                             leg["accel_mps2"])]
        try:
            fits[ax] = _AxisFit(t, u[:, ax], v[:, ax], t0, t1,
                                None if drag is None else drag[ax], leg)
        except ValueError as exc:
            axes[AXES[ax]] = {"ok": False, "error": str(exc)}
    groups = [[0, 1], [2]] if shared_xy and 0 in fits and 1 in fits else [[a] for a in fits]
    for g in groups:
        g = [a for a in g if a in fits]
        if not g:
            continue
        tau, d = _search([fits[a] for a in g])
        for a in g:
            axes[AXES[a]] = _record(fits[a], tau, d)
        if len(g) == 2 and all(fits[a].leg is not None for a in g):
            # north and east share the leg's drag as they share the lag: each axis alone read
            # 0.82-1.44 /s over 14 flights on PX4 SIH (its drag 1.0 on both), their mean
            # 0.93-1.14; the mission learns each axis's own after
            own = [axes[AXES[a]]["drag_per_s"] for a in g]
            c = max(float(np.mean(own)), 0.0)
            tied = {a: _AxisFit(t, u[:, a], v[:, a], fits[a].window[0], fits[a].window[1],
                                c) for a in g}
            tau, d = _search(list(tied.values()))
            for a, mine in zip(g, own):
                axes[AXES[a]] = {**_record(tied[a], tau, d), "drag_from": "leg",
                                 "leg_drag_own_per_s": mine}
    rec = {"model": f"{ORDER} equal first-order lag{'s' if ORDER > 1 else ''} plus a dead time, "
                    "fitted on velocity" + (", north and east together" if len(groups) == 2
                                             and len(groups[0]) == 2 else ""),
           "axes": {a: axes[a] for a in AXES if a in axes}}
    if reading:
        rec["leg"] = {AXES[ax]: None if r is None else {
            k: np.round(x, 4).tolist() for k, x in r.items()} for ax, r in reading.items()}
    ok = [bool(rec["axes"].get(a, {}).get("ok")) for a in AXES]
    if ok[0] and ok[1]:
        # the vertical alone failing (on PX4 SIH once: gain -19, its height estimate drifting
        # through the doublets) leaves the horizontal model good: the vertical flies the safe
        # gains, with no model (unidentified_axes)
        rec["input_lag"] = [round(rec["axes"][a]["lag_s"], 4) if k else 0.0
                            for a, k in zip(AXES, ok)]
        if not ok[2]:
            rec["unidentified"] = ["z"]
    return rec


def unidentified_axes(rec):
    """The axes an identification that gives an input model could not fit (flown on the safe
    default gains with no model; :func:`mavadrc.design.gains.resolve_gains`)."""
    return list(rec.get("unidentified", ()))


def partial_text(rec):
    """Why an axis of an identification that gives a model flies without one (None: none)."""
    bad = unidentified_axes(rec)
    if not bad:
        return None
    return (f"the input model could not be identified on axis {', '.join(bad)} (R2 < {MIN_R2} "
            f"or gain outside {GAIN_RANGE[0]}-{GAIN_RANGE[1]}): that axis flies the safe default "
            "gains with no input model, the others the mission's with the model identified")


def summary_line(rec):
    """One line for the console: per axis tau + dead time (fit quality)."""
    parts = []
    for a in AXES:
        f = rec["axes"].get(a)
        if f is None:
            continue
        if "tau_s" not in f:
            parts.append(f"{a}: {f.get('error', 'no fit')}")
            continue
        parts.append(f"{a} {1e3 * f['tau_s']:.0f} ms + {1e3 * f['delay_s']:.0f} ms dead time "
                     f"(gain {f['gain']:.2f}, R2 {f['r2']:.3f}{'' if f['ok'] else ', REJECTED'})")
    return "; ".join(parts)


def failure_text(rec):
    """Why the record gives no input model (None if it does)."""
    if "input_lag" in rec:
        return None
    bad = [a for a in AXES if not rec["axes"].get(a, {}).get("ok")]
    return (f"the input model could not be identified on axis {', '.join(bad)} "
            f"(R2 < {MIN_R2} or gain outside {GAIN_RANGE[0]}-{GAIN_RANGE[1]})")


# --- on the bundled vehicle, in process ----------------------------------------------------------



def fit_flight(t, u, v, age, windows, flown, drag=None):
    """The identification record of a flight's samples: :func:`fit` of the commands ``u`` and
    velocities ``v`` at times ``t`` (``drag``: known per axis, as :func:`fit` takes it), the
    samples' median age (``age``, s; NaN: unknown) and where it was ``flown``."""
    rec = fit(t, u, v, windows, drag=drag)
    rec["sample_age_s"] = median_age(t, age, windows)
    rec["flown"] = flown
    return rec


def median_age(t, age, windows):
    """The samples' median age (s) over the identification's windows (0 if none is known)."""
    t, age = np.asarray(t, dtype=float), np.asarray(age, dtype=float)
    keep = (t >= min(w[1] for w in windows)) & (t <= max(w[2] for w in windows)) & (age == age)
    return float(np.median(age[keep])) if keep.any() else 0.0


def observer_lag(rec, spec):
    """The observers' input lag for ``spec`` from an identification: as identified (the
    samples' age included: the controller sees its commands act that much later), less the age
    the controller compensates itself (its ``latency``: the median age measured during the
    identification for ``auto``, the seconds given otherwise)."""
    age = _compensated_age(rec, spec)
    bad = unidentified_axes(rec)
    return tuple(None if a in bad else max(float(x) - age, 0.0)
                 for a, x in zip(AXES, rec["input_lag"]))


def _compensated_age(rec, spec):
    """The samples' age (s) ``spec``'s controller compensates itself (its ``latency``: the
    median age measured during the identification for ``auto``, the seconds given otherwise),
    to be taken out of the identified response."""
    lat = spec.gains.get("latency", 0.0)
    return rec.get("sample_age_s", 0.0) if lat == "auto" else float(lat or 0.0)


def observer_dead_time(rec, spec):
    """The dead time (s per axis) of the observers' input model shaped as identified
    (``input_dead_time``, with ``input_lags`` :data:`ORDER`): the fitted dead time less the
    samples' age the controller compensates itself (as :func:`observer_lag`), 0 on an axis not
    identified."""
    age = _compensated_age(rec, spec)
    bad = unidentified_axes(rec)
    return tuple(0.0 if a in bad else max(float(rec["axes"][a]["delay_s"]) - age, 0.0)
                 for a in AXES)



def response_margin(ctrl, rec, spec):
    """The delay margin (s) of ``ctrl`` on the response identified rather than on its own input
    model: its horizontal loop closed around :data:`ORDER` lags ``tau`` after the dead time
    fitted on north (east shares them), the samples' age it compensates (``latency``) counted
    as known.  The observers model the response as one lag of its 63 % time; the fitted one has
    more phase lag at the loop's crossover, so this is the smaller margin, and the one a swing
    in flight follows.  None without a fit."""
    from mavadrc.design.margin import delay_margin
    f = rec["axes"].get("x", {})
    if "tau_s" not in f:
        return None
    lat = spec.gains.get("latency", 0.0)
    known = rec.get("sample_age_s", 0.0) if lat == "auto" else None
    return delay_margin(ctrl, tau=f["tau_s"], delay=f["delay_s"], order=ORDER, known_s=known)


def observer_drag(rec):
    """The linear drag (1/s per axis) of an identification for the observers' model (``drag:
    auto``): the fit's ``c``, none where it came out negative or the axis was not identified."""
    bad = unidentified_axes(rec)
    return tuple(0.0 if a in bad else max(float(rec["axes"][a]["drag_per_s"]), 0.0)
                 for a in AXES)


def needs_identification(spec, kind=None):
    """Whether flying ``spec`` as ``kind`` needs the input model identified first."""
    kind = kind or spec.kind
    return kind in ("ladrc", "adrc") and spec.gains.get("input_lag") == "auto"


def needs_design_lag(spec, kind=None):
    """Whether flying ``spec`` as ``kind`` needs the lags its own gains were chosen for: it
    identifies its vehicle and gives gains of its own (wc or wo), which are scaled to the
    vehicle identified (:func:`mavadrc.design.gains.scale_to_vehicle`)."""
    kind = kind or spec.kind
    own = kind == spec.kind and ("wc" in spec.gains or "wo" in spec.gains)
    return own and needs_identification(spec, kind)



# --- mavadrc identify ----------------------------------------------------------------------------


def model_yaml(rec, source):
    """The identified input model as a mission's ``controller:`` section (YAML text), the fit
    in comments."""
    lines = [f"# input model identified by mavadrc identify ({rec.get('flown', '')}; "
             f"{source})",
             f"# {rec['model']}: a(t) = k lag_tau(u(t - d)) - c v + b(t)"]
    for a in AXES:
        f = rec["axes"].get(a, {})
        if "tau_s" in f:
            lines.append(f"#   {a}: tau {f['tau_s']:.4f} s, dead time {f['delay_s']:.4f} s, "
                         f"63 % time {f['lag_s']:.4f} s, gain {f['gain']:.3f}, drag "
                         f"{f['drag_per_s']:.3f} /s ({f.get('drag_from', 'fitted')}), "
                         f"R2 {f['r2']:.4f}")
    lines += ["controller:",
              "  input_lag: [" + ", ".join(f"{x:.4f}" for x in rec["input_lag"]) + "]",
              "  input_dead_time: [" + ", ".join(
                  f"{min(rec['axes'][a]['delay_s'], x):.4f}"
                  for a, x in zip(AXES, rec["input_lag"])) + "]",
              f"  input_lags: {ORDER}",
              "  drag: [" + ", ".join(f"{x:.4f}" for x in observer_drag(rec)) + "]"]
    return "\n".join(lines) + "\n"


