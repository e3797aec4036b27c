"""The report of an experiment: Markdown tables, findings, goals and figures from its records."""

import math
from collections import OrderedDict
from pathlib import Path

import numpy as np

from mavadrc.flight.console import counted
from mavadrc.study.experiment import SATURATION_SHARE, goal_covers, metric

TABLE_METRICS = (
    ("RMS x", "after_settle.rms_error_xyz_m.0"),
    ("RMS y", "after_settle.rms_error_xyz_m.1"),
    ("RMS z", "after_settle.rms_error_xyz_m.2"),
    ("RMS 3-D", "after_settle.rms_error_m"),
    ("max 3-D", "after_settle.max_error_m"),
    ("roll/pitch osc. deg", "after_settle.attitude_oscillation_deg"),
    ("osc. regularity", "after_settle.attitude_oscillation_regularity"),
    ("joining max", "joining.max_error_m"),
    ("effort", "effort_rms_accel"),
    ("thrust sat. s", "thrust_saturated_s"),
    ("limited s", "limited_s"),
)
#: a run against a SITL process (``compare --sitl``): the error by the autopilot's estimate (the
#: controller's: estimate - reference), by the simulator's truth (truth - reference), and the
#: estimator's own (truth - estimate, over the scored span)
SITL_METRICS = TABLE_METRICS[:5] + (
    ("truth RMS x", "truth.after_settle.rms_error_xyz_m.0"),
    ("truth RMS y", "truth.after_settle.rms_error_xyz_m.1"),
    ("truth RMS z", "truth.after_settle.rms_error_xyz_m.2"),
    ("truth RMS 3-D", "truth.after_settle.rms_error_m"),
    ("truth max 3-D", "truth.after_settle.max_error_m"),
    ("estimator RMS 3-D", "estimator_error.rms_m"),
    ("estimator max 3-D", "estimator_error.max_m"),
)


def table_metrics(meta):
    """The columns of a report's scenario tables: the SITL ones for ``compare --sitl``."""
    return SITL_METRICS if meta.get("via") == "sitl" else TABLE_METRICS


def grouped(exp, records):
    """OrderedDict (scenario, controller) -> records over seeds, in the experiment's order."""
    out = OrderedDict()
    for sc in exp.scenarios:
        for c in exp.controllers:
            out[(sc.name, c.name)] = []
    for r in records:
        out.setdefault((r["scenario"], r["controller"]), []).append(r)
    return out


def stat(recs, path):
    """(mean, std) of a metric over runs (NaN-free runs only); (nan, nan) if none."""
    xs = np.array([metric(r, path) for r in recs], dtype=float)
    xs = xs[np.isfinite(xs)]
    if xs.size == 0:
        return math.nan, math.nan
    return float(xs.mean()), float(xs.std(ddof=1)) if xs.size > 1 else 0.0


def _fmt(mean, std, digits=3):
    if not math.isfinite(mean):
        return "-"
    s = f"{mean:.{digits}f}"
    if std and math.isfinite(std) and std > 0.5 * 10 ** -digits:
        s += f" ± {std:.{digits}f}"
    return s


def feasible(recs):
    return all(r.get("feasible", False) for r in recs)


def _status(recs, oracle=False):
    if not recs:
        return "not run (the oracle runs in process only)" if oracle else "not run"
    if feasible(recs):
        return "ok"
    bad = [r for r in recs if not r.get("feasible", False)]
    reason = bad[0].get("infeasible_reason", "infeasible")
    return f"**infeasible** ({len(bad)}/{len(recs)}: {reason})"


def thesis_cell(sc, c):
    fig = sc.thesis.get(c.name) or sc.thesis.get(c.kind) or sc.thesis.get(c.kind.upper())
    if not fig:
        return ""
    parts = []
    if "max_error_xyz_m" in fig:
        parts.append("max x/y/z " + "/".join(f"{v:g}" for v in fig["max_error_xyz_m"]))
    if "max_error_m" in fig:
        parts.append(f"max {fig['max_error_m']:g}")
    if fig.get("note"):
        parts.append(fig["note"])
    return "; ".join(parts)


