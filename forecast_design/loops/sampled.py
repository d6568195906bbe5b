"""The sampled-data force loop at the control rate: discretised controller and observer, ZOH plant, delays.

:func:`sampled_force_loop` builds the loop the 2 kHz hardware (and the simulator) runs,
from the same discrete controller and observer objects as the simulator and the C export,
and hands its polynomials to :mod:`forecast_design.margins`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .. import polynomials as poly
from ..errors import ParameterError
from ..lti import RationalTF
from ..margins import STABILITY_TOLERANCE, DiskMargin, check_skew, disk_margin_from_polynomials
from ..compensators import compensator_strategy
from ..controllers import PAPER_PD, Controller, DiscreteLaw, controller_law, resolve_controller
from ..params import Compensator, Design
from ..limits import check_limit, check_physical
from .closing import BREAK_POINTS, ObservedPlant, close_loop

__all__ = ["COMMAND_DELAY_SAMPLES", "SampledForceLoop", "sampled_force_loop", "ZohPlant", "zoh_plant", "to_w", "law_in_w"]

# ---------------------------------------------------------------------------------------------
# Sampled-data force loop (2 kHz): discretised controller and observer, ZOH plant, delays
# ---------------------------------------------------------------------------------------------

#: Relative size below which a trailing coefficient is the exact rigid-body root w = 0 of a
#: free output (exact in exact arithmetic, see :func:`sampled_force_loop`).
_DEFLATE_RTOL = 1e-9

#: The command-delay convention of every sampled analysis [samples]: the command computed from the
#: samples at t_n is applied within the same period, as the virtual testbed's kernel and the
#: firmware (``fd_app.c`` writes the DAC at once) run it, so a sampled margin, the simulation and the
#: benchmark's disk-margin column describe one loop. A board that applies its command one period
#: late is analysed with ``delay_samples = 1`` and simulated with a ``delay`` effect of one period
#: (the two agree: ``tests/test_loops_sampled.py``).
COMMAND_DELAY_SAMPLES = 0


@dataclass(frozen=True, eq=False)
class SampledForceLoop:
    """The sampled-data force loop: discrete controller and observer, ZOH plant, delays.

    Everything is held in the Tustin variable w = (2/T)(z - 1)/(z + 1) [rad/s] (the
    w-plane): a z-polynomial of order ~15 with roots clustered near z = 1 (poles at
    |p| T << 1) has coefficients that no longer determine its roots in double precision,
    while in w the same roots sit near the continuous poles. z = exp(j w T) corresponds to
    w = j (2/T) tan(w T / 2), and |z| < 1 to Re w < 0.

    Attributes
    ----------
    L : RationalTF
        (property) Discrete loop transfer function L(z) (``dt`` set), negative feedback
        [-]; for display and export. Use :meth:`disk_margin` (from ``L_w``) for margins.
    L_w : RationalTF
        The same loop in the w-plane (continuous-time object) [-].
    characteristic_polynomial : ndarray, shape (n + 1,)
        Closed-loop characteristic polynomial in w (descending), full order.
    closed_loop_poles : ndarray of complex, shape (n,)
        Its roots mapped to the z-plane, z = (1 + w T/2)/(1 - w T/2) [-].
    stable : bool
        All w-roots satisfy Re w < -1e-9 max(1, |w|) (i.e. |z| < 1), and the order did not
        drop (no pole at z = -1).
    rate_hz : float
        Sampling rate [Hz].
    delay_samples : int
        Computation delay of the command [samples].
    break_at : str
        ``'controller'`` or ``'plant-input'``.
    C : RationalTF
        The force controller's feedback path C(z) as it runs (``u = C_r tau_r - C tau_s``) [N m/N m].
    P, P_theta : RationalTF
        ZOH-discretised tau_s/tau_m [N m/N m] and theta/tau_m [rad/(N m)], z-domain.
    observer : tuple of RationalTF
        The compensator's discrete linear filters (G_m, G_s, G_theta; an absent path is the zero
        TF) as the simulator and the C export run them; empty without a linear part.
    controller : Controller
        The controller analysed.
    law : DiscreteLaw
        Its difference equation at ``rate_hz``.
    """

    L_w: RationalTF
    characteristic_polynomial: np.ndarray
    closed_loop_poles: np.ndarray
    stable: bool
    rate_hz: float
    delay_samples: int
    break_at: str
    C: RationalTF
    P: RationalTF
    P_theta: RationalTF
    observer: tuple[RationalTF, ...]
    controller: Controller
    law: DiscreteLaw

    @property
    def max_pole_magnitude(self) -> float:
        """Largest |z| of the closed-loop poles [-]."""
        return float(np.max(np.abs(self.closed_loop_poles))) if self.closed_loop_poles.size else 0.0

    @cached_property
    def L(self) -> RationalTF:
        """Discrete loop L(z) (``dt`` set): Tustin of ``L_w``, computed on first use [-].

        For display and export only: at order ~14 with poles clustered near z = 1 its
        coefficients do not determine the response near z = 1 in double precision
        (python-control's grid on it gave alpha = 0.47 for a loop whose exact margin is
        1.10, stiff/LO-DOB 5 Hz at 2 kHz). Margins come from :meth:`disk_margin` (``L_w``).
        """
        from ..discrete import discretize

        lz = discretize(self.L_w, self.rate_hz, "tustin")
        return RationalTF(lz.num, lz.den, dt=1.0 / self.rate_hz, name="L")

    def disk_margin(self, sigma: float = 0.0) -> DiskMargin:
        """Exact disk margin of the sampled loop up to Nyquist.

        Parameters
        ----------
        sigma : float
            Disk skew [-].

        Returns
        -------
        DiskMargin
            As :func:`disk_margin` of L(z) (critical frequency [rad/s] in (0, pi/T], delay
            margin [s]), computed from ``L_w`` and the stability flag of this loop.
        """
        sigma = check_skew(sigma)
        a = 0.5 / self.rate_hz
        num, den = np.asarray(self.L_w.num, float), np.asarray(self.L_w.den, float)
        n = max(len(num), len(den))
        num, den = poly.pad(num, n), poly.pad(den, n)
        # disk_margin's discrete variable is s~ = (z - 1)/(z + 1) = a w: coefficients of w^k
        # scale by a^-k
        k = np.arange(n - 1, -1, -1)
        scale = a ** (-k.astype(float))
        num, den = num * scale, den * scale
        f = max(np.max(np.abs(num)), np.max(np.abs(den)))
        stable = self.stable and (num[0] + den[0]) != 0.0
        proxy = RationalTF((1.0,), (1.0,), dt=1.0 / self.rate_hz, name="L")
        return disk_margin_from_polynomials(proxy, num / f, den / f, sigma, stable)


#: Widest spread of the characteristic polynomial's coefficients the exact analysis trusts [decades]:
#: each delay sample multiplies it by 2/T (3.6 decades at 2 kHz); beyond about 300 decades double
#: precision loses the roots (a stable loop read as unstable, then LinAlgError), and up to 290 the
#: margins were checked against a dense frequency grid and the poles against a state-space model.
MAX_COEFFICIENT_DECADES = 250.0


def _check_resolvable(chi: np.ndarray, delay_samples: int, rate_hz: float) -> None:
    """Refuse a loop whose characteristic polynomial double precision cannot resolve (issue 23)."""
    magnitudes = np.abs(chi[chi != 0.0])
    finite = bool(np.all(np.isfinite(chi)))
    decades = float(np.log10(magnitudes.max() / magnitudes.min())) if finite and magnitudes.size else math.inf
    if decades > MAX_COEFFICIENT_DECADES:
        spread = f"{decades:.0f} decades" if math.isfinite(decades) else "more decades than a float holds"
        raise ParameterError(f"delay_samples = {delay_samples} at rate_hz = {rate_hz:g} Hz: the sampled loop's "
                             f"characteristic polynomial spans {spread}, more than double precision "
                             f"resolves ({MAX_COEFFICIENT_DECADES:g} decades; each delay sample adds "
                             f"{math.log10(2.0 * rate_hz):.1f}); give fewer delay samples",
                             name="delay_samples", value=delay_samples)


def _deflate_w(p: np.ndarray, what: str) -> np.ndarray:
    """p(w) / w for the exact rigid-body root w = 0, checking it is there up to rounding."""
    p = np.asarray(p, float)
    if abs(p[-1]) > _DEFLATE_RTOL * float(np.max(np.abs(p))):
        raise ParameterError(f"sampled_force_loop: {what} has no root at w = 0 (z = 1) to divide out",
                             name=what, value=float(p[-1]))
    return p[:-1] if len(p) > 1 else np.zeros(1)


def to_w(dtf: Any) -> tuple[np.ndarray, np.ndarray]:
    """A discrete transfer function in the w-plane, ``z = (1 + a w) / (1 - a w)``, ``a = T / 2``.

    Parameters
    ----------
    dtf : DiscreteTF or RationalTF
        From :func:`forecast_design.discrete.discretize` (a Tustin one without prewarp maps back
        to its continuous source exactly), or a discrete RationalTF (``dt`` set).

    Returns
    -------
    (ndarray, ndarray)
        Numerator and denominator in ``w``, descending powers.
    """
    if getattr(dtf, "method", None) == "tustin" and getattr(dtf, "prewarp_hz", None) is None \
            and dtf.source is not None:
        return np.asarray(dtf.source.num, float), np.asarray(dtf.source.den, float)
    a = 0.5 * dtf.dt
    num, den = np.asarray(dtf.num, float), np.asarray(dtf.den, float)
    n = max(len(num), len(den)) - 1
    rho, ell = np.array([a, 1.0]), np.array([-a, 1.0])

    def mapped(p):
        out = np.zeros(n + 1)
        for i, c in enumerate(poly.pad(p, n + 1)):
            j = n - i
            out += c * poly.mul(poly.power(rho, j), poly.power(ell, n - j))
        return poly.trim(out)

    return mapped(num), mapped(den)


def law_in_w(law: DiscreteLaw) -> RationalTF:
    """A controller's feedback path ``C(z)`` in the w-plane, channel by channel (Tustin channels exactly).

    Parameters
    ----------
    law : DiscreteLaw
        The controller's difference equation.

    Returns
    -------
    RationalTF
        ``C`` as a function of ``w`` (a continuous-time object) [N m/N m].
    """
    total = RationalTF((0.0,), (1.0,))
    sign = {"error": 1.0, "tau_r": 0.0, "tau_s": -1.0}
    for ch in law.channels:
        if sign[ch.source]:
            total = total + sign[ch.source] * RationalTF(*to_w(ch.tf))
    if law.integrator is not None:
        total = total + RationalTF(*to_w(law.integrator.tf(law.dt)))
    return total.named("C_w")


def _common_plant(design: Design) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N_s, N_theta, D): P and P_theta of a design over one continuous denominator."""
    from ..symbolic import force_plant_tf, motor_angle_tf

    P = force_plant_tf(design)
    Pt = motor_angle_tf(design)
    pn, pd = np.asarray(P.num, float), np.asarray(P.den, float)
    tn, td = np.asarray(Pt.num, float), np.asarray(Pt.den, float)
    pn, pd = pn / pd[0], pd / pd[0]
    tn, td = tn / td[0], td / td[0]
    if len(pd) == len(td) and np.allclose(pd, td, rtol=1e-12, atol=0.0):
        return pn, tn, pd
    # a free output (k_e = 0): force_plant_tf divided the exact factor s out of P, P_theta keeps
    # the rigid-body pole; bring P back over P_theta's denominator
    q, r = np.polydiv(td, pd)
    if np.all(np.abs(r) <= 1e-12 * np.max(np.abs(td))):
        return poly.mul(pn, q), tn, td
    return poly.mul(pn, td), poly.mul(tn, pd), poly.mul(pd, td)


