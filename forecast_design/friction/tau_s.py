"""What a measured ``tau_s`` column means for a friction fit: its zero and its scale.

The friction identification explains ``tau_m - J_m theta'' - tau_s``; a torque sensor's zero
enters it as a constant (fitted as an offset term when the column carries one,
:func:`tau_s_zero_offset`) and its scale as a torque proportional to ``tau_s``, which the log
cannot tell from an error of ``k``: :func:`tau_s_scale_check` repeats the fit with the encoders'
torque and flags what moves.
"""

from __future__ import annotations

import dataclasses
import math
from types import MappingProxyType
from typing import Any, Callable

import numpy as np

from ..errors import ForecastError
from .results import FrictionFit
from .source import friction_log
from .terms import FrictionModel

__all__ = ["TAU_S_SCALE_CHECK", "tau_s_scale_check", "tau_s_zero_offset"]


#: Relative disagreement between a measured ``tau_s`` and ``k (theta - q)`` above which the friction
#: fit is repeated with the encoders' torque (:func:`tau_s_scale_check`) [-].
TAU_S_SCALE_CHECK = 0.005


def tau_s_scale_check(log: Any, fit: FrictionFit, fm: FrictionModel, fit_friction: Callable[..., FrictionFit],
                      **options: Any) -> FrictionFit:
    """Flag the parameters that depend on a measured ``tau_s``'s scale when it disagrees with the encoders.

    A torque sensor whose reading is ``g k (theta - q)`` with ``|g - 1|`` above
    :data:`TAU_S_SCALE_CHECK` has a scale error, or the TOML's ``k`` has one (its datasheet
    tolerance is 3 %), and the log cannot say which; the explained torque
    ``tau_m - J_m theta'' - tau_s`` carries it (an 8 % scale moved viscous by 9 % outside its
    interval on an independent log, where the link's damping makes ``tau_s`` follow the velocity). The fit is repeated with ``tau_s`` from the encoders,
    ``k (theta - q)`` plus the column's zero (by ``fit_friction``, the identification's own fit,
    with the same ``options``); every parameter that moves by more than its 95 % interval's
    half-width is ``uncertain`` with the reason, the others keep their status.
    """
    from ..experiment import Experiment, experiment_from_arrays
    from ..plausibility import DATASHEET_TOLERANCE, ParameterStatus
    from ..tau_s_source import tau_s_source_of

    if not isinstance(log, Experiment):
        return fit
    src = tau_s_source_of(log)
    k = log.design.testbed.k
    if not src.measured or src.k_log is None or abs(src.k_log / k - 1.0) <= TAU_S_SCALE_CHECK:
        return fit
    sig = log.signals
    theta = np.asarray(sig.theta, dtype=float)
    q = np.zeros_like(theta) if log.design.environment.locked else np.asarray(sig.q, dtype=float)
    encoders = experiment_from_arrays(log.design, log.rate_hz, sig.t, sig.tau_m, sig.theta, sig.q,
                                      tau_s=k * (theta - q) + (src.offset_N_m or 0.0), tau_r=sig.tau_r)
    data = friction_log(encoders)
    try:
        other = fit_friction(data.t, data.position, data.force, fm,
                             inertia=None if "inertia" in fm.names else data.inertia, adequacy=False,
                             **{**options, "method_error": False})
    except ForecastError:
        return fit
    status = dict(fit.status)
    for name, st in fit.status.items():
        lo, hi = fit.interval95.get(name, (math.nan, math.nan))
        half = 0.5 * (hi - lo)
        moved = float(other.params.get(name, math.nan)) - float(fit.params[name])
        if st.identified and math.isfinite(half) and abs(moved) > half:
            status[name] = ParameterStatus(
                name=name, value=st.value, std=st.std, status="uncertain", plausible=st.plausible,
                reason=(f"moves by {moved:+.3g} when tau_s is taken from the encoders: the column reads "
                        f"{100 * (src.k_log / k - 1):+.1f} % against k (theta - q) (the spring's datasheet "
                        f"tolerance is {100 * DATASHEET_TOLERANCE['k']:g} %): a torque sensor's scale, or k, "
                        "is off, and this log cannot say which"))
    return dataclasses.replace(fit, status=MappingProxyType(status))


def tau_s_zero_offset(log: Any) -> bool:
    """True for an SEA experiment whose ``tau_s`` column carries a constant beyond ``k_log (theta - q)``."""
    from ..experiment import Experiment
    from ..tau_s_source import tau_s_source_of

    return isinstance(log, Experiment) and tau_s_source_of(log).zero_offset
