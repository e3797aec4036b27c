"""Sensors: truth by default, exact latency through the ring buffer, seeded noise of the
requested size, and an estimate's slow wander with the spectrum measured on PX4 SIH."""

import numpy as np
import pytest

from mavadrc.control.rotations import quat_from_euler
from sim.physics import NX
from sim.sensors import WANDER_CORNER_HZ, Sensors, wander_band_rms


def _state(t):
    x = np.zeros(NX)
    x[0:3] = [t, 2 * t, -t]
    x[3:6] = [1.0, 2.0, -1.0]
    x[6:10] = quat_from_euler(0.1, 0.0, 0.01 * t)
    x[10:13] = [0.1 * t, 0.0, 0.0]
    x[13:] = 1000.0
    return x


def test_truth_by_default():
    s = Sensors()
    x = _state(1.0)
    y = s.measure(1.0, x)
    assert np.array_equal(y, x) and y is not x
    y[0] = 99.0
    assert x[0] == 1.0


def test_latency_delivers_the_state_from_latency_ago():
    s = Sensors(latency_s=0.02)
    dt = 1e-3
    out = [s.measure(k * dt, _state(k * dt)) for k in range(500)]   # grows the ring buffer
    assert np.array_equal(out[0], _state(0.0))
    assert np.array_equal(out[10], _state(0.0))          # not yet 20 ms of history
    for k in (20, 21, 250, 499):
        assert np.allclose(out[k], _state((k - 20) * dt), rtol=0, atol=1e-12)
    s.reset()
    assert np.array_equal(s.measure(5.0, _state(5.0)), _state(5.0))


def test_noise_is_seeded_and_has_the_requested_size():
    sig = {"position": 0.1, "velocity": 0.05, "attitude": 0.02, "rates": 0.3}
    x = _state(2.0)
    a = np.array([Sensors(sig, seed=1).measure(0.0, x) for _ in range(3)])
    assert np.array_equal(a[0], a[1])
    s = Sensors(sig, seed=1)
    ys = np.array([s.measure(k * 1e-3, x) for k in range(4000)])
    assert np.array_equal(ys[0], a[0])
    assert not np.array_equal(ys[0], ys[1])
    err = ys - x
    assert err[:, 0:3].std(axis=0) == pytest.approx([0.1] * 3, rel=0.06)
    assert err[:, 3:6].std(axis=0) == pytest.approx([0.05] * 3, rel=0.06)
    assert err[:, 10:13].std(axis=0) == pytest.approx([0.3] * 3, rel=0.06)
    assert np.array_equal(ys[:, 13:], np.broadcast_to(x[13:], (4000, 4)))
    # attitude: unit quaternions, rotated by angles of about sigma
    assert np.allclose(np.linalg.norm(ys[:, 6:10], axis=1), 1.0)
    dots = np.abs(ys[:, 6:10] @ x[6:10])
    angles = 2 * np.arccos(np.minimum(dots, 1.0))
    assert np.sqrt(np.mean(angles ** 2)) == pytest.approx(0.02 * np.sqrt(3), rel=0.06)
    other = Sensors(sig, seed=2).measure(0.0, x)
    assert not np.array_equal(other, a[0])


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="unknown noise key"):
        Sensors({"altitude": 0.1})
    with pytest.raises(ValueError, match="noise position"):
        Sensors({"position": -1.0})
    with pytest.raises(ValueError, match="latency_s"):
        Sensors(latency_s=-0.1)
    with pytest.raises(ValueError, match="wander must be 0 to 1 m"):
        Sensors(wander=-0.01)
    with pytest.raises(ValueError, match="wander_corner_hz"):
        Sensors(wander=0.05, wander_corner_hz=0.0)
    with pytest.raises(ValueError, match="dt must be"):
        Sensors(wander=0.05, dt=0.0)


