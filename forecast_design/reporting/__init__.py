"""Reports people read: Markdown with plots and the machine-readable JSON beside it.

:func:`write_report` writes the sim-to-real gap diagnosis report (:mod:`.gap`).
"""

from .gap import write_report

__all__ = ["write_report"]
