"""Independent log generator: draw (see the package docstring)."""

from __future__ import annotations

import math
from dataclasses import replace
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..effects import Effect
from ..errors import IdentifiabilityError, ParameterError, SolverError
from ..controllers import PD, PID
from ..params import Environment, Testbed, environment_preset
from ..plausibility import DATASHEET_TOLERANCE
from .model import (ANGLE_WORDS, MAX_ATTEMPTS, RATES_HZ, _WORDS, Excitation, IndependentCase,
                    IndependentLog, IndependentTruth, _word)
from .signals import excitation_signal, one_line_fraction
from .plant import simulate_independent

# --------------------------------------------------------------------------------------
# drawing cases


#: Largest zero offset of a drawn torque sensor [N m] (0.2-0.4 % of a 5-10 N m sensor's range).
SENSOR_OFFSET_N_M = 0.02
#: Largest relative scale error of a drawn torque sensor [-].
SENSOR_GAIN_ERROR = 0.08


def _motor_gain(tb: Testbed, env: Environment, f_hz: float) -> float:
    """|theta / tau_m| of the nominal linear plant at f_hz [rad/(N m)]."""
    s = 2j * math.pi * f_hz
    motor = tb.J_m * s * s + tb.d_m * s
    if env.locked:
        return abs(1.0 / (motor + tb.k))
    e = env.J * s * s + env.d * s + env.k_e
    return abs((e + tb.k) / (motor * (e + tb.k) + tb.k * e))


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _draw_environment(rng: np.random.Generator, word: Effect) -> tuple[str, Environment]:
    if word in ANGLE_WORDS:
        r = rng.random()
        if r < 0.45:
            return "link-only", environment_preset("link-only")
        if r < 0.8:
            return "soft", environment_preset("soft")
        k_e, J_e = _loguniform(rng, 0.5, 1.0), _loguniform(rng, 1e-3, 1e-2)
    else:
        names = ("soft", "stiff", "link-only", "locked", "exp-soft", "custom")
        weights = (0.17, 0.17, 0.17, 0.04 if word is Effect.ENVIRONMENT_MISMATCH else 0.17, 0.15, 0.17)
        name = str(rng.choice(names, p=np.array(weights) / sum(weights)))
        if name != "custom":
            return name, environment_preset(name)
        k_e, J_e = _loguniform(rng, 0.5, 200.0), _loguniform(rng, 1e-3, 0.1)
    d_e = 2.0 * math.sqrt(k_e * J_e) * float(rng.uniform(0.3, 1.2))
    return "custom", Environment(J_e=J_e, d_e=d_e, k_e=k_e)


