"""A companion whose console or terminal goes away, or that is asked to stop, still flies its
vehicle down: a reader of its output that quits (``| head``), an SSH session lost (SIGHUP) or a
service manager stopping it (SIGTERM) never leaves a vehicle in the air to its autopilot's
failsafe.  Flown for real on PX4 SIH: a companion whose stdout pipe closed died of the
BrokenPipeError its console raised mid-identification, wrote no summary, and PX4's failsafe
landed the vehicle and left it in OFFBOARD."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mavadrc.flight.console import Console, Guarded, Terminated, interrupt_reason
from mavadrc.flight.fly import interrupt_status
from sitl_helpers import wait_rows

MISSIONS = Path(__file__).resolve().parent.parent / "configs" / "missions"


def _closed_pipe():
    r, w = os.pipe()
    os.close(r)
    return os.fdopen(w, "w")


def test_a_stream_whose_reader_is_gone_goes_quiet_and_hands_its_text_on():
    out, said = _closed_pipe(), []
    g = Guarded(out, fallback=said.append)
    g.write("flying ladrc\n")
    g.flush()  # the pipe's reader is gone: EPIPE, raised here or at the write
    assert g.lost is not None and g.lost.startswith("BrokenPipeError")
    g.write("landed\n")
    g.flush()
    assert "".join(said).split() == ["flying", "ladrc", "landed"]
    # the descriptor now writes to the null device: what Python flushes at exit cannot fail
    assert os.write(out.fileno(), b"late") == 4
    out.close()


def test_the_console_says_to_its_fallback_once_its_stream_fails():
    said = []
    c = Console(_closed_pipe(), progress=True, fallback=said.append)
    c.say("input model identified")
    c.progress("hover", 1.0, 10.0, 0.01)  # the live line is no record: not kept
    c.vehicle("Takeoff detected")
    assert c.lost is not None
    assert "".join(said).splitlines() == ["input model identified", "  vehicle: Takeoff detected"]


def test_a_working_stream_is_written_as_it_was():
    import io
    s = io.StringIO()
    g = Guarded(s, fallback=lambda text: pytest.fail("nothing failed"))
    g.write("a\n")
    g.flush()
    assert s.getvalue() == "a\n" and g.lost is None and not g.isatty()


def test_sigterm_reads_as_a_termination_with_its_shell_status():
    exc = Terminated(signal.SIGTERM)
    assert isinstance(exc, KeyboardInterrupt) and exc.signame == "SIGTERM"
    assert interrupt_reason(exc) == "terminated by SIGTERM"
    assert interrupt_reason(KeyboardInterrupt()) == "interrupted by the user"
    assert interrupt_status({"aborted": ["terminated by SIGTERM"]}) == 143
    assert interrupt_status({"aborted": ["interrupted by the user"]}) == 130
    assert interrupt_status({"aborted": ["geofence"]}) is None


# --- end to end, the bundled vehicle in real time ------------------------------------------------

def _start(tmp_path, duration=None, stdout=subprocess.PIPE):
    text = (MISSIONS / "hover.yaml").read_text()
    if duration is not None:
        text = text.replace("duration: 5", f"duration: {duration}")
    # these flights are about signals and pipes, not the link: a machine loaded past its cores
    # (CI beside other work) once left 0.73 s between two samples and the telemetry failsafe
    # landed the vehicle early
    text += "safety: {telemetry_timeout_s: 3.0}\n"
    path = tmp_path / "m.yaml"
    path.write_text(text)
    out = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "mavadrc", "fly", str(path), "--out", str(out),
                             "--no-figures", "-q"], stdout=stdout, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    return proc, out


def _wait_rows(out, n=50, timeout=300.0):
    return wait_rows(lambda: out.glob("*/controller.csv"), n, timeout)


def _finish(proc, timeout=120):
    try:
        return proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the bundled vehicle in its group too


@pytest.mark.realtime
def test_a_flight_whose_output_pipe_closes_flies_on_and_lands(tmp_path):
    proc, out = _start(tmp_path, duration=1)
    first = proc.stdout.readline()  # a reader that quits after a line, as `| head -1` does
    proc.stdout.close()
    status = _finish(proc)
    folder = next(out.glob("*/summary.json")).parent
    summary = json.loads((folder / "summary.json").read_text())
    assert first.strip()
    assert status == 0, (folder / "companion.log").read_text()
    assert summary["landed"] and summary["disarmed"] and summary["aborted"] == []
    assert summary["console"]["lost"].startswith("BrokenPipeError")
    log = (folder / "companion.log").read_text()
    # what the console would have said is kept: the flight's closing line among it
    assert "landed" in log and "disarmed" in log and "Traceback" not in log


@pytest.mark.realtime
def test_sigterm_holds_then_lands_and_exits_as_shells_expect(tmp_path):
    proc, out = _start(tmp_path, duration=60)
    try:
        folder = _wait_rows(out)
        os.kill(proc.pid, signal.SIGTERM)  # the companion only, as `kill` or systemd send it
        output, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the bundled vehicle in its group too
    summary = json.loads((folder / "summary.json").read_text())
    said = [line for line in output.splitlines() if "hold, then land" in line]
    assert said == ["terminated by SIGTERM: hold, then land (SIGTERM again to leave the "
                    "vehicle to its autopilot)"], output
    assert summary["aborted"] == ["terminated by SIGTERM"]
    assert summary["disarmed"]  # landed and disarmed: never left to the autopilot in offboard
    assert summary["duration_s"] < 40  # cut short: not the 60 s hover flown to its end
    assert proc.returncode == 128 + signal.SIGTERM and "Traceback" not in output


@pytest.mark.realtime
def test_sighup_is_flown_through(tmp_path):
    proc, out = _start(tmp_path, duration=2)
    try:
        folder = _wait_rows(out)
        # the terminal gone: the hangup reaches the whole process group, the bundled vehicle too,
        # which must fly on with the companion (without a handler, the end of both)
        os.killpg(proc.pid, signal.SIGHUP)
        output, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the bundled vehicle in its group too
    summary = json.loads((folder / "summary.json").read_text())
    assert proc.returncode == 0, output
    assert summary["landed"] and summary["aborted"] == []
    assert summary["console"]["hung_up_at_s"] is not None and summary["console"]["lost"] is None
    assert "SIGHUP" in (folder / "companion.log").read_text()


# --- a record that cannot be written ---------------------------------------------------------------

@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux)")
def test_a_disk_that_fills_mid_flight_stops_the_record_not_the_flight(tmp_path, monkeypatch):
    """An SD card fills in the air: every file of the record then meets ENOSPC (the writers'
    files swapped for /dev/full, companion.log and summary.json made unwritable).  Before, the
    first failed row was an error in the companion, the land it set off failed on the tlog
    write of its own command, and the OSError left the vehicle to its autopilot."""
    import csv
    import io

    import mavadrc.flight.record as R
    from mavadrc.flight.fly import fly
    from mavadrc.mission.config import load_mission

    records = []
    init = R.FlightRecord.__init__

    def recording(self, *a, **k):
        init(self, *a, **k)
        records.append(self)

    row = R.TableWriter.row
    rows = [0]

    def filling(self, values):
        rows[0] += 1
        if rows[0] == 500:  # 5 s into the mission, at 100 Hz
            rec = records[-1]
            rec.table._f = open("/dev/full", "w")
            rec.table._w = csv.writer(rec.table._f)
            rec.tlog._f = open("/dev/full", "wb")
            rec.folder = Path("/dev/full/none")  # the notes and summary.json: ENOTDIR
        return row(self, values)

    monkeypatch.setattr(R.FlightRecord, "__init__", recording)
    monkeypatch.setattr(R.TableWriter, "row", filling)
    out = io.StringIO()
    summary, _ = fly(load_mission(MISSIONS / "hover.yaml"), out=tmp_path, lockstep=True,
                     progress=False, stream=out)
    said = out.getvalue()
    assert summary["landed"] and summary["disarmed"] and summary["aborted"] == []
    assert "No space left on device" in summary["record_lost"]
    assert any("the record stopped being written" in w for w in summary["warnings"])
    assert "error in the companion" not in said
    assert "summary.json could not be written" in said


# --- the hold a failsafe asks of ArduCopter -----------------------------------------------------

def _interrupted_ardupilot_flight(tmp_path, monkeypatch, at_s=4.0):
    """The bundled ArduCopter hovering at 1.5 m, interrupted (as Ctrl-C or SIGTERM are taken)
    ``at_s`` s into its mission: the failsafe holds, then lands."""
    import io

    from mavadrc.flight.fly import fly
    from mavadrc.flight.mission_step import MissionStep
    from mavadrc.mission.config import load_mission

    step = MissionStep.step
    fired = []

    def interrupting(self, s):
        start = self.progress.start
        if not fired and start is not None and s.t - start > at_s:
            fired.append(s.t)
            raise KeyboardInterrupt
        return step(self, s)

    monkeypatch.setattr(MissionStep, "step", interrupting)
    path = tmp_path / "m.yaml"
    path.write_text((MISSIONS / "ardupilot_hover.yaml").read_text()
                    .replace("duration: 5", "duration: 20"))
    out = io.StringIO()
    # in real time: in lockstep the vehicle's clock waits on the companion, which sends nothing
    # while the autopilot holds, so a hold would take no simulated time at all
    summary, folder = fly(load_mission(path), out=tmp_path, progress=False,
                          stream=out)
    assert fired
    return summary, folder, out.getvalue()


@pytest.mark.realtime
def test_an_ardupilot_failsafe_holds_in_brake_and_lands_at_its_land_speed(tmp_path, monkeypatch):
    """ArduCopter's LOITER flies the pilot's throttle stick as a climb rate: asked to hold in it,
    a vehicle with no pilot (or the stick down) sinks at the pilot's full rate; flown on
    ArduCopter SITL, it met the ground from 3 m at 2.49 m/s. The hold is BRAKE: the vehicle
    stays where it was until LAND brings it down at LAND_SPEED (0.5 m/s)."""
    from mavadrc.flight.record import read_table

    summary, folder, said = _interrupted_ardupilot_flight(tmp_path, monkeypatch)
    assert summary["aborted"] == ["interrupted by the user"] and summary["disarmed"], said
    assert "refused" not in said and "the autopilot is in LAND: watching it land" in said
    truth = read_table(folder / "truth.csv")  # the simulator's own (SIM_STATE)
    after = truth["t"] > 4.0
    assert truth["vd"][after].max() < 0.6, truth["vd"][after].max()  # LAND's 0.5 m/s, no drop


@pytest.mark.realtime
def test_a_hold_the_autopilot_refuses_is_skipped_for_its_land(tmp_path, monkeypatch):
    """ArduCopter refuses BRAKE without a position estimate (GUIDED_NOGPS flown indoors): the
    failsafe lands at once instead of asking again until its landing bound runs out."""
    import mavadrc.mavlink.sequence as S

    monkeypatch.setattr(S, "AP_BRAKE", 99)  # a mode the vehicle does not have: refused
    summary, folder, said = _interrupted_ardupilot_flight(tmp_path, monkeypatch)
    assert "the autopilot refused its hold mode: landing without it" in said
    assert summary["disarmed"] and "the autopilot is in LAND: watching it land" in said


@pytest.mark.realtime
def test_a_companion_killed_outright_takes_its_forked_vehicle_with_it(tmp_path):
    """SIGKILL leaves a companion no say; the bundled vehicle it forked (which ignores Ctrl-C
    and hangups, to be flown down) must not run on for ever with nobody to fly it."""
    psutil = pytest.importorskip("psutil")
    from mavadrc.flight.embedded import can_fork

    if not sys.platform.startswith("linux"):
        pytest.skip("the forked vehicle and its parent-death signal are Linux's")
    proc, out = _start(tmp_path, duration=60, stdout=subprocess.DEVNULL)
    try:
        _wait_rows(out)
        children = psutil.Process(proc.pid).children()
        assert children or not can_fork(), "no vehicle was forked"
        os.kill(proc.pid, signal.SIGKILL)  # the companion only
        proc.wait(timeout=10)
        gone, alive = psutil.wait_procs(children, timeout=10)
        assert not alive, [p.pid for p in alive]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for p in psutil.Process().children(recursive=True):
            if "mavadrc" in " ".join(p.cmdline()):
                p.kill()
