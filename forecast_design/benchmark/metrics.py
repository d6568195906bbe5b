"""Performance indicators of one run and of a set of repetitions (the Forecast methodology, Section 2).

Per run (step reference of height A): the run's final value ``y_f`` is the mean of its last 10 %
(the final-value window); every percentage and band is relative to the reference step |A|, so a
run that ends near zero (stuck by friction) cannot turn a small excursion into a huge percentage
(the convention MATLAB's ``stepinfo`` and python-control's ``step_info`` allow through their
final-value and threshold arguments; :data:`INDICATOR_DEFINITIONS` states it in words):

* ``mae_N_m``: mean |tau_s - tau_s,expected| against the frictionless expected response
  (the same controller on the nominal plant without friction, compensator or noise: the
  red dashed lines of Figs. 10-12);
* ``rise_time_s``: 10 % to 90 % of ``y_f``, first crossings (NaN when ``y_f`` is not on the
  step's side of zero);
* ``overshoot_percent``: ``100 (peak - y_f) / |A|``, 0 without overshoot;
* ``settling_time_s``: time after the step from which ``|tau_s - y_f| <= 2 % |A|`` holds to the
  end; the run is ``settled`` only when that holds over the whole final-value window, and an
  unsettled run has no settling time (NaN, counted, never the last sample's time);
* ``steady_state_error_N_m``: ``A - y_f``.

Per run (chirp reference): ``bandwidth_hz``, the lowest frequency at which the measured
tau_s / tau_r gain falls 3 dB below its value at the chirp's start frequency
(:func:`tracking_bandwidth_hz`).

Per set of repetitions: ``repeatability``, the mean pairwise zero-lag cross-correlation
of tau_s (Table 3, :func:`forecast_design.reproduce.pairwise_xcorr`); per run the mean
correlation with the other repetitions (whose mean is the set's value).

Per loop: ``disk_margin`` and ``stable``, the balanced disk margin and nominal stability of the
sampled force loop with the compensator (:func:`sampled_loop_margin`, through
:func:`forecast_design.analysis.loop_margins`; the SFM is a feed-forward and leaves the
plant's margin).
"""

from __future__ import annotations

import math
import numpy as np

from ..analysis import loop_margins
from ..loops import COMMAND_DELAY_SAMPLES
from ..margins import DiskMargin
from ..errors import ParameterError
from ..params import Compensator, Design
from ..reproduce import pairwise_xcorr, pairwise_xcorr_per_run, xcorr_se_from_per_run

__all__ = ["step_metrics", "tracking_bandwidth_hz", "frequency_response", "repeatability_per_run",
           "pairwise_xcorr", "xcorr_se_from_per_run", "sampled_loop_margin", "METRICS", "HIGHER_IS_BETTER",
           "INDICATOR_DEFINITIONS", "SETTLING_BAND", "FINAL_WINDOW"]

#: Metric columns of the result table, in order.
METRICS = ("repeatability", "mae_N_m", "rise_time_s", "overshoot_percent", "settling_time_s",
           "steady_state_error_N_m", "bandwidth_hz", "disk_margin")
#: Metrics where larger is better (the others: smaller, or smaller magnitude for the error).
HIGHER_IS_BETTER = frozenset({"repeatability", "bandwidth_hz", "disk_margin"})
#: Settling band, a fraction of the reference step |A| [-].
SETTLING_BAND = 0.02
#: Final-value window, a fraction of the run after the step [-].
FINAL_WINDOW = 0.1

