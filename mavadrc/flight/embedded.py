"""The embedded default: the bundled vehicle started as its own process for one flight.

On Linux, when this process runs a single thread, the vehicle is forked from it: the child
already has numpy, numba (initialised) and pymavlink loaded, and often the vehicle's compiled
kernels too, so it answers within a few tenths of a second instead of the ~1.2 s a fresh
``python -m sim`` needs.  Otherwise (other platforms, other threads running, where a fork could
inherit a held lock) it is started as ``python -m sim``.  Either way it is a separate process
that runs the same ``sim.cli.main`` with the same arguments, ignores Ctrl-C (the flight handles
that, then stops the vehicle) and writes its output to the flight's ``vehicle.log``.
"""

import gc
import logging
import math
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback

import yaml

#: ports chosen free are drawn from here up to the kernel's ephemeral range (MAVLink's own
#: 14540-14580 and 14550 lie below)
PORT_FLOOR = 20000
_pick = random.SystemRandom()  # a test that seeds the global random cannot make two pick alike


def _ephemeral_range():
    """The kernel's range for ports bound to 0 ((low, high)), None where it cannot be read."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            low, high = (int(v) for v in f.read().split())
        return low, high
    except (OSError, ValueError):
        return None


def _free_port(kind):
    """A loopback port nobody holds, below the ephemeral range where the kernel has one: a port
    chosen here is released until its user binds it, and meanwhile any socket bound to port 0
    (the vehicle's, a proxy's, another program's) could be handed it from inside that range."""
    span = _ephemeral_range()
    if span is not None and span[0] > PORT_FLOOR + 1000:
        for _ in range(100):
            port = _pick.randrange(PORT_FLOOR, span[0])
            s = socket.socket(socket.AF_INET, kind)
            try:
                s.bind(("127.0.0.1", port))
                return port
            except OSError:
                continue
            finally:
                s.close()
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def free_udp_port():
    """A loopback UDP port nobody is bound to right now."""
    return _free_port(socket.SOCK_DGRAM)


def udp_sink():
    """A loopback UDP socket bound to a port of its own and never read: the destination for
    datagrams nobody reads (a vehicle's ground-station streams in a test or a benchmark).  A
    port that was only free when asked for (:func:`free_udp_port`) may be handed to another
    program meanwhile, which then reads these datagrams as its own vehicle's.  Close it when
    the sender stops."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


def free_tcp_port():
    """A loopback TCP port nobody is bound to right now."""
    return _free_port(socket.SOCK_STREAM)


class EmbeddedVehicle:
    """``python -m sim`` for the mission's vehicle, wind and seed, talking over loopback MAVLink.

    Its offboard link sends to a free local port (``url`` is where the companion listens); its
    ground-station link sends to 14550 as PX4 SITL does, so QGroundControl can watch the flight.
    """

    def __init__(self, mission, *, lockstep=False, rate_hz=100.0, workdir=None, seed=None,
                 wind=None, log_path=None, start="auto", signing_key=None, params=None):
        port = free_udp_port()
        vehicle = mission.vehicle or "crazyflie"
        if (mission.mass_scale, mission.motor_thrust_curve,
                mission.attitude_bandwidth_scale) != (1.0, None, 1.0):
            from mavadrc.mission.config import vehicle_flown

            vehicle = workdir / "vehicle.yaml"  # the file, changed as the mission's sim: says
            vehicle.write_text(yaml.safe_dump(vehicle_flown(mission).as_file()))
        cmd = [sys.executable, "-m", "sim", "--vehicle", str(vehicle),
               "--seed", str(mission.seed if seed is None else seed),
               "--autopilot", mission.autopilot,
               "--attitude-controller", mission.attitude_controller,
               "--offboard-port", str(port), "--bind-offboard", "0", "--bind-gcs", "0", "-v"]
        wind = mission.wind if wind is None else wind
        if isinstance(wind, dict):
            path = workdir / "wind.yaml"
            path.write_text(yaml.safe_dump(plain(wind)))
            wind = str(path)
        if wind is not None:
            cmd += ["--wind", str(wind)]
        if lockstep:
            cmd += ["--lockstep", "--lockstep-rate", str(rate_hz)]
        if mission.noise:
            cmd += ["--noise"]
        if mission.wander:
            cmd += ["--wander", repr(mission.wander),
                    "--wander-corner", repr(mission.wander_corner_hz)]
        if mission.sensor_latency_s:
            cmd += ["--latency", repr(mission.sensor_latency_s)]
        if mission.height_drift_mps:
            cmd += ["--height-drift", repr(mission.height_drift_mps)]
        if mission.ground_climb_mps:
            cmd += ["--ground-climb", repr(mission.ground_climb_mps)]
        if mission.rangefinder:
            cmd += ["--rangefinder"]
        if mission.clock_rate != 1.0:  # real time only (fly refuses it in lockstep)
            cmd += ["--clock-rate", repr(mission.clock_rate)]
        if math.isnan(mission.heading_deg):
            cmd += ["--heading", "random"]  # drawn from --seed, as the fast path draws it
        elif mission.heading_deg:
            cmd += ["--heading", str(mission.heading_deg)]
        if signing_key is not None:
            key_path = workdir / "signing.key"
            key_path.write_text(bytes(signing_key).hex() + "\n")
            cmd += ["--signing-key", str(key_path)]
        for name, value in (params or {}).items():
            cmd += ["--param", f"{name}={value}"]
        cmd += link_options(mission)
        if start == "auto":
            start = "fork" if can_fork() else "spawn"
        self.log = subprocess.DEVNULL
        if start == "fork":
            self.proc = ForkedVehicle(cmd[3:], log_path)
        elif start == "spawn":
            if log_path is not None:
                self.log = open(log_path, "w")
            self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT,
                                         preexec_fn=_outlive_the_terminal if os.name == "posix" else None)
        else:
            raise ValueError(f"start must be auto, fork or spawn (got {start!r})")
        self.start = start
        self.url = f"udpin:127.0.0.1:{port}"
        self.cmd = cmd
        self.log_path = log_path

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
        """Raise FlightError if the vehicle process died, with its last words (the error line
        of a traceback, not the frames above it) and where its whole log is."""
        if self.proc.poll() is not None:
            from mavadrc.errors import FlightError

            raise FlightError(f"the bundled vehicle exited at once (code {self.proc.returncode})"
                              f"{last_words(self.log_path)}")


def last_words(log_path):
    """': <the log's last meaningful line> (whole log: PATH)', or '' with no log."""
    if log_path is None or not log_path.exists():
        return ""
    lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines()
             if ln.strip()]
    if not lines:
        return ""
    # a traceback's last line names the error; its frames (indented, "File ...") do not
    last = next((ln for ln in reversed(lines) if not ln.startswith(("File ", "^", "~"))),
                lines[-1])
    return f": {last} (whole log: {log_path})"


