"""The link model and sensor latency from mission and experiment YAML, on the in-process fast
path and on the lockstep MAVLink path: the same flight on both for the same seed, and what the
link does to the flight."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")

from mavadrc.study.experiment import experiment_from_text, run_inprocess  # noqa: E402
from mavadrc.fast.inprocess import L_POS, L_REF, L_T, STATUS_LINK  # noqa: E402
from mavadrc.fast.fly import fly_inprocess  # noqa: E402
from mavadrc.mission.config import load_mission  # noqa: E402
from sim.link_model import LINK_FROM  # noqa: E402
from sim.vehicle import SimVehicle  # noqa: E402
from sim.yamlio import ConfigError  # noqa: E402
from sitl_helpers import both_paths  # noqa: E402

EXPERIMENT = """
name: link
seeds: 1
defaults:
  vehicle: crazyflie
  settle_s: 3
controllers:
  - {name: LADRC, type: ladrc, wc: [2.5, 2.5, 3.0], wo: [12.5, 12.5, 15.0]}
scenarios:
  - name: perfect
    trajectory:
      - takeoff: {altitude: 1.0, speed: 0.5}
      - hover: {duration: 4}
    wind: {components: [{type: constant, speed: 3.0, direction_from_deg: 270}]}
  - name: radio
    trajectory:
      - takeoff: {altitude: 1.0, speed: 0.5}
      - hover: {duration: 4}
    wind: {components: [{type: constant, speed: 3.0, direction_from_deg: 270}]}
    sim:
      sensor_latency_s: 0.02
      link:
        down: {latency_s: 0.02, jitter_s: 0.015, loss: 0.05}
        up: {latency_s: 0.01, jitter_s: 0.01, loss: 0.03}
        blackouts: [[5.0, 0.2]]
