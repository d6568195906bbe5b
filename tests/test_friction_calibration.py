"""Friction identification checked against an independent generator (forecast_design.independent).

The logs come from :func:`forecast_design.independent.friction_log` and
:func:`~forecast_design.independent.simulate_independent` (event-based
stick/slip and LuGre integration with scipy, 2,000,000-count encoder, 2 kHz),
not from the project's virtual testbed nor from the identification's own
model code. Regressions of three failure classes seen on such logs:

7. Stribeck collapsed on slow breakaways (static = Coulomb, v_s on a grid end,
   a std of exactly 0, ``Solve_Succeeded``).
8. Extended SFM biased by sticking samples and reversals, intervals covering
   the truth in 70 % of the logs.
9. LuGre confident and wrong on a closed-loop log with little sliding.
"""

import json

import numpy as np
import pytest

from forecast_design import PD
from forecast_design.cli import main
from forecast_design.effects import Effect
from forecast_design.experiment import save_experiment
from forecast_design.friction import identify
from forecast_design.independent import Excitation, IndependentCase, friction_log, simulate_independent
from forecast_design.params import Testbed, environment_preset

N_LOGS = 24
EXT_NAMES = ("viscous", "coulomb", "sin1", "cos1", "sin2", "cos2", "sin3", "cos3", "sin4", "cos4")


@pytest.fixture(scope="module")
def extended_sfm_runs():
    """(truth, default fit, fit on every sample) for N_LOGS independent extended-SFM logs of 10 s."""
    runs = []
    for seed in range(N_LOGS):
        exp, true = friction_log("extended-sfm", seed=seed, duration_s=10.0)
        runs.append((true, identify(exp, "extended-sfm", holdout=0.0),
                     identify(exp, "extended-sfm", holdout=0.0, selection="off")))
    return runs


@pytest.mark.slow
def test_extended_sfm_intervals_cover_and_estimates_are_unbiased(extended_sfm_runs):
    err = np.array([[fit.params[k] - true[k] for k in EXT_NAMES] for true, fit, _ in extended_sfm_runs])
    std = np.array([[fit.std[k] for k in EXT_NAMES] for _, fit, _ in extended_sfm_runs])
    lo = np.array([[fit.interval95[k][0] - true[k] for k in EXT_NAMES] for true, fit, _ in extended_sfm_runs])
    hi = np.array([[fit.interval95[k][1] - true[k] for k in EXT_NAMES] for true, fit, _ in extended_sfm_runs])
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    coverage = np.mean((lo <= 0) & (hi >= 0), axis=0)
    for name, c in zip(EXT_NAMES, coverage):
        assert c >= 0.90, f"{name}: nominal 95 % intervals cover the truth in {100 * c:.0f} % of {N_LOGS} logs"
    se = err.std(axis=0, ddof=1) / np.sqrt(N_LOGS)
    for name, m, s in zip(EXT_NAMES, err.mean(axis=0), se):
        assert abs(m) <= 3 * s, f"{name}: mean error {m:.3g} is {abs(m) / s:.1f} standard errors from 0"
    for true, fit, _ in extended_sfm_runs:
        for k in ("viscous", "coulomb"):
            assert fit.params[k] == pytest.approx(true[k], rel=0.05), k
        for k in EXT_NAMES[2:]:
            assert fit.params[k] == pytest.approx(true[k], abs=0.01), k
        assert fit.selection.applied and fit.n_samples_used < fit.n_samples


@pytest.mark.slow
def test_sticking_samples_bias_the_fit_that_keeps_them(extended_sfm_runs):
    """Failure class 8: without the sample selection the Coulomb level is biased beyond its noise."""
    for fits in (1, 2):
        err = np.array([run[fits].params["coulomb"] - run[0]["coulomb"] for run in extended_sfm_runs])
        se = err.std(ddof=1) / np.sqrt(err.size)
        if fits == 1:
            assert abs(err.mean()) <= 3 * se
        else:
            assert abs(err.mean()) > 5 * se, "the regression log no longer sticks: the check is void"
    doc = json.loads(json.dumps(extended_sfm_runs[0][1].to_mapping(), allow_nan=False))
    assert doc["selection"]["applied"] and doc["n_samples_used"] == extended_sfm_runs[0][1].n_samples_used


def test_stribeck_on_slow_breakaways_is_recovered_with_real_intervals():
    """Failure class 7: many slow breakaways, static 0.45 / Coulomb 0.25."""
    exp, true = friction_log("stribeck", {"static": 0.45, "coulomb": 0.25, "stribeck_velocity": 0.05},
                             seed=4, duration_s=20.0)
    fit = identify(exp, "stribeck", holdout=0.0)
    for k in true:
        assert fit.params[k] == pytest.approx(true[k], rel=0.05), k
        lo, hi = fit.interval95[k]
        assert fit.std[k] > 0 and hi > lo
    assert fit.params["static"] - fit.params["coulomb"] > 3 * (fit.std["static"] + fit.std["coulomb"])
    assert fit.identified and fit.identifiability == "identified"
    assert fit.solver["method"].startswith("variable projection")


