"""Processor-in-the-loop: the board firmware on qemu (netduinoplus2) in lock-step with the virtual testbed,
against the all-Python closed loop with the same discrete controller.

Bound (stated in docs/firmware.md): the firmware loop equals the Python loop run in float32 with the
firmware's own sensor conversion (``python_closed_loop(dtype=np.float32)``) within PIL_BOUND_N_M on
every signal; measured: 0 (bit-identical, -ffp-contract=off). Against the float64 design controller fed
the firmware's own float32 inputs, the commands differ by float32 rounding only (FLOAT64_BOUND_REL of the
largest command). Cost: instructions per control period from qemu -icount against 84,000 cycles.
"""

import json

import numpy as np
import pytest

from forecast_design.export.firmware import FirmwareOptions
from forecast_design.experiment import load_experiment
from forecast_design.runtime.pil import PIL_LINK_TIMEOUT_MS, python_closed_loop, qemu_available, run_pil

NO_PIL = qemu_available()
pytestmark = pytest.mark.skipif(NO_PIL is not None, reason=str(NO_PIL))

#: Firmware vs the float32 Python loop, any signal [N m or rad]: float32 bit-identity up to one ulp of 1 N m.
PIL_BOUND_N_M = 1e-7
#: Firmware commands vs the float64 design controller on the same inputs, relative to max |u| [-].
FLOAT64_BOUND_REL = 1e-6
SFM = {"viscous": 0.05, "coulomb": 0.02, "offset": 0.001}
#: Edges at k = 150, 250, 300, 350 where the host's float64 t / period rounds below the half period:
#: the software in the loop must use the firmware's own reference generator to match it.
REFERENCE = "square:0.2:0.05"
CASES = [("none", None), ("sfm", SFM), ("ea-fob", None), ("lo-dob", None), ("ld-dob", None), ("motor-fob", None)]


@pytest.mark.slow
@pytest.mark.parametrize("compensator, sfm", CASES, ids=[c for c, _ in CASES])
def test_pil_matches_the_python_closed_loop(tmp_path, compensator, sfm):
    opts = FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    res = run_pil(compensator=compensator, env="exp-soft", w_q_hz=10.0, sfm_params=sfm,
                  reference=REFERENCE, duration=0.2, out=tmp_path / "run.toml", work_dir=tmp_path / "fw",
                  options=opts)
    assert res.fault is None and res.samples == res.expected == 400
    from forecast_design.export.firmware import export_firmware

    fw = export_firmware(out_dir=tmp_path / "fw2", compensator=compensator, env="exp-soft", w_q_hz=10.0,
                         sfm_params=sfm, options=opts)
    py = python_closed_loop(fw.program, fw.design, REFERENCE, res.samples, options=opts)
    for name in ("tau_m", "theta", "q", "tau_s", "tau_r", "u", "tau_frc_hat"):
        assert np.max(np.abs(res.arrays[name] - py[name])) <= PIL_BOUND_N_M, name
    assert np.any(res.arrays["theta"] != 0.0)                 # the loop moved the motor
    if compensator != "none":
        assert np.any(res.arrays["tau_frc_hat"] != 0.0)       # and the compensator acted
    # the firmware's commands vs the float64 controller on the inputs the firmware saw
    ref = fw.program.make_step(np.float64)
    cmd = ref.run(res.arrays["tau_r"], res.arrays["tau_s"], res.arrays["theta"])
    assert np.max(np.abs(cmd - res.arrays["tau_m"])) <= FLOAT64_BOUND_REL * np.max(np.abs(res.arrays["u"]))
    # cost: instructions per period (qemu -icount) x CPI bound 2 far inside the 84,000-cycle budget
    assert 100 < res.instructions_per_step and 2.0 * res.instructions_per_step < 0.05 * 84_000
    # recorded in the experiment format with u and tau_frc_hat, like a simulated run
    cols = load_experiment(res.path).signals.columns()
    np.testing.assert_allclose(cols["tau_frc_hat"], res.arrays["tau_frc_hat"], rtol=0, atol=0)
    np.testing.assert_allclose(cols["u"], res.arrays["u"], rtol=0, atol=0)


def test_an_unwritable_out_is_refused_before_the_firmware_is_built(tmp_path):
    # a PIL session is not free to repeat: its output is probed before the build, like `run`'s
    from forecast_design.errors import ParameterError

    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where a folder is expected\n")
    with pytest.raises(ParameterError, match="--out"):
        run_pil(compensator="none", duration=0.05, out=blocker / "run.toml", work_dir=tmp_path / "fw")
    assert not (tmp_path / "fw").exists()


