"""`mavadrc compare --sitl`: each run against a fresh SITL process, flown by `mavadrc fly
--connect`, scored by the estimate and by the truth, the SITL stopped whatever happens, the
results folder resumable.  The flights run against the bundled vehicle as `mavadrc sitl` (no
test needs a PX4 or ArduPilot build); the readiness and stopping tests against a stand-in
process that speaks only heartbeats, or nothing."""

import io
import json
import os
import sys
import textwrap
from pathlib import Path

import pytest

from mavadrc.study import sitl_launch, sitl_runs
from mavadrc.study.experiment import experiment_from_text, load_experiment
from mavadrc.study.sitl_config import (
    SitlConfigError,
    autopilot_wind,
    flight_altitude,
    parse_sitl_options,
    scenario_autopilot,
)
from mavadrc.study.sitl_launch import SitlError, SitlPlan, SitlProcess

TINY = textwrap.dedent("""\
    name: tiny sitl
    seeds: 1
    defaults:
      vehicle: crazyflie
      settle_s: 3
      safety: {geofence: {north: [-10, 10], east: [-10, 10]}}
    controllers:
      - {name: PD, type: pd, rate_hz: 50, wc: [2.5, 2.5, 3.0]}
      - {name: LADRC, type: ladrc, rate_hz: 50, wc: [2.5, 2.5, 3.0], wo: [15, 15, 15]}
    scenarios:
      - name: hover
        trajectory:
          - takeoff: {altitude: 1.0, speed: 1.0}
          - hover: {duration: 3}
    """)


def tiny(tmp_path, text=TINY):
    path = tmp_path / "tiny.yaml"
    path.write_text(text)
    return path


