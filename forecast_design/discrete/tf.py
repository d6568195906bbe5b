"""Continuous-to-discrete conversion: :func:`discretize` and the :class:`DiscreteTF` it returns."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF
from .realise import _check_dtype, _matched_zpk, _realise, _substitute, _tustin_constant, _zoh
from .filters import delta_to_sos

#: Supported methods: ``tustin`` (bilinear), ``tustin-prewarp`` (bilinear exact at ``prewarp_hz``),
#: ``zoh`` (zero-order hold, exact for piecewise-constant inputs), ``backward-euler``
#: (s = (z - 1) / (T z)), ``forward-euler`` (s = (z - 1) / T) and ``matched`` (pole-zero
#: matching, see :func:`discretize`). The experiment format's ``discretization`` values are
#: all of these but ``forward-euler``.
METHODS = ("tustin", "tustin-prewarp", "zoh", "backward-euler", "forward-euler", "matched")

@dataclass(frozen=True, slots=True)
class DiscreteTF:
    """A discrete transfer function that remembers how it was made.

    Parameters
    ----------
    num, den : tuple of float
        Coefficients in descending powers of z, ``den[0] == 1``, both of
        length ``order + 1`` (leading numerator zeros kept so that
        ``num[0]`` is the direct feedthrough b0).
    rate_hz : float
        Sampling rate [Hz].
    method : str
        One of :data:`METHODS`.
    prewarp_hz : float or None
        Tustin prewarp frequency [Hz] (``None``: plain bilinear).
    source : RationalTF or None
        The continuous TF that was discretised; ``None`` for a TF given by its
        z-coefficients (:meth:`from_z`, method ``given``).
    name : str
        Label (copied from ``source.name``).
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    rate_hz: float
    method: str
    prewarp_hz: float | None
    source: RationalTF | None
    name: str = ""

    @classmethod
    def from_z(cls, num: Any, den: Any, rate_hz: float, name: str = "") -> "DiscreteTF":
        """A discrete TF given by its coefficients in descending powers of z (method ``given``).

        Parameters
        ----------
        num, den : sequence of float
            Coefficients in descending powers of z; ``den[0] != 0``, deg num <= deg den (causal).
        rate_hz : float
            Sampling rate [Hz].
        name : str
            Label.

        Returns
        -------
        DiscreteTF
            Monic denominator, numerator padded to the denominator's length.

        Raises
        ------
        ParameterError
            A zero leading denominator coefficient, a non-causal TF, a bad rate.
        """
        tf = RationalTF(num, den, dt=1.0 / rate_hz if isinstance(rate_hz, (int, float)) and rate_hz > 0 else None,
                        name=name)
        if not (isinstance(rate_hz, (int, float)) and not isinstance(rate_hz, bool) and math.isfinite(rate_hz)
                and rate_hz > 0.0):
            raise ParameterError(f"{name or 'discrete TF'}: rate_hz must be > 0 [Hz], got {rate_hz!r}",
                                 name="rate_hz", value=rate_hz)
        if tf.relative_degree < 0:
            raise ParameterError(f"{name or 'discrete TF'}: numerator degree {len(tf.num) - 1} > denominator degree "
                                 f"{len(tf.den) - 1} in z is not causal", name="num", value=num)
        lead = tf.den[0]
        numz = (0.0,) * (len(tf.den) - len(tf.num)) + tuple(c / lead for c in tf.num)
        return cls(numz, tuple(c / lead for c in tf.den), float(rate_hz), "given", None, None, name)

    @property
    def dt(self) -> float:
        """Sample period 1 / rate_hz [s]."""
        return 1.0 / self.rate_hz

    @property
    def order(self) -> int:
        """Number of poles (len(den) - 1)."""
        return len(self.den) - 1

    def to_rational(self) -> RationalTF:
        """The same TF as a discrete-time :class:`RationalTF` (``dt`` set)."""
        return RationalTF(self.num, self.den, dt=self.dt, name=self.name)

    def freqresp(self, w_rad_s: np.ndarray) -> np.ndarray:
        """Frequency response at ``z = exp(j w dt)`` for angular frequencies ``w_rad_s`` [rad/s]."""
        z = np.exp(1j * np.asarray(w_rad_s, dtype=float) * self.dt)
        return np.polyval(self.num, z) / np.polyval(self.den, z)

    def dcgain(self) -> float:
        """Gain at z = 1 [-]; inf at a pole there."""
        return self.to_rational().dcgain()

    def to_delta_sos(self, dtype: Any = np.float64) -> np.ndarray:
        """The realisation: delta-operator second-order sections (module docstring).

        Parameters
        ----------
        dtype : numpy dtype
            ``np.float64`` (default) or ``np.float32`` coefficients (rounded
            from the float64 design values).

        Returns
        -------
        ndarray, shape (n_sections, 6)
            Rows ``[b0, b1, b2, 1, a1, a2]`` in ``rho = z - 1``: first the
            first-difference sections of the source's zeros at s = 0, then
            the pole groups, least sensitive first.

        Raises
        ------
        ParameterError
            For a dtype other than float64/float32.
        """
        dtype = _check_dtype(dtype)
        return np.ascontiguousarray(_realise(self), dtype=dtype)

    def to_sos(self, dtype: Any = np.float64) -> np.ndarray:
        """The same sections in scipy's shift-operator layout (for interoperability).

        Parameters
        ----------
        dtype : numpy dtype
            ``np.float64`` (default) or ``np.float32``.

        Returns
        -------
        ndarray, shape (n_sections, 6)
            :func:`delta_to_sos` of :meth:`to_delta_sos`, usable with
            ``scipy.signal.sosfilt``/``sosfreqz``. The filters of this
            package never run this form (it loses precision near z = 1).
        """
        dtype = _check_dtype(dtype)
        return np.ascontiguousarray(delta_to_sos(_realise(self)), dtype=dtype)

    def to_mapping(self) -> dict[str, Any]:
        """Coefficients and provenance (for JSON and the C export header)."""
        return {
            "num": list(self.num), "den": list(self.den), "rate_hz": self.rate_hz,
            "method": self.method, "prewarp_hz": self.prewarp_hz, "name": self.name,
            "source": None if self.source is None else {"num": list(self.source.num), "den": list(self.source.den)},
        }


