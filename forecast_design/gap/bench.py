"""Withheld-effect benchmark of the gap diagnosis on the virtual testbed.

Each case draws, from its own seed, one effect word (or none) with a random
magnitude, an environment preset, an excitation (open-loop multisine, chirp or
sweep torque; closed-loop PD tracking of a square, sine, multisine or sweep
force reference; a sweep is a slow 0.05-0.1 Hz swing plus a small multisine), a random absolute motor angle and nominal-parameter errors: the
experiment's ``J_m``, ``d_m`` and ``k`` are off by up to ``param_error`` from
the simulated truth. The simulator records 2,000,000-count encoders and a small
process torque noise. Only the experiment reaches :func:`diagnose`; the truth
stays in the case record.

Magnitudes are drawn where the effect is physically distinguishable from the
tolerated parameter errors (e.g. a torque gain beyond +-15 %: a smaller one is a
common rescaling of ``J_m``, ``d_m`` and ``k``).

Scoring rule (the main score). Every log of the main suite is *identifiable*:
the generator redraws the scenario (environment, excitation, magnitude; next
``attempt`` of the same seed, at most ``MAX_ATTEMPTS``) until the *truth* shows
that the log can tell the effect apart, by these criteria:

* ``cogging``, ``position_friction``: the true motor angle covers >= one
  revolution (2 pi rad) and the motor reverses direction >= 2 times; only
  environments whose series stiffness lets ~1 N m turn the motor a revolution
  (``k_series 2 pi <= 3 N m``: ``soft``, ``link-only``) with a sweep
  excitation are drawn;
* ``coulomb``, ``stiction``: >= 2 direction reversals;
* ``delay``, ``torque_gain``: the command is not a single sine (< 95 % of its
  variance in one spectral line), since at one frequency a delay is extra
  damping and a gain error a rescaling of ``J_m``, ``d_m`` and ``k``;
* ``backlash``: the true spring deflection exceeds the dead band (99th
  percentile of ``|theta - q|`` > width);
* ``environment_mismatch``: the output is not locked.

A verdict is correct when it names the withheld effect (``none`` for the
effect-free logs). The optional *hard* suite (``hard=N``) runs logs that are
deliberately *not* identifiable (angle effects in ``stiff``/``locked``
environments, a delay or torque gain under a closed-loop single sine); there a verdict is
scored *honest* when it names the effect, or when the diagnosis's caveats name
the withheld effect as not excluded. The *pairs* suite (``pairs=N``) withholds
two effects at once and compares the forward-selection secondary effect of
:func:`diagnose` with the joint group-lasso attribution.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .. import effects as fx
from ..effects import Effect
from ..errors import ParameterError
from ..executor import available_workers, make_executor
from ..controllers import PAPER_PD
from ..params import Design, environment_preset
from ..limits import check_limit

__all__ = ["BenchCase", "BenchResult", "benchmark", "draw_case", "run_case", "make_log", "make_logs", "simulate_cases",
           "identifiability", "BENCH_WORDS", "PAIRS", "MAX_ATTEMPTS", "available_workers"]

#: Effect words of the benchmark: every vocabulary word, ``none`` included.
BENCH_WORDS: tuple[Effect, ...] = tuple(Effect)
ENVIRONMENTS = ("soft", "stiff", "link-only", "locked", "exp-soft")
EXCITATIONS = ("ol-multisine", "ol-chirp", "ol-sweep", "cl-square", "cl-sine", "cl-multisine", "cl-sweep")
#: Two-effect combinations of the pairs suite.
PAIRS: tuple[tuple[Effect, Effect], ...] = (
    (Effect.COULOMB, Effect.COGGING), (Effect.DELAY, Effect.TORQUE_GAIN), (Effect.COULOMB, Effect.DELAY),
    (Effect.BACKLASH, Effect.TORQUE_GAIN), (Effect.COGGING, Effect.ENVIRONMENT_MISMATCH),
)
#: Hard (non-identifiable) scenarios: effect, environments, excitations.
HARD: tuple[tuple[Effect, tuple[str, ...], tuple[str, ...]], ...] = (
    (Effect.POSITION_FRICTION, ("stiff", "locked"), EXCITATIONS),
    (Effect.COGGING, ("stiff", "locked"), EXCITATIONS),
    (Effect.DELAY, ENVIRONMENTS, ("cl-sine",)),
    (Effect.TORQUE_GAIN, ENVIRONMENTS, ("cl-sine",)),
)
#: Redraws allowed to find an identifiable scenario.
MAX_ATTEMPTS = 12
ANGLE_EFFECTS = (Effect.COGGING, Effect.POSITION_FRICTION)


@dataclass(frozen=True, slots=True, kw_only=True)
class CaseSpec:
    """Everything needed to simulate one benchmark log (the truth)."""

    words: tuple[Effect, ...]
    index: int
    seed: int
    environment: str
    excitation: str
    effects: tuple
    errors: tuple[float, float, float]
    initial_angle: float
    duration_s: float
    attempt: int = 0
    suite: str = "main"

    @property
    def word(self) -> Effect:
        """The (first) withheld effect; ``none`` for effect-free logs."""
        return self.words[0] if self.words else Effect.NONE


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchCase:
    """Outcome of one benchmark log.

    Parameters
    ----------
    truth : Effect
        The withheld effect (the first one for the pairs suite).
    verdict : Effect
        The diagnosis's verdict.
    joint : tuple of Effect or None
        Effects named by the joint (group-lasso) attribution; None where it was not run (the independent
        generator's logs, diagnosed without it).
    reduction : float
        Held-out reduction of the verdict [-].
    true_reduction : float
        Held-out reduction of the *true* effect's candidate (NaN for none) [-].
    environment, excitation : str
        Scenario.
    effect_params : dict
        The simulated effect's parameters.
    seconds : float
        Wall time of the diagnosis alone [s].
    suite : str
        ``main``, ``hard`` or ``pairs``.
    truths : tuple of Effect
        All withheld effects (two for the pairs suite).
    secondary : Effect
        The diagnosis's secondary effect (``none`` when it names none).
    caveats : tuple of str
        The diagnosis's caveats.
    attempts : int
        Scenario draws needed to find an identifiable log (main suite) [-].
    design : dict
        The log's nominal model as its file declares it (:meth:`Design.to_mapping`: testbed, environment, and in
        closed loop the controller and compensator), with its ``rate_hz`` and ``duration_s``.
    """

    truth: Effect
    verdict: Effect
    joint: tuple[Effect, ...] | None
    reduction: float
    true_reduction: float
    environment: str
    excitation: str
    effect_params: dict
    seconds: float
    suite: str = "main"
    truths: tuple[Effect, ...] = ()
    secondary: Effect = Effect.NONE
    caveats: tuple[str, ...] = ()
    attempts: int = 1
    design: dict = field(default_factory=dict)

    @property
    def correct(self) -> bool:
        """Main suite: the verdict names the withheld effect. Hard suite: honest (see module doc)."""
        if self.suite == "hard":
            return self.verdict == self.truth or any(str(self.truth) in c for c in self.caveats)
        return self.verdict == self.truth

    @property
    def named(self) -> frozenset:
        """Effects named by verdict + secondary (pairs suite)."""
        return frozenset(e for e in (self.verdict, self.secondary) if e is not Effect.NONE)

    @property
    def joint_correct(self) -> bool | None:
        """True when the joint attribution names exactly the withheld effect (nothing for none); None if not run."""
        if self.joint is None:
            return None
        if self.truth is Effect.NONE:
            return len(self.joint) == 0
        if self.suite == "pairs":
            return frozenset(self.joint) == frozenset(self.truths)
        return len(self.joint) >= 1 and self.joint[0] == self.truth

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"suite": self.suite, "truth": str(self.truth), "truths": [str(e) for e in self.truths],
                "verdict": str(self.verdict), "secondary": str(self.secondary),
                "joint": None if self.joint is None else [str(e) for e in self.joint], "reduction": self.reduction,
                "true_reduction": None if math.isnan(self.true_reduction) else self.true_reduction,
                "environment": self.environment, "excitation": self.excitation, "attempts": self.attempts,
                "effect_params": self.effect_params, "caveats": list(self.caveats), "seconds": self.seconds,
                "design": self.design}


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchResult:
    """Confusion matrix and accuracy of the withheld-effect benchmark.

    Parameters
    ----------
    cases : tuple of BenchCase
        Every log's outcome (all suites).
    per_effect : int
        Logs per effect word in the main suite [-].
    seed : int
        Master seed.
    elapsed_s : float
        Wall time of the whole benchmark [s].
    workers : int
        Worker processes used [-].
    generator : str
        ``testbed`` or ``independent``.
    magnitude_scale : float
        Fraction of the typical effect magnitudes (independent generator) [-].
    """

    cases: tuple[BenchCase, ...]
    per_effect: int
    seed: int
    elapsed_s: float
    workers: int = 1
    generator: str = "testbed"
    magnitude_scale: float = 1.0

    def suite(self, name: str) -> tuple[BenchCase, ...]:
        """The cases of one suite (``main``, ``hard``, ``pairs``)."""
        return tuple(c for c in self.cases if c.suite == name)

    @property
    def main(self) -> tuple[BenchCase, ...]:
        """The main (identifiable, one-effect) suite."""
        return self.suite("main")

    @property
    def accuracy(self) -> float:
        """Share of main-suite verdicts naming the withheld effect [-]."""
        m = self.main
        return sum(c.correct for c in m) / max(1, len(m))

    @property
    def joint_accuracy(self) -> float | None:
        """Share of main-suite joint attributions naming exactly the withheld effect first, over the logs where the
        attribution ran (None where it ran on none: the independent generator) [-]."""
        ran = [c.joint_correct for c in self.main if c.joint is not None]
        return sum(ran) / len(ran) if ran else None

    @property
    def false_alarms(self) -> int:
        """Effect-free logs blamed on an effect [-]."""
        return sum(1 for c in self.main if c.truth is Effect.NONE and c.verdict is not Effect.NONE)

    @property
    def min_true_reduction(self) -> float:
        """Smallest held-out reduction of the true effect's candidate over main-suite effect logs [-]."""
        vals = [c.true_reduction for c in self.main
                if c.truth is not Effect.NONE and not math.isnan(c.true_reduction)]
        return min(vals) if vals else float("nan")

    @property
    def hard_honesty(self) -> float:
        """Share of hard-suite logs answered correctly or with the withheld effect named in a caveat [-]."""
        h = self.suite("hard")
        return sum(c.correct for c in h) / len(h) if h else float("nan")

    def pairs_scores(self) -> dict[str, float | None]:
        """Pairs suite: exact two-effect recovery by forward selection and by the group lasso (None: not run) [-]."""
        p = self.suite("pairs")
        if not p:
            return {}
        n = len(p)
        ran = [c for c in p if c.joint is not None]
        return {"n_logs": n,
                "forward_exact": sum(c.named == frozenset(c.truths) for c in p) / n,
                "forward_verdict_in_truth": sum(c.verdict in c.truths for c in p) / n,
                "joint_exact": sum(frozenset(c.joint) == frozenset(c.truths) for c in ran) / len(ran) if ran else None,
                "joint_first_in_truth":
                    sum(bool(c.joint) and c.joint[0] in c.truths for c in ran) / len(ran) if ran else None}

    def confusion(self) -> dict[str, dict[str, int]]:
        """``confusion[truth][verdict]`` counts over the vocabulary (main suite)."""
        words = [str(e) for e in BENCH_WORDS]
        out = {t: {v: 0 for v in words} for t in words}
        for c in self.main:
            out[str(c.truth)][str(c.verdict)] += 1
        return out

    def format_confusion(self) -> str:
        """Confusion matrix as a fixed-width text table (rows: truth, columns: verdict)."""
        words = [str(e) for e in BENCH_WORDS]
        short = {w: w[:6] for w in words}
        conf = self.confusion()
        lines = ["truth \\ verdict".ljust(22) + " ".join(short[w].rjust(6) for w in words)]
        for t in words:
            lines.append(t.ljust(22) + " ".join(str(conf[t][v]).rjust(6) for v in words))
        return "\n".join(lines)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready summary with the confusion matrix and every case."""
        secs = [c.seconds for c in self.cases]
        return {"definitions": {name: " ".join(getattr(type(self), name).__doc__.split())
                                for name in ("accuracy", "joint_accuracy", "false_alarms", "min_true_reduction",
                                             "hard_honesty")},
                "generator": self.generator, "magnitude_scale": self.magnitude_scale,
                "per_effect": self.per_effect, "seed": self.seed, "n_logs": len(self.main),
                "accuracy": self.accuracy, "joint_accuracy": self.joint_accuracy,
                "false_alarms": self.false_alarms, "min_true_reduction": self.min_true_reduction,
                "confusion": self.confusion(), "elapsed_s": self.elapsed_s, "workers": self.workers,
                "hard_honesty": None if math.isnan(self.hard_honesty) else self.hard_honesty,
                "n_hard": len(self.suite("hard")), "pairs": self.pairs_scores(),
                "diagnosis_seconds": {"mean": float(np.mean(secs)) if secs else None,
                                      "max": float(np.max(secs)) if secs else None},
                "cases": [c.to_mapping() for c in self.cases]}


def _draw_effect(word: Effect, rng: np.random.Generator, environment: str) -> tuple:
    u = rng.uniform
    if word is Effect.NONE:
        return ()
    if word is Effect.COULOMB:
        return (fx.Coulomb(F_c=u(0.1, 0.5)),)
    if word is Effect.STICTION:
        F_c = u(0.1, 0.4)
        return (fx.Stiction(F_c=F_c, F_s=F_c * u(1.3, 1.8), v_s=u(0.005, 0.05), sigma0=u(150.0, 500.0),
                            sigma1=u(0.2, 1.0), sigma2=u(0.0, 0.1)),)
    if word is Effect.POSITION_FRICTION:
        F_c = u(0.2, 0.5)
        n = int(rng.integers(1, 3))
        amp = rng.uniform(-1, 1, (2, n))
        amp *= u(0.4, 0.9) * F_c / np.abs(amp).sum()
        return (fx.PositionFriction(F_c=F_c, a=tuple(amp[0]), b=tuple(amp[1])),)
    if word is Effect.COGGING:
        n = int(rng.integers(1, 4))
        amp = rng.uniform(-1, 1, (2, n))
        amp *= u(0.1, 0.3) / np.sqrt((amp ** 2).sum())
        return (fx.Cogging(a=tuple(amp[0]), b=tuple(amp[1])),)
    if word is Effect.BACKLASH:
        return (fx.Backlash(width_rad=u(3e-3, 1e-2)),)
    if word is Effect.DELAY:
        return (fx.Delay(delay_s=u(1e-3, 6e-3)),)
    if word is Effect.TORQUE_GAIN:
        return (fx.TorqueGain(gain=u(0.7, 0.85) if rng.random() < 0.5 else u(1.18, 1.35)),)
    if word is Effect.ENVIRONMENT_MISMATCH:
        env = environment_preset(environment)
        scales = {"J_scale": 1.0, "d_scale": 1.0, "k_e_scale": 1.0}
        options = ["J_scale", "d_scale"] + (["k_e_scale"] if env.k_e > 0 else [])
        for name in rng.choice(options, size=int(rng.integers(1, len(options) + 1)), replace=False):
            scales[str(name)] = u(1.4, 2.0) if rng.random() < 0.5 else u(0.4, 0.7)
        return (fx.EnvironmentMismatch(**scales),)
    raise ParameterError(f"no benchmark generator for effect '{word}'", name="word", value=str(word))


def _k_series(environment: str) -> float:
    """Static stiffness seen by the motor [N m/rad]: k in series with k_e (k when locked)."""
    env = environment_preset(environment)
    k = Design.nominal(environment).testbed.k
    if env.locked:
        return k
    return k * env.k_e / (k + env.k_e)


def _environments(words: Sequence[Effect]) -> list[str]:
    envs = list(ENVIRONMENTS)
    if Effect.ENVIRONMENT_MISMATCH in words:
        envs = [e for e in envs if not environment_preset(e).locked]
    if any(w in ANGLE_EFFECTS for w in words):
        # ~1 N m of torque must be able to turn the motor through a revolution
        envs = [e for e in envs if _k_series(e) * 2.0 * np.pi <= 3.0]
    return envs


def draw_case(word: Effect | Sequence[Effect], index: int, seed: int, *, duration_s: float = 10.0,
              param_error: float = 0.03, attempt: int = 0, suite: str = "main") -> CaseSpec:
    """Draw one benchmark scenario (deterministic in its arguments).

    Parameters
    ----------
    word : Effect or sequence of Effect
        The effect(s) to withhold (``Effect.NONE``: effect-free; two for the pairs suite).
    index : int
        Case number within the word [-].
    seed : int
        Master seed [-].
    duration_s : float
        Log length [s].
    param_error : float
        Largest relative error of the nominal ``J_m``, ``d_m``, ``k`` [-].
    attempt : int
        Redraw number (the generator redraws until the log is identifiable) [-].
    suite : str
        ``main``, ``hard`` or ``pairs``.

    Returns
    -------
    CaseSpec
        The scenario, truth included.
    """
    words = tuple(Effect(w) for w in ((word,) if isinstance(word, (str, Effect)) else word))
    words = tuple(w for w in words if w is not Effect.NONE)
    ids = [list(Effect).index(w) for w in words] or [0]
    key = [seed, *ids, index, attempt, ("main", "hard", "pairs").index(suite)]
    rng = np.random.default_rng(key)
    if suite == "hard":
        _, envs, excs = next(h for h in HARD if h[0] == words[0])
        envs, excs = list(envs), list(excs)
    else:
        envs, excs = _environments(words), list(EXCITATIONS)
        if any(w in ANGLE_EFFECTS for w in words):
            # only a slow swing turns the motor through revolutions within a 10 s log
            excs = [e for e in excs if e.endswith("sweep")]
    environment = str(envs[(index + attempt + int(rng.integers(len(envs)))) % len(envs)])
    excitation = str(excs[(index + attempt + int(rng.integers(len(excs)))) % len(excs)])
    effects = tuple(e for w in words for e in _draw_effect(w, rng, environment))
    errors = tuple(float(x) for x in rng.uniform(-param_error, param_error, 3))
    return CaseSpec(words=words, index=index, seed=int(rng.integers(2 ** 31)), environment=environment,
                    excitation=excitation, effects=effects, errors=errors,
                    initial_angle=float(rng.uniform(0, 2 * np.pi)), duration_s=duration_s, attempt=attempt,
                    suite=suite)


def _reference(spec: CaseSpec, rng: np.random.Generator):
    from ..simulation import references as refs

    kind = spec.excitation
    if kind == "ol-multisine":
        f = np.geomspace(0.2, 15.0, 12)
        a = rng.uniform(0.5, 1.0) * 2.0 / np.sqrt(f.size) * np.ones(f.size)
        return refs.Multisine(amplitudes=tuple(a), frequencies_hz=tuple(f),
                              phases_rad=tuple(rng.uniform(0, 2 * np.pi, f.size))), False
    if kind == "ol-chirp":
        return refs.Chirp(amplitude=rng.uniform(1.0, 2.0), f0_hz=0.2, f1_hz=15.0, duration_s=spec.duration_s), False
    if kind == "cl-square":
        amp = rng.uniform(0.5, 1.5)
        return refs.Square(high=amp, low=-amp, period_s=rng.uniform(0.5, 2.0)), True
    if kind == "cl-sine":
        return refs.Sine(amplitude=rng.uniform(0.5, 1.5), frequency_hz=rng.uniform(0.3, 3.0)), True
    if kind in ("ol-sweep", "cl-sweep"):
        # a slow, large swing (turns a compliant output through revolutions) plus a small multisine
        f = np.array([rng.uniform(0.05, 0.1), 1.1, 2.9, 6.7])
        a = np.concatenate([[rng.uniform(1.5, 2.5) if kind == "ol-sweep" else rng.uniform(1.0, 2.0)],
                            rng.uniform(0.1, 0.3, 3)])
        return refs.Multisine(amplitudes=tuple(a), frequencies_hz=tuple(f),
                              phases_rad=tuple(rng.uniform(0, 2 * np.pi, f.size))), kind == "cl-sweep"
    f = np.array([0.3, 1.1, 2.9, 6.7])
    return refs.Multisine(amplitudes=tuple(rng.uniform(0.2, 0.5, f.size)), frequencies_hz=tuple(f),
                          phases_rad=tuple(rng.uniform(0, 2 * np.pi, f.size))), True


def simulate_case(spec: CaseSpec):
    """Simulate one case: the experiment as recorded (nominal design with errors) and the truth.

    Parameters
    ----------
    spec : CaseSpec
        The scenario.

    Returns
    -------
    (Experiment, SimulationResult)
        The blind log and the full simulation result.
    """
    from ..simulation import simulate

    ref, closed, true_design = _setup(spec)
    result = simulate(true_design, reference=ref, duration_s=spec.duration_s, effects=spec.effects,
                      seed=spec.seed, closed_loop=closed, initial_angle=spec.initial_angle)
    return _recorded(spec, result), result


def _setup(spec: CaseSpec):
    """The case's reference, loop (closed or open) and true design."""
    ref, closed = _reference(spec, np.random.default_rng(spec.seed))
    return ref, closed, Design.nominal(spec.environment, controller=PAPER_PD if closed else None)


