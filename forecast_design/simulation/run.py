"""The virtual testbed: closed-loop (or open-loop) runs at the control rate, recorded as experiments.

One control period at sample ``n`` (time ``t_n = n / rate_hz``), as on the
embedded board and as the experiment format defines a row:

1. sample the encoders: ``theta_m = Q(theta(t_n))``, ``q_m = Q(q(t_n))``
   (round to the nearest of ``encoder_counts`` per revolution);
   ``tau_s_m = k (theta_m - q_m)`` with the *nominal* k;
2. the controller and compensator program (:mod:`forecast_design.program`, the one the C
   export and the firmware run): ``u[n]`` from ``tau_r[n]`` and ``tau_s_m`` by the
   controller's law, the estimate ``tau_hat[n]`` (friction feed-forward from ``theta_m``;
   observers from ``tau_m[n-1]``, ``tau_s_m``, ``theta_m``);
3. closed loop: ``tau_m[n] = sat(u[n] + tau_hat[n])``; open loop: ``tau_m[n] =
   sat(profile(t_n))`` (the estimate is computed and logged, not applied);
4. the true plant integrates over [t_n, t_n+1) with ``substeps`` RK4 steps,
   the command held (zero-order hold), modified by the effects (delay,
   torque gain) plus a process torque noise held per period.

The whole loop runs in one numba-compiled function (pure Python without
numba). The recorded experiment holds the nominal design only; the truth
(effects, true environment, true states and friction) is kept apart in
:class:`SimulationTruth` and written to sidecar files.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..effects import effects_to_mappings
from ..errors import ParameterError, SolverError
from ..experiment_io import csv_chunks
from ..discrete import check_kernel_cache, njit as _njit
from ..compensators import DEFAULT_VELOCITY_CUTOFF_HZ
from ..controllers import PAPER_PD
from ..params import Compensator, Design, Environment
from ..limits import SIGNAL_LIMITS, check_limit, check_physical, first_beyond
from ..program import ControllerProgram, build_program, program_step
from .plant import (I_BL, I_BLC, I_K, PlantModel, PlantStepper, TorqueSensor, advance_period, build_plant,
                    history_length, spring_torque, stability_check)

__all__ = [
    "ENCODER_COUNTS",
    "DEFAULT_PROCESS_NOISE_STD",
    "SimulationTruth",
    "SimulationResult",
    "simulate",
    "save_simulation",
    "plant_stepper",
    "process_noise",
]

#: Encoder resolution of the Forecast testbed (DHO-05) [counts/rev].
ENCODER_COUNTS = 2_000_000
#: Largest encoder jitter :func:`simulate` takes [counts] (beyond it the readings are noise, not an encoder).
MAX_ENCODER_JITTER_COUNTS = 100.0
#: Default process torque noise (std of a per-period held torque) [N m].
DEFAULT_PROCESS_NOISE_STD = 1e-3


# Columns of the kernel logs.
_MEAS = ("theta", "q", "tau_s", "tau_m", "u", "tau_frc_hat")
_TRUTH = ("theta", "omega", "q", "v", "z", "tau_frc", "tau_s", "tau_m_applied")


@_njit(inline="always")
def _sensors(theta, q, jt, jq, enc_step, k_nom, sensor, gain, reading, k_spring, bl, blc):
    """Step 1 of a period: the encoder readings ``theta_m``, ``q_m`` [rad] and ``tau_s_m`` [N m] at the true angles.

    ``jt``, ``jq`` are the encoders' jitter at this sample [rad], added before the quantiser. ``tau_s_m`` is derived from the encoders, ``k_nom (theta_m - q_m)``, or, with a torque ``sensor``, ``gain``
    times the true spring torque (``k_spring``, its backlash ``bl``, ``blc`` included) plus ``reading``, the
    sensor's zero and noise at this sample. Scalars only: numba reference-counts every array an inlined helper
    receives, which would cost more than the arithmetic.
    """
    th = theta
    qq = q
    if enc_step > 0.0:
        th = math.floor((theta + jt) / enc_step + 0.5) * enc_step
        qq = math.floor((q + jq) / enc_step + 0.5) * enc_step
    if sensor:
        return th, qq, gain * spring_torque(theta - q, k_spring, bl, blc) + reading
    return th, qq, k_nom * (th - qq)


@_njit(inline="always")
def _reading(sens, k):
    """The torque sensor's zero and noise at sample ``k`` [N m] (0 past its end: the code loop reads once more)."""
    return sens[k] if k < sens.shape[0] else 0.0


@_njit(inline="always")
def _jitter(jit, k, c):
    """The encoders' jitter at sample ``k`` on angle ``c`` (0: theta, 1: q) [rad]; 0 without jitter (shape (0, 2))
    or past its end (the code loop reads once more)."""
    return jit[k, c] if k < jit.shape[0] else 0.0


