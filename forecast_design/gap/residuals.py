"""Equation-error residuals of the nominal model, filtered and decimated, with a block split.

The recorded motor torque is the authoritative input. Each equation of the
experiment format's nominal model is turned into an *equation error* (a
torque [N m]) that is zero when the log obeys the nominal model::

    motor        r_m = u - J_m theta'' - d_m theta' - tau_s
    environment  r_e = tau_s - (J q'' + d q' + k_e q)          (not when locked)
    coupling     r_c = tau_s - k (theta - q)                   (only with a measured tau_s)

``u`` is the motor torque command held over ``[t_k, t_k+1)`` (the format's
zero-order hold). The acceleration is the second difference over one period,
which equals the true acceleration averaged under a hat kernel of half-width
``T``; the same kernel turns the held command into ``u[k] = (tau_m[k-1] +
tau_m[k]) / 2`` (:func:`delayed_input`). For a pure inertia that pairing is
exact, so a log that obeys the nominal model leaves (almost) no residual even
under broadband (square-wave, derivative-kick) commands; the gradient of the
gradient, by contrast, carries a ``cos^2(w T / 2)`` magnitude error that
looks like a small delay.

Every raw column (positions, command, spring torque, candidate features) goes
through the same zero-phase Butterworth low-pass (``position_cutoff_hz``) and
the same parallel decimation (:mod:`forecast_design.friction.derivatives`): a
linear filter applied to targets and regressors alike keeps models that are
linear in their parameters unbiased.

Unmodelled effects enter these residuals additively (see
:mod:`forecast_design.gap.candidates`): friction, cogging, delay and torque gain
in ``r_m``; environment mismatch in ``r_e``; backlash in ``r_m`` and ``r_e`` when
``tau_s`` is derived from the encoders, in ``r_c`` when it is measured.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np

from ..errors import ExperimentFormatError, IdentifiabilityError, ParameterError
from ..experiment import Experiment
from ..tau_s_source import TauSSource, classify_tau_s, significant_digits
from ..plausibility import DATASHEET_TOLERANCE, LogScales, encoder_step_of, log_scales
from ..limits import SIGNAL_LIMITS, first_beyond
from scipy import signal

from ..friction.derivatives import FilterSettings, butterworth, decimate_columns, default_filter_settings

__all__ = ["GapOptions", "GapData", "TauSSource", "prepare_gap_data", "classify_tau_s", "significant_digits",
           "zoh_input", "delayed_input", "lowpass", "gap_log_scales"]

#: Raw-rate samples (columns x log length) filtered in one pass by ``GapData.decimate_many`` [-]:
#: 2 MB per filter copy, a fixed size rather than one per sample.
BATCH_SAMPLES = 1 << 18

#: Equation names, in stacking order.
EQUATIONS = ("motor", "environment", "coupling")


@dataclass(frozen=True, slots=True, kw_only=True)
class GapOptions:
    """Settings of the gap diagnosis.

    Parameters
    ----------
    position_cutoff_hz : float, optional
        Zero-phase Butterworth cut-off on encoder positions [Hz]; default ``rate_hz / 10``, or
        the decimated rate when the encoder's resolution lowers it (below).
    decimated_rate_hz : float, optional
        Target rate after parallel decimation [Hz]; the factor is ``round(rate_hz / this)``.
        Default: 100 Hz, lowered (not below 10 Hz) until the encoder's quantisation, twice
        differentiated in ``J_m theta''``, stays below ``quantization_noise_fraction`` of the RMS
        motor command in the band kept (0.4 x the decimated rate): see :func:`equation_band`.
    quantization_noise_fraction : float
        Largest RMS torque [fraction of the RMS command] that the encoder's quantisation may put
        into the motor equation in the automatic band [-].
    n_blocks : int
        Number of interleaved time blocks; even blocks fit, odd blocks are held out [-].
    calibration_tolerance : float
        Relative range within which ``J_m`` and the spring torque scale (``k``) may be
        re-calibrated before anything is blamed on an unmodelled effect [-]; default the
        testbed's datasheet tolerance (:data:`forecast_design.plausibility.DATASHEET_TOLERANCE`,
        3 %). A wider range lets the re-calibration absorb a torque gain (a common
        rescaling of ``J_m``, ``d_m`` and ``k``); a re-calibration at this bound is reported.
    n_harmonics : int
        Harmonics of the motor angle used by the ``cogging`` and ``position_friction``
        candidates [-].
    alpha : float
        Family-wise significance level of the held-out test, split over the candidates (weighted
        Bonferroni, :func:`.heldout.candidate_levels`) [-].
    min_reduction : float
        Smallest held-out gap reduction ``1 - gap_after / gap_before`` that counts [-].
    stick_velocity : float
        Motor speed below which a decimated row counts as stuck (its friction is set-valued:
        soft-thresholded by the friction candidates) [rad/s]. It is not the dead band of the
        friction sign feature, which is the encoder's speed resolution (a slower motor still moves).
    max_delay_s : float
        Largest delay the ``delay`` candidate searches [s].
    min_effect_fraction : float
        Smallest RMS torque an effect must explain on held-out data, as a fraction of the RMS
        motor command [-]: a model error below 0.1 % of the torque is below any motor's torque
        accuracy (current sensing is good to about 1 %) and is not blamed on an effect.
    tau_s_reading : str
        ``auto`` (decide from the data, :func:`forecast_design.tau_s_source.classify_tau_s`),
        ``derived`` or ``measured`` (force a reading of a logged ``tau_s`` column; the diagnosis
        tries both itself when the decision is uncertain).
    """

    position_cutoff_hz: float | None = None
    decimated_rate_hz: float | None = None
    quantization_noise_fraction: float = 0.02
    n_blocks: int = 20
    calibration_tolerance: float = DATASHEET_TOLERANCE["J_m"]
    n_harmonics: int = 4
    alpha: float = 0.01
    min_reduction: float = 0.4
    stick_velocity: float = 2e-3
    max_delay_s: float = 0.02
    min_effect_fraction: float = 1e-3
    tau_s_reading: str = "auto"

    def __post_init__(self) -> None:
        for name in ("decimated_rate_hz", "calibration_tolerance", "alpha", "stick_velocity", "max_delay_s",
                     "min_effect_fraction", "quantization_noise_fraction"):
            value = getattr(self, name)
            if name == "decimated_rate_hz" and value is None:
                continue
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ParameterError(f"GapOptions {name} must be > 0, got {value!r}", name=name, value=value)
        if self.tau_s_reading not in ("auto", "derived", "measured"):
            raise ParameterError(f"GapOptions tau_s_reading must be auto, derived or measured, got {self.tau_s_reading!r}",
                                 name="tau_s_reading", value=self.tau_s_reading)
        if not (0.0 <= self.min_reduction < 1.0):
            raise ParameterError(f"GapOptions min_reduction must lie in [0, 1), got {self.min_reduction!r}",
                                 name="min_reduction", value=self.min_reduction)
        for name, lo in (("n_blocks", 4), ("n_harmonics", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise ParameterError(f"GapOptions {name} must be an integer >= {lo}, got {value!r}",
                                     name=name, value=value)


def zoh_input(tau_m: np.ndarray) -> np.ndarray:
    """Motor command re-timed for its zero-order hold.

    Parameters
    ----------
    tau_m : ndarray, shape (n,)
        Command held over each sample period [N m].

    Returns
    -------
    ndarray, shape (n,)
        ``u[k] = (tau_m[k-1] + tau_m[k]) / 2`` (``u[0] = tau_m[0]``) [N m]: the held
        signal's value, in the band below the sample rate, at the sample instants.
    """
    return delayed_input(tau_m, 0.0, 1.0)


def delayed_input(tau_m: np.ndarray, delay_s: float, rate_hz: float) -> np.ndarray:
    """Zero-order-held command delayed by ``delay_s``, as seen by the second difference.

    The motor acceleration is taken as the second difference
    ``(theta[k+1] - 2 theta[k] + theta[k-1]) / T^2``, which is the true acceleration
    averaged under a triangular (hat) kernel of half-width ``T`` centred on ``t_k``.
    For a pure inertia driven by a held command this is *exact*; the matching input
    is the held, delayed command averaged under the same kernel: a sum of the
    samples weighted by the quadratic B-spline (box convolved with hat). Without
    delay it is ``(tau_m[k-1] + tau_m[k]) / 2``.

    Parameters
    ----------
    tau_m : ndarray, shape (n,)
        Command held over each sample period ``[t_k, t_k+1)`` [N m].
    delay_s : float
        Extra delay [s] (>= 0).
    rate_hz : float
        Sample rate [Hz].

    Returns
    -------
    ndarray, shape (n,)
        The hat-averaged delayed held command at the sample instants; the first
        value is repeated before the start [N m].
    """
    tau_m = np.asarray(tau_m, dtype=float)
    n = tau_m.size
    d = float(delay_s) * float(rate_hz)
    whole = int(np.floor(d))
    f = d - whole
    # quadratic B-spline N(x) on [0, 3]: x^2/2, (-2x^2 + 6x - 3)/2, (3 - x)^2/2
    def spline(x: float) -> float:
        if 0.0 <= x < 1.0:
            return 0.5 * x * x
        if 1.0 <= x < 2.0:
            return 0.5 * (-2.0 * x * x + 6.0 * x - 3.0)
        if 2.0 <= x <= 3.0:
            return 0.5 * (3.0 - x) ** 2
        return 0.0
    # weight of tau_m[k - whole - j] at t_k, j = -1..2: N(1 - f + j)
    out = np.zeros(n)
    pad = np.concatenate([np.full(whole + 3, tau_m[0] if n else 0.0), tau_m, np.full(2, tau_m[-1] if n else 0.0)])
    base = whole + 3
    for j in range(-1, 3):
        w = spline(1.0 - f + j)
        if w == 0.0:
            continue
        start = base - whole - j
        out += w * pad[start:start + n]
    return out


def lowpass(x: np.ndarray, settings: FilterSettings) -> np.ndarray:
    """Zero-phase Butterworth low-pass applied to every raw-rate column.

    Parameters
    ----------
    x : ndarray, shape (n,) or (k, n)
        A raw-rate signal, or k of them along the last axis (any unit).
    settings : FilterSettings
        Cut-off ``position_cutoff_hz`` [Hz] and order.

    Returns
    -------
    ndarray, same shape as `x`
        The filtered signal (``scipy.signal.sosfiltfilt``), same unit.
    """
    sos, = butterworth(settings.filter_order, settings.position_cutoff_hz / (settings.rate_hz / 2.0), "sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=-1)


def _derivatives(position: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference velocity and second-difference acceleration [rad/s, rad/s^2].

    The second difference over one period (not the gradient of the gradient, which
    spans two) is the acceleration under a hat kernel of half-width ``T``; with the
    held command averaged the same way (:func:`delayed_input`) a pure inertia obeys
    the sampled equation exactly.
    """
    dt = 1.0 / rate_hz
    v = np.gradient(position, dt)
    a = np.empty_like(position)
    a[1:-1] = (position[2:] - 2.0 * position[1:-1] + position[:-2]) / dt ** 2
    a[0], a[-1] = a[1], a[-2]
    return v, a


