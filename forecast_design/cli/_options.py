"""Options shared by the verbs: environments, testbed, compensator with identified friction, JSON, skew.

One spelling per concept (README, "Interface conventions"); the older spellings are aliases.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

__all__: list[str] = []


def _float_range(text: str) -> float:
    """A number option's value (argparse ``type``): a finite or infinite float, never NaN; the message
    names the value, not this function."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if value != value:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}")
    return value


#: How the verbs spell a controller (forecast_design.controllers.parse_controller).
CONTROLLER_FORMS = ("pd:P:D[:T_f], pid:P:I:D[:T_f], tf:NUM/DEN or discrete:NUM/DEN (comma-separated "
                    "coefficients, descending powers), other:NAME, with :key=value for the kind's other keys "
                    "(e.g. pd:5:0.1:0.0008:discretization=tustin, pid:8:160:0:u_min=-2:u_max=2:anti_windup=clamping), "
                    "a TOML file with a [controller] table, or a controller written as code: FILE.c, FILE.py:Class "
                    "or module:Class (docs/controllers-as-code.md)")


def _add_controller_option(p: argparse.ArgumentParser, *, default: str = "pd:5:0.1") -> None:
    """The one spelling of ``--controller`` (any kind; default the paper's PD)."""
    p.add_argument("--controller", default=None, metavar="SPEC",
                   help=f"force controller (default {default}, the paper's): {CONTROLLER_FORMS}")


def _controller_from_args(args: argparse.Namespace, default: str = "pd:5:0.1"):
    """The controller the verb runs, resolved once here (the boundary); ``--method`` (export, pil)
    sets its discretization."""
    import dataclasses

    from ..controllers import LinearController, resolve_controller
    from ..errors import ParameterError

    controller = resolve_controller(getattr(args, "controller", None) or default)
    method = getattr(args, "method", None)
    if method is not None:
        if not isinstance(controller, LinearController) or not controller.is_continuous:
            raise ParameterError(f"--method sets a continuous controller's discretization; {controller.spelling()} "
                                 "has none", name="method", value=method)
        controller = dataclasses.replace(controller, discretization=method)
    return controller


_ENV_HELP = ("environment: a preset (soft), inline values (k_e=20,J_e=0.02[,d_e=..][,locked=true]), "
             "a TOML file (one or a set, docs/environments.md) or a comma list of presets")


def _add_environment_options(p: argparse.ArgumentParser, *, default: str, many: bool,
                             believed: bool = False, testbed: bool = True) -> None:
    """The one spelling of the environment/testbed options (``--env``, alias ``--envs``; ``--testbed``;
    ``--experiment RUN.toml``). ``many``: the verb takes a set (repeat or give a file); else exactly one."""
    what = "environment set" if many else "the environment (exactly one)"
    p.add_argument("--env", "--envs", dest="env", action="append", metavar="SPEC",
                   help=f"{what}; {_ENV_HELP}; repeatable (default {default})")
    p.set_defaults(env_default=default)
    if testbed:
        p.add_argument("--testbed", metavar="SPEC",
                       help="testbed: inline (k=40[,J_m=..][,d_m=..][,J_l=..,d_l=..]) or a TOML file with "
                            "[testbed]; its link J_l, d_l is the default of every environment (default: the "
                            "paper's Table 1)")
        p.add_argument("--experiment", metavar="RUN.toml",
                       help="take testbed and environment from a log's TOML (its CSV is not read)")
    if believed:
        p.add_argument("--believed", metavar="SPEC",
                       help="environment the observer believes in (same forms as --env; default: the true one)")


def _note(notes) -> None:
    for note in notes:
        print(f"forecast-design: note: {note}", file=sys.stderr)


def _experiment_from_args(args: argparse.Namespace, *conflicting: str) -> str | None:
    """The --experiment file, checked: it exists and none of the options ``conflicting`` is given beside it."""
    experiment = getattr(args, "experiment", None)
    if experiment and any(getattr(args, name, None) for name in conflicting):
        from ..errors import ParameterError

        raise ParameterError("give --experiment or --env/--testbed, not both (the log's TOML holds its testbed "
                             "and environment)", name="experiment")
    if experiment and not os.path.isfile(experiment):
        from ..errors import ExperimentFormatError

        raise ExperimentFormatError(f"{experiment}: experiment file not found", path=experiment)
    return experiment


def _testbed_from_args(args: argparse.Namespace):
    """The testbed of --testbed / --experiment (Table 1 when neither is given)."""
    from ..environments import resolve_testbed

    experiment = _experiment_from_args(args, "testbed", "env")
    spec = experiment or getattr(args, "testbed", None)
    if spec is None:
        from ..environments import testbed_of_environment_files

        found = testbed_of_environment_files(getattr(args, "env", None))
        if found is not None:      # the file describes the SEA once: its [testbed], not Table 1's
            _note_once(args, f"testbed from {found[1]}'s [testbed] (no --testbed given)")
            return found[0]
    return resolve_testbed(spec)


