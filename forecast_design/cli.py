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
