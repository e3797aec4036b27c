"""`mavadrc tune`: search a controller's bandwidths to minimise the RMS error of an experiment.

The search space is the bandwidth parameterisation every kind shares (Gao's for LADRC, the same
shorthand for the others, see :func:`mavadrc.design.gains.make_controller`): horizontal and vertical
controller bandwidths ``wc`` and, for the observer kinds, the observer-to-controller ratio
``wo / wc`` (up to 6: beyond it the loop through the vehicle's attitude response has too little
margin left); for the classical ADRC also fhan's acceleration bound ``r`` and fal's linear zone
``delta``.  The observers' input model is not searched: it is a property of the vehicle,
measured (``input_lag: auto``), not a knob.  ``b0`` stays 1: the position channels command
acceleration, and the vehicle file's hover thrust turns that into normalized thrust.

The cost is the geometric mean, over the chosen scenarios and seeds (1000, 1001, ...: disjoint
from the seeds an experiment reports), of the RMS 3-D position error after each scenario's
settling window (a run that is infeasible or stops at a safety limit counts as 10 m).  scipy's
differential evolution searches it, evaluating a generation's candidates in parallel worker
processes (``updating='deferred'``), each candidate's runs on the fast path.
"""

import copy
import fnmatch
import math
import sys

import numpy as np

from mavadrc.flight.console import Steps, counted
from mavadrc.study.experiment import (
    experiment_from_text,
    goal_covers,
    load_experiment,
    run_inprocess,
)
from mavadrc.study.pool import default_workers, process_pool, stop_pool
from sim.yamlio import choose, did_you_mean

INFEASIBLE_COST = 10.0
TUNING_SEEDS = 1000  # the first seed a search uses

# (name, lower, upper) per kind; x -> gains in _gains()
SPACES = {
    "ladrc": (("wc_xy", 0.5, 4.0), ("wc_z", 0.5, 8.0), ("wo_ratio", 2.0, 6.0)),
    "adrc": (("wc_xy", 0.5, 4.0), ("wc_z", 0.5, 8.0), ("wo_ratio", 2.0, 6.0),
             ("r", 2.0, 40.0), ("delta", 0.01, 0.5)),
    "pd": (("wc_xy", 0.5, 10.0), ("wc_z", 0.5, 10.0)),
    "oracle": (("wc_xy", 0.5, 10.0), ("wc_z", 0.5, 10.0)),
    "pid": (("wc_xy", 0.3, 6.0), ("wc_z", 0.3, 6.0)),
}


def _gains(kind, x):
    wc = (float(x[0]), float(x[0]), float(x[1]))
    g = {"wc": wc}
    if kind in ("ladrc", "adrc"):
        g["wo"] = tuple(float(x[2]) * w for w in wc)
    if kind == "adrc":  # Han's nonlinear parameters: fhan's acceleration bound, fal's linear zone
        g["r"] = (float(x[3]),) * 3
        g["delta"] = (float(x[4]),) * 3
    return g


def spec_with(spec, kind, x):
    """A copy of ``spec`` with the bandwidth gains of parameter vector x (other keys kept, the
    explicit gains that the bandwidths replace dropped)."""
    s = copy.deepcopy(spec)
    drop = {"kp", "kd", "h1", "beta", "kp_pos", "kp_vel", "ki_vel", "kd_vel"}
    s.gains = {k: v for k, v in s.gains.items() if k not in drop}
    s.gains.update(_gains(kind, x))
    return s


def _cost(exp, j, scenarios, seeds, spec=None):
    """Geometric mean over scenarios and seeds of the RMS error after settling: every scenario
    weighs the same in relative terms, so one hard scenario (metres of error) does not drown
    the others (centimetres).  A scenario the seed does not change is flown once and counts
    for every seed."""
    total = 0.0
    n = 0
    for i in scenarios:
        random = exp.scenarios[i].random
        weight = 1 if random else len(seeds)
        for s in seeds if random else seeds[:1]:
            rec, _ = run_inprocess(exp, i, j, s, spec=spec)
            e = rec["after_settle"]["rms_error_m"]
            ok = rec["feasible"] and math.isfinite(e)
            total += weight * math.log(max(e, 1e-6) if ok else INFEASIBLE_COST)
            n += weight
    return math.exp(total / n)


class _Objective:
    """A candidate's cost (picklable: differential evolution maps it over worker processes)."""

    def __init__(self, source, text, j, scenarios, seeds):
        self.args = (source, text, j, tuple(scenarios), tuple(seeds))

    def __call__(self, x):
        source, text, j, scenarios, seeds = self.args
        exp = experiment_from_text(source, text)
        spec = spec_with(exp.controllers[j].spec, exp.controllers[j].kind, x)
        return _cost(exp, j, scenarios, seeds, spec)


