"""Tests for forecast_design.analysis: exact disk margins and the Fig. 6 table."""

from __future__ import annotations

import importlib.util
import json
import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from forecast_design.analysis import (
    DiskMargin,
    disk_center_radius,
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from forecast_design.errors import ParameterError
from forecast_design.lti import RationalTF

RTOL_GRID = 1e-4          # fine 20k-point grid vs exact peak
ATOL_DENSE = 1e-6         # refined dense grid vs exact peak
SLACK = 1e-9              # exact alpha may never exceed a sampled alpha by more than this

#: Seiler, Packard, Gahinet (2020), Example; MATLAB ``diskmargin`` documentation.
SEILER_L = RationalTF([25.0], [1.0, 10.0, 10.0, 10.0], name="L")

#: Stable loops for the cross-checks (closed-loop stability verified in the test).
STABLE_LOOPS = [
    SEILER_L,
    RationalTF([10.0], [1.0, 7.0, 10.0, 0.0], name="integrator, type 1"),
    RationalTF([2.0, 1.0], [1.0, 0.4, 4.0, 0.0], name="lightly damped resonance"),
    RationalTF([5.0, 50.0], [0.1, 1.0, 0.0], name="PD x double integrator-ish"),
    RationalTF([0.5, -0.5, 3.0], [1.0, 3.0, 3.0, 1.0], name="NMP zeros"),
    RationalTF([300.0, 3000.0], [1.0, 12.0, 150.0, 100.0, 0.0], name="4th order, resonance"),
]


def _delta_of(f: complex, sigma: float) -> complex:
    """Inverse of the Moebius map f = (1 + (1-sigma)d/2) / (1 - (1+sigma)d/2)."""
    return (f - 1.0) / ((1.0 - sigma) / 2.0 + (1.0 + sigma) / 2.0 * f)


def _closed_loop_roots(L: RationalTF, f: complex = 1.0) -> np.ndarray:
    num = np.asarray(L.num, complex) * f
    den = np.asarray(L.den, complex)
    n = max(len(num), len(den))
    num = np.concatenate([np.zeros(n - len(num)), num])
    den = np.concatenate([np.zeros(n - len(den)), den])
    return np.roots(den + num)


def _grid_alpha(L: RationalTF, w: np.ndarray, sigma: float) -> tuple[float, float]:
    """Min over a grid of 1/|S + (sigma-1)/2|, evaluated independently with plain numpy."""
    s = 1j * w if L.dt is None else np.exp(1j * w * L.dt)
    g = _abs_G(L, s, sigma)
    i = int(np.argmax(g))
    return float(1.0 / g[i]), float(w[i])


def _abs_G(L: RationalTF, s: np.ndarray, sigma: float) -> np.ndarray:
    """|S + c| as |den (1 + c) + c num| / |num + den|: S + c formed directly would cancel."""
    c = (sigma - 1.0) / 2.0
    n, d = np.polyval(L.num, s), np.polyval(L.den, s)
    return np.abs((d * (1.0 + c) + c * n) / (n + d))


def _control_grid_alpha(L, sigma: float, w_focus: float, w_lo: float = 1e-4, w_hi: float = 1e4) -> float:
    """python-control's disk margin on a 2001-point log grid plus 4001 points within +-20 %
    of ``w_focus`` (python-control needs ~70 us per point, so one global 40k grid is too slow)."""
    w = np.logspace(math.log10(w_lo), math.log10(w_hi), 2001)
    if math.isfinite(w_focus) and w_focus > 0.0:
        w = np.concatenate([w, np.linspace(0.8 * w_focus, min(1.2 * w_focus, w_hi), 4001)])
    dm, _, _ = control.disk_margins(L.to_control(), np.sort(w), skew=sigma)
    return float(dm)


def _refined_alpha(L: RationalTF, sigma: float, w_lo: float = 1e-4, w_hi: float = 1e4) -> float:
    """Dense log grid, then scipy's bounded scalar minimiser around the grid peak."""
    w = np.logspace(math.log10(w_lo), math.log10(w_hi), 20001)
    alpha_grid, _ = _grid_alpha(L, w, sigma)
    g = _abs_G(L, 1j * w, sigma)
    i = int(np.argmax(g))
    lo, hi = w[max(i - 1, 0)], w[min(i + 1, w.size - 1)]

    def neg(u: float) -> float:
        return -float(_abs_G(L, np.array([1j * math.exp(u)]), sigma)[0])

    res = minimize_scalar(neg, bounds=(math.log(lo), math.log(hi)), method="bounded",
                          options={"xatol": 1e-12})
    # both ends: w = 0 exactly and w -> inf (the peak may sit at either)
    g0 = float(_abs_G(L, np.zeros(1, complex), sigma)[0])
    return min(alpha_grid, 1.0 / -res.fun, 1.0 / max(g0, -neg(math.log(w_hi * 1e4)), 1e-300))


# ---------------------------------------------------------------------------------------------
# Published example and closed forms
# ---------------------------------------------------------------------------------------------


def test_disk_margin_seiler_example_matches_published_digits():
    # Seiler et al. 2020 / MATLAB diskmargin: DM 0.4581, GM [0.6273, 1.5942] (+-4.05 dB), PM 25.8 deg
    dm = disk_margin(SEILER_L)
    assert dm.stable
    assert round(dm.alpha, 4) == 0.4581
    assert round(dm.gain_margin[0], 4) == 0.6273
    assert round(dm.gain_margin[1], 4) == 1.5942
    assert round(dm.gain_margin_db[1], 2) == 4.05
    assert round(dm.gain_margin_db[0], 2) == -4.05
    assert round(dm.phase_margin_deg, 1) == 25.8


def test_disk_margin_seiler_example_frequency_is_argmax_of_dense_grid():
    dm = disk_margin(SEILER_L)
    w = np.linspace(1.5, 2.5, 200001)
    alpha_grid, w_grid = _grid_alpha(SEILER_L, w, 0.0)
    assert dm.alpha <= alpha_grid + SLACK
    assert dm.frequency_rad_s == pytest.approx(w_grid, abs=2e-5)


@pytest.mark.parametrize("w_c", [0.1, 1.0, 30.0])
@pytest.mark.parametrize("sigma", [-0.5, 0.0, 0.5, 1.0])
def test_disk_margin_integrator_loop_closed_form(w_c, sigma):
    # S(jw) = jw/(jw + w_c) traces the circle |S - 1/2| = 1/2, so
    # ||S + (sigma-1)/2||_inf = (1 + |sigma|)/2 and alpha = 2/(1 + |sigma|).
    dm = disk_margin(RationalTF([w_c], [1.0, 0.0]), sigma)
    assert dm.alpha == pytest.approx(2.0 / (1.0 + abs(sigma)), rel=1e-12)
    lo, hi = dm.gain_margin
    if sigma >= 0.0:
        # alpha (1 + sigma) = 2: the disk is the half-plane Re f >= sigma/(1 + sigma)
        assert hi == math.inf and dm.gain_margin_db[1] == math.inf
        assert lo == pytest.approx(sigma / (1.0 + sigma), abs=1e-12)
    else:
        assert lo == pytest.approx(0.0, abs=1e-12)
        assert hi == pytest.approx((sigma - 1.0) / sigma, rel=1e-9)
    # classical delay margin: crossover at w_c with phase -90 deg
    assert dm.delay_margin_s == pytest.approx(math.pi / 2.0 / w_c, rel=1e-9)


def test_disk_margin_integrator_loop_balanced_phase_margin_is_90_deg():
    dm = disk_margin(RationalTF([2.0], [1.0, 0.0]))
    assert dm.alpha == pytest.approx(2.0, rel=1e-12)
    assert dm.phase_margin_deg == pytest.approx(90.0, abs=1e-9)
    assert dm.gain_margin == (0.0, math.inf)


@pytest.mark.parametrize("k", [8.5, 10.0, 50.0])
def test_disk_margin_unstable_closed_loop_gives_zero(k):
    # k/(s+1)^3: Routh gives stability iff k < 8
    L = RationalTF([k], [1.0, 3.0, 3.0, 1.0])
    assert np.max(_closed_loop_roots(L).real) > 0.0
    dm = disk_margin(L)
    assert dm.alpha == 0.0 and not dm.stable
    assert dm.phase_margin_deg == 0.0 and dm.gain_margin == (1.0, 1.0)


def test_disk_margin_stable_below_routh_limit():
    dm = disk_margin(RationalTF([7.0], [1.0, 3.0, 3.0, 1.0]))
    assert dm.stable and dm.alpha > 0.0
    # the disk's real gains are inside the true gain range (0, 8/7) for this loop
    assert dm.gain_margin[1] < 8.0 / 7.0


def test_disk_margin_open_loop_unstable_but_closed_loop_stable():
    # L = 2/(s - 1): closed loop s + 1, stable; S = (s-1)/(s+1) is all-pass, |S - 1/2| peaks at 3/2
    dm = disk_margin(RationalTF([2.0], [1.0, -1.0]))
    assert dm.stable
    assert dm.alpha == pytest.approx(2.0 / 3.0, rel=1e-12)


def test_disk_margin_marginal_closed_loop_is_unstable():
    # L = 1/s^2: closed-loop poles at +-j
    assert not disk_margin(RationalTF([1.0], [1.0, 0.0, 0.0])).stable


def test_disk_margin_external_stability_flag_overrides_root_check():
    dm = disk_margin(SEILER_L, closed_loop_stable=False)
    assert dm.alpha == 0.0 and not dm.stable


def test_disk_margin_not_well_posed_loop_is_unstable():
    # 1 + L(inf) = 0
    assert not disk_margin(RationalTF([-1.0, 0.0], [1.0, 1.0])).stable


# ---------------------------------------------------------------------------------------------
# Cross-checks against python-control and dense grids
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("L", STABLE_LOOPS, ids=lambda L: L.name)
@pytest.mark.parametrize("sigma", [0.0, 0.7, -0.4])
def test_disk_margin_agrees_with_python_control_fine_grid(L, sigma):
    assert np.all(_closed_loop_roots(L).real < 0.0)
    dm = disk_margin(L, sigma)
    dm_grid = _control_grid_alpha(L, sigma, dm.frequency_rad_s)
    assert dm.alpha <= dm_grid + SLACK
    assert dm.alpha == pytest.approx(dm_grid, rel=RTOL_GRID)


@pytest.mark.parametrize("L", STABLE_LOOPS, ids=lambda L: L.name)
def test_disk_margin_matches_refined_dense_grid(L):
    dm = disk_margin(L)
    assert dm.alpha == pytest.approx(_refined_alpha(L, 0.0), abs=ATOL_DENSE)


@pytest.mark.parametrize("L", STABLE_LOOPS, ids=lambda L: L.name)
def test_disk_margin_worst_perturbation_reaches_imaginary_axis(L):
    # At the critical frequency f* = -1/L(jw) puts a closed-loop pole on the axis, and
    # f* lies on the boundary of D(alpha, sigma): |delta(f*)| = alpha.
    dm = disk_margin(L, 0.3)
    if math.isinf(dm.frequency_rad_s):
        # peak in the limit w -> inf, where a strictly proper L vanishes: S = 1
        assert L.relative_degree > 0
        assert dm.alpha == pytest.approx(1.0 / abs(1.0 + (0.3 - 1.0) / 2.0), rel=1e-12)
        return
    f_star = -1.0 / complex(L.freqresp(np.array([dm.frequency_rad_s]))[0])
    assert abs(_delta_of(f_star, 0.3)) == pytest.approx(dm.alpha, rel=1e-9)


@pytest.mark.parametrize("L", STABLE_LOOPS[:3], ids=lambda L: L.name)
def test_disk_margin_delay_margin_matches_python_control_phase_margin(L):
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(L.to_control())
    dm = disk_margin(L)
    assert dm.delay_margin_s == pytest.approx(math.radians(pm) / wgc, rel=1e-6)


def test_disk_margin_is_lower_bound_on_classical_gain_margin():
    gm, _, _, _, _, _ = control.stability_margins(SEILER_L.to_control())
    dm = disk_margin(SEILER_L)
    assert dm.gain_margin[1] < gm
    # and the disk's gains really are stabilising at the edges
    for g in (dm.gain_margin[0] * 1.0001, dm.gain_margin[1] * 0.9999):
        assert np.all(_closed_loop_roots(SEILER_L, g).real < 0.0)


@pytest.mark.parametrize("dt", [0.01, 0.1])
@pytest.mark.parametrize("sigma", [0.0, 0.5])
def test_disk_margin_discrete_agrees_with_grid_up_to_nyquist(dt, sigma):
    # ZOH of 25/(s^3 + 10 s^2 + 10 s + 10), via python-control
    Ld_ctrl = control.sample_system(SEILER_L.to_control(), dt, method="zoh")
    Ld = RationalTF(np.ravel(Ld_ctrl.num[0][0]), np.ravel(Ld_ctrl.den[0][0]), dt=dt)
    nyq = math.pi / dt
    dm = disk_margin(Ld, sigma)
    w = np.logspace(-4, math.log10(nyq * (1 - 1e-12)), 2001)   # python-control warns above Nyquist
    w = np.sort(np.concatenate([w, np.minimum(np.linspace(0.8, 1.2, 4001) * dm.frequency_rad_s, w[-1])]))
    dm_grid, _, _ = control.disk_margins(Ld_ctrl, w, skew=sigma)
    assert dm.stable
    assert dm.alpha <= float(dm_grid) + SLACK
    assert dm.alpha == pytest.approx(float(dm_grid), rel=RTOL_GRID)
    assert 0.0 <= dm.frequency_rad_s <= nyq * (1 + 1e-12)
    alpha_here = 1.0 / abs(1.0 / (1.0 + complex(Ld.freqresp(np.array([dm.frequency_rad_s]))[0]))
                           + (sigma - 1.0) / 2.0)
    assert alpha_here == pytest.approx(dm.alpha, rel=1e-9)


def test_disk_margin_discrete_unstable_closed_loop():
    # L(z) = 3/(z - 0.5): closed-loop pole at z = -2.5
    dm = disk_margin(RationalTF([3.0], [1.0, -0.5], dt=0.01))
    assert not dm.stable and dm.alpha == 0.0


def test_disk_margin_discrete_integrator_closed_form():
    # L(z) = 0.5/(z - 1): S = (z - 1)/(z - 0.5), |S|^2 = (2 - 2 cos t)/(1.25 - cos t) grows
    # monotonically to 4/3 at z = -1, so alpha(sigma=1) = 3/4 at Nyquist
    dt = 0.002
    dm = disk_margin(RationalTF([0.5], [1.0, -1.0], dt=dt), 1.0)
    assert dm.stable
    assert dm.alpha == pytest.approx(0.75, rel=1e-12)
    assert dm.frequency_rad_s == pytest.approx(math.pi / dt, rel=1e-12)
    assert not disk_margin(RationalTF([1.0], [1.0, 0.0], dt=dt)).stable   # 1/z: pole at z = -1


def test_disk_margin_discrete_peak_at_nyquist():
    # L(z) = 0.5/(z + 0.2): |S| is largest at z = -1 where L = 0.5/(-0.8) = -0.625
    dt = 0.001
    dm = disk_margin(RationalTF([0.5], [1.0, 0.2], dt=dt), 1.0)
    assert dm.alpha == pytest.approx(1.0 / abs(1.0 / (1.0 - 0.625)), rel=1e-12)
    assert dm.frequency_rad_s == pytest.approx(math.pi / dt, rel=1e-12)


def test_disk_margin_tiny_gain_sharp_resonance_not_lost_to_rounding():
    # |L| ~ 1e-6 with a resonance of damping ratio 1.3e-3: |S - 3/4| varies by ~1e-6 only,
    # so forming S + c (or |N|^2 - k|D|^2) directly loses the peak to cancellation.
    den = np.real(np.poly([-14.27 + 85.75j, -14.27 - 85.75j, -0.1103 + 84.26j, -0.1103 - 84.26j]))
    L = RationalTF([0.0784], den)
    dm = disk_margin(L, -0.5)
    w = np.linspace(84.0, 84.6, 600001)
    alpha_grid, w_grid = _grid_alpha(L, w, -0.5)
    assert dm.alpha <= alpha_grid * (1.0 + 1e-13)
    assert dm.alpha == pytest.approx(alpha_grid, rel=1e-13)
    assert dm.frequency_rad_s == pytest.approx(w_grid, abs=1e-5)


# ---------------------------------------------------------------------------------------------
# Hypothesis: random stable low-order loops
# ---------------------------------------------------------------------------------------------


@st.composite
def stable_loops(draw):
    n = draw(st.integers(1, 4))
    poles = []
    while len(poles) < n:
        re = -10 ** draw(st.floats(-1.5, 1.5))
        if n - len(poles) >= 2 and draw(st.booleans()):
            im = 10 ** draw(st.floats(-1.5, 1.5))
            poles += [complex(re, im), complex(re, -im)]
        else:
            poles.append(complex(re, 0.0))
    m = draw(st.integers(0, n - 1))
    zeros = [draw(st.floats(-20.0, 20.0)) for _ in range(m)]
    k = 10 ** draw(st.floats(-1.0, 1.5))
    den = np.real(np.poly(poles))
    num = k * np.real(np.poly(zeros)) if m else np.array([k])
    L = RationalTF(num, den)
    roots = _closed_loop_roots(L)
    from hypothesis import assume

    assume(np.max(roots.real) < -1e-3 * max(1.0, np.max(np.abs(roots))))
    return L


@settings(max_examples=60, deadline=None)
@given(L=stable_loops(), sigma=st.sampled_from([0.0, 0.5, -0.5, 1.0]))
def test_disk_margin_exact_peak_never_below_sampled_peak(L, sigma):
    dm = disk_margin(L, sigma)
    assert dm.stable
    w = np.logspace(-4, 4, 4001)
    alpha_grid, _ = _grid_alpha(L, w, sigma)
    assert dm.alpha <= alpha_grid + SLACK
    assert dm.alpha == pytest.approx(_refined_alpha(L, sigma), abs=ATOL_DENSE)


@settings(max_examples=40, deadline=None)
@given(L=stable_loops(), sigma=st.sampled_from([0.0, 0.5, -0.5]),
       r=st.floats(0.0, 0.999), theta=st.floats(-math.pi, math.pi))
def test_disk_margin_perturbations_inside_disk_keep_loop_stable(L, sigma, r, theta):
    # the guarantee itself: every complex f in D(alpha, sigma) keeps den + f num Hurwitz
    dm = disk_margin(L, sigma)
    delta = r * min(dm.alpha, 1e3) * np.exp(1j * theta)
    f = (1.0 + (1.0 - sigma) * delta / 2.0) / (1.0 - (1.0 + sigma) * delta / 2.0)
    roots = _closed_loop_roots(L, f)
    assert np.max(roots.real) < 1e-9 * max(1.0, float(np.max(np.abs(roots))))


# ---------------------------------------------------------------------------------------------
# Disk geometry
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("alpha", [0.1, 0.4581, 1.0, 1.9])
@pytest.mark.parametrize("sigma", [-0.8, 0.0, 0.6])
def test_disk_boundary_contains_gain_and_phase_margin_points(alpha, sigma):
    lo, hi = disk_gain_margin(alpha, sigma)
    pm = math.radians(disk_phase_margin_deg(alpha, sigma))
    if lo > 0.0:                       # clipped at 0 once the disk contains f = 0
        assert abs(_delta_of(lo, sigma)) == pytest.approx(alpha, rel=1e-12)
    else:
        assert alpha * (1.0 - sigma) >= 2.0
    if math.isfinite(hi):
        assert abs(_delta_of(hi, sigma)) == pytest.approx(alpha, rel=1e-12)
    if 0.0 < pm < math.pi:
        assert abs(_delta_of(np.exp(1j * pm), sigma)) == pytest.approx(alpha, rel=1e-9)
    c, r, exterior = disk_center_radius(alpha, sigma)
    for th in np.linspace(0.0, 2 * math.pi, 7):
        d = alpha * np.exp(1j * th)
        f = (1 + (1 - sigma) * d / 2) / (1 - (1 + sigma) * d / 2)
        if math.isfinite(c):
            assert abs(f - c) == pytest.approx(r, rel=1e-9)


def test_disk_phase_margin_balanced_closed_form():
    for a in (0.05, 0.5, 1.5, 2.0):
        assert disk_phase_margin_deg(a, 0.0) == pytest.approx(math.degrees(2 * math.atan(a / 2)), rel=1e-12)


def test_disk_center_radius_balanced_closed_form():
    # sigma = 0: gamma = (2 -+ a)/(2 +- a) -> centre (1 + (a/2)^2)/(1 - (a/2)^2), radius a/(1 - (a/2)^2)
    a = 0.8
    c, r, exterior = disk_center_radius(a, 0.0)
    assert c == pytest.approx((1 + (a / 2) ** 2) / (1 - (a / 2) ** 2), rel=1e-12)
    assert r == pytest.approx(a / (1 - (a / 2) ** 2), rel=1e-12)
    assert not exterior


# ---------------------------------------------------------------------------------------------
# Curve, serialisation and errors
# ---------------------------------------------------------------------------------------------


def test_disk_margin_curve_minimum_matches_python_control_returnall():
    w = np.logspace(-2, 2, 500)
    curve = disk_margin_curve(SEILER_L, w, 0.3)
    dm_all, dgm_all, dpm_all = control.disk_margins(SEILER_L.to_control(), w, skew=0.3, returnall=True)
    np.testing.assert_allclose(curve.alpha, np.asarray(dm_all), rtol=1e-10)
    # python-control writes inf where the whole unit circle is inside the disk; we write 180
    dpm = np.asarray(dpm_all)
    np.testing.assert_allclose(curve.phase_margin_deg, np.where(np.isinf(dpm), 180.0, dpm), rtol=1e-8)
    assert curve.alpha.min() >= disk_margin(SEILER_L, 0.3).alpha - SLACK


def test_disk_margin_curve_integrator_pole_on_grid_gives_s_zero():
    curve = disk_margin_curve(RationalTF([1.0], [1.0, 0.0]), [0.0, 1.0])
    assert curve.alpha[0] == pytest.approx(2.0)   # S(0) = 0 -> 1/|0 - 1/2|


def test_disk_margin_to_mapping_is_strict_json():
    dm = disk_margin(RationalTF([1.0], [1.0, 0.0]))
    text = json.dumps(dm.to_mapping(), allow_nan=False)
    back = json.loads(text)
    assert back["gain_margin_db"][1] is None and back["stable"] is True
    assert isinstance(dm, DiskMargin)


def test_disk_margin_rejects_bad_inputs():
    with pytest.raises(ParameterError, match="sigma"):
        disk_margin(SEILER_L, float("nan"))
    with pytest.raises(ParameterError, match="RationalTF"):
        disk_margin(SEILER_L.to_control())


# ---------------------------------------------------------------------------------------------
# Fig. 6 (needs forecast_design.loops.continuous.force_loop)
# ---------------------------------------------------------------------------------------------

HAS_LOOPS = importlib.util.find_spec("forecast_design.loops.continuous") is not None
needs_loops = pytest.mark.skipif(not HAS_LOOPS, reason="forecast_design.loops.continuous not available")


@pytest.fixture(scope="module")
def fig6_rows():
    from forecast_design.analysis import fig6_table

    return fig6_table()


def _row(rows, env, obs, wq=None):
    (r,) = [r for r in rows if r.environment == env and r.observer == obs and r.w_q_hz == wq]
    return r


@needs_loops
def test_fig6_table_shape_and_json_keys(fig6_rows):
    assert len(fig6_rows) == 2 * (1 + 3 * 3)
    keys = {"environment", "observer", "w_q_hz", "disk_margin", "gain_margin_db",
            "phase_margin_deg", "frequency_rad_s", "stable"}
    for r in fig6_rows:
        m = r.to_mapping()
        assert set(m) == keys
        json.dumps(m, allow_nan=False)


@needs_loops
@pytest.mark.parametrize("env", ["soft", "stiff"])
@pytest.mark.parametrize("wq", [1.0, 5.0, 10.0])
def test_fig6_ea_fob_within_two_percent_of_plant_alone(fig6_rows, env, wq):
    plant = _row(fig6_rows, env, "none")
    ea = _row(fig6_rows, env, "ea-fob", wq)
    assert plant.stable and ea.stable
    assert ea.disk_margin == pytest.approx(plant.disk_margin, rel=0.02)


@needs_loops
def test_fig6_lo_dob_disk_margin_decreases_with_cutoff_in_soft(fig6_rows):
    a = [_row(fig6_rows, "soft", "lo-dob", wq).disk_margin for wq in (1.0, 5.0, 10.0)]
    assert a[0] > a[1] > a[2]


@needs_loops
def test_fig6_ld_dob_unstable_at_10_hz_in_stiff(fig6_rows):
    r = _row(fig6_rows, "stiff", "ld-dob", 10.0)
    assert not r.stable and r.disk_margin == 0.0


@needs_loops
def test_fig6_disk_margins_agree_with_python_control_grid():
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for env, comp in [("soft", None), ("stiff", Compensator(kind="lo-dob", w_q_hz=5.0)),
                      ("soft", Compensator(kind="ea-fob", w_q_hz=10.0))]:
        loop = force_loop(Design.nominal(env), comp)
        assert loop.stable
        dm = disk_margin(loop.L, closed_loop_stable=loop.stable)
        dm_grid = _control_grid_alpha(loop.L, 0.0, dm.frequency_rad_s, 1e-3, 1e5)
        assert dm.alpha <= dm_grid + SLACK
        assert dm.alpha == pytest.approx(dm_grid, rel=RTOL_GRID)


@needs_loops
def test_fig6_every_stable_row_matches_refined_dense_grid(fig6_rows):
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for r in fig6_rows:
        if not r.stable:
            continue
        comp = None if r.w_q_hz is None else Compensator(kind=r.observer, w_q_hz=r.w_q_hz)
        L = force_loop(Design.nominal(r.environment), comp).L
        alpha_grid, _ = _grid_alpha(L, np.logspace(-3, 5, 8001), 0.0)
        assert r.disk_margin <= alpha_grid + SLACK, r
        assert r.disk_margin == pytest.approx(_refined_alpha(L, 0.0, 1e-3, 1e5), abs=ATOL_DENSE), r


# ---------------------------------------------------------------------------------------------
# Plots (forecast_design.plotting.margins)
# ---------------------------------------------------------------------------------------------


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_disk_upper_boundary_runs_from_gamma_max_to_gamma_min_in_upper_half():
    from forecast_design.plotting.margins import disk_upper_boundary

    for alpha, sigma in [(0.4581, 0.0), (1.2, 0.5), (0.9, -0.7)]:
        f = disk_upper_boundary(alpha, sigma, 101)
        lo, hi = disk_gain_margin(alpha, sigma)
        assert f[0].real == pytest.approx(hi, rel=1e-12) and f[-1].real == pytest.approx(lo, rel=1e-12)
        assert np.all(f.imag >= -1e-12)
        np.testing.assert_allclose(np.abs(_delta_of(f, sigma)), alpha, rtol=1e-12)


def test_plot_fig6_writes_png_with_one_panel_per_environment(tmp_path):
    from forecast_design.analysis import MarginRow
    from forecast_design.plotting.margins import plot_fig6

    def row(env, obs, wq, a, stable=True):
        return MarginRow(environment=env, observer=obs, w_q_hz=wq, disk_margin=a,
                         gain_margin_db=disk_gain_margin(a) if stable else (0.0, 0.0),
                         phase_margin_deg=disk_phase_margin_deg(a), frequency_rad_s=10.0, stable=stable)

    rows = [row("soft", "none", None, 1.96), row("soft", "lo-dob", 10.0, 1.03),
            row("soft", "ea-fob", 10.0, 2.0), row("soft", "ld-dob", 10.0, 2.5),   # half-plane, exterior
            row("stiff", "none", None, 1.16), row("stiff", "ld-dob", 5.0, 0.38),
            row("stiff", "ld-dob", 10.0, 0.0, stable=False)]
    out = plot_fig6(rows, tmp_path / "fig6.png")
    w, h = _png_size(out)
    assert h > w * 0.9           # two stacked panels
    one = plot_fig6(rows[:4], tmp_path / "soft.png")
    assert _png_size(one)[1] < h
    with pytest.raises(ParameterError):
        plot_fig6([], tmp_path / "none.png")


def test_plot_disk_margin_curve_writes_png(tmp_path):
    from forecast_design.plotting.margins import plot_disk_margin_curve

    w = np.logspace(-2, 2, 200)
    curves = {"L": disk_margin_curve(SEILER_L, w),
              "w_c/s": disk_margin_curve(RationalTF([1.0], [1.0, 0.0]), w)}
    out = plot_disk_margin_curve(curves, tmp_path / "curve.png", title="alpha(w)")
    assert _png_size(out)[0] > 0
    assert plot_disk_margin_curve(curves["L"], tmp_path / "one.png").exists()


@needs_loops
def test_fig6_stability_flag_agrees_with_roots_of_loop_polynomials(fig6_rows):
    # ForceLoop.stable comes from the uncancelled characteristic polynomial; our own check
    # uses den(L) + num(L). They agree when L has no hidden cancellation.
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for r in fig6_rows:
        comp = None if r.w_q_hz is None else Compensator(kind=r.observer, w_q_hz=r.w_q_hz)
        loop = force_loop(Design.nominal(r.environment), comp)
        assert disk_margin(loop.L).stable == r.stable == loop.stable, r


def test_fig6_table_rejects_unknown_observer_and_environment():
    from forecast_design.analysis import fig6_table

    with pytest.raises(ParameterError, match="observer"):
        fig6_table(observers=("magic",))
    if HAS_LOOPS:
        with pytest.raises(ParameterError, match="unknown environment"):
            fig6_table(environments=("mud",), observers=("none",))


# ---------------------------------------------------------------------------------------------
# Sampled-data loop
# ---------------------------------------------------------------------------------------------

from forecast_design.analysis import loop_margins, sampled_force_loop  # noqa: E402
from forecast_design.params import Compensator, Design, PDController  # noqa: E402

SAMPLED_CASES = [("soft", None, None), ("stiff", None, None), ("soft", "lo-dob", 5.0),
                 ("stiff", "ea-fob", 10.0), ("soft", "ld-dob", 5.0), ("stiff", "motor-fob", 10.0),
                 ("link-only", "motor-fob", 5.0), ("locked", "lo-dob", 5.0)]


def _continuous_filtered_reference(env, kind, wq, break_at="controller"):
    """The continuous loop with the simulator's filtered PD, C(s) F_DOB(s), from public pieces."""
    from forecast_design.simulation.controllers import pd_transfer_function
    from forecast_design.symbolic import force_loop

    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    fl = force_loop(Design.nominal(env), comp)
    C = pd_transfer_function(PDController(P=5.0, D=0.1))
    L = RationalTF(np.convolve(C.num, fl.F_DOB.num), np.convolve(C.den, fl.F_DOB.den))
    return disk_margin(L)


@needs_loops
@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES)
def test_sampled_margin_tends_to_continuous_as_rate_grows(env, kind, wq):
    """At 20 kHz (delay and ZOH lag 10x smaller) the margin is within 1 % of the continuous
    loop with the same filtered PD, and the error shrinks about tenfold again at 200 kHz."""
    ref = _continuous_filtered_reference(env, kind, wq)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    errs = []
    for rate in (2e3, 2e4, 2e5):
        loop = sampled_force_loop(Design.nominal(env), comp, rate_hz=rate)
        assert loop.stable == ref.stable
        errs.append(abs(loop.disk_margin().alpha - ref.alpha) / ref.alpha)
    assert errs[1] < 0.01
    assert errs[2] < 0.2 * errs[1] + 1e-6


