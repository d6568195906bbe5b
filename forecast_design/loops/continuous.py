"""The continuous force loop: true plant, compensator's linear part and any force controller.

The loop is built without any pole-zero cancellation, so a mode hidden by a cancellation
(e.g. an unstable observer mode cancelled in L(s)) stays in the characteristic polynomial.

Signals (Laplace domain, true plant P = N_s/D, P_theta = N_theta/D over one
denominator; compensator filters G = A/D_o over one denominator)::

    tau_m = u + G_m tau_m + G_s tau_s + G_theta theta      (compensator feed-forward)
    tau_s = P tau_m,   theta = P_theta tau_m               (true plant)
    u     = C_r tau_r - C tau_s                            (force controller, any kind)

which gives F_DOB = tau_s/u = N_s D_o / Delta with
Delta = D_o D - A_m D - A_s N_s - A_theta N_theta; the controller closes the loop in
:func:`~forecast_design.loops.closing.close_loop` (L = C F_DOB, chi = C_d Delta + C_n N_s D_o).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .. import polynomials as poly
from ..lti import RationalTF
from ..margins import STABILITY_TOLERANCE
from ..compensators import compensator_strategy
from ..controllers import PAPER_PD, Controller, controller_tf, resolve_controller
from ..params import Compensator, Design
from ..symbolic.numeric import catalogue_polynomials, strip_common_s
from ..symbolic.observers import ObserverFilters
from .closing import BREAK_POINTS, ObservedPlant, close_loop

__all__ = ["ForceLoop", "force_loop", "observed_plant", "BREAK_POINTS", "STABILITY_TOLERANCE"]



def _plant_polynomials(design: Design) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N_s, N_theta, D) of the true plant (plant.sea_polynomials), descending powers of s."""
    polys = catalogue_polynomials("sea_locked" if design.environment.locked else "sea", design)
    return tuple(poly.trim(p) for p in polys)


def _add(*polys: np.ndarray) -> np.ndarray:
    return poly.trim(poly.add(*polys))


def _mul(*polys: np.ndarray) -> np.ndarray:
    return poly.trim(poly.mul(*polys))


def observed_plant(N_s: np.ndarray, N_theta: np.ndarray, D: np.ndarray, filters: ObserverFilters, *,
                   strip_position_mode: bool = True) -> ObservedPlant:
    """Close the compensator's linear part around a plant given by its polynomials (module docstring).

    Parameters
    ----------
    N_s, N_theta, D : ndarray
        ``tau_s/tau_m = N_s/D`` [N m/N m] and ``theta/tau_m = N_theta/D`` [rad/(N m)], descending
        powers of s (the catalogue's ``sea``/``sea_locked`` polynomials).
    filters : ObserverFilters
        The compensator's linear filters.
    strip_position_mode : bool
        Divide out an exact common factor s^m of N_s, D (and N_theta when the compensator reads
        theta): the rigid-body position mode of a free output (k_e = 0), which tau_s does not see.
        ``False`` keeps every factor, so that the result is linear in (N_s, N_theta, D)
        (:mod:`forecast_design.passivity` relies on it).

    Returns
    -------
    ObservedPlant
        ``F_DOB``, the compensator's paths and the plant-input denominator.
    """
    D_o = np.asarray(filters.den, dtype=float)
    A_m = np.asarray(filters.from_tau_m.num, dtype=float)
    A_s = np.asarray(filters.from_tau_s.num, dtype=float)
    A_t = np.asarray(filters.from_theta.num, dtype=float)
    N_s, N_theta, D = (np.asarray(p, dtype=float) for p in (N_s, N_theta, D))

    # G_theta acts on s^r theta (r = 2 for the motor FOB: acceleration; 1 for a viscous
    # feed-forward); moving s^r into the plant lets the rigid-body position mode cancel exactly
    # when k_e = 0.
    uses_theta = bool(np.any(A_t != 0.0))
    if uses_theta:
        r = poly.trailing_zeros(A_t)
        A_t = poly.drop_trailing(A_t, r)
        N_theta = np.concatenate([N_theta, np.zeros(r)])
    if strip_position_mode:
        m = min(poly.trailing_zeros(N_s), poly.trailing_zeros(D),
                poly.trailing_zeros(N_theta) if uses_theta else 10**9)
        if 0 < m < 10**9:
            N_s, D, N_theta = poly.drop_trailing(N_s, m), poly.drop_trailing(D, m), poly.drop_trailing(N_theta, m)

    obs = _add(_mul(A_s, N_s), _mul(A_t, N_theta))
    delta = _add(_mul(D_o, D), -_mul(A_m, D), -obs)
    return ObservedPlant(_mul(N_s, D_o), delta, obs, _mul(_add(D_o, -A_m), D))


