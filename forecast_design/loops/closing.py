"""Where the force controller closes the loop: one construction for the continuous and the sampled loop.

Both loops first close the compensator's linear part around the plant (in ``s``, or in the
Tustin variable ``w`` for the sampled loop), which gives an :class:`ObservedPlant`: the force
plant seen by the controller, ``F_DOB = tau_s / u`` (eq. (4) for the observers), and the parts
of the loop broken at the plant input. The controller ``C = C_n / C_d`` then closes it in one
place, :func:`close_loop`, with the transfer-function algebra of
:class:`~forecast_design.lti.RationalTF` (nothing cancelled)::

    controller break:   L = C F_DOB                           (the paper's, Fig. 5)
    plant-input break:  L = (C_n F_n - C_d O) / (C_d R)
    characteristic polynomial (both):  chi = C_d Delta + C_n F_n = (L feedback 1).den

with ``F_DOB = F_n / Delta``, ``O`` the compensator's own paths through the plant
(``G_s P + G_theta P_theta`` over the common denominator) and ``R`` the plant's denominator
times the compensator's ``1 - G_m`` (delays included when sampled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import polynomials as poly
from ..errors import ParameterError
from ..lti import RationalTF
from ..params import BREAK_POINTS

__all__ = ["ObservedPlant", "close_loop", "BREAK_POINTS"]


@dataclass(frozen=True, slots=True)
class ObservedPlant:
    """The plant with the compensator's linear part closed around it (module docstring).

    Parameters
    ----------
    f_num, delta : ndarray
        ``F_DOB = f_num / delta`` (tau_s / u), descending powers of s or w.
    obs_num : ndarray
        ``O``: the compensator's paths through the plant, over the plant-input denominator.
    pi_den : ndarray
        ``R``: the plant-input break's denominator without the controller.
    """

    f_num: np.ndarray
    delta: np.ndarray
    obs_num: np.ndarray
    pi_den: np.ndarray

    @property
    def F_DOB(self) -> RationalTF:
        """``tau_s / u`` with the compensator closed [N m/N m] (continuous object: in s or w)."""
        return RationalTF(poly.trim(self.f_num), poly.trim(self.delta), name="F_DOB")


def close_loop(plant: ObservedPlant, C: RationalTF, break_at: str) -> tuple[RationalTF, np.ndarray]:
    """Close the force loop with the controller ``C`` (module docstring).

    Parameters
    ----------
    plant : ObservedPlant
        Plant and compensator, closed.
    C : RationalTF
        The controller's feedback path ``C(s)`` (or ``C(w)``), ``u = C_r tau_r - C tau_s``.
    break_at : str
        One of :data:`BREAK_POINTS`.

    Returns
    -------
    (RationalTF, ndarray)
        ``L`` at the break point (negative feedback, 1 + L = 0) and the closed-loop
        characteristic polynomial (descending), nothing cancelled.
    """
    if break_at not in BREAK_POINTS:
        raise ParameterError(f"break_at must be one of {', '.join(BREAK_POINTS)}, got {break_at!r}",
                             name="break_at", value=break_at)
    L = (C * plant.F_DOB).named("L")
    chi = poly.trim(np.asarray(L.feedback().den, dtype=float))
    if break_at == "plant-input":
        cn, cd = np.asarray(C.num, float), np.asarray(C.den, float)
        num = poly.trim(poly.sub(poly.mul(cn, plant.f_num), poly.mul(cd, plant.obs_num)))
        L = RationalTF(num, poly.trim(poly.mul(cd, plant.pi_den)), name="L")
    return L, chi
