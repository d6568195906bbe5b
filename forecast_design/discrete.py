"""Continuous-to-discrete conversion and the one discrete filter implementation.

:func:`discretize` maps a continuous :class:`~forecast_design.lti.RationalTF`
to a :class:`DiscreteTF` that records how it was made (method, rate,
prewarp). :meth:`DiscreteTF.to_delta_sos` realises it as *delta-operator
second-order sections* and :class:`DiscreteFilter` runs them with the
recursion below, the same one the simulator runs and the C export emits.

Why the delta operator
----------------------
At 2 kHz the poles and zeros of 1-100 Hz filters sit within a few
hundredths of z = 1. Shift-operator coefficients ``a1 ~ -2``, ``a2 ~ 1``
then carry the filter in their last few bits: in float32 the EA-FOB's
G_s = -Q / P_n^EA lost 0.6 % of its DC gain and a motor-side FOB's
double differentiator no longer had its zeros at z = 1. Rewriting every
section in ``rho = z - 1`` (the delta operator with T = 1) stores
``(z - p1)(z - p2) = rho^2 + (d1 + d2) rho + d1 d2`` with ``d = 1 - p``,
so poles and zeros near z = 1 keep their *relative* precision. The
coefficients are computed from the continuous roots mapped exactly
(Tustin ``rho = 2 s / (c - s)``, Euler ``rho = s T``, ``s T / (1 - s T)``,
ZOH ``rho = expm1(s T)``), never from the expanded z-polynomial.

Three more rules make the float32 realisation match float64 to ~1e-6:

* zeros exactly at s = 0 (differentiators: the motor-side FOB's
  J_m s^2, the SFM's velocity filter) become leading first-difference
  sections ``(1 - z^-1)`` that act on the raw input; the difference of two
  nearby floats is exact, so a large angle never has to cancel against
  an integrated state;
* each section with a finite, non-zero DC gain is scaled to DC gain 1
  *exactly* (its constant numerator coefficient is the very same number
  as its constant denominator coefficient), and the overall gain goes
  into the first non-difference section: a unity-DC Q filter keeps
  Q(1) = 1 in float32, so the observer loop ``1 - Q`` keeps its integral
  action and the estimate does not drift;
* poles are grouped in conjugate pairs (two real poles share a section,
  an odd one gets a first-order section); zeros are given to the pole
  group nearest the unit circle first, each taking its nearest zeros;
  sections run fastest-first, the slowest (most sensitive) last.

Delta section recursion
-----------------------
Each row ``[b0, b1, b2, 1, a1, a2]`` of a delta-SOS array is::

    H(rho) = (b0 + b1 rho^-1 + b2 rho^-2) / (1 + a1 rho^-1 + a2 rho^-2),  rho = z - 1,

run in transposed direct form II with ``rho^-1`` (an accumulator
``s[n+1] = s[n] + v[n]``) in place of ``z^-1``; states ``s1, s2`` per
section, initially zero, and this exact order of operations::

    y  = b0 x + s1
    t1 = (b1 x - a1 y) + s2
    t2 = b2 x - a2 y
    s1 = s1 + t1
    s2 = s2 + t2

The output ``y`` of section ``i`` is the input ``x`` of section ``i + 1``.
A row with ``b2 = a2 = 0`` is a first-order section ``(b0 rho + b1) / (rho
+ a1)`` (``s2`` stays 0); ``[1, 0, 0, 1, 1, 0]`` is the first difference
``1 - z^-1``. :func:`delta_to_sos` / :func:`sos_to_delta` convert to and
from scipy's shift-operator sections (for interoperability only: the
conversion to shift form is exactly what loses the precision).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import ParameterError
from .lti import RationalTF

try:  # numba is optional: without it the kernels run as (slow) plain Python.
    from numba import njit as _numba_njit
    from numba import prange

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _numba_njit = None
    prange = range
    HAVE_NUMBA = False


def njit(func=None, *, inline: str = "never", parallel: bool = False):
    """The project's one numba shim: ``numba.njit(cache=True, inline=..., parallel=...)``, or the plain function.

    Parameters
    ----------
    func : callable, optional
        The function (``@njit`` or ``njit(f, inline="always")``).
    inline : str
        numba's IR-level inlining at jitted call sites (``"never"`` or ``"always"``).
    parallel : bool
        Run the function's ``prange`` loops (:data:`prange`, ``range`` without numba) on
        numba's thread pool.

    Returns
    -------
    callable
        The compiled function (the function itself without numba).
    """
    def wrap(f):
        if _numba_njit is None:
            return f
        if parallel:
            return _numba_njit(cache=True, inline=inline, parallel=True)(f)
        return _numba_njit(cache=True, inline=inline)(f)

    return wrap if func is None else wrap(func)


_njit = njit   # deprecated private alias, kept for one release


__all__ = [
    "METHODS",
    "DiscreteTF",
    "DiscreteFilter",
    "discretize",
    "sos_step",
    "sos_filter",
    "delta_to_sos",
    "sos_to_delta",
    "FIRST_DIFFERENCE",
    "njit",
    "HAVE_NUMBA",
]

#: Supported methods: ``tustin`` (bilinear, optional prewarp), ``zoh``
#: (zero-order hold, exact for piecewise-constant inputs), ``backward-euler``
#: (s = (z - 1) / (T z)) and ``forward-euler`` (s = (z - 1) / T).
METHODS = ("tustin", "zoh", "backward-euler", "forward-euler")


@njit
def sos_step(sos, state, x):
    """Advance a cascade of delta-operator second-order sections by one sample (in place).

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Delta sections, rows ``[b0, b1, b2, 1, a1, a2]`` (module docstring).
    state : ndarray, shape (n_sections, 2)
        Accumulator states ``s1, s2``; updated in place.
    x : float
        Input sample.

    Returns
    -------
    float
        Output sample. The arithmetic is done in the dtype of ``sos``/``state``
        (float32 arrays give float32 arithmetic, bit for bit the emitted C
        ``float`` code built without FMA contraction).
    """
    y = x
    for i in range(sos.shape[0]):
        xi = y
        y = sos[i, 0] * xi + state[i, 0]
        t1 = sos[i, 1] * xi - sos[i, 4] * y + state[i, 1]
        t2 = sos[i, 2] * xi - sos[i, 5] * y
        state[i, 0] = state[i, 0] + t1
        state[i, 1] = state[i, 1] + t2
    return y


@njit
def sos_filter(sos, state, x, y):
    """Run :func:`sos_step` over an input array.

    Parameters
    ----------
    sos : ndarray, shape (n_sections, 6)
        Delta sections.
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


