"""Draw docs/gust_response.png: the bundled x500 holding position through a 1-cosine gust.

The vehicle's own firmware flies (PX4-like position cascade), once with each inner loop: the
PX4-like rate PID and the thesis's LADRC attitude channels.  Panels: the gust and the
acceleration it puts on the vehicle (SimVehicle.true_disturbance), the position deviation, and
the tilt the firmware answers with.

    /tmp/venv/bin/python tools/gust_response.py [--out docs/gust_response.png]
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim.vehicle import SimVehicle  # noqa: E402

GUST = {"type": "gust", "amplitude": 5.0, "direction_from_deg": 0.0, "t_start": 1.0,
        "t_rise": 1.0, "t_hold": 2.0}
HOLD = np.array([0.0, 0.0, -5.0])


def fly(kind, duration=10.0, dt=0.01):
    v = SimVehicle("x500", wind=GUST, attitude_controller=kind, position=HOLD)
    v.arm()
    v.set_position_target(pos=HOLD, yaw=0.0)
    rows = []
    for _ in range(int(round(duration / dt))):
        v.step(dt)
        r = v.reported()
        rows.append((v.time, -v.wind_velocity[0], *(r.position - HOLD), *np.degrees(r.euler[:2]),
                     *v.true_disturbance()))
    return np.array(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "docs"
                                         / "gust_response.png"))
    args = ap.parse_args()
    runs = {"px4 rate PID": fly("px4"), "LADRC attitude": fly("ladrc")}
    fig, ax = plt.subplots(3, 1, figsize=(7.5, 7.0), sharex=True, constrained_layout=True)
    first = next(iter(runs.values()))
    ax[0].plot(first[:, 0], first[:, 1], color="0.3", label="gust: wind from north (m/s)")
    ax[0].plot(first[:, 0], first[:, 7], color="tab:red",
               label="true disturbance, north (m/s$^2$)")
    ax[0].set_ylabel("wind / accel.")
    ax[0].legend(loc="upper right", fontsize=8)
    for (name, d), color in zip(runs.items(), ("tab:blue", "tab:green")):
        ax[1].plot(d[:, 0], 100.0 * d[:, 2], color=color, label=f"north, {name}")
        ax[1].plot(d[:, 0], 100.0 * -d[:, 4], color=color, ls="--", label=f"altitude, {name}")
        ax[2].plot(d[:, 0], d[:, 6], color=color, label=f"pitch, {name}")
    ax[1].set_ylabel("deviation (cm)")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].set_ylabel("pitch (deg)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(loc="upper right", fontsize=8)
    peak = max(np.abs(d[:, 2]).max() for d in runs.values())
    ax[0].set_title("x500 holding position, PX4-like position loop, 5 m/s 1-cosine gust "
                    f"(peak drift {100 * peak:.0f} cm)", fontsize=10)
    for a in ax:
        a.grid(alpha=0.3)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
