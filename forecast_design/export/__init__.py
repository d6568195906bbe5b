"""Controller export: discretisation (and, later, C emission) of filters and controllers."""

from .discretize import METHODS, DiscreteFilter, DiscreteTF, discretize, sos_filter, sos_step

__all__ = ["METHODS", "DiscreteTF", "DiscreteFilter", "discretize", "sos_step", "sos_filter"]
