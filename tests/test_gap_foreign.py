"""The diagnosis on logs from an independent generator (scipy's ODE solver, 1 kHz, another excitation).

The project's virtual testbed (numba RK4) is where the diagnosis was developed; these logs come
from a separate implementation of the spec's plant equations, integrated by scipy's adaptive
LSODA, sampled at 1 kHz instead of 2 kHz, with a zero-order-held random-phase multisine command.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from forecast_design import Design, experiment_from_arrays
from forecast_design.gap import diagnose

RATE_HZ = 1000.0
DURATION_S = 12.0
COUNTS = 2_000_000


def _command(rng):
    t = np.arange(int(DURATION_S * RATE_HZ)) / RATE_HZ
    freqs = np.array([0.11, 0.37, 0.83, 1.9, 4.3])
    phases = rng.uniform(0, 2 * np.pi, freqs.size)
    amps = np.array([1.2, 0.6, 0.4, 0.25, 0.15])
    return t, 0.5 + (amps[:, None] * np.sin(2 * np.pi * freqs[:, None] * t + phases[:, None])).sum(axis=0)


def _log(design, *, friction=lambda w, th: 0.0, gain=1.0, delay_s=0.0, true_env=None, seed=0):
    """Integrate J_m th'' = g tau_m(t - delay) - k (th - q) - d_m th' - f(th', th); J q'' + d q' + k_e q = k (th - q)."""
    rng = np.random.default_rng(seed)
    tb, env = design.testbed, (true_env or design.environment)
    t, cmd = _command(rng)

    def rhs(time, x):
        th, w, q, v = x
        n = int(np.floor((time - delay_s) * RATE_HZ + 1e-9))
        tau = gain * cmd[min(n, cmd.size - 1)] if n >= 0 else 0.0    # held over each period
        tau_s = tb.k * (th - q)
        dw = (tau - tau_s - tb.d_m * w - friction(w, th)) / tb.J_m
        dv = (tau_s - env.d * v - env.k_e * q) / env.J
        return [w, dw, v, dv]

    x = np.zeros(4)
    states = np.empty((t.size, 4))
    edges = np.unique(np.round(np.concatenate([t, t + delay_s, [t[-1] + 1 / RATE_HZ]]), 12))
    edges = edges[edges <= t[-1] + 1 / RATE_HZ]
    k = 0
    for a, b in zip(edges[:-1], edges[1:]):   # integrate between command switches so the hold is exact
        while k < t.size and abs(t[k] - a) < 1e-12:
            states[k] = x
            k += 1
        x = solve_ivp(rhs, (a, b), x, method="LSODA", rtol=1e-9, atol=1e-12).y[:, -1]
    quant = 2 * np.pi / COUNTS
    theta = np.round(states[:, 0] / quant) * quant
    q = np.round(states[:, 2] / quant) * quant
    return experiment_from_arrays(design, RATE_HZ, t, cmd, theta, q, description="scipy LSODA generator")


@pytest.fixture(scope="module")
def design():
    return Design.nominal("link-only")


@pytest.mark.slow
def test_effect_free_foreign_log_is_none(design):
    assert diagnose(_log(design, seed=1)).to_mapping()["verdict"]["effect"] == "none"


@pytest.mark.slow
@pytest.mark.parametrize("effect,kwargs", [
    ("coulomb", {"friction": lambda w, th: 0.3 * np.tanh(w / 1e-3)}),
    ("cogging", {"friction": lambda w, th: 0.06 * np.sin(th) + 0.04 * np.cos(2 * th)}),
    ("torque_gain", {"gain": 0.8}),
    ("delay", {"delay_s": 0.004}),
    ("position_friction", {"friction": lambda w, th: np.tanh(w / 1e-3) * (0.3 + 0.08 * np.sin(th))}),
])
def test_withheld_effect_in_foreign_log_is_named(design, effect, kwargs):
    verdict = diagnose(_log(design, seed=2, **kwargs)).to_mapping()["verdict"]
    assert verdict["effect"] == effect
    assert verdict["reduction"] >= 0.5


@pytest.mark.slow
def test_environment_mismatch_in_foreign_log_is_named(design):
    import dataclasses

    heavier = dataclasses.replace(design.environment, J_e=0.004, d_e=0.1)   # declared: the bare link
    verdict = diagnose(_log(design, true_env=heavier, seed=3)).to_mapping()["verdict"]
    assert verdict["effect"] == "environment_mismatch"
    assert verdict["reduction"] >= 0.5
