"""The `mavadrc` command."""

import argparse
import sys


def _bench(args):
    from mavadrc.study import bench

    return bench.main(as_json=args.json, sitl=not args.no_sitl, compare=not args.no_compare,
                      compare_seeds=args.compare_seeds, progress=not args.quiet)


def _sitl(args):
    from sim import cli as sim_cli

    return sim_cli.run(args)


def _fly(args):
    from mavadrc.cli import fly

    return fly.main(args)


def _response(args):
    from mavadrc.study.response import main as response_main
    return response_main(args)


def _identify(args):
    from mavadrc.cli import identify

    return identify.main(args)


def _compare(args):
    from mavadrc.study import compare, sitl_runs

    if sitl_runs.wants_sitl(args):
        return sitl_runs.main(args)
    if args.via is None:
        args.via = "inprocess"
    return compare.main(args)


def _tune(args):
    from mavadrc.study import tune

    return tune.main(args)


def _plot(args):
    from mavadrc.study import figures

    figures.main(args.target, args.out)
    return 0


def flight_options(p):
    """The options of a flight (``fly``, ``identify``): records, the bundled vehicle's, the
    wall clock, which autopilot, signing, quiet."""
    p.add_argument("--out", default=None, help="folder for the flight records (default: runs/)")
    p.add_argument("--lockstep", action="store_true",
                   help="bundled vehicle only: run as fast as the machine allows, deterministically")
    p.add_argument("--seed", type=int, default=None, help="bundled vehicle's wind/noise seed")
    p.add_argument("--wind", default=None, help="bundled vehicle's wind (overrides the mission)")
    p.add_argument("--no-figures", action="store_true", help="do not draw the PNG figures")
    p.add_argument("--timeout", type=float, default=None,
                   help="wall-clock seconds for the whole flight, every phase included: past "
                        "them the vehicle is landed, and the landing itself is bounded")
    p.add_argument("--sysid", type=int, default=None,
                   help="fly the autopilot with this system id (default: the first heard)")
    p.add_argument("--signing-key", default=None, metavar="FILE",
                   help="MAVLink 2 signing: the 32-byte secret as 64 hex characters; "
                        "everything sent is signed and everything received must be (the bundled "
                        "vehicle is started with the same key)")
    p.add_argument("-q", "--quiet", action="store_true", help="no live progress line")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="mavadrc",
        description="Disturbance-rejecting offboard control (ADRC, LADRC, PD, PID) for "
                    "multirotors over MAVLink, with a bundled simulated vehicle.")
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name, help, description=None):
        # the line in mavadrc --help, and (unless a longer one is given) mavadrc NAME --help's
        return sub.add_parser(name, help=help,
                              description=description or help[0].upper() + help[1:] + ".")

    b = command("bench", help="print per-call step times of the controllers and the vehicle")
    b.add_argument("--json", action="store_true",
                   help="print one JSON object mapping figure names (units in the name) to numbers")
    b.add_argument("--no-sitl", action="store_true",
                   help="skip the MAVLink figures (they start the vehicle as a process, ~25 s)")
    b.add_argument("--no-compare", action="store_true",
                   help="skip the experiment figures (the thesis matrix, ~1 min)")
    b.add_argument("--compare-seeds", type=int, default=10,
                   help="seeds for the thesis-matrix figure (default 10; 100 takes minutes)")
    b.add_argument("-q", "--quiet", action="store_true",
                   help="no progress on stderr (the parts measured, as they start)")
    b.set_defaults(func=_bench)
    f = command("fly", help="fly a mission (against the bundled vehicle unless --connect)")
    f.add_argument("mission", help="mission YAML file (or a name in configs/missions)")
    f.add_argument("--connect", default=None,
                   help="fly a vehicle at this MAVLink URL (udpin:0.0.0.0:14540, udp://:14540, "
                        "udpout:HOST:PORT, tcp:HOST:PORT, /dev/ttyUSB0:57600) instead of starting "
                        "the bundled one")
    f.add_argument("--controller", choices=("adrc", "ladrc", "pd", "pid", "native"), default=None,
                   type=str.lower, help="position controller, in either case: ladrc or LADRC; "
                                        "native: the autopilot's own, sent the mission's "
                                        "reference as position targets (default: the mission's)")
    f.add_argument("--takeover", action="store_true",
                   help="fly a vehicle that is already armed, in the air or in OFFBOARD/GUIDED "
                        "(another controller's), from where it is; without it such a vehicle is "
                        "refused and nothing is sent that changes its mode, arming or thrust")
    flight_options(f)
    f.set_defaults(func=_fly)
    i = command("identify", help="measure a vehicle's input model (how late it produces a "
                                 "commanded acceleration) in a short flight",
                description="Take off, fly small acceleration doublets at hover on the safe "
                            "default gains, fit two lags plus a dead time per axis, land; write "
                            "the result as a controller section (input_lag).")
    i.add_argument("mission", nargs="?", default="hover",
                   help="mission YAML whose vehicle, rate and limits are used (default: hover)")
    i.add_argument("--connect", default=None,
                   help="identify a vehicle at this MAVLink URL instead of the bundled one")
    i.add_argument("--write", default=None, metavar="FILE",
                   help="the YAML to write (default: input_model.yaml in the record folder)")
    i.add_argument("--altitude", type=float, default=1.0,
                   help="hover altitude for the doublets (m, default 1)")
    flight_options(i)
    i.set_defaults(func=_identify)
    r = command("response", help="measure the autopilot's attitude response from a flight "
                                 "record, beside the identified model",
                description="Read a flight record: the roll and pitch commanded (controller.csv) "
                            "and reported (the tlog's ATTITUDE) while airborne, both on the "
                            "vehicle's clock; print per frequency the gain, phase and coherence "
                            "of the response, and what the input model identified in that "
                            "flight says there.")
    r.add_argument("folder", help="a flight record folder (flight.tlog, controller.csv, "
                                  "summary.json)")
    r.add_argument("--json", action="store_true", help="print the result as JSON")
    r.set_defaults(func=_response)
    c = command("compare", help="run an experiment (scenarios x controllers x seeds) and "
                                       "write its report")
    c.add_argument("experiment", help="experiment YAML file (or a name in configs/experiments)")
    c.add_argument("--out", default=None,
                   help="output folder (default: runs/compare-NAME)")
    c.add_argument("--seeds", type=int, default=None,
                   help="run seeds 0..N-1 (default: the experiment's seeds)")
    c.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: one per core)")
    c.add_argument("--scheduler", default=None,
                   help="run on a Dask distributed cluster at this address (tcp://HOST:PORT)")
    c.add_argument("--via", choices=("inprocess", "mavlink"), default=None,
                   help="inprocess (default): the fast path on the vehicle's kernels; mavlink: "
                        "each run flown over MAVLink against the bundled vehicle in lockstep "
                        "(its report has tables, no figures: they are drawn from the fast "
                        "path's logs)")
    c.add_argument("--sitl", action="append", default=[], metavar="AUTOPILOT=PATH",
                   help="fly every run against a fresh SITL process, one at a time, in real "
                        "time: px4=PATH (PX4 SIH: its source tree or build/px4_sitl_default/"
                        "bin/px4), ardupilot=PATH (ArduCopter SITL: its source tree or "
                        "build/sitl/bin/arducopter), bundled (mavadrc sitl, as either "
                        "autopilot) or bundled=px4|ardupilot; repeatable: each scenario flies "
                        "on the autopilot its sitl: key names (docs/experiments.md)")
    c.add_argument("--ready-timeout", type=float, default=180.0, metavar="S",
                   help="with --sitl: seconds a SITL may take to become armable (default 180)")
    c.add_argument("--rerun-identical", action="store_true",
                   help="fly every seed even of scenarios the seed does not change (no "
                        "turbulence, no sensor noise); by default those fly once per controller "
                        "and their record stands for every seed")
    c.add_argument("--no-figures", action="store_true", help="tables only")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    c.set_defaults(func=_compare)
    t = command("tune", help="search controller bandwidths that minimise the RMS error "
                                    "over an experiment's scenarios and seeds")
    t.add_argument("experiment", help="experiment YAML file (or a name in configs/experiments)")
    t.add_argument("--controller", required=True,
                   help="the experiment's controller whose gains are searched, by its name in "
                        "either case (LADRC or ladrc)")
    t.add_argument("--scenarios", action="append", default=None,
                   help="scenario names to tune on (shell pattern; repeat for several; "
                        "default: all)")
    t.add_argument("--seeds", type=int, default=None,
                   help="number of wind seeds, from 1000 up (default: as many as the file's)")
    t.add_argument("--maxiter", type=int, default=20, help="differential evolution generations")
    t.add_argument("--popsize", type=int, default=8, help="population size per parameter")
    t.add_argument("--workers", type=int, default=None,
                   help="parallel evaluations (default: one per core)")
    t.add_argument("--seed", type=int, default=0, help="the optimiser's seed")
    t.add_argument("--bounds", action="append", default=[], metavar="NAME=LO:HI",
                   help="a search parameter's range, e.g. wo_ratio=2:10 (repeatable; the "
                        "defaults are printed at the start)")
    t.add_argument("--out", default=None, help="controller YAML to write (default: stdout)")
    t.set_defaults(func=_tune)
    p = command("plot", help="redraw the figures of a flight record or of any .tlog")
    p.add_argument("target", help="a flight record folder or a .tlog file")
    p.add_argument("--out", default=None, help="where to write the PNGs")
    p.set_defaults(func=_plot)
    from sim import cli as sim_cli

    s = command(
        "sitl", help="run the bundled vehicle behind MAVLink, like PX4 SITL",
        description="Run the bundled simulated vehicle behind MAVLink, as a PX4 SITL (or, with "
                    "--autopilot ardupilot, an ArduCopter SITL) would: it sends its offboard "
                    "link to UDP port 14540 (plus --instance) and its ground-station link to "
                    "14550, where mavadrc fly --connect, MAVSDK, MAVProxy or QGroundControl "
                    "find it. Real time until Ctrl-C or --duration; --lockstep steps once per "
                    "setpoint received.")
    sim_cli.add_arguments(s)
    s.set_defaults(func=_sitl)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
