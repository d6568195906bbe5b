"""Sim-to-real gap diagnosis: which unmodelled effect explains a log, and how far the gap shrinks.

Decision rule (stated in every diagnosis's ``metric``). Every threshold below either is a
probability or scales with the information in the log; none is tuned to one generator:

1. The gap is the RMS of the stacked equation errors (motor, environment and,
   with a ``tau_s`` column judged to be an independent measurement, coupling) [N m]
   on the *held-out* blocks: the log is cut into ``n_blocks`` interleaved time
   blocks, models are fitted on the even blocks and scored on the odd ones.
2. The reference is the calibrated nominal model: ``J_m`` and the spring torque
   scale within the datasheet tolerance ``calibration_tolerance`` (3 %), ``d_m >= 0``.
3. A candidate counts when it lowers the total held-out gap (all equations: explaining one equation
   while the total does not drop is no verdict) by the held-out test of (c) at the same level (at ``alpha``
   when it removes ``min_reduction`` of the total) and, on the equations where its physics acts
   (:func:`~.candidates.effect_rows`), (a) its held-out reduction is at least
   ``min_reduction`` of the gap above the encoders' quantisation floor (:mod:`.grading`), (b) the torque it explains, ``sqrt(gap_before^2 - gap_after^2)``,
   is at least ``min_effect_fraction`` (0.1 %) of the RMS command (the motor's torque accuracy; a backlash's
   also the RMS quantisation of the spring torque; an environment mismatch's, where the encoders derive the spring
   torque its equation holds, 0.1 % of that torque's RMS and its quantisation instead), (c) a one-sided paired t-test of the log ratio of squared errors over
   held-out *test units* gives p below the candidate's level (a weighted Bonferroni split of ``alpha``
   fixed on the fit blocks: ``alpha / 2`` for the candidate that explains them best, ``alpha / (2 (n - 1))``
   for each other, :func:`.heldout.candidate_levels`) -- units are
   twice the correlation length of the candidate's residual (:func:`test_units`), so
   the number of independent units, and the power, grows with the log's length and
   its excitation; the test runs over every unit and over the units where the
   candidate's prediction differs from the nominal one by more than the floor (an effect
   that acts in a few units, a delay at the edges of a slow square), Simes-combined
   (:func:`.heldout.units_test`) -- and (d) it is *identified* (:mod:`.identifiability`): its defining
   coefficients pass a joint Wald test with the residual's autocorrelation accounted
   for, and no parameter is outside the plausible range of :mod:`forecast_design.plausibility` (a
   friction level also reaches the torque accuracy of (b)); an
   environment mismatch, a delay, a Coulomb level and a torque gain also persist in half the equation band, and
   still lower the held-out gap there
   (:func:`.halfband.persists_in_half_band`: the encoders' quantisation shrinks a fitted J, a closed
   loop's answer to it looks like a delay, and it can fit a level of a few mN m or a gain). What a log
   resolves only together is fitted that way: a delay short against the band, which shows only as
   coefficient x delay, is read where that ridge leaves the coefficient's bound; a dead band crossed
   quickly, which shows only as c x width, at c nearest 1; an output J shrunk below a tenth of the
   declared one is held at it (stated in a caveat) while d and k_e are fitted (:mod:`.candidates`).
4. Among the candidates that count, the winner minimises a held-out BIC,
   ``n log(SSE / n) + p log(n)`` (p = number of effect parameters). A winner (clear or weak) that a torque gain within
   the datasheet tolerance (a re-calibration) explains as well is no verdict, nor a periodic one over less than a
   period that another candidate explains as well (:func:`.heldout.verdict_ties`). An effect outside the motor
   equation (an environment mismatch; backlash in the coupling read by a torque sensor) counts only where no
   motor-equation candidate that passes the held-out test removes more of the total gap.
5. Parsimony between nested friction laws (:func:`.heldout.richer_law_justified`):
   ``stiction`` or ``position_friction`` wins over ``coulomb`` only if it resolves what it adds
   (stiction: ``F_s`` 5 % above a Coulomb level with a bump no narrower than the stick velocity, or bristles wider
   than one count holding it; position_friction: its harmonics) and beats ``coulomb`` by the
   held-out test at :data:`.heldout.NESTED_ALPHA` (one planned comparison between two laws that
   both count) on the held-out units where the two laws' predictions differ by more than the
   floor and on all of them (Simes' combination of the two), or, for stiction, shows its breakaway
   at rest, above the Coulomb level. The rule decides between the two laws whichever the BIC ranks
   first: a stiction that counts and that the rule justifies is the verdict over a coulomb the BIC
   prefers (the BIC weighs every row alike, a breakaway acts on a few). A friction law keeps a level
   per direction of motion only where that lowers the held-out gap and the two levels are within a
   factor 3 (else one level for both, stated in a caveat); the same rule applies to the two-effect
   path and to the second effect. Where ``coulomb`` does not count, a richer law must still beat it if
   it is resolved but weak, and name only what it resolves (:func:`.heldout.richer_law_resolved`); else
   the next candidate that counts, or the weak grade.
6. No candidate counts: the verdict is the best candidate that passes every test but the
   reduction, graded ``weak`` (:mod:`.grading`; it must be told from the re-calibration and have a parameter on
   a direction the log resolves, :func:`.grading.weak_set_aside`); else one of a clear verdict's size whose
   held-out test stops short of its level (below :data:`.replicas.PROBABLE_P`) and that no effect-free replica of
   the log produces, graded ``probable`` (:func:`.replicas.probable_verdict`); or ``none`` when there is none.
7. A second effect (forward selection, one step): every other candidate is fitted
   *together with* the winner; the best one by held-out BIC is reported as a
   secondary effect when it passes the same test against the winner alone, is
   identified, and removes ``min_reduction`` of the winner's remaining held-out gap.
   When no single candidate counts (two effects of similar size), the three best
   plausible candidates are each paired the same way (second step: ``min_reduction / 2``
   of the remaining gap); the best pair that removes ``min_reduction`` of the gap and
   passes the test against the nominal model becomes verdict + secondary effect, the verdict
   being the one of the two that removes more of the gap alone. A fit that failed the half-band
   check alone is quantisation and joins no pair.
8. Caveats are computed from the log: the isolability matrix names the words this log
   cannot tell from the verdict; candidates that would remove ``min_reduction`` of the
   gap but are not identified are listed with the reason; a re-calibration on its
   datasheet bound is reported.
9. What the sensors leave open is read both ways and the data choose: a ``tau_s`` column between a
   logger's rounding and a quiet sensor (the verdict that explains more of its gap), and motion below the
   encoder's speed resolution, at rest or creeping where the recorded angle moves
   (:func:`.motion.creeping`; the reading whose friction fits predict the held-out data better), each
   stated in a caveat.

A second view of the gap, the output-error replay (:mod:`.replay`), simulates the
nominal and the augmented model from the recorded ``tau_m`` over short windows
and compares ``theta`` and ``tau_s`` with the log.
"""

