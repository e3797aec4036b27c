"""Single-channel controllers: thin Python holders of the state/parameter vectors of ``kernels``.

Every class is explicitly discrete with nominal step ``h`` and uses the notation of the project's
ADRC notes.  ``update`` takes the real interval since the last sample as an optional ``h``
(None: the nominal step); see :mod:`mavadrc.control.kernels` for what each law does with it.
The plant of one channel is taken in canonical form ``y'' = f + b*u`` with only a nominal ``b0``
known; ``z3`` estimates the total disturbance ``f`` (including ``(b - b0)*u``).
"""

import math

import numpy as np

from . import kernels as K

_NAN = math.nan


def check_positive(name, value):
    """Return ``value`` as float if finite and > 0, else raise ValueError naming the parameter."""
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite number > 0 (got {value!r})")
    return v


def check_finite(name, value):
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite (got {value!r})")
    return v


def check_limits(u_min, u_max):
    lo = -math.inf if u_min is None else float(u_min)
    hi = math.inf if u_max is None else float(u_max)
    if math.isnan(lo) or math.isnan(hi) or not lo < hi:
        raise ValueError(f"u_min must be < u_max (got u_min={u_min!r}, u_max={u_max!r})")
    return lo, hi


def check_b0(b0):
    v = float(b0)
    if not math.isfinite(v) or v == 0.0:
        raise ValueError(f"b0 must be finite and non-zero (got {b0!r})")
    return v


def nonfinite_error(**values):
    bad = [name for name, v in values.items() if not math.isfinite(v)]
    return ValueError(f"non-finite input {', '.join(bad)} = {', '.join(repr(values[n]) for n in bad)}; "
                      "state left unchanged")


def bad_input(h, **values):
    """The error for a step the kernel refused: a bad interval ``h``, else non-finite values."""
    if not (h > 0.0 and math.isfinite(h)):
        return ValueError(f"the interval h must be a finite number > 0 s (got {h!r}); "
                          "state left unchanged")
    return nonfinite_error(**values)


def nonfinite_arrays(**values):
    bad = [name for name, v in values.items() if not np.all(np.isfinite(v))]
    return ValueError(f"non-finite input in {', '.join(bad)}; state left unchanged")


def ladrc_params(*, h, b0, wc, wo, u_min=None, u_max=None, discretization="zoh"):
    """Parameter vector of a linear ADRC channel (kp = wc^2, kd = 2 wc, LESO bandwidth wo)."""
    h = check_positive("h", h)
    b0 = check_b0(b0)
    wc = check_positive("wc", wc)
    wo = check_positive("wo", wo)
    lo, hi = check_limits(u_min, u_max)
    if discretization not in ("zoh", "euler"):
        raise ValueError(f"discretization must be 'zoh' or 'euler' (got {discretization!r})")
    if discretization == "euler" and wo * h > 0.2:
        raise ValueError(
            f"wo*h = {wo * h:.3g} > 0.2: the forward-Euler LESO is unstable or badly damped there; "
            "use discretization='zoh' or a smaller wo or h")
    p = K.new_params()
    p[K.P_KIND] = K.KIND_LADRC
    p[K.P_H], p[K.P_B0], p[K.P_UMIN], p[K.P_UMAX] = h, b0, lo, hi
    p[K.P_KP], p[K.P_KD] = wc * wc, 2.0 * wc
    p[K.P_L1], p[K.P_L2], p[K.P_L3] = K.leso_gains(wo, h, discretization)
    p[K.P_WO] = wo
    p[K.P_OBS] = K.OBS_ZOH if discretization == "zoh" else K.OBS_EULER
    return p