@needs_loops
def test_sampled_ld_dob_stiff_10hz_is_unstable_like_continuous():
    loop = sampled_force_loop(Design.nominal("stiff"), Compensator(kind="ld-dob", w_q_hz=10.0))
    assert not loop.stable and loop.max_pole_magnitude > 1.0
    assert loop.disk_margin().alpha == 0.0


@needs_loops
@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6])
def test_sampled_plant_is_zoh_step_invariant(env, kind, wq):
    """ZOH: the discrete step response equals the continuous one at the sampling instants."""
    from scipy import signal

    from forecast_design.symbolic import force_plant_tf

    design = Design.nominal(env)
    loop = sampled_force_loop(design, None, rate_hz=2000.0)
    n = 400
    u = np.ones(n)
    _, yd = signal.dlsim((np.asarray(loop.P.num), np.asarray(loop.P.den), loop.P.dt), u)
    P = force_plant_tf(design)
    t = np.arange(n) / 2000.0
    _, yc = signal.step((P.num, P.den), T=t)
    np.testing.assert_allclose(yd.ravel(), yc, atol=1e-6 * np.max(np.abs(yc)))


@needs_loops
@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6])
def test_sampled_loop_frequency_response_is_closed_form_composition(env, kind, wq):
    """L(e^{jwT}) = C(z) P(z) z^-d / (1 - z^-1 G_m - z^-d (G_s P + G_theta P_theta)) from the
    discrete pieces (the C export's filters, python-control's ZOH plant), at every frequency."""
    design = Design.nominal(env)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    for d in (0, 1, 2):
        loop = sampled_force_loop(design, comp, delay_samples=d)
        T = 1.0 / loop.rate_hz
        w = np.logspace(-1, math.log10(0.99 * math.pi / T), 200)
        z = np.exp(1j * w * T)
        from forecast_design.symbolic import derive_motor_angle_plant, force_plant_tf
        P = control.c2d(force_plant_tf(design).to_control(), T, "zoh")
        Pt = control.c2d(derive_motor_angle_plant(design.environment.locked).at(design).to_control(), T, "zoh")
        Pz, Ptz = P(z), Pt(z)
        C = loop.C(z)
        Gm, Gs, Gt = (g(z) for g in loop.observer) if loop.observer else (0.0, 0.0, 0.0)
        expected = C * Pz * z**-d / (1.0 - Gm / z - z**-d * (Gs * Pz + Gt * Ptz))
        s_w = 1j * 2.0 / T * np.tan(w * T / 2.0)
        # python-control's z-polynomials lose ~1e-6 near z = 1 (the reason L_w exists)
        np.testing.assert_allclose(loop.L_w(s_w), expected, rtol=2e-5)