@dataclass(frozen=True, slots=True)
class ZohPlant:
    Ns_w: np.ndarray      # w-plane numerators and common denominator
    Nt_w: np.ndarray
    D_w: np.ndarray
    Ns_z: np.ndarray      # z-domain, for display
    Nt_z: np.ndarray
    D_z: np.ndarray
    free: bool


def _tf2ss(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``scipy.signal.tf2ss`` of rows ``num`` over ``den`` (controllable canonical form), the same
    numbers (its normalisation and its trimming of numerator columns below 1e-14 included), without
    importing ``scipy.signal``: that import takes over a second of every process that
    needs a sampled loop, and only these two conversions of it are used here."""
    den = den[np.flatnonzero(den)[0]:]
    num, den = num / den[0], den / den[0]
    lead = 0
    while lead < num.shape[1] - 1 and np.all(np.abs(num[:, lead]) <= 1e-14):
        lead += 1
    num = np.hstack((np.zeros((num.shape[0], len(den) - num.shape[1] + lead)), num[:, lead:]))
    A = np.r_[-np.array([den[1:]]), np.eye(len(den) - 2, len(den) - 1)]
    return A, np.eye(len(den) - 1, 1), num[:, 1:] - np.outer(num[:, 0], den[1:]), num[:, :1]


def _ss2tf(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.ss2tf`` of a single-input system (numerator rows, denominator), the same numbers."""
    den = np.poly(A)
    num = np.empty((C.shape[0], A.shape[0] + 1))
    for k in range(C.shape[0]):
        num[k] = np.poly(A - B @ C[k:k + 1, :]) + (D[k] - 1) * den
    return num, den


def zoh_plant(design: Design, rate_hz: float) -> ZohPlant:
    """ZOH discretisation of [P; P_theta] from one state-space realisation (shared poles).

    Parameters
    ----------
    design : Design
        The true plant (testbed and environment).
    rate_hz : float
        Sampling rate [Hz].

    Returns
    -------
    ZohPlant
        Numerators of ``tau_s / tau_m`` and ``theta / tau_m`` and their common denominator in
        the w-plane.

    With Phi = int_0^T exp(A t) dt (from one matrix exponential), A_d = I + A Phi and
    B_d = Phi B, so A_d - I is formed without cancellation. In the w-plane,
    z I - A_d = a (I + A_d)(w I - A_w)/(1 - a w) with a = T/2 and
    A_w = (I + A_d)^-1 A Phi / a, hence P(w) = (1 - a w) C (w I - A_w)^-1 B~ with
    B~ = (I + A_d)^-1 Phi B / a (P is strictly proper).
    """
    from scipy import linalg

    ns, nt, d = _common_plant(design)
    n = len(d) - 1
    num = np.vstack([poly.pad(ns, n + 1), poly.pad(nt, n + 1)])
    A, B, Cm, Dm = _tf2ss(num, d)
    if np.any(Dm != 0.0):  # pragma: no cover - P and P_theta are strictly proper
        raise ParameterError("sampled_force_loop: the plant must be strictly proper", name="P", value=None)
    T = 1.0 / rate_hz
    a = 0.5 * T
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n] = A * T
    m[:n, n:] = np.eye(n) * T
    e = linalg.expm(m)
    Ad, Phi = e[:n, :n], e[:n, n:]
    Bd = Phi @ B
    IAd = np.eye(n) + Ad
    Aw = np.linalg.solve(IAd, A @ Phi) / a
    Bw = np.linalg.solve(IAd, Bd) / a
    n1, dw = _ss2tf(Aw, Bw, Cm, np.zeros((2, 1)))
    numz, denz = _ss2tf(Ad, Bd, Cm, Dm)
    ell = np.array([-a, 1.0])
    free = bool(d[-1] == 0.0)
    return ZohPlant(poly.trim(poly.mul(ell, n1[0])), poly.trim(poly.mul(ell, n1[1])), np.asarray(dw, float),
                     np.asarray(numz[0], float), np.asarray(numz[1], float), np.asarray(denz, float), free)


