"""Issue 25, gap diagnosis: the last paths to a confident wrong answer, on the independent generator.

9.  a logger-written tau_s is read as derived for every rounding a logger can use (significant
    digits, fixed decimals, float32, printed angles), so backlash stays visible; a column between a
    logger's rounding and a quiet sensor is read both ways and the reading the data support is kept;
10. a parameter the encoders cannot resolve (a bristle deflection below one count) is not
    evidence against stiction on a 14-bit log, and stiction is named over coulomb there;
11. a real but weak effect is the verdict graded ``weak``; effect-free logs stay ``none`` (coarse
    encoders, a torque sensor's zero and scale, the other SEA);
12. a verdict lowers the total held-out gap;
    (and the parsimony between friction laws: a richer law that the log resolves wins without a fixed
    share of the gap, a stiction fit with F_s = F_c is a Coulomb law; one friction level for both
    directions where the log hardly moves one way, a level per direction where friction differs; a
    breakaway the rows at rest hold; between candidates that are not nested, the one with fewer
    parameters when the other adds less on top of it than a second effect needs);
13. a torque gain inside the datasheet tolerance and a delay on its search bound never count.
"""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.effects import Effect
from forecast_design.gap import GapOptions, diagnose
from forecast_design.gap.candidates import levels_shared
from forecast_design.gap.grading import explainable_reduction, noise_floor
from forecast_design import independent as ind
from forecast_design.independent import Excitation, IndependentCase, draw_independent_case, simulate_independent
from forecast_design.controllers import PD
from forecast_design.params import Testbed, environment_preset
from forecast_design.tau_s_source import classify_tau_s, printed_quantum

MULTISINE = Excitation(kind="multisine", amplitude=0.5, f_lo_hz=0.2, f_hi_hz=8.0, lines=16, periods=2, tilt=0.5)


def _log(words, params, env="exp-soft", excitation=MULTISINE, **kw):
    kw.setdefault("rate_hz", 1000.0)
    kw.setdefault("duration_s", 10.0)
    case = IndependentCase(words=words, environment=environment_preset(env), environment_name=env,
                           excitation=excitation, effect_params=params, seed=11, tau_m_digits=8, **kw)
    return simulate_independent(case)[0]


# --- 9. tau_s written by a logger, whatever its rounding ----------------------------------------


def _printed(values, rule):
    kind, _, n = rule.partition(":")
    if kind == "digits":
        return np.array([float(format(v, f".{int(n) - 1}e")) for v in values])
    if kind == "decimals":
        return np.array([float(format(v, f".{int(n)}f")) for v in values])
    return np.asarray(values, dtype=np.float32).astype(float)      # float32 storage


@settings(max_examples=40, deadline=None)
@given(rule=st.one_of(st.integers(4, 12).map(lambda d: f"digits:{d}"), st.integers(2, 9).map(lambda d: f"decimals:{d}"),
                      st.just("float32")),
       angles=st.sampled_from(["exact", "digits:9", "decimals:7", "float32"]),
       k=st.floats(5.0, 500.0), counts=st.sampled_from([2**14, 2**16, 2_000_000]), seed=st.integers(0, 10_000))
def test_a_derived_tau_s_is_read_derived_for_every_rounding_and_a_noisy_one_measured(rule, angles, k, counts, seed):
    rng = np.random.default_rng(seed)
    step = 2 * np.pi / counts
    theta = np.round(np.cumsum(rng.normal(0, 30 * step, 3000)) / step) * step
    q = np.round(0.4 * theta / step) * step
    tau = _printed(k * (theta - q), rule)            # computed from the angles, then printed
    th_p, q_p = (_printed(x, angles) if angles != "exact" else x for x in (theta, q))
    src = classify_tau_s(False, tau, th_p, q_p)
    assert src.source == "derived" and not src.uncertain, (src.beyond_rounding, src.excess)
    # a sensor whose noise is ten times the rounding its printed digits (and the printed angles) allow
    noise = 10.0 * float(np.median(printed_quantum(tau) + k * (printed_quantum(th_p) + printed_quantum(q_p))))
    noisy = _printed(k * (theta - q) + rng.normal(0, noise, theta.size), rule)
    assert classify_tau_s(False, noisy, th_p, q_p).source == "measured"


