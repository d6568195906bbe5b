"""Cost of the exported C controller: Cortex-M4 .text size, instructions/cycles per step, host ns per step.

Run: ``python benchmarks/bench_export.py [--steps 20000]``. Needs a host C
compiler; the Cortex-M4 columns need arm-none-eabi-gcc and qemu-system-arm
(``tools/setup.sh --test``) and are ``-`` without them. Instructions per
step are measured under ``qemu -icount shift=0`` (see
:mod:`forecast_design.export.toolchain`); cycles are that count times the
stated cycles-per-instruction bound, against the 84,000-cycle budget of one
2 kHz period at 168 MHz.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from forecast_design.export import toolchain
from forecast_design.export.c import export_controller

KINDS = ["none", "sfm", "ea-fob", "lo-dob", "ld-dob", "motor-fob"]
SFM_PARAMS = {"viscous": 0.35, "coulomb": 0.30, "sin1": 0.04, "cos1": -0.02, "sin2": 0.015, "cos2": 0.01,
              "sin3": -0.008, "cos3": 0.006, "sin4": 0.004, "cos4": -0.003}

_TIMER = r"""#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "fd_controller.h"
int main(void)
{
    static fd_state s;
    struct timespec a, b;
    volatile float sink = 0.0f;
    long i, n = %d;
    fd_init(&s);
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (i = 0; i < n; ++i) {
        sink = fd_step(&s, (i / 1000) %% 2 ? 0.2f : -0.2f, 0.001f * (float)(i %% 97), 0.3f + 1e-5f * (float)i);
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%%.3f\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / (double)n);
    (void)sink;
    return 0;
}
"""


def main() -> None:
    """Export each compensator once, then print size, M4 instructions/cycles and host ns per step."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="steps per measurement")
    args = parser.parse_args()
    tools = toolchain.find_tools()
    if tools.cc is None:
        raise SystemExit("no host C compiler")
    budget = toolchain.budget_cycles(2000.0)
    print(f"{'compensator':12s} {'.text [B]':>10s} {'instr/step':>11s} {'cycles<=':>9s} {'% budget':>9s} "
          f"{'host ns/step':>13s}")
    rng = np.random.default_rng(0)
    inputs = np.column_stack([np.where(np.arange(args.steps) % 2000 < 1000, 0.2, -0.2),
                              0.01 * rng.normal(size=args.steps),
                              0.3 + np.cumsum(rng.normal(size=args.steps)) * 1e-4]).astype(np.float32)
    for kind in KINDS:
        d = Path(tempfile.mkdtemp(prefix="fd_bench_"))
        try:
            export_controller(out_dir=d, compensator=kind, sfm_params=SFM_PARAMS if kind == "sfm" else None)
            (d / "timer.c").write_text(_TIMER % args.steps)
            exe = d / "timer"
            subprocess.run([tools.cc, *toolchain.HOST_CFLAGS[:-3], "-ffp-contract=off", "-o", str(exe),
                            str(d / "timer.c"), str(d / "fd_controller.c"), "-lm"], check=True)
            ns = float(min(subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
                           for _ in range(3)))
            text = instr = cycles = frac = "-"
            if tools.arm_ready:
                elf = toolchain.build_arm(d, inputs, tools=tools)
                run = toolchain.run_qemu(elf, args.steps, qemu=tools.qemu)
                text = str(toolchain.text_size(d / "arm" / "fd_controller.o", size_tool=tools.arm_size))
                instr = f"{run.instructions_per_step:.1f}"
                cycles = f"{run.cycles_per_step_bound:.0f}"
                frac = f"{100 * run.cycles_per_step_bound / budget:.2f}"
            print(f"{kind:12s} {text:>10s} {instr:>11s} {cycles:>9s} {frac:>9s} {ns:13.1f}")
        finally:
            shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    main()