#: a parameter within this share of its range from a bound "sits on" it
ON_BOUND = 0.01


def search_space(kind, overrides=None):
    """[(name, lower, upper)] of ``kind``'s search, with ``overrides`` {name: (lo, hi)}."""
    space = list(SPACES[kind])
    names = [nm for nm, _, _ in space]
    for nm, (lo, hi) in (overrides or {}).items():
        if nm not in names:
            raise ValueError(f"--bounds: {kind} has no parameter {nm!r} (its search: "
                             f"{', '.join(names)})")
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo < hi):
            raise ValueError(f"--bounds {nm}: need 0 < LO < HI (got {lo:g}:{hi:g})")
        space[names.index(nm)] = (nm, float(lo), float(hi))
    return space


def parse_bounds(items):
    """{name: (lo, hi)} from ``NAME=LO:HI`` strings."""
    out = {}
    for item in items or ():
        name, sep, rng = item.partition("=")
        lo, sep2, hi = rng.partition(":")
        try:
            if not (sep and sep2):
                raise ValueError
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise ValueError(f"--bounds: expected NAME=LO:HI (got {item!r})") from None
    return out


def on_bounds(space, x):
    """[(name, value, the bound it sits on)] of the parameters at a bound of their range."""
    out = []
    for (nm, lo, hi), v in zip(space, x):
        margin = ON_BOUND * (hi - lo)
        if v <= lo + margin:
            out.append((nm, float(v), lo))
        elif v >= hi - margin:
            out.append((nm, float(v), hi))
    return out


def judged_on_tuned(exp, controller, idx):
    """The experiment's goals about ``controller`` whose scenarios include ones tuned on:
    [(goal text or metric, [scenario names])]."""
    tuned = {exp.scenarios[i].name for i in idx}
    out = []
    for g in exp.goals:
        if controller not in g["controllers"] and g.get("ratio_to") != controller:
            continue
        hit = sorted(n for n in tuned if goal_covers(g, n))
        if hit:
            out.append((g["text"] or g["metric"], hit))
    return out


def tune(path, controller, *, scenarios="*", seeds=None, maxiter=20, popsize=8, workers=None,
         seed=0, stream=sys.stderr, bounds=None):
    """Run the search; returns a dict with the best gains, its cost and the starting cost.
    ``bounds``: {parameter: (lo, hi)} replacing the kind's default range (:data:`SPACES`)."""
    from scipy.optimize import differential_evolution

    exp = load_experiment(path)
    names = [c.name for c in exp.controllers]
    named = choose(controller, names)  # LADRC or ladrc
    if named is None:
        raise ValueError(f"--controller {controller}: {exp.source} has no controller called "
                         f"that (its controllers: {', '.join(names)}"
                         f"{did_you_mean(controller, names)})")
    controller = named
    j = names.index(controller)
    kind = exp.controllers[j].kind
    if kind == "native":
        raise ValueError(f"--controller {controller}: the autopilot's own position controller "
                         "has no gains of mavadrc's to search (its gains are the autopilot's "
                         "parameters: PX4 MPC_*, ArduCopter PSC_*)")
    patterns = [scenarios] if isinstance(scenarios, str) else list(scenarios)
    idx = [i for i, sc in enumerate(exp.scenarios)
           if any(fnmatch.fnmatchcase(sc.name, p) for p in patterns)]
    if not idx:
        raise ValueError(f"no scenario matches {scenarios!r}")
    # tuned on wind seeds the experiment does not report (it uses 0, 1, ...), so the report's
    # figures are not the ones the search saw
    seed_list = list(range(TUNING_SEEDS, TUNING_SEEDS + (len(exp.seeds) if seeds is None
                                                         else int(seeds))))
    space = search_space(kind, bounds)
    limits = [(lo, hi) for _, lo, hi in space]
    obj = _Objective(exp.source, exp.text, j, idx, seed_list)
    n = default_workers(workers)
    stream.write(f"tuning {controller} ({kind}) on {counted(len(idx), 'scenario')} x "
                 f"{counted(len(seed_list), 'seed')}; search: " + ", ".join(f"{nm} {lo:g}..{hi:g}" for nm, lo, hi in space)
                 + " (--bounds NAME=LO:HI to change)\n")
    for text, names in judged_on_tuned(exp, controller, idx):
        stream.write(f"warning: the goal '{text}' is judged on scenarios tuned on "
                     f"({', '.join(names)}): judge it on held-out scenarios too\n")
    start = _cost(exp, j, idx, seed_list)
    stream.write(f"starting gains cost {start:.4f} m\n")
    evals = [0]
    # on a terminal a tqdm bar over the generations, the best so far as its description; in a
    # log or a pipe one line per generation
    bar = Steps(maxiter, "generation", out=stream) if stream.isatty() else None

    def report(intermediate_result):  # the generation's best, as scipy keeps it
        evals[0] += 1
        r = intermediate_result
        at = ", ".join(f"{nm} {v:.3f}" for (nm, _, _), v in zip(space, r.x))
        if bar is not None:
            bar.describe(f"best {r.fun:.4f} m at {at}")
            bar.step()
            return
        stream.write(f"  generation {evals[0]}/{maxiter}: best {r.fun:.4f} m at {at}\n")
        stream.flush()

    pool = process_pool(n) if n > 1 else None
    mapper = pool.map if pool is not None else map
    try:
        res = differential_evolution(obj, limits, maxiter=maxiter, popsize=popsize, seed=seed,
                                     tol=1e-3, polish=False, updating="deferred",
                                     workers=mapper, callback=report, init="sobol")
    except KeyboardInterrupt:
        if pool is not None:  # the workers ignore SIGINT: stopped, not waited for
            stop_pool(pool)
            pool = None
        raise
    finally:
        if pool is not None:
            pool.shutdown()
        if bar is not None:
            bar.close()
    edges = on_bounds(space, res.x)
    for nm, v, b in edges:
        stream.write(f"warning: {nm} = {v:.4g} sits on its bound {b:g}: the optimum may lie "
                     f"beyond it (--bounds {nm}=LO:HI widens the search)\n")
    worse = not res.fun < start
    if worse:
        # a search that did not beat its start must not hand back worse gains as "tuned"
        stream.write(f"warning: the search found nothing better than the starting gains "
                     f"({res.fun:.4f} against {start:.4f} m): writing the starting gains; give "
                     f"it more --maxiter / --popsize\n")
        best = copy.deepcopy(exp.controllers[j].spec)
        cost = start
    else:
        best = spec_with(exp.controllers[j].spec, kind, res.x)
        cost = float(res.fun)
    return {"controller": controller, "kind": kind, "gains": best.gains, "cost_m": cost,
            "start_cost_m": start, "x": {nm: float(v) for (nm, _, _), v in zip(space, res.x)},
            "evaluations": int(res.nfev), "scenarios": [exp.scenarios[i].name for i in idx],
            "seeds": seed_list, "spec": best, "bounds": {nm: (lo, hi) for nm, lo, hi in space},
            "on_bounds": [nm for nm, _, _ in edges], "improved": not worse}


