"""Q-filter tuning by optimisation (casadi): the largest robust cutoff, or the best Q shape.

Both problems use the same frequency-domain facts. With the observer written
as tau_frc_hat = G_m tau_m + G_s tau_s + G_theta theta (one home:
:func:`forecast_design.symbolic.observer_filters`), G_m = Q, G_s = -Q A and
G_theta = -Q B, where A(jw) and B(jw) do not depend on the cutoff. With the
true plant P = tau_s/tau_m and P_theta = theta/tau_m, let
M = A P + B P_theta - 1. Then F_DOB = P / (1 + Q M) (eq. 4 for the DOBs) and,
with Q = 1/D_q(s/w_q),

    S = (D_q + M) / (D_q + M + C_F P D_q)          loop broken at the controller
    S = (D_q - 1) / (D_q + M + C_F P D_q)          loop broken at the motor torque input

so at any frequency the sensitivity is an explicit function of w_q whose
only non-constant part is the Q polynomial. P, P_theta, A, B and C_F are
evaluated once per environment and frequency; casadi sees real arithmetic on
their real and imaginary parts.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .loops.response import (LoopResponse, loop_response, observer_responses, q_argument, sensitivity,
                             sensitivity_terms)
from .executor import Executor
from .margins import disk_margin
from .errors import ParameterError, SolverError
from .plausibility import check_limit, check_physical
from .environments import resolve_environments, resolve_testbed
from .params import Compensator, Design, Environment, PDController

__all__ = ["TuningResult", "environment_set", "tune_q", "tune_q_shape", "worst_case_ratio"]

_GRID_RAD_S = np.logspace(-2, 4.5, 700)   # constraint/verification grid [rad/s]
_GRID_POINTS = 700
_ACTIVE_PER_PLANT = 4                     # frequencies per plant in the first NLP
_MAX_CUTS = 12                            # cutting-plane rounds
_FEAS_RTOL = 1e-6                         # relative slack of the ratio requirement


@dataclass(frozen=True, slots=True)
class _Setting:
    """What every loop of one tuning shares."""

    controller: PDController
    break_at: str
    sigma: float
    sampled: bool = False
    rate_hz: float = 2000.0
    delay_samples: int = 1

    def __post_init__(self) -> None:
        check_physical("tuning", "rate_hz", self.rate_hz)
        check_limit("delay_samples", "delay_samples", self.delay_samples)

    def grid(self) -> np.ndarray:
        """Constraint grid [rad/s]: 1e-2 ... 3e4, or up to just below Nyquist when sampled."""
        if not self.sampled:
            return _GRID_RAD_S
        return np.logspace(-2, math.log10(0.999 * math.pi * self.rate_hz), _GRID_POINTS)


@dataclass(frozen=True, slots=True)
class _Plant:
    """One true plant of the set, with the observer's belief and precomputed responses.

    At frequency w the sensitivity offset is a function of D_q(j W / w_q) only:
    S = (D_q + M) / (D_q + M + CP D_q) (controller) or (D_q - dm) / (...) (plant input),
    with W = w (continuous) or the Tustin-warped (2/T) tan(w T / 2) (sampled).
    """

    label: str
    true_design: Design
    believed: Design
    alpha_plant: float             # disk margin of the plant alone [-]
    w: np.ndarray                  # frequency grid [rad/s]
    W: np.ndarray                  # argument of Q at those frequencies [rad/s]
    CP: np.ndarray                 # C_F P (times the command delay when sampled)
    M: np.ndarray                  # A P + B P_theta - 1 (sampled: delays included)
    dm: np.ndarray                 # 1, or the observer's z^-1 on the previous command
@dataclass(frozen=True, slots=True)
class TuningResult:
    """Outcome of a Q-filter tuning.

    Attributes
    ----------
    observer : str
        Compensator kind.
    w_q_hz : float
        Chosen cutoff [Hz] (nan if infeasible).
    worst_ratio : float
        min over the set of alpha_observer / alpha_plant at the answer [-] (exact margins).
    worst_environment : str
        Label of the plant attaining it.
    feasible : bool
        Whether the answer meets the ratio requirement in every plant.
    evaluations : int
        Exact disk-margin evaluations plus NLP solves.
    scan_w_q_hz : float
        Best cutoff of the independent dense scan [Hz].
    agrees_with_scan : bool
        Answer feasible and within 2 % of the scan's best.
    q_damping : float or None
        Damping ratio of the 2nd-order Q (shape mode only) [-].
    solver : dict
        casadi/ipopt return status and iteration counts.
    at_bound : str or None
        The end of the search band (or of the Q damping range) the answer sits on, in words;
        the true optimum may lie beyond it. None when the answer is inside.
    """

    observer: str
    w_q_hz: float
    worst_ratio: float
    worst_environment: str
    feasible: bool
    evaluations: int
    scan_w_q_hz: float
    agrees_with_scan: bool
    min_ratio: float
    band_hz: tuple[float, float]
    plants: int
    q_damping: float | None = None
    solver: dict = field(default_factory=dict)
    at_bound: str | None = None    # the search-range end the answer sits on, in words (None: inside)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping (the ``tune-q`` output); ``compensator`` repeats ``observer`` (the key every
        verb uses)."""
        out = {
            "observer": self.observer,
            "compensator": self.observer,
            "w_q_hz": None if math.isnan(self.w_q_hz) else self.w_q_hz,
            "worst_ratio": self.worst_ratio,
            "worst_environment": self.worst_environment,
            "feasible": self.feasible,
            "evaluations": self.evaluations,
            "scan_w_q_hz": None if math.isnan(self.scan_w_q_hz) else self.scan_w_q_hz,
            "agrees_with_scan": self.agrees_with_scan,
            "min_ratio": self.min_ratio,
            "band_hz": list(self.band_hz),
            "plants": self.plants,
            "solver": self.solver,
        }
        if self.q_damping is not None:
            out["q_damping"] = self.q_damping
        out["at_bound"] = self.at_bound
        return out


