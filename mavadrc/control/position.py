"""Position controller: three channels (x, y, z NED) -> desired acceleration -> attitude + thrust.

Each axis is a channel of the chosen kind acting on the double integrator ``p'' = a + d`` with
``b0 = 1`` (the command is an acceleration in m/s^2, gravity included on z).  The geometric map of
:mod:`mavadrc.control.geometry` turns the three commands into an attitude quaternion and a
normalized thrust, with a tilt limit and altitude priority; each observer is then fed the
acceleration the *limited* setpoint really commands.
"""

import math

import numpy as np

from . import geometry as G
from . import kernels as K
from .channels import han_params, ladrc_params, nonfinite_arrays, pd_params, pid_params
from .jit import jit

AXES = ("x", "y", "z")

# the observers' input model, one row per axis (see ``input_lag``)
IN_ALPHA = 0  # 1 - exp(-h/tau) at the nominal step, per lag (1: no lag)
IN_STATE = 1  # the last lag's output: the acceleration the observer is fed
IN_TAU = 2  # each lag's time constant (s; 0: none)
IN_DIFF = 3  # the last lag's input minus its output before the last advance (to redo it)
IN_DRAG = 4  # the vehicle's linear drag (1/s; 0: none): a = u - drag * v + disturbance
IN_NLAG = 5  # how many equal lags (1 or 2: input_lags)
IN_L1 = 6  # with two lags, the first one's output
IN_DIFF1 = 7  # with two lags, the first one's input minus its output before the last advance
IN_ND = 8  # the dead time before the lags, in nominal steps (input_dead_time)
IN_HEAD = 9  # the slot of the dead time's ring of commands read and written next
IN_LEAD = 10  # s: the model's mean delay (dead time + lags x tau): the feed-forward's lead
IN_BUF = 11  # the ring of the last IN_ND commands
DEAD_MAX = 80  # the longest dead time, in steps (0.32 s at 250 Hz, 0.8 s at 100 Hz)
NIN = IN_BUF + DEAD_MAX
#: the 63 % time of n equal first-order lags, in units of their time constant (n = 1, 2)
LAG63 = (0.0, 1.0, 2.1462)
DRAG_MAX = 20.0  # the most drag (1/s per axis) a model may give, learnt or told


