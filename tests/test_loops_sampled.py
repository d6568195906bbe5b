"""Tests for the sampled-data force loop (forecast_design.loops.sampled) and loop_margins."""

from __future__ import annotations

import math

import control
import numpy as np
import pytest

from forecast_design.analysis import disk_margin
from forecast_design.errors import ParameterError
from forecast_design.lti import RationalTF


# ---------------------------------------------------------------------------------------------
# Sampled-data loop
# ---------------------------------------------------------------------------------------------

from forecast_design.analysis import loop_margins, sampled_force_loop  # noqa: E402
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design  # noqa: E402

SAMPLED_CASES = [("soft", None, None), ("stiff", None, None), ("soft", "lo-dob", 5.0),
                 ("stiff", "ea-fob", 10.0), ("soft", "ld-dob", 5.0), ("stiff", "motor-fob", 10.0),
                 ("link-only", "motor-fob", 5.0), ("locked", "lo-dob", 5.0)]


#: A PD with a 200 Hz derivative filter, Tustin-discretised (the filtered PD of the reproductions).
FILTERED_PD = PD(P=5.0, D=0.1, T_f=1.0 / (2.0 * math.pi * 200.0), discretization="tustin")


def _continuous_filtered_reference(env, kind, wq, break_at="controller", controller=FILTERED_PD):
    """The continuous loop with the same controller, C(s) F_DOB(s), from public pieces."""
    from forecast_design.loops import force_loop

    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    fl = force_loop(Design.nominal(env), comp)
    C = controller.feedback_tf()
    L = RationalTF(np.convolve(C.num, fl.F_DOB.num), np.convolve(C.den, fl.F_DOB.den))
    return disk_margin(L)


@pytest.mark.parametrize("controller", [FILTERED_PD, PD(P=5.0, D=0.1)], ids=["tustin-filtered", "euler-unfiltered"])
@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES)
def test_sampled_margin_tends_to_continuous_as_rate_grows(env, kind, wq, controller):
    """At 20 kHz (delay and ZOH lag 10x smaller) the margin is within 1 % (Tustin) or 2 % (backward
    Euler: its derivative lags by w T / 2) of the continuous loop with the same controller, and the
    error shrinks at least fivefold again at 200 kHz."""
    ref = _continuous_filtered_reference(env, kind, wq, controller=controller)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    errs = []
    for rate in (2e3, 2e4, 2e5):
        loop = sampled_force_loop(Design.nominal(env), comp, rate_hz=rate, controller=controller)
        assert loop.stable == ref.stable
        errs.append(abs(loop.disk_margin().alpha - ref.alpha) / ref.alpha)
    assert errs[1] < (0.01 if controller.discretization == "tustin" else 0.02)
    assert errs[2] < 0.2 * errs[1] + 1e-6


def test_sampled_ld_dob_stiff_10hz_is_unstable_like_continuous():
    loop = sampled_force_loop(Design.nominal("stiff"), Compensator(kind="ld-dob", w_q_hz=10.0))
    assert not loop.stable and loop.max_pole_magnitude > 1.0
    assert loop.disk_margin().alpha == 0.0


@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6])
def test_sampled_plant_is_zoh_step_invariant(env, kind, wq):
    """ZOH: the discrete step response equals the continuous one at the sampling instants."""
    from scipy import signal

    from forecast_design.symbolic import force_plant_tf

    design = Design.nominal(env)
    loop = sampled_force_loop(design, None, rate_hz=2000.0)
    n = 400
    u = np.ones(n)
    _, yd = signal.dlsim((np.asarray(loop.P.num), np.asarray(loop.P.den), loop.P.dt), u)
    P = force_plant_tf(design)
    t = np.arange(n) / 2000.0
    _, yc = signal.step((P.num, P.den), T=t)
    np.testing.assert_allclose(yd.ravel(), yc, atol=1e-6 * np.max(np.abs(yc)))


