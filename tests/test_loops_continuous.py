"""The numeric force loop against independent python-control interconnections."""

import dataclasses
import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from forecast_design.errors import ParameterError
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design, Environment
from forecast_design.loops import force_loop
from forecast_design.symbolic import force_plant_tf, observer_filters

# --- independent reference built from the paper's printed formulas with python-control ------


def _tf(num, den):
    return control.tf(list(num), list(den))


def _ref_plant(design):
    """(P, P_theta) from control blocks: 1/(J_m s^2 + d_m s), k, 1/E (or q = 0 when locked)."""
    tb, env = design.testbed, design.environment
    motor = _tf([1.0], [tb.J_m, tb.d_m, 0.0])
    if env.locked:
        spring = _tf([tb.k], [1.0])
    else:
        spring = control.feedback(_tf([tb.k], [1.0]), _tf([1.0], [env.J, env.d, env.k_e]))
    P_theta = control.feedback(motor, spring)
    return P_theta * spring, P_theta


def _ref_q(comp):
    w = 2 * math.pi * comp.w_q_hz
    if comp.q_family == "butterworth":
        b, a = signal.butter(comp.q_order, w, analog=True)
        return _tf(b, a)
    return _tf([w**comp.q_order], np.poly([-w] * comp.q_order))


def _ref_nominal_inverse(kind, believed):
    """1 / P_n from eqs. (5), (6), (8) as printed."""
    J_m, k = believed.testbed.J_m, believed.testbed.k
    env = believed.environment
    if kind == "lo-dob" or (kind == "ea-fob" and env.locked):
        return _tf([J_m / k, 0.0, 1.0], [1.0])
    if kind == "ld-dob":
        J_l, d_l = env.J_l, env.d_l
        return _tf([J_m * J_l, J_m * d_l, k * (J_m + J_l), k * d_l], [k * J_l, k * d_l])
    E = np.array([env.J, env.d, env.k_e])
    # P_n^-1 = ((E/k + 1) J_m s^2 + E) / E
    num = np.polyadd(np.polymul(np.polyadd(E / k, [1.0]), [J_m, 0.0, 0.0]), E)
    return _tf(num, E)


def _ref_loop(true, comp, controller, believed=None, break_at="controller"):
    believed = believed or true
    P, P_theta = _ref_plant(true)
    C = _tf([controller.D, controller.P], [1.0])
    if comp is None or comp.kind in ("none", "sfm"):
        H = _tf([0.0], [1.0])
        G_m = G_s = G_t = H
    else:
        Q = _ref_q(comp)
        if comp.kind == "motor-fob":
            G_m, G_s, G_t = Q, -Q, -Q * _tf([believed.testbed.J_m, 0.0, 0.0], [1.0])
        else:
            G_m, G_s, G_t = Q, -Q * _ref_nominal_inverse(comp.kind, believed), _tf([0.0], [1.0])
    H = G_m + G_s * P + G_t * P_theta
    F = P * control.feedback(_tf([1.0], [1.0]), -H)
    if break_at == "controller":
        return C * F, F
    L_in = (C * P - G_s * P - G_t * P_theta) * control.feedback(_tf([1.0], [1.0]), -G_m)
    return L_in, F


CASES = [
    ("stiff", None),
    ("stiff", Compensator(kind="ea-fob", w_q_hz=10.0)),
    ("stiff", Compensator(kind="lo-dob", w_q_hz=5.0, q_family="binomial", q_order=3)),
    ("soft", Compensator(kind="ld-dob", w_q_hz=10.0)),
    ("fig7", Compensator(kind="motor-fob", w_q_hz=1.0)),
    ("locked", Compensator(kind="ea-fob", w_q_hz=5.0)),
    ("locked", Compensator(kind="motor-fob", w_q_hz=10.0, q_order=3)),
    ("exp-soft", Compensator(kind="ld-dob", w_q_hz=5.0, q_family="binomial")),
    ("link-only", Compensator(kind="ea-fob", w_q_hz=5.0)),
]
CONTROLLER = PD(P=5.0, D=0.1)


