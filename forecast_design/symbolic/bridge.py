"""Bridge from sympy transfer functions to numbers: ParametricTF and the model catalogue.

A :class:`ParametricTF` is built once from a sympy rational function of
``s``; its numerator and denominator coefficients are lambdified functions
of the parameter symbols, so evaluating it at a design (``.at``) costs a
few float operations, and the same coefficient functions can be evaluated
on casadi symbols (``.casadi``) for gradient-based tuning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any, Mapping

import numpy as np
import sympy as sp

from ..errors import ParameterError
from ..lti import RationalTF
from ..params import Design
from . import plant as _plant
from .numeric import (
    NOMINAL_KINDS,
    TransferFunctionEntry,
    TransferFunctions,
    force_plant_tf,
    ordered_values,
    parameter_values,
    strip_common_s,
    transfer_functions,
)

__all__ = [
    "ParametricTF",
    "derive_force_plant",
    "derive_locked_force_plant",
    "derive_motor_angle_plant",
    "derive_joint_angle_plant",
    "nominal_plant",
    "force_plant_tf",
    "parameter_values",
    "NOMINAL_KINDS",
    "TransferFunctionEntry",
    "TransferFunctions",
    "transfer_functions",
]


class _Coefficients:
    """Coefficients (descending powers of s) of one polynomial, as functions of parameters."""

    def __init__(self, poly_expr: sp.Expr, symbols: tuple[sp.Symbol, ...]):
        self.coeffs = tuple(sp.Poly(poly_expr, _plant.s).all_coeffs())
        self.symbols = symbols
        self._numeric = sp.lambdify(symbols, list(self.coeffs), modules="numpy", cse=True)

    def __call__(self, values: tuple[float, ...]) -> np.ndarray:
        out = self._numeric(*values)
        return np.array([float(c) for c in out], dtype=float)

    @cached_property
    def _casadi(self):
        import casadi as ca

        mapping = {"sqrt": ca.sqrt, "cos": ca.cos, "sin": ca.sin, "exp": ca.exp, "log": ca.log,
                   "Abs": ca.fabs, "pi": math.pi}
        return sp.lambdify(self.symbols, list(self.coeffs), modules=[mapping, "math"])

    def symbolic(self, values):
        """Evaluate on casadi symbols (or anything supporting + - * / **)."""
        return self._casadi(*values)


class ParametricTF:
    """A rational transfer function of ``s`` whose coefficients depend on parameters.

    Parameters
    ----------
    expr : sympy.Expr
        Rational function of the Laplace variable ``s`` (the symbol
        :data:`forecast_design.symbolic.plant.s`).
    name : str
        Label carried to the evaluated :class:`RationalTF`, e.g. ``"P"``.

    Attributes
    ----------
    expr : sympy.Expr
        The cancelled rational expression.
    symbols : tuple of sympy.Symbol
        Parameter symbols, sorted by name (the order of the casadi parameter vector).
    num, den : sympy.Expr
        Expanded numerator and denominator polynomials in ``s``.
    """

    def __init__(self, expr: sp.Expr, *, name: str = ""):
        expr = sp.cancel(sp.together(sp.sympify(expr)))
        num, den = sp.fraction(expr)
        self.expr = expr
        self.name = name
        self.num = sp.expand(num)
        self.den = sp.expand(den)
        free = (self.num.free_symbols | self.den.free_symbols) - {_plant.s}
        self.symbols: tuple[sp.Symbol, ...] = tuple(sorted(free, key=lambda sym: sym.name))
        self._num = _Coefficients(self.num, self.symbols)
        self._den = _Coefficients(self.den, self.symbols)

    def __repr__(self) -> str:
        return f"ParametricTF({self.name!r}: {self.expr})"

    @property
    def symbol_names(self) -> tuple[str, ...]:
        """Names of the parameter symbols, in casadi parameter-vector order."""
        return tuple(sym.name for sym in self.symbols)

    @property
    def relative_degree(self) -> int:
        """deg(den) - deg(num) for generic (non-zero) parameter values."""
        return sp.degree(self.den, _plant.s) - sp.degree(self.num, _plant.s)

    def _values(self, params: Design | Mapping[str, float]) -> tuple[float, ...]:
        return ordered_values(self.symbol_names, params, self.name)

    def at(self, params: Design | Mapping[str, float]) -> RationalTF:
        """Numeric transfer function at given parameter values.

        Parameters
        ----------
        params : Design or Mapping[str, float]
            See :func:`parameter_values`. Extra keys are ignored.

        Returns
        -------
        RationalTF
            Continuous-time TF, coefficients in descending powers of s.
            Exact common factors ``s^m`` (from parameters that are exactly
            0, e.g. a free output with k_e = 0) are divided out; no other
            cancellation is done.

        Raises
        ------
        ParameterError
            If a parameter is missing or the denominator vanishes identically.
        """
        values = self._values(params)
        num, den = strip_common_s(self._num(values), self._den(values))
        if not np.any(den != 0.0):
            raise ParameterError(
                f"{self.name or 'transfer function'} has a zero denominator at "
                + ", ".join(f"{n}={v:g}" for n, v in zip(self.symbol_names, values)),
                name=self.name, value=values,
            )
        return RationalTF(num, den, name=self.name)

    def latex(self) -> str:
        """LaTeX of the (cancelled) expression.

        Returns
        -------
        str
            E.g. ``\\frac{J k s^{2} + ...}{...}``.
        """
        return sp.latex(self.expr)

    def casadi(self):
        """casadi Function of the frequency response.

        Returns
        -------
        casadi.Function
            ``f(omega, p) -> (re, im)`` with ``omega`` the angular frequency
            [rad/s] (scalar) and ``p`` the parameter vector in the order of
            :attr:`symbol_names`; ``re`` and ``im`` are the real and imaginary
            parts of H(j omega). Built from the same coefficient expressions
            as :meth:`at`.
        """
        import casadi as ca

        omega = ca.SX.sym("omega")
        p = ca.SX.sym("p", len(self.symbols))
        args = [p[i] for i in range(len(self.symbols))]

        def at_jw(coeffs):
            # sum_n c_n (j w)^n, with (j)^n cycling 1, j, -1, -j.
            re, im = ca.SX(0), ca.SX(0)
            degree = len(coeffs) - 1
            for i, c in enumerate(coeffs):
                n = degree - i
                term = c * omega**n
                re, im = [(re + term, im), (re, im + term), (re - term, im), (re, im - term)][n % 4]
            return re, im

        nr, ni = at_jw(self._num.symbolic(args))
        dr, di = at_jw(self._den.symbolic(args))
        mag2 = dr * dr + di * di
        re = (nr * dr + ni * di) / mag2
        im = (ni * dr - nr * di) / mag2
        return ca.Function(self.name.replace("^", "_") or "tf", [omega, p], [re, im],
                           ["omega", "p"], ["re", "im"])


@lru_cache(maxsize=None)
def derive_force_plant() -> ParametricTF:
    """P(s) = tau_s/tau_m of the SEA with environment E(s) (paper eq. (2)).

    Returns
    -------
    ParametricTF
        In J_m [kg m^2], d_m [N m s/rad], k [N m/rad], J [kg m^2],
        d [N m s/rad], k_e [N m/rad]; [N m/N m].
    """
    return ParametricTF(_plant.force_plant_expr(), name="P")


@lru_cache(maxsize=None)
def derive_locked_force_plant() -> ParametricTF:
    """Locked-output plant k / (J_m s^2 + d_m s + k) = lim_{k_e -> inf} P(s).

    Returns
    -------
    ParametricTF
        In J_m, d_m, k; [N m/N m]. DC gain 1, natural frequency sqrt(k/J_m) [rad/s].
    """
    return ParametricTF(_plant.locked_force_plant_expr(), name="P")


@lru_cache(maxsize=None)
def derive_motor_angle_plant(locked: bool = False) -> ParametricTF:
    """theta/tau_m, the motor-angle response [rad/(N m)].

    Parameters
    ----------
    locked : bool
        Output locked (q = 0).

    Returns
    -------
    ParametricTF
        The motor-angle plant.
    """
    return ParametricTF(_plant.motor_angle_plant_expr(locked=locked), name="P_theta")


@lru_cache(maxsize=None)
def derive_joint_angle_plant() -> ParametricTF:
    """q/tau_m, the joint-angle response [rad/(N m)].

    Returns
    -------
    ParametricTF
        The joint-angle plant.
    """
    return ParametricTF(_plant.joint_angle_plant_expr(), name="P_q")


@lru_cache(maxsize=None)
def nominal_plant(kind: str) -> ParametricTF:
    """Nominal plant P_n(s) of an observer.

    Parameters
    ----------
    kind : str
        ``'ea-fob'`` (eq. (5), in J_m, k, J, d, k_e), ``'lo-dob'`` (eq. (6),
        in J_m, k) or ``'ld-dob'`` (eq. (8), in J_m, k, J_l, d_l).

    Returns
    -------
    ParametricTF
        P_n(s) [N m/N m].

    Raises
    ------
    ParameterError
        For another kind.
    """
    exprs = {"ea-fob": (_plant.nominal_ea_expr, "P_n^EA"),
             "lo-dob": (_plant.nominal_lo_expr, "P_n^LO"),
             "ld-dob": (_plant.nominal_ld_expr, "P_n^LD")}
    if kind not in exprs:
        raise ParameterError(
            f"nominal plant kind must be one of {', '.join(exprs)}, got {kind!r}", name="kind", value=kind
        )
    make, name = exprs[kind]
    return ParametricTF(make(), name=name)
