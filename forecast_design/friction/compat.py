"""Deprecated friction entry points, kept for one release: use identify, validate and friction_log."""

from __future__ import annotations

from typing import Any

import numpy as np

from .identify import FrictionFit, FrictionValidation, identify, validate
from .source import friction_log
from .terms import FrictionModel

__all__ = ["fit_friction_experiment", "validate_experiment", "log_arrays"]


def fit_friction_experiment(experiment: Any, model: FrictionModel | str = "extended-sfm", *,
                            harmonics: int | None = None, offset: bool = False,
                            estimate_inertia: bool = False, **kwargs: Any) -> FrictionFit:
    """Deprecated alias of :func:`identify` on an experiment (no hold-out unless asked, as before).

    Parameters
    ----------
    experiment : Experiment
        The log.
    model : FrictionModel or str
        As in :func:`identify`.
    harmonics, offset, estimate_inertia
        As in :func:`identify`.
    **kwargs
        As in :func:`identify`; ``holdout`` defaults to 0.

    Returns
    -------
    FrictionFit
        ``identify(experiment, model, holdout=0.0, ...)``.
    """
    kwargs.setdefault("holdout", 0.0)
    kwargs.setdefault("selection", "auto")
    return identify(experiment, model, harmonics=harmonics, offset=offset, estimate_inertia=estimate_inertia,
                    **kwargs)


def validate_experiment(fit: FrictionFit, experiment: Any) -> FrictionValidation:
    """Deprecated alias of :func:`validate` on an experiment.

    Parameters
    ----------
    fit : FrictionFit
        The fit to test.
    experiment : Experiment
        The second log.

    Returns
    -------
    FrictionValidation
        ``validate(fit, experiment)``.
    """
    return validate(fit, experiment)


def log_arrays(log: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, float | None]:
    """Deprecated: ``(t, position, force, inertia)`` of :func:`friction_log`.

    Parameters
    ----------
    log : Experiment or AxisLog
        The log.

    Returns
    -------
    tuple
        Time [s], position [rad or m], explained force [N m or N], nominal inertia or None.
    """
    data = friction_log(log)
    return data.t, data.position, data.force, data.inertia