def scenario_table(exp, sc, groups, metrics=TABLE_METRICS):
    cols = ["controller"] + [name for name, _ in metrics] + ["status"]
    has_thesis = bool(sc.thesis)
    if has_thesis:
        cols.append("thesis reports (m)")
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for c in exp.controllers:
        recs = groups.get((sc.name, c.name), [])
        cells = [c.name]
        for _, path in metrics:
            cells.append(_fmt(*stat(recs, path), digits=2 if path.endswith("_s") else 3))
        cells.append(_status(recs, c.kind == "oracle"))
        if has_thesis:
            cells.append(thesis_cell(sc, c))
        lines.append("| " + " | ".join(cells) + " |")
    yaw = [r.get("yaw_step") for c in exp.controllers
           for r in groups.get((sc.name, c.name), [])[:1] if r.get("yaw_step")]
    if yaw:
        lines += ["", "| controller (its attitude loop) | yaw step (deg) | overshoot % | "
                      "rise 10-90 % (s) | settling 2 % (s) | steady error (deg) |",
                  "|---|---|---|---|---|---|"]
        for c in exp.controllers:
            recs = groups.get((sc.name, c.name), [])
            if not recs or not recs[0].get("yaw_step"):
                continue
            ys = recs[0]["yaw_step"]
            lines.append(f"| {c.name} ({recs[0].get('attitude_controller', '')}) | "
                         f"{ys['step_deg']:.1f} | {ys['overshoot_pct']:.1f} | "
                         f"{ys['rise_time_s']:.3f} | {ys['settling_time_s']:.3f} | "
                         f"{ys['steady_error_deg']:.3f} |")
    return "\n".join(lines)


def _series(exp, name):
    """The scenarios that are points of series ``name``, by value."""
    return sorted((sc for sc in exp.scenarios if sc.point(name)),
                  key=lambda sc: sc.point(name)["value"])


def value(sc, b):
    """Scenario ``sc``'s value along break ``b``'s series."""
    return sc.point(b["series"])["value"]


def unit(sc, b):
    return sc.point(b["series"])["unit"]


def margin(exp, b, c, groups):
    """Where controller ``c`` holds along break ``b``'s series: (scenarios sorted by value,
    index of the nominal, (lowest, highest) index that holds around it or None if the nominal
    breaks, the first breaking (scenario, value of the metric, feasible) below it and above it
    or None).  A value holds when every run is feasible and the metric is at most ``above``."""
    series = _series(exp, b["series"])
    values = [value(sc, b) for sc in series]
    nominal = b.get("nominal")
    k0 = 0 if nominal is None else min(range(len(values)), key=lambda k: abs(values[k] - nominal))

    def judged(sc):
        recs = groups.get((sc.name, c.name), [])
        m, _ = stat(recs, b["metric"])
        ok = feasible(recs) and math.isfinite(m) and m <= b["above"]
        return ok, (sc, m, feasible(recs))

    ok, first = judged(series[k0])
    if not ok:
        return series, k0, None, first, first
    lo = hi = k0
    below = above = None
    for k in range(k0 - 1, -1, -1):
        ok, hit = judged(series[k])
        if not ok:
            below = hit
            break
        lo = k
    for k in range(k0 + 1, len(series)):
        ok, hit = judged(series[k])
        if not ok:
            above = hit
            break
        hi = k
    return series, k0, (lo, hi), below, above


def _broke(b, hit):
    sc, m, ok = hit
    why = f"{m:.3f}" if ok and math.isfinite(m) else "infeasible"
    return f"{value(sc, b):g} {unit(sc, b)} (`{b['metric']}` {why} > {b['above']:g})"