def han_params(*, h, b0, r0=100.0, h0=None, r=100.0, c=0.5, h1=None, beta=None, eso_gains="han",
               delta=None, td=True, law="fhan", k1=None, k2=None, a1=0.75, a2=1.25, delta_law=None,
               u_min=None, u_max=None):
    """Parameter vector of a classical ADRC channel (TD + Han's NLESO + NLSEF)."""
    h = check_positive("h", h)
    b0 = check_b0(b0)
    r0 = check_positive("r0", r0)
    h0 = h if h0 is None else check_positive("h0", h0)
    if h0 < h:
        raise ValueError(f"h0 must be >= h (got h0={h0!r}, h={h!r})")
    r = check_positive("r", r)
    c = check_positive("c", c)
    h1 = 10.0 * h if h1 is None else check_positive("h1", h1)
    if beta is None:
        beta = K.han_eso_gains(h, eso_gains)
    if len(beta) != 3:
        raise ValueError(f"beta must be three gains (beta01, beta02, beta03), got {beta!r}")
    beta = tuple(check_positive(f"beta0{i + 1}", b) for i, b in enumerate(beta))
    delta = h if delta is None else check_positive("delta", delta)
    lo, hi = check_limits(u_min, u_max)
    p = K.new_params()
    p[K.P_KIND] = K.KIND_HAN
    p[K.P_H], p[K.P_B0], p[K.P_UMIN], p[K.P_UMAX] = h, b0, lo, hi
    p[K.P_R0], p[K.P_H0], p[K.P_R], p[K.P_C], p[K.P_H1] = r0, h0, r, c, h1
    p[K.P_B01], p[K.P_B02], p[K.P_B03] = beta
    p[K.P_DELTA] = delta
    p[K.P_TD] = 1.0 if td else 0.0
    if law == "fhan":
        p[K.P_LAW] = K.LAW_FHAN
    elif law == "fal":
        p[K.P_LAW] = K.LAW_FAL
        p[K.P_K1] = check_positive("k1", 100.0 if k1 is None else k1)
        p[K.P_K2] = check_positive("k2", 20.0 if k2 is None else k2)
        p[K.P_A1] = check_positive("a1", a1)
        p[K.P_A2] = check_positive("a2", a2)
        if not (p[K.P_A1] < 1.0 < p[K.P_A2]):
            raise ValueError(f"a1 < 1 < a2 required for the fal-form NLSEF (got a1={a1!r}, a2={a2!r})")
        p[K.P_DL] = h if delta_law is None else check_positive("delta_law", delta_law)
    else:
        raise ValueError(f"law must be 'fhan' or 'fal' (got {law!r})")
    return p


def pd_params(*, h, kp, kd, b0=1.0, u_min=None, u_max=None):
    """Parameter vector of the PD baseline: u = (kp*e + kd*edot + rddot)/b0."""
    p = K.new_params()
    p[K.P_KIND] = K.KIND_PD
    p[K.P_H] = check_positive("h", h)
    p[K.P_B0] = check_b0(b0)
    p[K.P_KP] = check_positive("kp", kp)
    kd = float(kd)
    if not (math.isfinite(kd) and kd >= 0.0):
        raise ValueError(f"kd must be a finite number >= 0 (got {kd!r})")
    p[K.P_KD] = kd
    p[K.P_UMIN], p[K.P_UMAX] = check_limits(u_min, u_max)
    return p


def _nonneg(name, value):
    v = float(value)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0 (got {value!r})")
    return v


def pid_gains(wc):
    """The PID kind's bandwidth shorthand: (kp_pos, kp_vel, ki_vel, kd_vel) for ``wc`` (rad/s).

    ``kp_pos = wc/2, kp_vel = 2 wc, ki_vel = wc^2/2, kd_vel = 0``.  Without the integrator this is
    exactly the PD kind at the same wc (kp_vel kp_pos = wc^2, kp_vel = 2 wc: a double pole at
    -wc).  On the double integrator the error obeys

        s^3 + kp_vel s^2 + (kp_vel kp_pos + ki_vel) s + ki_vel kp_pos = 0
          = s^3 + 2 wc s^2 + 1.5 wc^2 s + 0.25 wc^3,

    poles at -0.886 wc +- 0.558j wc (damping 0.85) and -0.228 wc (the integrator, which removes
    a constant disturbance with time constant ~4.4/wc); gain crossover 2.07 wc (PD: 2.06 wc),
    phase margin 70 deg.  A step of r with rdot = 0 does not overshoot.  At wc = 2 the gains are
    PX4's own vertical defaults (MPC_Z_P 1, MPC_Z_VEL_P_ACC 4, MPC_Z_VEL_I_ACC 2).
    """
    wc = check_positive("wc", wc)
    return 0.5 * wc, 2.0 * wc, 0.5 * wc * wc, 0.0


