"""What a Q cutoff costs and buys: the trade-off the tuner resolves (``tune-q --plot``).

A higher cutoff w_q rejects friction over a wider band but, with a nominal plant that differs
from the true one, eats disk margin. :func:`cutoff_tradeoff` evaluates both against the cutoff
for one observer over an environment set:

* the cost: the worst-case margin ratio min_e alpha_obs,e / alpha_plant,e over the set, with the
  tuner's own exact margins (:func:`forecast_design.tuning.tune_q` verifies its answer with the
  same evaluation), and the environment attaining it (the binding one);
* the gain: the friction-rejection bandwidth, the lowest frequency where the observer stops
  attenuating friction by at least 3 dB relative to the loop without it, the worst (smallest)
  over the set.

Friction-rejection ratio. Friction tau_f opposes the motor torque, so the plant's input is
x = tau_m - tau_f. With tau_m = u + G_m tau_m + G_s tau_s + G_theta theta, u = -C_F tau_s
(reference zero), G_m = Q = 1/D_q, G_s = -Q A, G_theta = -Q B and
M = A P + B P_theta - 1 (:mod:`forecast_design.loops.response`), solving for x gives

    x / tau_f = -(D_q - 1) / (D_q + M + C_F P D_q)      with the observer,
    x / tau_f = -1 / (1 + C_F P)                         without,

so the friction reaching the spring torque is scaled by

    R(jw) = (D_q - 1)(1 + C_F P) / (D_q + M + C_F P D_q) = S_plant-input (1 + C_F P),

the loop's plant-input sensitivity (:func:`forecast_design.loops.response.sensitivity`) times
the return difference without the observer. With an exact nominal plant (M = 0) R = 1 - Q;
for the 2nd-order Butterworth Q, |1 - Q(jw)| = 1/sqrt(2) at w = sqrt(sqrt(5) - 2) w_q
~= 0.486 w_q. The rejection is evaluated on the continuous loop (well below Nyquist the
sampled loop's is the same).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..loops.response import loop_response, sensitivity
from ..loops import COMMAND_DELAY_SAMPLES
from ..params import OBSERVER_KINDS, Compensator, Design
from ..controllers import PAPER_PD, Controller, resolve_controller
from .plants import _exact_ratios, _plants, _q_polynomial, _Setting
from .tune import TuningResult

__all__ = ["CutoffTradeoff", "cutoff_tradeoff", "friction_rejection", "rejection_bandwidth_hz",
           "REJECTION_LEVEL"]

REJECTION_LEVEL = 1.0 / math.sqrt(2.0)    # |R| at the edge of the rejection band (-3 dB) [-]
_REJECTION_GRID_RAD_S = np.logspace(-3, 4, 1400)


@dataclass(frozen=True, slots=True)
class CutoffTradeoff:
    """Worst-case margin ratio and friction-rejection bandwidth of one observer against its cutoff.

    Attributes
    ----------
    observer : str
        Observer kind.
    w_q_hz : ndarray, shape (n,)
        Cutoffs [Hz], ascending (the chosen one included when given).
    ratios : ndarray, shape (n, plants)
        alpha_observer / alpha_plant of every plant of the set at every cutoff [-] (exact, 0
        when the loop is unstable).
    environments : tuple of str
        Plant labels of the set (columns of ``ratios``).
    rejection_bandwidth_hz : ndarray, shape (n,)
        Friction-rejection bandwidth, the smallest over the set [Hz] (0: no rejection; nan
        where a loop of the set is unstable, which rejects nothing).
    min_ratio : float
        The tuner's requirement on the worst-case ratio [-].
    chosen_w_q_hz : float or None
        The tuner's answer [Hz], when given.
    ideal_bandwidth_ratio : float
        Rejection bandwidth / w_q with an exact nominal plant (R = 1 - Q) [-]; 0.486 for the
        2nd-order Butterworth Q.
    """

    observer: str
    w_q_hz: np.ndarray
    ratios: np.ndarray
    environments: tuple[str, ...]
    rejection_bandwidth_hz: np.ndarray
    min_ratio: float
    chosen_w_q_hz: float | None = None
    ideal_bandwidth_ratio: float = math.nan

    @property
    def worst_ratio(self) -> np.ndarray:
        """min over the set of alpha_observer / alpha_plant at each cutoff [-]."""
        return self.ratios.min(axis=1)

    @property
    def binding_environment(self) -> tuple[str, ...]:
        """Label of the plant attaining the worst ratio at each cutoff."""
        return tuple(self.environments[i] for i in np.argmin(self.ratios, axis=1))

    def at(self, w_q_hz: float) -> int:
        """Index of the cutoff nearest to ``w_q_hz`` [Hz] (in log)."""
        return int(np.argmin(np.abs(np.log(self.w_q_hz / w_q_hz))))

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping: one list per quantity, aligned with ``w_q_hz``."""
        return {
            "observer": self.observer,
            "w_q_hz": self.w_q_hz.tolist(),
            "worst_ratio": self.worst_ratio.tolist(),
            "binding_environment": list(self.binding_environment),
            "rejection_bandwidth_hz": self.rejection_bandwidth_hz.tolist(),
            "min_ratio": self.min_ratio,
            "chosen_w_q_hz": self.chosen_w_q_hz,
            "ideal_bandwidth_ratio": self.ideal_bandwidth_ratio,
        }


