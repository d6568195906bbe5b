"""Results of a friction identification: the fit with its uncertainty and status, and validation scores.

:class:`FrictionFit` is what :func:`~forecast_design.friction.identify.fit_friction` returns;
:func:`fit_percent` and :class:`FrictionValidation` score a fit on data.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..errors import IllConditionedWarning
from ..plausibility import LogScales, ParameterStatus
from .derivatives import FilterSettings
from .selection import SelectionResult
from .terms import FrictionModel

__all__ = ["FrictionFit", "FrictionValidation", "IdentificationData", "IllConditionedWarning", "fit_percent",
           "not_identifiable_mapping"]


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Normalised fit, ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``.

    Parameters
    ----------
    y : ndarray
        Measured force [N m].
    y_hat : ndarray
        Predicted force [N m].

    Returns
    -------
    float
        Fit [%]; 100 is perfect, 0 is as good as the mean, negative is worse.
    """
    y = np.asarray(y, dtype=float)
    den = float(np.linalg.norm(y - y.mean()))
    if den == 0.0:
        return float("nan")
    return 100.0 * (1.0 - float(np.linalg.norm(y - np.asarray(y_hat))) / den)


def _relative_error(y: np.ndarray, y_hat: np.ndarray) -> float:
    den = float(np.linalg.norm(y))
    return float("nan") if den == 0.0 else 100.0 * float(np.linalg.norm(y - y_hat)) / den


@dataclass(frozen=True, slots=True, kw_only=True)
class IdentificationData:
    """Filtered, decimated samples a fit works on.

    Parameters
    ----------
    force : ndarray, shape (m,)
        Force explained by the model [N m] (measured force minus a known
        inertia times acceleration).
    velocity, position, acceleration : ndarray, shape (m,)
        Decimated kinematics [rad/s], [rad], [rad/s^2].
    regressor : ndarray, shape (m, p_lin)
        Decimated regressor of the model's linear terms.
    dt : float
        Sample period after decimation [s].
    settings : FilterSettings
        How the data were made.
    n_raw : int
        Raw samples in the log [-].
    keep : ndarray of bool, shape (m,), optional
        Samples a static fit uses (away from stops and reversals, see
        :mod:`forecast_design.friction.selection`); default all.
    selection : SelectionResult, optional
        What the sample selection did.
    encoder_step : float
        Position resolution used for the speed threshold [rad] (or [m]).
    static_keep : ndarray of bool, optional
        For LuGre (which keeps every sample): the samples the static rule
        would keep, used by its Stribeck start.
    sliding : ndarray of bool, shape (m,), optional
        Samples that slide, away from stops and reversals: what the sample rule would keep
        if it were on (:mod:`forecast_design.friction.selection`), whatever its mode. The
        information a static friction law is identified from; checked on every path.
    force_filtered, regressor_filtered : ndarray, optional
        For LuGre: the force and the regressor (but the inertia column) low-passed
        by the position filter, ``lowpass(force) - inertia theta''``. The
        measured friction reaches the fit through the filtered acceleration,
        i.e. low-passed; LuGre compares it with its low-passed simulation.
    """

    force: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    acceleration: np.ndarray
    regressor: np.ndarray
    dt: float
    settings: FilterSettings
    n_raw: int
    keep: np.ndarray | None = None
    selection: SelectionResult | None = None
    encoder_step: float = 0.0
    static_keep: np.ndarray | None = None
    sliding: np.ndarray | None = None
    force_filtered: np.ndarray | None = None
    regressor_filtered: np.ndarray | None = None

    @property
    def used(self) -> np.ndarray:
        """Boolean mask of the samples a fit uses (all when no selection)."""
        return np.ones(self.force.size, dtype=bool) if self.keep is None else self.keep

    def head(self, n: int) -> "IdentificationData":
        """The first `n` decimated samples."""
        return dataclasses.replace(
            self, force=self.force[:n], velocity=self.velocity[:n], position=self.position[:n],
            acceleration=self.acceleration[:n], regressor=self.regressor[:n],
            keep=None if self.keep is None else self.keep[:n],
            static_keep=None if self.static_keep is None else self.static_keep[:n],
            sliding=None if self.sliding is None else self.sliding[:n],
            force_filtered=None if self.force_filtered is None else self.force_filtered[:n],
            regressor_filtered=None if self.regressor_filtered is None else self.regressor_filtered[:n])


@dataclass(frozen=True, slots=True, kw_only=True)
class FrictionValidation:
    """Cross-test of a fit on a second log (same filtering).

    Parameters
    ----------
    relative_error_percent : float
        ``100 ||y - y_hat|| / ||y||`` [%] (the EMPS reference's measure).
    fit_percent : float
        ``100 (1 - ||y - y_hat|| / ||y - mean y||)`` [%].
    n_samples : int
        Decimated samples compared [-].
    """

    relative_error_percent: float
    fit_percent: float
    n_samples: int

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"relative_error_percent": self.relative_error_percent, "fit_percent": self.fit_percent,
                "n_samples": self.n_samples}


