"""Benchmark plots: indicators against environment stiffness, repetition overlays, a heat map of the set.

The plots draw what :mod:`forecast_design.benchmark` computed (the tidy table and the
stored traces); they compute nothing of their own.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ParameterError
from . import _pyplot, write_figure

__all__ = ["plot_indicators", "plot_overlays", "plot_heatmap", "UNITS"]

#: Axis labels of the metrics.
UNITS = {"repeatability": "repeatability (mean x-corr) [-]", "mae_N_m": "MAE to frictionless [N m]",
         "rise_time_s": "rise time [s]", "overshoot_percent": "overshoot [%]", "settling_time_s": "settling time [s]",
         "steady_state_error_N_m": "steady-state error [N m]", "bandwidth_hz": "tracking bandwidth [Hz]",
         "disk_margin": "disk margin [-]"}


def _env_means(df):
    sub = df[(df["kind"] == "environment") & (df["statistic"] == "mean")]
    if sub.empty:
        raise ParameterError("benchmark table has no per-environment rows", name="table", value=len(df))
    return sub


def _stiffness_axis(sub) -> tuple[dict[str, float], float | None]:
    """x position of each environment: k_e, locked ones one decade right of the stiffest."""
    free = sub[~sub["locked"].astype(bool)]
    top = float(free["k_e"].max()) if not free.empty else 1.0
    xs = {}
    for name, k, locked in zip(sub["environment"], sub["k_e"], sub["locked"].astype(bool)):
        xs[name] = top * 10.0 if locked else float(k)
    return xs, (top * 10.0 if bool(sub["locked"].astype(bool).any()) else None)


def plot_indicators(df, path: str | Path | None = None, *,
                    metrics: Sequence[str] = ("repeatability", "mae_N_m", "rise_time_s", "overshoot_percent",
                                              "bandwidth_hz", "disk_margin")):
    """Each indicator (per-environment mean) against the environment stiffness, one line per controller/compensator.

    Parameters
    ----------
    df : pandas.DataFrame
        The benchmark table (:func:`forecast_design.benchmark.result_table`).
    path : str or Path, optional
        Write the figure there.
    metrics : sequence of str
        Indicators to draw (one panel each; those all-NaN are skipped).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    plt = _pyplot()
    sub = _env_means(df)
    keys = ["controller", "compensator", "reference", "environment"]
    se_rows = df[(df["kind"] == "environment") & (df["statistic"] == "se")]
    se_of = {tuple(r[k] for k in keys): r for _, r in se_rows.iterrows()}
    metrics = [m for m in metrics if m in sub and np.isfinite(sub[m].to_numpy(dtype=float)).any()]
    xs, locked_x = _stiffness_axis(sub)
    n = max(1, len(metrics))
    cols = min(3, n)
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, squeeze=False, figsize=(4.6 * cols, 3.4 * rows))
    for ax, m in zip(axes.flat, metrics):
        for (ctrl, comp, ref), g in sub.groupby(["controller", "compensator", "reference"], sort=False):
            x = np.array([xs[e] for e in g["environment"]])
            y = g[m].to_numpy(dtype=float)
            order = np.argsort(x)
            if not np.isfinite(y).any():
                continue
            line, = ax.plot(x[order], y[order], marker="o", lw=1.2, label=f"{ctrl} + {comp} ({ref.split(':')[0]})")
            se = np.array([float(se_of[(ctrl, comp, ref, e)][m]) if (ctrl, comp, ref, e) in se_of else np.nan
                           for e in g["environment"]])
            if np.isfinite(se).any():      # +- one standard error over the repetitions
                ax.errorbar(x[order], y[order], yerr=np.nan_to_num(se[order]), fmt="none", ecolor=line.get_color(),
                            elinewidth=0.8, capsize=2)
        ax.set_xscale("log")
        ax.set_xlabel("environment stiffness k_e [N m/rad]" + (" (locked at right)" if locked_x else ""))
        ax.set_ylabel(UNITS.get(m, m))
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[len(metrics):]:
        ax.axis("off")
    if metrics:
        axes.flat[0].legend(fontsize=7)
    fig.suptitle("Benchmark indicators over the environment set (per-environment means +- one standard error)")
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path)
    return fig