def _controllable_ss(num: tuple[float, ...], den: tuple[float, ...]):
    """Controllable canonical (A, B, C, D) of a proper num/den (no scipy normalisation warnings)."""
    a = np.asarray(den, dtype=float) / den[0]
    n = len(a) - 1
    b = np.concatenate([np.zeros(n + 1 - len(num)), np.asarray(num, dtype=float)]) / den[0]
    A = np.zeros((n, n))
    A[0, :] = -a[1:]
    A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    B[0, 0] = 1.0
    C = (b[1:] - b[0] * a[1:]).reshape(1, n)
    return A, B, C, float(b[0])


def _zoh_ss(num: tuple[float, ...], den: tuple[float, ...], dt: float):
    """ZOH of num/den in delta form: (A_d - I, B_d, C, D), A_d - I = A int_0^T exp(A t) dt (no cancellation)."""
    from scipy import linalg

    A, B, C, D = _controllable_ss(num, den)
    # Companion matrices of fast filters span many decades (w^n); a diagonal similarity brings
    # the entries to one scale so expm and the zero pencil keep their precision.
    _, (scale, _) = linalg.matrix_balance(A, permute=False, separate=True)
    A, B, C = A * scale[None, :] / scale[:, None], B / scale[:, None], C * scale[None, :]
    n = A.shape[0]
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n] = A * dt
    m[:n, n:] = np.eye(n) * dt
    gamma = linalg.expm(m)[:n, n:]
    return A @ gamma, gamma @ B, C, D


