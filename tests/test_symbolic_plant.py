"""Symbolic proofs of the paper's eqs. (1)-(8), the observer sign convention and the Q filters."""

import pytest
import sympy as sp

from forecast_design.errors import ParameterError
from forecast_design.params import Compensator, Design
from forecast_design.symbolic import nominal_plant, observer_filters, q_filter, required_q_order
from forecast_design.symbolic import plant as pl
from forecast_design.symbolic.plant import J, J_l, J_m, d, d_l, d_m, k, k_e, s, w_q


def _is_zero(expr) -> bool:
    return sp.simplify(sp.cancel(sp.together(expr))) == 0


def _paper_ea():
    """Eq. (5) as printed."""
    E = pl.environment_polynomial()
    return E / ((E / k + 1) * J_m * s**2 + E)


def test_force_plant_solved_equals_printed_eq2():
    assert _is_zero(pl.force_plant_expr() - pl.paper_force_plant_expr())


def test_force_plant_relative_degree_is_two():
    num, den = sp.fraction(pl.force_plant_expr())
    assert sp.degree(den, s) - sp.degree(num, s) == 2


def test_sea_polynomials_share_one_denominator_of_solved_system():
    n_s, n_t, den = pl.sea_polynomials()
    sol = pl.solve_sea()
    assert _is_zero(n_s / den - sol["tau_s"])
    assert _is_zero(n_t / den - sol["theta"])
    # theta/tau_m from the spring law: theta = q + tau_s/k with q = tau_s / E.
    assert _is_zero(sol["theta"] - sol["tau_s"] * (1 / k + 1 / pl.environment_polynomial()))
    assert _is_zero(sol["q"] - sol["tau_s"] / pl.environment_polynomial())


def test_locked_plant_is_limit_and_equals_solved_locked_system():
    locked = pl.locked_force_plant_expr()
    assert _is_zero(locked - k / (J_m * s**2 + d_m * s + k))
    assert _is_zero(locked - pl.solve_locked_sea()["tau_s"])
    n_s, n_t, den = pl.sea_polynomials(locked=True)
    assert _is_zero(n_t / den - 1 / (J_m * s**2 + d_m * s + k))


def test_nominal_ea_equals_printed_eq5():
    assert _is_zero(pl.nominal_ea_expr() - _paper_ea())


def test_eq6_is_limit_of_eq5():
    limit = sp.limit(_paper_ea(), k_e, sp.oo)
    assert _is_zero(limit - pl.paper_nominal_lo_expr())
    assert _is_zero(pl.nominal_lo_expr() - pl.paper_nominal_lo_expr())


def test_eq8_is_eq5_with_link_only_environment():
    E_link = J_l * s**2 + d_l * s
    substituted = sp.cancel(sp.together(_paper_ea().subs({J: J_l, d: d_l, k_e: 0})))
    assert _is_zero(substituted - pl.paper_nominal_ld_expr())
    assert _is_zero(pl.nominal_ld_expr() - pl.paper_nominal_ld_expr())
    # and directly from E(s) in (5)
    direct = E_link / ((E_link / k + 1) * J_m * s**2 + E_link)
    assert _is_zero(direct - pl.paper_nominal_ld_expr())


def test_dob_block_diagram_gives_eq4():
    assert _is_zero(pl.dob_force_dynamics_expr() - pl.paper_dob_force_dynamics_expr())


def test_paper_printed_estimate_sign_does_not_give_eq4():
    # tau_hat = tau_s P_n^-1 Q - tau_m Q fed forward as tau_m = u + tau_hat.
    P, P_n, Q, u, tau_m = sp.symbols("P P_n Q u tau_m")
    (sol,) = sp.linsolve([sp.Eq(tau_m, u + (P * tau_m / P_n * Q - tau_m * Q))], [tau_m])
    f_printed = P * sol[0] / u
    assert not _is_zero(f_printed - pl.paper_dob_force_dynamics_expr())
    assert _is_zero(f_printed - P / (1 - Q * (P / P_n - 1)))


