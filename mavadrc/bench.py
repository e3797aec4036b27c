"""`mavadrc bench`: per-call step times of the controllers (and, when present, of the vehicle).

Figures are medians over repeated blocks of calls on this machine; peers (pyadrc) are measured
in the same run so ratios stay meaningful on a shared, noisy machine.  Names carry their units.
"""

import json
import math
import statistics
import sys
import time

import numpy as np

from .control import PD, AttitudeController, HanADRC, LinearADRC, PositionController


def per_call_us(fn, calls=2000, repeats=25):
    """Median over ``repeats`` blocks of the mean time of one call, in microseconds."""
    fn()  # compile / warm up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(samples)


def control_figures():
    h = 0.001
    lad = LinearADRC(h=h, b0=1.0, wc=20.0, wo=100.0, u_min=-50.0, u_max=50.0)
    han = HanADRC(h=h, b0=1.0, r0=20.0, r=100.0, c=0.5, h1=10 * h, u_min=-50.0, u_max=50.0)
    pd = PD(h=h, kp=400.0, kd=40.0)
    y = [0.0]

    def step(ctrl):
        def call():
            y[0] = 0.999 * y[0] + 0.001
            ctrl.update(y[0], 1.0, 0.0, 0.0)
        return call

    pos = PositionController("ladrc", h=0.01, hover_thrust=0.5, wc=2.0, wo=10.0)
    pos_han = PositionController("adrc", h=0.01, hover_thrust=0.5, r0=5.0, r=20.0)
    p = np.array([0.1, -0.2, -1.0])
    v = np.zeros(3)
    rp = np.array([0.0, 0.0, -1.0])
    rv = np.zeros(3)
    ra = np.zeros(3)
    att = AttitudeController("ladrc", h=h, inertia=(1.43e-5, 1.43e-5, 2.89e-5), wc=25.0, wo=120.0)
    e = np.array([0.01, -0.02, 0.3])
    w = np.zeros(3)
    er = np.array([0.0, 0.0, 0.3])
    fig = {
        "linear_adrc_step_us": per_call_us(step(lad)),
        "han_adrc_step_us": per_call_us(step(han)),
        "pd_step_us": per_call_us(step(pd)),
        "position_controller_ladrc_step_us": per_call_us(lambda: pos.update(p, v, rp, rv, ra, 0.0)),
        "position_controller_adrc_step_us": per_call_us(
            lambda: pos_han.update(p, v, rp, rv, ra, 0.0)),
        "attitude_controller_ladrc_step_us": per_call_us(lambda: att.update(e, w, er)),
    }
    try:
        import pyadrc
    except ImportError:
        fig["pyadrc_statespace_step_us"] = math.nan
        fig["ratio_pyadrc_over_linear_adrc"] = math.nan
    else:
        peer = pyadrc.StateSpace(order=2, delta=h, b0=1.0, w_cl=20.0, k_eso=5.0,
                                 m_lim=(-50.0, 50.0))
        u = [0.0]

        def peer_call():
            y[0] = 0.999 * y[0] + 0.001
            u[0] = peer(y[0], u[0], 1.0)

        fig["pyadrc_statespace_step_us"] = per_call_us(peer_call)
        fig["ratio_pyadrc_over_linear_adrc"] = (fig["pyadrc_statespace_step_us"]
                                                / fig["linear_adrc_step_us"])
    return fig


def all_figures():
    fig = control_figures()
    try:
        from sim.bench import physics_figures
    except ImportError:
        return fig
    fig.update(physics_figures())
    return fig


def main(as_json=False, out=sys.stdout):
    fig = all_figures()
    if as_json:
        out.write(json.dumps(fig) + "\n")
        return 0
    width = max(len(k) for k in fig)
    for k, v in fig.items():
        out.write(f"{k:<{width}}  {v:12.4g}\n")
    return 0
