"""`mavadrc fly`: fly a mission, print its table, draw its figures."""
import contextlib
import sys
import time

from mavadrc.design.identify import needs_design_lag
from mavadrc.errors import FlightError, LinkError, UsageError, os_error_text
from mavadrc.flight.console import guarded, interrupt_exit_status, interrupt_word, ticking
from mavadrc.flight.fly import Interrupted, fly, interrupt_status, interrupted
from mavadrc.flight.summary import print_table
from mavadrc.mission.config import load_mission
from sim.yamlio import ConfigError


def draw_figures(folder, stream):
    """The record's figures, from whatever the flight logged; a flight that logged nothing to
    draw is said so, not a traceback."""
    try:
        from mavadrc.study.figures import plot_record
    except ImportError as exc:
        stream.write(f"figures skipped: {exc}\n")
        return
    try:
        plot_record(folder)
    except (ValueError, OSError) as exc:
        stream.write(f"figures skipped: {exc}\n")



def main(args):
    # guarded: an output that fails (a closed pipe, a terminal hung up) never ends a flight nor
    # turns its end into a traceback
    out, err = guarded(sys.stdout), guarded(sys.stderr)
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            return _main(args)
        except KeyboardInterrupt as exc:  # before the flight could answer it: nothing flew
            print(f"\nmavadrc fly: {interrupt_word(exc)}: nothing flew", file=sys.stderr)
            return interrupt_exit_status(exc)



def _main(args):
    try:
        mission = load_mission(args.mission)
        if args.wind is not None:
            from sim.wind import load_wind
            load_wind(args.wind)
        if args.connect is None:
            check_bundled(mission)
        lag = found_design_lag(mission, args.controller)
        summary, folder = fly(mission, connect=args.connect, kind=args.controller, out=args.out,
                              lockstep=args.lockstep, seed=args.seed, wind=args.wind,
                              progress=not args.quiet,
                              timeout=args.timeout, takeover=args.takeover, sysid=args.sysid,
                              signing_key=read_key(args.signing_key), design_lag=lag)
    except (ConfigError, UsageError) as exc:
        print(f"mavadrc fly: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"mavadrc fly: {os_error_text(exc)}", file=sys.stderr)
        return 2
    except Interrupted as exc:
        print(f"\nmavadrc fly: {exc}", file=sys.stderr)
        return exc.status
    except (FlightError, LinkError) as exc:
        print(f"\nmavadrc fly: {exc}", file=sys.stderr)
        return 1
    if not args.no_figures:
        draw_figures(folder, sys.stdout)
    print_table(summary)
    if summary["landed"]:
        state = (f"landed (touchdown {summary['touchdown_speed_mps']:.2f} m/s) and disarmed"
                 if summary.get("touchdown_speed_mps") is not None else "landed and disarmed")
        refused = (summary.get("disarm") or {}).get("refused_s")
        if refused is not None:
            state += f" by its land mode (the disarm refused for {refused:.1f} s)"
    elif summary["touchdown_seen"] and not summary["touchdown_soft"]:
        state = (f"touched down hard ({summary['touchdown_speed_mps']:.2f} m/s)"
                 + (" and disarmed" if summary["disarmed"] else ""))
    else:
        state = "ended: " + "; ".join(summary["aborted"] or ["not seen to land and disarm"])
        state += f"; last known: {summary['last_known_state']}"
    print(f"  {summary['duration_s']:.1f} s, {state}; record in {folder}")
    if interrupted(summary):
        return interrupt_status(summary)
    return 0 if summary["landed"] else 1



def check_bundled(mission):
    """A mission flown on the bundled vehicle must name the vehicle flown: ``vehicle: {mass,
    max_thrust}`` or ``{hover_thrust}`` describe a real vehicle's (for --connect), and the
    bundled vehicle would fly the Crazyflie whatever they say."""
    if mission.vehicle is None and (mission.mass is not None or mission.hover_thrust is not None):
        given = ("mass and max_thrust" if mission.mass is not None else "hover_thrust")
        raise UsageError(
            f"{mission.source}: vehicle: {{{given}}} describes a real vehicle flown with "
            "--connect; the bundled vehicle flies a vehicle file: name one (vehicle: crazyflie, "
            "x500, quad2kg, ... in configs/vehicles, or a path to your own)")



def read_key(path):
    """The 32-byte signing secret of a --signing-key file (64 hex characters), or None."""
    if path is None:
        return None
    from sim.mavlink.link import read_signing_key

    try:
        return read_signing_key(path)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"--signing-key {path}: {exc.strerror or exc}") from None


def found_design_lag(mission, kind=None):
    """:func:`~mavadrc.fast.identify.flight_design_lag`, said when finding it took long (the
    kernels compiled once), before anything is sent."""
    if not needs_design_lag(mission.controller, kind):
        return None
    # only now: the fast path loads the simulator's compiled kernels (seconds on a first run),
    # which a flight that needs no design lag never uses
    from mavadrc.fast.identify import flight_design_lag

    t0 = time.perf_counter()
    with ticking(print, "finding the lag the mission's gains were chosen for: its vehicle file "
                 "flown in process, the kernels compiling on a first run"):
        lag = flight_design_lag(mission, kind)
    took = time.perf_counter() - t0
    if lag is not None and took > 2.0:
        print(f"the lag the mission's gains were chosen for: {lag[0]:.3f} s horizontally, its "
              f"vehicle file identified in process ({took:.0f} s: the kernels compiled once)")
    return lag
