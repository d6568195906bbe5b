"""Documented ranges of what a user may give: physical parameters, sizes of a computation, logged signals.

Every check that refuses an input in one line reads its range from here (:data:`PHYSICAL_RANGES`,
:data:`COMPUTATION_LIMITS`, :data:`SIGNAL_LIMITS`); results pass :func:`require_no_nan` before a
verb exits 0. Fitted numbers are judged by :mod:`forecast_design.plausibility` instead.
"""

from __future__ import annotations

import math
import numbers
from typing import Any, Mapping

import numpy as np

from .errors import ParameterError, SolverError

__all__ = [
    "first_beyond",
    "check_signal",
    "SIGNAL_LIMITS",
    "PHYSICAL_RANGES",
    "COMPUTATION_LIMITS",
    "check_physical",
    "check_limit",
    "check_number",
    "check_below_nyquist",
    "limit_of",
    "require_no_nan",
]

# forecast_design.plausibility judges *fitted* numbers against a log. The ranges here bound what a user may
# *give*: the nominal model's physical parameters and the sizes of a computation. They are wide (about
# six decades and more around the Forecast testbed's values of Table 1 and the presets; a nearly
# held output may take J_e = 1e9), so any real SEA passes;
# what they reject are the values that give NaN/inf or hang (J_m = 1e308, k = 1e300, w_q = 1e-300 Hz,
# 1e8 substeps). One home: params.py (Testbed, Environment, Compensator), the scenario loader, the
# runtime and the CLI read them from here.

#: Plausible physical parameters: name -> (lowest, highest, unit). ``J_m`` and ``k`` must be > 0, the
#: rest >= 0; ``w_q_hz`` is a Q-filter cutoff, ``rate_hz`` a control/sampling rate.
PHYSICAL_RANGES: Mapping[str, tuple[float, float, str]] = {
    "J_m": (1e-6, 1e6, "kg m^2"),
    "d_m": (0.0, 1e6, "N m s/rad"),
    "k": (1e-3, 1e9, "N m/rad"),
    "J_e": (0.0, 1e10, "kg m^2"),
    "d_e": (0.0, 1e10, "N m s/rad"),
    "k_e": (0.0, 1e10, "N m/rad"),
    "J_l": (0.0, 1e6, "kg m^2"),
    "d_l": (0.0, 1e6, "N m s/rad"),
    "w_q_hz": (1e-3, 1e5, "Hz"),
    "rate_hz": (1.0, 1e6, "Hz"),
    "P": (0.0, 1e4, "N m/N m"),
    "D": (0.0, 1e3, "N m s/N m"),
    "I": (0.0, 1e6, "1/s"),
    "T_f": (0.0, 10.0, "s"),
    "T_t": (1e-6, 1e3, "s"),
    "feedforward": (-1e3, 1e3, "-"),
    "u_min": (-1e6, 1e6, "N m"),
    "u_max": (-1e6, 1e6, "N m"),
    "prewarp_hz": (1e-3, 1e6, "Hz"),
}

#: Sizes of a computation a user may ask for: name -> (lowest, highest, what it bounds).
#: Largest magnitude a logged signal may take: an angle [rad] (about 160,000 revolutions) and a
#: torque [N m] beyond these is a diverged simulation or a corrupt file, not a measurement.
SIGNAL_LIMITS: Mapping[str, float] = {"angle_rad": 1e6, "torque_N_m": 1e6}


def first_beyond(values: np.ndarray, limit: float) -> int | None:
    """Index of the first sample whose magnitude exceeds `limit` or is not finite, or None.

    Parameters
    ----------
    values : ndarray
        Samples (any unit).
    limit : float
        Largest magnitude allowed (same unit).

    Returns
    -------
    int or None
    """
    v = np.asarray(values, dtype=float)
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(~(np.abs(v) <= limit))
    return int(bad[0]) if bad.size else None


