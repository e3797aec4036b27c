"""Test-session setup shared by every test file."""

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

# One BLAS and OpenMP thread per process: the workers (one more than the cores) and the
# vehicles and fits they start already fill the cores, and OpenBLAS's threads spin-wait after
# each call they share.  Measured on 2 cores (test_physics, test_robustness, test_identify,
# -n 2): 44 CPU-s against 50-55.  Set before numpy is first imported (here, in the controller,
# whose environment the workers and their children inherit).  numba's own threads
# (NUMBA_NUM_THREADS) are left at the cores: its parallel kernels stay tested on two threads.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

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

#: where the stamp of the last warm-up that succeeded is kept (pytest's cache, .pytest_cache/)
WARM_UP_KEY = "mavadrc/warm-up"


def warm_up_stamp(root):
    """What numba's cache of the warmed-up kernels depends on: the interpreter, numba's version
    and settings, :data:`WARM_UPS`, and every source file that mentions ``jit`` (the kernels' and
    the decorator's) by its modification time and size, as numba itself judges a cache stale.
    About 0.1 s: the files are read, no module is imported."""
    from importlib.metadata import version

    h = hashlib.sha256()
    h.update(repr((sys.executable, sys.version, version("numba"), WARM_UPS,
                   sorted((k, v) for k, v in os.environ.items() if k.startswith("NUMBA_"))))
             .encode())
    for pkg in ("mavadrc", "sim"):
        for path in sorted((root / pkg).rglob("*.py")):
            if b"jit" in path.read_bytes():
                st = path.stat()
                h.update(f"{path.relative_to(root)} {st.st_mtime_ns} {st.st_size}\n".encode())
    return h.hexdigest()


def numba_indexes(root):
    """The index files of numba's on-disk cache (beside the sources, or under
    ``NUMBA_CACHE_DIR``), relative to where they are."""
    base = Path(os.environ["NUMBA_CACHE_DIR"]) if os.environ.get("NUMBA_CACHE_DIR") else root
    dirs = [base] if base != root else [root / "mavadrc", root / "sim"]
    return base, sorted(str(p.relative_to(base)) for d in dirs for p in d.rglob("*.nbi"))


def warm_up_needed(config):
    """Whether :data:`WARM_UPS` must run: no warm-up succeeded with the kernels' sources as they
    are now, or a cache file it left has gone since.  Without pytest's cache (``-p
    no:cacheprovider``) it always runs."""
    cache = getattr(config, "cache", None)
    if cache is None:
        return True
    last = cache.get(WARM_UP_KEY, None)
    if not isinstance(last, dict) or last.get("stamp") != warm_up_stamp(config.rootpath):
        return True
    base, _ = numba_indexes(config.rootpath)
    return not last.get("indexes") or \
        not all((base / rel).exists() for rel in last["indexes"])


def pytest_configure(config):
    """In the controller of a run with workers: :data:`WARM_UPS`, unless numba's cache is known
    fresh for them (:func:`warm_up_needed`; then they would only load it, ~5 s).  One that fails
    costs only the time: the workers compile what it did not, as they would have anyway."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return
    if not warm_up_needed(config):
        return
    stamp = warm_up_stamp(config.rootpath)
    procs = [subprocess.Popen([sys.executable, "-c", code], cwd=config.rootpath,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for code in WARM_UPS]
    failed = False
    for p in procs:
        try:
            _, err = p.communicate(timeout=600)
        except subprocess.TimeoutExpired:
            p.kill()
            err = "did not finish in 600 s"
        if p.returncode:
            failed = True
            sys.stderr.write(f"conftest: compiling the kernels ahead failed; the workers will "
                             f"compile them ({err.strip().splitlines()[-1:]})\n")
    # stamped only if the sources did not change while it compiled
    if not failed and getattr(config, "cache", None) is not None \
            and warm_up_stamp(config.rootpath) == stamp:
        config.cache.set(WARM_UP_KEY, {"stamp": stamp,
                                       "indexes": numba_indexes(config.rootpath)[1]})


def pytest_collection_modifyitems(config, items):
    """A test on the wall clock or with an outside client is slow as well: the fast tier,
    ``-m "not slow"``, leaves out all three kinds."""
    for item in items:
        if item.get_closest_marker("realtime") or item.get_closest_marker("clients"):
            item.add_marker(pytest.mark.slow)