def test_backlash_is_named_on_a_log_whose_tau_s_the_logger_printed_with_fixed_decimals():
    # before: an "excess" of 2.05-2.28 over a threshold of 2 read such a column as a torque sensor,
    # which hid the dead band (width on its search bound, k on its -3 % bound)
    exp = _log((Effect.BACKLASH,), {"width": 3e-3}, tau_s_logging="decimals:4", angle_logging="digits:9")
    diag = diagnose(exp, joint=False)
    assert diag.data.tau_s_source.source == "derived"
    assert diag.effect is Effect.BACKLASH
    assert diag.params["width_rad"] == pytest.approx(3e-3, rel=0.15)


def test_backlash_is_named_on_a_log_whose_logger_stores_tau_s_and_the_angles_as_float32():
    exp = _log((Effect.BACKLASH,), {"width": 3e-3}, tau_s_logging="float32", angle_logging="float32")
    diag = diagnose(exp, joint=False)
    assert diag.data.tau_s_source.source == "derived" and not diag.data.tau_s_source.uncertain
    assert diag.effect is Effect.BACKLASH
    assert diag.params["width_rad"] == pytest.approx(3e-3, rel=0.2)


@pytest.mark.parametrize("word,params", [(Effect.COULOMB, {"F_c": 0.2}), (Effect.DELAY, {"delay_s": 3e-3})])
def test_a_quiet_torque_sensor_is_an_uncertain_reading_and_both_readings_are_tried(word, params):
    # a noiseless torque sensor next to angles printed with 5 decimals: under 1 % of its rows leave the rounding
    # a logger's k (theta - q) would show, so the column could be either; the diagnosis runs both readings,
    # keeps the one whose verdict explains more and names the other
    exp = _log((word,), params, tau_s_logging="sensor", sensor_noise=0.0, angle_logging="decimals:5")
    src = classify_tau_s(False, exp.signals.tau_s, exp.signals.theta, exp.signals.q)
    assert src.uncertain and 0.0 < src.beyond_rounding < 0.05
    diag = diagnose(exp, joint=False)
    alternative = diag.to_mapping()["tau_s"]["alternative"]
    assert alternative is not None and diag.reading == alternative
    assert {alternative["source"], alternative["chosen"]} == {"derived", "measured"}
    assert diag.caveats[0].startswith("Caution: the tau_s column is between a logger's rounding and a quiet sensor")
    # each reading forced on its own (GapOptions.tau_s_reading): the kept one is the one that explains more
    forced = {r: diagnose(exp, options=GapOptions(tau_s_reading=r), joint=False) for r in ("derived", "measured")}
    kept, other = forced[alternative["chosen"]], forced[alternative["source"]]
    assert diag.effect is kept.effect is word and diag.reduction == pytest.approx(kept.reduction, rel=1e-12)
    assert alternative["effect"] == str(other.effect) and alternative["reduction"] == pytest.approx(other.reduction, rel=1e-12)
    assert kept.reduction >= other.reduction


# --- 10. coarse encoders and stiction -------------------------------------------------------------


SWEEP = Excitation(kind="sweep", amplitude=1.2, f_lo_hz=0.15, dither=0.05)


def test_stiction_on_a_14_bit_log_is_not_rejected_for_a_deflection_below_one_count():
    exp = _log((Effect.STICTION,), {"F_c": 0.2, "F_s": 0.36, "v_s": 0.05}, env="soft", excitation=SWEEP,
               encoder_counts=2**14, duration_s=12.0)
    diag = diagnose(exp, joint=False)
    stiction = next(r for r in diag.ranking if r.effect is Effect.STICTION)
    coulomb = next(r for r in diag.ranking if r.effect is Effect.COULOMB)
    statuses = stiction.assessment.status
    # a presliding stiffness beyond F_s / (one count) is not resolved: never "implausible", never a reason
    assert all(st_.status != "implausible" for name, st_ in statuses.items() if name in ("sigma0", "x_p"))
    assert not any("sigma0" in reason for reason in stiction.assessment.reasons)
    assert stiction.identified
    # stiction explains 70 % of the gap, coulomb 54 %: on the held-out units where the two laws differ by more
    # than the 14-bit quantisation every one is better explained by stiction (before: coulomb was named,
    # the t-test over all units, most of them quantisation, gave p = 0.02)
    assert stiction.reduction > coulomb.reduction + 0.1
    assert diag.effect is Effect.STICTION
    assert diag.params["F_s"] > diag.params["F_c"]


