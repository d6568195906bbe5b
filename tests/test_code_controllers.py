"""Controllers written as code: a Python class or a C file run where the linear kinds run.

Facts checked: the example gain-scheduled PID equals its documented difference equations
(scipy's lfilter on its linear regime) and its C twin equals it up to float32 rounding; a Python
PD written as code runs in the simulator exactly as the compiled kernel runs ``pd:P:D`` (and a C
PD within float32 rounding); a failing step (exception, NaN, hang) stops the run with zero
torque and a recorded fault; the code reaches scenarios, the benchmark (local processes and a
Dask cluster on the loopback interface), the margins (through a linearisation, said so, equal to
the same transfer function given as ``tf:``), the export, the emulated board and the firmware
on qemu (software in the loop = processor in the loop, bit for bit); bad code is one line.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import loopback_cluster

from forecast_design.controllers import CController, PythonController, resolve_controller
from forecast_design.controllers.examples import example_path
from forecast_design.errors import ParameterError
from forecast_design.export import toolchain
from forecast_design.export.toolchain import find_tools
from forecast_design.params import Compensator, Design
from forecast_design.simulation.code import code_runner
from forecast_design.simulation.references import Step
from forecast_design.simulation import TorqueSensor
from forecast_design.simulation.run import simulate

EXAMPLE_PY = "forecast_design.controllers.examples.gain_scheduled_pid:GainScheduledPID"
EXAMPLE_C = str(example_path("gain_scheduled_pid.c"))
needs_cc = pytest.mark.skipif(find_tools().cc is None, reason="no host C compiler")
CLI = [sys.executable, "-m", "forecast_design"]

PD_PY = textwrap.dedent("""
    class PD:
        '''u = P e + D (e_k - e_(k-1)) / T: pd:5:0.1 as the format defines it (backward Euler, T_f = 0).'''
        def reset(self, rate_hz, testbed, environment):
            self.dt = 1.0 / rate_hz
            self.e_prev = 0.0
        def step(self, t, tau_r, tau_s, theta, q):
            e = tau_r - tau_s
            u = 5.0 * e + 0.1 * (e - self.e_prev) / self.dt
            self.e_prev = e
            return u
""")
PD_C = textwrap.dedent("""
    static float rate, e_prev;
    void fd_user_init(float rate_hz) { rate = rate_hz; e_prev = 0.0f; }
    float fd_user_step(float tau_r, float tau_s, float theta, float q)
    {
        const float e = tau_r - tau_s;
        const float u = 5.0f * e + 0.1f * (e - e_prev) * rate;
        (void)theta; (void)q;
        e_prev = e;
        return u;
    }
