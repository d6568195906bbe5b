"""The ``check`` verb: validate an experiment (TOML + CSV) and summarise it."""

from __future__ import annotations

import argparse

from . import _add_json_option, _command, _json_positional, _write_json


def _configure_check(p: argparse.ArgumentParser) -> None:
    p.add_argument("experiment", metavar="EXPERIMENT.toml", nargs="?",
                   help="experiment in the forecast-experiment/1 format")
    _add_json_option(p, "the summary")


@_command("check", "validate an experiment (TOML + CSV) and summarise it", _configure_check)
def _cmd_check(args: argparse.Namespace) -> int:
    from ..experiment import load_experiment

    _json_positional(args, "experiment")
    if args.json not in (None, "-"):
        from pathlib import Path

        from ..fileio import refuse_overwriting

        toml = Path(args.experiment)
        refuse_overwriting([args.json], [toml, toml.with_suffix(".csv")])
    from ..limits import limit_of

    summary = load_experiment(args.experiment, max_samples=limit_of("log_samples_check"), reader="check").summary()
    if args.json:
        _write_json(args.json, summary)
    if args.json != "-":
        env = summary["design"]["environment"]
        print(f"{args.experiment}: ok, {summary['n_samples']} samples at {summary['rate_hz']:g} Hz "
              f"({summary['duration_s']:.4g} s), columns {', '.join(summary['columns'])}, "
              f"{'locked' if summary['locked'] else 'environment k_e = %g' % env['k_e']}")
    return 0
