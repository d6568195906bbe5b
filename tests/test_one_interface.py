"""One interface across verbs and functions (issue 13): scenarios' environments, simulate --friction,
--json [FILE] in check/simulate, --skew in reproduce, shared JSON keys, environments in the Python API."""

import json
import math

import control
import numpy as np
import pytest

import forecast_design as fd
from forecast_design import Compensator, Design, Environment, Testbed, loop_margins, transfer_functions
from forecast_design.cli import main
from forecast_design.environments import resolve_environments
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.experiment import load_experiment
from forecast_design.loops import force_loop
from forecast_design.params import ENVIRONMENT_PRESETS
from forecast_design.reproduce import fig6_table
from forecast_design.simulation.scenario import load_scenario

# A short closed-loop scenario (0.4 s) on the Table 1 testbed; {environment} and {compensator} vary.
SCENARIO = """format = "forecast-scenario/1"
{environment}
[sampling]
rate_hz = 2000.0

[testbed]
J_m = 0.133
d_m = 0.3
k = 58.0

[controller]
kind = "pd"
P = 5.0
D = 0.1
{compensator}
[[truth.effects]]
effect = "coulomb"
F_c = 0.3

[reference]
kind = "square"
high = 0.5
low = -0.5
period_s = 0.2

[simulation]
duration_s = 0.4
seed = 0
"""
TABLE = "[environment]\nJ_e = 0.001\nd_e = 0.063\nk_e = 5.0\nJ_l = 0.0018\nd_l = 0.35\nlocked = false\n"
FRICTION = {"viscous": 0.31, "coulomb": 0.27, "sin1": 0.02}


def _run(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:      # argparse usage errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _scenario(tmp_path, environment=TABLE, compensator="", name="s.toml"):
    path = tmp_path / name
    path.write_text(SCENARIO.format(environment=environment, compensator=compensator))
    return path


# --- scenarios: [environment] as a preset, inline values or a file ------------------------------------


def test_scenario_environment_may_be_a_preset_inline_values_or_a_file_beside_it(tmp_path):
    stiff = load_scenario(_scenario(tmp_path, 'environment = "stiff"'))
    assert stiff.design.environment == ENVIRONMENT_PRESETS["stiff"]
    inline = load_scenario(_scenario(tmp_path, 'environment = "k_e=20,J_e=0.02"'))
    # d_e left out: critically damped (Section 5's rule) on the Table 1 link
    assert inline.design.environment == Environment(J_e=0.02, d_e=2 * math.sqrt(20 * 0.02), k_e=20.0)
    assert any("critical" in note and "d_e" in note for note in inline.notes) and not stiff.notes
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "mine.toml").write_text(TABLE)          # an environment file, found beside the scenario
    from_file = load_scenario(_scenario(sub, 'environment = "mine.toml"'))
    assert from_file.design.environment == load_scenario(_scenario(tmp_path, TABLE)).design.environment
    assert from_file.design.environment == ENVIRONMENT_PRESETS["exp-soft"]
    # the written run carries the resolved numbers: a scenario round-trips to the same design
    from forecast_design.simulation.scenario import scenario_from_mapping

    assert scenario_from_mapping(inline.to_mapping()).design == inline.design


@pytest.mark.parametrize("environment,fragment", [
    ('environment = "mud"', "environment = 'mud': unknown environment 'mud'"),
    ('environment = "k_e=20,J_e=0.02,Q=1"', "unknown key 'Q'"),
    ('environment = "set.toml"', "a scenario needs one environment, got 3"),
    ('environment = "nowhere.toml"', "nowhere.toml: environment file not found"),
    ('environment = "soft,stiff"', "a scenario needs one environment, got 2"),
    ("", "missing required table [environment]"),
])
def test_scenario_environment_bad_forms_are_one_line_errors_naming_the_file(tmp_path, capsys, environment,
                                                                            fragment):
    (tmp_path / "set.toml").write_text('[[environment]]\nname = "w"\nk_e = {log = [1, 10], n = 3}\nJ_e = 0.01\n')
    path = _scenario(tmp_path, environment)
    with pytest.raises(ExperimentFormatError, match="s.toml"):
        load_scenario(path)
    code, _, err = _run(capsys, "simulate", path, "--out", tmp_path / "run.toml")
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run.toml").exists()


