"""Stribeck and LuGre fits as casadi/ipopt nonlinear programs.

Stribeck
    Output is static in the velocity, so the fit is a nonlinear least-squares
    problem in (linear terms, F_s, F_c, log v_s, viscous). Given v_s the model is
    linear, so the start is the best linear fit over a log-spaced grid of v_s
    (variable projection), refined by ipopt. If the optimum is unphysical
    (F_c < 0, F_s < F_c, viscous < 0) the problem at the found v_s is re-solved as
    a convex QP with cvxpy under those constraints and flagged.
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
    millisecond. The recursion is a casadi ``mapaccum`` (single shooting) and
    ipopt optimises (log sigma0, sigma1, F_c, F_s - F_c, log v_s, sigma2) with
    the physical bounds (sigma1, F_c, F_s - F_c, sigma2 >= 0) always imposed,
    since g(v) must stay positive for the bristle equation to exist. The start
    is the Stribeck fit plus a grid over sigma0. The initial state is the
    steady state of the first sample.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import casadi as ca
import numpy as np

from ..errors import ParameterError, SolverError
from . import _lsq
from .terms import FrictionModel, LuGre, Stribeck, lugre_force

__all__ = ["NonlinearResult", "fit_nonlinear", "IPOPT_OPTIONS"]

#: Quiet ipopt (the project's convention).
IPOPT_OPTIONS = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
_KNOWN_OPTIONS = ("max_iter", "sigma0_init")


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


def _solve_nlp(x: ca.MX, f: ca.MX, x0: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, what: str,
               max_iter: int, *, hess_lag: ca.Function | None = None,
               grad_f: ca.Function | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    opts = dict(IPOPT_OPTIONS)
    if hess_lag is not None:
        opts["hess_lag"] = hess_lag
    if grad_f is not None:
        opts["grad_f"] = grad_f
    opts["ipopt.max_iter"] = int(max_iter)
    solver = ca.nlpsol(f"friction_{what}", "ipopt", {"x": x, "f": f}, opts)
    sol = solver(x0=x0, lbx=lbx, ubx=ubx)
    st = solver.stats()
    summary = {"method": f"ipopt ({what})", "return_status": str(st.get("return_status")),
               "iter_count": int(st.get("iter_count", -1)), "success": bool(st.get("success"))}
    if not st.get("success"):
        raise SolverError(f"{what} friction fit: ipopt did not converge ({st.get('return_status')}, "
                          f"{st.get('iter_count')} iterations)", stats=summary)
    return np.asarray(sol["x"], dtype=float).ravel(), summary


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


def _stribeck_basis(v: np.ndarray, vs: float) -> tuple[np.ndarray, np.ndarray]:
    sgn = np.sign(v)
    return sgn, np.exp(-((v / vs) ** 2)) * sgn


def _grid_vs(data, Phi: np.ndarray) -> tuple[float, np.ndarray]:
    """Best v_s on a log grid with the rest linear; returns v_s and [lin, F_c, F_s - F_c, viscous]."""
    v, y = data.velocity, data.force
    vmax = float(np.max(np.abs(v)))
    best = (np.inf, None, None)
    for vs in np.geomspace(1e-3 * vmax, 0.5 * vmax, 40):
        sgn, e = _stribeck_basis(v, vs)
        W = np.column_stack([Phi, sgn, e, v])
        s = np.linalg.norm(W, axis=0)
        s[s == 0] = 1
        p = np.linalg.lstsq(W / s, y, rcond=None)[0] / s
        sse = float(np.sum((y - W @ p) ** 2))
        if sse < best[0]:
            best = (sse, vs, p)
    return float(best[1]), best[2]


def _fit_stribeck(model: FrictionModel, data, *, constrain: bool, max_iter: int) -> NonlinearResult:
    Phi, y, v = data.regressor, data.force, data.velocity
    L = Phi.shape[1]
    vs0, p0 = _grid_vs(data, Phi)
    sgn, e0 = _stribeck_basis(v, vs0)
    # natural parameters: [lin..., static, coulomb, stribeck_velocity, viscous]
    W0 = np.column_stack([Phi, e0, sgn * (1 - np.exp(-((v / vs0) ** 2))), v])
    sc = _scales(W0, y)
    x = ca.MX.sym("x", L + 4)
    p_lin = x[:L] * sc[:L]
    Fs, Fc, visc = x[L] * sc[L], x[L + 1] * sc[L + 1], x[L + 3] * sc[L + 2]
    vs = vs0 * ca.exp(x[L + 2])
    vd, sd = ca.DM(v), ca.DM(sgn)
    F = (Fc + (Fs - Fc) * ca.exp(-(vd / vs) ** 2)) * sd + visc * vd
    if L:
        F = F + ca.mtimes(ca.DM(Phi), p_lin)
    ny2 = max(float(y @ y), 1e-300)
    f = 0.5 * ca.sumsqr(F - ca.DM(y)) / ny2
    lin0, c0, d0, visc0 = p0[:L], p0[L], p0[L + 1], p0[L + 2]
    x0 = np.concatenate([lin0 / sc[:L], [(c0 + d0) / sc[L], c0 / sc[L + 1], 0.0, visc0 / sc[L + 2]]])
    lim = np.log(1e3)
    lbx = np.full(L + 4, -np.inf)
    ubx = np.full(L + 4, np.inf)
    lbx[L + 2], ubx[L + 2] = -lim, lim
    xo, summary = _solve_nlp(x, f, x0, lbx, ubx, "stribeck", max_iter)
    p_nat = np.concatenate([xo[:L] * sc[:L], [xo[L] * sc[L], xo[L + 1] * sc[L + 1],
                                               vs0 * np.exp(xo[L + 2]), xo[L + 3] * sc[L + 2]]])
    if abs(xo[L + 2]) > lim - 1e-6:
        summary["note"] = "stribeck_velocity reached its search bound (1e3 x the grid start)"
    J = _stribeck_jacobian(p_nat, Phi, v)
    r = y - _stribeck_predict(p_nat, Phi, v)
    lin_nonneg = _lin_nonneg(model)
    Fs_, Fc_, vs_, visc_ = p_nat[L:]
    violated = (Fc_ < 0) or (Fs_ < Fc_) or (visc_ < 0) or bool(np.any(lin_nonneg & (p_nat[:L] < 0)))
    if not (constrain and violated):
        cov, cond, cond_raw = _jacobian_stats(J, r)
        return NonlinearResult(p_nat, cov, cond, cond_raw, False, (), summary)
    # Convex re-solve at the found v_s: columns [lin, F_c, F_s - F_c, viscous], all >= 0 but lin.
    sgn, e = _stribeck_basis(v, vs_)
    W = np.column_stack([Phi, sgn, e, v])
    mask = np.concatenate([lin_nonneg, [True, True, True]])
    q, act = _lsq.solve_nonneg_lstsq(W, y, mask)
    labels = [f"{n} >= 0" for n in model.linear_names] + ["coulomb >= 0", "static >= coulomb", "viscous >= 0"]
    active = tuple(lbl for lbl, a in zip(labels, act) if a) + ("stribeck_velocity fixed",)
    p_nat = np.concatenate([q[:L], [q[L] + q[L + 1], q[L], vs_, q[L + 2]]])
    r = y - W @ q
    cov_q = _lsq.ls_covariance(W, r, ~act)
    T = np.zeros((L + 4, L + 3))  # natural = T @ [lin, Fc, delta, visc]
    T[:L, :L] = np.eye(L)
    T[L, L] = T[L, L + 1] = 1.0
    T[L + 1, L] = 1.0
    T[L + 3, L + 2] = 1.0
    cov = T @ cov_q @ T.T
    _, cond, cond_raw = _jacobian_stats(W, r)
    summary = dict(summary, method=summary["method"] + " + cvxpy constrained least squares at fixed v_s")
    return NonlinearResult(p_nat, cov, cond, cond_raw, True, active, summary)


def _stribeck_predict(p: np.ndarray, Phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    L = Phi.shape[1]
    Fs, Fc, vs, visc = p[L:]
    out = (Fc + (Fs - Fc) * np.exp(-((v / vs) ** 2))) * np.sign(v) + visc * v
    return out + Phi @ p[:L] if L else out


def _stribeck_jacobian(p: np.ndarray, Phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """d F / d [lin, static, coulomb, stribeck_velocity, viscous] (closed form)."""
    L = Phi.shape[1]
    Fs, Fc, vs, _ = p[L:]
    sgn = np.sign(v)
    e = np.exp(-((v / vs) ** 2))
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
    g = Fc + (Fs - Fc) * ca.exp(-(v / vs) ** 2)
    w1 = (w + h * s0 * v) / (1 + h * s0 * ca.fabs(v) / g)
    S1 = ca.jacobian(w1, w) * S + ca.jacobian(w1, p).T
    W1 = ca.SX.sym("W1")  # F's partial derivatives are taken with w+ held as a symbol
    F_of = W1 + (s1 / s0) * (W1 - w) / h + s2 * v
    dF_of = ca.jacobian(F_of, W1) * S1 + ca.jacobian(F_of, w) * S + ca.jacobian(F_of, p).T
    F, dF = ca.substitute([F_of, dF_of], [W1], [w1])
    return ca.Function("lugre_step", [ca.vertcat(w, S), v, p], [ca.vertcat(w1, S1), ca.vertcat(F, dF)])


def _lugre_simulator(h: float, v: np.ndarray) -> ca.Function:
    """Function p (6) -> (F (m), dF/dp (m x 6)) along the velocity samples `v`."""
    m = v.size
    p = ca.SX.sym("p", 6)
    g0 = p[3] + (p[2] - p[3]) * ca.exp(-(v[0] / p[4]) ** 2)
    w0 = g0 * float(np.sign(v[0]))
    F0 = w0 + p[5] * float(v[0])
    head = ca.Function("lugre_start", [p], [ca.vertcat(w0, ca.jacobian(w0, p).T),
                                            ca.vertcat(F0, ca.jacobian(F0, p).T)])
    pm = ca.MX.sym("p", 6)
    x0, out0 = head(pm)
    _, out = _lugre_casadi(h).mapaccum("lugre_sim", m - 1)(x0, ca.DM(v[1:]).T, pm)
    allout = ca.horzcat(out0, out)  # 7 x m
    return ca.Function("lugre_force", [pm], [allout[0, :].T, allout[1:, :].T])


def _fit_lugre(model: FrictionModel, data, *, max_iter: int, sigma0_init: float | None) -> NonlinearResult:
    Phi, y, v, h = data.regressor, data.force, data.velocity, data.dt
    L, m = Phi.shape[1], y.size
    # Start: Stribeck fit on the same data, then a grid over sigma0.
    strib = _fit_stribeck(FrictionModel(terms=model.linear_terms + (Stribeck(),)), data,
                          constrain=True, max_iter=max_iter)
    lin0 = strib.params[:L]
    Fs0, Fc0, vs0, visc0 = strib.params[L:]
    Fc0 = max(Fc0, 1e-3 * max(Fs0, 1e-12))
    Fs0 = max(Fs0, Fc0)
    P = L + 6
    sim = _lugre_simulator(h, v)

    def force_and_jacobian(p_):
        Fb, Jb = sim(p_[L:])
        if L:
            return Fb + ca.mtimes(ca.DM(Phi), p_[:L]), ca.horzcat(ca.DM(Phi), Jb)
        return Fb, Jb

    if sigma0_init is None:
        v_typ = float(np.median(np.abs(v[np.abs(v) > 0]))) if np.any(v != 0) else 1.0
        best = (np.inf, None)
        for tau in h * np.geomspace(0.1, 100.0, 10):
            s0 = Fc0 / (tau * v_typ)
            F = lugre_force(v, h, sigma0=s0, sigma1=0.0, static=Fs0, coulomb=Fc0,
                            stribeck_velocity=vs0, viscous=visc0) + (Phi @ lin0 if L else 0.0)
            sse = float(np.sum((y - F) ** 2))
            if sse < best[0]:
                best = (sse, s0)
        sigma0_init = best[1]
    elif not sigma0_init > 0:
        raise ParameterError(f"sigma0_init must be > 0 [N m/rad], got {sigma0_init!r}", name="sigma0_init",
                             value=sigma0_init)
    s0i = float(sigma0_init)
    sF = max(Fs0, 1e-12)
    sv = max(visc0, 1e-3 * sF / max(float(np.max(np.abs(v))), 1e-12))
    s1i = 0.0
    # decision x = [lin/sc, log(s0/s0i), s1/sv, Fc/sF, (Fs-Fc)/sF, log(vs/vs0), visc/sv]
    sc_lin = _scales(Phi, y) if L else np.zeros(0)
    x = ca.MX.sym("x", P)
    nat = ca.vertcat(x[:L] * sc_lin if L else ca.MX(0, 1),
                     s0i * ca.exp(x[L]), x[L + 1] * sv, (x[L + 2] + x[L + 3]) * sF, x[L + 2] * sF,
                     vs0 * ca.exp(x[L + 4]), x[L + 5] * sv)
    ny2 = max(float(y @ y), 1e-300)
    Fx, Jx = force_and_jacobian(nat)
    r = Fx - ca.DM(y)
    Jr = ca.mtimes(Jx, ca.jacobian(nat, x))
    f = 0.5 * ca.sumsqr(r) / ny2
    # Gauss-Newton: gradient J^T r and Hessian J^T J from the sensitivity recursion.
    p_empty, lam_f, lam_g = ca.MX.sym("p", 0), ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0)
    grad = ca.Function("nlp_grad_f", [x, p_empty], [f, ca.mtimes(Jr.T, r) / ny2],
                       ["x", "p"], ["f", "grad_f_x"])
    hess = ca.Function("nlp_hess_l", [x, p_empty, lam_f, lam_g],
                       [ca.triu(lam_f * ca.mtimes(Jr.T, Jr) / ny2)],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    x0 = np.concatenate([lin0 / np.where(sc_lin > 0, sc_lin, 1.0) if L else np.zeros(0),
                         [0.0, s1i / sv, Fc0 / sF, (Fs0 - Fc0) / sF, 0.0, visc0 / sv]])
    lim = np.log(1e4)
    lbx = np.full(L + 6, -np.inf)
    ubx = np.full(L + 6, np.inf)
    lin_nonneg = _lin_nonneg(model)
    lbx[:L][lin_nonneg] = 0.0
    lbx[L], ubx[L] = -lim, lim
    lbx[L + 1] = 0.0
    lbx[L + 2] = 1e-6
    lbx[L + 3] = 0.0
    lbx[L + 4], ubx[L + 4] = -np.log(1e3), np.log(1e3)
    lbx[L + 5] = 0.0
    xo, summary = _solve_nlp(x, f, x0, lbx, ubx, "lugre", max_iter, hess_lag=hess, grad_f=grad)
    summary["simulation"] = (f"backward Euler single shooting (casadi mapaccum), h = {h:g} s, "
                             "Gauss-Newton Hessian")
    summary["sigma0_init"] = s0i
    p_nat = np.asarray(ca.Function("nat", [x], [nat])(xo), dtype=float).ravel()
    labels = ([f"{n} >= 0" for n in model.linear_names]
              + ["sigma0 within 1e4 of its start", "sigma1 >= 0", "coulomb > 0", "static >= coulomb",
                 "stribeck_velocity within 1e3 of its start", "viscous >= 0"])
    tol = 1e-4  # scaled units; ipopt's interior point stops just inside a bound
    at_bound = (np.isfinite(lbx) & (xo <= lbx + tol)) | (np.isfinite(ubx) & (xo >= ubx - tol))
    active = tuple(lbl for lbl, a in zip(labels, at_bound) if a)
    F_opt, J_opt = force_and_jacobian(ca.DM(p_nat))
    J = np.asarray(J_opt, dtype=float)
    r = y - np.asarray(F_opt, dtype=float).ravel()
    free = ~at_bound
    free[L + 3] = True  # static >= coulomb: static itself stays free
    cov, cond, cond_raw = _jacobian_stats(J, r, free)
    # report in model.names order: lin..., sigma0, sigma1, static, coulomb, stribeck_velocity, viscous
    return NonlinearResult(p_nat, cov, cond, cond_raw, bool(active), active, summary)


def fit_nonlinear(model: FrictionModel, data, *, constrain: bool = True, **options: Any) -> NonlinearResult:
    """Fit a model with a Stribeck or LuGre term (see the module docstring).

    Parameters
    ----------
    model : FrictionModel
        Model with exactly one nonlinear term.
    data : IdentificationData
        Decimated data (:func:`~forecast_design.friction.identify.prepare_identification_data`).
    constrain : bool
        Re-solve an unphysical Stribeck optimum under constraints (LuGre is
        always bounded).
    **options
        ``max_iter`` (ipopt iterations, default 500), ``sigma0_init`` (LuGre start
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
        return _fit_stribeck(model, data, constrain=constrain, max_iter=max_iter)
    if isinstance(term, LuGre):
        return _fit_lugre(model, data, max_iter=max_iter, sigma0_init=options.get("sigma0_init"))
    raise ParameterError(f"no nonlinear fit for term {type(term).__name__}", name="model")
