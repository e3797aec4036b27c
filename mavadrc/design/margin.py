"""Delay margin of a position controller: how much delay its loop tolerates before it goes unstable.

One horizontal channel, linearised where it rests (zero error, hover), closed around a plant that
produces the commanded acceleration through a first-order lag ``tau`` after ``delay`` seconds:

    p'' = a,   a' = (u(t - delay) - a) / tau      (tau = 0: a = u(t - delay))

sampled at the controller's step h with the command held between samples (exact zero-order hold).
The controller is the real one, its compiled channel kernel and input model, not a formula: the
closed loop's one-step map is differentiated numerically at rest (every nonlinearity of the
classical ADRC, fhan and fal, is linear there; no limit is active), and the loop is stable when
that Jacobian's spectral radius is below 1.  The delay margin is the largest extra delay, in whole
samples, that keeps it so; a limit cycle is what a loop past its margin does (the nonlinearities
and the tilt limit bound its amplitude).

``delay_margin(ctrl)`` judges a controller on the plant it believes in (its own input model, no
delay): the extra lag and delay a vehicle may add before the loop oscillates.
``delay_margin(ctrl, tau=0.25, delay=0.05)`` judges it on a given plant.

A controller that compensates the samples' age (``latency``) is closed with its delay line: it
knows ``age`` seconds of the plant's delay (its ``latency`` in seconds; measured, ``auto``: all
of ``delay``) and carries its estimate over them.  Its margin is then the delay it does *not*
know about: the extra delay beyond the one measured or given.  The known part costs a linear
observer nothing (its loop is the undelayed one, as a Smith predictor's), so a compensating
controller keeps the margin it has with no delay at all, at any age it is told.
"""

import math

import numpy as np

from mavadrc.control import kernels as K
from mavadrc.control.position import IN_ALPHA, IN_ND, IN_NLAG, IN_TAU

#: the longest extra delay searched (s)
MAX_EXTRA_S = 1.0
_EPS = 1e-7  # finite-difference step: far inside fal's zone and fhan's linear region


