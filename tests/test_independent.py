"""The independent log generator: physics facts of its plant, integrator, controller and logger."""

import dataclasses
import math

import control
import numpy as np
from scipy import signal
import pytest
from scipy.integrate import simpson

import forecast_design.independent as ind
from forecast_design.effects import Effect
from forecast_design.errors import ParameterError
from forecast_design.independent import (
    ENCODER_STEP,
    MAX_ATTEMPTS,
    Excitation,
    IndependentCase,
    draw_independent_case,
    excitation_signal,
    friction_log,
    identifiability,
    make_independent_log,
    one_line_fraction,
    round_significant,
    simulate_independent,
)
from forecast_design.controllers import PD, PID
from forecast_design.params import Testbed, environment_preset

MULTISINE = Excitation(kind="multisine", amplitude=0.6, f_lo_hz=0.2, f_hi_hz=20.0, lines=16)


def _case(words=(), env="soft", excitation=MULTISINE, **kwargs):
    kwargs.setdefault("rate_hz", 2000.0)
    kwargs.setdefault("duration_s", 4.0)
    return IndependentCase(words=words, environment=environment_preset(env), environment_name=env,
                           excitation=excitation, **kwargs)


def _zoh_response(truth, u, rate_hz, locked):
    """theta, omega (and q, v) of the linear plant under the ZOH command u, by python-control's c2d."""
    tb, env = truth.testbed, truth.environment
    if locked:
        a = [[0, 1], [-tb.k / tb.J_m, -tb.d_m / tb.J_m]]
        b = [[0], [1 / tb.J_m]]
    else:
        a = [[0, 1, 0, 0], [-tb.k / tb.J_m, -tb.d_m / tb.J_m, tb.k / tb.J_m, 0], [0, 0, 0, 1],
             [tb.k / env.J, 0, -(tb.k + env.k_e) / env.J, -env.d / env.J]]
        b = [[0], [1 / tb.J_m], [0], [0]]
    sys = control.c2d(control.ss(np.array(a), np.array(b), np.eye(len(a)), 0), 1.0 / rate_hz, "zoh")
    return control.forced_response(sys, U=u, X0=0).outputs


# --- the linear plant -------------------------------------------------------------------


@pytest.mark.parametrize("env", ["soft", "stiff", "locked", "link-only", "exp-soft"])
def test_effect_free_log_is_the_exact_zoh_response_of_the_plant(env):
    case = _case(env=env, nominal_errors={"J_m": 0.015, "d_m": -0.02, "k": 0.01})
    exp, truth = simulate_independent(case)
    y = _zoh_response(truth, np.asarray(exp.signals.tau_m), case.rate_hz, env == "locked")
    assert np.max(np.abs(y[0] - truth.theta)) < 1e-9
    assert np.max(np.abs(y[1] - truth.omega)) < 1e-8
    if env != "locked":
        assert np.max(np.abs(y[2] - truth.q)) < 1e-9
    assert np.ptp(truth.theta) > 0.05                      # the test is not trivially met


@pytest.mark.parametrize("word,params", [("torque_gain", {"gain": 0.87}),
                                         ("environment_mismatch", {"J_factor": 2.5}),
                                         ("environment_mismatch", {"k_e_factor": 0.4})])
def test_linear_effects_are_the_zoh_response_of_the_true_plant(word, params):
    case = _case((word,), env="exp-soft", effect_params=params)
    exp, truth = simulate_independent(case)
    assert truth.environment.J == pytest.approx(case.environment.J * params.get("J_factor", 1.0))
    assert truth.environment.k_e == pytest.approx(case.environment.k_e * params.get("k_e_factor", 1.0))
    u = params.get("gain", 1.0) * np.asarray(exp.signals.tau_m)
    y = _zoh_response(truth, u, case.rate_hz, False)
    assert np.max(np.abs(y[0] - truth.theta)) < 1e-9


