"""`mavadrc identify`: fly the identification and write the input model."""

from mavadrc.cli.fly import draw_figures
from mavadrc.design.identify import (
    failure_text,
    model_yaml,
    partial_text,
    summary_line,
    unidentified_axes,
)
from mavadrc.mission.config import flight_mission


def main(args):
    """``mavadrc identify``: fly the identification and write the input model."""
    import sys
    from pathlib import Path

    from mavadrc.cli.fly import check_bundled, read_key
    from mavadrc.errors import FlightError, LinkError
    from mavadrc.flight.fly import EXIT_INTERRUPTED, Interrupted, UsageError, fly
    from mavadrc.mission.config import load_mission
    from sim.yamlio import ConfigError

    def fail(text, code):
        print(f"mavadrc identify: {text}", file=sys.stderr)
        return code

    try:
        if not 0.3 <= args.altitude <= 100.0:
            raise UsageError(f"--altitude {args.altitude:g}: give 0.3-100 m above the takeoff "
                             "spot")
        mission = load_mission(args.mission)
        if args.connect is None:
            check_bundled(mission)
        m = flight_mission(mission, args.altitude)
        summary, folder = fly(m, connect=args.connect, out=args.out, lockstep=args.lockstep,
                              seed=args.seed, wind=args.wind,
                              progress=not args.quiet, timeout=args.timeout, sysid=args.sysid,
                              signing_key=read_key(args.signing_key))
    except KeyboardInterrupt:
        return fail("interrupted: nothing flew", EXIT_INTERRUPTED)
    except (ConfigError, UsageError) as exc:
        return fail(exc, 2)
    except Interrupted as exc:
        return fail(exc, exc.status)
    except (FlightError, LinkError) as exc:
        return fail(exc, 1)
    except OSError as exc:
        return fail(f"{exc.filename}: {exc.strerror}" if exc.filename else exc, 2)
    if not args.no_figures:
        draw_figures(folder, sys.stdout)
    rec = summary.get("identification")
    if rec is None:
        return fail("the flight ended before the identification was flown: "
                    + "; ".join(summary.get("aborted") or ["see the record"])
                    + f" (record in {folder})", 1)
    if "input_lag" not in rec or unidentified_axes(rec):
        # a file with no model on an axis would fly it on the mission's gains, not the safe ones
        why = failure_text(rec) or partial_text(rec).split(":")[0]
        return fail(f"{why}: {summary_line(rec)} (record in {folder})", 1)
    text = model_yaml(rec, f"mission {Path(mission.source).name}"
                      + (f", {args.connect}" if args.connect else
                         f", bundled {mission.vehicle or 'crazyflie'}"))
    target = Path(args.write) if args.write else Path(folder) / "input_model.yaml"
    target.write_text(text)
    sys.stdout.write(text)
    print(f"written to {target}; the flight {'landed' if summary['landed'] else 'did not land'} "
          f"(record in {folder})")
    return 0 if summary["landed"] else 1
