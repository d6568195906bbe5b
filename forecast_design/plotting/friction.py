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
    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    ax_t.plot(t, y, color="black", lw=0.8, label=r"measured $\tau_{frc}$")
    ax_t.plot(t, y_hat, color="tab:blue", lw=0.8, ls="--", label=r"estimated $\hat\tau_{frc}$")
    ax_t.set_xlabel("time [s]")
    units = axis_units(prismatic)
    ax_t.set_ylabel(f"friction [{units['force']}]")
    ax_t.legend(loc="best")
    ax_t.set_title(f"{fit.model.name}: fit {fit.fit_percent_estimation:.2f} %")
    order = np.argsort(data.velocity, kind="stable")
    ax_v.plot(data.velocity, y, ".", color="black", ms=1.5, alpha=0.4, label="measured")
    ax_v.plot(data.velocity[order], y_hat[order], ".", color="tab:blue", ms=1.5, label="estimated")
    ax_v.set_xlabel(f"velocity [{units['velocity']}]")
    ax_v.set_ylabel(f"friction [{units['force']}]")
    ax_v.legend(loc="best")
    return save_figure(fig, path, dpi=120)
