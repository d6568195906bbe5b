"""Robustness analysis of force loops: exact disk margins and the Fig. 6 table."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Sequence

import numpy as np

from .errors import ParameterError
from . import polynomials as poly
from .lti import RationalTF
from .params import COMPENSATOR_KINDS, Compensator, Design, PDController

__all__ = [
    "DiskMargin",
    "DiskMarginCurve",
    "MarginRow",
    "disk_margin",
    "disk_margin_curve",
    "disk_gain_margin",
    "disk_phase_margin_deg",
    "disk_center_radius",
    "fig6_table",
    "SampledForceLoop",
    "sampled_force_loop",
    "loop_margins",
]

# A closed-loop root counts as stable only if Re(p) < -_STABILITY_RTOL * max(1, |p|): roots
# on the imaginary axis (e.g. L = 1/s^2) are computed as +-1e-17 and must not pass.
_STABILITY_RTOL = 1e-9       # as symbolic.loops.STABILITY_TOLERANCE
# Roots of the stationarity polynomial with |Im x| up to this fraction of |x| are kept as
# candidates. Keeping spurious ones is harmless: every candidate is evaluated on the actual
# |G(jw)|, so the maximum can only improve; dropping a true one is what must not happen.
_ROOT_IMAG_RTOL = 1e-3
# Points per decade of the guard grid (scaled frequency), see _peak.
_GUARD_POINTS_PER_DECADE = 40
_NEWTON_STEPS = 8
_BACKTRACK_STEPS = 4
_UNBOUNDED_RTOL = 1e-12


# ---------------------------------------------------------------------------------------------
# Result types
# ---------------------------------------------------------------------------------------------


def _json_float(x: float) -> float | None:
    """JSON has no infinity: infinite or NaN values are written as null."""
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True, slots=True, kw_only=True)
class DiskMargin:
    """Disk margin of a SISO loop and the gain/phase variations it guarantees.

    All margins are *disk-based* (Seiler, Packard, Gahinet 2020): the loop stays
    stable for every simultaneous gain and phase factor ``f`` in the disk
    ``D(alpha, sigma)``, in particular for real gains in ``gain_margin`` and
    for pure phase shifts up to ``phase_margin_deg``.

    An unstable (or not well-posed) nominal loop has ``alpha = 0``: the disk shrinks to
    f = 1, so ``gain_margin = (1, 1)``, 0 dB, 0 deg, ``delay_margin_s = 0`` and
    ``frequency_rad_s = nan``. ``frequency_rad_s`` is ``inf`` (continuous) or the Nyquist
    frequency (discrete) when the peak is the high-frequency limit. A lower gain bound
    clipped at 0 has ``-inf`` dB; an unbounded upper one is ``inf``.
    """

    alpha: float                              # disk margin, 0 if the closed loop is unstable   [-]
    sigma: float                              # skew of the disk (0 balanced, 1 = S, -1 = T)   [-]
    gain_margin: tuple[float, float]          # (gamma_min, gamma_max), gain factors            [-]
    gain_margin_db: tuple[float, float]       # the same in dB                                  [dB]
    phase_margin_deg: float                   # disk-based phase margin                         [deg]
    frequency_rad_s: float                    # frequency of the critical (smallest) disk       [rad/s]
    delay_margin_s: float                     # classical delay margin of L                     [s]
    stable: bool                              # nominal closed loop stable

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping; infinite values (e.g. an unbounded gain margin) become ``None``."""
        return {
            "alpha": _json_float(self.alpha),
            "sigma": self.sigma,
            "gain_margin": [_json_float(g) for g in self.gain_margin],
            "gain_margin_db": [_json_float(g) for g in self.gain_margin_db],
            "phase_margin_deg": _json_float(self.phase_margin_deg),
            "frequency_rad_s": _json_float(self.frequency_rad_s),
            "delay_margin_s": _json_float(self.delay_margin_s),
            "stable": self.stable,
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class DiskMarginCurve:
    """Frequency-dependent disk margin alpha(w) = 1 / |S(jw) + (sigma - 1)/2|."""

    w_rad_s: np.ndarray            # frequencies, shape (n,)                       [rad/s]
    alpha: np.ndarray              # disk margin at each frequency, shape (n,)     [-]
    gain_margin_db: np.ndarray     # (gamma_min, gamma_max) in dB, shape (n, 2)    [dB]
    phase_margin_deg: np.ndarray   # disk-based phase margin, shape (n,)           [deg]
    sigma: float                   # skew                                          [-]

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping (lists; infinities become ``None``)."""
        return {
            "w_rad_s": [float(w) for w in self.w_rad_s],
            "alpha": [_json_float(a) for a in self.alpha],
            "gain_margin_db": [[_json_float(lo), _json_float(hi)] for lo, hi in self.gain_margin_db],
            "phase_margin_deg": [_json_float(p) for p in self.phase_margin_deg],
            "sigma": self.sigma,
        }


# ---------------------------------------------------------------------------------------------
# Disk geometry (Seiler, Packard, Gahinet 2020, Section 3)
# ---------------------------------------------------------------------------------------------


def _check_sigma(sigma: float) -> float:
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not math.isfinite(sigma):
        raise ParameterError(f"disk margin skew sigma must be a finite number, got {sigma!r}",
                             name="sigma", value=sigma)
    return float(sigma)


def _gamma_bounds(alpha: float, sigma: float) -> tuple[float, float]:
    """Real-axis crossings of the boundary of D(alpha, sigma); gamma_max may be <= 0 (exterior)."""
    lo = (2.0 - alpha * (1.0 - sigma)) / (2.0 + alpha * (1.0 + sigma))
    den = 2.0 - alpha * (1.0 + sigma)
    hi = (2.0 + alpha * (1.0 - sigma)) / den if den != 0.0 else math.inf
    return lo, hi


def disk_gain_margin(alpha: float, sigma: float = 0.0) -> tuple[float, float]:
    """Disk-based gain margin: the real factors contained in the disk D(alpha, sigma).

    Parameters
    ----------
    alpha : float
        Disk size (the disk margin) [-], >= 0.
    sigma : float
        Skew [-].

    Returns
    -------
    tuple of float
        ``(gamma_min, gamma_max)`` [-]: every real gain in this interval keeps the loop
        stable. ``gamma_max`` is ``inf`` when ``alpha (1 + sigma) >= 2`` (the disk becomes a
        half-plane or the exterior of a disk; within a relative 1e-12, to absorb rounding).
        ``gamma_min`` is clipped at 0.

    Notes
    -----
    gamma_min = (2 - alpha(1 - sigma)) / (2 + alpha(1 + sigma)),
    gamma_max = (2 + alpha(1 - sigma)) / (2 - alpha(1 + sigma)) [1, eq. (14)].

    References
    ----------
    .. [1] P. Seiler, A. Packard, P. Gahinet, "An Introduction to Disk Margins",
       IEEE Control Systems Magazine 40(5), 2020.
    """
    sigma = _check_sigma(sigma)
    lo, hi = _gamma_bounds(alpha, sigma)
    # alpha carries rounding error, so alpha (1 + sigma) = 2 exactly (e.g. L = w_c/s) may come
    # out as 2 - 1e-16; a gain margin beyond 1e12 (240 dB) is reported as unbounded
    if alpha * (1.0 + sigma) >= 2.0 * (1.0 - _UNBOUNDED_RTOL):
        hi = math.inf
    return max(lo, 0.0), hi


def disk_center_radius(alpha: float, sigma: float = 0.0) -> tuple[float, float, bool]:
    """Centre and radius of the boundary circle of D(alpha, sigma) in the complex plane.

    Parameters
    ----------
    alpha : float
        Disk size [-].
    sigma : float
        Skew [-].

    Returns
    -------
    center : float
        Real centre of the boundary circle [-] (``inf`` when it is a line).
    radius : float
        Radius [-] (``inf`` when it is a line).
    exterior : bool
        True when D is the exterior of the circle (``alpha (1 + sigma) > 2``); when the
        boundary is the vertical line Re f = gamma_min (``alpha (1 + sigma) == 2``) D is the
        half-plane to its right and ``center``/``radius`` are ``inf``.

    Notes
    -----
    The Moebius map f = (1 + (1 - sigma) delta / 2) / (1 - (1 + sigma) delta / 2) maps the
    circle |delta| = alpha onto a circle symmetric about the real axis through gamma_min
    and the (possibly negative) gamma_max of :func:`disk_gain_margin` without clipping.
    """
    sigma = _check_sigma(sigma)
    lo, hi = _gamma_bounds(alpha, sigma)
    if not math.isfinite(hi):
        return math.inf, math.inf, False
    return 0.5 * (lo + hi), 0.5 * abs(hi - lo), alpha * (1.0 + sigma) > 2.0


def disk_phase_margin_deg(alpha: float, sigma: float = 0.0) -> float:
    """Disk-based phase margin: the largest phase of unit-modulus factors in D(alpha, sigma).

    Parameters
    ----------
    alpha : float
        Disk size [-].
    sigma : float
        Skew [-].

    Returns
    -------
    float
        Phase margin [deg] in [0, 180]; 180 when the whole unit circle lies in D.

    Notes
    -----
    The boundary circle crosses the real axis at gamma_min and gamma_max, so it meets the
    unit circle where cos(phi) = (1 + gamma_min gamma_max) / (gamma_min + gamma_max) [1].
    For sigma = 0 this is phi = 2 atan(alpha / 2).

    References
    ----------
    .. [1] P. Seiler, A. Packard, P. Gahinet, "An Introduction to Disk Margins",
       IEEE Control Systems Magazine 40(5), 2020, eq. (15).
    """
    sigma = _check_sigma(sigma)
    if alpha <= 0.0:
        return 0.0
    lo, hi = _gamma_bounds(alpha, sigma)
    if not math.isfinite(hi):
        c = lo                      # boundary is the line Re f = gamma_min
    else:
        c = (1.0 + lo * hi) / (lo + hi)
    if c <= -1.0:
        return 180.0                # the whole unit circle is inside D
    if c >= 1.0:
        return 0.0
    return math.degrees(math.acos(c))


# ---------------------------------------------------------------------------------------------
# Polynomial machinery
# ---------------------------------------------------------------------------------------------


def _bilinear(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map z-domain polynomials through z = (1 + s)/(1 - s) (same factor for both).

    The unit circle z = exp(j theta) becomes s = j tan(theta / 2), so an H-infinity norm over
    [0, Nyquist] equals one over the whole imaginary axis of the mapped continuous system.
    """
    K = max(len(num), len(den)) - 1
    plus, minus = np.array([1.0, 1.0]), np.array([-1.0, 1.0])

    def conv_pow(base: np.ndarray, k: int) -> np.ndarray:
        out = np.ones(1)
        for _ in range(k):
            out = np.convolve(out, base)
        return out

    def mapped(p: np.ndarray) -> np.ndarray:
        out = np.zeros(K + 1)
        deg = len(p) - 1
        for i, c in enumerate(p):
            k = deg - i
            term = np.convolve(conv_pow(plus, k), conv_pow(minus, K - k))
            out += c * term
        return poly.trim(out)

    return mapped(num), mapped(den)


def _char_poly(L: RationalTF) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    num, den = np.asarray(L.num, float), np.asarray(L.den, float)
    n = max(len(num), len(den))
    return poly.pad(num, n), poly.pad(den, n), poly.pad(num, n) + poly.pad(den, n)


def _is_stable(L: RationalTF, char: np.ndarray) -> bool:
    """Closed-loop stability from the roots of den + num; improper closed loops are unstable."""
    n_deg = max(len(L.num), len(L.den)) - 1
    char = poly.trim(char)
    if len(char) - 1 < len(L.den) - 1 or len(char) - 1 < n_deg:
        # 1 + L(inf) = 0: the loop is not well posed (an infinite sensitivity peak)
        return False
    roots = np.roots(char)
    if roots.size == 0:
        return True
    if L.dt is None:
        return bool(np.all(roots.real < -_STABILITY_RTOL * np.maximum(1.0, np.abs(roots))))
    return bool(np.all(np.abs(roots) < 1.0 - _STABILITY_RTOL))


@dataclass(frozen=True, slots=True)
class _Scaled:
    """G = S + c = g + R(s~)/D(s~) with s = w0 s~, coefficients balanced for conditioning.

    Splitting off the constant g = G(inf) keeps the information about how |G| varies in R
    instead of in a difference of nearly equal numbers: when |L| is small, G is nearly
    constant and N/D forms would lose it to rounding.
    """

    R: np.ndarray
    D: np.ndarray
    g: float
    w0: float

    def abs_at(self, v: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(v, float)
        return np.abs(self.g + np.polyval(self.R, s) / np.polyval(self.D, s))


def _scaled_G(num: np.ndarray, den: np.ndarray, c: float) -> _Scaled:
    """G = S + c = (den + c (den + num)) / (den + num) = g + R/D, frequency scaled by w0.

    ``num`` and ``den`` have equal length (padded) and den + num keeps its leading
    coefficient (a well-posed loop). With leading coefficients n_l, d_l,
    g = (d_l (1 + c) + c n_l) / (n_l + d_l) and R = den (1 + c - g) + num (c - g), whose
    leading coefficient vanishes; for a strictly proper L, g = 1 + c and R = -num exactly.
    w0 is the geometric mean of the closed-loop pole magnitudes, |D_0 / D_m|^(1/m): after
    s = w0 s~ the poles sit around |s~| = 1 and the coefficients stay near O(1).
    """
    D = num + den
    g = (den[0] * (1.0 + c) + c * num[0]) / D[0]
    if num[0] == 0.0:
        R = -num                               # exact: strictly proper L
    else:
        R = den * (1.0 + c - g) + num * (c - g)
    R = poly.trim(np.concatenate([[0.0], R[1:]]))  # the leading term cancels analytically
    D = poly.trim(D)
    nz = np.flatnonzero(D != 0.0)
    core = D[: nz[-1] + 1]                     # drop roots at s = 0 (only with an external flag)
    m = len(core) - 1
    w0 = abs(core[-1] / core[0]) ** (1.0 / m) if m > 0 else 1.0
    if not math.isfinite(w0) or w0 <= 0.0:
        w0 = 1.0

    def scale(p: np.ndarray) -> np.ndarray:
        return p * w0 ** np.arange(len(p) - 1, -1, -1)

    Rs, Ds = scale(R), scale(D)
    f = np.max(np.abs(Ds))
    return _Scaled(Rs / f, Ds / f, float(g), w0)


def _horner(c: list[float], s: complex) -> complex:
    # plain Python: for one point and degree <= ~20 this is ~20x faster than np.polyval
    acc = 0j
    for ci in c:
        acc = acc * s + ci
    return acc


def _horner_rows(C: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Evaluate every row of the coefficient matrix C (descending powers) at all points s.

    One Vandermonde product instead of a Python loop over the degree: the points are scaled
    frequencies of order 1, where summing explicit powers is as accurate as Horner.
    """
    return (np.vander(s, C.shape[1]) @ C.T).T


def _newton_polish(G: _Scaled, v0: np.ndarray | float) -> np.ndarray:
    """Refine local maxima of |G(jv)| from the starting points ``v0``, all at once.

    Newton's method on h(v) = d/dv log|G(jv)|^2 = 2 Re(j G'/G), with
    h'(v) = -2 Re(G''/G - (G'/G)^2) and G' = (R'D - RD')/D^2, evaluated on R and D
    themselves (not on the stationarity polynomial). A step is taken only where h' < 0 (concave
    basin) and is halved until |G| does not decrease, so polishing never lowers a value.
    """
    v = np.atleast_1d(np.asarray(v0, dtype=float)).copy()
    if v.size == 0:
        return v
    R, D, g = G.R, G.D, G.g
    rows = [R, poly.derivative(R), poly.derivative(poly.derivative(R)), D, poly.derivative(D), poly.derivative(poly.derivative(D))]
    C = np.zeros((6, max(len(R), len(D))))
    for i, r in enumerate(rows):
        C[i, C.shape[1] - len(r):] = r
    C_val = C[[0, 3]]
    live = np.arange(v.size)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        nd = _horner_rows(C_val, 1j * v)
        val = np.abs(g + nd[0] / nd[1])
        for _ in range(_NEWTON_STEPS):
            r0, r1, r2, d0, d1, d2 = _horner_rows(C, 1j * v[live])
            G0 = g + r0 / d0
            G1 = (r1 * d0 - r0 * d1) / d0**2
            G2 = (r2 * d0 - r0 * d2) / d0**2 - 2.0 * d1 * (r1 * d0 - r0 * d1) / d0**3
            q1 = G1 / G0
            h = 2.0 * np.real(1j * q1)
            hp = -2.0 * np.real(G2 / G0 - q1 * q1)
            step = -h / hp
            vl = v[live]
            # keep only points in a concave basin that still move
            # (a step below 1e-10 v changes |G| by ~1e-20 relative: converged)
            # heading through v = 0 means the maximum is the w = 0 limit, a candidate already
            go = (hp < 0.0) & np.isfinite(step) & (np.abs(step) > 1e-10 * vl) & (vl + step > 0.0)
            live, step, vl = live[go], step[go], vl[go]
            moved = np.zeros(live.size, dtype=bool)
            pending = np.ones(live.size, dtype=bool)
            for _ in range(_BACKTRACK_STEPS):
                idx = np.flatnonzero(pending)
                if idx.size == 0:
                    break
                v_try = vl[idx] + step[idx]
                nd = _horner_rows(C_val, 1j * v_try)
                val_try = np.abs(g + nd[0] / nd[1])
                better = val_try >= val[live[idx]]
                acc = idx[better]
                v[live[acc]] = v_try[better]
                val[live[acc]] = val_try[better]
                moved[acc] = True
                pending[acc] = False
                step[idx[~better]] *= 0.5
            live = live[moved]
            if live.size == 0:
                break
    return v


def _golden_max(G: _Scaled, lo: float, hi: float, iters: int = 60) -> float:
    """Golden-section maximisation of |G(j exp(u))| over u in [log lo, log hi]."""
    a, b = math.log(lo), math.log(hi)
    r = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - r * (b - a), a + r * (b - a)
    fc, fd = float(G.abs_at(math.exp(c))), float(G.abs_at(math.exp(d)))
    for _ in range(iters):
        if fc > fd:
            b, d, fd = d, c, fc
            c = b - r * (b - a)
            fc = float(G.abs_at(math.exp(c)))
        else:
            a, c, fc = c, d, fd
            d = a + r * (b - a)
            fd = float(G.abs_at(math.exp(d)))
        if b - a < 1e-13:
            break
    return math.exp(0.5 * (a + b))


def _peak(G: _Scaled) -> tuple[float, float]:
    """Exact sup over v >= 0 of |G(jv)| (scaled frequency); returns (peak, v_peak).

    v_peak is ``inf`` when the supremum is the limit at infinite frequency.
    """
    degD = len(G.D) - 1
    # |G|^2 = g^2 + E/B with E = 2 g Re(R D*) + |R|^2 and B = |D|^2 (polynomials in x = v^2):
    # the stationary points of |G|^2 are the roots of E'B - EB'
    B = poly.abs2_even(G.D)
    E = poly.add(2.0 * G.g * poly.cross_even(G.R, G.D), poly.abs2_even(G.R))
    F = poly.trim(poly.sub(np.convolve(poly.derivative(E), B), np.convolve(E, poly.derivative(B))))
    cands = np.zeros(0)
    if len(F) > 1:
        roots = np.roots(F)
        keep = (np.abs(roots.imag) <= _ROOT_IMAG_RTOL * np.abs(roots) + 1e-12) & (roots.real > 0.0)
        cands = np.sqrt(roots.real[keep])
    # Closed-loop poles near the axis make the sharp peaks; where rounding spoils the roots of
    # A'B - AB' (|G| nearly constant, a lightly damped pole), |Im p| and |p| still start
    # Newton in the right basin.
    poles = np.roots(G.D) if degD > 0 else np.zeros(0)
    pole_cands = np.concatenate([np.abs(poles.imag), np.abs(poles)])
    pole_cands = pole_cands[pole_cands > 0.0]
    starts = np.concatenate([cands, pole_cands])
    polished = _newton_polish(G, starts)
    # Guard grid against anything still missed (the larger value wins). The scaled
    # closed-loop poles have geometric-mean magnitude 1; the grid spans them with two decades
    # to spare and at least 1e-4..1e4.
    pm = np.abs(poles[poles != 0.0]) if poles.size and np.any(poles != 0.0) else np.ones(1)
    lo = min(-4.0, math.floor(math.log10(pm.min())) - 2.0)
    hi = max(4.0, math.ceil(math.log10(pm.max())) + 2.0)
    grid = np.logspace(lo, hi, int(round((hi - lo) * _GUARD_POINTS_PER_DECADE)) + 1)
    pts = np.concatenate([[0.0], polished, grid])
    vals = G.abs_at(pts)
    nc = 1 + polished.size
    i = int(np.argmax(vals[:nc]))
    best, best_v = float(vals[i]), float(pts[i])
    j = nc + int(np.argmax(vals[nc:]))
    if vals[j] > best * (1.0 + 1e-12):
        # a peak nothing above caught: refine it between the neighbouring grid points
        v = _golden_max(G, float(pts[max(j - 1, nc)]), float(pts[min(j + 1, pts.size - 1)]))
        v = float(_newton_polish(G, v)[0])
        val = float(G.abs_at(v))
        best, best_v = (val, v) if val > vals[j] else (float(vals[j]), float(pts[j]))
    ginf = abs(G.g)
    if ginf > best:
        best, best_v = ginf, math.inf
    return float(best), float(best_v)


def _continuous_equivalent(L: RationalTF) -> tuple[np.ndarray, np.ndarray]:
    num, den = np.asarray(L.num, float), np.asarray(L.den, float)
    if L.dt is not None:
        num, den = _bilinear(num, den)
    n = max(len(num), len(den))
    return poly.pad(num, n), poly.pad(den, n)


def _to_rad_s(L: RationalTF, v: float) -> float:
    """Map a frequency of the (possibly bilinear-mapped) loop back to [rad/s]."""
    if L.dt is None:
        return v
    return math.pi / L.dt if math.isinf(v) else 2.0 / L.dt * math.atan(v)


def _delay_margin(L: RationalTF, num: np.ndarray, den: np.ndarray, w0: float) -> float:
    """Classical delay margin of L: min over gain crossovers of ((angle L + pi) mod 2 pi) / w_gc.

    Crossovers are the positive roots x = v^2 of |num(jv)|^2 - |den(jv)|^2 (exact, like the
    disk-margin peak), polished by Newton steps on log|L(jv)| = 0. For a discrete loop
    ``num``/``den`` are the bilinear-mapped polynomials: L takes the same value at v as at
    z = exp(j w dt) with w = 2 atan(v) / dt, and the delay is tau = phase / w [s].
    """
    k = np.arange(max(len(num), len(den)) - 1, -1, -1)
    ns, ds = num * w0 ** k[-len(num):], den * w0 ** k[-len(den):]
    f = max(np.max(np.abs(ns)), np.max(np.abs(ds)))
    ns, ds = poly.trim(ns / f), poly.trim(ds / f)
    P = poly.trim(poly.sub(poly.abs2_even(ns), poly.abs2_even(ds)))
    if len(P) <= 1:
        return math.inf
    roots = np.roots(P)
    keep = (np.abs(roots.imag) <= _ROOT_IMAG_RTOL * np.abs(roots) + 1e-12) & (roots.real > 0.0)
    n0, d0 = ns.tolist(), ds.tolist()
    n1, d1 = poly.derivative(ns).tolist(), poly.derivative(ds).tolist()
    best = math.inf
    for x in roots.real[keep]:
        v = math.sqrt(x)
        for _ in range(_NEWTON_STEPS):
            s = 1j * v
            nv, dv = _horner(n0, s), _horner(d0, s)
            if nv == 0 or dv == 0:
                break
            g = math.log(abs(nv / dv))
            gp = (1j * (_horner(n1, s) / nv - _horner(d1, s) / dv)).real
            if gp == 0.0 or abs(g) < 1e-15:
                break
            v_new = v - g / gp
            if not v_new > 0.0:
                break
            v = v_new
        s = 1j * v
        Lv = _horner(n0, s) / _horner(d0, s)
        if not math.isfinite(abs(Lv)) or abs(abs(Lv) - 1.0) > 1e-9:
            continue                    # a spurious (complex) root, not a crossover
        w = _to_rad_s(L, v * w0)
        if w > 0.0:
            best = min(best, ((math.atan2(Lv.imag, Lv.real) + math.pi) % (2.0 * math.pi)) / w)
    return best


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------


def _check_loop(L: RationalTF) -> None:
    if not isinstance(L, RationalTF):
        raise ParameterError(f"loop L must be a RationalTF, got {type(L).__name__}", name="L", value=L)
    if L.dt is not None and (not math.isfinite(L.dt) or L.dt <= 0.0):
        raise ParameterError(f"loop {L.name!r}: sample period dt must be > 0 [s], got {L.dt!r}",
                             name="dt", value=L.dt)


def disk_margin(L: RationalTF, sigma: float = 0.0, *, closed_loop_stable: bool | None = None) -> DiskMargin:
    """Exact disk margin of a SISO loop (continuous, or discrete up to Nyquist).

    Parameters
    ----------
    L : RationalTF
        Loop transfer function L(s) (or L(z) with ``dt``), negative feedback u = -L y.
    sigma : float
        Skew of the disk [-]: 0 balanced (S - T)/2, 1 uses S, -1 uses T.
    closed_loop_stable : bool or None
        Nominal closed-loop stability if known from elsewhere (e.g. ``ForceLoop.stable``,
        which also sees hidden pole-zero cancellations). ``None`` checks the roots of
        den(L) + num(L).

    Returns
    -------
    DiskMargin
        ``alpha`` = 1 / ||S + (sigma - 1)/2||_inf [-] with the disk-based gain margin [-]/[dB],
        phase margin [deg], critical frequency [rad/s] and the classical delay margin of L
        [s]. An unstable closed loop gives ``alpha = 0``, ``stable = False``.

    Raises
    ------
    ParameterError
        If ``L`` is not a RationalTF, ``dt`` is not positive or ``sigma`` is not finite.

    Notes
    -----
    Write G = S + (sigma - 1)/2 = g + R/D with D = den + num and g = G(inf) split off
    exactly (so a nearly constant |G|, i.e. a small |L|, keeps its variation in R instead of
    in a cancelling difference). Then |G(jw)|^2 = g^2 + E(w^2)/B(w^2) with real polynomials
    E = 2 g Re(R D*) + |R|^2 and B = |D|^2, and its stationary points are the nonnegative
    roots x = w^2 of E'B - EB'. The peak is the largest |G| over those roots, over Newton
    starts at |Im p| and |p| of each closed-loop pole (the sharp peaks sit there even when
    rounding spoils the roots), at w = 0 and w -> inf. Every candidate is polished by
    safeguarded Newton steps on d log|G|/dw evaluated from R and D themselves, so values
    are evaluations of G, never extrapolations. A 40-points-per-decade guard grid in scaled
    frequency (closed-loop poles with geometric-mean magnitude 1, two decades beyond the
    extreme poles) catches anything still missed; the larger value wins. Frequencies are
    scaled by that geometric mean for conditioning. A discrete loop is mapped with
    z = (1 + s)/(1 - s), which turns [0, pi/dt] into [0, inf).

    Stability is checked first: python-control 0.10.2's ``disk_margins`` reports a positive
    alpha for an unstable loop, which is wrong (no disk of perturbations around f = 1 keeps
    an unstable loop stable).

    ``delay_margin_s`` is the classical delay margin of L (smallest delay that makes the
    loop marginally stable, from the gain crossovers), not a disk-based bound; ``inf`` when
    |L(jw)| never crosses 1.

    References
    ----------
    .. [1] P. Seiler, A. Packard, P. Gahinet, "An Introduction to Disk Margins",
       IEEE Control Systems Magazine 40(5), 2020.

    Examples
    --------
    >>> dm = disk_margin(RationalTF([25.0], [1.0, 10.0, 10.0, 10.0]))
    >>> round(dm.alpha, 4), round(dm.gain_margin_db[1], 2), round(dm.phase_margin_deg, 1)
    (0.4581, 4.05, 25.8)
    """
    _check_loop(L)
    sigma = _check_sigma(sigma)
    num, den = _continuous_equivalent(L)
    if closed_loop_stable is None:
        _, _, char = _char_poly(L)
        stable = _is_stable(L, char)
    else:
        stable = bool(closed_loop_stable)
    if stable and (num[0] + den[0]) == 0.0:
        # leading terms cancel: 1 + L(inf) = 0 (or, discrete, a closed-loop pole at z = -1)
        stable = False
    return _disk_margin_from(L, num, den, sigma, stable)


def _disk_margin_from(L: RationalTF, num: np.ndarray, den: np.ndarray, sigma: float,
                      stable: bool) -> DiskMargin:
    """disk_margin on the (continuous-equivalent, padded) polynomials; ``L`` gives ``dt``."""
    if not stable:
        return DiskMargin(alpha=0.0, sigma=sigma, gain_margin=(1.0, 1.0), gain_margin_db=(0.0, 0.0),
                          phase_margin_deg=0.0, frequency_rad_s=math.nan, delay_margin_s=0.0,
                          stable=False)
    G = _scaled_G(num, den, 0.5 * (sigma - 1.0))
    peak, v = _peak(G)
    alpha = 1.0 / peak if peak > 0.0 else math.inf
    w = _to_rad_s(L, v * G.w0) if math.isfinite(v) else _to_rad_s(L, math.inf)
    lo, hi = disk_gain_margin(alpha, sigma)
    db = lambda g: 20.0 * math.log10(g) if g > 0.0 else -math.inf  # noqa: E731
    return DiskMargin(
        alpha=alpha,
        sigma=sigma,
        gain_margin=(lo, hi),
        gain_margin_db=(db(lo), db(hi) if math.isfinite(hi) else math.inf),
        phase_margin_deg=disk_phase_margin_deg(alpha, sigma),
        frequency_rad_s=float(w),
        delay_margin_s=float(_delay_margin(L, num, den, G.w0)),
        stable=True,
    )


def disk_margin_curve(L: RationalTF, w_rad_s: Sequence[float] | np.ndarray,
                      sigma: float = 0.0) -> DiskMarginCurve:
    """Frequency-dependent disk margin alpha(w) = 1 / |S(jw) + (sigma - 1)/2| for plots.

    Parameters
    ----------
    L : RationalTF
        Loop transfer function (continuous, or discrete with ``dt``).
    w_rad_s : array_like
        Frequencies [rad/s], shape (n,).
    sigma : float
        Skew [-].

    Returns
    -------
    DiskMarginCurve
        alpha(w) [-], the disk-based gain margins [dB] and phase margins [deg] at each
        frequency. Meaningful only for a stable closed loop (check :func:`disk_margin`).

    Raises
    ------
    ParameterError
        If ``L`` is not a RationalTF or ``sigma`` is not finite.
    """
    _check_loop(L)
    sigma = _check_sigma(sigma)
    w = np.asarray(w_rad_s, dtype=float).ravel()
    c = 0.5 * (sigma - 1.0)
    x = 1j * w if L.dt is None else np.exp(1j * w * L.dt)
    n, d = np.polyval(L.num, x), np.polyval(L.den, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        # S + c = (d (1 + c) + c n) / (n + d): no cancellation for small |L| and no
        # infinity at a pole of L (an integrator gives S = 0 there)
        alpha = np.abs((n + d) / (d * (1.0 + c) + c * n))
    gm = np.empty((w.size, 2))
    pm = np.empty(w.size)
    for i, a in enumerate(alpha):
        lo, hi = disk_gain_margin(float(a), sigma)
        gm[i] = (20.0 * math.log10(lo) if lo > 0.0 else -math.inf,
                 20.0 * math.log10(hi) if math.isfinite(hi) else math.inf)
        pm[i] = disk_phase_margin_deg(float(a), sigma)
    return DiskMarginCurve(w_rad_s=w, alpha=alpha, gain_margin_db=gm, phase_margin_deg=pm, sigma=sigma)


# ---------------------------------------------------------------------------------------------
# Fig. 6: disk margins of the observers in soft and stiff environments
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class MarginRow:
    """One disk of the paper's Fig. 6: an environment, an observer and its Q cutoff."""

    environment: str                        # environment preset name
    observer: str                           # compensator kind ('none' is the plant alone)
    w_q_hz: float | None                    # Q(s) cutoff, None for 'none'      [Hz]
    disk_margin: float                      # alpha (0 if unstable)            [-]
    gain_margin_db: tuple[float, float]     # disk-based (lo, hi)              [dB]
    phase_margin_deg: float                 # disk-based                       [deg]
    frequency_rad_s: float                  # critical frequency               [rad/s]
    stable: bool                            # nominal closed loop stable

    def to_mapping(self) -> dict[str, Any]:
        """JSON row with keys environment, observer, w_q_hz, disk_margin, gain_margin_db,
        phase_margin_deg, frequency_rad_s, stable (infinities as ``None``)."""
        return {
            "environment": self.environment,
            "observer": self.observer,
            "w_q_hz": self.w_q_hz,
            "disk_margin": _json_float(self.disk_margin),
            "gain_margin_db": [_json_float(g) for g in self.gain_margin_db],
            "phase_margin_deg": _json_float(self.phase_margin_deg),
            "frequency_rad_s": _json_float(self.frequency_rad_s),
            "stable": self.stable,
        }