def simulate_cases(specs: Sequence[CaseSpec]) -> list:
    """:func:`simulate_case` of many cases through :func:`~forecast_design.simulation.batch.simulate_batch`.

    One batch per loop type and duration; each result equals :func:`simulate_case`'s bit for bit
    (the batch's runs equal ``simulate``'s). Returns ``[(Experiment, SimulationResult), ...]`` in order.
    """
    from ..simulation.batch import BatchRun, simulate_batch

    groups: dict[tuple, list] = {}
    for i, spec in enumerate(specs):
        ref, closed, true_design = _setup(spec)
        groups.setdefault((closed, spec.duration_s), []).append(
            (i, BatchRun(design=true_design, effects=spec.effects, seed=spec.seed, initial_angle=spec.initial_angle,
                         reference=ref)))
    out: list = [None] * len(specs)
    for (closed, duration_s), members in groups.items():
        batch = simulate_batch([run for _, run in members], duration_s=duration_s, closed_loop=closed)
        for k, (i, _) in enumerate(members):
            result = batch.result(k)
            out[i] = (_recorded(specs[i], result), result)
    return out


def _recorded(spec: CaseSpec, result: Any):
    """The blind log of a simulated case: the experiment with the (slightly wrong) nominal model."""
    tb = result.design.testbed
    e = spec.errors
    nominal_tb = dataclasses.replace(tb, J_m=tb.J_m * (1 + e[0]), d_m=tb.d_m * (1 + e[1]), k=tb.k * (1 + e[2]))
    exp = result.to_experiment()
    # the log's TOML holds the (slightly wrong) nominal model; tau_s is what the logger derives from it
    nominal = dataclasses.replace(exp.design, testbed=nominal_tb)
    return dataclasses.replace(exp, design=nominal).replace_signals(tau_s=None)


