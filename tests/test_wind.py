"""Wind models: conventions, Dryden statistics and spectra, gust shapes, the thesis's numbers,
drag from the air-relative velocity, reproducibility, configuration errors."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.signal import welch

from mavadrc.control import rotations as rot
from sim import physics as ph
from sim.params import load_vehicle
from sim.wind import (DRYDEN_W20, KNOT, CompositeWind, ConstantWind, DrydenTurbulence,
                      OneMinusCosineGust, SinusoidWind, ThesisWind, _dryden2_coeffs,
                      dryden_scales, load_wind, wind_vector)
from sim.yamlio import ConfigError

Z3 = np.zeros(3)
LOW = np.array([0.0, 0.0, -3.0])        # below 10 ft: the Dryden scales clip there


def test_direction_is_where_the_wind_blows_from():
    assert np.allclose(wind_vector(2.0, 0.0), [-2.0, 0.0, 0.0])       # from north: to the south
    assert np.allclose(wind_vector(2.0, 270.0), [0.0, 2.0, 0.0])      # from west: to the east
    assert np.allclose(wind_vector(2.0, 90.0, vertical=0.5), [0.0, -2.0, -0.5])  # updraft: -z


def test_constant_wind_profiles():
    pos = lambda h: np.array([0.0, 0.0, -h])  # noqa: E731
    w = ConstantWind(4.0, 270.0, profile="sqrt60")
    assert np.allclose(w.mean(pos(15.0)), [0.0, 2.0, 0.0])
    assert np.allclose(w.mean(pos(100.0)), [0.0, 4.0, 0.0])
    assert np.allclose(w.mean(pos(0.0)), 0.0)
    log = ConstantWind(4.0, 0.0, profile="log", ref_height=10.0, roughness=0.03)
    assert log.mean(pos(10.0))[0] == pytest.approx(-4.0)
    assert log.mean(pos(20.0))[0] == pytest.approx(-4.0 * math.log(20 / 0.03) / math.log(10 / 0.03))
    v, f, tau = ConstantWind(3.0, 45.0, vertical=1.0).step(0.0, 1e-3, pos(5.0), Z3)
    assert np.allclose(v, [-3 / math.sqrt(2), -3 / math.sqrt(2), -1.0])
    assert not f.any() and not tau.any()


def test_dryden_scales_match_mil_f_8785c_example():
    """SIMULATION.md: h = 10 m, W20 = 15 kt -> L_u 67 m, L_w 10 m, sigma_u 1.46, sigma_w 0.77."""
    sig_u, sig_w, l_u, l_w = dryden_scales(10.0, 15 * KNOT)
    assert (sig_u, sig_w) == pytest.approx((1.46, 0.77), abs=0.01)
    assert (l_u, l_w) == pytest.approx((67.0, 10.0), abs=0.5)
    assert DRYDEN_W20["moderate"] == pytest.approx(30 * KNOT)


@pytest.mark.parametrize("eps", [1e-3, 0.05, 0.7, 1.0, 2.5, 4.0])
def test_dryden_two_state_discretisation_is_exact(eps):
    """Against Van Loan's method with scipy's expm: Phi = e^{A eps}, L L^T = the step's noise
    covariance, for the unit filter A = [[0, 1], [-1, -2]], B = [0, 1]."""
    A = np.array([[0.0, 1.0], [-1.0, -2.0]])
    BBt = np.array([[0.0, 0.0], [0.0, 1.0]])
    M = np.block([[-A, BBt], [np.zeros((2, 2)), A.T]]) * eps
    G = expm(M)
    phi = G[2:, 2:].T
    Q = phi @ G[:2, 2:]
    c = np.empty(7)
    _dryden2_coeffs(eps, c)
    assert np.allclose(c[:4].reshape(2, 2), phi, rtol=1e-9, atol=1e-15)
    L = np.array([[c[4], 0.0], [c[5], c[6]]])
    assert np.allclose(L @ L.T, Q, rtol=1e-8, atol=1e-16)
    # small steps: the leading terms [[e^3/3, e^2/2], [e^2/2, e]] without cancellation
    _dryden2_coeffs(1e-7, c)
    L = np.array([[c[4], 0.0], [c[5], c[6]]])
    assert np.allclose(L @ L.T, [[1e-21 / 3, 1e-14 / 2], [1e-14 / 2, 1e-7]], rtol=1e-6)


def _series(dt, seconds, seed=11, velocity=Z3):
    mean = ConstantWind(30.0, 270.0)                       # u along +y (east), v along -x
    turb = DrydenTurbulence(w20=10.0, mean_wind=mean, seed=seed)
    out = turb.sample(int(round(seconds / dt)), dt, LOW, velocity)
    return np.column_stack([out[:, 1], -out[:, 0], out[:, 2]])    # u, v, w


@pytest.mark.parametrize("dt", [1e-3, 2e-3, 10e-3])
def test_dryden_realised_std_does_not_depend_on_the_step(dt):
    sig_u, sig_w, _, _ = dryden_scales(3.0, 10.0)
    uvw = _series(dt, 3000.0)
    std = uvw.std(axis=0)
    assert std == pytest.approx([sig_u, sig_u, sig_w], rel=0.05)
    assert np.abs(uvw.mean(axis=0)).max() < 0.1 * sig_u


def _dryden_shapes(f, L, V):
    w = 2 * np.pi * f * L / V
    return 1.0 / (1.0 + w ** 2), (1.0 + 3.0 * w ** 2) / (1.0 + w ** 2) ** 2


def test_dryden_spectrum_and_correlation_follow_the_transfer_functions():
    dt = 2e-3
    V = 30.0
    _, _, l_u, l_w = dryden_scales(3.0, 10.0)
    uvw = _series(dt, 3000.0, seed=5)
    # u: exponential autocorrelation exp(-V tau / L_u)
    lag = int(round(l_u / V / dt))
    u = uvw[:, 0] - uvw[:, 0].mean()
    assert np.mean(u[:-lag] * u[lag:]) / np.var(u) == pytest.approx(math.exp(-1), abs=0.04)
    # power at low vs high frequency, per component, against the analytic PSD shape
    for k, L in ((0, l_u), (1, l_u), (2, l_w)):
        f, psd = welch(uvw[:, k], fs=1 / dt, nperseg=1 << 17)
        shape = _dryden_shapes(f, L, V)[0 if k == 0 else 1]
        f_corner = V / (2 * np.pi * L)
        lo = (f > 0.1 * f_corner) & (f < 0.3 * f_corner)
        hi = (f > 3.0 * f_corner) & (f < 10.0 * f_corner)
        measured = psd[lo].mean() / psd[hi].mean()
        expected = shape[lo].mean() / shape[hi].mean()
        assert measured == pytest.approx(expected, rel=0.1), (k, measured, expected)


def test_dryden_advects_at_the_relative_speed_with_a_floor():
    """Drifting with the mean wind, the field passes at v_min: u decorrelates over L_u/v_min."""
    mean = ConstantWind(5.0, 0.0)
    turb = DrydenTurbulence(w20=5.0, mean_wind=mean, v_min=1.5, seed=2)
    dt = 0.01
    out = turb.sample(400_000, dt, LOW, mean.mean(LOW))
    _, _, l_u, _ = dryden_scales(3.0, 5.0)
    u = -out[:, 0]
    lag = int(round(l_u / 1.5 / dt))
    u = u - u.mean()
    assert np.mean(u[:-lag] * u[lag:]) / np.var(u) == pytest.approx(math.exp(-1), abs=0.08)


def test_one_minus_cosine_gust_shape():
    gust = OneMinusCosineGust([0.0, 4.0, -2.0], t_start=1.0, t_rise=0.5, t_hold=2.0)
    amp = lambda t: gust.step(t, 1e-3, Z3, Z3)[0]  # noqa: E731
    assert np.all(amp(0.99) == 0.0) and np.all(amp(1.0) == 0.0)
    assert np.allclose(amp(1.25), [0.0, 2.0, -1.0])
    assert np.allclose(amp(1.5), [0.0, 4.0, -2.0]) and np.allclose(amp(3.0), [0.0, 4.0, -2.0])
    assert np.allclose(amp(3.5 + 0.125), amp(1.5 - 0.125))          # the fall mirrors the rise
    assert np.allclose(amp(4.0), 0.0) and np.all(amp(5.0) == 0.0)


def test_sinusoid():
    s = SinusoidWind(wind_vector(2.0, 180.0), freq=0.5, phase=0.0)
    assert np.allclose(s.step(0.5, 1e-3, Z3, Z3)[0], [2.0, 0.0, 0.0])
    assert np.allclose(s.step(1.0, 1e-3, Z3, Z3)[0], 0.0, atol=1e-12)


def test_thesis_model_reproduces_its_published_numbers():
    wind = load_wind("thesis")
    assert isinstance(wind, ThesisWind)
    f = wind.rotor_forces()
    assert np.allclose(f, -0.2477, atol=5e-4)          # f_wi = 0.0023 - 0.2500 N per rotor
    v, f_ext, tau = wind.step(0.0, 1e-3, Z3, Z3)
    s = f.sum()
    assert s == pytest.approx(-0.991, abs=2e-3)
    assert not v.any()
    assert np.allclose(f_ext, [s, s, -s])                # x'', y'' and z'' (up) of eq. 13
    assert np.allclose(tau, [0.0, 0.0, 4 * (1.293 / 2) * 1.0 ** 2])
    # on the 30 g Crazyflie at hover: 33 m/s^2 on every axis, downward in NED
    cf = load_vehicle("crazyflie")
    x = ph.initial_state((0, 0, -10.0), rotor_speed=cf.hover_omega)
    xd = np.empty(ph.NX)
    ph.derivatives(x, np.full(4, cf.hover_omega), cf.pack(), v, f_ext, Z3, xd)
    assert np.allclose(xd[3:6], [-33.03, -33.03, 33.03], atol=0.05)


def test_drag_from_the_air_relative_velocity_gives_the_predicted_acceleration():
    """Hovering level in wind w (yawed, so body and world axes differ), at rest: F_body =
    k_d Omega (w_body in the rotor plane) per rotor + (linear + quadratic |w|) w_body per axis."""
    cf = load_vehicle("crazyflie")
    yaw = 0.6
    x = ph.initial_state((0, 0, -10.0), yaw=yaw, rotor_speed=cf.hover_omega)
    wind = np.array([1.0, -2.0, 0.5])
    xd = np.empty(ph.NX)
    ph.derivatives(x, np.full(4, cf.hover_omega), cf.pack(), wind, Z3, Z3, xd)
    R = rot.rotation_matrix(x[6:10])
    wb = R.T @ wind
    f = (cf.drag_linear + cf.drag_quadratic * np.linalg.norm(wind)) * wb
    f[:2] += 4 * cf.rotor_drag * cf.hover_omega * wb[:2]
    f[2] -= cf.weight
    expect = R @ f / cf.mass + [0.0, 0.0, ph.GRAVITY]
    assert np.allclose(xd[3:6], expect, rtol=1e-12, atol=1e-12)
    # about 0.25 m/s^2 per 1 m/s of horizontal wind on a hovering Crazyflie (SIMULATION.md)
    ph.derivatives(x, np.full(4, cf.hover_omega), cf.pack(), np.array([1.0, 0, 0]), Z3, Z3, xd)
    assert 0.22 < np.linalg.norm(xd[3:5]) < 0.33


def test_constant_wind_drift_follows_the_drag_model():
    """Held level at hover thrust, the vehicle is carried by the wind until its air speed is 0:
    m v' = c (w - v) + q |w - v| (w - v), c = 4 k_d Omega_h + linear, q = quadratic."""
    cf = load_vehicle("x500")
    wind = load_wind("breeze_1ms")
    x = ph.initial_state((0, 0, -10.0), rotor_speed=cf.hover_omega)
    cmd = np.full(4, cf.hover_omega)
    P = cf.pack()
    dt = 1e-3
    times = [1.0, 3.0, 10.0, 40.0]
    got = []
    t = 0.0
    for t_end in times:
        while t < t_end - 1e-9:
            v_wind, f_ext, tau_ext = wind.step(t, dt, x[:3], x[3:6])
            ph.step(x, cmd, P, v_wind, f_ext, tau_ext, dt)
            t += dt
        got.append(x[4])
    c = 4 * cf.rotor_drag * cf.hover_omega + cf.drag_linear[1]
    q = cf.drag_quadratic[1]
    ref = solve_ivp(lambda _, v: (c * (1 - v) + q * abs(1 - v) * (1 - v)) / cf.mass,
                    (0, times[-1]), [0.0], t_eval=times, rtol=1e-12, atol=1e-14).y[0]
    assert np.allclose(got, ref, rtol=1e-6)
    assert got[-1] == pytest.approx(1.0, abs=0.01)
    assert x[2] == pytest.approx(-10.0, abs=1e-9) and abs(x[3]) < 1e-12
    assert np.abs(x[10:13]).max() < 1e-12