def test_fractional_delay_is_an_exact_shift_of_the_held_command():
    """1.5 samples of delay at 1 kHz is a 3-sample shift of the same ZOH command at 2 kHz."""
    case = _case(("delay",), env="locked", rate_hz=1000.0, effect_params={"delay_s": 1.5e-3})
    exp, truth = simulate_independent(case)
    fine = np.concatenate([np.zeros(3), np.repeat(np.asarray(exp.signals.tau_m), 2)])[:2 * len(truth.t)]
    y = _zoh_response(truth, fine, 2000.0, True)
    assert np.max(np.abs(y[0][::2] - truth.theta)) < 1e-9
    assert truth.tau_applied[1] == 0.0 and truth.tau_applied[2] == exp.signals.tau_m[0]


def test_energy_balance_with_coulomb_friction_and_sticking():
    case = _case(("coulomb",), effect_params={"F_c": 0.25}, duration_s=6.0)
    _, tr = simulate_independent(case)
    tb, env = tr.testbed, tr.environment
    th, w, q, v = (np.asarray(a) for a in (tr.theta, tr.omega, tr.q, tr.v))
    energy = (0.5 * tb.J_m * w ** 2 + 0.5 * tb.k * (th - q) ** 2
              + 0.5 * env.J * v ** 2 + 0.5 * env.k_e * q ** 2)
    work_in = float(np.sum(tr.command[:-1] * np.diff(th)))              # exact: the command is held
    dt = 1.0 / case.rate_hz
    lost = simpson(tb.d_m * w ** 2 + env.d * v ** 2 + tr.tau_friction * w, dx=dt)
    assert tr.stuck.any() and not tr.stuck.all()
    assert energy[-1] - energy[0] == pytest.approx(work_in - lost, abs=1e-5 * work_in)


# --- switching: dead band, sticking, events ---------------------------------------------


def test_dead_band_transmits_no_torque_and_the_motor_runs_free_inside_it():
    width = 4e-3
    case = _case(("backlash",), env="stiff", effect_params={"width": width})
    _, tr = simulate_independent(case)
    tb, h = tr.testbed, width / 2
    d = np.asarray(tr.theta) - np.asarray(tr.q)
    inside = np.abs(d) < h - 1e-9
    assert inside.sum() > 100 and (np.abs(d) > h).sum() > 100
    assert np.all(tr.tau_spring[inside] == 0.0)
    out = np.abs(d) > h + 1e-9
    np.testing.assert_allclose(tr.tau_spring[out], tb.k * (d[out] - np.sign(d[out]) * h), rtol=1e-12)
    assert np.all(tr.spring_mode[inside] == 0)
    # inside the band: J_m w' = u - d_m w exactly (first-order, solved over one held period)
    a = math.exp(-tb.d_m / tb.J_m / case.rate_hz)
    deep = np.flatnonzero((np.abs(d[:-1]) < h / 3) & (np.abs(d[1:]) < h / 3))
    assert deep.size > 50
    w = np.asarray(tr.omega)
    pred = a * w[deep] + (1 - a) * tr.tau_applied[deep] / tb.d_m
    assert np.max(np.abs(pred - w[deep + 1])) < 1e-9


@pytest.mark.parametrize("level,stays", [(0.9, True), (0.99, True), (1.05, False)])
def test_stuck_motor_stays_stuck_while_the_net_torque_is_below_breakaway(level, stays):
    f_s = 0.3
    case = _case(("stiction",), env="locked", excitation=Excitation(kind="constant", amplitude=level * f_s),
                 rate_hz=1000.0, duration_s=1.0, effect_params={"F_c": 0.2, "F_s": f_s, "v_s": 0.02})
    _, tr = simulate_independent(case)
    assert bool(np.all(tr.theta == 0.0)) is stays
    assert bool(tr.stuck.all()) is stays
    if not stays:   # it slides until the spring holds it: k theta within [u - F_s, u + F_s]
        assert 0.0 < tr.theta[-1] * tr.testbed.k <= level * f_s + f_s


