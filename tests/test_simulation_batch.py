"""Batched Monte-Carlo simulation: every run of a batch equals the single-run simulator exactly."""

import numpy as np
import pytest

from forecast_design.effects import Cogging, Delay, EnvironmentMismatch, PositionFriction, Stiction, TorqueGain
from forecast_design.environments import environment_preset
from forecast_design.errors import ParameterError
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.simulation import Sine, Square, TorqueSensor, simulate
from forecast_design.simulation.batch import MEASURED, TRUE, BatchRun, simulate_batch, simulate_scenario
from forecast_design.simulation.scenario import Variability, scenario_from_mapping

REF = Square(high=0.5, low=-0.5, period_s=0.1)


def _runs() -> list[BatchRun]:
    """Runs that differ in everything a run may: environment, compensator, effects, seed, angle, reference."""
    sfm = {"viscous": 0.3, "coulomb": 0.35, "sin1": 0.02, "coulomb_cos2": 0.01}
    cases = [
        ("fig7", Compensator(kind="ea-fob", w_q_hz=10.0),
         (Stiction(F_s_a=(0.05, 0.0), F_s_b=(0.0, 0.02), v_s_a=(0.3,), v_s_b=(0.1,)),)),
        ("soft", Compensator(kind="none"), (Cogging(a=(0.02, 0.01, 0.005), b=(0.0, 0.004, 0.0)), Delay(delay_s=1e-3))),
        ("locked", Compensator(kind="lo-dob", w_q_hz=5.0), (Stiction(), TorqueGain(gain=0.9))),
        ("exp-soft", Compensator(kind="sfm", friction=sfm), (PositionFriction(F_c=0.1, a=(0.03,), b=(0.02,)),)),
        ("stiff", Compensator(kind="ld-dob", w_q_hz=3.0), (EnvironmentMismatch(k_e_scale=1.5), Stiction(F_s=0.6))),
    ]
    runs = []
    for i, (env, comp, effects) in enumerate(cases):
        design = Design.nominal(env, controller=PD(P=5.0 - 0.5 * i), compensator=comp)
        runs.append(BatchRun(design=design, effects=effects, seed=10 + i, initial_angle=0.7 * i,
                             reference=Sine(amplitude=0.3, frequency_hz=3.0) if i == 2 else None))
    return runs


def _assert_same(a, b):
    for name in MEASURED:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for name in TRUE:
        assert np.array_equal(getattr(a.truth, name), getattr(b.truth, name)), name
    assert np.array_equal(a.tau_r, b.tau_r)
    assert a.options == b.options and a.design == b.design and a.truth.effects == b.truth.effects


def test_every_run_equals_simulate_bit_for_bit():
    runs = _runs()
    batch = simulate_batch(runs, duration_s=0.3, reference=REF, torque_limit=8.0)
    assert len(batch) == len(runs) and batch.measured.shape == (len(runs), 600, 6)
    for i, run in enumerate(runs):
        single = simulate(run.design, reference=run.reference or REF, duration_s=0.3, effects=run.effects,
                          seed=run.seed, initial_angle=run.initial_angle, torque_limit=8.0)
        _assert_same(batch.result(i), single)
        assert np.array_equal(batch.column("tau_s")[i], single.tau_s)
        assert np.array_equal(batch.true_column("tau_frc")[i], single.truth.tau_frc)


def test_open_loop_batch_and_thread_count_do_not_change_results():
    runs = [BatchRun(design=Design.nominal("exp-soft"), effects=(Stiction(F_s_a=(0.1,), F_s_b=(0.05,)),), seed=s,
                     initial_angle=float(s)) for s in range(3)]
    one = simulate_batch(runs, duration_s=0.2, reference=Sine(amplitude=1.0, frequency_hz=2.0), closed_loop=False,
                         threads=1)
    two = simulate_batch(runs, duration_s=0.2, reference=Sine(amplitude=1.0, frequency_hz=2.0), closed_loop=False)
    assert np.array_equal(one.measured, two.measured) and np.array_equal(one.true, two.true)
    single = simulate(runs[1].design, reference=Sine(amplitude=1.0, frequency_hz=2.0), duration_s=0.2,
                      effects=runs[1].effects, seed=1, initial_angle=1.0, closed_loop=False)
    _assert_same(one.result(1), single)
    # different angles see different stiction levels: the runs differ
    assert not np.array_equal(one.true[0], one.true[2])



def test_batches_from_two_threads_at_once_equal_the_main_thread_batch():
    # worker threads (e.g. a Dask worker's) run their batches without numba's pool, which two
    # threads must not enter at once; the results are the main thread's
    from concurrent.futures import ThreadPoolExecutor

    runs = _runs()[:3]
    main = simulate_batch(runs, duration_s=0.1, reference=REF)
    with ThreadPoolExecutor(2) as pool:
        got = list(pool.map(lambda k: simulate_batch(runs, duration_s=0.1, reference=REF), range(4)))
    for b in got:
        assert np.array_equal(b.measured, main.measured) and np.array_equal(b.true, main.true)

def _variability_doc() -> dict:
    return {"format": "forecast-scenario/1", "sampling": {"rate_hz": 2000.0},
           "testbed": Design.nominal().testbed.to_mapping(), "environment": environment_preset("exp-soft").to_mapping(),
           "controller": {"kind": "pd", "P": 5.0, "D": 0.1}, "compensator": {"kind": "ea-fob", "w_q_hz": 8.0},
           "truth": {"effects": [Stiction(F_s=0.7, F_s_a=(0.2,), F_s_b=(0.0,), v_s_a=(0.5,), v_s_b=(0.2,)).to_mapping()]},
           "variability": {"repetitions": 3, "initial_angle": "random", "seed": 4, "viscous_drift": 0.05},
           "reference": {"kind": "square", "high": 0.4, "low": -0.4, "period_s": 0.1},
           "simulation": {"duration_s": 0.2, "seed": 7}}


