"""Friction identification from logs: data preparation, linear and nonlinear fits, validation."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import warnings
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
from scipy import special

from ..errors import ForecastError, IdentifiabilityError, ParameterError
from ..plausibility import LogScales, log_scales
from . import _lsq
from .derivatives import FilterSettings, decimate_columns, default_filter_settings, differentiate, lowpass
from .source import FrictionLog, _check_array, _rate_from_time, experiment_scales, friction_log, zoh_align
from .selection import SampleSelection, resolve_selection, select_samples
from .selection import encoder_step as _observed_step
from .terms import FrictionModel, Inertia, Offset, friction_model
from .tau_s import tau_s_scale_check, tau_s_zero_offset
from .results import (FrictionFit, FrictionValidation, IdentificationData, IllConditionedWarning,
                      _relative_error, _ro, fit_percent)
from .verdict import grade, identifiability
from .method_error import method_error as _method_error

__all__ = [
    "FrictionFit",
    "FrictionValidation",
    "IllConditionedWarning",
    "IdentificationData",
    "fit_friction",
    "identify",
    "prepare_identification_data",
    "validate",
    "fit_data",
    "predict_data",
    "fit_percent",
    "experiment_scales",
    "zoh_align",
    "CONDITION_WARN",
]

#: Scaled condition number above which a fit warns (the estimate is fragile).
CONDITION_WARN = 1e6
#: Scaled condition number above which parameters are declared not identifiable.
CONDITION_SINGULAR = 1e12


# --- data preparation ----------------------------------------------------------------


def _resolve_model(model: FrictionModel | str) -> FrictionModel:
    if isinstance(model, FrictionModel):
        return model
    if isinstance(model, str):
        return friction_model(model)
    if hasattr(model, "names") and hasattr(model, "columns"):
        return FrictionModel(terms=(model,))
    raise ParameterError(f"model must be a FrictionModel or a model name, got {model!r}",
                         name="model", value=model)


def prepare_identification_data(t: np.ndarray, position: np.ndarray, force: np.ndarray,
                                model: FrictionModel, *, velocity: np.ndarray | None = None,
                                inertia: float | None = None,
                                settings: FilterSettings | None = None,
                                selection: SampleSelection | str | bool | None = "auto",
                                encoder_step: float | None = None) -> IdentificationData:
    """Filter, differentiate and decimate a log for a friction fit.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times, uniform [s].
    position : ndarray, shape (n,)
        Encoder position [rad] (or [m]).
    force : ndarray, shape (n,)
        Force to explain [N m] (or [N]).
    model : FrictionModel
        Gives the regressor columns.
    velocity : ndarray, shape (n,), optional
        Measured velocity [rad/s]; default differentiate position.
    inertia : float, optional
        Known inertia [kg m^2]: ``inertia * acceleration`` is subtracted from `force`.
    settings : FilterSettings, optional
        Default :func:`default_filter_settings` at the log's rate; for nonlinear
        models no decimation (``decimation="subsample"``, factor 1).
    selection : SampleSelection or str
        Which samples a static fit uses (``"auto"``, ``"on"``, ``"off"``; see
        :mod:`forecast_design.friction.selection`); LuGre keeps every sample.
    encoder_step : float, optional
        Position resolution [rad] (or [m]); default the log's smallest non-zero step.

    Returns
    -------
    IdentificationData
        The decimated data with the ``keep`` mask.
    """
    t = _check_array("t", t)
    n = t.size
    position = _check_array("position", position, n)
    force = _check_array("force", force, n)
    if velocity is not None:
        velocity = _check_array("velocity", velocity, n)
    rate = _rate_from_time(t)
    if settings is None:
        if model.is_linear:
            settings = default_filter_settings(rate)
        else:
            # No decimation: the Stribeck hump lives in the few samples around each
            # velocity reversal, and LuGre's implicit step must resolve the bristle
            # time constant g / (sigma0 |v|) (often ~1 ms).
            settings = default_filter_settings(rate, decimation="subsample", decimation_factor=1)
    elif not math.isclose(settings.rate_hz, rate, rel_tol=1e-3):
        settings = dataclasses.replace(settings, rate_hz=rate)
    kin = differentiate(position, settings, velocity=velocity)
    p = len(model.linear_names)
    dynamic = model.is_dynamic
    dec = _decimated_block(_raw_columns(force, kin, model, settings, inertia),
                           4 + p * (2 if dynamic else 1) + int(dynamic), settings)
    rule = resolve_selection(selection)
    step = _observed_step(position) if encoder_step is None else float(encoder_step)
    keep_raw, sel = select_samples(kin.velocity, settings, step, rule)
    e, R = settings.edge_samples, settings.decimation_factor
    keep = np.ascontiguousarray(keep_raw[e:n - e][::R])[:dec.shape[0]]
    # what slides, whatever the rule's mode: the identifiability check runs on every path
    sliding_raw = keep_raw if sel.applied else select_samples(
        kin.velocity, settings, step, dataclasses.replace(rule, mode="on"))[0]
    sliding = np.ascontiguousarray(sliding_raw[e:n - e][::R])[:dec.shape[0]]
    static_keep = None
    if model.is_dynamic and sel.applied:
        static_keep, keep = keep, np.ones(keep.size, dtype=bool)
        sel = dataclasses.replace(sel, applied=False, reason="LuGre is dynamic: it explains the stops "
                                                             "(presliding) and keeps every sample")
    sel = dataclasses.replace(sel, n_used=int(keep.sum()), n_total=int(keep.size))
    return IdentificationData(force=dec[:, 0], velocity=dec[:, 1], position=dec[:, 2],
                              acceleration=dec[:, 3], regressor=dec[:, 4:4 + p],
                              force_filtered=dec[:, 4 + p] if dynamic else None,
                              regressor_filtered=dec[:, 5 + p:] if dynamic else None,
                              dt=settings.decimation_factor / rate, settings=settings, n_raw=n,
                              keep=keep, selection=sel, encoder_step=step, static_keep=static_keep,
                              sliding=sliding)


def _raw_columns(force: np.ndarray, kin: Any, model: FrictionModel, settings: FilterSettings,
                 inertia: float | None):
    """The raw-rate columns of the identification data, one at a time, in the block's order.

    Order: explained force, velocity, position, acceleration, the regressor's columns; for a
    dynamic model also the low-passed force and regressor (the inertia column unfiltered: J
    theta'' is already the filtered acceleration). One term's columns exist at a time, so the
    preparation holds a few raw columns instead of the whole block (issue 16). A regressor column that
    *is* the velocity, position or acceleration is yielded as that column's index: decimated once.
    """
    yield force if inertia is None else force - float(inertia) * kin.acceleration
    signals = (kin.velocity, kin.position, kin.acceleration)
    yield from signals
    for term in model.linear_terms:
        block = term.columns(kin.velocity, kin.position, kin.acceleration)
        for j in range(block.shape[1]):
            same = [i for i, x in enumerate(signals, start=1) if _same_data(block[:, j], x)]
            yield same[0] if same else block[:, j]
        del block
    if model.is_dynamic:
        yield lowpass(force, settings) - (0.0 if inertia is None else float(inertia) * kin.acceleration)
        for term in model.linear_terms:
            block = term.columns(kin.velocity, kin.position, kin.acceleration)
            for j, name in enumerate(term.names()):
                yield block[:, j] if name == "inertia" else lowpass(block[:, j], settings)
            del block


def _same_data(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether `a` and `b` are views of the same numbers (same memory, strides, shape and type)."""
    return (a.shape, a.strides, a.dtype, a.ctypes.data) == (b.shape, b.strides, b.dtype, b.ctypes.data)