def test_stick_slip_log_respects_the_static_friction_law():
    p = {"F_c": 0.2, "F_s": 0.35, "v_s": 0.03, "cog_a": (0.03, 0.0), "cog_b": (0.0, 0.02)}
    case = _case(("stiction", "cogging"), env="soft", effect_params=p, initial_angle=0.7, duration_s=6.0)
    _, tr = simulate_independent(case)
    stuck = np.asarray(tr.stuck)
    assert 0.02 < stuck.mean() < 0.9 and tr.events > 10
    assert np.all(tr.omega[stuck] == 0.0)
    # while stuck the friction holds the net torque, never more than F_s
    net = tr.tau_applied - tr.tau_spring - tr.tau_cogging
    np.testing.assert_allclose(tr.tau_friction[stuck], net[stuck], atol=1e-12)
    assert np.max(np.abs(net[stuck])) <= p["F_s"] + 1e-9
    # the angle does not move during a stuck run
    runs = np.flatnonzero(stuck[:-1] & stuck[1:])
    assert np.all(tr.theta[runs] == tr.theta[runs + 1])
    # while sliding the friction follows the Stribeck curve in the direction of motion
    slide = ~stuck & (np.abs(tr.omega) > 1e-6)
    w = np.asarray(tr.omega)[slide]
    curve = np.sign(w) * (p["F_c"] + (p["F_s"] - p["F_c"]) * np.exp(-(w / p["v_s"]) ** 2))
    np.testing.assert_allclose(tr.tau_friction[slide], curve, atol=1e-12)


@pytest.mark.parametrize("words,params,env", [
    (("coulomb",), {"F_c": 0.3}, "soft"),
    (("stiction",), {"F_c": 0.2, "F_s": 0.35, "v_s": 0.03}, "locked"),
    (("backlash",), {"width": 4e-3}, "stiff"),
    (("position_friction",), {"F_c": 0.25, "pos_a": (0.05, 0.0, 0.02), "pos_b": (0.0, 0.04, 0.0)},
     "link-only"),
    (("stiction", "cogging", "backlash"),
     {"F_c": 0.1, "F_s": 0.2, "v_s": 0.02, "cog_a": (0.03,), "cog_b": (0.02,), "width": 2e-3}, "soft"),
])
def test_switch_instants_do_not_depend_on_the_log_rate(monkeypatch, words, params, env):
    """Switches are located by root finding: one held command logged at 1 and 2 kHz, one trajectory."""
    case = _case(words, env=env, rate_hz=1000.0, effect_params=params, initial_angle=1.0, tau_m_digits=17)
    _, slow = simulate_independent(case)
    held = np.repeat(np.asarray(slow.command), 2)
    monkeypatch.setattr(ind.plant, "excitation_signal", lambda ex, n, rate: held[:n])
    _, fast = simulate_independent(dataclasses.replace(case, rate_hz=2000.0))
    assert slow.events > 0 and fast.events == slow.events
    assert np.max(np.abs(fast.theta[::2] - slow.theta)) < 1e-9
    assert np.max(np.abs(fast.omega[::2] - slow.omega)) < 1e-8


# --- logger -------------------------------------------------------------------------------


def test_encoders_quantise_to_two_million_counts_per_revolution():
    assert ENCODER_STEP == 2 * math.pi / 2_000_000
    exp, tr = simulate_independent(_case(env="soft", encoder_noise_counts=0.5))
    for logged, true in ((exp.signals.theta, tr.theta), (exp.signals.q, tr.q)):
        counts = np.asarray(logged) / ENCODER_STEP
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
        assert np.max(np.abs(logged - true)) < 4 * ENCODER_STEP
        steps = np.abs(np.diff(np.round(counts)))
        assert steps[steps > 0].min() == 1.0


@pytest.mark.parametrize("digits", [6, 8, 10])
def test_derived_tau_s_is_k_nominal_deflection_at_the_printed_precision(digits):
    case = _case(env="exp-soft", tau_s_logging=f"derived:{digits}", nominal_errors={"k": 0.02})
    exp, _ = simulate_independent(case)
    sig = exp.signals
    assert not sig.tau_s_derived
    np.testing.assert_array_equal(round_significant(sig.tau_s, digits), sig.tau_s)
    exact = exp.design.testbed.k * (np.asarray(sig.theta) - np.asarray(sig.q))
    nz = exact != 0.0
    ulp = 10.0 ** (np.floor(np.log10(np.abs(exact[nz]))) - digits + 1)
    assert np.all(np.abs(sig.tau_s[nz] - exact[nz]) <= 0.5 * ulp * (1 + 1e-9))
    assert np.any(sig.tau_s[nz] != exact[nz]) or digits >= 10


