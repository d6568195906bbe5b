"""Plots (matplotlib, Agg backend, imported lazily inside the plotting functions)."""

from pathlib import Path

from ..errors import ParameterError
from ..fileio import atomic_open


def write_figure(fig, path, *, dpi: int = 110) -> Path:
    """Write a matplotlib figure atomically (the format from the file's suffix), keep it open.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or Path
        Output file; ``.png`` (or another format matplotlib writes: ``.pdf``, ``.svg``...).
    dpi : int
        Resolution [dots per inch].

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ParameterError
        If matplotlib cannot write the suffix's format (nothing is written).
    OutputError
        If the file cannot be written; an old file of that name is left intact.
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".") or "png"
    supported = fig.canvas.get_supported_filetypes()
    if fmt not in supported:
        raise ParameterError(f"{path}: cannot draw a '.{fmt}' file; use one of "
                             f"{', '.join('.' + k for k in sorted(supported))}", name="plot", value=str(path))
    with atomic_open(path) as fh:
        fig.savefig(fh, dpi=dpi, format=fmt)
    return path


def _pyplot():
    """``matplotlib.pyplot`` on the Agg backend, imported on first use (the package itself imports no matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
        write_figure(fig, path, dpi=dpi)
    finally:
        plt.close(fig)
    return path