CONTROLLER_CASES = ["pid:8:160:0", "pid:6:20:0.05:0.002:anti_windup=clamping:u_min=-0.3:u_max=0.3",
                    "tf:0.006,0.36,3/0.002,0.504,1", "discrete:5.2,-5.1/1,-1:rate_hz=2000",
                    "pd:5:0.1:0.0008:discretization=tustin:derivative_on=measurement:feedforward=0.5"]


@pytest.mark.slow
@pytest.mark.parametrize("controller", CONTROLLER_CASES)
def test_pil_runs_every_controller_kind_bit_identical_to_the_python_loop(tmp_path, controller):
    """The firmware on qemu runs the controller's own law (integrator, anti-windup, saturation,
    measurement derivative, feed-forward) exactly as the float32 Python loop does."""
    from forecast_design.controllers import resolve_controller
    from forecast_design.export.firmware import export_firmware

    opts = FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    c = resolve_controller(controller)
    res = run_pil(controller=c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0, reference="square:0.2:0.125",
                  duration=0.2, out=tmp_path / "run.toml", work_dir=tmp_path / "fw", options=opts)
    assert res.fault is None and res.samples == res.expected == 400
    fw = export_firmware(out_dir=tmp_path / "fw2", controller=c, compensator="ea-fob", env="exp-soft", w_q_hz=10.0,
                         options=opts)
    py = python_closed_loop(fw.program, fw.design, "square:0.2:0.125", res.samples, options=opts)
    for name in ("tau_m", "tau_s", "u", "tau_frc_hat"):
        assert np.max(np.abs(res.arrays[name] - py[name])) <= PIL_BOUND_N_M, name
    assert load_experiment(res.path).design.controller == fw.design.controller   # the log says what ran
    assert 2.0 * res.instructions_per_step < 0.05 * 84_000


# --- a scenario in the loop (issue 26): friction and effects in a processor-in-the-loop run -------------------


def _user_scenario(tmp_path, text=None):
    from test_user_testbed import MYSEA, SCENARIO

    (tmp_path / "mysea.toml").write_text(MYSEA)
    path = tmp_path / "sc.toml"
    path.write_text(SCENARIO if text is None else text)
    return path


@pytest.mark.slow
def test_pil_runs_a_scenario_with_its_friction_on_the_users_sea(tmp_path):
    """pil --scenario: the scenario's design on the firmware, its Coulomb friction, seed and noise in the
    virtual testbed; bit-identical to the float32 Python loop on the same hardware, and the friction acts."""
    from forecast_design.export.firmware import export_firmware
    from forecast_design.runtime.pil import run_pil_scenario, scenario_reference
    from forecast_design.simulation.scenario import load_scenario
    from test_user_testbed import D_L, J_L, J_M

    scenario = load_scenario(_user_scenario(tmp_path))
    res = run_pil_scenario(scenario, out=tmp_path / "run.toml", work_dir=tmp_path / "fw")
    assert res.fault is None and res.samples == res.expected == 400          # duration_s 0.2 at 2 kHz
    opts = FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    fw = export_firmware(scenario.design, tmp_path / "fw2", rate_hz=scenario.rate_hz, options=opts)
    rep = scenario.repetition(0)
    ref = scenario_reference(scenario.reference)
    py = python_closed_loop(fw.program, fw.design, ref, res.samples, options=opts, effects=rep.effects, seed=rep.seed)
    for name in ("tau_m", "theta", "q", "tau_s", "tau_r", "u", "tau_frc_hat"):
        assert np.max(np.abs(res.arrays[name] - py[name])) <= PIL_BOUND_N_M, name
    frictionless = python_closed_loop(fw.program, fw.design, ref, res.samples, options=opts, seed=rep.seed)
    # the Coulomb friction acted: 170 encoder counts apart (measured 5.4e-4 rad; same seed, same noise)
    assert np.max(np.abs(frictionless["theta"] - res.arrays["theta"])) > 50 * 2 * np.pi / opts.encoder_counts
    exp = load_experiment(res.path)
    assert exp.design.testbed.J_m == J_M and (exp.design.environment.J_l, exp.design.environment.d_l) == (J_L, D_L)
    assert exp.design.compensator.kind == "ea-fob" and "sc.toml" in exp.description


