"""Nothing hangs, no NaN answer exits 0, bad input is one line: the Numbers items of docs/reliability.md.

CLI cases run in-process through ``forecast_design.cli.main`` with a wall-clock bound per case; the
fuzz tests are hypothesis-driven, derandomised, with a small ``max_examples``.
"""

import contextlib
import copy
import math
import resource
import signal
import time
import tomllib
from importlib import resources

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from forecast_design.cli import main
from forecast_design.errors import ExperimentFormatError, ForecastError, ParameterError
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design, Environment, Testbed
from forecast_design.limits import COMPUTATION_LIMITS, PHYSICAL_RANGES, require_no_nan

FUZZ = settings(derandomize=True, max_examples=25, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
CASE_SECONDS = 120.0         # wall-clock bound of one CLI case: catches a hang, not a slow case on a busy CI machine
CASE_MEGABYTES = 500.0       # growth bound of the peak resident memory over one case


def _max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class CaseTimeout(Exception):
    """Raised inside a CLI case that outlives CASE_SECONDS (a hang becomes a failure, not a stalled suite)."""


@contextlib.contextmanager
def time_bound(seconds: float = CASE_SECONDS):
    """Interrupt the block after ``seconds`` of wall clock (SIGALRM; main thread, POSIX)."""
    def expire(signum, frame):
        raise CaseTimeout(f"case still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def memory_bound(megabytes: float = 4 * CASE_MEGABYTES):
    """Cap the process's data segment at its current size + ``megabytes`` for the block (RLIMIT_DATA).

    A case that tries to allocate without bound then meets a MemoryError (a test failure) instead of
    the kernel's out-of-memory killer (a dead suite, and a starved machine).
    """
    with open("/proc/self/status") as status:
        data_kb = next(int(line.split()[1]) for line in status if line.startswith("VmData:"))
    previous = resource.getrlimit(resource.RLIMIT_DATA)
    cap = int((data_kb * 1024) + megabytes * 1024 * 1024)
    resource.setrlimit(resource.RLIMIT_DATA, (cap if previous[1] == resource.RLIM_INFINITY else min(cap, previous[1]),
                                              previous[1]))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, previous)


def cli(argv, capsys):
    """Run one CLI case in-process; return (code, stdout, stderr), enforcing the time and memory bounds."""
    rss, t0 = _max_rss_mb(), time.monotonic()
    try:
        with time_bound(CASE_SECONDS), memory_bound():
            code = main([str(a) for a in argv])
    except SystemExit as exc:   # argparse's own one-line usage errors exit 2 this way
        code = exc.code
    elapsed = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert elapsed < CASE_SECONDS, f"{argv} took {elapsed:.1f} s"
    assert _max_rss_mb() - rss < CASE_MEGABYTES, f"{argv} grew the resident memory by > {CASE_MEGABYTES} MB"
    return code, out, err


def assert_one_line_error(code, err, *words):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("forecast-design"), err   # nothing around it
    assert ": error: " in lines[0], err
    for w in words:
        assert w in lines[0], lines[0]


def write_experiment(folder, name="run", *, J_m=0.133, k=58.0, J_e=0.001, J_l=0.0018):
    toml = folder / f"{name}.toml"
    toml.write_text(f'format = "forecast-experiment/1"\ndata = "{name}.csv"\n[sampling]\nrate_hz = 1000.0\n'
                    f"[testbed]\nJ_m = {J_m!r}\nd_m = 0.3\nk = {k!r}\n"
                    f"[environment]\nJ_e = {J_e!r}\nd_e = 0.063\nk_e = 5.0\nJ_l = {J_l!r}\nd_l = 0.35\n")
    t = (np.arange(2000) / 1000.0).tolist()   # Python floats: repr of a numpy scalar is not a CSV number
    rows = "".join(f"{a!r},{0.5 * math.sin(6 * a)!r},{0.01 * math.sin(6 * a)!r},{0.005 * math.sin(6 * a)!r}\n"
                   for a in t)
    (folder / f"{name}.csv").write_text("t,tau_m,theta,q\n" + rows)
    return toml


# --- inputs that hang or exhaust memory get a bound --------------------------------------------------------


@pytest.mark.parametrize("argv, words", [
    (["margins", "--sampled", "--delay-samples", "1000000"], ["delay_samples", "[0, 100]"]),
    (["tune-q", "--observer", "ea-fob", "--envs", "soft", "--q-order", "50"], ["q_order", "[1, 8]"]),
    (["tune-q", "--observer", "ea-fob", "--envs", "random:100000000"], ["random:100000000", "[1, 1000]"]),
    (["tune-q", "--observer", "ea-fob", "--envs", "random:0"], ["random:0"]),
    (["tune-q", "--observer", "ea-fob", "--envs", "random:3", "--seed", "-1"], ["seed"]),
    (["bench-gap", "--per-effect", "1", "--seed", "-1"], ["seed"]),
    (["emulate", "--fault", "seed:-1"], ["seed"]),
    (["tune-q", "--observer", "ea-fob", "--envs", "soft", "--band", "1e-300", "1e-299"], ["band", "w_q_hz"]),
    (["margins", "--observer", "ea-fob", "--w-q-hz", "1e-300"], ["w_q_hz", "plausible range"]),
    (["margins", "--observer", "ea-fob", "--w-q-hz", "1e300"], ["w_q_hz", "plausible range"]),
    (["margins", "--sampled", "--rate-hz", "1e9"], ["rate_hz"]),
])
def test_bounded_inputs_are_one_line_errors_in_bounded_time(argv, words, capsys):
    code, out, err = cli(argv, capsys)
    assert_one_line_error(code, err, *words)


@pytest.mark.parametrize("values, verb, words", [
    ({"J_m": 1e308}, "diagnose", ["J_m", "plausible range"]),
    ({"k": 1e300}, "diagnose", ["k =", "plausible range"]),
    ({"k": 1e300}, "tf", ["k =", "plausible range"]),
    ({"J_e": 0.0, "J_l": 0.0}, "diagnose", ["J_e + J_l = 0"]),
    ({"J_e": 0.0, "J_l": 0.0}, "check", ["J_e + J_l = 0"]),
])
def test_absurd_physical_parameters_are_refused_not_nan(tmp_path, capsys, values, verb, words):
    toml = write_experiment(tmp_path, **values)
    argv = [verb, str(toml)] if verb != "tf" else ["tf", "--experiment", str(toml)]
    code, out, err = cli(argv, capsys)
    assert_one_line_error(code, err, toml.name, *words)
    assert "nan" not in out.lower()


def test_non_utf8_toml_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'format = "forecast-experiment/1"\ndescription = "\xff\xfe"\n')
    for verb in ("check", "diagnose"):
        code, _, err = cli([verb, bad], capsys)
        assert_one_line_error(code, err, "bad.toml")


