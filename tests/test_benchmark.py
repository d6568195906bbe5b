"""Benchmark over an environment set: indicators, aggregation, tables, the verb; run-to-run variability."""

import json
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.benchmark import (BenchmarkSpec, parse_compensators, parse_controller, parse_reference,
                                       repeatability_per_run, result_rows, result_table, run_benchmark,
                                       step_metrics, tracking_bandwidth_hz)
from forecast_design.benchmark.metrics import pairwise_xcorr, xcorr_se_from_per_run
from forecast_design.cli import main
from forecast_design.effects import Stiction
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.friction.laws import stribeck_level
from forecast_design.controllers import PD
from forecast_design.params import Design, environment_preset
from forecast_design.simulation import simulate
from forecast_design.simulation.plant import _bristle_rate, build_plant
from forecast_design.simulation.scenario import Variability, scenario_from_mapping

control = pytest.importorskip("control")


# --- indicators -------------------------------------------------------------------------------


def _step_info_relative_to_the_step(t, y, amplitude):
    """python-control's step_info read with the benchmark's conventions: the final value is the mean of
    the last 10 %, the settling band 2 % of the reference step |A| (a threshold relative to y_f of
    0.02 |A| / |y_f|), overshoot rescaled from y_f to |A|; settled when the band holds over that window."""
    window = int(y.size * 0.1)
    yf = float(np.mean(y[-window:]))
    info = control.step_info(y, t, yfinal=yf, SettlingTimeThreshold=0.02 * abs(amplitude) / abs(yf),
                             RiseTimeLimits=(0.1, 0.9))
    settled = math.isfinite(info["SettlingTime"]) and info["SettlingTime"] <= t[y.size - window]
    return {"rise_time_s": info["RiseTime"], "overshoot_percent": info["Overshoot"] * abs(yf) / abs(amplitude),
            "settling_time_s": info["SettlingTime"] if settled else math.nan, "settled": settled,
            "steady_state_error_N_m": amplitude - yf}


def test_step_metrics_match_python_control_step_info():
    # a second-order step response, closed form, checked against python-control's step_info
    wn, zeta = 20.0, 0.3
    sys_ = control.tf([0.8 * wn**2], [1.0, 2 * zeta * wn, wn**2])
    t = np.linspace(0.0, 3.0, 6001)
    _, y = control.step_response(sys_, t)
    y = 0.2 * y                                   # response to a 0.2 N m step of gain 0.8 -> 0.16
    m = step_metrics(t, y, amplitude=0.2)
    ref = _step_info_relative_to_the_step(t, y, 0.2)
    assert m["settled"] and ref["settled"]
    assert m["rise_time_s"] == pytest.approx(ref["rise_time_s"], abs=2 * (t[1] - t[0]))
    assert m["overshoot_percent"] == pytest.approx(ref["overshoot_percent"], rel=1e-3)
    assert m["settling_time_s"] == pytest.approx(ref["settling_time_s"], abs=2 * (t[1] - t[0]))
    assert m["steady_state_error_N_m"] == pytest.approx(0.2 - 0.16, abs=1e-6)
    # closed-form overshoot of a 2nd-order system, relative to the step: 0.8 exp(-zeta pi / sqrt(1 - zeta^2))
    assert m["overshoot_percent"] == pytest.approx(
        0.8 * 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), rel=1e-3)


def test_a_run_that_never_settles_has_no_settling_time():
    # a sustained oscillation of 5 % of the step around 0.16 N m: never within 2 % of the step
    t = np.linspace(0.0, 1.0, 2001)
    y = 0.16 * (1 - np.exp(-t / 0.02)) + 0.01 * np.sin(2 * math.pi * 7.3 * t)
    m = step_metrics(t, y, amplitude=0.2)
    ref = _step_info_relative_to_the_step(t, y, 0.2)
    assert not m["settled"] and not ref["settled"]
    assert math.isnan(m["settling_time_s"]) and math.isnan(ref["settling_time_s"])
    # entering the band only near the end is not settling either: the band must hold over the final window
    late = np.where(t < 0.95, 0.16 + 0.01 * np.sin(2 * math.pi * 7.3 * t), 0.16)
    m = step_metrics(t, late, amplitude=0.2)
    assert not m["settled"] and math.isnan(m["settling_time_s"])


@settings(max_examples=60, deadline=None)
@given(final=st.floats(1e-4, 0.5), peak=st.floats(0.0, 0.5), amplitude=st.sampled_from([0.2, -0.2, 1.0]))
def test_overshoot_is_bounded_by_the_excursion_relative_to_the_step(final, peak, amplitude):
    # a run that rises to final + peak and falls back to a final value however small: its overshoot is
    # the excursion over the reference step, never the excursion over its own (tiny) final value
    t = np.linspace(0.0, 1.0, 1001)
    sign = math.copysign(1.0, amplitude)
    y = sign * (final + peak * np.exp(-((t - 0.05) / 0.01) ** 2))
    m = step_metrics(t, y, amplitude=amplitude)
    excursion = float(np.max(sign * y) - np.mean(sign * y[-100:]))
    assert m["overshoot_percent"] == pytest.approx(100 * excursion / abs(amplitude), rel=1e-9, abs=1e-9)
    assert m["overshoot_percent"] <= 100 * peak / abs(amplitude) + 1e-9