# --- simulate --friction, --json [FILE] ------------------------------------------------------------------


def test_simulate_friction_file_equals_the_scenarios_own_sfm_table(tmp_path, capsys):
    """Two routes to the same SFM compensator: identify's JSON (--friction) and a [sfm] table."""
    (tmp_path / "f.json").write_text(json.dumps({"model": "sfm", "params": FRICTION}))
    plain = _scenario(tmp_path, TABLE, name="plain.toml")
    table = "\n[compensator]\nkind = \"sfm\"\n\n[sfm]\n" + "".join(f"{k} = {v!r}\n" for k, v in FRICTION.items())
    with_table = _scenario(tmp_path, TABLE, table, name="table.toml")
    code, out, _ = _run(capsys, "simulate", plain, "--out", tmp_path / "a.toml", "--friction", tmp_path / "f.json",
                        "--json")
    summary = json.loads(out)
    assert code == 0 and summary["compensator"] == "sfm" and summary["friction"] == FRICTION
    assert _run(capsys, "simulate", with_table, "--out", tmp_path / "b.toml")[0] == 0
    a = load_experiment(tmp_path / "a.toml").signals.columns()
    b = load_experiment(tmp_path / "b.toml").signals.columns()
    assert np.array_equal(a["tau_frc_hat"], b["tau_frc_hat"]) and np.array_equal(a["tau_s"], b["tau_s"])
    assert np.max(np.abs(a["tau_frc_hat"])) > 0.1        # the SFM really ran on the identified friction
    # the Python route: Scenario.with_friction builds Compensator(kind="sfm", friction=...)
    scen = load_scenario(plain).with_friction(FRICTION)
    assert scen.design.compensator == Compensator(kind="sfm", friction=FRICTION)
    assert np.array_equal(scen.run().tau_frc_hat, a["tau_frc_hat"])


@pytest.mark.parametrize("compensator,friction,fragment", [
    ("\n[compensator]\nkind = \"ea-fob\"\n", {"model": "sfm", "params": FRICTION},
     "the scenario's compensator is 'ea-fob'"),
    ("", {"model": "lugre", "params": {"sigma0": 1.0}}, "model 'lugre' cannot drive the SFM"),
    ("", {"model": "sfm", "params": {"viscous": 0.3, "mystery": 1.0}}, "mystery"),
    ("", {"model": "sfm", "params": {"viscous": float("nan")}}, "viscous"),
])
def test_simulate_friction_bad_inputs_exit_2_and_write_nothing(tmp_path, capsys, compensator, friction, fragment):
    (tmp_path / "f.json").write_text(json.dumps(friction))
    path = _scenario(tmp_path, TABLE, compensator)
    code, _, err = _run(capsys, "simulate", path, "--out", tmp_path / "run.toml", "--friction", tmp_path / "f.json")
    assert code == 2 and fragment in err and "Traceback" not in err and len(err.strip().splitlines()) <= 2
    assert not (tmp_path / "run.toml").exists()


def test_simulate_json_says_what_the_run_assumed(tmp_path, capsys):
    # the JSON named the compensator's kind but not its cutoff, nor the testbed, environment, rate or true plant:
    # a summary a reader could not tie to a design. Now it carries them, as the scenario defines them
    path = _scenario(tmp_path, TABLE, "\n[compensator]\nkind = \"ea-fob\"\nw_q_hz = 7.0\n")
    scen = load_scenario(path)
    code, out, _ = _run(capsys, "simulate", path, "--out", tmp_path / "r.toml", "--json", "-")
    doc = json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert code == 0 and doc["design"]["compensator"] == {"kind": "ea-fob", "w_q_hz": 7.0}
    assert doc["design"]["testbed"] == scen.design.testbed.to_mapping()
    assert doc["design"]["environment"] == scen.design.environment.to_mapping()
    assert doc["rate_hz"] == scen.rate_hz and doc["options"]["seed"] == scen.options["seed"]
    assert doc["reference"] == scen.reference.to_mapping()
    assert doc["options"]["torque_limit"] is None      # no limit: null, not Infinity
    assert doc["truth"] == str(tmp_path / "r.truth.json") and "effects" in doc["true_plant"]
    # every statistic is a count or carries its unit in its name
    assert set(doc["statistics"]) <= {"n_samples", "duration_s", "max_abs_tau_m_N_m", "mae_friction_estimate_N_m",
                                      "mae_tracking_N_m"}


