"""The simulated SEA + environment with unmodelled effects, and its fixed-step RK4 integrator.

State ``x = [theta, omega, q, v, z]``: motor angle [rad] and velocity
[rad/s], environment angle [rad] and velocity [rad/s], LuGre bristle
deflection [rad]. Equations (experiment format, "Plant equations")::

    J_m omega' = tau_app - tau_s - tau_frc
    tau_s      = k dz(theta - q - c)            (dz: backlash dead band centred at c, identity without it)
    J v' + d v + k_e q = tau_s                   (locked: q = v = 0;
                                                  J = 0, d > 0: d q' + k_e q = tau_s)
    tau_frc    = d_m omega + F_c sat(omega / v_reg)                        (coulomb)
               + sigma0 z + sigma1 z' + sigma2 omega                       (stiction, LuGre)
               + sat(omega / v_reg) (F_c' + sum a_i sin i th + b_i cos i th) (position_friction)
               + sum a_i sin i th + b_i cos i th                           (cogging)
    tau_app    = gain * tau_cmd(t - delay) + w                            (torque_gain, delay,
                                                                           process noise w)

where ``th = theta + initial_angle`` is the absolute motor angle.

Integration and stability
-------------------------
Each control period T = 1/rate_hz is split into ``substeps`` classical RK4
steps of h = T / substeps, with the command held (zero-order hold). For the
nominal testbed at 2 kHz and 10 substeps, h = 50 us. RK4's stability region
reaches |h lambda| ~ 2.79 on the negative real axis and ~ 2.83 on the
imaginary axis. The stiffest modes of the supported set-ups are:

* spring / environment oscillators: the two-mass mode of a light link,
  sqrt(k (1/J_m + 1/J)) = sqrt(58 (1/0.133 + 1/0.0028)) ~ 145 rad/s for
  ``exp-soft`` / ``link-only`` (h lambda ~ 0.007), the locked motor
  sqrt(k/J_m) ~ 21 rad/s, and the environment damping pole d/J ~ 150 1/s;
* sticking LuGre bristles: stiffness sigma0 + k = 318 N m/rad on J_m = 0.133
  gives ~ 49 rad/s with damping (sigma1 + sigma2 + d_m)/J_m ~ 7.5 1/s
  (h lambda ~ 0.0025);
* sliding LuGre bristles: z relaxes at rate a = sigma0 |omega| / g(omega),
  at most sigma0 |omega| / min(F_c, F_s). With Table 2 (sigma0 = 260,
  F_c = 0.4) h a = 0.0325 |omega| : RK4 stays stable up to |omega| ~ 85 rad/s.
  Above the switch ``h a > 2`` (|omega| > 61 rad/s at 2 kHz x 10) the
  bristle is treated as quasi-steady for that substep: z is slaved to its
  frozen-velocity equilibrium g(omega) sign(omega) / sigma0, i.e. the
  friction is the Stribeck curve, which is where the real bristle state
  settles within a fraction of h anyway (singular perturbation);
* regularised Coulomb / position friction: slope F_c / v_reg on J_m, e.g.
  0.4 / 1e-3 / 0.133 = 3000 1/s (h lambda = 0.15).

:func:`stability_check` computes these rates for the actual parameters
(eigenvalues of the linearised plant, sticking and sliding) and raises if
any |R(h lambda)| > 1, R the RK4 stability polynomial.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..effects import (
    Backlash,
    Cogging,
    Coulomb,
    Delay,
    EnvironmentMismatch,
    NoEffect,
    PositionFriction,
    Stiction,
    TorqueGain,
)
from ..errors import ParameterError
from ..discrete import HAVE_NUMBA, njit
from ..friction.laws import stribeck_level
from ..params import Design, Environment

# numba IR-level inlining of the per-substep helpers. The helpers take scalars and the parameter
# tuple of _unpack, never an array but the harmonic table (and that only inside the branch for
# angle harmonics): numba reference-counts each array a call binds, atomically, and that cost 3x
# the arithmetic of a substep (issue 16). Only the array-binding helpers and the outer two are
# IR-inlined: LLVM inlines the scalar ones (_rhs, _level, stribeck_level) as well, and inlining
# them in numba's IR too multiplied the first compile by 2.5 (25 s against 10 s per kernel) for no
# measurable speed (benchmarks/RESULTS.md, "Plant kernel: compile time").
_INLINE = {"_substep": "always", "_unpack": "always", "advance_period": "always", "_angle_terms": "always",
           "spring_torque": "always"}

def _njit(func):
    return njit(func, inline=_INLINE.get(func.__name__, "never"))


# The friction laws' one definition, compiled for the scalar kernels.
_stribeck_level = _njit(stribeck_level)

__all__ = ["PlantModel", "PlantStepper", "TorqueSensor", "build_plant", "stability_check", "rk4_growth", "integrate_open_loop",
           "advance_period", "history_length", "spring_torque", "HAVE_NUMBA"]

# Indices into the packed float parameter vector of the kernels.
I_JM, I_DM, I_K, I_MODE, I_J, I_D, I_KE, I_BL = 0, 1, 2, 3, 4, 5, 6, 7
I_CFC, I_CVR = 8, 9
I_LUGRE, I_FS, I_FC, I_S2, I_VS, I_S1, I_S0 = 10, 11, 12, 13, 14, 15, 16
I_PFC, I_PVR, I_GAIN, I_ANG0, I_H, I_QS, I_HARM = 17, 18, 19, 20, 21, 22, 23
I_BLC = 24                        # backlash: centre of the dead band in theta - q [rad]
N_PARAMS = 25
# Rows of the harmonic table: position friction a/b, cogging a/b, LuGre F_s a/b, LuGre ln v_s a/b.
H_PA, H_PB, H_CA, H_CB, H_SA, H_SB, H_VA, H_VB = 0, 1, 2, 3, 4, 5, 6, 7
N_HARM_ROWS = 8

#: Environment modes of the kernel.
MODE_LOCKED, MODE_INERTIAL, MODE_FIRST_ORDER = 0.0, 1.0, 2.0
#: Quasi-steady bristle switch: h * sigma0 |omega| / g(omega) above this.
QS_THRESHOLD = 2.0
#: RK4 real-axis stability limit (root of 1 + x + x^2/2 + x^3/6 + x^4/24 = +-1).
RK4_REAL_LIMIT = 2.785293563405282


@dataclass(frozen=True, slots=True, kw_only=True)
class TorqueSensor:
    """A torque sensor in the spring: its reading is ``gain`` times the true spring torque, plus ``offset_N_m``
    and white noise of std ``noise_std_N_m`` per sample.

    Parameters
    ----------
    noise_std_N_m : float
        Std of the white noise [N m] (>= 0).
    gain : float
        Scale of the reading [-] (> 0; a datasheet's few per cent off 1).
    offset_N_m : float
        Zero of the reading [N m].

    Examples
    --------
    >>> TorqueSensor(noise_std_N_m=0.002, gain=1.05).to_mapping()
    {'noise_std_N_m': 0.002, 'gain': 1.05, 'offset_N_m': 0.0}
    """

    noise_std_N_m: float = 0.0
    gain: float = 1.0
    offset_N_m: float = 0.0

    def __post_init__(self) -> None:
        for name, ok in (("noise_std_N_m", lambda v: 0.0 <= v < math.inf), ("gain", lambda v: 0.0 < v < math.inf),
                         ("offset_N_m", math.isfinite)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not ok(float(value)):
                raise ParameterError(f"TorqueSensor {name} must be a finite number"
                                     f"{' >= 0' if name == 'noise_std_N_m' else ' > 0' if name == 'gain' else ''}, "
                                     f"got {value!r}", name=name, value=value)

    def to_mapping(self) -> dict[str, float]:
        """The sensor's values for JSON (``noise_std_N_m`` [N m], ``gain`` [-], ``offset_N_m`` [N m])."""
        return {"noise_std_N_m": float(self.noise_std_N_m), "gain": float(self.gain), "offset_N_m": float(self.offset_N_m)}


@dataclass(frozen=True, slots=True)
class PlantModel:
    """Packed parameters of the true plant for the compiled kernels.

    Build with :func:`build_plant`. ``params`` and ``harmonics`` are
    read-only arrays in the kernel layout; the other fields say what they
    mean.
    """

    environment: Environment          # the true environment
    params: np.ndarray                # packed float parameters, shape (N_PARAMS,)
    harmonics: np.ndarray             # shape (N_HARM_ROWS, n_harmonics)
    delay_substeps: int               # command delay in substeps [-]
    h: float                          # integration step [s]
    effects: tuple = field(default=())

    @property
    def locked(self) -> bool:
        """True when q == 0."""
        return self.params[I_MODE] == MODE_LOCKED


def _first(effects: Sequence[Any], cls: type):
    found = [e for e in effects if isinstance(e, cls)]
    if len(found) > 1:
        raise ParameterError(f"effect '{cls.effect}' given {len(found)} times; give it once",
                             name="effects", value=str(cls.effect))
    return found[0] if found else None


_KNOWN = (NoEffect, Coulomb, Stiction, PositionFriction, Cogging, Backlash, Delay, TorqueGain, EnvironmentMismatch)


def build_plant(design: Design, effects: Sequence[Any] = (), *, rate_hz: float = 2000.0, substeps: int = 10,
                initial_angle: float = 0.0, include_nominal_viscous: bool = True) -> PlantModel:
    """Pack the true plant (nominal design + effects) for the kernels.

    Parameters
    ----------
    design : Design
        Nominal testbed and environment: ``J_m`` [kg m^2], ``d_m`` [N m s/rad],
        ``k`` [N m/rad], environment ``J``, ``d``, ``k_e``.
    effects : sequence of effect parameter values
        From :mod:`forecast_design.effects`; each kind at most once.
    rate_hz : float
        Control rate [Hz].
    substeps : int
        RK4 steps per control period [-] (>= 1).
    initial_angle : float
        Absolute motor angle at theta = 0, used by the angle-dependent
        effects [rad].
    include_nominal_viscous : bool
        Keep ``d_m omega`` in the true friction (default True: the nominal
        model is part of the truth).

    Returns
    -------
    PlantModel
        The packed plant.

    Raises
    ------
    ParameterError
        Unknown effect objects, duplicated effects, an environment without
        inertia and damping (static), or non-positive rate/substeps.
    """
    if not (isinstance(rate_hz, (int, float)) and rate_hz > 0 and math.isfinite(rate_hz)):
        raise ParameterError(f"rate_hz must be > 0 [Hz], got {rate_hz!r}", name="rate_hz", value=rate_hz)
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ParameterError(f"substeps must be an integer >= 1, got {substeps!r}", name="substeps", value=substeps)
    for e in effects:
        if not isinstance(e, _KNOWN):
            raise ParameterError(f"unknown effect {e!r}; use the classes of forecast_design.effects",
                                 name="effects", value=e)
    h = 1.0 / (float(rate_hz) * int(substeps))
    p = np.zeros(N_PARAMS)
    tb = design.testbed
    p[I_JM], p[I_K] = tb.J_m, tb.k
    p[I_DM] = tb.d_m if include_nominal_viscous else 0.0
    mismatch = _first(effects, EnvironmentMismatch)
    env = design.environment if mismatch is None else mismatch.true_environment(design.environment)
    if env.locked:
        p[I_MODE] = MODE_LOCKED
    elif env.J > 0.0:
        p[I_MODE] = MODE_INERTIAL
    elif env.d > 0.0:
        p[I_MODE] = MODE_FIRST_ORDER
    else:
        raise ParameterError(
            "simulated environment has J = J_e + J_l = 0 and d = d_e + d_l = 0: a massless, undamped spring "
            "in series is not a dynamic system; fold it into k or give the link inertia",
            name="J_l", value=env.J_l,
        )
    p[I_J], p[I_D], p[I_KE] = env.J, env.d, env.k_e
    bl = _first(effects, Backlash)
    p[I_BL] = 0.0 if bl is None else bl.width_rad / 2.0
    p[I_BLC] = 0.0 if bl is None else -bl.position * bl.width_rad / 2.0
    c = _first(effects, Coulomb)
    if c is not None:
        p[I_CFC], p[I_CVR] = c.F_c, c.v_reg
    else:
        p[I_CVR] = 1.0
    s = _first(effects, Stiction)
    if s is not None:
        p[I_LUGRE] = 1.0
        p[I_FS], p[I_FC], p[I_S2], p[I_VS], p[I_S1], p[I_S0] = s.F_s, s.F_c, s.sigma2, s.v_s, s.sigma1, s.sigma0
    pf = _first(effects, PositionFriction)
    cg = _first(effects, Cogging)
    n_h = max([1] + [len(e.a) for e in (pf, cg) if e is not None]
              + ([len(s.F_s_a), len(s.v_s_a)] if s is not None else []))
    harm = np.zeros((N_HARM_ROWS, n_h))
    if pf is not None:
        p[I_PFC], p[I_PVR] = pf.F_c, pf.v_reg
        harm[H_PA, :len(pf.a)], harm[H_PB, :len(pf.b)] = pf.a, pf.b
    else:
        p[I_PVR] = 1.0
    if cg is not None:
        harm[H_CA, :len(cg.a)], harm[H_CB, :len(cg.b)] = cg.a, cg.b
    if s is not None:
        harm[H_SA, :len(s.F_s_a)], harm[H_SB, :len(s.F_s_b)] = s.F_s_a, s.F_s_b
        harm[H_VA, :len(s.v_s_a)], harm[H_VB, :len(s.v_s_b)] = s.v_s_a, s.v_s_b
    p[I_HARM] = 1.0 if (pf is not None or cg is not None or np.any(harm[H_SA:] != 0.0)) else 0.0
    g = _first(effects, TorqueGain)
    p[I_GAIN] = 1.0 if g is None else g.gain
    d = _first(effects, Delay)
    delay_sub = 0 if d is None else int(round(d.delay_s / h))
    p[I_ANG0] = float(initial_angle)
    p[I_H] = h
    p[I_QS] = QS_THRESHOLD
    p.flags.writeable = False
    harm.flags.writeable = False
    return PlantModel(env, p, harm, delay_sub, h, tuple(effects))


def rk4_growth(z: complex | np.ndarray) -> np.ndarray:
    """|R(z)| of classical RK4, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24.

    Parameters
    ----------
    z : complex or ndarray
        h * lambda [-].

    Returns
    -------
    ndarray
        Amplification factor; <= 1 inside the stability region.
    """
    z = np.asarray(z, dtype=complex)
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


def _linear_matrix(p: np.ndarray, extra_stiffness: float, extra_damping: float) -> np.ndarray:
    JM, K = p[I_JM], p[I_K]
    dm = p[I_DM] + extra_damping
    km = K + extra_stiffness
    mode = p[I_MODE]
    if mode == MODE_LOCKED:
        return np.array([[0.0, 1.0], [-km / JM, -dm / JM]])
    if mode == MODE_INERTIAL:
        J, D, KE = p[I_J], p[I_D], p[I_KE]
        return np.array([[0.0, 1.0, 0.0, 0.0],
                         [-km / JM, -dm / JM, K / JM, 0.0],
                         [0.0, 0.0, 0.0, 1.0],
                         [K / J, 0.0, -(K + KE) / J, -D / J]])
    D, KE = p[I_D], p[I_KE]
    return np.array([[0.0, 1.0, 0.0],
                     [-km / JM, -dm / JM, K / JM],
                     [K / D, 0.0, -(K + KE) / D]])


def stable_substeps(design: Design, effects: Sequence[Any] = (), *, rate_hz: float = 2000.0, start: int = 10,
                    limit: int = 1000) -> int:
    """Fewest RK4 substeps, from `start` doubling up to `limit`, at which the plant's step is stable.

    A user's SEA (a small J_m against the Table 3 hardware's bristle stiffness) may need more than
    the default 10 substeps per control period; :func:`stability_check` judges each candidate.

    Parameters
    ----------
    design : Design
        Testbed and environment.
    effects : sequence
        The hardware's unmodelled effects.
    rate_hz : float
        Control rate [Hz].
    start, limit : int
        First and largest substep count tried [-].

    Returns
    -------
    int
        The substeps.

    Raises
    ------
    ParameterError
        If even `limit` substeps leave the step unstable (from :func:`stability_check`).
    """
    n = int(start)
    while True:
        try:
            stability_check(build_plant(design, effects, rate_hz=rate_hz, substeps=n))
            return n
        except ParameterError:
            if n >= limit:
                raise
            n = min(2 * n, int(limit))


def stability_check(plant: PlantModel) -> dict[str, float]:
    """Fastest modes of the plant and RK4's amplification at the step h.

    Parameters
    ----------
    plant : PlantModel
        The packed plant.

    Returns
    -------
    dict
        ``max_h_lambda`` (largest |h lambda| [-]), ``max_growth`` (largest
        |R(h lambda)| [-], <= 1 when stable), ``sticking_rad_s`` and
        ``sliding_rad_s`` (largest |lambda| of the linearised plant with
        sticking bristles and with the steepest regularised friction slopes
        [rad/s]), ``bristle_switch_rad_s`` (|omega| above which the LuGre
        bristle is quasi-steady [rad/s], inf without LuGre).

    Raises
    ------
    ParameterError
        If some mode has |R(h lambda)| > 1 (too few substeps).
    """
    p, h = plant.params, plant.h
    slope = 0.0
    if p[I_CFC] > 0.0:
        slope += p[I_CFC] / p[I_CVR]
    if p[I_PFC] > 0.0:
        slope += (p[I_PFC] + np.sum(np.abs(plant.harmonics[H_PA:H_PB + 1]))) / p[I_PVR]
    lam_slide = np.linalg.eigvals(_linear_matrix(p, 0.0, slope + p[I_S2] + p[I_S1]))
    lams = [lam_slide]
    if p[I_LUGRE]:
        lam_stick = np.linalg.eigvals(_linear_matrix(p, p[I_S0], slope + p[I_S1] + p[I_S2]))
        lams.append(lam_stick)
        gmin = min(p[I_FC], p[I_FS] - np.sum(np.abs(plant.harmonics[H_SA:H_SB + 1])))
        switch = QS_THRESHOLD * gmin / (p[I_S0] * h)
        # Dynamic-bristle substeps have h * a <= QS_THRESHOLD at their start.
        lams.append(np.array([-QS_THRESHOLD / h]))
    else:
        lam_stick = np.zeros(1)
        switch = math.inf
    allz = h * np.concatenate(lams)
    growth = float(np.max(rk4_growth(allz)))
    out = {
        "h_s": h,
        "max_h_lambda": float(np.max(np.abs(allz))),
        "max_growth": growth,
        "sticking_rad_s": float(np.max(np.abs(lam_stick))),
        "sliding_rad_s": float(np.max(np.abs(lam_slide))),
        "bristle_switch_rad_s": float(switch),
    }
    if growth > 1.0 + 1e-12:
        raise ParameterError(
            f"RK4 step h = {h:.3g} s is unstable for this plant (max |h lambda| = {out['max_h_lambda']:.3g}, "
            f"|R| = {growth:.3g} > 1); increase substeps or the regularisation velocity v_reg",
            name="substeps", value=round(1.0 / (h * 1.0)),
        )
    return out


@_njit
def _unpack(p):
    """The packed parameter vector as a tuple of scalars (indexed like ``p``: :data:`I_JM` ...).

    The substep helpers take this tuple, not the array: numba reference-counts every array an
    inlined helper receives (an atomic increment and decrement per call), which cost more than
    the arithmetic of a substep; a tuple of floats is passed by value and costs nothing.
    """
    return (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13], p[14],
            p[15], p[16], p[17], p[18], p[19], p[20], p[21], p[22], p[23], p[24])


