"""Stribeck and LuGre fits: variable projection, and a bounded Gauss-Newton on casadi sensitivities.

Stribeck
    Output is static in the velocity, and for a fixed Stribeck velocity v_s
    the model ``(F_c + (F_s - F_c) exp(-(v/v_s)^2)) sign v + viscous v`` (+ the
    linear terms) is linear in the rest. The fit is a *variable projection*:
    the residual of the best (bounded: F_c, F_s - F_c, viscous >= 0 when
    constrained) linear fit is profiled over 48 log-spaced v_s between the
    plausibility bounds (:func:`forecast_design.plausibility.friction_bound`:
    two encoder speed steps to the largest speed), and the best grid cell is
    refined by a bounded 1-D Brent search. The optimum is exact in the linear
    parameters and needs no start; a v_s on a grid end is returned *on* the
    end and reported ``at_bound`` (the data push it beyond the range the log
    can resolve). With ``F_s = F_c`` the profile is flat and v_s undefined
    (``uncertain``); a 95 % profile interval that runs to an end of the range
    makes v_s ``uncertain`` too. The friction levels are bounded by their
    plausible range. Standard deviations come from the full Jacobian at the
    optimum (v_s included) with a Newey-West sandwich
    (:func:`forecast_design.friction._lsq.hac_covariance`); v_s's interval is
    computed on log v_s.
LuGre
    Output-error fit: the bristle state is simulated along the measured
    velocity and the simulated force is matched to the measured one. The state
    is carried in force units, w = sigma0 z, and stepped with backward Euler,
    which is explicit here because dz/dt is linear in z::

        w+ = (w + h sigma0 v+) / (1 + h sigma0 |v+| / g(v+))
        F+ = w+ + (sigma1 / sigma0) (w+ - w) / h + sigma2 v+

    with g(v) = F_c + (F_s - F_c) exp(-(v/v_s)^2), on the decimated grid
    (h = decimation_factor / rate_hz); the step is stable for any h, which
    matters because the bristle time constant g / (sigma0 |v|) is often below a
    millisecond. The recursion, with its parameter sensitivities, is a casadi
    ``mapaccum`` (single shooting). The measured friction reaches the fit
    through the acceleration of the low-passed position, i.e. low-passed
    itself, so the simulated force is low-passed by the same zero-phase
    Butterworth before the two are compared (a *filtered* output error; the
    unfiltered comparison biases the curve towards a smooth one at
    reversals). scipy's ``least_squares`` (trf, Gauss-Newton with the
    sensitivity Jacobian) optimises (log sigma0, sigma1, F_c, F_s - F_c,
    log v_s, sigma2) with the physical bounds (sigma1, F_c, F_s - F_c,
    sigma2 >= 0) always imposed, since g(v) must stay positive for the bristle
    equation to exist; sigma0 and v_s search their plausible ranges. The
    start is the best of a (v_s, sigma0) grid, each v_s with its Stribeck
    curve fitted away from the stops (candidates whose sums of squares tie,
    as every v_s of a collapsed curve does, go to the v_s nearest the typical
    sliding speed, not to rounding). The initial state is the steady state
    of the first sample, and the residual counts from the first gross sliding
    on (the bristle state before it is unknown). A converged solver is not a
    verdict on the numbers: :func:`~forecast_design.friction.fit_friction`
    grades every parameter with :mod:`forecast_design.plausibility`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import casadi as ca
import numpy as np
from scipy.optimize import least_squares, lsq_linear, minimize_scalar

from ..discrete import njit
from ..errors import ParameterError, SolverError
from ..plausibility import speed_resolution
from . import _lsq
from .derivatives import lowpass
from .laws import clipped_exp, stribeck_decay, stribeck_level
from .terms import FrictionModel, LuGre, Stribeck

__all__ = ["NonlinearResult", "fit_nonlinear", "IPOPT_OPTIONS"]

#: Quiet ipopt (the friction fits themselves no longer use ipopt; the Q tuner's NLP does).
#: casadi/ipopt options that keep the solver silent (no iteration log, no timing table, no banner):
#: every ``nlpsol(..., "ipopt", ...)`` of the package starts from these, so a successful command
#: prints nothing of the solver's on stderr/stdout (``tests/test_reliability_fuzz.py``).
IPOPT_OPTIONS = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
_KNOWN_OPTIONS = ("max_iter", "sigma0_init")
#: Iterations of the Stribeck start of a LuGre fit (not the user's limit).
_START_ITER = 500


@dataclass(frozen=True, slots=True)
class NonlinearResult:
    """Outcome of a nonlinear friction fit (parameters in ``model.names`` order)."""

    params: np.ndarray
    covariance: np.ndarray
    condition_number: float
    condition_number_unscaled: float
    constrained: bool
    active: tuple[str, ...]
    solver: Mapping[str, Any] = field(default_factory=dict)
    #: i.i.d. covariance sigma^2 (J^T J)^-1 of the same fit (the classical figure)
    covariance_iid: np.ndarray | None = None
    #: parameters held on a bound of the search, with that search range (lo, hi)
    held: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    #: Newey-West bandwidth [samples] and median std inflation over i.i.d. [-]
    lags: int = 0
    inflation: float = 1.0
    #: statuses decided by the fit itself: name -> (status, reason)
    overrides: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    #: parameters whose 95 % interval is computed on the log scale (strictly positive)
    log_scale: tuple[str, ...] = ()


def _scales(W: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Parameter scales that make every column contribute O(||y||)."""
    n = np.sqrt(np.einsum("ij,ij->j", W, W))
    ny = max(float(np.linalg.norm(y)), 1e-300)
    return np.where(n > 0, ny / np.where(n > 0, n, 1.0), 1.0)