def fig6_table(
    *,
    environments: Sequence[str] = ("soft", "stiff"),
    w_q_hz: Sequence[float] = (1.0, 5.0, 10.0),
    observers: Sequence[str] = ("none", "ea-fob", "lo-dob", "ld-dob"),
    controller: PDController = PDController(P=5.0, D=0.1),
    sigma: float = 0.0,
) -> list[MarginRow]:
    """Disk margins of the force loop with each observer, as in the paper's Fig. 6.

    Parameters
    ----------
    environments : sequence of str
        Environment preset names (paper: ``soft``, ``stiff``).
    w_q_hz : sequence of float
        Q(s) cutoffs [Hz] for every observer (paper: 1, 5, 10).
    observers : sequence of str
        Compensator kinds; ``none`` is the plant alone and gets a single row.
    controller : PDController
        Force controller (paper: P = 5 [N m / N m], D = 0.1 [N m s / N m]).
    sigma : float
        Skew of the disk [-] (the paper uses the balanced disk, 0).

    Returns
    -------
    list of MarginRow
        One row per environment, observer and cutoff (one per environment for ``none``),
        in the order of the arguments.

    Raises
    ------
    ParameterError
        For an unknown environment or observer kind, or a nonpositive cutoff.

    Notes
    -----
    Each loop is :func:`forecast_design.symbolic.loops.force_loop` of the nominal design in
    that environment, broken at the controller; its ``stable`` flag (from the full
    characteristic polynomial, which sees cancellations) is passed to :func:`disk_margin`.
    """
    for kind in observers:
        if kind not in COMPENSATOR_KINDS:
            raise ParameterError(
                f"fig6_table: observer must be one of {', '.join(COMPENSATOR_KINDS)}, got {kind!r}",
                name="observers", value=kind)
    from .symbolic.loops import force_loop  # sympy-backed; imported only when needed
    rows: list[MarginRow] = []
    for env in environments:
        design = Design.nominal(env)
        for kind in observers:
            cutoffs: Sequence[float | None] = (None,) if kind == "none" else tuple(w_q_hz)
            for wq in cutoffs:
                comp = None if wq is None else Compensator(kind=kind, w_q_hz=wq)
                loop = force_loop(design, comp, controller=controller)
                dm = disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))
                rows.append(MarginRow(
                    environment=env, observer=kind, w_q_hz=None if wq is None else float(wq),
                    disk_margin=dm.alpha, gain_margin_db=dm.gain_margin_db,
                    phase_margin_deg=dm.phase_margin_deg, frequency_rad_s=dm.frequency_rad_s,
                    stable=dm.stable,
                ))
    return rows


