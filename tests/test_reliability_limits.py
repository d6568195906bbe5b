"""Bounded memory and time, no tracebacks, no wrong answers with exit 0 (issue 23).

CLI cases run in-process under the harness of ``test_reliability.py`` (a wall-clock bound, a cap on the data
segment, a bound on resident-memory growth, exactly one stderr line on error).
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import warnings
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from test_reliability import assert_one_line_error, cli, write_experiment

from forecast_design.limits import COMPUTATION_LIMITS, limit_of

SCENARIO_TEXT = (resources.files("forecast_design") / "data" / "example_scenario.toml").read_text()


def _scenario(folder: Path, name: str = "s.toml", *, replace=(), duration: float = 0.2) -> Path:
    text = re.sub(r"(?m)^duration_s = .*$", f"duration_s = {duration!r}", SCENARIO_TEXT)
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = folder / name
    path.write_text(text)
    return path


def _deep_toml(folder: Path, name: str = "deep.toml", depth: int = 1000) -> Path:
    path = folder / name
    path.write_text("x = " + "[" * depth + "]" * depth + "\n")
    return path


# --- files checked before they are read -----------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["check", "{f}"], ["simulate", "{f}", "--out", "o.toml"], ["tf", "--env", "{f}"],
                                  ["emulate", "--scenario", "{f}"], ["diagnose", "{f}"], ["tf", "--testbed", "{f}"]])
def test_a_toml_nested_1000_levels_is_one_line_not_a_recursion_error(tmp_path, capsys, argv):
    deep = _deep_toml(tmp_path)
    code, out, err = cli([a.format(f=deep) for a in argv], capsys)
    assert_one_line_error(code, err, "deep.toml", "nested more than 32 levels")


def test_a_huge_toml_is_refused_before_it_is_read(tmp_path, capsys):
    big = tmp_path / "big.toml"
    with open(big, "wb") as fh:                      # 1 GiB, sparse: no disk, and nothing may read it whole
        fh.truncate(2**30)
    for argv in (["check", big], ["simulate", big, "--out", tmp_path / "o.toml"], ["tf", "--env", big]):
        code, out, err = cli(argv, capsys)
        assert_one_line_error(code, err, "big.toml", "1073741824 bytes", "not read")


def _experiment_with_csv(folder: Path, raw: bytes) -> Path:
    toml = write_experiment(folder, "run")
    (folder / "run.csv").write_bytes(raw)
    return toml


@pytest.mark.parametrize("what", ["nul-file", "sparse-1GiB", "long-field", "long-header", "nul-in-row"])
def test_hostile_csv_files_are_one_line_in_bounded_memory(tmp_path, capsys, what):
    if what == "sparse-1GiB":
        toml = write_experiment(tmp_path, "run")
        with open(tmp_path / "run.csv", "wb") as fh:
            fh.truncate(2**30)
    elif what == "nul-file":
        toml = _experiment_with_csv(tmp_path, b"\x00" * 5000)
    elif what == "long-field":        # the csv module's field limit is 131,072 characters
        toml = _experiment_with_csv(tmp_path, b"t,tau_m,theta,q\n0,0,0,0\n0.001,\"" + b"1" * 140_000 + b"\",0,0\n")
    elif what == "long-header":
        toml = _experiment_with_csv(tmp_path, b"t,tau_m,theta,q," + b"x" * 200_000 + b"\n0,0,0,0,0\n")
    else:
        toml = _experiment_with_csv(tmp_path, b"t,tau_m,theta,q\n0,0,0,0\n0.001,0,\"0\x00\",0\n")
    for verb in ("check", "diagnose", "identify"):
        code, out, err = cli([verb, toml], capsys)       # cli() bounds time, memory growth (500 MB) and lines
        assert_one_line_error(code, err, "run.csv")


def test_every_log_limit_is_checked_before_the_csv_is_parsed(tmp_path, capsys, monkeypatch):
    """With the limits lowered to 1000 rows, a 2000-row log is refused by each verb, naming its limit."""
    toml = write_experiment(tmp_path, "run")         # 2000 rows
    (tmp_path / "runs").mkdir()
    write_experiment(tmp_path / "runs", "run")       # a folder of recorded runs for benchmark --runs
    for name in ("log_samples_check", "log_samples_identify", "log_samples_diagnose", "log_samples_benchmark"):
        monkeypatch.setitem(COMPUTATION_LIMITS, name, (1, 1000, "test"))
    for verb, reader in (("check", "check"), ("identify", "identify"), ("diagnose", "diagnose")):
        code, out, err = cli([verb, toml], capsys)
        assert_one_line_error(code, err, "run.csv", "2000 rows", f"{reader} reads at most 1000 rows")
    code, out, err = cli(["benchmark", "--runs", tmp_path / "runs", "--out", tmp_path / "b", "--no-plots"], capsys)
    assert_one_line_error(code, err, "run.csv", "2000 rows", "benchmark --runs reads at most 1000 rows")
    assert not (tmp_path / "b").exists()
    code, out, err = cli(["identify", "--csv", tmp_path / "run.csv", "--time", "t", "--position", "theta",
                          "--force", "tau_m"], capsys)
    assert_one_line_error(code, err, "2000 rows", "identify reads at most 1000 rows")
    # the size check comes first: a file too large for the rows it may hold is refused from its size alone
    monkeypatch.setitem(COMPUTATION_LIMITS, "log_samples_check", (1, 10, "test"))
    code, out, err = cli(["check", toml], capsys)
    assert_one_line_error(code, err, "bytes of rows, more than 10 rows of 4 cells can hold")


def test_the_stated_log_limits():
    """The limits docs/reliability.md states (memory per sample: the next test)."""
    assert limit_of("log_samples_check") == 2**23 and limit_of("log_samples_identify") == 2**22
    assert limit_of("log_samples_diagnose") == 2**22 and limit_of("log_samples_benchmark") == 2**20


_LOG = """
import sys, numpy as np
from forecast_design.experiment import experiment_from_arrays, save_experiment
from forecast_design.params import Design
n, path = int(sys.argv[1]), sys.argv[2]
rng = np.random.default_rng(1)
t = np.arange(n) / 2000.0
tau_m = 0.5 * np.sin(2 * np.pi * 0.7 * t) + 0.2 * np.sign(np.sin(2 * np.pi * 0.13 * t))
theta = 0.3 * np.sin(2 * np.pi * 0.7 * t - 0.3) + 1e-4 * rng.standard_normal(n)
q = 0.28 * np.sin(2 * np.pi * 0.7 * t - 0.35)
save_experiment(experiment_from_arrays(Design.nominal("exp-soft"), 2000.0, t, tau_m, theta, q,
                                       tau_s=58.0 * (theta - q), tau_r=0.5 * np.sign(np.sin(t))), path)
