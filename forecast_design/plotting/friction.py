"""Plots of friction fits: measured vs estimated friction against time and velocity."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..friction.identify import FrictionFit, IdentificationData, predict_data
from ..friction.logs import axis_units
from . import _pyplot, save_figure

__all__ = ["plot_friction_fit"]


def plot_friction_fit(fit: FrictionFit, data: IdentificationData, path: str | os.PathLike[str], *,
                      prismatic: bool = False) -> Path:
    """Measured vs estimated friction against time and against velocity (like the paper's Fig. 9).

    Parameters
    ----------
    fit : FrictionFit
        The fit to show.
    data : IdentificationData
        Prepared log, e.g. ``fit_data(fit, t, position, force)``.
    path : str or path-like
        PNG file to write.
    prismatic : bool
        Label a linear axis in N and m/s (e.g. EMPS, ``AxisLog.prismatic``) instead of N m and rad/s.

    Returns
    -------
    pathlib.Path
        The written file.

    Notes
    -----
    "Measured" friction is the prepared force minus the estimated inertial
    term (when the model has one); "estimated" is the model minus the same
    term, so both panels show friction only.
    """
    plt = _pyplot()

    y = np.asarray(data.force, dtype=float)
    y_hat = predict_data(fit, data)
    if "inertia" in fit.params:
        inertial = fit.params["inertia"] * data.acceleration
        y, y_hat = y - inertial, y_hat - inertial
    t = np.arange(y.size) * data.dt
    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(11, 4.3), layout="constrained")
    ax_t.plot(t, y, color="black", lw=0.9, label=r"measured $\tau_{frc}$", gid="measured")
    ax_t.plot(t, y_hat, color="tab:orange", lw=0.9, ls="--", label=r"estimated $\hat\tau_{frc}$ (model)",
              gid="estimated")
    ax_t.set_xlabel("time [s]")
    units = axis_units(prismatic)
    ax_t.set_ylabel(f"friction [{units['force']}]")
    ax_t.set_title("against time", fontsize="medium")
    # the model as a wide pale band, the measured points small on top: both stay visible where they agree
    order = np.argsort(data.velocity, kind="stable")
    ax_v.plot(data.velocity[order], y_hat[order], ".", color="tab:orange", ms=4.0, alpha=0.3, zorder=2.0,
              gid="estimated|velocity")
    ax_v.plot(data.velocity, y, ".", color="black", ms=0.8, zorder=3.0, gid="measured|velocity")
    ax_v.set_xlabel(f"velocity [{units['velocity']}]")
    ax_v.set_ylabel(f"friction [{units['force']}]")
    ax_v.set_title("against velocity", fontsize="medium")
    for ax in (ax_t, ax_v):
        ax.grid(True, alpha=0.3)
    fig.legend(loc="outside lower center", ncol=2, fontsize="small", frameon=False)
    fig.suptitle(f"Friction identified: model {fit.model.name}, fit {fit.fit_percent_estimation:.2f} % "
                 "on the estimation data", fontsize="medium")
    return save_figure(fig, path, dpi=120)