@pytest.mark.parametrize("break_at", ["controller", "plant-input"])
@pytest.mark.parametrize("env,comp", CASES)
def test_loop_matches_python_control_frequency_response(env, comp, break_at, rng):
    design = Design.nominal(env)
    loop = force_loop(design, comp, controller=CONTROLLER, break_at=break_at)
    L_ref, F_ref = _ref_loop(design, comp, CONTROLLER, break_at=break_at)
    for w in 10 ** rng.uniform(-1.0, 3.0, size=8):
        assert loop.L(1j * w) == pytest.approx(complex(L_ref(1j * w)), rel=1e-8)
        assert loop.F_DOB(1j * w) == pytest.approx(complex(F_ref(1j * w)), rel=1e-8)
    assert loop.L.relative_degree >= 0


@pytest.mark.parametrize("env,comp", CASES)
def test_closed_loop_poles_are_python_control_poles(env, comp):
    design = Design.nominal(env)
    loop = force_loop(design, comp, controller=CONTROLLER)
    L_ref, _ = _ref_loop(design, comp, CONTROLLER)
    ref_poles = control.feedback(L_ref, 1).poles()
    if not design.environment.locked and design.environment.k_e == 0.0:
        # Free output: the reference keeps the rigid-body position mode(s) at s = 0,
        # which force_loop divides out exactly (no force signal sees them).
        assert np.sum(np.abs(ref_poles) < 1e-9) >= 1
        ref_poles = ref_poles[np.abs(ref_poles) >= 1e-9]
    # The reference is a non-minimal realisation: ours must be among its poles.
    for p in loop.closed_loop_poles:
        assert np.min(np.abs(ref_poles - p)) <= 1e-5 * max(1.0, abs(p))
    assert loop.stable == bool(np.all(ref_poles.real < 0))
    # Same characteristic polynomial whichever break point.
    other = force_loop(design, comp, controller=CONTROLLER, break_at="plant-input")
    np.testing.assert_allclose(other.characteristic_polynomial, loop.characteristic_polynomial, rtol=1e-12)


def test_no_observer_is_plant_alone():
    design = Design.nominal("stiff")
    P = force_plant_tf(design)
    for comp in (None, Compensator(kind="none"), Compensator(kind="sfm")):
        loop = force_loop(design, comp)
        for w in (0.5, 20.0, 300.0):
            assert loop.F_DOB(1j * w) == pytest.approx(P(1j * w), rel=1e-12)
            assert loop.L(1j * w) == pytest.approx((5.0 + 0.1j * w) * P(1j * w), rel=1e-12)
        assert loop.stable


def test_fdob_equals_eq4():
    design = Design.nominal("stiff")
    comp = Compensator(kind="lo-dob", w_q_hz=5.0)
    loop = force_loop(design, comp)
    P = force_plant_tf(design)
    Q = _ref_q(comp)
    Pn_inv = _ref_nominal_inverse("lo-dob", design)
    for w in (0.3, 10.0, 90.0):
        x = 1j * w
        expected = P(x) / (1 + complex(Q(x)) * (complex(Pn_inv(x)) * P(x) - 1))
        assert loop.F_DOB(x) == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("env", ["soft", "stiff", "fig7", "exp-soft", "link-only", "locked"])
def test_motor_fob_equals_ea_fob_when_environment_exact(env):
    design = Design.nominal(env)
    ea = force_loop(design, Compensator(kind="ea-fob", w_q_hz=10.0))
    mo = force_loop(design, Compensator(kind="motor-fob", w_q_hz=10.0))
    for w in np.logspace(-1, 3, 15):
        assert ea.L(1j * w) == pytest.approx(mo.L(1j * w), rel=1e-8)
    # EA's extra closed-loop modes are exactly the roots of its observer's P_n numerator, E(s).
    ea_only = list(ea.closed_loop_poles)
    for p in mo.closed_loop_poles:
        i = int(np.argmin(np.abs(np.array(ea_only) - p)))
        assert abs(ea_only[i] - p) <= 1e-6 * max(1.0, abs(p))
        ea_only.pop(i)
    if not design.environment.locked:
        env_ = design.environment
        E_roots = np.roots(np.trim_zeros([env_.J, env_.d, env_.k_e], "b"))
        np.testing.assert_allclose(np.sort_complex(np.array(ea_only)), np.sort_complex(E_roots), rtol=1e-6,
                                   atol=1e-9)
    assert ea.stable == mo.stable


