"""The bench command prints its figures as one JSON object with units in the names."""

import json
import math
import subprocess
import sys

from mavadrc.bench import sitl_figures

UNITS = ("_us", "_s", "_x_realtime", "_pct", "_pct_of_core")


def test_bench_json_prints_the_control_and_physics_figures():
    out = subprocess.run([sys.executable, "-m", "mavadrc", "bench", "--json", "--no-sitl",
                          "--no-compare"],
                         check=True, capture_output=True, text=True, timeout=600).stdout
    fig = json.loads(out)
    for key in ("linear_adrc_step_us", "han_adrc_step_us", "pd_step_us",
                "position_controller_ladrc_step_us", "attitude_controller_ladrc_step_us",
                "physics_step_us", "vehicle_step_us", "batch_vehicle_steps_per_s"):
        assert math.isfinite(fig[key]) and fig[key] > 0.0, key
    assert all(k.endswith(UNITS) or k.startswith("ratio_") for k in fig)


def test_sitl_figures_measure_a_running_vehicle():
    fig = sitl_figures(realtime_seconds=2.0, lockstep_seconds=1.0)
    assert set(fig) == {"sitl_realtime_clock_error_pct", "sitl_realtime_cpu_pct_of_core",
                        "sitl_lockstep_x_realtime"}
    assert all(math.isfinite(v) and v >= 0.0 for v in fig.values())
    assert fig["sitl_lockstep_x_realtime"] > 1.0  # lockstep is not tied to the wall clock