def environment_set(names: Any, *, uncertainty: float = 0.0, seed: int = 0,
                    testbed: Any = None) -> list[tuple[str, Environment, Environment]]:
    """True/believed environment pairs for an environment set, with parametric uncertainty.

    Parameters
    ----------
    names : str, Environment, EnvironmentSet, path or iterable
        Anything :func:`forecast_design.environments.resolve_environments` accepts: preset
        names (comma-separated in a string), ``random:N`` (N environments drawn log-uniformly,
        k_e in [0.1, 1000] N m/rad, J_e in [1e-3, 1] kg m^2, critically damped d_e, with
        ``seed``), inline ``k_e=..,J_e=..`` values, an environment-set TOML file, objects.
    uncertainty : float
        Relative range u [-] of the true J, d and k_e: the 8 vertices of
        [1 - u, 1 + u]^3 and the nominal point; the observer keeps the nominal.
    seed : int
        Seed of ``random:N``.
    testbed : Testbed, str or None
        The testbed, for link defaults (see :func:`~forecast_design.environments.resolve_environments`).

    Returns
    -------
    list of (label, true Environment, believed Environment)
    """
    if not (0.0 <= uncertainty < 1.0):
        raise ParameterError(f"uncertainty must be in [0, 1), got {uncertainty!r}", name="uncertainty",
                             value=uncertainty)
    envset = resolve_environments(names, testbed=resolve_testbed(testbed), seed=seed)
    out = []
    for label, env in envset:
        out.append((label, env, env))
        if uncertainty > 0.0 and not env.locked:
            for fj, fd, fk in itertools.product((1 - uncertainty, 1 + uncertainty), repeat=3):
                true = dataclasses.replace(env, J_e=env.J_e * fj, J_l=env.J_l * fj, d_e=env.d_e * fd,
                                           d_l=env.d_l * fd, k_e=env.k_e * fk)
                out.append((f"{label}[J*{fj:g},d*{fd:g},k_e*{fk:g}]", true, env))
    return out


