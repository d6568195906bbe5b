"""Coupled stability with every passive environment: the actuator's one-port, exactly.

Modules: :mod:`.port` (the driving-point impedance Z(s) from the force loop's own objects),
:mod:`.exact` (extrema and sign changes on the imaginary axis, root-locus intervals: roots of
polynomials, no grid), :mod:`.analysis` (the ``passivity`` verb's result).
"""

from .analysis import PassivityCurve, PassivityResult, analyse_passivity
from .exact import (is_hurwitz, magnitude_range, negative_bands, real_part_minimum, stable_parameter_intervals)
from .port import PORTS, PortImpedance, port_impedance, tustin_equivalent

__all__ = ["analyse_passivity", "PassivityResult", "PassivityCurve", "PortImpedance", "port_impedance", "PORTS",
           "tustin_equivalent", "real_part_minimum", "negative_bands", "magnitude_range", "is_hurwitz",
           "stable_parameter_intervals"]