@_njit
def _angle_terms(x0, c, harm):
    """The angle harmonics at motor angle ``x0`` (absolute angle ``x0 + initial_angle``).

    ``c``: the parameters as :func:`_unpack` gives them. Returns ``(pos, cog, fsh, lvs)``:
    position-friction ripple, cogging torque, stiction level F_s harmonics [N m] and ln v_s
    harmonics [-], each ``sum_i a_i sin(i th) + b_i cos(i th)`` (the harmonic table's rows,
    :data:`H_PA` ...). The one expansion the plant's right-hand side and the bristle rate share;
    sin/cos of i th by the angle-addition recurrence.
    """
    th = x0 + c[I_ANG0]
    s1 = math.sin(th)
    c1 = math.cos(th)
    si = s1
    ci = c1
    pos = 0.0
    cog = 0.0
    fsh = 0.0
    lvs = 0.0
    for i in range(harm.shape[1]):
        pos += harm[H_PA, i] * si + harm[H_PB, i] * ci
        cog += harm[H_CA, i] * si + harm[H_CB, i] * ci
        fsh += harm[H_SA, i] * si + harm[H_SB, i] * ci
        lvs += harm[H_VA, i] * si + harm[H_VB, i] * ci
        si, ci = si * c1 + ci * s1, ci * c1 - si * s1
    return pos, cog, fsh, lvs