def test_stribeck_decay_below_the_encoder_resolution_is_flagged():
    """No breakaway the encoder can resolve (v_s = 0.003 rad/s): v_s and the static level are not estimates."""
    exp, _ = friction_log("stribeck", {"static": 0.45, "coulomb": 0.25, "stribeck_velocity": 0.003},
                          seed=2, duration_s=10.0)
    fit = identify(exp, "stribeck", holdout=0.0)
    assert fit.status["stribeck_velocity"].status in ("at_bound", "uncertain")
    assert not fit.status["static"].identified
    assert fit.params["coulomb"] == pytest.approx(0.25, rel=0.05) and fit.status["coulomb"].identified
    assert set(fit.to_mapping()["not_identified"]) >= {"static", "stribeck_velocity"}


def test_lugre_with_enough_sliding_is_recovered():
    exp, true = friction_log("lugre", seed=1, duration_s=20.0)
    fit = identify(exp, "lugre", holdout=0.0)
    for k in ("sigma0", "static", "coulomb", "stribeck_velocity", "viscous"):
        assert fit.params[k] == pytest.approx(true[k], rel=0.05), k
    for k in ("static", "coulomb", "stribeck_velocity", "viscous"):
        assert fit.status[k].identified, k
    assert fit.params["sigma1"] == pytest.approx(true["sigma1"], rel=0.10)
    # the bristles relax (F_c / (sigma0 |v|) ~ 0.4 ms at the median sliding speed) within one 0.5 ms
    # sample: the bristle parameters' few-percent discretisation error is in their intervals (the
    # method's error, a refit at half the rate), which hold the truth
    for k in ("sigma0", "sigma1"):
        lo, hi = fit.interval95[k]
        assert lo <= true[k] <= hi, k
        assert fit.std_method[k] > 0, k


@pytest.mark.parametrize("rate_hz", [500.0, 1000.0])
def test_lugre_damping_interval_carries_its_discretisation_error_when_the_bristles_relax_within_a_sample(rate_hz):
    # On these logs sigma1 comes out 9-10 % low (the transient it acts in lasts less than a sample; at
    # half the rate 18-19 % low: an error of first order in the sample period); with the noise alone its
    # interval missed the truth by 7-25 std. The method's error puts the truth inside, sigma1 is not
    # reported as a number, and the other parameters stay within 5 %.
    exp, true = friction_log("lugre", seed=0, duration_s=30.0, rate_hz=rate_hz)
    fit = identify(exp, "lugre", holdout=0.0)
    st = fit.status["sigma1"]
    lo, hi = fit.interval95["sigma1"]
    assert st.status == "uncertain" and lo <= true["sigma1"] <= hi
    assert fit.std_method["sigma1"] > 0.5 * fit.std["sigma1"]   # most of the width is the method's error
    assert "sigma1" in fit.to_mapping()["not_identified"]
    for k in ("sigma0", "static", "coulomb", "viscous"):
        assert fit.params[k] == pytest.approx(true[k], rel=0.05), k


def _little_sliding_log():
    """Closed-loop PD force control against a stiff environment: the motor hardly slides."""
    tb = Testbed(J_m=Testbed.nominal().J_m, d_m=0.3, k=Testbed.nominal().k)
    case = IndependentCase(
        words=(Effect.STICTION,), environment=environment_preset("stiff"), environment_name="stiff",
        excitation=Excitation(kind="multisine", amplitude=0.3, f_lo_hz=0.2, f_hi_hz=3.0, lines=8),
        closed_loop=True, controller=PD(P=5.0, D=0.1), rate_hz=2000.0, duration_s=10.0, testbed=tb,
        effect_params=dict(F_c=0.3, F_s=0.45, v_s=0.05, sigma0=1000.0, sigma1=5.0), seed=3, tau_m_digits=9)
    return simulate_independent(case)[0]


def test_lugre_on_a_closed_loop_log_with_little_sliding_says_not_identifiable(tmp_path, capsys):
    """Failure class 9, through the CLI: "not identifiable" is an answer (issue 25): the JSON is written, exit 3,
    one warning per parameter that is not an estimate."""
    path = tmp_path / "little.toml"
    save_experiment(_little_sliding_log(), path)
    out = tmp_path / "fit.json"
    assert main(["identify", str(path), "--model", "lugre", "--json", str(out)]) == 3
    doc = json.loads(out.read_text())
    assert doc["identifiability"].startswith("not identifiable: too little sliding")
    assert not doc["identified"]
    assert set(doc["not_identified"]) == {"sigma1", "static", "coulomb", "stribeck_velocity", "viscous"}
    assert doc["exit_code"] == 3
    for name in doc["not_identified"]:
        assert doc["status"][name]["status"] in ("at_bound", "uncertain", "implausible", "not_identifiable")
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == len(doc["not_identified"])
    assert all(line.startswith("forecast-design: warning: ") and "not identified" in line for line in err)