@_njit
def _loop(n, nsub, dsub, p, harm, x, closed, ref, ol, torque_limit, enc_step, jit, noise, k_nom, sens, sens_gain,
          sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem, meas, truth, hist):
    out = np.zeros(2)
    H = hist.shape[0]
    sensor = sens.shape[0] > 0
    k_spring, bl, blc = p[I_K], p[I_BL], p[I_BLC]
    for k in range(n):
        th, qq, tau_s = _sensors(x[0], x[2], _jitter(jit, k, 0), _jitter(jit, k, 1), enc_step, k_nom, sensor,
                                 sens_gain, sens[k] if sensor else 0.0, k_spring, bl, blc)
        if closed:
            cmd = program_step(sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem, ref[k], tau_s, th)
            u = mem[3]
        else:
            # open loop: the program has no controller channels; its estimate is logged, not applied
            program_step(sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem, 0.0, tau_s, th)
            u = 0.0
            cmd = ol[k]
            if cmd > torque_limit:
                cmd = torque_limit
            elif cmd < -torque_limit:
                cmd = -torque_limit
            mem[2] = cmd          # the observers' G_m sees the command that was applied
        meas[k, 0] = th
        meas[k, 1] = qq
        meas[k, 2] = tau_s
        meas[k, 3] = cmd
        meas[k, 4] = u
        meas[k, 5] = mem[4]
        hist[k % H] = cmd
        advance_period(x, k, nsub, dsub, hist, p, harm, noise[k], out, truth[k])


@_njit
def _code_period(k, th, qq, tau_s, u, tau_r, stopped, nsub, dsub, p, harm, x, enc_step, jit, noise, k_nom, sens,
                 sens_gain,
                 sos, meta, gains, flags, par, ff_coef, ff_harm, state, mem, meas, truth, hist, out):
    """Period ``k`` of ``_loop`` for a controller written as code (:mod:`.code`), which gave ``u`` [N m].

    ``th``, ``qq``, ``tau_s`` are the period's encoder readings (the previous call's return) and
    ``tau_r`` its reference [N m]. The program (the compensator, saturation and command) runs in its
    arrays' dtype (float32 for C, as on the board); with ``stopped`` (after a controller fault) the
    command is zero and the program does not run. Logs the period, steps the plant and returns the
    encoder readings of period ``k + 1``: ``(theta_m, q_m, tau_s_m)``.
    """
    f = mem.dtype.type
    cmd = 0.0
    uu = 0.0
    hat = 0.0
    if not stopped:
        if flags[6] != 0:
            mem[3] = f(u)
        cmd = program_step(sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem,
                           f(tau_r), f(tau_s), f(th))
        uu = mem[3]
        hat = mem[4]
    meas[k, 0] = th
    meas[k, 1] = qq
    meas[k, 2] = tau_s
    meas[k, 3] = cmd
    meas[k, 4] = uu
    meas[k, 5] = hat
    hist[k % hist.shape[0]] = cmd
    advance_period(x, k, nsub, dsub, hist, p, harm, noise[k] if k < noise.shape[0] else 0.0, out, truth[k])
    return _sensors(x[0], x[2], _jitter(jit, k + 1, 0), _jitter(jit, k + 1, 1), enc_step, k_nom, sens.shape[0] > 0,
                    sens_gain, _reading(sens, k + 1), p[I_K], p[I_BL], p[I_BLC])


def _kernel_dependencies() -> list:
    """The modules ``_loop``, ``_code_period`` and the batch kernels inline or call (their cache keys)."""
    import importlib

    root = __package__.rsplit('.', 1)[0]
    return [importlib.import_module(f"{root}.discrete.filters"), importlib.import_module(f"{root}.friction.laws"),
            importlib.import_module(f"{__package__}.plant"), importlib.import_module(f"{root}.program"),
            importlib.import_module(f"{root}.compensators.feedforward"), importlib.import_module(__name__)]


def process_noise(seed: int, std: float, n: int) -> np.ndarray:
    """The simulator's process torque noise: one held value per period [N m], shape (n,)."""
    return np.random.default_rng(seed).normal(0.0, std, n) if std > 0 else np.zeros(n)


def sensor_noise(seed: int, sensor: TorqueSensor | None, n: int) -> np.ndarray:
    """A torque sensor's zero plus its white noise, one value per sample [N m], shape (n,); shape (0,) without a
    sensor (``tau_s`` derived from the encoders). Drawn from its own stream: the process noise is the same either
    way."""
    if sensor is None:
        return np.zeros(0)
    noise = (np.random.default_rng([seed, 0x5E45]).normal(0.0, sensor.noise_std_N_m, n) if sensor.noise_std_N_m > 0
             else np.zeros(n))
    return noise + sensor.offset_N_m


