"""Imports the verb modules of the command line so that they register (one module per verb)."""
from . import benchmark  # noqa: F401  (forecast-design benchmark)
from . import pil  # noqa: F401  (forecast-design pil)
from . import check  # noqa: F401  (forecast-design check)
from . import identify  # noqa: F401  (forecast-design identify)
from . import simulate  # noqa: F401  (forecast-design simulate)
from . import tune_q  # noqa: F401  (forecast-design tune-q)
from . import passivity  # noqa: F401  (forecast-design passivity)