def test_tracking_bandwidth_of_the_frictionless_loop_matches_its_transfer_function():
    # chirp on the frictionless virtual testbed (stiff environment) vs the -3 dB point of the
    # continuous closed loop tau_s/tau_r = C P / (1 + C P) from python-control
    env = environment_preset("stiff")
    ref, dur = parse_reference("chirp:0.2:0.5:40:8")
    r = simulate(Design.nominal("stiff", controller=PD(P=5.0, D=0.1)), reference=ref, duration_s=dur,
                 include_nominal_viscous=False, process_noise_std=0.0, encoder_counts=None)
    bw = tracking_bandwidth_hz(r.tau_r, r.tau_s, 2000.0, 0.5, 40.0)
    tb = Design.nominal().testbed
    s = control.tf("s")
    J, d, ke = env.J, env.d, env.k_e
    E = J * s**2 + d * s + ke
    # tau_s / tau_m of the SEA with the environment (J_m, d_m = 0 here, k, environment E)
    P = tb.k * E / ((tb.J_m * s**2) * (E + tb.k) + tb.k * E)
    C = 5.0 + 0.1 * s * (2 * math.pi * 200) / (s + 2 * math.pi * 200)
    T = control.feedback(C * P, 1)
    w = np.geomspace(2 * math.pi * 0.5, 2 * math.pi * 40, 4000)
    mag = np.abs(T(1j * w))
    target = np.mean(np.abs(T(1j * w[:2]))) / math.sqrt(2)
    bw_tf = w[np.nonzero(mag < target)[0][0]] / (2 * math.pi) if np.any(mag < target) else 40.0
    assert bw == pytest.approx(bw_tf, rel=0.15)


def test_repeatability_per_run_averages_to_the_pairwise_xcorr(rng):
    x = rng.normal(size=(5, 80)).cumsum(axis=1)
    assert np.mean(repeatability_per_run(x)) == pytest.approx(pairwise_xcorr(x), rel=1e-12)


@pytest.mark.parametrize("text,match", [("pi:5:0.1", "pd:P:D"), ("pd:5", "pd:P:D"), ("pd:x:0.1", "not a decimal number")])
def test_bad_controller_is_one_line(text, match):
    with pytest.raises(ParameterError, match=match):
        parse_controller(text)


def test_parsing_compensators_and_references():
    comps = parse_compensators(["none,sfm", "ea-fob:20,none"])
    assert [c.kind for c in comps] == ["none", "sfm", "ea-fob"] and comps[2].w_q_hz == 20.0
    with pytest.raises(ParameterError, match="kind must be one of"):
        parse_compensators("none,magic")
    ref, dur = parse_reference("step:0.3", duration_s=2.0)
    assert ref.amplitude == 0.3 and dur == 2.0
    for bad in ("step", "chirp:0.2:1", "ramp:1", "step:0"):
        with pytest.raises(ParameterError, match="--reference"):
            parse_reference(bad)


# --- runner and aggregation ---------------------------------------------------------------------


def _spec(**kw):
    base = dict(controllers=(PD(P=5.0, D=0.1),), compensators=parse_compensators("none,ea-fob"),
                environments=(("exp-soft", environment_preset("exp-soft")), ("locked", environment_preset("locked"))),
                references=(parse_reference("step:0.2:0.5"),), repetitions=3)
    base.update(kw)
    return BenchmarkSpec(**base)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    cells, info = run_benchmark(_spec(), out=out)
    return out, cells, info


def test_cells_are_keyed_by_their_inputs_and_reruns_reuse_them(bench):
    out, cells, info = bench
    assert info["computed"] == 4 and info["reused"] == 0
    again, info2 = run_benchmark(_spec(), out=out)
    assert info2["computed"] == 0 and info2["reused"] == 4
    for a, b in zip(again, cells):
        assert json.dumps(a.to_mapping(), sort_keys=True) == json.dumps(b.to_mapping(), sort_keys=True)
        assert np.array_equal(a.tau_s, b.tau_s)
    # a changed input (more repetitions) is a different cell
    _, info3 = run_benchmark(_spec(repetitions=4), out=out)
    assert info3["computed"] == 4


def test_aggregates_are_the_mean_best_and_worst_of_their_rows(bench):
    _, cells, _ = bench
    rows = result_rows(cells)
    runs = [r for r in rows if r["kind"] == "run"]
    assert len(runs) == 4 * 3
    for cell in cells:
        lab = cell.labels
        mine = [r for r in runs if all(r[k] == lab[k] for k in ("compensator", "environment"))]
        env = {r["statistic"]: r for r in rows if r["kind"] == "environment"
               and all(r[k] == lab[k] for k in ("compensator", "environment"))}
        assert env["mean"]["mae_N_m"] == pytest.approx(np.mean([r["mae_N_m"] for r in mine]), rel=1e-12)
        assert env["best"]["mae_N_m"] == min(r["mae_N_m"] for r in mine)
        assert env["worst"]["mae_N_m"] == max(r["mae_N_m"] for r in mine)
        assert env["mean"]["repeatability"] == pytest.approx(cell.repeatability, rel=1e-12)
        # the mean's standard error over the repetitions: std/sqrt(n) of the runs; the jackknife (its
        # closed form from the runs' mean correlations, checked against the brute-force jackknife in
        # test_reproduce) for the repeatability; 0 for the one loop's disk margin
        maes = np.array([r["mae_N_m"] for r in mine])
        assert env["se"]["mae_N_m"] == pytest.approx(np.std(maes, ddof=1) / np.sqrt(maes.size), rel=1e-12)
        assert env["se"]["repeatability"] == pytest.approx(
            xcorr_se_from_per_run(np.array([r["repeatability"] for r in mine])), rel=1e-12)
        assert env["se"]["disk_margin"] == 0.0
    sets = {(r["compensator"], r["statistic"]): r for r in rows if r["kind"] == "set"}
    env_means = [r for r in rows if r["kind"] == "environment" and r["statistic"] == "mean" and r["compensator"] == "none"]
    assert sets[("none", "worst")]["mae_N_m"] == max(r["mae_N_m"] for r in env_means)
    assert sets[("none", "best")]["repeatability"] == max(r["repeatability"] for r in env_means)
    env_ses = [r for r in rows if r["kind"] == "environment" and r["statistic"] == "se" and r["compensator"] == "none"]
    assert sets[("none", "se")]["mae_N_m"] == pytest.approx(
        np.sqrt(sum(r["mae_N_m"] ** 2 for r in env_ses)) / len(env_ses), rel=1e-12)


