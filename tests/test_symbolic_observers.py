"""The observers' filters (forecast_design.symbolic.observers) against their defining identities."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.params import Compensator, Design
from forecast_design.symbolic import compensator_q_tf, nominal_plant_tf, observer_filters, required_q_order

S = 1j * np.logspace(-1, 3, 25)


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob"])
@pytest.mark.parametrize("env", ["soft", "stiff", "exp-soft", "locked"])
def test_dob_filters_are_q_and_minus_q_over_the_nominal_plant(kind, env):
    design = Design.nominal(env)
    comp = Compensator(kind=kind, w_q_hz=7.0)
    f = observer_filters(comp, design)
    Q, Pn = compensator_q_tf(comp)(S), nominal_plant_tf(kind, design)(S)
    np.testing.assert_allclose(f.from_tau_m(S), Q, rtol=1e-9)
    np.testing.assert_allclose(f.from_tau_s(S), -Q / Pn, rtol=1e-8)
    np.testing.assert_allclose(f.from_theta(S), 0.0, atol=0.0)
    # one shared denominator: the observer is one system with three inputs
    assert f.from_tau_m.den == f.from_tau_s.den == f.from_theta.den


@pytest.mark.parametrize("env", ["soft", "stiff", "locked"])
def test_motor_side_fob_filters_are_q_minus_q_and_minus_q_jm_s2(env):
    design = Design.nominal(env)
    comp = Compensator(kind="motor-fob", w_q_hz=12.0)
    f = observer_filters(comp, design)
    Q = compensator_q_tf(comp)(S)
    np.testing.assert_allclose(f.from_tau_m(S), Q, rtol=1e-9)
    np.testing.assert_allclose(f.from_tau_s(S), -Q, rtol=1e-9)
    np.testing.assert_allclose(f.from_theta(S), -Q * design.testbed.J_m * S ** 2, rtol=1e-8)


@settings(max_examples=40, deadline=None)
@given(w_q_hz=st.floats(0.1, 200.0), zeta=st.floats(0.2, 2.0))
def test_second_order_q_has_unit_dc_gain_and_the_given_damping(w_q_hz, zeta):
    q = compensator_q_tf(Compensator(kind="ea-fob", w_q_hz=w_q_hz, q_damping=zeta))
    w = 2 * math.pi * w_q_hz
    assert abs(q(0.0) - 1.0) < 1e-12
    np.testing.assert_allclose(np.array(q.den) / q.den[0], [1.0, 2 * zeta * w, w * w], rtol=1e-12)


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob", "motor-fob"])
def test_required_q_order_makes_every_filter_proper(kind):
    n = required_q_order(kind)
    f = observer_filters(Compensator(kind=kind, q_order=n), Design.nominal("stiff"))
    for tf in (f.from_tau_m, f.from_tau_s, f.from_theta):
        assert len(tf.num) <= len(tf.den)


def test_no_observer_has_zero_filters():
    for comp in (None, Compensator(kind="none"), Compensator(kind="sfm")):
        f = observer_filters(comp, Design.nominal("soft"))
        assert np.all(f.estimate(1.0, 2.0, 3.0, S) == 0.0)
