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
logged command. The candidate is fitted on each replica as on the log, and the log's statistic
(the share of the gap above the noise floor the effect removes, counted as the diagnosis counts
it) is ranked among the replicas'. An effect the replicas reach is the measurement chain's.

What the replicas leave out (a logger's printing of ``tau_m``, encoders' jitter, a torque limit)
only narrows their spread: the check can keep a false alarm, not remove a true effect that stands
above what the chain it models produces.
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

#: Replicas simulated per check (a log must beat every one: Monte Carlo p = 1 / (n + 1) = 0.05).
N_REPLICAS = 19


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplicaCheck:
    """A candidate's statistic on the log against the same on effect-free replicas of its loop.

    Parameters
    ----------
    effect : Effect
        The candidate.
    observed : float
        Share of the gap above the noise floor it removes on the log (counted as the diagnosis
        counts it) [-].
    replicas : tuple of float
        The same on each effect-free replica [-].
    p_value : float
        ``(1 + #(replica >= observed)) / (n + 1)`` [-].
    encoder_counts : int
        Encoder resolution the replicas used (read from the log) [counts/rev].
    sensor_noise_std_N_m : float or None
        The torque sensor's noise the replicas used [N m]; None: ``tau_s`` derived from the encoders.
    closed_loop : bool
        The replicas ran the log's controller on its force reference (else its motor command, open loop).
    """

    effect: Effect
    observed: float
    replicas: tuple[float, ...]
    p_value: float
    encoder_counts: int
    sensor_noise_std_N_m: float | None
    closed_loop: bool

    @property
    def distinct(self) -> bool:
        """The log's statistic is above every replica's."""
        return self.p_value <= 1.0 / (len(self.replicas) + 1) + 1e-12

    def caveat(self) -> str:
        """Why a weak candidate that does not stand above the replicas is no verdict."""
        chain = (f"{self.encoder_counts}-count encoders" + ("" if self.sensor_noise_std_N_m is None else
                 f", the torque sensor's {1e3 * self.sensor_noise_std_N_m:.2g} mN m noise, scale and zero"))
        loop = "its controller and force reference" if self.closed_loop else "its motor command, open loop"
        n_as_much = sum(r >= self.observed for r in self.replicas)
        return (f"Not distinct from the sensors: '{self.effect}' removes {100 * self.observed:.0f} % of the gap "
                f"above the floor, but effect-free replicas of this log ({loop}; {chain}) remove as much in "
                f"{n_as_much} of {len(self.replicas)} (p = {self.p_value:.2g}): no effect is named.")

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the effect, the statistic on the log and on the replicas, p, what the replicas assumed."""
        return {"effect": str(self.effect), "observed": self.observed, "replicas": list(self.replicas),
                "p_value": self.p_value, "distinct": self.distinct, "encoder_counts": self.encoder_counts,
                "sensor_noise_std_N_m": self.sensor_noise_std_N_m, "closed_loop": self.closed_loop,
                "assumed": "the log's design with its re-calibrated J_m and d_m (and, with a torque sensor, k and the "
                           "sensor's scale and zero), in closed loop its controller, compensator and force reference, open loop its motor command; effect-free; "
                           "the encoders' step and the sensor's white noise read from the log; no process noise, "
                           "no torque limit"}


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
    return 0.0 if fit is None else own_reduction(rdata, base, fit, noise_floor(rdata)).counted


def replica_check(data: GapData, base: CandidateFit, fit: CandidateFit, *, n: int = N_REPLICAS,
                     seed: int = 0) -> ReplicaCheck | None:
    """Rank a candidate's statistic on a log among effect-free replicas of its measurement chain.

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

    observed = own_reduction(data, base, fit, noise_floor(data)).counted
    counts = int(round(2.0 * math.pi / encoder_step_of(np.asarray(data.experiment.signals.theta, dtype=float))))
    sensor = sensor_noise_std(data)
    try:
        reps = tuple(_replica_statistic(data, base.calibration, fit.effect, seed + i, sensor, counts) for i in range(n))
    except (ForecastError, ValueError, FloatingPointError):
        return None
    p = (1 + sum(r >= observed for r in reps)) / (n + 1)
    return ReplicaCheck(effect=fit.effect, observed=float(observed), replicas=tuple(float(r) for r in reps),
                          p_value=float(p), encoder_counts=counts, sensor_noise_std_N_m=sensor,
                          closed_loop=closed_loop(data))
