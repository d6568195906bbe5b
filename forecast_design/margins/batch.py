"""Disk margins of many loops at once (issue 16): the peak of |S + (sigma - 1)/2| for N loops.

One home for the disk margin is :mod:`forecast_design.margins` (the single-loop exact routine,
:func:`~forecast_design.margins.disk_margin`); this module evaluates the same quantity for a
batch with numpy operations over all loops instead of a Python loop over them:

1. closed-loop poles of every loop from one batched eigenvalue call on companion matrices
   (stability, and the frequency scale w0 = geometric mean of the pole magnitudes);
2. |G(jv)|, G = S + c, on the single routine's guard grid of scaled frequencies v = w / w0
   (40 per decade) for all loops at once, one einsum over exact powers of jv;
3. Newton's method on d/dv log|G(jv)| from the single routine's starting points (the
   stationary points of |G|^2, i.e. the positive roots of the stationarity polynomial, one
   batched eigenvalue call per degree, and every pole's |Im p| and |p|) and the grid's local
   maxima; only the real starts of all loops in one array, a step taken only where it does
   not lower |G|, stopped when the predicted rise is below rounding;
4. the largest value over v = 0, the polished points and v -> infinity; a loop whose guard
   grid beats that value had a peak no start reached and goes to the single routine.

The peak found is a stationary point polished to machine precision; tests compare every loop
with the single-loop routine and python-control, and force the guard grid's fallback.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import ParameterError
from .disk import check_skew
from .exact import STABILITY_TOLERANCE, as_loop, continuous_equivalent, frequency_rad_s
from .exact import _ROOT_IMAG_RTOL, _char_poly, _is_stable, _peak, _scaled_G   # one algorithm: the single routine's pieces

__all__ = ["DiskMarginBatch", "disk_margins"]

_GRID = np.logspace(-4.0, 4.0, 321)   # scaled frequencies v = w / w0 (the single routine's 40 per decade)
_NEWTON_STEPS = 12
_HALVINGS = 4
_RISE_TOL = 1e-16   # predicted relative rise of |G| below which a point has converged [-]


@dataclass(frozen=True, slots=True, eq=False)
class DiskMarginBatch:
    """Disk margins of N loops.

    Parameters
    ----------
    alpha : numpy.ndarray, shape (N,)
        Disk margin of each loop; 0 for a closed loop that is unstable or not well posed [-].
    w_peak_rad_s : numpy.ndarray, shape (N,)
        Frequency of the sensitivity peak; ``inf`` when the peak is the limit at infinite
        frequency (``pi/dt`` for sampled loops), ``nan`` for unstable loops [rad/s].
    stable : numpy.ndarray of bool, shape (N,)
        Nominal closed-loop stability.
    sigma : float
        Skew of the disk [-].
    """

    alpha: np.ndarray
    w_peak_rad_s: np.ndarray
    stable: np.ndarray
    sigma: float

    def __len__(self) -> int:
        return int(self.alpha.shape[0])


def _scaled_powers(n: int, w0: np.ndarray) -> np.ndarray:
    """w0 ** (n - 1 - k) for k = 0..n-1, one row per loop (descending coefficient order)."""
    return w0[:, None] ** np.arange(n - 1, -1, -1)[None, :]


@functools.lru_cache(maxsize=64)
def _grid_powers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's powers of j v split by parity: for P(jv) = sum_k p_k (jv)^(n-1-k), the real
    part sums the even powers and the imaginary part the odd ones, with signs j^k = 1, j, -1, -j.

    Returns (even, W_even, W_odd): a mask of the even-power columns and the two signed power
    matrices, shapes (n,), (n_even, grid), (n_odd, grid); built exactly, read-only.
    """
    k = np.arange(n - 1, -1, -1)
    W = np.array([1.0, 1.0, -1.0, -1.0])[k % 4][:, None] * _GRID[None, :] ** k[:, None]
    even = k % 2 == 0
    out = (even, W[even], W[~even])
    for a in out:
        a.flags.writeable = False
    return out