"""


def _peak_rss_bytes(argv: list[str]) -> int:
    """Peak resident size of a child process running ``argv`` (os.wait4's rusage) [bytes]."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    # identify's answer on this log (a sine through a spring, no friction term to speak of) is
    # "not identifiable", exit 3, after the whole fit: the peak is the same path's
    assert proc.returncode in (0, 3), err[-500:]
    return usage.ru_maxrss * 1024


@pytest.fixture(scope="module")
def memory_logs(tmp_path_factory):
    """The 100k- and 300k-sample logs of the memory test, written once for its three verbs (they only read them)."""
    folder = tmp_path_factory.mktemp("memory")
    paths = []
    for n in (100_000, 300_000):
        paths.append(folder / f"run{n}.toml")
        subprocess.run([sys.executable, "-c", _LOG, str(n), str(paths[-1])], check=True, timeout=600)
    return paths


@pytest.mark.slow
@pytest.mark.parametrize("verb, stated", [("check", 300), ("identify", 270), ("diagnose", 400)])
def test_peak_memory_per_sample_is_what_the_limits_state(memory_logs, verb, stated):
    """The slope of a verb's peak resident size between a 100k- and a 300k-sample log, in a fresh process."""
    peaks = [_peak_rss_bytes([sys.executable, "-m", "forecast_design", verb, str(path)]) for path in memory_logs]
    per_sample = (peaks[1] - peaks[0]) / 200_000
    assert per_sample < 1.2 * stated, f"{verb}: {per_sample:.0f} B per sample, stated about {stated}"


# --- counts bounded before allocation ---------------------------------------------------------------------------------


@pytest.mark.parametrize("repetitions", [1_000_000_000, 10_000_000_000, 10_001])
def test_variability_repetitions_are_bounded_before_anything_is_allocated(tmp_path, capsys, repetitions):
    s = _scenario(tmp_path, replace=[("[truth]", f"[variability]\nrepetitions = {repetitions}\n\n[truth]")])
    for extra in ([], ["--repetitions", "all"]):
        code, out, err = cli(["simulate", s, "--out", tmp_path / "r.toml", *extra], capsys)
        assert_one_line_error(code, err, "s.toml", "[variability]", "repetitions", "[1, 10000]")


def test_a_batch_is_bounded_by_its_total_samples(tmp_path, capsys):
    s = _scenario(tmp_path, duration=100.0, replace=[("[truth]", "[variability]\nrepetitions = 60\n\n[truth]")])
    code, out, err = cli(["simulate", s, "--out", tmp_path / "r.toml", "--repetitions", "all"], capsys)
    assert_one_line_error(code, err, "--repetitions: 60 runs x 200000 samples", "[1, 10000000]")
    code, out, err = cli(["benchmark", "--repetitions", "1000", "--duration", "10", "--out", tmp_path / "b"], capsys)
    assert_one_line_error(code, err, "benchmark cell of 1000 repetitions", "[1, 10000000]")


@pytest.mark.parametrize("grid, words", [
    ("k_e = {log = [0.1, 100], n = 100000000}", ["n must be an integer in [2, 10000]"]),
    ("k_e = {log = [0.1, 100], n = 9223372036854775807}", ["n must be an integer in [2, 10000]"]),
    ("k_e = {log = [0.1, 100], n = 100}\nJ_e = {log = [0.001, 1], n = 100}\nd_e = {lin = [0.0, 1.0], n = 100}",
     ["100 x 100 x 100 = 1000000 environments", "(10000)"]),
    ("k_e = [" + ", ".join(["1.0"] * 10001) + "]", ["10001 values"]),
])
def test_environment_grids_are_counted_before_any_environment_is_built(tmp_path, capsys, grid, words):
    env = tmp_path / "g.toml"
    env.write_text("[environment]\n" + grid + "\n")
    for argv in (["tf", "--env", env], ["tune-q", "--observer", "ea-fob", "--env", env],
                 ["benchmark", "--envs", env, "--out", tmp_path / "b"]):
        code, out, err = cli(argv, capsys)
        assert_one_line_error(code, err, "g.toml", *words)


# --- tracebacks and wrong answers with exit 0 ------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["margins", "--sampled", "--delay-samples", "80"],
                                  ["margins", "--sampled", "--delay-samples", "100"],
                                  ["tune-q", "--observer", "ea-fob", "--envs", "soft", "--sampled", "--delay-samples",
                                   "80"],
                                  ["margins", "--sampled", "--delay-samples", "60", "--rate-hz", "100000"]])