@pytest.mark.parametrize("sig, wander", [
    ({"position": 0.1, "velocity": 0.05, "attitude": 0.02, "rates": 0.3}, 0.0),
    ({"velocity": 0.05, "attitude": 0.02}, 0.0),
    ({"position": 0.1}, 0.0),
    ({}, 0.0),
    ({"position": 0.1, "velocity": 0.05, "attitude": 0.02, "rates": 0.3}, 0.06),
    ({"attitude": 0.02}, 0.06),
])
def test_noise_drawn_ahead_reads_as_measure_does(sig, wander):
    """Sensors.draws + measure_into (the compiled loops' way, tick by tick) give exactly the
    readings of measure, and leave the stream where measure would: the draws of a run can be
    taken ahead in one go, after and before calls of measure."""
    from sim.sensors import measure_into

    a, b = Sensors(sig, seed=4, wander=wander), Sensors(sig, seed=4, wander=wander)
    xs = [_state(0.01 * k) for k in range(60)]
    want = [a.measure(0.0, x) for x in xs]
    got = [b.measure(0.0, xs[0])]
    noise = b.draws(49)
    for k in range(1, 50):
        xm = np.empty(NX)
        measure_into(xs[k], noise[k - 1], b.sigmas(), xm)
        got.append(xm)
    got += [b.measure(0.0, x) for x in xs[50:]]
    assert np.array_equal(np.array(got), np.array(want))
    if not sig and not wander:
        assert not noise.any()


def _band(x, fs, lo, hi):
    from scipy.signal import welch

    f, p = welch(x, fs=fs, nperseg=2 ** 16, axis=0)
    m = (f >= lo) & (f < hi)
    return np.sqrt(np.trapezoid(p[m], f[m], axis=0))


def test_the_wander_has_the_spectrum_measured_on_px4_sih():
    """0.06 m of wander: per axis 0.06 m RMS, in 0.3-0.6 Hz 10.7 mm and in 0.6-1 Hz 3.6 mm (as
    PX4 SIH's estimate: 8-15 and 3-5 mm), its velocity the position's rate; seeded, and on a
    stream of its own, so the white noise of a seed is unchanged by it."""
    dt, n = 0.001, 400_000  # 400 s: 60 of the wander's time constants
    s = Sensors(seed=7, wander=0.06)
    d = s.draws(n)
    pos, vel = d[:, 0:3], d[:, 3:6]
    assert np.sqrt(np.mean(pos ** 2)) == pytest.approx(0.06, rel=0.15)
    assert np.abs(pos.mean(axis=0)).max() < 0.03  # stationary from the start: no transient
    assert np.allclose(vel[1:], np.diff(pos, axis=0) / dt, rtol=0, atol=1e-9)
    for lo, hi, want in ((0.3, 0.6, 0.0107), (0.6, 1.0, 0.0036)):
        assert wander_band_rms(0.06, WANDER_CORNER_HZ, lo, hi) == pytest.approx(want, rel=0.02)
        assert np.mean(_band(pos, 1 / dt, lo, hi)) == pytest.approx(want, rel=0.15)
    assert np.mean(_band(pos, 1 / dt, 2.0, 5.0)) < 0.001  # slow: nothing left above 2 Hz
    assert s.sigmas()[0] == pytest.approx(0.06) and s.sigmas()[1] == pytest.approx(
        np.sqrt(np.mean(vel ** 2)), rel=0.15)
    # seeded, its own stream
    sig = {"position": 0.01, "velocity": 0.02, "rates": 0.01, "attitude": 0.002}
    a = Sensors(sig, seed=3, wander=0.06).draws(2000)
    b = Sensors(sig, seed=3, wander=0.06).draws(2000)
    c = Sensors(sig, seed=3).draws(2000)
    assert np.array_equal(a, b)
    assert np.array_equal(a[:, 6:], c[:, 6:])  # rates and attitude as without it
    w = a[:, 0:3] - c[:, 0:3]  # the wander alone: slow
    assert np.abs(np.diff(w, axis=0)).max() < 1e-3 and np.abs(w).max() > 1e-3
    assert not np.array_equal(Sensors(sig, seed=4, wander=0.06).draws(2000)[:, 0:3]
                              - Sensors(sig, seed=4).draws(2000)[:, 0:3], w)