def encoder_jitter(seed: int, jitter_counts: float, enc_step: float, n: int) -> np.ndarray:
    """The encoders' jitter: a white noise on theta and q before the quantiser [rad], shape (n, 2); shape (0, 2)
    without jitter. Drawn from its own stream: the process and sensor noises are the same either way."""
    if not jitter_counts > 0.0:
        return np.zeros((0, 2))
    return np.random.default_rng([seed, 0xE7C0]).standard_normal((n, 2)) * (jitter_counts * enc_step)


def plant_stepper(design: Design, effects: Sequence[Any] = (), *, n: int, rate_hz: float = 2000.0,
                    substeps: int = 10, seed: int = 0, process_noise_std: float = DEFAULT_PROCESS_NOISE_STD,
                    encoder_counts: int | None = ENCODER_COUNTS, initial_angle: float = 0.0,
                    include_nominal_viscous: bool = True) -> PlantStepper:
    """The virtual testbed of :func:`simulate` as a period-by-period stepper (for the board emulator).

    Parameters
    ----------
    design : Design
        Nominal design (its testbed's ``k`` derives ``tau_s``).
    effects : sequence of effect parameter values
        Unmodelled effects of the true hardware.
    n : int
        Periods the process noise is drawn for (the same draws as ``simulate`` with this seed) [-].
    rate_hz : float
        Control rate [Hz].
    substeps : int
        RK4 substeps per period [-].
    seed : int
        Seed of the process noise.
    process_noise_std : float
        Process torque noise [N m].
    encoder_counts : int or None
        Encoder resolution [counts/rev]; None or 0 for exact positions.
    initial_angle : float
        Absolute motor angle at ``theta = 0`` [rad].
    include_nominal_viscous : bool
        The nominal ``d_m theta'`` is part of the true friction (a scenario's ``[truth]`` key).

    Returns
    -------
    PlantStepper
        Driven by the commands of a :func:`simulate` run with the same arguments, it reproduces
        that run's measurements and truth exactly.
    """
    plant = build_plant(design, effects, rate_hz=rate_hz, substeps=substeps, initial_angle=initial_angle,
                        include_nominal_viscous=include_nominal_viscous)
    stability_check(plant)
    return PlantStepper(plant, substeps=substeps, k_nominal=design.testbed.k,
                        encoder_step=2.0 * math.pi / encoder_counts if encoder_counts else 0.0,
                        noise=process_noise(seed, process_noise_std, n))


@dataclass(frozen=True, slots=True)
class SimulationTruth:
    """What the simulated hardware really did (never part of the experiment's TOML).

    All arrays have shape (n,) and hold values at the sample times t_n.
    """

    effects: tuple                   # effect parameter values that were simulated
    environment: Environment         # the true environment
    initial_angle: float             # absolute motor angle at theta = 0 [rad]
    include_nominal_viscous: bool    # d_m omega part of tau_frc
    theta: np.ndarray                # motor angle [rad]
    omega: np.ndarray                # motor velocity [rad/s]
    q: np.ndarray                    # environment angle [rad]
    v: np.ndarray                    # environment velocity [rad/s]
    z: np.ndarray                    # LuGre bristle deflection [rad]
    tau_frc: np.ndarray              # total friction (+ cogging) torque at the motor [N m]
    tau_s: np.ndarray                # true spring torque (with backlash) [N m]
    tau_m_applied: np.ndarray        # torque acting on the motor (delay, gain, noise) [N m]

    def columns(self) -> dict[str, np.ndarray]:
        """The truth signals by name (sidecar CSV columns, without ``t``)."""
        return {name: getattr(self, name) for name in _TRUTH}

    def metadata(self) -> dict[str, Any]:
        """Effects, true environment and flags (for the sidecar JSON)."""
        return {"effects": effects_to_mappings(self.effects), "environment": self.environment.to_mapping(),
                "initial_angle": self.initial_angle, "include_nominal_viscous": self.include_nominal_viscous}