@_njit
def _level(x1, c, fsh, lvs):
    """The LuGre bristle's Stribeck level g(omega, theta) [N m] at speed ``x1``, with the angle's F_s and
    ln v_s harmonics ``fsh``, ``lvs`` (:func:`_angle_terms`); 1 without LuGre."""
    g = 1.0
    if c[I_LUGRE] > 0.0:
        fs = c[I_FS]
        if c[I_HARM] > 0.0:
            fs += fsh
        vs = c[I_VS] if lvs == 0.0 else c[I_VS] * math.exp(lvs)
        g = _stribeck_level(x1, fs, c[I_FC], vs)
    return g


@_njit
def spring_torque(delta, k, bl, blc):
    """The spring torque [N m] at deflection ``delta = theta - q`` [rad]: ``k`` [N m/rad], with a backlash dead
    band of half-width ``bl`` [rad] centred on ``blc`` [rad] (none when ``bl`` is 0)."""
    if bl > 0.0:
        delta = delta - blc
        if delta > bl:
            delta = delta - bl
        elif delta < -bl:
            delta = delta + bl
        else:
            delta = 0.0
    return k * delta


@_njit
def _rhs(x0, x1, x2, x3, x4, tau, c, pos, cog, g, qs):
    """Derivatives and (tau_frc, tau_s) at one state.

    ``c`` from :func:`_unpack`; ``pos, cog`` at this state from :func:`_angle_terms` and ``g`` from :func:`_level`;
    ``qs``: quasi-steady bristle.
    """
    tau_s = spring_torque(x0 - x2, c[I_K], c[I_BL], c[I_BLC])
    w = x1
    frc = c[I_DM] * w
    if c[I_CFC] > 0.0:
        r = w / c[I_CVR]
        frc += c[I_CFC] * (1.0 if r > 1.0 else (-1.0 if r < -1.0 else r))
    if c[I_HARM] > 0.0:
        frc += cog
        if c[I_PFC] > 0.0:
            r = w / c[I_PVR]
            frc += (1.0 if r > 1.0 else (-1.0 if r < -1.0 else r)) * (c[I_PFC] + pos)
    dz = 0.0
    if c[I_LUGRE] > 0.0:
        s0 = c[I_S0]
        if qs:
            frc += (g if w > 0.0 else (-g if w < 0.0 else 0.0)) + c[I_S2] * w
        else:
            dz = w - s0 * abs(w) * x4 / g
            frc += s0 * x4 + c[I_S1] * dz + c[I_S2] * w
    if c[I_MODE] == MODE_LOCKED:
        dq = 0.0
        dv = 0.0
    elif c[I_MODE] == MODE_INERTIAL:
        dq = x3
        dv = (tau_s - c[I_D] * x3 - c[I_KE] * x2) / c[I_J]
    else:
        dq = (tau_s - c[I_KE] * x2) / c[I_D]
        dv = 0.0
    dw = (tau - tau_s - frc) / c[I_JM]
    return x1, dw, dq, dv, dz, frc, tau_s


