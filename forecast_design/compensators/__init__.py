"""Friction compensators as strategies: one interface, a registry by kind, one definition each.

A compensator adds ``tau_frc_hat`` to the controller's output, ``tau_m = u + tau_frc_hat``.
Every kind answers the same questions (pysindy's one-base-class pattern), so the loop
analysis, the tuner, the simulator, the Python program reference, the C export and the
firmware all ask the same object:

* :meth:`CompensatorStrategy.linear_filters`: its linear part as three continuous filters,
  ``tau_frc_hat = G_m tau_m + G_s tau_s + G_theta theta`` (what the continuous loop sees);
* :meth:`CompensatorStrategy.discrete_filters`: the same at the control rate, as it runs
  (``G_m`` fed the previous command);
* :meth:`CompensatorStrategy.feedforward`: its static nonlinear part (the friction model's
  feed-forward), or None;
* :meth:`CompensatorStrategy.analysis_note`: what of it the linear analysis does not see.

==============  ==========================================  ====================================
kind            linear part                                 nonlinear part
==============  ==========================================  ====================================
none            none                                        none
sfm             G_theta = viscous s/(s/w_v + 1)             Coulomb/Stribeck/offset/harmonics
ea-fob          G_m = Q, G_s = -Q/P_n^EA                    none
lo-dob          G_m = Q, G_s = -Q/P_n^LO                    none
ld-dob          G_m = Q, G_s = -Q/P_n^LD                    none
motor-fob       G_m = Q, G_s = -Q, G_theta = -Q J_m s^2     none
==============  ==========================================  ====================================

The compensator's *value* (kind, cutoff, Q filter, identified friction) is
:class:`forecast_design.params.Compensator`; :func:`compensator_strategy` maps it to its kind's
strategy. Adding a kind: a strategy class here and one :func:`register_compensator` line.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF
from ..params import Compensator, Design
from ..symbolic.observers import ObserverFilters, observer_filters
from .sfm_params import FEEDFORWARD_PARAMETERS, viscous_slope

if TYPE_CHECKING:   # the discrete filters and the compiled feed-forward load on first use (numba)
    from ..discrete import DiscreteTF
    from .feedforward import FrictionFeedforward

#: Default velocity filter of the friction feed-forward [Hz].
DEFAULT_VELOCITY_CUTOFF_HZ = 50.0
_LAZY = {"FrictionFeedforward": "feedforward", "feedforward_eval": "feedforward", "friction_feedforward": "feedforward"}


def __getattr__(name: str) -> Any:
    """The compiled feed-forward on first use (PEP 562): the loop analysis needs none of it."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "CompensatorStrategy",
    "DiscreteFilters",
    "COMPENSATOR_STRATEGIES",
    "register_compensator",
    "compensator_strategy",
    "FrictionFeedforward",
    "feedforward_eval",
    "friction_feedforward",
    "DEFAULT_VELOCITY_CUTOFF_HZ",
    "FEEDFORWARD_PARAMETERS",
    "OBSERVER_METHOD",
]

#: Discretisation of the observers' filters on the board and in the simulator.
OBSERVER_METHOD = "tustin"


@dataclass(frozen=True, slots=True)
class DiscreteFilters:
    """A compensator's linear part at the control rate, ``G_m``, ``G_s``, ``G_theta`` as they run.

    Parameters
    ----------
    from_tau_m, from_tau_s, from_theta : DiscreteTF or None
        The filters (None: that path is absent). ``from_tau_m`` is fed the previous applied
        command (a one-sample delay, ``z^-1 G_m``).
    """

    from_tau_m: "DiscreteTF | None"
    from_tau_s: "DiscreteTF | None"
    from_theta: "DiscreteTF | None"

    def paths(self) -> "tuple[tuple[str, DiscreteTF], ...]":
        """The present filters with their source signal (``tau_m_prev``, ``tau_s``, ``theta``)."""
        out = []
        for source, tf in (("tau_m_prev", self.from_tau_m), ("tau_s", self.from_tau_s), ("theta", self.from_theta)):
            if tf is not None:
                out.append((source, tf))
        return tuple(out)

    @property
    def is_zero(self) -> bool:
        """True when there is no linear path."""
        return not self.paths()


