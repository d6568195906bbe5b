"""Small withheld-effect benchmark: the diagnosis names each effect blind on the virtual testbed."""

from __future__ import annotations

import json

import pytest

from forecast_design.effects import Effect
from forecast_design.gap.bench import BENCH_WORDS, benchmark, draw_case


def test_draw_case_is_deterministic_and_keeps_truth_apart():
    a = draw_case(Effect.DELAY, 2, 7)
    b = draw_case(Effect.DELAY, 2, 7)
    assert a == b
    assert a.effects[0].effect is Effect.DELAY
    assert all(abs(e) <= 0.03 for e in a.errors)
    assert draw_case(Effect.NONE, 0, 7).effects == ()
    # a locked output cannot show an environment mismatch
    assert all(draw_case(Effect.ENVIRONMENT_MISMATCH, i, 7).environment != "locked" for i in range(10))


@pytest.mark.slow
def test_small_benchmark_names_every_withheld_effect():
    res = benchmark(per_effect=1, seed=11, workers=2, duration_s=6.0, progress=False)
    assert len(res.cases) == len(BENCH_WORDS)
    assert res.false_alarms == 0
    assert res.accuracy >= 8 / 9
    assert res.min_true_reduction >= 0.5
    m = json.loads(json.dumps(res.to_mapping()))
    assert sum(sum(row.values()) for row in m["confusion"].values()) == len(BENCH_WORDS)
