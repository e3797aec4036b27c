"""A flight's roll/pitch swing is measured and named for what it is: a limit cycle repeats
itself period after period; a loop's resonance driven by noise or wind swings as far and forgets
itself within a few periods.  The summary's warnings say which, and a limit cycle predicted from
the delay margin is held against the swing flown."""

import io
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from mavadrc.flight.summary import (OSCILLATION_WARN_DEG, margin_outcome, print_table, swing_text,
                                    swing_warning)
from mavadrc.flight.record import LIMIT_CYCLE_REGULARITY, attitude_oscillation, regularity

RATE = 50.0  # Hz: ATTITUDE as the autopilots stream it
T = np.arange(0.0, 40.0, 1.0 / RATE)


def resonance(zeta, seed, deg=5.0, f0=1.0):
    """White noise through a second-order resonance at ``f0`` Hz with damping ``zeta``, scaled
    to ``deg`` RMS (rad): a loop answering noise."""
    w = 2 * np.pi * f0
    b, a = signal.bilinear([w * w], [1.0, 2.0 * zeta * w, w * w], RATE)
    x = signal.lfilter(b, a, np.random.default_rng(seed).normal(size=T.size))
    return np.radians(deg) * x / np.std(x)


def tone(deg, f, noise_deg=0.0, seed=0):
    x = np.radians(deg) * np.sin(2 * np.pi * f * T)
    return x + np.radians(noise_deg) * np.random.default_rng(seed).normal(size=T.size)


def test_a_sustained_tone_is_a_limit_cycle():
    # as ArduCopter and PX4 SIH swung with fast gains and no input model: +-28 deg near 1 Hz
    osc = attitude_oscillation(T, tone(27.0, 0.98, noise_deg=1.0), np.zeros(T.size))
    assert osc["limit_cycle"] is True
    assert osc["regularity"] > 0.95
    assert osc["amplitude_deg"] == pytest.approx(27.0, rel=0.1)
    assert osc["frequency_hz"] == pytest.approx(0.98, abs=0.05)
    # small, and under white noise of a third of its size, still regular (on the other axis)
    small = attitude_oscillation(T, np.zeros(T.size), tone(1.5, 0.9, noise_deg=0.5, seed=1))
    assert small["limit_cycle"] is True and small["frequency_hz"] == pytest.approx(0.9, abs=0.05)


@pytest.mark.parametrize("zeta", [0.15, 0.25])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_resonance_driven_by_noise_is_not(zeta, seed):
    """The loop's resonance answering noise (PX4 SIH's swing on x500_gusts was 0.26-0.33 alike
    three periods later) swings as far, and is no limit cycle: exp(-2 pi zeta 3) in theory
    (0.06 at zeta 0.15), 0.16-0.42 here in windows of 8 periods."""
    osc = attitude_oscillation(T, resonance(zeta, seed), np.zeros(T.size))
    assert osc["amplitude_deg"] > 2 * OSCILLATION_WARN_DEG
    assert osc["frequency_hz"] == pytest.approx(1.0, abs=0.15)
    assert osc["regularity"] < 0.45 < LIMIT_CYCLE_REGULARITY
    assert osc["limit_cycle"] is False


def test_a_limit_cycle_clipped_at_the_tilt_limit_is_one():
    """Met at the tilt limit, a limit cycle is clipped to nearly a square wave: still alike
    period after period."""
    square = np.radians(35.0) * np.sign(np.sin(2 * np.pi * 0.9 * T))
    osc = attitude_oscillation(T, square, np.zeros(T.size))
    assert osc["regularity"] > 0.9 and osc["limit_cycle"] is True
    assert osc["frequency_hz"] == pytest.approx(0.9, abs=0.05)


def test_the_regularity_is_the_autocorrelation_three_periods_on():
    dt = 1.0 / RATE
    x = np.sin(2 * np.pi * 1.0 * T)
    assert regularity(x, dt, 1.0) == pytest.approx(1.0, abs=0.01)
    # a tone dying away at damping 0.1 (no noise): little alike three periods on
    w = 2 * np.pi
    ring = np.exp(-0.1 * w * T) * np.sin(w * T)
    assert regularity(ring[:500], dt, 1.0) < 0.5
    assert regularity(x[:250], dt, 1.0) is None  # 3 periods do not fit in half of 5 s