def test_delays_beyond_double_precision_are_one_line(capsys, argv):
    code, out, err = cli(argv, capsys)
    assert_one_line_error(code, err, "delay_samples", "decades", "give fewer delay samples")


def _state_space_max_pole(env: str, kind: str | None, d: int, rate: float = 2000.0) -> float:
    """Largest |z| of the sampled loop as python-control's state-space interconnection (delays exact, z = 0)."""
    import control as ct

    from forecast_design.compensators import compensator_strategy
    from forecast_design.controllers import PAPER_PD, controller_law
    from forecast_design.params import Compensator, Design
    from forecast_design.symbolic import force_plant_tf, motor_angle_tf

    T = 1.0 / rate
    design = Design.nominal(env)

    def ss(num, den, u, y, dt=T):
        return ct.ss(ct.tf(np.asarray(num, float), np.asarray(den, float), dt), inputs=u, outputs=y)

    pd = controller_law(PAPER_PD, rate).feedback_tf()     # the loop's u = -C(z) tau_s (+ reference path)
    blocks = [ss(pd.num, pd.den, "e", "u"), ss([1.0], [1.0] + [0.0] * d, "c", "a")]
    for tf, y in ((force_plant_tf(design), "tau_s"), (motor_angle_tf(design), "theta")):
        z = ct.sample_system(ct.ss(ct.tf(np.asarray(tf.num, float), np.asarray(tf.den, float))), T, "zoh")
        blocks.append(ct.ss(z.A, z.B, z.C, z.D, T, inputs="a", outputs=y))
    terms = ["u"]
    if kind is not None:
        comp = Compensator(kind=kind, w_q_hz=10.0)
        filters = compensator_strategy(comp).discrete_filters(comp, design, rate)
        gm, gs, gt = filters.from_tau_m, filters.from_tau_s, filters.from_theta
        blocks += [ss([1.0], [1.0, 0.0], "c", "cp"), ss(gm.num, gm.den, "cp", "hm"), ss(gs.num, gs.den, "tau_s", "hs")]
        terms += ["hm", "hs"]
        if gt is not None:
            blocks.append(ss(gt.num, gt.den, "theta", "ht"))
            terms.append("ht")
    blocks += [ct.summing_junction(terms, "c", dt=T), ct.summing_junction(["r", "-tau_s"], "e", dt=T)]
    with warnings.catch_warnings():          # theta feeds nothing in the DOB loops: python-control says so
        warnings.simplefilter("ignore", UserWarning)
        closed = ct.interconnect(blocks, inputs="r", outputs="tau_s")
    return float(np.max(np.abs(np.linalg.eigvals(closed.A))))