from __future__ import annotations

import dataclasses

import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from threadpoolctl import threadpool_limits

from ..effects import Effect
from ..errors import ParameterError
from ..experiment import Experiment
from .caveats import computed_caveats
from .joint import JointAttribution, fit_joint
from .candidates import CANDIDATE_EFFECTS, CandidateFit, effect_rows, fit_all, fit_baseline, fit_pair
from .identifiability import (EffectAssessment, assess_fit, calibration_status, method_shift, calibration_freedom,
                              calibration_on_bound, with_method_error)
from .isolability import Isolability, isolability
from .halfband import HALF_BAND_CHECKED, persists_in_half_band
from .locate import Location, locate_gap
from .replay import ReplayCheck, replay_check
from .replicas import PROBABLE_P, ReplicaCheck, probable_caveat, probable_verdict, replica_check, weak_caveat
from .reversals import ReversalTest, reversal_test
from .rules import metric_text
from ..plausibility import ParameterStatus
from .grading import explained_rms, noise_floor, own_reduction, weak_set_aside
from .structures import _FRICTION
from .heldout import (breakaway_proven_at_rest, candidate_levels, correlation_length, effect_held_out_test,
                      held_out_test, verdict_ties, richer_law_justified, richer_law_resolved, simplest_tied,
                      test_units)
from .motion import creeping
from .residuals import GapData, GapOptions, TauSSource, prepare_gap_data

__all__ = ["Diagnosis", "RankedCandidate", "diagnose", "held_out_test", "test_units", "correlation_length"]