def _decimated_block(columns, k: int, settings: FilterSettings) -> np.ndarray:
    """Decimate `k` raw columns one by one (:func:`decimate_columns`) into one (m, k) block.

    Column by column gives the same numbers bit for bit as decimating the stacked block
    (the filters run along each column alone) with a fraction of the memory; an index repeats a column.
    """
    out = None
    for j, col in enumerate(columns):
        if isinstance(col, int):
            out[:, j] = out[:, col]
            continue
        d = decimate_columns(col, settings)
        if out is None:
            out = np.empty((d.size, k))
        out[:, j] = d
    return out


def _check_identifiable(model: FrictionModel, position: np.ndarray, data: IdentificationData) -> None:
    names = model.names
    steps = np.abs(np.diff(position))
    quantum = float(steps[steps > 0].min()) if np.any(steps > 0) else 0.0
    span = float(np.ptp(position))
    if span == 0.0 or span <= 2.0 * quantum:
        lost = [n for n in names if n != "offset"]
        raise IdentifiabilityError(
            f"no motion in the log (position range {span:.3g}): friction parameters "
            f"{', '.join(lost)} are not identifiable; excite the axis in both directions")
    sel = data.selection
    sliding = data.sliding if data.sliding is not None else data.used
    n_slide, n_total = int(np.count_nonzero(sliding)), int(sliding.size)
    frac = sel.rule.min_fraction if sel is not None else 0.05
    need = max(int(np.ceil(frac * n_total)), 4 * len(names))
    if n_slide < need and not model.is_dynamic:
        # on every path: switching the sample rule off fits the stops too, but a static law is
        # identified only from what slides (a log that never slides gave viscous 266 for 0.3)
        raise IdentifiabilityError(
            f"not identifiable: only {n_slide} of {n_total} samples slide away from stops and reversals "
            f"(need {need}); {', '.join(names)} cannot be identified by a static friction law from this log, "
            "whichever samples are fitted. Record a log that slides longer in both directions",
            parameters=tuple(names), reasons=(f"too little sliding: {n_slide} of {n_total} samples slide",))
    v = data.velocity[sliding] if n_slide else data.velocity[data.used]
    vth = 0.05 * float(np.max(np.abs(v))) if v.size else 0.0
    pos = float(np.mean(v > vth)) if v.size else 0.0
    neg = float(np.mean(v < -vth)) if v.size else 0.0
    directional = [n for term in model.terms if term.uses_direction for n in term.names()]
    if directional and min(pos, neg) < 0.01:
        side = "positive" if pos > neg else "negative"
        lost = directional + (["offset"] if model.has(Offset) else [])
        raise IdentifiabilityError(
            f"the log slides in the {side} direction only ({100 * max(pos, neg):.1f} % of the sliding samples "
            f"above 5 % of peak speed one way, {100 * min(pos, neg):.1f} % the other): "
            f"{', '.join(lost)} are not identifiable (a direction-dependent term cannot be told "
            "from an offset without motion both ways)", parameters=tuple(lost),
            reasons=(f"the log slides in the {side} direction only",))


