"""Held-out evidence that one fitted model beats another, and the parsimony rule between nested friction laws.

The diagnosis scores every model on held-out blocks (:mod:`.diagnose`). This module holds the
paired comparison of two fits on those blocks (:func:`held_out_test`, over test units sized by the
residual's correlation length, :func:`test_units`), the rule that decides between nested
friction laws (:func:`richer_law_justified`: ``stiction`` or ``position_friction`` over ``coulomb``) and
whether a verdict is told from another reading that explains the held-out data as well (:func:`verdict_ties`:
a re-calibration, or any candidate where a periodic verdict covers less than a period).

The nested rule is measured against the encoders' quantisation floor (:mod:`.grading`). Two laws
that share their Coulomb part predict the same torque wherever the richer law's extra terms are
idle; on a coarse encoder those units are quantisation and carry no evidence either way. A
stiction log on a 14-bit encoder showed it: the stiction law removed 70 % of the gap against 54 %
for coulomb and each of the 7 held-out units where the two laws' predictions differ by more than
the floor was better explained by stiction, but the t-test over all 60 units at 1 % (p = 0.02)
named coulomb.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

from ..effects import Effect
from .candidates import CandidateFit, effect_rows, fit_pair
from .grading import noise_floor
from .identifiability import method_shift, terms_wald_p
from .motion import held_at_rest_rows, held_level_factor
from .residuals import GapData, gap_log_scales
from .structures import _FRICTION

__all__ = ["held_out_test", "effect_held_out_test", "units_test", "correlation_length", "test_units", "nested_law_test", "richer_law_justified", "simplest_tied",
           "breakaway_resolved_at_rest", "breakaway_proven_at_rest", "richer_law_resolved", "candidate_levels", "verdict_ties", "NESTED_ALPHA"]


def held_out_test(reference: CandidateFit, candidate: CandidateFit, held_blocks: np.ndarray, *,
                  units: np.ndarray | None = None, floor: np.ndarray | None = None, rank: bool = False) -> float:
    """One-sided paired t-test that ``candidate`` lowers the squared error of the held-out data.

    The test statistic is the per-unit log ratio ``log(SSE_reference / SSE_candidate)``:
    units differ widely in excitation, and the log ratio makes a consistent relative
    improvement count equally in quiet and busy units. Unit SSEs are floored at
    ``1e-6`` times the reference's mean held-out unit SSE (so a ratio saturates at
    ``1e6`` instead of diverging on a unit explained exactly).

    Parameters
    ----------
    reference, candidate : CandidateFit
        Two fits on the same data.
    held_blocks : ndarray of int
        Indices of the held-out blocks (the units when ``units`` is not given).
    units : ndarray of int, optional
        Test unit of every stacked residual row (-1: not a held-out row); see
        :func:`test_units`. Default: the held-out blocks.
    floor : ndarray, optional
        Quantisation floor of every stacked row (:func:`.grading.noise_floor`) [N m^2]; with ``units``,
        the test is also run on the units where the two fits' predictions differ by at least the
        floor, and the two p-values combined (:func:`units_test`).
    rank : bool
        With ``units`` and ``floor``: the test over every unit by signed ranks (:func:`units_test`).

    Returns
    -------
    float
        p-value of H0 "mean log ratio <= 0" against H1 "mean log ratio > 0" [-].
    """
    if units is None:
        return _log_ratio_p(reference.block_sse[held_blocks], candidate.block_sse[held_blocks])
    return units_test(reference.residual, candidate.residual, units, floor, rank=rank)[0]


def units_test(reference: np.ndarray, candidate: np.ndarray, units: np.ndarray,
               floor: np.ndarray | None, *, rank: bool = False) -> tuple[float, int]:
    """Paired test over held-out units that ``candidate`` predicts better, on every unit and where the fits differ.

    Two one-sided t-tests on the per-unit log ratios ``log(SSE_reference / SSE_candidate)``: over every
    unit, and over the units where the two fits' predictions differ by at least the encoders'
    quantisation floor (elsewhere they predict the same torque within what the encoders resolve, and on
    a coarse encoder those units are quantisation noise that only widens the test). Each finds what the
    other misses: the first, differences below the floor in each unit that all point one way (a
    breakaway held at rest, seen a little in every unit); the second, an improvement concentrated in a
    few units (a delay, which acts only at the edges of a slow square wave: 98 % of the gap removed,
    in 5 of 20 units). The p-values are combined by Simes' rule, ``min(2 p_(1), p_(2))``, a valid level
    for tests that are positively dependent, as two tests on the same units are (Sarkar, Ann. Statist.
    26, 1998). With ``rank`` the test over every unit is Wilcoxon's signed-rank test instead of the t-test:
    where an improvement spans decades across the units (a delay on a square's edges: 10 of 10 units
    better, the log ratios 0.01-9.4), their spread takes the t-test's power (p = 0.0095) and not the
    ranks' (0.001). It is asked for candidates of a clear verdict's size only: the ranks also prove an
    improvement of a few percent in most units, which on an effect-free log is the nominal model's
    small error, not an effect (a torque gain removing 1.5 % of the gap: ranks p = 1e-12, t 0.025).

    Parameters
    ----------
    reference, candidate : ndarray
        Stacked residuals of the two fits [N m].
    units : ndarray of int
        Test unit of every stacked row (-1: not tested), :func:`test_units`.
    floor : ndarray or None
        Quantisation floor of every stacked row (:func:`.grading.noise_floor`) [N m^2]; None: the test over
        every unit alone.
    rank : bool
        The test over every unit by signed ranks (with ``floor``).

    Returns
    -------
    p : float
        Combined p-value of "the candidate is no better" [-].
    n_apart : int
        Number of units where the predictions differ by at least the floor.
    """
    use = units >= 0
    n = int(units.max()) + 1 if np.any(use) else 0
    if n == 0:
        return 1.0, 0
    u = units[use]
    a = np.bincount(u, weights=reference[use] ** 2, minlength=n)
    b = np.bincount(u, weights=candidate[use] ** 2, minlength=n)
    if floor is None:
        return _log_ratio_p(a, b), 0
    apart = np.bincount(u, weights=(reference[use] - candidate[use]) ** 2, minlength=n)
    informative = (apart >= np.bincount(u, weights=floor[use], minlength=n)) & (apart > 0.0)
    k = int(np.count_nonzero(informative))
    p_apart = _log_ratio_p(a[informative], b[informative]) if k >= 2 else 1.0
    p_all = _signed_rank_p(a, b) if rank else _log_ratio_p(a, b)
    lo, hi = sorted((p_apart, p_all))
    return min(1.0, 2.0 * lo, hi), k


def _log_ratios(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-unit ``log(a / b)`` of two non-empty arrays of unit SSEs [-]."""
    # A unit explained to (numerically) zero, e.g. a stuck motor under a static-friction
    # model, would give an infinite log ratio whose spread hides a consistent improvement:
    # squared errors below 1e-6 of the reference's mean unit are treated as equal.
    floor = max(1e-6 * float(np.mean(a)), 1e-300)
    return np.log(np.maximum(a, floor) / np.maximum(b, floor))


