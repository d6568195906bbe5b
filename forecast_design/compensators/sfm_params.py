"""The friction parameters a feed-forward takes, read without the numba kernels (for the loop analysis).

Names are :mod:`forecast_design.friction`'s (module docstring of
:mod:`forecast_design.compensators.feedforward` for the formula).
"""

from __future__ import annotations

import math
import re
from typing import Mapping

import numpy as np

from ..errors import ParameterError

__all__ = ["FEEDFORWARD_PARAMETERS", "feedforward_coefficients", "viscous_slope"]

_KEY = re.compile(r"^(viscous|viscous_pos|viscous_neg|coulomb|coulomb_pos|coulomb_neg|static|stribeck_velocity"
                  r"|offset|(coulomb_)?(sin|cos)([1-9][0-9]*))$")
#: Friction parameter names a feed-forward takes (``<i>`` a harmonic 1, 2, ...).
FEEDFORWARD_PARAMETERS = ("viscous", "coulomb", "offset", "sin<i>", "cos<i>", "coulomb_sin<i>", "coulomb_cos<i>",
                          "viscous_pos", "viscous_neg", "coulomb_pos", "coulomb_neg", "static", "stribeck_velocity")
_REFUSED = {
    "sigma0": "LuGre's bristle dynamics cannot be fed forward statically: fit the stribeck model for its static curve",
    "sigma1": "LuGre's bristle dynamics cannot be fed forward statically: fit the stribeck model for its static curve",
    "inertia": "an inertia is not friction: identify without --estimate-inertia for a compensator",
}



def feedforward_coefficients(params: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The feed-forward formula's coefficients from friction parameters by name.

    Parameters
    ----------
    params : Mapping[str, float]
        Identified parameters (viscous [N m s/rad], coulomb, offset, harmonics [N m], static [N m],
        stribeck_velocity [rad/s], the asymmetric names).

    Returns
    -------
    (ndarray, ndarray)
        ``coef`` shape (10,) (dead band and angle offset 0, last entry 1) and ``harm`` shape (4, n).

    Raises
    ------
    ParameterError
        Unknown or refused names, non-finite values, inconsistent sets.
    """
    if not isinstance(params, Mapping):
        raise ParameterError(f"friction parameters must map names to numbers, got {params!r:.60}",
                             name="friction", value=params)
    values: dict[str, float] = {}
    harmonics: list[tuple[int, int, float]] = []
    for key, value in params.items():
        key = str(key)
        if key in _REFUSED:
            raise ParameterError(f"friction parameter '{key}': {_REFUSED[key]}", name=key, value=value)
        m = _KEY.match(key)
        if m is None:
            raise ParameterError(f"friction parameter '{key}' unknown to the feed-forward; allowed: "
                                 f"{', '.join(FEEDFORWARD_PARAMETERS)}", name=key, value=value)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not math.isfinite(value):
            raise ParameterError(f"friction parameter '{key}' must be a finite number, got {value!r}",
                                 name=key, value=value)
        if m.group(4):
            row = (2 if m.group(2) else 0) + (0 if m.group(3) == "sin" else 1)
            harmonics.append((row, int(m.group(4)), float(value)))
        else:
            values[key] = float(value)
    for a, b in (("viscous", "viscous_pos"), ("viscous", "viscous_neg"), ("coulomb", "coulomb_pos"),
                 ("coulomb", "coulomb_neg")):
        if a in values and b in values:
            raise ParameterError(f"friction parameters '{a}' and '{b}' both given: a model is symmetric or "
                                 "asymmetric", name=b, value=values[b])
    if ("static" in values) != ("stribeck_velocity" in values):
        raise ParameterError("friction parameters 'static' and 'stribeck_velocity' come together (the Stribeck "
                             "model)", name="static", value=values.get("static"))
    if "static" in values and ("coulomb_pos" in values or "coulomb_neg" in values):
        raise ParameterError("a Stribeck curve needs the symmetric 'coulomb' level, not coulomb_pos/coulomb_neg",
                             name="static", value=values["static"])
    v_s = values.get("stribeck_velocity", 1.0)
    if not v_s > 0.0:
        raise ParameterError(f"friction parameter 'stribeck_velocity' must be > 0 [rad/s], got {v_s!r}",
                             name="stribeck_velocity", value=v_s)
    coulomb = values.get("coulomb", 0.0)
    coef = np.array([values.get("viscous", values.get("viscous_pos", 0.0)),
                     values.get("viscous", values.get("viscous_neg", 0.0)),
                     values.get("coulomb", values.get("coulomb_pos", 0.0)),
                     values.get("coulomb", values.get("coulomb_neg", 0.0)),
                     values.get("static", coulomb) - coulomb, v_s, values.get("offset", 0.0), 0.0, 0.0, 1.0])
    n = max((i for _, i, _ in harmonics), default=1)
    harm = np.zeros((4, n))
    for row, i, value in harmonics:
        harm[row, i - 1] = value
    return coef, harm




def viscous_slope(params: Mapping[str, float]) -> float:
    """The feed-forward's linear part, the mean of its two viscous levels [N m s/rad].

    Parameters
    ----------
    params : Mapping[str, float]
        Identified parameters.

    Returns
    -------
    float
        The describing-function slope of ``viscous v`` for a zero-mean sinusoid.
    """
    coef, _ = feedforward_coefficients(params)
    return 0.5 * float(coef[0] + coef[1])
