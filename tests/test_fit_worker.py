"""What stopped a real-time flight's loop: the input model's fit, now in its own process
(mavadrc.design.fitworker); the heap, now frozen for the loop (mavadrc.flight.flight._freeze_heap); a kernel
compiled at the mission's first sample, now run before the flight (mavadrc.design.gains.run_once).

On PX4 SIH the fit made in a thread beside the loop held the interpreter, and the samples' age
rose to 0.2-0.4 s as it ended, a moment before the spiral began; a full collection of the heap
stopped the loop for ~0.1 s.  What is tested here: the calls run in another process and return
the same result; a process that dies leaves the call to the calling thread; the mission's
controller made in the process is the one made here (pickled whole: gains, input model, drag,
margins); a flight leaves the heap unfrozen and the process stopped.
"""

import gc
import os

import numpy as np
import pytest

from mavadrc.design import identify as I

from mavadrc.fast import identify as FI
from mavadrc.design.fitworker import FitWorker
from mavadrc.design.gains import fit_and_make
from mavadrc.mission.config import load_mission


@pytest.fixture
def worker():
    w = FitWorker()
    yield w
    w.close()


def test_a_call_is_made_in_the_workers_own_process(worker):
    assert worker.where == "process" and worker.why_not is None
    assert worker.call(os.getpid) != os.getpid()
    assert worker.call(divmod, 17, 5) == (3, 2)
    # an exception of the call's own comes back as it is, and the process stays
    with pytest.raises(ZeroDivisionError):
        worker.call(divmod, 1, 0)
    assert worker.where == "process" and worker.call(os.getpid) != os.getpid()


def test_a_worker_process_that_dies_leaves_the_call_to_the_calling_thread(worker):
    assert worker.call(os.getpid) != os.getpid()
    worker._proc.kill()
    worker._proc.wait()
    assert worker.call(divmod, 17, 5) == (3, 2)  # made here
    assert worker.where == "thread" and worker.why_not
    assert worker.call(os.getpid) == os.getpid()


def test_the_worker_never_runs_the_callers_script_again(tmp_path):
    """A script that makes a worker without a __main__ guard: it runs once (multiprocessing's
    spawn would import it again in the child, flights and all)."""
    import subprocess
    import sys

    runs = tmp_path / "runs.txt"
    script = tmp_path / "script.py"
    script.write_text(f"""import os
from mavadrc.design.fitworker import FitWorker
with open({str(runs)!r}, "a") as f:
    f.write("run\\n")
w = FitWorker()
print(w.where, w.call(os.getpid) != os.getpid())
w.close()
""")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120, cwd=os.getcwd(),
                         env=dict(os.environ, PYTHONPATH=os.getcwd()))
    assert out.stdout.split() == ["process", "True"], out.stderr
    assert runs.read_text().splitlines() == ["run"]


@pytest.mark.slow
def test_the_controller_made_in_the_process_is_the_one_made_here(worker):
    """The doublets of thesis_spiral_wind on the bundled Crazyflie, fitted and the mission's
    LADRC made with the model: in the worker and here, the same fit, gains, margins and
    controller (its next command from the same samples)."""
    m = load_mission("configs/missions/thesis_spiral_wind.yaml")
    d, windows = FI.samples_inprocess(FI.identification_mission(m, calm=True), seed=0)
    job = (d, windows, "in a test", m.controller, "ladrc", 100.0, 0.47, FI.design_lag(m))
    rec_h, ctrl_h, gains_h, margin_h = fit_and_make(*job)
    rec_p, ctrl_p, gains_p, margin_p = worker.call(fit_and_make, *job)
    assert worker.where == "process"
    assert rec_h["input_lag"] == rec_p["input_lag"]
    assert rec_h["delay_margin_s"] == rec_p["delay_margin_s"]
    assert gains_h.keys() == gains_p.keys()
    for k in gains_h:
        assert np.array_equal(np.asarray(gains_h[k]), np.asarray(gains_p[k])), k
    assert margin_h == margin_p and margin_p > 0.0
    # the identified model is the bundled vehicle's (the identification's own test: 15 %)
    assert 0.05 < rec_p["input_lag"][0] < 0.3
    for c in (ctrl_h, ctrl_p):
        c.reset(np.array([0.1, -0.2, -1.0]))
    pos, vel, ref = np.array([0.12, -0.25, -1.02]), np.array([0.3, 0.1, 0.0]), \
        np.array([0.0, 0.0, -1.0])
    for _ in range(20):
        a_h = ctrl_h.update(pos, vel, ref)
        a_p = ctrl_p.update(pos, vel, ref)
        assert np.array_equal(np.asarray(a_h[0]), np.asarray(a_p[0]))
        assert a_h[1] == a_p[1]


@pytest.mark.slow
def test_a_flight_freezes_the_heap_for_its_loop_and_unfreezes_it_after(tmp_path, monkeypatch):
    """A lockstep hover over MAVLink: the loop runs with the heap frozen (so a collection
    walks only what the flight made), and the flight leaves it unfrozen."""
    import mavadrc.flight.flight as F
    from mavadrc.cli.main import main

    frozen = []
    loop = F.Flight._loop

    def watched(self):
        frozen.append(gc.get_freeze_count())
        return loop(self)

    monkeypatch.setattr(F.Flight, "_loop", watched)
    assert gc.get_freeze_count() == 0
    assert main(["fly", "configs/missions/hover.yaml", "--lockstep", "--out", str(tmp_path),
                 "--no-figures", "-q"]) == 0
    assert frozen and frozen[0] > 10000
    assert gc.get_freeze_count() == 0


def test_a_heap_the_caller_froze_is_left_to_the_caller():
    from mavadrc.flight.flight import _freeze_heap

    gc.freeze()
    try:
        n = gc.get_freeze_count()
        made_after = [[i] for i in range(5000)]
        # Frozen objects that die leave the count (another thread may free some meanwhile),
        # so it may fall; a second freeze would raise it by the 5000 lists made after.
        assert _freeze_heap() is False and 0 < gc.get_freeze_count() <= n
        assert len(made_after) == 5000
    finally:
        gc.unfreeze()
    assert _freeze_heap() is True and gc.get_freeze_count() > 0
    gc.unfreeze()


def test_a_controller_built_for_flight_has_every_kernel_the_record_reads_ready():
    """The record reads ADRC's TD outputs each step through their own kernel; built for a
    flight (Flight._build, the fit's controller), the controller has run it already, so the
    mission's first sample does not compile it (on PX4 SIH that answered 28 samples up to
    0.32 s late).  In a fresh interpreter: not run before, run after."""
    import subprocess
    import sys

    code = ("from mavadrc.control import kernels as K\n"
            "from mavadrc.design.gains import built, run_once\n"
            "from mavadrc.mission.config import ControllerSpec\n"
            "ready = lambda: bool(getattr(K.td_output, 'signatures', [True]))\n"
            "before = ready()\n"
            "ctrl, _ = built(ControllerSpec(kind='adrc', rate_hz=100.0), 0.5, 'adrc', 100.0,"
            " None)\n"
            "run_once(ctrl)\n"
            "print(before, ready())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, env=dict(os.environ, PYTHONPATH=os.getcwd()))
    assert out.stdout.split() == ["False", "True"], out.stderr[-2000:]
