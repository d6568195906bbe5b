"""Fuzz every verb and every public function with hostile arguments (issue 14, docs/reliability.md).

Each CLI case runs in-process through ``forecast_design.cli.main`` under the harness of
``test_reliability.py`` (a hard wall-clock bound per case and a bound on resident-memory growth). The
properties, over derandomised hypothesis examples:

* the exit code is 0, 1 or 2;
* exit 2 prints exactly one line on stderr, ``forecast-design: error: ...``, and no traceback;
* an exit-0 run prints no ``NaN``/``Infinity`` token (its ``--json -`` output is strict JSON);
* a public Python function raises a ``ForecastError`` (or a documented ``TypeError``/``ValueError``),
  never an ``AttributeError``, ``ZeroDivisionError``, ``KeyError`` or ``IndexError``.

Verbs that would serve, upload or run a long job are cut where their work starts (``emulate``'s server,
``run`` on a port that does not exist, ``pil``'s qemu, the executors of ``benchmark`` and
``bench-gap``, ``export --check-arm``'s toolchain): every argument check before that point runs for real.
"""

import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from test_reliability import CASE_SECONDS, assert_one_line_error, cli, memory_bound, time_bound, write_experiment

import forecast_design
from forecast_design.cli import build_parser
from forecast_design.errors import ForecastError