def check_signal(name: str, values: np.ndarray, kind: str) -> None:
    """Refuse a signal beyond :data:`SIGNAL_LIMITS` in one line naming it and the sample.

    Parameters
    ----------
    name : str
        The signal's name (for the message).
    values : ndarray
        Its samples.
    kind : str
        ``angle_rad`` or ``torque_N_m`` (the key of :data:`SIGNAL_LIMITS`).

    Raises
    ------
    ParameterError
        At the first sample beyond the limit.
    """
    limit = SIGNAL_LIMITS[kind]
    at = first_beyond(values, limit)
    if at is not None:
        raise ParameterError(f"{name} reaches {float(np.asarray(values)[at]):.3g} at sample {at}, beyond {limit:g}: "
                             "a diverged run or a corrupt log, not a measurement", name=name, value=int(at))


COMPUTATION_LIMITS: Mapping[str, tuple[int, int, str]] = {
    "delay_samples": (0, 100, "computation delay of the sampled loop [samples] (50 ms at 2 kHz)"),
    "q_order": (1, 8, "order of the Q filter"),
    "random_environments": (1, 1000, "environments of random:N"),
    "substeps": (1, 1000, "RK4 substeps per control period"),
    "harmonics": (1, 64, "angle harmonics of a friction term (2 regressor columns each)"),
    "simulation_samples": (1, 10_000_000, "samples of one simulation (duration_s x rate_hz)"),
    "runs": (1, 100_000, "simulated runs of one benchmark (bench-gap logs, benchmark cells x repetitions)"),
    "seed": (0, 2**63 - 1, "random seed"),
    "repetitions": (1, 10_000, "repetitions of a scenario's [variability] or of a benchmark cell"),
    "batch_samples": (1, 10_000_000, "simulated samples of one batch (runs x duration_s x rate_hz), "
                                     "about 280 B each"),
    "environments": (1, 10_000, "environments of one set (the points of every grid of a file, lists, presets)"),
    "log_samples_check": (1, 2**23, "samples of a log check reads (70 min at 2 kHz), about 300 B each"),
    "log_samples_identify": (1, 2**22, "samples of a log identify reads (35 min at 2 kHz), about 270 B each"),
    "log_samples_diagnose": (1, 2**22, "samples of a log diagnose reads (35 min at 2 kHz), about 360 B each"),
    "log_samples_benchmark": (1, 2**20, "samples of one recorded run benchmark --runs reads (8.7 min at 2 kHz)"),
}


def check_physical(owner: str, name: str, value: float) -> float:
    """Check a finite number against :data:`PHYSICAL_RANGES`; ParameterError naming it and the range.

    Parameters
    ----------
    owner : str
        Where the number lives, e.g. ``"[testbed]"`` (goes first in the message).
    name : str
        A key of :data:`PHYSICAL_RANGES`.
    value : float
        The candidate (already known to be a finite number).

    Returns
    -------
    float
        ``value``.
    """
    lo, hi, unit = PHYSICAL_RANGES[name]
    if not lo <= value <= hi:
        raise ParameterError(f"{owner} {name} = {value!r} is outside its plausible range [{lo:g}, {hi:g}] {unit}",
                             name=name, value=value)
    return value


def check_below_nyquist(name: str, frequency_hz: float, rate_hz: float) -> float:
    """Refuse a filter frequency a discretisation at ``rate_hz`` cannot represent (at or above Nyquist).

    Tustin folds a cutoff above ``rate_hz / 2`` onto ``(2/T) atan(w T / 2)`` below it, ZOH and
    backward Euler place its poles near z = 0 or -1: the discrete filter is no longer the one
    named, and the loop that runs it is not the one analysed.

    Parameters
    ----------
    name : str
        How the message names the frequency (e.g. ``"w_q_hz (the Q cutoff)"``).
    frequency_hz : float
        The filter's frequency [Hz].
    rate_hz : float
        The sampling rate [Hz].

    Returns
    -------
    float
        ``frequency_hz``.

    Raises
    ------
    ParameterError
        One line naming the frequency, the Nyquist frequency and the rate.
    """
    if math.isfinite(frequency_hz) and math.isfinite(rate_hz) and frequency_hz >= rate_hz / 2.0:
        raise ParameterError(f"{name} = {frequency_hz:g} Hz is at or above the Nyquist frequency {rate_hz / 2.0:g} Hz "
                             f"of rate_hz = {rate_hz:g} Hz: a discrete filter cannot represent it; choose a value "
                             f"below {rate_hz / 2.0:g} Hz", name=name.split()[0], value=frequency_hz)
    return frequency_hz


