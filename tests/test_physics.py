"""The rigid-body kernels: equilibria, exact solutions, conservation laws, the thesis's eq. 4,
motors, ground contact, and batch == single."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mavadrc.control import rotations as rot
from sim import physics as ph
from sim.params import (P_DRAG_LIN, P_DRAG_QUAD, P_IXX, P_KF, P_KM, P_ROTOR_DIR,
                        P_ROTOR_DRAG, P_ROTOR_INERTIA, load_vehicle)

Z3 = np.zeros(3)
DT = 1e-3


@pytest.fixture(scope="module")
def cf():
    return load_vehicle("crazyflie")


def no_drag(P):
    P = P.copy()
    P[P_DRAG_LIN:P_DRAG_LIN + 3] = 0.0
    P[P_DRAG_QUAD:P_DRAG_QUAD + 3] = 0.0
    P[P_ROTOR_DRAG] = 0.0
    return P


def angular_momentum_world(x, P):
    """R (J w + h_r e3): body plus rotor angular momentum, in NED."""
    J = P[P_IXX:P_IXX + 3]
    dirs = P[P_ROTOR_DIR:P_ROTOR_DIR + 4]
    h = J * x[ph.IX_W:ph.IX_W + 3]
    h[2] -= P[P_ROTOR_INERTIA] * float(dirs @ x[ph.IX_ROT:ph.IX_ROT + 4])
    return rot.rotation_matrix(x[ph.IX_Q:ph.IX_Q + 4]) @ h


@pytest.mark.parametrize("name", ["crazyflie", "quad2kg", "x500"])
def test_hover_at_hover_rotor_speed_holds_altitude(name):
    p = load_vehicle(name)
    x = ph.initial_state((1.0, 2.0, -10.0), yaw=0.7, rotor_speed=p.hover_omega)
    cmd = np.full(4, p.hover_omega)
    ph.step_n(x, cmd, p.pack(), Z3, Z3, Z3, DT, 10_000)
    assert abs(x[2] + 10.0) < 1e-6
    assert np.allclose(x[:2], [1.0, 2.0], atol=1e-9)
    assert np.allclose(x[ph.IX_Q:ph.IX_Q + 4], rot.quat_from_euler(0, 0, 0.7), atol=1e-12)
    assert np.abs(x[ph.IX_VEL:ph.IX_VEL + 3]).max() < 1e-9
    assert np.abs(x[ph.IX_W:ph.IX_W + 3]).max() < 1e-12


def test_free_fall_accelerates_at_g(cf):
    x = ph.initial_state((0.0, 0.0, -100.0))
    ph.step_n(x, np.zeros(4), no_drag(cf.pack()), Z3, Z3, Z3, DT, 2000)
    t = 2.0
    assert x[5] == pytest.approx(ph.GRAVITY * t, rel=1e-9)
    assert x[2] == pytest.approx(-100.0 + 0.5 * ph.GRAVITY * t * t, rel=1e-9)
    assert ph.GRAVITY == 9.80665


def test_torque_free_spin_conserves_momentum_and_energy(cf):
    """Tumbling about the intermediate axis (Dzhanibekov): R J w and w.J w/2 stay constant."""
    P = no_drag(cf.pack())
    P[P_IXX:P_IXX + 3] = [1.0e-5, 2.0e-5, 2.6e-5]
    x = ph.initial_state((0.0, 0.0, -100.0))
    x[ph.IX_W:ph.IX_W + 3] = [0.2, 4.0, 0.3]
    hover = np.array([0.0, 0.0, -P[0] * ph.GRAVITY])   # an upward force equal to the weight
    J = P[P_IXX:P_IXX + 3]
    h0 = angular_momentum_world(x, P)
    e0 = 0.5 * float(J @ x[10:13] ** 2)
    worst_h = worst_e = 0.0
    min_wy = x[11]
    for _ in range(30):
        ph.step_n(x, np.zeros(4), P, Z3, hover, Z3, DT, 100)
        worst_h = max(worst_h, np.linalg.norm(angular_momentum_world(x, P) - h0))
        worst_e = max(worst_e, abs(0.5 * float(J @ x[10:13] ** 2) - e0))
        min_wy = min(min_wy, x[11])
    assert min_wy < -3.0            # the spin axis flipped: the motion is far from trivial
    assert worst_h < 1e-9 * np.linalg.norm(h0)
    assert worst_e < 1e-9 * e0
    assert np.allclose(x[:3], [0.0, 0.0, -100.0], atol=1e-9)


def test_rotor_gyroscopic_and_reaction_torques_conserve_total_momentum(cf):
    """With spinning rotors (no thrust or drag torque), body + rotor momentum is conserved:
    while the body tumbles, and while the rotors change speed (the body counter-rotates)."""
    P = no_drag(cf.pack())
    P[P_KF] = 0.0
    P[P_KM] = 0.0
    P[P_ROTOR_INERTIA] = 2e-7
    hover = np.array([0.0, 0.0, -P[0] * ph.GRAVITY])
    x = ph.initial_state((0.0, 0.0, -100.0))
    x[ph.IX_W:ph.IX_W + 3] = [1.0, 2.0, 0.5]
    rotors = np.array([1500.0, 1000.0, 1500.0, 1000.0])
    x[ph.IX_ROT:] = rotors
    h0 = angular_momentum_world(x, P)
    ph.step_n(x, rotors, P, Z3, hover, Z3, DT, 2000)
    assert np.linalg.norm(angular_momentum_world(x, P) - h0) < 1e-9 * np.linalg.norm(h0)

    x = ph.initial_state((0.0, 0.0, -100.0), rotor_speed=1000.0)
    ph.step_n(x, np.array([1000.0, 2000.0, 1000.0, 2000.0]), P, Z3, hover, Z3, DT, 300)
    # rotors 2 and 4 (counter-clockwise seen from above) sped up: the body reacts clockwise,
    # nose right (r > 0), with Izz r + (h_r - h_r0) = 0
    dirs = P[P_ROTOR_DIR:P_ROTOR_DIR + 4]
    dh_r = -P[P_ROTOR_INERTIA] * float(dirs @ (x[ph.IX_ROT:] - 1000.0))
    assert x[12] > 0.1
    assert P[P_IXX + 2] * x[12] + dh_r == pytest.approx(0.0, abs=1e-15)


def test_derivatives_match_thesis_eq4_in_ned(cf):
    """Thesis eq. 4 (z up), corrected y row: x'' = (U1/m)(cps sth cph + sps sph),
    y'' = (U1/m)(sps sth cph - cps sph), z'' = (U1/m) cth cph - g; phi'' = U2/Ix +
    (Iy - Iz)/Ix th' ps', and cyclic. The bracket is the third column of R = Rz(psi) Ry(th)
    Rx(phi): the thrust direction. In NED the thrust points along -z body and gravity along +z,
    so with NED Euler angles (ZYX, same R formula): x'' = -(U1/m)(cps sth cph + sps sph),
    y'' = -(U1/m)(sps sth cph - cps sph), z'' = g - (U1/m) cth cph. The rotational rows are
    Euler's equations; they hold exactly in body rates, and in Euler-angle rates in the
    small-angle limit, where (phi', th', psi') -> (p, q, r). No drag, no motor lag, no rotor
    inertia (the thesis has none of them), U2..U4 = the body torques of the allocation."""
    P = no_drag(cf.pack())
    P[P_ROTOR_INERTIA] = 0.0
    m = cf.mass
    Ix, Iy, Iz = cf.inertia
    rng = np.random.default_rng(4)
    for angle_scale in (1e-3, 0.3):
        for _ in range(5):
            phi, th, psi = rng.uniform(-1, 1, 3) * angle_scale * np.array([1, 1, 10])
            rates = rng.uniform(-1, 1, 3) * angle_scale
            omega = cf.hover_omega * (1.0 + 0.05 * rng.uniform(-1, 1, 4))
            x = ph.initial_state((0.0, 0.0, -5.0))
            x[ph.IX_Q:ph.IX_Q + 4] = rot.quat_from_euler(phi, th, psi)
            x[ph.IX_W:ph.IX_W + 3] = rates
            x[ph.IX_ROT:] = omega
            xd = np.empty(ph.NX)
            ph.derivatives(x, omega, P, Z3, Z3, Z3, xd)
            U1, U2, U3, U4 = cf.allocation_matrix() @ omega ** 2
            cph, sph, cth, sth, cps, sps = (math.cos(phi), math.sin(phi), math.cos(th),
                                            math.sin(th), math.cos(psi), math.sin(psi))
            expect_acc = [-(U1 / m) * (cps * sth * cph + sps * sph),
                          -(U1 / m) * (sps * sth * cph - cps * sph),
                          ph.GRAVITY - (U1 / m) * cth * cph]
            assert np.allclose(xd[3:6], expect_acc, rtol=0, atol=1e-12)
            p, q, r = rates
            expect_alpha = [U2 / Ix + (Iy - Iz) / Ix * q * r,
                            U3 / Iy + (Iz - Ix) / Iy * p * r,
                            U4 / Iz + (Ix - Iy) / Iz * p * q]
            assert np.allclose(xd[10:13], expect_alpha, rtol=1e-12, atol=1e-9)
            assert np.all(xd[13:] == 0.0)
            if angle_scale < 0.01:
                # Euler-angle rates from q' equal the body rates to first order
                h = 1e-7
                e1 = rot.euler_from_quat(x[6:10] + h * xd[6:10])
                e0 = rot.euler_from_quat(x[6:10])
                assert np.allclose((e1 - e0) / h, rates, atol=5e-5 * angle_scale / 1e-3)


def test_allocation_signs_follow_the_geometry(cf):
    """Plus: more thrust on the right rotor (2) rolls left (tau_x < 0 in FRD); the front rotor
    (1) pitches nose up (tau_y > 0). X (PX4 order): rotors 1, 2 counter-clockwise, so speeding
    them up yaws nose-right (tau_z > 0)."""
    A = cf.allocation_matrix()
    assert A[1, 1] < 0 and A[1, 3] > 0 and A[2, 0] > 0 and A[2, 2] < 0
    assert np.array_equal(np.sign(A[3]), [-1, 1, -1, 1])    # thesis eq. 3 yaw signs
    x500 = load_vehicle("x500")
    pos = x500.rotor_positions
    assert np.array_equal(np.sign(pos[:, :2]), [[1, 1], [-1, -1], [1, -1], [-1, 1]])
    assert np.allclose(np.abs(pos[:, :2]), 0.174, atol=1e-6)
    A = x500.allocation_matrix()
    assert np.array_equal(np.sign(A[3]), [1, 1, -1, -1])
    # derivatives agree with the allocation: J w' = tau at zero rates
    P = x500.pack()
    omega = np.array([700.0, 710.0, 690.0, 705.0])
    x = ph.initial_state((0, 0, -5), rotor_speed=0.0)
    x[ph.IX_ROT:] = omega
    xd = np.empty(ph.NX)
    ph.derivatives(x, omega, P, Z3, Z3, Z3, xd)
    assert np.allclose(x500.inertia * xd[10:13], (A @ omega ** 2)[1:], rtol=1e-12)


def test_motor_lag_and_limits():
    p = load_vehicle("x500")          # tau_up 12.5 ms, tau_down 25 ms
    P = p.pack()
    dt = 0.5e-3
    x = ph.initial_state((0.0, 0.0, -100.0), rotor_speed=600.0)
    cmd = np.array([900.0, 300.0, 600.0, 600.0])
    ph.step_n(x, cmd, P, Z3, Z3, Z3, dt, 25)                 # t = tau_up
    assert x[13] == pytest.approx(600.0 + 300.0 * (1 - math.exp(-1)), rel=1e-7)
    ph.step_n(x, cmd, P, Z3, Z3, Z3, dt, 25)                 # t = tau_down
    assert x[14] == pytest.approx(600.0 - 300.0 * (1 - math.exp(-1)), rel=1e-7)
    assert x[15] == 600.0
    # commands beyond the limits are clamped: the motors head for omega_max / omega_min
    x[ph.IX_ROT:] = 600.0
    cmd = np.array([5000.0, -50.0, 5000.0, -50.0])
    ph.step_n(x, cmd, P, Z3, Z3, Z3, dt, 25)
    assert x[13] == pytest.approx(1000.0 - 400.0 * math.exp(-1), rel=1e-7)
    ph.step_n(x, cmd, P, Z3, Z3, Z3, dt, 25)
    assert x[14] == pytest.approx(600.0 * math.exp(-1), rel=1e-7)
    top = bottom = 600.0
    for _ in range(1000):
        ph.step(x, cmd, P, Z3, Z3, Z3, dt)
        top = max(top, x[13], x[15])
        bottom = min(bottom, x[14], x[16])
    assert p.omega_max - 1e-3 < top <= p.omega_max
    assert p.omega_min <= bottom < p.omega_min + 1e-3


def test_vehicle_rests_on_ground_and_lifts_off_above_weight(cf):
    P = cf.pack()
    h = cf.hover_omega
    x = ph.initial_state((3.0, 4.0, 0.0), yaw=1.0, rotor_speed=0.0)
    # below-hover thrust with a roll/pitch torque imbalance: stays put, level, at z = 0
    cmd = h * np.array([0.95, 0.7, 0.9, 0.8])
    for _ in range(2000):
        ph.step(x, cmd, P, np.array([2.0, 0.0, 0.0]), Z3, Z3, DT)
        assert x[2] == 0.0
    assert np.allclose(x[:2], [3.0, 4.0], atol=0)
    assert np.all(x[3:6] == 0.0) and np.all(x[10:13] == 0.0)
    assert np.allclose(x[6:10], rot.quat_from_euler(0, 0, 1.0), atol=1e-12)
    # just above weight: lifts off and climbs
    cmd = np.full(4, 1.05 * h)
    lifted = None
    for k in range(1000):
        ph.step(x, cmd, P, Z3, Z3, Z3, DT)
        if lifted is None and x[2] < 0.0:
            lifted = k
    assert lifted is not None and x[2] < -0.05 and x[5] < 0.0
    # liftoff comes when the lagging rotors' thrust passes the weight
    t = np.arange(0.0, 1.0, 1e-5)[:, None]
    start = h * np.array([0.95, 0.7, 0.9, 0.8])
    omega = 1.05 * h + (start - 1.05 * h) * np.exp(-t / cf.tau_up)
    t_cross = t[np.argmax((cf.k_f * omega ** 2).sum(axis=1) > cf.weight), 0]
    assert abs(lifted * DT - t_cross) <= 2 * DT


def test_dropped_vehicle_stops_on_ground_level(cf):
    x = ph.initial_state((0.0, 0.0, -5.0))
    x[6:10] = rot.quat_from_euler(0.3, -0.2, 0.5)
    x[10:13] = [1.0, -2.0, 0.5]
    lowest = -5.0
    for _ in range(2000):
        ph.step(x, np.zeros(4), cf.pack(), Z3, Z3, Z3, DT)
        lowest = max(lowest, x[2])
    assert lowest == 0.0 and x[2] == 0.0
    assert np.all(x[3:6] == 0.0) and np.all(x[10:13] == 0.0)
    roll, pitch, _ = rot.euler_from_quat(x[6:10])
    assert roll == 0.0 and pitch == 0.0


def _batch_case():
    rng = np.random.default_rng(7)
    names = ["crazyflie", "x500", "quad2kg", "crazyflie", "x500"]
    params = [load_vehicle(n) for n in names]
    X = np.array([ph.initial_state((0, 0, -20.0), rotor_speed=p.hover_omega) for p in params])
    X[:, 3:6] += rng.normal(0, 1, (5, 3))
    X[:, 10:13] += rng.normal(0, 0.5, (5, 3))
    for i in range(5):
        X[i, 6:10] = rot.quat_from_euler(*rng.normal(0, 0.2, 3))
    CMD = np.array([p.hover_omega * (1 + 0.03 * rng.normal(size=4)) for p in params])
    P = np.array([p.pack() for p in params])
    return X, CMD, P, rng.normal(0, 2, (5, 3)), rng.normal(0, 0.01, (5, 3)), \
        rng.normal(0, 1e-5, (5, 3))


def test_batch_step_equals_single_step():
    X, CMD, P, VW, FE, TE = _batch_case()
    singles = X.copy()
    for i in range(5):
        for _ in range(300):
            ph.step(singles[i], CMD[i], P[i], VW[i], FE[i], TE[i], DT)
    batch = X.copy()
    ph.step_batch(batch, CMD, P, VW, FE, TE, DT, n=100)
    for _ in range(200):
        ph.step_batch(batch, CMD, P, VW, FE, TE, DT)
    assert np.array_equal(batch, singles) or np.allclose(batch, singles, rtol=1e-12, atol=1e-12)
    # a shared parameter vector and shared wind broadcast over the batch
    shared = X[[1, 4]].copy()
    ph.step_batch(shared, CMD[[1, 4]], P[1], VW[1], Z3, Z3, DT, n=50)
    one = X[4].copy()
    ph.step_n(one, CMD[4], P[1], VW[1], Z3, Z3, DT, 50)
    assert np.allclose(shared[1], one, rtol=1e-12, atol=1e-12)


def test_kernels_run_without_jit_and_agree():
    """NUMBA_DISABLE_JIT=1 must run the same code (for debugging and coverage)."""
    X, CMD, P, VW, FE, TE = _batch_case()
    expect = X.copy()
    ph.step_batch(expect, CMD, P, VW, FE, TE, DT, n=20)
    inputs = [a.tolist() for a in (X, CMD, P, VW, FE, TE)]
    script = (
        "import json, sys, numpy as np\n"
        "from sim import physics as ph\n"
        "X, *args = [np.array(a) for a in json.loads(sys.stdin.read())]\n"
        "ph.step_batch(X, *args, 1e-3, n=20)\n"
        "print(json.dumps(X.tolist()))\n"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         input=json.dumps(inputs), text=True, timeout=120,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    assert np.allclose(np.array(json.loads(out.stdout)), expect, rtol=1e-11, atol=1e-11)