@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6])
def test_sampled_loop_frequency_response_is_closed_form_composition(env, kind, wq):
    """L(e^{jwT}) = C(z) P(z) z^-d / (1 - z^-1 G_m - z^-d (G_s P + G_theta P_theta)) from the
    discrete pieces (the C export's filters, python-control's ZOH plant), at every frequency."""
    design = Design.nominal(env)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    for d in (0, 1, 2):
        loop = sampled_force_loop(design, comp, delay_samples=d)
        T = 1.0 / loop.rate_hz
        w = np.logspace(-1, math.log10(0.99 * math.pi / T), 200)
        z = np.exp(1j * w * T)
        from forecast_design.symbolic import derive_motor_angle_plant, force_plant_tf
        P = control.c2d(force_plant_tf(design).to_control(), T, "zoh")
        Pt = control.c2d(derive_motor_angle_plant(design.environment.locked).at(design).to_control(), T, "zoh")
        Pz, Ptz = P(z), Pt(z)
        C = loop.C(z)
        Gm, Gs, Gt = (g(z) for g in loop.observer) if loop.observer else (0.0, 0.0, 0.0)
        expected = C * Pz * z**-d / (1.0 - Gm / z - z**-d * (Gs * Pz + Gt * Ptz))
        s_w = 1j * 2.0 / T * np.tan(w * T / 2.0)
        # python-control's z-polynomials lose ~1e-6 near z = 1 (the reason L_w exists)
        np.testing.assert_allclose(loop.L_w(s_w), expected, rtol=2e-5)


def test_sampled_pure_delay_costs_exactly_w_T_of_phase_margin_frequency():
    """One more sample of delay multiplies L by z^-1: |L| unchanged, phase -w T (closed form)."""
    design = Design.nominal("stiff")
    comp = Compensator(kind="lo-dob", w_q_hz=5.0)
    # with the observer, z^-d also enters Delta; without it the identity is exact
    l0 = sampled_force_loop(design, None, delay_samples=0)
    l1 = sampled_force_loop(design, None, delay_samples=1)
    T = 1.0 / l0.rate_hz
    w = np.logspace(0, 3.5, 50)
    s_w = 1j * 2.0 / T * np.tan(w * T / 2.0)
    np.testing.assert_allclose(l1.L_w(s_w), l0.L_w(s_w) * np.exp(-1j * w * T), rtol=1e-9)
    assert sampled_force_loop(design, comp).stable


@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6] + [("stiff", "ld-dob", 10.0)])
@pytest.mark.parametrize("d", [0, 1])
def test_sampled_stability_agrees_with_python_control_feedback(env, kind, wq, d):
    """Closed loop from python-control state-space interconnection of the discrete pieces."""
    design = Design.nominal(env)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    loop = sampled_force_loop(design, comp, delay_samples=d)
    T = 1.0 / loop.rate_hz
    from forecast_design.symbolic import derive_motor_angle_plant, force_plant_tf

    Pc = force_plant_tf(design).to_control()
    Ptc = derive_motor_angle_plant(design.environment.locked).at(design).to_control()
    if design.environment.k_e == 0.0 and not design.environment.locked:
        pytest.skip("free output: P_theta's rigid-body mode is cancelled only symbolically")
    from scipy import signal

    # one realisation per output (no shared states: the plant modes appear twice, both stable)
    Ps = control.c2d(control.ss(*signal.tf2ss(Pc.num[0][0], Pc.den[0][0])), T, "zoh")
    Pts = control.c2d(control.ss(*signal.tf2ss(Ptc.num[0][0], Ptc.den[0][0])), T, "zoh")
    split = control.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((2, 0)), np.ones((2, 1)), T)
    plant = control.series(split, control.append(Ps, Pts))
    delay = control.ss(control.tf([1.0], [1.0] + [0.0] * d, T)) if d else control.ss(control.tf([1.0], [1.0], T))
    z1 = control.ss(control.tf([1.0], [1.0, 0.0], T))
    C = control.ss(control.tf(list(loop.C.num), list(loop.C.den), T))
    if loop.observer:
        Gm, Gs, Gt = (control.ss(control.tf(list(g.num), list(g.den), T)) for g in loop.observer)
    else:
        Gm = Gs = Gt = control.ss(control.tf([0.0], [1.0], T))
    # c = u + Gm z^-1 c + Gs tau_s + Gt theta; tau_s, theta = plant(z^-d c); u = -C tau_s
    fwd = control.series(delay, plant)                       # c -> [tau_s; theta]
    obs = control.ss(control.append(Gs, Gt))
    obs_out = control.series(fwd, obs)                       # c -> [Gs tau_s; Gt theta]
    sum2 = control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.ones((1, 2)), T)
    H = control.parallel(control.series(obs_out, sum2), control.series(z1, Gm))   # c -> tau_hat
    inner = control.feedback(control.ss(control.tf([1.0], [1.0], T)), H, sign=1)  # u -> c
    pick = control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[1.0, 0.0]]), T)
    L = control.series(inner, fwd, pick, C)                  # u -> C tau_s
    closed = control.feedback(L, 1, sign=-1)
    poles = control.poles(closed)
    assert (np.max(np.abs(poles)) < 1.0) == loop.stable
    # every root of our characteristic polynomial is a pole of the interconnection
    for p in loop.closed_loop_poles:
        if abs(p) > 1e-6:
            assert np.min(np.abs(poles - p)) < 1e-5 * max(1.0, abs(p)), p