def _check_conditioning(names: tuple[str, ...], sol: "_lsq.LsqSolution", stacklevel: int) -> float:
    _, _, vec = _lsq.scaled_conditioning(sol.normal_scaled)
    sv = sol.singular_values
    cond = float(sv[0] / sv[-1]) if sv.size and sv[-1] > 0 else float("inf")
    if not cond < CONDITION_SINGULAR:
        weak = np.abs(vec[:, 0])
        culprits = [names[j] for j in np.argsort(-weak) if weak[j] > 0.2]
        raise IdentifiabilityError(
            f"regressor is rank deficient (scaled condition number {cond:.3g}): "
            f"{', '.join(culprits)} are not identifiable from this log (linearly dependent columns)")
    if cond > CONDITION_WARN:
        warnings.warn(f"friction fit is ill-conditioned: scaled condition number {cond:.3g} > 1e6; "
                      "estimates may be unreliable", IllConditionedWarning, stacklevel=stacklevel)
    return cond


# --- fits ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Estimate:
    params: np.ndarray
    covariance: np.ndarray
    condition_number: float
    condition_number_unscaled: float
    constrained: bool
    active: tuple[str, ...]
    solver: Mapping[str, Any]
    covariance_iid: np.ndarray
    held: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    lags: int = 0
    overrides: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    log_scale: tuple[str, ...] = ()


def _nonneg_mask(model: FrictionModel, names: tuple[str, ...]) -> np.ndarray:
    nonneg = {n for term in model.terms for n in term.nonnegative}
    return np.array([n in nonneg for n in names], dtype=bool)


def _fit_linear(model: FrictionModel, data: IdentificationData, *, constrain: bool,
                check: bool = True, covariance: bool = True) -> _Estimate:
    keep = data.used
    W_all, y_all = data.regressor, data.force
    W, y = W_all[keep], y_all[keep]
    names = model.linear_names
    sol = _lsq.solve_lstsq(W, y)
    sv = sol.singular_values
    if check:
        cond = _check_conditioning(names, sol, 5)
    else:
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    lam_raw = np.linalg.eigvalsh(W.T @ W)
    cond_raw = float(np.sqrt(lam_raw[-1] / lam_raw[0])) if lam_raw[0] > 0 else float("inf")
    p = sol.params
    mask = _nonneg_mask(model, names)
    violated = mask & (p < 0)
    active: tuple[str, ...] = ()
    free = None
    method = "casadi.solve (column-scaled normal equations)"
    if constrain and violated.any():
        method += " + cvxpy nonnegative least squares"
        p, act = _lsq.solve_nonneg_lstsq(W, y, mask)
        active = tuple(f"{names[j]} >= 0" for j in np.flatnonzero(act))
        free = ~act
    zero = np.zeros((p.size, p.size))   # a refit whose parameters alone are used: no Newey-West sums
    hac = (_lsq.hac_covariance(W_all, y_all - W_all @ p, free, keep) if covariance
           else _lsq.HacResult(zero, 0, zero, 1.0))
    held = {names[j]: (0.0, math.inf) for j in range(len(names)) if free is not None and not free[j]}
    return _Estimate(params=p, covariance=hac.covariance, condition_number=cond,
                     condition_number_unscaled=cond_raw, constrained=bool(violated.any() and constrain),
                     active=active, solver=MappingProxyType({"method": method}),
                     covariance_iid=hac.iid_covariance, held=held, lags=hac.lags)


