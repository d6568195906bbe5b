"""Polynomial helpers: the one home for coefficient arithmetic of transfer functions.

Polynomials are 1-D float arrays of coefficients in *descending* powers (``s`` or
``z``), as numpy's ``polyval`` and python-control use them. These small functions
replace ``np.polyadd``/``np.polymul``/``np.polyder``, which go through ``poly1d``
checks, on the hot paths of the disk margins and the force-loop builders; they
never trim unless asked (:func:`trim`), so lengths stay predictable.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["trim", "pad", "add", "sub", "mul", "power", "derivative", "abs2_even", "cross_even",
           "trailing_zeros", "drop_trailing"]


def trim(p: Sequence[float] | np.ndarray) -> np.ndarray:
    """Drop leading zero coefficients; the zero polynomial is ``[0.0]``.

    Parameters
    ----------
    p : array_like
        Coefficients, descending powers.

    Returns
    -------
    ndarray
        The same polynomial without leading zeros (a view where possible).
    """
    p = np.atleast_1d(np.asarray(p, dtype=float))
    nz = np.flatnonzero(p != 0.0)
    return p[nz[0]:] if nz.size else np.zeros(1)


def pad(p: np.ndarray, n: int) -> np.ndarray:
    """``p`` with leading zeros up to length ``n`` (unchanged when already that long)."""
    return np.concatenate([np.zeros(n - len(p)), p]) if len(p) < n else p


def add(*polys: np.ndarray) -> np.ndarray:
    """Sum of polynomials (not trimmed): length of the longest."""
    n = max(len(p) for p in polys)
    out = np.zeros(n)
    for p in polys:
        out[n - len(p):] += p
    return out


def sub(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``p - q`` (not trimmed)."""
    n = max(len(p), len(q))
    return pad(p, n) - pad(q, n)


def mul(*polys: np.ndarray) -> np.ndarray:
    """Product of polynomials (not trimmed); the empty product is ``[1.0]``."""
    out = np.ones(1)
    for p in polys:
        out = np.convolve(out, np.asarray(p, dtype=float))
    return out


def power(p: np.ndarray, k: int) -> np.ndarray:
    """``p**k`` for an integer ``k >= 0``."""
    return mul(*([p] * k)) if k else np.ones(1)


def derivative(p: np.ndarray) -> np.ndarray:
    """``dp/ds``; the derivative of a constant is ``[0.0]``."""
    return p[:-1] * np.arange(len(p) - 1, 0, -1) if len(p) > 1 else np.zeros(1)


def abs2_even(p: np.ndarray) -> np.ndarray:
    """``A(x)`` with ``A(w^2) = |p(jw)|^2``, coefficients descending in ``x`` (trimmed).

    ``p(s) p(-s)`` is even in ``s``; at ``s = jw`` its ``s^(2k)`` term is ``(-1)^k x^k``.
    """
    n = len(p) - 1
    p_minus = p * (-1.0) ** np.arange(n, -1, -1)
    q = np.convolve(p, p_minus)[::-1][::2]          # ascending coefficients of s^0, s^2, ...
    a = q * (-1.0) ** np.arange(len(q))
    return trim(a[::-1].copy())


def cross_even(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``C(x)`` with ``C(w^2) = Re(p(jw) conj(q(jw)))``, coefficients descending in ``x`` (trimmed).

    ``(p(s) q(-s) + p(-s) q(s)) / 2`` is even in ``s``; at ``s = jw`` its ``s^(2k)`` term is
    ``(-1)^k x^k``.
    """
    q_minus = q * (-1.0) ** np.arange(len(q) - 1, -1, -1)
    p_minus = p * (-1.0) ** np.arange(len(p) - 1, -1, -1)
    e = 0.5 * add(np.convolve(p, q_minus), np.convolve(p_minus, q))
    a = e[::-1][::2]
    a = a * (-1.0) ** np.arange(len(a))
    return trim(a[::-1].copy())


def trailing_zeros(p: np.ndarray) -> int:
    """Multiplicity of the root at 0 (trailing zero coefficients); ``10**9`` for the zero polynomial."""
    if not np.any(p != 0.0):
        return 10**9
    return int(len(p) - 1 - np.flatnonzero(p != 0.0)[-1])


def drop_trailing(p: np.ndarray, m: int) -> np.ndarray:
    """``p / s**m`` for ``m`` known trailing zeros (the zero polynomial stays as it is)."""
    return p[: len(p) - m] if m and np.any(p != 0.0) else p
