"""`mavadrc fly MISSION.yaml`: load, connect (or start the bundled vehicle), fly, record, report.

Exit status: 0 when the vehicle took off, flew the mission, was seen to touch down and was seen
disarmed, with nothing cut short; 1 when the flight did not start or ended any other way (the
reasons and the vehicle's last known state are printed and in summary.json); 2 for a bad mission
file or option, before anything is sent to a vehicle; 130 (as shells expect of Ctrl-C) when the
user interrupted it (in the air: after the hold and landing that follow).

A flight that never heard an autopilot (no heartbeat, or Ctrl-C while waiting for one) flew
nothing and leaves no record folder behind; one whose bundled vehicle died at start keeps its
folder, with the vehicle's ``vehicle.log`` and a ``summary.json`` that says why.
"""

import dataclasses
import datetime
import math
import shutil
import signal
import sys
from pathlib import Path

from mavadrc.errors import LinkError, UsageError
from mavadrc.flight.console import (
    EXIT_INTERRUPTED,
    FlightSignals,
    guarded,
    interrupt_exit_status,
    interrupt_word,
)
from mavadrc.flight.flight import Flight
from mavadrc.flight.record import FlightRecord
from mavadrc.mavlink.link import Link
from mavadrc.mavlink.transport import parse_url


class Interrupted(Exception):
    """Ctrl-C (or SIGTERM) before an autopilot was heard: nothing flew (exit 130, or 128 plus
    the signal's number: ``status``)."""

    def __init__(self, text, status=None):
        super().__init__(text)
        self.status = EXIT_INTERRUPTED if status is None else status




def check_options(*, connect=None, lockstep=False, seed=None, wind=None, timeout=None,
                  sysid=None, out=None):
    """Every option of a flight checked before anything starts: raises :class:`UsageError`
    naming the option and what it must be."""
    if connect is not None:
        if lockstep:
            raise UsageError("--lockstep needs the bundled vehicle (no --connect)")
        try:
            parse_url(connect)
        except LinkError as exc:
            raise UsageError(f"--connect {exc}") from None
        for name, value in (("--seed", seed), ("--wind", wind)):
            if value is not None:
                raise UsageError(f"{name} sets the bundled vehicle's wind: it means nothing with "
                                 "--connect")
    if seed is not None and not 0 <= seed < 2 ** 32:
        raise UsageError(f"--seed {seed}: must be 0 to {2 ** 32 - 1}")
    if timeout is not None and not timeout > 0:
        raise UsageError(f"--timeout {timeout:g}: must be a positive number of seconds")
    if sysid is not None and not 1 <= sysid <= 255:
        raise UsageError(f"--sysid {sysid}: a MAVLink system id is 1 to 255")
    if out is not None:
        check_out_folder(out, "--out")


def check_out_folder(out, option="--out"):
    """``out`` is a folder, or can be made one: not a file, nor under one."""
    p = Path(out)
    for q in (p, *p.parents):
        if q.exists():
            if not q.is_dir():
                what = "is a file" if q == p else f"is under {q}, a file"
                raise UsageError(f"{option} {out}: {what}, not a folder")
            return


def record_folder(out, mission, kind):
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S-%f")[:-3]
    return Path(out) / f"{stamp}-{Path(mission.source).stem}-{kind}"


def real_vehicle_notices(mission):
    """With --connect the bundled vehicle's keys mean nothing: which are ignored, and the hover
    thrust the flight takes from the mission (None: the autopilot's parameter)."""
    notes = []
    if mission.vehicle is not None:
        notes.append(f"vehicle: {mission.vehicle} names a bundled vehicle: ignored with --connect "
                     "(its hover thrust too; the autopilot's own is read)")
    if mission.wind is not None:
        notes.append("wind: ignored with --connect (the bundled vehicle's wind)")
    if mission.sim_given:
        notes.append("sim: ignored with --connect (the bundled vehicle's settings)")
    hover = None if mission.vehicle is not None else mission.hover_thrust
    return notes, hover


