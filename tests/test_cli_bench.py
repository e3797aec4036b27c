"""The bench command prints its figures as one JSON object with units in the names."""

import json
import math
import subprocess
import sys


def test_bench_json_prints_the_control_figures():
    out = subprocess.run([sys.executable, "-m", "mavadrc", "bench", "--json"], check=True,
                         capture_output=True, text=True, timeout=600).stdout
    fig = json.loads(out)
    for key in ("linear_adrc_step_us", "han_adrc_step_us", "pd_step_us",
                "position_controller_ladrc_step_us", "attitude_controller_ladrc_step_us"):
        assert math.isfinite(fig[key]) and fig[key] > 0.0, key
    assert all(k.endswith(("_us", "_s", "_x_realtime")) or k.startswith("ratio_") for k in fig)
