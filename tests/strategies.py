"""Hypothesis strategies for physically valid parameters, designs and experiments.

Magnitudes are drawn log-uniformly over ranges that bracket real SEA testbeds
(the paper's Table 1 values sit inside every range), so that each decade is
visited as often as any other.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from forecast_design.controllers import PD, PID, TFController
from forecast_design.params import (
    COMPENSATOR_KINDS,
    Compensator,
    Design,
    Environment,
    Testbed,
)

__all__ = [
    "log_uniform",
    "maybe_zero",
    "testbeds",
    "environments",
    "controllers",
    "compensators",
    "designs",
    "rates_hz",
    "experiments",
]


def log_uniform(lo: float, hi: float) -> st.SearchStrategy[float]:
    """Floats with log10 uniform on [log10 lo, log10 hi]; lo, hi > 0."""
    return st.floats(math.log10(lo), math.log10(hi), allow_nan=False).map(lambda e: 10.0 ** e)


def maybe_zero(lo: float, hi: float) -> st.SearchStrategy[float]:
    """Zero (a physically allowed limit: no damping, no spring) or log-uniform."""
    return st.one_of(st.just(0.0), log_uniform(lo, hi))


def testbeds() -> st.SearchStrategy[Testbed]:
    """SEA testbeds: J_m 1e-4..1 kg m^2, d_m 0 or 1e-3..10 N m s/rad, k 1..1e4 N m/rad."""
    return st.builds(Testbed, J_m=log_uniform(1e-4, 1.0), d_m=maybe_zero(1e-3, 10.0),
                     k=log_uniform(1.0, 1e4))


@st.composite
def environments(draw, locked: bool | None = None) -> Environment:
    """Environments: J_e 0 or 1e-5..10, d_e 0 or 1e-4..100, k_e 0 or 1e-2..1e4,
    J_l 1e-5..0.1 (a link always has mass, so E(s) is never 0), d_l 0 or 1e-3..10.
    ``locked=None`` draws the flag too."""
    is_locked = draw(st.booleans()) if locked is None else locked
    return Environment(
        J_e=draw(maybe_zero(1e-5, 10.0)), d_e=draw(maybe_zero(1e-4, 100.0)),
        k_e=draw(maybe_zero(1e-2, 1e4)), J_l=draw(log_uniform(1e-5, 0.1)),
        d_l=draw(maybe_zero(1e-3, 10.0)), locked=is_locked,
    )


def controllers():
    """Controllers of the format's LTI kinds: PD (P 1e-2..1e3 [N m / N m], D 0 or 1e-4..10 [N m s / N m]),
    PID (I 0 or 1e-2..1e3 [1/s], a derivative filter), and proper tf lead/lag filters."""
    pd = st.builds(PD, P=log_uniform(1e-2, 1e3), D=maybe_zero(1e-4, 10.0))
    pid = st.builds(lambda P, I, D, T_f: PID(P=P, I=I, D=D, T_f=T_f, discretization="tustin"),
                    P=log_uniform(1e-2, 1e3), I=maybe_zero(1e-2, 1e3), D=maybe_zero(1e-4, 1.0),
                    T_f=log_uniform(1e-4, 1e-1))
    tf = st.builds(lambda k, z, p: TFController(num=(k * z, k), den=(p, 1.0)),
                   k=log_uniform(1e-1, 1e2), z=log_uniform(1e-4, 1.0), p=log_uniform(1e-4, 1.0))
    return st.one_of(pd, pid, tf)


@st.composite
def compensators(draw) -> Compensator:
    """Compensators as the experiment format can store them: the observer kinds carry
    w_q_hz (0.1..500 Hz); the others keep the default; Q family/order stay default."""
    kind = draw(st.sampled_from(COMPENSATOR_KINDS))
    if Compensator(kind=kind).is_observer:
        return Compensator(kind=kind, w_q_hz=draw(log_uniform(0.1, 500.0)))
    return Compensator(kind=kind)


@st.composite
def designs(draw, locked: bool | None = None) -> Design:
    """Designs with optional controller and compensator (open- and closed-loop runs)."""
    return Design(
        testbed=draw(testbeds()), environment=draw(environments(locked=locked)),
        controller=draw(st.none() | controllers()), compensator=draw(st.none() | compensators()),
    )


def rates_hz() -> st.SearchStrategy[float]:
    """Sampling rates 10 Hz..20 kHz."""
    return log_uniform(10.0, 2e4)


_signal_values = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def experiments(draw, max_samples: int = 40):
    """Valid experiment inputs: a dict of ``experiment_from_arrays`` keyword arguments.

    Times are ``t0 + i / rate_hz``; signal values are any float64 in [-1e3, 1e3]
    (subnormals and -0.0 included, they must survive the text round trip);
    ``q`` is zero when the drawn environment is locked.
    """
    design = draw(designs())
    rate = draw(rates_hz())
    n = draw(st.integers(1, max_samples))
    t0 = draw(st.floats(-100.0, 1e3, allow_nan=False))
    t = t0 + np.arange(n) / rate
    column = st.lists(_signal_values, min_size=n, max_size=n).map(np.array)
    q = np.zeros(n) if design.environment.locked else draw(column)
    kwargs = dict(design=design, rate_hz=rate, t=t, tau_m=draw(column), theta=draw(column), q=q,
                  tau_s=draw(st.none() | column), tau_r=draw(st.none() | column),
                  description=draw(st.text(max_size=30)))
    names = draw(st.lists(st.sampled_from(["i_a", "u_raw", "temp_C", "x y"]), unique=True, max_size=3))
    kwargs["extra"] = {name: draw(column) for name in names}
    return kwargs