def _grid_abs2(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """|P(jv) / Q(jv)|^2 of every row on the grid, shape (K, grid).

    One ``einsum`` per parity (numpy's own loops: a BLAS matrix product this small is slower
    than the arithmetic when the BLAS threads share a busy machine), squared in place: large
    temporaries cost more than the arithmetic here.
    """
    even, W_even, W_odd = _grid_powers(P.shape[1])
    PQ = np.concatenate([P, Q])
    re = np.einsum("kn,ng->kg", PQ[:, even], W_even)
    im = np.einsum("kn,ng->kg", PQ[:, ~even], W_odd)
    np.multiply(re, re, out=re)
    re += np.multiply(im, im, out=im)
    K = P.shape[0]
    return np.divide(re[:K], re[K:], out=re[:K])


def _horner_stack(C: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Polynomials C[l, j, :] (descending powers) at s[l]: (L, J, n) and (L,) give (L, J)."""
    acc = C[:, :, 0].astype(complex)
    s = s[:, None]
    for k in range(1, C.shape[2]):
        acc = acc * s + C[:, :, k]
    return acc


def _derivative_rows(C: np.ndarray) -> np.ndarray:
    n = C.shape[1]
    powers = np.arange(n - 1, 0, -1, dtype=float)
    out = np.zeros_like(C)
    out[:, 1:] = C[:, :-1] * powers
    return out


def _group(num: np.ndarray, den: np.ndarray, c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Peak of |G(jv)| for loops with (K, n) padded coefficients; returns (peak, v_peak*w0, stable)."""
    K, n = num.shape
    char = num + den
    lead = char[:, 0]
    posed = lead != 0.0  # 1 + L(inf) = 0: not well posed (as disk_margin)
    peak = np.full(K, np.inf)
    w_at = np.full(K, np.nan)
    stable = np.zeros(K, dtype=bool)
    if not posed.any():
        return peak, w_at, stable
    idx = np.flatnonzero(posed)
    A, N_ = char[idx], num[idx]
    m = n - 1
    if m > 0:
        comp = np.zeros((idx.size, m, m))
        comp[:, 0, :] = -A[:, 1:] / A[:, :1]
        comp[:, np.arange(1, m), np.arange(m - 1)] = 1.0
        poles = np.linalg.eigvals(comp)
        mag = np.abs(poles)
        stab = np.all(poles.real < -STABILITY_TOLERANCE * np.maximum(1.0, mag), axis=1)
        nonzero = np.where(mag > 0.0, mag, np.nan)
        w0 = np.exp(np.nanmean(np.log(nonzero), axis=1))
        w0 = np.where(np.isfinite(w0) & (w0 > 0.0), w0, 1.0)
    else:
        poles = np.zeros((idx.size, 0), dtype=complex)
        stab = np.ones(idx.size, dtype=bool)
        w0 = np.ones(idx.size)
    # G = S + c = (den + c char) / char, frequency-scaled: s = w0 s~, rows normalised
    powers = _scaled_powers(n, w0)
    P = (A - N_ + c * A) * powers
    Q = A * powers
    f = np.max(np.abs(Q), axis=1, keepdims=True)
    P, Q = P / f, Q / f
    with np.errstate(all="ignore"):
        g2 = _grid_abs2(P, Q)
        # starting points: the grid's interior local maxima and the scaled poles
        interior = (g2[:, 1:-1] >= g2[:, :-2]) & (g2[:, 1:-1] >= g2[:, 2:])
        grid_starts = np.where(interior, _GRID[None, 1:-1], np.nan)
        scaled_poles = poles / w0[:, None]
        # the single-loop routine's starting points: the stationary points of |G|^2 (roots of
        # the stationarity polynomial) and the poles' |Im p| and |p|; the grid's maxima on top
        # (a conjugate pair gives the same two starts twice: each start once per loop)
        pole_starts = np.sort(np.concatenate([np.abs(scaled_poles.imag), np.abs(scaled_poles)], axis=1), axis=1)
        pole_starts[:, 1:][pole_starts[:, 1:] == pole_starts[:, :-1]] = np.nan
        starts = np.concatenate([grid_starts, _stationary_points(P, Q), pole_starts], axis=1)
        # only the real starts go to Newton (most grid columns are not local maxima)
        K, S = starts.shape
        flat = np.flatnonzero(starts > 0.0)          # NaN compares false
        v, val = _newton(P, Q, flat // S, starts.reshape(-1)[flat])
        vals = np.full(K * S, -np.inf)
        vals[flat] = np.where(np.isnan(val), -np.inf, val)
        where = np.full(K * S, np.nan)
        where[flat] = v
        ends = np.concatenate([np.abs(P[:, -1:] / Q[:, -1:]), np.abs(P[:, :1] / Q[:, :1])], axis=1)
        candidates = np.concatenate([vals.reshape(K, S), ends], axis=1)
        where = np.concatenate([where.reshape(K, S), np.zeros((K, 1)), np.full((K, 1), np.inf)], axis=1)
        best = np.argmax(np.where(np.isnan(candidates), -np.inf, candidates), axis=1)
        rows = np.arange(K)
        peak[idx] = candidates[rows, best]
        w_at[idx] = where[rows, best] * w0
        # the guard grid: a grid value above every polished point is a peak no start reached;
        # that loop goes to the single-loop routine (golden section and polish between grid points)
        missed = np.flatnonzero(np.sqrt(np.max(g2, axis=1)) > peak[idx] * (1.0 + 1e-12))
        for k in missed:
            G = _scaled_G(num[idx[k]], den[idx[k]], c)
            value, v_peak = _peak(G)
            peak[idx[k]], w_at[idx[k]] = value, v_peak * G.w0
    stable[idx] = stab
    return peak, w_at, stable


def _conv_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise polynomial products of (K, n) and (K, m) coefficient rows (any order, complex ok)."""
    out = np.zeros((a.shape[0], a.shape[1] + b.shape[1] - 1), dtype=np.result_type(a, b))
    for i in range(a.shape[1]):
        out[:, i:i + b.shape[1]] += a[:, i:i + 1] * b
    return out


def _abs2_rows(P: np.ndarray) -> np.ndarray:
    """A(x) with A(v^2) = |P(jv)|^2 for every row (descending powers in s in, in x out)."""
    n = P.shape[1]
    asc = P[:, ::-1]
    jk = 1j ** np.arange(n)
    prod = _conv_rows(asc * jk, asc * np.conj(jk))    # ascending in v, real, even
    return np.real(prod[:, ::2])[:, ::-1]             # descending in x = v^2


def _derivative_x(A: np.ndarray) -> np.ndarray:
    m = A.shape[1]
    return A[:, :-1] * np.arange(m - 1, 0, -1, dtype=float) if m > 1 else np.zeros((A.shape[0], 1))


def _stationary_points(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Scaled frequencies v > 0 where d/dv |P/Q (jv)|^2 = 0: sqrt of the positive real roots x of
    A'B - AB' (A = |P|^2, B = |Q|^2 in x = v^2), as the single-loop routine's candidates; one
    batched eigenvalue call per effective degree. Spurious roots are harmless (every start is
    evaluated on |G| itself); NaN where a row has fewer roots."""
    K = P.shape[0]
    A, B = _abs2_rows(P), _abs2_rows(Q)
    F = _conv_rows(_derivative_x(A), B) - _conv_rows(A, _derivative_x(B))
    scale = np.max(np.abs(F), axis=1, keepdims=True)
    F = np.where(scale > 0.0, F / np.where(scale > 0.0, scale, 1.0), 0.0)
    F = np.where(np.abs(F) > 1e-13, F, 0.0)           # cancelled leading terms are rounding
    lead = np.argmax(F != 0.0, axis=1)
    degree = np.where(F.any(axis=1), F.shape[1] - 1 - lead, 0)   # |G| constant: no stationary point
    out = np.full((K, max(F.shape[1] - 1, 1)), np.nan)
    for d in np.unique(degree):
        if d < 1:
            continue
        rows = np.flatnonzero(degree == d)
        C = F[rows[:, None], lead[rows][:, None] + np.arange(d + 1)[None, :]]
        comp = np.zeros((rows.size, d, d))
        comp[:, 0, :] = -C[:, 1:] / C[:, :1]
        comp[:, np.arange(1, d), np.arange(d - 1)] = 1.0
        roots = np.linalg.eigvals(comp)
        keep = (np.abs(roots.imag) <= _ROOT_IMAG_RTOL * np.abs(roots) + 1e-12) & (roots.real > 0.0)
        out[rows, :d] = np.where(keep, np.sqrt(np.abs(roots.real)), np.nan)
    return out


def _newton(P: np.ndarray, Q: np.ndarray, rows: np.ndarray, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of |P/Q (jv)| from the starts v0 of loops ``rows`` (1-D, all finite and > 0).

    Returns the polished points and |P/Q| there. Newton's method on d/dv log|P/Q (jv)|; a step
    is taken only in a concave basin and halved until |P/Q| does not decrease.
    """
    P1, Q1 = _derivative_rows(P), _derivative_rows(Q)
    C = np.stack([P, P1, _derivative_rows(P1), Q, Q1, _derivative_rows(Q1)], axis=1)  # (K, 6, n)
    C_val = C[:, [0, 3]]
    v = v0.copy()

    def value(at: np.ndarray, vv: np.ndarray) -> np.ndarray:
        pq = _horner_stack(C_val[rows[at]], 1j * vv)
        return np.abs(pq[:, 0] / pq[:, 1])

    live = np.arange(v.size)
    val = value(live, v)
    for _ in range(_NEWTON_STEPS):
        if live.size == 0:
            break
        p0, p1, p2, q0, q1, q2 = _horner_stack(C[rows[live]], 1j * v[live]).T
        # log G = log p - log q; d/ds and d2/ds2 of it; d/dv = j d/ds
        l1 = p1 / p0 - q1 / q0
        l2 = (p2 / p0 - (p1 / p0) ** 2) - (q2 / q0 - (q1 / q0) ** 2)
        h = np.real(1j * l1)          # d/dv log|G| = Re(j G'/G)
        hp = -np.real(l2)             # d2/dv2 log|G| = Re(j^2 (log G)'')
        step = -h / hp
        vl = v[live]
        # converged when the step's predicted rise of log|G|, h^2 / (2 |h'|), is below rounding
        go = (hp < 0.0) & np.isfinite(step) & (np.abs(step) > 1e-12 * vl) & (0.5 * h * step > _RISE_TOL)
        live, step, vl = live[go], step[go], vl[go]
        moved = np.zeros(live.size, dtype=bool)
        for _ in range(_HALVINGS):
            trial = vl + step
            ok = (trial > 0.0) & ~moved
            if not ok.any():
                step *= 0.5
                continue
            cand = np.flatnonzero(ok)
            new_val = value(live[cand], trial[cand])
            better = new_val >= val[live[cand]]
            acc = cand[better]
            v[live[acc]] = trial[acc]
            val[live[acc]] = new_val[better]
            moved[acc] = True
            step = np.where(moved, step, 0.5 * step)
        live = live[moved]
    return v, val


def disk_margins(loops: Sequence[Any], skew: float = 0.0, *,
                 closed_loop_stable: Sequence[bool] | None = None) -> DiskMarginBatch:
    """Disk margins of many SISO loops in one vectorised evaluation.

    Parameters
    ----------
    loops : sequence of RationalTF (or python-control TransferFunction/StateSpace)
        The loops L, continuous or sampled (``dt``; mapped by the bilinear transform as in
        :func:`forecast_design.margins.disk_margin`); loops of equal order are evaluated together.
    skew : float
        Skew sigma of the disk [-]: 0 balanced, 1 uses S, -1 uses T.
    closed_loop_stable : sequence of bool, optional
        Nominal closed-loop stability of each loop if known from elsewhere (e.g.
        ``ForceLoop.stable``, which also sees hidden pole-zero cancellations), as the argument
        of the same name of :func:`forecast_design.margins.disk_margin`; default: the roots of
        den(L) + num(L) of each loop.

    Returns
    -------
    DiskMarginBatch
        ``alpha``, ``w_peak_rad_s`` and ``stable`` per loop, in the order given.

    Raises
    ------
    ParameterError
        If a loop is not a transfer function, ``skew`` is not finite, or ``loops`` is empty.

    Notes
    -----
    ``alpha = 1 / max_w |S(jw) + (sigma - 1)/2|`` (Seiler, Packard and Gahinet 2020), the
    same definition and stability rule as :func:`forecast_design.margins.disk_margin`; it
    is tested equal to that routine to 1e-9 relative on random SEA loops.
    """
    sigma = check_skew(skew)
    loops = [as_loop(L) for L in loops]
    if not loops:
        raise ParameterError("disk_margins needs at least one loop", name="loops", value=loops)
    known = None
    if closed_loop_stable is not None:
        known = np.asarray(closed_loop_stable, dtype=bool).reshape(-1)
        if known.size != len(loops):
            raise ParameterError(f"closed_loop_stable has {known.size} entries for {len(loops)} loops",
                                 name="closed_loop_stable", value=known.size)
    c = (sigma - 1.0) / 2.0
    pairs = [continuous_equivalent(L) for L in loops]
    alpha = np.zeros(len(loops))
    w_peak = np.full(len(loops), np.nan)
    stable = np.zeros(len(loops), dtype=bool)
    by_length: dict[int, list[int]] = {}
    for i, (num, _) in enumerate(pairs):
        by_length.setdefault(len(num), []).append(i)
    for n, members in by_length.items():
        num = np.array([pairs[i][0] for i in members], dtype=float).reshape(len(members), n)
        den = np.array([pairs[i][1] for i in members], dtype=float).reshape(len(members), n)
        peak, w_at, stab = _group(num, den, c)
        if known is not None:   # as disk_margin: the given flag, unless 1 + L(inf) = 0
            stab = known[members] & (num[:, 0] + den[:, 0] != 0.0)
        else:
            for k, i in enumerate(members):
                if loops[i].dt is not None:
                    # a z-polynomial's own roots, as disk_margin decides (and warns where its
                    # coefficients cannot place them); the mapped polynomial would hide that
                    stab[k] = _is_stable(loops[i], _char_poly(loops[i])[2]) and num[k, 0] + den[k, 0] != 0.0
        for k, i in enumerate(members):
            stable[i] = bool(stab[k])
            if stab[k] and math.isfinite(peak[k]) and peak[k] > 0.0:
                alpha[i] = 1.0 / peak[k]
                w_peak[i] = frequency_rad_s(loops[i], float(w_at[k]))
    return DiskMarginBatch(alpha=alpha, w_peak_rad_s=w_peak, stable=stable, sigma=sigma)
