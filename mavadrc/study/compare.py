"""`mavadrc compare EXPERIMENT.yaml`: run an experiment's matrix and write its report.

Runs go to local worker processes (default: one per core), or with ``--scheduler
tcp://HOST:PORT`` to a Dask distributed cluster; either way each run is a pure function of
(experiment text, scenario, controller, seed), so the same seeds give the same records.  Output,
in one folder: ``results.json`` (one record per run), ``results.csv`` (the same, flat),
``report.md`` (tables, findings, goals) and figures.
"""

import collections
import json
import math
import os
import sys
import time
from pathlib import Path

from mavadrc.errors import UsageError, os_error_text
from mavadrc.flight.console import Steps, counted, ticking
from mavadrc.study.experiment import load_experiment, run_task
from mavadrc.study.pool import default_workers, process_pool, stop_pool

RESULTS_VERSION = 1


def _warm_up(exp):
    """Compile (or load from numba's cache) the whole closed loop once, before any worker
    starts, so workers load it instead of compiling it side by side."""
    from mavadrc.study.experiment import run_inprocess

    kinds = {}
    for j, c in enumerate(exp.controllers):
        kinds.setdefault(c.kind, j)
    for j in kinds.values():
        run_inprocess(exp, 0, j, exp.seeds[0])



def run_matrix(exp, *, seeds=None, workers=None, scheduler=None, via="inprocess", out_dir=None,
               progress=True, keep_logs_seed=None, stream=None, rerun_identical=False):
    """Every run of the matrix; returns (records in matrix order, {(i, j): log} for the runs of
    ``keep_logs_seed``, wall seconds).

    A scenario whose seed changes nothing (no turbulence, no sensor noise:
    :attr:`Scenario.random` is False) is flown once per controller, with ``keep_logs_seed`` (or
    the first seed), and its record stands for every seed: the runs are deterministic, so
    flying them again would give the same record.  Those records carry
    ``seed_independent: true``, and the copies ``same_as_seed`` and ``wall_s`` 0.
    ``rerun_identical`` flies every seed anyway.
    """
    stream = stream if stream is not None else sys.stderr
    seeds = list(exp.seeds if seeds is None else seeds)
    runs = exp.runs(seeds)
    if via == "mavlink":
        skipped = [r for r in runs if exp.controllers[r[1]].kind == "oracle"]
        runs = [r for r in runs if exp.controllers[r[1]].kind != "oracle"]
        if skipped:
            stream.write(f"{len(skipped)} oracle runs skipped: the oracle runs in process only\n")
    same = {}  # run -> the run whose record it shares
    if not rerun_identical and len(seeds) > 1:
        first = keep_logs_seed if keep_logs_seed in seeds else seeds[0]
        fixed = {i for i, sc in enumerate(exp.scenarios) if not sc.random}
        same = {(i, j, s): (i, j, first) for i, j, s in runs if i in fixed and s != first}
    flown = [r for r in runs if r not in same]
    tasks = [(exp.source, exp.text, i, j, s, via, s == keep_logs_seed,
              str(Path(out_dir or ".") / "flights")) for i, j, s in flown]
    bar = Steps(len(runs), "run", out=stream, enabled=progress)
    repeats = collections.Counter(same.values())  # flown run -> how many records copy it
    ticks = [1 + repeats[r] for r in flown]  # progress: a flown run and its copies
    t0 = time.perf_counter()
    results = [None] * len(tasks)
    if scheduler:
        Client, as_completed = dask_client()

        with Client(scheduler) as client:
            futures = client.map(run_task, tasks, pure=False)
            index = {f.key: k for k, f in enumerate(futures)}
            for fut in as_completed(futures):
                k = index[fut.key]
                results[k] = fut.result()
                bar.step(ticks[k])
    else:
        if via == "inprocess":
            from mavadrc.control.jit import needs_compiling
            from mavadrc.fast.inprocess import closed_loop

            compiling = needs_compiling(closed_loop)
            if compiling:
                stream.write("compiling the simulation and controller kernels (the first run "
                             "after an install or an update; numba caches them)\n")
                stream.flush()

            def say(text):
                stream.write(text + "\n")
                stream.flush()

            with ticking(say, "still compiling the kernels", enabled=compiling):
                _warm_up(exp)
        n = default_workers(workers)
        if via == "mavlink":
            n = 1  # each run already runs two processes (companion + vehicle)
        if n <= 1 or len(tasks) <= 1:
            for k, task in enumerate(tasks):
                results[k] = run_task(task)
                bar.step(ticks[k])
        else:
            pool = process_pool(n)
            try:
                chunk = max(1, min(8, len(tasks) // (4 * n)))
                for k, res in enumerate(pool.map(run_task, tasks, chunksize=chunk)):
                    results[k] = res
                    bar.step(ticks[k])
            except BaseException:  # Ctrl-C, an error: the workers are stopped, not waited for
                stop_pool(pool)
                raise
            pool.shutdown()
    wall = time.perf_counter() - t0
    by_run = {r: res[0] for r, res in zip(flown, results)}
    for r in repeats:
        by_run[r]["seed_independent"] = True
    records = []
    for r in runs:
        if r in same:
            rec = dict(by_run[same[r]], seed=int(r[2]), same_as_seed=int(same[r][2]), wall_s=0.0)
        else:
            rec = by_run[r]
        records.append(rec)
    logs = {(i, j): res[1] for (i, j, s), res in zip(flown, results) if res[1] is not None}
    return records, logs, wall



def dask_client():
    """Dask's (Client, as_completed), or a UsageError saying how to install it."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise UsageError("--scheduler runs on a Dask cluster, and the distributed package is "
                         "not installed: pip install -e \".[cluster]\"") from None
    return Client, as_completed



def runs_flown(records):
    """How many of run_matrix's records were flown (the others copy a seed-independent run)."""
    return sum(1 for r in records if "same_as_seed" not in r)


def write_results(folder, exp, records, meta):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    doc = {"version": RESULTS_VERSION, "experiment": exp.name, "experiment_file": exp.source,
           **meta, "records": records}
    tmp = folder / "results.json.tmp"
    tmp.write_text(json.dumps(_finite(doc), indent=1) + "\n")
    os.replace(tmp, folder / "results.json")
    _write_csv(folder / "results.csv", records)


def _finite(x):
    """JSON has no NaN: NaN and infinities become null."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _flat(rec, prefix=""):
    out = {}
    for k, v in rec.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, key + "."))
        elif isinstance(v, (list, tuple)) and len(v) == 3 and all(
                isinstance(a, (int, float)) or a is None for a in v):
            for a, x in zip("xyz", v):
                out[f"{key}.{a}"] = x
        else:
            out[key] = v
    return out


def _write_csv(path, records):
    import csv

    rows = [_flat(r) for r in records]
    cols = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})


def compare(path, *, out=None, seeds=None, workers=None, scheduler=None, via="inprocess",
            figures=True, progress=True, stream=None, rerun_identical=False):
    """Run the experiment at ``path`` and write its folder; returns (folder, experiment,
    records)."""
    stream = stream if stream is not None else sys.stderr
    if seeds is not None and seeds < 1:
        raise UsageError(f"--seeds {seeds}: must be at least 1 (the runs use seeds 0..N-1)")
    if workers is not None and workers < 1:
        raise UsageError(f"--workers {workers}: must be at least 1")
    if scheduler:
        dask_client()
    if out:
        from mavadrc.flight.fly import check_out_folder

        check_out_folder(out)
    exp = load_experiment(path)
    seed_list = exp.seeds if seeds is None else list(range(int(seeds)))
    folder = Path(out) if out else Path("runs") / f"compare-{Path(exp.source).stem}"
    folder.mkdir(parents=True, exist_ok=True)
    stream.write(f"{exp.name}: {counted(len(exp.scenarios), 'scenario')} x "
                 f"{counted(len(exp.controllers), 'controller')} x "
                 f"{counted(len(seed_list), 'seed')}"
                 f"{' over MAVLink (lockstep)' if via == 'mavlink' else ''}"
                 f"{f' on {scheduler}' if scheduler else ''}\n")
    records, logs, wall = run_matrix(exp, seeds=seed_list, workers=workers, scheduler=scheduler,
                                     via=via, out_dir=folder, progress=progress,
                                     keep_logs_seed=seed_list[0] if figures else None,
                                     stream=stream, rerun_identical=rerun_identical)
    stream.write(f"writing the report{' and figures' if figures else ''} to {folder}\n")
    stream.flush()
    flown = runs_flown(records)
    meta = {"seeds": seed_list, "via": via, "scheduler": scheduler, "runs": len(records),
            "rerun_identical": bool(rerun_identical),
            "runs_flown": flown, "wall_s": wall,
            "runs_per_s": len(records) / wall if wall > 0 else None,
            "runs_flown_per_s": flown / wall if wall > 0 else None}
    write_results(folder, exp, records, meta)
    from mavadrc.study.report import write_report

    write_report(folder, exp, records, meta, logs if figures else {},
                 workers=default_workers(workers))
    stream.write(f"{runs_line(len(records), flown, wall)}; report in {folder / 'report.md'}\n")
    return folder, exp, records


def runs_line(runs, flown, wall):
    """How many runs took how long: "105 runs in 14.0 s (7.5 runs/s; 41 flown, 2.9/s, the other
    64 copied from a seed-independent run)", or, when every run was flown, "8 runs in 5.3 s
    (1.5 runs/s)"."""
    rate = f"{runs / wall:.1f}" if wall > 0 else "-"
    text = f"{counted(runs, 'run')} in {wall:.1f} s ({rate} runs/s"
    if flown < runs:
        flown_rate = f"{flown / wall:.1f}" if wall > 0 else "-"
        text += (f"; {flown} flown, {flown_rate}/s, the other {runs - flown} copied from a "
                 f"seed-independent run")
    return text + ")"


def command_status(run, interrupted, failures=()):
    """The exit status of ``mavadrc compare`` running ``run()`` (it returns (folder, experiment,
    records)): 0, the summary table printed; 130 on Ctrl-C, ``interrupted`` said; 1 for an
    exception of ``failures`` (what could not be run); 2 for a file or an option that cannot be
    run as given.  Each is said in one line."""
    from sim.yamlio import ConfigError

    try:
        _, exp, records = run()
    except KeyboardInterrupt:
        print(f"\nmavadrc compare: interrupted: {interrupted}", file=sys.stderr)
        return 130
    except failures as exc:
        print(f"mavadrc compare: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"mavadrc compare: {os_error_text(exc)}", file=sys.stderr)
        return 2
    except (ConfigError, ValueError) as exc:
        print(f"mavadrc compare: {exc}", file=sys.stderr)
        return 2
    from mavadrc.study.report import summary_table

    print(summary_table(exp, records))
    return 0


def main(args):
    return command_status(
        lambda: compare(args.experiment, out=args.out, seeds=args.seeds, workers=args.workers,
                        scheduler=args.scheduler, via=args.via or "inprocess",
                        figures=not args.no_figures, progress=not args.quiet,
                        rerun_identical=args.rerun_identical),
        "the workers were stopped, no report written")