def test_tau_s_omitted_or_from_an_independent_sensor():
    exp, _ = simulate_independent(_case(env="soft", tau_s_logging="omitted"))
    assert exp.signals.tau_s_derived
    exp, tr = simulate_independent(_case(env="soft", tau_s_logging="sensor", sensor_noise=0.003))
    residual = np.asarray(exp.signals.tau_s) - tr.tau_spring
    assert 0.002 < residual.std() < 0.004 and abs(residual.mean()) < 5e-4
    # a sensor whose zero is off reads spring torque + offset
    exp, tr = simulate_independent(_case(env="soft", tau_s_logging="sensor", sensor_noise=0.003, sensor_offset=0.015))
    residual = np.asarray(exp.signals.tau_s) - tr.tau_spring
    assert residual.mean() == pytest.approx(0.015, abs=5e-4)


def test_drawn_torque_sensors_have_a_bounded_zero_and_scale_and_other_loggers_none():
    from forecast_design.independent.draw import SENSOR_GAIN_ERROR, SENSOR_OFFSET_N_M, draw_independent_case

    cases = [draw_independent_case("none", i, 3) for i in range(60)]
    sensors = [c for c in cases if c.tau_s_logging == "sensor"]
    assert sensors and all(0 < abs(c.sensor_offset) <= SENSOR_OFFSET_N_M for c in sensors)
    assert all(0 < abs(c.sensor_gain - 1) <= SENSOR_GAIN_ERROR for c in sensors)
    assert all(c.sensor_offset == 0.0 and c.sensor_gain == 1.0 for c in cases if c.tau_s_logging != "sensor")
    # the sensor reads gain x spring torque + offset
    exp, tr = simulate_independent(_case(env="soft", tau_s_logging="sensor", sensor_gain=1.05))
    assert np.asarray(exp.signals.tau_s) == pytest.approx(1.05 * tr.tau_spring, abs=1e-5)


def test_printed_command_and_nominal_testbed():
    case = _case(env="soft", tau_m_digits=7, nominal_errors={"J_m": 0.02, "d_m": -0.02, "k": 0.01}, t0_s=12.5)
    exp, tr = simulate_independent(case)
    np.testing.assert_array_equal(round_significant(exp.signals.tau_m, 7), exp.signals.tau_m)
    assert exp.design.testbed == Testbed.nominal()
    assert tr.testbed.J_m * 1.02 == pytest.approx(exp.design.testbed.J_m)
    assert tr.testbed.k * 1.01 == pytest.approx(exp.design.testbed.k)
    assert exp.signals.t[0] == 12.5 and exp.rate_hz == 2000.0


def test_closed_loop_command_is_the_filtered_pd_law_of_the_logged_signals():
    case = _case(("coulomb",), env="locked", closed_loop=True, controller=PD(P=5.0, D=0.1),
                 excitation=Excitation(kind="square", amplitude=0.3, period_s=1.0, slew=5.0),
                 effect_params={"F_c": 0.2}, derivative_filter_hz=80.0, rate_hz=1000.0, tau_m_digits=9)
    exp, tr = simulate_independent(case)
    sig = exp.signals
    e = np.asarray(sig.tau_r) - exp.design.testbed.k * (np.asarray(sig.theta) - np.asarray(sig.q))
    tf, dt = 1 / (2 * math.pi * 80.0), 1e-3
    de = np.zeros_like(e)
    for k in range(1, e.size):
        de[k] = (2 * tf - dt) / (2 * tf + dt) * de[k - 1] + 2 / (2 * tf + dt) * (e[k] - e[k - 1])
    u = np.clip(5.0 * e + 0.1 * de, -case.torque_limit, case.torque_limit)
    np.testing.assert_allclose(sig.tau_m, u, rtol=1e-8, atol=1e-9)
    err = (sig.tau_r - tr.tau_spring)[np.arange(e.size) % 500 > 400]   # settled part of each half period
    assert np.sqrt(np.mean(err ** 2)) < 0.1


