"""Is the fitted friction model adequate? Structure left in its residual, and its whiteness.

A least-squares fit returns tight intervals for whatever model it is given: plain SFM on
friction whose levels differ by direction gave ``identified`` parameters whose intervals
excluded both true levels (6 of 6 independent logs). After every fit of a static model the
residual is therefore tested for the structure a richer model of the toolbox would explain:

``direction``
    the friction columns (Coulomb, viscous, the Stribeck curve's) copied for negative motion
    only: levels that differ by direction (``--model asymmetric``);
``speed``
    a Stribeck bump ``sign(v) exp(-(v / v_s)^2)`` at the best of a few ``v_s`` between the
    encoder's speed resolution and the log's typical speed (Bonferroni over them): a
    breakaway level above the Coulomb level (``--model stribeck``), for models without one;
``angle``
    the motor angle's harmonics ``sin(i theta), cos(i theta)`` (cogging, ``--model
    extended-sfm``) and ``sign(v) sin(i theta), sign(v) cos(i theta)`` (friction that varies
    with the angle, ``--model position-friction``), i = 1..4, for a log that turns at least a
    revolution and a model without them.

Each is a Wald test (prewhitened Newey-West covariance, :func:`~forecast_design.friction._lsq.
group_wald_p`) of the added columns in the regression of the residual on the model's own
columns (its Jacobian for Stribeck) and the added ones, made orthogonal to the model's first
(a column the model already spans carries no test). A structure is *significant* at
``alpha / n_tests``. It then decides nothing by itself (a long log finds any small misfit
significant): a parameter is downgraded to ``uncertain`` only when the richer model moves
it outside its own 95 % interval (the richer model's values, per direction for
``direction``, are the fit with the added columns, first order for Stribeck), with the
reason naming the structure and the model the data ask for.

Whiteness is reported as MATLAB's ``resid`` does: the residual's autocorrelation at lags
1..25 and its cross-correlation with the velocity (the friction's input) at lags 0..25 against
the 99 % band ``2.58 / sqrt(N)``. Residuals of filtered, decimated data are not white; the
intervals come from a covariance that accounts for it (Newey-West), so whiteness is
information, not a verdict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..plausibility import ParameterStatus, speed_resolution
from ._lsq import group_wald_p
from .terms import AsymmetricCoulomb, Coulomb, FrictionModel, Harmonics, Inertia, LuGre, Offset, PositionFriction, Stribeck

__all__ = ["Adequacy", "StructureTest", "Whiteness", "check_adequacy", "ADEQUACY_ALPHA", "RESID_LAGS"]

#: Family-wise level of the structure tests (Bonferroni over the tests made) [-].
ADEQUACY_ALPHA = 0.01
#: Lags of the whiteness test (MATLAB ``resid``'s default M = 25) [decimated samples].
RESID_LAGS = 25
#: Harmonic orders of the angle test [-].
ANGLE_ORDERS = 4
#: Stribeck velocities tried by the speed test [-].
SPEED_GRID = 16


@dataclass(frozen=True, slots=True, kw_only=True)
class StructureTest:
    """One structure test of the residual.

    Parameters
    ----------
    name : str
        ``direction``, ``speed`` or ``angle``.
    p_value : float or None
        Wald p-value of the added columns [-]; None when not tested (see ``note``).
    suggests : str
        The model whose terms the added columns are (the ``--model`` to fit), or ``""``.
    note : str
        Why not tested, or what the structure is.
    moved : Mapping[str, tuple of float]
        For each parameter of the fitted model, its value(s) under the richer model (two for
        ``direction``: positive and negative motion).
    significant : bool
        ``p_value < alpha / n_tests``.
    """

    name: str
    p_value: float | None
    suggests: str = ""
    note: str = ""
    moved: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    significant: bool = False

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"p_value": self.p_value, "significant": self.significant, "suggests": self.suggests or None,
                "note": self.note, "moved": {k: list(v) for k, v in self.moved.items()}}


@dataclass(frozen=True, slots=True, kw_only=True)
class Whiteness:
    """MATLAB ``resid``-style whiteness of a residual.

    Parameters
    ----------
    lags : int
        Lags tested [decimated samples].
    bound99 : float
        The 99 % band of a white residual's correlation, ``2.58 / sqrt(N)`` [-].
    autocorrelation_outside : int
        Lags 1..lags whose autocorrelation lies outside the band [-].
    max_autocorrelation : float
        Largest |autocorrelation| over those lags [-].
    cross_outside : int
        Lags 0..lags whose cross-correlation with the velocity lies outside the band [-].
    max_cross : float
        Largest |cross-correlation| [-].
    """

    lags: int
    bound99: float
    autocorrelation_outside: int
    max_autocorrelation: float
    cross_outside: int
    max_cross: float

    @property
    def white(self) -> bool:
        """True when every autocorrelation lag lies inside the 99 % band."""
        return self.autocorrelation_outside == 0

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"lags": self.lags, "bound99": self.bound99, "white": self.white,
                "autocorrelation_outside": self.autocorrelation_outside,
                "max_autocorrelation": self.max_autocorrelation, "cross_outside": self.cross_outside,
                "max_cross_correlation": self.max_cross,
                "note": "filtered, decimated residuals are not white; the intervals use a Newey-West covariance"}


@dataclass(frozen=True, slots=True, kw_only=True)
class Adequacy:
    """The adequacy of one fitted model.

    Parameters
    ----------
    tests : tuple of StructureTest
        The structure tests.
    whiteness : Whiteness or None
        The residual's whiteness.
    flagged : Mapping[str, str]
        Parameters the richer model moves outside their interval, with the reason.
    alpha : float
        Family-wise level of the tests [-].
    """

    tests: tuple[StructureTest, ...]
    whiteness: Whiteness | None
    flagged: Mapping[str, str] = field(default_factory=dict)
    alpha: float = ADEQUACY_ALPHA

    @property
    def suggested(self) -> tuple[str, ...]:
        """The richer models the data ask for (significant structures that move a parameter)."""
        names = []
        for t in self.tests:
            if t.significant and t.suggests and any(t.name in r for r in self.flagged.values()):
                names.append(t.suggests)
        return tuple(dict.fromkeys(names))

    @property
    def adequate(self) -> bool:
        """True when no parameter is moved outside its interval by a significant structure."""
        return not self.flagged

    def summary(self) -> str:
        """One line for the fit's identifiability verdict ('' when adequate)."""
        if self.adequate:
            return ""
        models = " or ".join(f"--model {m}" for m in self.suggested) or "a richer model"
        return (f"the residual has structure the model lacks "
                f"({', '.join(t.name for t in self.tests if t.significant)}); the data ask for {models}")

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping: ``adequate``, ``rule``, ``suggested``, ``tests``, ``whiteness``, ``flagged``, ``alpha``."""
        return {"adequate": self.adequate, "rule": ADEQUACY_RULE, "suggested": list(self.suggested), "alpha": self.alpha,
                "tests": {t.name: t.to_mapping() for t in self.tests},
                "whiteness": None if self.whiteness is None else self.whiteness.to_mapping(),
                "flagged": dict(self.flagged)}


#: How ``adequate`` is decided, for the JSON: a significant structure alone is not enough.
ADEQUACY_RULE = ("inadequate when a structure test is significant at alpha and the richer model it suggests moves a "
                 "fitted parameter outside its 95 % interval (listed in 'flagged'); a significant structure that "
                 "moves nothing leaves the model adequate for its parameters")


def whiteness(residual: np.ndarray, velocity: np.ndarray, lags: int = RESID_LAGS) -> Whiteness:
    """Autocorrelation and cross-correlation with the velocity of a residual, as MATLAB's ``resid``.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        The residual [N m] (rows the fit did not use set to zero).
    velocity : ndarray, shape (n,)
        The input [rad/s].
    lags : int
        Largest lag [samples].

    Returns
    -------
    Whiteness
        Counts of lags outside the 99 % band and the largest correlations.
    """
    e = np.asarray(residual, dtype=float)
    u = np.asarray(velocity, dtype=float)
    n = e.size
    e = e - e.mean()
    u = u - u.mean()
    band = 2.58 / math.sqrt(max(n, 1))
    den_e = float(e @ e)
    den_u = float(u @ u)
    L = max(1, min(int(lags), n // 4))
    if den_e <= 0.0 or n < 8:
        return Whiteness(lags=L, bound99=band, autocorrelation_outside=0, max_autocorrelation=0.0,
                         cross_outside=0, max_cross=0.0)
    acf = np.array([float(e[k:] @ e[:n - k]) / den_e for k in range(1, L + 1)])
    ccf = (np.array([float(e[k:] @ u[:n - k]) for k in range(0, L + 1)]) / math.sqrt(den_e * den_u)
           if den_u > 0 else np.zeros(L + 1))
    return Whiteness(lags=L, bound99=band, autocorrelation_outside=int(np.sum(np.abs(acf) > band)),
                     max_autocorrelation=float(np.max(np.abs(acf))), cross_outside=int(np.sum(np.abs(ccf) > band)),
                     max_cross=float(np.max(np.abs(ccf))))


def _columns(model: FrictionModel, params: Mapping[str, float], data: Any) -> np.ndarray:
    """The model's own columns (its Jacobian at the estimate), in ``model.names`` order."""
    if model.nonlinear_term is None:
        return np.asarray(data.regressor, dtype=float)
    from .nonlinear import _stribeck_jacobian

    p = np.array([params[n] for n in model.names], dtype=float)
    return _stribeck_jacobian(p, np.asarray(data.regressor, dtype=float), np.asarray(data.velocity, dtype=float))


