"""`mavadrc fly MISSION.yaml`: load, connect (or start the bundled vehicle), fly, record, report."""

import datetime
import sys
from pathlib import Path

from sim.yamlio import ConfigError

from .flight import Flight, FlightError, print_table
from .link import Link, LinkError
from .mission import load_mission
from .record import FlightRecord


def record_folder(out, mission, kind):
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S-%f")[:-3]
    return Path(out) / f"{stamp}-{Path(mission.source).stem}-{kind}"


def fly(mission, *, connect=None, kind=None, out=None, lockstep=False, seed=None, wind=None,
        figures=True, progress=True, timeout=None, stream=sys.stdout, start_at=None):
    """Fly ``mission`` (a :class:`~mavadrc.mission.Mission`); returns (summary, record folder)."""
    kind = kind or mission.controller.kind
    folder = record_folder(out or mission.out, mission, kind)
    rec = FlightRecord(folder, mission.text)
    vehicle = None
    link = None
    summary = None
    try:
        if connect is None:
            from .embedded import EmbeddedVehicle
            vehicle = EmbeddedVehicle(mission, lockstep=lockstep,
                                      rate_hz=mission.controller.rate_hz, workdir=folder,
                                      seed=seed, wind=wind, log_path=folder / "vehicle.log")
            url = vehicle.url
            stream.write(f"started the bundled vehicle ({mission.vehicle or 'crazyflie'}, "
                         f"{mission.autopilot}{', lockstep' if lockstep else ''})\n")
        else:
            if lockstep:
                raise FlightError("--lockstep needs the bundled vehicle (no --connect)")
            url = connect
        link = Link(url, tlog=rec.tlog)
        flight = Flight(mission, link, rec, kind=kind, progress=progress, out=stream,
                        max_wall_s=timeout, lockstep=lockstep and connect is None,
                        heartbeat_timeout=15.0 if vehicle is None else 120.0,
                        start_at=start_at)
        summary = flight.run()
    finally:
        if link is not None:
            link.close()
        if vehicle is not None:
            vehicle.stop()
        rec.close()
    if figures:
        try:
            from .figures import plot_record
            plot_record(folder)
        except ImportError:
            pass
    return summary, folder


def main(args):
    try:
        mission = load_mission(args.mission)
    except (ConfigError, OSError) as exc:
        print(f"mavadrc fly: {exc}", file=sys.stderr)
        return 2
    try:
        summary, folder = fly(mission, connect=args.connect, kind=args.controller, out=args.out,
                              lockstep=args.lockstep, seed=args.seed, wind=args.wind,
                              figures=not args.no_figures, progress=not args.quiet,
                              timeout=args.timeout)
    except (FlightError, LinkError) as exc:
        print(f"\nmavadrc fly: {exc}", file=sys.stderr)
        return 1
    print_table(summary)
    state = "landed and disarmed" if summary["landed"] else (
        f"ended: {summary['aborted']}" if summary["aborted"] else "not disarmed")
    print(f"  {summary['duration_s']:.1f} s, {state}; record in {folder}")
    return 0 if summary["landed"] else 1
