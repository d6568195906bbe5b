"""What a friction fit explains, from whatever log it is given: one adapter, one type.

An SEA experiment and a plain axis log describe the same thing differently. An
experiment explains ``tau_frc + J_m theta'' = zoh(tau_m) - tau_s`` with a nominal
motor inertia and the plausibility scales of its sensors; an axis log gives a
force and a position and no inertia. :func:`friction_log` turns either into a
:class:`FrictionLog`, the one input of :func:`~forecast_design.friction.identify`,
:func:`~forecast_design.friction.identify.validate` and
:func:`~forecast_design.friction.identify.fit_data`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..experiment import Experiment
from ..plausibility import LogScales, log_scales
from ..limits import check_signal
from .logs import AxisLog

__all__ = ["FrictionLog", "experiment_scales", "friction_log", "zoh_align"]


@dataclass(frozen=True, slots=True, kw_only=True)
class FrictionLog:
    """The arrays a friction fit explains.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times [s].
    position : ndarray, shape (n,)
        Motor angle [rad] (or axis position [m]).
    force : ndarray, shape (n,)
        Force explained by inertia and friction [N m] (or [N]).
    inertia : float or None
        Nominal inertia [kg m^2] (or [kg]) whose ``inertia * acceleration`` is
        subtracted from `force`; None when the log carries none (it is then estimated).
    scales : LogScales or None
        The log's magnitudes for the plausibility checks (SEA experiments).
    source : str
        Where the log came from (file name or ``"arrays"``).
    """

    t: np.ndarray
    position: np.ndarray
    force: np.ndarray
    inertia: float | None = None
    scales: LogScales | None = None
    source: str = "arrays"


def zoh_align(force: np.ndarray) -> np.ndarray:
    """Average a zero-order-hold command over consecutive samples: ``(f[k-1] + f[k]) / 2`` (first kept).

    A command held over ``[t_k, t_k+1)`` acts on the central-difference
    acceleration at ``t_k`` (which spans ``[t_k-1, t_k+1]``) as the mean of
    the two commands around ``t_k``.

    Parameters
    ----------
    force : ndarray, shape (n,)
        The held command [N m] (or [N]).

    Returns
    -------
    ndarray, shape (n,)
        The aligned force.
    """
    f = np.array(force, dtype=float)
    if f.size > 1:
        f[1:] = 0.5 * (f[1:] + f[:-1])
    return f


def experiment_scales(experiment: Experiment) -> LogScales:
    """The plausibility scales of an SEA experiment (motor torque ``tau_m``, motor angle, spring deflection).

    The encoder step is the log's smallest angle step, not below the
    testbed's 2 pi / 2,000,000 rad (:func:`forecast_design.plausibility.log_scales`).

    Parameters
    ----------
    experiment : Experiment
        The log.

    Returns
    -------
    LogScales
        Its magnitudes, with the nominal ``J_m``.
    """
    sig = experiment.signals
    theta = np.asarray(sig.theta, dtype=float)
    return log_scales(torque=np.asarray(sig.tau_m, dtype=float), position=theta,
                      rate_hz=float(experiment.rate_hz), deflection=theta - np.asarray(sig.q, dtype=float),
                      J_m=float(experiment.design.testbed.J_m))


def friction_log(log: Any) -> FrictionLog:
    """The friction-fit view of a log.

    Parameters
    ----------
    log : Experiment, AxisLog or FrictionLog
        An SEA experiment explains ``zoh(tau_m) - tau_s`` [N m] with its nominal
        ``J_m`` (``tau_m`` is held over ``[t_k, t_k+1)`` by the format, hence
        :func:`zoh_align`; ``tau_s`` is measured at ``t_k``); an axis log explains
        its force with no nominal inertia.

    Returns
    -------
    FrictionLog
        The arrays, the nominal inertia and (for an experiment) the scales.

    Raises
    ------
    ParameterError
        For anything else (a path, a mapping...), naming what was given.
    """
    if isinstance(log, FrictionLog):
        return log
    if isinstance(log, Experiment):
        sig = log.signals
        # the reader always fills tau_s (derived as k (theta - q) when the file has no column)
        force = zoh_align(np.asarray(sig.tau_m, dtype=float)) - np.asarray(sig.tau_s, dtype=float)
        return FrictionLog(t=np.asarray(sig.t, dtype=float), position=np.asarray(sig.theta, dtype=float),
                           force=force, inertia=float(log.design.testbed.J_m), scales=experiment_scales(log),
                           source=str(log.source) if log.source is not None else "experiment")
    if isinstance(log, AxisLog):
        return FrictionLog(t=np.asarray(log.t), position=np.asarray(log.position), force=np.asarray(log.force),
                           source=log.source)
    raise ParameterError(
        f"a friction log must be an Experiment (load_experiment), an AxisLog (load_axis_csv) or a "
        f"FrictionLog, got {type(log).__name__}", name="log", value=type(log).__name__)


def _check_array(name: str, x: Any, n: int | None = None) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a numeric array: {exc}", name=name) from None
    if a.ndim != 1:
        raise ParameterError(f"{name} must be 1-D, got shape {a.shape}", name=name, value=a.shape)
    if n is not None and a.size != n:
        raise ParameterError(f"{name} has {a.size} samples but t has {n}", name=name, value=a.size)
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ParameterError(f"{name} contains NaN or inf at sample {bad[0]} ({bad.size} bad samples)",
                             name=name, value=int(bad[0]))
    if name in ("position", "force"):   # rad or m; N m or N
        check_signal(name, a, "angle_rad" if name == "position" else "torque_N_m")
    return a


def _rate_from_time(t: np.ndarray) -> float:
    dts = np.diff(t)
    if dts.size == 0:
        raise ParameterError("t needs at least two samples", name="t", value=t.size)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        raise ParameterError(f"t must be strictly increasing; t[{bad[0] + 1}] = {t[bad[0] + 1]!r} "
                             f"after t[{bad[0]}] = {t[bad[0]]!r}", name="t", value=int(bad[0] + 1))
    dt = (t[-1] - t[0]) / (t.size - 1)
    worst = int(np.argmax(np.abs(dts - dt)))
    if abs(dts[worst] - dt) > 0.01 * dt:
        raise ParameterError(f"t must be uniformly sampled (within 1 %); step {worst} is {dts[worst]!r} s, "
                             f"mean step {dt!r} s", name="t", value=worst)
    return 1.0 / dt
