"""Reproductions of the paper's simulation (Fig. 7) and experiments (Table 3) on the virtual testbed.

Library side of ``forecast-design reproduce fig7`` and ``reproduce table3``.
Both return result dataclasses with a ``to_mapping()`` for JSON; the
figures are drawn by :func:`forecast_design.plotting.simulation.plot_fig7`
and :func:`~forecast_design.plotting.simulation.plot_table3`.

Fig. 7 (Section 6)
------------------
LuGre friction with Table 2's parameters in the true plant, PD force
control P = 5, D = 0.1, a 1 N m square-wave reference, and two friction
estimates fed forward (``tau_m = u + tau_hat``): the SFM ``tau_hat = d_m
theta' + d_c sign(theta')`` and the EA-FOB with a 10 Hz Q filter (the
observer of :func:`forecast_design.symbolic.observers.observer_filters`,
run by the simulator). Metrics: the MAE between estimated and true
friction torque (paper: 0.35 N m SFM, 0.02 N m EA-FOB) and the MAE between
reference and spring torque.

The paper leaves several things open; :class:`Fig7Choices` fixes them and
:func:`reproduce_fig7` reruns the comparison with each varied in turn (the
sensitivity table). Why the defaults are what they are:

* ``environment = "stiff"`` (Section 5's J_e = 0.1 kg m^2, k_e = 100 N m/rad,
  critically damped): the high-impedance environment of the paper that is
  fully specified. The PD was *tuned* on J_e = 1 (the ``fig7`` preset), which
  the text does not say was the simulated one. With J_e = 1 the EA-FOB is
  still the better estimator for holds of 2 s or more, but at 1 s holds the
  SFM's error is the smaller (sensitivity table): the SFM only enters its
  stick-slip limit cycle after a while at J_e = 1, while at J_e = 0.1 it does
  so within each hold, which is what the paper's 0.35 N m (an error as large
  as the friction itself) indicates.
* ``period_s = 4`` (2 s per level), two periods: the EA-FOB's error is the Q
  filter's lag at the reference edges (measured: the estimate matches the
  Q-filtered true friction to a few mN m), so its MAE scales with the number
  of edges per second; 2 s holds put it at the paper's 0.02 N m.
* ``include_nominal_viscous = True``: the testbed's nominal d_m = 0.3 is part
  of the hardware; the EA-FOB's nominal plant has no d_m (Section 5), so it
  estimates d_m theta' as friction too, and so does the SFM.
* ``sfm_viscous = 0.3`` (the nominal d_m), ``sfm_coulomb = 0.4`` (Table 2's
  Coulomb level): the SFM's d_m, d_c read as the known model. Alternatives
  (LuGre's viscous 0.1, or d_m + sigma2 = 0.4) are in the table.
* Q: 2nd-order Butterworth (the toolbox default); derivative filter 200 Hz
  (see :mod:`forecast_design.simulation.controllers`); no torque limit (the
  paper gives none; 5 and 10 N m are in the table); SFM velocity from the
  encoder through a 50 Hz filtered derivative.

Table 3 (Section 7)
-------------------
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
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .effects import Cogging, PositionFriction, Stiction
from .errors import ParameterError
from .environments import resolve_environments, resolve_testbed
from .margins import _skew, disk_margin, json_float
from .params import COMPENSATOR_KINDS, Compensator, Design, PDController

__all__ = [
    "PAPER_FIG7",
    "PAPER_TABLE3",
    "TABLE3_TRUTH",
    "TABLE3_SFM_DEADBAND",
    "Fig7Choices",
    "Fig7Result",
    "reproduce_fig7",
    "Table3Row",
    "Table3Result",
    "reproduce_table3",
    "pairwise_xcorr",
    "MarginRow",
    "fig6_table",
]

#: The paper's Fig. 7 numbers (Section 6) [N m].
PAPER_FIG7: Mapping[str, float] = {"mae_friction_sfm": 0.35, "mae_friction_eafob": 0.02}

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

_RATE = 2000.0
#: Dead band of the Table 3 SFM's sign(theta') [rad/s]. The paper prints a plain sign(); on an
#: encoder-differentiated velocity that drives a stick-slip limit cycle whenever the motor stops
#: (run-to-run phase differences: x-corr 0.6 soft / 0.9 locked in the sensitivity table), which the
#: testbed's SFM (0.98 / 0.99) evidently did not have; 0.1 rad/s removes it (0.05 rad/s leaves a
#: trace of it: sensitivity table).
TABLE3_SFM_DEADBAND = 0.1


# --- Fig. 7 -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Fig7Choices:
    """What the paper leaves open in Section 6 (module docstring: why these defaults).

    Attributes
    ----------
    environment : str
        Environment preset of the simulated (and nominal) environment.
    period_s : float
        Square-wave period [s] (high for the first half).
    high, low : float
        Square-wave levels [N m].
    periods : int
        Number of periods simulated [-]; the MAEs cover the whole run.
    include_nominal_viscous : bool
        The true plant has the nominal d_m theta' besides LuGre.
    q_family : str
        Q filter family (``butterworth`` | ``binomial``).
    q_order : int
        Q filter order [-].
    w_q_hz : float
        Q cutoff [Hz].
    derivative_cutoff_hz : float
        PD derivative filter [Hz].
    torque_limit : float or None
        Motor torque saturation [N m]; None for none.
    sfm_viscous : float
        SFM d_m [N m s/rad].
    sfm_coulomb : float
        SFM d_c [N m].
    velocity_cutoff_hz : float
        SFM velocity filter [Hz].
    seed : int
        Process-noise seed.
    """

    environment: str = "stiff"
    period_s: float = 4.0
    high: float = 1.0
    low: float = -1.0
    periods: int = 2
    include_nominal_viscous: bool = True
    q_family: str = "butterworth"
    q_order: int = 2
    w_q_hz: float = 10.0
    derivative_cutoff_hz: float = 200.0
    torque_limit: float | None = None
    sfm_viscous: float = 0.3
    sfm_coulomb: float = 0.4
    velocity_cutoff_hz: float = 50.0
    seed: int = 0

    def __post_init__(self) -> None:
        from .params import environment_preset

        environment_preset(self.environment)  # raises on an unknown name
        for name in ("period_s", "w_q_hz", "derivative_cutoff_hz", "velocity_cutoff_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < math.inf):
                raise ParameterError(f"fig7 {name} must be a positive number, got {value!r}", name=name, value=value)
        if isinstance(self.periods, bool) or not isinstance(self.periods, int) or self.periods < 1:
            raise ParameterError(f"fig7 periods must be an integer >= 1, got {self.periods!r}", name="periods",
                                 value=self.periods)
        if self.torque_limit is not None and not (self.torque_limit > 0):
            raise ParameterError(f"fig7 torque_limit must be > 0 [N m] or None, got {self.torque_limit!r}",
                                 name="torque_limit", value=self.torque_limit)

    def to_mapping(self) -> dict[str, Any]:
        """The choices by name (JSON-ready; ``torque_limit`` None means none)."""
        return dataclasses.asdict(self)

    @property
    def compensator_kwargs(self) -> dict[str, Any]:
        """Q filter settings for :class:`~forecast_design.params.Compensator`."""
        return {"w_q_hz": float(self.w_q_hz), "q_family": self.q_family, "q_order": int(self.q_order)}


@dataclass(frozen=True, slots=True)
class Fig7Result:
    """The Fig. 7 comparison and its sensitivity to the open choices.

    Attributes
    ----------
    mae_friction_sfm, mae_friction_eafob : float
        MAE between estimated and true friction torque [N m].
    mae_tracking_sfm, mae_tracking_eafob : float
        MAE between tau_r and tau_s [N m].
    choices : Fig7Choices
        The choices of this run.
    sensitivity : tuple of dict
        One row per variation: ``vary`` (what changed), the choice values
        and the four MAEs [N m].
    explanation : str
        Deviations from the paper and why.
    mae_friction_eafob_vs_q : float
        MAE between the EA-FOB estimate and the Q-filtered true friction
        [N m]: the observer's error apart from the lag Q imposes.
    runs : dict
        ``{"sfm": SimulationResult, "ea-fob": SimulationResult}`` (not in JSON).
    """

    mae_friction_sfm: float
    mae_friction_eafob: float
    mae_tracking_sfm: float
    mae_tracking_eafob: float
    choices: Fig7Choices
    sensitivity: tuple
    explanation: str
    mae_friction_eafob_vs_q: float
    runs: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def to_mapping(self) -> dict[str, Any]:
        """JSON of the ``reproduce fig7`` verb (keys as in issue 5, plus ``explanation``)."""
        return {
            "mae_friction_sfm": self.mae_friction_sfm,
            "mae_friction_eafob": self.mae_friction_eafob,
            "mae_tracking_sfm": self.mae_tracking_sfm,
            "mae_tracking_eafob": self.mae_tracking_eafob,
            "choices": self.choices.to_mapping(),
            "sensitivity": [dict(row) for row in self.sensitivity],
            "explanation": self.explanation,
        }


def _fig7_runs(c: Fig7Choices) -> dict[str, Any]:
    from .simulation import Square, simulate

    runs = {}
    for kind in ("sfm", "ea-fob"):
        comp = Compensator(kind=kind, **c.compensator_kwargs) if kind == "ea-fob" else Compensator(kind="sfm")
        design = Design.nominal(c.environment, controller=PDController(P=5.0, D=0.1), compensator=comp)
        runs[kind] = simulate(
            design, reference=Square(high=c.high, low=c.low, period_s=c.period_s), duration_s=c.periods * c.period_s,
            effects=[Stiction()], rate_hz=_RATE, seed=c.seed, include_nominal_viscous=c.include_nominal_viscous,
            sfm_params={"viscous": c.sfm_viscous, "coulomb": c.sfm_coulomb} if kind == "sfm" else None,
            derivative_cutoff_hz=c.derivative_cutoff_hz, velocity_cutoff_hz=c.velocity_cutoff_hz,
            torque_limit=math.inf if c.torque_limit is None else float(c.torque_limit),
            description=f"reproduce fig7: {kind}",
        )
    return runs


def _mae(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.abs(np.asarray(a) - np.asarray(b))))


def _fig7_metrics(runs: Mapping[str, Any]) -> dict[str, float]:
    s, e = runs["sfm"], runs["ea-fob"]
    return {
        "mae_friction_sfm": _mae(s.tau_frc_hat, s.truth.tau_frc),
        "mae_friction_eafob": _mae(e.tau_frc_hat, e.truth.tau_frc),
        "mae_tracking_sfm": _mae(s.tau_r, s.tau_s),
        "mae_tracking_eafob": _mae(e.tau_r, e.tau_s),
    }


def _q_filtered(values: np.ndarray, c: Fig7Choices) -> np.ndarray:
    from scipy import signal

    from .discrete import discretize
    from .symbolic.observers import compensator_q_tf

    q = discretize(compensator_q_tf(Compensator(kind="ea-fob", **c.compensator_kwargs)), _RATE, "tustin")
    return signal.lfilter(np.asarray(q.num, dtype=float), np.asarray(q.den, dtype=float), values)


#: The sensitivity table's variations (label, changes to the defaults).
FIG7_VARIATIONS: tuple[tuple[str, Mapping[str, Any]], ...] = (
    ("defaults", {}),
    ("environment", {"environment": "fig7"}),
    ("environment, period_s", {"environment": "fig7", "period_s": 2.0}),
    ("environment, period_s", {"environment": "fig7", "period_s": 8.0}),
    ("period_s", {"period_s": 2.0}),
    ("period_s", {"period_s": 8.0}),
    ("square 0..1 N m", {"low": 0.0}),
    ("include_nominal_viscous", {"include_nominal_viscous": False}),
    ("q_family", {"q_family": "binomial"}),
    ("q_order", {"q_order": 3}),
    ("derivative_cutoff_hz", {"derivative_cutoff_hz": 50.0}),
    ("derivative_cutoff_hz", {"derivative_cutoff_hz": 1000.0}),
    ("torque_limit", {"torque_limit": 10.0}),
    ("torque_limit", {"torque_limit": 5.0}),
    ("sfm_viscous (LuGre sigma2)", {"sfm_viscous": 0.1}),
    ("sfm_viscous (d_m + sigma2)", {"sfm_viscous": 0.4}),
    ("velocity_cutoff_hz", {"velocity_cutoff_hz": 200.0}),
)


def reproduce_fig7(*, sensitivity: bool = True, **choices: Any) -> Fig7Result:
    """Reproduce the paper's Fig. 7: SFM vs EA-FOB friction estimates under LuGre friction.

    Parameters
    ----------
    sensitivity : bool
        Also rerun with each open choice varied (:data:`FIG7_VARIATIONS`,
        applied on top of `choices`); False leaves the table empty.
    **choices
        Overrides of :class:`Fig7Choices` (e.g. ``environment="fig7"``,
        ``period_s=2.0`` [s], ``torque_limit=10.0`` [N m]).

    Returns
    -------
    Fig7Result
        The four MAEs [N m], the choices, the sensitivity rows and the
        explanation of deviations from the paper.

    Raises
    ------
    ParameterError
        Unknown or invalid choices.
    """
    names = {f.name for f in dataclasses.fields(Fig7Choices)}
    for key, value in choices.items():
        if key not in names:
            raise ParameterError(f"unknown fig7 choice '{key}'; allowed: {', '.join(sorted(names))}", name=key,
                                 value=value)
    c = Fig7Choices(**choices)
    runs = _fig7_runs(c)
    metrics = _fig7_metrics(runs)
    e = runs["ea-fob"]
    vs_q = _mae(e.tau_frc_hat, _q_filtered(e.truth.tau_frc, c))
    rows = []
    if sensitivity:
        for label, change in FIG7_VARIATIONS:
            ci = dataclasses.replace(c, **change)
            m = metrics if ci == c else _fig7_metrics(_fig7_runs(ci))
            rows.append({"vary": label, **ci.to_mapping(), **m})
    explanation = _fig7_explanation(c, metrics, vs_q, rows, runs)
    return Fig7Result(**metrics, choices=c, sensitivity=tuple(rows), explanation=explanation,
                      mae_friction_eafob_vs_q=vs_q, runs=runs)


def _fig7_explanation(c: Fig7Choices, m: Mapping[str, float], vs_q: float, rows: Sequence[Mapping[str, Any]],
                      runs: Mapping[str, Any]) -> str:
    ratio = m["mae_friction_sfm"] / m["mae_friction_eafob"] if m["mae_friction_eafob"] > 0 else math.inf
    peak = max(float(np.max(np.abs(r.tau_m))) for r in runs.values())
    parts = [
        f"Friction-estimate MAE: SFM {m['mae_friction_sfm']:.3f} N m (paper 0.35), EA-FOB "
        f"{m['mae_friction_eafob']:.3f} N m (paper 0.02), ratio {ratio:.1f}.",
        f"The EA-FOB estimate differs from the Q-filtered true friction by only {vs_q:.4f} N m MAE: its error "
        "against the true friction is the lag of the 10 Hz Q filter where the friction changes fast (the "
        "velocity transients after each reference edge), so it scales with the edges per second "
        "(sensitivity rows 'period_s').",
        "The SFM's error comes from its sign(theta') feed-forward: when the motor should stick it drives a "
        "stick-slip limit cycle, and its estimate jumps by 2 d_c while the true friction stays small.",
        f"Open choices (paper silent): environment '{c.environment}', square period {c.period_s:g} s "
        f"({c.low:g} to {c.high:g} N m, {c.periods} periods), d_m in the true plant: "
        f"{c.include_nominal_viscous}, Q {c.q_family} order {c.q_order}, derivative filter "
        f"{c.derivative_cutoff_hz:g} Hz, torque limit {c.torque_limit or 'none'}, SFM d_m = {c.sfm_viscous:g}, "
        f"d_c = {c.sfm_coulomb:g}; see forecast_design.reproduce for why.",
        f"Without a torque limit the unfiltered reference edge through the PD's derivative asks for up to "
        f"{peak:.0f} N m for one sample; the torque_limit rows show the effect of a real motor's saturation.",
    ]
    flips = [r for r in rows if r["mae_friction_eafob"] >= r["mae_friction_sfm"]]
    if flips:
        parts.append("The ordering reverses (SFM better) for: " + "; ".join(
            f"{r['vary']} = " + ", ".join(f"{k}={r[k]}" for k in ('environment', 'period_s'))
            + f" (SFM {r['mae_friction_sfm']:.3f}, EA-FOB {r['mae_friction_eafob']:.3f})" for r in flips) + ".")
    return " ".join(parts)


# --- Table 3 --------------------------------------------------------------------------------


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
                         "3 mrad of travel.")
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


# ---------------------------------------------------------------------------------------------
# Fig. 6: disk margins of the observers in soft and stiff environments
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class MarginRow:
    """One disk of the paper's Fig. 6: an environment, an observer and its Q cutoff."""

    environment: str                        # environment name (preset or set label)
    observer: str                           # compensator kind ('none' is the plant alone)
    w_q_hz: float | None                    # Q(s) cutoff, None for 'none'      [Hz]
    disk_margin: float                      # alpha (0 if unstable)            [-]
    gain_margin_db: tuple[float, float]     # disk-based (lo, hi)              [dB]
    phase_margin_deg: float                 # disk-based                       [deg]
    frequency_rad_s: float                  # critical frequency               [rad/s]
    stable: bool                            # nominal closed loop stable
    skew: float = 0.0                       # skew of the disk                 [-]

    def to_mapping(self) -> dict[str, Any]:
        """JSON row with keys environment, observer, w_q_hz, disk_margin, gain_margin_db,
        phase_margin_deg, frequency_rad_s, stable (infinities as ``None``), and the keys every verb
        uses for these quantities (README, "Interface conventions"): ``compensator`` (= observer),
        ``alpha`` (= disk_margin), ``skew``, ``phase_margins_deg`` ([-phase, +phase]) and
        ``frequency_hz``."""
        pm, w = json_float(self.phase_margin_deg), json_float(self.frequency_rad_s)
        return {
            "environment": self.environment,
            "observer": self.observer,
            "compensator": self.observer,
            "w_q_hz": self.w_q_hz,
            "disk_margin": json_float(self.disk_margin),
            "alpha": json_float(self.disk_margin),
            "skew": self.skew,
            "gain_margin_db": [json_float(g) for g in self.gain_margin_db],
            "phase_margin_deg": pm,
            "phase_margins_deg": None if pm is None else [-pm, pm],
            "frequency_rad_s": w,
            "frequency_hz": None if w is None else w / (2.0 * math.pi),
            "stable": self.stable,
        }