def fly(mission, *, connect=None, kind=None, out=None, lockstep=False, seed=None, wind=None,
        progress=True, timeout=None, stream=None, start_at=None,
        takeover=False, sysid=None, signing_key=None, design_lag=None):
    """Fly ``mission`` (a :class:`~mavadrc.mission.config.Mission`); returns (summary, record folder).

    ``design_lag``: the lags (s per axis) the mission's own gains were chosen for, when it
    identifies its vehicle (:func:`mavadrc.fast.identify.flight_design_lag` computes them before
    the flight; None: its gains fly as given once identified).

    Raises :class:`UsageError` before anything is sent when the mission or an option cannot be
    flown, and :class:`FlightError` / :class:`LinkError` when the flight could not start (the
    record, summary.json included, is written either way)."""
    # guarded: a console that fails (a closed pipe, a terminal hung up) never ends a flight
    stream = guarded(stream if stream is not None else sys.stdout)
    kind = kind or mission.controller.kind
    hover, source = mission.hover_thrust, mission.hover_source
    check_options(connect=connect, lockstep=lockstep, seed=seed, wind=wind, timeout=timeout,
                  sysid=sysid, out=out)
    if lockstep and connect is None and mission.clock_rate != 1.0:
        raise UsageError(f"--lockstep: the mission's sim.clock_rate ({mission.clock_rate:g}) is "
                         "for real time; in lockstep the setpoints are the vehicle's clock")
    # the mission as flown: every override applied (the record holds this one)
    mission = dataclasses.replace(mission, seed=mission.seed if seed is None else seed,
                                  wind=mission.wind if wind is None else wind)
    if connect is not None:
        notes, hover = real_vehicle_notices(mission)
        for n in notes:
            stream.write(f"note: {n}\n")
    folder = record_folder(out or mission.out, mission, kind)
    rec = FlightRecord(folder, mission.text)
    stream = guarded(stream, rec.note)  # what the console cannot say goes to companion.log
    vehicle = None
    link = None
    summary = None
    url = connect
    flying = []  # the flight, once there is one (a SIGHUP is noted in its record)
    signals = FlightSignals(on_hangup=lambda: flying and flying[0].hung_up())
    try:
        signals.install()
        if connect is None:
            from mavadrc.flight.embedded import EmbeddedVehicle
            vehicle = EmbeddedVehicle(mission, lockstep=lockstep,
                                      rate_hz=mission.controller.rate_hz, workdir=folder,
                                      seed=seed, wind=wind, log_path=folder / "vehicle.log",
                                      signing_key=signing_key)
            url = vehicle.url
            stream.write(f"started the bundled vehicle ({mission.vehicle or 'crazyflie'}, "
                         f"{mission.autopilot}{', lockstep' if lockstep else ''})\n")
        link = Link(url, tlog=rec.tlog, signing_key=signing_key, sysid=sysid)
        flight = Flight(mission, link, rec, kind=kind, progress=progress, out=stream,
                        max_wall_s=timeout, lockstep=lockstep and connect is None,
                        heartbeat_timeout=15.0 if vehicle is None else 120.0,
                        start_at=start_at, takeover=takeover, hover_thrust=hover,
                        hover_source=source, bundled=True if vehicle is not None else None,
                        watchdog=vehicle.check if vehicle is not None else None,
                        design_lag=design_lag)
        flight.context = run_context(mission, kind, connect, lockstep)
        flying.append(flight)
        if kind == "native" and kind != mission.controller.kind:
            stream.write(f"note: --controller native: the autopilot's own position controller "
                         f"flies the reference (the mission's {mission.controller.kind} gains do "
                         "not apply)\n")
        elif kind != mission.controller.kind:
            stream.write(f"note: --controller {kind}: the mission's {mission.controller.kind} "
                         f"gains do not apply; flying {kind}'s defaults (summary.json: "
                         "controller_flown)\n")
        try:
            summary = flight.run()
        finally:
            if flight.summary is not None:
                try:
                    write_effective(folder, mission, flight.summary, bundled=connect is None)
                except OSError as exc:  # a full disk: the flight is flown, its record as it is
                    stream.write(f"effective.yaml could not be written ({exc.strerror or exc})\n")
    except KeyboardInterrupt as exc:
        summary = None  # before the flight could answer it: nothing was heard, nothing flew
        raise Interrupted(f"{interrupt_word(exc)}{f' while waiting for {url}' if url else ''}"
                          ": nothing flew", interrupt_exit_status(exc)) from None
    finally:
        signals.restore()
        heard = link is not None and link.heartbeat is not None
        died = vehicle is not None and vehicle.proc.poll() is not None
        if link is not None:
            link.close()
        if vehicle is not None:
            vehicle.stop()
        rec.close()
        if not heard and not died:
            # no autopilot ever answered: nothing flew, and a folder of empty files would only
            # hide the records of real flights
            shutil.rmtree(folder, ignore_errors=True)
    if not heard and interrupted(summary):
        raise Interrupted(f"{interrupted(summary)} while waiting for an autopilot's heartbeat "
                          f"on {url}: nothing flew, no record kept", interrupt_status(summary))
    return summary, folder