def test_tune_q_json_says_what_the_cutoff_was_tuned_for(capsys):
    # a cutoff is meaningless without the loop it was tuned in: the JSON gave no controller (the default PD was
    # silent), no testbed and no environment values (only "plants": 2)
    from forecast_design.controllers import parse_controller

    code, out, _ = _run(capsys, "tune-q", "--observer", "lo-dob", "--envs", "soft,stiff",
                        "--controller", "pid:6:20:0.05:0.002", "--json", "-")
    doc = json.loads(out)
    assert code == 0 and doc["assumed"]["controller"] == parse_controller("pid:6:20:0.05:0.002").to_mapping()
    envs = dict(resolve_environments("soft,stiff"))
    assert doc["assumed"]["environments"] == {label: env.to_mapping() for label, env in envs.items()}
    assert doc["assumed"]["testbed"] == Design.nominal("soft").testbed.to_mapping()
    assert doc["assumed"]["loop"] == "continuous" and doc["assumed"]["q_family"] == "butterworth"


def test_check_and_simulate_json_file_stdout_and_old_flag_form_agree(tmp_path, capsys):
    scenario = _scenario(tmp_path)
    code, out, _ = _run(capsys, "simulate", scenario, "--out", tmp_path / "r.toml", "--json", tmp_path / "s.json")
    written = json.loads((tmp_path / "s.json").read_text())
    assert code == 0 and written["experiment"] == str(tmp_path / "r.toml") and "experiment:" in out
    assert written["statistics"]["duration_s"] == 0.4 and written["compensator"] == "none"
    # old form: `simulate --json SCENARIO.toml` (the flag without a file) still reads the scenario
    code, out, _ = _run(capsys, "simulate", "--json", scenario, "--out", tmp_path / "r2.toml")
    assert code == 0 and json.loads(out)["statistics"] == written["statistics"]
    code, shown, _ = _run(capsys, "check", tmp_path / "r.toml", "--json")
    summary = json.loads(shown)
    assert code == 0 and summary["n_samples"] == 800 and summary["duration_s"] == 0.4 and "duration" not in summary
    assert _run(capsys, "check", tmp_path / "r.toml", "--json", tmp_path / "c.json")[0] == 0
    assert json.loads((tmp_path / "c.json").read_text()) == summary
    assert json.loads(_run(capsys, "check", "--json", tmp_path / "r.toml")[1]) == summary   # old flag form
    code, _, err = _run(capsys, "check", "--json")
    assert code == 2 and "missing the EXPERIMENT.toml argument" in err
    code, _, err = _run(capsys, "simulate", "--out", tmp_path / "r3.toml")
    assert code == 2 and "missing the SCENARIO.toml argument" in err
    code, _, err = _run(capsys, "check", tmp_path / "r.toml", "--json", tmp_path / "r.toml")
    assert code == 2 and "r.toml" in err and load_experiment(tmp_path / "r.toml").n_samples == 800  # input kept


# --- --skew and one JSON key per quantity -------------------------------------------------------------


