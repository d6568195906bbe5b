"""Benchmark plots: indicators against environment stiffness, repetition overlays, a heat map of the set.

The plots draw what :mod:`forecast_design.benchmark` computed (the tidy table and the
stored traces); they compute nothing of their own. Conventions shared by the three:

* a colour per compensator (:func:`~forecast_design.plotting.style.observer_colour`, lighter for a
  lower cutoff) and a line style and marker per controller, one legend for the whole figure;
* environments by stiffness on a log axis, a locked output (no stiffness) at its own labelled
  position to the right, a free one (k_e = 0) to the left, never connected by a line;
* a cell whose ``stable`` flag is false (unstable loop or diverged run) drawn as such: a red
  cross (indicators; a triangle on the frame when its value is off the scale of the stable
  cells), a red panel (overlays), a hatched grey square (heat map); it never sets a scale.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ParameterError
from . import _pyplot, write_figure
from .style import observer_colour

__all__ = ["plot_indicators", "plot_overlays", "plot_heatmap", "UNITS", "UNSTABLE_COLOUR"]

#: Axis labels of the metrics.
UNITS = {"repeatability": "repeatability (mean x-corr) [-]", "mae_N_m": "MAE to frictionless [N m]",
         "rise_time_s": "rise time [s]", "overshoot_percent": "overshoot (of the step) [%]",
         "settling_time_s": "settling time [s]", "steady_state_error_N_m": "steady-state error [N m]",
         "bandwidth_hz": "tracking bandwidth [Hz]", "disk_margin": "disk margin [-]"}
#: Colour of what is unstable (markers, panel tint, hatch edge).
UNSTABLE_COLOUR = "#d62728"
_CONTROLLER_STYLES = (("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"), ((0, (5, 1, 1, 1)), "v"), ((0, (1, 3)), "P"))
#: Series whose values differ by less than this fraction of the panel's range are merged (with a note).
_SAME = 0.01


def _env_means(df):
    sub = df[(df["kind"] == "environment") & (df["statistic"] == "mean")]
    if sub.empty:
        raise ParameterError("benchmark table has no per-environment rows", name="table", value=len(df))
    return sub


def _unstable(value: Any) -> bool:
    """A ``stable`` flag that is false (None, NaN and pandas' NA: unknown, not unstable)."""
    try:
        return value is not None and not bool(value)
    except TypeError:         # pandas' NA has no truth value
        return False


def _positions(sub) -> tuple[dict[str, float], list[float], list[str], list[float]]:
    """x of each environment: log10 k_e; a free output (k_e <= 0) one decade left, a locked one right.

    Returns the positions, the tick positions and labels, and where to draw separators.
    """
    locked = {e: bool(lk) for e, lk in zip(sub["environment"], sub["locked"].fillna(False))}
    ks = {e: float(k) for e, k in zip(sub["environment"], sub["k_e"])}
    logs = [math.log10(k) for e, k in ks.items() if not locked[e] and k > 0]
    lo, hi = (math.floor(min(logs)), math.ceil(max(logs))) if logs else (0, 0)
    if hi == lo:
        hi = lo + 1
    xs, ticks, labels, seps = {}, [float(d) for d in range(lo, hi + 1)], [f"$10^{{{d}}}$" for d in range(lo, hi + 1)], []
    for e in ks:
        if locked[e]:
            xs[e] = hi + 1.0
        elif ks[e] <= 0:
            xs[e] = lo - 1.0
        else:
            xs[e] = math.log10(ks[e])
    if any(locked.values()):
        ticks.append(hi + 1.0), labels.append("locked"), seps.append(hi + 0.5)
    if any(not locked[e] and ks[e] <= 0 for e in ks):
        ticks.insert(0, lo - 1.0), labels.insert(0, "k_e = 0"), seps.append(lo - 0.5)
    return xs, ticks, labels, seps


def _styles(keys: Sequence[tuple[str, str, str]]) -> dict[tuple[str, str, str], dict[str, Any]]:
    """Colour per compensator (shade per cutoff of one kind), line style and marker per controller."""
    ctrls = list(dict.fromkeys(k[0] for k in keys))
    refs = list(dict.fromkeys(k[2] for k in keys))
    cut: dict[str, list[float]] = {}
    for _, comp, _ in keys:
        kind, _, w = comp.partition(":")
        if w:
            cut.setdefault(kind, []).append(float(w))
    out = {}
    for key in keys:
        ctrl, comp, ref = key
        kind, _, w = comp.partition(":")
        cs = sorted(set(cut.get(kind, [])))
        shade = 0.55 + 0.45 * (cs.index(float(w)) + 1) / len(cs) if w else 1.0
        ls, marker = _CONTROLLER_STYLES[ctrls.index(ctrl) % len(_CONTROLLER_STYLES)]
        label = f"{ctrl} + {comp}" + (f" ({ref})" if len(refs) > 1 else "")
        out[key] = {"color": observer_colour(kind, shade), "ls": ls, "marker": marker, "label": label}
    return out


def _grid(plt, n: int, width: float, height: float):
    """Up to three panels a row; returns the figure, the used axes and the first free slot (or None)."""
    cols = min(3, max(1, n))
    rows = int(math.ceil(max(1, n) / cols))
    fig, axes = plt.subplots(rows, cols, squeeze=False, figsize=(width * cols, height * rows))
    flat = list(axes.flat)
    for ax in flat[n:]:
        ax.remove()
    return fig, flat[:n], (flat[n] if n < len(flat) else None)


def plot_indicators(df, path: str | Path | None = None, *,
                    metrics: Sequence[str] = ("repeatability", "mae_N_m", "rise_time_s", "overshoot_percent",
                                              "settling_time_s", "bandwidth_hz", "disk_margin")):
    """Each indicator (per-environment mean) against the environment stiffness, a line per controller + compensator.

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
        The figure: panels with their y labels and units, one legend for every series; series
        that coincide within 1 % of a panel's range are drawn once and named in a note in
        that panel; unstable cells are red crosses that do not set the y scale.
    """
    plt = _pyplot()
    from matplotlib.lines import Line2D

    sub = _env_means(df)
    keys = ["controller", "compensator", "reference", "environment"]
    se_rows = df[(df["kind"] == "environment") & (df["statistic"] == "se")]
    se_of = {tuple(r[k] for k in keys): r for _, r in se_rows.iterrows()}
    metrics = [m for m in metrics if m in sub and np.isfinite(sub[m].to_numpy(dtype=float)).any()]
    xs, ticks, tick_labels, seps = _positions(sub)
    series = list(dict.fromkeys(zip(sub["controller"], sub["compensator"], sub["reference"])))
    styles = _styles(series)
    fig, axes, free = _grid(plt, len(metrics), 4.8, 3.5)
    any_unstable = off_scale = False
    for ax, m in zip(axes, metrics):
        drawn: list[tuple[tuple, np.ndarray]] = []
        notes: dict[tuple, list[tuple]] = {}
        good = np.array([not _unstable(s) for s in sub["stable"]])
        y_all = sub[m].to_numpy(dtype=float)[good]
        e_all = np.array([float(se_of[tuple(r[k] for k in keys)][m]) if tuple(r[k] for k in keys) in se_of else 0.0
                          for _, r in sub[good].iterrows()])
        e_all = np.nan_to_num(e_all)
        stable_vals = np.concatenate([y_all - e_all, y_all + e_all])
        stable_vals = stable_vals[np.isfinite(stable_vals)]
        lo, hi = (float(stable_vals.min()), float(stable_vals.max())) if stable_vals.size else (0.0, 1.0)
        span = (hi - lo) or max(abs(hi), 1e-12)
        envs = list(dict.fromkeys(sub["environment"]))
        for key in series:
            g = sub[(sub["controller"] == key[0]) & (sub["compensator"] == key[1]) & (sub["reference"] == key[2])]
            y = g.set_index("environment")[m].reindex(envs).to_numpy(dtype=float)
            if not np.isfinite(y).any():
                continue
            same = next((k for k, other in drawn if np.array_equal(np.isnan(other), np.isnan(y))
                         and np.all(np.abs(np.nan_to_num(other - y)) <= _SAME * span)), None)
            if same is not None:          # coincides with a series already drawn: named in the panel's note
                notes.setdefault(same, []).append(key)
                continue
            drawn.append((key, y))
            st = styles[key]
            bad = np.array([_unstable(v) for v in g.set_index("environment")["stable"].reindex(envs)])
            x = np.array([xs[e] for e in envs])
            se = np.array([float(se_of[(*key, e)][m]) if (*key, e) in se_of else np.nan for e in envs])
            ok = np.isfinite(y) & ~bad
            special = np.isin(x, [t for t, lab in zip(ticks, tick_labels) if lab in ("locked", "k_e = 0")])
            line = ok & ~special
            order = np.argsort(x[line])
            ax.plot(x[line][order], y[line][order], ls=st["ls"], color=st["color"], marker=st["marker"], ms=5, lw=1.3)
            ax.plot(x[ok & special], y[ok & special], ls="none", color=st["color"], marker=st["marker"], ms=6)
            if np.isfinite(se[ok]).any():      # +- one standard error over the repetitions
                ax.errorbar(x[ok], y[ok], yerr=np.nan_to_num(se[ok]), fmt="none", ecolor=st["color"],
                            elinewidth=0.8, capsize=2)
            for xi, yi in zip(x[bad & np.isfinite(y)], y[bad & np.isfinite(y)]):
                any_unstable = True
                pad = 0.08 * span
                if yi > hi + pad or yi < lo - pad:
                    off_scale = True
                    ax.plot([xi], [hi + pad if yi > hi else lo - pad], ls="none", marker="^" if yi > hi else "v",
                            mfc=st["color"], mec=UNSTABLE_COLOUR, mew=1.8, ms=9, clip_on=False, gid="unstable")
                else:
                    ax.plot([xi], [yi], ls="none", marker="X", mfc=st["color"], mec=UNSTABLE_COLOUR, mew=1.8, ms=10,
                            gid="unstable")
        if stable_vals.size:
            ax.set_ylim(lo - 0.08 * span, hi + 0.08 * span)
        if notes:                 # which series this panel draws once (a legend placed where no data is)
            merged = ax.legend(handles=[Line2D([], [], color=styles[k]["color"], ls=styles[k]["ls"],
                                               marker=styles[k]["marker"]) for k in notes],
                               labels=[" = ".join(styles[x]["label"] for x in (k, *others)) for k, others in notes.items()],
                               loc="best", fontsize=6.5, title="drawn once (within 1 % of the axis)",
                               title_fontsize=6.5, framealpha=0.9)
            merged.set_gid("merged")
        ax.set_xticks(ticks, tick_labels)
        for s in seps:
            ax.axvline(s, color="0.5", lw=0.8, ls=":")
        ax.set_xlim(min(ticks) - 0.4, max(ticks) + 0.4)
        ax.set_xlabel("environment stiffness k_e [N m/rad]")
        ax.set_ylabel(UNITS.get(m, m))
        ax.grid(True, alpha=0.3)
    handles = [Line2D([], [], color=styles[k]["color"], ls=styles[k]["ls"], marker=styles[k]["marker"],
                      label=styles[k]["label"]) for k in series]
    if any_unstable:
        handles.append(Line2D([], [], ls="none", marker="X", mfc="0.8", mec=UNSTABLE_COLOUR, mew=1.8, ms=10,
                              label="unstable cell (series colour; not in the set rows)"))
    if off_scale:
        handles.append(Line2D([], [], ls="none", marker="^", mfc="0.8", mec=UNSTABLE_COLOUR, mew=1.8, ms=9,
                              label="unstable cell, value off the scale"))
    fig.suptitle("Benchmark indicators over the environment set (per-environment means +- one standard error)")
    legend = {"handles": handles, "fontsize": 8, "title": "controller + compensator", "title_fontsize": 8}
    if free is not None:          # the grid's free slot holds the legend
        fig.tight_layout()
        fig.legend(loc="center", bbox_to_anchor=free.get_subplotspec().get_position(fig), **legend)
    else:
        _legend_below(fig, legend)
    if path is not None:
        write_figure(fig, path)
    return fig


def _legend_below(fig, legend: dict[str, Any]) -> None:
    """A figure legend below the panels, inside the canvas: as many columns as the width holds."""
    n = len(legend["handles"])
    cols = max(1, min(n, 3, int(fig.get_figwidth() / 3.4)))
    lines = int(math.ceil(n / cols)) + (1 if legend.get("title") else 0)
    fig.tight_layout(rect=(0, min(0.5, (0.2 + 0.19 * lines) / fig.get_figheight()), 1, 1))
    fig.legend(loc="lower center", ncols=cols, **legend)


def _cell_flags(cell: Any) -> tuple[bool, int]:
    unsettled = sum(1 for r in cell.runs if r.get("settled") is False)
    return cell.stable is False, unsettled


def plot_overlays(cells: Sequence[Any], path: str | Path | None = None, *, reference: str | None = None):
    """Repetition overlays (Figs. 10-12): tau_s of every repetition and the frictionless expected response.

    Parameters
    ----------
    cells : sequence of CellResult
        The benchmark's cells: every controller and compensator is drawn.
    path : str or Path, optional
        Write the figure there.
    reference : str, optional
        Reference label to draw (default: the first step reference, else the first).

    Returns
    -------
    matplotlib.figure.Figure
        Rows: controller + compensator; columns: environments. An unstable cell's panel is
        tinted red and titled UNSTABLE; a cell's unsettled runs are counted in its title.
    """
    plt = _pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    cells = list(cells)
    if not cells:
        raise ParameterError("overlay plot needs at least one benchmark cell", name="cells", value=0)
    refs = list(dict.fromkeys(c.labels["reference"] for c in cells))
    ref = reference or next((r for r in refs if r.startswith("step")), refs[0])
    chosen = [c for c in cells if c.labels["reference"] == ref]
    rows = list(dict.fromkeys((c.labels["controller"], c.labels["compensator"]) for c in chosen))
    envs = list(dict.fromkeys(c.labels["environment"] for c in chosen))
    fig, axes = plt.subplots(len(rows), len(envs), squeeze=False, sharex=True,
                             figsize=(2.9 * len(envs) + 0.8, 2.1 * len(rows) + 1.2))
    any_bad = False
    for c in chosen:
        ax = axes[rows.index((c.labels["controller"], c.labels["compensator"])), envs.index(c.labels["environment"])]
        bad, unsettled = _cell_flags(c)
        for y in c.tau_s:
            ax.plot(c.t, y, lw=0.8, alpha=0.75, color="#1f77b4")
        ax.plot(c.t, c.expected, "--", color="k", lw=1.1)
        title = f"{c.labels['controller']} + {c.labels['compensator']} | {c.labels['environment']}\n" \
                f"x-corr {c.repeatability:.3f}" + (f", {unsettled}/{len(c.runs)} unsettled" if unsettled else "")
        if bad:
            any_bad = True
            ax.set_facecolor("#fde3e3")
            title = "UNSTABLE " + title
        ax.set_title(title, fontsize=7, color=UNSTABLE_COLOUR if bad else "k")
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$\tau_s$ [N m]", fontsize=8)
    handles = [Line2D([], [], color="#1f77b4", lw=0.8, label="repetitions (tau_s, one line each)"),
               Line2D([], [], color="k", ls="--", lw=1.1, label="frictionless expected response")]
    if any_bad:
        handles.append(Patch(facecolor="#fde3e3", edgecolor=UNSTABLE_COLOUR, label="unstable cell (not in the set rows)"))
    fig.suptitle(f"{ref}: repetitions and the frictionless expected response,\nevery controller and compensator",
                 fontsize=9)
    _legend_below(fig, {"handles": handles, "fontsize": 8})
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
        The figure; an unstable cell is a hatched grey square labelled ``unstable`` with its
        value, outside the colour scale (which spans the stable cells only).
    """
    plt = _pyplot()
    from matplotlib.patches import Rectangle

    sub = _env_means(df)
    metrics = [m for m in metrics if np.isfinite(sub[m].to_numpy(dtype=float)).any()]
    envs = list(dict.fromkeys(sub["environment"]))
    keys = list(dict.fromkeys(zip(sub["controller"], sub["compensator"], sub["reference"])))
    refs = {k[2] for k in keys}
    fig, axes = plt.subplots(1, max(1, len(metrics)), squeeze=False,
                             figsize=(1.0 * len(envs) * max(1, len(metrics)) + 4.5, 0.45 * len(keys) + 2.2))
    any_bad = False
    for ax, m in zip(axes[0], metrics):
        grid = np.full((len(keys), len(envs)), np.nan)
        bad = np.zeros_like(grid, dtype=bool)
        for _, r in sub.iterrows():
            i, j = keys.index((r["controller"], r["compensator"], r["reference"])), envs.index(r["environment"])
            grid[i, j], bad[i, j] = r[m], _unstable(r["stable"])
        shown = np.where(bad, np.nan, grid)
        im = ax.imshow(np.ma.masked_invalid(shown), aspect="auto", cmap="viridis")
        cmap, norm = im.get_cmap(), im.norm
        for i in range(len(keys)):
            for j in range(len(envs)):
                if bad[i, j]:
                    any_bad = True
                    ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, facecolor="0.85", edgecolor=UNSTABLE_COLOUR,
                                           hatch="///", lw=1.2, gid="unstable"))
                    ax.text(j, i, "unstable" + (f"\n{grid[i, j]:.3g}" if np.isfinite(grid[i, j]) else ""),
                            ha="center", va="center", fontsize=6.5, color="k")
                elif np.isfinite(grid[i, j]):
                    r_, g_, b_, _ = cmap(norm(grid[i, j]))
                    ax.text(j, i, f"{grid[i, j]:.3g}", ha="center", va="center", fontsize=7,
                            color="k" if 0.299 * r_ + 0.587 * g_ + 0.114 * b_ > 0.5 else "w")
        ax.set_xticks(range(len(envs)), envs, rotation=45, ha="right", fontsize=7)
        ax.set_yticks(range(len(keys)), [f"{a} + {b}" + (f" ({c})" if len(refs) > 1 else "") for a, b, c in keys],
                      fontsize=7)
        ax.set_xlabel("environment", fontsize=8)
        ax.set_title(UNITS.get(m, m), fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8).set_label("scale: stable cells only", fontsize=7)
    fig.suptitle("Per-environment means" + (" (hatched: unstable cell, outside the colour scale and the set rows)"
                                            if any_bad else ""), fontsize=9)
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path)
    return fig