def _note_once(args: argparse.Namespace, text: str) -> None:
    """One ``forecast-design: note:`` line per invocation for ``text``."""
    said = getattr(args, "_notes_said", None)
    if said is None:
        said = set()
        setattr(args, "_notes_said", said)
    if text not in said:
        said.add(text)
        _note([text])


def _environments_from_args(args: argparse.Namespace, *, seed: int = 0):
    """The EnvironmentSet of --env/--envs (repeats concatenated) or --experiment; notes go to stderr."""
    from ..environments import resolve_environments

    specs = getattr(args, "env", None)
    experiment = _experiment_from_args(args, "env")
    envset = resolve_environments(experiment or specs or args.env_default,
                                  testbed=_testbed_from_args(args), seed=seed)
    _note(envset.notes)
    return envset


def _one_environment_from_args(args: argparse.Namespace, what: str):
    """(name, Environment) of a verb that takes exactly one environment (a set is an error, never the last)."""
    return _environments_from_args(args).single(f"{what} (--env)")


def _design_from_args(args: argparse.Namespace, *, env_name: str | None = None):
    """The one design named by --experiment or --env/--testbed (``env_name`` overrides --env)."""
    from ..environments import resolve_environments
    from ..params import Design

    testbed = _testbed_from_args(args)
    if env_name is not None:
        env = resolve_environments(env_name, testbed=testbed).single(f"environment {env_name!r}")[1]
    else:
        env = _one_environment_from_args(args, "this command")[1]
    return Design(testbed=testbed, environment=env)


def _add_json_option(p: argparse.ArgumentParser, what: str = "the result") -> None:
    """``--json [FILE]``, the same in every verb: FILE, or stdout with no FILE or '-'."""
    p.add_argument("--json", metavar="FILE", nargs="?", const="-",
                   help=f"write {what} as JSON to FILE (stdout with no FILE or '-')")


def _json_positional(args: argparse.Namespace, name: str, suffix: str = ".toml") -> None:
    """``VERB --json RUN.toml`` (the old flag form) read RUN.toml as the JSON target: give it back."""
    if getattr(args, name) is None and args.json not in (None, "-") and args.json.endswith(suffix):
        setattr(args, name, args.json)
        args.json = "-"
    if getattr(args, name) is None:
        from ..errors import ParameterError

        raise ParameterError(f"missing the {name.upper()}{suffix} argument", name=name)


_FRICTION_MODELS = ("sfm", "extended-sfm")
FRICTION_MAX_BYTES = 2**20   # an identify --json file is a few kB


def _friction_from_file(path: str, allow_unidentified: bool = False) -> dict[str, float]:
    """The identified friction of an ``identify --json F.json`` file, for an SFM compensator.

    Only the SFM-shaped laws (viscous, coulomb, offset, angle harmonics) drive the SFM feed-forward;
    a fitted inertia is not friction and is left out (with a note). A file whose fit says a number is
    not identified (``not_identified``, ``identified: false``, a "not identifiable" or "model
    inadequate" verdict) is refused unless ``allow_unidentified`` (``--allow-unidentified``).
    """
    from ..errors import ExperimentFormatError
    from ..experiment_io import read_regular_file

    raw = read_regular_file(path, path, not_found=f"{path}: friction file not found (write it with identify --json)",
                            error_path=path, max_bytes=FRICTION_MAX_BYTES, what="friction file")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ExperimentFormatError(f"{path}: not an identify --json file: {str(exc).splitlines()[0]}",
                                    path=path) from None
    params = doc.get("params") if isinstance(doc, dict) else None
    if not isinstance(params, dict) or not params:
        raise ExperimentFormatError(f"{path}: no 'params' object (expected the output of identify --json)",
                                    path=path, key="params")
    model = doc.get("model")
    if model not in _FRICTION_MODELS:
        raise ExperimentFormatError(f"{path}: model {model!r} cannot drive the SFM compensator; identify with "
                                    f"--model {' or --model '.join(_FRICTION_MODELS)}", path=path, key="model")
    lost = list(doc.get("not_identified") or ())
    verdict = str(doc.get("identifiability") or "")
    if lost or doc.get("identified") is False or verdict.startswith(("not identifiable", "model inadequate")):
        shown = ", ".join(f"{n} ({(doc.get('status') or {}).get(n, {}).get('status', 'not identified')})"
                          for n in lost) or verdict
        if not allow_unidentified:
            raise ExperimentFormatError(
                f"{path}: the friction is not identified ({shown}): a compensator on numbers the log did not "
                "determine is not written; identify a model the log identifies, or pass --allow-unidentified to "
                "use the values as they are", path=path, key="not_identified")
        print(f"forecast-design: warning: {path}: --allow-unidentified: using friction that is not identified "
              f"({shown}) as it is", file=sys.stderr)
    if "inertia" in params:
        _note([f"{path}: the fitted inertia is not friction; the SFM compensator leaves it out"])
    return {k: v for k, v in params.items() if k != "inertia"}