def test_a_closed_loop_pid_command_is_the_tustin_pid_the_toml_declares_by_scipy():
    # the log's command against scipy's bilinear discretisation of the continuous PID the TOML declares
    case = _case(("coulomb",), env="locked", closed_loop=True, controller=PID(P=4.0, I=20.0, D=0.08),
                 excitation=Excitation(kind="square", amplitude=0.3, period_s=1.0, slew=5.0),
                 effect_params={"F_c": 0.2}, derivative_filter_hz=80.0, rate_hz=1000.0, tau_m_digits=9)
    exp, tr = simulate_independent(case)
    declared = exp.design.controller
    assert isinstance(declared, PID) and (declared.P, declared.I, declared.D) == (4.0, 20.0, 0.08)
    assert declared.discretization == "tustin" and declared.T_f == pytest.approx(1 / (2 * math.pi * 80.0))
    T_f = declared.T_f
    num = np.polyadd(np.polyadd([4.0 * T_f, 4.0, 0.0], [20.0 * T_f, 20.0]), [0.08, 0.0, 0.0])   # over s (T_f s + 1)
    b, a, _ = signal.cont2discrete((num, [T_f, 1.0, 0.0]), 1e-3, method="bilinear")
    sig = exp.signals
    e = np.asarray(sig.tau_r) - exp.design.testbed.k * (np.asarray(sig.theta) - np.asarray(sig.q))
    u = signal.lfilter(np.ravel(b), a, e)
    assert np.max(np.abs(u)) < case.torque_limit
    # the generator starts its derivative filter at rest on the first error (lfilter from zero): the difference decays
    # with the filter's pole, (2 T_f - T) / (2 T_f + T) = 0.6 per sample
    np.testing.assert_allclose(sig.tau_m[60:], u[60:], rtol=1e-7, atol=1e-8)
    # and the same case under the PD of the same P and D is another log: the integral term acted
    pd_exp, _ = simulate_independent(dataclasses.replace(case, controller=PD(P=4.0, D=0.08)))
    assert np.max(np.abs(np.asarray(pd_exp.signals.tau_m) - np.asarray(sig.tau_m))) > 0.01


# --- excitations ------------------------------------------------------------------------


def test_excitations():
    rate, n = 2000.0, 20000
    ms = excitation_signal(Excitation(kind="multisine", amplitude=0.5, f_lo_hz=0.2, f_hi_hz=20.0, lines=25),
                           n, rate)
    assert np.sqrt(np.mean(ms ** 2)) == pytest.approx(0.5)
    assert np.max(np.abs(ms)) / 0.5 < 2.5                   # crest factor (random phases: ~3 for 23 lines)
    pink = excitation_signal(Excitation(kind="multisine", amplitude=0.5, f_lo_hz=0.2, f_hi_hz=20.0, lines=25,
                                        tilt=1.0), n, rate)
    assert np.max(np.abs(pink)) / 0.5 < 1.7
    sq = excitation_signal(Excitation(kind="square", amplitude=1.0, period_s=2.0, slew=10.0), n, rate)
    assert np.max(np.abs(np.diff(sq))) <= 10.0 / rate + 1e-12 and sq.max() == pytest.approx(1.0)
    ch = excitation_signal(Excitation(kind="chirp", amplitude=0.8, f_lo_hz=0.2, f_hi_hz=10.0), n, rate)
    assert np.max(np.abs(ch)) <= 0.8 and one_line_fraction(ch) < 0.5
    sine = excitation_signal(Excitation(kind="sweep", amplitude=1.0, f_lo_hz=0.3), n, rate)
    assert one_line_fraction(sine) > 0.95 and 0.7 < one_line_fraction(np.sign(sine)) < 0.95


def test_sweeps_turn_the_motor_a_revolution_on_soft_environments():
    for i in range(4):
        case = draw_independent_case(Effect.COGGING, i, 11)
        if case.excitation.kind == "sweep":
            _, tr = simulate_independent(case)
            assert np.ptp(tr.theta) > 2 * math.pi, case


# --- drawing, determinism, identifiability -------------------------------------------------


