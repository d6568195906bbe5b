"""A newcomer's SEA described once (issue 26): a testbed file with its own link drives every verb.

The lab's SEA: J_m 0.06 kg m^2, d_m 0.12 N m s/rad, k 150 N m/rad, link J_l 0.004 kg m^2, d_l
0.2 N m s/rad; environments k_e 2..400 N m/rad plus a locked output. No paper value (Table 1's
J_m 0.133, d_m 0.3, k 58, link 0.0018 / 0.35) may leak into what any verb computes. The checks
are closed forms (the paper's eq. (8) for the LD-DOB nominal plant with the user's numbers) and an
independent loop built with python-control, not our code compared with itself.
"""

import json
import math

import control
import numpy as np
import pytest

import forecast_design as fd
from forecast_design.cli import main
from forecast_design.environments import resolve_environments, resolve_testbed
from forecast_design.errors import ParameterError
from forecast_design.params import TABLE1_LINK

J_M, D_M, K, J_L, D_L = 0.06, 0.12, 150.0, 0.004, 0.2
K_E = (2.0, 10.0, 50.0, 150.0, 400.0)
J_E = 0.01
MYSEA = f"""# a newcomer's SEA and its environments, described once
[testbed]
J_m = {J_M}
d_m = {D_M}
k = {K}
J_l = {J_L}
d_l = {D_L}

[[environment]]
name = "e"
k_e = {list(K_E)}
J_e = {J_E}

[[environment]]
name = "held"
locked = true
"""


@pytest.fixture
def mysea(tmp_path):
    path = tmp_path / "mysea.toml"
    path.write_text(MYSEA)
    return path


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _no_table1_link(env):
    assert (env.J_l, env.d_l) == (J_L, D_L), env
    assert (env.J_l, env.d_l) != TABLE1_LINK


def test_the_testbed_file_carries_the_link_to_every_environment(mysea):
    tb = resolve_testbed(mysea)
    assert (tb.J_m, tb.d_m, tb.k, tb.link) == (J_M, D_M, K, (J_L, D_L))
    # the file's own tables, presets (defined on Table 1's link), inline values: the user's link
    envs = resolve_environments([mysea, "soft", "locked", "link-only", "k_e=20,J_e=0.02"], testbed=tb)
    assert len(envs) == len(K_E) + 1 + 4
    for _, env in envs:
        _no_table1_link(env)
    # the set file alone also takes its own [testbed]'s link
    for _, env in resolve_environments(mysea):
        _no_table1_link(env)
    # an environment with a link of its own keeps it
    assert resolve_environments("k_e=20,J_e=0.02,J_l=0.01,d_l=0.5", testbed=tb).single()[1].J_l == 0.01
    # ... even when that link is exactly Table 1's (given, not left on the default)
    table1 = f"k_e=20,J_e=0.02,J_l={TABLE1_LINK[0]},d_l={TABLE1_LINK[1]}"
    assert (resolve_environments(table1, testbed=tb).single()[1].J_l,) == (TABLE1_LINK[0],)
    given = fd.Environment(J_e=0.1, d_e=0.3, k_e=5.0, J_l=TABLE1_LINK[0], d_l=TABLE1_LINK[1])
    assert (fd.Design(testbed=tb, environment=given).environment.J_l,
            fd.Design(testbed=tb, environment=given).environment.d_l) == TABLE1_LINK
    # Design gives the testbed's link to an environment on the default link, in Python too
    assert fd.Design.nominal("stiff", testbed=tb).environment.J_l == J_L
    assert fd.Design(testbed=tb, environment=fd.Environment(J_e=0.1, d_e=0.3, k_e=5.0)).environment.d_l == D_L
    # inline --testbed spelling; the link is given whole or not at all
    assert resolve_testbed(f"J_m={J_M},d_m={D_M},k={K},J_l={J_L},d_l={D_L}") == tb
    with pytest.raises(ParameterError, match="J_l given without d_l"):
        resolve_testbed("k=150,J_l=0.004")