# ---------------------------------------------------------------------------------------------
# Sampled-data force loop (2 kHz): discretised controller and observer, ZOH plant, delays
# ---------------------------------------------------------------------------------------------

#: Relative size below which a trailing coefficient is the exact rigid-body root w = 0 of a
#: free output (exact in exact arithmetic, see :func:`sampled_force_loop`).
_DEFLATE_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class SampledForceLoop:
    """The sampled-data force loop: discrete controller and observer, ZOH plant, delays.

    Everything is held in the Tustin variable w = (2/T)(z - 1)/(z + 1) [rad/s] (the
    w-plane): a z-polynomial of order ~15 with roots clustered near z = 1 (poles at
    |p| T << 1) has coefficients that no longer determine its roots in double precision,
    while in w the same roots sit near the continuous poles. z = exp(j w T) corresponds to
    w = j (2/T) tan(w T / 2), and |z| < 1 to Re w < 0.

    Attributes
    ----------
    L : RationalTF
        (property) Discrete loop transfer function L(z) (``dt`` set), negative feedback
        [-]; for display and export. Use :meth:`disk_margin` (from ``L_w``) for margins.
    L_w : RationalTF
        The same loop in the w-plane (continuous-time object) [-].
    characteristic_polynomial : ndarray, shape (n + 1,)
        Closed-loop characteristic polynomial in w (descending), full order.
    closed_loop_poles : ndarray of complex, shape (n,)
        Its roots mapped to the z-plane, z = (1 + w T/2)/(1 - w T/2) [-].
    stable : bool
        All w-roots satisfy Re w < -1e-9 max(1, |w|) (i.e. |z| < 1), and the order did not
        drop (no pole at z = -1).
    rate_hz : float
        Sampling rate [Hz].
    delay_samples : int
        Computation delay of the command [samples].
    break_at : str
        ``'controller'`` or ``'plant-input'``.
    C : RationalTF
        Discretised force controller C_F(z) [N m/N m].
    P, P_theta : RationalTF
        ZOH-discretised tau_s/tau_m [N m/N m] and theta/tau_m [rad/(N m)], z-domain.
    observer : tuple of RationalTF
        Discretised (G_m, G_s, G_theta) as the simulator and the C export run them; empty
        without an observer.
    """

    L_w: RationalTF
    characteristic_polynomial: np.ndarray
    closed_loop_poles: np.ndarray
    stable: bool
    rate_hz: float
    delay_samples: int
    break_at: str
    C: RationalTF
    P: RationalTF
    P_theta: RationalTF
    observer: tuple[RationalTF, ...]

    @property
    def max_pole_magnitude(self) -> float:
        """Largest |z| of the closed-loop poles [-]."""
        return float(np.max(np.abs(self.closed_loop_poles))) if self.closed_loop_poles.size else 0.0

    @cached_property
    def L(self) -> RationalTF:
        """Discrete loop L(z) (``dt`` set): Tustin of ``L_w``, computed on first use [-].

        For display and export only: at order ~14 with poles clustered near z = 1 its
        coefficients do not determine the response near z = 1 in double precision
        (python-control's grid on it gave alpha = 0.47 for a loop whose exact margin is
        1.10, stiff/LO-DOB 5 Hz at 2 kHz). Margins come from :meth:`disk_margin` (``L_w``).
        """
        from .discrete import discretize

        lz = discretize(self.L_w, self.rate_hz, "tustin")
        return RationalTF(lz.num, lz.den, dt=1.0 / self.rate_hz, name="L")

    def disk_margin(self, sigma: float = 0.0) -> DiskMargin:
        """Exact disk margin of the sampled loop up to Nyquist.

        Parameters
        ----------
        sigma : float
            Disk skew [-].

        Returns
        -------
        DiskMargin
            As :func:`disk_margin` of L(z) (critical frequency [rad/s] in (0, pi/T], delay
            margin [s]), computed from ``L_w`` and the stability flag of this loop.
        """
        sigma = _check_sigma(sigma)
        a = 0.5 / self.rate_hz
        num, den = np.asarray(self.L_w.num, float), np.asarray(self.L_w.den, float)
        n = max(len(num), len(den))
        num, den = poly.pad(num, n), poly.pad(den, n)
        # disk_margin's discrete variable is s~ = (z - 1)/(z + 1) = a w: coefficients of w^k
        # scale by a^-k
        k = np.arange(n - 1, -1, -1)
        scale = a ** (-k.astype(float))
        num, den = num * scale, den * scale
        f = max(np.max(np.abs(num)), np.max(np.abs(den)))
        stable = self.stable and (num[0] + den[0]) != 0.0
        proxy = RationalTF((1.0,), (1.0,), dt=1.0 / self.rate_hz, name="L")
        return _disk_margin_from(proxy, num / f, den / f, sigma, stable)


