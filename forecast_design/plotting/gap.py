"""Plots of the sim-to-real gap diagnosis (matplotlib, Agg backend, imported lazily).

Every function draws a :class:`forecast_design.gap.views.DiagnosisViews` (computed by
:func:`forecast_design.gap.views.diagnosis_views`); nothing is computed here. "Before" (the
calibrated nominal model) is drawn wherever "after" (with the verdict effect) is, in the same
colours in every plot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ParameterError
from . import _pyplot, save_figure

__all__ = ["plot_residual_time", "plot_residual_spectrum", "plot_residual_operating", "plot_before_after",
           "plot_replay", "BEFORE_COLOUR", "AFTER_COLOUR", "MEASURED_COLOUR"]

BEFORE_COLOUR = "#1f77b4"     # nominal model (calibrated): "before"
AFTER_COLOUR = "#ff7f0e"      # with the verdict effect: "after"
MODEL_COLOUR = "#2ca02c"      # the effect's own prediction
MEASURED_COLOUR = "black"
LOW_COHERENCE = "0.85"        # grey of untrusted frequency bands


def _labels(views) -> tuple[str, str]:
    return "before: nominal (calibrated)", f"after: with {views.effect}"


def _dropped_note(fig, views) -> None:
    if views.dropped:
        text = ", ".join(f"{eq} (RMS {rms:.2g} N m)" for eq, rms in views.dropped.items())
        fig.text(0.01, 0.005, f"Not drawn, numerical noise only: {text}", fontsize=7, color="0.35",
                 ha="left", va="bottom")


def plot_residual_time(views, path: str | Path) -> Path:
    """Residual of each drawn equation over time, before and after, hot windows shaded.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views`.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _pyplot()
    before_label, after_label = _labels(views)
    eqs = views.equations
    fig, axes = plt.subplots(len(eqs), 1, figsize=(9, 2.6 * len(eqs) + 0.4), sharex=True, squeeze=False)
    for ax, eq in zip(axes[:, 0], eqs):
        ax.plot(views.t, views.before[eq], lw=0.7, color=BEFORE_COLOUR, label=before_label, gid=f"before|{eq}")
        if eq in views.after:
            ax.plot(views.t, views.after[eq], lw=0.7, color=AFTER_COLOUR, label=after_label, gid=f"after|{eq}")
        for t0, t1 in views.time_windows_s:
            ax.axvspan(t0, t1, color="tab:red", alpha=0.12)
        ax.set_ylabel(f"{eq} residual [N m]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize=8, framealpha=0.9)
    axes[0, 0].set_title("Equation error over time (shaded: windows with most residual energy)")
    axes[-1, 0].set_xlabel("t [s]")
    _dropped_note(fig, views)
    return save_figure(fig, path)


def plot_residual_spectrum(views, path: str | Path) -> Path:
    """Residual PSD before/after (top); measured vs nominal tau_m -> tau_s response beside its coherence.

    Frequencies where the coherence is below the views' threshold are greyed out in both
    bottom panels and the measured points there are drawn hollow: the measurement does not
    support a comparison with the linear model there.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views`.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _pyplot()
    before_label, after_label = _labels(views)
    fig = plt.figure(figsize=(10.5, 7.5), layout="constrained")
    grid = fig.add_gridspec(2, 2)
    ax1 = fig.add_subplot(grid[0, :])
    ax1.semilogy(views.psd_f_hz, views.psd_before, color=BEFORE_COLOUR, label=before_label, gid="before|psd")
    if views.psd_after is not None:
        ax1.semilogy(views.psd_f_hz, views.psd_after, color=AFTER_COLOUR, label=after_label, gid="after|psd")
    lo, hi = views.frequency_band_hz
    ax1.axvspan(lo, hi, color="tab:red", alpha=0.12, label="band with 80 % of the energy")
    ax1.set_xlabel("f [Hz]")
    ax1.set_ylabel("residual PSD [N^2 m^2/Hz]")
    ax1.set_title("Residual spectrum (" + ", ".join(views.equations) + (" equations)" if len(views.equations) > 1
                                                                       else " equation)"), fontsize="medium")
    ax1.legend(fontsize=8)
    ax1.grid(True, alpha=0.3)

    r = views.response
    ax2 = fig.add_subplot(grid[1, 0])
    ax3 = fig.add_subplot(grid[1, 1], sharex=ax2)
    for a, b in r.low_bands_hz():
        for ax in (ax2, ax3):
            ax.axvspan(max(a, r.f_hz[0] * 0.9), b, color=LOW_COHERENCE, zorder=0, gid="low-coherence")
    good = ~r.low
    ax2.loglog(r.f_hz[good], np.abs(r.measured[good]), "o", ms=3, color=MEASURED_COLOUR,
               label="measured H1 (coherent)", gid="measured|coherent")
    if np.any(r.low):
        ax2.loglog(r.f_hz[r.low], np.abs(r.measured[r.low]), "o", ms=3, mfc="none", color="0.55",
                   label=f"measured, coherence < {r.threshold:g}", gid="measured|low")
    ax2.loglog(r.nominal_f_hz, np.abs(r.nominal), color=BEFORE_COLOUR, label="nominal P(j w)", gid="nominal")
    ax2.set_xlabel("f [Hz]")
    ax2.set_ylabel("|tau_s / tau_m| [-]")
    ax2.set_title("Frequency response tau_m -> tau_s", fontsize="medium")
    ax2.legend(fontsize=7)
    ax3.semilogx(r.f_hz, r.coherence, ".-", ms=3, lw=0.8, color=MEASURED_COLOUR, gid="coherence")
    ax3.axhline(r.threshold, color="tab:red", linestyle="--", linewidth=1.0, label=f"threshold {r.threshold:g}")
    ax3.set_ylim(0.0, 1.05)
    ax3.set_xlabel("f [Hz]")
    ax3.set_ylabel("coherence tau_m, tau_s [-]")
    ax3.set_title("Coherence (grey: too low to trust the response)", fontsize="medium")
    ax3.legend(fontsize=7, loc="lower left")
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    for ax in (ax2, ax3):
        ax.grid(True, which="both", alpha=0.3)
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
    _dropped_note(fig, views)
    return save_figure(fig, path)


