"""Coupled stability with every passive environment: the ``passivity`` verb's analysis.

Colgate and Hogan (1988): a one-port coupled to *any* passive environment is stable if and only if
the port is passive, i.e. its driving-point impedance Z(s) is positive real. Z comes from the force
loop's own objects (:mod:`.port`); its positive-realness, passivity indices, the bands where it
fails and the ranges of environment stiffness and inertia that keep the loop stable are computed
exactly (:mod:`.exact`: roots of polynomials, no frequency or parameter grid).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import polynomials as poly
from ..controllers import PAPER_PD, Controller, resolve_controller
from ..environments import resolve_environments, resolve_testbed
from ..errors import ParameterError
from ..margins import json_float
from ..params import Compensator, Design
from .exact import is_hurwitz, magnitude_range, negative_bands, real_part_minimum, stable_parameter_intervals
from .port import PORTS, PortImpedance, port_impedance, tustin_equivalent

__all__ = ["PassivityResult", "PassivityCurve", "analyse_passivity"]

#: Re Z counts as negative below -PASSIVITY_RTOL |Z| at the minimum (rounding of the polynomials) [-].
PASSIVITY_RTOL = 1e-9

_CONVENTIONS = (
    "one-port at the joint: effort = torque the actuator exerts on the environment [N m], flow = joint "
    "velocity q' [rad/s]; Z(s) = effort/flow [N m s/rad] with the force reference at zero; environment "
    "Z_e = J_e s + d_e + k_e/s; coupled characteristic polynomial s chi_locked (Z + Z_e) = chi_free + "
    "E chi_locked (nothing cancelled); passive = Z positive real (locked loop stable, Re Z(jw) >= 0 for all w, "
    "s = 0 and infinite-frequency poles simple with positive residue) (Colgate and Hogan 1988); indices as "
    "MATLAB getPassiveIndex: input (IFP) nu = min Re Z, output (OFP) rho = min Re 1/Z; frequencies in rad/s")


@dataclass(frozen=True, slots=True)
class PassivityCurve:
    """Re Z and |Z| over frequency, for plots (computed here, drawn in plotting).

    Parameters
    ----------
    w_rad_s : ndarray, shape (n,)
        Frequencies [rad/s].
    re_z : ndarray, shape (n,)
        Re Z(jw) [N m s/rad].
    abs_z : ndarray, shape (n,)
        |Z(jw)| [N m s/rad].
    """

    w_rad_s: np.ndarray
    re_z: np.ndarray
    abs_z: np.ndarray


@dataclass(frozen=True, eq=False)
class PassivityResult:
    """Whether the force-controlled SEA is stable with every passive environment, and how far from it.

    Attributes
    ----------
    passive : bool
        Z is positive real: stable coupled to every passive environment (Colgate and Hogan 1988).
    locked_stable : bool
        The force loop with the port locked (v = 0) is stable (Z's poles).
    free_stable : bool
        The loop with nothing attached at the port is stable, apart from the one position mode at
        s = 0 the port's velocity does not see (Y's poles).
    min_re_z : float
        min over w of Re Z(jw) [N m s/rad] = the input-feedforward passivity index nu.
    w_min_rad_s : float
        Where [rad/s] (``inf``: the limit at infinite frequency).
    bands_rad_s : tuple of (float, float)
        Frequency bands where Re Z(jw) < 0 [rad/s].
    output_index : float or None
        Output-feedback passivity index rho = min Re Y(jw) [rad/(N m s)] (None: Y unstable).
    index_interval : dict
        The passivity index interval (see :func:`analyse_passivity`, Notes).
    stiffness_intervals : tuple of (float, float)
        Every k_e >= 0 [N m/rad] keeping the loop stable with the environment's J_e, d_e.
    inertia_intervals : tuple of (float, float)
        Every J_e >= 0 [kg m^2] keeping it stable with the environment's d_e, k_e.
    destabilising_environment : dict or None
        A passive environment (J_e, d_e, k_e at the link's end) verified to destabilise the loop,
        built at the worst frequency (None when the port at the link's end is passive).
    port : PortImpedance
        The port analysed.
    design : Design
        Testbed and the environment given (the believed one for the observers).
    assumptions : dict
        What was assumed.
    notes : tuple of str
        What was decided for the user.
    """

    passive: bool
    locked_stable: bool
    free_stable: bool
    min_re_z: float
    w_min_rad_s: float
    bands_rad_s: tuple
    output_index: float | None
    index_interval: dict
    stiffness_intervals: tuple
    inertia_intervals: tuple
    destabilising_environment: dict | None
    port: PortImpedance
    design: Design
    assumptions: dict
    notes: tuple = ()

    @staticmethod
    def _containing(intervals: tuple, value: float) -> tuple | None:
        for lo, hi in intervals:
            if lo <= value <= hi and (value > lo or lo == 0.0):
                return (lo, hi)
        return None

    @property
    def stiffness_range(self) -> tuple | None:
        """The stable interval of k_e [N m/rad] containing the environment's own (None: it is unstable)."""
        return self._containing(self.stiffness_intervals, self.design.environment.k_e)

    @property
    def inertia_range(self) -> tuple | None:
        """The stable interval of J_e [kg m^2] containing the environment's own (None: it is unstable)."""
        return self._containing(self.inertia_intervals, self.design.environment.J_e)

    def curve(self, n: int = 600) -> PassivityCurve:
        """Re Z and |Z| on ``n`` log-spaced frequencies around the bands and the minimum (for plots).

        Parameters
        ----------
        n : int
            Number of frequencies [-].

        Returns
        -------
        PassivityCurve
            The frequency response of Z.
        """
        marks = [w for band in self.bands_rad_s for w in band if 0.0 < w < math.inf]
        if 0.0 < self.w_min_rad_s < math.inf:
            marks.append(self.w_min_rad_s)
        lo = min([1e-1, *[m / 100.0 for m in marks]])
        hi = max([1e4, *[m * 100.0 for m in marks]])
        w = np.geomspace(lo, hi, int(n))
        z = self.port.Z.freqresp(w)
        return PassivityCurve(w, z.real, np.abs(z))

    def title(self) -> str:
        """One line naming controller, compensator, environment and port (for plots)."""
        a = self.assumptions
        return (f"{a['controller']['label']} + {a['compensator']['label']}, believed environment "
                f"{a['environment']['name']}, port at the {self.port.port}'s end")

    def to_mapping(self) -> dict[str, Any]:
        """JSON: the verdict, Re Z's minimum and bands, indices, ranges, witness and assumptions."""
        pair = lambda p: None if p is None else [json_float(p[0]), json_float(p[1])]  # noqa: E731
        return {
            "passive": self.passive,
            "locked_stable": self.locked_stable,
            "free_stable": self.free_stable,
            "min_re_z": json_float(self.min_re_z),
            "min_re_z_n_m_s_per_rad": json_float(self.min_re_z),
            "w_min_rad_s": json_float(self.w_min_rad_s),
            "bands_rad_s": [pair(b) for b in self.bands_rad_s],
            "passivity_indices": {
                "input_feedforward_nu_n_m_s_per_rad": json_float(self.min_re_z),
                "output_feedback_rho_rad_per_n_m_s": None if self.output_index is None
                else json_float(self.output_index),
            },
            "passivity_index_interval": self.index_interval,
            "stiffness_range_n_m_per_rad": pair(self.stiffness_range),
            "stiffness_intervals_n_m_per_rad": [pair(i) for i in self.stiffness_intervals],
            "inertia_range_kg_m2": pair(self.inertia_range),
            "inertia_intervals_kg_m2": [pair(i) for i in self.inertia_intervals],
            "destabilising_environment": self.destabilising_environment,
            "impedance": {"num": list(self.port.Z.num), "den": list(self.port.Z.den)},
            "assumptions": self.assumptions,
            "notes": list(self.notes),
        }


def _design(spec: Any, testbed: Any) -> tuple[str, Design]:
    if isinstance(spec, Design):
        design = spec if testbed is None else dataclasses.replace(spec, testbed=resolve_testbed(testbed))
        return "custom", design
    tb = resolve_testbed(testbed)
    name, env = resolve_environments(spec, testbed=tb).single("passivity")
    return name, Design(testbed=tb, environment=env)


def _continuous_law(ctrl: Controller, rate_hz: float | None, notes: list[str]):
    """C(s) of the controller; a discrete C(z) through its inverse Tustin map (said in notes)."""
    if not ctrl.has_equations:
        raise ctrl.no_equations("passivity")
    if ctrl.is_code:
        notes.append(f"controller {ctrl.label} is code: the linearisation its transfer_function() gives is analysed")
    if ctrl.is_continuous:
        return ctrl.feedback_tf()
    rate = getattr(ctrl, "rate_hz", None) or rate_hz
    if rate is None:
        raise ParameterError(f"controller {ctrl.spelling()} is discrete: give its rate (rate_hz=...) so that its "
                             "continuous (inverse Tustin) equivalent can be analysed", name="rate_hz")
    notes.append(f"controller {ctrl.spelling()} is discrete: its inverse-Tustin continuous equivalent at {rate:g} Hz "
                 "is analysed (the sample-and-hold and computation delay are not)")
    return tustin_equivalent(ctrl.num, ctrl.den, rate)


def _residue_ok(port: PortImpedance) -> bool:
    """Z's poles at s = 0 and at infinity are simple with positive residues (positive realness)."""
    free, sl = poly.trim(port.free), poly.trim(port.s_locked)
    rel = (len(free) - 1) - (len(sl) - 1)
    if rel > 1 or (rel == 1 and free[0] / sl[0] <= 0.0):
        return False
    if free[-1] != 0.0 and port.locked[-1] != 0.0:        # a pole at s = 0: k / s with k > 0
        return bool(free[-1] / port.locked[-1] > 0.0)
    return True


def _free_stable(free: np.ndarray) -> bool:
    p = poly.trim(free)
    if len(p) > 1 and p[-1] == 0.0:
        p = p[:-1]                                         # the position mode the port cannot see
    return is_hurwitz(p)


def _index_interval(port: PortImpedance, bands, locked_stable: bool, free_stable: bool) -> dict:
    """Our construction of the passivity index interval (see :func:`analyse_passivity`, Notes)."""
    if bands:
        ranges = [magnitude_range(port.free, port.s_locked, a, b) for a, b in bands]
        interval = [json_float(min(r[0] for r in ranges)), json_float(max(r[1] for r in ranges))]
    return {
        "interval_n_m_s_per_rad": interval if bands else None,
        "light_side_certified": bool(bands) and free_stable,
        "heavy_side_certified": bool(bands) and locked_stable,
        "bands_rad_s": [[json_float(a), json_float(b)] for a, b in bands],
        "definition": "[lo, hi]: a passive environment Z_e is certified stable when |Z_e(jw)| < lo at every w of the "
                      "bands where Re Z < 0 (small gain from the free port, if light_side_certified) or |Z_e(jw)| > hi "
                      "there (from the locked port, if heavy_side_certified); passivity certifies every other "
                      "frequency. null: no band, every passive environment is certified. Our construction after "
                      "Shime et al. (2025), whose exact definition could not be read (docs/passivity.md).",
    }


def _witness(link: PortImpedance) -> dict | None:
    """A passive environment at the link's end that destabilises the loop, verified by its roots."""
    value, w = real_part_minimum(link.free, link.s_locked)
    if not (value < 0.0 and 0.0 < w < math.inf):
        return None
    z = complex(link.Z(1j * w))
    d_star, x = -z.real, -z.imag                        # Z_e(jw) = d + j (J w - k/w) = -Z(jw)
    J0, k0 = (x / w, 0.0) if x > 0.0 else (0.0, -x * w)
    for m in (0.0, abs(J0) + abs(k0) / w**2 + 1e-3):
        J, k = J0 + m, k0 + m * w * w
        for factor in (0.9, 0.99, 1.01, 1.1, 0.5):
            d = d_star * factor
            roots = np.roots(link.coupled(J, d, k))
            if roots.size and float(np.max(roots.real)) > 1e-9 * max(1.0, w):
                return {"J_e_kg_m2": J, "d_e_n_m_s_per_rad": d, "k_e_n_m_per_rad": k,
                        "at_rad_s": w, "max_pole_real_part_rad_s": float(np.max(roots.real))}
    return None


def analyse_passivity(
    design: Any = "soft",
    compensator: Compensator | str | None = None,
    *,
    testbed: Any = None,
    controller: Any = None,
    port: str = "link",
    rate_hz: float | None = None,
    environment_name: str | None = None,
) -> PassivityResult:
    """Is the force-controlled SEA stable coupled to every passive environment? (the ``passivity`` verb).

    Parameters
    ----------
    design : Design, Environment, str or path
        Testbed and environment (any form :func:`~forecast_design.environments.resolve_environments`
        takes, e.g. ``"soft"``). The environment is what the compensator *believes* (the EA-FOB's E0;
        the LD-DOB reads its link) and where the stiffness and inertia ranges are taken; the port is
        tested against every passive *true* environment.
    compensator : Compensator, str or None
        The compensator (or its kind at 10 Hz); None: the design's, or none.
    testbed : Testbed, str or None
        The testbed (:func:`~forecast_design.environments.resolve_testbed`); None keeps the design's.
    controller : Controller, str, python-control system or None
        Force controller, any LTI kind; None: the design's, or the paper's PD 5/0.1. A discrete
        ``C(z)`` is analysed through its inverse-Tustin ``C(s)`` (needs its rate).
    port : str
        ``'link'`` (default: the link J_l, d_l is the actuator's; environments attach at its end) or
        ``'spring'`` (the link counts as environment).
    rate_hz : float or None
        Rate of a discrete controller that does not carry one [Hz].
    environment_name : str or None
        How to name the environment in the assumptions.

    Returns
    -------
    PassivityResult
        ``passive``, the locked and free stabilities, min Re Z [N m s/rad] with its frequency
        [rad/s], the bands where Re Z < 0 [rad/s], the passivity indices, the passivity index
        interval, the stable ranges of k_e [N m/rad] and J_e [kg m^2], a destabilising passive
        environment when there is one, and the assumptions.

    Notes
    -----
    Z(s) = chi_free / (s chi_locked) (:mod:`forecast_design.passivity.port`). Z is positive real
    when chi_locked is Hurwitz, Re Z(jw) >= 0 for every w (its minimum from the stationary points of
    Re Z(jw), roots of a polynomial in w^2) and the poles at s = 0 and infinity are simple with
    positive residues. The bands are bounded by the positive roots of Re(chi_free conj(s chi_locked)).

    The ranges come from the root locus of ``chi_free + E chi_locked`` in k_e (or J_e): a root
    crosses the imaginary axis only at the roots of a polynomial in w^2 (exact crossing values);
    one evaluation per interval between them decides its stability.

    Passivity index interval. Shime, Vergamini, Zanette, dos Santos, Maitan, Calanca and
    Boaventura, "Load-independent metrics for benchmarking force controllers" (2025,
    arXiv:2505.08730) define a *passivity index interval* blending passivity and small-gain
    reasoning; only the paper's abstract could be read here, so the quantity reported is our
    construction of that idea, not a transcription: in each band where Re Z < 0, a passive
    environment cannot cancel Z unless |Z_e(jw)| = |Z(jw)|. Environments lighter than the band's
    least |Z| (homotopy from the free port, which must be stable) or heavier than its greatest
    |Z| (from the locked port) are certified; passivity certifies every other frequency. The
    interval [light_below, heavy_above] of impedance magnitudes is the one left uncertified.

    References
    ----------
    .. [1] J. E. Colgate, N. Hogan, "Robust control of dynamically interacting systems",
       Int. J. Control 48(1), 1988.
    .. [2] V. Shime et al., "Load-independent metrics for benchmarking force controllers",
       arXiv:2505.08730, 2025.

    Examples
    --------
    >>> r = analyse_passivity("soft", "lo-dob")
    >>> r.passive, r.locked_stable
    (True, True)
    """
    if environment_name is not None and not isinstance(environment_name, str):
        raise ParameterError(f"environment_name must be a string or None, got {type(environment_name).__name__}",
                             name="environment_name", value=environment_name)
    if rate_hz is not None and (isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float))
                                or not math.isfinite(rate_hz) or rate_hz <= 0.0):
        raise ParameterError(f"rate_hz must be a rate > 0 [Hz] or None, got {rate_hz!r:.40}", name="rate_hz",
                             value=rate_hz)
    name, design = _design(design, testbed)
    if isinstance(compensator, str):
        compensator = None if compensator == "none" else Compensator(kind=compensator)
    comp = compensator if compensator is not None else design.compensator
    ctrl = resolve_controller(controller if controller is not None else design.controller, default=PAPER_PD)
    if design.environment.locked:
        raise ParameterError("passivity: the environment is locked; give the environment the compensator believes "
                             "(a locked output has no port to attach environments to)", name="environment")
    notes: list[str] = []
    C = _continuous_law(ctrl, rate_hz, notes)
    P = port_impedance(design, comp, ctrl, C=C, port=port)
    link = P if port == "link" else port_impedance(design, comp, ctrl, C=C, port="link")
    locked_stable = is_hurwitz(P.locked)
    free_stable = _free_stable(P.free)
    min_re, w_min = real_part_minimum(P.free, P.s_locked)
    z_at = abs(complex(P.Z(1j * w_min))) if 0.0 < w_min < math.inf else abs(min_re)
    bands = tuple(negative_bands(P.free, P.s_locked)) if min_re < 0.0 else ()
    passive = bool(locked_stable and _residue_ok(P) and min_re >= -PASSIVITY_RTOL * max(z_at, 1e-300))
    rho = real_part_minimum(P.s_locked, P.free)[0] if free_stable else None
    env = design.environment
    stiff = stable_parameter_intervals(link.coupled(env.J_e, env.d_e, 0.0), link.locked)
    a_j, b_j = link.coupled(0.0, env.d_e, env.k_e), np.concatenate([link.locked, [0.0, 0.0]])
    m = min(poly.trailing_zeros(a_j), poly.trailing_zeros(b_j))
    if 0 < m < 10**9:      # k_e = 0: the free output's position (no torque sees it) is divided out, as force_loop does
        a_j, b_j = poly.drop_trailing(a_j, m), poly.drop_trailing(b_j, m)
    inertia = stable_parameter_intervals(a_j, b_j)
    comp_value = comp or Compensator()
    from ..compensators import compensator_strategy

    assumptions = {
        "controller": {"label": ctrl.label, "spelling": ctrl.spelling(), "table": ctrl.to_mapping()},
        "compensator": {"label": comp_value.label, "table": comp_value.to_mapping(),
                        "w_q_hz": comp_value.w_q_hz if comp_value.is_observer else None,
                        "linear_analysis": compensator_strategy(comp_value).analysis_note(comp_value)},
        "testbed": design.testbed.to_mapping(),
        "environment": {"name": environment_name or name, **env.to_mapping(),
                        "role": "believed by the compensator (EA-FOB E0, LD-DOB link); the J_e, d_e (k_e) at which "
                                "the stiffness (inertia) range is taken; the port is tested against every passive "
                                "true environment"},
        "port": {"at": port, "link_J_l_kg_m2": env.J_l, "link_d_l_n_m_s_per_rad": env.d_l,
                 "link_in": "actuator" if port == "link" else "environment"},
        "loop": "continuous (the controller's C(s); a discrete controller's inverse-Tustin equivalent)",
        "conventions": _CONVENTIONS,
    }
    return PassivityResult(
        passive=passive, locked_stable=locked_stable, free_stable=free_stable, min_re_z=min_re,
        w_min_rad_s=w_min, bands_rad_s=bands, output_index=rho,
        index_interval=_index_interval(P, bands, locked_stable, free_stable),
        stiffness_intervals=tuple(stiff), inertia_intervals=tuple(inertia),
        destabilising_environment=_witness(link), port=P, design=design, assumptions=assumptions,
        notes=tuple(notes))
