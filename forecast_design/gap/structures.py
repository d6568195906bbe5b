"""Each candidate's feature columns at its fixed nonlinear parameters (one :class:`_Structure` per grid point).

A candidate is linear in its coefficients once its nonlinear parameter (Stribeck velocity, bristle
displacement, delay, dead band) is fixed; this module builds those columns from a prepared log, once per
log (cached on :class:`.residuals.GapData`), and :mod:`.candidates` fits them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..effects import Effect
from .motion import motion_direction
from .residuals import GapData, delayed_input, gap_log_scales

_FRICTION = (Effect.COULOMB, Effect.STICTION, Effect.POSITION_FRICTION)


@dataclass(frozen=True, slots=True)
class _Coef:
    name: str
    parts: tuple[np.ndarray | None, ...]   # the column in each equation (GapData.equations), None where zero
    lo: float = -np.inf
    hi: float = np.inf

    @property
    def column(self) -> np.ndarray:
        """The column stacked over the equations, zeros where it does not act (``GapData.stack``)."""
        m = next(part.size for part in self.parts if part is not None)
        return np.concatenate([np.zeros(m) if part is None else part for part in self.parts])


def _design_matrix(coefs: Sequence[_Coef], rows: np.ndarray | None = None) -> np.ndarray:
    """The coefficients' stacked columns side by side (on ``rows`` only when given), one column at a time:
    ``np.column_stack`` of the stacked columns would hold each of them twice."""
    first = coefs[0].parts
    n = len(first) * next(part.size for part in first if part is not None)   # the stacked length, not built
    A = np.empty((n if rows is None else int(np.count_nonzero(rows)), len(coefs)))
    for j, c in enumerate(coefs):
        A[:, j] = c.column if rows is None else c.column[rows]
    return A


def _coef(data: GapData, name: str, per_equation: Mapping[str, np.ndarray], lo: float = -np.inf,
          hi: float = np.inf) -> _Coef:
    """A column kept per equation, stacked when used: the cached grids hold one decimated column per coefficient."""
    return _Coef(name, tuple(per_equation.get(eq) for eq in data.equations), lo, hi)


def _dahl(v: np.ndarray, dt: float, x_p: float, chunk: int = 1 << 16) -> np.ndarray:
    """Direction state of a Dahl/LuGre bristle: s' = (v - |v| s) / x_p, implicit Euler, s(0) = sign(v0)."""
    a = dt / x_p
    # the same float operations as (s + a v_k) / (1 + a |v_k|) step by step, the products vectorised;
    # `chunk` samples at a time, as a Python list of a whole log takes 32 B per sample and list
    out, sk = np.empty(v.size), float(np.sign(v[0])) if v.size else 0.0
    for start in range(0, v.size, chunk):
        part, states = v[start:start + chunk], []
        for ak, dk in zip((a * part).tolist(), (1.0 + a * np.abs(part)).tolist()):
            sk = (sk + ak) / dk
            states.append(sk)
        out[start:start + part.size] = states
    return out


def _sign(data: GapData) -> np.ndarray:
    """Direction of the kinetic friction at the raw rate (:func:`.motion.motion_direction`), 0 where unresolved.

    The dead band is the encoder's speed resolution (one step per derivative-filter window,
    :attr:`forecast_design.plausibility.LogScales.speed_resolution`, 0.6 mrad/s on the
    testbed at 2 kHz): below it the sign of the filtered speed is quantisation noise, and a
    motor at rest has a set-valued friction that the soft threshold on the ``stuck`` rows
    explains. It is deliberately *not* ``GapOptions.stick_velocity`` (2 mrad/s), the speed
    below which a *decimated* row may be stuck: a motor passing through a reversal at
    1-2 mrad/s still moves and feels the full ``F_c`` (Coulomb's law does not depend on the
    speed). A dead band that wide zeroed the feature for the ~10 raw samples each slow
    reversal spends inside it, so the decimated sign column lacked ``2 F_c`` times that time
    at every reversal; the anti-alias filters smear that hole into the neighbouring
    *moving* rows, where a Stribeck bump ``sign(v) exp(-(v/v_s)^2)`` with ``v_s`` just
    above the band (non-zero exactly next to the hole) fills it in. Coulomb logs in closed
    loop (slow sine reversals) were then named ``stiction`` with ``F_s ~ 3 F_c``. A motor creeping below
    the resolution in one direction between two samples that resolve it moves that way and is not at rest.
    """
    return motion_direction(data)


