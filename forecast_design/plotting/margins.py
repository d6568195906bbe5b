"""Disk-margin plots: the paper's Fig. 6 upper half-disks and alpha(w) curves."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..margins import DiskMarginCurve, disk_center_radius
from ..reproduce import MarginRow
from ..errors import ParameterError
from . import save_figure

__all__ = ["plot_fig6", "plot_disk_margin_curve", "disk_upper_boundary"]

# Colour maps per observer; darker shades for higher Q cutoffs, as in the paper's Fig. 6
# ("the disappearance of the dark red disk" is LD-DOB at 10 Hz).
_CMAPS = {"ea-fob": "Greens", "lo-dob": "Blues", "ld-dob": "Reds", "motor-fob": "Purples", "sfm": "Oranges"}
_LABELS = {"none": "plant", "ea-fob": "EA-FOB", "lo-dob": "LO-DOB", "ld-dob": "LD-DOB",
           "motor-fob": "motor FOB", "sfm": "SFM"}


def disk_upper_boundary(alpha: float, sigma: float = 0.0, n: int = 400) -> np.ndarray:
    """Upper half of the boundary of the disk D(alpha, sigma) in the complex plane.

    Parameters
    ----------
    alpha : float
        Disk size (disk margin) [-].
    sigma : float
        Skew [-], in [-1, 1].
    n : int
        Number of points.

    Returns
    -------
    ndarray of complex, shape (n,)
        f = (1 + (1 - sigma) delta / 2) / (1 - (1 + sigma) delta / 2) for
        delta = alpha exp(j theta), theta from 0 to pi; Im f = Im delta >= 0 when
        |sigma| <= 1, so this is the upper half. It runs from gamma_max (theta = 0) to
        gamma_min (theta = pi); points beyond a pole (alpha (1 + sigma) >= 2) are large.
    """
    theta = np.linspace(0.0, math.pi, n)
    delta = alpha * np.exp(1j * theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (1.0 + (1.0 - sigma) * delta / 2.0) / (1.0 - (1.0 + sigma) * delta / 2.0)


def _half_disk_patch(disk_alpha: float, sigma: float, xlim: tuple[float, float], ylim: tuple[float, float],
                     **kw):
    """A matplotlib patch for the upper half of D(disk_alpha, sigma) (``kw`` go to the patch)."""
    from matplotlib.patches import PathPatch, Polygon
    from matplotlib.path import Path as MplPath

    center, radius, exterior = disk_center_radius(disk_alpha, sigma)
    big = 10.0 * max(abs(xlim[0]), abs(xlim[1]), ylim[1], 1.0)
    lo = (2.0 - disk_alpha * (1.0 - sigma)) / (2.0 + disk_alpha * (1.0 + sigma))
    if not math.isfinite(center):
        # boundary is the vertical line Re f = gamma_min: the right half-plane
        return Polygon([(lo, 0.0), (big, 0.0), (big, big), (lo, big)], closed=True, **kw)
    theta = np.linspace(0.0, math.pi, 721)
    arc = np.column_stack([center + radius * np.cos(theta), radius * np.sin(theta)])
    if not exterior:
        return Polygon(arc, closed=True, **kw)
    # exterior of the circle: a big box with the half-circle as a hole (opposite orientation)
    box = np.array([(-big, 0.0), (big, 0.0), (big, big), (-big, big), (-big, 0.0)])
    hole = arc[::-1]
    verts = np.concatenate([box, hole, hole[:1]])
    codes = ([MplPath.MOVETO] + [MplPath.LINETO] * 3 + [MplPath.CLOSEPOLY]
             + [MplPath.MOVETO] + [MplPath.LINETO] * (len(hole) - 1) + [MplPath.CLOSEPOLY])
    return PathPatch(MplPath(verts, codes), **kw)


def plot_fig6(rows: Sequence[MarginRow], path: str | Path, *, sigma: float = 0.0,
              xlim: tuple[float, float] = (-0.25, 4.0), ylim: tuple[float, float] = (0.0, 2.25),
              title: str | None = "Disk margins of the DOB solutions (cf. paper Fig. 6)") -> Path:
    """Upper half-disks of gain/phase variations per environment (the paper's Fig. 6).

    Parameters
    ----------
    rows : sequence of MarginRow
        Rows of :func:`forecast_design.reproduce.fig6_table`; one subplot per environment in
        order of appearance. Unstable rows have no disk and are listed as unstable in the
        legend, as the paper's figure drops them.
    path : str or Path
        Output PNG file.
    sigma : float
        Skew the rows were computed with [-] (the disk's shape depends on it).
    xlim, ylim : tuple of float
        Axes limits in the complex plane of the perturbation f [-].
    title : str or None
        Figure title.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ParameterError
        If ``rows`` is empty.

    Notes
    -----
    Each disk is D(alpha, sigma) = {(1 + (1 - sigma) delta / 2) / (1 - (1 + sigma) delta / 2)
    : |delta| <= alpha}; for sigma = 0 its boundary is the circle with centre
    (1 + (alpha/2)^2) / (1 - (alpha/2)^2) and radius alpha / (1 - (alpha/2)^2). The dashed
    unit circle reads off the disk-based phase margin where it meets each disk boundary.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(rows)
    if not rows:
        raise ParameterError("plot_fig6 needs at least one MarginRow", name="rows", value=rows)
    envs = list(dict.fromkeys(r.environment for r in rows))
    fig, axes = plt.subplots(len(envs), 1, figsize=(7.5, 3.6 * len(envs)), squeeze=False)
    try:
        for ax, env in zip(axes[:, 0], envs):
            env_rows = [r for r in rows if r.environment == env]
            cutoffs = sorted({r.w_q_hz for r in env_rows if r.w_q_hz is not None})
            handles = []
            for r in env_rows:
                label = _LABELS.get(r.observer, r.observer)
                if r.w_q_hz is not None:
                    label += f" {r.w_q_hz:g} Hz"
                if not r.stable or r.disk_margin <= 0.0:
                    (h,) = ax.plot([], [], " ", label=f"{label}: unstable")
                    handles.append(h)
                    continue
                if r.observer == "none":
                    kw = dict(facecolor="none", edgecolor="black", linewidth=2.2, zorder=3.0)
                else:
                    cmap = plt.get_cmap(_CMAPS.get(r.observer, "Greys"))
                    rgba = cmap(0.45 + 0.5 * (cutoffs.index(r.w_q_hz) + 1) / max(len(cutoffs), 1))
                    # faint fill, strong edge: many disks overlap and must stay readable;
                    # small disks are drawn on top of big ones
                    kw = dict(facecolor=(*rgba[:3], 0.10), edgecolor=rgba, linewidth=1.6,
                              zorder=2.0 + 1.0 / (1.0 + r.disk_margin))
                patch = _half_disk_patch(r.disk_margin, sigma, xlim, ylim, **kw)
                patch.set_label(f"{label}: alpha = {r.disk_margin:.3f}")
                ax.add_patch(patch)
                handles.append(patch)
            theta = np.linspace(0.0, math.pi, 361)
            (h,) = ax.plot(np.cos(theta), np.sin(theta), "k--", linewidth=0.7, label="unit circle")
            handles.append(h)
            ax.plot([1.0], [0.0], "k+", markersize=9)
            ax.set_xlim(*xlim)
            ax.set_ylim(*ylim)
            ax.set_aspect("equal")
            ax.set_xlabel("Re f [-]")
            ax.set_ylabel("Im f [-]")
            ax.set_title(f"{env} environment")
            ax.grid(True, alpha=0.3)
            ax.legend(handles=handles, loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize="x-small")
        if title:
            fig.suptitle(title)
        path = save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)
    return path


def plot_disk_margin_curve(curves: DiskMarginCurve | Mapping[str, DiskMarginCurve], path: str | Path, *,
                           title: str | None = None) -> Path:
    """Frequency-dependent disk margin alpha(w) and disk-based phase margin, saved as PNG.

    Parameters
    ----------
    curves : DiskMarginCurve or Mapping[str, DiskMarginCurve]
        One curve, or labelled curves from :func:`forecast_design.margins.disk_margin_curve`.
    path : str or Path
        Output PNG file.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ParameterError
        If no curve is given.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    items = [("", curves)] if isinstance(curves, DiskMarginCurve) else list(curves.items())
    if not items:
        raise ParameterError("plot_disk_margin_curve needs at least one curve", name="curves", value=curves)
    fig, (ax_a, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(7.0, 5.5))
    try:
        for label, c in items:
            f_hz = c.w_rad_s / (2.0 * math.pi)
            line, = ax_a.semilogx(f_hz, c.alpha, label=str(label) or None)
            i = int(np.nanargmin(c.alpha))
            ax_a.plot(f_hz[i], c.alpha[i], "o", color=line.get_color())
            ax_p.semilogx(f_hz, c.phase_margin_deg, color=line.get_color())
        ax_a.set_ylabel("disk margin alpha(w) [-]")
        ax_p.set_ylabel("disk phase margin [deg]")
        ax_p.set_xlabel("frequency [Hz]")
        for ax in (ax_a, ax_p):
            ax.grid(True, which="both", alpha=0.3)
        if any(label for label, _ in items):
            ax_a.legend(loc="best", fontsize="small")
        if title:
            ax_a.set_title(title)
        path = save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)
    return path
