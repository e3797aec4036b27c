"""What an experiment flown against SITL processes needs, read and checked before anything starts.

Three things, each a plain value:

- the **SITLs given** (:func:`read_sitl_section` for the experiment's ``sitl:`` section,
  :func:`parse_sitl_options` for ``--sitl``): per autopilot (``px4``, ``ardupilot``) the build
  to start (a path, or ``bundled``: mavadrc's own ``mavadrc sitl`` speaking as that autopilot)
  and the parameters every run sets;
- a **scenario's needs** (:func:`read_scenario_sitl`): the autopilot it is for, its frame (quad
  or hexa), and parameters of its own;
- a scenario's **wind as the autopilot's parameters** (:func:`autopilot_wind`): ArduCopter SITL
  models a mean wind and a turbulence (``SIM_WIND_*``); PX4 SIH models none, so a scenario with
  wind is refused there.
"""

import math

AUTOPILOTS = ("px4", "ardupilot")
FRAMES = ("quad", "hexa")
#: each autopilot's name in sentences
AUTOPILOT_NAMES = {"px4": "PX4 SIH", "ardupilot": "ArduCopter SITL"}
#: ``--sitl bundled``: the bundled vehicle serves every autopilot a scenario asks for
BUNDLED = "bundled"


class SitlConfigError(ValueError):
    """A ``--sitl`` option or a ``sitl:`` section that cannot be used (exit 2)."""


def _params(sec, key="params"):
    """{NAME: number} of a ``params:`` mapping (names upper case, values numbers)."""
    if not sec.has(key):
        return {}
    ps = sec.section(key)
    out = {}
    for name in list(ps.data):
        ps.check(name, isinstance(name, str) and name.replace("_", "").isalnum()
                 and len(name) <= 16, "a parameter name is at most 16 letters, digits or _")
        out[str(name)] = ps.number(name)
    ps.finish()
    return out


def read_sitl_section(top):
    """The experiment's ``sitl:`` section (``top``: the file's Section) as {autopilot: {"path",
    "params"}}; {} without one.  Two forms::

        sitl: {autopilot: ardupilot, path: ~/ardupilot, params: {SIM_SPEEDUP: 1}}
        sitl:
          px4: {path: ~/PX4-Autopilot, params: {EKF2_HGT_REF: 2}}
          ardupilot: {path: ~/ardupilot}

    ``path`` may be left out (``--sitl AUTOPILOT=PATH`` gives it) or be ``bundled``."""
    if not top.has("sitl"):
        return {}
    sec = top.section("sitl")
    out = {}
    if sec.has("autopilot"):
        ap = sec.string("autopilot", choices=AUTOPILOTS)
        out[ap] = {"path": sec.string("path", None), "params": _params(sec)}
    else:
        for ap in AUTOPILOTS:
            if sec.has(ap):
                s = sec.section(ap)
                out[ap] = {"path": s.string("path", None), "params": _params(s)}
                s.finish()
        sec.check(None, bool(out), "give autopilot: px4|ardupilot (with path, params), or a "
                                   "px4: and/or ardupilot: section")
    sec.finish()
    return out


def read_scenario_sitl(sec):
    """A scenario's ``sitl:`` key: {"autopilot": None|px4|ardupilot, "frame", "params"}."""
    if not sec.has("sitl"):
        return {"autopilot": None, "frame": "quad", "params": {}}
    s = sec.section("sitl")
    out = {"autopilot": s.string("autopilot", None, choices=AUTOPILOTS),
           "frame": s.string("frame", "quad", choices=FRAMES), "params": _params(s)}
    s.finish()
    return out


def parse_sitl_options(items, section=None):
    """{autopilot: {"path", "params"}} of the ``--sitl`` values over the experiment's ``sitl:``
    section: ``px4=PATH``, ``ardupilot=PATH``, ``bundled`` (the bundled vehicle for both),
    ``bundled=px4|ardupilot`` (for one).  With no option, the section's autopilots that name a
    path.  Raises :class:`SitlConfigError`."""
    section = section or {}
    given = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        name, value = name.strip().lower(), value.strip()
        if name == BUNDLED:
            aps = (value.lower(),) if sep else AUTOPILOTS
            if sep and aps[0] not in AUTOPILOTS:
                raise SitlConfigError(f"--sitl {item}: bundled=px4 or bundled=ardupilot "
                                      "(or bundled alone: both)")
            for ap in aps:
                given[ap] = BUNDLED
        elif name in AUTOPILOTS and sep and value:
            given[name] = value
        else:
            raise SitlConfigError(f"--sitl {item}: give px4=PATH, ardupilot=PATH (the "
                                  "autopilot's SITL binary or its source tree with the build), "
                                  "bundled or bundled=px4|ardupilot")
    if not items:
        given = {ap: s["path"] for ap, s in section.items() if s.get("path")}
        if not given:
            raise SitlConfigError("no SITL to fly: give --sitl px4=PATH, --sitl ardupilot=PATH "
                                  "or --sitl bundled, or path: in the experiment's sitl: section")
    return {ap: {"path": path, "params": dict(section.get(ap, {}).get("params", {}))}
            for ap, path in given.items()}