def _compensator_from_args(args: argparse.Namespace):
    """The Compensator of --compensator/--w-q-hz (and --friction for sfm), or None for 'none'."""
    from ..errors import ParameterError
    from ..params import Compensator

    friction = getattr(args, "friction", None)
    if friction and args.compensator != "sfm":
        raise ParameterError(f"--friction applies to --compensator sfm, not {args.compensator!r}", name="friction")
    if args.compensator == "sfm" and not friction:
        raise ParameterError("--compensator sfm needs --friction F.json (from identify --model sfm --json F.json)",
                             name="friction")
    if args.compensator == "none":
        return None
    return Compensator(kind=args.compensator, w_q_hz=args.w_q_hz,
                       friction=_friction_from_file(friction, getattr(args, "allow_unidentified", False))
                       if friction else ())


def _add_allow_unidentified(p: argparse.ArgumentParser) -> None:
    """``--allow-unidentified``: use a --friction file whose numbers are not all identified."""
    p.add_argument("--allow-unidentified", action="store_true",
                   help="with --friction: use friction that identify did not report identified (default: refuse)")


def _check_sfm_loop(design, friction, controller=None, rate_hz: float = 2000.0) -> None:
    """Refuse, in one line, an SFM feed-forward that makes the sampled force loop unstable."""
    from ..analysis import sfm_loop_check
    from ..errors import ParameterError

    check = sfm_loop_check(design, friction, controller=controller, rate_hz=rate_hz)
    if not check.stable:
        raise ParameterError(f"{check.message()}; no code or run is produced for it", name="friction",
                             value=check.viscous)


def _add_skew_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--skew", "--sigma", dest="sigma", type=_float_range, default=0.0, metavar="SKEW",
                   help="disk skew sigma (python-control/MATLAB 'skew'; 0 balanced, the paper's)")


# --- inputs that an output must not replace ------------------------------------------------------------------------

_INPUT_OPTIONS = ("experiment", "log", "scenario", "csv", "validate", "friction", "testbed", "believed", "envs")
_RUN_OUT_VERBS = ("simulate", "run", "pil")     # --out names an experiment TOML; its CSV goes beside it


def _experiment_data(path: str) -> str | None:
    """The CSV an experiment TOML names, or None (not an experiment, or unreadable: the verb says why)."""
    from pathlib import Path

    from ..errors import ForecastError
    from ..experiment_io import FORMAT, read_toml

    try:
        doc, _ = read_toml(Path(path))
    except ForecastError:
        return None
    data = doc.get("data")
    if doc.get("format") != FORMAT or not isinstance(data, str) or "\x00" in data:
        return None
    return str(Path(path).parent / data)


def _controller_files(spellings) -> list[str]:
    """The files controllers written as code name (``FILE.c``, ``FILE.py:Class``): inputs of the verb."""
    if spellings is None:
        return []
    out = []
    for text in [spellings] if isinstance(spellings, str) else spellings:
        for part in str(text).split(","):
            if part.endswith(".c"):
                out.append(part)
            elif ".py:" in part:
                out.append(part.rsplit(":", 1)[0])
    return out


def _refuse_inputs_as_outputs(args: argparse.Namespace) -> None:
    """Before any work: no --json, --plot or --out file may be a file the command reads.

    The inputs are every file an option names (an experiment TOML with its CSV, a scenario,
    friction, environment and testbed files); the outputs every file the verb will write under
    its own name (``fileio.refuse_overwriting`` compares what they resolve to). Files a verb
    finds only while it runs are guarded when written (``fileio.guard_inputs``).
    """
    from ..fileio import refuse_overwriting

    named = [getattr(args, name, None) for name in _INPUT_OPTIONS]
    named += list(getattr(args, "env", None) or ())
    named += _controller_files(getattr(args, "controller", None))
    inputs = [v for v in named if isinstance(v, str) and v and os.path.isfile(v)]
    inputs += [csv for csv in map(_experiment_data, [v for v in inputs if v.endswith(".toml")]) if csv]
    outputs = [getattr(args, "json", None), getattr(args, "plot", None)]
    out = getattr(args, "out", None)
    if getattr(args, "command", None) in _RUN_OUT_VERBS and isinstance(out, str) and out:
        from pathlib import Path

        toml = Path(out)
        outputs += [toml, toml.with_suffix(".csv"), toml.with_name(toml.stem + ".truth.json"),
                    toml.with_name(toml.stem + ".truth.csv")]
    refuse_overwriting([o for o in outputs if o], inputs)

