"""The loops a Q tuning evaluates: environment sets, per-plant frequency responses and exact margin checks."""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..loops.response import LoopResponse, loop_response, observer_responses, q_argument, sensitivity
from ..loops import COMMAND_DELAY_SAMPLES
from ..executor import Executor
from ..margins import disk_margin, disk_margins
from ..errors import ParameterError
from ..limits import check_limit, check_physical
from ..environments import resolve_environments, resolve_testbed
from ..params import Compensator, Design, Environment
from ..controllers import PAPER_PD, Controller, resolve_controller


_GRID_POINTS = 700
_GRID_RAD_S = np.logspace(-2, 4.5, _GRID_POINTS)   # constraint/verification grid [rad/s]
_ACTIVE_PER_PLANT = 4                     # frequencies per plant in the first NLP
_MAX_CUTS = 12                            # cutting-plane rounds
_FEAS_RTOL = 1e-6                         # relative slack of the ratio requirement inside the NLP
_BACKOFF_STEPS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)   # relative cutoff steps down to meet it exactly
_CERTIFY_ROUNDS = 3                       # re-tunings with a certified interior worst point added
_BATCH_MARGINS = True                     # exact margins of many loops in one disk_margins call
_FIRST_BATCH = 8                          # plants in the first batch of an early-stopping check


@dataclass(frozen=True, slots=True)
class _Setting:
    """What every loop of one tuning shares."""

    controller: Controller
    break_at: str
    sigma: float
    sampled: bool = False
    rate_hz: float = 2000.0
    delay_samples: int = COMMAND_DELAY_SAMPLES

    def __post_init__(self) -> None:
        object.__setattr__(self, "controller", resolve_controller(self.controller))
        if not self.sampled and not self.controller.is_continuous:
            raise ParameterError(f"controller {self.controller.spelling()} is discrete: tune the sampled loop "
                                 "(--sampled, at its rate)", name="controller", value=self.controller.kind)
        check_physical("tuning", "rate_hz", self.rate_hz)
        delay = self.delay_samples   # given as passed (an integral float is accepted, inf or 1.5 are not)
        if isinstance(delay, float) and delay.is_integer():
            delay = int(delay)
        object.__setattr__(self, "delay_samples", check_limit("delay_samples", "delay_samples", delay))

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
        from ..loops.sampled import sampled_force_loop

        dm = sampled_force_loop(true_design, compensator, controller=setting.controller, believed=believed,
                                rate_hz=setting.rate_hz, break_at=setting.break_at,
                                delay_samples=setting.delay_samples).disk_margin(setting.sigma)
    else:
        from ..loops import force_loop

        loop = force_loop(true_design, compensator, controller=setting.controller, believed=believed,
                          break_at=setting.break_at)
        dm = disk_margin(loop.L, setting.sigma, closed_loop_stable=loop.stable)
    return dm.alpha, dm.frequency_rad_s


