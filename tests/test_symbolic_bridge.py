"""ParametricTF evaluation, the model catalogue and the tf-verb compute function."""

import dataclasses
import json
import math

import control
import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from forecast_design.errors import ParameterError
from forecast_design.lti import RationalTF
from forecast_design.params import Design, Environment, Testbed
from forecast_design.symbolic import (
    derive_force_plant,
    derive_locked_force_plant,
    derive_motor_angle_plant,
    force_plant_tf,
    nominal_plant,
    q_filter_tf,
    transfer_functions,
)
from forecast_design.symbolic import plant as pl


def _hand_built_plant(design: Design, *, d_m: float | None = None):
    """P = tau_s/tau_m from python-control blocks: 1/(J_m s^2 + d_m s), k, 1/E."""
    tb, env = design.testbed, design.environment
    d_m = tb.d_m if d_m is None else d_m
    motor = control.tf([1.0], [tb.J_m, d_m, 0.0])           # theta = motor (tau_m - tau_s)
    spring = control.feedback(control.tf([tb.k], [1.0]),      # tau_s = k (theta - tau_s / E)
                              control.tf([1.0], [env.J, env.d, env.k_e]))
    return control.feedback(motor * spring, 1)


def _normalized(num, den):
    num, den = np.trim_zeros(np.asarray(num, float), "f"), np.trim_zeros(np.asarray(den, float), "f")
    return num / den[0], den / den[0]


def test_force_plant_stiff_matches_python_control_interconnection():
    design = Design.nominal("stiff")
    ours = force_plant_tf(design).normalized()
    ref = _hand_built_plant(design)
    num, den = _normalized(ref.num[0][0], ref.den[0][0])
    np.testing.assert_allclose(ours.num, num, rtol=1e-9)
    np.testing.assert_allclose(ours.den, den, rtol=1e-9)


def test_locked_plant_dc_gain_one_and_resonance():
    tf = force_plant_tf(Design.nominal("locked"))
    assert tf.dcgain() == pytest.approx(1.0, abs=1e-12)
    # |p|^2 = k / J_m for the pole pair of J_m s^2 + d_m s + k.
    np.testing.assert_allclose(np.abs(tf.poles()), math.sqrt(58.0 / 0.133), rtol=1e-12)
    assert math.sqrt(58.0 / 0.133) == pytest.approx(20.88, abs=0.005)


def test_ea_nominal_is_force_plant_without_motor_damping():
    design = Design.nominal("fig7")
    ea = nominal_plant("ea-fob").at(design).normalized()
    ref = _hand_built_plant(design, d_m=0.0)
    num, den = _normalized(ref.num[0][0], ref.den[0][0])
    np.testing.assert_allclose(ea.num, num, rtol=1e-9)
    np.testing.assert_allclose(ea.den, den, rtol=1e-9)


def test_motor_angle_plant_matches_python_control():
    design = Design.nominal("exp-soft")
    tb, env = design.testbed, design.environment
    spring = control.feedback(control.tf([tb.k], [1.0]), control.tf([1.0], [env.J, env.d, env.k_e]))
    ref = control.feedback(control.tf([1.0], [tb.J_m, tb.d_m, 0.0]), spring)
    ours = derive_motor_angle_plant().at(design)
    for w in (0.1, 3.0, 50.0, 400.0):
        assert ours(1j * w) == pytest.approx(complex(ref(1j * w)), rel=1e-10)


def test_free_output_strips_exact_rigid_body_factor():
    design = Design.nominal("link-only")  # k_e = 0: P has s in numerator and denominator
    tf = force_plant_tf(design)
    assert tf.num[-1] != 0.0 and tf.den[-1] != 0.0
    ref = _hand_built_plant(design)
    for w in (0.05, 2.0, 80.0):
        assert tf(1j * w) == pytest.approx(complex(ref(1j * w)), rel=1e-10)


@pytest.mark.parametrize("order", [2, 3, 4, 5])
def test_butterworth_q_matches_scipy_and_half_power(order):
    w_q_hz = 7.0
    w = 2 * math.pi * w_q_hz
    q = q_filter_tf("butterworth", order, w_q_hz).normalized()
    b, a = signal.butter(order, w, analog=True)
    np.testing.assert_allclose(q.den, a / a[0], rtol=1e-12)
    np.testing.assert_allclose(q.num, b / a[0], rtol=1e-12)
    assert abs(q(1j * w)) == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    assert q.dcgain() == pytest.approx(1.0, rel=1e-14)


def test_at_missing_parameter_raises_naming_it():
    with pytest.raises(ParameterError) as info:
        derive_force_plant().at({"J_m": 0.1, "d_m": 0.0, "k": 10.0, "J": 1.0, "d": 1.0})
    assert info.value.name == "k_e"


def test_latex_uses_paper_symbols():
    tex = derive_locked_force_plant().latex()
    assert "J_{m}" in tex and "d_{m}" in tex and r"\frac" in tex


