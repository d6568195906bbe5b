"""Least-squares kernels shared by the linear and nonlinear friction fits (private)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from ..errors import SolverError

__all__ = ["LsqSolution", "solve_lstsq", "solve_nonneg_lstsq", "ls_covariance", "hac_covariance", "group_wald_p",
           "HacResult", "scaled_conditioning", "one_blas_thread"]


def one_blas_thread(func: Callable[..., Any]) -> Callable[..., Any]:
    """Run `func` with one BLAS thread (``threadpoolctl``), the gap diagnosis' rule for small products.

    A friction fit is hundreds of tall, thin products and factorisations (a few thousand to 1e6
    rows, <= 40 columns: the fit, its Newey-West sums, the adequacy's Wald tests, the method
    error's refits). With OpenBLAS's default two threads on a 2-core machine with another busy
    process, each waited for the second thread: a QR and a Gram product of 2000 x 20 took 6.7 ms of
    CPU instead of 0.9 ms, an extended-SFM identification of 2e4 samples 1.5 s instead of 0.18 s
    (``benchmarks/bench_friction_threads.py``); on a calm machine the gap diagnosis measured no
    difference.

    Parameters
    ----------
    func : callable
        The function to wrap.

    Returns
    -------
    callable
        `func` with the BLAS thread pools limited to one thread while it runs.
    """
    @functools.wraps(func)
    def run(*args: Any, **kwargs: Any) -> Any:
        with threadpool_limits(1, user_api="blas"):
            return func(*args, **kwargs)
    return run


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


@dataclass(frozen=True, slots=True)
class HacResult:
    """A heteroskedasticity and autocorrelation consistent covariance."""

    covariance: np.ndarray  # natural units, zero rows/columns for parameters held at a bound
    lags: int               # Bartlett bandwidth used [samples]
    iid_covariance: np.ndarray  # sigma^2 (W^T W)^-1 on the same samples, for comparison
    inflation: float        # median over free parameters of std_hac / std_iid [-]


def _andrews_bandwidth(u: np.ndarray) -> float:
    """Andrews (1991) AR(1) plug-in bandwidth for the Bartlett kernel, from the score series.

    Every column at once (one AR(1) coefficient per column; columns that never move are skipped).
    """
    x0, x1 = u[:-1], u[1:]
    d = np.einsum("ij,ij->j", x0, x0)
    ok = d > 0
    if not ok.any():
        return 0.0
    x0, x1 = x0[:, ok], x1[:, ok]
    rho = np.clip(np.einsum("ij,ij->j", x1, x0) / d[ok], -0.97, 0.97)
    s2 = np.mean((x1 - rho * x0) ** 2, axis=0)
    num = float(np.sum(4.0 * rho**2 * s2**2 / ((1.0 - rho) ** 6 * (1.0 + rho) ** 2)))
    den = float(np.sum(s2**2 / (1.0 - rho) ** 4))
    if den == 0.0:
        return 0.0
    return 1.1447 * (num / den * u.shape[0]) ** (1.0 / 3.0)


def _bartlett_lag_sum(eps: np.ndarray, L: int) -> np.ndarray:
    """``sum_{l=1..L} (1 - l / (L + 1)) eps[l:]^T eps[:-l]`` without a loop over the lags.

    ``Z[t] = sum_l w_l eps[t - l]`` (zeros before the start) is one product of a sliding
    window over the lagged scores with the weights; the sum is then ``eps^T Z``.
    """
    n, k = eps.shape
    if L <= 0 or n < 2:
        return np.zeros((k, k))
    padded = np.concatenate([np.zeros((L, k)), eps[:-1]])          # padded[t + j] = eps[t + j - L]
    window = np.lib.stride_tricks.sliding_window_view(padded, L, axis=0)[:n]   # (n, k, L)
    weights = 1.0 - np.arange(L, 0, -1) / (L + 1.0)                 # window slot j is lag L - j
    return eps.T @ (window @ weights)


#: Smallest singular value of the column-scaled regressor, relative to its largest, below which a
#: direction counts as not determined by the data (a scaled condition number beyond 1e10) [-].
UNRESOLVED_SINGULAR = 1e-10


def _normal_inverse(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(X^T X)^-1`` of a column-scaled regressor from its singular values, and the unresolved parameters.

    The inverse is formed as ``V diag(1 / s^2) V^T`` from the SVD of X's R factor, which stays
    accurate to condition numbers near 1 / eps where a pseudo-inverse of the normal matrix
    (squared condition) silently drops the weak directions and reports *zero* variance along
    them. Directions with ``s < UNRESOLVED_SINGULAR s_max`` are left out of the inverse, and the
    parameters that load on them (weight above 1e-3) are returned as unresolved: their variance is
    infinite, not zero.
    """
    k = X.shape[1]
    if k == 0:
        return np.zeros((0, 0)), np.zeros(0, dtype=bool)
    R = np.linalg.qr(X, mode="r")
    _, sv, Vt = np.linalg.svd(R)
    ok = sv > UNRESOLVED_SINGULAR * (sv[0] if sv.size else 0.0)
    V = Vt.T
    inv = (V[:, ok] / sv[ok] ** 2) @ V[:, ok].T
    unresolved = np.any(np.abs(V[:, ~ok]) > 1e-3, axis=1) if np.any(~ok) else np.zeros(k, dtype=bool)
    return inv, unresolved


def hac_covariance(W: np.ndarray, residual: np.ndarray, free: Sequence[bool] | None = None,
                   keep: np.ndarray | None = None, *, lags: int | None = None) -> HacResult:
    """Newey-West sandwich covariance of a least-squares estimate on correlated residuals.

    ``cov = (W^T W)^-1 S (W^T W)^-1`` with ``S = sum_l w_l Gamma_l`` the Bartlett-
    weighted (``w_l = 1 - l / (L + 1)``) autocovariances of the scores
    ``u_t = w_t r_t``, after a VAR(1) prewhitening of the scores (Andrews and
    Monahan 1992): filtered, decimated residuals are strongly correlated and
    the plain Bartlett estimate under-covers then. The bandwidth ``L`` is
    Andrews' (1991) AR(1) plug-in on the whitened scores, so it follows the
    residuals' actual autocorrelation. Samples left out of the fit (``keep``
    False) count as zero scores at their place in time, so lags stay lags in
    time across the gaps. A degrees-of-freedom factor ``m / (m - k)`` is applied.

    Parameters
    ----------
    W : ndarray, shape (n, p)
        Regressor (or Jacobian), every row in time order.
    residual : ndarray, shape (n,)
        Residuals.
    free : sequence of bool, optional
        Parameters not held at a bound (the others get zero rows and columns).
    keep : ndarray of bool, shape (n,), optional
        Rows used by the fit.
    lags : int, optional
        Fixed bandwidth instead of the plug-in.

    Returns
    -------
    HacResult
        Covariance, bandwidth and the i.i.d. covariance of the same fit; infinite for the free parameters
        when the kept rows are no more than them (nothing is determined), and in directions the data do
        not determine.
    """
    n, p = W.shape
    free_mask = np.ones(p, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    keep_mask = np.ones(n, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    cov = np.zeros((p, p))
    cov_iid = np.zeros((p, p))
    k = int(free_mask.sum())
    m = int(keep_mask.sum())
    if k == 0:
        return HacResult(cov, 0, cov_iid, 1.0)
    if m <= k:
        # fewer rows than free coefficients determine none of them: no variance, not a zero one (a
        # closed-loop square at rest but for one decimated row read a Coulomb level +-0 from it)
        for C in (cov, cov_iid):
            C[np.ix_(free_mask, free_mask)] = np.inf
        return HacResult(cov, 0, cov_iid, 1.0)
    # the n x k intermediates are made in place where the numbers are the same (a long log's diagnosis
    # holds several of these designs at its peak memory)
    X = np.where(keep_mask[:, None], W[:, free_mask], 0.0)
    s = _column_scale(X)
    X /= s
    e = np.where(keep_mask, residual, 0.0)
    Ainv, unresolved = _normal_inverse(X)
    u = X                  # the scores u_t = x_t e_t, in X's place
    u *= e[:, None]
    del X
    # VAR(1) prewhitening: u_t = B u_{t-1} + eps_t
    U0, U1 = u[:-1], u[1:]
    B = (np.linalg.pinv(U0.T @ U0) @ (U0.T @ U1)).T
    if not np.all(np.isfinite(B)):
        B = np.zeros_like(B)   # a score series the VAR(1) cannot describe: no prewhitening
    try:
        lam = np.abs(np.linalg.eigvals(B)) if B.size else np.zeros(0)
    except np.linalg.LinAlgError:
        B, lam = np.zeros_like(B), np.zeros(0)
    if lam.size and lam.max() > 0.97:  # keep the recolouring finite (Andrews-Monahan's adjustment)
        B = B * (0.97 / lam.max())
    eps = U0 @ B.T
    np.subtract(U1, eps, out=eps)      # U1 - U0 B^T
    del u, U0, U1
    L = int(np.ceil(_andrews_bandwidth(eps))) if lags is None else int(lags)
    L = max(0, min(L, eps.shape[0] // 4))
    G = _bartlett_lag_sum(eps, L)
    S = eps.T @ eps + (G + G.T)
    C = np.linalg.pinv(np.eye(k) - B)
    S = C @ S @ C.T * (m / (m - k))
    cov_f = Ainv @ S @ Ainv / np.outer(s, s)
    sigma2 = float(e @ e) / (m - k)
    cov_i = sigma2 * Ainv / np.outer(s, s)
    for C in (cov_f, cov_i):   # a direction the data do not determine: no variance, not a zero one
        C[unresolved, unresolved] = np.inf
    cov[np.ix_(free_mask, free_mask)] = cov_f
    cov_iid[np.ix_(free_mask, free_mask)] = cov_i
    d_h, d_i = np.diag(cov_f), np.diag(cov_iid[np.ix_(free_mask, free_mask)])
    ok = np.isfinite(d_i) & np.isfinite(d_h) & (d_i > 0)
    inflation = float(np.median(np.sqrt(np.clip(d_h[ok] / d_i[ok], 0.0, None)))) if ok.any() else 1.0
    return HacResult(cov, L, cov_iid, inflation)


def group_wald_p(A: np.ndarray, residual: np.ndarray, coef: np.ndarray, group: Sequence[int], *,
                 keep: np.ndarray | None = None, bound: np.ndarray | None = None) -> float:
    """p-value of the joint Wald test that a group of least-squares coefficients is zero [-].

    The test is made on the principal directions of the group's standardised columns (on the
    fit rows) that carry at least ``1e-6`` of their variance: collinear columns (harmonics over
    a fraction of a revolution) leave a lower-rank test of the contribution they share, which is
    well determined even when no single coefficient is. The covariance of those directions is
    the Newey-West sandwich (:func:`hac_covariance`) of the design re-expressed in them
    (projecting the coefficients' covariance would cancel catastrophically). Columns never
    excited carry no test; a direction the data do not determine gives p = 1.

    Parameters
    ----------
    A : ndarray, shape (n, p)
        The design (every row in time order).
    residual : ndarray, shape (n,)
        Residual of the fit of all p coefficients.
    coef : ndarray, shape (p,)
        The fitted coefficients.
    group : sequence of int
        Indices of the free coefficients tested.
    keep : ndarray of bool, shape (n,), optional
        Rows the fit used.
    bound : ndarray of bool, shape (p,), optional
        Coefficients held on a bound (no variance).

    Returns
    -------
    float
        The p-value (chi-square with as many degrees of freedom as kept directions).
    """
    from scipy import stats

    g = np.asarray(group, dtype=int)
    n, p = A.shape
    rows = np.ones(n, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    held = np.zeros(p, dtype=bool) if bound is None else np.asarray(bound, dtype=bool)
    coef = np.asarray(coef, dtype=float)
    others = np.setdiff1d(np.arange(p), g)   # an unexcited group column leaves the test whole
    norm = np.sqrt(np.sum(A[:, g][rows] ** 2, axis=0))
    ok = np.isfinite(norm) & (norm > 0) & np.isfinite(coef[g])
    if not np.any(ok):
        return 1.0
    g, norm = g[ok], norm[ok]
    Z = A[:, g]
    Z /= norm                                         # standardised columns
    Zr = Z[rows]
    C = Zr.T @ Zr
    del Zr
    try:
        w, V = np.linalg.eigh(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        return 1.0
    kept = w > 1e-6 * max(float(w.max()), 1e-300)
    if not np.any(kept):
        return 1.0
    Vk = V[:, kept]
    A_red = np.column_stack([A[:, others], Z @ Vk])
    del Z
    free = np.concatenate([~held[others], np.ones(Vk.shape[1], dtype=bool)])
    cov = hac_covariance(A_red, residual, free=free, keep=rows).covariance
    n_o = others.size
    S = cov[n_o:, n_o:]
    z = Vk.T @ (coef[g] * norm)                       # the group's estimate along the kept directions
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(z))):
        return 1.0
    chi2 = float(z @ np.linalg.lstsq(0.5 * (S + S.T), z, rcond=1e-12)[0])
    return float(stats.chi2.sf(chi2, int(Vk.shape[1]))) if np.isfinite(chi2) else 1.0
