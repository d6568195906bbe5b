"""Symbolic SEA models (sympy) and observer filters (the force loop is in :mod:`forecast_design.loops`).

The models are derived in sympy (:mod:`.plant`, :mod:`.bridge`); their
coefficient polynomials are also written to a generated numeric catalogue
(:mod:`.codegen`, kept identical by a test), so evaluating plants, observers
and loops does not import sympy. The sympy-backed names below are imported on
first use.
"""

from .numeric import (
    NOMINAL_KINDS,
    TransferFunctionEntry,
    TransferFunctions,
    catalogue_tf,
    force_plant_tf,
    motor_angle_tf,
    nominal_plant_tf,
    parameter_values,
    transfer_functions,
)
from .observers import (
    ObserverFilters,
    compensator_q_tf,
    observer_filters,
    q_filter,
    q_filter_tf,
    required_q_order,
)

__all__ = [
    "NOMINAL_KINDS",
    "ParametricTF",
    "TransferFunctionEntry",
    "TransferFunctions",
    "catalogue_tf",
    "derive_force_plant",
    "derive_joint_angle_plant",
    "derive_locked_force_plant",
    "derive_motor_angle_plant",
    "force_plant_tf",
    "motor_angle_tf",
    "nominal_plant",
    "nominal_plant_tf",
    "parameter_values",
    "transfer_functions",
    "ObserverFilters",
    "observer_filters",
    "q_filter",
    "q_filter_tf",
    "compensator_q_tf",
    "required_q_order",
]

# The force loop moved to forecast_design.loops.continuous; its names resolve there for one release.
_MOVED_TO_LOOPS = ("BREAK_POINTS", "ForceLoop", "force_loop")
_SYMPY_BACKED = ("ParametricTF", "derive_force_plant", "derive_joint_angle_plant", "derive_locked_force_plant",
                 "derive_motor_angle_plant", "nominal_plant")


def __getattr__(name: str):
    """Import the sympy-backed derivations on first use (PEP 562)."""
    if name in _MOVED_TO_LOOPS:
        import importlib

        return getattr(importlib.import_module(__name__.rsplit(".", 1)[0] + ".loops.continuous"), name)
    if name in _SYMPY_BACKED:
        from . import bridge

        value = getattr(bridge, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'forecast_design.symbolic' has no attribute {name!r}")
