"""Least-squares kernels shared by the linear and nonlinear friction fits (private)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np
import scipy.linalg

from ..errors import SolverError

__all__ = ["LsqSolution", "solve_lstsq", "solve_nonneg_lstsq", "ls_covariance", "scaled_conditioning"]


@dataclass(frozen=True, slots=True)
class LsqSolution:
    """Solution of min ||W p - y||^2 with its column scaling."""

    params: np.ndarray           # natural units
    scale: np.ndarray            # column norms used for scaling
    normal_scaled: np.ndarray    # (W/s)^T (W/s)
    singular_values: np.ndarray  # of W/s, from its R factor (accurate beyond 1e8)


def _column_scale(W: np.ndarray) -> np.ndarray:
    s = np.sqrt(np.einsum("ij,ij->j", W, W))
    s[s == 0.0] = 1.0
    return s


def solve_lstsq(W: np.ndarray, y: np.ndarray) -> LsqSolution:
    """Solve the least-squares problem with casadi on column-scaled normal equations.

    Scaling every column to unit norm makes the normal matrix's condition number
    the square of the scaled regressor's (about 19 for EMPS instead of 675); the
    p x p solve is casadi's ``solve`` (the sums over samples are numpy BLAS
    products, which casadi's sparse DM would do 100x slower for 1e6 rows).
    """
    s = _column_scale(W)
    Ws = W / s
    A = Ws.T @ Ws
    b = Ws.T @ y
    x = np.asarray(ca.solve(ca.DM(A), ca.DM(b)), dtype=float).ravel()
    sv = np.linalg.svd(np.linalg.qr(Ws, mode="r"), compute_uv=False) if W.shape[1] else np.zeros(0)
    return LsqSolution(params=x / s, scale=s, normal_scaled=A, singular_values=sv)


def scaled_conditioning(A: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Condition number of the scaled regressor from its normal matrix, and the eigenpairs.

    Squaring limits the resolution to about 1e8; :func:`solve_lstsq` also returns
    singular values from the R factor for the rank decision.
    """
    lam, vec = np.linalg.eigh(A)
    lam_min = max(lam[0], 0.0)
    cond = float(np.sqrt(lam[-1] / lam_min)) if lam_min > 0 else float("inf")
    return cond, lam, vec


def ls_covariance(W: np.ndarray, residual: np.ndarray, free: Sequence[bool] | None = None) -> np.ndarray:
    """Covariance sigma^2 (W^T W)^-1 with sigma^2 = ||r||^2 / (n - p_free).

    Parameters held at an active bound (``free[j] == False``) get zero variance;
    the others are computed from the free columns only.
    """
    n, p = W.shape
    free_mask = np.ones(p, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    cov = np.zeros((p, p))
    k = int(free_mask.sum())
    if k == 0:
        return cov
    Wf = W[:, free_mask]
    s = _column_scale(Wf)
    A = (Wf / s).T @ (Wf / s)
    sigma2 = float(residual @ residual) / max(n - k, 1)
    Ainv = np.linalg.pinv(A)
    cov[np.ix_(free_mask, free_mask)] = sigma2 * Ainv / np.outer(s, s)
    return cov


def solve_nonneg_lstsq(W: np.ndarray, y: np.ndarray, nonneg: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """min ||W p - y||^2 subject to p_j >= 0 where `nonneg`, as a cvxpy convex QP.

    The n-row problem is first compressed to p rows with the Cholesky factor of
    the scaled normal matrix (||W x - y||^2 = ||R x - R^-T W^T y||^2 + const), so the
    QP is tiny even for 1e6 samples.

    Returns
    -------
    params : ndarray
        Constrained solution in natural units.
    active : ndarray of bool
        Which nonnegativity constraints are active.
    """
    import cvxpy as cp

    s = _column_scale(W)
    Ws = W / s
    A = Ws.T @ Ws
    b = Ws.T @ y
    try:
        R = scipy.linalg.cholesky(A, lower=False)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(A)
        R = (vec * np.sqrt(np.clip(lam, 0.0, None))).T
    d = np.linalg.lstsq(R.T, b, rcond=None)[0]
    x = cp.Variable(W.shape[1])
    mask = np.asarray(nonneg, dtype=bool)
    cons = [x[np.flatnonzero(mask)] >= 0] if mask.any() else []
    prob = cp.Problem(cp.Minimize(cp.sum_squares(R @ x - d)), cons)
    try:
        prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:  # pragma: no cover - solver failure is rare
        raise SolverError(f"constrained friction least squares failed: {exc}",
                          stats={"status": prob.status}) from exc
    if prob.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or x.value is None:
        raise SolverError(f"constrained friction least squares: cvxpy status {prob.status}",
                          stats={"status": prob.status})
    xs = np.asarray(x.value, dtype=float)
    tol = 1e-7 * max(1.0, float(np.max(np.abs(xs))))
    active = mask & (xs <= tol)
    xs = np.where(active, 0.0, xs)
    return xs / s, active
