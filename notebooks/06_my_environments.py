# %% [markdown]
# # Your own testbed and environments, from definition to exported controller
#
# The Forecast idea is a *set of environments of interest*: the friction observer is tuned so
# that it keeps the force loop's robustness in every environment the actuator will meet. Here a
# user with their own spring (k = 40 N m/rad) describes the environments once, in a TOML file
# (format: `docs/environments.md`), and uses that same file everywhere: transfer functions,
# disk margins, Q-cutoff tuning and the C export. The command line takes the same file
# (`--envs my_envs.toml`, `--testbed k=40`).

# %%
import math

import numpy as np

import forecast_design as fd

testbed = fd.resolve_testbed("k=40")          # J_m, d_m keep the paper's Table 1 values
print(testbed)

# %% [markdown]
# ## The environment set
#
# A wall whose stiffness is known only to a decade or three (a log grid of 7 stiffnesses, d_e
# left out so that each is critically damped), and a soft object known to +-20 % around its
# nominal stiffness.

# %%
from pathlib import Path

Path("my_envs.toml").write_text("""
[[environment]]
name = "wall"
k_e = {log = [0.1, 100], n = 7}
J_e = 0.01

[[environment]]
name = "object"
k_e = {nominal = 5.0, rel = 0.2}
J_e = 0.001
d_e = 0.063
""")
envs = fd.resolve_environments("my_envs.toml", testbed=testbed)
for note in envs.notes:
    print("note:", note)
for name, env in envs:
    print(f"{name:<18} k_e = {env.k_e:8.4g} N m/rad  J_e = {env.J_e:.3g} kg m^2  d_e = {env.d_e:.4g} N m s/rad")

# %% [markdown]
# ## Transfer functions, in python-control
#
# Each result converts to python-control (`to_control()`), so the rest of a user's toolchain
# (step responses, Bode plots, `control.disk_margins`) works on it directly.

# %%
import control

designs = envs.designs(testbed)
name, design = designs[0]
P = fd.transfer_functions(design).to_control()["P"]
print(name, "P(s) poles:", np.round(control.poles(P), 3))
assert abs(control.dcgain(P) - 1.0) < 1e-9      # the spring passes the motor torque at DC

# %% [markdown]
# ## Tune the EA-FOB's cutoff for this set
#
# The largest cutoff keeping at least 90 % of the plant's own disk margin in every
# environment of the set; the answer is verified with exact margins and an independent scan.

# %%
tuned = fd.tune_q("ea-fob", envs, testbed=testbed, min_ratio=0.9, band_hz=(0.5, 30.0))
print(f"w_q = {tuned.w_q_hz:.3g} Hz, worst ratio {tuned.worst_ratio:.3f} in {tuned.worst_environment}, "
      f"agrees with scan: {tuned.agrees_with_scan}, at a bound: {tuned.at_bound}")
assert tuned.feasible and tuned.agrees_with_scan

# %% [markdown]
# An independent check with `loop_margins`, which accepts an Environment object directly.

# %%
comp = fd.Compensator(kind="ea-fob", w_q_hz=tuned.w_q_hz)
ratios = {name: fd.loop_margins(env, comp, testbed=testbed).alpha / fd.loop_margins(env, testbed=testbed).alpha
          for name, env in envs}
worst = min(ratios, key=ratios.get)
print(f"worst: {worst} {ratios[worst]:.4f}")
assert ratios[worst] >= 0.9 * (1 - 1e-6)

# %% [markdown]
# ## Export the controller
#
# The observer's nominal plant needs one environment: the exported EA-FOB is built for the one
# the actuator is about to meet (here the nominal soft object), at the cutoff tuned for the
# whole set, with the command saturated at 2 N m.

# %%
nominal_object = envs["object[k_e=5]"]
result = fd.export_controller(out_dir="my_export", controller="pd:5:0.1", compensator="ea-fob",
                              env=nominal_object, testbed=testbed, w_q_hz=tuned.w_q_hz, tau_max=2.0)
print(result.header, result.source, result.digest[:12])
assert "fd_step" in result.source.read_text()

# %% [markdown]
# The same from the command line:
#
# ```sh
# forecast-design tune-q --observer ea-fob --envs my_envs.toml --testbed k=40 --json tuned.json
# forecast-design export --compensator ea-fob --env k_e=5,J_e=0.001,d_e=0.063 --testbed k=40 \
#     --w-q-hz W_Q_HZ --tau-max 2 --out my_export
# ```
