"""Withheld-effect benchmark of the gap diagnosis on the virtual testbed.

Each case draws, from its own seed, one effect word (or none) with a random
magnitude, an environment preset, an excitation (open-loop multisine or chirp
torque; closed-loop PD tracking of a square, sine or multisine force
reference), a random absolute motor angle and nominal-parameter errors: the
experiment's ``J_m``, ``d_m`` and ``k`` are off by up to ``param_error`` from
the simulated truth. The simulator records 2,000,000-count encoders and a small
process torque noise. Only the experiment reaches :func:`diagnose`; the truth
stays in the case record.

Magnitudes are drawn where the effect is physically distinguishable from the
tolerated parameter errors (e.g. a torque gain beyond +-15 %: a smaller one is a
common rescaling of ``J_m``, ``d_m`` and ``k``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .. import effects as fx
from ..effects import Effect
from ..errors import ParameterError
from ..params import Design, PDController, environment_preset

__all__ = ["BenchCase", "BenchResult", "benchmark", "draw_case", "run_case", "BENCH_WORDS"]

#: Effect words of the benchmark: every vocabulary word, ``none`` included.
BENCH_WORDS: tuple[Effect, ...] = tuple(Effect)
ENVIRONMENTS = ("soft", "stiff", "link-only", "locked", "exp-soft")
EXCITATIONS = ("ol-multisine", "ol-chirp", "cl-square", "cl-sine", "cl-multisine")


@dataclass(frozen=True, slots=True, kw_only=True)
class CaseSpec:
    """Everything needed to simulate one benchmark log (the truth)."""

    word: Effect
    index: int
    seed: int
    environment: str
    excitation: str
    effects: tuple
    errors: tuple[float, float, float]
    initial_angle: float
    duration_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchCase:
    """Outcome of one benchmark log.

    Parameters
    ----------
    truth : Effect
        The withheld effect.
    verdict : Effect
        The diagnosis's verdict.
    joint : tuple of Effect
        Effects named by the joint (group-lasso) attribution.
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
    """

    truth: Effect
    verdict: Effect
    joint: tuple[Effect, ...]
    reduction: float
    true_reduction: float
    environment: str
    excitation: str
    effect_params: dict
    seconds: float

    @property
    def correct(self) -> bool:
        """True when the verdict names the withheld effect."""
        return self.verdict == self.truth

    @property
    def joint_correct(self) -> bool:
        """True when the joint attribution names exactly the withheld effect (nothing for none)."""
        if self.truth is Effect.NONE:
            return len(self.joint) == 0
        return len(self.joint) >= 1 and self.joint[0] == self.truth

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping."""
        return {"truth": str(self.truth), "verdict": str(self.verdict), "joint": [str(e) for e in self.joint],
                "reduction": self.reduction,
                "true_reduction": None if math.isnan(self.true_reduction) else self.true_reduction,
                "environment": self.environment, "excitation": self.excitation,
                "effect_params": self.effect_params, "seconds": self.seconds}


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchResult:
    """Confusion matrix and accuracy of the withheld-effect benchmark.

    Parameters
    ----------
    cases : tuple of BenchCase
        Every log's outcome.
    per_effect : int
        Logs per effect word [-].
    seed : int
        Master seed.
    elapsed_s : float
        Wall time of the whole benchmark [s].
    """

    cases: tuple[BenchCase, ...]
    per_effect: int
    seed: int
    elapsed_s: float

    @property
    def accuracy(self) -> float:
        """Share of verdicts naming the withheld effect [-]."""
        return sum(c.correct for c in self.cases) / max(1, len(self.cases))

    @property
    def joint_accuracy(self) -> float:
        """Share of joint attributions naming exactly the withheld effect first [-]."""
        return sum(c.joint_correct for c in self.cases) / max(1, len(self.cases))

    @property
    def false_alarms(self) -> int:
        """Effect-free logs blamed on an effect [-]."""
        return sum(1 for c in self.cases if c.truth is Effect.NONE and c.verdict is not Effect.NONE)

    @property
    def min_true_reduction(self) -> float:
        """Smallest held-out reduction of the true effect's candidate over effect logs [-]."""
        vals = [c.true_reduction for c in self.cases if c.truth is not Effect.NONE and not math.isnan(c.true_reduction)]
        return min(vals) if vals else float("nan")

    def confusion(self) -> dict[str, dict[str, int]]:
        """``confusion[truth][verdict]`` counts over the vocabulary."""
        words = [str(e) for e in BENCH_WORDS]
        out = {t: {v: 0 for v in words} for t in words}
        for c in self.cases:
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
        return {"per_effect": self.per_effect, "seed": self.seed, "n_logs": len(self.cases),
                "accuracy": self.accuracy, "joint_accuracy": self.joint_accuracy,
                "false_alarms": self.false_alarms, "min_true_reduction": self.min_true_reduction,
                "confusion": self.confusion(), "elapsed_s": self.elapsed_s,
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
    raise ParameterError(f"no benchmark generator for effect {word!r}", name="word", value=word)


def draw_case(word: Effect, index: int, seed: int, *, duration_s: float = 10.0,
              param_error: float = 0.03) -> CaseSpec:
    """Draw one benchmark scenario (deterministic in ``word``, ``index`` and ``seed``).

    Parameters
    ----------
    word : Effect
        The effect to withhold (``Effect.NONE``: effect-free).
    index : int
        Case number within the word [-].
    seed : int
        Master seed [-].
    duration_s : float
        Log length [s].
    param_error : float
        Largest relative error of the nominal ``J_m``, ``d_m``, ``k`` [-].

    Returns
    -------
    CaseSpec
        The scenario, truth included.
    """
    rng = np.random.default_rng([seed, list(Effect).index(word), index])
    envs = [e for e in ENVIRONMENTS if not (word is Effect.ENVIRONMENT_MISMATCH and e == "locked")]
    environment = str(envs[(index + int(rng.integers(len(envs)))) % len(envs)])
    excitation = str(EXCITATIONS[(index + int(rng.integers(len(EXCITATIONS)))) % len(EXCITATIONS)])
    effects = _draw_effect(word, rng, environment)
    errors = tuple(float(x) for x in rng.uniform(-param_error, param_error, 3))
    return CaseSpec(word=word, index=index, seed=int(rng.integers(2 ** 31)), environment=environment,
                    excitation=excitation, effects=effects, errors=errors,
                    initial_angle=float(rng.uniform(0, 2 * np.pi)), duration_s=duration_s)


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

    rng = np.random.default_rng(spec.seed)
    ref, closed = _reference(spec, rng)
    true_design = Design.nominal(spec.environment, controller=PDController() if closed else None)
    result = simulate(true_design, reference=ref, duration_s=spec.duration_s, effects=spec.effects,
                      seed=spec.seed, closed_loop=closed, initial_angle=spec.initial_angle)
    tb = true_design.testbed
    e = spec.errors
    nominal_tb = dataclasses.replace(tb, J_m=tb.J_m * (1 + e[0]), d_m=tb.d_m * (1 + e[1]), k=tb.k * (1 + e[2]))
    exp = result.to_experiment()
    # the log's TOML holds the (slightly wrong) nominal model; tau_s is what the logger derives from it
    nominal = dataclasses.replace(exp.design, testbed=nominal_tb)
    exp = dataclasses.replace(exp, design=nominal).replace_signals(tau_s=None)
    return exp, result


def run_case(spec: CaseSpec) -> BenchCase:
    """Simulate one case and diagnose it blind.

    Parameters
    ----------
    spec : CaseSpec
        The scenario.

    Returns
    -------
    BenchCase
        Truth, verdict and scores.
    """
    from .diagnose import diagnose

    exp, _ = simulate_case(spec)
    t0 = time.perf_counter()
    diag = diagnose(exp)
    seconds = time.perf_counter() - t0
    true_red = float("nan")
    for r in diag.ranking:
        if r.effect == spec.word:
            true_red = r.reduction
    params = spec.effects[0].to_mapping() if spec.effects else {}
    return BenchCase(truth=spec.word, verdict=diag.effect, joint=diag.joint.effects if diag.joint else (),
                     reduction=diag.reduction, true_reduction=true_red, environment=spec.environment,
                     excitation=spec.excitation, effect_params=params, seconds=seconds)


def benchmark(per_effect: int = 5, seed: int = 0, workers: int | None = None, *, duration_s: float = 10.0,
              words: Sequence[Effect] = BENCH_WORDS, progress: bool = True) -> BenchResult:
    """Run the withheld-effect benchmark.

    Parameters
    ----------
    per_effect : int
        Logs per effect word (``none`` included) [-].
    seed : int
        Master seed [-].
    workers : int, optional
        Worker processes; default the number of available cores.
    duration_s : float
        Length of each log [s].
    words : sequence of Effect
        Effect words to include.
    progress : bool
        Show a tqdm progress bar (on stderr).

    Returns
    -------
    BenchResult
        Confusion matrix, accuracy and per-case outcomes.
    """
    from tqdm import tqdm

    if isinstance(per_effect, bool) or not isinstance(per_effect, int) or per_effect < 1:
        raise ParameterError(f"per_effect must be an integer >= 1, got {per_effect!r}", name="per_effect",
                             value=per_effect)
    specs = [draw_case(Effect(w), i, seed, duration_s=duration_s) for w in words for i in range(per_effect)]
    n_workers = workers if workers is not None else (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                                     else (os.cpu_count() or 1))
    t0 = time.perf_counter()
    bar = tqdm(total=len(specs), desc="bench-gap", disable=not progress, unit="log")
    cases: list[BenchCase] = []
    if n_workers <= 1:
        for spec in specs:
            cases.append(run_case(spec))
            bar.update()
    else:
        with ProcessPoolExecutor(max_workers=n_workers) as pool:
            for case in pool.map(run_case, specs):
                cases.append(case)
                bar.update()
    bar.close()
    return BenchResult(cases=tuple(cases), per_effect=per_effect, seed=seed,
                       elapsed_s=time.perf_counter() - t0)
