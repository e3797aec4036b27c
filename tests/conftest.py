"""Test-session setup shared by every test file."""

import os
import signal
import subprocess
import sys

# MAVLink 2 before any test module imports pymavlink (which picks its dialect once, on import),
# whatever order a file's imports come in
os.environ.setdefault("MAVLINK20", "1")

# The Ctrl-C tests send SIGINT to a command they started, as a terminal does.  A shell starts a
# background job (`pytest ... &` with no job control, as CI scripts often do) with SIGINT
# ignored, and an ignored signal stays ignored across exec: the command would never see the
# Ctrl-C.  A terminal's commands have SIGINT at its default, so the session restores that here
# (a handler is reset to the default in the commands it starts; an ignored signal is not).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (the README's command): one worker more than the cores this process may use.
    About half of the suite's time is real-time flights waiting on the vehicle's clock, and a
    third worker on two cores fills that wait (measured: 12.0 min against 14.2 with two, the
    cores 92 % busy).  ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still decides when set, and
    ``--maxprocesses`` still caps."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return cores + 1


#: what the controller process compiles before the workers start, two processes side by side:
#: the bundled vehicle's firmware, and the in-process closed loop with the companion's
#: controllers and the identification fit's.  numba caches them on disk; without this, on a
#: clean clone every worker compiles the same kernels at its first flight, at once (a minute of
#: both cores, three times over).
WARM_UPS = (
    "from sim.cli import warm_up; warm_up('x500', 'thesis', 'px4')",
    "import numpy as np\n"
    "from mavadrc.design.gains import make_controller\n"
    "from mavadrc.fast.fly import fly_inprocess\n"
    "from mavadrc.mission.config import load_mission\n"
    "m = load_mission('configs/missions/hover.yaml')\n"
    "fly_inprocess(m)\n"
    "for kind in ('ladrc', 'adrc', 'pd', 'pid'):\n"
    "    c = make_controller(m.controller, hover_thrust=0.5, kind=kind, vehicle='x500')\n"
    "    c.reset(np.zeros(3)); c.update(np.zeros(3), np.zeros(3), np.zeros(3))\n"
    "from mavadrc.design.identify import load_fitting\n"
    "load_fitting()\n",
)


def pytest_configure(config):
    """In the controller of a run with workers: :data:`WARM_UPS`.  One that fails costs only
    the time: the workers compile what it did not, as they would have anyway."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return
    procs = [subprocess.Popen([sys.executable, "-c", code], cwd=config.rootpath,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for code in WARM_UPS]
    for p in procs:
        try:
            _, err = p.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            p.kill()
            err = "did not finish in 600 s"
        if p.returncode:
            sys.stderr.write(f"conftest: compiling the kernels ahead failed; the workers will "
                             f"compile them ({err.strip().splitlines()[-1:]})\n")
