"""Numeric evaluation of the catalogued symbolic models, without importing sympy.

The coefficient functions come from ``_catalogue.py``, generated from the sympy
derivations by :mod:`.codegen` (a test keeps the two identical). Everything a
command needs at run time (plants, nominal plants, Q filters, the plant
polynomials of the force loop, the ``tf`` verb's table) is evaluated here.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..environments import resolve_environments, resolve_testbed
from ..errors import ParameterError
from ..lti import RationalTF
from ..params import Design
from ._catalogue import MODELS

__all__ = [
    "parameter_values",
    "catalogue_tf",
    "catalogue_polynomials",
    "catalogue_relative_degree",
    "catalogue_latex",
    "force_plant_tf",
    "motor_angle_tf",
    "sea_state_space",
    "nominal_plant_tf",
    "NOMINAL_KINDS",
    "NOMINAL_KEYS",
    "TransferFunctionEntry",
    "TransferFunctions",
    "transfer_functions",
]

#: Compensator kinds that have a nominal plant P_n(s).
NOMINAL_KINDS = ("ea-fob", "lo-dob", "ld-dob")
#: Catalogue key of each nominal plant.
NOMINAL_KEYS = {"ea-fob": "P_n^EA", "lo-dob": "P_n^LO", "ld-dob": "P_n^LD"}


def parameter_values(params: Design | Mapping[str, float]) -> dict[str, float]:
    """Flat parameter values keyed by symbol name.

    Parameters
    ----------
    params : Design or Mapping[str, float]
        A design (``Design.parameters()``; plus ``w_q`` = 2 pi ``w_q_hz``
        [rad/s] when it has a compensator) or a mapping from symbol names
        (``J_m``, ``d_m``, ``k``, ``J``, ``d``, ``k_e``, ``J_l``, ``d_l``,
        ``w_q``) to values in SI units.

    Returns
    -------
    dict of str to float
        The values.
    """
    if isinstance(params, Design):
        values = params.parameters()
        if params.compensator is not None:
            values["w_q"] = 2.0 * math.pi * params.compensator.w_q_hz
        return values
    if not isinstance(params, Mapping):
        raise ParameterError(
            "parameters must be a Design or a mapping of symbol names to numbers, "
            f"got {type(params).__name__}",
            name="params", value=params,
        )
    return {str(key): value for key, value in params.items()}


def ordered_values(names: tuple[str, ...], params: Design | Mapping[str, float], label: str) -> tuple[float, ...]:
    """Values of ``names`` from ``params``, validated (missing or non-numeric -> ParameterError).

    Parameters
    ----------
    names : tuple of str
        Parameter names, in the order the coefficient functions take them.
    params : Design or Mapping[str, float]
        See :func:`parameter_values`.
    label : str
        Name of the model, for messages.

    Returns
    -------
    tuple of float
        The values.
    """
    values = parameter_values(params)
    out = []
    for name in names:
        if name not in values:
            where = "design (no compensator sets w_q)" if name == "w_q" else "parameters"
            raise ParameterError(f"{label or 'transfer function'} needs parameter '{name}', missing from the {where}",
                                 name=name, value=None)
        value = values[name]
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise ParameterError(f"parameter '{name}' must be a number, got {value!r}", name=name, value=value)
        out.append(float(value))
    return tuple(out)


def strip_common_s(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Divide num and den by the largest common power of s (exact trailing zeros).

    A parameter that is exactly 0 (k_e = 0: free output; d_l = 0) makes a
    factor s appear in both polynomials; dividing it out is exact.

    Parameters
    ----------
    num, den : ndarray
        Polynomials in descending powers of s.

    Returns
    -------
    (ndarray, ndarray)
        The reduced pair.
    """
    if not np.any(num != 0.0):
        return num, den
    while len(num) > 1 and len(den) > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return num, den


def _model(key: str) -> Mapping[str, Any]:
    try:
        return MODELS[key]
    except KeyError:
        raise ParameterError(f"no catalogued model '{key}'", name="key", value=key) from None


