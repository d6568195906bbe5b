"""Velocity and acceleration from encoder positions, and parallel decimation (IDIM practice).

The recipe follows the inverse-dynamic identification practice used for the
EMPS benchmark (Janot, Gautier, Brunot 2019):

1. zero-phase Butterworth low-pass (``scipy.signal.filtfilt``, order 4) on the
   position, cut-off ``position_cutoff_hz`` (default ``rate_hz / 10``: 100 Hz at
   1 kHz, 200 Hz at 2 kHz);
2. central differences (``numpy.gradient``) for velocity and acceleration;
3. drop ``edge_samples`` at each end, where the filter transients live
   (default ``round(5 rate_hz / position_cutoff_hz) - 1``: 49 samples, as in
   the EMPS script);
4. *parallel decimation*: the force and every regressor column go through
   the same zero-phase low-pass and are down-sampled by
   ``decimation_factor`` (default 10), with ``scipy.signal.decimate`` (order-8
   Chebyshev I, ``filtfilt``), cut-off ``0.8 * (rate_hz / 2) / decimation_factor``
   (40 Hz at 1 kHz, 80 Hz at 2 kHz).

Because the low-pass is linear and applied to the force and to every column
alike, it does not bias a model linear in its parameters, and it removes the
force noise above the band of the rigid-body dynamics.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import signal

from ..errors import ParameterError

__all__ = ["FilterSettings", "Kinematics", "default_filter_settings", "differentiate", "decimate_columns", "antialias",
           "settling_samples", "lowpass"]

DECIMATION_MODES = ("parallel", "subsample")


@dataclass(frozen=True, slots=True, kw_only=True)
class FilterSettings:
    """Filtering and decimation used to build the identification data.

    Parameters
    ----------
    rate_hz : float
        Sample rate of the raw log [Hz].
    position_cutoff_hz : float
        Cut-off of the zero-phase Butterworth low-pass on the position [Hz].
    filter_order : int
        Order of that Butterworth filter (applied forward and backward, so the
        magnitude response is squared) [-].
    decimation_factor : int
        Down-sampling factor R >= 1 [-].
    edge_samples : int
        Raw samples dropped at each end (filter transients) [-].
    decimation : str
        ``"parallel"``: zero-phase Chebyshev low-pass on force and regressors,
        then down-sampling (linear models). ``"subsample"``: down-sampling only;
        used for nonlinear models, whose force cannot be low-passed column by
        column without smearing the Coulomb jump the model reproduces exactly.
    """

    rate_hz: float
    position_cutoff_hz: float
    filter_order: int = 4
    decimation_factor: int = 10
    edge_samples: int = 49
    decimation: str = "parallel"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ParameterError(f"rate_hz must be > 0 [Hz], got {self.rate_hz!r}", name="rate_hz",
                                 value=self.rate_hz)
        nyq = self.rate_hz / 2.0
        if not (0.0 < self.position_cutoff_hz < nyq):
            raise ParameterError(
                f"position_cutoff_hz must lie in (0, {nyq:g}) [Hz] at rate {self.rate_hz:g} Hz, "
                f"got {self.position_cutoff_hz!r}", name="position_cutoff_hz", value=self.position_cutoff_hz)
        for name in ("filter_order", "decimation_factor"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ParameterError(f"{name} must be an integer >= 1, got {value!r}", name=name, value=value)
        if isinstance(self.edge_samples, bool) or not isinstance(self.edge_samples, (int, np.integer)) \
                or self.edge_samples < 0:
            raise ParameterError(f"edge_samples must be an integer >= 0, got {self.edge_samples!r}",
                                 name="edge_samples", value=self.edge_samples)
        if self.decimation not in DECIMATION_MODES:
            raise ParameterError(f"decimation must be one of {', '.join(DECIMATION_MODES)}, "
                                 f"got {self.decimation!r}", name="decimation", value=self.decimation)

    @property
    def decimation_cutoff_hz(self) -> float:
        """Cut-off of the decimation low-pass [Hz] (``inf`` when not filtering)."""
        if self.decimation_factor == 1 or self.decimation == "subsample":
            return float("inf")
        return 0.8 * (self.rate_hz / 2.0) / self.decimation_factor

    @property
    def decimated_rate_hz(self) -> float:
        """Sample rate after decimation [Hz]."""
        return self.rate_hz / self.decimation_factor

    def to_mapping(self) -> dict:
        """JSON-ready mapping of the settings, with the derived decimation cut-off [Hz]."""
        cut = self.decimation_cutoff_hz
        return {
            "rate_hz": self.rate_hz,
            "position_cutoff_hz": self.position_cutoff_hz,
            "filter_order": int(self.filter_order),
            "decimation": self.decimation,
            "decimation_factor": int(self.decimation_factor),
            "decimation_cutoff_hz": None if not np.isfinite(cut) else cut,
            "edge_samples": int(self.edge_samples),
        }


def default_filter_settings(rate_hz: float, *, position_cutoff_hz: float | None = None,
                            decimation_factor: int | None = None, edge_samples: int | None = None,
                            filter_order: int = 4, decimation: str = "parallel") -> FilterSettings:
    """IDIM filter settings scaled to the sample rate.

    Parameters
    ----------
    rate_hz : float
        Sample rate of the log [Hz].
    position_cutoff_hz : float, optional
        Butterworth cut-off on position [Hz]; default ``rate_hz / 10``
        (100 Hz at 1 kHz as in the EMPS reference, 200 Hz at 2 kHz).
    decimation_factor : int, optional
        Default 10 (EMPS: round(0.8 * 500 / 40) = 10), i.e. decimation
        cut-off 0.04 rate_hz (40 Hz at 1 kHz).
    edge_samples : int, optional
        Default ``round(5 rate_hz / position_cutoff_hz) - 1`` (49 at 1 kHz/100 Hz).
    filter_order : int
        Butterworth order [-], default 4.
    decimation : str
        ``"parallel"`` or ``"subsample"`` (see :class:`FilterSettings`).

    Returns
    -------
    FilterSettings
        The settings.

    Examples
    --------
    >>> s = default_filter_settings(1000.0)
    >>> s.position_cutoff_hz, s.decimation_factor, s.decimation_cutoff_hz, s.edge_samples
    (100.0, 10, 40.0, 49)
    """
    rate_hz = float(rate_hz)
    fc = rate_hz / 10.0 if position_cutoff_hz is None else float(position_cutoff_hz)
    R = 10 if decimation_factor is None else decimation_factor
    edge = max(0, int(round(5.0 * rate_hz / fc)) - 1) if edge_samples is None else edge_samples
    return FilterSettings(rate_hz=rate_hz, position_cutoff_hz=fc, filter_order=filter_order,
                          decimation_factor=R, edge_samples=edge, decimation=decimation)


@dataclass(frozen=True, slots=True)
class Kinematics:
    """Filtered position and its derivatives at the raw rate.

    Parameters
    ----------
    position : ndarray, shape (n,)
        Low-passed position [rad].
    velocity : ndarray, shape (n,)
        Velocity [rad/s].
    acceleration : ndarray, shape (n,)
        Acceleration [rad/s^2].
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@lru_cache(maxsize=32)
def _butterworth(order: int, wn: float, output: str) -> tuple[np.ndarray, ...]:
    out = signal.butter(order, wn, output=output)
    return tuple(out) if output == "ba" else (out,)


