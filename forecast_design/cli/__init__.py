"""The ``forecast-design`` command line: one verb, one library call."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

from .. import __version__
from ..errors import ForecastError
from ..fileio import guard_inputs
from ..limits import require_no_nan
from ..params import BREAK_POINTS, COMPENSATOR_KINDS, Q_FAMILIES
from ..controllers.base import DISCRETIZATIONS

__all__ = ["main"]


class _ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2 (argparse's own convention)."""

    def error(self, message: str) -> None:  # pragma: no cover - exercised via main()
        # the same prefix as every other error line; the verb (prog "forecast-design VERB") follows it
        verb = self.prog.partition(" ")[2]
        self.exit(2, f"forecast-design: error: {verb + ': ' if verb else ''}{message}\n")


@contextlib.contextmanager
def _progress_bar(desc: str, unit: str, *, enabled: bool = True):
    """The CLI's one progress mechanism: a tqdm bar on stderr behind a ``progress(done, total)`` callback."""
    from tqdm import tqdm

    with tqdm(total=0, desc=desc, unit=unit, disable=None if enabled else True, leave=False,
              file=sys.stderr) as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        yield progress

def _print_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2, allow_nan=True)
    sys.stdout.write("\n")


_COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]]] = {}


def _command(name: str, help_text: str, configure: Callable[[argparse.ArgumentParser], None]):
    def register(handler: Callable[[argparse.Namespace], int]):
        _COMMANDS[name] = (help_text, configure, handler)
        return handler

    return register


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every verb."""
    parser = _ArgumentParser(
        prog="forecast-design",
        description="Force-control design toolbox for series elastic actuators (Forecast testbed).",
    )
    parser.add_argument("--version", action="version", version=f"forecast-design {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_ArgumentParser)
    for name, (help_text, configure, handler) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        configure(p)
        p.set_defaults(handler=handler)
    return parser


def _print_warnings(caught: Sequence[warnings.WarningMessage]) -> None:
    """One line per distinct warning: the toolbox's own plainly, others (numpy's) with their category."""
    seen: set[str] = set()
    for w in caught:
        text = (str(w.message).strip().splitlines() or [""])[0]
        if not w.category.__module__.startswith("forecast_design"):
            text = f"{w.category.__name__}: {text}"
        if text not in seen:
            seen.add(text)
            print(f"forecast-design: warning: {text}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code (0 ok, 1 an answer that is a failure, 2 bad input, 3 not identifiable)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        print("forecast-design: error: give a command (forecast-design --help lists them)", file=sys.stderr)
        return 2
    try:
        # Python warnings (the toolbox's own, numpy's) become one line each, printed only when the verb
        # succeeds: an error path prints its one error line and nothing else.
        with warnings.catch_warnings(record=True) as caught, guard_inputs():
            if not args.debug:
                warnings.simplefilter("default")
            _refuse_inputs_as_outputs(args)      # no output replaces a file the command reads
            code = int(args.handler(args) or 0)
        _print_warnings(caught)
        return code
    except ForecastError as exc:
        if args.debug:
            raise
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"forecast-design: error: {message}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:
        if args.debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"forecast-design: error: {where}{exc.strerror or exc}".splitlines()[0], file=sys.stderr)
        return 2


# --- shared option helpers -------------------------------------------------

from ._options import (  # noqa: E402  (the shared option helpers; verb modules import them from here)
    _add_controller_option,
    _add_environment_options,
    _controller_from_args,
    _add_json_option,
    _add_skew_option,
    _compensator_from_args,
    _design_from_args,
    _environments_from_args,
    _float_range,
    _add_allow_unidentified,
    _check_sfm_loop,
    _friction_from_file,
    _json_positional,
    _note,
    _one_environment_from_args,
    _refuse_inputs_as_outputs,
    _testbed_from_args,
)


# --- tf ---------------------------------------------------------------------


def _configure_tf(p: argparse.ArgumentParser) -> None:
    _add_environment_options(p, default="soft", many=True)
    _add_json_option(p, "P, EA, LO, LD (one object, or one per environment)")
    p.add_argument("--plot", metavar="OUT.png", help="Bode plot of P and the nominal plants")


#: How to read the ``tf`` JSON (its symbols and units).
_TF_CONVENTIONS = ("P = tau_s / tau_m (the force plant, eq. 2), EA, LO, LD its nominal plants (eqs. 5-8); num and den "
                   "in powers of s, highest first, den[0] = 1; in the latex J = J_e + J_l and d = d_e + d_l (the "
                   "output's whole inertia [kg m^2] and damping [N m s/rad]); poles as [re, im] [rad/s]; dc_gain [-]")


@_command("tf", "print the plant P and the nominal plants EA, LO, LD (eqs. 2-8)", _configure_tf)
def _cmd_tf(args: argparse.Namespace) -> int:
    from ..symbolic import transfer_functions

    testbed = _testbed_from_args(args)
    designs = _environments_from_args(args).designs(testbed)
    results = []
    with _progress_bar("tf", "environment", enabled=args.json != "-" and len(designs) > 1) as progress:
        for label, design in designs:
            results.append((label, transfer_functions(design)))
            progress(len(results), len(designs))
    require_no_nan({label: tfs.to_mapping() for label, tfs in results}, "tf")
    if args.plot:
        from ..plotting.bode import plot_plants

        plot_plants(results, args.plot)
    if args.json:
        described = {label: {**tfs.to_mapping(), "design": design.to_mapping(), "conventions": _TF_CONVENTIONS}
                     for (label, tfs), (_, design) in zip(results, designs)}
        _write_json(args.json, next(iter(described.values())) if len(results) == 1 else described)
        if args.json == "-":
            return 0
    for label, tfs in results:
        print(f"environment: {label}")
        for key, value in tfs.to_mapping().items():
            print(f"  {key}(s) = {value['latex']}")
            print(f"    num = {value['num']}")
            print(f"    den = {value['den']}")
            poles = ", ".join(f"{re:.6g}{im:+.6g}j" for re, im in value["poles"])
            print(f"    poles = [{poles}]  dc_gain = {value['dc_gain']:.6g}")
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


# --- reproduce ----------------------------------------------------------------


def _configure_reproduce(p: argparse.ArgumentParser) -> None:
    p.add_argument("figure", choices=["fig6", "fig7", "table3"], help="which result of the paper")
    _add_skew_option(p)
    _add_environment_options(p, default="soft,stiff", many=True)
    p.add_argument("--json", metavar="OUT", nargs="?", const="-",
                   help="write the result as JSON to OUT (stdout with no OUT or '-')")
    p.add_argument("--plot", metavar="OUT.png", help="draw the figure")
    p.add_argument("--xcorr", metavar="MODE", help="table3: reading of the paper's 'mean cross-correlation' "
                   "(pearson [default]: zero lag, means removed; pearson-max-lag; raw: means kept)")
    p.add_argument("--derivative-on", metavar="WHERE", help="table3: where the board's PD takes its derivative "
                   "(measurement [default]: no kick at the step; error: the format's u = P e + D de/dt)")


def _recorded_assumptions(path: str | None, reference: str, duration_s: float | None) -> dict:
    """What a recorded run (``run``, ``pil``) assumed, read back from the experiment it wrote: the design (testbed,
    environment, controller, compensator with its cutoff), the rate [Hz], the force reference and duration [s]."""
    from ..experiment_io import parse_toml, read_toml_document

    out: dict[str, Any] = {"reference": reference, "duration_s": duration_s}
    if path:
        design, rate_hz, _, _ = parse_toml(read_toml_document(Path(path)), str(path))
        out = {"design": design.to_mapping(), "rate_hz": rate_hz, **out}
    return out


def _write_json(target: str, obj: Any) -> None:
    if target == "-":
        _print_json(obj)
        return
    from ..fileio import atomic_write

    atomic_write(target, json.dumps(obj, indent=2) + "\n")


def _reproduce_fig6(args: argparse.Namespace) -> int:
    from ..reproduce import fig6_table

    with _progress_bar("fig6", "environment", enabled=args.json != "-") as progress:
        rows = fig6_table(environments=_environments_from_args(args), testbed=_testbed_from_args(args),
                          skew=args.sigma, progress=progress)
    mapping = [row.to_mapping() for row in rows]
    if args.plot:
        from ..plotting.margins import plot_fig6

        plot_fig6(rows, args.plot, sigma=args.sigma)
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        print(f"{'environment':<10} {'observer':<8} {'w_q_hz':>6} {'alpha':>7} {'GM_hi_dB':>9} "
              f"{'PM_deg':>7} {'w_c_rad_s':>9} stable")
        for r in mapping:
            wq = "-" if r["w_q_hz"] is None else f"{r['w_q_hz']:g}"
            gm = r["gain_margin_db"][1]
            print(f"{r['environment']:<10} {r['observer']:<8} {wq:>6} {r['disk_margin']:>7.4f} "
                  f"{(gm if gm is not None else float('inf')):>9.3f} {r['phase_margin_deg']:>7.2f} "
                  f"{(r['frequency_rad_s'] or float('nan')):>9.3f} {r['stable']}")
    return 0


def _reproduce_fig7(args: argparse.Namespace) -> int:
    from ..reproduce import reproduce_fig7

    result = reproduce_fig7()
    if args.plot:
        from ..plotting.simulation import plot_fig7

        plot_fig7(result, args.plot)
    mapping = result.to_mapping()
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        for key in ("mae_friction_sfm", "mae_friction_eafob", "mae_tracking_sfm", "mae_tracking_eafob"):
            print(f"{key:<20} {mapping[key]:.4f} N m")
        print(result.explanation)
    return 0


def _reproduce_table3(args: argparse.Namespace) -> int:
    from ..reproduce import reproduce_table3

    result = reproduce_table3(xcorr=args.xcorr or "pearson", derivative_on=args.derivative_on or "measurement")
    if args.plot:
        from ..plotting.simulation import plot_table3

        plot_table3(result, args.plot)
    # The issue's contract is a list of rows; each row also carries the explanation of deviations.
    rows = [{**row, "explanation": result.explanation} for row in result.to_mapping()]
    if args.json:
        _write_json(args.json, rows)
    if args.json != "-":
        def se(v, digits):   # a standard error, blank without one (fewer than 3 repetitions)
            return f"{v:.{digits}f}" if v is not None else "-"

        print(f"{'environment':<10} {'compensator':<11} {'xcorr':>7} {'+-':>6} {'paper':>6} {'mae_N_m':>8} "
              f"{'+-':>7} {'paper':>6}")
        for r in rows:
            print(f"{r['environment']:<10} {r['compensator']:<11} {r['xcorr']:>7.3f} {se(r['xcorr_se'], 3):>6} "
                  f"{r['paper_xcorr']:>6.2f} {r['mae']:>8.4f} {se(r['mae_se'], 4):>7} {r['paper_mae']:>6.3f}")
        print(result.explanation)
    return 0


_REPRODUCERS: dict[str, Callable[[argparse.Namespace], int]] = {
    "fig6": _reproduce_fig6, "fig7": _reproduce_fig7, "table3": _reproduce_table3,
}


@_command("reproduce", "reproduce a result of the paper: fig6 (disk margins), fig7, table3", _configure_reproduce)
def _cmd_reproduce(args: argparse.Namespace) -> int:
    from ..errors import ParameterError

    handler = _REPRODUCERS.get(args.figure)
    if handler is None:
        raise ParameterError(f"reproduce {args.figure}: not available in this version", name="figure",
                             value=args.figure)
    given = [opt for opt, value in (("--env", args.env), ("--testbed", args.testbed), ("--experiment", args.experiment),
                                    ("--skew", args.sigma)) if value]
    if args.xcorr is not None and args.figure != "table3":
        raise ParameterError(f"reproduce {args.figure}: --xcorr applies to table3 only", name="xcorr")
    if args.derivative_on is not None and args.figure != "table3":
        raise ParameterError(f"reproduce {args.figure}: --derivative-on applies to table3 only",
                             name="derivative_on")
    if args.figure != "fig6" and given:
        raise ParameterError(f"reproduce {args.figure} runs the paper's own set-up; {', '.join(given)} applies to "
                             f"fig6 only", name=given[0].lstrip("-"))
    return handler(args)


# --- pipeline ----------------------------------------------------------------------


def _configure_pipeline(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="report", metavar="DIR", help="report folder (default report/)")
    _add_json_option(p, "the summary")


@_command("pipeline", "run the whole design pipeline on bundled defaults into a report folder", _configure_pipeline)
def _cmd_pipeline(args: argparse.Namespace) -> int:
    from ..pipeline import run_pipeline

    result = run_pipeline(args.out, progress=None if args.json == "-" else lambda step: print(f"[{step}]", flush=True))
    if args.json:
        _write_json(args.json, result.to_mapping())
    if args.json != "-":
        print(f"report: {result.out_dir / 'index.md'}")
    return 0


# --- export / emulate / run -----------------------------------------------------------

_COMPENSATOR_CHOICES = COMPENSATOR_KINDS


def _configure_export(p: argparse.ArgumentParser) -> None:
    _add_controller_option(p)
    p.add_argument("--compensator", "--observer", dest="compensator", default="none", choices=_COMPENSATOR_CHOICES)
    _add_environment_options(p, default="exp-soft", many=False)
    p.add_argument("--friction", metavar="F.json", help="identified friction for --compensator sfm "
                                                        "(the file identify --model sfm --json F.json writes)")
    _add_allow_unidentified(p)
    p.add_argument("--tau-max", type=_float_range, default=float("inf"), metavar="N_M",
                   help="command saturation |tau_m| <= TAU_MAX [N m] (default: none for C; 1 N m with --firmware, "
                        "the board's torque limit, docs/firmware.md)")
    p.add_argument("--w-q-hz", type=_float_range, default=10.0, help="Q cutoff [Hz] (default 10)")
    p.add_argument("--method", default=None, choices=("backward-euler", "tustin", "zoh", "matched"),
                   help="set the controller's discretization (default: the controller's own, e.g. backward-euler "
                        "for pd/pid, tustin for tf); the observers are discretised with tustin")
    p.add_argument("--rate-hz", type=_float_range, default=2000.0, help="control rate [Hz] (default 2000)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for fd_controller.h / fd_controller.c")
    p.add_argument("--check-arm", action="store_true",
                   help="cross-compile for the Cortex-M4, run on qemu (mps2-an386), compare with the host build")
    _add_json_option(p, "the export summary")
    from ._firmware import _add_firmware_options

    _add_firmware_options(p)


@_command("export", "export the controller and compensator as C99 for the Nucleo F446RE (2 kHz)", _configure_export)
def _cmd_export(args: argparse.Namespace) -> int:
    from ..errors import ParameterError
    from ..export.c import export_controller

    if not (args.tau_max > 0.0):
        raise ParameterError(f"--tau-max must be > 0 [N m], got {args.tau_max:g}", name="tau_max")
    _, env = _one_environment_from_args(args, "export")
    comp = _compensator_from_args(args)
    if comp is not None and comp.kind == "sfm":
        # the loop's stability with the compensator, before code is written for a board
        from ..params import Design

        _check_sfm_loop(Design(testbed=_testbed_from_args(args), environment=env), comp.friction_params,
                        controller=_controller_from_args(args), rate_hz=args.rate_hz)
    if args.firmware:
        from ._firmware import _cmd_export_firmware

        return _cmd_export_firmware(args, env, comp)
    result = export_controller(out_dir=args.out, controller=_controller_from_args(args),
                               compensator=comp if comp is not None else "none", env=env,
                               testbed=_testbed_from_args(args), w_q_hz=args.w_q_hz, rate_hz=args.rate_hz,
                               tau_max=args.tau_max)
    mapping = result.to_mapping()
    if args.check_arm:
        from ..export.toolchain import check_on_cortex_m4

        mapping["cortex_m4"] = check_on_cortex_m4(args.out, rate_hz=result.program.rate_hz)
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        print(f"wrote {result.header} and {result.source} (sha256 {result.digest[:12]})")
        if args.check_arm:
            m4 = mapping["cortex_m4"]
            print(f"Cortex-M4 (qemu): {m4['instructions_per_step']:.0f} instructions/step, <= "
                  f"{m4['cycles_per_step_bound']:.0f} cycles of {m4['budget_cycles_per_period']:.0f}; "
                  f".text {m4['text_bytes']} B; max |M4 - host| {m4['max_abs_diff_vs_host']:.3g} N m")
    return 0


def _configure_emulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fault", action="append", default=[], metavar="KIND:VALUE",
                   help="inject faults: flip:P, drop:P (probabilities), disconnect:N (samples), seed:S")
    p.add_argument("--realtime", action="store_true", help="pace the sample stream in real time")
    p.add_argument("--scenario", metavar="SCENARIO.toml",
                   help="the virtual hardware of a simulation scenario: its testbed, environment and [truth] "
                        "effects (friction, cogging, ...; docs/scenario.md)")
    p.add_argument("--controller", default=None, metavar="FILE.c|FILE.py:Class",
                   help="a controller written as code that the emulated board was built with (as export --firmware "
                        "--controller FILE.c links it): the host's upload of it is accepted and it runs each period; "
                        "linear controllers need no option (the host uploads them)")
    _add_environment_options(p, default="exp-soft", many=False)


@_command("emulate", "emulate the board on a pseudo-terminal (prints its path, serves until terminated)",
          _configure_emulate)
def _cmd_emulate(args: argparse.Namespace) -> int:
    from ..errors import ParameterError
    from ..runtime import emulate, parse_fault

    import dataclasses

    faults = parse_fault(args.fault)
    code = None
    if args.controller is not None:
        code = _controller_from_args(args)
        if not code.is_code:
            raise ParameterError(f"emulate --controller takes a controller written as code (FILE.c, FILE.py:Class); "
                                 f"{code.spelling()} is uploaded by the host (run --controller)", name="controller",
                                 value=args.controller)
        from ..simulation.code import code_runner

        code_runner(code)   # compiled and loaded now: a bad file is one line before the pty is served
    if args.scenario:
        from ..simulation.scenario import load_scenario

        if args.env or args.testbed or args.experiment:
            raise ParameterError("give --scenario or --env/--testbed/--experiment, not both (the scenario holds "
                                 "the testbed and the environment)", name="scenario")
        scenario = load_scenario(args.scenario)
        _note(scenario.notes)
        design = scenario.design if code is None else dataclasses.replace(scenario.design, controller=code)
        with scenario.naming_errors():      # e.g. an RK4 step unstable for this plant: names the scenario file
            return emulate(faults=faults, design=design, effects=scenario.effects, realtime=args.realtime)
    design = _design_from_args(args)
    return emulate(faults=faults, design=design if code is None else dataclasses.replace(design, controller=code),
                   realtime=args.realtime)


def _configure_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port (device path, pty, or a pyserial URL)")
    _add_controller_option(p)
    p.add_argument("--compensator", "--observer", dest="compensator", default="none", choices=_COMPENSATOR_CHOICES)
    p.add_argument("--friction", metavar="F.json", help="identified friction for --compensator sfm (identify --json)")
    _add_allow_unidentified(p)
    p.add_argument("--w-q-hz", type=_float_range, default=10.0)
    _add_environment_options(p, default="exp-soft", many=False)
    p.add_argument("--reference", default="square:0.2:0.5", metavar="KIND:ARGS",
                   help="force reference: square:AMP:PERIOD, sine:AMP:PERIOD or step:AMP[:DELAY] (N m, s); "
                        "sine:0.2:0.5 is 0.2 N m at 2 Hz")
    p.add_argument("--duration", type=_float_range, default=5.0, help="run length [s]")
    p.add_argument("--timeout", type=_float_range, default=1.0, help="serial silence that counts as a disconnect [s]")
    p.add_argument("--out", required=True, metavar="RUN.toml", help="recorded experiment")
    p.add_argument("--json", metavar="SUMMARY", nargs="?", const="-", help="write the run summary as JSON")


@_command("run", "upload the exported controller to a board, record a run as an experiment", _configure_run)
def _cmd_run(args: argparse.Namespace) -> int:
    from ..runtime import BoardError, LinkError, run_on_port

    try:
        comp = _compensator_from_args(args)
        env = _one_environment_from_args(args, "run")[1]
        if comp is not None and comp.kind == "sfm":
            # the loop's stability with the compensator, before its code goes to the board
            from ..params import Design

            _check_sfm_loop(Design(testbed=_testbed_from_args(args), environment=env), comp.friction_params,
                            controller=_controller_from_args(args))
        result = run_on_port(args.port, out=args.out, reference=args.reference, duration=args.duration,
                             controller=_controller_from_args(args), compensator=comp if comp is not None else "none",
                             w_q_hz=args.w_q_hz, env=env, testbed=_testbed_from_args(args), timeout=args.timeout)
        summary = {**result.to_mapping(), "assumed": _recorded_assumptions(result.path, args.reference, args.duration)}
    except (LinkError, BoardError) as exc:
        # a run that ended badly (lost link, board fault, a late write failure saved to a recovery file)
        # still gets its --json summary, and the one error line says where it went
        if args.json and getattr(exc, "summary", None):
            try:
                _write_json(args.json, exc.summary)
                note = "" if args.json == "-" else f"; run summary written to {args.json}"
            except ForecastError as failed:
                note = f"; the run summary could not be written either ({str(failed).splitlines()[0]})"
            exc.args = (f"{str(exc).splitlines()[0]}{note}",) + exc.args[1:]
        raise
    if args.json:
        _write_json(args.json, summary)
    if args.json != "-":
        print(f"{args.out}: {summary['samples']} samples, {summary['lost']} lost, "
              f"{summary['corrupt_frames']} corrupt frames, {summary['resyncs']} resyncs")
    return 0


# --- diagnose / bench-gap ----------------------------------------------------------------


def _configure_diagnose(p: argparse.ArgumentParser) -> None:
    p.add_argument("experiment", metavar="EXPERIMENT.toml", help="measured log; its TOML is the nominal model")
    p.add_argument("--json", metavar="OUT", nargs="?", const="-", help="write the diagnosis JSON to OUT (or stdout)")
    p.add_argument("--report", metavar="DIR", help="write a Markdown report with plots")


@_command("diagnose", "diagnose the sim-to-real gap: where, which unmodelled effect, how much", _configure_diagnose)
def _cmd_diagnose(args: argparse.Namespace) -> int:
    from ..experiment import load_experiment
    from ..gap import diagnose
    from ..gap.grading import QUALIFIED_GRADES
    from ..reporting import write_report

    from ..limits import limit_of

    experiment = load_experiment(args.experiment, max_samples=limit_of("log_samples_diagnose"), reader="diagnose")
    diagnosis = diagnose(experiment)
    mapping = require_no_nan(diagnosis.to_mapping(), "diagnose")
    if args.report:
        write_report(diagnosis, experiment, args.report)
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        v = mapping["verdict"]
        graded = f", graded {v['grade']}" if v["grade"] in QUALIFIED_GRADES else ""
        print(f"verdict: {v['effect']}{graded} (gap {v['gap_before']:.4g} -> {v['gap_after']:.4g}, "
              f"reduction {100 * v['reduction']:.1f} %)")
        if v["status"]:
            # the numbers with their 95 % intervals and statuses: an `uncertain` one is to be read by its interval
            print("parameters (95 % intervals): " + ", ".join(
                f"{k} = {st['value']:.4g}" + (f" +- {1.96 * st['std']:.2g}" if st.get("std") is not None else "")
                + f" ({st['status']})" for k, st in v["status"].items()))
        if v["secondary"] is not None:
            print(f"second effect: {v['secondary']['effect']} (gap with both {v['secondary']['gap_after']:.4g}, "
                  f"reduction {100 * v['secondary']['reduction']:.1f} %)")
        print(f"where: {mapping['location']['summary']}")
        for row in mapping["ranking"]:
            flag = "" if row["identified"] else "  not identified: " + "; ".join(row["reasons"][:2])
            print(f"  {row['effect']:<22} reduction {100 * row['reduction']:6.1f} %{flag}")
        pairs = mapping.get("isolability", {}).get("not_isolable", [])
        if pairs:
            print(f"this log cannot tell apart: {', '.join(pairs)}")
    for row in mapping["ranking"]:
        if not row["identified"] and row["reduction"] >= diagnosis.data.options.min_reduction:
            print(f"forecast-design: warning: {row['effect']} would remove {100 * row['reduction']:.0f} % of the gap "
                  f"but is not identified on this log: {'; '.join(row['reasons'][:2])}", file=sys.stderr)
    if args.report and args.json != "-":
        print(f"report: {args.report}")
    return 0


def _configure_bench_gap(p: argparse.ArgumentParser) -> None:
    p.add_argument("--per-effect", type=int, default=5, metavar="N", help="logs per effect word (default 5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=_float_range, default=10.0, help="length of each generated log [s]")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the logs on a Dask cluster (tcp://HOST:PORT) instead of local processes")
    p.add_argument("--hard", type=int, default=0, metavar="N",
                   help="also N logs per non-identifiable scenario (scored for honest caveats)")
    p.add_argument("--pairs", type=int, default=0, metavar="N", help="also N logs per two-effect combination")
    p.add_argument("--generator", choices=("testbed", "independent"), default="testbed",
                   help="log generator: the virtual testbed or the independent one (default testbed)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="effect magnitudes as a fraction of the typical ones, in (0, 1] (independent generator)")
    p.add_argument("--json", metavar="OUT", nargs="?", const="-", help="write the result JSON to OUT (or stdout)")


@_command("bench-gap", "withheld-effect benchmark of the diagnosis (confusion matrix, accuracy)", _configure_bench_gap)
def _cmd_bench_gap(args: argparse.Namespace) -> int:
    from ..errors import ParameterError
    from ..gap import benchmark

    if args.per_effect < 1:
        raise ParameterError(f"--per-effect must be >= 1, got {args.per_effect}", name="per_effect")
    with _progress_bar("bench-gap", "log", enabled=args.json != "-") as progress:
        result = benchmark(per_effect=args.per_effect, seed=args.seed, workers=args.workers,
                           duration_s=args.duration, hard=args.hard, pairs=args.pairs, progress=progress,
                           generator=args.generator, magnitude_scale=args.scale, scheduler=args.scheduler)
    if args.json:
        _write_json(args.json, result.to_mapping())
    if args.json != "-":
        print(result.format_confusion())
        print(f"accuracy {100 * result.accuracy:.1f} %, false alarms {result.false_alarms}, "
              f"lowest held-out reduction of a correct effect {result.min_true_reduction:.3f}")
    return 0


# --- margins ---------------------------------------------------------------------------------


def _configure_margins(p: argparse.ArgumentParser) -> None:
    _add_environment_options(p, default="soft", many=False, believed=True)
    p.add_argument("--compensator", "--observer", dest="observer", default="none", choices=_COMPENSATOR_CHOICES,
                   help="compensator/observer in the loop (default none)")
    p.add_argument("--w-q-hz", type=_float_range, default=10.0, help="Q cutoff [Hz]")
    p.add_argument("--q-family", default="butterworth", choices=Q_FAMILIES)
    _add_controller_option(p)
    p.add_argument("--break-at", default="controller", choices=BREAK_POINTS)
    p.add_argument("--sampled", action="store_true", help="sampled-data loop at --rate-hz")
    p.add_argument("--rate-hz", type=_float_range, default=2000.0)
    p.add_argument("--delay-samples", type=int, default=None,
                   help="--sampled: samples between computing the command and applying it (default 0: within the "
                        "period, as the simulator, the benchmark and the firmware run it)")
    p.add_argument("--method", default=None, choices=DISCRETIZATIONS,
                   help="--sampled: set the controller's discretization (default: the controller's own, as "
                        "simulate runs it); the observers are discretised with tustin")
    _add_skew_option(p)
    p.add_argument("--uncertainty", type=_float_range, default=0.0, metavar="FRACTION",
                   help="also the certified worst-case disk margin over the true J, d, k_e in [1-u, 1+u] x nominal "
                        "(continuous loop; branch and bound: lower and upper bounds and the worst point)")
    _add_json_option(p, "the margins")
    p.add_argument("--plot", metavar="OUT.png", help="the loop at a glance: disk margin over frequency, |S| and |T|, "
                                                    "the Nyquist curve near -1")


@_command("margins", "disk and classical margins of one force loop (any controller, compensator, environment, "
          "knowledge error); exit 1 if unstable", _configure_margins)
def _cmd_margins(args: argparse.Namespace) -> int:
    from ..analysis import analyse_loop
    from ..loops import COMMAND_DELAY_SAMPLES
    from ..environments import resolve_environments
    from ..params import Compensator, Design

    env_name, env = _one_environment_from_args(args, "margins")
    design = Design(testbed=_testbed_from_args(args), environment=env)
    comp = None if args.observer == "none" else Compensator(kind=args.observer, w_q_hz=args.w_q_hz,
                                                            q_family=args.q_family)
    believed = None
    if args.believed:
        believed_env = resolve_environments(args.believed, testbed=design.testbed).single("--believed")[1]
        believed = Design(testbed=design.testbed, environment=believed_env)
    if not args.sampled and (args.method is not None or args.delay_samples is not None):
        from ..errors import ParameterError

        raise ParameterError("--method and --delay-samples describe the sampled loop; add --sampled", name="sampled")
    if args.uncertainty and args.sampled:
        from ..errors import ParameterError

        raise ParameterError("--uncertainty certifies the continuous loop (a ZOH plant mixes frequencies); drop "
                             "--sampled, or check the sampled loop at chosen environments", name="uncertainty")
    controller = _controller_from_args(args)
    analysis = analyse_loop(design, comp, believed=believed, controller=controller,
                            break_at=args.break_at, sampled=args.sampled, rate_hz=args.rate_hz,
                            delay_samples=COMMAND_DELAY_SAMPLES if args.delay_samples is None else args.delay_samples,
                            skew=args.sigma, environment_name=env_name)
    _note(analysis.notes)
    worst = None
    if args.uncertainty:
        from ..worstcase import worst_case_disk_margin

        worst = worst_case_disk_margin(design, comp, controller=controller, uncertainty=args.uncertainty,
                                       believed=believed or design, skew=args.sigma, break_at=args.break_at)
    dm = analysis.disk
    if args.plot:
        from ..plotting.margins import plot_loop_analysis

        plot_loop_analysis(analysis, args.plot)
    mapping = require_no_nan({**analysis.to_mapping(), "environment": env_name, "compensator": args.observer,
                              **(worst.to_dict() if worst is not None else {})}, "margins")
    if args.json:
        _write_json(args.json, mapping)
    out = sys.stderr if args.json == "-" else sys.stdout
    print(f"loop: {analysis.title()}", file=out)
    if not dm.stable:
        print(f"the closed loop is UNSTABLE: no margin; disk margin 0" + (f"; plot: {args.plot}" if args.plot else ""),
              file=out)
        return 1
    if args.json != "-":
        lo, hi = dm.gain_margin_db
        print(f"disk margin {dm.alpha:.4f} (stable): gain [{lo:.3f}, {hi:.3f}] dB, phase "
              f"+-{dm.phase_margin_deg:.2f} deg at {dm.frequency_rad_s / (2 * math.pi):.4g} Hz "
              f"({dm.frequency_rad_s:.4g} rad/s); delay margin {dm.delay_margin_s:.4g} s")
        cm = analysis.classical
        gm, pm = cm.gain_margin, cm.phase_margin
        print("classical: gain margin " + (f"{gm.gain_margin_db:+.2f} dB at {gm.frequency_rad_s:.4g} rad/s"
                                           if gm else "infinite") +
              (f", phase margin {pm.phase_margin_deg:.2f} deg at {pm.frequency_rad_s:.4g} rad/s, delay margin "
               f"{pm.delay_margin_s:.4g} s" if pm else ", no gain crossover") +
              f" ({len(cm.phase_crossovers)} phase and {len(cm.gain_crossovers)} gain crossovers)")
        print(f"compensator: {analysis.assumptions['compensator']['linear_analysis']}")
        if worst is not None:
            print(worst.summary("disk margin"))
        if args.plot:
            print(f"plot: {args.plot}")
    return 0


# Verbs with modules of their own register themselves on import (kept last so
# `_command` and the shared helpers above exist when they load).
from . import _verbs  # noqa: E402,F401
