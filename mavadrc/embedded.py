"""The embedded default: the bundled vehicle started as its own process for one flight."""

import socket
import subprocess
import sys
import time

import yaml


def _free_port(kind):
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def free_udp_port():
    """A loopback UDP port nobody is bound to right now."""
    return _free_port(socket.SOCK_DGRAM)


def free_tcp_port():
    """A loopback TCP port nobody is bound to right now."""
    return _free_port(socket.SOCK_STREAM)


class EmbeddedVehicle:
    """``python -m sim`` for the mission's vehicle, wind and seed, talking over loopback MAVLink.

    Its offboard link sends to a free local port (``url`` is where the companion listens); its
    ground-station link sends to 14550 as PX4 SITL does, so QGroundControl can watch the flight.
    """

    def __init__(self, mission, *, lockstep=False, rate_hz=100.0, workdir=None, seed=None,
                 wind=None, log_path=None):
        port = free_udp_port()
        cmd = [sys.executable, "-m", "sim", "--vehicle", mission.vehicle or "crazyflie",
               "--seed", str(mission.seed if seed is None else seed),
               "--autopilot", mission.autopilot,
               "--attitude-controller", mission.attitude_controller,
               "--offboard-port", str(port), "--bind-offboard", "0", "--bind-gcs", "0", "-v"]
        wind = mission.wind if wind is None else wind
        if isinstance(wind, dict):
            path = workdir / "wind.yaml"
            path.write_text(yaml.safe_dump(_plain(wind)))
            wind = str(path)
        if wind is not None:
            cmd += ["--wind", str(wind)]
        if lockstep:
            cmd += ["--lockstep", "--lockstep-rate", str(rate_hz)]
        if mission.noise:
            cmd += ["--noise"]
        self.log = open(log_path, "w") if log_path is not None else subprocess.DEVNULL
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT)
        self.url = f"udpin:127.0.0.1:{port}"
        self.cmd = cmd

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if self.log is not subprocess.DEVNULL:
            self.log.close()

    def check(self):
        """Raise if the vehicle process died (with the end of its log)."""
        if self.proc.poll() is not None:
            time.sleep(0.1)
            raise RuntimeError(f"the bundled vehicle exited with code {self.proc.returncode}")


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_plain(v) for v in x]
    return x