def identifiability(spec: CaseSpec, result: Any) -> str | None:
    """Why a simulated log cannot tell its withheld effect(s) apart, from the truth; ``None`` if it can.

    Parameters
    ----------
    spec : CaseSpec
        The scenario.
    result : SimulationResult
        The simulation (truth and measured command).

    Returns
    -------
    str or None
        The failed criterion in words (see the module docstring), or ``None``.
    """
    from .locate import tone_fraction

    tr = result.truth
    omega = np.asarray(tr.omega)
    moving = omega[np.abs(omega) > 1e-2]
    reversals = int(np.count_nonzero(np.diff(np.sign(moving)) != 0))
    span = float(np.ptp(tr.theta))
    for w in spec.words:
        if w in ANGLE_EFFECTS and span < 2.0 * np.pi:
            return f"motor angle spans {span:.2f} rad < 2 pi"
        if w in (Effect.COULOMB, Effect.STICTION, Effect.POSITION_FRICTION) and reversals < 2:
            return f"{reversals} direction reversals < 2"
        if w in (Effect.DELAY, Effect.TORQUE_GAIN):
            frac, f_hz = tone_fraction(np.asarray(result.tau_m), result.rate_hz)
            if frac >= 0.95:
                return f"single-tone command ({100 * frac:.0f} % at {f_hz:.2g} Hz)"
        if w is Effect.BACKLASH:
            width = next(e.width_rad for e in spec.effects if e.effect is Effect.BACKLASH)
            if np.percentile(np.abs(np.asarray(tr.theta) - np.asarray(tr.q)), 99) <= width:
                return "spring deflection inside the dead band"
    return None


