"""Friction observers as linear filters: Q filters and the observer transfer functions.

Every observer of the toolbox is one linear map from the measured signals
to the friction estimate::

    tau_frc_hat = G_m(s) tau_m + G_s(s) tau_s + G_theta(s) theta

and the estimate is fed forward: tau_m = u + tau_frc_hat.

==============  ============  =================  ==================
kind            G_m           G_s                G_theta
==============  ============  =================  ==================
ea-fob          Q             -Q / P_n^EA         0
lo-dob          Q             -Q / P_n^LO         0
ld-dob          Q             -Q / P_n^LD         0
motor-fob       Q             -Q                 -Q J_m s^2
==============  ============  =================  ==================

Sign convention (derived, not copied from the paper)
----------------------------------------------------
Write the friction as an input disturbance of the nominal plant,
tau_s = P_n (tau_m - tau_frc). Then tau_m - P_n^{-1} tau_s = tau_frc, so

    tau_frc_hat = Q (tau_m - P_n^{-1} tau_s)  ->  Q tau_frc,

and tau_m = u + tau_frc_hat cancels the friction below the cutoff of Q.
With the true plant, tau_m (1 - Q + Q P_n^{-1} P) = u, i.e.
tau_s/u = P / (1 + Q (P_n^{-1} P - 1)): exactly the paper's eq. (4).

The paper prints tau_hat = tau_s P_n^{-1} Q - tau_m Q, the *negative* of
this estimate. Fed forward as tau_m = u + tau_hat it would double the
friction instead of cancelling it (and give tau_s/u = P/(1 - Q(P_n^{-1}P - 1)),
not eq. (4)); it is consistent only with tau_m = u - tau_hat. We keep
eq. (4) and the "+" feed-forward.

Motor-side FOB: J_m s^2 theta = tau_m - tau_s - tau_frc gives
tau_frc = tau_m - tau_s - J_m s^2 theta from the motor encoder alone, with
no environment model. When E(s) is exact, P_n^EA^{-1} tau_s = tau_s +
J_m s^2 theta, so EA-FOB and motor-side FOB are the same map on the true
plant (tested).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from typing import TYPE_CHECKING

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF
from ..params import Q_FAMILIES, Compensator, Design
from ._catalogue import MODELS
from .numeric import catalogue_relative_degree, catalogue_tf, nominal_plant_tf

if TYPE_CHECKING:  # sympy is imported only where a symbolic expression is asked for
    import sympy as sp

__all__ = [
    "q_filter",
    "q_filter_tf",
    "compensator_q_tf",
    "ObserverFilters",
    "observer_filters",
    "required_q_order",
]

#: Relative degree of the motor-side FOB's G_theta / Q (from J_m s^2).
_MOTOR_FOB_RELATIVE_DEGREE = 2


def _butterworth_polynomial(order: int) -> "sp.Expr":
    """Normalised Butterworth polynomial B_n(x) (cutoff 1 rad/s), exact coefficients."""
    import sympy as sp

    x = sp.Symbol("x")
    poly = sp.Integer(1)
    for i in range(1, order // 2 + 1):
        # Conjugate pole pair exp(+-j pi (2i + n - 1) / (2n)).
        poly *= x**2 - 2 * sp.cos(sp.pi * (2 * i + order - 1) / (2 * order)) * x + 1
    if order % 2:
        poly *= x + 1
    return sp.expand(poly), x


@lru_cache(maxsize=None)
def q_filter(family: str = "butterworth", order: int = 2) -> "sp.Expr":
    """Low-pass Q(s) with unity DC gain, symbolic in ``s`` and ``w_q``.

    Parameters
    ----------
    family : str
        ``'butterworth'``: w_q^n / (w_q^n B_n(s / w_q)) with B_n the
        normalised Butterworth polynomial (|Q(j w_q)| = 1/sqrt(2));
        ``'binomial'``: w_q^n / (s + w_q)^n (n real poles at -w_q).
    order : int
        Filter order n >= 1 [-].

    Returns
    -------
    sympy.Expr
        Q(s) in the symbols ``s`` and ``w_q`` [rad/s].

    Raises
    ------
    ParameterError
        For an unknown family or an order < 1.
    """
    if family not in Q_FAMILIES:
        raise ParameterError(
            f"Q-filter family must be one of {', '.join(Q_FAMILIES)}, got {family!r}",
            name="q_family", value=family,
        )
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise ParameterError(f"Q-filter order must be an integer >= 1, got {order!r}",
                             name="q_order", value=order)
    import sympy as sp

    from . import plant as _plant

    s, w_q = _plant.s, _plant.w_q
    if family == "binomial":
        return w_q**order / (s + w_q) ** order
    poly, x = _butterworth_polynomial(order)
    den = sp.expand(w_q**order * poly.subs(x, s / w_q))
    return w_q**order / den


@lru_cache(maxsize=None)
def _q_parametric(family: str, order: int):
    from .bridge import ParametricTF

    return ParametricTF(q_filter(family, order), name="Q")


def q_filter_tf(family: str, order: int, w_q_hz: float) -> RationalTF:
    """Numeric Q(s).

    Parameters
    ----------
    family : str
        ``'butterworth'`` or ``'binomial'``.
    order : int
        Filter order [-].
    w_q_hz : float
        Cutoff [Hz]; w_q = 2 pi w_q_hz [rad/s].

    Returns
    -------
    RationalTF
        Q(s), unity DC gain.
    """
    values = {"w_q": 2.0 * math.pi * float(w_q_hz)}
    key = f"Q_{family}_{order}"
    if key in MODELS:
        return catalogue_tf(key, values)
    q_filter(family, order)          # validates family and order with a one-line error
    return _q_parametric(family, order).at(values)   # beyond the catalogue: derive once with sympy


def compensator_q_tf(compensator: Compensator) -> RationalTF:
    """Numeric Q(s) of a compensator: its family and order, or a 2nd-order Q of given damping.

    Parameters
    ----------
    compensator : Compensator
        ``w_q_hz`` [Hz], ``q_family``, ``q_order`` and optional ``q_damping`` [-]: with it,
        Q = w_q^2 / (s^2 + 2 q_damping w_q s + w_q^2) (Butterworth is q_damping = 1/sqrt(2),
        binomial q_damping = 1).

    Returns
    -------
    RationalTF
        Q(s), unity DC gain.
    """
    if compensator.q_damping is None:
        return q_filter_tf(compensator.q_family, compensator.q_order, compensator.w_q_hz)
    w_q = 2.0 * math.pi * compensator.w_q_hz
    return RationalTF((w_q**2,), (1.0, 2.0 * compensator.q_damping * w_q, w_q**2), name="Q")


@lru_cache(maxsize=None)
def required_q_order(kind: str) -> int:
    """Smallest Q order making the observer proper (relative degree of P_n).

    Parameters
    ----------
    kind : str
        ``'ea-fob'``, ``'lo-dob'``, ``'ld-dob'`` or ``'motor-fob'``.

    Returns
    -------
    int
        The relative degree of the nominal plant (2 for all four) [-].
    """
    if kind == "motor-fob":
        return _MOTOR_FOB_RELATIVE_DEGREE
    if kind not in ("ea-fob", "lo-dob", "ld-dob"):
        raise ParameterError(f"observer kind must be ea-fob, lo-dob, ld-dob or motor-fob, got {kind!r}",
                             name="kind", value=kind)
    return catalogue_relative_degree({"ea-fob": "P_n^EA", "lo-dob": "P_n^LO", "ld-dob": "P_n^LD"}[kind])


@dataclass(frozen=True, slots=True)
class ObserverFilters:
    """The three filters of an observer, tau_frc_hat = G_m tau_m + G_s tau_s + G_theta theta.

    All three share one denominator (``from_tau_m.den == from_tau_s.den ==
    from_theta.den``): the characteristic polynomial of the observer realised
    as one system with three inputs. Nothing is cancelled.
    """

    kind: str                 # compensator kind
    w_q_hz: float             # Q cutoff [Hz] (nan without observer)
    from_tau_m: RationalTF    # G_m: motor torque -> estimate [N m/N m]
    from_tau_s: RationalTF    # G_s: spring torque -> estimate [N m/N m]
    from_theta: RationalTF    # G_theta: motor angle -> estimate [N m/rad]

    @property
    def den(self) -> tuple[float, ...]:
        """The shared denominator (descending powers of s)."""
        return self.from_tau_m.den

    @property
    def is_zero(self) -> bool:
        """True when the observer outputs nothing (kinds 'none', 'sfm')."""
        return all(tf.num == (0.0,) for tf in (self.from_tau_m, self.from_tau_s, self.from_theta))

    def estimate(self, tau_m: complex | np.ndarray, tau_s: complex | np.ndarray,
                 theta: complex | np.ndarray, s: complex | np.ndarray) -> complex | np.ndarray:
        """Friction estimate in the frequency domain at complex ``s``.

        Parameters
        ----------
        tau_m, tau_s : complex or ndarray
            Phasors of motor and spring torque [N m].
        theta : complex or ndarray
            Phasor of the motor angle [rad].
        s : complex or ndarray
            Laplace variable [rad/s].

        Returns
        -------
        complex or ndarray
            tau_frc_hat [N m].
        """
        return self.from_tau_m(s) * tau_m + self.from_tau_s(s) * tau_s + self.from_theta(s) * theta


def _zero_filters(kind: str) -> ObserverFilters:
    return ObserverFilters(kind, math.nan, *(RationalTF((0.0,), (1.0,), name=name)
                                             for name in ("G_m", "G_s", "G_theta")))


def observer_filters(compensator: Compensator | None, believed: Design) -> ObserverFilters:
    """Numeric observer filters of a compensator.

    Parameters
    ----------
    compensator : Compensator or None
        Kind, cutoff ``w_q_hz`` [Hz] (w_q = 2 pi w_q_hz [rad/s]), Q family
        and order. ``None``, ``'none'`` and ``'sfm'`` (static feed-forward,
        no linear dynamics) give all-zero filters.
    believed : Design
        The design the observer believes in: J_m [kg m^2] and k [N m/rad]
        of its testbed and, for EA-FOB / LD-DOB, its environment. It may
        differ from the true design (environment-knowledge error). For a
        locked believed environment the EA-FOB nominal plant is P_n^LO.

    Returns
    -------
    ObserverFilters
        G_m, G_s, G_theta over one shared (monic) denominator.

    Raises
    ------
    ParameterError
        If the Q order is below the nominal plant's relative degree (the
        observer would be improper) or the nominal plant is identically
        zero (LD-DOB with J_l = d_l = 0), or an argument is of the wrong type.
    """
    if compensator is not None and not isinstance(compensator, Compensator):
        raise ParameterError(f"compensator must be a Compensator or None (Compensator(kind='ea-fob')), got "
                             f"{type(compensator).__name__} {compensator!r:.40}", name="compensator", value=compensator)
    if not isinstance(believed, Design):
        raise ParameterError(f"the believed design must be a Design, got {type(believed).__name__}", name="believed",
                             value=believed)
    if compensator is None or not compensator.is_observer:
        return _zero_filters("none" if compensator is None else compensator.kind)
    kind = compensator.kind
    needed = required_q_order(kind)
    if compensator.q_order < needed:
        raise ParameterError(
            f"[compensator] q_order = {compensator.q_order} is below the relative degree {needed} of the "
            f"{kind} nominal plant: Q P_n^-1 would be improper",
            name="q_order", value=compensator.q_order,
        )
    q = compensator_q_tf(compensator)
    qn, qd = np.asarray(q.num), np.asarray(q.den)
    if kind == "motor-fob":
        J_m = believed.testbed.J_m
        g_m, g_s = qn, -qn
        g_theta = -J_m * np.concatenate([qn, [0.0, 0.0]])
        den = qd
    else:
        pn = nominal_plant_tf(kind, believed)   # locked EA -> P_n^LO, decided there
        if pn.num == (0.0,):
            raise ParameterError(
                f"{kind} nominal plant is identically zero for the believed design "
                f"(J_l = {believed.environment.J_l:g}, d_l = {believed.environment.d_l:g}); "
                "it cannot be inverted",
                name="J_l", value=believed.environment.J_l,
            )
        pnn, pnd = np.asarray(pn.num), np.asarray(pn.den)
        if len(qn) + len(pnd) > len(qd) + len(pnn):
            raise ParameterError(
                f"[compensator] q_order = {compensator.q_order}: Q P_n^-1 is improper for the believed "
                f"{kind} nominal plant (relative degree {pn.relative_degree})",
                name="q_order", value=compensator.q_order,
            )
        g_m = np.convolve(qn, pnn)
        g_s = -np.convolve(qn, pnd)
        g_theta = np.zeros(1)
        den = np.convolve(qd, pnn)
    lead = den[0]
    return ObserverFilters(
        kind,
        compensator.w_q_hz,
        RationalTF(g_m / lead, den / lead, name="G_m"),
        RationalTF(g_s / lead, den / lead, name="G_s"),
        RationalTF(g_theta / lead, den / lead, name="G_theta"),
    )