def _estimate(model: FrictionModel, data: IdentificationData, *, constrain: bool, check: bool = True,
              scales: LogScales | None = None, covariance: bool = True, **nl_options: Any) -> _Estimate:
    if model.is_linear:   # with one BLAS thread: fit_friction and method_error are _lsq.one_blas_thread
        return _fit_linear(model, data, constrain=constrain, check=check, covariance=covariance)
    from ..plausibility import friction_bound
    from . import nonlinear

    if check:
        _check_conditioning(model.linear_names + ("coulomb", "viscous"),
                            _lsq.solve_lstsq(*_linear_surrogate(data)), 4)
    bounds: dict[str, Any] = {}
    if scales is not None:
        b = friction_bound("stribeck_velocity", scales)
        # an unquantised log has no speed resolution: start the grid 1e-4 below the top speed
        bounds["vs_bounds"] = (max(b.lo, 1e-4 * b.hi), b.hi)
        if scales.torque_max > 0:
            bounds["level_max"] = friction_bound("static", scales).hi
        if model.is_dynamic and scales.torque_max > 0:
            b = friction_bound("sigma0", scales)
            bounds["sigma0_bounds"] = (b.lo, b.hi)
    # LuGre keeps every sample; its Stribeck start uses the samples the static rule keeps.
    keep = data.static_keep if model.is_dynamic and data.static_keep is not None else data.used
    res = nonlinear.fit_nonlinear(model, data, constrain=constrain, keep=keep, **bounds, **nl_options)
    cov_iid = res.covariance_iid if res.covariance_iid is not None else res.covariance
    return _Estimate(params=res.params, covariance=res.covariance, condition_number=res.condition_number,
                     condition_number_unscaled=res.condition_number_unscaled, constrained=res.constrained,
                     active=res.active, solver=MappingProxyType(dict(res.solver)), covariance_iid=cov_iid,
                     held=dict(res.held), lags=res.lags, overrides=dict(res.overrides), log_scale=res.log_scale)


def _linear_surrogate(data: IdentificationData) -> tuple[np.ndarray, np.ndarray]:
    keep = data.used
    W = np.column_stack([data.regressor, np.sign(data.velocity), data.velocity])
    return W[keep], data.force[keep]


def _predict_data(model: FrictionModel, params: Mapping[str, float], data: IdentificationData) -> np.ndarray:
    out = np.zeros_like(data.force)
    if model.linear_terms:
        out = out + data.regressor @ np.array([params[n] for n in model.linear_names])
    nl = model.nonlinear_term
    if nl is not None:
        out = out + nl.evaluate(params, data.velocity, data.dt)
    return out


def _intervals(names, p, std, dof, log_scale: tuple[str, ...] = ()) -> dict[str, tuple[float, float]]:
    """Student-t intervals; on the log scale for strictly positive parameters in `log_scale`."""
    q = float(special.stdtrit(max(dof, 1), 0.975))   # Student-t quantile (scipy.stats.t.ppf's kernel)
    out = {}
    for i, n in enumerate(names):
        if n in log_scale and p[i] > 0 and math.isfinite(std[i]):
            w = min(q * std[i] / p[i], 700.0)
            out[n] = (float(p[i] * math.exp(-w)), float(p[i] * math.exp(w)))
        else:
            out[n] = (float(p[i] - q * std[i]), float(p[i] + q * std[i]))
    return out


