"""Discretisation and the discrete filter, against closed forms, scipy and python-control."""

import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from forecast_design.errors import ParameterError
from forecast_design.export import FIRST_DIFFERENCE, DiscreteFilter, delta_to_sos, discretize, sos_to_delta
from forecast_design.lti import RationalTF

SCIPY_METHOD = {"tustin": "bilinear", "zoh": "zoh", "backward-euler": "backward_diff", "forward-euler": "euler"}
RTOL_COEFF = 1e-10


@pytest.mark.parametrize("tau,rate_hz", [(0.1, 1000.0), (0.01, 2000.0), (2.0, 50.0)])
def test_zoh_first_order_lag_closed_form(tau, rate_hz):
    d = discretize(RationalTF([1.0], [tau, 1.0]), rate_hz, "zoh")
    a = math.exp(-1.0 / (rate_hz * tau))
    assert d.den == pytest.approx((1.0, -a), rel=1e-13, abs=1e-15)
    assert d.num == pytest.approx((0.0, 1.0 - a), rel=1e-12, abs=1e-15)
    assert d.method == "zoh" and d.prewarp_hz is None and d.rate_hz == rate_hz


proper_tfs = [
    RationalTF([2.0, 3.0, 5.0], [1.0, 4.0, 30.0, 7.0]),
    RationalTF([1.0, 0.0], [0.01, 1.0]),
    RationalTF([0.5, 1.0, 2.0], [1.0, 2.0, 100.0]),
    RationalTF([1.0], [1.0, 0.0]),
]


@pytest.mark.parametrize("method", list(SCIPY_METHOD))
@pytest.mark.parametrize("tf", proper_tfs, ids=range(len(proper_tfs)))
def test_discretize_matches_scipy_cont2discrete(method, tf):
    d = discretize(tf, 200.0, method)
    num, den, _ = signal.cont2discrete((tf.num, tf.den), 1.0 / 200.0, method=SCIPY_METHOD[method])
    num = np.atleast_1d(np.squeeze(num)) / den[0]
    den = den / den[0]
    num = np.concatenate([np.zeros(len(den) - len(num)), num])
    np.testing.assert_allclose(d.den, den, rtol=RTOL_COEFF, atol=1e-12)
    np.testing.assert_allclose(d.num, num, rtol=RTOL_COEFF, atol=1e-12)


