"""Replicas of a log's measurement chain: would the nominal model alone show this effect?

Some small effects are the sensors' answer, not the hardware's. In a closed loop the controller feeds
the sensors' noise back into the motor torque: a torque sensor's noise, or the encoders'
quantisation of a derived ``tau_s``, then moves the motor in step with the noise that is also in the
equation errors, and a small friction level fitted on the filtered signals explains part of it (an
effect-free 2^21-count square with a torque sensor: a Coulomb level of 0.5 mN m removing 35 % of the
gap above the floor, held-out p = 3e-10, the weak verdict). A torque sensor's scale, re-calibrated
next to a spring whose k may move only within its datasheet tolerance, leaves a torque gain on a
16-bit log (an effect-free closed-loop square: a gain of 0.966 removing all of the gap above the
floor, 3 % of the total, a clear verdict). That part grows with the noise and the sensor's
errors, not with any effect, so no held-out test on the log itself can tell it from one.

A parametric bootstrap can: the nominal model (the log's design with its re-calibrated ``J_m`` and
``d_m``; with a torque sensor, the re-calibrated ``k`` and the sensor's scale and zero) is
simulated with the log's own measurement chain (the encoders' step read from the log; a torque
sensor's white noise read from ``tau_s``), effect-free, ``n`` times with other noise draws: in
closed loop under the log's controller, compensator and force reference, open loop under its
logged command. The candidate is fitted on each replica as on the log; the torque it explains on
the log must be :data:`REPLICA_MARGIN` times the most it explains on a replica. What it explains
there is the measurement chain's.

What the replicas leave out (a logger's printing of ``tau_m``, encoders' jitter, process noise, a
torque limit) narrows their spread, which the margin covers.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..effects import Effect
from ..errors import ForecastError
from .candidates import CandidateFit, fit_baseline, fit_candidate
from .grading import noise_floor, own_reduction
from .residuals import GapData, prepare_gap_data

__all__ = ["ReplicaCheck", "closed_loop", "replica_check", "sensor_noise_std"]

#: Replicas simulated per check [-].
N_REPLICAS = 19
#: How many times the torque the chain alone explains a candidate must explain on the log [-]: the replicas
#: leave out part of the log's noise (a logger's printing, encoders' jitter, process noise; without a sensor they
#: are all one), which the margin covers. On 94 logs of twenty-one seeds the false alarms and wrong verdicts the
#: replicas reproduce stood at 0.30-1.06 times the replicas' torque, the true effects at 1.58 and above.
REPLICA_MARGIN = 1.5


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplicaCheck:
    """A candidate on the log against the same candidate on effect-free replicas of its measurement chain.

    The statistic is the torque the candidate explains on the held-out rows of its own equations
    (RMS, beyond the calibrated nominal model): what the chain alone makes it explain is the
    replicas'. Not the share of the gap it removes: that compares against residuals the replicas do
    not reproduce (an open-loop 16-bit log with a sensor reading 6 % low: a gain explaining
    5.7 mN m there, 48 % of the gap above the floor, and 6.1 mN m on its replicas, 24 %).

    Parameters
    ----------
    effect : Effect
        The candidate.
    observed_N_m : float
        Torque it explains on the log [N m].
    replicas_N_m : tuple of float
        The same on each effect-free replica [N m].
    encoder_counts : int
        Encoder resolution the replicas used (read from the log) [counts/rev].
    sensor_noise_std_N_m : float or None
        The torque sensor's noise the replicas used [N m]; None: ``tau_s`` derived from the encoders.
    closed_loop : bool
        The replicas ran the log's controller on its force reference (else its motor command, open loop).
    """

    effect: Effect
    observed_N_m: float
    replicas_N_m: tuple[float, ...]
    encoder_counts: int
    sensor_noise_std_N_m: float | None
    closed_loop: bool

    @property
    def ratio(self) -> float:
        """The log's torque over the largest replica's [-] (inf when no replica explains any)."""
        top = max(self.replicas_N_m, default=0.0)
        return self.observed_N_m / top if top > 0.0 else math.inf

    @property
    def distinct(self) -> bool:
        """The log's candidate explains :data:`REPLICA_MARGIN` times the torque of every replica's."""
        return self.ratio >= REPLICA_MARGIN

    def caveat(self) -> str:
        """Why a candidate that does not stand above the replicas is no verdict."""
        chain = (f"{self.encoder_counts}-count encoders" + ("" if self.sensor_noise_std_N_m is None else
                 f", the torque sensor's {1e3 * self.sensor_noise_std_N_m:.2g} mN m noise, scale and zero"))
        loop = "its controller and force reference" if self.closed_loop else "its motor command, open loop"
        return (f"Not distinct from the sensors: '{self.effect}' explains {1e3 * self.observed_N_m:.2g} mN m, but on "
                f"effect-free replicas of this log ({loop}; {chain}) it explains up to "
                f"{1e3 * max(self.replicas_N_m):.2g} mN m (a ratio of {self.ratio:.2f}, where a verdict needs "
                f"{REPLICA_MARGIN:g}): no effect is named.")

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the effect, the torque it explains on the log and on each replica [N m], their ratio (null when no
        replica explains any), the margin, whether it is distinct, and what the replicas assumed."""
        return {"effect": str(self.effect), "observed_N_m": self.observed_N_m, "replicas_N_m": list(self.replicas_N_m),
                "ratio": None if math.isinf(self.ratio) else self.ratio, "margin": REPLICA_MARGIN,
                "distinct": self.distinct, "encoder_counts": self.encoder_counts,
                "sensor_noise_std_N_m": self.sensor_noise_std_N_m, "closed_loop": self.closed_loop,
                "assumed": "the log's design with its re-calibrated J_m and d_m (and, with a torque sensor, k and the "
                           "sensor's scale and zero); in closed loop its controller, compensator and force reference, "
                           "open loop its motor command; effect-free; the encoders' step and the sensor's white noise "
                           "read from the log; no process noise, no torque limit"}


