"""The force loop's frequency response in cutoff-free parts, for the Q tuner (numpy and casadi).

With the observer's Q = 1 / D_q(s / w_q), the loop's sensitivity at one frequency depends on
the cutoff only through ``D_q(j W / w_q)``::

    S_controller = (D_q + M) / (D_q + M + CP D_q)
    S_plant      = (D_q - dm) / (D_q + M + CP D_q)

with ``CP = C_F P`` (times the command delay when sampled), ``M = A P + B P_theta - dm``
(``G_s = -Q A``, ``G_theta = -Q B``: the observer's filters of
:func:`forecast_design.symbolic.observer_filters`) and ``dm`` the observer's one-sample delay
on the previous command (1 when continuous). The parts are the same plant, controller and
observer objects the polynomial loops (:mod:`.continuous`, :mod:`.sampled`) are built from;
``tests/test_loops_response.py`` checks that the sensitivity they give equals ``1 / (1 + L)``
of those loops.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..controllers import Controller, controller_law, controller_tf
from ..params import Compensator, Design
from .sampled import COMMAND_DELAY_SAMPLES

__all__ = ["LoopResponse", "loop_response", "observer_responses", "sensitivity", "sensitivity_terms", "q_argument"]


@dataclass(frozen=True, slots=True)
class LoopResponse:
    """Cutoff-free parts of one loop's frequency response.

    Parameters
    ----------
    w : ndarray
        Frequencies [rad/s].
    W : ndarray
        Argument of Q there [rad/s]: ``w``, or the Tustin-warped ``(2/T) tan(w T / 2)`` when sampled.
    CP : ndarray
        ``C_F P`` (times the command delay when sampled) [-].
    M : ndarray
        ``A P + B P_theta - dm`` [-].
    dm : ndarray
        The observer's delay on the previous command (1 when continuous) [-].
    """

    w: np.ndarray
    W: np.ndarray
    CP: np.ndarray
    M: np.ndarray
    dm: np.ndarray


def q_argument(w: np.ndarray, *, sampled: bool = False, rate_hz: float = 2000.0) -> np.ndarray:
    """Where Q is evaluated at frequency ``w`` [rad/s]: ``w``, or Tustin-warped ``(2/T) tan(w T / 2)`` when sampled."""
    w = np.asarray(w, dtype=float)
    if not sampled:
        return w
    T = 1.0 / rate_hz
    return 2.0 / T * np.tan(0.5 * w * T)


def observer_responses(compensator: Compensator, believed: Design, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A(s), B(s)`` with ``G_s = -Q A`` and ``G_theta = -Q B`` (independent of the cutoff).

    Parameters
    ----------
    compensator : Compensator
        An observer kind.
    believed : Design
        The design the observer believes.
    s : ndarray
        Points of the (continuous or w-) plane [rad/s].

    Returns
    -------
    (ndarray, ndarray)
        ``A`` and ``B`` at ``s``.
    """
    from ..symbolic import observer_filters

    filters = observer_filters(compensator, believed)
    g_m = np.polyval(filters.from_tau_m.num, s)
    return -np.polyval(filters.from_tau_s.num, s) / g_m, -np.polyval(filters.from_theta.num, s) / g_m


def loop_response(true_design: Design, believed: Design, compensator: Compensator, controller: Controller,
                  w: np.ndarray, *, sampled: bool = False, rate_hz: float = 2000.0,
                  delay_samples: int = COMMAND_DELAY_SAMPLES,
                  observer: tuple[np.ndarray, np.ndarray] | None = None) -> LoopResponse:
    """The cutoff-free parts of the force loop's response on a frequency grid.

    Parameters
    ----------
    true_design : Design
        The true testbed and environment.
    believed : Design
        What the observer believes.
    compensator : Compensator
        The observer (its cutoff is not used).
    controller : Controller
        Force controller (continuous: its C(s); sampled: its difference equation at ``rate_hz``,
        the same C(w) as :func:`~.sampled.sampled_force_loop`).
    w : ndarray
        Frequencies [rad/s] (below Nyquist when sampled).
    sampled : bool
        The sampled-data loop of :func:`~.sampled.sampled_force_loop` instead of the continuous one.
    rate_hz : float
        Sampling rate [Hz].
    delay_samples : int
        Command delay [samples] (sampled).
    observer : (ndarray, ndarray), optional
        Precomputed :func:`observer_responses` at the same points (a cache).

    Returns
    -------
    LoopResponse
        ``W``, ``CP``, ``M``, ``dm`` on ``w``.
    """
    w = np.asarray(w, dtype=float)
    if sampled:
        from .sampled import law_in_w, zoh_plant

        T = 1.0 / rate_hz
        W = q_argument(w, sampled=True, rate_hz=rate_hz)
        s = 1j * W
        zp = zoh_plant(true_design, rate_hz)
        P = np.polyval(zp.Ns_w, s) / np.polyval(zp.D_w, s)
        P_theta = np.polyval(zp.Nt_w, s) / np.polyval(zp.D_w, s)
        C = law_in_w(controller_law(controller, rate_hz))(s)
        dm = np.exp(-1j * w * T)
        dp = dm ** delay_samples
    else:
        from ..symbolic import force_plant_tf, motor_angle_tf

        W = w
        s = 1j * w
        P = force_plant_tf(true_design)(s)
        P_theta = motor_angle_tf(true_design)(s)
        C = controller_tf(controller)(s)
        dm = np.ones_like(s)
        dp = dm
    A, B = observer if observer is not None else observer_responses(compensator, believed, s)
    with np.errstate(invalid="ignore"):
        # B = 0 (no theta path) times a free output's rigid-body pole is 0, not nan
        theta_term = np.where(B == 0.0, 0.0, B * P_theta)
    M = (A * P + theta_term) * dp - dm
    return LoopResponse(w=w, W=W, CP=C * P * dp, M=M, dm=dm)


def sensitivity_terms(M: Any, CP: Any, dm: Any, dq: Any, break_at: str = "controller") -> tuple[Any, Any]:
    """Numerator and denominator of the sensitivity ``S = num / den`` at one or many frequencies.

    Written with ``+``, ``-`` and ``*`` only, so it serves numpy complex arrays and the Q
    tuner's complex pairs of casadi expressions alike.

    Parameters
    ----------
    M, CP, dm : complex or ndarray
        Parts of :class:`LoopResponse`.
    dq : complex, ndarray or a complex-like object
        The Q denominator at ``j W / w_q``.
    break_at : str
        ``controller`` or ``plant-input``.

    Returns
    -------
    (num, den)
        ``S = num / den``.
    """
    den = dq + M + CP * dq
    num = dq + M if break_at == "controller" else dq - dm
    return num, den


def sensitivity(response: LoopResponse, dq: np.ndarray, break_at: str = "controller") -> np.ndarray:
    """The loop's sensitivity ``1 / (1 + L)`` from its parts and ``D_q(j W / w_q)``.

    Parameters
    ----------
    response : LoopResponse
        Cutoff-free parts.
    dq : ndarray
        The Q denominator at ``j W / w_q`` (broadcast against the grid).
    break_at : str
        ``controller`` or ``plant-input``.

    Returns
    -------
    ndarray
        ``S`` at each frequency.
    """
    num, den = sensitivity_terms(response.M, response.CP, response.dm, dq, break_at)
    return num / den
