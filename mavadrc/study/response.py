"""The autopilot's attitude response measured from a flight record: ``mavadrc response FOLDER``.

The observers' input model (:mod:`mavadrc.design.identify`) is fitted to the velocity the doublets
produce, so it is weighted towards the frequencies the doublets excite (below 1 Hz).  A loop
swinging faster than that is shaped by what the autopilot does there, which the fit
extrapolates.  This reads what the flight's own tlog holds, with no model of the vehicle:

* the roll and pitch the companion commanded (controller.csv), each timed by the sample it
  answered, and
* the roll and pitch the autopilot reported (the tlog's ATTITUDE frames, by their time_boot_ms),

both on the vehicle's clock (the response from a sample to the attitude, as the loop closes it
and the identification fits it), resampled on one grid over the airborne part of the flight,
and gives per frequency the gain and phase of reported over commanded (Welch's cross-spectrum
over the commanded spectrum) and their coherence.  Beside them it prints what the identified
model (its two lags after the dead time; the acceleration follows the tilt) says at the same
frequency, so where the two part is seen at once.  On PX4 SIH the model matched the measured
phase to 1-4 degrees below 1 Hz and was 8-15 degrees short of it at 1.3-2 Hz (29 at 2.5).
"""

import json
import math
from pathlib import Path

import numpy as np

#: frequencies reported (Hz)
FREQUENCIES = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5)
#: the grid both streams are resampled on (Hz) and Welch's segment (s)
GRID_HZ = 100.0
SEGMENT_S = 10.24
#: a setpoint below this thrust (normalised) is on the ground or cut: not part of the window
AIRBORNE_THRUST = 0.15


def read_attitudes(folder, summary):
    """(commanded, reported): arrays of rows (time s, roll, pitch; rad) of the flight in
    ``folder``, both on the vehicle's clock: the attitude the controller commanded at each step
    while airborne (controller.csv; thrust at least :data:`AIRBORNE_THRUST`), timed by the
    sample it answered, and the ATTITUDE frames the autopilot sent (flight.tlog), timed by their
    ``time_boot_ms`` (``summary``: the flight's summary.json, for its mission's start).  The
    response between them is the one the loop closes through, from the sample to the attitude
    (as the identification times its fit; in lockstep too, where the tlog's wall-clock stamps
    run fast)."""
    from pymavlink import mavutil

    from mavadrc.control.rotations import quats_to_euler
    from mavadrc.flight.record import read_table
    folder = Path(folder)
    t0 = summary.get("mission_start_s")
    if t0 is None:
        raise ValueError(f"{folder / 'summary.json'}: the mission never started (no "
                         "mission_start_s)")
    tab = read_table(folder / "controller.csv")
    t = np.asarray(tab["t"], dtype=float) + float(t0)
    q = np.column_stack([np.asarray(tab[c], dtype=float) for c in ("q_w", "q_x", "q_y", "q_z")])
    keep = (np.asarray(tab["thrust"], dtype=float) >= AIRBORNE_THRUST) & np.isfinite(q).all(1)
    euler = np.empty((int(keep.sum()), 3))
    quats_to_euler(np.ascontiguousarray(q[keep]), euler)
    cmd = np.column_stack([t[keep], euler[:, :2]])
    m = mavutil.mavlink_connection(str(folder / "flight.tlog"), dialect="common")
    rep = []
    while True:
        msg = m.recv_match(type="ATTITUDE")
        if msg is None:
            break
        rep.append((msg.time_boot_ms / 1000.0, float(msg.roll), float(msg.pitch)))
    rep = sorted(set(rep))  # each frame once, in time order
    return cmd, np.array(rep).reshape(-1, 3)


