"""Experiments: a matrix of scenarios x controllers x seeds, run and summarised.

An experiment file (``configs/experiments/*.yaml``)::

    name: thesis section 6
    seeds: 1                      # how many (0, 1, ...), or a list; --seeds N overrides
    defaults:                     # mission keys every scenario starts from
      vehicle: crazyflie
      safety: {geofence: {north: [-20, 20], east: [-20, 20]}}
      settle_s: 12                # errors are reported before (joining) and after this time
    controllers:                  # every scenario runs every controller
      - {name: PD, type: pd, wc: [2.5, 2.5, 3.0]}
      - {name: LADRC, type: ladrc, wc: [...], wo: [...]}
      - {name: oracle, type: oracle}          # PD + the simulator's true disturbance (in process)
    scenarios:
      - name: circle 2 m/s
        group: PD on the circle, no wind (thesis 6.2.1)
        series: {name: circle speed, value: 2.0, unit: m/s}   # for "where does it break"
                                  # (or a list: a nominal run can be a point of several)
        trajectory:               # as a mission's; may end in the air
          - takeoff: {altitude: 1.0, speed: 0.5}
          - circle: {radius: 10, speed: 2, altitude: 1, duration: 41.4, join: direct}
        wind: breeze_1ms
        thesis: {PD: {max_error_xyz_m: [0.018, 0.033, 0.031], note: "fig. 8a"}}
        sample_rate_hz: 50        # every controller at 50 Hz here, one step per position sample
        input_model_scale: 2      # every observer's input model (input_lag) x2 of the truth
        sim: {mass_scale: 1.3}    # the vehicle against its file (mission keys, docs/flying.md)
        sitl: {autopilot: ardupilot, frame: quad, params: {NAME: 1}}  # compare --sitl only:
                                  # the autopilot the scenario is for, its frame and parameters
    goals:                        # claims the report checks, measured
      - {scenario: "spiral in wind", controllers: [ADRC, LADRC],
         metric: after_settle.max_error_m, at_most: 0.05}
      - {scenario: "*", controllers: [ADRC], metric: after_settle.rms_error_m,
         ratio_to: PD, at_most: 0.333, over: all}   # all: pooled over the scenarios;
                                                     # each (default): every scenario
      - {scenario: [nominal, "latency [24]0 ms"], ...}  # a list of name patterns
    sitl:                         # compare --sitl: the builds and the parameters of every run
      px4: {path: ~/PX4-Autopilot, params: {EKF2_HGT_REF: 2}}
      ardupilot: {path: ~/ardupilot}
    breaks:                       # where a controller breaks along a series
      - {series: circle speed, metric: after_settle.max_error_m, above: 0.5}
      - {series: mass, metric: after_settle.max_error_m, above: 0.1, nominal: 1}
                                  # judged outward from the nominal value, both ways (default:
                                  # the smallest value, upwards)

Each run is one mission flown by :func:`mavadrc.fast.fly.fly_inprocess` (the fast path) or, with
``via="mavlink"``, by ``mavadrc fly --lockstep`` against the bundled vehicle; both give the same
record.  Against SITL processes (``compare --sitl``) runs are flown by
:mod:`mavadrc.study.sitl_runs`.  A record holds ``scenario``, ``controller``, ``seed`` and the error keys of a flight's
``summary.json`` (``rms_error_m``, ``max_error_m``, ``rms_error_xyz_m``, ``max_error_xyz_m``, and
``after_settle``), plus the joining transient, control effort and saturation figures, and whether
the scenario was feasible for it.
"""

import copy
import dataclasses
import fnmatch
import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mavadrc.flight.record import attitude_oscillation, error_figures
from mavadrc.mission.config import KINDS, mission_from_section, read_controller
from mavadrc.study.sitl_config import read_scenario_sitl, read_sitl_section
from sim.yamlio import Section, YamlMap, choose, config_path, described, did_you_mean, load_yaml

CONTROLLER_KINDS = KINDS + ("oracle",)
# the vehicle's own attitude loop when a scenario asks for the one matching the controller
MATCHING_ATTITUDE = {"pd": "pd", "adrc": "adrc", "ladrc": "ladrc", "pid": "px4", "oracle": "px4",
                     "native": "px4"}
