"""Discrete controllers and friction compensators of the simulated testbed (2 kHz).

Each object has a ``step(...)`` for use in Python and exposes its
coefficient arrays to the compiled closed loop in :mod:`.run`, which calls
the very same :func:`~forecast_design.discrete.sos_step`
recursion, so a Python re-run of the controller on logged measurements
reproduces the simulated commands exactly.

PD force controller
-------------------
``C_F(s) = P + D s / (s / w_d + 1)`` acting on ``e = tau_r - tau_s``,
discretised with Tustin. The derivative filter pole ``w_d = 2 pi
derivative_cutoff_hz`` defaults to 200 Hz: one tenth of the 2 kHz rate,
where Tustin's frequency warping is below 4 % (tan(pi/10)/(pi/10) = 1.034),
and twenty times the ~10 Hz force bandwidth the paper tuned P = 5, D = 0.1
for, so the filter costs ~3 deg of phase at 10 Hz. A pure Tustin
differentiator would put a pole at z = -1 (an undamped Nyquist-rate mode);
the filter makes the high-frequency gain finite, D w_d ~ 126 N m/N m, which
turns the 1.8e-4 N m spring-torque quantum of the encoders into ~0.02 N m
of command chatter at most.

Compensators
------------
``none``; ``sfm``: ``tau_hat = viscous v_hat + coulomb sign(v_hat) +
offset + sum_i sin_i sin(i th) + cos_i cos(i th) + sign(v_hat) sum_i
(coulomb_sin_i sin(i th) + coulomb_cos_i cos(i th))`` with ``v_hat`` a
Tustin-discretised filtered derivative ``s / (s / w_v + 1)`` of the
measured motor angle and ``th`` the measured angle plus the known absolute
offset (the paper's SFM is ``viscous``/``coulomb``; Section 7's extended
SFM adds the harmonics); the observers ``ea-fob``, ``lo-dob``, ``ld-dob``,
``motor-fob``: ``tau_hat = G_m tau_m + G_s tau_s + G_theta theta`` with the
three filters of :func:`forecast_design.symbolic.observers.observer_filters`
discretised by :func:`forecast_design.discrete.discretize` and run as
second-order sections.

The algebraic loop of the observers: the applied command is ``tau_m[n] =
sat(u[n] + tau_hat[n])`` and ``G_m`` has direct feedthrough after Tustin,
so ``tau_hat[n]`` would depend on ``tau_m[n]``. As on the embedded board,
``G_m`` is fed the *previous* applied command ``tau_m[n-1]`` (the torque
that acted over [t_{n-1}, t_n) and produced the measurements at t_n): a
one-sample delay in the ``G_m`` path, i.e. ``z^-1 G_m(z)``. It shifts the
loop phase by ``w T`` (1.8 deg at 10 Hz) and lets the saturated value, not
the requested one, feed the observer (no windup of the estimate).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..errors import ParameterError
from ..discrete import DiscreteFilter, DiscreteTF, discretize, njit as _njit
from ..lti import RationalTF
from ..params import Compensator, Design, PDController
from ..plausibility import check_below_nyquist

__all__ = [
    "DEFAULT_DERIVATIVE_CUTOFF_HZ",
    "DEFAULT_VELOCITY_CUTOFF_HZ",
    "DERIVATIVE_ON",
    "pd_transfer_function",
    "DiscretePD",
    "SfmCompensator",
    "ObserverCompensator",
    "cancel_common_roots",
    "sfm_eval",
]

#: Default derivative filter of the PD controller [Hz] (see module docstring).
DEFAULT_DERIVATIVE_CUTOFF_HZ = 200.0
#: Where the PD takes its derivative: ``error`` (the format's u = P e + D de/dt) or ``measurement``
#: (u = P e - D d tau_s/dt: no derivative kick at a reference step).
DERIVATIVE_ON = ("error", "measurement")
#: Default velocity filter of the SFM compensator [Hz].
DEFAULT_VELOCITY_CUTOFF_HZ = 50.0

_SFM_KEY = re.compile(r"^(viscous|coulomb|offset|(coulomb_)?(sin|cos)([1-9][0-9]*))$")


def pd_transfer_function(controller: PDController, derivative_cutoff_hz: float = DEFAULT_DERIVATIVE_CUTOFF_HZ
                         ) -> RationalTF:
    """Continuous PD with a filtered derivative, ``P + D s / (s / w_d + 1)``.

    Parameters
    ----------
    controller : PDController
        Gains ``P`` [N m/N m] and ``D`` [N m s/N m].
    derivative_cutoff_hz : float
        Derivative filter pole ``w_d / (2 pi)`` [Hz]; ``inf`` for a pure
        derivative (improper, cannot be discretised).

    Returns
    -------
    RationalTF
        ``((P / w_d + D) s + P) / (s / w_d + 1)`` [N m/N m].
    """
    if not (derivative_cutoff_hz > 0.0):
        raise ParameterError(f"derivative_cutoff_hz must be > 0 [Hz], got {derivative_cutoff_hz!r}",
                             name="derivative_cutoff_hz", value=derivative_cutoff_hz)
    P, D = controller.P, controller.D
    if math.isinf(derivative_cutoff_hz):
        return RationalTF((D, P), (1.0,), name="C_F")
    wd = 2.0 * math.pi * derivative_cutoff_hz
    return RationalTF((P / wd + D, P), (1.0 / wd, 1.0), name="C_F")


def cancel_common_roots(tf: RationalTF, rtol: float = 1e-7) -> RationalTF:
    """Remove pole-zero pairs that coincide to ``rtol`` (a numeric minimal realisation).

    The observer filters share one denominator and keep uncancelled pairs
    (e.g. a pole and a zero at s = 0 for a free link); discretised into
    sections such a pair becomes a marginal pole that round-off can leave
    uncancelled, so the simulator cancels them first.

    Parameters
    ----------
    tf : RationalTF
        Continuous TF.
    rtol : float
        Relative distance under which a zero cancels a pole [-].

    Returns
    -------
    RationalTF
        The reduced TF with the same high-frequency gain ratio and name.
    """
    if tf.num == (0.0,) or len(tf.den) == 1 or len(tf.num) == 1:
        return tf
    zeros = list(np.roots(tf.num))
    poles = list(np.roots(tf.den))
    keep_p = []
    for p in poles:
        best = None
        for i, z in enumerate(zeros):
            if abs(z - p) <= rtol * max(1.0, abs(p)) and (best is None or abs(z - p) < abs(zeros[best] - p)):
                best = i
        if best is None:
            keep_p.append(p)
        else:
            zeros.pop(best)
    if len(keep_p) == len(poles):
        return tf
    num = np.real_if_close(np.poly(zeros)) * tf.num[0] if zeros else np.array([tf.num[0]])
    den = np.real_if_close(np.poly(keep_p)) * tf.den[0] if keep_p else np.array([tf.den[0]])
    return RationalTF(tuple(np.real(num)), tuple(np.real(den)), name=tf.name)


class DiscretePD:
    """The 2 kHz PD force controller ``u = C_F(z) e``, ``e = tau_r - tau_s``.

    Parameters
    ----------
    controller : PDController
        Gains P [N m/N m], D [N m s/N m].
    rate_hz : float
        Control rate [Hz].
    derivative_cutoff_hz : float
        Derivative filter [Hz] (module docstring: 200 Hz default).
    method : str
        Discretisation method (default ``tustin``).

    Attributes
    ----------
    tf : DiscreteTF
        The discretised controller.
    sos : ndarray, shape (1, 6)
        Its sections (the kernel's coefficients).
    """

    def __init__(self, controller: PDController, rate_hz: float, *,
                 derivative_cutoff_hz: float = DEFAULT_DERIVATIVE_CUTOFF_HZ, method: str = "tustin") -> None:
        self.controller = controller
        self.tf: DiscreteTF = discretize(pd_transfer_function(controller, derivative_cutoff_hz), rate_hz, method)
        self._filter = DiscreteFilter(self.tf)
        self.sos = self._filter.sos

    def measurement_reference(self, reference: np.ndarray) -> np.ndarray:
        """The reference r' for which this PD on r' - tau_s takes its derivative on the measurement.

        ``C (r' - y) = P r - C y`` when ``C r' = P r``: r' is r through ``P / C(z)``, stable since
        C's zero lies at s = -P / (P / w_d + D) (-48 rad/s for P = 5, D = 0.1). No derivative of the
        reference reaches the motor, so a step has no kick.

        Parameters
        ----------
        reference : ndarray, shape (n,)
            The reference r at the control periods [N m].

        Returns
        -------
        ndarray, shape (n,)
            r' [N m].
        """
        from scipy.signal import lfilter

        return lfilter(self.controller.P * np.asarray(self.tf.den, dtype=float), np.asarray(self.tf.num, dtype=float),
                       np.asarray(reference, dtype=float))

    def reset(self) -> None:
        """Zero the filter state."""
        self._filter.reset()

    def step(self, e: float) -> float:
        """Controller output u [N m] for the force error e [N m]."""
        return self._filter.step(e)


def _check_sfm_params(params: Mapping[str, float]) -> tuple[float, float, float, np.ndarray]:
    if not isinstance(params, Mapping):
        raise ParameterError(f"sfm parameters must be a mapping name -> value, got {params!r}",
                             name="sfm_params", value=params)
    viscous = coulomb = offset = 0.0
    n_h = 0
    parsed = []
    for key, value in params.items():
        m = _SFM_KEY.match(str(key))
        if m is None:
            raise ParameterError(
                f"sfm parameter '{key}' unknown; allowed: viscous, coulomb, offset, sin<i>, cos<i>, "
                "coulomb_sin<i>, coulomb_cos<i>",
                name=str(key), value=value,
            )
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not math.isfinite(value):
            raise ParameterError(f"sfm parameter '{key}' must be a finite number, got {value!r}",
                                 name=str(key), value=value)
        parsed.append((m, float(value)))
        if m.group(4):
            n_h = max(n_h, int(m.group(4)))
    harm = np.zeros((4, max(n_h, 1)))  # rows: sin, cos, coulomb_sin, coulomb_cos
    for m, value in parsed:
        name = m.group(1)
        if name == "viscous":
            viscous = value
        elif name == "coulomb":
            coulomb = value
        elif name == "offset":
            offset = value
        else:
            row = (2 if m.group(2) else 0) + (0 if m.group(3) == "sin" else 1)
            harm[row, int(m.group(4)) - 1] = value
    return viscous, coulomb, offset, harm


@dataclass(frozen=True, slots=True)
class _SfmCoefficients:
    coef: np.ndarray   # [viscous, coulomb, offset, deadband, angle_offset]
    harm: np.ndarray   # (4, n): sin, cos, coulomb_sin, coulomb_cos


class SfmCompensator:
    """Static friction model feed-forward (SFM and the extended SFM of Section 7).

    Parameters
    ----------
    params : Mapping[str, float]
        Identified parameters by name: ``viscous`` [N m s/rad], ``coulomb``
        [N m], ``offset`` [N m], ``sin<i>``/``cos<i>`` [N m] (angle
        harmonics) and ``coulomb_sin<i>``/``coulomb_cos<i>`` [N m]
        (direction-signed harmonics), as named by
        :mod:`forecast_design.friction.terms`. Missing names are 0.
    rate_hz : float
        Control rate [Hz].
    velocity_cutoff_hz : float
        Pole of the filtered derivative giving ``v_hat`` [Hz].
    deadband : float
        ``sign(v_hat)`` is 0 for ``|v_hat| <= deadband`` [rad/s] (0: plain sign).
    angle_offset : float
        Absolute motor angle at theta = 0 (a homed encoder) [rad].
    """

    def __init__(self, params: Mapping[str, float], rate_hz: float, *,
                 velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, deadband: float = 0.0,
                 angle_offset: float = 0.0) -> None:
        viscous, coulomb, offset, harm = _check_sfm_params(params)
        if not (velocity_cutoff_hz > 0.0 and velocity_cutoff_hz < rate_hz / 2.0):
            raise ParameterError(f"sfm velocity_cutoff_hz must be in (0, rate_hz/2) [Hz], got {velocity_cutoff_hz!r}",
                                 name="velocity_cutoff_hz", value=velocity_cutoff_hz)
        if not (deadband >= 0.0):
            raise ParameterError(f"sfm deadband must be >= 0 [rad/s], got {deadband!r}", name="deadband",
                                 value=deadband)
        self.params = dict(params)
        wv = 2.0 * math.pi * velocity_cutoff_hz
        self.velocity_tf = discretize(RationalTF((1.0, 0.0), (1.0 / wv, 1.0), name="v_hat"), rate_hz, "tustin")
        self._velocity = DiscreteFilter(self.velocity_tf)
        self.velocity_sos = self._velocity.sos
        self.coefficients = _SfmCoefficients(
            np.array([viscous, coulomb, offset, float(deadband), float(angle_offset)]), harm)

    def reset(self) -> None:
        """Zero the velocity filter."""
        self._velocity.reset()

    def step(self, theta: float) -> float:
        """Friction estimate tau_hat [N m] from the measured motor angle theta [rad]."""
        v = self._velocity.step(theta)
        return float(sfm_eval(self.coefficients.coef, self.coefficients.harm, theta, v))


@_njit
def sfm_eval(coef, harm, theta, v):
    """The SFM formula, shared by :meth:`SfmCompensator.step` and the compiled loop.

    Parameters
    ----------
    coef : ndarray, shape (5,)
        ``[viscous, coulomb, offset, deadband, angle_offset]``.
    harm : ndarray, shape (4, n)
        Rows sin, cos, coulomb_sin, coulomb_cos of harmonics 1..n [N m].
    theta : float
        Measured motor angle [rad].
    v : float
        Filtered velocity estimate [rad/s].

    Returns
    -------
    float
        tau_hat [N m]; float32 when called un-compiled on float32 arrays and scalars.
    """
    sgn = 0.0
    if v > coef[3]:
        sgn = 1.0
    elif v < -coef[3]:
        sgn = -1.0
    # Evaluated in the C code's order (export/c.py writes the same expressions), so that the
    # same function, called un-compiled on float32 values, is the export's float32 reference.
    out = (coef[0] * v + coef[1] * sgn) + coef[2]
    th = theta + coef[4]
    for i in range(harm.shape[1]):
        if harm[0, i] == 0.0 and harm[1, i] == 0.0 and harm[2, i] == 0.0 and harm[3, i] == 0.0:
            continue
        s = np.sin((i + 1) * th)
        c = np.cos((i + 1) * th)
        out = out + (harm[0, i] * s + harm[1, i] * c) + sgn * (harm[2, i] * s + harm[3, i] * c)
    return out


class ObserverCompensator:
    """A Q-filtered observer (EA-FOB, LO-DOB, LD-DOB, motor-side FOB) as three discrete filters.

    Parameters
    ----------
    compensator : Compensator
        Kind and Q filter (``w_q_hz`` [Hz], family, order).
    believed : Design
        The nominal design the observer is built on.
    rate_hz : float
        Control rate [Hz].
    method : str
        Discretisation method of the three filters (default ``tustin``).

    Attributes
    ----------
    filters : ObserverFilters
        The continuous G_m, G_s, G_theta.
    tfs : tuple of DiscreteTF
        Their discretisations (after :func:`cancel_common_roots`).
    sos_m, sos_s, sos_theta : ndarray
        Second-order sections of each.

    Notes
    -----
    ``step`` takes the previous applied command (module docstring).
    """

    def __init__(self, compensator: Compensator, believed: Design, rate_hz: float, *,
                 method: str = "tustin") -> None:
        from ..symbolic.observers import observer_filters

        if compensator is None or not compensator.is_observer:
            raise ParameterError(f"ObserverCompensator needs an observer kind, got {compensator!r}",
                                 name="kind", value=getattr(compensator, "kind", None))
        check_below_nyquist("w_q_hz (the Q cutoff)", compensator.w_q_hz, rate_hz)   # issue 23
        self.filters = observer_filters(compensator, believed)
        self.tfs = tuple(discretize(cancel_common_roots(tf), rate_hz, method)
                         for tf in (self.filters.from_tau_m, self.filters.from_tau_s, self.filters.from_theta))
        self._g = tuple(DiscreteFilter(tf) for tf in self.tfs)
        self.sos_m, self.sos_s, self.sos_theta = (g.sos for g in self._g)

    def reset(self) -> None:
        """Zero the three filter states."""
        for g in self._g:
            g.reset()

    def step(self, tau_m_prev: float, tau_s: float, theta: float) -> float:
        """Friction estimate [N m] from the previous applied command [N m], tau_s [N m] and theta [rad]."""
        return self._g[0].step(tau_m_prev) + self._g[1].step(tau_s) + self._g[2].step(theta)

