"""Robustness of one force loop: its disk margin, continuous or sampled (the ``margins`` verb).

The disk-margin mathematics lives in :mod:`forecast_design.margins`, the sampled-data loop in
:mod:`forecast_design.loops.sampled`, the Fig. 6 table in :mod:`forecast_design.reproduce`;
their names stay importable from here for one release.
"""

from __future__ import annotations

import importlib
from typing import Any

from .loops.sampled import SampledForceLoop, sampled_force_loop
from .margins import (
    DiskMargin,
    DiskMarginCurve,
    disk_center_radius,
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from .params import Compensator, Design, PDController

__all__ = [
    "DiskMargin",
    "DiskMarginCurve",
    "disk_margin",
    "disk_margin_curve",
    "disk_gain_margin",
    "disk_phase_margin_deg",
    "disk_center_radius",
    "SampledForceLoop",
    "sampled_force_loop",
    "loop_margins",
]

# Names that moved to a higher layer (Fig. 6 is a reproduction); resolved on use, one release.
_MOVED = {"fig6_table": "reproduce", "MarginRow": "reproduce"}


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module(f"{__package__}.{_MOVED[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def loop_margins(
    design: Design,
    compensator: Compensator | None = None,
    *,
    believed: Design | None = None,
    controller: PDController | None = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = 1,
    sigma: float = 0.0,
) -> DiskMargin:
    """Disk margin of one force loop (the ``margins`` verb).

    Parameters
    ----------
    design : Design
        The true testbed and environment; its ``controller`` and ``compensator`` are the
        defaults of the next two arguments.
    compensator : Compensator or None
        Observer; ``None`` uses ``design.compensator`` (none if that is unset).
    believed : Design or None
        What the observer believes (environment-knowledge error); ``None``: the truth.
    controller : PDController or None
        Force controller; ``None`` uses ``design.controller`` or the paper's P = 5, D = 0.1.
    break_at : str
        ``'controller'`` (paper) or ``'plant-input'``.
    sampled : bool
        Analyse the sampled-data loop (:func:`sampled_force_loop`: 200 Hz derivative filter,
        Tustin controller and observer, ZOH plant, delays) instead of the continuous one
        (:func:`~forecast_design.loops.continuous.force_loop`, pure PD).
    rate_hz : float
        Sampling rate for ``sampled`` [Hz].
    delay_samples : int
        Computation delay for ``sampled`` [samples].
    sigma : float
        Disk skew [-].

    Returns
    -------
    DiskMargin
        alpha [-], disk-based gain [dB] and phase [deg] margins, critical frequency [rad/s]
        and delay margin [s]; ``stable`` from the full characteristic polynomial.
    """
    comp = compensator if compensator is not None else design.compensator
    ctrl = controller if controller is not None else (design.controller or PDController(P=5.0, D=0.1))
    if sampled:
        return sampled_force_loop(design, comp, controller=ctrl, believed=believed, rate_hz=rate_hz,
                                  break_at=break_at, delay_samples=delay_samples).disk_margin(sigma)
    from .loops import force_loop

    loop = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at)
    return disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))
