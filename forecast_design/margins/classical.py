"""Classical stability margins of a loop, every crossover as MATLAB's ``allmargin`` reports them.

For a loop ``L`` (negative feedback, ``1 + L = 0``):

* gain crossovers ``|L(jw)| = 1``: the phase margin ``PM = 180 deg + arg L`` (wrapped to
  (-180, 180]) and the delay margin ``(PM mod 360 deg) / w`` [s] at each;
* phase crossovers ``arg L(jw) = -180 deg`` (``Im L = 0``, ``Re L < 0``): the gain margin
  ``1 / |L(jw)|`` at each (below 1: the loop goes unstable when the gain *drops* that much);
* the summary margins are those closest to instability: the gain margin with the smallest
  ``|log GM|`` and the phase margin with the smallest ``|PM|`` (MATLAB's ``margin``).

Crossovers are found exactly, not on a grid: they are the positive real roots of
``|N(jw)|^2 - |D(jw)|^2`` and of ``Im(N(jw) conj D(jw))`` (polynomials in ``w``), each
refined by bisection on the exact response; a dense logarithmic grid adds any root the
polynomial root finder misses. A sampled loop is given in the Tustin variable (``L_w`` of
:class:`~forecast_design.loops.sampled.SampledForceLoop`, ``rate_hz`` set): its frequency axis
``W = (2/T) tan(w T / 2)`` maps back to ``w`` below Nyquist, and ``z = -1`` (Nyquist) is a
phase crossover when ``L`` is negative there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import polynomials as poly
from ..errors import ParameterError

__all__ = ["ClassicalMargins", "Crossover", "classical_margins"]


@dataclass(frozen=True, slots=True)
class Crossover:
    """One crossover frequency and its margin.

    Parameters
    ----------
    frequency_rad_s : float
        Where it happens [rad/s].
    gain_margin : float or None
        ``1 / |L|`` at a phase crossover [-] (None at a gain crossover).
    phase_margin_deg : float or None
        ``180 + arg L`` at a gain crossover [deg] (None at a phase crossover).
    delay_margin_s : float or None
        ``(PM mod 360 deg) / w`` at a gain crossover [s]: the smallest added delay that puts
        ``L`` through -1 there (``inf`` when the crossover is at w = 0, None at a phase crossover).
    """

    frequency_rad_s: float
    gain_margin: float | None = None
    phase_margin_deg: float | None = None
    delay_margin_s: float | None = None

    @property
    def gain_margin_db(self) -> float | None:
        """The gain margin in dB [dB] (None at a gain crossover)."""
        return None if self.gain_margin is None else 20.0 * math.log10(self.gain_margin)

    def to_mapping(self) -> dict[str, Any]:
        """JSON row with units in the names."""
        out: dict[str, Any] = {"frequency_rad_s": self.frequency_rad_s,
                               "frequency_hz": self.frequency_rad_s / (2.0 * math.pi)}
        if self.gain_margin is not None:
            out.update(gain_margin=self.gain_margin, gain_margin_db=self.gain_margin_db)
        if self.phase_margin_deg is not None:
            out.update(phase_margin_deg=self.phase_margin_deg,
                       delay_margin_s=None if self.delay_margin_s is None or not math.isfinite(self.delay_margin_s)
                       else self.delay_margin_s)
        return out


@dataclass(frozen=True, slots=True)
class ClassicalMargins:
    """Every crossover of one loop and the summary margins (module docstring).

    Parameters
    ----------
    phase_crossovers : tuple of Crossover
        With their gain margins, ascending frequency.
    gain_crossovers : tuple of Crossover
        With their phase and delay margins, ascending frequency.
    stable : bool
        The closed loop's stability (from its characteristic polynomial, not from these margins).
    """

    phase_crossovers: tuple[Crossover, ...]
    gain_crossovers: tuple[Crossover, ...]
    stable: bool

    @property
    def gain_margin(self) -> Crossover | None:
        """The phase crossover whose gain margin is closest to 1 (None: the gain can grow without bound)."""
        return min(self.phase_crossovers, key=lambda c: abs(math.log(c.gain_margin)), default=None)

    @property
    def phase_margin(self) -> Crossover | None:
        """The gain crossover with the smallest ``|PM|`` (None: ``|L|`` never crosses 1)."""
        return min(self.gain_crossovers, key=lambda c: abs(c.phase_margin_deg), default=None)

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the summary margins with their frequencies and every crossover (``allmargin``)."""
        gm, pm = self.gain_margin, self.phase_margin
        return {
            "stable": self.stable,
            "gain_margin": None if gm is None else gm.gain_margin,
            "gain_margin_db": None if gm is None else gm.gain_margin_db,
            "phase_crossover_rad_s": None if gm is None else gm.frequency_rad_s,
            "phase_margin_deg": None if pm is None else pm.phase_margin_deg,
            "gain_crossover_rad_s": None if pm is None else pm.frequency_rad_s,
            "delay_margin_s": None if pm is None or pm.delay_margin_s is None
            or not math.isfinite(pm.delay_margin_s) else pm.delay_margin_s,
            "all_gain_margins": [c.to_mapping() for c in self.phase_crossovers],
            "all_phase_margins": [c.to_mapping() for c in self.gain_crossovers],
        }


def _jw_poly(p: np.ndarray) -> np.ndarray:
    """Complex coefficients of ``p(j w)`` as a polynomial in ``w`` (descending)."""
    n = len(p) - 1
    return np.asarray(p, dtype=float) * (1j) ** np.arange(n, -1, -1)


def _positive_real_roots(c: np.ndarray, w_max: float) -> list[float]:
    c = poly.trim(np.asarray(c, dtype=float))
    if len(c) <= 1:
        return []
    scale = np.max(np.abs(c))
    roots = np.roots(c / scale)
    out = []
    for r in roots:
        if r.real > 0.0 and abs(r.imag) <= 1e-6 * abs(r) and r.real < w_max:
            out.append(float(r.real))
    return out


