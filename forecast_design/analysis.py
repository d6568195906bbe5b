"""Robustness of one force loop: its disk margin, continuous or sampled (the ``margins`` verb).

The disk-margin mathematics lives in :mod:`forecast_design.margins`, the sampled-data loop in
:mod:`forecast_design.loops.sampled`, the Fig. 6 table in :mod:`forecast_design.reproduce`;
their names stay importable from here for one release.
"""

from __future__ import annotations

import dataclasses
import importlib
import warnings
from typing import Any

from .loops.sampled import SampledForceLoop, sampled_force_loop
from .margins import (
    DiskMargin,
    check_skew,
    DiskMarginCurve,
    disk_center_radius,
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from .environments import resolve_environments, resolve_testbed
from .params import Compensator, Design, PDController

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
    "SfmLoopCheck",
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
    controller: PDController | None = None,
    break_at: str = "controller",
    sampled: bool = False,
    rate_hz: float = 2000.0,
    delay_samples: int = 1,
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
    controller : PDController or None
        Force controller; ``None`` uses ``design.controller`` or the paper's P = 5, D = 0.1.
    break_at : str
        ``'controller'`` (paper) or ``'plant-input'``.
    sampled : bool
        Analyse the sampled-data loop (:func:`sampled_force_loop`: 200 Hz derivative filter,
        Tustin controller and observer, ZOH plant, delays) instead of the continuous one
        (:func:`~forecast_design.loops.continuous.force_loop`, pure PD).
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
    design = _as_design(design, testbed, "loop_margins")
    if believed is not None:
        believed = _as_design(believed, design.testbed, "loop_margins(believed=...)")
    if isinstance(compensator, str):
        compensator = None if compensator == "none" else Compensator(kind=compensator)
    sigma = check_skew(skew if sigma is None else sigma)
    comp = compensator if compensator is not None else design.compensator
    ctrl = controller if controller is not None else (design.controller or PDController(P=5.0, D=0.1))
    if sampled:
        return sampled_force_loop(design, comp, controller=ctrl, believed=believed, rate_hz=rate_hz,
                                  break_at=break_at, delay_samples=delay_samples).disk_margin(sigma)
    from .loops import force_loop

    loop = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at)
    return disk_margin(loop.L, sigma, closed_loop_stable=bool(loop.stable))


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
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


def sfm_loop_check(design: Design, friction: Any, *, controller: PDController | None = None, rate_hz: float = 2000.0,
                   delay_samples: int = 1) -> SfmLoopCheck:
    """Linear stability of the sampled force loop with an SFM compensator (before code goes to a board).

    The SFM feed-forward ``tau_m = u + viscous v_hat + coulomb sign(v_hat) + ...`` is, linearised,
    a velocity feedback ``viscous V(z) theta`` (``V`` the compensator's filtered derivative,
    Tustin) around the plant; its Coulomb, offset and harmonic terms are bounded and do not move
    the poles. The loop is the ZOH plant ``tau_m -> [tau_s, theta]`` (python-control's ``c2d``
    of the motor, spring and environment equations), the PD force controller with its filtered
    derivative (Tustin) on ``-tau_s`` and that velocity feedback, delayed ``delay_samples``;
    an identified viscous far above the motor's own damping (266 N m s/rad for d_m = 0.3 on a log
    that never slid) makes it unstable.

    Parameters
    ----------
    design : Design
        The plant the code will run on (testbed and environment).
    friction : Mapping[str, float]
        The SFM parameters (``viscous`` [N m s/rad]; the others do not change stability).
    controller : PDController, optional
        The force controller (default the design's, else P = 5, D = 0.1).
    rate_hz : float
        Control rate [Hz].
    delay_samples : int
        Computation delay [samples] (the board's: 1).

    Returns
    -------
    SfmLoopCheck
        Stability and the largest pole magnitude.
    """
    import control
    import numpy as np

    tb, env = design.testbed, design.environment
    ctrl = controller if controller is not None else (design.controller or PDController(P=5.0, D=0.1))
    viscous = float(dict(friction).get("viscous", 0.0))
    if env.locked:
        A = [[0.0, 1.0], [-tb.k / tb.J_m, -tb.d_m / tb.J_m]]
        B = [[0.0], [1.0 / tb.J_m]]
        C = [[tb.k, 0.0], [1.0, 0.0]]
    else:
        J, d, k_e = env.J, env.d, env.k_e
        A = [[0.0, 1.0, 0.0, 0.0], [-tb.k / tb.J_m, -tb.d_m / tb.J_m, tb.k / tb.J_m, 0.0], [0.0, 0.0, 0.0, 1.0],
             [tb.k / J, 0.0, -(tb.k + k_e) / J, -d / J]]
        B = [[0.0], [1.0 / tb.J_m], [0.0], [0.0]]
        C = [[tb.k, 0.0, -tb.k, 0.0], [1.0, 0.0, 0.0, 0.0]]
    T = 1.0 / float(rate_hz)
    with warnings.catch_warnings():
        # scipy flags the leading zero of a strictly proper numerator in python-control's conversions
        warnings.simplefilter("ignore")
        return _sfm_loop(A, B, C, T, ctrl, viscous, delay_samples, env, tb)


def _sfm_loop(A, B, C, T, ctrl, viscous, delay_samples, env, tb) -> "SfmLoopCheck":
    """The closed loop of :func:`sfm_loop_check` and its spectral radius."""
    import control
    import numpy as np

    from .simulation.controllers import DEFAULT_DERIVATIVE_CUTOFF_HZ, DEFAULT_VELOCITY_CUTOFF_HZ, pd_transfer_function

    plant = control.c2d(control.ss(np.array(A), np.array(B), np.array(C), np.zeros((2, 1))), T, "zoh")
    cf = pd_transfer_function(ctrl, DEFAULT_DERIVATIVE_CUTOFF_HZ).to_control()
    wv = 2.0 * np.pi * DEFAULT_VELOCITY_CUTOFF_HZ
    velocity = control.tf([1.0, 0.0], [1.0 / wv, 1.0])
    delay = control.tf([1.0], [1.0] + [0.0] * int(delay_samples), T) if delay_samples else control.tf([1.0], [1.0], T)
    k_s = control.c2d(-cf, T, "tustin") * delay
    k_th = control.c2d(viscous * velocity, T, "tustin") * delay
    a, b = control.ss(k_s), control.ss(k_th)       # u = k_s tau_s + k_th theta: one 1 x 2 realisation
    na, nb = a.nstates, b.nstates
    Ag = np.block([[a.A, np.zeros((na, nb))], [np.zeros((nb, na)), b.A]])
    Bg = np.block([[a.B, np.zeros((na, 1))], [np.zeros((nb, 1)), b.B]])
    gains = control.ss(Ag, Bg, np.hstack([a.C, b.C]), np.hstack([a.D, b.D]), T)
    loop = control.feedback(plant, gains, sign=+1)
    poles = loop.poles()
    # a free output (k_e = 0) has a rigid-body mode, motor and output turning together, at z = 1: it moves
    # no spring torque and no speed, so it is not a loop pole
    poles = poles[np.abs(poles - 1.0) > 1e-8] if env.k_e == 0.0 and not env.locked else poles
    radius = float(np.max(np.abs(poles))) if poles.size else 0.0
    return SfmLoopCheck(stable=bool(radius < 1.0), spectral_radius=radius, viscous=viscous, d_m=float(tb.d_m))
