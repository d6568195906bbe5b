"""A controller the format cannot describe (format kind ``other``): nonlinear, adaptive, learned, code.

It carries a name only. Tools that need its equations (margins, tuning, simulation, export)
say so in one line and stop; tools that need only the log (checking, identification,
diagnosis, benchmarking recorded runs) go on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from ..errors import ParameterError
from ..lti import RationalTF
from .base import Controller, DiscreteLaw

__all__ = ["OtherController"]


@dataclass(frozen=True, slots=True, kw_only=True)
class OtherController(Controller):
    """A force controller known by name only (format kind ``other``).

    Parameters
    ----------
    name : str
        Free text naming it (e.g. ``"admittance, lab build 3"``).

    Examples
    --------
    >>> OtherController(name="energy tank").spelling()
    'other:energy tank'
    """

    kind: ClassVar[str] = "other"
    keys: ClassVar[tuple[str, ...]] = ("name",)
    required: ClassVar[tuple[str, ...]] = ("name",)
    has_equations: ClassVar[bool] = False

    name: str

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ParameterError(f"[controller] other: name must be a non-empty string, got {self.name!r:.60}",
                                 name="name", value=self.name)
        if len(self.name) > 200 or any(ch in self.name for ch in "\n\r\x00"):
            raise ParameterError("[controller] other: name must be one line of at most 200 characters",
                                 name="name", value=self.name[:60])

    @classmethod
    def parse_fields(cls, positional: list[str], options: Any, owner: str) -> dict[str, Any]:
        """``other:NAME`` (the name may hold colons)."""
        return {"name": ":".join([*positional, *(f"{k}={v}" for k, v in dict(options).items())])}

    def no_equations(self, what: str = "this analysis") -> ParameterError:
        """The one-line refusal for a tool that needs the controller's equations.

        Parameters
        ----------
        what : str
            The tool (``"margins"``).

        Returns
        -------
        ParameterError
            To raise.
        """
        return ParameterError(f"controller 'other' ({self.name}) has no equations in the format: {what} needs a "
                              "pd, pid, tf or discrete controller", name="controller", value=self.name)

    def feedback_tf(self) -> RationalTF:
        """Refused (no equations)."""
        raise self.no_equations("the loop analysis")

    def reference_tf(self) -> RationalTF:
        """Refused (no equations)."""
        raise self.no_equations("the loop analysis")

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """Refused (no equations)."""
        raise self.no_equations("running it")

    def spelling(self) -> str:
        """``other:NAME``."""
        return f"other:{self.name}"

    @property
    def label(self) -> str:
        """``other (NAME)``."""
        return f"other ({self.name})"
