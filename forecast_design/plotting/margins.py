"""Disk-margin plots: the paper's Fig. 6 upper half-disks and alpha(w) curves."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..margins import DiskMarginCurve, disk_center_radius
from ..reproduce import MarginRow
from ..errors import ParameterError
from . import _pyplot, save_figure
from .style import OBSERVER_MARKERS, cutoff_style, observer_colour, observer_label

__all__ = ["figure_fig6", "plot_fig6", "plot_disk_margin_curve", "disk_upper_boundary", "plot_loop_analysis"]


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


_NEAR_ONE = (-0.25, 4.0)   # Re f shown around the nominal f = 1 at least [-]


def _disk_extent(r: MarginRow, sigma: float) -> tuple[float, float, float] | None:
    """(gamma_min, gamma_max, radius) of a bounded disk [-]; None for no disk or an unbounded one."""
    if not r.stable or r.disk_margin <= 0.0:
        return None
    center, radius, exterior = disk_center_radius(r.disk_margin, sigma)
    if exterior or not math.isfinite(center):
        return None
    return center - radius, center + radius, radius


def _frame(extents: Sequence[tuple[float, float, float]]) -> tuple[tuple[float, float], tuple[float, float]]:
    """Limits holding every extent whole, the unit circle and f = 1 (equal aspect: y up to half the width)."""
    lo = min([_NEAR_ONE[0]] + [1.04 * e[0] if e[0] < 0 else 0.0 for e in extents])
    hi = max([_NEAR_ONE[1]] + [e[1] for e in extents])
    hi = lo + 1.04 * (hi - lo)
    top = max([0.5 * (hi - lo)] + [1.04 * e[2] for e in extents])
    return (lo, hi), (0.0, top)


def _fig6_frames(env_rows: Sequence[MarginRow], sigma: float) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """One frame holding every bounded disk whole; a second one near f = 1 when the first makes the
    small disks tiny (the largest reaches more than 3 times as far as the frame near f = 1)."""
    extents = [e for e in (_disk_extent(r, sigma) for r in env_rows) if e is not None]
    whole = _frame(extents)
    near = _frame([e for e in extents if e[1] <= 10.0])
    if whole[0][1] - whole[0][0] > 3.0 * (near[0][1] - near[0][0]):
        return [whole, near]
    return [whole]


def figure_fig6(rows: Sequence[MarginRow], *, sigma: float = 0.0,
                xlim: tuple[float, float] | None = None, ylim: tuple[float, float] | None = None,
                title: str | None = "Disk margins of the DOB solutions (cf. paper Fig. 6)"):
    """Draw the paper's Fig. 6 and return the open matplotlib figure (see :func:`plot_fig6`).

    One row per environment: the upper half-disks of tolerated gain/phase variations (one
    frame holding every disk whole, and beside it a frame near f = 1 when the largest disks
    would make the others tiny), then a bar per observer and cutoff with its disk margin alpha
    (disks of nearly equal alpha coincide; the bars keep each one readable). Colours follow
    :mod:`forecast_design.plotting.style`: one hue per observer, darker and more solid for
    higher cutoffs, the same in every panel. The plant is a thick pale band underneath; each
    observer's disk carries its marker at its own places along the arc, so a disk of the
    plant's size (EA-FOB) shows on top of the plant's.
    """
    plt = _pyplot()
    from matplotlib.lines import Line2D

    rows = list(rows)
    if not rows:
        raise ParameterError("plot_fig6 needs at least one MarginRow", name="rows", value=rows)
    envs = list(dict.fromkeys(r.environment for r in rows))
    cutoffs = sorted({r.w_q_hz for r in rows if r.w_q_hz is not None})
    frames = {env: ([(xlim, ylim or (0.0, 0.5 * (xlim[1] - xlim[0]) + 0.05))] if xlim else
                    _fig6_frames([r for r in rows if r.environment == env], sigma)) for env in envs}
    two = any(len(f) == 2 for f in frames.values())
    fig = plt.figure(figsize=(14.5 if two else 11.0, 3.9 * len(envs) + 1.3), layout="constrained")
    grid = fig.add_gridspec(len(envs), 3 if two else 2, width_ratios=(1.2, 1.2, 1.0) if two else (2.1, 1.0))
    legend: dict[str, Line2D] = {}
    others = [r for r in rows if r.observer != "none"]
    order = list(dict.fromkeys((r.observer, r.w_q_hz) for r in others))

    def style_of(r: MarginRow) -> dict:
        shade, ls = cutoff_style(r.w_q_hz, cutoffs)
        if r.observer == "none":
            return {"color": observer_colour("none"), "linestyle": "-", "linewidth": 5.0, "alpha": 0.3}
        return {"color": observer_colour(r.observer, shade), "linestyle": ls, "linewidth": 1.5}

    def name_of(r: MarginRow) -> str:
        return observer_label(r.observer) + ("" if r.w_q_hz is None else f" {r.w_q_hz:g} Hz")

    def marker_of(r: MarginRow) -> dict:
        st = style_of(r)
        return {"marker": OBSERVER_MARKERS.get(r.observer, "o"), "markersize": 6.5, "color": st["color"],
                "markeredgecolor": "white", "markeredgewidth": 0.6, "linestyle": "none"}

    for k, env in enumerate(envs):
        env_rows = [r for r in rows if r.environment == env]
        env_frames = frames[env]
        axes = ([fig.add_subplot(grid[k, 0]), fig.add_subplot(grid[k, 1])] if len(env_frames) == 2
                else [fig.add_subplot(grid[k, 0:2] if two else grid[k, 0])])
        bars = fig.add_subplot(grid[k, 2 if two else 1])
        for r in env_rows:
            st = style_of(r)
            handle = {**st, **({k2: v for k2, v in marker_of(r).items() if k2 != "linestyle"}
                               if r.observer != "none" else {})}
            legend.setdefault(name_of(r), Line2D([], [], **handle))
        for i, (ax, (fx, fy)) in enumerate(zip(axes, env_frames)):
            unbounded = _draw_disks(ax, env_rows, sigma, fx, fy, style_of, marker_of, order)
            theta = np.linspace(0.0, math.pi, 361)
            ax.plot(np.cos(theta), np.sin(theta), color="0.45", linestyle=(0, (4, 3)), linewidth=0.8)
            ax.plot([1.0], [0.0], "k+", markersize=9)
            ax.set_xlim(*fx)
            ax.set_ylim(*fy)
            ax.set_aspect("equal")
            ax.set_xlabel("Re f [-]")
            ax.set_ylabel("Im f [-]")
            ax.grid(True, alpha=0.3)
            if i == 0:
                ax.set_title(f"{env} environment: upper half-disks, each whole (dashed grey: unit circle)",
                             fontsize="medium")
            else:
                ax.set_title(f"near f = 1 (Re f up to {fx[1]:.3g}); larger disks whole on the left",
                             fontsize="medium")
                from matplotlib.patches import Rectangle

                axes[0].add_patch(Rectangle((fx[0], fy[0]), fx[1] - fx[0], fy[1] - fy[0], fill=False,
                                            edgecolor="0.35", linestyle=":", linewidth=1.0, zorder=1.0))
            if unbounded and i == 0:
                ax.text(0.98, 0.97, f"{len(unbounded)} disks unbounded (alpha >= 2): shaded to the frame's edge",
                        transform=ax.transAxes, ha="right", va="top", fontsize="x-small",
                        bbox={"facecolor": "white", "edgecolor": "0.7", "alpha": 0.9})
        _alpha_bars(bars, env_rows, style_of, name_of)
    # one legend column per observer, one line per cutoff (blank entries pad short columns)
    columns: dict[str, list[tuple[str, Line2D]]] = {}
    for name, handle in legend.items():
        kind = next(r.observer for r in rows if name_of(r) == name)
        columns.setdefault(kind, []).append((name, handle))
    depth = max(len(c) for c in columns.values())
    entries = [e for c in columns.values() for e in c + [("", Line2D([], [], linestyle="none"))] * (depth - len(c))]
    fig.legend(handles=[h for _, h in entries], labels=[n for n, _ in entries], loc="outside lower center",
               ncol=len(columns), fontsize="small", frameon=False)
    if title:
        fig.suptitle(title)
    return fig


def _draw_disks(ax, rows: Sequence[MarginRow], sigma: float, xlim, ylim, style_of, marker_of,
                order: Sequence[tuple[str, float | None]]) -> list[MarginRow]:
    """The half-disks of ``rows`` in one frame (plant underneath, markers along each observer's arc);
    returns the unbounded ones."""
    unbounded = []
    for r in rows:
        if not r.stable or r.disk_margin <= 0.0:
            continue
        st = style_of(r)
        patch = _half_disk_patch(r.disk_margin, sigma, xlim, ylim, facecolor="none", edgecolor=st["color"],
                                 linestyle=st["linestyle"], linewidth=st["linewidth"], alpha=st.get("alpha"),
                                 zorder=1.5 if r.observer == "none" else 2.0 + 1.0 / (1.0 + r.disk_margin))
        patch.set_gid(f"{r.environment}|{r.observer}|{r.w_q_hz}")
        ax.add_patch(patch)
        extent = _disk_extent(r, sigma)
        if extent is None:
            unbounded.append(r)
        elif r.observer != "none" and extent[2] > 0.02 * (xlim[1] - xlim[0]):   # tiny here: see the frame near 1
            # each observer and cutoff at its own angles: coinciding arcs keep every disk visible
            j = order.index((r.observer, r.w_q_hz))
            theta = math.pi * (0.06 + 0.88 * ((j + 0.5) / (3 * len(order)) + np.arange(3) / 3.0))
            center, radius = 0.5 * (extent[0] + extent[1]), extent[2]
            ax.plot(center + radius * np.cos(theta), radius * np.sin(theta), zorder=4.0,
                    gid=f"marker|{r.environment}|{r.observer}|{r.w_q_hz}", **marker_of(r))
    return unbounded


def _alpha_bars(ax, rows: Sequence[MarginRow], style_of, name_of) -> None:
    """Horizontal bars of alpha per observer and cutoff; the plant's alpha as a black line."""
    plant = [r for r in rows if r.observer == "none"]
    others = [r for r in rows if r.observer != "none"]
    y = np.arange(len(others))[::-1].astype(float)
    top = max([r.disk_margin for r in rows] + [0.1])
    for yi, r in zip(y, others):
        st = style_of(r)
        if r.stable and r.disk_margin > 0.0:
            ax.barh(yi, r.disk_margin, height=0.72, color=(*st["color"], 0.35), edgecolor=st["color"],
                    linestyle=st["linestyle"], linewidth=1.4, gid=f"{r.environment}|{r.observer}|{r.w_q_hz}")
            ax.text(max([r.disk_margin] + [p.disk_margin for p in plant]) + 0.02 * top, yi,
                    f"{r.disk_margin:.3f}", va="center", fontsize="x-small")
        else:
            ax.plot([0.0], [yi], marker="x", color=st["color"], markersize=8, mew=2.0)
            ax.text(0.04 * top, yi, "unstable", va="center", fontsize="x-small", color=st["color"],
                    fontweight="bold")
    for r in plant:
        ax.axvline(r.disk_margin, color="black", linewidth=1.6)
        ax.text(r.disk_margin, len(others) - 0.35, f"plant {r.disk_margin:.3f}", ha="right", va="bottom",
                fontsize="x-small")
    ax.set_yticks(y, [name_of(r) for r in others], fontsize="x-small")
    ax.set_xlim(0.0, 1.25 * top)
    ax.set_ylim(-0.7, len(others) + 0.3)
    ax.set_xlabel("disk margin alpha [-]")
    ax.grid(True, axis="x", alpha=0.3)


def plot_fig6(rows: Sequence[MarginRow], path: str | Path, *, sigma: float = 0.0,
              xlim: tuple[float, float] | None = None, ylim: tuple[float, float] | None = None,
              title: str | None = "Disk margins of the DOB solutions (cf. paper Fig. 6)") -> Path:
    """Upper half-disks of gain/phase variations per environment (the paper's Fig. 6), as PNG.

    Parameters
    ----------
    rows : sequence of MarginRow
        Rows of :func:`forecast_design.reproduce.fig6_table`; one row of panels per environment
        in order of appearance. Unstable rows have no disk (the paper's figure drops them)
        and show as "unstable" in the bars.
    path : str or Path
        Output PNG file.
    sigma : float
        Skew the rows were computed with [-] (the disk's shape depends on it).
    xlim, ylim : tuple of float, optional
        Axes limits in the complex plane of the perturbation f [-], the same in every panel;
        default per environment: a frame holding every bounded disk whole, and a second frame
        near f = 1 (every disk ending before Re f = 10 whole) when the first makes those tiny.
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
    (1 + (alpha/2)^2) / (1 - (alpha/2)^2) and radius alpha / (1 - (alpha/2)^2). Near
    alpha = 2 the disk is huge (alpha = 1.96 reaches Re f = 99), so disks of nearly equal
    alpha coincide in the plane: each observer's disk carries markers at its own places along
    the arc, and the bar panel beside each environment gives every observer and cutoff its own bar. The dashed unit circle reads off the disk-based
    phase margin where it meets each disk boundary.
    """
    return save_figure(figure_fig6(rows, sigma=sigma, xlim=xlim, ylim=ylim, title=title), path, dpi=120)


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
    plt = _pyplot()

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


def _loop_title(a: Mapping) -> str:
    """Environment, compensator with its cutoff, controller and loop, from a LoopAnalysis' assumptions."""
    comp = a["compensator"]
    kind = comp["table"]["kind"]
    comp_text = "no compensator" if kind == "none" else f"compensator {observer_label(kind)}" + (
        f" at cutoff w_q = {comp['w_q_hz']:g} Hz" if comp["w_q_hz"] is not None else "")
    loop = a["loop"]
    loop_text = (f"sampled at {loop['rate_hz']:g} Hz, delay {loop['delay_samples']}" if loop["kind"] == "sampled"
                 else "continuous")
    believed = a.get("believed_environment")
    env = a["environment"]["name"]
    if isinstance(believed, Mapping):
        env += " (observer believes " + ("locked" if believed.get("locked") else
                                         f"k_e = {believed.get('k_e', float('nan')):g} N m/rad") + ")"
    return f"environment {env}; {comp_text}; controller {a['controller']['label']} ({loop_text} loop)"


def plot_loop_analysis(analysis, path: str | Path) -> Path:
    """The ``margins`` picture of one loop: disk margin over frequency, |S| and |T|, the Nyquist curve.

    Parameters
    ----------
    analysis : LoopAnalysis
        From :func:`forecast_design.analysis.analyse_loop` (it computes the response; this draws).
    path : str or Path
        Output PNG file.

    Returns
    -------
    Path
        The written file.
    """
    plt = _pyplot()
    r = analysis.response()
    f_hz = r.w_rad_s / (2.0 * math.pi)
    dm = analysis.disk
    fig, axes = plt.subplots(2, 2, figsize=(11.0, 7.5))
    (ax_a, ax_n), (ax_s, ax_t) = axes
    try:
        ax_a.semilogx(f_hz, r.alpha, color="C0" if dm.stable else "0.6", gid="alpha")
        if not dm.stable:
            ax_a.text(0.5, 0.5, "closed loop UNSTABLE: no disk margin\n(alpha(f) bounds nothing here)",
                      transform=ax_a.transAxes, ha="center", va="center", color="C3", fontweight="bold",
                      bbox={"facecolor": "white", "edgecolor": "C3", "alpha": 0.9})
        if dm.stable and math.isfinite(dm.frequency_rad_s):
            # the curve's minimum is the disk margin: marked, labelled, and its frequency on every panel
            fc = dm.frequency_rad_s / (2.0 * math.pi)
            ax_a.plot(fc, dm.alpha, "o", color="C3", gid="disk-margin")
            ax_a.annotate(f"minimum: disk margin {dm.alpha:.3f}\nat {fc:.3g} Hz", (fc, dm.alpha),
                          textcoords="offset points", xytext=(10, -28), fontsize="small", color="C3",
                          arrowprops={"arrowstyle": "-", "color": "C3", "lw": 0.8})
            for ax in (ax_a, ax_s, ax_t):
                ax.axvline(fc, color="C3", lw=0.8, ls=":", gid="disk-margin-frequency")
        ax_a.set_ylabel("disk margin alpha(f) [-]")
        ax_a.set_xlabel("frequency [Hz]")
        ax_a.set_ylim(0.0, max(2.5, min(10.0, float(np.nanpercentile(r.alpha, 90)))))
        ax_a.set_title("disk margin over frequency")
        ax_s.semilogx(f_hz, 20 * np.log10(np.abs(r.S)), color="C1", label="|S| = |1/(1 + L)|")
        ax_s.semilogx(f_hz, 20 * np.log10(np.abs(r.T)), color="C2", label="|T| = |L/(1 + L)|")
        ax_s.axhline(0.0, color="0.5", lw=0.8)
        i = int(np.argmax(np.abs(r.S)))
        ax_s.plot(f_hz[i], 20 * np.log10(abs(r.S[i])), "o", color="C1")
        ax_s.annotate(f"peak |S| {20 * np.log10(abs(r.S[i])):.2f} dB", (f_hz[i], 20 * np.log10(abs(r.S[i]))),
                      textcoords="offset points", xytext=(8, 6), fontsize="small", color="C1")
        ax_s.set_ylabel("magnitude [dB]")
        ax_s.set_xlabel("frequency [Hz]")
        ax_s.set_ylim(-60.0, 20.0)
        ax_s.legend(loc="lower left", fontsize="small")
        ax_s.set_title("sensitivity and complementary sensitivity")
        # the Nyquist curve near the critical point, with the disk the margin keeps L away from
        ax_n.plot(r.L.real, r.L.imag, color="C0", label="L(jw), w > 0")
        ax_n.plot(r.L.real, -r.L.imag, color="C0", ls=":", label="L(-jw)")
        ax_n.plot([-1.0], [0.0], "x", color="k", ms=9, label="-1")
        if dm.stable and dm.alpha > 0:
            th = np.linspace(0.0, 2.0 * math.pi, 200)
            # L stays outside the disk of -1/f for every f in the disk of radius alpha
            exclusion = -1.0 / (1.0 + (1.0 - dm.sigma) / 2.0 * dm.alpha * np.exp(1j * th)) * \
                (1.0 - (1.0 + dm.sigma) / 2.0 * dm.alpha * np.exp(1j * th))
            ax_n.fill(exclusion.real, exclusion.imag, color="C3", alpha=0.15, label=f"kept clear by the\ndisk margin {dm.alpha:.3g}\n(-1/f, f in the disk)")
        ax_n.set_xlim(-4.0, 2.0)
        ax_n.set_ylim(-3.0, 3.0)
        ax_n.set_aspect("equal")
        ax_n.axhline(0.0, color="0.6", lw=0.6)
        ax_n.axvline(0.0, color="0.6", lw=0.6)
        ax_n.set_xlabel("Re L [-]")
        ax_n.set_ylabel("Im L [-]")
        ax_n.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="x-small", frameon=False)
        ax_n.set_title("Nyquist curve near -1")
        # Bode of L with the classical crossovers
        mag = 20 * np.log10(np.abs(r.L))
        ax_t.semilogx(f_hz, mag, color="C0", label="|L| [dB]")
        ax_t.axhline(0.0, color="0.5", lw=0.8)
        ax_t.set_ylabel("|L| [dB]")
        ax_t.set_xlabel("frequency [Hz]")
        ax_t.set_ylim(max(-80.0, float(np.nanmin(mag)) - 5), min(80.0, float(np.nanmax(mag)) + 5))
        ax_p = ax_t.twinx()
        ax_p.semilogx(f_hz, np.degrees(np.unwrap(np.angle(r.L))), color="C4", lw=1.0, label="arg L [deg]")
        ax_p.set_ylabel("arg L [deg]", color="C4")
        cm_ = analysis.classical
        # crossovers close in frequency get their labels stacked, not printed over each other
        for i, c in enumerate(cm_.gain_crossovers):
            fx = c.frequency_rad_s / (2 * math.pi)
            ax_t.plot(fx, 0.0, "s", color="C2")
            ax_t.annotate(f"PM {c.phase_margin_deg:.0f} deg", (fx, 0.0), textcoords="offset points",
                          xytext=(5, 6 + 10 * i), fontsize="x-small", color="C2")
        for i, c in enumerate(c for c in cm_.phase_crossovers if c.frequency_rad_s > 0):
            fx = c.frequency_rad_s / (2 * math.pi)
            ax_t.plot(fx, -c.gain_margin_db, "^", color="C3")
            ax_t.annotate(f"GM {c.gain_margin_db:+.1f} dB", (fx, -c.gain_margin_db), textcoords="offset points",
                          xytext=(5, -12 - 10 * i), fontsize="x-small", color="C3")
        ax_t.set_title("loop L: classical crossovers")
        ax_t.grid(True, which="both", alpha=0.3)
        for ax in (ax_a, ax_s):
            ax.grid(True, which="both", alpha=0.3)
        ax_n.grid(True, alpha=0.3)
        cm = analysis.classical
        gm, pm = cm.gain_margin, cm.phase_margin
        summary = (f"disk margin {dm.alpha:.3f}" + (f"; GM {gm.gain_margin_db:+.1f} dB at {gm.frequency_rad_s / (2 * math.pi):.3g} Hz"
                                                    if gm else "; GM inf")
                   + (f"; PM {pm.phase_margin_deg:.1f} deg at {pm.frequency_rad_s / (2 * math.pi):.3g} Hz" if pm else ""))
        fig.suptitle(f"{_loop_title(analysis.assumptions)}\n{summary}"
                     + ("" if dm.stable else "  -- UNSTABLE closed loop"), fontsize="medium")
        fig.tight_layout()
        path = save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
    return path