def make_log(word: Effect | Sequence[Effect], index: int, seed: int, *, duration_s: float = 10.0,
             suite: str = "main"):
    """Draw and simulate the case, redrawing until identifiable (main and pairs suites).

    Parameters
    ----------
    word : Effect or sequence of Effect
        Withheld effect(s).
    index, seed : int
        Case number and master seed [-].
    duration_s : float
        Log length [s].
    suite : str
        ``main``, ``hard`` (no redraw) or ``pairs``.

    Returns
    -------
    (CaseSpec, Experiment, SimulationResult)
        The accepted scenario, the blind log and the simulation.

    Raises
    ------
    ParameterError
        If no identifiable scenario is found in ``MAX_ATTEMPTS`` draws.
    """
    return make_logs([(word, index, seed, duration_s, suite)])[0]


def make_logs(requests: Sequence[tuple]) -> list:
    """:func:`make_log` of many cases, each redraw round one batch of simulations (:func:`simulate_cases`).

    ``requests``: ``(word, index, seed, duration_s, suite)`` per case. Returns ``(CaseSpec,
    Experiment, SimulationResult)`` per request, equal to :func:`make_log`'s; raises as it does for
    the first request without an identifiable scenario.
    """
    done: list = [None] * len(requests)
    last = [""] * len(requests)
    pending = list(range(len(requests)))
    for attempt in range(MAX_ATTEMPTS):
        if not pending:
            break
        specs = [draw_case(requests[i][0], requests[i][1], requests[i][2], duration_s=requests[i][3],
                           attempt=attempt, suite=requests[i][4]) for i in pending]
        still = []
        for i, spec, (exp, result) in zip(pending, specs, simulate_cases(specs)):
            why = None if spec.suite == "hard" else identifiability(spec, result)
            if why is None:
                done[i] = (spec, exp, result)
            else:
                last[i] = why
                still.append(i)
        pending = still
    if pending:
        word, index = requests[pending[0]][0], requests[pending[0]][1]
        # the effect words as the vocabulary spells them (a tuple of Effect printed its enum repr)
        name = " + ".join(map(str, word)) if isinstance(word, (tuple, list)) else str(word)
        raise ParameterError(f"no identifiable scenario for {name or 'none'} #{index} in {MAX_ATTEMPTS} draws "
                             f"(last: {last[pending[0]]}); a longer --duration gives the effects room",
                             name="word", value=name)
    return done


