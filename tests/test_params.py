"""Parameter dataclasses: presets from the paper, validation at the boundary."""

import dataclasses
import math

import pytest
from hypothesis import given, strategies as st

from forecast_design import (
    ENVIRONMENT_PRESETS,
    Compensator,
    Design,
    Environment,
    ExperimentFormatError,
    ParameterError,
    PD,
    Testbed,
    environment_preset,
)


def test_testbed_nominal_is_paper_table_1():
    tb = Testbed.nominal()
    assert (tb.J_m, tb.d_m, tb.k) == (0.133, 0.3, 58.0)


@pytest.mark.parametrize("name,k_e,J_e", [("soft", 0.1, 1e-3), ("stiff", 100.0, 0.1)])
def test_section5_presets_are_critically_damped(name, k_e, J_e):
    env = environment_preset(name)
    assert (env.k_e, env.J_e) == (k_e, J_e)
    # critical damping of J_e q'' + d_e q' + k_e q: zeta = d_e / (2 sqrt(k_e J_e)) = 1
    assert env.d_e / (2.0 * math.sqrt(env.k_e * env.J_e)) == pytest.approx(1.0, rel=1e-15)
    assert (env.J_l, env.d_l) == (0.0018, 0.35)
    assert env.J == pytest.approx(J_e + 0.0018) and env.d == pytest.approx(env.d_e + 0.35)


def test_other_presets_match_paper_sections():
    assert (ENVIRONMENT_PRESETS["fig7"].k_e, ENVIRONMENT_PRESETS["fig7"].J_e) == (100.0, 1.0)
    assert (ENVIRONMENT_PRESETS["exp-soft"].k_e, ENVIRONMENT_PRESETS["exp-soft"].J_e) == (5.0, 0.001)
    assert ENVIRONMENT_PRESETS["locked"].locked
    link = ENVIRONMENT_PRESETS["link-only"]
    assert (link.k_e, link.J_e, link.d_e, link.J_l, link.d_l) == (0.0, 0.0, 0.0, 0.0018, 0.35)
    for name, env in ENVIRONMENT_PRESETS.items():
        assert (env.J_l, env.d_l) == (0.0018, 0.35), name


def test_unknown_preset_lists_known_names():
    with pytest.raises(ParameterError, match="unknown environment 'squishy'.*soft.*stiff"):
        environment_preset("squishy")


@pytest.mark.parametrize("field", ["J_m", "k"])
@given(value=st.floats(max_value=0.0, allow_nan=False, allow_infinity=False))
def test_nonpositive_testbed_inertia_or_stiffness_raises(field, value):
    with pytest.raises(ParameterError, match=f"{field} must be > 0"):
        Testbed(**{field: value})


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1.0", True, None])
def test_non_numeric_or_non_finite_values_raise(bad):
    with pytest.raises(ParameterError, match="J_e"):
        Environment(J_e=bad, d_e=0.0, k_e=1.0)


def test_empty_environment_is_rejected_but_locked_is_not():
    with pytest.raises(ParameterError, match="all 0"):
        Environment(J_e=0.0, d_e=0.0, k_e=0.0, J_l=0.0, d_l=0.0)
    assert Environment(J_e=0.0, d_e=0.0, k_e=0.0, J_l=0.0, d_l=0.0, locked=True).locked


def test_from_mapping_rejects_unknown_and_missing_keys_naming_file():
    with pytest.raises(ExperimentFormatError, match=r"run\.toml: \[testbed\] unknown key 'K'") as info:
        Testbed.from_mapping({"J_m": 1.0, "d_m": 0.1, "K": 5.0}, source="run.toml")
    assert info.value.path == "run.toml" and info.value.key == "testbed.K"
    with pytest.raises(ExperimentFormatError, match=r"run\.toml: \[environment\] missing required key 'd_l'"):
        Environment.from_mapping({"J_e": 1.0, "d_e": 0.1, "k_e": 5.0, "J_l": 0.0}, source="run.toml")
    with pytest.raises(ExperimentFormatError, match=r"run\.toml: \[testbed\] .*k must be > 0"):
        Testbed.from_mapping({"J_m": 1.0, "d_m": 0.1, "k": -58.0}, source="run.toml")