def closed_loop(data: GapData) -> bool:
    """True when the log is a closed loop the simulator can replay (a force reference and a declared controller);
    otherwise its replicas replay the logged motor command open loop."""
    exp = data.experiment
    return exp.signals.tau_r is not None and exp.design.controller is not None


def sensor_noise_std(data: GapData) -> float | None:
    """White noise of a measured ``tau_s`` [N m] (None when ``tau_s`` is derived or absent).

    From the second differences of ``tau_s`` at the raw rate, ``var = 6 sigma^2`` for white noise: over
    two periods the spring torque itself changes by far less (the noise fed back moves the motor by
    about ``P sigma T^2 / J_m``, micro-N m), and the median absolute deviation leaves out the few
    samples where a reference step moves it. The encoders play no part: with a sensor the loop
    feeds back the sensor, whatever their resolution.
    """
    if not data.tau_s_measured:
        return None
    d2 = np.diff(np.asarray(data.experiment.signals.tau_s, dtype=float), 2)
    return 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)


def _replica_statistic(data: GapData, cal: dict[str, float], effect: Effect, seed: int, sensor_std: float | None,
                       encoder_counts: int) -> float:
    from ..experiment import experiment_from_arrays
    from ..simulation import TorqueSensor, simulate

    exp = data.experiment
    tb = dataclasses.replace(exp.design.testbed, J_m=cal["J_m"], d_m=max(cal["d_m"], 0.0))
    sensor = None
    if sensor_std is not None:
        # the log's re-calibration: true spring torque = spring_scale x tau_s + offset, the spring's own k
        scale = cal["spring_scale"]
        tb = dataclasses.replace(tb, k=cal["k"])
        sensor = TorqueSensor(noise_std_N_m=sensor_std, gain=1.0 / scale, offset_N_m=-cal["tau_s_offset_N_m"] / scale)
    closed = closed_loop(data)
    reference = exp.signals.tau_r if closed else exp.signals.tau_m
    run = simulate(dataclasses.replace(exp.design, testbed=tb), reference=np.asarray(reference, dtype=float),
                   duration_s=exp.n_samples / exp.rate_hz, rate_hz=exp.rate_hz, seed=seed, closed_loop=closed,
                   encoder_counts=encoder_counts, process_noise_std=0.0, torque_sensor=sensor)
    # the declared design, as the log's: the replica's gap is measured against the same nominal model
    rexp = experiment_from_arrays(exp.design, exp.rate_hz, run.t, run.tau_m, run.theta, run.q,
                                  tau_s=run.tau_s if exp.signals.tau_s is not None else None,
                                  tau_r=run.tau_r if closed else None)
    rdata = prepare_gap_data(rexp, data.options)
    base = fit_baseline(rdata)
    fit = fit_candidate(rdata, effect)
    return 0.0 if fit is None else own_reduction(rdata, base, fit, noise_floor(rdata)).explained_rms


def replica_check(data: GapData, base: CandidateFit, fit: CandidateFit, *, n: int = N_REPLICAS,
                  seed: int = 0) -> ReplicaCheck | None:
    """The torque a candidate explains on a log against what it explains on effect-free replicas of the log.

    Parameters
    ----------
    data : GapData
        The prepared log: a closed loop (:func:`closed_loop`) or an open-loop command.
    base, fit : CandidateFit
        The calibrated nominal model and the candidate, fitted on ``data``.
    n : int
        Replicas [-].
    seed : int
        First replica's noise seed (replica ``i`` uses ``seed + i``).

    Returns
    -------
    ReplicaCheck or None
        None when a replica cannot be simulated or prepared (no check is no evidence either way).
    """
    from ..plausibility import encoder_step_of

    observed = own_reduction(data, base, fit, noise_floor(data))
    counts = int(round(2.0 * math.pi / encoder_step_of(np.asarray(data.experiment.signals.theta, dtype=float))))
    sensor = sensor_noise_std(data)
    try:
        reps = tuple(_replica_statistic(data, base.calibration, fit.effect, seed + i, sensor, counts) for i in range(n))
    except (ForecastError, ValueError, FloatingPointError):
        return None
    return ReplicaCheck(effect=fit.effect, observed_N_m=float(observed.explained_rms),
                        replicas_N_m=tuple(float(r) for r in reps), encoder_counts=counts,
                        sensor_noise_std_N_m=sensor, closed_loop=closed_loop(data))
