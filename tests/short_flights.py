"""The short hover the companion's fault tests fly, and how they fly it: over MAVLink against the
bundled vehicle, through the lossy-link proxy of ``sim/lossy/``, in real time."""

import io

from sitl_helpers import start_lossy_vehicle

from mavadrc.flight.fly import fly
from mavadrc.mission.config import load_mission


SHORT = """name: short hover
vehicle: crazyflie
controller: {type: ladrc, rate_hz: 100, input_lag: [0.13, 0.13, 0.05]}  # the Crazyflie's response
trajectory:
  - takeoff: {altitude: 1.0, speed: 1.0}
  - hover: {duration: HOVER}
  - land: {speed: 0.6}
wind: breeze_1ms
safety: {geofence: {north: [-5, 5], east: [-5, 5]}, altitude: {max: 5}}
"""
#: the bundled PX4 without its spool-up wait, to keep real-time tests short
FAST_PX4 = {"COM_SPOOLUP_TIME": 0.0}


def short_mission(tmp_path, hover=3, extra="", telemetry_timeout_s=None):
    """The short hover; ``telemetry_timeout_s``: its safety's (default the mission's 0.5 s)."""
    text = SHORT.replace("HOVER", str(hover))
    if telemetry_timeout_s is not None:
        text = text.replace("altitude: {max: 5}}",
                            f"altitude: {{max: 5}}, telemetry_timeout_s: {telemetry_timeout_s}}}")
        assert f"telemetry_timeout_s: {telemetry_timeout_s}" in text
    path = tmp_path / f"short{hover}.yaml"
    path.write_text(text + extra)
    return load_mission(path)


def fly_through(link, mission, tmp_path, **kw):
    out = io.StringIO()
    kw.setdefault("timeout", 90.0)
    summary, folder = fly(mission, connect=link.companion_url, out=tmp_path / "runs",
                          progress=False, stream=out, **kw)
    return summary, folder, out.getvalue()


def lossy_vehicle(**kw):
    kw.setdefault("wind", "breeze_1ms")
    kw.setdefault("params", dict(FAST_PX4))
    return start_lossy_vehicle(**kw)


def stop(srv, link):
    link.stop(check=False)
    srv.stop()