@pytest.mark.slow
def test_a_breakaway_held_at_rest_a_little_in_every_unit_is_stiction():
    # an open-loop square on a locked output, 16-bit encoders, a torque sensor, asymmetric stiction
    # (F_c 0.279 / 0.293, F_s 0.445 / 0.459 N m): the motor rests 43 % of the time and holds up to F_s.
    # Stiction is better in 9 of the 10 held-out units, but beyond the quantisation floor in only two;
    # the test on those two alone named coulomb (p = 0.15) for this noise draw (and one other of four; the
    # generator's case of independent seed 3, log 5, with the sensor and encoder noise drawn again)
    case = dataclasses.replace(draw_independent_case("stiction", 5, 3), seed=104)
    exp, truth = simulate_independent(case)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.STICTION
    assert diag.params["F_s"] == pytest.approx(case.effect_params["F_s"], rel=0.1)


@pytest.mark.slow
def test_a_breakaway_seen_at_rest_and_in_the_stribeck_term_is_stiction_where_units_cannot_tell():
    # an open-loop multisine that rarely stops (the other SEA, k = 145, asymmetric stiction F_c 0.153 / 0.180,
    # F_s 0.223 / 0.250 N m): stiction removes more of the gap than coulomb and its breakaway shows at rest and
    # in dF, but the few milliseconds of each breakaway are a handful of the held-out units and the nested-law
    # test over units did not separate the laws (verdict coulomb); independent seed 54, log 2
    log = ind.make_independent_log("stiction", 2, 54)
    diag = diagnose(log.experiment, joint=False)
    assert diag.effect is Effect.STICTION
    assert diag.params["F_s"] > diag.params["F_c"]
    f_s = diag.to_mapping()["verdict"]["status"]["F_s"]      # its interval holds the truth (wide: `uncertain`)
    assert abs(f_s["value"] - log.case.effect_params["F_s"]) <= 2.0 * f_s["std"]


@pytest.mark.parametrize("counts", [2**14, 2**16])
def test_coulomb_friction_on_a_coarse_encoder_stays_coulomb(counts):
    # the same sweep with Coulomb friction alone (sticking below F_c): the richer laws predict the same
    # torque within the quantisation wherever the motor moves, and the parsimony rule keeps coulomb
    exp = _log((Effect.COULOMB,), {"F_c": 0.25}, env="soft", excitation=SWEEP, encoder_counts=counts,
               duration_s=12.0)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.COULOMB, [(str(r.effect), round(r.reduction, 3)) for r in diag.ranking[:3]]


# --- 11. weak effects, and no false alarm -----------------------------------------------------------


#: The other SEA the generator draws (independent.draw.OTHER_SEA): a stiffer spring, a lighter motor.
OTHER_SEA = Testbed(J_m=0.053, d_m=0.3, k=145.0)