def test_the_eafob_beats_pd_alone_over_the_set(bench):
    # Section 7's claim, over the set: closer to the frictionless response and more repeatable
    _, cells, _ = bench
    sets = {r["compensator"]: r for r in result_rows(cells) if r["kind"] == "set" and r["statistic"] == "mean"}
    assert sets["ea-fob:10"]["mae_N_m"] < sets["none"]["mae_N_m"]
    assert sets["ea-fob:10"]["repeatability"] > sets["none"]["repeatability"]


def test_a_pd_with_its_derivative_on_the_measurement_is_benchmarked_against_the_same_expected_response():
    # derivative_on = "measurement" is the controller's own: no kick at the step in the runs nor in the
    # frictionless expected response (the MAE compares like with like); the cells get their own keys
    from forecast_design.benchmark.runner import run_cell

    plain = _spec(repetitions=2)
    meas = _spec(repetitions=2, controllers=(PD(P=5.0, D=0.1, derivative_on="measurement"),))
    cell, cell_m = plain.cells()[2], meas.cells()[2]                  # none, locked
    assert meas.cell_key(cell_m, None) != plain.cell_key(cell, None)
    assert cell_m.labels["controller"] == "pd:5:0.1:derivative_on=measurement"
    res = run_cell((meas.cell_key(cell_m, None), cell_m, meas, None))
    kick = run_cell((plain.cell_key(cell, None), cell, plain, None))
    # the kick's 200 N m command (D x 0.2 N m x 2000 Hz, one period) lifts tau_s at once; without it
    # the rise starts slowly
    assert res.expected[2] < 0.5 * kick.expected[2]
    assert np.all(np.isfinite([r["mae_N_m"] for r in res.runs]))
    with pytest.raises(ParameterError, match="derivative_on must be one of"):
        PD(P=5.0, D=0.1, derivative_on="setpoint")


def test_the_same_controller_twice_is_refused():
    with pytest.raises(ParameterError, match="controllers repeated: pd:5:0.1"):
        _spec(controllers=(PD(P=5.0, D=0.1), PD(P=5.0, D=0.1)))


def test_bad_spec_is_one_line():
    with pytest.raises(ParameterError, match="repetitions must be an integer >= 2"):
        _spec(repetitions=1)
    with pytest.raises(ParameterError, match="unique"):
        _spec(environments=(("a", environment_preset("soft")), ("a", environment_preset("stiff"))))


# --- the verb -------------------------------------------------------------------------------------


def test_benchmark_verb_writes_table_plots_report_and_json(tmp_path, capsys):
    envs = tmp_path / "set.toml"
    envs.write_text('[[environment]]\nname = "k"\nJ_e = 0.01\nk_e = {log = [1.0, 100.0], n = 2}\n')
    out = tmp_path / "out"
    args = ["benchmark", "--controller", "pd:5:0.1", "--compensator", "none,ea-fob", "--envs", str(envs),
            "--repetitions", "2", "--reference", "step:0.2:0.4", "--reference", "chirp:0.1:1:20:3",
            "--out", str(out), "--workers", "1", "--json", str(tmp_path / "s.json")]
    assert main(args) == 0
    df = pd.read_parquet(out / "results.parquet")
    assert set(df["kind"]) == {"run", "environment", "set"}
    assert len(df[df["kind"] == "run"]) == 2 * 2 * 2 * 2
    chirp = df[(df["kind"] == "run") & df["reference"].str.startswith("chirp")]
    assert chirp["bandwidth_hz"].notna().all() and chirp["rise_time_s"].isna().all()
    csv = pd.read_csv(out / "results.csv")
    assert np.allclose(csv["mae_N_m"].to_numpy(), df["mae_N_m"].to_numpy(), equal_nan=True, rtol=0, atol=0)
    for name in ("indicators.png", "overlays.png", "heatmap.png", "report.md", "summary.json"):
        assert (out / name).stat().st_size > 500
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["run"]["computed"] == 8 and {r["statistic"] for r in summary["set"]} == {"mean", "se", "best", "worst"}
    capsys.readouterr()
    assert main(args[:-2] + ["--no-plots"]) == 0
    assert "0 cells computed, 8 reused" in capsys.readouterr().out


@pytest.mark.parametrize("extra,match", [(["--controller", "pd:5"], "pd:P:D"),
                                         (["--compensator", "none,fob"], "kind must be one of"),
                                         (["--repetitions", "1"], "repetitions"),
                                         (["--envs", "moon"], "moon"),
                                         (["--scheduler", "nowhere"], "tcp://HOST:PORT"),
                                         (["--derivative-on", "sideways"], "--derivative-on"),
                                         (["--controller", "tf:1,2,3/1,1"], "improper"),
                                         (["--controller", "other:my law"], "has no equations")])