# --- NaN never reaches an answer ---------------------------------------------------------------------------------


def test_require_no_nan_finds_nan_anywhere_and_allows_inf():
    assert require_no_nan({"gm": [1.0, math.inf], "x": None, "s": "nan"}, "t")["gm"][1] == math.inf
    for bad in ({"a": {"b": [0.0, float("nan")]}}, [np.array([1.0, np.nan])], {"p": complex(0, float("nan"))}):
        with pytest.raises(ForecastError, match="NaN at"):
            require_no_nan(bad, "t")


@FUZZ
@given(w_q=st.floats(1e-3, 1e5), env=st.sampled_from(["soft", "stiff", "exp-soft", "locked", "link-only"]),
       observer=st.sampled_from(["none", "ea-fob", "lo-dob", "ld-dob", "motor-fob"]))
def test_margins_over_the_plausible_range_never_prints_nan_with_exit_0(w_q, env, observer, capsys):
    code, out, err = cli(["margins", "--env", env, "--observer", observer, "--w-q-hz", repr(w_q), "--json"], capsys)
    assert code in (0, 1, 2)
    if code in (0, 1):
        assert "NaN" not in out and "nan" not in out
    else:
        assert_one_line_error(code, err)


_HOSTILE_NUMBERS = st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e-300", "1e300", "1e9", "-0.0",
                                    "123456789012345678901234567890", "5_2", "0x10", ""])


@FUZZ
@given(option=st.sampled_from(["--w-q-hz", "--rate-hz", "--delay-samples", "--sigma"]), value=_HOSTILE_NUMBERS)
def test_margins_fuzz_hostile_numbers_one_line_or_answer(option, value, capsys):
    code, out, err = cli(["margins", "--sampled", "--observer", "ea-fob", option, value], capsys)
    assert code in (0, 1, 2)
    if code == 2:
        assert err.count("\n") == 1 and "Traceback" not in err
    else:
        assert "nan" not in out.lower()