def _deflate_w(p: np.ndarray, what: str) -> np.ndarray:
    """p(w) / w for the exact rigid-body root w = 0, checking it is there up to rounding."""
    p = np.asarray(p, float)
    if abs(p[-1]) > _DEFLATE_RTOL * float(np.max(np.abs(p))):
        raise ParameterError(f"sampled_force_loop: {what} has no root at w = 0 (z = 1) to divide out",
                             name=what, value=float(p[-1]))
    return p[:-1] if len(p) > 1 else np.zeros(1)


def _to_w(dtf: Any) -> tuple[np.ndarray, np.ndarray]:
    """A DiscreteTF in the w-plane: Tustin's own source exactly, else z = (1 + a w)/(1 - a w)."""
    if dtf.method == "tustin" and dtf.prewarp_hz is None:
        return np.asarray(dtf.source.num, float), np.asarray(dtf.source.den, float)
    a = 0.5 * dtf.dt
    num, den = np.asarray(dtf.num, float), np.asarray(dtf.den, float)
    n = max(len(num), len(den)) - 1
    rho, ell = np.array([a, 1.0]), np.array([-a, 1.0])

    def mapped(p):
        out = np.zeros(n + 1)
        for i, c in enumerate(poly.pad(p, n + 1)):
            j = n - i
            out += c * poly.mul(poly.power(rho, j), poly.power(ell, n - j))
        return poly.trim(out)

    return mapped(num), mapped(den)