@dataclass(frozen=True, eq=False)
class ForceLoop:
    """The closed force loop of one design, compensator and force controller.

    Attributes
    ----------
    L : RationalTF
        Loop transfer function at the break point (negative-feedback
        convention, closed loop 1 + L = 0) [-].
    characteristic_polynomial : ndarray, shape (n + 1,)
        Closed-loop characteristic polynomial, descending powers of s,
        nothing cancelled.
    closed_loop_poles : ndarray of complex, shape (n,)
        Its roots [rad/s].
    stable : bool
        All roots satisfy Re(p) < -STABILITY_TOLERANCE * max(1, |p|).
    P : RationalTF
        True force plant tau_s/tau_m [N m/N m].
    F_DOB : RationalTF
        tau_s/u with the observer (eq. (4) for the DOB kinds; P without observer) [N m/N m].
    filters : ObserverFilters
        The compensator's linear filters used.
    break_at : str
        ``'controller'`` or ``'plant-input'``.
    C : RationalTF
        The controller's feedback path C(s) [N m/N m].
    controller : Controller
        The controller analysed.
    """

    L: RationalTF
    characteristic_polynomial: np.ndarray
    closed_loop_poles: np.ndarray
    stable: bool
    P: RationalTF
    F_DOB: RationalTF
    filters: ObserverFilters
    break_at: str
    C: RationalTF
    controller: Controller

    @property
    def max_real_pole(self) -> float:
        """Largest real part of the closed-loop poles [rad/s]."""
        return float(np.max(self.closed_loop_poles.real)) if self.closed_loop_poles.size else -np.inf


def force_loop(
    true_design: Design,
    compensator: Compensator | None = None,
    *,
    controller: object = PAPER_PD,
    believed: Design | None = None,
    break_at: str = "controller",
) -> ForceLoop:
    """Assemble the force loop: true plant, compensator (believing ``believed``) and controller.

    Parameters
    ----------
    true_design : Design
        The real testbed [J_m kg m^2, d_m N m s/rad, k N m/rad] and
        environment (locked allowed). Its ``controller`` and ``compensator``
        fields are *not* consulted; pass them explicitly.
    compensator : Compensator or None
        Compensator; its linear part (:mod:`forecast_design.compensators`) enters the loop:
        an observer's filters, an SFM's viscous feed-forward. ``None``/``'none'``: the plant alone.
    controller : Controller, str or python-control system
        The force controller (anything :func:`~forecast_design.controllers.resolve_controller`
        takes); its continuous law C(s) closes the loop. Default the paper's PD 5/0.1.
    believed : Design or None
        What the compensator believes (environment-knowledge error);
        ``None`` means ``true_design``.
    break_at : str
        ``'controller'``: L = C F_DOB, at the force-controller output
        (as in the paper); ``'plant-input'``: at the motor-torque input,
        L = (C P - G_s P - G_theta P_theta) / (1 - G_m).

    Returns
    -------
    ForceLoop
        L, the characteristic polynomial, closed-loop poles, stability flag
        and the pieces.

    Raises
    ------
    ParameterError
        For an unknown ``break_at``, an improper observer (see
        :func:`~forecast_design.symbolic.observers.observer_filters`), or a controller with no
        continuous law (``discrete``: use the sampled loop; ``other``: no equations).

    Notes
    -----
    The closed loop is proper when C is (an unfiltered PD is not, but P has relative degree 2).
    A free output (k_e = 0 exactly) adds a rigid-body position mode at
    s = 0 that neither tau_s nor the motor acceleration sees; that exact
    common factor s is divided out (as in ``force_plant_tf``). Any other
    common factor, stable or not, is kept.
    """
    if break_at not in BREAK_POINTS:
        raise ParameterError(
            f"break_at must be one of {', '.join(BREAK_POINTS)}, got {break_at!r}",
            name="break_at", value=break_at,
        )
    controller = resolve_controller(controller)
    C = controller_tf(controller)
    if not isinstance(true_design, Design):
        raise ParameterError(f"true_design must be a Design (Design.nominal('soft')), got {type(true_design).__name__}",
                             name="true_design", value=true_design)
    filters = compensator_strategy(compensator).linear_filters(
        compensator or Compensator(), believed if believed is not None else true_design)
    N_s, N_theta, D = _plant_polynomials(true_design)
    plant = observed_plant(N_s, N_theta, D, filters)
    L, chi = close_loop(plant, C, break_at)
    poles = np.roots(chi) if len(chi) > 1 else np.zeros(0, dtype=complex)
    stable = bool(np.all(poles.real < -STABILITY_TOLERANCE * np.maximum(1.0, np.abs(poles))))
    chi = chi.copy()
    chi.flags.writeable = False
    poles = np.asarray(poles, dtype=complex)
    poles.flags.writeable = False
    return ForceLoop(
        L=L,
        characteristic_polynomial=chi,
        closed_loop_poles=poles,
        stable=stable,
        P=RationalTF(*strip_common_s(N_s, D), name="P"),
        F_DOB=plant.F_DOB,
        filters=filters,
        break_at=break_at,
        C=C,
        controller=controller,
    )
