"""The command line: every verb reachable, JSON for machines, exit 2 on bad input."""

import json
import subprocess
import sys

import control
import numpy as np
import pytest

from forecast_design.cli import build_parser, main
from forecast_design.params import Design, environment_preset, Testbed


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _hand_built_plant(env, tb=Testbed()):
    """P = tau_s/tau_m from the spec equations, interconnected by python-control."""
    s = control.tf("s")
    motor = 1 / (tb.J_m * s**2 + tb.d_m * s)                 # theta = motor (tau_m - tau_s)
    E = env.J * s**2 + env.d * s + env.k_e                     # tau_s = E q
    # tau_s = k (theta - q), q = tau_s / E  ->  tau_s = k theta / (1 + k/E)
    spring = tb.k * E / (E + tb.k)
    return control.minreal(control.feedback(motor * spring, 1), verbose=False)


@pytest.mark.parametrize("env_name", ["stiff", "soft", "exp-soft", "link-only"])
def test_tf_json_matches_hand_built_python_control_model(capsys, env_name):
    code, out, _ = _run(capsys, "tf", "--env", env_name, "--json")
    assert code == 0
    result = json.loads(out)
    assert set(result) == {"P", "EA", "LO", "LD", "design", "conventions"}
    # what the plants were computed for: the environment preset with the testbed's link, and the paper's testbed
    assert result["design"] == Design.nominal(env_name).to_mapping()
    hand = _hand_built_plant(environment_preset(env_name))
    num = np.trim_zeros(hand.num[0][0], "f")
    den = np.trim_zeros(hand.den[0][0], "f")
    num, den = num / den[0], den / den[0]
    np.testing.assert_allclose(result["P"]["num"], num, rtol=1e-9)
    np.testing.assert_allclose(result["P"]["den"], den, rtol=1e-9)
    assert result["P"]["den"][0] == 1.0
    assert result["P"]["dc_gain"] == pytest.approx(float(control.dcgain(hand)), rel=1e-9)
    key = lambda p: (round(p.real, 6), round(p.imag, 6))  # noqa: E731
    poles = sorted((complex(re, im) for re, im in result["P"]["poles"]), key=key)
    np.testing.assert_allclose(sorted(hand.poles(), key=key), poles, rtol=1e-7)


def test_tf_locked_plant_is_second_order_lag(capsys):
    code, out, _ = _run(capsys, "tf", "--env", "locked", "--json")
    result = json.loads(out)
    tb = Testbed()
    np.testing.assert_allclose(result["P"]["den"], [1.0, tb.d_m / tb.J_m, tb.k / tb.J_m], rtol=1e-12)
    assert result["P"]["dc_gain"] == pytest.approx(1.0)
    assert result["EA"]["den"] == result["LO"]["den"]


def test_tf_plot_overlays_environments(capsys, tmp_path):
    out_png = tmp_path / "bode.png"
    code, _, _ = _run(capsys, "tf", "--env", "soft", "--env", "stiff", "--plot", str(out_png))
    assert code == 0 and out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tf_from_experiment_uses_its_nominal_model(capsys, tmp_path):
    from forecast_design.experiment import experiment_from_arrays, save_experiment
    from forecast_design.params import Design

    design = Design.nominal("stiff")
    t = np.arange(10) / 2000.0
    exp = experiment_from_arrays(design, 2000.0, t, np.zeros(10), np.zeros(10), np.zeros(10))
    path = save_experiment(exp, tmp_path / "run.toml")
    _, from_file, _ = _run(capsys, "tf", "--experiment", str(path), "--json")
    _, from_env, _ = _run(capsys, "tf", "--env", "stiff", "--json")
    assert json.loads(from_file) == json.loads(from_env)


