"""Deprecated location of :mod:`forecast_design.loops.continuous` (kept for one release).

Resolved on use so that the symbolic layer does not import the loops layer above it.
"""

import importlib as _importlib

_NAMES = ("ForceLoop", "force_loop", "BREAK_POINTS", "STABILITY_TOLERANCE")


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(_importlib.import_module(__name__.rsplit(".", 2)[0] + ".loops.continuous"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