@jit
def position_update(S, P, M, IN, pos, vel, rpos, rvel, racc, yaw, out, h, age):
    """One step of the three position channels and the attitude map; False on non-finite input.

    S: (3, NS) channel states (or (3, NSD): with delay lines), P: (3, NP) channel parameters,
    M: mapping parameters, IN: (3, NIN) the observers' input model per axis (IN_* columns; see
    ``input_lag``).  ``vel`` is the measured velocity (used by PD and PID channels; NaN entries
    make them differentiate).  ``out``: the layout of :func:`geometry.accel_to_attitude`
    followed by the three raw commands.  ``h``: the interval since the sample of the last step
    (P[:, P_H] is nominal).  ``age``: how long before now the sample was taken (s): the
    observers of rows with delay lines correct at the sample's time and the law acts on their
    estimate for now, the reference being now's (:func:`kernels.channel_update_aged`); NaN:
    the sample is taken as now's (the age is not compensated).  A law that predicts
    (``P_PRED`` > 0) reads the reference's own acceleration now in its state's ``S_AREF`` (the
    caller sets it: ``racc`` is the acceleration fed forward).

    The input model is the first-order lag ``u_obs += alpha (u_applied - u_obs)``, alpha = 1 -
    exp(-h/tau), exact for a command held over the interval.  Each step advances it by the
    nominal step (the next interval is not known yet) and the next step, once it knows the
    interval, redoes that advance with its alpha: the observer then predicts with the input the
    vehicle really received, across a gap too.  With the age compensated the interval is the
    one between the steps (the samples' interval plus the change of their age).
    """
    for i in range(3):
        if not (math.isfinite(pos[i]) and math.isfinite(rpos[i]) and math.isfinite(rvel[i])
                and math.isfinite(racc[i]) and math.isfinite(S[i, K.S_AREF])):
            return False
    if not math.isfinite(yaw):
        return False
    hh = K.real_step(P[0], h)
    if hh != hh:
        return False
    if M[G.M_TPA_RATE] > 0.0:
        # from the estimates of the last step (on the ground its z3 was held at 0 after it)
        learn_thrust(S[2], M, IN[2, IN_STATE], hh, P[2, K.P_KIND] == K.KIND_PID)
    aged = age == age
    for i in range(3):
        hs = hh
        if aged:  # the interval between the steps, over which the last command was held
            a = min(max(age, 0.0), K.AGE_MAX)
            hs = max(hh + a - K.previous_age(S[i], a), 0.0)
            if abs(hs - P[0, K.P_H]) <= K.H_SNAP * P[0, K.P_H]:
                hs = P[0, K.P_H]
        tau = IN[i, IN_TAU]
        if hs != P[0, K.P_H] and tau > 0.0:
            corr = -math.expm1(-hs / tau) - IN[i, IN_ALPHA]
            da = corr * IN[i, IN_DIFF]
            if IN[i, IN_NLAG] >= 2.0:
                # the first lag's advance redone too, and (to first order) what its change
                # did to the second's
                d1 = corr * IN[i, IN_DIFF1]
                IN[i, IN_L1] += d1
                da += (IN[i, IN_ALPHA] + corr) * d1
            IN[i, IN_STATE] += da
            K.set_applied_input(S[i], S[i, K.S_U] + da)
    # the drag the model knows is fed forward along the reference (the observers see it as
    # part of their input: their z3 is what is left)
    f0 = racc[0] + IN[0, IN_DRAG] * rvel[0]
    f1 = racc[1] + IN[1, IN_DRAG] * rvel[1]
    f2 = racc[2] + IN[2, IN_DRAG] * rvel[2]
    if aged:
        a0 = K.channel_update_aged(S[0], P[0], pos[0], vel[0], rpos[0], rvel[0], f0, hh, age)
        a1 = K.channel_update_aged(S[1], P[1], pos[1], vel[1], rpos[1], rvel[1], f1, hh, age)
        a2 = K.channel_update_aged(S[2], P[2], pos[2], vel[2], rpos[2], rvel[2], f2, hh, age)
    else:
        a0 = K.channel_update(S[0], P[0], pos[0], vel[0], rpos[0], rvel[0], f0, hh)
        a1 = K.channel_update(S[1], P[1], pos[1], vel[1], rpos[1], rvel[1], f1, hh)
        a2 = K.channel_update(S[2], P[2], pos[2], vel[2], rpos[2], rvel[2], f2, hh)
    G.accel_to_attitude(a0, a1, a2, yaw, M, out)
    for i in range(3):
        # the observers' input: the limited command through the input model (a dead time and
        # one or two first-order lags standing for the vehicle's attitude and motor response;
        # alpha 1 and no dead time = none)
        x = input_model_advance(IN[i], out[G.O_ACC + i])
        diff = x - IN[i, IN_STATE]
        IN[i, IN_DIFF] = diff
        IN[i, IN_STATE] += IN[i, IN_ALPHA] * diff
        # and the drag along the reference, fed forward above, as known
        K.set_applied_input(S[i], IN[i, IN_STATE] - IN[i, IN_DRAG] * rvel[i])
    out[G.NO] = a0
    out[G.NO + 1] = a1
    out[G.NO + 2] = a2
    return True


@jit
def input_model_advance(row, command):
    """The input model's row ``row`` (IN_* columns) taking ``command``: the dead time's ring
    advanced and, with two lags, the first lag; returns the last lag's input (the caller
    advances it)."""
    x = command
    nd = int(row[IN_ND])
    if nd > 0:
        head = int(row[IN_HEAD])
        x = row[IN_BUF + head]  # the command of nd steps ago
        row[IN_BUF + head] = command
        row[IN_HEAD] = (head + 1) % nd
    if row[IN_NLAG] >= 2.0:
        d1 = x - row[IN_L1]
        row[IN_DIFF1] = d1
        row[IN_L1] += row[IN_ALPHA] * d1
        x = row[IN_L1]
    return x


@jit
def input_model_rest(row, a):
    """The input model's row at rest with ``a`` applied all along (every stage holds it)."""
    row[IN_STATE] = a
    row[IN_L1] = a
    row[IN_DIFF] = 0.0
    row[IN_DIFF1] = 0.0
    row[IN_HEAD] = 0.0
    for k in range(DEAD_MAX):
        row[IN_BUF + k] = a


#: the thrust per acceleration learnt in flight stays within this factor of the figure told
TPA_RANGE = 2.0
#: s: the time constant with which a mission's LADRC and ADRC learn the thrust per acceleration
#: in flight (``thrust_estimate``, on by default, like PX4's hover thrust estimator); a vehicle
#: 30 % lighter than told otherwise gets 1.43x the horizontal loop gain it was tuned for
THRUST_ESTIMATE_S = 2.0


