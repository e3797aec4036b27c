"""The delay margin: the linearised loop of the real controller kernels against an independent
derivation, and its predictions against the flights it is meant to predict."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from mavadrc.design.gains import make_controller
from mavadrc.design.margin import delay_margin, disturbance_response, spectral_radius
from mavadrc.design.gains import spec_margin
from mavadrc.mission.config import ControllerSpec


def _ladrc_radius(wc, wo, tau, delay, h, order=1):
    """LADRC (b0 = 1, ZOH current observer, kp = wc^2, kd = 2 wc, no input model) on
    p'' = a, a reached from u(t - delay) through ``order`` equal lags tau, written out by hand
    as one matrix."""
    nx = 2 + order  # p, v, a and the lags' inner outputs
    m = np.zeros((nx + 1, nx + 1))
    m[0, 1] = m[1, 2] = 1.0
    for i in range(2, nx):
        m[i, i] = -1.0 / tau
        m[i, i + 1] = 1.0 / tau
    e = expm(m * h)
    ap, bp = e[:nx, :nx], e[:nx, nx]
    n = int(round(delay / h))
    b = math.exp(-wo * h)
    phi = np.array([[1, h, h * h / 2], [0, 1, h], [0, 0, 1]])
    gam = np.array([h * h / 2, h, 0])
    lc = np.array([1 - b ** 3, 1.5 * (1 - b) ** 2 * (1 + b) / h, (1 - b) ** 3 / h ** 2])
    o, c = nx, nx + 3  # the observer's columns, the commands in flight (u_{k-1} .. u_{k-1-n})
    size = nx + 3 + n + 1
    f = np.zeros((size, size))
    f[0:nx, 0:nx] = ap
    f[0:nx, c + n] = bp
    pred = np.zeros((3, size))
    pred[:, o:o + 3] = phi
    pred[:, c] = gam  # the observer predicts with the last command
    y = np.zeros(size)
    y[0:nx] = ap[0]
    y[c + n] += bp[0]
    f[o:o + 3] = pred + np.outer(lc, y - pred[0])
    u = -wc * wc * f[o] - 2 * wc * f[o + 1] - f[o + 2]
    f[c] = u
    for j in range(1, n + 1):
        f[c + j, c + j - 1] = 1.0
    return max(abs(np.linalg.eigvals(f)))


@pytest.mark.parametrize("rate_hz", [50.0, 100.0, 250.0])
@pytest.mark.parametrize("tau, delay", [(0.03, 0.0), (0.13, 0.02), (0.25, 0.05)])
@pytest.mark.parametrize("order", [1, 2])
def test_the_linearised_kernels_match_the_loop_written_out_by_hand(rate_hz, tau, delay, order):
    ctrl = make_controller(ControllerSpec(kind="ladrc", rate_hz=rate_hz,
                                          gains={"wc": (2.0,) * 3, "wo": (8.0,) * 3}),
                           hover_thrust=0.5)
    got = spectral_radius(ctrl, tau, delay, order=order)
    want = _ladrc_radius(2.0, 8.0, tau, delay, 1.0 / rate_hz, order)
    assert got == pytest.approx(want, abs=1e-6)
    if order == 2:  # a second lag is not the first over again
        assert abs(want - _ladrc_radius(2.0, 8.0, tau, delay, 1.0 / rate_hz)) > 1e-4


def test_the_response_identified_leaves_less_margin_than_the_lag_the_observers_model():
    """PX4 SIH identified as two lags of 99 ms after 54 ms (63 % at 0.266 s): x500_gusts'
    gains (wc 2, wo 10), modelling one lag of 0.266 s, keep 90 ms on that lag but 20-30 ms on
    the response as fitted, which has more phase lag at the loop's crossover (flown there, the
    roll and pitch swung 3-8 deg at 1 Hz).  Slower gains keep more of both."""
    def ladrc(wc, wo):
        return make_controller(ControllerSpec(kind="ladrc", gains={
            "wc": (wc, wc, 2.5), "wo": (wo, wo, 12.5), "input_lag": (0.266, 0.266, 0.05)}),
            hover_thrust=0.5)
    own = delay_margin(ladrc(2.0, 10.0))
    fitted = delay_margin(ladrc(2.0, 10.0), tau=0.099, delay=0.054, order=2)
    assert 0.08 <= own <= 0.1 and 0.01 <= fitted <= 0.03
    assert delay_margin(ladrc(1.6, 16.0), tau=0.099, delay=0.054, order=2) >= fitted + 0.03


def test_the_margin_predicts_what_was_flown_on_slow_autopilots():
    """PX4 SIH's attitude response (63 % at ~0.27 s) and ArduCopter SITL's (~0.19 s): LADRC at
    wc 2.5 / wo 12.5 with no input model (the defaults flown there then) has no margin left on
    either (it limit-cycled at 21-34 deg on both real autopilots); PD keeps one (it flew within
    1.5 deg), and so do today's defaults."""
    ladrc = make_controller(ControllerSpec(kind="ladrc", gains={"wc": (2.5, 2.5, 3.0),
                                                                "wo": (12.5, 12.5, 15.0)}),
                            hover_thrust=0.5)
    pd = make_controller(ControllerSpec(kind="pd"), hover_thrust=0.5)
    safe = make_controller(ControllerSpec(kind="ladrc"), hover_thrust=0.5)
    for tau in (0.19, 0.27):
        assert delay_margin(ladrc, tau=tau) == 0.0
        assert delay_margin(pd, tau=tau) > 0.0
        assert delay_margin(safe, tau=tau) > 0.05
    # on the plant it assumes (acceleration at once) the fast LADRC holds ~0.1 s
    assert 0.05 <= delay_margin(ladrc) <= 0.2