@needs_loops
def test_sampled_pure_delay_costs_exactly_w_T_of_phase_margin_frequency():
    """One more sample of delay multiplies L by z^-1: |L| unchanged, phase -w T (closed form)."""
    design = Design.nominal("stiff")
    comp = Compensator(kind="lo-dob", w_q_hz=5.0)
    # with the observer, z^-d also enters Delta; without it the identity is exact
    l0 = sampled_force_loop(design, None, delay_samples=0)
    l1 = sampled_force_loop(design, None, delay_samples=1)
    T = 1.0 / l0.rate_hz
    w = np.logspace(0, 3.5, 50)
    s_w = 1j * 2.0 / T * np.tan(w * T / 2.0)
    np.testing.assert_allclose(l1.L_w(s_w), l0.L_w(s_w) * np.exp(-1j * w * T), rtol=1e-9)
    assert sampled_force_loop(design, comp).stable


@needs_loops
@pytest.mark.parametrize("env,kind,wq", SAMPLED_CASES[:6] + [("stiff", "ld-dob", 10.0)])
@pytest.mark.parametrize("d", [0, 1])
def test_sampled_stability_agrees_with_python_control_feedback(env, kind, wq, d):
    """Closed loop from python-control state-space interconnection of the discrete pieces."""
    design = Design.nominal(env)
    comp = None if kind is None else Compensator(kind=kind, w_q_hz=wq)
    loop = sampled_force_loop(design, comp, delay_samples=d)
    T = 1.0 / loop.rate_hz
    from forecast_design.symbolic import derive_motor_angle_plant, force_plant_tf

    Pc = force_plant_tf(design).to_control()
    Ptc = derive_motor_angle_plant(design.environment.locked).at(design).to_control()
    if design.environment.k_e == 0.0 and not design.environment.locked:
        pytest.skip("free output: P_theta's rigid-body mode is cancelled only symbolically")
    from scipy import signal

    # one realisation per output (no shared states: the plant modes appear twice, both stable)
    Ps = control.c2d(control.ss(*signal.tf2ss(Pc.num[0][0], Pc.den[0][0])), T, "zoh")
    Pts = control.c2d(control.ss(*signal.tf2ss(Ptc.num[0][0], Ptc.den[0][0])), T, "zoh")
    split = control.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((2, 0)), np.ones((2, 1)), T)
    plant = control.series(split, control.append(Ps, Pts))
    delay = control.ss(control.tf([1.0], [1.0] + [0.0] * d, T)) if d else control.ss(control.tf([1.0], [1.0], T))
    z1 = control.ss(control.tf([1.0], [1.0, 0.0], T))
    C = control.ss(control.tf(list(loop.C.num), list(loop.C.den), T))
    if loop.observer:
        Gm, Gs, Gt = (control.ss(control.tf(list(g.num), list(g.den), T)) for g in loop.observer)
    else:
        Gm = Gs = Gt = control.ss(control.tf([0.0], [1.0], T))
    # c = u + Gm z^-1 c + Gs tau_s + Gt theta; tau_s, theta = plant(z^-d c); u = -C tau_s
    fwd = control.series(delay, plant)                       # c -> [tau_s; theta]
    obs = control.ss(control.append(Gs, Gt))
    obs_out = control.series(fwd, obs)                       # c -> [Gs tau_s; Gt theta]
    sum2 = control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.ones((1, 2)), T)
    H = control.parallel(control.series(obs_out, sum2), control.series(z1, Gm))   # c -> tau_hat
    inner = control.feedback(control.ss(control.tf([1.0], [1.0], T)), H, sign=1)  # u -> c
    pick = control.ss(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[1.0, 0.0]]), T)
    L = control.series(inner, fwd, pick, C)                  # u -> C tau_s
    closed = control.feedback(L, 1, sign=-1)
    poles = control.poles(closed)
    assert (np.max(np.abs(poles)) < 1.0) == loop.stable
    # every root of our characteristic polynomial is a pole of the interconnection
    for p in loop.closed_loop_poles:
        if abs(p) > 1e-6:
            assert np.min(np.abs(poles - p)) < 1e-5 * max(1.0, abs(p)), p


