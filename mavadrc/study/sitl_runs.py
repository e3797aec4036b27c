"""`mavadrc compare EXPERIMENT --sitl ...`: every run flown against a fresh SITL process.

For each run (scenario x controller x seed), one at a time: a fresh SITL in a scratch folder of
the run's own (:mod:`mavadrc.study.sitl_launch`), its parameters set and read back (the
scenario's wind as the autopilot's, GUID_OPTIONS on ArduCopter, the experiment's), a wait until
it can arm, then ``mavadrc fly RUN/mission.yaml --connect URL`` as a process of its own, and the
SITL stopped.  The run's record comes from the flight's summary.json: the errors by the
autopilot's estimate (the controller's: estimate - reference), by the simulator's truth (truth -
reference) and between the two (the estimator's: truth - estimate).

The results folder is resumable: each finished run leaves ``runs/SCENARIO/CONTROLLER/seedN/
record.json``; the same command on the same folder skips those (a run whose mission or SITL
settings changed since is flown again) and flies the rest.
"""

import copy
import dataclasses
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from mavadrc.errors import UsageError
from mavadrc.flight.console import Steps, counted
from mavadrc.flight.embedded import plain
from mavadrc.study.experiment import MATCHING_ATTITUDE, SCENARIO_KEYS
from mavadrc.study.sitl_config import (
    AUTOPILOT_NAMES,
    BUNDLED,
    autopilot_wind,
    flight_altitude,
    heading_of,
    scenario_autopilot,
)
from mavadrc.study.sitl_launch import (
    SitlPlan,
    SitlProcess,
    prepare,
    project_env,
    stop_process,
)

#: seconds a SITL may take to become armable (ArduCopter's EKF: ~40 s; PX4 SIH: ~6-10 s)
READY_TIMEOUT_S = 180.0
#: seconds a flight may take beyond its mission (identification, landing, disarm)
FLIGHT_MARGIN_S = 150.0
#: seconds a flight is given to land after a Ctrl-C before it is stopped
LANDING_GRACE_S = 30.0
RECORD = "record.json"


def _slug(text):
    return "".join(ch if ch.isalnum() or ch in "-." else "_" for ch in str(text)).strip("_")


def run_folder(out, exp, i, j, seed):
    return (Path(out) / "runs" / _slug(exp.scenarios[i].name) /
            _slug(exp.controllers[j].name) / f"seed{seed}")


def mission_doc(exp, i, j):
    """The mission ``mavadrc fly`` flies for scenario i and controller j: the scenario's keys
    over the defaults, the controller's section, its settling time, a landing at the end; no
    ``wind:`` nor ``sim:`` (the SITL is given those)."""
    raw = yaml.safe_load(exp.text)
    sc = exp.scenarios[i]
    merged = {**(raw.get("defaults") or {}), **raw["scenarios"][i]}
    doc = {"name": f"{sc.name} / {exp.controllers[j].name}"}
    doc.update({k: copy.deepcopy(v) for k, v in merged.items()
                if k not in SCENARIO_KEYS and k not in ("wind", "sim", "logging")})
    ctrl = copy.deepcopy(raw["controllers"][j])
    if sc.sample_rate_hz is not None:
        ctrl["rate_hz"] = sc.sample_rate_hz
    doc["controller"] = ctrl
    if not (doc["trajectory"] and "land" in doc["trajectory"][-1]):
        doc["trajectory"].append({"land": {"speed": 0.5}})
    doc["logging"] = {"settle_s": float(sc.settle_s)}
    return doc


def sitl_plan(exp, i, j, seed, autopilot, given, run_dir):
    """The :class:`SitlPlan` of scenario i's run by controller j on ``autopilot`` (``given``: its entry of
    :func:`~mavadrc.study.sitl_config.parse_sitl_options`); ValueError when the scenario asks
    what that SITL cannot do."""
    sc = exp.scenarios[i]
    m = sc.mission
    bundled = given["path"] == BUNDLED
    heading = heading_of(m)
    if autopilot == "px4" and not bundled and heading != 0.0:
        raise ValueError("PX4 SIH always starts facing north: heading_deg must be 0")
    if not bundled and sc.input_model_scale != 1.0:
        raise ValueError("input_model_scale scales the bundled vehicle's observers' model: not "
                         "for a real autopilot")
    params = dict(given["params"])
    params.update(autopilot_wind(autopilot, m.wind, flight_altitude(m), bundled))
    if autopilot == "ardupilot":
        params["GUID_OPTIONS"] = 8  # SET_ATTITUDE_TARGET's thrust is thrust, not a climb rate
    params.update(sc.sitl["params"])
    args = []
    if bundled:
        args = ["--vehicle", m.vehicle or "crazyflie", "--seed", str(int(seed))]
        if m.wind is not None:
            wind = m.wind if isinstance(m.wind, dict) else yaml.safe_load(
                Path(_wind_file(m.wind)).read_text())
            path = Path(run_dir) / "wind.yaml"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(yaml.safe_dump(plain(wind)))
            args += ["--wind", str(path)]
        if m.noise:
            args.append("--noise")
        if m.wander > 0.0:
            args += ["--wander", f"{m.wander:g}"]
        if m.rangefinder:
            args.append("--rangefinder")
        att = m.attitude_controller
        if sc.attitude_match:
            att = MATCHING_ATTITUDE.get(exp.controllers[j].kind, "px4")
        args += ["--attitude-controller", att]
    return SitlPlan(autopilot, None if bundled else given["path"], sc.sitl["frame"], heading,
                    params, args)