@pytest.mark.parametrize("prewarp_hz", [1.0, 10.0, 80.0])
def test_tustin_prewarp_matches_python_control(prewarp_hz):
    tf = RationalTF([2.0, 3.0, 5.0], [1.0, 4.0, 30.0, 7.0])
    d = discretize(tf, 200.0, "tustin", prewarp_hz=prewarp_hz)
    ref = control.sample_system(tf.to_control(), 1 / 200.0, method="tustin",
                                prewarp_frequency=2 * np.pi * prewarp_hz)
    den = np.asarray(ref.den[0][0], dtype=float)
    np.testing.assert_allclose(d.den, den / den[0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(d.num, np.asarray(ref.num[0][0], dtype=float) / den[0], rtol=1e-10, atol=1e-12)
    # and the response is exact at the prewarp frequency
    w = 2 * np.pi * prewarp_hz
    assert d.freqresp(np.array([w]))[0] == pytest.approx(tf(1j * w), rel=1e-10)
    assert d.prewarp_hz == prewarp_hz


def test_tustin_frequency_response_matches_below_tenth_of_rate():
    # Warping at f: tan(pi f/rate)/(pi f/rate) - 1 <= 3.4 % for f <= rate/10.
    rate = 2000.0
    tf = RationalTF([1.0], [1 / (2 * np.pi * 30.0) ** 2, 2 * 0.5 / (2 * np.pi * 30.0), 1.0])
    d = discretize(tf, rate)
    w = 2 * np.pi * np.logspace(-1, np.log10(rate / 10), 200)
    # Tustin identity: H_d(exp(j w T)) = H((2/T) tan(w T / 2) j) exactly.
    w_warped = 2 * rate * np.tan(w / (2 * rate))
    np.testing.assert_allclose(d.freqresp(w), tf.freqresp(w_warped), rtol=1e-9)
    rel = np.abs(d.freqresp(w) - tf.freqresp(w)) / np.abs(tf.freqresp(w))
    # a 2nd-order roll-off turns the <= 3.4 % frequency warp into <= ~7 % in magnitude
    assert np.max(rel) < 2 * (math.tan(math.pi / 10) / (math.pi / 10) - 1) + 0.001
    assert np.max(rel[w < 2 * np.pi * rate / 100]) < 0.005
    assert d.dcgain() == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("method", ["tustin", "zoh", "backward-euler"])
def test_discrete_filter_equals_sosfilt_and_lfilter(method, rng):
    tf = RationalTF([2.0, 3.0, 5.0, 1.0], [1.0, 4.0, 30.0, 7.0, 2.0])
    d = discretize(tf, 100.0, method)
    x = rng.normal(size=2000)
    f = DiscreteFilter(d)
    y = f.filter(x)
    np.testing.assert_allclose(y, signal.sosfilt(d.to_sos(), x), rtol=0, atol=1e-12)
    cascade = x
    for sec in d.to_sos():  # lfilter section by section: the same cascade, another implementation
        cascade = signal.lfilter(sec[:3], sec[3:], cascade)
    np.testing.assert_allclose(y, cascade, rtol=0, atol=1e-12)
    # the direct-form 4th-order recursion differs only by coefficient round-off
    np.testing.assert_allclose(y, signal.lfilter(d.num, d.den, x), rtol=0, atol=1e-6 * np.max(np.abs(y)))
    f.reset()
    y2 = np.array([f.step(v) for v in x])
    assert np.array_equal(y, y2)


def test_float32_filter_runs_in_float32_and_stays_close(rng):
    d = discretize(RationalTF([1.0], [1 / (2 * np.pi * 10) ** 2, 1.414 / (2 * np.pi * 10), 1.0]), 2000.0)
    x = rng.normal(size=500)
    f32 = DiscreteFilter(d, np.float32)
    y32 = f32.filter(x)
    assert f32.sos.dtype == np.float32 and y32.dtype == np.float32
    y64 = DiscreteFilter(d).filter(x)
    assert np.max(np.abs(y32 - y64)) < 1e-3 * np.max(np.abs(y64))
    assert not np.array_equal(y32.astype(float), y64)


def test_to_sos_has_the_same_response_as_the_tf():
    d = discretize(RationalTF([2.0, 3.0, 5.0, 1.0], [1.0, 4.0, 30.0, 7.0, 2.0]), 100.0)
    sos = d.to_sos()
    assert sos.shape == (2, 6) and np.all(sos[:, 3] == 1.0)
    w, h_sos = signal.sosfreqz(sos, worN=64)
    _, h_tf = signal.freqz(d.num, d.den, worN=w)
    np.testing.assert_allclose(h_sos, h_tf, rtol=1e-7)  # poles near z = 1: root-finding conditioning


def test_zero_filter_outputs_zeros():
    d = discretize(RationalTF([0.0], [1.0, 2.0]), 100.0)
    assert np.all(DiscreteFilter(d).filter(np.ones(10)) == 0.0)


@given(p=st.floats(0.1, 100.0), z=st.floats(0.1, 100.0), k=st.floats(-10, 10))
@settings(max_examples=30, deadline=None)
def test_tustin_preserves_dc_gain_and_stability(p, z, k):
    tf = RationalTF([k, k * z], [1.0, p])
    d = discretize(tf, 1000.0)
    assert d.dcgain() == pytest.approx(tf.dcgain(), rel=1e-9, abs=1e-12)
    assert np.all(np.abs(np.roots(d.den)) < 1.0)


def test_discretize_rejects_bad_input():
    with pytest.raises(ParameterError, match="improper"):
        discretize(RationalTF([1.0, 0.0], [1.0]), 100.0)
    with pytest.raises(ParameterError, match="method"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, "bogus")
    with pytest.raises(ParameterError, match="improper.*backward-euler"):
        discretize(RationalTF([1.0, 0.0], [1.0]), 100.0, "matched")
    with pytest.raises(ParameterError, match="needs prewarp_hz"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, "tustin-prewarp")
    with pytest.raises(ParameterError, match="prewarp_hz applies to tustin"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, "zoh", prewarp_hz=1.0)
    with pytest.raises(ParameterError, match="rate_hz/2"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, prewarp_hz=60.0)
    with pytest.raises(ParameterError, match="rate_hz"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 0.0)
    with pytest.raises(ParameterError, match="continuous"):
        discretize(RationalTF([1.0], [1.0, 1.0], dt=0.01), 100.0)


# --- the delta-operator realisation -------------------------------------------------------

def _delta_response(dsos, w_rad_s, rate_hz):
    """Frequency response of delta sections, evaluated in rho = exp(j w T) - 1 (no cancellation)."""
    wt = np.asarray(w_rad_s) / rate_hz
    r = -2.0 * np.sin(wt / 2) ** 2 + 1j * np.sin(wt)  # exp(j wT) - 1 without cancellation
    h = np.ones_like(r)
    for b0, b1, b2, _, a1, a2 in dsos:
        if b2 == 0.0 and a2 == 0.0:
            h *= (b0 * r + b1) / (r + a1)
        else:
            h *= (b0 * r * r + b1 * r + b2) / (r * r + a1 * r + a2)
    return h


def _observer_tfs(kind, env="exp-soft", w_q_hz=10.0, method="tustin"):
    """The observer's filters as the compensator strategy realises them (Tustin), or with ``method``."""
    from forecast_design.compensators import compensator_strategy
    from forecast_design.params import Compensator, Design

    comp = Compensator(kind=kind, w_q_hz=w_q_hz)
    design = Design.nominal(env, compensator=comp)
    f = compensator_strategy(comp).linear_filters(comp, design)
    return [discretize(tf.minreal(), 2000.0, method) for tf in (f.from_tau_m, f.from_tau_s, f.from_theta)
            if any(c != 0.0 for c in tf.num)]


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob", "motor-fob"])
@pytest.mark.parametrize("env", ["exp-soft", "locked", "link-only"])
def test_delta_sections_are_the_tustin_map_of_the_continuous_filter(kind, env):
    # Tustin identity: H_d(exp(j w T)) = H((2/T) tan(w T / 2) j), exact; the delta realisation
    # meets it to float64 round-off although its poles sit within 0.01 of z = 1
    w = 2 * np.pi * np.logspace(-1, np.log10(900.0), 80)
    for tf in _observer_tfs(kind, env):
        h = _delta_response(tf.to_delta_sos(), w, 2000.0)
        ref = tf.source.freqresp(2 * 2000.0 * np.tan(w / (2 * 2000.0)))
        np.testing.assert_allclose(h, ref, rtol=1e-11, atol=1e-11 * np.max(np.abs(ref)))


@pytest.mark.parametrize("kind", ["ea-fob", "ld-dob", "motor-fob"])
def test_zoh_delta_sections_match_scipy_state_space(kind):
    w = 2 * np.pi * np.logspace(-1, np.log10(900.0), 40)
    for tf in _observer_tfs(kind, method="zoh"):
        A, B, C, D = signal.tf2ss(tf.source.num, tf.source.den)
        Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, D), 1 / 2000.0, method="zoh")
        z = np.exp(1j * w / 2000.0)
        ref = np.array([(Cd @ np.linalg.solve(zz * np.eye(A.shape[0]) - Ad, Bd))[0, 0] + Dd[0, 0] for zz in z])
        h = _delta_response(tf.to_delta_sos(), w, 2000.0)
        np.testing.assert_allclose(h, ref, rtol=1e-6, atol=1e-9 * np.max(np.abs(ref)))


