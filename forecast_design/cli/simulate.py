"""The ``simulate`` verb: a scenario on the virtual testbed into an experiment (docs/scenario.md)."""

from __future__ import annotations

import argparse

from . import _add_json_option, _command, _friction_from_file, _json_positional, _write_json


def _configure_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO.toml", nargs="?",
                   help="nominal model + [truth] effects + [reference] + [simulation] (see docs/scenario.md)")
    p.add_argument("--out", required=True, metavar="RUN.toml", help="the simulated run, as an experiment")
    p.add_argument("--friction", metavar="F.json",
                   help="identified friction (identify --model sfm --json F.json): the run's compensator becomes "
                        "an SFM on these parameters (the scenario's compensator must be none or sfm)")
    _add_json_option(p, "the written paths and the run's statistics")
    p.add_argument("--plot", metavar="OUT.png", help="plot the run (torque tracking, friction, motion)")


@_command("simulate", "simulate the testbed (friction, effects, controller at 2 kHz) into an experiment",
          _configure_simulate)
def _cmd_simulate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..fileio import check_writable, refuse_overwriting
    from ..simulation.run import save_simulation
    from ..simulation.scenario import load_scenario

    _json_positional(args, "scenario")
    out = Path(args.out)  # save_simulation writes RUN.toml, RUN.csv, RUN.truth.json, RUN.truth.csv
    refuse_overwriting([out, out.with_suffix(".csv"), out.with_name(out.stem + ".truth.json"),
                        out.with_name(out.stem + ".truth.csv")] + ([args.plot] if args.plot else [])
                       + ([args.json] if args.json not in (None, "-") else []),
                       [args.scenario] + ([args.friction] if args.friction else []))
    check_writable(out)
    scenario = load_scenario(args.scenario)
    if args.friction:
        scenario = scenario.with_friction(_friction_from_file(args.friction))
    result = scenario.run()
    paths = save_simulation(result, args.out)
    if args.plot:
        from ..plotting.simulation import plot_simulation

        plot_simulation({args.scenario: result}, args.plot)
    if args.json:
        comp = result.design.compensator
        _write_json(args.json, {**{key: str(value) for key, value in paths.items()},
                                "compensator": "none" if comp is None else comp.kind,
                                "friction": None if comp is None else comp.friction_params,
                                "statistics": result.to_mapping()["statistics"]})
    if args.json != "-":
        for key, value in paths.items():
            print(f"{key}: {value}")
    return 0
