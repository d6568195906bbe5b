"""Independent log generator: model (see the package docstring)."""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..effects import Effect
from ..errors import ParameterError
from ..experiment import Experiment
from ..controllers import PD, PID
from ..params import Environment, Design, Testbed

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
FRICTION_LAWS = ("sfm", "extended-sfm", "asymmetric", "stribeck", "lugre", "position-friction")
#: Words whose effect depends on the motor angle (need a revolution of travel).
ANGLE_WORDS = (Effect.POSITION_FRICTION, Effect.COGGING)

_WORDS = tuple(Effect)
_FRICTION_WORDS = (Effect.COULOMB, Effect.STICTION, Effect.POSITION_FRICTION)
_PARAM_KEYS = ("F_c", "F_s", "v_s", "sigma0", "sigma1", "pos_a", "pos_b", "cog_a", "cog_b",
               "width", "delay_s", "gain", "J_factor", "d_factor", "k_e_factor", "F_c_neg", "F_s_neg", "d_neg")
_TAU_S_RE = re.compile(r"^(omitted|sensor|float32|derived:(\d+)|decimals:(\d+))$")
_ANGLE_RE = re.compile(r"^(exact|float32|digits:(\d+)|decimals:(\d+))$")
#: Encoder resolutions the loggers may have [counts/rev]: the testbed's, 16 and 14 bit.
ENCODER_COUNTS = (COUNTS_PER_REV, 2**16, 2**14)

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
        PD or PID force control (``controller``) instead of an open-loop command.
    controller : PD, PID or None
        Gains of the force controller (closed loop): ``P``, ``D`` and, for a PID, ``I`` [1/s], whose
        integrator the generator's own loop runs with the trapezoidal rule, without anti-windup.
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
        ``omitted``, ``derived:<digits>`` (printed ``k_nominal (theta - q)`` at
        1-17 significant digits), ``decimals:<n>`` (the same printed with a fixed
        number 0-12 of decimal places, ``%.<n>f``: small torques keep fewer
        significant digits than large ones), ``float32`` (the same stored as a
        32-bit float, written with every digit of that float) or ``sensor`` (independent torque
        sensor with noise, printed at 7 significant digits; the controller then
        feeds back the sensor).
    tau_m_digits : int
        Significant digits of the printed ``tau_m`` (and ``tau_r``).
    encoder_noise_counts : float
        Standard deviation of encoder noise before quantisation [counts].
    encoder_counts : int
        Counts per revolution of both encoders [-] (2,000,000 on the testbed; 65,536 or
        16,384 for 16- and 14-bit encoders).
    angle_logging : str
        How the logger prints ``theta`` and ``q``: ``exact`` (every digit of the quantised
        angle), ``digits:<n>`` (n = 4-17 significant digits), ``decimals:<n>`` (n = 3-12
        decimal places) or ``float32`` (stored as 32-bit floats: 24 bits of mantissa, coarser than
        the encoder beyond a few revolutions). A derived ``tau_s`` is computed from the angles
        before printing.
    sensor_noise : float
        Standard deviation of the torque-sensor noise [N m].
    sensor_offset : float
        Zero offset of the torque sensor (reads gain x spring torque + offset) [N m].
    sensor_gain : float
        Scale of the torque sensor [-] (1: calibrated).
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
        ``F_c_neg``, ``F_s_neg`` [N m] and ``d_neg`` [N m s/rad]: asymmetric friction,
        the Coulomb and static levels and the viscous coefficient for negative motion
        (``F_c``, ``F_s`` and the testbed's ``d_m`` then act for positive motion).
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
    controller: PD | PID | None = None
    derivative_filter_hz: float = 100.0
    torque_limit: float = 5.0
    rate_hz: float = 2000.0
    duration_s: float = 10.0
    t0_s: float = 0.0
    tau_s_logging: str = "omitted"
    tau_m_digits: int = 8
    encoder_noise_counts: float = 0.0
    encoder_counts: int = COUNTS_PER_REV
    angle_logging: str = "exact"
    sensor_noise: float = 0.0
    sensor_offset: float = 0.0
    sensor_gain: float = 1.0
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
        if m is None or (m.group(2) is not None and not 1 <= int(m.group(2)) <= 17) \
                or (m.group(3) is not None and not 0 <= int(m.group(3)) <= 12):
            raise ParameterError("tau_s_logging must be 'omitted', 'sensor', 'float32', 'derived:<1..17>' or "
                                 f"'decimals:<0..12>', got {self.tau_s_logging!r}", name="tau_s_logging",
                                 value=self.tau_s_logging)
        a = _ANGLE_RE.match(str(self.angle_logging))
        if a is None or (a.group(2) is not None and not 4 <= int(a.group(2)) <= 17) \
                or (a.group(3) is not None and not 3 <= int(a.group(3)) <= 12):
            raise ParameterError("angle_logging must be 'exact', 'float32', 'digits:<4..17>' or 'decimals:<3..12>', "
                                 f"got {self.angle_logging!r}", name="angle_logging", value=self.angle_logging)
        c = self.encoder_counts
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 64 <= int(c) <= 10**9:
            raise ParameterError(f"encoder_counts must be an integer in [64, 1e9], got {c!r}",
                                 name="encoder_counts", value=c)
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
    def encoder_step(self) -> float:
        """One count of the case's encoders [rad]."""
        return 2.0 * math.pi / int(self.encoder_counts)

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
        """The nominal design written to the TOML (with the controller that ran when closed loop: its gains,
        the first-order derivative filter and the Tustin discretisation of :func:`~.plant` 's loop)."""
        ran = None
        if self.closed_loop and self.controller is not None:
            ran = dataclasses.replace(self.controller, T_f=1.0 / (2.0 * math.pi * self.derivative_filter_hz),
                                      discretization="tustin")
        return Design(testbed=self.testbed, environment=self.environment, controller=ran)

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
