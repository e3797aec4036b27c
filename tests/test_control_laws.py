"""The closed-loop facts of the ADRC notes (section 6), with the thesis's errata shown to fail.

Plant unless stated: exact-ZOH double integrator y'' = b*u + d with h = 1 ms, a unit step at
t = 0 and d = -3 switched on at t = 1 s, b = 2 and b0 = 1 (the observer's model is off by 2x).
"""

import math

import numpy as np
import pytest

from mavadrc.control import (PD, HanADRC, HanESO, LinearADRC, LinearESO, TrackingDifferentiator,
                             fal, fhan)
from mavadrc.control import kernels as K

H = 1e-3


def plant_step(y, yd, a, h=H):
    """Exact zero-order-hold step of y'' = a."""
    return y + h * yd + 0.5 * h * h * a, yd + h * a


def closed_loop(control, b=2.0, d=-3.0, t_d=1.0, T=3.0, h=H, limit=None):
    """Run ``control(k, y, yd) -> u`` on the double integrator; returns (y, u) series."""
    n = int(round(T / h))
    y = yd = 0.0
    ys, us = np.empty(n), np.empty(n)
    for k in range(n):
        u = control(k, y, yd)
        if limit is not None:
            u = min(max(u, -limit), limit)
        y, yd = plant_step(y, yd, b * u + (d if k * h >= t_d else 0.0), h)
        ys[k], us[k] = y, u
    return ys, us


def step_metrics(ys, h=H, t_d=1.0, band=0.02):
    """Overshoot (%), 2% settling time before the disturbance, final error."""
    pre = ys[: int(round(t_d / h))]
    outside = np.nonzero(np.abs(pre - 1.0) > band)[0]
    settle = (outside[-1] + 1) * h if outside.size else 0.0
    return (pre.max() - 1.0) * 100.0, settle, ys[-1] - 1.0


def channel(ctrl):
    return lambda k, y, yd: ctrl.update(y, 1.0)


# --- section 1: fhan and fal ---------------------------------------------------------------------


def fhan_if_else(x1, x2, r, h):
    """Han's older if/else form of fhan (as in the thesis appendix), for cross-checking."""
    d = r * h
    d0 = h * d
    y = x1 + h * x2
    a0 = math.sqrt(d * d + 8.0 * r * abs(y))
    if abs(y) > d0:
        a = x2 + (a0 - d) / 2.0 * math.copysign(1.0, y)
    else:
        a = x2 + y / h
    if abs(a) > d:
        return -r * math.copysign(1.0, a)
    return -r * a / d


def test_fhan_unit_facts():
    assert fhan(0.0, 0.0, 10.0, 0.01) == 0.0
    assert fhan(-1.0, 0.0, 10.0, 0.01) == pytest.approx(10.0, abs=1e-12)
    rng = np.random.default_rng(0)
    for x1, x2 in rng.normal(0.0, 1.0, (200, 2)):
        assert fhan(-x1, -x2, 10.0, 0.01) == pytest.approx(-fhan(x1, x2, 10.0, 0.01), abs=1e-12)


def test_fhan_compact_and_if_else_forms_agree():
    rng = np.random.default_rng(1)
    for x1, x2, r, h in zip(rng.normal(0, 2, 2000), rng.normal(0, 2, 2000),
                            rng.uniform(0.5, 200, 2000), rng.uniform(1e-3, 5e-2, 2000)):
        a, b = fhan(x1, x2, r, h), fhan_if_else(x1, x2, r, h)
        assert abs(a - b) <= 1e-12 * max(1.0, abs(b)) * 10


def test_fal_is_odd_continuous_and_linear_inside():
    delta = 0.01
    for alpha in (0.25, 0.5, 0.75, 1.25):
        inside = fal(delta * (1 - 1e-12), alpha, delta)
        outside = fal(delta * (1 + 1e-12), alpha, delta)
        assert inside == pytest.approx(outside, rel=1e-9)
        assert fal(-0.3, alpha, delta) == -fal(0.3, alpha, delta)
        assert fal(0.004, alpha, delta) == pytest.approx(0.004 * delta ** (alpha - 1.0))
    assert fal(4.0, 0.5, delta) == pytest.approx(2.0)


