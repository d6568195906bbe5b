"""Sim-to-real gap diagnosis: closed-form pieces, recovery of withheld effects, the JSON contract."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from forecast_design import effects as fx
from forecast_design.effects import Effect
from forecast_design.gap import GapOptions, diagnose, held_out_test, prepare_gap_data
from forecast_design.reporting import write_report
from forecast_design.gap.locate import empirical_response
from forecast_design.gap.residuals import delayed_input, zoh_input
from forecast_design.controllers import PD
from forecast_design.params import Design
from forecast_design.simulation import references as refs
from forecast_design.simulation import simulate

VOCAB = {e.value for e in Effect}


def _log(effects=(), env="exp-soft", duration_s=6.0, closed=False, seed=3, errors=(0.0, 0.0, 0.0),
         initial_angle=0.4, offset=0.0):
    design = Design.nominal(env, controller=PD() if closed else None)
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


@pytest.mark.parametrize("delay_samples", [0.0, 0.3, 1.0, 2.7])
def test_delayed_input_is_exact_for_a_pure_inertia_under_held_command(rng, delay_samples):
    # A pure inertia J theta'' = tau_zoh(t - D): integrate the held, delayed command exactly
    # (piecewise-constant acceleration between the breakpoints t_j + D) and check that the
    # one-period second difference equals delayed_input / J at every sample.
    rate, J, n = 1000.0, 0.2, 60
    T = 1.0 / rate
    tau = rng.normal(size=n)
    D = delay_samples * T
    # breakpoints of the delayed held command, and its value on each piece
    knots = np.concatenate([[-1.0], np.arange(n) * T + D])
    vals = np.concatenate([[tau[0]], tau])      # first value repeated before the start

    def theta(t):
        th, v, t0 = 0.0, 0.0, -1.0
        for i in range(knots.size):
            t1 = knots[i + 1] if i + 1 < knots.size else np.inf
            h = min(t, t1) - t0
            if h <= 0:
                break
            a = vals[i] / J
            th, v, t0 = th + v * h + 0.5 * a * h * h, v + a * h, t0 + h
        return th

    th = np.array([theta(k * T) for k in range(n)])
    d2 = (th[2:] - 2 * th[1:-1] + th[:-2]) / T ** 2
    np.testing.assert_allclose(J * d2[5:-5], delayed_input(tau, D, rate)[1:-1][5:-5], atol=1e-9)


def test_nominal_closed_loop_square_wave_leaves_no_residual_and_no_spurious_delay():
    # exact plant (no noise, no quantisation, exact parameters) under derivative kicks
    design = Design.nominal("exp-soft", controller=PD())
    res = simulate(design, reference=refs.Square(high=1.0, low=-1.0, period_s=1.3), duration_s=6.0, seed=5,
                   closed_loop=True, process_noise_std=0.0, encoder_counts=None)
    exp = res.to_experiment().replace_signals(tau_s=None)
    d = diagnose(exp, joint=False)
    tau_rms = float(np.std(exp.signals.tau_m))
    assert d.gap_before < 1e-4 * tau_rms
    assert d.effect is Effect.NONE
    delay = next(r for r in d.ranking if r.effect is Effect.DELAY)
    assert delay.reduction < 0.2
    assert d.baseline.calibration["J_m"] == pytest.approx(design.testbed.J_m, rel=1e-3)


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


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n_units=st.integers(3, 40), shift=st.floats(-0.5, 1.5))
def test_units_test_by_ranks_is_simes_over_scipys_signed_rank_and_t_tests(seed, n_units, shift):
    from forecast_design.gap.heldout import units_test

    rng = np.random.default_rng(seed)
    units = np.repeat(np.arange(n_units), 8)
    ref = rng.normal(0.0, 1.0, units.size) * rng.uniform(0.2, 3.0, units.size)
    cand = ref * np.exp(-shift * rng.lognormal(0.0, 1.5, units.size)) + rng.normal(0.0, 0.05, units.size)
    floor = np.full(units.size, 0.02)
    a = np.bincount(units, weights=ref ** 2)
    b = np.bincount(units, weights=cand ** 2)
    lr = np.log(np.maximum(a, 1e-6 * a.mean()) / np.maximum(b, 1e-6 * a.mean()))
    apart = np.bincount(units, weights=(ref - cand) ** 2) >= np.bincount(units, weights=floor)
    p_all = stats.wilcoxon(lr, alternative="greater").pvalue
    p_apart = stats.ttest_1samp(lr[apart], 0.0, alternative="greater").pvalue if apart.sum() >= 2 else 1.0
    lo, hi = sorted((p_all, p_apart))
    p, k = units_test(ref, cand, units, floor, rank=True)
    assert k == int(apart.sum())
    assert p == pytest.approx(min(1.0, 2.0 * lo, hi), rel=1e-9, abs=1e-300)


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


def _locked_sine_log(F_c, amplitude, frequency_hz, seed, duration_s=6.0, errors=(0.01, 0.02, 0.01)):
    """Closed-loop PD force control of a sine in a locked environment: slow motor reversals."""
    design = Design.nominal("locked", controller=PD())
    res = simulate(design, reference=refs.Sine(amplitude=amplitude, frequency_hz=frequency_hz),
                   duration_s=duration_s, effects=(fx.Coulomb(F_c=F_c),), seed=seed, closed_loop=True,
                   initial_angle=1.0)
    exp = res.to_experiment()
    tb = exp.design.testbed
    nominal = dataclasses.replace(tb, J_m=tb.J_m * (1 + errors[0]), d_m=tb.d_m * (1 + errors[1]),
                                  k=tb.k * (1 + errors[2]))
    return dataclasses.replace(exp, design=dataclasses.replace(exp.design, testbed=nominal)).replace_signals(tau_s=None)


@settings(max_examples=40, deadline=None)
@given(rate_hz=st.sampled_from([500.0, 1000.0, 2000.0]), R=st.sampled_from([5, 10, 20]),
       levels=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)), jump=st.integers(-300, 300),
       cutoff=st.floats(0.02, 0.2))
def test_held_level_lift_bounds_a_filtered_jump_through_scipys_decimate(rate_hz, R, levels, jump, cutoff):
    # a friction torque that jumps once from a to b (|a|, |b| <= 1) and is seen through the gap's filters (the
    # zero-phase Butterworth, then scipy's own decimate: Chebyshev I, zero-phase) stays within
    # max(|a|, |b|) + |b - a| / 2 o[d], d raw samples from the jump
    from scipy import signal as sps

    from forecast_design.friction.derivatives import default_filter_settings
    from forecast_design.gap.motion import _step_overshoot
    from forecast_design.gap.residuals import lowpass

    settings = default_filter_settings(rate_hz, position_cutoff_hz=cutoff * rate_hz, decimation_factor=R)
    n = 40 * R + 1200
    j = n // 2 + jump
    a, b = levels
    x = np.where(np.arange(n) < j, a, b)
    y = sps.decimate(lowpass(x, settings), R, ftype="iir", zero_phase=True)
    i = np.arange(y.size) * R
    d = np.abs(i - j + 0.5).astype(int)
    o = _step_overshoot(settings)
    bound = max(abs(a), abs(b)) + abs(b - a) / 2.0 * o[np.minimum(d, o.size - 1)]
    inner = slice(y.size // 5, 4 * y.size // 5)           # away from the signal's ends (filtfilt's padding)
    assert np.all(np.abs(y[inner]) <= bound[inner] + 1e-9)
    assert o[0] > 0.05 and np.all(np.diff(o) <= 0.0)        # it rings, and the bound only falls with distance


def test_coulomb_feature_is_full_through_slow_reversals():
    # Regression: the sign feature was zero wherever |theta'| < stick_velocity (2 mrad/s), although a
    # motor passing through a reversal that slowly still moves and feels the full F_c. The hole
    # (2 F_c times the time spent in the band, at every reversal) was left in the residual: coulomb
    # kept 15-25 % of the gap of these logs, and a Stribeck bump next to the band filled it in.
    exp = _locked_sine_log(F_c=0.2, amplitude=0.5, frequency_hz=2.5, seed=4)
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.COULOMB
    assert d.fits["coulomb"].params["F_c"] == pytest.approx(0.2, rel=0.02)
    assert d.fits["coulomb"].gap_held_out < 0.05 * d.gap_before


def test_coulomb_log_with_closed_loop_sine_reversals_is_not_called_stiction():
    # the withheld-effect benchmark's log that was named stiction (F_s ~ 3 F_c, v_s just above the
    # old 2 mrad/s dead band of the sign feature)
    from forecast_design.gap.bench import make_log

    spec, exp, _ = make_log(Effect.COULOMB, 4, 0)
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.COULOMB
    assert d.params["F_c"] == pytest.approx(spec.effects[0].F_c, rel=0.01)
    assert d.fits["coulomb"].gap_held_out < 0.05 * d.gap_before


def test_assessment_cache_never_serves_the_assessment_of_another_fit():
    # fits are cached by id(); a dropped pair fit's id can be reused by the next one, which must
    # not inherit its assessment
    from forecast_design.gap.identifiability import EffectAssessment, assess_fit

    d = diagnose(_log((fx.Coulomb(F_c=0.3),)), joint=False)
    fit = d.fits["coulomb"]
    stale = EffectAssessment(identified=False, status={}, reasons=("stale",))
    d.data.cache[("assessment", id(fit))] = (object(), stale)
    fresh = assess_fit(d.data, fit)
    assert fresh is not stale and fresh.identified
    assert assess_fit(d.data, fit) is fresh


def test_json_contract_exact_keys_and_types(tmp_path):
    exp = _log((fx.Coulomb(F_c=0.3),), duration_s=4.0)
    d = diagnose(exp)
    m = json.loads(json.dumps(d.to_mapping()))
    assert set(m) == {"verdict", "metric", "location", "ranking", "caveats", "isolability", "tau_s", "design"}
    # what the gap is measured against: the log's own nominal model and extent
    assert m["design"]["testbed"] == exp.design.testbed.to_mapping()
    assert m["design"]["environment"] == exp.design.environment.to_mapping()
    assert m["design"]["rate_hz"] == exp.rate_hz and m["design"]["duration_s"] == pytest.approx(4.0)
    assert set(m["verdict"]) == {"effect", "grade", "gap_before", "gap_after", "reduction", "params", "status",
                                 "secondary", "calibration", "std_method",
                                 "std_calibration_bound", "replicas", "reversals"}
    assert m["verdict"]["grade"] in ("clear", "weak", "probable", "none")
    assert set(m["location"]) == {"time_windows_s", "frequency_band_hz", "speed_band_rad_s", "summary"}
    assert m["verdict"]["effect"] in VOCAB and 0.0 <= m["verdict"]["reduction"] <= 1.0
    assert m["verdict"]["gap_after"] <= m["verdict"]["gap_before"]
    assert m["verdict"]["secondary"] is None or m["verdict"]["secondary"]["effect"] in VOCAB
    # every parameter of the verdict carries a status; a verdict's parameters are plausible
    assert set(m["verdict"]["status"]) >= set(m["verdict"]["params"])
    assert all(v["status"] != "implausible" for v in m["verdict"]["status"].values())
    assert set(m["verdict"]["calibration"]) == {"J_m", "spring_scale", "d_m"}
    # a re-calibration has no interval: never `identified` (README's statuses ask for one)
    assert all(v["std"] is None and v["status"] in ("uncertain", "at_bound") for v in m["verdict"]["calibration"].values())
    assert m["tau_s"]["source"] == "absent"
    words = m["isolability"]["words"]
    assert words[-1] == "calibration" and len(m["isolability"]["separation"]) == len(words)
    for r in m["ranking"]:
        assert {"effect", "gap_after", "reduction", "params", "p_value", "counts", "weak", "identified",
                "not_identified", "status", "reasons", "equations", "reduction_in_equations", "explained_rms_N_m",
                "below_accuracy", "level", "n_units", "short_of_level"} == set(r)
        # a candidate short of its level is one whose test did not reach it
        assert not r["short_of_level"] or (not r["counts"] and r["p_value"] >= r["level"])
        assert r["effect"] in VOCAB - {"none"} and 0.0 <= r["reduction"] <= 1.0
        assert r["counts"] <= r["identified"]
        assert 0.0 < r["level"] <= 0.01 and r["n_units"] >= 1 and (not r["counts"] or r["p_value"] < r["level"])
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


def test_replay_windows_matches_scipy_dlsim(rng):
    from scipy import signal as sps

    from forecast_design.gap.replay import replay_windows
    from forecast_design.params import environment_preset

    design = Design.nominal("exp-soft")
    tb, env = design.testbed, environment_preset("exp-soft")
    rate, n = 1000.0, 400
    u = np.column_stack([rng.normal(size=n), np.zeros(n)])
    A = np.array([[0, 1, 0, 0], [-tb.k / tb.J_m, -tb.d_m / tb.J_m, tb.k / tb.J_m, 0], [0, 0, 0, 1],
                  [tb.k / env.J, 0, -(tb.k + env.k_e) / env.J, -env.d / env.J]])
    B = np.array([[0], [1 / tb.J_m], [0], [0]])
    sysd = sps.cont2discrete((A, B, np.eye(4), np.zeros((4, 1))), 1 / rate, method="zoh")
    x0 = np.array([0.1, -0.2, 0.05, 0.3])
    _, _, xs = sps.dlsim((sysd[0], sysd[1], sysd[2], sysd[3], 1 / rate), u[:, :1], x0=x0)
    X = replay_windows(tb, env, u, x0[None, :], np.array([0]), n, rate)
    np.testing.assert_allclose(X[0], xs, rtol=1e-9, atol=1e-12)


def test_replay_check_nominal_log_is_tight_and_effect_log_improves():
    exp = _log((), env="locked", duration_s=4.0)
    d = diagnose(exp, joint=False)
    assert d.replay is not None and d.replay.relative_before < 0.01
    d2 = diagnose(_log((fx.Coulomb(F_c=0.3),), env="locked", duration_s=4.0), joint=False)
    assert d2.effect is Effect.COULOMB
    assert d2.replay.relative_before > 0.1
    assert d2.replay.tau_s_error_after < 0.2 * d2.replay.tau_s_error_before
    assert "replay" in d2.to_mapping()["location"]["summary"]


def test_two_effects_are_both_named():
    d = diagnose(_log((fx.Coulomb(F_c=0.3), fx.TorqueGain(gain=0.7)), duration_s=6.0), joint=False)
    assert {d.effect, d.secondary.effect if d.secondary else Effect.NONE} == {Effect.COULOMB, Effect.TORQUE_GAIN}


def test_single_tone_none_verdict_warns_that_delay_is_not_excluded():
    design = Design.nominal("stiff", controller=PD())
    res = simulate(design, reference=refs.Sine(amplitude=1.0, frequency_hz=0.8), duration_s=6.0, seed=2,
                   closed_loop=True, effects=(fx.Delay(delay_s=4e-3),))
    d = diagnose(res.to_experiment().replace_signals(tau_s=None), joint=False)
    assert d.location.single_tone
    # a single tone cannot separate delay, torque gain and re-calibration: the answer must say so
    assert any("delay" in c and "torque_gain" in c for c in d.caveats)


def _save(exp, path):
    from forecast_design.experiment import save_experiment

    save_experiment(exp, path)
    return path


@pytest.mark.parametrize("case", ["no-motion", "no-command", "too-short"])
def test_bad_logs_give_one_line_forecast_error(tmp_path, capsys, case):
    from forecast_design.cli import main
    from forecast_design.errors import ForecastError
    from forecast_design.experiment import experiment_from_arrays

    design = Design.nominal("locked")
    n = 4000 if case != "too-short" else 300
    t = np.arange(n) / 2000.0
    tau_m = np.zeros(n) if case == "no-command" else 1e-6 * np.sin(2 * np.pi * 3 * t)
    if case == "too-short":
        exp = _log((), env="locked", duration_s=0.15)
    else:
        exp = experiment_from_arrays(design, 2000.0, t, tau_m, np.zeros(n), np.zeros(n))
    with pytest.raises(ForecastError):
        diagnose(exp)
    path = _save(exp, tmp_path / "bad.toml")
    code = main(["diagnose", str(path)])
    out, err = capsys.readouterr()
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("forecast-design: error:")
    assert "Traceback" not in err


def test_nan_in_log_is_rejected_with_one_line(tmp_path, capsys):
    from forecast_design.cli import main

    exp = _log((), env="locked", duration_s=1.0)
    path = _save(exp, tmp_path / "ok.toml")
    csv = next(p for p in tmp_path.iterdir() if p.suffix == ".csv")
    lines = csv.read_text().splitlines()
    cells = lines[-50].split(",")
    cells[1] = "nan"
    lines[-50] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    code = main(["diagnose", str(path)])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.slow
def test_twenty_second_two_kilohertz_log_is_diagnosed_in_under_30_s():
    import time

    exp = _log((fx.Coulomb(F_c=0.3),), duration_s=20.0)
    assert exp.rate_hz == 2000.0 and exp.n_samples == 40000
    t0 = time.perf_counter()
    d = diagnose(exp)
    assert time.perf_counter() - t0 < 30.0
    assert d.effect is Effect.COULOMB


def test_bundled_example_stiction_in_a_stiff_environment_is_named():
    # The packaged Fig. 7 scenario: LuGre stiction, EA-FOB, stiff environment, ~0.05 rad of motor
    # travel. The bristle stiffness is judged by the fitted breakaway level (F_s / sigma0 is the
    # presliding displacement), not by the log's largest torque, which refused the true effect.
    from importlib.resources import files

    from forecast_design.simulation.scenario import load_scenario

    sc = load_scenario(files("forecast_design") / "data" / "example_scenario.toml")
    d = diagnose(sc.run().to_experiment(), joint=False)
    assert d.location.angle_span_rad < 0.5
    assert d.effect is Effect.STICTION
    st = {r.effect: r for r in d.ranking}[Effect.STICTION]
    x_p = st.params["F_s"] / st.params["sigma0"]     # presliding displacement [rad]
    assert 1e-4 <= x_p <= 0.1
    assert st.identified and st.assessment.status["sigma0"].status != "implausible"


@pytest.mark.parametrize("env,kind", [("exp-soft", "none"), ("locked", "none")])
def test_cogging_over_part_of_a_revolution_is_tested_on_the_direction_the_log_resolves(env, kind):
    # Over ~0.05-0.5 rad the four harmonics are collinear: no single coefficient is resolved,
    # yet their shared contribution is, and it is what the Wald test must judge (a test on the
    # coefficients' own correlation kept the unresolved directions and found nothing: p = 1).
    design = Design.nominal(env, controller=PD(P=5.0, D=0.1))
    ref = refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1), phases_rad=(0.0, 1.0, 2.0))
    res = simulate(design, reference=ref, duration_s=10.0, effects=(fx.Cogging(a=(0.15,), b=(0.05,)),), seed=7,
                   initial_angle=0.3)
    d = diagnose(res.to_experiment(), joint=False)
    assert not d.location.full_revolution
    assert d.effect is Effect.COGGING
    # over the locked output's 0.05 rad the harmonics make a constant torque, which a current
    # driver's offset (or, tau_s being k (theta - q), encoders homed with the spring loaded) would
    # give as well: the verdict says so when a constant removes >= 90 % of what cogging removes
    from forecast_design.gap.candidates import fit_constant_torque

    base = d.baseline.gap_held_out
    r_const = 1 - fit_constant_torque(d.data).gap_held_out / base
    r_cog = 1 - d.fits["cogging"].gap_held_out / base
    said = any("would look the same" in c for c in d.caveats)
    assert said == (r_const >= 0.9 * r_cog)
    assert said or env != "locked"


@pytest.mark.parametrize("tau_s", ["derived", "sensor"])
def test_a_current_drivers_offset_is_named_cogging_only_with_the_caveat(tau_s):
    # the motor gets command + 0.03 N m (a driver's offset: the log holds the command): a constant
    # torque is no effect word; over 0.05 rad of travel cogging is the nearest, and the verdict must
    # say a constant explains it as well, with the constant's value
    from forecast_design import experiment_from_arrays

    design = Design.nominal("locked", controller=PD(P=5.0, D=0.1))
    ref = refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1), phases_rad=(0.0, 1.0, 2.0))
    s = simulate(design, reference=ref, duration_s=10.0, seed=7, initial_angle=0.3).to_experiment().signals
    column = None if tau_s == "derived" else np.round(
        np.asarray(s.tau_s) + np.random.default_rng(1).normal(0, 0.002, s.t.size), 6)
    exp = experiment_from_arrays(design, 2000.0, s.t, np.asarray(s.tau_m) - 0.03, s.theta, s.q, tau_s=column,
                                 tau_r=s.tau_r)
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.COGGING
    caveat = next(c for c in d.caveats if "would look the same" in c)
    value = float(caveat.split("constant motor torque of ")[1].split(" N m")[0])
    assert value == pytest.approx(-0.03, rel=0.05)


def _closed_loop_log(effect, env, compensator, reference, duration_s=10.0, **simulate_options):
    from forecast_design.params import Compensator

    references = {"square": refs.Square(high=1.0, low=-1.0, period_s=4.0),
                  "multisine": refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1),
                                              phases_rad=(0.0, 1.0, 2.0))}
    # the paper's PD with a 200 Hz derivative filter (Tustin): an unfiltered derivative would turn a coarse
    # encoder's 1.5 mrad steps into ~18 N m command spikes
    pd = PD(P=5.0, D=0.1, T_f=1.0 / (2.0 * np.pi * 200.0), discretization="tustin")
    design = Design.nominal(env, controller=pd, compensator=Compensator(kind=compensator))
    return simulate(design, reference=references[reference], duration_s=duration_s, effects=(effect,), seed=7,
                    initial_angle=0.3, **simulate_options).to_experiment()


def test_in_memory_tau_s_computed_from_the_encoders_is_classified_derived():
    # a log built in Python keeps tau_s = k (theta - q) at 17 digits: least-squares round-off of a
    # few ulps is not a torque sensor (it made backlash invisible: the coupling equation was void)
    from forecast_design.gap.residuals import classify_tau_s

    exp = _closed_loop_log(fx.Backlash(width_rad=2e-3), "locked", "none", "square")
    s = exp.signals
    theta, q = np.asarray(s.theta), np.asarray(s.q)
    assert np.array_equal(np.asarray(s.tau_s), exp.design.testbed.k * (theta - q))
    assert classify_tau_s(False, np.asarray(s.tau_s), theta, q).source == "derived"
    noisy = np.asarray(s.tau_s) + 1e-6 * np.random.default_rng(0).standard_normal(theta.size)
    assert classify_tau_s(False, noisy, theta, q).source == "measured"
    assert diagnose(exp, joint=False).effect is Effect.BACKLASH


def test_common_environment_scale_within_the_spring_tolerance_is_not_an_environment_mismatch():
    # stiction pushes the spring-scale re-calibration to its 3 % bound; J, d and k_e scaled alike
    # by the same 3 % in the environment equation are that re-calibration, not a mismatch
    d = diagnose(_closed_loop_log(fx.Stiction(), "exp-soft", "ea-fob", "square"), joint=False)
    assert d.effect is not Effect.ENVIRONMENT_MISMATCH
    env = {r.effect: r for r in d.ranking}[Effect.ENVIRONMENT_MISMATCH]
    assert not env.identified and any("scaled alike" in r for r in env.assessment.reasons)
    # a true mismatch of one parameter is still named
    d = diagnose(_closed_loop_log(fx.EnvironmentMismatch(k_e_scale=1.4), "exp-soft", "ea-fob", "square"), joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH


def test_collinear_harmonics_beyond_the_range_but_unresolved_are_uncertain_not_implausible():
    d = diagnose(_closed_loop_log(fx.Cogging(a=(0.15,), b=(0.05,)), "stiff", "none", "multisine"), joint=False)
    assert d.effect is Effect.COGGING
    cog = {r.effect: r for r in d.ranking}[Effect.COGGING]
    assert all(st.status != "implausible" for st in cog.assessment.status.values())


def test_coarse_encoder_narrows_the_equation_band_and_names_the_larger_of_two_effects():
    # A 4096-count encoder (1.5 mrad): at the default 100 Hz band the twice-differentiated
    # quantisation in J_m theta'' (about 0.3 N m) buried a 15 % torque loss and an environment
    # mismatch absorbed the leak of the spring-scale re-calibration into the environment equation.
    from forecast_design.gap import GapOptions
    from forecast_design.gap.residuals import equation_band

    fine = _closed_loop_log(fx.TorqueGain(gain=0.85), "exp-soft", "none", "multisine", duration_s=30.0)
    assert equation_band(fine, GapOptions()) == (100.0, None)
    coarse = _closed_loop_log(fx.TorqueGain(gain=0.85), "exp-soft", "none", "multisine", duration_s=30.0,
                              encoder_counts=4096, process_noise_std=0.02)
    rate, cutoff = equation_band(coarse, GapOptions())
    assert 10.0 <= rate < 100.0 and cutoff == rate
    # the predicted quantisation noise in the kept band is the set fraction of the RMS command
    step = 2.0 * np.pi / 4096
    tau_rms = float(np.sqrt(np.mean(np.asarray(coarse.signals.tau_m) ** 2)))
    f_band = 0.4 * rate
    noise = coarse.design.testbed.J_m * step / np.sqrt(12) * np.sqrt((2 * np.pi) ** 4 * f_band ** 5 / (5 * 1000.0))
    assert noise == pytest.approx(0.02 * tau_rms, rel=1e-6)
    d = diagnose(coarse, joint=False)
    assert d.effect is Effect.TORQUE_GAIN
    assert d.params["gain"] == pytest.approx(0.85, abs=0.05)
    # a log coarser than the validation says so; the testbed's encoder does not
    assert any("resolve the spring torque" in c for c in d.caveats)
    assert not any("resolve the spring torque" in c for c in diagnose(fine, joint=False).caveats)


def _gain_log(effect, env, P, D, reference, duration_s=20.0):
    design = Design.nominal(env, controller=PD(P=P, D=D))
    references = {"square": refs.Square(high=1.0, low=-1.0, period_s=4.0),
                  "multisine": refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1),
                                              phases_rad=(0.0, 1.0, 2.0))}
    return simulate(design, reference=references[reference], duration_s=duration_s,
                    effects=() if effect is None else (effect,), seed=5, initial_angle=0.3, rate_hz=1000.0)


def test_a_diverged_closed_loop_is_no_log_and_a_diverged_file_is_refused_in_one_line(tmp_path, capsys):
    from forecast_design.cli import main
    from forecast_design.errors import SolverError
    from forecast_design.experiment import save_experiment

    # PD 20/0.02 with a 2 ms transmission delay against the stiff environment is unstable
    res = _gain_log(fx.Delay(delay_s=2e-3), "stiff", 20.0, 0.02, "multisine")
    assert res.diverged_at_s is not None and np.max(np.abs(res.theta)) > 1e6
    with pytest.raises(SolverError, match="diverged"):
        res.to_experiment()
    # the same samples written by another tool: the diagnosis names the column and the row
    ok = _gain_log(None, "stiff", 5.0, 0.1, "multisine").to_experiment()
    theta = np.asarray(ok.signals.theta).copy()
    theta[4502] = -1.01e6
    save_experiment(ok.replace_signals(theta=theta), tmp_path / "diverged.toml")
    assert main(["diagnose", str(tmp_path / "diverged.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column theta" in err[0] and "row 4502" in err[0]


def test_derivative_kicks_do_not_make_a_two_effect_false_alarm():
    # PD 20/0.3 on a square wave kicks the motor with 500 N m at each edge; the effect-free gap is
    # 0.1 % of tau_s, and a stiction + delay pair that 'removes' half of it explains less than the
    # motor's torque accuracy (0.1 % of the RMS command): no effect
    res = _gain_log(None, "stiff", 20.0, 0.3, "square")
    assert np.max(np.abs(res.tau_m)) > 100.0
    d = diagnose(res.to_experiment(), joint=False)
    assert d.effect is Effect.NONE


def test_bristle_stiffness_at_the_grid_end_is_judged_by_the_fitted_breakaway_level():
    # a low-gain PD (P = 2) with large derivative kicks: the largest torque (57 N m) is no measure of
    # the friction level, F_s / sigma0 is
    d = diagnose(_gain_log(fx.Stiction(), "exp-soft", 2.0, 0.3, "square").to_experiment(), joint=False)
    assert d.effect is Effect.STICTION


@pytest.mark.parametrize("jitter, counts", [(0.0, 65_536), (0.3, 65_536), (0.8, 65_536), (0.6, 16_384)])
def test_an_encoders_jitter_is_read_from_how_often_its_readings_toggle(jitter, counts):
    # the replicas read their angles with the jitter of the log's encoders (noise before the quantiser): the one
    # whose readings of the replica's own motion undo a count change on the next sample as often as the log's do
    from forecast_design.gap.replicas import read_encoders, toggle_share
    from forecast_design.simulation import Square, simulate

    design, ref = Design.nominal("exp-soft"), Square(high=0.4, low=-0.4, period_s=0.5)
    exact = simulate(design, reference=ref, duration_s=4.0, encoder_counts=None, closed_loop=False, seed=5)
    step = 2.0 * math.pi / counts
    theta, q = np.asarray(exact.theta, dtype=float), np.asarray(exact.q, dtype=float)
    # the "log": another noise draw than the replica's
    log_theta = np.round((theta + jitter * step * np.random.default_rng(11).standard_normal(theta.size)) / step) * step
    read_theta, read_q, found = read_encoders(theta, q, step, toggle_share(log_theta), seed=3)
    assert found == pytest.approx(jitter, abs=0.1)
    if jitter == 0.0:
        # no jitter: the simulator's own quantiser, reading for reading
        quantised = simulate(design, reference=ref, duration_s=4.0, encoder_counts=counts, closed_loop=False, seed=5)
        assert np.array_equal(read_theta, np.asarray(quantised.theta))
        assert np.array_equal(read_q, np.asarray(quantised.q))
    else:
        assert toggle_share(np.round(theta / step) * step) < toggle_share(log_theta) <= toggle_share(read_theta)


@pytest.mark.parametrize("std, counts", [(1e-3, 2_000_000), (4e-3, 16_384)])
def test_a_torque_sensors_noise_is_read_from_the_log_whatever_the_encoders(std, counts):
    # the replicas of a closed loop need the noise its controller fed back: a sensor's, read from tau_s alone
    # (14-bit encoders put 12 mN m of quantisation into k (theta - q), three times the noise sought)
    from forecast_design.gap.replicas import sensor_noise_std
    from forecast_design.gap.residuals import prepare_gap_data
    from forecast_design.simulation import Square, TorqueSensor, simulate

    run = simulate(Design.nominal("exp-soft"), reference=Square(high=0.4, low=-0.4, period_s=0.5), duration_s=4.0,
                   encoder_counts=counts, torque_sensor=TorqueSensor(noise_std_N_m=std), seed=5)
    data = prepare_gap_data(run.to_experiment())
    assert data.tau_s_measured
    assert sensor_noise_std(data) == pytest.approx(std, rel=0.1)
    derived = simulate(Design.nominal("exp-soft"), reference=Square(high=0.4, low=-0.4, period_s=0.5),
                       duration_s=4.0, encoder_counts=counts, seed=5)
    assert sensor_noise_std(prepare_gap_data(derived.to_experiment())) is None


# --- the friction laws on the motor's trajectory around its reversals (gap/reversals) ---------------------------------

@settings(max_examples=40, deadline=None)
@given(u=st.floats(0.5, 3.0), F=st.floats(0.05, 0.4), v0=st.floats(0.01, 2.0), J=st.floats(1e-3, 0.2))
def test_a_sliding_motor_under_a_constant_torque_follows_the_parabola(u, F, v0, J):
    """Sliding one way under a constant net torque (no spring, no damping), the angle is theta0 + v0 t + (u - F) t^2 /
    (2 J) at every sample: the trapezoidal step is exact for a constant acceleration."""
    from forecast_design.gap.reversals import simulate_windows
    one = np.ones(1)
    dt, n = 5e-4, 60
    th = simulate_windows(np.full((1, n), u), 0.1 * one, v0 * one, F_pos=F * one, F_neg=F * one, r=one,
                          v_s=0.01 * one, d_m=0.0, J_m=J, k=0.0, dt=dt)[0]
    t = np.arange(n) * dt
    np.testing.assert_allclose(th, 0.1 + v0 * t + 0.5 * (u - F) / J * t ** 2, rtol=1e-10, atol=1e-13)


@settings(max_examples=40, deadline=None)
@given(net=st.floats(0.01, 1.0), F=st.floats(0.05, 0.3), r=st.floats(1.0, 2.0))
def test_a_motor_at_rest_breaks_away_only_above_its_breakaway(net, F, r):
    """At rest the motor holds while |net torque| <= r F; above, it leaves in the direction of the torque."""
    from forecast_design.gap.reversals import simulate_windows
    one = np.ones(1)
    th = simulate_windows(np.full((1, 10), -net), 0 * one, 0 * one, F_pos=F * one, F_neg=F * one, r=r * one,
                          v_s=0.01 * one, d_m=0.0, J_m=1e-3, k=0.0, dt=5e-4)[0]
    if net <= r * F * (1 - 1e-9):
        assert np.all(th == 0.0)
    elif net > r * F * (1 + 1e-6):
        assert th[-1] < 0.0


def test_the_window_simulation_agrees_with_scipy_through_a_reversal():
    """A spring-loaded motor with Stribeck friction sliding through a reversal it does not stick at (the net torque
    there exceeds the breakaway): the semi-implicit steps against scipy's adaptive solver on the smooth law, within a
    tenth of a 16-bit count at the default 10 substeps, and converging as the substeps shrink."""
    from scipy.integrate import solve_ivp
    from forecast_design.gap.reversals import simulate_windows
    J, k, d, Fc, r, vs, u = 0.05, 20.0, 0.1, 0.1, 1.5, 0.05, 1.0
    dt, n = 5e-4, 200
    one = np.ones(1)

    def rhs(_t, x):
        fr = np.sign(x[1]) * Fc * (1 + (r - 1) * np.exp(-(x[1] / vs) ** 2))
        return [x[1], (u - k * x[0] - d * x[1] - fr) / J]

    ref = solve_ivp(rhs, (0, (n - 1) * dt), [0.0, -0.8], t_eval=np.arange(n) * dt, rtol=1e-10, atol=1e-12,
                    max_step=dt / 20).y[0]
    assert np.sign(np.diff(ref)).min() < 0 < np.sign(np.diff(ref)).max()      # it does reverse
    err = [np.abs(simulate_windows(np.full((1, n), u), 0.0 * one, -0.8 * one, F_pos=Fc * one, F_neg=Fc * one,
                                   r=r * one, v_s=vs * one, d_m=d, J_m=J, k=k, dt=dt,
                                   substeps=m)[0] - ref).max() for m in (10, 640)]
    assert err[0] < 0.1 * 2 * np.pi / 65536
    assert err[1] < err[0] / 10
