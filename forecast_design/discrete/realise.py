"""The delta-operator realisation of a discrete TF: roots mapped from the source, sections, gains.

See :mod:`forecast_design.discrete` for the rules (why the delta operator, the first differences,
unity-DC sections, the pairing of poles and zeros).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError
from .filters import FIRST_DIFFERENCE, _REAL_TOL

if TYPE_CHECKING:
    from .tf import DiscreteTF

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
    if dtf.source is None:
        return _given_rho_roots(dtf)
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
    if dtf.method in ("tustin", "tustin-prewarp"):
        c = _tustin_constant(T, dtf.prewarp_hz)
        zeros = np.concatenate([2.0 * s_zeros / (c - s_zeros), np.full(n_inf, -2.0)])
        poles = 2.0 * s_poles / (c - s_poles)
        s0 = c * (_Z0 - 1.0) / (_Z0 + 1.0)
        target = np.polyval(num, s0) / np.polyval(den, s0)
    elif dtf.method == "backward-euler":
        # an improper source (a pure derivative) gets its poles at infinity at z = 0 (rho = -1)
        zeros = np.concatenate([s_zeros * T / (1.0 - s_zeros * T), np.full(max(n_inf, 0), -1.0)])
        poles = np.concatenate([s_poles * T / (1.0 - s_poles * T), np.full(max(-n_inf, 0), -1.0)])
        s0 = (_Z0 - 1.0) / (T * _Z0)
        target = np.polyval(num, s0) / np.polyval(den, s0)
    elif dtf.method == "matched":
        z_zeros, z_poles, gain = _matched_zpk(num, den, T)
        zeros = z_zeros - 1.0
        poles = z_poles - 1.0
        target = gain * np.prod(_Z0 - z_zeros) / np.prod(_Z0 - z_poles)
        # the zeros at s = 0 are mapped to z = 1 by _matched_zpk: they are the m differences below
        zeros = zeros[np.abs(zeros) > 0.0] if m else zeros
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


def _given_rho_roots(dtf: "DiscreteTF") -> tuple[int, np.ndarray, np.ndarray, float | None, complex]:
    """:func:`_rho_roots` of a TF given by its z-coefficients (no continuous source to map from).

    The roots come from the z-polynomials (all the precision there is); zeros exactly at z = 1 are
    first differences, as for a source's zeros at s = 0.
    """
    num = np.trim_zeros(np.asarray(dtf.num, dtype=float), "f")
    den = np.asarray(dtf.den, dtype=float)
    z_zeros = np.roots(num).astype(complex) if len(num) > 1 else np.zeros(0, complex)
    z_poles = np.roots(den).astype(complex) if len(den) > 1 else np.zeros(0, complex)
    at_one = z_zeros == 1.0
    m = int(np.count_nonzero(at_one))
    # (z - 1)^m = z^m (1 - z^-1)^m: m differences and m compensating zeros at z = 0 (rho = -1)
    zeros = np.concatenate([z_zeros[~at_one] - 1.0, np.full(m, -1.0)])
    target = np.polyval(dtf.num, _Z0) / np.polyval(dtf.den, _Z0)
    dc_num, dc_den = np.polyval(dtf.num, 1.0), np.polyval(dtf.den, 1.0)
    dc = float(dc_num / dc_den) if m == 0 and dc_num != 0.0 and dc_den != 0.0 else None
    return m, zeros, z_poles - 1.0, dc, complex(target)


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


def _tustin_constant(dt: float, prewarp_hz: float | None) -> float:
    """``c`` of the bilinear map s = c (z - 1)/(z + 1): 2/T, or w_p / tan(w_p T / 2) with prewarp [1/s]."""
    if prewarp_hz is None:
        return 2.0 / dt
    wp = 2.0 * math.pi * prewarp_hz
    return wp / math.tan(wp * dt / 2.0)


def _matched_zpk(num: np.ndarray, den: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Matched pole-zero map of a proper num/den: z-plane zeros, poles and gain.

    Finite poles and zeros map by z = exp(s T) (``expm1`` keeps those near z = 1 precise); the
    zeros at infinity map to z = -1 (Franklin, Powell and Workman, *Digital Control of Dynamic
    Systems*, 3rd ed., sec. 6.3.2), so the result has the continuous relative degree's
    high-frequency roll-off up to Nyquist. The gain matches the low-frequency asymptote:
    ``lim ((z - 1)/T)^m H(z)`` at z = 1 equals ``lim s^m H(s)`` at s = 0, with m the number of
    poles minus zeros at s = 0 (m = 0: the DC gains agree; an integrator I/s gives I T/2 (z + 1)/(z - 1),
    Tustin's).
    """
    num = np.trim_zeros(np.asarray(num, dtype=float), "f")
    den = np.trim_zeros(np.asarray(den, dtype=float), "f")
    nz0 = len(num) - 1 - int(np.flatnonzero(num)[-1])
    np0 = len(den) - 1 - int(np.flatnonzero(den)[-1])
    num_red, den_red = num[:len(num) - nz0], den[:len(den) - np0]
    s_zeros = np.roots(num_red).astype(complex)
    s_poles = np.roots(den_red).astype(complex)
    n_inf = (len(den) - 1) - (len(num) - 1)
    m = np0 - nz0
    g_c = num_red[-1] / den_red[-1]          # the reduced DC gain (no roots at 0 left)
    one_minus_p = -_expm1_complex(s_poles * dt)
    one_minus_z = -_expm1_complex(s_zeros * dt)
    gain = g_c * dt ** m * np.prod(one_minus_p) / (2.0 ** n_inf * np.prod(one_minus_z))
    z_zeros = np.concatenate([np.exp(s_zeros * dt), np.ones(nz0), np.full(n_inf, -1.0)])
    z_poles = np.concatenate([np.exp(s_poles * dt), np.ones(np0)])
    return z_zeros, z_poles, float(np.real(gain))


def _check_dtype(dtype: Any) -> np.dtype:
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ParameterError(f"sections dtype must be float64 or float32, got {dtype}", name="dtype", value=dtype)
    return dtype
