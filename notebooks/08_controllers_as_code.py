# %% [markdown]
# # Your own force controller, written as code
#
# Many force controllers a lab wants to benchmark are not linear filters: limits and
# anti-windup, gain schedules, switching, energy tanks, learned laws. Written as code, such a
# controller runs where the linear kinds (`pd`, `pid`, `tf`, `discrete`) run: the simulator
# calls it once per 2 kHz control period with the friction compensator, the delays, the
# saturation and the plant unchanged around it; the benchmark takes it like any controller;
# written in C, it also runs compiled on the host (software in the loop) and on the board's
# firmware (processor in the loop on qemu). The interfaces are in `docs/controllers-as-code.md`.
#
# This notebook walks through one controller from the first line to the board:
#
# 1. write it in Python (a class with `reset` and `step`, and a `transfer_function()` linearisation),
# 2. test it against its own equations,
# 3. simulate it on the virtual testbed,
# 4. benchmark it over an environment set against the paper's PD,
# 5. write it again in C and check both versions agree (software in the loop),
# 6. read its margins through its linearisation,
# 7. build it into the firmware and run it on an emulated Cortex-M4.
#
# The command-line equivalent of step 4:
#
# ```
# forecast-design benchmark --controller pd:5:0.1 --controller pid_aw.py:PIDAntiWindup \
#     --controller pid_aw.c --compensator none,ea-fob --envs exp-soft,soft,stiff,locked \
#     --repetitions 5 --reference step:0.2 --out bench
# ```
#
# With `FORECAST_FAST=1` the runs are shorter and the sets smaller.

# %%
import os
import tempfile
import textwrap
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from scipy.signal import lfilter

from forecast_design import Compensator, Design, parse_controller, simulate
from forecast_design.reproduce import TABLE3_TRUTH
from forecast_design.simulation.code import code_runner
from forecast_design.simulation.references import Step

FAST = os.environ.get("FORECAST_FAST") == "1"
scratch = tempfile.TemporaryDirectory(prefix="controllers-as-code-")    # removed in the last cell
work = Path(scratch.name)
RATE_HZ = 2000.0   # the board's control rate [Hz]

# %% [markdown]
# ## 1. Write the controller in Python
#
# Any class with two methods (instantiated with no arguments):
#
# - `reset(self, rate_hz, testbed, environment)`: called before each run, with the control
#   rate [Hz] and the nominal testbed and environment (a controller may read them, or not);
#   it puts the state at rest.
# - `step(self, t, tau_r, tau_s, theta, q) -> u`: called once per control period with the time
#   [s], the force reference and the measured spring torque [N m], and the motor and output
#   encoder angles [rad]; it returns the controller output u [N m]. The compensator's estimate is
#   added to u afterwards and the sum is saturated, as for the built-in controllers.
#
# Optionally `transfer_function()` returns a linearisation C(s) (a python-control
# `TransferFunction`, with u = C(s) (tau_r - tau_s)), which the margins and the Q-filter
# tuning use and say so.
#
# Our controller: a PID whose derivative acts on the measurement (a step of the reference
# gives no derivative kick) through a first-order filter, with its output limited and a
# back-calculation anti-windup (the integrator is pulled back at the rate (u - v)/T_T while
# the output v sits beyond its limit).

# %%
PY_SOURCE = textwrap.dedent('''
    """A PID force controller: derivative on the measurement, limited output, back-calculation anti-windup.

    e = tau_r - tau_s;  d = -D s/(T_F s + 1) tau_s (backward Euler);  v = P e + x + d;
    u = clip(v, -U_MAX, U_MAX);  x <- x + T (I e + (u - v)/T_T)   (T = 1/rate) [N m]
    """


    class PIDAntiWindup:
        P = 5.0        # proportional gain [N m/N m]
        I = 30.0       # integral gain [1/s]
        D = 0.1        # derivative gain [s]
        T_F = 0.001    # derivative filter time constant [s]
        T_T = 0.02     # anti-windup tracking time constant [s]
        U_MAX = 2.0    # output limit [N m]

        def reset(self, rate_hz, testbed, environment):
            self.dt = 1.0 / rate_hz
            self.x = 0.0             # integrator [N m]
            self.d = 0.0             # filtered derivative term [N m]
            self.tau_s_prev = 0.0    # last measured spring torque [N m]

        def step(self, t, tau_r, tau_s, theta, q):
            e = tau_r - tau_s
            self.d = (self.T_F * self.d - self.D * (tau_s - self.tau_s_prev)) / (self.T_F + self.dt)
            self.tau_s_prev = tau_s
            v = self.P * e + self.x + self.d
            u = min(max(v, -self.U_MAX), self.U_MAX)
            self.x += self.dt * (self.I * e + (u - v) / self.T_T)
            return u

        def transfer_function(self):
            """Linearisation without the limit: C(s) = P + I/s + D s/(T_F s + 1)."""
            import control

            s = control.tf("s")
            return self.P + self.I / s + self.D * s / (self.T_F * s + 1)
''')
py_file = work / "pid_aw.py"
py_file.write_text(PY_SOURCE)

