"""``thrust_tilt: measured``: the thrust sized for the tilt the vehicle reports rather than the
one commanded, so that its vertical part is what the loop asked for while the attitude loop is
still on its way (PX4 SIH's answers a tilt in 0.26 s, its thrust in 0.05)."""

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")

from mavadrc.control.geometry import (GRAVITY, TILT_RATIO_RANGE,  # noqa: E402
                                      acceleration_to_attitude, thrust_for_tilt)
from mavadrc.study.experiment import experiment_from_text, run_inprocess  # noqa: E402
from mavadrc.fast.identify import with_identified  # noqa: E402
from mavadrc.mission.identification import doublets  # noqa: E402
from mavadrc.fast.inprocess import L_POS, L_REF, L_T, L_THRUST  # noqa: E402
from mavadrc.fast.fly import fly_inprocess  # noqa: E402
from mavadrc.mission.config import load_mission  # noqa: E402
from sim.yamlio import ConfigError  # noqa: E402
from sitl_helpers import both_paths  # noqa: E402

SPIRAL = Path(__file__).resolve().parents[1] / "configs" / "missions" / "thesis_spiral_wind.yaml"


def test_the_thrust_keeps_the_vertical_part_commanded_at_the_tilt_measured():
    q, thrust, acc = acceleration_to_attitude((4.0, 3.0, 0.0), 0.3, hover_thrust=0.5)
    cos_cmd = 1.0 - 2.0 * (q[1] ** 2 + q[2] ** 2)
    assert cos_cmd == pytest.approx(GRAVITY / math.hypot(5.0, GRAVITY))
    for tilt_now in (10.0, 20.0, 35.0):  # the attitude loop behind, level, or past it
        c = math.cos(math.radians(tilt_now))
        t = thrust_for_tilt(thrust, *q, c, 1.0)
        # the vertical part of the thrust is the one commanded (the hover's, here)
        assert t * c == pytest.approx(thrust * cos_cmd, rel=1e-12)
        assert t * c == pytest.approx(0.5, rel=1e-9)
    # at the tilt commanded, the thrust as computed
    assert thrust_for_tilt(thrust, *q, cos_cmd, 1.0) == pytest.approx(thrust, rel=1e-12)
    # an attitude far from the one commanded moves the thrust no further than the range
    assert thrust_for_tilt(thrust, *q, 1e-3, 1.0) == pytest.approx(
        thrust * TILT_RATIO_RANGE[1])
    lo = thrust_for_tilt(thrust, 1.0, 0.0, 0.0, 0.0, math.cos(math.radians(60.0)), 1.0)
    assert lo == pytest.approx(thrust * TILT_RATIO_RANGE[1])
    assert thrust_for_tilt(thrust, *q, 1.0, 1.0) == pytest.approx(thrust * cos_cmd)
    # the thrust limit holds, and a meaningless tilt (upside down) leaves the thrust alone
    assert thrust_for_tilt(0.9, *q, 0.5, 1.0) == 1.0
    assert thrust_for_tilt(thrust, *q, -0.5, 1.0) == thrust


def _px4_sih_spiral(tmp_path, tilt):
    """thesis_spiral_wind on the bundled model of PX4 SIH's quad (its attitude answers in
    0.26 s, its thrust in 0.05), in calm air, identified as a flight identifies it."""
    text = SPIRAL.read_text().replace("vehicle: crazyflie\n", "vehicle: px4_sih_quad\n")
    text = re.sub(r"\nwind: .*", "\nwind: calm", text)
    text = re.sub(r"\n  thrust_tilt: .*", "", text)
    text = text.replace("controller:\n", f"controller:\n  thrust_tilt: {tilt}\n")
    path = tmp_path / f"spiral_{tilt}.yaml"
    path.write_text(text)
    m = load_mission(path)
    assert m.controller.thrust_tilt == tilt
    run = fly_inprocess(with_identified(m))
    L = run.log
    sel = L[:, L_T] >= m.settle_s + doublets(np.zeros(3)).duration
    err = L[sel, L_POS:L_POS + 3] - L[sel, L_REF:L_REF + 3]
    return float(np.linalg.norm(err, axis=1).max()), float(np.sqrt(np.mean(err[:, 2] ** 2)))


