"""The ``identify`` verb: friction identification from a log, with "not identifiable" as an answer."""

from __future__ import annotations

import argparse
import sys

from . import _command, _float_range, _write_json

#: What the exit codes of ``identify`` mean (its ``--help`` epilog and the README).
EXIT_CODES_TEXT = ("exit codes: 0 identified, partly identified or model inadequate (one warning per number that "
                   "is not an estimate, and the model the data ask for); 2 bad input; 3 not identifiable: the log "
                   "lacks the information (the JSON is written, with the status of every parameter and the "
                   "reasons)")


def _configure_identify(p: argparse.ArgumentParser) -> None:
    from ..friction import MODEL_NAMES

    p.epilog = EXIT_CODES_TEXT
    p.add_argument("log", nargs="?", metavar="LOG.toml", help="experiment in the shared format (motor side)")
    p.add_argument("--csv", metavar="FILE", help="instead: a plain CSV of a rigid axis (with the column options)")
    p.add_argument("--time", metavar="COL", help="--csv: time column [s]")
    p.add_argument("--position", metavar="COL", help="--csv: position column [rad or m]")
    p.add_argument("--force", metavar="COL", help="--csv: force/torque column [N m or N]")
    p.add_argument("--rate-hz", type=_float_range, help="--csv: declared sample rate [Hz]")
    p.add_argument("--scale-force", type=_float_range, default=1.0, help="--csv: factor on the force column")
    p.add_argument("--model", default="extended-sfm", choices=MODEL_NAMES)
    p.add_argument("--harmonics", type=int, help="angle harmonics N (default 4 where they apply)")
    p.add_argument("--estimate-inertia", action="store_true", help="fit the inertia instead of the nominal J_m")
    p.add_argument("--offset", action=argparse.BooleanOptionalAction, default=None,
                   help="fit a constant offset term (default: when tau_s is a torque sensor's measurement)")
    p.add_argument("--holdout", type=_float_range, default=0.3, help="fraction held out for fit %% (default 0.3)")
    p.add_argument("--select-samples", choices=("auto", "on", "off"), default="auto",
                   help="leave stops and reversals out of static fits: auto (when the log stops, default), "
                        "on, off (plain IDIM on every sample; the log must still slide enough)")
    p.add_argument("--validate", metavar="FILE", help="second log (same kind and column mapping) to cross-test")
    p.add_argument("--json", metavar="OUT", nargs="?", const="-", help="write the fit as JSON to OUT (or stdout)")
    p.add_argument("--plot", metavar="OUT.png", help="measured vs estimated friction (like the paper's Fig. 9)")


def _load_log(path: str, args: argparse.Namespace):
    from ..limits import limit_of

    limit = limit_of("log_samples_identify")
    if args.csv is not None:
        from ..friction import load_axis_csv

        missing = [opt for opt in ("time", "position", "force") if getattr(args, opt) is None]
        if missing:
            from ..errors import ParameterError

            raise ParameterError(f"--csv needs --{', --'.join(missing)} (the column names)", name=missing[0])
        return load_axis_csv(path, time=args.time, position=args.position, force=args.force,
                             rate_hz=args.rate_hz, scale_force=args.scale_force, max_samples=limit)
    from ..experiment import load_experiment

    return load_experiment(path, max_samples=limit, reader="identify")


def _not_identifiable(args: argparse.Namespace, log, exc) -> int:
    """Write the answer "not identifiable" (JSON with every parameter's status and the reasons); exit 3."""
    from ..errors import EXIT_NOT_IDENTIFIABLE
    from ..friction.results import not_identifiable_mapping
    from ..friction.source import friction_log
    from ..friction.terms import friction_model
    from ..friction.tau_s import tau_s_zero_offset

    offset = tau_s_zero_offset(log) if args.offset is None else args.offset
    estimate = args.estimate_inertia or friction_log(log).inertia is None
    model = friction_model(args.model, harmonics=args.harmonics, offset=offset, estimate_inertia=estimate)
    mapping = not_identifiable_mapping(model, exc)
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        print(f"model {mapping['model']}: {mapping['identifiability']}")
    for name in mapping["not_identified"]:
        print(f"forecast-design: warning: {name} not identified (not_identifiable): {mapping['reasons'][0]}",
              file=sys.stderr)
    return EXIT_NOT_IDENTIFIABLE


@_command("identify", "identify friction from a log by least squares (casadi), SFM to LuGre", _configure_identify)
def _cmd_identify(args: argparse.Namespace) -> int:
    from ..errors import EXIT_NOT_IDENTIFIABLE, IdentifiabilityError, ParameterError
    from ..friction import identify

    if (args.log is None) == (args.csv is None):
        raise ParameterError("give exactly one of LOG.toml or --csv FILE", name="log")
    log = _load_log(args.csv if args.csv is not None else args.log, args)
    validation = _load_log(args.validate, args) if args.validate else None
    try:
        fit = identify(log, args.model, harmonics=args.harmonics, offset=args.offset,
                       estimate_inertia=args.estimate_inertia, holdout=args.holdout, validation_log=validation,
                       selection=args.select_samples)
    except IdentifiabilityError as exc:
        return _not_identifiable(args, log, exc)
    if args.plot:
        from ..friction import fit_data
        from ..plotting.friction import plot_friction_fit

        plot_friction_fit(fit, fit_data(fit, log), args.plot, prismatic=getattr(log, "prismatic", False))
    mapping = fit.to_mapping()
    from ..friction.logs import axis_units, parameter_unit    # units follow the log: N, m for a prismatic axis

    prismatic = getattr(log, "prismatic", False)
    mapping["units"] = {name: parameter_unit(name, prismatic) for name in mapping["params"]}
    # the log's scales in the axis' units too (a linear axis: N and m, though the keys say torque and angle)
    u = axis_units(prismatic)
    mapping["scale_units"] = {"torque_max": u["force"], "speed_max": u["velocity"], "speed_p99": u["velocity"],
                              "deflection_max": u["position"], "angle_span": u["position"], "rate_hz": "Hz",
                              "duration_s": "s", "encoder_step": u["position"]}
    not_identifiable = mapping["identifiability"].startswith("not identifiable")
    mapping["exit_code"] = EXIT_NOT_IDENTIFIABLE if not_identifiable else 0
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        sel = mapping["selection"]
        used = (f", {mapping['n_samples_used']} of {mapping['n_samples']} samples (stops and reversals left out)"
                if sel and sel["applied"] else "")
        print(f"model {mapping['model']}: fit {mapping['fit_percent']['estimation']:.2f} % (estimation), "
              f"{mapping['fit_percent']['holdout']:.2f} % (hold-out), condition number "
              f"{mapping['condition_number']:.4g}{used}")
        for name, value in mapping["params"].items():
            std = mapping["std"].get(name)
            shown = f"+- {std:.3g}" if std is not None else "(no interval)"
            status = mapping["status"][name]["status"]
            print(f"  {name:<20} {value: .6g}  {shown} {mapping['units'][name]}"
                  + ("" if status == "identified" else f"  [{status}]"))
        if "validation" in mapping:
            print(f"validation: relative error {mapping['validation']['relative_error_percent']:.3f} %")
        if mapping["identifiability"] != "identified":
            print(mapping["identifiability"])
    # One warning per number that is not an estimate; exit 3 when the log identifies no friction parameter.
    for name in mapping["not_identified"]:
        st = mapping["status"][name]
        print(f"forecast-design: warning: {name} not identified ({st['status']}): {st.get('reason', '')}",
              file=sys.stderr)
    return mapping["exit_code"]