@dataclass(frozen=True, slots=True, kw_only=True)
class RankedCandidate:
    """One candidate's held-out score.

    Parameters
    ----------
    effect : Effect
        The effect word.
    gap_after : float
        Held-out gap with this effect added [N m].
    reduction : float
        ``1 - gap_after / gap_before`` clipped to [0, 1] [-].
    params : Mapping[str, Any]
        Fitted effect parameters (physical units).
    p_value : float
        One-sided paired t-test p-value of the held-out improvement [-].
    bic : float
        Held-out BIC used for ranking [-].
    significant : bool
        True when the candidate passes the reduction threshold and the test, and is identified.
    assessment : EffectAssessment or None
        Parameter uncertainty, plausibility and whether the effect is identified on this log.
    reduction_own : float
        Held-out reduction on the equations where the effect acts (the one that must reach
        ``min_reduction``) [-].
    equations : tuple of str
        Those equations.
    weak : bool
        Passes every test but removes less than ``min_reduction`` of the explainable gap
        (:mod:`.grading`): a weak effect.
    explained_rms : float
        RMS torque the candidate explains on the held-out rows of its equations (:func:`.grading.explained_rms`)
        [N m].
    accuracy : float
        The least it must explain to count: the motor's torque accuracy (``GapOptions.min_effect_fraction`` of
        the RMS command), for a dead band the spring torque's quantisation where larger [N m].
    withheld_by_accuracy : bool
        Passes every other test of a clear or weak effect but explains less than ``accuracy``: not counted.
    level : float
        The level its held-out test must reach (:func:`.heldout.candidate_levels`) [-]; NaN where not set.
    n_units : int
        Held-out test units of that test (:func:`.heldout.test_units`) [-].
    short_of_level : bool
        A clear verdict's size whose held-out p lies between ``level`` and :data:`.replicas.PROBABLE_P`
        (:func:`.replicas.probable_verdict`).
    """

    effect: Effect
    gap_after: float
    reduction: float
    params: Mapping[str, Any]
    p_value: float
    bic: float
    significant: bool
    assessment: EffectAssessment | None = None
    reduction_own: float = float("nan")
    equations: tuple[str, ...] = ()
    weak: bool = False
    explained_rms: float = float("nan")
    accuracy: float = 0.0
    withheld_by_accuracy: bool = False
    level: float = float("nan")
    n_units: int = 0
    short_of_level: bool = False

    @property
    def identified(self) -> bool:
        """True when the fitted effect is identified on this log (see :mod:`.identifiability`)."""
        return self.assessment is not None and self.assessment.identified

    def to_mapping(self) -> dict[str, Any]:
        """The ranking entry of the diagnosis JSON.

        Returns
        -------
        dict
            ``effect``, ``gap_after`` [N m], ``reduction``, ``params``, ``p_value``, ``counts``
            (passes every test), ``weak``, ``equations``, ``reduction_in_equations``, ``explained_rms_N_m``,
            ``below_accuracy`` (withheld by the accuracy alone), ``level`` (the level ``p_value`` must reach,
            null where not set), ``n_units`` (held-out test units), ``short_of_level``, and ``identified``,
            ``not_identified``, ``status``, ``reasons`` from the assessment.
        """
        out = {"effect": str(self.effect), "gap_after": float(self.gap_after),
               "reduction": float(self.reduction), "params": _jsonable(self.params),
               "p_value": float(self.p_value), "counts": bool(self.significant), "weak": bool(self.weak),
               "equations": list(self.equations),
               "reduction_in_equations": None if math.isnan(self.reduction_own) else float(self.reduction_own),
               "explained_rms_N_m": None if math.isnan(self.explained_rms) else float(self.explained_rms),
               "below_accuracy": bool(self.withheld_by_accuracy),
               "level": None if math.isnan(self.level) else float(self.level), "n_units": int(self.n_units),
               "short_of_level": bool(self.short_of_level)}
        if self.assessment is not None:
            out.update(self.assessment.to_mapping())
        return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value)
    if isinstance(value, (np.integer, int)) and not isinstance(value, bool):
        return int(value)
    return value


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Diagnosis:
    """Result of :func:`diagnose`.

    Parameters
    ----------
    effect : Effect
        The verdict: the effect blamed, or ``Effect.NONE``.
    gap_before : float
        Held-out gap of the calibrated nominal model [N m].
    gap_after : float
        Held-out gap with the verdict's effect added [N m].
    reduction : float
        ``1 - gap_after / gap_before`` in [0, 1] [-].
    params : Mapping[str, Any]
        The verdict effect's fitted parameters.
    metric : str
        How the gap is measured and split, and the decision rule.
    location : Location
        Where the gap lies.
    ranking : tuple of RankedCandidate
        Every candidate tried, best first.
    joint : JointAttribution or None
        Group-lasso joint attribution (not part of the JSON contract).
    caveats : tuple of str
        Why the verdict may be ambiguous on this log.
    baseline : CandidateFit
        Fit of the calibrated nominal model.
    fits : Mapping[str, CandidateFit]
        Every candidate's fit, keyed by effect word.
    data : GapData
        The prepared equation errors.
    secondary : RankedCandidate or None
        A second effect that counts on top of the verdict (its ``gap_after`` is the
        held-out gap with both effects, ``reduction`` relative to ``gap_before``).
    replay : ReplayCheck or None
        Output-error replay of the nominal model and of the verdict's model.
    isolability : Isolability or None
        Which pairs of effect words this log can tell apart.
    calibration : Mapping[str, ParameterStatus]
        The baseline's re-calibrated ``J_m``, ``spring_scale`` (and ``k``) with ``at_bound`` flags.
    reading : Mapping or None
        When the ``tau_s`` column's reading was uncertain: the other reading's ``source``, ``effect``
        and ``reduction``, and the reading ``chosen`` (JSON ``tau_s.alternative``).
    grade : str
        ``clear`` (the effect removes ``min_reduction`` of the explainable gap), ``weak`` (it passes
        every other test but removes less), ``probable`` (it removes ``min_reduction`` but its held-out test stops
        short of its level, below :data:`.replicas.PROBABLE_P`, and no effect-free replica of the log produces it:
        :func:`.replicas.probable_verdict`) or ``none`` (:mod:`.grading`).
    method_shift : Mapping[str, float]
        How far the verdict's parameters move when the analysis is repeated with the position filter's
        cut-off halved (:func:`.identifiability.method_shift`), in their units; already in their
        standard deviations (JSON ``verdict.std_method``).
    calibration_freedom : Mapping[str, float]
        What the verdict's re-calibration, held on its bounds, hid of its standard deviations
        (:func:`.identifiability.calibration_freedom`), in their units; already in them (JSON
        ``verdict.std_calibration_bound``; empty when no calibrated value is on its bound).
    replicas : ReplicaCheck or None
        A weak verdict's candidate, or a clear one removing less than ``min_reduction`` of the total
        gap, against effect-free replicas of the log (:func:`.replicas.replica_check`; JSON
        ``verdict.replicas``); None when none was made.
    reversals : ReversalTest or None
        A Coulomb verdict's laws compared on the trajectory around the reversals (:func:`.reversals.reversal_test`;
        JSON ``verdict.reversals``); None when not made (another verdict, encoders fine enough, too few reversals).
    """

    effect: Effect
    gap_before: float
    gap_after: float
    reduction: float
    params: Mapping[str, Any]
    metric: str
    location: Location
    ranking: tuple[RankedCandidate, ...]
    joint: JointAttribution | None = None
    caveats: tuple[str, ...] = ()
    baseline: CandidateFit = field(repr=False, default=None)  # type: ignore[assignment]
    fits: Mapping[str, CandidateFit] = field(repr=False, default_factory=dict)
    data: GapData = field(repr=False, default=None)  # type: ignore[assignment]
    secondary: RankedCandidate | None = None
    replay: ReplayCheck | None = None
    isolability: Isolability | None = None
    calibration: Mapping[str, ParameterStatus] = field(default_factory=dict)
    reading: Mapping[str, Any] | None = None
    grade: str = "clear"
    method_shift: Mapping[str, float] = field(default_factory=dict)
    calibration_freedom: Mapping[str, float] = field(default_factory=dict)
    replicas: ReplicaCheck | None = None
    reversals: ReversalTest | None = None

    @property
    def identified(self) -> bool:
        """False when the verdict's parameters are not all identified (levels a log does not separate, named by a
        breakaway at rest; a stiction named by its trajectories, whose two folds disagree): read their statuses."""
        return self.effect is Effect.NONE or bool(self.ranking and self.ranking[0].identified)

    @property
    def summary(self) -> str:
        """``location.summary`` of the JSON: caveats, where the gap lies, the replay, a second effect."""
        parts = list(self.caveats) + [self.location.summary()]
        if self.replay is not None:
            parts.append(self.replay.summary(str(self.effect)))
        if self.secondary is not None:
            parts.append(f"A second effect also counts on top of {self.effect}: {self.secondary.effect} "
                         f"(held-out gap with both {self.secondary.gap_after:.3g} N m, "
                         f"{100 * self.secondary.reduction:.0f} % below the nominal model).")
        return " ".join(parts)

    def to_mapping(self) -> dict[str, Any]:
        """Exactly the JSON object of the output contract (issue 6).

        Returns
        -------
        dict
            ``{"verdict": {...}, "metric": str, "location": {...}, "ranking": [...],
            "isolability": {...}, "tau_s": {...}, "design": {...}, "caveats": [...]}``; ``design`` is the nominal model
            the gap is measured against (testbed, environment, controller and compensator as logged, ``rate_hz``,
            ``duration_s``). The verdict holds
            ``effect``, ``gap_before``/``gap_after`` [N m], ``reduction``, ``params``, their
            ``status`` (value, std, status), ``std_method`` (the analysis' own error per parameter),
            ``std_calibration_bound`` (what a re-calibration held on its bounds hid, per parameter),
            ``secondary`` (``effect``, ``params`` and ``status`` of the pair fitted together,
            ``gap_after`` with both effects [N m], ``reduction`` of both relative to
            ``gap_before``; null when no second effect counts) and ``calibration`` (the
            re-calibrated nominal values with ``at_bound`` flags; without an interval, so never ``identified``).
            ``replicas``: a small verdict's torque against effect-free replicas of the log (also one it
            dropped), or null; ``reversals``: a Coulomb verdict's laws compared around the reversals, or null.
        """
        loc = self.location.to_mapping()
        loc["summary"] = self.summary
        verdict: dict[str, Any] = {"effect": str(self.effect), "grade": self.grade if self.effect is not Effect.NONE
                                   else "none", "gap_before": float(self.gap_before),
                                   "gap_after": float(self.gap_after), "reduction": float(self.reduction),
                                   "params": _jsonable(self.params)}
        top = self.ranking[0] if self.ranking and self.effect is not Effect.NONE else None
        verdict["status"] = ({k: v.to_mapping() for k, v in top.assessment.status.items()}
                             if top is not None and top.assessment is not None else {})
        verdict["secondary"] = None if self.secondary is None else {
            "effect": str(self.secondary.effect), "params": _jsonable(self.secondary.params),
            "gap_after": float(self.secondary.gap_after), "reduction": float(self.secondary.reduction),
            # the pair's numbers (both effects, fitted together) with their intervals and statuses
            "status": ({k: v.to_mapping() for k, v in self.secondary.assessment.status.items()}
                       if self.secondary.assessment is not None else {})}
        verdict["std_method"] = {k: float(v) for k, v in self.method_shift.items()}
        verdict["std_calibration_bound"] = {k: float(v) for k, v in self.calibration_freedom.items()}
        verdict["replicas"] = None if self.replicas is None else self.replicas.to_mapping()
        verdict["reversals"] = None if self.reversals is None else self.reversals.to_mapping()
        verdict["calibration"] = {k: {**v.to_mapping(), "at_bound": v.status == "at_bound"}
                                  for k, v in self.calibration.items()}
        out = {
            "verdict": verdict,
            "metric": self.metric,
            "location": loc,
            "ranking": [r.to_mapping() for r in self.ranking],
            "caveats": list(self.caveats),
        }
        if self.isolability is not None:
            out["isolability"] = self.isolability.to_mapping()
        if self.data is not None:
            out["tau_s"] = self.data.tau_s_source.to_mapping()
            out["tau_s"]["alternative"] = None if self.reading is None else dict(self.reading)
            out["design"] = self.data.experiment.declared()     # the nominal model the gap is measured against
        return out


