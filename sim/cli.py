"""`mavadrc sitl` / `python -m sim`: the bundled vehicle behind MAVLink, like PX4 SITL."""

import argparse
import logging
import math
import signal
import sys
import threading

from .link_flags import add_link_arguments, link_from_args
from .mavlink.link import LOOPBACK, PortInUse, bind_udp, default_ports, read_signing_key
from .sensors import CLOCK_RATES, TYPICAL_NOISE, WANDER_CORNER_HZ
from .server import SitlServer


class UsageError(SystemExit):
    """A bad option of ``mavadrc sitl``: :func:`run` says it in one line on stderr and exits
    2, as every mavadrc command (and argparse) does for a usage error."""


def add_arguments(p):
    p.add_argument("--vehicle", default="crazyflie",
                   help="vehicle name in configs/vehicles or a YAML file (default: crazyflie)")
    p.add_argument("--wind", default=None, help="wind name in configs/wind or a YAML file")
    p.add_argument("--seed", type=int, default=0, help="seed of wind and sensor noise")
    p.add_argument("--instance", type=int, default=0,
                   help="instance N: ports + N, system id N + 1 (default 0)")
    p.add_argument("--count", type=int, default=1, metavar="N",
                   help="serve N vehicles from one process, instances INSTANCE..INSTANCE+N-1 "
                        "with their own ports and system ids, vehicle k with seed SEED+k "
                        "(real time only; default 1)")
    p.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="autopilot personality on the wire (default px4)")
    p.add_argument("--attitude-controller", choices=("px4", "ladrc", "adrc", "pd"), default="px4",
                   help="the vehicle's own attitude loop (default px4)")
    p.add_argument("--lockstep", action="store_true",
                   help="advance the vehicle one step per setpoint received (as fast as the "
                        "controller runs, deterministic)")
    p.add_argument("--lockstep-rate", type=float, default=100.0,
                   help="controller rate in lockstep: each setpoint advances 1/RATE s (default 100)")
    p.add_argument("--signing-key", default=None,
                   help="file with the 32-byte MAVLink 2 signing secret as 64 hex characters")
    p.add_argument("--noise", action="store_true",
                   help="report position/velocity/attitude/rates with typical sensor noise")
    p.add_argument("--wander", type=float, default=0.0, metavar="M",
                   help="the reported position estimate wanders this much (RMS per axis, m), "
                        "slowly, as PX4 SIH's EKF2 does (0.05-0.08 m there; default 0: not)")
    p.add_argument("--wander-corner", type=float, default=WANDER_CORNER_HZ, metavar="HZ",
                   help=f"the wander's corner frequency (default {WANDER_CORNER_HZ:g} Hz)")
    p.add_argument("--latency", type=float, default=0.0, help="sensor latency (s)")
    p.add_argument("--clock-rate", type=float, default=1.0, metavar="R",
                   help="in real time the vehicle's clock (time_boot_ms, TIMESYNC) runs at R of "
                        "the wall clock, as a simulator's that cannot keep up does (PX4 SITL's "
                        "ran 0.9865 on 2 cores; default 1)")
    p.add_argument("--height-drift", type=float, default=0.0, metavar="M/S",
                   help="the reported height estimate drifts up this fast (a barometer's drift; "
                        "the vehicle lands where its estimate says the ground is)")
    p.add_argument("--ground-climb", type=float, default=0.0, metavar="M/S",
                   help="once the vehicle has flown and come to rest on the ground, its height "
                        "estimate reads a climb this fast, held 4 s then dying away in 4 s "
                        "(PX4 SIH's EKF2 read 0.35-0.4 m/s so; its land detector then refused "
                        "the disarm)")
    p.add_argument("--rangefinder", action="store_true",
                   help="a downward range finder: DISTANCE_SENSOR of the true height above the "
                        "ground (10 Hz on the onboard link, as PX4 SIH's), whatever the height "
                        "estimate says")
    p.add_argument("--link", default=None, metavar="FILE",
                   help="YAML file with a link model (latency, jitter, loss per direction, "
                        "blackouts), as a mission's sim: {link: ...}")
    p.add_argument("--home", default="47.397742,8.545594,488.0",
                   help="home LAT,LON,ALT (deg, deg, m AMSL)")
    p.add_argument("--heading", type=_heading, default=0.0, metavar="DEG",
                   help="initial heading (deg from north, clockwise; default 0), or 'random': "
                        "drawn from the seed (each vehicle of --count its own)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="initial value of one of the autopilot's parameters, e.g. "
                        "COM_SPOOLUP_TIME=0 (repeatable)")
    p.add_argument("--offboard-port", type=int, default=None,
                   help="UDP port the offboard link sends to (default 14540 + instance; with "
                        "--count, vehicle k sends to this + k)")
    p.add_argument("--gcs-port", type=int, default=None,
                   help="UDP port the ground-station link sends to (default 14550)")
    p.add_argument("--bind-offboard", type=int, default=None,
                   help="local UDP port of the offboard link (default 14580 + instance; 0: any; "
                        "with --count, vehicle k binds this + k)")
    p.add_argument("--bind-gcs", type=int, default=None,
                   help="local UDP port of the ground-station link (default 18570 + instance; "
                        "0: any; with --count, vehicle k binds this + k)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many wall-clock seconds (default: run until Ctrl-C)")
    add_link_arguments(p)
    p.add_argument("-v", "--verbose", action="store_true", help="log every STATUSTEXT")
    return p