def catalogue_polynomials(key: str, params: Design | Mapping[str, float]) -> tuple[np.ndarray, ...]:
    """Coefficient arrays (descending powers of s) of a catalogued model's polynomials.

    Parameters
    ----------
    key : str
        Catalogue key (``P``, ``P_locked``, ``P_theta``, ``P_n^EA``, ``sea``, ``Q_butterworth_2``...).
    params : Design or Mapping[str, float]
        Parameter values (see :func:`parameter_values`).

    Returns
    -------
    tuple of ndarray
        (num, den) for a transfer function; (N_s, N_theta, D) for ``sea``/``sea_locked``.
    """
    model = _model(key)
    values = ordered_values(model["symbols"], params, model["label"])
    return tuple(np.array(f(*values), dtype=float) for f in model["polynomials"])


def sea_state_space(design: Design, *, spring_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Nominal SEA state space x' = A x + B u from the symbolic equations (plant.sea_state_space).

    Parameters
    ----------
    design : Design
        Testbed and (unless locked) environment; the environment needs J > 0.
    spring_scale : float
        Factor on the spring stiffness k [-] (a calibrated spring torque scale).

    Returns
    -------
    (A, B) : tuple of ndarray
        States (theta [rad], theta' [rad/s], q [rad], q' [rad/s]) (locked: the first two);
        inputs (tau_m [N m], extra output torque tau_e [N m]).
    """
    key = "sea_ss_locked" if design.environment.locked else "sea_ss"
    model = _model(key)
    values = parameter_values(design)
    values["k"] = values["k"] * spring_scale
    args = ordered_values(model["symbols"], values, "state space")
    return tuple(np.array(f(*args), dtype=float) for f in model["matrices"])


def catalogue_tf(key: str, params: Design | Mapping[str, float]) -> RationalTF:
    """A catalogued transfer function at given parameter values.

    Parameters
    ----------
    key : str
        Catalogue key.
    params : Design or Mapping[str, float]
        Parameter values; extra keys are ignored.

    Returns
    -------
    RationalTF
        Coefficients in descending powers of s; exact common factors s^m (from
        parameters exactly 0) divided out, nothing else cancelled.
    """
    model = _model(key)
    num, den = catalogue_polynomials(key, params)
    num, den = strip_common_s(num, den)
    if not np.any(den != 0.0):
        raise ParameterError(f"{model['label']} has a zero denominator at the given parameters",
                             name=model["label"], value=None)
    return RationalTF(num, den, name=model["label"])


def catalogue_relative_degree(key: str) -> int:
    """Relative degree of a catalogued transfer function for generic parameters.

    Parameters
    ----------
    key : str
        Catalogue key.

    Returns
    -------
    int
        deg(den) - deg(num).
    """
    return int(_model(key)["relative_degree"])


def catalogue_latex(key: str) -> str:
    """LaTeX of a catalogued transfer function (as sympy printed it).

    Parameters
    ----------
    key : str
        Catalogue key.

    Returns
    -------
    str
        The LaTeX.
    """
    return str(_model(key)["latex"])


def force_plant_tf(design: Design) -> RationalTF:
    """Numeric P(s) = tau_s/tau_m for a design, locked or not.

    Parameters
    ----------
    design : Design
        Uses J_m [kg m^2], d_m [N m s/rad], k [N m/rad] and, unless
        ``environment.locked``, J [kg m^2], d [N m s/rad], k_e [N m/rad].

    Returns
    -------
    RationalTF
        P(s), coefficients in descending powers of s [N m/N m].

    Examples
    --------
    >>> from forecast_design.params import Design
    >>> round(force_plant_tf(Design.nominal("locked")).dcgain(), 12)
    1.0
    """
    return catalogue_tf("P_locked" if design.environment.locked else "P", design)


def motor_angle_tf(design: Design) -> RationalTF:
    """Numeric theta/tau_m for a design, locked or not [rad/(N m)].

    Parameters
    ----------
    design : Design
        The true design.

    Returns
    -------
    RationalTF
        theta(s)/tau_m(s).
    """
    return catalogue_tf("P_theta_locked" if design.environment.locked else "P_theta", design)


def nominal_plant_tf(kind: str, believed: Design) -> RationalTF:
    """Numeric nominal plant P_n(s) of an observer at the design it believes in.

    Parameters
    ----------
    kind : str
        ``'ea-fob'`` (eq. 5), ``'lo-dob'`` (eq. 6) or ``'ld-dob'`` (eq. 8).
    believed : Design
        The believed design (J_m, k; for EA its environment, for LD its link). With a locked
        believed environment the EA-FOB's nominal plant is P_n^LO (the limit k_e -> infinity).

    Returns
    -------
    RationalTF
        P_n(s) [N m/N m].
    """
    if kind not in NOMINAL_KEYS:
        raise ParameterError(f"nominal plant kind must be one of {', '.join(NOMINAL_KEYS)}, got {kind!r}",
                             name="kind", value=kind)
    if kind == "ea-fob" and believed.environment.locked:
        kind = "lo-dob"   # a locked environment is k_e -> infinity: P_n^EA becomes P_n^LO (eq. 6)
    return catalogue_tf(NOMINAL_KEYS[kind], believed)


@dataclass(frozen=True, slots=True)
class TransferFunctionEntry:
    """One transfer function: its symbolic form and its value at a design."""

    latex: str        # LaTeX of the parametric expression
    tf: RationalTF    # value at the design [N m/N m]

    def to_mapping(self) -> dict[str, Any]:
        """``{"latex", "num", "den", "poles", "dc_gain"}`` with den[0] == 1."""
        return {"latex": self.latex, **self.tf.to_mapping()}

    def to_control(self):
        """The value as a ``control.TransferFunction`` (python-control)."""
        return self.tf.to_control()


@dataclass(frozen=True, slots=True)
class TransferFunctions:
    """The plant and the three nominal plants at one design (the ``tf`` verb)."""

    P: TransferFunctionEntry    # true force plant, eq. (2) (locked plant if locked)
    EA: TransferFunctionEntry   # EA-FOB nominal plant, eq. (5) (= LO if locked)
    LO: TransferFunctionEntry   # LO-DOB nominal plant, eq. (6)
    LD: TransferFunctionEntry   # LD-DOB nominal plant, eq. (8)

    def to_mapping(self) -> dict[str, dict[str, Any]]:
        """``{"P": {...}, "EA": {...}, "LO": {...}, "LD": {...}}`` (see TransferFunctionEntry)."""
        return {name: getattr(self, name).to_mapping() for name in ("P", "EA", "LO", "LD")}

    def to_control(self) -> dict[str, Any]:
        """``{"P", "EA", "LO", "LD"}`` as ``control.TransferFunction`` values (python-control)."""
        return {name: getattr(self, name).to_control() for name in ("P", "EA", "LO", "LD")}


def transfer_functions(design: Any = "soft", *, testbed: Any = None) -> TransferFunctions:
    """P and the nominal plants P_n^EA, P_n^LO, P_n^LD at a design.

    Parameters
    ----------
    design : Design, Environment, str or path
        A Design, or one environment in any form
        :func:`~forecast_design.environments.resolve_environments` accepts (an Environment, a
        preset name such as ``"soft"``, inline ``"k_e=20,J_e=0.02"`` values, a file holding one;
        a set of several is an error: call once per member). EA uses the design's own
        environment (with d_m = 0); LD uses its J_l [kg m^2] and d_l [N m s/rad]; LO depends
        on J_m and k only. For a locked design P is the locked plant and EA equals LO.
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`: a Testbed, inline
        ``"k=40"``, a TOML file); None keeps the Design's, or Table 1 for an environment.

    Returns
    -------
    TransferFunctions
        ``.to_mapping()`` gives, per name, ``latex``, ``num``, ``den``
        (descending powers, den[0] == 1), ``poles`` ([[re, im], ...]) and
        ``dc_gain``.
    """
    if isinstance(design, Design):
        if testbed is not None:
            design = dataclasses.replace(design, testbed=resolve_testbed(testbed))
    else:
        tb = resolve_testbed(testbed)
        design = Design(testbed=tb, environment=resolve_environments(design, testbed=tb).single(
            "transfer_functions")[1])
    locked = design.environment.locked

    def entry(key: str, name: str) -> TransferFunctionEntry:
        tf = catalogue_tf(key, design)
        return TransferFunctionEntry(catalogue_latex(key), RationalTF(tf.num, tf.den, name=name))

    return TransferFunctions(
        P=entry("P_locked" if locked else "P", "P"),
        EA=entry("P_n^LO" if locked else "P_n^EA", "P_n^EA"),
        LO=entry("P_n^LO", "P_n^LO"),
        LD=entry("P_n^LD", "P_n^LD"),
    )
