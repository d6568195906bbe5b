"""Friction laws written once: every layer (identification, simulation, diagnosis) evaluates these.

The functions take the exponential as a parameter so that one definition serves
numpy arrays (:func:`clipped_exp`, the default for arrays), casadi expressions
(``exp=casadi.exp``) and numba-compiled scalar kernels (the default ``np.exp``
compiles for floats).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

__all__ = ["stribeck_level", "stribeck_decay", "clipped_exp"]


def clipped_exp(x: Any) -> Any:
    """``exp(x)`` for ``x <= 0``, flushed to 0 below ``-50`` (subnormal exponentials are ~30x slower)."""
    x = np.maximum(x, -50.0)
    return np.where(x > -50.0, np.exp(x), 0.0)


def stribeck_level(v: Any, static: Any, coulomb: Any, v_s: Any, exp: Callable[[Any], Any] = np.exp) -> Any:
    """Stribeck curve ``g(v) = F_c + (F_s - F_c) exp(-(v / v_s)^2)``: the friction level at speed ``v``.

    Parameters
    ----------
    v : float, ndarray or casadi expression
        Speed [rad/s] (or [m/s]).
    static : float or array
        Breakaway level ``F_s`` [N m] (or [N]).
    coulomb : float or array
        Coulomb level ``F_c``, same unit.
    v_s : float or array
        Stribeck velocity [rad/s], > 0.
    exp : callable
        The exponential for the argument's type: ``np.exp`` (default; numba scalars),
        :func:`clipped_exp` (large numpy arrays) or ``casadi.exp``.

    Returns
    -------
    float, ndarray or casadi expression
        ``g(v)``, same unit as the levels. The friction force of a static Stribeck law is
        ``g(v) sign(v) + viscous v``; LuGre uses ``g`` as the bristles' steady-state level.
    """
    r = v / v_s
    return coulomb + (static - coulomb) * exp(-(r * r))


def stribeck_decay(v: Any, v_s: Any, exp: Callable[[Any], Any] = np.exp) -> Any:
    """``exp(-(v / v_s)^2)`` [-]: the Stribeck curve with ``F_s = 1``, ``F_c = 0``."""
    return stribeck_level(v, 1.0, 0.0, v_s, exp)