def scenario_autopilot(name, scenario_sitl, given):
    """The autopilot scenario ``name`` flies on: its own ``sitl.autopilot``, or, untagged, the
    only one given; None when it is for an autopilot not given.  Raises
    :class:`SitlConfigError` for an untagged scenario when two are given."""
    ap = scenario_sitl["autopilot"]
    if ap is not None:
        return ap if ap in given else None
    if len(given) == 1:
        return next(iter(given))
    raise SitlConfigError(f"scenario {name!r} names no autopilot and two are given: add "
                          "sitl: {autopilot: px4|ardupilot} to it (or to the defaults)")


# --- wind ----------------------------------------------------------------------------------------

def _wind_mapping(wind):
    """A wind (name, path or mapping) as its YAML mapping."""
    if isinstance(wind, dict):
        return wind
    from sim.yamlio import config_path, load_yaml
    return load_yaml(config_path(wind, "wind"))


def autopilot_wind(autopilot, wind, altitude_m, bundled=False):
    """The parameters that give ``autopilot``'s SITL the scenario's ``wind`` (None: calm), at
    its flight altitude ``altitude_m``; {} for the bundled vehicle, which flies the wind itself.

    ArduCopter SITL: one constant part is ``SIM_WIND_SPD`` / ``SIM_WIND_DIR`` (both say where
    the wind comes from), with ``SIM_WIND_T`` 1 (the same at every height) for profile none and
    0 for ``sqrt60`` (ArduPilot's own profile); a Dryden part is ``SIM_WIND_TURB``, its
    horizontal sigma at ``altitude_m`` (ArduPilot's turbulence is a filtered random walk of that
    standard deviation, not Dryden's spectrum).  Gusts, sinusoids, the thesis's forces, an
    updraft, a log profile or two mean winds: ValueError.  PX4 SIH has no wind: anything but
    calm is a ValueError."""
    if bundled:
        return {}
    data = {} if wind is None else _wind_mapping(wind)
    parts = [data] if "components" not in data and data.get("type") else \
        list(data.get("components") or [])
    name = AUTOPILOT_NAMES[autopilot]
    if autopilot == "px4":
        if parts:
            raise ValueError(f"{name} has no wind model: fly this scenario calm "
                             "(wind: calm) or on ArduCopter SITL")
        return {}
    out = {"SIM_WIND_SPD": 0.0, "SIM_WIND_DIR": 0.0, "SIM_WIND_TURB": 0.0, "SIM_WIND_T": 1.0}
    constants = [p for p in parts if p.get("type") == "constant"]
    others = sorted({str(p.get("type")) for p in parts} - {"constant", "dryden"})
    if others:
        raise ValueError(f"{name} models a mean wind and turbulence only, not "
                         f"{', '.join(others)}")
    if len(constants) > 1:
        raise ValueError(f"{name} models one mean wind: give one constant part")
    if constants:
        c = constants[0]
        if float(c.get("vertical", 0.0)) != 0.0:
            raise ValueError(f"{name}'s wind here is horizontal: no vertical part")
        profile = c.get("profile", "none")
        if profile not in ("none", "sqrt60"):
            raise ValueError(f"{name} scales its wind by sqrt(h/60) or not at all: profile "
                             "none or sqrt60, not " + str(profile))
        out["SIM_WIND_SPD"] = float(c["speed"])
        out["SIM_WIND_DIR"] = float(c.get("direction_from_deg", 0.0)) % 360.0
        out["SIM_WIND_T"] = 1.0 if profile == "none" else 0.0
    if any(p.get("type") == "dryden" for p in parts):
        from sim.wind import CompositeWind, DrydenTurbulence, dryden_scales, load_wind

        model = load_wind(data)
        found = model.parts if isinstance(model, CompositeWind) else [model]
        dryden = next(p for p in found if isinstance(p, DrydenTurbulence))
        sigma_u = dryden_scales(altitude_m, dryden._w20)[0]
        out["SIM_WIND_TURB"] = round(float(sigma_u), 3)
    return out


def flight_altitude(mission):
    """The altitude (m) a mission mostly flies at: its takeoff's."""
    for kind, spec, _ in mission.segments:
        if kind == "takeoff":
            return float(spec.get("altitude", 1.0))
    return 1.0


def heading_of(mission):
    """The scenario's initial heading (deg), 0 unless its ``sim: {heading_deg}`` says."""
    h = mission.heading_deg
    if isinstance(h, float) and math.isnan(h):
        raise ValueError("heading_deg: random is drawn by the bundled vehicle in process; give "
                         "degrees for a SITL")
    return float(h)
