"""Discrete-time control kernels: Han's functions, the TD, both ESOs, NLSEF, LADRC, PD and PID.

Everything here is a pure function over floats and float64 arrays (no I/O, no clocks), compiled
with numba.  A channel controller is two small vectors: a *state* vector (``S_*`` indices) and a
*parameter* vector (``P_*`` indices).  The classes in :mod:`mavadrc.control.channels` are thin
holders of those vectors; the position and attitude controllers and batch experiments keep one row
per channel in a 2-D array and call :func:`channel_update` on each row.

The laws are the corrected ones of the project's ADRC notes (docs/thesis.md,
"Corrections"): ``d = r*h^2`` in ``fhan``; the TD is a discrete recursion at the real step; the NLSEF is
``u0 = -fhan(e1, c*e2, r, h1)`` and ``u = (u0 + a - z3)/b0``, the feed-forward ``a`` the TD's own
acceleration ``fh`` when the TD runs, else the reference's ``rddot``; the LESO's second state
integrates ``z3 - l2*(z1 - y) + b0*u``; PD and LADRC use ``z2 - rdot`` for the rate error.
PID is PX4's cascade (position P -> velocity PID with conditional integration, see
:func:`pid_step`).

Every step takes the real interval ``h`` since the sample the previous step was computed from
(``P_H`` is the nominal step the gains were designed for).  With ``h == P_H`` every law is exactly
the fixed-step recursion; an interval within :data:`H_SNAP` (relative) of ``P_H`` counts as
``P_H``, so sample times carried as float seconds (or milliseconds) do not perturb a nominal run.
Otherwise (see :func:`leso_step`, :func:`nleso_step`, :func:`td_step`, :func:`pid_step`):

* ZOH LESO: predict with the exact Phi(h), Gamma(h) and correct with Lc(h) from ``wo``: the
  discrete poles sit at exp(-wo h) for every h.
* Euler-type observers (Han's NLESO, the Euler LESO), whose gains only suit the nominal step:
  re-align the estimate to the sample time by exact open-loop prediction with the applied input,
  then one correcting step whose rate and disturbance channels see the innovation per nominal
  step (:func:`_realign`).  A gap neither destabilises them nor makes their estimates jump.
* TD: whole nominal steps on its own grid, the reference interpolated, the rest of the interval
  carried to the next update (:func:`_td_interval`).
* PD / PID: differences, integral and the D low-pass with the real h.

A law that predicts (``P_PRED`` > 0; LADRC, and ADRC without its TD) acts on its errors carried
that far ahead at the accelerations of now, the reference's (``S_AREF``, set by the caller) and
the estimate's (z3 plus the input model's output in ``S_U``): :func:`_predicted_error`.

A sample that is older than the step using it (a link's latency) goes through
:func:`channel_update_aged`: the observer corrects at the sample's time and the law acts on its
estimate carried to now, from a delay line kept after the state (rows of ``NSD`` entries).

Observers are always fed the input that was *applied* over the last step (after limits), which is
what ``S_U`` holds.  A caller that limits the command further (tilt limits, a mixer) overwrites
``S_U`` with what it really applied; the PID kind compares it with its own command to stop its
integrator winding up.
"""

import math

import numpy as np

from .jit import jit, jit_inline

# --- channel kinds -------------------------------------------------------------------------------
KIND_PD = 0
KIND_LADRC = 1
KIND_HAN = 2
KIND_PID = 3

# --- state vector layout -------------------------------------------------------------------------
S_Z1 = 0  # observer: output estimate
S_Z2 = 1  # observer: rate estimate
S_Z3 = 2  # observer: total disturbance estimate (acceleration units of the channel)
S_U = 3  # input applied over the last step (after limits)
S_V1 = 4  # TD: tracked reference
S_V2 = 5  # TD: its derivative
S_INIT = 6  # 1.0 once initialised from a measurement (PID: 2.0 once it has a previous rate)
S_YPREV = 7  # PD: previous measurement (for differentiation when no rate is measured)
S_U0 = 8  # virtual control u0 (before disturbance cancellation and division by b0)
S_FH = 9  # TD: acceleration of the tracked reference
S_I = 10  # PID: velocity integrator times ki_vel (acceleration units, |S_I| <= i_limit)
S_VPREV = 11  # PID: previous rate (for the D term)
S_DF = 12  # PID: low-pass filtered derivative of the measured rate (the D term's input)
S_RPREV = 13  # TD: the reference of the last step (interpolated over long intervals)
S_TDR = 14  # TD: the time (s, < the nominal step) from its last grid step to the last update
S_AREF = 15  # the reference's own acceleration now, set by the caller for a law that predicts
NS = 16