def test_controller_and_compensator_tables_round_trip():
    pd = PD(P=5.0, D=0.1)
    assert PD.from_mapping(pd.to_mapping()) == pd
    comp = Compensator(kind="ea-fob", w_q_hz=10.0)
    assert comp.to_mapping() == {"kind": "ea-fob", "w_q_hz": 10.0}
    assert Compensator.from_mapping(comp.to_mapping()) == comp
    # the format's optional Q keys are written only when they differ from the defaults, and read back
    q = Compensator(kind="ea-fob", w_q_hz=5.0, q_family="binomial", q_order=3)
    assert q.to_mapping() == {"kind": "ea-fob", "w_q_hz": 5.0, "q_family": "binomial", "q_order": 3}
    assert Compensator.from_mapping(q.to_mapping()) == q
    with pytest.raises(ExperimentFormatError, match=r"\[compensator\] key 'w_q_hz' does not belong to kind 'sfm'"):
        Compensator.from_mapping({"kind": "sfm", "w_q_hz": 3}, source="x.toml")
    with pytest.raises(ExperimentFormatError, match=r"\[compensator\] key 'q_shape' does not belong"):
        Compensator.from_mapping({"kind": "ea-fob", "q_shape": 3}, source="x.toml")
    with pytest.raises(ExperimentFormatError, match=r"\[controller\] kind must be 'pd'"):
        PD.from_mapping({"kind": "pid", "P": 1.0, "D": 0.0}, source="x.toml")


@pytest.mark.parametrize("kwargs,match", [
    ({"kind": "kalman"}, "kind must be one of"),
    ({"kind": "ea-fob", "w_q_hz": 0.0}, "w_q_hz must be > 0"),
    ({"kind": "ea-fob", "q_family": "chebyshev"}, "q_family"),
    ({"kind": "ea-fob", "q_order": 0}, "q_order"),
])
def test_compensator_validation(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        Compensator(**kwargs)


def test_parameters_are_frozen_and_replace_validates():
    tb = Testbed()
    with pytest.raises(dataclasses.FrozenInstanceError):
        tb.k = 1.0  # type: ignore[misc]
    assert dataclasses.replace(tb, k=40.0).k == 40.0
    with pytest.raises(ParameterError):
        dataclasses.replace(tb, k=-1.0)


def test_design_parameters_flatten_environment_sums():
    p = Design.nominal("stiff").parameters()
    assert p["J"] == pytest.approx(0.1 + 0.0018) and p["d"] == pytest.approx(2 * math.sqrt(10.0) + 0.35)
    assert p["k_e"] == 100.0 and p["J_m"] == 0.133


def test_sfm_compensator_carries_its_identified_friction():
    import numpy as np

    from forecast_design.export.c import program_for_export
    from forecast_design.simulation import references as refs
    from forecast_design.simulation import simulate

    params = {"viscous": 0.3, "coulomb": 0.35, "sin1": 0.02}
    comp = Compensator(kind="sfm", friction=params)
    assert comp.friction_params == params and hash(comp) == hash(Compensator(kind="sfm", friction=params))
    # the experiment format's [compensator.friction] sub-table: a run with an SFM replays without its log
    assert comp.to_mapping() == {"kind": "sfm", "friction": params}
    assert Compensator.from_mapping(comp.to_mapping()) == comp
    design = Design.nominal("exp-soft", controller=PD(), compensator=comp)
    plain = Design.nominal("exp-soft", controller=PD(), compensator=Compensator(kind="sfm"))
    kw = dict(reference=refs.Step(amplitude=0.2), duration_s=0.2, process_noise_std=0.0)
    np.testing.assert_array_equal(simulate(design, **kw).tau_m, simulate(plain, sfm_params=params, **kw).tau_m)
    assert program_for_export(design).info == program_for_export(plain.with_friction(params)).info
    with pytest.raises(ParameterError, match="apply to kind 'sfm'"):
        Compensator(kind="ea-fob", friction=params)
    with pytest.raises(ParameterError, match="friction"):
        Compensator(kind="sfm", friction={"coulomb": float("nan")})
