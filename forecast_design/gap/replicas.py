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

A parametric bootstrap can: the nominal model (the log's design with its re-calibrated ``J_m`` -- the declared one
where the re-calibration sits on its datasheet bound, which is the bound's value, not the motor's -- and ``d_m``;
with a torque sensor, the re-calibrated ``k`` and the sensor's scale and zero) is simulated with the log's own
measurement chain (the encoders' step read from the log; a torque sensor's white noise read from ``tau_s``),
effect-free, ``n`` times with other noise draws: in
closed loop under the log's controller, compensator and force reference, open loop under its
logged command. The candidate is fitted on each replica as on the log; the torque it explains on
the log must be :data:`REPLICA_MARGIN` times the most it explains on a replica. What it explains
there is the measurement chain's.

Where the loop does not feed the angles back (open loop, or a torque sensor fed back) the encoders read
the simulated motion with the jitter the log's own readings show: an encoder whose reading jitters toggles
between two counts, which a motor's inertia does not, and the jitter is the one whose readings toggle as often
as the log's (an effect-free closed-loop square with a torque sensor and 0.8 counts of jitter: 55 % of its count
changes undone on the next sample, a Coulomb level of 67 mN m named clear; replicas without jitter explained
up to 11 mN m of what it explained, 19 mN m, with it up to 42 mN m). A closed loop on a derived ``tau_s`` feeds the
jitter back into the motor torque, so its replicas read it inside the loop (``simulate``'s ``encoder_jitter_counts``,
:func:`loop_jitter_counts`): without it the 19 replicas were one deterministic run (a 16-bit square with a 2.7 ms
delay and 0.79 counts of jitter: a stiction of 12 mN m named weak, 3.7 times that run's; 0.99 times the most of 19
jittered replicas). Where the encoders are read after the fact, each replica also draws where their count edges lie
against the motion (an encoder is homed anywhere within a count), so that a log with no noise source at all has
replicas that differ. What the replicas leave out (a logger's printing of ``tau_m``, process noise, a torque limit)
narrows their spread, which the margin covers.

A closed loop is also judged against a second null: its own logged command replayed open loop through the
effect-free model, the encoders read after the fact (``n`` replays). The command carries the loop's noise as it
happened, with whatever the replicas leave out of it; the candidate must explain the margin over the most of both
(an effect-free 16-bit loop whose Coulomb level explains 7 mN m, 1.8 times the most of its jittered replicas, 0.7
times the most of its replays).
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
from .heldout import richer_law_justified, verdict_ties
from .identifiability import calibration_on_bound
from .residuals import GapData, prepare_gap_data

__all__ = ["ReplicaCheck", "PROBABLE_P", "closed_loop", "command_replayed", "loop_jitter_counts", "probable_caveat",
           "probable_verdict", "read_encoders", "replica_check", "sensor_noise_std", "toggle_share", "weak_caveat"]

#: Replicas simulated per check [-].
N_REPLICAS = 19
#: How many times the torque the chain alone explains a candidate must explain on the log [-]: the replicas
#: leave out part of the log's noise (a logger's printing, process noise), which the margin covers. On 94 logs of
#: twenty-one seeds the false alarms and wrong verdicts the replicas reproduce stood at 0.30-1.06 times the replicas'
#: torque, the true effects at 1.58 and above.
REPLICA_MARGIN = 1.5
#: Offset of the replays' noise seeds from the replicas' [-].
REPLAY_SEED = 1000
#: Largest held-out p-value of a candidate the replicas may name, graded ``probable`` (:func:`probable_verdict`) [-].
PROBABLE_P = 0.05


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
    encoder_jitter_counts : float
        The encoders' jitter the replicas read their angles with (median over the replicas) [counts]: the one
        that makes them toggle as often as the log's (:func:`read_encoders`); inside the loop where it feeds the
        angles back (a closed loop on a derived ``tau_s``, :func:`loop_jitter_counts`).
    replayed : bool
        A closed loop whose controller has no equations (:func:`command_replayed`): the replicas replayed its
        logged command open loop, without the noise the loop feeds back.
    replays_N_m : tuple of float
        A closed loop's second null: the torque the candidate explains where the log's own command is replayed open
        loop through the effect-free model and the encoders read after the fact [N m] (the command carries the
        loop's noise as it happened, with what the replicas leave out); empty elsewhere.
    """

    effect: Effect
    observed_N_m: float
    replicas_N_m: tuple[float, ...]
    encoder_counts: int
    sensor_noise_std_N_m: float | None
    closed_loop: bool
    encoder_jitter_counts: float = 0.0
    replayed: bool = False
    replays_N_m: tuple[float, ...] = ()

    @property
    def most_N_m(self) -> float:
        """The most torque the candidate explains on any replica or replay [N m] (0 when there is none)."""
        return max(self.replicas_N_m + self.replays_N_m, default=0.0)

    @property
    def ratio(self) -> float:
        """The log's torque over the largest replica's or replay's [-] (inf when none explains any)."""
        return self.observed_N_m / self.most_N_m if self.most_N_m > 0.0 else math.inf

    @property
    def distinct(self) -> bool:
        """The log's candidate explains :data:`REPLICA_MARGIN` times the torque of every replica's."""
        return self.ratio >= REPLICA_MARGIN

    def caveat(self, named: str = "no effect is named") -> str:
        """Why a candidate that does not stand above the replicas is no verdict (``named``: what follows)."""
        chain = (f"{self.encoder_counts}-count encoders"
                 + (f" jittering {self.encoder_jitter_counts:.2g} counts" if self.encoder_jitter_counts > 0 else "")
                 + ("" if self.sensor_noise_std_N_m is None else
                 f", the torque sensor's {1e3 * self.sensor_noise_std_N_m:.2g} mN m noise, scale and zero"))
        loop = ("its controller and force reference, and its logged command replayed open loop" if self.closed_loop else
                "its logged motor command replayed open loop: its controller has no equations" if self.replayed else
                "its motor command, open loop")
        return (f"Not distinct from the sensors: '{self.effect}' explains {1e3 * self.observed_N_m:.2g} mN m, but on "
                f"effect-free replicas of this log ({loop}; {chain}) it explains up to "
                f"{1e3 * self.most_N_m:.2g} mN m (a ratio of {self.ratio:.2f}, where a "
                f"verdict needs {REPLICA_MARGIN:g}): {named}.")

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the effect, the torque it explains on the log and on each replica [N m], their ratio (null when no
        replica explains any), the margin, whether it is distinct, and what the replicas assumed."""
        return {"effect": str(self.effect), "observed_N_m": self.observed_N_m, "replicas_N_m": list(self.replicas_N_m),
                "ratio": None if math.isinf(self.ratio) else self.ratio, "margin": REPLICA_MARGIN,
                "distinct": self.distinct, "encoder_counts": self.encoder_counts,
                "sensor_noise_std_N_m": self.sensor_noise_std_N_m, "closed_loop": self.closed_loop,
                "replayed": self.replayed, "replays_N_m": list(self.replays_N_m),
                "encoder_jitter_counts": self.encoder_jitter_counts,
                "assumed": "the log's design with its re-calibrated J_m (the declared one where the re-calibration "
                           "sits on its datasheet bound) and d_m (and, with a torque sensor, k and the sensor's scale "
                           "and zero); in closed loop its controller, compensator and force reference, and its "
                           "logged command replayed open loop (replays_N_m), open loop its motor command; "
                           "effect-free; the encoders' step, their jitter (inside the loop where it feeds the angles "
                           "back) and the sensor's white noise read from the log, where the count edges lie drawn per "
                           "replica (not inside a loop); no process noise, no torque limit"}


def closed_loop(data: GapData) -> bool:
    """True when the log is a closed loop the simulator can replay (a force reference and a declared controller with
    equations); otherwise its replicas replay the logged motor command open loop."""
    exp = data.experiment
    return exp.signals.tau_r is not None and exp.design.controller is not None \
        and exp.design.controller.has_equations


def command_replayed(data: GapData) -> bool:
    """True for a closed loop whose controller has no equations (``other``: a lab's code, known by name): its replicas
    replay the logged command open loop, without the noise the loop feeds back."""
    exp = data.experiment
    return exp.signals.tau_r is not None and exp.design.controller is not None and not closed_loop(data)


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


def toggle_share(angle: np.ndarray) -> float:
    """Share of an encoder's count changes that the next sample reverses [-].

    A motor inertia cannot turn back within one period at a count's edge but rarely; an encoder whose
    reading jitters (noise before the quantiser) toggles between two counts wherever the motion dwells near an
    edge. The share of steps undone on the next sample measures that jitter.
    """
    d = np.diff(np.asarray(angle, dtype=float))
    moved = d != 0.0
    n = int(np.count_nonzero(moved[:-1]))
    return float(np.count_nonzero(d[:-1] * d[1:] < 0.0)) / n if n else 0.0


#: Encoder jitters tried to match a log's toggle share [counts] (standard deviation of the noise before the quantiser).
JITTER_GRID_COUNTS = np.linspace(0.0, 2.0, 41)


def read_encoders(theta: np.ndarray, q: np.ndarray, step: float, share: float,
                  seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Quantised readings of exact angles, with the jitter whose toggle share (:func:`toggle_share`) matches ``share``.

    The jitter is a white noise added before the quantiser, the same for both encoders; its standard
    deviation is the smallest of :data:`JITTER_GRID_COUNTS` whose readings of ``theta`` toggle at least as often
    as ``share`` (zero when the quantiser alone does: the readings are then ``round(angle / step) step``). One
    noise draw (from ``seed``) serves every level tried, so the share grows with the level.

    Parameters
    ----------
    theta, q : ndarray, shape (n,)
        Exact motor and output angles [rad].
    step : float
        Encoder step [rad].
    share : float
        The toggle share to match [-] (a log's).
    seed : int
        Noise seed.

    Returns
    -------
    theta_read, q_read : ndarray, shape (n,)
        The readings [rad].
    jitter_counts : float
        The jitter used [counts].

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 2001)
    >>> step = 2 * np.pi / 2**16
    >>> exact = 0.01 * np.sin(2 * np.pi * t)
    >>> noisy = np.round((exact + 0.5 * step * np.random.default_rng(1).standard_normal(t.size)) / step) * step
    >>> _, _, jitter = read_encoders(exact, np.zeros_like(t), step, toggle_share(noisy), seed=2)
    >>> abs(jitter - 0.5) <= 0.1
    True
    """
    noise = _jitter_noise(seed, theta.size, step)
    sigma, reading = 0.0, _quantise(theta, step)
    for level in JITTER_GRID_COUNTS[1:]:
        if toggle_share(reading) >= share:
            break
        sigma = float(level)
        reading = _quantise(theta + sigma * noise[0], step)
    return reading, _quantise(q + sigma * noise[1], step), sigma


def _jitter_noise(seed: int, n: int, step: float) -> np.ndarray:
    """The replicas' unit jitter on theta and q [rad per count of jitter], shape (2, n): one draw per seed."""
    return np.random.default_rng([int(seed), 0x71773]).standard_normal((2, n)) * step


def _quantise(angle: np.ndarray, step: float) -> np.ndarray:
    """An encoder's reading of ``angle``: the nearest count [rad]."""
    return np.round(angle / step) * step


def _replica_design(data: GapData, cal: dict[str, float], sensor_std: float | None) -> tuple[Any, Any]:
    """The replicas' design (the log's with its re-calibration) and torque sensor (None: ``tau_s`` derived)."""
    from ..simulation import TorqueSensor

    exp = data.experiment
    tb = dataclasses.replace(exp.design.testbed, J_m=cal["J_m"], d_m=max(cal["d_m"], 0.0))
    sensor = None
    if sensor_std is not None:
        # the log's re-calibration: true spring torque = spring_scale x tau_s + offset, the spring's own k
        scale = cal["spring_scale"]
        tb = dataclasses.replace(tb, k=cal["k"])
        sensor = TorqueSensor(noise_std_N_m=sensor_std, gain=1.0 / scale, offset_N_m=-cal["tau_s_offset_N_m"] / scale)
    return dataclasses.replace(exp.design, testbed=tb), sensor


def _replica_run(data: GapData, design: Any, sensor: Any, seed: int, encoder_counts: int | None,
                 jitter_counts: float = 0.0, *, closed: bool) -> Any:
    """One effect-free simulated run of the log's loop (``closed``) or of its logged command, with its chain."""
    from ..simulation import simulate

    exp = data.experiment
    reference = exp.signals.tau_r if closed else exp.signals.tau_m
    return simulate(design, reference=np.asarray(reference, dtype=float), duration_s=exp.n_samples / exp.rate_hz,
                    rate_hz=exp.rate_hz, seed=seed, closed_loop=closed, encoder_counts=encoder_counts,
                    encoder_jitter_counts=jitter_counts, process_noise_std=0.0, torque_sensor=sensor)


def loop_jitter_counts(data: GapData, cal: dict[str, float], encoder_counts: int, share: float, seed: int) -> float:
    """The encoders' jitter a closed loop on a derived ``tau_s`` reads its angles with [counts] (0 elsewhere).

    Such a loop feeds the jitter back, so its replicas must read it inside the loop (``simulate``'s
    ``encoder_jitter_counts``); its level is the one whose readings of one effect-free run with exact angles
    toggle as often as the log's (:func:`read_encoders`).
    """
    if not closed_loop(data) or data.tau_s_measured or share <= 0.0:
        return 0.0
    design, sensor = _replica_design(data, cal, None)
    theta = np.asarray(_replica_run(data, design, sensor, seed, None, closed=True).theta, dtype=float)
    step = 2.0 * math.pi / encoder_counts
    high = read_encoders(theta, theta, step, share, seed)[2]
    if high <= 0.0:
        return 0.0
    # read_encoders takes the first grid level reaching the share; between it and the one below, the share is
    # interpolated (a grid step too high lets every replica explain more: 0.85 counts for a log's 0.79)
    low = high - float(JITTER_GRID_COUNTS[1] - JITTER_GRID_COUNTS[0])
    noise = _jitter_noise(seed, theta.size, step)[0]
    s_low, s_high = (toggle_share(_quantise(theta + lvl * noise, step)) for lvl in (low, high))
    return float(np.interp(share, [s_low, s_high], [low, high])) if s_high > s_low else high


def _replica_statistic(data: GapData, cal: dict[str, float], effect: Effect, seed: int, sensor_std: float | None,
                       encoder_counts: int, share: float, loop_jitter: float = 0.0,
                       replay: bool = False) -> tuple[float, float]:
    """Torque the candidate explains on one effect-free replica [N m], and the encoders' jitter it used [counts]."""
    from ..experiment import experiment_from_arrays

    exp = data.experiment
    design, sensor = _replica_design(data, cal, sensor_std)
    closed = closed_loop(data) and not replay
    # where the loop does not feed the angles back (open loop, or a torque sensor fed back) the encoders read the
    # simulated motion after the fact, with the jitter the log's own readings show (read_encoders); a closed loop on
    # a derived tau_s reads them inside the loop, with the jitter loop_jitter_counts matched
    after = not closed or sensor is not None
    run = _replica_run(data, design, sensor, seed, None if after else encoder_counts, 0.0 if after else loop_jitter,
                       closed=closed)
    theta, q, tau_s, jitter = run.theta, run.q, run.tau_s, (0.0 if after else loop_jitter)
    if after:
        step = 2.0 * math.pi / encoder_counts
        # where the count edges lie against the motion is unknown (an encoder is homed anywhere within a count): each
        # replica draws it, so that a log with no noise source has replicas that differ (an effect-free 14-bit sweep:
        # a torque gain explaining 9.7 mN m, 1.8 times one deterministic replica, 1.4 times the most of 19 drawn). Not
        # inside a loop on a derived tau_s: drawn there, it took six true weak effects and no false alarm.
        phase = np.random.default_rng([int(seed), 0x0FF5E7]).uniform(-0.5, 0.5, 2) * step
        theta, q, jitter = read_encoders(np.asarray(run.theta, dtype=float) + phase[0],
                                         np.asarray(run.q, dtype=float) + phase[1], step, share, seed)
        if exp.design.environment.locked:
            # a locked output reads zero, jitter or not (the format asks q == 0; a jittered q failed every replica,
            # which left a weak verdict on an effect-free locked log unchecked)
            q = np.zeros_like(q)
        if sensor is None:
            tau_s = exp.design.testbed.spring_torque(theta, q)
    # the declared design, as the log's: the replica's gap is measured against the same nominal model
    rexp = experiment_from_arrays(exp.design, exp.rate_hz, run.t, run.tau_m, theta, q,
                                  tau_s=tau_s if exp.signals.tau_s is not None else None,
                                  tau_r=run.tau_r if closed else (exp.signals.tau_r if replay else None))
    rdata = prepare_gap_data(rexp, data.options)
    base = fit_baseline(rdata)
    fit = fit_candidate(rdata, effect)
    return (0.0 if fit is None else own_reduction(rdata, base, fit, noise_floor(rdata)).explained_rms), jitter


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
    share = toggle_share(np.asarray(data.experiment.signals.theta, dtype=float))     # the log's, once for every replica
    cal = dict(base.calibration)
    if "J_m" in calibration_on_bound(data, base):
        # a re-calibration on its datasheet bound is the bound's value, not the motor's: the replicas run the declared
        # J_m, so that whatever pushed the log's onto the bound (the encoders' jitter in the filtered acceleration:
        # an effect-free 16-bit sweep, J_m on its -3 % bound and a gain of 0.965 taking up the rest, 7.4 times its
        # replicas' at the bound's J_m, 1.3 times at the declared one) pushes theirs too
        cal["J_m"] = data.experiment.design.testbed.J_m
    try:
        loop_jitter = loop_jitter_counts(data, cal, counts, share, seed)
        reps = [_replica_statistic(data, cal, fit.effect, seed + i, sensor, counts, share, loop_jitter)
                for i in range(n)]
        # a closed loop's own command replayed open loop (an effect-free locked 2^21-count square: a dead band of
        # 1 mrad explaining 0.86 mN m that no replica of the loop explains, five of 19 replays 0.71-0.86 mN m)
        replays = [_replica_statistic(data, cal, fit.effect, seed + REPLAY_SEED + i, sensor, counts, share,
                                      replay=True)[0] for i in range(n)] if closed_loop(data) else []
    except (ForecastError, ValueError, FloatingPointError):
        return None
    return ReplicaCheck(effect=fit.effect, observed_N_m=float(observed.explained_rms),
                        replicas_N_m=tuple(float(r) for r, _ in reps), encoder_counts=counts,
                        sensor_noise_std_N_m=sensor, closed_loop=closed_loop(data), replayed=command_replayed(data),
                        encoder_jitter_counts=float(np.median([j for _, j in reps])),
                        replays_N_m=tuple(float(r) for r in replays))


def probable_verdict(data: GapData, ranked: list, base: CandidateFit, fits: dict[str, CandidateFit],
                     span: dict[str, Any]) -> tuple[Any, ReplicaCheck] | None:
    """A clear verdict's size that the held-out test leaves short of its level, named where no replica produces it.

    A candidate that removes ``min_reduction`` of its equations' gap, lowers the total gap and is identified, but
    whose held-out test gives a p-value between its level and :data:`PROBABLE_P` (``short_of_level``), is
    short of units rather than of effect: a delay acting on the edges of a slow square wave (20 units, 45 % of
    the gap, p = 0.012 at a level of 0.005). Its evidence is then asked of the replicas (:func:`replica_check`): it
    must explain :data:`REPLICA_MARGIN` times the torque it explains on every effect-free replica of the log (the
    delay above: 37 times). The first such candidate by held-out BIC that no other reading explains as well
    (:func:`.heldout.verdict_ties`), and for ``stiction`` or ``position_friction`` that the nested-law rule justifies
    over ``coulomb``, is checked; the one check decides.

    Parameters
    ----------
    data : GapData
        The prepared log.
    ranked : list of RankedCandidate
        The diagnosis's ranking (no candidate counts, none is weak).
    base : CandidateFit
        The calibrated nominal model.
    fits : dict of str to CandidateFit
        Every candidate's fit by effect word.
    span : dict
        ``angle_span_rad`` and ``n_harmonics`` of :func:`.heldout.verdict_ties`.

    Returns
    -------
    (RankedCandidate, ReplicaCheck) or None
        The candidate and its replicas, or None where none is short of its level or the replicas produce it (or
        cannot be simulated).
    """
    short = sorted((r for r in ranked if r.short_of_level and not verdict_ties(ranked, r, **span)),
                   key=lambda r: r.bic)
    coulomb = fits.get(str(Effect.COULOMB))
    for r in short:
        if r.effect in (Effect.STICTION, Effect.POSITION_FRICTION) and coulomb is not None \
                and not richer_law_justified(data, fits[str(r.effect)], coulomb):
            continue
        check = replica_check(data, base, fits[str(r.effect)])
        return (r, check) if check is not None and check.distinct else None
    return None


def weak_caveat(winner: Any, check: ReplicaCheck | None, min_reduction: float) -> str:
    """What a ``weak`` verdict rests on: the held-out test, and the replicas where they ran."""
    said = ("; it was not checked against effect-free replicas of the log (they could not be simulated): the sensors "
            "alone may produce it." if check is None else
            ", explaining torque no effect-free replica of the log explains."
            if math.isinf(check.ratio) else f", explaining {check.ratio:.3g} times the torque it explains on "
            "effect-free replicas of the log.")
    return (f"Weak effect: '{winner.effect}' removes {100 * winner.reduction_own:.0f} % of the gap above the encoders' "
            f"noise floor, below the {100 * min_reduction:g} % of a clear verdict, but passes the held-out test "
            f"(p = {winner.p_value:.2g}) and is identified" + said)


def probable_caveat(winner: Any, check: ReplicaCheck) -> str:
    """What a ``probable`` verdict rests on (:func:`probable_verdict`)."""
    times = "more than any" if math.isinf(check.ratio) else f"{check.ratio:.3g} times the most of"
    replays = f" and {len(check.replays_N_m)} replays of its command" if check.replays_N_m else ""
    return (f"Probable: '{winner.effect}' is identified and removes {100 * winner.reduction:.0f} % of the gap, but its "
            f"held-out test over {winner.n_units} units gives p = {winner.p_value:.2g}, above its level "
            f"{winner.level:.2g} (below {PROBABLE_P:g}); it explains {1e3 * check.observed_N_m:.3g} mN m, {times} "
            f"{len(check.replicas_N_m)} effect-free replicas{replays} of this log ({1e3 * check.most_N_m:.3g} mN m; a "
            f"verdict needs {REPLICA_MARGIN:g} times): named, graded probable (a longer log would prove or refute it).")
