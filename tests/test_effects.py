"""The unmodelled-effect vocabulary and its parameter values."""

import re
from pathlib import Path

import pytest

from forecast_design.effects import (
    EFFECT_CLASSES,
    Backlash,
    Cogging,
    Coulomb,
    Delay,
    Effect,
    EnvironmentMismatch,
    NoEffect,
    PositionFriction,
    Stiction,
    TorqueGain,
    effect_from_mapping,
)
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.params import environment_preset

SPEC = Path(__file__).resolve().parents[1].parent / "shared" / "spec" / "experiment-format.md"
PAPER = Path(__file__).resolve().parents[1].parent / "shared" / "paper" / "ea-fob-paper.txt"


def test_effect_words_are_exactly_the_spec_table():
    if not SPEC.exists():
        pytest.skip("shared spec not available")
    text = SPEC.read_text(encoding="utf-8").split("## Unmodelled effects", 1)[1]
    words = re.findall(r"^\| `([a-z_]+)` \|", text, flags=re.M)
    assert words == [e.value for e in Effect]
    assert set(EFFECT_CLASSES) == set(Effect)


def test_stiction_defaults_are_table_2():
    s = Stiction()
    assert (s.F_s, s.F_c, s.sigma2, s.v_s, s.sigma1, s.sigma0) == (0.5, 0.4, 0.1, 0.01, 0.6, 260.0)
    if PAPER.exists():
        table = PAPER.read_text(encoding="utf-8").split("Table 2.", 1)[1][:600]
        assert "0.5 Nm" in table and "0.4 Nm" in table and "260" in table and "0.01" in table


@pytest.mark.parametrize("value", [
    NoEffect(), Coulomb(F_c=0.3), Stiction(F_s_a=(0.05, 0.01), F_s_b=(0.0, 0.02)),
    PositionFriction(F_c=0.2, a=(0.05, 0.02), b=(0.01, 0.0)), Cogging(a=(0.1,), b=(-0.05,)),
    Backlash(width_rad=2e-3), Delay(delay_s=5e-4), TorqueGain(gain=1.2),
    EnvironmentMismatch(k_e_scale=2.0), EnvironmentMismatch(environment=environment_preset("stiff")),
], ids=lambda v: str(v.effect))
def test_effect_mapping_round_trip(value):
    mapping = value.to_mapping()
    assert mapping["effect"] == value.effect.value
    assert effect_from_mapping(mapping) == value
    assert type(value).from_mapping({k: v for k, v in mapping.items() if k != "effect"}) == value


def test_unknown_key_and_word_name_the_key_and_file():
    with pytest.raises(ExperimentFormatError, match=r"s\.toml: \[truth\.effects\[1\]\] unknown key 'Fc'") as exc:
        effect_from_mapping({"effect": "coulomb", "Fc": 0.3}, source="s.toml", where="truth.effects[1]")
    assert exc.value.key == "truth.effects[1].Fc" and exc.value.path == "s.toml"
    with pytest.raises(ExperimentFormatError, match="effect must be one of"):
        effect_from_mapping({"effect": "viscosity"})
    with pytest.raises(ExperimentFormatError, match="F_c must be >= 0"):
        effect_from_mapping({"effect": "coulomb", "F_c": -1.0})


@pytest.mark.parametrize("make,match", [
    (lambda: Coulomb(F_c=-0.1), "F_c must be >= 0"),
    (lambda: Stiction(sigma0=0.0), "sigma0 must be > 0"),
    (lambda: Stiction(F_s=0.1, F_s_a=(0.2,), F_s_b=(0.0,)), "g\\(v\\) > 0"),
    (lambda: PositionFriction(F_c=0.05, a=(0.05,), b=(0.01,)), "magnitude"),
    (lambda: Cogging(a=(0.1, 0.2), b=(0.1,)), "same length"),
    (lambda: TorqueGain(gain=0.0), "gain must be > 0"),
    (lambda: Delay(delay_s=-1e-3), "delay_s must be >= 0"),
    (lambda: Backlash(width_rad=float("nan")), "finite"),
])
def test_invalid_effect_parameters_raise(make, match):
    with pytest.raises(ParameterError, match=match):
        make()


def test_environment_mismatch_scales_the_nominal_environment():
    nominal = environment_preset("exp-soft")
    true = EnvironmentMismatch(J_scale=2.0, d_scale=0.5, k_e_scale=3.0).true_environment(nominal)
    assert true.J == pytest.approx(2.0 * nominal.J)
    assert true.d == pytest.approx(0.5 * nominal.d)
    assert true.k_e == pytest.approx(3.0 * nominal.k_e)
    stiff = environment_preset("stiff")
    assert EnvironmentMismatch(environment=stiff, k_e_scale=9.0).true_environment(nominal) == stiff


def test_effect_is_a_str_enum_usable_as_a_word():
    assert Effect("backlash") is Effect.BACKLASH
    assert f"{Effect.TORQUE_GAIN}" == "torque_gain"