def _draw_harmonics(rng: np.random.Generator, total: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """1-3 of the orders 1..4 with random phases; the amplitudes sum to `total` [N m]."""
    orders = rng.choice(4, size=int(rng.integers(1, 4)), replace=False)
    weights = rng.dirichlet(np.ones(orders.size))
    phases = rng.uniform(0.0, 2.0 * math.pi, orders.size)
    a, b = [0.0] * 4, [0.0] * 4
    for o, w, ph in zip(orders, weights, phases):
        a[o], b[o] = total * w * math.cos(ph), total * w * math.sin(ph)
    return tuple(a), tuple(b)


def _draw_effect(rng: np.random.Generator, word: Effect, scale: float, env: Environment) -> dict[str, Any]:
    """Typical (full) magnitudes for the Forecast testbed, times `scale`."""
    if word is Effect.COULOMB:
        return {"F_c": scale * rng.uniform(0.15, 0.4)}
    if word is Effect.STICTION:
        f_c = scale * rng.uniform(0.1, 0.3)
        return {"F_c": f_c, "F_s": f_c * rng.uniform(1.3, 2.0), "v_s": _loguniform(rng, 0.01, 0.1)}
    if word is Effect.POSITION_FRICTION:
        f_c = scale * rng.uniform(0.15, 0.35)
        a, b = _draw_harmonics(rng, f_c * rng.uniform(0.25, 0.6))
        return {"F_c": f_c, "pos_a": a, "pos_b": b}
    if word is Effect.COGGING:
        a, b = _draw_harmonics(rng, scale * rng.uniform(0.04, 0.12))
        return {"cog_a": a, "cog_b": b}
    if word is Effect.BACKLASH:
        return {"width": scale * rng.uniform(1e-3, 5e-3)}
    if word is Effect.DELAY:
        return {"delay_s": scale * rng.uniform(2e-3, 6e-3)}
    if word is Effect.TORQUE_GAIN:
        if rng.random() < 0.5:
            return {"gain": 1.0 - scale * rng.uniform(0.05, 0.15)}
        return {"gain": 1.0 + scale * rng.uniform(0.05, 0.2)}
    if word is Effect.ENVIRONMENT_MISMATCH:
        which = ["J_factor", "d_factor"] + (["k_e_factor"] if env.k_e > 0.0 else [])
        key = str(rng.choice(which))
        log_f = rng.uniform(math.log(1.5), math.log(3.0)) * (1.0 if rng.random() < 0.5 else -1.0)
        return {key: math.exp(scale * log_f)}
    return {}


def _static_friction(params: Mapping[str, Any]) -> float:
    """Largest torque friction and cogging can hold [N m]."""
    f = params.get("F_s", params.get("F_c", 0.0))
    for key in ("pos", "cog"):
        f += sum(math.hypot(a, b) for a, b in zip(params.get(f"{key}_a", ()), params.get(f"{key}_b", ())))
    return float(f)


def _travel_linear(x: np.ndarray, tb: Testbed, env: Environment, rate: float) -> float:
    """Peak-to-peak motor angle the nominal linear plant answers to the periodic command x [rad]."""
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(x.size, 1.0 / rate)
    gain = np.zeros(f.size, dtype=complex)
    s = 2j * np.pi * f[1:]
    motor = tb.J_m * s * s + tb.d_m * s
    if env.locked:
        gain[1:] = 1.0 / (motor + tb.k)
    else:
        e = env.J * s * s + env.d * s + env.k_e
        gain[1:] = (e + tb.k) / (motor * (e + tb.k) + tb.k * e)
    return float(np.ptp(np.fft.irfft(spec * gain, x.size)))


def _draw_excitation(rng: np.random.Generator, word: Effect, closed: bool, tb: Testbed, env: Environment,
                     duration: float, rate: float, holding: float) -> Excitation:
    offset = 0.0
    angle = word in ANGLE_WORDS
    if closed:
        kind = "square" if angle else str(rng.choice(("square", "multisine", "chirp"), p=(0.45, 0.35, 0.2)))
        if rng.random() < 0.4 and not angle:
            offset = float(rng.uniform(-0.3, 0.3))
        if kind == "square":
            slew = None if rng.random() < 0.5 else float(rng.uniform(1.0, 10.0))
            if angle:   # the output turns: tau_s / d_l on a bare link, tau_s / k_e on a soft spring
                return Excitation(kind=kind, amplitude=float(rng.uniform(0.6, 1.0)),
                                  period_s=float(rng.uniform(4.0, 8.0)), slew=slew)
            return Excitation(kind=kind, amplitude=float(rng.uniform(0.1, 0.5)), offset=offset,
                              period_s=float(rng.uniform(1.0, 4.0)), slew=slew)
        if kind == "multisine":
            return Excitation(kind=kind, amplitude=float(rng.uniform(0.1, 0.3)), offset=offset,
                              f_lo_hz=float(rng.uniform(0.1, 0.5)), f_hi_hz=float(rng.uniform(2.0, 10.0)),
                              lines=int(rng.integers(8, 25)), periods=int(rng.integers(1, 4)),
                              tilt=float(rng.uniform(0.0, 1.0)))
        return Excitation(kind=kind, amplitude=float(rng.uniform(0.1, 0.4)), offset=offset,
                          f_lo_hz=float(rng.uniform(0.1, 0.3)), f_hi_hz=float(rng.uniform(3.0, 10.0)))
    if angle:
        kinds, p = ("sweep", "multisine", "square"), (0.6, 0.25, 0.15)
    else:
        kinds, p = ("multisine", "square", "chirp", "sweep"), (0.35, 0.25, 0.2, 0.2)
    kind = str(rng.choice(kinds, p=p))
    if rng.random() < 0.3:
        offset = float(rng.uniform(-0.4, 0.4))
    if kind == "sweep":
        f = float(rng.uniform(1.5, 3.0)) / duration
        amplitude = min(max(1.6 * math.pi / _motor_gain(tb, env, f) + 1.2 * holding, 0.3), 3.5)
        dither = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.02, 0.1))
        return Excitation(kind="sweep", amplitude=amplitude, offset=0.3 * offset, f_lo_hz=f,
                          f_hi_hz=max(f, 8.0), dither=dither)
    if kind == "multisine":
        ex = Excitation(kind=kind, amplitude=float(rng.uniform(0.3, 1.0)), offset=offset,
                        f_lo_hz=float(rng.uniform(0.05, 0.2) if angle else rng.uniform(0.1, 0.5)),
                        f_hi_hz=float(rng.uniform(5.0, 30.0)), lines=int(rng.integers(10, 30)),
                        periods=int(rng.integers(1, 3 if angle else 4)),
                        tilt=float(rng.uniform(0.8, 1.5) if angle else rng.uniform(0.0, 1.2)))
    elif kind == "square":
        slew = None if rng.random() < 0.5 else float(rng.uniform(2.0, 20.0))
        ex = Excitation(kind=kind, amplitude=float(rng.uniform(0.3, 1.5)), offset=offset,
                        period_s=float(rng.uniform(4.0, 8.0) if angle else rng.uniform(1.0, 4.0)), slew=slew)
    else:
        ex = Excitation(kind=kind, amplitude=float(rng.uniform(0.3, 1.2)), offset=offset,
                        f_lo_hz=float(rng.uniform(0.1, 0.5)), f_hi_hz=float(rng.uniform(5.0, 20.0)))
    if angle:   # scale so the linear plant would turn the motor 1.5 revolutions
        x = excitation_signal(ex, int(round(duration * rate)), rate)
        travel = _travel_linear(x, tb, env, rate)
        peak = float(np.max(np.abs(x - ex.offset)))
        factor = min(3.0 * math.pi / max(travel, 1e-9), 3.0 / max(peak, 1e-9))
        ex = replace(ex, amplitude=ex.amplitude * max(factor, 1.0))
    return replace(ex, amplitude=ex.amplitude + holding)


