"""The force controller seam: one contract run over every controller kind and every compensator kind.

Every kind of :mod:`forecast_design.controllers` (the paper's PD, a filtered PD on the
measurement, the issue's PI, PID, python-control lead-lag and 2 kHz difference equation, a PID
with saturation and anti-windup) must give, against independent implementations:

* a continuous loop equal to python-control's interconnection of the same blocks;
* a sampled loop whose margin tends to the continuous one as the rate grows;
* commands from the simulator equal to the Python program reference re-run on the logged
  measurements, and a host-compiled C equal to the float32 reference;
* a ``[controller]`` table that round-trips through the experiment format;
* disk margins equal to a dense-grid computation on python-control's frequency response.
"""

import dataclasses
import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from forecast_design.compensators import compensator_strategy
from forecast_design.controllers import (CONTROLLER_KINDS, CONTROLLERS, PAPER_PD, PD, PID, Controller,
                                         DiscreteController, OtherController, TFController, parse_controller,
                                         resolve_controller)
from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.loops import force_loop, sampled_force_loop
from forecast_design.margins import disk_margin
from forecast_design.params import Compensator, Design
from forecast_design.program import build_program

RATE = 2000.0
SFM = {"viscous": 0.3, "coulomb": 0.35, "sin1": 0.02, "cos2": -0.01}

#: The controllers a lab brings (the issue's four, the paper's PD and variants of the options).
CONTROLLERS_UNDER_TEST = {
    "paper-pd": PAPER_PD,
    "pd-filtered-measurement": parse_controller("pd:5:0.1:0.0008:discretization=tustin:derivative_on=measurement"),
    "pi": parse_controller("pid:8:160:0"),                                       # 8 (1 + 1/(0.05 s))
    "pid": parse_controller("pid:6:20:0.05:0.002"),                             # 6 + 20/s + 0.05 s/(0.002 s + 1)
    "pid-clamped": parse_controller("pid:6:20:0.05:0.002:anti_windup=clamping:u_min=-0.5:u_max=0.5"),
    "pid-back-calculation": parse_controller("pid:6:20:0.05:0.002:anti_windup=back-calculation:T_t=0.05:"
                                             "u_min=-0.5:u_max=0.5:derivative_on=measurement"),
    # a lead-lag given as a python-control object: 3 (0.02 s + 1)(0.1 s + 1)/((0.004 s + 1)(0.5 s + 1))
    "lead-lag": resolve_controller(3.0 * control.tf([0.02, 1.0], [0.004, 1.0]) * control.tf([0.1, 1.0], [0.5, 1.0])),
    "tf-matched-feedforward": parse_controller("tf:0.2,5/0.001,1:discretization=matched:feedforward=0.5"),
    # a 2 kHz difference equation: u_k = u_(k-1) + 205 e_k - 200 e_(k-1) + ... (a PI-like law in z)
    "discrete": resolve_controller(control.tf([5.2, -5.1], [1.0, -1.0], 1.0 / RATE)),
    # a lead-type difference equation u_k = 0.6 u_(k-1) + 70 e_k - 66 e_(k-1) (DC gain 10)
    "discrete-lead": parse_controller("discrete:70,-66/1,-0.6:rate_hz=2000"),
}
CONTINUOUS = [k for k, c in CONTROLLERS_UNDER_TEST.items() if c.is_continuous]
COMPENSATORS = {
    "none": None,
    "sfm": Compensator(kind="sfm", friction=SFM),
    "ea-fob": Compensator(kind="ea-fob", w_q_hz=10.0),
    "lo-dob": Compensator(kind="lo-dob", w_q_hz=5.0),
    "ld-dob": Compensator(kind="ld-dob", w_q_hz=2.0),
    "motor-fob": Compensator(kind="motor-fob", w_q_hz=10.0),
}
ENVIRONMENTS = ("exp-soft", "stiff", "locked")


def test_every_registered_kind_is_under_test():
    # 'other' has no equations (tests below); 'python' and 'c' are code (test_code_controllers.py)
    kinds = {c.kind for c in CONTROLLERS_UNDER_TEST.values()} | {"other", "python", "c"}
    assert kinds == set(CONTROLLER_KINDS) == set(CONTROLLERS)


# --- continuous loop against python-control's interconnection -------------------------------


def _tf(rational):
    return control.tf(list(rational.num), list(rational.den))


def _reference_loop(design, comp, controller):
    """L = C P / (1 - G_m - G_s P - G_theta P_theta) from python-control blocks (no toolbox algebra)."""
    tb, env = design.testbed, design.environment
    motor = control.tf([1.0], [tb.J_m, tb.d_m, 0.0])
    spring = control.tf([tb.k], [1.0]) if env.locked else control.feedback(
        control.tf([tb.k], [1.0]), control.tf([1.0], [env.J, env.d, env.k_e]))
    P_theta = control.feedback(motor, spring)
    P = P_theta * spring
    f = compensator_strategy(comp).linear_filters(comp or Compensator(), design)
    G_m, G_s, G_t = (_tf(g) for g in (f.from_tau_m, f.from_tau_s, f.from_theta))
    C = _tf(controller.feedback_tf())
    return C * P * control.feedback(control.tf([1.0], [1.0]), -(G_m + G_s * P + G_t * P_theta))


