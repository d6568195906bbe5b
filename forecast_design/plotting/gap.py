"""Plots of the sim-to-real gap diagnosis (matplotlib, Agg backend, imported lazily)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from . import save_figure

__all__ = ["plot_residual_time", "plot_residual_spectrum", "plot_residual_operating", "plot_before_after",
           "plot_replay"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _split(diag: Any, r: np.ndarray) -> dict[str, np.ndarray]:
    m = diag.data.t.size
    return {eq: r[i * m:(i + 1) * m] for i, eq in enumerate(diag.data.equations)}


def _after(diag: Any):
    return diag.fits.get(str(diag.effect)) if str(diag.effect) != "none" else None


def plot_residual_time(diag: Any, path: str | Path) -> Path:
    """Residual of the calibrated nominal model over time, hot windows shaded.

    Parameters
    ----------
    diag : Diagnosis
        A diagnosis.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _plt()
    data = diag.data
    before = _split(diag, diag.baseline.residual)
    fit = _after(diag)
    after = _split(diag, fit.residual) if fit is not None else None
    fig, axes = plt.subplots(len(before), 1, figsize=(9, 2.6 * len(before)), sharex=True, squeeze=False)
    for ax, (eq, r) in zip(axes[:, 0], before.items()):
        ax.plot(data.t, r, lw=0.7, label="nominal (calibrated)")
        if after is not None:
            ax.plot(data.t, after[eq], lw=0.7, label=f"with {diag.effect}")
        for t0, t1 in diag.location.time_windows_s:
            ax.axvspan(t0, t1, color="tab:red", alpha=0.12)
        ax.set_ylabel(f"{eq} residual [N m]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[0, 0].set_title("Equation error over time (shaded: windows with most residual energy)")
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path)


def plot_residual_spectrum(diag: Any, path: str | Path) -> Path:
    """Welch PSD of the residual before/after, and empirical vs nominal tau_m -> tau_s response.

    Parameters
    ----------
    diag : Diagnosis
        A diagnosis.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    from ..gap.locate import empirical_response, residual_psd

    plt = _plt()
    data = diag.data
    fs = data.settings.decimated_rate_hz
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5))
    for label, fit in (("nominal (calibrated)", diag.baseline), (f"with {diag.effect}", _after(diag))):
        if fit is None:
            continue
        ax1.semilogy(*residual_psd(data, fit.residual), label=label)
    lo, hi = diag.location.frequency_band_hz
    ax1.axvspan(lo, hi, color="tab:red", alpha=0.12, label="band with 80 % of the energy")
    ax1.set_xlabel("f [Hz]")
    ax1.set_ylabel("residual PSD [N^2 m^2/Hz]")
    ax1.legend(fontsize=8)
    ax1.grid(True, alpha=0.3)
    f, meas, nom = empirical_response(data)
    keep = (f > 0) & (f <= fs / 2)
    ax2.loglog(f[keep], np.abs(meas[keep]), ".", ms=3, label="measured (H1 from tau_m to tau_s)")
    ax2.loglog(f[keep], np.abs(nom[keep]), label="nominal P(j w)")
    ax2.set_xlabel("f [Hz]")
    ax2.set_ylabel("|tau_s / tau_m| [-]")
    ax2.legend(fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def plot_residual_operating(diag: Any, path: str | Path) -> Path:
    """Motor-side residual against motor speed and against motor angle (mod 2 pi).

    Parameters
    ----------
    diag : Diagnosis
        A diagnosis.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _plt()
    data = diag.data
    rm = _split(diag, diag.baseline.residual)["motor"]
    v = data.columns["v_sub"]
    th = np.mod(data.columns["theta_sub"], 2 * np.pi)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(v, rm, ".", ms=2, alpha=0.5)
    ax1.set_xlabel("motor speed theta' [rad/s]")
    ax1.set_ylabel("motor residual [N m]")
    lo, hi = diag.location.speed_band_rad_s
    ax1.set_title(f"speed band |theta'| {lo:.2g}-{hi:.2g} rad/s")
    ax2.plot(th, rm, ".", ms=2, alpha=0.5)
    ax2.set_xlabel("motor angle mod 2 pi [rad]")
    ax2.set_title(f"angle span {diag.location.angle_span_rad:.2f} rad")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    return save_figure(fig, path)


