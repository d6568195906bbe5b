"""Imports the verb modules of the command line so that they register (one module per verb)."""
from . import benchmark  # noqa: F401  (forecast-design benchmark)
from . import pil  # noqa: F401  (forecast-design pil)
