"""A flight's record says how it was made: the effective configuration (every override applied,
the gains flown), the command line, the versions and the vehicle, in strict JSON; and its
effective.yaml flies the same flight again, bit for bit in lockstep."""

import json
import math
from pathlib import Path

import pytest

from mavadrc.cli.main import main
from mavadrc.flight.summary import print_table
from mavadrc.flight.record import FlightRecord, error_figures

ROOT = Path(__file__).resolve().parent.parent


def strict(text):
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")
    return json.loads(text, parse_constant=refuse)


@pytest.mark.slow
def test_the_record_reproduces_a_flight_with_every_override(tmp_path, capsys):
    argv = ["fly", str(ROOT / "configs" / "missions" / "hover.yaml"), "--lockstep", "--seed", "7",
            "--wind", "moderate_gusts", "--controller", "adrc", "--no-figures", "-q"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert "--controller adrc: the mission's ladrc gains do not apply" in capsys.readouterr().out
    (a,) = (tmp_path / "a").iterdir()
    s = strict((a / "summary.json").read_text())
    assert s["config"]["seed"] == 7 and s["config"]["wind"] == "moderate_gusts"
    assert s["config"]["controller_replaced"] and s["config"]["lockstep"]
    flown = s["controller_flown"]
    assert flown["type"] == "adrc" and flown["wc"] == [1.0] * 3 and flown["wo"] == [4.0] * 3
    assert flown["r"] == [8.0] * 3 and flown["td"] is False  # the defaults, named
    assert set(s["versions"]) == {"mavadrc", "pymavlink", "numpy", "numba", "python"}
    assert all(s["versions"].values())
    assert s["vehicle"]["autopilot"] == "px4" and s["vehicle"]["system_id"] == 1
    assert s["vehicle"]["firmware_version"]  # from AUTOPILOT_VERSION
    assert isinstance(s["command_line"], list)
    # mission.yaml is the file as given; effective.yaml flies the same flight again
    assert "type: ladrc" in (a / "mission.yaml").read_text()
    assert main(["fly", str(a / "effective.yaml"), "--lockstep", "--no-figures", "-q", "--out",
                 str(tmp_path / "b")]) == 0
    (b,) = (tmp_path / "b").iterdir()
    assert (a / "controller.csv").read_bytes() == (b / "controller.csv").read_bytes()
    again = strict((b / "summary.json").read_text())
    assert again["controller_flown"] == flown and not again["config"]["controller_replaced"]


def test_a_flight_cut_short_writes_null_not_nan_and_prints_no_nan(tmp_path, capsys):
    """Ctrl-C before the settling window ended: the figures after it do not exist."""
    nothing = error_figures([], [], [], 0.0)
    assert math.isnan(nothing["rms_error_m"])  # what the recorder gives, before the record
    from mavadrc.flight.record import finite

    summary = finite({"rms_error_xyz_m": [0.1, 0.1, 0.1], "max_error_xyz_m": [0.2, 0.2, 0.2],
                      "rms_error_m": 0.17, "max_error_m": 0.3, "settle_s": 14.0,
                      "after_settle": nothing})
    rec = FlightRecord(tmp_path / "r")
    rec.write_summary(summary)
    rec.close()
    assert strict((tmp_path / "r" / "summary.json").read_text())["after_settle"][
        "rms_error_m"] is None
    print_table(summary)
    out = capsys.readouterr().out
    assert "nan" not in out and "after 14 s: not reached" in out