@_njit
def _bristle_rate(x0, x1, p, harm):
    """sigma0 |omega| / g(omega, theta): the sliding bristle's relaxation rate [1/s], and g [N m]."""
    c = _unpack(p)
    fsh = 0.0
    lvs = 0.0
    if c[I_HARM] > 0.0:
        pos, cog, fsh, lvs = _angle_terms(x0, c, harm)
    g = _level(x1, c, fsh, lvs)
    return c[I_S0] * abs(x1) / g, g


@_njit
def _substep(x0, x1, x2, x3, x4, tau, c, harm):
    """One RK4 step of length ``c[I_H]`` from the state ``x0..x4``; ``c`` from :func:`_unpack`.

    Returns the new state and ``(tau_frc, tau_s)`` at the start state. The start state's angle
    terms and Stribeck level serve both the quasi-steady switch and the first stage; the harmonic
    table is read only when the plant has angle harmonics.
    """
    h = c[I_H]
    harmonic = c[I_HARM] > 0.0
    pos = 0.0
    cog = 0.0
    fsh = 0.0
    lvs = 0.0
    if harmonic:
        pos, cog, fsh, lvs = _angle_terms(x0, c, harm)
    g = _level(x1, c, fsh, lvs)
    qs = False
    if c[I_LUGRE] > 0.0:
        qs = c[I_S0] * abs(x1) / g * h > c[I_QS]
    a0, a1, a2, a3, a4, f0, ts0 = _rhs(x0, x1, x2, x3, x4, tau, c, pos, cog, g, qs)
    hh = 0.5 * h
    y0 = x0 + hh * a0
    y1 = x1 + hh * a1
    if harmonic:
        pos, cog, fsh, lvs = _angle_terms(y0, c, harm)
    g = _level(y1, c, fsh, lvs)
    b0, b1, b2, b3, b4, f, ts = _rhs(y0, y1, x2 + hh * a2, x3 + hh * a3, x4 + hh * a4, tau, c, pos, cog, g, qs)
    y0 = x0 + hh * b0
    y1 = x1 + hh * b1
    if harmonic:
        pos, cog, fsh, lvs = _angle_terms(y0, c, harm)
    g = _level(y1, c, fsh, lvs)
    c0, c1, c2, c3, c4, f, ts = _rhs(y0, y1, x2 + hh * b2, x3 + hh * b3, x4 + hh * b4, tau, c, pos, cog, g, qs)
    y0 = x0 + h * c0
    y1 = x1 + h * c1
    if harmonic:
        pos, cog, fsh, lvs = _angle_terms(y0, c, harm)
    g = _level(y1, c, fsh, lvs)
    d0, d1, d2, d3, d4, f, ts = _rhs(y0, y1, x2 + h * c2, x3 + h * c3, x4 + h * c4, tau, c, pos, cog, g, qs)
    h6 = h / 6.0
    y0 = x0 + h6 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
    y1 = x1 + h6 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
    y2 = x2 + h6 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
    y3 = x3 + h6 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
    y4 = x4 + h6 * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
    if qs:
        # Slave z to its equilibrium at the new velocity (quasi-steady bristle).
        if harmonic:
            pos, cog, fsh, lvs = _angle_terms(y0, c, harm)
        g = _level(y1, c, fsh, lvs)
        y4 = (g if y1 > 0.0 else (-g if y1 < 0.0 else 0.0)) / c[I_S0]
    return y0, y1, y2, y3, y4, f0, ts0


