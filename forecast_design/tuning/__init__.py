"""Q-filter tuning by optimisation (casadi): the largest robust cutoff, or the best Q shape.

Both problems use the same frequency-domain facts. With the observer written
as tau_frc_hat = G_m tau_m + G_s tau_s + G_theta theta (one home:
:func:`forecast_design.symbolic.observer_filters`), G_m = Q, G_s = -Q A and
G_theta = -Q B, where A(jw) and B(jw) do not depend on the cutoff. With the
true plant P = tau_s/tau_m and P_theta = theta/tau_m, let
M = A P + B P_theta - 1. Then F_DOB = P / (1 + Q M) (eq. 4 for the DOBs) and,
with Q = 1/D_q(s/w_q),

    S = (D_q + M) / (D_q + M + C_F P D_q)          loop broken at the controller
    S = (D_q - 1) / (D_q + M + C_F P D_q)          loop broken at the motor torque input

so at any frequency the sensitivity is an explicit function of w_q whose
only non-constant part is the Q polynomial. P, P_theta, A, B and C_F are
evaluated once per environment and frequency; casadi sees real arithmetic on
their real and imaginary parts.

Modules: :mod:`.plants` (the loops a tuning evaluates and their exact checks),
:mod:`.nlp` (the casadi problem), :mod:`.tune` (``tune_q``, ``tune_q_shape``),
:mod:`.tradeoff` (the margin/rejection trade-off a user reads before choosing).
"""

from .plants import environment_set, worst_case_ratio
from .tune import TuningResult, tune_q, tune_q_shape

__all__ = ["TuningResult", "environment_set", "tune_q", "tune_q_shape", "worst_case_ratio"]