def diagnose(experiment: Experiment, *, options: GapOptions | None = None, joint: bool = True) -> Diagnosis:
    """Diagnose the sim-to-real gap of one log.

    Parameters
    ----------
    experiment : Experiment
        The log; its ``[testbed]``/``[environment]`` are the nominal model and its
        recorded ``tau_m`` is the input replayed through it.
    options : GapOptions, optional
        Filter, split and test settings.
    joint : bool
        Also run the group-lasso joint attribution (Clarabel).

    Returns
    -------
    Diagnosis
        Verdict, location, ranking of every candidate tried.

    Raises
    ------
    ParameterError
        If the log is too short for the filter and the block split.
    IdentifiabilityError
        If the command is constant or the motor does not move (< 20 encoder counts).
    ExperimentFormatError
        If a signal is not finite (an in-memory log; files are checked on load).
    """
    if not isinstance(experiment, Experiment):
        hint = " (load it first: load_experiment(path))" if isinstance(experiment, (str, os.PathLike)) else ""
        raise ParameterError(f"diagnose needs an Experiment{hint}, got {type(experiment).__name__}",
                             name="experiment", value=experiment)
    # Hundreds of small least-squares solves (a few thousand rows, ~10 columns): a threaded BLAS
    # only adds hand-offs, and on a busy machine its spinning threads made the diagnosis 3-8x
    # slower (issue 16); one BLAS thread also makes the numbers independent of the core count.
    with threadpool_limits(1, user_api="blas"):
        diag = _diagnose(experiment, options, joint)
        src = diag.data.tau_s_source
        if src.uncertain and diag.data.options.tau_s_reading == "auto":
            # the column sits between a logger's rounding and a quiet sensor: try the other reading too
            # and keep the one whose verdict explains more of its gap (what the data support)
            other = "derived" if src.measured else "measured"
            alt = _diagnose(experiment, dataclasses.replace(diag.data.options, tau_s_reading=other), joint,
                            tau_s_source=src)
            diag = _choose_reading(diag, alt)
        if np.mean(creeping(diag.data) != 0.0) >= CREEPING_SHARE:
            # below the speed resolution the encoder cannot tell a creep from short stays at rest: read both ways
            diag = _choose_creep_reading(diag, _diagnose(experiment, diag.data.options, joint,
                                                         tau_s_source=diag.data.tau_s_source, creep=True))
        return diag


#: Share of a log's samples that may creep below the encoder's speed resolution (:func:`.motion.creeping`)
#: from which the diagnosis also reads the log as creeping [-].
CREEPING_SHARE = 0.01


