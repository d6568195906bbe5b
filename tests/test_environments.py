"""Environment sets and testbeds from presets, inline values and TOML files (forecast_design.environments)."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings

from forecast_design import (
    ENVIRONMENT_PRESETS,
    Environment,
    ExperimentFormatError,
    ParameterError,
    Testbed,
    load_experiment,
)
from forecast_design.environments import EnvironmentSet, resolve_environments, resolve_testbed

import strategies

SPEC_EXAMPLE = "tests/data/spec_example.toml"


def _write(tmp_path, text, name="envs.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_presets_and_comma_lists_resolve_to_the_paper_presets_in_order():
    s = resolve_environments("stiff, soft")
    assert s.names == ("stiff", "soft")
    assert s.environments == (ENVIRONMENT_PRESETS["stiff"], ENVIRONMENT_PRESETS["soft"])
    assert len(s) == 2 and list(s) == list(s.items()) == list(zip(s.names, s.environments))
    assert s["soft"] is ENVIRONMENT_PRESETS["soft"]


def test_inline_values_default_to_critical_damping_and_the_table1_link_and_say_so():
    # Section 5's stiff environment is k_e 100, J_e 0.1, critically damped, on the Table 1 link
    s = resolve_environments("k_e=100,J_e=0.1")
    assert s.environments[0] == ENVIRONMENT_PRESETS["stiff"]
    assert any("critically damped" in note for note in s.notes)
    given_d = resolve_environments("k_e=20,J_e=0.02,d_e=0.5,J_l=0.01,d_l=0,name=mine")
    assert given_d.names == ("mine",) and given_d.notes == ()
    assert given_d.environments[0] == Environment(J_e=0.02, d_e=0.5, k_e=20.0, J_l=0.01, d_l=0.0)
    locked = resolve_environments("locked=true").environments[0]
    assert locked.locked and locked == ENVIRONMENT_PRESETS["locked"]


@settings(max_examples=40)
@given(env=strategies.environments(locked=False))
def test_inline_text_of_any_environment_reads_back_exactly(env):
    text = f"k_e={env.k_e!r},J_e={env.J_e!r},d_e={env.d_e!r},J_l={env.J_l!r},d_l={env.d_l!r}"
    assert resolve_environments(text).environments == (env,)


@settings(max_examples=25)
@given(tb=strategies.testbeds())
def test_inline_testbed_reads_back_exactly(tb):
    assert resolve_testbed(f"J_m={tb.J_m!r},d_m={tb.d_m!r},k={tb.k!r}") == tb


def test_random_sets_are_seeded_log_uniform_and_critically_damped():
    a, b = resolve_environments("random:20", seed=3), resolve_environments("random:20", seed=3)
    assert a == b and a != resolve_environments("random:20", seed=4)
    for env in a.environments:
        assert 0.1 <= env.k_e <= 1000.0 and 1e-3 <= env.J_e <= 1.0
        assert env.d_e == pytest.approx(2.0 * math.sqrt(env.k_e * env.J_e), rel=1e-15)


def test_log_grid_of_seven_stiffnesses_is_geometric_with_exact_ends(tmp_path):
    path = _write(tmp_path, '[[environment]]\nname = "wall"\nk_e = {log = [0.1, 100], n = 7}\nJ_e = 0.01\n')
    s = resolve_environments(path)
    k = np.array([env.k_e for env in s.environments])
    assert len(s) == 7 and k[0] == pytest.approx(0.1, rel=1e-15) and k[-1] == pytest.approx(100.0, rel=1e-15)
    np.testing.assert_allclose(k[1:] / k[:-1], 10 ** 0.5, rtol=1e-12)   # 3 decades in 6 steps
    assert s.names[0] == "wall[k_e=0.1]" and s.source == str(path)
    for env in s.environments:
        assert env.d_e == pytest.approx(2.0 * math.sqrt(env.k_e * 0.01), rel=1e-15)


def test_linear_grids_lists_and_nominal_uncertainty_form_a_product(tmp_path):
    path = _write(tmp_path, """
[[environment]]
name = "a"
k_e = {lin = [1, 3], n = 3}
J_e = [0.1, 0.2]
d_e = 0.5