def _independent_case(job: tuple) -> BenchCase:
    """One log of the independent generator (:mod:`forecast_design.independent`), diagnosed blind.

    Half its closed loops run a PID instead of the PD (``controllers``). A word for which no
    identifiable log is drawn within the generator's attempts (e.g. a torque gain within the
    datasheet tolerance at a quarter of the typical magnitude) is diagnosed on its first draw and
    scored in the ``hard`` suite (an honest caveat counts).
    """
    from ..errors import IdentifiabilityError
    from .. import independent as ind
    from .diagnose import diagnose

    words, index, seed, _, _, _, scale = job
    word = words[0] if words else Effect.NONE
    suite = "main"
    try:
        log = ind.make_independent_log(word, index, seed, magnitude_scale=scale, controllers=True)
        case, exp, attempts = log.case, log.experiment, log.case.attempt + 1
    except IdentifiabilityError:
        case = ind.draw_independent_case(word, index, seed, magnitude_scale=scale, controllers=True)
        exp, _ = ind.simulate_independent(case)
        suite, attempts = "hard", ind.MAX_ATTEMPTS
    t0 = time.perf_counter()
    diag = diagnose(exp, joint=False)
    seconds = time.perf_counter() - t0
    true_red = next((r.reduction for r in diag.ranking if r.effect == word), float("nan"))
    loop = "cl" if case.closed_loop else "ol"
    return BenchCase(truth=word, verdict=diag.effect, joint=None, reduction=diag.reduction, true_reduction=true_red,
                     environment=case.environment_name, excitation=f"{loop}-{case.excitation.kind}",
                     effect_params=_jsonable_params(case.effect_params), seconds=seconds, suite=suite,
                     truths=(word,), secondary=diag.secondary.effect if diag.secondary else Effect.NONE,
                     caveats=diag.caveats, attempts=attempts, design=exp.declared())