class CompensatorStrategy(ABC):
    """The behaviour of one compensator kind (module docstring)."""

    kind: ClassVar[str]

    def linear_filters(self, compensator: Compensator, believed: Design) -> ObserverFilters:
        """The continuous linear part ``G_m, G_s, G_theta`` over one denominator.

        Parameters
        ----------
        compensator : Compensator
            The value (kind, cutoff, Q filter, friction).
        believed : Design
            The design the compensator is built on.

        Returns
        -------
        ObserverFilters
            All zero when the kind has no linear part.
        """
        return _zero_filters(compensator.kind)

    def discrete_filters(self, compensator: Compensator, believed: Design, rate_hz: float) -> DiscreteFilters:
        """The linear part at ``rate_hz`` [Hz] as the board runs it (None paths omitted).

        Parameters
        ----------
        compensator : Compensator
            The value.
        believed : Design
            The design the compensator is built on.
        rate_hz : float
            Control rate [Hz].

        Returns
        -------
        DiscreteFilters
            The running filters.
        """
        return DiscreteFilters(None, None, None)

    def feedforward(self, compensator: Compensator, rate_hz: float, *,
                    velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, deadband: float = 0.0,
                    angle_offset: float = 0.0) -> "FrictionFeedforward | None":
        """The static nonlinear part at ``rate_hz`` [Hz], or None.

        Parameters
        ----------
        compensator : Compensator
            The value.
        rate_hz : float
            Control rate [Hz].
        velocity_cutoff_hz : float
            Velocity filter of a feed-forward [Hz].
        deadband : float
            Sign dead band of a feed-forward [rad/s].
        angle_offset : float
            Absolute angle at theta = 0 [rad].

        Returns
        -------
        FrictionFeedforward or None
            The block.
        """
        return None

    @abstractmethod
    def analysis_note(self, compensator: Compensator) -> str:
        """One line saying what the linear analysis sees of this compensator."""


def _zero_filters(kind: str) -> ObserverFilters:
    zero = [RationalTF((0.0,), (1.0,), name=name) for name in ("G_m", "G_s", "G_theta")]
    return ObserverFilters(kind, float("nan"), *zero)


class _None(CompensatorStrategy):
    kind = "none"

    def linear_filters(self, compensator: Compensator, believed: Design) -> ObserverFilters:
        return _zero_filters("none")

    def analysis_note(self, compensator: Compensator) -> str:
        return "no compensator"


class _Sfm(CompensatorStrategy):
    """Feed-forward of an identified friction model; its viscous part is linear (G_theta)."""

    kind = "sfm"

    def linear_filters(self, compensator: Compensator, believed: Design) -> ObserverFilters:
        params = compensator.friction_params
        if not params:
            return _zero_filters("sfm")
        slope = viscous_slope(params)
        if slope == 0.0:
            return _zero_filters("sfm")
        wv = 2.0 * np.pi * DEFAULT_VELOCITY_CUTOFF_HZ
        den = (1.0 / wv, 1.0)
        return ObserverFilters("sfm", float("nan"), RationalTF((0.0,), den, name="G_m"),
                               RationalTF((0.0,), den, name="G_s"), RationalTF((slope, 0.0), den, name="G_theta"))

    def discrete_filters(self, compensator: Compensator, believed: Design, rate_hz: float) -> DiscreteFilters:
        if not compensator.friction_params:
            return DiscreteFilters(None, None, None)
        ff = self.feedforward(compensator, rate_hz)
        return DiscreteFilters(None, None, ff.linear_filter() if ff.viscous_slope else None)

    def feedforward(self, compensator: Compensator, rate_hz: float, *,
                    velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, deadband: float = 0.0,
                    angle_offset: float = 0.0) -> "FrictionFeedforward | None":
        from .feedforward import friction_feedforward

        return friction_feedforward(compensator.require_friction(), rate_hz, velocity_cutoff_hz=velocity_cutoff_hz,
                                    deadband=deadband, angle_offset=angle_offset)

    def analysis_note(self, compensator: Compensator) -> str:
        params = compensator.friction_params
        if not params:
            return "sfm without identified friction: nothing linear to analyse"
        slope = viscous_slope(params)
        return (f"sfm: its viscous part {slope:.4g} N m s/rad x v_hat ({DEFAULT_VELOCITY_CUTOFF_HZ:g} Hz velocity "
                "filter) is in the loop; Coulomb, Stribeck, offset and angle terms are not linear and are not")