def test_estimate_sign_cancels_input_friction():
    # With tau_s = P_n (tau_m - tau_frc): Q (tau_m - P_n^-1 tau_s) = Q tau_frc, so
    # tau_m = u + tau_hat leaves tau_s = P_n (u - (1 - Q) tau_frc): no DC friction.
    P_n, Q, u, tau_frc, tau_m = sp.symbols("P_n Q u tau_frc tau_m")
    tau_s = P_n * (tau_m - tau_frc)
    (sol,) = sp.linsolve([sp.Eq(tau_m, u + Q * (tau_m - tau_s / P_n))], [tau_m])
    tau_s_closed = sp.expand(tau_s.subs(tau_m, sol[0]))
    assert _is_zero(tau_s_closed - P_n * (u - (1 - Q) * tau_frc))


def test_ea_inverse_equals_motor_side_estimate_when_environment_exact():
    # P_n^EA^-1 tau_s = tau_s + J_m s^2 theta, with tau_s = k (theta - q), q = tau_s / E.
    theta = sp.Symbol("theta")
    E = pl.environment_polynomial()
    q_of_theta = sp.solve(sp.Eq(E * sp.Symbol("q"), k * (theta - sp.Symbol("q"))), sp.Symbol("q"))[0]
    tau_s = k * (theta - q_of_theta)
    assert _is_zero(tau_s / pl.nominal_ea_expr() - (tau_s + J_m * s**2 * theta))


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5, 6])
def test_butterworth_unity_dc_and_half_power_at_cutoff(order):
    Q = q_filter("butterworth", order)
    assert sp.simplify(Q.subs(s, 0)) == 1
    w = sp.Symbol("w", positive=True)
    mag2 = sp.simplify(sp.expand(Q.subs(s, sp.I * w) * Q.subs(s, -sp.I * w)))
    # |Q(jw)|^2 = 1 / (1 + (w / w_q)^(2n)): the defining Butterworth property.
    assert _is_zero(mag2 - 1 / (1 + (w / w_q) ** (2 * order)))


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_binomial_unity_dc_and_gain_at_cutoff(order):
    Q = q_filter("binomial", order)
    assert Q.subs(s, 0) == 1
    mag2 = sp.simplify(Q.subs(s, sp.I * w_q) * Q.subs(s, -sp.I * w_q))
    assert sp.simplify(mag2 - sp.Rational(1, 2**order)) == 0


def test_q_filter_rejects_unknown_family_and_bad_order():
    with pytest.raises(ParameterError):
        q_filter("chebyshev", 2)
    with pytest.raises(ParameterError):
        q_filter("butterworth", 0)


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob", "motor-fob"])
def test_q_order_below_relative_degree_raises(kind):
    assert required_q_order(kind) == 2
    with pytest.raises(ParameterError) as info:
        observer_filters(Compensator(kind=kind, q_order=1), Design.nominal("stiff"))
    assert info.value.name == "q_order"


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob"])
def test_nominal_plants_have_relative_degree_two(kind):
    assert nominal_plant(kind).relative_degree == 2


def test_observer_filters_are_q_times_nominal_inverse():
    design = Design.nominal("stiff")
    comp = Compensator(kind="ld-dob", w_q_hz=5.0)
    filt = observer_filters(comp, design)
    Qexpr = q_filter("butterworth", 2).subs(w_q, 2 * sp.pi * 5)
    Pn = pl.paper_nominal_ld_expr().subs({J_m: 0.133, k: 58.0, J_l: 0.0018, d_l: 0.35})
    for x in (0.3j, 7.0j, 2.0 + 40.0j):
        q = complex(Qexpr.subs(s, x).evalf())
        pn = complex(Pn.subs(s, x).evalf())
        assert filt.from_tau_m(x) == pytest.approx(q, rel=1e-12)
        assert filt.from_tau_s(x) == pytest.approx(-q / pn, rel=1e-12)
        assert filt.from_theta(x) == 0
    assert filt.from_tau_m.den == filt.from_tau_s.den == filt.from_theta.den
