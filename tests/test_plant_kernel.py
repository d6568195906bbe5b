"""The plant kernel's scalar parameter tuple (issue 16: no array reference counting per substep)."""

import numpy as np
import pytest

from forecast_design.effects import Backlash, Cogging, Coulomb, Delay, PositionFriction, Stiction, TorqueGain
from forecast_design.params import Design
from forecast_design.simulation import plant
from forecast_design.simulation.plant import N_PARAMS, PlantStepper, _unpack, build_plant, integrate_open_loop


@pytest.mark.parametrize("env", ["fig7", "locked", "exp-soft"])
def test_unpacked_parameters_are_the_packed_vector(env):
    # every field of the packed vector reaches the substeps, in its index
    effects = (Stiction(F_s_a=(0.05,), F_s_b=(0.01,)), Coulomb(F_c=0.2), Backlash(width_rad=0.01),
               TorqueGain(gain=1.1))
    p = build_plant(Design.nominal(env), effects).params
    c = _unpack(np.array(p))
    assert len(c) == N_PARAMS == p.size
    assert all(isinstance(v, float) for v in c)
    assert np.array_equal(np.array(c), p)


def test_substep_helper_equals_the_array_step_and_the_period_step():
    # rk4_substep (arrays in place) and advance_period (scalars across a period) are one step
    st = Stiction(F_s=0.6, F_s_a=(0.05, 0.02), F_s_b=(0.01, 0.0), v_s_a=(0.2,), v_s_b=(0.1,))
    pl = build_plant(Design.nominal("exp-soft"), (st, Cogging(a=(0.01,), b=(0.02,)),
                                                   PositionFriction(F_c=0.05, a=(0.01,), b=(0.0,)),
                                                   Delay(delay_s=0.0012)), initial_angle=0.4)
    cmd = 1.5 * np.sin(np.arange(600) / 2000.0 * 2 * np.pi * 1.3)
    log = integrate_open_loop(pl, cmd, substeps=10)
    x, out = np.zeros(5), np.zeros(2)
    hist = np.zeros(plant.history_length(10, pl.delay_substeps))
    stepper = PlantStepper(pl, substeps=10, k_nominal=58.0, encoder_step=0.0)
    for k in range(cmd.size):
        hist[k % hist.size] = cmd[k]
        for j in range(10):
            idx = k * 10 + j - pl.delay_substeps
            tau = pl.params[plant.I_GAIN] * (hist[(idx // 10) % hist.size] if idx >= 0 else 0.0)
            if j == 0:
                assert np.array_equal(x, log[k, :5])
            plant.rk4_substep(x, tau, np.array(pl.params), np.array(pl.harmonics), out)
            if j == 0:
                assert (out[0], out[1]) == (log[k, 5], log[k, 6])
        stepper.advance(cmd[k])
        assert np.array_equal(stepper.x, x)
