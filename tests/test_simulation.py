"""The virtual testbed: closed forms, python-control cross-checks, effect definitions, files."""

import json
import math

import control
import numpy as np
import pytest
import tomli_w
from scipy import stats

from forecast_design.effects import (
    Backlash,
    Cogging,
    Coulomb,
    Delay,
    EnvironmentMismatch,
    PositionFriction,
    Stiction,
    TorqueGain,
)
from forecast_design.compensators import compensator_strategy, friction_feedforward
from forecast_design.discrete import DiscreteFilter
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design, Environment, Testbed
from forecast_design.simulation import (
    REFERENCE_KINDS,
    Chirp,
    Multisine,
    PiecewiseLinear,
    Sine,
    Square,
    Step,
    TorqueSensor,
    build_plant,
    integrate_open_loop,
    reference_from_mapping,
    save_simulation,
    simulate,
)
from forecast_design.simulation.plant import rk4_growth
from forecast_design.simulation.scenario import load_scenario, run_scenario, scenario_from_mapping

RATE = 2000.0
EXACT = {"encoder_counts": None, "process_noise_std": 0.0}   # no sensor or process noise


def _plant_tf(design: Design) -> control.TransferFunction:
    """Paper eq. (2), P = E / ((E/k + 1)(J_m s^2 + d_m s) + E); locked: k / (J_m s^2 + d_m s + k)."""
    tb, env = design.testbed, design.environment
    s = control.tf("s")
    motor = tb.J_m * s**2 + tb.d_m * s
    if env.locked:
        return control.tf([tb.k], [tb.J_m, tb.d_m, tb.k])
    E = env.J * s**2 + env.d * s + env.k_e
    return control.minreal(E / ((E / tb.k + 1) * motor + E), verbose=False)


# --- open loop against closed forms and python-control ---------------------------------


def test_locked_open_loop_step_matches_analytic_step_response():
    design = Design.nominal("locked")
    r = simulate(design, reference=np.ones(4000), duration_s=2.0, closed_loop=False, **EXACT)
    ref = control.step_response(_plant_tf(design), T=r.t)
    np.testing.assert_allclose(r.tau_s, ref.outputs, rtol=0, atol=1e-10)
    np.testing.assert_allclose(r.truth.tau_s, r.tau_s, rtol=0, atol=1e-14)
    assert np.all(r.q == 0.0)