mine = parse_controller(f"{py_file}:PIDAntiWindup")   # the command line's spelling: FILE.py:Class
print(mine.label, "|", mine.model)

# %% [markdown]
# ## 2. Test it against its equations
#
# A controller written as code is a program, so test it like one, before any simulation.
# `code_runner` loads it exactly as the simulator does. Two facts:
#
# - **Linear regime.** Below its limit, with tau_r = 0 (so e = -tau_s and the derivative on the
#   measurement is the derivative on the error), the law is the difference equation
#   u = P e + I T z^-1/(1 - z^-1) e + D (1 - z^-1)/(T_F + T - T_F z^-1) e. scipy's `lfilter`
#   computes it independently from the same coefficients, on a random input.
# - **Anti-windup.** With a constant error large enough to hold the output on its limit, the
#   integrator settles where x' = 0: v = U_MAX + T_T I e, so x = U_MAX + (T_T I - P) e (d = 0
#   for a constant tau_s), instead of growing without bound.

# %%
from forecast_design.controllers import load_python_class

C = load_python_class(mine)            # the class itself, for its constants
T = 1.0 / RATE_HZ
rng = np.random.default_rng(1)
e = 0.005 * rng.standard_normal(4000 if FAST else 20_000)     # small: the limit is never reached [N m]

runner = code_runner(mine)
runner.reset(RATE_HZ, None, None)
u = np.array([runner.step(k * T, 0.0, -ek, 0.0, 0.0) for k, ek in enumerate(e)])
expected = (C.P * e + lfilter([0.0, C.I * T], [1.0, -1.0], e)
            + lfilter([C.D, -C.D], [C.T_F + T, -C.T_F], e))
print(f"max |u| = {np.max(np.abs(u)):.3f} N m (limit {C.U_MAX}); "
      f"max |u - lfilter| = {np.max(np.abs(u - expected)):.1e} N m")
assert np.max(np.abs(u)) < C.U_MAX
np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)

e_big = 0.5                                                      # [N m]
ctl = C()                                                        # the class directly, to read its state
ctl.reset(RATE_HZ, None, None)
u_sat = [ctl.step(k * T, e_big, 0.0, 0.0, 0.0) for k in range(4000)]      # 2 s on the limit
x_expected = C.U_MAX + (C.T_T * C.I - C.P) * e_big
print(f"output {u_sat[-1]:.3f} N m; integrator {ctl.x:.6f} N m, back-calculation's fixed point {x_expected:.6f} N m")
assert u_sat[-1] == C.U_MAX and abs(ctl.x - x_expected) < 1e-9

# %% [markdown]
# ## 3. Simulate it on the virtual testbed
#
# The `exp-soft` environment with the Table 3 hardware (angle-dependent stiction and Stribeck
# curve, cogging: `TABLE3_TRUTH`), a 0.2 N m step, no friction compensation: the paper's PD
# against ours. The PD leaves the motor stuck short of the reference (stiction holds it once
# P e falls below the breakaway torque); the integrator pushes through. The derivative on the
# measurement also spares the motor the PD's derivative kick at the step (D/T x 0.2 N m = 40 N m
# for one period).

# %%
duration = 0.6 if FAST else 1.5
runs = {}
for name, controller in (("paper PD (pd:5:0.1)", parse_controller("pd:5:0.1")), ("PIDAntiWindup", mine)):
    design = Design.nominal("exp-soft", controller=controller)
    runs[name] = simulate(design, reference=Step(amplitude=0.2, t0=0.05), duration_s=duration,
                          effects=TABLE3_TRUTH, seed=1, initial_angle=0.4)
    r = runs[name]
    assert r.fault is None, r.fault
    err = np.mean(np.abs(r.tau_r - r.tau_s)[r.t > duration - 0.2])
    print(f"{name:>20}: mean |tau_r - tau_s| over the last 0.2 s = {err:.4f} N m; max |u| = {np.max(np.abs(r.u)):.2f} N m")