@dataclass(frozen=True, slots=True)
class _Structure:
    """A candidate at fixed nonlinear parameters: its coefficients and how to read them."""

    coefs: list[_Coef]
    to_params: Callable[[np.ndarray], dict[str, Any]]
    level: Callable[[np.ndarray], np.ndarray | float] | None = None   # breakaway level on motor rows
    n_params: int = 0
    # groups of effect-coefficient indices that must each differ from zero (Wald test) for the
    # effect to count, and the grid parameters with their grid ends: (name, value, lo, hi)
    tests: tuple[tuple[int, ...], ...] = ((0,),)
    grid: tuple[tuple[str, float, float, float], ...] = ()


def _structures(effect: Effect, data: GapData) -> list[_Structure]:
    """All grid points of one candidate (built once per log and cached on ``data``)."""
    key = ("structures", effect)
    if key not in data.cache:
        data.cache[key] = _build_structures(effect, data)
    return data.cache[key]


def _build_structures(effect: Effect, data: GapData) -> list[_Structure]:
    c = data.columns
    opts = data.options
    tb = data.experiment.design.testbed
    env = data.experiment.design.environment
    nh = opts.n_harmonics
    out: list[_Structure] = []
    if effect is Effect.TORQUE_GAIN:
        out.append(_Structure([_coef(data, "c", {"motor": c["u"]}, -np.inf, 1.0)],
                              lambda p: {"gain": float(1.0 - p[0])}, n_params=1))
    elif effect is Effect.COULOMB:
        sign = _sign(data)
        pos, neg = data.decimate_many(f(sign, 0.0) for f in (np.maximum, np.minimum))
        # a level per direction of motion (friction often differs by direction), both >= 0: a constant
        # torque, which would need a negative level one way, is not friction
        out.append(_Structure([_coef(data, "F_c", {"motor": pos}, 0.0),
                               _coef(data, "F_c_neg", {"motor": neg}, 0.0)],
                              lambda p: {"F_c": float(p[0]), "F_c_neg": float(p[1])},
                              level=lambda p: max(p[0], p[1]), n_params=2, tests=((0, 1),)))
    elif effect is Effect.STICTION:
        # LuGre-type friction: presliding (bristle) direction state s in [-1, 1] with
        # presliding displacement x_p, a Stribeck bump of width v_s and bristle damping. Its Coulomb
        # level is tested on its own too: a bump with F_c = 0 (on its bound) is a narrow spike at
        # the reversals, which a delay in closed loop makes, not friction.
        v = data.raw["v"]
        dt = 1.0 / data.experiment.rate_hz
        # searches bounded by the log: a Stribeck bump narrower than twice the speed resolution, or a
        # presliding displacement below one encoder count, is not resolved and would only fit noise
        scales = gap_log_scales(data)
        v_lo = max(1e-3, 2.0 * scales.speed_resolution)
        x_lo = max(1e-4, scales.encoder_step)
        x_grid, v_grid = np.geomspace(x_lo, max(1e-2, 10 * x_lo), 5), np.geomspace(v_lo, max(0.3, 10 * v_lo), 6)
        for x_p in x_grid:
            s = _dahl(v, dt, x_p)
            # raw-rate columns made and decimated one at a time (8 B per sample each); levels and damping shared
            columns = [lambda: np.maximum(s, 0.0), lambda: np.gradient(s, dt) * x_p, lambda: np.minimum(s, 0.0)] + \
                [lambda v_s=v_s: s * np.exp(-(v / v_s) ** 2) for v_s in v_grid]
            pos, damp, neg, *dec_bumps = data.decimate_many(make() for make in columns)
            c_pos, c_damp, c_neg = (_coef(data, name, {"motor": col}, 0.0)
                                    for name, col in (("F_c", pos), ("sigma1", damp), ("F_c_neg", neg)))
            for v_s, bump in zip(v_grid, dec_bumps):
                out.append(_Structure(
                    [c_pos, _coef(data, "dF", {"motor": bump}, 0.0), c_damp, c_neg],
                    lambda p, v_s=v_s, x_p=x_p: {"F_s": float(p[0] + p[1]), "F_c": float(p[0]), "v_s": float(v_s),
                                                 "sigma0": float((p[0] + p[1]) / x_p), "sigma1": float(p[2]),
                                                 "F_c_neg": float(p[3])},
                    level=lambda p: max(p[0], p[3]) + p[1], n_params=6, tests=((0, 1, 3), (0,)),
                    grid=(("v_s", float(v_s), float(v_grid[0]), float(v_grid[-1])),
                          ("x_p", float(x_p), float(x_grid[0]), float(x_grid[-1])))))
        # Static (switched) Stribeck friction without presliding, x_p -> 0: the Coulomb candidate's
        # sign feature plus a Stribeck bump, the breakaway level F_s holding the motor at rest.
        # It nests coulomb (dF = 0), so stiction is never worse than coulomb on the fit blocks,
        # whatever the hardware's sticking mechanism (bristles or a true stick-slip switch).
        sign = _sign(data)
        columns = [lambda: np.maximum(sign, 0.0), lambda: np.minimum(sign, 0.0)] + \
            [lambda v_s=v_s: sign * np.exp(-(v / v_s) ** 2) for v_s in v_grid]
        pos, neg, *dec_bumps = data.decimate_many(make() for make in columns)
        c_pos, c_neg = (_coef(data, name, {"motor": col}, 0.0) for name, col in (("F_c", pos), ("F_c_neg", neg)))
        for v_s, bump in zip(v_grid, dec_bumps):
            out.append(_Structure(
                [c_pos, _coef(data, "dF", {"motor": bump}, 0.0), c_neg],
                lambda p, v_s=v_s: {"F_s": float(p[0] + p[1]), "F_c": float(p[0]), "v_s": float(v_s),
                                    "F_c_neg": float(p[2])},
                level=lambda p: max(p[0], p[2]) + p[1], n_params=4, tests=((0, 1, 2), (0,)),
                grid=(("v_s", float(v_s), float(v_grid[0]), float(v_grid[-1])),)))
    elif effect in (Effect.COGGING, Effect.POSITION_FRICTION):
        th = data.raw["theta"]
        base = _sign(data) if effect is Effect.POSITION_FRICTION else np.ones_like(th)
        coefs = []
        raw = (base * f(i * th) for i in range(1, nh + 1) for f in (np.sin, np.cos))
        first = [base] if effect is Effect.POSITION_FRICTION else []
        dec = list(data.decimate_many(col for part in (first, raw) for col in part))   # one column at a time
        if effect is Effect.POSITION_FRICTION:
            coefs.append(_coef(data, "F_c", {"motor": dec.pop(0)}, 0.0))
        for i in range(1, nh + 1):
            coefs.append(_coef(data, f"a{i}", {"motor": dec[2 * i - 2]}))
            coefs.append(_coef(data, f"b{i}", {"motor": dec[2 * i - 1]}))
        th_sub = c["theta_sub"]

        def harm(p: np.ndarray, off: int) -> tuple[list[float], list[float]]:
            return ([float(p[off + 2 * i]) for i in range(nh)], [float(p[off + 2 * i + 1]) for i in range(nh)])

        if effect is Effect.COGGING:
            out.append(_Structure(coefs, lambda p: dict(zip(("a", "b"), harm(p, 0))), n_params=2 * nh,
                                  tests=(tuple(range(2 * nh)),)))
        else:
            def level(p: np.ndarray) -> np.ndarray:
                lv = np.full(th_sub.shape, p[0])
                for i in range(1, nh + 1):
                    lv += p[2 * i - 1] * np.sin(i * th_sub) + p[2 * i] * np.cos(i * th_sub)
                return lv

            out.append(_Structure(coefs, lambda p: {"F_c": float(p[0]), **dict(zip(("a", "b"), harm(p, 1)))},
                                  level=level, n_params=2 * nh + 1, tests=((0,), tuple(range(1, 2 * nh + 1)))))
    elif effect is Effect.DELAY:
        d_grid = np.geomspace(DELAY_GRID_START_S, opts.max_delay_s, DELAY_GRID_POINTS)
        out += delay_structures(data, d_grid, (float(d_grid[0]), float(d_grid[-1])))
    elif effect is Effect.BACKLASH:
        x = data.raw["x"]
        span = float(np.percentile(np.abs(x), 99))
        step = gap_log_scales(data).encoder_step
        if span <= 2.0 * step:
            return out
        # a dead band below an encoder count is not resolved: the search starts there
        # up to the largest deflection less a count, where the spring still engages at all (0.8 of the 99th
        # percentile stopped short of true dead bands the spring leaves only at the extremes of the motion)
        h_grid = np.geomspace(max(span * 1e-4, 1e-6, step), max(float(np.max(np.abs(x))) - step, 0.8 * span), 30)
        out += dead_band_structures(data, h_grid, (2.0 * h_grid[0], 2.0 * h_grid[-1]))
    elif effect is Effect.ENVIRONMENT_MISMATCH:
        if data.locked:
            return out
        coefs = [_coef(data, "dJ", {"environment": c["qa"]}, -env.J),
                 _coef(data, "dd", {"environment": c["qv"]}, -env.d),
                 _coef(data, "dk_e", {"environment": c["q"]}, -env.k_e)]

        def to_params(p: np.ndarray) -> dict[str, Any]:
            out_p: dict[str, Any] = {"J": float(env.J + p[0]), "d": float(env.d + p[1]),
                                     "k_e": float(env.k_e + p[2])}
            for name, nom, dp in (("J_scale", env.J, p[0]), ("d_scale", env.d, p[1]),
                                  ("k_e_scale", env.k_e, p[2])):
                if nom > 0:
                    out_p[name] = float((nom + dp) / nom)
            return out_p

        out.append(_Structure(coefs, to_params, n_params=3, tests=((0, 1, 2),)))
    return out