_TUNE_Q_BAD = {"--seed": ["-1", "-5", "nan", "9223372036854775808"], "--q-order": ["0", "9", "50", "1000000", "-1"],
               "--delay-samples": ["-1", "101", "1000000"], "--rate-hz": ["nan", "1e9", "0", "-2000"],
               "--band": [("1e-300", "1e-299"), ("1e300", "1e301"), ("5", "1"), ("nan", "1")]}


@FUZZ
@given(pair=st.sampled_from([(k, v) for k, vs in _TUNE_Q_BAD.items() for v in vs]))
def test_tune_q_fuzz_bad_sizes_fail_fast(pair, capsys):
    option, value = pair
    values = list(value) if isinstance(value, tuple) else [value]
    argv = ["tune-q", "--observer", "ea-fob", "--envs", "random:2", "--sampled", option, *values]
    code, out, err = cli(argv, capsys)
    assert_one_line_error(code, err)


# --- the Python API: clear errors, not raw AttributeErrors ---------------------------------------------------------


def test_api_type_errors_are_parameter_errors():
    from forecast_design.analysis import loop_margins
    from forecast_design.export.c import export_controller
    from forecast_design.gap import diagnose
    from forecast_design.symbolic import transfer_functions

    for call in (lambda: transfer_functions(42), lambda: diagnose("run.toml"),
                 lambda: export_controller("soft", out_dir="unused"), lambda: Design(testbed="x"),
                 lambda: Design(environment="soft"), lambda: Design(compensator="ea-fob")):
        with pytest.raises(ParameterError) as info:
            call()
        assert "\n" not in str(info.value)
    assert loop_margins(Design.nominal("soft"), "ea-fob").stable   # a kind name is accepted here
    assert transfer_functions("soft").P.tf == transfer_functions(Design.nominal("soft")).P.tf   # so is a preset


@FUZZ
@given(J_m=st.floats(0.01, 10.0), k=st.integers(1, 1000),
       kind=st.sampled_from([np.float64, np.float32, np.int64, np.int32, float, int]))
def test_testbed_accepts_numpy_scalars_as_the_same_numbers(J_m, k, kind):
    tb = Testbed(J_m=kind(J_m) if kind not in (np.int64, np.int32, int) else kind(max(1, round(J_m))),
                 d_m=kind(0), k=kind(k))
    assert isinstance(tb.J_m, float) and tb.k == float(kind(k))


def test_experiment_from_arrays_rejects_complex_values():
    from forecast_design.experiment import experiment_from_arrays

    t = np.arange(4) / 1000.0
    with pytest.raises(ExperimentFormatError, match="'tau_m' must be real"):
        experiment_from_arrays(Design.nominal("locked"), 1000.0, t, 0 * t + 1j, 0.01 + 0 * t, 0 * t)


@FUZZ
@given(name=st.sampled_from(sorted(set(PHYSICAL_RANGES) - {"w_q_hz", "rate_hz"})),
       value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e300, -1e-300, 1e308])))
def test_physical_parameters_inside_their_range_or_one_line_error(name, value):
    from forecast_design.controllers import PID, TFController

    lo, hi, _ = PHYSICAL_RANGES[name]
    owner, base = {
        "J_m": (Testbed, {}), "d_m": (Testbed, {}), "k": (Testbed, {}),
        "P": (PD, {}), "D": (PD, {}), "feedforward": (PD, {}), "u_min": (PD, {}), "u_max": (PD, {}),
        "T_f": (PD, {"discretization": "tustin"}), "I": (PID, {"P": 1.0}),
        "T_t": (PID, {"P": 1.0, "I": 1.0, "anti_windup": "back-calculation", "u_min": -1e6, "u_max": 1e6}),
        "prewarp_hz": (TFController, {"num": (1.0,), "den": (0.01, 1.0), "discretization": "tustin-prewarp"}),
    }.get(name, (Environment, {"J_e": 0.001, "d_e": 0.06, "k_e": 5.0}))
    inside = math.isfinite(value) and lo <= value <= hi and not (name in ("J_m", "k", "T_t", "prewarp_hz")
                                                                 and value <= 0)
    if name in ("u_min", "u_max") and inside:
        inside = not (name == "u_min" and value >= 1e6) and not (name == "u_max" and value <= -1e6)
    if name == "T_f" and inside and value == 0.0:
        inside = False                                     # tustin needs a filter: refused, naming T_f
    try:
        made = owner(**{**base, name: value})
    except ParameterError as exc:
        assert "\n" not in str(exc) and name in str(exc)
        if inside:   # the only in-range refusals: E(s) = 0 or an output without inertia
            assert "J_e + J_l" in str(exc) or "all 0" in str(exc)
        return
    assert inside and getattr(made, name) == value