#: a run whose thrust sits at a limit for more than this share of the tracking window is
#: reported infeasible (the vehicle cannot do what the scenario asks)
SATURATION_SHARE = 0.10


@dataclass
class ControllerEntry:
    name: str
    spec: object  # mission.ControllerSpec; kind may be 'oracle'

    @property
    def kind(self):
        return self.spec.kind


@dataclass
class Scenario:
    name: str
    group: str
    mission: object  # mission.Mission without a controller
    settle_s: float
    series: dict = None  # {name, value, unit}
    thesis: dict = field(default_factory=dict)  # controller name or kind -> reported figures
    attitude_match: bool = False
    note: str = ""
    #: every controller runs at this rate here (Hz; None: its own), one control step per
    #: position sample: the rate the vehicle's samples come at and the controller's step
    sample_rate_hz: float = None
    #: every observer's input model (``input_lag``, given or ``auto``) times this, against the
    #: vehicle's true response; controllers without one fly as they are
    input_model_scale: float = 1.0
    #: every series the scenario is a point of (``series`` is the first): a nominal run can
    #: be the shared point of several series
    points: list = field(default_factory=list)
    #: what the scenario needs of a SITL process (``compare --sitl``): {"autopilot": None or
    #: px4|ardupilot, "frame": quad|hexa, "params": {NAME: value}}
    sitl: dict = field(default_factory=lambda: {"autopilot": None, "frame": "quad",
                                                "params": {}})

    def point(self, name):
        """The scenario's point ({name, value, unit}) of series ``name``, or None."""
        return next((p for p in self.points if p["name"] == name), None)

    @functools.cached_property
    def random(self):
        """True when the seed changes this scenario's runs: its wind draws random numbers
        (Dryden turbulence), it flies with sensor noise or a wander, its link draws loss or jitter, or its
        initial heading is drawn (``heading_deg: random``).
        Otherwise every seed flies the same run, and an experiment flies it once
        (:func:`mavadrc.study.compare.run_matrix`)."""
        m = self.mission
        if m.noise or m.wander or math.isnan(m.heading_deg):
            return True
        if m.link is not None and any(w.loss > 0.0 or w.jitter_s > 0.0
                                      for w in (m.link.down, m.link.up)):
            return True
        if m.wind is None:
            return False
        from sim.wind import load_wind

        return bool(load_wind(m.wind).random)


@dataclass
class Experiment:
    name: str
    source: str
    text: str
    description: str
    controllers: list
    scenarios: list
    seeds: list
    goals: list
    breaks: list
    #: the experiment's ``sitl:`` section: {autopilot: {"path", "params"}} (``compare --sitl``)
    sitl: dict = field(default_factory=dict)

    def runs(self, seeds=None):
        """Every (scenario index, controller index, seed) of the matrix, scenario-major."""
        seeds = self.seeds if seeds is None else seeds
        return [(i, j, s) for i in range(len(self.scenarios))
                for j in range(len(self.controllers)) for s in seeds]

    def mission(self, i, j, spec=None):
        """The mission of scenario i flown by controller j (with ``spec`` instead of its own
        :class:`~mavadrc.mission.config.ControllerSpec`, when given)."""
        sc = self.scenarios[i]
        m = copy.copy(sc.mission)
        m.controller = spec if spec is not None else self.controllers[j].spec
        if sc.attitude_match:
            m.attitude_controller = MATCHING_ATTITUDE[self.controllers[j].kind]
        if sc.sample_rate_hz is not None:
            m.controller = dataclasses.replace(m.controller, rate_hz=sc.sample_rate_hz)
        if sc.input_model_scale != 1.0 and "input_lag" in m.controller.gains:
            if m.controller.gains["input_lag"] == "auto":
                # scaled once identified (mavadrc.fast.identify.with_identified)
                m.input_model_scale = sc.input_model_scale
            else:
                g = m.controller.gains
                m.controller = dataclasses.replace(m.controller, gains={
                    **g, **{key: tuple(sc.input_model_scale * float(t) for t in g[key])
                            for key in ("input_lag", "input_dead_time") if key in g}})
        return m