def friction_rejection(true_design: Design, compensator: Compensator, w_rad_s: np.ndarray, *,
                       controller: Controller = PAPER_PD, believed: Design | None = None) -> np.ndarray:
    """Friction-rejection ratio R(jw): friction reaching tau_s with the observer over without it.

    Parameters
    ----------
    true_design : Design
        The true testbed and environment.
    compensator : Compensator
        Observer with its cutoff [Hz].
    w_rad_s : ndarray
        Frequencies [rad/s].
    controller : Controller, str or python-control system
        Force controller C_F.
    believed : Design, optional
        What the observer believes (default: the truth).

    Returns
    -------
    ndarray of complex
        R = S_plant-input (1 + C_F P) (module docstring); |R| < 1 where the observer helps.
    """
    w = np.asarray(w_rad_s, dtype=float)
    parts = loop_response(true_design, believed if believed is not None else true_design, compensator,
                          resolve_controller(controller), w)
    dq = np.polyval(_q_polynomial(compensator)[::-1], 1j * w / (2.0 * math.pi * compensator.w_q_hz))
    return sensitivity(parts, dq, "plant-input") * (1.0 + parts.CP)


def rejection_bandwidth_hz(w_rad_s: np.ndarray, rejection: np.ndarray, level: float = REJECTION_LEVEL) -> float:
    """Lowest frequency where |R| reaches ``level`` from below [Hz] (log-interpolated).

    Parameters
    ----------
    w_rad_s : ndarray
        Ascending frequencies [rad/s].
    rejection : ndarray of complex
        R at those frequencies.
    level : float
        Edge of the rejection band [-] (default -3 dB).

    Returns
    -------
    float
        The bandwidth [Hz]: 0 when |R| is not below ``level`` at the lowest frequency, the
        top of the grid when it never reaches it.
    """
    mag = np.abs(np.asarray(rejection))
    w = np.asarray(w_rad_s, dtype=float)
    above = np.flatnonzero(~(mag < level))
    if above.size == 0:
        return float(w[-1] / (2.0 * math.pi))
    k = int(above[0])
    if k == 0:
        return 0.0
    lw = np.log(w[k - 1:k + 1])
    lm = np.log(mag[k - 1:k + 1])
    frac = (math.log(level) - lm[0]) / (lm[1] - lm[0])
    return float(math.exp(lw[0] + frac * (lw[1] - lw[0])) / (2.0 * math.pi))


