"""What the diagnosis plots show, computed here so that the plotting layer only draws.

:func:`diagnosis_views` turns a :class:`~forecast_design.gap.diagnose.Diagnosis` into arrays:
per-equation residuals before (calibrated nominal model) and after (with the verdict effect),
their spectra, the measured frequency response tau_m -> tau_s with its coherence, the
motor-side residual against speed and angle, the held-out overlay and the replay traces.
Two readability decisions are made here, from the data:

* an equation whose nominal residual is at the level of the log's rounding (RMS at most
  ten times the rounding of its largest term at the digits the file was written with) only
  shows numerical noise: it is left out of the plots and named in ``dropped``;
* frequencies where the magnitude-squared coherence between tau_m and tau_s is below
  ``coherence_threshold`` are marked: there the measured response is not a measurement of
  the linear plant (too little excitation, noise or nonlinearity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .grading import QUALIFIED_GRADES
from .locate import measured_response, residual_psd
from .replay import replay_trace
from .residuals import significant_digits

__all__ = ["DiagnosisViews", "FrequencyResponseView", "OperatingView", "diagnosis_views", "measured_response"]

COHERENCE_THRESHOLD = 0.8     # magnitude-squared coherence below which the measured response is greyed [-]


@dataclass(frozen=True, slots=True)
class FrequencyResponseView:
    """Measured (H1) and nominal response tau_m -> tau_s with the coherence of the estimate.

    Attributes
    ----------
    f_hz : ndarray
        Frequencies [Hz] (0 excluded, up to the decimated Nyquist frequency).
    measured : ndarray of complex
        H1 = S_us / S_uu at ``f_hz`` [N m / N m].
    nominal_f_hz, nominal : ndarray
        A dense log grid over the same range [Hz] and the nominal P(j 2 pi f) there [N m / N m].
    coherence : ndarray
        Magnitude-squared coherence of tau_m and tau_s (:func:`scipy.signal.coherence`) [-].
    threshold : float
        Coherence below which the estimate is not trusted [-].
    """

    f_hz: np.ndarray
    measured: np.ndarray
    nominal_f_hz: np.ndarray
    nominal: np.ndarray
    coherence: np.ndarray
    threshold: float

    @property
    def low(self) -> np.ndarray:
        """True where the coherence is below the threshold."""
        return self.coherence < self.threshold

    def low_bands_hz(self) -> list[tuple[float, float]]:
        """Contiguous low-coherence stretches as (lo, hi) [Hz], half a bin either side."""
        if self.f_hz.size == 0:
            return []
        df = float(np.median(np.diff(self.f_hz))) if self.f_hz.size > 1 else 1.0
        bands, start = [], None
        for f, low in zip(self.f_hz, self.low):
            if low and start is None:
                start = f
            if not low and start is not None:
                bands.append((start - df / 2, prev + df / 2))
                start = None
            prev = f
        if start is not None:
            bands.append((start - df / 2, prev + df / 2))
        return bands


@dataclass(frozen=True, slots=True)
class OperatingView:
    """Motor-side residual against motor speed and angle.

    Attributes
    ----------
    speed_rad_s : ndarray
        Motor speed [rad/s].
    angle_rad : ndarray
        Motor angle [rad]: modulo 2 pi when the motor turns through a revolution or more,
        else relative to its smallest value (no wrap artefact).
    wrapped : bool
        Whether ``angle_rad`` is modulo 2 pi.
    before, after : ndarray
        Motor-equation residual before and after (None without a verdict) [N m].
    """

    speed_rad_s: np.ndarray
    angle_rad: np.ndarray
    wrapped: bool
    before: np.ndarray
    after: np.ndarray | None


@dataclass(frozen=True, slots=True)
class DiagnosisViews:
    """Everything the diagnosis plots draw.

    Attributes
    ----------
    effect : str
        The verdict (``none``: no "after" curves).
    t : ndarray
        Decimated sample times [s].
    equations : tuple of str
        Equations worth drawing (numerical-noise ones left out).
    dropped : dict
        Equation -> RMS of its residual [N m], for those left out.
    before, after, prediction : dict of ndarray
        Residual per equation before, after, and the verdict effect's prediction [N m]
        (``after``/``prediction`` empty when the verdict is ``none``).
    psd_f_hz, psd_before, psd_after : ndarray
        Welch PSD of the residual summed over the drawn equations [N^2 m^2/Hz]
        (``psd_after`` None without a verdict).
    response : FrequencyResponseView
        Measured vs nominal response with coherence.
    operating : OperatingView
        Motor residual against speed and angle.
    held_out : ndarray of bool
        The held-out stretch shown in the before/after overlay (``window_s`` long).
    replay : dict of ndarray or None
        :func:`~forecast_design.gap.replay.replay_trace` over the nominal model's worst window.
    reversals : dict or None
        A Coulomb verdict's laws around the reversals (:class:`~forecast_design.gap.reversals.ReversalTest`): the up
        to four windows where the two laws' predictions differ most, ``t_s`` (L,) from the reversal [s],
        ``theta_counts``, ``coulomb_counts``, ``bump_counts`` (n, L) [counts], ``window_start_s`` (n,) [s],
        ``rms_counts`` (Coulomb, bump) over all windows, ``p_value``, ``names_stiction``.
    time_windows_s, frequency_band_hz, speed_band_rad_s, angle_span_rad
        Where the gap lies (the diagnosis' location) [s], [Hz], [rad/s], [rad].
    gap_before, gap_after : float
        Held-out gap before and after [N m].
    grade : str
        The verdict's grade (``clear``, ``weak``, ``probable``, ``none``).
    """

    effect: str
    t: np.ndarray
    equations: tuple[str, ...]
    dropped: dict
    before: dict
    after: dict
    prediction: dict
    psd_f_hz: np.ndarray
    psd_before: np.ndarray
    psd_after: np.ndarray | None
    response: FrequencyResponseView
    operating: OperatingView
    held_out: np.ndarray
    replay: dict | None
    time_windows_s: tuple = ()
    frequency_band_hz: tuple = (math.nan, math.nan)
    speed_band_rad_s: tuple = (math.nan, math.nan)
    angle_span_rad: float = math.nan
    gap_before: float = math.nan
    gap_after: float = math.nan
    reversals: dict | None = None
    grade: str = "clear"

    @property
    def qualified(self) -> bool:
        """Whether the verdict's grade is said beside it (:data:`.grading.QUALIFIED_GRADES`)."""
        return self.grade in QUALIFIED_GRADES

    @property
    def has_after(self) -> bool:
        """Whether there is a verdict effect (and "after" curves)."""
        return self.effect != "none"


def _split(data: Any, stacked: np.ndarray) -> dict[str, np.ndarray]:
    m = data.t.size
    return {eq: stacked[i * m:(i + 1) * m] for i, eq in enumerate(data.equations)}


def _rounding_floor(data: Any, eq: str) -> float:
    """Ten times the RMS rounding of the equation's largest term at the log's written digits [N m]."""
    sig = data.experiment.signals
    cols = [np.asarray(sig.tau_m, float), np.asarray(sig.tau_s, float)]
    digits = min(significant_digits(c) for c in cols)
    scale = max(float(np.sqrt(np.mean(c ** 2))) for c in cols)
    rel = max(0.5 * 10.0 ** (1 - digits), 4.0 * np.finfo(float).eps)
    return 10.0 * rel * scale


def diagnosis_views(diag: Any, *, window_s: float = 2.0, coherence_threshold: float = COHERENCE_THRESHOLD,
                    nperseg: int = 1024) -> DiagnosisViews:
    """Compute what the diagnosis plots show.

    Parameters
    ----------
    diag : Diagnosis
        Result of :func:`forecast_design.gap.diagnose`.
    window_s : float
        Length of the held-out stretch of the before/after overlay [s].
    coherence_threshold : float
        Coherence below which the measured response is marked as untrusted [-].
    nperseg : int
        Welch segment length of the measured response [samples].

    Returns
    -------
    DiagnosisViews
        Arrays for :mod:`forecast_design.plotting.gap`.
    """
    from ..symbolic import force_plant_tf

    data = diag.data
    effect = str(diag.effect)
    fit = diag.fits.get(effect) if effect != "none" else None
    before_all = _split(data, diag.baseline.residual)
    after_all = _split(data, fit.residual) if fit is not None else {}
    pred_all = _split(data, fit.prediction) if fit is not None else {}
    dropped = {}
    for eq, r in before_all.items():
        rms = float(np.sqrt(np.mean(r ** 2)))
        rms_after = float(np.sqrt(np.mean(after_all[eq] ** 2))) if eq in after_all else 0.0
        if max(rms, rms_after) <= _rounding_floor(data, eq):
            dropped[eq] = rms
    eqs = tuple(eq for eq in data.equations if eq not in dropped) or tuple(data.equations)
    keep = {eq: before_all[eq] for eq in eqs}

    def psd(stacked_parts: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        # the drawn equations only, zeros in place of the dropped ones
        return residual_psd(data, np.concatenate([stacked_parts[eq] if eq in eqs else np.zeros(data.t.size)
                                                  for eq in data.equations]))

    f_psd, p_before = psd(before_all)
    p_after = psd(after_all)[1] if fit is not None else None

    exp = data.experiment
    f, h1, coh = measured_response(exp.signals.tau_m, exp.signals.tau_s, exp.rate_hz, nperseg=nperseg)
    sel = (f > 0) & (f <= data.settings.decimated_rate_hz / 2)
    f_dense = np.geomspace(f[sel][0], f[sel][-1], 400) if np.any(sel) else np.zeros(0)
    nominal = force_plant_tf(exp.design).freqresp(2.0 * np.pi * f_dense)
    response = FrequencyResponseView(f_hz=f[sel], measured=h1[sel], nominal_f_hz=f_dense, nominal=nominal,
                                     coherence=coh[sel], threshold=float(coherence_threshold))

    theta = np.asarray(data.columns["theta_sub"], dtype=float)
    span = float(np.ptp(theta)) if theta.size else 0.0
    wrapped = span >= 2.0 * math.pi
    angle = np.mod(theta, 2.0 * math.pi) if wrapped else theta - (theta.min() if theta.size else 0.0)
    operating = OperatingView(speed_rad_s=np.asarray(data.columns["v_sub"], dtype=float), angle_rad=angle,
                              wrapped=wrapped, before=before_all["motor"], after=after_all.get("motor"))

    held = np.flatnonzero(data.held_out)
    t0 = data.t[held[0]] if held.size else data.t[0]
    window = (data.t >= t0) & (data.t < t0 + window_s)

    rc = diag.replay
    replay = None
    if rc is not None:
        start = rc.worst_windows_s[0][0] if rc.worst_windows_s else float(data.t[0])
        replay = replay_trace(data, fit, start, window_s=rc.window_s)
    rv = diag.reversals
    reversals = None
    if rv is not None and rv.traces:
        tr = rv.traces
        # where the laws' predictions differ most, whichever the log sides with
        show = np.argsort(np.abs(tr["coulomb_counts"] - tr["bump_counts"]).max(axis=1))[::-1][:4]
        reversals = {"t_s": tr["t_s"], **{k: tr[k][show] for k in ("theta_counts", "coulomb_counts", "bump_counts",
                                                                   "window_start_s")},
                     "rms_counts": rv.held_out_rms_counts, "p_value": rv.p_value, "names_stiction": rv.names_stiction}
    return DiagnosisViews(effect=effect, t=data.t, equations=eqs, dropped=dropped, before=keep,
                          after={eq: after_all[eq] for eq in eqs if eq in after_all},
                          prediction={eq: pred_all[eq] for eq in eqs if eq in pred_all},
                          psd_f_hz=f_psd, psd_before=p_before, psd_after=p_after, response=response,
                          operating=operating, held_out=window, replay=replay,
                          time_windows_s=tuple(tuple(w) for w in diag.location.time_windows_s),
                          frequency_band_hz=tuple(diag.location.frequency_band_hz),
                          speed_band_rad_s=tuple(diag.location.speed_band_rad_s),
                          angle_span_rad=float(diag.location.angle_span_rad),
                          gap_before=float(diag.gap_before), gap_after=float(diag.gap_after), reversals=reversals,
                          grade=str(diag.grade))
