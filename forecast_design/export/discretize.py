"""Continuous-to-discrete conversion and the one discrete filter implementation.

:func:`discretize` maps a continuous :class:`~forecast_design.lti.RationalTF`
to a :class:`DiscreteTF` that records how it was made (method, rate,
prewarp). :meth:`DiscreteTF.to_sos` gives second-order sections and
:class:`DiscreteFilter` runs them with the recursion below, the same one the
simulator runs and the C export emits.

Second-order-section recursion (direct form II transposed, per section
``[b0, b1, b2, 1, a1, a2]``, sections in series, state ``s1, s2`` per
section, initially zero)::

    y  = b0 x + s1
    s1 = b1 x - a1 y + s2
    s2 = b2 x - a2 y

The output ``y`` of section ``i`` is the input ``x`` of section ``i + 1``.
This is exactly ``scipy.signal.sosfilt``'s recursion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF

try:  # numba is optional: without it the same functions run as plain Python.
    from numba import njit as _numba_njit

    def _njit(func):
        return _numba_njit(cache=True)(func)

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    def _njit(func):
        return func

    HAVE_NUMBA = False

__all__ = [
    "METHODS",
    "DiscreteTF",
    "DiscreteFilter",
    "discretize",
    "sos_step",
    "sos_filter",
]

#: Supported methods: ``tustin`` (bilinear, optional prewarp), ``zoh``
#: (zero-order hold, exact for piecewise-constant inputs), ``backward-euler``
#: (s = (z - 1) / (T z)) and ``forward-euler`` (s = (z - 1) / T).
METHODS = ("tustin", "zoh", "backward-euler", "forward-euler")


@_njit
def sos_step(sos, state, x):
    """Advance a cascade of second-order sections by one sample (in place).

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Rows ``[b0, b1, b2, 1, a1, a2]``.
    state : ndarray, shape (n_sections, 2)
        DF-II-transposed states ``s1, s2``; updated in place.
    x : float
        Input sample.

    Returns
    -------
    float
        Output sample. The arithmetic is done in the dtype of ``sos``/``state``
        (float32 arrays give float32 arithmetic, as a C ``float`` filter).
    """
    y = x
    for i in range(sos.shape[0]):
        xi = y
        y = sos[i, 0] * xi + state[i, 0]
        state[i, 0] = sos[i, 1] * xi - sos[i, 4] * y + state[i, 1]
        state[i, 1] = sos[i, 2] * xi - sos[i, 5] * y
    return y


@_njit
def sos_filter(sos, state, x, y):
    """Run :func:`sos_step` over an input array.

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Sections.
    state : ndarray, shape (n_sections, 2)
        States, updated in place.
    x : ndarray, shape (n,)
        Input.
    y : ndarray, shape (n,)
        Output, written in place.
    """
    for n in range(x.shape[0]):
        y[n] = sos_step(sos, state, x[n])


def _poly_pow(p: np.ndarray, n: int) -> np.ndarray:
    out = np.array([1.0])
    for _ in range(n):
        out = np.polymul(out, p)
    return out


def _substitute(coeffs: tuple[float, ...], order: int, num_s: np.ndarray, den_s: np.ndarray) -> np.ndarray:
    """sum_i c_i (num_s/den_s)^i times den_s^order, as a z-polynomial (descending)."""
    deg = len(coeffs) - 1
    total = np.zeros(order + 1)
    for j, c in enumerate(coeffs):
        i = deg - j  # power of s
        term = c * np.polymul(_poly_pow(num_s, i), _poly_pow(den_s, order - i))
        total[order + 1 - len(term):] += term
    return total


def _zoh(num: tuple[float, ...], den: tuple[float, ...], dt: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy import linalg, signal

    n = len(den) - 1
    if n == 0:
        return np.array([num[0] / den[0]]), np.array([1.0])
    A, B, C, D = signal.tf2ss(num, den)
    m = np.zeros((n + 1, n + 1))
    m[:n, :n] = A * dt
    m[:n, n:] = B * dt
    e = linalg.expm(m)
    Ad, Bd = e[:n, :n], e[:n, n:]
    numd, dend = signal.ss2tf(Ad, Bd, C, D)
    return np.atleast_1d(np.squeeze(numd)), np.atleast_1d(dend)


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
    source : RationalTF
        The continuous TF that was discretised.
    name : str
        Label (copied from ``source.name``).
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    rate_hz: float
    method: str
    prewarp_hz: float | None
    source: RationalTF
    name: str = ""

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

    def to_sos(self, dtype: Any = np.float64) -> np.ndarray:
        """Second-order sections ``[b0, b1, b2, 1, a1, a2]`` per row.

        Parameters
        ----------
        dtype : numpy dtype
            ``np.float64`` (default) or ``np.float32`` coefficients.

        Returns
        -------
        ndarray, shape (max(1, ceil(order / 2)), 6)
            Sections from :func:`scipy.signal.tf2sos` (nearest pole-zero
            pairing, overall gain in the first section).
        """
        from scipy import signal

        dtype = np.dtype(dtype)
        if dtype not in (np.dtype(np.float64), np.dtype(np.float32)):
            raise ParameterError(f"to_sos dtype must be float64 or float32, got {dtype}", name="dtype", value=dtype)
        num = np.trim_zeros(np.asarray(self.num, dtype=float), "f")
        if num.size == 0:  # the zero filter (e.g. an observer path that is not used)
            sos = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
        elif self.order == 0:
            sos = np.array([[self.num[-1] / self.den[0], 0.0, 0.0, 1.0, 0.0, 0.0]])
        else:
            # tf2sos would strip a leading b0 = 0 (strictly proper, e.g. ZOH) and so advance the
            # output by one sample. Build H(z) z^d from zeros/poles instead (zpk2sos pads zeros at
            # the origin: factors z), then take the d delays back out of sections with b2 == 0.
            delay = len(self.num) - num.size
            sos = signal.zpk2sos(np.roots(num), np.roots(self.den), num[0] / self.den[0])
            for sec in sos:
                while delay > 0 and sec[2] == 0.0 and np.any(sec[:3] != 0.0):
                    sec[1:3] = sec[0:2].copy()
                    sec[0] = 0.0
                    delay -= 1
            if delay:  # pragma: no cover - zpk2sos always pads enough origin zeros
                raise ParameterError(f"to_sos: could not place {delay} delays in the sections",
                                     name="num", value=self.num)
        return np.ascontiguousarray(sos, dtype=dtype)

    def to_mapping(self) -> dict[str, Any]:
        """Coefficients and provenance (for JSON and the C export header)."""
        return {
            "num": list(self.num), "den": list(self.den), "rate_hz": self.rate_hz,
            "method": self.method, "prewarp_hz": self.prewarp_hz, "name": self.name,
            "source": {"num": list(self.source.num), "den": list(self.source.den)},
        }


def discretize(tf: RationalTF, rate_hz: float, method: str = "tustin",
               prewarp_hz: float | None = None) -> DiscreteTF:
    """Discretise a continuous, proper transfer function.

    Parameters
    ----------
    tf : RationalTF
        Continuous-time TF (``tf.dt is None``), proper (deg num <= deg den).
    rate_hz : float
        Sampling rate [Hz]; T = 1 / rate_hz [s].
    method : str
        ``tustin`` (default), ``zoh``, ``backward-euler`` or ``forward-euler``.
    prewarp_hz : float, optional
        Tustin only: frequency [Hz] at which the discrete response equals the
        continuous one exactly; must be below rate_hz / 2.

    Returns
    -------
    DiscreteTF
        Monic-denominator discrete TF recording method, rate and prewarp.

    Raises
    ------
    ParameterError
        Unknown method, non-positive rate, improper or discrete ``tf``, prewarp
        with a method other than Tustin or at/above Nyquist.

    Notes
    -----
    Tustin substitutes ``s = c (z - 1) / (z + 1)`` with ``c = 2 / T``, or
    ``c = w_p / tan(w_p T / 2)`` with prewarp ``w_p = 2 pi prewarp_hz``.
    Backward Euler substitutes ``s = (z - 1) / (T z)``, forward Euler
    ``s = (z - 1) / T``; both multiply through by the needed power of z.
    ZOH is exact for piecewise-constant inputs:
    ``exp([[A, B], [0, 0]] T)`` of a state-space realisation.

    Examples
    --------
    >>> d = discretize(RationalTF([1.0], [0.1, 1.0]), 1000.0, "zoh")
    >>> round(d.den[1], 12) == round(-math.exp(-0.01), 12)
    True
    """
    if not isinstance(tf, RationalTF) or tf.dt is not None:
        raise ParameterError(f"discretize needs a continuous RationalTF, got {tf!r}", name="tf", value=tf)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) or not (rate_hz > 0.0) \
            or not math.isfinite(rate_hz):
        raise ParameterError(f"discretize rate_hz must be > 0 [Hz], got {rate_hz!r}", name="rate_hz", value=rate_hz)
    if method not in METHODS:
        raise ParameterError(f"discretize method must be one of {', '.join(METHODS)}, got {method!r}",
                             name="method", value=method)
    if tf.relative_degree < 0:
        raise ParameterError(
            f"discretize: {tf.name or 'tf'} is improper (numerator degree {len(tf.num) - 1} > "
            f"denominator degree {len(tf.den) - 1}); add a filter pole",
            name="tf", value=tf,
        )
    if prewarp_hz is not None:
        if method != "tustin":
            raise ParameterError(f"discretize prewarp_hz applies to tustin only, got method {method!r}",
                                 name="prewarp_hz", value=prewarp_hz)
        if not (0.0 < prewarp_hz < rate_hz / 2.0):
            raise ParameterError(f"discretize prewarp_hz must be in (0, rate_hz/2 = {rate_hz / 2.0}) [Hz], "
                                 f"got {prewarp_hz!r}", name="prewarp_hz", value=prewarp_hz)
    rate_hz = float(rate_hz)
    dt = 1.0 / rate_hz
    order = len(tf.den) - 1
    num_s = tuple(tf.num)
    if method == "zoh":
        numz, denz = _zoh(num_s, tf.den, dt)
    else:
        if method == "tustin":
            if prewarp_hz is None:
                c = 2.0 / dt
            else:
                wp = 2.0 * math.pi * prewarp_hz
                c = wp / math.tan(wp * dt / 2.0)
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


class DiscreteFilter:
    """A running discrete filter: second-order sections in DF-II-transposed form.

    Parameters
    ----------
    dtf : DiscreteTF or ndarray
        The discrete TF (converted with :meth:`DiscreteTF.to_sos`) or an SOS
        array of shape (n_sections, 6).
    dtype : numpy dtype
        ``np.float64`` (default) or ``np.float32``: coefficients, states and
        arithmetic (float32 emulates a C ``float`` implementation).

    Notes
    -----
    The recursion is the module docstring's, implemented once in
    :func:`sos_step`; the simulator calls the same function. This object is
    stateful on purpose (it is a running filter); the coefficients are
    read-only.
    """

    __slots__ = ("sos", "state", "dtf")

    def __init__(self, dtf: DiscreteTF | np.ndarray, dtype: Any = np.float64) -> None:
        if isinstance(dtf, DiscreteTF):
            sos = dtf.to_sos(dtype)
            self.dtf = dtf
        else:
            sos = np.ascontiguousarray(np.atleast_2d(np.asarray(dtf)), dtype=dtype)
            if sos.ndim != 2 or sos.shape[1] != 6 or not np.all(sos[:, 3] == 1.0):
                raise ParameterError("DiscreteFilter sos must have shape (n, 6) with a0 == 1 in column 3",
                                     name="sos", value=dtf)
            self.dtf = None
        sos.flags.writeable = False
        self.sos = sos
        self.state = np.zeros((sos.shape[0], 2), dtype=sos.dtype)

    def reset(self) -> None:
        """Zero the states."""
        self.state[:] = 0.0

    def step(self, x: float) -> float:
        """Filter one sample; return the output."""
        return float(sos_step(self.sos, self.state, self.sos.dtype.type(x)))

    def filter(self, x: np.ndarray) -> np.ndarray:
        """Filter a whole array from the current state (the state is advanced).

        Parameters
        ----------
        x : ndarray, shape (n,)
            Input samples.

        Returns
        -------
        ndarray, shape (n,)
            Output samples (in the filter dtype).
        """
        x = np.ascontiguousarray(x, dtype=self.sos.dtype)
        y = np.empty_like(x)
        sos_filter(self.sos, self.state, x, y)
        return y
