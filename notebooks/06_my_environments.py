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

# %% [markdown]
# ## Your own force controller
#
# The Forecast testbed exists to benchmark *force controllers* (paper Sections 1-2). A lab
# runs its own: here a PID with a filtered derivative, C(s) = 6 + 20/s + 0.05 s/(0.002 s + 1),
# written as the experiment format writes it (`pid:6:20:0.05:0.002`, or `fd.PID(...)`, or a
# `control.TransferFunction`). The controller is one value that every step below uses: the
# margins analyse its C(s), the Q cutoff is tuned for it, the simulator and the exported C run
# its difference equation (backward Euler, the format's default for `pid`).

# %%
pid = fd.PID(P=6.0, I=20.0, D=0.05, T_f=0.002)
print(pid.label, "|", pid.spelling())
law = pid.discrete_law(2000.0)
print("C(z) =", np.round(law.feedback_tf().num, 4), "/", np.round(law.feedback_tf().den, 4))

# the same controller from python-control, and back
pid_tf = control.tf([1.0], [1.0]) * 6.0 + control.tf([20.0], [1.0, 0.0]) + control.tf([0.05, 0.0], [0.002, 1.0])
w = np.array([1.0, 10.0, 100.0])
assert np.allclose(pid.to_control()(1j * w), pid_tf(1j * w))

# %% [markdown]
# Its margins in every environment of the set, with the EA-FOB at the cutoff tuned above for
# the paper's PD; `analyse_loop` says what it assumed and gives the classical margins too.

# %%
for name, env in list(envs)[:3]:
    a = fd.analyse_loop(env, fd.Compensator(kind="ea-fob", w_q_hz=tuned.w_q_hz), testbed=testbed, controller=pid,
                        environment_name=name)
    cm = a.classical
    print(f"{name:<18} disk margin {a.disk.alpha:.3f}, phase margin "
          f"{cm.phase_margin.phase_margin_deg if cm.phase_margin else float('nan'):.1f} deg")

# %% [markdown]
# The cutoff for *this* controller: the tuner closes the same loop with the PID.

# %%
tuned_pid = fd.tune_q("ea-fob", envs, testbed=testbed, min_ratio=0.9, band_hz=(0.5, 60.0), controller=pid)
print(f"PID: w_q = {tuned_pid.w_q_hz:.3g} Hz (the paper's PD: {tuned.w_q_hz:.3g} Hz), "
      f"worst ratio {tuned_pid.worst_ratio:.3f}")
assert tuned_pid.worst_ratio >= 0.9 * (1 - 1e-6)

# %% [markdown]
# Simulated on the virtual testbed against the soft object, the log's TOML says exactly what
# ran (the controller table with its discretisation, the compensator with its cutoff).

# %%
from forecast_design.simulation import Step, simulate

comp_pid = fd.Compensator(kind="ea-fob", w_q_hz=tuned_pid.w_q_hz)
run = simulate(fd.Design(testbed=testbed, environment=nominal_object, controller=pid, compensator=comp_pid),
               reference=Step(amplitude=0.2), duration_s=1.0)
print(run.to_experiment().design.controller.to_mapping())
print(f"tau_s after 1 s: {run.tau_s[-1]:.4f} N m (reference 0.2; the integrator removes the static error)")
assert abs(run.tau_s[-1] - 0.2) < 0.01

# %% [markdown]
# Benchmarked against the paper's PD over two environments of the set, 5 repetitions each:

# %%
import tempfile

from forecast_design.benchmark import BenchmarkSpec, parse_compensators, parse_reference, result_table, run_benchmark

bench_envs = tuple(list(envs.items())[:2])
spec = BenchmarkSpec(controllers=(fd.PAPER_PD, pid), compensators=parse_compensators("none,ea-fob:10"),
                     environments=bench_envs, references=(parse_reference("step:0.2:0.6"),), repetitions=5,
                     testbed=testbed)
with tempfile.TemporaryDirectory(prefix="pid-bench-") as folder:    # the cells' store, removed afterwards
    cells, info = run_benchmark(spec, out=folder)
table = result_table(cells)
print(table.groupby(["controller", "compensator"])[["repeatability", "mae_N_m", "disk_margin"]].mean())

# %% [markdown]
# And exported: the C runs the PID's difference equation (its integrator kept apart for the
# anti-windup when saturation is given) with the EA-FOB at the PID's cutoff.

# %%
result_pid = fd.export_controller(out_dir="my_export_pid", controller=pid, compensator="ea-fob",
                                  env=nominal_object, testbed=testbed, w_q_hz=tuned_pid.w_q_hz, tau_max=2.0)
print(result_pid.to_mapping()["controller"], result_pid.digest[:12])
assert result_pid.program.integrator is not None

# %% [markdown]
# From the command line, every verb spells the controller the same way:
#
# ```sh
# forecast-design margins --env k_e=5,J_e=0.001,d_e=0.063 --testbed k=40 --compensator ea-fob \
#     --controller pid:6:20:0.05:0.002 --plot pid_margins.png
# forecast-design tune-q --observer ea-fob --envs my_envs.toml --testbed k=40 --controller pid:6:20:0.05:0.002
# forecast-design benchmark --controller pd:5:0.1 --controller pid:6:20:0.05:0.002 --envs my_envs.toml \
#     --testbed k=40 --repetitions 5 --out bench
# forecast-design export --firmware --controller pid:6:20:0.05:0.002 --compensator ea-fob --out fw
# ```
