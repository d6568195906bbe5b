"""Disk geometry (Seiler, Packard, Gahinet 2020): skew, the gains and phases a disk margin alpha covers, and the margin result types."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError


_UNBOUNDED_RTOL = 1e-12


def json_float(x: float) -> float | None:
    """A number for JSON, which has no infinity.

    Parameters
    ----------
    x : float
        Any value (any unit).

    Returns
    -------
    float or None
        ``x``, or None when it is infinite or NaN.
    """
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

    @property
    def skew(self) -> float:
        """The disk's skew (python-control's and MATLAB's name for ``sigma``) [-]."""
        return self.sigma

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping; infinite values (e.g. an unbounded gain margin) become ``None``.

        ``disk_margin`` is ``alpha`` (both keys kept), ``skew`` is ``sigma``, ``phase_margins_deg``
        is ``[-phase, +phase]`` as MATLAB's ``diskmargin`` reports it and ``frequency_hz`` the
        critical frequency in Hz.
        """
        pm, w = json_float(self.phase_margin_deg), json_float(self.frequency_rad_s)
        return {
            "disk_margin": json_float(self.alpha),
            "skew": self.sigma,
            "phase_margins_deg": None if pm is None else [-pm, pm],
            "frequency_hz": None if w is None else w / (2.0 * math.pi),
            "alpha": json_float(self.alpha),
            "sigma": self.sigma,
            "gain_margin": [json_float(g) for g in self.gain_margin],
            "gain_margin_db": [json_float(g) for g in self.gain_margin_db],
            "phase_margin_deg": json_float(self.phase_margin_deg),
            "frequency_rad_s": json_float(self.frequency_rad_s),
            "delay_margin_s": json_float(self.delay_margin_s),
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
        """JSON-ready mapping (lists; infinities become ``None``); ``disk_margin``, ``frequency_hz`` and
        ``skew`` are the keys every verb uses (``alpha``, ``w_rad_s`` and ``sigma`` kept)."""
        alpha = [json_float(a) for a in self.alpha]
        return {
            "frequency_hz": [float(w) / (2.0 * math.pi) for w in self.w_rad_s],
            "disk_margin": alpha,
            "skew": self.sigma,
            "w_rad_s": [float(w) for w in self.w_rad_s],
            "alpha": alpha,
            "gain_margin_db": [[json_float(lo), json_float(hi)] for lo, hi in self.gain_margin_db],
            "phase_margin_deg": [json_float(p) for p in self.phase_margin_deg],
            "sigma": self.sigma,
        }


def resolve_skew(skew: float, sigma: float | None) -> float:
    """``skew``, or its alias ``sigma`` when given (both differing is an error).

    Parameters
    ----------
    skew : float
        Disk skew [-] (python-control and MATLAB name).
    sigma : float or None
        Its alias [-].

    Returns
    -------
    float
        The skew to use.
    """
    if sigma is not None and skew not in (0.0, sigma):
        raise ParameterError(f"give skew or its alias sigma, not both ({skew!r} and {sigma!r})", name="skew")
    return skew if sigma is None else sigma


def check_skew(sigma: float) -> float:
    """Validate the disk skew ``sigma`` (a finite number; 0 is the balanced disk).

    Parameters
    ----------
    sigma : float
        Skew [-].

    Returns
    -------
    float
        ``sigma`` as a float.
    """
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not math.isfinite(sigma):
        raise ParameterError(f"disk margin skew sigma must be a finite number, got {sigma!r}",
                             name="sigma", value=sigma)
    if abs(sigma) > SKEW_LIMIT:   # beyond it the disk's gain bounds over/underflow (1e300 divides by zero)
        raise ParameterError(f"disk margin skew sigma must lie in [-{SKEW_LIMIT:g}, {SKEW_LIMIT:g}], got {sigma!r}",
                             name="sigma", value=sigma)
    return float(sigma)


#: Largest |sigma| accepted (sigma = +-1 already gives a disk touching 0 or infinity; 100 is far past any use).
SKEW_LIMIT = 100.0


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
    sigma = check_skew(sigma)
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
    sigma = check_skew(sigma)
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
    sigma = check_skew(sigma)
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