def _choose_creep_reading(at_rest: Diagnosis, creep: Diagnosis) -> Diagnosis:
    """Of a log read at rest and read as creeping below the speed resolution, the reading whose friction fits
    (the best of coulomb, stiction, position_friction) predict the held-out data better, with a caveat."""
    def friction_gap(d: Diagnosis) -> float:
        return min((r.gap_after for r in d.ranking if r.effect in _FRICTION), default=math.inf)

    a, c = friction_gap(at_rest), friction_gap(creep)
    share = 100 * float(np.mean(creeping(at_rest.data) != 0.0))
    if c < a:
        note = (f"Assumed: below the encoder's speed resolution the motor creeps ({share:.2g} % of the samples, "
                f"where the recorded angle moves the same way on both sides): read so, the friction fits predict "
                f"the held-out data better ({c:.3g} against {a:.3g} N m at rest).")
        return dataclasses.replace(creep, caveats=(note,) + tuple(creep.caveats))
    return at_rest


def _choose_reading(first: Diagnosis, second: Diagnosis) -> Diagnosis:
    """Of two readings of an uncertain ``tau_s`` column, the diagnosis the data support, with a caveat naming both."""
    def score(d: Diagnosis) -> float:
        return d.reduction if d.effect is not Effect.NONE else 0.0

    keep, drop = (second, first) if score(second) > score(first) else (first, second)
    a, b = keep.data.tau_s_source, first.data.tau_s_source
    note = (f"Caution: the tau_s column is between a logger's rounding and a quiet sensor ({100 * (b.beyond_rounding or 0):.2g} % "
            f"of the rows beyond the rounding their printed digits allow): read as {a.source}, the verdict is "
            f"'{keep.effect}' ({100 * keep.reduction:.0f} % of the gap); read as {drop.data.tau_s_source.source}, "
            f"'{drop.effect}' ({100 * drop.reduction:.0f} %). The data support the {a.source} reading.")
    alternative = {"source": drop.data.tau_s_source.source, "effect": str(drop.effect),
                   "reduction": float(drop.reduction), "chosen": a.source}
    return dataclasses.replace(keep, caveats=(note,) + tuple(keep.caveats), reading=alternative)