def _responses(true_design: Design, believed: Design, compensator: Compensator, setting: _Setting,
               w: np.ndarray, cache: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(W, CP, M, dm) of one plant on the grid ``w`` [rad/s] (:func:`~.loops.response.loop_response`)."""
    key = (believed, float(w[0]), float(w[-1]), w.size)
    if key not in cache:
        W = q_argument(w, sampled=setting.sampled, rate_hz=setting.rate_hz)
        cache[key] = observer_responses(compensator, believed, 1j * W)
    r = loop_response(true_design, believed, compensator, setting.controller, w, sampled=setting.sampled,
                      rate_hz=setting.rate_hz, delay_samples=setting.delay_samples, observer=cache[key])
    return r.W, r.CP, r.M, r.dm


def _exact_ratio(true_design: Design, believed: Design, compensator: Compensator | None,
                 setting: _Setting) -> tuple[float, float]:
    """Exact disk margin (stability checked) and its critical frequency [rad/s]."""
    if setting.sampled:
        from .loops.sampled import sampled_force_loop

        dm = sampled_force_loop(true_design, compensator, controller=setting.controller, believed=believed,
                                rate_hz=setting.rate_hz, break_at=setting.break_at,
                                delay_samples=setting.delay_samples).disk_margin(setting.sigma)
    else:
        from .loops import force_loop

        loop = force_loop(true_design, compensator, controller=setting.controller, believed=believed,
                          break_at=setting.break_at)
        dm = disk_margin(loop.L, setting.sigma, closed_loop_stable=loop.stable)
    return dm.alpha, dm.frequency_rad_s


def _q_polynomial(compensator: Compensator) -> np.ndarray:
    """Coefficients (ascending powers of s/w_q) of D_q, Q = 1/D_q(s/w_q)."""
    from .symbolic import compensator_q_tf

    q = compensator_q_tf(dataclasses.replace(compensator, w_q_hz=1.0 / (2.0 * math.pi)))
    return np.asarray(q.den[::-1]) / q.num[-1]


def _sensitivity_offset(plant: _Plant, dq: np.ndarray, break_at: str, sigma: float) -> np.ndarray:
    parts = LoopResponse(w=plant.w, W=plant.W, CP=plant.CP, M=plant.M, dm=plant.dm)
    return sensitivity(parts, dq, break_at) + 0.5 * (sigma - 1.0)


def _grid_ratios(plants: Sequence[_Plant], coeffs: np.ndarray, w_q_hz: np.ndarray, break_at: str,
                 sigma: float) -> np.ndarray:
    """Grid alpha_observer/alpha_plant, shape (cutoffs, plants): an upper bound of the exact one.

    On a stable loop the grid peak of |S + (sigma-1)/2| is at most the true peak, so the grid
    margin is at least the exact one; an unstable loop has exact margin 0. Hence a cutoff
    that fails on the grid fails exactly, and only grid-feasible cutoffs need exact checks.
    """
    w_q = 2.0 * math.pi * np.atleast_1d(np.asarray(w_q_hz, float))
    out = np.empty((w_q.size, len(plants)))
    for i, plant in enumerate(plants):
        dq = np.polyval(coeffs[::-1], 1j * plant.W[None, :] / w_q[:, None])
        peak = np.max(np.abs(_sensitivity_offset(plant, dq, break_at, sigma)), axis=1)
        out[:, i] = (1.0 / peak) / plant.alpha_plant
    return out


def _exact_ratios(plants: Sequence[_Plant], compensator: Compensator, setting: _Setting,
                  order: Sequence[int] | None = None, stop_below: float | None = None,
                  executor: Executor | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Exact alpha_observer/alpha_plant (stability checked), critical frequencies [rad/s] and the
    number of evaluations; with ``stop_below``, stop at the first ratio under it (others nan).
    With an executor every plant is evaluated (in coarse batches), whatever ``stop_below``."""
    if executor is not None:
        items = [(p.true_design, p.believed, compensator, setting) for p in plants]
        out = executor.map_batched(_exact_of, items, batch_size=_batch_size(executor, len(items)))
        alphas = np.array([a for a, _ in out])
        return alphas / np.array([p.alpha_plant for p in plants]), np.array([f for _, f in out]), len(plants)
    ratios, freqs = np.full(len(plants), np.nan), np.full(len(plants), np.nan)
    n = 0
    for i in (range(len(plants)) if order is None else order):
        plant = plants[i]
        alpha, freqs[i] = _exact_ratio(plant.true_design, plant.believed, compensator, setting)
        ratios[i] = alpha / plant.alpha_plant
        n += 1
        if stop_below is not None and ratios[i] < stop_below:
            break
    return ratios, freqs, n


def worst_case_ratio(compensator: Compensator, envs: Sequence[str] | str = ("soft", "stiff"), *,
                     uncertainty: float = 0.0, controller: PDController = PDController(),
                     break_at: str = "controller", sigma: float = 0.0, sampled: bool = False,
                     rate_hz: float = 2000.0, delay_samples: int = 1, seed: int = 0,
                     testbed: Any = None) -> tuple[float, str]:
    """Exact worst ratio alpha_observer / alpha_plant over an environment set.

    Parameters
    ----------
    compensator : Compensator
        Observer with its cutoff ``w_q_hz`` [Hz].
    envs : str or sequence of str
        See :func:`environment_set`.
    uncertainty : float
        Relative uncertainty of the true J, d, k_e [-].
    controller : PDController
        C_F = P + D s.
    break_at : str
        Loop-break point (``'controller'`` or ``'plant-input'``).
    sigma : float
        Disk skew [-].
    sampled : bool
        Use the sampled-data loop (:func:`forecast_design.loops.sampled.sampled_force_loop`).
    rate_hz : float
        Sampling rate when ``sampled`` [Hz].
    delay_samples : int
        Computation delay when ``sampled`` [samples].
    seed : int
        Seed of ``random:N`` sets.
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`; None: Table 1).

    Returns
    -------
    (float, str)
        The worst ratio [-] and the label of the plant attaining it.
    """
    setting = _Setting(controller, break_at, float(sigma), bool(sampled), float(rate_hz), int(delay_samples))
    plants = _plants(compensator, envs, uncertainty, setting, seed, testbed=testbed)
    ratios, _, _ = _exact_ratios(plants, compensator, setting)
    i = int(np.argmin(ratios))
    return float(ratios[i]), plants[i].label


def _plant_of(item: tuple) -> _Plant:
    """One plant of the set from ``(label, true_design, believed, compensator, setting)`` (an executor task)."""
    label, true_design, believed, compensator, setting = item
    alpha = _exact_ratio(true_design, true_design, None, setting)[0]
    W, CP, M, dm = _responses(true_design, believed, compensator, setting, setting.grid(), {})
    return _Plant(label, true_design, believed, alpha, setting.grid(), W, CP, M, dm)


def _exact_of(item: tuple) -> tuple[float, float]:
    """:func:`_exact_ratio` of ``(true_design, believed, compensator, setting)`` (an executor task)."""
    return _exact_ratio(*item)


def _batch_size(executor: Executor, n: int) -> int:
    """Items per task: about four tasks per worker (coarse tasks; results do not depend on it)."""
    return max(1, math.ceil(n / (4 * max(1, executor.workers))))


def _plants(compensator: Compensator, envs, uncertainty: float, setting: _Setting, seed: int = 0,
            progress: Callable[[int, int], None] | None = None, testbed: Any = None,
            executor: Executor | None = None) -> list[_Plant]:
    if not compensator.is_observer:
        raise ParameterError(f"tuning needs an observer kind (ea-fob, lo-dob, ld-dob, motor-fob), "
                             f"got {compensator.kind!r}", name="observer", value=compensator.kind)
    if setting.break_at not in ("controller", "plant-input"):
        raise ParameterError(f"break_at must be 'controller' or 'plant-input', got {setting.break_at!r}",
                             name="break_at", value=setting.break_at)
    base = Design(testbed=resolve_testbed(testbed))
    w = setting.grid()
    cache: dict = {}
    alone: dict = {}
    pairs = environment_set(envs, uncertainty=uncertainty, seed=seed, testbed=base.testbed)
    if executor is not None:
        items = [(label, dataclasses.replace(base, environment=true), dataclasses.replace(base, environment=bel),
                  compensator, setting) for label, true, bel in pairs]
        return executor.map_batched(_plant_of, items, batch_size=_batch_size(executor, len(items)),
                                    progress=progress)
    out = []
    for n, (label, true, bel) in enumerate(pairs):
        true_design = dataclasses.replace(base, environment=true)
        believed = dataclasses.replace(base, environment=bel)
        if true_design not in alone:
            alone[true_design] = _exact_ratio(true_design, true_design, None, setting)[0]
        W, CP, M, dm = _responses(true_design, believed, compensator, setting, w, cache)
        out.append(_Plant(label, true_design, believed, alone[true_design], w, W, CP, M, dm))
        if progress:
            progress(n + 1, len(pairs))
    return out


def _with_frequency(plant: _Plant, compensator: Compensator, setting: _Setting, w_new: float) -> _Plant:
    """The plant with one more grid frequency (a cut at an exact peak between grid points)."""
    w = np.append(plant.w, w_new)
    W, CP, M, dm = _responses(plant.true_design, plant.believed, compensator, setting, np.array([w_new]), {})
    return dataclasses.replace(plant, w=w, W=np.append(plant.W, W), CP=np.append(plant.CP, CP),
                               M=np.append(plant.M, M), dm=np.append(plant.dm, dm))


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
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 300,
            "ipopt.tol": 1e-10}
    solver = ca.nlpsol("tune", "ipopt", nlp, opts)
    sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    stats = solver.stats()
    info = {"return_status": stats.get("return_status"), "iterations": int(stats.get("iter_count", 0)),
            "success": bool(stats.get("success"))}
    if not stats.get("success") and stats.get("return_status") not in ("Solved_To_Acceptable_Level",):
        raise SolverError(f"ipopt did not converge: {stats.get('return_status')}", stats=info)
    return np.asarray(sol["x"]).ravel(), info