def test_transfer_functions_mapping_shape_and_values():
    design = Design.nominal("stiff")
    out = transfer_functions(design).to_mapping()
    json.dumps(out)
    assert set(out) == {"P", "EA", "LO", "LD"}
    for entry in out.values():
        assert set(entry) == {"latex", "num", "den", "poles", "dc_gain"}
        assert entry["den"][0] == 1.0
    # P(0) = k_e / (k_e + 0) ... DC: E(0) / ((E(0)/k + 1) * 0 + E(0)) = 1 for k_e > 0.
    assert out["P"]["dc_gain"] == pytest.approx(1.0)
    # LO = k / (J_m s^2 + k): undamped poles at +-j sqrt(k/J_m).
    np.testing.assert_allclose(sorted(abs(p[1]) for p in out["LO"]["poles"]), [math.sqrt(58 / 0.133)] * 2)
    assert max(abs(p[0]) for p in out["LO"]["poles"]) < 1e-9
    # LD DC gain k d_l / (k d_l) = 1.
    assert out["LD"]["dc_gain"] == pytest.approx(1.0)
    # LO does not depend on the environment.
    assert transfer_functions(Design.nominal("soft")).to_mapping()["LO"]["num"] == out["LO"]["num"]


def test_transfer_functions_locked_ea_equals_lo():
    out = transfer_functions(Design.nominal("locked")).to_mapping()
    assert out["EA"]["num"] == out["LO"]["num"] and out["EA"]["den"] == out["LO"]["den"]
    assert out["P"]["dc_gain"] == pytest.approx(1.0)


def test_transfer_functions_ld_uses_design_link():
    base = Design.nominal("soft")
    heavy = dataclasses.replace(base, environment=dataclasses.replace(base.environment, J_l=0.01, d_l=0.5))
    ld = transfer_functions(heavy).LD.tf
    expected = pl.paper_nominal_ld_expr().subs({pl.J_m: 0.133, pl.k: 58.0, pl.J_l: 0.01, pl.d_l: 0.5})
    for x in (0.5j, 30j):
        assert ld(x) == pytest.approx(complex(expected.subs(pl.s, x).evalf()), rel=1e-12)


# --- hypothesis: lambdified coefficients == sympy subs, and casadi agrees --------------------

_designs = st.builds(
    lambda J_m, d_m, k, J_e, d_e, k_e, J_l, d_l: Design(
        testbed=Testbed(J_m=J_m, d_m=d_m, k=k),
        environment=Environment(J_e=J_e, d_e=d_e, k_e=k_e, J_l=J_l, d_l=d_l),
    ),
    J_m=st.floats(1e-3, 1.0), d_m=st.floats(0.0, 2.0), k=st.floats(1.0, 500.0),
    J_e=st.floats(0.0, 2.0), d_e=st.floats(0.0, 20.0), k_e=st.floats(0.0, 1000.0),
    J_l=st.floats(1e-4, 0.05), d_l=st.floats(0.0, 1.0),
)

_PARAMETRIC = [derive_force_plant, derive_locked_force_plant, derive_motor_angle_plant,
               lambda: nominal_plant("ea-fob"), lambda: nominal_plant("lo-dob"),
               lambda: nominal_plant("ld-dob")]


@settings(max_examples=25, deadline=None)
@given(design=_designs, w=st.floats(1e-2, 1e3), which=st.integers(0, len(_PARAMETRIC) - 1))
def test_parametric_at_and_casadi_match_sympy_subs(design, w, which):
    ptf = _PARAMETRIC[which]()
    params = design.parameters()
    subs = {sym: params[sym.name] for sym in ptf.symbols}
    expected = complex(sp.N(ptf.expr.subs(subs).subs(pl.s, sp.I * w), 30))
    got = ptf.at(design)(1j * w)
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-12 * abs(expected))
    f = ptf.casadi()
    re, im = f(w, [params[name] for name in ptf.symbol_names])
    assert complex(float(re), float(im)) == pytest.approx(expected, rel=1e-9, abs=1e-300)


def test_casadi_q_filter_with_irrational_coefficients():
    from forecast_design.symbolic.observers import _q_parametric

    ptf = _q_parametric("butterworth", 5)
    f = ptf.casadi()
    w_q = 2 * math.pi * 3.0
    re, im = f(w_q, [w_q])
    assert abs(complex(float(re), float(im))) == pytest.approx(1 / math.sqrt(2), rel=1e-12)


def test_plot_bode_writes_png(tmp_path):
    from forecast_design.plotting.bode import bode_data, plot_bode

    tfs = {env: force_plant_tf(Design.nominal(env)) for env in ("soft", "stiff", "locked")}
    path = plot_bode(tfs, tmp_path / "bode.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Magnitude of the locked plant at DC is 0 dB; phase tends to -180 deg well above resonance.
    f_hz, mag_db, phase_deg = bode_data(tfs["locked"], np.array([1e-3, 1e4]))
    assert mag_db[0] == pytest.approx(0.0, abs=1e-6)
    assert phase_deg[1] == pytest.approx(-180.0, abs=0.1)
    with pytest.raises(ParameterError):
        plot_bode([("x", "not a tf")], tmp_path / "bad.png")
    assert isinstance(tfs["soft"], RationalTF)
