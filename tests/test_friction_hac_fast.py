"""Issue 16: the Newey-West sums without Python loops, and the decimation of repeated columns.

The vectorised kernels of ``friction/_lsq.py`` are checked against the textbook loops written
out here (one Gram matrix per lag; one AR(1) fit per column), and the preparation's shortcut for
regressor columns that are the velocity or acceleration against decimating them directly.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from forecast_design.friction import _lsq
from forecast_design.friction.derivatives import decimate_columns, default_filter_settings, differentiate
from forecast_design.friction.identify import prepare_identification_data
from forecast_design.friction.terms import friction_model


def _loop_lag_sum(eps: np.ndarray, L: int) -> np.ndarray:
    G = np.zeros((eps.shape[1], eps.shape[1]))
    for lag in range(1, L + 1):
        G += (1.0 - lag / (L + 1.0)) * (eps[lag:].T @ eps[:-lag])
    return G


def _loop_bandwidth(u: np.ndarray) -> float:
    num = den = 0.0
    for a in range(u.shape[1]):
        x0, x1 = u[:-1, a], u[1:, a]
        d = float(x0 @ x0)
        if d <= 0:
            continue
        rho = min(max(float(x1 @ x0) / d, -0.97), 0.97)
        s2 = float(np.mean((x1 - rho * x0) ** 2))
        num += 4.0 * rho**2 * s2**2 / ((1.0 - rho) ** 6 * (1.0 + rho) ** 2)
        den += s2**2 / (1.0 - rho) ** 4
    return 0.0 if den == 0.0 else 1.1447 * (num / den * u.shape[0]) ** (1.0 / 3.0)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(8, 3000), k=st.integers(1, 8), lags=st.integers(0, 60), seed=st.integers(0, 2**31),
       ar=st.floats(-0.95, 0.95))
def test_bartlett_lag_sum_equals_the_sum_of_lagged_grams(n, k, lags, seed, ar):
    rng = np.random.default_rng(seed)
    eps = rng.standard_normal((n, k)) * 10.0 ** rng.uniform(-4, 4, k)
    eps[1:] += ar * eps[:-1]
    L = min(lags, n // 4)
    ref = _loop_lag_sum(eps, L)
    got = _lsq._bartlett_lag_sum(eps, L)
    scale = np.sqrt(np.outer(np.diag(eps.T @ eps), np.diag(eps.T @ eps)))   # Cauchy-Schwarz bound
    assert np.all(np.abs(got - ref) <= 1e-12 * np.maximum(scale, 1e-300))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(3, 3000), k=st.integers(1, 8), seed=st.integers(0, 2**31), dead=st.booleans())
def test_andrews_bandwidth_equals_the_column_by_column_plug_in(n, k, seed, dead):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, k))
    u[1:] += rng.uniform(-0.9, 0.9, k) * u[:-1]
    if dead:
        u[:, rng.integers(k)] = 0.0
    ref = _loop_bandwidth(u)
    assert _lsq._andrews_bandwidth(u) == pytest.approx(ref, rel=1e-12, abs=1e-300)


def _log(n=40_000, rate=2000.0, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    th = np.round((3 * np.sin(2 * np.pi * 0.3 * t) + 0.5 * np.sin(2 * np.pi * 1.1 * t)) / 3e-6) * 3e-6
    v = np.gradient(th, 1 / rate)
    return t, th, 0.3 * v + 0.4 * np.sign(v) + 0.05 * np.sin(th) + 0.01 * rng.standard_normal(n)


def test_velocity_and_inertia_columns_are_the_decimated_kinematics():
    t, th, f = _log()
    model = friction_model("extended-sfm", estimate_inertia=True)   # inertia, viscous, coulomb, harmonics
    data = prepare_identification_data(t, th, f, model)
    s = data.settings
    kin = differentiate(th, s)
    names = model.linear_names
    assert np.array_equal(data.regressor[:, names.index("viscous")], decimate_columns(kin.velocity, s))
    assert np.array_equal(data.regressor[:, names.index("inertia")], decimate_columns(kin.acceleration, s))
    assert np.array_equal(data.regressor[:, names.index("coulomb")], decimate_columns(np.sign(kin.velocity), s))
    assert s == default_filter_settings(2000.0)
