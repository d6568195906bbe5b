"""Symbolic SEA models (sympy), observer filters and the numeric force loop.

Importing this package imports sympy; the rest of the toolbox imports it
only where symbolic models are needed.
"""

from .bridge import (
    NOMINAL_KINDS,
    ParametricTF,
    TransferFunctionEntry,
    TransferFunctions,
    derive_force_plant,
    derive_joint_angle_plant,
    derive_locked_force_plant,
    derive_motor_angle_plant,
    force_plant_tf,
    nominal_plant,
    parameter_values,
    transfer_functions,
)
from .loops import BREAK_POINTS, ForceLoop, force_loop
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
    "derive_force_plant",
    "derive_joint_angle_plant",
    "derive_locked_force_plant",
    "derive_motor_angle_plant",
    "force_plant_tf",
    "nominal_plant",
    "parameter_values",
    "transfer_functions",
    "BREAK_POINTS",
    "ForceLoop",
    "force_loop",
    "ObserverFilters",
    "observer_filters",
    "q_filter",
    "q_filter_tf",
    "compensator_q_tf",
    "required_q_order",
]