def fig6_table(
    *,
    environments: Any = ("soft", "stiff"),
    w_q_hz: Sequence[float] = (1.0, 5.0, 10.0),
    observers: Sequence[str] = ("none", "ea-fob", "lo-dob", "ld-dob"),
    controller: PDController = PDController(P=5.0, D=0.1),
    skew: float = 0.0,
    sigma: float | None = None,
    testbed: Any = None,
) -> list[MarginRow]:
    """Disk margins of the force loop with each observer, as in the paper's Fig. 6.

    Parameters
    ----------
    environments : str, Environment, EnvironmentSet, path or sequence
        The environments (paper: ``soft``, ``stiff``): anything
        :func:`~forecast_design.environments.resolve_environments` accepts (preset names, inline
        ``k_e=..,J_e=..`` values, an environment-set file, Environment objects); rows are labelled
        with the set's names.
    w_q_hz : sequence of float
        Q(s) cutoffs [Hz] for every observer (paper: 1, 5, 10).
    observers : sequence of str
        Compensator kinds; ``none`` is the plant alone and gets a single row.
    controller : PDController
        Force controller (paper: P = 5 [N m / N m], D = 0.1 [N m s / N m]).
    skew : float
        Skew of the disk [-] (the paper uses the balanced disk, 0); python-control's and MATLAB's name.
    sigma : float, optional
        Alias of ``skew`` (kept for existing callers).
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`); None: Table 1.

    Returns
    -------
    list of MarginRow
        One row per environment, observer and cutoff (one per environment for ``none``),
        in the order of the arguments.

    Raises
    ------
    ParameterError
        For an unknown environment or observer kind, or a nonpositive cutoff.

    Notes
    -----
    Each loop is :func:`forecast_design.loops.continuous.force_loop` of the nominal design in
    that environment, broken at the controller; its ``stable`` flag (from the full
    characteristic polynomial, which sees cancellations) is passed to :func:`disk_margin`.
    """
    for kind in observers:
        if kind not in COMPENSATOR_KINDS:
            raise ParameterError(
                f"fig6_table: observer must be one of {', '.join(COMPENSATOR_KINDS)}, got {kind!r}",
                name="observers", value=kind)
    from .loops import force_loop
    skew = _skew(skew, sigma)
    tb = resolve_testbed(testbed)
    rows: list[MarginRow] = []
    for env, environment in resolve_environments(environments, testbed=tb):
        design = Design(testbed=tb, environment=environment)
        for kind in observers:
            cutoffs: Sequence[float | None] = (None,) if kind == "none" else tuple(w_q_hz)
            for wq in cutoffs:
                comp = None if wq is None else Compensator(kind=kind, w_q_hz=wq)
                loop = force_loop(design, comp, controller=controller)
                dm = disk_margin(loop.L, skew, closed_loop_stable=bool(loop.stable))
                rows.append(MarginRow(
                    environment=env, observer=kind, w_q_hz=None if wq is None else float(wq),
                    disk_margin=dm.alpha, gain_margin_db=dm.gain_margin_db,
                    phase_margin_deg=dm.phase_margin_deg, frequency_rad_s=dm.frequency_rad_s,
                    stable=dm.stable, skew=dm.sigma,
                ))
    return rows
