"""Speed figures of the bundled vehicle, for `mavadrc bench`.

:func:`physics_figures` returns a dict of medians measured on this machine.  rotorpy, when it
can be imported, is measured in the same run (its Crazyflie, ``Multirotor.step`` at 1 kHz with
motor speed commands) so that the ratio stays meaningful on a shared, noisy machine.
"""

import math
import statistics
import time

import numpy as np

from . import physics as phys
from .batch import BatchVehicles
from .params import load_vehicle
from .vehicle import SimVehicle


def median_us(fn, calls, repeats):
    """Median over ``repeats`` blocks of the mean time per call of ``fn`` (us)."""
    fn()  # compile / warm up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(samples)


def _median_s(fn, repeats):
    fn()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)


def _rotorpy_step_us(calls, repeats):
    """rotorpy's Crazyflie Multirotor.step at 1 kHz (us per step); None if not importable."""
    try:
        from rotorpy.vehicles.crazyflie_params import quad_params
        from rotorpy.vehicles.multirotor import Multirotor
    except ImportError:
        return None
    quad = Multirotor(quad_params)
    state = {k: np.array(v, dtype=float) for k, v in quad.initial_state.items()}
    hover = math.sqrt(quad_params["mass"] * 9.81 / (4.0 * quad_params["k_eta"]))
    control = {"cmd_motor_speeds": np.full(4, hover)}
    box = [state]

    def call():
        box[0] = quad.step(box[0], control, 0.001)

    return median_us(call, calls, repeats)


def physics_figures(quick=False):
    """Benchmark figures of the physics, the vehicle with its firmware and the batch form.

    - ``physics_step_us``: one RK4 step of one Crazyflie, called from Python (median);
    - ``physics_step_compiled_us``: the same inside a compiled loop (``step_n``);
    - ``vehicle_step_us``: one physics step of a SimVehicle with its firmware (attitude mode,
      stepped 10 ms at a time);
    - ``sim_speed_x_realtime``: simulated over wall seconds of a SimVehicle flying a position
      hold (position loop at 100 Hz, inner loop at 1 kHz, no wind);
    - ``batch_physics_vehicle_steps_per_s``: the physics alone, 1000 vehicles in parallel, 10
      steps per call;
    - ``batch_vehicle_steps_per_s``: BatchVehicles with 1000 Crazyflies in attitude mode
      (physics and firmware);
    - ``rotorpy_step_us`` and ``ratio_rotorpy_over_ours`` (rotorpy step over physics_step_us)
      when rotorpy is installed, else None (``mavadrc bench`` says how to install it).
    """
    reps = 5 if quick else 15
    vp = load_vehicle("crazyflie")
    P = vp.pack()
    x = phys.initial_state((0.0, 0.0, -1.0), 0.0, vp.hover_omega)
    cmd = np.full(4, vp.hover_omega)
    z3 = np.zeros(3)
    fig = {}
    fig["physics_step_us"] = median_us(lambda: phys.step(x, cmd, P, z3, z3, z3, 0.001),
                                        2000, reps)
    n = 20000
    fig["physics_step_compiled_us"] = _median_s(
        lambda: phys.step_n(x, cmd, P, z3, z3, z3, 0.001, n), reps) / n * 1e6

    v = SimVehicle("crazyflie", position=(0.0, 0.0, -2.0))
    v.arm()
    v.set_attitude_target([1.0, 0.0, 0.0, 0.0], v.hover_thrust)
    fig["vehicle_step_us"] = median_us(lambda: v.step(0.01), 50, reps) / 10.0

    f = SimVehicle("crazyflie", position=(0.0, 0.0, -2.0))
    f.arm()
    f.set_position_target(pos=(0.5, 0.0, -2.0))
    sim_s = 1.0
    fig["sim_speed_x_realtime"] = sim_s / _median_s(lambda: f.step(sim_s), reps)

    nb = 1000
    X = np.tile(x, (nb, 1))
    cmds = np.tile(cmd, (nb, 1))
    fig["batch_physics_vehicle_steps_per_s"] = nb * 10 / _median_s(
        lambda: phys.step_batch(X, cmds, P, z3, z3, z3, 0.001, 10), reps)

    b = BatchVehicles(nb, "crazyflie", positions=(0.0, 0.0, -2.0))
    b.arm()
    b.set_attitude_targets([1.0, 0.0, 0.0, 0.0], b.hover_thrust)
    steps = 100
    fig["batch_vehicle_steps_per_s"] = nb * steps / _median_s(
        lambda: b.step(steps * b.physics_dt), reps)

    peer = _rotorpy_step_us(50 if quick else 200, reps)
    fig["rotorpy_step_us"] = peer
    fig["ratio_rotorpy_over_ours"] = None if peer is None else peer / fig["physics_step_us"]
    return fig
