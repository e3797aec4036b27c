"""The link model and the bandwidth as options of ``mavadrc sitl`` / ``python -m sim``, and back.

``--link-down latency=0.02,jitter=0.01,loss=0.05`` and ``--link-up ...`` (seconds, and a
probability), ``--link-blackout START:DURATION`` (s of vehicle time, repeatable), ``--link-on
offboard|gcs|both`` (the links the model applies to, default offboard) and ``--link-bandwidth
BYTES_PER_S`` (those links) or ``NAME=BYTES_PER_S`` (that link; repeatable).  A bad value ends
the command with one line naming the option.  :func:`link_args` turns a
:class:`sim.link_model.LinkModel` back into the options, so that a mission's ``sim: {link:}``
reaches a vehicle started as its own process.
"""

import math

from .link_model import LinkModel, Way

LINKS = ("offboard", "gcs")
#: a 57600-baud radio: 10 bits a byte on the wire
RADIO_57600 = 5760

_KEYS = {"latency": "latency_s", "latency_s": "latency_s", "jitter": "jitter_s",
         "jitter_s": "jitter_s", "loss": "loss"}


def add_link_arguments(p):
    p.add_argument("--link-down", default=None, metavar="latency=S,jitter=S,loss=P",
                   help="the link vehicle -> companion: each datagram delayed by latency plus "
                        "a uniform draw in [0, jitter] s, lost with probability loss (real "
                        "time; seeded by --seed)")
    p.add_argument("--link-up", default=None, metavar="latency=S,jitter=S,loss=P",
                   help="the link companion -> vehicle, as --link-down")
    p.add_argument("--link-blackout", action="append", default=[], metavar="START:DURATION",
                   help="no datagram either way from START for DURATION s of vehicle time "
                        "(repeatable)")
    p.add_argument("--link-on", default="offboard", metavar="offboard|gcs|both",
                   help="the links the link model and --link-bandwidth apply to (default "
                        "offboard)")
    p.add_argument("--link-bandwidth", action="append", default=[],
                   metavar="[LINK=]BYTES_PER_S",
                   help="bytes a second the link carries (default: unlimited, as UDP); a "
                        "57600-baud radio carries 5760.  The vehicle throttles its streams "
                        "to fit, as the autopilot does.  LINK=... sets one link (repeatable)")
    return p


def _number(flag, text, what):
    try:
        v = float(text)
    except ValueError:
        raise SystemExit(f"{flag}: {what} must be a number (got {text!r})") from None
    if not math.isfinite(v):
        raise SystemExit(f"{flag}: {what} must be finite (got {text!r})")
    return v


def parse_way(flag, text):
    """A :class:`sim.link_model.Way` from ``latency=S,jitter=S,loss=P``."""
    kw = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in _KEYS:
            raise SystemExit(f"{flag}: expected latency=S,jitter=S,loss=P (got {item.strip()!r})")
        kw[_KEYS[key]] = _number(flag, value.strip(), key)
    try:
        return Way(**kw)
    except ValueError as e:
        raise SystemExit(f"{flag}: {e}") from None


def parse_blackout(text):
    flag = "--link-blackout"
    start, sep, duration = text.partition(":")
    if not sep:
        raise SystemExit(f"{flag}: expected START:DURATION in s (got {text!r})")
    s, d = _number(flag, start, "START"), _number(flag, duration, "DURATION")
    if s < 0 or d <= 0:
        raise SystemExit(f"{flag}: START must be >= 0 and DURATION > 0 s (got {text!r})")
    return s, d


def parse_link_on(text):
    names = LINKS if text == "both" else (text,)
    if text != "both" and text not in LINKS:
        raise SystemExit(f"--link-on: expected offboard, gcs or both (got {text!r})")
    return names


def link_from_args(args):
    """(LinkModel or None, the links it applies to, {link name: bytes/s}) from the options."""
    on = parse_link_on(args.link_on)
    down = parse_way("--link-down", args.link_down) if args.link_down else Way()
    up = parse_way("--link-up", args.link_up) if args.link_up else Way()
    blackouts = tuple(parse_blackout(b) for b in args.link_blackout)
    model = LinkModel(down, up, blackouts)
    bandwidth = {}
    for item in args.link_bandwidth:
        name, sep, value = item.rpartition("=")
        if sep and name not in LINKS:
            raise SystemExit(f"--link-bandwidth: LINK must be offboard or gcs (got {name!r})")
        v = _number("--link-bandwidth", value, "BYTES_PER_S")
        if v <= 0:
            raise SystemExit(f"--link-bandwidth: BYTES_PER_S must be > 0 (got {value!r})")
        for n in ((name,) if sep else on):
            bandwidth[n] = v
    return (None if model.perfect else model), on, bandwidth


def link_args(model, on=None, bandwidth=None):
    """The options that give a vehicle ``model`` (a :class:`sim.link_model.LinkModel` or
    None), on the links ``on`` ("offboard", "gcs" or "both"), with ``bandwidth`` bytes/s."""
    out = []
    if model is not None:
        for flag, w in (("--link-down", model.down), ("--link-up", model.up)):
            if not w.perfect:
                out += [flag, f"latency={w.latency_s!r},jitter={w.jitter_s!r},loss={w.loss!r}"]
        for start, duration in model.blackouts:
            out += ["--link-blackout", f"{start!r}:{duration!r}"]
    if on is not None and on != "offboard":
        out += ["--link-on", on]
    if bandwidth:
        out += ["--link-bandwidth", repr(float(bandwidth))]
    return out
