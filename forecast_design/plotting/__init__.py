"""Plots (matplotlib, Agg backend, imported lazily inside the plotting functions)."""

from pathlib import Path


def save_figure(fig, path, *, dpi: int = 110) -> Path:
    """Lay out, write as PNG and close a matplotlib figure.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed afterwards, so loops of plots do not pile up).
    path : str or Path
        Output PNG file.
    dpi : int
        Resolution [dots per inch].

    Returns
    -------
    Path
        The file written.
    """
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        if fig.get_layout_engine() is None:   # keep a layout the plot chose (e.g. constrained)
            fig.tight_layout()
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
    return path