def _diagnose(experiment: Experiment, options: GapOptions | None, joint: bool, *,
              tau_s_source: TauSSource | None = None, creep: bool = False) -> Diagnosis:
    data = prepare_gap_data(experiment, options, tau_s_source=tau_s_source, creep=creep)
    opts = data.options
    base = fit_baseline(data)
    fits = fit_all(data, CANDIDATE_EFFECTS)
    held_blocks = np.arange(1, opts.n_blocks, 2)
    n_held = int(np.count_nonzero(data.stacked(data.held_out)))
    alpha = opts.alpha / max(1, len(fits))     # second effects and pairs: Bonferroni over the candidates
    alphas = candidate_levels(data, fits, opts.alpha)
    gap0 = base.gap_held_out
    ranked = []
    floor = noise_floor(data)
    in_band_only: set[Effect] = set()
    for fit, alpha_fit in zip(fits, alphas):
        red = 1.0 - fit.gap_held_out / gap0 if gap0 > 0 else 0.0
        own = effect_rows(data, fit)
        mine = own_reduction(data, base, fit, floor)
        red_own, explained, accuracy, counted = mine.reduction, mine.explained_rms, mine.accuracy, mine.counted
        all_units = test_units(data, fit)
        # a clear verdict's size is tested by signed ranks: its improvement may span decades across the units (an
        # effect at a square's edges), which takes the t-test's power and not the ranks' (.heldout.units_test)
        p = effect_held_out_test(data, base, fit, units=all_units, floor=floor, rank=counted >= opts.min_reduction)
        # and the total gap, all equations, must drop by the same test (an environment mismatch explaining its quiet
        # equation next to a motor equation full of stiction is no verdict); one removing min_reduction of the total
        # is asked there at the unsplit level, its own test keeping its share (J x 0.44: 82 %, p 0.0076 > 0.005)
        p_total = p if bool(np.all(own)) else held_out_test(base, fit, held_blocks, units=all_units, floor=floor,
                                                            rank=red >= opts.min_reduction)
        lowers_total = red > 0.0 and p_total < (opts.alpha if red >= opts.min_reduction else alpha_fit)
        sse = fit.gap_held_out ** 2 * n_held
        bic = n_held * math.log(max(sse / n_held, 1e-300)) + fit.n_params * math.log(n_held)
        assessment = assess_fit(data, fit)
        if fit.effect in HALF_BAND_CHECKED and assessment.identified and p < alpha_fit and lowers_total:
            assessment = persists_in_half_band(data, fit, assessment)     # a refit: only where it can decide
            # the encoders' quantisation, not an effect: in a pair too
            if not assessment.identified:
                in_band_only.add(fit.effect)
        passes = bool(p < alpha_fit and assessment.identified and lowers_total)
        # a clear verdict's size whose held-out test stops short of its level: replicas may name it (.replicas)
        short = bool(not passes and counted >= opts.min_reduction and red > 0.0 and max(p, p_total) < PROBABLE_P
                     and assessment.identified)
        if short and fit.effect in HALF_BAND_CHECKED:
            assessment = persists_in_half_band(data, fit, assessment)
            short = assessment.identified
        ranked.append(RankedCandidate(effect=fit.effect, gap_after=fit.gap_held_out,
                                      reduction=float(min(max(red, 0.0), 1.0)), params=fit.params,
                                      p_value=p, bic=bic, assessment=assessment, reduction_own=red_own,
                                      equations=tuple(eq for k, eq in enumerate(data.equations)
                                                      if own[k * data.t.size]),
                                      significant=passes and counted >= opts.min_reduction,
                                      weak=passes and 0.0 < counted < opts.min_reduction,
                                      explained_rms=explained, accuracy=accuracy,
                                      withheld_by_accuracy=passes and red_own > 0.0 and counted == 0.0,
                                      level=alpha_fit, n_units=int(all_units.max()) + 1, short_of_level=short))
    # an effect outside the motor equation (an environment mismatch; backlash read by a torque sensor, in the coupling):
    # where a motor-equation candidate passing the test removes more of the total gap, it lies in the motor equation
    # (six environment verdicts: 47-95 % of a quiet equation, 0.3-10 % of the total, beside a friction, gain or cogging
    # removing 11-37 %; a backlash: 59 % of the coupling, 0.6 % of the total, beside a torque gain removing 37 %)
    motor = max((r.reduction for r in ranked if r.p_value < alpha and "motor" in r.equations), default=0.0)
    demoted = [r for r in ranked if "motor" not in r.equations and r.significant and r.reduction < motor]
    ranked = [dataclasses.replace(r, significant=False) if r in demoted else r for r in ranked]
    caveats: list[str] = [f"Not counted: '{r.effect}' explains {100 * r.reduction_own:.0f} % of the {' and '.join(r.equations)} "
                          f"equation but {100 * r.reduction:.0f} % of the total gap, less than a motor-equation "
                          f"candidate ({100 * motor:.0f} %): the gap lies in the motor equation." for r in demoted]
    ranked.sort(key=lambda r: (not r.significant, r.bic))
    by_effect = {str(f.effect): f for f in fits}
    winner = ranked[0] if ranked and ranked[0].significant else None
    stiction = next((r for r in ranked if r.effect is Effect.STICTION and r.significant), None)
    if winner is not None and winner.effect is Effect.COULOMB and stiction is not None \
            and richer_law_justified(data, by_effect[str(Effect.STICTION)], by_effect[str(Effect.COULOMB)]):
        # the BIC over every row cannot weigh a breakaway held for milliseconds of a few stays (coulomb 30 %,
        # stiction 29 % of the gap): the nested rule decides between the laws, as where stiction ranks first
        # (asked only there, it named coulomb on nine stiction logs of 8,460 it justified)
        winner = stiction
        ranked.remove(winner)
        ranked.insert(0, winner)
    elif winner is not None and winner.effect in (Effect.STICTION, Effect.POSITION_FRICTION):
        coul = next((r for r in ranked if r.effect is Effect.COULOMB), None)
        richer, simpler = by_effect[str(winner.effect)], by_effect.get(str(Effect.COULOMB))
        # where coulomb is resolved (clear or weak) the richer law must beat it on the held-out data: its margin
        # over a weak coulomb is no evidence (a coulomb log: coulomb 37 %, LuGre 42 % with one-count bristles,
        # nested p = 0.64); where coulomb is not, it must still resolve its extra terms (an effect-free
        # closed-loop square: a 1.8 mN m "stiction", dF at Wald p = 0.8)
        if coul is not None and (coul.significant or coul.weak):
            keep = richer_law_justified(data, richer, simpler)
        else:
            keep = simpler is None or richer_law_resolved(data, richer, simpler)
        if not keep and coul is not None and coul.significant:
            winner = coul
            ranked.remove(coul)
            ranked.insert(0, coul)
        elif not keep:
            # the next candidate that counts, else the weak grade
            ranked[ranked.index(winner)] = dataclasses.replace(winner, significant=False)
            ranked.sort(key=lambda r: (not r.significant, r.bic))
            winner = ranked[0] if ranked[0].significant else None
    if winner is not None:
        simpler, extra = simplest_tied(data, winner, [r for r in ranked if r.significant], by_effect)
        if simpler is not winner:
            n_s, n_w = by_effect[str(simpler.effect)].n_params, by_effect[str(winner.effect)].n_params
            caveats.append(f"Tied: fitted on top of '{simpler.effect}' ({n_s} parameters), '{winner.effect}' "
                           f"({n_w}) removes {100 * max(extra, 0.0):.0f} % of what is left, below the "
                           f"{100 * opts.min_reduction:g} % a second effect needs: this log cannot tell them "
                           "apart, and the verdict is the one with fewer parameters.")
            winner = simpler
            ranked.remove(winner)
            ranked.insert(0, winner)
    st = next((r for r in ranked if r.effect is Effect.STICTION), None)
    if winner is not None and winner.effect is Effect.COULOMB and st is not None and not st.significant \
            and st.assessment is not None and st.p_value < st.level and st.reduction > winner.reduction \
            and not any(x.status in ("implausible", "at_bound") for x in st.assessment.status.values()) \
            and breakaway_proven_at_rest(data, by_effect[str(Effect.COULOMB)]):
        # levels the log does not separate are unidentified, not evidence against the law: a breakaway proven at the
        # raw rate decides (a 16-bit closed-loop square: stiction 95 % of the gap, coulomb 40 %, F_c at Wald p = 0.36)
        caveats.append(f"Unresolved: the levels of 'stiction' are not separated by this log "
                       f"({'; '.join(st.assessment.reasons[:2]) or 'their intervals are wide'}); it is named for "
                       f"removing {100 * st.reduction:.0f} % of the gap against coulomb's {100 * winner.reduction:.0f} "
                       "% with a breakaway proven at rest: read its parameters' intervals, not their values.")
        winner = st
        ranked.remove(winner)
        ranked.insert(0, winner)
    location = locate_gap(data, base.residual)
    span = dict(angle_span_rad=location.angle_span_rad, n_harmonics=opts.n_harmonics)
    tie = verdict_ties(ranked, winner, **span)
    if tie:
        caveats.append(tie)
        winner = None
    iso = isolability(data, fits)
    jt = fit_joint(data, fits) if joint and fits else None
    secondary = None
    # an effect another reading explains as well joins no pair (a cogging over 6.5 mrad, tied, came back in one)
    joinable = {r.effect for r in ranked if r.effect not in in_band_only and not verdict_ties(ranked, r, **span)}
    pairable = [f for f in fits if f.effect in joinable]
    if winner is not None:
        secondary = _second_effect(data, by_effect[str(winner.effect)], pairable, gap0, n_held, held_blocks, alpha)
    else:
        # Two effects of similar size (none counts alone): the three best as a first step; a pair counts (_second_effect)
        best_pair = None
        for first in [r for r in ranked if r.reduction > 0.0 and r.effect not in in_band_only and r.assessment
                      and not any(st.status == "implausible" for st in r.assessment.status.values())][:3]:
            if first.effect not in joinable:   # tied: not tried, its place among the three not given to another
                continue
            pair = _second_effect(data, by_effect[str(first.effect)], pairable, gap0, n_held, held_blocks, alpha,
                                  min_extra=0.5 * opts.min_reduction, base=base)
            if pair is not None and pair.reduction >= opts.min_reduction and \
                    (best_pair is None or pair.bic < best_pair[1].bic):
                best_pair = (first, pair)
        if best_pair is not None and best_pair[0].effect in (Effect.STICTION, Effect.POSITION_FRICTION):
            # the same parsimony between nested friction laws as for a single effect
            coul = next((r for r in ranked if r.effect is Effect.COULOMB), None)
            if coul is not None:
                f_w = fit_pair(data, by_effect[str(best_pair[0].effect)], best_pair[1].effect)
                f_c = fit_pair(data, by_effect[str(Effect.COULOMB)], best_pair[1].effect)
                if f_w is not None and f_c is not None and not richer_law_justified(data, f_w, f_c):
                    alt = _second_effect(data, by_effect[str(Effect.COULOMB)], pairable, gap0, n_held, held_blocks,
                                         alpha, min_extra=0.5 * opts.min_reduction, base=base)
                    if alt is not None and alt.reduction >= opts.min_reduction:
                        best_pair = (coul, alt)
        if best_pair is not None:
            winner, secondary = best_pair
            alone = next((r for r in ranked if r.effect is secondary.effect), None)
            if alone is not None and alone.reduction > winner.reduction:
                # forward selection may only reach the pair from the smaller effect (the larger one
                # leaves too little for the smaller to add): the verdict names the larger
                winner, secondary = alone, dataclasses.replace(secondary, effect=winner.effect)
            ranked.insert(0, ranked.pop(ranked.index(winner)))
    replicas = None
    if winner is not None and (not winner.significant or secondary is None and winner.reduction < opts.min_reduction):
        # clear only above the encoders' floor, or a pair no single effect made: it must stand above what the sensors
        # alone produce (.replicas; an effect-free closed loop with a torque sensor: stiction of 0.9 mN m, not
        # resolved alone, with a gain of 0.958, the stiction 0.96 times its replicas')
        replicas = replica_check(data, base, by_effect[str(winner.effect)])
        if replicas is not None and not replicas.distinct:
            caveats.append(replicas.caveat() if secondary is None else
                           replicas.caveat(f"neither it nor the pair with {secondary.effect} is named"))
            winner = secondary = None
    grade = "none" if winner is None else "clear"
    if winner is None:
        # an effect the log resolves (held-out test, identified, the torque accuracy, the total gap lowered)
        # but that explains less than min_reduction: the verdict, graded weak
        aside = {r.effect: weak_set_aside(data, r, by_effect[str(r.effect)], base, iso) for r in ranked if r.weak}
        weak = sorted((r for r in ranked if r.weak and not aside[r.effect] and not verdict_ties(ranked, r, **span)),
                      key=lambda r: r.bic)
        if weak and weak[0].effect in (Effect.STICTION, Effect.POSITION_FRICTION):
            coul = next((r for r in weak if r.effect is Effect.COULOMB), None)
            richer, simpler = by_effect[str(weak[0].effect)], by_effect[str(Effect.COULOMB)]
            if coul is not None and not richer_law_justified(data, richer, simpler):
                weak.remove(coul)
                weak.insert(0, coul)
            elif coul is None and not richer_law_resolved(data, richer, simpler):
                # as a clear one: with coulomb not resolved, its extra terms must be (an effect-free 14-bit square:
                # the Coulomb level the quantisation, F_s 0.10 +- 0.14 N m, a weak stiction)
                weak.pop(0)
        # only what stands above what the sensors alone produce (.replicas)
        replicas = replica_check(data, base, by_effect[str(weak[0].effect)]) if weak else replicas
        if weak and replicas is not None and not replicas.distinct:
            caveats.append(replicas.caveat())
        elif weak:
            winner, grade = weak[0], "weak"
            ranked.insert(0, ranked.pop(ranked.index(winner)))
            caveats.append(weak_caveat(winner, replicas, opts.min_reduction))
        probable = None if winner is not None else probable_verdict(data, ranked, base, by_effect, span)
        if probable is not None:
            (winner, replicas), grade = probable, "probable"
            ranked.insert(0, ranked.pop(ranked.index(winner)))
            caveats.append(probable_caveat(winner, replicas))
        caveats += [why for why in aside.values() if why and winner is None]
    # a Coulomb verdict on encoders too coarse for the equation errors to see a Stribeck bump: the trajectory around
    # the reversals decides between the laws (.reversals; 9 of 72 stiction logs named coulomb there, no Coulomb log)
    reversals = reversal_test(data, by_effect[str(Effect.COULOMB)]) if winner is not None and secondary is None \
        and winner.effect is Effect.COULOMB and st is not None else None
    if reversals is not None and reversals.names_stiction:
        caveats.append(reversals.caveat())
        ranked.remove(st)
        winner = dataclasses.replace(st, params=reversals.params, assessment=reversals.assessment())
        ranked.insert(0, winner)
    if winner is not None and winner.effect is Effect.STICTION and str(Effect.COULOMB) in by_effect \
            and breakaway_proven_at_rest(data, by_effect[str(Effect.COULOMB)]):
        caveats.append("Stiction over coulomb: while the encoder read one count the motor held net torques that would "
                       "have moved it by more under any Coulomb level (a breakaway proven at the raw rate).")
    shift: dict[str, float] = {}
    freed: dict[str, float] = {}
    by_trajectory = reversals is not None and reversals.names_stiction     # its intervals are the folds' (.reversals)
    if winner is not None and winner.assessment is not None and not by_trajectory:
        # the verdict's intervals carry the analysis' own error (the filter's), as the friction fit's do
        shift = method_shift(data, by_effect[str(winner.effect)])
        # and what a re-calibration held on its bounds hid of them (a level traded with viscous friction)
        freed = calibration_freedom(data, by_effect[str(winner.effect)])
        both = {k: math.hypot(shift.get(k, 0.0), freed.get(k, 0.0)) for k in {*shift, *freed}}
        widened = dataclasses.replace(winner, assessment=with_method_error(winner.assessment, both))
        ranked[ranked.index(winner)] = widened
        winner = widened
        if freed:
            held = calibration_on_bound(data, by_effect[str(winner.effect)])
            caveats.append(f"Caution: the fit of '{winner.effect}' holds its re-calibrated {' and '.join(held)} on "
                           f"{'a bound' if len(held) == 1 else 'their bounds'} "
                           f"(d_m >= 0, J_m and the spring scale within +-{100 * opts.calibration_tolerance:g} %): its "
                           "parameters' intervals are widened by what that freedom would move them "
                           "(verdict.std_calibration_bound).")
    if winner is None:
        eff, gap_after, params = Effect.NONE, gap0, {}
    else:
        eff, gap_after, params = winner.effect, winner.gap_after, winner.params
    caveats += computed_caveats(data, eff, ranked, iso, base, opts, by_effect.get(str(eff), base),
                                secondary and secondary.effect, None if by_trajectory else by_effect.get("coulomb"))
    if location.single_tone:
        caveats.append(f"Caution: the command is essentially one sine at {location.tone_hz:.2g} Hz; there a delay "
                       "looks like extra motor damping and a torque_gain like a J_m/k rescaling, so delay, "
                       "torque_gain and a re-calibration cannot be told apart: "
                       f"'{eff}' is one reading of this log, not a unique one.")
    reduction = float(min(max(1.0 - gap_after / gap0, 0.0), 1.0)) if gap0 > 0 else 0.0
    replay = replay_check(data, by_effect.get(str(eff), base))   # none: the calibrated nominal model
    return Diagnosis(effect=eff, gap_before=gap0, gap_after=gap_after, reduction=reduction, params=params,
                     metric=metric_text(data), location=location, ranking=tuple(ranked), joint=jt,
                     caveats=tuple(caveats), baseline=base, fits=by_effect, data=data, secondary=secondary,
                     replay=replay, isolability=iso, calibration=calibration_status(data, base, viscous=True), grade=grade,
                     method_shift=shift, calibration_freedom=freed, replicas=replicas, reversals=reversals)