def _jacobian_stats(J: np.ndarray, r: np.ndarray, free: np.ndarray | None = None):
    cov = _lsq.ls_covariance(J, r, free)
    s = np.sqrt(np.einsum("ij,ij->j", J, J))
    s[s == 0] = 1.0
    cond = _lsq.scaled_conditioning((J / s).T @ (J / s))[0]
    lam = np.linalg.eigvalsh(J.T @ J)
    cond_raw = float(np.sqrt(lam[-1] / lam[0])) if lam[0] > 0 else float("inf")
    return cov, cond, cond_raw


# --- Stribeck ---------------------------------------------------------------------------

#: Points of the log-spaced v_s grid the Stribeck profile is evaluated on [-].
STRIBECK_GRID = 48


def _decay(v: np.ndarray, vs: float) -> np.ndarray:
    """exp(-(v/v_s)^2), flushed to zero beyond 7 v_s (avoids slow subnormal exponentials)."""
    return stribeck_decay(v, vs, clipped_exp)


def _stribeck_basis(v: np.ndarray, vs: float) -> tuple[np.ndarray, np.ndarray]:
    sgn = np.sign(v)
    return sgn, _decay(v, vs) * sgn


class _StribeckProfile:
    """Residual of the best linear fit at fixed v_s (variable projection).

    Columns ``[lin..., sign v, exp(-(v/v_s)^2) sign v, v]`` with parameters
    ``[lin..., F_c, F_s - F_c, viscous]``. Only the third column depends on
    v_s, so the normal equations of the other columns are formed once and
    each v_s costs one pass over the samples (O(m p)).
    """

    def __init__(self, Phi: np.ndarray, y: np.ndarray, v: np.ndarray, bounds: np.ndarray | None):
        self.v, self.y = v, y
        self.sgn = np.sign(v)
        self.F = np.column_stack([Phi, self.sgn, v])  # fixed columns
        self.L = Phi.shape[1]
        self.FtF = self.F.T @ self.F
        self.Fty = self.F.T @ y
        self.yty = float(y @ y)
        self.bounds = bounds  # (lb, ub) in [lin..., F_c, delta, viscous] order, or None
        self.evaluations = 0

    def normal(self, vs: float) -> tuple[np.ndarray, np.ndarray]:
        c = _decay(self.v, vs) * self.sgn
        L = self.L
        p = L + 3
        A = np.empty((p, p))
        b = np.empty(p)
        idx = np.r_[np.arange(L + 1), L + 2]  # fixed columns in the full order
        A[np.ix_(idx, idx)] = self.FtF
        Fc = self.F.T @ c
        A[idx, L + 1] = A[L + 1, idx] = Fc
        A[L + 1, L + 1] = float(c @ c)
        b[idx] = self.Fty
        b[L + 1] = float(c @ self.y)
        return A, b

    def solve(self, vs: float) -> tuple[float, np.ndarray, np.ndarray]:
        """SSE, parameters [lin, F_c, delta, viscous] and active-bound flags at this v_s."""
        self.evaluations += 1
        A, b = self.normal(vs)
        s = np.sqrt(np.clip(np.diag(A), 0.0, None))
        s[s == 0] = 1.0
        As = A / np.outer(s, s)
        bs = b / s
        x = np.linalg.lstsq(As, bs, rcond=None)[0]
        active = np.zeros(x.size, dtype=bool)
        if self.bounds is not None:
            lb, ub = self.bounds[0] * s, self.bounds[1] * s
            if np.any(x < lb) or np.any(x > ub):
                lam, vec = np.linalg.eigh(As)
                R = (vec * np.sqrt(np.clip(lam, 0.0, None))).T
                d = np.linalg.lstsq(R.T, bs, rcond=None)[0]
                res = lsq_linear(R, d, bounds=(lb, ub), method="bvls", tol=1e-12)
                x = res.x
                active = res.active_mask != 0
                x = np.where(active, np.where(res.active_mask < 0, lb, ub), x)
        sse = self.yty - 2.0 * float(bs @ x) + float(x @ As @ x)
        return max(sse, 0.0), x / s, active


