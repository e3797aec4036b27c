"""A faulty link in front of any autopilot that speaks MAVLink over UDP: the lossy proxy
(``sim/lossy/``) run on its own, so a real PX4 SITL (or a vehicle on a bench) can be
flown through loss, latency, jitter and blackouts as the bundled vehicle is with ``mavadrc sitl
--link-down/--link-up``.

    python tools/lossy_proxy.py --down latency=0.02,jitter=0.02,loss=0.05 \\
        --up latency=0.01,jitter=0.01,loss=0.02 [--blackout 40:1] [--seed 3]
    mavadrc fly MISSION --connect udpin:127.0.0.1:14640

By default it takes PX4 SITL's onboard link: PX4 sends to 14540 from 14580; the proxy listens
on 14540 and forwards to the companion at 14640 (``--vehicle-port``, ``--vehicle-addr``,
``--companion-port``).  ``--down``/``--up`` read as ``mavadrc sitl``'s: each datagram waits
``latency`` plus a uniform draw in [0, ``jitter``] s and is lost with probability ``loss``.
``--blackout START:DURATION``: nothing passes either way for DURATION s, START s after the
4000th LOCAL_POSITION_NED forwarded (``--blackout-after``; about 40 s into a flight at 100
Hz).  Ctrl-C ends it and prints what it dropped.
"""

import argparse
import signal
import sys
import time

from sim.link_flags import parse_way
from sim.lossy import LossyLink


def _address(text):
    host, _, port = text.rpartition(":")
    try:
        return host or "127.0.0.1", int(port)
    except ValueError:
        raise SystemExit(f"--vehicle-addr must be HOST:PORT (got {text!r})") from None


def main(argv=None):
    p = argparse.ArgumentParser(prog="tools/lossy_proxy.py", description=__doc__.split("\n")[0])
    p.add_argument("--vehicle-port", type=int, default=14540,
                   help="the port the autopilot sends its link to (default 14540, PX4 SITL's)")
    p.add_argument("--vehicle-addr", default="127.0.0.1:14580",
                   help="where the companion's first datagrams go before the autopilot has sent "
                        "(default 127.0.0.1:14580, PX4 SITL's onboard link)")
    p.add_argument("--companion-port", type=int, default=14640,
                   help="the port the companion listens on (udpin:127.0.0.1:PORT)")
    p.add_argument("--down", default=None, metavar="latency=S,jitter=S,loss=P",
                   help="vehicle -> companion")
    p.add_argument("--up", default=None, metavar="latency=S,jitter=S,loss=P",
                   help="companion -> vehicle")
    p.add_argument("--blackout", action="append", default=[], metavar="START:DURATION",
                   help="both ways dead for DURATION s, START s after --blackout-after samples")
    p.add_argument("--blackout-after", type=int, default=4000, metavar="N",
                   help="the samples (LOCAL_POSITION_NED) forwarded before the blackouts' clock "
                        "starts (default 4000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the link's draws")
    args = p.parse_args(argv)
    vehicle_addr = _address(args.vehicle_addr)
    ways = {flag: parse_way(flag, text)
            for flag, text in (("--down", args.down), ("--up", args.up)) if text is not None}
    blackouts = []
    for text in args.blackout:
        try:
            start, duration = (float(v) for v in text.split(":"))
            if not (start >= 0 and duration >= 0):
                raise ValueError
        except ValueError:
            raise SystemExit(f"--blackout: expected START:DURATION in s, START >= 0 and "
                             f"DURATION >= 0 (got {text!r})") from None
        blackouts.append((start, duration))
    try:
        link = LossyLink(args.companion_port, vehicle_port=args.vehicle_port, seed=args.seed,
                         vehicle_addr=vehicle_addr)
    except OSError as e:
        raise SystemExit(f"UDP port {args.vehicle_port}: {e.strerror or e} (is another program "
                         "bound to it? --vehicle-port chooses another)") from None
    for flag, channel in (("--down", link.down), ("--up", link.up)):
        way = ways.get(flag)
        if way is None:
            continue
        # uniform over [latency, latency + jitter], as mavadrc sitl draws it
        channel.latency = way.latency_s + 0.5 * way.jitter_s
        channel.jitter = 0.5 * way.jitter_s
        channel.loss = way.loss
    for start, duration in blackouts:
        link.blackout(start, duration, after_lpn=args.blackout_after)
    link.start()
    print(f"lossy proxy: the autopilot's port {args.vehicle_port} <-> {link.companion_url} "
          "(Ctrl-C ends it)", flush=True)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    try:
        while not stop:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        link.stop(check=False)
    for name, ch in (("down", link.down), ("up", link.up)):
        s = ch.stats
        print(f"{name}: {s.datagrams_in} datagrams in, {s.datagrams_out} out, dropped "
              f"{dict(s.datagrams_dropped)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