@pytest.mark.parametrize("env", ["exp-soft", "stiff", "fig7", "soft", "link-only"])
def test_free_environment_open_loop_matches_zoh_linear_model(env, rng):
    design = Design.nominal(env)
    n = 2000
    u = np.repeat(rng.normal(0.0, 0.5, n // 100), 100)  # piecewise-constant command
    r = simulate(design, reference=u, duration_s=n / RATE, closed_loop=False, **EXACT)
    pd_ = control.sample_system(_plant_tf(design), 1 / RATE, method="zoh")
    ref = control.forced_response(pd_, T=r.t, U=u)
    # 1e-7: the reference's own round-off (4th-order TF -> ZOH); halving h does not change the gap
    np.testing.assert_allclose(r.truth.tau_s, ref.outputs, rtol=0, atol=1e-7 * np.max(np.abs(ref.outputs)))


def test_conservative_plant_keeps_its_energy():
    design = Design(testbed=Testbed(J_m=0.133, d_m=0.0, k=58.0),
                    environment=Environment(J_e=0.01, d_e=0.0, k_e=20.0, J_l=0.0018, d_l=0.0))
    plant = build_plant(design, rate_hz=RATE, substeps=10)
    log = integrate_open_loop(plant, np.zeros(2000), substeps=10, x0=[0.01, 0.0, -0.005, 0.3, 0.0])
    th, w, q, v = log[:, 0], log[:, 1], log[:, 2], log[:, 3]
    energy = 0.5 * 0.133 * w**2 + 0.5 * design.environment.J * v**2 + 0.5 * 58.0 * (th - q) ** 2 + 0.5 * 20.0 * q**2
    assert np.max(np.abs(energy / energy[0] - 1.0)) < 1e-9
    assert np.ptp(q) > 0.005  # it did move


def test_rk4_is_fourth_order():
    design = Design.nominal("locked")
    effects = [Cogging(a=(0.3, 0.1), b=(0.1, 0.0))]  # smooth nonlinearity
    u = np.sin(np.arange(50) / 100.0 * 2 * np.pi) * 2.0

    def final(substeps):
        plant = build_plant(design, effects, rate_hz=100.0, substeps=substeps)
        return integrate_open_loop(plant, u, substeps=substeps, x0=[0.2, 0.0, 0.0, 0.0, 0.0])[-1, 0]

    ref = final(256)
    e = [abs(final(n) - ref) for n in (1, 2, 4)]
    assert 12.0 < e[0] / e[1] < 20.0
    assert 12.0 < e[1] / e[2] < 20.0


def test_rk4_stability_polynomial_limit():
    assert rk4_growth(-2.785) < 1.0 < rk4_growth(-2.79)
    assert rk4_growth(2.8j) < 1.0 < rk4_growth(2.9j)


# --- effects behave as defined ---------------------------------------------------------


def _free_run(effects, *, initial_angle=0.0, env="link-only", amplitude=5.0):
    return simulate(Design.nominal(env), reference=Sine(amplitude=amplitude, frequency_hz=0.5), duration_s=2.0,
                    closed_loop=False, effects=effects, initial_angle=initial_angle, **EXACT)


def test_coulomb_friction_is_fc_sign_v():
    r = _free_run([Coulomb(F_c=0.3)])
    w = r.truth.omega
    moving = np.abs(w) > 1e-3
    assert np.any(w[moving] > 0) and np.any(w[moving] < 0)
    extra = r.truth.tau_frc - r.design.testbed.d_m * w
    np.testing.assert_allclose(extra[moving], 0.3 * np.sign(w[moving]), rtol=0, atol=1e-12)
    assert np.all(r.truth.tau_frc * w >= 0.0)  # viscous + Coulomb never add energy


def test_position_friction_and_cogging_follow_the_absolute_angle():
    pf = PositionFriction(F_c=0.2, a=(0.05, 0.03), b=(0.02, -0.04))
    cg = Cogging(a=(0.02,), b=(0.01,))
    r = _free_run([pf, cg], initial_angle=0.7)
    w, th = r.truth.omega, r.truth.theta + 0.7
    moving = np.abs(w) > pf.v_reg
    level = pf.F_c + sum(a * np.sin((i + 1) * th) + b * np.cos((i + 1) * th) for i, (a, b) in enumerate(zip(pf.a, pf.b)))
    cog = 0.02 * np.sin(th) + 0.01 * np.cos(th)
    expected = r.design.testbed.d_m * w + np.sign(w) * level + cog
    np.testing.assert_allclose(r.truth.tau_frc[moving], expected[moving], rtol=0, atol=1e-12)
    assert np.ptp(th) > np.pi  # over half a revolution: the harmonics were exercised


@pytest.mark.parametrize("v0", [0.005, -0.01, 0.02, -0.05, 0.3, 100.0, -80.0])
def test_lugre_steady_state_is_the_stribeck_curve(v0):
    # A huge flywheel behind a stiff spring drags the motor at constant velocity v0; a large d_m
    # keeps the sliding motor stable on the negative Stribeck slope. |v0| > 61 rad/s exercises
    # the quasi-steady bristle branch.
    s = Stiction()
    design = Design(testbed=Testbed(J_m=0.133, d_m=10.0, k=1000.0),
                    environment=Environment(J_e=1e9, d_e=0.0, k_e=0.0, J_l=0.0, d_l=0.0))
    plant = build_plant(design, [s], rate_hz=RATE, substeps=10)
    log = integrate_open_loop(plant, np.zeros(20000), substeps=10, x0=[0.0, v0, 0.0, v0, 0.0])
    w = log[-1, 1]
    assert w == pytest.approx(v0, rel=1e-3)
    g = s.F_c + (s.F_s - s.F_c) * math.exp(-((w / s.v_s) ** 2))
    assert log[-1, 5] - 10.0 * w == pytest.approx(g * np.sign(w) + s.sigma2 * w, abs=1e-6)


def test_lugre_breakaway_happens_between_coulomb_and_static_level():
    # slow torque ramp on the free link: LuGre holds the motor (presliding only) until the
    # torque nears the static level F_s = 0.5; without friction effects it moves at once.
    ramp = PiecewiseLinear(times_s=(0.0, 2.0), values=(0.0, 1.0))
    kw = dict(reference=ramp, duration_s=2.0, closed_loop=False, **EXACT)
    r = simulate(Design.nominal("link-only"), effects=[Stiction()], **kw)
    i = int(np.argmax(np.abs(r.truth.omega) > 0.05))
    assert 0.4 < r.tau_m[i] < 0.55
    assert np.max(np.abs(r.truth.z[:i])) <= 0.5 / 260.0  # bristles deflect at most F_s / sigma0
    free = simulate(Design.nominal("link-only"), **kw)
    assert free.tau_m[int(np.argmax(np.abs(free.truth.omega) > 0.05))] < 0.2  # viscous + inertial lag only


def test_torque_gain_scales_the_applied_torque():
    u = Sine(amplitude=1.0, frequency_hz=2.0)
    a = simulate(Design.nominal("exp-soft"), reference=u, duration_s=1.0, closed_loop=False,
                 effects=[TorqueGain(gain=1.3)], **EXACT)
    b = simulate(Design.nominal("exp-soft"), reference=lambda t: 1.3 * u(t), duration_s=1.0, closed_loop=False,
                 **EXACT)
    np.testing.assert_array_equal(a.truth.tau_m_applied, 1.3 * a.tau_m)
    np.testing.assert_array_equal(a.truth.theta, b.truth.theta)


def test_delay_shifts_the_applied_torque():
    u = Sine(amplitude=1.0, frequency_hz=2.0).sample(2000, RATE)
    a = simulate(Design.nominal("exp-soft"), reference=u, duration_s=1.0, closed_loop=False,
                 effects=[Delay(delay_s=3 / RATE)], **EXACT)
    b = simulate(Design.nominal("exp-soft"), reference=np.concatenate([np.zeros(3), u[:-3]]), duration_s=1.0,
                 closed_loop=False, **EXACT)
    assert a.options["delay_substeps"] == 30
    np.testing.assert_array_equal(a.truth.tau_m_applied[3:], a.tau_m[:-3])
    np.testing.assert_array_equal(a.truth.theta, b.truth.theta)


def test_backlash_is_a_dead_band_in_the_spring():
    width = 2e-3
    r = simulate(Design.nominal("locked"), reference=Sine(amplitude=0.2, frequency_hz=2.0), duration_s=1.0,
                 closed_loop=False, effects=[Backlash(width_rad=width)], **EXACT)
    d = r.truth.theta - r.truth.q
    dz = d - np.clip(d, -width / 2, width / 2)
    np.testing.assert_array_equal(r.truth.tau_s, 58.0 * dz)
    assert np.any(r.truth.tau_s == 0.0) and np.any(np.abs(d) > width)
    np.testing.assert_allclose(r.tau_s, 58.0 * d, atol=1e-15)  # the sensor still reads k (theta - q)


def test_environment_mismatch_simulates_the_true_environment_but_records_the_nominal():
    nominal = Design.nominal("exp-soft")
    mm = EnvironmentMismatch(k_e_scale=3.0, J_scale=2.0)
    a = simulate(nominal, reference=Step(amplitude=0.3), duration_s=0.5, closed_loop=False, effects=[mm], **EXACT)
    b = simulate(nominal.with_environment(mm.true_environment(nominal.environment)), reference=Step(amplitude=0.3),
                 duration_s=0.5, closed_loop=False, **EXACT)
    np.testing.assert_array_equal(a.truth.q, b.truth.q)
    assert a.design.environment == nominal.environment
    assert a.truth.environment.k_e == 15.0


# --- closed loop -------------------------------------------------------------------------


def test_closed_loop_pd_on_locked_plant_matches_discrete_linear_loop():
    design = Design.nominal("locked", controller=PD(P=5.0, D=0.1))
    r = simulate(design, reference=Step(amplitude=0.2), duration_s=3.0, **EXACT)
    law = design.controller.discrete_law(RATE).feedback_tf()     # backward Euler: 5 + 0.1 (1 - 1/z) 2000
    c = control.tf(list(law.num), list(law.den), 1 / RATE)
    p = control.sample_system(_plant_tf(design), 1 / RATE, method="zoh")
    ref = control.forced_response(control.feedback(c * p, 1), T=r.t, U=r.tau_r)
    np.testing.assert_allclose(r.tau_s, ref.outputs, rtol=0, atol=1e-9)
    # steady-state error of P + D s on a unit-DC-gain plant: e = tau_r / (1 + P)
    assert r.tau_r[-1] - r.tau_s[-1] == pytest.approx(0.2 / 6.0, rel=1e-6)


def test_same_seed_same_run_other_seed_other_run():
    kw = dict(reference=Square(high=0.5, low=-0.5, period_s=0.2), duration_s=0.5, effects=[Stiction()])
    d = Design.nominal("exp-soft")
    a, b, c = simulate(d, seed=3, **kw), simulate(d, seed=3, **kw), simulate(d, seed=4, **kw)
    np.testing.assert_array_equal(a.theta, b.theta)
    np.testing.assert_array_equal(a.truth.tau_frc, b.truth.tau_frc)
    assert not np.array_equal(a.theta, c.theta)


def test_encoder_quantisation_is_2e6_counts_per_rev():
    r = simulate(Design.nominal("exp-soft"), reference=Step(amplitude=0.2), duration_s=0.2)
    step = 2 * np.pi / 2_000_000
    counts = r.theta / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.max(np.abs(r.theta - r.truth.theta)) <= step / 2 + 1e-15


@pytest.mark.parametrize("jitter_counts", [0.3, 0.7])
def test_an_encoder_jitter_toggles_a_reading_at_rest_as_often_as_the_normal_law_says(jitter_counts):
    # a motor at rest on a count's centre reads off it when the noise passes half a count: P = 2 (1 - Phi(0.5 / s))
    kw = dict(reference=np.zeros(8000), duration_s=4.0, closed_loop=False, encoder_counts=2**16, process_noise_std=0.0,
              seed=5)
    r = simulate(Design.nominal("locked"), encoder_jitter_counts=jitter_counts, **kw)
    plain = simulate(Design.nominal("locked"), **kw)
    step = 2 * np.pi / 2**16
    assert np.all(r.truth.theta == 0.0) and np.all(plain.theta == 0.0)
    p = 2.0 * stats.norm.sf(0.5 / jitter_counts)
    off = np.count_nonzero(r.theta)
    assert abs(off - p * r.theta.size) <= 5.0 * math.sqrt(r.theta.size * p * (1 - p))
    assert set(np.unique(np.round(r.theta / step))) <= {-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0}
    assert np.all(r.q == 0.0) and r.options["encoder_jitter_counts"] == jitter_counts


def test_an_encoder_jitter_in_the_loop_moves_the_motor():
    # closed loop on a derived tau_s: the P controller acts on k (theta_m - q_m), the jitter included
    kw = dict(reference=Step(amplitude=0.2), duration_s=0.5, seed=2, process_noise_std=0.0, encoder_counts=2**16)
    design = Design.nominal("locked", controller=PD(P=5.0, D=0.0))
    r = simulate(design, encoder_jitter_counts=0.8, **kw)
    quiet = simulate(design, **kw)
    k, step = design.testbed.k, 2 * np.pi / 2**16
    np.testing.assert_allclose(r.tau_m, 5.0 * (r.tau_r - k * r.theta), rtol=1e-12, atol=1e-12)
    # the readings differ from the quantised true angle by more than the quantiser does (half a count) ...
    assert np.max(np.abs(r.theta - r.truth.theta)) > step
    # ... and the motor moves with them: the jitter is in the loop, not added to the log afterwards
    assert np.max(np.abs(r.truth.theta - quiet.truth.theta)) > 0.0
    with pytest.raises(ParameterError, match="encoder_jitter_counts needs encoder_counts"):
        simulate(design, encoder_jitter_counts=0.5, **{**kw, "encoder_counts": None})
    for bad in (-0.1, float("nan"), 1e3, True):
        with pytest.raises(ParameterError, match="encoder_jitter_counts must be in"):
            simulate(design, encoder_jitter_counts=bad, **kw)


def test_torque_saturation():
    r = simulate(Design.nominal("stiff"), reference=Square(high=1.0, low=-1.0, period_s=0.5), duration_s=1.0,
                 torque_limit=0.5)
    assert np.max(np.abs(r.tau_m)) == 0.5


@pytest.mark.parametrize("kind", ["ea-fob", "lo-dob", "ld-dob", "motor-fob"])
def test_observer_in_the_loop_is_the_python_filter_object(kind):
    design = Design.nominal("exp-soft", compensator=Compensator(kind=kind, w_q_hz=10.0))
    r = simulate(design, reference=Sine(amplitude=0.3, frequency_hz=1.0), duration_s=0.5, effects=[Coulomb()])
    filters = compensator_strategy(design.compensator).discrete_filters(design.compensator, design, RATE)
    running = [(src, DiscreteFilter(tf)) for src, tf in filters.paths()]
    pd_ = DiscreteFilter(PD().discrete_law(RATE).channels[0].tf)
    prev = 0.0
    hat, u = np.empty(r.t.size), np.empty(r.t.size)
    for n in range(r.t.size):
        inputs = {"tau_m_prev": prev, "tau_s": r.tau_s[n], "theta": r.theta[n]}
        total = 0.0
        for src, f in running:
            total = total + f.step(inputs[src])
        hat[n] = total
        u[n] = pd_.step(r.tau_r[n] - r.tau_s[n])
        prev = r.tau_m[n]
    np.testing.assert_array_equal(hat, r.tau_frc_hat)
    np.testing.assert_array_equal(u, r.u)
    np.testing.assert_array_equal(r.tau_m, u + hat)


def test_sfm_in_the_loop_is_the_python_object():
    params = {"viscous": 0.4, "coulomb": 0.35, "sin1": 0.02, "cos2": -0.01, "coulomb_sin1": 0.01}
    design = Design.nominal("locked", compensator=Compensator(kind="sfm"))
    r = simulate(design, reference=Sine(amplitude=0.5, frequency_hz=1.0), duration_s=0.5, effects=[Stiction()],
                 sfm_params=params, initial_angle=0.4)
    hat = friction_feedforward(params, RATE, angle_offset=0.4).evaluate(r.theta)
    np.testing.assert_array_equal(hat, r.tau_frc_hat)


def test_ea_fob_estimates_friction_and_beats_no_compensation():
    design = Design.nominal("exp-soft", compensator=Compensator(kind="ea-fob", w_q_hz=10.0))
    kw = dict(reference=Sine(amplitude=0.5, frequency_hz=0.5), duration_s=4.0, effects=[Coulomb(F_c=0.3)])
    r = simulate(design, **kw)
    late = r.t > 1.0
    err = np.abs(r.tau_frc_hat - r.truth.tau_frc)[late]
    assert np.mean(err) < 0.25 * np.mean(np.abs(r.truth.tau_frc[late]))
    bare = simulate(Design.nominal("exp-soft"), **kw)
    assert np.mean(np.abs(r.tau_r - r.tau_s)[late]) < np.mean(np.abs(bare.tau_r - bare.tau_s)[late])


@pytest.mark.parametrize("env", ["locked", "link-only", "stiff"])
def test_every_observer_runs_on_every_environment(env):
    for kind in ("ea-fob", "lo-dob", "ld-dob", "motor-fob"):
        r = simulate(Design.nominal(env, compensator=Compensator(kind=kind, w_q_hz=5.0)),
                     reference=Step(amplitude=0.2), duration_s=0.2, effects=[Stiction()])
        assert np.all(np.isfinite(r.tau_frc_hat))


def test_too_few_substeps_for_a_steep_coulomb_raise():
    with pytest.raises(ParameterError, match="unstable"):
        simulate(Design.nominal("locked"), reference=Step(), duration_s=0.1, effects=[Coulomb(v_reg=1e-6)])


def test_bad_options_raise():
    d = Design.nominal("locked")
    with pytest.raises(ParameterError, match="'sfm' needs identified friction"):
        simulate(d.with_environment("locked").__class__(compensator=Compensator(kind="sfm")),
                 reference=Step(), duration_s=0.1)
    with pytest.raises(ParameterError, match="compensator is 'none'; it applies to 'sfm'"):
        simulate(d, reference=Step(), duration_s=0.1, sfm_params={"viscous": 0.1, "coulomb": 0.2})
    with pytest.raises(ParameterError, match="reference must give 200 samples"):
        simulate(d, reference=np.zeros(10), duration_s=0.1)
    with pytest.raises(ParameterError, match="given 2 times"):
        simulate(d, reference=Step(), duration_s=0.1, effects=[Coulomb(), Coulomb()])
    with pytest.raises(ParameterError, match="unknown"):
        friction_feedforward({"visc": 1.0}, RATE)


# --- files ----------------------------------------------------------------------------------


def test_saved_run_is_a_nominal_experiment_with_truth_sidecars(tmp_path):
    from forecast_design.experiment import load_experiment

    nominal = Design.nominal("exp-soft", compensator=Compensator(kind="ea-fob", w_q_hz=10.0))
    effects = [Stiction(), EnvironmentMismatch(k_e_scale=2.0)]
    r = simulate(nominal, reference=Step(amplitude=0.2), duration_s=0.25, effects=effects)
    paths = save_simulation(r, tmp_path / "run.toml")
    exp = load_experiment(paths["experiment"])
    assert exp.design.environment == nominal.environment
    assert exp.design.compensator.kind == "ea-fob" and exp.design.controller == PD()
    np.testing.assert_array_equal(exp.signals.theta, r.theta)
    np.testing.assert_array_equal(exp.signals.extra["tau_frc_hat"], r.tau_frc_hat)
    assert "stiction" not in paths["experiment"].read_text()
    meta = json.loads(paths["truth"].read_text())
    assert [e["effect"] for e in meta["truth"]["effects"]] == ["stiction", "environment_mismatch"]
    assert meta["truth"]["environment"]["k_e"] == 10.0
    truth = np.genfromtxt(paths["truth_data"], delimiter=",", names=True)
    np.testing.assert_array_equal(truth["tau_frc"], r.truth.tau_frc)


def _scenario_doc():
    return {
        "format": "forecast-scenario/1",
        "description": "test",
        "sampling": {"rate_hz": 2000.0},
        "testbed": {"J_m": 0.133, "d_m": 0.3, "k": 58.0},
        "environment": {"J_e": 0.001, "d_e": 0.063, "k_e": 5.0, "J_l": 0.0018, "d_l": 0.35, "locked": False},
        "controller": {"kind": "pd", "P": 5.0, "D": 0.1},
        "compensator": {"kind": "ea-fob", "w_q_hz": 10.0},
        "truth": {"initial_angle": 0.3, "effects": [{"effect": "stiction"}, {"effect": "cogging", "a": [0.02],
                                                                               "b": [0.0]}]},
        "reference": {"kind": "step", "amplitude": 0.2},
        "simulation": {"duration_s": 0.2, "seed": 5, "torque_limit": 5.0},
    }


def test_scenario_file_runs_like_simulate(tmp_path):
    path = tmp_path / "sc.toml"
    path.write_text(tomli_w.dumps(_scenario_doc()))
    sc = load_scenario(path)
    assert sc.closed_loop and sc.options["seed"] == 5 and sc.options["initial_angle"] == 0.3
    paths = run_scenario(path, tmp_path / "out" / "run.toml")
    direct = simulate(sc.design, reference=Step(amplitude=0.2), duration_s=0.2, seed=5, torque_limit=5.0,
                      effects=[Stiction(), Cogging(a=(0.02,), b=(0.0,))], initial_angle=0.3, description="test")
    from forecast_design.experiment import load_experiment

    np.testing.assert_array_equal(load_experiment(paths["experiment"]).signals.tau_m, direct.tau_m)
    again = scenario_from_mapping(sc.to_mapping())
    assert again == scenario_from_mapping(_scenario_doc())


@pytest.mark.parametrize("edit,match,key", [
    (lambda d: d["simulation"].update(durations=1.0), "unknown key 'durations'", "simulation.durations"),
    (lambda d: d["simulation"].pop("duration_s"), "missing required key 'duration_s'", "simulation.duration_s"),
    (lambda d: d.pop("reference"), r"missing required table \[reference\]", "reference"),
    (lambda d: d["truth"]["effects"][0].update(sigma3=1.0), "unknown key 'sigma3'", "truth.effects[0].sigma3"),
    (lambda d: d["truth"]["effects"][1].update(effect="stickiness"), "effect must be one of",
     "truth.effects[1].effect"),
    (lambda d: d["reference"].update(amplitud=0.3), "unknown key 'amplitud'", "reference.amplitud"),
    (lambda d: d["sampling"].pop("rate_hz"), "missing required key 'rate_hz'", "sampling.rate_hz"),
    (lambda d: d["compensator"].update(kind="sfm") or d["compensator"].pop("w_q_hz"), r"needs a \[sfm\] table", "sfm"),
    (lambda d: d["compensator"].update(kind="sfm"), "key .w_q_hz. does not belong to kind .sfm.", "compensator.w_q_hz"),
    (lambda d: d["reference"].update(kind="sawtooth"), "kind must be one of", "reference.kind"),
    (lambda d: d.update(extra=1), "unknown key 'extra'", "extra"),
])
def test_scenario_errors_name_file_and_key(tmp_path, edit, match, key):
    doc = _scenario_doc()
    edit(doc)
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(doc))
    with pytest.raises(ExperimentFormatError, match=match) as exc:
        load_scenario(path)
    assert exc.value.key == key and str(path) in str(exc.value)


def test_example_scenario_is_package_data_and_runs(tmp_path):
    import subprocess
    import sys
    from importlib.resources import files

    from forecast_design.effects import Stiction as _Stiction

    path = files("forecast_design") / "data" / "example_scenario.toml"
    sc = load_scenario(path)
    assert sc.closed_loop and sc.design.compensator.kind == "ea-fob" and sc.effects == (_Stiction(),)
    assert sc.design.environment == Design.nominal("stiff").environment
    out = tmp_path / "run.toml"
    proc = subprocess.run([sys.executable, "-m", "forecast_design", "simulate", str(path), "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert {"experiment", "data", "truth", "truth_data"} <= set(summary)    # the paths, plus the run's figures
    assert summary["compensator"] == "ea-fob" and summary["statistics"]["n_samples"] == 16000
    from forecast_design.experiment import load_experiment

    exp = load_experiment(out)
    assert exp.signals.t.shape == (16000,)
    # the Fig. 7 EA-FOB: friction estimate within 0.05 N m of the truth on average
    truth = np.genfromtxt(tmp_path / "run.truth.csv", delimiter=",", names=True)
    assert np.mean(np.abs(exp.signals.extra["tau_frc_hat"] - truth["tau_frc"])) < 0.05


def test_scenario_doc_example_matches_the_format(tmp_path):
    from pathlib import Path

    doc = Path(__file__).resolve().parents[1] / "docs" / "scenario.md"
    text = doc.read_text()
    block = text.split("## Example", 1)[1].split("```toml", 1)[1].split("```", 1)[0]
    path = tmp_path / "doc.toml"
    path.write_text(block)
    sc = load_scenario(path)
    assert sc.reference == Square(high=1.0, low=-1.0, period_s=4.0) and sc.options["duration_s"] == 8.0
    for key in ("format", "sampling", "testbed", "environment", "controller", "compensator", "sfm", "truth",
                "reference", "simulation"):
        assert f"`[{key}]`" in text or f"`{key} =" in text or key == "format"


# --- references --------------------------------------------------------------------------------


def test_square_wave_levels_and_duty():
    sq = Square(high=1.0, low=-1.0, period_s=2.0, t0=0.5)
    t = np.array([0.0, 0.5, 1.4, 1.6, 2.4, 2.6])
    np.testing.assert_array_equal(sq(t), [-1.0, 1.0, 1.0, -1.0, -1.0, 1.0])


@pytest.mark.parametrize("method", ["linear", "logarithmic"])
def test_chirp_instantaneous_frequency_sweeps_f0_to_f1(method):
    ch = Chirp(f0_hz=0.5, f1_hz=20.0, duration_s=4.0, method=method)
    t = np.array([1e-6, 4.0 - 1e-6, 5.0])
    dphi = (ch.phase(t + 1e-7) - ch.phase(t - 1e-7)) / 2e-7 / (2 * np.pi)
    np.testing.assert_allclose(dphi, [0.5, 20.0, 20.0], rtol=1e-4)


def test_multisine_default_phases_are_schroeder():
    ms = Multisine(amplitudes=(1.0, 1.0, 1.0), frequencies_hz=(1.0, 2.0, 3.0))
    t = np.linspace(0, 1, 1001)
    expected = sum(np.sin(2 * np.pi * f * t - np.pi * i * (i - 1) / 3) for i, f in zip((1, 2, 3), (1.0, 2.0, 3.0)))
    np.testing.assert_allclose(ms(t), expected, atol=1e-12)


@pytest.mark.parametrize("kind", list(REFERENCE_KINDS))
def test_reference_mapping_round_trip(kind):
    ref = REFERENCE_KINDS[kind]()
    assert reference_from_mapping(ref.to_mapping()) == ref


def test_plots_write_png_files(tmp_path):
    from forecast_design.plotting.simulation import plot_simulation, plot_step_responses

    r = simulate(Design.nominal("locked", compensator=Compensator(kind="ea-fob")), reference=Step(amplitude=0.2),
                 duration_s=0.1, effects=[Stiction()])
    fig = plot_simulation({"EA-FOB": r}, tmp_path / "fig7.png")
    assert (tmp_path / "fig7.png").stat().st_size > 1000 and len(fig.axes) == 4          # forces and motion
    assert len(plot_simulation({"EA-FOB": r}, motion=False).axes) == 2
    plot_step_responses({"locked": [r, r]}, tmp_path / "steps.png", expected={"locked": r})
    assert (tmp_path / "steps.png").exists()
    import matplotlib.pyplot as plt

    plt.close("all")


def test_a_torque_sensor_reads_the_true_spring_torque_with_its_gain_zero_and_white_noise():
    # a backlash makes the true spring torque differ from k (theta - q): the sensor reads the spring, not the encoders
    width, std, gain, zero = 2e-3, 3e-3, 1.05, -0.02
    kw = dict(reference=Sine(amplitude=0.2, frequency_hz=2.0), duration_s=2.0, closed_loop=False,
              effects=[Backlash(width_rad=width)], seed=4)
    sensor = TorqueSensor(noise_std_N_m=std, gain=gain, offset_N_m=zero)
    r = simulate(Design.nominal("locked"), torque_sensor=sensor, **kw)
    e = r.tau_s - (gain * r.truth.tau_s + zero)
    n = e.size
    assert abs(e.mean()) < 4.0 * std / np.sqrt(n)
    assert stats.chi2.ppf(1e-4, n - 1) < (n - 1) * e.var(ddof=1) / std ** 2 < stats.chi2.ppf(1 - 1e-4, n - 1)
    assert abs(np.corrcoef(e[:-1], e[1:])[0, 1]) < 4.0 / np.sqrt(n)        # white
    # open loop: the sensor changes nothing the plant does; the process noise is drawn as before
    plain = simulate(Design.nominal("locked"), **kw)
    np.testing.assert_array_equal(r.theta, plain.theta)
    np.testing.assert_array_equal(r.truth.tau_s, plain.truth.tau_s)
    exact = simulate(Design.nominal("locked"), torque_sensor=TorqueSensor(), **kw)
    np.testing.assert_array_equal(exact.tau_s, exact.truth.tau_s)
    assert r.options["torque_sensor"] == sensor.to_mapping() and plain.options["torque_sensor"] is None
    assert not r.to_experiment().signals.tau_s_derived


def test_a_torque_sensor_in_the_loop_feeds_its_noise_back():
    # closed loop: the PD acts on the sensor's reading, so the motor torque carries -P times its noise
    kw = dict(reference=Step(amplitude=0.2), duration_s=0.5, seed=2, process_noise_std=0.0, encoder_counts=None)
    design = Design.nominal("locked", controller=PD(P=5.0, D=0.0))
    quiet = simulate(design, torque_sensor=TorqueSensor(noise_std_N_m=0.0), **kw)
    noisy = simulate(design, torque_sensor=TorqueSensor(noise_std_N_m=1e-3), **kw)
    sens = noisy.tau_s - noisy.truth.tau_s
    assert 0.9e-3 < sens.std() < 1.1e-3 and not np.array_equal(noisy.tau_m, quiet.tau_m)
    # the P controller acted on the sensor's reading, its noise included
    np.testing.assert_allclose(noisy.tau_m, 5.0 * (noisy.tau_r - noisy.tau_s), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(quiet.tau_m, 5.0 * (quiet.tau_r - quiet.truth.tau_s), rtol=1e-12, atol=1e-15)
    for bad in (dict(noise_std_N_m=-1e-3), dict(gain=0.0), dict(offset_N_m=float("nan"))):
        with pytest.raises(ParameterError, match=f"TorqueSensor {next(iter(bad))}"):
            TorqueSensor(**bad)
    with pytest.raises(ParameterError, match="torque_sensor must be a TorqueSensor"):
        simulate(design, torque_sensor=1e-3, **kw)


def test_a_scenarios_encoder_jitter_runs_like_simulate_and_round_trips(tmp_path):
    doc = _scenario_doc()
    doc["simulation"].update(encoder_counts=65536, encoder_jitter_counts=0.7)
    path = tmp_path / "sc.toml"
    path.write_text(tomli_w.dumps(doc))
    sc = load_scenario(path)
    assert sc.options["encoder_jitter_counts"] == 0.7
    assert scenario_from_mapping(sc.to_mapping()).options == sc.options
    paths = run_scenario(path, tmp_path / "run.toml")
    direct = simulate(sc.design, reference=Step(amplitude=0.2), duration_s=0.2, seed=5, torque_limit=5.0,
                      effects=[Stiction(), Cogging(a=(0.02,), b=(0.0,))], initial_angle=0.3, encoder_counts=65536,
                      encoder_jitter_counts=0.7)
    from forecast_design.experiment import load_experiment

    np.testing.assert_array_equal(load_experiment(paths["experiment"]).signals.theta, direct.theta)
    assert json.loads(paths["truth"].read_text())["options"]["encoder_jitter_counts"] == 0.7


def test_a_scenarios_torque_sensor_runs_like_simulate_and_round_trips(tmp_path):
    doc = _scenario_doc()
    doc["truth"] = {"torque_sensor": {"noise_std_N_m": 0.002, "gain": 0.95}}
    sc = scenario_from_mapping(doc)
    assert sc.options["torque_sensor"] == TorqueSensor(noise_std_N_m=0.002, gain=0.95)
    again = scenario_from_mapping(sc.to_mapping())
    assert again.options == sc.options
    r = sc.run()
    direct = simulate(sc.design, reference=sc.reference, duration_s=0.2, seed=5, torque_limit=5.0,
                      torque_sensor=TorqueSensor(noise_std_N_m=0.002, gain=0.95))
    np.testing.assert_array_equal(r.tau_s, direct.tau_s)
    doc["truth"] = {"torque_sensor": {"noise_std_N_m": 0.002, "gian": 0.95}}
    with pytest.raises(ExperimentFormatError, match=r"\[truth.torque_sensor\] unknown key 'gian'"):
        scenario_from_mapping(doc)
    doc["truth"] = {"torque_sensor": {"gain": -1.0}}
    with pytest.raises(ExperimentFormatError, match=r"\[truth.torque_sensor\] TorqueSensor gain"):
        scenario_from_mapping(doc)
