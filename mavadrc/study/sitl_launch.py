"""One SITL process for one run: started fresh in a scratch folder, its parameters set over
MAVLink, waited on until it can arm, and stopped by its process id whatever happens.

- PX4 SIH: ``PX4_SIM_MODEL=sihsim_quadx PX4_SIMULATOR=sihsim px4 -d -w SCRATCH ETC``; its offboard
  link sends to UDP 14540 (``udpin:0.0.0.0:14540``).
- ArduCopter SITL: ``arducopter --model quad --speedup 1 --defaults copter.parm -I0 --home
  LAT,LON,ALT,HEADING`` in the scratch folder; MAVLink on ``tcp:127.0.0.1:5760``.
- the bundled vehicle: ``python -m mavadrc sitl --autopilot AP ...`` on free UDP ports, so it
  never meets a real SITL on the fixed ones.

A real SITL listens on fixed ports: two at once on one machine would fly each other's commands,
so runs are flown one at a time.
"""

import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from mavadrc.study.sitl_config import AUTOPILOT_NAMES, BUNDLED

#: ArduCopter SITL's home (the ArduPilot autotest site); its heading is the run's
ARDUPILOT_HOME = (-35.363261, 149.165230, 584.0)
#: PX4 SIH's airframe per frame, ArduCopter's --model
PX4_MODELS = {"quad": "sihsim_quadx", "hexa": "sihsim_hex"}
ARDUPILOT_MODELS = {"quad": "quad", "hexa": "hexa"}
#: seconds between SIGTERM and SIGKILL when a SITL is stopped
STOP_GRACE_S = 5.0


class SitlError(RuntimeError):
    """A SITL that could not be started, prepared or made ready (exit 1); says which, why, and
    where its log is."""


@dataclass
class SitlPlan:
    """What one run's SITL is, as values: the autopilot, its build (None: the bundled vehicle),
    frame, initial heading (deg) and the parameters set before it flies; for the bundled vehicle
    also the ``mavadrc sitl`` options of the scenario (vehicle, wind file, seed, ...)."""
    autopilot: str
    path: str = None
    frame: str = "quad"
    heading_deg: float = 0.0
    params: dict = field(default_factory=dict)
    bundled_args: list = field(default_factory=list)

    @property
    def bundled(self):
        return self.path is None or self.path == BUNDLED

    def describe(self):
        return (f"the bundled vehicle as {self.autopilot}" if self.bundled
                else f"{AUTOPILOT_NAMES[self.autopilot]} ({self.path})")


def _px4_build(path):
    """(px4 binary, its etc folder) from a PX4 binary, build folder or source tree."""
    p = Path(path).expanduser()
    for binary in (p, p / "bin" / "px4", p / "build" / "px4_sitl_default" / "bin" / "px4"):
        if binary.is_file() and (binary.parent.parent / "etc").is_dir():
            return binary.resolve(), (binary.parent.parent / "etc").resolve()
    raise SitlError(f"--sitl px4={path}: no PX4 SITL build there (looked for "
                    "build/px4_sitl_default/bin/px4 beside its etc folder)")


def _ardupilot_build(path):
    """(arducopter binary, copter.parm) from the binary or the ArduPilot source tree."""
    p = Path(path).expanduser()
    parm = Path("Tools/autotest/default_params/copter.parm")
    for binary in (p, p / "build" / "sitl" / "bin" / "arducopter"):
        if binary.is_file():
            tree = binary.resolve().parents[3] if binary.resolve() == (p.resolve()) else p
            if (tree / parm).is_file():
                return binary.resolve(), (tree / parm).resolve()
            raise SitlError(f"--sitl ardupilot={path}: found {binary} but not {parm} beside "
                            "it: give the ArduPilot source tree")
    raise SitlError(f"--sitl ardupilot={path}: no ArduCopter SITL build there (looked for "
                    "build/sitl/bin/arducopter)")


