"""Exact frequency-domain extrema of a rational function on the imaginary axis, and root-locus intervals.

The one home of the polynomial reasoning behind the passivity analysis, in the style of the
exact disk margin (:mod:`forecast_design.margins.exact`): a quantity over frequency is a ratio
of polynomials in ``x = w^2``; its extrema are at the roots of a polynomial, its sign changes at
the roots of another, and nothing is sampled on a grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import polynomials as poly
from ..margins import STABILITY_TOLERANCE

__all__ = ["AxisRatio", "axis_real_part", "axis_magnitude", "real_part_minimum", "negative_bands",
           "magnitude_range", "is_hurwitz", "stable_parameter_intervals"]

# Roots of a polynomial in x with |Im x| up to this fraction of |x| are kept as candidates: a
# spurious candidate is harmless (every candidate is evaluated on the function itself), a dropped
# true one is not.
_ROOT_IMAG_RTOL = 1e-3
_NEWTON_STEPS = 12


def _scale(p: np.ndarray, w0: float) -> np.ndarray:
    """p(w0 s~) as coefficients in s~ (descending)."""
    return p * w0 ** np.arange(len(p) - 1, -1, -1)


def _frequency_scale(den: np.ndarray) -> float:
    """Geometric mean of the nonzero root magnitudes of ``den`` [rad/s] (1 without roots)."""
    d = poly.trim(den)
    nz = np.flatnonzero(d != 0.0)
    core = d[: nz[-1] + 1]
    m = len(core) - 1
    w0 = abs(core[-1] / core[0]) ** (1.0 / m) if m > 0 else 1.0
    return w0 if math.isfinite(w0) and w0 > 0.0 else 1.0


@dataclass(frozen=True, slots=True)
class AxisRatio:
    """``F(w) = P(w^2) / Q(w^2)`` with real polynomials P, Q in x = (w / w0)^2, times ``gain``.

    Built from a rational function ``num(s)/den(s)`` with ``s = w0 s~`` (frequency scaled for
    conditioning); ``F`` is ``Re`` or ``|.|^2`` of it on the imaginary axis.
    """

    P: np.ndarray
    Q: np.ndarray
    gain: float
    w0: float

    def at_x(self, x: np.ndarray) -> np.ndarray:
        """F at scaled ``x = (w / w0)^2`` (limits at x = 0 and inf handled by the caller)."""
        return self.gain * np.polyval(self.P, x) / np.polyval(self.Q, x)

    def limit_zero(self) -> float:
        """lim F as w -> 0+ (common powers of x divided out; +-inf at a pole)."""
        P, Q = self.P, self.Q
        m = min(poly.trailing_zeros(P), poly.trailing_zeros(Q))
        if m >= 10**9:
            return 0.0
        P, Q = poly.drop_trailing(P, m), poly.drop_trailing(Q, m)
        if Q[-1] == 0.0:
            return math.copysign(math.inf, self.gain * P[-1] * _sign_near_zero(Q))
        return float(self.gain * P[-1] / Q[-1])

    def limit_inf(self) -> float:
        """lim F as w -> inf."""
        P, Q = poly.trim(self.P), poly.trim(self.Q)
        if not np.any(P != 0.0):
            return 0.0
        if len(P) > len(Q):
            return math.copysign(math.inf, self.gain * P[0] / Q[0])
        if len(P) < len(Q):
            return 0.0
        return float(self.gain * P[0] / Q[0])


def _sign_near_zero(Q: np.ndarray) -> float:
    nz = np.flatnonzero(Q != 0.0)
    return float(np.sign(Q[nz[-1]])) if nz.size else 1.0


def _scaled(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    num, den = poly.trim(np.asarray(num, float)), poly.trim(np.asarray(den, float))
    w0 = _frequency_scale(den)
    ns, ds = _scale(num, w0), _scale(den, w0)
    fn, fd = float(np.max(np.abs(ns))) or 1.0, float(np.max(np.abs(ds)))
    return ns / fn, ds / fd, fn / fd, w0


def axis_real_part(num: np.ndarray, den: np.ndarray) -> AxisRatio:
    """``Re(num(jw)/den(jw))`` as a ratio of polynomials in ``x = (w / w0)^2``.

    Parameters
    ----------
    num, den : ndarray
        The rational function, descending powers of s.

    Returns
    -------
    AxisRatio
        ``P = Re(num conj den)``, ``Q = |den|^2`` (:func:`forecast_design.polynomials.cross_even`,
        :func:`~forecast_design.polynomials.abs2_even`).
    """
    ns, ds, g, w0 = _scaled(num, den)
    return AxisRatio(poly.cross_even(ns, ds), poly.abs2_even(ds), g, w0)


def axis_magnitude(num: np.ndarray, den: np.ndarray) -> AxisRatio:
    """``|num(jw)/den(jw)|^2`` as a ratio of polynomials in ``x = (w / w0)^2``.

    Parameters
    ----------
    num, den : ndarray
        The rational function, descending powers of s.

    Returns
    -------
    AxisRatio
        ``P = |num|^2``, ``Q = |den|^2`` (``gain`` is the squared scale).
    """
    ns, ds, g, w0 = _scaled(num, den)
    return AxisRatio(poly.abs2_even(ns), poly.abs2_even(ds), g * g, w0)


def _positive_real_roots(p: np.ndarray) -> np.ndarray:
    p = poly.trim(p)
    if len(p) <= 1:
        return np.zeros(0)
    r = np.roots(p)
    keep = (np.abs(r.imag) <= _ROOT_IMAG_RTOL * np.abs(r) + 1e-12) & (r.real > 0.0)
    return np.sort(r.real[keep])


def _polish_root(p: np.ndarray, x: float) -> float:
    """Newton steps on the polynomial ``p`` from ``x`` (kept when the residual does not grow)."""
    dp = poly.derivative(p)
    best, fbest = x, abs(np.polyval(p, x))
    for _ in range(_NEWTON_STEPS):
        d = np.polyval(dp, x)
        if d == 0.0 or not math.isfinite(d):
            break
        x_new = x - np.polyval(p, x) / d
        if not (x_new > 0.0 and math.isfinite(x_new)):
            break
        x = x_new
        f = abs(np.polyval(p, x))
        if f < fbest:
            best, fbest = x, f
        if f == 0.0:
            break
    return float(best)


def _stationary(F: AxisRatio) -> np.ndarray:
    """Positive roots x of d/dx (P/Q) = (P'Q - PQ')/Q^2, polished on the stationarity polynomial."""
    S = poly.trim(poly.sub(np.convolve(poly.derivative(F.P), F.Q), np.convolve(F.P, poly.derivative(F.Q))))
    return np.array([_polish_root(S, x) for x in _positive_real_roots(S)])


def real_part_minimum(num: np.ndarray, den: np.ndarray) -> tuple[float, float]:
    """``min over w >= 0 of Re(num(jw)/den(jw))`` and where, exactly (no grid).

    Parameters
    ----------
    num, den : ndarray
        The rational function, descending powers of s.

    Returns
    -------
    (float, float)
        The minimum (unit of the function) and its frequency [rad/s] (``inf`` when the infimum
        is the limit at infinite frequency, 0 at w -> 0).

    Notes
    -----
    ``Re F(jw) = P(x)/Q(x)`` with ``x = w^2`` (:func:`axis_real_part`); its stationary points are
    the positive roots of ``P'Q - PQ'``; the infimum is the least value over them, over w -> 0 and
    over w -> inf. The roots are polished by Newton steps on the stationarity polynomial and every
    candidate is evaluated on ``P/Q`` itself.
    """
    F = axis_real_part(num, den)
    xs = _stationary(F)
    cands = [(F.limit_zero(), 0.0), (F.limit_inf(), math.inf)]
    if xs.size:
        vals = F.at_x(xs)
        cands += [(float(v), float(math.sqrt(x) * F.w0)) for v, x in zip(vals, xs) if math.isfinite(v)]
    value, w = min(cands, key=lambda c: c[0])
    return float(value), float(w)


def _sign_intervals(F: AxisRatio) -> list[tuple[float, float, float]]:
    """(x_lo, x_hi, value inside) for the intervals between sign changes of P (scaled x)."""
    roots = sorted({_polish_root(poly.trim(F.P), x) for x in _positive_real_roots(F.P)})
    edges = [0.0, *roots, math.inf]
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if lo == 0.0:
            mid = 1.0 if math.isinf(hi) else 0.5 * hi
        else:
            mid = 2.0 * lo if math.isinf(hi) else math.sqrt(lo * hi)
        out.append((lo, hi, float(F.at_x(np.array([mid]))[0])))
    return out


def negative_bands(num: np.ndarray, den: np.ndarray) -> list[tuple[float, float]]:
    """Frequency bands where ``Re(num(jw)/den(jw)) < 0``, exactly.

    Parameters
    ----------
    num, den : ndarray
        The rational function, descending powers of s.

    Returns
    -------
    list of (float, float)
        ``(w_lo, w_hi)`` [rad/s], ascending; ``w_hi`` may be ``inf``. The edges are the positive
        roots of ``Re(num conj den)(x)`` (x = w^2); the sign inside each interval between two
        edges is the sign at one interior point (constant there).
    """
    F = axis_real_part(num, den)
    bands: list[list[float]] = []
    for lo, hi, v in _sign_intervals(F):
        if v < 0.0:
            if bands and bands[-1][1] == lo:
                bands[-1][1] = hi
            else:
                bands.append([lo, hi])
    w = lambda x: float(math.sqrt(x) * F.w0) if math.isfinite(x) else math.inf  # noqa: E731
    return [(w(lo), w(hi)) for lo, hi in bands]


def magnitude_range(num: np.ndarray, den: np.ndarray, w_lo: float, w_hi: float) -> tuple[float, float]:
    """Least and greatest ``|num(jw)/den(jw)|`` over ``w_lo <= w <= w_hi``, exactly.

    Parameters
    ----------
    num, den : ndarray
        The rational function, descending powers of s.
    w_lo, w_hi : float
        The band [rad/s] (``w_hi`` may be ``inf``).

    Returns
    -------
    (float, float)
        min and max of the magnitude (unit of the function): over the band's ends and the
        stationary points of ``|F|^2`` inside it.
    """
    F = axis_magnitude(num, den)
    x_lo, x_hi = (w_lo / F.w0) ** 2, (w_hi / F.w0) ** 2
    vals = []
    for x in (x_lo, x_hi):
        if x == 0.0:
            vals.append(F.limit_zero())
        elif math.isinf(x):
            vals.append(F.limit_inf())
        else:
            vals.append(float(F.at_x(np.array([x]))[0]))
    xs = _stationary(F)
    xs = xs[(xs > x_lo) & (xs < x_hi)]
    if xs.size:
        vals += [float(v) for v in F.at_x(xs)]
    vals = [math.sqrt(max(v, 0.0)) for v in vals]
    return min(vals), max(vals)


def is_hurwitz(p: np.ndarray) -> bool:
    """Every root of ``p`` has ``Re < -STABILITY_TOLERANCE max(1, |root|)`` (the loops' test).

    Parameters
    ----------
    p : ndarray
        Polynomial, descending powers of s.

    Returns
    -------
    bool
        Strict stability (a constant is stable).
    """
    p = poly.trim(np.asarray(p, float))
    if len(p) <= 1:
        return bool(p[0] != 0.0)
    r = np.roots(p)
    return bool(np.all(r.real < -STABILITY_TOLERANCE * np.maximum(1.0, np.abs(r))))


def stable_parameter_intervals(a: np.ndarray, b: np.ndarray, lo: float = 0.0,
                               hi: float = math.inf) -> list[tuple[float, float]]:
    """The values ``p`` in ``[lo, hi)`` for which ``a(s) + p b(s)`` is Hurwitz, as intervals (no sampling).

    Parameters
    ----------
    a, b : ndarray
        Polynomials, descending powers of s.
    lo, hi : float
        The parameter's domain (``hi`` may be ``inf``).

    Returns
    -------
    list of (float, float)
        Maximal intervals of stability, ascending. Inside each, every value is stable; an end is a
        value where a root of ``a + p b`` is on the imaginary axis (or the domain's end, or the
        value where the degree drops).

    Notes
    -----
    A root crosses the imaginary axis at ``s = jw`` only where ``a(jw) + p b(jw) = 0`` with ``p``
    real: ``Im(a conj b)(jw) = 0``, whose positive roots in ``x = w^2`` are those of
    ``Re(a conj (s b))`` (:func:`forecast_design.polynomials.cross_even`), giving
    ``p = -Re(a conj b)/|b|^2`` there; at ``w = 0``, ``p = -a(0)/b(0)``; the degree drops at
    ``p = -a_0/b_0`` when both have the same degree. Between two consecutive critical values the
    number of unstable roots is constant, so one evaluation decides each interval (the root locus
    of ``a + p b``).
    """
    a, b = poly.trim(np.asarray(a, float)), poly.trim(np.asarray(b, float))
    n = max(len(a), len(b))
    A, B = poly.pad(a, n), poly.pad(b, n)
    w0 = _frequency_scale(A + B if np.any(A + B) else A)
    As, Bs = _scale(A, w0), _scale(B, w0)
    fa, fb = float(np.max(np.abs(As))) or 1.0, float(np.max(np.abs(Bs))) or 1.0
    As, Bs = As / fa, Bs / fb                       # a + p b = fa (As + (p fb / fa) Bs)
    crit: list[float] = []
    Im = poly.cross_even(As, np.concatenate([Bs, [0.0]]))
    Re, Mb = poly.cross_even(As, Bs), poly.abs2_even(Bs)
    for x in _positive_real_roots(Im):
        x = _polish_root(poly.trim(Im), x)
        mb = np.polyval(Mb, x)
        if mb > 0.0:
            crit.append(-np.polyval(Re, x) / mb * fa / fb)
    if Bs[-1] != 0.0:
        crit.append(-As[-1] / Bs[-1] * fa / fb)
    if As[0] != 0.0 and Bs[0] != 0.0:
        crit.append(-As[0] / Bs[0] * fa / fb)
    crit = sorted({float(c) for c in crit if lo < c < hi and math.isfinite(c)})
    edges = [lo, *crit, hi]
    stable = []
    for e0, e1 in zip(edges[:-1], edges[1:]):
        if math.isfinite(e1):
            mid = 0.5 * (e0 + e1)
        else:
            mid = 2.0 * e0 if e0 > 0.0 else max(e0, 0.0) + fa / fb
        stable.append(is_hurwitz(poly.add(a, mid * b)))
    out: list[list[float]] = []
    for (e0, e1), ok in zip(zip(edges[:-1], edges[1:]), stable):
        if not ok:
            continue
        if out and out[-1][1] == e0 and is_hurwitz(poly.add(a, e0 * b)):
            out[-1][1] = e1                         # a spurious critical value: stable across it
        else:
            out.append([e0, e1])
    return [(float(x), float(y)) for x, y in out]
