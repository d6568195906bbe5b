"""emulate --scenario + run + diagnose: the diagnosis names the effect the emulated board carries (issue 13).

The board emulator runs in its own process, as a user starts it (``forecast-design emulate --scenario
s.toml``); ``run`` records over the pseudo-terminal it prints and ``diagnose`` reads the recording
with the scenario's nominal model only (the effect is withheld from it).
"""

import json
import os
import select
import signal
import subprocess
import sys

import pytest

from forecast_design.cli import main
from forecast_design.experiment import load_experiment
from forecast_design.params import Environment, Testbed

# The user's own set-up: a softer spring than Table 1 and their own environment, so that the run
# must take the nominal model from the scenario (--experiment) to match the emulated hardware.
SCENARIO = """format = "forecast-scenario/1"
description = "emulated board: k = 40 N m/rad, the user's environment, {effect} withheld from the model"

[sampling]
rate_hz = 2000.0

[testbed]
J_m = 0.133
d_m = 0.3
k = 40.0

[environment]
J_e = 0.02
d_e = 1.2649110640673518
k_e = 20.0
J_l = 0.0018
d_l = 0.35
locked = false

[[truth.effects]]
effect = "{effect}"
{fields}

[reference]
kind = "constant"
value = 0.0

[simulation]
duration_s = 1.0
"""


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _start_emulator(scenario, timeout_s=60.0):
    proc = subprocess.Popen([sys.executable, "-m", "forecast_design", "emulate", "--scenario", str(scenario)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    path = proc.stdout.readline().decode().strip() if ready else ""
    if not path:
        proc.kill()
        _, err = proc.communicate(timeout=10)
        pytest.fail(f"the emulator printed no pty path: {err.decode()[-400:]}")
    return proc, path


@pytest.mark.parametrize("effect,fields", [
    ("torque_gain", "gain = 0.7"),                                    # 30 % weaker motor than commanded
    ("delay", "delay_s = 0.003"),                                     # 6 samples of dead time
])
def test_emulate_scenario_run_and_diagnose_name_the_scenarios_effect(capsys, tmp_path, effect, fields):
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO.format(effect=effect, fields=fields))
    proc, port = _start_emulator(scenario)
    try:
        code, out, err = _cli(capsys, "run", "--port", port, "--experiment", scenario, "--compensator", "none",
                              "--reference", "square:0.5:1", "--duration", "3", "--timeout", "30", "--out", tmp_path / "rec.toml",
                              "--json")
        assert code == 0, err
        summary = json.loads(out)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)       # closes the pipes too
    assert proc.returncode == 0            # the emulator stops cleanly on SIGTERM
    assert summary["samples"] == 6000 and summary["lost"] == 0
    # the summary says what the run assumed, as recorded: the scenario's nominal model, the reference, the length
    assumed = summary["assumed"]
    assert assumed["design"]["testbed"] == Testbed(k=40.0).to_mapping() and assumed["rate_hz"] == 2000.0
    assert assumed["reference"] == "square:0.5:1" and assumed["duration_s"] == 3.0
    rec = load_experiment(tmp_path / "rec.toml")
    # the recording carries the scenario's nominal model (testbed and environment), not the defaults
    assert rec.design.testbed == Testbed(k=40.0)
    assert rec.design.environment == Environment(J_e=0.02, d_e=1.2649110640673518, k_e=20.0)
    assert {"u", "tau_frc_hat"} <= set(rec.signals.columns())   # analysable like a simulated run
    code, out, err = _cli(capsys, "diagnose", tmp_path / "rec.toml", "--json")
    assert code == 0, err
    verdict = json.loads(out)["verdict"]
    assert verdict["effect"] == effect and verdict["reduction"] > 0.9


def test_emulate_and_run_bad_inputs_exit_2_with_one_line(capsys, tmp_path):
    """Bad inputs of the chain: a scenario that does not parse, and --experiment together with --env."""
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENARIO.format(effect="stickiness", fields=""))
    code, _, err = _cli(capsys, "emulate", "--scenario", bad)
    assert code == 2 and "bad.toml" in err and "stickiness" in err and len(err.strip().splitlines()) == 1
    good = tmp_path / "s.toml"
    good.write_text(SCENARIO.format(effect="torque_gain", fields="gain = 0.7"))
    code, _, err = _cli(capsys, "run", "--port", "loop://", "--experiment", good, "--env", "soft",
                        "--out", tmp_path / "x.toml")
    assert code == 2 and "give --experiment or --env/--testbed, not both" in err
    code, _, err = _cli(capsys, "run", "--port", "loop://", "--testbed", "k=-3", "--out", tmp_path / "x.toml")
    assert code == 2 and "k must be > 0" in err
    assert not (tmp_path / "x.toml").exists()
