"""Every command a newcomer tries ends in one clear line: exit 2 for a usage error (before
anything starts), 130 for Ctrl-C, never a traceback nor a silent wait."""

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mavadrc.cli.main import main
from mavadrc.flight.embedded import free_udp_port
from mavadrc.study.experiment import experiment_from_text
from mavadrc.flight.fly import fly
from mavadrc.errors import FlightError
from mavadrc.errors import LinkError
from mavadrc.mission.config import load_mission
from sim.yamlio import ConfigError

ROOT = Path(__file__).resolve().parent.parent
MISSIONS = ROOT / "configs" / "missions"


def run_cli(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    return code, [ln for ln in err.splitlines() if ln.strip()]


def one_clear_line(lines, *words):
    assert len(lines) == 1, lines
    assert lines[0].startswith("mavadrc "), lines
    assert "Traceback" not in lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("options, words", [
    (["--lockstep", "--wind", "gale"], ["gale", "no such wind"]),
    (["--lockstep", "--seed", "-1"], ["--seed -1"]),
    (["--timeout", "0"], ["--timeout 0", "positive"]),
    (["--sysid", "300"], ["--sysid 300", "1 to 255"]),
    (["--out", "README.md"], ["--out README.md", "is a file"]),
    (["--out", "README.md/runs"], ["under README.md"]),
    (["--connect", "udpin:0.0.0.0:999999"], ["--connect", "999999", "1 to 65535"]),
    (["--connect", "udpin:0.0.0.0:14540", "--lockstep"], ["--lockstep"]),
    (["--connect", "udpin:0.0.0.0:14540", "--seed", "3"], ["--seed", "--connect"]),
    (["--connect", "udpin:0.0.0.0:14540", "--wind", "calm"], ["--wind", "--connect"]),
    (["--signing-key", "/nonexistent/key"], ["--signing-key /nonexistent/key"]),
])
def test_fly_refuses_a_bad_option_in_one_line_before_starting_anything(options, words, capsys,
                                                                        monkeypatch, tmp_path):
    monkeypatch.chdir(ROOT)  # README.md is the file of the --out cases
    out = [] if "--out" in options else ["--out", str(tmp_path / "runs")]
    code, lines = run_cli(["fly", "hover", "--no-figures", "-q", *out, *options], capsys)
    assert code == 2
    one_clear_line(lines, *words)
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("vehicle, words", [
    ("{mass: 2.0, max_thrust: 34}", ["mass and max_thrust", "--connect", "configs/vehicles"]),
    ("{hover_thrust: 0.6}", ["hover_thrust", "--connect"]),
])
def test_a_real_vehicles_description_is_refused_for_the_bundled_vehicle(vehicle, words, capsys,
                                                                         tmp_path):
    """The bundled vehicle would fly the Crazyflie whatever mass and thrust the mission gave."""
    path = tmp_path / "m.yaml"
    path.write_text((MISSIONS / "hover.yaml").read_text().replace("vehicle: crazyflie",
                                                                  f"vehicle: {vehicle}"))
    assert f"vehicle: {vehicle}" in path.read_text()
    code, lines = run_cli(["fly", str(path), "--lockstep", "--out", str(tmp_path / "runs")],
                          capsys)
    assert code == 2
    one_clear_line(lines, *words)
    assert not (tmp_path / "runs").exists()


def test_a_vehicle_that_dies_at_start_is_reported_at_once_with_its_words(tmp_path):
    mission = load_mission(MISSIONS / "hover.yaml")
    mission.autopilot = "nope"  # the vehicle's own argument check refuses it and exits
    t0 = time.monotonic()
    with pytest.raises(FlightError) as err:
        fly(mission, out=tmp_path, lockstep=True, progress=False,
            stream=io.StringIO())
    assert time.monotonic() - t0 < 30.0  # not the 120 s heartbeat wait (compiling included)
    msg = str(err.value)
    assert "exited" in msg and "invalid choice: 'nope'" in msg and "vehicle.log" in msg, msg
    assert "File " not in msg  # the error line, not a traceback's frames
    (folder,) = tmp_path.iterdir()  # kept: its vehicle.log says why
    assert (folder / "vehicle.log").exists()
    summary = json.loads((folder / "summary.json").read_text())
    assert "invalid choice" in summary["aborted"][0]


def test_a_connect_that_hears_nothing_leaves_no_record_folder(tmp_path):
    mission = load_mission(MISSIONS / "hover.yaml")
    out = io.StringIO()
    with pytest.raises(LinkError, match="no heartbeat"):
        fly(mission, connect=f"udpin:127.0.0.1:{free_udp_port()}", out=tmp_path, timeout=1.5,
            progress=False, stream=out)
    assert list(tmp_path.iterdir()) == []
    assert "waiting for an autopilot's heartbeat on udpin:127.0.0.1:" in out.getvalue()


def test_a_tcp_link_with_nobody_there_is_one_line_naming_its_tries(capsys, tmp_path):
    """pymavlink prints "[Errno 111] Connection refused sleeping" on every refused try; the
    user reads one line with the address, the reason and the tries instead."""
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = main(["fly", str(MISSIONS / "hover.yaml"), "--connect", f"tcp:127.0.0.1:{port}",
                 "--no-figures", "-q", "--out", str(tmp_path / "runs")])
    out, err = capsys.readouterr()
    assert code == 1 and list(tmp_path.glob("runs/*")) == []  # no record folder
    assert "sleeping" not in out + err and "Errno" not in out
    assert err.strip().splitlines()[-1] == (
        f"mavadrc fly: cannot open tcp:127.0.0.1:{port}: [Errno 111] Connection refused "
        "(3 tries, 1 s apart)")


@pytest.mark.parametrize("argv, said", [
    (["fly", "hover.yml"], "mavadrc fly: hover.yml: no such file; did you mean "
                           "'configs/missions/hover.yaml'?"),
    (["fly", "configs/missions/hovr.yaml"], "mavadrc fly: configs/missions/hovr.yaml: no such "
                                            "file; did you mean 'configs/missions/hover.yaml'?"),
    (["fly", "hovr"], "did you mean 'hover'?"),
    (["compare", "thesis.yml"], "mavadrc compare: thesis.yml: no such file; did you mean "
                                "'configs/experiments/thesis.yaml'?"),
    (["fly", "hover", "--wind", "moderate_gust.yaml"], "did you mean 'moderate_gusts'?"),
])
def test_a_missing_mission_or_experiment_says_the_one_meant_and_exits_2(argv, said, capsys,
                                                                        monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0], err


@pytest.mark.parametrize("argv, said", [
    (["sitl", "--count", "0"], "mavadrc sitl: --count must be at least 1 (got 0)"),
    (["sitl", "--param", "FOO"], "mavadrc sitl: --param must be NAME=VALUE (got 'FOO')"),
    (["sitl", "--wander", "3"], "mavadrc sitl: --wander must be 0 to 1 m (got 3.0)"),
])
def test_sitl_refuses_a_bad_option_in_one_line_with_exit_2_as_every_command(argv, said, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(said), err


def interrupt_when(args, marker, stream="stderr", within=120.0, path=()):
    """Run ``python -m mavadrc ARGS`` in a session of its own, send Ctrl-C (SIGINT to the whole
    group, as a terminal does) once a line of ``stream`` contains ``marker``; returns (exit
    status, stdout, stderr, the marker's line).  ``path``: folders put on PYTHONPATH after the
    project's."""
    proc = subprocess.Popen([sys.executable, "-m", "mavadrc", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=ROOT,
                            env={**os.environ,
                                 "PYTHONPATH": os.pathsep.join([str(ROOT), *map(str, path)])})
    try:
        t0 = time.monotonic()
        line = ""
        while marker not in line:
            line = getattr(proc, stream).readline()
            assert line and time.monotonic() - t0 < within, f"no line with {marker!r}"
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, out, err, line


def test_ctrl_c_while_waiting_for_a_heartbeat_is_one_line_and_exit_130(tmp_path):
    port = free_udp_port()
    # the wait is said at once, with the address waited on
    code, out, err, line = interrupt_when(
        ["fly", "hover", "--connect", f"udpin:127.0.0.1:{port}", "--out", str(tmp_path / "runs")],
        "waiting for an autopilot's heartbeat", stream="stdout", within=60.0)
    assert f"udpin:127.0.0.1:{port}" in line
    assert code == 130
    lines = [ln for ln in err.splitlines() if ln.strip()]
    one_clear_line(lines, "interrupted", f"udpin:127.0.0.1:{port}", "nothing flew")
    assert "Traceback" not in out + err and "nan" not in out
    assert not any((tmp_path / "runs").glob("*/*"))  # nothing flew: no record kept


# --- mavadrc compare ------------------------------------------------------------------------------

TINY = ROOT / "tests" / "data" / "tiny_experiment.yaml"


@pytest.mark.parametrize("options, words", [
    (["--seeds", "0"], ["--seeds 0", "at least 1"]),
    (["--workers", "0"], ["--workers 0", "at least 1"]),
    (["--out", "README.md"], ["--out README.md", "is a file"]),
])
def test_compare_refuses_a_bad_option_in_one_line(options, words, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    code, lines = run_cli(["compare", str(TINY), "-q", *options], capsys)
    assert code == 2
    one_clear_line(lines, *words)


def test_compare_on_a_cluster_without_dask_says_what_to_install(capsys, monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
    code, lines = run_cli(["compare", str(TINY), "-q", "--out", str(tmp_path / "c"),
                           "--scheduler", "tcp://127.0.0.1:8786"], capsys)
    assert code == 2
    one_clear_line(lines, "distributed", '.[cluster]')
    assert not (tmp_path / "c").exists()


def test_compare_says_it_writes_the_report_after_the_last_run(capsys, tmp_path):
    assert main(["compare", str(TINY), "--out", str(tmp_path), "--seeds", "1",
                 "--no-figures"]) == 0
    err = capsys.readouterr().err
    bar_end = err.index("6/6 runs")
    assert "writing the report" in err[bar_end:]
    assert "tiny: 2 scenarios x 3 controllers x 1 seed\n" in err  # not "1 seeds"


def test_progress_is_a_tqdm_bar_on_a_terminal_and_plain_lines_elsewhere():
    from mavadrc.flight.console import Steps

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty = Terminal()
    steps = Steps(4, "run", out=tty, desc="tiny")
    for _ in range(4):
        steps.step()
    text = tty.getvalue()
    assert "\r" in text and "4/4" in text and "100%" in text and "tiny" in text  # tqdm's bar
    pipe = io.StringIO()
    steps = Steps(4, "run", out=pipe, every=1e9)
    for _ in range(4):
        steps.step()
    assert pipe.getvalue() == pipe.getvalue().replace("\r", "")
    assert pipe.getvalue().splitlines()[-1].startswith("4/4 runs, ")  # the last always said


def test_the_flights_live_line_is_a_tqdm_bar_on_a_terminal_that_gives_way_to_messages():
    from mavadrc.flight.console import Console

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty = Terminal()
    c = Console(tty)
    c.progress("hover", 5.0, 20.0, 0.012, link=lambda: "100 Hz, lost 0.0 %")
    drawn = tty.getvalue()
    assert "hover" in drawn and "t    5.0/20 s" in drawn and "error  0.012 m" in drawn
    assert "100 Hz, lost 0.0 %" in drawn and "left" in drawn and "|" in drawn  # tqdm's bar
    c.say("land segment done")
    after = tty.getvalue()[len(drawn):]
    assert after.endswith("land segment done\n") and after.startswith("\r")  # cleared first
    c.close()
    # off a terminal: a plain line, no carriage return, no tqdm
    pipe = io.StringIO()
    Console(pipe).progress("hover", 5.0, 20.0, 0.012)
    assert "\r" not in pipe.getvalue() and "[#####---------------]" in pipe.getvalue()


def test_compare_names_the_runs_it_copied_only_when_there_are_some():
    from mavadrc.study.compare import runs_line

    assert runs_line(8, 8, 4.0) == "8 runs in 4.0 s (2.0 runs/s)"  # no "rest" to speak of
    assert runs_line(105, 41, 14.0) == ("105 runs in 14.0 s (7.5 runs/s; 41 flown, 2.9/s, the "
                                        "other 64 copied from a seed-independent run)")
    assert runs_line(1, 1, 0.0) == "1 run in 0.0 s (- runs/s)"


@pytest.mark.slow
def test_ctrl_c_during_compare_stops_the_workers_in_one_line(tmp_path):
    """The one line and nothing after it, with the pool's race at exit widened so it is hit
    every time (``tests/data/pool_exit_race``): the exit waits for the pool's manager."""
    text = TINY.read_text()
    # the progress bar: the workers are running
    code, out, err, _ = interrupt_when(["compare", str(TINY), "--seeds", "200", "--workers", "2",
                                        "--out", str(tmp_path / "c")], " runs, ",
                                       path=[ROOT / "tests" / "data" / "pool_exit_race"])
    assert code == 130
    lines = [ln for ln in err.splitlines() if ln.strip() and " runs, " not in ln]
    one_clear_line(lines, "interrupted", "workers")
    assert "Traceback" not in out + err
    assert text  # the experiment is the shipped tiny one, untouched


@pytest.mark.slow
def test_ctrl_c_during_tune_ends_in_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "tuned.yaml"
    # a generation line: the search is running in its workers
    code, _, err, _ = interrupt_when(["tune", str(TINY), "--controller", "PD", "--workers", "2",
                                      "--maxiter", "50", "--out", str(out)], "generation",
                                     within=180.0,
                                     path=[ROOT / "tests" / "data" / "pool_exit_race"])
    assert code == 130
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()


def test_a_long_wait_is_never_silent_and_a_short_one_says_nothing():
    from mavadrc.flight.console import ticking

    said = []
    with ticking(said.append, "still compiling", every=0.05):
        time.sleep(0.18)
    n = len(said)
    assert 2 <= n <= 4 and all(s.startswith("still compiling (") and s.endswith(" s)")
                               for s in said), said
    time.sleep(0.12)
    assert len(said) == n  # nothing after the wait ended
    with ticking(said.append, "quick", every=5.0):
        pass
    with ticking(said.append, "not asked", every=0.01, enabled=False):
        time.sleep(0.05)
    assert len(said) == n


def test_a_compile_is_announced_only_when_numba_has_not_cached_the_kernel(tmp_path, monkeypatch):
    from mavadrc.control.jit import needs_compiling

    (tmp_path / "fresh_kernel_mod.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef twice(x):\n    return 2.0 * x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import fresh_kernel_mod as mod

    assert needs_compiling(mod.twice)  # never compiled, nothing on disk
    assert mod.twice(1.5) == 3.0
    assert not needs_compiling(mod.twice)  # compiled in this process
    mod.twice.overloads.clear()
    assert not needs_compiling(mod.twice)  # and in numba's on-disk cache


# --- configuration files --------------------------------------------------------------------------

def valid_keys(message):
    """The keys a refusal lists after 'valid keys here:'."""
    return set(message.split("valid keys here: ", 1)[1].rstrip(")").split(", "))


HOVER = (MISSIONS / "hover.yaml").read_text()
TAKEOFF_KEYS = {"altitude", "speed", "yaw_deg", "join"}
MISSION_KEYS = {"name", "vehicle", "controller", "trajectory", "wind", "sim", "safety", "logging",
                "transit_speed", "transit_accel"}


@pytest.mark.parametrize("old, new, line, field, meant, listed", [
    ("rate_hz: 100", "rate_hz: 100\n  w0: 5", 7, "controller.w0", "wo",
     {"wo", "wc", "b0", "kp_pos", "ki_vel", "input_lag", "eso_gains", "type", "rate_hz"}),
    ("controller:", "contoller:", 4, "contoller", "controller", MISSION_KEYS),
    ("speed: 0.5}", "sped: 0.5}", 8, "trajectory[0].takeoff.sped", "speed", TAKEOFF_KEYS),
])
def test_a_misspelt_key_lists_every_valid_key_and_the_closest(old, new, line, field, meant,
                                                               listed, tmp_path, capsys):
    path = tmp_path / "typo.yaml"
    path.write_text(HOVER.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {field}: unknown key; did you mean '{meant}'?"), msg
    keys = valid_keys(msg)
    assert listed <= keys, listed - keys
    if listed in (MISSION_KEYS, TAKEOFF_KEYS):
        assert keys == listed
    code, lines = run_cli(["fly", str(path), "--lockstep", "--out", str(tmp_path / "runs")],
                          capsys)
    assert code == 2
    one_clear_line(lines, f"did you mean '{meant}'")


def test_a_misspelt_required_key_points_at_the_misspelling(tmp_path):
    path = tmp_path / "typo.yaml"
    path.write_text(HOVER.replace("altitude: 1.0", "altitud: 1.0"))
    with pytest.raises(ConfigError, match=rf"{path}:8: trajectory\[0\].takeoff.altitude: required "
                                          "field missing; is 'altitud' a misspelling of it"):
        load_mission(path)


def test_a_misspelt_choice_or_segment_is_named_and_the_case_of_a_kind_does_not_matter(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(HOVER.replace("type: ladrc", "type: LADRC"))
    assert load_mission(path).controller.kind == "ladrc"
    path.write_text(HOVER.replace("type: ladrc", "type: ladcr"))
    with pytest.raises(ConfigError, match=r"must be one of adrc, ladrc, pd, pid, native \(got 'ladcr'; "
                                          r"did you mean 'ladrc'\?\)"):
        load_mission(path)
    path.write_text(HOVER.replace("- takeoff:", "- takof:"))
    with pytest.raises(ConfigError, match=r"trajectory\[0\].takof: .*did you mean 'takeoff'"):
        load_mission(path)


def test_a_misspelt_shipped_name_is_named_with_the_closest(capsys):
    code, lines = run_cli(["compare", "thesys", "-q"], capsys)
    assert code == 2
    shipped = ", ".join(sorted(p.stem for p in (ROOT / "configs" / "experiments").glob("*.yaml")))
    one_clear_line(lines, f"thesys: no such experiments config (shipped: {shipped}; did you mean "
                          "'thesis'?)")


def test_a_misspelt_vehicle_key_is_named_with_the_closest(tmp_path):
    from sim.params import load_vehicle

    path = tmp_path / "v.yaml"
    text = (ROOT / "configs" / "vehicles" / "crazyflie.yaml").read_text()
    path.write_text(text.replace("\nrotor_drag:", "\nrotor_dragg:"))
    with pytest.raises(ConfigError) as err:
        load_vehicle(path)
    assert "rotor_dragg: unknown key; did you mean 'rotor_drag'?" in str(err.value)
    assert {"rotor_drag", "k_m", "motor_thrust_curve"} <= valid_keys(str(err.value))


def test_a_misspelt_default_of_an_experiment_is_named_in_its_defaults(tmp_path, capsys):
    path = tmp_path / "typo.yaml"
    text = TINY.read_text()
    path.write_text(text.replace("  settle_s: 4", "  setle_s: 4"))
    with pytest.raises(ConfigError) as err:
        experiment_from_text(str(path), path.read_text())
    msg = str(err.value)
    assert msg.startswith(f"{path}:6: defaults.setle_s: unknown key; did you mean 'settle_s'?")
    assert {"settle_s", "group", "trajectory", "wind", "safety"} <= valid_keys(msg)
    path.write_text(text.replace("  settle_s: 4", "  settle_s: -4"))
    with pytest.raises(ConfigError, match=f"{path}:6: defaults.settle_s: must be >= 0"):
        experiment_from_text(str(path), path.read_text())
    code, lines = run_cli(["compare", str(path), "-q", "--out", str(tmp_path / "c")], capsys)
    assert code == 2
    one_clear_line(lines, "defaults.settle_s")


@pytest.mark.parametrize("text, where", [
    ("- takeoff: {altitude: 1}\n", ":1: (top level): must be a mapping (got a list)"),
    ("just words\n", ": (top level): must be a mapping (got the text 'just words')"),
    (HOVER.replace("controller:\n  type: ladrc\n  rate_hz: 100\n", "controller: [ladrc]\n"),
     ":4: controller: must be a mapping (got a list)"),
    (HOVER.replace("- hover: {duration: 5}", "- hover"), ":9: trajectory[1]: must be a mapping "
                                                         "(got the text 'hover')"),
    (HOVER.replace("name: hover", "name: hover\nwind: [1, 2]"),
     ":3: wind: must be a wind name, a file or a mapping (got a list)"),
])
def test_a_list_or_a_scalar_where_a_mapping_belongs_is_said_in_words(text, where, tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    assert str(err.value) == f"{path}{where}"


# --- the vehicle's words --------------------------------------------------------------------------

@pytest.mark.parametrize("autopilot, custom_mode, name", [
    ("px4", 0x3040000, "AUTO.LOITER"), ("px4", 0x6040000, "AUTO.LAND"),
    ("px4", 0x2040000, "AUTO.TAKEOFF"), ("px4", 0x5040000, "AUTO.RTL"),
    ("px4", 6 << 16, "OFFBOARD"), ("px4", 3 << 16, "POSCTL"), ("px4", 2 << 16, "ALTCTL"),
    ("px4", 0x63040000, "custom_mode 0x63040000"),
    ("ardupilot", 4, "GUIDED"), ("ardupilot", 20, "GUIDED_NOGPS"), ("ardupilot", 9, "LAND"),
    ("ardupilot", 5, "LOITER"), ("ardupilot", 6, "RTL"), ("ardupilot", 0, "STABILIZE"),
    ("ardupilot", 99, "custom_mode 99"), (None, 0x3040000, "custom_mode 0x3040000"),
])
def test_flight_modes_are_named_as_the_autopilot_names_them(autopilot, custom_mode, name):
    from mavadrc.mavlink.sequence import mode_name, sequence_for

    assert mode_name(autopilot, custom_mode) == name
    if autopilot is not None:
        assert sequence_for(autopilot).mode_name(custom_mode) == name


# --- controller names in either case --------------------------------------------------------------

def test_a_controller_is_named_in_either_case_and_a_wrong_name_lists_the_choices(capsys,
                                                                                 tmp_path):
    from mavadrc.cli.main import build_parser

    for spelt in ("LADRC", "ladrc", "Ladrc"):
        assert build_parser().parse_args(["fly", "hover", "--controller", spelt]).controller \
            == "ladrc"
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["fly", "hover", "--controller", "lqr"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'lqr'" in err and "'adrc', 'ladrc', 'pd', 'pid'" in err
    # tune names the experiment's controllers; a wrong name is refused before any search
    code, lines = run_cli(["tune", str(TINY), "--controller", "LADCR", "--workers", "1",
                           "--out", str(tmp_path / "t.yaml")], capsys)
    assert code == 2
    one_clear_line(lines, "--controller LADCR", "PD, LADRC, oracle", "did you mean 'LADRC'")
    # an experiment's goals name its controllers in either case too
    text = TINY.read_text().replace("controllers: [LADRC], metric", "controllers: [ladrc], metric")
    text = text.replace("ratio_to: PD", "ratio_to: pd")
    exp = experiment_from_text(str(tmp_path / "e.yaml"), text)
    assert [(g["controllers"], g["ratio_to"]) for g in exp.goals] == [
        (["LADRC"], "PD"), (["PD"], None), (["LADRC"], "PD")]


# --- help and progress ----------------------------------------------------------------------------

def test_every_command_has_a_description_and_the_top_names_every_controller():
    from argparse import _SubParsersAction

    from mavadrc.cli.main import build_parser

    parser = build_parser()
    assert "(ADRC, LADRC, PD, PID)" in parser.format_help()
    (sub,) = [a for a in parser._actions if isinstance(a, _SubParsersAction)]
    for name, command in sub.choices.items():
        assert command.description and len(command.description) > 20, name
    assert "14540" in sub.choices["sitl"].description


def test_the_progress_line_keeps_a_long_segment_name_whole():
    from mavadrc.flight.console import Console, counted

    out = io.StringIO()
    Console(out).progress("transit to thesis_spiral", 3.0, 60.0, 0.25)
    assert out.getvalue().startswith("transit to thesis_spiral t    3.0/60 s")
    out = io.StringIO()
    Console(out).progress("hover", 3.0, 60.0, 0.25)
    assert out.getvalue().startswith("hover              t    3.0/60 s")  # columns kept
    assert (counted(1, "seed"), counted(2, "seed"), counted(0, "run")) == ("1 seed", "2 seeds",
                                                                           "0 runs")


def test_max_tracking_error_is_read_and_a_bad_one_names_its_line(tmp_path):
    """safety.max_tracking_error: 2 m by default, 0 turns the check off, a negative one is named
    with its file, line and field."""
    path = tmp_path / "m.yaml"
    path.write_text(HOVER)
    assert load_mission(path).safety.max_tracking_error == 2.0
    line = len(HOVER.rstrip("\n").splitlines()) + 2
    for value, expect in (("0", 0.0), ("3.5", 3.5)):
        path.write_text(HOVER.rstrip("\n") + f"\nsafety:\n  max_tracking_error: {value}\n")
        assert load_mission(path).safety.max_tracking_error == expect
    path.write_text(HOVER.rstrip("\n") + "\nsafety:\n  max_tracking_error: -1\n")
    with pytest.raises(ConfigError, match=rf"{path}:{line}: safety.max_tracking_error"):
        load_mission(path)
