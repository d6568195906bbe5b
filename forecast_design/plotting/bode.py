"""Bode plots of RationalTF values (magnitude in dB, phase in degrees, frequency in Hz)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF
from . import _pyplot, save_figure

__all__ = ["bode_data", "plot_bode"]


def _items(tfs: Mapping[str, RationalTF] | Sequence[tuple[str, RationalTF]]) -> list[tuple[str, RationalTF]]:
    items = list(tfs.items()) if isinstance(tfs, Mapping) else [tuple(item) for item in tfs]
    if not items:
        raise ParameterError("plot_bode needs at least one transfer function", name="tfs", value=tfs)
    for label, tf in items:
        if not isinstance(tf, RationalTF):
            raise ParameterError(f"'{label}' is a {type(tf).__name__}, not a RationalTF",
                                 name=str(label), value=tf)
    return items


def _default_grid(items: list[tuple[str, RationalTF]]) -> np.ndarray:
    # Two decades either side of the pole/zero magnitudes, within [1e-2, 1e5] rad/s.
    mags = [abs(r) for _, tf in items for r in np.concatenate([tf.poles(), tf.zeros()]) if r != 0.0]
    lo = min(mags, default=1.0) / 100.0
    hi = max(mags, default=1.0) * 100.0
    lo, hi = max(lo, 1e-2), min(max(hi, 10.0 * max(lo, 1e-2)), 1e5)
    return np.logspace(np.log10(lo), np.log10(hi), 800)


def bode_data(tf: RationalTF, w_rad_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequency [Hz], magnitude [dB] and unwrapped phase [deg] of a TF.

    Parameters
    ----------
    tf : RationalTF
        Continuous- or discrete-time transfer function.
    w_rad_s : ndarray, shape (n,)
        Angular frequencies [rad/s].

    Returns
    -------
    f_hz, mag_db, phase_deg : ndarray, shape (n,)
        Frequency [Hz], 20 log10 |H| [dB], unwrapped angle of H [deg].
    """
    w = np.asarray(w_rad_s, dtype=float)
    h = tf.freqresp(w)
    with np.errstate(divide="ignore"):
        mag_db = 20.0 * np.log10(np.abs(h))
    return w / (2.0 * np.pi), mag_db, np.degrees(np.unwrap(np.angle(h)))


def plot_bode(tfs: Mapping[str, RationalTF] | Sequence[tuple[str, RationalTF]], path: str | Path, *,
              w_rad_s: np.ndarray | None = None, title: str | None = None) -> Path:
    """Overlay Bode plots of several transfer functions and save a PNG.

    Parameters
    ----------
    tfs : Mapping[str, RationalTF] or sequence of (str, RationalTF)
        Labelled transfer functions (e.g. one per environment).
    path : str or Path
        Output PNG file.
    w_rad_s : ndarray, optional
        Angular frequencies [rad/s]; default a log grid two decades around
        the poles and zeros.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    plt = _pyplot()

    items = _items(tfs)
    w = _default_grid(items) if w_rad_s is None else np.asarray(w_rad_s, dtype=float)
    fig, (ax_mag, ax_phase) = plt.subplots(2, 1, sharex=True, figsize=(7.0, 6.0))
    try:
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        styles = ("-", "--", ":", "-.")
        for n, (label, tf) in enumerate(items):
            f_hz, mag_db, phase_deg = bode_data(tf, w)
            # Past the colour cycle, change the line style so every curve stays distinguishable.
            fmt = {"color": colors[n % len(colors)], "linestyle": styles[(n // len(colors)) % len(styles)]}
            ax_mag.semilogx(f_hz, mag_db, label=str(label), **fmt)
            ax_phase.semilogx(f_hz, phase_deg, label=str(label), **fmt)
        ax_mag.set_ylabel("magnitude [dB]")
        ax_phase.set_ylabel("phase [deg]")
        ax_phase.set_xlabel("frequency [Hz]")
        for ax in (ax_mag, ax_phase):
            ax.grid(True, which="both", alpha=0.3)
        ax_mag.legend(loc="best", fontsize="small")
        if title:
            ax_mag.set_title(title)
        path = save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)
    return path
