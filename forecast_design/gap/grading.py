"""How much of a log's gap an effect can explain: the sensors' noise floor and the verdict's grade.

The diagnosis blames an effect when it removes ``min_reduction`` (40 %) of the held-out gap. Part
of every gap is the encoders' quantisation, which no effect explains: on a 14-bit log a cogging
that explained everything it could removed 26 % of the gap, a delay 30 %. The reduction is
therefore measured on the *explainable* part, above the noise floor the encoders put into each
equation (:func:`noise_floor`):

    explainable reduction = 1 - sqrt((gap_after^2 - floor^2) / (gap_before^2 - floor^2))

which is the plain reduction on a 2,000,000-count log (floor ~ 1e-5 N m) and lets a coarse log
blame what it can. A candidate that passes every other test of the diagnosis (the held-out
t-test at the candidate's level, identified, at least 0.1 % of the RMS command explained, the
total gap lowered) but stays below ``min_reduction`` is a *weak* effect: the log resolves it,
since the held-out test's power grows with the log's length and excitation, but it explains
less than a clear verdict. It becomes the verdict with grade ``weak`` when no candidate is
clear (JSON ``verdict.grade``: ``clear``, ``weak`` or ``none``), and only where nothing the nominal model already
has looks the same and one of its parameters lies on a direction the log resolves (:func:`weak_set_aside`).

The same floor bounds what a friction law explains where the motor is at rest
(:func:`held_at_rest`): its breakaway level holds the residual there, but not below the floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..effects import Effect
from .candidates import CandidateFit, effect_rows, fit_constant_torque
from .identifiability import calibration_status
from .isolability import CALIBRATION, Isolability
from .residuals import GapData

__all__ = ["noise_floor", "floor_rms", "held_at_rest", "explainable_reduction", "explained_rms", "GRADES", "QUALIFIED_GRADES",
           "weak_set_aside",
           "CONSTANT_TORQUE_SHARE", "OwnReduction", "own_reduction"]

#: Grades of a verdict: an effect that removes ``min_reduction`` of the explainable gap, one the log
#: resolves but that explains less, one of a clear verdict's size whose held-out test stops short of its level and
#: that no effect-free replica produces (:func:`.replicas.probable_verdict`), or no effect.
GRADES = ("clear", "weak", "probable", "none")
#: The grades every output says beside the verdict (a clear one goes without saying).
QUALIFIED_GRADES = ("weak", "probable")


def noise_floor(data: GapData) -> np.ndarray:
    """Mean square [N m^2] of the encoders' quantisation in each stacked row's equation, in the kept band.

    One step ``s`` of quantisation is white with variance ``s^2 / 12`` up to the Nyquist frequency.
    Kept up to ``f`` (the position cut-off or 0.4 x the decimated rate, the smaller), it enters the
    motor equation through ``J_m theta''`` as ``J_m^2 s^2 / 12 (2 pi)^4 f^5 / (5 nyq)`` and, with a
    ``tau_s`` derived from the encoders, through ``k (theta - q)`` as ``k^2 s^2 / 12 2 f / nyq``
    (two encoders), both also in the environment equation (with the output's ``J``). A measured
    ``tau_s`` brings its own noise, which this floor does not count (it only lowers the floor).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray, shape (m * n_equations,)
        The floor of every stacked row [N m^2].
    """
    from ..plausibility import encoder_step_of

    exp = data.experiment
    s = encoder_step_of(np.asarray(exp.signals.theta, dtype=float))
    nyq = exp.rate_hz / 2.0
    f = min(data.settings.position_cutoff_hz, 0.4 * data.settings.decimated_rate_hz, nyq)
    white = s * s / 12.0
    accel = white * (2.0 * math.pi) ** 4 * f ** 5 / (5.0 * nyq)
    spring = 0.0 if data.tau_s_measured else white * 2.0 * f / nyq * exp.design.testbed.k ** 2
    env = exp.design.environment
    per = {"motor": exp.design.testbed.J_m ** 2 * accel + spring,
           "environment": (0.0 if data.locked else env.J ** 2 * accel) + spring,
           "coupling": exp.design.testbed.k ** 2 * white * 2.0 * f / nyq}
    m = data.t.size
    return np.concatenate([np.full(m, per[eq]) for eq in data.equations])


def floor_rms(data: GapData) -> np.ndarray:
    """RMS quantisation floor of every stacked row [N m] (:func:`noise_floor`), cached on ``data``.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray, shape (m * n_equations,)
        ``sqrt(noise_floor(data))`` [N m].
    """
    key = ("floor_rms",)
    if key not in data.cache:
        data.cache[key] = np.sqrt(noise_floor(data))
    return data.cache[key]


def held_at_rest(r: np.ndarray, level: np.ndarray | float, floor: np.ndarray) -> np.ndarray:
    """What a breakaway level leaves of the residual on rows at rest: a soft threshold that stops at the floor.

    A static friction holds any net torque up to its level, so it explains the residual of a motor at
    rest down to ``sign(r) max(|r| - level, 0)``; but no friction explains the encoders' quantisation,
    so the residual left is never below the row's floor (nor above ``|r|``): a level as large as the
    noise would otherwise "explain" every quiet row at rest (an effect-free closed-loop square wave
    was graded a weak stiction of 4.7 mN m that way).

    Parameters
    ----------
    r : ndarray
        Residual of the rows at rest before the friction's hold [N m].
    level : float or ndarray
        Breakaway level (per row for an angle-dependent law) [N m].
    floor : ndarray
        RMS quantisation floor of those rows (:func:`floor_rms`) [N m].

    Returns
    -------
    ndarray
        The residual left [N m], ``sign(r) min(|r|, max(|r| - level, floor))``.
    """
    a = np.abs(r)
    return np.sign(r) * np.minimum(a, np.maximum(a - np.maximum(level, 0.0), floor))


def explainable_reduction(reference: CandidateFit, candidate: CandidateFit, rows: np.ndarray,
                          floor: np.ndarray) -> float:
    """Share of the gap above the noise floor that the candidate removes on the given rows, in [0, 1].

    Parameters
    ----------
    reference, candidate : CandidateFit
        Two fits on the same data (the reference: the calibrated nominal model).
    rows : ndarray of bool
        Stacked rows compared (held-out rows of the candidate's equations).
    floor : ndarray
        :func:`noise_floor` of every stacked row [N m^2].

    Returns
    -------
    float
        ``1 - sqrt((gap_after^2 - floor^2) / (gap_before^2 - floor^2))``, clipped [-].
    """
    if not np.any(rows):
        return 0.0
    fl = float(np.mean(floor[rows]))
    a2 = float(np.mean(reference.residual[rows] ** 2)) - fl
    b2 = float(np.mean(candidate.residual[rows] ** 2)) - fl
    if a2 <= 0.0:
        return 0.0
    return float(min(max(1.0 - math.sqrt(max(b2, 0.0) / a2), 0.0), 1.0))


@dataclass(frozen=True, slots=True)
class OwnReduction:
    """What a candidate removes on the held-out rows of its own equations.

    ``reduction``: the explainable reduction there [-]; ``explained_rms``: the torque it explains [N m];
    ``accuracy``: the torque below which it is no effect [N m] (the motor's torque accuracy; the
    environment's for an environment mismatch; at least the spring torque's quantisation for a backlash);
    ``whole``: the reduction from which the accuracy is not asked [-] (infinite: always asked).
    """

    reduction: float
    explained_rms: float
    accuracy: float
    whole: float = math.inf

    @property
    def counted(self) -> float:
        """The reduction that counts: zero when the torque explained is below the accuracy, unless the
        candidate removes at least ``whole`` of its equations' gap [-]."""
        return self.reduction if self.explained_rms >= self.accuracy or self.reduction >= self.whole else 0.0


def own_reduction(data: GapData, reference: CandidateFit, candidate: CandidateFit,
                  floor: np.ndarray) -> OwnReduction:
    """:class:`OwnReduction` of a candidate over the reference on the held-out rows of the candidate's equations.

    Judged where the effect acts, a quiet equation's gap is not diluted by another equation's noise
    (an environment mismatch next to a noisy motor equation), and above the encoders' quantisation
    (:func:`noise_floor`), which no effect explains.
    """
    rows = data.stacked(data.held_out) & effect_rows(data, candidate)
    # below the motor's torque accuracy: not an effect; nor a dead band explaining less than the quantisation of
    # the spring torque it acts on (an effect-free 16-bit square: 0.7 of it, true dead bands at least 1.5)
    accuracy = data.environment_torque_accuracy if candidate.effect is Effect.ENVIRONMENT_MISMATCH else \
        max(data.torque_accuracy, data.spring_torque_quantisation if candidate.effect is Effect.BACKLASH else 0.0)
    # An environment mismatch that removes most of its equation's gap is that gap, however small: a sensor's
    # error there is a scale (J, d and k_e scaled alike: a re-calibration, judged in .identifiability) or noise,
    # which no inertia or damping explains (0.25 Hz sweeps into outputs 0.41-2.7 x the declared inertia: 63-100 %
    # of the equation, p < 1e-15, 0.2-2.5 mN m under the 0.1 % accuracy, named none; effect-free logs 4-14 %)
    whole = data.options.min_reduction if candidate.effect is Effect.ENVIRONMENT_MISMATCH else math.inf
    return OwnReduction(reduction=explainable_reduction(reference, candidate, rows, floor),
                        explained_rms=explained_rms(reference, candidate, rows), accuracy=accuracy, whole=whole)


def explained_rms(reference: CandidateFit, candidate: CandidateFit, rows: np.ndarray) -> float:
    """RMS torque [N m] a candidate explains beyond the reference on the given rows, ``sqrt(a^2 - b^2)``.

    Parameters
    ----------
    reference, candidate : CandidateFit
        Two fits on the same data.
    rows : ndarray of bool
        Stacked rows compared.

    Returns
    -------
    float
        ``sqrt(max(mean(r_ref^2) - mean(r_cand^2), 0))`` over the rows; 0 for no row [N m].
    """
    if not np.any(rows):
        return 0.0
    a2 = float(np.mean(reference.residual[rows] ** 2))
    b2 = float(np.mean(candidate.residual[rows] ** 2))
    return math.sqrt(max(a2 - b2, 0.0))


def weak_set_aside(data: GapData, weak: Any, fit: CandidateFit, base: CandidateFit, iso: Isolability) -> str:
    """Why a weak effect is not named although it passes its tests, or ``""`` when nothing else looks the same.

    It must be isolable from the re-calibration of J_m, d_m and k (:func:`.isolability.isolability`;
    a torque gain, which never is, only when the re-calibration sits on its datasheet bound), and a
    cogging must remove more than a constant motor torque does (over part of a revolution the
    harmonics make a constant: a driver's offset, a sensor's zero left over). And at least one of its
    parameters must lie on a direction the log resolves: harmonics that are all unresolved (collinear over the
    angles the log turns through, amplitudes up to 110 N m) only name a slow torque the weak grade cannot place.
    The reason is a caveat of its own: an effect that passes every test and is set aside is said, not dropped
    unsaid (a closed-loop 16-bit log with a torque gain of 0.943: the gain removing 20 % of the gap, none).

    Returns
    -------
    str
        The caveat (``Not distinct: ...``), or ``""`` when the weak effect may be named.
    """
    status = weak.assessment.status if weak.assessment is not None else {}
    why = ""
    if status and all(_unresolved(st) for st in status.values()):
        why = ("none of its parameters is placed by the log (each not identifiable, or with an interval wider than "
               "its whole plausible range)")
    elif weak.effect is Effect.TORQUE_GAIN:
        # a gain lies in the span of the re-calibration by construction; only the calibration's datasheet
        # bound tells them apart, so a weak gain counts when the re-calibration sits on that bound
        if not any(st.status == "at_bound" for st in calibration_status(data, base).values()):
            why = ("a gain lies in the span of the re-calibration of J_m, d_m and k, and the log tells it from that "
                   "re-calibration only where the latter sits on its datasheet bound "
                   f"(+-{100 * data.options.calibration_tolerance:g} %), which it does not here")
    elif CALIBRATION in iso.confusable_with(str(weak.effect)):
        why = (f"a re-calibration of J_m, d_m and k reads the same (feature separation below {iso.threshold:g} on "
               "held-out data)")
    elif weak.effect is Effect.COGGING and base.gap_held_out > 0:
        const = fit_constant_torque(data)
        r_cog = 1.0 - fit.gap_held_out / base.gap_held_out
        r_const = 1.0 - const.gap_held_out / base.gap_held_out
        if r_const >= CONSTANT_TORQUE_SHARE * r_cog:
            why = (f"a constant motor torque removes {100 * r_const:.0f} % against its {100 * r_cog:.0f} % (a "
                   "current driver's offset would look the same)")
    return (f"Not distinct: '{weak.effect}' passes its held-out test and removes {100 * weak.reduction:.0f} % of the "
            f"gap, but {why}: not named.") if why else ""


def _unresolved(st: Any) -> bool:
    """A parameter the log does not place: not identifiable, or a 95 % interval wider than its whole plausible range
    (an effect-free 16-bit open-loop log: four cogging harmonics of 0.2-1.6 N m, each +- 250-9,000 N m against a
    plausible 0-2.7 N m, named weak; on the cached seeds every weak verdict whose parameters were all so was wrong)."""
    if st.status == "not_identifiable":
        return True
    if st.plausible is None or st.std is None:
        return False
    lo, hi = st.plausible
    return bool(1.96 * st.std > hi - lo)


#: Share of the cogging verdict's held-out gap reduction that a constant motor torque must reach for
#: the verdict to say a constant would look the same [-].
CONSTANT_TORQUE_SHARE = 0.9
