"""Example force controllers written as code, to copy and adapt (docs/controllers-as-code.md).

``gain_scheduled_pid.py`` and ``gain_scheduled_pid.c`` are the same controller in Python and
in C: a PID on the force error whose proportional gain grows with the size of the force
reference, with a filtered derivative and an integrator that stops at the output limit.
Spell them ``forecast_design.controllers.examples.gain_scheduled_pid:GainScheduledPID`` and
``example_path("gain_scheduled_pid.c")``'s path.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["EXAMPLES", "example_path"]

#: The example files.
EXAMPLES = ("gain_scheduled_pid.py", "gain_scheduled_pid.c")


def example_path(name: str) -> Path:
    """The installed path of an example file (one of :data:`EXAMPLES`).

    Parameters
    ----------
    name : str
        File name.

    Returns
    -------
    Path
        Where it is installed (read it, or copy it to start your own).

    Examples
    --------
    >>> example_path("gain_scheduled_pid.c").name
    'gain_scheduled_pid.c'
    """
    if name not in EXAMPLES:
        raise ValueError(f"no example {name!r}; there are {', '.join(EXAMPLES)}")
    return Path(str(resources.files(__name__).joinpath(name)))
