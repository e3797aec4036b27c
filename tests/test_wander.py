"""A position estimate that wanders as PX4 SIH's EKF2 does (``sim: {wander: M}``): the loop
cannot follow what is slower than its vehicle answers and reads it as motion, so the error by
the estimate carries the wander, amplified; predicting amplifies it less.  Flown in process on
the bundled PX4 SIH quad (its attitude answers in 0.26 s, as PX4 SIH's does) at hover, with
x500_gusts' gains and the input model identified, three seeds each."""

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from mavadrc.fast.inprocess import L_POS, L_REF, L_T
from mavadrc.fast.fly import fly_inprocess
from mavadrc.mission.config import load_mission
from sim.sensors import WANDER_CORNER_HZ, wander_band_rms

HOVER = """name: hover on PX4 SIH's quad
vehicle: px4_sih_quad
controller: {type: ladrc, rate_hz: 100, wc: [2, 2, 2.5], wo: [10, 10, 12.5], input_lag: auto,
             predict: PREDICT}
trajectory:
  - takeoff: {altitude: 2.0, speed: 1.0}
  - hover: {duration: 40}
  - land: {speed: 0.7}
sim: {noise: true, wander: WANDER}
safety: {geofence: {north: [-15, 15], east: [-15, 15]}, altitude: {max: 10}}
"""
SETTLE_S, END_S = 6.0, 42.0  # the takeoff's 2 s and 4 s more; the hover ends at 42 s
BAND = wander_band_rms(0.06, WANDER_CORNER_HZ, 0.3, 1.0)  # 11.3 mm


def _flown(tmp_path, wander, predict, seed):
    """(max error after settling m, (x, y) RMS of the error by the estimate between 0.3 and 1
    Hz over the wander's there)."""
    path = tmp_path / f"hover-{wander}-{predict}-{seed}.yaml"
    path.write_text(HOVER.replace("WANDER", str(wander)).replace("PREDICT", str(predict).lower()))
    run = fly_inprocess(load_mission(path), seed=seed)
    assert run.aborted is None
    t = run.log[:, L_T] - run.mission_start
    e = run.log[:, L_REF:L_REF + 3] - run.log[:, L_POS:L_POS + 3]
    band = sosfiltfilt(butter(2, [0.3, 1.0], "band", fs=100.0, output="sos"), e[:, :2], axis=0)
    ok = (t >= SETTLE_S) & (t <= END_S)
    return (float(np.linalg.norm(e[ok], axis=1).max()),
            np.sqrt(np.mean(band[ok] ** 2, axis=0)) / BAND)


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wander")
    return {(w, p): [_flown(tmp, w, p, seed) for seed in range(3)]
            for w in (0.0, 0.06) for p in (False, True)}


@pytest.mark.slow
def test_the_loop_reads_the_wander_as_motion_and_amplifies_it(flights):
    """Measured: 0.2-0.25x the wander's band RMS without it (the white noise and the loop's own
    ripple), 1.18-1.37x with it (PX4 SIH flown, x500_gusts: 1.1-1.2x); the max error after
    settling 0.044-0.049 m without, 0.078-0.085 with (PX4 SIH's x500_gusts 0.08-0.12)."""
    for (mx0, band0), (mx1, band1) in zip(flights[0.0, False], flights[0.06, False]):
        assert np.all(band0 < 0.4)
        assert np.all(band1 > 1.05) and np.all(band1 < 1.7)
        assert mx0 < 0.065 and mx1 > 1.4 * mx0 and mx1 < 0.12


def test_predicting_amplifies_the_wander_less(flights):
    """The law that predicts acts where its command will: the loop's amplification over the
    band falls (measured 0.79-0.91x against 1.18-1.37x; linearised: 5.0x at 0.7 Hz to 2.5x
    at 1 Hz, "A law that predicts")."""
    for (_, plain), (mx, pred) in zip(flights[0.06, False], flights[0.06, True]):
        assert np.all(pred < 1.0)
        assert np.mean(pred) < 0.8 * np.mean(plain)
        assert mx < 0.12
    for (_, band0) in flights[0.0, True]:
        assert np.all(band0 < 0.4)


def test_a_bad_wander_is_refused_naming_where(tmp_path):
    from sim.yamlio import ConfigError

    path = tmp_path / "bad.yaml"
    path.write_text(HOVER.replace("WANDER", "-0.05").replace("PREDICT", "false"))
    with pytest.raises(ConfigError, match=r"bad\.yaml:9: sim\.wander: .*>= 0"):
        load_mission(path)
    path.write_text(HOVER.replace("WANDER", "0.05, wander_corner_hz: 0")
                    .replace("PREDICT", "false"))
    with pytest.raises(ConfigError, match=r"sim\.wander_corner_hz"):
        load_mission(path)