def _zoh(num: tuple[float, ...], den: tuple[float, ...], dt: float) -> tuple[np.ndarray, np.ndarray]:
    n = len(den) - 1
    if n == 0:
        return np.array([num[-1] / den[0]]), np.array([1.0])
    Ar, Bd, C, D = _zoh_ss(num, den, dt)
    Ad = Ar + np.eye(n)
    dend = np.poly(Ad)
    numd = np.poly(Ad - Bd @ C) + (D - 1.0) * dend  # SISO ss2tf
    return np.real(numd), np.real(dend)


#: The delta section of the first difference ``1 - z^-1 = rho / (rho + 1)``.
FIRST_DIFFERENCE = (1.0, 0.0, 0.0, 1.0, 1.0, 0.0)

# Roots with |imag| below this fraction of their modulus are real (np.roots splits a repeated
# real root, e.g. a binomial Q filter's, into a pair with a tiny imaginary part).
_REAL_TOL = 1e-9


def delta_to_sos(dsos: np.ndarray) -> np.ndarray:
    """Convert delta sections to scipy's shift-operator sections (float64).

    Parameters
    ----------
    dsos : ndarray, shape (n, 6)
        Delta sections ``[b0, b1, b2, 1, a1, a2]`` in ``rho = z - 1``.

    Returns
    -------
    ndarray, shape (n, 6)
        ``[b0, b1, b2, 1, a1, a2]`` in ``z^-1`` (``scipy.signal.sosfilt``
        layout), the same transfer function. First-order rows (``b2 = a2 =
        0``) map to first-order shift sections.
    """
    d = np.asarray(dsos, dtype=float).reshape(-1, 6)
    out = np.zeros_like(d)
    for row, (b0, b1, b2, _, a1, a2) in zip(out, d):
        if b2 == 0.0 and a2 == 0.0:  # (b0 rho + b1) / (rho + a1)
            row[:] = (b0, b1 - b0, 0.0, 1.0, a1 - 1.0, 0.0)
        else:
            row[:] = (b0, b1 - 2.0 * b0, b0 - b1 + b2, 1.0, a1 - 2.0, 1.0 - a1 + a2)
    return out


def sos_to_delta(sos: np.ndarray) -> np.ndarray:
    """Convert scipy shift-operator sections to delta sections (float64).

    Parameters
    ----------
    sos : ndarray, shape (n, 6)
        ``[b0, b1, b2, a0, a1, a2]`` in ``z^-1``, ``a0 != 0``.

    Returns
    -------
    ndarray, shape (n, 6)
        The same transfer function as delta sections. The conversion is
        exact algebra but cannot restore precision that shift-operator
        coefficients have already lost (prefer :meth:`DiscreteTF.to_delta_sos`).
    """
    s = np.asarray(sos, dtype=float).reshape(-1, 6)
    out = np.zeros_like(s)
    for row, (b0, b1, b2, a0, a1, a2) in zip(out, s):
        b0, b1, b2, a1, a2 = b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0
        if b2 == 0.0 and a2 == 0.0:
            row[:] = (b0, b1 + b0, 0.0, 1.0, a1 + 1.0, 0.0)
        else:
            row[:] = (b0, b1 + 2.0 * b0, b0 + b1 + b2, 1.0, a1 + 2.0, 1.0 + a1 + a2)
    return out


def _expm1_complex(w: np.ndarray) -> np.ndarray:
    """exp(w) - 1 without cancellation for small complex w."""
    a, b = w.real, w.imag
    return np.expm1(a) * np.cos(b) - 2.0 * np.sin(b / 2.0) ** 2 + 1j * np.exp(a) * np.sin(b)