def free_udp_port():
    """A UDP port nothing on the machine holds now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def project_env():
    """The environment for a child ``python -m mavadrc``: this tree first on its path."""
    import mavadrc

    root = str(Path(mavadrc.__file__).resolve().parent.parent)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(
        os.pathsep) if p and p != root])
    return env


def command(plan, scratch):
    """(argv, environment, MAVLink URL the companion connects to) of ``plan``'s SITL."""
    if plan.bundled:
        port = free_udp_port()
        argv = [sys.executable, "-m", "mavadrc", "sitl", "--autopilot", plan.autopilot,
                "--offboard-port", str(port), "--bind-offboard", "0",
                "--gcs-port", str(free_udp_port()), "--bind-gcs", "0",
                "--heading", f"{plan.heading_deg:g}", *plan.bundled_args]
        return argv, project_env(), f"udpin:127.0.0.1:{port}"
    if plan.autopilot == "px4":
        binary, etc = _px4_build(plan.path)
        env = dict(os.environ, PX4_SIM_MODEL=PX4_MODELS[plan.frame], PX4_SIMULATOR="sihsim")
        return [str(binary), "-d", "-w", str(scratch), str(etc)], env, "udpin:0.0.0.0:14540"
    binary, parm = _ardupilot_build(plan.path)
    lat, lon, alt = ARDUPILOT_HOME
    home = f"{lat},{lon},{alt:g},{plan.heading_deg % 360.0:g}"
    return ([str(binary), "--model", ARDUPILOT_MODELS[plan.frame], "--speedup", "1",
             "--defaults", str(parm), "-I0", "--home", home], dict(os.environ),
            "tcp:127.0.0.1:5760")


def stop_process(proc, grace=STOP_GRACE_S):
    """Stop ``proc`` (and its process group: it was started in a session of its own) by its id:
    SIGTERM, then SIGKILL after ``grace`` s; waits for it.  Returns its exit status."""
    if proc.poll() is not None:
        return proc.returncode
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        except PermissionError:  # not its own group after all: the process alone
            proc.send_signal(sig)
        try:
            return proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    return proc.wait()


class SitlProcess:
    """One SITL process in ``scratch`` (its log ``sitl.log`` and ``sitl.pid`` there): a context
    manager that stops it on the way out, on an exception or Ctrl-C too."""

    def __init__(self, plan, scratch):
        self.plan = plan
        self.scratch = Path(scratch)
        self.proc = None
        self.url = None
        self.log_path = self.scratch / "sitl.log"

    def start(self):
        if self.scratch.exists():  # a fresh SITL: nothing of an earlier attempt's (eeprom.bin)
            import shutil
            shutil.rmtree(self.scratch)
        self.scratch.mkdir(parents=True)
        argv, env, self.url = command(self.plan, self.scratch)
        (self.scratch / "command.txt").write_text(" ".join(argv) + "\n")
        with open(self.log_path, "wb") as log:
            try:
                # a session of its own: the terminal's Ctrl-C reaches the flight, which lands,
                # and this process is stopped after it
                self.proc = subprocess.Popen(argv, cwd=self.scratch, env=env, stdout=log,
                                             stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                             start_new_session=True)
            except OSError as exc:
                raise SitlError(f"{self.plan.describe()} could not start: "
                                f"{exc.strerror or exc}") from None
        (self.scratch / "sitl.pid").write_text(f"{self.proc.pid}\n")
        return self

    def check(self):
        """SitlError if the process has ended."""
        if self.proc is not None and self.proc.poll() is not None:
            raise SitlError(f"{self.plan.describe()} ended (exit {self.proc.returncode}); "
                            f"its log: {self.log_path}{self.log_tail()}")

    def log_tail(self, lines=6):
        try:
            text = self.log_path.read_text(errors="replace").strip().splitlines()[-lines:]
        except OSError:
            return ""
        return "".join(f"\n    {line}" for line in text)

    def stop(self):
        if self.proc is not None:
            stop_process(self.proc)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False


# --- over MAVLink: parameters and readiness ------------------------------------------------------

class _Target:
    """What :class:`~mavadrc.mavlink.params.Params` needs to know of the vehicle."""

    def __init__(self, system, autopilot):
        self.target_system = system
        self.autopilot = autopilot


def _connect(url, deadline, sitl):
    import contextlib
    import io

    from pymavlink import mavutil

    while True:
        try:
            # quiet: pymavlink prints each refused TCP attempt on stdout
            with contextlib.redirect_stdout(io.StringIO()):
                return mavutil.mavlink_connection(url, source_system=255, source_component=190,
                                                  autoreconnect=False)
        except OSError:  # the SITL's TCP port not open yet
            sitl.check()
            if time.monotonic() > deadline:
                raise SitlError(f"{sitl.plan.describe()}: nothing listens on {url}; its log: "
                                f"{sitl.log_path}{sitl.log_tail()}") from None
            time.sleep(0.5)