def _solve_max_cutoff(plants, coeffs, bound, log_lo, log_hi, x0, active, break_at, sigma):
    """max log(w_q) s.t. |G_e(w_i)|^2 <= bound_e^2 on the active frequencies."""
    import casadi as ca

    x = ca.SX.sym("log_w_q")
    g, dens = [], []
    for p, plant in enumerate(plants):
        idx = np.asarray(sorted(active[p]), dtype=int)
        u = plant.W[idx] / ca.exp(x)
        dq = [_dq_casadi(ca, coeffs, u[k]) for k in range(len(idx))]
        for top, den in _casadi_abs2_G(plant, idx, [d[0] for d in dq], [d[1] for d in dq], break_at, sigma):
            g.append(top - bound[p] ** 2 * den)   # |G|^2 <= bound^2, cleared of the denominator
            dens.append(den)
    # |den|^2 spans many decades (D_q grows like (w/w_q)^n up to Nyquist): scale each
    # constraint by its denominator at the start point so ipopt sees O(1) rows
    scale = np.asarray(ca.Function("den", [x], [ca.vertcat(*dens)])(x0)).ravel()
    scale = np.where(np.isfinite(scale) & (scale > 0.0), scale, 1.0)
    g = [gi / float(sc) for gi, sc in zip(g, scale)]
    nlp = {"x": x, "f": -x, "g": ca.vertcat(*g)}
    sol, info = _ipopt(ca, nlp, [x0], [log_lo], [log_hi], [-ca.inf] * len(g), [0.0] * len(g))
    return float(sol[0]), info