#: The delay search: from this delay [s] to ``GapOptions.max_delay_s`` in this many log-spaced points (20 % steps at
#: the default 20 ms; :func:`.candidates._best_on_grid` searches the steps next to the best point finer).
DELAY_GRID_START_S, DELAY_GRID_POINTS = 0.1e-3, 30


def delay_structures(data: GapData, delays: Sequence[float], search: tuple[float, float]) -> list[_Structure]:
    """A delay at given values: the motor receives ``u(t - delay)``, ``c (u - u(t - delay))`` less than ``u``.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    delays : sequence of float
        Delays [s], > 0.
    search : (float, float)
        Ends of the whole search [s] (a fit there is ``at_bound``).

    Returns
    -------
    list of _Structure
        One per delay; coefficient ``c`` in [0, 1.5] (``c = 1``: a pure delay).
    """
    u = data.columns["u"]
    rate = data.experiment.rate_hz
    delayed = data.decimate_many(delayed_input(data.raw["tau_m"], float(delay), rate) for delay in delays)
    return [_Structure([_coef(data, "c", {"motor": u - dec}, 0.0, 1.5)],
                       lambda p, d=float(delay): {"delay_s": d}, n_params=2,
                       grid=(("delay_s", float(delay), float(search[0]), float(search[1])),))
            for delay, dec in zip(delays, delayed)]