class Readiness:
    """What the SITL has said about being ready to arm: the pre-arm checks (SYS_STATUS), a
    position (ArduPilot's EKF_STATUS_REPORT; LOCAL_POSITION_NED otherwise), its last words."""

    def __init__(self, plan):
        from mavadrc.mavlink.dialect import M

        self.M = M
        self.ekf = plan.autopilot == "ardupilot" and not plan.bundled
        self.prearm = self.position = False
        self.texts = []

    def see(self, msg):
        M = self.M
        kind = msg.get_type()
        if kind == "SYS_STATUS":
            self.prearm = bool(msg.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
        elif kind == "EKF_STATUS_REPORT" and self.ekf:
            self.position = bool(msg.flags & M.EKF_POS_HORIZ_ABS)
        elif kind == "LOCAL_POSITION_NED" and not self.ekf:
            self.position = True
        elif kind == "STATUSTEXT":
            self.texts = (self.texts + [msg.text])[-4:]

    @property
    def ready(self):
        return self.prearm and self.position

    def missing(self):
        what = [] if self.prearm else ["its pre-arm checks fail (SYS_STATUS)"]
        if not self.position:
            what.append("its EKF has no position (EKF_STATUS_REPORT)" if self.ekf
                        else "it reports no position (LOCAL_POSITION_NED)")
        said = f"; it said last: {' | '.join(self.texts)}" if self.texts else ""
        return " and ".join(what) + said


def prepare(sitl, params, timeout, say=None):
    """Set ``params`` ({NAME: value}) on the SITL of ``sitl`` (a started :class:`SitlProcess`),
    each read back, and wait until it can arm; SitlError after ``timeout`` s, or at once if the
    process ends.  Returns ({NAME: value read back}, [names skipped]): the bundled vehicle skips
    a parameter it does not have (the experiment's are meant for the real builds); a real SITL
    without one is a SitlError."""
    from mavadrc.errors import LinkError
    from mavadrc.mavlink.dialect import M
    from mavadrc.mavlink.params import Params

    plan = sitl.plan
    deadline = time.monotonic() + timeout
    conn = _connect(sitl.url, deadline, sitl)
    try:
        hb = None
        while hb is None:
            sitl.check()
            if time.monotonic() > deadline:
                raise SitlError(f"{plan.describe()} sent no heartbeat on {sitl.url} in "
                                f"{timeout:g} s; its log: {sitl.log_path}{sitl.log_tail()}")
            msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if msg is not None and msg.autopilot != M.MAV_AUTOPILOT_INVALID:
                hb = msg
        system = hb.get_srcSystem()
        conn.target_system, conn.target_component = system, 1
        ready = Readiness(plan)
        if plan.autopilot == "ardupilot":
            conn.mav.request_data_stream_send(system, 1, M.MAV_DATA_STREAM_ALL, 4, 1)
        for mid in (M.MAVLINK_MSG_ID_SYS_STATUS, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
            conn.mav.command_long_send(system, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid,
                                       250000, 0, 0, 0, 0, 0)

        def recv(wait):
            msg = conn.recv_match(blocking=True, timeout=wait)
            if msg is not None:
                if msg.get_type() == "PARAM_VALUE":
                    par.on_value(msg)
                ready.see(msg)

        par = Params(conn, _Target(system, plan.autopilot), recv)
        values, skipped = {}, []
        for name, value in params.items():
            try:
                current = par.read(name, timeout=6.0 if not plan.bundled else 1.5,
                                   idle=sitl.check)
            except LinkError:
                if plan.bundled:
                    skipped.append(name)
                    continue
                raise SitlError(f"{plan.describe()} did not answer for parameter {name} (has "
                                f"it one of that name?)") from None
            try:
                ptype = par.values[name].param_type
                got = par.set(name, value, ptype, timeout=6.0, idle=sitl.check)
            except LinkError:
                raise SitlError(f"{plan.describe()} did not answer for parameter {name} (has "
                                f"it one of that name?)") from None
            if abs(float(got) - float(value)) > 1e-4 * max(1.0, abs(float(value))):
                raise SitlError(f"{plan.describe()} kept {name} = {got:g} (was {current:g}) "
                                f"when set to {value:g}")
            values[name] = got
        if say is not None and values:
            say("set " + ", ".join(f"{k}={v:g}" for k, v in values.items()))
        while not ready.ready:
            sitl.check()
            if time.monotonic() > deadline:
                raise SitlError(f"{plan.describe()} could not arm after {timeout:g} s: "
                                f"{ready.missing()}; its log: {sitl.log_path}")
            recv(0.5)
        return values, skipped
    finally:
        conn.close()
