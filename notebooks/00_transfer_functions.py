# %% [markdown]
# # Transfer functions of the SEA and the observers' nominal plants
#
# The force plant P(s) = tau_s/tau_m (paper eq. 2) is derived by solving the
# Laplace-transformed SEA equations (eq. 1) with the environment
# E(s) = J s^2 + d s + k_e; the nominal plants of the EA-FOB (eq. 5), the
# LO-DOB (eq. 6, the limit k_e -> infinity) and the LD-DOB (eq. 8, E = J_l s^2 + d_l s)
# are special cases of one expression.

# %%
import sympy as sp

from forecast_design import Design
from forecast_design.plotting.bode import plot_bode
from forecast_design.symbolic import derive_force_plant, nominal_plant, transfer_functions

P = derive_force_plant()
P.latex()

# %% [markdown]
# The EA-FOB's nominal plant is P with d_m = 0; the LO-DOB's is its limit for an
# infinitely stiff environment, which no longer depends on the environment at all:

# %%
ea, lo, ld = (nominal_plant(kind) for kind in ("ea-fob", "lo-dob", "ld-dob"))
print("P_n^LO =", lo.latex())
print("P_n^LD =", ld.latex())

# %% [markdown]
# Numbers at a design: the `tf` verb prints the same. Each denominator is monic;
# the locked plant has unit DC gain and its resonance at sqrt(k/J_m):

# %%
for name in ("soft", "stiff", "locked"):
    tfs = transfer_functions(Design.nominal(name))
    print(f"{name:6s}  P: dc gain {tfs.P.tf.dcgain():.6g}, poles {tfs.P.tf.poles().round(3)}")

# %% [markdown]
# How the environment changes the force dynamics, and how far each nominal
# plant is from the truth in the stiff environment:

# %%
stiff = transfer_functions(Design.nominal("stiff"))
soft = transfer_functions(Design.nominal("soft"))
plot_bode([("P soft", soft.P.tf), ("P stiff", stiff.P.tf), ("P_n^EA stiff", stiff.EA.tf),
           ("P_n^LO", stiff.LO.tf), ("P_n^LD", stiff.LD.tf)], "bode.png")

# %%
from IPython.display import Image  # noqa: E402

Image("bode.png")