def test_the_ld_dob_nominal_plant_is_the_closed_form_with_the_users_link(mysea, capsys):
    code, out, err = _cli(capsys, "tf", "--testbed", mysea, "--env", f"{mysea}#held", "--json")
    assert code == 0, err
    ld = json.loads(out)["LD"]
    # paper eq. (8): P_n^LD = k (J_l s + d_l) / (J_m J_l s^3 + J_m d_l s^2 + k (J_m + J_l) s + k d_l)
    num = np.array([K * J_L, K * D_L])
    den = np.array([J_M * J_L, J_M * D_L, K * (J_M + J_L), K * D_L])
    np.testing.assert_allclose(ld["num"], num / den[0], rtol=1e-12)
    np.testing.assert_allclose(ld["den"], den / den[0], rtol=1e-12)
    # the same numbers the paper's link would give are not these
    paper_den = np.array([J_M * TABLE1_LINK[0], J_M * TABLE1_LINK[1], K * (J_M + TABLE1_LINK[0]), K * TABLE1_LINK[1]])
    assert not np.allclose(ld["den"], paper_den / paper_den[0], rtol=1e-3)


def _butterworth_q(w_q_hz):
    wq = 2.0 * math.pi * w_q_hz
    return control.tf([wq**2], [1.0, math.sqrt(2.0) * wq, wq**2])


def test_margins_of_the_ld_dob_loop_match_an_independent_python_control_loop(mysea, capsys):
    """Locked output, LD-DOB 10 Hz, PD 5/0.1, broken at the controller: L = C P / (1 + Q (P / P_n - 1))
    with P = k / (J_m s^2 + d_m s + k) and P_n the LD closed form with the user's link (eqs. (2), (4), (8))."""
    code, out, err = _cli(capsys, "margins", "--testbed", mysea, "--env", f"{mysea}#held",
                          "--compensator", "ld-dob", "--w-q-hz", "10", "--json")
    assert code == 0, err
    got = json.loads(out)
    assumed = got["assumptions"]
    assert assumed["testbed"] == {"J_m": J_M, "d_m": D_M, "k": K}
    assert (assumed["environment"]["J_l"], assumed["environment"]["d_l"]) == (J_L, D_L)
    s = control.tf("s")
    P = K / (J_M * s**2 + D_M * s + K)
    Pn = K * (J_L * s + D_L) / (J_M * J_L * s**3 + J_M * D_L * s**2 + K * (J_M + J_L) * s + K * D_L)
    Q = _butterworth_q(10.0)
    L = control.minreal((5.0 + 0.1 * s) * P / (1 + Q * (P / Pn - 1)), verbose=False)
    w = np.logspace(-2, 4, 40001)
    alpha = np.min(control.disk_margins(L, w, skew=0.0)[0])
    assert got["disk_margin"] == pytest.approx(alpha, rel=2e-3)
    # with the paper's link the LD-DOB's loop differs, so the check above can tell them apart
    Pn_paper = K * (TABLE1_LINK[0] * s + TABLE1_LINK[1]) / (
        J_M * TABLE1_LINK[0] * s**3 + J_M * TABLE1_LINK[1] * s**2 + K * (J_M + TABLE1_LINK[0]) * s + K * TABLE1_LINK[1])
    L_paper = control.minreal((5.0 + 0.1 * s) * P / (1 + Q * (P / Pn_paper - 1)), verbose=False)
    assert abs(np.min(control.disk_margins(L_paper, w, skew=0.0)[0]) - alpha) > 0.01


def test_tune_q_plot_draws_the_given_testbed(mysea, tmp_path, capsys):
    png, js = tmp_path / "tq.png", tmp_path / "tq.json"
    code, _, err = _cli(capsys, "tune-q", "--observer", "ea-fob", "--testbed", mysea, "--env", mysea,
                        "--band", "1", "20", "--plot", png, "--json", js)
    assert code in (0, 1), err
    doc = json.loads(js.read_text())
    curve = doc["tradeoff"]
    i = curve["w_q_hz"].index(doc["w_q_hz"])
    # the plotted curve passes through the tuner's own worst ratio at its answer (same testbed, same set)
    assert curve["worst_ratio"][i] == pytest.approx(doc["worst_ratio"], rel=1e-9)
    assert set(curve["binding_environment"]) <= {f"e[k_e={k:.4g}]" for k in K_E} | {"held"}
    assert png.stat().st_size > 10_000
    # the trade-off of Table 1's testbed on the same set is another curve
    from forecast_design.tuning.tradeoff import cutoff_tradeoff

    table1 = cutoff_tradeoff("ea-fob", mysea, band_hz=(1.0, 20.0), chosen=doc["w_q_hz"])
    assert abs(table1.worst_ratio[table1.at(doc["w_q_hz"])] - doc["worst_ratio"]) > 0.01


