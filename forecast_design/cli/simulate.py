"""The ``simulate`` verb: a scenario on the virtual testbed into an experiment (docs/scenario.md)."""

from __future__ import annotations

import argparse
import math

from . import (_add_allow_unidentified, _add_json_option, _check_sfm_loop, _command, _friction_from_file,
               _json_positional, _note, _progress_bar, _write_json)


def _configure_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO.toml", nargs="?",
                   help="nominal model + [truth] effects + [reference] + [simulation] (see docs/scenario.md)")
    p.add_argument("--out", required=True, metavar="RUN.toml", help="the simulated run, as an experiment")
    p.add_argument("--friction", metavar="F.json",
                   help="identified friction (identify --model sfm --json F.json): the run's compensator becomes "
                        "an SFM on these parameters (the scenario's compensator must be none or sfm)")
    _add_allow_unidentified(p)
    p.add_argument("--repetitions", metavar="N|all",
                   help="simulate repetitions 0..N-1 (or all) of the scenario's [variability] in one batch "
                        "(simulate_batch, one run per core) and write RUN_000.toml, RUN_001.toml, ...")
    _add_json_option(p, "the written paths, what the run assumed (design, rate, reference, options, true "
                        "plant) and its statistics (a list with --repetitions)")
    p.add_argument("--plot", metavar="OUT.png", help="plot the run (torque tracking, friction, motion)")


@_command("simulate", "simulate the testbed (friction, effects, controller at 2 kHz) into an experiment",
          _configure_simulate)
def _cmd_simulate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..fileio import check_writable
    from ..simulation.run import save_simulation
    from ..simulation.scenario import load_scenario

    _json_positional(args, "scenario")
    if args.repetitions is not None:
        return _simulate_repetitions(args)
    out = Path(args.out)  # save_simulation writes RUN.toml, RUN.csv, RUN.truth.json, RUN.truth.csv
    _refuse_overwriting_inputs(args, [out])
    check_writable(out, stream_ok=False)   # RUN.toml names a set (RUN.csv, RUN.truth.*): never a device
    scenario = load_scenario(args.scenario)
    _note(scenario.notes)
    if args.friction:
        scenario = _with_checked_friction(scenario, args)
    result = scenario.run()
    paths = save_simulation(result, args.out)
    if args.plot:
        from ..plotting.simulation import plot_simulation, run_title

        plot_simulation({args.scenario: result}, args.plot, title=run_title(result, source=Path(args.scenario).name))
    if args.json:
        mapping = result.to_mapping()
        _write_json(args.json, {**{key: str(value) for key, value in paths.items()},
                                **_compensator_keys(result.design.compensator),
                                "controller": _controller_label(result.design.controller),
                                "controller_table": _controller_table(result.design.controller),
                                "controller_fault": result.fault, **_assumed(mapping),
                                "reference": scenario.to_mapping().get("reference"), **_run_assumed(mapping),
                                "statistics": mapping["statistics"]})
    if args.json != "-":
        for key, value in paths.items():
            print(f"{key}: {value}")
    return _report_faults([result.fault])


def _assumed(mapping: dict) -> dict:
    """What every run of a scenario assumed, for its JSON: the design (testbed, environment, controller, compensator
    with its cutoff) and the rate [Hz]."""
    return {"design": mapping["design"], "rate_hz": mapping["rate_hz"]}


def _run_assumed(mapping: dict) -> dict:
    """What one run (repetition) assumed: the simulation options (its seed; a non-finite value, e.g. no torque limit,
    as null) and the true plant (``true_plant``: its effects, environment and initial angle; ``truth`` is the path
    of its files)."""
    options = {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in mapping["options"].items()}
    return {"options": options, "true_plant": mapping["truth"]}


def _controller_label(controller) -> str | None:
    return None if controller is None else controller.label


def _controller_table(controller) -> dict | None:
    """The exact ``[controller]`` table (the label rounds its numbers for reading)."""
    return None if controller is None else controller.to_mapping()


def _report_faults(faults) -> int:
    """A controller written as code that stopped (each run's ``fault`` or None): one line each on
    stderr, exit 1 (the logs are written)."""
    import sys

    faulted = [f for f in faults if f is not None]
    for f in faulted:
        print(f"forecast-design: controller fault at t = {f['t_s']:.4g} s (period {f['period']}): "
              f"{f['reason']}; the command is zero from then on", file=sys.stderr)
    return 1 if faulted else 0


def _with_checked_friction(scenario, args: argparse.Namespace):
    """The scenario with the --friction SFM compensator, refused when not identified or when it destabilises the loop."""
    scenario = scenario.with_friction(_friction_from_file(args.friction, args.allow_unidentified))
    if scenario.closed_loop:
        _check_sfm_loop(scenario.design, scenario.design.compensator.friction_params,
                        controller=scenario.design.controller, rate_hz=scenario.rate_hz)
    return scenario