def _fit_stribeck(model: FrictionModel, data, *, constrain: bool, max_iter: int,
                  vs_bounds: tuple[float, float] | None = None, keep: np.ndarray | None = None,
                  level_max: float | None = None) -> NonlinearResult:
    """Stribeck fit by variable projection over v_s (see the module docstring)."""
    keep = np.ones(data.force.size, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    Phi_all, y_all, v_all = data.regressor, data.force, data.velocity
    Phi, y, v = Phi_all[keep], y_all[keep], v_all[keep]
    L = Phi.shape[1]
    vmax = float(np.max(np.abs(v))) if v.size else 0.0
    lo, hi = (1e-3 * vmax, vmax) if vs_bounds is None else (float(vs_bounds[0]), float(vs_bounds[1]))
    if not (0 < lo < hi and np.isfinite(hi)):
        raise ParameterError(f"Stribeck velocity search range [{lo:.3g}, {hi:.3g}] is empty: the log hardly "
                             "moves", name="stribeck_velocity", value=(lo, hi))
    lin_nonneg = _lin_nonneg(model)
    bounds = None
    if constrain:
        lb = np.concatenate([np.where(lin_nonneg, 0.0, -np.inf), [0.0, 0.0, 0.0]])
        ub = np.full(L + 3, np.inf)
        if level_max is not None and np.isfinite(level_max) and level_max > 0:
            # the friction levels stay in their plausible range: a decay column that only a few
            # samples feel cannot run off to 1e12
            ub[L] = ub[L + 1] = level_max
        bounds = np.vstack([lb, ub])
    prof = _StribeckProfile(Phi, y, v, bounds)
    grid = np.geomspace(lo, hi, STRIBECK_GRID)
    sse = np.array([prof.solve(g)[0] for g in grid])
    i = int(np.argmin(sse))
    a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, grid.size - 1)])
    res = minimize_scalar(lambda u: prof.solve(float(np.exp(u)))[0], bounds=(a, b), method="bounded",
                          options={"xatol": 1e-7, "maxiter": int(max_iter)})
    summary: dict[str, Any] = {
        "method": f"variable projection: profile over {STRIBECK_GRID} log-spaced v_s in [{lo:.3g}, {hi:.3g}] "
                  "+ bounded Brent refinement (scipy minimize_scalar)",
        "success": bool(res.success), "return_status": str(res.message), "iter_count": int(res.nfev),
        "evaluations": prof.evaluations}
    if not res.success:
        raise SolverError(f"stribeck friction fit: the v_s refinement did not converge ({res.message}, "
                          f"{res.nfev} evaluations)", stats=summary)
    vs = float(np.exp(res.x)) if res.fun <= sse[i] else float(grid[i])
    held: dict[str, tuple[float, float]] = {}
    notes: list[str] = []
    u_tol = 1e-4  # on log v_s: closer than this to a grid end counts as on it
    if i == 0 and np.log(vs) - np.log(lo) < u_tol:
        vs = lo
    elif i == grid.size - 1 and np.log(hi) - np.log(vs) < u_tol:
        vs = hi
    _, q, act = prof.solve(vs)
    overrides: dict[str, tuple[str, str]] = {}
    if q[L + 1] <= 0.0:
        # no decay: the profile is flat in v_s, which is then undefined
        vs = float(np.sqrt(lo * hi))
        overrides["stribeck_velocity"] = (
            "uncertain", "static = coulomb: the log shows no Stribeck decay, so stribeck_velocity is undefined")
    if vs in (lo, hi):
        held["stribeck_velocity"] = (lo, hi)
    p_nat = np.concatenate([q[:L], [q[L] + q[L + 1], q[L], vs, q[L + 2]]])
    labels = [f"{n} >= 0" for n in model.linear_names] + ["coulomb >= 0", "static >= coulomb", "viscous >= 0"]
    if bounds is not None:
        for j, name in ((L, "coulomb"), (L + 1, "static - coulomb")):
            if act[j] and q[j] >= bounds[1][j]:
                labels[j] = f"{name} <= {bounds[1][j]:.3g} (plausible friction level)"
    active = tuple(lbl for lbl, a_ in zip(labels, act) if a_)
    nat_names = list(model.linear_names) + ["static", "coulomb", "stribeck_velocity", "viscous"]
    for j in np.flatnonzero(act):
        upper = bounds is not None and q[j] >= bounds[1][j] and np.isfinite(bounds[1][j])
        if j < L:
            held[nat_names[j]] = (0.0, np.inf)
        elif j == L:
            held["coulomb"] = (0.0, float(bounds[1][j])) if upper else (0.0, np.inf)
        elif j == L + 1:
            held["static"] = (float(q[L]), float(q[L] + q[L + 1])) if upper else (float(q[L]), np.inf)
        else:
            held["viscous"] = (0.0, np.inf)
    # Covariance: the full Jacobian at the optimum (v_s included), sandwiched with the residual's autocorrelation.
    J = _stribeck_jacobian(p_nat, Phi_all, v_all)
    r = y_all - _stribeck_predict(p_nat, Phi_all, v_all)
    free = np.array([n not in held for n in nat_names])
    if "stribeck_velocity" in overrides:
        free[L + 2] = False
    if "static" in held:  # static = coulomb: one free level, carried by the coulomb column
        J = J.copy()
        J[:, L + 1] = J[:, L] + J[:, L + 1]
        free[L] = False
        free[L + 1] = "coulomb" not in held
    hac = _lsq.hac_covariance(J, r, free, keep)
    cov = hac.covariance
    cov_iid = hac.iid_covariance
    if "static" in held and free[L + 1]:
        for C in (cov, cov_iid):  # static = coulomb moves with it
            C[L, :] = C[L + 1, :]
            C[:, L] = C[:, L + 1]
    _, cond, cond_raw = _jacobian_stats(J[keep][:, free] if free.any() else J[keep], r[keep])
    # Profile interval of v_s: the grid points whose residual is within chi2(1, 0.95) of the optimum, the
    # residual variance scaled by the sandwich / i.i.d. ratio (correlated residuals). Local Jacobian
    # intervals are too narrow when the profile is flat; a profile interval that runs to an end of the
    # plausible range means v_s is not pinned down by the log.
    sse_opt = prof.solve(vs)[0]
    ratio = hac.inflation ** 2
    if free[L + 2] and cov_iid[L + 2, L + 2] > 0:
        ratio = max(cov[L + 2, L + 2] / cov_iid[L + 2, L + 2], 1.0)
    thr = sse_opt + 3.841 * sse_opt / max(int(keep.sum()) - (L + 4), 1) * ratio
    inside = np.flatnonzero(sse <= thr)
    i_opt = int(np.argmin(np.abs(np.log(grid) - np.log(vs))))
    lo_i, hi_i = i_opt, i_opt
    while lo_i > 0 and sse[lo_i - 1] <= thr:
        lo_i -= 1
    while hi_i < grid.size - 1 and sse[hi_i + 1] <= thr:
        hi_i += 1
    profile_interval = (float(grid[max(lo_i - 1, 0)]) if lo_i > 0 else float(lo),
                        float(grid[min(hi_i + 1, grid.size - 1)]) if hi_i < grid.size - 1 else float(hi))
    if inside.size and (lo_i == 0 or hi_i == grid.size - 1) and "stribeck_velocity" not in overrides \
            and "stribeck_velocity" not in held:
        end = "lower" if lo_i == 0 else "upper"
        overrides["stribeck_velocity"] = (
            "uncertain", f"the residual profile over stribeck_velocity is flat to the {end} end of its plausible "
                         f"range [{lo:.3g}, {hi:.3g}] (95 % profile interval {profile_interval[0]:.3g} .. "
                         f"{profile_interval[1]:.3g})")
        if hi_i == grid.size - 1 and "static" not in overrides and "static" not in held:
            # the static level is the curve's value at rest: a Stribeck decay spread over every
            # speed of the log trades static - coulomb against v_s, so neither is resolved
            overrides["static"] = (
                "uncertain", "static is read off a Stribeck curve whose velocity is not resolved (profile flat up to "
                             f"the upper end of [{lo:.3g}, {hi:.3g}]): the log has too little sliding below the decay "
                             "to separate the breakaway level from coulomb")
    if active:
        summary["method"] += " under bounds (scipy lsq_linear, bvls)"
    summary["profile"] = {"v_s_grid": [float(grid[0]), float(grid[-1])], "sse_min": float(sse.min()),
                          "sse_max": float(sse.max()), "interval95": list(profile_interval)}
    if notes:
        summary["notes"] = notes
    return NonlinearResult(p_nat, cov, cond, cond_raw, bool(active), active, summary,
                           covariance_iid=cov_iid, held=held, lags=hac.lags, inflation=hac.inflation,
                           overrides=overrides, log_scale=("stribeck_velocity",))


