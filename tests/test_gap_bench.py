"""Small withheld-effect benchmark: the diagnosis names each effect blind on the virtual testbed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from forecast_design.effects import Effect
from forecast_design.gap.bench import (ANGLE_EFFECTS, BENCH_WORDS, BenchCase, BenchResult, benchmark, draw_case,
                                     identifiability, make_log)


def test_draw_case_is_deterministic_and_keeps_truth_apart():
    a = draw_case(Effect.DELAY, 2, 7)
    b = draw_case(Effect.DELAY, 2, 7)
    assert a == b
    assert a.effects[0].effect is Effect.DELAY
    assert all(abs(e) <= 0.03 for e in a.errors)
    assert draw_case(Effect.NONE, 0, 7).effects == ()
    assert draw_case(Effect.DELAY, 2, 7, attempt=1) != a
    # a locked output cannot show an environment mismatch
    assert all(draw_case(Effect.ENVIRONMENT_MISMATCH, i, 7).environment != "locked" for i in range(10))
    # angle effects only where ~1 N m turns the motor a revolution, with a sweep
    for w in ANGLE_EFFECTS:
        for i in range(6):
            spec = draw_case(w, i, 7)
            assert spec.environment in ("soft", "link-only") and spec.excitation.endswith("sweep")


def test_generated_angle_effect_log_turns_a_revolution():
    spec, exp, res = make_log(Effect.COGGING, 0, 3, duration_s=6.0)
    assert identifiability(spec, res) is None
    assert np.ptp(res.truth.theta) >= 2 * np.pi
    # what the diagnosis sees (encoder angle) covers the same span as the truth
    assert np.ptp(exp.signals.theta) == pytest.approx(np.ptp(res.truth.theta), abs=1e-4)


@pytest.mark.slow
def test_small_benchmark_names_every_withheld_effect():
    res = benchmark(per_effect=1, seed=11, workers=2, duration_s=6.0, progress=False)
    assert len(res.cases) == len(BENCH_WORDS)
    assert res.false_alarms == 0
    assert res.accuracy >= 8 / 9
    assert res.min_true_reduction >= 0.5
    m = json.loads(json.dumps(res.to_mapping()))
    assert sum(sum(row.values()) for row in m["confusion"].values()) == len(BENCH_WORDS)
    # every case says what its log declared, and every score says what it counts
    assert all(c["design"]["duration_s"] == pytest.approx(6.0) and c["design"]["rate_hz"] == 2000.0
               and set(c["design"]) >= {"testbed", "environment"} for c in m["cases"])
    assert set(m["definitions"]) == {"accuracy", "joint_accuracy", "false_alarms", "min_true_reduction",
                                     "hard_honesty"}


def _case(truth, verdict, joint):
    return BenchCase(truth=truth, verdict=verdict, joint=joint, reduction=0.5, true_reduction=0.5,
                     environment="soft", excitation="ol-chirp", effect_params={}, seconds=0.1)


def test_joint_accuracy_counts_only_logs_where_the_attribution_ran():
    # the independent generator diagnoses without the group lasso: no joint score, not 1 in 9 (its none logs)
    skipped = BenchResult(cases=(_case(Effect.NONE, Effect.NONE, None), _case(Effect.DELAY, Effect.DELAY, None)),
                          per_effect=1, seed=0, elapsed_s=1.0, generator="independent")
    assert skipped.accuracy == 1.0 and skipped.joint_accuracy is None
    m = json.loads(json.dumps(skipped.to_mapping()))
    assert m["joint_accuracy"] is None and all(c["joint"] is None for c in m["cases"])
    ran = BenchResult(cases=(_case(Effect.NONE, Effect.NONE, ()), _case(Effect.DELAY, Effect.DELAY, (Effect.COULOMB,)),
                             _case(Effect.COULOMB, Effect.COULOMB, None)), per_effect=1, seed=0, elapsed_s=1.0)
    assert ran.joint_accuracy == pytest.approx(0.5)