@dataclass(frozen=True, slots=True)
class SimulationResult:
    """One simulated run: the measured signals (experiment format) and the truth.

    Attributes
    ----------
    design : Design
        Nominal design, with the controller/compensator that ran (open loop: none).
    rate_hz : float
        Control rate [Hz].
    t : ndarray, shape (n,)
        Sample times [s].
    tau_m : ndarray
        Applied command (after saturation) [N m].
    theta, q : ndarray
        Encoder readings [rad].
    tau_s : ndarray
        Measured spring torque k (theta - q) [N m].
    tau_r : ndarray or None
        Force reference (closed loop) [N m].
    u : ndarray
        Force-controller output [N m] (zeros in open loop).
    tau_frc_hat : ndarray
        Compensator friction estimate [N m] (zeros without compensator).
    truth : SimulationTruth
        The hidden truth.
    options : dict
        The simulation options (substeps, seed, noise, ...), for provenance.
    stability : dict
        :func:`~forecast_design.simulation.plant.stability_check` of the step.
    description : str
        Free text.
    fault : dict or None
        A controller written as code that failed (raised, returned NaN or infinity, or did not
        return in time): ``period``, ``t_s`` [s] and ``reason``; the command is zero from that
        period on, as the firmware's safe stop. None otherwise.
    """

    design: Design
    rate_hz: float
    t: np.ndarray
    tau_m: np.ndarray
    theta: np.ndarray
    q: np.ndarray
    tau_s: np.ndarray
    tau_r: np.ndarray | None
    u: np.ndarray
    tau_frc_hat: np.ndarray
    truth: SimulationTruth
    options: Mapping[str, Any] = field(default_factory=dict)
    stability: Mapping[str, float] = field(default_factory=dict)
    description: str = ""
    fault: Mapping[str, Any] | None = None

    @property
    def diverged_at_s(self) -> float | None:
        """Time [s] at which the run left every physical range (|theta| or |q| > 1e6 rad, |tau_m| or
        |tau_s| > 1e6 N m, or not finite: an unstable closed loop), or None."""
        hits = [first_beyond(getattr(self, name), SIGNAL_LIMITS[kind])
                for name, kind in (("theta", "angle_rad"), ("q", "angle_rad"), ("tau_m", "torque_N_m"),
                                   ("tau_s", "torque_N_m"))]
        hits = [h for h in hits if h is not None]
        return float(self.t[min(hits)]) if hits else None

    def to_experiment(self):
        """The measured run as an :class:`~forecast_design.experiment.Experiment` (extra columns u, tau_frc_hat).

        Raises
        ------
        SolverError
            If the run diverged (:attr:`diverged_at_s`): no log of it is a measurement.
        """
        from ..experiment import experiment_from_arrays

        at = self.diverged_at_s
        if at is not None:
            comp = self.design.compensator
            check = ("the SFM feed-forward's velocity feedback is checked by forecast_design.analysis.sfm_loop_check "
                     "(margins does not take friction)" if comp is not None and comp.kind == "sfm"
                     else "check it with `forecast-design margins`")
            raise SolverError(f"the simulation diverged at t = {at:.4g} s (|theta| > 1e6 rad or |tau| > 1e6 N m): "
                              f"the closed loop is unstable on this plant; {check}")

        description = self.description
        if self.fault is not None:
            description = (f"{description} " if description else "") + (
                f"[controller fault at t = {self.fault['t_s']:.6g} s: {self.fault['reason']}; zero torque from then on]")
        return experiment_from_arrays(self.design, self.rate_hz, self.t, self.tau_m, self.theta, self.q,
                                      tau_s=self.tau_s, tau_r=self.tau_r,
                                      extra={"u": self.u, "tau_frc_hat": self.tau_frc_hat},
                                      description=description)

    def to_mapping(self) -> dict[str, Any]:
        """Summary for JSON: options, truth metadata, stability and a few scalar statistics."""
        stats = {
            "n_samples": int(self.t.shape[0]),
            "duration_s": float(self.t.shape[0] / self.rate_hz),
            "max_abs_tau_m_N_m": float(np.max(np.abs(self.tau_m))) if self.t.size else 0.0,
            "mae_friction_estimate_N_m": float(np.mean(np.abs(self.tau_frc_hat - self.truth.tau_frc))),
        }
        if self.tau_r is not None:
            stats["mae_tracking_N_m"] = float(np.mean(np.abs(self.tau_r - self.tau_s)))
        return {"design": self.design.to_mapping(), "rate_hz": self.rate_hz, "options": dict(self.options),
                "truth": self.truth.metadata(), "stability": dict(self.stability), "statistics": stats,
                "controller_fault": None if self.fault is None else dict(self.fault),
                "description": self.description}


def _reference_samples(reference: Any, n: int, rate_hz: float, what: str) -> np.ndarray:
    t = np.arange(n) / rate_hz
    if callable(reference):
        values = np.asarray(reference(t), dtype=float)
        if values.shape == ():
            values = np.full(n, float(values))
    else:
        values = np.asarray(reference, dtype=float)
    if values.shape != (n,):
        raise ParameterError(f"{what} must give {n} samples (duration_s * rate_hz), got shape {values.shape}",
                             name=what, value=values.shape)
    if not np.all(np.isfinite(values)):
        raise ParameterError(f"{what} has non-finite values", name=what, value=None)
    return np.ascontiguousarray(values)