def _exact_margins(pairs: Sequence[tuple[Design, Design]], compensator: Compensator | None,
                   setting: _Setting) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_exact_ratio` of many ``(true_design, believed)`` pairs: exact margins and critical
    frequencies [rad/s].

    Continuous loops go through one :func:`~forecast_design.margins.disk_margins` call
    (the same exact peak and the loops' own stability flags); sampled loops, or
    ``_BATCH_MARGINS`` off, one :func:`~forecast_design.margins.disk_margin` per loop.
    """
    if setting.sampled or not _BATCH_MARGINS:
        out = [_exact_ratio(true, believed, compensator, setting) for true, believed in pairs]
        return np.array([a for a, _ in out], dtype=float), np.array([f for _, f in out], dtype=float)
    from ..loops import force_loop

    loops = [force_loop(true, compensator, controller=setting.controller, believed=believed,
                        break_at=setting.break_at) for true, believed in pairs]
    batch = disk_margins([lp.L for lp in loops], setting.sigma, closed_loop_stable=[lp.stable for lp in loops])
    return batch.alpha, batch.w_peak_rad_s


def _q_polynomial(compensator: Compensator) -> np.ndarray:
    """Coefficients (ascending powers of s/w_q) of D_q, Q = 1/D_q(s/w_q)."""
    from ..symbolic import compensator_q_tf

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
    todo = np.arange(len(plants)) if order is None else np.asarray(order, dtype=int)
    # with an early stop: a few plants first (the order puts those closest to failing first),
    # then batches four times larger; otherwise every plant in one batch
    size = todo.size if stop_below is None or not _BATCH_MARGINS else _FIRST_BATCH
    n = 0
    while n < todo.size:
        part = todo[n:n + size]
        if not _BATCH_MARGINS and stop_below is not None:
            part = part[:1]
        alpha, freqs[part] = _exact_margins([(plants[i].true_design, plants[i].believed) for i in part],
                                            compensator, setting)
        ratios[part] = alpha / np.array([plants[i].alpha_plant for i in part])
        n += part.size
        size *= 4
        if stop_below is not None and np.any(ratios[part] < stop_below):
            break
    return ratios, freqs, n


def worst_case_ratio(compensator: Compensator, envs: Sequence[str] | str = ("soft", "stiff"), *,
                     uncertainty: float = 0.0, controller: Controller = PAPER_PD,
                     break_at: str = "controller", sigma: float = 0.0, sampled: bool = False,
                     rate_hz: float = 2000.0, delay_samples: int = COMMAND_DELAY_SAMPLES, seed: int = 0,
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
    controller : Controller, str or python-control system
        The force controller (continuous: C(s); sampled: its difference equation).
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
    setting = _Setting(controller, break_at, float(sigma), bool(sampled), float(rate_hz), delay_samples)
    plants = _plants(compensator, envs, uncertainty, setting, seed, testbed=testbed)
    ratios, _, _ = _exact_ratios(plants, compensator, setting)
    i = int(np.argmin(ratios))
    return float(ratios[i]), plants[i].label


def _plant_of(item: tuple) -> _Plant:
    """One plant of the set from ``(label, true_design, believed, compensator, setting)`` (an executor task)."""
    label, true_design, believed, compensator, setting = item
    alpha = float(_exact_margins([(true_design, true_design)], None, setting)[0][0])
    W, CP, M, dm = _responses(true_design, believed, compensator, setting, setting.grid(), {})
    return _Plant(label, true_design, believed, alpha, setting.grid(), W, CP, M, dm)


def _exact_of(item: tuple) -> tuple[float, float]:
    """:func:`_exact_ratio` of ``(true_design, believed, compensator, setting)`` (an executor task), through
    :func:`_exact_margins` as in this process (a loop's batched margin does not depend on the batch)."""
    true_design, believed, compensator, setting = item
    alpha, freq = _exact_margins([(true_design, believed)], compensator, setting)
    return float(alpha[0]), float(freq[0])


def _batch_size(executor: Executor, n: int) -> int:
    """Items per task: about four tasks per worker (coarse tasks; results do not depend on it)."""
    return max(1, math.ceil(n / (4 * max(1, executor.workers))))


def _plants(compensator: Compensator, envs, uncertainty: float, setting: _Setting, seed: int = 0,
            progress: Callable[[int, int], None] | None = None, testbed: Any = None,
            executor: Executor | None = None, extra: Sequence = ()) -> list[_Plant]:
    if not compensator.is_observer:
        raise ParameterError(f"tuning needs an observer kind (ea-fob, lo-dob, ld-dob, motor-fob), "
                             f"got {compensator.kind!r}", name="observer", value=compensator.kind)
    if setting.break_at not in ("controller", "plant-input"):
        raise ParameterError(f"break_at must be 'controller' or 'plant-input', got {setting.break_at!r}",
                             name="break_at", value=setting.break_at)
    if executor is not None and not isinstance(executor, Executor):
        raise ParameterError(f"executor must be an Executor (forecast_design.executor.make_executor) or None, got "
                             f"{type(executor).__name__}", name="executor", value=executor)
    base = Design(testbed=resolve_testbed(testbed))
    w = setting.grid()
    cache: dict = {}
    pairs = environment_set(envs, uncertainty=uncertainty, seed=seed, testbed=base.testbed) + list(extra)
    if executor is not None:
        items = [(label, dataclasses.replace(base, environment=true), dataclasses.replace(base, environment=bel),
                  compensator, setting) for label, true, bel in pairs]
        return _require_stable_plants(executor.map_batched(_plant_of, items, batch_size=_batch_size(executor,
                                                                                                    len(items)),
                                                           progress=progress), setting)
    designs = [(label, dataclasses.replace(base, environment=true), dataclasses.replace(base, environment=bel))
               for label, true, bel in pairs]
    unique = list(dict.fromkeys(true_design for _, true_design, _ in designs))
    alone = dict(zip(unique, (float(a) for a in _exact_margins([(d, d) for d in unique], None, setting)[0])))
    out = []
    for n, (label, true_design, believed) in enumerate(designs):
        W, CP, M, dm = _responses(true_design, believed, compensator, setting, w, cache)
        out.append(_Plant(label, true_design, believed, alone[true_design], w, W, CP, M, dm))
        if progress:
            progress(n + 1, len(pairs))
    return _require_stable_plants(out, setting)


def _require_stable_plants(plants: list, setting: _Setting) -> list:
    """The plants, or a one-line refusal when the loop without observer is unstable in one of them:
    a margin ratio to an unstable loop (margin 0) means nothing."""
    bad = [p.label for p in plants if not p.alpha_plant > 0.0]
    if bad:
        raise ParameterError(
            f"the force loop with controller {setting.controller.spelling()} and no observer is unstable in "
            f"{len(bad)} of {len(plants)} environments (first: {bad[0]}): no cutoff has a margin ratio to an unstable "
            "loop; choose a controller that stabilises every environment of the set (check it with "
            "forecast-design margins --controller ... --env ...)", name="controller", value=bad[0])
    return plants


def _with_frequency(plant: _Plant, compensator: Compensator, setting: _Setting, w_new: float) -> _Plant:
    """The plant with one more grid frequency (a cut at an exact peak between grid points)."""
    w = np.append(plant.w, w_new)
    W, CP, M, dm = _responses(plant.true_design, plant.believed, compensator, setting, np.array([w_new]), {})
    return dataclasses.replace(plant, w=w, W=np.append(plant.W, W), CP=np.append(plant.CP, CP),
                               M=np.append(plant.M, M), dm=np.append(plant.dm, dm))