def test_stribeck_static_level_is_not_reported_when_the_decay_velocity_runs_to_the_top_of_its_range():
    # ten times the default friction, 6 s at 500 Hz: the log slides fast and the profile over v_s is
    # flat up to the top of its range; static then fell onto coulomb (3.0 for a true 4.5, +-0.0014)
    params = {"static": 4.5, "coulomb": 3.0, "stribeck_velocity": 0.05, "viscous": 3.0}
    exp, true = friction_log("stribeck", params, seed=1, duration_s=6.0, rate_hz=500.0)
    fit = identify(exp, "stribeck", holdout=0.0)
    assert not fit.status["stribeck_velocity"].identified
    # not reported: either the profile runs flat to the top of its range, or the interval is wider than
    # +-10 % of the value (the precision an identified number promises)
    st = fit.status["static"]
    assert st.status == "uncertain" and ("not resolved" in st.reason or "wider than +-10 %" in st.reason)
    assert fit.params["coulomb"] == pytest.approx(true["coulomb"], rel=0.05) and fit.status["coulomb"].identified


@pytest.fixture(scope="module")
def sensor_log():
    """One independent extended-SFM log (20 s) whose tau_s column the torque-sensor tests rewrite."""
    return friction_log("extended-sfm", seed=1)


@pytest.mark.parametrize("zero,noise", [(0.03, 0.002), (-0.03, 0.002), (0.03, 0.0)])
def test_a_torque_sensors_zero_is_fitted_by_default_and_not_leaked_into_the_harmonics(sensor_log, zero, noise):
    # an independent extended-SFM log whose tau_s reads the spring torque + a zero offset (+ noise:
    # a torque sensor; without noise: a logger that added a constant): unfitted, the 0.03 N m zero
    # moved cos1 (0.02 N m) by 50 % with an interval that missed the truth; by default the offset is
    # fitted whenever the column carries a constant beyond k (theta - q), and every parameter's 95 %
    # interval covers its truth (to 1e-4 N m, the generator's own discretisation); a log whose tau_s
    # is k (theta - q) gets no offset term
    from forecast_design import experiment_from_arrays
    from forecast_design.friction import identify
    from forecast_design.tau_s_source import tau_s_source_of

    exp, truth = sensor_log
    s = exp.signals
    k = exp.design.testbed.k
    rng = np.random.default_rng(0)
    column = np.round(k * (np.asarray(s.theta) - np.asarray(s.q)) + zero + rng.normal(0, noise, s.t.size), 6)
    logged = experiment_from_arrays(exp.design, exp.rate_hz, s.t, s.tau_m, s.theta, s.q, tau_s=column)
    src = tau_s_source_of(logged)
    assert src.zero_offset and src.offset_N_m == pytest.approx(zero, abs=0.002)
    assert src.measured == (noise > 0) and not tau_s_source_of(exp).zero_offset
    fit = identify(logged, "extended-sfm")
    assert fit.params["offset"] == pytest.approx(-zero, abs=0.003)
    for name in ("viscous", "coulomb", "sin1", "cos1"):
        lo, hi = fit.interval95[name]
        assert lo - 1e-4 <= truth[name] <= hi + 1e-4, name
    assert "offset" not in identify(exp, "extended-sfm").params
    unfitted = identify(logged, "extended-sfm", offset=False)
    assert "offset" not in unfitted.params
    assert abs(unfitted.params["cos1"] - truth["cos1"]) > 0.2 * truth["cos1"]     # what the default prevents


@pytest.mark.parametrize("scale", [1.08, 0.98])
def test_parameters_that_follow_a_torque_sensors_scale_are_flagged(sensor_log, scale):
    # a sensor reading scale x k (theta - q): the link's damping makes tau_s follow the velocity, so
    # the scale moved viscous (by 9 % at 1.08) outside its interval; the fit is repeated with the
    # encoders' torque and every parameter that moves beyond its interval is `uncertain`, naming
    # why; the others stay identified; a calibrated sensor triggers nothing
    from forecast_design import experiment_from_arrays
    from forecast_design.friction import identify

    exp, truth = sensor_log
    s = exp.signals
    k = exp.design.testbed.k
    noise = np.random.default_rng(0).normal(0, 0.002, s.t.size)

    def fitted(g):
        column = np.round(g * k * (np.asarray(s.theta) - np.asarray(s.q)) + noise, 6)
        return identify(experiment_from_arrays(exp.design, exp.rate_hz, s.t, s.tau_m, s.theta, s.q, tau_s=column),
                        "extended-sfm")

    fit = fitted(scale)
    for name, st in fit.status.items():
        lo, hi = fit.interval95[name]
        if not lo - 1e-4 <= truth[name] <= hi + 1e-4:       # a number that misses its truth is not reported as one
            assert st.status == "uncertain" and "torque sensor's scale" in st.reason, name
    assert fit.status["viscous"].status == "uncertain" and fit.status["coulomb"].identified
    assert not any("torque sensor's scale" in st.reason for st in fitted(1.0).status.values())
