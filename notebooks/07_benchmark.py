# %% [markdown]
# # Benchmarking a force controller across an environment set
#
# The Forecast methodology (Section 2) judges a force controller over a *whole set* of
# environments: the mean, best and worst performance over the set, not one environment.
# On the affordable testbed the friction depends on the motor angle (Section 2, Fig. 2c), so
# repetitions of the same experiment differ (Fig. 3) unless a friction compensator makes them
# repeatable (Section 7, Table 3). This notebook benchmarks the paper's PD (P = 5, D = 0.1)
# with no compensation, the identified extended SFM and the EA-FOB over a set of environments
# on the virtual testbed, and reads the result table with pandas. The command-line equivalent:
#
# ```
# forecast-design benchmark --controller pd:5:0.1 --compensator none,sfm,ea-fob \
#     --envs set.toml --repetitions 10 --reference step:0.2 --out bench [--scheduler tcp://HOST:PORT]
# ```
#
# With `FORECAST_FAST=1` the set and the repetitions are smaller, and the SFM is identified on a
# shorter staircase.

# %%
import os
import tempfile
from pathlib import Path

import pandas as pd

from forecast_design.benchmark import (BenchmarkSpec, parse_compensators, parse_controller, parse_reference,
                                       result_table, run_benchmark, write_tables)
from forecast_design.environments import resolve_environments
from forecast_design.executor import make_executor
from forecast_design.plotting.benchmark import plot_heatmap, plot_indicators, plot_overlays
from forecast_design.reproduce import identify_extended_sfm

FAST = os.environ.get("FORECAST_FAST") == "1"
work = tempfile.TemporaryDirectory(prefix="benchmark-")     # removed in the last cell
out = Path(work.name)

# %% [markdown]
# ## The environment set
#
# A TOML file in the format every verb reads: here a log grid of stiffnesses on a light
# environment inertia (d_e critically damped when not given) plus the paper's locked output.

# %%
set_file = out / "set.toml"
set_file.write_text(f"""
[[environment]]
name = "grid"
J_e = 0.01
k_e = {{log = [0.1, 1000.0], n = {3 if FAST else 6}}}

[[environment]]
name = "locked"
J_e = 0.0
d_e = 0.0
k_e = 0.0
locked = true
""")
envs = resolve_environments(set_file)
print(envs.names, envs.notes)

# %% [markdown]
# ## Run it
#
# The SFM compensates the friction it was *identified* with: a staircase of motor torques on the
# free link of the same hardware, fitted with `forecast_design.friction.identify` (what
# `run_benchmark` does by itself when it is given no parameters).
#
# Each (controller, compensator, environment, reference) cell is one task of the executor:
# local processes here; `make_executor("tcp://HOST:PORT")` sends the same tasks to a Dask
# cluster with bit-for-bit the same results. Every repetition starts from its own random motor
# angle, hence its own stiction level and Stribeck curve.

# %%
spec = BenchmarkSpec(controllers=(parse_controller("pd:5:0.1"),),
                     compensators=parse_compensators("none,sfm,ea-fob"),
                     environments=tuple(envs.items()),
                     references=(parse_reference("step:0.2:1.0"),),
                     repetitions=3 if FAST else 10)
sfm_params, _, _ = identify_extended_sfm(spec.effects, seed=spec.seed, testbed=spec.testbed,
                                       hold_s=2.0 if FAST else 5.0)
print({k: round(v, 4) for k, v in sfm_params.items()})
with make_executor(workers=1 if FAST else None) as executor:
    cells, info = run_benchmark(spec, out=out, executor=executor, sfm_params=sfm_params)
print(info["computed"], "cells computed on", info["executor"])
paths = write_tables(result_table(cells), out)

# %% [markdown]
# ## Read the table with pandas
#
# One row per run (`kind == "run"`), per environment statistic and per set statistic.

# %%
df = pd.read_parquet(paths["parquet"])
per_env = df[(df.kind == "environment") & (df.statistic == "mean")]
print(per_env.pivot(index="environment", columns="compensator", values="repeatability").round(3))
print(per_env.pivot(index="environment", columns="compensator", values="mae_N_m").round(4))

# %%
over_set = df[df.kind == "set"].set_index(["compensator", "statistic"])
print(over_set[["repeatability", "mae_N_m", "rise_time_s", "overshoot_percent", "disk_margin"]].round(4))
mean = over_set.xs("mean", level="statistic")
# Section 7 over the whole set: the EA-FOB is closer to the frictionless response than PD alone
assert mean.loc["ea-fob:10", "mae_N_m"] < mean.loc["none", "mae_N_m"]

# %% [markdown]
# ## Plots: indicators against stiffness, repetition overlays (Figs. 10-12), a heat map

# %%
plot_indicators(df);

# %%
plot_overlays(cells);

# %%
plot_heatmap(df);

# %% [markdown]
# The result folder was temporary: remove it.

# %%
work.cleanup()