@pytest.mark.parametrize("env", ENVIRONMENTS)
@pytest.mark.parametrize("comp", list(COMPENSATORS))
@pytest.mark.parametrize("name", CONTINUOUS)
def test_continuous_loop_equals_python_control_interconnection(name, comp, env):
    controller, compensator = CONTROLLERS_UNDER_TEST[name], COMPENSATORS[comp]
    design = Design.nominal(env)
    loop = force_loop(design, compensator, controller=controller)
    ref = _reference_loop(design, compensator, controller)
    w = np.geomspace(0.3, 3e3, 40)
    ours = loop.L(1j * w)
    theirs = np.array([ref(1j * wi) for wi in w])
    np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=1e-12)
    # feedback without cancellation: every factor of C and F_DOB stays in chi
    assert len(loop.characteristic_polynomial) - 1 == (len(loop.C.den) - 1) + (len(loop.F_DOB.den) - 1)


# --- sampled loop tends to the continuous loop ------------------------------------------------


@pytest.mark.parametrize("comp", ["none", "ea-fob", "sfm", "motor-fob"])
@pytest.mark.parametrize("name", CONTINUOUS)
def test_sampled_margin_tends_to_continuous(name, comp):
    controller, compensator = CONTROLLERS_UNDER_TEST[name], COMPENSATORS[comp]
    design = Design.nominal("exp-soft")
    cont = force_loop(design, compensator, controller=controller)
    alpha_c = disk_margin(cont.L, closed_loop_stable=cont.stable).alpha
    errs = []
    for rate in (2e3, 2e4, 2e5):
        s = sampled_force_loop(design, compensator, controller=controller, rate_hz=rate, delay_samples=0)
        errs.append(abs(s.disk_margin().alpha - alpha_c))
    assert errs[2] < max(2e-3 * alpha_c, 1e-4) and errs[2] <= errs[0] + 1e-9


# --- disk margins against a dense grid -------------------------------------------------------


@pytest.mark.parametrize("env", ["exp-soft", "stiff"])
@pytest.mark.parametrize("name", list(CONTROLLERS_UNDER_TEST))
def test_sampled_disk_margin_equals_dense_grid(name, env):
    controller = CONTROLLERS_UNDER_TEST[name]
    loop = sampled_force_loop(Design.nominal(env), COMPENSATORS["ea-fob"], controller=controller, rate_hz=RATE)
    dm = loop.disk_margin()
    if not loop.stable:
        assert dm.alpha == 0.0
        return
    # the loop in the w-plane on its frequency axis w = (2/T) tan(omega T/2), omega up to Nyquist
    omega = np.concatenate([np.geomspace(1e-2, math.pi * RATE * 0.999999, 400_000)])
    W = 2.0 * RATE * np.tan(omega / (2.0 * RATE))
    Lw = control.tf(list(loop.L_w.num), list(loop.L_w.den))
    S = 1.0 / (1.0 + Lw(1j * W))
    alpha_grid = 1.0 / np.max(np.abs(S - 0.5))
    assert dm.alpha == pytest.approx(alpha_grid, rel=2e-4)
    assert dm.alpha <= alpha_grid * (1 + 1e-9)   # the exact peak is at least the grid's


@pytest.mark.parametrize("name", CONTINUOUS)
def test_continuous_disk_margin_equals_dense_grid(name):
    loop = force_loop(Design.nominal("exp-soft"), COMPENSATORS["ea-fob"], controller=CONTROLLERS_UNDER_TEST[name])
    dm = disk_margin(loop.L, closed_loop_stable=loop.stable)
    assert loop.stable
    w = np.geomspace(1e-3, 1e5, 400_000)
    S = 1.0 / (1.0 + _tf(loop.L)(1j * w))
    assert dm.alpha == pytest.approx(1.0 / np.max(np.abs(S - 0.5)), rel=2e-4)


# --- the law that runs: simulator = program reference = C -------------------------------------


def _simulate(controller, comp, env="exp-soft", duration_s=0.6):
    from forecast_design.effects import Coulomb
    from forecast_design.simulation import Square, simulate

    design = Design.nominal(env, controller=controller, compensator=comp)
    return simulate(design, reference=Square(high=0.3, low=-0.3, period_s=0.2), duration_s=duration_s,
                    effects=[Coulomb(F_c=0.05)], seed=3, torque_limit=5.0)


@pytest.mark.parametrize("comp", list(COMPENSATORS))
@pytest.mark.parametrize("name", list(CONTROLLERS_UNDER_TEST))
def test_simulator_runs_exactly_the_program_reference(name, comp):
    controller, compensator = CONTROLLERS_UNDER_TEST[name], COMPENSATORS[comp]
    run = _simulate(controller, compensator)
    assert run.diverged_at_s is None
    program = build_program(run.design, rate_hz=RATE, tau_max=5.0)
    step = program.make_step()
    tau_m = step.run(run.tau_r, run.tau_s, run.theta)
    np.testing.assert_array_equal(tau_m, run.tau_m)
    # and the log says exactly what ran: the [controller] table reads back the same controller
    exp = run.to_experiment()
    assert exp.design.controller == controller.__class__.from_mapping(controller.to_mapping()) or \
        isinstance(controller, DiscreteController)


