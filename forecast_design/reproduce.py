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

Table 3 (Section 7) lives in :mod:`forecast_design.table3` (re-exported here).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .effects import Stiction
from .errors import ParameterError
from .environments import resolve_environments, resolve_testbed
from .margins import resolve_skew, disk_margin, json_float
from .controllers import PAPER_PD, PD, resolve_controller
from .params import COMPENSATOR_KINDS, Compensator, Design
from .table3 import (PAPER_TABLE3, TABLE3_PLAY_PROBE, TABLE3_SFM_DEADBAND, TABLE3_TRUTH, XCORR_MODES, Table3Result,
                     Table3Row, identify_extended_sfm, pairwise_xcorr, pairwise_xcorr_per_run,
                     pairwise_xcorr_se, reproduce_table3, xcorr_se_from_per_run)

__all__ = [
    "PAPER_FIG7",
    "PAPER_TABLE3",
    "TABLE3_TRUTH",
    "TABLE3_SFM_DEADBAND",
    "TABLE3_PLAY_PROBE",
    "XCORR_MODES",
    "Fig7Choices",
    "Fig7Result",
    "reproduce_fig7",
    "Table3Row",
    "Table3Result",
    "reproduce_table3",
    "pairwise_xcorr",
    "pairwise_xcorr_se",
    "pairwise_xcorr_per_run",
    "xcorr_se_from_per_run",
    "identify_extended_sfm",
    "MarginRow",
    "fig6_table",
]

#: The paper's Fig. 7 numbers (Section 6) [N m].
PAPER_FIG7: Mapping[str, float] = {"mae_friction_sfm": 0.35, "mae_friction_eafob": 0.02}

_RATE = 2000.0


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
        PD derivative filter [Hz]: the reproduction's PD is 5/0.1 with ``T_f = 1/(2 pi
        derivative_cutoff_hz)``, Tustin-discretised (:meth:`Fig7Choices.controller`).
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

    def controller(self) -> PD:
        """The PD the reproduction runs: P = 5, D = 0.1, derivative filter at ``derivative_cutoff_hz``, Tustin."""
        return PD(P=5.0, D=0.1, T_f=1.0 / (2.0 * math.pi * self.derivative_cutoff_hz), discretization="tustin")

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
            # the same numbers with their unit in the name (the keys above stay for existing scripts)
            **{f"{key}_N_m": getattr(self, key) for key in ("mae_friction_sfm", "mae_friction_eafob",
                                                              "mae_tracking_sfm", "mae_tracking_eafob")},
            "choices": self.choices.to_mapping(),
            "sensitivity": [dict(row) for row in self.sensitivity],
            "explanation": self.explanation,
        }


def _fig7_runs(c: Fig7Choices) -> dict[str, Any]:
    from .simulation import Square, simulate

    runs = {}
    for kind in ("sfm", "ea-fob"):
        comp = Compensator(kind=kind, **c.compensator_kwargs) if kind == "ea-fob" else Compensator(kind="sfm")
        design = Design.nominal(c.environment, controller=c.controller(), compensator=comp)
        runs[kind] = simulate(
            design, reference=Square(high=c.high, low=c.low, period_s=c.period_s), duration_s=c.periods * c.period_s,
            effects=[Stiction()], rate_hz=_RATE, seed=c.seed, include_nominal_viscous=c.include_nominal_viscous,
            sfm_params={"viscous": c.sfm_viscous, "coulomb": c.sfm_coulomb} if kind == "sfm" else None,
            velocity_cutoff_hz=c.velocity_cutoff_hz,
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
    #: The nominal design of this disk (testbed, environment values, controller, compensator); None
    #: for a row built by hand.
    design: Design | None = None

    def to_mapping(self) -> dict[str, Any]:
        """JSON row with keys environment, observer, w_q_hz, disk_margin, gain_margin_db,
        phase_margin_deg, frequency_rad_s, stable (infinities as ``None``), and the keys every verb
        uses for these quantities (README, "Interface conventions"): ``compensator`` (= observer),
        ``alpha`` (= disk_margin), ``skew``, ``phase_margins_deg`` ([-phase, +phase]) and
        ``frequency_hz``; ``assumed``: the design (testbed, environment values, controller,
        compensator), the Q filter's form, where the loop is broken, the loop kind and conventions."""
        pm, w = json_float(self.phase_margin_deg), json_float(self.frequency_rad_s)
        assumed: dict[str, Any] | None = None
        if self.design is not None:
            comp = self.design.compensator
            assumed = {"design": self.design.to_mapping(),
                       "q_family": comp.q_family if comp is not None else None,
                       "q_order": comp.q_order if comp is not None else None,
                       "break_at": "controller", "loop": "continuous",
                       "conventions": "negative feedback 1 + L = 0; balanced disk (skew 0) unless given; "
                                      "disk margin of Seiler, Packard and Gahinet (2020)"}
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
            "assumed": assumed,
        }


def fig6_table(
    *,
    environments: Any = ("soft", "stiff"),
    w_q_hz: Sequence[float] = (1.0, 5.0, 10.0),
    observers: Sequence[str] = ("none", "ea-fob", "lo-dob", "ld-dob"),
    controller: Any = PAPER_PD,
    skew: float = 0.0,
    sigma: float | None = None,
    testbed: Any = None,
    progress: Callable[[int, int], None] | None = None,
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
    controller : Controller, str or python-control system
        Force controller (paper: PD, P = 5 [N m / N m], D = 0.1 [N m s / N m]); its C(s).
    skew : float
        Skew of the disk [-] (the paper uses the balanced disk, 0); python-control's and MATLAB's name.
    sigma : float, optional
        Alias of ``skew`` (kept for existing callers).
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`); None: Table 1.
    progress : callable, optional
        ``progress(done, total)`` after each environment.

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
    controller = resolve_controller(controller)
    skew = resolve_skew(skew, sigma)
    tb = resolve_testbed(testbed)
    rows: list[MarginRow] = []
    envset = list(resolve_environments(environments, testbed=tb))
    for done, (env, environment) in enumerate(envset):
        if progress is not None:
            progress(done, len(envset))
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
                    design=dataclasses.replace(design, controller=controller, compensator=comp),
                ))
    return rows