def findings(exp, groups):
    """Sentences the report states, measured: where each controller breaks along each series,
    and how ADRC and LADRC compare."""
    out = []
    for b in exp.breaks:
        if not _series(exp, b["series"]):
            continue
        for c in exp.controllers:
            series, k0, held, below, above = margin(exp, b, c, groups)
            u = unit(series[0], b)
            values = ", ".join(f"{value(sc, b):g}" for sc in series)
            if held is None:
                out.append(f"- **{c.name}**, {b['series']}: breaks at "
                           f"{'the nominal ' if b.get('nominal') is not None else ''}"
                           f"{_broke(b, below)}.")
            elif below is None and above is None:
                out.append(f"- **{c.name}**, {b['series']} ({values} {u}): `{b['metric']}` "
                           f"stays at or below {b['above']:g} at every value.")
            elif b.get("nominal") is None:
                out.append(f"- **{c.name}**, {b['series']}: breaks at {_broke(b, above)}.")
            else:
                lo, hi = (value(series[k], b) for k in held)
                where = [f"{'below' if hit is below else 'above'}: {_broke(b, hit)}"
                         for hit in (below, above) if hit is not None]
                held = f"only at {lo:g} {u}" if lo == hi else f"from {lo:g} to {hi:g} {u}"
                out.append(f"- **{c.name}**, {b['series']} ({values} {u}; nominal "
                           f"{value(series[k0], b):g}): holds {held}; "
                           f"breaks {' and '.join(where)}.")
    # ADRC vs LADRC over the scenarios both could fly: the median ratio and its extremes
    kinds = {}
    for c in exp.controllers:  # the first controller of each kind
        kinds.setdefault(c.kind, c.name)
    if "adrc" in kinds and "ladrc" in kinds:
        a, l = kinds["adrc"], kinds["ladrc"]
        ratios = []
        for sc in exp.scenarios:
            ra = groups.get((sc.name, a), [])
            rl = groups.get((sc.name, l), [])
            if feasible(ra) and feasible(rl):
                ma, _ = stat(ra, "after_settle.rms_error_m")
                ml, _ = stat(rl, "after_settle.rms_error_m")
                if ma > 0 and ml > 0:
                    ratios.append((ma / ml, sc.name))
        if ratios:
            r = np.array([x for x, _ in ratios])
            best = min(ratios)
            worst = max(ratios)
            out.append(f"- **{a} vs {l}** (RMS after settling, {len(ratios)} feasible scenarios): "
                       f"median ratio {np.median(r):.2f}; {a} is better in "
                       f"{int((r < 1).sum())}, {l} in {int((r > 1).sum())}; extremes "
                       f"{best[0]:.2f} ({best[1]}) and {worst[0]:.2f} ({worst[1]}).")
    return out


def margins_table(exp, groups):
    """Markdown: per break series (rows) and controller (columns), the range of values around
    the nominal over which the controller holds; empty without breaks."""
    rows = []
    for b in exp.breaks:
        if not _series(exp, b["series"]):
            continue
        cells = []
        for c in exp.controllers:
            series, k0, held, below, above = margin(exp, b, c, groups)
            if held is None:
                cells.append("breaks at nominal" if b.get("nominal") is not None
                             else f"breaks at {value(series[0], b):g}")
                continue
            lo, hi = (value(series[k], b) for k in held)
            text = f"{lo:g}" if lo == hi else f"{lo:g}-{hi:g}"
            cells.append(text + ("" if below or above else " (all)"))
        nominal = f", nominal {value(series[k0], b):g}" if b.get("nominal") is not None else ""
        rows.append(f"| {b['series']} ({unit(series[0], b)}{nominal}; `{b['metric']}` <= "
                    f"{b['above']:g}) | " + " | ".join(cells) + " |")
    if not rows:
        return ""
    head = "| series | " + " | ".join(c.name for c in exp.controllers) + " |"
    return "\n".join([head, "|" + "---|" * (len(exp.controllers) + 1)] + rows)