def test_reproduce_fig6_skew_alias_and_keys_match_python_control_disk_margins(capsys):
    code, out, _ = _run(capsys, "reproduce", "fig6", "--skew", "0.4", "--json")
    rows = json.loads(out)
    assert code == 0 and json.loads(_run(capsys, "reproduce", "fig6", "--sigma", "0.4", "--json")[1]) == rows
    row = next(r for r in rows if r["environment"] == "stiff" and r["compensator"] == "ea-fob" and r["w_q_hz"] == 5)
    assert row["skew"] == 0.4 and row["alpha"] == row["disk_margin"]
    assert row["frequency_hz"] == pytest.approx(row["frequency_rad_s"] / (2 * math.pi), rel=1e-15)
    # independent implementation: python-control's disk_margins on a dense grid (the exact peak is <= it)
    L = force_loop(Design.nominal("stiff"), Compensator(kind="ea-fob", w_q_hz=5.0)).L.to_control()
    w = np.geomspace(0.1, 1e4, 20000)
    dm_grid = control.disk_margins(L, w, skew=0.4)[0]
    assert row["disk_margin"] <= dm_grid.min() * (1 + 1e-9)
    assert row["disk_margin"] == pytest.approx(dm_grid.min(), rel=1e-4)
    # the frequency-dependent curve: the same keys, and point-wise equal to python-control's
    from forecast_design.margins import disk_margin_curve

    w_few = np.geomspace(1.0, 1e3, 50)
    curve = disk_margin_curve(force_loop(Design.nominal("stiff"), Compensator(kind="ea-fob", w_q_hz=5.0)).L, w_few,
                              0.4).to_mapping()
    assert curve["disk_margin"] == curve["alpha"] and curve["skew"] == curve["sigma"] == 0.4
    np.testing.assert_allclose(curve["frequency_hz"], w_few / (2 * math.pi), rtol=1e-15)
    np.testing.assert_allclose(curve["disk_margin"], control.disk_margins(L, w_few, skew=0.4, returnall=True)[0],
                               rtol=1e-9)
    # the margins verb reports the same quantity under the same keys
    code, out, _ = _run(capsys, "margins", "--env", "stiff", "--compensator", "ea-fob", "--w-q-hz", "5", "--skew",
                        "0.4", "--json")
    m = json.loads(out)
    for key in ("disk_margin", "alpha", "skew", "phase_margins_deg", "frequency_hz", "compensator"):
        assert m[key] == pytest.approx(row[key], rel=1e-12) if isinstance(m[key], float) else m[key] == row[key]


def test_reproduce_fig6_takes_the_users_environments_and_testbed(capsys, tmp_path):
    (tmp_path / "envs.toml").write_text('[[environment]]\nname = "wall"\nk_e = [2.0, 50.0]\nJ_e = 0.01\n')
    code, out, _ = _run(capsys, "reproduce", "fig6", "--env", tmp_path / "envs.toml", "--testbed", "k=40",
                        "--json")
    rows = json.loads(out)
    assert code == 0 and {r["environment"] for r in rows} == {"wall[k_e=2]", "wall[k_e=50]"}
    row = next(r for r in rows if r["environment"] == "wall[k_e=50]" and r["observer"] == "lo-dob"
               and r["w_q_hz"] == 10)
    env = Environment(J_e=0.01, d_e=2 * math.sqrt(50 * 0.01), k_e=50.0)
    expected = loop_margins(env, Compensator(kind="lo-dob", w_q_hz=10.0), testbed=Testbed(k=40.0))
    assert row["disk_margin"] == pytest.approx(expected.alpha, rel=1e-12)
    for argv, fragment in ((["fig7", "--skew", "1"], "--skew applies to fig6 only"),
                           (["table3", "--env", "soft"], "--env applies to fig6 only"),
                           (["fig6", "--env", "mud"], "unknown environment 'mud'"),
                           (["fig6", "--skew", "nan"], "not a number")):
        code, _, err = _run(capsys, "reproduce", *argv)
        assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1