def test_pil_scenario_refusals_are_one_line(tmp_path, capsys):
    from forecast_design.cli import main
    from test_user_testbed import SCENARIO

    path = _user_scenario(tmp_path)
    for extra, words in ((["--compensator", "none"], "--compensator"), (["--testbed", "k=40"], "--testbed")):
        code = main(["pil", "--scenario", str(path), "--out", str(tmp_path / "r.toml"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and words in err and "not both" in err and len(err.strip().splitlines()) == 1
    chirp = SCENARIO.replace('kind = "square"\nhigh = 0.3\nlow = -0.3\nperiod_s = 0.1',
                             'kind = "chirp"\namplitude = 0.2\nf0_hz = 1.0\nf1_hz = 10.0\nduration_s = 0.2')
    path = _user_scenario(tmp_path, chirp)
    code = main(["pil", "--scenario", str(path), "--out", str(tmp_path / "r.toml")])
    err = capsys.readouterr().err
    assert code == 2 and "chirp" in err and "--reference" in err and len(err.strip().splitlines()) == 1
    open_loop = SCENARIO.replace('[controller]\nkind = "pd"\nP = 3.0\nD = 0.02\n', "").replace(
        '[compensator]\nkind = "ea-fob"\nw_q_hz = 10.0\n', "")
    code = main(["pil", "--scenario", str(_user_scenario(tmp_path, open_loop)), "--out", str(tmp_path / "r.toml")])
    err = capsys.readouterr().err
    assert code == 2 and "open loop" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("mapping", [
    {"kind": "step", "amplitude": 0.3, "t0": 0.01, "offset": -0.1},
    {"kind": "square", "high": 0.5, "low": -0.1, "period_s": 0.04},
    {"kind": "sine", "amplitude": 0.2, "frequency_hz": 7.0, "offset": 0.05},
    {"kind": "constant", "value": 0.25},
])
def test_a_scenario_reference_becomes_the_same_firmware_reference(mapping):
    from forecast_design.runtime.pil import scenario_reference
    from forecast_design.simulation.references import reference_from_mapping

    signal = reference_from_mapping(mapping)
    t = np.arange(400) / 2000.0
    np.testing.assert_allclose(scenario_reference(signal).signal()(t), signal(t), rtol=0, atol=1e-15)


@pytest.mark.slow
def test_pil_takes_the_scenarios_torque_limit_as_the_firmwares(tmp_path, capsys):
    """A scenario's [simulation] torque_limit is the firmware's clamp on tau_m (it was the 1 N m default)."""
    from forecast_design.cli import main
    from test_user_testbed import SCENARIO

    text = SCENARIO.replace("duration_s = 0.2", "duration_s = 0.05\ntorque_limit = 0.05")
    path = _user_scenario(tmp_path, text)
    code = main(["pil", "--scenario", str(path), "--out", str(tmp_path / "run.toml"), "--work-dir",
                 str(tmp_path / "fw"), "--json", str(tmp_path / "s.json")])
    assert code == 0, capsys.readouterr().err
    tau_m = np.asarray(load_experiment(tmp_path / "run.toml").signals.columns()["tau_m"])
    assert np.max(np.abs(tau_m)) <= 0.05 * (1 + 1e-6)        # the square of +-0.3 N m asks for more
    assert np.max(np.abs(tau_m)) >= 0.05 * (1 - 1e-3)        # and reaches the clamp
    # the summary says what ran: the recorded design, the scenario's reference and length
    from forecast_design.simulation.scenario import load_scenario

    assumed = json.loads((tmp_path / "s.json").read_text())["assumed"]
    assert assumed["design"] == load_experiment(tmp_path / "run.toml").design.to_mapping()
    assert assumed["reference"] == load_scenario(path).reference.to_mapping() and assumed["duration_s"] == 0.05


@pytest.mark.slow
def test_pil_counts_the_cycle_budget_of_its_own_rate(tmp_path, capsys):
    """The budget is one control period at the firmware's rate: 168,000 cycles at 1 kHz (it was 2 kHz's 84,000
    whatever --rate-hz, so the reported budget fraction was twice the true one at 1 kHz)."""
    from forecast_design.cli import main
    from forecast_design.export.toolchain import M4_CLOCK_HZ

    code = main(["pil", "--compensator", "ea-fob", "--rate-hz", "1000", "--duration", "0.1", "--out",
                 str(tmp_path / "run.toml"), "--work-dir", str(tmp_path / "fw"), "--json", str(tmp_path / "s.json")])
    assert code == 0, capsys.readouterr().err
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["rate_hz"] == 1000.0 and s["budget_cycles_per_period"] == M4_CLOCK_HZ / 1000.0
    assert s["budget_fraction_at_cpi_2"] == pytest.approx(2.0 * s["instructions_per_step"] / (M4_CLOCK_HZ / 1000.0))
    assert load_experiment(tmp_path / "run.toml").rate_hz == 1000.0