def _added_fit(J: np.ndarray, Z: np.ndarray, r: np.ndarray, rows: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Wald p of the columns Z added to J in the regression of the residual r, the shift of J's coefficients
    (``-B c``) and Z's coefficients ``c`` (Frisch-Waugh: Z made orthogonal to J on the fit rows)."""
    Ju, Zu = J[rows], Z[rows]
    B = np.linalg.lstsq(Ju, Zu, rcond=None)[0] if J.shape[1] else np.zeros((0, Z.shape[1]))
    Zp = Z - J @ B if J.shape[1] else Z.copy()
    scale = np.sqrt(np.sum(Z[rows] ** 2, axis=0))
    kept = np.sqrt(np.sum(Zp[rows] ** 2, axis=0)) > 1e-6 * np.where(scale > 0, scale, 1.0)
    c = np.zeros(Z.shape[1])
    if not np.any(kept):
        return 1.0, np.zeros(J.shape[1]), c
    c[kept] = np.linalg.lstsq(Zp[rows][:, kept], r[rows], rcond=None)[0]
    A = np.column_stack([J, Zp[:, kept]])
    coef = np.concatenate([np.zeros(J.shape[1]), c[kept]])
    res = r - Zp[:, kept] @ c[kept]
    p = group_wald_p(A, res, coef, np.arange(J.shape[1], A.shape[1]), keep=rows)
    return p, -(B @ c) if J.shape[1] else np.zeros(0), c


def check_adequacy(model: FrictionModel, params: Mapping[str, float], status: Mapping[str, ParameterStatus],
                   intervals: Mapping[str, tuple[float, float]], data: Any, residual: np.ndarray, *,
                   alpha: float = ADEQUACY_ALPHA) -> Adequacy:
    """Test a fitted model's residual for direction, speed and angle structure (see the module docstring).

    Parameters
    ----------
    model : FrictionModel
        The fitted model.
    params : Mapping[str, float]
        Its estimates.
    status : Mapping[str, ParameterStatus]
        Their statuses (a parameter on a bound keeps its column out of the tests).
    intervals : Mapping[str, (float, float)]
        Their 95 % intervals.
    data : IdentificationData
        The prepared log the fit used.
    residual : ndarray, shape (m,)
        ``force - prediction`` on the prepared log [N m].
    alpha : float
        Family-wise level [-].

    Returns
    -------
    Adequacy
        The tests, the whiteness and the parameters a significant structure moves outside their
        interval (with the reason).
    """
    rows = np.asarray(data.used, dtype=bool)
    r = np.asarray(residual, dtype=float)
    v = np.asarray(data.velocity, dtype=float)
    th = np.asarray(data.position, dtype=float)
    white = whiteness(np.where(rows, r, 0.0), np.where(rows, v, 0.0))
    if isinstance(model.nonlinear_term, LuGre):
        note = "not tested: LuGre is dynamic (its residual is an output error, not an equation error)"
        return Adequacy(tests=tuple(StructureTest(name=n, p_value=None, note=note)
                                    for n in ("direction", "speed", "angle")), whiteness=white, alpha=alpha)
    names = list(model.names)
    J = _columns(model, params, data)
    free = np.array([status[n].status not in ("at_bound",) and np.all(np.isfinite(J[:, i]))
                     for i, n in enumerate(names)], dtype=bool)
    Jf = J[:, free]
    fnames = [n for n, f in zip(names, free) if f]
    structural = {n for t in model.terms if not isinstance(t, (Inertia, Offset, Harmonics)) for n in t.names()}
    sgn = np.sign(v)
    plans: list[tuple[str, str, str, list[tuple[str, np.ndarray]] | None]] = []
    # direction: each friction column again, for negative motion only
    if model.has(AsymmetricCoulomb):
        plans.append(("direction", "", "not tested: the model's levels already depend on the direction", None))
    else:
        cols = [(n, Jf[:, j] * (v < 0.0)) for j, n in enumerate(fnames) if n in structural]
        suggests = "asymmetric" if not isinstance(model.nonlinear_term, Stribeck) else ""
        plans.append(("direction", suggests, "" if suggests else "no model of the toolbox has direction-dependent "
                      "Stribeck levels", cols or None))
    # speed: a Stribeck bump, for models without one
    if isinstance(model.nonlinear_term, Stribeck):
        plans.append(("speed", "", "not tested: the model has a Stribeck curve", None))
    elif not (model.has(Coulomb) or model.has(AsymmetricCoulomb)):
        plans.append(("speed", "", "not tested: the model has no Coulomb level", None))
    else:
        sel = np.abs(v[rows])
        res_v = speed_resolution(float(data.encoder_step), data.settings.rate_hz, data.settings.position_cutoff_hz)
        hi = float(np.percentile(sel, 50)) if sel.size else 0.0
        lo = 4.0 * res_v   # twice the sample rule's stop threshold: a bump below it has no sliding sample
        if hi > 2.0 * lo:
            grid = np.geomspace(lo, hi, SPEED_GRID)
            plans.append(("speed", "stribeck", "", [(f"bump at v_s = {g:.3g}", sgn * np.exp(-(v / g) ** 2))
                                                   for g in grid]))
        else:
            plans.append(("speed", "", "not tested: the log slides at too few distinct speeds", None))
    # angle: harmonics of the motor angle
    span = float(np.ptp(th)) if th.size else 0.0
    if span < 2.0 * math.pi:
        plans.append(("angle", "", f"not tested: the motor turns through {span:.2g} rad, less than a revolution",
                      None))
    else:
        cols = []
        if not model.has(Harmonics):
            cols += [(f"{f.__name__}{i}", f(i * th)) for i in range(1, ANGLE_ORDERS + 1) for f in (np.sin, np.cos)]
        if not model.has(PositionFriction):
            cols += [(f"sign(v) {f.__name__}{i}", sgn * f(i * th)) for i in range(1, ANGLE_ORDERS + 1)
                     for f in (np.sin, np.cos)]
        if cols:
            which = "position-friction" if model.has(Harmonics) else "extended-sfm"
            plans.append(("angle", which, "", cols))
        else:
            plans.append(("angle", "", "not tested: the model has both kinds of angle harmonics", None))
    n_tests = max(1, sum(p[3] is not None for p in plans))
    # marginal tests first; structures significant together are then re-tested each given the others'
    # columns (an angle-dependent torque also loads the direction copies of a sweep that turns back)
    sd = np.array([status[n].std if status[n].std is not None and np.isfinite(status[n].std) and status[n].std > 0
                   else np.inf for n in fnames])
    first = {name: _structure(name, cols, Jf, fnames, params, r, rows, model, sd) for name, _, _, cols in plans
             if cols is not None}
    joint = [name for name, res in first.items() if res[0] < alpha / n_tests]
    tests: list[StructureTest] = []
    flagged: dict[str, str] = {}
    for name, suggests, note, cols in plans:
        if cols is None:
            tests.append(StructureTest(name=name, p_value=None, suggests="", note=note))
            continue
        p, moved, label, which = first[name]
        if name in joint and len(joint) > 1:
            others = [c for other, _, _, ocols in plans if other in joint and other != name
                      for c in _nuisance(other, ocols, first[other][2])]
            # significance given the other structures; the values under the richer model stay its own
            Jn = np.column_stack([Jf] + others)
            p = _structure(name, cols, Jn, fnames + [""] * len(others), params, r, rows, model, sd)[0]
        note = note or label
        suggests = which or suggests
        significant = bool(p < alpha / n_tests)
        tests.append(StructureTest(name=name, p_value=float(p), suggests=suggests, note=note, moved=moved,
                                   significant=significant))
        if not significant:
            continue
        for n, values in moved.items():
            lo, hi = intervals.get(n, (math.nan, math.nan))
            st = status[n]
            if not (math.isfinite(lo) and math.isfinite(hi)) or st.status not in ("identified", "uncertain"):
                continue
            if any(not lo <= x <= hi for x in values):
                shown = " / ".join(f"{x:.4g}" for x in values)
                where = " (positive / negative motion)" if len(values) == 2 else ""
                model_hint = f"--model {suggests}" if suggests else "a richer model"
                why = (f"the residual depends on the {_WHAT[name]} (p = {p:.2g}); under {model_hint} {n} would be "
                       f"{shown}{where}, outside its 95 % interval [{lo:.4g}, {hi:.4g}]")
                flagged[n] = f"{flagged[n]}; {why}" if n in flagged else f"model inadequate: {why}"
    return Adequacy(tests=tuple(tests), whiteness=white, flagged=flagged, alpha=alpha)


def _structure(name: str, cols: list, J: np.ndarray, fnames: list[str], params: Mapping[str, float], r: np.ndarray,
               rows: np.ndarray, model: FrictionModel,
               scale: np.ndarray | None = None) -> tuple[float, dict[str, tuple[float, ...]], str, str]:
    """One structure test: (p, the parameters' values under the richer model, a label, the model it suggests)."""
    label, which = "", ""
    if name == "speed":
        # one bump at a time, Bonferroni over the grid. A low-speed remnant of the stops is often the most
        # significant bump and moves nothing, a true Stribeck decay further up moves the levels: among the
        # significant bumps the one that moves the model's parameters most (in their own standard units)
        # decides, the most significant one otherwise
        fits = []
        for lab, col in cols:
            p, shift, c = _added_fit(J, col[:, None], r, rows)
            fits.append((min(1.0, p * len(cols)), shift, c, lab))
        sig = [f for f in fits if f[0] < 0.01]
        if sig and scale is not None:
            p, shift, c, lab = max(sig, key=lambda f: float(np.max(np.abs(f[1][:len(scale)]) / scale)))
        else:
            p, shift, c, lab = min(fits, key=lambda f: f[0])
        label = f"a Stribeck {lab} rad/s"
        moved = {n: (float(params[n] + shift[j]),) for j, n in enumerate(fnames) if n}
        return p, moved, label, which
    p, shift, c = _added_fit(J, np.column_stack([col for _, col in cols]), r, rows)
    if name == "angle":
        cog = float(np.abs(c[:2 * ANGLE_ORDERS]).sum()) if not model.has(Harmonics) else 0.0
        posf = float(np.abs(c[-2 * ANGLE_ORDERS:]).sum()) if not model.has(PositionFriction) else 0.0
        which = "position-friction" if posf > cog else "extended-sfm"
        label = "harmonics of the motor angle"
        # the values under the model suggested: its own harmonics only (both kinds together trade the
        # Coulomb level against sign(v) harmonics over a revolution or two)
        own = [col for lab, col in cols if lab.startswith("sign(v)") == (which == "position-friction")]
        if len(own) < len(cols):
            _, shift, _ = _added_fit(J, np.column_stack(own), r, rows)
        return p, {n: (float(params[n] + shift[j]),) for j, n in enumerate(fnames) if n}, label, which
    copies = {n: k for k, (n, _) in enumerate(cols)}
    moved = {}
    for j, n in enumerate(fnames):
        if not n:
            continue
        base = float(params[n] + shift[j])
        moved[n] = (base, base + float(c[copies[n]])) if n in copies else (base,)
    return p, moved, "the friction levels for negative motion", which


def _nuisance(name: str, cols: list, label: str) -> list[np.ndarray]:
    """The columns of a significant structure, kept as nuisance while another is tested."""
    if name == "speed":
        return [col for lab, col in cols if label.endswith(f"{lab} rad/s")][:1]
    return [col for _, col in cols]


_WHAT = {"direction": "direction of motion", "speed": "speed (a Stribeck curve)", "angle": "motor angle"}
