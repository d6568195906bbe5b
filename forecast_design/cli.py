"""The ``forecast-design`` command line: one verb, one library call."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Callable, Sequence

from . import __version__
from .errors import ForecastError

__all__ = ["main"]


class _ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2 (argparse's own convention)."""

    def error(self, message: str) -> None:  # pragma: no cover - exercised via main()
        self.exit(2, f"{self.prog}: error: {message}\n")


def _print_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2, allow_nan=True)
    sys.stdout.write("\n")


_COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]]] = {}


def _command(name: str, help_text: str, configure: Callable[[argparse.ArgumentParser], None]):
    def register(handler: Callable[[argparse.Namespace], int]):
        _COMMANDS[name] = (help_text, configure, handler)
        return handler

    return register


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every verb."""
    parser = _ArgumentParser(
        prog="forecast-design",
        description="Force-control design toolbox for series elastic actuators (Forecast testbed).",
    )
    parser.add_argument("--version", action="version", version=f"forecast-design {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_ArgumentParser)
    for name, (help_text, configure, handler) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        configure(p)
        p.set_defaults(handler=handler)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code (0 ok, 2 bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        return int(args.handler(args) or 0)
    except ForecastError as exc:
        if args.debug:
            raise
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"forecast-design: error: {message}", file=sys.stderr)
        return 2
    except OSError as exc:
        if args.debug:
            raise
        print(f"forecast-design: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2


# --- shared option helpers -------------------------------------------------


def _design_from_args(args: argparse.Namespace, *, env_name: str | None = None):
    """The design named by --experiment (its nominal model) or --env (a preset)."""
    from .params import Design

    if getattr(args, "experiment", None):
        from .experiment import load_experiment

        return load_experiment(args.experiment).design
    return Design.nominal(env_name or "soft")


# --- tf ---------------------------------------------------------------------


def _configure_tf(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group()
    src.add_argument("--env", action="append", metavar="NAME",
                     help="environment preset (repeat to overlay in --plot); default soft")
    src.add_argument("--experiment", metavar="FILE.toml", help="use the nominal model of an experiment")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--plot", metavar="OUT.png", help="Bode plot of P and the nominal plants")


@_command("tf", "print the plant P and the nominal plants EA, LO, LD (eqs. 2-8)", _configure_tf)
def _cmd_tf(args: argparse.Namespace) -> int:
    from .symbolic import transfer_functions

    names = args.env or [None]
    designs = [(name or "soft", _design_from_args(args, env_name=name)) for name in names]
    if args.experiment:
        designs = [(args.experiment, designs[0][1])]
    results = [(label, transfer_functions(design)) for label, design in designs]
    if args.plot:
        from .plotting.bode import plot_bode

        curves = [(f"{key} ({label})" if len(results) > 1 else key, getattr(tfs, key).tf)
                  for label, tfs in results for key in ("P", "EA", "LO", "LD")]
        plot_bode(curves, args.plot)
    if args.json:
        _print_json(results[0][1].to_mapping() if len(results) == 1
                    else {label: tfs.to_mapping() for label, tfs in results})
        return 0
    for label, tfs in results:
        print(f"environment: {label}")
        for key, value in tfs.to_mapping().items():
            print(f"  {key}(s) = {value['latex']}")
            print(f"    num = {value['num']}")
            print(f"    den = {value['den']}")
            poles = ", ".join(f"{re:.6g}{im:+.6g}j" for re, im in value["poles"])
            print(f"    poles = [{poles}]  dc_gain = {value['dc_gain']:.6g}")
    if args.plot:
        print(f"plot: {args.plot}")
    return 0