def simulate(design: Design, *, reference: Callable[[np.ndarray], np.ndarray] | Sequence[float] | np.ndarray,
             duration_s: float, effects: Sequence[Any] = (), rate_hz: float = 2000.0, substeps: int = 10,
             seed: int = 0, closed_loop: bool = True, sfm_params: Mapping[str, float] | None = None,
             velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, sfm_deadband: float = 0.0,
             torque_limit: float = math.inf, encoder_counts: int | None = ENCODER_COUNTS,
             process_noise_std: float = DEFAULT_PROCESS_NOISE_STD, initial_angle: float = 0.0,
             include_nominal_viscous: bool = True, description: str = "",
             step_timeout_s: float | None = None,
             torque_sensor: TorqueSensor | None = None, encoder_jitter_counts: float = 0.0) -> SimulationResult:
    """Simulate the testbed: force control (+ compensator) or an open-loop torque profile.

    Parameters
    ----------
    design : Design
        Nominal testbed and environment; ``controller`` (default: the
        paper's PD, :data:`~forecast_design.controllers.PAPER_PD`) and ``compensator``
        (default none) are used in closed loop. The controller runs its own
        :meth:`~forecast_design.controllers.Controller.discrete_law` (its discretisation,
        derivative filter and placement, saturation); observers are built on this nominal
        design and discretised with Tustin.
    reference : callable or array_like
        Closed loop: force reference tau_r(t) [N m]; open loop: torque
        command profile tau_m(t) [N m]. A callable of the sample times
        [s] (e.g. :mod:`.references`) or an array of ``n`` samples.
    duration_s : float
        Run length [s]; ``n = round(duration_s * rate_hz)`` samples.
    effects : sequence of effect parameter values
        Unmodelled effects of the true hardware (:mod:`forecast_design.effects`).
    rate_hz : float
        Control/sampling rate [Hz].
    substeps : int
        RK4 steps per control period [-] (>= 1; 10 by default).
    seed : int
        Seed of ``np.random.default_rng`` for the process noise.
    closed_loop : bool
        Force control (True) or open-loop torque (False).
    sfm_params : Mapping[str, float], optional
        Kept for one release: prefer ``Compensator(kind="sfm", friction=...)``. When given,
        replaces the compensator's own ``friction`` (:meth:`Design.with_friction`): ``viscous`` [N m s/rad],
        ``coulomb`` [N m], optional ``offset``, ``sin<i>``, ``cos<i>``,
        ``coulomb_sin<i>``, ``coulomb_cos<i>`` [N m].
    velocity_cutoff_hz : float
        SFM velocity filter [Hz].
    sfm_deadband : float
        SFM sign() dead band [rad/s].
    torque_limit : float
        Motor torque saturation |tau_m| <= torque_limit [N m].
    encoder_counts : int or None
        Encoder counts per revolution on theta and q; ``None`` or 0: exact.
    encoder_jitter_counts : float
        Standard deviation of a white noise added to both angles before the encoders' quantiser
        [counts] (default 0): an encoder whose reading toggles between two counts where the motion
        dwells near an edge. In closed loop the controller reads it (a derived ``tau_s`` carries it).
        Needs ``encoder_counts``; drawn from the seed's own stream. A locked output's ``q`` reads zero.
    process_noise_std : float
        Std of a motor torque noise held per period [N m].
    torque_sensor : TorqueSensor, optional
        A torque sensor in the spring: ``tau_s`` (fed back and logged) is its reading of the true
        spring torque (its backlash included): its gain, zero and white noise (drawn from the
        seed's own stream). None (default): ``tau_s`` derived from the encoders, ``k (theta - q)``.
    initial_angle : float
        Absolute motor angle at theta = 0 for angle-dependent effects and
        the SFM harmonics [rad] (the controller's encoder is homed).
    include_nominal_viscous : bool
        Keep ``d_m omega`` in the true plant (False: friction = effects only).
    description : str
        Free text for the experiment.
    step_timeout_s : float, optional
        A controller written as code (:mod:`.code`): longest one step may take before the run
        stops with a fault [s] (default :data:`.code.DEFAULT_STEP_TIMEOUT_S`).

    Returns
    -------
    SimulationResult
        Measured signals and the truth; a code controller that failed stops safely (zero torque
        from then on) and :attr:`SimulationResult.fault` says where and why.

    Raises
    ------
    ParameterError
        Invalid options, missing ``sfm_params``, a controller without equations (``other``),
        or an RK4 step outside the stability region of the plant.

    Examples
    --------
    >>> from forecast_design.simulation.references import Step
    >>> r = simulate(Design.nominal("locked"), reference=Step(amplitude=0.2), duration_s=0.05)
    >>> r.t.shape
    (100,)
    """
    prep = _prepare(design, reference=reference, duration_s=duration_s, effects=effects, rate_hz=rate_hz,
                    substeps=substeps, seed=seed, closed_loop=closed_loop, sfm_params=sfm_params,
                    velocity_cutoff_hz=velocity_cutoff_hz,
                    sfm_deadband=sfm_deadband, torque_limit=torque_limit, encoder_counts=encoder_counts,
                    process_noise_std=process_noise_std, initial_angle=initial_angle,
                    include_nominal_viscous=include_nominal_viscous,
                    description=description, step_timeout_s=step_timeout_s,
                    torque_sensor=torque_sensor, encoder_jitter_counts=encoder_jitter_counts)
    meas = np.empty((prep.n, len(_MEAS)))
    truth = np.empty((prep.n, len(_TRUTH)))
    if prep.is_code:
        return prep.result(meas, truth, run_code(prep, meas, truth))
    _check_kernel_cache(_loop)
    _loop(*prep.kernel_args(meas, truth))
    return prep.result(meas, truth)


