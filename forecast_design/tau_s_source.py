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

__all__ = ["TauSSource", "classify_tau_s", "significant_digits", "tau_s_source_of", "printed_quantum",
           "DERIVED_MAX_BEYOND", "MEASURED_MIN_BEYOND"]


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
    """Half a unit in the last written decimal place of each value at ``digits`` significant digits [same unit]."""
    a = np.abs(np.asarray(values, dtype=float))
    exp10 = np.floor(np.log10(np.where(a > 0, a, 1.0)))
    return np.where(a > 0, 0.5 * 10.0 ** (exp10 - digits + 1), 0.0) + 4.0 * np.finfo(float).eps * a


def printed_quantum(values: np.ndarray) -> np.ndarray:
    """The rounding step each value can have been written with, whatever the logger's rule [same unit].

    The place of a value's last written digit (its shortest round-trip decimal representation)
    bounds the logger's rounding step from above, for every decimal rule at once: a fixed
    number of significant digits (``%.6g``), of decimal places (``%.4f``: small values keep
    fewer significant digits), or any other; a trailing zero the printer dropped only makes the
    bound looser. A value that is exactly a float32 (a logger or board that stores float32, whose
    decimal representation looks like 17 digits) may carry a float32 rounding of half its ulp. A
    zero gets the column's finest step (a fixed-decimal logger prints small values as zero).

    Parameters
    ----------
    values : ndarray
        The column as parsed (any unit).

    Returns
    -------
    ndarray, same shape
        The step [same unit].
    """
    v = np.asarray(values, dtype=float).ravel()
    out = np.zeros(v.size)
    for i, x in enumerate(v.tolist()):
        if x == 0.0 or not math.isfinite(x):
            continue
        mant, _, ex = repr(abs(x)).lower().partition("e")
        whole, _, frac = mant.partition(".")
        frac = frac.rstrip("0")
        if frac:
            place = -len(frac)
        else:
            place = len(whole) - len(whole.rstrip("0"))
        out[i] = 10.0 ** (place + (int(ex) if ex else 0))
    f32 = (v.astype(np.float32).astype(float) == v) & (v != 0.0)
    if np.any(f32):
        out[f32] = np.maximum(out[f32], np.spacing(np.abs(v[f32]).astype(np.float32)).astype(float))
    # a printed zero is anything below half the finest step of the column: with fixed decimals 0.0000
    # stands for |x| < 5e-5 (with significant digits a zero is exact, and the finest step is tiny)
    zero = (v == 0.0) & np.isfinite(v)
    if np.any(zero) and np.any(out > 0):
        out[zero] = float(np.min(out[out > 0]))
    return out.reshape(np.shape(values))


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
        Significant digits the column was written with (the most any value needs) [-].
    k_log : float or None
        Stiffness the column is consistent with [N m/rad] (a logger may use another
        ``k`` than the TOML's).
    excess : float or None
        RMS of ``tau_s - k_log (theta - q) - c`` divided by the RMS rounding error the
        printed values allow (:func:`printed_quantum` of ``tau_s``, ``theta`` and ``q``) [-].
    offset_N_m, offset_std_N_m : float or None
        The fitted constant ``c`` (a torque sensor's zero, or one the logger applied) and its
        standard error [N m].
    beyond_rounding : float or None
        Fraction of the rows whose ``|tau_s - k_log (theta - q) - c|`` exceeds the rounding those
        rows' printed digits allow [-]: 0 for a column the logger derived (any rounding rule),
        most rows for a sensor whose noise is above its printing step.
    uncertain : bool
        The decision is not clear-cut (between :data:`DERIVED_MAX_BEYOND` and
        :data:`MEASURED_MIN_BEYOND` of the rows beyond rounding): the diagnosis tries both readings.
    """

    source: str
    digits: int | None = None
    k_log: float | None = None
    excess: float | None = None
    offset_N_m: float | None = None
    offset_std_N_m: float | None = None
    beyond_rounding: float | None = None
    uncertain: bool = False

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
                "offset_N_m": self.offset_N_m, "beyond_rounding": self.beyond_rounding,
                "uncertain": self.uncertain}


#: Largest fraction of rows beyond their printed rounding for a column judged derived [-].
DERIVED_MAX_BEYOND = 1e-3
#: Smallest fraction of rows beyond their printed rounding for a column judged measured without doubt [-].
MEASURED_MIN_BEYOND = 0.05
#: Rows inspected by the decision (evenly spaced) [-].
CLASSIFY_ROWS = 4000


def classify_tau_s(derived: bool, tau_s: np.ndarray, theta: np.ndarray, q: np.ndarray) -> TauSSource:
    """Decide from the data, at the precision the file has, whether ``tau_s`` is a measurement.

    The experiment format allows both readings: on the Forecast testbed the logger
    computes ``tau_s = k (theta - q)`` itself and prints it; a testbed with a torque sensor
    writes an independent measurement. Rule: fit ``tau_s = k_log (theta - q) + c`` by least
    squares; a row is *beyond rounding* when what is left exceeds half the rounding step its
    printed values allow, ``(q_tau + |k_log| (q_theta + q_q)) / 2`` (:func:`printed_quantum`:
    the last written digit of each value, which bounds the step of any decimal rule, fixed
    significant digits or fixed decimals, and float32 storage), plus a floating-point floor of
    1e-12 of the column's RMS (a column computed in double precision leaves least-squares
    round-off of a few ulps, which no torque sensor agrees to). A logger-derived column has no
    row beyond rounding, whatever its rule; a sensor whose noise is above its printing step has
    most. The column is *derived* when at most :data:`DERIVED_MAX_BEYOND` of the rows are beyond
    rounding, *measured* otherwise, and the decision is *uncertain* below
    :data:`MEASURED_MIN_BEYOND` (a sensor quieter than its print step: the diagnosis then tries
    both readings).

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
    tau_s, theta, q = (np.asarray(a, dtype=float) for a in (tau_s, theta, q))
    x = theta - q
    A = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, tau_s, rcond=None)
    left = tau_s - A @ coef
    digits = significant_digits(tau_s)
    rows = np.arange(0, tau_s.size, max(1, tau_s.size // CLASSIFY_ROWS))
    step = (printed_quantum(tau_s[rows]) + abs(coef[0]) * (printed_quantum(theta[rows]) + printed_quantum(q[rows])))
    rms = float(np.sqrt(np.mean(tau_s ** 2))) if tau_s.size else 0.0
    expected = float(np.sqrt(np.mean((step / np.sqrt(12.0)) ** 2))) if rows.size else 0.0
    expected = max(expected, 1e-12 * rms)
    actual = float(np.sqrt(np.mean(left ** 2)))
    excess = actual / expected if expected > 0 else (0.0 if actual == 0 else math.inf)
    # standard errors of k_log and c: the residual (or, if smaller, the rounding) level over the design
    level = max(actual, expected)
    cov = np.linalg.pinv(A.T @ A) * level ** 2
    half = 0.5 * step + 1e-12 * rms + 8.0 * np.finfo(float).eps * np.abs(tau_s[rows])
    # the line a logger could have used: the least-squares one is pulled by rounding errors that repeat
    # (a motor at rest prints the same value for many rows), so the line whose largest rounding-scaled
    # residual is smallest is searched (a linear programme in k and c) and the rows beyond it counted
    kc = _chebyshev_line(A[rows], tau_s[rows], half, coef)
    beyond = float(np.mean(np.abs(tau_s[rows] - A[rows] @ kc) > half)) if rows.size else 0.0
    source = "derived" if beyond <= DERIVED_MAX_BEYOND else "measured"
    uncertain = DERIVED_MAX_BEYOND < beyond < MEASURED_MIN_BEYOND
    return TauSSource(source=source, digits=digits, k_log=float(coef[0]), excess=float(excess),
                      offset_N_m=float(coef[1]), offset_std_N_m=float(math.sqrt(cov[1, 1])),
                      beyond_rounding=beyond, uncertain=uncertain)


def _chebyshev_line(A: np.ndarray, y: np.ndarray, half: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``(k, c)`` minimising ``max |y - A (k, c)| / half`` (HiGHS linear programme), near ``start``.

    Solved for the change from ``start`` with both unknowns and the constraints scaled to order one;
    ``start`` is returned when the solver fails or does no better.
    """
    from scipy.optimize import linprog

    if y.size == 0 or not np.all(half > 0):
        return start
    r = (y - A @ start) / half
    Z = A / half[:, None]
    scale = np.max(np.abs(Z), axis=0)
    scale[scale == 0] = 1.0
    Zs = Z / scale
    # variables (du, dv, t): |r - Zs (du, dv)| <= 1 + t, minimise t
    ones = np.ones((y.size, 1))
    A_ub = np.vstack([np.hstack([-Zs, -ones]), np.hstack([Zs, -ones])])
    b_ub = np.concatenate([1.0 - r, 1.0 + r])
    bound = float(np.max(np.abs(r))) + 1.0
    res = linprog(c=[0.0, 0.0, 1.0], A_ub=A_ub, b_ub=b_ub, method="highs",
                  bounds=[(-bound, bound), (-bound, bound), (None, None)])
    if res.status != 0:
        return start
    kc = start + res.x[:2] / scale
    return kc if np.max(np.abs(y - A @ kc) / half) <= np.max(np.abs(r)) else start


def tau_s_source_of(experiment) -> TauSSource:
    """:func:`classify_tau_s` of an :class:`~forecast_design.experiment.Experiment`'s columns."""
    sig = experiment.signals
    theta = np.asarray(sig.theta, dtype=float)
    q = np.zeros_like(theta) if experiment.design.environment.locked else np.asarray(sig.q, dtype=float)
    return classify_tau_s(sig.tau_s_derived, np.asarray(sig.tau_s, dtype=float), theta, q)