def _merged(defaults, item, skip=()):
    """``item`` over ``defaults`` (top-level keys, those in ``skip`` left out), keeping each
    key's line, and for a key from the defaults that it was written there (errors about it
    name ``defaults``, not the scenario)."""
    out = YamlMap(line=getattr(item, "line", None))
    for src, origin in ((defaults, "defaults"), (item, None)):
        if src is None:
            continue
        lines = getattr(src, "lines", None) or {}
        for k, v in src.items():
            if k in skip:
                continue
            out[k] = v
            out.lines.pop(k, None)
            out.origins.pop(k, None)
            if k in lines:
                out.lines[k] = lines[k]
            if origin is not None:
                out.origins[k] = origin
    return out


#: scenario keys that belong to the experiment, not to the scenario's mission
SCENARIO_KEYS = ("name", "group", "note", "settle_s", "series", "thesis", "attitude_controller",
                 "sample_rate_hz", "input_model_scale", "sitl")
#: the physics rate of the bundled vehicle (Hz): a scenario's sample rate divides it
PHYSICS_RATE_HZ = 1000.0


def load_experiment(path):
    """Read and check an experiment file (a path, or a name in configs/experiments)."""
    path = Path(path) if Path(str(path)).exists() else config_path(path, "experiments")
    return experiment_from_text(str(path), Path(path).read_text())


