"""Board-firmware options shared by ``export --firmware`` and ``pil`` (one definition)."""

from __future__ import annotations

import argparse
import math

from ..params import BOARDS, OUTPUT_STAGES
from ._options import _float_range

__all__ = ["_add_firmware_options", "_firmware_options_from_args"]


def _add_firmware_options(p: argparse.ArgumentParser) -> None:
    """--firmware, --board, --output-stage, --tau-full-scale, --link-timeout-ms."""
    g = p.add_argument_group("board firmware (export --firmware, pil)")
    g.add_argument("--firmware", action="store_true",
                   help="write a complete bare-metal firmware project (make builds .elf/.bin) instead of the C only")
    g.add_argument("--board", default=BOARDS[0], choices=BOARDS, help="target board (default nucleo-f446re)")
    g.add_argument("--output-stage", default="dac", choices=OUTPUT_STAGES,
                   help="ESCON set value: dac (PA4 analog) or pwm (PA6, 10-90 %% duty); default dac")
    g.add_argument("--tau-full-scale", type=_float_range, default=2.0, metavar="N_M",
                   help="torque at the ESCON's full-scale set value [N m] (default 2.0; from k_t, gear, current range)")
    g.add_argument("--link-timeout-ms", type=_float_range, default=None, metavar="MS",
                   help="host silence during a run that zeroes the torque [ms] (default 100 for export; "
                        "pil: 10000, since the desktop host is not real-time)")


def _firmware_options_from_args(args: argparse.Namespace, *, link_timeout_ms: float | None = None):
    """FirmwareOptions of the parsed options; --tau-max is the torque limit (default 1 N m).

    ``link_timeout_ms`` is the verb's default when --link-timeout-ms is not given (None: the board's).
    """
    from ..export.firmware import FirmwareOptions

    limit = args.tau_max if math.isfinite(args.tau_max) else 1.0
    timeout = args.link_timeout_ms if args.link_timeout_ms is not None else link_timeout_ms
    extra = {} if timeout is None else {"link_timeout_ms": timeout}
    return FirmwareOptions(board=args.board, output=args.output_stage, tau_limit_N_m=limit,
                           tau_full_scale_N_m=args.tau_full_scale, **extra)


def _cmd_export_firmware(args: argparse.Namespace, env, comp) -> int:
    """``export --firmware``: write the firmware project (and build it when --check-arm)."""
    from ..export.firmware import build_firmware, export_firmware
    from . import _controller_from_args, _testbed_from_args, _write_json

    result = export_firmware(out_dir=args.out, controller=_controller_from_args(args),
                             compensator=comp if comp is not None else "none", env=env,
                             testbed=_testbed_from_args(args), w_q_hz=args.w_q_hz, rate_hz=args.rate_hz,
                             options=_firmware_options_from_args(args))
    mapping = result.to_mapping()
    if args.check_arm:   # build both targets here (-Werror) as a check
        mapping["elf"] = [str(build_firmware(args.out, "board")), str(build_firmware(args.out, "pil"))]
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        print(f"wrote the {result.options.board} firmware project to {result.out_dir} ({len(result.files)} files, "
              f"sha256 {result.digest[:12]}); build it with: make -C {result.out_dir}")
    _report_cycles(result.cycles)
    return 0


def _report_cycles(cycles) -> None:
    """A C controller's measured cost, on stderr: against the period's budget, a warning above half of it."""
    import sys

    if cycles is None:
        return
    if not cycles.get("measured"):
        print(f"forecast-design: note: the C controller's cycle budget was not measured: {cycles['why']}",
              file=sys.stderr)
        return
    line = (f"C controller on the Cortex-M4 (qemu, {cycles['steps']} steps): longest step <= "
            f"{cycles['max_cycles_per_step_bound']:.0f} cycles, mean <= {cycles['cycles_per_step_bound']:.0f}, of "
            f"{cycles['budget_cycles_per_period']:.0f} per period ({100 * cycles['max_budget_fraction']:.1f} %); "
            f"max |M4 - host| {cycles['max_abs_diff_vs_host']:.3g} N m")
    prefix = "warning" if cycles["verdict"] != "ok" else "note"
    print(f"forecast-design: {prefix}: {line}", file=sys.stderr)
