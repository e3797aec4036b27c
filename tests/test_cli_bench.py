"""The bench command prints its figures as one JSON object with units in the names."""

import importlib.util
import json
import math
import subprocess
import sys

import pytest

from mavadrc.study.bench import sitl_figures

UNITS = ("_us", "_ms", "_s", "_x_realtime", "_pct", "_pct_of_core")


@pytest.mark.slow
def test_bench_json_prints_the_control_and_physics_figures():
    out = subprocess.run([sys.executable, "-m", "mavadrc", "bench", "--json", "--no-sitl",
                          "--no-compare"],
                         check=True, capture_output=True, text=True, timeout=600).stdout
    fig = json.loads(out)
    for key in ("linear_adrc_step_us", "han_adrc_step_us", "pd_step_us",
                "position_controller_ladrc_step_us", "attitude_controller_ladrc_step_us",
                "physics_step_us", "vehicle_step_us", "batch_vehicle_steps_per_s",
                "reference_sample_us", "reference_sample_many_per_time_us",
                "identify_lags_us", "scipy_lfilter_lags_us", "identify_fit_axis_s",
                "fit_beside_loop_thread_longest_gap_ms",
                "fit_beside_loop_process_longest_gap_ms"):
        assert math.isfinite(fig[key]) and fig[key] > 0.0, key
    assert all(k.endswith(UNITS) or k.startswith("ratio_") for k in fig)
    for peer, key in (("pyadrc", "pyadrc_statespace_step_us"), ("rotorpy", "rotorpy_step_us")):
        # a peer not installed: null, not NaN (which is not JSON)
        assert fig[key] is None if importlib.util.find_spec(peer) is None else fig[key] > 0.0


def test_bench_says_a_peer_is_not_installed_and_how_to_install_it(monkeypatch):
    import io

    from mavadrc.study import bench

    figures = {"linear_adrc_step_us": 0.31, "pyadrc_statespace_step_us": None,
               "ratio_pyadrc_over_linear_adrc": None, "rotorpy_step_us": None}
    monkeypatch.setattr(bench, "all_figures", lambda *a: figures)
    out = io.StringIO()
    assert bench.main(out=out) == 0
    lines = out.getvalue().splitlines()
    assert lines[0].split() == ["linear_adrc_step_us", "0.31"]
    for line, peer in zip(lines[1:], ("pyadrc", "pyadrc", "rotorpy")):
        assert f"{peer} is not installed: pip install -e \".[bench]\"" in line, line
    assert "nan" not in out.getvalue()


def test_bench_says_each_part_as_it_starts_on_stderr_and_quiet_says_nothing(monkeypatch,
                                                                            capsys):
    """A bench run takes minutes: each part is named as it starts (a plain line off a
    terminal), never on stdout, where the figures go."""
    import io

    from mavadrc.study import bench

    monkeypatch.setattr(bench, "bench_parts", lambda *a: [
        ("the control laws' steps", lambda: {"linear_adrc_step_us": 0.31}),
        ("the vehicle's physics", lambda: {"physics_step_us": 2.0})])
    out = io.StringIO()
    assert bench.main(out=out) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("bench: the control laws' steps: 0/2 parts")
    assert err[1].startswith("bench: the vehicle's physics: 1/2 parts")
    assert err[-1].startswith("bench: the vehicle's physics: 2/2 parts")
    assert "bench:" not in out.getvalue() and "physics_step_us" in out.getvalue()
    assert bench.main(out=io.StringIO(), progress=False) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.realtime
def test_the_shipped_fleet_command_is_measured_with_a_client_asking_100_hz():
    """``mavadrc sitl --count 2`` as a user starts it, each vehicle asked for 100 Hz positions
    by the bench's client: both deliver them (a few percent either side over 2 s of the
    wall clock) on their own clocks, which keep the wall's."""
    from mavadrc.study.bench import count_as_shipped

    r = count_as_shipped(2, seconds=2.0)
    assert 90.0 < r["lpn_hz_min"] <= r["lpn_hz_median"] < 110.0, r
    assert 0.95 < r["x_realtime"] < 1.05, r
    assert 0.0 < r["cpu_pct_of_core"] < 100.0 and r["client_cpu_pct_of_core"] > 0.0, r


@pytest.mark.realtime
def test_sitl_figures_measure_a_running_vehicle():
    fig = sitl_figures(realtime_seconds=2.0, lockstep_seconds=1.0)
    assert set(fig) == {"sitl_realtime_clock_error_pct", "sitl_realtime_cpu_pct_of_core",
                        "sitl_realtime_wander_clock_error_pct",
                        "sitl_realtime_wander_cpu_pct_of_core",
                        "ratio_sitl_realtime_cpu_wander_over_plain", "sitl_lockstep_x_realtime"}
    assert all(math.isfinite(v) and v >= 0.0 for v in fig.values())
    assert fig["sitl_lockstep_x_realtime"] > 1.0  # lockstep is not tied to the wall clock


def test_bench_flies_lockstep_alone_and_two_at_once(tmp_path):
    """The figures of two lockstep flights side by side: both flown as processes of their own
    (a failed one raises), the walls and their ratio reported."""
    from mavadrc.study.bench import _lockstep_side_by_side
    path = tmp_path / "hover.yaml"
    path.write_text("name: bench hover\nvehicle: crazyflie\n"
                    "controller: {type: ladrc, rate_hz: 100}\ntrajectory:\n"
                    "  - takeoff: {altitude: 0.5, speed: 1.0}\n"
                    "  - hover: {duration: 1.0}\n  - land: {speed: 1.0}\n")
    fig = _lockstep_side_by_side(path, tmp_path)
    assert set(fig) == {"fly_lockstep_one_alone_wall_s", "fly_lockstep_two_at_once_wall_s",
                        "ratio_fly_lockstep_two_at_once_over_one"}
    assert all(math.isfinite(v) and v > 0.0 for v in fig.values())
    assert fig["ratio_fly_lockstep_two_at_once_over_one"] == pytest.approx(
        fig["fly_lockstep_two_at_once_wall_s"] / fig["fly_lockstep_one_alone_wall_s"])
    summaries = sorted(tmp_path.glob("side2-*/*/summary.json"))
    assert len(summaries) == 2 and all(json.loads(p.read_text())["landed"] for p in summaries)