def test_loop_margins_matches_force_loop_and_sampled():
    design = Design.nominal("stiff")
    comp = Compensator(kind="lo-dob", w_q_hz=5.0)
    from forecast_design.symbolic import force_loop

    fl = force_loop(design, comp, break_at="plant-input")
    cont = loop_margins(design, comp, break_at="plant-input", sigma=0.3)
    assert cont == disk_margin(fl.L, 0.3, closed_loop_stable=fl.stable)
    samp = loop_margins(design, comp, sampled=True, break_at="plant-input")
    ref = sampled_force_loop(design, comp, break_at="plant-input")
    assert samp == ref.disk_margin()
    # both break points give the same closed loop
    other = sampled_force_loop(design, comp, break_at="controller")
    np.testing.assert_allclose(other.characteristic_polynomial, ref.characteristic_polynomial, rtol=1e-9)
    assert 0.0 < samp.alpha and 0.0 < samp.frequency_rad_s <= math.pi * 2000.0


def test_sampled_disk_margin_agrees_with_discrete_L_grid_at_moderate_order():
    """The z-form L (Tustin of L_w) on a fine grid up to Nyquist gives the same peak."""
    loop = sampled_force_loop(Design.nominal("stiff"), None, rate_hz=2000.0)
    T = 1.0 / loop.rate_hz
    w = np.linspace(1e-3, math.pi / T, 200001)
    z = np.exp(1j * w * T)
    Lz = loop.L(z)
    grid_alpha = 1.0 / np.max(np.abs(1.0 / (1.0 + Lz) - 0.5))
    alpha = loop.disk_margin().alpha
    assert alpha <= grid_alpha + 1e-9 and abs(alpha - grid_alpha) < 1e-5


def test_sampled_force_loop_rejects_bad_inputs():
    design = Design.nominal("soft")
    with pytest.raises(ParameterError, match="rate_hz"):
        sampled_force_loop(design, rate_hz=0.0)
    with pytest.raises(ParameterError, match="delay_samples"):
        sampled_force_loop(design, delay_samples=-1)
    with pytest.raises(ParameterError, match="break_at"):
        sampled_force_loop(design, break_at="sensor")


def test_the_zoh_plants_state_space_conversions_are_scipy_signals_bit_for_bit():
    """zoh_plant converts with its own tf2ss / ss2tf (importing scipy.signal costs a process ~2 s): on
    presets and random testbeds and environments (free outputs included) they give scipy.signal's
    matrices and polynomials exactly."""
    import dataclasses
    import warnings

    from scipy import linalg, signal

    from forecast_design import polynomials as poly
    from forecast_design.loops import sampled

    rng = np.random.default_rng(7)
    base = Design.nominal("soft")
    designs = [Design.nominal(n) for n in ("soft", "stiff", "fig7", "exp-soft", "locked", "link-only")]
    for _ in range(40):
        env = dataclasses.replace(base.environment, k_e=float(10 ** rng.uniform(-2, 4)) * (rng.random() > 0.2),
                                  J_e=float(10 ** rng.uniform(-4, 0)), d_e=float(10 ** rng.uniform(-4, 1)))
        tb = dataclasses.replace(base.testbed, k=float(10 ** rng.uniform(0.5, 3)), J_m=float(10 ** rng.uniform(-5, -2)))
        designs.append(dataclasses.replace(base, environment=env, testbed=tb))
    for design in designs:
        ns, nt, d = sampled._common_plant(design)
        n = len(d) - 1
        num = np.vstack([poly.pad(ns, n + 1), poly.pad(nt, n + 1)])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", signal.BadCoefficients)
            ours, theirs = sampled._tf2ss(num, d), signal.tf2ss(num, d)
        assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(ours, theirs))
        A, B, C, D = theirs
        e = linalg.expm(np.block([[A, np.eye(n)], [np.zeros((n, 2 * n))]]) / 2000.0)
        Ad, Bd = e[:n, :n], e[:n, n:] @ B
        for args in ((Ad, Bd, C, D), (A, B, C, np.zeros((2, 1)))):
            assert all(np.array_equal(a, b) for a, b in zip(sampled._ss2tf(*args), signal.ss2tf(*args)))