def test_tune_q_and_export_json_share_the_keys(capsys, tmp_path):
    code, out, _ = _run(capsys, "tune-q", "--observer", "lo-dob", "--env", "soft,stiff", "--json")
    r = json.loads(out)
    assert code == 0 and r["compensator"] == r["observer"] == "lo-dob"
    code, out, _ = _run(capsys, "export", "--compensator", "ea-fob", "--tau-max", "3", "--out", tmp_path / "c",
                        "--json")
    assert code == 0 and json.loads(out)["tau_max_N_m"] == 3.0
    code, out, _ = _run(capsys, "export", "--compensator", "ea-fob", "--out", tmp_path / "d", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["tau_max_N_m"] is None       # no saturation: null, not Infinity
    # the defaults the [controller] and [compensator] tables leave out are said, as the generated C has them
    header = (tmp_path / "d" / "fd_controller.h").read_text()
    assert doc["controller_discretization"] == "backward-euler" and "controller by backward-euler" in header
    assert doc["q_filter"] == {"family": "butterworth", "order": 2} and "butterworth, order 2" in header
    code, out, _ = _run(capsys, "export", "--compensator", "none", "--out", tmp_path / "e", "--json")
    assert code == 0 and json.loads(out)["q_filter"] is None


# --- Python: environments as objects, names, inline values and sets -----------------------------------


def test_transfer_functions_take_an_environment_a_name_inline_values_a_design_and_a_testbed():
    stiff = Design.nominal("stiff")
    reference = transfer_functions(stiff).to_mapping()
    assert transfer_functions("stiff").to_mapping() == reference
    assert transfer_functions(ENVIRONMENT_PRESETS["stiff"]).to_mapping() == reference
    assert transfer_functions("k_e=100,J_e=0.1").to_mapping() == reference      # critical d_e: the preset
    soft40 = transfer_functions("soft", testbed="k=40")
    assert soft40.to_mapping() == transfer_functions(Design(testbed=Testbed(k=40.0))).to_mapping()
    assert transfer_functions(stiff, testbed=Testbed(k=40.0)).to_mapping() == \
        transfer_functions(Design(testbed=Testbed(k=40.0), environment=stiff.environment)).to_mapping()
    # P with the user's testbed against an independent python-control interconnection, at s = j
    s = control.tf("s")
    tb, env = Testbed(k=40.0), ENVIRONMENT_PRESETS["soft"]
    E = env.J * s**2 + env.d * s + env.k_e
    hand = control.feedback(1 / (tb.J_m * s**2 + tb.d_m * s) * (tb.k * E / (E + tb.k)), 1)
    assert soft40.to_control()["P"](1j) == pytest.approx(hand(1j), rel=1e-10)
    with pytest.raises(ParameterError, match="transfer_functions needs one environment, got 2"):
        transfer_functions("soft,stiff")
    with pytest.raises(ParameterError, match="cannot read environments from int"):
        transfer_functions(3)
    with pytest.raises(ParameterError, match="k must be > 0"):
        transfer_functions("soft", testbed="k=0")


def test_tune_q_takes_environment_objects_and_verifies_the_answer():
    env = fd.Environment(J_e=0.02, d_e=0.4, k_e=20.0)
    r = fd.tune_q("lo-dob", [env, "stiff"])
    assert r.feasible and r.plants == 2
    assert fd.tune_q("lo-dob", ["k_e=20,J_e=0.02,d_e=0.4", "stiff"]).w_q_hz == r.w_q_hz   # same set, as text
    # independent check with exact margins: both environments keep min_ratio (0.9) at the answer
    worst = min(loop_margins(e, Compensator(kind="lo-dob", w_q_hz=r.w_q_hz)).alpha / loop_margins(e).alpha
                for e in (env, ENVIRONMENT_PRESETS["stiff"]))
    assert worst >= 0.9 * (1 - 1e-6) and worst == pytest.approx(r.worst_ratio, rel=1e-6)
    with pytest.raises(ParameterError, match="cannot read environments"):
        fd.tune_q("ea-fob", [object()])


def test_fig6_table_takes_an_environment_set_and_the_skew_alias():
    envs = resolve_environments(["soft", fd.Environment(J_e=0.02, d_e=0.4, k_e=20.0)])
    rows = fig6_table(environments=envs, observers=("none", "ea-fob"), w_q_hz=(5.0,), skew=0.2)
    assert [r.environment for r in rows] == [envs.names[0]] * 2 + [envs.names[1]] * 2
    for r in rows:
        comp = None if r.observer == "none" else Compensator(kind=r.observer, w_q_hz=r.w_q_hz)
        assert r.disk_margin == pytest.approx(loop_margins(envs[r.environment], comp, skew=0.2).alpha, rel=1e-12)
    assert fig6_table(environments="soft", observers=("none",), sigma=0.2)[0] == rows[0]
    with pytest.raises(ParameterError, match="skew or its alias sigma, not both"):
        fig6_table(skew=0.1, sigma=0.2)


def test_simulate_says_which_defaults_a_scenario_left_to_the_toolbox(tmp_path, capsys):
    path = _scenario(tmp_path, 'environment = "k_e=20,J_e=0.02"')
    assert main(["simulate", str(path), "--out", str(tmp_path / "run.toml")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("forecast-design: note:")]
    assert len(notes) == 1 and "d_e" in notes[0]