def _jsonable_params(params: Any) -> dict:
    out = {}
    for k, v in dict(params).items():
        if isinstance(v, (tuple, list, np.ndarray)):
            out[str(k)] = [float(x) for x in v]
        elif isinstance(v, (int, float, np.floating)) and not isinstance(v, bool):
            out[str(k)] = float(v)
        else:
            out[str(k)] = str(v)
    return out


def run_case(job: tuple) -> BenchCase:
    """Simulate one case and diagnose it blind.

    Parameters
    ----------
    job : tuple
        ``(words, index, seed, duration_s, suite, generator, magnitude_scale)``.

    Returns
    -------
    BenchCase
        Truth, verdict and scores.
    """
    words, index, seed, duration_s, suite, generator, _ = job
    if generator == "independent":
        return _independent_case(job)
    spec, exp, _ = make_log(words, index, seed, duration_s=duration_s, suite=suite)
    return _diagnosed(spec, exp, suite)


def _run_logged(task: tuple) -> BenchCase:
    """A job whose testbed log the benchmark simulated already (``(job, spec, result)``), or any job (spec None)."""
    job, spec, result = task
    return run_case(job) if spec is None else _diagnosed(spec, _recorded(spec, result), job[4])


def _diagnosed(spec: CaseSpec, exp: Any, suite: str) -> BenchCase:
    """Diagnose a testbed case's blind log and score it."""
    from .diagnose import diagnose

    t0 = time.perf_counter()
    diag = diagnose(exp)
    seconds = time.perf_counter() - t0
    true_red = float("nan")
    for r in diag.ranking:
        if r.effect == spec.word:
            true_red = r.reduction
    params = spec.effects[0].to_mapping() if len(spec.effects) == 1 else \
        {"effects": [e.to_mapping() for e in spec.effects]}
    return BenchCase(truth=spec.word, verdict=diag.effect, joint=diag.joint.effects if diag.joint else (),
                     reduction=diag.reduction, true_reduction=true_red, environment=spec.environment,
                     excitation=spec.excitation, effect_params=params, seconds=seconds, suite=suite,
                     truths=spec.words, secondary=diag.secondary.effect if diag.secondary else Effect.NONE,
                     caveats=diag.caveats, attempts=spec.attempt + 1, design=exp.declared())