@_lsq.one_blas_thread
def fit_friction(t: np.ndarray, position: np.ndarray, force: np.ndarray, model: FrictionModel | str, *,
                 velocity: np.ndarray | None = None, inertia: float | None = None,
                 settings: FilterSettings | None = None, holdout: float = 0.0,
                 constrain: bool = True, selection: SampleSelection | str | bool | None = "auto",
                 encoder_step: float | None = None, zoh_force: bool = False,
                 scales: LogScales | None = None, adequacy: bool = True, method_error: bool = True,
                 **nonlinear_options: Any) -> FrictionFit:
    """Identify a friction model from one log.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Uniform sample times [s].
    position : ndarray, shape (n,)
        Encoder position [rad] (or [m] for a prismatic axis).
    force : ndarray, shape (n,)
        Force explained by the model [N m] (or [N]); with ``inertia`` given,
        the measured motor force.
    model : FrictionModel or str
        The model (e.g. ``friction_model("extended-sfm")`` or
        ``Viscous() + Coulomb() + Harmonics(n=4)``) or a model name.
    velocity : ndarray, shape (n,), optional
        Measured velocity [rad/s]; default: differentiate the filtered position.
    inertia : float, optional
        Known (nominal) inertia [kg m^2]; ``inertia * acceleration`` is subtracted
        from the force. Leave None and include an ``Inertia`` term to estimate it.
    settings : FilterSettings, optional
        Filtering and decimation; default :func:`default_filter_settings` at the
        log's rate (IDIM recipe: 4th-order Butterworth at rate/10 on position,
        parallel decimation by 10 with cut-off 0.04 rate, 49 edge samples); for
        Stribeck and LuGre the same position filter and no decimation.
    holdout : float
        Fraction in [0, 0.9] of the (decimated) log at its end used for the holdout
        score [-]. The score comes from a refit on the head; the returned
        parameters are fitted on the whole log.
    constrain : bool
        Enforce physical consistency (nonnegative viscous/Coulomb/inertia, static
        >= Coulomb) when the unconstrained fit violates it.
    selection : SampleSelection or str
        Leave stops and reversals out of static fits: ``"auto"`` (default: when
        the log stops), ``"on"``, ``"off"`` (plain IDIM on every sample), or a
        :class:`~forecast_design.friction.selection.SampleSelection`. The rule
        is in :mod:`forecast_design.friction.selection`; LuGre keeps every sample.
    encoder_step : float, optional
        Position resolution [rad] (or [m]) for the speed threshold and the
        plausible ranges; default the log's smallest non-zero position step.
    zoh_force : bool
        The force is a zero-order-hold command applied over ``[t_k, t_k+1)``
        (the experiment format's ``tau_m``): average consecutive samples so it
        lines up with the central-difference acceleration at ``t_k``.
        Without it a ZOH command is half a sample late, which biases a
        low-noise fit (0.07 % on viscous and Coulomb at 2 kHz, measured).
    scales : LogScales, optional
        The log's magnitudes for the plausible ranges; default measured from
        ``force`` and ``position`` (:func:`forecast_design.plausibility.log_scales`).
    adequacy : bool
        Test the residual for structure a richer model would explain (direction, speed,
        angle) and its whiteness (:mod:`forecast_design.friction.adequacy`); a parameter
        such a structure moves outside its interval becomes ``uncertain``.
    method_error : bool
        Add the method's own error to the standard deviations: the larger shift of every
        estimate when the analysis is repeated on every other sample and at half the position
        filter's cut-off (:mod:`forecast_design.friction.method_error`); when both repeated fits
        fail, the ``identified`` numbers become ``uncertain`` (their intervals carry the noise only).
    **nonlinear_options
        Passed to the nonlinear solver (``max_iter``, ``sigma0_init``); unknown
        keys raise ParameterError.

    Returns
    -------
    FrictionFit
        Parameters, uncertainties, a plausibility status per parameter and fit scores.

    Raises
    ------
    ParameterError
        NaN/inf in an input (the message names the array), non-uniform or
        non-increasing time, bad option.
    IdentifiabilityError
        No motion, motion in one direction only for a direction-dependent model,
        a rank-deficient regressor (names the parameters), or too few samples
        left after the sample selection.
    SolverError
        The LuGre least-squares search, the Stribeck search or the constrained
        QP (cvxpy) failed.

    Warns
    -----
    IllConditionedWarning
        When the scaled condition number exceeds 1e6 (the number is in the message).

    Notes
    -----
    Linear-in-parameter models are one least-squares problem ``y = Phi p`` on
    the selected samples, solved with casadi on the column-scaled normal
    equations. Stribeck is a variable projection over the Stribeck velocity,
    LuGre a bounded Gauss-Newton on its filtered output error; see
    :mod:`forecast_design.friction.nonlinear`.
    Standard deviations are a Newey-West sandwich
    ``(Phi^T Phi)^-1 S (Phi^T Phi)^-1`` whose bandwidth follows the residuals'
    autocorrelation (filtered, decimated residuals are not white; the
    classical IDIM ``sigma^2 (Phi^T Phi)^-1`` is kept as ``std_iid``), the
    Jacobian taking the place of ``Phi`` for nonlinear models, with the
    method's own error (the shift of each estimate at half the rate and at half
    the filter cut-off, :mod:`forecast_design.friction.method_error`) added in
    quadrature. Every number
    is then graded by :mod:`forecast_design.plausibility` (``status``): a
    solver's convergence is not a verdict on it.
    """
    model = _resolve_model(model)
    for label, value, kind in (("settings", settings, FilterSettings), ("scales", scales, LogScales)):
        if value is not None and not isinstance(value, kind):
            raise ParameterError(f"{label} must be a {kind.__name__} or None, got {type(value).__name__}", name=label,
                                 value=value)
    if nonlinear_options and model.is_linear:
        raise ParameterError(f"option(s) {', '.join(sorted(nonlinear_options))} apply to nonlinear models "
                             f"only; model {model.name!r} is linear", name=sorted(nonlinear_options)[0])
    if not (isinstance(holdout, (int, float)) and 0.0 <= holdout <= 0.9):
        raise ParameterError(f"holdout must be a fraction in [0, 0.9], got {holdout!r}", name="holdout",
                             value=holdout)
    if inertia is not None and not (math.isfinite(inertia) and inertia >= 0):
        raise ParameterError(f"inertia must be >= 0 [kg m^2], got {inertia!r}", name="inertia", value=inertia)
    if encoder_step is not None and not (isinstance(encoder_step, (int, float, np.floating))
                                         and math.isfinite(encoder_step) and encoder_step >= 0):
        raise ParameterError(f"encoder_step must be a finite number >= 0 [rad or m], got {encoder_step!r}",
                             name="encoder_step", value=encoder_step)
    rule = resolve_selection(selection)
    if zoh_force:
        force = zoh_align(_check_array("force", force))
    position = _check_array("position", position)
    if encoder_step is None:
        encoder_step = scales.encoder_step if scales is not None else _observed_step(position)
    data = prepare_identification_data(t, position, force, model, velocity=velocity, inertia=inertia,
                                       settings=settings, selection=rule, encoder_step=encoder_step)
    _check_identifiable(model, position, data)
    if scales is None:
        scales = log_scales(torque=np.asarray(force, dtype=float), position=position,
                            rate_hz=data.settings.rate_hz, encoder_step=encoder_step, J_m=inertia)
    est = _estimate(model, data, constrain=constrain, scales=scales, **nonlinear_options)
    names = model.names
    params = {n: float(v) for n, v in zip(names, est.params)}
    y_hat = _predict_data(model, params, data)
    keep = data.used
    m = data.force.size
    m_used = int(keep.sum())
    holdout_fit = None
    if holdout > 0:
        n_head = int(round((1.0 - holdout) * m))
        if int(keep[:n_head].sum()) < 2 * len(names) or int(keep[n_head:].sum()) < 2:
            raise ParameterError(f"holdout {holdout} leaves too few samples ({int(keep[:n_head].sum())} of "
                                 f"{m_used} used)", name="holdout", value=holdout)
        head = _estimate(model, data.head(n_head), constrain=constrain, check=False, scales=scales,
                         covariance=False, **nonlinear_options)
        y_cv = _predict_data(model, dict(zip(names, head.params)), data)
        tail = keep[n_head:]
        holdout_fit = fit_percent(data.force[n_head:][tail], y_cv[n_head:][tail])
    held = dict(est.held)
    me = _method_error(model, t, position, force, params, velocity=velocity, inertia=inertia, settings=settings,
                       selection=rule, encoder_step=encoder_step, constrain=constrain, scales=scales,
                       **nonlinear_options) if method_error else None
    std_method = np.array([me.std.get(n, 0.0) if me is not None else 0.0 for n in names])
    covariance = est.covariance + np.diag(std_method ** 2)
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    std_iid = np.sqrt(np.clip(np.diag(est.covariance_iid), 0.0, None))
    for i, n in enumerate(names):
        if n in held or n in est.overrides:  # on a bound of the fit or undefined: no interval
            std[i] = std_iid[i] = std_method[i] = math.nan
    status = grade(model, params, dict(zip(names, std)), scales, held=held, overrides=est.overrides,
                   active=est.active)
    if me is not None and not me.std:   # both repeated fits failed
        for name, st in status.items():
            if st.identified:
                status[name] = dataclasses.replace(st, status="uncertain", reason=(
                    f"the method's own error is not known ({me.failure}): the interval carries the noise only"))
    intervals = _intervals(names, est.params, std, m_used - len(names), est.log_scale)
    adq = None
    if adequacy:
        from .adequacy import check_adequacy

        adq = check_adequacy(model, params, status, intervals, data, data.force - y_hat)
        for name, why in adq.flagged.items():
            st = status[name]
            status[name] = dataclasses.replace(st, status="uncertain", reason=why)
    verdict = identifiability(model, status, data, intervals)  # may downgrade statuses (too little sliding)
    if adq is not None and not adq.adequate:
        lead = "" if verdict.startswith("model inadequate") else "model inadequate: "
        verdict = (verdict + "; " if verdict != "identified" else "") + lead + adq.summary()
    return FrictionFit(
        model=model,
        params=MappingProxyType(params),
        std=MappingProxyType({n: float(s_) for n, s_ in zip(names, std)}),
        interval95=MappingProxyType(intervals),
        covariance=_ro(covariance),
        condition_number=est.condition_number,
        condition_number_unscaled=est.condition_number_unscaled,
        fit_percent_estimation=fit_percent(data.force[keep], y_hat[keep]),
        fit_percent_holdout=holdout_fit,
        relative_error_percent=_relative_error(data.force[keep], y_hat[keep]),
        holdout=float(holdout),
        n_samples=m,
        n_raw_samples=data.n_raw,
        filter=data.settings,
        inertia_nominal=None if inertia is None else float(inertia),
        constrained=est.constrained,
        active_constraints=est.active,
        solver=est.solver,
        std_iid=MappingProxyType({n: float(s_) for n, s_ in zip(names, std_iid)}),
        status=MappingProxyType(status),
        identifiability=verdict,
        n_samples_used=m_used,
        selection=data.selection,
        hac_lags=est.lags,
        scales=scales,
        zoh_force=bool(zoh_force),
        adequacy=adq,
        std_method=MappingProxyType({n: float(v) for n, v in zip(names, std_method)} if me and me.std else {}),
    )


