"""The diagnosis's metric and decision rule, in words (JSON ``metric``)."""

from __future__ import annotations

from .heldout import BREAKAWAY_MARGIN, NESTED_ALPHA
from .replicas import N_REPLICAS, PROBABLE_P, REPLICA_MARGIN
from .residuals import GapData

__all__ = ["metric_text"]


def metric_text(data: GapData) -> str:
    """How the gap is measured and split, and the decision rule, in words (JSON ``metric``).

    Parameters
    ----------
    data : GapData
        The prepared log (its settings, options and equations).

    Returns
    -------
    str
        One paragraph.
    """
    o = data.options
    eqs = ", ".join(data.equations)
    return (f"RMS [N m] of the stacked equation errors ({eqs}) after the same zero-phase filtering of every "
            f"column ({data.settings.position_cutoff_hz:g} Hz Butterworth) and parallel decimation to "
            f"{data.settings.decimated_rate_hz:g} Hz, on held-out data: {o.n_blocks} interleaved time blocks, "
            f"parameters fitted on the even blocks and the gap measured on the odd ones. tau_s column: "
            f"{data.tau_s_source.source}. gap_before is the nominal model with J_m and the spring torque scale "
            f"re-calibrated within the datasheet tolerance +-{100 * o.calibration_tolerance:g} % and d_m >= 0. "
            f"An effect counts when it lowers the total held-out gap (all equations, by the t-test below) and, on the "
            f"equations where it acts, it removes "
            f">= {100 * o.min_reduction:g} % of the held-out gap above the encoders' quantisation floor (an effect "
            f"that passes every other test but removes less is the verdict graded weak when none counts) and explains >= {100 * o.min_effect_fraction:g} % of the RMS command (an environment mismatch: of the "
            f"RMS spring torque, unless it removes >= {100 * o.min_reduction:g} % of its equation's gap), a one-sided "
            f"t-test on the log ratio of squared errors over held-out units of twice the residual's correlation "
            f"length (all units, and those where the candidate differs from the nominal model by more than the floor, "
            f"Simes' combination; over all units by signed ranks for a candidate removing >= {100 * o.min_reduction:g} % of its "
            f"equations' gap) gives p < {o.alpha:g}/2 for the candidate that explains the fit blocks best and {o.alpha:g}/(2 (n_candidates - 1)) for each other (weighted Bonferroni), and it is identified (defining coefficients "
            f"distinguishable from zero by a Wald test with autocorrelation-corrected covariance, every parameter "
            f"within its plausible range, a friction law's highest level above the motor's torque accuracy by its 95 % noise interval; an environment mismatch, a delay, a torque gain or a Coulomb level near the quantisation also persists in half the band; a delay "
            f"short against the band is read where coefficient x delay leaves the coefficient's bound, an output J "
            f"shrunk below a tenth of the declared one is held at it); an effect outside the motor equation (an environment mismatch, backlash in the coupling) counts only where no motor-equation candidate removes more of the total gap; the winner minimises the held-out BIC; stiction/position_friction must "
            f"resolve what they add to coulomb (stiction F_s more than {100 * BREAKAWAY_MARGIN:g} % above its Coulomb level with a Stribeck velocity of at least {1e3 * o.stick_velocity:g} mrad/s, the stick velocity, or bristles wider than one count holding more than coulomb's level by as much) and beat coulomb by the same test at level {NESTED_ALPHA:g} on the held-out units where their predictions differ by more "
            f"than the floor and on all of them (Simes' combination), or (stiction) show the breakaway at rest, above the "
            f"Coulomb level on rows of two stays; this rule, not the BIC, decides between the two laws (a stiction it "
            f"justifies is the verdict over a coulomb the BIC prefers, and so is one whose levels the log does not separate "
            f"where it removes more of the gap and the breakaway is proven at the raw rate); a second effect fitted together with the winner is reported when it passes the test against "
            f"the winner alone. A weak verdict, a clear one removing less than {100 * o.min_reduction:g} % of the "
            f"total gap, or one named with a second effect where no single effect counts, must also explain "
            f"{REPLICA_MARGIN:g} times the torque it explains on any of {N_REPLICAS} "
            f"effect-free replicas of the log (its re-calibrated nominal model, J_m declared where on its bound, "
            f"controller and reference or motor "
            f"command, encoders' step, jitter and torque sensor simulated; a closed loop also against its logged "
            f"command replayed open loop; the candidate refitted on each); a weak one needs a parameter whose 95 % "
            f"interval is narrower than its plausible range. Where no candidate "
            f"counts and none is weak, one that passes every test of a clear verdict but whose held-out p lies between "
            f"its level and {PROBABLE_P:g} is the verdict graded probable when it explains {REPLICA_MARGIN:g} "
            f"times the torque of every replica.")