@needs_loops
def test_loop_margins_matches_force_loop_and_sampled():
    design = Design.nominal("stiff")
    comp = Compensator(kind="lo-dob", w_q_hz=5.0)
    from forecast_design.symbolic import force_loop

    fl = force_loop(design, comp, break_at="plant-input")
    cont = loop_margins(design, comp, break_at="plant-input", sigma=0.3)
    assert cont == disk_margin(fl.L, 0.3, closed_loop_stable=fl.stable)
    samp = loop_margins(design, comp, sampled=True, break_at="plant-input")
    ref = sampled_force_loop(design, comp, break_at="plant-input")
    assert samp == ref.disk_margin()
    # both break points give the same closed loop
    other = sampled_force_loop(design, comp, break_at="controller")
    np.testing.assert_allclose(other.characteristic_polynomial, ref.characteristic_polynomial, rtol=1e-9)
    assert 0.0 < samp.alpha and 0.0 < samp.frequency_rad_s <= math.pi * 2000.0


@needs_loops
def test_sampled_disk_margin_agrees_with_discrete_L_grid_at_moderate_order():
    """The z-form L (Tustin of L_w) on a fine grid up to Nyquist gives the same peak."""
    loop = sampled_force_loop(Design.nominal("stiff"), None, rate_hz=2000.0)
    T = 1.0 / loop.rate_hz
    w = np.linspace(1e-3, math.pi / T, 200001)
    z = np.exp(1j * w * T)
    Lz = loop.L(z)
    grid_alpha = 1.0 / np.max(np.abs(1.0 / (1.0 + Lz) - 0.5))
    alpha = loop.disk_margin().alpha
    assert alpha <= grid_alpha + 1e-9 and abs(alpha - grid_alpha) < 1e-5


def test_sampled_force_loop_rejects_bad_inputs():
    design = Design.nominal("soft")
    with pytest.raises(ParameterError, match="rate_hz"):
        sampled_force_loop(design, rate_hz=0.0)
    with pytest.raises(ParameterError, match="delay_samples"):
        sampled_force_loop(design, delay_samples=-1)
    with pytest.raises(ParameterError, match="break_at"):
        sampled_force_loop(design, break_at="sensor")