def versions():
    """The versions that decide a flight's numbers."""
    import platform
    from importlib import metadata

    from mavadrc import __version__

    out = {"mavadrc": __version__, "python": platform.python_version()}
    for name in ("pymavlink", "numpy", "numba"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def run_context(mission, kind, connect, lockstep):
    """What summary.json keeps of how the flight was made besides the controller: the command
    line, the versions, and the mission's settings after every override."""
    config = {"mission_file": str(mission.source), "controller": kind,
              "controller_replaced": kind != mission.controller.kind}
    if connect is None:
        wind = mission.wind
        config.update(vehicle=mission.vehicle or "crazyflie", seed=mission.seed,
                      wind=str(wind) if isinstance(wind, Path) else wind,
                      autopilot=mission.autopilot,
                      attitude_controller=mission.attitude_controller, noise=mission.noise,
                      wander=mission.wander, wander_corner_hz=mission.wander_corner_hz,
                      sensor_latency_s=mission.sensor_latency_s,
                      height_drift_mps=mission.height_drift_mps,
                      ground_climb_mps=mission.ground_climb_mps,
                      rangefinder=mission.rangefinder,
                      clock_rate=mission.clock_rate,
                      link=None if mission.link is None else mission.link.as_dict(),
                      heading_deg=("random" if math.isnan(mission.heading_deg)
                                   else mission.heading_deg),
                      lockstep=bool(lockstep))
    else:
        config.update(connect=connect)
    return {"command_line": list(sys.argv), "versions": versions(), "config": config}


def write_effective(folder, mission, summary, bundled):
    """effective.yaml beside mission.yaml: the mission with every override applied (the
    controller flown with its gains resolved; the bundled vehicle's seed and wind), so
    ``mavadrc fly FOLDER/effective.yaml --lockstep`` flies the same flight again.  Skipped for
    a mission that is not a file of its own (an experiment's run)."""
    import yaml

    controller = summary.get("controller_flown")
    if controller is None or not Path(folder).is_dir():
        return
    try:
        doc = yaml.safe_load(mission.text)
    except yaml.YAMLError:
        return
    if not isinstance(doc, dict) or "trajectory" not in doc:
        return
    doc["controller"] = controller
    for item in doc["trajectory"] if isinstance(doc["trajectory"], list) else []:
        # a trajectory file is read from the mission's folder: from the record's, it is named
        # by its full path
        spec = item.get("file") if isinstance(item, dict) else None
        if isinstance(spec, dict) and isinstance(spec.get("path"), str):
            spec["path"] = str((Path(mission.source).parent / spec["path"]).resolve())
    if bundled:
        sim = doc.get("sim") if isinstance(doc.get("sim"), dict) else {}
        doc["sim"] = {**sim, "seed": int(mission.seed)}
        wind = mission.wind
        if isinstance(wind, (str, Path)) and Path(wind).is_file():
            wind = str(Path(wind).resolve())
        if wind is not None:
            from mavadrc.flight.embedded import plain

            doc["wind"] = plain(wind)
    head = (f"# {Path(mission.source).name} as flown: every override applied, the controller's "
            "gains resolved\n")
    (Path(folder) / "effective.yaml").write_text(head + yaml.safe_dump(doc, sort_keys=False,
                                                                      default_flow_style=None))


def interrupted(summary):
    """How the flight of ``summary`` was interrupted ('interrupted': the user's Ctrl-C;
    'terminated by SIGTERM'), or None if it was not."""
    for why in (summary or {}).get("aborted") or []:
        if why == "interrupted by the user":
            return "interrupted"
        if why.startswith("terminated by SIG"):
            return why
    return None


def interrupt_status(summary):
    """The exit status of a flight ``interrupted`` (130 for Ctrl-C, 128 plus the signal's
    number for a signal, as shells report them); None if it was not."""
    why = interrupted(summary)
    if why is None:
        return None
    if why.startswith("terminated by "):
        return 128 + int(getattr(signal, why.split()[-1]))
    return EXIT_INTERRUPTED



