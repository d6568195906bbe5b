"""Reproductions of the paper's Fig. 7 and Table 3 on the virtual testbed (issue 5, "Done when")."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal, stats

from forecast_design.effects import PositionFriction, Stiction
from forecast_design.errors import ParameterError
from forecast_design.discrete import discretize
from forecast_design.params import Compensator
from forecast_design.reproduce import (
    FIG7_VARIATIONS,
    PAPER_TABLE3,
    TABLE3_TRUTH,
    XCORR_MODES,
    Fig7Choices,
    pairwise_xcorr,
    pairwise_xcorr_se,
    reproduce_fig7,
    reproduce_table3,
)
from forecast_design.symbolic.observers import compensator_q_tf


@pytest.fixture(scope="module")
def fig7():
    return reproduce_fig7()


@pytest.fixture(scope="module")
def table3():
    return reproduce_table3()


# --- Fig. 7 -------------------------------------------------------------------------------------


def test_fig7_eafob_estimate_is_5x_better_than_sfm_and_within_0_05(fig7):
    assert fig7.mae_friction_eafob <= 0.05
    assert 5.0 * fig7.mae_friction_eafob <= fig7.mae_friction_sfm
    # the paper's published pair (0.35, 0.02) within a factor 1.5
    assert 0.35 / 1.5 < fig7.mae_friction_sfm < 0.35 * 1.5
    assert 0.02 / 1.5 < fig7.mae_friction_eafob < 0.02 * 1.5


def test_fig7_eafob_estimate_is_the_q_filtered_true_friction(fig7):
    # Derivation: with the exact plant, tau_m - P_n^-1 tau_s = tau_frc, so tau_hat = Q tau_frc.
    # Cross-check with scipy filtering the *true* friction through the discretised Q.
    r = fig7.runs["ea-fob"]
    q = discretize(compensator_q_tf(Compensator(kind="ea-fob", w_q_hz=10.0)), 2000.0, "tustin")
    expected = signal.lfilter(q.num, q.den, r.truth.tau_frc)
    assert np.mean(np.abs(r.tau_frc_hat - expected)) < 0.005
    assert np.mean(np.abs(r.tau_frc_hat - expected)) == pytest.approx(fig7.mae_friction_eafob_vs_q)
    # sign convention: the estimate has the friction's sign (fed forward as u + tau_hat it cancels it)
    assert np.corrcoef(r.tau_frc_hat, r.truth.tau_frc)[0, 1] > 0.9


def test_fig7_eafob_compensation_tracks_better_than_no_compensation(fig7):
    from forecast_design.controllers import PD
    from forecast_design.params import Design
    from forecast_design.simulation import Square, simulate

    c = fig7.choices
    bare = simulate(Design.nominal(c.environment, controller=PD()), effects=[Stiction()],
                    reference=Square(high=c.high, low=c.low, period_s=c.period_s), duration_s=c.periods * c.period_s)
    assert fig7.mae_tracking_eafob < np.mean(np.abs(bare.tau_r - bare.tau_s))


def test_fig7_mapping_and_sensitivity_rows(fig7):
    m = fig7.to_mapping()
    maes = {"mae_friction_sfm", "mae_friction_eafob", "mae_tracking_sfm", "mae_tracking_eafob"}
    assert set(m) == maes | {f"{k}_N_m" for k in maes} | {"choices", "sensitivity", "explanation"}
    assert all(m[f"{k}_N_m"] == m[k] for k in maes)
    json.dumps(m, allow_nan=False)
    assert len(m["sensitivity"]) == len(FIG7_VARIATIONS)
    default = m["sensitivity"][0]
    assert default["vary"] == "defaults" and default["mae_friction_eafob"] == m["mae_friction_eafob"]
    choice_keys = set(Fig7Choices().to_mapping())
    for row in m["sensitivity"]:
        assert choice_keys | {"vary", "mae_friction_sfm", "mae_friction_eafob", "mae_tracking_sfm",
                              "mae_tracking_eafob"} == set(row)
        assert all(math.isfinite(row[k]) and row[k] > 0 for k in ("mae_friction_sfm", "mae_friction_eafob"))
    # the EA-FOB's lag error scales with the edges per second: halving the period roughly doubles it
    by_period = {r["period_s"]: r["mae_friction_eafob"] for r in m["sensitivity"]
                 if r["environment"] == "stiff" and r["vary"] in ("defaults", "period_s")}
    assert by_period[2.0] > 1.5 * by_period[4.0] > 1.5 * 1.5 * by_period[8.0]
    assert "0.35" in m["explanation"] and "0.02" in m["explanation"]


def test_fig7_rejects_unknown_and_bad_choices():
    with pytest.raises(ParameterError, match="unknown fig7 choice 'periode'"):
        reproduce_fig7(periode=2.0)
    with pytest.raises(ParameterError, match="period_s"):
        reproduce_fig7(period_s=-1.0, sensitivity=False)
    with pytest.raises(ParameterError, match="unknown environment"):
        Fig7Choices(environment="moon")


# --- Table 3 ------------------------------------------------------------------------------------


def test_table3_shows_the_papers_pattern_within_stated_tolerances(table3):
    # Table 3's pattern (issue 17): PD alone the least repeatable in both environments, by more
    # than two standard errors of the paired difference, and within 0.15 of the paper's 0.73 / 0.90;
    # the compensated loops repeatable (paper 0.98-0.99, tolerance 0.02); the EA-FOB the closest to
    # the frictionless response in both, its MAE within 0.005 N m of the paper's
    from forecast_design.reproduce import pairwise_xcorr_se

    for env in ("exp-soft", "locked"):
        e, s, n = (table3.row(env, k) for k in ("ea-fob", "sfm", "none"))
        assert e.xcorr == pytest.approx(e.paper_xcorr, abs=0.02)
        assert s.xcorr == pytest.approx(s.paper_xcorr, abs=0.02)
        assert n.xcorr == pytest.approx(n.paper_xcorr, abs=0.15)
        tau = {k: np.array([r.tau_s for r in table3.responses[(env, k)]]) for k in ("none", "sfm", "ea-fob")}
        for k, other in (("sfm", s), ("ea-fob", e)):
            # beyond one standard error of the paired difference (soft: 1.5 of them, its PD runs
            # split into two shapes; locked: about 3) and by 0.05 at least
            assert other.xcorr - n.xcorr > max(0.05, pairwise_xcorr_se(tau[k], paired_with=tau["none"]))
        assert e.mae < s.mae and e.mae < n.mae
        assert e.mae == pytest.approx(e.paper_mae, abs=0.005)           # paper 0.008 / 0.01
        assert f"{env}: PD alone is the least repeatable; the EA-FOB is the closest" in table3.explanation


def test_table3_pd_repeatability_rests_on_the_stated_choices(table3):
    # the explanation's mechanism, measured: with the derivative on the error (the kick) PD alone
    # is repeatable with the output locked again and the EA-FOB is not; the PD-alone runs that end
    # below a quarter of the frictionless level started where the static level is the highest
    probe = {(m["mechanism"], m["environment"], m["compensator"]): m["xcorr"] for m in table3.mechanisms}
    kick = {k: probe[("PD derivative on the error", "locked", k)] for k in ("none", "sfm", "ea-fob")}
    assert kick["none"] > kick["ea-fob"] + 0.05
    assert table3.choices["derivative_on"] == "measurement"
    from forecast_design.table3 import _static_levels

    levels = _static_levels(TABLE3_TRUTH, table3.initial_angles)
    final = np.array([r.tau_s[-200:].mean() for r in table3.responses[("locked", "none")]])
    stuck = final < 0.25 * table3.expected["locked"].tau_s[-1]
    assert stuck.any() and (~stuck).any()
    assert levels[stuck].min() > levels[~stuck].max()
    for r in table3:
        assert (f"{r.environment}/{r.compensator}: xcorr {r.xcorr:.3f} +- {r.xcorr_se:.3f} (paper "
                f"{r.paper_xcorr:.2f})") in table3.explanation
    for m in table3.mechanisms:
        assert f"{m['environment']}/{m['compensator']} {m['xcorr']:.3f}" in table3.explanation


def test_derivative_on_the_measurement_commands_P_r_minus_C_y():
    # derivative_on = "measurement": u = P r - C(z) y exactly, C the controller's own law (python-
    # control's response of C to the logged tau_s), so the step has no kick; on the error it kicks
    import control

    from forecast_design.controllers import PD
    from forecast_design.params import Design
    from forecast_design.simulation import Step, simulate
    from forecast_design.table3 import table3_controller

    pd = table3_controller("measurement")
    law = pd.discrete_law(2000.0)
    C = control.tf(law.feedback_tf().num, law.feedback_tf().den, 1 / 2000.0)
    run = simulate(Design.nominal("locked", controller=pd), reference=Step(amplitude=0.2, t0=0.002),
                   duration_s=0.2, encoder_counts=None, process_noise_std=0.0)
    y = np.asarray(run.tau_s)
    u = 5.0 * np.asarray(run.tau_r) - control.forced_response(C, U=y).outputs
    assert np.allclose(run.tau_r, np.where(run.t >= 0.002, 0.2, 0.0))        # the reference as given
    assert np.allclose(run.u, u, atol=1e-9) and np.max(np.abs(run.u)) < 2.0   # no 25 N m kick
    kick = simulate(Design.nominal("locked", controller=table3_controller("error")),
                    reference=Step(amplitude=0.2, t0=0.002), duration_s=0.2, encoder_counts=None,
                    process_noise_std=0.0)
    assert np.max(np.abs(kick.u)) > 10.0
    with pytest.raises(ParameterError, match="derivative_on must be one of"):
        PD(P=5.0, D=0.1, derivative_on="setpoint")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_table3_pattern_holds_for_other_draws_of_angles(seed):
    # the pattern is not one lucky draw of ten angles: PD alone is the least repeatable cell in
    # both environments and the EA-FOB the closest to the frictionless response, for other seeds
    t3 = reproduce_table3(seed=seed, sensitivity=(), play_probe_rad=None)
    for env in ("exp-soft", "locked"):
        e, s, n = (t3.row(env, k) for k in ("ea-fob", "sfm", "none"))
        assert n.xcorr < min(s.xcorr, e.xcorr) - 0.03
        assert min(s.xcorr, e.xcorr) > 0.95
        assert e.mae < min(s.mae, n.mae)


def test_table3_cells_carry_their_sampling_error(table3):
    # every cell's x-corr and MAE carry a standard error over the draw of ten angles; the MAE's is
    # the runs' std / sqrt(10), recomputed here from the responses
    for r in table3:
        tau = np.array([x.tau_s for x in table3.responses[(r.environment, r.compensator)]])
        mae_runs = np.mean(np.abs(tau - table3.expected[r.environment].tau_s), axis=1)
        assert r.mae_se == pytest.approx(np.std(mae_runs, ddof=1) / np.sqrt(10), rel=1e-12)
        assert r.xcorr_se == pytest.approx(pairwise_xcorr_se(tau), rel=1e-12) and r.xcorr_se >= 0.0
        assert r.to_mapping()["mae_se_N_m"] == r.mae_se
    n = table3.row("locked", "none")
    assert f"PD alone lies {abs(n.xcorr - n.paper_xcorr) / n.xcorr_se:.1f} standard errors" in table3.explanation
    assert "paired over the same angles" in table3.explanation


def test_table3_xcorr_readings_are_reported_and_only_pearson_can_reach_the_paper(table3):
    # the rows use the default reading; every reading is reported per cell; keeping the means
    # ('raw') rates every settled step response >= 0.99, so it cannot give the paper's 0.73
    assert table3.choices["xcorr"] == "pearson"
    readings = {(r["environment"], r["compensator"]): r for r in table3.readings}
    assert set(readings) == set(PAPER_TABLE3)
    for r in table3:
        got = readings[(r.environment, r.compensator)]
        assert got["pearson"] == r.xcorr
        assert got["pearson-max-lag"] >= got["pearson"] - 1e-12          # lag 0 is one of the lags
        assert got["raw"] >= 0.99
    assert readings[("exp-soft", "none")]["pearson"] == pytest.approx(0.73, abs=0.15)
    doc = table3.to_document()
    assert len(doc["readings"]) == 6 and len(doc["mechanisms"]) == 12    # two probes x six cells


def test_table3_rows_are_the_issue_json(table3):
    rows = table3.to_mapping()
    assert [(r["environment"], r["compensator"]) for r in rows] == list(PAPER_TABLE3)
    for r in rows:
        assert {"environment", "compensator", "xcorr", "mae"} <= set(r)
        assert (r["paper_xcorr"], r["paper_mae"]) == PAPER_TABLE3[(r["environment"], r["compensator"])]
        assert -1.0 <= r["xcorr"] <= 1.0 and r["mae"] >= 0.0
    json.dumps(table3.to_document(), allow_nan=False)
    assert len(list(table3)) == 6 and table3[0].compensator == "none"


def test_table3_initial_angles_differ_and_the_runs_use_them(table3):
    a = table3.initial_angles
    assert a.shape == (10,) and len(set(np.round(a, 9))) == 10 and np.all((a >= 0) & (a < 2 * np.pi))
    runs = table3.responses[("locked", "none")]
    assert [r.truth.initial_angle for r in runs] == list(a)


def test_table3_sfm_is_identified_not_copied(table3):
    # extended SFM fitted on the simulated identification run recovers the truth's averages:
    # viscous = d_m + sigma2 = 0.3 + 0.1, Coulomb = LuGre F_c + mean position friction = 0.4 + 0.1
    stiction = next(e for e in TABLE3_TRUTH if isinstance(e, Stiction))
    pf = next(e for e in TABLE3_TRUTH if isinstance(e, PositionFriction))
    p = table3.sfm_params
    assert set(p) == {"viscous", "coulomb"} | {f"{sc}{i}" for sc in ("sin", "cos") for i in range(1, 5)}
    assert p["viscous"] == pytest.approx(0.3 + stiction.sigma2, rel=0.1)
    assert p["coulomb"] == pytest.approx(stiction.F_c + pf.F_c, rel=0.1)
    assert p["coulomb"] != stiction.F_c and p["viscous"] != 0.3


def test_table3_frictionless_reference_is_the_pd_steady_state(table3):
    # P + D s on a unit-DC-gain plant: tau_s -> P / (1 + P) * 0.2
    for env, e in table3.expected.items():
        assert e.tau_s[-1] == pytest.approx(0.2 * 5.0 / 6.0, rel=1e-3)
        assert np.all(e.truth.tau_frc == 0.0)


def test_pairwise_xcorr_is_the_mean_pearson_r(rng):
    x = rng.normal(size=(4, 50)).cumsum(axis=1)
    expected = np.mean([stats.pearsonr(x[i], x[j])[0] for i in range(4) for j in range(i + 1, 4)])
    assert pairwise_xcorr(x) == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ParameterError):
        pairwise_xcorr(x[:1])


def _brute_jackknife(x, y=None):
    # leave each repetition out, recompute the statistic from scratch: the textbook jackknife
    m = x.shape[0]
    loo = np.array([pairwise_xcorr(np.delete(x, i, axis=0)) - (0.0 if y is None else
                                                                 pairwise_xcorr(np.delete(y, i, axis=0)))
                    for i in range(m)])
    return np.sqrt((m - 1) / m * np.sum((loo - loo.mean()) ** 2))


def test_pairwise_xcorr_se_is_the_leave_one_out_jackknife(rng):
    x = rng.normal(size=(7, 80)).cumsum(axis=1)
    y = x + rng.normal(scale=2.0, size=x.shape)
    assert pairwise_xcorr_se(x) == pytest.approx(_brute_jackknife(x), rel=1e-10)
    assert pairwise_xcorr_se(x, paired_with=y) == pytest.approx(_brute_jackknife(x, y), rel=1e-10)
    assert pairwise_xcorr_se(x, paired_with=x) == 0.0
    with pytest.raises(ParameterError, match="at least three repetitions"):
        pairwise_xcorr_se(x[:2])
    with pytest.raises(ParameterError, match="same 7 repetitions"):
        pairwise_xcorr_se(x, paired_with=y[:5])


def test_pairwise_xcorr_se_covers_the_spread_over_draws():
    # step-like responses whose shape varies per run (a random mix of a fast and a slow rise plus
    # noise): over 400 draws of ten runs the jackknife error matches the statistic's actual spread;
    # +-1.96 of it covers the mean of all draws 86 % of the time, not 95 % (ten runs, and a
    # correlation bounded by 1 is skewed), as pairwise_xcorr_se documents
    rng = np.random.default_rng(7)
    t = np.arange(400) / 400.0
    fast, slow = 1 - np.exp(-t / 0.01), 1 - np.exp(-t / 0.08)

    def draw():
        w = rng.uniform(0.0, 1.0, size=(10, 1))
        return w * fast + (1 - w) * slow + rng.normal(scale=0.02, size=(10, t.size))

    sets = [draw() for _ in range(400)]
    values = np.array([pairwise_xcorr(s) for s in sets])
    ses = np.array([pairwise_xcorr_se(s) for s in sets])
    assert 0.8 < np.mean(ses) / np.std(values, ddof=1) < 1.25
    assert 0.80 <= np.mean(np.abs(values - values.mean()) <= 1.96 * ses) <= 0.93


def test_pairwise_xcorr_readings_match_independent_formulas(rng):
    x = rng.normal(size=(4, 60)).cumsum(axis=1) + 3.0
    pairs = [(i, j) for i in range(4) for j in range(i + 1, 4)]
    raw = np.mean([x[i] @ x[j] / np.sqrt((x[i] @ x[i]) * (x[j] @ x[j])) for i, j in pairs])
    assert pairwise_xcorr(x, "raw") == pytest.approx(raw, rel=1e-12)
    xc = x - x.mean(axis=1, keepdims=True)
    lagged = np.mean([np.max(np.correlate(xc[i], xc[j], mode="full")) / np.sqrt((xc[i] @ xc[i]) * (xc[j] @ xc[j]))
                      for i, j in pairs])
    assert pairwise_xcorr(x, "pearson-max-lag") == pytest.approx(lagged, rel=1e-9)
    # a delayed copy: the best lag recovers it, zero lag does not
    base = np.concatenate([np.zeros(20), np.ones(80)])
    shifted = np.array([base, np.roll(base, 10)])
    assert pairwise_xcorr(shifted, "pearson-max-lag") > pairwise_xcorr(shifted, "pearson") + 0.1
    assert set(XCORR_MODES) == {"pearson", "pearson-max-lag", "raw"}
    with pytest.raises(ParameterError, match="xcorr mode must be one of"):
        pairwise_xcorr(x, "spearman")
    with pytest.raises(ParameterError, match="table3 xcorr must be one of"):
        reproduce_table3(xcorr="spearman")


@settings(max_examples=30, deadline=None)
@given(scale=st.floats(0.01, 100.0), shift=st.floats(-10.0, 10.0), n=st.integers(2, 6))
def test_pairwise_xcorr_is_one_for_affine_copies(scale, shift, n):
    base = np.sin(np.linspace(0.0, 3.0, 40)) + np.linspace(0.0, 1.0, 40)
    x = np.array([base * scale ** (i / n) + shift * i for i in range(n)])
    assert pairwise_xcorr(x) == pytest.approx(1.0, abs=1e-9)


def test_plots_write_png(fig7, table3, tmp_path):
    from forecast_design.plotting.simulation import plot_fig7, plot_table3

    f = plot_fig7(fig7, tmp_path / "fig7.png")
    assert len(f.axes) == 4 and (tmp_path / "fig7.png").stat().st_size > 10_000
    g = plot_table3(table3, tmp_path / "table3.png")
    assert len(g.axes) == 6 and (tmp_path / "table3.png").stat().st_size > 10_000
    with pytest.raises(ParameterError):
        plot_fig7(object())
    import matplotlib.pyplot as plt

    plt.close("all")


def test_cli_reproduce_table3_takes_where_the_derivative_acts(table3, capsys):
    # --derivative-on error: the probe's cells become the rows (the same runs)
    from forecast_design.cli import main

    code = main(["reproduce", "table3", "--derivative-on", "error", "--json"])
    rows = json.loads(capsys.readouterr().out)
    probe = {(m["environment"], m["compensator"]): m["xcorr"] for m in table3.mechanisms
             if m["mechanism"] == "PD derivative on the error"}
    assert code == 0 and len(rows) == 6
    for r in rows:
        assert r["xcorr"] == pytest.approx(probe[(r["environment"], r["compensator"])], rel=1e-12)


def test_cli_reproduce_table3_takes_the_xcorr_reading(table3, capsys):
    from forecast_design.cli import main

    code = main(["reproduce", "table3", "--xcorr", "pearson-max-lag", "--json"])
    rows = json.loads(capsys.readouterr().out)
    readings = {(r["environment"], r["compensator"]): r["pearson-max-lag"] for r in table3.readings}
    assert code == 0 and len(rows) == 6
    for r in rows:
        assert r["xcorr"] == pytest.approx(readings[(r["environment"], r["compensator"])], rel=1e-12)
    for argv, fragment in ((["table3", "--xcorr", "spearman"], "table3 xcorr must be one of"),
                           (["fig7", "--xcorr", "raw"], "--xcorr applies to table3 only"),
                           (["table3", "--derivative-on", "sideways"], "table3 derivative_on must be one of"),
                           (["fig6", "--derivative-on", "error"], "--derivative-on applies to table3 only")):
        code = main(["reproduce", *argv])
        err = capsys.readouterr().err
        assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1