@functools.lru_cache(maxsize=8)
def experiment_from_text(source, text):
    """An :class:`Experiment` from YAML text (``source`` names it in errors); cached."""
    data = load_yaml(source, text=text)
    top = Section(data, source)
    name = top.string("name", Path(source).stem)
    description = top.string("description", "")
    seeds_raw = top.raw("seeds", 1)
    if isinstance(seeds_raw, list):
        seeds = [int(s) for s in top.vector("seeds", len(seeds_raw), ge=0)]
    else:
        n = int(top.number("seeds", 1, ge=1))
        top.check("seeds", n == top.data.get("seeds", 1), "must be a whole number")
        seeds = list(range(n))
    defaults = top.raw("defaults", None)
    if defaults is not None and not isinstance(defaults, dict):
        top.error("defaults", f"must be a mapping of mission keys (got {described(defaults)})")
    controllers = []
    for cs in top.sections("controllers"):
        spec = read_controller(cs, kinds=CONTROLLER_KINDS)
        label = spec.name or spec.kind.upper()
        if any(c.name == label for c in controllers):
            cs.error("name", f"two controllers are called {label!r}")
        controllers.append(ControllerEntry(label, spec))
    if not controllers:
        top.error("controllers", "must list at least one controller")
    scenarios = []
    raw_scenarios = top.raw("scenarios")
    top.check("scenarios", isinstance(raw_scenarios, list),
              f"must be a list (got {described(raw_scenarios)})")
    lines = getattr(raw_scenarios, "lines", None)
    for n, raw in enumerate(raw_scenarios):
        if not isinstance(raw, dict):
            top.error("scenarios", f"item {n} must be a mapping (got {described(raw)})")
        where = f"scenarios[{n}]"
        sec = Section(_merged(defaults, raw), source, where, line=lines[n] if lines else None)
        sname = sec.string("name")
        if any(s.name == sname for s in scenarios):
            sec.error("name", f"two scenarios are called {sname!r}")
        group = sec.string("group", "")
        note = sec.string("note", "")
        settle = sec.number("settle_s", 0.0, ge=0.0)
        points = []
        for ss in (sec.sections("series") if isinstance(sec.raw("series", None), list)
                   else [sec.section("series")] if sec.has("series") else []):
            p = {"name": ss.string("name"), "value": ss.number("value"),
                 "unit": ss.string("unit", "")}
            ss.check("name", all(q["name"] != p["name"] for q in points),
                     f"the scenario is already a point of {p['name']!r}")
            ss.finish()
            points.append(p)
        series = points[0] if points else None
        thesis = {}
        if sec.has("thesis"):
            ts = sec.section("thesis")
            for ctrl_name in list(ts.data):
                cs = ts.section(ctrl_name)
                fig = {}
                for key in ("max_error_xyz_m", "max_velocity_error_xyz_ms"):
                    if cs.has(key):
                        fig[key] = list(cs.vector(key, 3, ge=0.0))
                if cs.has("max_error_m"):
                    fig["max_error_m"] = cs.number("max_error_m", ge=0.0)
                fig["note"] = cs.string("note", "")
                cs.finish()
                thesis[str(ctrl_name)] = fig
            ts.finish()
        match = sec.string("attitude_controller", None, choices=("match",)) == "match"
        rate = sec.number("sample_rate_hz", None, ge=5.0, le=500.0)
        if rate is not None:
            sec.check("sample_rate_hz", abs(PHYSICS_RATE_HZ / rate - round(PHYSICS_RATE_HZ / rate))
                      < 1e-9, f"must divide the vehicle's {PHYSICS_RATE_HZ:g} Hz physics rate "
                              "(25, 50, 100, 125, 200, 250, 500 Hz ...)")
        model_scale = sec.number("input_model_scale", 1.0, gt=0.0, le=10.0)
        sitl = read_scenario_sitl(sec)
        # the rest is a mission (without a controller, which the matrix supplies); its own
        # section refuses unknown keys
        msec = Section(_merged(defaults, raw, SCENARIO_KEYS), source, where, line=sec.line())
        msec.allow(*SCENARIO_KEYS)
        mission = mission_from_section(msec, source, text, sname, require_land=False,
                                       controller=False)
        mission.settle_s = settle
        if match and mission.attitude_bandwidth_scale != 1.0:
            sec.error("attitude_controller", "match flies other attitude loops than the PX4-like "
                                             "one sim.attitude_bandwidth_scale scales")
        scenarios.append(Scenario(sname, group, mission, settle, series, thesis, match, note,
                                  rate, model_scale, points, sitl))
    if not scenarios:
        top.error("scenarios", "must list at least one scenario")
    goals = []
    for gs in top.sections("goals", []):
        pats = gs.raw("scenario")
        pats = pats if isinstance(pats, list) else [gs.string("scenario")]
        gs.check("scenario", bool(pats) and all(isinstance(p, str) for p in pats),
                 "must be a scenario name pattern or a list of them")
        g = {"scenario": " | ".join(pats), "patterns": list(pats), "metric": gs.string("metric"),
             "controllers": [str(c) for c in gs.raw("controllers")],
             "ratio_to": gs.string("ratio_to", None),
             "at_most": gs.number("at_most", None), "at_least": gs.number("at_least", None),
             "text": gs.string("text", ""),
             "over": gs.string("over", "each", choices=("each", "all"))}
        names = [c.name for c in controllers]

        def named(c, key):  # a controller's name, in either case
            found = choose(c, names)
            gs.check(key, found is not None, f"no controller called {c!r} (the experiment's: "
                                             f"{', '.join(names)}{did_you_mean(c, names)})")
            return found

        g["controllers"] = [named(c, "controllers") for c in g["controllers"]]
        if g["ratio_to"]:
            g["ratio_to"] = named(g["ratio_to"], "ratio_to")
        gs.check("metric", g["at_most"] is not None or g["at_least"] is not None,
                 "give at_most or at_least")
        gs.finish()
        goals.append(g)
    breaks = []
    for bs in top.sections("breaks", []):
        b = {"series": bs.string("series"), "metric": bs.string("metric"),
             "above": bs.number("above"), "nominal": bs.number("nominal", None)}
        values = [sc.point(b["series"])["value"] for sc in scenarios if sc.point(b["series"])]
        bs.check("series", bool(values), f"no scenario has series {b['series']!r}")
        if b["nominal"] is not None:
            shown = ", ".join(f"{v:g}" for v in sorted(values))
            bs.check("nominal", any(abs(v - b["nominal"]) < 1e-12 for v in values),
                     f"must be one of the series' values ({shown})")
        bs.finish()
        breaks.append(b)
    sitl = read_sitl_section(top)
    top.finish()
    return Experiment(name, source, text, description, controllers, scenarios, seeds, goals,
                      breaks, sitl)


def goal_covers(g, name):
    """Whether goal ``g`` judges the scenario called ``name`` (any of its name patterns)."""
    return any(fnmatch.fnmatchcase(name, p) for p in g["patterns"])


# --- one run -------------------------------------------------------------------------------------