@_njit
def rk4_substep(x, tau, p, harm, out):
    """One RK4 step of length p[I_H] in place; out[0:2] = (tau_frc, tau_s) at the start state."""
    y0, y1, y2, y3, y4, f, ts = _substep(x[0], x[1], x[2], x[3], x[4], tau, _unpack(p), harm)
    x[0] = y0
    x[1] = y1
    x[2] = y2
    x[3] = y3
    x[4] = y4
    out[0] = f
    out[1] = ts


@_njit
def advance_period(x, k, nsub, dsub, hist, p, harm, noise_k, out, row):
    """One control period of the true plant: ``nsub`` RK4 substeps under the held, delayed command.

    The one place the plant is stepped: the simulator's closed-loop kernel, the open-loop
    integrator and :class:`PlantStepper` (the board emulator's testbed) all call it. The state
    and parameters are read into scalars once per period (:func:`_unpack`) and the substeps run
    on scalars (:func:`_substep`).

    Parameters
    ----------
    x : ndarray, shape (5,)
        State ``[theta, omega, q, v, z]``, advanced in place.
    k : int
        Period index [-].
    nsub, dsub : int
        Substeps per period and the command delay in substeps [-].
    hist : ndarray, shape (H,)
        Ring buffer of held commands: ``hist[i % H]`` is the command of period ``i`` [N m];
        ``H`` a power of two ``>= dsub // nsub + 2`` (:func:`history_length`) and period
        ``k``'s command already written. Periods before 0 hold 0.
    p, harm : ndarray
        Plant parameters and harmonics (:class:`PlantModel`).
    noise_k : float
        Process torque noise of this period [N m].
    out : ndarray, shape (2,)
        Set to ``(tau_frc, tau_s)`` at the start of the last substep.
    row : ndarray, shape (8,)
        Filled with the state at ``t_k``, ``tau_frc`` and ``tau_s`` of the first substep and
        the applied torque at ``t_k``.
    """
    c = _unpack(p)
    gain = c[I_GAIN]
    mask = hist.shape[0] - 1          # a power of two (history_length)
    x0 = x[0]
    x1 = x[1]
    x2 = x[2]
    x3 = x[3]
    x4 = x[4]
    f = 0.0
    ts = 0.0
    for j in range(nsub):
        idx = k * nsub + j - dsub
        cmd = hist[(idx // nsub) & mask] if idx >= 0 else 0.0
        tau = gain * cmd + noise_k
        if j == 0:
            row[0] = x0
            row[1] = x1
            row[2] = x2
            row[3] = x3
            row[4] = x4
            row[7] = tau
        x0, x1, x2, x3, x4, f, ts = _substep(x0, x1, x2, x3, x4, tau, c, harm)
        if j == 0:
            row[5] = f
            row[6] = ts
    x[0] = x0
    x[1] = x1
    x[2] = x2
    x[3] = x3
    x[4] = x4
    out[0] = f
    out[1] = ts


def history_length(nsub: int, dsub: int) -> int:
    """Ring-buffer length for :func:`advance_period` with a delay of ``dsub`` substeps [-].

    A power of two (at least ``dsub // nsub + 2``), so the ring index is a bit mask.
    """
    need = int(dsub) // max(int(nsub), 1) + 2
    return 1 << (need - 1).bit_length()


@_njit
def _integrate(x, tau_cmd, noise, p, harm, nsub, dsub, hist, log):
    """Open-loop integration: tau_cmd held per period; log[n] = state and (frc, tau_s, tau_app) at t_n."""
    out = np.zeros(2)
    H = hist.shape[0]
    for n in range(tau_cmd.shape[0]):
        hist[n % H] = tau_cmd[n]
        advance_period(x, n, nsub, dsub, hist, p, harm, noise[n], out, log[n])


def integrate_open_loop(plant: PlantModel, tau_cmd: np.ndarray, *, substeps: int,
                        noise: np.ndarray | None = None, x0: Sequence[float] | None = None) -> np.ndarray:
    """Integrate the true plant under a zero-order-held torque command (no sensors).

    Parameters
    ----------
    plant : PlantModel
        From :func:`build_plant` (its ``h`` must be period / substeps).
    tau_cmd : ndarray, shape (n,)
        Command per control period [N m], applied over [t_n, t_n+1).
    substeps : int
        RK4 steps per period [-].
    noise : ndarray, shape (n,), optional
        Process torque noise per period [N m].
    x0 : sequence of 5 float, optional
        Initial state [theta, omega, q, v, z]; zeros by default.

    Returns
    -------
    ndarray, shape (n, 8)
        Per sample at t_n: theta [rad], omega [rad/s], q [rad], v [rad/s],
        z [rad], tau_frc [N m], tau_s (true) [N m], applied torque [N m].
    """
    tau_cmd = np.ascontiguousarray(tau_cmd, dtype=float)
    noise = np.zeros_like(tau_cmd) if noise is None else np.ascontiguousarray(noise, dtype=float)
    x = np.zeros(5) if x0 is None else np.array(x0, dtype=float)
    log = np.empty((tau_cmd.shape[0], 8))
    hist = np.zeros(history_length(substeps, plant.delay_substeps))
    _integrate(x, tau_cmd, noise, plant.params, plant.harmonics, int(substeps), int(plant.delay_substeps), hist, log)
    return log


class PlantStepper:
    """The virtual testbed advanced one control period at a time, with its sensors.

    What a board sees: :meth:`measure` gives the encoder readings at ``t_k`` (quantised like
    the simulator's encoders) and the spring torque the logger derives from them;
    :meth:`advance` holds a command over ``[t_k, t_k+1)``. Every effect of
    :func:`build_plant` acts, the delay included, through :func:`advance_period`, the same
    step the simulator uses: driven by the commands a simulation recorded, it reproduces that
    simulation exactly.

    Parameters
    ----------
    plant : PlantModel
        From :func:`build_plant`.
    substeps : int
        RK4 substeps per period [-] (the ``substeps`` the plant was built with).
    k_nominal : float
        Spring stiffness the logger uses for ``tau_s = k (theta - q)`` [N m/rad].
    encoder_step : float
        Encoder resolution [rad]; 0 for exact positions.
    noise : ndarray, shape (n,), optional
        Process torque noise per period [N m]; zeros beyond its end.
    """

    def __init__(self, plant: PlantModel, *, substeps: int, k_nominal: float, encoder_step: float,
                 noise: np.ndarray | None = None) -> None:
        self.plant = plant
        self.substeps = int(substeps)
        self.k_nominal = float(k_nominal)
        self.encoder_step = float(encoder_step)
        self.noise = np.zeros(0) if noise is None else np.asarray(noise, dtype=float)
        self.x = np.zeros(5)
        self.period = 0
        self._hist = np.zeros(history_length(self.substeps, plant.delay_substeps))
        self._out = np.zeros(2)
        self.row = np.zeros(8)

    def measure(self) -> tuple[float, float, float]:
        """Encoder readings at the current instant: ``theta`` [rad], ``q`` [rad], ``tau_s`` [N m]."""
        th, qq = float(self.x[0]), float(self.x[2])
        if self.encoder_step > 0.0:
            th = math.floor(th / self.encoder_step + 0.5) * self.encoder_step
            qq = math.floor(qq / self.encoder_step + 0.5) * self.encoder_step
        if self.plant.locked:
            qq = 0.0
        return th, qq, self.k_nominal * (th - qq)

    def warm_up(self) -> PlantStepper:
        """Compile the period step now (numba compiles on the first call, ~0.7 s), on scratch state.

        A lock-step session calls this before it starts the board, whose link timeout would
        otherwise see the first period's compile as a silent host. Returns ``self``.
        """
        advance_period(self.x.copy(), 0, self.substeps, int(self.plant.delay_substeps), self._hist.copy(),
                       self.plant.params, self.plant.harmonics, 0.0, self._out.copy(), self.row.copy())
        return self

    def advance(self, tau_m: float) -> None:
        """Hold the command ``tau_m`` [N m] over one period and step the plant."""
        k = self.period
        self._hist[k % self._hist.size] = float(tau_m)
        noise_k = float(self.noise[k]) if k < self.noise.size else 0.0
        advance_period(self.x, k, self.substeps, int(self.plant.delay_substeps), self._hist, self.plant.params,
                       self.plant.harmonics, noise_k, self._out, self.row)
        self.period = k + 1