def _wind_file(name):
    from sim.yamlio import config_path
    return config_path(name, "wind")


def run_key(doc, plan):
    """A digest of what decides a run: its mission and its SITL's settings."""
    text = json.dumps({"mission": plain(doc), "plan": dataclasses.asdict(plan)},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def finished(run_dir, key):
    """The record of a run finished with the same key, or None."""
    try:
        rec = json.loads((Path(run_dir) / RECORD).read_text())
    except (OSError, ValueError):
        return None
    return rec if rec.get("run_key") == key else None


def save_record(run_dir, rec):
    from mavadrc.study.compare import _finite

    tmp = Path(run_dir) / (RECORD + ".tmp")
    tmp.write_text(json.dumps(_finite(rec), indent=1) + "\n")
    os.replace(tmp, Path(run_dir) / RECORD)


def fly_command(mission_path, url, out, timeout):
    return [sys.executable, "-m", "mavadrc", "fly", str(mission_path), "--connect", url,
            "--out", str(out), "--no-figures", "-q", "--timeout", f"{timeout:.0f}"]


def fly_flight(argv, log_path, timeout):
    """Run the flight ``argv`` (its console to ``log_path``); returns its exit status.  On
    Ctrl-C (or any exception) the flight is given :data:`LANDING_GRACE_S` to land, then
    stopped, and the exception goes on."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(argv, env=project_env(), stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)  # it lands, as on a Ctrl-C
            try:
                return proc.wait(timeout=LANDING_GRACE_S)
            except subprocess.TimeoutExpired:
                return stop_process(proc)
        except BaseException:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=LANDING_GRACE_S)
                except subprocess.TimeoutExpired:
                    pass
                stop_process(proc)
            raise


def flight_folder(out):
    """The record folder ``mavadrc fly --out OUT`` wrote (the newest with a summary.json)."""
    found = sorted(Path(out).glob("*/summary.json"), key=lambda p: p.stat().st_mtime)
    return found[-1].parent if found else None


def score(summary, base):
    """A run's record from its flight's ``summary`` over ``base`` (its names and settings)."""
    rec = dict(base)
    errs = ("rms_error_m", "max_error_m", "rms_error_xyz_m", "max_error_xyz_m")
    for k in errs:
        rec[k] = summary.get(k)
    rec["after_settle"] = summary.get("after_settle") or {k: summary.get(k) for k in errs}
    truth = summary.get("truth")
    if truth:
        rec["truth"] = {k: truth.get(k) for k in errs + ("source", "samples", "rate_hz")}
        rec["truth"]["after_settle"] = truth.get("after_settle") or {k: truth.get(k)
                                                                      for k in errs}
        est = truth.get("estimate_error") or {}
        rec["estimator_error"] = {k: est.get(k) for k in ("rms_m", "max_m", "rms_xyz_m",
                                                          "max_xyz_m")}
    else:
        rec["truth"] = None
        rec["estimator_error"] = None
    aborted = summary.get("aborted") or []
    rec.update(completed=not aborted, feasible=not aborted, aborted="; ".join(aborted) or None,
               landed=bool(summary.get("landed")), duration_s=summary.get("duration_s"),
               hover_thrust=summary.get("hover_thrust"),
               hover_thrust_learnt=summary.get("hover_thrust_learnt"),
               identification=summary.get("identification"),
               truth_source=(summary.get("sources") or {}).get("truth"))
    if aborted:
        rec["infeasible_reason"] = "; ".join(aborted)
    return rec


def fly_run(exp, i, j, seed, autopilot, given, out, ready_timeout, say):
    """Fly one run against a fresh SITL; returns its record (saved in its folder), or None when
    the flight left no summary (said)."""
    run_dir = run_folder(out, exp, i, j, seed)
    doc = mission_doc(exp, i, j)
    plan = sitl_plan(exp, i, j, seed, autopilot, given, run_dir)
    key = run_key(doc, plan)
    run_dir.mkdir(parents=True, exist_ok=True)
    mission_path = run_dir / "mission.yaml"
    mission_path.write_text(yaml.safe_dump(plain(doc), sort_keys=False))
    traj, _ = exp.mission(i, j).build_trajectory()
    timeout = traj.duration + FLIGHT_MARGIN_S
    flight_out = run_dir / "flight"
    t0 = time.monotonic()
    with SitlProcess(plan, run_dir / "sitl") as sitl:
        values, skipped = prepare(sitl, plan.params, ready_timeout)
        ready_s = time.monotonic() - t0
        status = fly_flight(fly_command(mission_path, sitl.url, flight_out, timeout),
                            run_dir / "fly.log", timeout + 60.0)
    folder = flight_folder(flight_out)
    if status == 2:
        raise UsageError(f"mavadrc fly refused the run's mission {mission_path}: see "
                         f"{run_dir / 'fly.log'}")
    if folder is None:
        say(f"{exp.scenarios[i].name} / {exp.controllers[j].name} / seed {seed}: the flight "
            f"left no summary (exit {status}); see {run_dir / 'fly.log'}")
        return None
    summary = json.loads((folder / "summary.json").read_text())
    sc, c = exp.scenarios[i], exp.controllers[j]
    base = {"scenario": sc.name, "group": sc.group, "controller": c.name, "kind": c.kind,
            "seed": int(seed), "via": "sitl", "autopilot": autopilot,
            "sitl": plan.describe(), "frame": plan.frame, "settle_s": sc.settle_s,
            "params_set": values, "params_skipped": skipped, "ready_s": round(ready_s, 1),
            "exit_status": status,
            "record_folder": str(folder), "run_key": key}
    if sc.series:
        base["series"] = dict(sc.series)
    rec = score(summary, base)
    rec["wall_s"] = round(time.monotonic() - t0, 1)
    save_record(run_dir, rec)
    return rec


def planned_runs(exp, given, seeds, out, say):
    """[(i, j, seed, autopilot)] of the runs the SITLs ``given`` can fly, each checked now
    (UsageError naming the scenario before anything starts); the others said."""
    runs, skipped = [], {}
    for i, sc in enumerate(exp.scenarios):
        ap = scenario_autopilot(sc.name, sc.sitl, given)
        if ap is None:
            skipped[sc.sitl["autopilot"]] = skipped.get(sc.sitl["autopilot"], 0) + 1
            continue
        for j, c in enumerate(exp.controllers):
            if c.kind == "oracle":
                continue
            try:
                sitl_plan(exp, i, j, seeds[0], ap, given[ap], run_folder(out, exp, i, j, seeds[0]))
                mission_doc(exp, i, j)
            except ValueError as exc:
                raise UsageError(f"scenario {sc.name!r} on {AUTOPILOT_NAMES[ap]}: {exc}") \
                    from None
            runs += [(i, j, s, ap) for s in seeds]
    for ap, n in skipped.items():
        say(f"{counted(n, 'scenario')} for {AUTOPILOT_NAMES[ap]} skipped: no --sitl {ap}=PATH")
    if any(c.kind == "oracle" for c in exp.controllers):
        say("the oracle's runs skipped: it runs in process only")
    return runs


def run_sitl(exp, given, *, out, seeds=None, progress=True, stream=None,
             ready_timeout=READY_TIMEOUT_S):
    """Fly the experiment's runs against the SITLs ``given``; returns (records, meta).  Runs
    already finished in ``out`` are skipped; each new one is saved as it finishes."""
    stream = stream if stream is not None else sys.stderr

    def say(text):
        stream.write(text + "\n")
        stream.flush()

    seeds = list(exp.seeds if seeds is None else seeds)
    runs = planned_runs(exp, given, seeds, out, say)
    if not runs:
        raise UsageError("no scenario of the experiment is for the autopilots given "
                         f"({', '.join(given)})")
    todo, records = [], {}
    for r in runs:
        i, j, s, ap = r
        run_dir = run_folder(out, exp, i, j, s)
        rec = finished(run_dir, run_key(mission_doc(exp, i, j),
                                        sitl_plan(exp, i, j, s, ap, given[ap], run_dir)))
        if rec is not None:
            records[r] = rec
        else:
            todo.append(r)
    if records:
        say(f"{counted(len(records), 'finished run')} skipped (their records are in {out}); "
            f"{len(todo)} to fly")
    # the runs flown now (a rate over skipped ones would say nothing)
    bar = Steps(len(todo), "run", out=stream, enabled=progress and bool(todo))
    failed = []
    t0 = time.perf_counter()
    for r in todo:
        i, j, s, ap = r
        bar.describe(f"{exp.scenarios[i].name} / {exp.controllers[j].name} / seed {s}")
        rec = fly_run(exp, i, j, s, ap, given[ap], out, ready_timeout, say)
        if rec is None:
            failed.append(r)
        else:
            records[r] = rec
        bar.step()
    wall = time.perf_counter() - t0
    if failed:
        say(f"{counted(len(failed), 'run')} left no record; the same command flies them again")
    ordered = [records[r] for r in runs if r in records]
    flown = len(todo) - len(failed)
    meta = {"seeds": seeds, "via": "sitl", "scheduler": None, "runs": len(ordered),
            "runs_flown": flown, "runs_skipped": len(runs) - len(todo),
            "runs_failed": len(failed), "wall_s": wall,
            "runs_per_s": flown / wall if wall > 0 and flown else 0.0,
            "sitl": {ap: g["path"] for ap, g in given.items()}}
    return ordered, meta


def flown_only(exp, records):
    """The experiment with only the scenarios some record is of (a SITL flies those for its
    autopilot alone)."""
    names = {r["scenario"] for r in records}
    return dataclasses.replace(exp, scenarios=[sc for sc in exp.scenarios if sc.name in names])


def compare_sitl(path, sitl, *, out=None, seeds=None, progress=True, stream=None,
                 ready_timeout=READY_TIMEOUT_S):
    """``mavadrc compare PATH --sitl ...``: fly, then write results.json, results.csv and
    report.md in the folder; returns (folder, experiment of the flown scenarios, records)."""
    from mavadrc.flight.fly import check_out_folder
    from mavadrc.study.compare import write_results
    from mavadrc.study.experiment import load_experiment
    from mavadrc.study.report import write_report
    from mavadrc.study.sitl_config import SitlConfigError, parse_sitl_options

    stream = stream if stream is not None else sys.stderr
    if seeds is not None and seeds < 1:
        raise UsageError(f"--seeds {seeds}: must be at least 1 (the runs use seeds 0..N-1)")
    if out:
        check_out_folder(out)
    exp = load_experiment(path)
    try:
        given = parse_sitl_options(sitl, exp.sitl)
    except SitlConfigError as exc:
        raise UsageError(str(exc)) from None
    seed_list = exp.seeds if seeds is None else list(range(int(seeds)))
    folder = Path(out) if out else Path("runs") / f"compare-{Path(exp.source).stem}-sitl"
    folder.mkdir(parents=True, exist_ok=True)
    where = "; ".join(f"{ap}: {'the bundled vehicle' if g['path'] == BUNDLED else g['path']}"
                      for ap, g in given.items())
    stream.write(f"{exp.name}: against SITL processes in real time, one run at a time "
                 f"({where})\n")
    records, meta = run_sitl(exp, given, out=folder, seeds=seed_list, progress=progress,
                             stream=stream, ready_timeout=ready_timeout)
    shown = flown_only(exp, records)
    write_results(folder, exp, records, meta)
    write_report(folder, shown, records, meta, {})
    stream.write(f"{counted(len(records), 'run')} ({meta['runs_flown']} flown now, "
                 f"{meta['runs_skipped']} finished before); report in {folder / 'report.md'}\n")
    return folder, shown, records


def wants_sitl(args):
    """Whether ``mavadrc compare`` flies SITL processes: --sitl given, or the experiment's
    ``sitl:`` section names a path and --via does not say otherwise."""
    if getattr(args, "sitl", None):
        return True
    if args.via is not None:
        return False
    from mavadrc.study.experiment import load_experiment
    from sim.yamlio import ConfigError
    try:
        exp = load_experiment(args.experiment)
    except (ConfigError, OSError, ValueError):
        return False  # compare says what is wrong with it
    return any(s.get("path") for s in exp.sitl.values())


def main(args):
    from mavadrc.study.compare import command_status
    from mavadrc.study.sitl_launch import SitlError

    if args.via is not None or args.scheduler or args.workers:
        print("mavadrc compare: --sitl flies one run at a time against SITL processes: no "
              "--via, --scheduler nor --workers with it", file=sys.stderr)
        return 2
    return command_status(
        lambda: compare_sitl(args.experiment, args.sitl, out=args.out, seeds=args.seeds,
                             progress=not args.quiet, ready_timeout=args.ready_timeout),
        "the SITL and the flight were stopped; the runs finished are kept, and the same "
        "command goes on from there", (SitlError,))