def _check_log(experiment: Experiment, theta: np.ndarray, q: np.ndarray, tau_m: np.ndarray, tau_s: np.ndarray,
               settings: FilterSettings, options: GapOptions) -> None:
    """One-line errors for logs the diagnosis cannot use (non-finite, too short, no motion)."""
    src = experiment.source.name if getattr(experiment, "source", None) is not None else "log"
    for name, col in (("theta", theta), ("q", q), ("tau_m", tau_m), ("tau_s", tau_s)):
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise ExperimentFormatError(f"{src}: column {name} is not finite at row {int(bad[0])} "
                                        f"({bad.size} rows); the gap diagnosis needs complete signals",
                                        path=str(experiment.source) if experiment.source else None, key=name)
    for name, col, kind, unit in (("theta", theta, "angle_rad", "rad"), ("q", q, "angle_rad", "rad"),
                                  ("tau_m", tau_m, "torque_N_m", "N m"), ("tau_s", tau_s, "torque_N_m", "N m")):
        at = first_beyond(col, SIGNAL_LIMITS[kind])
        if at is not None:
            raise ExperimentFormatError(f"{src}: column {name} reaches {col[at]:.3g} {unit} at row {at}, beyond "
                                        f"{SIGNAL_LIMITS[kind]:g} {unit}: a diverged run or a corrupt log, not a "
                                        "measurement", path=str(experiment.source) if experiment.source else None,
                                        key=name)
    n = theta.size
    need = max(2 * settings.edge_samples + 4 * options.n_blocks * settings.decimation_factor,
               30 * settings.decimation_factor, 16)
    if n < need:
        raise ParameterError(
            f"{src}: log too short for the gap diagnosis: {n} samples ({n / settings.rate_hz:.3g} s) at "
            f"{settings.rate_hz:g} Hz; need >= {need} ({need / settings.rate_hz:.3g} s) for {options.n_blocks} "
            "held-out blocks; record a longer run", name="n_blocks", value=options.n_blocks)
    if np.ptp(tau_m) <= 0.0:
        raise IdentifiabilityError(f"{src}: tau_m is constant ({tau_m[0]:g} N m): no excitation, nothing "
                                   "to diagnose; record a run with a varying torque command")
    # less than 20 encoder steps of 2e6 counts/rev in total motion: the motor did not move
    if np.ptp(theta) < 20 * 2.0 * np.pi / 2_000_000:
        raise IdentifiabilityError(f"{src}: the motor did not move (theta spans {np.ptp(theta):.3g} rad): "
                                   "equation errors are encoder noise only; record a run with motion")


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class GapData:
    """Decimated equation errors of one log and what the candidates need to build features.

    Parameters
    ----------
    experiment : Experiment
        The log.
    options : GapOptions
        Settings used.
    settings : FilterSettings
        Filter and decimation settings.
    t : ndarray, shape (m,)
        Decimated sample times [s].
    targets : Mapping[str, ndarray]
        Nominal equation errors per equation (``motor``, ``environment``, ``coupling``) [N m].
    columns : Mapping[str, ndarray]
        Decimated signals: ``u``, ``tau_s``, ``a``, ``v``, ``theta``, ``x`` (= theta - q),
        ``qa``, ``qv``, ``q`` [N m, rad/s^2, rad/s, rad].
    raw : Mapping[str, ndarray]
        Filtered raw-rate signals for nonlinear features: ``theta``, ``v``, ``x``, ``tau_m``.
    block : ndarray of int, shape (m,)
        Block index of each decimated sample [-].
    held_out : ndarray of bool, shape (m,)
        True for samples of held-out (odd) blocks.
    stuck : ndarray of bool, shape (m,)
        True where the motor speed is below ``options.stick_velocity``.
    creep : bool
        Whether motion below the encoder's speed resolution is read as creeping where the recorded angle
        moves (:func:`.motion.motion_direction`); False: at rest.
    """

    experiment: Experiment
    options: GapOptions
    settings: FilterSettings
    t: np.ndarray
    targets: Mapping[str, np.ndarray]
    columns: Mapping[str, np.ndarray]
    raw: Mapping[str, np.ndarray]
    block: np.ndarray
    held_out: np.ndarray
    stuck: np.ndarray
    equations: tuple[str, ...] = field(default=())
    tau_s_source: TauSSource = field(default_factory=lambda: TauSSource(source="absent"))
    creep: bool = False
    cache: dict = field(default_factory=dict, repr=False)


    @property
    def command_rms(self) -> float:
        """RMS of the logged motor command ``tau_m`` [N m] (:func:`command_rms`)."""
        return command_rms(self.experiment)

    @property
    def torque_accuracy(self) -> float:
        """Smallest RMS torque an effect must explain, ``options.min_effect_fraction`` x :attr:`command_rms` [N m]."""
        return self.options.min_effect_fraction * self.command_rms

    @property
    def environment_torque_accuracy(self) -> float:
        """Smallest RMS torque an effect in the environment equation alone must explain [N m].

        Where the encoders derive the spring torque, that equation holds it and not the motor's:
        ``options.min_effect_fraction`` x its RMS and not below :attr:`spring_torque_quantisation` (the motor's
        torque accuracy withheld true output inertias of 0.40-0.88 x, 84-100 % of their equation, on light outputs).
        A torque sensor's scale is calibrated against the motor's command, so its torque is known no better than
        the motor's: :attr:`torque_accuracy` (an effect-free open-loop log whose sensor read 0.924 x: J and d
        both 0.955 x, the calibrated scale's error, 7.6 % of the equation). A mismatch removing at least
        ``options.min_reduction`` of its equation's gap is not held to it (:class:`.grading.OwnReduction`).
        """
        if self.tau_s_measured:
            return self.torque_accuracy
        rms = float(np.sqrt(np.mean(np.square(self.columns["tau_s"]))))
        return max(self.options.min_effect_fraction * rms, self.spring_torque_quantisation)

    @property
    def spring_torque_quantisation(self) -> float:
        """RMS of the encoders' quantisation in the spring torque ``k (theta - q)`` [N m].

        ``k`` x each encoder's step (:func:`forecast_design.plausibility.encoder_step_of`) / sqrt(12), the motor's
        and the output's (unless locked) added in quadrature.
        """
        return self.experiment.design.testbed.k * math.sqrt(sum(s ** 2 for s in self.encoder_steps) / 12.0)

    @property
    def spring_torque_resolution(self) -> float:
        """Largest error of the spring torque ``k (theta - q)`` the encoders read: half a step of each [N m].

        ``k`` x (the motor encoder's step + the output encoder's, unless locked) / 2. Where the deflection stays
        within a count (a hold, a slow slide) that error does not average out.
        """
        return self.experiment.design.testbed.k * sum(self.encoder_steps) / 2.0

    @property
    def encoder_steps(self) -> tuple[float, ...]:
        """The motor encoder's step and, unless the output is locked, the output encoder's [rad] (cached)."""
        if "encoder_steps" not in self.cache:
            steps = [gap_log_scales(self).encoder_step]
            if not self.locked:
                steps.append(encoder_step_of(self.experiment.signals.q))
            self.cache["encoder_steps"] = tuple(steps)
        return self.cache["encoder_steps"]

    @property
    def locked(self) -> bool:
        """True when the output is locked (no environment equation)."""
        return "environment" not in self.equations

    @property
    def tau_s_measured(self) -> bool:
        """True when the log holds a measured ``tau_s`` column (coupling equation present)."""
        return "coupling" in self.equations

    def decimate(self, raw_column: np.ndarray) -> np.ndarray:
        """Drop the filter edges and parallel-decimate one raw-rate column.

        Parameters
        ----------
        raw_column : ndarray, shape (n,)
            A signal at the log's rate (any unit).

        Returns
        -------
        ndarray, shape (m,)
            The signal low-passed like every other column (position Butterworth,
            zero phase), then decimated to the decimated rate, same unit.
        """
        col = lowpass(np.asarray(raw_column, dtype=float), self.settings)
        return decimate_columns(col[:, None], self.settings)[:, 0]

    def decimate_many(self, raw_columns: Iterable[np.ndarray]) -> np.ndarray:
        """:meth:`decimate` of several raw-rate columns, a bounded batch per filter pass.

        The filters run along each column alone, so the rows are bit-equal to one filter pass over
        all the stacked columns. A generator of columns is consumed ``BATCH_SAMPLES // n`` columns
        at a time (one for a log of 262,144 samples or more): a short log's columns share a few filter
        calls (their set-up dominates there), a long log's filter copies stay a bounded size.

        Parameters
        ----------
        raw_columns : iterable of ndarray, each shape (n,)
            Signals at the log's rate (any unit).

        Returns
        -------
        ndarray, shape (len(raw_columns), m)
            Row ``i`` equals ``decimate(raw_columns[i])``.
        """
        it, rows = iter(raw_columns), []
        for first in it:
            first = np.asarray(first, dtype=float)
            batch = [first, *itertools.islice(it, max(1, BATCH_SAMPLES // max(first.size, 1)) - 1)]
            X = np.array(batch, dtype=float) if len(batch) > 1 else first[None, :]
            del batch, first
            rows.extend(decimate_columns(lowpass(X, self.settings), self.settings, axis=1))
        return np.array(rows, dtype=float, ndmin=2)

    def stack(self, per_equation: Mapping[str, np.ndarray]) -> np.ndarray:
        """Stack per-equation columns in equation order, zeros where an equation is absent.

        Parameters
        ----------
        per_equation : Mapping[str, ndarray]
            Column values for some of the equations, each shape (m,).

        Returns
        -------
        ndarray, shape (m * len(equations),)
            The stacked column.
        """
        m = self.t.size
        return np.concatenate([per_equation.get(eq, np.zeros(m)) for eq in self.equations])

    def stacked_target(self) -> np.ndarray:
        """All nominal equation errors stacked, shape (m * len(equations),) [N m]."""
        return np.concatenate([self.targets[eq] for eq in self.equations])

    def stacked(self, mask: np.ndarray) -> np.ndarray:
        """Repeat a per-sample mask or index array for each equation."""
        return np.concatenate([mask] * len(self.equations))


def gap_log_scales(data: GapData) -> LogScales:
    """The log's magnitudes (cached on ``data``): plausibility ranges and the encoder's speed resolution.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    LogScales
        :func:`forecast_design.plausibility.log_scales` of the log's command, motor angle,
        spring deflection and filtered speed; ``speed_resolution`` [rad/s] is one encoder
        step per derivative-filter window.
    """
    if "scales" not in data.cache:
        exp = data.experiment
        sig = exp.signals
        theta = np.asarray(sig.theta, dtype=float)
        q = np.zeros_like(theta) if data.locked else np.asarray(sig.q, dtype=float)
        data.cache["scales"] = log_scales(torque=np.asarray(sig.tau_m, dtype=float), position=theta,
                                          rate_hz=exp.rate_hz, deflection=theta - q, velocity=data.raw["v"],
                                          J_m=exp.design.testbed.J_m,
                                          position_cutoff_hz=data.settings.position_cutoff_hz)
    return data.cache["scales"]


def command_rms(experiment: Experiment) -> float:
    """RMS of a log's motor command ``tau_m`` [N m]: the scale of torque-accuracy and resolution tests."""
    return float(np.sqrt(np.mean(np.square(np.asarray(experiment.signals.tau_m, dtype=float)))))


#: Default and lowest automatic decimated rate of the equation errors [Hz].
DEFAULT_DECIMATED_RATE_HZ, MIN_DECIMATED_RATE_HZ = 100.0, 10.0


def equation_band(experiment: Experiment, options: GapOptions) -> tuple[float, float | None]:
    """Decimated rate and position cut-off [Hz] of the equation errors.

    Quantisation of step ``s`` is white with variance ``s^2 / 12`` up to the Nyquist frequency;
    differentiated twice and kept up to ``f``, it puts ``J_m (s / sqrt 12) sqrt((2 pi)^4 f^5 /
    (5 rate / 2))`` [N m] RMS into the motor equation. The automatic band keeps that below
    ``quantization_noise_fraction`` of the RMS command: with the Forecast testbed's 2,000,000
    counts it stays at 100 Hz; a 4096-count encoder (1.5 mrad) lowers it to about 50 Hz for a
    command of 1 N m RMS on the testbed's J_m, where an effect of a few tenths of a newton metre
    rises above the differentiated quantisation again.

    Parameters
    ----------
    experiment : Experiment
        The log (motor angle, command, sample rate, nominal J_m).
    options : GapOptions
        ``decimated_rate_hz`` and ``position_cutoff_hz`` when given are kept as they are.

    Returns
    -------
    decimated_rate_hz : float
    position_cutoff_hz : float or None
        None for the filter's own default (``rate_hz / 10``).
    """
    if options.decimated_rate_hz is not None:
        return float(options.decimated_rate_hz), options.position_cutoff_hz
    rate = float(experiment.rate_hz)
    sig = experiment.signals
    step = encoder_step_of(sig.theta)
    tau_rms = command_rms(experiment)
    J_m = float(experiment.design.testbed.J_m)
    per_band = J_m * step / math.sqrt(12.0) * math.sqrt((2.0 * math.pi) ** 4 / (5.0 * rate / 2.0))
    if tau_rms <= 0.0 or per_band <= 0.0:
        return DEFAULT_DECIMATED_RATE_HZ, options.position_cutoff_hz
    f_band = (options.quantization_noise_fraction * tau_rms / per_band) ** 0.4     # noise = per_band f^2.5
    dec = min(DEFAULT_DECIMATED_RATE_HZ, max(MIN_DECIMATED_RATE_HZ, f_band / 0.4,
                                                 8.0 * options.n_blocks * rate / max(len(sig.t), 1)))
    if dec >= DEFAULT_DECIMATED_RATE_HZ:
        return DEFAULT_DECIMATED_RATE_HZ, options.position_cutoff_hz
    cutoff = options.position_cutoff_hz if options.position_cutoff_hz is not None else min(rate / 10.0, dec)
    return float(dec), cutoff


def prepare_gap_data(experiment: Experiment, options: GapOptions | None = None, *,
                     tau_s_source: TauSSource | None = None, creep: bool = False) -> GapData:
    """Filter, differentiate and decimate a log into nominal equation errors.

    Parameters
    ----------
    experiment : Experiment
        The measured or simulated log; its design is the nominal model.
    options : GapOptions, optional
        Settings; defaults to ``GapOptions()``.
    tau_s_source : TauSSource, optional
        The ``tau_s`` column's classification already made on this log (a repeat of the analysis with
        other settings); default: classified here (:func:`~forecast_design.tau_s_source.classify_tau_s`).
    creep : bool
        Read motion below the encoder's speed resolution as creeping where the recorded angle moves
        (:func:`.motion.creeping`); default: at rest.

    Returns
    -------
    GapData
        Decimated equation errors, signals and the fit/held-out split.

    Raises
    ------
    ParameterError
        If the log is too short for the filter, the decimation or the block split.
    IdentifiabilityError
        If the command is constant or the motor does not move.
    ExperimentFormatError
        If a signal is not finite.
    """
    options = GapOptions() if options is None else options
    if not isinstance(options, GapOptions):
        raise ParameterError(f"options must be a GapOptions, got {type(options).__name__}", name="options",
                             value=options)
    rate = experiment.rate_hz
    sig = experiment.signals
    dec_rate, cutoff = equation_band(experiment, options)
    R = max(1, int(round(rate / dec_rate)))
    settings = default_filter_settings(rate, position_cutoff_hz=cutoff, decimation_factor=R)
    tb, env = experiment.design.testbed, experiment.design.environment
    locked = env.locked
    theta = np.asarray(sig.theta, dtype=float)
    q = np.zeros_like(theta) if locked else np.asarray(sig.q, dtype=float)
    tau_m = np.asarray(sig.tau_m, dtype=float)
    tau_s = np.asarray(sig.tau_s, dtype=float)
    _check_log(experiment, theta, q, tau_m, tau_s, settings, options)
    # Every column, targets and regressors alike, goes through the same zero-phase
    # low-pass (and later the same decimation): a linear filter then leaves a model
    # that is linear in its parameters exact, so a nominal log has no residual.
    # One raw-rate column at a time, each dropped once decimated (the filters run along each
    # column alone, so the numbers are those of a stacked block): only the motor angle, its
    # speed and the spring deflection stay at the raw rate, for the candidates' nonlinear features.
    thf = lowpass(theta, settings)
    th_v, th_a = _derivatives(thf, rate)
    cols = {"a": decimate_columns(th_a, settings), "v": decimate_columns(th_v, settings),
            "theta": decimate_columns(thf, settings)}
    del th_a
    qf = lowpass(q, settings)
    x = thf - qf
    for name, col in zip(("qv", "qa"), _derivatives(qf, rate)):
        cols[name] = decimate_columns(col, settings)
    cols["q"] = decimate_columns(qf, settings)
    del qf, col
    cols["x"] = decimate_columns(x, settings)
    cols["spring"] = decimate_columns(tb.k * x, settings)
    cols["u"] = decimate_columns(lowpass(zoh_input(tau_m), settings), settings)
    cols["tau_s"] = decimate_columns(lowpass(tau_s, settings), settings)
    km_velocity, km_position = th_v, thf
    e = settings.edge_samples
    n_raw = theta.size
    t = np.asarray(sig.t, dtype=float)[e:n_raw - e][::R]
    # Positions and speeds for masks and operating-region statistics are taken at the
    # decimated instants without the extra anti-alias pass (which would smear sign changes).
    sub = slice(e, n_raw - e)
    cols["v_sub"] = km_velocity[sub][::R]
    cols["theta_sub"] = km_position[sub][::R]
    m = t.size
    if m < 4 * options.n_blocks:
        raise ParameterError(
            f"log too short for the gap diagnosis: {m} decimated samples for {options.n_blocks} blocks "
            f"(need >= {4 * options.n_blocks}); record a longer run",
            name="n_blocks", value=options.n_blocks)

    if tau_s_source is None:
        tau_s_source = classify_tau_s(sig.tau_s_derived, tau_s, theta, q)
    if options.tau_s_reading != "auto" and tau_s_source.source != "absent":
        # a reading forced by the caller (the diagnosis tries both when the decision is uncertain)
        tau_s_source = dataclasses.replace(tau_s_source, source=options.tau_s_reading)
    if not tau_s_source.measured:
        # a column the logger derived from the encoders carries nothing beyond k (theta - q):
        # use the encoders (the TOML's k) so that backlash and spring errors act where they
        # physically do, in the motor and environment equations
        cols["tau_s"] = cols["spring"]
    targets = {"motor": cols["u"] - cols["tau_s"] - tb.J_m * cols["a"] - tb.d_m * cols["v"]}
    equations = ["motor"]
    if not locked:
        targets["environment"] = cols["tau_s"] - (env.J * cols["qa"] + env.d * cols["qv"] + env.k_e * cols["q"])
        equations.append("environment")
    if tau_s_source.measured:
        targets["coupling"] = cols["tau_s"] - cols["spring"]
        equations.append("coupling")
    block = np.minimum((np.arange(m) * options.n_blocks) // m, options.n_blocks - 1)
    held_out = (block % 2) == 1
    stuck = np.abs(cols["v_sub"]) < options.stick_velocity
    raw = {"theta": thf, "v": th_v, "x": x, "tau_m": tau_m}
    return GapData(experiment=experiment, options=options, settings=settings, t=t, targets=targets,
                   columns=cols, raw=raw, block=block, held_out=held_out, stuck=stuck,
                   equations=tuple(equations), tau_s_source=tau_s_source, creep=bool(creep))