def _log_or_arrays(log: Any, position: np.ndarray | None, force: np.ndarray | None) -> FrictionLog:
    """A FrictionLog from a log object, or from ``(t, position, force)`` arrays (the older form)."""
    if position is None and force is None:
        return friction_log(log)
    if position is None or force is None:
        raise ParameterError("give a log, or all of t, position and force", name="position", value=None)
    return FrictionLog(t=_check_array("t", log), position=_check_array("position", position),
                       force=_check_array("force", force))


def fit_data(fit: FrictionFit, log: Any, position: np.ndarray | None = None, force: np.ndarray | None = None,
             *, velocity: np.ndarray | None = None) -> IdentificationData:
    """Prepare a log exactly as `fit` prepared its own (same filters, nominal inertia, sample rule).

    Parameters
    ----------
    fit : FrictionFit
        Gives the filter settings and the nominal inertia.
    log : Experiment, AxisLog, FrictionLog or ndarray
        The log; or its times [s] when `position` and `force` are given as arrays
        (position [rad], force [N m], explained force as in :func:`fit_friction`).
    position, force : ndarray, shape (n,), optional
        See `log`.
    velocity : ndarray, shape (n,), optional
        Measured velocity [rad/s].

    Returns
    -------
    IdentificationData
        Decimated data, e.g. for :func:`forecast_design.plotting.friction.plot_friction_fit`.
    """
    data = _log_or_arrays(log, position, force)
    rate = _rate_from_time(_check_array("t", data.t))
    settings = dataclasses.replace(fit.filter, rate_hz=rate)
    f = zoh_align(_check_array("force", data.force)) if fit.zoh_force else data.force
    rule = fit.selection.rule if fit.selection is not None else "off"
    step = fit.scales.encoder_step if fit.scales is not None else None
    return prepare_identification_data(data.t, data.position, f, fit.model, velocity=velocity,
                                       inertia=fit.inertia_nominal, settings=settings, selection=rule,
                                       encoder_step=step)