def _second_effect(data: GapData, first: CandidateFit, fits: list[CandidateFit], gap0: float, n_held: int,
                   held_blocks: np.ndarray, alpha: float, min_extra: float | None = None,
                   base: CandidateFit | None = None) -> RankedCandidate | None:
    """Forward selection, one step: the best effect fitted together with the winner, if it counts."""
    opts = data.options
    best: RankedCandidate | None = None
    passing: dict[str, tuple[RankedCandidate, CandidateFit]] = {}
    held_rows = data.stacked(data.held_out)
    for fit in fits:
        pair = fit_pair(data, first, fit.effect)
        if pair is None:
            continue
        extra = 1.0 - pair.gap_held_out / first.gap_held_out if first.gap_held_out > 0 else 0.0
        units = test_units(data, pair)
        p = held_out_test(first, pair, held_blocks, units=units)
        sse = pair.gap_held_out ** 2 * n_held
        bic = n_held * math.log(max(sse / n_held, 1e-300)) + pair.n_params * math.log(n_held)
        need = opts.min_reduction if min_extra is None else min_extra
        # with no single winner, the pair must also beat the nominal model by the test
        p_base = held_out_test(base, pair, held_blocks, units=units) if base is not None else 0.0
        # with no single winner, the pair must also explain the motor's torque accuracy on its own
        explains = base is None or explained_rms(base, pair, held_rows) >= data.torque_accuracy
        if extra >= need and p < alpha and p_base < alpha and explains and (best is None or bic < best.bic):
            assessment = assess_fit(data, pair)
            if not assessment.identified:
                continue
            red = 1.0 - pair.gap_held_out / gap0 if gap0 > 0 else 0.0
            best = RankedCandidate(effect=fit.effect, gap_after=pair.gap_held_out,
                                   reduction=float(min(max(red, 0.0), 1.0)), params=pair.params, p_value=p,
                                   bic=bic, significant=True, assessment=assessment)
            passing[str(fit.effect)] = (best, pair)
    if best is not None and best.effect in (Effect.STICTION, Effect.POSITION_FRICTION):
        coul = passing.get(str(Effect.COULOMB))
        if coul is None:
            pair_c = fit_pair(data, first, Effect.COULOMB)
            p_c = held_out_test(first, pair_c, held_blocks, units=test_units(data, pair_c)) if pair_c else 1.0
            if pair_c is not None and p_c < alpha:
                red = 1.0 - pair_c.gap_held_out / gap0 if gap0 > 0 else 0.0
                sse = pair_c.gap_held_out ** 2 * n_held
                bic = n_held * math.log(max(sse / n_held, 1e-300)) + pair_c.n_params * math.log(n_held)
                coul = (RankedCandidate(effect=Effect.COULOMB, gap_after=pair_c.gap_held_out,
                                        reduction=float(min(max(red, 0.0), 1.0)), params=pair_c.params,
                                        p_value=p_c, bic=bic, significant=True,
                                        assessment=assess_fit(data, pair_c)), pair_c)
        if coul is not None and coul[0].identified and \
                not richer_law_justified(data, passing[str(best.effect)][1], coul[1]):
            best = coul[0]
    return best