def test_the_server_refuses_a_bad_wander_in_one_line():
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "sim", "--wander", "2", "--duration", "1",
                        "--bind-offboard", "0", "--bind-gcs", "0"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode != 0 and "--wander must be 0 to 1 m (got 2.0)" in p.stderr
    assert "Traceback" not in p.stderr


def _wander_flown(scenario, controller, seeds=range(3)):
    """``after_settle`` of configs/experiments/estimate_wander.yaml's ``scenario`` flown by its
    ``controller`` (both by name) on the fast path, one per seed."""
    from pathlib import Path

    from mavadrc.study.experiment import load_experiment, run_inprocess
    exp = load_experiment(Path(__file__).resolve().parent.parent / "configs" / "experiments"
                          / "estimate_wander.yaml")
    i = [s.name for s in exp.scenarios].index(scenario)
    j = [c.name for c in exp.controllers].index(controller)
    return [run_inprocess(exp, i, j, seed)[0]["after_settle"] for seed in seeds]


@pytest.mark.slow
def test_the_spiral_on_a_wandering_px4_sih_meets_px4_sihs_floor():
    """configs/experiments/estimate_wander.yaml, three seeds: PX4 SIH's wander (60 mm) costs
    the spiral 0.03-0.04 m on the bundled PX4 SIH quad, and leaves it where PX4 SIH flew it
    (measured with six seeds: 0.186 +- 0.013 at the 35 deg tilt limit, 0.140 +- 0.015 at 45;
    PX4 SIH flown 0.10-0.21 and 0.10-0.15): the wider limit is worth 0.04 m, and neither comes
    near 0.1 (README, "The floor, reproduced")."""
    got = {}
    for sc in ("white noise only", "wander 60 mm (PX4 SIH's)"):
        for c in ("wc 2.1 tilt 35", "wc 2.1 tilt 45"):
            got[sc, c] = np.mean([a["max_error_m"] for a in _wander_flown(sc, c)])
    for c in ("wc 2.1 tilt 35", "wc 2.1 tilt 45"):
        assert got["wander 60 mm (PX4 SIH's)", c] > got["white noise only", c] + 0.015, got
    wandering = got["wander 60 mm (PX4 SIH's)", "wc 2.1 tilt 45"]
    assert 0.11 < wandering < 0.17, got
    assert got["wander 60 mm (PX4 SIH's)", "wc 2.1 tilt 35"] > wandering + 0.02, got


@pytest.mark.slow
def test_the_observers_kept_answer_a_smooth_wander_better_and_white_noise_worse():
    """configs/experiments/estimate_wander.yaml, seeds 0-2: the spiral's rule since 2026-12-05
    keeps the mission's wo 23.9 where it slows wc to 2.1 on PX4 SIH's response.  Against PX4
    SIH's wander with no white noise on top (PX4's EKF2 output, smoothed, carries none), that
    beats wo 12.6 in every seed (six seeds: max 0.055-0.092 m for 0.071-0.114, RMS 0.034 for
    0.044), as PX4 SIH flew it (0.081-0.092 in six flights for 0.080-0.117).  The bundled white
    sensor noise turns it round: the faster observers pass it to the command, which at the
    35 deg tilt limit, with the spiral's drag asking ~30 deg, clips for 12 s of the 33 instead of
    7 and doubles the RMS (0.19 for 0.09); at 45 deg, 0.163 against 0.139 max (README, "The
    floor, reproduced")."""
    flown = _wander_flown
    smooth = "wander 60 mm, no white noise"
    kept, slowed = flown(smooth, "wc 2.1 wo 23.9 tilt 45"), flown(smooth, "wc 2.1 tilt 45")
    for k, s in zip(kept, slowed):
        assert k["max_error_m"] < s["max_error_m"] - 0.005, (kept, slowed)
    assert np.mean([k["rms_error_m"] for k in kept]) < \
        0.85 * np.mean([s["rms_error_m"] for s in slowed])
    white = "wander 60 mm (PX4 SIH's)"
    kept, slowed = flown(white, "wc 2.1 wo 23.9 tilt 35"), flown(white, "wc 2.1 tilt 35")
    for k, s in zip(kept, slowed):
        assert k["rms_error_m"] > 1.5 * s["rms_error_m"], (kept, slowed)
