"""Exception hierarchy of forecast_design; the CLI catches ForecastError only."""

from __future__ import annotations

from typing import Any

__all__ = [
    "ForecastError",
    "ExperimentFormatError",
    "ParameterError",
    "IdentifiabilityError",
    "SolverError",
    "ExportError",
    "OutputError",
    "EXIT_NOT_IDENTIFIABLE",
    "IllConditionedWarning",
]


class IllConditionedWarning(UserWarning):
    """A number its inputs do not determine in double precision: an ill-conditioned least-squares
    regressor (a friction fit), or polynomial roots whose side of the stability boundary the
    coefficients cannot tell (a sampled loop given as z-polynomials). The number is printed; it
    may be wrong, and the warning says so and names a better-conditioned route."""


class ForecastError(Exception):
    """Base class of every error the toolbox raises on purpose."""


class ExperimentFormatError(ForecastError, ValueError):
    """A malformed experiment file (TOML or CSV).

    Parameters
    ----------
    message : str
        One line: where, what, expected, got.
    path : str, optional
        The file at fault.
    key : str, optional
        The TOML key, CSV column or CSV line at fault.
    """

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None):
        super().__init__(message)
        self.path = path
        self.key = key


class ParameterError(ForecastError, ValueError):
    """A parameter outside its physical range or an unknown option.

    Parameters
    ----------
    message : str
        One line naming the parameter, the expected range and the value.
    name : str, optional
        Name of the parameter.
    value : object, optional
        The offending value.
    """

    def __init__(self, message: str, *, name: str | None = None, value: Any = None):
        super().__init__(message)
        self.name = name
        self.value = value


class IdentifiabilityError(ForecastError, ValueError):
    """A log that cannot identify the requested parameters (no motion, one direction, too little sliding).

    Not identifiable is an answer about the log, not bad input: the ``identify`` verb writes it
    as JSON and exits with its own code (3, :data:`forecast_design.errors.EXIT_NOT_IDENTIFIABLE`).

    Parameters
    ----------
    message : str
        What the log lacks (one line).
    parameters : tuple of str
        The parameters it cannot identify (empty: unspecified).
    reasons : tuple of str
        Short reasons, one per missing piece of information.
    """

    def __init__(self, message: str, *, parameters: tuple[str, ...] = (), reasons: tuple[str, ...] = ()):
        super().__init__(message)
        self.parameters = tuple(parameters)
        self.reasons = tuple(reasons) or (message,)


#: Exit code of a command whose answer is "not identifiable" (the log lacks the information) [-].
EXIT_NOT_IDENTIFIABLE = 3


class SolverError(ForecastError, RuntimeError):
    """A numerical solver (casadi/ipopt, cvxpy) did not converge.

    Parameters
    ----------
    message : str
        What failed.
    stats : dict, optional
        The solver's own statistics / return status.
    """

    def __init__(self, message: str, *, stats: dict | None = None):
        super().__init__(message)
        self.stats = stats or {}


class ExportError(ForecastError, RuntimeError):
    """Code generation or compilation of an exported controller failed."""


class OutputError(ForecastError, OSError):
    """An output file could not be written; the previous file, if any, is left intact.

    Parameters
    ----------
    message : str
        One line naming the user's path (never a temporary one) and the reason.
    path : str, optional
        The output path at fault.
    """

    def __init__(self, message: str, *, path: str | None = None):
        super().__init__(message)
        self.path = path