@pytest.mark.parametrize("name", list(CONTROLLERS_UNDER_TEST))
def test_program_matches_scipy_lfilter_of_the_law_without_saturation(name):
    """The program's controller output is ``C_r(z) tau_r - C(z) tau_s`` (scipy's lfilter as the oracle)."""
    controller = CONTROLLERS_UNDER_TEST[name]
    if getattr(controller, "u_min", None) is not None:
        controller = dataclasses.replace(controller, u_min=None, u_max=None, anti_windup="none", T_t=None)
    law = controller.discrete_law(RATE)
    rng = np.random.default_rng(1)
    r = np.repeat(rng.normal(0, 0.3, 40), 25)
    y = 0.1 * np.sin(np.arange(r.size) / 30.0)
    design = Design.nominal("exp-soft", controller=controller)
    step = build_program(design, rate_hz=RATE).make_step()
    u = np.array([step.step(a, b, 0.0) for a, b in zip(r, y)])
    Cr, C = law.reference_tf(), law.feedback_tf()
    expected = signal.lfilter(Cr.num, Cr.den, r) - signal.lfilter(C.num, C.den, y)
    np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-9)


def test_clamping_stops_integration_and_back_calculation_bleeds_it():
    """A saturated PI: clamping holds the integrator, back-calculation decays it; without either it winds up."""
    def run(spelling):
        c = parse_controller(spelling)
        step = build_program(Design.nominal("locked", controller=c), rate_hz=RATE).make_step()
        us = [step.step(1.0, 0.0, 0.0) for _ in range(400)]     # a constant error of 1 N m for 0.2 s
        return us, step._mem[0]
    plain, x_plain = run("pid:1:50:0:u_min=-2:u_max=2")
    clamp, x_clamp = run("pid:1:50:0:u_min=-2:u_max=2:anti_windup=clamping")
    back, x_back = run("pid:1:50:0:u_min=-2:u_max=2:anti_windup=back-calculation:T_t=0.01")
    assert max(plain) == max(clamp) == max(back) == 2.0
    assert x_plain == pytest.approx(1.0 + 50.0 * 400 / RATE - 1.0, rel=1e-9)   # x = I T n e: unbounded
    # clamping integrates only while u is inside the limits: u = 1 + x reaches 2 at x = 1, then x holds
    assert 1.0 - 50.0 / RATE - 1e-12 <= x_clamp <= 1.0 + 1e-12
    # back-calculation: x settles where the increment I T e balances (T/T_t)(u_un - u), u_un = 1 + x + I T e,
    # u = 2: x = 1 + I T_t - I T (the discrete equilibrium; I T_t for the continuous law)
    assert x_back == pytest.approx(1.0 + 50.0 * 0.01 - 50.0 / RATE, rel=1e-6)


