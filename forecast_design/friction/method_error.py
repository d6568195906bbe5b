"""The friction fit's own error: the analysis repeated at twice its time scales.

A fit's Newey-West standard deviations carry the noise of the log, not the error the method
itself makes: the derivative filter's distortion of the velocity and acceleration the friction
is explained with, the discretisation of a dynamic law (LuGre's bristle step, which cannot
follow a transient shorter than a sample), the sample rule's window around stops, the
zero-order hold of the command. On logs of the independent generator that error was larger than
the intervals: LuGre's sigma1 came out 3-12 % low and sigma0 about 1 % high with intervals of
+-0.3-8 % (sigma0 covered 0 of 24 times, sigma1 1 of 24), and on some static fits viscous and
Coulomb were 0.02-0.3 % off under intervals of +-0.01-0.13 % (4.1-4.4 standard deviations).

Every one of these errors shrinks with the analysis' time scales, which the default analysis
ties to the log's rate (position filter at a tenth of the rate, decimation by ten, the stop
window, the LuGre step). :func:`method_error` repeats the identification, with the same model,
sample rule and plausible ranges, twice: on every other sample (the default analysis of half
the rate: every time scale doubles) and on every sample with the position filter's cut-off
halved (the filter alone). For an error of first order in the time scale h, ``e(h) = c h``, the
shift ``theta(2h) - theta(h) = c h`` *is* the error at h (Richardson's estimate); an error of
higher order shifts by more than it errs. The larger of the two shifts is taken as one standard
deviation of the method's error and added in quadrature to the noise's
(:func:`~forecast_design.friction.identify.fit_friction`, ``FrictionFit.std_method``).

Measured on independent logs (``benchmarks/bench_friction_coverage.py``, 2 kHz): LuGre sigma1
-10.1 / -12.5 / -3.4 / -4.6 % at h and -24.0 / -22.9 / -7.5 / -9.8 % at half the rate (the error
doubles: first order), sigma0 +0.9-1.0 % at h and +1.6-3.3 % at half the rate; the
position-friction log whose Coulomb level was 0.19 % off at 4.4 standard deviations shifts by
0.14 % at half the rate and 0.10 % at half the cut-off; a closed-loop extended-SFM log (soft
environment) whose viscous was 0.15 % off at 4.2 standard deviations shifts by 0.05 % at half
the rate and 0.35 % at half the cut-off, which is why both repetitions are made. On 12 LuGre, 24
position-friction and 12 closed-loop extended-SFM logs the intervals then hold the truth for
every parameter (72/72, 240/240, 62/62; without: 47/72, 233/240, 57/62). Cost: two more fits,
one of them on half the samples, the LuGre ones started from the fit's optimum (no start grid):
CPU time x1.3 for LuGre on 4e4 samples and x1.5 for extended SFM on 1e6 samples
(``benchmarks/bench_friction.py``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..errors import ForecastError
from ..plausibility import LogScales
from ._lsq import one_blas_thread

__all__ = ["MethodError", "method_error"]


@dataclass(frozen=True, slots=True)
class MethodError:
    """How far a fit's estimates move when the analysis is repeated at twice its time scales.

    Parameters
    ----------
    std : mapping of str to float
        The larger shift of the two repeated analyses per parameter, in the parameter's units;
        empty when both failed.
    failure : str
        Why a repeated fit failed (empty when none did).
    """

    std: Mapping[str, float]
    failure: str = ""


@one_blas_thread
def method_error(model: Any, t: np.ndarray, position: np.ndarray, force: np.ndarray,
                 params: Mapping[str, float], *, velocity: np.ndarray | None = None,
                 inertia: float | None = None, settings: Any = None, selection: Any = "auto",
                 encoder_step: float | None = None, constrain: bool = True, scales: LogScales | None = None,
                 **nonlinear_options: Any) -> MethodError:
    """Repeat a friction fit at twice its time scales and return how far each estimate moves.

    Two repetitions: on every other sample (the default analysis of half the rate, or the
    given settings with the rate and the cut-off halved), and on every sample with the position
    filter's cut-off halved (and its edge doubled). The larger shift of each estimate is its
    method error.

    Parameters
    ----------
    model : FrictionModel
        The fitted model.
    t, position, force : ndarray, shape (n,)
        The log the fit was made on: times [s], position [rad] (or [m]), explained force [N m] (or [N]).
    params : Mapping[str, float]
        The fit's estimates (natural units).
    velocity : ndarray, shape (n,), optional
        Measured velocity [rad/s].
    inertia : float, optional
        Known inertia [kg m^2] subtracted with the acceleration.
    settings : FilterSettings, optional
        The fit's explicit filter settings; None for the defaults.
    selection : SampleSelection or str
        The fit's sample rule.
    encoder_step : float, optional
        Position resolution [rad] (or [m]).
    constrain : bool
        As the fit.
    scales : LogScales, optional
        The log's magnitudes (the plausible ranges the searches stay in).
    **nonlinear_options
        As the fit (``max_iter``, ``sigma0_init``).

    Returns
    -------
    MethodError
        ``max |theta' - theta|`` over the repeated analyses per parameter, and the failures.
    """
    from .derivatives import default_filter_settings
    from .identify import _estimate, prepare_identification_data

    t = np.asarray(t, dtype=float)
    position, force = np.asarray(position, dtype=float), np.asarray(force, dtype=float)
    rate = 1.0 / float(np.median(np.diff(t))) if t.size > 1 else float("nan")
    if settings is None:
        kw = {} if model.is_linear else {"decimation": "subsample", "decimation_factor": 1}
        base = default_filter_settings(rate, **kw)
    else:
        base = dataclasses.replace(settings, rate_hz=rate)
    half_cut = dataclasses.replace(base, position_cutoff_hz=base.position_cutoff_hz / 2.0,
                                   edge_samples=2 * base.edge_samples + 1)
    half_rate = None if settings is None else dataclasses.replace(
        base, rate_hz=rate / 2.0, position_cutoff_hz=base.position_cutoff_hz / 2.0)
    if scales is not None:
        half_scales = dataclasses.replace(scales, rate_hz=scales.rate_hz / 2.0, position_cutoff_hz=(
            None if scales.position_cutoff_hz is None else scales.position_cutoff_hz / 2.0))
    step = slice(None, None, 2)
    runs = (("half the rate", step, half_rate, None if scales is None else half_scales),
            ("half the filter cut-off", slice(None), half_cut, scales))
    shifts: list[np.ndarray] = []
    failures: list[str] = []
    for label, rows, settings_k, scales_k in runs:
        try:
            data = prepare_identification_data(t[rows], position[rows], force[rows], model,
                                               velocity=None if velocity is None else np.asarray(velocity)[rows],
                                               inertia=inertia, settings=settings_k, selection=selection,
                                               encoder_step=encoder_step)
            if int(data.used.sum()) <= 2 * len(model.names):
                raise ForecastError(f"{int(data.used.sum())} samples left")
            warm = {} if model.is_linear else {"start": params}   # the same optimum, not another basin
            est = _estimate(model, data, constrain=constrain, check=False, scales=scales_k, covariance=False,
                            **warm, **nonlinear_options)
        except (ForecastError, ValueError, np.linalg.LinAlgError) as exc:
            failures.append(f"the fit at {label} failed: {exc}")
            continue
        shifts.append(np.abs(np.asarray(est.params, dtype=float) - [float(params[n]) for n in model.names]))
    if not shifts:
        return MethodError(MappingProxyType({}), "; ".join(failures))
    std = np.max(shifts, axis=0)
    return MethodError(MappingProxyType({n: float(v) for n, v in zip(model.names, std)}), "; ".join(failures))