final = {name: np.mean(np.abs(r.tau_r - r.tau_s)[r.t > duration - 0.2]) for name, r in runs.items()}
assert final["PIDAntiWindup"] < 0.5 * final["paper PD (pd:5:0.1)"]

# %%
fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(8, 5.5))
top.plot(runs["PIDAntiWindup"].t, runs["PIDAntiWindup"].tau_r, color="0.6", lw=2, label=r"$\tau_r$")
for (name, r), colour in zip(runs.items(), ("tab:orange", "tab:blue")):
    top.plot(r.t, r.tau_s, color=colour, lw=1.1, label=rf"$\tau_s$, {name}")
    bottom.plot(r.t, r.u, color=colour, lw=1.1, label=name)
top.set_ylabel("spring torque [N m]")
top.set_title("0.2 N m step, exp-soft, Table 3 friction, no compensator")
top.legend(loc="center right", fontsize=8)
bottom.set_ylim(-0.5, 2.5)
bottom.annotate("PD's derivative kick: 40 N m, off the scale", xy=(0.05, 2.4), xytext=(0.12, 1.6),
                fontsize=8, arrowprops={"arrowstyle": "->", "color": "tab:orange"}, color="tab:orange")
bottom.axhline(C.U_MAX, color="tab:blue", ls=":", lw=1)
bottom.text(duration, C.U_MAX, "U_MAX ", ha="right", va="bottom", fontsize=8, color="tab:blue")
bottom.set_ylabel("controller output u [N m]")
bottom.set_xlabel("t [s]")
for ax in (top, bottom):
    ax.grid(True, alpha=0.3)
fig.tight_layout()
fig.savefig(work / "step.png", dpi=110)

# %% [markdown]
# ## 4. Benchmark it against the paper's PD
#
# The benchmark runs every (controller, compensator, environment) cell `repetitions` times,
# each from its own random motor angle (its own stiction level), and reports the indicators
# per environment and over the set (see `07_benchmark.py`). A code controller is one more entry
# in `controllers`; the result folder caches cells by their inputs, including the code's
# content, so an edited controller is run again and an unchanged one is not.

# %%
import pandas as pd

from forecast_design.benchmark import (BenchmarkSpec, parse_compensators, parse_reference, result_table,
                                       run_benchmark, write_tables)
from forecast_design.environments import resolve_environments
from forecast_design.executor import make_executor

bench = work / "bench"
envs = resolve_environments("exp-soft,locked" if FAST else "exp-soft,soft,stiff,locked")


def benchmark(controllers):
    """Run the benchmark for these controllers in the result folder `bench`; return the set-level table."""
    spec = BenchmarkSpec(controllers=tuple(controllers), compensators=parse_compensators("none,ea-fob"),
                         environments=tuple(envs.items()),
                         references=(parse_reference("step:0.2", duration_s=0.5 if FAST else 1.0),),
                         repetitions=2 if FAST else 5)
    with make_executor(workers=1 if FAST else None) as executor:
        cells, info = run_benchmark(spec, out=bench, executor=executor)
    print(info["computed"], "cells computed on", info["executor"])
    df = pd.read_parquet(write_tables(result_table(cells), bench)["parquet"])
    return df


df = benchmark([parse_controller("pd:5:0.1"), mine])
over_set = df[(df.kind == "set") & (df.statistic == "mean")].set_index(["controller", "compensator"])
print(over_set[["repeatability", "mae_N_m", "rise_time_s", "overshoot_percent", "disk_margin"]].round(4).to_string())

# %%
pd_row, mine_row = over_set.loc[("pd:5:0.1", "none")], over_set.loc[(mine.label, "none")]
# without compensation the integrator overcomes the stiction the PD stops at: a smaller tracking error
assert mine_row["mae_N_m"] < pd_row["mae_N_m"]
# the margin of a code controller is that of its linearisation (and said so in the report)
assert np.isfinite(mine_row["disk_margin"])

