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
    Fig7Choices,
    pairwise_xcorr,
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
    from forecast_design.params import Design, PDController
    from forecast_design.simulation import Square, simulate

    c = fig7.choices
    bare = simulate(Design.nominal(c.environment, controller=PDController()), effects=[Stiction()],
                    reference=Square(high=c.high, low=c.low, period_s=c.period_s), duration_s=c.periods * c.period_s)
    assert fig7.mae_tracking_eafob < np.mean(np.abs(bare.tau_r - bare.tau_s))


def test_fig7_mapping_and_sensitivity_rows(fig7):
    m = fig7.to_mapping()
    assert set(m) == {"mae_friction_sfm", "mae_friction_eafob", "mae_tracking_sfm", "mae_tracking_eafob",
                      "choices", "sensitivity", "explanation"}
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
    # Table 3: the compensated loops are repeatable (paper 0.98-0.99; tolerance 0.02), the EA-FOB
    # is the closest to the frictionless response in both environments, and in the soft environment
    # PD alone is by far the least repeatable (paper 0.73; tolerance 0.15)
    for env in ("exp-soft", "locked"):
        e, s, n = (table3.row(env, k) for k in ("ea-fob", "sfm", "none"))
        assert e.xcorr == pytest.approx(e.paper_xcorr, abs=0.02)
        assert s.xcorr == pytest.approx(s.paper_xcorr, abs=0.02)
        assert e.mae < s.mae and e.mae < n.mae
        assert e.mae <= e.paper_mae + 0.002                    # paper 0.008 / 0.01
        assert s.mae <= s.paper_mae + 0.005                    # paper 0.05 / 0.02
    soft = {k: table3.row("exp-soft", k) for k in ("none", "sfm", "ea-fob")}
    assert soft["none"].xcorr == pytest.approx(0.73, abs=0.15)
    assert soft["none"].xcorr < soft["sfm"].xcorr - 0.2 and soft["none"].xcorr < soft["ea-fob"].xcorr - 0.2


def test_table3_locked_pd_deviation_is_stated(table3):
    # known deviation: with the output locked, the virtual testbed's PD alone is about as repeatable
    # as the compensated loops (paper 0.90); the explanation must say so rather than claim the pattern
    n = table3.row("locked", "none")
    least = n.xcorr < min(table3.row("locked", k).xcorr for k in ("sfm", "ea-fob"))
    assert least or "locked: deviation: PD alone" in table3.explanation
    for r in table3:
        assert f"{r.environment}/{r.compensator}: xcorr {r.xcorr:.3f} (paper {r.paper_xcorr:.2f})" in table3.explanation


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
