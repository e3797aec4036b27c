"""The `mavadrc` command."""

import argparse
import sys


def _bench(args):
    from . import bench

    return bench.main(as_json=args.json, sitl=not args.no_sitl)


def _sitl(args):
    from sim import cli as sim_cli

    return sim_cli.run(args)


def build_parser():
    parser = argparse.ArgumentParser(
        prog="mavadrc",
        description="Disturbance-rejecting offboard control (ADRC, LADRC, PD) for multirotors.")
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bench", help="print per-call step times of the controllers and the vehicle")
    b.add_argument("--json", action="store_true",
                   help="print one JSON object mapping figure names (units in the name) to numbers")
    b.add_argument("--no-sitl", action="store_true",
                   help="skip the MAVLink figures (they start the vehicle as a process, ~25 s)")
    b.set_defaults(func=_bench)
    from sim import cli as sim_cli

    s = sub.add_parser("sitl", help="run the bundled vehicle behind MAVLink, like PX4 SITL")
    sim_cli.add_arguments(s)
    s.set_defaults(func=_sitl)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