FUZZ = settings(derandomize=True, max_examples=25, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

#: Values any option may receive from a hostile user: numbers at and beyond every edge, malformed
#: specs, paths of the wrong kind (all relative: the cases run in a temporary folder).
HOSTILE = ["nan", "inf", "-inf", "-1", "0", "1e-300", "1e300", "1e309", "-0.0", "5_2", "0x10", "", "abc",
           "123456789012345678901234567890", "random:0", "random:-1", "random:100000000", "k=nan",
           "k_e=-1,J_e=0", "J_m=1e308", "pd:nan:1", "pd:1e300:0", "square:nan:1", "sine:1:0", "step:1e300",
           "ea-fob:nan", ":", "::::", ".", "missing.toml", "run.csv", "run.toml", "s.toml", "sub/x.toml",
           "x.xyz", "out.png", "seed:-1", "disconnect:-3", "flip:2",
           # issue 23: files of the wrong kind or size, nested and limit-breaking files, unusable addresses
           "fifo.toml", "dir.toml", "loop.toml", "dangling.json", "deep.toml", "big.toml", "nullog.toml", "bom.toml",
           "crc.toml", "grid.toml", "reps.toml", "nyquist.toml", "dev", "tcp://127.0.0.1", "http://x", "pd:5_0:0",
           "/proc/self/fd/1", "all", "1000000000"]
#: The special nodes of the work folder: no case may turn one into something else (issue 23).
NODES = {"fifo.toml": "fifo", "dir.toml": "dir", "loop.toml": "link", "dangling.json": "link", "dev": "char"}

#: Options never fuzzed: they only print help/version.
SKIP_OPTIONS = {"-h", "--help"}

_NAN_TOKEN = re.compile(r"\b(NaN|-?Infinity)\b")


class _Reached(ForecastError):
    """Raised by a stub where a verb's real work would start: the arguments passed every check."""


def _reached(*args, **kwargs):
    raise _Reached("arguments accepted (stub)")


def _verb_options(verb):
    """(option string, nargs, choices, takes a value) of every option of ``verb``, from the parser itself."""
    sub = build_parser()._subparsers._group_actions[0].choices[verb]  # noqa: SLF001 - no public API
    out = []
    for action in sub._actions:  # noqa: SLF001
        if not action.option_strings or set(action.option_strings) & SKIP_OPTIONS:
            continue
        takes = action.nargs != 0
        out.append((action.option_strings[-1], action.nargs, tuple(action.choices or ()), takes))
    return out


def _mutation(verb):
    """A strategy of one hostile option (its argv fragment) of ``verb``."""
    @st.composite
    def draw(pick):
        option, nargs, choices, takes = pick(st.sampled_from(_verb_options(verb)))
        if not takes:
            return [option]
        pool = st.sampled_from(list(choices) + ["bogus"]) if choices else st.sampled_from(HOSTILE)
        if nargs == "?":
            return pick(st.sampled_from([[option], None])) or [option, pick(pool)]
        count = nargs if isinstance(nargs, int) else 1
        return [option] + [pick(pool) for _ in range(count)]
    return draw()


def _has_json(verb):
    return any(opt == "--json" for opt, *_ in _verb_options(verb))


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A temporary working folder with a short experiment, a plain CSV axis log and a short scenario."""
    monkeypatch.chdir(tmp_path)
    write_experiment(tmp_path, "run")
    t = np.arange(3000) / 1000.0
    x = 0.5 * np.sin(2 * np.pi * 0.7 * t)
    f = 2.0 * np.tanh(np.gradient(x, t) / 0.01) + 0.3 * np.gradient(x, t)
    (tmp_path / "axis.csv").write_text("t,x,f\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t, x, f)))
    from importlib import resources

    text = (resources.files("forecast_design") / "data" / "example_scenario.toml").read_text()
    (tmp_path / "s.toml").write_text(re.sub(r"(?m)^duration_s = .*$", "duration_s = 0.2", text))
    # cut the verbs where their real work would start (see the module docstring)
    import forecast_design.executor
    import forecast_design.export.toolchain
    import forecast_design.gap.bench
    import forecast_design.runtime
    import forecast_design.runtime.pil

    monkeypatch.setattr(forecast_design.runtime, "emulate", _reached)
    monkeypatch.setattr(forecast_design.runtime.pil, "qemu_available", lambda: "qemu stubbed by the test")
    monkeypatch.setattr(forecast_design.executor, "make_executor", _reached)
    monkeypatch.setattr(forecast_design.gap.bench, "make_executor", _reached)
    monkeypatch.setattr(forecast_design.export.toolchain, "check_on_cortex_m4", _reached)
    import forecast_design.export.firmware

    monkeypatch.setattr(forecast_design.export.firmware, "build_firmware", _reached)   # export --firmware --check-arm
    _hostile_files(tmp_path, text, monkeypatch)
    return tmp_path


def _hostile_files(folder, scenario_text, monkeypatch):
    """Issue 23's hostile inputs and outputs in the work folder (no test touches the real /dev)."""
    import os
    import stat

    import forecast_design.fileio

    monkeypatch.setattr(forecast_design.fileio, "FIFO_WAIT_S", 0.2)    # a FIFO nobody reads: one line, at once
    os.mkfifo(folder / "fifo.toml")
    (folder / "dir.toml").mkdir()
    os.symlink("loop.toml", folder / "loop.toml")
    os.symlink("nowhere/x.json", folder / "dangling.json")
    if os.geteuid() == 0:
        os.mknod(folder / "dev", stat.S_IFCHR | 0o666, os.makedev(1, 3))   # a null device, made here
    else:
        os.mkfifo(folder / "dev")
        NODES["dev"] = "fifo"
    (folder / "deep.toml").write_text("x = " + "[" * 1000 + "]" * 1000 + "\n")
    with open(folder / "big.toml", "wb") as fh:
        fh.truncate(2**30)                                   # sparse: refused before it is read
    write_experiment(folder, "nullog")
    (folder / "nullog.csv").write_bytes(b"\x00" * 4096)
    (folder / "bom.toml").write_bytes(b"\xef\xbb\xbf" + (folder / "run.toml").read_bytes())
    (folder / "crc.toml").write_text((folder / "run.toml").read_text() + "# data-crc32 = zz, data-bytes = 1\n")
    (folder / "grid.toml").write_text("[environment]\nk_e = {log = [0.1, 100], n = 100}\n"
                                      "J_e = {log = [0.001, 1], n = 100}\nd_e = {lin = [0.0, 1.0], n = 100}\n")
    (folder / "reps.toml").write_text(scenario_text.replace("[truth]", "[variability]\nrepetitions = 1000000000\n"
                                                                       "\n[truth]", 1))
    (folder / "nyquist.toml").write_text(scenario_text.replace("w_q_hz = 10.0", "w_q_hz = 1500.0", 1))


def _kind(path):
    import os
    import stat

    info = os.lstat(path)
    return ("link" if stat.S_ISLNK(info.st_mode) else "fifo" if stat.S_ISFIFO(info.st_mode)
            else "dir" if stat.S_ISDIR(info.st_mode) else "char" if stat.S_ISCHR(info.st_mode) else "file")


#: Options whose value a verb writes (everything else named in a command line is read, or not a file).
OUTPUT_OPTIONS = ("--out", "--json", "--plot", "--report", "--work-dir")


def _read_files(argv, folder):
    """Regular files of the work folder a command line names as inputs (with an experiment TOML's CSV)."""
    outputs = {argv[i + 1] for i, a in enumerate(argv[:-1]) if a in OUTPUT_OPTIONS}
    named = [a for a in argv if a not in outputs and (folder / a).is_file() and not (folder / a).is_symlink()]
    csvs = {a[:-5] + ".csv" for a in named if a.endswith(".toml")}
    return set(named) | {c for c in csvs if (folder / c).exists()}


def _snapshot(folder):
    import hashlib

    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir()
            if p.is_file() and not p.is_symlink() and p.stat().st_size < 2**20}


