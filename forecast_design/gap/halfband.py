"""Whether a diagnosis candidate's effect persists in half the equation band.

The equation errors are kept up to a band chosen for the motor equation's quantisation
(:func:`.residuals.equation_band`); twice-differentiated quantisation grows with the band as ``f^2.5``, and some
candidates can fit it: an environment's inertia shrunk by the output encoder's noise in ``q''``, a closed loop's
delayed answer to the encoders' noise, a friction level of a few millinewton metres, a torque gain taking up a
shrunk ``J_m``. A physical effect keeps its size when the analysis is repeated in half the band; those do not
(:func:`persists_in_half_band`).
"""

from __future__ import annotations

import dataclasses

from ..effects import Effect
from .candidates import CandidateFit, fit_baseline
from .grading import floor_rms
from .heldout import effect_held_out_test
from .identifiability import EffectAssessment, assess_fit, calibration_status, refit_prepared_again
from .residuals import GapData

__all__ = ["persists_in_half_band", "HALF_BAND_CHECKED", "HALF_BAND_ALPHA"]


#: Level of the held-out test a delay must pass in half the band [-]: a check that the effect has not gone, looser
#: than the detection's ``alpha`` (true delays of thirty-four seeds at scales 1 and 0.25: 687 of 689 below 0.05,
#: 682 below 0.01; the effect-free log below gave 0.12).
HALF_BAND_ALPHA = 0.05

#: Effects whose fit can explain the encoders' quantisation at the top of the band, checked in half of it.
HALF_BAND_CHECKED = (Effect.ENVIRONMENT_MISMATCH, Effect.DELAY, Effect.COULOMB, Effect.STICTION, Effect.TORQUE_GAIN)


