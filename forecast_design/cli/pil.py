"""The ``pil`` verb: the board firmware on qemu in the loop with the virtual testbed."""

from __future__ import annotations

import argparse
import math
import sys

from . import _command, _compensator_from_args, _configure_export, _controller_from_args, _one_environment_from_args
from . import _note, _testbed_from_args
from . import _recorded_assumptions, _write_json
from ._firmware import _firmware_options_from_args

#: pil's defaults of the design options it shares with export; None on the parser, so that an option a
#: user gives beside --scenario is seen (and refused) rather than mistaken for its default.
_DESIGN_DEFAULTS = {"compensator": "none", "w_q_hz": 10.0, "rate_hz": 2000.0}
#: Options the scenario replaces (refused beside --scenario).
_SCENARIO_HOLDS = ("env", "testbed", "experiment", "controller", "compensator", "w_q_hz", "rate_hz", "method",
                   "friction")


def _configure_pil(p: argparse.ArgumentParser) -> None:
    _configure_export(p)   # the same design options as export (--out is the recorded RUN.toml here)
    p.add_argument("--scenario", metavar="SCENARIO.toml",
                   help="run a simulation scenario (docs/scenario.md): its testbed, environment, controller, "
                        "compensator and rate are the firmware's design, its [truth] effects (friction...), "
                        "process noise and seed the virtual testbed's; its reference (step, square or sine) and "
                        "duration_s unless --reference/--duration are given")
    p.add_argument("--reference", default=None, metavar="KIND:ARGS",
                   help="force reference: square:AMP:PERIOD, sine:AMP:PERIOD, step:AMP[:DELAY] (default "
                        "square:0.2:0.5, or the scenario's)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default 2, or the scenario's)")
    p.add_argument("--work-dir", metavar="DIR", help="firmware project folder (default: RUN-firmware beside --out)")
    p.add_argument("--no-icount", action="store_true",
                   help="run qemu on real time (no instruction count; the link timeout is then wall-clock)")
    p.set_defaults(**{key: None for key in _DESIGN_DEFAULTS})


@_command("pil", "processor-in-the-loop: the board firmware on qemu (netduinoplus2) against the virtual testbed",
          _configure_pil)
def _cmd_pil(args: argparse.Namespace) -> int:
    from ..errors import ParameterError
    from ..runtime.pil import PIL_LINK_TIMEOUT_MS, run_pil, run_pil_scenario

    if args.check_arm:
        raise ParameterError("--check-arm is an export option; pil always runs the firmware on qemu",
                             name="check_arm")
    options = _firmware_options_from_args(args, link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    if args.scenario:
        from ..simulation.scenario import load_scenario

        given = [name for name in _SCENARIO_HOLDS if getattr(args, name, None)]
        if given:
            raise ParameterError(f"give --scenario or --{given[0].replace('_', '-')}, not both (the scenario holds "
                                 "the design the firmware runs and the virtual testbed)", name=given[0])
        scenario = load_scenario(args.scenario)     # the one resolution of the scenario, as simulate's
        limit = float(scenario.options.get("torque_limit", math.inf))
        if not math.isfinite(args.tau_max) and math.isfinite(limit):
            # the scenario's torque limit is the firmware's, within what the output stage can command
            if limit > args.tau_full_scale:
                _note([f"the scenario's torque_limit {limit:g} N m exceeds the output stage's full scale "
                       f"{args.tau_full_scale:g} N m (--tau-full-scale): the firmware clamps at the full scale"])
            args.tau_max = min(limit, args.tau_full_scale)
            options = _firmware_options_from_args(args, link_timeout_ms=PIL_LINK_TIMEOUT_MS)
        reference = args.reference or scenario.to_mapping().get("reference")
        duration_s = args.duration if args.duration is not None else scenario.options["duration_s"]
        result = run_pil_scenario(scenario, reference=args.reference, duration=args.duration, out=args.out,
                                  work_dir=args.work_dir, options=options, icount=not args.no_icount)
        _note(scenario.notes)                       # after the run: a refusal stays one line
    else:
        for key, value in _DESIGN_DEFAULTS.items():
            if getattr(args, key) is None:
                setattr(args, key, value)
        _, env = _one_environment_from_args(args, "pil")
        comp = _compensator_from_args(args)
        reference, duration_s = args.reference or "square:0.2:0.5", 2.0 if args.duration is None else args.duration
        result = run_pil(controller=_controller_from_args(args), compensator=comp if comp is not None else "none",
                         env=env, testbed=_testbed_from_args(args), w_q_hz=args.w_q_hz, rate_hz=args.rate_hz,
                         reference=reference, duration=duration_s, out=args.out,
                         work_dir=args.work_dir, options=options, icount=not args.no_icount)
    summary = {**result.to_mapping(), "assumed": _recorded_assumptions(result.path, reference, duration_s)}
    if args.json:
        _write_json(args.json, summary)
    if args.json != "-":
        ips, worst = summary["instructions_per_step"], summary["max_instructions_per_step"]
        cost = (f"; {ips:.0f} instructions per period (longest {worst:.0f}; x CPI 2 against "
                f"{summary['budget_cycles_per_period']:.0f} cycles: "
                f"{100 * summary['max_budget_fraction_at_cpi_2']:.1f} %)" if ips is not None and worst is not None
                else "")
        print(f"{args.out}: {result.samples} of {result.expected} periods with the firmware in the loop{cost}")
    if result.fault:
        print(f"forecast-design: error: firmware fault {result.fault} at sample {result.fault_index} (torque zero)",
              file=sys.stderr)
    return 2 if result.fault else 0
