"""Which samples a static friction fit uses: stops and reversals are left out (IDIM practice).

A static friction law ``F(theta', theta)`` says nothing about a motor that
sticks: while the speed is zero the force is whatever the rest of the
system applies, anywhere in ``[-F_s, F_s]``, and the model's ``sign(0)``
column cannot follow it. Around every reversal the identification filters
smear the friction jump: the acceleration ``theta''`` subtracted from the
force comes from a zero-phase low-pass of the position, so the measured
friction is a smoothed step while the regressor ``sign(theta')`` is a sharp
one. Both mismatches are systematic and bias a least-squares fit (the
Coulomb level low, viscous high, the angle harmonics absorb whatever torque
held the stuck motor). Standard inverse-dynamic identification excludes
these samples; the rule here is:

1. **Speed threshold.** A raw sample is *slow* when the filtered speed is
   below ``speed_factor`` x the encoder's speed resolution through the
   derivative filter (:func:`forecast_design.plausibility.speed_resolution`,
   ``encoder_step x position_cutoff_hz``: one count per filter window; default
   factor 2, the same floor :func:`forecast_design.plausibility.friction_bound`
   puts under a Stribeck velocity). Below it the sign of the filtered speed is
   quantisation noise. (One count per *sample*, ``encoder_step x rate_hz``,
   was used before: ten times coarser, it called a 16-bit encoder's motor
   stopped below 0.38 rad/s and dropped 46 % of a sliding log.)
2. **Reversals.** A raw sample where the filtered speed changes sign is an
   event too (a fast reversal can step over the slow band).
3. **Window.** Every sample closer than ``window`` raw samples to an event
   is excluded, with ``window`` the filters' settling time from
   :func:`~forecast_design.friction.derivatives.settling_samples`: the
   zero-phase Butterworth's impulse-response half-width at the position
   cut-off (+2 for the central differences; 20 samples at the default
   ``rate/10``) plus, with parallel decimation, the decimation low-pass's
   half-width (148 samples at R = 10), which spreads the stop's mismatch into
   the decimated samples around it. With the speed threshold at the
   filter's resolution (rule 1) the second half-width is needed: without it
   16 independent extended-SFM logs were biased by 5 standard errors (viscous
   +8e-6, Coulomb -2.5e-5 of 0.3), with it by 0.1-0.3, for 2.7 % fewer samples.

The fit keeps the decimated samples whose raw sample survives, and records
how many (``n_samples_used``). The rule applies to the static models
(``sfm``, ``extended-sfm``, ``asymmetric``, ``position-friction``,
``stribeck``); LuGre is dynamic and explains presliding at the stops, so it
keeps every sample and is checked for plausibility instead.

When it applies (``mode``):

``"auto"`` (default)
    when the motor *stops*: at least ``stop_fraction`` (0.5 %) of the raw
    samples are slow. That is where the bias lives (sticking samples: 2 %
    on the Coulomb level of a log that sticks 7 % of the time). A log that
    only reverses without stopping loses less than 0.1 % to the smeared
    reversals, below what a real log's model error moves, and is fitted
    whole. The EMPS benchmark (0.08 % slow samples) is therefore fitted
    exactly as its published IDIM reference.
``"on"``
    always.
``"off"``
    never: plain IDIM on every sample (CLI ``--select-samples off``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..plausibility import speed_resolution
from .derivatives import FilterSettings, settling_samples

__all__ = ["SampleSelection", "SelectionResult", "SELECTION_MODES", "select_samples", "encoder_step",
           "resolve_selection"]

#: When the rule applies: see the module docstring.
SELECTION_MODES = ("auto", "on", "off")


@dataclass(frozen=True, slots=True, kw_only=True)
class SampleSelection:
    """The rule that leaves stops and reversals out of a static friction fit.

    Parameters
    ----------
    mode : str
        ``"auto"`` (apply when the log stops), ``"on"`` or ``"off"`` (see the
        module docstring).
    speed_factor : float
        Slow-sample threshold in units of the encoder speed resolution
        ``encoder_step x position_cutoff_hz`` [-], default 2.
    window_samples : int or None
        Raw samples excluded on each side of a stop or reversal; default (None)
        the filters' settling time, derivative and decimation (see the module docstring).
    stop_fraction : float
        ``"auto"``: fraction of slow raw samples from which the rule applies [-].
    min_fraction : float
        Smallest fraction of the decimated samples the fit must keep [-];
        below it the fit raises IdentifiabilityError (the log hardly slides).
    """

    mode: str = "auto"
    speed_factor: float = 2.0
    window_samples: int | None = None
    stop_fraction: float = 0.005
    min_fraction: float = 0.05

    def __post_init__(self) -> None:
        if self.mode not in SELECTION_MODES:
            raise ParameterError(f"selection mode must be one of {', '.join(SELECTION_MODES)}, got {self.mode!r}",
                                 name="selection", value=self.mode)
        if not 0.0 <= self.stop_fraction <= 1.0:
            raise ParameterError(f"stop_fraction must lie in [0, 1], got {self.stop_fraction!r}",
                                 name="stop_fraction", value=self.stop_fraction)
        if not (np.isfinite(self.speed_factor) and self.speed_factor >= 0):
            raise ParameterError(f"speed_factor must be >= 0, got {self.speed_factor!r}", name="speed_factor",
                                 value=self.speed_factor)
        w = self.window_samples
        if w is not None and (isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 0):
            raise ParameterError(f"window_samples must be an integer >= 0 or None, got {w!r}",
                                 name="window_samples", value=w)
        if not 0.0 <= self.min_fraction < 1.0:
            raise ParameterError(f"min_fraction must lie in [0, 1), got {self.min_fraction!r}",
                                 name="min_fraction", value=self.min_fraction)


@dataclass(frozen=True, slots=True, kw_only=True)
class SelectionResult:
    """What the rule did on one log.

    Parameters
    ----------
    rule : SampleSelection
        The rule.
    applied : bool
        Whether samples were excluded by the rule.
    reason : str
        Why not, when not applied (empty otherwise).
    speed_threshold : float
        Slow-sample threshold [rad/s] (or [m/s]).
    window_samples : int
        Raw samples excluded on each side of an event [-].
    n_events : int
        Stops and reversals found (runs of event samples) [-].
    slow_fraction : float
        Fraction of raw samples below the speed threshold [-].
    n_used, n_total : int
        Decimated samples kept and available [-].
    """

    rule: SampleSelection
    applied: bool
    reason: str = ""
    speed_threshold: float = 0.0
    window_samples: int = 0
    n_events: int = 0
    slow_fraction: float = 0.0
    n_used: int = 0
    n_total: int = 0

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        out: dict[str, Any] = {"mode": self.rule.mode, "applied": self.applied,
                               "speed_threshold": self.speed_threshold, "window_samples": self.window_samples,
                               "n_events": self.n_events, "slow_fraction": self.slow_fraction,
                               "n_used": self.n_used, "n_total": self.n_total}
        if self.reason:
            out["reason"] = self.reason
        return out


def encoder_step(position: np.ndarray, floor: float = 0.0) -> float:
    """Position resolution of a log [rad] (or [m]), not below `floor`.

    A quantised log moves by whole counts: its non-zero steps are integer
    multiples of the smallest one, which is then the resolution. A log whose
    steps are not (an unquantised simulation, or one that never moves by a
    single count) has no visible resolution; its floor is then the float
    resolution of the position, 8 eps max(1, |position|).
    """
    x = np.asarray(position, dtype=float)
    steps = np.abs(np.diff(x))
    steps = steps[steps > 0]
    fine = 8.0 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(x)))) if x.size else 0.0
    if not steps.size:
        return max(fine, float(floor))
    q = float(steps.min())
    ratio = steps / q
    quantised = float(np.mean(np.abs(ratio - np.round(ratio)) < 0.01)) > 0.9
    return max(q if quantised else fine, float(floor))


def _dilate(mask: np.ndarray, w: int) -> np.ndarray:
    """True within `w` samples of any True sample (O(n), cumulative sums)."""
    if w == 0 or not mask.any():
        return mask.copy()
    c = np.concatenate([[0], np.cumsum(mask, dtype=np.int64)])
    n = mask.size
    idx = np.arange(n)
    hi = np.minimum(idx + w + 1, n)
    lo = np.maximum(idx - w, 0)
    return (c[hi] - c[lo]) > 0


def resolve_selection(selection: "SampleSelection | str | bool | None") -> SampleSelection:
    """A :class:`SampleSelection` from the shorthands ``"auto"``/``"on"``/``"off"``, True/False, None (off)."""
    if isinstance(selection, SampleSelection):
        return selection
    if selection is None or selection is False:
        return SampleSelection(mode="off")
    if selection is True:
        return SampleSelection(mode="on")
    if isinstance(selection, str):
        return SampleSelection(mode=selection)
    raise ParameterError(f"selection must be a SampleSelection or one of {', '.join(SELECTION_MODES)}, "
                         f"got {selection!r}", name="selection", value=selection)


def select_samples(velocity: np.ndarray, settings: FilterSettings, step: float,
                   rule: SampleSelection) -> tuple[np.ndarray, SelectionResult]:
    """Raw-rate mask of the samples a static fit may use.

    Parameters
    ----------
    velocity : ndarray, shape (n,)
        Filtered speed at the raw rate [rad/s].
    settings : FilterSettings
        The identification filters (window and rate).
    step : float
        Encoder resolution [rad] (or [m]).
    rule : SampleSelection
        The rule (its ``mode`` decides whether the mask excludes anything).

    Returns
    -------
    keep : ndarray of bool, shape (n,)
        True for the samples the fit uses.
    result : SelectionResult
        Threshold, window, event count and whether the rule applied
        (``n_used``/``n_total`` are filled in by the caller after decimation).
    """
    v = np.asarray(velocity, dtype=float)
    # the float floor catches a numerically constant (stuck) unquantised position
    resolution = speed_resolution(step, settings.rate_hz, settings.position_cutoff_hz)
    threshold = max(rule.speed_factor * resolution, 1e-9 * float(np.max(np.abs(v), initial=0.0)))
    window = sum(settling_samples(settings)) if rule.window_samples is None else int(rule.window_samples)
    slow = np.abs(v) <= threshold
    slow_fraction = float(np.mean(slow)) if v.size else 0.0
    event = slow.copy()
    flip = v[1:] * v[:-1] < 0
    event[1:] |= flip
    event[:-1] |= flip
    n_events = int(np.count_nonzero(event[1:] & ~event[:-1]) + int(event[0])) if v.size else 0
    info = dict(rule=rule, speed_threshold=float(threshold), window_samples=window, n_events=n_events,
                slow_fraction=slow_fraction)
    if rule.mode == "off":
        return np.ones(v.size, dtype=bool), SelectionResult(applied=False, reason="switched off", **info)
    if rule.mode == "auto" and slow_fraction < rule.stop_fraction:
        return np.ones(v.size, dtype=bool), SelectionResult(
            applied=False, reason=f"auto: the log hardly stops ({100 * slow_fraction:.2g} % of the samples "
                                  f"below {threshold:.3g}, the rule applies from {100 * rule.stop_fraction:g} %)",
            **info)
    return ~_dilate(event, window), SelectionResult(applied=True, **info)