#: A valid starting point per verb; the fuzz adds hostile options to it.
BASE = {
    "check": ["check", "run.toml"],
    "identify": ["identify", "run.toml", "--model", "sfm", "--select-samples", "off"],
    "identify-csv": ["identify", "--csv", "axis.csv", "--time", "t", "--position", "x", "--force", "f",
                     "--model", "sfm", "--select-samples", "off"],
    "simulate": ["simulate", "s.toml", "--out", "sim/out.toml"],
    "export": ["export", "--out", "c"],
    "emulate": ["emulate"],
    "run": ["run", "--port", "no-such-port", "--out", "rec.toml", "--duration", "0.1"],
    "diagnose": ["diagnose", "run.toml"],
    "bench-gap": ["bench-gap", "--per-effect", "1", "--duration", "1"],
    "tf": ["tf"],
    "margins": ["margins", "--observer", "ea-fob"],
    "tune-q": ["tune-q", "--observer", "ea-fob", "--envs", "soft"],
    "reproduce": ["reproduce", "fig6"],
    "benchmark": ["benchmark", "--out", "bench"],
    "pil": ["pil", "--out", "pil.toml"],
}
#: Verbs whose valid runs take about a second or more: fewer examples.
SLOW_VERBS = {"identify", "identify-csv", "diagnose", "simulate", "tune-q"}


def check_properties(argv, code, out, err):
    """The properties every CLI case must have (see the module docstring)."""
    # 3: identify's answer "not identifiable" (issue 25), an answer with its JSON, never another verb's
    assert code in (0, 1, 2) or (code == 3 and argv[0] == "identify"), (argv, code, err)
    assert "Traceback" not in err, (argv, err)
    if code == 2:
        assert_one_line_error(code, err)
        assert err.startswith("forecast-design: error: "), (argv, err)
    if code in (0, 1, 3):   # a numeric warning (overflow, invalid value) on a path that answers is a missing check
        assert "RuntimeWarning" not in err, (argv, err)
    if code in (0, 3):
        assert not _NAN_TOKEN.search(out), (argv, out[:500])
        if "--json" in argv and argv[argv.index("--json") + 1:argv.index("--json") + 2] in ([], ["-"]) \
                and out.strip().startswith(("{", "[")):
            json.loads(out, parse_constant=lambda token: pytest.fail(f"{argv}: {token} in JSON"))


def _fuzz_verb(verb, data, capsys, folder=None):
    from pathlib import Path

    folder = Path.cwd() if folder is None else folder
    argv = list(BASE[verb])
    for _ in range(data.draw(st.integers(1, 2), label="mutations")):
        argv += data.draw(_mutation(argv[0]), label="option")
    if _has_json(argv[0]) and data.draw(st.booleans(), label="json"):
        argv += ["--json", "-"]
    before, inputs = _snapshot(folder), _read_files(argv, folder)
    code, out, err = cli(argv, capsys)
    check_properties(argv, code, out, err)
    # nothing the user points at is destroyed: special nodes keep their kind, read files keep their bytes
    for name, kind in NODES.items():
        assert _kind(folder / name) == kind, (argv, name)
    after = _snapshot(folder)
    changed = {name for name in inputs if before.get(name) != after.get(name)}
    assert not changed, (argv, changed)
    return code, err


