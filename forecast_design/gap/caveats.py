"""Caveats a diagnosis computes from its log: what the verdict cannot tell apart, and what it did not count.

Each caveat is one sentence of the diagnosis JSON's ``caveats``, starting with its kind (``Caution``,
``Assumed``, ``Not identified``, ``Not proven``, ``Not proven at rest``, ``Below accuracy``, ``Parsimony``, ``Close``,
``Note``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..effects import Effect
from .candidates import CandidateFit, fit_constant_torque, levels_shared
from .grading import CONSTANT_TORQUE_SHARE
from .heldout import BREAKAWAY_MARGIN, breakaway_proven_at_rest, breakaway_resolved_at_rest
from .identifiability import calibration_status
from .isolability import CALIBRATION, Isolability
from .residuals import GapData, GapOptions, gap_log_scales
from .structures import _FRICTION, j_held

__all__ = ["computed_caveats", "COARSE_ENCODER_FRACTION", "VISCOUS_SHIFT_FACTOR"]


#: Spring-torque resolution ``k x encoder step``, as a fraction of the RMS command, above which a
#: diagnosis warns that the log is coarser than its validation [-] (2,000,000 counts: ~2e-4).
COARSE_ENCODER_FRACTION = 2e-3

#: Factor by which the re-calibrated viscous friction ``d_m`` may differ from the declared one (either way) before a
#: diagnosis says so: ``d_m`` has no datasheet tolerance (only ``d_m >= 0``), and what it absorbs is no verdict [-].
VISCOUS_SHIFT_FACTOR = 2.0


def computed_caveats(data: GapData, verdict: Effect, ranked: Sequence[Any], iso: Isolability,
                      base: CandidateFit, opts: GapOptions, chosen: CandidateFit | None = None,
                      secondary: Effect | None = None, coulomb: CandidateFit | None = None) -> list[str]:
    """Caveats computed from this log: isolability, unidentified candidates, a bounded re-calibration.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    verdict : Effect
        The verdict (``Effect.NONE`` for none).
    ranked : sequence of RankedCandidate
        The diagnosis' ranking.
    iso : Isolability
        Which candidates the log tells apart.
    base : CandidateFit
        The calibrated nominal model.
    opts : GapOptions
        The diagnosis' options.
    chosen : CandidateFit, optional
        The verdict's fit.
    secondary : Effect, optional
        The second effect named with the verdict (no rival of it).
    coulomb : CandidateFit, optional
        The coulomb fit, beside a stiction verdict read from the equation errors (not from the reversals'
        trajectories, which say how they decide): whether any stay at rest shows its breakaway.

    Returns
    -------
    list of str
        One sentence per caveat.
    """
    out: list[str] = []
    words: list[str] = []
    if verdict is not Effect.NONE:
        confused = iso.confusable_with(str(verdict))
        words = [w for w in confused if w != CALIBRATION]
        if words:
            out.append(f"Caution: this log cannot tell '{verdict}' from {', '.join(repr(w) for w in words)} "
                       f"(feature separation below {iso.threshold:g} on held-out data).")
        if CALIBRATION in confused:
            out.append(f"Caution: '{verdict}' acts in the same direction as a re-calibration of J_m, d_m and k; it "
                       f"is named because that re-calibration is limited to the datasheet tolerance "
                       f"(+-{100 * opts.calibration_tolerance:g} %): nominal values off by more would look the same.")
    if chosen is not None and levels_shared(chosen):
        out.append(f"Assumed: one {verdict} level for both directions of motion (F_c_neg = F_c); a level per "
                   "direction predicted the held-out data worse (this log hardly moves one way).")
    if chosen is not None and j_held(chosen.params):
        out.append("Assumed: the environment's J at its declared value, not estimated: fitted, it came out below a "
                   "tenth of it, the output encoder's quantisation in q'' (errors in variables), so only d and k_e "
                   "are fitted.")
    named = next((r for r in ranked if r.effect is verdict), None)
    out += _close_rivals(named, ranked, words, opts, secondary)
    if verdict is Effect.STICTION and chosen is not None and coulomb is not None \
            and not (breakaway_proven_at_rest(data, coulomb) or breakaway_resolved_at_rest(data, chosen, coulomb)):
        # Coulomb friction has been named stiction this way (9 of 320 fresh Coulomb logs): the sticking phases of a
        # closed-loop square read by presliding bristles or a small bump, reversals a 14-bit encoder does not resolve
        out.append("Not proven at rest: 'stiction' is named for what its Stribeck bump or presliding bristles explain "
                   "while the motor moves; no stay at rest shows a breakaway above the Coulomb level, and Coulomb "
                   "friction read through a closed loop's sticking phases or a coarse encoder's reversals can look "
                   "the same: read F_s - F_c with its interval.")
    for r in ranked:
        if verdict is Effect.COULOMB and named is not None and r.effect in (Effect.STICTION, Effect.POSITION_FRICTION) \
                and r.significant and r.reduction > named.reduction:
            # the nested-law rule (.heldout.richer_law_justified) chose the simpler law: say what it set aside
            out.append(f"Parsimony: '{r.effect}' removes {100 * r.reduction:.0f} % of the gap against coulomb's "
                       f"{100 * named.reduction:.0f} %, but the nested-law rule does not justify it (it must resolve "
                       f"what it adds: a breakaway more than {100 * BREAKAWAY_MARGIN:g} % above the Coulomb level, "
                       "bristles wider than one count holding it, or angle harmonics; and beat coulomb on the held-out "
                       "units, or show its breakaway at rest): the verdict is the simpler law.")
        if r.effect is not verdict and r.assessment is not None and not r.assessment.identified \
                and r.reduction >= opts.min_reduction:
            out.append(f"Not identified: '{r.effect}' would remove {100 * r.reduction:.0f} % of the gap but "
                       f"{'; '.join(r.assessment.reasons[:2])}.")
        elif r.effect is not verdict and r.identified and r.reduction >= opts.min_reduction \
                and not r.significant and not r.weak and r.p_value >= r.level:
            # a large, identified reduction the held-out test does not prove (few units, or an improvement
            # concentrated in a few of them: a delay on the edges of a slow square) is no verdict, but it is said
            out.append(f"Not proven: '{r.effect}' is identified and removes {100 * r.reduction:.0f} % of the gap, but "
                       f"its held-out test over {r.n_units} units gives p = {r.p_value:.2g}, above its level "
                       f"{r.level:.2g}: this log does not prove it (a longer log, or one with more of the motion "
                       "where it acts, would decide).")
        elif r.withheld_by_accuracy:
            what = ("the accuracy of the spring torque its equation holds" if r.effect is Effect.ENVIRONMENT_MISMATCH
                    else "the quantisation of the spring torque it acts on" if r.accuracy > data.torque_accuracy else
                    f"{100 * opts.min_effect_fraction:g} % of the RMS command, a motor's torque accuracy")
            out.append(f"Below accuracy: '{r.effect}' passes the held-out test (p = {r.p_value:.2g}) and removes "
                       f"{100 * r.reduction_own:.0f} % of the gap of its equations, but the torque it explains, "
                       f"{r.explained_rms:.2g} N m RMS, is below {r.accuracy:.2g} N m ({what}): not counted.")
    resolution = data.experiment.design.testbed.k * gap_log_scales(data).encoder_step
    tau_rms = data.command_rms
    if tau_rms > 0 and resolution > COARSE_ENCODER_FRACTION * tau_rms:
        out.append(f"Caution: the encoders resolve the spring torque k (theta - q) in steps of {resolution:.2g} N m "
                   f"({100 * resolution / tau_rms:.2g} % of the RMS command, above the "
                   f"{100 * COARSE_ENCODER_FRACTION:g} % the diagnosis is validated at): on such logs it misses most "
                   "delays and in a few percent of set-ups names a wrong effect (environment_mismatch, cogging).")
    if verdict is Effect.COGGING and chosen is not None and chosen is not base and base.gap_held_out > 0:
        # over a fraction of a revolution the harmonics make a constant: how much of what cogging
        # removes does a constant motor torque remove?
        const = fit_constant_torque(data)
        r_cog = 1.0 - chosen.gap_held_out / base.gap_held_out
        r_const = 1.0 - const.gap_held_out / base.gap_held_out
        if r_cog > 0 and r_const >= CONSTANT_TORQUE_SHARE * r_cog:
            span = float(np.ptp(data.columns["theta_sub"]))
            encoders = "" if data.tau_s_measured else (", or zero offsets of the encoders (homed with the spring "
                                                       "loaded, so that k (theta - q) is off by a constant)")
            out.append(f"Caution: over this log's {span:.2g} rad of motor travel a constant motor torque of "
                       f"{const.params['torque_N_m']:+.3g} N m removes {100 * r_const:.0f} % of the gap, against "
                       f"{100 * r_cog:.0f} % for cogging: a current driver's offset{encoders} would look the same.")
    offset = (chosen or base).calibration.get("tau_s_offset_N_m")     # the verdict's own calibration
    peak = float(np.max(np.abs(data.columns["tau_s"])))
    if offset is not None and abs(offset) > opts.calibration_tolerance * peak:
        out.append(f"Note: the torque sensor's zero offset, {-offset:+.3g} N m ({100 * abs(offset) / peak:.2g} % "
                   "of the peak |tau_s|), is calibrated out, not blamed on an effect.")
    d_m, d_m_declared = (chosen or base).calibration.get("d_m"), data.experiment.design.testbed.d_m
    if d_m is not None and d_m_declared > 0 and not 1.0 / VISCOUS_SHIFT_FACTOR <= d_m / d_m_declared <= VISCOUS_SHIFT_FACTOR:
        absorbed = ("an effect acting like viscous friction at this log's speeds is absorbed in it (a Coulomb level "
                    "on a log that moves at nearly one speed)" if d_m > d_m_declared else
                    "it absorbs an effect that cancels damping (a delay in a closed loop, at this log's frequencies)")
        out.append(f"Caution: the re-calibrated viscous friction d_m = {d_m:.3g} N m s/rad is {d_m / d_m_declared:.2g} x "
                   f"the declared {d_m_declared:.3g} (it is bounded below by zero only): the declared d_m is off, or "
                   f"{absorbed}.")
    at_bound = [k for k, st in calibration_status(data, base).items() if st.status == "at_bound"]
    if at_bound:
        out.append(f"Caution: the nominal re-calibration of {', '.join(at_bound)} sits on its datasheet bound "
                   f"(+-{100 * opts.calibration_tolerance:g} %): the nominal model is off by more than the tolerance, "
                   "or an effect acting in the same direction (e.g. torque_gain) is being absorbed.")
    return out


def _close_rivals(named: Any, ranked: Sequence[Any], confused: Sequence[str], opts: GapOptions,
                  secondary: Effect | None) -> list[str]:
    """A clear verdict's rivals that pass every test too and leave hardly more of the gap than it does.

    The ranking names the lowest BIC, and the nested friction laws (Parsimony) and ``simplest_tied``
    (a richer verdict that adds nothing to a simpler one) settle some near ties; what they leave is a
    simpler verdict beside a rival that explains almost as much. Where the rival leaves less than
    ``1 / (1 - min_reduction)`` times the verdict's remaining gap, the two differ by less than a second
    effect must remove to be named, and the log tells them apart by that margin only: a constant-amplitude
    square in open loop, where a Coulomb level acts as a torque gain while the motor slides (coulomb
    98.4 % of the gap against a gain's 98.7 %, the truth Coulomb; the other way round on another log).
    """
    if named is None or not named.significant:
        return []
    out = []
    for r in ranked:
        if r is named or not r.significant or r.effect is secondary or str(r.effect) in confused \
                or (r.effect in _FRICTION and named.effect in _FRICTION):
            continue
        if r.gap_after * (1.0 - opts.min_reduction) <= named.gap_after:
            out.append(f"Close: '{r.effect}' passes every test too and removes {100 * r.reduction:.1f} % of the gap "
                       f"against {100 * named.reduction:.1f} % for '{named.effect}': the two leave gaps that differ "
                       f"by less than the {100 * opts.min_reduction:g} % a second effect must remove, so this log "
                       f"tells them apart by that margin only; read both as readings of it.")
    return out