NOISE = TYPICAL_NOISE  # --noise


def warm_up(vehicle, wind, attitude_controller):
    """Run every firmware path once on a throwaway vehicle, so numba compiles (or loads from its
    cache) now rather than in the middle of a flight, where a pause would look like a lost link."""
    from .vehicle import SimVehicle

    v = SimVehicle(vehicle, wind=wind, attitude_controller=attitude_controller)
    v.arm()
    v.set_attitude_target([1.0, 0.0, 0.0, 0.0], v.hover_thrust)
    v.step(0.02)
    v.takeoff(1.0)
    v.step(0.02)
    v.set_position_target(pos=[0.0, 0.0, -1.0], vel=[0.0, 0.0, 0.0])
    v.step(0.02)
    v.hold()
    v.land()
    v.step(0.02)
    v.true_disturbance()
    v.reported()


def parse_params(items, autopilot):
    """{NAME: value} from --param NAME=VALUE items; SystemExit naming the bad one."""
    from .mavlink.parameters import parse_param
    from .personality import personality

    ap = personality(autopilot)
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UsageError(f"--param must be NAME=VALUE (got {item!r})")
        try:
            out[name] = parse_param(ap, name, value.strip())
        except ValueError as e:
            raise UsageError(f"--param {item}: {e}") from None
    return out


#: each link's local port: the option that sets it and its attribute in the arguments
BIND_OPTIONS = {"offboard": ("--bind-offboard", "bind_offboard"), "gcs": ("--bind-gcs", "bind_gcs")}


def port_in_use(e, args):
    """The SystemExit for :class:`~sim.mavlink.link.PortInUse` ``e``: the port, and the options
    that choose another."""
    option, dest = BIND_OPTIONS[e.link]
    how = f"{option} PORT (0: any free port)"
    if getattr(args, dest) is None:
        how += " or --instance N (every port + N)"
    return SystemExit(f"mavadrc sitl: {e}; choose another with {how}")


def fleet_ports(args, k):
    """The port options of vehicle k of a --count fleet: explicit offboard and local ports move
    by k as the defaults do (a local port of 0 stays 0: any free one); every vehicle's
    ground-station link sends to the same port (14550 by default), as PX4 SITL's instances do."""
    def plus(port):
        return port if not port else port + k
    return {"offboard_port": plus(args.offboard_port), "gcs_port": args.gcs_port,
            "bind_offboard": plus(args.bind_offboard), "bind_gcs": plus(args.bind_gcs)}


def check_ports(args):
    """Fail at once, before the warm-up compiles anything, if a link's local port is taken, or
    if a vehicle's offboard link would send to the ground-station port (instance 10 and up on
    the default ports: 14540 + 10 is 14550)."""
    fleet = [default_ports(args.instance + k, **fleet_ports(args, k))
             for k in range(getattr(args, "count", 1))]
    gcs = {ports["gcs"][0] for ports in fleet}
    # the whole fleet's plan first: a port taken on this machine is the lesser news
    for k, ports in enumerate(fleet):
        if ports["offboard"][0] in gcs:
            raise UsageError(f"mavadrc sitl: instance {args.instance + k} would send its "
                             f"offboard link to UDP {ports['offboard'][0]}, the ground-station "
                             f"port: give --offboard-port BASE (vehicle k sends to BASE + k) "
                             f"or --gcs-port")
    for ports in fleet:
        for name, (_, local) in ports.items():
            if local:
                try:
                    bind_udp(LOOPBACK, local, name).close()
                except PortInUse as e:
                    raise port_in_use(e, args) from None


