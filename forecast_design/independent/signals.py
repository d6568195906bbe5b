"""Independent log generator: signals (see the package docstring)."""

from __future__ import annotations

import math
from math import cos as _cos, sin as _sin
from typing import Any

import numpy as np

from .model import Excitation

# --------------------------------------------------------------------------------------
# small signal helpers


def round_significant(values: Any, digits: int) -> np.ndarray:
    """Round like a logger printing ``%.<digits>g``: parse back what would be printed.

    Parameters
    ----------
    values : array_like
        Numbers to round.
    digits : int
        Significant digits, 1..17.

    Returns
    -------
    ndarray
        The printed values as floats.
    """
    spec = f".{int(digits) - 1}e"
    arr = np.asarray(values, dtype=float)
    return np.array([float(format(x, spec)) for x in arr.ravel().tolist()]).reshape(arr.shape)


def one_line_fraction(x: Any) -> float:
    """Fraction of a signal's variance in its strongest spectral line.

    Hann-windowed periodogram of ``x - mean(x)``; the strongest bin and two
    bins either side (the window's leakage) make the line.

    Parameters
    ----------
    x : array_like
        Uniformly sampled signal.

    Returns
    -------
    float
        In [0, 1]; 1.0 for a constant signal, near 1 for one sine.
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    if x.size < 8 or not np.any(x):
        return 1.0
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    p[0] = 0.0
    total = p.sum()
    if total <= 0.0:
        return 1.0
    k = int(np.argmax(p))
    return float(p[max(k - 2, 0):k + 3].sum() / total)


def _schroeder_phases(bins: np.ndarray, amps: np.ndarray) -> np.ndarray:
    """Schroeder's phases for lines on harmonics `bins` with amplitudes `amps`.

    phi_k = -2 pi sum_{l<k} (b_k - b_l) p_l with p_l the relative power of line l
    (Schroeder 1970, for a general power spectrum; missing harmonics have p = 0).
    """
    p = amps ** 2 / np.sum(amps ** 2)
    return np.array([-2.0 * np.pi * np.sum((b - bins[:k]) * p[:k]) for k, b in enumerate(bins)])


def _low_crest_multisine(n: int, bins: np.ndarray, amps: np.ndarray, iterations: int = 40) -> np.ndarray:
    """One period of a multisine: Schroeder phases, then clipping and phase retrieval (best kept)."""
    spec = np.zeros(n // 2 + 1, dtype=complex)

    def synth(ph: np.ndarray) -> np.ndarray:
        spec[:] = 0.0
        spec[bins] = amps * np.exp(1j * ph) * n / 2.0
        return np.fft.irfft(spec, n)

    x = synth(_schroeder_phases(bins, amps))
    rms = float(np.sqrt(np.mean(x ** 2)))
    best, best_peak = x, float(np.max(np.abs(x)))
    for it in range(iterations):
        level = (1.6 - 0.5 * it / max(iterations - 1, 1)) * rms
        x = synth(np.angle(np.fft.rfft(np.clip(x, -level, level))[bins]))
        peak = float(np.max(np.abs(x)))
        if peak < best_peak:
            best, best_peak = x, peak
    return best


def _multisine(n: int, rate_hz: float, rms: float, f_lo: float, f_hi: float, lines: int,
               periods: int, tilt: float) -> np.ndarray:
    n_p = max(n // periods, 8)
    f_res = rate_hz / n_p
    want = np.geomspace(f_lo, max(f_hi, f_lo), lines)
    bins = np.unique(np.clip(np.round(want / f_res).astype(int), 1, n_p // 2 - 1))
    amps = (bins * f_res) ** (-tilt)
    x = _low_crest_multisine(n_p, bins, amps)
    x = x * (rms / np.sqrt(np.mean(x ** 2)))
    return np.resize(x, n)


def excitation_signal(excitation: Excitation, n: int, rate_hz: float) -> np.ndarray:
    """The sampled command (or reference) of an excitation.

    Parameters
    ----------
    excitation : Excitation
        What to generate.
    n : int
        Number of samples.
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    ndarray, shape (n,)
        Sample values, held over each period [N m].
    """
    ex = excitation
    t = np.arange(n) / rate_hz
    duration = n / rate_hz
    if ex.kind == "constant":
        x = np.full(n, ex.amplitude)
    elif ex.kind == "multisine":
        x = _multisine(n, rate_hz, ex.amplitude, ex.f_lo_hz, ex.f_hi_hz, ex.lines, ex.periods, ex.tilt)
    elif ex.kind == "square":
        x = ex.amplitude * np.where(np.sin(2 * np.pi * t / ex.period_s + 1e-9) >= 0.0, 1.0, -1.0)
    elif ex.kind == "chirp":
        r = math.log(ex.f_hi_hz / ex.f_lo_hz) if ex.f_hi_hz > ex.f_lo_hz else 0.0
        if r > 0.0:
            phase = 2 * np.pi * ex.f_lo_hz * duration / r * np.expm1(r * t / duration)
        else:
            phase = 2 * np.pi * ex.f_lo_hz * t
        fade = np.clip(t / 0.25, 0.0, 1.0)
        x = ex.amplitude * np.sin(phase) * (0.5 - 0.5 * np.cos(np.pi * fade))
    elif ex.kind == "sweep":
        x = ex.amplitude * np.sin(2 * np.pi * ex.f_lo_hz * t)
    else:  # triangle, starting at 0 and rising
        x = ex.amplitude * (2.0 / np.pi) * np.arcsin(np.sin(2 * np.pi * t / ex.period_s))
    if ex.dither > 0.0 and ex.kind in ("sweep", "triangle"):
        x = x + _multisine(n, rate_hz, ex.dither, 1.0, min(8.0, rate_hz / 20), 8, 1, 0.0)
    x = x + ex.offset
    if ex.kind == "square" and ex.slew is not None:
        step = ex.slew / rate_hz
        out = np.empty(n)
        y = 0.0
        for i, target in enumerate(x.tolist()):
            y += min(max(target - y, -step), step)
            out[i] = y
        x = out
    return x


def _harmonic(terms: list[tuple[int, float, float]], angle: float) -> float:
    total = 0      # as sum(): the terms added in order, from the integer 0 (the plant calls this per step stage)
    for i, a, b in terms:
        x = i * angle
        total += a * _sin(x) + b * _cos(x)
    return total


def _to_log_frame(a: tuple[float, ...], b: tuple[float, ...], phi: float) -> tuple[tuple, tuple]:
    """Harmonics of theta + phi written as harmonics of theta."""
    a2, b2 = [], []
    for i, (ai, bi) in enumerate(zip(a, b), start=1):
        c, s = math.cos(i * phi), math.sin(i * phi)
        a2.append(ai * c - bi * s)
        b2.append(ai * s + bi * c)
    return tuple(a2), tuple(b2)
