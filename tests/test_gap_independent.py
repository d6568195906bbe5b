"""The diagnosis on logs of the independent generator: one test per failure class of issue 11.

Every log here comes from :mod:`forecast_design.independent` (scipy event-located
integration, its own loggers and excitations, nominal errors of up to 2 %), never
from the virtual testbed the diagnosis was developed on.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from forecast_design import independent as ind
from forecast_design.effects import Effect
from forecast_design.gap import diagnose
from forecast_design.experiment import experiment_from_arrays
from forecast_design.gap.halfband import persists_in_half_band
from forecast_design.gap.candidates import fit_baseline
from forecast_design.gap.replicas import PROBABLE_P, probable_verdict, replica_check
from forecast_design.gap.residuals import classify_tau_s, significant_digits
from forecast_design.controllers import PD
from forecast_design.params import environment_preset


def _log(word, index=0, seed=5, scale=1.0, **changes):
    case = ind.draw_independent_case(word, index, seed, magnitude_scale=scale)
    if "effect_params" in changes:
        changes["effect_params"] = {**case.effect_params, **changes["effect_params"]}
    exp, truth = ind.simulate_independent(dataclasses.replace(case, **changes))
    return exp, truth


def _draw_where(word, seed, **want):
    """The first draw (index 0, 1, ...) of ``word`` whose case has the wanted fields (no simulation)."""
    for index in range(400):
        case = ind.draw_independent_case(word, index, seed)
        if all(getattr(case, k) == v for k, v in want.items()):
            return case
    pytest.skip(f"no {word} draw with {want} in 400 draws")


def _diagnosed(word, index, seed, effect, **draw):
    """The diagnosis (``joint=False``) of an independent log at full size and its ranked candidate ``effect``."""
    d = diagnose(ind.make_independent_log(word, index, seed, **draw).experiment, joint=False)
    return d, next(r for r in d.ranking if r.effect is effect)


def _laws(word, index, seed):
    """A draw with controllers (half the closed loops under a PID): log, diagnosis, stiction and coulomb fits."""
    log = ind.make_independent_log(word, index, seed, controllers=True)
    d = diagnose(log.experiment, joint=False)
    return log, d, d.fits["stiction"], d.fits["coulomb"]


def _first_identifiable(word, seed, scale=1.0, **want):
    """The first identifiable independent log (index 0, 1, ...) whose case has the wanted fields."""
    for index in range(40):
        log = ind.make_independent_log(word, index, seed, magnitude_scale=scale)
        if all(getattr(log.case, k) == v for k, v in want.items()):
            return log
    pytest.skip(f"no {word} log with {want} in 40 draws")


# --- 1. a tau_s column the logger derived from the encoders --------------------------------


@settings(max_examples=60, deadline=None)
@given(digits=st.integers(6, 10), k=st.floats(5.0, 500.0), scale=st.floats(1e-4, 0.1), seed=st.integers(0, 10_000))
def test_tau_s_printed_from_the_encoders_is_judged_derived_at_any_precision(digits, k, scale, seed):
    rng = np.random.default_rng(seed)
    step = 2 * np.pi / 2_000_000
    theta = np.round(np.cumsum(rng.normal(0, scale, 4000)) / step) * step
    q = np.round(0.3 * theta / step) * step
    tau_s = np.array([float(f"{v:.{digits}g}") for v in k * (theta - q)])
    src = classify_tau_s(False, tau_s, theta, q)
    assert src.source == "derived" and src.digits <= digits
    assert src.k_log == pytest.approx(k, rel=1e-5)
    # an independent sensor (noise far above the printed precision) is a measurement
    noisy = tau_s + rng.normal(0, 1e-4 * max(np.std(tau_s), 1e-3), tau_s.size)
    assert classify_tau_s(False, noisy, theta, q).source == "measured"


def test_significant_digits_reads_the_printed_precision():
    assert significant_digits(np.array([1.25, -3.5e-7, 12345.0])) == 5
    assert significant_digits(np.array([np.pi])) == 16


@pytest.mark.slow
@pytest.mark.parametrize("logging", ["derived:9", "derived:6", "omitted"])
@pytest.mark.parametrize("env", ["locked", "exp-soft"])
def test_backlash_is_named_whatever_the_tau_s_column(env, logging):
    exp, _ = _log("backlash", 1, 7, environment=environment_preset(env), environment_name=env, tau_s_logging=logging,
                  effect_params={"width": 3e-3})
    d = diagnose(exp, joint=False)
    assert d.data.tau_s_source.source == ("absent" if logging == "omitted" else "derived")
    assert d.effect is Effect.BACKLASH and d.reduction >= 0.5


# --- 1b. a torque sensor whose zero is off -----------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("word,env,offset,gain", [("none", "locked", 0.02, 1.0), ("none", "stiff", -0.02, 1.08),
                                                  ("delay", "locked", 0.02, 0.92), ("cogging", "exp-soft", -0.02, 1.0),
                                                  ("none", "locked", 0.0, 1.08)])
def test_a_torque_sensor_zero_and_scale_are_calibrated_out_not_blamed(word, env, offset, gain):
    # a closed-loop log turning a few hundredths of a radian from a sensor reading gain x spring
    # torque + offset: the offset is a constant torque, which the old diagnosis called cogging, and
    # an 8 % scale was named environment_mismatch or torque_gain (bench-gap --generator independent
    # fell to 80-93 % once the generator drew sensor errors); now both are calibrated (they show in
    # the coupling equation too) and the effect is named
    params = {"none": {}, "delay": {"delay_s": 0.003}, "cogging": {"cog_a": (0.12,), "cog_b": (0.05,)}}[word]
    case = ind.IndependentCase(
        words=(word,), environment=environment_preset(env), environment_name=env, closed_loop=True,
        controller=PD(P=5.0, D=0.1),
        excitation=ind.Excitation(kind="multisine", amplitude=0.6, f_lo_hz=0.2, f_hi_hz=3.0), rate_hz=2000.0,
        duration_s=10.0, tau_s_logging="sensor", sensor_noise=0.002, sensor_offset=offset, sensor_gain=gain,
        effect_params=params, seed=11)
    exp, _ = ind.simulate_independent(case)
    d = diagnose(exp, joint=False)
    assert d.data.tau_s_source.measured
    assert str(d.effect) == word
    # the verdict's calibration is the sensor's: true spring torque = scale tau_s + o, scale = 1 / gain,
    # o = -offset / gain
    cal = d.fits.get(word, d.baseline).calibration
    o = cal["tau_s_offset_N_m"]
    assert o == pytest.approx(-offset / gain, abs=0.2 * abs(offset) + 2e-3)
    assert cal["spring_scale"] == pytest.approx(1.0 / gain, abs=0.01)
    # the calibrated model replays the sensor's reading
    assert d.replay.tau_s_error_after < 0.5 * d.replay.tau_s_error_before or abs(gain - 1) + abs(offset) < 0.03
    # named in a note once beyond the calibration tolerance of the peak spring torque
    peak = np.max(np.abs(d.data.columns["tau_s"]))
    assert any("zero offset" in c for c in d.caveats) == (abs(o) > d.data.options.calibration_tolerance * peak)


# --- 2. a torque gain the re-calibration must not absorb ------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("gain", [0.9, 0.95, 1.05, 1.1])
def test_small_torque_gains_are_named_not_absorbed(gain):
    case = _draw_where("torque_gain", 3, closed_loop=False, environment_name="link-only")
    exp, _ = ind.simulate_independent(dataclasses.replace(case, effect_params={"gain": gain}))
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.TORQUE_GAIN
    # the gain and a re-calibration within the datasheet tolerance are one direction: the reported
    # interval carries the distance from the fit's calibration to any within the tolerance, which covers the
    # generator's own nominal errors (up to 2 %) too (with the +-3 % of a nominal calibration alone, the
    # 1.05 and 1.1 gains, J_m on its bound, needed 2 % more)
    st_ = d.ranking[0].assessment.status["gain"]
    assert st_.status == "identified"
    assert abs(st_.value - gain) <= 1.96 * st_.std
    assert (st_.value - 1.0) * (gain - 1.0) > 0
    # the re-calibration stays inside the datasheet tolerance it is allowed
    tb = exp.design.testbed
    assert abs(d.baseline.calibration["J_m"] / tb.J_m - 1) <= d.data.options.calibration_tolerance + 1e-9


# --- 3. stiction against coulomb in an open loop, k_e = 5 -----------------------------------


@pytest.mark.slow
def test_open_loop_stiction_in_a_soft_environment_is_stiction():
    hits = 0
    for seed in (21, 22, 23):
        case = _draw_where("stiction", seed, closed_loop=False, environment_name="exp-soft")
        exp, truth = ind.simulate_independent(case)
        assert ind.identifiability(case, truth) is None
        d = diagnose(exp, joint=False)
        hits += d.effect is Effect.STICTION
    assert hits == 3


# --- 4. a short closed-loop log with a delay -------------------------------------------------


@pytest.mark.slow
def test_five_second_closed_loop_log_with_a_short_delay_is_named():
    log = _first_identifiable("delay", 4, closed_loop=True)
    exp, _ = ind.simulate_independent(dataclasses.replace(
        log.case, duration_s=5.0, effect_params={"delay_s": 1.5e-3}))
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.DELAY
    assert d.params["delay_s"] == pytest.approx(1.5e-3, rel=0.35)


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [2.0e-3, 2.5e-3])
def test_a_delay_seen_only_at_the_edges_of_a_slow_square_is_named(delay_s):
    # an open-loop square of period 2.3 s on a locked output, 5.7 s at 1 kHz: the delay acts at the
    # few edges, removes 98 % of the held-out gap, but in 5 of 20 test units; over all units the t-test
    # on the log ratios gave p = 0.0014-0.0021, short of the Bonferroni level (verdict none)
    case = dataclasses.replace(ind.draw_independent_case("delay", 1, 11), effect_params={"delay_s": delay_s})
    exp, truth = ind.simulate_independent(case)
    assert ind.identifiability(case, truth) is None
    d = diagnose(exp, joint=False)
    assert d.effect is Effect.DELAY
    assert d.params["delay_s"] == pytest.approx(delay_s, rel=0.15)


@pytest.mark.slow
@pytest.mark.parametrize("index, loop", [(4, "closed"), (8, "open")])
def test_a_delay_on_a_short_square_is_tested_at_the_level_the_fit_blocks_give_it(index, loop):
    # a closed-loop square of 8.3 s (5.2 ms) and an open-loop one of 10.9 s (2.9 ms): the delay removes 44 % and
    # 21 % of the held-out gap and every test unit with an edge improves many-fold, but over 20-30 units the test
    # gives p = 0.003 / 0.002, short of the plain Bonferroni level 0.01 / 8 (verdict none). The delay explains the
    # fit blocks best, and the level of each candidate is fixed there before the held-out test: 0.005 for it
    log = ind.make_independent_log("delay", index, 71)
    assert log.case.closed_loop is (loop == "closed") and log.case.excitation.kind == "square"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.DELAY
    true_s = log.case.effect_params["delay_s"]
    # what the short log resolves is coefficient x delay (5.19 / 3.15 ms for 5.21 / 2.86); the delay alone comes
    # with an interval that covers the truth and says it is wide
    assert d.fits["delay"].coef[-1] * d.params["delay_s"] == pytest.approx(true_s, rel=0.15)
    status = d.to_mapping()["verdict"]["status"]["delay_s"]
    assert abs(status["value"] - true_s) <= 1.96 * status["std"] and status["status"] == "uncertain"


@pytest.mark.slow
def test_a_large_effect_the_held_out_test_leaves_short_of_its_level_is_named_probable_where_no_replica_produces_it():
    # A 16-bit closed-loop square with a 3.7 ms delay: the delay is identified and removes 65 % of the gap, but only
    # 32 of the 50 held-out units improve (the others by none or less), so even by signed ranks the test gives
    # p = 0.013 against its level 0.005. A bare "none" hid it; no effect-free replica of the log's chain makes a delay
    # explain a fortieth of the torque it explains here, so it is named, graded probable, and says what it rests on
    log = ind.make_independent_log("delay", 6, 80)
    assert log.case.closed_loop and log.case.excitation.kind == "square"
    doc = diagnose(log.experiment, joint=False).to_mapping()
    for r in doc["ranking"]:      # what "counts" means, entry by entry
        assert not r["counts"] or (r["level"] is not None and r["p_value"] < r["level"])
    v = doc["verdict"]
    assert (v["effect"], v["grade"]) == ("delay", "probable")
    delay = doc["ranking"][0]
    assert delay["effect"] == "delay" and delay["short_of_level"] and not delay["counts"]
    assert delay["level"] <= delay["p_value"] < PROBABLE_P and delay["reduction"] >= 0.4
    assert v["replicas"]["distinct"] and v["replicas"]["observed_N_m"] >= 1.5 * max(v["replicas"]["replicas_N_m"])
    true_s = log.case.effect_params["delay_s"]
    assert abs(v["status"]["delay_s"]["value"] - true_s) <= 1.96 * v["status"]["delay_s"]["std"]
    said = [c for c in doc["caveats"] if c.startswith("Probable: 'delay'")]
    assert len(said) == 1 and f"over {delay['n_units']} units" in said[0]
    # its first half (23 units): p = 0.08, beyond what the replicas may name; the verdict is none and says why
    e, s = log.experiment, log.experiment.signals
    n = e.n_samples // 2
    half = experiment_from_arrays(e.design, e.rate_hz, s.t[:n], s.tau_m[:n], s.theta[:n], s.q[:n], tau_s=s.tau_s[:n],
                                  tau_r=s.tau_r[:n])
    doc = diagnose(half, joint=False).to_mapping()
    delay = next(r for r in doc["ranking"] if r["effect"] == "delay")
    assert doc["verdict"]["effect"] == "none" and delay["p_value"] >= PROBABLE_P and not delay["short_of_level"]
    said = [c for c in doc["caveats"] if c.startswith("Not proven: 'delay'")]
    assert len(said) == 1 and f"over {delay['n_units']} units" in said[0]


def test_a_candidate_short_of_its_level_that_effect_free_replicas_produce_is_no_verdict():
    # an effect-free 16-bit open-loop log: its Coulomb candidate explains 2.2 mN m, its effect-free replicas as much;
    # were its held-out test short of its level only, the replicas still would not let it be named
    log = ind.make_independent_log("none", 2, 5)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    coulomb = next(r for r in d.ranking if r.effect is Effect.COULOMB)
    assert not coulomb.short_of_level and coulomb.explained_rms > 0.0
    span = dict(angle_span_rad=d.location.angle_span_rad, n_harmonics=d.data.options.n_harmonics)
    short = [dataclasses.replace(coulomb, short_of_level=True)]
    assert probable_verdict(d.data, short, fit_baseline(d.data), d.fits, span) is None


def test_a_pair_of_effects_the_replicas_produce_is_no_verdict():
    # an effect-free 2,000,000-count closed loop on a locked output with a torque sensor: no effect counts alone, and a
    # stiction of 0.9 mN m with a torque gain of 0.958 together removed 65 % of a 1.4 mN m gap, named stiction with a
    # second effect (the stiction alone was not even resolved above the torque accuracy); the replicas of its chain
    # (the sensor's noise fed back) make each explain as much
    log = ind.make_independent_log("none", 7, 238)
    assert log.case.closed_loop and log.case.environment_name == "locked" and log.case.tau_s_logging == "sensor"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE and d.secondary is None
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors")]
    assert len(said) == 1 and "nor the pair with" in said[0]


def test_replicas_of_a_locked_output_read_it_at_zero_and_run_the_declared_inertia_where_the_log_held_its_bound():
    # an open-loop 16-bit log on a locked output whose angles jitter: the replicas' jittered q failed the format's
    # q == 0 on every replica, so a weak verdict there went unchecked
    log = ind.make_independent_log("none", 3, 238, magnitude_scale=0.25)
    assert log.case.environment_name == "locked" and not log.case.closed_loop
    d = diagnose(log.experiment, joint=False)
    check = replica_check(d.data, fit_baseline(d.data), d.fits["torque_gain"], n=3)
    assert check is not None and check.encoder_jitter_counts > 0.0 and len(check.replicas_N_m) == 3
    # and its weak torque gain of 0.965 (J_m's re-calibration on its -3 % bound, pushed there by the encoders' 0.75
    # counts of jitter) is what replicas run with the declared J_m produce too: no effect is named
    assert d.effect is Effect.NONE and d.calibration["J_m"].status == "at_bound"
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors: 'torque_gain'")]
    assert len(said) == 1 and "jittering" in said[0]


@pytest.mark.slow
def test_replicas_of_a_closed_loop_on_encoder_angles_feed_the_encoders_jitter_back():
    # a 16-bit closed-loop square with a 2.7 ms delay and tau_s derived from encoders jittering 0.79 counts: the loop
    # feeds the jitter back into the motor torque, and a stiction fitted on it (12 mN m) was named, weak, against
    # replicas whose loop read the angles without jitter (19 copies of one deterministic run, 3.2 mN m); replicas
    # reading them with the jitter matched to the log's toggles produce as much: no effect is named
    log = ind.make_independent_log("delay", 8, 132)
    case = log.case
    assert case.closed_loop and case.encoder_counts == 2**16 and case.tau_s_logging != "sensor"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors: 'stiction'")]
    assert len(said) == 1 and "its controller and force reference" in said[0] and "jittering" in said[0]
    check = replica_check(d.data, fit_baseline(d.data), d.fits["stiction"], n=4)
    # the jitter read from the log's toggles is the generator's, and the replicas are no longer one run
    assert abs(check.encoder_jitter_counts - case.encoder_noise_counts) <= 0.1 * case.encoder_noise_counts
    assert len(set(check.replicas_N_m)) == 4


@pytest.mark.slow
def test_replicas_draw_where_the_count_edges_lie_so_a_log_without_noise_has_replicas_that_differ():
    # an effect-free 14-bit open-loop sweep on another SEA, no encoder jitter, no sensor: its replicas had no noise source
    # and were one run, against which a torque gain of 0.956 (J_m's re-calibration on its bound) explaining 9.7 mN m
    # was a weak verdict, 1.8 times that run's; replicas homed anywhere within a count explain 4.4-6.8 mN m
    log = ind.make_independent_log("none", 2, 256)
    case = log.case
    assert not case.closed_loop and case.encoder_counts == 2**14 and case.encoder_noise_counts == 0.0
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors: 'torque_gain'")]
    assert len(said) == 1 and "its motor command, open loop" in said[0]
    check = replica_check(d.data, fit_baseline(d.data), d.fits["torque_gain"], n=4)
    assert check.encoder_jitter_counts == 0.0 and len(set(check.replicas_N_m)) == 4


@pytest.mark.slow
def test_a_closed_loop_whose_controller_has_no_equations_is_checked_on_its_replayed_command():
    # a lab's code controller is logged as kind "other": the simulator cannot run it, every replica failed, and the
    # weak verdict went out unchecked and unsaid (a 2.7 ms delay in a 16-bit loop named a weak stiction); its replicas
    # now replay the logged command open loop and say so
    from forecast_design.controllers import OtherController

    log = ind.make_independent_log("delay", 8, 132)
    exp = log.experiment
    other = dataclasses.replace(exp, design=dataclasses.replace(exp.design, controller=OtherController(name="lab")))
    d = diagnose(other, joint=False)
    assert d.effect is Effect.NONE
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors: 'stiction'")]
    assert len(said) == 1 and "replayed open loop: its controller has no equations" in said[0]
    replicas = d.to_mapping()["verdict"]["replicas"]
    assert replicas["replayed"] is True and replicas["closed_loop"] is False


@pytest.mark.slow
def test_a_closed_loops_own_command_replayed_is_a_second_null():
    # an effect-free 2^21-count closed-loop square on a locked output, tau_s derived by the tool: a dead band of 1 mrad
    # removing 27 % of the gap (41 % of its equations') was a clear verdict; no replica of the loop explains any of it
    # (one deterministic run), and the log's own command replayed open loop through the same chain explains as much
    log = ind.make_independent_log("none", 6, 265, controllers=True)
    assert log.case.closed_loop and log.case.environment_name == "locked" and log.case.tau_s_logging == "omitted"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    said = [c for c in d.caveats if c.startswith("Not distinct from the sensors: 'backlash'")]
    assert len(said) == 1 and "its logged command replayed open loop" in said[0]
    replicas = d.to_mapping()["verdict"]["replicas"]
    assert len(replicas["replays_N_m"]) == len(replicas["replicas_N_m"]) == 19
    assert max(replicas["replicas_N_m"]) < replicas["observed_N_m"] / 1.5 <= max(replicas["replays_N_m"])


def test_a_weak_verdict_whose_replicas_could_not_run_says_it_was_not_checked():
    from types import SimpleNamespace

    from forecast_design.gap.replicas import weak_caveat

    winner = SimpleNamespace(effect=Effect.DELAY, reduction_own=0.24, p_value=1.7e-3)
    said = weak_caveat(winner, None, 0.4)
    assert "removes 24 %" in said and "not checked against effect-free replicas" in said
    assert "the sensors alone may produce it" in said


def test_the_report_says_the_grade_and_the_controller_the_log_declares(tmp_path):
    # a weak or probable verdict is said where the verdict is, and the loop by the controller the log declares
    # (the report called every closed loop "PD")
    from forecast_design.controllers import PID
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.reporting import write_report

    log = ind.make_independent_log("delay", 8, 151)
    d = diagnose(log.experiment, joint=False)
    assert (d.effect, d.grade) == (Effect.DELAY, "probable")
    text = write_report(d, log.experiment, tmp_path / "pd").read_text()
    assert "**delay** (graded probable)" in text and "closed loop (PD P=" in text
    assert diagnosis_views(d).grade == "probable"      # the before/after plot's title says it too
    pid = dataclasses.replace(log.experiment, design=dataclasses.replace(log.experiment.design,
                                                                          controller=PID(P=4.0, I=2.0, D=0.05)))
    text = write_report(d, pid, tmp_path / "pid").read_text()
    assert "closed loop (PID P=4 I=2 D=0.05" in text and "(PD" not in text


@pytest.mark.slow
def test_a_viscous_recalibration_far_from_the_declared_one_is_reported_and_said():
    # d_m has no datasheet tolerance (only d_m >= 0). On a 14-bit closed-loop square with stiction (true d_m 0.30 N m
    # s/rad) the nominal model's re-calibration took d_m = 12 (40 x) and the verdict was a bare none: the friction
    # had gone into d_m, and neither the JSON's calibration nor a caveat said so
    log = ind.make_independent_log("stiction", 6, 132)
    declared = log.experiment.design.testbed.d_m
    doc = diagnose(log.experiment, joint=False).to_mapping()
    d_m = doc["verdict"]["calibration"]["d_m"]["value"]
    assert d_m > 10 * declared
    said = [c for c in doc["caveats"] if c.startswith("Caution: the re-calibrated viscous friction")]
    assert doc["verdict"]["effect"] != "none" or len(said) == 1
    # an effect-free log keeps its d_m within the factor and says nothing of it
    free = diagnose(ind.make_independent_log("none", 6, 132).experiment, joint=False).to_mapping()
    ratio = free["verdict"]["calibration"]["d_m"]["value"] / declared
    assert 0.5 <= ratio <= 2.0 and not any("viscous friction d_m" in c for c in free["caveats"])

# --- 4b. the verdict's intervals: a delay, a dead band and an environment cover the truth --------

_TRUE_NAME = {"delay": {"delay_s": "delay_s"}, "backlash": {"width": "width_rad"},
              "coulomb": {"F_c": "F_c", "F_c_neg": "F_c_neg"},
              "environment_mismatch": {"J_factor": "J_scale", "d_factor": "d_scale", "k_e_factor": "k_e_scale"}}


@pytest.mark.slow
@pytest.mark.parametrize("word", list(_TRUE_NAME))
def test_verdict_intervals_cover_the_truth_on_independent_logs(word):
    # A grid parameter (delay, dead band) came out `identified` with no interval at all, an environment's
    # scales with intervals of 1e-5 around a 3 % error (the spring torque's re-calibration on its bound) and
    # Coulomb levels 0.2-5 % off under intervals of 0.01-1 % (the filter's error at the reversals): 0 of 38
    # delays, 0 of 40 widths and 49 of 74 levels covered on four seeds. Now every number with a status carries
    # an interval with the analysis' own error, and on a seed never used while the intervals were built the
    # 95 % intervals cover the truth.
    covered = total = 0
    for index in range(5):
        log = ind.make_independent_log(word, index, 41)
        d = diagnose(log.experiment, joint=False)
        status = d.ranking[0].assessment.status
        for st_ in status.values():
            if st_.status == "identified":
                assert st_.std is not None and 0.0 < st_.std < math.inf, st_
        if d.effect is not Effect(word):
            continue
        truth = {**{k: 1.0 for k in ("J_factor", "d_factor", "k_e_factor")}, **log.case.effect_params}
        truth.setdefault("F_c_neg", truth.get("F_c"))
        for true_name, name in _TRUE_NAME[word].items():
            if name in status and status[name].std is not None:
                total += 1
                covered += abs(status[name].value - truth[true_name]) <= 1.96 * status[name].std
    assert total >= 4
    assert covered >= total - max(1, total // 10), (covered, total)


# --- 5. absurd parameters are never a verdict ------------------------------------------------


@pytest.mark.slow
def test_locked_output_turning_a_few_hundredths_of_a_radian_gets_no_absurd_verdict():
    case = _draw_where("coulomb", 11, closed_loop=True, environment_name="locked")
    cog = ind.draw_independent_case("cogging", 0, 11)
    exp, truth = ind.simulate_independent(dataclasses.replace(case, words=(Effect.COGGING,),
                                                              effect_params=cog.effect_params))
    assert np.ptp(truth.theta) < 0.2
    d = diagnose(exp, joint=False)
    m = d.to_mapping()
    torque_max = float(np.max(np.abs(exp.signals.tau_m)))
    for name, st_ in m["verdict"]["status"].items():
        assert st_["status"] != "implausible", name
    for r in m["ranking"]:
        if r["counts"]:
            for name, value in r["params"].items():
                values = value if isinstance(value, list) else [value]
                if name in ("a", "b", "F_c", "F_s"):
                    assert all(abs(v) <= 1.5 * torque_max for v in values)
    # a harmonic fit over a few hundredths of a radian is reported as not identified, or is plausible
    cog = next(r for r in m["ranking"] if r["effect"] == "cogging")
    assert not cog["counts"] or all(v["status"] != "implausible" for v in cog["status"].values())


@pytest.mark.slow
def test_friction_levels_that_would_be_a_constant_torque_are_fitted_as_one_level():
    # a 16-bit closed-loop square that hardly moves one way (stiction, F_c 0.276 N m): two levels fitted
    # 0.965 / 0.277 N m, lower on the held-out blocks than one level, but a factor 3.5 apart, which is a
    # constant torque, not friction; the candidate was then not identified and the verdict `none`. The
    # friction law keeps one level for both directions, which the log identifies.
    log = ind.make_independent_log("stiction", 4, 3)
    assert log.case.closed_loop and log.case.encoder_counts == 2 ** 16
    d = diagnose(log.experiment, joint=False)
    coulomb = next(r for r in d.ranking if r.effect is Effect.COULOMB)
    assert coulomb.params["F_c"] == coulomb.params["F_c_neg"]
    assert coulomb.assessment.identified
    f_c = coulomb.assessment.status["F_c"]
    assert abs(f_c.value - log.case.effect_params["F_c"]) <= 1.96 * f_c.std
    assert d.effect is not Effect.NONE


# --- 5b. fits that explain the encoders' quantisation: an output inertia, a closed loop's delay ----------------


@pytest.mark.slow
@pytest.mark.parametrize("word, index, seed, scale, want, checked", [
    ("none", 0, 54, 0.25, Effect.NONE, Effect.ENVIRONMENT_MISMATCH),   # stiff, 16-bit: J fitted at 0.22 of the declared
    ("none", 4, 54, 0.25, Effect.NONE, Effect.ENVIRONMENT_MISMATCH),   # stiff, 16-bit: J at 0.69
    # 16-bit open-loop sweep, custom output: J at 0.13 in the full band, 1.11 and 4.2 in half and a quarter of it;
    # the quarter band confirmed a deviation on the other side of 1 (named environment_mismatch, weak)
    ("none", 3, 121, 0.25, Effect.NONE, Effect.ENVIRONMENT_MISMATCH),
    ("none", 7, 54, 0.25, Effect.NONE, Effect.DELAY),      # 14-bit closed-loop chirp, locked: a "delay" of 11.6 ms
    ("none", 5, 53, 0.25, Effect.NONE, Effect.COULOMB),    # 16-bit open-loop sweep: a Coulomb level of 1.7 mN m
    # 16-bit open-loop multisine, k = 145: a torque gain of 0.987 (J_m on its bound), 0.999 in half the band
    ("none", 4, 83, 1.0, Effect.NONE, Effect.TORQUE_GAIN),
    # 16-bit open-loop multisine, k = 145: a gain of 0.9931, within the tolerance, told from a re-calibration only by
    # J_m on its -3 % bound, which it leaves in half the band (named torque_gain, weak)
    ("none", 7, 82, 1.0, Effect.NONE, Effect.TORQUE_GAIN),
    # 16-bit open-loop sweep, k = 145: a delay of 1.29 ms at coefficient 1.50; in half the band 20 ms, the search's
    # end, at 0.17 (coefficient x delay "within a factor 2"), in a quarter of it none (named delay, clear, before)
    ("none", 2, 85, 0.25, Effect.NONE, Effect.DELAY),
    # 16-bit closed-loop multisine, k = 145, locked: a delay of 4.47 ms removing 62 % of the gap; in half the band
    # coefficient x delay 3.10 ms ("within a factor 2") while the refit raised the held-out gap (named delay, clear)
    ("none", 3, 131, 1.0, Effect.NONE, Effect.DELAY),
    # 14-bit closed-loop multisine, k = 145: 1.21 ms at coefficient 1.48; in half the band 12.3 ms at 0.08, coefficient
    # x delay "within a factor 2", the held-out gap 2 % lower at p = 0.12: not significant there (named delay, clear)
    ("none", 1, 131, 0.25, Effect.NONE, Effect.DELAY),
    ("environment_mismatch", 6, 54, 1.0, Effect.ENVIRONMENT_MISMATCH, None),   # stiff, 16-bit, d x 2.55: kept
    # link-only, 16-bit, d x 0.921: 0.894 in the full band, 0.949 in half of it (48 % of the deviation), held to
    # a quarter of the band: kept (named torque_gain when only the full and half bands were compared)
    ("environment_mismatch", 1, 0, 0.125, Effect.ENVIRONMENT_MISMATCH, None),
    # true gains of 0.969 and 0.967 at a quarter of their size: 0.930 / 0.922 in the full band (traded with the
    # re-calibration), 0.969 / 0.966 in half of it, beyond the re-calibration's tolerance: kept
    ("torque_gain", 2, 83, 0.25, Effect.TORQUE_GAIN, None),
    ("torque_gain", 9, 71, 0.25, Effect.TORQUE_GAIN, None),
    # an effect-free 2^21-count closed-loop square, stiff: a "stiction" of F_s 4.7 mN m over F_c 0.9 mN m (the
    # quantisation floor 0.7 mN m), named clear; F_c gone in half the band
    ("none", 3, 90, 0.25, Effect.NONE, Effect.STICTION),
    # 2^21-count squares whose motor is stuck 90-93 % of the time: true levels of 0.40 and 0.18 / 0.22 N m fell to
    # 0.09 and 0 in half the band, which loses the short slides, and were named torque_gain; 1,300 and 700 times
    # the quantisation floor, no quantisation's making: kept
    ("coulomb", 3, 91, 1.0, Effect.COULOMB, None),
    ("coulomb", 9, 93, 1.0, Effect.COULOMB, None),
])
def test_a_fit_that_explains_the_encoders_quantisation_does_not_persist_in_half_the_band(word, index, seed, scale,
                                                                                           want, checked):
    # the output's quantisation in q'' makes a least-squares J "explain" the noise by shrinking (errors in
    # variables), and a closed loop answers the encoders' noise a few milliseconds later, which a delayed command
    # fits; in half the band the effect-free logs' J comes back to 0.92-0.99 and the delay runs to the end of its
    # search, while a true mismatch keeps its value (the d x 2.55 of the last log: 2.542 -> 2.546). Before: the
    # four effect-free logs were named environment_mismatch, environment_mismatch, delay and coulomb (graded weak)
    log = ind.make_independent_log(word, index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is want
    if checked is not None:
        fit = next(r for r in d.ranking if r.effect is checked)
        assert not fit.identified
        # the half band refuses it on its own (the 1.7 mN m Coulomb level is also below the torque accuracy, which
        # is checked first)
        alone = dataclasses.replace(fit.assessment, identified=True, reasons=())
        assert not persists_in_half_band(d.data, d.fits[str(checked)], alone).identified
    elif want is Effect.ENVIRONMENT_MISMATCH:
        assert d.params["d_scale"] == pytest.approx(log.case.effect_params["d_factor"], rel=0.05)
    elif want is Effect.COULOMB:
        status = d.to_mapping()["verdict"]["status"]
        truth = log.case.effect_params
        for name in ("F_c", "F_c_neg"):
            want_value = truth.get(name, truth["F_c"])
            assert abs(status[name]["value"] - want_value) <= 1.96 * status[name]["std"]


# --- 5c. what a log resolves only together: a short delay's coefficient x delay, an output J under quantisation --


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale", [(2, 53, 1.0), (7, 11, 0.25), (8, 3, 1.0), (1, 62, 1.0)])
def test_a_closed_loop_delay_whose_coefficient_trades_with_the_delay_is_named(index, seed, scale):
    # a delay short against the equation band shows only as coefficient x delay (u(t - d) ~ u - d u'): the fit is
    # flat along that ridge and its minimum sat on the coefficient's bound 1.5, "not identified", verdict none
    # (5.9 ms removing 94 % of the gap). Read at the next longer delay whose coefficient is inside its bounds, the
    # delay is named within a factor 1.3 of the truth (4.6 / 0.62 / 5.6 / 4.6 ms for 5.9 / 0.71 / 5.5 / 4.5 ms)
    log = ind.make_independent_log("delay", index, seed, magnitude_scale=scale)
    assert log.case.closed_loop
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.DELAY
    fit = d.fits["delay"]
    assert 0.0 < fit.coef[-1] < fit.structure.coefs[-1].hi          # the coefficient inside its bounds
    assert d.params["delay_s"] == pytest.approx(log.case.effect_params["delay_s"], rel=0.3)


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale, factor", [(1, 3, 1.0, "d_factor"), (3, 53, 0.25, "k_e_factor")])
def test_an_environment_whose_inertia_the_output_encoder_cannot_resolve_is_fitted_with_the_declared_one(
        index, seed, scale, factor):
    # a 16- and a 14-bit open-loop sweep: least squares shrinks the output's J to 0.057 and 0.017 of the declared
    # value (errors in variables: q'' carries the quantisation), beyond any plausible environment, and the true
    # d x 0.604 / k_e x 0.768 went unnamed (none, cogging). J is then held at its declared value and said so
    log = ind.make_independent_log("environment_mismatch", index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH
    assert "J_scale" not in d.params and any(c.startswith("Assumed: the environment's J") for c in d.caveats)
    assert d.params[factor.replace("factor", "scale")] == pytest.approx(log.case.effect_params[factor], rel=0.03)
    status = d.to_mapping()["verdict"]["status"]
    assert "J_scale" not in status and all(v["std"] > 0.0 for v in status.values())


@pytest.mark.slow
@pytest.mark.parametrize("word, index, seed", [
    ("coulomb", 0, 61),
    # coulomb removes 73.9 % of the gap and stiction 73.6 %: the BIC ranks coulomb first; the nested rule decides
    # (the Stribeck coefficient at Wald p = 7e-8, stiction better on the held-out units at p = 0.011)
    ("stiction", 3, 3),
])
def test_a_motor_creeping_below_the_speed_resolution_of_a_coarse_encoder_is_read_so_where_the_data_say(word, index,
                                                                                                       seed):
    # 14-bit closed loops pushing against friction creep a count every few tens of milliseconds: below the speed
    # resolution (one step per derivative window) the friction's direction was unresolved, on 91 % of the coulomb
    # log's samples, while it slid at its full level: coulomb fitted F_c = 0 and the verdict was
    # environment_mismatch; the stiction log (F_s 0.255, F_c 0.190 N m) was named coulomb. Read as creeping where
    # the recorded angle moves the same way on both sides of a sample between two samples moving that way, the
    # friction fits predict the held-out data better (0.048 against 0.067 N m); the direction is the truth's in 98 % and
    # 64 % of those samples (on the stiction log a third of them are short stays at rest, which the encoder cannot tell)
    from forecast_design.gap.motion import creeping

    log = ind.make_independent_log(word, index, seed)
    assert log.case.closed_loop and log.case.encoder_counts == 2 ** 14
    d = diagnose(log.experiment, joint=False)
    assert d.data.creep and any(c.startswith("Assumed: below the encoder's speed resolution") for c in d.caveats)
    fill = creeping(d.data)
    assert np.mean(np.sign(np.asarray(log.truth.omega)[fill != 0.0]) == fill[fill != 0.0]) > 0.6
    assert d.effect is Effect(word)
    if word == "stiction":      # named for its breakaway, which the fit resolves: F_s 0.246 for 0.255 N m
        for name in ("F_c", "F_s", "v_s"):
            assert d.params[name] == pytest.approx(log.case.effect_params[name], rel=0.1)


@pytest.mark.slow
def test_a_fit_the_half_band_exposes_as_quantisation_never_joins_a_pair():
    # a 14-bit stiction sweep whose output J the full band shrinks to 0.12 (0.72 in half the band): rejected alone,
    # the environment mismatch came back as the first of a pair with a 1 % delay and was the verdict
    log = ind.make_independent_log("stiction", 3, 53)
    d = diagnose(log.experiment, joint=False)
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert not env.identified and any("half the equation band" in why for why in env.assessment.reasons)
    assert Effect.ENVIRONMENT_MISMATCH not in {d.effect, getattr(d.secondary, "effect", None)}


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale", [(1, 90, 1.0), (0, 92, 0.25)])
def test_an_effect_that_removes_most_of_the_total_gap_is_tested_on_the_total_at_the_unsplit_level(index, seed, scale):
    # 2^21-count closed-loop squares with the environment's J x 0.44 and x 1.16: the mismatch removed 82 % and 52 % of
    # the total held-out gap, 98-100 % of its own equation's, and its total test gave p = 0.0076 against the
    # candidate's Bonferroni share 0.005: "does not lower the total", verdict none. A candidate that removes
    # min_reduction of the total is not one that explains a quiet equation while the total stays (the case the total
    # test is for); its total is asked at the unsplit level, its own test keeping the share
    log = ind.make_independent_log("environment_mismatch", index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH and d.reduction >= d.data.options.min_reduction
    status = d.to_mapping()["verdict"]["status"]["J_scale"]
    assert abs(status["value"] - log.case.effect_params["J_factor"]) <= 1.96 * status["std"]


# --- 6. the second effect is machine-readable --------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(8, 53), (2, 73)])
def test_an_environment_mismatch_removing_less_of_the_total_than_a_motor_candidate_is_no_verdict(index, seed):
    # 16-bit torque-gain logs (open-loop multisine, closed-loop square) with a torque sensor: an environment mismatch
    # explained 75-90 % of the quiet environment equation, 6-10 % of the total gap, and was the clear verdict, while
    # the true gain removed 26-28 % of the total. The gap lies in the motor equation
    log = ind.make_independent_log("torque_gain", index, seed)
    d = diagnose(log.experiment, joint=False)
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    gain = next(r for r in d.ranking if r.effect is Effect.TORQUE_GAIN)
    assert env.reduction < gain.reduction and not env.significant
    assert d.effect is Effect.TORQUE_GAIN
    assert any(c.startswith("Not counted: 'environment_mismatch'") for c in d.to_mapping()["caveats"])


@pytest.mark.slow
def test_backlash_read_in_the_coupling_equation_alone_yields_to_a_motor_candidate_removing_more_of_the_total():
    # a 16-bit open-loop square with a torque sensor and a torque gain of 1.14: backlash in the coupling equation
    # (tau_s against k (theta - q)) explained 59 % of that equation but 0.6 % of the total gap and was the clear
    # verdict, while the true gain removed 37 % of the total at p = 1e-21. The gap lies in the motor equation
    log = ind.make_independent_log("torque_gain", 3, 120)
    d = diagnose(log.experiment, joint=False)
    backlash = next(r for r in d.ranking if r.effect is Effect.BACKLASH)
    gain = next(r for r in d.ranking if r.effect is Effect.TORQUE_GAIN)
    assert backlash.equations == ("coupling",) and backlash.reduction_own > d.data.options.min_reduction
    assert backlash.reduction < gain.reduction and not backlash.significant
    assert d.effect is Effect.TORQUE_GAIN
    assert any(c.startswith("Not counted: 'backlash' explains") for c in d.to_mapping()["caveats"])
    status = d.to_mapping()["verdict"]["status"]["gain"]
    assert abs(status["value"] - log.case.effect_params["gain"]) <= 1.96 * status["std"]


@pytest.mark.slow
def test_second_effect_is_in_the_json():
    log = _first_identifiable("coulomb", 8, closed_loop=False)
    case = dataclasses.replace(log.case, words=(Effect.COULOMB, Effect.TORQUE_GAIN),
                               effect_params={**log.case.effect_params, "gain": 0.7})
    exp, _ = ind.simulate_independent(case)
    m = json.loads(json.dumps(diagnose(exp, joint=False).to_mapping()))
    named = {m["verdict"]["effect"], (m["verdict"]["secondary"] or {}).get("effect")}
    assert named == {"coulomb", "torque_gain"}
    sec = m["verdict"]["secondary"]
    assert set(sec) == {"effect", "params", "gap_after", "reduction", "status"}
    assert sec["gap_after"] <= m["verdict"]["gap_after"] and sec["reduction"] >= m["verdict"]["reduction"]
    # the pair's numbers carry their intervals: the gain's holds the truth
    gain = sec["status"]["gain"]
    assert gain["std"] is not None and abs(gain["value"] - 0.7) <= 1.96 * gain["std"]


# --- isolability: computed from the log ---------------------------------------------------------


@pytest.mark.slow
def test_isolability_follows_the_excitation():
    # a slow sweep through revolutions: angle effects are told from coulomb
    sweep = _first_identifiable("cogging", 0)
    iso = diagnose(sweep.experiment, joint=False).isolability
    assert iso.isolable("cogging", "coulomb") and iso.isolable("position_friction", "coulomb")
    # the torque gain is told from a re-calibration of J_m, d_m, k only by the latter's bound
    assert not iso.isolable("torque_gain", "calibration")


def test_group_wald_test_on_collinear_and_unexcited_columns_equals_the_test_of_their_shared_column():
    from forecast_design.gap.identifiability import _Design, _group_wald_p

    rng = np.random.default_rng(4)
    n = 400
    x = np.sin(np.linspace(0.0, 7.0, n)) + 0.3
    noise = 0.05 * rng.standard_normal(n)
    y = 0.02 * x + noise
    beta = float(x @ y / (x @ x))
    rows = np.ones(n, dtype=bool)

    def design(A, coef):
        coef = np.asarray(coef, dtype=float)
        return _Design(A=A, rows=rows, residual=y - A @ np.nan_to_num(coef), coef=coef,
                       bound=np.zeros(coef.size, dtype=bool))

    single = _group_wald_p(design(x[:, None], [beta]), [0])
    assert 0.0 < single < 1.0
    # two identical columns share one direction: a rank-1 test of their sum, whatever the split
    for a in (beta, 0.3 * beta, -5.0 * beta):
        dup = _group_wald_p(design(np.column_stack([x, x]), [a, beta - a]), [0, 1])
        assert dup == pytest.approx(single, rel=1e-9)
    # a column the fit rows never excite carries no test
    assert _group_wald_p(design(np.column_stack([x, np.zeros(n)]), [beta, 0.0]), [0, 1]) == \
        pytest.approx(single, rel=1e-9)
    assert _group_wald_p(design(np.zeros((n, 1)), [1.0]), [0]) == 1.0
    assert _group_wald_p(design(x[:, None], [np.nan]), [0]) == 1.0


def test_hac_covariance_of_a_column_never_excited_has_infinite_not_zero_variance():
    import warnings

    from forecast_design.friction._lsq import hac_covariance

    rng = np.random.default_rng(0)
    W = np.column_stack([rng.normal(size=400), np.zeros(400), rng.normal(size=400)])
    W[:200, 2] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = hac_covariance(W, rng.normal(size=400), keep=np.arange(400) >= 200)
    # no NaN and no warning; the column the data never excite has no variance (infinite), not a zero
    # one (issue 25: a zero standard deviation is a covariance that failed), the others are finite
    cov = res.covariance
    assert not np.any(np.isnan(cov)) and np.isinf(cov[1, 1])
    assert np.all(np.isfinite(np.delete(np.delete(cov, 1, 0), 1, 1)))


# --- 5d. friction laws that name nothing coulomb would not, friction below the torque accuracy ------------------


@pytest.mark.slow
def test_a_friction_level_below_the_motors_torque_accuracy_is_not_friction():
    # an effect-free 2,000,000-count closed-loop square (RMS command 0.14 N m): a LuGre law with a Coulomb level
    # of 0.10 mN m and 3 mrad bristles removed the whole gap above the quantisation floor at p = 6e-17 and was the
    # verdict (a false alarm). No motor resolves a friction level below 0.1 % of its RMS command
    log = ind.make_independent_log("none", 4, 72, magnitude_scale=0.25)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    stiction = next(r for r in d.ranking if r.effect is Effect.STICTION)
    assert any("torque accuracy" in reason for reason in stiction.assessment.reasons)


@pytest.mark.slow
def test_a_richer_friction_law_that_does_not_beat_coulomb_is_no_verdict_even_when_coulomb_is_weak():
    # a 16-bit open-loop multisine with Coulomb friction of 0.152 N m: coulomb removed 37 % of the gap above the
    # floor (weak), a LuGre law with one-count bristles 42 % (clear) without beating coulomb on the held-out data
    # (nested p = 0.64): the verdict was stiction. The richer law must beat coulomb whenever coulomb is resolved
    # (since the rows of starts and stops hold the sliding level, coulomb is clear on this log)
    log = ind.make_independent_log("coulomb", 6, 71)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    assert max(d.params["F_c"], d.params["F_c_neg"]) == pytest.approx(log.case.effect_params["F_c"], rel=0.05)


@pytest.mark.slow
def test_an_effect_free_closed_loop_square_with_a_torque_sensor_is_no_stiction():
    # a sign(v)-like torque of 0.5 mN m (0.2 % of the RMS command, 0.35 of the gap above the floor) on an
    # effect-free 2,000,000-count closed-loop square with a torque sensor: stiction with an unresolved bump
    # (dF at Wald p = 0.8) was the clear verdict; it is not stiction
    log = ind.make_independent_log("none", 5, 73)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is not Effect.STICTION


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(9, 84), (7, 82), (4, 90)])
def test_stiction_held_at_rest_beyond_any_coulomb_level_is_stiction_where_its_bump_is_below_the_speed_resolution(
        index, seed):
    # open-loop logs whose Stribeck velocity (10-21 mrad/s) is within a few speed steps of the encoders: rows of
    # several stays at rest hold more than the Coulomb level can, but the bump's coefficient dF was at Wald
    # p = 0.07-0.19 and the held-out units that tell the laws apart few (nested p 0.06-0.28), and the verdict was
    # coulomb, with stiction explaining more of the gap. The rows at rest decide; the breakaway level is reported
    # as uncertain, the sliding level identified and covering the truth
    log = ind.make_independent_log("stiction", index, seed)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.STICTION
    status = d.to_mapping()["verdict"]["status"]
    truth = log.case.effect_params
    assert status["F_c"]["status"] == "identified"
    assert abs(status["F_c"]["value"] - truth["F_c"]) <= 1.96 * status["F_c"]["std"]
    assert abs(status["F_s"]["value"] - truth["F_s"]) <= 1.96 * status["F_s"]["std"]


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(5, 11), (0, 81)])
def test_a_breakaway_the_encoder_proves_at_rest_decides_between_the_laws_whatever_the_bic(index, seed):
    # open-loop sweeps (14-bit and 2^21 counts) with stiction of F_s / F_c = 1.7: coulomb removed as much of the
    # gap as stiction or more (0.45 / 0.45, 0.82 / 0.63) and, with fewer parameters, won the BIC, which never asked
    # the nested rule: the verdict was coulomb. At rest the motor held torques no Coulomb level lets it hold within one
    # count; that decides
    from forecast_design.gap.heldout import breakaway_proven_at_rest

    log = ind.make_independent_log("stiction", index, seed)
    d = diagnose(log.experiment, joint=False)
    assert breakaway_proven_at_rest(d.data, d.fits["coulomb"])
    assert d.effect is Effect.STICTION
    assert any(c.startswith("Stiction over coulomb") for c in d.to_mapping()["caveats"])
    assert not any(c.startswith("Not proven at rest") for c in d.caveats)


@pytest.mark.slow
@pytest.mark.parametrize("word, index, seed", [("coulomb", 0, 25), ("coulomb", 0, 92), ("coulomb", 6, 11),
                                               ("coulomb", 8, 84), ("coulomb", 3, 70)])
def test_coulomb_friction_never_proves_a_breakaway_at_rest(word, index, seed):
    # closed-loop squares (2^21 and 2^16 counts) stuck most of the time and an open-loop one: the filtered rows at
    # rest of the first held 1.13 F_c (the filter rings after the torque steps inside a stay), the raw-rate bound
    # stays within the level (on 520 Coulomb logs of twenty-six seeds at full and small sizes, none proved one)
    from forecast_design.gap.heldout import breakaway_proven_at_rest

    log = ind.make_independent_log(word, index, seed)
    d = diagnose(log.experiment, joint=False)
    assert not breakaway_proven_at_rest(d.data, d.fits["coulomb"])


@pytest.mark.slow
def test_a_coulomb_level_held_at_rest_within_the_analysis_error_is_no_breakaway():
    # a 16-bit closed-loop square with Coulomb friction, stuck 70 % of the time, the motor held at its level: the
    # coulomb fit's level, biased by the filters at the reversals, lay below the held torques, which then passed
    # for a breakaway (LuGre stiction, clear). The level's own error, its shift with the filter's cut-off halved,
    # is added before a held torque counts as a breakaway
    from forecast_design.gap.heldout import breakaway_resolved_at_rest

    log = ind.make_independent_log("coulomb", 0, 92)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    assert not breakaway_resolved_at_rest(d.data, d.fits["stiction"], d.fits["coulomb"])
    status = d.to_mapping()["verdict"]["status"]["F_c"]
    assert abs(status["value"] - log.case.effect_params["F_c"]) <= 1.96 * status["std"]


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale, named, sensor, closed", [
    # a 16-bit closed loop with a torque sensor reading 6.4 % high: a gain of 0.966 removed all of the gap above the
    # encoders' floor, 3.4 % of the total (clear)
    (8, 111, 1.0, Effect.TORQUE_GAIN, True, True),
    # open loop, 16 bits, a sensor reading 6.4 % low: a gain of 0.956 explaining 5.7 mN m, 48 % of the gap above the
    # floor (clear); its replicas' gain explains 6.1 mN m
    (2, 122, 0.25, Effect.TORQUE_GAIN, True, False),
    # a 16-bit closed-loop square, tau_s derived: the loop's answer to the encoders' quantisation read as a 4.4 ms
    # delay (weak, held-out p = 0.00045, still there in half the band)
    (8, 140, 0.25, Effect.DELAY, False, True),
])
def test_an_effect_free_log_whose_small_effect_its_sensors_alone_produce_names_none(index, seed, scale, named,
                                                                                     sensor, closed):
    log = ind.make_independent_log("none", index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    check = d.replicas
    assert check is not None and check.effect is named and not check.distinct and check.closed_loop is closed
    if sensor:      # the replicas' sensor noise is the log's, read from tau_s alone
        assert check.sensor_noise_std_N_m == pytest.approx(log.case.sensor_noise, rel=0.15)
    else:
        assert check.sensor_noise_std_N_m is None
    assert check.encoder_counts == pytest.approx(log.case.encoder_counts, rel=0.01)      # read from the angles
    assert any(c.startswith(f"Not distinct from the sensors: '{named}'") for c in d.caveats)
    assert d.to_mapping()["verdict"]["replicas"]["distinct"] is False


@pytest.mark.slow
def test_an_effect_free_log_whose_encoders_jitter_names_no_friction():
    # an effect-free closed-loop square on a stiff environment, a torque sensor fed back, 16-bit encoders jittering
    # 0.78 counts: 55 % of the motor encoder's count changes are undone on the next sample, and a Coulomb level of
    # 67 mN m removed 25 % of the gap (held-out p = 1e-21), named clear coulomb. Replicas read without jitter explained
    # up to 11 mN m of its 19 mN m; read with the log's jitter, up to 42 mN m: the encoders' answer, not friction
    from forecast_design.gap.replicas import toggle_share

    log = ind.make_independent_log("none", 4, 193)
    assert toggle_share(np.asarray(log.experiment.signals.theta, dtype=float)) > 0.5
    d = diagnose(log.experiment, joint=False)
    check = d.replicas
    assert check is not None and check.effect is Effect.COULOMB and check.closed_loop and not check.distinct
    assert check.encoder_jitter_counts == pytest.approx(log.case.encoder_noise_counts, abs=0.15)
    assert d.to_mapping()["verdict"]["replicas"]["encoder_jitter_counts"] == check.encoder_jitter_counts
    assert any(c.startswith("Not distinct from the sensors: 'coulomb'") and "jittering" in c for c in d.caveats)
    assert d.effect is Effect.NONE


@pytest.mark.slow
def test_a_weak_delay_in_a_closed_loop_stands_above_the_loops_noise():
    # a 14-bit closed-loop square with a torque sensor and a true delay: weak (24 % of the gap above the floor), and
    # effect-free replicas of the loop (their encoders homed anywhere within a count) explain at most a fifth of it
    log = ind.make_independent_log("delay", 4, 150)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.DELAY and d.grade == "weak"
    assert d.replicas is not None and d.replicas.distinct and d.replicas.ratio > 5.0
    assert d.params["delay_s"] == pytest.approx(log.case.effect_params["delay_s"], rel=0.5)


@pytest.mark.slow
def test_a_weak_effect_none_of_whose_parameters_the_log_resolves_is_not_named():
    # an effect-free 2,000,000-count open-loop multisine into a locked output, with a torque sensor: eight cogging
    # harmonics (a1 = 1.8 N m), every one on a direction of the harmonics the log does not resolve, removed 12 % of
    # the gap at p = 8e-7 and were the weak verdict (a false alarm)
    d, cogging = _diagnosed("none", 2, 103, Effect.COGGING)
    assert d.effect is Effect.NONE
    assert cogging.weak and all(st.status == "not_identifiable" for st in cogging.assessment.status.values())


@pytest.mark.slow
def test_a_weak_effect_whose_intervals_each_exceed_their_plausible_range_is_not_named():
    # an effect-free 16-bit open-loop multisine with a torque sensor, the motor turning 0.72 rad: four cogging
    # harmonics of 0.2-1.6 N m, each +- 250-9,000 N m against a plausible 0-2.7 N m, removed 1 % of the gap above the
    # floor at p = 4.5e-4, 1.8 times their replicas': the weak verdict (a false alarm)
    d, cogging = _diagnosed("none", 1, 281, Effect.COGGING, controllers=True)
    assert d.effect is Effect.NONE and cogging.weak
    for st in cogging.assessment.status.values():
        assert st.status == "uncertain" and 1.96 * st.std > st.plausible[1] - st.plausible[0]


@pytest.mark.slow
def test_a_dead_band_explaining_less_than_the_spring_torques_quantisation_is_not_named():
    # an effect-free 16-bit closed-loop square, stiff environment: a "dead band" of 4.6 mrad removed 1.5 % of the gap
    # at p = 3e-9 and was the weak verdict (a false alarm); the torque it explained, 1.6 mN m RMS, is 0.7 of the
    # quantisation of the spring torque k (theta - q) it acts on (true dead bands of twenty-two seeds: at least 1.5)
    from forecast_design.gap.candidates import effect_rows
    from forecast_design.gap.grading import explained_rms

    d, backlash = _diagnosed("none", 3, 102, Effect.BACKLASH)
    assert d.effect is Effect.NONE
    assert backlash.withheld_by_accuracy and not backlash.weak and not backlash.significant
    fit = d.fits["backlash"]
    rows = d.data.stacked(d.data.held_out) & effect_rows(d.data, fit)
    assert explained_rms(d.baseline, fit, rows) < d.data.spring_torque_quantisation


@pytest.mark.slow
def test_a_dead_band_the_spring_leaves_only_at_the_extremes_of_the_motion_is_searched_for():
    # a 2,000,000-count closed-loop chirp with a 3.34 mrad dead band: the spring deflects at most 2.38 mrad either
    # way, and the search ended at 0.8 of the 99th percentile (a width of 3.68 mrad), where the fit sat: "a search
    # that stops at its bound has not found the value", verdict environment_mismatch. It now runs to the largest
    # deflection less one count
    log = ind.make_independent_log("backlash", 6, 73)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.BACKLASH
    status = d.to_mapping()["verdict"]["status"]["width_rad"]
    assert abs(status["value"] - log.case.effect_params["width"]) <= 1.96 * status["std"]


# --- 5e. a verdict a re-calibration or another effect explains as well, a dead band on its ridge ------------


@pytest.mark.slow
def test_a_verdict_that_a_re_calibration_within_the_tolerance_explains_as_well_is_not_named():
    # a torque gain at a quarter of its size fitted at 1.016, inside the +-3 % a re-calibration stands for (so not
    # named as a gain), explains 73 % of the gap; a stiction law, through its share of the command, 20 %: stiction
    # was the verdict (weak). The log cannot tell it from the re-calibration
    log = ind.make_independent_log("torque_gain", 5, 3, magnitude_scale=0.25)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    gain = next(r for r in d.ranking if r.effect is Effect.TORQUE_GAIN)
    assert gain.assessment.rescaling and not gain.identified
    assert abs(gain.params["gain"] - 1.0) <= d.data.options.calibration_tolerance
    # the stiction law's 4.4 mN m level is not resolved above the motor's torque accuracy either (its interval reaches
    # 0.3 mN m): no friction to name in the re-calibration's place
    stiction = next(r for r in d.ranking if r.effect is Effect.STICTION)
    assert not stiction.assessment.identified and gain.gap_after <= stiction.gap_after
    assert any("not resolved above the motor's torque accuracy" in x for x in stiction.assessment.reasons)


@pytest.mark.slow
@pytest.mark.parametrize("word, index, seed, scale, tied", [
    # 0.034 rad: harmonics of up to 102 N m, cogging at 62 % of the gap, gain 79 %; coulomb 26 % (weak) then, 93 %
    # (clear) since the rows of starts and stops hold the sliding level: no tie with cogging left to flag
    ("coulomb", 8, 25, 1.0, False),
    ("torque_gain", 2, 25, 0.125, True),    # 0.68 rad: cogging at 88 % of the gap, environment_mismatch 88 %
])
def test_a_periodic_torque_over_less_than_a_period_is_named_only_where_nothing_else_explains_as_much(word, index, seed,
                                                                                                       scale, tied):
    # over less than a period of the highest harmonic the angle harmonics are a polynomial in the angle (an offset,
    # a spring, a curvature): they fit whatever smooth torque the log carries as the angle follows it, with large
    # coefficients that cancel. Each was named cogging (clear). A true cogging there is still named where nothing
    # explains as much (tests/test_gap.py). The second log is one the generator calls not identifiable
    case = ind.draw_independent_case(word, index, seed, magnitude_scale=scale)
    d = diagnose(ind.simulate_independent(case)[0], joint=False)
    # nor is any other effect named in its place (the tie's candidate keeps its place among a pair's first steps:
    # given to the fourth, an unidentified stiction paired with a delay on the coulomb log)
    assert d.effect in (Effect.NONE, Effect(word))
    assert any(c.startswith("Not distinguished: the motor turns through") for c in d.caveats) == tied
    cog = next(r for r in d.ranking if r.effect is Effect.COGGING)
    assert any(r.effect is not Effect.COGGING and r.gap_after <= cog.gap_after for r in d.ranking)


@pytest.mark.slow
def test_a_periodic_torque_another_reading_explains_as_well_joins_no_pair():
    # a 16-bit closed-loop square turning 6.5 mrad: cogging (39 % of the gap) tied with stiction (54 %) and was
    # dropped, then came back with a torque gain as a pair, and was the verdict (clear, harmonics of 1.3-4.0 N m);
    # then a weak torque gain of 0.71 with the tie flagged. Since the rows of starts and stops hold the sliding
    # level, coulomb removes 68 % of the gap (23 % before) and is the verdict, cogging far behind
    log = ind.make_independent_log("coulomb", 0, 0, magnitude_scale=0.5)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    assert Effect.COGGING not in {d.effect, getattr(d.secondary, "effect", None)}


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale", [
    (2, 81, 1.0),    # 16-bit closed-loop square, 3.00 mrad: c on its bound 2 at 1.41 mrad, verdict environment_mismatch
    (7, 83, 0.25),   # open-loop square, locked, 0.45 mrad: c on 2 at 0.21 mrad, verdict torque_gain
    (7, 53, 0.25),   # 16-bit closed-loop square, 1.00 mrad: c 0.29 at the search's widest 3.10 mrad, verdict cogging
    (3, 71, 1.0),    # closed-loop square, 3.06 mrad, the spring engaged only 0.07 mrad beyond: on the search's end
])
def test_a_dead_band_the_motion_crosses_quickly_is_read_where_it_is_physical(index, seed, scale):
    # the spring is inside its dead band for a few samples per reversal: the log resolves the torque the band takes
    # off outside it, c k h, and the fit is flat along c x h; the width is read at c nearest 1 (the physical dead
    # band), and the search is finer in its last step. Each was "not identified" before
    log = ind.make_independent_log("backlash", index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.BACKLASH
    status = d.to_mapping()["verdict"]["status"]["width_rad"]
    assert abs(status["value"] - log.case.effect_params["width"]) <= 1.96 * status["std"]
    c = float(d.fits["backlash"].coef[-1])
    assert 0.5 <= c <= 1.5


@pytest.mark.slow
@pytest.mark.parametrize("word, index, seed, scale", [
    ("delay", 9, 61, 1.0),    # closed-loop square, 3.1 ms: 95 % of the gap, 10 of 10 units better, t p = 0.0095
    ("delay", 3, 142, 1.0),   # open-loop square, 4.2 ms: 64 % of the gap, 19 of 20 units better, t p = 0.012
    ("torque_gain", 6, 62, 1.0),   # closed-loop square, gain 1.068: 60 % of the gap, t p = 0.012
])
def test_an_effect_whose_improvement_spans_decades_across_units_is_proven_by_ranks(word, index, seed, scale):
    # an effect at a square's edges improves every unit, some a thousandfold and some by a percent: the t-test on the
    # units' log ratios loses its power to that spread (the fit blocks' leader, tested at 0.005, named none). For a
    # candidate of a clear verdict's size the test over every unit is the signed-rank test
    from forecast_design.gap.grading import noise_floor
    from forecast_design.gap.heldout import effect_held_out_test, test_units

    log = ind.make_independent_log(word, index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect(word)
    r, fit = d.ranking[0], d.fits[word]
    units, floor = test_units(d.data, fit), noise_floor(d.data)
    by_t = effect_held_out_test(d.data, d.baseline, fit, units=units, floor=floor)
    by_rank = effect_held_out_test(d.data, d.baseline, fit, units=units, floor=floor, rank=True)
    assert by_rank == r.p_value < r.level <= by_t
    name = "delay_s" if word == "delay" else "gain"
    status = d.to_mapping()["verdict"]["status"][name]
    assert abs(status["value"] - log.case.effect_params[name]) <= 1.96 * status["std"]


@pytest.mark.slow
def test_a_consistent_small_improvement_on_an_effect_free_log_is_held_to_the_t_test():
    # an effect-free closed-loop log: a torque gain of 0.953 removes 1.5 % of the gap, a few percent in 100 of 120
    # units, and the signed-rank test would prove it (p ~ 1e-12) where the t-test does not (0.025): below a clear
    # verdict's size the t-test stays, and the log is named none
    from forecast_design.gap.grading import noise_floor
    from forecast_design.gap.heldout import effect_held_out_test, test_units

    log = ind.make_independent_log("none", 7, 72)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    r, fit = next(x for x in d.ranking if x.effect is Effect.TORQUE_GAIN), d.fits["torque_gain"]
    units, floor = test_units(d.data, fit), noise_floor(d.data)
    assert r.reduction_own < d.data.options.min_reduction
    assert effect_held_out_test(d.data, d.baseline, fit, units=units, floor=floor, rank=True) < r.level
    assert r.p_value == effect_held_out_test(d.data, d.baseline, fit, units=units, floor=floor) > r.level


@pytest.mark.slow
def test_stiction_whose_levels_the_log_does_not_separate_is_named_on_a_proven_breakaway():
    # a 16-bit closed-loop square (F_c 0.12, F_s 0.23 N m): the stiction fit removes 95 % of the gap against coulomb's
    # 40 %, but its Coulomb level is not told from zero (Wald p = 0.36) and the verdict was coulomb. The motor held
    # net torques beyond any Coulomb level while the encoder read one count: stiction, its levels unresolved
    log = ind.make_independent_log("stiction", 2, 122)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.STICTION
    st, coul = d.ranking[0], next(r for r in d.ranking if r.effect is Effect.COULOMB)
    assert not st.assessment.identified and st.reduction > coul.reduction
    assert any(c.startswith("Unresolved: the levels of 'stiction'") for c in d.caveats)
    status = d.to_mapping()["verdict"]["status"]
    for name in ("F_c", "F_s"):
        assert status[name]["status"] != "identified"
        assert abs(status[name]["value"] - log.case.effect_params[name]) <= 1.96 * status[name]["std"]


@pytest.mark.slow
@pytest.mark.parametrize("index,seed,path", [
    (3, 163, "stribeck"),   # closed-loop square, 2e6 counts: dF 0.06 % of F_c, its Wald test at p = 0.002
    (2, 131, "bristles"),   # closed-loop square, 16 bits: bristles a grid point wider than a count, F_s 3 % above
])
def test_a_breakaway_within_the_margin_of_a_coulomb_level_is_not_stiction(index, seed, path):
    # Coulomb friction with true sticking, named stiction: the stiction fit's breakaway stands within
    # BREAKAWAY_MARGIN (the Coulomb level's own error) of a Coulomb level, which is not F_s > F_c
    from forecast_design.gap.heldout import BREAKAWAY_MARGIN, NESTED_ALPHA, richer_law_resolved
    from forecast_design.gap.identifiability import terms_wald_p

    log = ind.make_independent_log("coulomb", index, seed)
    d = diagnose(log.experiment, joint=False)
    st, coul = d.fits["stiction"], d.fits["coulomb"]
    level = max(st.params["F_c"], st.params["F_c_neg"])
    breakaway = st.params["F_s"] - st.params["F_c"] + level
    if path == "stribeck":
        assert terms_wald_p(d.data, st, ["dF"]) < NESTED_ALPHA and breakaway < (1 + BREAKAWAY_MARGIN) * level
    else:
        x_p = next(g for g in st.structure.grid if g[0] == "x_p")
        assert x_p[1] > x_p[2] and breakaway < (1 + BREAKAWAY_MARGIN) * max(coul.params["F_c"], coul.params["F_c_neg"])
    assert not richer_law_resolved(d.data, st, coul)
    assert d.effect is Effect.COULOMB
    ranked = {r.effect: r for r in d.ranking}
    # the law set aside removed more of the gap: the output says so
    assert ranked[Effect.STICTION].significant and ranked[Effect.STICTION].reduction > ranked[Effect.COULOMB].reduction
    assert any(c.startswith("Parsimony: 'stiction' removes") for c in d.to_mapping()["caveats"])
    status = d.to_mapping()["verdict"]["status"]
    for name in ("F_c", "F_c_neg"):
        truth = log.case.effect_params.get(name, log.case.effect_params["F_c"])
        assert abs(status[name]["value"] - truth) <= 1.96 * status[name]["std"]


@pytest.mark.slow
@pytest.mark.parametrize("index,seed", [(7, 113), (2, 90)])   # closed loop, 2e6 counts: a multisine and a square
def test_a_stribeck_bump_narrower_than_the_stick_velocity_is_no_breakaway(index, seed):
    # Coulomb friction named stiction: the Stribeck bump sat on the search's lowest width (1-1.3 mrad/s, below the
    # 2 mrad/s under which a row may be at rest) at 2.5-4 x F_c, its coefficient at Wald p < 1e-7. A bump that
    # narrow acts only on rows the law at rest holds; only the rows at rest could prove it, and they do not
    from forecast_design.gap.heldout import (BREAKAWAY_MARGIN, NESTED_ALPHA, breakaway_proven_at_rest,
                                             breakaway_resolved_at_rest, richer_law_resolved)
    from forecast_design.gap.identifiability import terms_wald_p

    log = ind.make_independent_log("coulomb", index, seed)
    d = diagnose(log.experiment, joint=False)
    st, coul = d.fits["stiction"], d.fits["coulomb"]
    v_s, v_lo = next(g[1:3] for g in st.structure.grid if g[0] == "v_s")
    assert v_s == v_lo < d.data.options.stick_velocity
    assert st.params["F_s"] > (1 + BREAKAWAY_MARGIN) * st.params["F_c"] and terms_wald_p(d.data, st, ["dF"]) < NESTED_ALPHA
    assert not (breakaway_proven_at_rest(d.data, coul) or breakaway_resolved_at_rest(d.data, st, coul))
    assert not richer_law_resolved(d.data, st, coul)
    assert d.effect is Effect.COULOMB
    status = d.to_mapping()["verdict"]["status"]
    assert abs(status["F_c"]["value"] - log.case.effect_params["F_c"]) <= 1.96 * status["F_c"]["std"]


@pytest.mark.slow
def test_presliding_on_the_searchs_upper_end_is_no_stiction_on_an_effect_free_log():
    # an effect-free closed-loop square (2e6 counts, tau_s printed to 4 decimals): the stiction fit put its bristles on
    # the search's widest point (10 mrad) with every level's interval holding zero, coulomb unresolved, and was the
    # clear verdict. A width on the bound is not found (item 13): no evidence of presliding, no false alarm
    from forecast_design.gap.heldout import richer_law_resolved

    log = ind.make_independent_log("none", 8, 172, magnitude_scale=0.25)
    d = diagnose(log.experiment, joint=False)
    st = d.fits["stiction"]
    _, x_p, _, x_hi = next(g for g in st.structure.grid if g[0] == "x_p")
    assert x_p == x_hi
    assert not richer_law_resolved(d.data, st, d.fits["coulomb"])
    assert d.effect is Effect.NONE


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale", [
    # an effect-free closed-loop chirp (2e6 counts, a torque sensor): coulomb fitted 0.31 +- 0.53 mN m against a
    # torque accuracy of 0.30 mN m, both directions' intervals holding zero, passed the held-out test and was named
    # a weak coulomb
    (6, 25, 0.25),
    # the controller feeds the torque sensor's noise (2.7 mN m) back into the motor torque; the filtered regressors
    # saw a 0.56 +- 0.40 mN m sign(v)-like torque (accuracy 0.30 mN m) that removed 35 % of the gap above the floor
    # (held-out p = 3e-10); before, only the effect-free replicas of the log withheld it
    (5, 73, 1.0),
])
def test_a_friction_level_whose_interval_reaches_below_the_torque_accuracy_is_not_resolved(index, seed, scale):
    # a level not resolved above the motor's torque accuracy is no friction, whatever the held-out test says
    log = ind.make_independent_log("none", index, seed, magnitude_scale=scale)
    d = diagnose(log.experiment, joint=False)
    coulomb = next(r for r in d.ranking if r.effect is Effect.COULOMB)
    st = coulomb.assessment.status
    level = max(st["F_c"].value, st["F_c_neg"].value)
    assert level > d.data.torque_accuracy > max(s.value - 1.96 * s.std for s in (st["F_c"], st["F_c_neg"]))
    assert not coulomb.assessment.identified
    assert any("not resolved above the motor's torque accuracy" in r for r in coulomb.assessment.reasons)
    assert d.effect is Effect.NONE


@pytest.mark.slow
def test_a_friction_law_fitted_on_fewer_moving_rows_than_coefficients_reports_no_interval():
    # a closed-loop Coulomb square (2e6 counts, tau_s omitted) at rest on every decimated row but one: the friction
    # laws are fitted on the moving rows, and one row for four coefficients read F_c = 0.170 N m (truth 0.325)
    # "identified" +- 0.005 %, its covariance zero. Not determined is the answer: no finite interval
    from forecast_design.gap.candidates import _fit_rows

    log = ind.make_independent_log("coulomb", 4, 113)
    d = diagnose(log.experiment, joint=False)
    fit = d.fits["coulomb"]
    assert int(_fit_rows(d.data, fit.structure).sum()) < len(fit.coef)
    status = next(r for r in d.ranking if r.effect is Effect.COULOMB).assessment.status
    assert all(status[k].status == "not_identifiable" and math.isinf(status[k].std) for k in ("F_c", "F_c_neg"))
    assert d.effect is Effect.NONE


@pytest.mark.slow
def test_an_effect_withheld_by_the_torque_accuracy_is_reported_with_what_it_explains():
    # an effect-free open-loop multisine with a torque sensor: an environment mismatch passes the held-out test
    # (p = 4e-8) but removes 7 % of its equation, 0.3 mN m RMS, below the accuracy of the spring torque. The
    # verdict is none; the ranking and a caveat say what was withheld and why
    log = ind.make_independent_log("none", 2, 0)
    d = diagnose(log.experiment, joint=False)
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert d.effect is Effect.NONE
    assert env.withheld_by_accuracy and env.explained_rms < env.accuracy == d.data.environment_torque_accuracy
    assert 0.0 < env.reduction_own < d.data.options.min_reduction and not env.significant and not env.weak
    entry = next(r for r in d.to_mapping()["ranking"] if r["effect"] == "environment_mismatch")
    assert entry["below_accuracy"] and entry["explained_rms_N_m"] == pytest.approx(env.explained_rms)
    assert any(c.startswith("Below accuracy: 'environment_mismatch'") for c in d.caveats)


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(7, 71), (6, 120)])
def test_an_environment_mismatch_that_is_its_equations_gap_counts_below_the_torque_accuracy(index, seed):
    # open-loop 0.25 Hz sweeps into outputs 2.3 and 0.46 x the declared inertia: the mismatch removes 99 and 100 %
    # of the environment equation at p < 1e-35, but the torque it explains (2.2 and 0.9 mN m RMS) is below 0.1 %
    # of the RMS spring torque: named none while every effect was held to that accuracy. A sensor's error in that
    # equation is a scale (a re-calibration) or noise, which no inertia explains: what removes most of the
    # equation's gap is its gap
    log = ind.make_independent_log("environment_mismatch", index, seed)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH
    env = d.ranking[0]
    assert env.explained_rms < env.accuracy and env.reduction_own >= d.data.options.min_reduction
    status = d.to_mapping()["verdict"]["status"]["J_scale"]
    assert abs(status["value"] - log.case.effect_params["J_factor"]) <= 1.96 * status["std"]


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, scale", [(6, 133, 1.0), (3, 130, 0.25)])
def test_an_environment_mismatch_is_judged_against_the_accuracy_of_the_spring_torque_not_the_motors(index, seed,
                                                                                                   scale):
    # light soft outputs whose inertia is 0.40 and 0.88 x the declared one, tau_s from the encoders: the mismatch
    # removes 84 and 97 % of the environment equation at p < 1e-30, but explains 0.37 and 2.1 mN m RMS, below 0.1 %
    # of the RMS motor command (0.55 and 2.5 mN m): named none. That equation holds the spring torque, whose
    # accuracy is 0.1 % of its own RMS (0.29 and 1.3 mN m) and the encoders' quantisation of it
    log = ind.make_independent_log("environment_mismatch", index, seed, magnitude_scale=scale)
    assert not log.case.closed_loop and log.case.tau_s_logging == "omitted"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert d.data.environment_torque_accuracy <= env.explained_rms < d.data.torque_accuracy
    rms = float(np.sqrt(np.mean(np.square(d.data.columns["tau_s"]))))
    assert env.accuracy == max(d.data.options.min_effect_fraction * rms, d.data.spring_torque_quantisation)
    status = d.to_mapping()["verdict"]["status"]["J_scale"]
    assert abs(status["value"] - log.case.effect_params["J_factor"]) <= 1.96 * status["std"]


@pytest.mark.slow
def test_an_output_without_a_spring_scaled_alike_through_a_spring_scale_on_its_bound_is_no_environment_mismatch():
    # a true torque gain of 1.068 in closed loop, link-only output (k_e = 0: two scales): the spring scale on its
    # bound leaves J and d both 1.042 x, 63 % of the environment equation, named environment_mismatch once that
    # equation was judged against the spring torque's accuracy; the common-scale check asked for three scales and
    # a common change within the tolerance at a nominal spring scale (3 %), where the bound allows 6.2 %
    log = ind.make_independent_log("torque_gain", 6, 62)
    assert log.case.environment.k_e == 0.0 and not log.case.environment.locked
    d = diagnose(log.experiment, joint=False)
    assert d.effect is not Effect.ENVIRONMENT_MISMATCH
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert abs(env.params["J_scale"] - env.params["d_scale"]) < 0.01 and abs(env.params["J_scale"] - 1.0) > 0.03
    assert not env.identified and any(r.startswith("J, d scaled alike") for r in env.assessment.reasons)


@pytest.mark.slow
def test_a_torque_sensors_environment_equation_is_judged_against_the_motors_torque_accuracy():
    # an effect-free open-loop multisine whose sensor reads 0.924 x: the calibrated sensor scale leaves J and d
    # both at 0.955 x, 7.6 % of the environment equation and 0.37 mN m RMS, above 0.1 % of the RMS spring torque
    # (0.36 mN m). The sensor's scale is calibrated against the motor's command: its torque is known no better
    # than the motor's, 0.96 mN m here (named environment_mismatch against the spring torque's accuracy)
    log = ind.make_independent_log("none", 3, 133, magnitude_scale=0.25)
    assert log.case.tau_s_logging == "sensor"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    env = next(r for r in d.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert env.accuracy == d.data.environment_torque_accuracy == d.data.torque_accuracy > env.explained_rms


@pytest.mark.slow
@pytest.mark.parametrize("word", ["coulomb", "none"])
def test_the_recorded_angles_noise_is_read_in_encoder_steps(word):
    # the generator adds encoder noise of n = 0.2-1 counts before quantisation to 30 % of its logs: the angle then
    # departs from its low-pass by sqrt(n^2 + 1/12) steps RMS, which the factor reads (a low-pass keeps part of the
    # noise: 0.8-1 of it); quantisation alone is a factor of 1
    from forecast_design.gap.motion import angle_noise_factor
    from forecast_design.gap.residuals import prepare_gap_data

    for index in range(10):
        log = ind.make_independent_log(word, index, 80)
        factor = angle_noise_factor(prepare_gap_data(log.experiment))
        n = log.case.encoder_noise_counts
        assert 0.75 <= factor / math.sqrt(12.0 * n * n + 1.0) <= 1.05, (index, n, factor)


@pytest.mark.slow
def test_the_filters_ringing_before_a_start_is_no_motion_and_the_start_holds_the_coulomb_level():
    # a 2^21-count closed-loop square with Coulomb friction: before every torque step the zero-phase filter rang
    # (-2 ... +5 mrad/s on an encoder that did not move), read as motion both ways, and the rows of each start kept
    # the torque the motor held in its stay: ten rows left 95 % of coulomb's squared residual, LuGre's bristles took
    # them up, and the verdict was stiction
    log = ind.make_independent_log("coulomb", 2, 102)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    truth = log.case.effect_params
    status = d.to_mapping()["verdict"]["status"]
    for name in ("F_c", "F_c_neg"):
        assert abs(status[name]["value"] - truth[name]) <= 1.96 * status[name]["std"]
    # the rows of the starts now hold what the stays held (coulomb left 5 % of the gap before)
    assert d.fits["coulomb"].gap_held_out < 0.02 * d.gap_before


@pytest.mark.slow
def test_a_noisy_encoders_stays_hold_the_coulomb_level_where_its_reading_toggles():
    # a 16-bit closed-loop square, stiff environment, encoder noise of 0.9 counts: between the steps the motor rests
    # while its reading toggles over three counts, so no stay lasted more than a few samples and the rows there kept
    # the torque the friction held (coulomb removed 18 % of the gap); a torque gain of 0.58 was the clear verdict
    log = ind.make_independent_log("coulomb", 4, 80)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    # the level is 8 % high: the motor slides slowly at nearly one speed, so viscous friction and the Coulomb level are
    # nearly one column, and the encoder's noise in the speed pulled the re-calibrated d_m onto its bound 0 (truth
    # 0.30). The interval had been conditional on that bound (+-0.3 %); d_m freed, it covers the truth and says the
    # level is uncertain
    truth = log.case.effect_params["F_c"]
    assert d.params["F_c"] == pytest.approx(truth, rel=0.1)
    verdict = d.to_mapping()["verdict"]
    status = verdict["status"]["F_c"]
    assert abs(status["value"] - truth) <= 1.96 * status["std"] and status["status"] == "uncertain"
    assert verdict["std_calibration_bound"]["F_c"] > 5 * verdict["std_method"]["F_c"]
    assert any("holds its re-calibrated" in c and "d_m" in c.split("bound")[0] for c in d.caveats)
    rows = {r.effect: r for r in d.ranking}
    assert rows[Effect.COULOMB].gap_after < rows[Effect.TORQUE_GAIN].gap_after


@pytest.mark.slow
@pytest.mark.parametrize("index, seed, counts, graded", [(8, 11, 2 ** 14, "uncertain"), (1, 101, 2_000_000, "identified")])
def test_a_friction_level_is_known_no_better_than_the_spring_torque_the_encoders_read(index, seed, counts, graded):
    # the level is what the motor equation leaves after k (theta - q), which the encoders read to half a step each;
    # where the deflection stays within a count that error does not average out. A 14-bit closed-loop square with
    # k = 145 (steps of 0.056 N m) read a symmetric 0.379 N m as 0.334 +- 0.001 (identified, 71 standard deviations
    # off); a 2,000,000-count open-loop square 0.3752 +- 0.0003 for 0.3757. With the spring torque's resolution as a
    # bounded bias both intervals cover, and the coarse one says the level is uncertain
    log = ind.make_independent_log("coulomb", index, seed)
    assert log.case.encoder_counts == counts and log.case.tau_s_logging != "sensor"
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.COULOMB
    status = d.to_mapping()["verdict"]["status"]["F_c"]
    truth = log.case.effect_params["F_c"]
    assert abs(status["value"] - truth) <= 1.96 * status["std"] and status["status"] == graded
    assert status["std"] >= d.data.spring_torque_resolution / 1.96


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(6, 92), (6, 0)])
def test_a_dead_band_is_read_where_its_coefficient_is_one(index, seed):
    # backlash takes c k clip(x, +-h) off the spring torque, c free in [0, 2]; its width was read at a grid point
    # (24 % steps): 1.72 and 3.09 mrad for true 2.09 and 2.62, uncertain. Searched at thirds of a step next to the
    # best point and read where c crosses 1, the physical dead band: within 3 %, identified, the interval covering
    log = ind.make_independent_log("backlash", index, seed)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.BACKLASH
    assert d.fits["backlash"].coef[-1] == pytest.approx(1.0, abs=0.02)
    truth = log.case.effect_params["width"]
    status = d.to_mapping()["verdict"]["status"]["width_rad"]
    assert status["value"] == pytest.approx(truth, rel=0.03)
    assert abs(status["value"] - truth) <= 1.96 * status["std"] and status["status"] == "identified"


@pytest.mark.slow
@pytest.mark.parametrize("index, seed", [(5, 91), (4, 84), (7, 101)])
def test_a_delay_is_read_where_it_is_a_pure_delay(index, seed):
    # the delay candidate is c (u - u(t - d)), c free in [0, 1.5]: off c = 1 it mixes in a gain ((1 - c) u + c d u'),
    # and in closed loop the fit's minimum slid along that ridge to the same grid point, 4.64 ms at c 0.85 / 0.95 /
    # 1.05, for true delays of 4.06 / 4.44 / 4.86 ms, with intervals of +-0.1 ms (up to 5 standard deviations off).
    # Read where c = 1 (the word's physics), the delay is within a few percent and its interval covers it
    log = ind.make_independent_log("delay", index, seed)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.DELAY
    fit = d.fits["delay"]
    assert fit.coef[-1] == pytest.approx(1.0, abs=0.02)
    truth = log.case.effect_params["delay_s"]
    status = d.to_mapping()["verdict"]["status"]["delay_s"]
    assert status["value"] == pytest.approx(truth, rel=0.03)
    assert abs(status["value"] - truth) <= 1.96 * status["std"]


@pytest.mark.slow
def test_an_environment_read_through_a_spring_scale_on_its_bound_carries_the_whole_tolerance():
    # an open-loop chirp with the output damping x 0.52: the spring scale sits on its +3 % bound and the scales
    # come out 3.5 % high (J 1.035 for 1, d 0.536 for 0.518) under +-3 % intervals. The true spring scale lies
    # anywhere within the tolerance of the nominal one, so from a fit on its bound the scales are known to
    # 1.03 / 0.97 (6.2 %): the intervals cover
    log = ind.make_independent_log("environment_mismatch", 7, 110)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.ENVIRONMENT_MISMATCH
    assert d.fits["environment_mismatch"].calibration["spring_scale"] == pytest.approx(1.03, abs=1e-6)
    status = d.to_mapping()["verdict"]["status"]
    truth = {"J_scale": 1.0, "d_scale": log.case.effect_params["d_factor"]}
    for name, want in truth.items():
        assert abs(status[name]["value"] - want) > 0.03 * want      # off by more than the tolerance
        assert abs(status[name]["value"] - want) <= 1.96 * status[name]["std"], name


@pytest.mark.slow
def test_a_level_fitted_with_the_inertia_on_its_bound_carries_the_inertias_freedom():
    # a 16-bit open-loop sweep with position-dependent friction: its fit holds the re-calibrated J_m on the -3 %
    # bound and the Coulomb level came out 11 % high with +-4 % (conditional on that J_m); freed, J_m gives it the
    # interval the data leave (+-41 %), which covers the truth, and the verdict says which value sat on its bound
    log = ind.make_independent_log("position_friction", 0, 112)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.POSITION_FRICTION
    verdict = d.to_mapping()["verdict"]
    status, truth = verdict["status"]["F_c"], log.case.effect_params["F_c"]
    assert abs(status["value"] - truth) > 0.08 * truth       # the level itself is off
    assert abs(status["value"] - truth) <= 1.96 * status["std"] and status["status"] != "identified"
    assert verdict["std_calibration_bound"]["F_c"] > 3 * verdict["std_method"]["F_c"]
    assert any("holds its re-calibrated J_m on a bound" in c for c in d.caveats)


@pytest.mark.slow
def test_a_weak_stiction_where_coulomb_is_not_resolved_must_resolve_its_breakaway():
    # an effect-free 14-bit closed-loop square: the Coulomb level does not persist in half the band (the encoders'
    # quantisation), and a stiction with F_s 0.10 +- 0.14 N m and no breakaway the log resolves was the weak verdict
    # (a false alarm). As for a clear one, a stiction whose coulomb is not resolved must resolve its extra terms
    from forecast_design.gap.heldout import richer_law_resolved

    log = ind.make_independent_log("none", 1, 110, magnitude_scale=0.25)
    d = diagnose(log.experiment, joint=False)
    assert d.effect is Effect.NONE
    rows = {r.effect: r for r in d.ranking}
    assert not rows[Effect.COULOMB].weak and not rows[Effect.COULOMB].significant
    assert not richer_law_resolved(d.data, d.fits["stiction"], d.fits["coulomb"])


@pytest.mark.slow
def test_a_log_decimated_by_more_than_a_hundred_is_diagnosed():
    # a 14-bit closed-loop multisine with a torque sensor and a 4.7 ms delay, slow enough that half the equation band
    # decimates by 126: the decimation filter's smear, computed in transfer-function form, came out at -3121 samples
    # and the half-band refit of a friction level raised a traceback (the verdict itself is wrong, as before: RESULTS)
    log = ind.make_independent_log("delay", 6, 54)
    d = diagnose(log.experiment, joint=False)
    assert d.data.settings.decimation_factor * 2 > 100
    assert json.loads(json.dumps(d.to_mapping()))["verdict"]["effect"] in {e.value for e in Effect}


# --- 5e. stiction on coarse encoders, read on the motor's trajectory around its reversals -----------------------


@pytest.fixture(scope="module")
def stiction_at_16_bits():
    # a 16-bit closed-loop multisine with stiction (F_c 0.253, F_s 0.353 N m, v_s 27 mrad/s): a reversal moves the
    # angle by a few counts, the bump passes within milliseconds and the filtered acceleration's quantisation buries
    # it; the equation errors named coulomb
    log = ind.make_independent_log("stiction", 2, 153)
    return log, diagnose(log.experiment, joint=False)


@pytest.mark.slow
def test_stiction_the_equation_errors_do_not_resolve_is_named_from_the_trajectory_around_the_reversals(
        stiction_at_16_bits):
    log, d = stiction_at_16_bits
    assert log.case.encoder_counts == 65536
    assert d.effect is Effect.STICTION and d.reversals is not None and d.reversals.names_stiction
    # the bump predicts the held-out windows' angle better than Coulomb, by a margin no Coulomb log reached
    assert d.reversals.ratio < 0.4 and d.reversals.held_out_rms_counts[1] < 0.5
    verdict = d.to_mapping()["verdict"]
    true = log.case.effect_params
    for name in ("F_c", "F_s", "v_s"):
        st_ = verdict["status"][name]
        assert abs(st_["value"] - true[name]) <= 1.96 * st_["std"], name
    assert verdict["reversals"]["names_stiction"] and any(c.startswith("Stiction over coulomb, by the trajectory")
                                                         for c in d.caveats)


@pytest.mark.slow
def test_the_report_draws_the_logged_reversals_against_both_laws(stiction_at_16_bits, tmp_path):
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.reporting import write_report

    log, d = stiction_at_16_bits
    v = diagnosis_views(d).reversals
    tr = d.reversals.traces
    # the windows shown are those where the two laws' predictions differ most
    spread = np.abs(tr["coulomb_counts"] - tr["bump_counts"]).max(axis=1)
    shown = np.abs(v["coulomb_counts"] - v["bump_counts"]).max(axis=1)
    assert len(shown) == min(4, len(spread)) and shown.min() >= np.sort(spread)[-len(shown)]
    report = write_report(d, log.experiment, tmp_path)
    assert (tmp_path / "reversals.png").stat().st_size > 0 and "reversals.png" in report.read_text()


@pytest.mark.slow
def test_a_small_wide_bump_around_the_reversals_of_a_coulomb_log_is_no_stiction():
    # a 16-bit open-loop multisine with Coulomb friction (0.27 N m): around its 9 reversals a bump of 7-10 % at
    # v_s ~ 0.25 rad/s predicted the held-out windows' angle better than Coulomb (mean squares 0.31 x, p = 0.002),
    # soaking up the sliding law's misfit; a breakaway less than 20 % above the level names no stiction
    from forecast_design.gap.reversals import MIN_BREAKAWAY_RATIO

    log = ind.make_independent_log("coulomb", 6, 82)
    d = diagnose(log.experiment, joint=False)
    assert log.case.encoder_counts == 65536
    assert d.effect is Effect.COULOMB and d.reversals is not None and not d.reversals.names_stiction
    assert min(d.reversals.r_folds) < MIN_BREAKAWAY_RATIO


@pytest.mark.slow
def test_a_coulomb_level_on_a_constant_amplitude_square_reads_as_a_torque_gain_and_the_diagnosis_says_so():
    # open loop, a square of amplitude A: while the motor slides with the command, -F_c sign(v) = -(F_c / A) u, a
    # torque gain of 1 - F_c / A. Both candidates pass every test and leave gaps 1.3 and 1.6 % of the nominal one; the
    # ranking named the gain with nothing said (the truth: Coulomb), now with the rival's share beside it
    log = ind.make_independent_log("coulomb", 3, 279, controllers=True)
    assert log.case.excitation.kind == "square" and not log.case.closed_loop
    d = diagnose(log.experiment, joint=False)
    rows = {r.effect: r for r in d.ranking}
    level = 0.5 * (log.case.effect_params["F_c"] + log.case.effect_params["F_c_neg"])
    assert rows[Effect.TORQUE_GAIN].significant and rows[Effect.COULOMB].significant
    assert rows[Effect.TORQUE_GAIN].params["gain"] == pytest.approx(1.0 - level / log.case.excitation.amplitude,
                                                                    rel=0.01)
    assert d.grade == "clear" and d.effect in (Effect.COULOMB, Effect.TORQUE_GAIN)
    rival = Effect.COULOMB if d.effect is Effect.TORQUE_GAIN else Effect.TORQUE_GAIN
    assert sum(c.startswith(f"Close: '{rival}'") for c in d.caveats) == 1
    # a verdict no rival comes near says nothing of the kind: a delay on a closed-loop square
    far = diagnose(ind.make_independent_log("delay", 2, 5).experiment, joint=False)
    assert far.grade == "clear" and not any(c.startswith("Close") for c in far.caveats)


@pytest.mark.slow
def test_rows_held_at_rest_are_no_breakaway_where_the_stiction_fit_puts_its_breakaway_at_the_coulomb_level():
    # a PID loop on a locked output, a square, Coulomb friction, 2e6 counts: decimated rows at rest held more than the
    # coulomb law's level in two stays while the stiction fit put F_s (0.272 N m over its own F_c 0.231) at that level
    # (0.275): stiction was named, clear, removing 77 % of the gap against coulomb's 98 %
    from forecast_design.gap.heldout import breakaway_resolved_at_rest

    log, d, st, coul = _laws("coulomb", 2, 298)
    assert log.case.closed_loop and log.case.controller.kind == "pid"
    assert st.params["F_s"] <= max(coul.params["F_c"], coul.params["F_c_neg"])
    assert not breakaway_resolved_at_rest(d.data, st, coul)
    assert d.effect is Effect.COULOMB and d.grade == "clear"
    status = d.to_mapping()["verdict"]["status"]
    assert abs(status["F_c"]["value"] - log.case.effect_params["F_c"]) <= 1.96 * status["F_c"]["std"]


@pytest.mark.slow
def test_a_weak_effect_that_passes_its_tests_is_named_or_said_why_not():
    # a closed-loop 16-bit multisine with a torque gain of 0.943: the gain passed its held-out test and removed 20 % of
    # the gap, and the verdict was none with nothing said (a gain is told from the re-calibration only on its bound)
    log = ind.make_independent_log("torque_gain", 9, 272, controllers=True)
    d = diagnose(log.experiment, joint=False)
    gain = next(r for r in d.ranking if r.effect is Effect.TORQUE_GAIN)
    assert gain.weak and d.effect is Effect.NONE
    assert any(c.startswith("Not distinct: 'torque_gain'") for c in d.caveats)
    # a none says why of every candidate that passes its tests: here, and on an effect-free 16-bit open-loop log whose
    # cogging harmonics the log does not place (+- 250-9,000 N m)
    for exp in (log.experiment, ind.make_independent_log("none", 1, 281, controllers=True).experiment):
        d = diagnose(exp, joint=False)
        passing = [r.effect for r in d.ranking if r.weak]
        assert d.effect is Effect.NONE and passing
        assert all(any(c.startswith(f"Not distinct: '{e}'") for c in d.caveats) for e in passing)


@pytest.mark.slow
def test_a_stiction_law_that_predicts_the_held_out_data_worse_is_not_proven_by_the_units_log_ratios():
    # an open-loop sweep with Coulomb friction and a torque sensor: the stiction law's held-out units improved in most
    # units by a little (nested p = 0.019) while it predicted the held-out data worse in all (95.3 % of the gap against
    # coulomb's 97.7 %: it leaves twice coulomb's gap, more than a second effect must remove), and stiction was named
    from forecast_design.gap.heldout import NESTED_ALPHA, nested_law_test, richer_law_justified

    log, d, st, coul = _laws("coulomb", 0, 302)
    assert log.case.excitation.kind == "sweep" and not log.case.closed_loop
    assert nested_law_test(d.data, coul, st)[0] < NESTED_ALPHA
    assert st.gap_held_out * (1.0 - d.data.options.min_reduction) > coul.gap_held_out
    assert not richer_law_justified(d.data, st, coul)
    assert d.effect is Effect.COULOMB and d.grade == "clear"


@pytest.mark.slow
def test_a_stiction_no_stay_at_rest_shows_says_so():
    # a PID square with Coulomb friction (2e6 counts): LuGre bristles of 0.3 mrad read its sticking phases, stiction
    # removing 99.6 % of the gap against coulomb's 91.1 %, and stiction was named with nothing said of the breakaway no
    # stay at rest shows (the truth: Coulomb, F_s = F_c)
    from forecast_design.gap.heldout import breakaway_proven_at_rest, breakaway_resolved_at_rest

    log, d, st, coul = _laws("coulomb", 8, 321)
    assert log.case.closed_loop and log.case.excitation.kind == "square"
    assert not (breakaway_proven_at_rest(d.data, coul) or breakaway_resolved_at_rest(d.data, st, coul))
    # still a miss (the bristle reading, RESULTS): the verdict says what it rests on
    assert d.effect is Effect.STICTION
    assert sum(c.startswith("Not proven at rest: 'stiction'") for c in d.caveats) == 1