def test_a_short_record_does_not_tell():
    short = T[: int(6 * RATE)]
    osc = attitude_oscillation(short, np.radians(20) * np.sin(2 * np.pi * short),
                               np.zeros(short.size))
    assert osc["amplitude_deg"] > 15 and osc["limit_cycle"] is None
    assert "too short a record to tell" in swing_text(osc)
    # and its warning names no kind (a PX4 SIH spiral's summary, cut short by the ground, said
    # "too short a record to tell its kind: a limit cycle, whatever the error says")
    text = swing_warning(osc)
    assert "the record cannot say" in text and "no good flight" in text
    assert "a limit cycle, whatever" not in text and "no steady limit cycle" not in text


def test_the_warning_names_the_kind_of_swing():
    cycle = attitude_oscillation(T, tone(27.0, 0.98), np.zeros(T.size))
    noise = attitude_oscillation(T, resonance(0.25, 0, deg=4.0), np.zeros(T.size))
    calm = attitude_oscillation(T, resonance(0.25, 0, deg=0.5), np.zeros(T.size))
    assert "a limit cycle, whatever the error says" in swing_warning(cycle)
    text = swing_warning(noise)
    assert "no steady limit cycle" in text and "no good flight" in text
    assert "irregular" in text
    assert swing_warning(calm) is None and swing_warning(None) is None


def _margin_warned():
    said = ("no delay margin on the response identified: the loop is unstable on this "
            "vehicle's model and a limit cycle is expected")
    spoken = []
    notices = SimpleNamespace(warned_text={"margin": said}, say=spoken.append)
    return notices, said, spoken


def test_a_predicted_limit_cycle_not_flown_is_said_so():
    """A limit cycle predicted and not flown: the summary must not go on saying "expected"
    alone."""
    flight, said, spoken = _margin_warned()
    warnings = ["another", said]
    calm = attitude_oscillation(T, resonance(0.25, 0, deg=0.2), np.zeros(T.size))
    margin_outcome(flight, warnings, calm)
    assert warnings[0] == "another"
    assert warnings[1].startswith(said) and "; measured: +-0." in warnings[1]
    assert warnings[1].endswith(f"none past the {OSCILLATION_WARN_DEG:g} deg warned at")
    assert spoken and "none past the" in spoken[0]


def test_a_predicted_limit_cycle_flown_stays_warned():
    """A swing past 5 deg, of either kind, leaves the prediction standing beside its own
    warning."""
    flight, said, spoken = _margin_warned()
    warnings = [said]
    cycle = attitude_oscillation(T, tone(20.0, 1.0), np.zeros(T.size))
    margin_outcome(flight, warnings, cycle)
    assert warnings == [said] and not spoken
    noise = attitude_oscillation(T, resonance(0.25, 0, deg=4.0), np.zeros(T.size))
    assert noise["limit_cycle"] is False and noise["amplitude_deg"] > OSCILLATION_WARN_DEG
    margin_outcome(flight, warnings, noise)
    assert warnings == [said] and not spoken
    # a short record cannot tell: the warning stays as said
    short = T[: int(6 * RATE)]
    margin_outcome(flight, warnings, attitude_oscillation(
        short, np.radians(0.3) * np.sin(2 * np.pi * short), np.zeros(short.size)))
    assert warnings == [said] and not spoken


def test_the_table_prints_the_swing():
    osc = attitude_oscillation(T, tone(27.0, 0.98), np.zeros(T.size))
    summary = {"rms_error_xyz_m": [0.1, 0.1, 0.1], "max_error_xyz_m": [0.2, 0.2, 0.2],
               "rms_error_m": 0.17, "max_error_m": 0.3, "attitude_oscillation": osc}
    out = io.StringIO()
    print_table(summary, out)
    line = f"roll/pitch swing +-{osc['amplitude_deg']:.1f} deg at 0.97 Hz, regular (a limit cycle)"
    assert osc["amplitude_deg"] > 25 and line in out.getvalue()


def test_the_identified_margin_is_one_figure_with_its_share_of_the_lag():
    from mavadrc.design.margin import identified_margin_text

    gains = {"input_lag": (0.122, 0.120, 0.05)}
    little = identified_margin_text(0.020, gains)
    assert little == ("delay margin 20 ms on the response identified (little: under 75% of its "
                      "122 ms lag; a vehicle slower than identified by more will oscillate)")
    plenty = identified_margin_text(0.100, gains)
    assert "little" not in plenty and plenty.startswith("delay margin 100 ms")
    assert "expect a limit cycle" in identified_margin_text(0.0, gains)