# %% [markdown]
# ## 5. The same controller in C, in software in the loop
#
# On the board a controller is C. The interface is two functions in one `.c` file, with the
# state in static variables, no heap and nothing of libc beyond `math.h` (it runs in the 2 kHz
# interrupt):
#
# ```c
# void  fd_user_init(float rate_hz);                                    /* before each run */
# float fd_user_step(float tau_r, float tau_s, float theta, float q);   /* u [N m], each period */
# ```
#
# For software in the loop the toolbox compiles the file with the host compiler into a shared
# library and calls it each period in float32, as the board does (the compensator around it
# too). Here the C is a line-by-line translation of the Python; driven with the same inputs,
# the two differ by float32 rounding only.

# %%
C_SOURCE = textwrap.dedent('''
    /* pid_aw.py's PIDAntiWindup in C (float32): the same law, line by line. */
    #include <math.h>

    #define P 5.0f          /* proportional gain [N m/N m] */
    #define I_GAIN 30.0f    /* integral gain [1/s] */
    #define D 0.1f          /* derivative gain [s] */
    #define T_F 0.001f      /* derivative filter time constant [s] */
    #define T_T 0.02f       /* anti-windup tracking time constant [s] */
    #define U_MAX 2.0f      /* output limit [N m] */

    static float dt, x, d, tau_s_prev;

    void fd_user_init(float rate_hz)
    {
        dt = 1.0f / rate_hz;
        x = 0.0f;
        d = 0.0f;
        tau_s_prev = 0.0f;
    }

    float fd_user_step(float tau_r, float tau_s, float theta, float q)
    {
        const float e = tau_r - tau_s;
        float v, u;
        (void)theta;
        (void)q;
        d = (T_F * d - D * (tau_s - tau_s_prev)) / (T_F + dt);
        tau_s_prev = tau_s;
        v = P * e + x + d;
        u = fminf(fmaxf(v, -U_MAX), U_MAX);
        x += dt * (I_GAIN * e + (u - v) / T_T);
        return u;
    }
''')
c_file = work / "pid_aw.c"
c_file.write_text(C_SOURCE)
mine_c = parse_controller(str(c_file))                 # the command line's spelling: FILE.c
print(mine_c.label, "|", mine_c.model)

# %%
from forecast_design.export import toolchain

# closed-loop-like inputs (a square reference, a first-order tau_s with noise, slow angles):
# columns tau_r, tau_s, theta, q
inputs = toolchain.test_sequence(4000 if FAST else 20_000, with_q=True).astype(float)
outputs = {}
for name, controller in (("Python", mine), ("C", mine_c)):
    r = code_runner(controller)          # the C file is compiled here (the host compiler, once per content)
    r.reset(RATE_HZ, None, None)
    outputs[name] = np.array([r.step(k * T, *row) for k, row in enumerate(inputs)])
diff = np.abs(outputs["C"] - outputs["Python"])
rel = np.max(diff) / np.max(np.abs(outputs["Python"]))
print(f"max |u| = {np.max(np.abs(outputs['Python'])):.3f} N m; on the limit in "
      f"{np.count_nonzero(np.abs(outputs['Python']) == C.U_MAX)} of {len(inputs)} periods")
print(f"max |C - Python| = {np.max(diff):.2e} N m, relative to max |u|: {rel:.1e} (float32 epsilon 6e-8)")
assert np.any(np.abs(outputs["Python"]) == C.U_MAX)     # the limit and the anti-windup were exercised
assert rel < 1e-5 and not np.array_equal(outputs["C"], outputs["Python"])   # float32 apart, and the C ran

# %% [markdown]
# In the benchmark the C file is one more controller. The cells of the PD and of the Python
# version are read back from the result folder; only the C's are run, and its indicators
# match the Python version's to float32 rounding of the loop.

# %%
df = benchmark([parse_controller("pd:5:0.1"), mine, mine_c])
over_set = df[(df.kind == "set") & (df.statistic == "mean")].set_index(["controller", "compensator"])
print(over_set[["repeatability", "mae_N_m", "rise_time_s", "disk_margin"]].round(4).to_string())
for comp in ("none", "ea-fob:10"):
    a, b = over_set.loc[(mine.label, comp), "mae_N_m"], over_set.loc[(mine_c.label, comp), "mae_N_m"]
    print(f"{comp}: MAE Python {a:.5f}, C {b:.5f} N m")
    assert abs(a - b) <= 2e-3 * a