#: Integral gains of the PID force loops a draw with ``controllers`` runs [1/s] (I/P of 1-10 rad/s with P 3-6).
PID_I_PER_S = (5.0, 30.0)


def draw_independent_case(word: Effect | str, index: int, seed: int, *, magnitude_scale: float = 1.0,
                          attempt: int = 0, setups: bool = True, controllers: bool = False) -> IndependentCase:
    """Draw one case for an effect word, deterministically in the arguments.

    Parameters
    ----------
    word : Effect or str
        One word of the vocabulary (``none`` for an effect-free log).
    index : int
        Case number, >= 0.
    seed : int
        Seed, >= 0.
    magnitude_scale : float
        Fraction of the typical magnitude (1, 0.5, 0.25 ...), > 0 [-].
    attempt : int
        Redraw number, >= 0 (see :func:`make_independent_log`).
    setups : bool
        Also draw the set-ups of :func:`_draw_setup` (another SEA, 16/14-bit encoders, loggers
        printing with fixed decimals, asymmetric friction), from their own random stream: with
        False every case is the one drawn before they existed.
    controllers : bool
        Half the closed loops run a PID (the drawn P and D, an integral gain I of
        :data:`PID_I_PER_S`) instead of the PD, from their own random stream; False (default): every
        case is the one drawn before.

    Returns
    -------
    IndependentCase
        Environment, excitation, logger and true effect parameters.

    Notes
    -----
    Typical (full) magnitudes: Coulomb 0.15-0.4 N m; stiction F_c 0.1-0.3 N m,
    F_s = 1.3-2 F_c, v_s 0.01-0.1 rad/s; position friction F_c 0.15-0.35 N m
    with harmonics summing to 25-60 % of F_c; cogging 0.04-0.12 N m; dead band
    1-5 mrad; delay 2-6 ms; torque gain 0.85-0.95 or 1.05-1.2; environment J,
    d or k_e off by a factor 1.5-3 (either way). The scale multiplies torques,
    widths, delays and ``|g - 1|``; a mismatch factor f becomes f**scale.
    """
    effect = _word(word)
    scale = float(magnitude_scale)
    if not (scale > 0.0 and math.isfinite(scale)):
        raise ParameterError(f"magnitude_scale must be > 0, got {magnitude_scale!r}",
                             name="magnitude_scale", value=magnitude_scale)
    for name, value in (("index", index), ("seed", seed), ("attempt", attempt)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ParameterError(f"{name} must be an integer >= 0, got {value!r}", name=name, value=value)
    rng = np.random.default_rng(np.random.SeedSequence(
        [int(seed), int(index), int(attempt), _WORDS.index(effect), int(round(scale * 1e6))]))
    rate = float(rng.choice(RATES_HZ))
    duration = round(float(rng.uniform(5.0, 20.0)), 1)
    env_name, env = _draw_environment(rng, effect)
    params = _draw_effect(rng, effect, scale, env)
    tb = Testbed.nominal()
    closed = bool(rng.random() < (0.25 if effect in ANGLE_WORDS else 0.35))
    if effect in ANGLE_WORDS and env_name == "custom":
        closed = False      # a PD force loop cannot turn a k_e ~ 1 N m/rad spring a revolution
    excitation = _draw_excitation(rng, effect, closed, tb, env, duration, rate, _static_friction(params))
    controller = PD(P=float(rng.uniform(3.0, 6.0)), D=float(rng.uniform(0.05, 0.12)))
    r = rng.random()
    tau_s = "omitted" if r < 0.3 else ("sensor" if r > 0.8 else f"derived:{int(rng.integers(6, 11))}")
    case = IndependentCase(
        words=(effect,), magnitude_scale=scale, environment=env, environment_name=env_name,
        excitation=excitation, closed_loop=closed, controller=controller if closed else None,
        derivative_filter_hz=float(rng.uniform(50.0, 200.0)), rate_hz=rate, duration_s=duration,
        t0_s=0.0 if rng.random() < 0.5 else round(float(rng.uniform(0.0, 60.0)), 3),
        tau_s_logging=tau_s, tau_m_digits=int(rng.integers(7, 10)),
        encoder_noise_counts=0.0 if rng.random() < 0.7 else float(rng.uniform(0.2, 1.0)),
        sensor_noise=float(rng.uniform(0.001, 0.005)) if tau_s == "sensor" else 0.0,
        testbed=tb, nominal_errors={k: float(rng.uniform(-0.02, 0.02)) for k in ("J_m", "d_m", "k")},
        effect_params=params, initial_angle=float(rng.uniform(0.0, 2.0 * math.pi)),
        seed=int(rng.integers(0, 2**62)), index=int(index), attempt=int(attempt),
    )
    if tau_s == "sensor":
        # a torque sensor's zero and scale are never exact; drawn last, so the rest of the draw is unchanged
        case = replace(case, sensor_offset=float(rng.uniform(-SENSOR_OFFSET_N_M, SENSOR_OFFSET_N_M)),
                       sensor_gain=float(1.0 + rng.uniform(-SENSOR_GAIN_ERROR, SENSOR_GAIN_ERROR)))
    if setups:
        case = _draw_setup(case, effect, np.random.default_rng(np.random.SeedSequence(
            [int(seed), int(index), int(attempt), _WORDS.index(effect), int(round(scale * 1e6)), 0x25])))
    if controllers and case.closed_loop:
        crng = np.random.default_rng(np.random.SeedSequence(
            [int(seed), int(index), int(attempt), _WORDS.index(effect), int(round(scale * 1e6)), 0x26]))
        if crng.random() < 0.5:
            c = case.controller
            case = replace(case, controller=PID(P=c.P, I=float(crng.uniform(*PID_I_PER_S)), D=c.D))
    return case


#: The other SEA of the set-ups (a stiffer spring, a lighter motor) [N m/rad], [kg m^2].
OTHER_SEA = {"k": 145.0, "J_m": 0.053}


def _draw_setup(case: IndependentCase, effect: Effect, rng: np.random.Generator) -> IndependentCase:
    """Set-ups beyond the testbed's (issue 25), from their own random stream.

    A fifth of the logs come from another SEA (k 145 N m/rad, J_m 0.053 kg m^2); a fifth have
    16-bit and a tenth 14-bit encoders; a derived ``tau_s`` is printed with fixed decimals
    (3-6) in half the logs; a third of the loggers print the angles with 9-12 significant
    digits or 7-9 decimals; Coulomb friction and stiction differ by direction (the negative
    levels 0.7-1.3 times the positive) in a third of their logs.
    """
    changes: dict[str, Any] = {}
    if rng.random() < 0.2:
        changes["testbed"] = Testbed(J_m=OTHER_SEA["J_m"], d_m=case.testbed.d_m, k=OTHER_SEA["k"])
    r = rng.random()
    if r < 0.3:
        changes["encoder_counts"] = 2**16 if r < 0.2 else 2**14
    if case.tau_s_logging.startswith("derived:") and rng.random() < 0.5:
        changes["tau_s_logging"] = f"decimals:{int(rng.integers(3, 7))}"
    if rng.random() < 0.3:
        changes["angle_logging"] = (f"digits:{int(rng.integers(9, 13))}" if rng.random() < 0.5
                                    else f"decimals:{int(rng.integers(7, 10))}")
    if effect in (Effect.COULOMB, Effect.STICTION) and rng.random() < 1.0 / 3.0:
        p = dict(case.effect_params)
        p["F_c_neg"] = p["F_c"] * float(rng.uniform(0.7, 1.3))
        if "F_s" in p:
            p["F_s_neg"] = p["F_c_neg"] + (p["F_s"] - p["F_c"])
        changes["effect_params"] = p
    return replace(case, **changes) if changes else case


# --------------------------------------------------------------------------------------
# identifiability


def _reversals(omega: np.ndarray, threshold: float = 1e-3) -> int:
    """Sign changes of the velocity with a hysteresis of +-threshold [rad/s]."""
    state = np.where(omega > threshold, 1, np.where(omega < -threshold, -1, 0))
    state = state[state != 0]
    return int(np.count_nonzero(np.diff(state))) if state.size else 0


def _breakaways(stuck: np.ndarray) -> int:
    """Stuck episodes (>= 2 rows) that end in sliding."""
    s = stuck.astype(np.int8)
    edges = np.flatnonzero(np.diff(s))
    count, start = 0, 0 if s[0] else None
    for e in edges:
        if s[e + 1]:
            start = e + 1
        elif start is not None:
            count += int(e + 1 - start >= 2)
            start = None
    return count


#: Band of the equation errors an effect must show in [Hz] (the gap diagnosis keeps 40 Hz at its default
#: 100 Hz decimated rate) and how far above the encoders' quantisation its torque must be [-].
VISIBLE_BAND_HZ, VISIBLE_FACTOR = 40.0, 2.0


def quantisation_floor(case: IndependentCase) -> float:
    """RMS torque [N m] the encoders' quantisation puts into the motor equation in the visible band.

    White quantisation of one step ``s`` (variance ``s^2 / 12`` up to Nyquist) enters ``J_m theta''``
    twice differentiated, ``J_m (s / sqrt 12) sqrt((2 pi)^4 f^5 / (5 rate / 2))``, and the spring torque
    ``k (theta - q)`` of two encoders as is, ``k (s / sqrt 12) sqrt(2 f / (rate / 2))``, both kept up to
    ``f`` = :data:`VISIBLE_BAND_HZ`.
    """
    s, f, nyq = case.encoder_step, VISIBLE_BAND_HZ, case.rate_hz / 2.0
    tb = case.true_testbed
    inertial = tb.J_m * s / math.sqrt(12.0) * math.sqrt((2.0 * math.pi) ** 4 * f ** 5 / (5.0 * nyq))
    spring = tb.k * s / math.sqrt(12.0) * math.sqrt(2.0 * f / nyq)
    return float(math.hypot(inertial, spring))


def _signature(case: IndependentCase, truth: IndependentTruth, word: Effect) -> float:
    """RMS torque [N m] the effect adds to the equation it acts in (from the truth)."""
    if word in (Effect.COULOMB, Effect.STICTION, Effect.POSITION_FRICTION):
        x = np.asarray(truth.tau_friction)
    elif word is Effect.COGGING:
        x = np.asarray(truth.tau_cogging)
    elif word in (Effect.DELAY, Effect.TORQUE_GAIN):
        x = np.asarray(truth.tau_applied) - np.asarray(truth.command)
    elif word is Effect.BACKLASH:
        x = np.asarray(truth.tau_spring) - truth.testbed.k * (np.asarray(truth.theta) - np.asarray(truth.q))
    elif word is Effect.ENVIRONMENT_MISMATCH:
        true, nominal = truth.environment, case.environment
        v = np.asarray(truth.v)
        a = np.gradient(v, 1.0 / case.rate_hz)
        x = (true.J - nominal.J) * a + (true.d - nominal.d) * v + (true.k_e - nominal.k_e) * np.asarray(truth.q)
    else:
        return math.inf
    return float(np.sqrt(np.mean(np.square(x - np.mean(x))))) if word is Effect.COGGING else \
        float(np.sqrt(np.mean(np.square(x))))


def identifiability(case: IndependentCase, truth: IndependentTruth) -> str | None:
    """Why the log cannot tell its effect apart, judged from the truth; None when it can.

    Parameters
    ----------
    case : IndependentCase
        The case that was simulated.
    truth : IndependentTruth
        Its truth (see :func:`simulate_independent`).

    Returns
    -------
    str or None
        The first reason found, or None.

    Notes
    -----
    Angle effects need >= 2 pi of motor travel and >= 2 velocity reversals;
    Coulomb friction and stiction >= 2 reversals, stiction also >= 2
    breakaways after sticking and >= 5 % of the log sliding faster than
    ``2 v_s`` (else the Stribeck decay from ``F_s`` to ``F_c`` is never seen); delay and
    torque gain a command with < 95 % of
    its variance in one spectral line (:func:`one_line_fraction`); backlash
    >= 2 passages through the dead band from one contact side to the other;
    an environment mismatch an unlocked output that moves >= 100 counts; a torque
    gain ``|g - 1|`` beyond the datasheet tolerance of the nominal ``J_m`` and ``k``
    (:data:`forecast_design.plausibility.DATASHEET_TOLERANCE`), within which it is a
    common rescaling of the nominal model.
    Every log must also keep its command below the torque limit most of the
    time (closed loop) and its motor below 10^4 rad, and the effect's torque in the
    equation it acts in must be at least :data:`VISIBLE_FACTOR` times the encoders'
    quantisation floor (:func:`quantisation_floor`: the log must carry it above the
    resolution of its sensors; only coarse encoders make this bind).
    """
    th, w = np.asarray(truth.theta), np.asarray(truth.omega)
    if not (np.all(np.isfinite(th)) and np.max(np.abs(th)) < 1e4):
        return "the motor angle left any physical range"
    if case.closed_loop:
        sat = float(np.mean(np.abs(truth.command) >= case.torque_limit * (1 - 1e-6)))
        if sat > 0.05:
            return f"the command saturates {100 * sat:.0f} % of the time"
    floor = quantisation_floor(case)
    for word in case.words:
        why = _structural_reason(case, truth, word, th, w)
        if why:
            return why
        sig = _signature(case, truth, word)
        if sig < VISIBLE_FACTOR * floor:
            return (f"{word}: its torque ({sig:.2g} N m RMS) is below {VISIBLE_FACTOR:g} x the encoders' quantisation "
                    f"floor ({floor:.2g} N m at {case.encoder_counts} counts)")
    return None


def _structural_reason(case: IndependentCase, truth: IndependentTruth, word: Effect, th: np.ndarray,
                       w: np.ndarray) -> str | None:
    """Why the excitation or set-up cannot show ``word`` at all (checked before its size is)."""
    if word is Effect.ENVIRONMENT_MISMATCH and case.environment.locked:
        return "environment_mismatch: the output is locked"
    rev = _reversals(w)
    if word in (Effect.COULOMB, Effect.STICTION, *ANGLE_WORDS) and rev < 2:
        return f"{word}: {rev} velocity reversal(s), needs >= 2"
    if word in ANGLE_WORDS:
        travel = float(th.max() - th.min())
        if travel < 2.0 * math.pi:
            return f"{word}: motor travel {travel:.2f} rad, needs >= 2 pi"
    if word is Effect.STICTION and not case.effect_params.get("sigma0"):
        b = _breakaways(np.asarray(truth.stuck))
        if b < 2:
            return f"stiction: {b} breakaway(s) after sticking, needs >= 2"
        # the drop from F_s to F_c is seen only where the motor slides well beyond v_s
        fast = float(np.mean(np.abs(w) > 2.0 * float(case.effect_params["v_s"])))
        if fast < 0.05:
            return (f"stiction: the motor slides faster than 2 v_s in {100 * fast:.1f} % of the log, "
                    "needs >= 5 % to show the Stribeck decay")
    if word in (Effect.DELAY, Effect.TORQUE_GAIN):
        frac = one_line_fraction(truth.command)
        if frac >= 0.95:
            return f"{word}: {100 * frac:.1f} % of the command variance is one spectral line"
    if word is Effect.TORQUE_GAIN:
        # a gain is a common rescaling of J_m, d_m and k: inside the datasheet tolerance that a
        # re-calibration may absorb it is a nominal error, not a distinguishable effect
        g = float(case.effect_params["gain"])
        if abs(g - 1.0) <= DATASHEET_TOLERANCE["J_m"]:
            tol = DATASHEET_TOLERANCE["J_m"]
            return (f"torque_gain: |gain - 1| = {abs(g - 1.0):.3f} within the {tol:.0%} "
                    "datasheet tolerance of the re-calibration")
    if word is Effect.BACKLASH:
        sides = np.asarray(truth.spring_mode)
        sides = sides[(sides == 1) | (sides == -1)]
        passes = int(np.count_nonzero(np.diff(sides))) if sides.size else 0
        if passes < 2:
            return f"backlash: {passes} passage(s) through the dead band, needs >= 2"
    if word is Effect.ENVIRONMENT_MISMATCH:
        travel = float(np.ptp(truth.q))
        if travel < 100 * case.encoder_step:
            return (f"environment_mismatch: the output moves {travel / case.encoder_step:.0f} counts, "
                    "needs >= 100")
    return None


def make_independent_log(word: Effect | str, index: int, seed: int, *, magnitude_scale: float = 1.0,
                         setups: bool = True, controllers: bool = False) -> IndependentLog:
    """Draw, simulate and redraw (attempt 0, 1, ...) until the log is identifiable.

    Parameters
    ----------
    word : Effect or str
        The effect word.
    index : int
        Case number, >= 0.
    seed : int
        Seed, >= 0.
    magnitude_scale : float
        Fraction of the typical magnitude, > 0 [-].
    setups : bool
        Draw the set-ups of issue 25 too (see :func:`draw_independent_case`).
    controllers : bool
        Half the closed loops run a PID (see :func:`draw_independent_case`).

    Returns
    -------
    IndependentLog
        The first identifiable draw, with the reasons earlier draws were rejected.

    Raises
    ------
    IdentifiabilityError
        If none of :data:`MAX_ATTEMPTS` draws is identifiable (the message lists the reasons).
    """
    rejected: list[str] = []
    for attempt in range(MAX_ATTEMPTS):
        case = draw_independent_case(word, index, seed, magnitude_scale=magnitude_scale, attempt=attempt,
                                     setups=setups, controllers=controllers)
        try:
            exp, truth = simulate_independent(case)
        except SolverError as exc:
            rejected.append(f"attempt {attempt}: {exc}")
            continue
        reason = identifiability(case, truth)
        if reason is None:
            return IndependentLog(experiment=exp, truth=truth, case=case, rejected=tuple(rejected))
        rejected.append(f"attempt {attempt}: {reason}")
    raise IdentifiabilityError(f"no identifiable {word} log in {MAX_ATTEMPTS} draws (index {index}, "
                               f"seed {seed}, scale {magnitude_scale}): " + "; ".join(rejected))


# --------------------------------------------------------------------------------------
# friction-only logs for the identification


_FRICTION_DEFAULTS: Mapping[str, Mapping[str, float]] = MappingProxyType({
    "sfm": MappingProxyType({"viscous": 0.3, "coulomb": 0.3}),
    "asymmetric": MappingProxyType({"viscous_pos": 0.3, "viscous_neg": 0.25, "coulomb_pos": 0.3,
                                    "coulomb_neg": 0.22}),
    "extended-sfm": MappingProxyType({"viscous": 0.3, "coulomb": 0.3, "sin1": 0.05, "cos1": 0.02,
                                      "sin2": 0.0, "cos2": 0.03, "sin3": 0.01, "cos3": 0.0,
                                      "sin4": 0.0, "cos4": 0.01}),
    "stribeck": MappingProxyType({"static": 0.45, "coulomb": 0.3, "stribeck_velocity": 0.05,
                                  "viscous": 0.3}),
    "lugre": MappingProxyType({"sigma0": 1000.0, "sigma1": 5.0, "static": 0.45, "coulomb": 0.3,
                               "stribeck_velocity": 0.05, "viscous": 0.3}),
    "position-friction": MappingProxyType({"viscous": 0.3, "coulomb": 0.3, "coulomb_sin1": 0.04, "coulomb_cos1": 0.02,
                                           "coulomb_sin2": 0.0, "coulomb_cos2": 0.03, "coulomb_sin3": 0.01,
                                           "coulomb_cos3": 0.0, "coulomb_sin4": 0.0, "coulomb_cos4": 0.01}),
})