def discretize(tf: RationalTF, rate_hz: float, method: str = "tustin",
               prewarp_hz: float | None = None) -> DiscreteTF:
    """Discretise a continuous transfer function.

    Parameters
    ----------
    tf : RationalTF
        Continuous-time TF (``tf.dt is None``); proper, except with ``backward-euler``, which
        maps an improper TF (a pure derivative, e.g. an unfiltered PD) to a causal one.
    rate_hz : float
        Sampling rate [Hz]; T = 1 / rate_hz [s].
    method : str
        One of :data:`METHODS`: ``tustin`` (default), ``tustin-prewarp`` (needs
        ``prewarp_hz``), ``zoh``, ``backward-euler``, ``forward-euler`` or ``matched``.
    prewarp_hz : float, optional
        Tustin only: frequency [Hz] at which the discrete response equals the
        continuous one exactly; must be below rate_hz / 2. ``tustin`` with a prewarp is
        recorded as ``tustin-prewarp``.

    Returns
    -------
    DiscreteTF
        Monic-denominator discrete TF recording method, rate and prewarp.

    Raises
    ------
    ParameterError
        Unknown method, non-positive rate, discrete ``tf``, an improper ``tf`` with a method
        other than backward Euler, prewarp with a method other than Tustin or at/above Nyquist.

    Notes
    -----
    Tustin substitutes ``s = c (z - 1) / (z + 1)`` with ``c = 2 / T``, or
    ``c = w_p / tan(w_p T / 2)`` with prewarp ``w_p = 2 pi prewarp_hz``.
    Backward Euler substitutes ``s = (z - 1) / (T z)``, forward Euler
    ``s = (z - 1) / T``; both multiply through by the needed power of z.
    ZOH is exact for piecewise-constant inputs:
    ``exp([[A, B], [0, 0]] T)`` of a state-space realisation.
    Matched maps poles and zeros by ``z = exp(s T)``, zeros at infinity to
    ``z = -1``, and matches the low-frequency gain (DC, or ``s^m H(s)`` with m
    net poles at s = 0); python-control's ``sample_system(method="matched")``
    leaves the zeros at infinity out (the two agree for a biproper TF without
    roots at s = 0).

    Examples
    --------
    >>> d = discretize(RationalTF([1.0], [0.1, 1.0]), 1000.0, "zoh")
    >>> round(d.den[1], 12) == round(-math.exp(-0.01), 12)
    True
    >>> discretize(RationalTF([0.1, 5.0], [1.0]), 2000.0, "backward-euler").num   # P + D s
    (205.0, -200.0)
    """
    if not isinstance(tf, RationalTF) or tf.dt is not None:
        raise ParameterError(f"discretize needs a continuous RationalTF, got {tf!r}", name="tf", value=tf)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) or not (rate_hz > 0.0) \
            or not math.isfinite(rate_hz):
        raise ParameterError(f"discretize rate_hz must be > 0 [Hz], got {rate_hz!r}", name="rate_hz", value=rate_hz)
    if method not in METHODS:
        raise ParameterError(f"discretize method must be one of {', '.join(METHODS)}, got {method!r}",
                             name="method", value=method)
    if tf.relative_degree < 0 and method != "backward-euler":
        raise ParameterError(
            f"discretize: {tf.name or 'tf'} is improper (numerator degree {len(tf.num) - 1} > "
            f"denominator degree {len(tf.den) - 1}); {method} cannot realise it causally and stably: "
            "add a filter pole (a derivative filter T_f) or use backward-euler",
            name="tf", value=tf,
        )
    if method == "tustin-prewarp" and prewarp_hz is None:
        raise ParameterError("discretize method tustin-prewarp needs prewarp_hz [Hz]", name="prewarp_hz", value=None)
    if prewarp_hz is not None:
        if method not in ("tustin", "tustin-prewarp"):
            raise ParameterError(f"discretize prewarp_hz applies to tustin only, got method {method!r}",
                                 name="prewarp_hz", value=prewarp_hz)
        if isinstance(prewarp_hz, bool) or not isinstance(prewarp_hz, (int, float)) \
                or not (0.0 < prewarp_hz < rate_hz / 2.0):
            raise ParameterError(f"discretize prewarp_hz must be in (0, rate_hz/2 = {rate_hz / 2.0}) [Hz], "
                                 f"got {prewarp_hz!r}", name="prewarp_hz", value=prewarp_hz)
        method = "tustin-prewarp"
    rate_hz = float(rate_hz)
    dt = 1.0 / rate_hz
    order = max(len(tf.den), len(tf.num)) - 1
    num_s = tuple(tf.num)
    if method == "zoh":
        numz, denz = _zoh(num_s, tf.den, dt)
    elif method == "matched":
        z_zeros, z_poles, gain = _matched_zpk(np.asarray(tf.num), np.asarray(tf.den), dt)
        numz = gain * np.real(np.poly(z_zeros)) if len(z_zeros) else np.array([gain])
        denz = np.real(np.poly(z_poles)) if len(z_poles) else np.array([1.0])
    else:
        if method in ("tustin", "tustin-prewarp"):
            c = _tustin_constant(dt, prewarp_hz)
            s_num, s_den = np.array([c, -c]), np.array([1.0, 1.0])
        elif method == "backward-euler":
            s_num, s_den = np.array([1.0, -1.0]), np.array([dt, 0.0])
        else:  # forward-euler
            s_num, s_den = np.array([1.0, -1.0]) / dt, np.array([1.0])
        numz = _substitute(num_s, order, s_num, s_den)
        denz = _substitute(tf.den, order, s_num, s_den)
    numz = np.asarray(numz, dtype=float)
    denz = np.asarray(denz, dtype=float)
    if len(numz) < len(denz):
        numz = np.concatenate([np.zeros(len(denz) - len(numz)), numz])
    lead = denz[0]
    if lead == 0.0:
        raise ParameterError(
            f"discretize: {method} maps {tf.name or 'tf'} to a non-causal filter (pole at s = -2/T?)",
            name="tf", value=tf,
        )
    return DiscreteTF(tuple(float(v) for v in numz / lead), tuple(float(v) for v in denz / lead),
                      rate_hz, method, None if prewarp_hz is None else float(prewarp_hz), tf, tf.name)