# --- section 2: the tracking differentiator ------------------------------------------------------


def fhan_erratum(x1, x2, r, h):
    """fhan with the thesis's printed eq. 20: d = h*r^2 instead of r*h^2."""
    d = h * r * r
    a0 = h * x2
    y = x1 + a0
    a1 = math.sqrt(d * (d + 8.0 * abs(y)))
    sgn = lambda v: math.copysign(1.0, v) if v != 0 else 0.0  # noqa: E731
    a2 = a0 + sgn(y) * (a1 - d) / 2.0
    sy = (sgn(y + d) - sgn(y - d)) / 2.0
    a = (a0 + y - a2) * sy + a2
    sa = (sgn(a + d) - sgn(a - d)) / 2.0
    return -r * (a / d - sgn(a)) * sa - r * sgn(a)


def td_series(update, n):
    v1, v2 = np.empty(n), np.empty(n)
    for k in range(n):
        v1[k], v2[k] = update(1.0)
    return v1, v2


def td_step_ok(v1, v2, r0, h, A=1.0):
    """ADRC notes 6.2: time-optimal settling, overshoot <= r0 h^2, |dv2/dt| <= r0, v2 -> 0."""
    outside = np.nonzero(np.abs(v1 - A) > 1e-3 * A)[0]
    settle = (outside[-1] + 1) * h if outside.size else 0.0
    return (settle <= 2.0 * math.sqrt(A / r0) + 3 * h
            and v1.max() - A <= r0 * h * h
            and np.abs(np.diff(v2) / h).max() <= r0 * (1 + 1e-9)
            and abs(v2[-1]) < 1e-6)


def test_td_step_is_time_optimal_without_overshoot():
    td = TrackingDifferentiator(h=0.01, r0=10.0)
    v1, v2 = td_series(td.update, 300)
    assert td_step_ok(v1, v2, 10.0, 0.01)
    outside = np.nonzero(np.abs(v1 - 1.0) > 1e-3)[0]
    assert (outside[-1] + 1) * 0.01 == pytest.approx(2.0 * math.sqrt(0.1), abs=0.02)


def test_td_with_the_printed_d_fails_the_step_test():
    s = {"v1": 0.0, "v2": 0.0}

    def update(v, h=0.01, r0=10.0):
        fh = fhan_erratum(s["v1"] - v, s["v2"], r0, h)
        s["v1"], s["v2"] = s["v1"] + h * s["v2"], s["v2"] + h * fh
        return s["v1"], s["v2"]

    v1, v2 = td_series(update, 300)
    assert not td_step_ok(v1, v2, 10.0, 0.01)


def test_td_differentiates_a_sine():
    n = 4000
    t = np.arange(n) * H
    td = TrackingDifferentiator(h=H, r0=1000.0)
    v2 = np.array([td.update(math.sin(math.pi * tk))[1] for tk in t])
    late = t >= 2.0
    assert np.abs(v2[late] - math.pi * np.cos(math.pi * t[late])).max() <= 0.02


def test_td_filters_noise_far_better_than_finite_differences():
    n = 4000
    t = np.arange(n) * H
    s = np.sin(math.pi * t) + 0.01 * np.random.default_rng(1).standard_normal(n)
    td = TrackingDifferentiator(h=H, r0=1000.0, h0=10 * H)
    v2 = np.array([td.update(sk)[1] for sk in s])
    late = t >= 2.0
    truth = math.pi * np.cos(math.pi * t)
    rms_td = np.sqrt(np.mean((v2[late] - truth[late]) ** 2))
    rms_fd = np.sqrt(np.mean(((np.diff(s) / H)[late[1:]] - truth[1:][late[1:]]) ** 2))
    assert rms_td < 0.3
    assert rms_fd > 10.0


