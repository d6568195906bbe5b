"""The tuner's point-wise loop response and the polynomial loops are one loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forecast_design.loops import force_loop, sampled_force_loop
from forecast_design.loops.response import loop_response, q_argument, sensitivity
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.symbolic import compensator_q_tf


def _dq(comp: Compensator, W: np.ndarray) -> np.ndarray:
    q = compensator_q_tf(comp)                      # Q = num / den with num a constant
    return np.polyval(q.den, 1j * W) / q.num[-1]


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob", "motor-fob"])
@pytest.mark.parametrize("env", ["soft", "stiff", "locked"])
@pytest.mark.parametrize("break_at", ["controller", "plant-input"])
def test_parts_give_the_continuous_loops_sensitivity(kind, env, break_at):
    design, ctrl = Design.nominal(env), PD(P=5.0, D=0.1)
    believed = Design.nominal("fig7") if env != "locked" else design
    comp = Compensator(kind=kind, w_q_hz=7.0)
    w = np.logspace(-1, 3.5, 60)
    r = loop_response(design, believed, comp, ctrl, w)
    S = sensitivity(r, _dq(comp, r.W), break_at)
    L = force_loop(design, comp, controller=ctrl, believed=believed, break_at=break_at).L
    np.testing.assert_allclose(S, 1.0 / (1.0 + L(1j * w)), rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob"])
@pytest.mark.parametrize("delay", [0, 1, 2])
def test_parts_give_the_sampled_loops_sensitivity(kind, delay):
    design, ctrl, rate = Design.nominal("exp-soft"), PD(P=5.0, D=0.1), 2000.0
    comp = Compensator(kind=kind, w_q_hz=10.0)
    w = np.logspace(0, math.log10(0.9 * math.pi * rate), 50)
    r = loop_response(design, design, comp, ctrl, w, sampled=True, rate_hz=rate, delay_samples=delay)
    assert np.allclose(r.W, q_argument(w, sampled=True, rate_hz=rate))
    S = sensitivity(r, _dq(comp, r.W))
    # the loop's own w-plane form (its z-polynomials are too ill-conditioned near z = 1)
    L_w = sampled_force_loop(design, comp, controller=ctrl, rate_hz=rate, delay_samples=delay).L_w
    np.testing.assert_allclose(S, 1.0 / (1.0 + L_w(1j * r.W)), rtol=1e-6, atol=1e-9)