def gone(pid):
    """Whether process ``pid`` has ended (and been reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


# --- plans, without any process ------------------------------------------------------------------

def test_the_shipped_experiment_tags_each_scenario_with_an_autopilot_that_can_fly_its_wind():
    exp = load_experiment("real_autopilots")
    aps = {sc.sitl["autopilot"] for sc in exp.scenarios}
    assert aps == {"px4", "ardupilot"}
    assert [c.kind for c in exp.controllers] == ["pd", "pid", "adrc", "ladrc", "native"]
    assert exp.seeds == [0, 1, 2]
    winds = set()
    for sc in exp.scenarios:  # every wind maps onto its autopilot's parameters (PX4: calm)
        p = autopilot_wind(sc.sitl["autopilot"], sc.mission.wind, flight_altitude(sc.mission))
        if sc.sitl["autopilot"] == "ardupilot":
            assert p["SIM_WIND_T"] == 1.0
            winds.add((p["SIM_WIND_SPD"], round(p["SIM_WIND_TURB"], 1)))
        else:
            assert p == {}
    assert winds == {(w, t) for w in (0.0, 4.2, 8.5, 12.0) for t in (0.0, 2.0)}
    assert exp.sitl["px4"]["params"] == {}  # factory settings (the file says why)


def test_a_wind_the_autopilot_cannot_model_is_refused_with_why():
    gust = {"components": [{"type": "constant", "speed": 4, "direction_from_deg": 270},
                           {"type": "gust", "amplitude": 3, "t_start": 8, "t_rise": 1}]}
    with pytest.raises(ValueError, match="mean wind and turbulence only, not gust"):
        autopilot_wind("ardupilot", gust, 3.0)
    with pytest.raises(ValueError, match="PX4 SIH has no wind model"):
        autopilot_wind("px4", "breeze_1ms", 3.0)
    assert autopilot_wind("px4", "calm", 3.0) == {}
    assert autopilot_wind("px4", "breeze_1ms", 3.0, bundled=True) == {}  # it flies it itself
    sqrt = {"type": "constant", "speed": 5, "direction_from_deg": 90, "profile": "sqrt60"}
    assert autopilot_wind("ardupilot", sqrt, 3.0) == {
        "SIM_WIND_SPD": 5.0, "SIM_WIND_DIR": 90.0, "SIM_WIND_TURB": 0.0, "SIM_WIND_T": 0.0}


def test_sitl_options_name_the_builds_and_the_scenarios_their_autopilot():
    section = {"px4": {"path": None, "params": {"EKF2_HGT_REF": 2.0}}}
    given = parse_sitl_options(["px4=/opt/px4", "bundled=ardupilot"], section)
    assert given == {"px4": {"path": "/opt/px4", "params": {"EKF2_HGT_REF": 2.0}},
                     "ardupilot": {"path": "bundled", "params": {}}}
    assert set(parse_sitl_options(["bundled"])) == {"px4", "ardupilot"}
    for bad in (["px4"], ["inav=/x"], ["bundled=inav"]):
        with pytest.raises(SitlConfigError, match="--sitl"):
            parse_sitl_options(bad)
    with pytest.raises(SitlConfigError, match="no SITL to fly"):
        parse_sitl_options([], section)
    untagged = {"autopilot": None, "frame": "quad", "params": {}}
    assert scenario_autopilot("a", untagged, {"px4": {}}) == "px4"
    assert scenario_autopilot("a", dict(untagged, autopilot="ardupilot"), {"px4": {}}) is None
    with pytest.raises(SitlConfigError, match="names no autopilot"):
        scenario_autopilot("a", untagged, {"px4": {}, "ardupilot": {}})


def test_a_run_flies_the_scenario_with_its_controller_and_lands(tmp_path):
    exp = load_experiment(tiny(tmp_path))
    doc = sitl_runs.mission_doc(exp, 0, 1)
    assert doc["controller"]["type"] == "ladrc" and doc["logging"] == {"settle_s": 3.0}
    assert list(doc["trajectory"][-1]) == ["land"]
    assert "wind" not in doc and "sim" not in doc
    given = {"path": "/opt/ardupilot", "params": {"SIM_SPEEDUP": 1}}
    plan = sitl_runs.sitl_plan(exp, 0, 1, 0, "ardupilot", given, tmp_path / "run")
    assert plan.params["GUID_OPTIONS"] == 8 and plan.params["SIM_SPEEDUP"] == 1
    assert plan.params["SIM_WIND_SPD"] == 0.0 and plan.params["SIM_WIND_T"] == 1.0


def test_a_missing_build_is_said_before_anything_runs(tmp_path):
    for ap, what in (("px4", "no PX4 SITL build"), ("ardupilot", "no ArduCopter SITL build")):
        with pytest.raises(SitlError, match=what):
            SitlProcess(SitlPlan(ap, str(tmp_path / "nothing")), tmp_path / ap).start()


def test_an_unflyable_scenario_is_refused_before_any_sitl_starts(tmp_path, capsys):
    from mavadrc.cli.main import main

    text = TINY.replace("settle_s: 3", "settle_s: 3\n  wind: breeze_1ms")
    status = main(["compare", str(tiny(tmp_path, text)), "--sitl", f"px4={tmp_path}",
                   "--out", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    assert status == 2
    assert "scenario 'hover' on PX4 SIH: PX4 SIH has no wind model" in err
    assert not (tmp_path / "out" / "runs" / "hover" / "PD" / "seed0" / "sitl").exists()


# --- a stand-in SITL: readiness and stopping ----------------------------------------------------

# heartbeats from an autopilot that never passes its pre-arm checks; or, given "silent", nothing
STAND_IN = textwrap.dedent("""\
    import os, sys, time
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil
    if sys.argv[2] == "silent":
        time.sleep(600)
    m = mavutil.mavlink_connection("udpout:127.0.0.1:" + sys.argv[1], source_system=1)
    while True:
        m.mav.heartbeat_send(2, 12, 0, 0, 3)
        m.mav.sys_status_send(0, 0, 0, 500, 12000, -1, -1, 0, 0, 0, 0, 0, 0)
        time.sleep(0.2)
    """)


@pytest.fixture
def stand_in(monkeypatch):
    """SITLs that run the stand-in (``kind``: "armless" or "silent") instead of a build."""
    def use(kind):
        def command(plan, scratch):
            port = sitl_launch.free_udp_port()
            return ([sys.executable, "-c", STAND_IN, str(port), kind],
                    sitl_launch.project_env(), f"udpin:127.0.0.1:{port}")
        monkeypatch.setattr(sitl_launch, "command", command)
    return use


def sitl_pid(out):
    found = list(Path(out).rglob("sitl.pid"))
    assert len(found) == 1
    return int(found[0].read_text())


@pytest.mark.slow
@pytest.mark.realtime
@pytest.mark.parametrize("kind,wait,said", [
    ("armless", 8, ("could not arm after 8 s: its pre-arm checks fail (SYS_STATUS) and it "
                    "reports no position")),
    ("silent", 3, "sent no heartbeat on udpin:127.0.0.1:")])
def test_a_sitl_that_never_becomes_armable_is_said_and_stopped(tmp_path, stand_in, capsys,
                                                               kind, wait, said):
    from mavadrc.cli.main import main

    stand_in(kind)
    out = tmp_path / "out"
    status = main(["compare", str(tiny(tmp_path)), "--sitl", "bundled=px4", "--out", str(out),
                   "--ready-timeout", str(wait), "-q"])
    err = capsys.readouterr().err
    assert status == 1
    assert said in err and "the bundled vehicle as px4" in err
    assert gone(sitl_pid(out))  # no orphan left behind
    assert not list(out.rglob("record.json"))


@pytest.mark.parametrize("error", [KeyboardInterrupt, RuntimeError])
def test_ctrl_c_or_an_error_mid_run_stops_the_sitl(tmp_path, stand_in, monkeypatch, error):
    stand_in("armless")
    started = []

    def interrupted(sitl, params, timeout, say=None):
        started.append(sitl.proc.pid)
        assert not gone(sitl.proc.pid)
        raise error()

    monkeypatch.setattr(sitl_runs, "prepare", interrupted)
    out = tmp_path / "out"
    with pytest.raises(error):
        sitl_runs.compare_sitl(tiny(tmp_path), ["bundled=px4"], out=out, progress=False,
                               stream=io.StringIO())
    assert started and gone(started[0])


def test_ctrl_c_is_said_in_one_line_with_how_to_go_on(tmp_path, monkeypatch, capsys):
    from mavadrc.cli.main import main

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sitl_runs, "run_sitl", interrupted)
    status = main(["compare", str(tiny(tmp_path)), "--sitl", "bundled", "--out",
                   str(tmp_path / "out")])
    assert status == 130
    assert "the same command goes on from there" in capsys.readouterr().err


# --- flights against mavadrc sitl ---------------------------------------------------------------

@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """The tiny experiment (hover, PD and LADRC, one seed) against `mavadrc sitl` as PX4."""
    tmp = tmp_path_factory.mktemp("sitl_runs")
    out = tmp / "out"
    stream = io.StringIO()
    _, _, records = sitl_runs.compare_sitl(tiny(tmp), ["bundled=px4"], out=out,
                                           progress=False, stream=stream, ready_timeout=120.0)
    return tmp, out, records, stream.getvalue()


@pytest.mark.slow
@pytest.mark.realtime
def test_each_run_leaves_its_record_with_the_truth_beside_the_estimate(flown):
    _, out, records, _ = flown
    assert [(r["controller"], r["seed"]) for r in records] == [("PD", 0), ("LADRC", 0)]
    for r in records:
        saved = json.loads((out / "runs" / "hover" / r["controller"] / "seed0" /
                            "record.json").read_text())
        assert saved["run_key"] == r["run_key"]
        assert r["feasible"] and r["landed"] and r["via"] == "sitl"
        assert r["truth"]["source"] == "HIL_STATE_QUATERNION"
        assert 0.0 < r["truth"]["after_settle"]["rms_error_m"] < 0.1
        assert 0.0 <= r["estimator_error"]["rms_m"] < 0.02
        assert 0.0 < r["after_settle"]["rms_error_m"] < 0.1
        assert Path(r["record_folder"], "summary.json").is_file()
    doc = json.loads((out / "results.json").read_text())
    assert doc["via"] == "sitl" and len(doc["records"]) == 2
    report = (out / "report.md").read_text()
    assert "| truth RMS 3-D | truth max 3-D | estimator RMS 3-D |" in report
    assert "truth.after_settle.rms_error_m" in (out / "results.csv").read_text()


@pytest.mark.slow
@pytest.mark.realtime
def test_the_same_command_skips_the_finished_runs(flown, monkeypatch, capsys):
    from mavadrc.cli.main import main

    tmp, out, _, _ = flown

    def no_sitl(self):
        raise AssertionError("a finished run was flown again")

    monkeypatch.setattr(SitlProcess, "start", no_sitl)
    status = main(["compare", str(tmp / "tiny.yaml"), "--sitl", "bundled=px4", "--out", str(out),
                   "-q"])
    cap = capsys.readouterr()
    assert status == 0
    assert "2 finished runs skipped" in cap.err and "0 to fly" in cap.err
    assert "hover" in cap.out
    assert len(json.loads((out / "results.json").read_text())["records"]) == 2


def test_a_run_whose_mission_changed_is_not_skipped(tmp_path):
    exp = load_experiment(tiny(tmp_path))
    other = experiment_from_text(exp.source, exp.text.replace("duration: 3", "duration: 4"))
    given = {"path": "bundled", "params": {}}
    keys = [sitl_runs.run_key(sitl_runs.mission_doc(e, 0, 0),
                              sitl_runs.sitl_plan(e, 0, 0, 0, "px4", given, tmp_path))
            for e in (exp, other)]
    assert keys[0] != keys[1]
    run = tmp_path / "run"
    run.mkdir()
    sitl_runs.save_record(run, {"run_key": keys[0]})
    assert sitl_runs.finished(run, keys[0]) is not None
    assert sitl_runs.finished(run, keys[1]) is None
