"""Where the motor moves and where it rests: the direction of its motion at the raw rate, the rows a static
friction may hold, and how far the filters carry a breakaway into the rows next to a rest.

Below the encoder's speed resolution (one step per derivative-filter window) the filtered speed does not
resolve the motion; a log is read either with the motor at rest there or, where the recorded angle moves,
creeping (:func:`creeping`, ``GapData.creep``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ..friction.derivatives import FilterSettings, antialias, settling_samples
from .residuals import GapData, gap_log_scales, lowpass

__all__ = ["creeping", "motion_direction", "near_rest", "rest_distance", "held_at_rest_rows", "held_level_factor"]


def creeping(data: GapData) -> np.ndarray:
    """Raw samples below the speed resolution that may creep, and their direction (cached on ``data``).

    A closed loop pushing against a large friction turns a coarse encoder by a count every few tens of
    milliseconds: 57-91 % of such a log's samples lay below the speed resolution (one step per
    derivative-filter window, :func:`.residuals.gap_log_scales`) while the friction slid at its full level. A sample
    there may creep when it lies between two samples that resolve the same direction and the *recorded*
    angle moves that way on both sides of it (a motor that has just stopped moved on one side only), at
    least at ``GapOptions.stick_velocity`` over a window that resolves that speed by one encoder step.
    The encoder cannot tell such a creep from stays at rest of a few tens of milliseconds between two
    motions the same way: 0-11 % of those samples were at rest on Coulomb logs, 35-65 % on stiction logs.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray of float, shape (n_raw,)
        +1 or -1 where a sample may creep that way, 0 elsewhere.
    """
    if "creeping" not in data.cache:
        d = _resolved_direction(data)
        slow = d == 0.0
        scales = gap_log_scales(data)
        out = np.zeros(d.size)
        th = np.asarray(data.experiment.signals.theta, dtype=float)     # as recorded: still where it rests
        rate, stick = float(data.experiment.rate_hz), float(data.options.stick_velocity)
        w = int(math.ceil(scales.encoder_step / (2.0 * stick) * rate))     # half-window [raw samples]
        if w > 0 and np.any(slow) and np.any(~slow):
            n = d.size
            idx = np.arange(n)
            back = th - th[np.maximum(idx - w, 0)]
            fwd = th[np.minimum(idx + w, n - 1)] - th
            creep = np.where(back * fwd > 0.0, (back + fwd) * rate / (2.0 * w), 0.0)
            moving = np.flatnonzero(~slow)
            k = np.searchsorted(moving, idx)
            left = np.where(k > 0, d[moving[np.maximum(k - 1, 0)]], 0.0)
            right = np.where(k < moving.size, d[moving[np.minimum(k, moving.size - 1)]], 0.0)
            fill = slow & (left == right) & (left * creep >= stick)
            out[fill] = left[fill]
        data.cache["creeping"] = out
    return data.cache["creeping"]


def motion_direction(data: GapData) -> np.ndarray:
    """Direction of the motor's motion at the raw rate: +1, -1, or 0 at rest (cached on ``data``).

    ``sign(theta')`` where the filtered speed resolves it (at or above the encoder's speed resolution,
    :func:`.residuals.gap_log_scales`); below it the motor is at rest, or, when the log is read as creeping
    (``data.creep``), it creeps where :func:`creeping` says so. The diagnosis reads a log with creeping
    samples both ways and keeps the reading whose friction fits predict the held-out data better.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray of float, shape (n_raw,)
        +1, -1 or 0 per raw sample.
    """
    if "direction" not in data.cache:
        d = _resolved_direction(data)
        if data.creep:
            fill = creeping(data)
            d = np.where(fill != 0.0, fill, d)
        data.cache["direction"] = d
    return data.cache["direction"]


def angle_noise_factor(data: GapData) -> float:
    """How many encoder steps the recorded motor angle's noise is worth, at least 1 [-] (cached on ``data``).

    A quantised angle departs from its low-pass by at most half a step, uniformly: an RMS of ``step / sqrt(12)``.
    An encoder with electrical noise (or a motor that vibrates faster than the filter) departs by more, and
    its filtered speed flickers beyond the speed resolution while the motor rests (a 16-bit closed-loop square
    whose angle jumped by up to three counts from sample to sample: its stays at rest lasted a few samples
    each). ``sqrt(12)`` times the RMS departure, in steps (the few samples of fast motion the filter cannot
    follow left out), scales the speed below which :func:`rest_share` counts a sample quiet. On the independent
    generator's logs it reads 0.83-0.97 of ``sqrt(12 n^2 + 1)`` for an encoder noise of ``n`` = 0.2-1 counts,
    and 1 without noise.
    """
    if "angle_noise_factor" not in data.cache:
        dev = np.asarray(data.experiment.signals.theta, dtype=float) - data.raw["theta"]    # the low-passed angle
        # without the samples of fast motion the filter cannot follow (beyond five robust standard deviations)
        robust = 1.4826 * float(np.median(np.abs(dev - np.median(dev))))
        sigma = float(np.sqrt(np.mean(np.square(dev[np.abs(dev) <= 5.0 * robust])))) if robust > 0.0 else 0.0
        data.cache["angle_noise_factor"] = max(1.0, math.sqrt(12.0) * sigma / gap_log_scales(data).encoder_step)
    return data.cache["angle_noise_factor"]


def _resolved_direction(data: GapData) -> np.ndarray:
    """``sign(theta')`` where the filtered speed is at or above the speed resolution, 0 below (cached).

    Also 0 inside a stay of the recorded angle where the filtered speed is more than the stay allows: the
    zero-phase filter's ringing next to a start or a stop.
    """
    if "resolved_direction" not in data.cache:
        v = np.asarray(data.raw["v"], dtype=float)
        scales = gap_log_scales(data)
        d = np.sign(v)
        d[np.abs(v) < scales.speed_resolution] = 0.0
        # inside a stay of the recorded angle the motor moves less than a count. A motor at speed v, k samples
        # after the stay's first sample and k' before its last, moved v k dt since the first if it has been
        # slowing down, or moves v k' dt until the last if it is speeding up, and it does one or the other (a
        # reversal within the count: first one, then the other): a speed beyond twice a count over the nearer of
        # the two is the zero-phase filter's ringing next to a start or a stop (an encoder of 2^21 counts at rest
        # read -2 ... +5 mrad/s before a closed-loop square's step: a Coulomb level of alternating sign on a motor
        # at rest, which LuGre's bristles smoothed over)
        start, end = _runs(np.asarray(data.experiment.signals.theta, dtype=float))
        idx = np.arange(start.size)
        k = np.minimum(idx - start, end - 1 - idx)
        d[np.abs(v) * k > 2.0 * scales.encoder_step * float(data.experiment.rate_hz)] = 0.0
        data.cache["resolved_direction"] = d
    return data.cache["resolved_direction"]


def _raw_rest(data: GapData) -> np.ndarray:
    """Raw samples at rest: no direction of motion resolved (:func:`motion_direction`)."""
    return motion_direction(data) == 0.0


def near_rest(data: GapData) -> np.ndarray:
    """Decimated rows that a motor at rest reaches through the derivative filter (cached on ``data``).

    A raw sample is *at rest* when its filtered speed is below the encoder's speed resolution
    (:func:`.residuals.gap_log_scales`); there a static friction holds whatever net torque acts, anywhere
    in ``[-F_s, F_s]``, so no friction law predicts it. The zero-phase position filter and the
    two differences smear that torque ``settling_samples(...)[0]`` raw samples to either side
    (:func:`forecast_design.friction.derivatives.settling_samples`; 20 at the default cut-off),
    into rows whose motor moves. A row is near rest when it is ``stuck`` or a raw sample at
    rest lies within that smear of it (the IDIM rule of :mod:`forecast_design.friction.selection`).

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray of bool, shape (m,)
        True for the rows a static friction law is not fitted on.
    """
    if "near_rest" not in data.cache:
        rest = _raw_rest(data)
        n = rest.size
        w = settling_samples(data.settings)[0]
        c = np.concatenate([[0], np.cumsum(rest, dtype=np.int64)])
        idx = np.arange(n)
        near = (c[np.minimum(idx + w + 1, n)] - c[np.maximum(idx - w, 0)]) > 0
        e, R = data.settings.edge_samples, data.settings.decimation_factor
        near = near[e:n - e][::R][:data.t.size]
        data.cache["near_rest"] = near | data.stuck
    return data.cache["near_rest"]


@lru_cache(maxsize=16)
def _step_overshoot(settings: FilterSettings) -> np.ndarray:
    """``o[d]``: how far the filters' output exceeds a unit level ``d`` or more raw samples from a jump [-].

    A step from -1 to +1 through the gap's filters (the zero-phase low-pass, then the decimation's
    Chebyshev anti-alias filter) rings: ``|y| - 1`` reaches 0.15 next to the jump and a few
    percent one or two decimated rows away. ``o[d]`` is its largest value at distance ``d`` or more,
    non-increasing, 0 once settled (the array ends there).
    """
    der, dec = settling_samples(settings)
    n = 4 * (der + dec) + 64
    x = np.where(np.arange(2 * n) < n, -1.0, 1.0)
    y = antialias(lowpass(x, settings), settings)
    over = np.maximum(np.abs(y) - 1.0, 0.0)
    d = np.abs(np.arange(2 * n) - n + 0.5).astype(int)      # raw samples from the jump (between n-1 and n)
    o = np.zeros(n + 1)
    np.maximum.at(o, np.minimum(d, n), over)
    return np.maximum.accumulate(o[::-1])[::-1]


def rest_distance(data: GapData) -> np.ndarray:
    """Per decimated row, the raw samples from its own sample to the nearest moving one (cached on ``data``).

    A raw sample moves when its filtered speed is at or above the encoder's speed resolution
    (:func:`.residuals.gap_log_scales`, the rest rule of :func:`near_rest`). A ``stuck`` row (its *decimated*
    speed below ``GapOptions.stick_velocity``) may still move at the raw rate (a motor creeping or
    oscillating faster than the decimated band); a row at distance 0 does.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray of int, shape (m,)
        Distance [raw samples]; the log's length when no sample moves.
    """
    if "rest_distance" not in data.cache:
        rest = _raw_rest(data)
        moving = np.flatnonzero(~rest)
        e, R = data.settings.edge_samples, data.settings.decimation_factor
        pos = e + np.arange(data.t.size) * R
        if moving.size:
            i = np.searchsorted(moving, pos)
            left = moving[np.clip(i - 1, 0, moving.size - 1)]
            right = moving[np.clip(i, 0, moving.size - 1)]
            dist = np.minimum(np.abs(pos - left), np.abs(right - pos))
        else:
            dist = np.full(data.t.size, rest.size)
        data.cache["rest_distance"] = dist
    return data.cache["rest_distance"]


def held_at_rest_rows(data: GapData) -> np.ndarray:
    """Decimated rows at rest at the raw rate too: ``stuck``, their own raw sample not moving (:func:`rest_distance`).

    There the friction holds whatever net torque acts: the rows that show a breakaway level.
    """
    return data.stuck & (rest_distance(data) > 0)


def held_level_factor(data: GapData) -> np.ndarray:
    """Per decimated row, the factor by which the filters can lift a held friction level there [-].

    A friction torque that never exceeds ``F`` at the raw rate (a static friction holding up to
    its breakaway level, a Coulomb level sliding) is seen through the zero-phase filters: next to a
    reversal, where it jumps from ``-F`` to ``+F``, the filtered torque rings up to 15 % above
    ``F`` (:func:`_step_overshoot`). On a row ``d`` raw samples from the nearest moving sample
    (:func:`rest_distance`) the held torque may read up to ``F (1 + o[d])``: a Coulomb log's rows
    at rest next to reversals read 8-40 % above ``F_c``, which a breakaway level fitted on them
    took for stiction.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray, shape (m,)
        ``1 + o[d]`` for every row.
    """
    if "held_level_factor" not in data.cache:
        o = _step_overshoot(data.settings)
        data.cache["held_level_factor"] = 1.0 + o[np.minimum(rest_distance(data), o.size - 1)]
    return data.cache["held_level_factor"]


def rest_share(data: GapData) -> np.ndarray:
    """Per decimated row, the share of its filter window the motor spends in a stay, in [0, 1] (cached).

    A stay is a run of raw samples, at least as long as the derivative filter's settling
    (:func:`forecast_design.friction.derivatives.settling_samples`), over which the recorded angle does not
    change, or the motor is quiet: no direction resolved (:func:`motion_direction`) or a filtered speed below the
    speed resolution times :func:`angle_noise_factor`; where the log is read as creeping, not the samples that
    creep (:func:`creeping`). The motor stopped there (a reversal passing through a count in a few samples is no
    stay). Its indicator goes through the equation errors' own filters and
    decimation: 1 on a row deep in a stay, 0 on one far from any, in between on the rows of a start or a stop,
    whose filter windows mix samples at rest (where a static friction holds whatever net torque acts, up to its
    level) with moving ones.

    Parameters
    ----------
    data : GapData
        Prepared equation errors.

    Returns
    -------
    ndarray, shape (m,)
        The share of every decimated row [-].
    """
    if "rest_share" not in data.cache:
        w = settling_samples(data.settings)[0]
        # runs of one reading (a noisy encoder's reading toggles at rest) or of a quiet motor (a filter's ringing
        # may resolve a direction for a few samples of a stay)
        v = np.abs(np.asarray(data.raw["v"], dtype=float))
        quiet = (motion_direction(data) == 0.0) | (v < gap_log_scales(data).speed_resolution * angle_noise_factor(data))
        stay = _long_runs(np.asarray(data.experiment.signals.theta, dtype=float), w) | _long_runs(quiet, w, where=True)
        if data.creep:
            stay &= creeping(data) == 0.0       # read as creeping: those samples move
        data.cache["rest_share"] = np.clip(data.decimate(stay.astype(float)), 0.0, 1.0)
    return data.cache["rest_share"]


def _runs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the first sample of its run of equal consecutive values of ``x`` and the one after the run."""
    edges = np.r_[0, np.flatnonzero(np.diff(x) != 0) + 1, x.size]
    lengths = np.diff(edges)
    return np.repeat(edges[:-1], lengths), np.repeat(edges[1:], lengths)


def _long_runs(x: np.ndarray, w: int, where: bool | None = None) -> np.ndarray:
    """Samples in runs of equal consecutive values of ``x`` at least ``w`` long (only runs of value ``where``)."""
    start, end = _runs(x)
    keep = end - start >= w
    return keep & (x[start] == where) if where is not None else keep