#: Each indicator and flag in words (the report and ``summary.json`` carry them).
INDICATOR_DEFINITIONS = {
    "final value": "y_f = mean of tau_s over the last 10 % of the run after the step (the final-value window)",
    "repeatability": "mean pairwise zero-lag cross-correlation (Pearson) of tau_s over the repetitions (Table 3); "
                     "per run: its mean correlation with the other repetitions",
    "mae_N_m": "mean |tau_s - expected| against the frictionless expected response (same controller, nominal "
               "plant, no friction, no compensator, no noise) [N m]",
    "rise_time_s": "10 % to 90 % of y_f, first crossings, linear interpolation [s]; empty when y_f is not on the "
                   "step's side of zero",
    "overshoot_percent": "100 (peak - y_f) / |A|, relative to the reference step A so that a run ending near zero "
                         "cannot dominate a set; 0 without overshoot [%]",
    "settling_time_s": "time after the step from which |tau_s - y_f| <= 2 % of |A| holds to the end [s]; empty "
                       "(NaN) when the run did not settle",
    "settled": "the run stays within 2 % of |A| of y_f over the whole final-value window (else it did not "
               "settle: no settling time, counted in unsettled_runs)",
    "steady_state_error_N_m": "A - y_f [N m]",
    "bandwidth_hz": "-3 dB frequency of tau_s / tau_r from a chirp reference [Hz]",
    "disk_margin": "balanced disk margin of the sampled force loop (controller, compensator, testbed, "
                   "environment; broken at the controller output; 0 when unstable) at the control rate with the "
                   "command applied in the period it is computed (delay_samples = 0, the toolbox's one convention: "
                   "the virtual testbed, the firmware and `margins --sampled` use it) [-]",
    "passive": "load-independent: the cell's force-controlled SEA, seen from the environment at the link's end, is "
               "a passive one-port (Colgate and Hogan), so it stays stable with every passive environment "
               "(forecast_design.analyse_passivity; continuous loop, the compensator believing the cell's "
               "environment); empty where it does not apply (code without a linearisation, a locked belief)",
    "stable": "the cell's sampled force loop is nominally stable (characteristic polynomial) and no run nor the "
              "expected response diverged; empty when the controller has no linear model and nothing diverged",
    "aggregates": "per environment over its runs; over the set over the environments whose cell is not unstable "
                  "(excluded_cells counts those left out); means skip runs without a value (unsettled_runs counts "
                  "the runs without a settling time)",
}


def _first_crossing(t: np.ndarray, y: np.ndarray, level: float) -> float:
    idx = np.nonzero(y >= level)[0]
    if idx.size == 0:
        return math.nan
    i = int(idx[0])
    if i == 0:
        return float(t[0])
    # linear interpolation between the samples around the crossing
    y0, y1 = y[i - 1], y[i]
    return float(t[i - 1] + (level - y0) / (y1 - y0) * (t[i] - t[i - 1]))


def step_metrics(t: np.ndarray, y: np.ndarray, *, amplitude: float, t0: float = 0.0,
                 band: float = SETTLING_BAND) -> dict[str, float | bool]:
    """Rise time, overshoot, settling time and steady-state error of one step response.

    The conventions are :data:`INDICATOR_DEFINITIONS`: rise time on the run's own final value,
    overshoot and the settling band relative to the reference step ``|amplitude|``.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times [s].
    y : ndarray, shape (n,)
        Response (tau_s) [N m].
    amplitude : float
        Step height of the reference [N m] (non-zero).
    t0 : float
        Time of the step [s].
    band : float
        Settling band, a fraction of ``|amplitude|`` [-].

    Returns
    -------
    dict
        ``rise_time_s``, ``overshoot_percent``, ``settling_time_s`` (NaN when not settled),
        ``steady_state_error_N_m``, ``final_N_m`` and ``settled`` (bool).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.shape != y.shape or t.ndim != 1 or t.size < 10:
        raise ParameterError(f"step_metrics needs two equal 1-D arrays of >= 10 samples, got {t.shape}, {y.shape}",
                             name="y", value=y.shape)
    if amplitude == 0.0 or not math.isfinite(amplitude):
        raise ParameterError("step amplitude must be finite and non-zero", name="amplitude", value=amplitude)
    sign = 1.0 if amplitude > 0 else -1.0
    scale = abs(amplitude)
    after = t >= t0
    ts, ys = t[after] - t0, sign * y[after]
    window = max(1, int(ys.size * FINAL_WINDOW))
    final = float(np.mean(ys[-window:]))
    out: dict[str, float | bool] = {"final_N_m": sign * final, "steady_state_error_N_m": float(amplitude - sign * final)}
    if final > 0.0:
        out["rise_time_s"] = _first_crossing(ts, ys, 0.9 * final) - _first_crossing(ts, ys, 0.1 * final)
    else:
        out["rise_time_s"] = math.nan
    out["overshoot_percent"] = float(max(0.0, (np.max(ys) - final) / scale * 100.0))
    outside = np.nonzero(np.abs(ys - final) > band * scale)[0]
    first_in = 0 if outside.size == 0 else int(outside[-1]) + 1      # in the band from here to the end
    settled = first_in <= ys.size - window
    out["settled"] = bool(settled)
    out["settling_time_s"] = float(ts[first_in]) if settled else math.nan
    return out


def frequency_response(r: np.ndarray, y: np.ndarray, rate_hz: float, f_lo: float, f_hi: float,
                       bands: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Empirical frequency response y/r from one record, averaged over log-spaced bands.

    Parameters
    ----------
    r, y : ndarray, shape (n,)
        Input (reference) and output (tau_s) [N m].
    rate_hz : float
        Sampling rate [Hz].
    f_lo, f_hi : float
        Band of the excitation [Hz].
    bands : int
        Log-spaced frequency bands [-].

    Returns
    -------
    f_hz : ndarray
        Geometric band centres [Hz] (bands with no FFT bin dropped).
    H : ndarray of complex
        ``sum Y conj(R) / sum |R|^2`` over each band's bins.
    """
    r = np.asarray(r, dtype=float) - np.mean(r)
    y = np.asarray(y, dtype=float) - np.mean(y)
    R, Y = np.fft.rfft(r), np.fft.rfft(y)
    f = np.fft.rfftfreq(r.size, 1.0 / rate_hz)
    edges = np.geomspace(f_lo, f_hi, bands + 1)
    fc, H = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        den = np.sum(np.abs(R[sel]) ** 2)
        if not np.any(sel) or den == 0.0:
            continue
        fc.append(math.sqrt(lo * hi))
        H.append(np.sum(Y[sel] * np.conj(R[sel])) / den)
    return np.array(fc), np.array(H)


