"""Sim-to-real gap diagnosis: closed-form pieces, recovery of withheld effects, the JSON contract."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy import stats

from forecast_design import effects as fx
from forecast_design.effects import Effect
from forecast_design.gap import GapOptions, diagnose, held_out_test, prepare_gap_data, write_report
from forecast_design.gap.locate import empirical_response
from forecast_design.gap.residuals import delayed_input, zoh_input
from forecast_design.params import Design, PDController
from forecast_design.simulation import references as refs
from forecast_design.simulation import simulate

VOCAB = {e.value for e in Effect}


def _log(effects=(), env="exp-soft", duration_s=6.0, closed=False, seed=3, errors=(0.0, 0.0, 0.0),
         initial_angle=0.4, offset=0.0):
    design = Design.nominal(env, controller=PDController() if closed else None)
    if closed:
        ref = refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1), phases_rad=(0.0, 1.0, 2.0))
    else:
        f = np.geomspace(0.2, 15.0, 12)
        ref = refs.Multisine(amplitudes=tuple(0.6 * np.ones(f.size)), frequencies_hz=tuple(f),
                             phases_rad=tuple(np.random.default_rng(seed).uniform(0, 2 * np.pi, f.size)), offset=offset)
    res = simulate(design, reference=ref, duration_s=duration_s, effects=effects, seed=seed, closed_loop=closed,
                   initial_angle=initial_angle)
    exp = res.to_experiment()
    tb = exp.design.testbed
    nominal = dataclasses.replace(tb, J_m=tb.J_m * (1 + errors[0]), d_m=tb.d_m * (1 + errors[1]),
                                  k=tb.k * (1 + errors[2]))
    return dataclasses.replace(exp, design=dataclasses.replace(exp.design, testbed=nominal)).replace_signals(tau_s=None)


def test_delayed_input_of_a_ramp_is_the_ramp_shifted():
    rate = 1000.0
    ramp = np.arange(200, dtype=float)
    out = delayed_input(ramp, 3.5e-3, rate)
    # ZOH centring (half a sample) plus 3.5 samples of delay, away from the start
    np.testing.assert_allclose(out[10:], ramp[10:] - 4.0, atol=1e-12)
    np.testing.assert_allclose(zoh_input(ramp)[1:], ramp[1:] - 0.5, atol=1e-12)


def test_held_out_test_matches_scipy_one_sided_t_test_on_log_ratios(rng):
    from forecast_design.gap.candidates import CandidateFit

    def fit(sse):
        return CandidateFit(effect=Effect.NONE, params={}, calibration={}, n_params=0, residual=np.zeros(1),
                            gap_fit=0.0, gap_held_out=0.0, block_sse=sse, prediction=np.zeros(1))

    a = rng.uniform(1.0, 2.0, 20)
    b = a - rng.normal(0.05, 0.1, 20)
    held = np.arange(1, 20, 2)
    expected = stats.ttest_1samp(np.log(a[held] / b[held]), 0.0, alternative="greater").pvalue
    assert held_out_test(fit(a), fit(b), held) == pytest.approx(expected, rel=1e-10)


def test_nominal_response_locked_is_second_order_lag():
    exp = _log(env="locked", duration_s=2.0)
    data = prepare_gap_data(exp)
    f, _, nom = empirical_response(data)
    tb = exp.design.testbed
    s = 2j * np.pi * f
    np.testing.assert_allclose(nom, tb.k / (tb.J_m * s ** 2 + tb.d_m * s + tb.k), rtol=1e-12)
    assert nom[0] == pytest.approx(1.0)


def test_nominal_response_matches_two_mass_system_solve():
    exp = _log(env="exp-soft", duration_s=2.0)
    f, _, nom = empirical_response(prepare_gap_data(exp))
    tb, env = exp.design.testbed, exp.design.environment
    for i in (5, 50, 200):
        s = 2j * np.pi * f[i]
        # [M + k, -k; -k, E + k] [theta; q] = [u; 0], tau_s = k (theta - q)
        A = np.array([[tb.J_m * s ** 2 + tb.d_m * s + tb.k, -tb.k], [-tb.k, env.J * s ** 2 + env.d * s + env.k_e + tb.k]])
        th, q = np.linalg.solve(A, np.array([1.0, 0.0]))
        assert nom[i] == pytest.approx(tb.k * (th - q), rel=1e-10)


def test_effect_free_log_with_parameter_errors_is_none():
    exp = _log((), errors=(0.03, -0.03, 0.02))
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.NONE
    assert d.reduction == 0.0
    # the calibration recovers the true J_m within the tolerance
    assert d.baseline.calibration["J_m"] == pytest.approx(0.133, rel=0.02)


@pytest.mark.parametrize("effect, key, true, rel", [
    (fx.Coulomb(F_c=0.3), "F_c", 0.3, 0.05),
    (fx.Delay(delay_s=3e-3), "delay_s", 3e-3, 0.1),
    (fx.TorqueGain(gain=0.75), "gain", 0.75, 0.02),
    (fx.Backlash(width_rad=6e-3), "width_rad", 6e-3, 0.2),
])
def test_withheld_effect_is_named_and_its_parameter_recovered(effect, key, true, rel):
    d = diagnose(_log((effect,), errors=(0.02, -0.02, 0.02)), joint=False)
    assert d.effect is effect.effect
    assert d.params[key] == pytest.approx(true, rel=rel)
    assert d.reduction >= 0.5


def test_environment_mismatch_recovers_true_environment():
    effect = fx.EnvironmentMismatch(J_scale=1.5, d_scale=0.6, k_e_scale=1.8)
    exp = _log((effect,), env="exp-soft")
    d = diagnose(exp, joint=False)
    true_env = effect.true_environment(exp.design.environment)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH
    assert d.params["k_e"] == pytest.approx(true_env.k_e, rel=0.05)
    assert d.params["d"] == pytest.approx(true_env.d, rel=0.05)


def test_cogging_harmonics_recovered_over_full_revolutions():
    effect = fx.Cogging(a=(0.15, 0.0), b=(0.0, 0.08))
    d = diagnose(_log((effect,), env="link-only", duration_s=6.0, offset=1.0), joint=False)
    assert d.location.full_revolution
    assert d.effect is Effect.COGGING
    # the encoder is homed at the start (absolute angle 0.4 rad there), so compare the
    # frame-independent amplitude of each harmonic
    amp = np.hypot(d.params["a"], d.params["b"])
    np.testing.assert_allclose(amp[:2], [0.15, 0.08], atol=0.015)
    assert np.all(amp[2:] < 0.015)


def test_stiction_is_told_from_coulomb():
    d = diagnose(_log((fx.Stiction(F_c=0.3, F_s=0.45),), closed=True, env="locked"), joint=False)
    assert d.effect is Effect.STICTION


def test_json_contract_exact_keys_and_types(tmp_path):
    exp = _log((fx.Coulomb(F_c=0.3),), duration_s=4.0)
    d = diagnose(exp)
    m = json.loads(json.dumps(d.to_mapping()))
    assert set(m) == {"verdict", "metric", "location", "ranking"}
    assert set(m["verdict"]) == {"effect", "gap_before", "gap_after", "reduction", "params"}
    assert set(m["location"]) == {"time_windows_s", "frequency_band_hz", "speed_band_rad_s", "summary"}
    assert m["verdict"]["effect"] in VOCAB and 0.0 <= m["verdict"]["reduction"] <= 1.0
    assert m["verdict"]["gap_after"] <= m["verdict"]["gap_before"]
    for r in m["ranking"]:
        assert set(r) == {"effect", "gap_after", "reduction", "params"}
        assert r["effect"] in VOCAB - {"none"} and 0.0 <= r["reduction"] <= 1.0
    # locked output: no environment equation, so environment_mismatch is not tried
    tried = {r["effect"] for r in m["ranking"]}
    assert tried == VOCAB - {"none"}
    for w in m["location"]["time_windows_s"]:
        assert w[0] < w[1]
    path = write_report(d, exp, tmp_path / "rep")
    text = path.read_text()
    assert "coulomb" in text and (tmp_path / "rep" / "before_after.png").stat().st_size > 1000
    assert json.loads((tmp_path / "rep" / "diagnosis.json").read_text()) == m


def test_locked_log_does_not_try_environment_mismatch_and_notes_no_revolution():
    d = diagnose(_log((), env="locked", duration_s=3.0), joint=False)
    assert "environment_mismatch" not in {str(r.effect) for r in d.ranking}
    assert "less than one revolution" in d.location.summary()


def test_too_short_log_raises_parameter_error():
    from forecast_design.errors import ParameterError

    with pytest.raises(ParameterError, match="too short"):
        diagnose(_log((), duration_s=0.25), options=GapOptions(n_blocks=20))