class _Observer(CompensatorStrategy):
    """A Q-filtered observer (EA-FOB, LO-DOB, LD-DOB, motor-side FOB): linear filters only."""

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def linear_filters(self, compensator: Compensator, believed: Design) -> ObserverFilters:
        return observer_filters(compensator, believed)

    def discrete_filters(self, compensator: Compensator, believed: Design, rate_hz: float) -> DiscreteFilters:
        from ..discrete import discretize
        from ..limits import check_below_nyquist

        check_below_nyquist("w_q_hz (the Q cutoff)", compensator.w_q_hz, rate_hz)
        filters = observer_filters(compensator, believed)
        tfs = []
        for tf in (filters.from_tau_m, filters.from_tau_s, filters.from_theta):
            if tf.num == (0.0,):
                tfs.append(None)
                continue
            # the shared denominator keeps uncancelled pairs (a pole and a zero at s = 0 for a free
            # link); as sections such a pair becomes a marginal pole round-off leaves uncancelled
            tfs.append(discretize(tf.minreal(), rate_hz, OBSERVER_METHOD))
        return DiscreteFilters(*tfs)

    def analysis_note(self, compensator: Compensator) -> str:
        return (f"{self.kind} at w_q = {compensator.w_q_hz:g} Hz ({compensator.q_family} Q, order "
                f"{compensator.q_order}): linear, all of it in the loop")


#: kind -> strategy.
COMPENSATOR_STRATEGIES: dict[str, CompensatorStrategy] = {}


def register_compensator(strategy: CompensatorStrategy) -> CompensatorStrategy:
    """Register a strategy under its ``kind``.

    Parameters
    ----------
    strategy : CompensatorStrategy
        An instance with a ``kind``.

    Returns
    -------
    CompensatorStrategy
        ``strategy``.
    """
    if not isinstance(strategy, CompensatorStrategy):
        raise ParameterError(f"register_compensator needs a CompensatorStrategy, got {strategy!r}",
                             name="compensator", value=strategy)
    COMPENSATOR_STRATEGIES[strategy.kind] = strategy
    return strategy


for _s in (_None(), _Sfm(), _Observer("ea-fob"), _Observer("lo-dob"), _Observer("ld-dob"), _Observer("motor-fob")):
    register_compensator(_s)


def compensator_strategy(compensator: Compensator | None) -> CompensatorStrategy:
    """The strategy of a compensator value (``None``: kind ``none``).

    Parameters
    ----------
    compensator : Compensator or None
        The value.

    Returns
    -------
    CompensatorStrategy
        Its kind's strategy.
    """
    if compensator is None:
        return COMPENSATOR_STRATEGIES["none"]
    if not isinstance(compensator, Compensator):
        raise ParameterError(f"compensator must be a Compensator or None (Compensator(kind='ea-fob')), got "
                             f"{type(compensator).__name__} {compensator!r:.40}", name="compensator", value=compensator)
    try:
        return COMPENSATOR_STRATEGIES[compensator.kind]
    except KeyError:
        raise ParameterError(f"no strategy for compensator kind {compensator.kind!r}", name="kind",
                             value=compensator.kind) from None
