"""Exact disk margins (Seiler, Packard, Gahinet 2020) of a loop transfer function.

The one home of the disk-margin mathematics: the force-loop builders
(:mod:`forecast_design.loops.continuous`, :mod:`forecast_design.loops.sampled`), the Q
tuner and the reproductions all evaluate margins here.

Modules: :mod:`.disk` (the disk's geometry and the result types), :mod:`.exact`
(one loop, exactly), :mod:`.batch` (many loops at once, the same exact peaks).
"""

from .batch import DiskMarginBatch, disk_margins
from .classical import ClassicalMargins, Crossover, classical_margins
from .disk import (DiskMargin, DiskMarginCurve, check_skew, disk_center_radius, disk_gain_margin,
                   disk_phase_margin_deg, json_float, resolve_skew)
from .exact import (STABILITY_TOLERANCE, as_loop, continuous_equivalent, disk_margin, disk_margin_curve,
                    disk_margin_from_polynomials, frequency_rad_s)

__all__ = [
    "DiskMargin", "DiskMarginCurve", "DiskMarginBatch", "disk_margin", "disk_margins", "disk_margin_curve",
    "disk_gain_margin", "disk_phase_margin_deg", "disk_center_radius", "disk_margin_from_polynomials",
    "check_skew", "resolve_skew", "as_loop", "continuous_equivalent", "frequency_rad_s", "json_float",
    "STABILITY_TOLERANCE", "ClassicalMargins", "Crossover", "classical_margins",
]