SCENARIO = """format = "forecast-scenario/1"
description = "newcomer SEA with Coulomb friction, EA-FOB"
testbed = "mysea.toml"
environment = "mysea.toml#e[k_e=10]"

[sampling]
rate_hz = 2000.0

[controller]
kind = "pd"
P = 3.0
D = 0.02

[compensator]
kind = "ea-fob"
w_q_hz = 10.0

[[truth.effects]]
effect = "coulomb"
F_c = 0.1

[reference]
kind = "square"
high = 0.3
low = -0.3
period_s = 0.1

[simulation]
duration_s = 0.2
seed = 3
"""


def test_simulate_a_scenario_naming_the_testbed_file(mysea, tmp_path, capsys):
    scenario = tmp_path / "sc.toml"
    scenario.write_text(SCENARIO)
    code, _, err = _cli(capsys, "simulate", scenario, "--out", tmp_path / "run.toml")
    assert code == 0, err
    run = fd.load_experiment(tmp_path / "run.toml")
    tb, env = run.design.testbed, run.design.environment
    assert (tb.J_m, tb.d_m, tb.k) == (J_M, D_M, K)
    assert (env.k_e, env.J_e) == (10.0, J_E)
    _no_table1_link(env)
    # a [testbed] table with the link and an [environment] table that leaves the link to it
    table = SCENARIO.replace('testbed = "mysea.toml"\nenvironment = "mysea.toml#e[k_e=10]"\n', "")
    table += (f"\n[testbed]\nJ_m = {J_M}\nd_m = {D_M}\nk = {K}\nJ_l = {J_L}\nd_l = {D_L}\n"
              f"\n[environment]\nJ_e = {J_E}\nd_e = 0.5\nk_e = 10.0\n")
    (tmp_path / "sc2.toml").write_text(table)
    from forecast_design.simulation.scenario import load_scenario

    loaded = load_scenario(tmp_path / "sc2.toml")
    _no_table1_link(loaded.design.environment)
    # the scenario written back keeps its testbed's link
    from forecast_design.simulation.scenario import scenario_from_mapping

    assert scenario_from_mapping(loaded.to_mapping()).design == loaded.design
    # a testbed file that is not there: one line naming the scenario and the key
    (tmp_path / "sc3.toml").write_text(SCENARIO.replace('testbed = "mysea.toml"', 'testbed = "nosea.toml"'))
    code, _, err = _cli(capsys, "simulate", tmp_path / "sc3.toml", "--out", tmp_path / "r3.toml")
    assert code == 2 and "sc3.toml: testbed = 'nosea.toml'" in err and len(err.strip().splitlines()) == 1


def test_export_builds_the_ld_dob_on_the_users_link(mysea, tmp_path, capsys):
    code, out, err = _cli(capsys, "export", "--testbed", mysea, "--env", f"{mysea}#held", "--compensator", "ld-dob",
                          "--out", tmp_path / "c", "--json")
    assert code == 0, err
    said = json.loads(out)     # the JSON says what the C was built for, as the header does
    assert said["testbed"] == {"J_m": J_M, "d_m": D_M, "k": K}
    assert (said["environment"]["J_l"], said["environment"]["d_l"], said["environment"]["locked"]) == (J_L, D_L, True)
    header = (tmp_path / "c" / "fd_controller.h").read_text()
    assert f"J_m = {J_M}, d_m = {D_M}, k = {K}" in header and f"J_l = {J_L}, d_l = {D_L}" in header
    result = fd.export_controller(out_dir=tmp_path / "c2", compensator="ld-dob", env=f"{mysea}#held",
                                  testbed=str(mysea))
    _no_table1_link(result.design.environment)


@pytest.mark.slow
def test_benchmark_runs_the_users_sea_and_says_so(mysea, tmp_path, capsys):
    code, out, err = _cli(capsys, "benchmark", "--testbed", mysea, "--envs", mysea, "--compensator", "none",
                          "--repetitions", "2", "--duration", "0.2", "--no-plots", "--workers", "1",
                          "--out", tmp_path / "bench", "--json")
    assert code == 0, err
    spec = json.loads(out)["benchmark"]
    assert spec["testbed"] == {"J_m": J_M, "d_m": D_M, "k": K}
    assert len(spec["environments"]) == len(K_E) + 1
    for env in spec["environments"].values():
        assert (env["J_l"], env["d_l"]) == (J_L, D_L)


