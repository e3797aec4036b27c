"""Vehicle parameter files: the shipped vehicles, derived quantities, and validation errors that
name the file, the line and the field."""

import dataclasses

import numpy as np
import pytest

from sim.params import (P_KF, P_MASS, P_ROTOR_DIR, P_ROTOR_POS, P_SIZE, VehicleParams,
                        load_vehicle)
from sim.physics import GRAVITY
from sim.yamlio import ConfigError, load_yaml

VALID = """\
name: test
mass: 0.5
inertia: [2e-3, 2e-3, 4e-3]
arm_length: 0.12
layout: x
k_f: 1e-6
k_m: 1.6e-8
tau_up: 0.02
tau_down: 0.03
omega_max: 2000
"""


@pytest.mark.parametrize("name, tw", [("crazyflie", (2.0, 2.2)), ("quad2kg", (1.65, 1.85)),
                                      ("x500", (1.65, 1.85))])
def test_shipped_vehicles_load_with_sensible_thrust_to_weight(name, tw):
    p = load_vehicle(name)
    assert p.name == name
    assert tw[0] < p.thrust_to_weight < tw[1]
    assert 4 * p.k_f * p.hover_omega ** 2 == pytest.approx(p.mass * GRAVITY, rel=1e-12)
    assert p.hover_thrust_norm == pytest.approx(1 / p.thrust_to_weight)
    assert p.max_thrust == pytest.approx(4 * p.k_f * p.omega_max ** 2)
    assert np.allclose(np.linalg.norm(p.rotor_positions, axis=1), p.arm_length)


def test_shipped_numbers_carry_the_corrections():
    cf = load_vehicle("crazyflie")
    assert cf.mass == 0.030 and cf.arm_length == 0.046 and cf.layout == "plus"
    assert np.array_equal(cf.inertia, [1.43e-5, 1.43e-5, 2.89e-5])     # not 0.00143
    assert 0.15 < cf.k_f * cf.omega_max ** 2 < 0.16                      # N per motor
    assert cf.k_m / cf.k_f == pytest.approx(0.006)
    assert 16_000 < cf.hover_omega * 60 / (2 * np.pi) < 18_000           # rpm
    q = load_vehicle("quad2kg")
    assert np.array_equal(q.inertia, [0.018125, 0.018125, 0.035])
    assert q.arm_length == pytest.approx(0.45 / 2)                        # printed 0.45: diagonal
    assert q.rotor_inertia < 6e-3 / 100                                   # printed 6e-3: too large
    x = load_vehicle("x500")
    assert x.layout == "x" and x.k_f == pytest.approx(8.55e-6, rel=1e-3)
    assert x.k_m / x.k_f == pytest.approx(0.016) and x.omega_max == 1000.0
    assert (x.tau_up, x.tau_down) == (0.0125, 0.025)


def test_pack_layout():
    p = load_vehicle("x500")
    P = p.pack()
    assert P.shape == (P_SIZE,) and P.dtype == np.float64
    assert P[P_MASS] == p.mass and P[P_KF] == p.k_f
    assert np.array_equal(P[P_ROTOR_POS:P_ROTOR_POS + 12].reshape(4, 3), p.rotor_positions)
    assert np.array_equal(P[P_ROTOR_DIR:P_ROTOR_DIR + 4], p.rotor_directions)


def test_valid_file_loads_and_reads_exponents_without_a_dot(tmp_path):
    path = tmp_path / "v.yaml"
    path.write_text(VALID)
    p = load_vehicle(str(path))
    assert p.k_f == 1e-6 and p.inertia[0] == 2e-3
    assert p.omega_min == 0.0 and not p.drag_linear.any() and p.rotor_drag == 0.0


def _edit(text, key, new_line):
    lines = [(new_line if ln.startswith(f"{key}:") else ln) for ln in text.splitlines()]
    return "\n".join(ln for ln in lines if ln is not None) + "\n"


@pytest.mark.parametrize("change, line, field, reason", [
    (("mass", "mass: -1"), 2, "mass", "must be > 0 (got -1.0)"),
    (("mass", "mass: heavy"), 2, "mass", "must be a number (got 'heavy')"),
    (("mass", None), 1, "mass", "required field missing"),
    (("inertia", "inertia: [2e-3, -2e-3, 4e-3]"), 3, "inertia", "item 1 must be > 0"),
    (("inertia", "inertia: [2e-3, 4e-3]"), 3, "inertia", "must be a list of 3 numbers"),
    (("layout", "layout: hexa"), 5, "layout", "must be one of plus, x (got 'hexa')"),
    (("omega_max", "omega_max: 900"), 10, "omega_max", "thrust-to-weight"),
    (("tau_up", "tau_up: 0"), 8, "tau_up", "must be > 0"),
    (("omega_max", "omega_max: 2000\nomega_min: 2500"), 11, "omega_min",
     "must be < omega_max"),
    (("omega_max", "omega_max: 2000\ncolour: red"), 11, "colour", "unknown key"),
    (("omega_max", "omega_max: 2000\nmass: 2"), 11, "mass", "duplicate key (first on line 2)"),
    (("omega_max", "omega_max: 2000\ndrag_linear: [0.1, 0.1]"), 11, "drag_linear",
     "or one number"),
])
def test_malformed_files_name_file_line_and_field(tmp_path, change, line, field, reason):
    path = tmp_path / "bad.yaml"
    path.write_text(_edit(VALID, *change))
    with pytest.raises(ConfigError) as err:
        load_vehicle(str(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {field}: "), msg
    assert reason in msg, msg


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nmass: [1, 2\nlayout: x\n")
    with pytest.raises(ConfigError, match=rf"^{path}:\d+: invalid YAML"):
        load_vehicle(str(path))


def test_unknown_vehicle_name_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="crazyflie.*quad2kg.*x500"):
        load_vehicle("hexacopter")


def test_programmatic_parameters_are_validated_too():
    good = load_vehicle("x500")
    with pytest.raises(ConfigError, match="mass: must be > 0"):
        dataclasses.replace(good, mass=-2.0)
    with pytest.raises(ConfigError, match="thrust-to-weight"):
        dataclasses.replace(good, mass=5.0)
    with pytest.raises(ConfigError, match="layout"):
        dataclasses.replace(good, layout="octo")
    assert isinstance(dataclasses.replace(good, mass=2.5), VehicleParams)


def test_loaded_yaml_remembers_lines(tmp_path):
    path = tmp_path / "l.yaml"
    path.write_text("a: 1\nb:\n  - x: 2\n  - y: 3\n")
    data = load_yaml(path)
    assert data.lines == {"a": 1, "b": 2}
    assert data["b"].lines == [3, 4] and data["b"][1].lines == {"y": 4}