@pytest.mark.parametrize("name", list(CONTROLLERS_UNDER_TEST))
def test_host_c_equals_float32_reference(name, tmp_path):
    from forecast_design.export import toolchain
    from forecast_design.export.c import export_controller

    tools = toolchain.find_tools()
    if tools.cc is None:
        pytest.skip("no host C compiler")
    for comp in ("ea-fob", "sfm"):
        out = tmp_path / comp
        res = export_controller(out_dir=out, controller=CONTROLLERS_UNDER_TEST[name], compensator=comp,
                                sfm_params=SFM if comp == "sfm" else None, tau_max=3.0)
        exe = toolchain.build_host(out)
        rng = np.random.default_rng(7)
        n = 3000
        x = np.column_stack([np.repeat(rng.normal(0, 0.5, n // 100), 100), rng.normal(0, 0.2, n),
                             np.cumsum(rng.normal(0, 1e-3, n))]).astype(np.float32).astype(float)
        y_c = toolchain.run_host(exe, x)
        y_py = res.program.make_step(np.float32).run(*x.T)
        if comp == "sfm":   # glibc sinf/cosf against numba's float32 sin/cos: the last bit may differ
            assert np.max(np.abs(y_c - y_py)) <= 1e-5
        else:
            assert np.array_equal(y_c, y_py)


# --- the format: [controller] tables and spellings --------------------------------------------


@pytest.mark.parametrize("name", list(CONTROLLERS_UNDER_TEST))
def test_table_and_spelling_round_trip(name, tmp_path):
    from forecast_design.experiment import experiment_from_arrays, load_experiment, save_experiment

    c = CONTROLLERS_UNDER_TEST[name]
    assert parse_controller(c.spelling()) == c
    design = Design.nominal("exp-soft", controller=c)
    n = 50
    t = np.arange(n) / RATE
    exp = experiment_from_arrays(design, RATE, t, np.zeros(n), np.zeros(n), np.zeros(n), tau_r=np.zeros(n))
    save_experiment(exp, tmp_path / "run.toml")
    back = load_experiment(tmp_path / "run.toml").design.controller
    if isinstance(c, DiscreteController):   # the table leaves the rate to [sampling]
        assert back == c.at_rate(RATE)
    else:
        assert back == c
    assert resolve_controller(tmp_path / "run.toml") == back


@settings(max_examples=40, deadline=None, derandomize=True)
@given(P=st.floats(0.0, 100.0), I=st.floats(0.0, 500.0), D=st.floats(0.0, 1.0), T_f=st.floats(0.0, 0.01),
       on=st.sampled_from(["error", "measurement"]), ff=st.floats(-2.0, 2.0))
def test_pid_round_trips_for_any_gains(P, I, D, T_f, on, ff):
    disc = "backward-euler" if T_f == 0.0 else "tustin"
    c = PID(P=P, I=I, D=D, T_f=T_f, derivative_on=on, feedforward=ff, discretization=disc)
    assert parse_controller(c.spelling()) == c
    assert PID.from_mapping(c.to_mapping()) == c


def test_pd_with_only_P_and_D_means_what_it_always_meant():
    """kind = "pd" with P and D: u = P e + D (e_k - e_(k-1)) rate_hz (backward Euler, unfiltered, on the error)."""
    c = PD.from_mapping({"kind": "pd", "P": 5.0, "D": 0.1})
    assert c == PAPER_PD and c.to_mapping() == {"kind": "pd", "P": 5.0, "D": 0.1}
    e = np.array([0.0, 1.0, 1.0, 0.5])
    C = c.discrete_law(RATE).feedback_tf()
    np.testing.assert_allclose(signal.lfilter(C.num, C.den, e), 5.0 * e + 0.1 * np.diff(e, prepend=0.0) * RATE)


def test_python_control_objects_are_controllers():
    lead = control.tf([0.5, 10.0], [0.01, 1.0])
    c = resolve_controller(lead)
    assert isinstance(c, TFController)
    np.testing.assert_allclose(c.to_control().num[0][0], [0.5, 10.0])
    np.testing.assert_allclose(c.to_control().den[0][0], [0.01, 1.0])
    ss = control.ss(lead)
    w = np.array([1.0, 30.0, 300.0])
    np.testing.assert_allclose(resolve_controller(ss).feedback_tf()(1j * w), lead(1j * w), rtol=1e-9)
    d = resolve_controller(control.tf([2.0, -1.9], [1.0, -1.0], 0.0005))
    assert isinstance(d, DiscreteController) and d.rate_hz == 2000.0
    with pytest.raises(ParameterError, match="designed for 2000 Hz"):
        d.discrete_law(1000.0)


# --- bad input: one line naming the key --------------------------------------------------------


@pytest.mark.parametrize("table, match", [
    ({"kind": "tf", "num": [1.0, 2.0, 3.0], "den": [1.0, 1.0]}, "improper"),
    ({"kind": "tf", "num": [1.0], "den": [0.0, 1.0]}, r"den\[0\] = 0"),
    ({"kind": "discrete", "num": [1.0], "den": [0.0, 1.0]}, r"den\[0\] = 0"),
    ({"kind": "pd", "P": 5.0, "D": 0.1, "I": 3.0}, "key 'I' does not belong to kind 'pd'"),
    ({"kind": "tf", "num": [1.0], "den": [1.0, 1.0], "derivative_on": "error"}, "key 'derivative_on'"),
    ({"kind": "pd", "P": 5.0, "D": 0.1, "discretization": "tustin"}, "T_f"),
    ({"kind": "pid", "P": 1.0, "I": 2.0, "D": 0.0, "anti_windup": "clamping"}, "needs u_min and u_max"),
    ({"kind": "pid", "P": 1.0, "I": 2.0, "D": 0.0, "anti_windup": "back-calculation", "u_min": -1.0,
      "u_max": 1.0}, "needs T_t"),
    ({"kind": "pd", "P": 5.0}, "missing required key 'D'"),
    ({"kind": "pd", "P": -5.0, "D": 0.1}, "P must be >= 0"),
    ({"kind": "pd", "P": 5.0, "D": 0.1, "u_min": 1.0, "u_max": -1.0}, "u_min"),
    ({"kind": "lqr"}, "kind must be one of"),
    ({"kind": "other"}, "missing required key 'name'"),
])
def test_bad_controller_table_is_one_line_naming_the_file_and_key(table, match):
    from forecast_design.controllers import controller_from_mapping

    with pytest.raises(ExperimentFormatError, match=match) as info:
        controller_from_mapping(table, source="run.toml")
    assert str(info.value).startswith("run.toml: ") and "\n" not in str(info.value)


def test_discretisation_that_cannot_run_is_refused():
    # an unfiltered derivative with Tustin would put a pole at z = -1
    with pytest.raises(ParameterError, match="T_f"):
        parse_controller("pd:5:0.1:discretization=tustin")
    # prewarp at or above Nyquist
    with pytest.raises(ParameterError, match="Nyquist"):
        parse_controller("tf:1/0.01,1:discretization=tustin-prewarp:prewarp_hz=1500").discrete_law(RATE)


def test_other_controller_is_refused_by_tools_that_need_equations():
    other = OtherController(name="adaptive admittance")
    for call in (lambda: force_loop(Design.nominal("soft"), controller=other),
                 lambda: sampled_force_loop(Design.nominal("soft"), controller=other),
                 lambda: build_program(Design.nominal("soft", controller=other))):
        with pytest.raises(ParameterError, match="has no equations"):
            call()


def test_discrete_controller_has_no_continuous_loop():
    with pytest.raises(ParameterError, match="sampled loop"):
        force_loop(Design.nominal("soft"), controller=CONTROLLERS_UNDER_TEST["discrete"])


@pytest.mark.parametrize("text", ["pd:5_0:0", "pd:5", "pd:5:0.1:0:0:0", "pd:inf:0", "pd:0x10:0", "xx:1:2",
                                  "tf:1,2", "tf:1,a/1", "pd:5:0.1:bogus=1", "pd:5:0.1:T_f=1:0.2",
                                  "discrete:1/1:rate_hz=-5", "pd:nan:0.1"])
def test_bad_spelling_is_one_line(text):
    with pytest.raises(ParameterError) as info:
        parse_controller(text)
    assert "\n" not in str(info.value) and "controller" in str(info.value)


def test_controller_is_a_controller():
    assert all(issubclass(cls, Controller) for cls in CONTROLLERS.values())


# --- a new kind is one class and one registration -------------------------------------------------


def _lead_class():
    from dataclasses import dataclass
    from typing import ClassVar

    from forecast_design.controllers.base import LawChannel, LinearController, format_number
    from forecast_design.lti import RationalTF

    @dataclass(frozen=True, slots=True, kw_only=True)
    class Lead(LinearController):
        """C(s) = K (s/w_z + 1)/(s/w_p + 1), corners in Hz: a lab's own kind."""

        kind: ClassVar[str] = "lead"
        keys: ClassVar[tuple[str, ...]] = ("K", "f_z_hz", "f_p_hz", "discretization", "prewarp_hz", "feedforward",
                                           "u_min", "u_max")
        required: ClassVar[tuple[str, ...]] = ("K", "f_z_hz", "f_p_hz")
        positional: ClassVar[tuple[tuple[str, ...], tuple[str, ...]]] = (("K", "f_z_hz", "f_p_hz"), ())

        K: float
        f_z_hz: float
        f_p_hz: float

        def __post_init__(self):
            self._check_options()

        def feedback_tf(self):
            wz, wp = 2 * math.pi * self.f_z_hz, 2 * math.pi * self.f_p_hz
            return RationalTF((self.K / wz, self.K), (1.0 / wp, 1.0), name="C_F")

        def reference_tf(self):
            return self.feedback_tf() + self.feedforward

        def discrete_law(self, rate_hz):
            return self._options_law(rate_hz, [LawChannel("error", self._discretize(self.feedback_tf(), rate_hz, "C_F"),
                                                          "ctl")])

        def spelling(self):
            return f"lead:{format_number(self.K)}:{format_number(self.f_z_hz)}:{format_number(self.f_p_hz)}" + \
                self._options_spelling("tustin")

    return Lead


@pytest.fixture
def lead_kind():
    from forecast_design.controllers import register_controller

    cls = register_controller(_lead_class())
    yield cls
    del CONTROLLERS["lead"]


def test_a_new_kind_registered_once_runs_through_every_layer(lead_kind, tmp_path):
    from forecast_design.experiment import load_experiment
    from forecast_design.simulation import Step, save_simulation, simulate

    c = parse_controller("lead:4:3:30:u_max=2")
    assert isinstance(c, lead_kind) and c.u_max == 2.0
    design = Design.nominal("exp-soft", controller=c, compensator=COMPENSATORS["ea-fob"])
    ref = _reference_loop(design, design.compensator, c)
    loop = force_loop(design, design.compensator, controller=c)
    w = np.array([1.0, 20.0, 300.0])
    np.testing.assert_allclose(loop.L(1j * w), [ref(1j * x) for x in w], rtol=1e-9)
    assert sampled_force_loop(design, design.compensator, controller=c).disk_margin().stable
    run = simulate(design, reference=Step(amplitude=0.2), duration_s=0.3)
    save_simulation(run, tmp_path / "lead.toml")
    assert load_experiment(tmp_path / "lead.toml").design.controller == c     # its table reads back
    np.testing.assert_array_equal(build_program(run.design, tau_max=np.inf).make_step().run(run.tau_r, run.tau_s,
                                                                                             run.theta), run.tau_m)


# --- the friction feed-forward: any static fit, checked against the friction model's own prediction --------------


@pytest.mark.parametrize("model, params", [
    ("extended-sfm", {"viscous": 0.3, "coulomb": 0.35, "sin1": 0.02, "cos1": -0.01, "sin2": 0.005, "cos2": 0.0,
                      "sin3": 0.0, "cos3": 0.003, "sin4": 0.0, "cos4": 0.001}),
    ("asymmetric", {"viscous_pos": 0.32, "viscous_neg": 0.24, "coulomb_pos": 0.30, "coulomb_neg": 0.22}),
    ("stribeck", {"static": 0.5, "coulomb": 0.4, "stribeck_velocity": 0.05, "viscous": 0.1}),
    ("position-friction", {"viscous": 0.2, "coulomb": 0.3, "coulomb_sin1": 0.03, "coulomb_cos1": 0.0,
                           "coulomb_sin2": 0.0, "coulomb_cos2": -0.02, "coulomb_sin3": 0.0, "coulomb_cos3": 0.0,
                           "coulomb_sin4": 0.01, "coulomb_cos4": 0.0}),
])
def test_feedforward_equals_the_friction_models_prediction(model, params):
    """tau_hat(theta, v_hat) is the identified model's F(v, theta) at the filtered velocity (plain sign)."""
    from forecast_design.compensators import feedforward_eval, friction_feedforward
    from forecast_design.friction import friction_model

    ff = friction_feedforward(params, RATE)
    rng = np.random.default_rng(2)
    v = rng.normal(0.0, 0.3, 400)
    theta = rng.uniform(-10, 10, 400)
    ours = np.array([feedforward_eval(ff.coef, ff.harm, th, vi) for th, vi in zip(theta, v)])
    theirs = friction_model(model).predict(params, v, theta)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("params", [{"viscous_pos": 0.32, "viscous_neg": 0.24, "coulomb_pos": 0.30, "coulomb_neg": 0.22},
                                    {"static": 0.5, "coulomb": 0.4, "stribeck_velocity": 0.05, "viscous": 0.1}])
def test_any_static_fit_compensates_in_the_simulator_and_the_c(params, tmp_path):
    from forecast_design.export import toolchain
    from forecast_design.export.c import export_controller

    comp = Compensator(kind="sfm", friction=params)
    run = _simulate(PAPER_PD, comp)
    assert run.diverged_at_s is None and np.any(run.tau_frc_hat != 0.0)
    np.testing.assert_array_equal(build_program(run.design, tau_max=5.0).make_step().run(run.tau_r, run.tau_s,
                                                                                          run.theta), run.tau_m)
    tools = toolchain.find_tools()
    if tools.cc is None:
        pytest.skip("no host C compiler")
    res = export_controller(out_dir=tmp_path, compensator=comp)
    exe = toolchain.build_host(tmp_path)
    x = np.column_stack([run.tau_r, run.tau_s, run.theta]).astype(np.float32).astype(float)
    y_c = toolchain.run_host(exe, x)
    y_py = res.program.make_step(np.float32).run(*x.T)
    assert np.max(np.abs(y_c - y_py)) <= 1e-5     # expf in glibc and in numba may differ in the last bit


def test_the_viscous_feedforward_is_in_the_loop_analysis():
    """An SFM's viscous part v_hat viscous is a motor-angle filter: the margins see it (and Coulomb is not)."""
    design = Design.nominal("exp-soft")
    plain = force_loop(design, None)
    coulomb_only = force_loop(design, Compensator(kind="sfm", friction={"coulomb": 0.4}))
    viscous = force_loop(design, Compensator(kind="sfm", friction={"viscous": 0.3, "coulomb": 0.4}))
    w = np.geomspace(0.1, 1e3, 50)
    np.testing.assert_allclose(coulomb_only.L(1j * w), plain.L(1j * w), rtol=1e-12)
    assert np.max(np.abs(viscous.L(1j * w) - plain.L(1j * w))) > 1e-3
    # the feed-forward cancels viscous friction: the loop with d_m = 0.3 and the feed-forward of 0.3 behaves
    # below the velocity filter's cutoff like the loop of a plant with no viscous friction
    free = force_loop(dataclasses.replace(design, testbed=dataclasses.replace(design.testbed, d_m=0.0)), None)
    low = np.geomspace(0.1, 5.0, 20)
    np.testing.assert_allclose(viscous.L(1j * low), free.L(1j * low), rtol=0.05)
    a_plain = disk_margin(plain.L, closed_loop_stable=plain.stable).alpha
    a_visc = disk_margin(viscous.L, closed_loop_stable=viscous.stable).alpha
    assert a_visc != pytest.approx(a_plain, rel=1e-3)


# --- the command line: one spelling in every verb, bad input in one line with exit 2 ----------------


@pytest.mark.parametrize("argv, match", [
    (["margins", "--controller", "other:my adaptive law"], "has no equations"),
    (["margins", "--controller", "tf:1,2,3/1,1"], "improper"),
    (["margins", "--controller", "tf:1,2/0,1"], "den[0] = 0"),
    (["margins", "--controller", "pd:5:0.1:discretization=tustin", "--sampled"], "T_f"),
    (["margins", "--controller", "pd:5:0.1:I=3"], "key 'I' does not belong to kind 'pd'"),
    (["tune-q", "--observer", "ea-fob", "--controller", "pi:1:2"], "expected one of"),
    (["export", "--controller", "other:code", "--out", "{tmp}/c"], "has no equations"),
    (["export", "--controller", "discrete:1/1", "--method", "zoh", "--out", "{tmp}/c"], "has none"),
])
def test_cli_bad_controller_is_one_line_exit_2(argv, match, tmp_path, capsys):
    from forecast_design.cli import main

    code = main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err.strip()
    assert code == 2 and match in err and len(err.splitlines()) == 1 and err.startswith("forecast-design: error:")


def test_cli_controller_file_with_a_foreign_key_names_file_and_key(tmp_path, capsys):
    from forecast_design.cli import main

    f = tmp_path / "ctl.toml"
    f.write_text('[controller]\nkind = "pid"\nP = 6.0\nI = 20.0\nD = 0.05\nT_d = 0.002\n')
    assert main(["margins", "--controller", str(f)]) == 2
    err = capsys.readouterr().err
    assert "ctl.toml" in err and "key 'T_d' does not belong to kind 'pid'" in err


@pytest.mark.parametrize("spelling", ["pid:8:160:0", "pid:6:20:0.05:0.002", "tf:0.006,0.36,3/0.002,0.504,1",
                                      "discrete:5.2,-5.1/1,-1"])
def test_margins_names_what_it_analysed_and_gives_every_crossover(spelling, tmp_path, capsys):
    import json

    from forecast_design.cli import main

    code = main(["margins", "--env", "exp-soft", "--compensator", "ea-fob", "--controller", spelling,
                 "--json", str(tmp_path / "m.json"), "--plot", str(tmp_path / "m.png")])
    assert code == 0
    doc = json.loads((tmp_path / "m.json").read_text())
    c = resolve_controller(spelling)
    assert doc["assumptions"]["controller"]["table"] == c.to_mapping()
    assert doc["assumptions"]["compensator"]["w_q_hz"] == 10.0 and doc["assumptions"]["testbed"]["k"] == 58.0
    assert doc["assumptions"]["loop"]["kind"] == ("continuous" if c.is_continuous else "sampled")
    assert doc["classical"]["all_phase_margins"] and doc["disk_margin"] > 0.0
    # the classical margins are python-control's on the same loop (continuous loops)
    if c.is_continuous:
        loop = force_loop(Design.nominal("exp-soft"), COMPENSATORS["ea-fob"], controller=c)
        gm, pm, _, _, wgc, _ = control.stability_margins(_tf(loop.L), returnall=True)
        assert sorted(doc["classical"]["all_phase_margins"][i]["phase_margin_deg"]
                      for i in range(len(pm))) == pytest.approx(sorted(pm), abs=1e-6)
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
    assert c.label in capsys.readouterr().out


# --- recorded runs of any controller: the log tools go on ------------------------------------------


def test_recorded_pid_and_other_runs_are_diagnosed_and_benchmarked(tmp_path, capsys):
    """A lab's recorded PID runs (a [controller] kind = "pid" table) are grouped by their controller and
    benchmarked against the PID's own frictionless response; an 'other' controller's runs keep their
    repeatability (no equations: no expected response, no margin, said as NaN); both are diagnosed."""
    import json

    from forecast_design.cli import main
    from forecast_design.effects import Stiction
    from forecast_design.experiment import load_experiment, save_experiment
    from forecast_design.simulation import Square, save_simulation, simulate

    pid = parse_controller("pid:6:20:0.05:0.002")
    runs = tmp_path / "runs"
    for i in range(3):
        r = simulate(Design.nominal("exp-soft", controller=pid), reference=Square(high=0.6, low=-0.6, period_s=1.0),
                     duration_s=3.0, effects=[Stiction()], initial_angle=0.7 * i, seed=i)
        save_simulation(r, runs / f"pid{i}.toml")
        exp = load_experiment(runs / f"pid{i}.toml")
        save_experiment(dataclasses.replace(exp, design=dataclasses.replace(
            exp.design, controller=OtherController(name="lab adaptive law"))), runs / f"other{i}.toml")
    assert load_experiment(runs / "pid0.toml").design.controller == pid
    code = main(["benchmark", "--runs", str(runs), "--out", str(tmp_path / "bench"), "--no-plots", "--workers", "1",
                 "--json", str(tmp_path / "b.json")])
    assert code == 0
    doc = json.loads((tmp_path / "b.json").read_text())
    sets = {r["controller"]: r for r in doc["set"] if r["statistic"] == "mean"}
    assert set(sets) == {"pid:6:20:0.05:0.002", "other:lab adaptive law"}
    assert sets["pid:6:20:0.05:0.002"]["mae_N_m"] is not None and sets["pid:6:20:0.05:0.002"]["disk_margin"] > 0
    assert sets["other:lab adaptive law"]["repeatability"] is not None
    assert sets["other:lab adaptive law"]["mae_N_m"] is None          # no equations: not scored, not invented
    capsys.readouterr()
    for name in ("pid0.toml", "other0.toml"):
        assert main(["diagnose", str(runs / name), "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["verdict"]["effect"] in ("stiction", "coulomb")


# --- the four controllers through every verb, from the command line -------------------------

THE_FOUR = {
    "pi": "pid:8:160:0",                                  # 8 (1 + 1/(0.05 s))
    "pid": "pid:6:20:0.05:0.002",                         # 6 + 20/s + 0.05 s/(0.002 s + 1)
    "lead-lag": "tf:0.006,0.36,3/0.002,0.504,1",          # 3 (0.02 s + 1)(0.1 s + 1)/((0.004 s + 1)(0.5 s + 1))
    "difference-equation": "discrete:70,-66/1,-0.6",     # u_k = 0.6 u_(k-1) + 70 e_k - 66 e_(k-1), 2 kHz
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(THE_FOUR))
def test_every_verb_runs_the_controller_a_lab_brings(name, tmp_path, capsys):
    """margins -> tune-q --controller -> simulate (scenario) -> benchmark (against the paper's PD, an
    environment set, 5 repetitions) -> export -> export --firmware -> pil, and every output says which
    controller ran."""
    import json

    import tomli_w

    from forecast_design.cli import main
    from forecast_design.experiment import load_experiment
    from forecast_design.runtime.pil import qemu_available

    spelling = THE_FOUR[name]
    c = parse_controller(spelling)

    def run(*argv):
        code = main([str(a) for a in argv])
        out = capsys.readouterr()
        assert code == 0, out.err
        return out

    run("margins", "--env", "exp-soft", "--compensator", "ea-fob", "--controller", spelling, "--json", tmp_path / "m.json")
    assert json.loads((tmp_path / "m.json").read_text())["assumptions"]["controller"]["spelling"] == c.spelling()
    sampled = [] if c.is_continuous else ["--sampled"]
    code = main([str(a) for a in ("tune-q", "--observer", "lo-dob", "--env", "soft,exp-soft", "--controller", spelling,
                                  "--band", "0.5", "20", *sampled, "--json", tmp_path / "t.json")])
    capsys.readouterr()
    tuned = json.loads((tmp_path / "t.json").read_text())
    assert code == (0 if tuned["feasible"] else 1)      # no cutoff meeting the ratio is an answer that fails
    assert tuned["feasible"] == (tuned["worst_ratio"] >= 0.9 * (1 - 1e-6))
    # the cutoff's worst ratio is this controller's, recomputed by the loop analysis itself
    from forecast_design.analysis import analyse_loop

    comp = Compensator(kind="lo-dob", w_q_hz=tuned["w_q_hz"])
    ratios = [analyse_loop(env, comp, controller=c, sampled=bool(sampled)).disk.alpha /
              analyse_loop(env, None, controller=c, sampled=bool(sampled)).disk.alpha for env in ("soft", "exp-soft")]
    assert min(ratios) == pytest.approx(tuned["worst_ratio"], rel=1e-6)
    scenario = {"format": "forecast-scenario/1", "sampling": {"rate_hz": 2000.0},
                "testbed": {"J_m": 0.133, "d_m": 0.3, "k": 58.0}, "environment": "exp-soft",
                "controller": c.to_mapping(), "compensator": {"kind": "ea-fob", "w_q_hz": 10.0},
                "reference": {"kind": "step", "amplitude": 0.2}, "simulation": {"duration_s": 0.5}}
    (tmp_path / "s.toml").write_text(tomli_w.dumps(scenario))
    run("simulate", tmp_path / "s.toml", "--out", tmp_path / "sim" / "run.toml")
    assert load_experiment(tmp_path / "sim" / "run.toml").design.controller == \
        (c.at_rate(2000.0) if not c.is_continuous else c)
    run("benchmark", "--controller", "pd:5:0.1", "--controller", spelling, "--compensator", "none,ea-fob",
        "--envs", "soft,exp-soft", "--repetitions", "5", "--reference", "step:0.2", "--duration", "0.4",
        "--out", tmp_path / "bench", "--no-plots", "--workers", "1", "--json", tmp_path / "b.json")
    bench = json.loads((tmp_path / "b.json").read_text())
    assert {r["controller"] for r in bench["set"]} == {"pd:5:0.1", c.spelling()}
    run("export", "--controller", spelling, "--compensator", "ea-fob", "--out", tmp_path / "c", "--json",
        tmp_path / "e.json")
    assert json.loads((tmp_path / "e.json").read_text())["controller"] == c.to_mapping()
    run("export", "--firmware", "--controller", spelling, "--compensator", "ea-fob", "--out", tmp_path / "fw")
    assert (tmp_path / "fw" / "fd_blob.c").exists()
    if qemu_available() is None:
        run("pil", "--controller", spelling, "--compensator", "ea-fob", "--duration", "0.1",
            "--out", tmp_path / "pil" / "run.toml")
        assert load_experiment(tmp_path / "pil" / "run.toml").design.controller == \
            (c.at_rate(2000.0) if not c.is_continuous else c)


@settings(max_examples=60, deadline=None)
@given(P=st.floats(1e-3, 1e4), D=st.floats(1e-6, 10.0), T_f=st.floats(1e-6, 1e-2))
def test_the_label_rounds_for_reading_and_the_spelling_keeps_every_digit(P, D, T_f):
    """A plot title reads ``T_f=0.0007958``; the spelling (and the JSON's table) read back exactly."""
    import re

    c = PD(P=P, D=D, T_f=T_f)
    shown = dict(re.findall(r"(\w+)=([-+0-9.e]+)", c.label))
    assert set(shown) == {"P", "D", "T_f"}
    for key, number in shown.items():
        assert len(re.sub(r"e.*$|^[-+]?0*\.?0*|\.", "", number)) <= 4
        assert math.isclose(float(number), {"P": P, "D": D, "T_f": T_f}[key], rel_tol=5e-4)
    assert parse_controller(c.spelling()) == c