def link_options(mission):
    """The vehicle's options for the mission's ``sim: {link:}`` (``mission.link``, a
    :class:`sim.link_model.LinkModel` or None): applied on the wall clock by a real-time
    vehicle, in vehicle time by a lockstep one."""
    link = getattr(mission, "link", None)
    if link is None:
        return []
    from sim.link_flags import link_args

    return link_args(link)


def can_fork():
    """Whether the vehicle can be forked from this process: Linux, and no other thread that
    could hold a lock at the moment of the fork."""
    return sys.platform == "linux" and hasattr(os, "fork") and threading.active_count() == 1


def _end_with_the_companion():
    """Linux: SIGTERM to the forked vehicle when the companion that forked it dies, however it
    dies (SIGKILL included): a vehicle no companion will ever fly again is not left running."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _outlive_the_terminal():
    # Ctrl-C in a terminal reaches the whole process group, and so does the hangup of a terminal
    # that goes away; the flight answers both (hold and land; fly on) and needs the vehicle
    # alive to do so.  SIGTERM is the vehicle's own to answer (the companion's handler, which a
    # forked vehicle inherits, is not)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


class ForkedVehicle:
    """``sim.cli.main(argv)`` in a forked child, behind the part of Popen's interface that
    :class:`EmbeddedVehicle` uses (poll, wait, terminate, kill, returncode, pid)."""

    def __init__(self, argv, log_path=None):
        for f in (sys.stdout, sys.stderr):
            try:
                f.flush()
            except (OSError, ValueError):
                pass
        pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                gc.freeze()  # the inherited heap is not ours to collect (nor to copy, page by page)
                _outlive_the_terminal()
                _end_with_the_companion()
                fd = os.open(log_path if log_path is not None else os.devnull,
                             os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                os.dup2(fd, 1)
                os.dup2(fd, 2)
                sys.stdout = sys.stderr = open(1, "w", buffering=1, closefd=False)
                logging.root.handlers.clear()  # the vehicle configures its own logging
                from sim.cli import main

                code = main(argv) or 0
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:
                traceback.print_exc()
            finally:
                try:
                    sys.stdout.flush()
                finally:
                    os._exit(code)
        self.pid = pid
        self.returncode = None

    def poll(self):
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout=None):
        end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if end is not None and time.monotonic() > end:
                raise subprocess.TimeoutExpired(f"vehicle process {self.pid}", timeout)
            time.sleep(0.005)
        return self.returncode

    def _signal(self, sig):
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self):
        self._signal(signal.SIGTERM)

    def kill(self):
        self._signal(signal.SIGKILL)


def plain(x):
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list):
        return [plain(v) for v in x]
    return x
