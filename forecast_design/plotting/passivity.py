"""The ``passivity`` picture: Re Z(jw) of the actuator's port with the bands where it is negative."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import _pyplot, save_figure

__all__ = ["plot_passivity"]


def plot_passivity(result, path: str | Path) -> Path:
    """Re Z and |Z| of the port over frequency, the bands where Re Z < 0 shaded, min Re Z marked.

    Parameters
    ----------
    result : PassivityResult
        From :func:`forecast_design.passivity.analyse_passivity` (it computes the curve; this draws).
    path : str or Path
        Output PNG file.

    Returns
    -------
    Path
        The written file.
    """
    plt = _pyplot()
    c = result.curve()
    f_hz = c.w_rad_s / (2.0 * math.pi)
    fig, (ax, ax_m) = plt.subplots(2, 1, figsize=(9.0, 7.0), sharex=True)
    try:
        ax.semilogx(f_hz, c.re_z, color="C0", label="Re Z(jw)")
        ax.axhline(0.0, color="0.4", lw=0.8)
        for k, (lo, hi) in enumerate(result.bands_rad_s):
            top = hi if math.isfinite(hi) else c.w_rad_s[-1]
            for a in (ax, ax_m):
                a.axvspan(max(lo, c.w_rad_s[0]) / (2 * math.pi), top / (2 * math.pi), color="C3", alpha=0.2,
                          label="Re Z < 0 (not passive)" if k == 0 and a is ax else None)
        if 0.0 < result.w_min_rad_s < math.inf:
            fm = result.w_min_rad_s / (2.0 * math.pi)
            ax.plot(fm, result.min_re_z, "o", color="C3")
            ax.annotate(f"min Re Z = {result.min_re_z:.4g} N m s/rad\nat {fm:.4g} Hz", (fm, result.min_re_z),
                        textcoords="offset points", xytext=(10, -24), fontsize="small", color="C3")
        span = float(np.nanpercentile(np.abs(c.re_z), 98)) or 1.0
        ax.set_ylim(min(-0.1 * span, 1.2 * min(result.min_re_z, 0.0)), 1.2 * span)
        ax.set_ylabel("Re Z [N m s/rad]")
        verdict = "PASSIVE: stable with every passive environment" if result.passive else \
            "NOT passive" + ("" if result.locked_stable else " (locked loop unstable)")
        ax.set_title(f"{result.title()}\n{verdict}", fontsize="medium")
        ax.legend(loc="best", fontsize="small")
        ax_m.loglog(f_hz, c.abs_z, color="C1", label="|Z(jw)|")
        ax_m.set_ylabel("|Z| [N m s/rad]")
        ax_m.set_xlabel("frequency [Hz]")
        ax_m.legend(loc="best", fontsize="small")
        return save_figure(fig, path)
    finally:
        plt.close(fig)