[[environment]]
name = "b"
k_e = {nominal = 5.0, rel = 0.2}
J_e = {nominal = 0.001, rel = 0.5}
d_e = 0.063
""")
    s = resolve_environments(path)
    a = [(e.k_e, e.J_e) for n, e in s if n.startswith("a[")]
    assert sorted(a) == [(k, j) for k in (1.0, 2.0, 3.0) for j in (0.1, 0.2)]
    b = {(round(e.k_e, 12), round(e.J_e, 12)) for n, e in s if n.startswith("b[")}
    # {1 - rel, 1, 1 + rel} x nominal on each uncertain key: the 4 corners, the nominal, the edge mid-points
    assert b == {(k, j) for k in (4.0, 5.0, 6.0) for j in (0.0005, 0.001, 0.0015)}
    assert all(e.d_e == 0.063 for n, e in s if n.startswith("b["))


def test_one_environment_table_and_a_runs_toml(tmp_path):
    path = _write(tmp_path, '[environment]\nJ_e = 0.001\nd_e = 0.063\nk_e = 5.0\n', name="exp.toml")
    assert resolve_environments(path).environments == (ENVIRONMENT_PRESETS["exp-soft"],)
    design = load_experiment(SPEC_EXAMPLE).design
    assert resolve_environments(SPEC_EXAMPLE).environments == (design.environment,)
    # a run's testbed carries the run's link (the SEA's), the default of environments used with it
    env = design.environment
    assert resolve_testbed(SPEC_EXAMPLE) == dataclasses.replace(design.testbed, J_l=env.J_l, d_l=env.d_l)


def test_a_set_written_as_toml_reads_back_equal(tmp_path):
    s = resolve_environments(["soft", "k_e=20,J_e=0.02", "random:3", "locked"])
    path = _write(tmp_path, s.to_toml())
    back = resolve_environments(path)
    assert back.names == s.names and back.environments == s.environments


def test_iterables_mix_objects_presets_sets_and_keep_identical_repeats_once():
    env = Environment(J_e=0.02, d_e=0.3, k_e=20.0)
    s = resolve_environments([env, "soft", resolve_environments("stiff"), "soft"])
    assert s.environments == (env, ENVIRONMENT_PRESETS["soft"], ENVIRONMENT_PRESETS["stiff"])
    assert resolve_environments({"mine": env}).names == ("mine",)
    assert resolve_environments(ENVIRONMENT_PRESETS["stiff"]).names == ("stiff",)
    with pytest.raises(ParameterError, match="'soft' given twice"):
        resolve_environments(["soft", {"soft": env}])


def test_designs_attach_the_testbed_and_single_refuses_a_set():
    tb = resolve_testbed("k=40")
    assert tb == Testbed(k=40.0)
    designs = resolve_environments("soft,stiff").designs(tb)
    assert [d.testbed for _, d in designs] == [tb, tb]
    with pytest.raises(ParameterError, match="export needs one environment, got 2"):
        resolve_environments("soft,stiff").single("export")
    assert resolve_environments("soft").single() == ("soft", ENVIRONMENT_PRESETS["soft"])


def test_testbed_files_keep_table1_for_missing_keys(tmp_path):
    path = _write(tmp_path, "[testbed]\nk = 40.0\n", name="tb.toml")
    assert resolve_testbed(path) == Testbed(J_m=0.133, d_m=0.3, k=40.0)
    assert resolve_testbed(None) == resolve_testbed("table1") == Testbed.nominal()


@pytest.mark.parametrize("spec,match", [
    ("softt", "unknown environment 'softt'"),
    ("k_e=20,Je=0.02", "unknown key 'Je'"),
    ("k_e=twenty,J_e=0.02", "k_e must be a number"),
    ("J_e=0.02", "missing k_e"),
    ("k_e=-1,J_e=0.02", "k_e must be >= 0"),
    ("k_e=1,J_e=1,locked=maybe", "locked must be true or false"),
    ("k_e=1,k_e=2,J_e=1", "'k_e' given twice"),
    ("random:x", "expected random:N"),
    ("random:0", "expected random:N"),
    ("", "empty"),
    ([], "empty"),
    (3.5, "cannot read environments from float"),
])
def test_bad_inline_specs_are_one_line_parameter_errors(spec, match):
    with pytest.raises(ParameterError, match=match) as info:
        resolve_environments(spec)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("text,match", [
    ("[[environment]]\nname = 'a'\nk_E = 1.0\n", r"\[\[environment\]\] #1 unknown key 'k_E'"),
    ("[[environment]]\nk_e = {log = [0.1, 100], n = 1}\nJ_e = 1.0\n", r"k_e n must be an integer in \[2, 10000\]"),
    ("[[environment]]\nk_e = {log = [-1, 100], n = 3}\nJ_e = 1.0\n", "log grid ends must be > 0"),
    ("[[environment]]\nk_e = {nominal = 5.0, rel = 1.5}\nJ_e = 1.0\n", r"rel must be in \[0, 1\)"),
    ("[[environment]]\nk_e = {nominal = 5.0}\nJ_e = 1.0\n", "k_e table must be"),
    ("[[environment]]\nk_e = 'stiff'\nJ_e = 1.0\n", "k_e must be a number"),
    ("[[environment]]\nk_e = nan\nJ_e = 1.0\n", "k_e must be a finite number"),
    ("[[environment]]\nk_e = -1.0\nJ_e = 1.0\n", "k_e must be >= 0"),
    ("[[environment]]\nJ_e = 1.0\n", "missing k_e"),
    ("[[environment]]\nname='a'\nk_e=1.0\nJ_e=1.0\n[[environment]]\nname='a'\nk_e=2.0\nJ_e=1.0\n",
     "name 'a' is used twice"),
    ("envs = 3\n", "unknown top-level key 'envs'"),
    ("description = 'nothing'\n", r"no \[environment\] table"),
    ("[environment\n", "TOML syntax error"),
])
def test_bad_files_name_the_file_table_and_key(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(ExperimentFormatError, match=match) as info:
        resolve_environments(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_files_and_bad_testbeds_are_one_line_errors(tmp_path):
    with pytest.raises(ExperimentFormatError, match="environment file not found"):
        resolve_environments(tmp_path / "nope.toml")
    with pytest.raises(ExperimentFormatError, match="testbed file not found"):
        resolve_testbed(str(tmp_path / "nope.toml"))
    with pytest.raises(ParameterError, match="expected key=value with keys J_m, d_m, k, J_l, d_l"):
        resolve_testbed("kk=40")
    with pytest.raises(ParameterError, match="k must be > 0"):
        resolve_testbed("k=0")
    path = _write(tmp_path, "[testbed]\nk = 40.0\nJ_l = 1.0\n", name="tb.toml")
    with pytest.raises(ExperimentFormatError, match=r"tb\.toml: \[testbed\] J_l given without d_l"):
        resolve_testbed(path)
    path = _write(tmp_path, "[testbed]\nk = 40.0\nJ_l = 0.01\nd_l = 0.1\nK_l = 1\n", name="tb2.toml")
    with pytest.raises(ExperimentFormatError, match=r"tb2\.toml: \[testbed\] unknown key 'K_l'"):
        resolve_testbed(path)


def test_environment_set_checks_its_own_fields():
    with pytest.raises(ParameterError, match="2 names for 1 environments"):
        EnvironmentSet(("a", "b"), (ENVIRONMENT_PRESETS["soft"],))
    with pytest.raises(ParameterError, match="not an Environment"):
        EnvironmentSet(("a",), ("soft",))


def test_one_member_of_a_set_file_is_named_with_a_hash(tmp_path, capsys):
    from forecast_design.cli import main
    from forecast_design.simulation.scenario import load_scenario

    f = tmp_path / "set.toml"
    f.write_text('[[environment]]\nname = "gripper"\nk_e = 20.0\nJ_e = 0.02\n\n'
                 '[[environment]]\nname = "wall"\nk_e = 500.0\nJ_e = 1.0\n')
    whole = resolve_environments(f)
    one = resolve_environments(f"{f}#wall")
    assert one.names == ("wall",) and one["wall"] == whole["wall"]
    mixed = resolve_environments(f"soft,{f}#gripper")
    assert mixed.names == ("soft", "gripper") and mixed["gripper"] == whole["gripper"]
    with pytest.raises(ParameterError, match="no environment named 'door'.*gripper, wall"):
        resolve_environments(f"{f}#door")
    # every verb takes it (one resolver); a scenario's relative path is the scenario's folder's
    assert main(["margins", "--env", f"{f}#wall", "--json", str(tmp_path / "m.json")]) == 0
    from importlib.resources import files

    text = (files("forecast_design") / "data" / "example_scenario.toml").read_text()
    start, end = text.index("[environment]"), text.index("[controller]")
    scen = tmp_path / "s.toml"
    scen.write_text('environment = "set.toml#gripper"\n' + text[:start] + text[end:])
    assert load_scenario(scen).design.environment == whole["gripper"]


def test_an_unknown_member_of_a_set_file_is_one_line_exit_2(tmp_path, capsys):
    from forecast_design.cli import main

    f = tmp_path / "set.toml"
    f.write_text('[[environment]]\nname = "gripper"\nk_e = 20.0\nJ_e = 0.02\n')
    assert main(["margins", "--env", f"{f}#door"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no environment named 'door'" in err[0] and "gripper" in err[0]
