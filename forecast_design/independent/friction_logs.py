"""Independent log generator: friction logs (see the package docstring)."""

from __future__ import annotations

import math
import re
from typing import Any, Mapping

import numpy as np

from ..effects import Effect
from ..errors import ParameterError
from ..experiment import Experiment
from ..controllers import PD
from ..params import Testbed, environment_preset
from .model import COUNTS_PER_REV, Excitation, FRICTION_LAWS, IndependentCase
from .plant import simulate_independent
from .draw import _FRICTION_DEFAULTS, _motor_gain, _static_friction

#: Excitations of :func:`friction_log`: open loop (``sliding``, ``little-sliding``) or the force
#: reference of a closed loop (``multisine``, ``square``).
FRICTION_EXCITATIONS = ("sliding", "little-sliding", "presliding", "multisine", "square")


#: The harmonic parameter names of the angle-dependent laws: ``sin<i>``/``cos<i>`` (added to the friction,
#: extended SFM) and ``coulomb_sin<i>``/``coulomb_cos<i>`` (of the Coulomb level, position friction).
_HARMONIC_PREFIX = {"extended-sfm": "", "position-friction": "coulomb_"}


def _harmonic_re(law: str) -> re.Pattern:
    return re.compile(rf"^{_HARMONIC_PREFIX[law]}(sin|cos)(\d+)$")


def _friction_names(law: str, params: Mapping[str, float]) -> tuple[str, ...]:
    if law in _HARMONIC_PREFIX:
        n = max([int(m.group(2)) for m in (_harmonic_re(law).match(k) for k in params) if m] or [0])
        pre = _HARMONIC_PREFIX[law]
        return ("viscous", "coulomb") + tuple(f"{pre}{f}{i}" for i in range(1, n + 1) for f in ("sin", "cos"))
    return tuple(_FRICTION_DEFAULTS[law])


def _effect_params(law: str, true: Mapping[str, float]) -> tuple[dict[str, Any], tuple[Effect, ...], float]:
    """The plant's effect parameters, the effect words and the true d_m of a friction law's parameters."""
    if law in _HARMONIC_PREFIX:
        n_h, pre = (len(true) - 2) // 2, _HARMONIC_PREFIX[law]
        a = tuple(true[f"{pre}sin{i}"] for i in range(1, n_h + 1))
        b = tuple(true[f"{pre}cos{i}"] for i in range(1, n_h + 1))
        if law == "position-friction":     # the Coulomb level varies with the angle: F_c + sum a_i sin + b_i cos
            return {"F_c": true["coulomb"], "pos_a": a, "pos_b": b}, (Effect.POSITION_FRICTION,), true["viscous"]
        eff: dict[str, Any] = {"F_c": true["coulomb"], "cog_a": a, "cog_b": b}
        return eff, (Effect.COULOMB, Effect.COGGING), true["viscous"]
    if law == "sfm":
        return {"F_c": true["coulomb"]}, (Effect.COULOMB,), true["viscous"]
    if law == "asymmetric":
        eff = {"F_c": true["coulomb_pos"], "F_c_neg": true["coulomb_neg"], "d_neg": true["viscous_neg"]}
        return eff, (Effect.COULOMB,), true["viscous_pos"]
    eff = {"F_c": true["coulomb"], "F_s": true["static"], "v_s": true["stribeck_velocity"]}
    if law == "lugre":
        eff.update(sigma0=true["sigma0"], sigma1=true["sigma1"])
    return eff, (Effect.STICTION,), true["viscous"]