def test_draws_and_logs_are_deterministic():
    a = draw_independent_case("stiction", 3, 7, magnitude_scale=0.5)
    assert a == draw_independent_case("stiction", 3, 7, magnitude_scale=0.5)
    assert a != draw_independent_case("stiction", 3, 7, magnitude_scale=0.5, attempt=1)
    assert a != draw_independent_case("stiction", 3, 7, magnitude_scale=0.25)
    e1, t1 = simulate_independent(dataclasses.replace(a, duration_s=2.0))
    e2, t2 = simulate_independent(dataclasses.replace(a, duration_s=2.0))
    assert e1.signals == e2.signals and np.array_equal(t1.omega, t2.omega)


def test_a_draw_with_controllers_runs_a_pid_in_half_the_closed_loops_and_changes_nothing_else():
    from forecast_design.independent.draw import PID_I_PER_S

    closed = pid = 0
    for word in ("coulomb", "delay", "none"):
        for index in range(40):
            plain = draw_independent_case(word, index, 7)
            case = draw_independent_case(word, index, 7, controllers=True)
            assert dataclasses.replace(case, controller=plain.controller) == plain
            if isinstance(case.controller, PID):
                assert (case.controller.P, case.controller.D) == (plain.controller.P, plain.controller.D)
                assert PID_I_PER_S[0] <= case.controller.I <= PID_I_PER_S[1]
                assert isinstance(case.design.controller, PID) and case.design.controller.I == case.controller.I
            closed += plain.closed_loop
            pid += isinstance(case.controller, PID)
    assert closed > 20 and abs(pid - closed / 2) <= 3 * math.sqrt(closed / 4)


def test_draws_respect_the_documented_magnitudes():
    for s in (1.0, 0.5, 0.25):
        for i in range(5):
            p = draw_independent_case("backlash", i, 1, magnitude_scale=s).effect_params
            assert 1e-3 * s <= p["width"] <= 5e-3 * s
            g = draw_independent_case("torque_gain", i, 1, magnitude_scale=s).effect_params["gain"]
            assert 0.05 * s <= abs(g - 1) <= 0.2 * s
            d = draw_independent_case("delay", i, 1, magnitude_scale=s).effect_params["delay_s"]
            assert 2e-3 * s <= d <= 6e-3 * s
            c = draw_independent_case("environment_mismatch", i, 1, magnitude_scale=s)
            (f,) = c.effect_params.values()
            assert 1.5 ** s <= max(f, 1 / f) <= 3.0 ** s
            case = draw_independent_case("cogging", i, 1, magnitude_scale=s)
            assert case.environment_name in ("link-only", "soft", "custom") and case.environment.k_e <= 1.0
            assert case.rate_hz in (1000.0, 2000.0) and 5.0 <= case.duration_s <= 20.0
            assert all(abs(e) <= 0.02 for e in case.nominal_errors.values())


def test_identifiability_rules():
    sine = Excitation(kind="sweep", amplitude=0.5, f_lo_hz=0.5)
    case = _case(("delay",), env="locked", excitation=sine, effect_params={"delay_s": 2e-3}, duration_s=2.0)
    assert "spectral line" in identifiability(case, simulate_independent(case)[1])
    case = _case(("environment_mismatch",), env="locked", effect_params={"J_factor": 2.0}, duration_s=1.0)
    assert "locked" in identifiability(case, simulate_independent(case)[1])
    case = _case(("cogging",), env="stiff", effect_params={"cog_a": (0.05,), "cog_b": (0.0,)}, duration_s=1.0)
    assert "2 pi" in identifiability(case, simulate_independent(case)[1])
    case = _case(("stiction",), env="locked", excitation=Excitation(kind="constant", amplitude=0.1),
                 effect_params={"F_c": 0.2, "F_s": 0.3, "v_s": 0.02}, duration_s=1.0)
    assert "reversal" in identifiability(case, simulate_independent(case)[1])
    with pytest.raises(ParameterError):
        draw_independent_case("friction", 0, 0)
    with pytest.raises(ParameterError):
        _case(tau_s_logging="derived")