@pytest.mark.parametrize("env", ["exp-soft", "stiff", "locked"])
@pytest.mark.parametrize("setup", [
    {},
    {"encoder_counts": 2**14},
    {"encoder_counts": 2**16},
    # a torque sensor whose zero and scale are off by what a datasheet allows (0.02 N m, 3 %)
    {"tau_s_logging": "sensor", "sensor_noise": 0.003, "sensor_offset": 0.02, "sensor_gain": 1.03},
    {"tau_s_logging": "sensor", "sensor_noise": 0.003, "sensor_offset": -0.02, "sensor_gain": 0.97},
    {"testbed": OTHER_SEA},
    {"testbed": OTHER_SEA, "encoder_counts": 2**14},
], ids=["testbed", "14-bit", "16-bit", "sensor+", "sensor-", "other-SEA", "other-SEA-14-bit"])
def test_effect_free_logs_stay_none(env, setup):
    exp = _log((), {}, env=env, excitation=MULTISINE, nominal_errors={"J_m": 0.015, "d_m": -0.02, "k": 0.01}, **setup)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.NONE and diag.to_mapping()["verdict"]["grade"] == "none", \
        [(str(r.effect), round(r.reduction, 3), r.weak) for r in diag.ranking[:3]]


@pytest.mark.parametrize("env", ["exp-soft", "stiff", "locked"])
def test_effect_free_closed_loop_squares_stay_none(env):
    # PD force control of a square wave: the motor comes to rest between the edges, and a breakaway level as
    # large as the encoders' noise would explain every quiet row at rest (exp-soft was graded a weak stiction
    # of 4.7 mN m, 31 % of the gap above the floor): a level explains the rows at rest only down to the floor
    square = Excitation(kind="square", amplitude=0.3, period_s=2.0)
    exp = _log((), {}, env=env, excitation=square, closed_loop=True, controller=PD(P=4.0, D=0.08),
               nominal_errors={"J_m": 0.015, "d_m": -0.02, "k": 0.01})
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.NONE and diag.to_mapping()["verdict"]["grade"] == "none", \
        [(str(r.effect), round(r.reduction, 3), r.weak) for r in diag.ranking[:3]]


def test_a_small_cogging_on_a_14_bit_log_is_the_verdict_graded_weak():
    # 0.01 N m of cogging (a quarter of the smallest typical) under 14-bit encoders: it removes about a fifth
    # of the gap above the quantisation floor, passes the held-out test by orders of magnitude and is
    # identified, so the verdict names it with the grade weak, not none and not clear
    sweep = Excitation(kind="sweep", amplitude=1.5, f_lo_hz=0.1, dither=0.05)
    exp = _log((Effect.COGGING,), {"cog_a": (0.01, 0.0), "cog_b": (0.0, 0.005)}, env="link-only", excitation=sweep,
               encoder_counts=2**14, duration_s=20.0)
    diag = diagnose(exp, joint=False)
    doc = diag.to_mapping()
    top = diag.ranking[0]
    assert diag.effect is Effect.COGGING and diag.grade == "weak" and doc["verdict"]["grade"] == "weak"
    assert top.weak and not top.significant and top.identified
    assert 0.0 < top.reduction_own < diag.data.options.min_reduction
    assert any(c.startswith("Weak effect: 'cogging'") for c in diag.caveats)
    assert doc["ranking"][0]["weak"] is True and doc["ranking"][0]["counts"] is False


def test_an_eighth_size_delay_the_log_resolves_is_the_verdict():
    # a 0.25 ms delay (an eighth of the typical) in a closed-loop chirp removes 45 % of the gap (on a log with
    # 2,000,000-count encoders the floor is small): a clear verdict, named with its delay
    chirp = Excitation(kind="chirp", amplitude=0.3, f_lo_hz=0.2, f_hi_hz=8.0)
    exp = _log((Effect.DELAY,), {"delay_s": 2.5e-4}, env="stiff", excitation=chirp, closed_loop=True,
               controller=PD(P=4.0, D=0.08))
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.DELAY and diag.to_mapping()["verdict"]["grade"] == "clear"
    assert diag.ranking[0].reduction_own >= diag.data.options.min_reduction
    assert diag.params["delay_s"] == pytest.approx(2.5e-4, rel=0.5)


# --- 12./13. a verdict lowers the total gap; bounds and tolerances ------------------------------------


