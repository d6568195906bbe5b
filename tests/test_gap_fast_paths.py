"""The diagnosis's fast paths equal the straightforward computations they replace (issue 16).

Each check compares against an independent implementation: scipy's own ``decimate``, one column
at a time, the scalar Dahl recursion, and cvxpy's group lasso on the same data.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from forecast_design.friction.derivatives import decimate_columns, default_filter_settings
from forecast_design.gap import joint, residuals, structures
from forecast_design.gap.residuals import GapData, lowpass


@pytest.mark.parametrize("R", [2, 10])
def test_decimate_columns_is_bit_equal_to_scipy_decimate(R):
    rng = np.random.default_rng(R)
    st = default_filter_settings(2000.0, decimation_factor=R)
    e = st.edge_samples
    for shape, axis in (((3000, 3), 0), ((2, 3000), 1)):
        X = rng.standard_normal(shape)
        kept = X[e:-e] if axis == 0 else X[:, e:-e]
        want = signal.decimate(kept, R, ftype="iir", axis=axis, zero_phase=True)
        got = decimate_columns(X, st, axis=axis)
        assert got.shape == want.shape and np.array_equal(got, want)


class _Data:
    """The two attributes ``GapData.decimate``/``decimate_many`` read."""

    def __init__(self, settings):
        self.settings = settings

    decimate = GapData.decimate
    decimate_many = GapData.decimate_many


@pytest.mark.parametrize("batch_samples", [1 << 18, 4000, 9000])      # all six columns, one, two per pass
def test_decimate_many_is_bit_equal_to_one_column_at_a_time(monkeypatch, batch_samples):
    monkeypatch.setattr(residuals, "BATCH_SAMPLES", batch_samples)
    rng = np.random.default_rng(0)
    data = _Data(default_filter_settings(2000.0))
    cols = [rng.standard_normal(4000) * 10.0 ** k for k in range(-3, 3)]
    many = data.decimate_many(iter(cols))      # a generator's columns, one at a time
    assert many.shape[0] == len(cols)
    for row, col in zip(many, cols):
        assert np.array_equal(row, data.decimate(col))
    # the batched low-pass and decimation (scipy's filters over the stacked block) give the same numbers
    batched = decimate_columns(lowpass(np.array(cols), data.settings), data.settings, axis=1)
    assert np.array_equal(many, batched)
    assert np.array_equal(lowpass(np.array(cols), data.settings)[2], lowpass(cols[2], data.settings))


@pytest.mark.parametrize("chunk", [1 << 16, 7, 1000])
def test_dahl_state_equals_the_scalar_recursion(chunk):
    rng = np.random.default_rng(1)
    v = rng.standard_normal(3000) * 0.1
    v[rng.random(v.size) < 0.2] = 0.0
    dt, x_p = 5e-4, 1e-3
    s, want = float(np.sign(v[0])), []
    for vk in v:
        s = (s + dt / x_p * vk) / (1.0 + dt / x_p * abs(vk))
        want.append(s)
    assert np.array_equal(structures._dahl(v, dt, x_p, chunk), np.array(want))   # across chunk boundaries


def test_group_lasso_path_matches_cvxpy_on_the_same_problem():
    cp = pytest.importorskip("cvxpy")
    rng = np.random.default_rng(2)
    n, p = 400, 9
    A = rng.standard_normal((n, p))
    w_true = np.array([0.5, -0.2, 0.1, 1.0, -1.0, 0.0, 0.0, 0.0, 0.3])
    y = A @ w_true + 0.05 * rng.standard_normal(n)
    spans = [slice(3, 5), slice(5, 8), slice(8, 9)]
    lo = np.array([-0.15, 0.0, -np.inf] + [-np.inf] * 6)
    hi = np.array([0.15, np.inf, 0.05] + [np.inf] * 6)
    weight = 1.0 / n
    lams = [1e-1, 1e-2, 1e-4]
    Q, R = np.linalg.qr(A)
    got = joint._group_lasso_path(R, Q.T @ y, weight, spans, lo, hi, lams)
    w = cp.Variable(p)
    lam = cp.Parameter(nonneg=True)
    penalty = sum(np.sqrt(s.stop - s.start) * cp.norm(w[s], 2) for s in spans)
    cons = [w[i] >= lo[i] for i in range(p) if np.isfinite(lo[i])]
    cons += [w[i] <= hi[i] for i in range(p) if np.isfinite(hi[i])]
    prob = cp.Problem(cp.Minimize(weight * cp.sum_squares(A @ w - y) + lam * penalty), cons)
    for value, wv in zip(lams, got):
        lam.value = value
        prob.solve(solver=cp.CLARABEL)
        assert wv is not None
        np.testing.assert_allclose(wv, w.value, atol=1e-6)
    # the largest weight removes at least one group entirely, the bounds hold
    assert any(np.linalg.norm(got[0][s]) < 1e-6 for s in spans)
    assert all(np.all(g >= lo - 1e-9) and np.all(g <= hi + 1e-9) for g in got)