def tune_q(observer: str = "ea-fob", envs: Sequence[str] | str = ("soft", "stiff"), *,
           uncertainty: float = 0.0, min_ratio: float = 0.9, band_hz: tuple[float, float] = (0.5, 30.0),
           q_family: str = "butterworth", q_order: int = 2, controller: PDController = PDController(),
           break_at: str = "controller", sigma: float = 0.0, scan_points: int = 80, seed: int = 0,
           sampled: bool = False, rate_hz: float = 2000.0, delay_samples: int = 1, scan: str = "bounded",
           progress: Callable[[int, int], None] | None = None, testbed: Any = None,
           executor: Executor | None = None) -> TuningResult:
    """Largest Q cutoff keeping the disk margin near the plant's own in every environment.

    Parameters
    ----------
    observer : str
        ``ea-fob``, ``lo-dob``, ``ld-dob`` or ``motor-fob``.
    envs : str or sequence of str
        Environment set (see :func:`environment_set`).
    uncertainty : float
        Relative range of the true J, d, k_e [-]; the observer keeps the nominal values.
    min_ratio : float
        Required alpha_observer / alpha_plant in every plant of the set [-].
    band_hz : (float, float)
        Search band of the cutoff [Hz].
    q_family, q_order : str, int
        Q-filter family and order.
    controller : PDController
        C_F = P + D s (sampled: with the simulator's 200 Hz derivative filter).
    break_at : str
        ``'controller'`` (paper) or ``'plant-input'``.
    sigma : float
        Disk skew [-].
    scan_points : int
        Points of the independent verification scan (log-spaced over the band).
    seed : int
        Seed for ``random:N`` environment sets.
    sampled : bool
        Tune on the sampled-data loop (:func:`forecast_design.loops.sampled.sampled_force_loop`):
        constraints on the discrete frequency response up to Nyquist, exact verification on
        the sampled loop.
    rate_hz : float
        Sampling rate when ``sampled`` [Hz].
    delay_samples : int
        Computation delay when ``sampled`` [samples].
    scan : str
        ``'bounded'`` (default): the scan evaluates every cutoff on the grid at once and
        checks exactly only the grid-feasible cutoffs, from the top, until one passes (the
        grid margin bounds the exact one from above, so the result is the same as the full
        scan's); ``'exact'``: exact margins at every scan point and plant.
    progress : callable, optional
        ``progress(done, total)`` while the plant set is prepared and the scan runs.
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`; None: Table 1).
    executor : Executor, optional
        Where the per-plant work of a large set runs (:func:`forecast_design.executor.make_executor`:
        local processes or a Dask cluster): the plant set's responses and margins and every exact
        verification, in coarse batches of plants. None (default): this process, with the early
        stop of the bounded scan. The answer is the same either way; ``evaluations`` counts the
        exact margins computed, which without the early stop is more.

    Returns
    -------
    TuningResult
        The cutoff, its exact worst-case ratio and the scan's best for comparison.

    Notes
    -----
    Formulation (casadi NLP, solved by ipopt): with x = log w_q,

        maximise x  subject to  |S_e(j w_i; x) + (sigma - 1)/2|^2 <= (min_ratio alpha_e)^-2

    for every plant e of the set and every frequency w_i of an active set,
    written as |num|^2 - bound^2 |den|^2 <= 0 so nothing divides by zero.
    The active set starts with the largest sensitivities of each plant and
    grows by cutting planes: after each solve the 700-point grid
    (1e-2 ... 3e4 rad/s; sampled: up to just below Nyquist) is checked and
    each violating plant's worst frequency is added. The answer is then
    verified with exact disk margins (closed-loop stability included, peak
    found exactly); where the exact peak lies between grid points it is
    added as a cut. The independent scan finds the best feasible cutoff
    among ``scan_points`` log-spaced ones (exact margins, see ``scan``) and
    the answer must be feasible and within 2 % of it.

    When sampled, at frequency w the Tustin filters equal the continuous
    ones at W = (2/T) tan(w T / 2), the plant is the ZOH plant at
    z = exp(j w T), the command is delayed by z^-d and G_m sees z^-1: the
    sensitivity keeps the form above with D_q(j W / w_q).
    """
    if not (0.0 < band_hz[0] < band_hz[1]):
        raise ParameterError(f"band must satisfy 0 < lo < hi [Hz], got {band_hz}", name="band", value=band_hz)
    for end in band_hz:   # a cutoff of 1e-300 Hz gives w_q = nan, not an answer
        check_physical("band", "w_q_hz", float(end))
    if not (0.0 < min_ratio <= 1.0):
        raise ParameterError(f"min_ratio must be in (0, 1], got {min_ratio}", name="min_ratio", value=min_ratio)
    if scan not in ("bounded", "exact"):
        raise ParameterError(f"scan must be 'bounded' or 'exact', got {scan!r}", name="scan", value=scan)
    if sampled and band_hz[1] >= rate_hz / 2.0:
        raise ParameterError(f"band upper end {band_hz[1]} Hz must be below Nyquist ({rate_hz / 2.0} Hz)",
                             name="band", value=band_hz)
    setting = _Setting(controller, break_at, float(sigma), bool(sampled), float(rate_hz), int(delay_samples))
    base = Compensator(kind=observer, w_q_hz=band_hz[0], q_family=q_family, q_order=q_order)
    plants = _plants(base, envs, uncertainty, setting, seed, testbed=testbed, executor=executor)
    coeffs = _q_polynomial(base)
    evaluations = len({p.true_design for p in plants})    # plant-alone margins
    threshold = min_ratio * (1.0 - _FEAS_RTOL)

    def exact(w_q_hz: float, order=None, stop_below=None):
        nonlocal evaluations
        ratios, freqs, n = _exact_ratios(plants, dataclasses.replace(base, w_q_hz=w_q_hz), setting, order, stop_below,
                                         executor=executor)
        evaluations += n
        return ratios, freqs

    # Independent dense scan with exact margins (all points, or the grid-feasible ones from the top).
    scan_hz = np.geomspace(band_hz[0], band_hz[1], scan_points)
    scan_best = math.nan
    if scan == "exact":
        for n, f in enumerate(scan_hz):
            ratios, _ = exact(float(f))
            if ratios.min() >= threshold:
                scan_best = float(f)
            if progress:
                progress(n + 1, len(scan_hz))
    else:
        grid = _grid_ratios(plants, coeffs, scan_hz, break_at, sigma)
        candidates = np.flatnonzero(grid.min(axis=1) >= threshold * (1.0 - 1e-9))[::-1]
        for n, k in enumerate(candidates):
            # the plants closest to failing first: an infeasible cutoff usually fails at once
            ratios, _ = exact(float(scan_hz[k]), order=np.argsort(grid[k]), stop_below=threshold)
            if progress:
                progress(n + 1, len(candidates))
            if np.all(ratios >= threshold):
                scan_best = float(scan_hz[k])
                break
    feasible_scan = not math.isnan(scan_best)

    # NLP with cutting planes, started at the scan's best (or the band's low end).
    start_hz = scan_best if feasible_scan else band_hz[0]
    bound = 1.0 / (min_ratio * np.array([p.alpha_plant for p in plants]))
    active = []
    for plant in plants:
        dq = np.polyval(coeffs[::-1], 1j * plant.W / (2 * math.pi * start_hz))
        mags = np.abs(_sensitivity_offset(plant, dq, break_at, sigma))
        active.append(set(np.argsort(mags)[-_ACTIVE_PER_PLANT:].tolist()))
    log_lo, log_hi = math.log(2 * math.pi * band_hz[0]), math.log(2 * math.pi * band_hz[1])
    x = math.log(2 * math.pi * start_hz)
    info: dict = {}
    answer = math.nan
    nyquist = math.pi * rate_hz if sampled else math.inf
    rounds = 0 if feasible_scan and scan_best >= band_hz[1] else _MAX_CUTS
    if not rounds:
        # the band's upper end passed the exact check: nothing above it to search for
        answer, info = scan_best, {"return_status": "not needed: band upper end verified", "iterations": 0,
                                   "success": True}
    for _ in range(rounds):
        try:
            x, info = _solve_max_cutoff(plants, coeffs, bound, log_lo, log_hi, x, active, break_at, sigma)
        except SolverError as exc:
            info = dict(exc.stats or {})    # keep the verified scan point below
            break
        evaluations += 1
        w_q = math.exp(x)
        added = False
        for p, plant in enumerate(plants):
            dq = np.polyval(coeffs[::-1], 1j * plant.W / w_q)
            mags = np.abs(_sensitivity_offset(plant, dq, break_at, sigma))
            worst = int(np.argmax(mags))
            if mags[worst] > bound[p] * (1 + 1e-9) and worst not in active[p]:
                active[p].add(worst)
                added = True
        if added:
            continue
        w_q_hz = min(max(w_q / (2 * math.pi), band_hz[0]), band_hz[1])  # ipopt's bound tolerance
        ratios, freqs = exact(w_q_hz)
        if ratios.min() >= threshold:
            answer = w_q_hz
            break
        # Exact peak between grid points, or instability: cut at the exact critical frequency,
        # else search below this cutoff.
        new_cut = False
        for p in np.flatnonzero(ratios < threshold):
            if math.isfinite(freqs[p]) and 0.0 < freqs[p] < nyquist:
                plants[p] = _with_frequency(plants[p], base, setting, float(freqs[p]))
                active[p].add(plants[p].w.size - 1)
                new_cut = True
        if not new_cut:
            log_hi = x - 1e-3
            x = min(x, log_hi)
    if math.isnan(answer) and feasible_scan:
        answer = scan_best   # the NLP could not improve on the verified scan point
    if not math.isnan(answer):
        ratios, _ = exact(answer)
    else:
        ratios = np.array([0.0])
    worst = int(np.argmin(ratios))
    feasible = bool(ratios.min() >= threshold) and not math.isnan(answer)
    agrees = feasible and (math.isnan(scan_best) or answer >= scan_best * 0.98)
    return TuningResult(
        observer=observer, w_q_hz=answer, worst_ratio=float(ratios.min()),
        worst_environment=plants[worst].label if not math.isnan(answer) else "",
        feasible=feasible, evaluations=evaluations, scan_w_q_hz=scan_best, agrees_with_scan=agrees,
        min_ratio=min_ratio, band_hz=(float(band_hz[0]), float(band_hz[1])), plants=len(plants), solver=info,
        at_bound=_at_bound(answer, band_hz, "band", "Hz") if feasible else None,
    )


