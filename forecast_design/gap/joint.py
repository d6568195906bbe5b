"""Joint sparse attribution: every candidate's linear features at once, with a group-sparsity penalty.

The diagnosis names effects one at a time (:mod:`.diagnose`); this view fits all candidates at
their chosen grid points together and lets a group lasso keep the groups the held-out data ask for.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..effects import Effect
from .candidates import CandidateFit, _best_structure, _calibration, _solve
from .residuals import GapData
from .structures import _Coef, _design_matrix

__all__ = ["JointAttribution", "fit_joint"]


@dataclass(frozen=True, slots=True, kw_only=True)
class JointAttribution:
    """Joint sparse attribution over all candidates at once (group lasso).

    Parameters
    ----------
    effects : tuple of Effect
        Effects whose coefficient group survived, largest contribution first.
    contributions : Mapping[str, float]
        RMS contribution of each candidate's group on the held-out blocks [N m].
    lam : float
        Group-lasso weight chosen on the held-out blocks [-].
    gap_held_out : float
        Held-out gap of the refitted (unpenalised) model on the selected groups [N m].
    """

    effects: tuple[Effect, ...]
    contributions: Mapping[str, float]
    lam: float
    gap_held_out: float

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"effects": [str(e) for e in self.effects],
                "contributions": {k: float(v) for k, v in self.contributions.items()},
                "lambda": float(self.lam), "gap_held_out": float(self.gap_held_out)}


def fit_joint(data: GapData, fits: Sequence[CandidateFit], *, n_lambda: int = 8) -> JointAttribution:
    """All candidates' linear features at once, with a group-sparsity penalty (Clarabel).

    Nonlinear parameters are fixed at each candidate's one-at-a-time optimum. The
    objective is ``||A w - y||^2 / n + lam * sum_g sqrt(p_g) ||w_g||_2`` on the fit
    blocks with standardised columns and the calibration coefficients unpenalised and
    bounded; ``lam`` is chosen on the held-out blocks (largest ``lam`` whose held-out
    gap is within 2 % of the best), then the selected groups are refitted without
    penalty.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    fits : sequence of CandidateFit
        One-at-a-time fits (their grid optima fix the nonlinear parameters).
    n_lambda : int
        Number of penalty weights on the log-spaced path [-].

    Returns
    -------
    JointAttribution
        The selected effects and their held-out contributions.
    """
    cal = _calibration(data)
    groups: list[tuple[Effect, list[_Coef]]] = []
    for fit in fits:
        s = _best_structure(data, fit.effect, fit)
        if s is not None:
            groups.append((fit.effect, s.coefs))
    coefs = cal + [c for _, g in groups for c in g]
    As = _design_matrix(coefs)
    y = data.stacked_target()
    fit_rows = ~data.stacked(data.held_out)
    scale = np.sqrt(np.mean(As[fit_rows] ** 2, axis=0))
    scale[scale == 0.0] = 1.0
    As /= scale          # in place: the same quotients as As / scale, one matrix fewer
    # a few thousand rows are plenty for the selection; the refit uses all rows
    idx = np.flatnonzero(fit_rows)
    idx = idx[:: max(1, idx.size // 3000)]
    Af, yf = As[idx], y[idx]
    n_cal = len(cal)
    spans = []
    k = n_cal
    for _, g in groups:
        spans.append(slice(k, k + len(g)))
        k += len(g)
    lo = np.array([c.lo for c in coefs]) * scale
    hi = np.array([c.hi for c in coefs]) * scale
    y_rms = float(np.sqrt(np.mean(yf ** 2))) or 1.0
    # ||Af w - yf||^2 = ||R w - Q'yf||^2 + ||yf - Q Q'yf||^2 for Af = Q R (reduced QR): the same
    # minimiser from a square problem (the solver's work no longer grows with the rows).
    Q, R = np.linalg.qr(Af)
    held = data.stacked(data.held_out)
    A_held, y_held = As[held], y[held]
    results = []
    lams = np.geomspace(1e-1, 1e-5, n_lambda)
    path = _group_lasso_path(R, Q.T @ yf, 1.0 / (idx.size * y_rms ** 2), spans, lo, hi, lams)
    for value, wv in zip(lams, path):
        if wv is None:
            continue
        sel = tuple(i for i, sp in enumerate(spans)
                    if np.linalg.norm(wv[sp]) > 1e-3 * max(1.0, np.linalg.norm(wv[n_cal:])))
        gap = float(np.sqrt(np.mean((y_held - A_held @ wv) ** 2)))
        results.append((value, sel, gap))
    if not results:
        return JointAttribution(effects=(), contributions={}, lam=float("nan"), gap_held_out=float("nan"))
    best_gap = min(r[2] for r in results)
    value, sel, _ = max((r for r in results if r[2] <= 1.02 * best_gap), key=lambda r: r[0])
    # unpenalised refit on the selected groups
    chosen = cal + [c for i in sel for c in groups[i][1]]
    p = _solve(data, chosen, fit_rows)
    del As, A_held
    Ac = _design_matrix(chosen)
    r = y - Ac @ p
    contributions = {}
    k = n_cal
    for i in sel:
        n = len(groups[i][1])
        contributions[str(groups[i][0])] = float(np.sqrt(np.mean((Ac[held, k:k + n] @ p[k:k + n]) ** 2)))
        k += n
    order = sorted(sel, key=lambda i: -contributions[str(groups[i][0])])
    return JointAttribution(effects=tuple(groups[i][0] for i in order), contributions=contributions,
                            lam=float(value), gap_held_out=float(np.sqrt(np.mean(r[held] ** 2))))


def _group_lasso_path(R: np.ndarray, c: np.ndarray, weight: float, spans: Sequence[slice], lo: np.ndarray,
                      hi: np.ndarray, lams: Sequence[float]) -> list[np.ndarray | None]:
    """``argmin weight ||R w - c||^2 + lam sum_g sqrt(p_g) ||w_g||_2`` s.t. ``lo <= w <= hi``, per ``lam``.

    The conic program that cvxpy built for this problem, given to Clarabel directly (cvxpy's
    import and canonicalisation cost more than the solves): variables ``(w, t)``, one
    second-order cone ``||w_g|| <= t_g`` per group ``g`` (``spans``), the finite bounds as
    non-negative slacks. Returns ``w`` per ``lam``, None where Clarabel reports no solution.
    """
    import clarabel
    from scipy import sparse

    p, n_groups = R.shape[1], len(spans)
    n = p + n_groups
    P = np.zeros((n, n))
    P[:p, :p] = 2.0 * weight * (R.T @ R)
    q0 = np.zeros(n)
    q0[:p] = -2.0 * weight * (R.T @ c)
    rows: list[tuple[int, float]] = []          # (variable, coefficient) of each constraint row
    b: list[float] = []
    for i in np.flatnonzero(np.isfinite(lo)):
        rows.append((int(i), -1.0))             # s = w_i - lo_i >= 0
        b.append(-float(lo[i]))
    for i in np.flatnonzero(np.isfinite(hi)):
        rows.append((int(i), 1.0))              # s = hi_i - w_i >= 0
        b.append(float(hi[i]))
    cones: list[Any] = [clarabel.NonnegativeConeT(len(rows))] if rows else []
    for g, span in enumerate(spans):
        rows.append((p + g, -1.0))              # s = (t_g, w_g) in the second-order cone
        b.append(0.0)
        for i in range(span.start, span.stop):
            rows.append((i, -1.0))
            b.append(0.0)
        cones.append(clarabel.SecondOrderConeT(1 + span.stop - span.start))
    Acon = sparse.csc_matrix(([v for _, v in rows], ([r for r in range(len(rows))], [j for j, _ in rows])),
                             shape=(len(rows), n))
    Pu = sparse.triu(sparse.csc_matrix(P)).tocsc()
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    ok = (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved)
    out: list[np.ndarray | None] = []
    for lam in lams:
        q = q0.copy()
        q[p:] = [lam * np.sqrt(sp.stop - sp.start) for sp in spans]
        sol = clarabel.DefaultSolver(Pu, q, Acon, np.array(b), cones, settings).solve()
        out.append(np.asarray(sol.x[:p], dtype=float) if sol.status in ok else None)
    return out