@pytest.mark.parametrize("env, kind, d", [("soft", None, 60), ("soft", "ea-fob", 40), ("soft", "ea-fob", 50),
                                          ("soft", "lo-dob", 60), ("stiff", None, 30), ("stiff", None, 40),
                                          ("stiff", "lo-dob", 10), ("stiff", "lo-dob", 20)])
def test_long_delays_the_exact_analysis_accepts_agree_with_a_state_space_model(env, kind, d):
    from forecast_design.loops.sampled import sampled_force_loop
    from forecast_design.params import Compensator, Design

    loop = sampled_force_loop(Design.nominal(env), None if kind is None else Compensator(kind=kind, w_q_hz=10.0),
                              delay_samples=d)
    assert loop.stable == (_state_space_max_pole(env, kind, d) < 1.0)


def test_tune_q_at_1_hz_is_one_line_not_casadi_noise(capfd):
    from forecast_design.cli import main

    code = main(["tune-q", "--observer", "ea-fob", "--sampled", "--rate-hz", "1", "--band", "0.01", "0.4"])
    out, err = capfd.readouterr()                      # file-descriptor level: casadi writes from C++
    assert_one_line_error(code, err, "no observer is unstable", "first: soft")
    assert "CasADi" not in err and "nan" not in out.lower()


