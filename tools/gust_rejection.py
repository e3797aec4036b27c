"""What each controller of configs/experiments/gusts.yaml lets through of a disturbance, frequency
by frequency, and where the gusts put their power.

For each controller of gusts.yaml (its gains and input model; the oracle: its PD law with the
disturbance itself fed forward), and any controller file ``mavadrc tune`` wrote (``--also``),
the horizontal channel closed around the vehicle's measured response (a first-order lag of the
63 % time of :func:`sim.vehicle.response_time_constants`) gives |G_d(jw)|, the position error in
metres per m/s^2 of disturbance acceleration (:func:`mavadrc.design.margin.disturbance_response`), and
the delay margin on that plant.  The disturbance's spectrum is measured on the fast path: the
simulator's true disturbance acceleration (x and y) hovering in the gust scenarios' wind, wind
seeds 1000+ (not those the experiment reports).

    python tools/gust_rejection.py [--vehicle crazyflie] [--seeds 3] [--also ladrc.yaml ...]
"""

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.signal import welch

from mavadrc.study.experiment import load_experiment, run_inprocess
from mavadrc.design.gains import make_controller
from mavadrc.fast.inprocess import L_DIST, L_T
from mavadrc.design.margin import delay_margin, disturbance_response
from mavadrc.mission.config import read_controller
from sim.vehicle import response_time_constants
from sim.yamlio import Section, load_yaml

ROOT = Path(__file__).resolve().parent.parent
SHOWN = (0.3, 1.0, 2.0, 4.0, 8.0)  # rad/s


def disturbance_power(exp, vehicle, seeds):
    """(w rad/s, share of the horizontal disturbance's variance below w), hovering in the
    vehicle's gust scenarios after settling, over ``seeds``; and its RMS (m/s^2)."""
    j = [c.name for c in exp.controllers].index("PID")
    psds, rms = [], []
    for i, sc in enumerate(exp.scenarios):
        if sc.mission.vehicle != vehicle or "hover" not in sc.name:
            continue
        for seed in seeds:
            _, log = run_inprocess(exp, i, j, seed, keep_log=True)
            keep = log[:, L_T] >= sc.settle_s
            d = log[keep, L_DIST:L_DIST + 2]
            d = d - d.mean(axis=0)
            f, p = welch(d, fs=1.0 / float(np.median(np.diff(log[keep, L_T]))),
                         nperseg=min(4096, len(d)), axis=0)
            psds.append(p.sum(axis=1))
            rms.append(float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))))
    psd = np.mean(psds, axis=0)
    return 2.0 * math.pi * f, np.cumsum(psd) / psd.sum(), float(np.mean(rms))


def controllers(exp, also):
    """[(name, spec, oracle)] of the experiment and the controller files ``also``."""
    out = []
    for c in exp.controllers:
        oracle = c.kind == "oracle"
        out.append((c.name, dataclasses.replace(c.spec, kind="pd") if oracle else c.spec, oracle))
    for path in also:
        spec = read_controller(Section(load_yaml(path), str(path)))
        out.append((f"{spec.name or spec.kind} ({Path(path).name})", spec, False))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicle", default="crazyflie", choices=("crazyflie", "x500"))
    ap.add_argument("--seeds", type=int, default=3, help="wind seeds 1000.. for the spectrum")
    ap.add_argument("--also", nargs="*", default=[], help="controller files (mavadrc tune --out)")
    args = ap.parse_args(argv)
    exp = load_experiment(ROOT / "configs" / "experiments" / "gusts.yaml")
    tau = response_time_constants(args.vehicle)[0]
    w, share, rms = disturbance_power(exp, args.vehicle, range(1000, 1000 + args.seeds))
    quartiles = [w[np.searchsorted(share, q)] for q in (0.5, 0.9, 0.99)]
    print(f"{args.vehicle}: horizontal response 63 % at {tau:.3f} s; the gusts' disturbance "
          f"{rms:.2f} m/s^2 RMS (x and y, hovering), half its variance below "
          f"{quartiles[0]:.2f} rad/s, 90 % below {quartiles[1]:.2f}, 99 % below "
          f"{quartiles[2]:.2f}")
    print("| controller | " + " | ".join(f"{x:g} rad/s" for x in SHOWN)
          + " | delay margin (ms) |")
    print("|---|" + "---|" * (len(SHOWN) + 1))
    for name, spec, oracle in controllers(exp, args.also):
        ctrl = make_controller(spec, hover_thrust=0.5, vehicle=args.vehicle)
        g = disturbance_response(ctrl, SHOWN, tau=tau, feedforward=oracle)
        margin = "" if oracle else f"{1e3 * delay_margin(ctrl, tau=tau):.0f}"
        print(f"| {name} | " + " | ".join(f"{x:.4f}" for x in g) + f" | {margin} |")


if __name__ == "__main__":
    main()