# --- the delay line (observers that know the sample's age; see channel_update_aged) -------------
# A channel row of NSD entries: its state (NS), then the delayed estimate and the inputs applied.
# Times are on the line's own clock: 0 at the sample before the one it was seeded on.
HIST = 128  # inputs kept: 0.5 s at 250 Hz (older inputs count as the oldest kept)
DL_ON = NS  # 1.0 once seeded
DL_T = NS + 1  # the time of the last sample (when it was taken)
DL_NOW = NS + 2  # the time of the last step (the sample's time plus its age)
DL_Z1 = NS + 3  # the estimate at the last sample's time (z1, z2, z3: the delayed observer)
DL_N = NS + 6  # inputs stored (<= HIST)
DL_HEAD = NS + 7  # slot of the newest input
DL_TIMES = NS + 8  # HIST slots: when each input began to be applied
DL_INPUTS = DL_TIMES + HIST  # HIST slots: the input applied from then on
NSD = DL_INPUTS + HIST
#: the longest age compensated (s): an older sample is taken as this old
AGE_MAX = 0.5

# --- parameter vector layout ---------------------------------------------------------------------
P_KIND = 0
P_H = 1  # controller step (s)
P_B0 = 2  # nominal input gain
P_UMIN = 3
P_UMAX = 4
P_KP = 5  # LADRC / PD proportional gain (kp = wc^2)
P_KD = 6  # LADRC / PD derivative gain (kd = 2 wc)
P_L1 = 7  # LESO gains: current-observer Lc (ZOH) or continuous l (Euler)
P_L2 = 8
P_L3 = 9
P_OBS = 10  # LESO discretisation: OBS_ZOH or OBS_EULER
P_R0 = 11  # TD speed factor (acceleration bound)
P_H0 = 12  # TD filter factor (>= h)
P_R = 13  # NLSEF fhan: acceleration bound r
P_C = 14  # NLSEF fhan: damping c
P_H1 = 15  # NLSEF fhan: precision factor h1
P_B01 = 16  # NLESO gains (Han's convention: beta0i multiply the error, the step h multiplies all)
P_B02 = 17
P_B03 = 18
P_DELTA = 19  # NLESO fal linear zone
P_TD = 20  # 1.0: HanADRC tracks the reference with its TD; 0.0: uses (r, rdot) directly
P_LAW = 21  # HanADRC law: LAW_FHAN or LAW_FAL
P_K1 = 22  # fal-form NLSEF gains and exponents
P_K2 = 23
P_A1 = 24
P_A2 = 25
P_DL = 26  # fal-form NLSEF linear zone
P_KPP = 27  # PID: position P gain kp_pos (1/s)
P_KPV = 28  # PID: velocity P gain kp_vel (1/s)
P_KIV = 29  # PID: velocity I gain ki_vel (1/s^2)
P_KDV = 30  # PID: velocity D gain kd_vel (dimensionless; 0: no D term)
P_DALPHA = 31  # PID: low-pass factor per step of the D term (1 - exp(-2 pi fc h); 1: unfiltered)
P_ILIM = 32  # PID: integrator authority limit i_limit (acceleration units)
P_WO = 33  # LESO bandwidth wo (rad/s): the ZOH observer's Lc(h) for steps other than P_H
P_FC = 34  # PID: D-term low-pass cutoff (Hz; 0: unfiltered), for steps other than P_H
P_PRED = 35  # LADRC / ADRC without TD: the law acts on its errors carried this far (s; 0: now's)
NP = 36

#: An interval within this fraction of the nominal step is the nominal step.
H_SNAP = 1e-6
#: At most this many TD sub-steps per interval (beyond, they grow past the nominal step).
TD_MAX_SUBSTEPS = 1000

OBS_ZOH = 0.0
OBS_EULER = 1.0
LAW_FHAN = 0.0
LAW_FAL = 1.0