def persists_in_half_band(data: GapData, fit: CandidateFit, assessment: EffectAssessment) -> EffectAssessment:
    """An environment mismatch, a delay, a friction level or a torque gain that does not persist in half the band is not identified.

    Quantisation, differentiated twice, grows with the band as ``f^2.5``, and these fits can "explain" it:

    * the environment equation reads the output's acceleration ``q''``: on a coarse output encoder least squares
      shrinks ``J`` (errors in variables: effect-free 14- and 16-bit logs in a stiff environment fitted ``J`` at
      0.12-0.69 of the declared value, 0.92-1.0 with the band halved, while every true mismatch of seven seeds
      kept its value within a few percent). A scale's deviation persists when, in half the band, it keeps its
      sign, at least half its size and more than the spring torque's datasheet tolerance -- or does so from half
      to a quarter of the band and stands out of its noise there (the full band's value may carry the
      quantisation's bias itself);
    * in a closed loop the command answers the encoders' noise a few milliseconds later, so a delayed command
      correlates with it (an effect-free 14-bit closed-loop chirp: 11.6 ms at coefficient 0.47; in half the band
      20 ms, the search's end, at 0.04), and in an open loop it can fit the quantisation too (an effect-free 16-bit
      sweep: 1.29 ms at coefficient 1.50). The delay's effective size, coefficient times delay, persists when in
      half the band it is within a factor 2 and the refit there stops short of the search's end (true delays of
      four seeds: within 1.5, most within 1 %);
    * a friction level of a few millinewton metres on an effect-free 16-bit log (1.7 mN m; in half the band
      0.1 mN m, while true levels of 0.04-0.12 N m moved by at most 5 %) must keep at least half its size: the
      Coulomb level of a coulomb or a stiction fit (an effect-free 2^21-count closed-loop square: a "stiction" of
      F_s 4.7 mN m over F_c 0.9 mN m, F_c gone in half the band), unless it is beyond three times the
      quantisation floor, which no projection of the floor onto a sign feature reaches;
    * a torque gain whose fit takes up what the quantisation does to ``J_m theta''`` (an effect-free 16-bit log,
      k = 145: 0.987 with J_m on its datasheet bound, 0.999 in half the band) must keep the sign of its
      deviation from 1 and at least half its size, or stay beyond the re-calibration's tolerance; one within the
      tolerance, told from a re-calibration only by the nominal model's re-calibration on its bound, must find it
      on its bound there too (an effect-free 16-bit multisine: 0.9931 with J_m on its bound, 1.7 % inside it there).

    Before any of these, the refit must lower the held-out gap in half the band below the nominal model's there: an
    effect-free 16-bit closed-loop multisine (k = 145) kept a "delay" of 3.10 ms x coefficient there (4.47 in the
    full band, "within a factor 2") while its refit raised that gap.

    The candidate is refitted on the log prepared with half the decimated rate.

    Parameters
    ----------
    data : GapData
        The prepared log.
    fit : CandidateFit
        Its environment_mismatch, delay, coulomb, stiction or torque_gain fit.
    assessment : EffectAssessment
        That fit's assessment.

    Returns
    -------
    EffectAssessment
        The same, or not identified with the values in both bands as the reason; unchanged when the log is too
        short for half the band or the effect is not one of :data:`HALF_BAND_CHECKED`.
    """
    if fit.effect not in HALF_BAND_CHECKED:
        return assessment
    if fit.effect in (Effect.COULOMB, Effect.STICTION) and _beyond_quantisation(data, fit):
        return assessment
    half = _refit_in_band(data, fit, 0.5)
    if half is None:
        return assessment
    refit = half[1]
    # an effect must still explain the log in half the band: a closed loop's answer to the encoders' noise kept its
    # size there (an effect-free 16-bit chirp, k = 145: coefficient x delay 4.47 -> 3.10 ms) while its refit raised
    # the held-out gap (0.00324 -> 0.00336 N m) and vanished in a quarter of the band
    base_half = fit_baseline(half[0])
    if refit.gap_held_out >= base_half.gap_held_out:
        why = (f"the {fit.effect} does not reduce the held-out gap in half the equation band "
               f"({base_half.gap_held_out:.4g} -> {refit.gap_held_out:.4g}): the encoders' quantisation, not an effect")
        return dataclasses.replace(assessment, identified=False, reasons=tuple(assessment.reasons) + (why,))
    if fit.effect is Effect.DELAY:
        # and a delay must still pass a held-out test there: an effect-free 14-bit closed-loop multisine's "delay"
        # (1.21 ms at coefficient 1.48) came back as 12.3 ms at 0.08 in half the band, coefficient x delay "within
        # a factor 2", p = 0.12
        p_half = effect_held_out_test(half[0], base_half, refit)
        if not p_half < HALF_BAND_ALPHA:
            why = (f"the delay is not significant in half the equation band (held-out test p = {p_half:.2g}): "
                   "the encoders' quantisation, not a delay")
            return dataclasses.replace(assessment, identified=False, reasons=tuple(assessment.reasons) + (why,))
    if fit.effect in (Effect.COULOMB, Effect.STICTION):
        a, b = _friction_level(fit), _friction_level(refit)
        if b >= 0.5 * a:
            return assessment
        why = (f"the friction level does not persist in half the equation band ({a:.3g} -> {b:.3g} N m): the "
               "encoders' quantisation, not friction")
    elif fit.effect is Effect.TORQUE_GAIN:
        tol = data.options.calibration_tolerance
        if abs(1.0 - fit.params["gain"]) <= tol and not any(
                st.status == "at_bound" for st in calibration_status(half[0], base_half).values()):
            # a gain within the tolerance is told from a re-calibration only by the nominal model's re-calibration
            # sitting on its bound; the encoders' quantisation shrinks J_m onto it (an effect-free 16-bit
            # multisine, k = 145: 0.9931 with J_m on its -3 % bound, 1.7 % inside it in half the band): that bound
            # must hold there too
            why = (f"the torque gain {fit.params['gain']:.4g} is within the re-calibration's tolerance and the "
                   "re-calibration leaves its datasheet bound in half the equation band: the encoders' quantisation, "
                   "not a gain")
            return dataclasses.replace(assessment, identified=False, reasons=tuple(assessment.reasons) + (why,))
        # the gain trades with the re-calibration of J_m, d_m and k, more so where quantisation biases them: true
        # gains of 0.969 and 0.967 fitted 0.930 and 0.922 in the full band, 0.969 and 0.966 in half of it. Beyond
        # the re-calibration's tolerance there, the gain is one
        a, b = (1.0 - f.params["gain"] for f in (fit, refit))
        if a * b > 0.0 and (abs(b) >= 0.5 * abs(a) or abs(b) > tol):
            return assessment
        why = (f"the torque gain does not persist in half the equation band ({1.0 - a:.4g} -> {1.0 - b:.4g}): "
               "the encoders' quantisation, not a gain")
    elif fit.effect is Effect.DELAY:
        a, b = (float(f.coef[f.n_cal]) * f.params["delay_s"] for f in (fit, refit))
        # a refit that runs to the search's end has not found a delay there (an effect-free 16-bit open-loop sweep:
        # 1.29 ms at coefficient 1.50, in half the band 20 ms, the end, at 0.17: "within a factor 2"; none in a quarter)
        _, d_half, _, d_end = next(g for g in refit.structure.grid if g[0] == "delay_s")
        at_end = d_half >= d_end * (1.0 - 1e-9)
        if a > 0.0 and 0.5 * a <= b <= 2.0 * a:
            if not at_end:
                return assessment
            # along the ridge of a delay short against the band the refit may slide to the end and keep
            # coefficient x delay (true 4.52 ms: 5.82 -> 5.14 ms at 20 ms): it must then hold in a quarter of the band
            quarter = _refit_in_band(data, fit, 0.25)
            c = None if quarter is None else float(quarter[1].coef[quarter[1].n_cal]) * quarter[1].params["delay_s"]
            if c is None or 0.5 * a <= c <= 2.0 * a:
                return assessment
        source = "a closed loop's answer to the encoders' noise" if data.experiment.design.controller is not None \
            else "the encoders' quantisation"
        why = (f"the delay does not persist in half the equation band (coefficient x delay {1e3 * a:.3g} -> "
               f"{1e3 * b:.3g} ms{', the search at its end' if at_end else ''}): "
               f"{source}, not a delay")
    else:
        tol = data.options.calibration_tolerance
        pairs = [(k, fit.params[k], refit.params[k]) for k in ("J_scale", "d_scale", "k_e_scale")
                 if k in fit.params and k in refit.params]
        def persists(a: float, b: float) -> bool:
            return (a - 1.0) * (b - 1.0) > 0.0 and abs(b - 1.0) >= max(0.5 * abs(a - 1.0), tol)

        if any(persists(a, b) for _, a, b in pairs):
            return assessment
        # the full band's value may itself carry the quantisation's bias (a true d x 0.921 at an eighth of the
        # usual size: 0.894 -> 0.949): a deviation that then holds from half to a quarter of the band is real
        quarter = _refit_in_band(data, fit, 0.25)
        if quarter is not None:
            # there on a few samples: the value must also stand out of its own noise, beyond the tolerance
            q_assessment = assess_fit(*quarter)
            status = q_assessment.status
            # and on the side the verdict reports: an effect-free 16-bit output's J, 0.13 x in the full band, was
            # 1.11 x and 4.2 x in half and a quarter of it (named environment_mismatch, weak, at 0.13)
            if any(persists(b, quarter[1].params[k]) and (a - 1.0) * (quarter[1].params[k] - 1.0) > 0.0
                   and status[k].std is not None
                   and abs(quarter[1].params[k] - 1.0) > 1.96 * (status[k].std - q_assessment.bias.get(k, 0.0))
                   + tol * abs(quarter[1].params[k])
                   for k, a, b in pairs if k in quarter[1].params and k in status):
                return assessment
        moved = ", ".join(f"{k} {a:.3g} -> {b:.3g}" for k, a, b in pairs)
        why = (f"the deviation does not persist in half the equation band ({moved}): the output encoder's "
               "quantisation in q'', not the environment")
    return dataclasses.replace(assessment, identified=False, reasons=tuple(assessment.reasons) + (why,))


