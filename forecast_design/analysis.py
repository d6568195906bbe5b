"""Robustness of one force loop: its disk margin, continuous or sampled (the ``margins`` verb).

The disk-margin mathematics lives in :mod:`forecast_design.margins`, the sampled-data loop in
:mod:`forecast_design.loops.sampled`, the Fig. 6 table in :mod:`forecast_design.reproduce`;
their names stay importable from here for one release.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

from .loops.sampled import SampledForceLoop, sampled_force_loop
from .margins import (
    DiskMargin,
    check_skew,
    DiskMarginCurve,
    disk_center_radius,
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from .environments import resolve_environments, resolve_testbed
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


def _as_design(spec: Any, testbed: Any, what: str) -> Design:
    """A Design, or one environment (object, preset, inline values, file) on ``testbed``."""
    if isinstance(spec, Design):
        return spec if testbed is None else dataclasses.replace(spec, testbed=resolve_testbed(testbed))
    tb = resolve_testbed(testbed)
    return Design(testbed=tb, environment=resolve_environments(spec, testbed=tb).single(what)[1])


def loop_margins(
    design: Any,
    compensator: Compensator | str | None = None,
    *,
    testbed: Any = None,
    believed: Any = None,
    controller: PDController | None = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = 1,
    skew: float = 0.0,
    sigma: float | None = None,
    method: str = "tustin",
) -> DiskMargin:
    """Disk margin of one force loop (the ``margins`` verb).

    Parameters
    ----------
    design : Design, Environment, str or EnvironmentSet
        The true testbed and environment (a Design), or one environment in any form
        :func:`~forecast_design.environments.resolve_environments` accepts (an Environment,
        ``"soft"``, ``"k_e=20,J_e=0.02"``, a file holding one); a Design's ``controller`` and
        ``compensator`` are the defaults of the next arguments.
    compensator : Compensator, str or None
        Observer (or its kind); ``None`` uses ``design.compensator`` (none if that is unset).
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`); None keeps the
        Design's, or Table 1.
    believed : Design, Environment, str or None
        What the observer believes (environment-knowledge error), in the same forms;
        ``None``: the truth.
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
    skew : float
        Disk skew [-] (python-control's name).
    sigma : float or None
        Alias of ``skew``.
    method : str
        Discretisation of the controller and observer for ``sampled`` (``tustin``, ``zoh``,
        ``backward-euler``: the simulator's ``method``).

    Returns
    -------
    DiskMargin
        alpha [-], disk-based gain [dB] and phase [deg] margins, critical frequency [rad/s]
        and delay margin [s]; ``stable`` from the full characteristic polynomial.
    """
    design = _as_design(design, testbed, "loop_margins")
    if believed is not None:
        believed = _as_design(believed, design.testbed, "loop_margins(believed=...)")
    if isinstance(compensator, str):
        compensator = None if compensator == "none" else Compensator(kind=compensator)
    sigma = check_skew(skew if sigma is None else sigma)
    comp = compensator if compensator is not None else design.compensator
    ctrl = controller if controller is not None else (design.controller or PDController(P=5.0, D=0.1))
    if sampled:
        return sampled_force_loop(design, comp, controller=ctrl, believed=believed, rate_hz=rate_hz,
                                  break_at=break_at, delay_samples=delay_samples, method=method).disk_margin(sigma)
    from .loops import force_loop

    loop = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at)
    return disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))