def check_goals(exp, groups):
    """[(text, met, detail)] for each goal and controller of the experiment.

    ``over: each`` judges every matching scenario and reports the worst; ``over: all`` pools
    the runs of all matching scenarios into one mean (a ratio: over the reference controller's
    runs of the same scenarios)."""
    out = []
    for g in exp.goals:
        scs = [sc for sc in exp.scenarios if goal_covers(g, sc.name)]
        parts = [scs] if g.get("over") == "all" else [[sc] for sc in scs]
        bound = f"<= {g['at_most']:g}" if g["at_most"] is not None else f">= {g['at_least']:g}"
        for c in g["controllers"]:
            what = f"{c} / {g['ratio_to']}" if g["ratio_to"] else c
            judged = [_judge(g, part, c, groups) for part in parts if part]
            if not judged:
                out.append((f"{c}: `{g['metric']}` on {g['scenario']!r}", False,
                            "no such scenario"))
                continue
            # the worst: a failing part first, then the one farthest from the bound
            sign = -1.0 if g["at_most"] is not None else 1.0
            m, ok, part = min(judged, key=lambda x: (x[1], sign * x[0] if math.isfinite(x[0])
                                                    else -math.inf))
            if g["text"]:
                text = f"{c}: {g['text']}"
            else:
                scope = "mean " if len(parts) == 1 and len(scs) > 1 else ""
                text = f"{what}: {scope}`{g['metric']}` {bound} on {g['scenario']!r}"
            detail = f"{what} = {m:.4g} over {len(part)} scenarios pooled" if len(parts) == 1 \
                and len(scs) > 1 else f"worst: {m:.4g} ({part[0].name})"
            bad = [r for sc in part for r in groups.get((sc.name, c), [])
                   if not r.get("feasible", False)]
            if not ok and math.isfinite(m) and g["at_most"] is not None and m > g["at_most"]:
                detail += f", missed by {m / g['at_most']:.2f}x"
            if not ok and bad:
                detail += (f", infeasible: {bad[0].get('infeasible_reason', 'infeasible')} "
                           f"({bad[0]['scenario']})")
            out.append((text, ok, detail))
    return out


def _judge(g, scs, c, groups):
    """(value, met, scenarios) of goal g for controller c over the runs of scenarios scs."""
    def runs(name):
        return [r for sc in scs for r in groups.get((sc.name, name), [])]

    recs = runs(c)
    m, _ = stat(recs, g["metric"])
    if g["ratio_to"]:
        base, _ = stat(runs(g["ratio_to"]), g["metric"])
        m = m / base if base > 0 else math.nan
    ok = math.isfinite(m) and feasible(recs) and \
        (g["at_most"] is None or m <= g["at_most"]) and \
        (g["at_least"] is None or m >= g["at_least"])
    return m, ok, scs


def summary_table(exp, records):
    """A compact plain-text table for the terminal: RMS 3-D after settling per scenario."""
    groups = grouped(exp, records)
    names = [c.name for c in exp.controllers]
    title = "RMS error after settling (m)"
    w = max([len(sc.name) for sc in exp.scenarios] + [len(title)])
    cw = max([13] + [len(n) for n in names]) + 1  # a column: its name and a space before it
    lines = ["", f"  {title:<{w}}  " + "".join(f"{n:>{cw}}" for n in names)]
    for sc in exp.scenarios:
        cells = []
        for n in names:
            recs = groups.get((sc.name, n), [])
            m, _ = stat(recs, "after_settle.rms_error_m")
            cells.append(("x " if not feasible(recs) else "") + (f"{m:.4f}" if math.isfinite(m)
                                                                 else "-"))
        lines.append(f"  {sc.name:<{w}}  " + "".join(f"{c:>{cw}}" for c in cells))
    lines.append("  (x: infeasible: thrust saturated or the run stopped at a safety limit)")
    return "\n".join(lines)


def write_report(folder, exp, records, meta, logs, workers=1):
    folder = Path(folder)
    groups = grouped(exp, records)
    figs = {}
    if logs:
        try:
            figs = make_figures(folder, exp, groups, logs, workers)
        except ImportError:
            figs = {}
    L = [f"# {exp.name}", ""]
    if exp.description:
        L += [exp.description.strip(), ""]
    if meta["via"] == "sitl":
        L += sitl_header(exp, meta)
    else:
        L += matrix_header(exp, meta)
    goals = check_goals(exp, groups)
    if goals:
        L += ["## Goals", ""]
        for text, ok, detail in goals:
            L.append(f"- {'met' if ok else '**missed**'}: {text} ({detail})")
        L.append("")
    fs = findings(exp, groups)
    if fs:
        L += ["## Findings", ""] + fs + [""]
    table = margins_table(exp, groups)
    if table:
        L += ["## Margins", "", "Where each controller holds along each series: the values "
              "around the nominal (the smallest, where none is named) at which every run is "
              "feasible and the metric stays within its bound; `(all)`: every value swept.", "",
              table, ""]
        if "margins" in figs:
            L += [f"![margins]({figs['margins']})", ""]
    if "overview" in figs:
        L += [f"![overview]({figs['overview']})", ""]
    current = None
    for sc in exp.scenarios:
        if sc.group != current:
            current = sc.group
            if current:
                L += [f"## {current}", ""]
        L += [f"### {sc.name}", ""]
        if sc.note:
            L += [sc.note.strip(), ""]
        L += [scenario_table(exp, sc, groups, table_metrics(meta)), ""]
        if sc.name in figs:
            L += [f"![{sc.name}]({figs[sc.name]})", ""]
    (folder / "report.md").write_text("\n".join(L) + "\n")