def predict_data(fit: FrictionFit, data: IdentificationData) -> np.ndarray:
    """Force predicted by `fit` on prepared data.

    Parameters
    ----------
    fit : FrictionFit
        The fit.
    data : IdentificationData
        From :func:`fit_data` or :func:`prepare_identification_data`.

    Returns
    -------
    ndarray, shape (m,)
        Predicted force [N m] on the decimated grid.
    """
    return _predict_data(fit.model, fit.params, data)


def validate(fit: FrictionFit, log: Any, position: np.ndarray | None = None, force: np.ndarray | None = None,
             *, velocity: np.ndarray | None = None) -> FrictionValidation:
    """Cross-test a fit on a second log with the same filtering.

    Parameters
    ----------
    fit : FrictionFit
        The fit to test.
    log : Experiment, AxisLog, FrictionLog or ndarray
        The second log (the fit's nominal inertia is subtracted again); or its
        times [s] with `position` [rad] and `force` [N m] given as arrays.
    position, force : ndarray, shape (n,), optional
        See `log`.
    velocity : ndarray, shape (n,), optional
        Measured velocity [rad/s].

    Returns
    -------
    FrictionValidation
        Relative error ``100 ||y - y_hat|| / ||y||`` [%] and fit [%] on the
        samples the fit's sample rule keeps in this log.
    """
    data = fit_data(fit, log, position, force, velocity=velocity)
    y_hat = _predict_data(fit.model, fit.params, data)
    k = data.used
    return FrictionValidation(relative_error_percent=_relative_error(data.force[k], y_hat[k]),
                              fit_percent=fit_percent(data.force[k], y_hat[k]), n_samples=int(k.sum()))


