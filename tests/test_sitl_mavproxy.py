"""Unmodified MAVProxy, headless, connects to the ground-station link and reads the parameters."""

import os
import re
import shutil
import subprocess
import sys
import time

import pytest

from sitl_helpers import free_udp_port, udp_sink

# MAVProxy, a program of its own, against a vehicle running in real time
pytestmark = [pytest.mark.clients, pytest.mark.realtime]

MAVPROXY = shutil.which("mavproxy.py") or os.path.join(os.path.dirname(sys.executable),
                                                       "mavproxy.py")


@pytest.mark.skipif(not os.path.exists(MAVPROXY), reason="MAVProxy is not installed")
def test_mavproxy_detects_the_vehicle_and_downloads_every_parameter(tmp_path):
    gcs = free_udp_port()
    offboard = udp_sink()  # nobody reads the offboard link here: its streams go to a held port
    sim = subprocess.Popen([sys.executable, "-m", "mavadrc", "sitl", "--instance", "11",
                            "--gcs-port", str(gcs),
                            "--offboard-port", str(offboard.getsockname()[1]),
                            "--bind-offboard", "0", "--bind-gcs", "0", "--duration", "60"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log = tmp_path / "mavproxy.out"
    try:
        with open(log, "w") as out:
            mp = subprocess.Popen([sys.executable, MAVPROXY, f"--master=udpin:127.0.0.1:{gcs}",
                                   "--daemon", "--non-interactive", "--cmd=param fetch",
                                   f"--state-basedir={tmp_path}"],
                                  stdout=out, stderr=subprocess.STDOUT, cwd=tmp_path)
            end = time.monotonic() + 30
            while time.monotonic() < end and "Received" not in log.read_text():
                time.sleep(0.2)
            mp.terminate()
            mp.wait(10)
    finally:
        sim.terminate()
        sim.wait(10)
        offboard.close()
    text = log.read_text()
    assert "Detected vehicle 12:1" in text  # instance 11 -> system 12, autopilot component 1
    got = re.search(r"Received (\d+) parameters", text)
    assert got is not None, text
    from sim.personality import px4
    assert int(got.group(1)) == len(px4().params)
    assert "fence breach" not in text