def _plant(tau, h, order=1):
    """(A, B) of the sampled plant state (p, v, a, and with ``order`` 2 the first lag's output)
    under a held command u: ``order`` equal first-order lags ``tau`` from u to a."""
    if tau <= 0.0:
        return (np.array([[1.0, h, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]),
                np.array([0.5 * h * h, h, 1.0]))
    from scipy.linalg import expm

    nx = 2 + order
    m = np.zeros((nx + 1, nx + 1))
    m[0, 1] = 1.0
    m[1, 2] = 1.0
    for i in range(2, nx):  # a <- a1 <- ... <- u
        m[i, i] = -1.0 / tau
        m[i, i + 1] = 1.0 / tau
    e = expm(m * h)
    return e[:nx, :nx], e[:nx, nx]


class _Loop:
    """The sampled closed loop of channel 0 of ``ctrl`` on the plant, ``n`` samples of delay;
    ``known``: None, or the samples of it the controller compensates (its delay line).
    :meth:`step` takes a disturbance acceleration ``d`` added to the plant's (held over the
    step); with ``feedforward`` the controller is also given -d as its reference acceleration
    (the oracle's law: the true disturbance fed forward); with ``noise`` d is instead an error
    of the position the controller reads (its estimate's noise), the plant undisturbed."""

    def __init__(self, ctrl, tau, n, known=None, feedforward=False, order=1, noise=False):
        self.p = ctrl._P[0].copy()
        self.h = float(self.p[K.P_H])
        # the observers' input model, as position_update runs it: a dead time of ``md`` steps
        # and ``ml`` lags (alpha per step)
        self.alpha = float(ctrl._IN[0, IN_ALPHA])
        self.ml = int(ctrl._IN[0, IN_NLAG])
        self.md = int(ctrl._IN[0, IN_ND])
        self.nm = self.ml + self.md  # its states: the dead time's commands, then each lag's
        self.A, self.B = _plant(tau, self.h, order)
        self.nx = self.B.size
        self.n = n
        self.known = known
        self.ns = K.NS
        # channel state, input model, plant, command buffer; with a delay line, the delayed
        # estimate and the inputs applied over the known delay too
        self.line = 0 if known is None else 3 + known + 1
        self.size = self.ns + self.nm + self.nx + n + self.line
        self.feedforward = feedforward
        self.noise = noise
        h = self.h
        self.Bd = np.zeros(self.nx)  # a held disturbance acceleration
        self.Bd[:2] = 0.5 * h * h, h

    def _channel(self, s, line, y, ydot, racc=0.0):
        """One step of the channel, through its delay line if it has one; the command."""
        if self.known is None:
            return K.channel_update_nominal(s, self.p, y, ydot, 0.0, 0.0, racc), s, line
        # the line laid out afresh each step on its own clock: the last sample at 0, the
        # inputs of the last ``known + 1`` steps begun at (-known .. 0) h + age
        m, h = self.known + 1, self.h
        age = self.known * h
        row = np.zeros(K.NSD)
        row[:self.ns] = s
        row[K.DL_ON] = 1.0
        row[K.DL_NOW] = age
        row[K.DL_Z1:K.DL_Z1 + 3] = line[:3]
        row[K.DL_N] = m
        row[K.DL_HEAD] = m - 1
        row[K.DL_TIMES:K.DL_TIMES + m] = age + h * np.arange(-self.known, 1)
        row[K.DL_INPUTS:K.DL_INPUTS + m] = line[3:]
        u = K.channel_update_aged(row, self.p, y, ydot, 0.0, 0.0, racc, h, age)
        head = int(row[K.DL_HEAD])
        inputs = row[K.DL_INPUTS + (head - np.arange(m - 1, -1, -1)) % K.HIST]
        return u, row[:self.ns].copy(), np.concatenate([row[K.DL_Z1:K.DL_Z1 + 3], inputs])

    def step(self, z, d=0.0):
        ns, n, nm = self.ns, self.n, self.nm
        s = z[:ns].copy()
        model = z[ns:ns + nm].copy()
        nx = self.nx
        x = z[ns + nm:ns + nm + nx]
        buf = z[ns + nm + nx:ns + nm + nx + n]
        line = z[ns + nm + nx + n:]
        y, ydot = x[0], x[1]
        if self.noise:
            y, d = y + d, 0.0
        u, s, line = self._channel(s, line, y, ydot, -d if self.feedforward else 0.0)
        # the observers' input model, as position_update runs it
        xin = u
        if self.md:
            xin = model[self.md - 1]
            model[1:self.md] = model[:self.md - 1].copy()
            model[0] = u
        for k in range(self.md, nm):
            model[k] = model[k] + self.alpha * (xin - model[k])
            xin = model[k]
        obs = xin
        s[K.S_U] = obs
        if self.known is not None:
            line[-1] = obs
        if n:
            applied = buf[-1]
            buf = np.concatenate([[u], buf[:-1]])
        else:
            applied = u
        x = self.A @ x + self.B * applied + self.Bd * d
        return np.concatenate([s, model, x, buf, line])

    def linearised(self):
        """(J, b, c) of the loop linearised at rest: z' = J z + b d, position = c z, over the
        states that take part in it."""
        z0 = np.zeros(self.size)
        s = np.zeros(K.NS)
        K.channel_start(s, self.p, 0.0, 0.0)  # at rest, started (not waiting for a first sample)
        z0[:self.ns] = s
        J = np.empty((self.size, self.size))
        for j in range(self.size):
            if j == K.S_TDR or j == K.S_AREF:
                # the TD's time off its grid: 0 at the nominal step, where the loop runs; a
                # difference across 0 would step the TD once or not at all.  The reference's
                # acceleration (a law that predicts reads it) is an input, 0 at rest
                J[:, j] = 0.0
                J[j, j] = 1.0
                continue
            d = np.zeros(self.size)
            d[j] = _EPS
            J[:, j] = (self.step(z0 + d) - self.step(z0 - d)) / (2.0 * _EPS)
        b = (self.step(z0, _EPS) - self.step(z0, -_EPS)) / (2.0 * _EPS)
        # entries of the channel's state vector that this kind does not use carry over
        # unchanged and touch nothing: not part of the loop
        keep = [j for j in range(self.size)
                if not (abs(J[j, j] - 1.0) < 1e-9 and np.count_nonzero(np.abs(J[j]) > 1e-9) == 1
                        and np.count_nonzero(np.abs(J[:, j]) > 1e-9) == 1)]
        c = np.zeros(self.size)
        c[self.ns + self.nm] = 1.0  # the plant's position
        return J[np.ix_(keep, keep)], b[keep], c[keep]

    def radius(self):
        J, _, _ = self.linearised()
        return float(max(abs(np.linalg.eigvals(J))))


def _known(ctrl, delay, h, known_s=None):
    """The samples of the plant's delay the controller compensates (None: it does not):
    ``known_s`` of it if given, else its latency (``auto``: all of ``delay``)."""
    latency = getattr(ctrl, "latency", None)
    if latency is None:
        return None
    if known_s is not None:
        return min(int(round(known_s / h)), int(round(delay / h)))
    return int(round((delay if latency == "auto" else latency) / h))


def _delay(ctrl, delay):
    """The plant's delay: as given, or the one the controller assumes (its latency, if a
    number; else none)."""
    if delay is not None:
        return float(delay)
    latency = getattr(ctrl, "latency", None)
    return latency if isinstance(latency, float) else 0.0


def _own(ctrl, tau, delay, order):
    """The plant (tau, delay, order): as given, or where ``tau`` is None the controller's own
    input model (its lags, and its dead time added to the delay)."""
    delay = _delay(ctrl, delay)
    if tau is not None:
        return float(tau), delay, order
    h = float(ctrl._P[0, K.P_H])
    return (float(ctrl._IN[0, IN_TAU]), delay + h * int(ctrl._IN[0, IN_ND]),
            int(ctrl._IN[0, IN_NLAG]))


def spectral_radius(ctrl, tau=None, delay=None, order=1):
    """The linearised closed loop's spectral radius (< 1: stable) on the plant (``order`` equal
    lags ``tau`` s, default: the controller's own input model, its dead time included;
    ``delay`` s, rounded to samples, default the one the controller assumes: its ``latency`` if
    a number, else none)."""
    tau, delay, order = _own(ctrl, tau, delay, order)
    h = float(ctrl._P[0, K.P_H])
    return _Loop(ctrl, tau, int(round(delay / h)), _known(ctrl, delay, h),
                 order=order).radius()


def delay_margin(ctrl, tau=None, delay=None, max_extra_s=MAX_EXTRA_S, order=1, known_s=None):
    """The extra delay (s, in whole control periods) the loop tolerates on the plant (lag ``tau``,
    default the controller's input model; ``delay`` s already there, default the one the
    controller assumes) before its linearisation is unstable: 0.0 if it is unstable with no
    extra delay (``math.inf`` past ``max_extra_s``).  A controller that compensates the samples'
    age knows ``delay`` (measured, or its latency in seconds) and not the extra; ``known_s``:
    the seconds of it it knows instead (a dead time identified is not all sample age).
    ``order``: the plant's lag is that many equal lags ``tau`` (2: the identified response,
    :mod:`mavadrc.design.identify`).
    ``ctrl``: a :class:`mavadrc.control.position.PositionController`, at rest or not (its state
    is not touched); None for ``native`` (the autopilot's own loop: not the companion's to
    know)."""
    if ctrl.kind == "native":
        return None
    tau, delay, order = _own(ctrl, tau, delay, order)
    h = float(ctrl._P[0, K.P_H])
    n0 = int(round(delay / h))
    known = _known(ctrl, delay, h, known_s)
    if _Loop(ctrl, tau, n0, known, order=order).radius() >= 1.0:
        return 0.0
    stable = 0
    for extra in range(1, int(math.ceil(max_extra_s / h)) + 1):
        if _Loop(ctrl, tau, n0 + extra, known, order=order).radius() >= 1.0:
            return stable * h
        stable = extra
    return math.inf


def _response(ctrl, omegas, tau, delay, order, offset=0.0, **loop):
    """|c (z I - J)^-1 b + offset| at z = exp(j w h) for each of ``omegas``: the frequency
    response of the loop linearised at rest on the plant (:func:`_own`), ``loop``: the
    :class:`_Loop`'s input (``feedforward``, ``noise``).  NaN where the loop is unstable (it
    has no steady response)."""
    tau, delay, order = _own(ctrl, tau, delay, order)
    lp = _Loop(ctrl, tau, int(round(delay / float(ctrl._P[0, K.P_H]))), order=order, **loop)
    J, b, c = lp.linearised()
    omegas = np.atleast_1d(np.asarray(omegas, dtype=float))
    if max(abs(np.linalg.eigvals(J))) >= 1.0:
        return np.full(omegas.shape, math.nan)
    eye = np.eye(J.shape[0])
    return np.array([abs(c @ np.linalg.solve(np.exp(1j * w * lp.h) * eye - J, b) + offset)
                     for w in omegas])


def noise_response(ctrl, omegas, tau=None, delay=0.0, order=1):
    """|S(j w)|: the position error the controller sees (the reference less the position it
    reads) per m of sinusoidal noise in that position at each angular frequency of ``omegas``
    (rad/s); the true position moves by |S - 1| of it.  The loop as :func:`disturbance_response`
    has it.  Above 1 the loop amplifies its estimate's noise at that frequency: a position
    estimate's wander there (a GNSS fix's noise through the autopilot's filter) becomes a
    larger error, and a swing of the vehicle.  NaN where the loop is unstable."""
    # the position read is the plant's plus the noise: the error seen is -(that)
    return _response(ctrl, omegas, tau, delay, order, offset=1.0, noise=True)


def disturbance_response(ctrl, omegas, tau=None, delay=0.0, feedforward=False, order=1):
    """|G_d(j w)|: the position error (m) per m/s^2 of a sinusoidal disturbance acceleration at
    each angular frequency of ``omegas`` (rad/s), the loop linearised at rest on the plant (lag
    ``tau``, ``order`` of them, default the controller's input model; ``delay`` s) and sampled
    at its step;
    ``feedforward``: the disturbance also fed forward (the oracle).  NaN where the loop is
    unstable (it has no steady response)."""
    return _response(ctrl, omegas, tau, delay, order, feedforward=feedforward)


def margin_record(margin):
    """The margin as summary.json and the records carry it: seconds, or None past the search."""
    return None if margin is None or math.isinf(margin) else float(margin)


def margin_text(margin):
    """The delay margin for a console line."""
    if margin is None or math.isinf(margin):
        return f"delay margin over {MAX_EXTRA_S:g} s"
    if margin == 0.0:
        return ("no delay margin: unstable on the plant it assumes, expect a limit cycle")
    return (f"delay margin {1e3 * margin:.0f} ms (a vehicle slower than its input model by more "
            f"will make it oscillate)")


def identified_margin_text(margin, gains, share=0.75):
    """The one delay-margin figure of a flight that identified its vehicle: on the response
    identified, with how it stands against the lag (``gains``' ``input_lag``): "delay margin
    20 ms on the response identified (little: under 75 % of its 122 ms lag; a vehicle slower
    than identified by more will oscillate)"."""
    if margin is None or math.isinf(margin) or margin <= 0.0:
        return margin_text(margin)
    slow = max(float(gains["input_lag"][0]), float(gains["input_lag"][1]))
    little = (f"little: under {share:.0%} of its {1e3 * slow:.0f} ms lag; "
              if margin < share * slow else "")
    return (f"delay margin {1e3 * margin:.0f} ms on the response identified ({little}a vehicle "
            f"slower than identified by more will oscillate)")


def prediction_text(ctrl):
    """", the law predicting L s ahead" for a console line ("" for a law that does not)."""
    horizon = ctrl.prediction
    if not horizon.any():
        return ""
    return f", the law predicting {horizon[0]:.3f} s ahead"