def plot_overlays(cells: Sequence[Any], path: str | Path | None = None, *, reference: str | None = None):
    """Repetition overlays (Figs. 10-12): tau_s of every repetition and the frictionless expected response.

    Parameters
    ----------
    cells : sequence of CellResult
        The benchmark's cells (one controller is drawn: the first one's).
    path : str or Path, optional
        Write the figure there.
    reference : str, optional
        Reference label to draw (default: the first step reference, else the first).

    Returns
    -------
    matplotlib.figure.Figure
        Rows: compensators; columns: environments.
    """
    plt = _pyplot()
    cells = list(cells)
    if not cells:
        raise ParameterError("overlay plot needs at least one benchmark cell", name="cells", value=0)
    refs = list(dict.fromkeys(c.labels["reference"] for c in cells))
    ref = reference or next((r for r in refs if r.startswith("step")), refs[0])
    ctrl = cells[0].labels["controller"]
    chosen = [c for c in cells if c.labels["reference"] == ref and c.labels["controller"] == ctrl]
    comps = list(dict.fromkeys(c.labels["compensator"] for c in chosen))
    envs = list(dict.fromkeys(c.labels["environment"] for c in chosen))
    fig, axes = plt.subplots(len(comps), len(envs), squeeze=False, sharex=True,
                             figsize=(3.2 * len(envs) + 0.6, 2.4 * len(comps) + 0.6))
    for c in chosen:
        ax = axes[comps.index(c.labels["compensator"]), envs.index(c.labels["environment"])]
        for y in c.tau_s:
            ax.plot(c.t, y, lw=0.8, alpha=0.7)
        ax.plot(c.t, c.expected, "r--", lw=1.2)
        ax.set_title(f"{c.labels['compensator']} | {c.labels['environment']}\nx-corr {c.repeatability:.3f}",
                     fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$\tau_s$ [N m]", fontsize=8)
    fig.suptitle(f"{ctrl}, {ref}: repetitions (solid) and the frictionless response (red dashed)", fontsize=9)
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path)
    return fig


def plot_heatmap(df, path: str | Path | None = None, *, metrics: Sequence[str] = ("repeatability", "mae_N_m")):
    """Heat map of the set: per-environment means, rows controller + compensator (+ reference), columns environments.

    Parameters
    ----------
    df : pandas.DataFrame
        The benchmark table.
    path : str or Path, optional
        Write the figure there.
    metrics : sequence of str
        One heat map per indicator.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    plt = _pyplot()
    sub = _env_means(df)
    metrics = [m for m in metrics if np.isfinite(sub[m].to_numpy(dtype=float)).any()]
    envs = list(dict.fromkeys(sub["environment"]))
    keys = list(dict.fromkeys(zip(sub["controller"], sub["compensator"], sub["reference"])))
    fig, axes = plt.subplots(1, max(1, len(metrics)), squeeze=False,
                             figsize=(1.0 * len(envs) * max(1, len(metrics)) + 3.5, 0.45 * len(keys) + 1.8))
    for ax, m in zip(axes[0], metrics):
        grid = np.full((len(keys), len(envs)), np.nan)
        for _, r in sub.iterrows():
            grid[keys.index((r["controller"], r["compensator"], r["reference"])), envs.index(r["environment"])] = r[m]
        im = ax.imshow(grid, aspect="auto", cmap="viridis")
        for i in range(len(keys)):
            for j in range(len(envs)):
                if np.isfinite(grid[i, j]):
                    ax.text(j, i, f"{grid[i, j]:.3g}", ha="center", va="center", fontsize=7, color="w")
        ax.set_xticks(range(len(envs)), envs, rotation=45, ha="right", fontsize=7)
        ax.set_yticks(range(len(keys)), [f"{a} + {b} ({c.split(':')[0]})" for a, b, c in keys], fontsize=7)
        ax.set_title(UNITS.get(m, m), fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path)
    return fig