def _split_real(roots: np.ndarray) -> tuple[list[float], list[complex]]:
    """Real roots and one representative (imag > 0) per conjugate pair."""
    roots = np.asarray(roots, dtype=complex)
    is_real = np.abs(roots.imag) <= _REAL_TOL * np.abs(roots)
    pos = roots[~is_real & (roots.imag > 0)]
    neg = roots[~is_real & (roots.imag < 0)]
    if len(pos) != len(neg) or not np.allclose(np.sort_complex(pos), np.sort_complex(np.conj(neg)),
                                               rtol=1e-6, atol=0.0):
        raise ParameterError(f"roots {roots} are not closed under conjugation", name="roots", value=roots)
    return [float(r) for r in roots[is_real].real], [complex(r) for r in pos]


def _closeness(p: complex) -> float:
    """Distance of the z-plane root 1 + p from the unit circle (small: sensitive, slow)."""
    return abs(1.0 - abs(1.0 + p))


def _pair_sections(zeros: np.ndarray, poles: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Group poles in pairs and give each group its nearest zeros (rho-plane roots).

    Returns (numerator, denominator) monic rho-polynomials per section,
    least sensitive first. Numerators may be shorter than denominators
    (zeros at infinity).
    """
    preal, ppair = _split_real(poles)
    zreal, zpair = _split_real(zeros)
    groups: list[list[complex]] = [[p, np.conj(p)] for p in ppair]
    preal.sort(key=_closeness)
    groups += [preal[i:i + 2] for i in range(0, len(preal), 2)]
    groups.sort(key=lambda g: min(_closeness(p) for p in g))  # most sensitive first
    assigned: list[list[complex]] = []
    for k, g in enumerate(groups):
        rest = groups[k + 1:]
        cap = sum(len(h) for h in rest)
        n2 = sum(len(h) == 2 for h in rest)

        def dist(r: complex) -> float:
            return min(abs(r - p) for p in g)

        options: list[tuple[list[complex], list[float], list[complex]]] = [([], zreal, zpair)]
        by_dist = sorted(zreal, key=dist)
        if by_dist:
            options.append(([by_dist[0]], [r for r in zreal if r is not by_dist[0]], zpair))
        if len(g) == 2 and len(by_dist) >= 2:
            options.append((by_dist[:2], [r for r in zreal if r is not by_dist[0] and r is not by_dist[1]], zpair))
        if len(g) == 2:
            for c in zpair:
                options.append(([c, np.conj(c)], zreal, [d for d in zpair if d is not c]))
        feasible = [o for o in options if len(o[2]) <= n2 and 2 * len(o[2]) + len(o[1]) <= cap]
        chosen, zreal, zpair = min(feasible, key=lambda o: (-len(o[0]), max((dist(r) for r in o[0]), default=0.0)))
        assigned.append(chosen)
    sections = []
    for g, zs in zip(groups, assigned):
        num = np.real(np.poly(zs)) if zs else np.array([1.0])
        sections.append((num, np.real(np.poly(g))))
    return sections[::-1]


#: Where the realisation's gain is fitted: z0 = j (a quarter of the sample rate), far from
#: every pole and zero that matters here.
_Z0 = 1j


def _rho_roots(dtf: "DiscreteTF") -> tuple[int, np.ndarray, np.ndarray, float | None, complex]:
    """(m, zeros, poles, DC gain, H(z0)) in rho = z - 1 of the realisation ``(1 - z^-1)^m R(rho)``.

    The m leading differences stand for the source's zeros exactly at s = 0;
    R's zeros include the m compensating zeros at rho = -1 (z = 0). The DC
    gain (every method here preserves it) is ``None`` unless finite and
    non-zero. ``H(z0)`` is the exact discrete response at :data:`_Z0`,
    evaluated from the source (or the delta-form state space for ZOH), not
    from the expanded z-polynomials.
    """
    num = np.asarray(dtf.source.num, dtype=float)
    den = np.asarray(dtf.source.den, dtype=float)
    m_num = len(num) - 1 - int(np.flatnonzero(num)[-1])
    m_den = len(den) - 1 - int(np.flatnonzero(den)[-1])
    common = min(m_num, m_den)  # s^k / s^k: cancel exactly
    if common:
        num, den = num[:len(num) - common], den[:len(den) - common]
    m = m_num - common
    num_red = num[:len(num) - m] if m else num
    n_inf = (len(den) - 1) - (len(num) - 1)
    s_zeros = np.roots(num_red).astype(complex)
    s_poles = np.roots(den).astype(complex)
    T = dtf.dt
    if dtf.method == "tustin":
        if dtf.prewarp_hz is None:
            c = 2.0 / T
        else:
            wp = 2.0 * math.pi * dtf.prewarp_hz
            c = wp / math.tan(wp * T / 2.0)
        zeros = np.concatenate([2.0 * s_zeros / (c - s_zeros), np.full(n_inf, -2.0)])
        poles = 2.0 * s_poles / (c - s_poles)
        s0 = c * (_Z0 - 1.0) / (_Z0 + 1.0)
        target = np.polyval(num, s0) / np.polyval(den, s0)
    elif dtf.method == "backward-euler":
        zeros = np.concatenate([s_zeros * T / (1.0 - s_zeros * T), np.full(n_inf, -1.0)])
        poles = s_poles * T / (1.0 - s_poles * T)
        s0 = (_Z0 - 1.0) / (T * _Z0)
        target = np.polyval(num, s0) / np.polyval(den, s0)
    elif dtf.method == "forward-euler":
        zeros, poles = s_zeros * T, s_poles * T
        s0 = (_Z0 - 1.0) / T
        target = np.polyval(num, s0) / np.polyval(den, s0)
    else:  # zoh: poles map exactly; zeros are the finite generalised eigenvalues in delta form
        from scipy import linalg

        poles = _expm1_complex(s_poles * T)
        Ar, Bd, C, D = _zoh_ss(tuple(num), tuple(den), T)
        n = Ar.shape[0]
        # scale input and output so the pencil's blocks share one magnitude (zeros are invariant)
        a_norm = max(np.max(np.abs(Ar)), 1e-300)
        su = a_norm / max(np.max(np.abs(Bd)), 1e-300)
        sy = a_norm / max(np.max(np.abs(C)), abs(D), 1e-300)
        sys_m = np.block([[Ar, Bd * su], [C * sy, np.array([[D * su * sy]])]])
        sys_n = np.zeros((n + 1, n + 1))
        sys_n[:n, :n] = np.eye(n)
        alpha, beta = linalg.eigvals(sys_m, sys_n, homogeneous_eigvals=True)
        n_finite = n if D != 0.0 else n - 1  # generic: one sampling zero fewer than poles
        finite = np.argsort(-np.abs(beta) / np.maximum(np.abs(alpha), 1e-300))[:n_finite]
        zeros = alpha[finite] / beta[finite]
        target = (C @ np.linalg.solve((_Z0 - 1.0) * np.eye(n) - Ar, Bd))[0, 0] + D
        # A zero-hold keeps one zero exactly at z = 1 per zero DC gain; with s^2 and higher the
        # others land within ~(w T)^k of it, below what the eigen-solver resolves (~1e-11).
        # Zeros within 1e-8 of z = 1 (a frequency of 1e-8 rad/sample) are differences.
        tiny = np.abs(zeros) < 1e-8
        if m and not np.any(tiny):  # pragma: no cover - the exact zero must be found
            raise ParameterError(f"{dtf.name or 'filter'}: zoh lost the zero at z = 1", name="tf", value=dtf.source)
        m = int(np.count_nonzero(tiny))
        zeros = zeros[~tiny]
    zeros = np.concatenate([zeros, np.full(m, -1.0)])
    dc = float(num[-1] / den[-1]) if m == 0 and num[-1] != 0.0 and den[-1] != 0.0 else None
    return m, zeros, poles, dc, complex(target)


def _realise(dtf: "DiscreteTF") -> np.ndarray:
    """Delta sections of ``dtf`` in float64 (module docstring's rules)."""
    num = np.trim_zeros(np.asarray(dtf.num, dtype=float), "f")
    if num.size == 0:  # the zero filter (e.g. an observer path that is not used)
        return np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    if dtf.order == 0:
        return np.array([[dtf.num[-1] / dtf.den[0], 0.0, 0.0, 1.0, 0.0, 0.0]])
    m, zeros, poles, dc, target = _rho_roots(dtf)
    if len(poles) == 0:  # everything cancelled: a static gain
        return np.array([[float(dtf.dcgain()), 0.0, 0.0, 1.0, 0.0, 0.0]])
    rows, normalised = [], True
    for n_poly, d_poly in _pair_sections(zeros, poles):
        order = len(d_poly) - 1
        n_poly = np.concatenate([np.zeros(order + 1 - len(n_poly)), n_poly])
        if n_poly[-1] != 0.0 and d_poly[-1] != 0.0:
            c = d_poly[-1] / n_poly[-1]
            n_poly = n_poly * c
            n_poly[-1] = d_poly[-1]  # the same number: DC gain exactly 1 in any precision
        else:
            normalised = False
        if order == 1:
            rows.append([n_poly[0], n_poly[1], 0.0, 1.0, d_poly[1], 0.0])
        else:
            rows.append([n_poly[0], n_poly[1], n_poly[2], 1.0, d_poly[1], d_poly[2]])
    sections = np.array(rows)
    # Overall gain: the exact response at z0 over the sections' response there.
    rho0 = _Z0 - 1.0
    have = (rho0 / _Z0) ** m
    for b0, b1, b2, _, a1, a2 in sections:
        if b2 == 0.0 and a2 == 0.0:
            have *= (b0 * rho0 + b1) / (rho0 + a1)
        else:
            have *= (b0 * rho0**2 + b1 * rho0 + b2) / (rho0**2 + a1 * rho0 + a2)
    gain = target / have
    if abs(gain.imag) > 1e-6 * abs(gain) or (dc is not None and normalised
                                              and abs(gain.real - dc) > 1e-6 * abs(dc)):
        raise ParameterError(f"{dtf.name or 'filter'}: realisation gain {gain} disagrees with the "
                             f"transfer function (DC gain {dc}); roots too ill-conditioned",
                             name="num", value=dtf.num)
    if dc is not None and normalised:
        # every section has DC gain 1 and every method keeps the DC gain: use it exactly, so a
        # unity-DC filter is realised with gain 1.0 (no 1e-16 drift for float32 to round either way)
        sections[0, :3] *= dc
    else:
        sections[0, :3] *= gain.real
    diffs = np.tile(np.array(FIRST_DIFFERENCE), (m, 1))
    return np.ascontiguousarray(np.vstack([diffs, sections]))


def _check_dtype(dtype: Any) -> np.dtype:
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ParameterError(f"sections dtype must be float64 or float32, got {dtype}", name="dtype", value=dtype)
    return dtype


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
    """A running discrete filter: delta-operator second-order sections.

    Parameters
    ----------
    dtf : DiscreteTF or ndarray
        The discrete TF (realised with :meth:`DiscreteTF.to_delta_sos`) or a
        delta-SOS array of shape (n_sections, 6) (rows ``[b0, b1, b2, 1, a1,
        a2]`` in ``rho = z - 1``; convert scipy sections with :func:`sos_to_delta`).
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
            sos = dtf.to_delta_sos(dtype)
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