def _beyond_quantisation(data: GapData, fit: CandidateFit) -> bool:
    """Whether a Coulomb level is beyond what the motor equation's quantisation can make of a sign feature.

    Least squares projects a noise of RMS ``sigma`` onto a feature of magnitude one with a coefficient of at most
    ``sigma`` (Cauchy-Schwarz); a level beyond three times the quantisation floor is no quantisation's making,
    and on a log whose motor is stuck most of the time the half band's refit loses the short slides themselves
    (true levels of 0.18-0.40 N m, 700-1,300 floors, fell to zero in half the band of 2^21-count squares).
    """
    motor = data.equations.index("motor") * data.t.size
    return _friction_level(fit) > 3.0 * float(floor_rms(data)[motor])


def _friction_level(fit: CandidateFit) -> float:
    """A coulomb or stiction fit's Coulomb level, the larger of the two directions' [N m]."""
    return max(fit.params["F_c"], fit.params.get("F_c_neg", 0.0))


def _refit_in_band(data: GapData, fit: CandidateFit, factor: float) -> tuple[GapData, CandidateFit] | None:
    """The log prepared with ``factor`` times the decimated rate and the candidate refitted on it (None: too short)."""
    dec = factor * data.settings.decimated_rate_hz
    return refit_prepared_again(data, fit, dataclasses.replace(
        data.options, decimated_rate_hz=dec, position_cutoff_hz=min(data.settings.position_cutoff_hz, dec)))
