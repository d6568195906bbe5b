"""Controller export: discretisation (and, later, C emission) of filters and controllers."""

from ..discrete import (
    FIRST_DIFFERENCE,
    METHODS,
    DiscreteFilter,
    DiscreteTF,
    delta_to_sos,
    discretize,
    sos_filter,
    sos_step,
    sos_to_delta,
)

__all__ = ["METHODS", "FIRST_DIFFERENCE", "DiscreteTF", "DiscreteFilter", "discretize", "sos_step", "sos_filter",
           "delta_to_sos", "sos_to_delta"]
