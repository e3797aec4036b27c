"""Sensors: truth by default, exact latency through the ring buffer, seeded noise of the
requested size."""

import numpy as np
import pytest

from mavadrc.control.rotations import quat_from_euler
from sim.physics import NX
from sim.sensors import Sensors


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


@pytest.mark.parametrize("sig", [
    {"position": 0.1, "velocity": 0.05, "attitude": 0.02, "rates": 0.3},
    {"velocity": 0.05, "attitude": 0.02},
    {"position": 0.1},
    {},
])
def test_noise_drawn_ahead_reads_as_measure_does(sig):
    """Sensors.draws + measure_into (the compiled loops' way, tick by tick) give exactly the
    readings of measure, and leave the stream where measure would: the draws of a run can be
    taken ahead in one go, after and before calls of measure."""
    from sim.sensors import measure_into

    a, b = Sensors(sig, seed=4), Sensors(sig, seed=4)
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
    if not sig:
        assert not noise.any()
