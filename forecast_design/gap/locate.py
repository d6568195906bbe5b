"""Where the gap lies: time windows, frequency band, speed band and what the log can discriminate."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

from .residuals import GapData

__all__ = ["Location", "locate_gap", "empirical_response", "measured_response", "tone_fraction"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Location:
    """Where the residual of the calibrated nominal model concentrates.

    Parameters
    ----------
    time_windows_s : tuple of (float, float)
        Windows holding the largest residual energy, largest first [s].
    frequency_band_hz : (float, float)
        Band holding the central 80 % of the residual energy (Welch PSD) [Hz].
    speed_band_rad_s : (float, float)
        Motor-speed band |theta'| where the residual RMS exceeds half its peak [rad/s].
    angle_span_rad : float
        Range of motor angle covered by the log [rad].
    n_reversals : int
        Number of motor direction reversals [-].
    angle_fraction : float
        Share of the motor-side residual variance explained by harmonics of the motor angle [-].
    reversal_ratio : float
        Residual RMS within 50 ms of a reversal over the RMS elsewhere [-].
    torque_fraction : float
        Share of the motor-side residual variance explained by a multiple of the command [-].
    equation_share : dict
        Share of the residual energy per equation [-].
    notes : tuple of str
        Discrimination limits of this log, in words.
    tone_fraction : float
        Share of the command variance in its strongest spectral line (1 for a pure sine) [-].
    tone_hz : float
        Frequency of that line [Hz].
    """

    time_windows_s: tuple[tuple[float, float], ...]
    frequency_band_hz: tuple[float, float]
    speed_band_rad_s: tuple[float, float]
    angle_span_rad: float
    n_reversals: int
    angle_fraction: float
    reversal_ratio: float
    torque_fraction: float
    equation_share: dict
    notes: tuple[str, ...]
    tone_fraction: float = 0.0
    tone_hz: float = 0.0

    @property
    def single_tone(self) -> bool:
        """True when the command is essentially one sine (>= 95 % of its variance in one line)."""
        return self.tone_fraction >= 0.95

    @property
    def full_revolution(self) -> bool:
        """True when the motor angle covers at least one revolution."""
        return self.angle_span_rad >= 2.0 * np.pi

    def summary(self) -> str:
        """One paragraph in words for ``location.summary``."""
        share = ", ".join(f"{k} {100 * v:.0f} %" for k, v in self.equation_share.items())
        parts = [
            f"Residual energy by equation: {share}.",
            f"Most residual energy lies in {self.frequency_band_hz[0]:.2g}-{self.frequency_band_hz[1]:.2g} Hz "
            f"and at motor speeds {self.speed_band_rad_s[0]:.2g}-{self.speed_band_rad_s[1]:.2g} rad/s.",
            f"Motor-angle harmonics explain {100 * self.angle_fraction:.0f} % of the motor-side residual "
            f"(angle span {self.angle_span_rad:.2f} rad); a multiple of the command explains "
            f"{100 * self.torque_fraction:.0f} %; " + (
                f"the residual near the {self.n_reversals} direction reversals is {self.reversal_ratio:.2g} times "
                "its RMS elsewhere." if np.isfinite(self.reversal_ratio) else
                f"{self.n_reversals} direction reversals, too few (or too close together) to compare the residual "
                "near them with the rest."),
        ]
        return " ".join(parts + list(self.notes))

    def to_mapping(self) -> dict[str, Any]:
        """The ``location`` object of the diagnosis JSON."""
        return {"time_windows_s": [[float(a), float(b)] for a, b in self.time_windows_s],
                "frequency_band_hz": [float(x) for x in self.frequency_band_hz],
                "speed_band_rad_s": [float(x) for x in self.speed_band_rad_s],
                "summary": self.summary()}


def _windows(t: np.ndarray, r2: np.ndarray, n_max: int = 5) -> tuple[tuple[float, float], ...]:
    m = t.size
    n_win = max(4, min(40, m // 20))
    edges = np.linspace(0, m, n_win + 1).astype(int)
    energy = np.array([r2[a:b].sum() for a, b in zip(edges[:-1], edges[1:])])
    mean = energy.mean()
    hot = energy > 1.5 * mean if energy.max() > 1.5 * mean else energy >= np.sort(energy)[-1]
    spans = []
    i = 0
    while i < n_win:
        if hot[i]:
            j = i
            while j + 1 < n_win and hot[j + 1]:
                j += 1
            spans.append((energy[i:j + 1].sum(), float(t[edges[i]]), float(t[min(edges[j + 1], m - 1)])))
            i = j + 1
        else:
            i += 1
    spans.sort(key=lambda s: -s[0])
    return tuple((a, b) for _, a, b in spans[:n_max])


def _band(f: np.ndarray, p: np.ndarray, lo: float = 0.1, hi: float = 0.9) -> tuple[float, float]:
    c = np.cumsum(p)
    if c[-1] <= 0:
        return (float(f[0]), float(f[-1]))
    c = c / c[-1]
    return (float(f[np.searchsorted(c, lo)]), float(f[min(np.searchsorted(c, hi), f.size - 1)]))


def _explained(y: np.ndarray, X: np.ndarray) -> float:
    if y.size == 0 or not np.any(y):
        return 0.0
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(max(0.0, 1.0 - np.sum((y - X @ coef) ** 2) / np.sum((y - y.mean()) ** 2)))


def tone_fraction(x: np.ndarray, rate_hz: float) -> tuple[float, float]:
    """Share of a signal's variance in its strongest spectral line, and that line's frequency.

    Parameters
    ----------
    x : ndarray, shape (n,)
        A signal, e.g. the motor command (any unit).
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    fraction : float
        Variance within +-3 Welch bins (Hann, segments of ~4 s) of the PSD peak over the
        total variance [-]; near 1 for a single sine, small for broadband excitation.
    frequency_hz : float
        Frequency of the peak [Hz].
    """
    x = np.asarray(x, dtype=float) - float(np.mean(x))
    n = int(min(x.size, max(256, 4.0 * rate_hz)))
    f, p = signal.welch(x, fs=rate_hz, nperseg=n)
    total = float(p.sum())
    if total <= 0.0:
        return 0.0, 0.0
    i = int(np.argmax(p))
    return float(p[max(0, i - 3):i + 4].sum() / total), float(f[i])


def locate_gap(data: GapData, residual: np.ndarray) -> Location:
    """Localise a stacked residual in time, frequency and operating region.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    residual : ndarray, shape (m * n_equations,)
        Stacked residual of the calibrated nominal model [N m].

    Returns
    -------
    Location
        Windows, bands, coverage statistics and discrimination notes.
    """
    m = data.t.size
    parts = {eq: residual[i * m:(i + 1) * m] for i, eq in enumerate(data.equations)}
    r2 = sum(p ** 2 for p in parts.values())
    total = float(r2.sum()) or 1.0
    share = {eq: float(np.sum(p ** 2) / total) for eq, p in parts.items()}
    fs = data.settings.decimated_rate_hz
    f, psd = signal.welch(np.column_stack(list(parts.values())), fs=fs, nperseg=min(m, 256), axis=0)
    psd = psd.sum(axis=1)
    band = _band(f, psd)
    v = data.columns["v_sub"]
    th = data.columns["theta_sub"]
    rm = parts["motor"]
    speed = np.abs(v)
    edges = np.quantile(speed, np.linspace(0, 1, 13))
    idx = np.clip(np.searchsorted(edges, speed, side="right") - 1, 0, 11)
    rms = np.array([np.sqrt(np.mean(r2[idx == i])) if np.any(idx == i) else 0.0 for i in range(12)])
    hot = np.flatnonzero(rms >= 0.5 * rms.max()) if rms.max() > 0 else np.arange(12)
    speed_band = (float(edges[hot.min()]), float(edges[hot.max() + 1]))
    span = float(th.max() - th.min())
    moving = np.abs(v) > data.options.stick_velocity
    sv = np.sign(v[moving])
    n_rev = int(np.count_nonzero(np.diff(sv) != 0))
    harm = np.column_stack([np.ones(m)] + [fn(i * th) for i in range(1, 5) for fn in (np.sin, np.cos)])
    angle_fraction = _explained(rm, harm) - _explained(rm, np.ones((m, 1)))
    torque_fraction = _explained(rm, np.column_stack([np.ones(m), data.columns["u"]]))
    rev_times = data.t[np.flatnonzero(moving)[np.flatnonzero(np.diff(sv) != 0)]] if n_rev else np.array([])
    near = np.zeros(m, dtype=bool)
    for tr in rev_times:
        near |= np.abs(data.t - tr) < 0.05
    if near.any() and (~near).any():
        reversal_ratio = float(np.sqrt(np.mean(r2[near]) / max(np.mean(r2[~near]), 1e-300)))
    else:
        reversal_ratio = float("nan")
    notes = []
    if span < 2.0 * np.pi:
        notes.append(f"The motor turns through {span:.2f} rad, less than one revolution: angle-dependent effects "
                     "(cogging, position_friction) cannot be told apart from constant or smooth ones.")
    if n_rev < 2:
        notes.append("The motor barely reverses direction: Coulomb-type friction cannot be told apart from a "
                     "torque offset or gain error.")
    tone, tone_hz = tone_fraction(data.raw["tau_m"], data.experiment.rate_hz)
    if tone >= 0.95:
        notes.append(f"The command is essentially one sine ({100 * tone:.0f} % of its variance at {tone_hz:.2g} Hz): "
                     "at a single frequency a delay is indistinguishable from extra motor damping (d_m is "
                     "re-calibrated), and a gain error from a J_m/k rescaling; use broadband excitation.")
    return Location(time_windows_s=_windows(data.t, r2), frequency_band_hz=band, speed_band_rad_s=speed_band,
                    angle_span_rad=span, n_reversals=n_rev, angle_fraction=float(max(angle_fraction, 0.0)),
                    reversal_ratio=reversal_ratio, torque_fraction=torque_fraction, equation_share=share,
                    notes=tuple(notes), tone_fraction=tone, tone_hz=tone_hz)


def measured_response(u: np.ndarray, y: np.ndarray, rate_hz: float, *, nperseg: int = 1024
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 frequency-response estimate y/u and the magnitude-squared coherence (Welch).

    Parameters
    ----------
    u, y : ndarray, shape (n,)
        Input and output [any unit].
    rate_hz : float
        Sample rate [Hz].
    nperseg : int
        Welch segment length [samples] (at most ``n``).

    Returns
    -------
    (f, H1, coherence)
        Frequencies [Hz], S_uy / S_uu (nan where S_uu = 0), and
        |S_uy|^2 / (S_uu S_yy) as :func:`scipy.signal.coherence` computes it [-].
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    n = min(int(nperseg), u.size)
    f, suu = signal.welch(u, fs=rate_hz, nperseg=n)
    _, syy = signal.welch(y, fs=rate_hz, nperseg=n)
    _, suy = signal.csd(u, y, fs=rate_hz, nperseg=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        h1 = np.where(suu > 0, suy / np.where(suu > 0, suu, 1.0), np.nan)
        coh = np.where((suu > 0) & (syy > 0), np.abs(suy) ** 2 / np.where((suu > 0) & (syy > 0), suu * syy, 1.0),
                       0.0)
    return f, h1, coh


def empirical_response(data: GapData, *, nperseg: int = 1024) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empirical frequency response tau_m -> tau_s (H1 estimate) and the nominal P(j w).

    Parameters
    ----------
    data : GapData
        Prepared data (uses the raw-rate command and spring torque).
    nperseg : int
        Welch segment length [samples].

    Returns
    -------
    f : ndarray
        Frequencies [Hz].
    measured : ndarray of complex
        ``S_us / S_uu`` [N m / N m].
    nominal : ndarray of complex
        The nominal force plant P(j 2 pi f) of eq. (2) (the locked plant when locked),
        from :func:`forecast_design.symbolic.force_plant_tf` [N m / N m].
    """
    from ..symbolic import force_plant_tf

    exp = data.experiment
    f, measured, _ = measured_response(exp.signals.tau_m, exp.signals.tau_s, exp.rate_hz, nperseg=nperseg)
    # One home for P(s): the free-output factor s is cancelled there, so f = 0 is finite.
    nominal = force_plant_tf(exp.design).freqresp(2.0 * np.pi * f)
    return f, measured, nominal


def residual_psd(data: GapData, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density of a stacked residual, summed over the equations.

    Parameters
    ----------
    data : GapData
        Prepared equation errors (their decimated rate sets the frequency axis).
    residual : ndarray, shape (m * n_equations,)
        Stacked equation errors [N m].

    Returns
    -------
    (ndarray, ndarray)
        Frequencies [Hz] and the PSD summed over the equations [N^2 m^2/Hz].
    """
    m = data.t.size
    parts = np.column_stack([residual[i * m:(i + 1) * m] for i in range(len(data.equations))])
    f, p = signal.welch(parts, fs=data.settings.decimated_rate_hz, nperseg=min(256, m), axis=0)
    return f, p.sum(axis=1)