def _signed_rank_p(a: np.ndarray, b: np.ndarray) -> float:
    """One-sided Wilcoxon signed-rank p-value that ``log(a / b)`` over the units lies above zero."""
    if a.size == 0 or np.count_nonzero(d := _log_ratios(a, b)) < 2:
        return _log_ratio_p(a, b)
    return float(stats.wilcoxon(d, alternative="greater").pvalue)


def _log_ratio_p(a: np.ndarray, b: np.ndarray) -> float:
    """One-sided t-test p-value that the mean of ``log(a / b)`` over the units is > 0 (see :func:`held_out_test`)."""
    if a.size == 0:   # no held-out unit (a log too short or too still to test on): no evidence of improvement
        return 1.0
    d = _log_ratios(a, b)
    n = d.size
    sd = float(np.std(d, ddof=1)) if n > 1 else 0.0
    mean = float(np.mean(d))
    if sd <= 1e-12 * max(1.0, abs(mean)):
        return 0.0 if mean > 1e-12 else 1.0
    return float(stats.t.sf(mean / (sd / math.sqrt(n)), n - 1))


def effect_held_out_test(data: GapData, reference: CandidateFit, candidate: CandidateFit, *,
                         units: np.ndarray | None = None, floor: np.ndarray | None = None,
                         rank: bool = False) -> float:
    """:func:`held_out_test` of ``candidate`` on the held-out units of the equations where its effect acts.

    Parameters
    ----------
    data : GapData
        The prepared log both fits were made on.
    reference, candidate : CandidateFit
        The nominal model (or the fit the candidate must beat) and the candidate.
    units : ndarray or None
        The candidate's test units over every stacked row (:func:`test_units`); None: computed here.
    floor : ndarray or None
        The quantisation floor of every stacked row (:func:`.grading.noise_floor`); None: computed here.
    rank : bool
        The test over every unit by signed ranks (:func:`units_test`).

    Returns
    -------
    float
        One-sided p-value [-].
    """
    units = test_units(data, candidate) if units is None else units
    floor = noise_floor(data) if floor is None else floor
    return held_out_test(reference, candidate, np.arange(1, data.options.n_blocks, 2),
                         units=np.where(effect_rows(data, candidate), units, -1), floor=floor, rank=rank)