@jit
def learn_thrust(Sz, M, applied, h, pid=False):
    """Learn the thrust per acceleration (M_TPA) from the vertical observer, as PX4's hover
    thrust estimator learns MPC_THR_HOVER.

    With M_TPA too large by a factor k (the vehicle lighter than told), every thrust gives k
    times the specific force the map meant: the vertical observer cancels that on its own axis
    (its disturbance z3 = (1 - k) f_up, f_up = g - a_z the upward specific force it modelled as
    applied), but the tilt still turns k times the horizontal acceleration commanded, and a
    horizontal loop tuned to the margin it keeps then limit-cycles.  So M_TPA moves towards
    M_TPA / k at M_TPA_RATE per second (far slower than any observer, which relearns z3 as it
    moves), within TPA_RANGE of the figure told.  What is learnt is moved out of z3: with M_TPA
    times f, z3 += f_up (1/f - 1), so the next command asks for f_up / f, the thrust and the
    observer's prediction are what they were, and the vertical loop does not count the weight
    twice while z3 relearns (counted twice, a vehicle 30 % heavier leapt 0.5 m past its
    take-off altitude).  On the ground only a push down is kept in z3 (:func:`kernels.
    hold_disturbance`): a weight the thrust does not lift is learnt there too.

    ``pid``: the vertical channel is a PID, whose disturbance estimate is its velocity
    integrator's (z3 = -I, :func:`kernels.pid_step`): what is learnt is moved out of the
    integrator too (the read-out z3 is rewritten from it at the next step)."""
    up = M[G.M_G] - applied
    if not (up > 0.25 * M[G.M_G]):
        return  # falling or thrust near its floor: no hover to learn from
    k = 1.0 - Sz[K.S_Z3] / up
    if not (k > 0.0):
        return
    a = min(h * M[G.M_TPA_RATE], 1.0)
    old = M[G.M_TPA]
    tpa = old + a * (old / k - old)
    lo, hi = M[G.M_TPA0] / TPA_RANGE, M[G.M_TPA0] * TPA_RANGE
    tpa = min(max(tpa, lo), hi)
    M[G.M_TPA] = tpa
    dz = up * (old / tpa - 1.0)
    Sz[K.S_Z3] += dz
    if pid:
        Sz[K.S_I] -= dz
    if Sz.shape[0] >= K.NSD:
        Sz[K.DL_Z1 + 2] += dz


@jit
def position_start(S, P, IN, pos, vel):
    """Start the three channels now at ``pos`` (and rate estimates at ``vel``; NaN entries: 0),
    with the input model at rest (see :func:`kernels.channel_start`)."""
    for i in range(3):
        input_model_rest(IN[i], 0.0)
        S[i, :] = 0.0
        K.channel_start(S[i], P[i], pos[i], vel[i])


@jit
def position_hold_disturbance(S):
    """:func:`kernels.hold_disturbance` on the vertical channel, while on the ground.

    The ground pushes up: that reaction is no disturbance to carry into the take-off.  Sideways
    the ground holds the vehicle by friction only until the thrust nears its weight; a wind then
    pushes it before it leaves the ground, and the horizontal observers must be learning that."""
    K.hold_disturbance(S[2])


def _model_axes(value, kind, name, unit, most, what):
    """A per-axis figure of the observers' model (``input_lag``, ``drag``) checked: None when
    not given, else three finite numbers in 0..``most``; only the observer kinds take one."""
    if value is None:
        return None
    if kind not in ("ladrc", "adrc"):
        raise ValueError(f"{name} {what}: it applies to the 'ladrc' and 'adrc' kinds, not "
                         f"{kind!r}")
    out = [float(_axis(value, i, name)) for i in range(3)]
    if not all(math.isfinite(x) and 0.0 <= x <= most for x in out):
        bound = f">= 0 {unit}" if most == math.inf else f"within 0-{most:g} {unit}"
        raise ValueError(f"{name} must be {bound} (got {value!r})")
    return out


def _axis(value, i, name):
    """A per-axis setting: a scalar for all axes, or a sequence of three (x, y, z).

    ``beta`` (the NLESO gains, already a triple) is per axis only when given as three triples.
    """
    if name == "beta" and value is not None and not isinstance(value[0], (list, tuple, np.ndarray)):
        return value  # one (beta01, beta02, beta03) set for every axis
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != 3:
            raise ValueError(f"{name} must be a number or three numbers (x, y, z), got {value!r}")
        return value[i]
    return value