def _json_float(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _ro(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, slots=True, kw_only=True)
class FrictionFit:
    """Identified friction model.

    Parameters
    ----------
    model : FrictionModel
        The model that was fitted.
    params : mapping of str to float
        Estimates in natural units (``viscous`` [N m s/rad], ``coulomb`` [N m],
        ``inertia`` [kg m^2], ``stribeck_velocity`` [rad/s], ``sigma0`` [N m/rad] ...).
    std : mapping of str to float
        Standard deviations, same units: the noise's, from a Newey-West (HAC) sandwich
        that follows the residuals' actual autocorrelation, and the method's own error
        (``std_method``) added in quadrature; NaN for a parameter held on a bound of the
        fit (it has no interval).
    interval95 : mapping of str to (float, float)
        95 % confidence intervals (Student t on ``std``; on the log scale
        for ``stribeck_velocity`` and ``sigma0``).
    covariance : ndarray, shape (p, p)
        HAC parameter covariance in the order of ``model.names``, with ``std_method``
        squared added to its diagonal.
    condition_number : float
        Condition number of the column-scaled regressor (or Jacobian) [-].
    condition_number_unscaled : float
        Condition number of the raw regressor (the EMPS reference's figure) [-].
    fit_percent_estimation : float
        Fit of the returned parameters on the whole log [%].
    fit_percent_holdout : float or None
        Out-of-sample fit on the held-out tail [%] of a refit on the head; None
        without holdout.
    relative_error_percent : float
        ``100 ||y - y_hat|| / ||y||`` on the whole log [%].
    holdout : float
        Fraction of the log held out for the holdout score [-].
    n_samples : int
        Decimated samples available [-].
    n_raw_samples : int
        Samples in the raw log [-].
    filter : FilterSettings
        Filtering and decimation.
    inertia_nominal : float or None
        Known inertia whose ``J theta''`` was subtracted from the force [kg m^2].
    constrained : bool
        True when physical constraints changed the estimate (or, for LuGre,
        are active at the optimum).
    active_constraints : tuple of str
        The active constraints, e.g. ``("viscous >= 0",)``.
    solver : mapping
        Solver summary (``method``, and for nonlinear fits ``return_status``, ``iter_count``).
    validation : FrictionValidation or None
        Cross-test on a second log, when done.
    std_iid : mapping of str to float
        The classical IDIM standard deviations ``sigma^2 (Phi^T Phi)^-1`` (white
        residuals assumed), for comparison with published IDIM tables.
    status : mapping of str to ParameterStatus
        Every parameter graded by :mod:`forecast_design.plausibility`:
        ``identified``, ``at_bound``, ``uncertain`` or ``implausible`` with a reason.
    identifiability : str
        ``"identified"``, ``"partly identified: ..."`` or ``"not identifiable: ..."``
        (one line).
    n_samples_used : int
        Decimated samples the fit used after the sample selection [-].
    selection : SelectionResult or None
        What the sample selection did (:mod:`forecast_design.friction.selection`).
    hac_lags : int
        Newey-West bandwidth of the covariance [decimated samples].
    scales : LogScales or None
        The log's magnitudes the plausible ranges came from.
    zoh_force : bool
        The force was a zero-order-hold command, averaged over consecutive samples.
    adequacy : Adequacy or None
        Structure left in the residual (direction, speed, angle) and its whiteness
        (:mod:`forecast_design.friction.adequacy`); None when not tested.
    std_method : mapping of str to float
        The method's own error, same units: the larger shift of each estimate when the whole
        analysis is repeated at half the rate and at half the position filter's cut-off
        (:func:`~forecast_design.friction.method_error.method_error`); empty when not estimated.
    """

    model: FrictionModel
    params: Mapping[str, float]
    std: Mapping[str, float]
    interval95: Mapping[str, tuple[float, float]]
    covariance: np.ndarray
    condition_number: float
    condition_number_unscaled: float
    fit_percent_estimation: float
    fit_percent_holdout: float | None
    relative_error_percent: float
    holdout: float
    n_samples: int
    n_raw_samples: int
    filter: FilterSettings
    inertia_nominal: float | None = None
    constrained: bool = False
    active_constraints: tuple[str, ...] = ()
    solver: Mapping[str, Any] = field(default_factory=dict)
    validation: FrictionValidation | None = None
    std_iid: Mapping[str, float] = field(default_factory=dict)
    status: Mapping[str, ParameterStatus] = field(default_factory=dict)
    identifiability: str = ""
    n_samples_used: int = 0
    selection: SelectionResult | None = None
    hac_lags: int = 0
    scales: LogScales | None = None
    zoh_force: bool = False
    adequacy: Any = None
    std_method: Mapping[str, float] = field(default_factory=dict)

    @property
    def identified(self) -> bool:
        """True when every parameter is ``identified`` (an estimate, not a flag)."""
        return all(st.identified for st in self.status.values())

    @property
    def not_identified(self) -> tuple[str, ...]:
        """Names of the parameters that are not ``identified``, in model order."""
        return tuple(n for n, st in self.status.items() if not st.identified)

    def predict(self, velocity: np.ndarray, position: np.ndarray | None = None,
                acceleration: np.ndarray | None = None, *, dt: float | None = None) -> np.ndarray:
        """Force predicted with the fitted parameters.

        Parameters
        ----------
        velocity : ndarray, shape (n,)
            Velocity [rad/s].
        position : ndarray, shape (n,), optional
            Position [rad] (harmonic terms).
        acceleration : ndarray, shape (n,), optional
            Acceleration [rad/s^2] (inertia term).
        dt : float, optional
            Sample period [s] (LuGre).

        Returns
        -------
        ndarray, shape (n,)
            Force [N m].
        """
        return self.model.predict(self.params, velocity, position, acceleration, dt=dt)

    def with_validation(self, validation: FrictionValidation) -> "FrictionFit":
        """A copy carrying `validation` (see :func:`validate`)."""
        return dataclasses.replace(self, validation=validation)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping.

        Returns
        -------
        dict
            ``{"model", "params", "std", "interval95", "fit_percent": {"estimation",
            "holdout"}, "relative_error_percent", "condition_number",
            "condition_number_unscaled", "n_samples", "n_samples_used", "n_raw_samples",
            "holdout", "filter", "selection", "covariance", "std_iid", "std_method", "status",
            "not_identified", "identified", "identifiability", "scales", "zoh_force",
            "inertia_nominal", "constrained", "active_constraints", "solver", "adequacy"}`` plus
            ``"validation": {"relative_error_percent", ...}`` when validated. Non-finite
            numbers (the std of a parameter held on a bound) are None.
        """
        out: dict[str, Any] = {
            "model": self.model.name,
            "params": dict(self.params),
            "std": {k: _json_float(v) for k, v in self.std.items()},
            "interval95": {k: [_json_float(lo), _json_float(hi)] for k, (lo, hi) in self.interval95.items()},
            "std_iid": {k: _json_float(v) for k, v in self.std_iid.items()},
            "std_method": {k: _json_float(v) for k, v in self.std_method.items()},
            "status": {k: st.to_mapping() for k, st in self.status.items()},
            "not_identified": list(self.not_identified),
            "identified": self.identified,
            "identifiability": self.identifiability,
            "fit_percent": {"estimation": self.fit_percent_estimation, "holdout": self.fit_percent_holdout},
            "relative_error_percent": self.relative_error_percent,
            "condition_number": self.condition_number,
            "condition_number_unscaled": self.condition_number_unscaled,
            "n_samples": self.n_samples,
            "n_samples_used": self.n_samples_used,
            "n_raw_samples": self.n_raw_samples,
            "holdout": self.holdout,
            "filter": self.filter.to_mapping(),
            "selection": None if self.selection is None else self.selection.to_mapping(),
            "covariance": {"method": "Newey-West (Bartlett, VAR(1) prewhitened, Andrews bandwidth) + the "
                                     "method's error (std_method) squared on the diagonal",
                           "lags": self.hac_lags},
            "scales": None if self.scales is None else self.scales.to_mapping(),
            "zoh_force": self.zoh_force,
            "inertia_nominal": self.inertia_nominal,
            "constrained": self.constrained,
            "active_constraints": list(self.active_constraints),
            "solver": dict(self.solver),
            "adequacy": None if self.adequacy is None else self.adequacy.to_mapping(),
        }
        if self.validation is not None:
            out["validation"] = self.validation.to_mapping()
        return out


def not_identifiable_mapping(model: FrictionModel, error: Any) -> dict[str, Any]:
    """The JSON answer of a log that cannot identify a model: every parameter ``not_identifiable``, with the reasons.

    Parameters
    ----------
    model : FrictionModel
        The model asked for.
    error : IdentifiabilityError
        What the log lacks (its message, ``parameters`` and ``reasons``).

    Returns
    -------
    dict
        ``{"model", "identified": False, "identifiability": "not identifiable: ...", "params": {},
        "std": {}, "interval95": {}, "status": {name: {"value": None, "std": None, "status":
        "not_identifiable", "reason"}}, "not_identified", "reasons", "exit_code": 3}``.
    """
    from ..errors import EXIT_NOT_IDENTIFIABLE

    message = str(error).splitlines()[0] if str(error) else "not identifiable"
    verdict = "not identifiable: " + message.replace("not identifiable: ", "", 1)
    reasons = list(getattr(error, "reasons", ()) or (message,))
    names = list(model.names)
    return {"model": model.name, "identified": False, "identifiability": verdict, "params": {}, "std": {},
            "interval95": {}, "status": {n: {"value": None, "std": None, "status": "not_identifiable",
                                             "reason": message} for n in names},
            "not_identified": names, "reasons": reasons, "exit_code": EXIT_NOT_IDENTIFIABLE}
