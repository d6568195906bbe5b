"""``forecast-design benchmark``: controllers x compensators over an environment set, locally or on a Dask cluster."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

from . import _command, _progress_bar, _write_json
from ._options import CONTROLLER_FORMS


def _configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", action="append", default=None, metavar="SPEC",
                   help="force controller under test, repeatable (default pd:5:0.1, the paper's): " + CONTROLLER_FORMS)
    p.add_argument("--compensator", action="append", default=None, metavar="LIST",
                   help="comma list of friction compensators, KIND[:W_Q_HZ] (default none,sfm,ea-fob)")
    p.add_argument("--envs", "--env", dest="envs", action="append", default=None, metavar="SET",
                   help="environment set: presets (soft,stiff), random:N, inline k_e=..,J_e=.. or a TOML file "
                        "of [[environment]] tables with grids/uncertainty (default exp-soft,locked); repeats add "
                        "their environments to the set")
    p.add_argument("--testbed", default=None, metavar="SPEC",
                   help="the SEA under test: inline (k=40[,J_m=..][,d_m=..]) or a TOML file with [testbed] "
                        "(default: the paper's Table 1)")
    p.add_argument("--repetitions", type=int, default=None, metavar="N", help="runs per cell (default 10, >= 2)")
    p.add_argument("--reference", action="append", default=None, metavar="REF",
                   help="step:AMP[:DURATION_S] or chirp:AMP:F0_HZ:F1_HZ[:DURATION_S], repeatable (default step:0.2)")
    p.add_argument("--duration", type=float, default=1.0, metavar="S", help="length of a step run [s] (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the initial angles and noise (default 0)")
    p.add_argument("--viscous-drift", type=float, default=0.0, metavar="FRACTION",
                   help="relative viscous-friction drift per repetition (default 0)")
    p.add_argument("--derivative-on", default=None, metavar="WHERE",
                   help="override where every pd/pid controller takes its derivative: error (the format's "
                        "u = P e + D de/dt) or measurement (no kick at a step); default: each controller's own "
                        "(for --runs: each recorded [controller] table's)")
    p.add_argument("--runs", default=None, metavar="DIR",
                   help="benchmark recorded runs instead: a folder of experiments (real or simulated), grouped "
                        "into cells by their TOML's environment, controller and compensator")
    p.add_argument("--out", required=True, metavar="DIR", help="result folder (table, plots, report, cells/)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the cells on a Dask cluster, tcp://HOST:PORT (default: local processes)")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: all cores)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--json", metavar="OUT", nargs="?", const="-", help="write the JSON summary to OUT (or stdout)")


@_command("benchmark", "benchmark force controllers and friction compensators over an environment set", _configure)
def _cmd_benchmark(args: argparse.Namespace) -> int:
    from ..benchmark import (BenchmarkSpec, markdown_report, parse_compensators, parse_reference,
                             result_rows, result_table, run_benchmark, run_recorded, summary, write_report,
                             write_summary, write_tables, write_traces)
    from ..controllers import resolve_controller, with_derivative_on
    from ..environments import resolve_environments, resolve_testbed
    from ..errors import ParameterError
    from ..executor import make_executor
    from ..fileio import MANIFEST, staged_set

    if args.derivative_on is not None and args.derivative_on not in ("error", "measurement"):
        raise ParameterError(f"--derivative-on must be error or measurement, got {args.derivative_on!r}",
                             name="derivative_on", value=args.derivative_on)
    if not (args.duration > 0):
        raise ParameterError(f"--duration must be > 0 [s], got {args.duration}", name="duration")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ParameterError(f"--out {args.out}: not a folder (the result folder holds tables, plots and cells/)",
                             name="out", value=args.out)
    t0 = time.perf_counter()
    if args.runs is not None:
        given = [f"--{name.replace('_', '-')}" for name in ("controller", "compensator", "envs", "reference",
                                                            "repetitions", "testbed") if getattr(args, name) is not None]
        if given:
            raise ParameterError(f"--runs takes controllers, compensators, environments, references, repetitions and "
                                 f"the testbed from the experiments; drop {', '.join(given)}", name="runs", value=given)
        with make_executor(args.scheduler, args.workers) as executor, \
                _progress_bar("benchmark", "cell", enabled=args.json != "-") as progress:
            cells, info = run_recorded(args.runs, out=args.out, executor=executor, progress=progress,
                                       derivative_on=args.derivative_on)
        for why in info["skipped"]:
            print(f"forecast-design: note: skipped {why}", file=sys.stderr)
        for why in info["unreadable"]:
            print(f"forecast-design: warning: skipped {why}", file=sys.stderr)
        spec_doc = {"runs": args.runs, "controllers": sorted({c.labels["controller"] for c in cells}),
                    "compensators": sorted({c.labels["compensator"] for c in cells}),
                    "environments": {c.labels["environment"]: dict(c.environment) for c in cells},
                    "references": sorted({c.labels["reference"] for c in cells}),
                    "repetitions": max(len(c.runs) for c in cells)}
    else:
        testbed = resolve_testbed(args.testbed)
        if args.testbed is None:
            from ..environments import testbed_of_environment_files

            found = testbed_of_environment_files(args.envs)
            if found is not None:      # the set's file describes the SEA once: its [testbed], not Table 1's
                testbed = found[0]
                print(f"forecast-design: note: testbed from {found[1]}'s [testbed] (no --testbed given)",
                      file=sys.stderr)
        envs = resolve_environments(args.envs or "exp-soft,locked", testbed=testbed, seed=args.seed)
        for note in envs.notes:
            print(f"forecast-design: note: {note}", file=sys.stderr)
        spec = BenchmarkSpec(
            controllers=tuple(c if args.derivative_on is None else with_derivative_on(c, args.derivative_on)
                              for c in (resolve_controller(x) for x in (args.controller or ["pd:5:0.1"]))),
            compensators=parse_compensators(args.compensator or ["none,sfm,ea-fob"]),
            environments=tuple(envs.items()),
            references=tuple(parse_reference(r, duration_s=args.duration) for r in (args.reference or ["step:0.2"])),
            repetitions=10 if args.repetitions is None else args.repetitions, seed=args.seed,
            viscous_drift=args.viscous_drift, testbed=testbed)
        for label, model in spec.to_mapping()["controller_models"].items():
            if model.startswith("code"):
                print(f"forecast-design: note: controller {label} is {model}", file=sys.stderr)
        with make_executor(args.scheduler, args.workers) as executor, \
                _progress_bar("benchmark", "cell", enabled=args.json != "-") as progress:
            cells, info = run_benchmark(spec, out=args.out, executor=executor, progress=progress)
        spec_doc = spec.to_mapping()
    info["elapsed_s"] = round(time.perf_counter() - t0, 3)
    rows = result_rows(cells)
    df = result_table(cells)
    plots = {}
    # the result folder is one unit: written into a staging folder, swapped in, MANIFEST.sha256 last
    # (read_results refuses a folder whose manifest is missing or does not match); cells/ stays a cache
    with staged_set(args.out) as staging:
        write_tables(df, staging)
        traced = write_traces(cells, staging / "traces.parquet", store=os.path.join(args.out, "cells"))
        info["trace_step"] = traced["trace_step"]
        if not args.no_plots:
            from ..plotting.benchmark import plot_heatmap, plot_indicators, plot_overlays

            for caption, name, draw in (("Indicators against environment stiffness", "indicators.png",
                                         lambda p: plot_indicators(df, p)),
                                        ("Repetition overlays", "overlays.png", lambda p: plot_overlays(cells, p)),
                                        ("Heat map of the set", "heatmap.png", lambda p: plot_heatmap(df, p))):
                fig = draw(staging / name)
                import matplotlib.pyplot as plt

                plt.close(fig)
                plots[caption] = name
        doc = summary(rows, spec_doc, info)
        doc["files"] = {"parquet": "results.parquet", "csv": "results.csv", "traces": "traces.parquet",
                        "report": "report.md", "plots": plots, "manifest": MANIFEST}
        write_summary(doc, staging)
        write_report(markdown_report(rows, spec_doc, info, plots), staging)
    if args.json:
        _write_json(args.json, doc)
    if args.json != "-":
        for r in doc["set"]:
            if r["statistic"] == "mean":
                vals = ", ".join(f"{k} {r[k]:.4g}" for k in ("repeatability", "mae_N_m", "bandwidth_hz", "disk_margin")
                                 if r.get(k) is not None)
                left = f" ({r['excluded_cells']} unstable cell(s) left out)" if r.get("excluded_cells") else ""
                print(f"{r['controller']} + {r['compensator']} ({r['reference']}): set mean {vals}{left}")
        print(f"{info['computed']} cells computed, {info['reused']} reused, {info['elapsed_s']:.1f} s; "
              f"report: {args.out}/report.md")
    unstable = 0
    for c in cells:
        where = f"{c.labels['controller']} + {c.labels['compensator']} in {c.labels['environment']}"
        runs = [r for r in c.runs if isinstance(r, dict)]
        if c.stable is False:
            unstable += 1
            print(f"forecast-design: warning: {where} ({c.labels['reference']}): unstable (disk margin "
                  f"{c.disk_margin:.3g} of the sampled loop"
                  + (", a run diverged" if any(not math.isnan(float(r.get("diverged_at_s", math.nan))) for r in runs)
                     else "") + "): flagged stable = false, left out of the set aggregates", file=sys.stderr)
        if any(r.get("expected_diverged_at_s") is not None for r in runs):
            print(f"forecast-design: warning: {where}: the frictionless expected response (nominal plant, d_m = 0) "
                  "diverges: mae_N_m is not scored", file=sys.stderr)
        bad = [r["repetition"] for r in runs if not math.isnan(float(r.get("diverged_at_s", math.nan)))]
        if bad:
            print(f"forecast-design: warning: {where}: repetitions {', '.join(map(str, bad))} diverged (unstable "
                  "closed loop): not scored", file=sys.stderr)
        faulted = [r for r in runs if r.get("controller_fault")]
        if faulted:
            unstable += 1
            print(f"forecast-design: warning: {where}: the controller stopped with a fault in repetitions "
                  f"{', '.join(str(r['repetition']) for r in faulted)} ({faulted[0]['controller_fault']}): zero "
                  "torque from then on, not scored", file=sys.stderr)
    flags = doc["flags"]
    if flags["unsettled_runs"]:
        print(f"forecast-design: note: {flags['unsettled_runs']} of {flags['step_runs']} step runs did not settle "
              "(within 2 % of the step around their final value over the last 10 % of the run): no settling time, "
              "counted in unsettled_runs", file=sys.stderr)
    return 1 if unstable else 0
