"""One home for the plots' visual conventions: a colour per observer, a shade and line style per cutoff.

Every plot that shows observers (Fig. 6, the Q trade-off, ...) takes its colours from here, so
EA-FOB is the same green in every panel and every figure, and a cutoff keeps its line style.
"""

from __future__ import annotations

from typing import Sequence

__all__ = ["OBSERVER_COLOURS", "OBSERVER_LABELS", "OBSERVER_MARKERS", "PLANT_KINDS", "observer_colour", "observer_label", "cutoff_style",
           "plant_style"]

# Base colour per compensator kind (matplotlib's tab10, colour-blind friendlier than pure hues);
# the plant alone is black.
OBSERVER_COLOURS = {
    "none": "#000000",
    "ea-fob": "#2ca02c",      # green
    "lo-dob": "#1f77b4",      # blue
    "ld-dob": "#d62728",      # red
    "motor-fob": "#9467bd",   # purple
    "sfm": "#ff7f0e",         # orange
    "extended-sfm": "#8c564b",
}
OBSERVER_LABELS = {"none": "plant", "ea-fob": "EA-FOB", "lo-dob": "LO-DOB", "ld-dob": "LD-DOB",
                   "motor-fob": "motor FOB", "sfm": "SFM", "extended-sfm": "extended SFM"}
# A marker shape per observer: Fig. 6 puts each disk's markers at its own places along its arc, so
# disks of (nearly) the same size, whose arcs coincide, each stay visible.
OBSERVER_MARKERS = {"ea-fob": "o", "lo-dob": "s", "ld-dob": "^", "motor-fob": "D", "sfm": "v", "extended-sfm": "P"}
_LINESTYLES = ("-", "--", ":", "-.")    # highest cutoff solid, then dashed, dotted


def observer_label(kind: str) -> str:
    """Display name of a compensator kind (``'ea-fob'`` -> ``'EA-FOB'``)."""
    return OBSERVER_LABELS.get(kind, kind)


def observer_colour(kind: str, shade: float = 1.0) -> tuple[float, float, float]:
    """RGB colour of an observer; ``shade`` in (0, 1] lightens towards white (1: the base colour).

    Parameters
    ----------
    kind : str
        Compensator kind (unknown kinds are grey).
    shade : float
        1 gives the base colour, smaller values mix it with white [-].

    Returns
    -------
    (float, float, float)
        RGB in [0, 1].
    """
    from matplotlib.colors import to_rgb

    base = to_rgb(OBSERVER_COLOURS.get(kind, "#7f7f7f"))
    s = min(max(float(shade), 0.0), 1.0)
    return tuple(1.0 - s * (1.0 - c) for c in base)


def cutoff_style(w_q_hz: float | None, cutoffs: Sequence[float]) -> tuple[float, str]:
    """Shade and line style of one cutoff among ``cutoffs``: darker and more solid for higher cutoffs.

    As in the paper's Fig. 6, higher Q cutoffs are darker ("the disappearance of the dark red
    disk" is LD-DOB at 10 Hz). The line style (dotted, dashed, solid, dash-dot) tells cutoffs
    apart where edges coincide or colours are hard to see.

    Parameters
    ----------
    w_q_hz : float or None
        The cutoff [Hz] (None: the plant alone).
    cutoffs : sequence of float
        All cutoffs shown [Hz], sorted ascending.

    Returns
    -------
    (float, str)
        Shade for :func:`observer_colour` and a matplotlib line style.
    """
    if w_q_hz is None or w_q_hz not in cutoffs:
        return 1.0, "-"
    n = len(cutoffs)
    i = list(cutoffs).index(w_q_hz)
    shade = 0.6 + 0.4 * (i + 1) / n
    return shade, _LINESTYLES[(n - 1 - i) % len(_LINESTYLES)]


# The force plant and the observers' nominal plants (the ``tf`` verb): the observer's colour, and a
# line style and width of their own so curves that coincide (EA = LO when locked) stay visible.
PLANT_KINDS = ("P", "EA", "LO", "LD")
_PLANT_LOOKS = {
    "P": ("none", "-", 4.0, 0.35, r"$P$: true plant (eq. 2)"),
    "EA": ("ea-fob", "-", 1.6, 1.0, r"$P_n^{EA}$: EA-FOB nominal (eq. 5)"),
    "LO": ("lo-dob", (0, (5, 2)), 1.6, 1.0, r"$P_n^{LO}$: LO-DOB nominal (eq. 6)"),
    "LD": ("ld-dob", (0, (1, 1.5)), 2.0, 1.0, r"$P_n^{LD}$: LD-DOB nominal (eq. 8)"),
}


def plant_style(kind: str) -> dict:
    """Line keywords (colour, style, width, alpha, z-order, label) of one plant of the ``tf`` verb.

    Parameters
    ----------
    kind : str
        ``"P"`` (the true plant: thick and pale, underneath) or a nominal plant ``"EA"``,
        ``"LO"``, ``"LD"`` (its observer's colour, a line style of its own, on top).

    Returns
    -------
    dict
        Keywords for ``Axes.plot``.

    Raises
    ------
    KeyError
        If ``kind`` is not one of :data:`PLANT_KINDS`.
    """
    observer, ls, lw, alpha, label = _PLANT_LOOKS[kind]
    return {"color": observer_colour(observer), "linestyle": ls, "linewidth": lw, "alpha": alpha,
            "zorder": 2.0 if kind == "P" else 3.0 + PLANT_KINDS.index(kind) * 0.1, "label": label}
