"""An independent log generator: the spec's plant equations, integrated apart from the virtual testbed.

The virtual testbed (:mod:`forecast_design.simulation`) made every log the gap
diagnosis and the friction identification were tuned on. This module writes
logs of the same plant with other code, another integrator and another
logger, so methods can be judged on data the project did not make:

* plant (experiment format, SI, rad)::

      J_m theta'' = g tau_m(t - delay) - tau_s - d_m theta' - tau_f(theta', theta) - tau_cog(theta)
      tau_s       = k (theta - q)       (backlash: k deadzone(theta - q, width / 2))
      J q'' + d q' + k_e q = tau_s      (locked: q == 0)

* friction with true sticking: event-based stick/slip switching (Karnopp-like
  but exact: the switch instants are located by root finding), optionally
  LuGre bristle dynamics written from Canudas de Wit et al. (1995);
* backlash as three modes (contact +, dead band, contact -), switched by events;
* integration: Dormand-Prince 5(4) (``scipy.integrate.ode``, ``dopri5``) over
  each interval on which the applied torque is constant (exact zero-order
  hold, the delay splits a period in two); when a mode-validity function turns
  negative at the end of an interval the interval is redone by
  ``scipy.integrate.solve_ivp`` (DOP853) with terminal events, so every switch
  is located by root finding, never smoothed;
* the logger: 2,000,000-count encoders, 1 or 2 kHz, ``tau_s`` omitted,
  printed from ``k_nominal (theta - q)`` at 6-10 significant digits or measured
  by a torque sensor with noise, ``tau_m`` printed at 7-9 significant digits,
  a nominal testbed that is up to 2 % off the simulated one;
* closed loop: a discrete PD force controller with a first-order filtered
  derivative (Tustin), updated at the log rate, command held over the period.

It imports no simulation code of the toolbox (layer 2 of the package, it uses
only :mod:`params`, :mod:`effects` (the vocabulary), :mod:`experiment` and
:mod:`errors`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
from scipy.integrate import ode, solve_ivp

from .effects import Effect
from .errors import IdentifiabilityError, ParameterError, SolverError
from .experiment import Experiment, experiment_from_arrays
from .params import Environment, Design, PDController, Testbed, environment_preset
from .plausibility import DATASHEET_TOLERANCE

__all__ = [
    "COUNTS_PER_REV",
    "ENCODER_STEP",
    "MAX_ATTEMPTS",
    "RATES_HZ",
    "EXCITATION_KINDS",
    "FRICTION_LAWS",
    "ANGLE_WORDS",
    "Excitation",
    "IndependentCase",
    "IndependentTruth",
    "IndependentLog",
    "excitation_signal",
    "round_significant",
    "one_line_fraction",
    "draw_independent_case",
    "simulate_independent",
    "identifiability",
    "make_independent_log",
    "friction_log",
]

#: Encoder resolution of the Forecast testbed (paper section 7) [counts/rev].
COUNTS_PER_REV = 2_000_000
#: One encoder count [rad].
ENCODER_STEP = 2.0 * math.pi / COUNTS_PER_REV
#: Most draws :func:`make_independent_log` tries before giving up.
MAX_ATTEMPTS = 12
#: Log rates the logger uses [Hz].
RATES_HZ = (1000.0, 2000.0)
#: Excitation kinds (open-loop commands or closed-loop force references).
EXCITATION_KINDS = ("multisine", "square", "chirp", "sweep", "triangle", "constant")
#: Friction laws of :func:`friction_log`, named like :func:`forecast_design.friction.friction_model`.
FRICTION_LAWS = ("extended-sfm", "stribeck", "lugre")
#: Words whose effect depends on the motor angle (need a revolution of travel).
ANGLE_WORDS = (Effect.POSITION_FRICTION, Effect.COGGING)

_WORDS = tuple(Effect)
_FRICTION_WORDS = (Effect.COULOMB, Effect.STICTION, Effect.POSITION_FRICTION)
_PARAM_KEYS = ("F_c", "F_s", "v_s", "sigma0", "sigma1", "pos_a", "pos_b", "cog_a", "cog_b",
               "width", "delay_s", "gain", "J_factor", "d_factor", "k_e_factor")
_TAU_S_RE = re.compile(r"^(omitted|sensor|derived:(\d+))$")

# Integration tolerances and switching hysteresis (far below one encoder count, 3.1e-6 rad).
_RTOL = 1e-10
_ATOL = 1e-12
_TOL_W = 1e-10    # velocity  [rad/s]
_TOL_N = 1e-10    # torque    [N m]
_TOL_D = 1e-12    # deflection [rad]
_MAX_EVENTS_PER_INTERVAL = 200

# Motor modes: sliding in +/- direction, stuck, or free (no sticking friction at all).
_STUCK, _FREE = 0, 2
# Spring modes: contact +/-, dead band, or linear (no backlash).
_BAND, _LINEAR = 0, 2


# --------------------------------------------------------------------------------------
# parameters


@dataclass(frozen=True, slots=True, kw_only=True)
class Excitation:
    """An open-loop command or a closed-loop force reference, sampled at the log rate.

    Parameters
    ----------
    kind : str
        ``multisine`` (crest-factor optimised), ``square`` (optionally rate
        limited), ``chirp`` (logarithmic), ``sweep`` (slow sine that turns the
        motor, optional multisine dither), ``triangle`` (slow ramps, for
        breakaways) or ``constant``.
    amplitude : float
        RMS value for ``multisine``, peak (half peak-to-peak) otherwise, level
        for ``constant`` [N m].
    offset : float
        Added constant [N m].
    f_lo_hz : float
        Lowest multisine line, chirp start, sweep frequency [Hz].
    f_hi_hz : float
        Highest multisine line, chirp end [Hz].
    period_s : float
        Period of ``square`` and ``triangle`` [s].
    slew : float or None
        Rate limit of ``square`` [N m/s]; None for none.
    lines : int
        Number of multisine lines (log spaced; duplicates on the grid merge).
    periods : int
        Number of multisine periods in the log.
    tilt : float
        Multisine amplitude spectrum ~ f**(-tilt) [-].
    dither : float
        RMS of an added 1-8 Hz multisine for ``sweep`` and ``triangle`` [N m].
    """

    kind: str
    amplitude: float
    offset: float = 0.0
    f_lo_hz: float = 0.1
    f_hi_hz: float = 10.0
    period_s: float = 2.0
    slew: float | None = None
    lines: int = 20
    periods: int = 1
    tilt: float = 0.0
    dither: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in EXCITATION_KINDS:
            raise ParameterError(f"excitation kind must be one of {', '.join(EXCITATION_KINDS)}, "
                                 f"got {self.kind!r}", name="kind", value=self.kind)
        if not (0.0 < self.f_lo_hz <= self.f_hi_hz):
            raise ParameterError(f"excitation needs 0 < f_lo_hz <= f_hi_hz, got {self.f_lo_hz}, "
                                 f"{self.f_hi_hz}", name="f_lo_hz", value=self.f_lo_hz)
        if self.period_s <= 0.0 or self.lines < 1 or self.periods < 1:
            raise ParameterError("excitation period_s, lines and periods must be positive",
                                 name="period_s", value=self.period_s)
        if self.slew is not None and self.slew <= 0.0:
            raise ParameterError(f"excitation slew must be > 0 or None, got {self.slew}",
                                 name="slew", value=self.slew)


@dataclass(frozen=True, slots=True, kw_only=True)
class IndependentCase:
    """Everything that defines one independent log (deterministic given these fields).

    Parameters
    ----------
    words : tuple of Effect
        The unmodelled effects present (``()`` or ``(Effect.NONE,)`` for none).
    magnitude_scale : float
        Fraction of the typical (full) magnitude the effects were drawn at [-].
    environment : Environment
        The declared environment (written to the TOML).
    environment_name : str
        Preset name or ``custom``.
    excitation : Excitation
        Open-loop command, or the force reference when `closed_loop`.
    closed_loop : bool
        PD force control (``controller``) instead of an open-loop command.
    controller : PDController or None
        Gains of the PD force controller (closed loop).
    derivative_filter_hz : float
        Cutoff of the controller's first-order derivative filter [Hz].
    torque_limit : float
        Saturation of the controller's command [N m].
    rate_hz : float
        Log (and controller) rate [Hz].
    duration_s : float
        Log length [s].
    t0_s : float
        Time of the first row [s].
    tau_s_logging : str
        ``omitted``, ``derived:<digits>`` (printed ``k_nominal (theta - q)``)
        or ``sensor`` (independent torque sensor with noise, printed at 7
        significant digits; the controller then feeds back the sensor).
    tau_m_digits : int
        Significant digits of the printed ``tau_m`` (and ``tau_r``).
    encoder_noise_counts : float
        Standard deviation of encoder noise before quantisation [counts].
    sensor_noise : float
        Standard deviation of the torque-sensor noise [N m].
    testbed : Testbed
        The nominal testbed written to the TOML.
    nominal_errors : Mapping[str, float]
        Relative errors of the nominal ``J_m``, ``d_m``, ``k`` with respect to
        the simulated truth: ``nominal = true (1 + e)`` [-].
    effect_params : Mapping[str, object]
        True effect parameters, flat: ``F_c``, ``F_s`` [N m], ``v_s`` [rad/s],
        ``sigma0`` [N m/rad], ``sigma1`` [N m s/rad] (LuGre), ``pos_a``,
        ``pos_b``, ``cog_a``, ``cog_b`` (harmonic orders 1, 2, ... of the
        absolute motor angle) [N m], ``width`` (full dead band) [rad],
        ``delay_s`` [s], ``gain`` [-], ``J_factor``, ``d_factor``,
        ``k_e_factor`` (true / declared) [-].
    initial_angle : float
        Absolute motor angle at the first row (phase of the angle effects) [rad].
    seed : int
        Seed of the logger's noise.
    index : int
        Draw index (bookkeeping).
    attempt : int
        Redraw number (bookkeeping).
    """

    words: tuple[Effect, ...]
    magnitude_scale: float = 1.0
    environment: Environment
    environment_name: str = "custom"
    excitation: Excitation
    closed_loop: bool = False
    controller: PDController | None = None
    derivative_filter_hz: float = 100.0
    torque_limit: float = 5.0
    rate_hz: float = 2000.0
    duration_s: float = 10.0
    t0_s: float = 0.0
    tau_s_logging: str = "omitted"
    tau_m_digits: int = 8
    encoder_noise_counts: float = 0.0
    sensor_noise: float = 0.0
    testbed: Testbed = field(default_factory=Testbed.nominal)
    nominal_errors: Mapping[str, float] = field(default_factory=dict)
    effect_params: Mapping[str, Any] = field(default_factory=dict)
    initial_angle: float = 0.0
    seed: int = 0
    index: int = 0
    attempt: int = 0

    def __post_init__(self) -> None:
        words = tuple(_word(w) for w in self.words)
        object.__setattr__(self, "words", tuple(w for w in words if w is not Effect.NONE))
        m = _TAU_S_RE.match(str(self.tau_s_logging))
        if m is None or (m.group(2) is not None and not 1 <= int(m.group(2)) <= 17):
            raise ParameterError("tau_s_logging must be 'omitted', 'sensor' or 'derived:<1..17>', "
                                 f"got {self.tau_s_logging!r}", name="tau_s_logging",
                                 value=self.tau_s_logging)
        if self.rate_hz <= 0.0 or self.duration_s <= 0.0:
            raise ParameterError("rate_hz and duration_s must be > 0", name="rate_hz", value=self.rate_hz)
        if self.closed_loop and self.controller is None:
            raise ParameterError("a closed-loop case needs a controller", name="controller")
        if not 1 <= int(self.tau_m_digits) <= 17:
            raise ParameterError(f"tau_m_digits must be 1..17, got {self.tau_m_digits}",
                                 name="tau_m_digits", value=self.tau_m_digits)
        unknown = [k for k in self.effect_params if k not in _PARAM_KEYS]
        if unknown:
            raise ParameterError(f"unknown effect parameter(s) {', '.join(unknown)}; known: "
                                 f"{', '.join(_PARAM_KEYS)}", name=unknown[0])
        bad = [k for k in self.nominal_errors if k not in ("J_m", "d_m", "k")]
        if bad:
            raise ParameterError(f"nominal_errors keys are J_m, d_m, k; got {bad[0]!r}", name=bad[0])
        params = {k: (tuple(float(x) for x in v) if isinstance(v, (list, tuple, np.ndarray)) else float(v))
                  for k, v in self.effect_params.items()}
        object.__setattr__(self, "effect_params", MappingProxyType(params))
        object.__setattr__(self, "nominal_errors",
                           MappingProxyType({k: float(v) for k, v in self.nominal_errors.items()}))

    @property
    def true_testbed(self) -> Testbed:
        """The simulated testbed: nominal / (1 + error) for J_m, d_m and k."""
        e = self.nominal_errors
        tb = self.testbed
        return Testbed(J_m=tb.J_m / (1.0 + e.get("J_m", 0.0)), d_m=tb.d_m / (1.0 + e.get("d_m", 0.0)),
                       k=tb.k / (1.0 + e.get("k", 0.0)))

    @property
    def true_environment(self) -> Environment:
        """The simulated environment: the declared one times the mismatch factors."""
        env, p = self.environment, self.effect_params
        if env.locked:
            return env
        fj, fd, fk = p.get("J_factor", 1.0), p.get("d_factor", 1.0), p.get("k_e_factor", 1.0)
        return Environment(J_e=env.J_e * fj, J_l=env.J_l * fj, d_e=env.d_e * fd, d_l=env.d_l * fd,
                           k_e=env.k_e * fk, locked=False)

    @property
    def design(self) -> Design:
        """The nominal design written to the TOML (with the controller when closed loop)."""
        return Design(testbed=self.testbed, environment=self.environment,
                      controller=self.controller if self.closed_loop else None)

    @property
    def n_samples(self) -> int:
        """Rows of the log."""
        return int(round(self.duration_s * self.rate_hz))


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class IndependentTruth:
    """What really happened, sampled at the rows of the log.

    Parameters
    ----------
    t : ndarray
        Row times [s].
    theta, omega : ndarray
        True motor angle (log frame) [rad] and velocity [rad/s].
    q, v : ndarray
        True output angle [rad] and velocity [rad/s].
    tau_spring : ndarray
        True spring torque (dead band included) [N m].
    tau_friction : ndarray
        Friction beyond viscous ``d_m theta'`` and cogging; while stuck the
        holding torque [N m].
    tau_cogging : ndarray
        Angle-dependent conservative torque [N m].
    tau_applied : ndarray
        Torque at the motor from the row on, ``g tau_m(t - delay)`` [N m].
    command : ndarray
        The command ``tau_m`` as applied (the logged value) [N m].
    stuck : ndarray of bool
        Motor stuck at the row.
    spring_mode : ndarray of int
        2 linear spring, 1 / -1 contact on the positive / negative side, 0 in the dead band.
    testbed : Testbed
        The simulated testbed.
    environment : Environment
        The simulated environment.
    effect_params : Mapping[str, object]
        True effect parameters (as the case) plus ``cog_a_log``, ``cog_b_log``,
        ``pos_a_log``, ``pos_b_log``: the harmonics in the logged angle.
    initial_angle : float
        Absolute motor angle at the first row [rad].
    events : int
        Mode switches located by root finding.
    """

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tau_spring: np.ndarray
    tau_friction: np.ndarray
    tau_cogging: np.ndarray
    tau_applied: np.ndarray
    command: np.ndarray
    stuck: np.ndarray
    spring_mode: np.ndarray
    testbed: Testbed
    environment: Environment
    effect_params: Mapping[str, Any]
    initial_angle: float
    events: int


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class IndependentLog:
    """An identifiable independent log.

    Parameters
    ----------
    experiment : Experiment
        The log as a tool reads it.
    truth : IndependentTruth
        What really happened.
    case : IndependentCase
        The accepted draw.
    rejected : tuple of str
        Why earlier attempts were redrawn, one reason per attempt.
    """

    experiment: Experiment
    truth: IndependentTruth
    case: IndependentCase
    rejected: tuple[str, ...] = ()


def _word(word: Any) -> Effect:
    try:
        return Effect(str(word))
    except ValueError:
        raise ParameterError(f"unknown effect word {word!r}; known: {', '.join(_WORDS)}",
                             name="word", value=word) from None


# --------------------------------------------------------------------------------------
# small signal helpers


def round_significant(values: Any, digits: int) -> np.ndarray:
    """Round like a logger printing ``%.<digits>g``: parse back what would be printed.

    Parameters
    ----------
    values : array_like
        Numbers to round.
    digits : int
        Significant digits, 1..17.

    Returns
    -------
    ndarray
        The printed values as floats.
    """
    spec = f".{int(digits) - 1}e"
    arr = np.asarray(values, dtype=float)
    return np.array([float(format(x, spec)) for x in arr.ravel().tolist()]).reshape(arr.shape)


def one_line_fraction(x: Any) -> float:
    """Fraction of a signal's variance in its strongest spectral line.

    Hann-windowed periodogram of ``x - mean(x)``; the strongest bin and two
    bins either side (the window's leakage) make the line.

    Parameters
    ----------
    x : array_like
        Uniformly sampled signal.

    Returns
    -------
    float
        In [0, 1]; 1.0 for a constant signal, near 1 for one sine.
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    if x.size < 8 or not np.any(x):
        return 1.0
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    p[0] = 0.0
    total = p.sum()
    if total <= 0.0:
        return 1.0
    k = int(np.argmax(p))
    return float(p[max(k - 2, 0):k + 3].sum() / total)


def _schroeder_phases(bins: np.ndarray, amps: np.ndarray) -> np.ndarray:
    """Schroeder's phases for lines on harmonics `bins` with amplitudes `amps`.

    phi_k = -2 pi sum_{l<k} (b_k - b_l) p_l with p_l the relative power of line l
    (Schroeder 1970, for a general power spectrum; missing harmonics have p = 0).
    """
    p = amps ** 2 / np.sum(amps ** 2)
    return np.array([-2.0 * np.pi * np.sum((b - bins[:k]) * p[:k]) for k, b in enumerate(bins)])


def _low_crest_multisine(n: int, bins: np.ndarray, amps: np.ndarray, iterations: int = 40) -> np.ndarray:
    """One period of a multisine: Schroeder phases, then clipping and phase retrieval (best kept)."""
    spec = np.zeros(n // 2 + 1, dtype=complex)

    def synth(ph: np.ndarray) -> np.ndarray:
        spec[:] = 0.0
        spec[bins] = amps * np.exp(1j * ph) * n / 2.0
        return np.fft.irfft(spec, n)

    x = synth(_schroeder_phases(bins, amps))
    rms = float(np.sqrt(np.mean(x ** 2)))
    best, best_peak = x, float(np.max(np.abs(x)))
    for it in range(iterations):
        level = (1.6 - 0.5 * it / max(iterations - 1, 1)) * rms
        x = synth(np.angle(np.fft.rfft(np.clip(x, -level, level))[bins]))
        peak = float(np.max(np.abs(x)))
        if peak < best_peak:
            best, best_peak = x, peak
    return best


def _multisine(n: int, rate_hz: float, rms: float, f_lo: float, f_hi: float, lines: int,
               periods: int, tilt: float) -> np.ndarray:
    n_p = max(n // periods, 8)
    f_res = rate_hz / n_p
    want = np.geomspace(f_lo, max(f_hi, f_lo), lines)
    bins = np.unique(np.clip(np.round(want / f_res).astype(int), 1, n_p // 2 - 1))
    amps = (bins * f_res) ** (-tilt)
    x = _low_crest_multisine(n_p, bins, amps)
    x = x * (rms / np.sqrt(np.mean(x ** 2)))
    return np.resize(x, n)


def excitation_signal(excitation: Excitation, n: int, rate_hz: float) -> np.ndarray:
    """The sampled command (or reference) of an excitation.

    Parameters
    ----------
    excitation : Excitation
        What to generate.
    n : int
        Number of samples.
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    ndarray, shape (n,)
        Sample values, held over each period [N m].
    """
    ex = excitation
    t = np.arange(n) / rate_hz
    duration = n / rate_hz
    if ex.kind == "constant":
        x = np.full(n, ex.amplitude)
    elif ex.kind == "multisine":
        x = _multisine(n, rate_hz, ex.amplitude, ex.f_lo_hz, ex.f_hi_hz, ex.lines, ex.periods, ex.tilt)
    elif ex.kind == "square":
        x = ex.amplitude * np.where(np.sin(2 * np.pi * t / ex.period_s + 1e-9) >= 0.0, 1.0, -1.0)
    elif ex.kind == "chirp":
        r = math.log(ex.f_hi_hz / ex.f_lo_hz) if ex.f_hi_hz > ex.f_lo_hz else 0.0
        if r > 0.0:
            phase = 2 * np.pi * ex.f_lo_hz * duration / r * np.expm1(r * t / duration)
        else:
            phase = 2 * np.pi * ex.f_lo_hz * t
        fade = np.clip(t / 0.25, 0.0, 1.0)
        x = ex.amplitude * np.sin(phase) * (0.5 - 0.5 * np.cos(np.pi * fade))
    elif ex.kind == "sweep":
        x = ex.amplitude * np.sin(2 * np.pi * ex.f_lo_hz * t)
    else:  # triangle, starting at 0 and rising
        x = ex.amplitude * (2.0 / np.pi) * np.arcsin(np.sin(2 * np.pi * t / ex.period_s))
    if ex.dither > 0.0 and ex.kind in ("sweep", "triangle"):
        x = x + _multisine(n, rate_hz, ex.dither, 1.0, min(8.0, rate_hz / 20), 8, 1, 0.0)
    x = x + ex.offset
    if ex.kind == "square" and ex.slew is not None:
        step = ex.slew / rate_hz
        out = np.empty(n)
        y = 0.0
        for i, target in enumerate(x.tolist()):
            y += min(max(target - y, -step), step)
            out[i] = y
        x = out
    return x


def _harmonic(terms: list[tuple[int, float, float]], angle: float) -> float:
    return sum(a * math.sin(i * angle) + b * math.cos(i * angle) for i, a, b in terms)


def _to_log_frame(a: tuple[float, ...], b: tuple[float, ...], phi: float) -> tuple[tuple, tuple]:
    """Harmonics of theta + phi written as harmonics of theta."""
    a2, b2 = [], []
    for i, (ai, bi) in enumerate(zip(a, b), start=1):
        c, s = math.cos(i * phi), math.sin(i * phi)
        a2.append(ai * c - bi * s)
        b2.append(ai * s + bi * c)
    return tuple(a2), tuple(b2)


# --------------------------------------------------------------------------------------
# the plant and its hybrid integrator


class _Plant:
    """Right-hand side, mode-validity functions and mode transitions of the hybrid plant."""

    def __init__(self, case: IndependentCase):
        tb, env, p = case.true_testbed, case.true_environment, case.effect_params
        self.J_m, self.d_m, self.k = tb.J_m, tb.d_m, tb.k
        self.locked = env.locked
        self.J, self.d, self.k_e = env.J, env.d, env.k_e
        if not self.locked and self.J <= 0.0:
            raise ParameterError("the independent generator needs an output inertia J > 0 (or locked)",
                                 name="J_e", value=env.J)
        self.F_c = float(p.get("F_c", 0.0))
        self.F_s = float(p.get("F_s", self.F_c))
        self.v_s = float(p.get("v_s", 1.0))
        self.stribeck = self.F_s != self.F_c
        if self.F_s < self.F_c:
            raise ParameterError(f"stiction needs F_s >= F_c, got {self.F_s} < {self.F_c}", name="F_s")
        self.pos = [(i, a, b) for i, (a, b) in enumerate(zip(p.get("pos_a", ()), p.get("pos_b", ())), 1)
                    if a or b]
        self.cog = [(i, a, b) for i, (a, b) in enumerate(zip(p.get("cog_a", ()), p.get("cog_b", ())), 1)
                    if a or b]
        if self.pos and self.F_c - sum(math.hypot(a, b) for _, a, b in self.pos) < 0.0:
            raise ParameterError("position friction level F_c + sum(...) must stay >= 0",
                                 name="pos_a", value=p.get("pos_a"))
        self.lugre = "sigma0" in p
        self.sigma0 = float(p.get("sigma0", 0.0))
        self.sigma1 = float(p.get("sigma1", 0.0))
        self.h = 0.5 * float(p.get("width", 0.0))
        self.delay = float(p.get("delay_s", 0.0))
        self.gain = float(p.get("gain", 1.0))
        self.phi0 = float(case.initial_angle)
        self.sticking = (not self.lugre) and (self.F_s > 0.0 or bool(self.pos))
        self.switching = self.sticking or self.h > 0.0
        self.u = 0.0                      # applied torque g tau_m(t - delay) [N m]
        self.motor = _STUCK if self.sticking else _FREE
        self.spring = _BAND if self.h > 0.0 else _LINEAR
        self.events = 0

    # ---- forces
    def spring_torque(self, d: float) -> float:
        m = self.spring
        if m == _LINEAR:
            return self.k * d
        if m == 1:
            return self.k * (d - self.h)
        if m == -1:
            return self.k * (d + self.h)
        return 0.0

    def cogging(self, angle: float) -> float:
        return _harmonic(self.cog, angle) if self.cog else 0.0

    def level(self, angle: float, w: float) -> float:
        """Friction magnitude when sliding at w (Stribeck curve + position part)."""
        lv = self.F_c
        if self.stribeck:
            lv += (self.F_s - self.F_c) * math.exp(-((w / self.v_s) ** 2))
        if self.pos:
            lv += _harmonic(self.pos, angle)
        return lv

    def static_level(self, angle: float) -> float:
        return self.F_s + (_harmonic(self.pos, angle) if self.pos else 0.0)

    def net(self, x) -> float:
        """Torque on the motor apart from friction and viscous damping [N m]."""
        return self.u - self.spring_torque(x[0] - x[2]) - self.cogging(x[0] + self.phi0)

    def rhs(self, t: float, x) -> list[float]:
        th, w, q, v, z = x[0], x[1], x[2], x[3], x[4]
        ts = self.spring_torque(th - q)
        if self.locked:
            dq = dv = 0.0
        else:
            dq, dv = v, (ts - self.d * v - self.k_e * q) / self.J
        m = self.motor
        if m == _STUCK:
            return [0.0, 0.0, dq, dv, 0.0]
        ang = th + self.phi0
        dz = 0.0
        if self.lugre:
            g = self.level(ang, w)
            dz = w - self.sigma0 * abs(w) * z / g
            tf = self.sigma0 * z + self.sigma1 * dz
        elif m == _FREE:
            tf = 0.0
        else:
            tf = m * self.level(ang, w)
        dw = (self.u - ts - self.d_m * w - tf - self.cogging(ang)) / self.J_m
        return [w, dw, dq, dv, dz]

    def forces(self, x) -> tuple[float, float, float]:
        """(spring, friction beyond viscous, cogging) torques at state x [N m]."""
        th, w = x[0], x[1]
        ang = th + self.phi0
        ts = self.spring_torque(th - x[2])
        tc = self.cogging(ang)
        if self.lugre:
            dz = w - self.sigma0 * abs(w) * x[4] / self.level(ang, w)
            tf = self.sigma0 * x[4] + self.sigma1 * dz
        elif self.motor == _STUCK:
            tf = self.u - ts - tc
        elif self.motor == _FREE:
            tf = 0.0
        else:
            tf = self.motor * self.level(ang, w)
        return ts, tf, tc

    # ---- modes
    def tags(self) -> list[str]:
        out = []
        if self.motor in (1, -1):
            out.append("w")
        elif self.motor == _STUCK:
            out += ["stuck+", "stuck-"]
        if self.spring == 1:
            out.append("contact+")
        elif self.spring == -1:
            out.append("contact-")
        elif self.spring == _BAND:
            out += ["band+", "band-"]
        return out

    def validity(self, x) -> list[float]:
        """Mode-validity functions, all >= 0 while the current modes hold (order of :meth:`tags`)."""
        out = []
        m = self.motor
        if m == 1 or m == -1:
            out.append(m * x[1] + _TOL_W)
        elif m == _STUCK:
            n = self.net(x)
            fs = self.static_level(x[0] + self.phi0)
            out += [fs - n + _TOL_N, fs + n + _TOL_N]
        s = self.spring
        if s != _LINEAR:
            d = x[0] - x[2]
            if s == 1:
                out.append(d - self.h + _TOL_D)
            elif s == -1:
                out.append(-d - self.h + _TOL_D)
            else:
                out += [self.h - d + _TOL_D, d + self.h + _TOL_D]
        return out

    def _stick_or_slip(self, x) -> None:
        n = self.net(x)
        if abs(n) <= self.static_level(x[0] + self.phi0):
            self.motor = _STUCK
        else:
            self.motor = 1 if n > 0.0 else -1

    def transition(self, tag: str, x) -> None:
        """Apply the switch whose validity function crossed zero (x is modified in place)."""
        self.events += 1
        if tag == "w":
            x[1] = 0.0
            self._stick_or_slip(x)
        elif tag == "stuck+":
            self.motor = 1
        elif tag == "stuck-":
            self.motor = -1
        elif tag in ("contact+", "contact-"):
            self.spring = _BAND
        elif tag == "band+":
            self.spring = 1
        else:
            self.spring = -1

    def resolve(self, x) -> None:
        """Make the modes consistent with the state and the applied torque (after a torque step)."""
        for _ in range(6):
            changed = False
            if self.spring != _LINEAR:
                d = x[0] - x[2]
                s = self.spring
                valid = ((s == 1 and d >= self.h - _TOL_D) or (s == -1 and d <= -self.h + _TOL_D)
                         or (s == _BAND and -self.h - _TOL_D <= d <= self.h + _TOL_D))
                if not valid:
                    self.spring = 1 if d >= self.h else (-1 if d <= -self.h else _BAND)
                    changed = True
            if self.sticking:
                m = self.motor
                if m == _STUCK:
                    n = self.net(x)
                    if abs(n) > self.static_level(x[0] + self.phi0) + _TOL_N:
                        self.motor = 1 if n > 0.0 else -1
                        changed = True
                elif m * x[1] < -_TOL_W:    # a reversal the interval check missed
                    x[1] = 0.0
                    self._stick_or_slip(x)
                    changed = True
            if not changed:
                return


class _Integrator:
    """Advance the hybrid plant over intervals of constant applied torque."""

    def __init__(self, plant: _Plant):
        self.plant = plant
        self.ode = ode(plant.rhs).set_integrator("dopri5", rtol=_RTOL, atol=_ATOL, nsteps=200_000)

    def advance(self, x: np.ndarray, t_a: float, t_b: float) -> np.ndarray:
        p = self.plant
        p.resolve(x)
        r = self.ode
        r.set_initial_value(x, t_a)
        y = r.integrate(t_b)
        if not r.successful():
            raise SolverError(f"dopri5 failed on [{t_a}, {t_b}] s (code {r.get_return_code()})")
        if not p.switching or min(p.validity(y), default=1.0) >= 0.0:
            return np.array(y)
        return self._advance_with_events(np.array(x, dtype=float), t_a, t_b)

    def _advance_with_events(self, x: np.ndarray, t: float, t_b: float) -> np.ndarray:
        p = self.plant
        for _ in range(_MAX_EVENTS_PER_INTERVAL):
            tags = p.tags()
            events = []
            for i in range(len(tags)):
                def ev(_t, y, i=i):
                    return p.validity(y)[i]
                ev.terminal = True
                ev.direction = -1.0
                events.append(ev)
            sol = solve_ivp(p.rhs, (t, t_b), x, method="DOP853", rtol=_RTOL, atol=_ATOL, events=events)
            if sol.status == -1:
                raise SolverError(f"solve_ivp failed on [{t}, {t_b}] s: {sol.message}")
            if sol.status != 1:
                return sol.y[:, -1].copy()
            hits = [(te[0], i, ye[0])
                    for i, (te, ye) in enumerate(zip(sol.t_events, sol.y_events)) if len(te)]
            t_e, i, x_e = min(hits, key=lambda h: h[0])
            x = np.array(x_e, dtype=float)
            t = float(t_e)
            p.transition(tags[i], x)
            p.resolve(x)
            if t >= t_b:
                return x
        raise SolverError(f"more than {_MAX_EVENTS_PER_INTERVAL} mode switches in one interval at t = {t} s")


# --------------------------------------------------------------------------------------
# simulation and logging


def simulate_independent(case: IndependentCase) -> tuple[Experiment, IndependentTruth]:
    """Simulate one case and write its log.

    Parameters
    ----------
    case : IndependentCase
        The case (see :func:`draw_independent_case`).

    Returns
    -------
    experiment : Experiment
        The log: nominal TOML, quantised angles, printed ``tau_m`` (and
        ``tau_r``), ``tau_s`` as the case's logger writes it.
    truth : IndependentTruth
        The true signals at the rows and the true parameters.

    Raises
    ------
    SolverError
        If an integration step fails or the modes chatter.
    """
    plant = _Plant(case)
    integ = _Integrator(plant)
    rate, n = float(case.rate_hz), case.n_samples
    T = 1.0 / rate
    rng = np.random.default_rng(np.random.SeedSequence([int(case.seed), 0x10660]))
    enc_noise = rng.standard_normal((n, 2)) * (case.encoder_noise_counts * ENCODER_STEP)
    sens_noise = rng.standard_normal(n) * case.sensor_noise
    k_nom = case.testbed.k
    digits = int(case.tau_m_digits)
    fmt = f".{digits - 1}e"
    tau_s_mode = case.tau_s_logging
    ref = excitation_signal(case.excitation, n, rate)
    if case.closed_loop:
        ref = round_significant(ref, digits)
        ctrl = case.controller
        tf = 1.0 / (2.0 * math.pi * case.derivative_filter_hz)
        c1, c2 = (2.0 * tf - T) / (2.0 * tf + T), 2.0 / (2.0 * tf + T)
        limit = case.torque_limit
        e_prev = None
        de = 0.0
    else:
        ref_cmd = round_significant(ref, digits)

    m_delay = int(math.floor(plant.delay * rate + 1e-12))
    r_delay = plant.delay - m_delay * T
    if r_delay < 1e-12 * T:
        r_delay = 0.0
    cmd = np.zeros(n)
    rec = np.empty((n, 5))
    rec_forces = np.empty((n, 4))
    stuck = np.zeros(n, dtype=bool)
    smode = np.empty(n, dtype=np.int8)
    theta_m = np.empty(n)
    q_m = np.empty(n)
    tau_s_log = np.empty(n)
    x = np.zeros(5)

    def applied(j: int) -> float:
        return plant.gain * cmd[j] if j >= 0 else 0.0

    for k in range(n):
        t_k = k * T
        # measurement at t_k
        th_meas = round((x[0] + enc_noise[k, 0]) / ENCODER_STEP) * ENCODER_STEP
        q_meas = 0.0 if plant.locked else round((x[2] + enc_noise[k, 1]) / ENCODER_STEP) * ENCODER_STEP
        theta_m[k], q_m[k] = th_meas, q_meas
        if tau_s_mode == "sensor":
            tau_meas = float(format(plant.spring_torque(x[0] - x[2]) + sens_noise[k], ".6e"))
        else:
            tau_meas = k_nom * (th_meas - q_meas)
        tau_s_log[k] = tau_meas
        # command
        if case.closed_loop:
            e = ref[k] - tau_meas
            de = 0.0 if e_prev is None else c1 * de + c2 * (e - e_prev)
            e_prev = e
            u = min(max(ctrl.P * e + ctrl.D * de, -limit), limit)
            cmd[k] = float(format(u, fmt))
        else:
            cmd[k] = ref_cmd[k]
        # truth at t_k (modes resolved for the torque applied from t_k on)
        plant.u = applied(k - m_delay - 1) if r_delay > 0.0 else applied(k - m_delay)
        plant.resolve(x)
        rec[k] = x
        ts, tfr, tc = plant.forces(x)
        rec_forces[k] = (ts, tfr, tc, plant.u)
        stuck[k] = plant.motor == _STUCK
        smode[k] = plant.spring
        if k == n - 1:
            break
        # advance to t_{k+1}; the delay splits the period where the delayed command switches
        if r_delay > 0.0:
            x = integ.advance(x, t_k, t_k + r_delay)
            plant.u = applied(k - m_delay)
            x = integ.advance(x, t_k + r_delay, t_k + T)
        else:
            x = integ.advance(x, t_k, t_k + T)
        if not np.all(np.isfinite(x)) or abs(x[0]) > 1e6:
            raise SolverError(f"the state left any physical range at t = {t_k + T} s")

    t = np.round(case.t0_s + np.arange(n) * T, 9)
    if tau_s_mode == "omitted":
        tau_s_col = None
    elif tau_s_mode == "sensor":
        tau_s_col = tau_s_log
    else:
        tau_s_col = round_significant(tau_s_log, int(tau_s_mode.split(":")[1]))
    words = ", ".join(str(w) for w in case.words) or "none"
    description = (f"independent generator: {words} at x{case.magnitude_scale:g}, {case.excitation.kind}, "
                   f"{case.environment_name}, {'closed' if case.closed_loop else 'open'} loop")
    exp = experiment_from_arrays(case.design, rate, t, cmd, theta_m, q_m, tau_s=tau_s_col,
                                 tau_r=ref if case.closed_loop else None, description=description)
    params = dict(case.effect_params)
    for key in ("cog", "pos"):
        if f"{key}_a" in params:
            a, b = _to_log_frame(params[f"{key}_a"], params[f"{key}_b"], case.initial_angle)
            params[f"{key}_a_log"], params[f"{key}_b_log"] = a, b

    def ro(a: np.ndarray) -> np.ndarray:
        a = np.array(a)
        a.flags.writeable = False
        return a

    truth = IndependentTruth(
        t=ro(t), theta=ro(rec[:, 0]), omega=ro(rec[:, 1]), q=ro(rec[:, 2]), v=ro(rec[:, 3]),
        tau_spring=ro(rec_forces[:, 0]), tau_friction=ro(rec_forces[:, 1]), tau_cogging=ro(rec_forces[:, 2]),
        tau_applied=ro(rec_forces[:, 3]), command=ro(cmd), stuck=ro(stuck), spring_mode=ro(smode),
        testbed=case.true_testbed, environment=case.true_environment,
        effect_params=MappingProxyType(params), initial_angle=float(case.initial_angle), events=plant.events,
    )
    return exp, truth


# --------------------------------------------------------------------------------------
# drawing cases


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


def draw_independent_case(word: Effect | str, index: int, seed: int, *, magnitude_scale: float = 1.0,
                          attempt: int = 0) -> IndependentCase:
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
    controller = PDController(P=float(rng.uniform(3.0, 6.0)), D=float(rng.uniform(0.05, 0.12)))
    r = rng.random()
    tau_s = "omitted" if r < 0.3 else ("sensor" if r > 0.8 else f"derived:{int(rng.integers(6, 11))}")
    return IndependentCase(
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
    ``2 v_s`` (else the Stribeck decay from ``F_s`` to ``F_c`` is never seen); delay and torque gain a command with < 95 % of
    its variance in one spectral line (:func:`one_line_fraction`); backlash
    >= 2 passages through the dead band from one contact side to the other;
    an environment mismatch an unlocked output that moves >= 100 counts; a torque
    gain ``|g - 1|`` beyond the datasheet tolerance of the nominal ``J_m`` and ``k``
    (:data:`forecast_design.plausibility.DATASHEET_TOLERANCE`), within which it is a
    common rescaling of the nominal model.
    Every log must also keep its command below the torque limit most of the
    time (closed loop) and its motor below 10^4 rad.
    """
    th, w = np.asarray(truth.theta), np.asarray(truth.omega)
    if not (np.all(np.isfinite(th)) and np.max(np.abs(th)) < 1e4):
        return "the motor angle left any physical range"
    if case.closed_loop:
        sat = float(np.mean(np.abs(truth.command) >= case.torque_limit * (1 - 1e-6)))
        if sat > 0.05:
            return f"the command saturates {100 * sat:.0f} % of the time"
    for word in case.words:
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
                return (f"torque_gain: |gain - 1| = {abs(g - 1.0):.3f} within the {DATASHEET_TOLERANCE['J_m']:.0%} "
                        "datasheet tolerance of the re-calibration")
        if word is Effect.BACKLASH:
            sides = np.asarray(truth.spring_mode)
            sides = sides[(sides == 1) | (sides == -1)]
            passes = int(np.count_nonzero(np.diff(sides))) if sides.size else 0
            if passes < 2:
                return f"backlash: {passes} passage(s) through the dead band, needs >= 2"
        if word is Effect.ENVIRONMENT_MISMATCH:
            if case.environment.locked:
                return "environment_mismatch: the output is locked"
            travel = float(np.ptp(truth.q))
            if travel < 100 * ENCODER_STEP:
                return (f"environment_mismatch: the output moves {travel / ENCODER_STEP:.0f} counts, "
                        "needs >= 100")
    return None


def make_independent_log(word: Effect | str, index: int, seed: int, *,
                         magnitude_scale: float = 1.0) -> IndependentLog:
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
        case = draw_independent_case(word, index, seed, magnitude_scale=magnitude_scale, attempt=attempt)
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
    "extended-sfm": MappingProxyType({"viscous": 0.3, "coulomb": 0.3, "sin1": 0.05, "cos1": 0.02,
                                      "sin2": 0.0, "cos2": 0.03, "sin3": 0.01, "cos3": 0.0,
                                      "sin4": 0.0, "cos4": 0.01}),
    "stribeck": MappingProxyType({"static": 0.45, "coulomb": 0.3, "stribeck_velocity": 0.05,
                                  "viscous": 0.3}),
    "lugre": MappingProxyType({"sigma0": 1000.0, "sigma1": 5.0, "static": 0.45, "coulomb": 0.3,
                               "stribeck_velocity": 0.05, "viscous": 0.3}),
})


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