@pytest.mark.parametrize("argv", [
    ["margins", "--env", "stiff", "--compensator", "ea-fob", "--w-q-hz", "1500", "--sampled", "--rate-hz", "2000"],
    ["export", "--compensator", "ea-fob", "--w-q-hz", "1500", "--out", "{tmp}/c"],
    ["simulate", "{scenario}", "--out", "{tmp}/r.toml"],
    ["tune-q", "--observer", "ea-fob", "--envs", "soft", "--sampled", "--rate-hz", "50", "--band", "1", "24.9",
     "--max-margin", "30"],
])
def test_a_q_cutoff_at_or_above_nyquist_is_refused_everywhere(tmp_path, capsys, argv):
    scenario = _scenario(tmp_path, replace=[("w_q_hz = 10.0", "w_q_hz = 1500.0")])
    code, out, err = cli([a.format(tmp=tmp_path, scenario=scenario) for a in argv], capsys)
    assert_one_line_error(code, err, "w_q_hz", "Nyquist")
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("delay_samples", [0, 1, 2])
@pytest.mark.parametrize("method", ["tustin", "zoh", "backward-euler"])
def test_the_sampled_margin_and_the_simulation_agree_on_stability(method, delay_samples):
    """The sampled analysis says unstable exactly when the simulated run diverges: with the toolbox's
    convention (the command applied within its period, delay 0, as the simulator runs it) and with a
    board that applies it d periods late (``delay_samples = d`` against a simulated ``delay`` effect
    of d periods), for the controller's own discretization."""
    from forecast_design.analysis import loop_margins
    from forecast_design.controllers import PD
    from forecast_design.effects import Delay
    from forecast_design.loops import COMMAND_DELAY_SAMPLES, sampled_force_loop
    from forecast_design.params import Compensator, Design
    from forecast_design.simulation import simulate
    from forecast_design.simulation.references import Step

    assert COMMAND_DELAY_SAMPLES == 0
    rate = 2000.0
    design = Design.nominal("stiff")
    effects = [Delay(delay_s=delay_samples / rate)] if delay_samples else []
    verdicts = []
    for P in (5.0, 100.0, 300.0, 3000.0):
        ctrl = PD(P=P, D=0.02 * P, T_f=0.0008, discretization=method)
        for kind in ("none", "ea-fob", "lo-dob"):
            for w_q in (200.0, 950.0):
                comp = Compensator(kind=kind, w_q_hz=w_q)
                kwargs = {} if delay_samples == COMMAND_DELAY_SAMPLES else {"delay_samples": delay_samples}
                dm = loop_margins(design, comp, controller=ctrl, sampled=True, rate_hz=rate, **kwargs)
                duration = 0.5
                if not dm.stable:   # long enough for 25 e-folds of the fastest-growing pole (a slow one: seconds)
                    growth = np.log(np.abs(sampled_force_loop(design, comp, controller=ctrl, rate_hz=rate,
                                                              delay_samples=delay_samples).closed_loop_poles).max())
                    duration = min(max(duration, 25.0 / growth / rate), 10.0)
                run = simulate(Design(testbed=design.testbed, environment=design.environment, controller=ctrl,
                                      compensator=comp), effects=effects,
                               reference=Step(amplitude=0.2), duration_s=duration, rate_hz=rate,
                               process_noise_std=0.0, encoder_counts=None)
                verdicts.append((P, kind, w_q, dm.stable, run.diverged_at_s is None))
                if kind == "none":
                    break
    assert all(stable == ran for *_, stable, ran in verdicts), verdicts
    assert {stable for *_, stable, _ in verdicts} == {True, False}     # the sweep sees both answers


def _nan_prone_log(folder: Path, name: str, env, rate: float) -> Path:
    from forecast_design.experiment import experiment_from_arrays, save_experiment
    from forecast_design.params import Design, Testbed

    n = 2000 if rate > 1 else 300
    t = np.arange(n) / rate
    tau_m = 0.5 * np.sin(2 * np.pi * 0.7 * t) + 0.2 * np.sign(np.sin(0.9 * t))
    theta = 0.01 * np.sin(6 * t) + 1e-3 * np.random.default_rng(0).standard_normal(n)
    exp = experiment_from_arrays(Design(testbed=Testbed(), environment=env), rate, t, tau_m, theta,
                                 0.005 * np.sin(6 * t))
    return save_experiment(exp, folder / name)


