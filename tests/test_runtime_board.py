"""Board over a real pty against the emulator: clean run, faults, disconnect, recorded experiment."""

import os
import threading

import numpy as np
import pytest

from forecast_design.errors import ForecastError, ParameterError
from forecast_design.experiment import load_experiment
from forecast_design.params import Design, environment_preset
from forecast_design.runtime import Faults, LinkError, open_pty, parse_fault, run_on_port, serve_emulator
from forecast_design.runtime.emulator import warm_up


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up(Design(environment=environment_preset("exp-soft")))


@pytest.fixture
def emulator():
    started = []

    def start(faults=None, noise_std=1e-3, effects=()):
        master, slave, path = open_pty()
        stop = threading.Event()
        th = threading.Thread(target=serve_emulator, args=(master,), kwargs={"faults": faults, "stop": stop,
                                                                          "noise_std": noise_std,
                                                                          "effects": effects},
                              daemon=True)
        th.start()
        started.append((stop, th, master, slave))
        return path

    yield start
    for stop, th, master, slave in started:
        stop.set()
        th.join(5)
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


def test_clean_run_records_every_sample_and_matches_simulator(emulator, tmp_path):
    from forecast_design.export.c import resolve_design
    from forecast_design.simulation.references import Step
    from forecast_design.simulation.run import simulate

    path = emulator(noise_std=0.0)
    r = run_on_port(path, out=tmp_path / "run.toml", reference="step:0.2", duration=0.5, compensator="ea-fob")
    assert r.lost_ranges == () and r.to_mapping()["samples"] == 1000 and r.lost == 0 and r.corrupt_frames == 0 and r.resyncs == 0
    exp = load_experiment(tmp_path / "run.toml")
    assert exp.n_samples == 1000
    cols = exp.signals.columns()
    assert np.all(cols["received"] == 1.0)
    # independent implementation: the simulator's compiled closed loop, same design, no noise;
    # the emulator runs the uploaded float32 coefficients, hence the small tolerance
    sim = simulate(resolve_design(compensator="ea-fob"), reference=Step(amplitude=0.2), duration_s=0.5,
                   process_noise_std=0.0)
    sim_tau_s = sim.to_experiment().signals.columns()["tau_s"]
    assert np.max(np.abs(cols["tau_s"] - sim_tau_s)) < 2e-3
    assert np.max(np.abs(cols["tau_s"])) > 0.1


@pytest.mark.parametrize("effect", ["delay", "backlash", "torque_gain"])
def test_emulated_board_honours_the_simulators_effects(emulator, tmp_path, effect):
    from forecast_design import effects as fx
    from forecast_design.simulation.run import plant_stepper

    chosen = {"delay": fx.Delay(delay_s=3e-3), "backlash": fx.Backlash(width_rad=4e-3),
              "torque_gain": fx.TorqueGain(gain=0.7)}[effect]
    path = emulator(noise_std=0.0, effects=(chosen,))
    run_on_port(path, out=tmp_path / "run.toml", reference="step:0.2", duration=0.3, compensator="ea-fob")
    cols = load_experiment(tmp_path / "run.toml").signals.columns()
    # replay the recorded commands through the simulator's own plant with and without the effect
    design = Design(environment=environment_preset("exp-soft"))
    with_fx = plant_stepper(design, (chosen,), n=cols["t"].size, process_noise_std=0.0)
    without = plant_stepper(design, (), n=cols["t"].size, process_noise_std=0.0)
    a, b = [], []
    for cmd in cols["tau_m"]:
        a.append(with_fx.measure()[0])
        b.append(without.measure()[0])
        with_fx.advance(cmd)
        without.advance(cmd)
    # the stream carries float32 samples (the replayed commands are rounded): agreement to one
    # encoder count (2 pi / 2e6 rad), which a sample at a count boundary may cross
    np.testing.assert_allclose(cols["theta"], a, rtol=0, atol=1.01 * 2 * np.pi / 2e6)
    assert np.max(np.abs(np.array(a) - np.array(b))) > 1e-4   # the effect is there, not dropped


def test_flipped_and_dropped_bytes_are_counted_not_hidden(emulator, tmp_path):
    path = emulator(parse_fault(["flip:3e-4", "drop:3e-4", "seed:3"]))
    r = run_on_port(path, out=tmp_path / "run.toml", duration=0.5)
    assert r.lost > 0 and r.corrupt_frames + r.resyncs > 0
    assert r.samples + r.lost == 1000
    exp = load_experiment(tmp_path / "run.toml")
    received = exp.signals.columns()["received"]
    assert int(np.sum(received == 0.0)) == r.lost - (1000 - exp.n_samples)


def test_disconnect_mid_run_saves_received_and_raises(emulator, tmp_path):
    path = emulator(Faults(disconnect_after=300))
    with pytest.raises(LinkError) as info:
        run_on_port(path, out=tmp_path / "run.toml", duration=0.5, timeout=0.5)
    assert isinstance(info.value, ForecastError)
    summary = info.value.summary
    # bytes still in the pty buffer die with the cable, so at most the 300 sent arrive (on a
    # loaded host possibly none); every one of the 1000 is either received or counted lost
    assert 0 <= summary["samples"] <= 300 and summary["samples"] + summary["lost"] == 1000
    assert summary["lost_ranges"][-1][1] == 1000
    if summary["samples"] == 0:
        assert info.value.saved is None and "nothing received" in str(info.value)
        return
    received = load_experiment(info.value.saved).signals.columns()["received"]
    assert int(received.sum()) == summary["samples"] and received[-1] == 1.0


def test_bad_fault_option_is_parameter_error():
    with pytest.raises(ParameterError, match="fault 'flop:1'"):
        parse_fault(["flop:1"])
