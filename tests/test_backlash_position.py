"""Where the couplings' play starts (Backlash.position) and its run-to-run variability (issue 17c).

Physics: a motor that starts inside the play of its coupling turns freely until it reaches the
flank; with a constant torque tau from rest on the bare motor inertia (no friction) it reaches
the flank (1 - position) width / 2 away at t = sqrt(2 J_m gap / tau), and only then does the
spring carry torque.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.effects import Backlash, Stiction, effect_from_mapping
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.params import Design
from forecast_design.simulation import Constant, simulate
from forecast_design.simulation.scenario import Variability, scenario_from_mapping

EXACT = {"encoder_counts": None, "process_noise_std": 0.0, "include_nominal_viscous": False}
RATE = 2000.0


def _push(position: float, width: float, tau: float, duration_s: float = 0.2):
    return simulate(Design.nominal("locked"), reference=Constant(value=tau), duration_s=duration_s, closed_loop=False,
                    effects=[Backlash(width_rad=width, position=position)], rate_hz=RATE, **EXACT)


@pytest.mark.parametrize("position", [-1.0, -0.4, 0.0, 0.5])
def test_engagement_delay_is_the_free_travel_time_to_the_flank(position):
    width, tau, J_m = 4e-3, 0.5, 0.133
    gap = (1.0 - position) * width / 2.0
    r = _push(position, width, tau)
    t_engage = math.sqrt(2.0 * J_m * gap / tau)          # theta = tau t^2 / (2 J_m) = gap
    first = r.t[np.argmax(r.truth.tau_s > 0.0)]
    assert np.all(r.truth.tau_s[r.t < t_engage - 1 / RATE] == 0.0)
    assert first == pytest.approx(t_engage, abs=1.01 / RATE)
    # before the flank the motor is a free inertia: theta = tau t^2 / (2 J_m)
    free = r.t < t_engage
    np.testing.assert_allclose(r.truth.theta[free], tau * r.t[free] ** 2 / (2.0 * J_m), rtol=1e-9, atol=1e-15)


def test_a_coupling_against_its_flank_transmits_at_once():
    r = _push(1.0, 4e-3, 0.5, duration_s=0.01)
    assert r.truth.tau_s[1] > 0.0
    np.testing.assert_allclose(r.truth.tau_s, 58.0 * (r.truth.theta - r.truth.q), rtol=1e-12)


@settings(max_examples=25, deadline=None)
@given(position=st.floats(-1.0, 1.0), width=st.floats(1e-4, 1e-2))
def test_true_spring_torque_is_the_shifted_dead_band(position, width):
    r = simulate(Design.nominal("locked"), reference=Constant(value=0.3), duration_s=0.05, closed_loop=False,
                 effects=[Backlash(width_rad=width, position=position)], rate_hz=RATE,
                 **{**EXACT, "include_nominal_viscous": True})
    d = r.truth.theta - r.truth.q + position * width / 2.0       # measured from the band's centre
    dz = d - np.clip(d, -width / 2.0, width / 2.0)
    np.testing.assert_allclose(r.truth.tau_s, 58.0 * dz, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(r.tau_s, 58.0 * (r.theta - r.q), atol=1e-15)   # encoders read k (theta - q)


def test_backlash_position_is_validated_and_round_trips():
    assert effect_from_mapping(Backlash(width_rad=2e-3, position=-0.25).to_mapping()) == \
        Backlash(width_rad=2e-3, position=-0.25)
    with pytest.raises(ParameterError, match="backlash position must be in"):
        Backlash(position=1.5)
    with pytest.raises(ExperimentFormatError, match="position"):
        effect_from_mapping({"effect": "backlash", "position": "left"})


def test_variability_draws_a_start_inside_the_play_per_repetition():
    v = Variability(repetitions=8, seed=3, backlash_position="random")
    p = v.backlash_positions()
    assert p.shape == (8,) and np.all((p >= -1.0) & (p <= 1.0)) and len(set(p)) == 8
    again = Variability(repetitions=8, seed=3, backlash_position="random").backlash_positions()
    np.testing.assert_array_equal(p, again)
    effects = (Stiction(), Backlash(width_rad=2e-3))
    for i in range(8):
        drawn = v.effects_of(effects, i)
        assert drawn[0] == effects[0] and drawn[1] == Backlash(width_rad=2e-3, position=float(p[i]))
    assert Variability(repetitions=8, seed=3).effects_of(effects, 5) == effects          # "fixed": unchanged
    with pytest.raises(ParameterError, match="backlash_position"):
        Variability(backlash_position="sometimes")


def test_scenario_variability_table_takes_backlash_position():
    doc = {"format": "forecast-scenario/1", "sampling": {"rate_hz": RATE}, "environment": "locked",
           "testbed": {"J_m": 0.133, "d_m": 0.3, "k": 58.0},
           "truth": {"effects": [{"effect": "backlash", "width_rad": 2e-3}]},
           "variability": {"repetitions": 3, "backlash_position": "random"},
           "reference": {"kind": "constant", "value": 0.3}, "simulation": {"duration_s": 0.05}}
    sc = scenario_from_mapping(doc, source="s.toml")
    runs = sc.runs()
    starts = [next(e for e in r.truth.effects if isinstance(e, Backlash)).position for r in runs]
    assert starts == [float(x) for x in sc.variability.backlash_positions()]
    assert sc.variability.to_mapping()["backlash_position"] == "random"
    bad = {**doc, "variability": {"repetitions": 3, "backlash_position": "sometimes"}}
    with pytest.raises(ExperimentFormatError, match=r"s.toml: \[variability\].*backlash_position"):
        scenario_from_mapping(bad, source="s.toml")