@pytest.mark.parametrize("spec, words", [
    ("k=150000,J_m=60", ["k = 150000 N m/rad", "[0.5, 20000] N m/rad", "J_m = 60 kg m^2", "[1e-06, 10] kg m^2"]),
    ("J_m=60000", ["J_m = 60000 kg m^2", "benchtop SEA"]),
])
def test_values_in_the_wrong_unit_are_warned_naming_value_and_range(capsys, spec, words):
    code, _, err = _cli(capsys, "margins", "--testbed", spec)
    assert code == 0
    warnings = [line for line in err.splitlines() if line.startswith("forecast-design: warning:")]
    assert warnings and all(spec in line for line in warnings)
    for word in words:
        assert any(word in line for line in warnings), (word, err)


def test_the_newcomers_and_the_papers_testbeds_get_no_warning(mysea, capsys):
    for testbed in (mysea, "table1", "k=40"):
        code, _, err = _cli(capsys, "margins", "--testbed", testbed)
        assert code == 0 and "warning" not in err, err


def test_a_refusal_stays_a_refusal_beyond_the_hard_limits(capsys):
    code, _, err = _cli(capsys, "margins", "--testbed", "J_m=1e300")
    assert code == 2 and "J_m" in err and "plausible range" in err and len(err.strip().splitlines()) == 1


def test_python_api_takes_a_one_member_set_and_names_a_wrong_argument(mysea):
    member = resolve_environments(f"{mysea}#held", testbed=resolve_testbed(mysea))
    design = fd.Design(testbed=resolve_testbed(mysea), environment=member)
    assert design.environment == member["held"] and design.environment.locked
    with pytest.raises(ParameterError, match=r"needs one environment, got 6"):
        fd.Design(environment=resolve_environments(mysea))
    with pytest.raises(ParameterError, match=r"Compensator\(\) has no parameter 'w_q'; did you mean w_q_hz\?") as info:
        fd.Compensator(w_q=20)
    assert "\n" not in str(info.value) and info.value.name == "w_q"
    with pytest.raises(ParameterError, match=r"Environment\(\) needs J_e, d_e"):
        fd.Environment(k_e=1.0)
    with pytest.raises(ParameterError, match="keyword arguments only"):
        fd.Testbed(0.06)


def test_a_cli_number_error_names_no_internal_function(capsys):
    with pytest.raises(SystemExit) as info:     # argparse's own exit
        main(["margins", "--skew", "abc"])
    code, err = info.value.code, capsys.readouterr().err
    assert code == 2 and "_float_range" not in err and "expected a number, got 'abc'" in err


def test_an_environment_file_with_its_testbed_needs_no_testbed_option(mysea, tmp_path, capsys):
    """`--env mysea.toml#...` alone uses the file's [testbed], never Table 1's J_m, d_m, k (said in a note)."""
    first = f"{mysea}#e[k_e=2]"
    code, out, err = _cli(capsys, "margins", "--env", first, "--compensator", "ld-dob", "--json")
    assert code == 0, err
    alone = json.loads(out)
    assert "note: testbed from" in err and "mysea.toml's [testbed]" in err
    code, out, err = _cli(capsys, "margins", "--env", first, "--testbed", mysea, "--compensator", "ld-dob", "--json")
    assert code == 0, err
    given = json.loads(out)
    assert alone["assumptions"]["testbed"] == given["assumptions"]["testbed"] == {"J_m": J_M, "d_m": D_M, "k": K}
    assert alone["disk_margin"] == given["disk_margin"]
    # the benchmark too
    code, out, err = _cli(capsys, "benchmark", "--envs", mysea, "--compensator", "none", "--repetitions", "2",
                          "--duration", "0.2", "--no-plots", "--workers", "1", "--out", tmp_path / "bench", "--json")
    assert json.loads(out)["benchmark"]["testbed"] == {"J_m": J_M, "d_m": D_M, "k": K}
    assert "mysea.toml's [testbed]" in err


def test_link_given_is_a_flag_or_unset():
    with pytest.raises(ParameterError, match="link_given must be true, false or unset"):
        fd.Environment(J_e=0.1, d_e=0.3, k_e=5.0, link_given="yes")
    assert fd.Environment(J_e=0.1, d_e=0.3, k_e=5.0, link_given=True).link_given