def test_benchmark_verb_bad_input_exits_2_with_one_line(tmp_path, capsys, extra, match):
    assert main(["benchmark", "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err


# --- run-to-run variability ------------------------------------------------------------------------


def test_stribeck_velocity_follows_its_angle_harmonics():
    # v_s(theta) = v_s exp(c sin theta + d cos theta): the kernel's bristle level equals the one
    # friction law evaluated at that v_s
    st = Stiction(F_s=0.7, v_s=0.05, v_s_a=(1.2,), v_s_b=(0.5,))
    plant = build_plant(Design.nominal("locked"), (st,), initial_angle=0.3)
    for theta, v in ((0.0, 0.02), (1.0, -0.1), (2.5, 0.3)):
        th = theta + 0.3
        vs = 0.05 * math.exp(1.2 * math.sin(th) + 0.5 * math.cos(th))
        rate, g = _bristle_rate(theta, v, plant.params, plant.harmonics)
        assert g == pytest.approx(stribeck_level(v, 0.7, 0.4, vs), rel=1e-12)
        assert rate == pytest.approx(260.0 * abs(v) / g, rel=1e-12)


def test_variability_angles_and_drift():
    v = Variability(repetitions=5, seed=3, viscous_drift=0.1)
    a = v.initial_angles()
    assert np.array_equal(a, np.random.default_rng(3).uniform(0.0, 2 * math.pi, 5))
    assert np.all(Variability(repetitions=3, initial_angle="fixed").initial_angles(1.5) == 1.5)
    eff = v.effects_of((Stiction(),), 4)
    assert eff[0].sigma2 == pytest.approx(0.1 * 1.4)
    with pytest.raises(ParameterError, match="viscous_drift"):
        Variability(repetitions=3, viscous_drift=-0.6)


def test_scenario_variability_table_round_trips_and_runs_differ():
    doc = {"format": "forecast-scenario/1", "sampling": {"rate_hz": 2000.0},
           "testbed": Design.nominal().testbed.to_mapping(), "environment": environment_preset("exp-soft").to_mapping(),
           "controller": {"kind": "pd", "P": 5.0, "D": 0.1},
           "truth": {"effects": [Stiction(F_s=0.7, F_s_a=(0.2,), F_s_b=(0.0,)).to_mapping()]},
           "variability": {"repetitions": 3, "initial_angle": "random", "seed": 1},
           "reference": {"kind": "step", "amplitude": 0.2}, "simulation": {"duration_s": 0.3}}
    sc = scenario_from_mapping(doc)
    assert scenario_from_mapping(sc.to_mapping()) == sc
    runs = sc.runs()
    assert [r.truth.initial_angle for r in runs] == list(Variability(repetitions=3, seed=1).initial_angles())
    assert not np.array_equal(runs[0].tau_s, runs[1].tau_s)
    bad = dict(doc, variability={"repetitions": 3, "angle": "random"})
    with pytest.raises(ExperimentFormatError, match=r"\[variability\] unknown key 'angle'"):
        scenario_from_mapping(bad, source="s.toml")


# --- recorded runs (benchmark --runs DIR) ----------------------------------------------------------


def _simulated_runs(folder, spec):
    """Save each cell's repetitions as experiments, simulated exactly as run_cell simulates them."""
    from forecast_design.simulation import save_simulation

    var = Variability(repetitions=spec.repetitions, seed=spec.seed)
    for cell in spec.cells():
        design = Design(environment=cell.environment, controller=cell.controller, compensator=cell.compensator)
        for i, a in enumerate(var.initial_angles()):
            r = simulate(design, reference=cell.reference, duration_s=cell.duration_s, effects=spec.effects,
                         initial_angle=float(a), seed=spec.seed + 1 + i)
            name = f"{cell.environment_name}-{cell.compensator.kind}-{i}.toml"
            save_simulation(r, folder / cell.environment_name / name)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from forecast_design.simulation import save_simulation

    folder = tmp_path_factory.mktemp("runs")
    spec = _spec(repetitions=3)
    _simulated_runs(folder, spec)
    # an open-loop run (skipped) and a TOML that is not an experiment (ignored)
    ol = simulate(Design.nominal("link-only"), reference=np.full(200, 0.5), duration_s=0.1, closed_loop=False)
    save_simulation(ol, folder / "open-loop.toml")
    (folder / "set.toml").write_text('[[environment]]\nname = "a"\nk_e = 5.0\nJ_e = 0.001\n')
    return folder, spec


def test_recorded_runs_are_grouped_by_their_toml_and_give_the_simulated_cells_indicators(recorded):
    # the same runs benchmarked from their experiment files (TOML + CSV, 17 digits) and on the virtual
    # testbed give the same indicators: one implementation of the metrics, exact CSV round trip
    from forecast_design.benchmark import run_recorded

    folder, spec = recorded
    cells, info = run_recorded(folder)
    assert info["runs"] == 13 and info["cells"] == 4 and len(info["skipped"]) == 1
    assert "open-loop.toml" in info["skipped"][0]
    simulated = {tuple(c.labels.values()): c for c in run_benchmark(spec)[0]}
    for c in cells:
        sim = simulated[tuple(c.labels.values())]          # labels (incl. step:0.2:0.5) match
        assert len(c.runs) == 3
        assert c.repeatability == pytest.approx(sim.repeatability, rel=1e-12)
        assert c.disk_margin == pytest.approx(sim.disk_margin, rel=1e-12)
        for mine, theirs in zip(c.runs, sim.runs):
            for m in ("mae_N_m", "rise_time_s", "overshoot_percent", "settling_time_s", "steady_state_error_N_m",
                      "repeatability"):
                assert mine[m] == pytest.approx(theirs[m], rel=1e-9, abs=1e-12), m
            assert math.isnan(mine["initial_angle_rad"])


def test_benchmark_verb_on_recorded_runs_writes_the_table_and_reuses_cells(recorded, tmp_path, capsys):
    folder, _ = recorded
    out = tmp_path / "out"
    assert main(["benchmark", "--runs", str(folder), "--out", str(out), "--no-plots", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "note: skipped" in captured.err and "4 cells computed, 0 reused" in captured.out
    df = pd.read_parquet(out / "results.parquet")
    assert len(df[df["kind"] == "run"]) == 12
    assert set(df[df["kind"] == "run"]["environment"]) == {"exp-soft", "locked"}
    assert "recorded runs from" in (out / "report.md").read_text()
    assert main(["benchmark", "--runs", str(folder), "--out", str(out), "--no-plots", "--workers", "1"]) == 0
    assert "0 cells computed, 4 reused" in capsys.readouterr().out


@pytest.mark.parametrize("extra,match", [(["--runs", "nowhere"], "not a folder"),
                                         (["--runs", ".", "--controller", "pd:5:0.1"], "drop --controller")])
def test_benchmark_runs_bad_input_is_one_line(tmp_path, capsys, extra, match):
    assert main(["benchmark", "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err


def test_a_folder_without_closed_loop_runs_is_a_one_line_error(tmp_path, capsys):
    (tmp_path / "x.toml").write_text("a = 1\n")
    assert main(["benchmark", "--runs", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "no closed-loop experiment" in capsys.readouterr().err


SMALL_SEA = "J_m=0.0008,d_m=0.002,k=300"   # a user's small SEA: 166x less inertia, 5x stiffer spring


def test_a_users_testbed_is_benchmarked_on_itself_with_the_substeps_its_plant_needs(tmp_path, capsys):
    from forecast_design.environments import resolve_environments, resolve_testbed
    from forecast_design.reproduce import TABLE3_TRUTH
    from forecast_design.simulation.plant import stability_check, stable_substeps

    small = resolve_testbed(SMALL_SEA)
    env = resolve_environments("stiff", testbed=small).single("stiff")[1]
    design = Design(testbed=small, environment=env)
    # the Table 3 hardware's bristles are too stiff for 10 RK4 substeps on this inertia
    with pytest.raises(ParameterError, match="unstable"):
        stability_check(build_plant(design, TABLE3_TRUTH, substeps=10))
    n = stable_substeps(design, TABLE3_TRUTH)
    assert n > 10 and stability_check(build_plant(design, TABLE3_TRUTH, substeps=n))["max_growth"] <= 1.0
    assert stable_substeps(Design.nominal("stiff"), TABLE3_TRUTH) == 10       # the paper's testbed: unchanged

    out = tmp_path / "bm"
    # a PD with a 200 Hz derivative filter, Tustin-discretised: its sampled loop on this SEA is unstable
    code = main(["benchmark", "--controller", "pd:2:0.001:0.0007957747154594767:discretization=tustin",
                 "--compensator", "none,sfm", "--testbed", SMALL_SEA,
                 "--envs", "stiff", "--repetitions", "2", "--reference", "step:0.05", "--duration", "1.5",
                 "--out", str(out), "--no-plots", "--json", str(tmp_path / "s.json")])
    assert code == 1          # unstable cells: flagged, written, and the exit code says so
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["benchmark"]["testbed"] == small.to_mapping()
    # the frictionless reference of this PD on this SEA diverges when sampled (margins --sampled says
    # UNSTABLE): its MAE is not scored, in words, never a number of 1e7 N m
    err = capsys.readouterr().err
    assert "expected response" in err and "diverges" in err
    assert "warning: pd:2:0.001:0.0007957747154594767:discretization=tustin + none in stiff" in err
    table = pd.read_csv(out / "results.csv")
    assert table["mae_N_m"].isna().all()
    assert not table[table["kind"] != "set"]["stable"].any() and (table[table["kind"] == "set"]["excluded_cells"] == 1).all()
    # the disk margin is the sampled loop's that the runs were made with: 0 (unstable), where the
    # continuous loop would claim about 0.5
    from forecast_design.analysis import loop_margins

    cells = table[table["kind"] != "set"]
    assert (cells["disk_margin"] == 0.0).all()
    # every cell is unstable: the set rows aggregate none of them (NaN), never an unstable loop's numbers
    assert table[table["kind"] == "set"][["disk_margin", "repeatability"]].isna().all().all()
    assert float(loop_margins(Design(testbed=small, environment=env, controller=PD(P=2.0, D=0.001)),
                              parse_compensators(["none"])[0]).alpha) > 0.4
    # the testbed is part of every cell's key: the paper's testbed is not served from this cache
    spec = BenchmarkSpec(controllers=(PD(P=2.0, D=0.001),), compensators=parse_compensators(["none"]),
                         environments=(("stiff", env),), references=(parse_reference("step:0.05", duration_s=0.5),),
                         repetitions=2, testbed=small)
    cell = spec.cells()[0]
    other = BenchmarkSpec(controllers=spec.controllers, compensators=spec.compensators,
                          environments=spec.environments, references=spec.references, repetitions=2)
    assert spec.cell_key(cell, None) != other.cell_key(cell, None)


@pytest.mark.parametrize("argv, words", [
    (["--testbed", "k=-5"], "k"),                                  # absurd stiffness
    (["--testbed", "k=58,J_m=abc"], "J_m"),                       # not a number
    (["--testbed", "missing_testbed.toml"], "missing_testbed.toml"),
    (["--runs", "some_dir", "--testbed", "k=40"], "--testbed"),   # the runs carry their own testbed
])
def test_benchmark_testbed_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, words):
    out = tmp_path / "bm"
    assert main(["benchmark", *argv, "--repetitions", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("forecast-design: error:") and words in err[0]
    assert not (out / "results.csv").exists()


# --- a lab's SEA with an unstable cell: flags, aggregates, files that reproduce the indicators, plots ------

LAB_SEA = "k=150,J_m=0.06,d_m=0.12"     # issue 26's newcomer: J_m 0.06, d_m 0.12, k 150, link 0.004 / 0.2
LAB_ENVS = """
[[environment]]
name = "e10"
k_e = 10.0
J_e = 0.01
J_l = 0.004
d_l = 0.2
[[environment]]
name = "locked"
locked = true
J_l = 0.004
d_l = 0.2
"""


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """pd:5:0.1 and pd:8:0 with none and ea-fob:10 on the lab's SEA; pd:8:0 on the locked output is unstable."""
    import contextlib
    import io

    folder = tmp_path_factory.mktemp("lab")
    (folder / "envs.toml").write_text(LAB_ENVS)
    out = folder / "out"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()) as stdout:
        code = main(["benchmark", "--testbed", LAB_SEA, "--envs", str(folder / "envs.toml"), "--controller", "pd:5:0.1",
                     "--controller", "pd:8:0", "--compensator", "none,ea-fob", "--repetitions", "3",
                     "--reference", "step:0.2:0.6", "--out", str(out), "--workers", "1"])
    return {"code": code, "out": out, "err": err.getvalue(), "stdout": stdout.getvalue(),
            "table": pd.read_parquet(out / "results.parquet"), "traces": pd.read_parquet(out / "traces.parquet")}


def test_an_unstable_cell_is_flagged_everywhere_and_left_out_of_the_set(lab):
    from forecast_design.analysis import loop_margins
    from forecast_design.environments import resolve_environments, resolve_testbed

    df, tr = lab["table"], lab["traces"]
    assert lab["code"] == 1
    cells = df[df["kind"] == "environment"].drop_duplicates(["controller", "compensator", "environment"])
    bad = {(r.controller, r.compensator, r.environment) for r in cells.itertuples() if not pd.isna(r.stable) and not r.stable}
    assert bad == {("pd:8:0", "none", "locked"), ("pd:8:0", "ea-fob:10", "locked")}
    # the flag is the loop analysis' (sampled, delay 0), and the frictionless expected response agrees with it:
    # it grows on the unstable loop (issue 26: 0.54 -> 0.96 N m within 1 s) and decays to its final value elsewhere
    tb = resolve_testbed(LAB_SEA)
    envs = resolve_environments(str(lab["out"].parent / "envs.toml"), testbed=tb)
    for r in cells.itertuples():
        design = Design(testbed=tb, environment=dict(envs.items())[r.environment], controller=parse_controller(r.controller))
        comp = parse_compensators(r.compensator)[0]
        lm = loop_margins(design, comp, sampled=True, rate_hz=2000.0, delay_samples=0)
        if r.environment != "locked":   # the load-independent flag: the port's passivity, computed on its own
            from forecast_design import analyse_passivity
            assert r.passive == analyse_passivity(design, comp, controller=design.controller).passive
        else:
            assert pd.isna(r.passive)
        assert bool(r.stable) == lm.stable
        assert r.disk_margin == pytest.approx(lm.alpha, rel=1e-12, abs=1e-15)   # one convention: delay 0, stated
        e = tr[(tr["controller"] == r.controller) & (tr["compensator"] == r.compensator)
               & (tr["environment"] == r.environment) & (tr["repetition"] == 0)]["tau_s_expected"].to_numpy()
        n = e.size
        grows = np.ptp(e[int(0.8 * n):]) > np.ptp(e[int(0.2 * n):int(0.4 * n)])   # its swing at the end vs earlier
        assert grows == (not r.stable)
    # stderr names each unstable cell in one warning line; the report and the summary list them
    warn = [ln for ln in lab["err"].splitlines() if "unstable (disk margin" in ln]
    assert len(warn) == 2 and all(ln.startswith("forecast-design: warning: pd:8:0 + ") and " in locked " in ln
                                  for ln in warn)
    report = (lab["out"] / "report.md").read_text()
    assert "2 unstable cell(s)" in report and "- pd:8:0 + none in locked" in report
    summary = json.loads((lab["out"] / "summary.json").read_text())
    assert {(c["controller"], c["environment"]) for c in summary["flags"]["unstable_cells"]} == {("pd:8:0", "locked")}
    assert "relative to the reference step" in summary["indicators"]["overshoot_percent"]
    assert "delay_samples = 0" in summary["indicators"]["disk_margin"] and "delay_samples = 0" in report
    # the set rows aggregate the stable environments only, and count what they left out
    for comp in ("none", "ea-fob:10"):
        sets = df[(df["kind"] == "set") & (df["controller"] == "pd:8:0") & (df["compensator"] == comp)]
        assert (sets["excluded_cells"] == 1).all()
        env_mean = df[(df["kind"] == "environment") & (df["statistic"] == "mean") & (df["controller"] == "pd:8:0")
                      & (df["compensator"] == comp)]
        stable_mae = env_mean[env_mean["stable"].astype(bool)]["mae_N_m"].to_numpy()
        assert sets[sets["statistic"] == "mean"]["mae_N_m"].iloc[0] == pytest.approx(float(np.mean(stable_mae)), rel=1e-12)
        assert sets[sets["statistic"] == "worst"]["mae_N_m"].iloc[0] < 0.3      # never the unstable cell's error
    assert (df[(df["kind"] == "set") & (df["controller"] == "pd:5:0.1")]["excluded_cells"] == 0).all()
    assert "1 unstable cell(s) left out" in lab["stdout"]


def test_settled_and_settling_time_columns_agree(lab):
    df = lab["table"]
    runs = df[df["kind"] == "run"]
    assert runs["settled"].dtype == "boolean" and runs["stable"].dtype == "boolean"
    assert runs["settled"].notna().all()
    assert (runs["settling_time_s"].isna() == ~runs["settled"].astype(bool)).all()
    env = df[(df["kind"] == "environment") & (df["statistic"] == "mean")]
    for r in env.itertuples():
        mine = runs[(runs["controller"] == r.controller) & (runs["compensator"] == r.compensator)
                    & (runs["environment"] == r.environment)]
        assert r.unsettled_runs == int((~mine["settled"].astype(bool)).sum())
    csv = pd.read_csv(lab["out"] / "results.csv")
    assert csv.loc[~csv["settled"].astype("boolean").fillna(True), "settling_time_s"].isna().all()


def test_the_indicators_recompute_from_the_written_traces_with_independent_code(lab):
    # every run's indicators from traces.parquet alone: python-control's step_info (the benchmark's
    # conventions spelled in its arguments), numpy for the MAE, scipy's pearsonr for the repeatability
    from scipy.stats import pearsonr

    df, tr = lab["table"], lab["traces"]
    runs = df[df["kind"] == "run"]
    checked = 0
    for (ctrl, comp, env), cell in tr.groupby(["controller", "compensator", "environment"], observed=True):
        reps = sorted(cell["repetition"].unique())
        ys = {i: cell[cell["repetition"] == i] for i in reps}
        t = ys[0]["t"].to_numpy()
        assert t.size == round(0.6 * 2000) and np.allclose(np.diff(t), 1 / 2000.0, rtol=1e-9)   # every sample
        for i in reps:
            row = runs[(runs["controller"] == ctrl) & (runs["compensator"] == comp) & (runs["environment"] == env)
                       & (runs["repetition"] == i)].iloc[0]
            y = ys[i]["tau_s"].to_numpy()
            ref = _step_info_relative_to_the_step(t, y, 0.2)
            assert bool(row["settled"]) == ref["settled"]
            for m in ("rise_time_s", "overshoot_percent", "settling_time_s", "steady_state_error_N_m"):
                # rise: python-control takes the first sample at or past a level, the benchmark interpolates
                tol = 2.0 / 2000 if m == "rise_time_s" else 1e-9
                assert row[m] == pytest.approx(ref[m], abs=tol, rel=1e-9, nan_ok=True), (ctrl, comp, env, i, m)
            assert row["mae_N_m"] == pytest.approx(np.mean(np.abs(y - ys[i]["tau_s_expected"].to_numpy())), rel=1e-12)
            others = [pearsonr(y, ys[j]["tau_s"].to_numpy())[0] for j in reps if j != i]
            assert row["repeatability"] == pytest.approx(np.mean(others), rel=1e-9)
            checked += 1
    assert checked == len(runs) == 2 * 2 * 2 * 3


def _inside(fig, artist) -> bool:
    """The artist's drawn extent lies within the figure's canvas (one pixel of slack)."""
    fig.canvas.draw()
    box, canvas = artist.get_window_extent(), fig.bbox
    return box.x0 >= canvas.x0 - 1 and box.y0 >= canvas.y0 - 1 and box.x1 <= canvas.x1 + 1 and box.y1 <= canvas.y1 + 1


def _has_data(ax) -> bool:
    return bool(ax.lines or ax.images or ax.collections or ax.patches)


def test_benchmark_indicators_plot_reads_at_a_glance(lab):
    import matplotlib.pyplot as plt

    from forecast_design.plotting.benchmark import UNITS, plot_indicators

    df = lab["table"]
    fig = plot_indicators(df)
    try:
        step_metrics_drawn = [m for m in ("repeatability", "mae_N_m", "rise_time_s", "overshoot_percent",
                                          "settling_time_s", "disk_margin")]
        assert len(fig.axes) == len(step_metrics_drawn)             # no empty panel (bandwidth: no chirp here)
        assert fig.get_suptitle()
        series = {f"{c} + {k}" for c, k in zip(df["controller"], df["compensator"])}
        labels = [t.get_text() for t in fig.legends[0].get_texts()]
        assert series <= set(labels) and any("unstable" in x for x in labels)
        assert len(fig.legends) == 1 and _inside(fig, fig.legends[0])
        env = df[(df["kind"] == "environment") & (df["statistic"] == "mean")]
        for ax, m in zip(fig.axes, step_metrics_drawn):
            assert _has_data(ax) and ax.get_ylabel() == UNITS[m] and "[" in ax.get_ylabel()
            assert ax.get_xlabel() == "environment stiffness k_e [N m/rad]"
            ticks = [t.get_text() for t in ax.get_xticklabels()]
            assert ticks[-1] == "locked"
            locked_x = ax.get_xticks()[-1]
            # the locked output is a category of its own: never the end of a stiffness line, and right of a
            # separator, not at a stiffness of ~4000
            for line in ax.lines:
                x = np.asarray(line.get_xdata(), dtype=float)
                if x.size > 1 and line.get_linestyle() not in ("None", "none", ""):
                    assert locked_x not in x
            assert locked_x > math.log10(10.0) + 1
            # the unstable cells are marked and do not set the scale
            assert any(line.get_gid() == "unstable" for line in ax.lines)
            good = env[env["stable"].astype(bool)][m].to_numpy(dtype=float)
            lo, hi = ax.get_ylim()
            assert lo <= np.nanmin(good) and hi >= np.nanmax(good)
        mae = fig.axes[step_metrics_drawn.index("mae_N_m")]
        bad = env[~env["stable"].astype(bool)]["mae_N_m"].max()
        assert mae.get_ylim()[1] < bad          # the unstable cells' ~0.5 N m errors would flatten it
        # pd:5:0.1's disk margins with and without the EA-FOB coincide within 1 % of the axis: drawn once, named
        disk = fig.axes[step_metrics_drawn.index("disk_margin")]
        note = disk.get_legend()
        assert note is not None and note.get_gid() == "merged"
        assert any("pd:5:0.1 + none" in t.get_text() and "pd:5:0.1 + ea-fob:10" in t.get_text()
                   for t in note.get_texts())
    finally:
        plt.close(fig)


def test_benchmark_indicators_plot_puts_the_legend_in_a_free_panel_slot(lab):
    import matplotlib.pyplot as plt

    from forecast_design.plotting.benchmark import plot_indicators

    fig = plot_indicators(lab["table"], metrics=("repeatability", "mae_N_m", "rise_time_s", "overshoot_percent",
                                                 "disk_margin"))
    try:
        assert len(fig.axes) == 5 and all(_has_data(ax) for ax in fig.axes)
        legend = fig.legends[0]
        fig.canvas.draw()
        box = legend.get_window_extent()
        # bottom right of the 2 x 3 grid: right of the second row's panels, not over any of them
        assert _inside(fig, legend)
        assert all(not box.overlaps(ax.get_window_extent()) for ax in fig.axes)
    finally:
        plt.close(fig)


def test_benchmark_overlays_show_every_controller_and_mark_unstable_cells(lab):
    import matplotlib.pyplot as plt

    from forecast_design.benchmark.runner import CellResult
    from forecast_design.plotting.benchmark import plot_overlays

    doc = json.loads((lab["out"] / "summary.json").read_text())
    assert doc["files"]["traces"] == "traces.parquet"
    cells = [CellResult.load(lab["out"] / "cells", p.stem) for p in sorted((lab["out"] / "cells").glob("*.json"))]
    fig = plot_overlays([c.thinned() for c in cells])
    try:
        assert len(fig.axes) == 4 * 2 and all(_has_data(ax) and len(ax.lines) == 3 + 1 for ax in fig.axes)
        titles = [ax.get_title() for ax in fig.axes]
        for ctrl in ("pd:5:0.1", "pd:8:0"):
            assert sum(f"{ctrl} + " in t for t in titles) == 4
        unstable = [ax for ax in fig.axes if ax.get_title().startswith("UNSTABLE")]
        assert {ax.get_title().split("\n")[0] for ax in unstable} == {"UNSTABLE pd:8:0 + none | locked",
                                                                      "UNSTABLE pd:8:0 + ea-fob:10 | locked"}
        stable_faces = {ax.get_facecolor() for ax in fig.axes if ax not in unstable}
        assert not stable_faces & {ax.get_facecolor() for ax in unstable}    # an unstable cell's panel stands out
        for ax in fig.axes:
            assert ax.get_ylabel() in ("", r"$\tau_s$ [N m]")
        assert all(ax.get_xlabel() == "t [s]" for ax in fig.axes[-2:])
        assert _inside(fig, fig.legends[0])
        assert any("unstable" in t.get_text() for t in fig.legends[0].get_texts())
    finally:
        plt.close(fig)


def test_benchmark_heatmap_marks_unstable_cells_outside_its_colour_scale(lab):
    import matplotlib.pyplot as plt

    from forecast_design.plotting.benchmark import UNITS, plot_heatmap

    df = lab["table"]
    env = df[(df["kind"] == "environment") & (df["statistic"] == "mean")]
    fig = plot_heatmap(df)
    try:
        panels = [ax for ax in fig.axes if ax.images]
        assert [ax.get_title() for ax in panels] == [UNITS["repeatability"], UNITS["mae_N_m"]]
        for ax, m in zip(panels, ("repeatability", "mae_N_m")):
            marks = [p for p in ax.patches if p.get_gid() == "unstable"]
            assert len(marks) == int((~env["stable"].astype(bool)).sum()) == 2
            vmin, vmax = ax.images[0].norm.vmin, ax.images[0].norm.vmax
            good = env[env["stable"].astype(bool)][m].to_numpy(dtype=float)
            assert vmin == pytest.approx(good.min()) and vmax == pytest.approx(good.max())
            assert ax.get_xlabel() == "environment"
        assert "hatched: unstable" in fig.get_suptitle()
    finally:
        plt.close(fig)


def test_repeated_envs_options_add_to_the_set(tmp_path, capsys):
    """`--envs soft --envs stiff` benchmarks both (a repeat used to replace the first silently)."""
    code = main(["benchmark", "--envs", "soft", "--envs", "stiff", "--compensator", "none", "--repetitions", "2",
                 "--duration", "0.2", "--no-plots", "--workers", "1", "--out", str(tmp_path / "b"), "--json"])
    out = capsys.readouterr().out
    assert code == 0
    assert list(json.loads(out)["benchmark"]["environments"]) == ["soft", "stiff"]