def test_scenario_repetitions_equal_scenario_run():
    sc = scenario_from_mapping(_variability_doc())
    batch = simulate_scenario(sc)
    assert len(batch) == 3
    for i in range(3):
        _assert_same(batch.result(i), sc.run(i))
        assert batch.result(i).truth.initial_angle == Variability(repetitions=3, seed=4).initial_angles()[i]


def test_bad_batches_name_the_problem():
    run = BatchRun(design=Design.nominal("soft"))
    with pytest.raises(ParameterError, match="at least one run"):
        simulate_batch([], duration_s=0.1, reference=REF)
    with pytest.raises(ParameterError, match="unknown batch option 'seed'"):
        simulate_batch([run], duration_s=0.1, reference=REF, seed=3)
    with pytest.raises(ParameterError, match="run 0 has no reference"):
        simulate_batch([run], duration_s=0.1)
    with pytest.raises(ParameterError, match=r"run 1: .*duration_s|run 0: .*duration_s"):
        simulate_batch([run, run], duration_s=-1.0, reference=REF)
    with pytest.raises(ParameterError, match="threads"):
        simulate_batch([run], duration_s=0.1, reference=REF, threads=0)
    batch = simulate_batch([run], duration_s=0.01, reference=REF)
    with pytest.raises(ParameterError, match="run index"):
        batch.result(1)
    with pytest.raises(ParameterError, match="unknown measured column 'omega'"):
        batch.column("omega")


def test_one_repetition_rule_for_run_and_batch():
    """Scenario.repetition is the rule: angle i of Variability, seed + i, drifted effects."""
    sc = scenario_from_mapping(_variability_doc())
    angles = Variability(repetitions=3, seed=4).initial_angles()
    assert sc.repetition_count == 3
    for i in range(3):
        rep = sc.repetition(i)
        assert (rep.seed, rep.initial_angle) == (7 + i, angles[i])
        assert rep.effects == tuple(sc.variability.effects_of(sc.effects, i))
    assert sc.repetition(2).effects[0].sigma2 == pytest.approx(sc.effects[0].sigma2 * (1 + 0.05 * 2))
    with pytest.raises(ParameterError, match=r"repetition must be in 0\.\.2"):
        sc.repetition(3)
    plain = scenario_from_mapping({k: v for k, v in _variability_doc().items() if k != "variability"})
    assert plain.repetition_count == 1 and plain.repetition(0).seed == 7
    with pytest.raises(ParameterError, match="no \\[variability\\]"):
        plain.repetition(1)


def test_simulate_verb_writes_every_repetition_as_the_batch_computes_it(tmp_path, capsys):
    import json
    import tomli_w

    from forecast_design.cli import main
    from forecast_design.experiment import load_experiment

    scenario = tmp_path / "var.toml"
    scenario.write_text(tomli_w.dumps(_variability_doc()))
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "run.toml"), "--repetitions", "all",
                 "--json", str(tmp_path / "out.json")]) == 0
    sc = scenario_from_mapping(_variability_doc())
    report = json.loads((tmp_path / "out.json").read_text())
    assert [r["repetition"] for r in report["repetitions"]] == [0, 1, 2]
    for i in range(3):
        written = load_experiment(tmp_path / f"run_{i:03d}.toml")
        single = sc.run(i).to_experiment()
        for name, column in single.signals.columns().items():
            assert np.array_equal(written.signals.columns()[name], column), (i, name)
        assert (tmp_path / f"run_{i:03d}.truth.csv").is_file()
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "x.toml"), "--repetitions", "4"]) == 2
    assert "--repetitions must be 'all' or an integer in 1..3" in capsys.readouterr().err


def test_a_batch_with_a_torque_sensor_equals_simulate_bit_for_bit():
    runs = _runs()[:3]
    sensor = TorqueSensor(noise_std_N_m=2e-3, gain=0.95, offset_N_m=0.01)
    batch = simulate_batch(runs, duration_s=0.2, reference=REF, torque_sensor=sensor)
    for i, run in enumerate(runs):
        single = simulate(run.design, reference=run.reference or REF, duration_s=0.2, effects=run.effects,
                          seed=run.seed, initial_angle=run.initial_angle, torque_sensor=sensor)
        _assert_same(batch.result(i), single)
        assert 1e-3 < np.std(single.tau_s - 0.95 * single.truth.tau_s) < 3e-3


def test_a_batch_with_encoder_jitter_equals_simulate_bit_for_bit():
    runs = _runs()[:3]
    batch = simulate_batch(runs, duration_s=0.2, reference=REF, encoder_counts=2**16, encoder_jitter_counts=0.6)
    for i, run in enumerate(runs):
        single = simulate(run.design, reference=run.reference or REF, duration_s=0.2, effects=run.effects,
                          seed=run.seed, initial_angle=run.initial_angle, encoder_counts=2**16,
                          encoder_jitter_counts=0.6)
        _assert_same(batch.result(i), single)
        # a reading more than half a count off the true angle: the jitter is there
        assert np.max(np.abs(single.theta - single.truth.theta)) > 2 * np.pi / 2**16