def test_diagnose_text_never_prints_nan(tmp_path, capsys):
    from forecast_design.params import Environment

    for name, env, rate in (("tiny.toml", Environment(J_e=1e-300, d_e=0.063, k_e=5.0, J_l=0.0, d_l=0.35), 1000.0),
                            ("onehz.toml", Environment(J_e=0.001, d_e=0.063, k_e=5.0), 1.0)):
        toml = _nan_prone_log(tmp_path, name, env, rate)
        code, out, err = cli(["diagnose", toml], capsys)
        if code == 2:
            assert_one_line_error(code, err, name)
            continue
        assert code == 0 and not re.search(r"\bnan\b", out + err, re.IGNORECASE), out


def test_replay_and_location_texts_say_what_they_cannot_evaluate():
    from forecast_design.gap.replay import ReplayCheck

    check = ReplayCheck(window_s=0.5, n_windows=3, tau_s_error_before=math.nan, tau_s_error_after=math.nan,
                        theta_error_before=math.nan, theta_error_after=math.nan, tau_s_rms=0.1, worst_windows_s=())
    assert "cannot be replayed" in check.summary("coulomb") and "nan" not in check.summary("coulomb")
    from forecast_design.gap.locate import Location

    where = Location(time_windows_s=(), frequency_band_hz=(0.1, 2.0), speed_band_rad_s=(0.0, 1.0), angle_span_rad=0.5,
                     n_reversals=1, angle_fraction=0.1, reversal_ratio=math.nan, torque_fraction=0.2,
                     equation_share={"motor": 1.0}, notes=())
    text = where.summary()
    assert "too few" in text and "nan" not in text.lower()


