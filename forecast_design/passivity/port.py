"""The force-controlled SEA seen from the environment: a one-port, built from the force loop's own objects.

The port's effort is the torque the actuator exerts on what is attached, its flow the joint
velocity ``v = s q``. The coupled characteristic polynomial of the force loop
(:func:`~forecast_design.loops.continuous.force_loop`: true plant, compensator's linear part,
controller, nothing cancelled) is *affine* in the environment polynomial ``E = J s^2 + d s + k_e``:
the catalogue's SEA polynomials satisfy ``sea(E) = E sea_locked + sea(E = 0)`` (tested), and the
loop's characteristic polynomial ``chi = C_d Delta + C_n N_s D_o`` is linear in them. Hence::

    chi(s; E) = chi_free(s) + E(s) chi_locked(s)

with ``chi_locked`` the loop with the output locked and ``chi_free`` the loop with nothing at the
spring's end (massless free output). Dividing by ``s chi_locked``::

    chi = s chi_locked (Z(s) + E(s)/s),     Z(s) = chi_free(s) / (s chi_locked(s))

so the coupled system is ``Z + Z_e = 0`` with the environment's impedance ``Z_e = E/s = J s + d +
k_e/s``: ``Z`` is the actuator's driving-point impedance [N m s/rad] and ``Y = 1/Z`` its admittance.
With the port at the link's end (the default) the link ``J_l s + d_l`` belongs to the actuator:
``Z_link = Z + J_l s + d_l`` and the environment is ``J_e s + d_e + k_e/s``.

Nothing is re-derived here: the plant polynomials come from the symbolic catalogue, the observer
filters from the compensator strategy (designed for the *believed* environment), the closing from
:func:`~forecast_design.loops.closing.close_loop`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import polynomials as poly
from ..compensators import compensator_strategy
from ..controllers import Controller, controller_tf
from ..errors import ParameterError
from ..loops import close_loop, observed_plant
from ..lti import RationalTF
from ..params import Compensator, Design
from ..symbolic.numeric import catalogue_polynomials, parameter_values

__all__ = ["PORTS", "PortImpedance", "port_impedance", "tustin_equivalent"]

#: Where the environment attaches: at the link's end (the link is the actuator's) or at the spring's end.
PORTS = ("link", "spring")


@dataclass(frozen=True, eq=False)
class PortImpedance:
    """The actuator's one-port: ``Z = free / (s locked)`` and the coupled polynomial (module docstring).

    Attributes
    ----------
    free : ndarray
        Characteristic polynomial with nothing attached at the port (descending powers of s):
        the bare link for ``port='link'``, a massless free output for ``port='spring'``.
    locked : ndarray
        Characteristic polynomial with the port locked (v = 0): the locked-output force loop.
    port : str
        One of :data:`PORTS`.
    """

    free: np.ndarray
    locked: np.ndarray
    port: str

    @property
    def s_locked(self) -> np.ndarray:
        """``s chi_locked``: the impedance's denominator."""
        return np.concatenate([self.locked, [0.0]])

    @property
    def Z(self) -> RationalTF:
        """Driving-point impedance: torque on the environment per joint velocity [N m s/rad]."""
        return RationalTF(self.free, self.s_locked, name="Z")

    @property
    def Y(self) -> RationalTF:
        """Driving-point admittance ``1/Z`` [rad/(N m s)]."""
        return RationalTF(self.s_locked, self.free, name="Y")

    def coupled(self, J: float, d: float, k_e: float) -> np.ndarray:
        """Characteristic polynomial with the environment ``J s^2 + d s + k_e`` attached at the port.

        Parameters
        ----------
        J : float
            Attached inertia [kg m^2] (``J_e`` at the link's end; ``J_e + J_l`` at the spring's).
        d : float
            Attached damping [N m s/rad].
        k_e : float
            Attached stiffness [N m/rad].

        Returns
        -------
        ndarray
            ``free + (J s^2 + d s + k_e) locked`` (descending powers of s).
        """
        return poly.trim(poly.add(self.free, poly.mul(np.array([J, d, k_e], float), self.locked)))


def tustin_equivalent(num: tuple[float, ...], den: tuple[float, ...], rate_hz: float) -> RationalTF:
    """The continuous ``C(s) = C(z)`` at ``z = (1 + s T/2)/(1 - s T/2)`` (inverse Tustin) [-].

    Parameters
    ----------
    num, den : tuple of float
        ``C(z)``, descending powers of z.
    rate_hz : float
        The rate the law runs at [Hz] (T = 1/rate_hz).

    Returns
    -------
    RationalTF
        ``C(s)`` (same frequency response at w as C(z) at the Tustin-warped frequency).
    """
    h = 0.5 / float(rate_hz)
    n = max(len(num), len(den)) - 1
    plus, minus = np.array([h, 1.0]), np.array([-h, 1.0])

    def mapped(p: tuple[float, ...]) -> np.ndarray:
        deg = len(p) - 1
        out = np.zeros(n + 1)
        for i, c in enumerate(p):
            k = deg - i
            out = poly.add(out, c * poly.mul(poly.power(plus, k), poly.power(minus, n - k)))
        return out

    return RationalTF(mapped(num), mapped(den), name="C")


def _free_values(design: Design) -> dict[str, float]:
    values = parameter_values(design)
    values.update(J=0.0, d=0.0, k_e=0.0)
    return values


def port_impedance(design: Design, compensator: Compensator | None, controller: Controller, *,
                   believed: Design | None = None, C: RationalTF | None = None,
                   port: str = "link") -> PortImpedance:
    """The actuator's port seen by the environment (module docstring).

    Parameters
    ----------
    design : Design
        Testbed [J_m kg m^2, d_m N m s/rad, k N m/rad] and the link (``J_l`` [kg m^2], ``d_l``
        [N m s/rad] of its environment); the environment's own values do not enter Z.
    compensator : Compensator or None
        The compensator; its linear part (observer filters at their cutoff, an SFM's viscous
        feed-forward) closes around the plant.
    controller : Controller
        The force controller (resolved).
    believed : Design or None
        What the compensator believes (the EA-FOB's environment E0); None: ``design``.
    C : RationalTF or None
        The controller's continuous law; None: ``controller``'s ``C(s)``.
    port : str
        ``'link'`` (default) or ``'spring'`` (:data:`PORTS`).

    Returns
    -------
    PortImpedance
        The free and locked characteristic polynomials.
    """
    if port not in PORTS:
        raise ParameterError(f"port must be one of {', '.join(PORTS)}, got {port!r}", name="port", value=port)
    C = controller_tf(controller) if C is None else C
    filters = compensator_strategy(compensator).linear_filters(compensator or Compensator(),
                                                                believed if believed is not None else design)

    def chi(triple: tuple[np.ndarray, ...]) -> np.ndarray:
        plant = observed_plant(*(poly.trim(p) for p in triple), filters, strip_position_mode=False)
        return close_loop(plant, C, "controller")[1]

    locked = poly.trim(chi(catalogue_polynomials("sea_locked", design)))
    free = poly.trim(chi(catalogue_polynomials("sea", _free_values(design))))
    if port == "link":
        env = design.environment
        free = poly.trim(poly.add(free, poly.mul(np.array([env.J_l, env.d_l, 0.0]), locked)))
    return PortImpedance(free=free, locked=locked, port=port)
