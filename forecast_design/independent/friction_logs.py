"""Independent log generator: friction logs (see the package docstring)."""

from __future__ import annotations

import math
import re
from typing import Any, Mapping

import numpy as np

from ..effects import Effect
from ..errors import ParameterError
from ..experiment import Experiment
from ..params import Testbed, environment_preset
from .model import Excitation, FRICTION_LAWS, IndependentCase
from .plant import simulate_independent
from .draw import _FRICTION_DEFAULTS, _motor_gain, _static_friction

def _friction_names(law: str, params: Mapping[str, float]) -> tuple[str, ...]:
    if law == "extended-sfm":
        n = max([int(m.group(2)) for m in (re.match(r"^(sin|cos)(\d+)$", k) for k in params) if m] or [0])
        return ("viscous", "coulomb") + tuple(f"{f}{i}" for i in range(1, n + 1) for f in ("sin", "cos"))
    return tuple(_FRICTION_DEFAULTS[law])


def friction_log(law: str, params: Mapping[str, float] | None = None, *, duration_s: float = 20.0,
                 rate_hz: float = 2000.0, seed: int = 0,
                 excitation: str = "sliding") -> tuple[Experiment, dict[str, float]]:
    """An open-loop link-only log with a known friction law, for identification tests.

    Parameters
    ----------
    law : str
        ``extended-sfm`` (viscous + Coulomb + angle harmonics, with true
        sticking), ``stribeck`` (event-based stick/slip on the Stribeck curve)
        or ``lugre`` (LuGre bristle dynamics).
    params : Mapping[str, float], optional
        True parameters named as :func:`forecast_design.friction.friction_model`
        names them (``viscous``, ``coulomb``, ``sin1``, ``cos1`` ...;
        ``static``, ``stribeck_velocity``; ``sigma0``, ``sigma1``); missing
        names take typical values. ``viscous`` is the motor's ``d_m``.
    duration_s : float
        Log length [s].
    rate_hz : float
        Log rate [Hz].
    seed : int
        Seed of the excitation's dither and the initial angle.
    excitation : str
        ``sliding``: slow sweeps over several revolutions (extended SFM) or slow
        triangles through the breakaway level (Stribeck, LuGre), with dither:
        plenty of sliding and slow breakaways. ``little-sliding``: the command
        barely exceeds the breakaway level, in one direction only.

    Returns
    -------
    experiment : Experiment
        The log (``tau_s`` omitted, so derived as ``k (theta - q)``; the TOML
        testbed is the simulated one).
    params : dict
        The true parameters, one per name of the law's model.
    """
    if law not in FRICTION_LAWS:
        raise ParameterError(f"friction law must be one of {', '.join(FRICTION_LAWS)}, got {law!r}",
                             name="law", value=law)
    if excitation not in ("sliding", "little-sliding"):
        raise ParameterError(f"excitation must be 'sliding' or 'little-sliding', got {excitation!r}",
                             name="excitation", value=excitation)
    given = dict(params or {})
    base = dict(_FRICTION_DEFAULTS[law])
    if law == "extended-sfm" and any(re.match(r"^(sin|cos)\d+$", k) for k in given):
        base = {k: v for k, v in base.items() if not re.match(r"^(sin|cos)\d+$", k)}
    base.update(given)
    names = _friction_names(law, base)
    unknown = [k for k in base if k not in names]
    if unknown:
        raise ParameterError(f"unknown {law} parameter(s) {', '.join(unknown)}; expected {', '.join(names)}",
                             name=unknown[0])
    true = {n: float(base.get(n, 0.0)) for n in names}
    if law == "extended-sfm":
        n_h = (len(names) - 2) // 2
        eff: dict[str, Any] = {"F_c": true["coulomb"],
                               "cog_a": tuple(true[f"sin{i}"] for i in range(1, n_h + 1)),
                               "cog_b": tuple(true[f"cos{i}"] for i in range(1, n_h + 1))}
        words: tuple[Effect, ...] = (Effect.COULOMB, Effect.COGGING)
    else:
        eff = {"F_c": true["coulomb"], "F_s": true["static"], "v_s": true["stribeck_velocity"]}
        if law == "lugre":
            eff.update(sigma0=true["sigma0"], sigma1=true["sigma1"])
        words = (Effect.STICTION,)
    tb = Testbed(J_m=Testbed.nominal().J_m, d_m=true["viscous"], k=Testbed.nominal().k)
    env = environment_preset("link-only")
    holding = _static_friction(eff)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xF1C]))
    if excitation == "little-sliding":
        level = max(holding, 0.05)
        ex = Excitation(kind="sweep", amplitude=0.52 * level, offset=0.5 * level, f_lo_hz=3.0 / duration_s)
    elif law == "extended-sfm":
        f = float(rng.uniform(1.5, 2.0)) / duration_s
        amp = min(2.0 * math.pi / _motor_gain(tb, env, f) + 1.5 * holding, 3.5)
        ex = Excitation(kind="sweep", amplitude=amp, f_lo_hz=f, dither=0.1 * max(holding, 0.1))
    else:
        ex = Excitation(kind="triangle", amplitude=2.5 * max(holding, 0.1),
                        period_s=duration_s / float(rng.uniform(3.5, 5.0)), dither=0.05 * max(holding, 0.1))
    case = IndependentCase(words=words, environment=env, environment_name="link-only", excitation=ex,
                           rate_hz=rate_hz, duration_s=duration_s, testbed=tb, effect_params=eff,
                           initial_angle=0.0, seed=int(rng.integers(0, 2**62)), tau_m_digits=9)
    exp, _ = simulate_independent(case)
    return exp, true