def cutoff_tradeoff(observer: str = "ea-fob", envs: Any = ("soft", "stiff"), *,
                    band_hz: tuple[float, float] = (0.5, 30.0), points: int = 48, min_ratio: float = 0.9,
                    chosen: TuningResult | float | None = None, uncertainty: float = 0.0,
                    q_family: str = "butterworth", q_order: int = 2, q_damping: float | None = None,
                    controller: Controller = PAPER_PD, break_at: str = "controller",
                    sigma: float = 0.0, sampled: bool = False, rate_hz: float = 2000.0,
                    delay_samples: int = COMMAND_DELAY_SAMPLES,
                    seed: int = 0, testbed: Any = None) -> CutoffTradeoff:
    """The tuner's trade-off for one observer: worst-case margin ratio and rejection bandwidth.

    Parameters
    ----------
    observer : str
        Observer kind (``ea-fob``, ``lo-dob``, ``ld-dob``, ``motor-fob``).
    envs : str or sequence
        Environment set, as for :func:`forecast_design.tuning.tune_q`.
    band_hz : (float, float)
        Range of cutoffs [Hz] (log-spaced).
    points : int
        Number of cutoffs (>= 2).
    min_ratio : float
        The requirement the tuner used [-] (drawn as a line).
    chosen : TuningResult or float, optional
        The tuner's answer (or a cutoff [Hz]); added to the cutoffs, so the curve passes
        exactly through the tuner's own worst-case ratio there.
    uncertainty, q_family, q_order, controller, break_at, sigma, sampled, rate_hz, delay_samples, seed
        As for :func:`~forecast_design.tuning.tune_q`.
    q_damping : float, optional
        Damping of a 2nd-order Q (e.g. the answer of :func:`~forecast_design.tuning.tune_q_shape`) [-].
    testbed : Testbed, str or None
        The testbed, as for :func:`~forecast_design.tuning.tune_q` (None: Table 1); its link is the
        default of the set's environments.

    Returns
    -------
    CutoffTradeoff
        Ratios (exact disk margins, the tuner's evaluation) and rejection bandwidths.

    Raises
    ------
    ParameterError
        For an unknown observer, a bad band or fewer than two points.
    """
    if observer not in OBSERVER_KINDS:
        raise ParameterError(f"unknown observer {observer!r}; known: {', '.join(OBSERVER_KINDS)}",
                             name="observer", value=observer)
    if not (0.0 < band_hz[0] < band_hz[1]) or not all(map(math.isfinite, band_hz)):
        raise ParameterError(f"band must satisfy 0 < lo < hi [Hz], got {band_hz}", name="band", value=band_hz)
    if int(points) < 2:
        raise ParameterError(f"points must be >= 2, got {points}", name="points", value=points)
    chosen_hz = chosen.w_q_hz if isinstance(chosen, TuningResult) else chosen
    if chosen_hz is not None and not math.isfinite(chosen_hz):
        chosen_hz = None
    cutoffs = np.geomspace(band_hz[0], band_hz[1], int(points))
    if chosen_hz is not None:
        cutoffs = np.unique(np.append(cutoffs, float(chosen_hz)))
    setting = _Setting(controller, break_at, float(sigma), bool(sampled), float(rate_hz), delay_samples)
    base = Compensator(kind=observer, w_q_hz=float(cutoffs[0]), q_family=q_family, q_order=q_order,
                       q_damping=q_damping)
    plants = _plants(base, envs, uncertainty, setting, seed, testbed=testbed)
    ratios = np.empty((cutoffs.size, len(plants)))
    bandwidth = np.empty(cutoffs.size)
    for i, f in enumerate(cutoffs):
        comp = dataclasses.replace(base, w_q_hz=float(f))
        ratios[i] = _exact_ratios(plants, comp, setting)[0]
        bandwidth[i] = math.nan if ratios[i].min() <= 0.0 else min(rejection_bandwidth_hz(_REJECTION_GRID_RAD_S,
                                                  friction_rejection(p.true_design, comp, _REJECTION_GRID_RAD_S,
                                                                     controller=controller, believed=p.believed))
                           for p in plants)
    x = np.logspace(-3, 3, 1200)      # w / w_q
    ideal = rejection_bandwidth_hz(x, 1.0 - 1.0 / np.polyval(_q_polynomial(base)[::-1], 1j * x)) * 2.0 * math.pi
    return CutoffTradeoff(observer=observer, w_q_hz=cutoffs, ratios=ratios, ideal_bandwidth_ratio=ideal,
                          environments=tuple(p.label for p in plants), rejection_bandwidth_hz=bandwidth,
                          min_ratio=float(min_ratio), chosen_w_q_hz=None if chosen_hz is None else float(chosen_hz))