def test_more_delay_never_widens_the_margin():
    ctrl = make_controller(ControllerSpec(kind="adrc", gains={"wc": (2.5,) * 3}),
                           hover_thrust=0.5)
    margins = [delay_margin(ctrl, tau=0.05, delay=d) for d in (0.0, 0.02, 0.04)]
    assert margins[0] >= margins[1] >= margins[2]
    assert margins[0] - margins[2] == pytest.approx(0.04, abs=0.011)


def test_an_input_model_buys_margin_on_the_vehicle_it_describes():
    """The tuned observers are told the vehicle's lag: on that vehicle they keep a margin the
    same gains without the model do not have."""
    g = {"wc": (2.5, 2.5, 3.0), "wo": (12.5, 12.5, 15.0)}
    blind = make_controller(ControllerSpec(kind="ladrc", gains=dict(g)), hover_thrust=0.5)
    told = make_controller(ControllerSpec(kind="ladrc", gains={**g, "input_lag": (0.15,) * 3}),
                           hover_thrust=0.5)
    assert delay_margin(blind, tau=0.15) == 0.0
    assert delay_margin(told, tau=0.15) > 0.03


def test_the_spec_margin_is_what_records_carry():
    spec = ControllerSpec(kind="pd", gains={"wc": (2.5, 2.5, 3.0)})
    m = spec_margin(spec, "pd", "crazyflie")
    assert m == delay_margin(make_controller(spec, hover_thrust=0.5))
    assert 0.1 < m < 1.0


FAMILY = [(rate, tau, delay) for rate in (50.0, 100.0, 250.0) for tau in (0.03, 0.1, 0.2, 0.3)
          for delay in (0.0, 0.025, 0.05)]