def _common_plant(design: Design) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N_s, N_theta, D): P and P_theta of a design over one continuous denominator."""
    from .symbolic import force_plant_tf, motor_angle_tf

    P = force_plant_tf(design)
    Pt = motor_angle_tf(design)
    pn, pd = np.asarray(P.num, float), np.asarray(P.den, float)
    tn, td = np.asarray(Pt.num, float), np.asarray(Pt.den, float)
    pn, pd = pn / pd[0], pd / pd[0]
    tn, td = tn / td[0], td / td[0]
    if len(pd) == len(td) and np.allclose(pd, td, rtol=1e-12, atol=0.0):
        return pn, tn, pd
    # a free output (k_e = 0): force_plant_tf divided the exact factor s out of P, P_theta keeps
    # the rigid-body pole; bring P back over P_theta's denominator
    q, r = np.polydiv(td, pd)
    if np.all(np.abs(r) <= 1e-12 * np.max(np.abs(td))):
        return poly.mul(pn, q), tn, td
    return poly.mul(pn, td), poly.mul(tn, pd), poly.mul(pd, td)


@dataclass(frozen=True, slots=True)
class _ZohPlant:
    Ns_w: np.ndarray      # w-plane numerators and common denominator
    Nt_w: np.ndarray
    D_w: np.ndarray
    Ns_z: np.ndarray      # z-domain, for display
    Nt_z: np.ndarray
    D_z: np.ndarray
    free: bool


def _zoh_plant(design: Design, rate_hz: float) -> _ZohPlant:
    """ZOH discretisation of [P; P_theta] from one state-space realisation (shared poles).

    With Phi = int_0^T exp(A t) dt (from one matrix exponential), A_d = I + A Phi and
    B_d = Phi B, so A_d - I is formed without cancellation. In the w-plane,
    z I - A_d = a (I + A_d)(w I - A_w)/(1 - a w) with a = T/2 and
    A_w = (I + A_d)^-1 A Phi / a, hence P(w) = (1 - a w) C (w I - A_w)^-1 B~ with
    B~ = (I + A_d)^-1 Phi B / a (P is strictly proper).
    """
    from scipy import linalg, signal

    ns, nt, d = _common_plant(design)
    n = len(d) - 1
    num = np.vstack([poly.pad(ns, n + 1), poly.pad(nt, n + 1)])
    with warnings.catch_warnings():
        # strictly proper: the padded numerators start with zeros, which scipy flags
        warnings.simplefilter("ignore", signal.BadCoefficients)
        A, B, Cm, Dm = signal.tf2ss(num, d)
    if np.any(Dm != 0.0):  # pragma: no cover - P and P_theta are strictly proper
        raise ParameterError("sampled_force_loop: the plant must be strictly proper", name="P", value=None)
    T = 1.0 / rate_hz
    a = 0.5 * T
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n] = A * T
    m[:n, n:] = np.eye(n) * T
    e = linalg.expm(m)
    Ad, Phi = e[:n, :n], e[:n, n:]
    Bd = Phi @ B
    IAd = np.eye(n) + Ad
    Aw = np.linalg.solve(IAd, A @ Phi) / a
    Bw = np.linalg.solve(IAd, Bd) / a
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", signal.BadCoefficients)
        n1, dw = signal.ss2tf(Aw, Bw, Cm, np.zeros((2, 1)))
        numz, denz = signal.ss2tf(Ad, Bd, Cm, Dm)
    ell = np.array([-a, 1.0])
    free = bool(d[-1] == 0.0)
    return _ZohPlant(poly.trim(poly.mul(ell, n1[0])), poly.trim(poly.mul(ell, n1[1])), np.asarray(dw, float),
                     np.asarray(numz[0], float), np.asarray(numz[1], float), np.asarray(denz, float), free)


def sampled_force_loop(
    true_design: Design,
    compensator: Compensator | None = None,
    *,
    controller: PDController = PDController(P=5.0, D=0.1),
    believed: Design | None = None,
    rate_hz: float = 2000.0,
    break_at: str = "controller",
    delay_samples: int = 1,
    derivative_cutoff_hz: float | None = None,
) -> SampledForceLoop:
    """The force loop as it runs on the board: discrete controller and observer, ZOH plant.

    Parameters
    ----------
    true_design : Design
        The real testbed and environment (its ``controller``/``compensator`` are not used).
    compensator : Compensator or None
        Observer (``None``, ``'none'``, ``'sfm'``: plant alone).
    controller : PDController
        Gains of C_F(s) = P + D s / (s / w_d + 1) [N m/N m], [N m s/N m].
    believed : Design or None
        What the observer believes (``None``: the truth).
    rate_hz : float
        Sampling rate [Hz] (Forecast: 2000).
    break_at : str
        ``'controller'``: L = C_F(z) F_DOB(z) at the force-controller output (default, the
        paper's); ``'plant-input'``: at the command going to the motor (the observer's own
        ``tau_m_prev`` loop stays closed: it is memory inside the controller).
    delay_samples : int
        Computation delay d >= 0 [samples]: the command computed from the samples at t_n is
        applied from t_(n+d) (the issue's model: 1; the simulator applies it at once: 0).
    derivative_cutoff_hz : float or None
        Derivative filter of the PD [Hz]; ``None``: the simulator's default (200 Hz).

    Returns
    -------
    SampledForceLoop
        L(z), L in the w-plane, the full characteristic polynomial, poles, stability flag;
        ``.disk_margin(sigma)`` gives the exact margins up to Nyquist.

    Raises
    ------
    ParameterError
        For a bad rate, delay or break point, or an improper observer.

    Notes
    -----
    The pieces are those of the simulator and the C export (one construction, reused):
    C_F(z) is :class:`~forecast_design.simulation.controllers.DiscretePD`'s Tustin
    discretisation, the observer filters are
    :class:`~forecast_design.simulation.controllers.ObserverCompensator`'s (Tustin, each
    filter its own sections) with G_m fed the previous command (z^-1), and the plant
    [P; P_theta] is discretised with a zero-order hold from one state-space realisation
    (both outputs share the poles exp(p T)). A Tustin filter is, in the w-plane, exactly
    the continuous filter it was made from. With the command c, the applied torque
    a = z^-d c, G_x = B_x / E over the product E of the filter denominators,
    P = N_s / D, P_theta = N_theta / D, rho = 1 + w T/2, ell = 1 - w T/2 (z = rho/ell):

        Delta = D E rho^(d+1) - B_m ell rho^d D - (B_s N_s + B_theta N_theta) ell^d rho
        controller:   L = C_n N_s E ell^d rho / (C_d Delta)
        plant-input:  L = (C_n E N_s - C_d (B_s N_s + B_theta N_theta)) ell^d rho
                          / (C_d D rho^d (E rho - B_m ell))
        chi = C_d Delta + C_n N_s E ell^d rho   (both break points: num + den of L)

    chi has the full order (controller, filters, plant and delays): a mode cancelled in L
    still decides stability. A free output (k_e = 0) has the rigid-body root w = 0 in D and
    N_s (and in B_theta, the motor FOB's double differentiator): that exact factor is
    divided out, as :func:`~forecast_design.symbolic.loops.force_loop` divides out s.
    As T -> 0, rho, ell -> 1 and the plant tends to P(s): the loop tends to the continuous
    loop with the same (filtered) PD.
    """
    from .simulation.controllers import DEFAULT_DERIVATIVE_CUTOFF_HZ, DiscretePD, ObserverCompensator
    from .symbolic.loops import BREAK_POINTS

    if break_at not in BREAK_POINTS:
        raise ParameterError(f"break_at must be one of {', '.join(BREAK_POINTS)}, got {break_at!r}",
                             name="break_at", value=break_at)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) or not (rate_hz > 0.0) \
            or not math.isfinite(rate_hz):
        raise ParameterError(f"rate_hz must be a finite number > 0 [Hz], got {rate_hz!r}",
                             name="rate_hz", value=rate_hz)
    if isinstance(delay_samples, bool) or not isinstance(delay_samples, int) or delay_samples < 0:
        raise ParameterError(f"delay_samples must be an integer >= 0, got {delay_samples!r}",
                             name="delay_samples", value=delay_samples)
    if not isinstance(controller, PDController):
        raise ParameterError(f"controller must be a PDController, got {type(controller).__name__}",
                             name="controller", value=controller)
    rate_hz = float(rate_hz)
    T = 1.0 / rate_hz
    a = 0.5 * T
    d = delay_samples
    rho, ell = np.array([a, 1.0]), np.array([-a, 1.0])
    cutoff = DEFAULT_DERIVATIVE_CUTOFF_HZ if derivative_cutoff_hz is None else derivative_cutoff_hz
    ctf = DiscretePD(controller, rate_hz, derivative_cutoff_hz=cutoff).tf
    Cn, Cd = (poly.trim(p) for p in _to_w(ctf))
    plant = _zoh_plant(true_design, rate_hz)
    Ns, Nt, D = plant.Ns_w, plant.Nt_w, plant.D_w
    if compensator is not None and compensator.is_observer:
        obs = ObserverCompensator(compensator, believed if believed is not None else true_design, rate_hz)
        # a zero filter (e.g. G_theta of the DOBs) runs as one zero section: no poles
        pairs = [_to_w(tf) if any(c != 0.0 for c in tf.num) else (np.zeros(1), np.ones(1)) for tf in obs.tfs]
        dens = [den for _, den in pairs]
        E = poly.mul(*dens)
        Bm, Bs, Bt = (poly.mul(num, *(dens[j] for j in range(3) if j != i)) for i, (num, _) in enumerate(pairs))
        observer = tuple(tf.to_rational() for tf in obs.tfs)
    else:
        E, Bm, Bs, Bt = np.ones(1), np.zeros(1), np.zeros(1), np.zeros(1)
        observer = ()
    Bm, Bs, Bt = poly.trim(Bm), poly.trim(Bs), poly.trim(Bt)
    uses_theta = bool(np.any(Bt != 0.0))
    if plant.free:
        D, Ns = _deflate_w(D, "D"), _deflate_w(Ns, "N_s")
        if uses_theta:
            Bt = _deflate_w(Bt, "B_theta")
    if not uses_theta:
        Nt = np.zeros(1)            # theta unused (for a free output: its rigid-body drift too)
    obs_terms = poly.add(poly.mul(Bs, Ns), poly.mul(Bt, Nt))
    ell_d = poly.power(ell, d)
    delta = poly.trim(poly.sub(poly.sub(poly.mul(D, E, poly.power(rho, d + 1)), poly.mul(Bm, ell, poly.power(rho, d), D)),
                       poly.mul(obs_terms, ell_d, rho)))
    feed = poly.trim(poly.mul(Cn, Ns, E, ell_d, rho))
    chi = poly.trim(poly.add(poly.mul(Cd, delta), feed))
    if break_at == "controller":
        Lw = RationalTF(feed, poly.trim(poly.mul(Cd, delta)), name="L_w")
    else:
        num = poly.mul(poly.sub(poly.mul(Cn, E, Ns), poly.mul(Cd, obs_terms)), ell_d, rho)
        den = poly.mul(Cd, D, poly.power(rho, d), poly.sub(poly.mul(E, rho), poly.mul(Bm, ell)))
        Lw = RationalTF(poly.trim(num), poly.trim(den), name="L_w")
    order = (len(Cd) - 1) + (len(D) - 1) + (len(E) - 1) + d + 1
    roots = np.roots(chi) if len(chi) > 1 else np.zeros(0, dtype=complex)
    stable = len(chi) - 1 == order and bool(
        np.all(roots.real < -_STABILITY_RTOL * np.maximum(1.0, np.abs(roots))))
    with np.errstate(divide="ignore", invalid="ignore"):
        poles = (1.0 + a * roots) / (1.0 - a * roots)
    chi = chi.copy()
    chi.flags.writeable = False
    poles = np.asarray(poles, dtype=complex)
    poles.flags.writeable = False
    return SampledForceLoop(
        L_w=Lw, characteristic_polynomial=chi,
        closed_loop_poles=poles, stable=stable, rate_hz=rate_hz, delay_samples=d, break_at=break_at,
        C=RationalTF(ctf.num, ctf.den, dt=T, name="C_F"),
        P=RationalTF(plant.Ns_z, plant.D_z, dt=T, name="P"),
        P_theta=RationalTF(plant.Nt_z, plant.D_z, dt=T, name="P_theta"), observer=observer)


def loop_margins(
    design: Design,
    compensator: Compensator | None = None,
    *,
    believed: Design | None = None,
    controller: PDController | None = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = 1,
    sigma: float = 0.0,
) -> DiskMargin:
    """Disk margin of one force loop (the ``margins`` verb).

    Parameters
    ----------
    design : Design
        The true testbed and environment; its ``controller`` and ``compensator`` are the
        defaults of the next two arguments.
    compensator : Compensator or None
        Observer; ``None`` uses ``design.compensator`` (none if that is unset).
    believed : Design or None
        What the observer believes (environment-knowledge error); ``None``: the truth.
    controller : PDController or None
        Force controller; ``None`` uses ``design.controller`` or the paper's P = 5, D = 0.1.
    break_at : str
        ``'controller'`` (paper) or ``'plant-input'``.
    sampled : bool
        Analyse the sampled-data loop (:func:`sampled_force_loop`: 200 Hz derivative filter,
        Tustin controller and observer, ZOH plant, delays) instead of the continuous one
        (:func:`~forecast_design.symbolic.loops.force_loop`, pure PD).
    rate_hz : float
        Sampling rate for ``sampled`` [Hz].
    delay_samples : int
        Computation delay for ``sampled`` [samples].
    sigma : float
        Disk skew [-].

    Returns
    -------
    DiskMargin
        alpha [-], disk-based gain [dB] and phase [deg] margins, critical frequency [rad/s]
        and delay margin [s]; ``stable`` from the full characteristic polynomial.
    """
    comp = compensator if compensator is not None else design.compensator
    ctrl = controller if controller is not None else (design.controller or PDController(P=5.0, D=0.1))
    if sampled:
        return sampled_force_loop(design, comp, controller=ctrl, believed=believed, rate_hz=rate_hz,
                                  break_at=break_at, delay_samples=delay_samples).disk_margin(sigma)
    from .symbolic.loops import force_loop

    loop = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at)
    return disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))