def test_benchmark_runs_reports_every_unreadable_experiment_file(tmp_path, capsys):
    runs = tmp_path / "runs"
    runs.mkdir()
    s = _scenario(tmp_path, duration=0.3)
    for i in range(2):
        code, _, err = cli(["simulate", s, "--out", runs / f"ok{i}.toml"], capsys)
        assert code == 0, err
    (runs / "binary.toml").write_bytes(b"\x00\xff\xfe" * 100)
    text = (runs / "ok0.toml").read_text()
    (runs / "truncated.toml").write_text(text[: len(text) // 2] + '\n[testbed\nJ_m = ')
    os.mkfifo(runs / "fifo.toml")
    (runs / "folder.toml").mkdir()
    os.symlink("loop_b.toml", runs / "loop_a.toml")
    os.symlink("loop_a.toml", runs / "loop_b.toml")
    os.symlink("missing.toml", runs / "dangling.toml")
    (runs / "scenario.toml").write_text(SCENARIO_TEXT)          # another format: left alone, not reported
    code, out, err = cli(["benchmark", "--runs", runs, "--out", tmp_path / "b", "--no-plots", "--workers", "1",
                          "--json", tmp_path / "b.json"], capsys)
    assert code in (0, 1), err
    warned = [line for line in err.splitlines() if line.startswith("forecast-design: warning: skipped ")]
    names = ("binary.toml", "truncated.toml", "fifo.toml", "folder.toml", "loop_a.toml", "loop_b.toml",
             "dangling.toml")
    for name in names:
        assert sum(name in line for line in warned) == 1, (name, err)
    assert not any("scenario.toml" in line for line in warned)
    doc = json.loads((tmp_path / "b.json").read_text())
    assert len(doc["run"]["unreadable"]) == len(names) and doc["run"]["runs"] == 2


# --- smaller items ---------------------------------------------------------------------------------------------------


def test_a_utf8_bom_toml_is_accepted_everywhere(tmp_path, capsys):
    toml = write_experiment(tmp_path, "run")
    toml.write_bytes(b"\xef\xbb\xbf" + toml.read_bytes())
    code, out, err = cli(["check", toml], capsys)
    assert code == 0, err
    s = _scenario(tmp_path)
    s.write_bytes(b"\xef\xbb\xbf" + s.read_bytes())
    env = tmp_path / "env.toml"
    env.write_bytes(b"\xef\xbb\xbf[environment]\nk_e = 20.0\nJ_e = 0.02\nd_e = 1.0\n")
    for argv in (["simulate", s, "--out", tmp_path / "o.toml"], ["tf", "--env", env]):
        code, out, err = cli(argv, capsys)
        assert code == 0, err


@pytest.mark.parametrize("replace, words", [
    ([("substeps = 10", "substeps = 1"), ("k = 58.0", "k = 5800000.0")], ["RK4 step"]),
    ([("[reference]", '[[truth.effects]]\neffect = "stiction"\nF_s = 0.5\nF_c = 0.4\n\n[reference]')],
     ["effect 'stiction' is given 2 times"]),
    ([("encoder_counts = 2000000", "encoder_counts = -5")], ["[simulation] encoder_counts"]),
    ([("encoder_counts = 2000000", "encoder_counts = 2000000\nencoder_jitter_counts = -0.5")],
     ["[simulation] encoder_jitter_counts", ">= 0"]),
    ([("encoder_counts = 2000000", "encoder_counts = 0\nencoder_jitter_counts = 0.5")],
     ["[simulation] encoder_jitter_counts", "needs encoder_counts"]),
    ([('discretization = "tustin"', 'discretization = "euler"')], ["discretization", "tustin"]),
    ([("k_e = 100.0", "k_e = 1e+32")], ["k_e = 1e+32"]),
])
def test_scenario_errors_name_the_file(tmp_path, capsys, replace, words):
    s = _scenario(tmp_path, replace=replace)
    code, out, err = cli(["simulate", s, "--out", tmp_path / "o.toml"], capsys)
    assert_one_line_error(code, err, f"error: {s}: ", *words)


def test_emulate_scenario_errors_name_the_file(tmp_path, capsys):
    s = _scenario(tmp_path, replace=[("k = 58.0", "k = 580000000.0")])      # unstable even with 10 substeps
    code, out, err = cli(["emulate", "--scenario", s], capsys)
    assert_one_line_error(code, err, f"error: {s}: ", "RK4 step")


def test_digit_separators_in_a_controller_are_refused(capsys):
    for argv in (["margins", "--controller", "pd:5_0:0"], ["export", "--controller", "pd:5:0_1", "--out", "x"]):
        code, out, err = cli(argv, capsys)
        assert_one_line_error(code, err, "is not a decimal number", "5_0" if "margins" in argv else "0_1")
    assert not os.path.exists("x")


def test_a_garbled_checksum_line_is_an_error_not_a_silent_skip(tmp_path, capsys):
    toml = write_experiment(tmp_path, "run")
    for garbled in ("# data-crc32 = XYZ, data-bytes = 12", "#data-crc32 = 0000000g, data-bytes = 1",
                    "# data-crc32 = 1234abcd data-bytes=5"):
        toml.write_text(re.sub(r"(?m)^# data-crc32.*\n", "", toml.read_text()) + garbled + "\n")
        code, out, err = cli(["check", toml], capsys)
        assert_one_line_error(code, err, "run.toml", "'# data-crc32' line", "cannot vouch for")


def test_diagnose_and_benchmark_warnings_carry_the_prefix():
    """Every line a verb writes on stderr in its own words starts with 'forecast-design: ' (source check)."""
    root = Path(__file__).resolve().parents[1] / "forecast_design" / "cli"
    bad = []
    for path in root.glob("*.py"):
        text = path.read_text()
        for match in re.finditer(r'print\(f?"((?:warning|note|error):[^"]*)"', text):
            bad.append(f"{path.name}: {match.group(1)[:40]}")
    assert not bad, bad


def test_bench_gap_errors_name_effect_words(capsys):
    code, out, err = cli(["bench-gap", "--per-effect", "1", "--duration", "0.001"], capsys)
    assert_one_line_error(code, err, "no identifiable scenario for coulomb")
    assert "<Effect" not in err and "Effect." not in err


def test_run_writes_its_json_summary_after_a_late_write_failure_and_says_so(tmp_path, capsys, monkeypatch):
    """The emulator on a pseudo-terminal; the run's folder becomes a file while the run goes on."""
    import shutil
    import threading

    import forecast_design.runtime.board as board
    from forecast_design.runtime import open_pty, serve_emulator

    monkeypatch.chdir(tmp_path)
    lab = tmp_path / "lab"
    real = board.record_to_experiment

    def sabotage(*args, **kwargs):          # after the run, before it is saved: the folder is gone
        shutil.rmtree(lab)
        lab.write_text("the folder became a file mid-run")
        return real(*args, **kwargs)

    monkeypatch.setattr(board, "record_to_experiment", sabotage)
    master, slave, path = open_pty()
    stop = threading.Event()
    th = threading.Thread(target=serve_emulator, args=(master,), kwargs={"stop": stop}, daemon=True)
    th.start()
    try:
        code, out, err = cli(["run", "--port", path, "--out", lab / "run.toml", "--duration", "0.05", "--timeout", "30",
                              "--json", tmp_path / "summary.json"], capsys)
    finally:
        stop.set()
        th.join(5)
        os.close(slave)
    assert_one_line_error(code, err, "recovery file", "run summary written to", "summary.json")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["samples"] + summary["lost"] == 100
    assert list(tmp_path.glob("forecast-run-recovery-*.toml"))


# --- long loops show progress -------------------------------------------------------------------------------------


@pytest.mark.parametrize("argv, done", [
    (["simulate", "{scenario}", "--repetitions", "3", "--out", "{tmp}/r.toml"], "/3"),
    (["benchmark", "--controller", "pd:5:0.1", "--envs", "soft,stiff", "--compensator", "none", "--repetitions", "2",
      "--duration", "0.05", "--reference", "step:0.2", "--out", "{tmp}/b", "--no-plots", "--workers", "1"], "/2"),
])
def test_long_loops_show_progress_on_a_terminal(tmp_path, argv, done):
    """On a terminal (a pseudo-terminal here) the loop's bar counts done/total on stderr (tqdm may skip
    drawing the last step within its 0.1 s refresh, so any step of the total counts); piped, it stays silent."""
    import fcntl
    import pty
    import select
    import struct
    import termios

    text = SCENARIO_TEXT.replace("[reference]", "[variability]\nrepetitions = 3\n\n[reference]", 1) \
        if "repetitions =" not in SCENARIO_TEXT else SCENARIO_TEXT
    (tmp_path / "s.toml").write_text(re.sub(r"(?m)^duration_s = .*$", "duration_s = 0.05", text))
    args = [a.format(scenario=tmp_path / "s.toml", tmp=tmp_path) for a in argv]
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))   # a terminal has a width
    proc = subprocess.Popen([sys.executable, "-m", "forecast_design", *args], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=slave, cwd=tmp_path)
    os.close(slave)
    seen = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:         # the child closed the terminal
                break
            if not chunk:
                break
            seen += chunk
        elif proc.poll() is not None:
            break
    proc.stdout.read()
    proc.stdout.close()
    assert proc.wait() == 0, seen.decode(errors="replace")
    os.close(master)
    assert re.search(rf"[1-9]{done}", seen.decode(errors="replace")), seen[-500:]
    piped = subprocess.run([sys.executable, "-m", "forecast_design", *args], capture_output=True, text=True,
                           cwd=tmp_path)
    assert piped.returncode == 0 and done not in piped.stderr, piped.stderr