def benchmark(per_effect: int = 5, seed: int = 0, workers: int | None = None, *, duration_s: float = 10.0,
              words: Sequence[Effect] = BENCH_WORDS, hard: int = 0, pairs: int = 0,
              progress: Callable[[int, int], None] | None = None, generator: str = "testbed",
              magnitude_scale: float = 1.0, scheduler: str | None = None) -> BenchResult:
    """Run the withheld-effect benchmark.

    Parameters
    ----------
    per_effect : int
        Logs per effect word (``none`` included) in the main suite [-].
    seed : int
        Master seed [-].
    workers : int, optional
        Worker processes; default the number of available cores.
    duration_s : float
        Length of each log [s].
    words : sequence of Effect
        Effect words of the main suite.
    hard : int
        Logs per hard (non-identifiable) scenario [-].
    pairs : int
        Logs per two-effect combination of ``PAIRS`` [-].
    progress : callable, optional
        ``progress(done, total)`` after each log (the CLI draws a bar with it).
    generator : str
        ``testbed`` (the project's virtual testbed, :mod:`forecast_design.simulation`) or
        ``independent`` (:mod:`forecast_design.independent`, written separately from the physics:
        scipy event-located integration, its own loggers, excitations and magnitudes; its logs
        last 5-20 s, so ``duration_s`` does not apply; the hard and pairs suites are the testbed's).
    magnitude_scale : float
        Fraction of the typical effect magnitudes (independent generator only) [-].
    scheduler : str, optional
        Dask scheduler address ``tcp://HOST:PORT``: run the logs on that cluster
        (:mod:`forecast_design.executor`) instead of local processes.

    Returns
    -------
    BenchResult
        Confusion matrix, accuracy and per-case outcomes.
    """
    for name, value, lo in (("per_effect", per_effect, 0), ("hard", hard, 0), ("pairs", pairs, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            raise ParameterError(f"{name} must be an integer >= {lo}, got {value!r}", name=name, value=value)
    check_limit("seed", "seed", seed)
    if generator not in ("testbed", "independent"):
        raise ParameterError(f"generator must be 'testbed' or 'independent', got {generator!r}", name="generator",
                             value=generator)
    if not (isinstance(magnitude_scale, (int, float)) and 0.0 < magnitude_scale <= 1.0):
        raise ParameterError(f"magnitude_scale must lie in (0, 1], got {magnitude_scale!r}", name="magnitude_scale",
                             value=magnitude_scale)
    if generator == "testbed" and magnitude_scale != 1.0:
        raise ParameterError("magnitude_scale applies to the independent generator only", name="magnitude_scale",
                             value=magnitude_scale)
    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s) and duration_s > 0):
        raise ParameterError(f"duration_s must be > 0 [s], got {duration_s!r}", name="duration_s", value=duration_s)
    words = tuple(words)
    n_logs = per_effect * len(words) + hard * len(HARD) + pairs * len(PAIRS)
    if n_logs:   # counted before the job list is built: a huge count is an error, not an exhausted memory
        check_limit(f"bench-gap logs (per_effect x {len(words)} + hard x {len(HARD)} + pairs x {len(PAIRS)} = "
                    f"{n_logs})", "runs", n_logs)
    g = (generator, float(magnitude_scale))
    jobs = [((Effect(w),), i, seed, duration_s, "main", *g) for w in words for i in range(per_effect)]
    jobs += [((h[0],), i, seed, duration_s, "hard", "testbed", 1.0) for h in HARD for i in range(hard)]
    jobs += [(pair, i, seed, duration_s, "pairs", "testbed", 1.0) for pair in PAIRS for i in range(pairs)]
    if not jobs:
        raise ParameterError("the benchmark has no logs: per_effect, hard and pairs are all 0", name="per_effect",
                             value=per_effect)
    t0 = time.perf_counter()
    cases: list = []
    with make_executor(scheduler, workers) as executor:
        n_workers = executor.workers
        # the testbed logs of a chunk are simulated here as batches (simulate_batch, both cores), then the
        # chunk's diagnoses run on the executor; the independent generator's logs stay with their jobs.
        # Chunks of equal size bound the memory (~3 MB per 10 s log); the diagnosis is imported here
        # first, so local worker processes forked for each chunk start with it loaded.
        from . import diagnose as _loaded  # noqa: F401

        chunks = -(-len(jobs) // max(32, 16 * n_workers))
        step = -(-len(jobs) // chunks)
        for start in range(0, len(jobs), step):
            chunk = jobs[start:start + step]
            mine = [k for k, j in enumerate(chunk) if j[5] == "testbed"]
            logs = dict(zip(mine, make_logs([chunk[k][:5] for k in mine])))
            # (spec, simulation) travel to the workers, which record the blind log from them
            tasks = [(j, logs[k][0], logs[k][2]) if k in logs else (j, None, None) for k, j in enumerate(chunk)]
            del logs
            report = None if not callable(progress) else (lambda d, n, s=start: progress(s + d, len(jobs)))
            cases += executor.map(_run_logged, tasks, progress=report)
    return BenchResult(cases=tuple(cases), per_effect=per_effect, seed=seed,
                       elapsed_s=time.perf_counter() - t0, workers=n_workers, generator=generator,
                       magnitude_scale=float(magnitude_scale))