def pid_params(*, h, wc=None, kp_pos=None, kp_vel=None, ki_vel=None, kd_vel=None, i_limit=3.0,
               d_cutoff_hz=20.0, b0=1.0, u_min=None, u_max=None):
    """Parameter vector of the PX4-style cascade (see :class:`PID`).

    Gains: from the bandwidth shorthand ``wc`` (:func:`pid_gains`), each overridden by an
    explicit ``kp_pos, kp_vel, ki_vel, kd_vel``; without ``wc`` all of kp_pos and kp_vel must be
    given (ki_vel and kd_vel then default to 0).  ``i_limit``: the integrator's authority
    (acceleration units, |ki_vel I| <= i_limit).  ``d_cutoff_hz``: the D term's first-order
    low-pass (0: unfiltered).
    """
    h = check_positive("h", h)
    if wc is not None:
        g = dict(zip(("kp_pos", "kp_vel", "ki_vel", "kd_vel"), pid_gains(wc)))
    elif kp_pos is None or kp_vel is None:
        raise ValueError("the pid channel needs wc, or kp_pos and kp_vel "
                         f"(got wc=None, kp_pos={kp_pos!r}, kp_vel={kp_vel!r})")
    else:
        g = {"ki_vel": 0.0, "kd_vel": 0.0}
    for name, value in (("kp_pos", kp_pos), ("kp_vel", kp_vel), ("ki_vel", ki_vel),
                        ("kd_vel", kd_vel)):
        if value is not None:
            g[name] = value
    p = K.new_params()
    p[K.P_KIND] = K.KIND_PID
    p[K.P_H] = h
    p[K.P_B0] = check_b0(b0)
    p[K.P_KPP] = check_positive("kp_pos", g["kp_pos"])
    p[K.P_KPV] = check_positive("kp_vel", g["kp_vel"])
    p[K.P_KIV] = _nonneg("ki_vel", g["ki_vel"])
    p[K.P_KDV] = _nonneg("kd_vel", g["kd_vel"])
    p[K.P_ILIM] = _nonneg("i_limit", i_limit)
    fc = _nonneg("d_cutoff_hz", d_cutoff_hz)
    p[K.P_FC] = fc
    p[K.P_DALPHA] = 1.0 if fc == 0.0 else -math.expm1(-2.0 * math.pi * fc * h)
    p[K.P_UMIN], p[K.P_UMAX] = check_limits(u_min, u_max)
    return p


class TrackingDifferentiator:
    """Han's tracking differentiator as a discrete recursion (ADRC notes, section 2)::

        fh = fhan(v1 - v, v2, r0, h0);  v1 += h*v2;  v2 += h*fh

    ``r0`` bounds the acceleration of the tracked signal; ``h0 >= h`` is the filter factor
    (``h0 = h`` is time-optimal, larger values filter noise).  Starts at ``v1 = v2 = 0`` unless
    :meth:`reset` says otherwise.
    """

    __slots__ = ("_s", "_p", "_h")

    def __init__(self, *, h, r0, h0=None):
        h = check_positive("h", h)
        h0 = h if h0 is None else check_positive("h0", h0)
        if h0 < h:
            raise ValueError(f"h0 must be >= h (got h0={h0!r}, h={h!r})")
        self._p = K.new_params()
        self._p[K.P_H] = h
        self._p[K.P_R0] = check_positive("r0", r0)
        self._p[K.P_H0] = h0
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    def reset(self, v0=0.0, v0dot=0.0):
        self._s[:] = 0.0
        self._s[K.S_V1] = check_finite("v0", v0)
        self._s[K.S_V2] = check_finite("v0dot", v0dot)
        self._s[K.S_RPREV] = self._s[K.S_V1]

    def update(self, v, h=None):
        """One step on reference ``v``; ``h``: the interval since the last one (None: nominal)."""
        hh = self._h if h is None else float(h)
        if not K.td_update(self._s, self._p, v, hh):
            raise bad_input(hh, v=v)
        return K.td_output(self._s)

    @property
    def v(self):
        """(v1, v2): the tracked signal and its derivative."""
        return K.td_output(self._s)

    @property
    def acceleration(self):
        """fh of the last step: the acceleration the TD gave v2 (the classical ADRC feeds it
        forward)."""
        return self._s[K.S_FH]