def _stribeck_predict(p: np.ndarray, Phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    L = Phi.shape[1]
    Fs, Fc, vs, visc = p[L:]
    out = (Fc + (Fs - Fc) * _decay(v, vs)) * np.sign(v) + visc * v
    return out + Phi @ p[:L] if L else out


def _stribeck_jacobian(p: np.ndarray, Phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """d F / d [lin, static, coulomb, stribeck_velocity, viscous] (closed form)."""
    L = Phi.shape[1]
    Fs, Fc, vs, _ = p[L:]
    sgn = np.sign(v)
    e = _decay(v, vs)
    d_vs = (Fs - Fc) * sgn * e * 2.0 * v**2 / vs**3
    return np.column_stack([Phi, e * sgn, (1.0 - e) * sgn, d_vs, v])


def _lin_nonneg(model: FrictionModel) -> np.ndarray:
    nonneg = {n for t in model.linear_terms for n in t.nonnegative}
    return np.array([n in nonneg for n in model.linear_names], dtype=bool)


# --- LuGre -----------------------------------------------------------------------------


def _lugre_casadi(h: float) -> ca.Function:
    """One backward-Euler step with its forward parameter sensitivities.

    State ``[w, dw/dp]`` (7), output ``[F, dF/dp]`` (7) for p = (sigma0, sigma1,
    static, coulomb, stribeck_velocity, viscous). Carrying the sensitivities in the
    recursion gives the Jacobian in the same pass as the force, which is what the
    Gauss-Newton Hessian needs; casadi's generic AD through a 1e4-step mapaccum
    costs about ten times more.
    """
    w, v = ca.SX.sym("w"), ca.SX.sym("v")
    S = ca.SX.sym("S", 6)
    p = ca.SX.sym("p", 6)
    s0, s1, Fs, Fc, vs, s2 = (p[i] for i in range(6))
    g = stribeck_level(v, Fs, Fc, vs, ca.exp)
    w1 = (w + h * s0 * v) / (1 + h * s0 * ca.fabs(v) / g)
    S1 = ca.jacobian(w1, w) * S + ca.jacobian(w1, p).T
    W1 = ca.SX.sym("W1")  # F's partial derivatives are taken with w+ held as a symbol
    F_of = W1 + (s1 / s0) * (W1 - w) / h + s2 * v
    dF_of = ca.jacobian(F_of, W1) * S1 + ca.jacobian(F_of, w) * S + ca.jacobian(F_of, p).T
    F, dF = ca.substitute([F_of, dF_of], [W1], [w1])
    return ca.Function("lugre_step", [ca.vertcat(w, S), v, p], [ca.vertcat(w1, S1), ca.vertcat(F, dF)])


def _lugre_simulator(h: float, v: np.ndarray) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """p (6) -> (F (m), dF/dp (m x 6)) along the velocity samples `v`.

    casadi writes into numpy arrays (``Function.buffer``): converting its m x 6 outputs to numpy
    went through a Python list of every element, 15 % of a LuGre identification.
    """
    m = v.size
    p = ca.SX.sym("p", 6)
    g0 = stribeck_level(float(v[0]), p[2], p[3], p[4], ca.exp)
    w0 = g0 * float(np.sign(v[0]))
    F0 = w0 + p[5] * float(v[0])
    head = ca.Function("lugre_start", [p], [ca.vertcat(w0, ca.jacobian(w0, p).T),
                                            ca.vertcat(F0, ca.jacobian(F0, p).T)])
    pm = ca.MX.sym("p", 6)
    x0, out0 = head(pm)
    _, out = _lugre_casadi(h).mapaccum("lugre_sim", m - 1)(x0, ca.DM(v[1:]).T, pm)
    allout = ca.horzcat(out0, out)  # 7 x m
    # dense outputs: the buffer holds nonzeros only, and dF/dp has structural zeros (the first sample's
    # bristle state does not depend on sigma0, sigma1)
    buf, run = ca.Function("lugre_force", [pm], [ca.densify(allout[0, :].T), ca.densify(allout[1:, :].T)]).buffer()

    def simulate(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        arg = np.array(params, dtype=float)
        F, dF = np.empty(m), np.empty((6, m))      # dF/dp is column-major in casadi: its transpose in numpy
        buf.set_arg(0, memoryview(arg))
        buf.set_res(0, memoryview(F))
        buf.set_res(1, memoryview(dF))
        run()
        return F, np.ascontiguousarray(dF.T)

    return simulate


def _lugre_force_sets(v: np.ndarray, h: float, s0: np.ndarray, Fs: np.ndarray, Fc: np.ndarray,
                      vs: np.ndarray, visc: np.ndarray) -> np.ndarray:
    """LuGre force (sigma1 = 0) for C parameter sets at once, shape (C, m) (backward Euler, vectorised)."""
    g = stribeck_level(v[None, :], Fs[:, None], Fc[:, None], vs[:, None], clipped_exp)
    g = np.maximum(g, 1e-12)
    A = 1.0 / (1.0 + h * s0[:, None] * np.abs(v)[None, :] / g)
    Z = _bristle_recursion(A, h * v, g[:, 0] * np.sign(v[0]) / s0)
    return s0[:, None] * Z + visc[:, None] * v[None, :]


@njit
def _bristle_recursion(A: np.ndarray, b: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """``Z[:, 0] = z0``, ``Z[:, k] = A[:, k] (Z[:, k - 1] + b[k])``: the start grid's bristle states (compiled:
    a Python loop over the samples was half of a LuGre identification's time)."""
    C, m = A.shape
    Z = np.empty((C, m))
    for c in range(C):
        z = z0[c]
        Z[c, 0] = z
        for k in range(1, m):
            z = A[c, k] * (z + b[k])
            Z[c, k] = z
    return Z


def _lugre_starts(model: FrictionModel, data, strib: NonlinearResult, vs_bounds, keep, sigma0_init, lp, yf,
                  Phif, core):
    """Best (linear params, (F_s, F_c, v_s, viscous), sigma0) on a (v_s, sigma0) grid."""
    Phi, y, v, h = data.regressor, data.force, data.velocity, data.dt
    L = Phi.shape[1]
    keep = np.ones(y.size, dtype=bool) if keep is None else keep
    lin_nonneg = _lin_nonneg(model)
    lb = np.concatenate([np.where(lin_nonneg, 0.0, -np.inf), [0.0, 0.0, 0.0]])
    prof = _StribeckProfile(Phi[keep], y[keep], v[keep], np.vstack([lb, np.full(L + 3, np.inf)]))
    vmax = float(np.max(np.abs(v))) if v.size else 1.0
    lo, hi = (1e-3 * vmax, vmax) if vs_bounds is None else vs_bounds
    cands = [(strib.params[:L], strib.params[L:])]
    for vs in np.geomspace(lo, hi, 12):
        _, q, _ = prof.solve(float(vs))
        cands.append((q[:L], np.array([q[L] + q[L + 1], q[L], vs, q[L + 2]])))
    v_typ = float(np.median(np.abs(v[np.abs(v) > 0]))) if np.any(v != 0) else 1.0
    scored = []
    for lin, (Fs, Fc, vs, visc) in cands:
        Fc = max(Fc, 1e-3 * max(Fs, 1e-12))
        Fs = max(Fs, Fc)
        if sigma0_init is None:
            s0 = Fc / (h * np.geomspace(0.1, 100.0, 10) * v_typ)
        else:
            s0 = np.array([float(sigma0_init)])
        C = s0.size
        F = _lugre_force_sets(v, h, s0, np.full(C, Fs), np.full(C, Fc), np.full(C, vs), np.full(C, visc))
        target = yf - (Phif @ lin if L else 0.0)
        r = (lp(F.T) - target[:, None])[core]
        sse = np.einsum("ij,ij->j", r, r)
        j = int(np.argmin(sse))
        scored.append((float(sse[j]), lin, (Fs, Fc, vs, visc), float(s0[j])))
    # Candidates whose Stribeck hump collapsed (static = coulomb) are one force whatever their v_s: their
    # sums of squares tie to rounding, and the rounding (BLAS threads, CPU) used to pick the v_s the search
    # starts from, at times one far below the sliding speeds, whose hump the search then blew up (static
    # 1e14 N m on tests/test_friction_identify.py's log with one BLAS thread). Ties go to the v_s nearest
    # the typical sliding speed.
    low = min((c[0] for c in scored if c[0] < np.inf), default=np.inf)
    tied = [c for c in scored if c[0] <= low + 1e-9 * abs(low)]
    if not tied:
        return None, None, None
    best = min(tied, key=lambda c: abs(math.log(c[2][2] / v_typ)) if c[2][2] > 0 and v_typ > 0 else math.inf)
    return best[1], best[2], best[3]


def _fit_lugre(model: FrictionModel, data, *, max_iter: int, sigma0_init: float | None,
               vs_bounds: tuple[float, float] | None = None, sigma0_bounds: tuple[float, float] | None = None,
               start_keep: np.ndarray | None = None, start: Mapping[str, float] | None = None) -> NonlinearResult:
    Phi, v, h = data.regressor, data.velocity, data.dt
    # Filtered output error: the measured friction is low-passed by the position filter (through the
    # acceleration), so the simulated friction is low-passed alike before it is compared.
    yf = data.force_filtered if data.force_filtered is not None else data.force
    Phif = data.regressor_filtered if data.regressor_filtered is not None else Phi
    L, m = Phi.shape[1], yf.size
    settings = data.settings
    e = min(settings.edge_samples, max(m // 10, 0))
    core = np.zeros(m, dtype=bool)
    core[e:m - e] = True  # the model's own filter edges are left out
    # The bristle state at the start of the log is unknown (the simulation assumes steady sliding): the
    # residual counts from the first gross sliding on (20 encoder speed resolutions, then 10 ms to settle).
    moving = np.flatnonzero(np.abs(v) > 20.0 * speed_resolution(data.encoder_step, settings.rate_hz,
                                                                settings.position_cutoff_hz))
    if moving.size and moving[0] > 0:
        core[:min(m, moving[0] + int(round(0.01 / h)))] = False

    def lp(X: np.ndarray) -> np.ndarray:
        return lowpass(X, settings) if data.force_filtered is not None else X

    # Start: the best of a grid over (v_s, sigma0), each v_s with the Stribeck curve's linear parameters
    # fitted away from the stops (variable projection), each simulated with sigma1 = 0. (A single
    # Stribeck start is not enough: with fast reversals a Stribeck curve with v_s near the top speed
    # fits the static part as well as the true hump.)
    s1_0 = 0.0
    if start is not None:   # a neighbouring fit's optimum (the method's error): its basin, no grid
        lin0 = np.array([float(start[n]) for n in model.linear_names])
        Fs0, Fc0, vs0, visc0, s0_best, s1_0 = (float(start[n]) for n in ("static", "coulomb", "stribeck_velocity",
                                                                          "viscous", "sigma0", "sigma1"))
    else:
        strib = _fit_stribeck(FrictionModel(terms=model.linear_terms + (Stribeck(),)), data,
                              constrain=True, max_iter=_START_ITER, vs_bounds=vs_bounds, keep=start_keep)
        lin0, (Fs0, Fc0, vs0, visc0), s0_best = _lugre_starts(model, data, strib, vs_bounds, start_keep,
                                                              sigma0_init, lp, yf, Phif, core)
    if sigma0_init is None or start is not None:
        sigma0_init = s0_best
    elif not sigma0_init > 0:
        raise ParameterError(f"sigma0_init must be > 0 [N m/rad], got {sigma0_init!r}", name="sigma0_init",
                             value=sigma0_init)
    s0i = float(sigma0_init)
    if sigma0_bounds is not None:
        s0i = float(np.clip(s0i, *sigma0_bounds))
    sF = max(Fs0, 1e-12)
    sv = max(visc0, 1e-3 * sF / max(float(np.max(np.abs(v))), 1e-12))
    sc_lin = _scales(Phif, yf) if L else np.zeros(0)
    sim = _lugre_simulator(h, v)
    # decision x = [lin/sc, log(s0/s0i), s1/sv, Fc/sF, (Fs-Fc)/sF, log(vs/vs0), visc/sv]
    P = L + 6

    def natural(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Natural parameters [lin, s0, s1, Fs, Fc, vs, visc] and their Jacobian d nat / d x."""
        nat = np.concatenate([x[:L] * sc_lin, [s0i * np.exp(x[L]), x[L + 1] * sv, (x[L + 2] + x[L + 3]) * sF,
                                               x[L + 2] * sF, vs0 * np.exp(x[L + 4]), x[L + 5] * sv]])
        T = np.zeros((P, P))
        T[:L, :L] = np.diag(sc_lin)
        T[L, L] = nat[L]
        T[L + 1, L + 1] = sv
        T[L + 2, L + 2] = T[L + 2, L + 3] = sF
        T[L + 3, L + 2] = sF
        T[L + 4, L + 4] = nat[L + 4]
        T[L + 5, L + 5] = sv
        return nat, T

    cache: dict[str, Any] = {}

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = x.tobytes()
        if cache.get("key") != key:
            nat, T = natural(x)
            Fb, Jb = sim(nat[L:])
            F = lp(Fb)
            Jf = lp(Jb)
            if L:
                F = F + Phif @ nat[:L]
                Jf = np.column_stack([Phif, Jf])
            cache.update(key=key, r=(F - yf)[core], J=(Jf @ T)[core])
        return cache["r"], cache["J"]

    x0 = np.concatenate([lin0 / np.where(sc_lin > 0, sc_lin, 1.0) if L else np.zeros(0),
                         [0.0, s1_0 / sv, Fc0 / sF, (Fs0 - Fc0) / sF, 0.0, visc0 / sv]])
    # sigma0 and v_s search their plausible ranges (forecast_design.plausibility) when given,
    # else within 1e4 (sigma0) and 1e3 (v_s) of their starts.
    s0_lo, s0_hi = (s0i / 1e4, s0i * 1e4) if sigma0_bounds is None else sigma0_bounds
    vs_lo, vs_hi = (vs0 / 1e3, vs0 * 1e3) if vs_bounds is None else vs_bounds
    lbx = np.full(P, -np.inf)
    ubx = np.full(P, np.inf)
    lin_nonneg = _lin_nonneg(model)
    lbx[:L][lin_nonneg] = 0.0
    lbx[L], ubx[L] = np.log(s0_lo / s0i), np.log(s0_hi / s0i)
    lbx[L + 1] = 0.0
    lbx[L + 2] = 1e-6
    lbx[L + 3] = 0.0
    lbx[L + 4], ubx[L + 4] = np.log(vs_lo / vs0), np.log(vs_hi / vs0)
    lbx[L + 5] = 0.0
    x0 = np.clip(x0, lbx + 1e-9, ubx - 1e-9)
    res = least_squares(lambda x: evaluate(x)[0], x0, jac=lambda x: evaluate(x)[1], bounds=(lbx, ubx),
                        method="trf", x_scale="jac", ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=int(max_iter))
    summary: dict[str, Any] = {
        "method": "bounded Gauss-Newton (scipy least_squares, trf) on the filtered output error",
        "return_status": str(res.message), "iter_count": int(res.nfev), "success": bool(res.status > 0),
        "simulation": f"backward Euler along the measured velocity (casadi mapaccum with sensitivities), "
                      f"h = {h:g} s", "sigma0_init": s0i}
    if res.status <= 0:
        raise SolverError(f"lugre friction fit did not converge ({res.message}, {res.nfev} evaluations)",
                          stats=summary)
    xo = res.x
    p_nat, _ = natural(xo)
    labels = ([f"{n} >= 0" for n in model.linear_names]
              + [f"sigma0 in [{s0_lo:.3g}, {s0_hi:.3g}]", "sigma1 >= 0", "coulomb > 0", "static >= coulomb",
                 f"stribeck_velocity in [{vs_lo:.3g}, {vs_hi:.3g}]", "viscous >= 0"])
    at_bound = res.active_mask != 0
    active = tuple(lbl for lbl, a in zip(labels, at_bound) if a)
    r, Jx = evaluate(xo)
    _, T = natural(xo)
    J = Jx @ np.linalg.inv(T)  # Jacobian in natural units
    # decision order [lin, sigma0, sigma1, coulomb, static - coulomb, v_s, viscous];
    # natural (model.names) order [lin, sigma0, sigma1, static, coulomb, v_s, viscous]
    names = list(model.linear_names) + ["sigma0", "sigma1", "static", "coulomb", "stribeck_velocity", "viscous"]
    ranges = [(0.0, np.inf)] * L + [(s0_lo, s0_hi), (0.0, np.inf), (None, None), (1e-6 * sF, np.inf),
                                     (vs_lo, vs_hi), (0.0, np.inf)]
    held: dict[str, tuple[float, float]] = {}
    for j in np.flatnonzero(at_bound):
        if j == L + 3:
            held["static"] = (float(p_nat[L + 3]), np.inf)
        else:
            nat_j = L + 3 if j == L + 2 else j
            held[names[nat_j]] = ranges[nat_j]
    free = np.array([n not in held for n in names])
    if "static" in held:  # static = coulomb: one free level, carried by the coulomb column
        J = J.copy()
        J[:, L + 3] = J[:, L + 3] + J[:, L + 2]
    hac = _lsq.hac_covariance(J, -r, free)
    cov, cov_iid = hac.covariance, hac.iid_covariance
    if "static" in held and free[L + 3]:
        for C in (cov, cov_iid):
            C[L + 2, :] = C[L + 3, :]
            C[:, L + 2] = C[:, L + 3]
    _, cond, cond_raw = _jacobian_stats(J[:, free] if free.any() else J, r)
    return NonlinearResult(p_nat, cov, cond, cond_raw, bool(active), active, summary, covariance_iid=cov_iid,
                           held=held, lags=hac.lags, inflation=hac.inflation,
                           log_scale=("sigma0", "stribeck_velocity"))


def fit_nonlinear(model: FrictionModel, data, *, constrain: bool = True,
                  vs_bounds: tuple[float, float] | None = None, sigma0_bounds: tuple[float, float] | None = None,
                  keep: np.ndarray | None = None, level_max: float | None = None,
                  start: Mapping[str, float] | None = None, **options: Any) -> NonlinearResult:
    """Fit a model with a Stribeck or LuGre term (see the module docstring).

    Parameters
    ----------
    model : FrictionModel
        Model with exactly one nonlinear term.
    data : IdentificationData
        Decimated data (:func:`~forecast_design.friction.identify.prepare_identification_data`).
    constrain : bool
        Bound the Stribeck fit to a physical curve (LuGre is always bounded).
    vs_bounds : (float, float), optional
        Search range of the Stribeck velocity [rad/s] (the plausible range);
        default ``[1e-3, 1] x`` the largest speed.
    sigma0_bounds : (float, float), optional
        Search range of the LuGre bristle stiffness [N m/rad].
    keep : ndarray of bool, optional
        Samples the Stribeck fit (and the Stribeck start of LuGre) uses.
    level_max : float, optional
        Upper bound of the Stribeck fit's Coulomb level and static excess [N m]
        (the plausible friction level).
    start : Mapping[str, float], optional
        LuGre: start from these parameters (natural units, every name of the model) instead
        of the start grid, e.g. a neighbouring analysis' optimum; ignored by Stribeck.
    **options
        ``max_iter`` (Stribeck: Brent iterations; LuGre: function evaluations of
        ``least_squares``; default 500), ``sigma0_init`` (LuGre start
        [N m/rad], default from a grid).

    Returns
    -------
    NonlinearResult
        Parameters in ``model.names`` order, covariance, conditioning, flags.
    """
    unknown = sorted(set(options) - set(_KNOWN_OPTIONS))
    if unknown:
        raise ParameterError(f"unknown nonlinear fit option(s) {', '.join(unknown)}; "
                             f"known: {', '.join(_KNOWN_OPTIONS)}", name=unknown[0])
    max_iter = int(options.get("max_iter", 500))
    term = model.nonlinear_term
    if isinstance(term, Stribeck):
        return _fit_stribeck(model, data, constrain=constrain, max_iter=max_iter, vs_bounds=vs_bounds, keep=keep,
                             level_max=level_max)
    if isinstance(term, LuGre):
        return _fit_lugre(model, data, max_iter=max_iter, sigma0_init=options.get("sigma0_init"),
                          vs_bounds=vs_bounds, sigma0_bounds=sigma0_bounds, start_keep=keep, start=start)
    raise ParameterError(f"no nonlinear fit for term {type(term).__name__}", name="model")
