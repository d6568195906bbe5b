# %% [markdown]
# # The virtual testbed: the paper's Fig. 7 and Table 3 in simulation
#
# The simulator (`forecast_design.simulation`) integrates the SEA and its environment with
# fixed-step RK4 (10 substeps per 0.5 ms control period), LuGre friction and the other
# unmodelled effects, and runs the PD force controller and the compensators at 2 kHz with
# the very filters the C export emits. This notebook walks through the two reproductions
# (`forecast-design reproduce fig7`, `forecast-design reproduce table3`) and says where and
# why they deviate from the paper. With `FORECAST_FAST=1` the runs are shortened.

# %%
import json
import os

import numpy as np

from forecast_design.plotting.simulation import plot_fig7, plot_table3
from forecast_design.reproduce import reproduce_fig7, reproduce_table3

FAST = os.environ.get("FORECAST_FAST") == "1"

# %% [markdown]
# ## Fig. 7: SFM vs EA-FOB friction estimate under LuGre friction (Section 6)
#
# LuGre with Table 2's parameters in the true plant, PD P = 5, D = 0.1, a +-1 N m square
# wave; the SFM feeds forward `d_m theta' + d_c sign(theta')`, the EA-FOB
# `Q (tau_m - P_n^-1 tau_s)` with a 10 Hz Q. The paper reports a friction-estimate MAE of
# 0.35 N m (SFM) and 0.02 N m (EA-FOB). It leaves open the environment, the square-wave
# period, whether d_m is in the true plant, the Q family, the derivative filter and the SFM's
# parameters; the defaults and the reasons are in `forecast_design.reproduce`, and the
# sensitivity table varies each one.

# %%
fig7 = reproduce_fig7(sensitivity=not FAST, **({"periods": 1} if FAST else {}))
summary = {k: round(v, 4) for k, v in fig7.to_mapping().items() if isinstance(v, float)}
print(json.dumps(summary, indent=1))
print(f"EA-FOB estimate vs Q-filtered true friction: {fig7.mae_friction_eafob_vs_q:.4f} N m")
plot_fig7(fig7, "fig7.png");

# %% [markdown]
# The EA-FOB's estimate *is* the Q-filtered friction (a few mN m apart): its error against the
# true friction is the 10 Hz filter's lag during the fast friction transients after each
# reference edge, so it shrinks with longer holds. The SFM fails differently: when the motor
# should stick, its `sign(theta')` feed-forward starts a stick-slip limit cycle (the ripple on
# tau_s), and its estimate swings by 2 d_c while the true friction stays small.
#
# The sensitivity table (one choice varied at a time):

# %%
cols = ("vary", "environment", "period_s", "torque_limit", "mae_friction_sfm", "mae_friction_eafob",
        "mae_tracking_sfm", "mae_tracking_eafob")
for row in fig7.to_mapping()["sensitivity"]:
    print("  ".join(f"{row[c]:.3f}" if isinstance(row[c], float) else f"{str(row[c]):>12}" for c in cols))

# %% [markdown]
# **Deviation.** With the environment the PD was tuned on (J_e = 1 kg m^2, preset `fig7`) and
# 1 s holds, the ordering reverses: the SFM only falls into its limit cycle after a while at
# that inertia. With Section 5's stiff environment (J_e = 0.1) the SFM cycles in every hold,
# and the numbers (about 0.29 vs 0.018 N m) sit near the paper's pair. The full explanation
# travels with the JSON:

# %%
print(fig7.explanation)

# %% [markdown]
# ## Table 3: repeatability and fidelity of ten step responses (Section 7)
#
# The hardware now has the angle-dependent friction of Section 2: LuGre with a static level
# varying with the motor angle (0.5 +- 0.1 N m), an angle-periodic Coulomb ripple and a small
# cogging torque. Each of the ten 0.2 N m steps starts from its own random motor angle. The
# extended SFM is identified (least squares, viscous + Coulomb + 4 harmonics) from a simulated
# open-loop identification run of the same hardware. `xcorr` is the mean pairwise zero-lag
# Pearson correlation of the responses; `mae` the mean absolute error to the frictionless PD
# response (no friction at all, d_m = 0).

# %%
table3 = reproduce_table3(**({"repetitions": 4, "duration_s": 0.5, "sensitivity": ()} if FAST else {}))
print(f"identified extended SFM: {json.dumps({k: round(v, 4) for k, v in table3.sfm_params.items()})}")
print(f"{'environment':<10} {'compensator':<8} {'xcorr':>6} {'paper':>6} {'MAE':>8} {'paper':>6}")
for r in table3:
    print(f"{r.environment:<10} {r.compensator:<8} {r.xcorr:6.3f} {r.paper_xcorr:6.2f} {r.mae:8.4f} {r.paper_mae:6.3f}")
plot_table3(table3, "table3.png");

# %% [markdown]
# **Pattern and deviations.** As in the paper, PD alone is the least repeatable cell in both
# environments and the EA-FOB is the closest to the frictionless response. PD alone varies because
# at some start angles the static level comes close to its 1 N m command for the 0.2 N m step, so
# the motor hardly breaks away, while elsewhere it breaks away and sticks (the reproduction's board
# takes the PD's derivative on the measured torque; with the derivative on the error the kick
# throws the motor past any static level and PD alone becomes repeatable with the output locked,
# `reproduce_table3(derivative_on="error")`). PD alone's MAE stays above the paper's: the
# simulated static level, read from Fig. 2c, holds the motor further from the frictionless
# response. The SFM's sign() has a 0.01 rad/s dead band; with the paper's plain `sign(theta')`
# its feed-forward drives a stick-slip limit cycle once the motor stops (sensitivity rows):

# %%
for r in table3.sensitivity:
    print(r)
print(table3.explanation)