def butterworth(order: int, wn: float, output: str = "ba") -> tuple[np.ndarray, ...]:
    """``scipy.signal.butter(order, wn, output=output)``, designed once per argument set.

    Parameters
    ----------
    order : int
        Filter order [-].
    wn : float
        Cut-off as a fraction of Nyquist [-].
    output : str
        ``"ba"`` (returns ``(b, a)``) or ``"sos"`` (returns ``(sos,)``).

    Returns
    -------
    tuple of ndarray
        Copies of the cached coefficients (scipy's filters need writable arrays).
    """
    return tuple(arr.copy() for arr in _butterworth(int(order), float(wn), output))


def _lowpass(x: np.ndarray, settings: FilterSettings) -> np.ndarray:
    b, a = butterworth(settings.filter_order, settings.position_cutoff_hz / (settings.rate_hz / 2.0))
    return signal.filtfilt(b, a, x, axis=0)


def lowpass(x: np.ndarray, settings: FilterSettings) -> np.ndarray:
    """The position filter (zero-phase Butterworth) applied along axis 0 of `x`.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, k)
        Signals at ``settings.rate_hz``.
    settings : FilterSettings
        Cut-off and order.

    Returns
    -------
    ndarray
        Filtered signals, same shape.
    """
    return _lowpass(np.asarray(x, dtype=float), settings)