@jit
def _sign(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@jit
def fhan(x1, x2, r, h):
    """Han's discrete time-optimal synthesis function (ADRC notes, section 1).

    Returns the acceleration that brings the double integrator (x1, x2) to the origin fastest
    with acceleration bound ``r`` when sampled with step ``h``.  ``d = r*h^2`` (the thesis prints
    ``h*r^2``, which makes a TD step overshoot and never settle).
    """
    d = r * h * h
    a0 = h * x2
    y = x1 + a0
    a1 = math.sqrt(d * (d + 8.0 * abs(y)))
    a2 = a0 + _sign(y) * (a1 - d) * 0.5
    sy = (_sign(y + d) - _sign(y - d)) * 0.5
    a = (a0 + y - a2) * sy + a2
    sa = (_sign(a + d) - _sign(a - d)) * 0.5
    return -r * (a / d - _sign(a)) * sa - r * _sign(a)


@jit
def fal(e, alpha, delta):
    """Han's power function: linear (slope delta^(alpha-1)) inside |e| <= delta, |e|^alpha outside."""
    if abs(e) <= delta:
        return e / delta ** (1.0 - alpha)
    return abs(e) ** alpha * _sign(e)


@jit
def real_step(p, h):
    """The step a kernel uses for the interval ``h``: ``P_H`` when h is within H_SNAP of it
    (timestamp rounding), else h; NaN if h is not a finite number > 0."""
    hn = p[P_H]
    if not (h > 0.0 and h < math.inf):
        return math.nan
    if abs(h - hn) <= H_SNAP * hn:
        return hn
    return h


@jit_inline
def td_step(s, p, v, h):
    """The tracking differentiator on reference ``v`` over the interval h: updates S_V1, S_V2, S_FH.

    At the nominal step one recursion step; otherwise :func:`_td_interval`.
    """
    if h != p[P_H] or s[S_TDR] != 0.0:
        _td_interval(s, p, v, h)
        return
    fh = fhan(s[S_V1] - v, s[S_V2], p[P_R0], p[P_H0])
    s[S_V1] += h * s[S_V2]
    s[S_V2] += h * fh
    s[S_FH] = fh
    s[S_RPREV] = v


@jit
def _td_interval(s, p, v, h):
    """The TD over an interval h other than the nominal step hn, on its own grid of nominal
    steps: as many whole steps as the interval (with the time carried from the last one, S_TDR)
    holds, the reference interpolated from the last update's to ``v`` at each; the rest is
    carried to the next update (:func:`td_output` extrapolates over it).  The recursion's step
    never varies, so neither does its lag behind a moving reference: sampled with jitter, fh
    stays what it is at the nominal step instead of jumping by the change of that lag over
    h0^2 (+-40 m/s^2 on a 3 m/s ramp at 100 Hz with 20 % jitter and r0 = 100).  A gap of more
    than TD_MAX_SUBSTEPS steps is covered by that many equal longer steps (the filter factor
    kept >= the step)."""
    hn = p[P_H]
    r = s[S_TDR]
    total = r + h
    n = int(math.floor(total / hn + H_SNAP))
    hs = hn
    rest = total - n * hn
    if n > TD_MAX_SUBSTEPS:
        n = TD_MAX_SUBSTEPS
        hs = total / n
        rest = 0.0
    if rest < H_SNAP * hn:
        rest = 0.0
    h0 = max(p[P_H0], hs)
    v0 = s[S_RPREV]
    if not math.isfinite(v0):
        v0 = v
    for j in range(1, n + 1):
        f = (j * hs - r) / h
        vj = v if f >= 1.0 else v0 + (v - v0) * f
        fh = fhan(s[S_V1] - vj, s[S_V2], p[P_R0], h0)
        s[S_V1] += hs * s[S_V2]
        s[S_V2] += hs * fh
        s[S_FH] = fh
    s[S_TDR] = rest
    s[S_RPREV] = v


@jit_inline
def td_output(s):
    """(v1, v2) of the TD now: its grid state carried over the time since its last grid step."""
    r = s[S_TDR]
    if r == 0.0:
        return s[S_V1], s[S_V2]
    return s[S_V1] + r * s[S_V2], s[S_V2] + r * s[S_FH]


@jit
def _realign(s, p, h, b0u):
    """Euler-type observers (Han's NLESO, the Euler LESO) at an interval h other than the nominal.

    Their recursion ``z(k) = z(k-1) + hn*(f(z) + correction(z1 - y(k)))`` keeps z one nominal step
    ahead of the last sample, and their gains are tuned to the nominal step hn (Han's NLESO is
    unstable once h*beta01 > ~2).  Before the correcting step the estimate is moved from
    ``t(k-1) + hn`` to the sample time ``t(k-1) + h`` by open-loop prediction with the applied
    input (a = z3 + b0 u, constant over the interval), D = h - hn::

        h > hn:  z1 += D z2 + D^2/2 a,        z2 += D a     (exact)
        h < hn:  z1 += D z2 + D (D - hn)/2 a, z2 += D a     (counted from the last sample: the
                                                             exact prediction less h*hn/2*a, the
                                                             Euler step's own term, which
                                                             vanishes with h)

    The caller then does one correcting step ``z += hn*f(z) - m*gain_j*g_j(s_j*e)`` with
    (m, s2, s3) returned here.  Below the nominal step m = h, s = 1: corrections in proportion to
    the time elapsed, so a burst of samples does not multiply them.  Above it m = hn and the rate
    and disturbance channels see the innovation per nominal step, s2 = hn/h and
    s3 = hn/h*min(1, 3 hn/h): an error of z2 or z3 grows the innovation like h or h^2, and
    treating it as if it had built up in one nominal step would over-correct by as much (the
    NLESO's per-sample poles leave the unit circle from ~5 hn steadily, and a gap kicks z3).  With
    this the NLESO's per-sample poles stay inside its nominal radius at any longer interval (the
    Euler LESO's inside 0.95 at wo*hn = 0.2); the (hn/h)^2 share from three nominal steps on is
    what keeps them there at long intervals, the hn/h share below keeps a jittering stream from
    stirring z3 with measurement noise.  Across a gap the prediction carries the estimate: with a
    right model the innovation, and the estimates, stay where they were; a wrong one is corrected
    at the nominal pace.
    """
    hn = p[P_H]
    d = h - hn
    a = s[S_Z3] + b0u
    if d < 0.0:
        s[S_Z1] += d * s[S_Z2] + 0.5 * d * (d - hn) * a
        s[S_Z2] += d * a
        return h, 1.0, 1.0
    s[S_Z1] += d * s[S_Z2] + 0.5 * d * d * a
    s[S_Z2] += d * a
    r = hn / h
    return hn, r, r * min(1.0, 3.0 * r)


@jit_inline
def nleso_step(s, p, y, h):
    """Han's nonlinear ESO, forward-Euler recursion, fed the applied input S_U of the last step.

    ``h``: the interval since the last sample (:func:`_nleso_interval` when it is not the
    nominal step).
    """
    if h != p[P_H]:
        _nleso_interval(s, p, y, h)
        return
    delta = p[P_DELTA]
    z1 = s[S_Z1]
    z2 = s[S_Z2]
    z3 = s[S_Z3]
    e = z1 - y
    s[S_Z1] = z1 + h * (z2 - p[P_B01] * e)
    s[S_Z2] = z2 + h * (z3 - p[P_B02] * fal(e, 0.5, delta) + p[P_B0] * s[S_U])
    s[S_Z3] = z3 - h * p[P_B03] * fal(e, 0.25, delta)


@jit
def _nleso_interval(s, p, y, h):
    """The NLESO over an interval h other than the nominal step: :func:`_realign`, then one
    correcting step."""
    hn = p[P_H]
    delta = p[P_DELTA]
    b0u = p[P_B0] * s[S_U]
    m, s2, s3 = _realign(s, p, h, b0u)
    z1 = s[S_Z1]
    z2 = s[S_Z2]
    z3 = s[S_Z3]
    e = z1 - y
    s[S_Z1] = z1 + hn * z2 - m * p[P_B01] * e
    s[S_Z2] = z2 + hn * (z3 + b0u) - m * p[P_B02] * fal(s2 * e, 0.5, delta)
    s[S_Z3] = z3 - m * p[P_B03] * fal(s3 * e, 0.25, delta)


@jit_inline
def leso_step(s, p, y, h):
    """Linear ESO fed the applied input S_U of the last step, over the interval h.

    ZOH current observer (default): predict with the exact discretisation of the triple
    integrator over h, then correct with the new measurement with Lc(h) from wo (the stored Lc at
    the nominal step); the poles lie at exp(-wo*h) for every h.  Euler: the forward-Euler
    recursion of the continuous observer (poles at 1 - wo*h), re-aligned as in :func:`_realign`
    when h is not the nominal step.
    """
    if h != p[P_H]:
        _leso_interval(s, p, y, h)
        return
    b0u = p[P_B0] * s[S_U]
    z1 = s[S_Z1]
    z2 = s[S_Z2]
    z3 = s[S_Z3]
    if p[P_OBS] == OBS_ZOH:
        zp1 = z1 + h * z2 + 0.5 * h * h * (z3 + b0u)
        zp2 = z2 + h * (z3 + b0u)
        e = y - zp1
        s[S_Z1] = zp1 + p[P_L1] * e
        s[S_Z2] = zp2 + p[P_L2] * e
        s[S_Z3] = z3 + p[P_L3] * e
    else:
        e = y - z1
        s[S_Z1] = z1 + h * (z2 + p[P_L1] * e)
        s[S_Z2] = z2 + h * (z3 + p[P_L2] * e + b0u)
        s[S_Z3] = z3 + h * p[P_L3] * e


@jit
def _leso_interval(s, p, y, h):
    """The LESO over an interval h other than the nominal step: ZOH with Lc(h) from wo, or the
    Euler recursion re-aligned (:func:`_realign`) with one correcting step."""
    hn = p[P_H]
    b0u = p[P_B0] * s[S_U]
    if p[P_OBS] == OBS_ZOH:
        beta = math.exp(-p[P_WO] * h)
        omb = -math.expm1(-p[P_WO] * h)
        z1 = s[S_Z1]
        z2 = s[S_Z2]
        z3 = s[S_Z3]
        zp1 = z1 + h * z2 + 0.5 * h * h * (z3 + b0u)
        zp2 = z2 + h * (z3 + b0u)
        e = y - zp1
        s[S_Z1] = zp1 + (1.0 - beta * beta * beta) * e
        s[S_Z2] = zp2 + 1.5 * omb * omb * (1.0 + beta) / h * e
        s[S_Z3] = z3 + omb * omb * omb / (h * h) * e
        return
    m, s2, s3 = _realign(s, p, h, b0u)
    z1 = s[S_Z1]
    z2 = s[S_Z2]
    z3 = s[S_Z3]
    e = y - z1
    s[S_Z1] = z1 + hn * z2 + m * p[P_L1] * e
    s[S_Z2] = z2 + hn * (z3 + b0u) + m * p[P_L2] * s2 * e
    s[S_Z3] = z3 + m * p[P_L3] * s3 * e


@jit
def _clip(u, lo, hi):
    if u > hi:
        return hi
    if u < lo:
        return lo
    return u


@jit
def channel_init(s, y, r, rdot):
    """Anti-peaking start: observer at the first measurement, TD at the measurement too.

    Starting the TD at y (not at r) lets the classical ADRC arrange the transient from where the
    plant is to the reference, as the TD is meant to.  ``r`` is taken as the last reference (the
    TD interpolates from it over a long first interval).
    """
    s[S_Z1] = y
    s[S_Z2] = 0.0
    s[S_Z3] = 0.0
    s[S_U] = 0.0
    s[S_V1] = y
    s[S_V2] = 0.0
    s[S_FH] = 0.0
    s[S_YPREV] = y
    s[S_U0] = 0.0
    s[S_I] = 0.0
    s[S_VPREV] = 0.0
    s[S_DF] = 0.0
    s[S_RPREV] = r
    s[S_TDR] = 0.0
    s[S_INIT] = 1.0


@jit
def channel_start(s, p, y, ydot):
    """Start a channel now at measurement y moving at ``ydot`` (to take over a vehicle in
    flight): :func:`channel_init` at y, then the rate estimate z2 and the TD's v2 at ydot (a NaN
    ydot: 0, as channel_init).  The Euler-type observers (Han's NLESO, the Euler LESO) keep z1 one
    nominal step ahead of the last sample, so theirs starts at y + h*ydot."""
    channel_init(s, y, y, 0.0)
    if math.isfinite(ydot) and ydot != 0.0:
        s[S_Z2] = ydot
        s[S_V2] = ydot
        if p[P_KIND] == KIND_HAN or (p[P_KIND] == KIND_LADRC and p[P_OBS] == OBS_EULER):
            s[S_Z1] = y + p[P_H] * ydot


@jit
def hold_disturbance(s):
    """Hold the disturbance estimate z3 and the PID integrator (and its read-out) at no upward
    push.

    Call it after each step of a vertical channel while the vehicle rests on the ground: the
    ground's reaction (it pushes up: z3 < 0 in NED, a PID integrator > 0) is not a disturbance
    to learn and carry into the take-off.  A push down is kept: a vehicle heavier than told
    does not rise on the thrust the loop expected to lift it, and its observer must learn
    that weight on the ground, or the loop waits there for an error large enough to lift it.
    """
    s[S_Z3] = max(s[S_Z3], 0.0)
    s[S_I] = min(s[S_I], 0.0)
    if s.shape[0] >= NSD:
        s[DL_Z1 + 2] = max(s[DL_Z1 + 2], 0.0)


@jit
def _d_alpha(p, h):
    """The PID D-term low-pass factor over an interval h: 1 - exp(-2 pi fc h) (fc = 0: 1)."""
    fc = p[P_FC]
    if fc > 0.0:
        return -math.expm1(-2.0 * math.pi * fc * h)
    return 1.0


@jit_inline
def pid_step(s, p, y, ydot, r, rdot, rddot, h):
    """PX4-style cascade on one axis; returns the virtual control u0 (before 1/b0 and limits).

    ::

        v_sp = rdot + kp_pos (r - y)
        e_v  = v_sp - ydot                          (ydot NaN: backward difference of y)
        I   += h ki_vel e_v,  |I| <= i_limit        (I kept times ki_vel, in acceleration units)
        D    = low-pass(d ydot / dt)                (D on the measurement; skipped if kd_vel = 0)
        u0   = rddot + kp_vel e_v + I - kd_vel D

    ``h``: the interval since the last sample; differences and the integral use it, and the D
    low-pass factor is 1 - exp(-2 pi fc h) (the stored factor at the nominal step).

    Conditional integration: if the command of the last step (S_U0/b0) and what was really
    applied (S_U, which a caller may overwrite after tilt/thrust limits) differ by more than
    1e-6 and e_v would push the command further the same way, I is held.
    """
    if math.isfinite(ydot):
        rate = ydot
    else:
        rate = (y - s[S_YPREV]) / h
    s[S_YPREV] = y
    ev = rdot + p[P_KPP] * (r - y) - rate
    b0 = p[P_B0]
    excess = s[S_U0] / b0 - s[S_U]
    if not (abs(excess) > 1e-6 and excess * b0 * ev > 0.0):
        lim = p[P_ILIM]
        s[S_I] = _clip(s[S_I] + h * p[P_KIV] * ev, -lim, lim)
    u0 = rddot + p[P_KPV] * ev + s[S_I]
    kd = p[P_KDV]
    if kd != 0.0:
        if s[S_INIT] < 2.0:  # first step: no previous rate, no derivative kick
            s[S_VPREV] = rate
            s[S_INIT] = 2.0
        alpha = p[P_DALPHA] if h == p[P_H] else _d_alpha(p, h)
        s[S_DF] += alpha * ((rate - s[S_VPREV]) / h - s[S_DF])
        s[S_VPREV] = rate
        u0 -= kd * s[S_DF]
    s[S_Z1] = y  # read-outs in the observer slots: what the law used, and the integrator's
    s[S_Z2] = rate  # estimate of the disturbance acceleration (steady state: b0 u = I = -d)
    s[S_Z3] = -s[S_I]
    return u0


@jit_inline
def _channel_step(s, p, y, ydot, r, rdot, rddot, h):
    """The body of :func:`channel_update` (inlined into its entries)."""
    if not (math.isfinite(y) and math.isfinite(r) and math.isfinite(rdot) and math.isfinite(rddot)):
        return math.nan
    if h != p[P_H]:
        h = real_step(p, h)
        if h != h:
            return math.nan
    if s[S_INIT] == 0.0:
        channel_init(s, y, r, rdot)
    kind = p[P_KIND]
    if kind == KIND_LADRC:
        leso_step(s, p, y, h)
    elif kind == KIND_HAN:
        nleso_step(s, p, y, h)
    return _law(s, p, y, ydot, r, rdot, rddot, h)


@jit_inline
def _predicted_error(s, p, e1, e2):
    """The errors (e1, e2) carried ``P_PRED`` ahead: to where the vehicle and the reference
    will be when the command computed now acts, at the accelerations of now (the reference's in
    S_AREF; the estimate's, the observer's z3 plus the input model's output in S_U).  Tracking
    exactly, both stay 0; so the lag of the vehicle's response leaves the feedback as far as
    the input model is right."""
    L = p[P_PRED]
    de = s[S_AREF] - (s[S_Z3] + p[P_B0] * s[S_U])
    return e1 + L * (e2 + 0.5 * L * de), e2 + L * de


@jit_inline
def _law(s, p, y, ydot, r, rdot, rddot, h):
    """The control law of a channel on its estimates (the observer has run): u0, u = the limited
    command, kept in S_U0 and S_U."""
    kind = p[P_KIND]
    b0 = p[P_B0]
    if kind == KIND_LADRC:
        if p[P_OBS] == OBS_EULER:
            # the Euler LESO's estimate is one nominal step ahead of the sample: so is the
            # reference it is compared with (as Han's NLESO below)
            hn = p[P_H]
            e1 = r + hn * rdot + 0.5 * hn * hn * rddot - s[S_Z1]
            e2 = rdot + hn * rddot - s[S_Z2]
        else:
            e1 = r - s[S_Z1]
            e2 = rdot - s[S_Z2]
        if p[P_PRED] > 0.0:
            e1, e2 = _predicted_error(s, p, e1, e2)
        u0 = p[P_KP] * e1 + p[P_KD] * e2 + rddot
        u = (u0 - s[S_Z3]) / b0
    elif kind == KIND_HAN:
        if p[P_TD] != 0.0:
            td_step(s, p, r, h)
            v1, v2 = td_output(s)
            acc = s[S_FH]
        else:
            s[S_V1] = v1 = r
            s[S_V2] = v2 = rdot
            acc = rddot
        # Han's NLESO (forward Euler) leaves its estimate one nominal step ahead of the sample
        # (z1 += h (z2 - beta01 e)): the reference it is compared with is taken there too.
        # Compared with the sample's, every step read a moving reference h behind: an error of
        # speed x h (0.1 m at 5 m/s and 50 Hz)
        hn = p[P_H]
        e1 = v1 + hn * v2 + 0.5 * hn * hn * acc - s[S_Z1]
        e2 = v2 + hn * acc - s[S_Z2]
        if p[P_PRED] > 0.0:
            e1, e2 = _predicted_error(s, p, e1, e2)
        if p[P_LAW] == LAW_FHAN:
            u0 = -fhan(e1, p[P_C] * e2, p[P_R], p[P_H1]) + acc
        else:
            u0 = p[P_K1] * fal(e1, p[P_A1], p[P_DL]) + p[P_K2] * fal(e2, p[P_A2], p[P_DL]) + acc
        u = (u0 - s[S_Z3]) / b0
    elif kind == KIND_PID:
        u0 = pid_step(s, p, y, ydot, r, rdot, rddot, h)
        u = u0 / b0
    else:
        if math.isfinite(ydot):
            rate = ydot
        else:
            rate = (y - s[S_YPREV]) / h
        s[S_YPREV] = y
        u0 = p[P_KP] * (r - y) + p[P_KD] * (rdot - rate) + rddot
        u = u0 / b0
    s[S_U0] = u0
    u = _clip(u, p[P_UMIN], p[P_UMAX])
    s[S_U] = u
    return u


@jit
def channel_update(s, p, y, ydot, r, rdot, rddot, h):
    """One control step of a channel of any kind; returns the limited command u.

    ``h`` is the real interval since the sample of the previous step (``p[P_H]``: the nominal
    step; see :func:`real_step`).  ``ydot`` is a measured rate, used by PD and PID only (NaN: they
    differentiate y).  Non-finite y, r, rdot or rddot, or an h that is not a finite number > 0,
    leave the state untouched and return NaN, so a bad sample never enters the observer; the
    caller turns that into an error.
    """
    return _channel_step(s, p, y, ydot, r, rdot, rddot, h)


@jit
def channel_update_nominal(s, p, y, ydot, r, rdot, rddot):
    """:func:`channel_update` at the nominal step ``p[P_H]``: the fixed-rate entry for callers
    in Python (one argument fewer to pass through numba's dispatcher)."""
    return _channel_step(s, p, y, ydot, r, rdot, rddot, p[P_H])


# --- observers that know the sample's age ---------------------------------------------------------
#
# A sample taken ``age`` seconds before the step that uses it (the link, the estimator) is the
# delayed measurement of PX4's EKF2 fusion horizon: the observer runs at the sample's time, fed
# the inputs that were applied then, and is corrected there; the estimate for now is that one
# carried over the age by the observer's own model with the inputs applied since:
#
#     z1 += tau z2 + tau^2/2 (z3 + b0 u_j),   z2 += tau (z3 + b0 u_j)     per input u_j held tau
#
# (a Smith predictor built on the ESO: the extended state z3 keeps the prediction honest).  The
# control law then acts on the estimate for now.  For the linear ESO the prediction is exact for
# inputs held between steps; for Han's NLESO the correction is its own, at the sample's time, and
# the prediction the same linear model.  The Euler-type observers keep their estimate one nominal
# step ahead of the sample; the prediction moves it the age further, inputs in the same order.
#
# The line keeps the delayed estimate and the inputs applied (one per step, with the time it
# began) in the row after the channel's state (``NSD`` entries).  With age 0 at every step the
# observer is fed exactly the input it always was and nothing is predicted: the step is
# :func:`channel_update`'s, bit for bit.


@jit
def _open_loop(s, p, tau, u):
    """Carry the estimate (z1, z2) over ``tau`` with the input u held (z3 constant)."""
    a = s[S_Z3] + p[P_B0] * u
    s[S_Z1] += tau * s[S_Z2] + 0.5 * tau * tau * a
    s[S_Z2] += tau * a


@jit
def _inputs_over(s, p, t0, t1, predict):
    """The inputs applied over [t0, t1] on the line's clock.  ``predict``: carry the estimate
    over the span with them (:func:`_open_loop` piece by piece).  Returns their mean over the
    span (exactly the input, when one was held over all of it) and how many there were.
    Before the oldest input kept the oldest counts; with none kept, the input S_U."""
    n = int(s[DL_N])
    if n == 0:
        if predict:
            _open_loop(s, p, t1 - t0, s[S_U])
        return s[S_U], 1
    eps = H_SNAP * p[P_H]
    head = int(s[DL_HEAD])
    j = 0  # inputs back from the newest: the one applied at t0
    while j < n - 1 and s[DL_TIMES + (head - j) % HIST] > t0 + eps:
        j += 1
    t = t0
    total = 0.0
    pieces = 0
    u = 0.0
    while True:
        u = s[DL_INPUTS + (head - j) % HIST]
        end = t1 if j == 0 else min(t1, s[DL_TIMES + (head - j + 1) % HIST])
        if end - t > eps or (j == 0 and end > t):
            if predict:
                _open_loop(s, p, end - t, u)
            else:
                total += (end - t) * u
            pieces += 1
            t = end
        if j == 0 or t >= t1 - eps:
            break
        j -= 1
    if predict or pieces <= 1:
        return u, pieces
    return total / (t1 - t0), pieces


@jit
def _leso_correct(s, p, y, h):
    """The ZOH LESO's correction with Lc(h), on an estimate already predicted to the sample."""
    e = y - s[S_Z1]
    if h == p[P_H]:
        s[S_Z1] += p[P_L1] * e
        s[S_Z2] += p[P_L2] * e
        s[S_Z3] += p[P_L3] * e
        return
    beta = math.exp(-p[P_WO] * h)
    omb = -math.expm1(-p[P_WO] * h)
    s[S_Z1] += (1.0 - beta * beta * beta) * e
    s[S_Z2] += 1.5 * omb * omb * (1.0 + beta) / h * e
    s[S_Z3] += omb * omb * omb / (h * h) * e


@jit
def _push_input(s, t, u):
    n = int(s[DL_N])
    head = (int(s[DL_HEAD]) + 1) % HIST if n > 0 else 0
    s[DL_TIMES + head] = t
    s[DL_INPUTS + head] = u
    s[DL_HEAD] = head
    s[DL_N] = min(n + 1, HIST)


@jit
def set_applied_input(s, u):
    """The input applied from the last step on is ``u`` (a caller's limits, an input model):
    S_U, and the newest input of the delay line if the row has one in use."""
    s[S_U] = u
    if s.shape[0] >= NSD and s[DL_ON] != 0.0 and s[DL_N] > 0.0:
        s[DL_INPUTS + int(s[DL_HEAD])] = u


@jit
def previous_age(s, default):
    """The age of the sample of the last step (``default`` with no delay line in use)."""
    if s.shape[0] < NSD or s[DL_ON] == 0.0:
        return default
    return s[DL_NOW] - s[DL_T]


@jit
def channel_update_aged(s, p, y, ydot, r, rdot, rddot, h, age):
    """:func:`channel_update` on a sample taken ``age`` s before now (``h``: the interval since
    the sample of the last step, both taken at their sample times).

    LADRC and classical ADRC with a delay line (a row of NSD entries): the observer corrects its
    estimate at the sample's time, fed the inputs applied then, and the law acts on that
    estimate carried to now with the inputs applied since (see above); ``r, rdot, rddot`` are
    the reference for now.  An age past :data:`AGE_MAX` counts as AGE_MAX; a step whose age
    would take the clock back (a measured age that dropped by more than the interval) is taken
    at the last step's time.  PD, PID and rows without a delay line: :func:`channel_update`
    (the age is ignored).  NaN (state untouched) on what channel_update refuses or a NaN age.
    """
    kind = p[P_KIND]
    if (kind != KIND_LADRC and kind != KIND_HAN) or s.shape[0] < NSD:
        return _channel_step(s, p, y, ydot, r, rdot, rddot, h)
    if not (math.isfinite(y) and math.isfinite(r) and math.isfinite(rdot) and math.isfinite(rddot)
            and age == age):
        return math.nan
    if h != p[P_H]:
        h = real_step(p, h)
        if h != h:
            return math.nan
    age = min(max(age, 0.0), AGE_MAX)
    if s[S_INIT] == 0.0:
        channel_init(s, y, r, rdot)
    if s[DL_ON] == 0.0:  # seeded with the estimate there is, as of the last sample
        s[DL_ON] = 1.0
        s[DL_T] = 0.0
        s[DL_NOW] = age
        s[DL_N] = 0.0
        s[DL_HEAD] = 0.0
        for i in range(3):
            s[DL_Z1 + i] = s[S_Z1 + i]
    t0 = s[DL_T]
    t1 = t0 + h
    now = max(t1 + age, s[DL_NOW])
    hl = h  # the interval since the last step, for the law (its TD): h unless the age changed
    dage = (now - t1) - (s[DL_NOW] - t0)
    if dage != 0.0:
        hl = real_step(p, h + dage) if h + dage > 0.0 else h
    # the delayed observer, at the sample's time, fed the inputs applied then: the ZOH LESO
    # predicts with each exactly; the Euler-type observers, whose recursion takes one input,
    # with their mean (exact for the rate)
    u_then, pieces = _inputs_over(s, p, t0, t1, False)
    for i in range(3):
        s[S_Z1 + i] = s[DL_Z1 + i]
    s[S_U] = u_then
    if kind == KIND_LADRC and p[P_OBS] == OBS_ZOH and pieces > 1:
        _inputs_over(s, p, t0, t1, True)
        _leso_correct(s, p, y, h)
    elif kind == KIND_LADRC:
        leso_step(s, p, y, h)
    else:
        nleso_step(s, p, y, h)
    for i in range(3):
        s[DL_Z1 + i] = s[S_Z1 + i]
    s[DL_T] = t1
    # carried to now
    if now > t1:
        _inputs_over(s, p, t1, now, True)
    s[DL_NOW] = now
    if p[P_PRED] > 0.0 and s[DL_N] > 0.0:  # a law that predicts reads the input applied now
        s[S_U] = s[DL_INPUTS + int(s[DL_HEAD])]
    u = _law(s, p, y, ydot, r, rdot, rddot, hl)
    _push_input(s, now, u)
    return u


# --- parameter construction (plain Python, run once) ---------------------------------------------


def leso_gains(wo, h, discretization):
    """Observer gains for bandwidth ``wo``: the ZOH current observer's Lc, or l = (3wo, 3wo^2, wo^3)."""
    if discretization == "zoh":
        beta = math.exp(-wo * h)
        return (
            1.0 - beta**3,
            1.5 * (1.0 - beta) ** 2 * (1.0 + beta) / h,
            (1.0 - beta) ** 3 / h**2,
        )
    return 3.0 * wo, 3.0 * wo**2, wo**3


def han_eso_gains(h, convention="han"):
    """Default NLESO gains from the step h.

    ``"han"``: beta01 = 1/h, beta02 = 1/(1.6 h^1.5), beta03 = 1/(8.6 h^2.2) (Han's book).
    ``"thesis"``: the thesis's eq. 25 premultiplied set B0i = h*beta0i = (1, 1/(2 h^0.5),
    2/(25 h^1.2)), i.e. beta01 = 1/h, beta02 = 1/(2 h^1.5), beta03 = 2/(25 h^2.2).
    """
    if convention == "han":
        return 1.0 / h, 1.0 / (1.6 * h**1.5), 1.0 / (8.6 * h**2.2)
    if convention == "thesis":
        return 1.0 / h, 1.0 / (2.0 * h**1.5), 2.0 / (25.0 * h**2.2)
    raise ValueError(f"eso_gains: unknown convention {convention!r} (expected 'han' or 'thesis')")


def new_params():
    p = np.zeros(NP)
    p[P_UMIN] = -math.inf
    p[P_UMAX] = math.inf
    p[P_B0] = 1.0
    return p


def new_state(delay_line=False):
    """A channel's state vector (``delay_line``: with room for :func:`channel_update_aged`)."""
    return np.zeros(NSD if delay_line else NS)


@jit
def observer_update(s, p, y, u, h):
    """Advance a standalone ESO (LADRC or HAN kind) with measurement y and applied input u over
    the interval h.

    Returns False (state untouched) for a non-finite y or u, or an h that is not finite and > 0.
    """
    if not (math.isfinite(y) and math.isfinite(u)):
        return False
    h = real_step(p, h)
    if h != h:
        return False
    if s[S_INIT] == 0.0:
        channel_init(s, y, y, 0.0)
    s[S_U] = u
    if p[P_KIND] == KIND_HAN:
        nleso_step(s, p, y, h)
    else:
        leso_step(s, p, y, h)
    return True


@jit
def td_update(s, p, v, h):
    """Advance a standalone TD over the interval h; returns False (state untouched) for a
    non-finite v or an h that is not finite and > 0."""
    if not math.isfinite(v):
        return False
    h = real_step(p, h)
    if h != h:
        return False
    td_step(s, p, v, h)
    return True
