"""Polynomial helpers against numpy's polynomial functions and the closed forms they stand for."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from forecast_design import polynomials as poly

coeffs = arrays(np.float64, st.integers(1, 7), elements=st.floats(-10, 10, allow_nan=False))


@settings(max_examples=200, deadline=None)
@given(p=coeffs, q=coeffs)
def test_arithmetic_matches_numpy(p, q):
    np.testing.assert_allclose(poly.trim(poly.add(p, q)), poly.trim(np.polyadd(p, q)), atol=1e-12)
    np.testing.assert_allclose(poly.trim(poly.sub(p, q)), poly.trim(np.polysub(p, q)), atol=1e-12)
    np.testing.assert_allclose(poly.trim(poly.mul(p, q)), poly.trim(np.polymul(p, q)), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(poly.trim(poly.derivative(p)), poly.trim(np.polyder(p)) if p.size > 1 else [0.0])
    np.testing.assert_allclose(poly.trim(poly.power(p, 3)), poly.trim(np.polymul(np.polymul(p, p), p)),
                               rtol=1e-12, atol=1e-6)


@settings(max_examples=200, deadline=None)
@given(p=coeffs, q=coeffs, w=st.floats(0.0, 20.0))
def test_even_forms_evaluate_the_magnitude_and_the_cross_term_on_the_imaginary_axis(p, q, w):
    pj, qj = np.polyval(p, 1j * w), np.polyval(q, 1j * w)
    scale = 1.0 + abs(pj) ** 2 + abs(pj * qj)
    assert abs(np.polyval(poly.abs2_even(p), w * w) - abs(pj) ** 2) <= 1e-9 * scale
    assert abs(np.polyval(poly.cross_even(p, q), w * w) - (pj * np.conj(qj)).real) <= 1e-9 * scale


def test_trim_trailing_zeros_and_their_removal():
    assert poly.trim([0.0, 0.0, 1.0, 2.0]).tolist() == [1.0, 2.0]
    assert poly.trim([0.0, 0.0]).tolist() == [0.0]
    p = np.array([1.0, 3.0, 0.0, 0.0])                       # s^3 + 3 s^2 = s^2 (s + 3)
    assert poly.trailing_zeros(p) == 2
    assert poly.drop_trailing(p, 2).tolist() == [1.0, 3.0]
    assert poly.pad(np.array([1.0, 2.0]), 4).tolist() == [0.0, 0.0, 1.0, 2.0]