# --- section 4 and 6.4: the observers ------------------------------------------------------------


def eso_disturbance_series(obs, T=3.0):
    """b = 2, b0 = 1, u = 1, d = -3: the total disturbance seen with b0 = 1 is f = -3 + 1 = -2."""
    n = int(round(T / H))
    y = yd = 0.0
    z3 = np.empty(n)
    for k in range(n):
        obs.update(y, 1.0 if k > 0 else 0.0)
        z3[k] = obs.z[2]
        y, yd = plant_step(y, yd, 2.0 * 1.0 - 3.0)
    return z3


def settle_time(err, tol, h=H):
    outside = np.nonzero(np.abs(err) > tol)[0]
    return (outside[-1] + 1) * h if outside.size else 0.0


@pytest.mark.parametrize("obs, t2", [
    (HanESO(h=H, b0=1.0), 0.025),
    (LinearESO(h=H, b0=1.0, wo=100.0), 7.52 / 100.0 + 2 * H),
    (LinearESO(h=H, b0=1.0, wo=50.0), 7.52 / 50.0 + 2 * H),
])
def test_eso_estimates_the_total_disturbance_with_a_wrong_b0(obs, t2):
    z3 = eso_disturbance_series(obs)
    assert abs(z3[-1] + 2.0) < 1e-6
    assert settle_time(z3 + 2.0, 0.04) <= t2


def identify_linear_map(state, step, n):
    """Columns of the linear map x -> step(x) found by stepping unit states (y = u = r = d = 0)."""
    A = np.empty((n, n))
    for j in range(n):
        state[:] = 0.0
        state[j] = 1.0
        A[:, j] = step()
    return A