@pytest.mark.slow
@pytest.mark.parametrize("scale", [1.0, 0.25])   # the ends of the range; 0.5 is in bench-gap
@pytest.mark.parametrize("word", list(Effect))
def test_every_word_gives_an_identifiable_log(word, scale):
    log = make_independent_log(word, 0, 2024, magnitude_scale=scale)
    assert len(log.rejected) < MAX_ATTEMPTS
    assert identifiability(log.case, log.truth) is None
    assert log.case.words == (() if word is Effect.NONE else (word,))
    assert log.case.magnitude_scale == scale
    assert str(word) in log.experiment.description


# --- friction-only logs ---------------------------------------------------------------------


@pytest.mark.parametrize("law,names", [
    ("extended-sfm", ("viscous", "coulomb", "sin1", "cos1", "sin2", "cos2", "sin3", "cos3", "sin4", "cos4")),
    ("stribeck", ("static", "coulomb", "stribeck_velocity", "viscous")),
    ("lugre", ("sigma0", "sigma1", "static", "coulomb", "stribeck_velocity", "viscous")),
])
def test_friction_logs_slide_a_lot_or_little(law, names):
    exp, true = friction_log(law, None, duration_s=10.0, rate_hz=1000.0, seed=3)
    assert tuple(true) == names and exp.design.testbed.d_m == true["viscous"]
    th = np.asarray(exp.signals.theta)
    w = np.gradient(th, 1e-3)
    assert np.mean(np.abs(w) > 0.01) > 0.5                     # plenty of sliding
    assert (w > 0.05).mean() > 0.1 and (w < -0.05).mean() > 0.1  # in both directions
    if law == "extended-sfm":
        assert np.ptp(th) > 2 * math.pi
    else:   # slow breakaways: rests of >= 50 ms that end in sliding
        moving = np.abs(w) > 0.05
        rest_end = np.flatnonzero(moving[1:] & ~moving[:-1])
        rests = [k for k in rest_end if not moving[max(k - 50, 0):k + 1].any()]
        assert len(rests) >= 3
    exp, _ = friction_log(law, None, duration_s=10.0, rate_hz=1000.0, seed=3, excitation="little-sliding")
    th = np.asarray(exp.signals.theta)
    w = np.gradient(th, 1e-3)
    assert np.mean(np.abs(w) > 0.01) < 0.3 and (w < -0.05).mean() < 0.01 and np.ptp(th) < 1.0


def test_friction_log_uses_the_given_parameters():
    exp, true = friction_log("extended-sfm", {"coulomb": 0.2, "sin1": 0.04, "cos1": -0.01}, duration_s=2.0,
                             rate_hz=1000.0)
    assert true == {"viscous": 0.3, "coulomb": 0.2, "sin1": 0.04, "cos1": -0.01}
    with pytest.raises(ParameterError):
        friction_log("stribeck", {"sin1": 0.1}, duration_s=1.0)


# --- issue 25: asymmetric friction, coarse encoders, loggers that round ----------------------------------


def test_asymmetric_friction_acts_with_its_own_level_and_viscous_coefficient_each_way():
    exp, true = friction_log("asymmetric", {"coulomb_pos": 0.3, "coulomb_neg": 0.2, "viscous_pos": 0.3,
                                            "viscous_neg": 0.5}, seed=2, duration_s=4.0, rate_hz=1000.0)
    case = IndependentCase(words=(Effect.COULOMB,), environment=environment_preset("link-only"),
                           environment_name="link-only", excitation=Excitation(kind="sweep", amplitude=1.5,
                                                                               f_lo_hz=0.5, dither=0.03),
                           rate_hz=1000.0, duration_s=4.0, testbed=Testbed(J_m=0.133, d_m=0.3, k=58.0),
                           effect_params={"F_c": 0.3, "F_c_neg": 0.2, "d_neg": 0.5})
    _, truth = simulate_independent(case)
    w, tf, stuck = np.asarray(truth.omega), np.asarray(truth.tau_friction), np.asarray(truth.stuck)
    pos, neg = (w > 1e-3) & ~stuck, (w < -1e-3) & ~stuck
    assert pos.sum() > 200 and neg.sum() > 200
    # friction beyond the testbed's d_m theta': +0.3 one way, -0.2 + (0.5 - 0.3) theta' the other
    assert np.allclose(tf[pos], 0.3, atol=1e-9)
    assert np.allclose(tf[neg], -0.2 + 0.2 * w[neg], atol=1e-9)
    # stuck rows hold at most the breakaway level of the direction they would move in
    held = tf[stuck]
    assert np.all(held <= 0.3 + 1e-6) and np.all(held >= -0.2 - 1e-6)
    assert true == {"viscous_pos": 0.3, "viscous_neg": 0.5, "coulomb_pos": 0.3, "coulomb_neg": 0.2}