def check_latency(latency, kind):
    """A controller's ``latency`` setting: None (not compensated; also for 0), ``"auto"`` or a
    number of seconds in (0, AGE_MAX]; ValueError otherwise or on a kind without an observer."""
    if latency is None:
        return None
    if isinstance(latency, str):
        if latency != "auto":
            raise ValueError(f"latency must be 'auto' or a number of seconds (got {latency!r})")
    else:
        latency = float(latency)
        if not (math.isfinite(latency) and 0.0 <= latency <= K.AGE_MAX):
            raise ValueError(f"latency must be between 0 and {K.AGE_MAX:g} s (got {latency!r})")
        if latency == 0.0:
            return None
    if kind not in ("ladrc", "adrc"):
        raise ValueError("latency is compensated by the observers: it applies to the 'ladrc' "
                         f"and 'adrc' kinds, not {kind!r}")
    return latency


def authority(mapping):
    """Per axis (x, y, z), the acceleration (m/s^2) the vehicle can give either way: horizontally
    what the tilt limit allows at hover, g tan(tilt_max); vertically the smaller of the climb
    and the descent the thrust limits leave."""
    g, tpa = mapping[G.M_G], mapping[G.M_TPA]
    horizontal = g * math.tan(mapping[G.M_TILT])
    vertical = min(mapping[G.M_THR_MAX] / tpa - g, g - mapping[G.M_THR_MIN] / tpa)
    return (horizontal, horizontal, vertical)


def axis_params(kind, i, h, gains):
    """Kernel parameters of position axis ``i`` from per-axis gain keywords."""
    g = {k: _axis(v, i, k) for k, v in gains.items()}
    if kind == "ladrc":
        return ladrc_params(h=h, b0=g.pop("b0", 1.0), **g)
    if kind == "adrc":
        return han_params(h=h, b0=g.pop("b0", 1.0), **g)
    if kind == "pd":
        if "wc" in g:
            wc = g.pop("wc")
            g.setdefault("kp", wc * wc)
            g.setdefault("kd", 2.0 * wc)
        return pd_params(h=h, **g)
    if kind == "pid":
        return pid_params(h=h, **g)
    raise ValueError(f"controller kind must be 'adrc', 'ladrc', 'pd' or 'pid' (got {kind!r})")