def read_link(path):
    """A :class:`sim.link_model.LinkModel` from a YAML file holding a ``link:`` section's keys;
    a bad file ends the command with its file, line and field."""
    from .link_model import link_from_section
    from .yamlio import ConfigError, Section, load_yaml

    try:
        data = load_yaml(path)
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: a link file is a mapping (down, up, blackouts)")
        return link_from_section(Section(data, str(path)))
    except ConfigError as e:
        raise UsageError(f"--link: {e}") from None


def make_server(args):
    """The SitlServer of the options (with --count, the first of :func:`make_servers`)."""
    return make_servers(args)[0]


def _heading(text):
    """--heading: degrees, or 'random' (NaN: drawn from the vehicle's seed)."""
    from .vehicle import parse_heading

    try:
        return parse_heading(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be degrees or 'random' (got {text!r})") from None


def make_servers(args):
    """One SitlServer per vehicle of --count (instance + k, seed + k, ports + k), not started."""
    from .vehicle import SimVehicle

    count = getattr(args, "count", 1)
    if count < 1:
        raise UsageError(f"--count must be at least 1 (got {count})")
    if count > 1 and args.lockstep:
        raise UsageError("mavadrc sitl: --count serves its vehicles in real time only; for "
                         "lockstep start one process per vehicle (--instance N)")
    if math.isinf(args.heading):
        raise UsageError(f"--heading must be a finite number of degrees (got {args.heading!r})")
    params = parse_params(args.param, args.autopilot)  # before the warm-up: fail fast
    link, link_on, bandwidth = link_from_args(args)
    if args.link:
        if link is not None:
            raise UsageError("--link FILE and --link-down/--link-up/--link-blackout: give the "
                             "link model one way")
        link = read_link(args.link)
    try:
        home = tuple(float(v) for v in args.home.split(","))
        if len(home) != 3:
            raise ValueError
    except ValueError:
        raise UsageError(f"--home must be LAT,LON,ALT (got {args.home!r})") from None
    if not math.isfinite(args.height_drift) or abs(args.height_drift) > 0.5:
        raise UsageError(f"--height-drift must be -0.5 to 0.5 m/s (got {args.height_drift!r})")
    if not (math.isfinite(args.ground_climb) and 0.0 <= args.ground_climb <= 2.0):
        raise UsageError(f"--ground-climb must be 0 to 2 m/s (got {args.ground_climb!r})")
    if not (math.isfinite(args.wander) and 0.0 <= args.wander <= 1.0):
        raise UsageError(f"--wander must be 0 to 1 m (got {args.wander!r})")
    if not (math.isfinite(args.wander_corner) and 0.01 <= args.wander_corner <= 5.0):
        raise UsageError(f"--wander-corner must be 0.01 to 5 Hz (got {args.wander_corner!r})")
    clock_rate = getattr(args, "clock_rate", 1.0)
    lo, hi = CLOCK_RATES
    if not (math.isfinite(clock_rate) and lo <= clock_rate <= hi):
        raise UsageError(f"--clock-rate must be {lo:g} to {hi:g} (got {clock_rate!r})")
    if clock_rate != 1.0 and args.lockstep:
        raise UsageError("mavadrc sitl: --clock-rate is for real time; in lockstep the "
                         "setpoints are the clock")
    check_ports(args)
    warm_up(args.vehicle, args.wind, args.attitude_controller)
    sensors = None
    if args.noise or args.latency > 0.0 or args.wander > 0.0:
        sensors = {"noise": NOISE if args.noise else {}, "latency_s": args.latency,
                   "wander": args.wander, "wander_corner_hz": args.wander_corner}
    key = read_signing_key(args.signing_key) if args.signing_key else None
    servers = []
    try:
        for k in range(count):
            vehicle = SimVehicle(args.vehicle, wind=args.wind, seed=args.seed + k,
                                 sensors=sensors, attitude_controller=args.attitude_controller,
                                 yaw=math.radians(args.heading),
                                 height_drift_mps=args.height_drift,
                                 ground_climb_mps=args.ground_climb,
                                 rangefinder=args.rangefinder)
            servers.append(SitlServer(vehicle, args.autopilot, args.instance + k,
                                      lockstep=args.lockstep,
                                      lockstep_dt=1.0 / args.lockstep_rate, signing_key=key,
                                      home=home, params=params, link=link, link_on=link_on,
                                      link_bandwidth=bandwidth, link_seed=args.seed + k,
                                      clock_rate=clock_rate, **fleet_ports(args, k)))
    except PortInUse as e:  # taken since check_ports
        for s in servers:
            s._close()
        raise port_in_use(e, args) from None
    return servers


def _span(values):
    values = list(values)
    return str(values[0]) if len(values) == 1 or values[0] == values[-1] else \
        f"{values[0]}..{values[-1]}"


def run(args):
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s")
    try:
        servers = make_servers(args)
    except UsageError as e:
        text = str(e)
        print(text if text.startswith("mavadrc sitl:") else f"mavadrc sitl: {text}",
              file=sys.stderr)
        raise SystemExit(2) from None
    if len(servers) == 1:
        server = servers[0]
    else:
        from .fleet import FleetServer

        server = FleetServer(servers)
    first = servers[0]
    ports = [s.local_ports for s in servers]
    print(f"mavadrc sitl: {_count_of(servers)}{args.vehicle} as {args.autopilot}, system "
          f"{_span(s.sysid for s in servers)}; offboard link -> 127.0.0.1:"
          f"{_span(s.links[0].peers[0][1] for s in servers)} (local "
          f"{_span(p['offboard'] for p in ports)}), ground station -> 127.0.0.1:"
          f"{_span(s.links[1].peers[0][1] for s in servers)} (local "
          f"{_span(p['gcs'] for p in ports)}){', lockstep' if first.lockstep else ''}",
          flush=True)
    if first.link_model is not None or any(link.line for link in first.links):
        print(f"mavadrc sitl: link {describe_link(first)}", flush=True)
    if math.isnan(args.heading):
        degs = ", ".join(f"{math.degrees(s.vehicle.initial_yaw):.1f}" for s in servers)
        print(f"mavadrc sitl: random initial heading from the seed: {degs} deg", flush=True)
    if args.duration is not None:
        timer = threading.Timer(args.duration, server.stop_soon)
        timer.daemon = True
        timer.start()
    signal.signal(signal.SIGTERM, lambda *_: server.stop_soon())
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    stats = [s.stats for s in servers]
    print(f"mavadrc sitl: stopped at t = {server.time:.2f} s; "
          f"{sum(s.messages for s in stats)} messages, "
          f"{sum(s.dropped() for s in stats)} datagrams/frames dropped, "
          f"{sum(s.other_target for s in stats)} for other systems, "
          f"{sum(s.setpoints_rejected for s in stats)} setpoints rejected", flush=True)
    summary = first.stats.link_summary()
    if summary:
        print(f"mavadrc sitl: link {summary}", flush=True)
        logging.getLogger("mavadrc.sitl").info("link: %s", summary)
    return 0


def _count_of(servers):
    return f"{len(servers)} x " if len(servers) > 1 else ""


def describe_link(server):
    """The link model and bandwidths in force, in one line."""
    m = server.link_model
    parts = []
    if m is not None:
        for way in ("down", "up"):
            w = getattr(m, way)
            if not w.perfect:
                parts.append(f"{way} {1e3 * w.latency_s:g}+{1e3 * w.jitter_s:g} ms, "
                             f"loss {w.loss:g}")
        parts += [f"blackout {s:g}+{d:g} s" for s, d in m.blackouts]
        if server.lockstep:
            parts.append("(lockstep: applied in vehicle time by the lockstep path, not on the "
                         "wall clock)")
    parts += [f"{link.name} {link.line.rate:g} B/s" for link in server.links if link.line]
    return "; ".join(parts)


def main(argv=None):
    parser = add_arguments(argparse.ArgumentParser(prog="python -m sim", description=__doc__))
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
