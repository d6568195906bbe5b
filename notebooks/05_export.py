# %% [markdown]
# # Export to the hardware runtime
#
# The force controller (PD, C_F = P + D s with a 200 Hz derivative filter) and the
# EA-FOB (the same observer filters the analysis and the simulator use) are
# discretised at 2 kHz (Tustin) into second-order sections in the delta operator
# (rho = z - 1, well conditioned for poles near z = 1) and emitted as C99 for the
# Nucleo F446RE. Here we emit the code, compile it with the host compiler and
# check that the float32 C reproduces the float64 Python implementation.

# %%
import os
import shutil

import numpy as np

from forecast_design import export_controller

FAST = os.environ.get("FORECAST_FAST") == "1"
result = export_controller(out_dir="export", controller="pd:5:0.1", compensator="ea-fob", env="exp-soft",
                           w_q_hz=10.0)
print(result.header.read_text()[:1200])

# %% [markdown]
# ## Float32 C against float64 Python on the same input sequence

# %%
from forecast_design.export import toolchain

inputs = toolchain.test_sequence(4000 if FAST else 20_000)
python_step = result.program.make_step(np.float64)
reference = np.array([python_step.step(*row) for row in inputs.astype(float)])
if shutil.which("cc") or shutil.which("gcc"):
    c_out = toolchain.run_host(toolchain.build_host("export"), inputs.astype(float))
    print(f"max |C float32 - Python float64| = {np.max(np.abs(c_out - reference)):.2e} N m")
else:
    print("no host C compiler; skipping the compiled comparison")

# %% [markdown]
# ## On an emulated Cortex-M4
#
# With `arm-none-eabi-gcc` and `qemu-system-arm` installed (the test set-up installs
# them), the same code is cross-compiled with the F446RE's flags and run on qemu's
# mps2-an386; its outputs must equal the host build's, and the instruction count per
# step bounds the cycles against the 84,000 available in one 2 kHz period at 168 MHz.

# %%
if toolchain.find_tools().arm_ready and not FAST:
    print(toolchain.check_on_cortex_m4("export"))
else:
    print("ARM toolchain absent or FAST mode: see `forecast-design export --check-arm`")