def matrix_header(exp, meta):
    """The report's opening lines for runs flown in process or over MAVLink in lockstep."""
    ns = len(meta["seeds"])
    L = [f"Experiment file `{exp.source}`; {counted(meta['runs'], 'run')} "
         f"({counted(len(exp.scenarios), 'scenario')} x "
         f"{counted(len(exp.controllers), 'controller')} x {counted(ns, 'seed')}), "
         f"{'in process' if meta['via'] == 'inprocess' else 'over MAVLink in lockstep'}"
         f"{' on ' + meta['scheduler'] if meta.get('scheduler') else ''}, "
         f"{meta['wall_s']:.1f} s ({meta['runs_per_s']:.1f} runs/s).", ""]
    fixed = [sc.name for sc in exp.scenarios if not sc.random]
    if ns > 1 and fixed and not meta.get("rerun_identical"):
        L += [f"The seed changes nothing in {len(fixed)} of the {len(exp.scenarios)} scenarios "
              "(no turbulence, no sensor noise): each of their runs was flown once, and its "
              f"record stands for every seed ({meta.get('runs_flown', meta['runs'])} runs "
              "flown; `--rerun-identical` flies them all).", ""]
    L += ["Errors are position errors in metres: RMS and max over the tracking window (after "
          "each scenario's settling time, which covers the takeoff and the joining transient), "
          "mean ± std over seeds; `joining max` is the largest error before it. `roll/pitch osc. "
          "deg` is the 99th percentile of the vehicle's roll or pitch about its 1 s running "
          "mean over the same window (the worse axis; in process only): a limit cycle shows "
          "there whatever the error says; `osc. regularity` how alike that swing is to itself "
          "three of its periods later (its autocorrelation: a limit cycle 0.6 or more, 1 "
          "when sustained; a resonance driven by noise or wind less). `effort` is the "
          "RMS commanded acceleration (m/s^2) after settling; `thrust sat. s` the time the thrust "
          "setpoint sat at a limit; `limited s` the time the tilt or thrust limits cut the "
          "command. A run is **infeasible** when the scenario demands more thrust than the "
          "vehicle has (reference acceleration minus the true disturbance, against the thrust "
          "limit), or the controller's thrust sits at a limit, for more than "
          f"{100 * SATURATION_SHARE:.0f} % of the tracking window, or the run stopped at a "
          "safety limit.", ""]
    return L


def sitl_header(exp, meta):
    """The report's opening lines for runs flown against SITL processes."""
    where = "; ".join(f"{ap}: {'the bundled vehicle (mavadrc sitl)' if path == 'bundled' else f'`{path}`'}"
                      for ap, path in meta.get("sitl", {}).items())
    return [f"Experiment file `{exp.source}`; {counted(meta['runs'], 'run')} "
            f"({counted(len(exp.scenarios), 'scenario')} x "
            f"{counted(len(exp.controllers), 'controller')} x "
            f"{counted(len(meta['seeds']), 'repeat')}), each against a fresh SITL process in "
            f"real time ({where}); {meta.get('runs_flown', 0)} flown in this session "
            f"({meta['wall_s']:.0f} s), {meta.get('runs_skipped', 0)} finished before.", "",
            "Each run's errors come three ways. By the autopilot's estimate (`RMS x` ... `max "
            "3-D`): estimate - reference, the error the controller saw and answered: the "
            "**controller's**. By the simulator's truth (`truth ...`): truth - reference, where "
            "the vehicle really was. Between the two (`estimator ...`): truth - estimate, the "
            "**estimator's** error, which no controller flying on the estimate can remove. "
            "The first two are taken after each scenario's settling time (RMS and max, mean ± "
            "std over repeats); the estimator's over the whole scored flight. A run is "
            "**infeasible** when its flight ended early (a safety limit, a lost link).", ""]