def run_code(prep: "_Prepared", meas: np.ndarray, truth: np.ndarray) -> dict[str, Any] | None:
    """One prepared run whose controller is code (:mod:`.code`): its period loop; the fault or None."""
    from .code import code_runner, run_code_loop

    return run_code_loop(prep, code_runner(prep.ran.controller), meas, truth, step_timeout_s=prep.step_timeout_s)


def _check_kernel_cache(kernel) -> None:
    """Flush a stale on-disk cache of ``kernel`` once per process (:func:`~forecast_design.discrete.check_kernel_cache`)."""
    check_kernel_cache(kernel, _kernel_dependencies())


@dataclass(frozen=True, slots=True)
class _Prepared:
    """One run of :func:`simulate`, validated and packed for the kernel ``_loop`` (and the batch kernel).

    ``arrays`` holds the kernel's per-run inputs by name (writable, C-contiguous float64, so every
    call has one numba signature); :meth:`kernel_args` orders them for ``_loop`` and
    :meth:`result` turns the kernel's logs into a :class:`SimulationResult`.
    """

    n: int
    substeps: int
    plant: PlantModel
    stability: Mapping[str, float]
    closed_loop: bool
    ref: np.ndarray
    torque_limit: float
    enc_step: float
    k_nominal: float
    program: ControllerProgram
    arrays: Mapping[str, np.ndarray]
    ran: Design
    options: Mapping[str, Any]
    effects: tuple
    initial_angle: float
    include_nominal_viscous: bool
    rate_hz: float
    description: str
    step_timeout_s: float = math.inf
    sensor_gain: float = 1.0          # the torque sensor's gain (with no sensor: unused) [-]

    @property
    def is_code(self) -> bool:
        """True when the controller is code (its output comes from :mod:`.code`, not the kernel)."""
        return bool(self.program.external)

    def kernel_args(self, meas: np.ndarray, truth: np.ndarray) -> tuple:
        """Arguments of ``_loop`` writing into ``meas`` (n, 6) and ``truth`` (n, 8)."""
        a = self.arrays

        sos, meta, gains, flags, par, ff_coef, ff_harm = self.program_arrays()
        state, mem = self.program.pack().new_state()
        return (self.n, self.substeps, int(self.plant.delay_substeps), a["p"], a["harm"], np.zeros(5),
                self.closed_loop, a["ref"], a["ol"], self.torque_limit, self.enc_step, a["jit"], a["noise"],
                self.k_nominal,
                a["sens"], self.sensor_gain, sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem, meas, truth,
                np.zeros(history_length(self.substeps, self.plant.delay_substeps)))

    def program_arrays(self) -> tuple[np.ndarray, ...]:
        """The program's packed arrays as the kernel takes them (writable float64 copies: one numba signature)."""
        return tuple(np.array(arr, order="C") for arr in self.program.pack().arrays())

    def result(self, meas: np.ndarray, truth: np.ndarray, fault: Mapping[str, Any] | None = None) -> SimulationResult:
        """The run's :class:`SimulationResult` from the kernel's logs (columns copied, read-only)."""
        n, ref, closed_loop = self.n, self.ref, self.closed_loop
        cols = {name: np.ascontiguousarray(meas[:, i]) for i, name in enumerate(_MEAS)}
        tr = {name: np.ascontiguousarray(truth[:, i]) for i, name in enumerate(_TRUTH)}
        for arr in list(cols.values()) + list(tr.values()):
            arr.flags.writeable = False
        t = np.arange(n) / float(self.rate_hz)
        t.flags.writeable = False
        if closed_loop:
            ref = ref.copy()
            ref.flags.writeable = False
        return SimulationResult(
            design=self.ran, rate_hz=float(self.rate_hz), t=t, tau_m=cols["tau_m"], theta=cols["theta"], q=cols["q"],
            tau_s=cols["tau_s"], tau_r=ref if closed_loop else None, u=cols["u"], tau_frc_hat=cols["tau_frc_hat"],
            truth=SimulationTruth(effects=tuple(self.effects), environment=self.plant.environment,
                                  initial_angle=float(self.initial_angle),
                                  include_nominal_viscous=self.include_nominal_viscous, **tr),
            options=dict(self.options), stability=self.stability, description=self.description,
            fault=None if fault is None else dict(fault),
        )


