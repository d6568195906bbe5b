"""Deprecated location of :mod:`forecast_design.discrete` (kept for one release)."""

from ..discrete import *  # noqa: F401,F403
from ..discrete import __all__  # noqa: F401
