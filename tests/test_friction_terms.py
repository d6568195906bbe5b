"""Friction terms: regressor columns, names, closed-form curves, dissipativity."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from forecast_design.errors import ParameterError
from forecast_design.friction import (
    MODEL_NAMES,
    AsymmetricCoulomb,
    AsymmetricViscous,
    Coulomb,
    FrictionModel,
    Harmonics,
    Inertia,
    LuGre,
    Offset,
    PositionFriction,
    Stribeck,
    Viscous,
    friction_model,
    lugre_force,
    stribeck_force,
)


def test_extended_sfm_regressor_is_paper_phi_in_order(rng):
    # Paper Section 7: phi = [theta', sign theta', s(theta), c(theta), ..., s(4 theta), c(4 theta)].
    v = rng.normal(size=50)
    th = rng.uniform(-10, 10, size=50)
    model = friction_model("extended-sfm")
    phi = np.column_stack([v, np.sign(v)] + [f(i * th) for i in range(1, 5) for f in (np.sin, np.cos)])
    assert model.names == ("viscous", "coulomb", "sin1", "cos1", "sin2", "cos2", "sin3", "cos3",
                           "sin4", "cos4")
    np.testing.assert_allclose(model.regressor(v, th), phi, rtol=0, atol=1e-12)


def test_terms_compose_like_named_model():
    composed = Viscous() + Coulomb() + Harmonics(n=4)
    assert isinstance(composed, FrictionModel)
    assert composed.names == friction_model("extended-sfm").names
    assert composed.is_linear and not composed.is_dynamic


def test_named_models_options_add_terms():
    m = friction_model("sfm", offset=True, estimate_inertia=True)
    assert m.names == ("inertia", "viscous", "coulomb", "offset")
    assert friction_model("asymmetric").names == ("viscous_pos", "viscous_neg", "coulomb_pos", "coulomb_neg")
    pf = friction_model("position-friction", harmonics=2)
    assert pf.names == ("viscous", "coulomb", "coulomb_sin1", "coulomb_cos1", "coulomb_sin2", "coulomb_cos2")
    assert friction_model("stribeck").names == ("static", "coulomb", "stribeck_velocity", "viscous")
    assert friction_model("lugre").is_dynamic
    assert set(MODEL_NAMES) == {"sfm", "extended-sfm", "asymmetric", "stribeck", "lugre", "position-friction"}


def test_asymmetric_columns_follow_direction():
    v = np.array([-2.0, -0.5, 0.0, 0.5, 2.0])
    p = {"viscous_pos": 3.0, "viscous_neg": 5.0, "coulomb_pos": 1.0, "coulomb_neg": 2.0}
    f = (AsymmetricViscous() + AsymmetricCoulomb()).predict(p, v)
    np.testing.assert_allclose(f, [-12.0, -4.5, 0.0, 2.5, 7.0])


def test_position_friction_is_sign_times_harmonics(rng):
    v = rng.normal(size=20)
    th = rng.uniform(-4, 4, size=20)
    cols = PositionFriction(n=3).columns(v, th, None)
    np.testing.assert_allclose(cols[:, 4], np.sign(v) * np.sin(3 * th))
    np.testing.assert_allclose(cols[:, 5], np.sign(v) * np.cos(3 * th))


def test_inertia_and_offset_columns():
    a = np.array([1.0, -2.0, 3.0])
    m = Inertia() + Offset()
    np.testing.assert_allclose(m.predict({"inertia": 0.5, "offset": -1.0}, np.zeros(3), None, a),
                               [-0.5, -2.0, 0.5])
    with pytest.raises(ParameterError, match="acceleration"):
        m.predict({"inertia": 0.5, "offset": -1.0}, np.zeros(3))


def test_stribeck_limits_are_static_and_coulomb_plus_viscous():
    fs, fc, vs, d = 0.5, 0.4, 0.01, 0.1
    assert stribeck_force(np.array([1e-9]), fs, fc, vs, d)[0] == pytest.approx(fs, rel=1e-9)
    assert stribeck_force(np.array([-1e-9]), fs, fc, vs, d)[0] == pytest.approx(-fs, rel=1e-9)
    assert stribeck_force(np.array([2.0]), fs, fc, vs, d)[0] == pytest.approx(fc + 2 * d, rel=1e-12)
    # At v = v_s the excess static friction has decayed by exp(-1).
    assert stribeck_force(np.array([vs]), fs, fc, vs, d)[0] == pytest.approx(
        fc + (fs - fc) / np.e + d * vs, rel=1e-12)


PAPER_LUGRE = dict(sigma0=260.0, sigma1=0.6, static=0.5, coulomb=0.4, stribeck_velocity=0.01, viscous=0.1)


def test_lugre_constant_velocity_reaches_stribeck_curve():
    # Steady state of dz/dt = v - sigma0 |v| z / g(v): sigma0 z = g(v) sign v, so F is the Stribeck curve.
    for v0 in (-0.3, 0.005, 1.0):
        f = lugre_force(np.full(20000, v0), 1e-3, **PAPER_LUGRE, z0=0.0)  # 20 s >> g / (sigma0 |v|)
        expected = stribeck_force(np.array([v0]), 0.5, 0.4, 0.01, 0.1)[0]
        assert f[-1] == pytest.approx(expected, rel=1e-6)


def test_lugre_backward_euler_matches_scipy_radau():
    p = PAPER_LUGRE
    w = 2 * np.pi * 0.5
    t = np.arange(0, 4.0, 1e-4)
    v = 0.5 * np.cos(w * t)

    def rhs(tt, z):
        vv = 0.5 * np.cos(w * tt)
        g = p["coulomb"] + (p["static"] - p["coulomb"]) * np.exp(-(vv / p["stribeck_velocity"]) ** 2)
        return [vv - p["sigma0"] * abs(vv) * z[0] / g]

    z0 = p["coulomb"] / p["sigma0"]  # steady state of v = +0.5 (g = F_c there)
    sol = solve_ivp(rhs, (0, t[-1]), [z0], t_eval=t, method="Radau", rtol=1e-10, atol=1e-14)
    zd = np.array([rhs(a, [b])[0] for a, b in zip(t, sol.y[0])])
    f_ref = p["sigma0"] * sol.y[0] + p["sigma1"] * zd + p["viscous"] * v
    f = LuGre().evaluate(p, v, dt=1e-4)
    # First-order method at dt = 0.1 ms against a tight implicit reference.
    assert np.max(np.abs(f - f_ref)) < 0.02 * np.max(np.abs(f_ref))
    assert np.sqrt(np.mean((f - f_ref) ** 2)) < 2e-3


def test_lugre_predict_needs_dt():
    with pytest.raises(ParameterError, match="dt"):
        friction_model("lugre").predict(PAPER_LUGRE, np.ones(3))


def test_model_validation_errors():
    with pytest.raises(ParameterError, match="duplicate parameter"):
        Viscous() + Viscous()
    with pytest.raises(ParameterError, match="at most one nonlinear"):
        Stribeck() + LuGre()
    with pytest.raises(ParameterError, match="unknown friction model 'dahl'"):
        friction_model("dahl")
    with pytest.raises(ParameterError, match="harmonics"):
        friction_model("sfm", harmonics=-1)
    with pytest.raises(ParameterError, match="n must be an integer"):
        Harmonics(n=0)
    with pytest.raises(ParameterError, match="missing parameter"):
        friction_model("sfm").predict({"viscous": 1.0}, np.ones(2))


physical = st.floats(min_value=0.0, max_value=50.0, allow_nan=False)
velocities = st.lists(st.floats(min_value=-100.0, max_value=100.0, allow_nan=False), min_size=1, max_size=30)


@settings(max_examples=60, deadline=None)
@given(v=velocities, d=physical, fc=physical, extra=physical,
       vs=st.floats(min_value=1e-4, max_value=10.0), dp=physical, dn=physical, cp=physical, cn=physical)
def test_dissipative_terms_never_add_energy(v, d, fc, extra, vs, dp, dn, cp, cn):
    v = np.asarray(v)
    sfm = friction_model("sfm").predict({"viscous": d, "coulomb": fc}, v)
    stri = stribeck_force(v, fc + extra, fc, vs, d)
    asym = friction_model("asymmetric").predict(
        {"viscous_pos": dp, "viscous_neg": dn, "coulomb_pos": cp, "coulomb_neg": cn}, v)
    for f in (sfm, stri, asym):
        assert np.all(f * v >= 0.0)