def frequency_response(cmd, rep, freqs=FREQUENCIES):
    """Per axis (roll, pitch) and frequency the response of ``rep`` to ``cmd`` (rows of time,
    roll, pitch, as :func:`read_attitudes` gives): a dict ``{"roll": [...], "pitch": [...]}`` of
    ``{"hz", "gain", "phase_deg", "coherence"}``, over the span the commands cover (their
    gaps, a landing between two flights, are bridged by the interpolation).  None when less
    than two Welch segments of both are there."""
    from scipy import signal
    if len(cmd) < 2 or len(rep) < 2:
        return None
    t0, t1 = max(cmd[0, 0], rep[0, 0]), min(cmd[-1, 0], rep[-1, 0])
    if t1 - t0 < 2.0 * SEGMENT_S:
        return None
    grid = np.arange(t0, t1, 1.0 / GRID_HZ)
    n = int(round(SEGMENT_S * GRID_HZ))
    out = {}
    for col, name in ((1, "roll"), (2, "pitch")):
        u = np.interp(grid, cmd[:, 0], cmd[:, col])
        y = np.interp(grid, rep[:, 0], rep[:, col])
        u, y = u - u.mean(), y - y.mean()
        f, puu = signal.welch(u, GRID_HZ, nperseg=n)
        _, puy = signal.csd(u, y, GRID_HZ, nperseg=n)
        _, coh = signal.coherence(u, y, GRID_HZ, nperseg=n)
        rows = []
        for hz in freqs:
            i = int(np.argmin(np.abs(f - hz)))
            h = puy[i] / puu[i] if puu[i] > 0.0 else complex("nan")
            rows.append({"hz": float(f[i]), "gain": float(abs(h)),
                         "phase_deg": float(np.degrees(np.angle(h))),
                         "coherence": float(coh[i])})
        out[name] = rows
    return out


def model_response(fit, hz, order=2):
    """(gain, phase in degrees) of an identified axis (``tau_s``, ``delay_s``: :mod:`mavadrc.
    identify`'s record) at ``hz``: ``order`` equal lags after the dead time, unit gain."""
    w = 2.0 * math.pi * hz
    h = np.exp(-1j * w * fit["delay_s"]) / (1.0 + 1j * w * fit["tau_s"]) ** order
    return float(abs(h)), float(np.degrees(np.angle(h)))


def analyse(folder, freqs=FREQUENCIES):
    """The record of a flight folder: ``{"response": ..., "model": per axis x/y the identified
    model's (gain, phase) at each frequency, or None}``."""
    from mavadrc.design.identify import ORDER
    folder = Path(folder)
    for name in ("flight.tlog", "controller.csv", "summary.json"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder / name}: not found (give a flight record folder)")
    summary = json.loads((folder / "summary.json").read_text())
    cmd, rep = read_attitudes(folder, summary)
    resp = frequency_response(cmd, rep, freqs)
    axes = (summary.get("identification") or {}).get("axes") or {}
    # roll tilts the vehicle east (y), pitch north (x); each axis's model at the bins measured
    model = {name: [model_response(axes[ax], r["hz"], ORDER) for r in resp[name]]
             for name, ax in (("roll", "y"), ("pitch", "x"))
             if resp is not None and "tau_s" in axes.get(ax, {})} or None
    return {"commanded": int(len(cmd)), "reported": int(len(rep)), "response": resp,
            "model": model}


def table(result):
    """The analysis as text lines."""
    lines = [f"{result['commanded']} attitude setpoints sent airborne, {result['reported']} "
             "ATTITUDE reports received"]
    if result["response"] is None:
        lines.append(f"too short to measure: need {2 * SEGMENT_S:g} s of both streams")
        return lines
    for name, rows in result["response"].items():
        model = (result["model"] or {}).get(name)
        head = f"{name}: Hz    gain  phase  coherence"
        lines.append(head + ("   model gain  phase" if model else ""))
        for k, r in enumerate(rows):
            line = (f"  {r['hz']:8.2f} {r['gain']:6.2f} {r['phase_deg']:6.0f} "
                    f"{r['coherence']:10.2f}")
            if model:
                g, p = model[k]
                line += f"   {g:10.2f} {p:6.0f}"
            lines.append(line)
    return lines


def main(args):
    """``mavadrc response FOLDER``."""
    import sys
    try:
        result = analyse(args.folder)
    except (OSError, ValueError) as exc:
        print(f"mavadrc response: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print("\n".join(table(result)))
    return 0
