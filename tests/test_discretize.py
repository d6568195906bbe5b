"""Discretisation and the discrete filter, against closed forms, scipy and python-control."""

import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from forecast_design.errors import ParameterError
from forecast_design.export import DiscreteFilter, discretize
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
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, "matched")
    with pytest.raises(ParameterError, match="prewarp_hz applies to tustin"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, "zoh", prewarp_hz=1.0)
    with pytest.raises(ParameterError, match="rate_hz/2"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 100.0, prewarp_hz=60.0)
    with pytest.raises(ParameterError, match="rate_hz"):
        discretize(RationalTF([1.0], [1.0, 1.0]), 0.0)
    with pytest.raises(ParameterError, match="continuous"):
        discretize(RationalTF([1.0], [1.0, 1.0], dt=0.01), 100.0)