def sampled_force_loop(
    true_design: Design,
    compensator: Compensator | None = None,
    *,
    controller: object = PAPER_PD,
    believed: Design | None = None,
    rate_hz: float = 2000.0,
    break_at: str = "controller",
    delay_samples: int = COMMAND_DELAY_SAMPLES,
) -> SampledForceLoop:
    """The force loop as it runs on the board: the controller's difference equation, discrete compensator, ZOH plant.

    Parameters
    ----------
    true_design : Design
        The real testbed and environment (its ``controller``/``compensator`` are not used).
    compensator : Compensator or None
        Compensator (its discrete linear part enters: an observer's filters, an SFM's viscous
        feed-forward); ``None``/``'none'``: plant alone.
    controller : Controller, str or python-control system
        The force controller; its :meth:`~forecast_design.controllers.Controller.discrete_law`
        at ``rate_hz`` (its own discretisation) closes the loop. Default the paper's PD.
    believed : Design or None
        What the compensator believes (``None``: the truth).
    rate_hz : float
        Sampling rate [Hz] (Forecast: 2000).
    break_at : str
        ``'controller'``: L = C(z) F_DOB(z) at the force-controller output (default, the
        paper's); ``'plant-input'``: at the command going to the motor (the observer's own
        ``tau_m_prev`` loop stays closed: it is memory inside the controller).
    delay_samples : int
        Computation delay d >= 0 [samples]: the command computed from the samples at t_n is
        applied from t_(n+d); default :data:`COMMAND_DELAY_SAMPLES` (0, as the simulator and the
        firmware apply it).

    Returns
    -------
    SampledForceLoop
        L(z), L in the w-plane, the full characteristic polynomial, poles, stability flag;
        ``.disk_margin(sigma)`` gives the exact margins up to Nyquist.

    Raises
    ------
    ParameterError
        For a bad rate, delay or break point, an improper observer, a controller without
        equations or whose discretisation is unstable.

    Notes
    -----
    The pieces are those of the simulator and the C export (one construction, reused):
    C(z) is the controller's law (:mod:`forecast_design.controllers`), the compensator filters
    its strategy's (:mod:`forecast_design.compensators`; Tustin, each filter its own sections)
    with G_m fed the previous command (z^-1), and the plant [P; P_theta] is discretised with a
    zero-order hold from one state-space realisation (both outputs share the poles exp(p T)).
    A Tustin filter is, in the w-plane, exactly the continuous filter it was made from. With
    the command c, the applied torque a = z^-d c, G_x = B_x / E over the product E of the
    filter denominators, P = N_s / D, P_theta = N_theta / D, rho = 1 + w T/2,
    ell = 1 - w T/2 (z = rho/ell), the compensator closed around the plant gives
    (:class:`~forecast_design.loops.closing.ObservedPlant`)

        F_DOB = N_s E ell^d rho / Delta,
        Delta = D E rho^(d+1) - B_m ell rho^d D - (B_s N_s + B_theta N_theta) ell^d rho

    and the controller closes it in :func:`~forecast_design.loops.closing.close_loop`:
    L = C F_DOB, chi = C_d Delta + C_n N_s E ell^d rho (full order: a mode cancelled in L
    still decides stability). A free output (k_e = 0) has the rigid-body root w = 0 in D and
    N_s (and in B_theta, the motor FOB's double differentiator): that exact factor is
    divided out, as :func:`~forecast_design.loops.continuous.force_loop` divides out s.
    As T -> 0, rho, ell -> 1 and the plant tends to P(s): the loop tends to the continuous
    loop with the same controller (whose discretisation tends to its C(s)).
    """
    if break_at not in BREAK_POINTS:
        raise ParameterError(f"break_at must be one of {', '.join(BREAK_POINTS)}, got {break_at!r}",
                             name="break_at", value=break_at)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) or not (rate_hz > 0.0) \
            or not math.isfinite(rate_hz):
        raise ParameterError(f"rate_hz must be a finite number > 0 [Hz], got {rate_hz!r}",
                             name="rate_hz", value=rate_hz)
    check_limit("delay_samples", "delay_samples", delay_samples)
    check_physical("sampled loop", "rate_hz", rate_hz)
    controller = resolve_controller(controller)
    rate_hz = float(rate_hz)
    T = 1.0 / rate_hz
    a = 0.5 * T
    d = delay_samples
    rho, ell = np.array([a, 1.0]), np.array([-a, 1.0])
    law = controller_law(controller, rate_hz)
    C_w = law_in_w(law)
    plant = zoh_plant(true_design, rate_hz)
    Ns, Nt, D = plant.Ns_w, plant.Nt_w, plant.D_w
    filters = compensator_strategy(compensator).discrete_filters(
        compensator or Compensator(), believed if believed is not None else true_design, rate_hz)
    if not filters.is_zero:
        tfs = (filters.from_tau_m, filters.from_tau_s, filters.from_theta)
        # an absent path (e.g. G_theta of the DOBs) is a zero filter: no poles
        pairs = [to_w(tf) if tf is not None else (np.zeros(1), np.ones(1)) for tf in tfs]
        dens = [den for _, den in pairs]
        E = poly.mul(*dens)
        Bm, Bs, Bt = (poly.mul(num, *(dens[j] for j in range(3) if j != i)) for i, (num, _) in enumerate(pairs))
        observer = tuple(tf.to_rational() if tf is not None else RationalTF((0.0,), (1.0,), dt=T, name=name)
                         for tf, name in zip(tfs, ("G_m", "G_s", "G_theta")))
    else:
        E, Bm, Bs, Bt = np.ones(1), np.zeros(1), np.zeros(1), np.zeros(1)
        observer = ()
    Bm, Bs, Bt = poly.trim(Bm), poly.trim(Bs), poly.trim(Bt)
    uses_theta = bool(np.any(Bt != 0.0))
    if plant.free:
        D, Ns = _deflate_w(D, "D"), _deflate_w(Ns, "N_s")
        if uses_theta:
            Bt = _deflate_w(Bt, "B_theta")
    if not uses_theta:
        Nt = np.zeros(1)            # theta unused (for a free output: its rigid-body drift too)
    obs_terms = poly.add(poly.mul(Bs, Ns), poly.mul(Bt, Nt))
    ell_d = poly.power(ell, d)
    delta = poly.trim(poly.sub(poly.sub(poly.mul(D, E, poly.power(rho, d + 1)), poly.mul(Bm, ell, poly.power(rho, d), D)),
                       poly.mul(obs_terms, ell_d, rho)))
    observed = ObservedPlant(poly.trim(poly.mul(Ns, E, ell_d, rho)), delta, poly.trim(poly.mul(obs_terms, ell_d, rho)),
                             poly.trim(poly.mul(D, poly.power(rho, d), poly.sub(poly.mul(E, rho), poly.mul(Bm, ell)))))
    Lw, chi = close_loop(observed, C_w, break_at)
    Lw = Lw.named("L_w")
    order = (len(C_w.den) - 1) + (len(D) - 1) + (len(E) - 1) + d + 1
    _check_resolvable(chi, d, rate_hz)
    roots = np.roots(chi) if len(chi) > 1 else np.zeros(0, dtype=complex)
    stable = len(chi) - 1 == order and bool(
        np.all(roots.real < -STABILITY_TOLERANCE * np.maximum(1.0, np.abs(roots))))
    with np.errstate(divide="ignore", invalid="ignore"):
        poles = (1.0 + a * roots) / (1.0 - a * roots)
    chi = chi.copy()
    chi.flags.writeable = False
    poles = np.asarray(poles, dtype=complex)
    poles.flags.writeable = False
    cz = law.feedback_tf()
    return SampledForceLoop(
        L_w=Lw, characteristic_polynomial=chi,
        closed_loop_poles=poles, stable=stable, rate_hz=rate_hz, delay_samples=d, break_at=break_at,
        C=cz, P=RationalTF(plant.Ns_z, plant.D_z, dt=T, name="P"),
        P_theta=RationalTF(plant.Nt_z, plant.D_z, dt=T, name="P_theta"), observer=observer,
        controller=controller, law=law)