"""


@pytest.fixture(scope="module")
def exp():
    return experiment_from_text("link.yaml", EXPERIMENT)


def _rms(d):
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))


def test_the_fast_path_and_the_lockstep_wire_meet_the_same_link(exp, tmp_path):
    """Latency, jitter, loss and a blackout on both directions, and 20 ms of sensor latency:
    the in-process run and the lockstep MAVLink flight get the same samples at the same
    periods and fly the same flight (the link's decisions come from the seed, not from the
    path)."""
    rec_fast, log, rec_wire, tab, pos = both_paths(exp, 1, 0, 0, tmp_path)
    # the flight's record says which link it flew through
    summary = json.loads((Path(rec_wire["record_folder"]) / "summary.json").read_text())
    assert summary["config"]["link"] == exp.scenarios[1].mission.link.as_dict()
    assert summary["config"]["sensor_latency_s"] == 0.02
    assert _rms(pos - log[:, L_POS:L_POS + 3]) < 1e-3
    assert abs(rec_fast["rms_error_m"] - rec_wire["rms_error_m"]) < 1e-3
    # the link really acted: samples went missing and the intervals are not the period's
    dt = np.diff(log[:, L_T])
    assert dt.max() >= 0.2 - 1e-9  # the blackout
    assert (dt > 0.015).sum() > 0.03 * len(dt)


NOISY = EXPERIMENT.replace(
    "    wind: {components: [{type: constant, speed: 3.0, direction_from_deg: 270}]}\n"
    "  - name: radio",
    "    wind: {components: [{type: constant, speed: 3.0, direction_from_deg: 270}]}\n"
    "    sim: {noise: true}\n  - name: radio").replace(
    "    sim:\n      sensor_latency_s", "    sim:\n      noise: true\n      sensor_latency_s")


@pytest.mark.parametrize("i", [0, 1], ids=["noise", "noise, sensor latency and a radio"])
def test_sensor_noise_is_the_same_flight_on_the_fast_path_and_the_lockstep_wire(i, tmp_path):
    """Sensor noise (the server's --noise) on both paths, alone and with 20 ms of sensor
    latency and the lossy, late link: the firmware flies on the same noisy estimate, the
    companion gets the same noisy samples, and the two flights agree as without noise."""
    noisy = experiment_from_text("noisy.yaml", NOISY)
    assert all(sc.mission.noise for sc in noisy.scenarios)
    rec_fast, log, rec_wire, tab, pos = both_paths(noisy, i, 0, 2, tmp_path)
    ref = np.column_stack([tab["ref_x"], tab["ref_y"], tab["ref_z"]])
    assert np.max(np.abs(ref - log[:, L_REF:L_REF + 3])) < 1e-6  # the same (noisy) origin
    assert _rms(pos - log[:, L_POS:L_POS + 3]) < 1e-3
    # to the CSV's digits (~5e-9 m): the same draws in the same order, the spool-up levelled
    # at the heading the flight has then (the ATTITUDE of the period before)
    assert np.max(np.abs(pos - log[:, L_POS:L_POS + 3])) < 1e-7
    assert abs(rec_fast["rms_error_m"] - rec_wire["rms_error_m"]) < 1e-9
    # the noise really is in the samples: the velocity the companion got jitters by about
    # the sensors' 2 cm/s from one sample to the next
    dv = np.diff(np.column_stack([tab["vel_x"], tab["vel_y"], tab["vel_z"]]), axis=0)
    assert np.median(np.abs(dv)) > 0.005


def test_a_lossy_late_link_costs_accuracy_and_the_samples_it_lost(exp):
    """Same wind, same controller: the radio's scenario has fewer control steps (lost and
    merged samples) and a larger error than the perfect one."""
    rec_p, log_p = run_inprocess(exp, 0, 0, 0, keep_log=True)
    rec_r, log_r = run_inprocess(exp, 1, 0, 0, keep_log=True)
    assert len(log_r) < 0.95 * len(log_p)
    assert rec_r["after_settle"]["rms_error_m"] > 1.2 * rec_p["after_settle"]["rms_error_m"]
    assert rec_r["aborted"] is None


def test_a_link_with_loss_depends_on_the_seed(exp):
    assert not exp.scenarios[0].random and exp.scenarios[1].random
    a = run_inprocess(exp, 1, 0, 0, keep_log=True)[1]
    b = run_inprocess(exp, 1, 0, 1, keep_log=True)[1]
    assert len(a) != len(b) or not np.allclose(a[:, L_T], b[:, L_T])


def _mission(tmp_path, sim):
    p = tmp_path / "m.yaml"
    p.write_text("trajectory:\n  - takeoff: {altitude: 1.0, speed: 0.5}\n"
                 "  - hover: {duration: 3}\n  - land: {speed: 0.5}\n" + sim)
    return load_mission(p)


def test_a_blackout_past_the_gap_limit_ends_the_run_as_the_flight_would(tmp_path):
    """The flight ends on a gap between samples past safety.max_gap_s (0.5 s by default); the
    fast path does too, at the first sample after the gap."""
    m = _mission(tmp_path, "sim:\n  link: {blackouts: [[4.0, 0.8]]}\n")
    r = fly_inprocess(m, kind="pd")
    assert r.status == STATUS_LINK and "gap" in r.aborted
    t = r.log[:, L_T]
    assert np.diff(t)[-1] > 0.5 and t[-1] + r.mission_start >= 4.8 - 1e-9
    short = fly_inprocess(_mission(tmp_path, "sim:\n  link: {blackouts: [[4.0, 0.3]]}\n"),
                          kind="pd")
    assert short.aborted is None


def test_the_link_applies_from_link_from_on(tmp_path):
    """Before LINK_FROM (the arming handshake) the link is perfect: a blackout then changes
    nothing."""
    early = fly_inprocess(_mission(tmp_path, "sim:\n  link: {blackouts: [[0.5, 1.4]]}\n"),
                          kind="pd")
    none = fly_inprocess(_mission(tmp_path, ""), kind="pd")
    assert np.array_equal(early.log, none.log, equal_nan=True)
    assert LINK_FROM < 3.0


@pytest.mark.parametrize("text, where", [
    ("sim:\n  link: {down: {loss: 1.5}}\n", "m.yaml:6: sim.link.down.loss"),
    ("sim:\n  link: {sideways: {}}\n", "sideways"),
    ("sim:\n  link: {blackouts: [[1, -2]]}\n", "blackouts"),
    ("sim:\n  sensor_latency_s: -0.1\n", "sensor_latency_s"),
])
def test_a_malformed_link_names_file_line_and_field(tmp_path, text, where):
    with pytest.raises(ConfigError, match=where.replace(".", r"\.")):
        _mission(tmp_path, text)


def test_sensor_latency_off_the_control_grid_is_refused_on_the_fast_path(tmp_path):
    m = _mission(tmp_path, "sim:\n  sensor_latency_s: 0.015\n")
    with pytest.raises(ValueError, match="whole number of control periods"):
        fly_inprocess(m, kind="pd")


def test_a_sensor_model_reports_the_state_of_its_own_time():
    """With a sensor model (no noise, no latency) the reported state is the state at the
    vehicle's time, not that of the physics step before (as the truth is)."""
    a = SimVehicle("crazyflie", sensors={"noise": {}, "latency_s": 0.0}, position=(0, 0, -1))
    b = SimVehicle("crazyflie", position=(0, 0, -1))
    a.arm()
    b.arm()
    for v in (a, b):
        v.set_attitude_target([1.0, 0.0, 0.0, 0.0], 0.2)
        v.step(0.3)
    ra, rb = a.reported(), b.reported()
    assert np.allclose(ra.position, rb.position, atol=1e-12)
    assert np.allclose(ra.velocity, rb.velocity, atol=1e-12)
    assert abs(rb.velocity[2]) > 0.1 and math.isfinite(ra.position[2])
    late = SimVehicle("crazyflie", sensors={"latency_s": 0.05}, position=(0, 0, -1))
    late.arm()
    late.set_attitude_target([1.0, 0.0, 0.0, 0.0], 0.2)
    late.step(0.25)
    b2 = SimVehicle("crazyflie", position=(0, 0, -1))
    b2.arm()
    b2.set_attitude_target([1.0, 0.0, 0.0, 0.0], 0.2)
    b2.step(0.2)
    assert np.allclose(late.reported().position, b2.reported().position, atol=1e-12)


