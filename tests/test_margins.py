"""Tests for forecast_design.margins: exact disk margins, closed forms, cross-checks, disk geometry."""

from __future__ import annotations

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


def test_undetermined_root_follows_the_first_order_perturbation_bound():
    """A root cluster next to the boundary is undetermined; well-separated roots are not."""
    from forecast_design.margins.exact import undetermined_root

    separated = np.poly([0.5, -0.3, 0.2 + 0.4j, 0.2 - 0.4j]).real
    assert undetermined_root(separated, discrete=True) is None
    # a five-fold root at 0.999: rounding its coefficients scatters the computed roots by ~eps^(1/5),
    # past z = 1; the bound covers the scatter
    cluster = np.poly([0.999] * 5).real
    root, radius, distance = undetermined_root(cluster, discrete=True)
    assert radius > distance and np.all(np.abs(np.roots(cluster) - 0.999) < radius)
    assert undetermined_root(np.poly([-1.0, -2.0]).real, discrete=False) is None
    assert undetermined_root(np.poly([1j, -1j]).real, discrete=False) is None   # inside the tolerance band


@pytest.mark.parametrize("env", ["soft", "stiff"])
def test_a_z_polynomial_loop_whose_roots_it_cannot_place_says_so(env):
    """A sampled loop written as z-polynomials at 2 kHz with low cutoffs has poles crowded at z = 1
    that its coefficients do not determine: the z-form's verdict is noise (stable loops read as
    unstable, margins off by 70 %). Every such answer carries an IllConditionedWarning; the w-plane
    form (SampledForceLoop.disk_margin, whose verdicts the simulation reproduces:
    test_the_sampled_margin_and_the_simulation_agree_on_stability) is the reference."""
    import warnings

    from forecast_design.errors import IllConditionedWarning
    from forecast_design.loops import sampled_force_loop
    from forecast_design.margins import disk_margins
    from forecast_design.params import Compensator, Design

    design = Design.nominal(env)
    wrong = warned = 0
    for kind in ("lo-dob", "ea-fob", "ld-dob"):
        for w_q in (2.0, 10.0, 50.0, 200.0):
            for delay in (0, 1):
                loop = sampled_force_loop(design, Compensator(kind=kind, w_q_hz=w_q), delay_samples=delay)
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    z_form = disk_margin(loop.L)
                said = any(issubclass(w.category, IllConditionedWarning) for w in caught)
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    batch = disk_margins([loop.L])         # the batch decides as the single routine
                assert bool(batch.stable[0]) == z_form.stable
                assert said == any(issubclass(w.category, IllConditionedWarning) for w in caught)
                ref = loop.disk_margin()
                bad = z_form.stable != ref.stable or abs(z_form.alpha - ref.alpha) > 0.01 * ref.alpha
                assert said or not bad, (kind, w_q, delay, z_form.alpha, ref.alpha)
                wrong += bad
                warned += said
    assert wrong > 0 and warned >= wrong      # the sweep holds the case the warning exists for
    coarse = sampled_force_loop(design, Compensator(kind="lo-dob", w_q_hz=20.0), rate_hz=500.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllConditionedWarning)        # well conditioned: silent and right
        assert disk_margin(coarse.L).alpha == pytest.approx(coarse.disk_margin().alpha, rel=1e-6)


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
    with pytest.raises(ParameterError, match="RationalTF or a python-control"):
        disk_margin("25/(s^3+10s^2+10s+10)")
    with pytest.raises(ParameterError, match="skew or its alias sigma, not both"):
        disk_margin(SEILER_L, 0.5, sigma=-0.5)


def test_disk_margin_accepts_python_control_models_and_the_skew_name():
    tf = SEILER_L.to_control()
    ref = disk_margin(SEILER_L, 0.3)
    # a control.TransferFunction, a control.StateSpace realisation and the round trip give the same margin
    for L in (tf, control.ss(tf)):
        dm = disk_margin(L, skew=0.3)
        assert dm.alpha == pytest.approx(ref.alpha, rel=1e-9) and dm.skew == 0.3
    back = RationalTF.from_control(tf).normalized()
    assert (back.num, back.den, back.dt) == (SEILER_L.normalized().num, SEILER_L.normalized().den, None)
    assert disk_margin(SEILER_L, sigma=0.3) == ref
    # python-control's own disk margin of this stable loop (balanced) agrees with ours
    alpha_pc = control.disk_margins(tf, np.logspace(-2, 2, 4000), skew=0.0)[0]
    assert float(np.min(alpha_pc)) == pytest.approx(disk_margin(tf).alpha, rel=1e-4)
    mapping = disk_margin(tf).to_mapping()
    assert mapping["disk_margin"] == mapping["alpha"]
    assert mapping["phase_margins_deg"] == [-mapping["phase_margin_deg"], mapping["phase_margin_deg"]]
    assert mapping["frequency_hz"] == pytest.approx(mapping["frequency_rad_s"] / (2 * np.pi), rel=1e-15)