def _prepare(design: Design, *, reference: Any, duration_s: float, effects: Sequence[Any] = (),
             rate_hz: float = 2000.0, substeps: int = 10, seed: int = 0, closed_loop: bool = True,
             sfm_params: Mapping[str, float] | None = None,
             velocity_cutoff_hz: float = DEFAULT_VELOCITY_CUTOFF_HZ, sfm_deadband: float = 0.0,
             torque_limit: float = math.inf, encoder_counts: int | None = ENCODER_COUNTS,
             process_noise_std: float = DEFAULT_PROCESS_NOISE_STD, initial_angle: float = 0.0,
             include_nominal_viscous: bool = True, description: str = "",
             step_timeout_s: float | None = None, torque_sensor: TorqueSensor | None = None,
             encoder_jitter_counts: float = 0.0) -> _Prepared:
    """Validate :func:`simulate`'s arguments and pack one run for the kernel (no simulation)."""
    if not isinstance(design, Design):
        raise ParameterError(f"simulate needs a Design (e.g. Design.nominal('exp-soft')), got {type(design).__name__}",
                             name="design", value=design)
    if not (isinstance(duration_s, (int, float)) and duration_s > 0 and math.isfinite(duration_s)):
        raise ParameterError(f"duration_s must be > 0 [s], got {duration_s!r}", name="duration_s", value=duration_s)
    if not (isinstance(rate_hz, (int, float, np.floating)) and math.isfinite(rate_hz)):
        raise ParameterError(f"rate_hz must be a finite number [Hz], got {rate_hz!r}", name="rate_hz", value=rate_hz)
    check_physical("simulate", "rate_hz", float(rate_hz))
    if not (torque_limit > 0):
        raise ParameterError(f"torque_limit must be > 0 [N m], got {torque_limit!r}", name="torque_limit",
                             value=torque_limit)
    if step_timeout_s is None:
        from .code import DEFAULT_STEP_TIMEOUT_S

        step_timeout_s = DEFAULT_STEP_TIMEOUT_S
    if not (isinstance(step_timeout_s, (int, float)) and step_timeout_s > 0 and math.isfinite(step_timeout_s)):
        raise ParameterError(f"step_timeout_s must be > 0 [s], got {step_timeout_s!r}", name="step_timeout_s",
                             value=step_timeout_s)
    if not (process_noise_std >= 0 and math.isfinite(process_noise_std)):
        raise ParameterError(f"process_noise_std must be >= 0 [N m], got {process_noise_std!r}",
                             name="process_noise_std", value=process_noise_std)
    if torque_sensor is not None and not isinstance(torque_sensor, TorqueSensor):
        raise ParameterError(f"torque_sensor must be a TorqueSensor or None, got {type(torque_sensor).__name__}",
                             name="torque_sensor", value=torque_sensor)
    if encoder_counts is not None and (isinstance(encoder_counts, bool) or not isinstance(encoder_counts, int)
                                       or encoder_counts < 0):
        raise ParameterError(f"encoder_counts must be an integer >= 0 [counts/rev], got {encoder_counts!r}",
                             name="encoder_counts", value=encoder_counts)
    if not (isinstance(encoder_jitter_counts, (int, float, np.floating)) and not isinstance(encoder_jitter_counts, bool)
            and 0.0 <= encoder_jitter_counts <= MAX_ENCODER_JITTER_COUNTS):
        raise ParameterError(f"encoder_jitter_counts must be in [0, {MAX_ENCODER_JITTER_COUNTS:g}] [counts], got "
                             f"{encoder_jitter_counts!r}", name="encoder_jitter_counts", value=encoder_jitter_counts)
    if encoder_jitter_counts > 0 and not encoder_counts:
        raise ParameterError("encoder_jitter_counts needs encoder_counts (a jitter before the quantiser of exact "
                             "angles has no count)", name="encoder_jitter_counts", value=encoder_jitter_counts)
    plant: PlantModel = build_plant(design, effects, rate_hz=rate_hz, substeps=substeps,
                                    initial_angle=initial_angle, include_nominal_viscous=include_nominal_viscous)
    stability = stability_check(plant)
    n = int(round(duration_s * rate_hz))
    if n < 1:
        raise ParameterError(f"duration_s * rate_hz must give at least one sample, got {duration_s!r}",
                             name="duration_s", value=duration_s)
    check_limit(f"duration_s x rate_hz = {duration_s * rate_hz:.3g} samples", "simulation_samples", n)
    values = _reference_samples(reference, n, rate_hz, "reference")
    ref = values if closed_loop else np.zeros(n)
    ol = np.zeros(n) if closed_loop else values

    design = design.with_friction(sfm_params)   # the compensator carries its identified friction
    controller = (design.controller or PAPER_PD) if closed_loop else None
    comp = design.compensator if design.compensator is not None else Compensator(kind="none")
    # open loop: the program runs the compensator alone (its estimate is logged, not applied)
    program = build_program(dataclasses.replace(design, controller=controller or PAPER_PD, compensator=comp),
                            rate_hz=rate_hz, tau_max=torque_limit, velocity_cutoff_hz=velocity_cutoff_hz,
                            deadband=sfm_deadband, angle_offset=initial_angle)
    if not closed_loop:
        program = dataclasses.replace(program, channels=tuple(ch for ch in program.channels if ch.group == "hat"),
                                      integrator=None)

    noise = process_noise(seed, process_noise_std, n)
    enc_step = 2.0 * math.pi / encoder_counts if encoder_counts else 0.0

    def rw(a):
        # one numba signature for every call: writable, C-contiguous float64 copies
        return np.array(a, dtype=float, order="C")

    ran = dataclasses.replace(design, controller=controller,
                              compensator=(design.compensator if closed_loop else None))
    options = {
        "duration_s": float(duration_s), "substeps": int(substeps), "seed": int(seed),
        "closed_loop": bool(closed_loop), "controller": None if controller is None else controller.spelling(),
        "velocity_cutoff_hz": float(velocity_cutoff_hz), "sfm_deadband": float(sfm_deadband),
        "torque_limit": float(torque_limit), "encoder_counts": int(encoder_counts or 0),
        "encoder_jitter_counts": float(encoder_jitter_counts),
        "process_noise_std": float(process_noise_std),
        "torque_sensor": None if torque_sensor is None else torque_sensor.to_mapping(),
        "sfm_params": comp.friction_params,
        "compensator": comp.kind, "w_q_hz": comp.w_q_hz if comp.is_observer else None,
        "q_family": comp.q_family if comp.is_observer else None,
        "q_order": comp.q_order if comp.is_observer else None,
        "delay_substeps": int(plant.delay_substeps),
    }
    arrays = {"p": rw(plant.params), "harm": rw(plant.harmonics), "ref": rw(ref), "ol": ol, "noise": noise,
              "sens": sensor_noise(seed, torque_sensor, n),
              "jit": encoder_jitter(seed, float(encoder_jitter_counts), enc_step, n)}
    if design.environment.locked:
        arrays["jit"][:, 1] = 0.0       # a locked output reads zero (the format asks q == 0), jitter or not
    return _Prepared(n=n, substeps=int(substeps), plant=plant, stability=stability, closed_loop=bool(closed_loop),
                     ref=ref, torque_limit=float(torque_limit), enc_step=float(enc_step),
                     k_nominal=float(design.testbed.k), program=program, arrays=arrays, ran=ran,
                     options=options, effects=tuple(effects), initial_angle=float(initial_angle),
                     include_nominal_viscous=include_nominal_viscous, rate_hz=float(rate_hz),
                     description=description, step_timeout_s=float(step_timeout_s),
                     sensor_gain=1.0 if torque_sensor is None else float(torque_sensor.gain))