def metric(record, path):
    """A record's value at a dotted path ('after_settle.max_error_m', with list indices:
    'after_settle.rms_error_xyz_m.0'); NaN if absent."""
    v = record
    for part in path.split("."):
        if isinstance(v, dict) and part in v:
            v = v[part]
        elif isinstance(v, (list, tuple)) and part.isdigit() and int(part) < len(v):
            v = v[int(part)]
        else:
            return math.nan
    return float(v) if v is not None else math.nan


def summarise(t, ref, pos, acc_cmd, acc_applied, thrust, *, settle_s, duration, thrust_min,
              thrust_max, dt, aborted=None, yaw=None, ref_yaw=None, ref_acc=None,
              true_dist=None, hover_thrust=None, roll=None, pitch=None):
    """The record's figures from a run's per-step arrays (either path).

    With the reference acceleration, the simulator's true disturbance and the hover thrust, the
    thrust the *scenario* demands is checked too: |a_ref - d - g e3| * hover / g against the
    thrust limit, whatever the controller did.  With the vehicle's roll and pitch, the
    roll/pitch oscillation over the tracking window (:func:`mavadrc.flight.record.attitude_oscillation`:
    ``after_settle.attitude_oscillation_deg``, ``_hz`` and ``_regularity``): a limit cycle shows
    there whatever the position error says, and the joining manoeuvre does not."""
    t = np.asarray(t, dtype=float)
    out = error_figures(t, ref, pos)
    out["after_settle"] = error_figures(t, ref, pos, settle_s)
    if roll is not None and pitch is not None:
        keep = t >= settle_s
        osc = attitude_oscillation(t[keep], np.asarray(roll)[keep], np.asarray(pitch)[keep])
        out["after_settle"]["attitude_oscillation_deg"] = osc["amplitude_deg"] if osc else math.nan
        out["after_settle"]["attitude_oscillation_hz"] = osc["frequency_hz"] if osc else math.nan
        # how alike the swing is to itself three periods later (a limit cycle: >= 0.6)
        like = osc["regularity"] if osc else None
        out["after_settle"]["attitude_oscillation_regularity"] = math.nan if like is None else like
    join = t < settle_s
    out["joining"] = error_figures(t[join], np.asarray(ref)[join], np.asarray(pos)[join])
    track = t >= settle_s
    acc = np.asarray(acc_applied, dtype=float)
    limited = np.any(np.abs(np.asarray(acc_cmd, dtype=float) - acc) > 1e-6, axis=1)
    thr = np.asarray(thrust, dtype=float)
    at_limit = (thr >= thrust_max - 1e-6) | (thr <= thrust_min + 1e-6)
    n_track = int(track.sum())
    out["effort_rms_accel"] = float(np.sqrt(np.mean(np.sum(acc[track] ** 2, axis=1)))) \
        if n_track else math.nan
    out["thrust_saturated_s"] = float(at_limit.sum() * dt)
    out["limited_s"] = float(limited.sum() * dt)
    share = float(at_limit[track].mean()) if n_track else 1.0
    need_share = 0.0
    if ref_acc is not None and true_dist is not None and hover_thrust is not None and n_track:
        need = np.asarray(ref_acc, dtype=float) - np.asarray(true_dist, dtype=float)
        need[:, 2] -= 9.80665
        demand = np.linalg.norm(need, axis=1) * hover_thrust / 9.80665
        ok = np.isfinite(demand[track])
        if ok.any():
            need_share = float((demand[track][ok] > thrust_max).mean())
            out["thrust_demand_max"] = float(demand[track][ok].max())
    completed = aborted is None and t.size > 0 and t[-1] >= duration - 1e-6
    out["completed"] = bool(completed)
    # the reference climbs away from the ground and the vehicle never follows it up
    grounded = t.size > 0 and _never_lifted(np.asarray(ref, dtype=float),
                                            np.asarray(pos, dtype=float))
    out["aborted"] = aborted
    out["duration_s"] = float(t[-1]) if t.size else 0.0
    out["feasible"] = bool(completed and not grounded and share <= SATURATION_SHARE
                           and need_share <= SATURATION_SHARE)
    if not completed:
        out["infeasible_reason"] = f"{aborted or 'stopped early'} at {out['duration_s']:.1f} s"
    elif need_share > SATURATION_SHARE:
        out["infeasible_reason"] = (f"the scenario needs up to {out['thrust_demand_max']:.1f}x "
                                    "the vehicle's maximum thrust")
    elif grounded:
        out["infeasible_reason"] = "the vehicle never left the ground"
    elif share > SATURATION_SHARE:
        out["infeasible_reason"] = f"thrust at its limit {100 * share:.0f} % of the tracking window"
    if yaw is not None and ref_yaw is not None:
        out["yaw_step"] = _yaw_step(t, np.asarray(yaw), np.asarray(ref_yaw))
    return out