def correlation_length(residual: np.ndarray) -> int:
    """First lag [samples] at which a residual's autocorrelation falls inside its white-noise band ``2/sqrt(n)``."""
    e = np.asarray(residual, dtype=float)
    e = e - e.mean()
    n = e.size
    if n < 8 or not np.any(e):
        return 1
    spec = np.fft.rfft(e, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n]
    acf = acf / acf[0]
    inside = np.flatnonzero(np.abs(acf[1:]) < 2.0 / math.sqrt(n))
    return int(inside[0]) + 1 if inside.size else n


def test_units(data: GapData, candidate: CandidateFit, *, min_samples: int = 4) -> np.ndarray:
    """Test units of the held-out rows, sized by the information in the log.

    Each held-out block is cut into units of ``max(2 l, min_samples)`` decimated
    samples (at most the block), where ``l`` is the correlation length of the
    candidate's held-out motor-equation residual (:func:`correlation_length`): units
    that far apart are nearly independent, so the number of units -- and the power
    of :func:`held_out_test` -- grows with the log's length and shrinks with a
    correlated (badly explained) residual.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    candidate : CandidateFit
        The better-scoring model of the comparison.
    min_samples : int
        Smallest unit [decimated samples].

    Returns
    -------
    ndarray of int, shape (m * n_equations,)
        Unit index of every stacked row; -1 for rows on the fit blocks.
    """
    m = data.t.size
    held = data.held_out
    ell = correlation_length(candidate.residual[:m][held])
    size = max(2 * ell, min_samples)
    unit = np.full(m, -1, dtype=int)
    nxt = 0
    for b in np.unique(data.block[held]):
        idx = np.flatnonzero(data.block == b)
        n_units = max(1, idx.size // size)
        unit[idx] = nxt + np.minimum(np.arange(idx.size) * n_units // idx.size, n_units - 1)
        nxt += n_units
    return data.stacked(unit)


#: Level of the one planned comparison between nested friction laws [-]. Both laws already count (each
#: beat the nominal model at the Bonferroni level); this comparison only chooses between two readings
#: of the same friction torque, and at 1 % it named coulomb on stiction logs whose every unit that
#: tells the laws apart was better explained by stiction (14- and 16-bit encoders).
NESTED_ALPHA = 0.05


def nested_law_test(data: GapData, simpler: CandidateFit, richer: CandidateFit) -> tuple[float, int]:
    """One-sided test that the richer of two nested laws predicts the held-out data better.

    :func:`units_test` on the held-out test units of the richer law (:func:`test_units`): over every
    unit, and over the units where the two laws' predictions differ by at least the encoders'
    quantisation floor, Simes-combined.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    simpler, richer : CandidateFit
        The nested law and the law that nests it, fitted on the same data.

    Returns
    -------
    p : float
        Combined p-value of "the richer law is no better" [-].
    n_units : int
        Number of units where the laws' predictions differ by more than the floor.
    """
    return units_test(simpler.residual, richer.residual, test_units(data, richer), noise_floor(data))


def breakaway_resolved_at_rest(data: GapData, richer: CandidateFit, simpler: CandidateFit) -> bool:
    """Whether the rows at rest show a breakaway above the Coulomb level, beyond the filters and the noise.

    On a row at rest at the raw rate (a ``stuck`` row whose own raw sample does not move,
    :func:`.motion.held_at_rest_rows`) the Coulomb law's residual is the torque the static friction
    holds. A Coulomb friction holds at most its level ``F_c``, read through the filters up to
    ``F_c`` times :func:`.motion.held_level_factor` next to motion, plus quantisation noise of RMS
    ``floor`` (:func:`.grading.noise_floor`) whose largest of ``n`` rows reaches about
    ``floor sqrt(2 ln n)``; the level itself carries the analysis' own error, its shift when the filter's cut-off
    is halved (:func:`.identifiability.method_shift`), added to it. Stiction holds up to ``F_s``. The breakaway is
    resolved at rest when rows
    of at least two separate stays at rest hold more than that and the stiction fit puts its
    breakaway ``dF`` above the same noise allowance, both over its own Coulomb level and over the Coulomb law's.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    richer : CandidateFit
        A stiction fit (alone or first in a pair).
    simpler : CandidateFit
        The coulomb fit of the same data.

    Returns
    -------
    bool
        True when the rows at rest resolve the breakaway.
    """
    s, c = richer.structure, simpler.structure
    names = [x.name for x in s.coefs] if s is not None else []
    if "dF" not in names or richer.coef is None or c is None or c.level is None or simpler.coef is None:
        return False
    m = data.t.size
    rest = held_at_rest_rows(data)
    n = int(np.count_nonzero(rest))
    if n < 2:
        return False
    floor = np.sqrt(noise_floor(data)[:m][rest])
    z = math.sqrt(2.0 * math.log(n))
    allowance = z * float(np.sqrt(np.mean(floor ** 2)))
    d_f = float(richer.coef[richer.n_cal + names.index("dF")])
    if not d_f > allowance:
        return False
    level = c.level(simpler.coef[simpler.n_cal:])
    # the stiction fit's own breakaway must stand above the Coulomb law's level by the same allowance: rows that hold
    # more while the fit puts F_s at that level are the filters' reading of the stays, not a breakaway (a closed-loop
    # PID square with Coulomb friction: F_s 0.272 over its own F_c 0.231, coulomb's level 0.275; stiction named
    # with 77 % of the gap against coulomb's 98 %)
    if s.level is not None and not float(s.level(richer.coef[richer.n_cal:])) > float(np.max(level)) + allowance:
        return False
    # the Coulomb level carries the analysis' own error (the filters smear every reversal: 0.2-5 %), which a
    # torque held at the true level exceeds as often as not: a breakaway must stand beyond it too (a coulomb fit
    # alone; a pair's level would be refitted without its second effect)
    shift = method_shift(data, simpler) if set(simpler.params) <= {"F_c", "F_c_neg"} else {}
    level = level + max(shift.get("F_c", 0.0), shift.get("F_c_neg", 0.0))
    level = (level[rest] if np.ndim(level) else level) * held_level_factor(data)[rest]
    # the Coulomb law's torque at rows at rest (its sign feature is zero there): what the motor held
    held = np.abs(simpler.residual[:m][rest] + simpler.prediction[:m][rest])
    over = np.zeros(m, dtype=bool)
    over[np.flatnonzero(rest)] = held > level + z * floor
    stays = np.cumsum(np.diff(np.concatenate([[0], data.stuck.astype(np.int8)])) == 1)   # stay number per row
    return len(np.unique(stays[over])) >= 2


#: Share of the Coulomb level a torque held at rest must exceed it by, beyond the allowances of
#: :func:`breakaway_proven_at_rest`, to prove a breakaway [-]: what is left of the level's own error
#: (Coulomb logs of twenty-two seeds proved at most 1.024 of their fitted level, stiction logs up to F_s / F_c);
#: a fitted breakaway must stand as far above its Coulomb level (:func:`richer_law_resolved`).
BREAKAWAY_MARGIN = 0.05


def breakaway_proven_at_rest(data: GapData, simpler: CandidateFit) -> bool:
    """Whether the motor held, at rest, a torque no Coulomb level of ``simpler`` could hold: a breakaway.

    At the raw rate, where the encoder reads one count throughout a stay, the motor's angle stays within one
    encoder step ``delta``. Under a Coulomb law the friction never exceeds its level ``F`` (sliding or
    sticking), so ``J theta'' >= f - F`` with ``f = tau_m - tau_s`` the net torque (re-calibrated as ``simpler``
    reads it) and, for any three instants ``h`` samples apart inside the stay,
    ``theta(t+h) - 2 theta(t) + theta(t-h) = sum_j (h - |j|) dt^2 theta''`` is at most ``2 delta``. A stay whose
    hat-weighted mean net torque exceeds ``F`` by more than ``2 delta J / (h dt)^2`` plus ``z`` standard
    deviations of that mean (the net torque's noise, ``z = sqrt(2 ln n)`` over the ``n`` windows tried, ``h`` =
    2, 4, 8 ... samples) would have moved the motor by more than a count: the friction held more than ``F``. No
    filter is involved (the decimated rows at rest ring after a torque step inside a stay: a closed-loop Coulomb
    square held 1.13 ``F_c`` on them, 0.99 here). A breakaway is proven when stays of both directions together
    hold beyond the level (plus its analysis error, :func:`.identifiability.method_shift`, and
    :data:`BREAKAWAY_MARGIN`) at least twice.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    simpler : CandidateFit
        The coulomb fit (its levels ``F_c``, ``F_c_neg`` and its re-calibration; a pair's: False).

    Returns
    -------
    bool
        True when two stays prove a held torque beyond the Coulomb level.
    """
    key = ("breakaway_proven", id(simpler))
    if key in data.cache and data.cache[key][0] is simpler:     # asked by the nested rule and for the caveat
        return data.cache[key][1]
    data.cache[key] = (simpler, _breakaway_proven(data, simpler))
    return data.cache[key][1]


def _breakaway_proven(data: GapData, simpler: CandidateFit) -> bool:
    exp = data.experiment
    sig, tb = exp.signals, exp.design.testbed
    if not set(simpler.params) <= {"F_c", "F_c_neg"}:
        return False    # a pair's second effect acts at rest too, which the net torque below leaves in
    levels = _levels(simpler.params)
    if min(levels) <= 0.0:
        return False
    cal = simpler.calibration
    theta = np.asarray(sig.theta, dtype=float)
    tau_s = np.asarray(sig.tau_s, dtype=float) if data.tau_s_measured else tb.k * (theta - np.asarray(sig.q, dtype=float))
    f = np.asarray(sig.tau_m, dtype=float) - cal["spring_scale"] * tau_s - cal.get("tau_s_offset_N_m", 0.0)
    dt, J = 1.0 / float(exp.rate_hz), float(cal["J_m"])
    step = gap_log_scales(data).encoder_step
    d = np.diff(f)
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)     # the net torque's white noise
    edges = np.flatnonzero(np.diff(theta) != 0.0) + 1
    stays = [(a, b) for a, b in zip(np.r_[0, edges], np.r_[edges, theta.size]) if b - a >= 5]
    hats = [(a, b, h) for a, b in stays for h in (2 ** np.arange(1, 30)).tolist() if 2 * h < b - a]
    if not hats:
        return False
    z = math.sqrt(2.0 * math.log(max(sum(max(1, (b - a - 2 * h) // h) for a, b, h in hats), 2)))
    shift = method_shift(data, simpler)
    bar = [(lv + shift.get(k, 0.0)) * (1.0 + BREAKAWAY_MARGIN) for lv, k in zip(levels, ("F_c", "F_c_neg"))]
    proven = set()
    for a, b, h in hats:
        # the hat of half-width h is a box of h samples convolved with itself: weights h - |j|, summing to h^2;
        # the first and last windows are dropped, whose ends t -+ h lie outside the stay
        mean = _window_sums(_window_sums(f[a:b], h), h)[1:-1] / h ** 2
        allow = (2.0 * step * J / dt ** 2 + z * sigma * math.sqrt((2 * h ** 3 + h) / 3.0)) / h ** 2
        if mean.max() - allow > bar[0] or -mean.min() - allow > bar[1]:
            proven.add(a)
    return len(proven) >= 2


def _levels(params: Any) -> tuple[float, float]:
    """A friction fit's Coulomb levels ``(F_c, F_c_neg)`` [N m] (one shared level: both the same)."""
    return float(params["F_c"]), float(params.get("F_c_neg", params["F_c"]))


def _window_sums(x: np.ndarray, h: int) -> np.ndarray:
    """Sums of ``h`` consecutive samples of ``x`` (``np.convolve(x, ones(h), 'valid')`` in O(n))."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    return c[h:] - c[:-h]


def richer_law_resolved(data: GapData, richer: CandidateFit, simpler: CandidateFit, *,
                        at_rest: Callable[[], bool] | None = None, stribeck: Callable[[], bool] | None = None) -> bool:
    """Whether a richer friction law resolves what it adds to coulomb (part (a) of :func:`richer_law_justified`).

    Stiction: a breakaway above the Coulomb level (its Stribeck coefficient ``dF`` by the Wald test at
    :data:`NESTED_ALPHA` and more than :data:`BREAKAWAY_MARGIN` of its own level, for a bump no narrower than
    ``GapOptions.stick_velocity``, below which a row may be at rest; or at rest,
    :func:`breakaway_proven_at_rest`, :func:`breakaway_resolved_at_rest`) or presliding bristles wider than
    the search's first point (one encoder count) and short of its last (a bound hit finds no width) whose
    breakaway ``max(F_c, F_c_neg) + dF`` stands :data:`BREAKAWAY_MARGIN` above the Coulomb law's level (a
    presliding law reads its levels through the bristles); position_friction: its angle harmonics by the Wald
    test. A stiction law that resolves neither is a Coulomb law with a bump or presliding the log does not
    carry, whether or not the Coulomb law itself counts: the vocabulary's stiction is ``F_s > F_c``, and a
    breakaway within the Coulomb level's own error is not that.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    richer, simpler : CandidateFit
        The nesting law (alone or first in a pair) and coulomb, fitted on the same data.
    at_rest, stribeck : callable, optional
        The two stiction tests, when the caller computes them once for later use too.

    Returns
    -------
    bool
        True when the richer law's extra terms are resolved.
    """
    s = richer.structure
    names = [c.name for c in s.coefs] if s is not None else []
    if "dF" in names:
        at_rest = at_rest or (lambda: breakaway_proven_at_rest(data, simpler)
                              or breakaway_resolved_at_rest(data, richer, simpler))
        stribeck = stribeck or (lambda: terms_wald_p(data, richer, ["dF"]) < NESTED_ALPHA)
        bristles = next(((value, lo, hi) for nm, value, lo, hi in s.grid if nm == "x_p"), None)
        # presliding on the search's upper end has found no width (an effect-free closed-loop square: 10 mrad of
        # "bristles", every level's interval holding zero): no evidence, as any bound hit
        wide = bristles is not None and bristles[1] * (1.0 + 1e-9) < bristles[0] < bristles[2] * (1.0 - 1e-9)
        # a breakaway within BREAKAWAY_MARGIN of a Coulomb level is that level's own error, not F_s > F_c: above
        # the law's own level for its bump (a closed-loop Coulomb square: dF 0.06 % of F_c at Wald p = 0.002);
        # presliding reads its levels through the bristles, so there above the Coulomb law's (16-bit Coulomb
        # squares: one-count-wider bristles, F_s within 0-4 % of coulomb's F_c; a 14-bit stiction log: 17 % above)
        level, coulomb = max(_levels(richer.params)), max(_levels(simpler.params))
        breakaway = float(richer.params["F_s"]) - float(richer.params["F_c"]) + level
        # a bump narrower than the stick velocity acts only on rows that may be at rest, which the law at rest
        # already holds: its coefficient measures how those rows are read, not a Stribeck decay (2e6-count
        # closed-loop Coulomb logs: v_s on the search's 1 mrad/s end, F_s 2.5-4 x F_c at Wald p < 1e-7), so only
        # the rows at rest can prove it
        decay = float(richer.params.get("v_s", math.inf)) >= data.options.stick_velocity
        return (wide and breakaway > (1.0 + BREAKAWAY_MARGIN) * coulomb) or at_rest() \
            or (decay and breakaway > (1.0 + BREAKAWAY_MARGIN) * level and stribeck())
    harmonics = [nm for nm in names if len(nm) > 1 and nm[0] in "ab" and nm[1:].isdigit()]
    return terms_wald_p(data, richer, harmonics) < NESTED_ALPHA


def richer_law_justified(data: GapData, richer: CandidateFit, simpler: CandidateFit) -> bool:
    """Parsimony between nested friction laws: stiction or position_friction over plain coulomb.

    The richer law must (a) resolve what it adds to coulomb: for position_friction the angle
    harmonics of the level, for stiction either a breakaway above the Coulomb level (the Stribeck
    coefficient ``dF``: the vocabulary's stiction is ``F_s > F_c``; by its Wald test, or at rest above the
    encoders' noise, :func:`breakaway_proven_at_rest` or :func:`breakaway_resolved_at_rest`; a bump within
    :data:`BREAKAWAY_MARGIN` of the level is none, and one narrower than the stick velocity counts at rest only)
    or presliding bristles wider
    than the log's resolution (the presliding displacement above the grid's first point, one
    encoder count, with the breakaway above the Coulomb law's level by the same margin:
    LuGre stiction is told from coulomb by its bristles when the Stribeck bump is not
    resolved, as on the bundled Fig. 7 scenario, ``dF`` at Wald p = 0.24, stiction removing 99 % of
    the gap against 77 %); coefficients are judged by the Wald test of
    :func:`.identifiability.terms_wald_p` at :data:`NESTED_ALPHA`. A stiction fit with neither is a
    Coulomb law with a tiny bump or one-count presliding. And (b) it must beat the simpler law by
    :func:`nested_law_test` at :data:`NESTED_ALPHA` (one planned comparison), on the units where their
    predictions differ by more than the encoders' quantisation floor and on all units, without predicting the
    held-out data worse in all by more than a second effect must remove (``GapOptions.min_reduction``); or, for
    stiction, show its breakaway at rest (:func:`breakaway_proven_at_rest` at the raw rate, or
    :func:`breakaway_resolved_at_rest` on the decimated rows: a breakaway lasts milliseconds of a stay
    at rest, and on a log that rarely stops no test over held-out units finds it). The tests gain power with the
    log's length and excitation; no fixed share of the gap is asked for (half of ``min_reduction``
    named coulomb on a 16-bit stiction log where stiction removed 14 % of what coulomb left, at
    p = 2e-7, with ``F_s - F_c`` at 3 standard deviations).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    richer, simpler : CandidateFit
        The nesting law (stiction, position_friction; alone or in a pair, first) and coulomb, fitted
        on the same data.

    Returns
    -------
    bool
        True when the data justify the richer law.
    """
    s = richer.structure
    names = [c.name for c in s.coefs] if s is not None else []
    at_rest = functools.cache(lambda: breakaway_proven_at_rest(data, simpler)
                              or breakaway_resolved_at_rest(data, richer, simpler))
    stribeck = functools.cache(lambda: terms_wald_p(data, richer, ["dF"]) < NESTED_ALPHA)
    if not richer_law_resolved(data, richer, simpler, at_rest=at_rest, stribeck=stribeck):
        return False
    p, _ = nested_law_test(data, simpler, richer)
    # the units' log ratios weigh a consistent small gain in most units over a large loss in a few: a law that
    # predicts the held-out data worse in all, by more than a second effect must remove, is not proven by them (a
    # Coulomb sweep: stiction leaving 4.7 % of the gap against coulomb's 2.3 %, nested p = 0.019 over 188 units); within
    # that the units decide (a 14-bit stiction loop: 26.4 % against 26.1 %, p = 0.011)
    if p < NESTED_ALPHA and richer.gap_held_out * (1.0 - data.options.min_reduction) <= simpler.gap_held_out:
        return True
    # A breakaway is a few milliseconds of each stay at rest: on a multisine or a sweep that rarely stops, the
    # laws differ in a handful of the hundreds of held-out units and no test over units finds it (a 16-bit
    # stiction log: stiction removes 47 % of the gap, coulomb 43 %, p = 0.45 over 30 units). Rows of two stays
    # at rest that hold more than any Coulomb level can then decide. A Stribeck coefficient distinguishable
    # from zero was asked for too and named coulomb on stiction logs whose bump lies below the speed the
    # encoders resolve (F_s 0.36 for 0.40 N m, v_s 9.8 for 10.1 mrad/s, dF at Wald p = 0.25): seven of 880
    # logs of twenty seeds, and no coulomb log of them turned to stiction on the rows at rest alone
    return bool("dF" in names and at_rest())


def candidate_levels(data: GapData, fits: Sequence[CandidateFit], alpha: float) -> list[float]:
    """Level of each candidate's held-out test: a weighted Bonferroni split of ``alpha`` fixed on the fit blocks.

    The candidate that explains the fit blocks best (lowest BIC there, ``n log(SSE / n) + p log(n)``) is
    tested at ``alpha / 2``, every other one at ``alpha / (2 (n - 1))``. The levels still sum to
    ``alpha``, so the family-wise error stays controlled, and they are chosen from the fit blocks only,
    which the held-out test does not see. A plain Bonferroni split (``alpha / n`` each) named no effect on
    short closed-loop squares whose delay removed 44 % of the gap, every unit with an edge improved
    many-fold but the test over 20 units giving p = 0.003.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    fits : sequence of CandidateFit
        The single-effect candidates.
    alpha : float
        Family-wise level [-].

    Returns
    -------
    list of float
        The level of each candidate, in the order of ``fits`` [-].
    """
    n = len(fits)
    if n <= 1:
        return [alpha] * n
    n_fit = int(np.count_nonzero(~data.stacked(data.held_out)))

    def bic(f: CandidateFit) -> float:
        return n_fit * math.log(max(f.gap_fit ** 2, 1e-300)) + f.n_params * math.log(max(n_fit, 2))

    leader = min(range(n), key=lambda i: bic(fits[i]))
    return [alpha / 2.0 if i == leader else alpha / (2.0 * (n - 1)) for i in range(n)]


def verdict_ties(ranked: Sequence[Any], winner: Any | None, *, angle_span_rad: float, n_harmonics: int) -> str:
    """Why a verdict is not told from another reading of the log, or ``""`` when it is.

    * A torque gain within the datasheet tolerance of ``J_m``, ``d_m`` and ``k`` is a re-calibration, not an effect
      (:func:`.identifiability.assess_fit`). When that fit explains the held-out data at least as well as the
      verdict, the log does not tell the verdict from the re-calibration (a gain fitted at 1.016 explaining 73 % of
      the gap was named stiction, weak, at 20 %).
    * Over less than one period of the highest harmonic (``2 pi / n_harmonics`` of motor angle) the harmonics of
      cogging and position friction are a polynomial in the angle (an offset, a spring, a curvature): they still
      resolve a true cogging there, but they also fit whatever smooth torque the log carries as the angle follows
      it (gain, Coulomb and dead-band logs turning 0.003-0.7 rad were named cogging, with harmonics of up to
      100 N m). Such a verdict stands only when no other candidate (identified or not; a nested friction law
      excepted for position friction) explains the held-out data as well.

    Parameters
    ----------
    ranked : sequence of RankedCandidate
        The ranked candidates of one log (:class:`.diagnose.RankedCandidate`).
    winner : RankedCandidate or None
        The verdict so far (clear or weak).
    angle_span_rad : float
        The motor angle's span over the log [rad] (:attr:`.locate.Location.angle_span_rad`).
    n_harmonics : int
        Harmonics of the periodic candidates [-].

    Returns
    -------
    str
        The caveat to state when the verdict must be dropped, else an empty string.
    """
    if winner is None:
        return ""
    return _rescaling_tie(ranked, winner) or _periodic_tie(ranked, winner, angle_span_rad, n_harmonics)


def _rescaling_tie(ranked: Sequence[Any], winner: Any) -> str:
    """The re-calibration part of :func:`verdict_ties`."""
    gain = next((r for r in ranked if r.effect is Effect.TORQUE_GAIN), None)
    if gain is None or gain is winner or gain.assessment is None \
            or not gain.assessment.rescaling or gain.gap_after > winner.gap_after:
        return ""
    return (f"Not distinguished: '{winner.effect}' removes {100 * winner.reduction:.0f} % of the gap and a "
            f"re-calibration within the datasheet tolerance (torque_gain {gain.params['gain']:.4g}) "
            f"{100 * gain.reduction:.0f} %: no effect is named.")


def _periodic_tie(ranked: Sequence[Any], winner: Any, span: float, n_harmonics: int) -> str:
    """The periodic part of :func:`verdict_ties`."""
    period = 2.0 * math.pi / n_harmonics
    if winner.effect not in (Effect.COGGING, Effect.POSITION_FRICTION) or span >= period:
        return ""
    nested = (Effect.COULOMB, Effect.STICTION) if winner.effect is Effect.POSITION_FRICTION else ()
    rivals = [r for r in ranked if r is not winner and r.effect not in nested and r.gap_after <= winner.gap_after]
    if not rivals:
        return ""
    best = min(rivals, key=lambda r: r.gap_after)
    return (f"Not distinguished: the motor turns through {span:.3g} rad, less than one period ({period:.3g} rad) of "
            f"the highest harmonic, where '{winner.effect}' ({100 * winner.reduction:.0f} % of the gap) is a smooth "
            f"torque in the angle and '{best.effect}' explains as much ({100 * best.reduction:.0f} %): no effect is "
            "named.")


def simplest_tied(data: GapData, winner: Any, contenders: list[Any],
                  by_effect: Mapping[str, CandidateFit]) -> tuple[Any, float]:
    """Parsimony between candidates that are not nested: the simplest that leaves the winner nothing to add.

    The ranking's BIC counts every decimated row as independent, while filtered equation errors are
    correlated over many rows, and a many-parameter candidate also soaks up part of whatever else the
    nominal model misses: over the fraction of a revolution a force-control log turns through, eight
    cogging harmonics make any smooth function of the angle, and where the angle follows the command
    they mimic a torque gain (cogging 0.894 of the gap against the true torque gain's 0.890, "better"
    by the held-out t-test at p = 2e-35). The question the data can answer is the forward selection's:
    fitted on top of a simpler significant candidate, does the winner add what a second effect must
    (``GapOptions.min_reduction`` of what is left, as :func:`.diagnose.diagnose`'s second effect)? If not, the simpler one
    (fewest parameters first) explains the log and is the verdict. The nested friction laws have
    their own rule (:func:`richer_law_justified`).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.
    winner : RankedCandidate
        The verdict so far.
    contenders : list of RankedCandidate
        The candidates that count.
    by_effect : Mapping[str, CandidateFit]
        Every candidate's fit, keyed by effect word.

    Returns
    -------
    (RankedCandidate, float)
        The verdict, and the share of what the simpler candidate leaves that the winner removes on top
        of it (NaN when the winner stays) [-].
    """
    w_fit = by_effect[str(winner.effect)]
    simpler = sorted((r for r in contenders if r is not winner
                      and by_effect[str(r.effect)].n_params < w_fit.n_params
                      and not (r.effect in _FRICTION and winner.effect in _FRICTION)),
                     key=lambda r: by_effect[str(r.effect)].n_params)
    for r in simpler:
        s_fit = by_effect[str(r.effect)]
        pair = fit_pair(data, s_fit, winner.effect)
        if pair is None or s_fit.gap_held_out <= 0.0:
            continue
        extra = 1.0 - pair.gap_held_out / s_fit.gap_held_out
        if extra < data.options.min_reduction:
            return r, float(extra)
    return winner, float("nan")
