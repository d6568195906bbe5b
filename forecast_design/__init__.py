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
from .controllers import (
    CONTROLLER_KINDS,
    PAPER_PD,
    PD,
    PID,
    Controller,
    DiscreteController,
    OtherController,
    TFController,
    parse_controller,
    resolve_controller,
)
from .params import (
    COMPENSATOR_KINDS,
    ENVIRONMENT_PRESETS,
    Compensator,
    Design,
    Environment,
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
    "Controller",
    "PD",
    "PID",
    "TFController",
    "DiscreteController",
    "OtherController",
    "PAPER_PD",
    "CONTROLLER_KINDS",
    "parse_controller",
    "resolve_controller",
    "Compensator",
    "Design",
    "ENVIRONMENT_PRESETS",
    "COMPENSATOR_KINDS",
    "environment_preset",
    "EnvironmentSet",
    "resolve_environments",
    "resolve_testbed",
    "Effect",
    "Experiment",
    "Signals",
    "load_experiment",
    "save_experiment",
    "experiment_from_arrays",
    # imported on first use (sympy, casadi, numba, matplotlib stay out of `import forecast_design`)
    "transfer_functions",
    "force_loop",
    "disk_margin",
    "loop_margins",
    "analyse_loop",
    "analyse_passivity",
    "fig6_table",
    "tune_q",
    "identify",
    "fit_friction",
    "simulate",
    "diagnose",
    "export_controller",
    "run_pipeline",
]

_LAZY = {
    "Effect": "effects",
    "EnvironmentSet": "environments",
    "resolve_environments": "environments",
    "resolve_testbed": "environments",
    "Experiment": "experiment",
    "Signals": "experiment",
    "experiment_from_arrays": "experiment",
    "load_experiment": "experiment",
    "save_experiment": "experiment",
    "RationalTF": "lti",
    "transfer_functions": "symbolic",
    "force_loop": "symbolic",
    "disk_margin": "margins",
    "loop_margins": "analysis",
    "analyse_loop": "analysis",
    "analyse_passivity": "passivity",
    "fig6_table": "reproduce",
    "tune_q": "tuning",
    "identify": "friction",
    "fit_friction": "friction",
    "simulate": "simulation",
    "diagnose": "gap",
    "export_controller": "export.c",
    "run_pipeline": "pipeline",
}


def __getattr__(name: str):
    """Import the capabilities on first use (PEP 562): the command line's parser needs none of them."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'forecast_design' has no attribute {name!r}")