def differentiate(position: np.ndarray, settings: FilterSettings, *,
                  velocity: np.ndarray | None = None) -> Kinematics:
    """Zero-phase low-pass the position and take central differences.

    Parameters
    ----------
    position : ndarray, shape (n,)
        Encoder position [rad] (or [m]), uniformly sampled at ``settings.rate_hz``.
    settings : FilterSettings
        Butterworth cut-off and order.
    velocity : ndarray, shape (n,), optional
        A measured velocity [rad/s]; when given it is low-passed the same way and
        differentiated once for the acceleration instead of differentiating
        position twice.

    Returns
    -------
    Kinematics
        Filtered position, velocity and acceleration, full length (edges are
        dropped later, together with the force).
    """
    dt = 1.0 / settings.rate_hz
    x = np.asarray(position, dtype=float)
    n_min = 3 * (settings.filter_order + 1) + 1
    if x.size < n_min:
        raise ParameterError(f"position has {x.size} samples; need at least {n_min} for the filter",
                             name="position", value=x.size)
    xf = _lowpass(x, settings)
    if velocity is None:
        v = np.gradient(xf, dt)
    else:
        v = _lowpass(np.asarray(velocity, dtype=float), settings)
    a = np.gradient(v, dt)
    return Kinematics(position=xf, velocity=v, acceleration=a)


def decimate_columns(columns: np.ndarray, settings: FilterSettings, *, axis: int = 0) -> np.ndarray:
    """Drop filter edges and decimate every column alike (parallel decimation).

    Parameters
    ----------
    columns : ndarray, shape (n, k) (or (k, n) with ``axis=1``)
        Raw-rate signals: the force and the regressor columns.
    settings : FilterSettings
        ``edge_samples``, ``decimation_factor`` and ``decimation`` mode.
    axis : int
        The time axis, 0 or 1 (1 is faster for long logs: the filter runs
        along contiguous memory).

    Returns
    -------
    ndarray
        Decimated signals, time along `axis`, ``m ~ (n - 2 edge_samples) /
        decimation_factor`` samples.
    """
    X = np.asarray(columns, dtype=float)
    if axis not in (0, 1):
        raise ParameterError(f"axis must be 0 or 1, got {axis!r}", name="axis", value=axis)
    n = X.shape[axis]
    e = settings.edge_samples
    if n <= 2 * e + 1:
        raise ParameterError(f"log too short: {n} samples, {e} dropped at each end",
                             name="edge_samples", value=e)
    keep = slice(e, n - e)
    X = X[keep] if axis == 0 else X[:, keep]
    R = settings.decimation_factor
    if R == 1:
        return X
    if settings.decimation == "subsample":
        return X[::R] if axis == 0 else X[:, ::R]
    if X.shape[axis] <= 27 * R:
        raise ParameterError(f"log too short to decimate by {R}: {X.shape[axis]} samples",
                             name="decimation_factor", value=R)
    # ``signal.decimate(X, R, ftype="iir", axis=axis, zero_phase=True)`` with its Chebyshev
    # design made once per factor (scipy redesigns it on every call): bit-equal results.
    Y = antialias(X, settings, axis=axis)
    # a copy: a strided view would keep the whole raw-rate filter output alive (8 B per sample and column)
    return (Y[::R] if axis == 0 else Y[:, ::R]).copy()