@pytest.mark.parametrize("verb", sorted(set(BASE) - SLOW_VERBS))
@FUZZ
@given(data=st.data())
def test_fuzz_fast_verbs(verb, data, workdir, capsys):
    _fuzz_verb(verb, data, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("verb", sorted(SLOW_VERBS))
@settings(FUZZ, max_examples=8)
@given(data=st.data())
def test_fuzz_slow_verbs(verb, data, workdir, capsys):
    _fuzz_verb(verb, data, capsys)


# --- the public Python functions (forecast_design.__all__) with hostile arguments ---------------------------------

#: Hostile argument values: wrong types, NaN, infinities, huge, negative, empty.
HOSTILE_VALUES = [None, "", "x", -1, 0, -1.0, math.nan, math.inf, -math.inf, 1e300, 1e-300, True, [], {}, (),
                  object(), np.array([]), np.array([np.nan]), np.float32("nan"), 1j, 2 ** 70, b"\x00\xff"]
#: What a public function may raise on bad input (ForecastError subclasses are also ValueError/RuntimeError).
ALLOWED = (ForecastError, TypeError, ValueError)
#: Never acceptable: the signs of a missing check.
FORBIDDEN = (AttributeError, ZeroDivisionError, KeyError, IndexError)


def _baselines(folder):
    """A valid call of every public function: name -> (function, keyword arguments)."""
    from forecast_design import (Compensator, Design, Environment, EnvironmentSet, Signals, environment_preset,
                                 experiment_from_arrays, load_experiment)
    from forecast_design.loops import force_loop

    exp = load_experiment(write_experiment(folder, "base"))
    s = exp.signals
    soft = Design.nominal("soft")
    arrays = dict(t=s.t, tau_m=s.tau_m, theta=s.theta, q=s.q)
    return {
        "RationalTF": (forecast_design.RationalTF, dict(num=(1.0,), den=(1.0, 1.0))),
        "Testbed": (forecast_design.Testbed, {}),
        "Environment": (Environment, dict(J_e=0.001, d_e=0.06, k_e=5.0)),
        "PD": (forecast_design.PD, {}),
        "PID": (forecast_design.PID, dict(P=6.0, I=20.0, D=0.05, T_f=0.002)),
        "TFController": (forecast_design.TFController, dict(num=(0.5, 10.0), den=(0.01, 1.0))),
        "DiscreteController": (forecast_design.DiscreteController, dict(num=(5.2, -5.1), den=(1.0, -1.0))),
        "OtherController": (forecast_design.OtherController, dict(name="adaptive")),
        "parse_controller": (forecast_design.parse_controller, dict(text="pid:6:20:0.05:0.002")),
        "resolve_controller": (forecast_design.resolve_controller, dict(spec="pd:5:0.1")),
        "analyse_loop": (forecast_design.analyse_loop, dict(design=soft, compensator="ea-fob",
                                                             controller="pid:6:20:0.05:0.002")),
        "analyse_passivity": (forecast_design.analyse_passivity, dict(design=soft, compensator="ea-fob",
                                                                       controller="pid:6:20:0.05:0.002")),
        "Compensator": (Compensator, dict(kind="ea-fob")),
        "Design": (Design, {}),
        "environment_preset": (environment_preset, dict(name="soft")),
        "EnvironmentSet": (EnvironmentSet, dict(names=("a",), environments=(environment_preset("soft"),))),
        "resolve_environments": (forecast_design.resolve_environments, dict(spec="soft")),
        "resolve_testbed": (forecast_design.resolve_testbed, dict(spec="k=40")),
        "Effect": (forecast_design.Effect, dict(value="cogging")),
        "Experiment": (forecast_design.Experiment, dict(design=exp.design, rate_hz=exp.rate_hz, signals=s)),
        "Signals": (Signals, arrays),
        "load_experiment": (load_experiment, dict(path="base.toml")),
        "save_experiment": (forecast_design.save_experiment, dict(experiment=exp, path="saved/x.toml")),
        "experiment_from_arrays": (experiment_from_arrays, dict(design=exp.design, rate_hz=exp.rate_hz, **arrays)),
        "transfer_functions": (forecast_design.transfer_functions, dict(design="soft")),
        "force_loop": (force_loop, dict(true_design=soft, compensator=Compensator(kind="ea-fob"))),
        "disk_margin": (forecast_design.disk_margin, dict(L=force_loop(soft).L)),
        "loop_margins": (forecast_design.loop_margins, dict(design=soft, compensator="ea-fob")),
        "fig6_table": (forecast_design.fig6_table, dict(environments=("soft",), w_q_hz=(5.0,),
                                                         observers=("ea-fob",))),
        "tune_q": (forecast_design.tune_q, dict(observer="ea-fob", envs="soft")),
        "identify": (forecast_design.identify, dict(log=exp, model="sfm", selection="off")),
        "fit_friction": (forecast_design.fit_friction, dict(t=s.t, position=s.theta, force=s.tau_m, model="sfm",
                                                             selection="off")),
        "simulate": (forecast_design.simulate, dict(design=Design.nominal("exp-soft"), reference=[0.1],
                                                     duration_s=0.05)),
        "diagnose": (forecast_design.diagnose, dict(experiment=exp)),
        "export_controller": (forecast_design.export_controller, dict(out_dir="c", env="soft")),
    }


_NAMES = ["RationalTF", "Testbed", "Environment", "PD", "PID", "TFController", "DiscreteController",
          "OtherController", "parse_controller", "resolve_controller", "analyse_loop", "analyse_passivity", "Compensator", "Design", "environment_preset",
          "EnvironmentSet", "resolve_environments", "resolve_testbed", "Effect", "Experiment", "Signals",
          "load_experiment", "save_experiment", "experiment_from_arrays", "transfer_functions", "force_loop",
          "disk_margin", "loop_margins", "fig6_table", "tune_q", "identify", "fit_friction", "simulate",
          "diagnose", "export_controller"]


def test_the_api_fuzz_covers_every_public_callable():
    callables = {n for n in forecast_design.__all__ if callable(getattr(forecast_design, n))
                 and not (isinstance(getattr(forecast_design, n), type)
                          and issubclass(getattr(forecast_design, n), BaseException))}
    # run_pipeline writes a whole report: fuzzed on its argument types alone, below
    # run_pipeline: above; Controller: the abstract base (its kinds are fuzzed)
    assert callables - {"run_pipeline", "force_loop", "Controller"} <= set(_NAMES), callables - set(_NAMES)


def _call_hostile(name, param, value, folder):
    import inspect

    func, kwargs = _baselines(folder)[name]
    kwargs = dict(kwargs)
    if param is not None:
        kwargs[param] = value
    try:
        with time_bound(CASE_SECONDS), memory_bound():
            result = func(**kwargs)
    except FORBIDDEN as exc:
        pytest.fail(f"{name}({param}={value!r}) raised {type(exc).__name__}: {exc}")
    except ALLOWED as exc:
        if isinstance(exc, ForecastError):
            assert "\n" not in str(exc).strip(), f"{name}: a ForecastError is one line: {exc}"
        return
    except Exception as exc:  # noqa: BLE001 - anything else is a missing check too
        pytest.fail(f"{name}({param}={value!r}) raised {type(exc).__name__}: {exc}")
    mapping = getattr(result, "to_mapping", None)
    if callable(mapping) and not inspect.isclass(result):
        from forecast_design.limits import require_no_nan

        try:
            summary = mapping()
        except ForecastError:
            return   # e.g. an Experiment without a CSV name has no file mapping: not an answer
        require_no_nan(summary, f"{name}({param}={value!r})")


@st.composite
def _hostile_call(pick):
    import inspect

    name = pick(st.sampled_from(_NAMES))
    func = getattr(forecast_design, name, None) or __import__("forecast_design.loops", fromlist=["x"]).force_loop
    try:
        params = [p for p in inspect.signature(func).parameters if p not in ("self", "progress")]
    except ValueError:
        params = []
    params = [p for p in params if inspect.signature(func).parameters[p].kind not in
              (inspect.Parameter.VAR_KEYWORD, inspect.Parameter.VAR_POSITIONAL)]
    param = pick(st.sampled_from(params)) if params else None
    return name, param, pick(st.sampled_from(HOSTILE_VALUES))


@pytest.mark.slow
@settings(FUZZ, max_examples=400)
@given(call=_hostile_call())
def test_fuzz_public_functions_raise_forecast_errors_not_raw_python_errors(call, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _call_hostile(*call, tmp_path)


@pytest.mark.parametrize("value", [1.5, [], object(), b"\x00"])
def test_run_pipeline_refuses_an_out_dir_of_the_wrong_type(value, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with time_bound(CASE_SECONDS), pytest.raises(ALLOWED):
        forecast_design.run_pipeline(value)


# --- diagnose is finite over the plausible ranges (docs/reliability.md, "Numbers") -----------------------------------


def _in_range(name):
    """Log-uniform over the plausible range of ``name`` (zero included where the range starts at 0)."""
    from forecast_design.limits import PHYSICAL_RANGES

    lo, hi, _ = PHYSICAL_RANGES[name]
    inner = st.floats(math.log10(max(lo, 1e-6)), math.log10(hi)).map(lambda e: float(10.0 ** e))
    return st.one_of(inner, inner, inner, st.just(0.0)) if lo == 0.0 else inner   # 0 in about a quarter


def _finite_everywhere(obj, path=""):
    """The first key path holding a NaN or an infinity (None if every number is finite)."""
    if isinstance(obj, dict):
        return next((p for k, v in obj.items() if (p := _finite_everywhere(v, f"{path}.{k}"))), None)
    if isinstance(obj, (list, tuple)):
        return next((p for i, v in enumerate(obj) if (p := _finite_everywhere(v, f"{path}[{i}]"))), None)
    if isinstance(obj, (float, np.floating)) and not math.isfinite(obj):
        return path or "result"
    return None


@pytest.mark.slow
@settings(FUZZ, max_examples=30)
@example(tb={"J_m": 1778.2794100389228, "d_m": 0.0, "k": 0.1},   # once a NaN p-value: no held-out unit
         env={"J_e": 0.0, "d_e": 0.0, "k_e": 0.0, "J_l": 1.0, "d_l": 0.0}, closed=False)
@given(tb=st.fixed_dictionaries({n: _in_range(n) for n in ("J_m", "d_m", "k")}),
       env=st.fixed_dictionaries({n: _in_range(n) for n in ("J_e", "d_e", "k_e", "J_l", "d_l")}),
       closed=st.booleans())
def test_diagnose_is_finite_or_a_one_line_error_for_every_plausible_testbed_and_environment(tb, env, closed):
    """Over PHYSICAL_RANGES, a simulated 1 s log is either refused (one line) or diagnosed with finite numbers.

    The simulator may refuse a design it cannot integrate stably at 2 kHz (a ParameterError naming it);
    whatever it produces, ``diagnose`` answers with a JSON whose every number is finite, or refuses.
    """
    from forecast_design import PD, Design, Environment, Testbed, diagnose, simulate
    from forecast_design.simulation import references as refs

    try:
        design = Design(testbed=Testbed(**tb), environment=Environment(**env),
                        controller=PD() if closed else None)
    except ForecastError as exc:   # E(s) = 0 or an output without inertia: in range, refused with a reason
        assert "\n" not in str(exc)
        event("design refused")
        return
    ref = refs.Multisine(amplitudes=(0.6, 0.4, 0.3), frequencies_hz=(0.7, 2.3, 6.1), phases_rad=(0.0, 1.0, 2.0))
    with time_bound(CASE_SECONDS), memory_bound():
        try:
            experiment = simulate(design, reference=ref, duration_s=1.0, seed=1, closed_loop=closed,
                                  initial_angle=0.3).to_experiment()
            mapping = diagnose(experiment).to_mapping()
        except ForecastError as exc:
            assert "\n" not in str(exc).strip(), str(exc)
            event(f"refused: {type(exc).__name__}")
            return
    event("diagnosed")
    found = _finite_everywhere(mapping)
    assert found is None, f"diagnosis holds a non-finite number at {found} for {tb} {env}"


# --- regressions: each case the fuzz tests found, fixed where the check belongs -------------------------------------


@pytest.mark.parametrize("argv, words", [
    (["export", "--controller", "pd:1e300:0", "--out", "c"], ["P = 1e+300", "plausible range"]),   # params.py
    (["margins", "--controller", "pd:1e300:0"], ["P = 1e+300"]),                                   # was LinAlgError
    (["margins", "--sigma", "1e300"], ["sigma", "[-100, 100]"]),                                    # margins/disk.py
    (["bench-gap", "--per-effect", "100000000000000000"], ["bench-gap logs", "[1, 100000]"]),      # was OOM-killed
    (["benchmark", "--out", "b", "--repetitions", "100000000"], ["repetitions", "[1, 100000]"]),
    (["identify", "run.toml", "--harmonics", "1000000"], ["harmonics", "[1, 64]"]),                # was a hang
    (["identify", "--csv", "", "--time", "t", "--position", "x", "--force", "f"], []),            # was TypeError
    ([], ["give a command"]),                                                                      # was help, exit 2
    (["tune-q", "--observer", "ea-fob", "--q-order", "x"], ["tune-q: argument --q-order"]),       # argparse's prefix
])
def test_fuzz_findings_are_one_line_errors(argv, words, workdir, capsys):
    code, out, err = cli(argv, capsys)
    assert_one_line_error(code, err, *words)
    assert err.startswith("forecast-design: error: ")


def test_export_json_is_strict_json_without_a_torque_limit(workdir, capsys):
    code, out, _ = cli(["export", "--out", "c", "--json", "-"], capsys)
    doc = json.loads(out, parse_constant=lambda token: pytest.fail(f"{token} in export JSON"))
    assert code == 0 and doc["tau_max_N_m"] is None   # no saturation is null


def test_a_float32_overflow_is_an_export_error_not_a_numpy_warning():
    from forecast_design.errors import ExportError
    from forecast_design.export.c import c_float_literal

    assert c_float_literal(0.5) == "0.5f"
    with pytest.raises(ExportError, match="overflows float32"):   # filterwarnings=error: a warning would fail here
        c_float_literal(1e300)


def _api_cases():
    from forecast_design import Design, diagnose, fit_friction, simulate, tune_q
    from forecast_design.loops import force_loop
    from forecast_design.lti import RationalTF

    t = np.arange(2000) / 1000.0
    x = np.sin(t)
    return [
        (lambda: RationalTF((1.0,), (0.0,)), "denominator is zero"),            # was ZeroDivisionError
        (lambda: RationalTF(None, (1.0,)), "num must be"),                       # was a NaN polynomial
        (lambda: RationalTF((1.0,), (1.0, 1.0), dt=0.0), "dt must be"),
        (lambda: diagnose(None), "Experiment"),
        (lambda: simulate(None, reference=[0.1], duration_s=0.1), "Design"),     # was AttributeError
        (lambda: simulate(Design.nominal("soft"), reference=[0.1], duration_s=0.1, rate_hz=1e-300), "rate_hz"),
        (lambda: simulate(Design.nominal("soft"), reference=[0.1], duration_s=1e7), "samples"),
        (lambda: force_loop(None), "true_design"),                              # was AttributeError
        (lambda: force_loop(Design.nominal("soft"), ""), "Compensator"),        # was AttributeError
        (lambda: fit_friction(t, x, x, "sfm", settings=""), "settings"),        # was AttributeError
        (lambda: fit_friction(t, x, x, "sfm", scales=""), "scales"),
        (lambda: fit_friction(t, x, x, "sfm", encoder_step=math.nan), "encoder_step"),   # was a NaN result
        (lambda: tune_q(executor=""), "executor"),                               # was AttributeError
        (lambda: tune_q(band_hz=""), "band"),                                    # was IndexError
        (lambda: tune_q(sigma=1e300), "sigma"),                                  # was a division by zero
        (lambda: tune_q(delay_samples=math.inf), "delay_samples"),              # was OverflowError
    ]


@pytest.mark.parametrize("index", range(16))
def test_fuzz_findings_in_the_api_are_parameter_errors(index):
    from forecast_design.errors import ParameterError

    assert len(_api_cases()) == 16
    call, words = _api_cases()[index]
    with time_bound(CASE_SECONDS), pytest.raises(ParameterError, match=re.escape(words)) as info:
        call()
    assert "\n" not in str(info.value)


def test_diagnose_with_options_of_the_wrong_type_is_a_parameter_error(tmp_path):
    from forecast_design import diagnose, load_experiment
    from forecast_design.errors import ParameterError

    with pytest.raises(ParameterError, match="GapOptions"):
        diagnose(load_experiment(write_experiment(tmp_path)), options="")   # was AttributeError


# --- warnings and solver output: one line each on success, nothing but the error on failure -------------------------


def test_python_warnings_are_one_line_on_success_and_absent_on_error(monkeypatch, capsys):
    import warnings

    import forecast_design.cli as cli_module
    from forecast_design.errors import ParameterError

    def noisy(fail):
        def handler(args):
            warnings.warn("first line\nsecond line", UserWarning)
            np.float32(1e300)   # numpy's overflow RuntimeWarning
            if fail:
                raise ParameterError("--thing is wrong", name="thing")
            return 0
        return handler

    help_text, configure, _ = cli_module._COMMANDS["tf"]
    monkeypatch.setitem(cli_module._COMMANDS, "tf", (help_text, configure, noisy(False)))
    code, _, err = cli(["tf"], capsys)
    assert code == 0 and err.splitlines() == ["forecast-design: warning: UserWarning: first line",
                                              "forecast-design: warning: RuntimeWarning: overflow encountered in cast"]
    monkeypatch.setitem(cli_module._COMMANDS, "tf", (help_text, configure, noisy(True)))
    code, _, err = cli(["tf"], capsys)
    assert_one_line_error(code, err, "--thing is wrong")


def test_tune_q_prints_nothing_on_stderr_on_success_and_one_line_on_failure(capfd):
    """At the file-descriptor level (casadi and ipopt write from C++, below Python's sys.stderr)."""
    from forecast_design.cli import main

    # an interior optimum (not on the band's ends), so ipopt runs and no at-bound warning is due
    code = main(["tune-q", "--observer", "ea-fob", "--envs", "soft,stiff", "--uncertainty", "0.3"])
    out, err = capfd.readouterr()
    assert code == 0 and err == "", err
    assert "w_q = 13.96 Hz" in out and "Ipopt" not in out and "EXIT" not in out   # ipopt's banner and summary
    code = main(["tune-q", "--observer", "ea-fob", "--envs", "soft", "--band", "1e-300", "1e-299"])
    _, err = capfd.readouterr()
    assert_one_line_error(code, err, "w_q_hz")


def test_every_ipopt_solver_starts_from_the_quiet_options():
    import pathlib

    from forecast_design.friction.nonlinear import IPOPT_OPTIONS

    assert IPOPT_OPTIONS == {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
    package = pathlib.Path(forecast_design.__file__).parent
    for path in package.rglob("*.py"):
        text = path.read_text()
        for match in re.finditer(r"nlpsol\([^)]*\)", text):
            assert "IPOPT_OPTIONS" in text, f"{path.name}: {match.group(0)} without the quiet options"


# --- issue 23: every hostile file as every kind of input and output --------------------------------------------

_INPUT_FILES = ["fifo.toml", "dir.toml", "loop.toml", "deep.toml", "big.toml", "nullog.toml", "crc.toml", "grid.toml",
                "reps.toml", "nyquist.toml", "bom.toml", "dev"]
_READERS = [["check", "{f}"], ["diagnose", "{f}"], ["identify", "{f}"], ["simulate", "{f}", "--out", "o/o.toml"],
            ["simulate", "{f}", "--out", "o/o.toml", "--repetitions", "all"], ["tf", "--env", "{f}"],
            ["tf", "--testbed", "{f}"], ["margins", "--experiment", "{f}"], ["emulate", "--scenario", "{f}"],
            ["benchmark", "--envs", "{f}", "--out", "b"], ["export", "--compensator", "sfm", "--friction", "{f}",
                                                            "--out", "c"]]


@pytest.mark.parametrize("reader", _READERS, ids=lambda r: "-".join(a for a in r if a != "{f}")[:30])
def test_hostile_files_as_inputs_are_one_line_or_an_answer(reader, workdir, capsys):
    for name in _INPUT_FILES:
        argv = [a.format(f=name) for a in reader]
        before = _snapshot(workdir)
        code, out, err = cli(argv, capsys)
        check_properties(argv, code, out, err)
        if name in ("fifo.toml", "dir.toml", "loop.toml", "deep.toml", "big.toml", "dev"):
            assert code == 2, (argv, code, err)             # never read: refused in one line, nothing hangs
        for node, kind in NODES.items():
            assert _kind(workdir / node) == kind, (argv, node)
        assert {n for n in _read_files(argv, workdir) if before.get(n) != _snapshot(workdir).get(n)} == set()


_WRITERS = [["tf", "--json", "{f}"], ["tf", "--plot", "{f}"], ["margins", "--json", "{f}"],
            ["simulate", "s.toml", "--out", "{f}"], ["check", "run.toml", "--json", "{f}"],
            ["export", "--out", "{f}"], ["benchmark", "--out", "{f}"]]
_OUTPUT_FILES = ["fifo.toml", "dir.toml", "loop.toml", "dangling.json", "dev", "run.toml", "run.csv", "s.toml"]


@pytest.mark.parametrize("writer", _WRITERS, ids=lambda w: "-".join(a for a in w if a != "{f}")[:30])
def test_hostile_outputs_never_destroy_a_node_or_an_input(writer, workdir, capsys):
    for name in _OUTPUT_FILES:
        argv = [a.format(f=name) for a in writer]
        before = _snapshot(workdir)
        code, out, err = cli(argv, capsys)
        check_properties(argv, code, out, err)
        for node, kind in NODES.items():
            assert _kind(workdir / node) == kind, (argv, node, err)
        after = _snapshot(workdir)
        assert {n for n in _read_files(argv, workdir) if before.get(n) != after.get(n)} == set(), argv
        if name == "dangling.json" and code == 0:
            assert (workdir / "nowhere" / "x.json").exists()      # written at the link's target, the link kept