@pytest.mark.parametrize("wo, h", [(50, 1e-3), (50, 1e-2), (150, 1e-2), (250, 1e-2)])
def test_discrete_leso_poles_sit_at_exp_minus_wo_h(wo, h):
    obs = LinearESO(h=h, b0=1.0, wo=wo)
    s = obs._s  # the observer's own state vector: identify the recursion the code runs

    def step():
        z = s[:3].copy()
        s[:] = 0.0
        s[K.S_Z1:K.S_Z3 + 1] = z
        s[K.S_INIT] = 1.0
        obs.update(0.0, 0.0)
        return s[:3].copy()

    A = np.empty((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        s[:3] = e
        A[:, j] = step()
    beta = math.exp(-wo * h)
    assert np.allclose(np.poly(A), np.poly([beta] * 3), atol=1e-6)


def test_euler_leso_is_refused_beyond_wo_h_0_2():
    LinearESO(h=1e-3, b0=1.0, wo=150.0, discretization="euler")
    with pytest.raises(ValueError, match="wo\\*h"):
        LinearESO(h=1e-2, b0=1.0, wo=50.0, discretization="euler")


# --- section 6.6: closed-loop step with disturbance ----------------------------------------------


def test_linear_adrc_step_and_disturbance_rejection():
    ys, _ = closed_loop(channel(LinearADRC(h=H, b0=1.0, wc=20.0, wo=100.0)))
    overshoot, settle, final = step_metrics(ys)
    assert overshoot < 0.5
    assert settle < 0.36
    assert abs(final) < 1e-6


def test_classical_adrc_step_and_disturbance_rejection():
    ys, _ = closed_loop(channel(HanADRC(h=H, b0=1.0, r0=20.0, r=100.0, c=0.5, h1=10 * H)))
    overshoot, settle, final = step_metrics(ys)
    assert overshoot < 0.5
    assert 0.3 < settle <= 0.45
    assert abs(final) < 1e-6


def test_classical_adrc_fal_law_rejects_the_disturbance():
    ctrl = HanADRC(h=H, b0=1.0, r0=20.0, law="fal", k1=100.0, k2=20.0)
    ys, _ = closed_loop(channel(ctrl), T=4.0)
    assert abs(ys[-1] - 1.0) < 1e-4


def test_pd_keeps_the_steady_error_of_a_constant_disturbance():
    pd = PD(h=H, kp=400.0, kd=40.0)
    ys, _ = closed_loop(lambda k, y, yd: pd.update(y, 1.0, ydot=yd))
    assert 1.0 - ys[-1] == pytest.approx(-(-3.0) / (2.0 * 400.0), abs=1e-6)  # r - y = -d/(b kp)


def test_pd_without_a_measured_rate_differentiates_the_output():
    pd = PD(h=H, kp=400.0, kd=40.0)
    ys, _ = closed_loop(lambda k, y, yd: pd.update(y, 1.0))
    assert ys[-1] - 1.0 == pytest.approx(-3.0 / (2.0 * 400.0), abs=1e-5)


# --- section 6.7: saturation and the observer's input feed ---------------------------------------


def test_observer_fed_the_applied_input_settles_under_saturation():
    ctrl = LinearADRC(h=H, b0=1.0, wc=20.0, wo=100.0, u_min=-2.0, u_max=2.0)
    ys, us = closed_loop(channel(ctrl), T=10.0)
    assert np.abs(us).max() <= 2.0
    assert np.abs(ys[-500:] - 1.0).max() < 1e-6


def test_observer_fed_the_unlimited_input_does_not_settle():
    ctrl = LinearADRC(h=H, b0=1.0, wc=20.0, wo=100.0)  # knows nothing of the limit below
    ys, _ = closed_loop(channel(ctrl), T=10.0, limit=2.0)
    assert np.abs(ys[-500:] - 1.0).max() > 1.0


def test_set_applied_input_lets_a_downstream_limit_feed_the_observer():
    ctrl = LinearADRC(h=H, b0=1.0, wc=20.0, wo=100.0)

    def control(k, y, yd):
        u = min(max(ctrl.update(y, 1.0), -2.0), 2.0)
        ctrl.set_applied_input(u)
        return u

    ys, _ = closed_loop(control, T=10.0)
    assert np.abs(ys[-500:] - 1.0).max() < 1e-6


# --- section 6.8: b0 robustness ------------------------------------------------------------------


def continuous_closed_loop(ratio, wc=10.0, wo=50.0):
    """Plant (y, y') + continuous LESO (z1, z2, z3) + LADRC law with b0 = 1, b = ratio."""
    l1, l2, l3 = 3 * wo, 3 * wo**2, wo**3
    kp, kd = wc * wc, 2 * wc
    u = np.array([0.0, 0.0, -kp, -kd, -1.0])  # u = -kp z1 - kd z2 - z3 (r = 0)
    A = np.zeros((5, 5))
    A[0, 1] = 1.0
    A[1] = ratio * u
    A[2] = [l1, 0, -l1, 1, 0]
    A[3] = np.array([l2, 0, -l2, 0, 1]) + u
    A[4] = [l3, 0, -l3, 0, 0]
    return A


@pytest.mark.parametrize("ratio", [0.25, 0.5, 1.0, 2.0, 4.0])
def test_continuous_ladrc_is_stable_inside_the_b0_range(ratio):
    assert np.linalg.eigvals(continuous_closed_loop(ratio)).real.max() < 0.0


@pytest.mark.parametrize("ratio", [0.1, 8.0])
def test_continuous_ladrc_is_unstable_outside_the_b0_range(ratio):
    assert np.linalg.eigvals(continuous_closed_loop(ratio)).real.max() > 0.0


def discrete_spectral_radius(ratio, h=1e-2, wc=10.0, wo=50.0):
    """Closed loop of the real LinearADRC kernel with the ZOH plant, identified column by column.

    State: plant (y, y') and the controller's (z1, z2, z3, u_prev); r = d = 0, so the map is
    linear and unit states give its columns.
    """
    ctrl = LinearADRC(h=h, b0=1.0, wc=wc, wo=wo)
    s = ctrl._s
    A = np.empty((6, 6))
    for j in range(6):
        x = np.zeros(6)
        x[j] = 1.0
        s[:] = 0.0
        s[K.S_INIT] = 1.0
        s[K.S_Z1], s[K.S_Z2], s[K.S_Z3], s[K.S_U] = x[2], x[3], x[4], x[5]
        y, yd = plant_step(x[0], x[1], ratio * x[5], h)  # the plant moves under u_prev
        u = ctrl.update(y, 0.0)
        A[:, j] = [y, yd, s[K.S_Z1], s[K.S_Z2], s[K.S_Z3], u]
    return np.abs(np.linalg.eigvals(A)).max()


@pytest.mark.parametrize("ratio", [0.2, 0.5, 1.0, 2.0, 4.0])
def test_discrete_ladrc_is_stable_inside_its_b0_range(ratio):
    assert discrete_spectral_radius(ratio) < 1.0


@pytest.mark.parametrize("ratio", [0.16, 4.5])
def test_discrete_ladrc_is_unstable_outside_its_b0_range(ratio):
    assert discrete_spectral_radius(ratio) > 1.0


# --- section 6.9: each erratum, reinserted, fails ------------------------------------------------


def ladrc_with_law(law, wo=100.0, wc=20.0):
    """The project's LinearESO with a law written here: a harness to reinsert printed errors."""
    obs = LinearESO(h=H, b0=1.0, wo=wo)
    kp, kd = wc * wc, 2 * wc
    state = {"u": 0.0}

    def control(k, y, yd):
        z1, z2, z3 = obs.update(y, state["u"])
        state["u"] = law(z1, z2, z3, kp, kd)
        return state["u"]

    return control


def correct_law(z1, z2, z3, kp, kd):
    return kp * (1.0 - z1) + kd * (0.0 - z2) - z3


def test_harness_with_the_correct_law_reproduces_linear_adrc_exactly():
    ys_h, _ = closed_loop(ladrc_with_law(correct_law))
    ys_c, _ = closed_loop(channel(LinearADRC(h=H, b0=1.0, wc=20.0, wo=100.0)))
    assert np.abs(ys_h - ys_c).max() < 1e-12


def test_erratum_plus_z3_fails():
    ys, _ = closed_loop(ladrc_with_law(lambda z1, z2, z3, kp, kd: kp * (1 - z1) - kd * z2 + z3))
    assert abs(step_metrics(ys)[2]) > 1e-3  # +z3 doubles the disturbance instead of cancelling it


def test_erratum_z1_minus_rdot_fails():
    ys, _ = closed_loop(ladrc_with_law(lambda z1, z2, z3, kp, kd: kp * (1 - z1) - kd * z1 - z3))
    overshoot, settle, final = step_metrics(ys)
    assert overshoot > 5.0 or abs(final) > 1e-3


def test_erratum_leso_z2_integrating_itself_fails():
    """Eq. 55 prints zhat2' = zhat2 - L2(zhat1 - y) + b*u (zhat2 where zhat3 belongs)."""
    wo, wc = 100.0, 20.0
    l1, l2, l3 = 3 * wo, 3 * wo**2, wo**3
    z = np.zeros(3)
    st = {"u": 0.0, "init": False}

    def control(k, y, yd):
        if not st["init"]:
            z[0], st["init"] = y, True
        e = z[0] - y
        z[:] = z + H * np.array([z[1] - l1 * e, z[1] - l2 * e + st["u"], -l3 * e])
        st["u"] = wc * wc * (1 - z[0]) - 2 * wc * z[1] - z[2]
        return st["u"]

    ys, _ = closed_loop(control)
    assert not (np.all(np.isfinite(ys)) and abs(ys[-1] - 1.0) < 1e-3)


def han_with_law(law):
    """TD + NLESO of the project with an NLSEF written here (the TD's acceleration fed forward,
    as the project's NLSEF does; the NLESO's estimate is one step ahead of the sample, so the
    TD's profile is taken one step ahead too)."""
    td = TrackingDifferentiator(h=H, r0=20.0)
    obs = HanESO(h=H, b0=1.0)
    st = {"u": 0.0, "init": False}

    def control(k, y, yd):
        if not st["init"]:
            td.reset(y)
            st["init"] = True
        z1, z2, z3 = obs.update(y, st["u"])
        v1, v2 = td.update(1.0)
        a = td.acceleration
        st["u"] = law(v1 + H * v2 + 0.5 * H * H * a - z1, v2 + H * a - z2, z3) + a
        return st["u"]

    return control


def test_han_harness_with_the_correct_law_reproduces_han_adrc():
    ys_h, _ = closed_loop(han_with_law(lambda e1, e2, z3: -fhan(e1, 0.5 * e2, 100.0, 10 * H) - z3))
    ys_c, _ = closed_loop(channel(HanADRC(h=H, b0=1.0, r0=20.0, r=100.0, c=0.5, h1=10 * H)))
    assert np.abs(ys_h - ys_c).max() < 1e-9


def test_erratum_printed_nlsef_fails():
    """Eqs. 42-47: u = (-fhan(e1, c*e1, r, h1) + z3)/b0 goes unstable at b/b0 = 2."""
    ys, _ = closed_loop(han_with_law(lambda e1, e2, z3: -fhan(e1, 0.5 * e1, 100.0, 10 * H) + z3))
    assert not (np.all(np.isfinite(ys)) and abs(ys[-1] - 1.0) < 1e-3)


def test_erratum_han_plus_z3_alone_fails():
    """With the sign of z3 flipped the disturbance is doubled, not cancelled: a steady error stays
    (the correct law ends within 1e-6, see test_classical_adrc_step_and_disturbance_rejection)."""
    ys, _ = closed_loop(han_with_law(lambda e1, e2, z3: -fhan(e1, 0.5 * e2, 100.0, 10 * H) + z3))
    assert abs(ys[-1] - 1.0) > 1e-4


# --- section 6.10: NLSEF chatter -----------------------------------------------------------------


def test_nlsef_with_c_half_and_h1_10h_does_not_chatter():
    _, us = closed_loop(channel(HanADRC(h=H, b0=1.0, r0=20.0, r=100.0, c=0.5, h1=10 * H)))
    assert np.ptp(us[-1000:]) < 1e-4 * np.abs(us).max()


def test_nlsef_with_c_1_and_h1_5h_limit_cycles():
    _, us = closed_loop(channel(HanADRC(h=H, b0=1.0, r0=20.0, r=100.0, c=1.0, h1=5 * H)))
    assert np.ptp(us[-1000:]) > 0.5 * np.abs(us).max()


# --- the classical ADRC's bandwidth shorthand -----------------------------------------------------

@pytest.mark.parametrize("rate_hz", [100.0, 250.0])
@pytest.mark.parametrize("wo, delta", [(23.0, 0.0301), (12.0, 0.05)])
def test_the_adrc_wo_shorthand_puts_the_nlesos_linearised_poles_at_minus_wo(rate_hz, wo, delta):
    """``wo`` in a mission's ADRC gains: the NLESO recursion, linearised inside fal's zone
    (|e| < delta, where fal(e, a, delta) = e delta^(a-1)), has its three poles at -wo (the
    forward-Euler image 1 - wo h, identified from the recursion itself by finite differences).
    Without fal's scaling the same wo put them at |z| = 1.154 at 100 Hz (the thesis gains:
    unstable)."""
    from mavadrc.design.gains import make_controller
    from mavadrc.mission.config import ControllerSpec

    spec = ControllerSpec(kind="adrc", rate_hz=rate_hz,
                          gains={"wc": (4.0,) * 3, "wo": (wo,) * 3, "delta": (delta,) * 3})
    ctrl = make_controller(spec, hover_thrust=0.5)
    P, _ = ctrl.params
    h = 1.0 / rate_hz
    J = np.empty((3, 3))
    eps = 1e-4 * delta  # well inside the linear zone
    for j in range(3):
        cols = []
        for sgn in (1.0, -1.0):
            s = np.zeros(K.NS)
            s[K.S_Z1 + j] = sgn * eps
            K.nleso_step(s, P[0], 0.0, h)
            cols.append(s[[K.S_Z1, K.S_Z2, K.S_Z3]].copy())
        J[:, j] = (cols[0] - cols[1]) / (2.0 * eps)
    # characteristic polynomial of J against (z - (1 - wo h))^3: a triple root is ill-conditioned
    # as eigenvalues, well-conditioned as coefficients
    want = np.poly(np.full(3, 1.0 - wo * h))
    assert np.allclose(np.poly(J), want, rtol=0, atol=1e-9)
    assert max(abs(np.linalg.eigvals(J))) < 1.0


# --- the NLESO's one step ahead --------------------------------------------------------------------

def ramp_tail(c, h, v=5.0, seconds=8.0, tail_s=1.0):
    """Controller ``c`` (reset at 0) on y'' = u tracking y = v t with exact derivatives fed,
    at step ``h``: the errors (reference at the next step minus the output) of the last
    ``tail_s``."""
    y, yd = 0.0, v
    c.reset(y)
    errs = []
    for k in range(int(round(seconds / h))):
        t = k * h
        u = c.update(y, v * t, v, 0.0)
        y, yd = y + h * yd + 0.5 * h * h * u, yd + h * u
        errs.append(v * (t + h) - y)
    return np.array(errs[-int(round(tail_s / h)):])

@pytest.mark.parametrize("h", [0.004, 0.01, 0.02])
def test_classical_adrc_tracks_a_ramp_without_a_one_step_lag(h):
    """Han's forward-Euler NLESO leaves its estimate one nominal step ahead of the sample; the
    law compares it with the reference one step ahead too.  On a 5 m/s ramp (y'' = u, exact
    derivatives fed) the error settles under 1 % of speed x step; compared with the sample's
    reference it settled at speed x step (0.1 m at 50 Hz: the robustness study's ADRC at 50 Hz
    read 0.128 m on the spiral, 0.061 m now)."""
    c = HanADRC(h=h, b0=1.0, r=100.0, c=1.0, h1=0.5, td=False, beta=(12.0, 48.0, 64.0))
    assert np.abs(ramp_tail(c, h)).max() < 0.01 * 5.0 * h


@pytest.mark.parametrize("disc", ["euler", "zoh"])
def test_linear_adrc_tracks_a_ramp_without_a_one_step_lag(disc):
    """The Euler LESO is one step ahead as Han's NLESO is, and compared with the reference one
    step ahead; the ZOH current observer is at the sample's time.  Both settle under 1 % of
    speed x step on a 5 m/s ramp at 100 Hz."""
    h = 0.01
    c = LinearADRC(h=h, b0=1.0, wc=3.0, wo=12.0, discretization=disc)
    assert np.abs(ramp_tail(c, h)).max() < 0.01 * 5.0 * h


def test_erratum_printed_timing_trails_a_ramp():
    """The printed law's timing, the NLESO's estimate compared with the sample's reference
    (written here around the project's HanESO): on the same 5 m/s ramp at 50 Hz it settles a
    whole speed x step (0.1 m) behind."""
    h, v = 0.02, 5.0
    obs = HanESO(h=h, b0=1.0, beta=(12.0, 48.0, 64.0))
    y, yd, u = 0.0, v, 0.0
    obs.reset(y)
    errs = []
    for k in range(int(round(8.0 / h))):
        t = k * h
        z1, z2, z3 = obs.update(y, u)
        u = -fhan(v * t - z1, 1.0 * (v - z2), 100.0, 0.5) - z3
        y, yd = y + h * yd + 0.5 * h * h * u, yd + h * u
        errs.append(v * (t + h) - y)
    tail = np.array(errs[-50:])
    assert np.all(np.abs(tail - v * h) < 0.05 * v * h)