def _estimates(self):
    """(z1, z2, z3): the observer's output, rate and total-disturbance estimates."""
    return self._s[K.S_Z1], self._s[K.S_Z2], self._s[K.S_Z3]


class _Held:
    """Holder of a kernel state vector ``_s``, parameter vector ``_p`` and nominal step ``_h``."""

    __slots__ = ("_s", "_p", "_h")

    def reset(self, y0=None, ydot0=None):
        """Start again: at y0 now (z1 = y0, z2 = ydot0 or 0, z3 = 0), or from the next
        measurement (anti-peaking initialisation)."""
        if y0 is None and ydot0 is not None:
            raise ValueError("ydot0 needs y0: a rate estimate starts with a position")
        y = None if y0 is None else check_finite("y0", y0)
        rate = 0.0 if ydot0 is None else check_finite("ydot0", ydot0)
        self._s[:] = 0.0
        if y is not None:
            K.channel_start(self._s, self._p, y, rate)

    def hold_disturbance(self):
        """Zero the disturbance estimate z3 (PID: the integrator), e.g. while on the ground."""
        K.hold_disturbance(self._s)


class _Observer(_Held):
    __slots__ = ()

    def update(self, y, u, h=None):
        """Correct with measurement ``y``; ``u`` is the input applied since the last one, ``h``
        the interval since it (None: the nominal step)."""
        hh = self._h if h is None else float(h)
        if not K.observer_update(self._s, self._p, y, u, hh):
            raise bad_input(hh, y=y, u=u)
        return self._s[K.S_Z1], self._s[K.S_Z2], self._s[K.S_Z3]

    z = property(_estimates)


class HanESO(_Observer):
    """Han's nonlinear ESO for a second-order plant, with e = z1 - y::

        z1 += h*(z2 - beta01*e)
        z2 += h*(z3 - beta02*fal(e, 1/2, delta) + b0*u)
        z3 += h*(-beta03*fal(e, 1/4, delta))

    Gains default from h: ``eso_gains="han"`` gives (1/h, 1/(1.6 h^1.5), 1/(8.6 h^2.2));
    ``"thesis"`` gives the thesis's eq. 25 set written with B0i = h*beta0i = (1, 1/(2 h^0.5),
    2/(25 h^1.2)).  Pass ``beta=(b1, b2, b3)`` to set them directly.
    """

    def __init__(self, *, h, b0, beta=None, eso_gains="han", delta=None):
        self._p = han_params(h=h, b0=b0, beta=beta, eso_gains=eso_gains, delta=delta)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])


class LinearESO(_Observer):
    """Linear ESO with bandwidth ``wo`` (all poles at -wo; l = 3wo, 3wo^2, wo^3).

    ``discretization="zoh"`` (default) is the zero-order-hold current observer: predict
    ``zp = Phi z + Gamma u`` then correct ``z = zp + Lc (y - zp1)`` with
    ``Lc = [1 - beta^3, 3(1 - beta)^2 (1 + beta)/(2h), (1 - beta)^3/h^2]``, beta = exp(-wo h):
    the three discrete poles sit exactly at exp(-wo h).  ``"euler"`` is forward Euler and is
    refused for wo*h > 0.2.
    """

    def __init__(self, *, h, b0, wo, discretization="zoh"):
        self._p = ladrc_params(h=h, b0=b0, wc=1.0, wo=wo, discretization=discretization)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    @property
    def gains(self):
        """The observer gain vector as used by the recursion (Lc for ZOH, l for Euler)."""
        return self._p[K.P_L1], self._p[K.P_L2], self._p[K.P_L3]


