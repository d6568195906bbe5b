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
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_reliability import assert_one_line_error, cli, time_bound, write_experiment

import forecast_design
from forecast_design.cli import build_parser
from forecast_design.errors import ForecastError

FUZZ = settings(derandomize=True, max_examples=12, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

#: Values any option may receive from a hostile user: numbers at and beyond every edge, malformed
#: specs, paths of the wrong kind (all relative: the cases run in a temporary folder).
HOSTILE = ["nan", "inf", "-inf", "-1", "0", "1e-300", "1e300", "1e309", "-0.0", "5_2", "0x10", "", "abc",
           "123456789012345678901234567890", "random:0", "random:-1", "random:100000000", "k=nan",
           "k_e=-1,J_e=0", "J_m=1e308", "pd:nan:1", "pd:1e300:0", "square:nan:1", "sine:1:0", "step:1e300",
           "ea-fob:nan", ":", "::::", ".", "missing.toml", "run.csv", "run.toml", "s.toml", "sub/x.toml",
           "x.xyz", "out.png", "seed:-1", "disconnect:-3", "flip:2"]

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
    return tmp_path


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
    assert code in (0, 1, 2), (argv, code, err)
    assert "Traceback" not in err, (argv, err)
    if code == 2:
        assert_one_line_error(code, err)
        assert err.startswith("forecast-design: error: "), (argv, err)
    if code == 0:
        assert not _NAN_TOKEN.search(out), (argv, out[:500])
        if "--json" in argv and argv[argv.index("--json") + 1:argv.index("--json") + 2] in ([], ["-"]) \
                and out.strip().startswith(("{", "[")):
            json.loads(out, parse_constant=lambda token: pytest.fail(f"{argv}: {token} in JSON"))


def _fuzz_verb(verb, data, capsys):
    argv = list(BASE[verb])
    for _ in range(data.draw(st.integers(1, 2), label="mutations")):
        argv += data.draw(_mutation(argv[0]), label="option")
    if _has_json(argv[0]) and data.draw(st.booleans(), label="json"):
        argv += ["--json", "-"]
    code, out, err = cli(argv, capsys)
    check_properties(argv, code, out, err)
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
