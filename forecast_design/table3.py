"""The paper's Table 3 (Section 7) on the virtual testbed: repeatability and fidelity of step responses.

Library side of ``forecast-design reproduce table3`` (re-exported by
:mod:`forecast_design.reproduce`); the figure is drawn by
:func:`~forecast_design.plotting.simulation.plot_table3`.

Ten 0.2 N m step responses per cell, each from a different random absolute
motor angle (:class:`~forecast_design.simulation.scenario.Variability`), on
hardware whose stiction level and Stribeck curve depend on the angle (LuGre with
F_s and ln v_s harmonics, :data:`TABLE3_TRUTH`), with angle-periodic Coulomb
friction and cogging (Section 2, Figs. 2c and 3), in the
``exp-soft`` and ``locked`` environments, with PD alone, PD + extended SFM
and PD + EA-FOB (10 Hz). The extended SFM is *identified* with
:func:`forecast_design.friction.identify` (model ``extended-sfm``, N = 4)
from a simulated open-loop identification run of the same hardware, never
copied from the truth. Metrics per cell:

* ``xcorr``: mean over the 45 pairs of responses of the zero-lag normalised
  cross-correlation of the mean-removed responses (Pearson's r of tau_s over
  the run). Zero lag, so a delayed response counts as less repeatable.
* ``mae``: mean over the ten runs of the MAE [N m] between the measured
  tau_s and the frictionless response: the same PD on the nominal plant with
  no friction at all (no effects and d_m = 0), no compensator, no noise
  ("how the system would perform in the absence of friction").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .effects import Cogging, PositionFriction, Stiction
from .environments import resolve_environments
from .errors import ParameterError
from .params import Compensator, Design, PDController

__all__ = [
    "PAPER_TABLE3",
    "TABLE3_TRUTH",
    "TABLE3_SFM_DEADBAND",
    "Table3Row",
    "Table3Result",
    "reproduce_table3",
    "pairwise_xcorr",
    "identify_extended_sfm",
]

#: Control rate of the testbed's board [Hz] (Section 7: 2 kHz).
_RATE = 2000.0

#: The paper's Table 3: (environment, compensator) -> (mean cross-correlation [-], MAE [N m]).
PAPER_TABLE3: Mapping[tuple[str, str], tuple[float, float]] = {
    ("exp-soft", "none"): (0.73, 0.04), ("exp-soft", "sfm"): (0.98, 0.05), ("exp-soft", "ea-fob"): (0.99, 0.008),
    ("locked", "none"): (0.90, 0.02), ("locked", "sfm"): (0.99, 0.02), ("locked", "ea-fob"): (0.99, 0.01),
}

#: Hardware of the Table 3 reproduction (Section 2, Fig. 2c: the stiction level and the Stribeck
#: curve depend on the motor angle; angle-periodic friction ripple). LuGre with Table 2's F_c,
#: sigma0, sigma1, sigma2, a static level F_s(theta) = 0.7 N m with harmonics of 0.15 and 0.06 N m
#: (0.47 to 0.93 N m) and a Stribeck velocity v_s(theta) = 0.05 rad/s exp(+-1.2 ...) (about
#: 0.01 to 0.3 rad/s: sharp breakaway at some angles, a wide negative-slope region, i.e.
#: stick-slip, at others); position-dependent Coulomb 0.1 +- 0.09 and a small cogging [N m].
TABLE3_TRUTH: tuple = (
    Stiction(F_s=0.7, F_s_a=(0.15, 0.06), F_s_b=(0.0, 0.04), v_s=0.05, v_s_a=(1.2, 0.4), v_s_b=(0.5, 0.0)),
    PositionFriction(F_c=0.1, a=(0.04, 0.02), b=(0.02, 0.01)),
    Cogging(a=(0.01, 0.0, 0.0, 0.005), b=(0.0, 0.01, 0.0, 0.0)),
)


#: Dead band of the Table 3 SFM's sign(theta') [rad/s]. The paper prints a plain sign(); on an
#: encoder-differentiated velocity that drives a stick-slip limit cycle whenever the motor stops
#: (run-to-run phase differences: x-corr 0.6 soft / 0.9 locked in the sensitivity table), which the
#: testbed's SFM (0.98 / 0.99) evidently did not have; 0.1 rad/s removes it (0.05 rad/s leaves a
#: trace of it: sensitivity table).
TABLE3_SFM_DEADBAND = 0.1


@dataclass(frozen=True, slots=True)
class Table3Row:
    """One cell pair of Table 3.

    Attributes
    ----------
    environment : str
        ``exp-soft`` or ``locked``.
    compensator : str
        ``none``, ``sfm`` or ``ea-fob``.
    xcorr : float
        Mean pairwise zero-lag normalised cross-correlation of the responses [-].
    mae : float
        Mean MAE to the frictionless response [N m].
    paper_xcorr, paper_mae : float or None
        The paper's values for the cell.
    """

    environment: str
    compensator: str
    xcorr: float
    mae: float
    paper_xcorr: float | None = None
    paper_mae: float | None = None

    def to_mapping(self) -> dict[str, Any]:
        """``{"environment", "compensator", "xcorr", "mae", "paper_xcorr", "paper_mae"}``."""
        return dataclasses.asdict(self)


@dataclass(frozen=True, slots=True)
class Table3Result:
    """Table 3 on the virtual testbed; iterates over its rows like a list.

    Attributes
    ----------
    rows : tuple of Table3Row
        Environment x compensator.
    initial_angles : ndarray, shape (repetitions,)
        Absolute motor angle of each repetition [rad].
    sfm_params : dict
        Extended-SFM parameters identified from the simulated identification run.
    identification_fit_percent : float
        Fit of that identification [%].
    choices : dict
        Step amplitude [N m], duration [s], repetitions, seed, w_q_hz [Hz], truth effects.
    explanation : str
        Deviations from the paper and why.
    sensitivity : tuple of dict
        SFM cells recomputed with other sign() dead bands: ``environment``,
        ``compensator``, ``sfm_deadband`` [rad/s], ``xcorr`` [-], ``mae`` [N m].
    responses : dict
        ``(environment, compensator) -> list of SimulationResult`` (not in JSON).
    expected : dict
        ``environment -> SimulationResult`` of the frictionless PD (not in JSON).
    """

    rows: tuple
    initial_angles: np.ndarray
    sfm_params: Mapping[str, float]
    identification_fit_percent: float
    choices: Mapping[str, Any]
    explanation: str
    sensitivity: tuple = ()
    responses: Mapping[tuple[str, str], Any] = field(default_factory=dict, repr=False, compare=False)
    expected: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __iter__(self):
        return iter(self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i):
        return self.rows[i]

    def row(self, environment: str, compensator: str) -> Table3Row:
        """The row of one cell."""
        for r in self.rows:
            if r.environment == environment and r.compensator == compensator:
                return r
        raise KeyError((environment, compensator))

    def to_mapping(self) -> list[dict[str, Any]]:
        """JSON of the ``reproduce table3`` verb: the list of rows (issue 5)."""
        return [r.to_mapping() for r in self.rows]

    def to_document(self) -> dict[str, Any]:
        """Rows plus provenance: ``{"rows", "choices", "sfm_params", "initial_angles", ..., "explanation"}``."""
        return {"rows": self.to_mapping(), "choices": dict(self.choices), "sfm_params": dict(self.sfm_params),
                "identification_fit_percent": self.identification_fit_percent,
                "initial_angles": [float(a) for a in self.initial_angles],
                "sensitivity": [dict(r) for r in self.sensitivity], "explanation": self.explanation}


def pairwise_xcorr(responses: np.ndarray) -> float:
    """Mean zero-lag normalised cross-correlation over all pairs of responses.

    Parameters
    ----------
    responses : ndarray, shape (m, n)
        One response per row [any unit], m >= 2.

    Returns
    -------
    float
        Mean over i < j of ``sum (x_i - mean x_i)(x_j - mean x_j) /
        sqrt(sum (x_i - mean x_i)^2 sum (x_j - mean x_j)^2)`` [-] (Pearson's r).
    """
    x = np.asarray(responses, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2:
        raise ParameterError(f"pairwise_xcorr needs at least two responses as rows, got shape {x.shape}",
                             name="responses", value=x.shape)
    c = np.corrcoef(x)
    return float(np.mean(c[np.triu_indices(x.shape[0], 1)]))


def _identification_profile(levels: Sequence[float], hold_s: float, ramp_s: float = 0.2):
    from .simulation import PiecewiseLinear

    times, values = [], []
    for i, level in enumerate(levels):
        times += [i * hold_s, i * hold_s + ramp_s, (i + 1) * hold_s - ramp_s]
        values += [0.0, float(level), float(level)]
    times.append(len(levels) * hold_s)
    values.append(0.0)
    return PiecewiseLinear(times_s=tuple(times), values=tuple(values))


def identify_extended_sfm(effects: Sequence[Any] = TABLE3_TRUTH, *, seed: int = 0, hold_s: float = 5.0
                          ) -> tuple[dict[str, float], Any, Any]:
    """Identify the paper's extended SFM on a simulated open-loop run of the hardware.

    The free link (``link-only``) is driven by a staircase of motor torques
    (+-0.8, +-1.2, +-1.6 N m, each held ``hold_s``), turning the motor over
    about two revolutions: enough for three viscous levels, both directions
    and the angle harmonics. :func:`forecast_design.friction.identify` fits
    ``viscous``, ``coulomb`` and 4 angle harmonics to ``tau_m - J_m theta'' -
    tau_s`` from the measured (quantised) signals only.

    Parameters
    ----------
    effects : sequence of effect parameter values
        The hardware (default :data:`TABLE3_TRUTH`).
    seed : int
        Process-noise seed.
    hold_s : float
        Duration of each torque level [s].

    Returns
    -------
    params : dict
        Identified parameters (``viscous`` [N m s/rad], ``coulomb``, ``sin<i>``, ``cos<i>`` [N m]).
    fit : FrictionFit
        The identification result.
    run : SimulationResult
        The identification run (homed at absolute angle 0).
    """
    from .friction import identify
    from .simulation import simulate

    levels = (0.8, 1.2, 1.6, -0.8, -1.2, -1.6)
    profile = _identification_profile(levels, hold_s)
    run = simulate(Design.nominal("link-only"), reference=profile, duration_s=len(levels) * hold_s,
                   closed_loop=False, effects=effects, seed=seed, rate_hz=_RATE,
                   description="reproduce table3: extended-SFM identification run")
    fit = identify(run.to_experiment(), "extended-sfm")
    return {k: float(v) for k, v in fit.params.items()}, fit, run


def reproduce_table3(*, repetitions: int = 10, amplitude: float = 0.2, duration_s: float = 1.0, seed: int = 0,
                     w_q_hz: float = 10.0, environments: Any = ("exp-soft", "locked"),
                     effects: Sequence[Any] = TABLE3_TRUTH, sfm_deadband: float = TABLE3_SFM_DEADBAND,
                     sensitivity: Sequence[float] = (0.0, 0.01, 0.05)) -> Table3Result:
    """Reproduce the paper's Table 3 (repeatability and fidelity of step responses) in simulation.

    Parameters
    ----------
    repetitions : int
        Step responses per cell, each from its own random absolute motor
        angle, uniform in [0, 2 pi) [-] (>= 2).
    amplitude : float
        Step reference [N m].
    duration_s : float
        Length of each response [s].
    seed : int
        Seed of the initial angles and of the process noise.
    w_q_hz : float
        EA-FOB Q cutoff [Hz].
    environments : str, Environment, EnvironmentSet, path or sequence
        The environments (paper: ``exp-soft`` and ``locked``), in any form
        :func:`~forecast_design.environments.resolve_environments` accepts; rows carry the set's names.
    effects : sequence of effect parameter values
        The hardware (default :data:`TABLE3_TRUTH`).
    sfm_deadband : float
        Dead band of the SFM's sign(theta') [rad/s] (default :data:`TABLE3_SFM_DEADBAND`); 0 is
        the printed formula's plain sign.
    sensitivity : sequence of float
        Further SFM dead bands [rad/s] whose SFM cells are recomputed for
        ``Table3Result.sensitivity`` (empty: none).

    Returns
    -------
    Table3Result
        Rows ``{"environment", "compensator", "xcorr", "mae"}`` (plus the
        paper's values), responses, the identified SFM and the explanation.
    """
    from .simulation import Step, simulate
    from .simulation.scenario import Variability

    if isinstance(repetitions, bool) or not isinstance(repetitions, int) or repetitions < 2:
        raise ParameterError(f"table3 repetitions must be an integer >= 2, got {repetitions!r}",
                             name="repetitions", value=repetitions)
    angles = Variability(repetitions=repetitions, seed=seed).initial_angles()
    sfm_params, fit, _ = identify_extended_sfm(effects, seed=seed)
    ref = Step(amplitude=amplitude)
    envset = resolve_environments(environments)      # presets, inline values, files, Environment objects
    environments, env_of = envset.names, dict(envset.items())
    rows, responses, expected = [], {}, {}
    for env in environments:
        expected[env] = simulate(Design(environment=env_of[env], controller=PDController(P=5.0, D=0.1)),
                                 reference=ref, duration_s=duration_s, rate_hz=_RATE, include_nominal_viscous=False,
                                 process_noise_std=0.0, encoder_counts=None,
                                 description=f"reproduce table3: {env}, frictionless PD")
        for kind in ("none", "sfm", "ea-fob"):
            comp = Compensator(kind=kind, w_q_hz=w_q_hz) if kind == "ea-fob" else Compensator(kind=kind)
            design = Design(environment=env_of[env], controller=PDController(P=5.0, D=0.1), compensator=comp)
            runs = [simulate(design, reference=ref, duration_s=duration_s, rate_hz=_RATE, effects=effects,
                             initial_angle=float(a), seed=seed + 1 + i,
                             sfm_params=sfm_params if kind == "sfm" else None, sfm_deadband=sfm_deadband,
                             description=f"reproduce table3: {env}, {kind}, run {i}")
                    for i, a in enumerate(angles)]
            responses[(env, kind)] = runs
            tau = np.array([r.tau_s for r in runs])
            paper = PAPER_TABLE3.get((env, kind), (None, None))
            rows.append(Table3Row(env, kind, pairwise_xcorr(tau),
                                  float(np.mean(np.abs(tau - expected[env].tau_s))), paper[0], paper[1]))
    sens = []
    for db in sensitivity:
        for env in environments:
            design = Design(environment=env_of[env], controller=PDController(P=5.0, D=0.1),
                            compensator=Compensator(kind="sfm"))
            tau = np.array([simulate(design, reference=ref, duration_s=duration_s, rate_hz=_RATE, effects=effects,
                                     initial_angle=float(a), seed=seed + 1 + i, sfm_params=sfm_params,
                                     sfm_deadband=float(db)).tau_s for i, a in enumerate(angles)])
            sens.append({"environment": env, "compensator": "sfm", "sfm_deadband": float(db),
                         "xcorr": pairwise_xcorr(tau), "mae": float(np.mean(np.abs(tau - expected[env].tau_s)))})
    choices = {"repetitions": repetitions, "amplitude": amplitude, "duration_s": duration_s, "seed": seed,
               "w_q_hz": w_q_hz, "environments": list(environments), "sfm_deadband": float(sfm_deadband),
               "effects": [e.to_mapping() for e in effects],
               "xcorr": "mean over pairs of the zero-lag Pearson correlation of tau_s",
               "mae": "mean over runs of mean |tau_s - tau_s(frictionless PD, d_m = 0, no noise)|"}
    result = Table3Result(tuple(rows), angles, sfm_params, float(fit.fit_percent_estimation), choices, "",
                          tuple(sens), responses, expected)
    return dataclasses.replace(result, explanation=_table3_explanation(result))


def _table3_explanation(result: Table3Result) -> str:
    parts = [f"Extended SFM identified from a simulated open-loop run (fit {result.identification_fit_percent:.1f} "
             f"%; paper: 89.95 %): viscous {result.sfm_params.get('viscous', 0.0):.3f} N m s/rad, coulomb "
             f"{result.sfm_params.get('coulomb', 0.0):.3f} N m; SFM sign() dead band "
             f"{result.choices.get('sfm_deadband', 0.0):g} rad/s."]
    for r in result.rows:
        if r.paper_xcorr is not None:
            parts.append(f"{r.environment}/{r.compensator}: xcorr {r.xcorr:.3f} (paper {r.paper_xcorr:.2f}), "
                         f"MAE {r.mae:.4f} N m (paper {r.paper_mae:g}).")
    envs = list(dict.fromkeys(r.environment for r in result.rows))
    for env in envs:
        cells = {r.compensator: r for r in result.rows if r.environment == env}
        if not {"none", "sfm", "ea-fob"} <= set(cells):
            continue
        e, s, n = cells["ea-fob"], cells["sfm"], cells["none"]
        pd_least = n.xcorr < min(s.xcorr, e.xcorr)
        best_m = e.mae < min(s.mae, n.mae)
        parts.append(f"{env}: PD alone is {'the least' if pd_least else 'not the least'} repeatable; the EA-FOB is "
                     f"{'the closest' if best_m else 'not the closest'} to the frictionless response.")
        if n.paper_xcorr is not None and not pd_least:
            parts.append(f"{env}: deviation: PD alone ({n.xcorr:.3f}) is as repeatable as the compensated loops "
                         f"(paper {n.paper_xcorr:.2f}). With the output locked the motor turns only "
                         "~tau_s/k = 3 mrad: each run rises identically and sticks at its first velocity reversal, "
                         "so the angle-dependent stiction shifts the final level (a shift the zero-lag correlation "
                         "ignores) but not the shape; the testbed's stick-slip (Fig. 2b, Oldham-joint sliding) "
                         "changed the shape as well, which no friction law of the virtual testbed reproduces at "
                         "3 mrad of travel. Mechanisms tried and rejected (PD alone stays at 0.97 or above): a "
                         "motor torque limit of 2-10 N m and a 20-50 Hz derivative filter (the D kick is not what "
                         "makes the runs alike); repetitions run back to back, each starting from the state the "
                         "previous one left (the residual spring torque converges to one fixed point, x-corr "
                         "0.998); a spring pre-load held by stiction at each start with the encoders zeroed "
                         "(uniform within +-0.2 N m: PD 0.97, SFM 0.97, EA-FOB 0.95, so the pattern does not "
                         "appear either). With a fixed reference and no integrator the stuck motor sees a constant "
                         "net torque below the Coulomb level, so no stick-slip can follow the first stop.")
        elif n.paper_xcorr is not None and abs(n.xcorr - n.paper_xcorr) > 0.1:
            parts.append(f"{env}: PD alone {n.xcorr:.2f} vs the paper's {n.paper_xcorr:.2f}: the spread of the "
                         "simulated stiction (F_s 0.47-0.93 N m, v_s 0.01-0.3 rad/s over the angles) is a guess "
                         "read from Fig. 2c; the x-corr of PD scales with it.")
        if n.paper_mae is not None and n.mae > 1.5 * n.paper_mae:
            parts.append(f"{env}: PD alone's MAE {n.mae:.3f} N m exceeds the paper's {n.paper_mae:g}: the "
                         "simulated static level (0.7 N m mean) sticks the motor further from the frictionless "
                         "response than the testbed's friction did.")
        if s.paper_mae is not None and s.mae < 0.5 * s.paper_mae:
            parts.append(f"{env}: the SFM's MAE {s.mae:.4f} N m is below the paper's {s.paper_mae:g}: the "
                         "simulated hardware has exactly the friction structure the extended SFM models "
                         "(viscous, Coulomb, angle harmonics), so its identified model is better than on the "
                         "testbed, where the fit reached 89.95 %.")
        if e.paper_xcorr is not None and e.xcorr < e.paper_xcorr - 0.015:
            parts.append(f"{env}: the EA-FOB's x-corr {e.xcorr:.3f} is below the paper's {e.paper_xcorr:.2f}: its "
                         "10 Hz Q filter lets the first ~20 ms of the angle-dependent breakaway through, which "
                         "differs between runs.")
        if s.paper_xcorr is not None and s.xcorr < s.paper_xcorr - 0.015:
            parts.append(f"{env}: the SFM's x-corr {s.xcorr:.3f} is below the paper's {s.paper_xcorr:.2f}: the "
                         "feed-forward cannot follow the angle-dependent static level, so some runs stop early.")
    if result.sensitivity:
        parts.append("SFM with other sign() dead bands (sensitivity): " + "; ".join(
            f"{r['environment']} {r['sfm_deadband']:g} rad/s: xcorr {r['xcorr']:.3f}, MAE {r['mae']:.4f} N m"
            for r in result.sensitivity) + ". With the plain sign() (0 rad/s) the SFM drives a stick-slip limit "
            "cycle once the motor stops, whose phase differs from run to run.")
    return " ".join(parts)