class _Channel(_Held):
    __slots__ = ()

    def update(self, y, r, rdot=0.0, rddot=0.0, h=None):
        """One step: measurement y, reference r with its derivatives, ``h`` the interval since
        the last step's sample (None: the nominal step); returns the limited u."""
        if h is None:
            u = K.channel_update_nominal(self._s, self._p, y, _NAN, r, rdot, rddot)
        else:
            u = K.channel_update(self._s, self._p, y, _NAN, r, rdot, rddot, float(h))
        if u != u:
            raise bad_input(self._h if h is None else float(h), y=y, r=r, rdot=rdot, rddot=rddot)
        return u

    def set_applied_input(self, u):
        """Tell the observer what was really applied when something downstream limited u further."""
        self._s[K.S_U] = check_finite("u", u)

    @property
    def u(self):
        """The input applied over the last step (after limits)."""
        return self._s[K.S_U]

    @property
    def u0(self):
        """The virtual control of the last step (before disturbance cancellation and 1/b0)."""
        return self._s[K.S_U0]

    @property
    def h(self):
        return self._p[K.P_H]

    @property
    def b0(self):
        return self._p[K.P_B0]

    @property
    def limits(self):
        return self._p[K.P_UMIN], self._p[K.P_UMAX]

    @property
    def params(self):
        """A copy of the kernel parameter vector (for batch use with ``kernels.channel_update``)."""
        return self._p.copy()


class _ObservedChannel(_Channel):
    z = property(_estimates)


class LinearADRC(_ObservedChannel):
    """Linear ADRC (Gao): LESO + PD law with reference feed-forward::

        u = (kp (r - z1) + kd (rdot - z2) + rddot - z3) / b0,   kp = wc^2, kd = 2 wc

    The LESO is the ZOH current observer of :class:`LinearESO`, fed the applied (limited) input.
    Settling is about 6/wc; wo is typically 3..10 wc.
    """

    def __init__(self, *, h, b0, wc, wo, u_min=None, u_max=None, discretization="zoh"):
        self._p = ladrc_params(h=h, b0=b0, wc=wc, wo=wo, u_min=u_min, u_max=u_max,
                               discretization=discretization)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    @property
    def kp(self):
        return self._p[K.P_KP]

    @property
    def kd(self):
        return self._p[K.P_KD]


class HanADRC(_ObservedChannel):
    """Classical ADRC on one channel: TD + Han's NLESO + NLSEF::

        (v1, v2, fh) = TD(r)                  (or (r, rdot, rddot) with td=False)
        e1 = v1 - z1 ;  e2 = v2 - z2
        u0 = -fhan(e1, c*e2, r, h1) + fh      (law="fhan")
           = k1 fal(e1, a1, d) + k2 fal(e2, a2, d) + fh      (law="fal", a1 < 1 < a2)
        u  = (u0 - z3) / b0

    With the TD the acceleration fed forward is the TD's own (fh, the acceleration it gives v2),
    so the feed-forward belongs to the profile (v1, v2) being tracked; the reference's ``rddot``
    is then not read.

    Corrected against the thesis (eqs. 42-47 print ``+ z3`` and ``c*e1``).  ``h1 = 10h`` and
    ``c = 0.5`` by default: ``h1 = 5h, c = 1`` limit-cycles.  The TD starts at the first
    measurement, so a step is shaped from where the plant is.
    """

    def __init__(self, *, h, b0, r0=100.0, h0=None, r=100.0, c=0.5, h1=None, beta=None,
                 eso_gains="han", delta=None, td=True, law="fhan", k1=None, k2=None, a1=0.75,
                 a2=1.25, delta_law=None, u_min=None, u_max=None):
        self._p = han_params(h=h, b0=b0, r0=r0, h0=h0, r=r, c=c, h1=h1, beta=beta,
                             eso_gains=eso_gains, delta=delta, td=td, law=law, k1=k1, k2=k2, a1=a1,
                             a2=a2, delta_law=delta_law, u_min=u_min, u_max=u_max)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    @property
    def v(self):
        """(v1, v2): the TD's tracked reference and its derivative (with td=False: the reference
        and its rate)."""
        return K.td_output(self._s)