assert np.isnan(over_set.loc[(mine_c.label, "none"), "disk_margin"])     # C has no linear model: no margin

# %% [markdown]
# ## 6. Margins through the linearisation
#
# The disk margin needs a linear model. For a Python controller the toolbox takes its
# `transfer_function()` and says so in the result's notes (the limit and the anti-windup are
# not in it); the same C(s) given as a python-control transfer function gives the same margin.
# A C file has no equations: the analysis refuses in one line.

# %%
import control

from forecast_design import analyse_loop
from forecast_design.errors import ParameterError

design = Design.nominal("exp-soft")
a = analyse_loop(design, "ea-fob", controller=mine)
s = control.tf("s")
b = analyse_loop(design, "ea-fob", controller=C.P + C.I / s + C.D * s / (C.T_F * s + 1))
print(*a.notes, sep="\n")
print(f"disk margin alpha = {a.disk.alpha:.4f} ({a.disk.gain_margin_db[1]:.1f} dB, "
      f"{a.disk.phase_margin_deg:.1f} deg); the same C(s) as a transfer function: {b.disk.alpha:.4f}")
assert any("linearisation" in n for n in a.notes) and a.disk.stable
assert abs(a.disk.alpha - b.disk.alpha) <= 1e-9 * b.disk.alpha
try:
    analyse_loop(design, "ea-fob", controller=mine_c)
    raise AssertionError("a C controller has no linear model")
except ParameterError as exc:
    print("C:", exc)
    assert "no linear model" in str(exc)

# %% [markdown]
# ## 7. On the board
#
# ```
# forecast-design export --firmware --controller pid_aw.c --compensator ea-fob --env exp-soft --out fw
# forecast-design pil --controller pid_aw.c --compensator ea-fob --env exp-soft \
#     --reference square:0.2:0.125 --duration 0.5 --out pil.toml
# ```
#
# `export --firmware` links the file into the Nucleo F446RE firmware as `fd_user.c` in place of
# the generated controller, with the same interrupt, protocol, torque limit, watchdog and
# fault handling (a NaN from the code is fault 7, CONTROLLER, torque off). First it measures
# the compiled step on an emulated Cortex-M4 against the 84,000 cycles of a 2 kHz period at
# 168 MHz: over them it refuses, over half of them it warns. `pil` builds the same firmware for
# qemu and closes the loop with the virtual testbed over the board's protocol.
#
# Below, with the ARM toolchain and qemu installed, the same steps in Python: the firmware
# export with its cycle check, then a PIL run, compared with the software-in-the-loop run of
# the same firmware program on the same float32 measurements. They are bit-identical.

# %%
from forecast_design.export.firmware import export_firmware
from forecast_design.runtime.pil import python_closed_loop, qemu_available, run_pil

why = qemu_available()
if why:
    print("skipping the firmware and PIL steps:", why)
else:
    fw = export_firmware(out_dir=work / "fw", controller=mine_c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0)
    cyc = fw.cycles
    print(f"firmware in {fw.out_dir.name}/ with {', '.join(n for n in fw.files if n.startswith('fd_user'))}; "
          f"longest step <= {cyc['max_cycles_per_step_bound']:.0f} cycles of {cyc['budget_cycles_per_period']:.0f} "
          f"({cyc['max_budget_fraction']:.1%}): {cyc['verdict']}")
    assert cyc["verdict"] == "ok" and cyc["max_abs_diff_vs_host"] == 0.0

    square = "square:0.2:0.125"         # +-0.2 N m, 0.125 s period
    res = run_pil(controller=mine_c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0, reference=square,
                  duration=0.1 if FAST else 0.5, out=work / "pil.toml", work_dir=work / "pil-fw")
    sil = python_closed_loop(fw.program, fw.design, square, res.samples)
    print(f"PIL: {res.samples} periods, fault {res.fault}, "
          f"{res.to_mapping()['max_instructions_per_step']:.0f} instructions in the longest period")
    assert res.fault is None and res.samples == res.expected
    for name in ("tau_m", "tau_s", "u", "tau_frc_hat"):
        assert np.array_equal(res.arrays[name], sil[name]), name
    print("SIL = PIL bit for bit on tau_m, tau_s, u and tau_frc_hat")

# %% [markdown]
# The files of this notebook were written to a temporary folder: remove it.

# %%
scratch.cleanup()
