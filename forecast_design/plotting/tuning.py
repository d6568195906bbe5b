"""The Q-cutoff trade-off (``tune-q --plot``): margin kept and friction-rejection bandwidth bought."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

from ..errors import ParameterError
from ..tuning.tradeoff import CutoffTradeoff
from . import _pyplot, save_figure
from .style import observer_colour, observer_label

__all__ = ["figure_tradeoff", "plot_tradeoff"]

_MAX_ENV_CURVES = 6     # per-environment curves of the first observer drawn up to this many plants
_DASHES = ((0, (6, 2)), (0, (2, 2)), (0, (8, 2, 2, 2)), (0, (1, 1)))


def figure_tradeoff(tradeoffs: CutoffTradeoff | Sequence[CutoffTradeoff], *, title: str | None = None):
    """Draw the trade-off the Q tuner resolves and return the open figure (see :func:`plot_tradeoff`)."""
    plt = _pyplot()
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    items = [tradeoffs] if isinstance(tradeoffs, CutoffTradeoff) else list(tradeoffs)
    if not items:
        raise ParameterError("plot_tradeoff needs at least one CutoffTradeoff", name="tradeoffs", value=tradeoffs)
    first = items[0]
    fig, (ax_r, ax_b) = plt.subplots(2, 1, sharex=True, figsize=(10.5, 7.2), layout="constrained")
    if len(first.environments) <= _MAX_ENV_CURVES and len(first.environments) > 1:
        greys = [str(g) for g in (0.35, 0.55, 0.7, 0.45, 0.6, 0.8)]
        styles = (":", "-.", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 3)), (0, (8, 2)), (0, (3, 1, 1, 1)))
        for j, env in enumerate(first.environments):
            ax_r.semilogx(first.w_q_hz, first.ratios[:, j], color=greys[j], linestyle=styles[j], linewidth=1.0,
                          label=f"{observer_label(first.observer)} in {env}")
    for k, tr in enumerate(items):
        main = k == 0
        # comparison observers: thinner and each its own dash, so coinciding curves stay visible
        line = {"color": observer_colour(tr.observer), "linewidth": 2.4 if main else 1.4,
                "linestyle": "-" if main else _DASHES[(k - 1) % len(_DASHES)]}
        colour = line["color"]
        ax_r.semilogx(tr.w_q_hz, tr.worst_ratio, label=f"{observer_label(tr.observer)}: worst over the set",
                      gid=f"ratio|{tr.observer}", **line)
        ax_b.semilogx(tr.w_q_hz, tr.rejection_bandwidth_hz, label=observer_label(tr.observer),
                      gid=f"bandwidth|{tr.observer}", **line)
        if tr.chosen_w_q_hz is not None:
            i = tr.at(tr.chosen_w_q_hz)
            ratio, bw, env = tr.worst_ratio[i], tr.rejection_bandwidth_hz[i], tr.binding_environment[i]
            ax_r.plot([tr.w_q_hz[i]], [ratio], "o", color=colour, markersize=9 if main else 6,
                      markeredgecolor="black", zorder=5, gid=f"chosen|{tr.observer}")
            ax_b.plot([tr.w_q_hz[i]], [bw], "o", color=colour, markersize=9 if main else 6,
                      markeredgecolor="black", zorder=5)
            if main:
                for ax in (ax_r, ax_b):
                    ax.axvline(tr.w_q_hz[i], color=colour, linestyle="--", linewidth=1.0)
                # text on the side of the chosen cutoff with more room
                left_half = math.log(tr.w_q_hz[i] / tr.w_q_hz[0]) < 0.5 * math.log(tr.w_q_hz[-1] / tr.w_q_hz[0])
                dx, ha = (12, "left") if left_half else (-12, "right")
                box = {"facecolor": "white", "edgecolor": colour, "alpha": 0.9}
                ax_r.annotate(f"chosen w_q = {tr.w_q_hz[i]:.3g} Hz\nratio {ratio:.3f}, binding: {env}",
                              (tr.w_q_hz[i], ratio), xytext=(dx, -34), textcoords="offset points", ha=ha,
                              fontsize="small", bbox=box)
                ax_b.annotate(f"buys {bw:.3g} Hz of friction rejection", (tr.w_q_hz[i], bw), xytext=(dx, -24),
                              textcoords="offset points", ha=ha, fontsize="small", bbox=box)
    lo = min(float(tr.w_q_hz[0]) for tr in items)
    hi = max(float(tr.w_q_hz[-1]) for tr in items)
    ax_r.axhline(first.min_ratio, color="black", linestyle="--", linewidth=1.0,
                 label=f"required min ratio {first.min_ratio:g}")
    ax_r.axhspan(0.0, first.min_ratio, color="tab:red", alpha=0.06)
    top = max(1.05, max(float(tr.ratios.max()) for tr in items) * 1.03)
    ax_r.set_ylim(0.0, top)
    ax_r.set_ylabel("disk margin ratio observer / plant [-]")
    ax_r.set_title("Cost: margin kept in the worst environment of the set (shaded: below the requirement)",
                   fontsize="medium")
    ax_r.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    if math.isfinite(first.ideal_bandwidth_ratio):
        k = first.ideal_bandwidth_ratio
        ax_b.loglog([lo, hi], [lo * k, hi * k], color="0.5", linestyle=":", linewidth=1.0,
                    label=f"exact nominal plant (1 - Q): {k:.3f} w_q")
    ax_b.set_xlim(lo, hi)
    ax_b.set_ylabel("friction-rejection bandwidth [Hz]")
    ax_b.set_xlabel("Q cutoff w_q [Hz]")
    ax_b.set_title("Gain: band where friction is attenuated >= 3 dB (worst over the set; none where unstable)",
                   fontsize="medium")
    ax_b.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (ax_b.xaxis, ax_b.yaxis):
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(plain)
        axis.set_minor_formatter(NullFormatter())
    for ax in (ax_r, ax_b):
        ax.grid(True, which="both", alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig


def plot_tradeoff(tradeoffs: CutoffTradeoff | Sequence[CutoffTradeoff], path: str | Path, *,
                  title: str | None = None) -> Path:
    """Worst-case margin ratio and friction-rejection bandwidth against the Q cutoff, as PNG.

    Parameters
    ----------
    tradeoffs : CutoffTradeoff or sequence of CutoffTradeoff
        From :func:`forecast_design.tuning.tradeoff.cutoff_tradeoff`; the first is the tuned observer
        (drawn bold, with its chosen cutoff, binding environment and, for small sets, one curve
        per environment), the others are drawn thinner for comparison.
    path : str or Path
        Output PNG file.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    return save_figure(figure_tradeoff(tradeoffs, title=title), path, dpi=120)
