"""Friction feed-forward from an identified friction model (compensator kind ``sfm``), defined once.

The estimate is built from the friction model's own terms (``forecast_design.friction``
parameter names), so any static fit can be compensated: the SFM (``viscous``,
``coulomb``), Section 7's extended SFM (``+ offset, sin<i>, cos<i>``), position friction
(``coulomb_sin<i>``, ``coulomb_cos<i>``), the asymmetric model (``viscous_pos``,
``viscous_neg``, ``coulomb_pos``, ``coulomb_neg``) and the Stribeck model (``static``,
``coulomb``, ``stribeck_velocity``, ``viscous``)::

    v_hat  = s / (s / w_v + 1) theta                       (Tustin, w_v = 2 pi velocity_cutoff_hz)
    sgn    = sign(v_hat) with a dead band |v_hat| <= deadband
    tau_hat = (viscous_pos if v_hat > 0 else viscous_neg) v_hat
            + (coulomb_pos if sgn > 0; -coulomb_neg if sgn < 0)
            + sgn (static - coulomb) exp(-(v_hat / stribeck_velocity)^2)
            + offset + sum_i sin_i sin(i th) + cos_i cos(i th)
            + sgn sum_i coulomb_sin_i sin(i th) + coulomb_cos_i cos(i th),     th = theta + angle_offset

:func:`feedforward_eval` is that formula, compiled for the simulator's kernel and run
un-compiled on float32 values as the C export's reference; the C emitter writes the same
expressions in the same order. The linear part, ``viscous v_hat``, is what the loop analysis
sees (:meth:`FrictionFeedforward.linear_filter`): a motor-angle filter ``G_theta``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..discrete import DiscreteTF, discretize, njit
from ..errors import ParameterError
from ..lti import RationalTF
from . import DEFAULT_VELOCITY_CUTOFF_HZ
from .sfm_params import FEEDFORWARD_PARAMETERS, feedforward_coefficients

__all__ = [
    "DEFAULT_VELOCITY_CUTOFF_HZ",
    "FEEDFORWARD_PARAMETERS",
    "FrictionFeedforward",
    "feedforward_eval",
    "friction_feedforward",
]

# coef layout: [viscous_pos, viscous_neg, coulomb_pos, coulomb_neg, static_excess, stribeck_velocity,
#               offset, deadband, angle_offset, 1]


@njit
def feedforward_eval(coef, harm, theta, v):
    """The feed-forward formula (module docstring): one sample.

    Parameters
    ----------
    coef : ndarray, shape (10,)
        ``[viscous_pos, viscous_neg, coulomb_pos, coulomb_neg, static - coulomb,
        stribeck_velocity, offset, deadband, angle_offset, 1]``; the last entry is the constant
        1 in the array's dtype, so that a float32 call computes in float32 throughout
        (compiled or not: no float64 literal enters the arithmetic).
    harm : ndarray, shape (4, n)
        Rows sin, cos, coulomb_sin, coulomb_cos of harmonics 1..n [N m].
    theta : float
        Measured motor angle [rad].
    v : float
        Filtered velocity estimate [rad/s].

    Returns
    -------
    float
        tau_hat [N m], in the arrays' dtype.
    """
    one = coef[9]
    zero = one - one
    sgn = zero
    if v > coef[7]:
        sgn = one
    elif v < -coef[7]:
        sgn = -one
    # Evaluated in the C code's order (export/c.py writes the same expressions).
    if v > zero:
        out = coef[0] * v
    else:
        out = coef[1] * v
    if sgn > zero:
        out = out + coef[2]
    elif sgn < zero:
        out = out - coef[3]
    if coef[4] != zero:
        r = v / coef[5]
        out = out + sgn * (coef[4] * np.exp(-(r * r)))
    out = out + coef[6]
    th = theta + coef[8]
    k = zero
    for i in range(harm.shape[1]):
        k = k + one
        if harm[0, i] == zero and harm[1, i] == zero and harm[2, i] == zero and harm[3, i] == zero:
            continue
        s = np.sin(k * th)
        c = np.cos(k * th)
        out = out + (harm[0, i] * s + harm[1, i] * c) + sgn * (harm[2, i] * s + harm[3, i] * c)
    return out


@dataclass(frozen=True, slots=True)
class FrictionFeedforward:
    """The feed-forward as it runs at ``rate_hz``: the velocity filter and the formula's coefficients.

    Parameters
    ----------
    params : tuple of (str, float)
        The friction parameters it was built from (names as identified).
    velocity : DiscreteTF
        ``s / (s / w_v + 1)`` discretised with Tustin [rad/s per rad].
    coef : ndarray, shape (10,)
        :func:`feedforward_eval`'s coefficients (dead band [rad/s], angle offset [rad] and the
        typed constant 1 included).
    harm : ndarray, shape (4, n)
        Harmonic amplitudes [N m].
    """

    params: tuple[tuple[str, float], ...]
    velocity: DiscreteTF
    coef: np.ndarray
    harm: np.ndarray

    @property
    def viscous_slope(self) -> float:
        """The linear part's slope: mean of the two viscous levels [N m s/rad] (the describing
        function of a direction-dependent gain for a zero-mean sinusoid)."""
        return 0.5 * float(self.coef[0] + self.coef[1])

    @property
    def has_harmonics(self) -> bool:
        """True when any angle harmonic is non-zero (the C then needs sinf/cosf)."""
        return bool(np.any(self.harm != 0.0))

    @property
    def has_stribeck(self) -> bool:
        """True when a Stribeck excess is fed forward (the C then needs expf)."""
        return bool(self.coef[4] != 0.0)

    def linear_filter(self) -> DiscreteTF:
        """``viscous v_hat`` as a filter on theta: the part the loop analysis sees [N m/rad]."""
        src = self.velocity.source
        return discretize(RationalTF(tuple(self.viscous_slope * c for c in src.num), src.den, name="G_theta"),
                          self.velocity.rate_hz, self.velocity.method)

    def evaluate(self, theta: np.ndarray) -> np.ndarray:
        """Run the feed-forward over a motor-angle record from rest (float64) [N m].

        Parameters
        ----------
        theta : ndarray, shape (n,)
            Measured motor angle [rad] at the control rate.

        Returns
        -------
        ndarray, shape (n,)
            tau_hat [N m].
        """
        from ..discrete import DiscreteFilter

        v = DiscreteFilter(self.velocity).filter(np.asarray(theta, dtype=float))
        return np.array([feedforward_eval(self.coef, self.harm, th, vi) for th, vi in zip(theta, v)])


def friction_feedforward(params: Mapping[str, float], rate_hz: float, *,
                         velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, deadband: float = 0.0,
                         angle_offset: float = 0.0) -> FrictionFeedforward:
    """Build the feed-forward of identified friction for a control rate.

    Parameters
    ----------
    params : Mapping[str, float]
        Friction parameters by name (module docstring): viscous [N m s/rad], coulomb, offset,
        harmonics [N m], static [N m], stribeck_velocity [rad/s]... Missing names are 0.
    rate_hz : float
        Control rate [Hz].
    velocity_cutoff_hz : float
        Pole of the filtered derivative giving ``v_hat`` [Hz], below Nyquist.
    deadband : float
        ``sign(v_hat)`` is 0 for ``|v_hat| <= deadband`` [rad/s] (0: plain sign).
    angle_offset : float
        Absolute motor angle at theta = 0 (a homed encoder) [rad].

    Returns
    -------
    FrictionFeedforward
        The block the simulator, the program reference and the C run.

    Raises
    ------
    ParameterError
        Unknown or refused parameter names (LuGre's bristles, an inertia), non-finite values,
        a velocity cutoff at or above Nyquist, a negative dead band.
    """
    coef, harm = feedforward_coefficients(params)
    if not (isinstance(rate_hz, (int, float)) and rate_hz > 0.0 and math.isfinite(rate_hz)):
        raise ParameterError(f"feed-forward rate_hz must be > 0 [Hz], got {rate_hz!r}", name="rate_hz", value=rate_hz)
    if not (velocity_cutoff_hz > 0.0 and velocity_cutoff_hz < rate_hz / 2.0):
        raise ParameterError(f"sfm velocity_cutoff_hz must be in (0, rate_hz/2) [Hz], got {velocity_cutoff_hz!r}",
                             name="velocity_cutoff_hz", value=velocity_cutoff_hz)
    if not (deadband >= 0.0 and math.isfinite(deadband)):
        raise ParameterError(f"sfm deadband must be >= 0 [rad/s], got {deadband!r}", name="deadband", value=deadband)
    if not math.isfinite(angle_offset):
        raise ParameterError(f"angle_offset must be finite [rad], got {angle_offset!r}", name="angle_offset",
                             value=angle_offset)
    coef[7], coef[8] = float(deadband), float(angle_offset)
    wv = 2.0 * math.pi * velocity_cutoff_hz
    velocity = discretize(RationalTF((1.0, 0.0), (1.0 / wv, 1.0), name="v_hat"), rate_hz, "tustin")
    coef.flags.writeable = False
    harm.flags.writeable = False
    return FrictionFeedforward(tuple(sorted((str(k), float(v)) for k, v in params.items())), velocity, coef, harm)
