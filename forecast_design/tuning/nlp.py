"""The casadi NLP of the cutoff tuning: real arithmetic on the responses' real and imaginary parts."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..loops.response import sensitivity_terms
from ..errors import SolverError
from .plants import _Plant


class _Complex:
    """A complex number as a pair of real (casadi) expressions, for the NLP's sensitivity."""

    __slots__ = ("re", "im")

    def __init__(self, re: Any, im: Any = 0.0) -> None:
        self.re, self.im = re, im

    @staticmethod
    def of(x: Any) -> "_Complex":
        return x if isinstance(x, _Complex) else _Complex(float(np.real(x)), float(np.imag(x)))

    def __add__(self, other: Any) -> "_Complex":
        o = _Complex.of(other)
        return _Complex(self.re + o.re, self.im + o.im)

    __radd__ = __add__

    def __sub__(self, other: Any) -> "_Complex":
        o = _Complex.of(other)
        return _Complex(self.re - o.re, self.im - o.im)

    def __mul__(self, other: Any) -> "_Complex":
        if isinstance(other, (int, float)):
            return _Complex(other * self.re, other * self.im)
        o = _Complex.of(other)
        return _Complex(o.re * self.re - o.im * self.im, o.re * self.im + o.im * self.re)

    __rmul__ = __mul__

    def abs2(self) -> Any:
        return self.re ** 2 + self.im ** 2


def _casadi_abs2_G(plant: _Plant, idx: np.ndarray, dq_re, dq_im, break_at: str, sigma: float):
    """|S + (sigma-1)/2|^2 at the frequencies ``idx`` as (numerator, denominator) casadi expressions of D_q.

    ``S = num / den`` from :func:`~.loops.response.sensitivity_terms`, the same formula as the
    numpy grid; ``G = num / den + c`` is kept as ``|num + c den|^2 / |den|^2``.
    """
    exprs = []
    c = 0.5 * (sigma - 1.0)
    for j, (re, im) in enumerate(zip(dq_re, dq_im)):
        i = idx[j]
        num, den = sensitivity_terms(complex(plant.M[i]), complex(plant.CP[i]), complex(plant.dm[i]),
                                     _Complex(re, im), break_at)
        exprs.append(((num + c * den).abs2(), den.abs2()))
    return exprs


def _dq_casadi(ca, coeffs: np.ndarray, u):
    """Real and imaginary parts of D_q(j u) for casadi u."""
    re, im = 0, 0
    for n, c in enumerate(coeffs):
        term = c * u**n
        if n % 4 == 0:
            re = re + term
        elif n % 4 == 1:
            im = im + term
        elif n % 4 == 2:
            re = re - term
        else:
            im = im - term
    return re, im


def _ipopt(ca, nlp, x0, lbx, ubx, lbg, ubg) -> tuple[np.ndarray, dict]:
    # the one quiet ipopt setting (print_level 0, no timing table, no banner); imported where casadi is
    from ..friction.nonlinear import IPOPT_OPTIONS

    opts = {**IPOPT_OPTIONS, "ipopt.max_iter": 300, "ipopt.tol": 1e-10}
    solver = ca.nlpsol("tune", "ipopt", nlp, opts)
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    stats = solver.stats()
    info = {"return_status": stats.get("return_status"), "iterations": int(stats.get("iter_count", 0)),
            "success": bool(stats.get("success"))}
    if not stats.get("success") and stats.get("return_status") not in ("Solved_To_Acceptable_Level",):
        raise SolverError(f"ipopt did not converge: {stats.get('return_status')}", stats=info)
    return np.asarray(sol["x"]).ravel(), info


def _solve_max_cutoff(plants, coeffs, bound, log_lo, log_hi, x0, active, break_at, sigma):
    """max log(w_q) s.t. |G_e(w_i)|^2 <= bound_e^2 on the active frequencies.

    The constraints of all plants are one casadi vector expression (element-wise arithmetic on
    the stacked active frequencies: :func:`~.loops.response.sensitivity_terms` on complex pairs
    of vectors), so building the NLP costs no Python loop over plants and frequencies.
    """
    import casadi as ca

    x = ca.MX.sym("log_w_q")   # vector operations: MX keeps the graph small (SX would unroll it)
    picks = [(plant, np.asarray(sorted(active[p]), dtype=int), bound[p]) for p, plant in enumerate(plants)]

    def stacked(attr: str) -> "_Complex":
        v = np.concatenate([np.asarray(getattr(plant, attr), dtype=complex)[idx] for plant, idx, _ in picks])
        return _Complex(ca.DM(v.real), ca.DM(v.imag))

    W = np.concatenate([np.asarray(plant.W, dtype=float)[idx] for plant, idx, _ in picks])
    b2 = np.concatenate([np.full(idx.size, b ** 2) for _, idx, b in picks])
    re, im = _dq_casadi(ca, coeffs, ca.DM(W) / ca.exp(x))
    num, den = sensitivity_terms(stacked("M"), stacked("CP"), stacked("dm"), _Complex(re, im), break_at)
    c = 0.5 * (sigma - 1.0)
    dens = den.abs2()
    g = (num + c * den).abs2() - ca.DM(b2) * dens   # |G|^2 <= bound^2, cleared of the denominator
    # |den|^2 spans many decades (D_q grows like (w/w_q)^n up to Nyquist): scale each
    # constraint by its denominator at the start point so ipopt sees O(1) rows
    scale = np.asarray(ca.Function("den", [x], [dens])(x0)).ravel()
    scale = np.where(np.isfinite(scale) & (scale > 0.0), scale, 1.0)
    g = g / ca.DM(scale)
    nlp = {"x": x, "f": -x, "g": g}
    sol, info = _ipopt(ca, nlp, [x0], [log_lo], [log_hi], [-ca.inf] * W.size, [0.0] * W.size)
    return float(sol[0]), info
