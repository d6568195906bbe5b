"""Exact disk margin of one loop: the peak of |S + (sigma - 1)/2| from the roots of a polynomial, not on a grid."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .. import polynomials as poly
from ..errors import IllConditionedWarning, ParameterError
from ..lti import RationalTF
from .disk import DiskMargin, DiskMarginCurve, check_skew, disk_gain_margin, disk_phase_margin_deg, resolve_skew


# A closed-loop root counts as stable only if Re(p) < -_STABILITY_RTOL * max(1, |p|): roots
# on the imaginary axis (e.g. L = 1/s^2) are computed as +-1e-17 and must not pass.
#: A closed-loop root is stable when Re(p) < -STABILITY_TOLERANCE * max(1, |p|) [-].
STABILITY_TOLERANCE = 1e-9
_STABILITY_RTOL = STABILITY_TOLERANCE
# Roots of the stationarity polynomial with |Im x| up to this fraction of |x| are kept as
# candidates. Keeping spurious ones is harmless: every candidate is evaluated on the actual
# |G(jw)|, so the maximum can only improve; dropping a true one is what must not happen.
_ROOT_IMAG_RTOL = 1e-3
# Points per decade of the guard grid (scaled frequency), see _peak.
_GUARD_POINTS_PER_DECADE = 40
_NEWTON_STEPS = 8
_BACKTRACK_STEPS = 4


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
        stable = bool(np.all(roots.real < -_STABILITY_RTOL * np.maximum(1.0, np.abs(roots))))
    else:
        stable = bool(np.all(np.abs(roots) < 1.0 - _STABILITY_RTOL))
    worst = undetermined_root(char, roots, discrete=L.dt is not None)
    if worst is not None:
        root, radius, distance = worst
        where = f"|z| = {abs(root):.6g}" if L.dt is not None else f"Re s = {root.real:.6g}"
        warnings.warn(f"loop {L.name!r}: its closed-loop characteristic polynomial (degree {len(char) - 1}) does "
                      f"not determine on which side of the stability boundary its root at {where} lies "
                      f"(perturbation radius {radius:.2g} in double precision, distance {distance:.2g}): the "
                      f"verdict ({'stable' if stable else 'unstable'}) and the margin may be wrong; analyse a "
                      "better-conditioned form (a sampled loop's w-plane `SampledForceLoop.disk_margin`, or a "
                      "state-space model)", IllConditionedWarning, stacklevel=3)
    return stable


def undetermined_root(char: np.ndarray, roots: np.ndarray | None = None, *,
                      discrete: bool) -> tuple[complex, float, float] | None:
    """The root whose side of the stability boundary the polynomial's coefficients cannot tell.

    A simple root r of p(x) = sum a_k x^k moves by at most
    ``eps sum_k |a_k| |r|^k / |p'(r)|`` under relative coefficient errors ``eps`` (to first order,
    Wilkinson); with ``eps`` the unit round-off times the degree (the backward error of the
    companion eigenvalues), a root closer to the stability threshold (|z| = 1, or Re s = 0, less
    :data:`STABILITY_TOLERANCE`) than that radius may lie on either side. Sampled loops written as z-polynomials at a high rate
    (poles clustered near z = 1) are the usual case.

    Parameters
    ----------
    char : ndarray
        Characteristic polynomial, descending coefficients.
    roots : ndarray or None
        Its roots, if already computed.
    discrete : bool
        Boundary |z| = 1 (True) or Re s = 0 (False).

    Returns
    -------
    (root, radius, distance) or None
        The undetermined root with the largest radius-to-distance ratio, its perturbation radius
        and its distance to the boundary (both in the root's units); ``None`` when every root's
        side is determined.
    """
    char = np.asarray(char, dtype=float)
    roots = np.roots(char) if roots is None else np.asarray(roots)
    n = len(char) - 1
    if n < 1 or roots.size == 0:
        return None
    powers = np.abs(roots)[:, None] ** np.arange(n, -1, -1)[None, :]
    slope = np.abs(np.polyval(np.polyder(char), roots))
    with np.errstate(divide="ignore", invalid="ignore"):
        radius = n * np.finfo(float).eps * (powers @ np.abs(char)) / slope
    radius = np.where(np.isfinite(radius), radius, np.inf)
    # distance to the verdict's own threshold (a root inside the tolerance band is unstable either way)
    distance = (np.abs(1.0 - _STABILITY_RTOL - np.abs(roots)) if discrete
                else np.abs(roots.real + _STABILITY_RTOL * np.maximum(1.0, np.abs(roots))))
    ratio = radius / np.maximum(distance, np.finfo(float).tiny)
    i = int(np.argmax(ratio))
    if ratio[i] <= 1.0:
        return None
    return complex(roots[i]), float(radius[i]), float(distance[i])


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


def continuous_equivalent(L: RationalTF) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator of L in s, or of its bilinear map when L is discrete, padded to one length.

    Parameters
    ----------
    L : RationalTF
        The loop.

    Returns
    -------
    tuple of ndarray
        ``(num, den)``, highest power first, equal lengths.
    """
    num, den = np.asarray(L.num, float), np.asarray(L.den, float)
    if L.dt is not None:
        num, den = _bilinear(num, den)
    n = max(len(num), len(den))
    return poly.pad(num, n), poly.pad(den, n)


def frequency_rad_s(L: RationalTF, v: float) -> float:
    """Map a frequency of the (possibly bilinear-mapped) loop back to [rad/s].

    Parameters
    ----------
    L : RationalTF
        The loop (``dt`` [s] or None).
    v : float
        Frequency of :func:`continuous_equivalent` [rad/s or bilinear units].

    Returns
    -------
    float
        The loop's frequency [rad/s].
    """
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
        w = frequency_rad_s(L, v * w0)
        if w > 0.0:
            best = min(best, ((math.atan2(Lv.imag, Lv.real) + math.pi) % (2.0 * math.pi)) / w)
    return best


def as_loop(L: Any) -> RationalTF:
    """The loop as a RationalTF (python-control TransferFunction/StateSpace accepted), checked.

    Parameters
    ----------
    L : RationalTF or control.TransferFunction or control.StateSpace
        The loop.

    Returns
    -------
    RationalTF
        The loop, checked (positive finite ``dt`` when discrete).
    """
    if not isinstance(L, RationalTF):
        if type(L).__module__.split(".")[0] != "control":
            raise ParameterError(f"loop L must be a RationalTF or a python-control TransferFunction/StateSpace, "
                                 f"got {type(L).__name__}", name="L", value=L)
        L = RationalTF.from_control(L)
    if L.dt is not None and (not math.isfinite(L.dt) or L.dt <= 0.0):
        raise ParameterError(f"loop {L.name!r}: sample period dt must be > 0 [s], got {L.dt!r}",
                             name="dt", value=L.dt)
    return L


def _state_space_loop(sys: Any) -> tuple[RationalTF, np.ndarray, np.ndarray, bool]:
    """A SISO python-control StateSpace loop: (proxy, num, den in s or s~, closed-loop stable).

    Discrete: with ``z = (1 + s~)/(1 - s~)``, ``zI - A`` factors so that
    ``L(z) = D - C (I + A)^-1 B + C (I + A)^-1 (I - A_c) (s~ I - A_c)^-1 B`` with
    ``A_c = (A - I)(I + A)^-1``: the eigenvalues near z = 1 become well-separated roots near
    s~ = 0. Stability: the eigenvalues of ``A - B (1 + D)^-1 C`` (unit circle or left half-plane).
    """
    from scipy import signal

    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ParameterError(f"only SISO loops are supported, got {sys.noutputs}x{sys.ninputs}", name="L", value=sys)
    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
    d = float(D[0, 0])
    n = A.shape[0]
    dt = sys.dt
    if dt is True:
        raise ParameterError("discrete system with unspecified period (dt=True): give its sample time",
                             name="dt", value=dt)
    discrete = bool(dt)
    if 1.0 + d == 0.0:
        stable = False
    elif n == 0:
        stable = True
    else:
        eig = np.linalg.eigvals(A - B @ C / (1.0 + d))
        stable = bool(np.all(np.abs(eig) < 1.0 - STABILITY_TOLERANCE)) if discrete else \
            bool(np.all(eig.real < -STABILITY_TOLERANCE * np.maximum(1.0, np.abs(eig))))
    if n == 0:
        num, den = np.array([d]), np.array([1.0])
    else:
        if discrete:
            IA = np.eye(n) + A
            Ac = np.linalg.solve(IA.T, (A - np.eye(n)).T).T          # (A - I)(I + A)^-1
            M = np.linalg.solve(IA.T, C.T).T                           # C (I + A)^-1
            A_, B_, C_, d_ = Ac, B, M @ (np.eye(n) - Ac), d - float((M @ B)[0, 0])
        else:
            A_, B_, C_, d_ = A, B, C, d
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", signal.BadCoefficients)
                nn, dd = signal.ss2tf(A_, B_, C_, np.array([[d_]]))
        num, den = poly.trim(np.asarray(nn[0], float)), poly.trim(np.asarray(dd, float))
    k = max(len(num), len(den))
    proxy = RationalTF((1.0,), (1.0,), dt=float(dt) if discrete else None, name=str(sys.name or "L"))
    return proxy, poly.pad(num, k), poly.pad(den, k), stable


def disk_margin(L: RationalTF, skew: float = 0.0, *, closed_loop_stable: bool | None = None,
                sigma: float | None = None) -> DiskMargin:
    """Exact disk margin of a SISO loop (continuous, or discrete up to Nyquist).

    Parameters
    ----------
    L : RationalTF, control.TransferFunction or control.StateSpace
        Loop transfer function L(s) (or L(z) with ``dt``), negative feedback u = -L y.
    skew : float
        Skew sigma of the disk [-] (python-control's and MATLAB's ``skew``): 0 balanced
        (S - T)/2, 1 uses S, -1 uses T.
    closed_loop_stable : bool or None
        Nominal closed-loop stability if known from elsewhere (e.g. ``ForceLoop.stable``,
        which also sees hidden pole-zero cancellations). ``None`` checks the roots of
        den(L) + num(L).
    sigma : float or None
        Alias of ``skew`` (the name used before; give one of the two).

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
    sigma = check_skew(resolve_skew(skew, sigma))
    if type(L).__name__ == "StateSpace" and type(L).__module__.split(".")[0] == "control":
        # analysed on its own realisation: stability from the closed-loop state matrix, the
        # frequency response from the bilinear image of (A, B, C, D) (no z-polynomial roots)
        proxy, num, den, ss_stable = _state_space_loop(L)
        stable = ss_stable if closed_loop_stable is None else bool(closed_loop_stable)
        if stable and (num[0] + den[0]) == 0.0:
            stable = False
        return disk_margin_from_polynomials(proxy, num, den, sigma, stable)
    L = as_loop(L)
    num, den = continuous_equivalent(L)
    if closed_loop_stable is None:
        _, _, char = _char_poly(L)
        stable = _is_stable(L, char)
    else:
        stable = bool(closed_loop_stable)
    if stable and (num[0] + den[0]) == 0.0:
        # leading terms cancel: 1 + L(inf) = 0 (or, discrete, a closed-loop pole at z = -1)
        stable = False
    return disk_margin_from_polynomials(L, num, den, sigma, stable)


def disk_margin_from_polynomials(L: RationalTF, num: np.ndarray, den: np.ndarray, sigma: float,
                                 stable: bool) -> DiskMargin:
    """:func:`disk_margin` of a loop given as continuous-equivalent polynomials.

    Parameters
    ----------
    L : RationalTF
        The loop (or a proxy of the same ``dt``); only ``dt`` is used, to map the critical
        frequency back to [rad/s].
    num, den : ndarray
        Numerator and denominator of the continuous (or w-plane) loop, padded to one length,
        descending powers.
    sigma : float
        Disk skew [-].
    stable : bool
        Whether the closed loop is stable (from its full characteristic polynomial).

    Returns
    -------
    DiskMargin
        As :func:`disk_margin`.
    """
    if not stable:
        return DiskMargin(alpha=0.0, sigma=sigma, gain_margin=(1.0, 1.0), gain_margin_db=(0.0, 0.0),
                          phase_margin_deg=0.0, frequency_rad_s=math.nan, delay_margin_s=0.0,
                          stable=False)
    G = _scaled_G(num, den, 0.5 * (sigma - 1.0))
    peak, v = _peak(G)
    alpha = 1.0 / peak if peak > 0.0 else math.inf
    w = frequency_rad_s(L, v * G.w0) if math.isfinite(v) else frequency_rad_s(L, math.inf)
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
                      skew: float = 0.0, *, sigma: float | None = None) -> DiskMarginCurve:
    """Frequency-dependent disk margin alpha(w) = 1 / |S(jw) + (sigma - 1)/2| for plots.

    Parameters
    ----------
    L : RationalTF, control.TransferFunction or control.StateSpace
        Loop transfer function (continuous, or discrete with ``dt``).
    w_rad_s : array_like
        Frequencies [rad/s], shape (n,).
    skew : float
        Skew sigma [-] (python-control's ``skew``).
    sigma : float or None
        Alias of ``skew``.

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
    L = as_loop(L)
    sigma = check_skew(resolve_skew(skew, sigma))
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