def friction_log(law: str, params: Mapping[str, float] | None = None, *, duration_s: float = 20.0,
                 rate_hz: float = 2000.0, seed: int = 0, excitation: str = "sliding", loop: str = "open",
                 environment: str = "link-only", controller: PD | None = None,
                 encoder_counts: int = COUNTS_PER_REV, testbed: Testbed | None = None,
                 tau_s_logging: str = "omitted", encoder_noise_counts: float = 0.0) -> tuple[Experiment, dict[str, float]]:
    """A log with a known friction law, for identification tests.

    Parameters
    ----------
    law : str
        ``sfm`` (viscous + Coulomb with true sticking), ``extended-sfm`` (and angle
        harmonics added to the friction), ``position-friction`` (a Coulomb level that
        varies with the angle, ``coulomb + sum coulomb_sin<i> sin(i theta) + coulomb_cos<i>
        cos(i theta)``), ``asymmetric`` (Coulomb level and viscous coefficient differ by
        direction of motion), ``stribeck`` (event-based stick/slip on the Stribeck curve)
        or ``lugre`` (LuGre bristle dynamics).
    params : Mapping[str, float], optional
        True parameters named as :func:`forecast_design.friction.friction_model`
        names them (``viscous``, ``coulomb``, ``sin1``, ``cos1`` ...; ``coulomb_sin1`` ...; ``viscous_pos``,
        ``viscous_neg``, ``coulomb_pos``, ``coulomb_neg``; ``static``,
        ``stribeck_velocity``; ``sigma0``, ``sigma1``); missing names take typical values.
        ``viscous`` (``viscous_pos``) is the motor's ``d_m``.
    duration_s : float
        Log length [s].
    rate_hz : float
        Log rate [Hz].
    seed : int
        Seed of the excitation's dither and the initial angle.
    excitation : str
        Open loop: ``sliding`` (slow sweeps over several revolutions for the SFM laws,
        slow triangles through the breakaway level for Stribeck and LuGre, with
        dither), ``little-sliding`` (the command barely exceeds the breakaway level,
        in one direction only) or ``presliding`` (a slow sine with dither that stays
        below the breakaway level both ways: the motor never slides; LuGre bristles
        deflect). Closed loop: the force reference, ``multisine`` (0.1-5 Hz) or ``square``.
    loop : str
        ``open`` (the command is the excitation) or ``closed`` (a PD force controller
        tracks the excitation on the measured ``tau_s``).
    environment : str
        Environment preset (default ``link-only``).
    controller : PD, optional
        Closed loop: the PD gains (default P 5, D 0.1).
    encoder_counts : int
        Counts per revolution of the encoders [-].
    testbed : Testbed, optional
        The SEA (``J_m``, ``k``; its ``d_m`` is replaced by the viscous coefficient);
        default the Forecast testbed.
    tau_s_logging : str
        How the logger writes ``tau_s`` (:class:`IndependentCase`), default omitted.
    encoder_noise_counts : float
        Standard deviation of the encoders' noise before quantisation [counts].

    Returns
    -------
    experiment : Experiment
        The log (the TOML testbed is the simulated one).
    params : dict
        The true parameters, one per name of the law's model.
    """
    if law not in FRICTION_LAWS:
        raise ParameterError(f"friction law must be one of {', '.join(FRICTION_LAWS)}, got {law!r}",
                             name="law", value=law)
    if excitation not in FRICTION_EXCITATIONS:
        raise ParameterError(f"excitation must be one of {', '.join(FRICTION_EXCITATIONS)}, got {excitation!r}",
                             name="excitation", value=excitation)
    if loop not in ("open", "closed"):
        raise ParameterError(f"loop must be 'open' or 'closed', got {loop!r}", name="loop", value=loop)
    if (loop == "closed") != (excitation in ("multisine", "square")):
        raise ParameterError(f"excitation {excitation!r} does not apply to a {loop} loop (open: sliding, "
                             "little-sliding; closed: multisine, square)", name="excitation", value=excitation)
    given = dict(params or {})
    base = dict(_FRICTION_DEFAULTS[law])
    if law in _HARMONIC_PREFIX and any(_harmonic_re(law).match(k) for k in given):
        base = {k: v for k, v in base.items() if not _harmonic_re(law).match(k)}
    base.update(given)
    names = _friction_names(law, base)
    unknown = [k for k in base if k not in names]
    if unknown:
        raise ParameterError(f"unknown {law} parameter(s) {', '.join(unknown)}; expected {', '.join(names)}",
                             name=unknown[0])
    true = {n: float(base.get(n, 0.0)) for n in names}
    eff, words, d_m = _effect_params(law, true)
    nominal = Testbed.nominal() if testbed is None else testbed
    tb = Testbed(J_m=nominal.J_m, d_m=d_m, k=nominal.k)
    env = environment_preset(environment)
    holding = _static_friction({**eff, "F_s": max(eff.get("F_s", 0.0), eff.get("F_c_neg", 0.0), eff.get("F_c", 0.0))})
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xF1C]))
    ctrl = None
    if loop == "closed":
        ctrl = controller if controller is not None else PD(P=5.0, D=0.1)
        level = max(holding, 0.1)
        if excitation == "multisine":
            ex = Excitation(kind="multisine", amplitude=float(rng.uniform(2.0, 3.0)) * level, f_lo_hz=0.1,
                            f_hi_hz=5.0, lines=16, periods=2, tilt=0.5)
        else:
            ex = Excitation(kind="square", amplitude=float(rng.uniform(2.0, 3.0)) * level,
                            period_s=duration_s / float(rng.uniform(8.0, 12.0)))
    elif excitation == "little-sliding":
        level = max(holding, 0.05)
        ex = Excitation(kind="sweep", amplitude=0.52 * level, offset=0.5 * level, f_lo_hz=3.0 / duration_s)
    elif excitation == "presliding":
        level = min(eff.get("F_c", 0.0), eff.get("F_c_neg", eff.get("F_c", 0.0)))
        ex = Excitation(kind="sweep", amplitude=0.6 * level, f_lo_hz=3.0 / duration_s, dither=0.1 * level)
    elif law in ("sfm", "extended-sfm", "asymmetric", "position-friction"):
        f = float(rng.uniform(1.5, 2.0)) / duration_s
        amp = min(2.0 * math.pi / _motor_gain(tb, env, f) + 1.5 * holding, 3.5)
        ex = Excitation(kind="sweep", amplitude=amp, f_lo_hz=f, dither=0.1 * max(holding, 0.1))
    else:
        ex = Excitation(kind="triangle", amplitude=2.5 * max(holding, 0.1),
                        period_s=duration_s / float(rng.uniform(3.5, 5.0)), dither=0.05 * max(holding, 0.1))
    case = IndependentCase(words=words, environment=env, environment_name=environment, excitation=ex,
                           closed_loop=loop == "closed", controller=ctrl, rate_hz=rate_hz, duration_s=duration_s,
                           testbed=tb, effect_params=eff, initial_angle=0.0, seed=int(rng.integers(0, 2**62)),
                           tau_m_digits=9, encoder_counts=int(encoder_counts), tau_s_logging=tau_s_logging,
                           encoder_noise_counts=float(encoder_noise_counts))
    exp, _ = simulate_independent(case)
    return exp, true
