"""What a log's ``tau_s`` column is: the logger's ``k (theta - q)`` or an independent torque measurement.

The experiment format allows both readings (on the Forecast testbed the logger computes
``tau_s = k (theta - q)`` itself and prints it with 6-10 significant digits; a testbed with a
torque sensor writes an independent measurement) and tells readers to decide from the data, at
the precision the file has. The gap diagnosis (which equations a log has) and the friction
identification (whether a sensor's zero offset is fitted) both read the decision from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TauSSource", "classify_tau_s", "significant_digits", "tau_s_source_of"]


def significant_digits(values: np.ndarray, *, sample: int = 4000) -> int:
    """Decimal significant digits a column was written with (the shortest round-trip repr).

    Parameters
    ----------
    values : ndarray
        Column as parsed (any unit).
    sample : int
        At most this many evenly spaced non-zero values are inspected [-].

    Returns
    -------
    int
        The largest number of significant digits any inspected value needs to
        round-trip (17 for binary doubles that were never printed) [-].
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v != 0.0)]
    if v.size == 0:
        return 17
    v = v[:: max(1, v.size // sample)]
    best = 1
    for x in v.tolist():
        mant = repr(x).lower().split("e")[0].replace("-", "").replace(".", "").lstrip("0")
        best = max(best, len(mant.rstrip("0")) or 1)
        if best >= 17:
            break
    return best


def _half_ulp(values: np.ndarray, digits: int) -> np.ndarray:
    """Half a unit in the last written decimal place of each value [same unit]."""
    a = np.abs(np.asarray(values, dtype=float))
    exp10 = np.floor(np.log10(np.where(a > 0, a, 1.0)))
    return np.where(a > 0, 0.5 * 10.0 ** (exp10 - digits + 1), 0.0) + 4.0 * np.finfo(float).eps * a


@dataclass(frozen=True, slots=True, kw_only=True)
class TauSSource:
    """Whether a log's ``tau_s`` column carries information beyond ``k (theta - q)``.

    Parameters
    ----------
    source : str
        ``absent`` (no column: derived by the reader), ``derived`` (the logger wrote
        ``k (theta - q)`` itself: the column equals a fitted ``k_log (theta - q) + c`` to
        within the rounding of the written digits), or ``measured`` (an independent torque
        measurement).
    digits : int or None
        Significant digits the column was written with [-].
    k_log : float or None
        Stiffness the column is consistent with [N m/rad] (a logger may use another
        ``k`` than the TOML's).
    excess : float or None
        RMS of ``tau_s - k_log (theta - q) - c`` divided by the RMS rounding error expected
        from the digits of ``tau_s``, ``theta`` and ``q`` [-]; <= 2 means derived.
    offset_N_m, offset_std_N_m : float or None
        The fitted constant ``c`` (a torque sensor's zero, or one the logger applied) and its
        standard error [N m].
    """

    source: str
    digits: int | None = None
    k_log: float | None = None
    excess: float | None = None
    offset_N_m: float | None = None
    offset_std_N_m: float | None = None

    @property
    def measured(self) -> bool:
        """True for an independent torque measurement."""
        return self.source == "measured"

    @property
    def zero_offset(self) -> bool:
        """True when the column carries a constant beyond ``k_log (theta - q)`` (over 3 standard errors)."""
        return (self.offset_N_m is not None and self.offset_N_m != 0.0
                and abs(self.offset_N_m) > 3.0 * (self.offset_std_N_m or 0.0))

    def to_mapping(self) -> dict:
        """JSON-ready mapping."""
        return {"source": self.source, "digits": self.digits, "k_log": self.k_log, "excess": self.excess,
                "offset_N_m": self.offset_N_m}


def classify_tau_s(derived: bool, tau_s: np.ndarray, theta: np.ndarray, q: np.ndarray) -> TauSSource:
    """Decide from the data, at the precision the file has, whether ``tau_s`` is a measurement.

    The experiment format allows both readings: on the Forecast testbed the logger
    computes ``tau_s = k (theta - q)`` itself and prints it with 6-10 significant
    digits; a testbed with a torque sensor writes an independent measurement. Rule:
    fit ``tau_s = k_log (theta - q) + c`` by least squares; the column is *derived*
    when the RMS of what is left is at most twice the RMS rounding error implied by
    the digits each of ``tau_s``, ``theta`` and ``q`` was written with (uniform
    rounding: ``half_ulp / sqrt(3)``), *measured* otherwise.

    Parameters
    ----------
    derived : bool
        True when the reader derived the column (it was absent from the file).
    tau_s, theta, q : ndarray, shape (n,)
        Logged columns [N m, rad, rad].

    Returns
    -------
    TauSSource
        The decision with its evidence.
    """
    if derived:
        return TauSSource(source="absent")
    x = theta - q
    A = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, tau_s, rcond=None)
    left = tau_s - A @ coef
    digits = significant_digits(tau_s)
    rounding = np.sqrt(_half_ulp(tau_s, digits) ** 2 + (coef[0] * _half_ulp(theta, significant_digits(theta))) ** 2
                       + (coef[0] * _half_ulp(q, significant_digits(q))) ** 2) / np.sqrt(3.0)
    # floating-point floor: a column computed in double precision (an in-memory log, 17 digits)
    # leaves least-squares round-off of a few ulps, which no torque sensor agrees to
    expected = max(float(np.sqrt(np.mean(rounding ** 2))), 1e-12 * float(np.sqrt(np.mean(tau_s ** 2))))
    actual = float(np.sqrt(np.mean(left ** 2)))
    excess = actual / expected if expected > 0 else (0.0 if actual == 0 else math.inf)
    # standard error of c: the residual (or, if smaller, the rounding) level over the design
    level = max(actual, expected)
    cov = np.linalg.pinv(A.T @ A) * level ** 2
    return TauSSource(source="derived" if excess <= 2.0 else "measured", digits=digits, k_log=float(coef[0]),
                      excess=float(excess), offset_N_m=float(coef[1]), offset_std_N_m=float(math.sqrt(cov[1, 1])))


def tau_s_source_of(experiment) -> TauSSource:
    """:func:`classify_tau_s` of an :class:`~forecast_design.experiment.Experiment`'s columns."""
    sig = experiment.signals
    theta = np.asarray(sig.theta, dtype=float)
    q = np.zeros_like(theta) if experiment.design.environment.locked else np.asarray(sig.q, dtype=float)
    return classify_tau_s(sig.tau_s_derived, np.asarray(sig.tau_s, dtype=float), theta, q)
