"""The generated numeric catalogue equals a fresh generation from the sympy derivations."""

import numpy as np
import pytest
from hypothesis import given, settings

from forecast_design.symbolic import codegen, numeric
from forecast_design.symbolic.bridge import (
    derive_force_plant,
    derive_locked_force_plant,
    derive_motor_angle_plant,
    nominal_plant,
)

import strategies


def test_catalogue_file_is_up_to_date():
    assert codegen.CATALOGUE_PATH.read_text() == codegen.generate_source(), (
        "regenerate with: python -m forecast_design.symbolic.codegen")


@settings(max_examples=40, deadline=None)
@given(design=strategies.designs())
def test_catalogue_evaluation_equals_sympy_bridge(design):
    pairs = [
        (numeric.force_plant_tf(design),
         (derive_locked_force_plant() if design.environment.locked else derive_force_plant()).at(design)),
        (numeric.motor_angle_tf(design), derive_motor_angle_plant(design.environment.locked).at(design)),
        (numeric.nominal_plant_tf("lo-dob", design), nominal_plant("lo-dob").at(design)),
        (numeric.nominal_plant_tf("ld-dob", design), nominal_plant("ld-dob").at(design)),
    ]
    if not design.environment.locked:
        pairs.append((numeric.nominal_plant_tf("ea-fob", design), nominal_plant("ea-fob").at(design)))
    for fast, slow in pairs:
        np.testing.assert_allclose(fast.num, slow.num, rtol=1e-12, atol=0)
        np.testing.assert_allclose(fast.den, slow.den, rtol=1e-12, atol=0)


def test_commands_do_not_import_sympy():
    import subprocess
    import sys

    code = ("import sys; from forecast_design.analysis import fig6_table; fig6_table(); "
            "from forecast_design.symbolic import transfer_functions; from forecast_design import Design; "
            "transfer_functions(Design.nominal('stiff')); print('sympy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_q_filter_beyond_the_catalogue_falls_back_to_sympy():
    from forecast_design.symbolic import q_filter_tf

    q = q_filter_tf("binomial", 8, 1.0 / (2 * np.pi))
    np.testing.assert_allclose(q.den, np.poly(-np.ones(8)), rtol=1e-12)
    with pytest.raises(Exception, match="family"):
        q_filter_tf("chebyshev", 2, 10.0)


@settings(max_examples=30, deadline=None)
@given(design=strategies.designs())
def test_state_space_reproduces_the_transfer_functions(design):
    """C (sI - A)^-1 B of the derived state space equals P(s) and theta/tau_m at test frequencies."""
    if not design.environment.locked and design.environment.J == 0.0:
        return      # first-order output: no inertial state-space form (J q'' term absent)
    A, B = numeric.sea_state_space(design)
    n = A.shape[0]
    c_theta = np.eye(n)[0]
    c_spring = design.testbed.k * (np.eye(n)[0] - (0 if design.environment.locked else np.eye(n)[2]))
    for w in (0.3, 7.0, 55.0):
        s = 1j * w
        x = np.linalg.solve(s * np.eye(n) - A, B[:, 0])
        np.testing.assert_allclose(c_spring @ x, numeric.force_plant_tf(design)(s), rtol=1e-6)  # conditioning at extreme draws
        np.testing.assert_allclose(c_theta @ x, numeric.motor_angle_tf(design)(s), rtol=1e-6)