def dead_band_structures(data: GapData, halves: Sequence[float], search: tuple[float, float]) -> list[_Structure]:
    """Backlash at given half-widths: the spring torque loses ``c k clip(x, +-h)`` (``c = 1``: a dead band).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    halves : sequence of float
        Half-widths ``h`` of the dead band [rad].
    search : (float, float)
        The search's first and last full width [rad] (the grid's ends, for the bound checks).

    Returns
    -------
    list of _Structure
        One structure per half-width, in the given order.
    """
    k = data.experiment.design.testbed.k
    out = []
    for half, dec in zip(halves, data.decimate_many(np.clip(data.raw["x"], -h, h) for h in halves)):
        clip = k * dec
        cols = {"coupling": -clip} if data.tau_s_measured else {"motor": -clip, "environment": clip}
        out.append(_Structure([_coef(data, "c", cols, 0.0, 2.0)], lambda p, h=half: {"width_rad": float(2.0 * h)},
                              n_params=2, grid=(("width_rad", float(2 * half), float(search[0]), float(search[1])),)))
    return out


def _j_held(s: _Structure) -> _Structure:
    """The environment structure with ``J`` held at its declared value: only ``d`` and ``k_e`` move.

    ``J`` and ``J_scale`` are left out of the parameters (not reported as known: nothing estimates them).
    """
    names = [c.name for c in s.coefs]
    assert names[0] == "dJ", "the inertia comes first"

    def to_params(p: np.ndarray) -> dict[str, Any]:
        return {k: v for k, v in s.to_params(np.insert(np.asarray(p, dtype=float), 0, 0.0)).items()
                if k not in ("J", "J_scale")}

    return _Structure(s.coefs[1:], to_params, n_params=s.n_params - 1, tests=((0, 1),))


def j_held(params: Mapping[str, Any]) -> bool:
    """Whether an environment fit held ``J`` at its declared value (it reports ``d_scale`` without ``J_scale``)."""
    return "d_scale" in params and "J_scale" not in params