# --- a discrete loop given as a state space is analysed on its own realisation ------------------


def test_discrete_state_space_loop_uses_its_realisation():
    """A 2 kHz state-space loop with modes clustered at z ~ 1 (the ZOH image of a stiff force loop): its
    closed-loop eigenvalues and a dense grid of its own frequency response decide, not the roots of a
    z-polynomial made from it."""
    from forecast_design.loops import force_loop
    from forecast_design.params import Compensator, Design

    # soft / EA-FOB 10 Hz: its z-polynomials (ss -> tf) put a closed-loop root at |z| > 1 and said unstable
    cont = force_loop(Design.nominal("soft"), Compensator(kind="ea-fob", w_q_hz=10.0)).L
    ss = control.c2d(control.ss(cont.to_control()), 1 / 2000.0, "zoh")
    closed = np.linalg.eigvals(ss.A - ss.B @ ss.C / (1.0 + ss.D[0, 0]))
    stable = bool(np.max(np.abs(closed)) < 1.0)
    dm = disk_margin(ss)
    assert dm.stable == stable
    w = np.geomspace(1e-2, np.pi * 2000.0 * 0.999999, 100_000)
    L = np.asarray(ss(np.exp(1j * w / 2000.0))).ravel()
    alpha_grid = 1.0 / np.max(np.abs(1.0 / (1.0 + L) - 0.5))
    assert stable and dm.alpha == pytest.approx(alpha_grid, rel=1e-3) and dm.alpha <= alpha_grid * (1 + 1e-9)


# --- classical margins (every crossover) against python-control -----------------------------------


@pytest.mark.parametrize("sys", [control.tf([2.0], [1.0, 1.0, 1.0, 0.0]), control.tf([10.0], [1.0, 3.0, 3.0, 1.0]),
                                 control.tf([1.0, 2.0], [1.0, 0.1, 2.0, 0.3, 0.01]),
                                 control.tf([50.0, 5.0], [1.0, 2.0, 30.0, 10.0, 0.0])])
def test_classical_margins_match_python_control_returnall(sys):
    from forecast_design.margins import classical_margins

    m = classical_margins(RationalTF.from_control(sys), stable=True)
    gm, pm, _, wpc, wgc, _ = control.stability_margins(sys, returnall=True)
    ours_g = sorted((c.frequency_rad_s, c.gain_margin) for c in m.phase_crossovers if c.frequency_rad_s > 0)
    theirs_g = sorted((w, g) for w, g in zip(wpc, gm) if w > 0 and np.isfinite(g))
    assert len(ours_g) == len(theirs_g)
    for (w1, g1), (w2, g2) in zip(ours_g, theirs_g):
        assert w1 == pytest.approx(w2, rel=1e-6) and g1 == pytest.approx(g2, rel=1e-6)
    ours_p = sorted((c.frequency_rad_s, c.phase_margin_deg) for c in m.gain_crossovers)
    theirs_p = sorted(zip(wgc, pm))
    assert len(ours_p) == len(theirs_p)
    for (w1, p1), (w2, p2) in zip(ours_p, theirs_p):
        assert w1 == pytest.approx(w2, rel=1e-6) and p1 == pytest.approx(p2, abs=1e-6)


def test_classical_delay_margin_is_the_delay_that_destabilises():
    """A delay of the reported margin puts the loop exactly at the stability limit (L e^{-s tau} = -1)."""
    from forecast_design.margins import classical_margins

    L = RationalTF((4.0,), (1.0, 2.0, 0.0))
    pm = classical_margins(L, stable=True).phase_margin
    w, tau = pm.frequency_rad_s, pm.delay_margin_s
    assert complex(L(1j * w) * np.exp(-1j * w * tau)) == pytest.approx(-1.0, abs=1e-9)