def test_q_order_and_cutoff_limits_come_from_the_shared_tables():
    lo, hi, _ = COMPUTATION_LIMITS["q_order"]
    Compensator(kind="ea-fob", q_order=hi)
    with pytest.raises(ParameterError, match="q_order"):
        Compensator(kind="ea-fob", q_order=hi + 1)
    with pytest.raises(ParameterError, match="w_q_hz"):
        Compensator(kind="ea-fob", w_q_hz=PHYSICAL_RANGES["w_q_hz"][1] * 10)


# --- scenarios ------------------------------------------------------------------------------------------------------


def _example():
    path = resources.files("forecast_design") / "data" / "example_scenario.toml"
    return tomllib.loads(path.read_text())


@pytest.mark.parametrize("section, key, value, words", [
    ("simulation", "substeps", 100_000_000, "substeps"),
    ("simulation", "duration_s", 1e7, "samples"),
    ("sampling", "rate_hz", 1e9, "rate_hz"),
    ("simulation", "derivative_cutoff_hz", 200.0, "belongs to the controller"),
    ("controller", "T_f", -1.0, "T_f"),
    ("controller", "T_f", 1e3, "T_f"),
    ("controller", "discretization", "bilinear", "discretization"),
    ("simulation", "process_noise_std", 1e200, "process_noise_std"),
    ("simulation", "seed", -3, "seed"),
    ("simulation", "sfm_deadband", -0.1, "sfm_deadband"),
])
def test_scenario_bounds_name_the_file_and_key(section, key, value, words):
    from forecast_design.simulation.scenario import scenario_from_mapping

    doc = _example()
    doc[section][key] = value
    with pytest.raises(ExperimentFormatError) as info:
        scenario_from_mapping(doc, source="s.toml")
    message = str(info.value)
    assert message.startswith("s.toml: ") and words in message and "\n" not in message


def test_scenario_effects_reject_static_below_coulomb_and_zero_inertia_scale():
    from forecast_design.simulation.scenario import scenario_from_mapping

    doc = _example()
    stiction = next(e for e in doc["truth"]["effects"] if e["effect"] == "stiction")
    stiction["F_s"], stiction["F_c"] = 0.1, 0.3
    with pytest.raises(ExperimentFormatError, match="F_s must be >= F_c"):
        scenario_from_mapping(doc, source="s.toml")
    doc = _example()
    doc["truth"]["effects"].append({"effect": "environment_mismatch", "J_scale": 0.0})
    with pytest.raises(ExperimentFormatError, match="J_scale must be > 0"):
        scenario_from_mapping(doc, source="s.toml")


def test_scenario_compensator_errors_name_the_section_once():
    from forecast_design.simulation.scenario import scenario_from_mapping

    doc = _example()
    doc["compensator"]["w_q_hz"] = -1.0
    with pytest.raises(ExperimentFormatError) as info:
        scenario_from_mapping(doc, source="s.toml")
    assert str(info.value).count("[compensator]") == 1


@FUZZ
@given(key=st.sampled_from(["duration_s", "process_noise_std", "derivative_cutoff_hz", "velocity_cutoff_hz",
                            "sfm_deadband", "torque_limit", "substeps", "seed"]),
       value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**70, 2**70)))
def test_scenario_simulation_fuzz_valid_or_one_line(key, value):
    from forecast_design.simulation.scenario import scenario_from_mapping

    doc = copy.deepcopy(_example())
    doc["simulation"][key] = value
    try:
        sc = scenario_from_mapping(doc, source="s.toml")
    except ExperimentFormatError as exc:
        assert str(exc).startswith("s.toml: ") and "\n" not in str(exc)
        return
    opts = sc.options
    assert all(not isinstance(v, float) or math.isfinite(v) or k == "torque_limit" for k, v in opts.items())
    assert opts["duration_s"] * sc.rate_hz <= COMPUTATION_LIMITS["simulation_samples"][1]
