"""Parameter validation, NaN handling and the public API of mavadrc.control."""

import math

import numpy as np
import pytest

from mavadrc.control import (PD, HanADRC, HanESO, LinearADRC, LinearESO, TrackingDifferentiator,
                             make_channel)


@pytest.mark.parametrize("factory, name", [
    (lambda: LinearADRC(h=0.01, b0=1.0, wc=-2.0, wo=10.0), "wc"),
    (lambda: LinearADRC(h=0.01, b0=1.0, wc=2.0, wo=-10.0), "wo"),
    (lambda: LinearADRC(h=0.01, b0=1.0, wc=2.0, wo=math.nan), "wo"),
    (lambda: LinearADRC(h=0.01, b0=0.0, wc=2.0, wo=10.0), "b0"),
    (lambda: LinearADRC(h=0.0, b0=1.0, wc=2.0, wo=10.0), "h"),
    (lambda: LinearADRC(h=-0.01, b0=1.0, wc=2.0, wo=10.0), "h"),
    (lambda: LinearADRC(h=0.01, b0=1.0, wc=2.0, wo=10.0, u_min=1.0, u_max=-1.0), "u_min"),
    (lambda: HanADRC(h=0.01, b0=0.0), "b0"),
    (lambda: HanADRC(h=0.01, b0=1.0, r0=-1.0), "r0"),
    (lambda: HanADRC(h=0.01, b0=1.0, h0=0.001), "h0"),
    (lambda: HanADRC(h=0.01, b0=1.0, c=0.0), "c"),
    (lambda: HanADRC(h=0.01, b0=1.0, law="fal", a1=1.5), "a1"),
    (lambda: HanESO(h=0.01, b0=1.0, eso_gains="nope"), "convention"),
    (lambda: LinearESO(h=0.01, b0=1.0, wo=0.0), "wo"),
    (lambda: PD(h=0.01, kp=-1.0, kd=1.0), "kp"),
    (lambda: PD(h=0.01, kp=1.0, kd=-1.0), "kd"),
    (lambda: TrackingDifferentiator(h=0.0, r0=10.0), "h"),
    (lambda: TrackingDifferentiator(h=0.01, r0=10.0, h0=0.001), "h0"),
    (lambda: make_channel("pid", h=0.01), "kind"),
])
def test_bad_parameters_raise_value_error_naming_the_parameter(factory, name):
    with pytest.raises(ValueError, match=name):
        factory()


@pytest.mark.parametrize("make", [
    lambda: LinearADRC(h=0.01, b0=1.0, wc=2.0, wo=10.0),
    lambda: HanADRC(h=0.01, b0=1.0, r0=5.0, r=5.0),
    lambda: PD(h=0.01, kp=4.0, kd=4.0),
])
@pytest.mark.parametrize("bad", [{"y": math.nan}, {"r": math.inf}, {"rdot": math.nan},
                                 {"rddot": -math.inf}])
def test_non_finite_input_raises_and_never_poisons_the_state(make, bad):
    clean, hit = make(), make()
    samples = [(0.1 * k, 1.0) for k in range(50)]
    for y, r in samples[:25]:
        clean.update(y, r)
        hit.update(y, r)
    args = {"y": 0.3, "r": 1.0, "rdot": 0.0, "rddot": 0.0}
    args.update(bad)
    with pytest.raises(ValueError, match=next(iter(bad))):
        hit.update(**args)
    for y, r in samples[25:]:
        assert hit.update(y, r) == clean.update(y, r)
    assert np.all(np.isfinite(hit._s))


def test_observers_and_td_refuse_non_finite_samples():
    obs = LinearESO(h=0.01, b0=1.0, wo=20.0)
    obs.update(0.5, 0.0)
    before = obs.z
    with pytest.raises(ValueError, match="y"):
        obs.update(math.nan, 0.0)
    with pytest.raises(ValueError, match="u"):
        obs.update(0.5, math.inf)
    assert obs.z == before
    td = TrackingDifferentiator(h=0.01, r0=10.0)
    with pytest.raises(ValueError, match="v"):
        td.update(math.nan)
    assert td.v == (0.0, 0.0)


def test_pd_refuses_a_non_finite_measured_rate_without_touching_state():
    pd = PD(h=0.01, kp=4.0, kd=4.0)
    pd.update(0.0, 1.0, ydot=0.0)
    before = pd._s.copy()
    with pytest.raises(ValueError, match="ydot"):
        pd.update(0.0, 1.0, ydot=math.nan)
    assert np.array_equal(pd._s, before)


def test_anti_peaking_start_at_the_first_measurement():
    c = LinearADRC(h=0.01, b0=1.0, wc=2.0, wo=10.0)
    c.update(5.0, 5.0)
    z1, z2, z3 = c.z
    assert z1 == pytest.approx(5.0) and z2 == 0.0 and z3 == 0.0
    a = HanADRC(h=0.01, b0=1.0)
    a.update(-2.0, 3.0)
    assert a.z[0] == pytest.approx(-2.0)
    assert a.v[0] == pytest.approx(-2.0)  # the TD starts where the plant is
    c.reset(1.0)
    assert c.z == (1.0, 0.0, 0.0)


def test_limits_hold_and_the_limited_value_is_what_the_observer_sees():
    c = LinearADRC(h=0.01, b0=1.0, wc=10.0, wo=50.0, u_min=-0.5, u_max=0.5)
    u = c.update(0.0, 10.0)
    assert u == 0.5 and c.u == 0.5


def test_gains_follow_the_bandwidth_parameterisation():
    c = LinearADRC(h=0.001, b0=1.0, wc=7.0, wo=30.0)
    assert (c.kp, c.kd) == (49.0, 14.0)
    e = LinearESO(h=0.001, b0=1.0, wo=30.0, discretization="euler")
    assert e.gains == (90.0, 2700.0, 27000.0)
    p = PD.from_bandwidth(h=0.01, wc=3.0)
    assert (p.kp, p.kd) == (9.0, 6.0)


def test_eso_gain_conventions():
    h = 0.01
    han = HanESO(h=h, b0=1.0)
    thesis = HanESO(h=h, b0=1.0, eso_gains="thesis")
    from mavadrc.control import kernels as K
    assert han._p[K.P_B02] == pytest.approx(1.0 / (1.6 * h**1.5))
    assert han._p[K.P_B03] == pytest.approx(1.0 / (8.6 * h**2.2))
    # the thesis's premultiplied set: h*beta = (1, 1/(2 h^0.5), 2/(25 h^1.2))
    assert h * thesis._p[K.P_B01] == pytest.approx(1.0)
    assert h * thesis._p[K.P_B02] == pytest.approx(1.0 / (2.0 * h**0.5))
    assert h * thesis._p[K.P_B03] == pytest.approx(2.0 / (25.0 * h**1.2))