def save_simulation(result: SimulationResult, path: str | os.PathLike[str]) -> dict[str, Path]:
    """Write a simulated run: the experiment (TOML + CSV) and the truth sidecars.

    Parameters
    ----------
    result : SimulationResult
        The run.
    path : str or os.PathLike
        The experiment TOML path, e.g. ``RUN.toml``.

    Returns
    -------
    dict of str to pathlib.Path
        ``experiment`` (RUN.toml), ``data`` (RUN.csv), ``truth`` (RUN.truth.json:
        effects, true environment, options, stability) and ``truth_data``
        (RUN.truth.csv: t and the true signals, ``%.17g``).

    Notes
    -----
    The TOML holds the nominal model only, as the format requires; a
    diagnosis tool reading RUN.toml never sees the truth. The four files are written
    as one set (:func:`forecast_design.fileio.atomic_write_set`): all are complete on
    disk before any replaces an old one, the TOML last.
    """
    from ..experiment import save_experiment

    toml_path = Path(path)
    stem = toml_path.with_suffix("")
    truth_json = stem.with_name(stem.name + ".truth.json")
    truth_csv = stem.with_name(stem.name + ".truth.csv")
    cols = {"t": result.t, **result.truth.columns()}
    meta = {"format": "forecast-simulation-truth/1", "experiment": toml_path.name, "data": truth_csv.name,
            **result.to_mapping()}
    # One set: the truth files first, then the experiment's CSV and TOML (see fileio).
    save_experiment(result.to_experiment(), toml_path, sidecars={
        truth_csv: csv_chunks(cols), truth_json: json.dumps(meta, indent=2, allow_nan=True) + "\n"})
    return {"experiment": toml_path, "data": toml_path.with_suffix(".csv"), "truth": truth_json,
            "truth_data": truth_csv}
