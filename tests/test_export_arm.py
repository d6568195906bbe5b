"""Cross-compile check: the exported C on an emulated Cortex-M4 (qemu mps2-an386) equals the host build."""

import numpy as np
import pytest

from forecast_design.export import toolchain
from forecast_design.export.c import export_controller

from test_export_c import SFM_PARAMS

TOOLS = toolchain.find_tools()
pytestmark = pytest.mark.skipif(not (TOOLS.arm_ready and TOOLS.cc),
                                reason="arm-none-eabi toolchain / qemu-system-arm / host cc missing "
                                       "(tools/setup.sh --test installs them)")
KINDS = ["none", "sfm", "ea-fob", "lo-dob", "ld-dob", "motor-fob"]
N_STEPS = 20_000  # the 10 s input sequence at 2 kHz


@pytest.fixture(scope="module")
def inputs():
    """10 s of closed-loop-like measurements: square reference, noisy spring torque, wandering angle."""
    rng = np.random.default_rng(7)
    t = np.arange(N_STEPS) / 2000.0
    tau_r = np.where((t % 1.0) < 0.5, 0.2, -0.2)
    tau_s = tau_r * (1 - np.exp(-(t % 0.5) / 0.05)) + 1e-3 * rng.normal(size=N_STEPS)
    theta = 0.3 + 2.0 * np.sin(2 * np.pi * 0.3 * t) + np.cumsum(rng.normal(size=N_STEPS)) * 1e-4
    return np.column_stack([tau_r, tau_s, theta]).astype(np.float32)


@pytest.mark.parametrize("kind", KINDS)
def test_cortex_m4_build_matches_host_build(kind, inputs, tmp_path):
    export_controller(out_dir=tmp_path, compensator=kind, sfm_params=SFM_PARAMS if kind == "sfm" else None)
    elf = toolchain.build_arm(tmp_path, inputs)  # -Werror under the F446RE flags
    run = toolchain.run_qemu(elf, N_STEPS)
    host = toolchain.run_host(toolchain.build_host(tmp_path), inputs.astype(float))
    if kind == "sfm":
        # newlib's sinf/cosf and glibc's may differ in the last bit of sin(i theta); the harmonic
        # terms (<= 0.04 N m each) carry that into tau_m at ~1e-8 N m, far below 1e-6
        assert np.max(np.abs(run.outputs - host)) <= 1e-6
    else:
        assert np.array_equal(run.outputs, host)
    assert np.all(np.isfinite(run.outputs)) and np.max(np.abs(run.outputs)) > 0.1

    # no double precision anywhere in the image: no soft-double helper, no double libm entry
    assert toolchain.double_precision_symbols(elf) == []
    undefined = set(toolchain.undefined_symbols(tmp_path / "arm" / "fd_controller.o"))
    assert undefined <= ({"sinf", "cosf", "sincosf"} if kind == "sfm" else set())

    # cost: measured instructions per step (qemu -icount) bound the cycles far inside 84,000
    static = toolchain.static_instruction_count(elf)
    assert static <= run.instructions_per_step <= static + 40 or kind == "sfm"  # + call/loop; sfm calls libm
    assert run.cycles_per_step_bound < 0.05 * toolchain.budget_cycles(2000.0)
    assert toolchain.text_size(tmp_path / "arm" / "fd_controller.o") < 4096


def test_export_check_arm_from_the_command_line(tmp_path, capsys):
    import json

    from forecast_design.cli import main

    assert main(["export", "--compensator", "motor-fob", "--out", str(tmp_path), "--check-arm", "--json"]) == 0
    m4 = json.loads(capsys.readouterr().out)["cortex_m4"]
    assert m4["max_abs_diff_vs_host"] == 0.0 and m4["double_precision_symbols"] == []
    assert m4["budget_fraction"] < 0.05 and m4["steps"] == 20_000
