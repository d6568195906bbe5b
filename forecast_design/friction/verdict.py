"""The verdict on a friction fit: every number graded by :mod:`forecast_design.plausibility`.

A converged solver is not a verdict. Each parameter of a
:class:`~forecast_design.friction.FrictionFit` gets one of the four
statuses of :func:`forecast_design.plausibility.assess` (``identified``,
``at_bound``, ``uncertain``, ``implausible``) from its plausible range
(:func:`~forecast_design.plausibility.friction_bound` on the log's scales),
the bounds the fit held it on, and its (autocorrelation-consistent)
standard deviation. The fit as a whole is ``identified``, ``partly
identified`` or ``not identifiable``; LuGre, whose bristle and Stribeck
parameters need gross sliding, is also checked for it.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..plausibility import LogScales, ParameterStatus, assess, friction_bound, speed_resolution
from .terms import FrictionModel, LuGre, Stribeck

__all__ = ["grade", "identifiability", "SLIDING_MIN"]

#: Smallest fraction of the samples in gross sliding for a Stribeck or LuGre curve to be identifiable [-].
SLIDING_MIN = 0.05
#: Gross sliding is faster than 3 x the Stribeck velocity (the decay is then below exp(-9) ~ 1e-4, so
#: the Coulomb level is observed, not extrapolated) ...
GROSS_VS = 3.0
#: ... and faster than 10 encoder speed resolutions (one count per derivative-filter window,
#: :func:`forecast_design.plausibility.speed_resolution`): the quantisation's RMS speed noise through the
#: filter is ``(s / sqrt 12) rate sqrt((2 pi f_c / rate)^3 / (3 pi))``, 0.47 resolutions at a cut-off of a
#: tenth of the rate, so there one sample resolves the speed to 5 %.
GROSS_RESOLUTION = 10.0


def _bound_name(name: str) -> str:
    # position-friction harmonics (coulomb_sinN) are signed amplitudes: plausibility's psinN/pcosN
    if name.startswith(("coulomb_sin", "coulomb_cos")):
        return "p" + name[len("coulomb_"):]
    return name


def grade(model: FrictionModel, params: Mapping[str, float], std: Mapping[str, float], scales: LogScales, *,
          held: Mapping[str, tuple[float, float]] | None = None,
          overrides: Mapping[str, tuple[str, str]] | None = None,
          active: tuple[str, ...] = ()) -> dict[str, ParameterStatus]:
    """Status of every fitted parameter.

    Parameters
    ----------
    model : FrictionModel
        The fitted model.
    params, std : Mapping[str, float]
        Estimates and standard deviations (NaN for a parameter held on a bound).
    scales : LogScales
        The log's magnitudes (plausible ranges).
    held : Mapping[str, (float, float)], optional
        Parameters the fit held on a bound, with the range it searched.
    overrides : Mapping[str, (str, str)], optional
        Statuses the fit decided itself (e.g. an undefined Stribeck velocity).
    active : tuple of str
        Active constraint labels (for the reason text).

    Returns
    -------
    dict of str to ParameterStatus
        In ``model.names`` order.
    """
    held = held or {}
    overrides = overrides or {}
    out: dict[str, ParameterStatus] = {}
    for name in model.names:
        value = float(params[name])
        # sigma0 is judged by the fitted breakaway level: static / sigma0 is the presliding displacement
        bound = None if name == "inertia" else friction_bound(_bound_name(name), scales,
                                                                  static=params.get("static"))
        rng = None if bound is None else (bound.lo, bound.hi)
        s = float(std[name])
        if name in overrides:
            status, reason = overrides[name]
            out[name] = ParameterStatus(name=name, value=value, std=s if math.isfinite(s) else None,
                                        status=status, reason=reason, plausible=rng)
            continue
        st = assess(name, value, std=None if name in held else s, bound=bound, solver_bounds=held.get(name))
        if name in held and st.status in ("identified", "uncertain"):
            # the solver stopped within its tolerance of the bound
            lo, hi = held[name]
            label = next((a for a in active if a.startswith(name) or name in a.split()), "")
            end = lo if abs(value - lo) <= abs(value - hi) else hi
            st = ParameterStatus(name=name, value=value, std=None, status="at_bound",
                                 reason=f"{name} = {value:.4g} is held on the bound {end:.4g} of the fit"
                                        + (f" ({label})" if label else ""), plausible=rng)
        out[name] = st
    return out


def identifiability(model: FrictionModel, status: Mapping[str, ParameterStatus], data: Any,
                    interval95: Mapping[str, tuple[float, float]] | None = None) -> str:
    """One line on the whole fit: ``identified``, ``partly identified: ...``, ``model inadequate: ...``,
    ``imprecise: ...`` (every friction parameter only to its interval) or ``not identifiable: ...``
    (the log carries no information on them; the ``identify`` verb exits 3).

    A Stribeck or LuGre fit needs *gross sliding*: at least :data:`SLIDING_MIN`
    of the samples faster than ``max(3 v_s_hi, 10 speed_resolution)``, with
    ``v_s_hi`` the upper end of the Stribeck velocity's 95 % interval (when
    it is identified) and ``speed_resolution = encoder_step x position_cutoff_hz``
    (:func:`forecast_design.plausibility.speed_resolution`). Without
    it the curve parameters (and LuGre's damping sigma1) are downgraded to
    ``uncertain`` in `status` (modified in place when it is a dict) and the
    fit is declared not identifiable; LuGre's sigma0 (presliding stiffness,
    observed at the stops) keeps its own grade.

    Parameters
    ----------
    model : FrictionModel
        The fitted model.
    status : Mapping[str, ParameterStatus]
        From :func:`grade`.
    data : IdentificationData
        The prepared log (velocity, encoder step, rate).
    interval95 : Mapping[str, (float, float)], optional
        The fit's intervals (for ``stribeck_velocity``).

    Returns
    -------
    str
        The verdict; ``model inadequate: ...`` when every friction parameter is downgraded by the
        residual's structure (:mod:`forecast_design.friction.adequacy`): the log identifies a richer
        model, not this one.
    """
    term = model.nonlinear_term
    if isinstance(term, (LuGre, Stribeck)):
        vs_st = status["stribeck_velocity"]
        vs_hi = 0.0
        if vs_st.identified and interval95 is not None and math.isfinite(interval95["stribeck_velocity"][1]):
            vs_hi = float(interval95["stribeck_velocity"][1])
        v_res = speed_resolution(float(data.encoder_step), data.settings.rate_hz, data.settings.position_cutoff_hz)
        gross = max(GROSS_VS * vs_hi, GROSS_RESOLUTION * v_res)
        v = np.abs(np.asarray(data.velocity, dtype=float))
        frac = float(np.mean(v > gross)) if v.size else 0.0
        if frac < SLIDING_MIN:
            why = (f"too little sliding: {100 * frac:.2g} % of the samples are faster than {gross:.3g} "
                   f"(gross sliding: 3 x the Stribeck velocity and 10 encoder speed resolutions; need "
                   f"{100 * SLIDING_MIN:g} %), so the friction curve is not observed")
            lost = [n for n in term.names() if n != "sigma0"]
            if isinstance(status, dict):
                for n in lost:
                    st = status[n]
                    if st.status in ("identified", "uncertain"):
                        status[n] = ParameterStatus(name=n, value=st.value, std=st.std, status="uncertain",
                                                    reason=f"not identifiable: {why}", plausible=st.plausible)
            kept = [n for n in status if n not in lost and status[n].identified]
            return f"not identifiable: {why}" + (f"; still identified: {', '.join(kept)}" if kept else "")
    bad = [n for n, st in status.items() if not st.identified]
    if not bad:
        return "identified"
    friction = [n for n in status if n not in ("inertia", "offset")]
    if friction and all(n in bad for n in friction):
        reasons = "; ".join(f"{n}: {status[n].status}" for n in friction)
        if all(status[n].reason.startswith("model inadequate") for n in friction):
            # the log identifies a richer model, not this one: an answer about the model, not the log
            return f"model inadequate: no parameter of this model is identified ({reasons})"
        if any(status[n].status == "uncertain" for n in friction):
            # the log pins the numbers, only less precisely than an identified number promises
            return f"imprecise: no friction parameter is known to +-10 % ({reasons}); use the intervals"
        return f"not identifiable: no friction parameter is identified ({reasons})"
    return "partly identified: " + ", ".join(f"{n} ({status[n].status})" for n in bad) + " not identified"