def plot_before_after(diag: Any, path: str | Path, *, window_s: float = 2.0) -> Path:
    """Held-out overlay: the nominal equation error, the verdict effect's prediction and what is left.

    Parameters
    ----------
    diag : Diagnosis
        A diagnosis.
    path : str or Path
        PNG file to write.
    window_s : float
        Length of the held-out stretch shown [s].

    Returns
    -------
    Path
        The file written.
    """
    plt = _plt()
    data = diag.data
    held = np.flatnonzero(data.held_out)
    t0 = data.t[held[0]] if held.size else data.t[0]
    sel = (data.t >= t0) & (data.t < t0 + window_s)
    before = _split(diag, diag.baseline.residual)
    fit = _after(diag)
    eqs = [eq for eq in data.equations if np.any(before[eq][sel])]
    fig, axes = plt.subplots(len(eqs), 1, figsize=(9, 2.8 * len(eqs)), sharex=True, squeeze=False)
    for ax, eq in zip(axes[:, 0], eqs):
        ax.plot(data.t[sel], before[eq][sel], lw=1.0, label="before: nominal equation error")
        if fit is not None:
            pred = _split(diag, fit.prediction)[eq]
            after = _split(diag, fit.residual)[eq]
            ax.plot(data.t[sel], pred[sel], "--", lw=1.0, label=f"{diag.effect} model")
            ax.plot(data.t[sel], after[sel], lw=1.0, label="after: left over")
        ax.set_ylabel(f"{eq} [N m]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[0, 0].set_title(f"Held-out data: gap {diag.gap_before:.3g} -> {diag.gap_after:.3g} N m "
                         f"({100 * diag.reduction:.0f} % less)")
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path)


def plot_replay(diag: Any, path: str | Path, *, window_s: float = 0.5) -> Path:
    """Output-error replay over the worst window: measured vs replayed ``tau_s`` and ``theta``.

    Parameters
    ----------
    diag : Diagnosis
        A diagnosis (with its ``replay``).
    path : str or Path
        PNG file to write.
    window_s : float
        Window length [s] (the replay check's).

    Returns
    -------
    Path
        The file written.
    """
    from ..gap.replay import replay_trace

    plt = _plt()
    rc = diag.replay
    start = rc.worst_windows_s[0][0] if rc is not None and rc.worst_windows_s else float(diag.data.t[0])
    window_s = rc.window_s if rc is not None else window_s
    tr = replay_trace(diag.data, _after(diag), start, window_s=window_s)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    ax1.plot(tr["t"], tr["tau_s"], "k", lw=1.2, label="measured")
    ax1.plot(tr["t"], tr["tau_s_before"], lw=1.0, label="nominal model replay")
    ax2.plot(tr["t"], tr["theta"], "k", lw=1.2, label="measured")
    ax2.plot(tr["t"], tr["theta_before"], lw=1.0, label="nominal model replay")
    if _after(diag) is not None:
        ax1.plot(tr["t"], tr["tau_s_after"], "--", lw=1.0, label=f"with {diag.effect}")
        ax2.plot(tr["t"], tr["theta_after"], "--", lw=1.0, label=f"with {diag.effect}")
    ax1.set_ylabel("tau_s [N m]")
    ax2.set_ylabel("theta [rad]")
    ax2.set_xlabel("t [s]")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    ax1.legend(fontsize=8, loc="upper right")
    ax1.set_title("Output-error replay from the recorded tau_m, started from the measured state "
                  "(worst window of the nominal model)", fontsize=9)
    return save_figure(fig, path)