def test_sized_for_the_tilt_measured_a_slow_attitude_loop_no_longer_moves_the_height(tmp_path):
    """The spiral asks 30 deg of tilt of PX4 SIH's draggy quad.  Sized for the tilt commanded,
    every change of the horizontal command changes the thrust at once and the tilt 0.26 s
    later: the vertical loop reads the difference as a disturbance and fights it, and its
    thrust moves the vehicle sideways (measured on this model: 0.36 m after settling, 28 mm
    RMS vertically).  Sized for the tilt measured, the height no longer moves with the
    horizontal command (0.018 m, 0.3 mm)."""
    commanded = _px4_sih_spiral(tmp_path, "commanded")
    measured = _px4_sih_spiral(tmp_path, "measured")
    assert commanded[1] > 0.01 and measured[1] < 0.002
    assert measured[1] < commanded[1] / 10.0
    assert measured[0] < 0.05 and commanded[0] > 3.0 * measured[0]


EXPERIMENT = """
name: thrust tilt
seeds: 1
defaults:
  vehicle: px4_sih_quad
  settle_s: 3
controllers:
  - {name: LADRC, type: ladrc, wc: [1.5, 1.5, 3.0], wo: [7.5, 7.5, 15.0],
     input_lag: [0.26, 0.26, 0.05], thrust_tilt: measured}
scenarios:
  - name: a leg in wind
    trajectory:
      - takeoff: {altitude: 1.0, speed: 0.5}
      - waypoints: {points: [[3, 2, 1.5]], speed: 2.0}
      - hover: {duration: 2}
    wind: {components: [{type: constant, speed: 4.0, direction_from_deg: 270}]}
    sim: {noise: true}
"""


@pytest.mark.slow
def test_the_fast_path_and_the_lockstep_wire_size_the_thrust_alike(tmp_path):
    """Sized for the tilt measured, the two paths still fly the same flight: the fast path
    takes the tilt of the period before each sample, as the flight has it from the ATTITUDE
    that follows the position sample in a period's messages."""
    exp = experiment_from_text("tilt.yaml", EXPERIMENT)
    assert exp.controllers[0].spec.thrust_tilt == "measured"
    rec_fast, log, rec_wire, tab, pos = both_paths(exp, 0, 0, 1, tmp_path)
    assert np.max(np.abs(pos - log[:, L_POS:L_POS + 3])) < 1e-6
    assert np.max(np.abs(np.asarray(tab["thrust"]) - log[:, L_THRUST])) < 1e-6
    summary = json.loads((Path(rec_wire["record_folder"]) / "summary.json").read_text())
    assert summary["controller_flown"]["thrust_tilt"] == "measured"
    # the thrust really was resized: against the same flight sized for the tilt commanded
    plain = experiment_from_text("plain.yaml", EXPERIMENT.replace("measured", "commanded"))
    _, other = run_inprocess(plain, 0, 0, 1, keep_log=True)
    n = min(len(other), len(log))
    assert np.max(np.abs(other[:n, L_THRUST] - log[:n, L_THRUST])) > 0.005


def test_a_thrust_tilt_it_does_not_know_names_the_file_and_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(SPIRAL.read_text().replace("controller:\n",
                                               "controller:\n  thrust_tilt: sideways\n"))
    with pytest.raises(ConfigError, match=r"bad\.yaml.*thrust_tilt"):
        load_mission(path)


def test_tune_writes_the_thrust_tilt_its_gains_were_tuned_with():
    import yaml

    from mavadrc.mission.config import ControllerSpec
    from mavadrc.study.tune import controller_yaml
    for tilt in ("measured", "commanded"):
        spec = ControllerSpec(kind="ladrc", thrust_tilt=tilt, gains={"wc": (2.0, 2.0, 3.0)})
        result = {"spec": spec, "improved": True, "cost_m": 0.01, "start_cost_m": 0.02,
                  "scenarios": ["a"], "seeds": [0], "evaluations": 4, "bounds": {},
                  "on_bounds": [], "controller": "LADRC"}
        entry = yaml.safe_load(controller_yaml(result))
        assert entry.get("thrust_tilt", "commanded") == tilt