def _exit_code(argv):
    """main() returns 2 for library errors; argparse usage errors raise SystemExit(2)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize("argv,fragment", [
    (["tf", "--env", "squishy"], "unknown environment 'squishy'"),
    (["tf", "--experiment", "does-not-exist.toml"], "does-not-exist.toml"),
    (["tf", "--bogus-option"], "unrecognized arguments: --bogus-option"),
    (["no-such-verb"], "invalid choice"),
])
def test_bad_input_gives_one_line_error_and_exit_2(capsys, argv, fragment):
    code = _exit_code(argv)
    _, err = capsys.readouterr()
    assert code == 2
    lines = err.strip().splitlines()
    assert fragment in lines[-1]
    assert "Traceback" not in err


def test_help_lists_every_verb_with_one_line(capsys):
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices  # noqa: SLF001 - argparse has no public API
    help_text = parser.format_help()
    for verb in verbs:
        assert verb in help_text


def test_installed_entry_point_runs():
    exe = sys.executable.replace("python", "forecast-design")
    proc = subprocess.run([exe, "tf", "--env", "locked", "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["P"]["dc_gain"] == pytest.approx(1.0)


def _write_pair(tmp_path, toml_text, csv_text):
    (tmp_path / "run.toml").write_text(toml_text)
    (tmp_path / "run.csv").write_text(csv_text)
    return str(tmp_path / "run.toml")


_GOOD_TOML = """format = "forecast-experiment/1"
data = "run.csv"
[sampling]
rate_hz = 2000.0
[testbed]
J_m = 0.133
d_m = 0.3
k = 58.0
[environment]
J_e = 0.001
d_e = 0.063
k_e = 5.0
J_l = 0.0018
d_l = 0.35
"""
_GOOD_CSV = "t,tau_m,theta,q\n0,0,0,0\n0.0005,0.1,0,0\n0.001,0.1,1e-6,0\n"


def test_check_reads_a_good_experiment(tmp_path, capsys):
    path = _write_pair(tmp_path, _GOOD_TOML, _GOOD_CSV)
    code, out, _ = _run(capsys, "check", path, "--json")
    assert code == 0
    summary = json.loads(out)
    assert summary["n_samples"] == 3 and summary["rate_hz"] == 2000.0 and summary["tau_s_derived"]


@pytest.mark.parametrize("toml_edit,csv_text,fragment", [
    (("k = 58.0", "k = -58.0"), _GOOD_CSV, "k must be > 0"),
    (("k = 58.0", "k = 58.0\nkk = 1.0"), _GOOD_CSV, "unknown key 'kk'"),
    (("J_e = 0.001\n", ""), _GOOD_CSV, "missing required key 'J_e'"),
    (('format = "forecast-experiment/1"', 'format = "forecast-experiment/2"'), _GOOD_CSV, "format"),
    (("", ""), "t,tau_m,theta\n0,0,0\n", "'q'"),
    (("", ""), "t,tau_m,theta,q\n0,0,0,0\n0.0005,nan,0,0\n", "line 3"),
    (("", ""), "t,tau_m,theta,q\n0,0,0,0\n0.0005,0,0,0\n0.0005,0,0,0\n", "line 4"),
    (("", ""), "t,tau_m,theta,q\n0,0,0,0\n0.001,0,0,0\n0.002,0,0,0\n", "rate"),
    (("rate_hz = 2000.0", "rate_hz = 2000.0 ]"), _GOOD_CSV, "run.toml"),
])
def test_check_bad_experiment_exit_2_one_line_naming_file(tmp_path, capsys, toml_edit, csv_text, fragment):
    path = _write_pair(tmp_path, _GOOD_TOML.replace(*toml_edit), csv_text)
    code = _exit_code(["check", path])
    _, err = capsys.readouterr()
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert fragment in err and "run." in err


EMPS = __import__("pathlib").Path(__file__).resolve().parents[1].parent / "shared" / "data" / "emps"


@pytest.mark.skipif(not (EMPS / "emps_train.csv").exists(), reason="shared EMPS data not present")
def test_identify_emps_from_the_command_line_matches_published_idim_ls(tmp_path, capsys):
    out = tmp_path / "fit.json"
    code = main(["identify", "--csv", str(EMPS / "emps_train.csv"), "--time", "t_s", "--position", "qm_m",
                 "--force", "force_N", "--model", "sfm", "--offset", "--estimate-inertia",
                 "--validate", str(EMPS / "emps_pulses_test.csv"), "--json", str(out),
                 "--plot", str(tmp_path / "fit.png")])
    assert code == 0
    fit = json.loads(out.read_text())
    published = {"inertia": 95.1089, "viscous": 203.5034, "coulomb": 20.3935, "offset": -3.1648}
    for name, value in published.items():
        assert fit["params"][name] == pytest.approx(value, rel=0.01), name
    assert abs(fit["validation"]["relative_error_percent"] - 5.9824) <= 0.5
    assert (tmp_path / "fit.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("extra,fragment", [
    (["--time", "t_s", "--position", "nope", "--force", "force_N"], "nope"),
    (["--time", "t_s"], "--csv needs --position, --force"),
])
def test_identify_csv_bad_columns_exit_2(tmp_path, capsys, extra, fragment):
    csv_path = tmp_path / "axis.csv"
    csv_path.write_text("t_s,qm_m,force_N\n0,0,1\n0.001,0.1,1\n0.002,0.2,1\n")
    code = _exit_code(["identify", "--csv", str(csv_path), *extra])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1


def test_identify_requires_exactly_one_log(capsys):
    assert _exit_code(["identify"]) == 2
    assert "exactly one" in capsys.readouterr().err


_SCENARIO = """format = "forecast-scenario/1"
[sampling]
rate_hz = 2000.0
[testbed]
J_m = 0.133
d_m = 0.3
k = 58.0
[environment]
J_e = 0.0
d_e = 0.0
k_e = 0.0
J_l = 0.0018
d_l = 0.35
locked = true
[controller]
kind = "pd"
P = 5.0
D = 0.1
[[truth.effects]]
effect = "coulomb"
F_c = 0.3
[reference]
kind = "step"
amplitude = 0.2
[simulation]
duration_s = 0.5
"""


def test_simulate_writes_an_experiment_that_loads_with_truth_apart(tmp_path, capsys):
    scenario = tmp_path / "s.toml"
    scenario.write_text(_SCENARIO)
    code, out, _ = _run(capsys, "simulate", str(scenario), "--out", str(tmp_path / "run.toml"), "--json",
                        "--plot", str(tmp_path / "run.png"))
    assert code == 0
    paths = json.loads(out)
    run = __import__("forecast_design.experiment", fromlist=["load_experiment"]).load_experiment(tmp_path / "run.toml")
    assert run.n_samples == 1000 and run.design.environment.locked
    assert "truth" not in (tmp_path / "run.toml").read_text()          # the TOML stays the nominal model
    assert any("truth" in str(p) for p in paths.values())
    assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"
    # Locked output at rest: tau_m = P (tau_r - tau_s) and the motor sticks while
    # |tau_m - tau_s| <= F_c, so tau_s lies within F_c/(1+P) of P tau_r/(1+P).
    assert abs(run.signals.tau_s[-200:].mean() - 5.0 * 0.2 / 6.0) <= 0.3 / 6.0 + 2e-3


@pytest.mark.parametrize("edit,fragment", [
    (("amplitude = 0.2", "amplitude = 0.2\nwobble = 1"), "wobble"),
    (('effect = "coulomb"', 'effect = "gremlins"'), "gremlins"),
    (("duration_s = 0.5", ""), "duration_s"),
    (("duration_s = 0.5", 'duration_s = 0.5\nderivative_on = "error"'),
     "[simulation] derivative_on belongs to the controller now: set derivative_on in [controller]"),
    (("D = 0.1", 'D = 0.1\nderivative_on = "sideways"'), "derivative_on must be one of error, measurement"),
    (("D = 0.1", "D = 0.1\nI = 3.0"), "key 'I' does not belong to kind 'pd'"),
    (('[[truth.effects]]', '[truth.torque_sensor]\nnoise_std_N_m = -0.002\n\n[[truth.effects]]'),
     "[truth.torque_sensor] TorqueSensor noise_std_N_m must be a finite number >= 0"),
    (('[[truth.effects]]', '[truth.torque_sensor]\nnoise = 0.002\n\n[[truth.effects]]'),
     "[truth.torque_sensor] unknown key 'noise'"),
])
def test_simulate_bad_scenario_exit_2_names_key(tmp_path, capsys, edit, fragment):
    scenario = tmp_path / "s.toml"
    scenario.write_text(_SCENARIO.replace(*edit))
    code = _exit_code(["simulate", str(scenario), "--out", str(tmp_path / "run.toml")])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "s.toml" in err and len(err.strip().splitlines()) == 1


def test_margins_verb_agrees_with_fig6_and_reports_instability(capsys):
    code, out, _ = _run(capsys, "margins", "--env", "stiff", "--observer", "ld-dob", "--w-q-hz", "5", "--json")
    assert code == 0
    dm = json.loads(out)
    _, fig6, _ = _run(capsys, "reproduce", "fig6", "--json")
    row = next(r for r in json.loads(fig6) if r["environment"] == "stiff" and r["observer"] == "ld-dob"
               and r["w_q_hz"] == 5)
    assert dm["alpha"] == pytest.approx(row["disk_margin"], rel=1e-12)
    # LD-DOB at 10 Hz in the stiff environment is unstable (paper Fig. 6b): said in words, exit code 1
    code, out, err = _run(capsys, "margins", "--env", "stiff", "--observer", "ld-dob", "--w-q-hz", "10", "--json")
    assert code == 1 and json.loads(out)["stable"] is False and json.loads(out)["alpha"] == 0.0
    assert json.loads(out)["disk_margin"] == 0.0 and "UNSTABLE" in err     # JSON on stdout, the words on stderr
    assert row["stable"] is True and not next(
        r for r in json.loads(fig6) if r["environment"] == "stiff" and r["observer"] == "ld-dob"
        and r["w_q_hz"] == 10)["stable"]                                   # fig6 agrees on which loop is unstable
    code, out, err = _run(capsys, "margins", "--env", "stiff", "--observer", "ld-dob", "--w-q-hz", "10")
    assert code == 1 and "UNSTABLE" in out and "nan" not in out and err == ""


def test_tune_q_sampled_json(capsys):
    code, out, _ = _run(capsys, "tune-q", "--observer", "ea-fob", "--sampled", "--json")
    result = json.loads(out)
    assert code == 0 and result["feasible"] and result["agrees_with_scan"]
    assert set(result) >= {"observer", "w_q_hz", "worst_ratio", "worst_environment", "feasible", "evaluations"}


def test_bench_gap_rejects_a_nonpositive_count(capsys):
    assert _exit_code(["bench-gap", "--per-effect", "0"]) == 2
    err = capsys.readouterr().err
    assert "--per-effect must be >= 1" in err and len(err.strip().splitlines()) == 1


def test_export_bad_controller_string_exit_2(tmp_path, capsys):
    assert _exit_code(["export", "--controller", "pi:1:2:3", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "pi:1:2:3" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "fd_controller.c").exists()


@pytest.mark.parametrize("argv,fragment", [
    (["reproduce", "fig9"], "invalid choice"),
    (["tune-q", "--observer", "ea-fob", "--envs", "soft,mud"], "unknown environment 'mud'"),
    (["tune-q", "--observer", "ea-fob", "--band", "5", "1"], "band"),
    (["margins", "--env", "mud"], "unknown environment 'mud'"),
    (["emulate", "--fault", "gremlin:1"], "gremlin"),
    (["run", "--port", "loop://", "--reference", "triangle:1", "--out", "x.toml"], "triangle"),
    (["pipeline", "--bogus"], "unrecognized arguments"),
    (["identify", "--csv", "x.csv", "--time", "t", "--position", "x", "--force", "f", "--select-samples", "some"],
     "invalid choice"),
    (["margins", "--break-at", "middle"], "invalid choice"),
])
def test_every_verb_rejects_bad_arguments_with_one_line(capsys, tmp_path, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    assert _exit_code(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.parametrize("argv,fragment", [
    (["bench-gap", "--generator", "mine"], "invalid choice: 'mine'"),
    (["bench-gap", "--generator", "independent", "--scale", "0"], "magnitude_scale must lie in (0, 1]"),
    (["bench-gap", "--generator", "independent", "--scale", "nan"], "magnitude_scale must lie in (0, 1]"),
    (["bench-gap", "--generator", "independent", "--scale", "1.5"], "magnitude_scale must lie in (0, 1]"),
    (["bench-gap", "--scale", "0.5"], "independent generator only"),
])
def test_bench_gap_generator_options_reject_bad_values(capsys, argv, fragment):
    assert _exit_code(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_an_os_error_without_a_file_name_is_one_line_without_an_empty_name(monkeypatch, capsys):
    import errno

    from forecast_design import cli

    def full_disk(args):
        raise OSError(errno.ENOSPC, "No space left on device")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    parser._subparsers._group_actions[0].choices["tf"].set_defaults(handler=full_disk)  # noqa: SLF001
    assert cli.main(["tf"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["forecast-design: error: No space left on device"]


def test_identify_errors_about_the_data_name_the_file(tmp_path, capsys):
    """Issue 14: an error about a log's data names that log, the estimation one or the validation one."""
    short = tmp_path / "short.csv"
    short.write_text("t,x,f\n0,0,1\n0.001,0.1,2\n")
    t = np.arange(2000) / 1000.0
    ok = tmp_path / "ok.csv"
    ok.write_text("t,x,f\n" + "\n".join(f"{float(a)!r},{float(np.sin(a))!r},{float(0.3 * np.sign(np.cos(a)) + 0.1 * np.cos(a))!r}"
                                        for a in t) + "\n")
    columns = ["--time", "t", "--position", "x", "--force", "f", "--model", "sfm"]
    for argv in (["--csv", str(short)], ["--csv", str(ok), "--validate", str(short)]):
        assert main(["identify", *argv, *columns]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"forecast-design: error: {short}: "), err
    dup = tmp_path / "dup.csv"
    dup.write_text("t,x,f\n0,0,1\n0.001,0.1,2\n0.001,0.2,3\n")
    assert main(["identify", "--csv", str(dup), *columns]) == 2
    assert "(0.001 after 0.001)" in capsys.readouterr().err