@pytest.mark.parametrize("kind", ["ladrc", "adrc", "pd", "pid"])
def test_the_defaults_are_stable_on_every_vehicle_of_the_family(kind):
    """No input model, no gains given: the linearised loop is stable on every plant whose
    acceleration follows the command through a first-order lag of 0.03-0.30 s plus 0-50 ms of
    delay, at 50, 100 and 250 Hz (the rule: wc <= 1, wo <= 4 wc for the observers)."""
    for rate, tau, delay in FAMILY:
        ctrl = make_controller(ControllerSpec(kind=kind, rate_hz=rate), hover_thrust=0.5)
        assert spectral_radius(ctrl, tau, delay) < 1.0, (rate, tau, delay)


@pytest.mark.parametrize("kind", ["ladrc", "adrc"])
def test_the_fast_gains_are_kept_for_a_vehicle_whose_response_is_given(kind):
    """Told the vehicle's lag (input_lag), the observers get the fast bandwidths (wc 2.5):
    those are unstable somewhere in the family without the model, which is why the blind
    defaults are slower."""
    told = make_controller(ControllerSpec(kind=kind, gains={"input_lag": (0.13, 0.13, 0.05)}),
                           hover_thrust=0.5)
    blind = make_controller(ControllerSpec(kind=kind), hover_thrust=0.5)
    assert told._P[0, 0] != blind._P[0, 0] or not np.array_equal(told._P, blind._P)
    fast = make_controller(ControllerSpec(kind=kind, gains={"wc": (2.5,) * 3}), hover_thrust=0.5)
    assert any(spectral_radius(fast, tau, delay) >= 1.0
               for rate, tau, delay in FAMILY if rate == 100.0)
    assert delay_margin(told, tau=0.13) > 0.03


# PX4 SIH's horizontal response as identified in flight (2026-11-30): two equal lags of 74 ms
# after 76 ms of dead time (63 % at 0.234 s)
SIH_TAU, SIH_DEAD, SIH_T63 = 0.0737, 0.0764, 0.0764 + 2.1462 * 0.0737


def _sih_ladrc(wc, wo, shaped):
    gains = {"wc": (wc, wc, 2.5), "wo": (wo, wo, 12.5), "input_lag": (SIH_T63, SIH_T63, 0.05)}
    if shaped:
        gains.update(input_dead_time=(SIH_DEAD, SIH_DEAD, 0.0), input_lags=2)
    return make_controller(ControllerSpec(kind="ladrc", gains=gains), hover_thrust=0.5)


