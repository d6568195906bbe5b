"""Robustness of one force loop: disk and classical margins, continuous or sampled (the ``margins`` verb).

The disk-margin mathematics lives in :mod:`forecast_design.margins`, the sampled-data loop in
:mod:`forecast_design.loops.sampled`, the Fig. 6 table in :mod:`forecast_design.reproduce`;
their names stay importable from here for one release.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .loops.sampled import COMMAND_DELAY_SAMPLES, SampledForceLoop, sampled_force_loop
from .margins import (
    ClassicalMargins,
    DiskMargin,
    classical_margins,
    check_skew,
    DiskMarginCurve,
    disk_center_radius,
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from .environments import resolve_environments, resolve_testbed
from .controllers import PAPER_PD, resolve_controller
from .errors import ParameterError
from .params import Compensator, Design

__all__ = [
    "DiskMargin",
    "DiskMarginCurve",
    "disk_margin",
    "disk_margin_curve",
    "disk_gain_margin",
    "disk_phase_margin_deg",
    "disk_center_radius",
    "SampledForceLoop",
    "sampled_force_loop",
    "loop_margins",
    "LoopAnalysis",
    "LoopResponse",
    "SfmLoopCheck",
    "analyse_loop",
    "sfm_loop_check",
]

# Names that moved to a higher layer (Fig. 6 is a reproduction); resolved on use, one release.
_MOVED = {"fig6_table": "reproduce", "MarginRow": "reproduce"}


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        return getattr(importlib.import_module(f"{__package__}.{_MOVED[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _as_design(spec: Any, testbed: Any, what: str) -> Design:
    """A Design, or one environment (object, preset, inline values, file) on ``testbed``."""
    if isinstance(spec, Design):
        return spec if testbed is None else dataclasses.replace(spec, testbed=resolve_testbed(testbed))
    tb = resolve_testbed(testbed)
    return Design(testbed=tb, environment=resolve_environments(spec, testbed=tb).single(what)[1])


def loop_margins(
    design: Any,
    compensator: Compensator | str | None = None,
    *,
    testbed: Any = None,
    believed: Any = None,
    controller: Any = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = COMMAND_DELAY_SAMPLES,
    skew: float = 0.0,
    sigma: float | None = None,
) -> DiskMargin:
    """Disk margin of one force loop (the ``margins`` verb).

    Parameters
    ----------
    design : Design, Environment, str or EnvironmentSet
        The true testbed and environment (a Design), or one environment in any form
        :func:`~forecast_design.environments.resolve_environments` accepts (an Environment,
        ``"soft"``, ``"k_e=20,J_e=0.02"``, a file holding one); a Design's ``controller`` and
        ``compensator`` are the defaults of the next arguments.
    compensator : Compensator, str or None
        Observer (or its kind); ``None`` uses ``design.compensator`` (none if that is unset).
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`); None keeps the
        Design's, or Table 1.
    believed : Design, Environment, str or None
        What the observer believes (environment-knowledge error), in the same forms;
        ``None``: the truth.
    controller : Controller, str, python-control system or None
        Force controller (:func:`~forecast_design.controllers.resolve_controller`); ``None``
        uses ``design.controller`` or the paper's PD.
    break_at : str
        ``'controller'`` (paper) or ``'plant-input'``.
    sampled : bool
        Analyse the sampled-data loop (:func:`sampled_force_loop`: the controller's difference
        equation, Tustin observer, ZOH plant, delays) instead of the continuous one
        (:func:`~forecast_design.loops.continuous.force_loop`, the controller's C(s)).
    rate_hz : float
        Sampling rate for ``sampled`` [Hz].
    delay_samples : int
        Computation delay for ``sampled`` [samples].
    skew : float
        Disk skew [-] (python-control's name).
    sigma : float or None
        Alias of ``skew``.

    Returns
    -------
    DiskMargin
        alpha [-], disk-based gain [dB] and phase [deg] margins, critical frequency [rad/s]
        and delay margin [s]; ``stable`` from the full characteristic polynomial.
    """
    sigma = check_skew(skew if sigma is None else sigma)
    loop, *_ = _build_loop(design, compensator, testbed, believed, controller, break_at, sampled, rate_hz,
                           delay_samples, "loop_margins")
    if isinstance(loop, SampledForceLoop):
        return loop.disk_margin(sigma)
    return disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))


def _build_loop(design: Any, compensator: Any, testbed: Any, believed: Any, controller: Any, break_at: str,
                sampled: bool, rate_hz: float, delay_samples: int, what: str) -> tuple:
    """The one loop of :func:`loop_margins` and :func:`analyse_loop`: (loop, design, believed,
    compensator, controller, rate_hz, notes); a discrete controller is analysed sampled at its rate."""
    from .loops import force_loop

    design = _as_design(design, testbed, what)
    if believed is not None:
        believed = _as_design(believed, design.testbed, f"{what}(believed=...)")
    if isinstance(compensator, str):
        compensator = None if compensator == "none" else Compensator(kind=compensator)
    comp = compensator if compensator is not None else design.compensator
    ctrl = resolve_controller(controller if controller is not None else design.controller, default=PAPER_PD)
    if not ctrl.has_equations:
        raise ctrl.no_equations("margins")
    notes = []
    if ctrl.is_code:
        notes.append(f"controller {ctrl.label} is code: the linearisation its transfer_function() gives is "
                     "analysed, not its nonlinear parts (schedules, limits, switching)")
    if not sampled and not ctrl.is_continuous:
        sampled = True
        if ctrl.rate_hz is not None:
            rate_hz = ctrl.rate_hz
        notes.append(f"controller {ctrl.spelling()} is discrete: the sampled loop at {rate_hz:g} Hz is analysed")
    if sampled:
        loop = sampled_force_loop(design, comp, controller=ctrl, believed=believed, rate_hz=rate_hz,
                                  break_at=break_at, delay_samples=delay_samples)
    else:
        loop = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at)
    return loop, design, believed, comp, ctrl, float(rate_hz), tuple(notes)


@dataclass(frozen=True, slots=True)
class LoopResponse:
    """A loop's frequency response on a grid, for the plots (computed here, drawn in plotting).

    Parameters
    ----------
    w_rad_s : ndarray, shape (n,)
        Frequencies [rad/s] (below Nyquist when sampled).
    L, S, T : ndarray of complex, shape (n,)
        Loop, sensitivity ``1/(1 + L)`` and complementary sensitivity ``L/(1 + L)`` [-].
    alpha : ndarray, shape (n,)
        Frequency-dependent disk margin ``1/|S + (sigma - 1)/2|`` [-].
    """

    w_rad_s: np.ndarray
    L: np.ndarray
    S: np.ndarray
    T: np.ndarray
    alpha: np.ndarray


@dataclass(frozen=True, eq=False)
class LoopAnalysis:
    """Everything the ``margins`` verb says about one loop, and what it assumed.

    Attributes
    ----------
    disk : DiskMargin
        Exact disk margin [-] with its gain [dB], phase [deg] and delay [s] margins.
    classical : ClassicalMargins
        Every gain and phase crossover (MATLAB's ``allmargin``).
    loop : ForceLoop or SampledForceLoop
        The loop analysed.
    assumptions : dict
        Controller (label and table), compensator (table, cutoff, what the linear analysis
        sees of it), testbed, environment, believed environment, break point, continuous or
        sampled (rate, delay), skew.
    notes : tuple of str
        What was decided for the user (e.g. a discrete controller analysed sampled).
    """

    disk: DiskMargin
    classical: ClassicalMargins
    loop: Any
    assumptions: dict
    notes: tuple[str, ...] = ()

    @property
    def sampled(self) -> bool:
        """True for the sampled-data loop."""
        return isinstance(self.loop, SampledForceLoop)

    def response(self, n: int = 800) -> LoopResponse:
        """The loop's frequency response for plots: ``n`` log-spaced points up to 1e4 rad/s or Nyquist.

        Parameters
        ----------
        n : int
            Number of frequencies [-].

        Returns
        -------
        LoopResponse
            L, S, T and alpha(w).
        """
        top = 0.999 * math.pi * self.loop.rate_hz if self.sampled else 1e4
        w = np.geomspace(1e-2, top, int(n))
        if self.sampled:
            W = 2.0 * self.loop.rate_hz * np.tan(w / (2.0 * self.loop.rate_hz))
            L = self.loop.L_w(1j * W)
        else:
            L = self.loop.L(1j * w)
        S = 1.0 / (1.0 + L)
        alpha = 1.0 / np.abs(S + 0.5 * (self.disk.sigma - 1.0))
        return LoopResponse(w, L, S, L * S, alpha)

    def title(self) -> str:
        """One line naming controller, compensator, environment and the loop (for plots)."""
        a = self.assumptions
        comp = a["compensator"]["label"]
        kind = f"sampled {a['loop']['rate_hz']:g} Hz, delay {a['loop']['delay_samples']}" if self.sampled \
            else "continuous"
        return f"{a['controller']['label']} + {comp}, environment {a['environment']['name']} ({kind})"

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the disk margin (top-level keys as before), the classical margins and the assumptions."""
        return {**self.disk.to_mapping(), "classical": self.classical.to_mapping(),
                "assumptions": self.assumptions, "notes": list(self.notes)}


def analyse_loop(
    design: Any,
    compensator: Compensator | str | None = None,
    *,
    testbed: Any = None,
    believed: Any = None,
    controller: Any = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = COMMAND_DELAY_SAMPLES,
    skew: float = 0.0,
    environment_name: str | None = None,
) -> LoopAnalysis:
    """Disk and classical margins of one force loop, with everything it assumed (the ``margins`` verb).

    Parameters
    ----------
    design, compensator, testbed, believed, controller, break_at, sampled, rate_hz, delay_samples, skew
        As :func:`loop_margins`. A discrete controller (``C(z)``) has no continuous loop: it is
        analysed sampled at its own rate (said in ``notes``).
    environment_name : str, optional
        How to name the environment in the assumptions (default: its preset name, or ``custom``).

    Returns
    -------
    LoopAnalysis
        Margins, the loop and the assumptions.

    Examples
    --------
    >>> a = analyse_loop("soft", "ea-fob", controller="pid:6:20:0.05:0.002")
    >>> a.assumptions["controller"]["label"], a.disk.stable
    ('PID P=6 I=20 D=0.05 T_f=0.002', True)
    """
    from .compensators import compensator_strategy
    from .environments import resolve_environments as _resolve

    sigma = check_skew(skew)
    if environment_name is not None and not isinstance(environment_name, str):
        raise ParameterError(f"environment_name must be a string or None, got {type(environment_name).__name__}",
                             name="environment_name", value=environment_name)
    loop, design, believed, comp, ctrl, rate_hz, notes = _build_loop(
        design, compensator, testbed, believed, controller, break_at, sampled, rate_hz, delay_samples, "analyse_loop")
    sampled = isinstance(loop, SampledForceLoop)
    if sampled:
        dm = loop.disk_margin(sigma)
        cm = classical_margins(loop.L_w, stable=loop.stable, rate_hz=rate_hz)
    else:
        dm = disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))
        cm = classical_margins(loop.L, stable=loop.stable)
    comp_value = comp or Compensator()
    name = environment_name or next((n for n in ("soft", "stiff", "fig7", "exp-soft", "locked", "link-only")
                                     if _resolve(n).single("x")[1] == design.environment), "custom")
    assumptions = {
        "controller": {"label": ctrl.label, "spelling": ctrl.spelling(), "table": ctrl.to_mapping(),
                       "model": ctrl.model if ctrl.is_code else "linear (its equations)"},
        "compensator": {"label": comp_value.label, "table": comp_value.to_mapping(),
                        "w_q_hz": comp_value.w_q_hz if comp_value.is_observer else None,
                        "linear_analysis": compensator_strategy(comp_value).analysis_note(comp_value)},
        "testbed": design.testbed.to_mapping(),
        "environment": {"name": name, **design.environment.to_mapping()},
        "believed_environment": None if believed is None else believed.environment.to_mapping(),
        "break_at": break_at,
        "loop": ({"kind": "sampled", "rate_hz": float(rate_hz), "delay_samples": int(delay_samples),
                  "plant": "zero-order hold", "compensator_discretization": "tustin",
                  "controller_discretization": getattr(ctrl, "discretization", None) if ctrl.is_continuous
                  else "given in z"} if sampled else {"kind": "continuous"}),
        "skew": sigma,
        "conventions": "negative feedback 1 + L = 0; disk margin of Seiler, Packard and Gahinet (2020); "
                       "classical margins at every crossover (MATLAB allmargin); frequencies in rad/s and Hz",
    }
    return LoopAnalysis(dm, cm, loop, assumptions, notes)


@dataclass(frozen=True, slots=True, kw_only=True)
class SfmLoopCheck:
    """Whether the sampled force loop stays stable with an SFM feed-forward's velocity feedback.

    Parameters
    ----------
    stable : bool
        Every closed-loop pole inside the unit circle.
    spectral_radius : float
        Largest closed-loop pole magnitude [-].
    viscous : float
        The feed-forward's viscous coefficient [N m s/rad].
    d_m : float
        The plant's own motor damping [N m s/rad].
    """

    stable: bool
    spectral_radius: float
    viscous: float
    d_m: float

    def message(self) -> str:
        """One line saying why the loop is unstable ('' when stable)."""
        if self.stable:
            return ""
        return (f"the force loop with this SFM feed-forward is unstable (closed-loop pole at |z| = "
                f"{self.spectral_radius:.4g}): its viscous term {self.viscous:.4g} N m s/rad feeds the measured speed "
                f"back against the motor's own damping d_m = {self.d_m:.4g} N m s/rad")


def sfm_loop_check(design: Design, friction: Any, *, controller: Any = None, rate_hz: float = 2000.0,
                   delay_samples: int = COMMAND_DELAY_SAMPLES) -> SfmLoopCheck:
    """Linear stability of the sampled force loop with an SFM compensator (before code goes to a board).

    The SFM feed-forward ``tau_m = u + viscous v_hat + coulomb sign(v_hat) + ...`` is, linearised,
    a velocity feedback ``viscous V(z) theta`` around the plant (the sfm strategy's linear part);
    its Coulomb, offset and harmonic terms are bounded and do not move the poles. The loop is the
    one :func:`sampled_force_loop` builds for every analysis (ZOH plant, the controller's own
    law, the command ``delay_samples`` late); an identified viscous far above the motor's own
    damping (266 N m s/rad for d_m = 0.3 on a log that never slid) makes it unstable.

    Parameters
    ----------
    design : Design
        The plant the code will run on (testbed and environment).
    friction : Mapping[str, float]
        The SFM parameters (``viscous`` [N m s/rad] or its two directional levels; the others do not
        change stability).
    controller : Controller or str, optional
        The force controller (default the design's, else the paper's PD 5/0.1).
    rate_hz : float
        Control rate [Hz].
    delay_samples : int
        Samples between computing the command and applying it (default 0: within the period, as
        the simulator and the firmware run it).

    Returns
    -------
    SfmLoopCheck
        Stability and the largest closed-loop pole magnitude.

    Examples
    --------
    >>> from forecast_design.params import Design
    >>> sfm_loop_check(Design.nominal("exp-soft"), {"viscous": 265.8}).stable
    False
    """
    from .compensators.sfm_params import viscous_slope

    ctrl = resolve_controller(controller if controller is not None else design.controller, default=PAPER_PD)
    comp = Compensator(kind="sfm", friction=dict(friction))
    loop = sampled_force_loop(design, comp, controller=ctrl, rate_hz=rate_hz, delay_samples=delay_samples)
    return SfmLoopCheck(stable=bool(loop.stable), spectral_radius=loop.max_pole_magnitude,
                        viscous=float(viscous_slope(dict(friction))), d_m=float(design.testbed.d_m))