@pytest.mark.slow
def test_diagnose_prints_the_verdicts_numbers_with_their_intervals_and_statuses(tmp_path, capsys):
    # a number that may be wrong says so where a person reads it too: the noisy 16-bit Coulomb square's level, 8 %
    # high, is printed with its 95 % interval (which holds the truth) and `uncertain`, as in the JSON
    from forecast_design import independent as ind
    from forecast_design.experiment import save_experiment

    log = ind.make_independent_log("coulomb", 4, 80)
    path = tmp_path / "log.toml"
    save_experiment(log.experiment, path)
    capsys.readouterr()
    assert main(["diagnose", str(path), "--json", str(tmp_path / "d.json")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("parameters (95 % intervals): "))
    status = json.loads((tmp_path / "d.json").read_text())["verdict"]["status"]
    printed = dict(item.split(" = ") for item in line.split(": ", 1)[1].split(", "))
    assert set(printed) == set(status)
    value, rest = printed["F_c"].split(" +- ")
    half, graded = rest.split(" ")
    assert float(value) == pytest.approx(status["F_c"]["value"], rel=1e-3)
    assert float(half) == pytest.approx(1.96 * status["F_c"]["std"], rel=0.05) and graded == "(uncertain)"
    assert abs(float(value) - log.case.effect_params["F_c"]) <= float(half)
