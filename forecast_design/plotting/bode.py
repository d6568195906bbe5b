"""Bode plots of RationalTF values (magnitude in dB, phase in degrees, frequency in Hz)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import ParameterError
from ..lti import RationalTF
from . import _pyplot, save_figure
from .style import PLANT_KINDS, plant_style

__all__ = ["bode_data", "plot_bode", "figure_plants", "plot_plants"]


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
    fig, (ax_mag, ax_phase) = plt.subplots(2, 1, sharex=True, figsize=(7.0, 6.0 + 0.2 * ((len(items) + 1) // 2)),
                                           layout="constrained")
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
        # below the axes, two columns: as many curves as given, none covering the data
        fig.legend(*ax_mag.get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize="small",
                   frameon=False)
        if title:
            ax_mag.set_title(title)
        path = save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)
    return path


def figure_plants(results: Sequence[tuple[str, object]], *, w_rad_s: np.ndarray | None = None,
                  title: str | None = None):
    """Bode plots of P and the nominal plants, one panel (magnitude over phase) per environment.

    Every panel draws the same four curves in the same looks (:func:`~.style.plant_style`:
    the observer's colour, a line style of its own, the true plant thick and pale underneath),
    so one figure legend of four entries names every curve, whatever the number of environments.

    Parameters
    ----------
    results : sequence of (str, TransferFunctions)
        Environment label and :func:`forecast_design.symbolic.transfer_functions` of it.
    w_rad_s : ndarray, optional
        Angular frequencies [rad/s]; default a log grid two decades around every pole and zero.
    title : str, optional
        Figure title (default names the plants and the equations).

    Returns
    -------
    matplotlib.figure.Figure
        The open figure; the lines carry gids ``"mag|ENV|KIND"`` and ``"phase|ENV|KIND"``.

    Raises
    ------
    ParameterError
        If ``results`` is empty.
    """
    plt = _pyplot()
    from matplotlib.lines import Line2D

    results = list(results)
    if not results:
        raise ParameterError("plot_plants needs at least one environment", name="results", value=results)
    items = [(f"{kind} ({env})", getattr(tfs, kind).tf) for env, tfs in results for kind in PLANT_KINDS]
    w = _default_grid(_items(items)) if w_rad_s is None else np.asarray(w_rad_s, dtype=float)
    n = len(results)
    cols = min(n, 3)
    rows = -(-n // cols)
    fig = plt.figure(figsize=(4.6 * cols + 0.6, 4.4 * rows + 1.2), layout="constrained")
    grid = fig.add_gridspec(2 * rows, cols, height_ratios=(1.3, 1.0) * rows)
    first = None
    for k, (env, tfs) in enumerate(results):
        r, c = divmod(k, cols)
        ax_mag = fig.add_subplot(grid[2 * r, c], sharex=first)
        first = first or ax_mag
        ax_phase = fig.add_subplot(grid[2 * r + 1, c], sharex=first)
        for kind in PLANT_KINDS:
            f_hz, mag_db, phase_deg = bode_data(getattr(tfs, kind).tf, w)
            look = {key: v for key, v in plant_style(kind).items() if key != "label"}
            ax_mag.semilogx(f_hz, mag_db, gid=f"mag|{env}|{kind}", **look)
            ax_phase.semilogx(f_hz, phase_deg, gid=f"phase|{env}|{kind}", **look)
        ax_mag.set_title(f"environment {env}", fontsize="medium")
        ax_mag.set_ylabel("magnitude [dB]")
        ax_phase.set_ylabel("phase [deg]")
        ax_phase.set_xlabel("frequency [Hz]")
        ax_mag.tick_params(labelbottom=False)
        for ax in (ax_mag, ax_phase):
            ax.grid(True, which="both", alpha=0.3)
    handles = [Line2D([], [], **plant_style(kind)) for kind in PLANT_KINDS]
    fig.legend(handles=handles, labels=[h.get_label() for h in handles], loc="outside lower center",
               ncol=2 if cols == 1 else 4, fontsize="small", frameon=False)
    fig.suptitle(title or ("Force plant P and the observers' nominal plants" + (", per environment" if n > 1 else "")),
                 fontsize="large" if cols > 1 else "medium")
    return fig


def plot_plants(results: Sequence[tuple[str, object]], path: str | Path, *, w_rad_s: np.ndarray | None = None,
                title: str | None = None) -> Path:
    """Bode plots of P and the nominal plants per environment (the ``tf --plot`` picture), as PNG.

    Parameters
    ----------
    results : sequence of (str, TransferFunctions)
        Environment label and :func:`forecast_design.symbolic.transfer_functions` of it.
    path : str or Path
        Output PNG file.
    w_rad_s : ndarray, optional
        Angular frequencies [rad/s] (see :func:`figure_plants`).
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    return save_figure(figure_plants(results, w_rad_s=w_rad_s, title=title), path, dpi=110)