def test_every_counted_candidate_lowers_the_total_held_out_gap_and_a_small_gain_never_counts():
    exp = _log((Effect.TORQUE_GAIN, Effect.STICTION), {"gain": 0.99, "F_c": 0.2, "F_s": 0.33, "v_s": 0.05},
               env="link-only", excitation=Excitation(kind="sweep", amplitude=1.0, f_lo_hz=0.2, dither=0.05))
    diag = diagnose(exp, joint=False)
    for r in diag.ranking:
        if r.significant or r.weak:
            assert r.gap_after < diag.gap_before, r.effect
    gain = next(r for r in diag.ranking if r.effect is Effect.TORQUE_GAIN)
    assert not gain.identified
    assert diag.secondary is None or diag.secondary.effect is not Effect.TORQUE_GAIN
    delay = next(r for r in diag.ranking if r.effect is Effect.DELAY)
    if delay.assessment.status["delay_s"].status == "at_bound":
        assert not delay.identified and any("bound" in why for why in delay.assessment.reasons)


def test_a_gain_that_rescales_the_whole_motor_equation_of_a_locked_log_is_not_an_effect():
    # effect-free 14-bit locked square, tau_s derived by the logger: the torque gain, the spring scale and J_m
    # scaled alike multiply the whole motor equation, which only shrinks its residual; least squares took them to
    # the calibration's bound (gain 0.970, spring scale 0.970: 3 % less residual on every held-out unit, p = 2e-22)
    # and the verdict was a torque gain
    from forecast_design.independent import make_independent_log

    log = make_independent_log(Effect.NONE, 5, 25, magnitude_scale=0.125)
    diag = diagnose(log.experiment, joint=False)
    gain = {r.effect: r for r in diag.ranking}[Effect.TORQUE_GAIN]
    fit = diag.fits["torque_gain"]
    tol = diag.data.options.calibration_tolerance
    assert fit.calibration["spring_scale"] == pytest.approx(1.0 - tol)
    assert abs(fit.params["gain"] - 1.0) > tol                       # beyond the tolerance on its own
    assert abs(fit.params["gain"] / fit.calibration["spring_scale"] - 1.0) < tol
    assert not gain.identified and any("whole motor equation" in why for why in gain.assessment.reasons)
    assert diag.effect is Effect.NONE


def _drawn(word, index, seed, attempt=0, **changes):
    """A case the generator draws (its set-ups included), with some fields replaced, simulated."""
    case = dataclasses.replace(draw_independent_case(word, index, seed, attempt=attempt), **changes)
    return simulate_independent(case)[0]