def _flown_rate(ctrl, tau, order, delay, seconds=20.0):
    """The per-step growth of a 1 um offset north (small enough never to reach a limit), the controller's own kernel (its input model
    as position_update runs it) flown against the sampled plant: the envelope's slope over the
    last two thirds."""
    from mavadrc.design.margin import _plant
    h = ctrl._h
    a, b = _plant(tau, h, order)
    x = np.zeros(b.size)
    x[0] = 1e-6
    line = [0.0] * int(round(delay / h))
    ctrl.reset(pos=(0.0, 0.0, -3.0))
    env = []
    for _ in range(int(seconds / h)):
        ctrl.update((x[0], 0.0, -3.0), (x[1], 0.0, 0.0), ref_pos=(0.0, 0.0, -3.0))
        u = ctrl.accel_applied[0]
        line.insert(0, u)
        x = a @ x + b * line.pop()
        env.append(abs(x[0]))
    env = np.array(env)
    w = int(3.0 / h)  # the envelope: the largest excursion in each 3 s
    peaks = np.log([env[k:k + w].max() for k in range(len(env) // 3, len(env) - w, w)])
    return math.exp(np.polyfit(np.arange(len(peaks)) * w, peaks, 1)[0])


def test_the_shaped_input_model_flown_is_the_one_the_margin_linearises():
    """On PX4 SIH's response, wc 2.5 / wo 12.5: the observers told one lag of its 63 % time are
    unstable (the spectral radius just over 1), told its shape (the dead time and two lags,
    ``input_dead_time``, ``input_lags: 2``) stable.  The controller's own kernel, flown against
    the sampled plant, grows and decays at the rates the margin's linearisation of it says."""
    for shaped, stable in ((False, False), (True, True)):
        ctrl = _sih_ladrc(2.5, 12.5, shaped)
        radius = spectral_radius(ctrl, SIH_TAU, SIH_DEAD, order=2)
        assert (radius < 1.0) == stable, (shaped, radius)
        assert _flown_rate(ctrl, SIH_TAU, 2, SIH_DEAD) == pytest.approx(radius, abs=3e-4)


def test_the_shaped_model_damps_the_swing_the_one_lag_model_left_on_px4_sih():
    """x500_gusts' gains (wc 2, wo 10) on PX4 SIH's response: told one lag of the 63 % time the
    loop keeps about 10 ms of delay margin and rings near 0.8 Hz (a disturbance there moves it
    0.78 m per m/s^2: flown, the roll and pitch swung 8-10 deg at 0.9-1.1 Hz, warned); told the
    shape identified it keeps 40 ms and the peak falls 2.5x.  At 0.1 Hz, where the figure
    eight's own motion is, the two agree."""
    one, shaped = _sih_ladrc(2.0, 10.0, False), _sih_ladrc(2.0, 10.0, True)
    m_one = delay_margin(one, tau=SIH_TAU, delay=SIH_DEAD, order=2)
    m_shaped = delay_margin(shaped, tau=SIH_TAU, delay=SIH_DEAD, order=2)
    assert m_one <= 0.02 and m_shaped >= m_one + 0.02
    # the shaped controller's own margin is the one on the response: it models it
    assert delay_margin(shaped) == pytest.approx(m_shaped, abs=0.011)
    def response(ctrl, hz):
        return disturbance_response(ctrl, 2 * math.pi * np.asarray(hz), tau=SIH_TAU,
                                    delay=SIH_DEAD, order=2)
    band = np.linspace(0.5, 1.2, 36)
    assert response(one, band).max() > 2.0 * response(shaped, band).max()
    assert response(one, [0.1])[0] == pytest.approx(response(shaped, [0.1])[0], rel=0.1)


@pytest.mark.parametrize("controller, field", [
    ("{type: ladrc, input_dead_time: 0.05}", "input_dead_time"),           # no input_lag
    ("{type: ladrc, input_lag: auto, input_lags: 2}", "input_lags"),       # auto is shaped
    ("{type: ladrc, input_lag: 0.2, input_dead_time: 0.3}", "input_dead_time"),  # past the lag
    ("{type: ladrc, input_lag: 0.2, input_dead_time: -0.01}", "input_dead_time"),
    ("{type: ladrc, input_lag: 0.2, input_lags: 3}", "input_lags"),
    ("{type: pd, predict: true}", "predict"),                              # no observer
    ("{type: ladrc, predict: true}", "predict"),                           # no input model
    ("{type: ladrc, input_lag: auto, predict: 1}", "predict"),             # not a boolean
])
def test_a_bad_input_model_names_the_file_line_and_field(controller, field, tmp_path):
    from mavadrc.mission.config import load_mission
    from sim.yamlio import ConfigError
    path = tmp_path / "bad.yaml"
    path.write_text(f"name: bad\nvehicle: x500\ncontroller: {controller}\n"
                    "trajectory:\n  - takeoff: {altitude: 1}\n  - land: {}\n")
    with pytest.raises(ConfigError) as e:
        load_mission(path)
    assert field in str(e.value) and "bad.yaml:3" in str(e.value)


def test_a_shaped_input_model_given_in_a_mission_flies_as_given(tmp_path):
    """The shape ``mavadrc identify`` writes (``input_dead_time``, ``input_lags``) read back
    from a mission: the controller it makes runs that dead time and two lags, and its lead is
    the model's mean delay."""
    from mavadrc.control.position import IN_ND, IN_NLAG, IN_TAU
    from mavadrc.mission.config import load_mission
    path = tmp_path / "shaped.yaml"
    path.write_text("name: shaped\nvehicle: x500\ncontroller: {type: ladrc, input_lag: [0.234, "
                    "0.234, 0.05], input_dead_time: [0.076, 0.076, 0], input_lags: 2}\n"
                    "trajectory:\n  - takeoff: {altitude: 1}\n  - land: {}\n")
    ctrl = make_controller(load_mission(path).controller, hover_thrust=0.5)
    assert ctrl._IN[0, IN_NLAG] == 2 and ctrl._IN[0, IN_ND] == 8
    assert ctrl._IN[0, IN_TAU] == pytest.approx((0.234 - 0.076) / 2.1462)
    assert ctrl.feedforward_lead[0] == pytest.approx(0.076 + 2 * (0.234 - 0.076) / 2.1462)
    assert ctrl._IN[2, IN_ND] == 0 and ctrl._IN[2, IN_TAU] == pytest.approx(0.05 / 2.1462)


def test_the_identified_shape_is_flown_by_the_mission_gains_and_by_the_slowed_defaults():
    """``input_lag: auto`` resolved with the dead time identified: the mission's own gains and
    the defaults (slowed on a slow vehicle by the one-lag rule) both fly the shape; the
    vertical keeps its own dead time."""
    from mavadrc.design.gains import resolve_gains
    lag, dead = (0.25, 0.25, 0.05), (0.08, 0.08, 0.0)
    own = ControllerSpec(kind="ladrc", gains={"wc": (2.0, 2.0, 2.5), "input_lag": "auto"})
    bare = ControllerSpec(kind="ladrc", gains={"input_lag": "auto"})
    for spec in (own, bare):
        for kind in ("ladrc", "adrc"):
            g = resolve_gains(spec, kind, identified=lag, dead_time=dead)
            assert g["input_lags"] == 2 and g["input_dead_time"] == dead, (spec, kind)
            assert g["input_lag"] == lag
            assert "input_lags" not in resolve_gains(spec, kind, identified=lag)
    # the defaults are slowed on the one-lag model, as before the shape
    assert resolve_gains(bare, identified=lag, dead_time=dead)["wc"] == \
        resolve_gains(bare, identified=lag)["wc"]


@pytest.mark.slow
def test_the_takeoff_pid_keeps_more_margin_than_the_safe_ladrc_on_every_plant():
    """The PID that flies the takeoff of an identifying flight (flight.TAKEOFF_WC) reads the
    velocity measured: on every plant of the family, and on PX4 SIH's response (two lags of
    0.074 s after 0.076 s of dead time), it is stable and keeps at least the safe LADRC's delay
    margin, and at the family's worst corner (0.30 s, 50 ms) 40 ms where the safe LADRC keeps
    none (measured 50 and 0)."""
    from mavadrc.design.gains import TAKEOFF_KIND, identification_gains, takeoff_gains

    def ctrl(kind, gains, rate):
        return make_controller(ControllerSpec(kind=kind, rate_hz=rate), hover_thrust=0.5,
                               kind=kind, gains=gains)

    for rate in (50.0, 100.0, 250.0):
        pid = ctrl(TAKEOFF_KIND, takeoff_gains(), rate)
        safe = ctrl("ladrc", identification_gains(), rate)
        for tau, delay, order in [(t, d, 1) for _, t, d in FAMILY] + [(0.074, 0.076, 2)]:
            assert spectral_radius(pid, tau, delay, order=order) < 1.0, (rate, tau, delay)
            a = delay_margin(pid, tau=tau, delay=delay, order=order)
            b = delay_margin(safe, tau=tau, delay=delay, order=order)
            assert a >= b - 1e-9, (rate, tau, delay, a, b)
        assert delay_margin(pid, tau=0.3, delay=0.05) >= 0.04
        assert delay_margin(safe, tau=0.3, delay=0.05) < 0.02