""")


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def _cli(*args, cwd=None, timeout=900):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=timeout)


def _main(capsys, *args):
    """The command line's entry point in this process: exit code, stdout and stderr as ``_cli`` gives them
    (without a process start and its imports; the verbs that leave threads or worker processes behind
    run through ``_cli``)."""
    from types import SimpleNamespace

    from forecast_design.cli import main

    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out.out, stderr=out.err)


def _design(controller, compensator=None, env="exp-soft"):
    return dataclasses.replace(Design.nominal(env), controller=controller, compensator=compensator)


# --- the examples against their own equations --------------------------------------------------


def test_the_python_example_is_its_documented_difference_equation():
    """At tau_r = 0 the schedule is P0 and, unsaturated, the law is linear: u = C(z) e with
    C(z) = P0 + I T z^-1 / (1 - z^-1) + D (1 - z^-1) / (T_F + T - T_F z^-1) (scipy.signal.lfilter)."""
    from scipy.signal import lfilter

    from forecast_design.controllers.examples.gain_scheduled_pid import GainScheduledPID as G

    rate, n = 2000.0, 4000
    e = 0.05 * np.random.default_rng(3).standard_normal(n)
    runner = code_runner(resolve_controller(EXAMPLE_PY))
    runner.reset(rate, None, None)
    u = np.array([runner.step(k / rate, 0.0, -x, 0.0, 0.0) for k, x in enumerate(e)])   # tau_s = -e
    T = 1.0 / rate
    expected = (G.P0 * e + lfilter([0.0, G.I * T], [1.0, -1.0], e)
                + lfilter([G.D, -G.D], [G.T_F + T, -G.T_F], e))
    assert np.max(np.abs(u)) < G.U_MAX
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)


@needs_cc
def test_the_c_example_equals_the_python_example_to_float32_rounding():
    x = toolchain.test_sequence(20_000, with_q=True).astype(float)
    outs = []
    for spec in (EXAMPLE_PY, EXAMPLE_C):
        r = code_runner(resolve_controller(spec))
        r.reset(2000.0, None, None)
        outs.append(np.array([r.step(k / 2000.0, *row) for k, row in enumerate(x)]))
    py, c = outs
    assert np.max(np.abs(py)) > 1.0                       # the schedule and the integrator were exercised
    assert np.max(np.abs(py - c)) <= 1e-5 * np.max(np.abs(py))
    assert not np.array_equal(py, c)                      # the C ran, in float32


# --- the simulator's period loop ----------------------------------------------------------------


@pytest.mark.parametrize("compensator", [None, Compensator(kind="ea-fob", w_q_hz=10.0),
                                         Compensator(kind="lo-dob", w_q_hz=5.0)], ids=["none", "ea-fob", "lo-dob"])
def test_a_python_pd_runs_as_the_compiled_pd(tmp_path, compensator):
    """The same law written as code and as pd:5:0.1 gives the same closed loop (delays, compensator,
    saturation, plant and effects are the simulator's in both)."""
    from forecast_design.effects import Coulomb

    code = PythonController(source=str(_write(tmp_path, "pd.py", PD_PY)), class_name="PD")
    kw = dict(reference=Step(amplitude=0.2, t0=0.01), duration_s=0.5, effects=[Coulomb(F_c=0.05)], seed=4,
              torque_limit=3.0)
    a = simulate(_design(code, compensator), **kw)
    b = simulate(_design(resolve_controller("pd:5:0.1"), compensator), **kw)
    for name in ("tau_m", "tau_s", "u", "tau_frc_hat", "theta"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-9, err_msg=name)
    assert a.fault is None and np.max(np.abs(a.tau_s)) > 0.1
    assert a.design.controller == code and a.to_experiment().design.controller.to_mapping() == {
        "kind": "other", "name": f"python {code.source}:PD"}


@needs_cc
def test_a_c_pd_runs_as_the_compiled_pd_to_float32_rounding(tmp_path):
    code = resolve_controller(str(_write(tmp_path, "pd.c", PD_C)))
    assert isinstance(code, CController)
    kw = dict(reference=Step(amplitude=0.2, t0=0.01), duration_s=0.5, seed=4)
    comp = Compensator(kind="ea-fob", w_q_hz=10.0)
    a = simulate(_design(code, comp), **kw)
    b = simulate(_design(resolve_controller("pd:5:0.1"), comp), **kw)
    # float32 rounding moves the plant by less than an encoder count, which the quantised tau_s can
    # still flip: bounded by counts, and by the PD's gain P + D/T on them for the command
    count = Design.nominal("exp-soft").testbed.k * 2 * math.pi / 2_000_000    # [N m]
    assert np.max(np.abs(a.tau_s - b.tau_s)) <= 2 * count and np.mean(np.abs(a.tau_s - b.tau_s)) <= 0.2 * count
    assert np.max(np.abs(a.tau_m - b.tau_m)) <= 3 * count * (5.0 + 0.1 * 2000.0)
    assert a.u.dtype == np.float64 and np.array_equal(a.u, a.u.astype(np.float32))   # u came from float32 C


def test_runs_with_code_are_reproducible_by_seed_and_batch_equals_simulate(tmp_path):
    from forecast_design.effects import Coulomb
    from forecast_design.simulation.batch import BatchRun, simulate_batch

    design = _design(resolve_controller(EXAMPLE_PY), Compensator(kind="ea-fob", w_q_hz=10.0))
    pd = _design(resolve_controller("pd:5:0.1"))
    runs = [BatchRun(design=design, effects=[Coulomb(F_c=0.05)], seed=s, initial_angle=0.3 * s) for s in (1, 2)]
    runs.append(BatchRun(design=pd, seed=3))
    batch = simulate_batch(runs, duration_s=0.3, reference=Step(amplitude=0.2))
    for i, run in enumerate(runs):
        alone = simulate(run.design, reference=Step(amplitude=0.2), duration_s=0.3, effects=run.effects,
                         seed=run.seed, initial_angle=run.initial_angle)
        assert np.array_equal(batch.result(i).tau_m, alone.tau_m)
    assert not np.array_equal(batch.result(0).tau_s, batch.result(1).tau_s)


FAULTY = textwrap.dedent("""
    import time
    class Nan:
        def reset(self, *a): pass
        def step(self, t, *a): return float("nan") if t >= 0.05 else 0.1
    class Inf:
        def reset(self, *a): pass
        def step(self, t, *a): return float("inf") if t >= 0.05 else 0.1
    class Raises:
        def reset(self, *a): pass
        def step(self, t, *a):
            if t >= 0.05:
                raise RuntimeError("sensor table exhausted")
            return 0.1
    class Spins:
        def reset(self, *a): pass
        def step(self, t, *a):
            while t >= 0.05:
                pass
            return 0.1
    class Sleeps:
        def reset(self, *a): pass
        def step(self, t, *a):
            if t >= 0.05:
                time.sleep(3600)
            return 0.1
""")


@pytest.mark.parametrize("cls, why", [("Nan", "step returned nan"), ("Inf", "step returned inf"),
                                      ("Raises", "RuntimeError: sensor table exhausted"),
                                      ("Spins", "did not return within 0.5 s"),
                                      ("Sleeps", "did not return within 0.5 s")])
def test_a_failing_python_step_stops_the_run_safely(tmp_path, cls, why):
    code = PythonController(source=str(_write(tmp_path, "faulty.py", FAULTY)), class_name=cls)
    r = simulate(_design(code), reference=Step(amplitude=0.2), duration_s=0.2, step_timeout_s=0.5)
    assert r.fault is not None and why in r.fault["reason"] and r.fault["period"] == 100
    k = r.fault["period"]
    assert np.all(r.tau_m[k:] == 0.0) and np.all(r.tau_m[:k] == 0.1)   # zero torque from the fault on
    assert r.t.size == 400 and np.all(np.isfinite(r.theta))            # the plant ran to the end
    assert "controller fault at t = 0.05 s" in r.to_experiment().description
    assert r.to_mapping()["controller_fault"]["period"] == k


@needs_cc
def test_a_c_step_that_never_returns_stops_the_cli_run_with_exit_1(tmp_path):
    _write(tmp_path, "spin.c", textwrap.dedent("""
        static volatile unsigned n;
        void fd_user_init(float rate_hz) { (void)rate_hz; n = 0u; }
        float fd_user_step(float a, float b, float c, float d)
        {
            (void)a; (void)b; (void)c; (void)d;
            if (++n > 100u) { for (;;) { n++; } }
            return 0.1f;
        }
    """))
    scenario = (Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml").read_text()
    scenario = scenario.replace('kind = "pd"\nP = 5.0\nD = 0.1\n', 'kind = "c"\nsource = "spin.c"\n')
    scenario = "\n".join(line for line in scenario.splitlines()
                         if not line.startswith(("T_f =", 'discretization = "tustin"')))
    # the scenario's step timeout (default 10 s): 2 s, still far above any pause of a loaded machine
    scenario = scenario.replace("[simulation]\nduration_s = 8.0\n",
                                "[simulation]\nduration_s = 0.5\nstep_timeout_s = 2.0\n")
    (tmp_path / "s.toml").write_text(scenario)
    from forecast_design.simulation.scenario import load_scenario

    loaded = load_scenario(tmp_path / "s.toml")
    assert isinstance(loaded.design.controller, CController) and loaded.options["step_timeout_s"] == 2.0
    # a C step is abandoned on its thread
    p = _cli("simulate", "s.toml", "--out", "run.toml", "--json", "-", cwd=tmp_path)
    assert p.returncode == 1, p.stderr
    assert "controller fault at t = 0.05 s (period 100)" in p.stderr and "did not return within 2 s" in p.stderr
    doc = json.loads(p.stdout)
    assert doc["controller_fault"]["period"] == 100 and doc["controller"] == "c spin.c"
    from forecast_design.experiment import load_experiment

    exp = load_experiment(tmp_path / "run.toml")
    tau_m = np.asarray(exp.signals.tau_m)
    assert np.all(tau_m[100:] == 0.0) and exp.design.controller.to_mapping()["kind"] == "other"


@pytest.mark.parametrize("value", [0.0, -1.0, float("inf"), float("nan"), "10"])
def test_a_scenario_step_timeout_is_a_positive_finite_number_or_one_line(value):
    import tomllib

    from forecast_design.errors import ExperimentFormatError
    from forecast_design.simulation.scenario import scenario_from_mapping

    path = Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml"
    doc = tomllib.loads(path.read_text())
    doc["simulation"]["step_timeout_s"] = value
    with pytest.raises(ExperimentFormatError, match=r"^s\.toml: \[simulation\] step_timeout_s must be") as info:
        scenario_from_mapping(doc, source="s.toml")
    assert "\n" not in str(info.value)


# --- bad code is one line --------------------------------------------------------------------------


BAD_C = {
    "syntax.c": ("float fd_user_step(float a, float b, float c, float d) { return a +; }\n"
                 "void fd_user_init(float r) { (void)r; }\n", r"syntax\.c:1:.*error"),
    "nostep.c": ("void fd_user_init(float r) { (void)r; }\n", "missing symbol fd_user_step"),
    "heap.c": ("#include <stdlib.h>\nvoid fd_user_init(float r) { (void)r; }\n"
               "float *fd_kept;   /* global: the compiler cannot drop the allocation */\n"
               "float fd_user_step(float a, float b, float c, float d) { fd_kept = malloc(4); (void)b; (void)c; "
               "(void)d; *fd_kept = a; return *fd_kept; }\n", "calls malloc of libc"),
    # other types than the interface's: without the prototypes first, ctypes and the firmware would
    # pass floats where the code reads doubles (garbage, no error)
    "signature.c": ("void fd_user_init(double r) { (void)r; }\n"
                    "double fd_user_step(double a, double b, double c, double d) { (void)c; (void)d; return a - b; }\n",
                    r"signature\.c:1:6: error: conflicting types for .fd_user_init.*\(the interface: void "
                    r"fd_user_init\(float rate_hz\)"),
    "stdio.c": ("#include <stdio.h>\nvoid fd_user_init(float r) { (void)r; }\n"
                "float fd_user_step(float a, float b, float c, float d) { printf(\"%f\", a); (void)b; (void)c; (void)d; "
                "return a; }\n", "calls printf of libc"),
}


@needs_cc
@pytest.mark.parametrize("name", sorted(BAD_C))
def test_bad_c_is_one_line_with_exit_2(tmp_path, name, monkeypatch, capsys):
    import re

    text, pattern = BAD_C[name]
    _write(tmp_path, name, text)
    monkeypatch.chdir(tmp_path)
    for argv in (["benchmark", "--controller", name, "--envs", "exp-soft", "--compensator", "none", "--repetitions",
                  "2", "--duration", "0.05", "--out", "b", "--no-plots"],
                 ["export", "--controller", name, "--out", "c"]):      # the export compiles it once too
        p = _main(capsys, *argv)
        assert p.returncode == 2, p.stderr
        lines = [line for line in p.stderr.splitlines() if line.startswith("forecast-design: error")]
        assert len(lines) == 1 and "Traceback" not in p.stderr
        assert re.search(pattern, lines[0]), lines[0]
        assert name in lines[0]
    assert not (tmp_path / "c").exists()


BAD_PY = {
    "syntax.py": ("class C:\n    def step(self, t:\n", "importing .*syntax.py failed \\(line 2\\): SyntaxError"),
    "nostep.py": ("class C:\n    def reset(self, *a): pass\n", "class C has no step\\(\\)"),
    "noclass.py": ("X = 1\n", "has no class C"),
    "raises.py": ("raise ImportError('needs the lab package')\n", "ImportError: needs the lab package"),
    "ctor.py": ("class C:\n    def __init__(self, k):\n        pass\n    def reset(self, *a): pass\n"
                "    def step(self, *a): return 0.0\n", "C\\(\\) failed: TypeError"),
}


@pytest.mark.parametrize("name", sorted(BAD_PY))
def test_bad_python_is_one_line_with_exit_2(tmp_path, name, monkeypatch, capsys):
    import re

    text, pattern = BAD_PY[name]
    _write(tmp_path, name, text)
    monkeypatch.chdir(tmp_path)
    p = _main(capsys, "benchmark", "--controller", f"{name}:C", "--envs", "exp-soft", "--compensator", "none",
              "--repetitions", "2", "--duration", "0.05", "--out", "b", "--no-plots")
    assert p.returncode == 2, p.stderr
    lines = [line for line in p.stderr.splitlines() if line.startswith("forecast-design: error")]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert re.search(pattern, lines[0]), lines[0]


def test_missing_files_and_modules_are_one_line(tmp_path):
    with pytest.raises(ParameterError, match="not found"):
        resolve_controller(str(tmp_path / "nowhere.c"))
    with pytest.raises(ParameterError, match="not found"):
        resolve_controller(str(tmp_path / "nowhere.py") + ":C")
    with pytest.raises(ParameterError, match="importing no_such_lab_module failed: ModuleNotFoundError"):
        code_runner(resolve_controller("no_such_lab_module:Controller"))
    # a registered kind is never read as module:Class
    assert resolve_controller("pd:5:0.1").kind == "pd"


def test_parse_controller_reads_the_code_spellings_as_resolve_controller_does(tmp_path, monkeypatch):
    """The benchmark's and the package's parse_controller take FILE.py:Class, module:Class and FILE.c
    (relative to the working directory); a python:/c: prefix is one line naming the spellings."""
    from forecast_design import parse_controller
    from forecast_design.benchmark import parse_controller as bench_parse

    _write(tmp_path, "pd.py", PD_PY)
    _write(tmp_path, "pd.c", PD_C)
    monkeypatch.chdir(tmp_path)
    for text, kind in (("pd.py:PD", PythonController), (EXAMPLE_PY, PythonController), ("pd.c", CController)):
        got = parse_controller(text)
        assert isinstance(got, kind) and got == resolve_controller(text) == bench_parse(text)
    assert parse_controller("pd.c").source == str(tmp_path / "pd.c")
    for text in ("python:source=pd.py:class_name=PD", "c:pd"):
        with pytest.raises(ParameterError, match="code is spelled FILE.py:Class, module:Class or FILE.c") as info:
            parse_controller(text)
        assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match="FILE.py:Class, module:Class, FILE.c or a TOML file"):
        parse_controller("nonsense")


def test_an_experiment_records_code_as_other_and_refuses_code_kinds(tmp_path):
    from forecast_design.errors import ExperimentFormatError
    from forecast_design.experiment_io import parse_toml

    doc = {"format": "forecast-experiment/1", "data": "run.csv", "sampling": {"rate_hz": 2000.0},
           "testbed": Design.nominal("exp-soft").testbed.to_mapping(),
           "environment": Design.nominal("exp-soft").environment.to_mapping(),
           "controller": {"kind": "c", "source": "x.c"}}
    with pytest.raises(ExperimentFormatError, match="kind must be one of pd, pid, tf, discrete, other"):
        parse_toml(doc, "run.toml")


# --- analysis: a linearisation, or none ----------------------------------------------------------


def test_margins_use_the_linearisation_and_say_so():
    """The example's transfer_function() is P0 + I/s + D s/(T_F s + 1): its margins are those of the
    same transfer function given as tf:NUM/DEN (0.05s^2 + ... ), and the output says it is a linearisation."""
    from forecast_design.analysis import analyse_loop
    from forecast_design.controllers.examples.gain_scheduled_pid import GainScheduledPID as G

    # C(s) = ((P0 T_F + D) s^2 + (P0 + I T_F) s + I) / (T_F s^2 + s)
    num = [G.P0 * G.T_F + G.D, G.P0 + G.I * G.T_F, G.I]
    den = [G.T_F, 1.0, 0.0]
    tf = resolve_controller("tf:" + ",".join(map(repr, num)) + "/" + ",".join(map(repr, den)))
    a = analyse_loop(Design.nominal("exp-soft"), "ea-fob", controller=resolve_controller(EXAMPLE_PY))
    b = analyse_loop(Design.nominal("exp-soft"), "ea-fob", controller=tf)
    assert a.disk.alpha == pytest.approx(b.disk.alpha, rel=1e-9) and a.disk.stable
    assert any("linearisation" in n for n in a.notes)
    assert "linearisation" in a.assumptions["controller"]["model"]


@needs_cc
def test_margins_and_tuning_refuse_code_without_a_model_in_one_line(tmp_path, monkeypatch, capsys):
    path = _write(tmp_path, "pd.c", PD_C)
    monkeypatch.chdir(tmp_path)
    for verb in (["margins", "--env", "exp-soft"], ["tune-q", "--env", "exp-soft", "--compensator", "ea-fob"]):
        p = _main(capsys, *verb, "--controller", path)
        assert p.returncode == 2 and "is code with no linear model" in p.stderr, p.stderr
        assert p.stderr.count("\n") == 1


def test_tune_q_with_the_python_linearisation_answers_like_its_tf():
    from forecast_design.tuning import tune_q

    lin = resolve_controller(EXAMPLE_PY)
    a = tune_q("ea-fob", "exp-soft,soft", controller=lin, scan_points=30)
    tf = resolve_controller("tf:" + ",".join(map(repr, lin.feedback_tf().num)) + "/"
                            + ",".join(map(repr, lin.feedback_tf().den)))
    b = tune_q("ea-fob", "exp-soft,soft", controller=tf, scan_points=30)
    assert a.w_q_hz == pytest.approx(b.w_q_hz, rel=1e-9)


# --- benchmark: local processes and a Dask cluster ------------------------------------------------


@needs_cc
@pytest.mark.slow
def test_the_examples_are_benchmarked_against_the_paper_pd(tmp_path):
    p = _cli("benchmark", "--controller", "pd:5:0.1", "--controller", EXAMPLE_PY, "--controller", EXAMPLE_C,
             "--compensator", "none,ea-fob", "--envs", "exp-soft", "--repetitions", "2", "--duration", "0.4",
             "--out", "bench", "--json", "-", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "note: controller c gain_scheduled_pid.c is code without a linear model" in p.stderr
    doc = json.loads(p.stdout)
    rows = {(r["controller"], r["compensator"]): r for r in doc["set"] if r["statistic"] == "mean"}
    py = rows[("python " + EXAMPLE_PY.split(":")[0] + ":GainScheduledPID", "ea-fob:10")]
    c = rows[("c gain_scheduled_pid.c", "ea-fob:10")]
    assert py["mae_N_m"] == pytest.approx(c["mae_N_m"], rel=1e-3)           # the same controller, float32 apart
    assert math.isfinite(py["disk_margin"])
    assert c["disk_margin"] is None or math.isnan(c["disk_margin"])          # no linear model: no margin
    report = (tmp_path / "bench" / "report.md").read_text()
    assert "is code without a linear model" in report and "through its linearisation" in report
    assert (tmp_path / "bench" / "indicators.png").stat().st_size > 10_000


@pytest.fixture
def cluster():
    """A cluster for the one test that uses it (closed after it: idle workers use CPU)."""
    with loopback_cluster() as c:
        yield c


@pytest.mark.slow
def test_a_python_file_controller_on_a_dask_cluster_equals_local_processes(tmp_path, cluster):
    from forecast_design.benchmark.runner import run_benchmark
    from forecast_design.benchmark.spec import BenchmarkSpec, parse_compensators, parse_reference
    from forecast_design.environments import resolve_environments
    from forecast_design.executor import make_executor

    code = PythonController(source=str(_write(tmp_path, "pd.py", PD_PY)), class_name="PD")
    spec = BenchmarkSpec(controllers=(code,), compensators=parse_compensators("none,ea-fob"),
                         environments=tuple(resolve_environments("exp-soft,locked").items()),
                         references=(parse_reference("step:0.2", duration_s=0.3),), repetitions=2)
    with make_executor(None, 2) as ex:
        local, _ = run_benchmark(spec, executor=ex)
    with make_executor(cluster.scheduler_address) as ex:
        remote, _ = run_benchmark(spec, executor=ex)
    for a, b in zip(local, remote):
        assert a.key == b.key and np.array_equal(a.tau_s, b.tau_s)


# --- export, emulated board, firmware ------------------------------------------------------------


@needs_cc
def test_the_export_links_the_c_controller_and_its_host_build_is_the_float32_program(tmp_path):
    """Software in the loop of the exported C: fd_step with fd_user.c on the host equals the float32
    program fed the C controller's output (the simulator's path), bit for bit."""
    from forecast_design.export.c import export_controller
    from forecast_design.export.toolchain import HostController, build_host, run_host
    from forecast_design.program import ControllerProgram

    res = export_controller(out_dir=tmp_path, controller=EXAMPLE_C, compensator="ea-fob", tau_max=2.0)
    assert res.user_source is not None and res.user_source.read_bytes().endswith(Path(EXAMPLE_C).read_bytes())
    assert res.program.external.startswith("c sha256:") and not [c for c in res.program.channels if c.group == "u"]
    assert ControllerProgram.from_bytes(res.program.to_bytes()).external == res.program.external
    x = toolchain.test_sequence(5000, with_q=True)
    host = run_host(build_host(tmp_path), x)
    runner = code_runner(resolve_controller(EXAMPLE_C))
    runner.reset(2000.0, None, None)
    step = res.program.make_step(np.float32)
    ref = np.array([step.step(*row[:3], u_external=runner.step(0.0, *row)) for row in x.astype(float)])
    assert np.array_equal(host, ref) and np.max(np.abs(host)) == pytest.approx(2.0)   # saturated at tau_max
    lib = HostController(build_host(tmp_path, shared=True), res.program.n_sections)
    lib.step(0.1, 0.0, 0.0, 0.0)
    # first period, e = 0.1: K_p = 4 + 2 x 0.1, the integrator still 0, d = D e / (T_F + T)
    assert lib.u == pytest.approx(4.2 * 0.1 + 0.05 * 0.1 / (0.002 + 0.0005), rel=1e-6)


@needs_cc
def test_a_c_controller_without_a_compensator_exports_and_builds_with_the_strict_flags(tmp_path):
    """No compensator: the program has no filter section at all, and the generated C (built with
    -Werror -pedantic) is the user's step saturated: tau_m = sat(fd_user_step(...) + 0)."""
    from forecast_design.export.c import export_controller
    from forecast_design.export.toolchain import build_host, run_host

    res = export_controller(out_dir=tmp_path, controller=EXAMPLE_C, compensator="none", tau_max=2.0)
    assert res.program.n_sections == 0
    x = toolchain.test_sequence(5000, with_q=True)
    host = run_host(build_host(tmp_path), x)
    runner = code_runner(resolve_controller(EXAMPLE_C))
    runner.reset(2000.0, None, None)
    u = np.array([runner.step(0.0, *row) for row in x.astype(float)])
    assert np.array_equal(host, np.clip(u, -2.0, 2.0)) and np.max(np.abs(u)) > 2.0


@needs_cc
def test_the_emulated_board_runs_the_c_controller_it_was_built_with(tmp_path, monkeypatch, capsys):
    """emulate --controller FILE.c accepts the host's upload of that code (run --controller FILE.c),
    refuses another, and a NaN or an infinity from the code is fault CONTROLLER with zero torque."""
    import os
    import signal

    from forecast_design.experiment import load_experiment

    # after 50 periods a / 0: an infinity under a nonzero reference, NaN (0 / 0) under a zero one
    fault_c = _write(tmp_path, "fault.c", "static int n;\nvoid fd_user_init(float r) { (void)r; n = 0; }\n"
                     "float fd_user_step(float a, float b, float c, float d) { (void)b; (void)c; (void)d; "
                     "return ++n > 50 ? a / 0.0f : a; }\n")
    monkeypatch.chdir(tmp_path)      # the host's runs are this process's; each board is a process of its own
    for code in (EXAMPLE_C, str(fault_c)):
        emu = subprocess.Popen([*CLI, "emulate", "--controller", code], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=tmp_path)
        try:
            port = emu.stdout.readline().strip()
            assert port.startswith("/dev/"), emu.stderr.read() if emu.poll() is not None else port
            if code == EXAMPLE_C:
                # a board built with code still takes a linear program from the host
                other = _main(capsys, "run", "--port", port, "--controller", "pd:5:0.1", "--duration", "0.05",
                              "--timeout", "30", "--out", "pd.toml")
                assert other.returncode == 0, other.stderr
                p = _main(capsys, "run", "--port", port, "--controller", code, "--duration", "0.1", "--timeout", "30",
                          "--out", "run.toml", "--json", "-")
                assert p.returncode == 0, p.stderr
                u = np.asarray(load_experiment(tmp_path / "run.toml").signals.columns()["u"])
                assert np.any(u != 0.0)
                # another C file is not the code this board runs
                bad = _main(capsys, "run", "--port", port, "--controller", str(fault_c), "--duration", "0.05",
                            "--out", "x.toml")
                assert bad.returncode == 2 and "BAD_PAYLOAD" in bad.stderr.upper().replace(" ", "_"), bad.stderr
            else:
                for reference, what in (("step:0.2", "inf"), ("step:0", "nan")):
                    p = _main(capsys, "run", "--port", port, "--controller", code, "--reference", reference,
                              "--duration", "0.1", "--timeout", "30", "--out", f"{what}.toml", "--json", "-")
                    assert p.returncode == 2 and "CONTROLLER" in p.stderr + p.stdout, (what, p.stderr)
                    assert "after 50 of 200 samples (torque set to zero)" in p.stderr, (what, p.stderr)
        finally:
            os.kill(emu.pid, signal.SIGTERM)
            emu.wait(timeout=60)
            emu.stdout.close()
            emu.stderr.close()


def _pil_missing():
    from forecast_design.runtime.pil import qemu_available

    return qemu_available()


@pytest.mark.slow
@pytest.mark.skipif(_pil_missing() is not None, reason="no qemu / arm toolchain")
def test_sil_equals_pil_bit_for_bit_for_the_c_example(tmp_path):
    from forecast_design.export.firmware import FirmwareOptions, export_firmware
    from forecast_design.runtime.pil import PIL_LINK_TIMEOUT_MS, python_closed_loop, run_pil

    opts = FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    c = resolve_controller(EXAMPLE_C)
    res = run_pil(controller=c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0, reference="square:0.2:0.125",
                  duration=0.2, out=tmp_path / "run.toml", work_dir=tmp_path / "fw", options=opts)
    assert res.fault is None and res.samples == res.expected == 400
    fw = export_firmware(out_dir=tmp_path / "fw2", controller=c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0,
                         options=opts, check_cycles=False)
    sil = python_closed_loop(fw.program, fw.design, "square:0.2:0.125", res.samples, options=opts)
    for name in ("tau_m", "tau_s", "u", "tau_frc_hat"):
        assert np.array_equal(res.arrays[name], sil[name]), name
    assert np.any(res.arrays["u"] != 0.0)
    worst = res.to_mapping()["max_instructions_per_step"]
    assert 100 < worst and 2.0 * worst < 84_000


@pytest.mark.slow
@pytest.mark.skipif(_pil_missing() is not None, reason="no qemu / arm toolchain")
@pytest.mark.parametrize("bad", ["1.0f / 0.0f"], ids=["inf"])
def test_pil_stops_a_nan_or_infinite_c_controller_with_fault_controller(tmp_path, bad, monkeypatch, capsys):
    """An infinity is a fault, not a command at the torque limit (the firmware checks u + hat before
    fd_step's saturation). One qemu run: the firmware's test ``!(x - x == 0)`` is the same for a NaN
    (x - x is NaN for both); the emulator and the simulator tests run the NaN."""
    _write(tmp_path, "nan.c", "static int n;\nvoid fd_user_init(float r) { (void)r; n = 0; }\n"
           "float fd_user_step(float a, float b, float c, float d) { (void)b; (void)c; (void)d; "
           f"return ++n > 50 ? {bad} : a; }}\n")
    monkeypatch.chdir(tmp_path)
    p = _main(capsys, "pil", "--controller", "nan.c", "--duration", "0.1", "--out", "run.toml", "--json", "-")
    assert p.returncode == 2, p.stderr
    doc = json.loads(p.stdout)
    assert doc["fault"] == "CONTROLLER" and doc["fault_index"] == 50


@pytest.mark.slow
@pytest.mark.skipif(_pil_missing() is not None, reason="no qemu / arm toolchain")
def test_the_firmware_export_measures_a_c_controller_against_the_cycle_budget(tmp_path, monkeypatch, capsys):
    """A step above the period's 84,000 cycles is refused in one line; above half of it, a warning."""
    def heavy(n):
        return ("static volatile float acc;\nvoid fd_user_init(float r) { (void)r; acc = 0.0f; }\n"
                "float fd_user_step(float a, float b, float c, float d) { unsigned i; (void)b; (void)c; (void)d;\n"
                f"    for (i = 0u; i < {n}u; ++i) {{ acc = acc + a; }}\n    return acc; }}\n")

    _write(tmp_path, "over.c", heavy(20_000))
    _write(tmp_path, "half.c", heavy(4_500))
    monkeypatch.chdir(tmp_path)
    p = _main(capsys, "export", "--firmware", "--controller", "over.c", "--out", "fw_over")
    assert p.returncode == 2 and "would overrun on the board" in p.stderr and p.stderr.count("\n") == 1, p.stderr
    assert not (tmp_path / "fw_over").exists()
    p = _main(capsys, "export", "--firmware", "--controller", "half.c", "--out", "fw_half", "--json", "-")
    assert p.returncode == 0 and "warning: C controller on the Cortex-M4" in p.stderr, p.stderr
    cyc = json.loads(p.stdout)["controller_cycles"]
    assert cyc["verdict"] == "warning" and 0.5 < cyc["max_budget_fraction"] < 1.0
    assert cyc["max_abs_diff_vs_host"] == 0.0
    assert "fd_user.c" in json.loads(p.stdout)["files"]


def test_a_python_controller_acts_on_the_torque_sensors_reading_like_the_compiled_one(tmp_path):
    # the code loop's measurement is the simulator's: with a torque sensor, the true spring torque plus its noise;
    # a P controller written as code then gives the compiled P's run (both in float64)
    src = _write(tmp_path, "p.py", "class P:\n    def reset(self, *a): pass\n"
                                   "    def step(self, t, tau_r, tau_s, theta, q): return 5.0 * (tau_r - tau_s)\n")
    kw = dict(reference=Step(amplitude=0.2), duration_s=0.2, seed=3, torque_sensor=TorqueSensor(noise_std_N_m=2e-3))
    code = simulate(_design(PythonController(source=str(src), class_name="P")), **kw)
    compiled = simulate(_design(resolve_controller("pd:5:0")), **kw)
    assert 1.5e-3 < np.std(code.tau_s - code.truth.tau_s) < 2.5e-3
    np.testing.assert_allclose(code.tau_m, compiled.tau_m, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(code.tau_s, compiled.tau_s, rtol=1e-12, atol=1e-12)


def test_a_python_controller_reads_the_encoders_jitter_like_the_compiled_one(tmp_path):
    # the code loop's readings are the simulator's: a jittered derived tau_s; a P written as code runs as pd:5:0
    src = _write(tmp_path, "p.py", "class P:\n    def reset(self, *a): pass\n"
                                   "    def step(self, t, tau_r, tau_s, theta, q): return 5.0 * (tau_r - tau_s)\n")
    kw = dict(reference=Step(amplitude=0.2), duration_s=0.2, seed=3, encoder_counts=2**16, encoder_jitter_counts=0.8)
    code = simulate(_design(PythonController(source=str(src), class_name="P")), **kw)
    compiled = simulate(_design(resolve_controller("pd:5:0")), **kw)
    assert np.max(np.abs(code.theta - code.truth.theta)) > 2 * np.pi / 2**16
    np.testing.assert_allclose(code.tau_m, compiled.tau_m, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(code.theta, compiled.theta, rtol=0, atol=0)