def _run_files(out) -> list:
    """The four files :func:`~forecast_design.simulation.run.save_simulation` writes for ``RUN.toml``."""
    return [out, out.with_suffix(".csv"), out.with_name(out.stem + ".truth.json"),
            out.with_name(out.stem + ".truth.csv")]


def _refuse_overwriting_inputs(args: argparse.Namespace, outs: list) -> None:
    """Refuse, before any work, runs (``outs``), --plot or --json that would replace the scenario or --friction."""
    from ..fileio import refuse_overwriting

    refuse_overwriting([f for out in outs for f in _run_files(out)] + ([args.plot] if args.plot else [])
                       + ([args.json] if args.json not in (None, "-") else []),
                       [args.scenario] + ([args.friction] if args.friction else []))


def _compensator_keys(comp) -> dict:
    """The JSON keys ``compensator`` (kind or "none") and ``friction`` (identified parameters or None)."""
    return {"compensator": "none" if comp is None else comp.kind,
            "friction": None if comp is None else comp.friction_params}


_BATCH_SAMPLES = 1_000_000   # samples simulated (and held) at once by simulate --repetitions


def _repetition_count(text: str, available: int, source: str) -> int:
    from ..errors import ParameterError

    if text == "all":
        return available
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= available:
        raise ParameterError(f"--repetitions must be 'all' or an integer in 1..{available} (the [variability] "
                             f"repetitions of {source}), got {text!r}", name="repetitions", value=text)
    return n


def _simulate_repetitions(args: argparse.Namespace) -> int:
    """``--repetitions``: the scenario's repetitions as one batch, each written as ``RUN_<i>.toml``."""
    from pathlib import Path

    from ..fileio import check_writable
    from ..limits import check_limit
    from ..simulation.batch import simulate_scenario
    from ..simulation.run import save_simulation
    from ..simulation.scenario import load_scenario

    check_writable(args.out, stream_ok=False)
    scenario = load_scenario(args.scenario)
    _note(scenario.notes)
    n = _repetition_count(args.repetitions, scenario.repetition_count, args.scenario)
    base = Path(args.out)
    outs = [base.with_name(f"{base.stem}_{i:03d}{base.suffix or '.toml'}") for i in range(n)]
    _refuse_overwriting_inputs(args, outs)
    check_writable(base, stream_ok=False)
    if args.friction:
        scenario = _with_checked_friction(scenario, args)
    samples = max(1, round(scenario.options["duration_s"] * scenario.rate_hz))
    check_limit(f"--repetitions: {n} runs x {samples} samples", "batch_samples", n * samples)
    # batches of at most 1e6 samples (about 280 MB): each is written when done (memory of one batch, not of
    # all runs) and the bar moves; every run is bit-equal to its own simulation, whatever the batch
    step = max(1, min(n, _BATCH_SAMPLES // samples))
    results, written, stats, faults, assumed = [], [], [], [], {}
    with _progress_bar("simulate", "run", enabled=args.json != "-") as progress:
        for start in range(0, n, step):
            stop = min(n, start + step)
            batch = simulate_scenario(scenario, repetitions=range(start, stop))
            for k in range(stop - start):
                result = batch.result(k)
                written.append(save_simulation(result, outs[start + k]))
                faults.append(result.fault)
                if args.json:
                    mapping = result.to_mapping()
                    stats.append({**_run_assumed(mapping), "statistics": mapping["statistics"]})
                    assumed = assumed or _assumed(mapping)     # one design for every repetition
                if args.plot:
                    results.append(result)
            progress(stop, n)
    if args.plot:
        from ..plotting.simulation import plot_simulation, run_title

        what = run_title(results[0], source=Path(args.scenario).name).replace(" (repetition 0)", "")
        plot_simulation({f"repetition {i}": result for i, result in enumerate(results)}, args.plot,
                        title=what.replace("\n", f" ({len(results)} repetitions overlaid)\n", 1),
                        overlay=True)
    if args.json:
        _write_json(args.json, {**_compensator_keys(scenario.design.compensator),
                                "controller": _controller_label(scenario.design.controller),
                                "controller_table": _controller_table(scenario.design.controller), **assumed,
                                "reference": scenario.to_mapping().get("reference"),
                                "repetitions": [{"repetition": i, **{k: str(v) for k, v in paths.items()},
                                                 "controller_fault": fault, **stat}
                                                for i, (paths, stat, fault) in enumerate(zip(written, stats, faults))]})
    if args.json != "-":
        for i, paths in enumerate(written):
            print(f"repetition {i}: {paths['experiment']}")
    return _report_faults(faults)