def test_wrong_environment_changes_ea_fob_not_motor_fob():
    true = Design.nominal("stiff")
    believed = true.with_environment("soft")
    for kind, should_change in (("ea-fob", True), ("motor-fob", False)):
        comp = Compensator(kind=kind, w_q_hz=10.0)
        exact = force_loop(true, comp)
        wrong = force_loop(true, comp, believed=believed)
        diffs = [abs(wrong.L(1j * w) - exact.L(1j * w)) / abs(exact.L(1j * w))
                 for w in np.logspace(-1, 3, 20)]
        assert (max(diffs) > 1e-2) == should_change, (kind, max(diffs))


def test_ld_dob_stiff_10hz_butterworth_unstable_binomial_stable():
    # Paper Section 5: LD-DOB with w_q = 10 Hz in the stiff environment is unstable.
    design = Design.nominal("stiff")
    butter = force_loop(design, Compensator(kind="ld-dob", w_q_hz=10.0))
    binom = force_loop(design, Compensator(kind="ld-dob", w_q_hz=10.0, q_family="binomial"))
    assert not butter.stable
    assert butter.max_real_pole > 0.0
    assert binom.stable
    # Independent check of both verdicts with python-control.
    for comp, verdict in ((Compensator(kind="ld-dob", w_q_hz=10.0), False),
                          (Compensator(kind="ld-dob", w_q_hz=10.0, q_family="binomial"), True)):
        L_ref, _ = _ref_loop(design, comp, CONTROLLER)
        assert bool(np.all(control.feedback(L_ref, 1).poles().real < 0)) == verdict
    # The other observers stay stable at 10 Hz there.
    for kind in ("ea-fob", "lo-dob", "motor-fob"):
        assert force_loop(design, Compensator(kind=kind, w_q_hz=10.0)).stable


@pytest.mark.parametrize("kind", ["ea-fob", "motor-fob"])
def test_estimate_is_q_times_viscous_friction(kind):
    # Open loop, exact model: the only unmodelled torque is the friction d_m theta',
    # so the estimate (our sign convention) is exactly +Q(s) d_m s theta.
    comp = Compensator(kind=kind, w_q_hz=10.0)
    design = Design.nominal("stiff")
    filt = observer_filters(comp, design)
    P, P_theta = _ref_plant(design)
    Q = _ref_q(comp)
    for w in (0.05, 0.5, 5.0, 200.0):
        x = 1j * w
        tau_m = 1.0
        tau_s, theta = complex(P(x)), complex(P_theta(x))
        est = filt.estimate(tau_m, tau_s, theta, x)
        friction = design.testbed.d_m * x * theta
        assert est == pytest.approx(complex(Q(x)) * friction, rel=1e-8)


def test_free_output_has_no_spurious_origin_pole():
    design = Design.nominal("link-only")
    for comp in (None, Compensator(kind="ea-fob"), Compensator(kind="motor-fob")):
        loop = force_loop(design, comp)
        assert np.min(np.abs(loop.closed_loop_poles)) > 1e-3
        assert loop.stable


def test_force_loop_rejects_bad_break_point():
    with pytest.raises(ParameterError):
        force_loop(Design.nominal("stiff"), break_at="somewhere")


_envs = st.builds(
    lambda J_e, d_e, k_e: Environment(J_e=J_e, d_e=d_e, k_e=k_e),
    J_e=st.floats(1e-3, 2.0), d_e=st.floats(0.0, 20.0), k_e=st.floats(0.0, 1000.0),
)


@settings(max_examples=30, deadline=None)
@given(env=_envs, w_q_hz=st.floats(0.5, 20.0), w=st.floats(0.05, 500.0))
def test_motor_fob_equals_ea_fob_property(env, w_q_hz, w):
    design = Design.nominal(env)
    ea = force_loop(design, Compensator(kind="ea-fob", w_q_hz=w_q_hz))
    mo = force_loop(design, Compensator(kind="motor-fob", w_q_hz=w_q_hz))
    assert ea.L(1j * w) == pytest.approx(mo.L(1j * w), rel=1e-7)


def test_forceloop_is_frozen():
    loop = force_loop(Design.nominal("stiff"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        loop.stable = False
    with pytest.raises(ValueError):
        loop.characteristic_polynomial[0] = 2.0
