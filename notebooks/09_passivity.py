# %% [markdown]
# # The EA-FOB with an imprecise environment: stable with every passive environment?
#
# The EA-FOB needs a model E0 of the environment (paper, section 8: its limit where "knowledge of the
# environment is usually missing or extremely imprecise"). Seen from the environment, the
# force-controlled SEA is a one-port with impedance Z(s); by Colgate and Hogan's theorem it is stable
# with *every* passive environment exactly when Z is positive real (docs/passivity.md).
# `analyse_passivity` answers that exactly (roots of polynomials, no grid) for the environment the
# observer believes in.

# %%
import math

import numpy as np

import forecast_design as fd

for believed in ("soft", "stiff"):
    for w_q in (1.0, 5.0, 10.0):
        r = fd.analyse_passivity(believed, fd.Compensator(kind="ea-fob", w_q_hz=w_q))
        print(f"EA-FOB believing {believed:5s} at {w_q:4.1f} Hz: passive {r.passive!s:5s} "
              f"min Re Z {r.min_re_z:+.4f} N m s/rad, bands {[tuple(round(x, 1) for x in b) for b in r.bands_rad_s]}")

# %% [markdown]
# Designed for the stiff environment, the EA-FOB is passive at every cutoff: whatever passive true
# environment is attached, the loop stays stable. Designed for the soft one at 10 Hz it is not: Re Z
# is negative between about 57 and 84 rad/s and even the locked loop is unstable. Which true
# environments does it tolerate? The stiffness and inertia ranges are exact root-locus intervals.

# %%
r = fd.analyse_passivity("soft", fd.Compensator(kind="ea-fob", w_q_hz=10.0))
print("k_e range at the soft J_e, d_e:", r.stiffness_range, "N m/rad")
print("J_e range at the soft d_e, k_e:", r.inertia_range, "kg m^2")
print("a passive environment that destabilises it:", r.destabilising_environment)
print("passivity index interval (our construction):", r.index_interval["interval_n_m_s_per_rad"], "N m s/rad")

# %% [markdown]
# Check against the force loop the margins use: a true environment just inside the stiffness range is
# stable, one just outside is not (the observer keeps believing the soft environment).

# %%
from forecast_design.loops import force_loop

believed = r.design
hi = r.stiffness_range[1]
for k_e in (0.99 * hi, 1.01 * hi):
    env = fd.Environment(J_e=believed.environment.J_e, d_e=believed.environment.d_e, k_e=k_e)
    true = fd.Design(testbed=believed.testbed, environment=env)
    loop = force_loop(true, fd.Compensator(kind="ea-fob", w_q_hz=10.0), believed=believed)
    print(f"true k_e = {k_e:8.3f} N m/rad: stable {loop.stable}, largest pole real part {loop.max_real_pole:+.3f} rad/s")

# %% [markdown]
# Re Z over frequency, with the band where the port generates energy shaded.

# %%
from forecast_design.plotting.passivity import plot_passivity

plot_passivity(r, "passivity_ea_fob_soft_10hz.png")
c = r.curve()
print(f"Re Z sampled on {c.w_rad_s.size} points for the plot; its least sample {c.re_z.min():.4f} >= "
      f"the exact minimum {r.min_re_z:.4f}: {c.re_z.min() >= r.min_re_z - 1e-9}")