def controller_yaml(result):
    """The tuned controller as an experiment/mission ``controller`` entry (YAML text)."""
    s = result["spec"]
    lines = ([] if result["improved"] else
             ["# mavadrc tune found nothing better: these are the starting gains"])
    lines += [f"# mavadrc tune: RMS error after settling (geometric mean) {result['cost_m']:.4f} m "
             f"(was {result['start_cost_m']:.4f} m) over "
             f"{counted(len(result['scenarios']), 'scenario')} x "
             f"{counted(len(result['seeds']), 'seed')}, "
             f"{counted(result['evaluations'], 'candidate')}",
             "# search bounds: " + ", ".join(f"{nm} {lo:g}..{hi:g}"
                                             for nm, (lo, hi) in result["bounds"].items())
             + (f"; on a bound: {', '.join(result['on_bounds'])}" if result["on_bounds"]
                else ""),
             f"name: {result['controller']}", f"type: {s.kind}", f"rate_hz: {s.rate_hz:g}",
             f"tilt_max_deg: {s.tilt_max_deg:g}"]
    if s.thrust_tilt != "commanded":  # flown so while tuned: the gains are for it
        lines.append(f"thrust_tilt: {s.thrust_tilt}")
    for k, v in s.gains.items():
        if isinstance(v, (tuple, list)):
            lines.append(f"{k}: [{', '.join(f'{float(a):.4g}' for a in v)}]")
        elif isinstance(v, bool):
            lines.append(f"{k}: {'true' if v else 'false'}")
        else:
            lines.append(f"{k}: {v}")
    return "\n".join(lines) + "\n"


def main(args):
    from sim.yamlio import ConfigError

    try:
        result = tune(args.experiment, args.controller, scenarios=args.scenarios or ["*"],
                      seeds=args.seeds, maxiter=args.maxiter, popsize=args.popsize,
                      workers=args.workers, seed=args.seed,
                      bounds=parse_bounds(getattr(args, "bounds", None)))
    except (ConfigError, OSError, ValueError) as exc:
        print(f"mavadrc tune: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mavadrc tune: interrupted; nothing written", file=sys.stderr)
        return 130
    text = controller_yaml(result)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
        print(f"wrote {args.out}", file=sys.stderr)
    sys.stdout.write(text)
    return 0 if np.isfinite(result["cost_m"]) else 1