def _run(wind, steps=400, dt=1e-3):
    out = []
    for k in range(steps):
        pos = np.array([0.01 * k, 0.0, -5.0 - 0.001 * k])
        out.append(np.concatenate(wind.step(k * dt, dt, pos, np.array([1.0, 0.5, 0.0]))))
    return np.array(out)


def test_same_seed_same_wind_and_different_seed_different_wind():
    a = _run(load_wind("moderate_gusts", seed=3))
    b = _run(load_wind("moderate_gusts", seed=3))
    c = _run(load_wind("moderate_gusts", seed=4))
    assert np.array_equal(a, b)
    assert np.abs(a - c).max() > 0.01
    again = load_wind("moderate_gusts", seed=4)
    _run(again)
    again.reset(3)
    assert np.array_equal(_run(again), a)


def test_composite_sums_its_parts():
    parts = [ConstantWind(2.0, 90.0), SinusoidWind([0.0, 0.0, 1.0], 1.0, math.pi / 2),
             load_wind("thesis")]
    v, f, tau = CompositeWind(parts).step(0.0, 1e-3, LOW, Z3)
    assert np.allclose(v, [0.0, -2.0, 1.0])
    assert np.allclose(f, parts[2].step(0.0, 1e-3, LOW, Z3)[1])
    assert tau[2] == pytest.approx(2.586)