def test_float32_delta_coefficients_keep_the_dc_gain_shift_coefficients_do_not():
    # EA-FOB's G_s = -Q / P_n^EA has DC gain -1 and poles/zeros within 0.01 of z = 1 at 2 kHz.
    (g_m, g_s) = _observer_tfs("ea-fob")
    assert g_s.source.dcgain() == pytest.approx(-1.0, rel=1e-12)
    delta32 = g_s.to_delta_sos(np.float32).astype(float)
    dc_delta = np.prod([b2 / a2 for b0, b1, b2, _, a1, a2 in delta32])
    shift32 = g_s.to_sos(np.float32).astype(float)
    dc_shift = np.prod([(b0 + b1 + b2) / (1 + a1 + a2) for b0, b1, b2, _, a1, a2 in shift32])
    assert dc_delta == -1.0                      # every section: b2 is the very number a2
    assert abs(dc_shift + 1.0) > 1e-3            # float32 shift form: > 0.1 % off
    # Q (= G_m) keeps Q(1) = 1 exactly in float32: the observer loop 1 - Q keeps its integral action
    q32 = g_m.to_delta_sos(np.float32)
    y = DiscreteFilter(q32).filter(np.full(20000, 0.7, dtype=np.float32))
    assert abs(float(y[-1]) - 0.7) <= 2 * np.spacing(np.float32(0.7))


def test_differentiators_start_with_exact_first_differences():
    # motor-side FOB: G_theta = -Q J_m s^2 -> two first differences, then the Q sections
    (_, _, g_theta) = _observer_tfs("motor-fob")
    d = g_theta.to_delta_sos()
    assert np.array_equal(d[:2], np.array([FIRST_DIFFERENCE] * 2))
    # a large angle (1000 rad) moving: float32 and float64 runs of the same float32 input agree
    # to 1e-7 N m once the start-up transient has gone (the differences are exact; nothing has
    # to cancel against an integrated 1000 rad state)
    n = np.arange(8000)
    theta = (1000.0 + 0.5 * n / 2000.0 + 0.01 * np.sin(2 * np.pi * 2.0 * n / 2000.0)).astype(np.float32)
    y32 = DiscreteFilter(g_theta.to_delta_sos(np.float32)).filter(theta).astype(float)
    y64 = DiscreteFilter(g_theta.to_delta_sos()).filter(theta.astype(float))
    assert np.max(np.abs(y64[4000:])) > 0.1
    assert np.max(np.abs(y32 - y64)[4000:]) < 1e-7
    np.testing.assert_allclose(delta_to_sos(np.array([FIRST_DIFFERENCE])), [[1.0, -1.0, 0.0, 1.0, 0.0, 0.0]])