@pytest.mark.parametrize("counts", [2**16, 2**14])
def test_coarse_encoders_quantise_both_angles_to_their_own_step(counts):
    case = _case(encoder_counts=counts, duration_s=1.0)
    exp, truth = simulate_independent(case)
    step = 2 * math.pi / counts
    for logged, true in ((exp.signals.theta, truth.theta), (exp.signals.q, truth.q)):
        n = np.asarray(logged) / step
        assert np.allclose(n, np.round(n), atol=1e-6)
        assert np.max(np.abs(np.asarray(logged) - true)) <= 0.5 * step + 1e-12
    assert case.encoder_step == step


@pytest.mark.parametrize("tau_s,angles", [("decimals:4", "exact"), ("decimals:6", "decimals:8"),
                                          ("derived:7", "digits:9")])
def test_loggers_print_tau_s_and_the_angles_with_their_own_rounding(tau_s, angles):
    case = _case(duration_s=1.0, tau_s_logging=tau_s, angle_logging=angles)
    exp, truth = simulate_independent(case)
    sig = exp.signals
    kind, _, n = tau_s.partition(":")
    col = np.asarray(sig.tau_s)
    if kind == "decimals":
        assert np.all(np.abs(col * 10 ** int(n) - np.round(col * 10 ** int(n))) < 1e-6)
    else:
        assert np.array_equal(col, round_significant(col, int(n)))
    # tau_s was computed from the quantised angles before they were printed: within the printed rounding
    th, q = np.asarray(sig.theta), np.asarray(sig.q)
    if angles.startswith("decimals"):
        d = int(angles.split(":")[1])
        assert np.all(np.abs(th * 10 ** d - np.round(th * 10 ** d)) < 1e-6)
    exact = case.testbed.k * (np.round(np.asarray(truth.theta) / ENCODER_STEP) - np.round(np.asarray(truth.q) / ENCODER_STEP)) * ENCODER_STEP
    if kind == "decimals":
        bound = 0.5 * 10.0 ** -int(n)
    else:
        mag = np.floor(np.log10(np.where(exact != 0, np.abs(exact), 1.0)))
        bound = 0.5 * 10.0 ** (mag - int(n) + 1)
    assert np.all(np.abs(col - exact) <= bound * (1 + 1e-9) + 1e-15)


def test_a_float32_logger_stores_tau_s_and_the_angles_as_32_bit_floats():
    case = _case(duration_s=1.0, tau_s_logging="float32", angle_logging="float32")
    exp, truth = simulate_independent(case)
    sig = exp.signals
    for col in (sig.tau_s, sig.theta, sig.q):
        col = np.asarray(col)
        assert np.array_equal(col.astype(np.float32).astype(float), col)     # exactly representable in float32
    # tau_s was k (theta - q) of the quantised angles, rounded to float32 (half an ulp: 2^-24 relative)
    exact = case.testbed.k * (np.round(np.asarray(truth.theta) / ENCODER_STEP)
                              - np.round(np.asarray(truth.q) / ENCODER_STEP)) * ENCODER_STEP
    assert np.all(np.abs(np.asarray(sig.tau_s) - exact) <= np.abs(exact) * 2.0 ** -24 + 1e-300)
    assert np.all(np.abs(np.asarray(sig.theta) - np.round(np.asarray(truth.theta) / ENCODER_STEP) * ENCODER_STEP)
                  <= np.abs(np.asarray(sig.theta)) * 2.0 ** -24 + 1e-300)
    with pytest.raises(ParameterError, match="float32"):
        _case(tau_s_logging="float64")