def _bisect(f, a: float, b: float) -> float:
    fa = f(a)
    for _ in range(200):
        m = 0.5 * (a + b) if b / a < 4.0 else math.sqrt(a * b)
        fm = f(m)
        if fm == 0.0:
            return m
        if (fm > 0.0) == (fa > 0.0):
            a, fa = m, fm
        else:
            b = m
        if b - a <= 1e-14 * b:
            break
    return 0.5 * (a + b)


def _roots_of(f, candidates: list[float], grid: np.ndarray) -> list[float]:
    """Sign changes of ``f`` (vectorised over an array of frequencies) refined by bisection: brackets
    around the candidates and on the grid."""
    points = np.unique(np.concatenate([grid, np.asarray(candidates) * (1 - 1e-6), np.asarray(candidates) * (1 + 1e-6)]))
    points = points[points > 0.0]
    values = f(points)
    finite = np.isfinite(values[:-1]) & np.isfinite(values[1:])
    change = finite & ((values[:-1] > 0.0) != (values[1:] > 0.0))
    roots = [float(points[i]) for i in np.flatnonzero(finite & (values[:-1] == 0.0))]
    scalar = lambda w: float(f(np.array([w]))[0])  # noqa: E731
    roots += [_bisect(scalar, float(points[i]), float(points[i + 1])) for i in np.flatnonzero(change & (values[:-1] != 0.0))]
    roots.sort()
    merged: list[float] = []
    for r in roots:
        if not merged or r > merged[-1] * (1 + 1e-9):
            merged.append(r)
    return merged


def classical_margins(L: Any, *, stable: bool, rate_hz: float | None = None) -> ClassicalMargins:
    """Every gain and phase crossover of a loop, with its margin (module docstring).

    Parameters
    ----------
    L : RationalTF
        The loop: continuous in ``s``, or, with ``rate_hz``, a sampled loop in the Tustin
        variable ``w`` (``SampledForceLoop.L_w``).
    stable : bool
        Whether the closed loop is stable (from its characteristic polynomial).
    rate_hz : float, optional
        The sampling rate of a loop given in ``w`` [Hz].

    Returns
    -------
    ClassicalMargins
        Crossovers at physical frequencies [rad/s] (below Nyquist when sampled).

    Examples
    --------
    >>> from forecast_design.lti import RationalTF
    >>> m = classical_margins(RationalTF((2.0,), (1.0, 1.0, 1.0, 0.0)), stable=True)   # 2/(s (s^2 + s + 1))
    >>> round(m.gain_margin.gain_margin, 9), round(m.gain_margin.frequency_rad_s, 9)
    (0.5, 1.0)
    """
    num, den = np.asarray(L.num, dtype=float), np.asarray(L.den, dtype=float)
    if L.dt is not None:
        raise ParameterError("classical_margins takes a continuous loop or a sampled loop in w (L_w with rate_hz)",
                             name="L", value=L.dt)
    T = None if rate_hz is None else 1.0 / float(rate_hz)
    w_max = math.inf if T is None else math.inf   # W spans [0, inf) below Nyquist either way

    def L_of(w: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(w, dtype=float)
        return np.polyval(num, s) / np.polyval(den, s)

    def L_at(w: float) -> complex:
        return complex(L_of(np.array([w]))[0])

    def physical(W: float) -> float:
        return W if T is None else (2.0 / T) * math.atan(W * T / 2.0)

    Nj, Dj = _jw_poly(num), _jw_poly(den)
    mag = poly.add(np.real(np.convolve(Nj, np.conj(Nj))), -np.real(np.convolve(Dj, np.conj(Dj))))
    im = np.imag(np.convolve(Nj, np.conj(Dj)))
    grid = np.geomspace(1e-6, 1e9, 3000)
    with np.errstate(all="ignore"):
        gains = _roots_of(lambda w: np.abs(L_of(w)) - 1.0, _positive_real_roots(mag, w_max), grid)
        phases = _roots_of(lambda w: L_of(w).imag, _positive_real_roots(im, w_max), grid)
    gain_x = []
    for W in gains:
        w = physical(W)
        pm = math.degrees(math.atan2(L_at(W).imag, L_at(W).real)) + 180.0
        pm = (pm + 180.0) % 360.0 - 180.0
        # the smallest added delay that puts L through -1 at this crossover: the phase wrapped to [0, 360)
        gain_x.append(Crossover(w, phase_margin_deg=pm,
                                delay_margin_s=math.radians(pm % 360.0) / w if w > 0 else math.inf))
    phase_x = []
    for W in phases:
        value = L_at(W)
        if value.real < 0.0 and abs(value.imag) <= 1e-8 * abs(value):
            phase_x.append(Crossover(physical(W), gain_margin=1.0 / abs(value)))
    # the ends of the axis: w = 0 and (sampled) Nyquist, where L is real
    for W, w in ((0.0, 0.0), (math.inf, None if T is None else math.pi / T)):
        if w is None:
            continue
        with np.errstate(all="ignore"):
            if W == 0.0:
                value = L_at(0.0) if den[-1] != 0.0 else complex("nan")
            else:
                n, d = poly.trim(num), poly.trim(den)
                value = complex(n[0] / d[0]) if len(n) == len(d) else complex(0.0)
        if np.isfinite(value) and value.real < 0.0 and value != 0.0:
            phase_x.append(Crossover(w, gain_margin=1.0 / abs(value)))
    phase_x.sort(key=lambda c: c.frequency_rad_s)
    return ClassicalMargins(tuple(phase_x), tuple(gain_x), bool(stable))