class PositionController:
    """Three position channels of one kind and the geometric attitude map.

    ``PositionController(kind="ladrc", h=0.01, hover_thrust=0.5, wc=(2, 2, 3), wo=(10, 10, 15))``

    Gain keywords are those of the channel kind (``wc, wo, b0`` for 'ladrc'; ``r0, r, c, h1, ...``
    for 'adrc'; ``kp, kd`` or ``wc`` for 'pd'; ``wc`` or ``kp_pos, kp_vel, ki_vel, kd_vel`` and
    ``i_limit, d_cutoff_hz`` for 'pid'), each a scalar or an (x, y, z) triple.  The PID channels'
    integrators see the acceleration the limited setpoint commands, so they hold still while the
    tilt or thrust limits cut their axis (conditional integration).  Thrust is
    normalised by ``hover_thrust`` or by ``mass`` and ``max_thrust`` (N).  ``tilt_max`` is in rad.

    ``latency`` ('ladrc' and 'adrc'): how old the samples are, for the observers to compensate
    (:func:`kernels.channel_update_aged`): ``"auto"``, the age :meth:`update` is given with each
    sample (none given: 0); a number of seconds, every sample's age; 0 or None, not compensated
    (the sample is taken as now's).  Either way the reference :meth:`update` is given must be
    the one for now.

    ``input_lag`` ('ladrc' and 'adrc'; s per axis): the observers' input model, the time the
    vehicle's acceleration takes to reach 63 % of a step commanded.  Alone, one first-order lag
    of that time constant.  With ``input_dead_time`` (s per axis) and ``input_lags`` (1 or 2)
    it is shaped as identified in flight: the dead time (whole steps) and then that many equal
    lags sharing the rest of the 63 % time.  ``drag`` (1/s per axis): the linear drag modelled.

    ``predict`` (with an input model): the law acts on its errors carried the input model's
    mean delay ahead (:attr:`prediction`), where they will be when the command it computes
    takes effect: at the reference's own acceleration now (:meth:`update`'s ``ref_acc_now``)
    and the one the observers read (their z3 and the input model's output).  The lag of the
    vehicle's response leaves the loop's feedback as far as the model is right: the loop keeps
    more of its delay margin at the same bandwidths.
    """

    def __init__(self, kind="ladrc", *, h, hover_thrust=None, mass=None, max_thrust=None,
                 tilt_max=math.radians(35.0), thrust_min=0.05, thrust_max=1.0, g=G.GRAVITY,
                 latency=None, thrust_estimate_tau=None, predict=False, **gains):
        self.kind = kind
        self.latency = check_latency(latency, kind)
        self._IN = np.zeros((3, NIN))
        self._IN[:, IN_ALPHA] = 1.0
        self._IN[:, IN_NLAG] = 1.0
        lag = _model_axes(gains.pop("input_lag", None), kind, "input_lag", "s", math.inf,
                          "models the observers' input")
        dead = _model_axes(gains.pop("input_dead_time", None), kind, "input_dead_time", "s",
                           DEAD_MAX * h, "is part of the observers' input model")
        nlag = gains.pop("input_lags", 1)
        if nlag not in (1, 2):
            raise ValueError(f"input_lags must be 1 or 2 (got {nlag!r})")
        if (dead is not None or nlag != 1) and lag is None:
            raise ValueError("input_dead_time and input_lags shape the input model: give "
                             "input_lag (its 63 % time) too")
        if lag is not None:
            for i, t63 in enumerate(lag):
                # the 63 % time given, the dead time before the lags, the lags share the rest
                d = 0.0 if dead is None else min(dead[i], t63)
                tau = (t63 - d) / LAG63[nlag]
                self._IN[i, IN_ALPHA] = 1.0 - math.exp(-h / tau) if tau > 0.0 else 1.0
                self._IN[i, IN_TAU] = tau
                self._IN[i, IN_NLAG] = nlag if tau > 0.0 else 1.0
                self._IN[i, IN_ND] = round(d / h)
                self._IN[i, IN_LEAD] = d + self._IN[i, IN_NLAG] * tau
        drag = _model_axes(gains.pop("drag", None), kind, "drag", "/s", DRAG_MAX,
                           "is part of the observers' model")
        if drag is not None:
            self._IN[:, IN_DRAG] = drag
        if thrust_estimate_tau is not None and kind not in ("ladrc", "adrc", "pid"):
            raise ValueError("the thrust is learnt from the vertical disturbance estimate (an "
                             "observer's z3, a PID's integrator): thrust_estimate_tau applies "
                             f"to the 'ladrc', 'adrc' and 'pid' kinds, not {kind!r}")
        self._M = G.mapping_params(hover_thrust=hover_thrust, mass=mass, max_thrust=max_thrust,
                                   tilt_max=tilt_max, thrust_min=thrust_min,
                                   thrust_max=thrust_max, g=g,
                                   thrust_estimate_tau=thrust_estimate_tau)
        self._tpa_rate = float(self._M[G.M_TPA_RATE])  # restored when learning resumes
        self._P = np.stack([axis_params(kind, i, h, gains) for i in range(3)])
        if kind == "adrc":
            # the TD shapes the reference into a motion the vehicle can fly: its acceleration
            # (fed forward) bounded by what the tilt and thrust limits allow; and near the
            # reference it is a linear filter on the loop's own time scale, the NLSEF's h1
            # (1/wc): with h0 = h its fh is bang-bang at +-r0 for any offset past r0 h^2 (under
            # a millimetre), so a controller taking over 3 cm off its reference was kicked at
            # the full 7 m/s^2 (PX4 SITL)
            if "r0" not in gains:
                self._P[:, K.P_R0] = authority(self._M)
            if "h0" not in gains:
                self._P[:, K.P_H0] = np.maximum(self._P[:, K.P_H1], self._P[:, K.P_H])
            if self._P[0, K.P_TD] != 0.0:
                # the law tracks the TD's profile and feeds forward its fh, not the reference's
                # motion: the drag along the reference is not fed forward, so not modelled
                self._IN[:, IN_DRAG] = 0.0
        if predict:
            if kind not in ("ladrc", "adrc"):
                raise ValueError("predict carries the law's errors on the observers' estimate: "
                                 f"the 'ladrc' and 'adrc' kinds, not {kind!r}")
            if lag is None:
                raise ValueError("predict carries the law's errors over the input model's delay: "
                                 "give input_lag too")
            if kind == "adrc" and self._P[0, K.P_TD] != 0.0:
                raise ValueError("predict is not for the classical ADRC with its TD (the TD "
                                 "shapes the reference the law tracks): give td: false")
            self._P[:, K.P_PRED] = self._IN[:, IN_LEAD]
        self._h = float(self._P[0, K.P_H])
        self._S = np.zeros((3, K.NSD))
        self._out = np.zeros(G.NO + 3)
        self._nan3 = np.full(3, math.nan)
        self._zero3 = np.zeros(3)

    def reset(self, pos=None, vel=None):
        """Start again: at ``pos`` now, or from the next measurement.

        ``vel``: the measured velocity, to take over a vehicle already moving: the rate
        estimates (z2; classical ADRC: also the TD's v2) start there instead of at 0 (and the
        Euler-type observers' z1 one nominal step ahead, as they keep it).
        """
        if pos is not None:
            p = np.array(pos, dtype=np.float64).reshape(3)
            v = np.zeros(3) if vel is None else np.array(vel, dtype=np.float64).reshape(3)
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
                raise nonfinite_arrays(pos=p, vel=v)
            position_start(self._S, self._P, self._IN, p, v)
        elif vel is not None:
            raise ValueError("reset(vel=...) needs pos: the estimates start at a measured "
                             "position")
        else:
            self._S[:] = 0.0
            for i in range(3):
                input_model_rest(self._IN[i], 0.0)

    def hold_disturbance(self):
        """Zero the vertical disturbance estimate z3 (PID: the integrator).

        Call it after each :meth:`update` while the vehicle rests on the ground, so the
        observers do not learn the ground's reaction and carry it into the take-off
        (:func:`position_hold_disturbance`: only the vertical axis)."""
        position_hold_disturbance(self._S)

    def sample_age(self, age=None):
        """The age (s) the observers are told for a sample measured ``age`` s old (None:
        unknown): NaN when the controller does not compensate it."""
        if self.latency is None:
            return math.nan
        if self.latency == "auto":
            return 0.0 if age is None or not math.isfinite(age) else max(float(age), 0.0)
        return self.latency

    def update(self, pos, vel=None, ref_pos=None, ref_vel=None, ref_acc=None, yaw=0.0, dt=None,
               age=None, ref_acc_now=None):
        """One step: returns (q [w, x, y, z], normalized thrust).

        ``pos``/``vel``: measured NED position and velocity (``vel`` may be None for ADRC kinds;
        PD and PID then differentiate).  ``ref_*``: reference and its derivatives (None: zero).
        ``dt``: the interval (s) since the sample of the last step, from the vehicle's
        timestamps (None: the nominal step ``h``); it must be a finite number > 0.  ``age``: how
        long before now the sample was taken, as measured (s; None: unknown), used as
        ``latency`` says (:meth:`sample_age`).  ``ref_acc_now``: where ``ref_acc`` is the
        acceleration fed forward (led, with the drag's), the reference's own acceleration, which
        a law that predicts (:attr:`prediction`) compares with its estimate's (None: ``ref_acc``).
        """
        pos = np.asarray(pos, dtype=np.float64)
        vel = self._nan3 if vel is None else np.asarray(vel, dtype=np.float64)
        rp = pos if ref_pos is None else np.asarray(ref_pos, dtype=np.float64)
        rv = self._zero3 if ref_vel is None else np.asarray(ref_vel, dtype=np.float64)
        ra = self._zero3 if ref_acc is None else np.asarray(ref_acc, dtype=np.float64)
        h = self._h if dt is None else float(dt)
        self._S[:, K.S_AREF] = ra if ref_acc_now is None else ref_acc_now
        if not position_update(self._S, self._P, self._M, self._IN, pos, vel, rp, rv, ra,
                               float(yaw), self._out, h, self.sample_age(age)):
            if not (h > 0.0 and math.isfinite(h)):
                raise ValueError(f"dt must be a finite interval > 0 s (got {dt!r}); state left "
                                 "unchanged")
            raise nonfinite_arrays(pos=pos, ref_pos=rp, ref_vel=rv, ref_acc=ra, yaw=yaw,
                                   ref_acc_now=self._S[:, K.S_AREF])
        return self._out[G.O_Q:G.O_Q + 4].copy(), float(self._out[G.O_THRUST])

    @property
    def accel_command(self):
        """The three channels' acceleration commands of the last step (before the map's limits)."""
        return self._out[G.NO:G.NO + 3].copy()

    @property
    def accel_applied(self):
        """The acceleration the limited setpoint commands (what the observers were fed)."""
        return self._out[G.O_ACC:G.O_ACC + 3].copy()

    @property
    def z(self):
        """(3, 3) observer estimates: row per axis, columns z1, z2, z3 (PID: the position and
        rate it used, and its integrator's disturbance estimate).  The vertical z3 is the
        total disturbance against the thrust told: with the thrust learnt
        (``thrust_estimate_tau``), the part of it the learnt thrust has taken over is added
        back (:attr:`disturbance`)."""
        z = self._S[:, K.S_Z1:K.S_Z3 + 1].copy()
        z[2, 2] += self._learnt_share()
        return z

    @property
    def disturbance(self):
        """Estimated total disturbance acceleration per axis (z3; zero for PD; PID: minus the
        integrator's acceleration), against the thrust told: with the thrust learnt, vertically
        z3 + f_up (M_TPA / M_TPA0 - 1), the acceleration the learnt thrust adds to what the told
        one would give (f_up = g - the vertical acceleration applied)."""
        d = self._S[:, K.S_Z3].copy()
        d[2] += self._learnt_share()
        return d

    def _learnt_share(self):
        """The vertical acceleration the learnt thrust adds to what the one told would give,
        f_up (M_TPA / M_TPA0 - 1): 0 when the thrust is not learnt."""
        up = self._M[G.M_G] - self._IN[2, IN_STATE]
        return up * (self._M[G.M_TPA] / self._M[G.M_TPA0] - 1.0)

    def continue_from(self, old):
        """Go on where ``old`` (of this kind, its gains or model changed) is: every observer
        state, the input model's state and the thrust learnt, so the loop goes on without a
        jump mid-flight."""
        self._S[:] = old._S
        same = np.array_equal(self._IN[:, [IN_NLAG, IN_ND]], old._IN[:, [IN_NLAG, IN_ND]])
        for i in range(3):
            if same:  # the same stages: their states go on (the new lags' alphas take over)
                for col in (IN_STATE, IN_L1, IN_HEAD):
                    self._IN[i, col] = old._IN[i, col]
                self._IN[i, IN_BUF:] = old._IN[i, IN_BUF:]
            else:  # reshaped: held at the acceleration it gave
                input_model_rest(self._IN[i], old._IN[i, IN_STATE])
        if self.learns_thrust and old.learns_thrust:
            self.adopt_thrust(old)

    def take_over_from(self, old, pos, vel, ref_vel=None):
        """Start where ``old`` (any kind) left off: at the measured ``pos``/``vel``, with
        ``old``'s disturbance estimates, the thrust it had learnt (both learning) and the
        acceleration it last commanded as the input model's state (a controller made anew
        mid-flight then takes over without a jump).  ``ref_vel``: the reference's velocity now;
        the drag along it that this one models and ``old`` did not is moved out of the
        disturbance estimates (left in, it was fed forward twice: on PX4 SIH, taking over 1.5 s
        into the run-up at 0.75 m/s, the command went from -1.2 to -3 m/s^2 and the vehicle fell
        0.17 m off)."""
        self.reset(pos, vel)
        self._S[:, K.S_Z3] = old._S[:, K.S_Z3]
        if ref_vel is not None:
            self._S[:, K.S_Z3] += (self.drag - old.drag) * np.asarray(ref_vel, dtype=float)
        for i, a in enumerate(old.accel_applied):
            input_model_rest(self._IN[i], a)
        if self.learns_thrust and old.learns_thrust:
            self.adopt_thrust(old)
        elif old.learns_thrust:  # this one keeps the thrust told: its z3 is the whole disturbance
            self._S[2, K.S_Z3] = old.disturbance[2]

    def adopt_thrust(self, other):
        """Take the thrust per acceleration ``other`` has learnt (a controller taking over)."""
        self.adopt_thrust_of(other._M)

    def adopt_thrust_of(self, mapping):
        """Take the thrust per acceleration of a mapping vector (a copy of :attr:`params`' that
        a batch kernel flew and learnt in)."""
        self._M[G.M_TPA] = mapping[G.M_TPA]

    @property
    def learns_thrust(self):
        """Whether the thrust per acceleration is learnt in flight (``thrust_estimate_tau``),
        paused or not."""
        return self._tpa_rate > 0.0

    @property
    def thrust_learning_paused(self):
        """Whether learning the thrust is paused (:meth:`pause_thrust_learning`)."""
        return self.learns_thrust and not self._M[G.M_TPA_RATE] > 0.0

    def pause_thrust_learning(self, paused=True):
        """Hold the thrust per acceleration learnt so far (``paused``), or learn on (the
        rate ``thrust_estimate_tau`` gave).  A fit of the commanded against the produced
        acceleration needs the map between them to hold still over its window; the thrust
        learnt before it (the takeoff) is kept.  No effect on a controller that does not learn
        the thrust."""
        if self.learns_thrust:
            self._M[G.M_TPA_RATE] = 0.0 if paused else self._tpa_rate

    def raise_thrust(self, factor):
        """Multiply the thrust per acceleration by ``factor`` (> 1), within TPA_RANGE of the
        figure told.  For a takeoff waiting on the ground: a vehicle that does not rise on the
        thrust the loop expected to lift it is heavier than told, whatever the controller (PD
        too)."""
        hi = self._M[G.M_TPA0] * TPA_RANGE
        self._M[G.M_TPA] = min(self._M[G.M_TPA] * float(factor), hi)

    @property
    def thrust_at_most(self):
        """Whether the thrust per acceleration is at its bound, TPA_RANGE times the figure
        told (:meth:`raise_thrust` can raise it no further)."""
        return self._M[G.M_TPA] >= self._M[G.M_TPA0] * TPA_RANGE * (1.0 - 1e-9)

    @property
    def tilt_limit(self):
        """The tilt limit (rad) the acceleration map holds the attitude setpoint to."""
        return float(self._M[G.M_TILT])

    @tilt_limit.setter
    def tilt_limit(self, rad):
        rad = float(rad)
        if not (math.isfinite(rad) and 0.0 <= rad < 0.5 * math.pi):
            raise ValueError(f"tilt_limit must be in [0, pi/2) rad (got {rad!r})")
        self._M[G.M_TILT] = rad

    @property
    def hover_thrust_estimate(self):
        """The normalized thrust that holds a hover as the controller now takes it: the figure
        told, or what it has learnt in flight (``thrust_estimate_tau``)."""
        return float(self._M[G.M_G] * self._M[G.M_TPA])

    @property
    def feedforward_lead(self):
        """(3,) s per axis: how far ahead the reference's acceleration is fed forward, the
        observers' input model's mean delay (``input_lag``; with ``input_dead_time`` and
        ``input_lags`` the dead time plus the lags' time constants): a command acts that late,
        so the acceleration asked for now is the one the reference has then (to first order the
        inverse of the model, a + lead * da/dt).  0 without an input model, and for ADRC with its TD (which feeds
        forward its own acceleration)."""
        lead = self._IN[:, IN_LEAD].copy()
        if self.kind == "adrc" and self._P[0, K.P_TD] != 0.0:
            lead[:] = 0.0
        return lead

    @property
    def prediction(self):
        """(3,) s per axis: how far ahead of now the law carries its errors (``predict``: the
        input model's mean delay, as :attr:`feedforward_lead`), at the accelerations of now;
        0: the law acts on the errors of now."""
        return self._P[:, K.P_PRED].copy()

    @property
    def drag(self):
        """(3,) 1/s per axis: the vehicle's linear drag as the controller models it (``drag``; 0:
        none; off for ADRC with its TD): the drag along the reference velocity is fed forward
        and the observers take it as a known input, so their z3 keeps the rest (the wind, the
        drag of the tracking error).  The drag of the measured velocity is not modelled: the
        loop stays the one its gains and delay margin were designed for."""
        return self._IN[:, IN_DRAG].copy()

    def set_drag(self, drag):
        """Fly the linear drag ``drag`` ((3,) 1/s) from the next step on (learnt in flight:
        :mod:`mavadrc.control.learn`).  The observers' states are kept: their z3 gives up the part of
        the disturbance the model now carries over the next steps."""
        d = np.array(drag, dtype=np.float64).reshape(3)
        if not np.all((d >= 0.0) & (d <= DRAG_MAX)):
            raise ValueError(f"the drag must be within [0, {DRAG_MAX:g}] /s per axis (got "
                             f"{d.tolist()})")
        if not self.models_drag:
            raise ValueError("the drag is part of the ladrc and adrc observers' model (not "
                             "with the TD)")
        self._IN[:, IN_DRAG] = d

    @property
    def models_drag(self):
        """Whether the drag is in the observers' model (:attr:`drag`): LADRC and ADRC, but
        not ADRC with its TD."""
        return self.kind == "ladrc" or (self.kind == "adrc" and self._P[0, K.P_TD] == 0.0)

    @property
    def td(self):
        """(3, 2) TD outputs v1, v2 per axis (classical ADRC)."""
        return np.array([K.td_output(row) for row in self._S])

    @property
    def params(self):
        return self._P.copy(), self._M.copy()