@given(b=st.lists(st.floats(-2, 2), min_size=3, max_size=3), r=st.floats(0.05, 0.95), phi=st.floats(0.0, 3.0))
@settings(max_examples=40, deadline=None)
def test_delta_and_shift_sections_convert_both_ways(b, r, phi):
    sos = np.array([[b[0], b[1], b[2], 1.0, -2 * r * math.cos(phi), r * r]])
    dsos = sos_to_delta(sos)
    np.testing.assert_allclose(delta_to_sos(dsos), sos, rtol=1e-12, atol=1e-12)
    x = np.random.default_rng(0).normal(size=200)
    np.testing.assert_allclose(DiscreteFilter(dsos).filter(x), signal.sosfilt(sos, x), rtol=1e-9, atol=1e-9)


def test_zoh_of_a_zero_filter_raises_no_warning():
    d = discretize(RationalTF([0.0], [1.0, 88.9, 3948.0]), 2000.0, "zoh")  # warnings are errors here
    assert np.all(DiscreteFilter(d).filter(np.ones(5)) == 0.0)


# --- matched pole-zero and improper backward Euler ------------------------------------------------


@pytest.mark.parametrize("tf", [RationalTF([2.0, 3.0], [1.0, 4.0]), RationalTF([0.5, 1.0, 2.0], [1.0, 2.0, 100.0])],
                         ids=["first-order", "second-order"])
def test_matched_equals_python_control_for_a_biproper_tf(tf):
    d = discretize(tf, 200.0, "matched")
    ref = control.sample_system(tf.to_control(), 1 / 200.0, method="matched")
    den = np.asarray(ref.den[0][0], dtype=float)
    np.testing.assert_allclose(d.den, den / den[0], rtol=1e-12)
    np.testing.assert_allclose(d.num, np.asarray(ref.num[0][0], dtype=float) / den[0], rtol=1e-10)


def test_matched_zeros_at_infinity_go_to_z_minus_1():
    """A strictly proper TF: python-control's result times ((z + 1)/2)^(relative degree), the same DC gain."""
    tf = RationalTF([1.0, 3.0], [1.0, 4.0, 30.0])
    d = discretize(tf, 200.0, "matched")
    ref = control.sample_system(tf.to_control(), 1 / 200.0, method="matched") * control.tf([0.5, 0.5], [1.0], 1 / 200.0)
    z = np.exp(1j * np.array([0.3, 3.0, 30.0]) / 200.0)
    np.testing.assert_allclose(np.polyval(d.num, z) / np.polyval(d.den, z), [ref(zz) for zz in z], rtol=1e-10)
    assert d.dcgain() == pytest.approx(tf.dcgain(), rel=1e-12)


def test_matched_integrator_matches_the_low_frequency_asymptote():
    """I/s has no DC gain: s H(s) = I is matched by ((z - 1)/T) H(z) at z = 1, which gives Tustin's integrator."""
    d = discretize(RationalTF([20.0], [1.0, 0.0]), 2000.0, "matched")
    np.testing.assert_allclose(d.num, [0.005, 0.005], rtol=1e-12)
    np.testing.assert_allclose(d.den, [1.0, -1.0], rtol=0, atol=0)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(P=st.floats(0.0, 50.0), D=st.floats(1e-4, 1.0), rate=st.sampled_from([500.0, 2000.0, 10000.0]))
def test_backward_euler_of_an_unfiltered_pd_is_the_first_difference(P, D, rate):
    """P + D s -> P + D (1 - z^-1) rate: u_k = P e_k + D (e_k - e_(k-1)) rate, and its delta sections run it."""
    d = discretize(RationalTF([D, P], [1.0]), rate, "backward-euler")
    e = np.array([0.0, 1.0, 1.0, -0.5, 2.0])
    expected = P * e + D * np.diff(e, prepend=0.0) * rate
    np.testing.assert_allclose(signal.lfilter(d.num, d.den, e), expected, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(DiscreteFilter(d).filter(e), expected, rtol=1e-12, atol=1e-9 * max(1.0, D * rate))


def test_a_tf_given_in_z_is_realised_from_its_roots():
    from forecast_design.discrete import DiscreteTF

    d = DiscreteTF.from_z([5.2, -5.1], [1.0, -1.0], 2000.0)    # a PI in z
    x = np.random.default_rng(3).normal(size=500)
    np.testing.assert_allclose(DiscreteFilter(d).filter(x), signal.lfilter(d.num, d.den, x), rtol=1e-10, atol=1e-10)
    with pytest.raises(ParameterError, match="not causal"):
        DiscreteTF.from_z([1.0, 2.0, 3.0], [1.0, 0.5], 2000.0)