def tracking_bandwidth_hz(r: np.ndarray, y: np.ndarray, rate_hz: float, f_lo: float, f_hi: float) -> float:
    """Lowest frequency where the tracking gain |tau_s / tau_r| is 3 dB below its low-frequency value.

    Parameters
    ----------
    r, y : ndarray, shape (n,)
        Chirp reference and measured tau_s [N m].
    rate_hz : float
        Sampling rate [Hz].
    f_lo, f_hi : float
        The chirp's start and end frequencies [Hz].

    Returns
    -------
    float
        Bandwidth [Hz], interpolated in log frequency between bands; ``f_hi`` clipped (inf is
        not claimed) when the gain never drops 3 dB within the chirp; NaN when the record is
        too short to resolve ``f_lo``.
    """
    f, H = frequency_response(r, y, rate_hz, f_lo, f_hi)
    if f.size < 3:
        return math.nan
    gain = np.abs(H)
    ref = np.mean(gain[:2])
    below = np.nonzero(gain < ref / math.sqrt(2.0))[0]
    if below.size == 0:
        return float(f_hi)
    i = int(below[0])
    if i == 0:
        return float(f[0])
    g0, g1 = gain[i - 1], gain[i]
    target = ref / math.sqrt(2.0)
    x = (g0 - target) / (g0 - g1)
    return float(math.exp(math.log(f[i - 1]) + x * (math.log(f[i]) - math.log(f[i - 1]))))


def repeatability_per_run(responses: np.ndarray) -> np.ndarray:
    """Each run's mean zero-lag correlation with the other repetitions [-].

    Parameters
    ----------
    responses : ndarray, shape (m, n)
        One response per row, m >= 2.

    Returns
    -------
    ndarray, shape (m,)
        Its mean equals :func:`pairwise_xcorr` of the set; :func:`xcorr_se_from_per_run` turns it
        into the set value's jackknife standard error.
    """
    x = np.asarray(responses, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2:
        raise ParameterError(f"repeatability needs at least two responses as rows, got shape {x.shape}",
                             name="responses", value=x.shape)
    return pairwise_xcorr_per_run(x)


def sampled_loop_margin(design: Design, compensator: Compensator, rate_hz: float = 2000.0) -> DiskMargin | None:
    """Disk margin and stability of the sampled force loop the runs were made with.

    The loop as the virtual testbed runs it: sampled at `rate_hz`, the command applied in the period
    it is computed (``delay_samples =`` :data:`~forecast_design.loops.COMMAND_DELAY_SAMPLES` ``= 0``; on a small SEA where the continuous loop keeps a margin of
    0.5 this sampled loop, like the simulation, is unstable).

    Parameters
    ----------
    design : Design
        Testbed, environment and controller.
    compensator : Compensator
        Friction compensator: its linear part is in the loop (an observer's filters; an SFM's
        viscous feed-forward when it carries its identified friction).
    rate_hz : float
        Control rate [Hz].

    Returns
    -------
    DiskMargin or None
        :func:`forecast_design.analysis.loop_margins` (``alpha`` [-], 0 when unstable; ``stable``);
        None for a controller written as code without a linearisation (a Python controller's
        ``transfer_function()`` is analysed when it has one).
    """
    if design.controller is not None and not design.controller.has_equations:
        return None     # code without a linearisation: no loop to analyse (the spec says so)
    comp = compensator if compensator.is_observer or compensator.friction else Compensator(kind="none")
    return loop_margins(design, comp, sampled=True, rate_hz=rate_hz, delay_samples=COMMAND_DELAY_SAMPLES)