def plot_residual_operating(views, path: str | Path) -> Path:
    """Motor-side residual against motor speed and motor angle, before and after.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views`.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _pyplot()
    op = views.operating
    before_label, after_label = _labels(views)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10.5, 4.2), sharey=True)
    for ax, x in ((ax1, op.speed_rad_s), (ax2, op.angle_rad)):
        ax.plot(x, op.before, ".", ms=2, alpha=0.5, color=BEFORE_COLOUR, label=before_label, gid="before")
        if op.after is not None:
            ax.plot(x, op.after, ".", ms=2, alpha=0.5, color=AFTER_COLOUR, label=after_label, gid="after")
        ax.grid(True, alpha=0.3)
    ax1.set_xlabel("motor speed theta' [rad/s]")
    ax1.set_ylabel("motor residual [N m]")
    lo, hi = views.speed_band_rad_s
    ax1.set_title(f"speed band |theta'| {lo:.2g}-{hi:.2g} rad/s", fontsize="medium")
    ax2.set_xlabel("motor angle mod 2 pi [rad]" if op.wrapped else "motor angle from its smallest value [rad]")
    ax2.set_title(f"angle span {views.angle_span_rad:.2f} rad" + ("" if op.wrapped else " (less than a turn)"),
                  fontsize="medium")
    ax1.legend(fontsize=8, markerscale=4)
    return save_figure(fig, path)


def plot_before_after(views, path: str | Path) -> Path:
    """Held-out overlay: the nominal equation error, the verdict effect's prediction and what is left.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views` (its ``window_s`` sets the stretch).
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    plt = _pyplot()
    sel = views.held_out
    eqs = views.equations
    fig, axes = plt.subplots(len(eqs), 1, figsize=(9, 2.8 * len(eqs) + 0.4), sharex=True, squeeze=False)
    t = views.t[sel]
    for ax, eq in zip(axes[:, 0], eqs):
        ax.plot(t, views.before[eq][sel], lw=1.0, color=BEFORE_COLOUR, label="before: nominal equation error",
                gid=f"before|{eq}")
        if eq in views.after:
            ax.plot(t, views.prediction[eq][sel], "--", lw=1.0, color=MODEL_COLOUR, label=f"{views.effect} model",
                    gid=f"model|{eq}")
            ax.plot(t, views.after[eq][sel], lw=1.0, color=AFTER_COLOUR, label="after: left over",
                    gid=f"after|{eq}")
        ax.set_ylabel(f"{eq} equation error [N m]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="best", framealpha=0.9)
    reduction = 1.0 - views.gap_after / views.gap_before if views.gap_before > 0 else 0.0
    graded = f"; {views.effect} graded {views.grade}" if views.qualified else ""
    axes[0, 0].set_title(f"Held-out data: gap {views.gap_before:.3g} -> {views.gap_after:.3g} N m "
                         f"({100 * reduction:.0f} % less{graded})")
    axes[-1, 0].set_xlabel("t [s]")
    _dropped_note(fig, views)
    return save_figure(fig, path)


def plot_replay(views, path: str | Path) -> Path:
    """Output-error replay over the worst window: measured vs replayed ``tau_s`` and ``theta``.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views`, with a replay.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ParameterError
        If the views hold no replay.
    """
    if views.replay is None:
        raise ParameterError("the diagnosis has no output-error replay to plot", name="replay")
    plt = _pyplot()
    tr = views.replay
    before_label, after_label = _labels(views)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for ax, key, unit in ((ax1, "tau_s", "N m"), (ax2, "theta", "rad")):
        ax.plot(tr["t"], tr[key], color=MEASURED_COLOUR, lw=1.2, label="measured", gid=f"measured|{key}")
        ax.plot(tr["t"], tr[f"{key}_before"], color=BEFORE_COLOUR, lw=1.0, label=before_label, gid=f"before|{key}")
        if views.has_after:
            ax.plot(tr["t"], tr[f"{key}_after"], "--", color=AFTER_COLOUR, lw=1.0, label=after_label,
                    gid=f"after|{key}")
        ax.set_ylabel(f"{key} [{unit}]")
        ax.grid(True, alpha=0.3)
    ax2.set_xlabel("t [s]")
    ax1.legend(fontsize=8, loc="best", framealpha=0.9)
    ax1.set_title("Output-error replay from the recorded tau_m, started from the measured state "
                  "(worst window of the nominal model)", fontsize=9)
    return save_figure(fig, path)


def plot_reversals(views, path: str | Path) -> Path:
    """The friction laws around the motor's reversals: logged angle against each law's held-out prediction.

    Parameters
    ----------
    views : DiagnosisViews
        From :func:`forecast_design.gap.views.diagnosis_views`, with ``reversals``.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ParameterError
        If the views hold no reversal windows.
    """
    if views.reversals is None:
        raise ParameterError("the diagnosis compared no friction laws around reversals", name="reversals")
    plt = _pyplot()
    rv = views.reversals
    n = len(rv["window_start_s"])
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n + 1, 3.6), squeeze=False, sharey=False)
    t_ms = 1e3 * np.asarray(rv["t_s"])
    for i, ax in enumerate(axes[0]):
        ax.step(t_ms, rv["theta_counts"][i], where="post", color=MEASURED_COLOUR, lw=1.2, label="logged",
                gid=f"measured|{i}")
        ax.plot(t_ms, rv["coulomb_counts"][i], color=BEFORE_COLOUR, lw=1.0, label="Coulomb", gid=f"coulomb|{i}")
        ax.plot(t_ms, rv["bump_counts"][i], "--", color=AFTER_COLOUR, lw=1.0, label="Coulomb + Stribeck bump",
                gid=f"bump|{i}")
        ax.axvline(0.0, color="0.6", lw=0.8)
        ax.set_title(f"reversal at {rv['window_start_s'][i] - rv['t_s'][0]:.2f} s", fontsize=9)
        ax.set_xlabel("t from the reversal [ms]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("motor angle [encoder counts]")
    axes[0, 0].legend(fontsize=8, loc="best", framealpha=0.9)
    c, b = rv["rms_counts"]
    fig.suptitle(f"Held-out windows around reversals (each law fitted on the other fold): RMS {c:.2f} counts "
                 f"(Coulomb) vs {b:.2f} (bump), signed-rank p = {rv['p_value']:.2g}"
                 + (": stiction" if rv["names_stiction"] else ": no verdict change"), fontsize=9)
    return save_figure(fig, path)