def tune_q_shape(observer: str = "ea-fob", envs: Sequence[str] | str = ("soft", "stiff"), *,
                 w_q_hz: float = 10.0, uncertainty: float = 0.0, damping_range: tuple[float, float] = (0.3, 2.0),
                 controller: PDController = PDController(), break_at: str = "controller",
                 sigma: float = 0.0, seed: int = 0, sampled: bool = False, rate_hz: float = 2000.0,
                 delay_samples: int = 1, testbed: Any = None, executor: Executor | None = None) -> TuningResult:
    """Maximise the worst-case margin ratio at a fixed Q bandwidth over the Q damping.

    Parameters
    ----------
    observer : str
        Observer kind.
    envs : str or sequence of str
        Environment set (see :func:`environment_set`).
    w_q_hz : float
        Fixed cutoff [Hz].
    uncertainty : float
        Relative range of the true J, d, k_e [-].
    damping_range : (float, float)
        Bounds of the damping ratio zeta of Q = w_q^2 / (s^2 + 2 zeta w_q s + w_q^2) [-]
        (Butterworth: zeta = 1/sqrt(2); binomial: zeta = 1).
    controller : PDController
        C_F = P + D s.
    break_at : str
        Loop-break point.
    sigma : float
        Disk skew [-].
    seed : int
        Seed for ``random:N`` sets.
    sampled : bool
        Use the sampled-data loop (see :func:`tune_q`).
    rate_hz : float
        Sampling rate when ``sampled`` [Hz].
    delay_samples : int
        Computation delay when ``sampled`` [samples].
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`; None: Table 1).
    executor : Executor, optional
        Where the per-plant work runs (as in :func:`tune_q`); None: this process.

    Returns
    -------
    TuningResult
        ``q_damping`` holds the optimum; ``worst_ratio`` its exact worst-case ratio.

    Notes
    -----
    Epigraph NLP: maximise t subject to t^2 alpha_e^2 |num|^2 - |den|^2 <= 0 at the
    active frequencies of every plant (cutting planes as in :func:`tune_q`), over
    (zeta, t). Verified against a dense exact scan over zeta.
    """
    setting = _Setting(controller, break_at, float(sigma), bool(sampled), float(rate_hz), int(delay_samples))
    base = Compensator(kind=observer, w_q_hz=w_q_hz, q_family="butterworth", q_order=2)
    plants = _plants(base, envs, uncertainty, setting, seed, testbed=testbed, executor=executor)
    w_q = 2 * math.pi * w_q_hz
    import casadi as ca

    alpha = np.array([p.alpha_plant for p in plants])

    def exact_at(zeta: float) -> np.ndarray:
        comp = dataclasses.replace(base, q_damping=float(zeta))
        return _exact_ratios(plants, comp, setting, executor=executor)[0]

    zetas = np.linspace(*damping_range, 60)
    scan = np.array([exact_at(z).min() for z in zetas])
    z0 = float(zetas[int(np.argmax(scan))])
    active = []
    for plant in plants:
        u = 1j * plant.W / w_q
        mags = np.abs(_sensitivity_offset(plant, u**2 + 2 * z0 * u + 1, break_at, sigma))
        active.append(set(np.argsort(mags)[-_ACTIVE_PER_PLANT:].tolist()))
    zeta, info = z0, {}
    for _ in range(_MAX_CUTS):
        z = ca.SX.sym("zeta")
        t = ca.SX.sym("t")
        g = []
        for p, plant in enumerate(plants):
            idx = np.asarray(sorted(active[p]), dtype=int)
            for i, (top, den) in zip(idx, _casadi_abs2_G(
                    plant, idx, [1 - (plant.W[i] / w_q) ** 2 for i in idx], [2 * z * plant.W[i] / w_q for i in idx],
                    break_at, sigma)):
                g.append(t**2 * alpha[p] ** 2 * top - den)
        nlp = {"x": ca.vertcat(z, t), "f": -t, "g": ca.vertcat(*g)}
        sol, info = _ipopt(ca, nlp, [zeta, max(scan.max(), 0.1)], [damping_range[0], 0.0],
                           [damping_range[1], 10.0], [-ca.inf] * len(g), [0.0] * len(g))
        zeta = float(np.clip(sol[0], *damping_range))   # ipopt's bound tolerance
        added = False
        for p, plant in enumerate(plants):
            u = 1j * plant.W / w_q
            mags = np.abs(_sensitivity_offset(plant, u**2 + 2 * zeta * u + 1, break_at, sigma))
            worst = int(np.argmax(mags))
            if worst not in active[p] and 1.0 / (mags[worst] * alpha[p]) < sol[1] * (1 - 1e-9):
                active[p].add(worst)
                added = True
        if not added:
            break
    ratios = exact_at(zeta)
    best_scan = float(scan.max())
    if ratios.min() < best_scan:      # keep the verified better point
        zeta = float(zetas[int(np.argmax(scan))])
        ratios = exact_at(zeta)
    worst = int(np.argmin(ratios))
    return TuningResult(
        observer=observer, w_q_hz=w_q_hz, worst_ratio=float(ratios.min()), worst_environment=plants[worst].label,
        feasible=bool(ratios.min() > 0.0), evaluations=len(plants) * (len(zetas) + 2),
        scan_w_q_hz=w_q_hz, agrees_with_scan=bool(ratios.min() >= best_scan * 0.98), min_ratio=0.0,
        band_hz=(w_q_hz, w_q_hz), plants=len(plants), q_damping=zeta, solver=info,
        at_bound=_at_bound(zeta, damping_range, "Q damping range", ""),
    )


def _at_bound(value: float, bounds: tuple[float, float], what: str, unit: str) -> str | None:
    """Which end of a search range an answer sits on (within 0.1 %), in words, or None."""
    for end, name in zip(bounds, ("lower", "upper")):
        if abs(value - end) <= 1e-3 * abs(end):
            return f"{what} {name} end {end:g}{' ' + unit if unit else ''}"
    return None