def _never_lifted(ref, pos):
    """Whether a run that starts on the ground (the first sample) stayed there while its
    reference rose half a metre above it (:data:`mavadrc.mission.takeoff.LIFTOFF_HEIGHT` never reached)."""
    from mavadrc.mission.takeoff import LIFTOFF_HEIGHT

    ground = pos[0, 2]
    return bool(np.max(ground - ref[:, 2]) > 0.5 and np.max(ground - pos[:, 2]) < LIFTOFF_HEIGHT)


def _yaw_step(t, yaw, ref_yaw):
    """Step-response figures of the largest jump in the yaw reference, if there is one."""
    jumps = np.abs(np.diff(np.unwrap(ref_yaw)))
    if jumps.size == 0 or jumps.max() < math.radians(0.5):
        return None
    k = int(np.argmax(jumps)) + 1
    y0, y1 = float(np.unwrap(ref_yaw)[k - 1]), float(np.unwrap(ref_yaw)[k])
    step = y1 - y0
    y = (np.unwrap(yaw[k:]) - y0) / step
    tt = t[k:] - t[k]
    over = float(max(0.0, y.max() - 1.0) * 100.0)
    rise = tt[np.argmax(y >= 0.9)] - tt[np.argmax(y >= 0.1)] if np.any(y >= 0.9) else math.nan
    outside = np.nonzero(np.abs(y - 1.0) > 0.02)[0]
    settle = float(tt[outside[-1] + 1]) if outside.size and outside[-1] + 1 < tt.size else (
        0.0 if not outside.size else math.nan)
    return {"step_deg": math.degrees(step), "overshoot_pct": over, "rise_time_s": float(rise),
            "settling_time_s": settle,
            "steady_error_deg": float(abs(math.degrees(step * (1.0 - y[-1]))))}


def run_inprocess(exp, i, j, seed, keep_log=False, spec=None):
    """Scenario i x controller j x seed on the fast path; returns (record, log or None).
    ``spec``: other gains for controller j (a ControllerSpec of the same kind)."""
    from mavadrc.fast.fly import fly_inprocess
    from mavadrc.fast.identify import with_identified
    from mavadrc.fast.inprocess import (
        L_ACC,
        L_ACC_CMD,
        L_DIST,
        L_PITCH,
        L_POS,
        L_REF,
        L_REF_ACC,
        L_REF_YAW,
        L_ROLL,
        L_T,
        L_THRUST,
        L_YAW,
    )
    m = with_identified(exp.mission(i, j, spec), exp.controllers[j].kind, seed)
    t0 = time.perf_counter()
    r = fly_inprocess(m, kind=exp.controllers[j].kind, seed=seed)
    wall = time.perf_counter() - t0
    L = r.log
    cols = {"t": L[:, L_T], "ref": L[:, L_REF:L_REF + 3], "pos": L[:, L_POS:L_POS + 3],
            "acc_cmd": L[:, L_ACC_CMD:L_ACC_CMD + 3], "acc": L[:, L_ACC:L_ACC + 3],
            "thrust": L[:, L_THRUST], "ref_acc": L[:, L_REF_ACC:L_REF_ACC + 3],
            "dist": L[:, L_DIST:L_DIST + 3], "yaw": L[:, L_YAW], "ref_yaw": L[:, L_REF_YAW],
            "roll": L[:, L_ROLL], "pitch": L[:, L_PITCH]}
    rec = _run_record(exp, i, j, seed, "inprocess", m, cols, r.duration, r.aborted,
                      r.hover_thrust, wall, r.hover_thrust_learnt)
    return rec, (L if keep_log else None)


