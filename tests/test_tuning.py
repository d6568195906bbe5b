"""Q-cutoff tuning (casadi NLP) against exact disk margins and an independent scan."""

import dataclasses

import numpy as np
import pytest

from forecast_design import Compensator, ParameterError
from forecast_design.tuning import environment_set, tune_q, tune_q_shape, worst_case_ratio


@pytest.fixture(scope="module")
def paper_set_results():
    return {obs: tune_q(obs, "soft,stiff", min_ratio=0.9, band_hz=(0.5, 30.0))
            for obs in ("ea-fob", "lo-dob", "ld-dob")}


def test_tuned_cutoffs_are_feasible_and_agree_with_dense_scan(paper_set_results):
    for obs, result in paper_set_results.items():
        assert result.feasible, obs
        assert result.agrees_with_scan, obs
        assert result.worst_ratio >= 0.9 - 1e-6
        assert result.w_q_hz >= 0.98 * result.scan_w_q_hz
        assert 0.5 <= result.w_q_hz <= 30.0
        assert result.solver["success"]


def test_ea_fob_tolerates_a_much_faster_q_than_the_dobs(paper_set_results):
    ea = paper_set_results["ea-fob"].w_q_hz
    assert ea >= 5 * paper_set_results["lo-dob"].w_q_hz
    assert ea >= 5 * paper_set_results["ld-dob"].w_q_hz


@pytest.mark.parametrize("observer", ["lo-dob", "ld-dob"])
def test_tuned_cutoff_is_locally_maximal(paper_set_results, observer):
    """Just above the answer the exact worst-case ratio falls below the requirement."""
    result = paper_set_results[observer]
    above, _ = worst_case_ratio(Compensator(kind=observer, w_q_hz=result.w_q_hz * 1.02), "soft,stiff")
    at, _ = worst_case_ratio(Compensator(kind=observer, w_q_hz=result.w_q_hz), "soft,stiff")
    assert at >= 0.9 - 1e-6 > above


def test_uncertainty_can_only_lower_the_cutoff(paper_set_results):
    robust = tune_q("lo-dob", "soft,stiff", uncertainty=0.1, min_ratio=0.9, band_hz=(0.5, 30.0), scan_points=40)
    assert robust.plants == 2 * 9
    assert robust.feasible
    assert robust.w_q_hz <= paper_set_results["lo-dob"].w_q_hz * (1 + 1e-6)


def test_environment_set_vertices_keep_the_belief_nominal():
    pairs = environment_set("stiff", uncertainty=0.2)
    assert len(pairs) == 9
    believed = {bel for _, _, bel in pairs}
    assert len(believed) == 1
    ks = sorted({true.k_e for _, true, _ in pairs})
    np.testing.assert_allclose(ks, [80.0, 100.0, 120.0])
    Js = sorted({round(true.J, 12) for _, true, _ in pairs})
    np.testing.assert_allclose(Js, np.array([0.8, 1.0, 1.2]) * (0.1 + 0.0018))


def test_shape_mode_beats_both_standard_q_families():
    """Maximising over the damping at 10 Hz can only improve on Butterworth and binomial."""
    result = tune_q_shape("ld-dob", "soft,stiff", w_q_hz=10.0)
    butter, _ = worst_case_ratio(Compensator(kind="ld-dob", w_q_hz=10.0), "soft,stiff")
    binom, _ = worst_case_ratio(Compensator(kind="ld-dob", w_q_hz=10.0, q_family="binomial"), "soft,stiff")
    assert butter == 0.0            # the paper's instability: LD-DOB, stiff, 10 Hz
    assert result.worst_ratio >= binom - 1e-9 and result.worst_ratio > butter
    assert 0.3 <= result.q_damping <= 2.0


@pytest.mark.parametrize("kwargs,match", [
    ({"observer": "none"}, "observer kind"),
    ({"observer": "ea-fob", "band_hz": (5.0, 1.0)}, "band"),
    ({"observer": "ea-fob", "min_ratio": 1.5}, "min_ratio"),
    ({"observer": "ea-fob", "envs": "soft,mud"}, "unknown environment 'mud'"),
    ({"observer": "ea-fob", "uncertainty": 1.0}, "uncertainty"),
])
def test_bad_tuning_input_raises_parameter_error(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        tune_q(**kwargs)