def antialias(columns: np.ndarray, settings: FilterSettings, *, axis: int = -1) -> np.ndarray:
    """The parallel decimation's zero-phase anti-alias low-pass, without the subsampling.

    Parameters
    ----------
    columns : ndarray
        Raw-rate signals (any unit), time along `axis`.
    settings : FilterSettings
        ``decimation_factor`` R and ``decimation`` mode.
    axis : int
        The time axis.

    Returns
    -------
    ndarray
        The signals through scipy's ``decimate`` filter for R (Chebyshev I, order 8, cut-off
        0.8 / R of Nyquist, forward and backward); unchanged for R = 1 or ``subsample``.
    """
    X = np.asarray(columns, dtype=float)
    R = int(settings.decimation_factor)
    if R == 1 or settings.decimation == "subsample":
        return X
    sos, = _decimation_sos(R)
    return signal.sosfiltfilt(sos.copy(), X, axis=axis)


@lru_cache(maxsize=8)
def _decimation_sos(R: int) -> tuple[np.ndarray]:
    """The anti-alias filter of ``scipy.signal.decimate(..., ftype="iir")``: Chebyshev I, order 8."""
    return (np.asarray(signal.cheby1(8, 0.05, 0.8 / R, output="sos"), dtype=float),)


#: Fraction of its peak below which an impulse response counts as settled [-].
SETTLED = 0.01


def _halfwidth(sos: np.ndarray, n: int = 4096) -> int:
    """Half-width in samples of the zero-phase (sosfiltfilt) impulse response of ``sos``, at 1 % of its peak.

    Second-order sections: the transfer-function form of scipy's decimation filter is numerically unstable for
    decimation factors above about 60 (its half-width came out negative at R = 126, -3121 samples, and the
    filters' step response could not be formed). ``n`` samples on either side must hold the response.
    """
    x = np.zeros(2 * n + 1)
    x[n] = 1.0
    h = np.abs(signal.sosfiltfilt(np.asarray(sos, dtype=float), x, padtype=None))
    return int(np.flatnonzero(h > SETTLED * h.max()).max() - n)


@lru_cache(maxsize=64)
def settling_samples(settings: FilterSettings) -> tuple[int, int]:
    """How far (in raw samples) a jump in the log is smeared by the identification filters.

    Parameters
    ----------
    settings : FilterSettings
        The filters.

    Returns
    -------
    derivative : int
        Half-width of the zero-phase Butterworth's impulse response on the
        position (where it stays above 1 % of its peak) plus 2 samples for the
        two central differences: the acceleration ``theta''`` that is
        subtracted from the force feels a friction jump this far on either
        side (about ``0.9 rate_hz / position_cutoff_hz``, 20 samples at the
        default ``rate/10`` cut-off).
    decimation : int
        Half-width of the zero-phase Chebyshev decimation low-pass (1 %), 0
        without parallel decimation (148 samples for R = 10): the parallel
        decimation spreads whatever mismatch the first window holds this much
        further.
    """
    wn = settings.position_cutoff_hz / (settings.rate_hz / 2.0)
    sos, = butterworth(settings.filter_order, wn, output="sos")
    der = _halfwidth(sos, max(4096, int(np.ceil(40.0 / wn)))) + 2
    if not np.isfinite(settings.decimation_cutoff_hz):
        return der, 0
    R = int(settings.decimation_factor)
    sos_dec, = _decimation_sos(R)
    return der, _halfwidth(sos_dec, max(4096, 40 * R))