def run_mavlink(exp, i, j, seed, out_dir):
    """The same run flown over MAVLink against the bundled vehicle in lockstep."""
    import io

    from mavadrc.fast.identify import with_identified
    from mavadrc.fast.inprocess import MISSION_START
    from mavadrc.flight.fly import fly
    from mavadrc.flight.record import read_table
    kind = exp.controllers[j].kind
    if kind == "oracle":
        raise ValueError("the oracle needs the simulator's internals: it runs in process only")
    # identified as on the fast path (same flight, same fit), so both paths fly the same gains
    m = with_identified(exp.mission(i, j), kind, seed)
    t0 = time.perf_counter()
    summary, folder = fly(m, kind=kind, out=str(out_dir), lockstep=True, seed=seed,
                          progress=False, stream=io.StringIO(),
                          start_at=MISSION_START, timeout=600.0)
    wall = time.perf_counter() - t0
    tab = read_table(Path(folder) / "controller.csv")
    # the mission's steps: not the final descent into the ground past its end
    keep = np.array([p != "touchdown" for p in tab["phase"]], dtype=bool)
    tab = {k: (v[keep] if isinstance(v, np.ndarray) else [x for x, ok in zip(v, keep) if ok])
           for k, v in tab.items()}

    def xyz(prefix):
        return np.column_stack([tab[f"{prefix}{a}"] for a in "xyz"])

    cols = {"t": tab["t"], "ref": xyz("ref_"), "pos": xyz("pos_"), "acc_cmd": xyz("acc_cmd_"),
            "acc": xyz("acc_applied_"), "thrust": tab["thrust"], "ref_acc": xyz("ref_a"),
            "dist": xyz("true_dist_"), "yaw": tab["yaw"], "ref_yaw": tab["ref_yaw"]}
    traj, _ = m.build_trajectory()
    aborted = "; ".join(summary.get("aborted") or []) or None
    rec = _run_record(exp, i, j, seed, "mavlink", m, cols, traj.duration, aborted,
                      summary["hover_thrust"], wall, summary.get("hover_thrust_learnt"))
    rec["record_folder"] = str(folder)
    return rec, None


def _run_record(exp, i, j, seed, via, m, cols, duration, aborted, hover_thrust, wall,
                hover_thrust_learnt=None):
    """The record of one run from its per-step columns (either path); ``hover_thrust_learnt``:
    what the controller had learnt by the end (None: it does not learn)."""
    sc = exp.scenarios[i]
    c = exp.controllers[j]
    rec = {"scenario": sc.name, "group": sc.group, "controller": c.name, "kind": c.kind,
           "seed": int(seed), "via": via, "settle_s": sc.settle_s,
           "attitude_controller": m.attitude_controller}
    if sc.series:
        rec["series"] = dict(sc.series)
    # yaw step figures only where the scenario is about the attitude loop
    yaw = {"yaw": cols["yaw"], "ref_yaw": cols["ref_yaw"]} if sc.attitude_match else {}
    rec.update(summarise(cols["t"], cols["ref"], cols["pos"], cols["acc_cmd"], cols["acc"],
                         cols["thrust"], settle_s=sc.settle_s, duration=duration,
                         thrust_min=m.controller.thrust_min, thrust_max=m.controller.thrust_max,
                         dt=1.0 / m.controller.rate_hz, aborted=aborted,
                         ref_acc=cols["ref_acc"], true_dist=cols["dist"],
                         hover_thrust=hover_thrust, roll=cols.get("roll"),
                         pitch=cols.get("pitch"), **yaw))
    if c.kind != "oracle":
        from mavadrc.design.gains import spec_margin

        rec["delay_margin_s"] = spec_margin(m.controller, c.kind, m.vehicle or "crazyflie",
                                            m.attitude_controller)
    if m.identification is not None:  # input_lag: auto, as identified on the vehicle
        rec["input_lag_identified"] = list(m.identification["input_lag"])
    rec["hover_thrust_learnt"] = hover_thrust_learnt
    rec["wall_s"] = wall
    return rec


def run_task(task):
    """One run from a picklable task (source, text, i, j, seed, via, keep_log, out_dir): what a
    local worker process or a Dask worker executes."""
    source, text, i, j, seed, via, keep_log, out_dir = task
    exp = experiment_from_text(source, text)
    if via == "mavlink":
        return run_mavlink(exp, i, j, seed, out_dir)
    return run_inprocess(exp, i, j, seed, keep_log)