def test_a_reordered_frame_is_late_not_lost():
    """The frame count behind summary.json's frame_loss_fraction: a frame that arrives after a
    later one filled in its gap and is not counted lost; a repeat is not counted at all; a
    number jumped over half a lap ago cannot be filled in by the next lap's frame.  Behind the
    bundled link's 10 ms of jitter (5 % of the samples lost) it had read 23 %."""
    import collections
    import random

    from mavadrc.mavlink.sources import SKIPPED_KEPT, count_sequence

    def count(seqs):
        last, lost, skipped = None, 0, collections.deque(maxlen=SKIPPED_KEPT)
        for q in seqs:
            last, n = count_sequence(last, q, skipped)
            lost += n
        return lost

    assert count([0, 1, 2, 3]) == 0
    assert count([0, 2, 3]) == 1  # one lost
    assert count([0, 2, 1, 3]) == 0  # one late
    assert count([0, 2, 2, 3]) == 1  # one lost, one repeat
    assert count([254, 255, 1, 0, 2]) == 0  # late across the wrap
    lap = list(range(256))
    # 5 skipped, then a lap on; the repeat of 5 from the new lap is no late frame
    assert count([3, 4, 6] + lap[7:] + lap[:7] + [5]) == 1
    rng = random.Random(1)
    n, drop = 20000, 0.05
    sent = [k & 0xFF for k in range(n)]
    kept = [q for q in sent if rng.random() > drop]
    # each frame delayed by up to 3 frames' time: reordered, none lost beyond the drops
    order = sorted(range(len(kept)), key=lambda i: i + 3.0 * rng.random())
    lost = count([kept[i] for i in order])
    assert abs(lost / n - (n - len(kept)) / n) < 0.005, lost / n