def test_shipped_wind_files_load():
    assert not any(np.concatenate(load_wind("calm").step(0.0, 1e-3, LOW, Z3)))
    moderate = load_wind("moderate_gusts")
    dryden = [p for p in moderate.parts if isinstance(p, DrydenTurbulence)][0]
    assert dryden.w20 is None and dryden.mean_wind is not None     # W20 from the mean wind
    assert isinstance(load_wind({"type": "dryden", "intensity": "light"}), DrydenTurbulence)


@pytest.mark.parametrize("body, line, field, reason", [
    ("components:\n  - type: constant\n    speed: 2\n  - type: hurricane\n", 4,
     "components[1].type", "must be one of"),
    ("components:\n  - type: constant\n    speed: fast\n", 3, "components[0].speed",
     "must be a number"),
    ("components:\n  - type: constant\n    speed: 2\n    colour: red\n", 4,
     "components[0].colour", "unknown key"),
    ("components:\n  - type: dryden\n", 2, "components[0]", "give intensity or w20"),
    ("type: gust\namplitude: 2\nt_start: 1\nt_rise: -1\n", 4, "t_rise", "must be > 0"),
    ("type: constant\nspeed: 1\nwind: 2\n", 3, "wind", "unknown key"),
])
def test_bad_wind_files_name_file_line_and_field(tmp_path, body, line, field, reason):
    path = tmp_path / "bad.yaml"
    path.write_text(body)
    with pytest.raises(ConfigError) as err:
        load_wind(str(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {field}: "), msg
    assert reason in msg


def test_wind_from_a_mapping_reports_the_field():
    with pytest.raises(ConfigError, match=r"speed: must be >= 0"):
        load_wind({"components": [{"type": "constant", "speed": -1}]})
    with pytest.raises(ConfigError, match="amplitude: required field missing"):
        load_wind({"type": "gust", "t_start": 1.0, "t_rise": 1.0})
    with pytest.raises(ConfigError, match="no such file"):
        load_wind("configs/wind/no_such_file.yaml")


# --- compiled (packed) form ------------------------------------------------------------------

@pytest.mark.parametrize("wind", ["moderate_gusts", "breeze_1ms", "calm", {
    "components": [
        {"type": "constant", "speed": 3.0, "direction_from_deg": 200, "profile": "log"},
        {"type": "dryden", "intensity": "light"},
        {"type": "gust", "amplitude": [1.0, -0.5, 0.2], "t_start": 0.5, "t_rise": 0.4},
        {"type": "sinusoid", "amplitude": [0.5, 0.0, 0.1], "freq_hz": 0.3}]}])
def test_packed_wind_flies_the_same_as_the_python_models(wind):
    """The compiled wind the vehicle uses by default reproduces the per-step Python models: same
    Dryden stream, same gusts, same drag, so the same flight."""
    from sim.vehicle import SimVehicle

    states = []
    for packed in (True, False):
        v = SimVehicle("crazyflie", wind=wind, seed=11, position=(0.0, 0.0, -2.0))
        if not packed:
            v._packed = None  # force the per-step Python path
        v.arm()
        v.set_position_target(pos=[1.0, 0.5, -2.5])
        v.step(3.0)
        states.append((v.state, v.wind_velocity))
    assert np.allclose(states[0][0], states[1][0], rtol=0, atol=1e-8)
    assert np.allclose(states[0][1], states[1][1], rtol=0, atol=1e-9)
    if wind != "calm":
        assert np.linalg.norm(states[0][1]) > 0.1  # the wind really blew


def test_pack_wind_refuses_what_it_cannot_compile():
    from sim.wind import LayeredWind, pack_wind

    base = load_wind("moderate_gusts", seed=1)
    assert pack_wind(base) is not None
    assert pack_wind(LayeredWind(base, ConstantWind(2.0, 90.0))) is None
    two = CompositeWind([ConstantWind(1.0), ConstantWind(2.0, 90.0)])
    assert pack_wind(two) is None
    assert pack_wind(None) is None


@pytest.mark.parametrize("name", ["calm", "breeze_1ms", "moderate_gusts", "thesis"])
def test_random_says_whether_the_seed_changes_the_series(name):
    """``random`` is what lets an experiment fly a seed-independent run once: it must be True
    exactly when two seeds give different winds."""
    a, b = load_wind(name, seed=1), load_wind(name, seed=2)
    va = np.array([a.step(k * 0.01, 0.01, np.array([0, 0, -1.0]), np.zeros(3))[0]
                   for k in range(200)])
    vb = np.array([b.step(k * 0.01, 0.01, np.array([0, 0, -1.0]), np.zeros(3))[0]
                   for k in range(200)])
    assert a.random == (not np.array_equal(va, vb))
    assert a.random == (name == "moderate_gusts")