class PD(_Channel):
    """PD baseline with reference feed-forward::

        u = (kp (r - y) + kd (rdot - ydot) + rddot) / b0

    ``ydot`` is the measured rate where one exists; without it the rate is the backward
    difference of y.  No integral action: a constant disturbance d leaves the steady error
    -d/(b kp).  The thesis tuned these by Ziegler-Nichols, which does not apply to a double
    integrator; use kp = wc^2, kd = 2 wc (see :meth:`from_bandwidth`).
    """

    def __init__(self, *, h, kp, kd, b0=1.0, u_min=None, u_max=None):
        self._p = pd_params(h=h, kp=kp, kd=kd, b0=b0, u_min=u_min, u_max=u_max)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    @classmethod
    def from_bandwidth(cls, *, h, wc, b0=1.0, u_min=None, u_max=None):
        wc = check_positive("wc", wc)
        return cls(h=h, kp=wc * wc, kd=2.0 * wc, b0=b0, u_min=u_min, u_max=u_max)

    def update(self, y, r, rdot=0.0, rddot=0.0, ydot=None, h=None):
        """One step: measurement y (and its rate ``ydot`` where measured), reference r with its
        derivatives, ``h`` the interval since the last step's sample (None: the nominal step)."""
        if ydot is None:
            rate = _NAN
        elif math.isfinite(ydot):
            rate = ydot
        else:
            raise nonfinite_error(ydot=ydot)
        if h is None:
            u = K.channel_update_nominal(self._s, self._p, y, rate, r, rdot, rddot)
        else:
            u = K.channel_update(self._s, self._p, y, rate, r, rdot, rddot, float(h))
        if u != u:
            raise bad_input(self._h if h is None else float(h), y=y, r=r, rdot=rdot, rddot=rddot)
        return u

    @property
    def kp(self):
        return self._p[K.P_KP]

    @property
    def kd(self):
        return self._p[K.P_KD]


class PID(_Channel):
    """PX4-style cascade (mc_pos_control): position P, velocity PID, feed-forward::

        v_sp = rdot + kp_pos (r - y)
        e_v  = v_sp - ydot
        u    = (rddot + kp_vel e_v + ki_vel I - kd_vel D) / b0
        I   += h e_v                 (held when saturated; |ki_vel I| <= i_limit)

    ``ydot`` is the measured rate where one exists; without it the rate is the backward
    difference of y.  ``D`` is the derivative of the measured rate (D on the measurement, no kick
    from reference steps), low-passed at ``d_cutoff_hz``; ``kd_vel = 0`` drops it.  As in PX4,
    D on the measurement also acts against a reference acceleration: with kd_vel > 0 a reference
    whose acceleration changes leaves an error of about kd_vel |r'''|/(ki_vel kp_pos) (the
    integrator absorbs a constant one; the default shorthand has kd_vel = 0).

    Anti-windup: the integrator is clamped to the authority ``i_limit`` (acceleration units) and
    stops integrating in the direction of saturation whenever the input applied over the last
    step (``u``; see :meth:`set_applied_input` for limits downstream) differs from the command
    by more than 1e-6.  Gains from ``wc`` are those of :func:`pid_gains`; explicit gains win.
    The integrator's disturbance estimate ``-ki_vel I`` is read out as ``z[2]``.
    """

    def __init__(self, *, h, wc=None, kp_pos=None, kp_vel=None, ki_vel=None, kd_vel=None,
                 i_limit=3.0, d_cutoff_hz=20.0, b0=1.0, u_min=None, u_max=None):
        self._p = pid_params(h=h, wc=wc, kp_pos=kp_pos, kp_vel=kp_vel, ki_vel=ki_vel,
                             kd_vel=kd_vel, i_limit=i_limit, d_cutoff_hz=d_cutoff_hz, b0=b0,
                             u_min=u_min, u_max=u_max)
        self._s = K.new_state()
        self._h = float(self._p[K.P_H])

    update = PD.update

    @property
    def gains(self):
        """(kp_pos, kp_vel, ki_vel, kd_vel)."""
        p = self._p
        return p[K.P_KPP], p[K.P_KPV], p[K.P_KIV], p[K.P_KDV]

    @property
    def integrator(self):
        """ki_vel I: the integrator's share of the command (acceleration units)."""
        return self._s[K.S_I]

    z = property(_estimates)


def make_channel(kind, **params):
    """Build a channel controller by kind name: 'pd', 'ladrc' or 'adrc' (classical)."""
    kinds = {"pd": PD, "ladrc": LinearADRC, "adrc": HanADRC}
    try:
        cls = kinds[kind]
    except KeyError:
        raise ValueError(f"controller kind must be one of {sorted(kinds)} (got {kind!r})") from None
    return cls(**params)


__all__ = ["TrackingDifferentiator", "HanESO", "LinearESO", "LinearADRC", "HanADRC", "PD", "PID",
           "make_channel", "ladrc_params", "han_params", "pd_params", "pid_params", "pid_gains"]

