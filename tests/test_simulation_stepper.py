"""The period-by-period stepper (the board emulator's testbed) is the simulator's plant, every effect included."""

from __future__ import annotations

import numpy as np
import pytest

from forecast_design import effects as fx
from forecast_design.params import Design
from forecast_design.simulation import references as refs
from forecast_design.simulation import simulate, plant_stepper

EFFECTS = [
    (),
    (fx.Coulomb(F_c=0.3),),
    (fx.Stiction(F_c=0.2, F_s=0.3),),
    (fx.PositionFriction(F_c=0.3, a=(0.05,), b=(0.02,)),),
    (fx.Cogging(a=(0.05, 0.01), b=(0.02, 0.0)),),
    (fx.Backlash(width_rad=3e-3),),
    (fx.Delay(delay_s=2.3e-3),),
    (fx.Delay(delay_s=0.4e-3),),
    (fx.TorqueGain(gain=0.8),),
    (fx.EnvironmentMismatch(J_scale=1.5, k_e_scale=0.7),),
    (fx.Delay(delay_s=1.7e-3), fx.Coulomb(F_c=0.2), fx.TorqueGain(gain=1.1)),
]


@pytest.mark.parametrize("effects", EFFECTS, ids=lambda e: "+".join(str(x.effect) for x in e) or "none")
@pytest.mark.parametrize("env", ["exp-soft", "locked"])
def test_stepper_driven_by_a_simulation_reproduces_it_exactly(effects, env):
    design = Design.nominal(env)
    ref = refs.Multisine(amplitudes=(0.8, 0.3), frequencies_hz=(0.7, 3.1), phases_rad=(0.0, 1.0))
    n = 600
    res = simulate(design, reference=ref, duration_s=n / 2000.0, effects=effects, seed=4, closed_loop=False,
                   initial_angle=0.3)
    bed = plant_stepper(design, effects, n=n, seed=4, initial_angle=0.3)
    got = np.empty((n, 3))
    for k in range(n):
        got[k] = bed.measure()
        bed.advance(res.tau_m[k])
    np.testing.assert_array_equal(got[:, 0], res.theta)
    np.testing.assert_array_equal(got[:, 1], res.q)
    np.testing.assert_array_equal(got[:, 2], res.tau_s)


def test_a_delay_shifts_the_stepped_response_by_whole_periods():
    design = Design.nominal("locked")
    n, d = 200, 5
    delayed = plant_stepper(design, (fx.Delay(delay_s=d / 2000.0),), n=n, process_noise_std=0.0,
                              encoder_counts=None)
    plain = plant_stepper(design, (), n=n, process_noise_std=0.0, encoder_counts=None)
    a, b = [], []
    for k in range(n):
        a.append(delayed.measure()[0])
        b.append(plain.measure()[0])
        cmd = 1.0 if k >= 10 else 0.0
        delayed.advance(cmd)
        plain.advance(cmd)
    np.testing.assert_allclose(np.array(a)[d:], np.array(b)[:-d], rtol=0, atol=1e-15)
