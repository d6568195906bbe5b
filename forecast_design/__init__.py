"""forecast_design: force-control design toolbox for series elastic actuators.

Derive, analyse, tune, simulate, identify, diagnose and export force
controllers and friction observers for the Forecast SEA testbed.
"""

from .errors import (
    ExperimentFormatError,
    ExportError,
    ForecastError,
    IdentifiabilityError,
    ParameterError,
    SolverError,
)
from .lti import RationalTF
from .params import (
    COMPENSATOR_KINDS,
    ENVIRONMENT_PRESETS,
    Compensator,
    Design,
    Environment,
    PDController,
    Testbed,
    environment_preset,
)

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "ForecastError",
    "ExperimentFormatError",
    "ParameterError",
    "IdentifiabilityError",
    "SolverError",
    "ExportError",
    "RationalTF",
    "Testbed",
    "Environment",
    "PDController",
    "Compensator",
    "Design",
    "ENVIRONMENT_PRESETS",
    "COMPENSATOR_KINDS",
    "environment_preset",
]