def test_a_candidate_that_explains_only_its_own_quiet_equation_is_not_the_verdict():
    # a 14-bit open-loop multisine with stiction (F_c 0.20/0.15, F_s 0.30 N m): the environment equation
    # carries quantisation only, and an environment mismatch fitted to it removes 78 % of that equation's
    # gap above the floor but 0.6 % of the total (the held-out test on all equations: p = 0.006, above
    # 0.01 / 8). Before, it was the clear verdict while stiction and coulomb removed 39 % of the total.
    exp = _drawn(Effect.STICTION, 1, 7, attempt=2, encoder_counts=2**14)
    diag = diagnose(exp, joint=False)
    env = next(r for r in diag.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert env.reduction_own >= diag.data.options.min_reduction and env.reduction < 0.01
    assert not env.significant and not env.weak
    assert diag.effect is not Effect.ENVIRONMENT_MISMATCH
    assert diag.effect in (Effect.STICTION, Effect.COULOMB) and diag.reduction > 0.3


def test_a_candidate_whose_total_held_out_gap_rises_never_counts_on_a_two_effect_log():
    # Coulomb friction and a delay (16-bit encoders): an environment mismatch explains its own equation
    # (99 % of its gap above the floor) while the total held-out gap rises; it is neither the verdict nor
    # the second effect
    coulomb = draw_independent_case(Effect.COULOMB, 2, 25)
    delay = draw_independent_case(Effect.DELAY, 2, 25)
    exp = simulate_independent(dataclasses.replace(coulomb, words=(Effect.COULOMB, Effect.DELAY),
                                                   effect_params={**delay.effect_params, **coulomb.effect_params},
                                                   encoder_counts=2**16))[0]
    diag = diagnose(exp, joint=False)
    env = next(r for r in diag.ranking if r.effect is Effect.ENVIRONMENT_MISMATCH)
    assert env.reduction_own >= diag.data.options.min_reduction and env.gap_after > diag.gap_before
    assert not env.significant and not env.weak
    assert diag.effect is Effect.COULOMB
    assert diag.secondary is None or diag.secondary.effect is not Effect.ENVIRONMENT_MISMATCH


@pytest.mark.parametrize("env,excitation,loop", [
    ("exp-soft", Excitation(kind="multisine", amplitude=0.8, f_lo_hz=0.2, f_hi_hz=15.0, lines=20, periods=2, tilt=0.5),
     {}),
    ("stiff", Excitation(kind="chirp", amplitude=0.3, f_lo_hz=0.2, f_hi_hz=8.0),
     {"closed_loop": True, "controller": PD(P=4.0, D=0.08)}),
])
@pytest.mark.parametrize("delay_s", [1e-3, 2e-3])
def test_a_small_delay_under_stiction_is_never_a_confident_wrong_number(env, excitation, loop, delay_s):
    # stiction with a 1-2 ms delay (a third to a half of the typical): the verdict is the friction; the delay
    # fitted alone absorbs friction torque (in closed loop its coefficient x delay is 15 ms, read at 9.6-11.6 ms):
    # never a number to rely on -- not identified, or its interval of +-9 ms says "use the interval" (uncertain);
    # fitted with the stiction it removes 0-37 % of what is left (below the 40 % a second effect needs), so it is
    # not named, and when it is, its value is the truth's
    exp = _log((Effect.STICTION, Effect.DELAY), {"F_c": 0.2, "F_s": 0.33, "v_s": 0.05, "delay_s": delay_s}, env=env,
               excitation=excitation, **loop)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.STICTION
    alone = next(r for r in diag.ranking if r.effect is Effect.DELAY)
    delay = alone.assessment.status["delay_s"]
    assert delay.status != "identified"
    assert delay.status != "at_bound" or any("bound" in why for why in alone.assessment.reasons)
    if diag.secondary is not None and diag.secondary.effect is Effect.DELAY:
        assert diag.secondary.params["delay_s"] == pytest.approx(delay_s, rel=0.5)


def test_a_stiction_verdicts_levels_carry_the_grid_points_uncertainty():
    # a quarter-size stiction log (F_s 0.0561, F_c 0.0360 N m): fitted at the chosen point of the (v_s, x_p) grid,
    # F_s = 0.0531 +- 0.0003 was "identified" 12 standard deviations from the truth. The levels are conditional on
    # the grid point; half the largest move to a neighbouring point is one standard deviation more.
    from forecast_design.gap.identifiability import grid_neighbours
    from forecast_design.independent import make_independent_log

    log = make_independent_log(Effect.STICTION, 3, 3, magnitude_scale=0.25)
    truth = log.case.effect_params
    diag = diagnose(log.experiment, joint=False)
    assert diag.effect is Effect.STICTION
    status = diag.ranking[0].assessment.status
    moves = grid_neighbours(diag.data, diag.fits["stiction"])
    assert moves
    for name in ("F_s", "F_c"):
        st_ = status[name]
        assert st_.std >= 0.5 * max(abs(nb.params[name] - st_.value) for nb in moves)
        assert abs(st_.value - truth[name]) < 1.96 * st_.std
        assert st_.status != "identified" or abs(st_.value - truth[name]) < 2.5 * st_.std


# --- parsimony between candidates that are not nested ------------------------------------------------


def test_a_torque_gain_that_cogging_harmonics_mimic_over_part_of_a_revolution_stays_the_verdict():
    # open-loop square, gain 1.040: the motor turns a fraction of a revolution and its angle follows the command,
    # so eight cogging harmonics make a function of the angle that mimics the gain and fit the held-out data a
    # little better (0.894 of the gap against 0.890, and better by the held-out t-test), which the BIC named.
    # Fitted on top of the torque gain, cogging removes 4 % of what is left, far below what a second effect needs.
    from forecast_design.gap.candidates import fit_pair
    from forecast_design.independent import make_independent_log

    log = make_independent_log(Effect.TORQUE_GAIN, 9, 0, magnitude_scale=0.5)
    diag = diagnose(log.experiment, joint=False)
    rows = {r.effect: r for r in diag.ranking}
    assert rows[Effect.COGGING].significant and rows[Effect.COGGING].reduction > rows[Effect.TORQUE_GAIN].reduction
    gain = diag.fits["torque_gain"]
    on_top = fit_pair(diag.data, gain, Effect.COGGING)
    assert 1.0 - on_top.gap_held_out / gain.gap_held_out < diag.data.options.min_reduction
    assert diag.effect is Effect.TORQUE_GAIN
    assert any(c.startswith("Tied:") and "'cogging'" in c for c in diag.caveats)
    st = rows[Effect.TORQUE_GAIN].assessment.status["gain"]
    assert abs(st.value - log.case.effect_params["gain"]) < 1.96 * st.std


# --- parsimony between friction laws, and one level or two ------------------------------------------


def _friction_rows(diag):
    return {r.effect: r for r in diag.ranking}[Effect.STICTION], {r.effect: r for r in diag.ranking}[Effect.COULOMB]


def test_stiction_the_log_resolves_is_named_without_a_fixed_share_of_coulombs_gap():
    # a 16-bit open-loop multisine on the other SEA (F_c 0.209, F_s 0.382 N m): stiction removes 14 % of what
    # coulomb leaves above the quantisation floor (27 % since the rows of starts and stops hold the sliding level),
    # at p = 2e-7 on the units where the laws differ, with F_s - F_c at 3 standard deviations. A fixed share (half
    # of min_reduction, 20 %) named coulomb; stiction removes less than a second effect needs and is named
    exp = _drawn(Effect.STICTION, 1, 0)
    assert exp.design.testbed.k == 145.0
    diag = diagnose(exp, joint=False)
    stiction, coulomb = _friction_rows(diag)
    held = diag.data.stacked(diag.data.held_out)
    extra = explainable_reduction(diag.fits["coulomb"], diag.fits["stiction"], held, noise_floor(diag.data))
    assert 0.0 < extra < diag.data.options.min_reduction
    assert diag.effect is Effect.STICTION
    # F_s - F_c is at 3 standard deviations of the noise (the Wald test of the breakaway); with the analysis'
    # own error (the shift at half the filter's cut-off, which moves a breakaway the most) the verdict's
    # interval is wide, and holds the truth
    f_s = stiction.assessment.status["F_s"]
    true_f_s = draw_independent_case(Effect.STICTION, 1, 0).effect_params["F_s"]
    assert f_s.value > diag.params["F_c"] and abs(f_s.value - true_f_s) <= 1.96 * f_s.std
    assert diag.method_shift["F_s"] > diag.method_shift["F_c"]


def test_a_stiction_fit_without_breakaway_or_resolved_bristles_leaves_the_verdict_to_coulomb():
    # open-loop square with Coulomb friction (sticking below F_c = 0.195 N m): the stiction law fits F_s = F_c
    # (its Stribeck coefficient on the bound 0) with one-count presliding and removes 24 % of what coulomb
    # leaves; by the vocabulary (F_s > F_c) that fit is a Coulomb law
    exp = _drawn(Effect.COULOMB, 7, 0)
    diag = diagnose(exp, joint=False)
    stiction = diag.fits["stiction"]
    x_p = dict((g[0], g[1:]) for g in stiction.structure.grid).get("x_p")
    assert stiction.params["F_s"] == pytest.approx(stiction.params["F_c"], rel=1e-9)
    assert x_p is None or x_p[0] == x_p[1]
    assert diag.effect is Effect.COULOMB
    assert diag.params["F_c"] == pytest.approx(0.1949, rel=0.02)


def test_a_log_turning_almost_always_one_way_fits_one_friction_level_for_both_directions():
    # open-loop square turning the motor ~0.2 rad, almost always the same way (stiction F_c 0.238, F_s 0.320):
    # a level per direction put 39 N m on the other direction's handful of reversal rows, and both friction
    # laws were rejected as "a constant torque"; the verdict was an environment mismatch removing 0.8 %
    exp = _drawn(Effect.STICTION, 6, 0)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.STICTION and diag.reduction > 0.5
    assert levels_shared(diag.fits["stiction"]) and diag.params["F_c_neg"] == diag.params["F_c"]
    assert diag.params["F_c"] == pytest.approx(0.238, rel=0.05)
    assert any("one stiction level for both directions" in c for c in diag.caveats)


def test_friction_that_differs_by_direction_keeps_a_level_per_direction():
    exp = _log((Effect.COULOMB,), {"F_c": 0.3, "F_c_neg": 0.2}, env="soft", excitation=SWEEP, duration_s=12.0)
    diag = diagnose(exp, joint=False)
    assert diag.effect is Effect.COULOMB and not levels_shared(diag.fits["coulomb"])
    assert diag.params["F_c"] == pytest.approx(0.3, rel=0.05)
    assert diag.params["F_c_neg"] == pytest.approx(0.2, rel=0.05)


def _held_at_rest(diag):
    """|torque| the Coulomb fit says the static friction held on the rows at rest at the raw rate, and those rows."""
    from forecast_design.gap.motion import rest_distance

    data, fit = diag.data, diag.fits["coulomb"]
    m = data.t.size
    rest = data.stuck & (rest_distance(data) > 0)
    return np.abs(fit.residual[:m] + fit.prediction[:m])[rest], rest


def test_a_breakaway_held_at_rest_names_stiction_when_the_moving_rows_miss_the_stribeck_bump():
    # 16-bit open-loop multisine, F_c 0.142, F_s 0.246 N m, v_s 0.023 rad/s: a breakaway crosses the bump within
    # milliseconds, below the decimated rate, and a stiction law fitted on the moving rows alone had dF = 0 (the
    # verdict was coulomb) while the rows at rest held up to 0.23 N m. The breakaway level is now chosen on the
    # rows at rest too, and the rows at rest resolve it.
    from forecast_design.gap.heldout import breakaway_resolved_at_rest
    from forecast_design.independent import make_independent_log

    log = make_independent_log(Effect.STICTION, 6, 11)
    truth = log.case.effect_params
    diag = diagnose(log.experiment, joint=False)
    held, _ = _held_at_rest(diag)
    assert np.max(held) > 1.4 * truth["F_c"]                      # the log shows the breakaway at rest
    assert breakaway_resolved_at_rest(diag.data, diag.fits["stiction"], diag.fits["coulomb"])
    assert diag.effect is Effect.STICTION
    f_s = {r.effect: r for r in diag.ranking}[Effect.STICTION].assessment.status["F_s"]
    assert abs(f_s.value - truth["F_s"]) < 2.5 * f_s.std
    assert diag.params["F_c"] == pytest.approx(truth["F_c"], rel=0.05)


def test_a_coulomb_log_read_above_its_level_next_to_reversals_is_not_stiction():
    # open-loop sweep, Coulomb friction 0.178 / 0.160 N m: through the filters the Coulomb law's residual on rows at
    # rest next to a reversal reads up to 40 % above F_c (the low-pass and decimation filters ring 15 % of the jump);
    # a breakaway level chosen on those rows put F_s at 0.219 N m and named stiction. With the filters' lift allowed
    # for, the breakaway stays at the Coulomb level and the verdict coulomb.
    from forecast_design.gap.heldout import breakaway_resolved_at_rest
    from forecast_design.independent import make_independent_log

    log = make_independent_log(Effect.COULOMB, 3, 3)
    diag = diagnose(log.experiment, joint=False)
    stiction = diag.fits["stiction"].params
    assert stiction["F_s"] <= 1.05 * max(stiction["F_c"], stiction["F_c_neg"])
    assert not breakaway_resolved_at_rest(diag.data, diag.fits["stiction"], diag.fits["coulomb"])
    assert diag.effect is Effect.COULOMB
    assert diag.params["F_c"] == pytest.approx(log.case.effect_params["F_c"], rel=0.02)
