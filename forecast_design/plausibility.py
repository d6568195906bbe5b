"""Physical plausibility of fitted numbers: the one place that says when a number is *not identified*.

Every fitted parameter of the friction identification and of the gap
diagnosis passes through :func:`assess`, which gives it one of five statuses,
each defined by what a user may rely on:

``identified``
    *Use the number.* It is finite, inside its plausible range, not on a bound
    of the solver or search grid, it has a finite, positive standard deviation,
    and its 95 % interval is no wider than +-:data:`RELATIVE_PRECISION` (10 %) of
    the value: the number is known to within a tenth of itself, and the
    interval (which the identification checks on independent logs to cover
    the truth in >= 93 % of cases) says by how much more precisely. For a
    friction fit the standard deviation is the noise's (Newey-West) and the
    method's own error in quadrature: how far the estimate moves when the
    analysis is repeated at half the rate and at half the filter cut-off
    (:mod:`forecast_design.friction.method_error`); an interval narrower
    than the error the method makes would promise what it cannot hold.
``uncertain``
    *Use the interval, not the number.* The log pins the value only to an
    interval wider than +-10 % of it (the interval may include zero), or a
    check of the fit (a richer model the residual asks for, a sensor scale the
    log cannot separate) moves it by more than that interval. A friction number
    whose method's error could not be estimated (both repeated fits failed) is
    ``uncertain`` too, saying that its interval carries the noise only.
``at_bound``
    *Neither.* The estimate sits on a bound of the solver (a box constraint, the
    end of a search grid, a datasheet tolerance): the data pushed it there, so
    the true value may lie beyond and the number is not an estimate.
``implausible``
    *Neither.* Outside the range the log and the testbed allow (below).
``not_identifiable``
    *Nothing.* The log carries no information on it: its standard deviation is
    zero or not finite (a singular or near-singular problem; a zero standard
    deviation there is a failure of the covariance, never certainty), a
    direction of the regressor the excitation does not reach, or the fit as a
    whole is not identifiable (too little sliding).

Only ``identified`` numbers are reported as estimates; the others are flagged
(JSON ``status``, a CLI warning, a report caveat).

Plausible ranges are derived from the log (:class:`LogScales`) and the testbed:

========================  ==============================================================
quantity                  plausible range and why
========================  ==============================================================
friction levels           ``|F| <= 1.5 torque_max``: a friction torque larger than every
(Coulomb, static, offset, torque applied would never have let the motor move; 1.5 leaves
harmonic amplitudes)      room for inertial torques at reversals.
viscous coefficient       ``0 <= d <= 1.5 torque_max / speed_p99``: at the log's typical
                          top speed the viscous torque cannot exceed the torque range.
Stribeck velocity         ``2 speed_resolution <= v_s <= speed_max``: below the encoder's
                          speed resolution no curve can be resolved (``not_identifiable``);
                          above the largest speed the decay is not observed.
bristle stiffness sigma0  ``static / sigma0`` (presliding displacement) between one encoder
                          step and 0.1 rad; below one step it is not resolved
                          (``not_identifiable``, not implausible).
bristle damping sigma1    ``0 <= sigma1 <= 10 * 2 sqrt(sigma0 J_m)`` (ten times critical).
torque gain               ``0.5 <= g <= 2``: a factor beyond that is a wrong torque
                          constant, not an unmodelled effect.
delay                     ``0 <= delay <= 0.05 s`` (100 samples at 2 kHz).
backlash width            ``2 encoder steps <= width <= 2 deflection_max`` (below two steps:
                          not resolved, ``not_identifiable``).
environment scales        ``0.1 <= scale <= 10`` of the declared value.
========================  ==============================================================

Numbers a user *gives* for the nominal testbed are judged too: :data:`BENCHTOP_SEA` holds what a
benchtop series elastic actuator can be, and :func:`benchtop_warnings` says, in one line per
number, which given value lies outside it (most often a value in the wrong unit: ``k = 150000``
given in N mm/rad, ``J_m = 60`` in g m^2). It warns rather than refuses: such a value still has a
meaning for the models (the hard limits, where the numbers stop meaning anything, are
:data:`forecast_design.limits.PHYSICAL_RANGES`).

Datasheet tolerances of the nominal model (:data:`DATASHEET_TOLERANCE`) bound
how far the gap diagnosis may re-calibrate ``J_m`` and the spring before it
blames an effect; a re-calibration at that bound is itself reported.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np


__all__ = [
    "BENCHTOP_SEA",
    "ImplausibleInputWarning",
    "benchtop_warnings",
    "STATUSES",
    "RELATIVE_PRECISION",
    "DATASHEET_TOLERANCE",
    "ENCODER_COUNTS",
    "LogScales",
    "Bound",
    "ParameterStatus",
    "log_scales",
    "assess",
    "assess_all",
    "friction_bound",
    "effect_bound",
    "encoder_step_of",
    "speed_resolution",
    "not_identified",
    "ASYMMETRY_MAX_RATIO",
    "levels_are_friction",
]

#: Statuses of a fitted number, best first.
STATUSES = ("identified", "uncertain", "at_bound", "implausible", "not_identifiable")

#: Largest half-width of an ``identified`` number's 95 % interval, as a fraction of its value [-].
RELATIVE_PRECISION = 0.1

#: Relative tolerance of the nominal testbed values that a re-calibration may absorb [-].
#: ``J_m``: the reflected inertia from the rotor's datasheet inertia and the gear ratio (3 %);
#: ``k``: the series spring's bench calibration (3 %). ``d_m`` has no datasheet value (it is
#: the paper's viscous linearisation) and is free (>= 0).
DATASHEET_TOLERANCE: Mapping[str, float] = {"J_m": 0.03, "k": 0.03}

#: Encoder counts per revolution of the Forecast testbed (DHO-05 encoders) [-].
ENCODER_COUNTS = 2_000_000


@dataclass(frozen=True, slots=True, kw_only=True)
class LogScales:
    """What one log can say: the magnitudes that bound plausible parameters.

    Parameters
    ----------
    torque_max : float
        99.9th percentile of ``|tau_m|`` (or of the force for a plain axis log) [N m].
    speed_max : float
        99.9th percentile of the motor speed ``|theta'|`` [rad/s].
    speed_p99 : float
        99th percentile of ``|theta'|`` [rad/s].
    deflection_max : float
        99.9th percentile of the spring deflection ``|theta - q|`` [rad] (0 without a spring).
    angle_span : float
        Motor travel ``max theta - min theta`` [rad].
    rate_hz : float
        Sample rate [Hz].
    duration_s : float
        Log length [s].
    encoder_step : float
        Position resolution [rad] (2 pi / 2,000,000 for the testbed).
    J_m : float or None
        Motor inertia when known [kg m^2].
    position_cutoff_hz : float or None
        Cut-off of the position low-pass the speeds come from [Hz]; None for a tenth of the rate.
    """

    torque_max: float
    speed_max: float
    speed_p99: float
    deflection_max: float
    angle_span: float
    rate_hz: float
    duration_s: float
    encoder_step: float = 2.0 * math.pi / ENCODER_COUNTS
    J_m: float | None = None
    position_cutoff_hz: float | None = None

    @property
    def speed_resolution(self) -> float:
        """Smallest speed the encoder resolves over the derivative filter's window [rad/s] (:func:`speed_resolution`)."""
        return speed_resolution(self.encoder_step, self.rate_hz, self.position_cutoff_hz)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping (units in the docstring)."""
        return {"torque_max": self.torque_max, "speed_max": self.speed_max, "speed_p99": self.speed_p99,
                "deflection_max": self.deflection_max, "angle_span": self.angle_span, "rate_hz": self.rate_hz,
                "duration_s": self.duration_s, "encoder_step": self.encoder_step}


def speed_resolution(encoder_step: float, rate_hz: float, position_cutoff_hz: float | None = None) -> float:
    """Smallest speed an encoder resolves through the derivative filter [rad/s] (or [m/s]).

    One encoder step per window of the position low-pass, ``encoder_step x cutoff``: the filter
    averages the quantised position over about ``rate / cutoff`` samples, so a motor creeping
    by less than one count per window is indistinguishable from one at rest. The RMS speed
    noise of a quantised position through a 4th-order zero-phase Butterworth at ``cutoff`` is
    about half of it. It is *not* one count per sample (``encoder_step x rate``), which is ten
    times coarser at the default cut-off of a tenth of the rate and made a 16-bit encoder look
    unable to resolve 3.8 rad/s.

    Parameters
    ----------
    encoder_step : float
        Position resolution [rad] (or [m]).
    rate_hz : float
        Sample rate [Hz].
    position_cutoff_hz : float, optional
        Cut-off of the position low-pass [Hz]; default a tenth of the rate (the identification's
        and the diagnosis's default).

    Returns
    -------
    float
        The resolution [rad/s] (or [m/s]).
    """
    cutoff = rate_hz / 10.0 if position_cutoff_hz is None else min(position_cutoff_hz, rate_hz / 2.0)
    return float(encoder_step) * float(cutoff)


def encoder_step_of(position: np.ndarray) -> float:
    """Position resolution seen in a log [rad]: its smallest non-zero step, not below 2 pi / 2,000,000.

    Parameters
    ----------
    position : ndarray, shape (n,)
        Encoder positions [rad].

    Returns
    -------
    float
        The step [rad].
    """
    steps = np.abs(np.diff(np.asarray(position, dtype=float)))
    steps = steps[steps > 0]
    floor = 2.0 * math.pi / ENCODER_COUNTS
    return max(float(np.min(steps)), floor) if steps.size else floor


def log_scales(*, torque: np.ndarray, position: np.ndarray, rate_hz: float, deflection: np.ndarray | None = None,
               velocity: np.ndarray | None = None, encoder_step: float | None = None,
               J_m: float | None = None, position_cutoff_hz: float | None = None) -> LogScales:
    """Measure a log's scales.

    Parameters
    ----------
    torque : ndarray, shape (n,)
        Motor torque command (or axis force) [N m].
    position : ndarray, shape (n,)
        Motor angle (or axis position) [rad].
    rate_hz : float
        Sample rate [Hz].
    deflection : ndarray, shape (n,), optional
        Spring deflection ``theta - q`` [rad].
    velocity : ndarray, shape (n,), optional
        Motor speed [rad/s]; default the central difference of ``position``.
    encoder_step : float, optional
        Position resolution [rad]; default the smallest non-zero step seen in
        ``position``, but not below the testbed's 2 pi / 2,000,000.
    J_m : float, optional
        Motor inertia [kg m^2].
    position_cutoff_hz : float, optional
        Cut-off of the position low-pass behind ``velocity`` [Hz] (default a tenth of the rate).

    Returns
    -------
    LogScales
        The log's magnitudes.
    """
    torque = np.asarray(torque, dtype=float)
    position = np.asarray(position, dtype=float)
    if velocity is None:
        velocity = np.gradient(position, 1.0 / rate_hz) if position.size > 1 else np.zeros_like(position)
    speed = np.abs(np.asarray(velocity, dtype=float))
    if encoder_step is None:
        encoder_step = encoder_step_of(position)
    dmax = float(np.percentile(np.abs(deflection), 99.9)) if deflection is not None and np.size(deflection) else 0.0
    return LogScales(torque_max=float(np.percentile(np.abs(torque), 99.9)) if torque.size else 0.0,
                     speed_max=float(np.percentile(speed, 99.9)) if speed.size else 0.0,
                     speed_p99=float(np.percentile(speed, 99.0)) if speed.size else 0.0,
                     deflection_max=dmax, angle_span=float(np.ptp(position)) if position.size else 0.0,
                     rate_hz=float(rate_hz), duration_s=position.size / float(rate_hz),
                     encoder_step=float(encoder_step), J_m=J_m, position_cutoff_hz=position_cutoff_hz)


@dataclass(frozen=True, slots=True)
class Bound:
    """A plausible range.

    Parameters
    ----------
    lo, hi : float
        Range (``-inf``/``inf`` when open), same unit as the parameter.
    why : str
        One line: where the range comes from.
    magnitude : bool
        Compare ``|value|`` (harmonic coefficients, offsets of either sign) instead of the value.
    resolution : str
        Which end is the log's *resolution* rather than physics (``"above"``, ``"below"`` or
        ``""``): beyond it the number is not resolved by the sensors (a bristle deflection below
        one encoder count, a Stribeck velocity below the speed resolution), so it is
        ``not_identifiable``, not evidence against the effect it belongs to.
    """

    lo: float
    hi: float
    why: str
    magnitude: bool = False
    resolution: str = ""

    def contains(self, value: float) -> bool:
        """True when ``value`` lies in the range (``|value|`` for a magnitude bound)."""
        v = abs(value) if self.magnitude else value
        return bool(self.lo <= v <= self.hi)


@dataclass(frozen=True, slots=True, kw_only=True)
class ParameterStatus:
    """One fitted number and whether it may be reported as an estimate.

    Parameters
    ----------
    name : str
        Parameter name.
    value : float
        Estimate (parameter's unit).
    std : float or None
        Standard deviation, same unit (None when the fit gives none).
    status : str
        One of :data:`STATUSES`.
    reason : str
        Empty when identified; otherwise one line saying why not.
    plausible : (float, float) or None
        The plausible range used.
    """

    name: str
    value: float
    std: float | None
    status: str
    reason: str = ""
    plausible: tuple[float, float] | None = None

    @property
    def identified(self) -> bool:
        """True when the number is an estimate (status ``identified``)."""
        return self.status == "identified"

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        out: dict[str, Any] = {"value": _finite_or_none(self.value), "std": _finite_or_none(self.std),
                               "status": self.status}
        if self.reason:
            out["reason"] = self.reason
        if self.plausible is not None:
            out["plausible"] = [_finite_or_none(self.plausible[0]), _finite_or_none(self.plausible[1])]
        return out


def _finite_or_none(x: float | None) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def assess(name: str, value: float, *, std: float | None = None, bound: Bound | None = None,
           solver_bounds: tuple[float, float] | None = None, rel_tol: float = 1e-6,
           precision: float | None = RELATIVE_PRECISION) -> ParameterStatus:
    """Classify one fitted number (the statuses of the module docstring).

    Checks, in order (the first that fails decides): finite; inside the
    plausible ``bound``; not on a ``solver_bounds`` end (within ``rel_tol`` of the
    bound's scale); when ``std`` is given: finite and positive (else
    ``not_identifiable``), ``1.96 std < |value|`` and ``1.96 std <= precision |value|``
    (else ``uncertain``).

    Parameters
    ----------
    name : str
        Parameter name (for the reason text).
    value : float
        Estimate.
    std : float, optional
        Its standard deviation; a zero or non-finite std is a covariance that failed
        (a near-singular problem), never certainty: ``not_identifiable``.
    bound : Bound, optional
        Plausible range.
    solver_bounds : (float, float), optional
        The box (or grid ends) the solver searched; ``-inf``/``inf`` for open ends.
    rel_tol : float
        Relative distance to a solver bound that counts as "at" it [-].
    precision : float or None
        Largest relative half-width of the 95 % interval of an ``identified`` number
        [-] (default :data:`RELATIVE_PRECISION`); None checks only that the interval
        excludes zero.

    Returns
    -------
    ParameterStatus
        The number with its status and reason.
    """
    value = float(value)
    s = None if std is None else float(std)
    rng = None if bound is None else (bound.lo, bound.hi)

    def out(status: str, reason: str = "") -> ParameterStatus:
        return ParameterStatus(name=name, value=value, std=s, status=status, reason=reason, plausible=rng)

    if not math.isfinite(value):
        return out("implausible", f"{name} is not finite")
    if bound is not None and not bound.contains(value):
        shown = "|" + name + "|" if bound.magnitude else name
        v = abs(value) if bound.magnitude else value
        if (bound.resolution == "above" and v > bound.hi) or (bound.resolution == "below" and v < bound.lo):
            end = bound.hi if v > bound.hi else bound.lo
            return out("not_identifiable", f"{shown} = {v:.4g} is beyond {end:.3g}, the log's resolution "
                                           f"({bound.why}): not resolved, no evidence either way")
        return out("implausible", f"{shown} = {abs(value) if bound.magnitude else value:.4g} outside the plausible "
                                  f"range [{bound.lo:.3g}, {bound.hi:.3g}] ({bound.why})")
    if solver_bounds is not None:
        lo, hi = (float(solver_bounds[0]), float(solver_bounds[1]))
        scale = max(abs(lo) if math.isfinite(lo) else 0.0, abs(hi) if math.isfinite(hi) else 0.0, abs(value))
        tol = rel_tol * scale if scale > 0 else rel_tol
        for end, word in ((lo, "lower"), (hi, "upper")):
            if math.isfinite(end) and abs(value - end) <= tol:
                return out("at_bound", f"{name} = {value:.4g} sits on the {word} bound {end:.4g} of the search")
    if s is not None:
        if not (math.isfinite(s) and s > 0.0):
            return out("not_identifiable", f"{name} has {'a zero' if s == 0.0 else 'no finite'} standard deviation: "
                                           "the log does not determine it (a singular or near-singular problem)")
        if 1.96 * s >= abs(value):
            return out("uncertain", f"the 95 % interval of {name} ({value:.3g} +- {1.96 * s:.2g}) includes zero")
        if precision is not None and 1.96 * s > precision * abs(value):
            return out("uncertain", f"the 95 % interval of {name} ({value:.4g} +- {1.96 * s:.2g}) is wider than "
                                    f"+-{100 * precision:g} % of the value: use the interval, not the number")
    return out("identified")


def assess_all(values: Mapping[str, float], *, std: Mapping[str, float] | None = None,
               bounds: Mapping[str, Bound] | None = None,
               solver_bounds: Mapping[str, tuple[float, float]] | None = None) -> dict[str, ParameterStatus]:
    """:func:`assess` over a mapping of estimates.

    Parameters
    ----------
    values : Mapping[str, float]
        Estimates by name.
    std : Mapping[str, float], optional
        Standard deviations by name.
    bounds : Mapping[str, Bound], optional
        Plausible ranges by name (missing: no range check).
    solver_bounds : Mapping[str, (float, float)], optional
        Search boxes by name.

    Returns
    -------
    dict of str to ParameterStatus
        In the order of ``values``.
    """
    std = std or {}
    bounds = bounds or {}
    solver_bounds = solver_bounds or {}
    return {k: assess(k, v, std=std.get(k), bound=bounds.get(k), solver_bounds=solver_bounds.get(k))
            for k, v in values.items()}


def not_identified(statuses: Iterable[ParameterStatus]) -> list[ParameterStatus]:
    """The statuses that are not ``identified``, in order."""
    return [s for s in statuses if not s.identified]


def _torque_bound(scales: LogScales, what: str) -> Bound:
    return Bound(0.0, 1.5 * scales.torque_max,
                 f"{what} cannot exceed 1.5 x the largest applied torque {scales.torque_max:.3g}", magnitude=True)


def friction_bound(name: str, scales: LogScales, *, static: float | None = None) -> Bound | None:
    """Plausible range of one friction-model parameter (names of :mod:`forecast_design.friction`).

    Parameters
    ----------
    name : str
        ``viscous``, ``coulomb``, ``static``, ``stribeck_velocity``, ``sigma0``,
        ``sigma1``, ``sigma2``, ``offset``, ``sinN``/``cosN`` and their ``pos``/``neg``,
        ``psinN``/``pcosN`` variants; ``inertia`` has no range.
    scales : LogScales
        The log's magnitudes.
    static : float, optional
        The fitted static (breakaway) level [N m] that a bristle stiffness ``sigma0`` is judged
        with: the presliding displacement is ``static / sigma0``. Without it (a search range set
        before the fit) the largest applied torque stands in for the level.

    Returns
    -------
    Bound or None
        The range, or None for a parameter without one.
    """
    T = scales.torque_max
    if name in ("viscous", "sigma2") or name.startswith("viscous"):
        v = max(scales.speed_p99, scales.speed_resolution)
        return Bound(0.0, 1.5 * T / v, f"viscous torque at the log's top speed {v:.3g} within 1.5 x the torque range")
    if name.startswith("coulomb") or name == "static":
        return Bound(0.0, 1.5 * T, f"friction level within 1.5 x the largest applied torque {T:.3g}")
    if name == "offset" or name.startswith(("sin", "cos", "psin", "pcos")):
        return _torque_bound(scales, "a harmonic or offset amplitude")
    if name == "stribeck_velocity":
        lo = 2.0 * scales.speed_resolution
        return Bound(lo, max(scales.speed_max, lo),
                     f"Stribeck velocity between 2 encoder speed steps ({lo:.2g}) and the largest speed",
                     resolution="below")
    if name == "sigma0":
        # presliding displacement static / sigma0 between one encoder step and 0.1 rad
        if static is not None and math.isfinite(static) and static > 0.0:
            return Bound(static / 0.1, static / scales.encoder_step,
                         f"presliding displacement static/sigma0 = {static:.3g}/sigma0 between one encoder "
                         "step and 0.1 rad", resolution="above")
        return Bound(T / 0.1 if T > 0 else 0.0, 1.5 * T / scales.encoder_step,
                     "presliding displacement static/sigma0 between one encoder step and 0.1 rad",
                     resolution="above")
    if name == "sigma1":
        if scales.J_m is None:
            return Bound(0.0, math.inf, "bristle damping >= 0")
        hi = 10.0 * 2.0 * math.sqrt(1.5 * T / scales.encoder_step * scales.J_m)
        return Bound(0.0, hi, "bristle damping at most ten times critical")
    return None


def effect_bound(name: str, scales: LogScales, *, static: float | None = None) -> Bound | None:
    """Plausible range of one unmodelled-effect parameter (field names of :mod:`forecast_design.effects`).

    Parameters
    ----------
    name : str
        ``F_c``, ``F_s``, ``a``/``b`` (harmonic amplitudes), ``gain``, ``delay_s``,
        ``width_rad``, ``v_s``, ``sigma0``, ``sigma1``, ``J_scale``, ``d_scale``, ``k_e_scale``.
    scales : LogScales
        The log's magnitudes.
    static : float, optional
        The fitted breakaway level ``F_s`` [N m] that ``sigma0`` is judged with
        (:func:`friction_bound`).

    Returns
    -------
    Bound or None
        The range, or None.
    """
    if name in ("F_c", "F_s"):
        return friction_bound("coulomb", scales)
    if name in ("a", "b") or name.startswith(("a", "b")) and name[1:].isdigit():
        return _torque_bound(scales, "a harmonic amplitude")
    if name == "gain":
        return Bound(0.5, 2.0, "a torque factor beyond [0.5, 2] is a wrong torque constant, not an effect")
    if name == "delay_s":
        return Bound(0.0, 0.05, "delays beyond 50 ms are not a transmission delay of a 2 kHz loop")
    if name == "width_rad":
        lo = 2.0 * scales.encoder_step
        return Bound(lo, max(2.0 * scales.deflection_max, lo),
                     "dead band between two encoder steps and twice the largest spring deflection",
                     resolution="below")
    if name == "v_s":
        return friction_bound("stribeck_velocity", scales)
    if name in ("sigma0", "sigma1"):
        return friction_bound(name, scales, static=static)
    if name.endswith("_scale"):
        return Bound(0.1, 10.0, "the real environment within a factor 10 of the declared one")
    return None


#: What a benchtop SEA can be: name -> (lowest, highest, unit, why). The Forecast testbed (Table 1:
#: J_m 0.133, d_m 0.3, k 58, link 0.0018 / 0.35) sits well inside every range.
BENCHTOP_SEA: Mapping[str, tuple[float, float, str, str]] = {
    "J_m": (1e-6, 10.0, "kg m^2", "a rotor of 1e-7 to 1e-3 kg m^2 reflected through a gear of 1 to 100"),
    "d_m": (0.0, 50.0, "N m s/rad", "the viscous friction of a geared motor at the output"),
    "k": (0.5, 2e4, "N m/rad", "the series spring: compliant enough to measure force by its deflection"),
    "J_l": (0.0, 10.0, "kg m^2", "a link a bench can hold"),
    "d_l": (0.0, 50.0, "N m s/rad", "the link's bearing damping"),
}


class ImplausibleInputWarning(UserWarning):
    """A given number outside what a benchtop SEA can be (:data:`BENCHTOP_SEA`); the CLI prints it as
    ``forecast-design: warning: ...``."""


def benchtop_warnings(values: Mapping[str, float | None], where: str = "[testbed]", *,
                      warn: bool = True) -> list[str]:
    """One line per value outside :data:`BENCHTOP_SEA`, naming it, its unit and the range.

    Parameters
    ----------
    values : Mapping[str, float or None]
        Testbed numbers by name (``J_m`` [kg m^2], ``d_m`` [N m s/rad], ``k`` [N m/rad],
        ``J_l`` [kg m^2], ``d_l`` [N m s/rad]); None and unknown names are skipped.
    where : str
        Where the numbers come from (a file and its table), first in each line.
    warn : bool
        Also issue each line as an :class:`ImplausibleInputWarning`.

    Returns
    -------
    list of str
        The lines (empty when every value is plausible).
    """
    lines = []
    for name, value in values.items():
        if name not in BENCHTOP_SEA or value is None:
            continue
        lo, hi, unit, why = BENCHTOP_SEA[name]
        if not lo <= value <= hi:
            lines.append(f"{where} {name} = {value:g} {unit} is outside what a benchtop SEA has ([{lo:g}, {hi:g}] "
                         f"{unit}: {why}); check its unit (SI: kg m^2, N m s/rad, N m/rad): the results take "
                         "it as given")
    if warn:
        for line in lines:
            warnings.warn(line, ImplausibleInputWarning, stacklevel=2)
    return lines


#: Largest ratio of a friction law's levels for the two directions of motion [-]: a drive's friction differs
#: by direction by tens of percent; a level near zero one way is a constant torque (a driver's offset, cogging
#: over part of a revolution), not friction.
ASYMMETRY_MAX_RATIO = 3.0


def levels_are_friction(params: Mapping[str, Any]) -> bool:
    """Whether a friction law's two levels ``F_c`` / ``F_c_neg`` [N m] are within :data:`ASYMMETRY_MAX_RATIO`.

    Parameters
    ----------
    params : Mapping[str, Any]
        A fit's parameters (a missing level counts as 0).

    Returns
    -------
    bool
        False when one level is below the other divided by the ratio: a constant torque, not friction.
    """
    lv = (float(params.get("F_c", 0.0)), float(params.get("F_c_neg", 0.0)))
    return not (max(lv) > 0.0 and min(lv) < max(lv) / ASYMMETRY_MAX_RATIO)