@_lsq.one_blas_thread   # the scale check and the validation too, not only the fits (fit_friction's own rule)
def identify(log: Any, model: FrictionModel | str = "extended-sfm", *, harmonics: int | None = None,
             offset: bool | None = None, estimate_inertia: bool = False, holdout: float = 0.3,
             validation_log: Any = None, selection: SampleSelection | str = "auto",
             **fit_options: Any) -> FrictionFit:
    """Identify friction from one log and optionally cross-test it on another (the ``identify`` verb).

    Parameters
    ----------
    log : Experiment, AxisLog or FrictionLog
        The estimation log. On an SEA experiment the explained torque is
        tau_frc = tau_m - J_m theta'' - tau_s [N m] with the nominal J_m unless
        `estimate_inertia`; on an axis log, force = inertia x'' + friction.
    model : FrictionModel or str
        A model (e.g. ``Viscous() + Coulomb() + Harmonics(n=4)``) or one of
        :data:`~forecast_design.friction.MODEL_NAMES`.
    harmonics : int, optional
        Angle harmonics N when `model` is a name that has them.
    offset : bool, optional
        Add a constant offset term [N m] when `model` is a name. Default (None): on when the
        log is an SEA experiment whose ``tau_s`` column carries a constant beyond
        ``k_log (theta - q)`` (:attr:`forecast_design.tau_s_source.TauSSource.zero_offset`: a
        torque sensor's zero, or one the logger applied): unfitted, it leaks into the angle
        harmonics (a 0.03 N m zero moved a 0.02 N m cos1 by 50 %, its interval missing the truth,
        on an independent log); off otherwise.
    estimate_inertia : bool
        Estimate the inertia (always on for a log without a nominal one).
    holdout : float
        Fraction of the log's end held out for the hold-out fit % [-].
    validation_log : Experiment, AxisLog or FrictionLog, optional
        Second log for the relative error 100 ||y - y_hat|| / ||y|| [%].
    selection : SampleSelection or str
        Sample selection rule (``"auto"``, ``"on"``, ``"off"``), see
        :mod:`forecast_design.friction.selection`.
    **fit_options
        Passed to :func:`fit_friction` (``settings``, ``constrain``, ``velocity``...).

    Returns
    -------
    FrictionFit
        The fit (parameters on the whole log), with ``validation`` when a second
        log is given; ``status``/``not_identified`` say which numbers are estimates.
    """
    data = friction_log(log)
    wants_inertia = estimate_inertia or data.inertia is None
    if offset is None:
        offset = tau_s_zero_offset(log)
    if isinstance(model, str):
        fm = friction_model(model, harmonics=harmonics, offset=offset, estimate_inertia=wants_inertia)
    else:
        fm = _resolve_model(model)
        if wants_inertia and "inertia" not in fm.names:
            fm = Inertia() + fm
    fit_options.setdefault("scales", data.scales)
    with _naming(data.source):
        fit = fit_friction(data.t, data.position, data.force, fm,
                           inertia=None if "inertia" in fm.names else data.inertia,
                           holdout=holdout, selection=selection, **fit_options)
        fit = tau_s_scale_check(log, fit, fm, fit_friction, holdout=holdout, selection=selection, **fit_options)
    if validation_log is not None:
        vdata = friction_log(validation_log)
        with _naming(vdata.source):
            fit = fit.with_validation(validate(fit, vdata))
    return fit


@contextlib.contextmanager
def _naming(source: str):
    """Errors about a log's data name the log's file (a one-line error a user can act on)."""
    try:
        yield
    except ForecastError as exc:
        message = str(exc)
        if source not in ("arrays", "experiment") and not message.startswith(source):
            exc.args = (f"{source}: {message}",) + exc.args[1:]
        raise