def limit_of(name: str) -> int:
    """The largest value :data:`COMPUTATION_LIMITS` allows for ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`COMPUTATION_LIMITS`.
    """
    return COMPUTATION_LIMITS[name][1]


def check_limit(option: str, name: str, value: Any) -> int:
    """Check an integer size against :data:`COMPUTATION_LIMITS`; ParameterError naming ``option``.

    Parameters
    ----------
    option : str
        How the user wrote it (``"--delay-samples"``, ``"[simulation] substeps"``).
    name : str
        A key of :data:`COMPUTATION_LIMITS`.
    value : int
        The candidate.

    Returns
    -------
    int
        ``value`` as an int.
    """
    lo, hi, what = COMPUTATION_LIMITS[name]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= int(value) <= hi:
        raise ParameterError(f"{option} must be an integer in [{lo}, {hi}] ({what}), got {value!r}",
                             name=name, value=value)
    return int(value)


def require_no_nan(result: Any, what: str) -> Any:
    """Refuse a result holding a NaN anywhere (nested mappings, sequences, numpy arrays).

    An infinite value can be an answer (a gain margin of +inf dB); a NaN never is. Every verb
    that prints numbers passes its result through this before exiting 0.

    Parameters
    ----------
    result : object
        The result's JSON mapping (or any nesting of mappings, sequences, numbers, arrays).
    what : str
        The command or function, for the message.

    Returns
    -------
    object
        ``result`` unchanged.

    Raises
    ------
    SolverError
        One line naming the first key path that holds a NaN.
    """
    def walk(obj: Any, path: str) -> str | None:
        if isinstance(obj, Mapping):
            items: Iterable = ((f"{path}.{k}" if path else str(k), v) for k, v in obj.items())
        elif isinstance(obj, (list, tuple)):
            items = ((f"{path}[{i}]", v) for i, v in enumerate(obj))
        elif isinstance(obj, np.ndarray):
            if obj.dtype.kind in "fc" and np.isnan(obj).any():
                return path or "result"
            return None
        elif isinstance(obj, (float, complex, np.floating, np.complexfloating)):
            return (path or "result") if (obj != obj) else None
        else:
            return None
        for sub, value in items:
            found = walk(value, sub)
            if found:
                return found
        return None

    found = walk(result, "")
    if found:
        raise SolverError(f"{what}: the result holds NaN at {found}: the parameters are outside what the "
                          "models evaluate reliably (see the plausible ranges in docs/reliability.md)")
    return result


def check_number(owner: str, name: str, value: Any, *, positive: bool = False, nonneg: bool = True) -> float:
    """Validate one physical number at the boundary; raise ParameterError naming it.

    Parameters
    ----------
    owner : str
        Where the number lives, e.g. ``"[testbed]"`` or ``"stiction"``.
    name : str
        Its name.
    value : object
        The candidate (bool and non-numbers are rejected).
    positive : bool
        Require > 0.
    nonneg : bool
        Require >= 0 (ignored when ``positive``).

    Returns
    -------
    float
        The value as a float.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):   # numpy scalars are Real
        raise ParameterError(f"{owner} {name} must be a number, got {value!r}", name=name, value=value)
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{owner} {name} must be finite, got {value!r}", name=name, value=value)
    if positive and value <= 0.0:
        raise ParameterError(f"{owner} {name} must be > 0, got {value!r}", name=name, value=value)
    if nonneg and not positive and value < 0.0:
        raise ParameterError(f"{owner} {name} must be >= 0, got {value!r}", name=name, value=value)
    return value