def _slug(name):
    return "".join(ch if ch.isalnum() else "_" for ch in name).strip("_").lower()


def make_figures(folder, exp, groups, logs, workers=1):
    """Thesis-style figures of the first seed, per scenario some controller could fly: the 3-D
    path against the reference, the error over time, the observers' disturbance estimate
    against the truth, and U1..U4; plus an overview bar chart."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    fig_dir = Path(folder) / "figures"
    fig_dir.mkdir(exist_ok=True)
    names = [c.name for c in exp.controllers]
    # overview: RMS after settling per scenario and controller (log scale)
    fig, ax = plt.subplots(figsize=(max(8, 0.5 * len(exp.scenarios) * len(names) / 3), 4.5))
    width = 0.8 / len(names)
    for k, c in enumerate(exp.controllers):
        ys = []
        for sc in exp.scenarios:
            recs = groups.get((sc.name, c.name), [])
            m, _ = stat(recs, "after_settle.rms_error_m")
            ys.append(m if feasible(recs) else math.nan)
        ax.bar(np.arange(len(exp.scenarios)) + k * width, ys, width, label=c.name)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(exp.scenarios)) + 0.4 - width / 2)
    ax.set_xticklabels([sc.name for sc in exp.scenarios], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("RMS position error after settling (m)")
    ax.set_title(f"{exp.name} (missing bar: infeasible)")
    ax.legend(fontsize=7, ncol=len(names))
    fig.tight_layout()
    fig.savefig(fig_dir / "overview.png", dpi=110)
    plt.close(fig)
    out["overview"] = "figures/overview.png"
    if margins_figure(fig_dir / "margins.png", exp, groups):
        out["margins"] = "figures/margins.png"
    # every scenario that at least one controller could fly (an all-infeasible one is a table)
    chosen = [sc for sc in exp.scenarios
              if any(feasible(groups.get((sc.name, c.name), [])) for c in exp.controllers)]
    jobs = []
    for sc in chosen:
        i = exp.scenarios.index(sc)
        runs = [(c.name, c.kind, logs.get((i, j))) for j, c in enumerate(exp.controllers)]
        runs = [(n, k, L) for n, k, L in runs if L is not None and len(L)]
        if runs:
            name = f"figures/{_slug(sc.name)}.png"
            jobs.append((str(Path(folder) / name), sc.name, sc.settle_s, runs))
            out[sc.name] = name
    if workers > 1 and len(jobs) > 1:
        from mavadrc.study.pool import process_pool

        with process_pool(workers) as pool:
            list(pool.map(_scenario_figure, jobs))
    else:
        for job in jobs:
            _scenario_figure(job)
    return out


def margins_figure(path, exp, groups):
    """One panel per break series: the metric against the series' value, per controller, the
    bound dashed and the nominal dotted; an infeasible run is a cross on the panel's top edge.
    Returns whether there was anything to draw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [b for b in exp.breaks if _series(exp, b["series"])]
    if not panels:
        return False
    ncol = min(3, len(panels))
    nrow = -(-len(panels) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.3 * nrow), squeeze=False)
    for ax, b in zip(axes.flat, panels):
        series = _series(exp, b["series"])
        xs = np.array([value(sc, b) for sc in series])
        curves = []
        for c in exp.controllers:
            ys = np.array([stat(groups.get((sc.name, c.name), []), b["metric"])[0]
                           for sc in series])
            bad = np.array([not feasible(groups.get((sc.name, c.name), [])) for sc in series])
            curves.append((c.name, np.where(bad, np.nan, ys), bad))
        shown = [y for _, ys, _ in curves for y in ys if np.isfinite(y)]
        top = 1.5 * max(shown + [2.0 * b["above"]])  # infeasible runs: crosses up here
        for name, ys, bad in curves:
            line, = ax.plot(xs, ys, "o-", ms=3, lw=1, label=name)
            if bad.any():
                ax.plot(xs[bad], np.full(bad.sum(), top), "x", color=line.get_color(), ms=6)
        ax.axhline(b["above"], color="k", ls="--", lw=0.8)
        if b.get("nominal") is not None:
            ax.axvline(b["nominal"], color="grey", ls=":", lw=0.8)
        ax.set_yscale("log")
        ax.set_ylim(top=top * 1.3)
        ax.set_xlabel(f"{b['series']} ({unit(series[0], b)})", fontsize=8)
        ax.set_ylabel(b["metric"], fontsize=7)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6)
    fig.suptitle(f"{exp.name}: margins (dashed: the bound; x: infeasible)", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.97))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _scenario_figure(job):
    """One scenario's four-panel figure (a picklable job: path, title, settle_s, runs).  Each
    controller keeps its colour in every panel, named once in a legend above the panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from mavadrc.fast.inprocess import L_DIST, L_POS, L_REF, L_T, L_WRENCH, L_Z3
    from mavadrc.study.figures import MIN_SPAN_ACC, MIN_SPAN_M, label_3d, min_span

    path, title, settle_s, runs = job
    colour = {name: f"C{k}" for k, (name, _, _) in enumerate(runs)}
    fig = plt.figure(figsize=(12, 8), layout="constrained")
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    ref = runs[0][2]
    ax3.computed_zorder = False  # the reference drawn over the paths, not hidden under them
    for name, _, L in runs:
        ax3.plot(L[:, L_POS + 1], L[:, L_POS], -L[:, L_POS + 2], lw=1.2, color=colour[name],
                 zorder=2)
    ax3.plot(ref[:, L_REF + 1], ref[:, L_REF], -ref[:, L_REF + 2], "k--", lw=1, zorder=3)
    min_span(ax3, MIN_SPAN_M, "xyz")
    label_3d(ax3, "east (m)", "north (m)", "altitude (m)")
    ax = fig.add_subplot(2, 2, 2)
    for name, _, L in runs:
        e = np.linalg.norm(L[:, L_POS:L_POS + 3] - L[:, L_REF:L_REF + 3], axis=1)
        ax.plot(L[:, L_T], e, lw=1, color=colour[name])
    ax.axvline(settle_s, color="grey", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel("mission time (s)")
    ax.set_ylabel("|position error| (m)")
    ax.set_title("error (dotted: end of the settling window)", fontsize=9)
    ax = fig.add_subplot(2, 2, 3)
    shown = False
    for name, kind, L in runs:
        if kind in ("adrc", "ladrc"):
            ax.plot(L[:, L_T], L[:, L_Z3], lw=1, color=colour[name])
            shown = True
    ax.plot(ref[:, L_T], ref[:, L_DIST], "k:", lw=1.2)
    min_span(ax, MIN_SPAN_ACC)
    ax.set_xlabel("mission time (s)")
    ax.set_ylabel("disturbance accel. x (m/s^2)")
    ax.set_title("observer estimate z3 (x) vs truth (dotted)" if shown
                 else "true disturbance (x)", fontsize=9)
    ax = fig.add_subplot(2, 2, 4)
    styles = (("U1 T (N)", "-"), ("U2 tau_x x100 (N m)", "--"), ("U3 tau_y x100 (N m)", "-."),
              ("U4 tau_z x100 (N m)", ":"))
    for name, _, L in runs[:3]:
        for k, (_, ls) in enumerate(styles):
            ax.plot(L[:, L_T], L[:, L_WRENCH + k] * (1.0 if k == 0 else 100.0), ls=ls, lw=0.8,
                    color=colour[name])
    ax.set_xlabel("mission time (s)")
    ax.set_title("virtual inputs U1..U4" + (f" of {', '.join(n for n, _, _ in runs[:3])}"
                                             if len(runs) > 3 else ""), fontsize=9)
    ax.legend(handles=[Line2D([], [], color="0.3", ls=ls, lw=1, label=label)
                       for label, ls in styles], fontsize=7, ncol=2, loc="best")
    handles = [Line2D([], [], color=colour[name], lw=1.5, label=name) for name, _, _ in runs]
    handles.append(Line2D([], [], color="k", ls="--", lw=1, label="reference"))
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=9,
               frameon=False)
    fig.suptitle(title)
    fig.savefig(path, dpi=90)
    plt.close(fig)
